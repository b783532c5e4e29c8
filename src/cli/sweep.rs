//! `mireg sweep`: clap arguments → frames and pairs from a log with a reference trajectory →
//! [`crate::sweep`].

use std::collections::BTreeMap;
use std::ops::ControlFlow;
use std::path::PathBuf;

use anyhow::{Result, bail};
use clap::Args;
use nalgebra::{Isometry3, Point3};

use crate::pipeline::{PairConfig, prepare_frame, voxel_for_cloud};
use crate::sweep::{
    Acceptance, CSV_HEADER, PAPER_MUS, SweepConfig, SweepPair, Thresholds, pairs_from_trajectory,
    samplers, sweep,
};

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
    #[arg(long, default_value_t = crate::sweep::CHOI_MAX_ERROR)]
    pub max_info_error: f64,
    /// Point cloud topic [default: the only one].
    #[arg(long)]
    pub topic: Option<String>,
    /// Reference PoseStamped topic, matched to clouds by stamp.
    #[arg(long, default_value = crate::trajectory::DEFAULT_GROUND_TRUTH_TOPIC)]
    pub reference_topic: String,
    /// Frame gaps k of the pairs (i, i + k), comma-separated.
    #[arg(long, value_delimiter = ',', default_value = "5,10,20")]
    pub gaps: Vec<usize>,
    /// Seeded runs per pair and cell (the paper's M) [default: 20; 3 with --quick].
    #[arg(long)]
    pub runs: Option<usize>,
    /// First seed (run r uses seed + r).
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Rankings, comma-separated: ratio, distance, count_most (the authors'), count_fewest
    /// [default: ratio,distance,count_most; ratio,count_most with --quick].
    #[arg(long, value_delimiter = ',')]
    pub rankings: Option<Vec<String>>,
    /// Lévy locations μ, comma-separated [default: the paper's −1, −50, −1e2 … −1e6; −1, −50,
    /// −1e3, −1e6 with --quick].
    #[arg(long, value_delimiter = ',', allow_hyphen_values = true)]
    pub mus: Option<Vec<f64>>,
    /// At most this many pairs (evenly spaced over all of them) [default: all; 20 with --quick].
    #[arg(long)]
    pub max_pairs: Option<usize>,
    /// A quick look (under a minute on the fixture, 2 cores): the defaults of --runs, --mus,
    /// --rankings and --max-pairs become 3 runs, μ ∈ {−1, −50, −1e3, −1e6}, rankings ratio and
    /// count_most, at most 20 pairs. A flag given explicitly wins.
    #[arg(long)]
    pub quick: bool,
    /// Voxel size [m] [default: the first cloud's median range / 40, as register].
    #[arg(long)]
    pub voxel: Option<f64>,
    /// A reported registration is correct within this rotation error [deg].
    #[arg(long, default_value_t = 2.0)]
    pub max_re_deg: f64,
    /// ... and this translation error [m] [default: one voxel].
    #[arg(long)]
    pub max_te_m: Option<f64>,
    /// Reported needs at least this many RANSAC inliers (register's test).
    #[arg(long, default_value_t = Acceptance::default().min_inliers)]
    pub min_inliers: usize,
    /// ... and at least this ICP fitness.
    #[arg(long, default_value_t = Acceptance::default().min_fitness)]
    pub min_fitness: f64,
    /// Dataset name in the table [default: the input's file stem].
    #[arg(long)]
    pub dataset: Option<String>,
    /// Print CSV: dataset,ranking,sampler,mu,runs,pairs,recall,precision,hypotheses_median,time_s_median.
    #[arg(long)]
    pub csv: bool,
}

/// The clouds of a sweep and its pairs (indices into them).
type CloudsAndPairs = (Vec<Vec<Point3<f64>>>, Vec<SweepPair>);

