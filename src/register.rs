//! `mireg register`: MCAP log in, MCAP log out. The one module that joins file I/O to the pure
//! algorithms ([`crate::odometry`]).
//!
//! Three stages overlap, connected by bounded queues: the calling thread streams records (copying
//! each into the output), a *prepare* thread decodes, downsamples and computes features for frame
//! `k + 1` while a *register* thread registers frame `k`. Memory is bounded by one chunk plus the
//! queue capacity, whatever the log length.

mod clouds;
mod motions;
mod output;
mod stitch;
mod window;

use clouds::{CloudKind, choose_topic};
pub use clouds::{for_each_cloud, point_cloud_topic};
use motions::Motions;
pub use motions::{DeskewMode, OutputMessages};
pub use output::stats_json_schema;
use output::{Outputs, Topics, write_frame};
pub use stitch::{Seam, StitchSummary, stitch};
pub use window::{LogWindow, WindowBound};

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::sync::mpsc::{Receiver, SyncSender, sync_channel};
use std::time::Instant;

use nalgebra::Isometry3;

use crate::geometry::deskew::deskew;
use crate::io::atomic_file::same_file;
use crate::io::codec::{self, pose_stamped_decoder};
use crate::io::input_log::InputLog;
use crate::io::log_order::Reorder;
use crate::io::mcap::log::{ChannelInfo, OutputLog};
use crate::odometry::{FrameEstimate, Odometry, OdometryConfig, keep_map_fine_points};
use crate::pipeline::{
    FailureReason, PrepareScratch, PreparedFrame, feature_voxel_for_cloud, prepare_frame,
    prepare_frame_with, voxel_for_cloud, with_feature_voxel,
};
use crate::trajectory::{Trajectory, evaluate};
use crate::{Error, Result};

/// Frames in flight between stages (each queue). Bounds memory.
pub const QUEUE_CAPACITY: usize = 2;
/// Cloud message buffers outside the reorder window: the queue to the preparing thread, and the
/// one it decodes.
const MESSAGE_BUFFERS: usize = QUEUE_CAPACITY + 1;
/// Default of [`RegisterOptions::reorder_window`]: 16 clouds.
pub const REORDER_WINDOW: usize = 16;
/// Frames between two returns of the allocator's free memory to the system
/// ([`crate::heap::trim`]), which keeps the peak RSS of a long log within a few percent of a short
/// one's (docs/BENCHMARKS.md).
const TRIM_EVERY_FRAMES: usize = 8;

/// Runs `f` on a worker of rayon's global pool, the calling thread waiting (`rayon::scope` from
/// outside the pool). Registering a frame is many short parallel loops (an ICP iteration each);
/// called from the registering thread, each loop was injected into the pool and woke the caller
/// when done, where from a worker the loops split among the workers directly. On the KAIST03
/// keyframes: 1 800–2 100 → 940–1 150 context switches per run (docs/BENCHMARKS.md).
///
/// NOTE: not for preparing frames: on the workers, that stage's buffers shared their malloc
/// arenas with registration's, and the peak RSS of 200 KITTI-size frames rose to 1.11–1.12 × that
/// of 20 (issue 11's bound: 1.10); preparing on its own thread, 1.067.
fn on_pool<R: Send>(f: impl FnOnce() -> R + Send) -> R {
    rayon::scope(|_| f())
}

/// Topic of the reference poses used for the summary, when the log has one.
pub const DEFAULT_REFERENCE_TOPIC: &str = "/ground_truth/pose";

/// Everything `mireg register` needs.
#[derive(Debug, Clone)]
pub struct RegisterOptions {
    /// Input MCAP (never modified).
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
    /// prove its order ([`Reorder`]); a file whose chunks are time-ordered holds only its current
    /// chunk's clouds. A cloud that arrives after a later one was registered is an error naming
    /// both log times. Default [`REORDER_WINDOW`].
    pub reorder_window: usize,
    /// Derive the voxel from the first cloud ([`voxel_for_cloud`]) instead of using
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
    /// Errors against the reference pose topic, when the log has one.
    pub reference: Option<ReferenceErrors>,
}

struct CloudMsg {
    log_time: u64,
    publish_time: u64,
    data: Vec<u8>,
}

