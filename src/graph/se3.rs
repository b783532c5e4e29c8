//! SE(3) exponential and logarithm, adjoint and right Jacobians in GTSAM's Pose3 tangent order
//! **(rotation ω, translation v)**.
//!
//! `exp(ξ) = [Exp(ω), V(ω) v]`, `log(T) = [Log(R), V(ω)⁻¹ t]` with `V = J_l(ω)` the left Jacobian of
//! SO(3): exactly GTSAM's `Pose3::Expmap` / `Pose3::Logmap` (the full SE(3) maps, not a chart).
//! Jacobian formulas follow Barfoot, "State Estimation for Robotics" (2017), §7.1.5 (his `Q(ρ, φ)`),
//! rewritten for the (ω, v) ordering; unit tests check every one against finite differences.

use nalgebra::{Isometry3, Matrix3, Matrix6, Translation3, UnitQuaternion, Vector3, Vector6};

/// Below this rotation angle \[rad\] the trigonometric coefficients are evaluated by their Taylor
/// series (their closed forms lose digits to cancellation there).
const SMALL_ANGLE_RAD: f64 = 0.1;

/// Skew-symmetric matrix `[v]×` with `[v]× u = v × u`.
#[must_use]
pub fn hat(v: &Vector3<f64>) -> Matrix3<f64> {
    Matrix3::new(0.0, -v.z, v.y, v.z, 0.0, -v.x, -v.y, v.x, 0.0)
}

/// SO(3) logarithm of a unit quaternion: the rotation vector \[rad\], angle in `[0, π]`.
#[must_use]
pub fn so3_log(q: &UnitQuaternion<f64>) -> Vector3<f64> {
    let q = q.quaternion();
    // q and -q are the same rotation: take w ≥ 0 so that the angle is ≤ π.
    let (w, v) = if q.w < 0.0 {
        (-q.w, -q.imag())
    } else {
        (q.w, q.imag())
    };
    let s = v.norm();
    if s < 1e-8 {
        // θ/s = 2 atan(s/w)/s = (2/w)(1 − s²/(3w²) + …); w ≈ 1 here.
        v * (2.0 / w) * (1.0 - s * s / (3.0 * w * w))
    } else {
        v * (2.0 * s.atan2(w) / s)
    }
}

/// SO(3) exponential of a rotation vector \[rad\].
#[must_use]
pub fn so3_exp(w: &Vector3<f64>) -> UnitQuaternion<f64> {
    UnitQuaternion::from_scaled_axis(*w)
}

/// Coefficients `(a, b)` of `J_l(ω) = I + a [ω]× + b [ω]×²`:
/// `a = (1 − cos θ)/θ²`, `b = (θ − sin θ)/θ³`.
fn left_jacobian_coefficients(theta: f64) -> (f64, f64) {
    if theta < SMALL_ANGLE_RAD {
        let t2 = theta * theta;
        (
            0.5 - t2 / 24.0 + t2 * t2 / 720.0 - t2 * t2 * t2 / 40320.0,
            1.0 / 6.0 - t2 / 120.0 + t2 * t2 / 5040.0 - t2 * t2 * t2 / 362_880.0,
        )
    } else {
        let t2 = theta * theta;
        (
            (1.0 - theta.cos()) / t2,
            (theta - theta.sin()) / (t2 * theta),
        )
    }
}

/// Coefficient `c = 1/θ² − (1 + cos θ)/(2 θ sin θ)` of `J_l(ω)⁻¹ = I − ½[ω]× + c [ω]×²`.
fn inverse_jacobian_coefficient(theta: f64) -> f64 {
    if theta < SMALL_ANGLE_RAD {
        let t2 = theta * theta;
        1.0 / 12.0 + t2 / 720.0 + t2 * t2 / 30240.0 + t2 * t2 * t2 / 1_209_600.0
    } else {
        1.0 / (theta * theta) - (1.0 + theta.cos()) / (2.0 * theta * theta.sin())
    }
}

