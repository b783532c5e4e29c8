//! M-estimators on the Mahalanobis distance `d = √(eᵀ Ω e)` of an edge, as GTSAM's
//! `noiseModel::mEstimator` defines them: the edge's cost is `ρ(d)` and iteratively reweighted
//! least squares linearises it with the weight `w(d) = ρ'(d)/d` (GTSAM `noiseModel::Robust`).

/// Robust kernel applied to the edges marked `robust`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum RobustKernel {
    /// Cauchy / Lorentzian: `ρ(d) = ½ k² ln(1 + d²/k²)`, `w(d) = k²/(k² + d²)`
    /// (GTSAM `mEstimator::Cauchy`). Default.
    #[default]
    Cauchy,
    /// Geman–McClure: `ρ(d) = ½ k² d²/(k² + d²)`, `w(d) = k⁴/(k² + d²)²`
    /// (GTSAM 4.3 `mEstimator::GemanMcClure`).
    GemanMcClure,
}

impl RobustKernel {
    /// Cost `ρ(d)` of an edge at Mahalanobis distance `d` \[σ\] with scale `k` \[σ\].
    #[must_use]
    pub fn loss(self, d: f64, k: f64) -> f64 {
        let (d2, k2) = (d * d, k * k);
        match self {
            Self::Cauchy => 0.5 * k2 * (d2 / k2).ln_1p(),
            Self::GemanMcClure => 0.5 * k2 * d2 / (k2 + d2),
        }
    }

    /// IRLS weight `w(d) = ρ'(d)/d` ∈ (0, 1] at Mahalanobis distance `d` with scale `k`.
    #[must_use]
    pub fn weight(self, d: f64, k: f64) -> f64 {
        let (d2, k2) = (d * d, k * k);
        match self {
            Self::Cauchy => k2 / (k2 + d2),
            Self::GemanMcClure => {
                let s = k2 + d2;
                k2 * k2 / (s * s)
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn weight_is_derivative_of_loss_over_distance() {
        for kernel in [RobustKernel::Cauchy, RobustKernel::GemanMcClure] {
            for (d, k) in [(0.3, 1.0), (2.0, 1.0), (5.0, 0.5), (0.01, 3.0)] {
                let h = 1e-6;
                let deriv = (kernel.loss(d + h, k) - kernel.loss(d - h, k)) / (2.0 * h);
                let w = kernel.weight(d, k);
                assert!((deriv / d - w).abs() < 1e-7, "{kernel:?} d={d} k={k}");
                // Near zero both kernels are the quadratic ½ d².
                assert!((kernel.loss(1e-4, k) - 0.5e-8).abs() < 1e-14);
            }
        }
    }
}
