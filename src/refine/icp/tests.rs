//! Tests of point-to-plane ICP: exact convergence forward and inverse, noise and outliers,
//! thread-count independence, Open3D-equal evaluation, degenerate geometry, bad input.

use super::*;
use crate::geometry::NormalEstimate;
use nalgebra::Unit;
use nalgebra::Vector3;
use rand::{RngExt, SeedableRng};
use rand_distr::Distribution;
use rand_pcg::Pcg64Mcg;

/// Box corner (floor + two walls) and a sphere, ~6k points at 4 cm spacing, with analytic
/// normals. Centred near the origin; all six degrees of freedom are constrained.
pub(super) fn corner_and_sphere() -> (Vec<Point3<f64>>, Vec<Vector3<f64>>) {
    let spacing = 0.04;
    let offset = Vector3::new(-1.0, -1.0, -0.5);
    let mut points = Vec::new();
    let mut normals = Vec::new();
    let steps = |len: f64| (0..(len / spacing) as usize).map(|i| (i as f64 + 0.5) * spacing);
    for a in steps(2.0) {
        for b in steps(2.0) {
            points.push(Point3::new(a, b, 0.0) + offset);
            normals.push(Vector3::z());
        }
        for b in steps(1.5) {
            points.push(Point3::new(0.0, a, b) + offset);
            normals.push(Vector3::x());
            points.push(Point3::new(a, 0.0, b) + offset);
            normals.push(Vector3::y());
        }
    }
    // Fibonacci sphere.
    let centre = Point3::new(1.2, 1.1, 0.5) + offset;
    let radius = 0.35;
    let n = 1000;
    let golden = std::f64::consts::PI * (3.0 - 5f64.sqrt());
    for i in 0..n {
        let z = 1.0 - 2.0 * (i as f64 + 0.5) / n as f64;
        let r = (1.0 - z * z).sqrt();
        let phi = golden * i as f64;
        let dir = Vector3::new(r * phi.cos(), r * phi.sin(), z);
        points.push(centre + radius * dir);
        normals.push(dir);
    }
    (points, normals)
}

pub(super) fn ground_truth() -> Isometry3<f64> {
    let axis = Unit::new_normalize(Vector3::new(0.3, -0.5, 0.8));
    Isometry3::from_parts(
        Translation3::new(0.4, -0.2, 0.1),
        UnitQuaternion::from_axis_angle(&axis, 25f64.to_radians()),
    )
}

/// Rotation by `angle_deg` about a random axis and translation of `shift_m` in a random
/// direction.
fn perturbation(rng: &mut Pcg64Mcg, angle_deg: f64, shift_m: f64) -> Isometry3<f64> {
    let mut random_unit = || {
        Unit::new_normalize(Vector3::new(
            rng.random_range(-1.0..1.0),
            rng.random_range(-1.0..1.0),
            rng.random_range(-1.0..1.0),
        ))
    };
    let axis = random_unit();
    let dir = random_unit();
    Isometry3::from_parts(
        Translation3::from(dir.into_inner() * shift_m),
        UnitQuaternion::from_axis_angle(&axis, angle_deg.to_radians()),
    )
}

/// (rotation error \[deg\], translation error \[m\]) of `estimate` against `truth`.
fn pose_error(estimate: &Isometry3<f64>, truth: &Isometry3<f64>) -> (f64, f64) {
    let delta = truth.inverse() * estimate;
    (
        delta.rotation.angle().to_degrees(),
        delta.translation.vector.norm(),
    )
}

pub(super) fn gaussian(rng: &mut Pcg64Mcg) -> f64 {
    rand_distr::StandardNormal.sample(rng)
}

