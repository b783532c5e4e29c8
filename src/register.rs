//! `mireg register`: MCAP log in, MCAP log out. The one module that joins file I/O to the pure
//! algorithms ([`crate::odometry`]).
//!
//! The stages, each in its own file: `plan.rs` opens the input and settles the run; then three
//! overlap, connected by bounded queues: the calling thread streams records (`reader.rs`, copying
//! each into the output, and `writer.rs`, putting out each registered frame), a *prepare* thread
//! (`prepare.rs`) decodes, downsamples and computes features for frame `k + 1` while a *register*
//! thread (`registrar.rs`) registers frame `k` against the local map. The stages hold one chunk
//! plus the queue capacity, whatever the log length; each frame's `Estimate` (`frames.rs`, under
//! 1 kB) is kept for the summary and loop closure (docs/ARCHITECTURE.md).

mod closure;
mod clouds;
mod frames;
mod motions;
mod output;
mod plan;
mod prepare;
mod reader;
mod registrar;
mod stitch;
mod window;
mod writer;

use closure::KeyframeCache;
pub use closure::LoopSummary;
pub(crate) use closure::loop_pair_config;
pub(crate) use clouds::CloudKind;
pub use clouds::{for_each_cloud, point_cloud_topic};
pub use motions::{DeskewMode, OutputMessages};
use output::Outputs;
pub(crate) use output::{StampedPose, encode_pose, pose_channels};
pub use output::{loops_json_schema, stats_json_schema};
use plan::Plan;
use prepare::Prepare;
pub use stitch::{Seam, StitchSummary, stitch};
pub(crate) use stitch::{Segment, read_segment};
pub use window::{LogWindow, WindowBound};
use writer::Writer;

use std::path::{Path, PathBuf};
use std::sync::mpsc::sync_channel;
use std::time::Instant;

use crate::io::atomic_file::{check_target, same_file};
use crate::io::codec::livox::LivoxTags;
use crate::io::damage::{Damage, ReadPolicy};
use crate::io::mcap::log::OutputLog;
use crate::loops::LoopConfig;
use crate::odometry::{Odometry, OdometryConfig};
use crate::{Error, Result};

/// Frames in flight between stages (each queue). Bounds memory.
pub const QUEUE_CAPACITY: usize = 2;
/// Default of [`RegisterOptions::reorder_window`]: 16 clouds.
pub const REORDER_WINDOW: usize = 16;
/// Most bytes of cloud messages the reorder window holds \[bytes\]: 128 MiB (16 clouds of a
/// 64-beam LiDAR; 10 of an Ouster OS1-128). Past it the earliest cloud is handed on as if the
/// window were full, so that clouds of hostile size (a decompression bomb) cannot pile up.
pub const REORDER_WINDOW_BYTES: usize = 128 << 20;

/// Topic of the reference poses used for the summary, when the log has one.
pub const DEFAULT_REFERENCE_TOPIC: &str = "/ground_truth/pose";

