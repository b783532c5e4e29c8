//! Voxel-grid downsampling: one centroid per occupied voxel, as Open3D's
//! `PointCloud::voxel_down_sample`.

use std::collections::HashMap;

use nalgebra::{Point3, Vector3};
use rayon::prelude::*;

use crate::hash::FastHash;
use crate::{Error, Result};

/// Replaces the points of each occupied voxel by their centroid (arithmetic mean).
///
/// The grid is anchored like Open3D's: with `min` the component-wise minimum of the (finite) input
/// points, the voxel of `p` is `floor((p - (min - voxel_size_m / 2)) / voxel_size_m)` per axis, so
/// the minimum point sits at the centre of voxel 0. The arithmetic (subtract, divide, floor) and
/// the summation order within a voxel (input order) are Open3D's, so the same points land in the
/// same voxels and the centroids agree bit for bit.
///
/// Output order: sorted by voxel index (x, then y, then z), so the result is identical on any
/// thread count.
///
/// NOTE: Open3D returns its voxels in hash-map order (arbitrary); we sort. Open3D also lets NaN/inf
/// points poison the bounds; we skip non-finite points (PointCloud2 clouds are often not dense).
///
/// Errors: [`Error::InvalidInput`] when `voxel_size_m` is not finite and positive, or so small that
/// a voxel index would overflow `i32` (Open3D's "voxel_size is too small").
pub fn voxel_downsample(points: &[Point3<f64>], voxel_size_m: f64) -> Result<Vec<Point3<f64>>> {
    downsample(points, voxel_size_m, None)
}

/// [`voxel_downsample`], and for each input point the index of its voxel's centroid in the
/// output (`u32::MAX` for a non-finite point).
pub fn voxel_downsample_indexed(
    points: &[Point3<f64>],
    voxel_size_m: f64,
) -> Result<(Vec<Point3<f64>>, Vec<u32>)> {
    let mut voxel_of = Vec::new();
    let centroids = downsample(points, voxel_size_m, Some(&mut voxel_of))?;
    Ok((centroids, voxel_of))
}

/// [`voxel_downsample`], filling `voxel_of` (when given) as [`voxel_downsample_indexed`] does.
fn downsample(
    points: &[Point3<f64>],
    voxel_size_m: f64,
    mut voxel_of: Option<&mut Vec<u32>>,
) -> Result<Vec<Point3<f64>>> {
    if let Some(v) = voxel_of.as_deref_mut() {
        v.clear();
        v.resize(points.len(), u32::MAX);
    }
    if !(voxel_size_m.is_finite() && voxel_size_m > 0.0) {
        return Err(Error::InvalidInput(format!(
            "voxel_size_m must be finite and > 0, got {voxel_size_m}"
        )));
    }
    if points.len() > u32::MAX as usize {
        return Err(Error::InvalidInput(format!(
            "at most {} points, got {}",
            u32::MAX,
            points.len()
        )));
    }
    let is_finite = |p: &Point3<f64>| p.coords.iter().all(|c| c.is_finite());
    let Some((min, max)) = points.iter().filter(|p| is_finite(p)).fold(
        None,
        |acc: Option<(Point3<f64>, Point3<f64>)>, p| {
            Some(match acc {
                None => (*p, *p),
                Some((lo, hi)) => (lo.inf(p), hi.sup(p)),
            })
        },
    ) else {
        return Ok(Vec::new());
    };
    let half = 0.5 * voxel_size_m;
    let origin = min.coords.add_scalar(-half);
    let extent = (max.coords.add_scalar(half) - origin).max();
    if voxel_size_m * f64::from(i32::MAX) < extent {
        return Err(Error::InvalidInput(format!(
            "voxel_size_m {voxel_size_m} is too small for a cloud spanning {extent} m"
        )));
    }

    // Voxel index per axis, non-negative and below i32::MAX by the bounds check above. The
    // largest index per axis is the max point's (the arithmetic is monotone).
    let index = move |p: &Point3<f64>| {
        let rel = (p.coords - origin) / voxel_size_m;
        [
            // rel >= 0 on every axis, where truncation equals Open3D's floor (and needs no
            // libm call). Through i64: below i32::MAX (checked above), the same value, and x86
            // truncates to a signed integer in one instruction, to an unsigned one in several.
            rel.x as i64 as u64,
            rel.y as i64 as u64,
            rel.z as i64 as u64,
        ]
    };
    let last = index(&max);
    let (ny, nz) = (last[1] + 1, last[2] + 1);
    // Row-major packing preserves the (x, y, z) lexicographic order in one integer, keys below
    // this bound.
    let packed_bound = (last[0] + 1)
        .checked_mul(ny)
        .and_then(|v| v.checked_mul(nz));
    let packed = move |p: &Point3<f64>| {
        let [x, y, z] = index(p);
        (x * ny + y) * nz + z
    };
    Ok(match packed_bound {
        Some(bound) if bound <= u64::from(u32::MAX) => {
            // Keys below the bound fit 32 bits.
            centroids_radix(points, bound, move |p| packed(p) as u32, voxel_of)
        }
        Some(_) => centroids_hashed(points, packed, voxel_of),
        None => centroids(points, index, voxel_of),
    })
}