#[test]
fn converges_exactly_forward_and_inverse() {
    let (scene, scene_normals) = corner_and_sphere();
    let target_from_source = ground_truth();
    let source_from_target = target_from_source.inverse();
    // Source = the scene seen from the source frame; at the truth every source point lies
    // exactly on its twin target point.
    let source: Vec<_> = scene.iter().map(|p| source_from_target * p).collect();
    let source_normals: Vec<_> = scene_normals
        .iter()
        .map(|n| source_from_target.rotation * n)
        .collect();
    let forward_target = IcpTarget::new(&scene, &scene_normals).unwrap();
    let inverse_target = IcpTarget::new(&source, &source_normals).unwrap();
    let config = IcpConfig::new(0.5).max_iterations(100);
    let mut rng = Pcg64Mcg::seed_from_u64(7);
    for _ in 0..3 {
        let delta = perturbation(&mut rng, 10.0, 0.2);
        let init = target_from_source * delta;
        let forward =
            registration_icp_point_to_plane(&source, &forward_target, &init, &config).unwrap();
        let (rot_deg, trans_m) = pose_error(&forward.target_from_source, &target_from_source);
        assert!(forward.converged, "{forward:?}");
        // Gauss-Newton on exact data converges quadratically: a handful of updates.
        assert!(forward.iterations <= 10, "{forward:?}");
        assert!(
            rot_deg < 0.01 && trans_m < 1e-4,
            "{rot_deg} deg {trans_m} m"
        );
        assert_eq!(forward.fitness, 1.0);
        assert!(forward.inlier_rmse_m < 1e-4);

        let inverse =
            registration_icp_point_to_plane(&scene, &inverse_target, &init.inverse(), &config)
                .unwrap();
        let (rot_deg, trans_m) = pose_error(&inverse.target_from_source, &source_from_target);
        assert!(inverse.converged, "{inverse:?}");
        assert!(inverse.iterations <= 10, "{inverse:?}");
        assert!(
            rot_deg < 0.01 && trans_m < 1e-4,
            "{rot_deg} deg {trans_m} m"
        );
    }
}

#[test]
fn converges_near_truth_with_noise_and_outliers() {
    let (scene, scene_normals) = corner_and_sphere();
    let target_from_source = ground_truth();
    let source_from_target = target_from_source.inverse();
    let mut rng = Pcg64Mcg::seed_from_u64(11);
    let noise_m = 0.003;
    let mut source: Vec<_> = scene
        .iter()
        .map(|p| {
            let noisy =
                p + Vector3::new(gaussian(&mut rng), gaussian(&mut rng), gaussian(&mut rng))
                    * noise_m;
            source_from_target * noisy
        })
        .collect();
    let target = IcpTarget::new(&scene, &scene_normals).unwrap();
    let init = target_from_source * perturbation(&mut rng, 10.0, 0.2);
    let config = IcpConfig::new(0.5).max_iterations(100);
    let result = registration_icp_point_to_plane(&source, &target, &init, &config).unwrap();
    let (rot_deg, trans_m) = pose_error(&result.target_from_source, &target_from_source);
    assert!(result.converged, "{result:?}");
    assert!(
        rot_deg < 0.1 && trans_m < 0.003,
        "{rot_deg} deg {trans_m} m"
    );
    // Nearest-neighbour distance of a noisy point is at most its offset: RMSE ≲ √3 σ.
    assert!(
        result.inlier_rmse_m < 3f64.sqrt() * noise_m * 1.1,
        "{result:?}"
    );

    // 15 % gross outliers in a 1 m shell around the scene: Tukey keeps the estimate close.
    let outliers = source.len() * 15 / 100;
    for _ in 0..outliers {
        let p = Point3::new(
            rng.random_range(-1.5..1.5),
            rng.random_range(-1.5..1.5),
            rng.random_range(-1.0..1.5),
        );
        source.push(source_from_target * p);
    }
    let robust = config.robust_kernel(RobustKernel::Tukey { scale_m: 0.05 });
    let result = registration_icp_point_to_plane(&source, &target, &init, &robust).unwrap();
    let (rot_deg, trans_m) = pose_error(&result.target_from_source, &target_from_source);
    assert!(
        rot_deg < 0.2 && trans_m < 0.005,
        "{rot_deg} deg {trans_m} m"
    );
}

