//! Surface normals by PCA over a hybrid (radius + max count) neighbourhood, as Open3D's
//! `PointCloud::estimate_normals(KDTreeSearchParamHybrid(radius, max_nn))`.

use nalgebra::{Matrix3, Point3, Vector3};
use rayon::prelude::*;

use super::RadiusGrid;
use super::kdtree::{KdTree, Neighbourhoods};
use crate::{Error, Result};

/// Normal given to a point whose neighbourhood cannot define a plane (fewer than
/// [`MIN_NEIGHBOURS`] neighbours, or all neighbours coincident): +z, as Open3D.
pub const FALLBACK_NORMAL: Vector3<f64> = Vector3::new(0.0, 0.0, 1.0);

/// Fewest neighbours (the query point included) for which a covariance is computed (Open3D: 3).
pub const MIN_NEIGHBOURS: usize = 3;

/// Normal that [`NormalEstimate`] gives a point whose neighbourhood cannot define a plane (as
/// [`FALLBACK_NORMAL`]): zero, which ICP reads as "no plane here" and matches point to point
/// ([`crate::refine::icp`]).
///
/// NOTE: Open3D gives such a point +z. Among an ICP target's points those are the isolated ones:
/// far points and, on a LiDAR of few beams, points between its rings. A +z normal constrains them
/// along z alone, with the lever arm of their range: on KAIST03's scans cut to 16 of their 64
/// beams (a VLP-16's spacing) the map registrations' rotation information came out 30–125 times
/// weaker in its weakest direction than in its strongest (0.31–0.66 with point-to-point rows), no
/// frame tracked and loop verification refused the loops as degenerate (docs/ODOMETRY.md, "Points
/// with no plane"). Features keep Open3D's +z (their histograms are Open3D's).
pub const NO_PLANE: Vector3<f64> = Vector3::new(0.0, 0.0, 0.0);

/// Estimates one unit normal per point.
///
/// For each point, the neighbourhood is every point strictly within `radius_m` (metres), at most the
/// `max_nn` nearest (the point itself included), exactly Open3D's `KDTreeSearchParamHybrid`; the
/// normal is the eigenvector of the smallest eigenvalue of the neighbourhood covariance. Open3D's
/// defaults in registration pipelines: `radius_m = 2 * voxel`, `max_nn = 30`.
///
/// Orientation:
/// - `towards_sensor = Some(o)`: each normal is flipped to point towards `o` (`n · (o − p) ≥ 0`),
///   as Open3D's `orient_normals_towards_camera_location(o)`.
/// - `None`: Open3D's default for a cloud without normals, which is *no* orientation: the sign is
///   whatever its closed-form eigen solver yields. [`smallest_eigenvector`] follows the same
///   algorithm and sign conventions, so signs agree with Open3D except at numerical near-ties.
///
/// Points with fewer than [`MIN_NEIGHBOURS`] neighbours, or whose neighbours all coincide, get
/// [`FALLBACK_NORMAL`] (then oriented if requested), as in Open3D.
///
/// Runs in parallel (rayon); the result does not depend on the thread count.
///
/// Errors: [`Error::InvalidInput`] for a non-finite point, `radius_m` not finite and positive, or
/// `max_nn == 0`.
pub fn estimate_normals(
    points: &[Point3<f64>],
    radius_m: f64,
    max_nn: usize,
    towards_sensor: Option<Point3<f64>>,
) -> Result<Vec<Vector3<f64>>> {
    let tree = KdTree::new(points)?;
    estimate_normals_with_tree(points, &tree, radius_m, max_nn, towards_sensor)
}

/// [`estimate_normals`] with a prebuilt tree over exactly `points` (reuse it for features).
pub fn estimate_normals_with_tree(
    points: &[Point3<f64>],
    tree: &KdTree,
    radius_m: f64,
    max_nn: usize,
    towards_sensor: Option<Point3<f64>>,
) -> Result<Vec<Vector3<f64>>> {
    check_search_params(radius_m, max_nn)?;
    if tree.len() != points.len() {
        return Err(Error::InvalidInput(format!(
            "kd-tree holds {} points but {} were given",
            tree.len(),
            points.len()
        )));
    }
    Ok(tree_normals(
        tree,
        points,
        None,
        radius_m,
        max_nn,
        towards_sensor,
        FALLBACK_NORMAL,
    ))
}

