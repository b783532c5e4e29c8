//! Trajectory error metrics (Sturm et al. 2012, "A Benchmark for the Evaluation of RGB-D SLAM
//! Systems"): absolute trajectory error after alignment and relative pose error. Pure functions.

use nalgebra::{Isometry3, Matrix3, Point3, Translation3, UnitQuaternion, Vector3};

/// Relative pose error between consecutive frames: for each `k ≥ 1`,
/// `E_k = (gt_{k−1}⁻¹ gt_k)⁻¹ (est_{k−1}⁻¹ est_k)`; returns per-frame (translation [m],
/// rotation [deg]) of `E_k` (Sturm et al., Eq. 1 with Δ = 1).
pub fn relative_pose_errors(
    estimate: &[Isometry3<f64>],
    truth: &[Isometry3<f64>],
) -> Vec<(f64, f64)> {
    assert_eq!(estimate.len(), truth.len(), "trajectories differ in length");
    (1..estimate.len())
        .map(|k| {
            let d_est = estimate[k - 1].inverse() * estimate[k];
            let d_gt = truth[k - 1].inverse() * truth[k];
            let e = d_gt.inverse() * d_est;
            (e.translation.vector.norm(), e.rotation.angle().to_degrees())
        })
        .collect()
}

/// Rigid alignment `truth_from_estimate` minimising `Σ ‖truth_k.t − T·estimate_k.t‖²` over the
/// positions (Umeyama 1991 without scale); identity for fewer than 3 non-collinear positions.
pub fn align_positions(estimate: &[Isometry3<f64>], truth: &[Isometry3<f64>]) -> Isometry3<f64> {
    assert_eq!(estimate.len(), truth.len(), "trajectories differ in length");
    let n = estimate.len();
    if n < 3 {
        return Isometry3::identity();
    }
    let p: Vec<Point3<f64>> = estimate
        .iter()
        .map(|e| Point3::from(e.translation.vector))
        .collect();
    let q: Vec<Point3<f64>> = truth
        .iter()
        .map(|e| Point3::from(e.translation.vector))
        .collect();
    let cp = p.iter().fold(Vector3::zeros(), |a, x| a + x.coords) / n as f64;
    let cq = q.iter().fold(Vector3::zeros(), |a, x| a + x.coords) / n as f64;
    let mut h = Matrix3::zeros();
    for (a, b) in p.iter().zip(&q) {
        h += (a.coords - cp) * (b.coords - cq).transpose();
    }
    let svd = h.svd(true, true);
    let (Some(u), Some(v_t)) = (svd.u, svd.v_t) else {
        return Isometry3::identity();
    };
    let v = v_t.transpose();
    let mut d = Matrix3::identity();
    if (v * u.transpose()).determinant() < 0.0 {
        d[(2, 2)] = -1.0;
    }
    let r = nalgebra::Rotation3::from_matrix_unchecked(v * d * u.transpose());
    let rotation = UnitQuaternion::from_rotation_matrix(&r);
    Isometry3::from_parts(Translation3::from(cq - rotation * cp), rotation)
}

/// Absolute trajectory error: RMSE of position differences [m] after [`align_positions`].
pub fn ate_rmse(estimate: &[Isometry3<f64>], truth: &[Isometry3<f64>]) -> f64 {
    if estimate.is_empty() {
        return 0.0;
    }
    let t = align_positions(estimate, truth);
    let sum: f64 = estimate
        .iter()
        .zip(truth)
        .map(|(e, g)| ((t * e).translation.vector - g.translation.vector).norm_squared())
        .sum();
    (sum / estimate.len() as f64).sqrt()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn path(n: usize) -> Vec<Isometry3<f64>> {
        (0..n)
            .map(|k| {
                let a = k as f64 * 0.1;
                Isometry3::from_parts(
                    Translation3::new(a.cos() * 3.0, a.sin() * 2.0, 0.1 * k as f64),
                    UnitQuaternion::from_euler_angles(0.0, 0.0, a),
                )
            })
            .collect()
    }

    #[test]
    fn identical_trajectories_have_zero_error() {
        let p = path(20);
        assert!(ate_rmse(&p, &p) < 1e-12);
        assert!(
            relative_pose_errors(&p, &p)
                .iter()
                .all(|&(t, r)| t < 1e-12 && r < 1e-9)
        );
    }

    #[test]
    fn fixed_offset_vanishes_after_alignment() {
        let gt = path(30);
        let offset = Isometry3::from_parts(
            Translation3::new(5.0, -1.0, 2.0),
            UnitQuaternion::from_euler_angles(0.3, -0.2, 1.0),
        );
        let est: Vec<_> = gt.iter().map(|g| offset * g).collect();
        assert!(ate_rmse(&est, &gt) < 1e-9);
        // RPE is invariant to a global offset.
        assert!(
            relative_pose_errors(&est, &gt)
                .iter()
                .all(|&(t, r)| t < 1e-9 && r < 1e-7)
        );
    }

    #[test]
    fn pure_translation_drift() {
        // Each step overshoots by 1 cm along x in the frame's own axes (no rotation).
        let gt: Vec<_> = (0..10)
            .map(|k| Isometry3::translation(0.1 * k as f64, 0.0, 0.0))
            .collect();
        let est: Vec<_> = (0..10)
            .map(|k| Isometry3::translation(0.11 * k as f64, 0.0, 0.0))
            .collect();
        for (t, r) in relative_pose_errors(&est, &gt) {
            assert!((t - 0.01).abs() < 1e-12 && r.abs() < 1e-12);
        }
    }
}
