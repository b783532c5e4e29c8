//! Odometry with local-map refinement on synthetic sequences with known trajectories: constant
//! velocity, stop-and-go, a dropped frame, a 90° yaw jump between two frames, a static sensor.
//! Oracle: the generating poses (`world_from_camera(k)` relative to frame 0).

use mireg::odometry::{InitialGuess, MapFit, Odometry, OdometryConfig};
use mireg::pipeline::{PairConfig, prepare_frame};
use nalgebra::{Isometry3, Point3, Translation3, UnitQuaternion, Vector3};
use rand::{RngExt, SeedableRng};
use rand_distr::{Distribution, Normal};

#[path = "common/synthetic_log.rs"]
mod synthetic_log;
use synthetic_log::add_spheres_and_boxes;

/// A room (three walls) with boxes and spheres; every point seen from every pose (no occlusion).
fn scene() -> Vec<Point3<f64>> {
    let mut rng = rand_pcg::Pcg64Mcg::seed_from_u64(21);
    let mut pts = Vec::new();
    for _ in 0..5000 {
        let (u, v): (f64, f64) = (rng.random_range(-4.0..4.0), rng.random_range(0.0..3.0));
        match rng.random_range(0..3u32) {
            0 => pts.push(Point3::new(u, v - 1.5, 4.0)),
            1 => pts.push(Point3::new(-4.0, v - 1.5, u)),
            _ => pts.push(Point3::new(u, 1.5, v * 2.6 - 4.0)),
        }
    }
    add_spheres_and_boxes(&mut rng, &mut pts, -3.0..3.0, 400);
    pts
}

fn pose(x: f64, z: f64, yaw_deg: f64) -> Isometry3<f64> {
    Isometry3::from_parts(
        Translation3::new(x, 0.0, z),
        UnitQuaternion::from_euler_angles(0.0, yaw_deg.to_radians(), 0.0),
    )
}

/// Runs odometry over the scene seen from `world_from_camera` (noise σ = 2 mm); returns the
/// estimates and the largest translation [m] and rotation [deg] error against the truth.
fn run(
    world_from_camera: &[Isometry3<f64>],
    local_map: bool,
) -> (Vec<mireg::odometry::FrameEstimate>, f64, f64) {
    let config = OdometryConfig {
        pair: PairConfig {
            voxel_size_m: 0.1,
            seed: 4,
            ..Default::default()
        },
        local_map,
        ..Default::default()
    };
    run_with(world_from_camera, &config)
}

/// [`run`] with any configuration.
fn run_with(
    world_from_camera: &[Isometry3<f64>],
    config: &OdometryConfig,
) -> (Vec<mireg::odometry::FrameEstimate>, f64, f64) {
    let world = scene();
    let mut odo = Odometry::new(config.clone()).unwrap();
    let noise = Normal::new(0.0, 0.002).unwrap();
    let mut rng = rand_pcg::Pcg64Mcg::seed_from_u64(9);
    let first = world_from_camera[0];
    let (mut worst_t, mut worst_r) = (0.0f64, 0.0f64);
    let mut out = Vec::new();
    for w in world_from_camera {
        let cam_from_world = w.inverse();
        let pts: Vec<Point3<f64>> = world
            .iter()
            .map(|p| {
                let q = cam_from_world * p;
                q + Vector3::from_fn(|_, _| noise.sample(&mut rng))
            })
            .collect();
        let est = odo
            .push(prepare_frame(&pts, &config.pair).unwrap())
            .unwrap();
        let truth = first.inverse() * w;
        let err = truth.inverse() * est.world_from_frame;
        worst_t = worst_t.max(err.translation.vector.norm());
        worst_r = worst_r.max(err.rotation.angle().to_degrees());
        out.push(est);
    }
    (out, worst_t, worst_r)
}

/// Constant motion over 14 frames with frame 5 dropped, then a yaw jump of `jump_deg` and 4
/// more frames: frame 13 of the result is the jump.
fn motion_with_a_drop_and_a_jump(jump_deg: f64) -> Vec<Isometry3<f64>> {
    let mut poses: Vec<_> = (0..14)
        .filter(|&k| k != 5)
        .map(|k| pose(0.05 * k as f64, 0.02 * k as f64, 1.0 * k as f64))
        .collect();
    let turn = pose(0.7, 0.3, jump_deg);
    poses.extend((0..4).map(|k| turn * pose(0.03 * k as f64, 0.0, 0.0)));
    poses
}