/// Clouds and pairs from a `gt.log` (with `gt.info`, see [`SweepArgs::gt_info`]) or a `bun.conf`
/// (see [`SweepArgs::gt_log`]).
fn pairs_from_file(
    dir: &std::path::Path,
    gt: &std::path::Path,
    gt_info: Option<&std::path::Path>,
) -> Result<CloudsAndPairs> {
    use crate::io::{cloud_file, pose_file};
    let mut clouds = Vec::new();
    let mut index: BTreeMap<String, usize> = BTreeMap::new();
    let mut load = |file: std::path::PathBuf| -> Result<usize> {
        let key = file.display().to_string();
        if let Some(&k) = index.get(&key) {
            return Ok(k);
        }
        clouds.push(cloud_file::read_points(&file)?);
        index.insert(key, clouds.len() - 1);
        Ok(clouds.len() - 1)
    };
    let mut pairs = Vec::new();
    let text = crate::io::read_text(gt)?;
    if text.lines().any(|l| l.starts_with("bmesh")) {
        let scans = pose_file::parse_bunny_conf(&text, gt)?;
        for (a, sa) in scans.iter().enumerate() {
            for sb in &scans[a + 1..] {
                pairs.push(SweepPair {
                    target: load(dir.join(&sa.file))?,
                    source: load(dir.join(&sb.file))?,
                    target_from_source: sa.world_from_scan.inverse() * sb.world_from_scan,
                    information: None,
                });
            }
        }
    } else {
        let find = |i: usize| {
            ["ply", "pcd", "npy", "bin"]
                .iter()
                .map(|e| dir.join(format!("cloud_bin_{i}.{e}")))
                .find(|p| p.is_file())
        };
        let (mut skipped, records) = (0, pose_file::parse_log(&text, gt)?);
        let beside = gt.with_file_name("gt.info");
        let info_path = gt_info.or_else(|| beside.is_file().then_some(beside.as_path()));
        let information: BTreeMap<(usize, usize), nalgebra::Matrix6<f64>> = match info_path {
            Some(path) => pose_file::read_info(path)?
                .into_iter()
                .map(|r| ((r.i, r.j), r.information))
                .collect(),
            None => BTreeMap::new(),
        };
        for r in &records {
            match (find(r.i), find(r.j)) {
                (Some(ti), Some(sj)) => pairs.push(SweepPair {
                    target: load(ti)?,
                    source: load(sj)?,
                    target_from_source: r.pose,
                    information: information.get(&(r.i, r.j)).copied(),
                }),
                _ => skipped += 1,
            }
        }
        if let Some(path) = info_path {
            let with = pairs.iter().filter(|p| p.information.is_some()).count();
            eprintln!(
                "{}: information matrices for {with} of {} pairs (Choi's criterion, error ≤ max-info-error); the others by RE/TE",
                path.display(),
                pairs.len()
            );
        }
        if skipped > 0 {
            eprintln!(
                "{}: {skipped} of {} pairs skipped: their clouds are not in {}",
                gt.display(),
                records.len(),
                dir.display()
            );
        }
    }
    Ok((clouds, pairs))
}

/// `mireg sweep`.
pub(super) fn run_sweep(args: &SweepArgs) -> Result<()> {
    let (clouds, pairs) = match &args.gt_log {
        Some(gt) => pairs_from_file(&args.input, gt, args.gt_info.as_deref())?,
        None => log_pairs(args)?,
    };
    if pairs.is_empty() {
        bail!("{}: no pair to register", args.input.display());
    }
    sweep_pairs(args, clouds, pairs)
}

