//! `mireg register` and `mireg` with no arguments (the embedded fixture).

use super::flags::{DeskewArg, LivoxTagsArg, OutputMessagesArg, RegistrationFlags};
use anyhow::{Context, Result};
use clap::Args;

use std::path::{Path, PathBuf};

use crate::odometry::OdometryConfig;
use crate::register::{
    FLAGGED_FRAMES_LISTED, Flag, RegisterOptions, RegisterSettings, RegisterSummary, StepError,
    register_log,
};

/// Help of `--voxel` in `mireg register`, whose default derives from the first cloud (`pair`
/// keeps [`crate::pipeline::PairConfig`]'s 0.05 m).
const REGISTER_VOXEL_HELP: &str = "Voxel size in metres; normal, feature, inlier and ICP radii \
     derive from it [default: the first cloud's median range / 40; the summary prints it]";

/// Arguments of `mireg register`.
#[derive(Debug, Args)]
#[command(mut_arg("voxel", |a| a.help(REGISTER_VOXEL_HELP)))]
pub struct RegisterArgs {
    /// Input log (never modified): an MCAP file, a ROS 1 bag (.bag), or a ROS 2 bag directory
    /// (or its metadata.yaml).
    pub input: PathBuf,
    /// Output MCAP [default: INPUT's name with .mireg.mcap, next to it].
    #[arg(short, long, value_name = "FILE")]
    pub output: Option<PathBuf>,
    /// Point cloud topic [default: the only point cloud topic: sensor_msgs PointCloud2,
    /// foxglove.PointCloud or Livox CustomMsg].
    #[arg(long)]
    pub topic: Option<String>,
    /// Registration settings.
    #[command(flatten)]
    pub flags: RegistrationFlags,
    /// A registration with fewer RANSAC inliers is flagged as failed.
    #[arg(long, default_value_t = OdometryConfig::default().min_inliers, value_name = "N")]
    pub min_inliers: usize,
    /// A registration with lower ICP fitness is flagged as failed.
    #[arg(long, default_value_t = OdometryConfig::default().min_fitness, value_parser = parse_fraction, value_name = "FRACTION")]
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
    /// Register every frame globally (features matched, MI-RANSAC), as the paper registers every
    /// pair. By default each frame is first refined on the local map from the constant-velocity
    /// prediction, and registered globally only where that fit is doubtful (below 0.9× the
    /// previous frame's map fitness, or weakly constrained in some direction);
    /// docs/ODOMETRY.md has the measured rates and ATE.
    #[arg(long, conflicts_with = "track_first")]
    pub global_every_frame: bool,
    /// Tracking first: the default (kept so that scripts written when it was opt-in still run).
    #[arg(long, hide = true)]
    pub track_first: bool,
    /// Motion-compensate clouds with per-point times (Ouster t, Velodyne time, Hesai timestamp,
    /// Livox offset_time, time_stamp): auto when the field is present, on (required), off.
    #[arg(long, value_enum, default_value_t = DeskewArg::Auto)]
    pub deskew: DeskewArg,
    /// Message family of our /tf and pose channels: auto (the clouds' own: ROS 2, ROS 1 or
    /// foxglove), or one of them. Rerun decodes ROS 2 and foxglove messages, not ROS 1: pass
    /// foxglove for a ROS 1 log you open in Rerun.
    #[arg(long, value_enum, default_value_t = OutputMessagesArg::Auto)]
    pub output_messages: OutputMessagesArg,
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
    #[arg(long, default_value = "world", value_name = "FRAME")]
    pub world_frame: String,
    /// A cloud with more points is flagged (too_many_points) instead of registered.
    #[arg(long, value_name = "N", default_value_t = crate::register::DEFAULT_MAX_POINTS_PER_CLOUD)]
    pub max_points: usize,
    /// Clouds held at most to restore log-time order in a log whose chunk index does not prove
    /// its order; a cloud later out of order than this is an error.
    #[arg(long, value_name = "N", default_value_t = crate::register::REORDER_WINDOW)]
    pub reorder_window: usize,
    /// Skip loop closure: no /mireg/loops, no /mireg/pose_optimized (the odometry alone, as
    /// /mireg/pose always is). On by default: candidates by place and appearance, verified by
    /// MI-RANSAC + ICP, then a robust pose graph (docs/LOOPS.md).
    #[arg(long)]
    pub no_loops: bool,
    /// Memory for loop verification's prepared frames, MiB: the keyframes kept from the
    /// odometry and the frames read again, by their size on the heap, and the search structures
    /// verification builds on them while they fit (beyond, dropped and rebuilt when used; one
    /// per thread at a time can exceed it). More keeps more keyframes
    /// and reads the log again less; 0 keeps none. A candidate verifies the same either way;
    /// which redundant candidates are skipped can change with the order frames come in.
    #[arg(long, value_name = "MIB", default_value_t = crate::loops::closure::DEFAULT_LOOP_MEMORY_BYTES >> 20)]
    pub loop_memory: usize,
    /// Refuse a log that was cut off (no footer or summary, a last record or chunk that stops
    /// short). By default such a log is read up to its last whole message, the messages of the
    /// chunk being written when it stopped included, and the summary says where it was cut
    /// (docs/INPUTS.md, "Damaged logs").
    #[arg(long)]
    pub strict: bool,
    /// Skip a chunk whose CRC does not match or that does not decompress (naming it in the
    /// summary and the output's metadata) instead of failing. Its messages are lost; the rest of
    /// the log is read.
    #[arg(long)]
    pub skip_corrupt: bool,
    /// Which points of a Livox `CustomMsg` log are kept, by their `tag` byte: `drop-noise` drops
    /// the points Livox tags as high- or moderate-confidence noise (rain, dust, fog, edge
    /// stray returns), `keep-all` keeps every point, `first-returns` keeps returns 0 and 1 as
    /// FAST-LIO does (docs/INPUTS.md, "Livox").
    #[arg(long, value_enum, default_value_t = LivoxTagsArg::DropNoise)]
    pub livox_tags: LivoxTagsArg,
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

impl RegisterArgs {
    /// The flags as library settings (all but `--output`, `--json` and the input).
    pub fn settings(&self) -> RegisterSettings {
        RegisterSettings {
            pair: self.flags.settings(),
            topic: self.topic.clone(),
            min_inliers: self.min_inliers,
            min_fitness: self.min_fitness,
            no_local_map: self.no_local_map,
            no_map_fine: self.no_map_fine,
            map_fine: self.map_fine,
            global_every_frame: self.global_every_frame,
            track_first: self.track_first,
            deskew: self.deskew.into(),
            output_messages: self.output_messages.into(),
            start: self.start,
            end: self.end,
            copy_window: self.copy_window,
            map_points_per_voxel: self.map_points_per_voxel,
            feature_points: self.feature_points,
            world_frame: self.world_frame.clone(),
            max_points: self.max_points,
            reorder_window: self.reorder_window,
            no_loops: self.no_loops,
            loop_memory: self.loop_memory,
            strict: self.strict,
            skip_corrupt: self.skip_corrupt,
            livox_tags: self.livox_tags.into(),
            force: self.force,
            quiet: self.quiet,
        }
    }
}

/// The [`RegisterOptions`] that `mireg register` runs with for `args`: its settings
/// ([`RegisterSettings::options`]) with this process's command line recorded.
///
/// # Errors
/// A configuration file that cannot be read or parsed, or `--copy-window` without a segment.
pub fn register_options(args: &RegisterArgs) -> Result<RegisterOptions> {
    // The configuration's range checks first, in the command line's words.
    args.flags.config()?;
    let mut opts = args
        .settings()
        .options(&args.input, args.output.as_deref())?;
    opts.command_line = super::process::command_line();
    Ok(opts)
}

pub(super) fn run_register(args: &RegisterArgs) -> Result<()> {
    crate::heap::release_large_blocks_promptly();
    let opts = register_options(args)?;
    let summary = register_log(&opts)?;
    if let Some(d) = &summary.input_damage {
        // On stderr, even with --quiet or --json: the user should know the log is damaged.
        eprintln!(
            "mireg: warning: {}: damaged, read anyway: {} (--strict refuses such a log)",
            opts.input.display(),
            d.describe()
        );
    }
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
pub(super) fn run_default() -> Result<()> {
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
        command_line: super::process::command_line(),
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
    // The first frame is neither tracked nor registered: it defines the world. Every other
    // frame not tracked tried global registration; the failed ones are among them.
    let tried = s.frames.saturating_sub(1 + s.tracked_frames);
    let global = tried.saturating_sub(s.failed_frames);
    let failed = match tried - global {
        0 => String::new(),
        n => format!(", {n} more tried and failed"),
    };
    if s.tracked_frames > 0 {
        println!(
            "tracked {} frames on the local map from the motion so far, registered {global} globally{failed} (MI-RANSAC, mean inliers {:.1}; --global-every-frame registers all)",
            s.tracked_frames, s.mean_inliers
        );
    } else {
        println!(
            "registered {global} frames globally{failed} (MI-RANSAC, mean inliers {:.1})",
            s.mean_inliers
        );
    }
    println!(
        "failed frames {} ({:.1} %), {:.2} frames/s ({:.2} s), {} input messages copied, poses on {} and {}",
        s.failed_frames,
        100.0 * s.failed_frames as f64 / s.frames.max(1) as f64,
        s.frames_per_s,
        s.elapsed_s,
        s.messages_copied,
        s.tf_topic,
        s.pose_topic
    );
    print_flagged(s);
    if let Some(l) = &s.loops {
        println!(
            "loops: {} keyframes, {} candidates tried ({} more skipped as redundant), {} accepted ({} already measured by the odometry's map, {} down-weighted by the pose graph), {:.2} s; optimised poses on {}",
            l.keyframes,
            l.candidates,
            l.redundant,
            l.accepted,
            l.held_by_map,
            l.down_weighted,
            l.elapsed_s,
            s.pose_optimized_topic.as_deref().unwrap_or("-")
        );
        if l.inconsistent > 0 || l.found_after_solve > 0 {
            println!(
                "loops: {} dropped as inconsistent with the other loops through the odometry (PCM); {} found by {} search{} from the optimised poses",
                l.inconsistent,
                l.found_after_solve,
                l.search_rounds,
                if l.search_rounds == 1 { "" } else { "es" }
            );
        }
        if l.passes > 0 {
            println!(
                "loops: {} keyframes kept from the odometry ({:.0} MB); the other candidates' frames read again in {} pass{} over the log (--loop-memory MIB sets the budget)",
                l.kept_frames,
                l.kept_bytes as f64 / 1e6,
                l.passes,
                if l.passes == 1 { "" } else { "es" }
            );
        }
    }
    for (what, r) in [
        ("odometry", &s.reference),
        ("optimised", &s.reference_optimized),
    ] {
        if let Some(r) = r {
            println!(
                "{what} vs {} ({} frames): ATE RMSE {:.4} m, RPE mean {:.4} m / {:.3} deg per frame",
                r.topic, r.frames, r.ate_rmse_m, r.rpe_trans_mean_m, r.rpe_rot_mean_deg
            );
            if let Some(d) = &r.dominant_step {
                let (error, unit) = match d.error {
                    StepError::Translation => ("translation", "m"),
                    StepError::Rotation => ("rotation", "deg"),
                };
                println!(
                    "{what}: warning: the step to frame {}{} carries {:.0} % of the {error} error \
                     ({:.4} {unit} of {:.4} {unit} summed over {} steps): estimate and reference part \
                     there (a wrong registration, or a jump in either), and the ATE mostly \
                     measures that one step",
                    d.frame,
                    d.stamp_ns
                        .map(|ns| format!(" (stamp {})", stamp_s(ns)))
                        .unwrap_or_default(),
                    100.0 * d.share,
                    d.value,
                    d.total,
                    d.steps
                );
            }
        }
    }
}

/// A stamp in nanoseconds as seconds with nine decimals.
fn stamp_s(ns: i64) -> String {
    let sign = if ns < 0 { "-" } else { "" };
    let abs = ns.unsigned_abs();
    format!("{sign}{}.{:09} s", abs / 1_000_000_000, abs % 1_000_000_000)
}

/// The failed and suspect frames, at most [`FLAGGED_FRAMES_LISTED`] of them by index, stamp and
/// reason, then how many more.
fn print_flagged(s: &RegisterSummary) {
    let flagged = s.failed_frames + s.suspect_frames;
    if flagged == 0 {
        return;
    }
    println!(
        "flagged frames ({} failed, {} suspect; each frame's flags in /mireg/stats):",
        s.failed_frames, s.suspect_frames
    );
    for f in &s.flagged {
        let flag = match f.flag {
            Flag::Failed => "failed",
            Flag::Suspect => "suspect",
        };
        println!(
            "  frame {} (stamp {}): {flag}, {}",
            f.frame,
            stamp_s(f.stamp_ns),
            f.reason
        );
    }
    if flagged > s.flagged.len() {
        println!(
            "  ... and {} more (the first {FLAGGED_FRAMES_LISTED} are listed)",
            flagged - s.flagged.len()
        );
    }
}