/// [`run_with`] over [`motion_with_a_drop_and_a_jump`], checking that the known motion is
/// tracked (worst error under 1 cm and 0.2°), that every frame registered, and that `map_fit`
/// holds of every map fit after the first frame. Returns the estimates.
fn tracks_a_drop_and_a_jump(
    jump_deg: f64,
    config: &OdometryConfig,
    map_fit: impl Fn(&MapFit) -> bool,
) -> Vec<mireg::odometry::FrameEstimate> {
    let (est, t, r) = run_with(&motion_with_a_drop_and_a_jump(jump_deg), config);
    assert!(t < 0.01 && r < 0.2, "worst error {t} m, {r} deg");
    assert!(est.iter().all(|e| e.success));
    for e in &est[1..] {
        let map = e.map.unwrap();
        assert!(map_fit(&map), "frame {}: {map:?}", e.index);
    }
    est
}

#[test]
fn constant_velocity_is_tracked() {
    let poses: Vec<_> = (0..25)
        .map(|k| pose(0.05 * k as f64, 0.02 * k as f64, 1.0 * k as f64))
        .collect();
    let (est, t, r) = run(&poses, true);
    assert!(t < 0.01 && r < 0.2, "worst error {t} m, {r} deg");
    assert!(est.iter().all(|e| e.success));
    assert!(est[1..].iter().all(|e| e.map.is_some_and(|m| m.used)));
}

#[test]
fn stop_and_go_is_tracked() {
    let mut x = 0.0;
    let poses: Vec<_> = (0..30)
        .map(|k| {
            if !(10..20).contains(&k) {
                x += 0.06;
            }
            pose(x, 0.0, 0.0)
        })
        .collect();
    let (_, t, r) = run(&poses, true);
    assert!(t < 0.01 && r < 0.2, "worst error {t} m, {r} deg");
}

/// A dropped frame doubles one step: the prediction is then wrong by a whole step (0.15 m and
/// 2°, 1.5 map distances). Tracking first, ICP from the prediction reaches the right pose; with
/// every frame registered globally, the global estimate is right and the map fit starts from it.
#[test]
fn a_dropped_frame_recovers() {
    let poses: Vec<_> = (0..16)
        .filter(|&k| k != 8)
        .map(|k| pose(0.15 * k as f64, 0.0, 2.0 * k as f64))
        .collect();
    let (_, t, r) = run(&poses, true);
    assert!(t < 0.01 && r < 0.2, "worst error {t} m, {r} deg");
    let config = OdometryConfig {
        pair: PairConfig {
            voxel_size_m: 0.1,
            seed: 4,
            ..Default::default()
        },
        track_first: false,
        ..Default::default()
    };
    let (est, t, r) = run_with(&poses, &config);
    assert!(t < 0.01 && r < 0.2, "worst error {t} m, {r} deg");
    assert_eq!(est[8].map.unwrap().guess, InitialGuess::Global);
}

/// A 90° turn between two frames (a kidnap for a motion prior): the global estimate wins.
#[test]
fn a_90_degree_yaw_jump_recovers() {
    let poses: Vec<_> = (0..12)
        .map(|k| pose(0.03 * k as f64, 0.0, if k >= 6 { 90.0 } else { 0.0 }))
        .collect();
    let (est, t, r) = run(&poses, true);
    assert!(t < 0.01 && r < 0.2, "worst error {t} m, {r} deg");
    let jump = est[6].map.unwrap();
    assert_eq!(jump.guess, InitialGuess::Global);
    assert!(jump.used);
}

/// A sensor standing still: the map holds it, whatever the noise does frame to frame.
#[test]
fn a_static_sensor_does_not_drift() {
    let poses = vec![pose(0.3, -0.2, 10.0); 40];
    let (est, t, r) = run(&poses, true);
    let last = est.last().unwrap().world_from_frame;
    assert!(t < 0.002 && r < 0.05, "worst error {t} m, {r} deg");
    assert!(last.translation.vector.norm() < 0.001, "{last:?}");
}

/// Global registration on a coarser cloud than ICP (`mireg register` on dense frames): the map
/// refinement runs coarse to fine, and the known motion, a dropped frame and a 90° jump are
/// still recovered.
#[test]
fn global_registration_on_a_coarser_cloud_tracks_known_motion() {
    let fine = PairConfig {
        voxel_size_m: 0.05,
        seed: 4,
        ..Default::default()
    };
    let config = OdometryConfig {
        pair: mireg::pipeline::with_feature_voxel(&fine, 0.12),
        ..Default::default()
    };
    // Coarse iterations happen only where the feature cloud is not the ICP cloud.
    let est = tracks_a_drop_and_a_jump(100.0, &config, |map| {
        map.used
            && map.coarse_iterations > 0
            && map.iterations <= mireg::odometry::MAP_ICP_MAX_ITERATIONS_AFTER_COARSE
    });
    // The jump (frame 13) is recovered from the global estimate.
    assert_eq!(est[13].map.unwrap().guess, InitialGuess::Global);
}

