//! What a `register` run did ([`RegisterSummary`]) and the parts it names: the errors against a
//! reference, the step that dominates them, the flagged frames.

use std::path::PathBuf;

use crate::io::damage::Damage;

use super::closure::LoopSummary;

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
    /// Frames accepted by tracking: refined on the local map from the constant-velocity
    /// prediction, without global registration ([`crate::odometry::OdometryConfig::track_first`]).
    pub tracked_frames: usize,
    /// Mean MI-RANSAC inliers over the frames registered globally (tracked frames have none);
    /// 0 without such a frame.
    pub mean_inliers: f64,
    /// Input messages copied.
    pub messages_copied: u64,
    /// Voxel used \[m\].
    pub voxel_m: f64,
    /// Where it came from: `"configured"` (flag or configuration) or `"first_cloud"`.
    pub voxel_source: &'static str,
    /// Voxel of the cloud global registration ran on \[m\] (the voxel itself, or coarser:
    /// [`crate::odometry::OdometryConfig::feature_points`]).
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
