//! Command-line interface: clap arguments → library calls. No algorithm lives here.

use std::io::Write;

use anyhow::{Context, Result};
use clap::{Args, Parser, Subcommand};

use std::path::{Path, PathBuf};

use clap::ValueEnum;
use nalgebra::Isometry3;

use crate::correspondence::ranking::{CountOrder, PAPER_DESCRIPTOR_RADIUS};
use crate::io::{cloud_file, pose_file};
use crate::pipeline::{
    PairConfig, PairResult, RankingConfig, SamplerConfig, pose_error, register_pair,
};
use crate::simulate::{CSV_HEADER, SimulationConfig, SimulationRow, simulate};

/// mireg: register point clouds in robotics logs with MI-RANSAC.
#[derive(Debug, Parser)]
#[command(name = "mireg", version, about)]
pub struct Cli {
    /// What to do.
    #[command(subcommand)]
    pub command: Option<Command>,
}

/// Subcommands.
#[derive(Debug, Subcommand)]
pub enum Command {
    /// Reproduce the paper's sampling simulation (Zhang & Chen, Fig. 5).
    Simulate(SimulateArgs),
    /// Register one point cloud (SRC) to another (TGT): prints target_from_source.
    Pair(PairArgs),
}

/// Sampler choice on the command line.
#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum SamplerArg {
    /// MI-RANSAC's truncated Lévy law over the ranks.
    Levy,
    /// Plain RANSAC.
    Uniform,
    /// PROSAC.
    Prosac,
}

/// Ranking choice on the command line.
#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum RankingArg {
    /// Lowe ratio d1/d2, ascending.
    Ratio,
    /// Descriptor distance, ascending.
    Distance,
    /// Paper's neighbour count, largest first (authors' order).
    CountMost,
    /// Paper's neighbour count, smallest first.
    CountFewest,
}

/// Ground-truth file formats for `--gt`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum GtFormat {
    /// 16 numbers: the 4×4 target_from_source, row-major.
    Matrix,
    /// 3DMatch `gt.log`: the record `TARGET SOURCE n` (needs --gt-pair).
    GtLog,
    /// Redwood/ICL-NUIM `trajectory.log` of world_from_camera per frame (needs --gt-pair).
    Trajectory,
    /// Stanford `bun.conf`: scans looked up by the SRC and TGT file names.
    Bunny,
}

/// Arguments of `mireg pair`.
#[derive(Debug, Args)]
pub struct PairArgs {
    /// Source cloud (.ply, .pcd, .npy, KITTI .bin).
    pub source: PathBuf,
    /// Target cloud; the result maps source points into its frame.
    pub target: PathBuf,
    /// Voxel size [m]; normal, feature, inlier and ICP radii derive from it.
    #[arg(long, default_value_t = 0.05)]
    pub voxel: f64,
    /// Hypothesis sampler.
    #[arg(long, value_enum, default_value_t = SamplerArg::Levy)]
    pub sampler: SamplerArg,
    /// Lévy location μ (< 0).
    #[arg(long, default_value_t = -50.0, allow_hyphen_values = true)]
    pub mu: f64,
    /// Lévy scale c.
    #[arg(long, default_value_t = 1.0)]
    pub levy_c: f64,
    /// Lévy draws with replacement (the authors' behaviour).
    #[arg(long)]
    pub with_replacement: bool,
    /// Correspondence ranking.
    #[arg(long, value_enum, default_value_t = RankingArg::Ratio)]
    pub ranking: RankingArg,
    /// Descriptor radius τ_d for the count rankings [FPFH units].
    #[arg(long, default_value_t = PAPER_DESCRIPTOR_RADIUS as f32)]
    pub descriptor_radius: f32,
    /// Keep only mutual nearest neighbours in feature space.
    #[arg(long)]
    pub mutual: bool,
    /// Cap on RANSAC hypotheses.
    #[arg(long, default_value_t = crate::ransac::consensus::DEFAULT_MAX_HYPOTHESES)]
    pub max_hypotheses: u64,
    /// Skip ICP refinement.
    #[arg(long)]
    pub no_icp: bool,
    /// Seed of all randomness.
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Ground truth to compare against (adds rotation/translation errors).
    #[arg(long)]
    pub gt: Option<PathBuf>,
    /// Format of --gt.
    #[arg(long, value_enum, default_value_t = GtFormat::Matrix)]
    pub gt_format: GtFormat,
    /// For gt-log / trajectory: the TARGET,SOURCE record or frame indices.
    #[arg(long, value_parser = parse_pair, value_name = "TARGET,SOURCE")]
    pub gt_pair: Option<(usize, usize)>,
    /// Print one JSON object instead of text.
    #[arg(long)]
    pub json: bool,
}