#[test]
fn bit_identical_on_one_and_two_threads() {
    let (scene, scene_normals) = corner_and_sphere();
    let target = IcpTarget::new(&scene, &scene_normals).unwrap();
    let mut rng = Pcg64Mcg::seed_from_u64(3);
    let source: Vec<_> = scene
        .iter()
        .map(|p| ground_truth().inverse() * p + Vector3::repeat(0.002 * gaussian(&mut rng)))
        .collect();
    let init = ground_truth() * perturbation(&mut rng, 5.0, 0.1);
    let config = IcpConfig::new(0.4);
    let run = |threads: usize| {
        rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .unwrap()
            .install(|| registration_icp_point_to_plane(&source, &target, &init, &config))
            .unwrap()
    };
    assert!(source.len() > 4 * CHUNK_POINTS);
    assert_eq!(run(1), run(2));
}

#[test]
fn evaluation_matches_hand_computation() {
    let target = IcpTarget::points_only(&[
        Point3::new(0.0, 0.0, 0.0),
        Point3::new(1.0, 0.0, 0.0),
        Point3::new(0.0, 1.0, 0.0),
    ])
    .unwrap();
    let source = [
        Point3::new(0.1, 0.0, 0.0),  // → target 0 at 0.1
        Point3::new(1.0, 0.2, 0.0),  // → target 1 at 0.2
        Point3::new(0.0, 1.0, 0.05), // → target 2 at 0.05
        Point3::new(5.0, 5.0, 5.0),  // no correspondence within 0.3
    ];
    let identity = Isometry3::identity();
    let e = evaluate_registration(&source, &target, &identity, 0.3).unwrap();
    assert_eq!(e.num_inliers, 3);
    assert_eq!(e.fitness, 0.75);
    let expected_rmse = ((0.01 + 0.04 + 0.0025) / 3.0f64).sqrt();
    assert!((e.inlier_rmse_m - expected_rmse).abs() < 1e-12);

    // Shifting the source by −0.1 m in x: (0,0,0)→0 at 0, (0.9,0.2,0)→1 at √0.05,
    // (−0.1,1,0.05)→2 at √0.0125; threshold 0.2 drops the second.
    let shift = Isometry3::translation(-0.1, 0.0, 0.0);
    let e = evaluate_registration(&source, &target, &shift, 0.2).unwrap();
    assert_eq!(e.num_inliers, 2);
    assert_eq!(e.fitness, 0.5);
    assert!((e.inlier_rmse_m - (0.0125f64 / 2.0).sqrt()).abs() < 1e-12);

    // Nothing within reach: Open3D reports fitness 0 and RMSE 0.
    let far = Isometry3::translation(100.0, 0.0, 0.0);
    let e = evaluate_registration(&source, &target, &far, 0.3).unwrap();
    assert_eq!((e.fitness, e.inlier_rmse_m, e.num_inliers), (0.0, 0.0, 0));
}

#[test]
fn degenerate_plane_stays_finite_and_fixes_constrained_dofs() {
    // A single plane z = 0 constrains only z, roll and pitch: Cholesky fails, SVD solves.
    let mut points = Vec::new();
    for i in 0..40 {
        for j in 0..40 {
            points.push(Point3::new(i as f64 * 0.05, j as f64 * 0.05, 0.0));
        }
    }
    let normals = vec![Vector3::z(); points.len()];
    let target = IcpTarget::new(&points, &normals).unwrap();
    let init = Isometry3::from_parts(
        Translation3::new(0.0, 0.0, 0.05),
        UnitQuaternion::from_euler_angles(2f64.to_radians(), -1f64.to_radians(), 0.0),
    );
    let result =
        registration_icp_point_to_plane(&points, &target, &init, &IcpConfig::new(0.2)).unwrap();
    let moved: Vec<_> = points
        .iter()
        .map(|p| result.target_from_source * p)
        .collect();
    assert!(moved.iter().all(|p| p.z.abs() < 1e-6), "{result:?}");
}

