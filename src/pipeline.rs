//! Registration of a pair of point clouds: preprocess → FPFH → correspondences → rank → MI-RANSAC →
//! point-to-plane ICP. Pure: clouds in, poses and statistics out; no file I/O.
//!
//! Each cloud is prepared once ([`prepare_frame`]) so that a stream of consecutive frames computes
//! every frame's features a single time, whether it serves as source or as target.

use std::time::Instant;

use nalgebra::{Isometry3, Point3, Vector3};
use serde::{Deserialize, Serialize};

use crate::Result;
use crate::correspondence::matching::{MatchConfig, match_features_against, match_features_with};
use crate::correspondence::ranking::{
    Ranking, rank_by_distance, rank_by_neighbour_count, rank_by_ratio,
};
use crate::ransac::consensus::{Consensus, ConsensusConfig, Termination};
use crate::ransac::{
    DenseRigidEstimator, Estimator, Levy, OverlapTarget, Prosac, RigidEstimator, TruncatedLevy,
    Uniform, run_consensus,
};

mod config;
mod prepare;
pub mod refine;
mod resolution;
pub use config::*;
pub use prepare::*;
use refine::{feature_tree, refine};
pub use resolution::{
    DEFAULT_FEATURE_POINTS, FEATURE_VOXEL_STEP, VOXEL_PER_MEDIAN_RANGE, feature_voxel_for_cloud,
    voxel_for_cloud, with_feature_voxel,
};

/// Wall-clock seconds per stage of one registration.
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize, Deserialize)]
pub struct PairTimings {
    /// Downsampling of both clouds.
    pub downsample: f64,
    /// Normals of both clouds.
    pub normals: f64,
    /// FPFH of both clouds.
    pub features: f64,
    /// Nearest neighbours in feature space.
    pub matching: f64,
    /// Ranking.
    pub ranking: f64,
    /// MI-RANSAC.
    pub ransac: f64,
    /// ICP.
    pub icp: f64,
    /// Everything above.
    pub total: f64,
}

/// Why a registration produced no trustworthy pose.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum FailureReason {
    /// A cloud has fewer than 3 points after downsampling.
    TooFewPoints,
    /// Fewer than 3 feature correspondences.
    TooFewCorrespondences,
    /// RANSAC found no model with at least 3 inliers.
    NoConsensus,
    /// Fewer RANSAC inliers than the caller's minimum (odometry: [`crate::odometry::OdometryConfig`]).
    TooFewInliers,
    /// Fitness after ICP below the caller's minimum.
    LowFitness,
    /// The cloud could not be decoded or prepared (e.g. a missing field, or coordinates so large
    /// the voxel grid overflows).
    InvalidCloud,
    /// The cloud has more points than the caller's bound (`mireg register --max-points`).
    TooManyPoints,
}

impl FailureReason {
    /// The snake_case name used in JSON output.
    pub fn as_str(&self) -> &'static str {
        match self {
            FailureReason::TooFewPoints => "too_few_points",
            FailureReason::TooFewCorrespondences => "too_few_correspondences",
            FailureReason::NoConsensus => "no_consensus",
            FailureReason::TooFewInliers => "too_few_inliers",
            FailureReason::LowFitness => "low_fitness",
            FailureReason::InvalidCloud => "invalid_cloud",
            FailureReason::TooManyPoints => "too_many_points",
        }
    }
}

