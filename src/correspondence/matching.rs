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
//!   broken by the **lowest target index**. See docs/BENCHMARKS.md for how much it skips.
//! - [`MatchMethod::KdTree`]: kiddo `ImmutableKdTree<f32, 33>`; in 33-D the tree prunes little.
//!
//! Each squared distance is accumulated over dimensions 0..33 in order with fused multiply-adds
//! (`f32::mul_add`), so brute-force results do not depend on the vector width or the number of
//! threads. (On x86-64 CPUs without FMA — pre-2013 — `mul_add` falls back to a slow but exact
//! software routine.)

use kiddo::{ImmutableKdTree, SquaredEuclidean};
use rayon::prelude::*;
use std::num::NonZeroUsize;

/// Length of an FPFH descriptor.
pub const FPFH_DIM: usize = 33;

/// An FPFH descriptor: 3 histograms of 11 bins, Open3D scale (each histogram sums to 200).
pub type Fpfh = [f32; FPFH_DIM];

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
    assert!(
        source.len() <= u32::MAX as usize && target.len() <= u32::MAX as usize,
        "descriptor indices must fit in u32"
    );
    if source.is_empty() || target.is_empty() {
        return Matches::default();
    }
    let count_radius_sq = config.count_radius.map(|r| r * r);
    let scans = search(config.method, source, target, count_radius_sq);
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
        MatchMethod::BruteForce => scan_all(queries, &Database::new(database), radius_sq),
        MatchMethod::KdTree => kd_scan_all(&build_tree(database), queries, radius_sq),
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
// Brute force with an exact lower-bound filter
//
// Every pair's squared distance is *defined* as the in-order `mul_add` sum over dimensions 0..33
// of the original descriptors, and every pair that could change a query's result (nearest,
// second nearest, neighbour count) is computed that way. Pairs are skipped only when a rigorous
// lower bound proves they cannot matter:
//
// - The database is projected onto its first [`PCA_DIMS`] principal axes (orthonormal, so the
//   projected distance never exceeds the true one). On real FPFH clouds the first axis carries
//   72–75 % of the variance (3DMatch, KITTI), so the bound is tight.
// - Database descriptors are stored in blocks of [`LANES`], sorted along the first axis. A query
//   walks outwards from its own position on that axis, alternately up and down, and stops in a
//   direction once the gap along the first axis alone exceeds its current threshold; inside the
//   window, a block's exact distances are computed only if one of its lanes passes the
//   [`PCA_DIMS`]-dimensional bound.
// - The threshold follows the query's current second-nearest distance (and the count radius),
//   inflated by a margin that covers every rounding error (see [`prune_threshold`]), so the
//   results are bit-identical to the full scan: same nearest index (ties → lowest index, made
//   order-independent by [`Scan::offer`]), same distances, same counts.

/// Principal axes of the lower bound. 16 measured fastest among 6/8/12/16 on the 3DMatch and KITTI
/// pairs (`examples/match_bench.rs --real`).
const PCA_DIMS: usize = 16;
/// Database descriptors per block, stored dimension-major so one vector register holds the same
/// dimension of `LANES` descriptors.
const LANES: usize = 8;
/// Queries per parallel work unit (consecutive along the first axis, so they share windows).
const WORK_QUERIES: usize = 64;

/// `LANES` database descriptors, dimension-major. Unused lanes hold +∞.
type Block = [[f32; LANES]; FPFH_DIM];
/// The same descriptors projected onto the principal axes, dimension-major. Unused lanes hold 0
/// (with an infinite squared norm).
type LowBlock = [[f32; LANES]; PCA_DIMS];

