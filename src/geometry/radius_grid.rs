//! Nearest point within a fixed radius, for many queries against one cloud: a uniform grid
//! whose cell edge is the radius, so the answer lies in the query's 3 × 3 × 3 block of cells.
//!
//! Serves dense RANSAC verification ([`crate::ransac::DenseRigidEstimator`]), which asks, for
//! every source point under every verified hypothesis, whether some target point lies within the
//! inlier threshold. Cells are stored column by column, so the three cells `(x, y, z − 1 ..= z + 1)`
//! of a column are one contiguous run of points: a query scans 9 runs, against a kd-tree descent with a
//! result heap (dense scoring on the bunny feature clouds, ~1250 queries against ~1400 points:
//! 52–102 ns per query against 510–547 ns with the kd-tree, `DIAG_BENCH=1 examples/pair_diag.rs`
//! on a busy 2-core machine). Memory grows with the cloud's extent over the radius squared (a bit
//! per column, an entry per occupied one where most are empty): [`RadiusGrid::new`] declines
//! clouds that would need more than a cap of columns, and the caller falls back to a kd-tree.

use nalgebra::Point3;

use super::kdtree::{bounds, check_points};
use crate::Result;

/// Default cap on the grid's columns (cells of the plane spanned by the cloud's two longest axes):
/// `max(DEFAULT_COLUMNS_PER_POINT · points, DEFAULT_MIN_COLUMNS)`.
pub const DEFAULT_COLUMNS_PER_POINT: usize = 64;
/// See [`DEFAULT_COLUMNS_PER_POINT`].
pub const DEFAULT_MIN_COLUMNS: usize = 1 << 20;

/// The default cap on the columns of a grid over `points` points:
/// `max(DEFAULT_COLUMNS_PER_POINT · points, DEFAULT_MIN_COLUMNS)`.
pub fn default_max_columns(points: usize) -> usize {
    (DEFAULT_COLUMNS_PER_POINT * points).max(DEFAULT_MIN_COLUMNS)
}

/// A cloud bucketed for "nearest point strictly within `radius`" queries.
///
/// Layout: the cloud's two longest axes span a 2-D array of columns; along the shortest axis
/// each column stores only the cells between its lowest and highest occupied one. A LiDAR scan
/// (160 m × 160 m × 20 m at a 0.75 m radius: 1.8 M cells, ~45 k columns) thus costs about one
/// entry per column plus one per occupied height, not the full box. Where most columns are empty
/// (more than [`SPARSE_COLUMNS_PER_ENTRY`] columns per point or cell), only the occupied ones
/// have an entry, and a bit per column finds it.
///
/// NOTE: an entry for every column, empty or not (8 bytes, and 8 more while building), made a
/// grid over a 16 k-point KAIST03 scan at 0.37 m (~900 k columns) 10–14 MB, built in 4–9 ms,
/// mostly zeroing and faulting in its column table; a loop verification builds one or two
/// (docs/SESSIONS.md). With entries for the occupied columns only: 1.3 MB, 0.5–0.7 ms.
#[derive(Debug, Clone)]
pub struct RadiusGrid {
    /// Axis indices: `axes[0]`, `axes[1]` span the columns, `axes[2]` runs along them.
    axes: [usize; 3],
    /// Lower corner, in grid axis order.
    min: [f64; 3],
    /// Cell edge: the radius, a hair larger so that rounding of `(p − min) / edge` can never put
    /// an in-radius pair two cells apart.
    edge: f64,
    radius_sq: f64,
    /// Bound \[m\] on how far rounding can put a point (or a query) outside its cell's faces.
    slack: f64,
    /// Cells along the two column axes.
    dims: [usize; 2],
    /// Which columns hold points, and the entry in `columns` of each that does.
    occupied: Occupancy,
    /// Per column with an entry ([`Occupancy`]: every column, or the occupied ones), in column
    /// order, `(first occupied cell along the column, offset into starts)`, then one entry past
    /// the last whose offset ends the last column. An empty column of a dense table has
    /// `offset == next entry's offset`.
    columns: Vec<(u32, u32)>,
    /// For the cells `lo ..= hi` of a column at `offset`: `starts[offset + k]` is the first point
    /// of cell `lo + k`, `starts[offset + hi − lo + 1]` the end of the column's points.
    starts: Vec<u32>,
    /// x, y and z of the points in cell order (original axes), each contiguous: a run of points
    /// is scanned 4 at a time.
    xyz: [Vec<f64>; 3],
    /// Index in the input cloud of each point.
    index: Vec<u32>,
    /// Whether `index[s] == s` for every storage position `s` ([`Self::index_by_storage_order`],
    /// [`Self::from_sorted_lattice`]).
    index_is_storage_order: bool,
    /// The construction's temporaries, kept for [`RadiusGrid::into_storage`].
    scratch: Box<Scratch>,
}