/// Everything `mireg register` needs.
#[derive(Debug, Clone)]
pub struct RegisterOptions {
    /// Input log (never modified): an MCAP file, a ROS 1 bag, or a ROS 2 bag directory.
    pub input: PathBuf,
    /// Output MCAP.
    pub output: PathBuf,
    /// Point cloud topic; `None` auto-detects the single one.
    pub topic: Option<String>,
    /// Registration settings.
    pub config: OdometryConfig,
    /// Replace an existing output.
    pub force: bool,
    /// Name of the world frame in `/tf` and `/mireg/pose` (the first cloud's sensor frame).
    pub world_frame: String,
    /// The command line, recorded in the output's metadata.
    pub command_line: String,
    /// Show a progress bar on stderr (only drawn when stderr is a terminal).
    pub progress: bool,
    /// A cloud with more points is not registered but flagged (`too_many_points`), so that one
    /// huge message cannot take the run's memory and time. Default
    /// [`DEFAULT_MAX_POINTS_PER_CLOUD`].
    pub max_points_per_cloud: usize,
    /// Cloud messages held at most to restore log-time order when the file's chunk index does not
    /// prove its order ([`crate::io::log_order::Reorder`]); a file whose chunks are time-ordered holds only its current
    /// chunk's clouds. A cloud that arrives after a later one was registered is an error naming
    /// both log times. Default [`REORDER_WINDOW`].
    pub reorder_window: usize,
    /// Derive the voxel from the first cloud ([`crate::pipeline::voxel_for_cloud`]) instead of using
    /// `config.pair.voxel_size_m` (`mireg register` without `--voxel` or a configured voxel).
    /// Default `false`.
    pub derive_voxel: bool,
    /// Whether clouds with per-point times are motion-compensated. Default
    /// [`DeskewMode::Auto`].
    pub deskew: DeskewMode,
    /// The message family of our `/tf` and pose channels. Default [`OutputMessages::Auto`]
    /// (the clouds' family).
    pub output_messages: OutputMessages,
    /// First cloud of the segment to register (`--start`); `None`: the log's first. The
    /// segment's first frame is its world. Default `None`.
    pub start: Option<WindowBound>,
    /// First cloud after the segment (`--end`, exclusive); `None`: to the end. Default `None`.
    pub end: Option<WindowBound>,
    /// Copy only the input messages whose log time lies in the segment (`--copy-window`),
    /// instead of the whole log. Default `false`.
    pub copy_window_only: bool,
    /// Close loops after the odometry (`closure.rs`): `/mireg/loops`, `/mireg/pose_optimized`
    /// and its `/tf` variant. Default `true` (`--no-loops` turns it off).
    pub loops: bool,
    /// Loop-closure settings; `None`: [`LoopConfig::for_voxel`] of the run's voxel. Default
    /// `None`.
    pub loop_config: Option<LoopConfig>,
    /// Replaces the loop configuration's [`LoopConfig::memory_budget_bytes`] (`--loop-memory`)
    /// \[bytes\]. Default `None`.
    pub loop_memory_bytes: Option<usize>,
    /// How a damaged input is treated (`--strict`, `--skip-corrupt`). Default: a log cut short
    /// is read up to its last whole message, a corrupt chunk is an error.
    pub read_policy: ReadPolicy,
    /// Which Livox `CustomMsg` points are kept, by their tag (`--livox-tags`). Default
    /// [`LivoxTags::DropNoise`]; no effect on other clouds.
    pub livox_tags: LivoxTags,
    /// Called after each frame is written. Default `None`.
    pub on_frame: Option<OnFrame>,
}

/// A callback `register` calls after writing each frame with (frames written so far, clouds
/// the log holds by its summary or index, 0 when unknown), from the writing thread: for a
/// progress display of the caller's own (the Python package's `register_log`).
#[derive(Clone)]
pub struct OnFrame(pub std::sync::Arc<dyn Fn(u64, u64) + Send + Sync>);

impl std::fmt::Debug for OnFrame {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str("OnFrame(..)")
    }
}

impl RegisterOptions {
    /// `input` registered into `output` with `config`; the other fields at their defaults: the
    /// cloud topic auto-detected, no `--force`, world frame `world`, no command line, no progress
    /// bar, [`DEFAULT_MAX_POINTS_PER_CLOUD`], [`REORDER_WINDOW`].
    pub fn new(input: &Path, output: &Path, config: OdometryConfig) -> Self {
        Self {
            input: input.to_path_buf(),
            output: output.to_path_buf(),
            topic: None,
            config,
            force: false,
            world_frame: "world".into(),
            command_line: String::new(),
            progress: false,
            max_points_per_cloud: DEFAULT_MAX_POINTS_PER_CLOUD,
            reorder_window: REORDER_WINDOW,
            derive_voxel: false,
            deskew: DeskewMode::Auto,
            output_messages: OutputMessages::Auto,
            start: None,
            end: None,
            copy_window_only: false,
            loops: true,
            read_policy: ReadPolicy::default(),
            livox_tags: LivoxTags::default(),
            on_frame: None,
            loop_config: None,
            loop_memory_bytes: None,
        }
    }
}

/// Default bound on points per cloud: 4 000 000, 15× an Ouster OS1-128 scan (262 144 points) and
/// 4× a 1280×720 depth image; decoded, such a cloud takes 96 MB.
pub const DEFAULT_MAX_POINTS_PER_CLOUD: usize = 4_000_000;

/// Default output path: `NAME.mireg.mcap` next to `NAME.mcap`.
pub fn default_output(input: &Path) -> PathBuf {
    let stem = input
        .file_stem()
        .map(|s| s.to_string_lossy().into_owned())
        .unwrap_or_else(|| "out".into());
    input.with_file_name(format!("{stem}.mireg.mcap"))
}

/// Errors against the log's reference pose topic.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct ReferenceErrors {
    /// Topic the reference came from.
    pub topic: String,
    /// Frames with a reference pose at the same stamp.
    pub frames: usize,
    /// ATE RMSE after rigid alignment \[m\].
    pub ate_rmse_m: f64,
    /// Mean RPE translation per frame \[m\].
    pub rpe_trans_mean_m: f64,
    /// Mean RPE rotation per frame \[deg\].
    pub rpe_rot_mean_deg: f64,
    /// The one step that carries most of the relative error, when one does.
    pub dominant_step: Option<DominantStep>,
}

