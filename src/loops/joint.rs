//! The verified loops judged together, and the search for loops again from the optimised poses.
//!
//! [`judge_loops`]: loops the odometry's map already measured stay out of the graph
//! ([`map_agreement`]); the rest join a first robust solve ([`optimize_trajectory`]); then every
//! accepted loop is judged against every other through the odometry ([`super::consistency`],
//! PCM), each odometry step's covariance divided by the weight the first solve left its edge,
//! and the loops outside the largest mutually consistent set are dropped and the graph solved
//! again without them.
//!
//! [`close_in_rounds`]: after that solve, candidates from the optimised poses
//! ([`search_again`]) find the loops the drift hid (a revisit whose odometry positions lay
//! beyond the place radius); they are verified as the first ones were, and the loops judged
//! again, while new loops are accepted, at most [`LoopConfig::search_rounds`] times
//! (issue 45 item 6).
//!
//! Pure: the verification of new candidates is the caller's (`verify`), so that `mireg
//! register` reads their frames from the log and a test can answer from a known truth.

use std::collections::BTreeSet;

use nalgebra::Isometry3;

use super::candidates::{Candidate, Keyframe, find_candidates};
use super::closure::{LoopConfig, LoopEdge, Step, edge_prior, map_agreement, optimize_trajectory};
use super::consistency::{PairwiseConsistency, maximum_clique};
use crate::Result;
use crate::graph::se3::log;

/// Default [`LoopConfig::search_rounds`]: 2 searches after the first solve at most.
pub const DEFAULT_SEARCH_ROUNDS: usize = 2;

/// What became of one accepted loop.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum LoopDecision {
    /// Left out of the graph: the odometry measured the same relation against its map; the
    /// squared Mahalanobis distance of their disagreement ([`map_agreement`]).
    HeldByMap(f64),
    /// An edge of the final graph, with its robust weight at the optimum.
    InGraph(f64),
    /// Outside the largest set of mutually consistent loops: dropped.
    Inconsistent {
        /// How many of the other accepted loops it is consistent with.
        consistent_with: usize,
        /// How many other accepted loops there are.
        others: usize,
        /// The size of the largest consistent set, which it is not part of.
        clique: usize,
    },
}

/// The result of [`judge_loops`].
#[derive(Debug, Clone, PartialEq)]
pub struct Judged {
    /// `world_from_sensor` per frame after optimisation (the odometry's without loops in the
    /// graph).
    pub optimized: Vec<Isometry3<f64>>,
    /// One decision per loop, in the order given.
    pub decisions: Vec<LoopDecision>,
    /// Pose-graph iterations over every solve.
    pub graph_iterations: usize,
}

/// The robust weights of `poses.len()` odometry steps (`[0]` unused, 1) in a solution of
/// [`optimize_trajectory`], whose first edges are the steps into frames 1, 2, ….
fn step_weights(n: usize, edge_weights: &[f64]) -> Vec<f64> {
    std::iter::once(1.0)
        .chain(edge_weights.iter().take(n.saturating_sub(1)).copied())
        .collect()
}

/// The squared Mahalanobis distance of loop `l`'s edge at `poses` (its information with the
/// graph's prior): how far the trajectory lies from it.
fn residual2(poses: &[Isometry3<f64>], l: &LoopEdge, config: &LoopConfig) -> f64 {
    let omega = l.information.unwrap_or_else(|| {
        crate::odometry::uncertainty::diagonal_information(
            config.loop_sigma_m,
            config.loop_sigma_deg,
        )
    }) + edge_prior(config);
    let e = log(&(l.match_from_query.inverse() * poses[l.matched].inverse() * poses[l.query]));
    let d2 = (e.transpose() * omega * e)[(0, 0)];
    if d2.is_finite() { d2 } else { f64::INFINITY }
}