fn parse_pair(s: &str) -> std::result::Result<(usize, usize), String> {
    let (a, b) = s
        .split_once(',')
        .ok_or_else(|| format!("expected TARGET,SOURCE, got {s:?}"))?;
    let p = |x: &str| x.trim().parse::<usize>().map_err(|e| format!("{x:?}: {e}"));
    Ok((p(a)?, p(b)?))
}

/// Arguments of `mireg simulate`.
#[derive(Debug, Args)]
pub struct SimulateArgs {
    /// Budgets ≤ 1e4 and 5 runs: finishes in seconds.
    #[arg(long)]
    pub quick: bool,
    /// Print CSV instead of a table.
    #[arg(long)]
    pub csv: bool,
    /// Monte Carlo runs per cell [default: 20, or 5 with --quick].
    #[arg(long)]
    pub runs: Option<usize>,
    /// Seed of all randomness.
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
}

/// Runs the parsed command line; returns the process exit code.
pub fn run(cli: Cli) -> Result<()> {
    match cli.command {
        Some(Command::Simulate(args)) => run_simulate(&args),
        Some(Command::Pair(args)) => run_pair(&args),
        None => run_simulate(&SimulateArgs {
            quick: true,
            csv: false,
            runs: None,
            seed: 0,
        }),
    }
}

fn run_simulate(args: &SimulateArgs) -> Result<()> {
    let mut config = if args.quick {
        SimulationConfig::quick()
    } else {
        SimulationConfig::default()
    };
    if let Some(runs) = args.runs {
        config.runs = runs;
    }
    config.seed = args.seed;
    let rows = simulate(&config).context("simulation failed")?;
    let stdout = std::io::stdout();
    let mut out = stdout.lock();
    if args.csv {
        writeln!(out, "{CSV_HEADER}")?;
        for row in &rows {
            writeln!(out, "{}", row.to_csv())?;
        }
    } else {
        write_table(&mut out, &rows)?;
    }
    Ok(())
}

fn write_table(out: &mut impl Write, rows: &[SimulationRow]) -> std::io::Result<()> {
    writeln!(
        out,
        "{:<9} {:>9} {:>2} {:>9} {:>14} {:>10} {:>13}",
        "strategy", "mu", "s", "budget", "unique_ok_mean", "std", "first_ok_med"
    )?;
    for r in rows {
        let mu = match r.strategy {
            crate::simulate::Strategy::Levy { mu, .. } => format!("{mu}"),
            _ => "-".into(),
        };
        writeln!(
            out,
            "{:<9} {:>9} {:>2} {:>9} {:>14.1} {:>10.1} {:>13}",
            r.strategy.name(),
            mu,
            r.sample_size,
            r.hypotheses,
            r.unique_outlier_free_mean,
            r.unique_outlier_free_std,
            r.first_success_median
                .map_or("-".into(), |m| format!("{m}"))
        )?;
    }
    Ok(())
}

impl PairArgs {
    /// The pipeline configuration these flags describe.
    pub fn config(&self) -> PairConfig {
        PairConfig {
            voxel_size_m: self.voxel,
            mutual_filter: self.mutual,
            ranking: match self.ranking {
                RankingArg::Ratio => RankingConfig::Ratio,
                RankingArg::Distance => RankingConfig::Distance,
                RankingArg::CountMost => RankingConfig::NeighbourCount {
                    radius: self.descriptor_radius,
                    order: CountOrder::MostFirst,
                },
                RankingArg::CountFewest => RankingConfig::NeighbourCount {
                    radius: self.descriptor_radius,
                    order: CountOrder::FewestFirst,
                },
            },
            sampler: match self.sampler {
                SamplerArg::Uniform => SamplerConfig::Uniform,
                SamplerArg::Prosac => SamplerConfig::Prosac {
                    growth_max_samples: crate::ransac::prosac::DEFAULT_GROWTH_MAX_SAMPLES,
                },
                SamplerArg::Levy => SamplerConfig::Levy {
                    mu: self.mu,
                    c: self.levy_c,
                    window: crate::ransac::levy::DEFAULT_WINDOW,
                    with_replacement: self.with_replacement,
                },
            },
            max_hypotheses: self.max_hypotheses,
            icp: !self.no_icp,
            seed: self.seed,
            ..PairConfig::default()
        }
    }
}