#[test]
fn rejects_bad_input() {
    let p = [Point3::origin()];
    assert!(IcpTarget::new(&p, &[]).is_err());
    assert!(IcpTarget::points_only(&[]).is_err());
    let target = IcpTarget::new(&p, &[Vector3::z()]).unwrap();
    let id = Isometry3::identity();
    assert!(registration_icp_point_to_plane(&p, &target, &id, &IcpConfig::new(0.0)).is_err());
    assert!(registration_icp_point_to_plane(&[], &target, &id, &IcpConfig::new(1.0)).is_err());
    let points_only = IcpTarget::points_only(&p).unwrap();
    assert!(registration_icp_point_to_plane(&p, &points_only, &id, &IcpConfig::new(1.0)).is_err());
    let tukey = IcpConfig::new(1.0).robust_kernel(RobustKernel::Tukey { scale_m: -1.0 });
    assert!(registration_icp_point_to_plane(&p, &target, &id, &tukey).is_err());
}

#[test]
fn kernel_weights() {
    assert_eq!(RobustKernel::L2.weight(3.0), 1.0);
    let huber = RobustKernel::Huber { scale_m: 0.5 };
    assert_eq!(huber.weight(-0.25), 1.0);
    assert_eq!(huber.weight(2.0), 0.25);
    let tukey = RobustKernel::Tukey { scale_m: 2.0 };
    assert_eq!(tukey.weight(1.0), 0.5625); // (1 − 1/4)²
    assert_eq!(tukey.weight(-2.5), 0.0);
}

#[test]
fn nearest_equals_brute_force() {
    let mut rng = Pcg64Mcg::seed_from_u64(9);
    let mut random_point = |scale: f64| {
        Point3::new(
            rng.random_range(-scale..scale),
            rng.random_range(-scale..scale),
            rng.random_range(-scale..scale),
        )
    };
    let points: Vec<_> = (0..5000).map(|_| random_point(1.0)).collect();
    let queries: Vec<_> = (0..2000).map(|_| random_point(1.2)).collect();
    let target = IcpTarget::points_only(&points).unwrap();
    let max_squared = 0.1f64 * 0.1;
    let mut wrong = 0;
    for q in &queries {
        let truth = points
            .iter()
            .map(|p| (p - q).norm_squared())
            .fold(f64::INFINITY, f64::min);
        let got = target.nearest(q, max_squared).map(|(_, d)| d);
        let expected = (truth <= max_squared).then_some(truth);
        wrong += (got != expected) as usize;
    }
    assert_eq!(wrong, 0);
}

#[test]
fn a_minimum_update_stops_early_and_bad_values_are_rejected() {
    let (scene, scene_normals) = corner_and_sphere();
    let target = IcpTarget::new(&scene, &scene_normals).unwrap();
    let mut rng = Pcg64Mcg::seed_from_u64(8);
    let source: Vec<_> = scene.iter().map(|p| ground_truth().inverse() * p).collect();
    let init = ground_truth() * perturbation(&mut rng, 3.0, 0.05);
    let full =
        registration_icp_point_to_plane(&source, &target, &init, &IcpConfig::new(0.4)).unwrap();
    // An update always smaller than 1 m and 1 rad: one step, then stop.
    let one = IcpConfig::new(0.4).min_update(1.0, 1.0);
    let r = registration_icp_point_to_plane(&source, &target, &init, &one).unwrap();
    assert!(full.iterations > 1, "{full:?}");
    assert_eq!((r.iterations, r.converged), (1, true));
    // Thresholds of zero never fire: the same run as without them.
    let zero = IcpConfig::new(0.4).min_update(0.0, 0.0);
    assert_eq!(
        registration_icp_point_to_plane(&source, &target, &init, &zero).unwrap(),
        full
    );
    let bad = IcpConfig::new(0.4).min_update(-1.0, 0.0);
    assert!(registration_icp_point_to_plane(&source, &target, &init, &bad).is_err());
}

