//! What the stages of `mireg register` hand each other: a cloud message (reader → prepare), a
//! prepared frame (prepare → registrar), a registered frame (registrar → writer), and what the
//! writer keeps of it for the summary and loop closure.

use nalgebra::Isometry3;

use crate::io::codec;
use crate::loops::Descriptor;
use crate::odometry::FrameEstimate;
use crate::pipeline::{FailureReason, FrameTimings, PreparedFrame};

/// One cloud message's bytes and times.
pub(super) struct CloudMsg {
    pub(super) log_time: u64,
    pub(super) publish_time: u64,
    pub(super) data: Vec<u8>,
}

/// One cloud, decoded and prepared.
pub(super) struct PreparedMsg {
    /// Why the cloud could not be decoded or prepared (the frame is then empty and flagged).
    pub(super) invalid: Option<(FailureReason, String)>,
    /// The cloud's time field, and whether its points were deskewed by it.
    pub(super) time_field: Option<String>,
    pub(super) deskewed: bool,
    /// The motion (`prev_from_curr`, seconds) the cloud was deskewed by, if it was.
    pub(super) deskew_motion: Option<(Isometry3<f64>, f64)>,
    /// The frame's appearance descriptor, when loop closure is on and the frame has features.
    pub(super) descriptor: Option<Descriptor>,
    /// Points dropped by the decoder: non-finite, and zero returns of an organised cloud.
    pub(super) dropped: Dropped,
    pub(super) log_time: u64,
    pub(super) publish_time: u64,
    pub(super) header: codec::Header,
    pub(super) decode_s: f64,
    pub(super) frame: PreparedFrame,
}

/// Points the decoder dropped from one cloud.
#[derive(Debug, Clone, Copy, Default)]
pub(super) struct Dropped {
    pub(super) non_finite: usize,
    pub(super) zero: usize,
}

/// One frame registered: what the writer puts out.
pub(super) struct FrameOut {
    pub(super) invalid: Option<(FailureReason, String)>,
    pub(super) time_field: Option<String>,
    pub(super) deskewed: bool,
    /// The motion (`prev_from_curr`, seconds) the cloud was deskewed by, if it was.
    pub(super) deskew_motion: Option<(Isometry3<f64>, f64)>,
    /// The frame's appearance descriptor, when loop closure is on and the frame has features.
    pub(super) descriptor: Option<Descriptor>,
    pub(super) dropped: Dropped,
    pub(super) log_time: u64,
    pub(super) publish_time: u64,
    pub(super) header: codec::Header,
    pub(super) decode_s: f64,
    pub(super) prep: FrameTimings,
    pub(super) register_s: f64,
    pub(super) est: FrameEstimate,
}

/// One frame's estimate as the summary and loop closure need it (a few hundred bytes a frame).
#[derive(Debug, Clone)]
pub(super) struct Estimate {
    /// The cloud's header stamp \[ns\].
    pub(super) stamp_ns: i64,
    pub(super) world_from_frame: Isometry3<f64>,
    pub(super) success: bool,
    pub(super) inliers: usize,
    /// The cloud's header (stamp and frame id), log and publish times.
    pub(super) header: codec::Header,
    pub(super) log_time: u64,
    pub(super) publish_time: u64,
    /// The motion the cloud was deskewed by, if it was ([`super::frames::PreparedMsg`]).
    pub(super) deskew_motion: Option<(Isometry3<f64>, f64)>,
    /// The loop-closure descriptor, when computed.
    pub(super) descriptor: Option<Descriptor>,
}