fn load_gt(args: &PairArgs, path: &Path) -> Result<Isometry3<f64>> {
    let need_pair = || {
        args.gt_pair.with_context(|| {
            format!(
                "--gt-format {:?} needs --gt-pair TARGET,SOURCE",
                args.gt_format
            )
        })
    };
    Ok(match args.gt_format {
        GtFormat::Matrix => pose_file::read_matrix4(path)?,
        GtFormat::GtLog => {
            let (t, s) = need_pair()?;
            let records = pose_file::read_log(path)?;
            pose_file::find_log_pair(&records, t, s)
                .with_context(|| format!("{}: no record for pair {t} {s}", path.display()))?
                .pose
        }
        GtFormat::Trajectory => {
            let (t, s) = need_pair()?;
            let records = pose_file::read_log(path)?;
            let frame = |k: usize| {
                records
                    .iter()
                    .find(|r| r.i == k)
                    .map(|r| r.pose)
                    .with_context(|| format!("{}: no pose for frame {k}", path.display()))
            };
            frame(t)?.inverse() * frame(s)?
        }
        GtFormat::Bunny => {
            let text = std::fs::read_to_string(path)
                .with_context(|| format!("reading {}", path.display()))?;
            let name = |p: &Path| {
                p.file_name()
                    .map(|n| n.to_string_lossy().into_owned())
                    .unwrap_or_default()
            };
            let world_from_src = pose_file::bunny_pose(&text, &name(&args.source))?;
            let world_from_tgt = pose_file::bunny_pose(&text, &name(&args.target))?;
            world_from_tgt.inverse() * world_from_src
        }
    })
}

fn run_pair(args: &PairArgs) -> Result<()> {
    let config = args.config();
    config.resolved()?;
    let gt = args.gt.as_deref().map(|p| load_gt(args, p)).transpose()?;
    let (source, target) = rayon::join(
        || cloud_file::read_points(&args.source),
        || cloud_file::read_points(&args.target),
    );
    let (source, target) = (source?, target?);
    let result = register_pair(&source, &target, &config)?;
    let errors = gt.map(|gt| pose_error(&gt, &result.target_from_source));
    let stdout = std::io::stdout();
    let mut out = stdout.lock();
    if args.json {
        writeln!(out, "{}", pair_json(&result, errors))?;
    } else {
        write_pair_text(&mut out, &result, errors)?;
    }
    Ok(())
}

fn matrix_rows(m: &Isometry3<f64>) -> Vec<Vec<f64>> {
    let h = m.to_homogeneous();
    (0..4)
        .map(|r| (0..4).map(|c| h[(r, c)]).collect())
        .collect()
}

/// The `--json` object of `mireg pair`.
pub fn pair_json(r: &PairResult, errors: Option<(f64, f64)>) -> serde_json::Value {
    let mut v = serde_json::json!({
        "target_from_source": matrix_rows(&r.target_from_source),
        "ransac_target_from_source": matrix_rows(&r.ransac_target_from_source),
        "success": r.failure.is_none(),
        "failure_reason": r.failure,
        "num_points": r.num_points,
        "num_points_downsampled": r.num_points_downsampled,
        "num_correspondences": r.num_correspondences,
        "num_inliers": r.num_inliers,
        "hypotheses": r.hypotheses,
        "prerejected": r.prerejected,
        "verified": r.verified,
        "best_found_at": r.best_found_at,
        "converged": r.converged,
        "fitness": r.fitness,
        "inlier_rmse_m": r.inlier_rmse_m,
        "icp_iterations": r.icp_iterations,
        "timings_s": r.timings_s,
    });
    if let Some((rot, trans)) = errors {
        v["rotation_error_deg"] = rot.into();
        v["translation_error_m"] = trans.into();
    }
    v
}

fn write_pair_text(
    out: &mut impl Write,
    r: &PairResult,
    errors: Option<(f64, f64)>,
) -> std::io::Result<()> {
    match r.failure {
        None => writeln!(out, "registration succeeded")?,
        Some(reason) => writeln!(out, "registration FAILED: {reason:?}")?,
    }
    writeln!(out, "target_from_source:")?;
    for row in matrix_rows(&r.target_from_source) {
        writeln!(
            out,
            "  {:>12.6} {:>12.6} {:>12.6} {:>12.6}",
            row[0], row[1], row[2], row[3]
        )?;
    }
    writeln!(
        out,
        "points {} / {} (downsampled {} / {}), correspondences {}, inliers {}",
        r.num_points[0],
        r.num_points[1],
        r.num_points_downsampled[0],
        r.num_points_downsampled[1],
        r.num_correspondences,
        r.num_inliers
    )?;
    writeln!(
        out,
        "hypotheses {} (pre-rejected {}, best first found at {}), converged {}",
        r.hypotheses,
        r.prerejected,
        r.best_found_at.map_or("-".into(), |h| h.to_string()),
        r.converged
    )?;
    writeln!(
        out,
        "fitness {:.4}, inlier RMSE {:.4} m, ICP iterations {}",
        r.fitness, r.inlier_rmse_m, r.icp_iterations
    )?;
    let t = &r.timings_s;
    writeln!(
        out,
        "time {:.3} s (downsample {:.3}, normals {:.3}, features {:.3}, matching {:.3}, ranking {:.3}, ransac {:.3}, icp {:.3})",
        t.total, t.downsample, t.normals, t.features, t.matching, t.ranking, t.ransac, t.icp
    )?;
    if let Some((rot, trans)) = errors {
        writeln!(
            out,
            "error vs ground truth: rotation {rot:.3} deg, translation {trans:.4} m"
        )?;
    }
    Ok(())
}
