//! Each frame's pose uncertainty from its own registration: the point-to-plane ICP's
//! Gauss–Newton covariance `σ² (JᵀJ)⁻¹` ([`IcpHessian`]), moved into the frame and calibrated,
//! so that a frame whose geometry pins a direction down poorly (a corridor, the ground alone, a
//! narrow field of view, few points) is weak in that direction.
//!
//! Conventions: information and covariance are for the right perturbation `T · Exp(δ)` of the
//! frame's pose `T = world_from_frame`, `δ` in the frame, in the pose graph's (rotation \[rad\],
//! translation \[m\]) order ([`crate::graph::se3`]). For the relative step `prev⁻¹ · T` with the
//! previous pose held, the right perturbation is the same `δ`: the information is the odometry
//! edge's ([`crate::loops::pose_graph`]). [`PoseUncertainty::ros_covariance`] reorders into ROS's
//! `PoseWithCovariance` convention (x y z, then rotation about x y z, row-major).

use nalgebra::{Isometry3, Matrix3, Matrix6, SymmetricEigen, Vector6};

use crate::refine::icp::IcpHessian;

/// A registration's information counts at most this many correspondences: with `n` of them, its
/// Gauss–Newton information is scaled by `min(1, EFFECTIVE_CORRESPONDENCES / n)`, so that the
/// covariance follows the geometry's shape and the residuals' spread, not the number of points.
///
/// NOTE: not in the paper, which has no covariance. `σ² (JᵀJ)⁻¹` treats every correspondence as
/// an independent measurement; a frame's residuals are not (neighbouring points share the map's
/// voxel centroids and its surface-model error), so the raw covariance is over-confident by a
/// factor that grows with the number of points. Measured with `tools/calibrate_covariance.py`
/// (docs/ODOMETRY.md "Covariance"): the raw covariance's median NEES needed a scale of 10.6
/// (the ICL-NUIM fixture, exact ground truth), 41 (micro211) and 413 (KAIST03) — 40× apart —
/// where the scale per correspondence was 0.005, 0.021 and 0.029: 6× apart. 100 is between the
/// two ICL-NUIM logs' (1/0.005 and 1/0.021); KAIST03's reference, a SLAM estimate good to
/// centimetres, adds its own step error to the NEES.
pub const EFFECTIVE_CORRESPONDENCES: f64 = 100.0;

/// Standard deviation of a step nothing measured, per voxel of the log's ICP voxel: 10 voxels
/// of translation (each axis). A failed frame's step has this much; every frame's information is
/// at least this prior's, so that a degenerate direction is uncertain, not undetermined.
pub const UNINFORMED_SIGMA_VOXELS: f64 = 10.0;

/// Standard deviation of the rotation of a step nothing measured \[deg\] (each axis): 20.
pub const UNINFORMED_SIGMA_DEG: f64 = 20.0;

/// The information matrix of a step with standard deviations `sigma_m` (translation, each axis)
/// and `sigma_deg` (rotation), (rotation, translation) order.
#[must_use]
pub fn diagonal_information(sigma_m: f64, sigma_deg: f64) -> Matrix6<f64> {
    let r = 1.0 / sigma_deg.to_radians().powi(2);
    let t = 1.0 / (sigma_m * sigma_m);
    Matrix6::from_diagonal(&Vector6::new(r, r, r, t, t, t))
}

/// The prior information of an unmeasured step at an ICP voxel of `voxel_m` metres
/// ([`UNINFORMED_SIGMA_VOXELS`], [`UNINFORMED_SIGMA_DEG`]).
#[must_use]
pub fn uninformed_information(voxel_m: f64) -> Matrix6<f64> {
    diagonal_information(UNINFORMED_SIGMA_VOXELS * voxel_m, UNINFORMED_SIGMA_DEG)
}

/// The calibrated information of the pose `target_from_source` that a registration with
/// normal matrix `hessian` found: [`IcpHessian::information_in_source`] scaled by
/// `min(1, EFFECTIVE_CORRESPONDENCES / n)` ([`EFFECTIVE_CORRESPONDENCES`]). `None` where the
/// registration measured nothing usable (fewer than 7 correspondences, a zero residual
/// variance).
#[must_use]
pub fn registration_information(
    hessian: &IcpHessian,
    target_from_source: &Isometry3<f64>,
) -> Option<Matrix6<f64>> {
    let scale = (EFFECTIVE_CORRESPONDENCES / hessian.count as f64).min(1.0);
    hessian
        .information_in_source(target_from_source)
        .map(|omega| omega * scale)
}

