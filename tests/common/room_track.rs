//! The room scene (`room_scene.rs`) seen from a sensor moving along a track, registered by the
//! streaming odometry: each frame's estimate and its position error against the known truth.

use mireg::odometry::stream::StreamOdometry;
use mireg::odometry::{FrameEstimate, OdometryConfig};
use nalgebra::{Isometry3, Translation3, UnitQuaternion, Vector3};

use super::room_scene;

/// Registers 8 000-point views of the room from the poses of `track` (x offset \[m\] and yaw
/// \[deg\] per frame, at a fixed height, 0.1 s apart) with `config`; returns each frame's estimate
/// and the distance \[m\] of its position from the truth (world = the first frame's sensor frame).
pub fn run(config: OdometryConfig, track: &[(f64, f64)]) -> Vec<(FrameEstimate, f64)> {
    let mut odometry = StreamOdometry::new(config, true, false);
    let mut first = None;
    track
        .iter()
        .enumerate()
        .map(|(k, &(x, yaw_deg))| {
            let world_from_frame = Isometry3::from_parts(
                Translation3::new(0.5 + x, 0.6, 1.0),
                UnitQuaternion::from_axis_angle(&Vector3::z_axis(), yaw_deg.to_radians()),
            );
            let points: Vec<_> = room_scene::scene(8000, k as u64)
                .into_iter()
                .map(|p| world_from_frame.inverse() * p)
                .collect();
            let est = odometry
                .push(points, None, (k as i64) * 100_000_000)
                .unwrap();
            let truth = first.get_or_insert(world_from_frame).inverse() * world_from_frame;
            let error = (truth.inverse() * est.world_from_frame)
                .translation
                .vector
                .norm();
            (est, error)
        })
        .collect()
}
