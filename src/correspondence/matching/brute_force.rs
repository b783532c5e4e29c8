//! Brute-force matching with an exact lower-bound filter (the default [`super::MatchMethod`]).

use rayon::prelude::*;

use super::{FPFH_DIM, Fpfh, Scan};

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
//   [`PCA_DIMS`]-dimensional bound. That bound is computed on coordinates quantised to 13-bit
//   integers ([`Quantiser`]): exact integer arithmetic, 16-bit lanes, and a margin of √PCA_DIMS
//   quantisation steps for the rounding to integers. (It replaced an f32 bound over 16 axes:
//   KITTI pair, one thread, 63 → 47 ms, bit-identical results.)
// - The thresholds follow the query's current second-nearest distance (and the count radius),
//   inflated by margins that cover every rounding error (see [`prune_threshold`] and
//   [`Quantiser::threshold`]), so the results are bit-identical to the full scan: same nearest
//   index (ties → lowest index, made order-independent by [`Scan::offer`]), same distances, same
//   counts.

/// Principal axes of the lower bound (even: two per [`QuantBlock`] row; at most 32, see
/// [`QUANT_MAX`]). 24 measured fastest among 16/20/24/28/32 on the KITTI pair (one thread:
/// 16 → 24 took 50 → 47 ms) and no slower on 3DMatch (`examples/match_bench.rs --real`).
pub(super) const PCA_DIMS: usize = 24;
/// Database descriptors per block, stored dimension-major so one vector register holds the same
/// dimension of `LANES` descriptors.
pub(super) const LANES: usize = 8;
/// Queries per parallel work unit (consecutive along the first axis, so they share windows).
pub(super) const WORK_QUERIES: usize = 64;
/// Largest magnitude of a quantised projected coordinate: the difference of two fits in an
/// `i16`, and [`PCA_DIMS`] ≤ 32 squared differences sum to at most 32 · 8190² < 2³¹.
pub(super) const QUANT_MAX: f64 = 4095.0;
const _: () = assert!(PCA_DIMS.is_multiple_of(2) && PCA_DIMS <= 32);

/// `LANES` database descriptors, dimension-major. Unused lanes hold +∞.
pub(super) type Block = [[f32; LANES]; FPFH_DIM];
/// The same descriptors' quantised projections ([`Quantiser`]), two dimensions per row
/// interleaved by lane: row `k` holds dimensions `2k` and `2k + 1` of lane 0, then of lane 1, …
/// (the operand layout of a pairwise multiply-add such as AVX2's `vpmaddwd`). Unused lanes hold 0;
/// their exact distances are +∞, so letting them through the bound costs time, never a result.
pub(super) type QuantBlock = [[i16; 2 * LANES]; PCA_DIMS / 2];

/// A searchable set of descriptors.
pub(super) struct Database {
    /// Mean descriptor (the projection's origin).
    pub(super) mean: [f64; FPFH_DIM],
    /// Orthonormal principal axes, by decreasing variance, transposed: `axes_t[i][k]` is
    /// component `i` of axis `k`.
    pub(super) axes_t: [[f64; PCA_DIMS]; FPFH_DIM],
    /// Projected descriptors in block order (sorted along the first axis), `LANES` per block.
    projected: Vec<[f64; PCA_DIMS]>,
    /// Original descriptors per block.
    full: Vec<Block>,
    /// Original index of each lane (`u32::MAX` for unused lanes).
    index: Vec<[u32; LANES]>,
    /// Smallest and largest first-axis coordinate of each block (rounded to f32).
    first_axis_range: Vec<(f32, f32)>,
    /// Largest absolute first-axis coordinate (for the rounding margin of the window test).
    max_abs_first: f32,
}

/// Mean and principal axes of `descriptors` (non-empty), from at most 4096 evenly strided
/// samples (the axes only need to be orthonormal for the bound to hold; sampling affects how
/// tight it is, not whether it is exact).
pub(super) fn principal_axes(
    descriptors: &[Fpfh],
) -> ([f64; FPFH_DIM], [[f64; PCA_DIMS]; FPFH_DIM]) {
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
    let axes_t =
        std::array::from_fn(|i| std::array::from_fn(|k| eigen.eigenvectors[(i, order[k])]));
    (mean, axes_t)
}

