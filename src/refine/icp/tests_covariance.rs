//! The registration's Gauss–Newton covariance (`IcpHessian`) against oracles: a Monte-Carlo
//! estimate over noisy copies of a scene with a known transform, and the directions a plane or
//! two parallel walls leave free.

use super::tests::{corner_and_sphere, gaussian, ground_truth};
use super::*;
use crate::graph::se3;
use nalgebra::{Matrix3, SymmetricEigen, Vector3};
use rand::SeedableRng;
use rand_pcg::Pcg64Mcg;

/// Noise of every source point, each axis \[m\].
const NOISE_M: f64 = 0.003;

#[test]
fn hessian_covariance_matches_a_monte_carlo_estimate() {
    let (scene, normals) = corner_and_sphere();
    let truth = ground_truth();
    let target = IcpTarget::new(&scene, &normals).unwrap();
    // Every second scene point seen from the source frame; independent noise per trial.
    let clean: Vec<Point3<f64>> = scene
        .iter()
        .step_by(2)
        .map(|p| truth.inverse() * p)
        .collect();
    let config = IcpConfig::new(0.1).max_iterations(50);
    let mut rng = Pcg64Mcg::seed_from_u64(11);
    let trials = 120;
    let mut errors = Vec::with_capacity(trials);
    let mut predicted = Matrix6::zeros();
    for _ in 0..trials {
        let source: Vec<Point3<f64>> = clean
            .iter()
            .map(|p| {
                p + NOISE_M
                    * Vector3::new(gaussian(&mut rng), gaussian(&mut rng), gaussian(&mut rng))
            })
            .collect();
        let r = registration_icp_point_to_plane(&source, &target, &truth, &config).unwrap();
        assert!(r.converged, "{r:?}");
        // The right perturbation taking the truth to the estimate, (rotation, translation).
        errors.push(se3::log(&(truth.inverse() * r.target_from_source)));
        let omega = r
            .hessian
            .information_in_source(&r.target_from_source)
            .unwrap();
        predicted += omega.try_inverse().unwrap() / trials as f64;
        // The residual variance is the noise along the normal: σ².
        let variance = r.hessian.residual_variance_m2().unwrap();
        assert!(
            (variance / (NOISE_M * NOISE_M) - 1.0).abs() < 0.1,
            "residual variance {variance}"
        );
    }
    let mean: Vector6<f64> = errors.iter().sum::<Vector6<f64>>() / trials as f64;
    let sample: Matrix6<f64> = errors
        .iter()
        .map(|e| (e - mean) * (e - mean).transpose())
        .sum::<Matrix6<f64>>()
        / (trials - 1) as f64;
    // Each axis: the sample variance of 120 draws is within ±35 % of the truth with
    // probability > 0.99 (χ²(119) / 119 lies in [0.69, 1.36] at 99.6 %).
    for i in 0..6 {
        let ratio = sample[(i, i)] / predicted[(i, i)];
        assert!(
            (0.65..1.4).contains(&ratio),
            "axis {i}: sample {} predicted {} (ratio {ratio})",
            sample[(i, i)],
            predicted[(i, i)]
        );
    }
    // NEES: χ²(6) per trial, mean 6 with a standard error of √(12/120) = 0.32.
    let inverse = predicted.try_inverse().unwrap();
    let nees = errors.iter().map(|e| e.dot(&(inverse * e))).sum::<f64>() / trials as f64;
    assert!((nees - 6.0).abs() < 1.3, "mean NEES {nees}");
}

/// Points on a `2 × 2` m square grid at `spacing`, mapped by `place` (u, v) → point, each with
/// `normal`.
fn patch(
    place: impl Fn(f64, f64) -> Point3<f64>,
    normal: Vector3<f64>,
    spacing: f64,
) -> (Vec<Point3<f64>>, Vec<Vector3<f64>>) {
    let n = (2.0 / spacing) as usize;
    let mut points = Vec::new();
    for i in 0..n {
        for j in 0..n {
            points.push(place(i as f64 * spacing - 1.0, j as f64 * spacing - 1.0));
        }
    }
    let normals = vec![normal; points.len()];
    (points, normals)
}