/// Judges the verified `loops` of the odometry `poses` together (module doc) and returns the
/// optimised trajectory. `steps` and `ranges` as [`optimize_trajectory`] and [`map_agreement`]
/// take them. With [`LoopConfig::consistency_chi2`] 0 no loop is dropped.
///
/// Among maximum consistent sets of equal size the one found first wins: loops are tried by
/// how many others they agree with, then by how close the first solve's trajectory lies to
/// them; the same input gives the same answer.
///
/// # Errors
/// As [`optimize_trajectory`].
pub fn judge_loops(
    poses: &[Isometry3<f64>],
    steps: &[Step],
    ranges: &[Option<f64>],
    loops: &[LoopEdge],
    config: &LoopConfig,
) -> Result<Judged> {
    let held: Vec<Option<f64>> = loops
        .iter()
        .map(|l| {
            map_agreement(poses, steps, ranges, l, config)
                .filter(|d2| *d2 <= config.map_agreement_chi2)
        })
        .collect();
    let graph_loops = |keep: &[bool]| -> Vec<LoopEdge> {
        (0..loops.len())
            .filter(|&i| held[i].is_none() && keep[i])
            .map(|i| loops[i])
            .collect()
    };
    let all = vec![true; loops.len()];
    let first = graph_loops(&all);
    let (mut optimized, mut solution) = optimize_trajectory(poses, steps, &first, config)?;
    let mut iterations = solution.as_ref().map_or(0, |s| s.iterations);
    let (keep, adjacent) = if config.consistency_chi2 > 0.0 && loops.len() > 1 {
        let weights = solution
            .as_ref()
            .map(|s| step_weights(poses.len(), &s.edge_weights));
        let pcm = PairwiseConsistency::new(poses, steps, weights.as_deref(), config)?;
        let adjacent = pcm.graph(loops, config.consistency_chi2, config);
        let rank: Vec<f64> = loops
            .iter()
            .map(|l| residual2(&optimized, l, config))
            .collect();
        let mut keep = vec![false; loops.len()];
        for i in maximum_clique(&adjacent, &rank) {
            keep[i] = true;
        }
        (keep, adjacent)
    } else {
        (all, vec![vec![true; loops.len()]; loops.len()])
    };
    let graph = graph_loops(&keep);
    if graph.len() != first.len() {
        (optimized, solution) = optimize_trajectory(poses, steps, &graph, config)?;
        iterations += solution.as_ref().map_or(0, |s| s.iterations);
    }
    // The loop edges come after the odometry's in the graph, in the order of `graph`.
    let mut weights = solution
        .as_ref()
        .map(|s| s.edge_weights[s.edge_weights.len() - graph.len()..].to_vec())
        .unwrap_or_default()
        .into_iter();
    let clique = keep.iter().filter(|k| **k).count();
    let decisions = (0..loops.len())
        .map(|i| match (held[i], keep[i]) {
            (_, false) => LoopDecision::Inconsistent {
                consistent_with: adjacent[i].iter().filter(|a| **a).count(),
                others: loops.len() - 1,
                clique,
            },
            (Some(d2), true) => LoopDecision::HeldByMap(d2),
            (None, true) => LoopDecision::InGraph(weights.next().unwrap_or(1.0)),
        })
        .collect();
    Ok(Judged {
        optimized,
        decisions,
        graph_iterations: iterations,
    })
}

/// Candidates from the `optimized` poses: [`find_candidates`] over the `keyframes` (their
/// `pose` replaced by the optimised pose of their frame; path and descriptor kept), in frame
/// indices, without the pairs in `tried`.
///
/// # Errors
/// As [`find_candidates`].
pub fn search_again(
    keyframes: &[Keyframe],
    optimized: &[Isometry3<f64>],
    tried: &BTreeSet<(usize, usize)>,
    config: &LoopConfig,
) -> Result<Vec<Candidate>> {
    let moved: Vec<Keyframe> = keyframes
        .iter()
        .filter(|k| k.frame < optimized.len())
        .map(|k| Keyframe {
            pose: optimized[k.frame],
            ..k.clone()
        })
        .collect();
    Ok(find_candidates(&moved, &config.candidates)?
        .into_iter()
        .map(|c| Candidate {
            query: moved[c.query].frame,
            matched: moved[c.matched].frame,
            odometry_distance_m: (optimized[moved[c.query].frame].translation.vector
                - optimized[moved[c.matched].frame].translation.vector)
                .norm(),
            ..c
        })
        .filter(|c| !tried.contains(&(c.query, c.matched)))
        .collect())
}

/// What [`close_in_rounds`] returns.
#[derive(Debug, Clone, PartialEq)]
pub struct Rounds {
    /// Every accepted loop: the first ones, then each round's, in order.
    pub loops: Vec<LoopEdge>,
    /// The final judgement of `loops`.
    pub judged: Judged,
    /// Searches after a first solve that found candidates (each one verification round).
    pub rounds: usize,
}

/// Judges the first `loops` ([`judge_loops`]), then searches again from the optimised poses
/// ([`search_again`], without the pairs in `tried`, which it extends), verifies what it finds by
/// `verify(candidates, optimized poses)` (which returns the accepted loops among them), and
/// judges every loop again, while new loops are accepted and at most
/// [`LoopConfig::search_rounds`] times.
///
/// # Errors
/// As [`judge_loops`] and [`search_again`], and whatever `verify` returns.
#[allow(clippy::too_many_arguments)]
pub fn close_in_rounds(
    poses: &[Isometry3<f64>],
    steps: &[Step],
    ranges: &[Option<f64>],
    keyframes: &[Keyframe],
    mut loops: Vec<LoopEdge>,
    tried: &mut BTreeSet<(usize, usize)>,
    config: &LoopConfig,
    mut verify: impl FnMut(&[Candidate], &[Isometry3<f64>]) -> Result<Vec<LoopEdge>>,
) -> Result<Rounds> {
    let mut judged = judge_loops(poses, steps, ranges, &loops, config)?;
    let mut rounds = 0;
    while rounds < config.search_rounds {
        let candidates = search_again(keyframes, &judged.optimized, tried, config)?;
        if candidates.is_empty() {
            break;
        }
        rounds += 1;
        tried.extend(candidates.iter().map(|c| (c.query, c.matched)));
        let found = verify(&candidates, &judged.optimized)?;
        if found.is_empty() {
            break;
        }
        loops.extend(found);
        judged = judge_loops(poses, steps, ranges, &loops, config)?;
    }
    Ok(Rounds {
        loops,
        judged,
        rounds,
    })
}