/// Which columns of a grid have an entry in its column table. Dense: every column has one (an
/// empty column's offset is the next one's). Sparse: only the occupied ones; one bit per column
/// (row-major over the two column axes) tells which, with the count of set bits before each
/// 64-bit word, so an occupied column's rank among them is its entry. A word and its count share
/// 16 bytes: one cache line answers a lookup.
///
/// NOTE: dense when the table is small beside the points ([`SPARSE_COLUMNS_PER_ENTRY`]): a
/// lookup there is one read, where the bits take a popcount and a second read (nearest-point
/// queries on a KITTI scan at 0.375 m, 160 k columns for 25 k points: 3.0 ms dense, 3.4 ms
/// sparse, `examples/radius_grid_bench.rs`).
#[derive(Debug, Clone, Default)]
pub(super) struct Occupancy {
    sparse: bool,
    /// Sparse: per 64 columns, their bits and the set bits before them.
    words: Vec<(u64, u64)>,
}

/// A [`RadiusGrid`] keeps column-table entries for its occupied columns only, found by a bit per
/// column, when it has more than this many columns per entry of its points (point or lattice
/// cell): 16. Below, every column has an entry: one read per lookup.
pub const SPARSE_COLUMNS_PER_ENTRY: usize = 16;

impl Occupancy {
    /// Starts a grid of `columns` columns over `entries` points or cells: sparse (none occupied
    /// yet) when it has more than [`SPARSE_COLUMNS_PER_ENTRY`] columns per entry, else dense.
    /// Returns whether sparse.
    pub(super) fn reset(&mut self, columns: usize, entries: usize) -> bool {
        self.sparse = columns > SPARSE_COLUMNS_PER_ENTRY * entries;
        self.words.clear();
        if self.sparse {
            self.words.resize(columns.div_ceil(64), (0, 0));
        }
        self.sparse
    }

    /// Marks column `col` occupied (sparse).
    #[inline]
    pub(super) fn set(&mut self, col: usize) {
        self.words[col / 64].0 |= 1 << (col % 64);
    }

    /// After the last [`Occupancy::set`]: the ranks, and how many columns are occupied.
    pub(super) fn finish(&mut self) -> usize {
        let mut total = 0u64;
        for (bits, rank) in &mut self.words {
            *rank = total;
            total += u64::from(bits.count_ones());
        }
        total as usize
    }

    /// The entry of column `col`; sparse, `None` when it holds no point.
    #[inline(always)]
    fn entry(&self, col: usize) -> Option<usize> {
        if !self.sparse {
            return Some(col);
        }
        let (bits, rank) = self.words[col / 64];
        let b = col % 64;
        (bits >> b & 1 == 1)
            .then(|| rank as usize + (bits & ((1u64 << b) - 1)).count_ones() as usize)
    }

    /// The entry of an occupied column `col` (sparse).
    #[inline]
    pub(super) fn entry_of_occupied(&self, col: usize) -> usize {
        let (bits, rank) = self.words[col / 64];
        rank as usize + (bits & ((1u64 << (col % 64)) - 1)).count_ones() as usize
    }

    fn heap_bytes(&self) -> usize {
        self.words.capacity() * 16
    }
}

#[derive(Debug, Clone, Default)]
struct Scratch {
    cell: Vec<(usize, u32)>,
    range: Vec<(u32, u32)>,
    next: Vec<u32>,
}