/// `omega` (a step's information, (rotation, translation) order) with the spread of a rival
/// estimate added to its covariance: `(Ω⁻¹ + ξξᵀ)⁻¹`, where `ξ` is the rival's offset from the
/// step's pose as a right perturbation, `log` of it (rotation vector \[rad\], translation
/// part \[m\]: [`crate::graph::se3::log`], the pose graph's coordinates). By the
/// Sherman–Morrison formula, `Ω − Ωξ (Ωξ)ᵀ / (1 + ξᵀΩξ)`: the information along `ξ` falls to
/// about `1/|ξ|²` where it was larger, and is unchanged across it.
#[must_use]
pub fn with_spread(omega: &Matrix6<f64>, xi: &Vector6<f64>) -> Matrix6<f64> {
    let w = omega * xi;
    omega - (w * w.transpose()) / (1.0 + xi.dot(&w))
}

/// A step's covariance and the figures `/mireg/stats` reports of it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PoseUncertainty {
    /// `(Ω + Ω₀)⁻¹`: the measured information `Ω` (none for a failed frame) plus the prior `Ω₀`
    /// of an unmeasured step, inverted; (rotation \[rad\], translation \[m\]) order. Units: rad²,
    /// rad·m, m².
    pub covariance: Matrix6<f64>,
    /// Standard deviation along the least certain translation direction \[m\].
    pub sigma_m: f64,
    /// Standard deviation about the least certain rotation axis \[deg\].
    pub sigma_deg: f64,
    /// Smallest over largest eigenvalue of the translation block of the information that the
    /// registration measured (its marginal over the rotation), in [0, 1]: 1 when every direction
    /// is pinned down alike, near 0 along a corridor or over a plane; 0 for a failed frame.
    pub degeneracy_translation: f64,
    /// The same for the rotation block (marginal over the translation), in [0, 1]: near 0 for a
    /// plane seen alone (rotation about its normal is free).
    pub degeneracy_rotation: f64,
}

impl PoseUncertainty {
    /// The uncertainty of a step with measured `information` (`None`: a failed frame) on top of
    /// the `prior` ([`uninformed_information`]).
    #[must_use]
    pub fn new(information: Option<&Matrix6<f64>>, prior: &Matrix6<f64>) -> Self {
        let measured = information.copied().unwrap_or_else(Matrix6::zeros);
        let covariance = (measured + prior)
            .try_inverse()
            .map(|c| 0.5 * (c + c.transpose()))
            .unwrap_or_else(|| prior.try_inverse().unwrap_or_else(Matrix6::zeros));
        let block_max = |m: Matrix3<f64>| {
            SymmetricEigen::new(m)
                .eigenvalues
                .iter()
                .fold(0.0f64, |a, &b| a.max(b))
        };
        let rotation = covariance.fixed_view::<3, 3>(0, 0).into_owned();
        let translation = covariance.fixed_view::<3, 3>(3, 3).into_owned();
        let (degeneracy_translation, degeneracy_rotation) =
            information.map_or((0.0, 0.0), degeneracy);
        Self {
            covariance,
            sigma_m: block_max(translation).max(0.0).sqrt(),
            sigma_deg: block_max(rotation).max(0.0).sqrt().to_degrees(),
            degeneracy_translation,
            degeneracy_rotation,
        }
    }

    /// The covariance in ROS's `geometry_msgs/PoseWithCovariance` convention: (x, y, z, rotation
    /// about x, y, z), row-major, 36 values (m², m·rad, rad²).
    #[must_use]
    pub fn ros_covariance(&self) -> [f64; 36] {
        // Graph order (ω, t) → ROS order (t, ω).
        let from = |i: usize| if i < 3 { i + 3 } else { i - 3 };
        let mut out = [0.0; 36];
        for r in 0..6 {
            for c in 0..6 {
                out[6 * r + c] = self.covariance[(from(r), from(c))];
            }
        }
        out
    }
}

/// `(translation, rotation)`: smallest over largest eigenvalue of each block of the information
/// `omega` marginalised over the other ([`PoseUncertainty::degeneracy_translation`]), in [0, 1].
#[must_use]
pub fn degeneracy(omega: &Matrix6<f64>) -> (f64, f64) {
    (
        marginal_condition(omega, 3, 0),
        marginal_condition(omega, 0, 3),
    )
}