/// Coordinates of `d` on the axes (given transposed: `axes_t[i][k]` is component `i` of axis
/// `k`), in f64. Each coordinate sums its 33 products in order; the loop runs over all axes at
/// once so that it vectorises (bit-identical to one dot product per axis).
#[inline]
pub(super) fn project(
    d: &Fpfh,
    mean: &[f64; FPFH_DIM],
    axes_t: &[[f64; PCA_DIMS]; FPFH_DIM],
) -> [f64; PCA_DIMS] {
    let mut s = [0.0f64; PCA_DIMS];
    for ((&x, &m), axis) in d.iter().zip(mean).zip(axes_t) {
        let centred = f64::from(x) - m;
        for (s, &a) in s.iter_mut().zip(axis) {
            *s += a * centred;
        }
    }
    s
}

/// The projections of `descriptors` (in their order) and their indices sorted along the first
/// axis (ties by index).
pub(super) fn project_sorted(
    descriptors: &[Fpfh],
    mean: &[f64; FPFH_DIM],
    axes_t: &[[f64; PCA_DIMS]; FPFH_DIM],
) -> (Vec<[f64; PCA_DIMS]>, Vec<u32>) {
    let coords: Vec<[f64; PCA_DIMS]> = descriptors
        .par_iter()
        .map(|d| project(d, mean, axes_t))
        .collect();
    let mut order: Vec<u32> = (0..descriptors.len() as u32).collect();
    order.sort_unstable_by(|&a, &b| {
        coords[a as usize][0]
            .total_cmp(&coords[b as usize][0])
            .then(a.cmp(&b))
    });
    (coords, order)
}

impl Database {
    /// Builds the database (`descriptors` non-empty and finite).
    pub(super) fn new(descriptors: &[Fpfh]) -> Database {
        let (mean, axes_t) = principal_axes(descriptors);
        let (coords, order) = project_sorted(descriptors, &mean, &axes_t);
        let blocks = order.len().div_ceil(LANES);
        let mut db = Database {
            mean,
            axes_t,
            projected: order.iter().map(|&i| coords[i as usize]).collect(),
            full: vec![[[f32::INFINITY; LANES]; FPFH_DIM]; blocks],
            index: vec![[u32::MAX; LANES]; blocks],
            first_axis_range: Vec::with_capacity(blocks),
            max_abs_first: 0.0,
        };
        for (b, members) in order.chunks(LANES).enumerate() {
            for (l, &i) in members.iter().enumerate() {
                for (dim, &v) in descriptors[i as usize].iter().enumerate() {
                    db.full[b][dim][l] = v;
                }
                db.index[b][l] = i;
            }
            let first = coords[members[0] as usize][0] as f32;
            let last = coords[members[members.len() - 1] as usize][0] as f32;
            db.first_axis_range.push((first, last));
            db.max_abs_first = db.max_abs_first.max(first.abs()).max(last.abs());
        }
        db
    }
}

/// Quantisation of projected coordinates to integers of magnitude ≤ [`QUANT_MAX`], with one
/// scale for the database and the queries of a search, so that a lower bound on the projected
/// distance costs a few integer instructions per block (exact arithmetic: no rounding to track).
#[derive(Clone, Copy)]
pub(super) struct Quantiser {
    /// FPFH units per integer step.
    scale: f64,
}

impl Quantiser {
    /// The scale that maps the largest coordinate magnitude of `db` and `queries` to
    /// [`QUANT_MAX`].
    pub(super) fn new(db: &Database, queries: &[[f64; PCA_DIMS]]) -> Quantiser {
        let max_abs = db
            .projected
            .iter()
            .chain(queries)
            .flatten()
            .fold(0.0f64, |m, &x| m.max(x.abs()));
        Quantiser {
            scale: if max_abs > 0.0 {
                max_abs / QUANT_MAX
            } else {
                1.0
            },
        }
    }