struct PreparedMsg {
    /// Why the cloud could not be decoded or prepared (the frame is then empty and flagged).
    invalid: Option<(FailureReason, String)>,
    /// The cloud's time field, and whether its points were deskewed by it.
    time_field: Option<String>,
    deskewed: bool,
    /// Points dropped by the decoder: non-finite, and zero returns of an organised cloud.
    dropped: Dropped,
    log_time: u64,
    publish_time: u64,
    header: codec::Header,
    decode_s: f64,
    frame: PreparedFrame,
}

/// Points the decoder dropped from one cloud.
#[derive(Debug, Clone, Copy, Default)]
struct Dropped {
    non_finite: usize,
    zero: usize,
}

struct FrameOut {
    invalid: Option<(FailureReason, String)>,
    time_field: Option<String>,
    deskewed: bool,
    dropped: Dropped,
    log_time: u64,
    publish_time: u64,
    header: codec::Header,
    decode_s: f64,
    prep: crate::pipeline::FrameTimings,
    register_s: f64,
    est: FrameEstimate,
}

/// Why a cloud message could not be decoded, naming topic, log time and field.
fn decode_detail(topic: &str, log_time: u64, e: &codec::DecodeError) -> String {
    format!(
        "message on {topic} at log time {log_time} ns: field {}: {}",
        e.field, e.detail
    )
}

/// The header stamp given to a cloud that could not be decoded: its log time.
fn stamp_of_log_time(log_time: u64) -> codec::Time {
    i64::try_from(log_time)
        .ok()
        .and_then(codec::Time::from_ns)
        .unwrap_or_default()
}

/// The first cloud on `topic` that decodes to at least 3 finite, non-zero points (one that
/// [`voxel_for_cloud`] can size); `None` when none does.
fn first_usable_cloud(
    input: &InputLog,
    channels: &[ChannelInfo],
    topic: &str,
    kind: CloudKind,
) -> Result<Option<Vec<nalgebra::Point3<f64>>>> {
    use std::ops::ControlFlow::{Break, Continue};
    let ids: Vec<u16> = channels
        .iter()
        .filter(|c| c.topic == topic)
        .map(|c| c.id)
        .collect();
    let mut first = None;
    input.for_each_message_until(|header, data| {
        if ids.contains(&header.channel_id)
            && let Ok(cloud) = kind.decode(data)
            && voxel_for_cloud(&cloud.points).is_some()
        {
            first = Some(cloud.points);
        }
        Ok(if first.is_some() {
            Break(())
        } else {
            Continue(())
        })
    })?;
    Ok(first)
}

