//! `mireg sweep`: clap arguments → [`crate::sweep::SweepOptions`] → [`crate::sweep::prepare_sweep`],
//! its notes and table printed.

use std::path::PathBuf;

use anyhow::Result;
use clap::Args;

use crate::sweep::{Acceptance, CSV_HEADER, SweepOptions, prepare_sweep};

/// Arguments of `mireg sweep`.
#[derive(Debug, Args)]
pub struct SweepArgs {
    /// A log with point clouds and a reference PoseStamped topic (e.g. a fixture, or a
    /// `register` output of a log that has one); with --gt-log, the folder of the clouds.
    pub input: PathBuf,
    /// Pairs and ground truth from a file instead of a log: a Redwood/3DMatch `gt.log` (records
    /// `i j n` + 4×4 `i_from_j`; clouds `cloud_bin_{i}.ply|.pcd|.npy|.bin` in INPUT; pairs whose
    /// clouds are absent are skipped), or a Stanford `bun.conf` (every pair of its scans, files
    /// as named there).
    #[arg(long, value_name = "FILE")]
    pub gt_log: Option<PathBuf>,
    /// Choi et al.'s information matrices for the `gt.log` pairs [default: `gt.info` beside the
    /// `gt.log`, when there is one]. A pair with a record is correct when its information-matrix
    /// error is within --max-info-error; pairs without one use --max-re-deg / --max-te-m.
    #[arg(long, value_name = "FILE", requires = "gt_log")]
    pub gt_info: Option<PathBuf>,
    /// Largest information-matrix error of a correct registration [m²] (Choi's 0.04: 0.2 m RMSE).
    #[arg(long, default_value_t = crate::sweep::CHOI_MAX_ERROR, value_name = "ERROR")]
    pub max_info_error: f64,
    /// Point cloud topic [default: the only one].
    #[arg(long)]
    pub topic: Option<String>,
    /// Reference PoseStamped topic, matched to clouds by stamp.
    #[arg(long, default_value = crate::trajectory::DEFAULT_GROUND_TRUTH_TOPIC, value_name = "TOPIC")]
    pub reference_topic: String,
    /// Frame gaps k of the pairs (i, i + k), comma-separated.
    #[arg(
        value_name = "FRAMES,...",
        long,
        value_delimiter = ',',
        default_value = "5,10,20"
    )]
    pub gaps: Vec<usize>,
    /// Seeded runs per pair and cell (the paper's M) [default: 20; 3 with --quick].
    #[arg(long, value_name = "N")]
    pub runs: Option<usize>,
    /// First seed (run r uses seed + r).
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Rankings, comma-separated: ratio, distance, count_most (the authors'), count_fewest
    /// [default: ratio,distance,count_most; ratio,count_most with --quick].
    #[arg(long, value_delimiter = ',', value_name = "RANKING,...")]
    pub rankings: Option<Vec<String>>,
    /// Lévy locations μ, comma-separated [default: the paper's −1, −50, −1e2 … −1e6; −1, −50,
    /// −1e3, −1e6 with --quick].
    #[arg(
        value_name = "MU,...",
        long,
        value_delimiter = ',',
        allow_hyphen_values = true
    )]
    pub mus: Option<Vec<f64>>,
    /// At most this many pairs (evenly spaced over all of them) [default: all; 20 with --quick].
    #[arg(long, value_name = "N")]
    pub max_pairs: Option<usize>,
    /// A quick look (under a minute on the fixture, 2 cores): the defaults of --runs, --mus,
    /// --rankings and --max-pairs become 3 runs, μ ∈ {−1, −50, −1e3, −1e6}, rankings ratio and
    /// count_most, at most 20 pairs. A flag given explicitly wins.
    #[arg(long)]
    pub quick: bool,
    /// Voxel size [m] [default: the first cloud's median range / 40, as register].
    #[arg(long, value_name = "METRES")]
    pub voxel: Option<f64>,
    /// A reported registration is correct within this rotation error [deg].
    #[arg(long, default_value_t = 2.0, value_name = "DEGREES")]
    pub max_re_deg: f64,
    /// ... and this translation error [m] [default: one voxel].
    #[arg(long, value_name = "METRES")]
    pub max_te_m: Option<f64>,
    /// Reported needs at least this many RANSAC inliers (register's test).
    #[arg(long, default_value_t = Acceptance::default().min_inliers, value_name = "N")]
    pub min_inliers: usize,
    /// ... and at least this ICP fitness.
    #[arg(long, default_value_t = Acceptance::default().min_fitness, value_name = "FRACTION")]
    pub min_fitness: f64,
    /// Dataset name in the table [default: the input's file stem].
    #[arg(long, value_name = "NAME")]
    pub dataset: Option<String>,
    /// Print CSV: dataset,ranking,sampler,mu,runs,pairs,recall,precision,hypotheses_median,time_s_median.
    #[arg(long)]
    pub csv: bool,
}

impl SweepArgs {
    /// The flags as the job's options.
    pub fn options(&self) -> SweepOptions {
        SweepOptions {
            input: self.input.clone(),
            gt_log: self.gt_log.clone(),
            gt_info: self.gt_info.clone(),
            max_info_error: self.max_info_error,
            topic: self.topic.clone(),
            reference_topic: self.reference_topic.clone(),
            gaps: self.gaps.clone(),
            runs: self.runs,
            seed: self.seed,
            rankings: self.rankings.clone(),
            mus: self.mus.clone(),
            max_pairs: self.max_pairs,
            quick: self.quick,
            voxel: self.voxel,
            max_re_deg: self.max_re_deg,
            max_te_m: self.max_te_m,
            min_inliers: self.min_inliers,
            min_fitness: self.min_fitness,
            dataset: self.dataset.clone(),
        }
    }
}

/// `mireg sweep`.
pub(super) fn run_sweep(args: &SweepArgs) -> Result<()> {
    let prepared = prepare_sweep(&args.options())?;
    for note in &prepared.notes {
        eprintln!("{note}");
    }
    let (config, thresholds) = (&prepared.config, &prepared.config.thresholds);
    eprintln!(
        "{}: {} frames, {} pairs (gaps {:?}; ignored with --gt-log), voxel {:.3} m, {} cells × {} runs; correct within {} deg / {} m",
        args.input.display(),
        prepared.frames.len(),
        prepared.pairs.len(),
        args.gaps,
        prepared.voxel_m,
        config.rankings.len() * config.samplers.len(),
        config.runs,
        thresholds.max_re_deg,
        thresholds.max_te_m
    );
    let rows = prepared.run()?;
    if args.csv {
        println!("{CSV_HEADER}");
        for r in &rows {
            println!("{}", r.csv_row());
        }
    } else {
        println!(
            "{:<12} {:<8} {:>8} {:>7} {:>9} {:>12} {:>10}",
            "ranking", "sampler", "mu", "recall", "precision", "hypotheses", "time [s]"
        );
        for r in &rows {
            println!(
                "{:<12} {:<8} {:>8} {:>7.3} {:>9.3} {:>12} {:>10.4}",
                r.ranking,
                r.sampler,
                r.mu.map(|m| format!("{m}")).unwrap_or_default(),
                r.recall,
                r.precision,
                r.hypotheses_median,
                r.time_s_median
            );
        }
    }
    Ok(())
}