/// Bits of key sorted per pass of [`centroids_radix`].
const RADIX_BITS: u32 = 11;

/// The finite points' (key, input index) pairs sorted by key with a stable LSD radix sort (so
/// input order within a voxel), then one pass summing each run of equal keys in that order (as
/// Open3D): the same centroids, in the same order, as [`centroids_hashed`], without a hash
/// table. Keys must be below `key_bound` (at most `u32::MAX + 1`). Fills `voxel_of` (sized
/// to `points`) with each point's voxel when given.
fn centroids_radix<F>(
    points: &[Point3<f64>],
    key_bound: u64,
    key: F,
    mut voxel_of: Option<&mut Vec<u32>>,
) -> Vec<Point3<f64>>
where
    F: Fn(&Point3<f64>) -> u32,
{
    let mut keyed: Vec<(u32, u32)> = Vec::with_capacity(points.len());
    for (i, p) in points.iter().enumerate() {
        if p.coords.iter().all(|c| c.is_finite()) {
            keyed.push((key(p), i as u32));
        }
    }
    let bits = u64::BITS - key_bound.saturating_sub(1).leading_zeros();
    let mut other = vec![(0u32, 0u32); keyed.len()];
    let mut counts = vec![0usize; 1 << RADIX_BITS];
    let mask = (1u32 << RADIX_BITS) - 1;
    for shift in (0..bits).step_by(RADIX_BITS as usize) {
        counts.fill(0);
        for &(k, _) in &keyed {
            counts[((k >> shift) & mask) as usize] += 1;
        }
        let mut total = 0;
        for c in &mut counts {
            (*c, total) = (total, total + *c);
        }
        for &entry in &keyed {
            let slot = &mut counts[((entry.0 >> shift) & mask) as usize];
            other[*slot] = entry;
            *slot += 1;
        }
        std::mem::swap(&mut keyed, &mut other);
    }
    let mut out = Vec::new();
    let mut run = keyed.as_slice();
    while let Some(&(k, _)) = run.first() {
        let end = run.iter().position(|e| e.0 != k).unwrap_or(run.len());
        let mut sum = Vector3::zeros();
        for &(_, i) in &run[..end] {
            sum += points[i as usize].coords;
        }
        if let Some(v) = voxel_of.as_deref_mut() {
            for &(_, i) in &run[..end] {
                v[i as usize] = out.len() as u32;
            }
        }
        out.push(Point3::from(sum / f64::from(end as u32)));
        run = &run[end..];
    }
    out
}

