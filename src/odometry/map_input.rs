//! What a frame gives the local map: its ICP cloud and the normals of the points a voxel keeps.

use nalgebra::{Isometry3, Vector3};

use crate::Result;
use crate::pipeline::PreparedFrame;
use crate::refine::icp::IcpTarget;
use crate::refine::local_map::LocalMap;

/// Adds an accepted frame's ICP cloud at `world_from_frame` to `map`; voxels farther than the
/// frame's farthest point from its origin are dropped.
pub(super) fn add_to_map(
    map: &mut LocalMap,
    frame: &PreparedFrame,
    world_from_frame: &Isometry3<f64>,
) {
    if let Some((icp, range)) = map_input(frame) {
        map.insert_with(world_from_frame, icp.points(), kept_normals(icp), range);
    }
}

/// [`add_to_map`], then the map as an ICP target at `distance` \[m\]; the kept points' normals
/// are estimated while the target is built ([`LocalMap::insert_and_target`]).
pub(super) fn add_to_map_and_target<'m>(
    map: &'m mut LocalMap,
    frame: &PreparedFrame,
    world_from_frame: &Isometry3<f64>,
    distance: f64,
) -> Result<Option<&'m IcpTarget>> {
    let Some((icp, range)) = map_input(frame) else {
        return map.target(distance);
    };
    map.insert_and_target(
        world_from_frame,
        icp.points(),
        kept_normals(icp),
        range,
        distance,
    )
}

/// The normals of the points of `icp` that a map insertion keeps, estimated for those only
/// (most of a 10 Hz frame lands in voxels already full).
fn kept_normals(icp: &IcpTarget) -> impl FnOnce(&[u32]) -> Vec<Vector3<f64>> + Send + '_ {
    |at: &[u32]| icp.normals_at(at).unwrap_or_default()
}

/// How far from its pose a frame keeps the local map when it joins it \[m\]: its farthest ICP
/// point's range (voxels beyond are dropped); `None` if it cannot join.
pub(super) fn map_range(frame: &PreparedFrame) -> Option<f64> {
    map_input(frame).map(|(_, range)| range)
}

/// A frame's ICP cloud, if it can join the map (it has normals, given or deferred), and its
/// farthest point's range \[m\].
fn map_input(frame: &PreparedFrame) -> Option<(&IcpTarget, f64)> {
    let icp = frame.icp.as_ref().filter(|icp| icp.has_normals())?;
    let range = icp
        .points()
        .iter()
        .map(|p| p.coords.norm())
        .fold(0.0f64, f64::max);
    Some((icp, range))
}