/// A searchable set of descriptors.
struct Database {
    /// Mean descriptor (the projection's origin).
    mean: [f64; FPFH_DIM],
    /// Orthonormal principal axes, by decreasing variance.
    axes: [[f64; FPFH_DIM]; PCA_DIMS],
    /// Projected descriptors per block, blocks sorted along the first axis.
    low: Vec<LowBlock>,
    /// Squared norms of the projected descriptors (+∞ for unused lanes).
    low_norm_sq: Vec<[f32; LANES]>,
    /// Largest finite squared norm in each block (for the rounding margin).
    low_norm_sq_max: Vec<f32>,
    /// Original descriptors per block (same order).
    full: Vec<Block>,
    /// Original index of each lane (`u32::MAX` for unused lanes).
    index: Vec<[u32; LANES]>,
    /// Smallest and largest first-axis coordinate of each block.
    first_axis_range: Vec<(f32, f32)>,
    /// Largest absolute projected coordinate (for the rounding margin).
    max_abs_coordinate: f32,
}

/// Mean and principal axes of `descriptors` (non-empty), from at most 4096 evenly strided
/// samples (the axes only need to be orthonormal for the bound to hold; sampling affects how
/// tight it is, not whether it is exact).
fn principal_axes(descriptors: &[Fpfh]) -> ([f64; FPFH_DIM], [[f64; FPFH_DIM]; PCA_DIMS]) {
    let stride = descriptors.len().div_ceil(4096);
    let samples: Vec<&Fpfh> = descriptors.iter().step_by(stride).collect();
    let n = samples.len() as f64;
    let mut mean = [0.0f64; FPFH_DIM];
    for d in &samples {
        for (m, &x) in mean.iter_mut().zip(d.iter()) {
            *m += f64::from(x);
        }
    }
    mean.iter_mut().for_each(|m| *m /= n);
    let mut cov = nalgebra::SMatrix::<f64, FPFH_DIM, FPFH_DIM>::zeros();
    for d in &samples {
        let c = nalgebra::SVector::<f64, FPFH_DIM>::from_fn(|i, _| f64::from(d[i]) - mean[i]);
        cov.syger(1.0, &c, &c, 1.0);
    }
    let eigen = nalgebra::SymmetricEigen::new(cov);
    let mut order: Vec<usize> = (0..FPFH_DIM).collect();
    order.sort_by(|&a, &b| {
        eigen.eigenvalues[b]
            .total_cmp(&eigen.eigenvalues[a])
            .then(a.cmp(&b))
    });
    let axes = std::array::from_fn(|k| {
        let v = eigen.eigenvectors.column(order[k]);
        std::array::from_fn(|i| v[i])
    });
    (mean, axes)
}

/// Coordinates of `d` on the axes (computed in f64, rounded to f32 once).
#[inline]
fn project(
    d: &Fpfh,
    mean: &[f64; FPFH_DIM],
    axes: &[[f64; FPFH_DIM]; PCA_DIMS],
) -> [f32; PCA_DIMS] {
    std::array::from_fn(|k| {
        let mut s = 0.0f64;
        for i in 0..FPFH_DIM {
            s += axes[k][i] * (f64::from(d[i]) - mean[i]);
        }
        s as f32
    })
}

impl Database {
    /// Builds the database (`descriptors` non-empty and finite).
    fn new(descriptors: &[Fpfh]) -> Database {
        let (mean, axes) = principal_axes(descriptors);
        let coords: Vec<[f32; PCA_DIMS]> = descriptors
            .par_iter()
            .map(|d| project(d, &mean, &axes))
            .collect();
        let mut order: Vec<u32> = (0..descriptors.len() as u32).collect();
        order.sort_unstable_by(|&a, &b| {
            coords[a as usize][0]
                .total_cmp(&coords[b as usize][0])
                .then(a.cmp(&b))
        });
        let blocks = order.len().div_ceil(LANES);
        let mut db = Database {
            mean,
            axes,
            low: vec![[[0.0; LANES]; PCA_DIMS]; blocks],
            low_norm_sq: vec![[f32::INFINITY; LANES]; blocks],
            low_norm_sq_max: vec![0.0; blocks],
            full: vec![[[f32::INFINITY; LANES]; FPFH_DIM]; blocks],
            index: vec![[u32::MAX; LANES]; blocks],
            first_axis_range: Vec::with_capacity(blocks),
            max_abs_coordinate: 0.0,
        };
        for (b, members) in order.chunks(LANES).enumerate() {
            for (l, &i) in members.iter().enumerate() {
                let (c, d) = (&coords[i as usize], &descriptors[i as usize]);
                for (row, &x) in db.low[b].iter_mut().zip(c) {
                    row[l] = x;
                    db.max_abs_coordinate = db.max_abs_coordinate.max(x.abs());
                }
                for (dim, &v) in d.iter().enumerate() {
                    db.full[b][dim][l] = v;
                }
                let norm_sq = squared_norm(c);
                db.low_norm_sq[b][l] = norm_sq;
                db.low_norm_sq_max[b] = db.low_norm_sq_max[b].max(norm_sq);
                db.index[b][l] = i;
            }
            let first = coords[members[0] as usize][0];
            let last = coords[members[members.len() - 1] as usize][0];
            db.first_axis_range.push((first, last));
        }
        db
    }
}

