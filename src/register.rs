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
mod options;
mod output;
mod plan;
mod prepare;
mod reader;
mod registrar;
mod settings;
mod stitch;
mod summary;
mod window;
mod writer;

use closure::KeyframeCache;
pub use closure::LoopSummary;
pub(crate) use closure::{KeptKeyframes, loop_pair_config};
pub(crate) use clouds::CloudKind;
pub use clouds::{for_each_cloud, for_each_cloud_where, point_cloud_topic};
pub use options::{
    DEFAULT_MAX_POINTS_PER_CLOUD, DEFAULT_REFERENCE_TOPIC, DeskewMode, OnFrame, OutputMessages,
    QUEUE_CAPACITY, REORDER_WINDOW, REORDER_WINDOW_BYTES, RegisterOptions, default_output,
};
use output::Outputs;
pub(crate) use output::{
    StampedPose, encode_pose, pose_channels, relative_pose_json, relative_pose_schema,
};
pub use output::{loops_json_schema, stats_json_schema};
use plan::Plan;
use prepare::{Prepare, TimeTally};
pub use settings::RegisterSettings;
pub use stitch::{Seam, StitchSummary, stitch};
pub(crate) use stitch::{SegFrame, Segment, read_segment};
pub use summary::{
    DOMINANT_MIN_STEPS, DOMINANT_SHARE, DominantStep, FLAGGED_FRAMES_LISTED, Flag, FlaggedFrame,
    ReferenceErrors, RegisterSummary, StepError,
};
pub use window::{LogWindow, WindowBound};
use writer::Writer;

use std::sync::mpsc::sync_channel;
use std::time::Instant;

use crate::Result;
use crate::io::atomic_file::{check_not_an_input, check_target};
use crate::io::mcap::log::OutputLog;
use crate::loops::LoopConfig;
use crate::odometry::Odometry;

/// Runs the whole job: the stages `plan.rs` → `reader.rs` → `prepare.rs` → `registrar.rs` →
/// `writer.rs`, then loop closure (`closure.rs`) over the whole trajectory (docs/ARCHITECTURE.md).
/// On any error the output path is left untouched.
pub fn register_log(opts: &RegisterOptions) -> Result<RegisterSummary> {
    register_log_keeping_keyframes(opts, false).map(|(summary, _)| summary)
}

/// [`register_log`]; with `keep_keyframes` and loop closure off, also the keyframes' frames
/// the odometry prepared, kept as loop closure keeps them (within its memory budget).
pub(crate) fn register_log_keeping_keyframes(
    opts: &RegisterOptions,
    keep_keyframes: bool,
) -> Result<(RegisterSummary, Option<KeptKeyframes>)> {
    let start = Instant::now();
    check_not_an_input(&opts.output, [opts.input.as_path()], "the input")?;
    // Before the input is opened: a missing folder or an existing output fails at once.
    check_target(&opts.output, opts.force)?;
    let plan = Plan::new(opts)?;
    let mut odometry = Odometry::new(plan.config.clone())?;
    let (mut log, mut writer) = open_output(opts, &plan)?;
    let loop_config = loop_config(opts, plan.voxel_m);
    let (copied, cached, times) = run_stages(
        opts,
        &plan,
        &mut odometry,
        &mut log,
        &mut writer,
        &loop_config,
        keep_keyframes,
    )?;
    let cached = cached.map(KeyframeCache::into_frames).unwrap_or_default();
    let (loops, kept) = if opts.loops {
        let loops = close_loops(&plan, opts, &writer.estimates, loop_config, cached);
        (loops, None)
    } else {
        let kept = keep_keyframes.then(|| KeptKeyframes {
            loops: loop_config,
            pair: closure::loop_pair_config(&plan.config.pair, &loop_config),
            frames: cached,
        });
        (None, kept)
    };
    let topic = plan.topic.clone();
    let summary = writer.finish(log, plan, opts, copied, start, loops)?;
    // On stderr, even with --quiet or --json: points were dropped or clouds left skewed.
    times.warn(&opts.input, &topic);
    Ok((summary, kept))
}

/// The output log, created (unnamed until complete) with the input's schemas and channels and
/// this run's, and the writer of this run's messages.
fn open_output<'a>(opts: &'a RegisterOptions, plan: &Plan) -> Result<(OutputLog, Writer<'a>)> {
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
    Ok((log, writer))
}

/// Loop closure's settings: [`RegisterOptions::loop_config`], else those for the run's voxel
/// (`voxel_m`, metres), with [`RegisterOptions::loop_memory_bytes`] as the memory budget.
fn loop_config(opts: &RegisterOptions, voxel_m: f64) -> LoopConfig {
    let mut loop_config = opts
        .loop_config
        .unwrap_or_else(|| LoopConfig::for_voxel(voxel_m));
    if let Some(bytes) = opts.loop_memory_bytes {
        loop_config.memory_budget_bytes = bytes;
    }
    loop_config
}

/// The streaming stages: the reader and the writer on the calling thread, prepare and register
/// on a thread each, bounded queues between them. Returns the input records copied, the
/// keyframes the odometry kept for loop closure (when it keeps them: with loop closure, or
/// `keep_keyframes`) and the clouds whose point times were unusable.
fn run_stages(
    opts: &RegisterOptions,
    plan: &Plan,
    odometry: &mut Odometry,
    log: &mut OutputLog,
    writer: &mut Writer,
    loop_config: &LoopConfig,
    keep_keyframes: bool,
) -> Result<(u64, Option<KeyframeCache>, TimeTally)> {
    let prepare = Prepare {
        plan,
        input: &opts.input,
        max_points: opts.max_points_per_cloud,
        deskew_mode: opts.deskew,
    };
    std::thread::scope(|scope| -> Result<_> {
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
        let keep = (opts.loops || keep_keyframes) && loop_config.keep_odometry_frames;
        let cache = (opts.loops || keep).then(|| KeyframeCache::new(loop_config, keep));
        let describe = opts.loops;
        let registrar = scope
            .spawn(move || registrar::run(odometry, (prep_rx, out_tx, motion_tx), cache, describe));
        let read = reader::read(plan, opts, log, writer, cloud_tx, recycle_rx, &out_rx);
        let copied = writer.drain(log, out_rx, read)?;
        let cached = registrar
            .join()
            .expect("the registering thread does not panic");
        let times = preparing
            .join()
            .expect("the preparing thread does not panic");
        Ok((copied, cached, times))
    })
}

/// Loop closure over the written odometry (`estimates`), with the frames the odometry kept
/// (`cached`); a loop closure that fails costs the loops, not the run (a warning, `None`).
fn close_loops(
    plan: &Plan,
    opts: &RegisterOptions,
    estimates: &[frames::Estimate],
    config: LoopConfig,
    cached: std::collections::BTreeMap<usize, crate::pipeline::PreparedFrame>,
) -> Option<(closure::LoopOutcome, LoopConfig)> {
    // The odometry is written: a loop closure that fails costs the loops, not the run.
    match closure::close_loops(plan, opts, estimates, &config, cached, &[]) {
        Ok(outcome) => Some((outcome, config)),
        Err(e) => {
            eprintln!(
                "mireg: warning: loop closure failed ({e}); {} has the odometry only",
                opts.output.display()
            );
            None
        }
    }
}
