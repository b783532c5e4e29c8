//! Hybrid (radius + count) neighbourhoods of every point of a cloud among the same points, through
//! a uniform grid whose cell edge is the search radius: each point's candidates are the points of
//! its own and the 26 surrounding cells, which hold, in sorted cell order, in 9 contiguous runs.
//!
//! Same sets as [`KdTree::hybrid_neighbourhoods`](super::KdTree::hybrid_neighbourhoods) on a
//! tree over the same points (strict radius, ties by index, at most `max_nn`), with one rule made
//! explicit: when equal distances straddle the `max_nn` cut, the lowest indices are kept. Only the
//! order differs: the nearest comes first, the others follow in an unspecified (but
//! deterministic) order, where the tree sorts them all. On the voxel-downsampled clouds this serves, a cell lookup per query replaces a tree
//! descent with a bounded result heap (figures in docs/PAIRWISE.md).

use nalgebra::Point3;

use super::Neighbourhoods;
use super::kdtree::{QUERY_CHUNK, bounds, check_points};
use super::normals::check_search_params;
use crate::Result;

/// Largest number of cells along an axis; beyond it (a radius tiny against the cloud's extent)
/// the caller should use the kd-tree.
const MAX_CELLS_PER_AXIS: f64 = (1u64 << 40) as f64;

/// Neighbourhoods of every point of `points` among `points`: the points strictly closer than
/// `radius_m` (m), at most `max_nn` of them (the nearest, ties by index); the nearest first (each
/// point is its own first neighbour), the others in an unspecified, deterministic order. Returns
/// `Ok(None)` when the cloud's extent exceeds 2⁴⁰ cells of the radius (use
/// [`KdTree::hybrid_neighbourhoods`](super::KdTree::hybrid_neighbourhoods) then).
///
/// Errors: [`Error::InvalidInput`](crate::Error::InvalidInput) on a non-finite coordinate, `radius_m` not finite and
/// positive, `max_nn == 0`, or more than `u32::MAX` points.
pub fn self_neighbourhoods(
    points: &[Point3<f64>],
    radius_m: f64,
    max_nn: usize,
) -> Result<Option<Neighbourhoods>> {
    let mut out = Neighbourhoods::default();
    Ok(self_neighbourhoods_into(points, radius_m, max_nn, &mut out)?.then_some(out))
}

/// [`self_neighbourhoods`] into `out`, replacing its contents but keeping its storage (a stream
/// of similar clouds allocates its neighbourhoods once). Returns `Ok(false)`, leaving `out`
/// untouched, where [`self_neighbourhoods`] returns `Ok(None)`.
pub fn self_neighbourhoods_into(
    points: &[Point3<f64>],
    radius_m: f64,
    max_nn: usize,
    out: &mut Neighbourhoods,
) -> Result<bool> {
    check_search_params(radius_m, max_nn)?;
    check_points(points)?;
    let Some(grid) = Grid::new(points, radius_m) else {
        return Ok(false);
    };
    let radius_sq = radius_m * radius_m;
    out.refill(points.len(), |first, block| {
        let mut search = CellSearch::default();
        let end = (first + QUERY_CHUNK).min(points.len());
        for (i, q) in points[first..end].iter().enumerate() {
            let cell = grid.cell_of_point[first + i];
            let found = search.query(&grid, cell, q, radius_sq, max_nn);
            block.indices.extend(found.iter().map(|&key| key as u32));
            block
                .distances_sq
                .extend(found.iter().map(|&key| f64::from_bits((key >> 32) as u64)));
            block.offsets.push(block.indices.len());
        }
    });
    Ok(true)
}

