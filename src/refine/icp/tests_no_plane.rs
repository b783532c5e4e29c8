//! Tests of targets with points that have no plane (a zero normal, [`crate::geometry::NO_PLANE`]):
//! point-to-point rows for them, weighed against the point-to-plane rows by their share of the
//! correspondences.

use super::*;
use crate::geometry::NO_PLANE;
use nalgebra::Vector3;
use rand::{RngExt, SeedableRng};
use rand_pcg::Pcg64Mcg;

/// `n` points spread over a 4 m box, 0.3 m apart at least (an isolated point's nearest
/// neighbour in the target is itself after a small motion).
fn scattered(n: usize, seed: u64) -> Vec<Point3<f64>> {
    let mut rng = Pcg64Mcg::seed_from_u64(seed);
    let mut points: Vec<Point3<f64>> = Vec::new();
    while points.len() < n {
        let p = Point3::new(
            rng.random_range(-2.0..2.0),
            rng.random_range(-2.0..2.0),
            rng.random_range(0.5..2.0),
        );
        if points.iter().all(|q| (p - q).norm() > 0.3) {
            points.push(p);
        }
    }
    points
}

/// A floor z = 0, 5 cm apart, with its normal.
fn floor() -> (Vec<Point3<f64>>, Vec<Vector3<f64>>) {
    let points: Vec<Point3<f64>> = (0..60)
        .flat_map(|i| {
            (0..60).map(move |j| Point3::new(-1.5 + 0.05 * i as f64, -1.5 + 0.05 * j as f64, 0.0))
        })
        .collect();
    let normals = vec![Vector3::z(); points.len()];
    (points, normals)
}

/// A small motion: 3 cm along x and y, 1 cm up, 0.4° of yaw and 0.2° of roll.
fn small_motion() -> Isometry3<f64> {
    Isometry3::from_parts(
        Translation3::new(0.03, -0.03, 0.01),
        UnitQuaternion::from_euler_angles(0.2f64.to_radians(), 0.0, 0.4f64.to_radians()),
    )
}

/// The source `target_from_source⁻¹ · target`, registered from the identity.
fn register(
    target_points: &[Point3<f64>],
    normals: &[Vector3<f64>],
    target_from_source: &Isometry3<f64>,
) -> IcpResult {
    let target = IcpTarget::new(target_points, normals).unwrap();
    let source: Vec<Point3<f64>> = target_points
        .iter()
        .map(|p| target_from_source.inverse() * p)
        .collect();
    let config = IcpConfig::new(0.15).max_iterations(50);
    registration_icp_point_to_plane(&source, &target, &Isometry3::identity(), &config).unwrap()
}

fn errors(estimate: &Isometry3<f64>, truth: &Isometry3<f64>) -> (f64, f64) {
    let d = estimate.inverse() * truth;
    (d.translation.vector.norm(), d.rotation.angle())
}

#[test]
fn a_target_with_no_plane_is_registered_point_to_point_forward_and_inverse() {
    let points = scattered(300, 3);
    let normals = vec![NO_PLANE; points.len()];
    for truth in [small_motion(), small_motion().inverse()] {
        let result = register(&points, &normals, &truth);
        let (dt, dr) = errors(&result.target_from_source, &truth);
        assert!(dt < 1e-9 && dr < 1e-9, "{dt} m, {dr} rad: {result:?}");
        assert_eq!(result.fitness, 1.0);
    }
}

#[test]
fn points_with_no_plane_pin_down_what_a_floor_leaves_free() {
    // A floor alone fixes z, roll and pitch; x, y and yaw are free. A few isolated points above
    // it, matched point to point, fix them; given the floor's normal instead (Open3D's +z for a
    // point without neighbours) they add nothing the floor lacks.
    let (mut points, mut normals) = floor();
    let isolated = scattered(12, 5);
    points.extend(&isolated);
    let truth = small_motion();
    normals.extend(vec![NO_PLANE; isolated.len()]);
    let result = register(&points, &normals, &truth);
    let (dt, dr) = errors(&result.target_from_source, &truth);
    assert!(dt < 1e-9 && dr < 1e-9, "{dt} m, {dr} rad");

    let n = normals.len();
    normals[n - isolated.len()..].fill(Vector3::z());
    let plane_only = register(&points, &normals, &truth);
    let (dt, _) = errors(&plane_only.target_from_source, &truth);
    assert!(dt > 0.02, "x and y stay free with +z normals: {dt} m");
}

#[test]
fn each_kind_of_row_weighs_by_its_share_of_the_correspondences() {
    // GenZ-ICP's weight, checked on the sums of one pass at the identity: the floor's rows are
    // scaled by α = planar / (planar + point), the isolated points' by 1 − α.
    let (mut points, mut normals) = floor();
    let isolated = scattered(12, 5);
    points.extend(&isolated);
    normals.extend(vec![NO_PLANE; isolated.len()]);
    let target = IcpTarget::new(&points, &normals).unwrap();
    let shift = Isometry3::translation(0.01, 0.02, 0.03);
    let source: Vec<Point3<f64>> = points.iter().map(|p| shift * p).collect();
    let kernel = Some(RobustKernel::L2);
    let both = correspondence_pass(&source, &target, None, &Isometry3::identity(), 0.15, kernel);
    let planar = (points.len() - isolated.len()) as f64;
    let alpha = planar / (planar + isolated.len() as f64);
    // Oracle: the rows written out by hand. Floor: r = 0.03, J = (p × z, z); isolated points:
    // r = the shift's component, J = (p × e, e).
    let mut jtj = Matrix6::zeros();
    let mut jtr = Vector6::zeros();
    for (p, n) in source.iter().zip(&normals) {
        let d = shift.translation.vector;
        let rows: Vec<(Vector3<f64>, f64)> = if *n == NO_PLANE {
            [Vector3::x(), Vector3::y(), Vector3::z()]
                .into_iter()
                .zip(d.iter().copied())
                .collect()
        } else {
            vec![(*n, d.dot(n))]
        };
        let weight = if *n == NO_PLANE { 1.0 - alpha } else { alpha };
        for (e, r) in rows {
            let j = Vector6::from_iterator(p.coords.cross(&e).iter().chain(e.iter()).copied());
            jtj += weight * j * j.transpose();
            jtr += weight * r * j;
        }
    }
    let (got_jtj, got_jtr) = both.normal_equations();
    assert!(
        (got_jtj - jtj).norm() < 1e-9 * jtj.norm(),
        "{got_jtj} vs {jtj}"
    );
    assert!(
        (got_jtr - jtr).norm() < 1e-9 * jtr.norm(),
        "{got_jtr} vs {jtr}"
    );
    assert_eq!(
        both.hessian().count,
        points.len() - isolated.len() + 3 * isolated.len()
    );
}

#[test]
fn without_points_lacking_a_plane_the_sums_are_the_point_to_plane_ones_bit_for_bit() {
    let (points, normals) = floor();
    let target = IcpTarget::new(&points, &normals).unwrap();
    let shift = Isometry3::translation(0.0, 0.0, 0.02);
    let source: Vec<Point3<f64>> = points.iter().map(|p| shift * p).collect();
    let sums = correspondence_pass(
        &source,
        &target,
        None,
        &Isometry3::identity(),
        0.15,
        Some(RobustKernel::L2),
    );
    assert_eq!(sums.point.rows, 0);
    let (jtj, jtr) = sums.normal_equations();
    assert_eq!(jtj, upper_to_full(&sums.plane.jtj_upper));
    assert_eq!(jtr, Vector6::from(sums.plane.jtr));
}
