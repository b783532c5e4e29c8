//! Resolutions that fit the sensor: the voxel of a log from its first cloud, and the coarser
//! voxel on which a dense LiDAR frame's global registration (descriptors, matching, RANSAC) runs
//! while ICP and the local map keep the voxel cloud.

use nalgebra::Point3;

use super::PairConfig;
use crate::Result;
use crate::geometry::voxel::voxel_downsample;

/// Voxel edge per metre of median range for [`voxel_for_cloud`]: 1/40. Chosen by measurement
/// (docs/ODOMETRY.md): it gives 0.049 m on the ICL-NUIM RGB-D frames (median range 1.96 m; 0.05 m
/// is their best voxel), 0.37 m on the MulRan KAIST03 Ouster keyframes (14.8 m) and 0.25 m on
/// KITTI HDL-64 scans (10.1 m).
pub const VOXEL_PER_MEDIAN_RANGE: f64 = 1.0 / 40.0;

/// A voxel edge \[m\] that fits the sensor of `points` (sensor frame): the median distance of
/// its finite, non-zero points from the origin times [`VOXEL_PER_MEDIAN_RANGE`], so that an
/// indoor RGB-D cloud and an outdoor LiDAR scan both get a workable resolution. `None` for
/// fewer than 3 such points.
pub fn voxel_for_cloud(points: &[Point3<f64>]) -> Option<f64> {
    let mut ranges: Vec<f64> = points
        .iter()
        .map(|p| p.coords.norm())
        .filter(|r| r.is_finite() && *r > 0.0)
        .collect();
    if ranges.len() < 3 {
        return None;
    }
    let mid = ranges.len() / 2;
    let (_, median, _) = ranges.select_nth_unstable_by(mid, f64::total_cmp);
    Some(*median * VOXEL_PER_MEDIAN_RANGE)
}

/// Default bound on the points of the cloud that global registration runs on in
/// `mireg register` ([`feature_voxel_for_cloud`]): 2 000. Chosen by measurement
/// (docs/ODOMETRY.md, "Dense LiDAR frames"): against 4 000, the same ATE on KAIST03 (also with
/// gaps), micro211 and the fixture, the same recall of pairs at gaps up to 80 frames, and
/// 15–50 % more frames/s.
pub const DEFAULT_FEATURE_POINTS: usize = 2_000;

/// Ratio between successive candidate feature voxels in [`feature_voxel_for_cloud`]: 2^(1/4).
pub const FEATURE_VOXEL_STEP: f64 = 1.189_207_115_002_721;

/// The voxel \[m\] of the cloud that descriptors, matching and RANSAC use, for frames like
/// `points` registered at `voxel_m`: the smallest of `voxel_m · FEATURE_VOXEL_STEP^k`,
/// k = 0, 1, …, 24 (up to 64 × `voxel_m`), at which the `voxel_m` cloud of `points` downsamples to
/// at most `max_points` points (as [`super::prepare_frame`] makes the feature cloud from the ICP
/// cloud). `max_points` = 0 gives `voxel_m` (no coarser cloud).
///
/// NOTE: the paper registers one cloud per pair. A LiDAR scan at the voxel that local-map ICP
/// needs (15–25 k points for an Ouster OS1-64 or HDL-64 at 0.25–0.37 m) costs most of its frame
/// time in descriptor matching, quadratic in the points; a coarse pose is all that ICP against
/// the map needs from global registration, so the descriptors go on a cloud of a few thousand
/// points (docs/ODOMETRY.md).
pub fn feature_voxel_for_cloud(
    points: &[Point3<f64>],
    voxel_m: f64,
    max_points: usize,
) -> Result<f64> {
    let fine = voxel_downsample(points, voxel_m)?;
    if max_points == 0 || fine.len() <= max_points {
        return Ok(voxel_m);
    }
    // Two candidates at a time, one per core: this runs once, before the frames' pipeline
    // starts, so nothing else would use the second core.
    let voxel = |k: i32| voxel_m * FEATURE_VOXEL_STEP.powi(k);
    let fits =
        |k: i32| -> Result<bool> { Ok(voxel_downsample(&fine, voxel(k))?.len() <= max_points) };
    for k in (1..MAX_FEATURE_VOXEL_STEPS).step_by(2) {
        let (a, b) = rayon::join(|| fits(k), || fits(k + 1));
        if a? {
            return Ok(voxel(k));
        }
        if b? {
            return Ok(voxel(k + 1));
        }
    }
    Ok(voxel(MAX_FEATURE_VOXEL_STEPS))
}

/// Candidates of [`feature_voxel_for_cloud`] beyond the voxel, up to 64 × the voxel (even: they
/// are tried in pairs).
const MAX_FEATURE_VOXEL_STEPS: i32 = 24;

/// `pair` with its global registration on a `feature_voxel_m` cloud: `voxel_size_m` becomes
/// `feature_voxel_m` (normal, FPFH and inlier radii derive from it unless set), while ICP keeps
/// the old voxel for its cloud and correspondence distance unless those were set. Unchanged when
/// `feature_voxel_m` is the voxel.
pub fn with_feature_voxel(pair: &PairConfig, feature_voxel_m: f64) -> PairConfig {
    let mut c = pair.clone();
    if feature_voxel_m != pair.voxel_size_m {
        c.icp_voxel_size_m.get_or_insert(pair.voxel_size_m);
        c.icp_max_distance_m.get_or_insert(pair.voxel_size_m);
        c.voxel_size_m = feature_voxel_m;
    }
    c
}
