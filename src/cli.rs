//! Command-line interface: clap arguments → library calls. No algorithm lives here.

use std::io::Write;

use anyhow::{Context, Result};
use clap::{Args, Parser, Subcommand};

use std::path::{Path, PathBuf};

use clap::ValueEnum;
use nalgebra::Isometry3;

use crate::correspondence::ranking::{CountOrder, PAPER_DESCRIPTOR_RADIUS};
use crate::io::{cloud_file, pose_file};
use crate::odometry::OdometryConfig;
use crate::pipeline::{
    PairConfig, PairResult, RankingConfig, SamplerConfig, Verification, pose_error, register_pair,
};
use crate::register::{RegisterOptions, RegisterSummary, default_output, register_log};
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
    /// Register consecutive point clouds of an MCAP log; write poses and statistics to a new MCAP.
    Register(RegisterArgs),
    /// Compare the estimated trajectory of a `register` output with a reference (ATE, RPE, drift).
    Evaluate(crate::cli_eval::EvaluateArgs),
    /// Write the estimated trajectory of a `register` output as TUM or KITTI text.
    Export(crate::cli_eval::ExportArgs),
    /// List a log's channels and message counts, and the point cloud topic `register` reads.
    Info(crate::cli_log::InfoArgs),
    /// Join the outputs of overlapping `register --start/--end` segments into one output.
    Stitch(crate::cli_log::StitchArgs),
    /// The paper's registration experiment (Fig. 6): recall and precision per sampler, μ and
    /// ranking on frame pairs of a log with a reference trajectory.
    Sweep(crate::cli_sweep::SweepArgs),
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

/// Hypothesis verification on the command line ([`crate::pipeline::Verification`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum VerificationArg {
    /// Overlap of the whole feature clouds (Open3D's fitness).
    Dense,
    /// Correspondence inliers (the paper's count).
    Correspondences,
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

/// Registration flags shared by `pair` and `register`. Unset flags keep the value from
/// `--config` (TOML of [`PairConfig`]) or the documented default.
#[derive(Debug, Args, Default)]
pub struct RegistrationFlags {
    /// TOML file with any fields of the pairwise configuration (see docs/CONFIG.md).
    #[arg(long, value_name = "FILE")]
    pub config: Option<PathBuf>,
    /// Voxel size in metres; normal, feature, inlier and ICP radii derive from it [default: 0.05].
    #[arg(long)]
    pub voxel: Option<f64>,
    /// Hypothesis sampler [default: levy].
    #[arg(long, value_enum)]
    pub sampler: Option<SamplerArg>,
    /// Lévy location μ (< 0) [default: -50].
    #[arg(long, allow_hyphen_values = true)]
    pub mu: Option<f64>,
    /// Lévy scale c [default: 1].
    #[arg(long)]
    pub levy_c: Option<f64>,
    /// Lévy draws with replacement (the authors' behaviour).
    #[arg(long)]
    pub with_replacement: bool,
    /// Correspondence ranking [default: ratio].
    #[arg(long, value_enum)]
    pub ranking: Option<RankingArg>,
    /// Descriptor radius τ_d for the count rankings, in FPFH units [default: 12].
    #[arg(long)]
    pub descriptor_radius: Option<f32>,
    /// Keep only mutual nearest neighbours in feature space.
    #[arg(long)]
    pub mutual: bool,
    /// Cap on RANSAC hypotheses [default: 200000; Open3D's is 100000].
    #[arg(long)]
    pub max_hypotheses: Option<u64>,
    /// What RANSAC hypotheses are scored against [default: dense].
    #[arg(long, value_enum)]
    pub verification: Option<VerificationArg>,
    /// Skip ICP refinement.
    #[arg(long)]
    pub no_icp: bool,
    /// Seed of all randomness [default: 0].
    #[arg(long)]
    pub seed: Option<u64>,
}

impl RegistrationFlags {
    /// Whether the voxel was given, by `--voxel` or as `voxel_size_m` in the `--config` file.
    pub fn voxel_configured(&self) -> Result<bool> {
        if self.voxel.is_some() {
            return Ok(true);
        }
        let Some(path) = &self.config else {
            return Ok(false);
        };
        let text =
            std::fs::read_to_string(path).with_context(|| format!("reading {}", path.display()))?;
        let table: toml::Table = toml::from_str(&text)
            .with_context(|| format!("{}: invalid configuration", path.display()))?;
        Ok(table.contains_key("voxel_size_m"))
    }

