//! Suspect steps: a frame that registered, but whose registration is doubtful, is flagged with
//! the reason and its step's information weakened ([`SUSPECT_SIGMA_FACTOR`]), so that the pose
//! graph lets the loops overrule it ([`crate::loops`]).
//!
//! NOTE: not in the paper. A registration can meet every acceptance threshold and still be
//! wrong: on real logs a frame "succeeded" 0.66–2.9 m off. The rules below flag what the frame's
//! own registration shows of that; they do not change its pose.

use serde::{Deserialize, Serialize};

use super::FrameEstimate;
use super::uncertainty::{degeneracy, with_spread};

/// Why a registered frame is suspect.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Suspect {
    /// Its registration leaves a direction nearly free: the smallest over largest eigenvalue of
    /// the translation or rotation information is below [`SUSPECT_DEGENERACY`] (a corridor, the
    /// ground alone, a narrow view).
    Degenerate,
    /// Its fit to the local map is below [`SUSPECT_FITNESS_DROP`] times the previous accepted
    /// frame's, even after a second global registration.
    FitnessDrop,
    /// Global registration drew its whole hypothesis budget without its stopping rule being met,
    /// and the pose came from that estimate.
    HypothesisCap,
    /// Another start of its registration ended elsewhere (beyond the map distance or 1°) and
    /// fitted the map nearly as well: at least [`AMBIGUOUS_FITNESS_RATIO`] of the accepted
    /// fitness ([`super::MapFit::rival`]). Its step's covariance also gains the rival's offset
    /// ([`super::uncertainty::with_spread`]).
    Ambiguous,
    /// Global registration found models, but none fitted the map as well as the
    /// constant-velocity prediction, whose refinement gave the pose, and that refinement
    /// constrains some direction weakly (degeneracy below [`UNCONFIRMED_DEGENERACY`]): along it
    /// the step is the prediction's, confirmed by nothing (a floor alone, whose every global
    /// estimate, retries included, slid off).
    Unconfirmed,
}

impl Suspect {
    /// The snake_case name used in JSON output.
    pub fn as_str(&self) -> &'static str {
        match self {
            Suspect::Degenerate => "degenerate",
            Suspect::FitnessDrop => "fitness_drop",
            Suspect::HypothesisCap => "hypothesis_cap",
            Suspect::Ambiguous => "ambiguous",
            Suspect::Unconfirmed => "unconfirmed",
        }
    }
}

/// A registration whose information's smallest over largest eigenvalue (translation or rotation
/// block, [`degeneracy`]) is below this is [`Suspect::Degenerate`]: 0.01. Measured on the shared
/// logs (docs/ODOMETRY.md "Covariance"): every registered frame was at 0.05 or above (ICL-NUIM's
/// depth camera, the narrowest view, 0.05–0.07 in translation; KAIST03 0.32); a frame of one
/// plane is at 0.
pub const SUSPECT_DEGENERACY: f64 = 0.01;

/// A rival start fitting the map at this fraction of the accepted one's fitness or more makes a
/// frame [`Suspect::Ambiguous`]: 0.9 (similar support for two answers). Measured 2026-12-06 over
/// seeds 0–2 of the fixture, micro211, KAIST03 and its gap, cone (70°, 25°, 40° with a gap) and
/// degenerate logs and the KITTI replay: rivals (wrong models, 0.6–50 m away, that lost) fitted
/// at 0.32–0.82 of the accepted pose, none at 0.9 or above.
pub const AMBIGUOUS_FITNESS_RATIO: f64 = 0.9;

/// A frame placed by the prediction ([`Suspect::Unconfirmed`]) whose registration's smallest
/// over largest eigenvalue is below this: 0.05, the lowest of any registered frame of the shared
/// logs (ICL-NUIM's narrow depth camera, 0.05–0.07). Measured 2026-12-06 in
/// `tests/suspect_steps.rs`: a floor-only frame placed by the prediction at 0.016 (above
/// [`SUSPECT_DEGENERACY`]: the floor's edges meet the map's walls), the frame with walls after it
/// well above.
pub const UNCONFIRMED_DEGENERACY: f64 = 0.05;

/// A map fitness below this fraction of the previous accepted frame's is
/// [`Suspect::FitnessDrop`]: 0.7 (below the second opinion's trigger,
/// [`super::MAP_FITNESS_DROP`], so that a frame the second opinion could not mend is flagged).
pub const SUSPECT_FITNESS_DROP: f64 = 0.7;

/// A suspect step's standard deviations are this many times what its registration measured:
/// 10 (its information divided by 100).
pub const SUSPECT_SIGMA_FACTOR: f64 = 10.0;