/// Runs the whole job. On any error the output path is left untouched.
pub fn register_log(opts: &RegisterOptions) -> Result<RegisterSummary> {
    let start = Instant::now();
    let input = &opts.input;
    if same_file(input, &opts.output) {
        return Err(Error::InvalidInput(format!(
            "output {} is the input; mireg never writes over its input",
            opts.output.display()
        )));
    }
    let (input_log, catalog) = InputLog::open(input)?;
    let channels = catalog.channel_infos();
    let (topic, kind) = choose_topic(input, &channels, opts.topic.as_deref())?;
    let mut config = opts.config.clone();
    let mut voxel_source = "configured";
    // The first cloud sizes the voxel (unless configured) and the feature voxel (unless
    // --feature-points 0); without either, it is not read twice.
    let first = if opts.derive_voxel || config.feature_points > 0 {
        first_usable_cloud(&input_log, &channels, &topic, kind)?
    } else {
        None
    };
    if opts.derive_voxel
        && let Some(v) = first.as_deref().and_then(voxel_for_cloud)
    {
        config.pair.voxel_size_m = v;
        voxel_source = "first_cloud";
    }
    let voxel_m = config.pair.voxel_size_m;
    if let Some(points) = &first {
        let fv = feature_voxel_for_cloud(points, voxel_m, config.feature_points)?;
        config.pair = with_feature_voxel(&config.pair, fv);
    }
    drop(first);
    // Frames carry input points for the map ICP's fine stage, not for the pairwise one, which
    // the local map replaces (`Odometry::new` turns that off).
    config.pair.icp_fine = config.map_fine;
    config.pair.icp_fine_points_per_icp_point = crate::odometry::MAP_FINE_DRAW_PER_ICP_POINT;
    let mut odometry = Odometry::new(config.clone())?;
    // A log registered before keeps its mireg topics; this run's go to the next namespace
    // (`/mireg_2/…`), so that no topic mixes two runs.
    let topics = Topics::for_input(&channels);
    let reference = channels
        .iter()
        .filter(|c| c.topic == DEFAULT_REFERENCE_TOPIC)
        .find_map(|c| pose_stamped_decoder(&c.schema_name, &c.message_encoding));
    let reference_topic = reference.map(|_| DEFAULT_REFERENCE_TOPIC.to_string());
    let chunk_times = input_log.chunk_times()?;
    let total_frames = channels
        .iter()
        .filter(|c| c.topic == topic)
        .filter_map(|c| c.message_count)
        .sum::<u64>();

    let mut log = OutputLog::create(&opts.output, opts.force, kind.profile())?;
    // The input's schemas and channels keep their ids (its chunks are copied as they are); ours
    // get ids above them.
    log.declare_input(input, &catalog)?;
    let family = match opts.output_messages {
        OutputMessages::Auto => kind,
        OutputMessages::Ros2 => CloudKind::Ros2,
        OutputMessages::Ros1 => CloudKind::Ros1,
        OutputMessages::Foxglove => CloudKind::Foxglove,
    };
    let ch = Outputs::create(&mut log, family, &topics)?;
    let cloud_channels: Vec<u16> = channels
        .iter()
        .filter(|c| c.topic == topic)
        .map(|c| c.id)
        .collect();
    let reference_channels: Vec<u16> = channels
        .iter()
        .filter(|c| Some(&c.topic) == reference_topic.as_ref())
        .map(|c| c.id)
        .collect();
    let segment = LogWindow::resolve(&input_log, &cloud_channels, opts.start, opts.end)?;
    let wanted: std::collections::BTreeSet<u16> = cloud_channels
        .iter()
        .chain(&reference_channels)
        .copied()
        .collect();

    let progress = if opts.progress && std::io::IsTerminal::is_terminal(&std::io::stderr()) {
        let bar = indicatif::ProgressBar::new(total_frames);
        bar.set_style(
            indicatif::ProgressStyle::with_template(
                "{bar:40} {pos}/{len} frames  {per_sec}  ETA {eta}",
            )
            .expect("valid template"),
        );
        Some(bar)
    } else {
        None
    };

    let mut estimates: Vec<(i64, Isometry3<f64>, bool, usize)> = Vec::new(); // (stamp, pose, success, inliers)
    let reference_decoder = reference;
    let mut reference: Vec<(i64, Isometry3<f64>)> = Vec::new();
    let mut copied = 0u64;
    let config = &config;
    let max_points = opts.max_points_per_cloud;
    let deskew_mode = opts.deskew;

    std::thread::scope(|scope| -> Result<()> {
        let (cloud_tx, cloud_rx): (SyncSender<CloudMsg>, Receiver<CloudMsg>) =
            sync_channel(QUEUE_CAPACITY);
        let (prep_tx, prep_rx) = sync_channel::<Result<PreparedMsg>>(QUEUE_CAPACITY);
        // Unbounded: results are small (no point data), and the reading thread, which drains them,
        // may itself be blocked handing on a cloud; a bound here could close a cycle and deadlock.
        let (out_tx, out_rx) = std::sync::mpsc::channel::<Result<FrameOut>>();
        // Each registered frame's motion, back to the preparing thread for deskewing (unbounded:
        // one small message per frame, drained as frames are prepared).
        let (motion_tx, motion_rx) = std::sync::mpsc::channel::<(usize, Isometry3<f64>, f64)>();
        // Message buffers back from the preparing thread once decoded, for the next clouds'
        // bytes: the few buffers in flight are allocated (and faulted in) once, instead of a
        // multi-megabyte map and unmap per cloud whose timing across threads decided the peak
        // RSS. The reader keeps at most MESSAGE_BUFFERS of them outside the reorder window.
        let (recycle_tx, recycle_rx) = std::sync::mpsc::channel::<Vec<u8>>();
        let topic_ref = topic.as_str();

        scope.spawn(move || {
            let mut scratch = PrepareScratch::default();
            // The frame id of a cloud that cannot be decoded: the previous cloud's.
            let mut last_frame_id = String::new();
            let mut motions = Motions::new(motion_rx);
            // The previous cloud's points, once prepared: their buffer takes the next cloud's
            // (a LiDAR frame's few megabytes are allocated and faulted in once, not per cloud).
            let mut spare_points = Vec::new();
            for (frame_index, msg) in cloud_rx.into_iter().enumerate() {
                let t = Instant::now();
                let decoded = kind.decode_reusing(&msg.data, std::mem::take(&mut spare_points));
                let (mut time_field, mut deskewed, mut fatal) = (None, false, None);
                let dropped = decoded.as_ref().map_or(Dropped::default(), |c| Dropped {
                    non_finite: c.num_dropped_non_finite,
                    zero: c.num_dropped_zero,
                });
                // The message bytes are not needed past decoding: don't hold them through prepare.
                let _ = recycle_tx.send(msg.data);
                let decode_s = t.elapsed().as_secs_f64();
                // A cloud that cannot be decoded, is too large, or that the pipeline cannot take
                // (e.g. a glitch at 1e38 m) is one bad frame: flag it, keep going.
                let (header, prepared) = match decoded {
                    Err(e) => {
                        let detail = decode_detail(topic_ref, msg.log_time, &e);
                        let header = codec::Header {
                            stamp: stamp_of_log_time(msg.log_time),
                            frame_id: last_frame_id.clone(),
                        };
                        (header, Err((FailureReason::InvalidCloud, detail)))
                    }
                    Ok(cloud) if cloud.points.len() > max_points => {
                        let detail = format!(
                            "{} points, more than the bound of {max_points} (--max-points)",
                            cloud.points.len()
                        );
                        (cloud.header, Err((FailureReason::TooManyPoints, detail)))
                    }
                    Ok(mut cloud) => {
                        if let Some(times) = &cloud.times {
                            time_field = Some(times.field.clone());
                            if deskew_mode != DeskewMode::Off
                                && let Some((motion, dt)) = motions.of(frame_index.checked_sub(2))
                            {
                                deskew(&mut cloud.points, &times.seconds, &motion, dt);
                                deskewed = true;
                            }
                        } else if deskew_mode == DeskewMode::On {
                            let detail = format!(
                                "--deskew on: no per-point time field (one of {})",
                                crate::io::point_time::TIME_FIELDS.join(", ")
                            );
                            fatal = Some(Error::InvalidInput(format!(
                                "{}: cloud on {topic_ref} at log time {} ns: {detail}",
                                input.display(),
                                msg.log_time
                            )));
                        }
                        let prepared =
                            prepare_frame_with(&cloud.points, &config.pair, &mut scratch)
                                .map(|mut frame| {
                                    keep_map_fine_points(&mut frame);
                                    frame
                                })
                                .map_err(|e| (FailureReason::InvalidCloud, e.to_string()));
                        spare_points = cloud.points;
                        (cloud.header, prepared)
                    }
                };
                if let Some(e) = fatal.take() {
                    let _ = prep_tx.send(Err(e));
                    break;
                }
                last_frame_id.clone_from(&header.frame_id);
                let r = match prepared {
                    Ok(f) => Ok((f, None)),
                    Err(invalid) => prepare_frame(&[], &config.pair).map(|f| (f, Some(invalid))),
                }
                .map(|(frame, invalid)| PreparedMsg {
                    invalid,
                    time_field,
                    deskewed,
                    dropped,
                    log_time: msg.log_time,
                    publish_time: msg.publish_time,
                    header,
                    decode_s,
                    frame,
                });
                let failed = r.is_err();
                if prep_tx.send(r).is_err() || failed {
                    break;
                }
            }
        });
        let odometry = &mut odometry;
        scope.spawn(move || {
            let mut previous_stamp: Option<i64> = None;
            for (k, msg) in prep_rx.into_iter().enumerate() {
                if k % TRIM_EVERY_FRAMES == TRIM_EVERY_FRAMES - 1 {
                    crate::heap::trim();
                }
                let r = msg.and_then(|m| {
                    let prep = m.frame.timings;
                    let t = Instant::now();
                    let mut est = on_pool(|| odometry.push(m.frame))?;
                    if let Some((reason, _)) = &m.invalid {
                        est.failure = Some(*reason);
                    }
                    // The motion and its duration, for deskewing a later frame.
                    let stamp = m.header.stamp.to_ns();
                    let dt = previous_stamp.map_or(f64::NAN, |p| (stamp - p) as f64 * 1e-9);
                    previous_stamp = Some(stamp);
                    let _ = motion_tx.send((k, est.prev_from_curr, dt));
                    Ok(FrameOut {
                        invalid: m.invalid,
                        time_field: m.time_field,
                        deskewed: m.deskewed,
                        dropped: m.dropped,
                        log_time: m.log_time,
                        publish_time: m.publish_time,
                        header: m.header,
                        decode_s: m.decode_s,
                        prep,
                        register_s: t.elapsed().as_secs_f64(),
                        est,
                    })
                });
                let failed = r.is_err();
                if out_tx.send(r).is_err() || failed {
                    break;
                }
            }
        });

        let mut handle_out = |log: &mut OutputLog, r: Result<FrameOut>| -> Result<()> {
            let out = r?;
            write_frame(log, &ch, &opts.world_frame, &out)?;
            estimates.push((
                out.header.stamp.to_ns(),
                out.est.world_from_frame,
                out.est.success,
                out.est.pair.as_ref().map_or(0, |p| p.num_inliers),
            ));
            if let Some(bar) = &progress {
                bar.inc(1);
            }
            Ok(())
        };

        // Clouds are handed on in log-time order: at once where the chunk index proves nothing
        // earlier follows, else after a window of REORDER_WINDOW clouds.
        let reorder_window = opts.reorder_window;
        let mut pending = Reorder::new(reorder_window, chunk_times);
        let mut cloud_tx = Some(cloud_tx);
        // Message buffers allocated so far (each is recycled or, when outsized, freed).
        let mut buffers = 0usize;
        // Input chunks are copied byte for byte; only messages on the cloud and reference
        // channels come here, in file order.
        let copy_only = opts
            .copy_window_only
            .then_some(segment.start_ns..segment.end_ns);
        let read = input_log.pass_through(&mut log, &wanted, copy_only, |log, header, data| {
            if !segment.contains(header.log_time) {
                // Outside the segment: copied (unless --copy-window), not registered.
            } else if cloud_channels.contains(&header.channel_id) {
                if let Some(handed) = pending.too_late(header.log_time) {
                    return Err(Error::Format {
                        path: input.to_path_buf(),
                        detail: format!(
                            "cloud on {topic} at log time {} ns comes after the cloud at log time {handed} ns was registered: the log is out of log-time order by more than the reorder window of {reorder_window} clouds; rerun with a larger --reorder-window (each holds one cloud in memory)",
                            header.log_time
                        ),
                    });
                }
                pending.push(
                    header.log_time,
                    CloudMsg {
                        log_time: header.log_time,
                        publish_time: header.publish_time,
                        data: {
                            // A buffer more than twice this cloud's size (after an outsized
                            // cloud) is freed rather than kept for the rest of the log.
                            // At most MESSAGE_BUFFERS outside the reorder window: the
                            // preparing thread returns each one once decoded, so waiting for it
                            // cannot deadlock, and the peak memory does not hang on how far the
                            // reader ran ahead.
                            let recycled = if buffers - pending.len() >= MESSAGE_BUFFERS {
                                recycle_rx.recv().ok()
                            } else {
                                recycle_rx.try_recv().ok()
                            };
                            if recycled.is_none() {
                                buffers += 1;
                            }
                            let mut buf = recycled
                                .filter(|b| b.capacity() <= 2 * data.len())
                                .unwrap_or_default();
                            buf.clear();
                            // Exact: amortised doubling would let a recycled buffer one byte
                            // short of the next cloud grow to twice its size.
                            buf.reserve_exact(data.len());
                            buf.extend_from_slice(data);
                            buf
                        },
                    },
                );
                while let Some(msg) = pending.pop_ready() {
                    if cloud_tx.as_ref().expect("open").send(msg).is_err() {
                        return Err(Error::InvalidInput("registration stopped early".into()));
                    }
                }
            } else if reference_channels.contains(&header.channel_id)
                && let Some(decode) = reference_decoder
                && let Ok((h, pose)) = decode(data)
            {
                reference.push((h.stamp.to_ns(), pose));
            }
            while let Ok(r) = out_rx.try_recv() {
                handle_out(log, r)?;
            }
            Ok(())
        })
        .map(|n| copied = n);
        if read.is_ok() {
            for msg in pending.into_remaining() {
                if cloud_tx.as_ref().expect("open").send(msg).is_err() {
                    break;
                }
            }
        }
        drop(cloud_tx.take());
        // A worker's error is the root cause of any later failure to hand it work: report it.
        let mut result = read;
        let mut worker_error = None;
        for r in out_rx.iter() {
            match r {
                Err(e) => worker_error = worker_error.or(Some(e)),
                Ok(out) if result.is_ok() => result = handle_out(&mut log, Ok(out)),
                Ok(_) => {}
            }
        }
        match worker_error {
            Some(e) => Err(e),
            None => result,
        }
    })?;
    if let Some(bar) = &progress {
        bar.finish_and_clear();
    }

    let mut meta = BTreeMap::new();
    meta.insert("version".to_string(), env!("CARGO_PKG_VERSION").to_string());
    meta.insert(
        "config".to_string(),
        serde_json::to_string(config).expect("config JSON"),
    );
    meta.insert("voxel_source".to_string(), voxel_source.to_string());
    meta.insert("voxel_m".to_string(), voxel_m.to_string());
    meta.insert(
        "feature_voxel_m".to_string(),
        config.pair.voxel_size_m.to_string(),
    );
    meta.insert("seed".to_string(), config.pair.seed.to_string());
    meta.insert("command_line".to_string(), opts.command_line.clone());
    meta.insert("input".to_string(), input.display().to_string());
    meta.insert("topic".to_string(), topic.clone());
    meta.insert("pose_topic".to_string(), topics.pose.clone());
    meta.insert("stats_topic".to_string(), topics.stats.clone());
    meta.insert("tf_topic".to_string(), topics.tf.clone());
    if segment != LogWindow::ALL {
        meta.insert(
            "segment".to_string(),
            serde_json::to_string(&segment).expect("segment JSON"),
        );
    }
    log.write_metadata("mireg", meta)?;
    log.finish()?;

    let frames = estimates.len();
    let failed_frames = estimates.iter().filter(|e| !e.2).count();
    let registered: Vec<usize> = estimates
        .iter()
        .skip(1)
        .filter(|e| e.2)
        .map(|e| e.3)
        .collect();
    let mean_inliers = if registered.is_empty() {
        0.0
    } else {
        registered.iter().sum::<usize>() as f64 / registered.len() as f64
    };
    let reference = reference_topic
        .and_then(|t| reference_errors(&t, &estimates, std::mem::take(&mut reference)));
    let elapsed_s = start.elapsed().as_secs_f64();
    Ok(RegisterSummary {
        output: opts.output.clone(),
        topic,
        tf_topic: topics.tf,
        pose_topic: topics.pose,
        frames,
        failed_frames,
        mean_inliers,
        messages_copied: copied,
        voxel_m,
        voxel_source,
        feature_voxel_m: config.pair.voxel_size_m,
        feature_points: config.feature_points,
        elapsed_s,
        frames_per_s: frames as f64 / elapsed_s.max(1e-9),
        reference,
    })
}

/// The run's trajectory against the reference poses at the same stamps
/// ([`crate::trajectory::evaluate`] with exact stamp association); `None` with fewer than 2 pairs.
fn reference_errors(
    topic: &str,
    estimates: &[(i64, Isometry3<f64>, bool, usize)],
    reference: Vec<(i64, Isometry3<f64>)>,
) -> Option<ReferenceErrors> {
    let estimate = Trajectory::stamped(
        estimates.iter().map(|e| e.0).collect(),
        estimates.iter().map(|e| e.1).collect(),
    );
    let (stamps, poses) = reference.into_iter().unzip();
    let e = evaluate(&estimate, &Trajectory::stamped(stamps, poses), None, 0).ok()?;
    Some(ReferenceErrors {
        topic: topic.to_string(),
        frames: e.rows.len(),
        ate_rmse_m: e.ate_rmse_m,
        rpe_trans_mean_m: e.rpe_trans_mean_m,
        rpe_rot_mean_deg: e.rpe_rot_mean_deg,
    })
}