    /// The configuration: defaults, then `--config`, then explicit flags.
    pub fn config(&self) -> Result<PairConfig> {
        let mut c = match &self.config {
            Some(path) => {
                let text = std::fs::read_to_string(path)
                    .with_context(|| format!("reading {}", path.display()))?;
                toml::from_str::<PairConfig>(&text)
                    .with_context(|| format!("{}: invalid configuration", path.display()))?
            }
            None => PairConfig::default(),
        };
        if let Some(v) = self.voxel {
            c.voxel_size_m = v;
        }
        if self.mutual {
            c.mutual_filter = true;
        }
        if let Some(r) = self.ranking {
            let radius = self.descriptor_radius.unwrap_or(match c.ranking {
                RankingConfig::NeighbourCount { radius, .. } => radius,
                _ => PAPER_DESCRIPTOR_RADIUS as f32,
            });
            c.ranking = match r {
                RankingArg::Ratio => RankingConfig::Ratio,
                RankingArg::Distance => RankingConfig::Distance,
                RankingArg::CountMost => RankingConfig::NeighbourCount {
                    radius,
                    order: CountOrder::MostFirst,
                },
                RankingArg::CountFewest => RankingConfig::NeighbourCount {
                    radius,
                    order: CountOrder::FewestFirst,
                },
            };
        } else if let (Some(d), RankingConfig::NeighbourCount { radius, .. }) =
            (self.descriptor_radius, &mut c.ranking)
        {
            *radius = d;
        }
        let (mut mu, mut levy_c, window, mut repl) = match c.sampler {
            SamplerConfig::Levy {
                mu,
                c,
                window,
                with_replacement,
            } => (mu, c, window, with_replacement),
            _ => (-50.0, 1.0, crate::ransac::levy::DEFAULT_WINDOW, false),
        };
        mu = self.mu.unwrap_or(mu);
        levy_c = self.levy_c.unwrap_or(levy_c);
        repl |= self.with_replacement;
        let levy = SamplerConfig::Levy {
            mu,
            c: levy_c,
            window,
            with_replacement: repl,
        };
        c.sampler = match self.sampler {
            Some(SamplerArg::Uniform) => SamplerConfig::Uniform,
            Some(SamplerArg::Prosac) => SamplerConfig::Prosac {
                growth_max_samples: crate::ransac::prosac::DEFAULT_GROWTH_MAX_SAMPLES,
            },
            Some(SamplerArg::Levy) => levy,
            None if matches!(c.sampler, SamplerConfig::Levy { .. }) => levy,
            None => c.sampler,
        };
        if let Some(m) = self.max_hypotheses {
            c.max_hypotheses = m;
        }
        if let Some(v) = self.verification {
            c.verification = match v {
                VerificationArg::Dense => Verification::Dense,
                VerificationArg::Correspondences => Verification::Correspondences,
            };
        }
        if self.no_icp {
            c.icp = false;
        }
        if let Some(seed) = self.seed {
            c.seed = seed;
        }
        c.resolved().context("invalid configuration")?;
        Ok(c)
    }
}