/// The normals of `points` (all, or those at the indices `at`, in that order) from `tree`'s
/// neighbourhoods ([`estimate_normals_with_tree`]); each depends on its own point only.
fn tree_normals(
    tree: &KdTree,
    points: &[Point3<f64>],
    at: Option<&[u32]>,
    radius_m: f64,
    max_nn: usize,
    towards_sensor: Option<Point3<f64>>,
    fallback: Vector3<f64>,
) -> Vec<Vector3<f64>> {
    let normal = |p: &Point3<f64>| {
        let nn = tree.within_radius(p, radius_m, max_nn);
        oriented_normal(
            points,
            p,
            nn.iter().map(|n| n.index),
            towards_sensor,
            fallback,
        )
    };
    match at {
        None => points.par_iter().map(normal).collect(),
        Some(at) => at
            .par_iter()
            .map(|&i| normal(&points[i as usize]))
            .collect(),
    }
}

/// [`estimate_normals_with_tree`] through a [`RadiusGrid`] of cell edge `radius_m` over `points`
/// instead of a kd-tree: the same neighbourhoods (every point strictly within the radius, the
/// `max_nn` nearest by (distance, index)), summed in the same (distance, index) order, so the
/// normals are the tree's bit for bit, but where equal distances straddle the `max_nn` cut: the
/// grid keeps the lowest indices there, the tree its own choice. `Ok(None)` where the grid
/// declines the cloud (an extent of more than `max_columns` columns of the radius): use the tree
/// then.
///
/// NOTE: on the LiDAR ICP clouds of `mireg register` (KAIST03: 16k points, 0.74 m radius) the
/// tree's bounded-heap search was a quarter of all instructions of a run; a cell scan of the
/// 3 × 3 × 3 block, then a sort of the few dozen hits, needs a fraction of that
/// (docs/BENCHMARKS_ARCHIVE.md).
///
/// Errors: as [`estimate_normals`].
pub fn estimate_normals_with_grid(
    points: &[Point3<f64>],
    radius_m: f64,
    max_nn: usize,
    towards_sensor: Option<Point3<f64>>,
    max_columns: usize,
) -> Result<Option<Vec<Vector3<f64>>>> {
    check_search_params(radius_m, max_nn)?;
    let Some(grid) = RadiusGrid::new(points, radius_m, max_columns)? else {
        return Ok(if points.is_empty() {
            Some(Vec::new())
        } else {
            None
        });
    };
    Ok(Some(grid_normals(
        &grid,
        points,
        None,
        max_nn,
        towards_sensor,
        FALLBACK_NORMAL,
    )))
}

/// The normals of `points` (all, or those at the indices `at`, in that order) from `grid`'s
/// neighbourhoods ([`estimate_normals_with_grid`]); each depends on its own point only.
fn grid_normals(
    grid: &RadiusGrid,
    points: &[Point3<f64>],
    at: Option<&[u32]>,
    max_nn: usize,
    towards_sensor: Option<Point3<f64>>,
    fallback: Vector3<f64>,
) -> Vec<Vector3<f64>> {
    let normal = |members: &mut Vec<u128>, p: &Point3<f64>| {
        members.clear();
        grid.within(p, members);
        // The grid's hits come unordered.
        if !keep_nearest(members, max_nn) {
            members.sort_unstable();
        }
        let indices = members.iter().map(|&key| key as u32 as usize);
        oriented_normal(points, p, indices, towards_sensor, fallback)
    };
    match at {
        None => points.par_iter().map_init(Vec::new, normal).collect(),
        Some(at) => at
            .par_iter()
            .map_init(Vec::new, |members, &i| normal(members, &points[i as usize]))
            .collect(),
    }
}

/// The settings of a normal estimation kept for later (an ICP target's: a point that cannot have
/// a plane gets [`NO_PLANE`], not Open3D's +z), so that a cloud's normals can be
/// estimated where and when they are needed: `mireg register` adds only the points of a frame
/// that land in a local-map voxel not yet full, 6 % of the ICP points on the KITTI replay log.
/// Through a [`RadiusGrid`] as [`estimate_normals_with_grid`], or a kd-tree where the grid
/// declines the cloud, as `prepare_frame` does.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct NormalEstimate {
    /// Neighbourhood radius \[m\].
    pub radius_m: f64,
    /// Most neighbours used (the nearest).
    pub max_nn: usize,
    /// Orient the normals towards this point (the sensor); `None`: as they come.
    pub towards_sensor: Option<Point3<f64>>,
    /// Most grid columns before the kd-tree is used instead.
    pub max_columns: usize,
}