/// One step that carries most of a trajectory's relative error against the reference
/// ([`ReferenceErrors::dominant_step`]): more than [`DOMINANT_SHARE`] of the sum of the per-step
/// RPE translation (or rotation) over at least [`DOMINANT_MIN_STEPS`] steps. Such a step broke
/// the trajectory there (a wrong registration, a jump in the log), and the ATE mostly measures it.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct DominantStep {
    /// Frame index of the step's second frame (the step from the frame before it).
    pub frame: u64,
    /// Its header stamp \[ns\].
    pub stamp_ns: Option<i64>,
    /// Which error it dominates.
    pub error: StepError,
    /// Its RPE: \[m\] for translation, \[deg\] for rotation.
    pub value: f64,
    /// The sum of that RPE over every step, same unit.
    pub total: f64,
    /// `value / total`, in (0.5, 1].
    pub share: f64,
    /// Steps compared.
    pub steps: usize,
}

/// The part of a step's relative pose error ([`DominantStep::error`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "snake_case")]
pub enum StepError {
    /// RPE translation \[m\].
    Translation,
    /// RPE rotation \[deg\].
    Rotation,
}

/// A step is [`DominantStep`] when it carries more than this share of the summed RPE: 0.5 (most).
pub const DOMINANT_SHARE: f64 = 0.5;
/// Steps needed before one can be said to dominate: 3.
pub const DOMINANT_MIN_STEPS: usize = 3;

/// Flagged frames a summary lists, the first in frame order: 10 (the others are counted in
/// [`RegisterSummary::failed_frames`] and [`RegisterSummary::suspect_frames`]; every frame's
/// flags are in `/mireg/stats`).
pub const FLAGGED_FRAMES_LISTED: usize = 10;

/// How a frame was flagged ([`FlaggedFrame::flag`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Flag {
    /// Global registration failed; the pose came from the fallback.
    Failed,
    /// Registered, but doubtful (`suspect` in `/mireg/stats`).
    Suspect,
}

/// A frame flagged failed or suspect, as the summary names it.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct FlaggedFrame {
    /// Frame index (0-based, in log-time order).
    pub frame: usize,
    /// The cloud's header stamp \[ns\].
    pub stamp_ns: i64,
    /// Failed or suspect.
    pub flag: Flag,
    /// Why: `failure_reason` or `suspect` of `/mireg/stats` (`too_few_inliers`, `degenerate`, …).
    pub reason: &'static str,
}

/// What a run did.
#[derive(Debug, Clone, serde::Serialize)]
pub struct RegisterSummary {
    /// Output file.
    pub output: PathBuf,
    /// Cloud topic registered.
    pub topic: String,
    /// Topic our transforms went to.
    pub tf_topic: String,
    /// Topic of our poses (`/mireg/pose`; `/mireg_N/pose` when the input already had mireg
    /// topics).
    pub pose_topic: String,
    /// Frames processed.
    pub frames: usize,
    /// Frames whose global registration failed (flagged; pose from the fallback).
    pub failed_frames: usize,
    /// Registered frames flagged as doubtful (`suspect` in `/mireg/stats`).
    pub suspect_frames: usize,
    /// The first [`FLAGGED_FRAMES_LISTED`] failed or suspect frames, in frame order, with why.
    pub flagged: Vec<FlaggedFrame>,
    /// Mean RANSAC inliers over registered frames.
    pub mean_inliers: f64,
    /// Input messages copied.
    pub messages_copied: u64,
    /// Voxel used \[m\].
    pub voxel_m: f64,
    /// Where it came from: `"configured"` (flag or configuration) or `"first_cloud"`.
    pub voxel_source: &'static str,
    /// Voxel of the cloud global registration ran on \[m\] (the voxel itself, or coarser:
    /// [`OdometryConfig::feature_points`]).
    pub feature_voxel_m: f64,
    /// The bound on that cloud's points in the first frame (0: none).
    pub feature_points: usize,
    /// Wall-clock seconds for the whole run.
    pub elapsed_s: f64,
    /// Frames per second (wall clock).
    pub frames_per_s: f64,
    /// Errors against the reference pose topic, when the log has one (the odometry's).
    pub reference: Option<ReferenceErrors>,
    /// Topic of the optimised poses (`/mireg/pose_optimized`), when loop closure ran.
    pub pose_optimized_topic: Option<String>,
    /// What loop closure did, when it ran.
    pub loops: Option<LoopSummary>,
    /// The optimised trajectory's errors against the reference, when both exist.
    pub reference_optimized: Option<ReferenceErrors>,
    /// What was wrong with the input and read anyway (a cut-off log, skipped corrupt chunks);
    /// `None` when nothing was.
    pub input_damage: Option<Damage>,
}

