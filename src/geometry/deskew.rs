//! Motion compensation of a spinning scan ("deskewing"): each point was measured at its own time
//! during the sweep, while the sensor moved; under constant velocity it is moved to where the
//! sensor at the reference time (the header stamp) would have seen it.
//!
//! The motion between two frames `dt` seconds apart, `prev_from_curr`, is a screw motion of
//! constant twist ξ = log(prev_from_curr) (SE(3) logarithm); the sensor at time `τ` after the
//! reference is at `exp(τ/dt · ξ)` in the reference sensor frame, so a point `p` measured then is
//! `exp(τ/dt · ξ) · p` there (as KISS-ICP's deskewing, Vizzo et al. 2023, Sec. IV-A, which
//! interpolates the same way).

use nalgebra::{Isometry3, Matrix3, Point3, Translation3, UnitQuaternion, Vector3};

/// The twist `(ω, v)` of `motion` (SE(3) logarithm): rotation vector \[rad\] and the translation
/// part \[m\], so that [`exp_twist`] of it gives `motion` back.
pub fn log_isometry(motion: &Isometry3<f64>) -> (Vector3<f64>, Vector3<f64>) {
    let omega = motion.rotation.scaled_axis();
    let v = left_jacobian(&omega)
        .try_inverse()
        .unwrap_or_else(Matrix3::identity)
        * motion.translation.vector;
    (omega, v)
}

/// `exp((ω, v))` in SE(3).
pub fn exp_twist(omega: &Vector3<f64>, v: &Vector3<f64>) -> Isometry3<f64> {
    Isometry3::from_parts(
        Translation3::from(left_jacobian(omega) * v),
        UnitQuaternion::from_scaled_axis(*omega),
    )
}

/// SO(3) left Jacobian `V(ω) = I + (1 − cos θ)/θ² [ω]× + (θ − sin θ)/θ³ [ω]×²`, with its series
/// near θ = 0.
fn left_jacobian(omega: &Vector3<f64>) -> Matrix3<f64> {
    let theta = omega.norm();
    let w = omega.cross_matrix();
    let (a, b) = if theta < 1e-5 {
        (
            0.5 - theta * theta / 24.0,
            1.0 / 6.0 - theta * theta / 120.0,
        )
    } else {
        let t2 = theta * theta;
        (
            (1.0 - theta.cos()) / t2,
            (theta - theta.sin()) / (t2 * theta),
        )
    };
    Matrix3::identity() + w * a + w * w * b
}

/// Where a sensor that moves by `motion` over some interval, at constant velocity, is after the
/// fraction `s` of it (negative: before its start): `exp(s · log(motion))`.
pub fn screw_fraction(motion: &Isometry3<f64>, s: f64) -> Isometry3<f64> {
    let (omega, v) = log_isometry(motion);
    exp_twist(&(omega * s), &(v * s))
}

/// Moves each of `points`, measured `times_s[i]` seconds after the reference time, into the
/// sensor frame at the reference time, for a sensor that moved by `prev_from_curr` in the
/// `dt_s` seconds before it (constant velocity).
///
/// # Panics
/// If `points` and `times_s` differ in length, or `dt_s` is not finite and positive.
pub fn deskew(
    points: &mut [Point3<f64>],
    times_s: &[f64],
    prev_from_curr: &Isometry3<f64>,
    dt_s: f64,
) {
    assert_eq!(points.len(), times_s.len(), "one time per point");
    assert!(
        dt_s.is_finite() && dt_s > 0.0,
        "dt_s must be > 0, got {dt_s}"
    );
    let (omega, v) = log_isometry(prev_from_curr);
    for (p, &t) in points.iter_mut().zip(times_s) {
        let s = t / dt_s;
        *p = exp_twist(&(omega * s), &(v * s)) * *p;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn log_and_exp_are_inverse() {
        for m in [
            Isometry3::identity(),
            Isometry3::from_parts(
                Translation3::new(1.0, -2.0, 0.3),
                UnitQuaternion::from_euler_angles(0.1, -0.4, 1.2),
            ),
            Isometry3::from_parts(
                Translation3::new(0.0, 0.0, 1e-9),
                UnitQuaternion::from_euler_angles(1e-8, 0.0, 0.0),
            ),
        ] {
            let (w, v) = log_isometry(&m);
            let back = exp_twist(&w, &v);
            assert!((back.to_homogeneous() - m.to_homogeneous()).norm() < 1e-12);
        }
    }
}
