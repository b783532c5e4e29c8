//! What a `register` run is asked to do ([`RegisterOptions`]) and the constants its stages
//! share: a room of its own below `register.rs`, so that the stage files import it without
//! importing their parent.

use std::path::{Path, PathBuf};

use crate::io::codec::livox::LivoxTags;
use crate::io::damage::ReadPolicy;
use crate::loops::LoopConfig;
use crate::odometry::OdometryConfig;

use super::window::WindowBound;

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

/// Motion compensation of clouds with per-point times
/// ([`crate::io::point_time`], [`crate::geometry::deskew`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum DeskewMode {
    /// Deskew every cloud that has a time field.
    #[default]
    Auto,
    /// As `auto`, and a cloud without a time field is an error.
    On,
    /// Never deskew.
    Off,
}

/// The message family of our `/tf` and pose channels.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum OutputMessages {
    /// The clouds' family: ROS 2 for ROS 2 clouds, ROS 1 for ROS 1 clouds, foxglove for
    /// foxglove clouds.
    #[default]
    Auto,
    /// `tf2_msgs/msg/TFMessage` and `geometry_msgs/msg/PoseStamped` in cdr.
    Ros2,
    /// `tf2_msgs/TFMessage` and `geometry_msgs/PoseStamped` in ros1.
    Ros1,
    /// `foxglove.FrameTransforms` and `foxglove.PoseInFrame` in protobuf.
    Foxglove,
}