/// Runs the whole job: the stages `plan.rs` → `reader.rs` → `prepare.rs` → `registrar.rs` →
/// `writer.rs`, then loop closure (`closure.rs`) over the whole trajectory (docs/ARCHITECTURE.md).
/// On any error the output path is left untouched.
pub fn register_log(opts: &RegisterOptions) -> Result<RegisterSummary> {
    let start = Instant::now();
    if same_file(&opts.input, &opts.output) {
        return Err(Error::InvalidInput(format!(
            "output {} is the input; mireg never writes over its input",
            opts.output.display()
        )));
    }
    // Before the input is opened: a missing folder or an existing output fails at once.
    check_target(&opts.output, opts.force)?;
    let plan = Plan::new(opts)?;
    let mut odometry = Odometry::new(plan.config.clone())?;
    let mut log = OutputLog::create(&opts.output, opts.force, plan.kind.profile())?;
    // The input's schemas and channels keep their ids (its chunks are copied as they are); ours
    // get ids above them.
    log.declare_input(&opts.input, &plan.catalog)?;
    let family = match opts.output_messages {
        OutputMessages::Auto => plan.kind.family(),
        OutputMessages::Ros2 => CloudKind::Ros2,
        OutputMessages::Ros1 => CloudKind::Ros1,
        OutputMessages::Foxglove => CloudKind::Foxglove,
    };
    let outputs = Outputs::create(
        &mut log,
        family,
        &plan.topics,
        opts.loops,
        Some(plan.voxel_m),
    )?;
    let mut writer = Writer::new(outputs, &opts.world_frame, opts.progress, plan.total_frames);
    writer.on_frame = opts.on_frame.clone();
    let prepare = Prepare {
        plan: &plan,
        input: &opts.input,
        max_points: opts.max_points_per_cloud,
        deskew_mode: opts.deskew,
        descriptors: opts.loops,
    };

    let mut loop_config = opts
        .loop_config
        .unwrap_or_else(|| LoopConfig::for_voxel(plan.voxel_m));
    if let Some(bytes) = opts.loop_memory_bytes {
        loop_config.memory_budget_bytes = bytes;
    }
    let (copied, cached, times) = std::thread::scope(|scope| -> Result<_> {
        let (cloud_tx, cloud_rx) = sync_channel(QUEUE_CAPACITY);
        let (prep_tx, prep_rx) = sync_channel(QUEUE_CAPACITY);
        // Unbounded: results are small (no point data), and the reading thread, which drains them,
        // may itself be blocked handing on a cloud; a bound here could close a cycle and deadlock.
        let (out_tx, out_rx) = std::sync::mpsc::channel();
        // Each registered frame's motion, back to the preparing thread for deskewing (unbounded:
        // one small message per frame, drained as frames are prepared).
        let (motion_tx, motion_rx) = std::sync::mpsc::channel();
        // Message buffers back from the preparing thread once decoded (`reader.rs`).
        let (recycle_tx, recycle_rx) = std::sync::mpsc::channel();
        let prepare = &prepare;
        let preparing = scope.spawn(move || prepare.run(cloud_rx, prep_tx, motion_rx, recycle_tx));
        let odometry = &mut odometry;
        let cache = (opts.loops && loop_config.keep_odometry_frames)
            .then(|| KeyframeCache::new(&loop_config));
        let registrar =
            scope.spawn(move || registrar::run(odometry, prep_rx, out_tx, motion_tx, cache));
        let read = reader::read(
            &plan,
            opts,
            &mut log,
            &mut writer,
            cloud_tx,
            recycle_rx,
            &out_rx,
        );
        let copied = writer.drain(&mut log, out_rx, read)?;
        let cached = registrar
            .join()
            .expect("the registering thread does not panic");
        let times = preparing
            .join()
            .expect("the preparing thread does not panic");
        Ok((copied, cached, times))
    })?;
    let loops = if opts.loops {
        let config = loop_config;
        let cached = cached.map(KeyframeCache::into_frames).unwrap_or_default();
        // The odometry is written: a loop closure that fails costs the loops, not the run.
        match closure::close_loops(&plan, opts, &writer.estimates, &config, cached, &[]) {
            Ok(outcome) => Some((outcome, config)),
            Err(e) => {
                eprintln!(
                    "mireg: warning: loop closure failed ({e}); {} has the odometry only",
                    opts.output.display()
                );
                None
            }
        }
    } else {
        None
    };
    let topic = plan.topic.clone();
    let summary = writer.finish(log, plan, opts, copied, start, loops)?;
    // On stderr, even with --quiet or --json: points were dropped or clouds left skewed.
    times.warn(&opts.input, &topic);
    Ok(summary)
}