/// The map's fine stage on, with frames prepared as `mireg register` prepares them for it
/// (`icp_fine`: they carry input points).
fn map_fine_config() -> OdometryConfig {
    OdometryConfig {
        pair: PairConfig {
            voxel_size_m: 0.1,
            seed: 4,
            icp_fine: true,
            ..Default::default()
        },
        map_fine: true,
        ..Default::default()
    }
}

/// `map_fine`: the map ICP's last stage with the frames' own input points (prepared with
/// `icp_fine`, as `mireg register --map-fine` prepares them) runs on every frame and keeps the
/// known motion, a dropped frame and a 90° jump as well as without it.
#[test]
fn the_map_fine_stage_tracks_known_motion() {
    let config = map_fine_config();
    tracks_a_drop_and_a_jump(90.0, &config, |map| map.used && map.fine_iterations > 0);
    // Without it, no fine iterations.
    let off = OdometryConfig {
        map_fine: false,
        ..config
    };
    let (est, _, _) = run_with(&motion_with_a_drop_and_a_jump(90.0), &off);
    assert!(est[1..].iter().all(|e| e.map.unwrap().fine_iterations == 0));
}

/// Global registration on a cloud coarse enough that the map ICP's coarse source is at most a
/// quarter of the ICP cloud, with the fine stage on: the fine stage follows every coarse stage
/// that converged below its iteration cap directly (no update of the whole ICP cloud,
/// `MAP_FINE_FINISHES_MIN_STRIDE`), and the known motion, a dropped frame and a 90° jump are
/// kept as well. Without the fine stage the whole cloud finishes as before.
#[test]
fn the_fine_stage_finishes_a_sparse_coarse_stage() {
    let base = map_fine_config();
    let config = OdometryConfig {
        pair: mireg::pipeline::with_feature_voxel(
            &PairConfig {
                voxel_size_m: 0.05,
                ..base.pair.clone()
            },
            0.3,
        ),
        ..base
    };
    let cap = config.pair.icp_max_iterations;
    let est = tracks_a_drop_and_a_jump(90.0, &config, |map| {
        map.used && map.fine_iterations > 0 && (map.coarse_iterations == cap || map.iterations == 0)
    });
    assert!(
        est[1..]
            .iter()
            .any(|e| e.map.unwrap().coarse_iterations > 0),
        "no frame ran the coarse stage"
    );
    let off = OdometryConfig {
        map_fine: false,
        ..config
    };
    let (est, _, _) = run_with(&motion_with_a_drop_and_a_jump(90.0), &off);
    assert!(
        est[1..]
            .iter()
            .filter_map(|e| e.map)
            .filter(|m| m.used && m.coarse_iterations > 0)
            .all(|m| m.iterations > 0)
    );
}

/// Frames thinned to the input points the map's fine stage uses (`keep_map_fine_points`, as
/// `mireg register`'s preparing thread does) give the same poses, bit for bit, as frames that
/// carry all of them; they carry fewer.
#[test]
fn frames_thinned_to_the_fine_points_give_the_same_poses() {
    let config = map_fine_config();
    let world = scene();
    let noise = Normal::new(0.0, 0.002).unwrap();
    let mut rng = rand_pcg::Pcg64Mcg::seed_from_u64(11);
    let (mut whole, mut thinned) = (
        Odometry::new(config.clone()).unwrap(),
        Odometry::new(config.clone()).unwrap(),
    );
    for w in &motion_with_a_drop_and_a_jump(90.0)[..8] {
        let pts: Vec<Point3<f64>> = world
            .iter()
            .map(|p| w.inverse() * p + Vector3::from_fn(|_, _| noise.sample(&mut rng)))
            .collect();
        // Prepared twice: the same frame (preparation is deterministic).
        let frame = prepare_frame(&pts, &config.pair).unwrap();
        let mut thin = prepare_frame(&pts, &config.pair).unwrap();
        mireg::odometry::keep_map_fine_points(&mut thin);
        assert!(
            thin.fine.len() < frame.fine.len(),
            "{} of {}",
            thin.fine.len(),
            frame.fine.len()
        );
        let cap = mireg::odometry::MAP_FINE_POINTS_PER_ICP_POINT
            * thin.icp.as_ref().unwrap().points().len();
        assert!(thin.fine.len() <= cap.min(mireg::odometry::MAP_FINE_MAX_POINTS));
        let (a, b) = (whole.push(frame).unwrap(), thinned.push(thin).unwrap());
        assert_eq!(a.world_from_frame, b.world_from_frame);
        assert!(
            a.map
                .is_none_or(|m| m.fine_iterations == b.map.unwrap().fine_iterations)
        );
    }
}