/// The vectors of a [`RadiusGrid`] (its cells and the temporaries of building it), for building
/// another grid without allocating ([`RadiusGrid::new_reusing`]): each build clears them first.
#[derive(Debug, Default)]
pub struct GridStorage {
    occupied: Occupancy,
    columns: Vec<(u32, u32)>,
    starts: Vec<u32>,
    xyz: [Vec<f64>; 3],
    index: Vec<u32>,
    cell: Vec<(usize, u32)>,
    range: Vec<(u32, u32)>,
    next: Vec<u32>,
}

impl RadiusGrid {
    /// Buckets `points` into cells of edge `radius_m` \[m\]. `Ok(None)` when the cloud is empty or
    /// would need more than `max_columns` columns (use a kd-tree then).
    ///
    /// Errors: [`Error::InvalidInput`](crate::Error::InvalidInput) on a non-finite coordinate, a
    /// radius that is not finite and positive, or more than `u32::MAX` points.
    pub fn new(points: &[Point3<f64>], radius_m: f64, max_columns: usize) -> Result<Option<Self>> {
        let grid = Self::new_reusing(points, radius_m, max_columns, GridStorage::default())?;
        // A grid built once needs no temporaries afterwards.
        Ok(grid.map(|g| Self {
            scratch: Box::default(),
            ..g
        }))
    }

    /// [`RadiusGrid::new`] building into `storage` (that of an earlier grid, from
    /// [`RadiusGrid::into_storage`]): a grid rebuilt every frame over a similar cloud (a local
    /// map) then allocates, and faults in, its megabytes once. Same grid as [`RadiusGrid::new`].
    pub fn new_reusing(
        points: &[Point3<f64>],
        radius_m: f64,
        max_columns: usize,
        mut storage: GridStorage,
    ) -> Result<Option<Self>> {
        check_radius(radius_m)?;
        check_points(points)?;
        if points.is_empty() {
            return Ok(None);
        }
        let edge = cell_edge(radius_m);
        let (lo, hi) = bounds(points);
        // Longest axes first (ties by index); the shortest runs along the columns.
        let mut axes = [0usize, 1, 2];
        axes.sort_by(|&a, &b| (hi[b] - lo[b]).total_cmp(&(hi[a] - lo[a])).then(a.cmp(&b)));
        let min: [f64; 3] = std::array::from_fn(|k| lo[axes[k]]);
        let cells = |k: usize| ((hi[axes[k]] - lo[axes[k]]) / edge).floor() + 1.0;
        let (n0, n1) = (cells(0), cells(1));
        if !(n0 * n1 <= max_columns as f64 && cells(2) <= u32::MAX as f64) {
            return Ok(None);
        }
        let dims = [n0 as usize, n1 as usize];
        let n2 = cells(2) as usize;
        let cell_of = |p: &Point3<f64>| -> (usize, u32) {
            // p − min ≥ 0, where truncation is floor (and needs no libm call); through i64,
            // one instruction on x86 (the count of cells bounds it far below 2⁶³).
            let c =
                |k: usize, n: usize| ((((p[axes[k]] - min[k]) / edge) as i64) as usize).min(n - 1);
            (c(0, dims[0]) * dims[1] + c(1, dims[1]), c(2, n2) as u32)
        };
        storage.cell.clear();
        storage.cell.extend(points.iter().map(cell_of));
        let layout = Layout {
            axes,
            min,
            edge,
            radius_m,
            dims,
            max_abs: lo.iter().chain(&hi).fold(0.0f64, |m, v| m.max(v.abs())),
        };
        // One point per entry.
        Ok(assemble(points, layout, storage, |i| i..i + 1))
    }