/// Reusable buffers of one worker: the candidates of the last cell searched (consecutive queries,
/// sorted by voxel, often share a cell) and the neighbours found.
#[derive(Default)]
struct CellSearch {
    cell: Option<u32>,
    x: Vec<f64>,
    y: Vec<f64>,
    z: Vec<f64>,
    index: Vec<u32>,
    /// Squared distance of each candidate to the current query \[m²\].
    distance_sq: Vec<f64>,
    /// Positions (in the candidates) of those within the radius.
    within: Vec<u32>,
    /// Squared distance as bits (monotone for non-negative values) above the index: one integer
    /// whose order is (distance, index), compared in one step where a tuple needs two.
    found: Vec<u128>,
}

impl CellSearch {
    /// Neighbours of `q` (in cell `cell`) strictly within `radius_sq`, at most `max_nn` (the
    /// nearest, ties by index); the nearest first, the others unordered.
    fn query(
        &mut self,
        grid: &Grid,
        cell: u32,
        q: &Point3<f64>,
        radius_sq: f64,
        max_nn: usize,
    ) -> &[u128] {
        if self.cell != Some(cell) {
            self.cell = Some(cell);
            for v in [&mut self.x, &mut self.y, &mut self.z] {
                v.clear();
            }
            self.index.clear();
            for &(start, end) in &grid.runs[cell as usize] {
                let range = start as usize..end as usize;
                for p in &grid.sorted_xyz[range.clone()] {
                    self.x.push(p[0]);
                    self.y.push(p[1]);
                    self.z.push(p[2]);
                }
                self.index.extend_from_slice(&grid.sorted_index[range]);
            }
        }
        // Three passes, each simple enough for the compiler to keep tight: the distances (no
        // dependency between candidates, so vectorised), a branch-free filter writing each
        // candidate's position at the next free slot, which only advances when it is within the
        // radius (about half are, so a branch on it would be mispredicted often), and the keys of
        // the few found. One loop building a key per candidate took 3 times the instructions.
        let candidates = self.index.len();
        // Grown, never shrunk nor cleared: every slot read below was written for this query.
        if self.within.len() < candidates {
            self.distance_sq.resize(candidates, 0.0);
            self.within.resize(candidates, 0);
            self.found.resize(candidates, 0);
        }
        let distance_sq = &mut self.distance_sq[..candidates];
        for (((d, x), y), z) in distance_sq
            .iter_mut()
            .zip(&self.x)
            .zip(&self.y)
            .zip(&self.z)
        {
            // kiddo's squared Euclidean distance, term by term.
            let (dx, dy, dz) = (q.x - x, q.y - y, q.z - z);
            *d = dx * dx + dy * dy + dz * dz;
        }
        let within = &mut self.within[..candidates];
        let mut n = 0;
        for (k, &d) in distance_sq.iter().enumerate() {
            within[n] = k as u32;
            n += usize::from(d < radius_sq);
        }
        for (key, &k) in self.found.iter_mut().zip(&within[..n]) {
            let k = k as usize;
            *key = u128::from(distance_sq[k].to_bits()) << 32 | u128::from(self.index[k]);
        }
        let mut found = &mut self.found[..n];
        if found.len() > max_nn {
            found.select_nth_unstable(max_nn);
            found = &mut found[..max_nn];
        }
        // Only the nearest has a fixed place (first): FPFH skips it, as Open3D skips its first
        // neighbour, and no consumer needs the rest ordered. Sorting them was about a fifth of
        // preparing a KITTI cloud (docs/PAIRWISE.md).
        if let Some(nearest) = (0..found.len()).min_by_key(|&k| found[k]) {
            found.swap(0, nearest);
        }
        found
    }
}

/// Points sorted by cell, and for each occupied cell the 9 runs of sorted points covering its
/// 3 × 3 × 3 block of cells.
struct Grid {
    /// Index into `runs` of each input point's cell.
    cell_of_point: Vec<u32>,
    /// Per occupied cell: for each (dx, dy) ∈ {−1, 0, 1}², the range of sorted points in cells
    /// (x + dx, y + dy, z − 1 ..= z + 1).
    runs: Vec<[(u32, u32); 9]>,
    /// Coordinates in cell order.
    sorted_xyz: Vec<[f64; 3]>,
    /// Original index of each sorted point.
    sorted_index: Vec<u32>,
}

