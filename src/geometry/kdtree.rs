//! A small 3-D kd-tree adapter over kiddo's `ImmutableKdTree<f64, 3>`.
//!
//! Every query returns neighbours sorted by (squared distance, index), so results are identical
//! whatever the thread count. Radius queries are strict (`distance < radius`), as in nanoflann,
//! which Open3D's `KDTreeFlann` wraps.

use std::num::NonZeroUsize;

use kiddo::{ImmutableKdTree, SquaredEuclidean};
use nalgebra::Point3;
use rayon::prelude::*;

use crate::{Error, Result};

/// One neighbour of a query point.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Neighbour {
    /// Index of the neighbour in the slice the tree was built from.
    pub index: usize,
    /// Squared Euclidean distance to the query point (m²).
    pub distance_sq: f64,
}

/// Neighbourhoods of many query points, flat (CSR) per block of 256 queries: no
/// per-query allocation survives, the blocks are filled in parallel where they stay (no merge
/// copy), and [`KdTree::hybrid_neighbourhoods_into`] reuses their storage from one cloud to the
/// next.
#[derive(Debug, Clone, Default)]
pub struct Neighbourhoods {
    len: usize,
    blocks: Vec<NeighbourBlock>,
}

/// The neighbourhoods of one block of queries: query `k`'s are at `offsets[k]..offsets[k + 1]`.
#[derive(Debug, Clone, Default)]
pub(crate) struct NeighbourBlock {
    pub(crate) offsets: Vec<usize>,
    pub(crate) indices: Vec<u32>,
    pub(crate) distances_sq: Vec<f64>,
}

impl Neighbourhoods {
    /// Number of query points.
    pub fn len(&self) -> usize {
        self.len
    }

    /// `true` when there are no query points.
    pub fn is_empty(&self) -> bool {
        self.len == 0
    }

    /// Refills `self` for `queries` queries, block by block in parallel: `fill(first, block)`
    /// receives the index of the block's first query and an empty block (storage kept) to push
    /// the [`QUERY_CHUNK`] (or fewer, for the last) queries' neighbourhoods into, starting with
    /// the leading `0` offset already in place.
    pub(crate) fn refill(
        &mut self,
        queries: usize,
        fill: impl Fn(usize, &mut NeighbourBlock) + Sync + Send,
    ) {
        self.len = queries;
        self.blocks
            .resize_with(queries.div_ceil(QUERY_CHUNK), Default::default);
        self.blocks
            .par_iter_mut()
            .enumerate()
            .for_each(|(b, block)| {
                block.offsets.clear();
                block.indices.clear();
                block.distances_sq.clear();
                block.offsets.push(0);
                fill(b * QUERY_CHUNK, block);
            });
    }

    /// Neighbour indices and squared distances (m²) of query `i`: the nearest first; the others
    /// nearest first too when the kd-tree searched them, in an unspecified (deterministic) order
    /// when [`grid::self_neighbourhoods`](super::grid::self_neighbourhoods) did.
    ///
    /// # Panics
    /// If `i >= self.len()`.
    pub fn get(&self, i: usize) -> (&[u32], &[f64]) {
        assert!(i < self.len, "query {i} of {}", self.len);
        let block = &self.blocks[i / QUERY_CHUNK];
        let k = i % QUERY_CHUNK;
        let range = block.offsets[k]..block.offsets[k + 1];
        (&block.indices[range.clone()], &block.distances_sq[range])
    }
}

/// Kd-tree over a fixed set of 3-D points (coordinates in metres).
pub struct KdTree {
    tree: Option<ImmutableKdTree<f64, 3>>,
    len: usize,
}

/// Queries processed per rayon task when building [`Neighbourhoods`].
pub(crate) const QUERY_CHUNK: usize = 256;

/// The input checks of every neighbour search over `points`: at most `u32::MAX` points (indices
/// are stored as `u32`), all coordinates finite.
pub(crate) fn check_points(points: &[Point3<f64>]) -> Result<()> {
    if points.len() > u32::MAX as usize {
        return Err(Error::InvalidInput(format!(
            "neighbour searches support at most {} points, got {}",
            u32::MAX,
            points.len()
        )));
    }
    if let Some(i) = points
        .iter()
        .position(|p| !p.coords.iter().all(|c| c.is_finite()))
    {
        return Err(Error::InvalidInput(format!(
            "point {i} has a non-finite coordinate: {:?}",
            points[i]
        )));
    }
    Ok(())
}

/// Per-axis minimum and maximum of `points` (`[+∞; 3]` and `[−∞; 3]` when empty).
pub(crate) fn bounds(points: &[Point3<f64>]) -> ([f64; 3], [f64; 3]) {
    let mut lo = [f64::INFINITY; 3];
    let mut hi = [f64::NEG_INFINITY; 3];
    for p in points {
        for a in 0..3 {
            lo[a] = lo[a].min(p[a]);
            hi[a] = hi[a].max(p[a]);
        }
    }
    (lo, hi)
}