    /// A grid over `points` already bucketed on the lattice of edge `edge_m` anchored at the
    /// origin (a local map's voxels): `cells` lists each occupied cell's key, `floor(p / edge_m)`
    /// per axis, and the range of `points` it holds; the points of a cell lie in it. No point
    /// is bucketed again, so this costs a pass over the cells and a copy of the points (a key
    /// listed twice is one cell holding both ranges). `edge_m` must be at least
    /// [`cell_edge`]`(radius_m)`, so that rounding can never put an in-radius pair two cells
    /// apart. `Ok(None)` when there are no cells, more
    /// than `max_columns` columns or keys beyond ±2³⁰ (where the cell edge no longer covers
    /// rounding).
    ///
    /// Errors: [`Error::InvalidInput`](crate::Error::InvalidInput) on a radius that is not finite
    /// and positive, an edge below `cell_edge(radius_m)`, or a cell range outside `points`.
    pub fn from_lattice(
        points: &[Point3<f64>],
        cells: &[([i64; 3], std::ops::Range<usize>)],
        edge_m: f64,
        radius_m: f64,
        max_columns: usize,
        mut storage: GridStorage,
    ) -> Result<Option<Self>> {
        check_radius(radius_m)?;
        if !(edge_m >= cell_edge(radius_m) && edge_m.is_finite()) {
            return Err(crate::Error::InvalidInput(format!(
                "lattice edge {edge_m} m is below the cell edge of radius {radius_m} m"
            )));
        }
        if points.len() > u32::MAX as usize {
            return Err(crate::Error::InvalidInput(format!(
                "at most {} points, got {}",
                u32::MAX,
                points.len()
            )));
        }
        if let Some((_, r)) = cells
            .iter()
            .find(|(_, r)| r.start > r.end || r.end > points.len())
        {
            return Err(crate::Error::InvalidInput(format!(
                "cell range {r:?} outside the {} points",
                points.len()
            )));
        }
        let Some((lo, hi)) = key_bounds(cells.iter().map(|(k, _)| k)) else {
            return Ok(None);
        };
        let Some(layout) = lattice_layout(lo, hi, edge_m, radius_m, max_columns) else {
            return Ok(None);
        };
        let (axes, dims) = (layout.axes, layout.dims);
        storage.cell.clear();
        storage.cell.extend(cells.iter().map(|(key, _)| {
            let c = |k: usize| (key[axes[k]] - lo[axes[k]]) as usize;
            (c(0) * dims[1] + c(1), c(2) as u32)
        }));
        Ok(assemble(points, layout, storage, |i| cells[i].1.clone()))
    }

    /// [`RadiusGrid::from_lattice`] over points already in the grid's storage order: `cells`
    /// lists each occupied cell's key (`floor(p / edge_m)` per axis) and how many points it
    /// holds, in increasing [`lattice_order`] under [`lattice_axes`] of the keys' bounds, and
    /// `points` holds the cells' points one cell after the other in that order. Nothing is
    /// sorted: the tables are written in one pass over the cells, and the queries answer with
    /// positions in `points`. The same grid as `from_lattice` over the same cells, which a
    /// local map kept in this order hands over every frame ([`crate::refine::local_map`]).
    /// `Ok(None)` as `from_lattice`.
    ///
    /// Errors: as `from_lattice`, and when the cells are not in that order (or a key repeats)
    /// or their counts do not add up to `points.len()`.
    pub fn from_sorted_lattice(
        points: &[Point3<f64>],
        cells: &[([i64; 3], u32)],
        edge_m: f64,
        radius_m: f64,
        max_columns: usize,
        storage: GridStorage,
    ) -> Result<Option<Self>> {
        check_radius(radius_m)?;
        if !(edge_m >= cell_edge(radius_m) && edge_m.is_finite()) {
            return Err(crate::Error::InvalidInput(format!(
                "lattice edge {edge_m} m is below the cell edge of radius {radius_m} m"
            )));
        }
        let total: u64 = cells.iter().map(|&(_, n)| u64::from(n)).sum();
        if total != points.len() as u64 || points.len() > u32::MAX as usize {
            return Err(crate::Error::InvalidInput(format!(
                "the cells hold {total} points, the cloud {} (at most {})",
                points.len(),
                u32::MAX
            )));
        }
        let Some((lo, hi)) = key_bounds(cells.iter().map(|(k, _)| k)) else {
            return Ok(None);
        };
        let Some(layout) = lattice_layout(lo, hi, edge_m, radius_m, max_columns) else {
            return Ok(None);
        };
        let axes = layout.axes;
        if let Some(w) = cells
            .windows(2)
            .find(|w| lattice_order(&w[0].0, axes) >= lattice_order(&w[1].0, axes))
        {
            return Err(crate::Error::InvalidInput(format!(
                "lattice cells out of order: {:?} before {:?} (axes {axes:?})",
                w[0].0, w[1].0
            )));
        }
        Ok(assemble_sorted(points, layout, storage, cells, lo))
    }

