//! Nearest-neighbour matching of FPFH descriptors (33-D, unnormalised Open3D scale) and the
//! neighbour count used by MI-RANSAC's ranking metric (τ_d = 12).
//!
//! Scale, measured on Open3D 0.20 `compute_fpfh_feature` (3DMatch redkitchen, 16k points): each
//! 11-bin block sums to 200 (the point's own SPFH, 100 per block, plus the weighted mean of its
//! neighbours'), so a descriptor sums to 600; nearest-neighbour distances were 4 / 19 / 48 at the
//! 10th / 50th / 90th percentile.
//!
//! Two exact search methods give the same answers (up to floating-point near-ties):
//! - [`MatchMethod::BruteForce`] (default, faster by measurement — see `examples/match_bench.rs`):
//!   an exact scan that skips only pairs a rigorous lower bound (principal-axis projection) proves
//!   irrelevant, in parallel over queries; AVX2 + FMA are used when the CPU has them. Ties are
//!   broken by the **lowest target index**. See docs/PAIRWISE.md for how much it skips.
//! - [`MatchMethod::KdTree`]: kiddo `ImmutableKdTree<f32, 33>`; in 33-D the tree prunes little.
//!
//! Each squared distance is accumulated over dimensions 0..33 in order with fused multiply-adds
//! (`f32::mul_add`), so brute-force results do not depend on the vector width or the number of
//! threads. (On x86-64 CPUs without FMA — pre-2013 — `mul_add` falls back to a slow but exact
//! software routine.)

use kiddo::{ImmutableKdTree, SquaredEuclidean};

use super::duplicates::Unique;
use rayon::prelude::*;
use std::num::NonZeroUsize;

/// Length of an FPFH descriptor (the features' own [`crate::features::fpfh::FPFH_BINS`]).
pub use crate::features::fpfh::{FPFH_BINS as FPFH_DIM, Fpfh};

/// Which exact nearest-neighbour search [`match_features_with`] uses.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum MatchMethod {
    /// Vectorised exact scan with lower-bound pruning. Ties go to the lowest index. Default
    /// (faster, measured).
    #[default]
    BruteForce,
    /// kiddo kd-tree in 33-D. Tie-breaking is kiddo's.
    KdTree,
}

/// Options of [`match_features_with`].
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct MatchConfig {
    /// Keep only pairs where the source descriptor is also its target's nearest source
    /// descriptor (with brute force, ties again go to the lowest source index). Default: `false`.
    pub mutual: bool,
    /// If set, also count target descriptors within this Euclidean distance (inclusive) of each
    /// source descriptor, in the same pass (FPFH units; the paper uses 12). Default: `None`.
    pub count_radius: Option<f32>,
    /// Search method. Default: [`MatchMethod::BruteForce`].
    pub method: MatchMethod,
}

/// Putative correspondences, one entry per kept source descriptor, as parallel vectors sorted by
/// `source_index`.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Matches {
    /// Index of the source descriptor.
    pub source_index: Vec<u32>,
    /// Index of its nearest target descriptor.
    pub target_index: Vec<u32>,
    /// Euclidean distance to that target descriptor.
    pub distance: Vec<f32>,
    /// Euclidean distance to the second-nearest target descriptor (equal to `distance` on a
    /// tie; `f32::INFINITY` if the target has a single descriptor). For Lowe's ratio test.
    pub second_distance: Vec<f32>,
    /// Number of target descriptors within [`MatchConfig::count_radius`]; empty if not requested.
    pub count_within: Vec<u32>,
}

impl Matches {
    /// Number of correspondences.
    pub fn len(&self) -> usize {
        self.source_index.len()
    }

    /// Whether there are no correspondences.
    pub fn is_empty(&self) -> bool {
        self.source_index.is_empty()
    }
}

/// Matches each source descriptor to its nearest target descriptor (brute force, ties → lowest
/// target index); with `mutual`, keeps only mutual nearest neighbours. An empty `source` or
/// `target` gives no matches. Descriptors must be finite.
pub fn match_features(source: &[Fpfh], target: &[Fpfh], mutual: bool) -> Matches {
    match_features_with(
        source,
        target,
        &MatchConfig {
            mutual,
            ..MatchConfig::default()
        },
    )
}

/// [`match_features`] with all options (neighbour count in the same pass, search method).
pub fn match_features_with(source: &[Fpfh], target: &[Fpfh], config: &MatchConfig) -> Matches {
    match_prepared(source, target, None, config)
}

