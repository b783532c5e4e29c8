//! The coarser cloud global registration runs on in `mireg register` (`feature_voxel_for_cloud`,
//! `with_feature_voxel`): the smallest voxel of the geometric ladder voxel · 2^(k/4) at which
//! the voxel cloud downsamples to at most N points, checked against an independent computation
//! (voxel centroids from a hash map of sums, occupied cells from a hash set of keys), and the
//! configuration it gives.

use std::collections::{HashMap, HashSet};

use mireg::pipeline::{
    FEATURE_VOXEL_STEP, PairConfig, feature_voxel_for_cloud, voxel_for_cloud, with_feature_voxel,
};
use nalgebra::Point3;
use rand::{RngExt, SeedableRng};

/// Cell of `p` in Open3D's voxel grid of edge `v` over `points`: anchored half a cell below the
/// cloud's lowest corner.
fn cell(points: &[Point3<f64>], v: f64) -> impl Fn(&Point3<f64>) -> [i64; 3] {
    let lo: [f64; 3] =
        std::array::from_fn(|k| points.iter().map(|p| p[k]).fold(f64::INFINITY, f64::min));
    move |p: &Point3<f64>| std::array::from_fn(|k| ((p[k] - (lo[k] - 0.5 * v)) / v).floor() as i64)
}

/// Occupied cells of edge `v` (the number of points voxel downsampling keeps).
fn occupied(points: &[Point3<f64>], v: f64) -> usize {
    let key = cell(points, v);
    points.iter().map(key).collect::<HashSet<_>>().len()
}

/// Centroids of the occupied cells of edge `v` (the voxel cloud), in no particular order.
fn centroids(points: &[Point3<f64>], v: f64) -> Vec<Point3<f64>> {
    let key = cell(points, v);
    let mut sums: HashMap<[i64; 3], ([f64; 3], f64)> = HashMap::new();
    for p in points {
        let e = sums.entry(key(p)).or_insert(([0.0; 3], 0.0));
        for k in 0..3 {
            e.0[k] += p[k];
        }
        e.1 += 1.0;
    }
    sums.values()
        .map(|(s, n)| Point3::new(s[0] / n, s[1] / n, s[2] / n))
        .collect()
}

/// A spinning LiDAR on a street: ground ring, walls, ranges 2–80 m.
fn lidar_scan(n: usize, seed: u64) -> Vec<Point3<f64>> {
    let mut rng = rand_pcg::Pcg64Mcg::seed_from_u64(seed);
    (0..n)
        .map(|_| {
            let a = rng.random_range(0.0..std::f64::consts::TAU);
            let r = 2.0 + 78.0 * rng.random::<f64>().powi(2);
            let z = if rng.random_range(0..3) == 0 {
                rng.random_range(-1.7..3.0)
            } else {
                -1.7
            };
            Point3::new(r * a.cos(), r * a.sin(), z)
        })
        .collect()
}

#[test]
fn the_feature_voxel_is_the_smallest_rung_that_fits() {
    let scan = lidar_scan(60_000, 5);
    let voxel = voxel_for_cloud(&scan).unwrap();
    // The voxel cloud, computed independently; the ladder is counted on it.
    let fine = centroids(&scan, voxel);
    for max_points in [500, 2_000, 4_000, 10_000] {
        let fv = feature_voxel_for_cloud(&scan, voxel, max_points).unwrap();
        let k = (fv / voxel).ln() / FEATURE_VOXEL_STEP.ln();
        assert!((k - k.round()).abs() < 1e-9, "{fv} is not on the ladder");
        let at = occupied(&fine, fv);
        assert!(at <= max_points, "{max_points}: {at} points at {fv}");
        if k.round() > 0.0 {
            let below = fv / FEATURE_VOXEL_STEP;
            let n = occupied(&fine, below);
            assert!(n > max_points, "{max_points}: {n} points at {below}");
        }
    }
    // More points allowed: never a coarser voxel.
    let a = feature_voxel_for_cloud(&scan, voxel, 2_000).unwrap();
    let b = feature_voxel_for_cloud(&scan, voxel, 4_000).unwrap();
    assert!(b <= a && a > voxel);
}

#[test]
fn a_cloud_that_fits_keeps_its_voxel_and_zero_disables() {
    let scan = lidar_scan(3_000, 6);
    let voxel = 0.2;
    assert!(occupied(&scan, voxel) <= 4_000);
    assert_eq!(feature_voxel_for_cloud(&scan, voxel, 4_000).unwrap(), voxel);
    let big = lidar_scan(60_000, 7);
    assert_eq!(feature_voxel_for_cloud(&big, voxel, 0).unwrap(), voxel);
    assert!(feature_voxel_for_cloud(&big, f64::NAN, 10).is_err());
}

#[test]
fn only_global_registration_moves_to_the_feature_voxel() {
    let pair = PairConfig {
        voxel_size_m: 0.3,
        ..Default::default()
    };
    let c = with_feature_voxel(&pair, 0.6).resolved().unwrap();
    assert_eq!(c.voxel_size_m, 0.6);
    assert_eq!(c.normal_radius_m, Some(1.2));
    assert_eq!(c.feature_radius_m, Some(3.0));
    assert_eq!(c.inlier_threshold_m, Some(0.6 * 1.5));
    // ICP keeps the voxel cloud and its distance.
    assert_eq!(c.icp_voxel_size_m, Some(0.3));
    assert_eq!(c.icp_max_distance_m, Some(0.3));
    // Settings the user made stay.
    let set = PairConfig {
        icp_max_distance_m: Some(0.45),
        feature_radius_m: Some(2.0),
        ..pair.clone()
    };
    let c = with_feature_voxel(&set, 0.6).resolved().unwrap();
    assert_eq!(
        (c.icp_max_distance_m, c.feature_radius_m),
        (Some(0.45), Some(2.0))
    );
    // The same voxel: nothing changes.
    assert_eq!(with_feature_voxel(&pair, 0.3), pair);
}