    /// The grid's storage, for [`RadiusGrid::new_reusing`].
    pub fn into_storage(self) -> GridStorage {
        let Scratch { cell, range, next } = *self.scratch;
        GridStorage {
            occupied: self.occupied,
            columns: self.columns,
            starts: self.starts,
            xyz: self.xyz,
            index: self.index,
            cell,
            range,
            next,
        }
    }

    /// Squared distance \[m²\] from `q` to the nearest point of the cloud if that is strictly below
    /// the radius squared, else `None`. Exact (the same value as a kd-tree's nearest neighbour
    /// whenever that one is within the radius). A non-finite `q` has no neighbour.
    pub fn nearest_within_sq(&self, q: &Point3<f64>) -> Option<f64> {
        self.nearest_within(q).map(|(_, d)| d)
    }

    /// Index (in the cloud given to [`RadiusGrid::new`]) of and squared distance \[m²\] to the
    /// nearest point of the cloud if that is strictly within the radius, else `None`. Of several
    /// equidistant nearest points, the one first in the grid's storage order. A non-finite `q`
    /// has no neighbour.
    pub fn nearest_within(&self, q: &Point3<f64>) -> Option<(u32, f64)> {
        self.nearest_within_point(q).map(|(i, d, _)| (i, d))
    }

    /// [`Self::nearest_within`] with the nearest point's coordinates, read from the grid's own
    /// copy (the scan has just brought them into cache; a caller's array of the cloud would be
    /// one more memory access per query): the same values as the cloud's point, bit for bit.
    pub fn nearest_within_point(&self, q: &Point3<f64>) -> Option<(u32, f64, Point3<f64>)> {
        #[cfg(target_arch = "x86_64")]
        if std::arch::is_x86_feature_detected!("avx2") {
            // SAFETY: the CPU supports AVX2 (checked).
            return unsafe { self.nearest_within_avx2(q) };
        }
        self.nearest_within_impl(q)
    }

    /// [`Self::nearest_within_point`] compiled for AVX2: the same operations, 4 points per
    /// instruction.
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2")]
    fn nearest_within_avx2(&self, q: &Point3<f64>) -> Option<(u32, f64, Point3<f64>)> {
        self.nearest_within_impl(q)
    }

    #[inline(always)]
    fn nearest_within_impl(&self, q: &Point3<f64>) -> Option<(u32, f64, Point3<f64>)> {
        let c = self.query_cell(q)?;
        // Lower bounds on the squared distance from `q` to a point of the column before, at and
        // after q's own along each column axis: `q`'s distance to the face between them.
        let bounds = |k: usize| -> [f64; 3] {
            let face = self.min[k] + c[k] as f64 * self.edge;
            let v = q[self.axes[k]];
            let below = (v - face - self.slack).max(0.0);
            let above = (face + self.edge - v - self.slack).max(0.0);
            [below * below, 0.0, above * above]
        };
        let (bx, by) = (bounds(0), bounds(1));
        // The least (squared distance, storage position): of equidistant points the first in
        // storage order, whatever order the columns are visited in.
        let mut best = (self.radius_sq, usize::MAX);
        // q's own column first: its nearest point rules out the columns whose face is farther.
        if let Some(run) = self.column_run(c, 0, 0) {
            self.scan_nearest(q, run, &mut best);
        }
        for dx in -1i64..=1 {
            for dy in -1i64..=1 {
                if (dx, dy) == (0, 0) || bx[(dx + 1) as usize] + by[(dy + 1) as usize] > best.0 {
                    continue;
                }
                if let Some(run) = self.column_run(c, dx, dy) {
                    self.scan_nearest(q, run, &mut best);
                }
            }
        }
        (best.0 < self.radius_sq).then(|| {
            let s = best.1;
            // Indexed by storage order, the answer is the position itself: no read of `index`.
            let i = if self.index_is_storage_order {
                s as u32
            } else {
                self.index[s]
            };
            let [x, y, z] = &self.xyz;
            (i, best.0, Point3::new(x[s], y[s], z[s]))
        })
    }

