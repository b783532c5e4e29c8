//! Assembling a [`super::RadiusGrid`]'s storage: the layout of its columns and the points sorted
//! into them.

use nalgebra::Point3;

use super::{GridStorage, Occupancy, RadiusGrid, Scratch, lattice_axes};

/// The layout of a grid over lattice keys between `lo` and `hi`; `None` beyond `max_columns`
/// columns or keys beyond ±2³⁰ (where the cell edge no longer covers rounding).
pub(super) fn lattice_layout(
    lo: [i64; 3],
    hi: [i64; 3],
    edge_m: f64,
    radius_m: f64,
    max_columns: usize,
) -> Option<Layout> {
    const KEY_BOUND: i64 = 1 << 30;
    if lo.iter().chain(&hi).any(|k| k.abs() > KEY_BOUND) {
        return None;
    }
    let axes = lattice_axes(lo, hi);
    let extent = |k: usize| (hi[axes[k]] - lo[axes[k]]) as usize + 1;
    let dims = [extent(0), extent(1)];
    if dims[0].saturating_mul(dims[1]) > max_columns {
        return None;
    }
    Some(Layout {
        axes,
        min: std::array::from_fn(|k| lo[axes[k]] as f64 * edge_m),
        edge: edge_m,
        radius_m,
        dims,
        max_abs: (lo.iter().chain(&hi).map(|k| k.abs()).max().unwrap_or(0) + 1) as f64 * edge_m,
    })
}

/// Where a grid's cells lie: see the fields of [`RadiusGrid`].
pub(super) struct Layout {
    pub(super) axes: [usize; 3],
    pub(super) min: [f64; 3],
    pub(super) edge: f64,
    pub(super) radius_m: f64,
    pub(super) dims: [usize; 2],
    /// Largest coordinate magnitude \[m\] of the points.
    pub(super) max_abs: f64,
}

/// A grid's tables: see the fields of [`RadiusGrid`].
pub(super) struct Tables {
    pub(super) columns: Vec<(u32, u32)>,
    pub(super) starts: Vec<u32>,
    pub(super) xyz: [Vec<f64>; 3],
    pub(super) index: Vec<u32>,
    pub(super) index_is_storage_order: bool,
}

impl Layout {
    /// The grid of this layout with these tables.
    fn into_grid(self, tables: Tables, occupied: Occupancy, scratch: Scratch) -> RadiusGrid {
        let Tables {
            columns,
            starts,
            xyz,
            index,
            index_is_storage_order,
        } = tables;
        RadiusGrid {
            axes: self.axes,
            min: self.min,
            edge: self.edge,
            radius_sq: self.radius_m * self.radius_m,
            // (p − min) / edge is off by a few ulps of p's magnitude; 1e-6 of the edge on top.
            slack: 1e-6 * self.edge + 64.0 * f64::EPSILON * self.max_abs,
            dims: self.dims,
            occupied,
            columns,
            starts,
            xyz,
            index,
            index_is_storage_order,
            scratch: Box::new(scratch),
        }
    }
}