/// One pass over the finite points accumulating per-voxel sums in input order (as Open3D), then
/// the occupied voxels sorted by key: O(n) hashing plus a sort of the (few) voxels. Fills
/// `voxel_of` (sized to `points`) with each point's voxel when given.
fn centroids_hashed<F>(
    points: &[Point3<f64>],
    key: F,
    mut voxel_of: Option<&mut Vec<u32>>,
) -> Vec<Point3<f64>>
where
    F: Fn(&Point3<f64>) -> u64,
{
    let mut slot_of: HashMap<u64, u32, FastHash> = HashMap::default();
    let mut voxels: Vec<(u64, Vector3<f64>, u32)> = Vec::new();
    for (i, p) in points.iter().enumerate() {
        if !p.coords.iter().all(|c| c.is_finite()) {
            continue;
        }
        let k = key(p);
        let slot = *slot_of.entry(k).or_insert_with(|| {
            voxels.push((k, Vector3::zeros(), 0));
            (voxels.len() - 1) as u32
        });
        let v = &mut voxels[slot as usize];
        v.1 += p.coords;
        v.2 += 1;
        if let Some(of) = voxel_of.as_deref_mut() {
            of[i] = slot;
        }
    }
    // Keys are distinct: the order is total.
    let mut order: Vec<u32> = (0..voxels.len() as u32).collect();
    order.sort_unstable_by_key(|&slot| voxels[slot as usize].0);
    if let Some(of) = voxel_of {
        let mut rank = vec![0u32; voxels.len()];
        for (r, &slot) in order.iter().enumerate() {
            rank[slot as usize] = r as u32;
        }
        for v in of.iter_mut().filter(|v| **v != u32::MAX) {
            *v = rank[*v as usize];
        }
    }
    order
        .into_iter()
        .map(|slot| {
            let (_, sum, n) = voxels[slot as usize];
            Point3::from(sum / f64::from(n))
        })
        .collect()
}