    /// Lowers `best` (squared distance, storage position) to the least over the points of `run`.
    #[inline(always)]
    fn scan_nearest(&self, q: &Point3<f64>, run: std::ops::Range<usize>, best: &mut (f64, usize)) {
        let [xs, ys, zs] = self.xyz.each_ref().map(|v| &v[run.clone()]);
        let offer = |best: &mut (f64, usize), d: f64, at: usize| {
            if d < best.0 || (d == best.0 && at < best.1) {
                *best = (d, at);
            }
        };
        let (x4, y4, z4) = (xs.chunks_exact(4), ys.chunks_exact(4), zs.chunks_exact(4));
        for (k, ((x, y), z)) in x4.zip(y4).zip(z4).enumerate() {
            let d: [f64; 4] = std::array::from_fn(|l| squared_distance(q, x[l], y[l], z[l]));
            // Most quads hold no candidate: one vector compare rules them out.
            if d.iter().fold(false, |any, &d| any | (d <= best.0)) {
                for (l, &d) in d.iter().enumerate() {
                    offer(best, d, run.start + 4 * k + l);
                }
            }
        }
        for k in xs.len() / 4 * 4..xs.len() {
            offer(
                best,
                squared_distance(q, xs[k], ys[k], zs[k]),
                run.start + k,
            );
        }
    }

    /// Every point of the cloud strictly within the radius of `q`, appended to `out` as one key
    /// per point, `(squared distance bits) << 32 | index` (index in the cloud given to
    /// [`RadiusGrid::new`]): for non-negative distances the keys order by (distance, index), so a
    /// caller sorts or selects on them directly. Unordered. A non-finite `q` finds none.
    pub fn within(&self, q: &Point3<f64>, out: &mut Vec<u128>) {
        let Some(c) = self.query_cell(q) else {
            return;
        };
        self.for_each_run(c, |run| {
            let [xs, ys, zs] = self.xyz.each_ref().map(|v| &v[run.clone()]);
            for (((&x, &y), &z), &i) in xs.iter().zip(ys).zip(zs).zip(&self.index[run]) {
                let d = squared_distance(q, x, y, z);
                if d < self.radius_sq {
                    out.push(u128::from(d.to_bits()) << 32 | u128::from(i));
                }
            }
        });
    }

    /// Whether some point of the cloud is strictly within the radius of `q`: [`Self::nearest_within`]
    /// `.is_some()`, but scanning `q`'s own column first and stopping at the first point found
    /// (a query near the cloud usually finds one there). A non-finite `q` has none.
    pub fn any_within(&self, q: &Point3<f64>) -> bool {
        let Some(c) = self.query_cell(q) else {
            return false;
        };
        // Own column, then edge neighbours, then corners: the likeliest to hold a point first.
        const ORDER: [(i64, i64); 9] = [
            (0, 0),
            (-1, 0),
            (1, 0),
            (0, -1),
            (0, 1),
            (-1, -1),
            (-1, 1),
            (1, -1),
            (1, 1),
        ];
        ORDER.iter().any(|&(dx, dy)| {
            self.column_run(c, dx, dy).is_some_and(|run| {
                let [xs, ys, zs] = self.xyz.each_ref().map(|v| &v[run.clone()]);
                (xs.iter().zip(ys).zip(zs))
                    .any(|((&x, &y), &z)| squared_distance(q, x, y, z) < self.radius_sq)
            })
        })
    }