impl NormalEstimate {
    /// Checks the settings (as [`estimate_normals`]).
    pub fn new(
        radius_m: f64,
        max_nn: usize,
        towards_sensor: Option<Point3<f64>>,
        max_columns: usize,
    ) -> Result<Self> {
        check_search_params(radius_m, max_nn)?;
        Ok(Self {
            radius_m,
            max_nn,
            towards_sensor,
            max_columns,
        })
    }

    /// The normals of `points` (finite), all of them or those at the indices `at` (in that
    /// order), each from its neighbourhood in the whole cloud: bit for bit what estimating all of
    /// them and picking those would give.
    ///
    /// Errors: an index in `at` outside `points`; otherwise as [`estimate_normals`].
    pub fn estimate(
        &self,
        points: &[Point3<f64>],
        at: Option<&[u32]>,
    ) -> Result<Vec<Vector3<f64>>> {
        check_search_params(self.radius_m, self.max_nn)?;
        if let Some(i) = at.and_then(|at| at.iter().find(|&&i| i as usize >= points.len())) {
            return Err(Error::InvalidInput(format!(
                "normal asked for point {i} of {}",
                points.len()
            )));
        }
        if points.is_empty() {
            return Ok(Vec::new());
        }
        let (radius, max_nn, towards) = (self.radius_m, self.max_nn, self.towards_sensor);
        if let Some(grid) = RadiusGrid::new(points, radius, self.max_columns)? {
            return Ok(grid_normals(&grid, points, at, max_nn, towards, NO_PLANE));
        }
        let tree = KdTree::new(points)?;
        Ok(tree_normals(
            &tree, points, at, radius, max_nn, towards, NO_PLANE,
        ))
    }
}

/// [`estimate_normals_with_tree`] from precomputed neighbourhoods `nbhd` of every point (e.g. the
/// FPFH ones) searched with a radius ≥ `radius_m` and a cap ≥ `max_nn`: each normal's
/// neighbourhood is the larger one's members strictly within `radius_m`, the `max_nn` nearest
/// (ties by index) when there are more — the set the direct search returns. Saves one search.
///
/// The covariance sums the members in `nbhd`'s order (the `max_nn` nearest sorted, when there are
/// more), so the normals equal [`estimate_normals_with_tree`]'s bit for bit when `nbhd` is
/// sorted (a kd-tree's), and to rounding when it is not (the grid's).
pub fn estimate_normals_from_neighbourhoods(
    points: &[Point3<f64>],
    nbhd: &Neighbourhoods,
    radius_m: f64,
    max_nn: usize,
    towards_sensor: Option<Point3<f64>>,
) -> Result<Vec<Vector3<f64>>> {
    check_search_params(radius_m, max_nn)?;
    if nbhd.len() != points.len() {
        return Err(Error::InvalidInput(format!(
            "{} neighbourhoods for {} points",
            nbhd.len(),
            points.len()
        )));
    }
    let radius_sq = radius_m * radius_m;
    Ok(points
        .par_iter()
        .enumerate()
        .map_init(Vec::<u128>::new, |members, (i, p)| {
            let (idx, d2) = nbhd.get(i);
            // (distance² bits, index): one integer ordered by distance, then index.
            members.clear();
            members.extend(
                idx.iter()
                    .zip(d2)
                    .filter(|&(_, &d)| d < radius_sq)
                    .map(|(&j, &d)| u128::from(d.to_bits()) << 32 | u128::from(j)),
            );
            keep_nearest(members, max_nn);
            let indices = members.iter().map(|&key| key as u32 as usize);
            oriented_normal(points, p, indices, towards_sensor, FALLBACK_NORMAL)
        })
        .collect())
}

/// Keeps the `max_nn` least of `members`, keys `(squared distance bits) << 32 | index` (the
/// nearest, ties by index), sorted, when there are more; `true` when it dropped some.
fn keep_nearest(members: &mut Vec<u128>, max_nn: usize) -> bool {
    if members.len() <= max_nn {
        return false;
    }
    members.select_nth_unstable(max_nn);
    members.truncate(max_nn);
    members.sort_unstable();
    true
}