/// Flags `est` (a registered frame) as suspect where a rule applies, the first that does, and
/// weakens its information by [`SUSPECT_SIGMA_FACTOR`]. `last_map_fitness` is the previous
/// accepted frame's fit to the map; `max_hypotheses` RANSAC's budget.
pub fn judge(est: &mut FrameEstimate, last_map_fitness: Option<f64>, max_hypotheses: u64) {
    if !est.success {
        return;
    }
    let weakest = est.information.map(|omega| {
        let (t, r) = degeneracy(&omega);
        t.min(r)
    });
    let degenerate = weakest.is_some_and(|d| d < SUSPECT_DEGENERACY);
    let fitness_drop = match (est.map, last_map_fitness) {
        (Some(fit), Some(last)) if fit.used => fit.fitness < SUSPECT_FITNESS_DROP * last,
        _ => false,
    };
    let from_global = est.map.is_none_or(|m| m.guess.is_global());
    let capped = from_global
        && est
            .pair
            .as_ref()
            .is_some_and(|p| !p.converged && p.hypotheses >= max_hypotheses);
    let unconfirmed = est
        .map
        .is_some_and(|m| m.used && m.guess == super::InitialGuess::ConstantVelocity)
        && weakest.is_some_and(|d| d < UNCONFIRMED_DEGENERACY);
    let ambiguous = est.map.and_then(|m| {
        m.rival
            .filter(|r| m.used && r.fitness >= AMBIGUOUS_FITNESS_RATIO * m.fitness)
    });
    if let (Some(r), Some(omega)) = (ambiguous, est.information.as_mut()) {
        // The offset in the graph's tangent coordinates (its edges' residuals are `log`s).
        *omega = with_spread(omega, &crate::graph::se3::log(&r.offset));
    }
    est.suspect = if degenerate {
        Some(Suspect::Degenerate)
    } else if fitness_drop {
        Some(Suspect::FitnessDrop)
    } else if capped {
        Some(Suspect::HypothesisCap)
    } else if ambiguous.is_some() {
        Some(Suspect::Ambiguous)
    } else if unconfirmed {
        Some(Suspect::Unconfirmed)
    } else {
        None
    };
    if est.suspect.is_some()
        && let Some(omega) = est.information.as_mut()
    {
        *omega /= SUSPECT_SIGMA_FACTOR * SUSPECT_SIGMA_FACTOR;
    }
}

#[cfg(test)]
mod tests {
    use nalgebra::{Isometry3, Matrix6, Translation3, UnitQuaternion, Vector3};

    use super::*;
    use crate::odometry::{InitialGuess, MapFit, Rival};
    use crate::refine::icp::IcpHessian;

    /// A frame registered on the map at fitness 0.8 with isotropic information, with `rival`.
    fn registered(rival: Option<Rival>) -> FrameEstimate {
        let fit = MapFit {
            guess: InitialGuess::Global,
            fitness: 0.8,
            inlier_rmse_m: 0.01,
            iterations: 3,
            coarse_iterations: 0,
            fine_iterations: 0,
            map_points: 1000,
            used: true,
            target_s: 0.0,
            icp_s: 0.0,
            hessian: IcpHessian::ZERO,
            retry_rounds: 1,
            rival,
        };
        FrameEstimate {
            map: Some(fit),
            information: Some(Matrix6::from_diagonal_element(1e4)),
            ..FrameEstimate::with_counts(3, 1000, 500)
        }
    }

    fn rival_at(fitness: f64) -> Rival {
        Rival {
            fitness,
            offset: Isometry3::from_parts(
                Translation3::new(2.0, 0.0, 0.0),
                UnitQuaternion::from_axis_angle(&Vector3::z_axis(), 0.0),
            ),
        }
    }

    #[test]
    fn a_rival_with_similar_support_makes_the_step_ambiguous_along_its_offset() {
        let mut est = registered(Some(rival_at(0.9 * 0.8 + 1e-9)));
        judge(&mut est, Some(0.8), 1000);
        assert_eq!(est.suspect, Some(Suspect::Ambiguous));
        let cov = est.information.unwrap().try_inverse().unwrap();
        // x (graph index 3) gains the offset's 2 m as a deviation, on top of the suspect's 10×
        // weakening of 1 cm; y and z keep the weakened 1 cm × 10 = 10 cm.
        let sd = |i: usize| cov[(i, i)].sqrt();
        let weakened = 0.01 * SUSPECT_SIGMA_FACTOR;
        let expected_x = SUSPECT_SIGMA_FACTOR * (0.01f64.powi(2) + 4.0).sqrt();
        assert!((sd(3) - expected_x).abs() < 1e-9, "{}", sd(3));
        assert!((sd(4) - weakened).abs() < 1e-12 && (sd(5) - weakened).abs() < 1e-12);
    }

    #[test]
    fn a_rival_that_fitted_clearly_worse_changes_nothing() {
        let mut est = registered(Some(rival_at(0.9 * 0.8 - 1e-9)));
        let before = est.information;
        judge(&mut est, Some(0.8), 1000);
        assert_eq!(est.suspect, None);
        assert_eq!(est.information, before);
    }
}