/// The outcome of [`register_prepared`].
#[derive(Debug, Clone, PartialEq)]
pub struct PairResult {
    /// Final estimate (identity on failure).
    pub target_from_source: Isometry3<f64>,
    /// RANSAC's estimate before ICP (identity on failure).
    pub ransac_target_from_source: Isometry3<f64>,
    /// `None` on success.
    pub failure: Option<FailureReason>,
    /// Points in the source / target input clouds.
    pub num_points: [usize; 2],
    /// Points after downsampling (source, target).
    pub num_points_downsampled: [usize; 2],
    /// Putative correspondences.
    pub num_correspondences: usize,
    /// RANSAC inliers among them.
    pub num_inliers: usize,
    /// Hypotheses drawn.
    pub hypotheses: u64,
    /// Hypotheses removed by edge-length pre-rejection.
    pub prerejected: u64,
    /// Hypotheses scored.
    pub verified: u64,
    /// Hypothesis index at which the final best model was first found.
    pub best_found_at: Option<u64>,
    /// RANSAC stopped by its adaptive rule.
    pub converged: bool,
    /// Fraction of source points (ICP cloud) within the ICP distance of the target after alignment.
    pub fitness: f64,
    /// RMSE of those inlier distances \[m\].
    pub inlier_rmse_m: f64,
    /// ICP iterations run (0 without ICP).
    pub icp_iterations: usize,
    /// The point-to-plane normal matrix of the final ICP pose (its ICP cloud against the
    /// target's, at the ICP distance), from which its covariance follows; `None` without ICP.
    pub icp_hessian: Option<crate::refine::icp::IcpHessian>,
    /// Per-stage seconds.
    pub timings_s: PairTimings,
}

fn make_ranking(
    matches: &crate::correspondence::matching::Matches,
    num_target: usize,
    r: RankingConfig,
) -> Ranking {
    match r {
        RankingConfig::NeighbourCount { order, .. } => {
            rank_by_neighbour_count(&matches.count_within, num_target, order)
        }
        RankingConfig::Distance => rank_by_distance(&matches.distance),
        RankingConfig::Ratio => rank_by_ratio(&matches.distance, &matches.second_distance),
    }
}

/// Runs the configured sampler over `estimator`'s correspondences.
pub fn run_sampler<E: Estimator<Model = Isometry3<f64>>>(
    sampler: SamplerConfig,
    estimator: &E,
    consensus: &ConsensusConfig,
) -> Result<Consensus<Isometry3<f64>>> {
    let n = estimator.num_items();
    Ok(match sampler {
        SamplerConfig::Uniform => run_consensus(&Uniform::new(n), estimator, consensus),
        SamplerConfig::Levy {
            mu,
            c,
            window,
            with_replacement,
        } => {
            let s = Levy::new(TruncatedLevy::new(mu, c, window)?, n)?
                .with_replacement(with_replacement);
            run_consensus(&s, estimator, consensus)
        }
        SamplerConfig::Prosac { growth_max_samples } => run_consensus(
            &Prosac::new(n, 3, growth_max_samples)?,
            estimator,
            consensus,
        ),
    })
}

/// Registers prepared `source` to prepared `target`: the pose maps source points into the target
/// frame. Never fails on data: a failed registration is a [`PairResult`] with `failure` set.
pub fn register_prepared(
    source: &PreparedFrame,
    target: &PreparedFrame,
    config: &PairConfig,
) -> Result<PairResult> {
    register_prepared_with(source, target, config, true)
}

/// [`register_prepared`] up to the RANSAC model, without the ICP refinement: `target_from_source`
/// is the RANSAC model, `fitness` and `inlier_rmse_m` are 0. For callers that refine elsewhere
/// (odometry against its local map), or later with [`refine_prepared`].
pub fn register_prepared_coarse(
    source: &PreparedFrame,
    target: &PreparedFrame,
    config: &PairConfig,
) -> Result<PairResult> {
    register_prepared_with(source, target, config, false)
}

/// The ICP step of [`register_prepared`] on a result of [`register_prepared_coarse`] with a
/// model: refines `out.ransac_target_from_source` and sets pose, fitness, RMSE, iterations and
/// the ICP timing (and the total).
pub fn refine_prepared(
    out: &mut PairResult,
    source: &PreparedFrame,
    target: &PreparedFrame,
    config: &PairConfig,
) -> Result<()> {
    let c = config.resolved()?;
    let t = Instant::now();
    let built = std::cell::OnceCell::new();
    refine(out, source, target, &c, || feature_tree(target, &built))?;
    let icp_s = t.elapsed().as_secs_f64();
    out.timings_s.icp = icp_s;
    out.timings_s.total += icp_s;
    Ok(())
}