/// Arguments of `mireg pair`.
#[derive(Debug, Args)]
pub struct PairArgs {
    /// Source cloud (.ply, .pcd, .npy, KITTI .bin).
    pub source: PathBuf,
    /// Target cloud; the result maps source points into its frame.
    pub target: PathBuf,
    /// Registration settings.
    #[command(flatten)]
    pub flags: RegistrationFlags,
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

/// Arguments of `mireg register`.
#[derive(Debug, Args)]
pub struct RegisterArgs {
    /// Input MCAP log (never modified).
    pub input: PathBuf,
    /// Output MCAP [default: INPUT's name with .mireg.mcap, next to it].
    #[arg(short, long)]
    pub output: Option<PathBuf>,
    /// Point cloud topic [default: the only sensor_msgs/msg/PointCloud2 topic].
    #[arg(long)]
    pub topic: Option<String>,
    /// Registration settings.
    #[command(flatten)]
    pub flags: RegistrationFlags,
    /// A registration with fewer RANSAC inliers is flagged as failed.
    #[arg(long, default_value_t = OdometryConfig::default().min_inliers)]
    pub min_inliers: usize,
    /// A registration with lower ICP fitness is flagged as failed.
    #[arg(long, default_value_t = OdometryConfig::default().min_fitness, value_parser = parse_fraction)]
    pub min_fitness: f64,
    /// Register each frame to the previous one only: no refinement against a local map of
    /// recent frames (chains frame-to-frame estimates; drifts more on long logs).
    #[arg(long)]
    pub no_local_map: bool,
    /// Skip the map ICP's last stage on each frame's own input points (on by default:
    /// docs/ODOMETRY.md has what it gains, 0.1–0.3 cm of ATE on the KAIST03 and ICL-NUIM logs,
    /// and costs, about 10 % of the frame rate).
    #[arg(long, conflicts_with = "map_fine")]
    pub no_map_fine: bool,
    /// The map ICP's last stage on each frame's own input points: the default (kept so that
    /// scripts written when it was opt-in still run).
    #[arg(long)]
    pub map_fine: bool,
    /// Motion-compensate clouds with per-point times (Ouster t, Velodyne time, Hesai timestamp,
    /// Livox offset_time, time_stamp): auto when the field is present, on (required), off.
    #[arg(long, value_enum, default_value_t = crate::register::DeskewMode::Auto)]
    pub deskew: crate::register::DeskewMode,
    /// Message family of our /tf and pose channels: auto (the clouds' own: ROS 2, ROS 1 or
    /// foxglove), or one of them. Rerun decodes ROS 2 and foxglove messages, not ROS 1: pass
    /// foxglove for a ROS 1 log you open in Rerun.
    #[arg(long, value_enum, default_value_t = crate::register::OutputMessages::Auto)]
    pub output_messages: crate::register::OutputMessages,
    /// Register only the clouds from this one on: a cloud index (120, 0-based in log-time
    /// order), or a log time in seconds (1700000012.5s) or nanoseconds (…ns). The segment's
    /// first frame is its world.
    #[arg(long, value_name = "BOUND")]
    pub start: Option<crate::register::WindowBound>,
    /// Register only the clouds before this one (exclusive), same forms as --start.
    #[arg(long, value_name = "BOUND")]
    pub end: Option<crate::register::WindowBound>,
    /// Copy only the input messages whose log time lies in the --start/--end segment, instead
    /// of the whole log.
    #[arg(long)]
    pub copy_window: bool,
    /// Points kept per voxel of the local map (its voxel is the ICP voxel).
    #[arg(long, value_name = "N", default_value_t = OdometryConfig::default().map_max_points_per_voxel)]
    pub map_points_per_voxel: usize,
    /// Global registration (descriptors, matching, RANSAC) runs on a coarser cloud of at most
    /// N points when the first frame's voxel cloud has more; ICP and the local map keep the
    /// voxel cloud. 0: everything on the voxel cloud.
    #[arg(long, value_name = "N", default_value_t = OdometryConfig::default().feature_points)]
    pub feature_points: usize,
    /// Name of the world frame (the first cloud's sensor frame) in /tf and /mireg/pose.
    #[arg(long, default_value = "world")]
    pub world_frame: String,
    /// A cloud with more points is flagged (too_many_points) instead of registered.
    #[arg(long, value_name = "N", default_value_t = crate::register::DEFAULT_MAX_POINTS_PER_CLOUD)]
    pub max_points: usize,
    /// Clouds held at most to restore log-time order in a log whose chunk index does not prove
    /// its order; a cloud later out of order than this is an error.
    #[arg(long, value_name = "N", default_value_t = crate::register::REORDER_WINDOW)]
    pub reorder_window: usize,
    /// Replace an existing output file.
    #[arg(long)]
    pub force: bool,
    /// No progress bar, no summary.
    #[arg(short, long)]
    pub quiet: bool,
    /// Print the summary as JSON on stdout.
    #[arg(long)]
    pub json: bool,
}

/// A number in [0, 1] (NaN is refused: it would disable the check it sets).
fn parse_fraction(s: &str) -> std::result::Result<f64, String> {
    let v: f64 = s.trim().parse().map_err(|e| format!("{s:?}: {e}"))?;
    if (0.0..=1.0).contains(&v) {
        Ok(v)
    } else {
        Err(format!("{s:?} is not a fraction in [0, 1]"))
    }
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

/// The error and its causes on one line, `outer: inner: …`, each said once: a cause whose text
/// the line already ends with (an I/O error that its wrapper prints too) is left out.
pub fn error_text(e: &anyhow::Error) -> String {
    let mut text = e.to_string();
    for cause in e.chain().skip(1) {
        let c = cause.to_string();
        if !text.ends_with(&c) {
            text.push_str(": ");
            text.push_str(&c);
        }
    }
    text
}

/// Runs the parsed command line.
pub fn run(cli: Cli) -> Result<()> {
    // Ctrl-C and SIGTERM end a run at once, leaving no partial output behind.
    crate::io::atomic_file::install_signal_handlers();
    match cli.command {
        Some(Command::Simulate(args)) => run_simulate(&args),
        Some(Command::Pair(args)) => run_pair(&args),
        Some(Command::Register(args)) => run_register(&args),
        Some(Command::Evaluate(args)) => crate::cli_eval::run_evaluate(&args),
        Some(Command::Export(args)) => crate::cli_eval::run_export(&args),
        Some(Command::Info(args)) => crate::cli_log::run_info(&args),
        Some(Command::Stitch(args)) => crate::cli_log::run_stitch(&args),
        Some(Command::Sweep(args)) => crate::cli_sweep::run_sweep(&args),
        None => run_default(),
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
    crate::heap::keep_freed_memory();
    let config = args.flags.config()?;
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
    match result.failure {
        None => Ok(()),
        Some(reason) => Err(RegistrationFailed(reason.as_str().to_string()).into()),
    }
}

/// `mireg pair` ran but its registration failed the checks (the result was still printed):
/// exit code 1, where errors exit 2.
#[derive(Debug, thiserror::Error)]
#[error("registration failed: {0}")]
pub struct RegistrationFailed(pub String);

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

/// The command line as typed, recorded in outputs' metadata.
pub(crate) fn command_line() -> String {
    std::env::args().collect::<Vec<_>>().join(" ")
}

fn run_register(args: &RegisterArgs) -> Result<()> {
    crate::heap::release_large_blocks_promptly();
    let config = OdometryConfig {
        pair: args.flags.config()?,
        min_inliers: args.min_inliers,
        min_fitness: args.min_fitness,
        local_map: !args.no_local_map,
        map_fine: !args.no_map_fine,
        map_max_points_per_voxel: args.map_points_per_voxel,
        feature_points: args.feature_points,
    };
    let opts = RegisterOptions {
        input: args.input.clone(),
        output: args
            .output
            .clone()
            .unwrap_or_else(|| default_output(&args.input)),
        topic: args.topic.clone(),
        config,
        force: args.force,
        world_frame: args.world_frame.clone(),
        command_line: command_line(),
        progress: !args.quiet,
        max_points_per_cloud: args.max_points,
        reorder_window: args.reorder_window,
        derive_voxel: !args.flags.voxel_configured()?,
        deskew: args.deskew,
        output_messages: args.output_messages,
        start: args.start,
        end: args.end,
        copy_window_only: args.copy_window,
    };
    if opts.copy_window_only && opts.start.is_none() && opts.end.is_none() {
        return Err(crate::Error::InvalidInput(
            "--copy-window needs a segment: --start and/or --end".into(),
        )
        .into());
    }
    let summary = register_log(&opts)?;
    if args.json {
        println!("{}", serde_json::to_string_pretty(&summary)?);
    } else if !args.quiet {
        print_summary(&summary);
    }
    Ok(())
}

/// The embedded default fixture: ICL-NUIM livingroom1 as a ROS 2 MCAP (CC BY 3.0).
pub const DEFAULT_FIXTURE: &str = "fixtures/icl_livingroom1.mcap";

/// `mireg` with no arguments: registers the embedded fixture into a temporary directory and
/// prints a summary.
fn run_default() -> Result<()> {
    crate::heap::release_large_blocks_promptly();
    let local = PathBuf::from(DEFAULT_FIXTURE);
    let input = if local.is_file() {
        local
    } else {
        Path::new(env!("CARGO_MANIFEST_DIR")).join(DEFAULT_FIXTURE)
    };
    let dir = tempfile::tempdir().context("creating a temporary directory")?;
    let output = dir.path().join("icl_livingroom1.mireg.mcap");
    eprintln!(
        "mireg: no arguments: registering the embedded fixture {} (see `mireg --help`)",
        input.display()
    );
    let opts = RegisterOptions {
        command_line: command_line(),
        progress: true,
        derive_voxel: true,
        ..RegisterOptions::new(&input, &output, OdometryConfig::default())
    };
    let summary = register_log(&opts)?;
    print_summary(&summary);
    println!(
        "(output was written to a temporary directory and removed; run `mireg register {DEFAULT_FIXTURE}` to keep it)"
    );
    Ok(())
}

fn print_summary(s: &RegisterSummary) {
    println!(
        "registered {} frames of {} -> {}",
        s.frames,
        s.topic,
        s.output.display()
    );
    let source = match s.voxel_source {
        "first_cloud" => "from the first cloud's median range; --voxel sets it",
        _ => "configured",
    };
    println!("voxel {:.3} m ({source})", s.voxel_m);
    if s.feature_voxel_m != s.voxel_m {
        println!(
            "global registration on a {:.3} m voxel cloud (at most {} points in the first frame; --feature-points sets it)",
            s.feature_voxel_m, s.feature_points
        );
    }
    println!(
        "failed frames {} ({:.1} %), mean inliers {:.1}, {:.2} frames/s ({:.2} s), {} input messages copied, poses on {} and {}",
        s.failed_frames,
        100.0 * s.failed_frames as f64 / s.frames.max(1) as f64,
        s.mean_inliers,
        s.frames_per_s,
        s.elapsed_s,
        s.messages_copied,
        s.tf_topic,
        s.pose_topic
    );
    if let Some(r) = &s.reference {
        println!(
            "vs {} ({} frames): ATE RMSE {:.4} m, RPE mean {:.4} m / {:.3} deg per frame",
            r.topic, r.frames, r.ate_rmse_m, r.rpe_trans_mean_m, r.rpe_rot_mean_deg
        );
    }
}