impl KdTree {
    /// Builds the tree. Fails with [`Error::InvalidInput`] on a non-finite coordinate or more than
    /// `u32::MAX` points. An empty slice gives a tree on which every query returns nothing.
    pub fn new(points: &[Point3<f64>]) -> Result<Self> {
        check_points(points)?;
        if points.is_empty() {
            return Ok(Self { tree: None, len: 0 });
        }
        let coords: Vec<[f64; 3]> = points.iter().map(|p| [p.x, p.y, p.z]).collect();
        let tree = ImmutableKdTree::new_from_slice(&coords)
            .map_err(|e| Error::InvalidInput(format!("kd-tree construction failed: {e}")))?;
        Ok(Self {
            tree: Some(tree),
            len: points.len(),
        })
    }

    /// The kiddo tree (`None` for an empty cloud), e.g. to hand it on to ICP without rebuilding.
    pub(crate) fn into_inner(self) -> Option<ImmutableKdTree<f64, 3>> {
        self.tree
    }

    /// Number of points in the tree.
    pub fn len(&self) -> usize {
        self.len
    }

    /// `true` when the tree holds no point.
    pub fn is_empty(&self) -> bool {
        self.len == 0
    }

    /// The `k` nearest points to `query`, nearest first (fewer if the tree is smaller).
    pub fn nearest_k(&self, query: &Point3<f64>, k: usize) -> Vec<Neighbour> {
        let (Some(tree), Some(k)) = (&self.tree, NonZeroUsize::new(k)) else {
            return Vec::new();
        };
        let q = [query.x, query.y, query.z];
        sorted_neighbours(
            tree.query(&q)
                .nearest_n::<SquaredEuclidean<f64>>(k)
                .execute()
                .into_iter()
                .map(|r| (r.item, r.distance)),
        )
    }

    /// Points strictly closer than `radius_m` to `query`, nearest first, at most `max_nn` of them
    /// (Open3D's `KDTreeSearchParamHybrid(radius, max_nn)` search). The query point itself is
    /// included when it is in the tree (distance 0).
    pub fn within_radius(
        &self,
        query: &Point3<f64>,
        radius_m: f64,
        max_nn: usize,
    ) -> Vec<Neighbour> {
        let (Some(tree), Some(max_nn)) = (&self.tree, NonZeroUsize::new(max_nn)) else {
            return Vec::new();
        };
        let q = [query.x, query.y, query.z];
        sorted_neighbours(
            tree.query(&q)
                .nearest_n::<SquaredEuclidean<f64>>(max_nn)
                .within(radius_m * radius_m)
                .exclusive_boundaries()
                .execute()
                .into_iter()
                .map(|r| (r.item, r.distance)),
        )
    }

    /// [`Self::within_radius`] for every point of `queries`, in parallel.
    pub fn hybrid_neighbourhoods(
        &self,
        queries: &[Point3<f64>],
        radius_m: f64,
        max_nn: usize,
    ) -> Neighbourhoods {
        let mut out = Neighbourhoods::default();
        self.hybrid_neighbourhoods_into(queries, radius_m, max_nn, &mut out);
        out
    }

    /// [`Self::hybrid_neighbourhoods`] into `out`, replacing its contents but keeping its storage:
    /// a stream of similar clouds allocates its neighbourhoods once (megabytes a frame at LiDAR
    /// size, which the allocator would otherwise map and unmap for every frame).
    pub fn hybrid_neighbourhoods_into(
        &self,
        queries: &[Point3<f64>],
        radius_m: f64,
        max_nn: usize,
        out: &mut Neighbourhoods,
    ) {
        out.refill(queries.len(), |first, block| {
            let end = (first + QUERY_CHUNK).min(queries.len());
            for q in &queries[first..end] {
                for n in self.within_radius(q, radius_m, max_nn) {
                    block.indices.push(n.index as u32);
                    block.distances_sq.push(n.distance_sq);
                }
                block.offsets.push(block.indices.len());
            }
        });
    }
}

/// Sorts by squared distance, ties by index, so the order never depends on tree internals.
/// kiddo's `(item, squared distance)` results as [`Neighbour`]s in (distance, index) order.
fn sorted_neighbours(results: impl Iterator<Item = (u32, f64)>) -> Vec<Neighbour> {
    let mut out: Vec<Neighbour> = results
        .map(|(item, distance_sq)| Neighbour {
            index: item as usize,
            distance_sq,
        })
        .collect();
    sort_neighbours(&mut out);
    out
}

