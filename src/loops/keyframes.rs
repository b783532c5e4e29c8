//! Keyframe selection: which frames of a log become loop-closure keyframes.

use nalgebra::Isometry3;

use crate::{Error, Result};

/// When a frame becomes a keyframe.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct KeyframeConfig {
    /// Path length since the previous keyframe that makes a new one \[m\]. Default
    /// [`DEFAULT_KEYFRAME_DISTANCE_M`] (1 m).
    pub keyframe_distance_m: f64,
    /// Rotation since the previous keyframe that makes a new one \[deg\]. Default
    /// [`DEFAULT_KEYFRAME_ANGLE_DEG`] (10°).
    pub keyframe_angle_deg: f64,
}

/// Default [`KeyframeConfig::keyframe_distance_m`]: 1 m (the KAIST03 keyframes of SC-A-LOAM that
/// `examples/loop_descriptors.rs` reads are 0.8–1.4 m apart). Set it to a few centimetres for a
/// room-scale RGB-D log (ICL-NUIM moves ~2 cm per frame), or 0 to keep every frame.
pub const DEFAULT_KEYFRAME_DISTANCE_M: f64 = 1.0;

/// Default [`KeyframeConfig::keyframe_angle_deg`]: 10°.
pub const DEFAULT_KEYFRAME_ANGLE_DEG: f64 = 10.0;

impl Default for KeyframeConfig {
    fn default() -> Self {
        Self {
            keyframe_distance_m: DEFAULT_KEYFRAME_DISTANCE_M,
            keyframe_angle_deg: DEFAULT_KEYFRAME_ANGLE_DEG,
        }
    }
}

/// Indices of the keyframes among `poses` (odometry `world_from_sensor`, in log order) with
/// `travelled_m[k]` the path length from the log's start to frame k (e.g.
/// [`crate::evaluate::path_distances`]): frame 0, then every frame whose path length since the
/// previous keyframe is ≥ `keyframe_distance_m` or whose rotation from it is ≥
/// `keyframe_angle_deg`. With both thresholds 0 every frame is a keyframe.
///
/// NOTE: "moved" is path length, not the straight-line distance: a robot that goes back and
/// forth over a metre still makes keyframes, which the loop search then sees as places.
///
/// # Errors
/// [`Error::InvalidInput`] when the lengths differ or a threshold is negative or not finite.
pub fn select_keyframes(
    poses: &[Isometry3<f64>],
    travelled_m: &[f64],
    config: &KeyframeConfig,
) -> Result<Vec<usize>> {
    if poses.len() != travelled_m.len() {
        return Err(Error::InvalidInput(format!(
            "select_keyframes: {} poses but {} path lengths",
            poses.len(),
            travelled_m.len()
        )));
    }
    for (name, x) in [
        ("keyframe_distance_m", config.keyframe_distance_m),
        ("keyframe_angle_deg", config.keyframe_angle_deg),
    ] {
        if !(x.is_finite() && x >= 0.0) {
            return Err(Error::InvalidInput(format!(
                "{name} must be finite and >= 0, got {x}"
            )));
        }
    }
    let mut selector = KeyframeSelector::new(config);
    let keys = (0..poses.len())
        .filter(|&k| selector.push(&poses[k], travelled_m[k]))
        .collect();
    Ok(keys)
}

/// [`select_keyframes`] one frame at a time, for a caller that sees the poses as they come
/// (`mireg register` keeps the keyframes' prepared frames for loop verification).
#[derive(Debug, Clone)]
pub struct KeyframeSelector {
    distance_m: f64,
    angle_rad: f64,
    /// The last keyframe's pose and path length.
    last: Option<(Isometry3<f64>, f64)>,
}

impl KeyframeSelector {
    /// A selector by `config` (not checked: [`select_keyframes`] checks it).
    pub fn new(config: &KeyframeConfig) -> Self {
        Self {
            distance_m: config.keyframe_distance_m,
            angle_rad: config.keyframe_angle_deg.to_radians(),
            last: None,
        }
    }

    /// Whether the next frame, at `pose` after `travelled_m` of path from the log's start, is a
    /// keyframe.
    pub fn push(&mut self, pose: &Isometry3<f64>, travelled_m: f64) -> bool {
        let new = self.last.is_none_or(|(last, last_travelled)| {
            let moved = travelled_m - last_travelled;
            let turned = (last.rotation.inverse() * pose.rotation).angle();
            moved >= self.distance_m || turned >= self.angle_rad
        });
        if new {
            self.last = Some((*pose, travelled_m));
        }
        new
    }
}