    /// Grid cell of `q`, or `None` when no point can be within one cell of it (or `q` is not
    /// finite). Cells −1 and n along the column axes are outside the grid but adjacent to it.
    #[inline]
    fn query_cell(&self, q: &Point3<f64>) -> Option<[i64; 3]> {
        let mut c = [0i64; 3];
        for k in 0..3 {
            let v = (q[self.axes[k]] - self.min[k]) / self.edge;
            // Along the columns, the column's own range decides.
            let n = if k < 2 {
                self.dims[k] as f64
            } else {
                u32::MAX as f64
            };
            // floor(v) ∈ [−1, n], i.e. v ∈ [−1, n + 1) (false for NaN); floor without libm:
            // truncation for v ≥ 0, −1 below.
            if !(v >= -1.0 && v < n + 1.0) {
                return None;
            }
            c[k] = if v >= 0.0 { v as i64 } else { -1 };
        }
        Some(c)
    }

    /// Calls `f` with the storage range of the points in cells `c[2] − 1 ..= c[2] + 1` of each
    /// column `(c[0] + dx, c[1] + dy)`, dx, dy ∈ {−1, 0, 1}, that is inside the grid and holds
    /// some, in storage order. [`Self::column_run`] for the 3 × 3 block, with one bounds check
    /// per row.
    #[inline]
    fn for_each_run(&self, c: [i64; 3], mut f: impl FnMut(std::ops::Range<usize>)) {
        let (n0, n1) = (self.dims[0] as i64, self.dims[1] as i64);
        let (y_lo, y_hi) = ((c[1] - 1).max(0), (c[1] + 1).min(n1 - 1));
        if y_lo > y_hi {
            return;
        }
        for x in (c[0] - 1).max(0)..=(c[0] + 1).min(n0 - 1) {
            let row = x as usize * self.dims[1];
            for y in y_lo..=y_hi {
                let Some((z_lo, off, end)) = self.column(row + y as usize) else {
                    continue;
                };
                let z_hi = z_lo as i64 + (end - off) as i64 - 2;
                let (a, b) = ((c[2] - 1).max(z_lo as i64), (c[2] + 1).min(z_hi));
                if a > b {
                    continue;
                }
                let first = self.starts[off as usize + (a - z_lo as i64) as usize] as usize;
                let last = self.starts[off as usize + (b - z_lo as i64) as usize + 1] as usize;
                f(first..last);
            }
        }
    }

    /// Column `col`'s first cell along it, its offset into `starts` and its end there (the next
    /// entry's offset: the table has one entry past the last column); `None` when it holds no
    /// point.
    #[inline(always)]
    fn column(&self, col: usize) -> Option<(u32, u32, u32)> {
        let k = self.occupied.entry(col)?;
        let ((z_lo, off), end) = (self.columns[k], self.columns[k + 1].1);
        (off != end).then_some((z_lo, off, end))
    }

    /// Storage range of the points in cells `c[2] − 1 ..= c[2] + 1` of column
    /// `(c[0] + dx, c[1] + dy)`, or `None` when that column is outside the grid or holds none.
    #[inline]
    fn column_run(&self, c: [i64; 3], dx: i64, dy: i64) -> Option<std::ops::Range<usize>> {
        let (x, y) = (c[0] + dx, c[1] + dy);
        if x < 0 || y < 0 || x >= self.dims[0] as i64 || y >= self.dims[1] as i64 {
            return None;
        }
        let (z_lo, off, end) = self.column(x as usize * self.dims[1] + y as usize)?;
        let z_hi = z_lo as i64 + (end - off) as i64 - 2;
        let (a, b) = ((c[2] - 1).max(z_lo as i64), (c[2] + 1).min(z_hi));
        if a > b {
            return None;
        }
        let first = self.starts[off as usize + (a - z_lo as i64) as usize] as usize;
        let last = self.starts[off as usize + (b - z_lo as i64) as usize + 1] as usize;
        Some(first..last)
    }