impl Grid {
    /// `None` if the extent exceeds [`MAX_CELLS_PER_AXIS`] cells.
    fn new(points: &[Point3<f64>], radius_m: f64) -> Option<Grid> {
        // A cell edge a little above the radius keeps every in-radius pair within one cell of
        // each other despite the rounding of (p − min) / edge.
        let edge = radius_m * (1.0 + 1e-6);
        let (min, max) = bounds(points);
        if (0..3).any(|a| (max[a] - min[a]) / edge > MAX_CELLS_PER_AXIS) {
            return None;
        }
        let cell = |p: &Point3<f64>| -> [i64; 3] {
            // p − min ≥ 0, where truncation is floor (and needs no libm call).
            std::array::from_fn(|a| ((p[a] - min[a]) / edge) as i64)
        };
        let mut keyed: Vec<([i64; 3], u32)> = points
            .iter()
            .enumerate()
            .map(|(i, p)| (cell(p), i as u32))
            .collect();
        keyed.sort_unstable();
        let mut cell_keys: Vec<[i64; 3]> = Vec::new();
        let mut cell_starts: Vec<u32> = Vec::new();
        let mut cell_of_point = vec![0u32; points.len()];
        for (s, &(key, i)) in keyed.iter().enumerate() {
            if cell_keys.last() != Some(&key) {
                cell_keys.push(key);
                cell_starts.push(s as u32);
            }
            cell_of_point[i as usize] = (cell_keys.len() - 1) as u32;
        }
        cell_starts.push(keyed.len() as u32);
        let runs = cell_keys
            .iter()
            .map(|&[x, y, z]| {
                std::array::from_fn(|k| {
                    let (dx, dy) = (k as i64 / 3 - 1, k as i64 % 3 - 1);
                    let first = cell_keys.partition_point(|c| *c < [x + dx, y + dy, z - 1]);
                    let end = cell_keys.partition_point(|c| *c <= [x + dx, y + dy, z + 1]);
                    (cell_starts[first], cell_starts[end.max(first)])
                })
            })
            .collect();
        Some(Grid {
            cell_of_point,
            runs,
            sorted_xyz: keyed
                .iter()
                .map(|&(_, i)| {
                    let p = &points[i as usize];
                    [p.x, p.y, p.z]
                })
                .collect(),
            sorted_index: keyed.iter().map(|&(_, i)| i).collect(),
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::KdTree;
    use rand::{RngExt, SeedableRng};
    use rand_pcg::Pcg64;

    /// Brute force: all points strictly within the radius, by (distance², index), first max_nn.
    fn oracle(points: &[Point3<f64>], q: usize, radius: f64, max_nn: usize) -> Vec<(u32, f64)> {
        let mut all: Vec<(f64, u32)> = points
            .iter()
            .enumerate()
            .map(|(j, p)| {
                let d = points[q] - p;
                (d.x * d.x + d.y * d.y + d.z * d.z, j as u32)
            })
            .filter(|&(d, _)| d < radius * radius)
            .collect();
        all.sort_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
        all.truncate(max_nn);
        all.into_iter().map(|(d, j)| (j, d)).collect()
    }

    /// Query `i`'s neighbours sorted by (distance², index).
    fn sorted(nbhd: &Neighbourhoods, i: usize) -> Vec<(u32, f64)> {
        let (idx, d2) = nbhd.get(i);
        let mut v: Vec<(u32, f64)> = idx.iter().copied().zip(d2.iter().copied()).collect();
        v.sort_by(|a, b| a.1.total_cmp(&b.1).then(a.0.cmp(&b.0)));
        v
    }

    fn check(points: &[Point3<f64>], radius: f64, max_nn: usize) {
        let nbhd = self_neighbourhoods(points, radius, max_nn)
            .unwrap()
            .unwrap();
        assert_eq!(nbhd.len(), points.len());
        for i in 0..points.len() {
            let expected = oracle(points, i, radius, max_nn);
            let got = sorted(&nbhd, i);
            assert_eq!(got, expected, "point {i}");
            // The nearest comes first (FPFH skips it).
            let (idx, d2) = nbhd.get(i);
            assert_eq!((idx[0], d2[0]), expected[0], "point {i}");
        }
    }

    #[test]
    fn equals_brute_force_on_random_clouds_and_surfaces() {
        let mut rng = Pcg64::seed_from_u64(11);
        let cube: Vec<Point3<f64>> = (0..1500)
            .map(|_| Point3::from(std::array::from_fn(|_| rng.random_range(-1.0..1.0))))
            .collect();
        // A plane and a sphere far from the origin (large coordinates, many cells empty).
        let mut surfaces: Vec<Point3<f64>> = (0..800)
            .map(|_| {
                Point3::new(
                    rng.random_range(-3.0..3.0),
                    rng.random_range(-3.0..3.0),
                    0.0,
                )
            })
            .collect();
        surfaces.extend((0..800).map(|_| {
            let u: [f64; 3] = rand_distr::Distribution::sample(&rand_distr::UnitSphere, &mut rng);
            let v = nalgebra::Vector3::from(u);
            Point3::new(1000.0, -2000.0, 50.0) + v * 2.0
        }));
        for (radius, max_nn) in [(0.1, 30), (0.25, 10), (0.6, 100), (5.0, 7)] {
            check(&cube, radius, max_nn);
            check(&surfaces, radius, max_nn);
        }
    }

    /// An integer lattice at spacing = radius puts many points exactly on the radius (excluded)
    /// and many equal distances across the max_nn cut (lowest indices kept).
    #[test]
    fn lattice_boundaries_and_ties() {
        let mut points = Vec::new();
        for x in 0..6 {
            for y in 0..6 {
                for z in 0..4 {
                    points.push(Point3::new(x as f64 * 0.5, y as f64 * 0.5, z as f64 * 0.5));
                }
            }
        }
        for (radius, max_nn) in [(0.5, 50), (0.5000001, 3), (0.75, 5), (1.0, 100)] {
            check(&points, radius, max_nn);
        }
    }

    #[test]
    fn agrees_with_kd_tree_when_no_tie_straddles_the_cut() {
        let mut rng = Pcg64::seed_from_u64(5);
        let points: Vec<Point3<f64>> = (0..2000)
            .map(|_| Point3::from(std::array::from_fn(|_| rng.random_range(-1.0..1.0))))
            .collect();
        let tree = KdTree::new(&points).unwrap();
        let a = tree.hybrid_neighbourhoods(&points, 0.2, 30);
        let b = self_neighbourhoods(&points, 0.2, 30).unwrap().unwrap();
        for i in 0..points.len() {
            let (idx, d2) = a.get(i);
            let tree_order: Vec<(u32, f64)> = idx.iter().copied().zip(d2.iter().copied()).collect();
            assert_eq!(tree_order, sorted(&b, i), "point {i}");
        }
    }

    #[test]
    fn bad_inputs() {
        let p = [Point3::new(0.0, 0.0, 0.0), Point3::new(f64::NAN, 0.0, 0.0)];
        assert!(self_neighbourhoods(&p, 1.0, 5).is_err());
        assert!(self_neighbourhoods(&p[..1], 0.0, 5).is_err());
        assert!(self_neighbourhoods(&p[..1], 1.0, 0).is_err());
        assert!(self_neighbourhoods(&p[..1], f64::INFINITY, 5).is_err());
        let empty = self_neighbourhoods(&[], 1.0, 5).unwrap().unwrap();
        assert!(empty.is_empty());
        let far = [Point3::new(0.0, 0.0, 0.0), Point3::new(1e300, 0.0, 0.0)];
        assert!(self_neighbourhoods(&far, 1e-9, 5).unwrap().is_none());
    }
}