    /// `round(x / scale)`: within `scale / 2` of `x` (up to f64 rounding, ~1e-12 steps).
    #[inline]
    fn quantise(self, x: f64) -> i16 {
        (x / self.scale).round().clamp(-QUANT_MAX, QUANT_MAX) as i16
    }

    /// The database's coordinates as [`QuantBlock`]s.
    pub(super) fn blocks(self, db: &Database) -> Vec<QuantBlock> {
        let mut out = vec![[[0i16; 2 * LANES]; PCA_DIMS / 2]; db.full.len()];
        for (k, c) in db.projected.iter().enumerate() {
            let (b, l) = (k / LANES, k % LANES);
            for (dim, &x) in c.iter().enumerate() {
                out[b][dim / 2][2 * l + dim % 2] = self.quantise(x);
            }
        }
        out
    }

    /// A query's quantised coordinates.
    pub(super) fn coordinates(self, c: &[f64; PCA_DIMS]) -> [i16; PCA_DIMS] {
        std::array::from_fn(|k| self.quantise(c[k]))
    }

    /// Largest quantised squared distance that can still belong to a pair whose computed full
    /// squared distance is ≤ `bound_sq`; a lane above it is skipped. With `D` = [`PCA_DIMS`],
    /// `s` = the scale, `a`, `b` exact projections, `A`, `B` their quantisations:
    /// - ‖a − b‖ ≥ s·‖A − B‖ − s·√D (each quantised vector is within s·√D / 2 of its own), so
    ///   ‖A − B‖ > (‖a − b‖) / s + √D is impossible;
    /// - the projection onto orthonormal axes never lengthens a vector, so ‖a − b‖ ≤ the exact
    ///   full distance;
    /// - the computed full squared distance (33 in-order fused multiply-adds of rounded
    ///   differences) is within a factor (1 − 40u) of the exact one, covered by 1 + 4e-5 on its
    ///   root; the factors 1 + 1e-9 and the 1e-6 step cover the f64 rounding of the projection
    ///   (orthonormal axes to ~1e-15), of the quantisation and of this function.
    #[inline]
    pub(super) fn threshold(self, bound_sq: f32) -> i32 {
        if bound_sq.is_infinite() {
            return i32::MAX;
        }
        let root = f64::from(bound_sq.max(0.0)).sqrt() * (1.0 + 4e-5);
        let steps = root / self.scale * (1.0 + 1e-9) + (PCA_DIMS as f64).sqrt() + 1e-6;
        let sq = (steps * steps * (1.0 + 1e-9)).ceil();
        if sq >= f64::from(i32::MAX) {
            i32::MAX
        } else {
            sq as i32
        }
    }
}

/// Whether a block can hold a pair that matters: some lane's quantised squared distance to the
/// query (its [`pattern`]) is ≤ `threshold`. The distances are exact integers (each
/// term ≤ 8190², the sum < 2³¹), so every implementation decides alike.
pub(super) trait BoundKernel: Copy {
    fn any_within(self, pattern: &QuantBlock, block: &QuantBlock, threshold: i32) -> bool;
}

/// Plain Rust.
#[derive(Clone, Copy)]
pub(super) struct PortableBound;

impl BoundKernel for PortableBound {
    #[inline(always)]
    fn any_within(self, pattern: &QuantBlock, block: &QuantBlock, threshold: i32) -> bool {
        let mut acc = [0i32; LANES];
        for (q, row) in pattern.iter().zip(block) {
            for l in 0..LANES {
                let d0 = i32::from(q[2 * l].wrapping_sub(row[2 * l]));
                let d1 = i32::from(q[2 * l + 1].wrapping_sub(row[2 * l + 1]));
                acc[l] += d0 * d0 + d1 * d1;
            }
        }
        acc.iter().any(|&d| d <= threshold)
    }
}

/// AVX2: one 16-bit subtract and one pairwise multiply-add (`vpmaddwd`) per row of two
/// dimensions. Only constructed once the CPU is known to have AVX2.
#[cfg(target_arch = "x86_64")]
#[derive(Clone, Copy)]
pub(super) struct Avx2Bound(pub(super) ());