/// Left Jacobian of SO(3), `J_l(ω)` (= `V(ω)` of the SE(3) exponential).
#[must_use]
pub fn so3_left_jacobian(w: &Vector3<f64>) -> Matrix3<f64> {
    let (a, b) = left_jacobian_coefficients(w.norm());
    let k = hat(w);
    Matrix3::identity() + k * a + k * k * b
}

/// Inverse left Jacobian of SO(3), `J_l(ω)⁻¹`. Singular at θ = 2π, fine on `[0, π]`.
#[must_use]
pub fn so3_left_jacobian_inv(w: &Vector3<f64>) -> Matrix3<f64> {
    let c = inverse_jacobian_coefficient(w.norm());
    let k = hat(w);
    Matrix3::identity() - k * 0.5 + k * k * c
}

/// SE(3) exponential of `ξ = (ω [rad], v [m])` (GTSAM `Pose3::Expmap`).
#[must_use]
pub fn exp(xi: &Vector6<f64>) -> Isometry3<f64> {
    let w = xi.fixed_rows::<3>(0).into_owned();
    let v = xi.fixed_rows::<3>(3).into_owned();
    let t = so3_left_jacobian(&w) * v;
    Isometry3::from_parts(Translation3::from(t), so3_exp(&w))
}

/// SE(3) logarithm `(ω [rad], v [m])` (GTSAM `Pose3::Logmap`).
#[must_use]
pub fn log(pose: &Isometry3<f64>) -> Vector6<f64> {
    let w = so3_log(&pose.rotation);
    let v = so3_left_jacobian_inv(&w) * pose.translation.vector;
    Vector6::new(w.x, w.y, w.z, v.x, v.y, v.z)
}

/// Adjoint of `T = (R, t)` in (ω, v) order: `Ad_T = [[R, 0], [[t]× R, R]]`, so that
/// `T · Exp(ξ) · T⁻¹ = Exp(Ad_T ξ)` (GTSAM `Pose3::AdjointMap`).
#[must_use]
pub fn adjoint(pose: &Isometry3<f64>) -> Matrix6<f64> {
    let r = pose.rotation.to_rotation_matrix().into_inner();
    let tr = hat(&pose.translation.vector) * r;
    let mut ad = Matrix6::zeros();
    ad.fixed_view_mut::<3, 3>(0, 0).copy_from(&r);
    ad.fixed_view_mut::<3, 3>(3, 3).copy_from(&r);
    ad.fixed_view_mut::<3, 3>(3, 0).copy_from(&tr);
    ad
}

/// Barfoot's `Q(ρ, φ)` (eq. 7.86): the off-diagonal block of the SE(3) left Jacobian,
/// `J_l(ξ) = [[J_l(φ), 0], [Q(ρ, φ), J_l(φ)]]` in (ω, v) order.
fn barfoot_q(rho: &Vector3<f64>, phi: &Vector3<f64>) -> Matrix3<f64> {
    let theta = phi.norm();
    let (c1, c2, c3) = if theta < SMALL_ANGLE_RAD {
        let t2 = theta * theta;
        let t4 = t2 * t2;
        let t6 = t4 * t2;
        (
            1.0 / 6.0 - t2 / 120.0 + t4 / 5040.0 - t6 / 362_880.0,
            1.0 / 24.0 - t2 / 720.0 + t4 / 40320.0 - t6 / 3_628_800.0,
            1.0 / 120.0 - t2 / 2520.0 + t4 / 120_960.0 - t6 / 9_979_200.0,
        )
    } else {
        let (s, c) = theta.sin_cos();
        let t2 = theta * theta;
        (
            (theta - s) / (t2 * theta),
            (t2 + 2.0 * c - 2.0) / (2.0 * t2 * t2),
            (2.0 * theta - 3.0 * s + theta * c) / (2.0 * t2 * t2 * theta),
        )
    };
    let p = hat(phi);
    let r = hat(rho);
    let pr = p * r;
    let rp = r * p;
    let prp = pr * p;
    r * 0.5 + (pr + rp + prp) * c1 + (p * pr + rp * p - prp * 3.0) * c2 + (prp * p + p * prp) * c3
}