    /// The grid's points in its storage order (cell by cell, column by column).
    pub fn points_in_storage_order(&self) -> impl ExactSizeIterator<Item = Point3<f64>> + '_ {
        let [xs, ys, zs] = &self.xyz;
        (xs.iter().zip(ys).zip(zs)).map(|((&x, &y), &z)| Point3::new(x, y, z))
    }

    /// For each point in storage order, its index in the cloud given to the constructor: the
    /// indices the queries answer with.
    pub fn storage_index(&self) -> &[u32] {
        &self.index
    }

    /// Makes the queries answer with storage positions: afterwards the cloud the indices refer
    /// to is [`Self::points_in_storage_order`], and the caller must reorder anything it keeps
    /// per point by [`Self::storage_index`] (read before). The answers are otherwise the same
    /// points (ties still go to the first in storage order).
    pub fn index_by_storage_order(&mut self) {
        for (s, i) in self.index.iter_mut().enumerate() {
            *i = s as u32;
        }
        self.index_is_storage_order = true;
    }

    /// Number of points.
    pub fn len(&self) -> usize {
        self.index.len()
    }

    /// The heap this grid holds \[bytes\]: its column bits (sparse), columns, cell starts,
    /// coordinates, indices and any scratch kept for a rebuild (capacities, not lengths).
    pub fn heap_bytes(&self) -> usize {
        let Scratch { cell, range, next } = &*self.scratch;
        self.occupied.heap_bytes()
            + self.columns.capacity() * std::mem::size_of::<(u32, u32)>()
            + (self.starts.capacity() + self.index.capacity() + next.capacity()) * 4
            + self.xyz.iter().map(|v| v.capacity() * 8).sum::<usize>()
            + cell.capacity() * std::mem::size_of::<(usize, u32)>()
            + range.capacity() * std::mem::size_of::<(u32, u32)>()
    }

    /// Whether only the occupied columns have an entry ([`Occupancy`]).
    #[cfg(test)]
    fn is_sparse(&self) -> bool {
        self.occupied.sparse
    }

    /// Whether the grid holds no points (never: [`RadiusGrid::new`] declines empty clouds).
    pub fn is_empty(&self) -> bool {
        self.index.is_empty()
    }
}

/// The cell edge of a grid of radius `radius_m` \[m\]: the radius and 1e-6 of it, so that
/// rounding of `p / edge` can never put an in-radius pair two cells apart.
pub fn cell_edge(radius_m: f64) -> f64 {
    radius_m * (1.0 + 1e-6)
}

/// A radius \[m\] is finite and positive.
pub(crate) fn check_radius(radius_m: f64) -> Result<()> {
    if radius_m.is_finite() && radius_m > 0.0 {
        Ok(())
    } else {
        Err(crate::Error::InvalidInput(format!(
            "radius must be finite and > 0, got {radius_m}"
        )))
    }
}

/// The lowest and highest lattice key along each axis; `None` for no keys.
pub(crate) fn key_bounds<'a>(
    keys: impl Iterator<Item = &'a [i64; 3]>,
) -> Option<([i64; 3], [i64; 3])> {
    keys.fold(None, |acc, k| {
        Some(match acc {
            None => (*k, *k),
            Some((lo, hi)) => (
                std::array::from_fn(|a| lo[a].min(k[a])),
                std::array::from_fn(|a| hi[a].max(k[a])),
            ),
        })
    })
}

/// The axes of a grid over lattice keys between `lo` and `hi`: the two of widest extent span
/// its columns (ties by axis index), the third runs along them.
pub fn lattice_axes(lo: [i64; 3], hi: [i64; 3]) -> [usize; 3] {
    let mut axes = [0usize, 1, 2];
    axes.sort_by(|&a, &b| (hi[b] - lo[b]).cmp(&(hi[a] - lo[a])).then(a.cmp(&b)));
    axes
}

/// A lattice key permuted to `axes`: keys in increasing order of this are cells in a grid's
/// storage order (column by column, along each column), whatever the grid's bounds.
#[inline]
pub fn lattice_order(key: &[i64; 3], axes: [usize; 3]) -> [i64; 3] {
    axes.map(|a| key[a])
}

/// Squared distance \[m²\] from `q` to `(x, y, z)`: kiddo's squared Euclidean distance, term by
/// term, so the grid's answers are the kd-tree's to the bit.
#[inline(always)]
fn squared_distance(q: &Point3<f64>, x: f64, y: f64, z: f64) -> f64 {
    let (dx, dy, dz) = (q.x - x, q.y - y, q.z - z);
    dx * dx + dy * dy + dz * dz
}

mod build;
use build::{Layout, assemble, assemble_sorted, lattice_layout};
#[cfg(test)]
mod tests;