/// The target side of a brute-force search without a count radius (the default
/// [`MatchConfig`]'s), built once per target cloud: its distinct descriptors and their search
/// database. [`match_features_against`] reuses it for every source matched against that target.
pub struct MatchTarget {
    groups: Option<Unique>,
    db: Database,
    len: usize,
}

impl std::fmt::Debug for MatchTarget {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("MatchTarget")
            .field("len", &self.len)
            .finish()
    }
}

impl MatchTarget {
    /// Heap bytes a target holds per descriptor, roughly: its projection (`f64` per principal
    /// axis), its descriptor (`f32` per bin), its index and, when descriptors repeat, its group
    /// (`u32` each). For sizing caches, not accounting.
    pub const APPROX_BYTES_PER_DESCRIPTOR: usize =
        8 * brute_force::PCA_DIMS + 4 * crate::features::fpfh::FPFH_BINS + 4 + 8;

    /// Number of target descriptors.
    pub fn len(&self) -> usize {
        self.len
    }

    /// Whether the target holds no descriptor (never: [`MatchTarget::new`] declines an empty
    /// one).
    pub fn is_empty(&self) -> bool {
        self.len == 0
    }

    /// The search structures over `target` (finite descriptors); `None` when it is empty.
    pub fn new(target: &[Fpfh]) -> Option<Self> {
        if target.is_empty() {
            return None;
        }
        let groups = Unique::of(target);
        let db = match &groups {
            None => Database::new(target),
            Some(g) => Database::new(&g.descriptors(target)),
        };
        Some(MatchTarget {
            groups,
            db,
            len: target.len(),
        })
    }
}

/// [`match_features_with`] against `target` with its search structures `prepared` once
/// ([`MatchTarget::new`] of the same `target`): the same matches. Configurations the prepared
/// structures do not serve (a count radius, the kd-tree) build their own.
///
/// Panics if `prepared` was made from a target of another length.
pub fn match_features_against(
    source: &[Fpfh],
    target: &[Fpfh],
    prepared: &MatchTarget,
    config: &MatchConfig,
) -> Matches {
    assert_eq!(prepared.len, target.len(), "MatchTarget of another target");
    match_prepared(source, target, Some(prepared), config)
}

fn match_prepared(
    source: &[Fpfh],
    target: &[Fpfh],
    prepared: Option<&MatchTarget>,
    config: &MatchConfig,
) -> Matches {
    assert!(
        source.len() <= u32::MAX as usize && target.len() <= u32::MAX as usize,
        "descriptor indices must fit in u32"
    );
    if source.is_empty() || target.is_empty() {
        return Matches::default();
    }
    let count_radius_sq = config.count_radius.map(|r| r * r);
    let serves = config.method == MatchMethod::BruteForce && count_radius_sq.is_none();
    let scans = match prepared.filter(|_| serves) {
        Some(prepared) => scan_prepared(source, prepared),
        None => search(config.method, source, target, count_radius_sq),
    };
    if !config.mutual {
        return collect(scans, config, |_, _| true);
    }
    // Reverse search only for the targets that some source picked.
    let mut picked: Vec<u32> = scans.iter().map(|s| s.best_index).collect();
    picked.sort_unstable();
    picked.dedup();
    let picked_descriptors: Vec<Fpfh> = picked.iter().map(|&j| target[j as usize]).collect();
    let reverse = search(config.method, &picked_descriptors, source, None);
    collect(scans, config, |i, j| {
        let k = picked.binary_search(&j).expect("picked target");
        reverse[k].best_index == i
    })
}

/// Nearest, second nearest and (if `radius_sq` is set) neighbour count of every query in
/// `database` (both non-empty).
fn search(
    method: MatchMethod,
    queries: &[Fpfh],
    database: &[Fpfh],
    radius_sq: Option<f32>,
) -> Vec<Scan> {
    match method {
        MatchMethod::BruteForce => scan_distinct(queries, database, radius_sq),
        MatchMethod::KdTree => kd_scan_all(&build_tree(database), queries, radius_sq),
    }
}

/// [`scan_all`] over each distinct query and, without a radius, each distinct database
/// descriptor once ([`Unique`]): the same results, without the quadratic cost of many equal
/// descriptors. A group's representative is its lowest index, which the scan's tie-break would
/// pick among the equal distances; a group of two or more is its own second nearest.
fn scan_distinct(queries: &[Fpfh], database: &[Fpfh], radius_sq: Option<f32>) -> Vec<Scan> {
    match radius_sq {
        None => scan_prepared(queries, &MatchTarget::new(database).expect("non-empty")),
        Some(_) => per_distinct_query(queries, |qs| {
            scan_all(qs, &Database::new(database), radius_sq)
        }),
    }
}