/// The normal of `p` from its neighbourhood `members` (indices into `points`, summed in this
/// order): `fallback` ([`FALLBACK_NORMAL`], or [`NO_PLANE`] for ICP targets) below
/// [`MIN_NEIGHBOURS`] members or for coincident ones, flipped towards `towards_sensor` when given.
fn oriented_normal(
    points: &[Point3<f64>],
    p: &Point3<f64>,
    members: impl ExactSizeIterator<Item = usize> + Clone,
    towards_sensor: Option<Point3<f64>>,
    fallback: Vector3<f64>,
) -> Vector3<f64> {
    let normal = if members.len() < MIN_NEIGHBOURS {
        fallback
    } else {
        smallest_eigenvector(&covariance(points, members)).unwrap_or(fallback)
    };
    match towards_sensor {
        Some(o) if normal.dot(&(o - p)) < 0.0 => -normal,
        _ => normal,
    }
}

/// Validates a hybrid search's radius (m) and neighbour cap.
pub(crate) fn check_search_params(radius_m: f64, max_nn: usize) -> Result<()> {
    if !(radius_m.is_finite() && radius_m > 0.0) {
        return Err(Error::InvalidInput(format!(
            "radius_m must be finite and > 0, got {radius_m}"
        )));
    }
    if max_nn == 0 {
        return Err(Error::InvalidInput("max_nn must be > 0".into()));
    }
    Ok(())
}

/// Population covariance (divided by n) of the indexed points.
///
/// NOTE: Open3D accumulates raw moments (E[xxᵀ] − E[x]E[x]ᵀ), which cancels catastrophically far
/// from the origin (map-frame robotics clouds); we centre on the mean first. The matrices agree to
/// rounding near the origin.
fn covariance(
    points: &[Point3<f64>],
    indices: impl Iterator<Item = usize> + Clone,
) -> Matrix3<f64> {
    let mut mean = Vector3::zeros();
    let mut n = 0usize;
    for i in indices.clone() {
        mean += points[i].coords;
        n += 1;
    }
    mean /= n as f64;
    let mut cov = Matrix3::zeros();
    for i in indices {
        let d = points[i].coords - mean;
        cov += d * d.transpose();
    }
    cov / n as f64
}

/// Unit eigenvector of the smallest eigenvalue of a symmetric 3×3 matrix, `None` for the zero
/// matrix.
///
/// Closed form after D. Eberly, "A Robust Eigensolver for 3×3 Symmetric Matrices" (Geometric
/// Tools, 2014), the algorithm Open3D's `FastEigen3x3` implements: eigenvalues from the
/// trigonometric solution of the characteristic cubic of the scaled, shifted matrix; the
/// well-separated extreme eigenvector from the largest cross product of two rows of `A − λI`; the
/// middle one from a 2×2 null space in the plane orthogonal to it; the third as a cross product.
/// Accurate to ~1e-15 also for repeated eigenvalues (planes, lines). The sign conventions follow
/// the paper (and Open3D), which fixes the sign of unoriented normals.
pub fn smallest_eigenvector(a: &Matrix3<f64>) -> Option<Vector3<f64>> {
    let scale = a.amax();
    if scale == 0.0 || !scale.is_finite() {
        return None;
    }
    let a = a / scale;
    let off = a[(0, 1)].powi(2) + a[(0, 2)].powi(2) + a[(1, 2)].powi(2);
    if off == 0.0 {
        // Diagonal: the axis of the strictly smallest diagonal entry, z on ties (Open3D's order).
        let d = a.diagonal();
        return Some(if d.x < d.y && d.x < d.z {
            Vector3::x()
        } else if d.y < d.x && d.y < d.z {
            Vector3::y()
        } else {
            Vector3::z()
        });
    }
    let q = a.trace() / 3.0;
    let b = a - Matrix3::identity() * q;
    let p = ((b[(0, 0)].powi(2) + b[(1, 1)].powi(2) + b[(2, 2)].powi(2) + 2.0 * off) / 6.0).sqrt();
    let half_det = (0.5 * b.determinant() / (p * p * p)).clamp(-1.0, 1.0);
    let angle = half_det.acos() / 3.0;
    const TWO_THIRDS_PI: f64 = 2.0 * std::f64::consts::FRAC_PI_3;
    let beta_hi = 2.0 * angle.cos();
    let beta_lo = 2.0 * (angle + TWO_THIRDS_PI).cos();
    let beta_mid = -(beta_lo + beta_hi);
    let (lo, mid, hi) = (q + p * beta_lo, q + p * beta_mid, q + p * beta_hi);

    // The eigenvalue farther from the middle one is well separated: solve for it directly.
    if half_det >= 0.0 {
        let v_hi = isolated_eigenvector(&a, hi);
        if hi < lo && hi < mid {
            return Some(v_hi);
        }
        let v_mid = second_eigenvector(&a, &v_hi, mid);
        if mid < lo && mid < hi {
            return Some(v_mid);
        }
        Some(v_mid.cross(&v_hi))
    } else {
        let v_lo = isolated_eigenvector(&a, lo);
        if lo < mid && lo < hi {
            return Some(v_lo);
        }
        let v_mid = second_eigenvector(&a, &v_lo, mid);
        if mid < lo && mid < hi {
            return Some(v_mid);
        }
        Some(v_lo.cross(&v_mid))
    }
}