#[test]
fn skipping_the_pass_after_the_last_update_keeps_the_pose_and_measures_the_pose_before_it() {
    let (scene, scene_normals) = corner_and_sphere();
    let target = IcpTarget::new(&scene, &scene_normals).unwrap();
    let mut rng = Pcg64Mcg::seed_from_u64(9);
    let source: Vec<_> = scene.iter().map(|p| ground_truth().inverse() * p).collect();
    let init = ground_truth() * perturbation(&mut rng, 3.0, 0.05);
    let measured = IcpConfig::new(0.4).min_update(1e-3, 1e-3);
    let with = registration_icp_point_to_plane(&source, &target, &init, &measured).unwrap();
    let skipped = measured.measure_final_pose(false);
    let without = registration_icp_point_to_plane(&source, &target, &init, &skipped).unwrap();
    assert!(with.iterations >= 2 && with.converged, "{with:?}");
    assert_eq!(without.target_from_source, with.target_from_source);
    assert_eq!(
        (without.iterations, without.converged),
        (with.iterations, true)
    );
    // Oracle: the same run stopped one update earlier, measured by `evaluate_registration`.
    let earlier = IcpConfig::new(0.4).max_iterations(with.iterations - 1);
    let before = registration_icp_point_to_plane(&source, &target, &init, &earlier).unwrap();
    let e = evaluate_registration(&source, &target, &before.target_from_source, 0.4).unwrap();
    assert!(
        (without.fitness - e.fitness).abs() < 1e-12,
        "{without:?} {e:?}"
    );
    assert!(
        (without.inlier_rmse_m - e.inlier_rmse_m).abs() < 1e-12,
        "{without:?} {e:?}"
    );
    assert_ne!(without.inlier_rmse_m, with.inlier_rmse_m);
    // Stopped by the iteration cap instead: the same pose as the measured run, measured one
    // update earlier (oracle: the run capped one update sooner), and not converged.
    let capped = IcpConfig::new(0.4).max_iterations(2);
    let with = registration_icp_point_to_plane(&source, &target, &init, &capped).unwrap();
    let without =
        registration_icp_point_to_plane(&source, &target, &init, &capped.measure_final_pose(false))
            .unwrap();
    assert_eq!((with.iterations, with.converged), (2, false), "{with:?}");
    assert_eq!(without.target_from_source, with.target_from_source);
    assert_eq!((without.iterations, without.converged), (2, false));
    let once = IcpConfig::new(0.4).max_iterations(1);
    let before = registration_icp_point_to_plane(&source, &target, &init, &once).unwrap();
    let (e, hessian) =
        evaluate_with_hessian(&source, &target, &before.target_from_source, 0.4).unwrap();
    assert_eq!(
        (without.fitness, without.inlier_rmse_m),
        (e.fitness, e.inlier_rmse_m)
    );
    assert_eq!(without.hessian, hessian);
    assert_ne!(without.inlier_rmse_m, with.inlier_rmse_m);
}

#[test]
fn a_target_rebuilt_in_its_storage_answers_as_a_new_one() {
    let (scene, scene_normals) = corner_and_sphere();
    let mut rng = Pcg64Mcg::seed_from_u64(12);
    let source: Vec<_> = scene.iter().map(|p| ground_truth().inverse() * p).collect();
    let init = ground_truth() * perturbation(&mut rng, 3.0, 0.05);
    let config = IcpConfig::new(0.3);
    // A target first holding another cloud (its grid built), then rebuilt in its storage with
    // the scene.
    let half = scene.len() / 2;
    let old = IcpTarget::new(&scene[half..], &scene_normals[half..]).unwrap();
    old.prepare_for_distance(0.3).unwrap();
    let (mut p, mut n, spare) = old.into_storage();
    p.clear();
    n.clear();
    p.extend_from_slice(&scene);
    n.extend_from_slice(&scene_normals);
    let reused = IcpTarget::from_storage(p, n, spare).unwrap();
    let fresh = IcpTarget::new(&scene, &scene_normals).unwrap();
    assert_eq!(
        registration_icp_point_to_plane(&source, &reused, &init, &config).unwrap(),
        registration_icp_point_to_plane(&source, &fresh, &init, &config).unwrap()
    );
    // A rebuild with a bad normal is an error, not a panic.
    let (mut p, mut n, spare) = reused.into_storage();
    p.clear();
    n.clear();
    p.push(Point3::origin());
    n.push(Vector3::new(f64::NAN, 0.0, 1.0));
    assert!(IcpTarget::from_storage(p, n, spare).is_err());
}