/// [`scan_distinct`] without a radius, against a database built before.
fn scan_prepared(queries: &[Fpfh], target: &MatchTarget) -> Vec<Scan> {
    per_distinct_query(queries, |qs| {
        let mut scans = scan_all(qs, &target.db, None);
        if let Some(g) = &target.groups {
            for s in &mut scans {
                let group = s.best_index as usize;
                if g.size[group] >= 2 {
                    s.second_sq = s.best_sq;
                }
                s.best_index = g.first[group];
            }
        }
        scans
    })
}

/// `scan` of each distinct query once, handed back for every query.
fn per_distinct_query(queries: &[Fpfh], scan: impl FnOnce(&[Fpfh]) -> Vec<Scan>) -> Vec<Scan> {
    let query_groups = Unique::of(queries);
    let distinct_queries;
    let qs = match &query_groups {
        Some(u) => {
            distinct_queries = u.descriptors(queries);
            &distinct_queries[..]
        }
        None => queries,
    };
    let scans = scan(qs);
    match query_groups {
        None => scans,
        Some(u) => u.group.iter().map(|&g| scans[g as usize]).collect(),
    }
}

/// Number of target descriptors within Euclidean distance `radius` (inclusive) of each source
/// descriptor (the paper's ranking metric uses `radius = 12`). Brute force, parallel.
pub fn count_within(source: &[Fpfh], target: &[Fpfh], radius: f32) -> Vec<u32> {
    if target.is_empty() {
        return vec![0; source.len()];
    }
    let scans = scan_all(source, &Database::new(target), Some(radius * radius));
    scans.iter().map(|s| s.count).collect()
}

/// Per-source result of one scan over the targets (squared distances).
#[derive(Clone, Copy, Debug, PartialEq)]
struct Scan {
    best_index: u32,
    best_sq: f32,
    second_sq: f32,
    count: u32,
}

impl Scan {
    const EMPTY: Scan = Scan {
        best_index: 0,
        best_sq: f32::INFINITY,
        second_sq: f32::INFINITY,
        count: 0,
    };

    /// Offers database descriptor `j` at squared distance `d` for nearest/second nearest, in any
    /// order: on equal distances the lowest index is nearest, and `second_sq` is the second
    /// smallest distance counted with multiplicity.
    #[inline(always)]
    fn offer(&mut self, j: u32, d: f32) {
        if d < self.best_sq || (d == self.best_sq && j < self.best_index) {
            self.second_sq = self.best_sq;
            self.best_sq = d;
            self.best_index = j;
        } else if d < self.second_sq {
            self.second_sq = d;
        }
    }
}

fn collect(scans: Vec<Scan>, config: &MatchConfig, keep: impl Fn(u32, u32) -> bool) -> Matches {
    let mut m = Matches::default();
    for (i, s) in scans.iter().enumerate() {
        let i = i as u32;
        if !keep(i, s.best_index) {
            continue;
        }
        m.source_index.push(i);
        m.target_index.push(s.best_index);
        m.distance.push(s.best_sq.sqrt());
        m.second_distance.push(s.second_sq.sqrt());
        if config.count_radius.is_some() {
            m.count_within.push(s.count);
        }
    }
    m
}

// ---------------------------------------------------------------------------------------------
// kd-tree

type FpfhTree = ImmutableKdTree<f32, FPFH_DIM>;

fn build_tree(descriptors: &[Fpfh]) -> FpfhTree {
    ImmutableKdTree::new_from_slice(descriptors).expect("kd-tree over a non-empty, u32-indexed set")
}

fn kd_scan_all(tree: &FpfhTree, queries: &[Fpfh], radius_sq: Option<f32>) -> Vec<Scan> {
    let two = NonZeroUsize::new(2).expect("2 > 0");
    queries
        .par_iter()
        .map(|q| {
            let nearest = tree
                .query(q)
                .nearest_n::<SquaredEuclidean<f32>>(two)
                .execute();
            let count = radius_sq.map_or(0, |r2| {
                tree.query(q)
                    .within::<SquaredEuclidean<f32>>(r2)
                    .execute()
                    .len() as u32
            });
            Scan {
                best_index: nearest[0].item,
                best_sq: nearest[0].distance,
                second_sq: nearest.get(1).map_or(f32::INFINITY, |n| n.distance),
                count,
            }
        })
        .collect()
}

mod brute_force;
use brute_force::{Database, scan_all};
#[cfg(test)]
mod tests;