/// Eigenvector of a simple eigenvalue `lambda`: the longest cross product of two rows of
/// `A − λI` (the first of equal ones).
fn isolated_eigenvector(a: &Matrix3<f64>, lambda: f64) -> Vector3<f64> {
    let m = a - Matrix3::identity() * lambda;
    let (r0, r1, r2) = (
        m.row(0).transpose(),
        m.row(1).transpose(),
        m.row(2).transpose(),
    );
    let candidates = [r0.cross(&r1), r0.cross(&r2), r1.cross(&r2)];
    let mut best = candidates[0];
    let mut best_sq = best.norm_squared();
    for c in &candidates[1..] {
        let sq = c.norm_squared();
        if sq > best_sq {
            best = *c;
            best_sq = sq;
        }
    }
    best / best_sq.sqrt()
}

/// Eigenvector of `lambda` orthogonal to the known unit eigenvector `w`: the null vector of the
/// 2×2 restriction of `A − λI` to an orthonormal basis (u, v) of w's orthogonal plane.
fn second_eigenvector(a: &Matrix3<f64>, w: &Vector3<f64>, lambda: f64) -> Vector3<f64> {
    let u = if w.x.abs() > w.y.abs() {
        Vector3::new(-w.z, 0.0, w.x) / (w.x * w.x + w.z * w.z).sqrt()
    } else {
        Vector3::new(0.0, w.z, -w.y) / (w.y * w.y + w.z * w.z).sqrt()
    };
    let v = w.cross(&u);
    let (au, av) = (a * u, a * v);
    let m00 = u.dot(&au) - lambda;
    let m01 = u.dot(&av);
    let m11 = v.dot(&av) - lambda;
    // Take the row with the larger diagonal; its null direction is (row[1], −row[0]), signed by
    // the row's dominant entry (ties to the diagonal), as in Eberly's normalisation.
    let (row, diag_first) = if m00.abs() >= m11.abs() {
        ((m00, m01), true)
    } else {
        ((m01, m11), false)
    };
    let len = row.0.hypot(row.1);
    if len == 0.0 {
        return u;
    }
    let (diag, other) = if diag_first {
        (row.0, row.1)
    } else {
        (row.1, row.0)
    };
    let sign = if diag.abs() >= other.abs() {
        diag.signum()
    } else {
        other.signum()
    };
    (u * row.1 - v * row.0) * (sign / len)
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::{Rotation3, Unit};
    use rand::{RngExt, SeedableRng};
    use rand_pcg::Pcg64;

    #[test]
    fn eigenvector_matches_a_constructed_spectrum() {
        let mut rng = Pcg64::seed_from_u64(21);
        for _ in 0..500 {
            let axis = Unit::new_normalize(Vector3::new(
                rng.random_range(-1.0..1.0),
                rng.random_range(-1.0..1.0),
                rng.random_range(-1.0..1.0),
            ));
            let r = Rotation3::from_axis_angle(&axis, rng.random_range(0.0..6.0));
            // Distinct, repeated-large (plane) and all-but-one-zero (line) spectra.
            let smallest: f64 = rng.random_range(0.0..1e-3);
            let spectra = [[smallest, 0.3, 1.0], [smallest, 1.0, 1.0], [0.0, 0.0, 1.0]];
            for (k, s) in spectra.iter().enumerate() {
                let m = r.matrix()
                    * Matrix3::from_diagonal(&Vector3::from(*s))
                    * r.matrix().transpose();
                let v = smallest_eigenvector(&m).unwrap();
                assert!((v.norm() - 1.0).abs() < 1e-12);
                if k < 2 {
                    let expected = r.matrix().column(0);
                    assert!(
                        v.dot(&expected).abs() > 1.0 - 1e-10,
                        "spectrum {s:?}: {v} vs {expected}"
                    );
                } else {
                    // Double zero eigenvalue: any unit vector orthogonal to the third column.
                    assert!(v.dot(&r.matrix().column(2)).abs() < 1e-10);
                }
            }
        }
        assert_eq!(smallest_eigenvector(&Matrix3::zeros()), None);
        assert_eq!(
            smallest_eigenvector(&Matrix3::from_diagonal(&Vector3::new(2.0, 1.0, 3.0))),
            Some(Vector3::y())
        );
    }

    #[test]
    fn deferred_estimation_of_some_points_equals_all_of_them_picked() {
        // Noisy samples of a sphere and a plane: neighbourhoods of varied size.
        let mut rng = Pcg64::seed_from_u64(77);
        let mut points: Vec<Point3<f64>> = (0..1500)
            .map(|_| {
                let d = Vector3::new(
                    rng.random_range(-1.0..1.0),
                    rng.random_range(-1.0..1.0),
                    rng.random_range(-1.0..1.0),
                );
                Point3::from(d.normalize() * 0.8)
            })
            .collect();
        points.extend((0..1500).map(|_| {
            Point3::new(
                rng.random_range(-2.0..2.0),
                rng.random_range(-2.0..2.0),
                -1.0 + rng.random_range(-0.01..0.01),
            )
        }));
        let sensor = Some(Point3::new(0.1, 0.2, 3.0));
        let at: Vec<u32> = (0..points.len() as u32)
            .filter(|i| i % 7 == 3)
            .rev()
            .collect();
        let pick = |all: &[Vector3<f64>]| -> Vec<Vector3<f64>> {
            at.iter().map(|&i| all[i as usize]).collect()
        };
        // Through the grid: the same as estimate_normals_with_grid, for all or some points.
        let grid = NormalEstimate::new(0.25, 20, sensor, usize::MAX).unwrap();
        let by_grid = estimate_normals_with_grid(&points, 0.25, 20, sensor, usize::MAX)
            .unwrap()
            .unwrap();
        assert_eq!(grid.estimate(&points, None).unwrap(), by_grid);
        assert_eq!(grid.estimate(&points, Some(&at)).unwrap(), pick(&by_grid));
        // A grid of one column declines the cloud: the kd-tree then, as estimate_normals_with_tree.
        let tree = NormalEstimate::new(0.25, 20, sensor, 1).unwrap();
        let by_tree =
            estimate_normals_with_tree(&points, &KdTree::new(&points).unwrap(), 0.25, 20, sensor)
                .unwrap();
        assert_eq!(tree.estimate(&points, None).unwrap(), by_tree);
        assert_eq!(tree.estimate(&points, Some(&at)).unwrap(), pick(&by_tree));
        // Nothing asked, nothing computed; an index outside the cloud and bad settings fail.
        assert!(grid.estimate(&points, Some(&[])).unwrap().is_empty());
        assert!(
            grid.estimate(&points, Some(&[points.len() as u32]))
                .is_err()
        );
        assert!(NormalEstimate::new(0.0, 20, None, 10).is_err());
        assert!(NormalEstimate::new(0.25, 0, None, 10).is_err());
    }

    #[test]
    fn plane_gives_its_exact_normal() {
        // Random points on the plane through c with unit normal n, jittered only in-plane.
        let mut rng = Pcg64::seed_from_u64(31);
        let n = Vector3::new(1.0, -2.0, 0.5).normalize();
        let u = n.cross(&Vector3::z()).normalize();
        let v = n.cross(&u);
        let c = Point3::new(0.3, -0.1, 2.0);
        let points: Vec<Point3<f64>> = (0..2000)
            .map(|_| c + u * rng.random_range(-1.0..1.0) + v * rng.random_range(-1.0..1.0))
            .collect();
        let sensor = c + n * 3.0;
        let normals = estimate_normals(&points, 0.1, 30, Some(sensor)).unwrap();
        for m in &normals {
            assert!((m - n).norm() < 1e-9, "{m} vs {n}");
        }
        let away = estimate_normals(&points, 0.1, 30, Some(c - n * 3.0)).unwrap();
        assert!(away.iter().all(|m| (m + n).norm() < 1e-9));
    }

    #[test]
    fn sphere_normals_are_radial_and_oriented() {
        let mut rng = Pcg64::seed_from_u64(41);
        let centre = Point3::new(1.0, 2.0, -0.5);
        let radius = 0.8;
        let points: Vec<Point3<f64>> = (0..4000)
            .map(|_| {
                let d = Vector3::new(
                    rng.random_range(-1.0..1.0),
                    rng.random_range(-1.0..1.0),
                    rng.random_range(-1.0..1.0),
                );
                centre + d.normalize() * radius
            })
            .filter(|p| p.coords.iter().all(|c: &f64| c.is_finite()))
            .collect();
        // Sensor at the centre: normals point inward.
        let inward = estimate_normals(&points, 0.15, 30, Some(centre)).unwrap();
        for (p, m) in points.iter().zip(&inward) {
            let radial = (p - centre).normalize();
            assert!(m.dot(&radial) < -0.995, "{m} vs {radial}");
        }
        // Unoriented: parallel to the radial direction, either sign.
        let free = estimate_normals(&points, 0.15, 30, None).unwrap();
        for (p, m) in points.iter().zip(&free) {
            assert!(m.dot(&(p - centre).normalize()).abs() > 0.995);
        }
    }

    #[test]
    fn isolated_points_get_the_fallback_and_output_is_thread_independent() {
        let points = [
            Point3::new(0.0, 0.0, 0.0),
            Point3::new(0.01, 0.0, 0.0),
            Point3::new(5.0, 0.0, 0.0),
        ];
        let n = estimate_normals(&points, 0.1, 30, None).unwrap();
        assert_eq!(n, vec![FALLBACK_NORMAL; 3]);
        let n = estimate_normals(&points, 0.1, 30, Some(Point3::new(0.0, 0.0, -1.0))).unwrap();
        assert_eq!(n[2], -FALLBACK_NORMAL);
        assert!(matches!(
            estimate_normals(&points, 0.0, 30, None),
            Err(Error::InvalidInput(_))
        ));
        assert!(matches!(
            estimate_normals(&points, 0.1, 0, None),
            Err(Error::InvalidInput(_))
        ));

        let mut rng = Pcg64::seed_from_u64(51);
        let cloud: Vec<Point3<f64>> = (0..5000)
            .map(|_| {
                Point3::new(
                    rng.random_range(0.0..1.0),
                    rng.random_range(0.0..1.0),
                    rng.random_range(0.0..0.05),
                )
            })
            .collect();
        let run = |t| {
            rayon::ThreadPoolBuilder::new()
                .num_threads(t)
                .build()
                .unwrap()
                .install(|| estimate_normals(&cloud, 0.05, 30, None).unwrap())
        };
        assert_eq!(run(1), run(3));
    }

    #[test]
    fn an_icp_target_estimate_gives_isolated_points_no_plane_and_others_the_same_normal() {
        // A floor patch 2 cm apart and two points far from it: `NormalEstimate` (ICP targets)
        // gives those two zero, Open3D's estimate +z; the floor's normals are the same.
        let mut points: Vec<Point3<f64>> = (0..20)
            .flat_map(|i| (0..20).map(move |j| Point3::new(0.02 * i as f64, 0.02 * j as f64, 0.0)))
            .collect();
        points.extend([Point3::new(3.0, 0.0, 1.0), Point3::new(3.05, 0.0, 1.0)]);
        let sensor = Some(Point3::new(0.1, 0.1, 1.0));
        let open3d = estimate_normals(&points, 0.1, 30, sensor).unwrap();
        let estimate = NormalEstimate::new(0.1, 30, sensor, 1 << 20).unwrap();
        let icp = estimate.estimate(&points, None).unwrap();
        let floor = points.len() - 2;
        // (Ties at equal distances in the regular grid may take other members: equal to
        // rounding, not bit for bit.)
        let close = |a: &[Vector3<f64>], b: &[Vector3<f64>]| {
            a.len() == b.len() && a.iter().zip(b).all(|(x, y)| (x - y).norm() < 1e-12)
        };
        assert!(close(&icp[..floor], &open3d[..floor]));
        assert!(
            open3d[..floor]
                .iter()
                .all(|n| (n - Vector3::z()).norm() < 1e-12)
        );
        assert_eq!(&open3d[floor..], &[FALLBACK_NORMAL; 2]);
        assert_eq!(&icp[floor..], &[NO_PLANE; 2]);
        // The same through the kd-tree (a cloud too wide for the grid's columns) and for a few.
        let narrow = NormalEstimate::new(0.1, 30, sensor, 1).unwrap();
        let by_tree = narrow.estimate(&points, None).unwrap();
        assert!(close(&by_tree[..floor], &icp[..floor]));
        assert_eq!(&by_tree[floor..], &[NO_PLANE; 2]);
        let at = [0u32, floor as u32 + 1];
        assert_eq!(
            estimate.estimate(&points, Some(&at)).unwrap(),
            vec![icp[0], NO_PLANE]
        );
    }

    /// A noisy surface patch plus scattered points (every tenth): full, partial and tiny
    /// neighbourhoods.
    fn noisy_patch(seed: u64) -> Vec<Point3<f64>> {
        let mut rng = Pcg64::seed_from_u64(seed);
        (0..3000)
            .map(|k| {
                let (x, y): (f64, f64) = (rng.random_range(-1.0..1.0), rng.random_range(-1.0..1.0));
                let z = if k % 10 == 0 {
                    rng.random_range(-1.0..1.0)
                } else {
                    0.2 * (3.0 * x).sin() * y + rng.random_range(-0.005..0.005)
                };
                Point3::new(x, y, z)
            })
            .collect()
    }

    #[test]
    fn normals_from_shared_neighbourhoods_equal_direct_search() {
        let points = noisy_patch(41);
        let tree = KdTree::new(&points).unwrap();
        let origin = Some(Point3::new(0.0, 0.0, 5.0));
        for (radius, max_nn) in [(0.08, 30), (0.05, 30), (0.1, 8)] {
            let direct =
                estimate_normals_with_tree(&points, &tree, radius, max_nn, origin).unwrap();
            let nbhd = tree.hybrid_neighbourhoods(&points, 2.5 * radius, 100);
            let shared =
                estimate_normals_from_neighbourhoods(&points, &nbhd, radius, max_nn, origin)
                    .unwrap();
            assert_eq!(direct, shared, "radius {radius}, max_nn {max_nn}");
        }
    }

    /// The grid's normals are the kd-tree's bit for bit (same neighbours, summed in the same
    /// order), also far from the origin and with neighbourhoods above and below the cap; a cloud
    /// the grid declines gives `None`.
    #[test]
    fn grid_normals_equal_tree_normals() {
        let patch = noisy_patch(43);
        let far: Vec<Point3<f64>> = patch
            .iter()
            .map(|p| p + Vector3::new(3000.0, -1200.0, 40.0))
            .collect();
        for points in [&patch, &far] {
            let tree = KdTree::new(points).unwrap();
            let origin = Some(points[0] + Vector3::new(0.0, 0.0, 5.0));
            for (radius, max_nn, towards) in
                [(0.08, 30, origin), (0.05, 30, None), (0.1, 8, origin)]
            {
                let direct =
                    estimate_normals_with_tree(points, &tree, radius, max_nn, towards).unwrap();
                let grid = estimate_normals_with_grid(points, radius, max_nn, towards, 1 << 20)
                    .unwrap()
                    .expect("the grid takes this cloud");
                assert_eq!(direct, grid, "radius {radius}, max_nn {max_nn}");
            }
        }
        assert!(
            estimate_normals_with_grid(&patch, 0.05, 30, None, 10)
                .unwrap()
                .is_none()
        );
        assert_eq!(
            estimate_normals_with_grid(&[], 0.05, 30, None, 10).unwrap(),
            Some(Vec::new())
        );
        assert!(estimate_normals_with_grid(&patch, 0.0, 30, None, 1 << 20).is_err());
    }
}