#[cfg(target_arch = "x86_64")]
impl BoundKernel for Avx2Bound {
    #[inline(always)]
    fn any_within(self, pattern: &QuantBlock, block: &QuantBlock, threshold: i32) -> bool {
        // SAFETY: an `Avx2Bound` exists only where AVX2 was detected (see `scan`).
        unsafe { any_within_avx2(pattern, block, threshold) }
    }
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
#[inline]
pub(super) fn any_within_avx2(pattern: &QuantBlock, block: &QuantBlock, threshold: i32) -> bool {
    use std::arch::x86_64::*;
    let mut acc = _mm256_setzero_si256();
    for (q, row) in pattern.iter().zip(block) {
        // SAFETY: each row is 16 contiguous i16 (32 bytes); unaligned loads.
        let (q, row) = unsafe {
            (
                _mm256_loadu_si256(q.as_ptr().cast()),
                _mm256_loadu_si256(row.as_ptr().cast()),
            )
        };
        let d = _mm256_sub_epi16(q, row);
        acc = _mm256_add_epi32(acc, _mm256_madd_epi16(d, d));
    }
    let above = _mm256_cmpgt_epi32(acc, _mm256_set1_epi32(threshold));
    _mm256_movemask_epi8(above) != -1
}

/// Squared lower-bound threshold on the first-axis gap of a query whose results can only change
/// through pairs at squared distance ≤ `bound_sq`, where the stored first-axis coordinates carry
/// an absolute rounding error of at most `eta` each. A block whose computed gap squared exceeds
/// the returned value holds no pair with a computed full squared distance ≤ `bound_sq`:
/// - the stored coordinates (f32) of both descriptors are within `eta` of the exact projections,
///   so the exact gap is at least the stored one minus 2·eta; the final factor 1 + 1e-5 covers
///   the rounding of this function and of the gap;
/// - the projection onto an axis never lengthens a vector;
/// - the computed full squared distance is within a factor (1 − 40u) of the exact one, covered
///   by the factor 1 + 4e-5 on its root.
#[inline]
pub(super) fn prune_threshold(bound_sq: f32, eta: f32) -> f32 {
    if bound_sq.is_infinite() {
        return f32::INFINITY;
    }
    let root = bound_sq.max(0.0).sqrt() * (1.0 + 4e-5) + 2.0 * eta;
    root * root * (1.0 + 1e-5)
}

/// A query's quantised coordinates laid out like a [`QuantBlock`] row by row (repeated in every
/// lane).
pub(super) fn pattern(coordinates: &[i16; PCA_DIMS]) -> QuantBlock {
    std::array::from_fn(|row| std::array::from_fn(|k| coordinates[2 * row + k % 2]))
}

/// One query of a scan: its original index, its f32 first-axis coordinate and its quantised
/// coordinates (expanded to a [`pattern`] only while it is searched: 48 bytes, not 384, per
/// query).
pub(super) struct Query {
    index: u32,
    first_axis: f32,
    coordinates: [i16; PCA_DIMS],
}

/// Searches one query through `db` (`blocks` = its quantised coordinates).
#[inline(always)]
pub(super) fn search_one<K: BoundKernel>(
    kernel: K,
    db: &Database,
    blocks: &[QuantBlock],
    quantiser: Quantiser,
    query: &Fpfh,
    q: &Query,
    radius_sq: f32,
) -> Scan {
    let x = q.first_axis;
    let eta = (db.max_abs_first.max(x.abs()) * f32::EPSILON).max(f32::MIN_POSITIVE);
    let pattern = pattern(&q.coordinates);
    let mut search = QuerySearch {
        kernel,
        db,
        blocks,
        quantiser,
        query,
        pattern: &pattern,
        radius_sq,
        eta,
        scan: Scan::EMPTY,
        threshold: f32::INFINITY,
        quantised_threshold: i32::MAX,
    };
    let count = db.full.len();
    let start = db
        .first_axis_range
        .partition_point(|&(first, _)| first <= x);
    let (mut up, mut down) = (start, start);
    while up < count || down > 0 {
        if up < count {
            let gap = db.first_axis_range[up].0 - x;
            if gap > 0.0 && gap * gap > search.threshold {
                up = count;
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
pub(super) struct QuerySearch<'a, K> {
    kernel: K,
    db: &'a Database,
    blocks: &'a [QuantBlock],
    quantiser: Quantiser,
    query: &'a Fpfh,
    pattern: &'a QuantBlock,
    radius_sq: f32,
    /// Rounding bound of the stored first-axis coordinates (see [`prune_threshold`]).
    eta: f32,
    scan: Scan,
    /// First-axis gap squared beyond which a block cannot matter.
    threshold: f32,
    /// Quantised squared distance beyond which a lane cannot matter.
    quantised_threshold: i32,
}

impl<K: BoundKernel> QuerySearch<'_, K> {
    /// Offers block `b` to the scan if its lower bound lets any lane through; refreshes the
    /// thresholds.
    #[inline(always)]
    fn visit(&mut self, b: usize) {
        if !self
            .kernel
            .any_within(self.pattern, &self.blocks[b], self.quantised_threshold)
        {
            return;
        }
        let db = self.db;
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
            let bound_sq = self.scan.second_sq.max(self.radius_sq);
            self.threshold = prune_threshold(bound_sq, self.eta);
            self.quantised_threshold = self.quantiser.threshold(bound_sq);
        }
    }
}

/// The shared state of one scan's work units.
pub(super) struct ScanInput<'a> {
    db: &'a Database,
    blocks: &'a [QuantBlock],
    quantiser: Quantiser,
    all: &'a [Fpfh],
    radius_sq: f32,
}

#[inline(always)]
pub(super) fn scan_generic(
    kernel: impl BoundKernel,
    input: &ScanInput,
    queries: &[Query],
    out: &mut [Scan],
) {
    for (q, o) in queries.iter().zip(out) {
        *o = search_one(
            kernel,
            input.db,
            input.blocks,
            input.quantiser,
            &input.all[q.index as usize],
            q,
            input.radius_sq,
        );
    }
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
pub(super) fn scan_avx2_fma(input: &ScanInput, queries: &[Query], out: &mut [Scan]) {
    scan_generic(Avx2Bound(()), input, queries, out)
}

pub(super) fn scan(input: &ScanInput, queries: &[Query], out: &mut [Scan]) {
    #[cfg(target_arch = "x86_64")]
    if std::arch::is_x86_feature_detected!("avx2") && std::arch::is_x86_feature_detected!("fma") {
        // SAFETY: the CPU supports AVX2 and FMA (checked above).
        unsafe { scan_avx2_fma(input, queries, out) };
        return;
    }
    scan_generic(PortableBound, input, queries, out)
}

/// Nearest, second nearest and (if `radius_sq` is set) neighbour count of every query in `db`.
pub(super) fn scan_all(queries: &[Fpfh], db: &Database, radius_sq: Option<f32>) -> Vec<Scan> {
    // Without a radius, count nothing: −∞ never satisfies `d <= radius_sq`.
    let radius_sq = radius_sq.unwrap_or(f32::NEG_INFINITY);
    // Queries in first-axis order, so a work unit's windows overlap (cache locality); each
    // query's result is independent of the order and of the thread that computes it.
    let (projected, order) = project_sorted(queries, &db.mean, &db.axes_t);
    let quantiser = Quantiser::new(db, &projected);
    let blocks = quantiser.blocks(db);
    let sorted: Vec<Query> = order
        .par_iter()
        .map(|&i| {
            let c = &projected[i as usize];
            Query {
                index: i,
                first_axis: c[0] as f32,
                coordinates: quantiser.coordinates(c),
            }
        })
        .collect();
    let input = ScanInput {
        db,
        blocks: &blocks,
        quantiser,
        all: queries,
        radius_sq,
    };
    let mut sorted_out = vec![Scan::EMPTY; queries.len()];
    sorted_out
        .par_chunks_mut(WORK_QUERIES)
        .zip(sorted.par_chunks(WORK_QUERIES))
        .for_each(|(out, qs)| scan(&input, qs, out));
    let mut out = vec![Scan::EMPTY; queries.len()];
    for (q, s) in sorted.iter().zip(sorted_out) {
        out[q.index as usize] = s;
    }
    out
}