#[test]
fn deferred_normals_answer_as_given_ones() {
    let (scene, _) = corner_and_sphere();
    let mut rng = Pcg64Mcg::seed_from_u64(5);
    let estimate = NormalEstimate::new(0.1, 30, Some(Point3::new(0.2, 0.3, 2.0)), 1 << 20).unwrap();
    let normals = estimate.estimate(&scene, None).unwrap();
    let given = IcpTarget::new(&scene, &normals).unwrap();
    // A few normals before all of them are estimated, and after: the given ones, bit for bit.
    let deferred = IcpTarget::with_deferred_normals(scene.clone(), estimate).unwrap();
    assert!(deferred.has_normals());
    let at = [7u32, 0, 4000, 3];
    let picked: Vec<_> = at.iter().map(|&i| normals[i as usize]).collect();
    assert_eq!(deferred.normals_at(&at).unwrap(), picked);
    let source: Vec<_> = scene.iter().map(|p| ground_truth().inverse() * p).collect();
    let init = ground_truth() * perturbation(&mut rng, 3.0, 0.05);
    let config = IcpConfig::new(0.3);
    // A fitness alone needs no normals: evaluating against the target leaves them unestimated
    // (the loop's overlap the other way, on query frames that are never a target).
    assert!(deferred.pending_normal_bytes() > 0);
    assert_eq!(
        evaluate_registration(&source, &deferred, &init, 0.3).unwrap(),
        evaluate_registration(&source, &given, &init, 0.3).unwrap()
    );
    assert!(
        deferred.pending_normal_bytes() > 0,
        "evaluation estimated the normals"
    );
    assert_eq!(
        registration_icp_point_to_plane(&source, &deferred, &init, &config).unwrap(),
        registration_icp_point_to_plane(&source, &given, &init, &config).unwrap()
    );
    assert_eq!(deferred.pending_normal_bytes(), 0, "ICP estimated them");
    assert_eq!(deferred.normals().unwrap(), &normals[..]);
    assert_eq!(deferred.normals_at(&at).unwrap(), picked);
    // An index outside the cloud has no normal; a target without normals has none at all.
    assert_eq!(deferred.normals_at(&[scene.len() as u32]), None);
    let bare = IcpTarget::points_only(&scene).unwrap();
    assert!(!bare.has_normals());
    assert_eq!(bare.normals_at(&at), None);
    assert!(registration_icp_point_to_plane(&source, &bare, &init, &config).is_err());
    assert!(IcpTarget::with_deferred_normals(Vec::new(), estimate).is_err());
}

#[test]
fn asking_for_most_deferred_normals_estimates_and_keeps_them_all() {
    let (scene, _) = corner_and_sphere();
    let estimate = NormalEstimate::new(0.1, 30, Some(Point3::new(0.2, 0.3, 2.0)), 1 << 20).unwrap();
    let normals = estimate.estimate(&scene, None).unwrap();
    let half = (ESTIMATE_ALL_FRACTION * scene.len() as f64).ceil() as usize;
    let pick = |at: &[u32]| -> Vec<_> { at.iter().map(|&i| normals[i as usize]).collect() };
    // One index fewer than the share: those alone, the rest still pending.
    let fewer: Vec<u32> = (0..half as u32 - 1).rev().collect();
    let deferred = IcpTarget::with_deferred_normals(scene.clone(), estimate).unwrap();
    assert_eq!(deferred.normals_at(&fewer).unwrap(), pick(&fewer));
    assert!(deferred.pending_normal_bytes() > 0);
    // The share: every normal estimated and kept, the same values.
    let most: Vec<u32> = (0..half as u32)
        .map(|i| (i * 7) % scene.len() as u32)
        .collect();
    assert_eq!(deferred.normals_at(&most).unwrap(), pick(&most));
    assert_eq!(deferred.pending_normal_bytes(), 0, "all of them estimated");
    assert_eq!(deferred.normals().unwrap(), &normals[..]);
}
