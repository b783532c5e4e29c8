//! Features deferred to their first use (`prepare_frame_deferring_features`, what `mireg
//! register`'s odometry prepares) against features computed while preparing
//! (`prepare_frame_with`), the oracle: the same FPFH bit for bit, the same registration, and
//! deferred only where the ICP cloud does not need the feature cloud's normals.

use std::path::Path;

use mireg::io::cloud_file;
use mireg::pipeline::{
    PairConfig, PrepareScratch, PreparedFrame, prepare_frame_deferring_features,
    prepare_frame_with, register_prepared,
};
use nalgebra::Point3;

fn clouds() -> (Vec<Point3<f64>>, Vec<Point3<f64>>) {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("fixtures/icl_nuim");
    (
        cloud_file::read_points(&dir.join("rgbd5_00004.ply")).unwrap(),
        cloud_file::read_points(&dir.join("rgbd5_00000.ply")).unwrap(),
    )
}

/// `mireg register`'s layout: an ICP cloud finer than the feature cloud.
fn separate_icp_cloud() -> PairConfig {
    PairConfig {
        voxel_size_m: 0.08,
        icp_voxel_size_m: Some(0.04),
        seed: 3,
        ..Default::default()
    }
}

fn eager(points: &[Point3<f64>], config: &PairConfig) -> PreparedFrame {
    prepare_frame_with(points, config, &mut PrepareScratch::default()).unwrap()
}

fn deferred(points: &[Point3<f64>], config: &PairConfig) -> PreparedFrame {
    prepare_frame_deferring_features(points, config, &mut PrepareScratch::default()).unwrap()
}

#[test]
fn deferred_features_equal_the_features_computed_while_preparing() {
    let (source, _) = clouds();
    let config = separate_icp_cloud();
    let now = eager(&source, &config);
    let later = deferred(&source, &config);
    assert!(now.timings.features > 0.0);
    // Nothing of the features was computed while preparing; the frame still has them.
    assert_eq!(later.timings.features, 0.0);
    assert_eq!(later.timings.normals, 0.0);
    assert!(later.has_features());
    assert_eq!(later.stage_timings().features, 0.0);
    assert_eq!(later.points, now.points);
    assert_eq!(
        later.icp.as_ref().unwrap().points(),
        now.icp.as_ref().unwrap().points()
    );
    assert!(!now.features().is_empty());
    assert_eq!(later.features().len(), now.features().len());
    for (a, b) in later.features().iter().zip(now.features()) {
        assert_eq!(a, b);
    }
    // Computing them is timed as the frame's own.
    assert!(later.stage_timings().features > 0.0);
}

#[test]
fn frames_with_deferred_features_register_as_frames_prepared_whole() {
    let (source, target) = clouds();
    let config = separate_icp_cloud();
    let whole =
        register_prepared(&eager(&source, &config), &eager(&target, &config), &config).unwrap();
    let later = register_prepared(
        &deferred(&source, &config),
        &deferred(&target, &config),
        &config,
    )
    .unwrap();
    assert!(whole.failure.is_none(), "{:?}", whole.failure);
    assert_eq!(later.failure, whole.failure);
    assert_eq!(later.num_correspondences, whole.num_correspondences);
    assert_eq!(later.num_inliers, whole.num_inliers);
    assert_eq!(later.target_from_source, whole.target_from_source);
    assert_eq!(later.fitness, whole.fitness);
    // The deferred features' seconds are counted in the pair's timings, as prepared ones are.
    assert!(later.timings_s.features > 0.0);
}

#[test]
fn features_are_computed_while_preparing_where_the_icp_cloud_needs_their_normals() {
    let (source, _) = clouds();
    // The ICP cloud is the feature cloud: its normals are the feature cloud's, computed with
    // the FPFH in one neighbourhood pass.
    let config = PairConfig {
        voxel_size_m: 0.08,
        seed: 3,
        ..Default::default()
    };
    let frame = deferred(&source, &config);
    assert!(frame.timings.features > 0.0);
    let now = eager(&source, &config);
    assert_eq!(frame.features(), now.features());
}

#[test]
fn a_cloud_too_small_has_no_features_either_way() {
    let config = separate_icp_cloud();
    let two = [Point3::new(0.0, 0.0, 1.0), Point3::new(1.0, 0.0, 1.0)];
    for frame in [eager(&two, &config), deferred(&two, &config)] {
        assert!(!frame.has_features());
        assert!(frame.features().is_empty());
    }
}
