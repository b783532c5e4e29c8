//! Kabsch against known rigid transforms, forward and inverse; degenerate samples rejected.

use mireg::ransac::estimator::DEFAULT_MIN_SINGULAR_RATIO;
use mireg::ransac::kabsch;
use nalgebra::{Isometry3, Point3, Translation3, UnitQuaternion, Vector3};
use rand::{RngExt, SeedableRng};
use rand_distr::Distribution;
use rand_pcg::Pcg64Mcg;

fn random_isometry(rng: &mut Pcg64Mcg) -> Isometry3<f64> {
    // Uniform rotation: a normalised 4-D standard normal vector is uniform on the unit
    // 3-sphere of quaternions.
    let v: [f64; 4] = std::array::from_fn(|_| rand_distr::StandardNormal.sample(rng));
    let q = nalgebra::Quaternion::new(v[0], v[1], v[2], v[3]);
    let t = Vector3::from_fn(|_, _| rng.random_range(-10.0..10.0));
    Isometry3::from_parts(Translation3::from(t), UnitQuaternion::from_quaternion(q))
}

fn random_points(rng: &mut Pcg64Mcg, n: usize) -> Vec<Point3<f64>> {
    (0..n)
        .map(|_| Point3::from(Vector3::from_fn(|_, _| rng.random_range(-5.0..5.0))))
        .collect()
}

fn pose_error(a: &Isometry3<f64>, b: &Isometry3<f64>) -> (f64, f64) {
    let d = a.inverse() * b;
    (d.rotation.angle(), d.translation.vector.norm())
}

#[test]
fn recovers_random_transforms_forward_and_inverse() {
    let mut rng = Pcg64Mcg::seed_from_u64(42);
    for n in [3, 4, 10, 100] {
        for _ in 0..50 {
            let gt = random_isometry(&mut rng);
            let src = random_points(&mut rng, n);
            let tgt: Vec<_> = src.iter().map(|p| gt * p).collect();
            let est = kabsch(&src, &tgt, DEFAULT_MIN_SINGULAR_RATIO).expect("non-degenerate");
            let (r, t) = pose_error(&gt, &est);
            assert!(r < 1e-9 && t < 1e-9, "n {n}: rot {r:e} rad, trans {t:e} m");
            let inv = kabsch(&tgt, &src, DEFAULT_MIN_SINGULAR_RATIO).expect("non-degenerate");
            let (r, t) = pose_error(&gt.inverse(), &inv);
            assert!(
                r < 1e-9 && t < 1e-9,
                "inverse n {n}: rot {r:e} rad, trans {t:e} m"
            );
        }
    }
}

#[test]
fn rejects_degenerate_samples() {
    let mut rng = Pcg64Mcg::seed_from_u64(7);
    let gt = random_isometry(&mut rng);
    let map = |pts: &[Point3<f64>]| pts.iter().map(|p| gt * p).collect::<Vec<_>>();
    // Too few points.
    let two = [Point3::new(0.0, 0.0, 0.0), Point3::new(1.0, 0.0, 0.0)];
    assert!(kabsch(&two, &map(&two), DEFAULT_MIN_SINGULAR_RATIO).is_none());
    // Collinear.
    let line: Vec<_> = (0..5)
        .map(|i| Point3::new(i as f64, 2.0 * i as f64, -(i as f64)))
        .collect();
    assert!(kabsch(&line, &map(&line), DEFAULT_MIN_SINGULAR_RATIO).is_none());
    // Near-collinear: 0.1 mm off a 1 m line.
    let near = [
        Point3::new(0.0, 0.0, 0.0),
        Point3::new(1.0, 0.0, 0.0),
        Point3::new(0.5, 1e-4, 0.0),
    ];
    assert!(kabsch(&near, &map(&near), DEFAULT_MIN_SINGULAR_RATIO).is_none());
    // Coincident (a sample that repeats one correspondence).
    let same = [Point3::new(1.0, 2.0, 3.0); 3];
    assert!(kabsch(&same, &map(&same), DEFAULT_MIN_SINGULAR_RATIO).is_none());
    // A proper triangle 10 cm wide over 1 m passes.
    let tri = [
        Point3::new(0.0, 0.0, 0.0),
        Point3::new(1.0, 0.0, 0.0),
        Point3::new(0.5, 0.1, 0.0),
    ];
    let est = kabsch(&tri, &map(&tri), DEFAULT_MIN_SINGULAR_RATIO).expect("triangle is fine");
    let (r, t) = pose_error(&gt, &est);
    assert!(r < 1e-9 && t < 1e-9);
}

#[test]
fn planar_points_with_reflection_ambiguity_give_a_rotation() {
    // Coplanar points admit a reflection with zero residual; Kabsch must return a proper rotation.
    let mut rng = Pcg64Mcg::seed_from_u64(9);
    let gt = random_isometry(&mut rng);
    let src: Vec<_> = (0..20)
        .map(|_| {
            Point3::new(
                rng.random_range(-1.0..1.0),
                rng.random_range(-1.0..1.0),
                0.0,
            )
        })
        .collect();
    let tgt: Vec<_> = src.iter().map(|p| gt * p).collect();
    let est = kabsch(&src, &tgt, DEFAULT_MIN_SINGULAR_RATIO).unwrap();
    let det = est.rotation.to_rotation_matrix().matrix().determinant();
    assert!((det - 1.0).abs() < 1e-12);
    let (r, t) = pose_error(&gt, &est);
    assert!(r < 1e-9 && t < 1e-9);
}

/// Open3D's distance checker: a model fitted to a sample survives only if it maps each sampled
/// source point strictly within the distance of its target point.
#[test]
fn sample_distance_check_rejects_samples_that_disagree_with_their_own_model() {
    use mireg::ransac::estimator::{Estimator, RigidEstimator};
    let mut rng = Pcg64Mcg::seed_from_u64(7);
    let gt = random_isometry(&mut rng);
    // A unit right triangle and a fourth point; correspondence 3 is moved 2 m along the first
    // edge in the target, which changes that triangle's edge lengths by more than 0.5 m: no
    // rigid model can then keep all three residuals below 0.25 m (|Δedge| ≤ rᵢ + rⱼ).
    let src = vec![
        Point3::new(0.0, 0.0, 0.0),
        Point3::new(1.0, 0.0, 0.0),
        Point3::new(0.0, 1.0, 0.0),
        Point3::new(1.0, 1.0, 0.0),
    ];
    let mut tgt: Vec<Point3<f64>> = src.iter().map(|p| gt * p).collect();
    tgt[3] = gt * Point3::new(3.0, 1.0, 0.0);
    let check = |distance: Option<f64>, sample: &[usize]| {
        let e = RigidEstimator::new(&src, &tgt)
            .edge_similarity(0.0)
            .sample_distance(distance);
        let model = e.estimate(sample).expect("non-degenerate sample");
        e.accept_model(&model, sample)
    };
    // Exact correspondences: residuals are rounding only.
    assert!(check(Some(1e-6), &[0, 1, 2]));
    for distance in [Some(0.05), Some(0.25)] {
        assert!(!check(distance, &[0, 1, 3]), "{distance:?}");
        assert!(!check(distance, &[1, 2, 3]), "{distance:?}");
    }
    // A distance beyond every residual accepts; no check accepts everything.
    assert!(check(Some(10.0), &[0, 1, 3]));
    assert!(check(None, &[0, 1, 3]));
}