fn sort_neighbours(nn: &mut [Neighbour]) {
    // kiddo already sorts by distance; only exact ties can be out of index order.
    let ordered = |a: &Neighbour, b: &Neighbour| {
        a.distance_sq < b.distance_sq || (a.distance_sq == b.distance_sq && a.index <= b.index)
    };
    if nn.windows(2).all(|w| ordered(&w[0], &w[1])) {
        return;
    }
    nn.sort_unstable_by(|a, b| {
        a.distance_sq
            .total_cmp(&b.distance_sq)
            .then(a.index.cmp(&b.index))
    });
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{RngExt, SeedableRng};
    use rand_pcg::Pcg64;

    fn random_cloud(n: usize, seed: u64) -> Vec<Point3<f64>> {
        let mut rng = Pcg64::seed_from_u64(seed);
        (0..n)
            .map(|_| {
                Point3::new(
                    rng.random_range(-1.0..1.0),
                    rng.random_range(-1.0..1.0),
                    rng.random_range(-1.0..1.0),
                )
            })
            .collect()
    }

    fn brute_force(points: &[Point3<f64>], q: &Point3<f64>) -> Vec<Neighbour> {
        let mut all: Vec<Neighbour> = points
            .iter()
            .enumerate()
            .map(|(index, p)| Neighbour {
                index,
                distance_sq: (p - q).norm_squared(),
            })
            .collect();
        sort_neighbours(&mut all);
        all
    }

    #[test]
    fn nearest_k_matches_brute_force() {
        let points = random_cloud(2000, 1);
        let tree = KdTree::new(&points).unwrap();
        for q in random_cloud(50, 2) {
            let expected: Vec<Neighbour> = brute_force(&points, &q).into_iter().take(17).collect();
            assert_eq!(tree.nearest_k(&q, 17), expected);
        }
    }

    #[test]
    fn within_radius_matches_brute_force_and_caps_at_max_nn() {
        let points = random_cloud(2000, 3);
        let tree = KdTree::new(&points).unwrap();
        let radius = 0.2;
        let mut capped = 0;
        for q in random_cloud(50, 4).iter().chain(points.iter().take(50)) {
            let inside: Vec<Neighbour> = brute_force(&points, q)
                .into_iter()
                .filter(|n| n.distance_sq < radius * radius)
                .collect();
            assert_eq!(tree.within_radius(q, radius, 10_000), inside);
            let cap = 5;
            capped += usize::from(inside.len() > cap);
            assert_eq!(
                tree.within_radius(q, radius, cap),
                inside[..inside.len().min(cap)]
            );
        }
        assert!(capped > 10, "test must exercise the max_nn cap");
    }

    #[test]
    fn hybrid_neighbourhoods_equal_single_queries() {
        let points = random_cloud(1000, 5);
        let tree = KdTree::new(&points).unwrap();
        let nbhd = tree.hybrid_neighbourhoods(&points, 0.15, 30);
        assert_eq!(nbhd.len(), points.len());
        for (i, p) in points.iter().enumerate() {
            let single = tree.within_radius(p, 0.15, 30);
            let (idx, d2) = nbhd.get(i);
            assert_eq!(idx.len(), single.len());
            assert_eq!(idx[0] as usize, i, "a point is its own nearest neighbour");
            for (k, n) in single.iter().enumerate() {
                assert_eq!((idx[k] as usize, d2[k]), (n.index, n.distance_sq));
            }
        }
    }

    #[test]
    fn reused_neighbourhoods_equal_fresh_ones() {
        let tree = KdTree::new(&random_cloud(3000, 6)).unwrap();
        let mut reused = Neighbourhoods::default();
        // A larger query set, then a smaller one with a partial last block, then none.
        for (n, seed) in [(1000, 7), (600, 8), (0, 9)] {
            let queries = random_cloud(n, seed);
            tree.hybrid_neighbourhoods_into(&queries, 0.2, 40, &mut reused);
            let fresh = tree.hybrid_neighbourhoods(&queries, 0.2, 40);
            assert_eq!((reused.len(), fresh.len()), (n, n));
            for (i, q) in queries.iter().enumerate() {
                assert_eq!(reused.get(i), fresh.get(i));
                let single = tree.within_radius(q, 0.2, 40);
                let (idx, d2) = reused.get(i);
                assert_eq!(idx.len(), single.len());
                for (k, nb) in single.iter().enumerate() {
                    assert_eq!((idx[k] as usize, d2[k]), (nb.index, nb.distance_sq));
                }
            }
        }
    }

    #[test]
    fn empty_and_invalid_inputs() {
        let tree = KdTree::new(&[]).unwrap();
        assert!(tree.within_radius(&Point3::origin(), 1.0, 10).is_empty());
        assert!(tree.nearest_k(&Point3::origin(), 3).is_empty());
        let bad = [Point3::new(0.0, f64::NAN, 0.0)];
        assert!(matches!(KdTree::new(&bad), Err(Error::InvalidInput(_))));
    }
}