/// Smallest over largest eigenvalue of the 3×3 block at `at` of `omega` marginalised over the
/// block at `other` (the Schur complement `A − B D⁻¹ Bᵀ`, the information of those three
/// parameters with the others unknown); 0 when it is not positive.
fn marginal_condition(omega: &Matrix6<f64>, at: usize, other: usize) -> f64 {
    let a = omega.fixed_view::<3, 3>(at, at).into_owned();
    let b = omega.fixed_view::<3, 3>(at, other).into_owned();
    let d = omega.fixed_view::<3, 3>(other, other).into_owned();
    // A direction of `D` with no information carries none across (its row of `B` is zero too):
    // the pseudo-inverse leaves it out.
    let Ok(d_inv) = d.pseudo_inverse(1e-12 * d.norm()) else {
        return 0.0;
    };
    let schur = a - b * d_inv * b.transpose();
    let e = SymmetricEigen::new(0.5 * (schur + schur.transpose())).eigenvalues;
    let (lo, hi) = (e.min(), e.max());
    if hi > 0.0 && lo.is_finite() {
        (lo / hi).clamp(0.0, 1.0)
    } else {
        0.0
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn spread_adds_its_outer_product_to_the_covariance() {
        // Oracle: the covariance inverted, the spread added, inverted back.
        let a = Matrix6::from_fn(|i, j| ((i * 7 + j * 3) % 5) as f64 * 0.1);
        let omega = a * a.transpose() + Matrix6::from_diagonal_element(2.0);
        let xi = Vector6::new(0.01, -0.02, 0.005, 0.3, -0.1, 0.05);
        let direct = (omega.try_inverse().unwrap() + xi * xi.transpose())
            .try_inverse()
            .unwrap();
        let got = with_spread(&omega, &xi);
        assert!(
            (got - direct).amax() < 1e-9 * direct.amax(),
            "{got} vs {direct}"
        );
        // Along ξ the variance grows by |ξ|²; a direction Ω-orthogonal to ξ keeps its information.
        let u = xi.normalize();
        let var = |m: &Matrix6<f64>| (u.transpose() * m.try_inverse().unwrap() * u)[(0, 0)];
        assert!((var(&got) - var(&omega) - xi.norm_squared()).abs() < 1e-9);
    }

    #[test]
    fn ros_order_puts_translation_first() {
        let mut c = Matrix6::zeros();
        for i in 0..6 {
            c[(i, i)] = (i + 1) as f64;
        }
        c[(0, 3)] = 7.0; // rotation x – translation x
        c[(3, 0)] = 7.0;
        let u = PoseUncertainty {
            covariance: c,
            sigma_m: 0.0,
            sigma_deg: 0.0,
            degeneracy_translation: 0.0,
            degeneracy_rotation: 0.0,
        };
        let ros = u.ros_covariance();
        // ROS (x, y, z) are graph indices 3, 4, 5; ROS rotations are graph 0, 1, 2.
        assert_eq!(&[ros[0], ros[7], ros[14]], &[4.0, 5.0, 6.0]);
        assert_eq!(&[ros[21], ros[28], ros[35]], &[1.0, 2.0, 3.0]);
        assert_eq!((ros[3], ros[18]), (7.0, 7.0)); // (x, rot x) and (rot x, x)
    }

    #[test]
    fn a_failed_step_has_the_prior_and_no_figure_of_merit() {
        let prior = uninformed_information(0.5);
        let u = PoseUncertainty::new(None, &prior);
        assert!((u.sigma_m - 5.0).abs() < 1e-9, "{}", u.sigma_m);
        assert!((u.sigma_deg - 20.0).abs() < 1e-9, "{}", u.sigma_deg);
        assert_eq!(
            (u.degeneracy_translation, u.degeneracy_rotation),
            (0.0, 0.0)
        );
    }

    #[test]
    fn a_weak_direction_is_uncertain_and_flagged() {
        // Measured: rotation to 0.1°, translation x and y to 1 cm, z not at all.
        let mut omega = diagonal_information(0.01, 0.1);
        omega[(5, 5)] = 0.0;
        let prior = uninformed_information(0.5);
        let u = PoseUncertainty::new(Some(&omega), &prior);
        assert!(
            (u.sigma_m - 5.0).abs() < 1e-6,
            "z falls back to the prior: {}",
            u.sigma_m
        );
        assert!(u.covariance[(3, 3)].sqrt() < 0.0101);
        assert_eq!(u.degeneracy_translation, 0.0);
        assert!((u.degeneracy_rotation - 1.0).abs() < 1e-12);
    }
}
