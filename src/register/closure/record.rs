//! The `/mireg/loops` record of each loop candidate tried, and an accepted loop's information
//! as its graph edge carries it.

use nalgebra::Matrix6;
use serde::Serialize;

use super::super::frames::Estimate;
use super::super::output::{FoundBy, Verdict, relative_pose_json};
use crate::loops::{Candidate, LOOP_INFORMATION_SCALE, LoopDecision, Verification};
use crate::odometry::uncertainty::{PoseUncertainty, registration_information};

/// One candidate tried: what `/mireg/loops` carries ([`loops_json_schema`]).
#[derive(Debug, Clone, Serialize)]
pub(in crate::register) struct LoopRecord {
    pub(in crate::register) query_frame: usize,
    pub(in crate::register) match_frame: usize,
    pub(in crate::register) query_stamp_ns: i64,
    pub(in crate::register) match_stamp_ns: i64,
    pub(in crate::register) found_by: FoundBy,
    pub(in crate::register) descriptor_distance: f64,
    pub(in crate::register) odometry_distance_m: f64,
    pub(in crate::register) path_between_m: f64,
    pub(in crate::register) verdict: Verdict,
    pub(in crate::register) reason: String,
    pub(in crate::register) match_from_query: Option<serde_json::Value>,
    pub(in crate::register) inliers: usize,
    pub(in crate::register) correspondences: usize,
    pub(in crate::register) fitness: f64,
    pub(in crate::register) inlier_rmse_m: f64,
    /// The ICP's iterations (0 when it did not run).
    pub(in crate::register) icp_iterations: usize,
    pub(in crate::register) odometry_disagreement_m: f64,
    pub(in crate::register) odometry_disagreement_deg: f64,
    /// An accepted loop's predicted deviations along its least certain translation \[m\] and
    /// rotation \[deg\] directions, and its covariance in ROS order (x, y, z, rotation about x, y,
    /// z; row-major, m² … rad²): the loop edge's information in the graph, inverted.
    pub(in crate::register) sigma_m: Option<f64>,
    pub(in crate::register) sigma_deg: Option<f64>,
    pub(in crate::register) covariance: Option<Vec<f64>>,
    /// Robust weight of the loop edge at the optimum (0 for a rejected candidate).
    pub(in crate::register) weight: f64,
    pub(in crate::register) verify_s: f64,
    /// The pair registration's seconds per stage (matching, ranking, RANSAC, ICP, …).
    pub(in crate::register) timings_s: Option<crate::pipeline::PairTimings>,
}

/// The calibrated information of an accepted loop's registration (right perturbation of
/// `match_from_query`, [`LOOP_INFORMATION_SCALE`] times the odometry's calibration), as its
/// graph edge carries it.
pub(super) fn loop_information(v: &Verification) -> Option<Matrix6<f64>> {
    let match_from_query = v.match_from_query?;
    v.pair
        .icp_hessian
        .and_then(|h| registration_information(&h, &match_from_query))
        .map(|omega| omega * LOOP_INFORMATION_SCALE)
}

/// The reason text of an accepted loop's decision (empty for a loop in the graph found by the
/// first search), and whether it stays accepted.
fn decided(decision: Option<&LoopDecision>, round: usize) -> (Verdict, String) {
    let found = if round > 0 {
        format!("found by the search from the optimised poses after a first solve (round {round})")
    } else {
        String::new()
    };
    let join = |s: String| {
        if found.is_empty() {
            s
        } else if s.is_empty() {
            found.clone()
        } else {
            format!("{found}; {s}")
        }
    };
    match decision {
        Some(LoopDecision::HeldByMap(d2)) => (
            Verdict::Accepted,
            join(format!(
                "left out of the graph: the odometry registered the query against the match's \
                 place and agrees (squared Mahalanobis distance {d2:.2})"
            )),
        ),
        Some(LoopDecision::Inconsistent {
            consistent_with,
            others,
            clique,
        }) => (
            Verdict::Rejected,
            join(format!(
                "inconsistent with the other loops through the odometry (PCM): consistent with \
                 {consistent_with} of the {others} other verified loops, outside the largest \
                 consistent set ({clique} loops)"
            )),
        ),
        Some(LoopDecision::InGraph(_)) | None => (Verdict::Accepted, join(String::new())),
    }
}

/// The `/mireg/loops` record of candidate `c`, tried in search `round` (0: the first, on the
/// odometry), with the decision on it if it was verified as a loop.
pub(super) fn record(
    c: &Candidate,
    round: usize,
    estimates: &[Estimate],
    travelled: &[f64],
    verified: Option<&(Verification, f64)>,
    decision: Option<&LoopDecision>,
    prior: &Matrix6<f64>,
) -> LoopRecord {
    let held = matches!(decision, Some(LoopDecision::HeldByMap(_)));
    let uncertainty = verified
        .filter(|(v, _)| v.accepted)
        .and_then(|(v, _)| loop_information(v))
        .map(|omega| PoseUncertainty::new(Some(&omega), prior));
    let (verdict, reason) = match verified {
        Some((v, _)) if v.accepted => decided(decision, round),
        Some((v, _)) => (Verdict::Rejected, v.reason.clone()),
        None => (
            Verdict::Rejected,
            "a frame could not be read or prepared".to_string(),
        ),
    };
    LoopRecord {
        query_frame: c.query,
        match_frame: c.matched,
        query_stamp_ns: estimates[c.query].stamp_ns(),
        match_stamp_ns: estimates[c.matched].stamp_ns(),
        found_by: c.by.into(),
        descriptor_distance: c.descriptor_distance,
        odometry_distance_m: c.odometry_distance_m,
        path_between_m: travelled[c.query] - travelled[c.matched],
        verdict,
        reason,
        match_from_query: verified
            .and_then(|(v, _)| v.match_from_query.as_ref().map(relative_pose_json)),
        inliers: verified.map_or(0, |(v, _)| v.pair.num_inliers),
        correspondences: verified.map_or(0, |(v, _)| v.pair.num_correspondences),
        fitness: verified.map_or(0.0, |(v, _)| v.pair.fitness),
        inlier_rmse_m: verified.map_or(0.0, |(v, _)| v.pair.inlier_rmse_m),
        icp_iterations: verified.map_or(0, |(v, _)| v.pair.icp_iterations),
        odometry_disagreement_m: verified.map_or(f64::NAN, |(v, _)| v.disagreement_m),
        odometry_disagreement_deg: verified.map_or(f64::NAN, |(v, _)| v.disagreement_deg),
        sigma_m: uncertainty.as_ref().map(|u| u.sigma_m),
        sigma_deg: uncertainty.as_ref().map(|u| u.sigma_deg),
        covariance: uncertainty.as_ref().map(|u| u.ros_covariance().to_vec()),
        // A loop left out of the graph has no weight: null.
        weight: match decision {
            _ if held => f64::NAN,
            Some(LoopDecision::InGraph(w)) => *w,
            _ => 0.0,
        },
        verify_s: verified.map_or(0.0, |(_, s)| *s),
        timings_s: verified.map(|(v, _)| v.pair.timings_s),
    }
}