/// Sorts finite points by (voxel key, input index) and averages each run of equal keys. The index
/// makes entries unique, so the unstable sort is deterministic and keeps input order in a voxel.
/// Fills `voxel_of` (sized to `points`) with each point's voxel when given.
fn centroids<K, F>(
    points: &[Point3<f64>],
    key: F,
    mut voxel_of: Option<&mut Vec<u32>>,
) -> Vec<Point3<f64>>
where
    K: Ord + Copy + Send,
    F: Fn(&Point3<f64>) -> K + Sync,
{
    let mut keyed: Vec<(K, u32)> = points
        .par_iter()
        .enumerate()
        .filter(|(_, p)| p.coords.iter().all(|c| c.is_finite()))
        .map(|(i, p)| (key(p), i as u32))
        .collect();
    keyed.par_sort_unstable();

    let mut out = Vec::new();
    let mut start = 0;
    while start < keyed.len() {
        let k = keyed[start].0;
        let mut sum = Vector3::zeros();
        let mut end = start;
        while end < keyed.len() && keyed[end].0 == k {
            sum += points[keyed[end].1 as usize].coords;
            if let Some(v) = voxel_of.as_deref_mut() {
                v[keyed[end].1 as usize] = out.len() as u32;
            }
            end += 1;
        }
        out.push(Point3::from(sum / (end - start) as f64));
        start = end;
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{RngExt, SeedableRng};
    use rand_pcg::Pcg64;

    #[test]
    fn centroids_and_counts_on_a_constructed_grid() {
        // Voxel size 1 m and a point at the origin that is the minimum of the cloud: the grid
        // origin is (-0.5, -0.5, -0.5), so voxel k spans [k - 0.5, k + 0.5) on each axis.
        let voxels: [([f64; 3], &[[f64; 3]]); 4] = [
            (
                [3.0, 0.0, 0.0],
                &[[-0.4, 0.1, 0.0], [0.2, 0.3, 0.0], [0.2, 0.2, 0.3]],
            ),
            ([0.0, 0.0, 0.0], &[[0.0, 0.0, 0.0], [0.4, 0.2, 0.1]]),
            (
                [1.0, 1.0, 5.0],
                &[[0.0, 0.0, 0.0], [0.0, 0.0, 0.49], [-0.49, -0.2, -0.3]],
            ),
            (
                [0.0, 2.0, 0.0],
                &[
                    [0.1, 0.1, 0.1],
                    [0.1, 0.1, 0.1],
                    [0.1, 0.1, 0.1],
                    [0.3, -0.1, 0.1],
                ],
            ),
        ];
        let mut points = Vec::new();
        for (c, offs) in voxels {
            for o in offs {
                points.push(Point3::new(c[0] + o[0], c[1] + o[1], c[2] + o[2]));
            }
        }
        // Expected centroids (centre + mean offset), in voxel-key order.
        let expected = [
            Point3::new(0.2, 0.1, 0.05),
            Point3::new(0.15, 2.05, 0.1),
            Point3::new(1.0 - 0.49 / 3.0, 1.0 - 0.2 / 3.0, 5.0 + 0.19 / 3.0),
            Point3::new(3.0, 0.2, 0.1),
        ];
        let out = voxel_downsample(&points, 1.0).unwrap();
        assert_eq!(out.len(), expected.len());
        for (o, e) in out.iter().zip(&expected) {
            assert!((o - e).norm() < 1e-12, "{o} vs {e}");
        }
    }

    #[test]
    fn point_per_voxel_lattice_is_unchanged_and_sorted() {
        // A 5x4x3 lattice with spacing = voxel size: every point is alone in its voxel.
        let mut points = Vec::new();
        for z in 0..3 {
            for y in 0..4 {
                for x in 0..5 {
                    points.push(Point3::new(
                        x as f64 * 0.05,
                        y as f64 * 0.05,
                        z as f64 * 0.05,
                    ));
                }
            }
        }
        let mut rng = Pcg64::seed_from_u64(7);
        for i in (1..points.len()).rev() {
            points.swap(i, rng.random_range(0..=i));
        }
        let out = voxel_downsample(&points, 0.05).unwrap();
        assert_eq!(out.len(), 60);
        let mut k = 0;
        for x in 0..5 {
            for y in 0..4 {
                for z in 0..3 {
                    let e = Point3::new(x as f64 * 0.05, y as f64 * 0.05, z as f64 * 0.05);
                    assert!((out[k] - e).norm() < 1e-15, "{} vs {e}", out[k]);
                    k += 1;
                }
            }
        }
    }

    #[test]
    fn deterministic_across_thread_counts() {
        let mut rng = Pcg64::seed_from_u64(11);
        let points: Vec<Point3<f64>> = (0..20_000)
            .map(|_| {
                Point3::new(
                    rng.random_range(0.0..3.0),
                    rng.random_range(0.0..3.0),
                    rng.random_range(0.0..1.0),
                )
            })
            .collect();
        let run = |threads| {
            rayon::ThreadPoolBuilder::new()
                .num_threads(threads)
                .build()
                .unwrap()
                .install(|| voxel_downsample(&points, 0.1).unwrap())
        };
        let one = run(1);
        assert_eq!(one, run(2));
        assert_eq!(one, run(5));
        // ~9,000 to 10,571 voxels for ~2.2 points each: most but not all are occupied.
        assert!((7_500..=31 * 31 * 11).contains(&one.len()), "{}", one.len());
    }

    #[test]
    fn radix_hashed_and_sorted_centroids_agree_bit_for_bit() {
        use rand::{RngExt, SeedableRng};
        let mut rng = rand_pcg::Pcg64::seed_from_u64(21);
        // Clustered points (many per voxel, in scrambled order) and a few non-finite ones.
        let mut points: Vec<Point3<f64>> = (0..5000)
            .map(|_| Point3::from(std::array::from_fn(|_| rng.random_range(-3.0..3.0))))
            .collect();
        points[17] = Point3::new(f64::NAN, 0.0, 0.0);
        points[4000] = Point3::new(0.0, f64::INFINITY, 0.0);
        let voxel = 0.25;
        let (nx, ny, nz) = (40u64, 40u64, 40u64);
        let index = |p: &Point3<f64>| -> [u64; 3] {
            std::array::from_fn(|k| ((p[k] + 4.0) / voxel) as u64)
        };
        let packed = |p: &Point3<f64>| {
            let [x, y, z] = index(p);
            (x * ny + y) * nz + z
        };
        let of = || Some(vec![u32::MAX; points.len()]);
        let (mut radix_of, mut hashed_of, mut sorted_of) = (of(), of(), of());
        let radix = centroids_radix(
            &points,
            nx * ny * nz,
            |p| packed(p) as u32,
            radix_of.as_mut(),
        );
        let hashed = centroids_hashed(&points, packed, hashed_of.as_mut());
        let sorted = centroids(&points, index, sorted_of.as_mut());
        assert!(radix.len() > 1000, "{} voxels", radix.len());
        assert_eq!(radix, hashed);
        assert_eq!(radix, sorted);
        assert_eq!(radix_of, hashed_of);
        assert_eq!(radix_of, sorted_of);
        // One voxel only: no radix pass at all.
        let one = centroids_radix(&points[..3], 1, |_| 0, None);
        assert_eq!(one, centroids_hashed(&points[..3], |_| 0, None));
    }

    #[test]
    fn each_point_is_indexed_to_the_centroid_of_its_voxel() {
        use rand::{RngExt, SeedableRng};
        let mut rng = rand_pcg::Pcg64::seed_from_u64(22);
        let mut points: Vec<Point3<f64>> = (0..3000)
            .map(|_| Point3::from(std::array::from_fn(|_| rng.random_range(-1.0..1.0))))
            .collect();
        points[5] = Point3::new(0.0, f64::NAN, 0.0);
        let voxel = 0.2;
        let (centroids, voxel_of) = voxel_downsample_indexed(&points, voxel).unwrap();
        assert_eq!(centroids, voxel_downsample(&points, voxel).unwrap());
        assert_eq!(voxel_of[5], u32::MAX);
        // Oracle: the voxel of each point by direct arithmetic (Open3D's grid, anchored half a
        // voxel below the minimum); points sharing a voxel share an index, whose centroid is
        // their mean.
        let finite: Vec<usize> = (0..points.len()).filter(|&i| i != 5).collect();
        let min = finite
            .iter()
            .fold(Point3::from([f64::INFINITY; 3]), |m, &i| m.inf(&points[i]));
        let cell = |p: &Point3<f64>| -> [i64; 3] {
            std::array::from_fn(|k| ((p[k] - (min[k] - voxel / 2.0)) / voxel).floor() as i64)
        };
        let mut members: std::collections::BTreeMap<[i64; 3], Vec<usize>> = Default::default();
        for &i in &finite {
            members.entry(cell(&points[i])).or_default().push(i);
        }
        assert_eq!(members.len(), centroids.len());
        for group in members.values() {
            let j = voxel_of[group[0]];
            assert!(group.iter().all(|&i| voxel_of[i] == j));
            let mean = group
                .iter()
                .fold(Vector3::zeros(), |s, &i| s + points[i].coords)
                / group.len() as f64;
            assert!((centroids[j as usize].coords - mean).norm() < 1e-12);
        }
    }

    #[test]
    fn huge_grids_use_the_unpacked_key_and_agree() {
        // 1e9 voxels per axis: the packed u64 key would overflow, the [u32; 3] key is used.
        let points = [
            Point3::new(1e6, 1e6, 1e6),
            Point3::new(0.0, 0.0, 0.0),
            Point3::new(2e-4, 0.0, 0.0),
            Point3::new(1e6, 0.0, 2e-4),
            Point3::new(1e6, 0.0, 0.0),
        ];
        let out = voxel_downsample(&points, 1e-3).unwrap();
        let expected = [
            Point3::new(1e-4, 0.0, 0.0),
            Point3::new(1e6, 0.0, 1e-4),
            Point3::new(1e6, 1e6, 1e6),
        ];
        assert_eq!(out.len(), 3);
        for (o, e) in out.iter().zip(&expected) {
            assert!((o - e).norm() < 1e-9, "{o} vs {e}");
        }
    }

    #[test]
    fn invalid_sizes_and_non_finite_points() {
        let pts = [
            Point3::new(0.0, 0.0, 0.0),
            Point3::new(f64::NAN, 0.0, 0.0),
            Point3::new(0.1, 0.0, 0.0),
        ];
        for bad in [0.0, -1.0, f64::NAN, f64::INFINITY] {
            assert!(matches!(
                voxel_downsample(&pts, bad),
                Err(Error::InvalidInput(_))
            ));
        }
        assert!(matches!(
            voxel_downsample(&[Point3::origin(), Point3::new(1e9, 0.0, 0.0)], 1e-9),
            Err(Error::InvalidInput(_))
        ));
        assert_eq!(
            voxel_downsample(&pts, 1.0).unwrap(),
            vec![Point3::new(0.05, 0.0, 0.0)]
        );
        assert!(voxel_downsample(&[], 1.0).unwrap().is_empty());
    }
}
