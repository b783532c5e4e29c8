//! Verification of a loop candidate: prior-free MI-RANSAC between the two frames, then ICP
//! ([`register_prepared`]), and an acceptance test on the result.
//!
//! A revisit comes with no usable prior (the drift may be metres, at any heading), which is the
//! setting global registration is for: the query frame is registered against the earlier frame
//! exactly as `mireg pair` registers two clouds. The candidate is accepted when
//! - registration succeeded ([`PairResult::failure`] is `None`);
//! - it has at least [`VerifyConfig::min_inliers`] RANSAC inliers;
//! - its ICP fitness (the fraction of the query's ICP cloud within the ICP distance of the match
//!   frame: their overlap) is at least [`VerifyConfig::min_fitness`];
//! - the overlap holds both ways: the match frame's ICP cloud, moved by the inverse pose, lies on
//!   the query's surfaces as well (fitness at least [`VerifyConfig::min_reverse_fitness`]);
//! - its ICP pins every direction down: the registration's information
//!   ([`crate::odometry::uncertainty`]) has a smallest over largest eigenvalue of at least
//!   [`LOOP_MIN_DEGENERACY`] in translation and rotation (a corridor or
//!   a floor seen alone registers anywhere along it);
//! - where the path between the two frames is short enough for the odometry to be trusted
//!   (a drift allowance is given), the loop's relative pose agrees with the odometry's within
//!   that allowance — translation within the allowance, rotation within
//!   [`VerifyConfig::max_rotation_disagreement_deg`].
//!
//! NOTE: KISS-SLAM accepts a MapClosures candidate on its inlier count alone; the overlap and the
//! agreement tests are ours, so that a look-alike place (repeated geometry, a corridor) whose
//! registration is self-consistent but wrong is rejected where the odometry can tell, and is
//! down-weighted by the robust pose graph where it cannot.

use nalgebra::Isometry3;

use crate::Result;
use crate::odometry::uncertainty::{degeneracy, registration_information};
use crate::pipeline::{PairConfig, PairResult, PreparedFrame, register_prepared};
use crate::refine::icp::evaluate_registration;

/// A loop's registration must have a smallest over largest eigenvalue of its translation and
/// rotation information of at least this: 0.05.
///
/// NOTE: stricter than a step's suspect bound
/// ([`crate::odometry::suspect::SUSPECT_DEGENERACY`], 0.01): a loop edge moves the whole
/// trajectory. On KAIST03 out-and-back with two frames cut to the road
/// (`tools/make_loop_logs.py --degenerate 5,14`) the two road-only frames matched each other
/// 1.6 m and 1° off at 0.020; every right loop on that log and on the cone and KITTI replay logs
/// had 0.12 or more (docs/LOOPS.md).
pub const LOOP_MIN_DEGENERACY: f64 = 0.05;

/// The acceptance test of [`verify`].
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct VerifyConfig {
    /// RANSAC inliers needed. Default [`DEFAULT_MIN_LOOP_INLIERS`] (30).
    pub min_inliers: usize,
    /// ICP fitness (overlap) needed, in `[0, 1]`. Default [`DEFAULT_MIN_LOOP_FITNESS`] (0.5).
    pub min_fitness: f64,
    /// Fitness the other way (the match frame's ICP cloud on the query's surfaces) needed, in
    /// `[0, 1]`. Default [`DEFAULT_MIN_LOOP_FITNESS`] (0.5), as [`VerifyConfig::min_fitness`]:
    /// two scans of one place overlap alike both ways. A tile of a prior map holds what many
    /// scans saw, more than one scan can: `mireg localize` asks less of it
    /// (`crate::merge::MAP_MIN_REVERSE_FITNESS`).
    pub min_reverse_fitness: f64,
    /// Largest rotation between the loop's relative pose and the odometry's, where the
    /// agreement test applies \[deg\]. Default 10.
    pub max_rotation_disagreement_deg: f64,
}

/// Default [`VerifyConfig::min_inliers`]: 30, 2.5× odometry's minimum
/// ([`crate::odometry::OdometryConfig::min_inliers`], 12): a loop edge moves the whole trajectory,
/// a frame-to-frame edge only one step.
pub const DEFAULT_MIN_LOOP_INLIERS: usize = 30;
/// Default [`VerifyConfig::min_fitness`]: 0.5 (odometry accepts 0.3): half the query's ICP cloud
/// must lie on the match frame's surfaces.
pub const DEFAULT_MIN_LOOP_FITNESS: f64 = 0.5;