/// Squared norm of stored projected coordinates, summed in f64 and rounded once.
#[inline]
fn squared_norm(c: &[f32; PCA_DIMS]) -> f32 {
    c.iter().map(|&x| f64::from(x) * f64::from(x)).sum::<f64>() as f32
}

/// Rounding slack of the projected squared distance computed as ‖a‖² + ‖b‖² − 2·a·b, relative to
/// ‖a‖² + ‖b‖²: each norm is rounded once, the dot product accumulates `PCA_DIMS` fused
/// multiply-adds (error ≤ PCA_DIMS·u·‖a‖‖b‖ ≤ PCA_DIMS·u·(‖a‖² + ‖b‖²)/2), and the sum and
/// difference round twice more, so the error is below (PCA_DIMS + 5)·u·(‖a‖² + ‖b‖²); twice that
/// is used.
const DOT_SLACK: f32 = (2 * PCA_DIMS + 10) as f32 * f32::EPSILON / 2.0;

/// Squared lower-bound threshold for a query whose results can only change through pairs at
/// squared distance ≤ `bound_sq`, where stored coordinates carry an absolute rounding error of at
/// most `eta` each. A pair whose computed projected squared distance exceeds the returned value
/// has a computed full squared distance > `bound_sq`:
/// - the computed projected squared distance is within an absolute [`DOT_SLACK`] term (added by
///   the caller) of the exact one on the stored coordinates (u = 2⁻²⁴), and the final factor
///   1 + 1e-5 covers the rounding of this function;
/// - the stored coordinates of both descriptors are within `eta` of the exact projections, so
///   the exact projected distance is at least the stored one minus 2·eta·√PCA_DIMS;
/// - the projection onto orthonormal axes never lengthens a vector;
/// - the computed full squared distance (33 in-order fused multiply-adds of rounded differences)
///   is within a factor (1 − 40u) of the exact one, covered by the factor 1 + 4e-5 on its root.
#[inline]
fn prune_threshold(bound_sq: f32, eta: f32) -> f32 {
    if bound_sq.is_infinite() {
        return f32::INFINITY;
    }
    let margin = 2.0 * eta * (PCA_DIMS as f32).sqrt();
    let root = bound_sq.max(0.0).sqrt() * (1.0 + 4e-5) + margin;
    root * root * (1.0 + 1e-5)
}

/// Searches one query (projected to `low_query`) through `db`.
#[inline(always)]
fn search_one(db: &Database, query: &Fpfh, low_query: &[f32; PCA_DIMS], radius_sq: f32) -> Scan {
    let eta = (db
        .max_abs_coordinate
        .max(low_query.iter().fold(0.0f32, |m, c| m.max(c.abs())))
        * f32::EPSILON)
        .max(f32::MIN_POSITIVE);
    let mut search = QuerySearch {
        db,
        query,
        low_query,
        low_norm_sq: squared_norm(low_query),
        radius_sq,
        eta,
        scan: Scan::EMPTY,
        threshold: f32::INFINITY,
    };
    let blocks = db.low.len();
    let x = low_query[0];
    let start = db
        .first_axis_range
        .partition_point(|&(first, _)| first <= x);
    let (mut up, mut down) = (start, start);
    while up < blocks || down > 0 {
        if up < blocks {
            let gap = db.first_axis_range[up].0 - x;
            if gap > 0.0 && gap * gap > search.threshold {
                up = blocks;
            } else {
                search.visit(up);
                up += 1;
            }
        }
        if down > 0 {
            let gap = x - db.first_axis_range[down - 1].1;
            if gap > 0.0 && gap * gap > search.threshold {
                down = 0;
            } else {
                search.visit(down - 1);
                down -= 1;
            }
        }
    }
    search.scan
}

