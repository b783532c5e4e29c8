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
//!   descriptors are copied into 40-float rows (33 + zero padding) and scanned linearly, a tile of
//!   query rows at a time so each target row is loaded once per tile, in parallel over queries;
//!   AVX2 + FMA are used when the CPU has them. Ties are broken by the **lowest target index**.
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
    /// Tiled, vectorised linear scan. Ties go to the lowest index. Default (faster, measured).
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
        MatchMethod::BruteForce => scan_all(queries, &to_blocks(database), radius_sq),
        MatchMethod::KdTree => kd_scan_all(&build_tree(database), queries, radius_sq),
    }
}

/// Number of target descriptors within Euclidean distance `radius` (inclusive) of each source
/// descriptor (the paper's ranking metric uses `radius = 12`). Brute force, parallel.
pub fn count_within(source: &[Fpfh], target: &[Fpfh], radius: f32) -> Vec<u32> {
    if target.is_empty() {
        return vec![0; source.len()];
    }
    let scans = scan_all(source, &to_blocks(target), Some(radius * radius));
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

    /// Offers target `j` at squared distance `d` for nearest/second nearest; strict `<` keeps
    /// the lowest index on ties (candidates must be offered in increasing index order).
    #[inline(always)]
    fn offer(&mut self, j: u32, d: f32) {
        if d < self.second_sq {
            if d < self.best_sq {
                self.second_sq = self.best_sq;
                self.best_sq = d;
                self.best_index = j;
            } else {
                self.second_sq = d;
            }
        }
    }

    /// Offers `LANES` consecutive targets starting at index `base`: counts those within
    /// `radius_sq` and, only if one of them beats the current second nearest, updates the pair.
    #[inline(always)]
    fn offer_lanes(&mut self, base: u32, d: &[f32; LANES], radius_sq: f32) {
        let mut count = 0;
        let mut min = d[0];
        for &x in d {
            count += (x <= radius_sq) as u32;
            min = min.min(x);
        }
        self.count += count;
        if min < self.second_sq {
            for (l, &x) in d.iter().enumerate() {
                self.offer(base + l as u32, x);
            }
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
// Brute force

/// Database descriptors per block, stored dimension-major so one vector register holds the same
/// dimension of `LANES` descriptors: distances to `LANES` descriptors come out of the lanes with
/// no horizontal sums.
const LANES: usize = 8;
/// Query descriptors scanned together (each loaded block serves all of them). 8 accumulators fill
/// half of the 16 AVX registers; measured faster than 4 and 12 (`examples/match_bench.rs`).
const TILE: usize = 8;
/// Query descriptors per parallel work unit.
const WORK_QUERIES: usize = 64;
/// Database blocks per cache chunk (256 × 1056 B ≈ 270 kB, fits L2): every query of a work unit
/// is scanned against one chunk before moving to the next.
const CHUNK_BLOCKS: usize = 256;

/// `LANES` database descriptors, dimension-major. Unused lanes hold +∞ (distance +∞: never
/// nearest, never counted).
type Block = [[f32; LANES]; FPFH_DIM];

fn to_blocks(descriptors: &[Fpfh]) -> Vec<Block> {
    descriptors
        .chunks(LANES)
        .map(|chunk| {
            let mut block = [[f32::INFINITY; LANES]; FPFH_DIM];
            for (l, d) in chunk.iter().enumerate() {
                for (dim, &v) in d.iter().enumerate() {
                    block[dim][l] = v;
                }
            }
            block
        })
        .collect()
}

/// Dimensions accumulated before a tile may be abandoned (the θ block of FPFH).
const PRUNE_DIMS: usize = 11;

/// Squared distances from `TILE` queries to the `LANES` descriptors of `block`, each accumulated
/// over dimensions 0..33 in order with `mul_add` (the same as a sequential scalar loop, whatever
/// the vector width), abandoned after [`PRUNE_DIMS`] dimensions (`None`) when no pair can still
/// matter: squared distances only grow with more dimensions, so a pair whose partial sum is
/// already ≥ its query's current second-nearest distance `second_sq[k]` and > `radius_sq` would
/// be ignored by [`Scan::offer_lanes`] anyway. Results are therefore bit-identical to the full
/// computation; on real FPFH clouds most tiles are abandoned once good neighbours are known.
#[inline(always)]
fn tile_distances_pruned(
    queries: &[Fpfh; TILE],
    block: &Block,
    second_sq: &[f32; TILE],
    radius_sq: f32,
) -> Option<[[f32; LANES]; TILE]> {
    let mut acc = [[0.0f32; LANES]; TILE];
    for (dim, t) in block.iter().enumerate().take(PRUNE_DIMS) {
        for k in 0..TILE {
            let q = queries[k][dim];
            for l in 0..LANES {
                let x = q - t[l];
                acc[k][l] = x.mul_add(x, acc[k][l]);
            }
        }
    }
    let mut alive = false;
    for (row, &bound) in acc.iter().zip(second_sq) {
        for &d in row {
            alive |= (d < bound) | (d <= radius_sq);
        }
    }
    if !alive {
        return None;
    }
    for (dim, t) in block.iter().enumerate().skip(PRUNE_DIMS) {
        for k in 0..TILE {
            let q = queries[k][dim];
            for l in 0..LANES {
                let x = q - t[l];
                acc[k][l] = x.mul_add(x, acc[k][l]);
            }
        }
    }
    Some(acc)
}

#[inline(always)]
fn scan_generic(queries: &[Fpfh], blocks: &[Block], radius_sq: f32, out: &mut [Scan]) {
    let mut tile = [[0.0f32; FPFH_DIM]; TILE];
    for (c, chunk) in blocks.chunks(CHUNK_BLOCKS).enumerate() {
        let first_block = c * CHUNK_BLOCKS;
        for (qs, states) in queries.chunks(TILE).zip(out.chunks_mut(TILE)) {
            // A short last tile repeats its last query; the extra results are dropped.
            for k in 0..TILE {
                tile[k] = qs[k.min(qs.len() - 1)];
            }
            let mut local = [Scan::EMPTY; TILE];
            local[..states.len()].copy_from_slice(states);
            for (b, block) in chunk.iter().enumerate() {
                let base = ((first_block + b) * LANES) as u32;
                let second_sq = std::array::from_fn(|k| local[k].second_sq);
                let Some(d) = tile_distances_pruned(&tile, block, &second_sq, radius_sq) else {
                    continue;
                };
                for k in 0..TILE {
                    local[k].offer_lanes(base, &d[k], radius_sq);
                }
            }
            states.copy_from_slice(&local[..states.len()]);
        }
    }
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
fn scan_avx2_fma(queries: &[Fpfh], blocks: &[Block], radius_sq: f32, out: &mut [Scan]) {
    scan_generic(queries, blocks, radius_sq, out)
}

fn scan(queries: &[Fpfh], blocks: &[Block], radius_sq: f32, out: &mut [Scan]) {
    #[cfg(target_arch = "x86_64")]
    if std::arch::is_x86_feature_detected!("avx2") && std::arch::is_x86_feature_detected!("fma") {
        // SAFETY: the CPU supports AVX2 and FMA (checked above).
        unsafe { scan_avx2_fma(queries, blocks, radius_sq, out) };
        return;
    }
    scan_generic(queries, blocks, radius_sq, out)
}

/// Nearest, second nearest and (if `radius_sq` is set) neighbour count of every query among
/// the database `blocks`.
fn scan_all(queries: &[Fpfh], blocks: &[Block], radius_sq: Option<f32>) -> Vec<Scan> {
    // Without a radius, count nothing: −∞ never satisfies `d <= radius_sq`.
    let radius_sq = radius_sq.unwrap_or(f32::NEG_INFINITY);
    let mut out = vec![Scan::EMPTY; queries.len()];
    out.par_chunks_mut(WORK_QUERIES)
        .zip(queries.par_chunks(WORK_QUERIES))
        .for_each(|(out, queries)| scan(queries, blocks, radius_sq, out));
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