impl Default for VerifyConfig {
    fn default() -> Self {
        Self {
            min_inliers: DEFAULT_MIN_LOOP_INLIERS,
            min_fitness: DEFAULT_MIN_LOOP_FITNESS,
            min_reverse_fitness: DEFAULT_MIN_LOOP_FITNESS,
            max_rotation_disagreement_deg: 10.0,
        }
    }
}

/// The outcome of [`verify`].
#[derive(Debug, Clone, PartialEq)]
pub struct Verification {
    /// Whether the loop passed every test.
    pub accepted: bool,
    /// Why it did not (empty when accepted).
    pub reason: String,
    /// The query frame's pose in the match frame (`p_match = T · p_query`); `None` when the
    /// registration failed.
    pub match_from_query: Option<Isometry3<f64>>,
    /// The pair registration's result.
    pub pair: PairResult,
    /// Translation between the loop's relative pose and the odometry's \[m\].
    pub disagreement_m: f64,
    /// Rotation between them \[deg\].
    pub disagreement_deg: f64,
}

/// Registers `query` (source) against `matched` (target) with `pair` and applies the acceptance
/// test. `odometry_match_from_query` is the relative pose the odometry gives;
/// `drift_allowance_m`, when `Some`, turns on the agreement test with that translation bound.
///
/// # Errors
/// Only what [`register_prepared`] returns for an invalid configuration; a failed registration is
/// a rejected candidate, not an error.
pub fn verify(
    query: &PreparedFrame,
    matched: &PreparedFrame,
    odometry_match_from_query: &Isometry3<f64>,
    drift_allowance_m: Option<f64>,
    pair: &PairConfig,
    config: &VerifyConfig,
) -> Result<Verification> {
    let result = register_prepared(query, matched, pair)?;
    let estimate = result.target_from_source;
    let delta = odometry_match_from_query.inverse() * estimate;
    let disagreement_m = delta.translation.vector.norm();
    let disagreement_deg = delta.rotation.angle().to_degrees();
    let reason = if let Some(f) = result.failure {
        format!("registration failed: {}", f.as_str())
    } else if result.num_inliers < config.min_inliers {
        format!(
            "{} inliers, fewer than {}",
            result.num_inliers, config.min_inliers
        )
    } else if result.fitness.is_nan() || result.fitness < config.min_fitness {
        format!(
            "fitness {:.3}, below {}",
            result.fitness, config.min_fitness
        )
    } else if let Some(reverse) = reverse_fitness(query, matched, &estimate, pair)?
        && (reverse.is_nan() || reverse < config.min_reverse_fitness)
    {
        format!(
            "fitness the other way (match onto query) {reverse:.3}, below {}",
            config.min_reverse_fitness
        )
    } else if let Some((t, r)) = result
        .icp_hessian
        .and_then(|h| registration_information(&h, &estimate))
        .map(|omega| degeneracy(&omega))
        && t.min(r) < LOOP_MIN_DEGENERACY
    {
        format!(
            "its registration leaves a direction free (degeneracy {t:.4} in translation, {r:.4} in rotation, below {LOOP_MIN_DEGENERACY})"
        )
    } else if let Some(allowance) = drift_allowance_m
        && disagreement_m > allowance
    {
        format!(
            "disagrees with the odometry by {disagreement_m:.3} m, more than the drift allowance of {allowance:.3} m"
        )
    } else if drift_allowance_m.is_some() && disagreement_deg > config.max_rotation_disagreement_deg
    {
        format!(
            "disagrees with the odometry by {disagreement_deg:.1}°, more than {}°",
            config.max_rotation_disagreement_deg
        )
    } else {
        String::new()
    };
    Ok(Verification {
        accepted: reason.is_empty(),
        reason,
        match_from_query: result.failure.is_none().then_some(estimate),
        pair: result,
        disagreement_m,
        disagreement_deg,
    })
}

/// The fitness of `matched`'s ICP cloud against `query`'s at `match_from_query⁻¹`, at the ICP
/// distance: the overlap seen from the other side. `None` when either frame has no ICP cloud.
fn reverse_fitness(
    query: &PreparedFrame,
    matched: &PreparedFrame,
    match_from_query: &Isometry3<f64>,
    pair: &PairConfig,
) -> Result<Option<f64>> {
    let (Some(q), Some(m)) = (&query.icp, &matched.icp) else {
        return Ok(None);
    };
    let c = pair.resolved()?;
    let distance = c.icp_max_distance_m.unwrap_or(c.voxel_size_m);
    let e = evaluate_registration(m.points(), q, &match_from_query.inverse(), distance)?;
    Ok(Some(e.fitness))
}