/// One query's walk through a [`Database`]: the query, its projection, and its results so far.
struct QuerySearch<'a> {
    db: &'a Database,
    query: &'a Fpfh,
    low_query: &'a [f32; PCA_DIMS],
    /// Squared norm of `low_query`.
    low_norm_sq: f32,
    radius_sq: f32,
    /// Rounding bound of the stored projected coordinates (see [`prune_threshold`]).
    eta: f32,
    scan: Scan,
    /// Projected squared distance beyond which a lane cannot matter.
    threshold: f32,
}

impl QuerySearch<'_> {
    /// Offers block `b` to the scan if its lower bound lets any lane through; refreshes the
    /// threshold.
    #[inline(always)]
    fn visit(&mut self, b: usize) {
        let db = self.db;
        // ‖a − b‖² = ‖a‖² + ‖b‖² − 2·a·b: one fused multiply-add per dimension and lane.
        let mut dot = [0.0f32; LANES];
        for (&q, row) in self.low_query.iter().zip(&db.low[b]) {
            for l in 0..LANES {
                dot[l] = q.mul_add(row[l], dot[l]);
            }
        }
        let limit = self.threshold + DOT_SLACK * (self.low_norm_sq + db.low_norm_sq_max[b]);
        let mut alive = false;
        for (&d, &norm_sq) in dot.iter().zip(&db.low_norm_sq[b]) {
            alive |= (self.low_norm_sq + norm_sq) - 2.0 * d <= limit;
        }
        if !alive {
            return;
        }
        let mut acc = [0.0f32; LANES];
        for (dim, row) in db.full[b].iter().enumerate() {
            let q = self.query[dim];
            for l in 0..LANES {
                let x = q - row[l];
                acc[l] = x.mul_add(x, acc[l]);
            }
        }
        let mut count = 0;
        let mut improves = false;
        for &d in &acc {
            count += (d <= self.radius_sq) as u32;
            improves |= d <= self.scan.second_sq;
        }
        self.scan.count += count;
        if improves {
            for (l, &d) in acc.iter().enumerate() {
                self.scan.offer(db.index[b][l], d);
            }
            self.threshold = prune_threshold(self.scan.second_sq.max(self.radius_sq), self.eta);
        }
    }
}

