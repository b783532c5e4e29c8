//! What the stages of `mireg register` hand each other: a cloud message (reader → prepare), a
//! prepared frame (prepare → registrar), a registered frame (registrar → writer), and what the
//! writer keeps of it for the summary and loop closure.

use nalgebra::Isometry3;

use crate::io::codec;
use crate::loops::Descriptor;
use crate::odometry::FrameEstimate;
use crate::odometry::stream::Deskewed;
use crate::pipeline::{FailureReason, FrameTimings, PreparedFrame};

/// One cloud message's bytes and times.
pub(super) struct CloudMsg {
    pub(super) log_time: u64,
    pub(super) publish_time: u64,
    pub(super) data: Vec<u8>,
}

/// What the prepare stage learnt of one cloud, carried with it to the writer.
pub(super) struct CloudInfo {
    /// Why the cloud could not be decoded or prepared (the frame is then empty and flagged).
    pub(super) invalid: Option<(FailureReason, String)>,
    /// The cloud's time field.
    pub(super) time_field: Option<String>,
    /// The motion (`prev_from_curr`, seconds) the cloud was deskewed by and the mean of its
    /// points' times after the stamp, if it was ([`Deskewed`]).
    pub(super) deskewed: Deskewed,
    /// The frame's appearance descriptor, when loop closure is on and the frame has features.
    pub(super) descriptor: Option<Descriptor>,
    /// Points dropped by the decoder: non-finite, zero returns of an organised cloud, Livox
    /// tags, glitches of the time field.
    pub(super) dropped: Dropped,
    pub(super) log_time: u64,
    pub(super) publish_time: u64,
    pub(super) header: codec::Header,
    pub(super) decode_s: f64,
}

impl CloudInfo {
    /// Whether the cloud's points were deskewed by its time field.
    pub(super) fn deskewed(&self) -> bool {
        self.deskewed.is_some()
    }

    /// The motion (`prev_from_curr`, seconds) the cloud was deskewed by, if it was.
    pub(super) fn deskew_motion(&self) -> Option<(Isometry3<f64>, f64)> {
        self.deskewed.map(|(motion, dt, _)| (motion, dt))
    }
}

/// One cloud, decoded and prepared.
pub(super) struct PreparedMsg {
    pub(super) cloud: CloudInfo,
    pub(super) frame: PreparedFrame,
}

/// Points the decoder dropped from one cloud.
#[derive(Debug, Clone, Copy, Default)]
pub(super) struct Dropped {
    pub(super) non_finite: usize,
    /// Points dropped because a coordinate's magnitude was at least
    /// [`crate::io::codec::MAX_COORDINATE_M`].
    pub(super) far: usize,
    pub(super) zero: usize,
    /// Livox points dropped by their tag.
    pub(super) tag: usize,
    /// Points dropped because their per-point time was a glitch (not finite, or more than
    /// [`crate::io::point_time::POINT_TIME_BOUND_S`] from the cloud's median point time).
    pub(super) time: usize,
}

/// One frame registered: what the writer puts out.
pub(super) struct FrameOut {
    pub(super) cloud: CloudInfo,
    pub(super) prep: FrameTimings,
    pub(super) register_s: f64,
    pub(super) est: FrameEstimate,
}

/// One frame's estimate as the summary and loop closure need it, kept for every frame of the run:
/// under 1 kB a frame (768 bytes on x86-64, plus its frame id's text; checked by
/// `tests::an_estimate_takes_under_a_kilobyte`).
#[derive(Debug, Clone)]
pub(super) struct Estimate {
    pub(super) world_from_frame: Isometry3<f64>,
    pub(super) success: bool,
    /// MI-RANSAC inliers of its global registration; `None` where none ran (tracked frames,
    /// the first).
    pub(super) inliers: Option<usize>,
    /// The cloud's header (stamp and frame id), log and publish times.
    pub(super) header: codec::Header,
    pub(super) log_time: u64,
    pub(super) publish_time: u64,
    /// The motion the cloud was deskewed by, if it was ([`super::frames::PreparedMsg`]).
    pub(super) deskew_motion: Option<(Isometry3<f64>, f64)>,
    /// The loop-closure descriptor, when computed.
    pub(super) descriptor: Option<Descriptor>,
    /// The step's calibrated information ([`crate::odometry::FrameEstimate::information`]).
    pub(super) information: Option<nalgebra::Matrix6<f64>>,
    /// [`crate::odometry::FrameEstimate::map_range_m`].
    pub(super) map_range_m: Option<f64>,
}

impl Estimate {
    /// The cloud's header stamp \[ns\].
    pub(super) fn stamp_ns(&self) -> i64 {
        self.header.stamp.to_ns()
    }
}

#[cfg(test)]
mod tests {
    /// docs/ARCHITECTURE.md and the README count what a run keeps per frame: under 1 kB.
    #[test]
    fn an_estimate_takes_under_a_kilobyte() {
        assert!(std::mem::size_of::<super::Estimate>() < 1024);
    }
}
