//! A prepared frame's memory: what it holds idle, what serving as a registration target adds,
//! and that dropping those search structures gives the idle size back (as predicted before the
//! first use) without changing the next registration against it (loop closure keeps frames idle
//! between candidates).

#[path = "common/room_scene.rs"]
mod room_scene;

use mireg::pipeline::{PairConfig, prepare_frame, register_prepared};
use nalgebra::{Isometry3, Point3, Translation3, UnitQuaternion};
use room_scene::scene;

#[test]
fn dropping_search_structures_restores_the_idle_size_and_changes_no_result() {
    let truth = Isometry3::from_parts(
        Translation3::new(0.3, -0.2, 0.05),
        UnitQuaternion::from_euler_angles(0.02, -0.01, 0.4),
    );
    let target_points = scene(40_000, 1);
    let source_points: Vec<Point3<f64>> = scene(40_000, 2)
        .iter()
        .map(|p| truth.inverse() * p)
        .collect();
    for icp_voxel in [None, Some(0.05)] {
        let c = PairConfig {
            voxel_size_m: 0.1,
            icp_voxel_size_m: icp_voxel,
            seed: 7,
            ..Default::default()
        };
        let source = prepare_frame(&source_points, &c).unwrap();
        let mut target = prepare_frame(&target_points, &c).unwrap();

        // Idle, the frame holds at least its clouds: feature points and FPFH, ICP points.
        let idle = target.heap_bytes();
        let icp_points = target.icp.as_ref().map_or(0, |t| t.points().len());
        let floor = target.points.len() * 24 + target.features().len() * 4 * 33 + icp_points * 24;
        assert!(idle >= floor, "{icp_voxel:?}: idle {idle} B < {floor} B");

        // What it will hold idle after serving as a target, predicted before.
        let predicted = target.idle_bytes();
        assert!(
            predicted >= idle,
            "{icp_voxel:?}: predicted {predicted} B, idle {idle} B"
        );

        let first = register_prepared(&source, &target, &c).unwrap();
        assert!(
            first.failure.is_none(),
            "{icp_voxel:?}: {:?}",
            first.failure
        );
        let used = target.heap_bytes();
        // Serving as a target builds its matching target at least (one entry per descriptor).
        assert!(
            used >= idle + target.features().len() * 4 * 33,
            "{icp_voxel:?}: in use {used} B, idle {idle} B"
        );

        target.drop_search_structures();
        // Normals estimated for the ICP stay (they are the frame's, not a search structure).
        let normals = target
            .icp
            .as_ref()
            .and_then(|t| t.normals().map(<[_]>::len))
            .unwrap_or(0);
        let after = target.heap_bytes();
        assert!(
            after <= idle + normals * 24 && after < used,
            "{icp_voxel:?}: after dropping {after} B, idle {idle} B, in use {used} B"
        );
        assert_eq!(after, predicted, "{icp_voxel:?}");
        assert_eq!(target.idle_bytes(), predicted, "{icp_voxel:?}");

        let again = register_prepared(&source, &target, &c).unwrap();
        assert_eq!(
            first.target_from_source, again.target_from_source,
            "{icp_voxel:?}"
        );
        assert_eq!(first.num_inliers, again.num_inliers);
        assert_eq!(first.fitness, again.fitness);
        assert_eq!(first.inlier_rmse_m, again.inlier_rmse_m);
    }
}