/// A result with nothing registered yet: identity poses, zero counts, the two frames' point
/// counts and preparation timings.
fn fresh_result(source: &PreparedFrame, target: &PreparedFrame) -> PairResult {
    PairResult {
        target_from_source: Isometry3::identity(),
        ransac_target_from_source: Isometry3::identity(),
        failure: None,
        num_points: [source.num_points, target.num_points],
        num_points_downsampled: [source.points.len(), target.points.len()],
        num_correspondences: 0,
        num_inliers: 0,
        hypotheses: 0,
        prerejected: 0,
        verified: 0,
        best_found_at: None,
        converged: false,
        fitness: 0.0,
        inlier_rmse_m: 0.0,
        icp_iterations: 0,
        icp_hessian: None,
        timings_s: PairTimings {
            downsample: source.timings.downsample + target.timings.downsample,
            normals: source.stage_timings().normals + target.stage_timings().normals,
            features: source.stage_timings().features + target.stage_timings().features,
            ..Default::default()
        },
    }
}

/// Feature matching of `source` against `target` (and its seconds), beside it (one
/// [`rayon::join`]) the ICP stages' sources, targets and correspondence grids built once per
/// frame when `refined`: single passes that fill the gaps of the matching's parallel loops.
fn match_and_prepare(
    source: &PreparedFrame,
    target: &PreparedFrame,
    c: &PairConfig,
    refined: bool,
) -> Result<(crate::correspondence::matching::Matches, f64)> {
    let count_radius = match c.ranking {
        RankingConfig::NeighbourCount { radius, .. } => Some(radius),
        _ => None,
    };
    // The ICP stages' sources, targets and correspondence grids are built (once per frame)
    // beside the matching: single passes that fill the gaps of the matching's parallel loops.
    let build_fine = refined && c.icp && c.icp_fine && !source.fine.is_empty();
    let prepare_targets = || -> Result<()> {
        let Some(icp) = target.icp.as_ref().filter(|_| refined && c.icp) else {
            return Ok(());
        };
        if build_fine {
            source.fine_source();
        }
        icp.prepare_for_distance(c.icp_max_distance_m.unwrap())?;
        if let Some(fine) = build_fine
            .then(|| target.fine_target())
            .transpose()?
            .flatten()
        {
            fine.prepare_for_distance(c.icp_fine_distance_m.unwrap())?;
        }
        Ok(())
    };
    let (matched, prepared) = rayon::join(
        || {
            let t = Instant::now();
            let config = MatchConfig {
                mutual: c.mutual_filter,
                count_radius,
                ..Default::default()
            };
            let (s, t_features) = (source.features(), target.features());
            // The prepared structures serve the search without a count radius only: the
            // other builds its own.
            let prepared = count_radius.is_none().then(|| target.match_target());
            let matches = match prepared.flatten() {
                Some(prepared) => match_features_against(s, t_features, prepared, &config),
                None => match_features_with(s, t_features, &config),
            };
            (matches, t.elapsed().as_secs_f64())
        },
        prepare_targets,
    );
    prepared?;
    Ok(matched)
}