/// Inverse right Jacobian of SE(3) in (ω, v) order: `Log(Exp(ξ)·Exp(δ)) ≈ ξ + J_r(ξ)⁻¹ δ`
/// (GTSAM `Pose3::LogmapDerivative`).
#[must_use]
pub fn right_jacobian_inv(xi: &Vector6<f64>) -> Matrix6<f64> {
    // J_r(ξ) = J_l(−ξ) = [[J_r(ω), 0], [Q(−v, −ω), J_r(ω)]], J_r(ω) = J_l(−ω).
    let w = xi.fixed_rows::<3>(0).into_owned();
    let v = xi.fixed_rows::<3>(3).into_owned();
    let jinv = so3_left_jacobian_inv(&(-w));
    let q = barfoot_q(&(-v), &(-w));
    let mut out = Matrix6::zeros();
    out.fixed_view_mut::<3, 3>(0, 0).copy_from(&jinv);
    out.fixed_view_mut::<3, 3>(3, 3).copy_from(&jinv);
    out.fixed_view_mut::<3, 3>(3, 0)
        .copy_from(&(-(jinv * q * jinv)));
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    fn samples() -> Vec<Vector6<f64>> {
        vec![
            Vector6::new(0.3, -0.2, 0.5, 1.0, -2.0, 0.5),
            Vector6::new(1e-3, 2e-3, -1e-3, 0.1, 0.2, 0.3),
            Vector6::new(0.05, 0.0, 0.02, -0.4, 0.0, 0.1),
            Vector6::new(0.0, 0.0, 0.0, 1.0, 2.0, 3.0),
            Vector6::new(2.0, -1.0, 1.5, 0.3, -0.7, 2.0),
            Vector6::new(1e-9, -2e-9, 0.0, 1e-3, 0.0, 0.0),
        ]
    }

    #[test]
    fn exp_log_round_trip() {
        for xi in samples() {
            let back = log(&exp(&xi));
            assert!((back - xi).norm() < 1e-12, "{xi:?} -> {back:?}");
        }
    }

    #[test]
    fn adjoint_conjugates_exp() {
        let t = exp(&Vector6::new(0.4, -0.3, 0.9, 1.0, 2.0, -3.0));
        for xi in samples() {
            let lhs = t * exp(&xi) * t.inverse();
            let rhs = exp(&(adjoint(&t) * xi));
            assert!((log(&(lhs.inverse() * rhs))).norm() < 1e-12);
        }
    }

    #[test]
    fn right_jacobian_inverse_matches_finite_differences() {
        let h = 1e-6;
        for xi in samples() {
            let t = exp(&xi);
            let analytic = right_jacobian_inv(&xi);
            let mut numeric = Matrix6::zeros();
            for k in 0..6 {
                let mut d = Vector6::zeros();
                d[k] = h;
                let plus = log(&(t * exp(&d)));
                let minus = log(&(t * exp(&(-d))));
                numeric.set_column(k, &((plus - minus) / (2.0 * h)));
            }
            let err = (analytic - numeric).abs().max();
            assert!(err < 1e-7, "ξ = {xi:?}: max |J − J_fd| = {err:e}");
        }
    }

    #[test]
    fn so3_log_near_pi_and_identity() {
        let w = Vector3::new(0.0, 0.0, std::f64::consts::PI - 1e-9);
        assert!((so3_log(&so3_exp(&w)) - w).norm() < 1e-8);
        let w = Vector3::new(1e-12, 0.0, 0.0);
        assert!((so3_log(&so3_exp(&w)) - w).norm() < 1e-20);
    }
}