/// The grid whose entry `i` of `storage.cell` is the (column, cell along it) of the points
/// `points[run(i)]`; `None` when the columns' cells overflow `u32` offsets.
pub(super) fn assemble(
    points: &[Point3<f64>],
    layout: Layout,
    storage: GridStorage,
    run: impl Fn(usize) -> std::ops::Range<usize>,
) -> Option<RadiusGrid> {
    let GridStorage {
        mut occupied,
        mut columns,
        mut starts,
        mut xyz,
        mut index,
        mut cell,
        mut range,
        mut next,
    } = storage;
    let dims = layout.dims;
    let mut num_columns = dims[0] * dims[1];
    if occupied.reset(num_columns, cell.len()) {
        // The occupied columns, and each entry's column replaced by its rank among them: the
        // tables below cover those alone.
        for &(col, _) in &cell {
            occupied.set(col);
        }
        num_columns = occupied.finish();
        for (col, _) in &mut cell {
            *col = occupied.entry_of_occupied(*col);
        }
    }
    // Occupied range of each column.
    range.clear();
    range.resize(num_columns, (u32::MAX, 0u32));
    for &(col, z) in &cell {
        let r = &mut range[col];
        r.0 = r.0.min(z);
        r.1 = r.1.max(z);
    }
    // Each column's offset: a running sum of the occupied columns' widths (cells + 1 end entry).
    // One branch-free pass: a dense table may hold many empty columns.
    columns.clear();
    let mut offset = 0u64;
    columns.extend(range.iter().map(|&(z_lo, z_hi)| {
        let column = (z_lo, offset as u32);
        let width = u64::from(z_hi.wrapping_sub(z_lo).wrapping_add(2));
        offset += if z_lo <= z_hi { width } else { 0 };
        column
    }));
    if offset > u64::from(u32::MAX) {
        return None;
    }
    columns.push((0, offset as u32));
    // Counting sort by (column, cell along it): count into starts[slot + 1], prefix-sum. A
    // column's first entry is never counted into, so one running sum over all of `starts` leaves
    // there the points of the columns before it.
    let slot = |(col, z): (usize, u32)| columns[col].1 as usize + (z - columns[col].0) as usize;
    starts.clear();
    starts.resize(offset as usize, 0);
    for (i, &c) in cell.iter().enumerate() {
        starts[slot(c) + 1] += run(i).len() as u32;
    }
    let mut total = 0u32;
    for start in &mut starts {
        total += *start;
        *start = total;
    }
    next.clear();
    next.extend_from_slice(&starts);
    let n = total as usize;
    for v in &mut xyz {
        v.clear();
        v.resize(n, 0.0);
    }
    index.clear();
    index.resize(n, 0);
    for (i, &c) in cell.iter().enumerate() {
        let s = &mut next[slot(c)];
        for j in run(i) {
            let p = &points[j];
            for (v, c) in xyz.iter_mut().zip([p.x, p.y, p.z]) {
                v[*s as usize] = c;
            }
            index[*s as usize] = j as u32;
            *s += 1;
        }
    }
    let tables = Tables {
        columns,
        starts,
        xyz,
        index,
        index_is_storage_order: false,
    };
    Some(layout.into_grid(tables, occupied, Scratch { cell, range, next }))
}

/// [`assemble`] for points already in storage order, `cells` (key, points) in lattice order
/// under `layout.axes` and `lo` the keys' lower bounds: the same tables, written in one pass
/// over the cells (and, in a dense table, the empty columns between them) instead of a counting
/// sort.
pub(super) fn assemble_sorted(
    points: &[Point3<f64>],
    layout: Layout,
    storage: GridStorage,
    cells: &[([i64; 3], u32)],
    lo: [i64; 3],
) -> Option<RadiusGrid> {
    let GridStorage {
        mut occupied,
        mut columns,
        mut starts,
        mut xyz,
        mut index,
        cell,
        range,
        next,
    } = storage;
    let (axes, dims) = (layout.axes, layout.dims);
    let at = |key: &[i64; 3], k: usize| (key[axes[k]] - lo[axes[k]]) as usize;
    let column_of = |key: &[i64; 3]| at(key, 0) * dims[1] + at(key, 1);
    let num_columns = dims[0] * dims[1];
    columns.clear();
    let sparse = occupied.reset(num_columns, cells.len());
    if !sparse {
        columns.reserve(num_columns + 1);
    }
    starts.clear();
    // An empty column of a dense table: no cells, its offset that of the next one.
    let empty = |starts: &Vec<u32>| (u32::MAX, starts.len() as u32);
    let mut total = 0u32;
    let mut rest = cells;
    while let Some((first, _)) = rest.first() {
        let col = column_of(first);
        let len = rest.iter().take_while(|(k, _)| column_of(k) == col).count();
        let (here, after) = rest.split_at(len);
        if sparse {
            occupied.set(col);
        } else {
            columns.resize(col, empty(&starts));
        }
        // The column's cells z_lo ..= z_hi: each one's first point (an empty cell's is the next
        // one's), then the end of the column's points.
        let z_lo = at(first, 2) as u32;
        columns.push((z_lo, starts.len() as u32));
        let mut z = z_lo;
        for (key, n) in here {
            let zc = at(key, 2) as u32;
            while z <= zc {
                starts.push(total);
                z += 1;
            }
            total += n;
        }
        starts.push(total);
        rest = after;
    }
    if sparse {
        occupied.finish();
    } else {
        columns.resize(num_columns, empty(&starts));
    }
    if starts.len() > u32::MAX as usize {
        return None;
    }
    columns.push((0, starts.len() as u32));
    for (v, k) in xyz.iter_mut().zip(0..3) {
        v.clear();
        v.extend(points.iter().map(|p| p[k]));
    }
    index.clear();
    index.extend(0..points.len() as u32);
    let tables = Tables {
        columns,
        starts,
        xyz,
        index,
        index_is_storage_order: true,
    };
    Some(layout.into_grid(tables, occupied, Scratch { cell, range, next }))
}