#[inline(always)]
fn scan_generic(
    db: &Database,
    queries: &[(u32, [f32; PCA_DIMS])],
    all: &[Fpfh],
    radius_sq: f32,
    out: &mut [Scan],
) {
    for ((i, low), o) in queries.iter().zip(out) {
        *o = search_one(db, &all[*i as usize], low, radius_sq);
    }
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
fn scan_avx2_fma(
    db: &Database,
    queries: &[(u32, [f32; PCA_DIMS])],
    all: &[Fpfh],
    radius_sq: f32,
    out: &mut [Scan],
) {
    scan_generic(db, queries, all, radius_sq, out)
}

fn scan(
    db: &Database,
    queries: &[(u32, [f32; PCA_DIMS])],
    all: &[Fpfh],
    radius_sq: f32,
    out: &mut [Scan],
) {
    #[cfg(target_arch = "x86_64")]
    if std::arch::is_x86_feature_detected!("avx2") && std::arch::is_x86_feature_detected!("fma") {
        // SAFETY: the CPU supports AVX2 and FMA (checked above).
        unsafe { scan_avx2_fma(db, queries, all, radius_sq, out) };
        return;
    }
    scan_generic(db, queries, all, radius_sq, out)
}

/// Nearest, second nearest and (if `radius_sq` is set) neighbour count of every query in `db`.
fn scan_all(queries: &[Fpfh], db: &Database, radius_sq: Option<f32>) -> Vec<Scan> {
    // Without a radius, count nothing: −∞ never satisfies `d <= radius_sq`.
    let radius_sq = radius_sq.unwrap_or(f32::NEG_INFINITY);
    // Queries in first-axis order, so a work unit's windows overlap (cache locality); each
    // query's result is independent of the order and of the thread that computes it.
    let mut projected: Vec<(u32, [f32; PCA_DIMS])> = queries
        .par_iter()
        .enumerate()
        .map(|(i, q)| (i as u32, project(q, &db.mean, &db.axes)))
        .collect();
    projected.sort_unstable_by(|a, b| a.1[0].total_cmp(&b.1[0]).then(a.0.cmp(&b.0)));
    let mut sorted_out = vec![Scan::EMPTY; queries.len()];
    sorted_out
        .par_chunks_mut(WORK_QUERIES)
        .zip(projected.par_chunks(WORK_QUERIES))
        .for_each(|(out, qs)| scan(db, qs, queries, radius_sq, out));
    let mut out = vec![Scan::EMPTY; queries.len()];
    for ((i, _), s) in projected.iter().zip(sorted_out) {
        out[*i as usize] = s;
    }
    out
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

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{RngExt, SeedableRng};
    use rand_pcg::Pcg64Mcg;

    /// Descriptors with small integer entries: every squared distance is an exact integer in f32
    /// whatever the summation order, and ties are frequent, so index equality is exact.
    fn integer_descriptors(rng: &mut Pcg64Mcg, n: usize, max: u32) -> Vec<Fpfh> {
        (0..n)
            .map(|_| std::array::from_fn(|_| rng.random_range(0..=max) as f32))
            .collect()
    }

    /// FPFH-like: each 11-bin block is non-negative and sums to 100; descriptors cluster around
    /// a few peaky centres.
    fn fpfh_like(rng: &mut Pcg64Mcg, n: usize, clusters: usize) -> Vec<Fpfh> {
        let peaky_block = |rng: &mut Pcg64Mcg| -> [f32; 11] {
            std::array::from_fn(|_| rng.random::<f32>().powi(4))
        };
        let centres: Vec<[[f32; 11]; 3]> = (0..clusters)
            .map(|_| std::array::from_fn(|_| peaky_block(rng)))
            .collect();
        (0..n)
            .map(|_| {
                let centre = centres[rng.random_range(0..clusters)];
                let mut d = [0.0f32; FPFH_DIM];
                for (b, block) in centre.iter().enumerate() {
                    let noise = peaky_block(rng);
                    let raw: [f32; 11] = std::array::from_fn(|k| block[k] + 0.05 * noise[k]);
                    let sum: f32 = raw.iter().sum();
                    for k in 0..11 {
                        d[b * 11 + k] = 100.0 * raw[k] / sum;
                    }
                }
                d
            })
            .collect()
    }

    fn oracle_squared(a: &Fpfh, b: &Fpfh) -> f64 {
        a.iter()
            .zip(b)
            .map(|(&x, &y)| (x as f64 - y as f64).powi(2))
            .sum()
    }

    /// Naive O(N·M): (nearest index with lowest index on ties, nearest², second nearest²).
    fn oracle_nearest(query: &Fpfh, set: &[Fpfh]) -> (u32, f64, f64) {
        let mut d: Vec<(f64, u32)> = set
            .iter()
            .enumerate()
            .map(|(j, t)| (oracle_squared(query, t), j as u32))
            .collect();
        d.sort_by(|a, b| a.partial_cmp(b).unwrap());
        (d[0].1, d[0].0, d.get(1).map_or(f64::INFINITY, |x| x.0))
    }

    fn oracle_count(query: &Fpfh, set: &[Fpfh], radius: f64) -> u32 {
        set.iter()
            .filter(|t| oracle_squared(query, t) <= radius * radius)
            .count() as u32
    }

    #[test]
    fn brute_force_equals_naive_oracle_with_ties() {
        let mut rng = Pcg64Mcg::seed_from_u64(1);
        // Sizes not multiples of TILE or WORK_ROWS; entries 0..=3 make many exact ties.
        let source = integer_descriptors(&mut rng, 301, 3);
        let target = integer_descriptors(&mut rng, 257, 3);
        let config = MatchConfig {
            count_radius: Some(8.0),
            ..MatchConfig::default()
        };
        let m = match_features_with(&source, &target, &config);
        assert_eq!(m.len(), source.len());
        let mut ties = 0;
        for (i, q) in source.iter().enumerate() {
            let (j, best, second) = oracle_nearest(q, &target);
            ties += (best == second) as usize;
            assert_eq!(m.source_index[i], i as u32);
            assert_eq!(m.target_index[i], j, "source {i}");
            assert_eq!(m.distance[i] as f64, (best as f32).sqrt() as f64);
            assert_eq!(m.second_distance[i] as f64, (second as f32).sqrt() as f64);
            assert_eq!(m.count_within[i], oracle_count(q, &target, 8.0));
        }
        assert!(
            ties > 10,
            "the data should exercise tie-breaking, got {ties} ties"
        );
    }

    /// The documented definition of a squared distance: dimensions 0..33 in order, `mul_add`.
    fn in_order_squared(a: &Fpfh, b: &Fpfh) -> f32 {
        a.iter().zip(b).fold(0.0f32, |acc, (&x, &y)| {
            let d = x - y;
            d.mul_add(d, acc)
        })
    }

    /// The lower-bound filter must never drop a pair that matters: on FPFH-like floats (with
    /// exact and one-ulp duplicates, and outliers far from the bulk that stretch the projected
    /// coordinates), nearest index, both distances and the count are bit-identical to a naive
    /// scan under the same distance definition.
    #[test]
    fn pruned_search_is_bit_identical_to_naive_scan_on_floats() {
        let mut rng = Pcg64Mcg::seed_from_u64(7);
        let mut target = fpfh_like(&mut rng, 1500, 12);
        for j in (0..300).step_by(3) {
            let mut d = target[j];
            if j % 2 == 0 {
                d[rng.random_range(0..FPFH_DIM)] = f32::from_bits(d[0].to_bits() + 1);
            }
            target.push(d);
        }
        target.extend((0..20).map(|_| std::array::from_fn(|_| rng.random_range(0.0..5e4f32))));
        let mut source = fpfh_like(&mut rng, 700, 12);
        source.extend(target.iter().step_by(7).take(100).copied());
        source.extend((0..10).map(|_| std::array::from_fn(|_| rng.random_range(0.0..5e4f32))));
        let radius = 12.0f32;
        let config = MatchConfig {
            count_radius: Some(radius),
            ..MatchConfig::default()
        };
        let m = match_features_with(&source, &target, &config);
        for (i, q) in source.iter().enumerate() {
            let d: Vec<f32> = target.iter().map(|t| in_order_squared(q, t)).collect();
            let (mut best, mut j_best) = (f32::INFINITY, 0u32);
            for (j, &x) in d.iter().enumerate() {
                if x < best {
                    (best, j_best) = (x, j as u32);
                }
            }
            let mut rest = d.clone();
            rest.remove(j_best as usize);
            let second = rest.iter().copied().fold(f32::INFINITY, f32::min);
            let count = d.iter().filter(|&&x| x <= radius * radius).count() as u32;
            assert_eq!(m.target_index[i], j_best, "source {i}");
            assert_eq!(m.distance[i].to_bits(), best.sqrt().to_bits(), "source {i}");
            assert_eq!(
                m.second_distance[i].to_bits(),
                second.sqrt().to_bits(),
                "source {i}"
            );
            assert_eq!(m.count_within[i], count, "source {i}");
        }
        assert!(m.distance.iter().filter(|&&d| d == 0.0).count() >= 100);
    }

    #[test]
    fn mutual_filter_equals_oracle() {
        let mut rng = Pcg64Mcg::seed_from_u64(2);
        let source = integer_descriptors(&mut rng, 203, 4);
        let target = integer_descriptors(&mut rng, 150, 4);
        let m = match_features(&source, &target, true);
        let expected: Vec<(u32, u32)> = (0..source.len())
            .filter_map(|i| {
                let (j, _, _) = oracle_nearest(&source[i], &target);
                let (back, _, _) = oracle_nearest(&target[j as usize], &source);
                (back == i as u32).then_some((i as u32, j))
            })
            .collect();
        let got: Vec<(u32, u32)> = m
            .source_index
            .iter()
            .copied()
            .zip(m.target_index.iter().copied())
            .collect();
        assert!(!expected.is_empty() && expected.len() < source.len());
        assert_eq!(got, expected);
        assert!(m.count_within.is_empty());
    }

    #[test]
    fn count_within_equals_oracle() {
        let mut rng = Pcg64Mcg::seed_from_u64(3);
        let source = integer_descriptors(&mut rng, 97, 2);
        let target = integer_descriptors(&mut rng, 611, 2);
        for radius in [0.0f32, 4.0, 6.0, 7.5] {
            let counts = count_within(&source, &target, radius);
            let expected: Vec<u32> = source
                .iter()
                .map(|q| oracle_count(q, &target, radius as f64))
                .collect();
            assert_eq!(counts, expected, "radius {radius}");
        }
        // FPFH-like floats at the paper's τ_d = 12: exact except for distances within rounding
        // of the radius.
        let mut source = fpfh_like(&mut rng, 1100, 20);
        let target = source.split_off(200);
        let counts = count_within(&source, &target, 12.0);
        assert!(counts.iter().any(|&c| c > 0) && counts.iter().any(|&c| c < 900));
        for (q, &c) in source.iter().zip(&counts) {
            let low = oracle_count(q, &target, 12.0 - 1e-3);
            let high = oracle_count(q, &target, 12.0 + 1e-3);
            assert!(low <= c && c <= high, "{low} <= {c} <= {high}");
        }
    }

    #[test]
    fn kd_tree_agrees_with_brute_force() {
        let mut rng = Pcg64Mcg::seed_from_u64(4);
        let mut source = fpfh_like(&mut rng, 2200, 30);
        let target = source.split_off(700);
        for mutual in [false, true] {
            let brute = MatchConfig {
                mutual,
                count_radius: Some(12.0),
                method: MatchMethod::BruteForce,
            };
            let kd = MatchConfig {
                method: MatchMethod::KdTree,
                ..brute
            };
            let a = match_features_with(&source, &target, &brute);
            let b = match_features_with(&source, &target, &kd);
            assert_eq!(a.source_index, b.source_index, "mutual {mutual}");
            assert_eq!(a.target_index, b.target_index);
            for i in 0..a.len() {
                assert!((a.distance[i] - b.distance[i]).abs() <= 1e-4 * a.distance[i].max(1.0));
                assert!(
                    (a.second_distance[i] - b.second_distance[i]).abs()
                        <= 1e-4 * a.second_distance[i].max(1.0)
                );
                assert!(a.count_within[i].abs_diff(b.count_within[i]) <= 1);
            }
        }
    }

    #[test]
    fn same_result_on_one_and_two_threads() {
        let mut rng = Pcg64Mcg::seed_from_u64(5);
        let mut source = fpfh_like(&mut rng, 1500, 25);
        let target = source.split_off(500);
        let config = MatchConfig {
            mutual: true,
            count_radius: Some(12.0),
            method: MatchMethod::BruteForce,
        };
        let run = |threads: usize| {
            rayon::ThreadPoolBuilder::new()
                .num_threads(threads)
                .build()
                .unwrap()
                .install(|| match_features_with(&source, &target, &config))
        };
        assert_eq!(run(1), run(2));
    }

    #[test]
    fn degenerate_sizes() {
        let one = [[1.0f32; FPFH_DIM]];
        let m = match_features(&one, &one, false);
        assert_eq!((m.target_index[0], m.distance[0]), (0, 0.0));
        assert_eq!(m.second_distance[0], f32::INFINITY);
        assert!(match_features(&one, &[], true).is_empty());
        assert!(match_features(&[], &one, false).is_empty());
        assert_eq!(count_within(&one, &[], 12.0), vec![0]);
    }
}