/// Clouds matched to the reference topic by stamp, and the pairs (i, i + k) of `--gaps`.
fn log_pairs(args: &SweepArgs) -> Result<CloudsAndPairs> {
    let reference = crate::io::poses::read_mcap_pose_topic(&args.input, &args.reference_topic)?;
    let by_stamp: BTreeMap<i64, Isometry3<f64>> = reference
        .stamps_ns
        .iter()
        .copied()
        .zip(reference.poses.iter().copied())
        .collect();
    let mut clouds: Vec<(Vec<Point3<f64>>, Isometry3<f64>)> = Vec::new();
    crate::register::for_each_cloud(&args.input, args.topic.as_deref(), |_, cloud| {
        if let Some(pose) = by_stamp.get(&cloud.header.stamp.to_ns()) {
            clouds.push((cloud.points, *pose));
        }
        Ok(ControlFlow::Continue(()))
    })?;
    if clouds.len() < 2 {
        bail!(
            "{}: {} clouds have a pose on {} at the same stamp; a sweep needs at least 2",
            args.input.display(),
            clouds.len(),
            args.reference_topic
        );
    }
    let poses: Vec<Isometry3<f64>> = clouds.iter().map(|c| c.1).collect();
    let pairs = pairs_from_trajectory(&poses, &args.gaps);
    Ok((clouds.into_iter().map(|c| c.0).collect(), pairs))
}

fn sweep_pairs(
    args: &SweepArgs,
    clouds: Vec<Vec<Point3<f64>>>,
    mut pairs: Vec<SweepPair>,
) -> Result<()> {
    let voxel = match args.voxel {
        Some(v) => v,
        None => voxel_for_cloud(&clouds[0]).unwrap_or(PairConfig::default().voxel_size_m),
    };
    let pair = PairConfig {
        voxel_size_m: voxel,
        ..Default::default()
    };
    let frames = clouds
        .iter()
        .map(|p| prepare_frame(p, &pair))
        .collect::<crate::Result<Vec<_>>>()?;
    // --quick changes the defaults only: an explicit flag wins.
    let max_pairs = args.max_pairs.or(args.quick.then_some(20));
    if let Some(m) = max_pairs.filter(|&m| m < pairs.len()) {
        let n = pairs.len();
        pairs = (0..m).map(|i| pairs[i * n / m].clone()).collect();
    }
    let thresholds = Thresholds {
        max_re_deg: args.max_re_deg,
        max_te_m: args.max_te_m.unwrap_or(voxel),
        max_info_error: args.max_info_error,
    };
    // Pairs whose motion is within the thresholds would count the identity as correct.
    let trivial = pairs
        .iter()
        .filter(|p| thresholds.correct(p, &Isometry3::identity()))
        .count();
    if trivial > 0 {
        eprintln!(
            "warning: {trivial} of {} pairs move less than the thresholds ({} deg, {} m): the identity would count as correct there; use larger --gaps or smaller --max-re-deg/--max-te-m",
            pairs.len(),
            thresholds.max_re_deg,
            thresholds.max_te_m
        );
    }
    let (runs, mus, rankings) = (
        args.runs.unwrap_or(if args.quick { 3 } else { 20 }),
        args.mus.clone().unwrap_or_else(|| {
            if args.quick {
                vec![-1.0, -50.0, -1e3, -1e6]
            } else {
                PAPER_MUS.to_vec()
            }
        }),
        args.rankings.clone().unwrap_or_else(|| {
            let names: &[&str] = if args.quick {
                &["ratio", "count_most"]
            } else {
                &["ratio", "distance", "count_most"]
            };
            names.iter().map(|s| s.to_string()).collect()
        }),
    );
    let config = SweepConfig {
        dataset: args.dataset.clone().unwrap_or_else(|| {
            args.input
                .file_stem()
                .map(|s| s.to_string_lossy().into_owned())
                .unwrap_or_default()
        }),
        rankings,
        samplers: samplers(&mus),
        runs,
        seed: args.seed,
        pair,
        acceptance: Acceptance {
            min_inliers: args.min_inliers,
            min_fitness: args.min_fitness,
        },
        thresholds,
    };
    eprintln!(
        "{}: {} frames, {} pairs (gaps {:?}; ignored with --gt-log), voxel {voxel:.3} m, {} cells × {} runs; correct within {} deg / {} m",
        args.input.display(),
        frames.len(),
        pairs.len(),
        args.gaps,
        config.rankings.len() * config.samplers.len(),
        config.runs,
        thresholds.max_re_deg,
        thresholds.max_te_m
    );
    let rows = sweep(&frames, &pairs, &config)?;
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
