//! Position error of a trajectory against the truth without alignment, for tests whose
//! estimate and truth share their first pose (a pose graph holds node 0 fixed).

use nalgebra::Isometry3;

/// RMS translation error \[m\] between `estimate` and `truth`, pose by pose.
pub fn position_rms(estimate: &[Isometry3<f64>], truth: &[Isometry3<f64>]) -> f64 {
    let sum: f64 = estimate
        .iter()
        .zip(truth)
        .map(|(a, b)| (a.translation.vector - b.translation.vector).norm_squared())
        .sum();
    (sum / truth.len() as f64).sqrt()
}