fn register_prepared_with(
    source: &PreparedFrame,
    target: &PreparedFrame,
    config: &PairConfig,
    refined: bool,
) -> Result<PairResult> {
    let c = config.resolved()?;
    // Features that preparing deferred are computed first, both at once (distinct frames): no
    // task of the parallel stages below then waits on another's first use of them, and their
    // seconds are the frames' own ([`PreparedFrame::stage_timings`]), as if prepared with them.
    rayon::join(|| source.features(), || target.features());
    let start = Instant::now();
    let mut out = fresh_result(source, target);
    let finish = |mut out: PairResult| {
        let t = &mut out.timings_s;
        t.total = t.downsample + t.normals + t.features + start.elapsed().as_secs_f64();
        out
    };
    if source.points.len() < 3 || target.points.len() < 3 {
        out.failure = Some(FailureReason::TooFewPoints);
        return Ok(finish(out));
    }

    let (matches, matching_s) = match_and_prepare(source, target, &c, refined)?;
    out.timings_s.matching = matching_s;
    out.num_correspondences = matches.len();
    if matches.len() < 3 {
        out.failure = Some(FailureReason::TooFewCorrespondences);
        return Ok(finish(out));
    }

    let t = Instant::now();
    let ranking = make_ranking(&matches, target.points.len(), c.ranking);
    let src = ranking.gather(&matches.source_index, &source.points);
    let tgt = ranking.gather(&matches.target_index, &target.points);
    out.timings_s.ranking = t.elapsed().as_secs_f64();

    let t = Instant::now();
    let estimator = RigidEstimator::new(&src, &tgt)
        .edge_similarity(c.edge_similarity)
        .sample_distance(
            c.sample_distance_check
                .then(|| c.inlier_threshold_m.expect("resolved")),
        );
    let consensus = ConsensusConfig {
        inlier_threshold: c.inlier_threshold_m.unwrap(),
        scoring: c.scoring,
        confidence: c.confidence,
        max_hypotheses: c.max_hypotheses,
        lo_iterations: c.lo_iterations,
        termination: Termination::Adaptive,
        seed: c.seed,
    };
    // The target feature cloud's kd-tree, built on first use unless the ICP target is that cloud.
    let built_tree = std::cell::OnceCell::new();
    let target_tree = || feature_tree(target, &built_tree);
    let result = match c.verification {
        Verification::Correspondences => run_sampler(c.sampler, &estimator, &consensus)?,
        Verification::Dense => {
            let overlap =
                OverlapTarget::new(&target.points, consensus.inlier_threshold, target_tree)?;
            run_sampler(
                c.sampler,
                &DenseRigidEstimator::new(estimator, &source.points, &overlap).scoring(c.scoring),
                &consensus,
            )?
        }
    };
    out.timings_s.ransac = t.elapsed().as_secs_f64();
    out.hypotheses = result.hypotheses;
    out.prerejected = result.prerejected;
    out.verified = result.verified;
    out.best_found_at = result.best_found_at;
    out.converged = result.converged;
    out.num_inliers = result.num_inliers;
    let Some(model) = result.model.filter(|_| result.num_inliers >= 3) else {
        out.failure = Some(FailureReason::NoConsensus);
        return Ok(finish(out));
    };
    out.ransac_target_from_source = model;
    out.target_from_source = model;
    if !refined {
        return Ok(finish(out));
    }
    let t = Instant::now();
    refine(&mut out, source, target, &c, target_tree)?;
    out.timings_s.icp = t.elapsed().as_secs_f64();
    Ok(finish(out))
}

/// [`prepare_frame`] both clouds (in parallel) and [`register_prepared`] them. The per-stage
/// timings of the two frames add up; `timings_s.total` is the wall-clock time of the whole call.
pub fn register_pair(
    source: &[Point3<f64>],
    target: &[Point3<f64>],
    config: &PairConfig,
) -> Result<PairResult> {
    let start = Instant::now();
    let (s, t) = rayon::join(
        || prepare_frame(source, config),
        || prepare_frame(target, config),
    );
    let mut result = register_prepared(&s?, &t?, config)?;
    result.timings_s.total = start.elapsed().as_secs_f64();
    Ok(result)
}

/// Rotation error \[deg\] and translation error \[m\] of `estimate` against `truth`: the angle of
/// `R_truthᵀ·R_est` and `‖t_est − t_truth‖`.
pub fn pose_error(truth: &Isometry3<f64>, estimate: &Isometry3<f64>) -> (f64, f64) {
    let r = truth.rotation.inverse() * estimate.rotation;
    let dt: Vector3<f64> = estimate.translation.vector - truth.translation.vector;
    (r.angle().to_degrees(), dt.norm())
}