/// The registration of a noisy copy of `points` (normals `normals`) onto itself: its Hessian.
fn self_registration(points: &[Point3<f64>], normals: &[Vector3<f64>]) -> IcpHessian {
    let target = IcpTarget::new(points, normals).unwrap();
    let mut rng = Pcg64Mcg::seed_from_u64(3);
    let source: Vec<Point3<f64>> = points
        .iter()
        .map(|p| {
            p + NOISE_M * Vector3::new(gaussian(&mut rng), gaussian(&mut rng), gaussian(&mut rng))
        })
        .collect();
    let config = IcpConfig::new(0.1).max_iterations(5);
    registration_icp_point_to_plane(&source, &target, &Isometry3::identity(), &config)
        .unwrap()
        .hessian
}

/// Eigenvalues (ascending) and eigenvectors of a symmetric 3×3 matrix.
fn eigen(m: Matrix3<f64>) -> Vec<(f64, Vector3<f64>)> {
    let e = SymmetricEigen::new(m);
    let mut pairs: Vec<(f64, Vector3<f64>)> = (0..3)
        .map(|i| (e.eigenvalues[i], e.eigenvectors.column(i).into_owned()))
        .collect();
    pairs.sort_by(|a, b| a.0.total_cmp(&b.0));
    pairs
}

#[test]
fn a_plane_leaves_its_in_plane_motions_free() {
    let (points, normals) = patch(|u, v| Point3::new(u, v, 0.0), Vector3::z(), 0.05);
    let h = self_registration(&points, &normals);
    let omega = h.information_in_source(&Isometry3::identity()).unwrap();
    // Translation: only z is measured.
    let t = eigen(omega.fixed_view::<3, 3>(3, 3).into_owned());
    assert!(t[1].0 < 1e-9 * t[2].0, "{t:?}");
    assert!(
        t[2].1.z.abs() > 0.999,
        "the measured direction is the normal: {t:?}"
    );
    // Rotation: about x and y (tilting the plane) measured, about z free.
    let r = eigen(omega.fixed_view::<3, 3>(0, 0).into_owned());
    assert!(r[0].0 < 1e-9 * r[2].0 && r[1].0 > 0.1 * r[2].0, "{r:?}");
    assert!(r[0].1.z.abs() > 0.999, "the free axis is the normal: {r:?}");
}

#[test]
fn two_parallel_walls_leave_the_corridor_axis_free() {
    // Walls x = ±1 m, running along y (the corridor) and up z.
    let (mut points, mut normals) = patch(|u, v| Point3::new(-1.0, u, v), Vector3::x(), 0.05);
    let (p2, n2) = patch(|u, v| Point3::new(1.0, u, v), -Vector3::x(), 0.05);
    points.extend(p2);
    normals.extend(n2);
    let h = self_registration(&points, &normals);
    let omega = h.information_in_source(&Isometry3::identity()).unwrap();
    let covariance = (omega + Matrix6::identity() * 1e-6).try_inverse().unwrap();
    // Translation along y and z is free: the covariance's two largest translation directions
    // span the walls' plane, the smallest is x, across the corridor.
    let t = eigen(covariance.fixed_view::<3, 3>(3, 3).into_owned());
    assert!(t[0].1.x.abs() > 0.999, "{t:?}");
    assert!(t[1].0 > 1e6 * t[0].0, "{t:?}");
    // Rotation about x (rolling along the walls) is free as well.
    let r = eigen(covariance.fixed_view::<3, 3>(0, 0).into_owned());
    assert!(r[2].1.x.abs() > 0.999, "{r:?}");
    assert!(r[2].0 > 1e6 * r[0].0, "{r:?}");
}
