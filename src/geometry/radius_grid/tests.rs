//! Tests of [`super::RadiusGrid`] against brute force and the kd-tree.

use super::*;
use rand::{RngExt, SeedableRng};
use rand_pcg::Pcg64;

/// Brute force: the smallest squared distance, if strictly below radius².
fn oracle(points: &[Point3<f64>], q: &Point3<f64>, radius: f64) -> Option<f64> {
    points
        .iter()
        .map(|p| {
            let (dx, dy, dz) = (q.x - p.x, q.y - p.y, q.z - p.z);
            dx * dx + dy * dy + dz * dz
        })
        .min_by(f64::total_cmp)
        .filter(|&d| d < radius * radius)
}

/// `within` against brute force: the same (distance, index) keys, on a noisy shell and on a
/// lattice whose spacing equals the radius (many points exactly on it, excluded).
#[test]
fn within_equals_brute_force() {
    let mut rng = Pcg64::seed_from_u64(8);
    let shell: Vec<Point3<f64>> = (0..1500)
        .map(|_| {
            let u: [f64; 3] = rand_distr::Distribution::sample(&rand_distr::UnitSphere, &mut rng);
            Point3::new(100.0, -20.0, 5.0) + nalgebra::Vector3::from(u) * 0.8
        })
        .collect();
    let lattice: Vec<Point3<f64>> = (0..400)
        .map(|k| {
            Point3::new(
                (k % 8) as f64 * 0.25,
                (k / 8 % 10) as f64 * 0.25,
                (k / 80) as f64 * 0.25,
            )
        })
        .collect();
    for (points, radius) in [(&shell, 0.15), (&shell, 0.4), (&lattice, 0.25)] {
        let grid = RadiusGrid::new(points, radius, 1 << 20).unwrap().unwrap();
        let mut got = Vec::new();
        for q in points.iter().chain([&Point3::new(1e9, 0.0, 0.0)]) {
            got.clear();
            grid.within(q, &mut got);
            got.sort_unstable();
            let mut want: Vec<u128> = points
                .iter()
                .enumerate()
                .filter_map(|(j, p)| {
                    let (dx, dy, dz) = (q.x - p.x, q.y - p.y, q.z - p.z);
                    let d = dx * dx + dy * dy + dz * dz;
                    (d < radius * radius).then(|| u128::from(d.to_bits()) << 32 | j as u128)
                })
                .collect();
            want.sort_unstable();
            assert_eq!(got, want, "query {q:?}, radius {radius}");
        }
    }
}

#[test]
fn equals_brute_force_inside_around_and_far_from_the_cloud() {
    let mut rng = Pcg64::seed_from_u64(3);
    // A sphere shell far from the origin plus a plane: many empty cells.
    let mut points: Vec<Point3<f64>> = (0..1500)
        .map(|_| {
            let u: [f64; 3] = rand_distr::Distribution::sample(&rand_distr::UnitSphere, &mut rng);
            let v = nalgebra::Vector3::from(u);
            Point3::new(100.0, -20.0, 5.0) + v * 0.8
        })
        .collect();
    points.extend((0..500).map(|_| {
        Point3::new(
            rng.random_range(99.0..101.0),
            rng.random_range(-21.0..-19.0),
            4.0,
        )
    }));
    // The same cloud with its thin axis (z) moved to x and to y: the column axis follows it.
    let permuted = |perm: [usize; 3]| -> Vec<Point3<f64>> {
        points
            .iter()
            .map(|p| Point3::new(p[perm[0]], p[perm[1]], p[perm[2]]))
            .collect()
    };
    // Both column tables answer alike: at the smallest radius the 2 m × 2 m cloud spans more
    // than 16 columns per point (only occupied columns have an entry), at the others fewer.
    let mut sparse = std::collections::BTreeSet::new();
    for perm in [[0, 1, 2], [2, 0, 1], [1, 2, 0]] {
        let points = permuted(perm);
        check_cloud(&points, &mut rng, |radius| {
            let grid = RadiusGrid::new(&points, radius, usize::MAX)
                .unwrap()
                .unwrap();
            sparse.insert((radius.to_bits(), grid.is_sparse()));
            (grid, points.clone())
        });
        // The same queries on grids whose cells are a lattice of voxels given by the caller:
        // of the cell edge, and 2.5 times larger.
        for scale in [1.0, 2.5] {
            check_cloud(&points, &mut rng, |radius| {
                lattice_grid(&points, radius, cell_edge(radius) * scale)
            });
        }
    }
    let sparse_at = |r: f64| {
        sparse
            .iter()
            .filter(move |(b, _)| *b == r.to_bits())
            .map(|x| x.1)
    };
    assert!(sparse_at(0.01).all(|s| s), "{sparse:?}");
    assert!(sparse_at(0.2).all(|s| !s), "{sparse:?}");
}

/// [`RadiusGrid::from_lattice`] over `points` grouped by voxel of edge `edge`, and the points
/// in the order it indexes them.
fn lattice_grid(points: &[Point3<f64>], radius: f64, edge: f64) -> (RadiusGrid, Vec<Point3<f64>>) {
    let mut voxels: std::collections::BTreeMap<[i64; 3], Vec<Point3<f64>>> = Default::default();
    for p in points {
        let key = [p.x, p.y, p.z].map(|c| crate::geometry::floor_i64(c / edge));
        voxels.entry(key).or_default().push(*p);
    }
    let (mut ordered, mut cells) = (Vec::new(), Vec::new());
    for (key, pts) in voxels {
        cells.push((key, ordered.len()..ordered.len() + pts.len()));
        ordered.extend(pts);
    }
    let grid = RadiusGrid::from_lattice(
        &ordered,
        &cells,
        edge,
        radius,
        usize::MAX,
        Default::default(),
    );
    (grid.unwrap().unwrap(), ordered)
}

#[test]
fn from_lattice_rejects_cells_smaller_than_the_radius_and_bad_ranges() {
    let points = [Point3::new(0.1, 0.1, 0.1)];
    let cells = [([0, 0, 0], 0..1)];
    let build = |edge: f64, cells: &[([i64; 3], std::ops::Range<usize>)]| {
        RadiusGrid::from_lattice(&points, cells, edge, 0.5, usize::MAX, Default::default())
    };
    assert!(
        build(0.5, &cells).is_err(),
        "edge = radius: rounding not covered"
    );
    assert!(build(cell_edge(0.5), &cells).unwrap().is_some());
    assert!(build(1.0, &[([0, 0, 0], 0..2)]).is_err());
    assert!(build(1.0, &[]).unwrap().is_none());
    // Keys far out, where the edge no longer covers rounding: declined.
    assert!(build(1.0, &[([1 << 40, 0, 0], 0..1)]).unwrap().is_none());
}

/// A key listed twice is one cell holding both ranges: the same answers as brute force.
#[test]
fn from_lattice_takes_a_repeated_key_as_one_cell() {
    let points = [
        Point3::new(0.1, 0.1, 0.1),
        Point3::new(0.9, 0.2, 0.3),
        Point3::new(0.5, 0.5, 0.5),
    ];
    let cells = [([0, 0, 0], 0..2), ([0, 0, 0], 2..3)];
    let grid = RadiusGrid::from_lattice(&points, &cells, 1.0, 0.5, usize::MAX, Default::default())
        .unwrap()
        .unwrap();
    assert_eq!(grid.len(), 3);
    for q in [
        Point3::new(0.45, 0.5, 0.5),
        Point3::new(0.8, 0.2, 0.3),
        Point3::new(0.1, 0.1, 0.3),
        Point3::new(1.2, 0.2, 0.3),
    ] {
        assert_eq!(
            grid.nearest_within_sq(&q),
            oracle(&points, &q, 0.5),
            "{q:?}"
        );
    }
}

/// `build(radius)` gives a grid and the points in the order it indexes them.
fn check_cloud(
    points: &[Point3<f64>],
    rng: &mut Pcg64,
    mut build: impl FnMut(f64) -> (RadiusGrid, Vec<Point3<f64>>),
) {
    let (lo, hi) = bounds(points);
    for radius in [0.01, 0.05, 0.2, 3.0] {
        let (grid, points) = build(radius);
        let points = &points[..];
        assert_eq!(grid.len(), points.len());
        for _ in 0..4000 {
            // Queries in and around the bounding box (±1.5 radius beyond it) and near points.
            let q = if rng.random_range(0..2) == 0 {
                let p = points[rng.random_range(0..points.len())];
                p + nalgebra::Vector3::from_fn(|_, _| rng.random_range(-1.5..1.5) * radius)
            } else {
                Point3::from(std::array::from_fn(|a| {
                    rng.random_range(lo[a] - 1.5 * radius..hi[a] + 1.5 * radius)
                }))
            };
            let expected = oracle(points, &q, radius);
            assert_eq!(grid.nearest_within_sq(&q), expected, "{q:?}");
            assert_eq!(grid.any_within(&q), expected.is_some(), "{q:?}");
            // The index returned is a point at exactly that distance.
            let found = grid.nearest_within(&q);
            assert_eq!(found.map(|(_, d)| d), expected, "{q:?}");
            // With the point: the same answer, and the coordinates of the cloud's point.
            let with_point = grid.nearest_within_point(&q);
            assert_eq!(with_point.map(|(j, d, _)| (j, d)), found, "{q:?}");
            if let Some((j, _, p)) = with_point {
                assert_eq!(p, points[j as usize], "{q:?}");
            }
            if let Some((j, d)) = found {
                let p = points[j as usize];
                let (dx, dy, dz) = (q.x - p.x, q.y - p.y, q.z - p.z);
                assert_eq!(dx * dx + dy * dy + dz * dz, d, "{q:?}");
            }
        }
        let inside = points[0];
        for far in [
            Point3::new(0.0, 0.0, 0.0),
            Point3::new(1e300, inside.y, inside.z),
            Point3::new(inside.x, inside.y, -1e300),
            Point3::new(f64::NAN, inside.y, inside.z),
            Point3::new(inside.x, f64::INFINITY, inside.z),
        ] {
            assert_eq!(grid.nearest_within_sq(&far), None);
            assert!(!grid.any_within(&far));
        }
    }
}

/// Points exactly on the radius are excluded (strict), as in Open3D's radius search.
#[test]
fn lattice_points_on_the_radius_are_outside() {
    let points: Vec<Point3<f64>> = (0..5)
        .flat_map(|x| (0..5).map(move |y| Point3::new(x as f64 * 0.5, y as f64 * 0.5, 0.0)))
        .collect();
    let grid = RadiusGrid::new(&points, 0.5, usize::MAX).unwrap().unwrap();
    // Midway between two lattice points: 0.25 away.
    assert_eq!(
        grid.nearest_within_sq(&Point3::new(0.25, 0.0, 0.0)),
        Some(0.0625)
    );
    // Exactly 0.5 above a lattice point: on the radius, excluded.
    assert_eq!(grid.nearest_within_sq(&Point3::new(1.0, 1.0, 0.5)), None);
    assert!(!grid.any_within(&Point3::new(1.0, 1.0, 0.5)));
    assert!(grid.any_within(&Point3::new(1.0, 1.0, 0.4999)));
    assert_eq!(
        grid.nearest_within_sq(&Point3::new(1.0, 1.0, 0.4999)),
        Some(0.4999 * 0.4999)
    );
}

#[test]
fn declines_too_many_cells_and_rejects_bad_input() {
    let far = [
        Point3::new(0.0, 0.0, 0.0),
        Point3::new(1000.0, 1000.0, 1000.0),
    ];
    // 10⁴ × 10⁴ columns.
    assert!(RadiusGrid::new(&far, 0.1, 1 << 20).unwrap().is_none());
    assert!(RadiusGrid::new(&far, 100.0, 1 << 20).unwrap().is_some());
    assert!(RadiusGrid::new(&[], 0.1, 1 << 20).unwrap().is_none());
    assert!(RadiusGrid::new(&far, 0.0, 1 << 20).is_err());
    assert!(RadiusGrid::new(&far, f64::NAN, 1 << 20).is_err());
    let nan = [Point3::new(f64::NAN, 0.0, 0.0)];
    assert!(RadiusGrid::new(&nan, 0.1, 1 << 20).is_err());
}

#[test]
fn a_grid_built_in_reused_storage_answers_as_a_new_one() {
    let mut rng = Pcg64::seed_from_u64(11);
    let cloud = |rng: &mut Pcg64, n: usize, size: f64| -> Vec<Point3<f64>> {
        (0..n)
            .map(|_| Point3::from(std::array::from_fn(|_| rng.random_range(0.0..size))))
            .collect()
    };
    // Storage of a larger and of a smaller cloud, at another radius, and of a grid whose table
    // has entries for occupied columns only (300 points over 200 m: sparse), into grids with a
    // dense table and with a sparse one.
    let mut modes = std::collections::BTreeSet::new();
    for ((n, size), (m, span)) in [
        ((5000, 30.0), (1500, 10.0)),
        ((200, 2.0), (1500, 10.0)),
        ((300, 200.0), (1500, 10.0)),
        ((5000, 30.0), (300, 200.0)),
    ] {
        let old = RadiusGrid::new(&cloud(&mut rng, n, size), 0.7, usize::MAX)
            .unwrap()
            .unwrap();
        let points = cloud(&mut rng, m, span);
        let fresh = RadiusGrid::new(&points, 0.4, usize::MAX).unwrap().unwrap();
        modes.insert((old.is_sparse(), fresh.is_sparse()));
        let reused = RadiusGrid::new_reusing(&points, 0.4, usize::MAX, old.into_storage())
            .unwrap()
            .unwrap();
        for _ in 0..3000 {
            let p = points[rng.random_range(0..points.len())];
            let q = p + nalgebra::Vector3::from_fn(|_, _| rng.random_range(-0.6..0.6));
            assert_eq!(reused.nearest_within(&q), fresh.nearest_within(&q));
            assert_eq!(reused.any_within(&q), fresh.any_within(&q));
        }
    }
    assert!(
        modes.contains(&(true, false)) && modes.contains(&(false, true)),
        "{modes:?}"
    );
}

/// A local map's grid is rebuilt every frame in the storage of the last one: the same cells
/// rebuilt there hold no more heap than the first build, dense or sparse.
#[test]
fn a_sorted_lattice_rebuilt_in_its_storage_holds_no_more() {
    let mut rng = Pcg64::seed_from_u64(13);
    for span in [10.0, 300.0] {
        let points: Vec<Point3<f64>> = (0..2000)
            .map(|_| {
                Point3::new(
                    rng.random_range(0.0..span),
                    rng.random_range(0.0..span),
                    1.0,
                )
            })
            .collect();
        let (mut grid, _) = lattice_grid(&points, 0.4, 0.5);
        grid.index_by_storage_order();
        let ordered: Vec<Point3<f64>> = grid.points_in_storage_order().collect();
        let key = |p: &Point3<f64>| [p.x, p.y, p.z].map(|c| crate::geometry::floor_i64(c / 0.5));
        let mut cells: Vec<([i64; 3], u32)> = Vec::new();
        for p in &ordered {
            match cells.last_mut() {
                Some((k, n)) if *k == key(p) => *n += 1,
                _ => cells.push((key(p), 1)),
            }
        }
        let build = |storage| {
            RadiusGrid::from_sorted_lattice(&ordered, &cells, 0.5, 0.4, usize::MAX, storage)
                .unwrap()
                .unwrap()
        };
        let first = build(GridStorage::default());
        let bytes = first.heap_bytes();
        let sparse = first.is_sparse();
        let mut again = first;
        for _ in 0..3 {
            again = build(again.into_storage());
            assert_eq!(again.heap_bytes(), bytes, "span {span}");
        }
        assert_eq!(sparse, span > 100.0);
    }
}

/// After `index_by_storage_order`, each query answers with the storage position of the same
/// point it answered before: `storage_index` (read before) maps it back, and
/// `points_in_storage_order` holds that point there.
#[test]
fn indexing_by_storage_order_answers_the_same_points() {
    let mut rng = Pcg64::seed_from_u64(12);
    let points: Vec<Point3<f64>> = (0..2000)
        .map(|_| {
            Point3::new(
                rng.random_range(-3.0..3.0),
                rng.random_range(-3.0..3.0),
                0.1,
            )
        })
        .collect();
    let mut grid = RadiusGrid::new(&points, 0.2, 1 << 20).unwrap().unwrap();
    let queries: Vec<Point3<f64>> = (0..500)
        .map(|_| {
            Point3::new(
                rng.random_range(-3.5..3.5),
                rng.random_range(-3.5..3.5),
                0.0,
            )
        })
        .collect();
    let before: Vec<_> = queries.iter().map(|q| grid.nearest_within(q)).collect();
    assert!(before.iter().filter(|a| a.is_some()).count() > 100);
    let index = grid.storage_index().to_vec();
    let ordered: Vec<Point3<f64>> = grid.points_in_storage_order().collect();
    assert_eq!(ordered.len(), points.len());
    for (s, &i) in index.iter().enumerate() {
        assert_eq!(ordered[s], points[i as usize]);
    }
    grid.index_by_storage_order();
    for (q, was) in queries.iter().zip(&before) {
        let now = grid.nearest_within(q);
        assert_eq!(now.map(|(s, d)| (index[s as usize], d)), *was);
        if let Some((s, _, p)) = grid.nearest_within_point(q) {
            assert_eq!(p, ordered[s as usize]);
        }
    }
}

/// Over the same voxels, [`RadiusGrid::from_sorted_lattice`] (the points handed over in
/// storage order) stores the points in the order of [`RadiusGrid::from_lattice`] (given the
/// voxels in key order, which it sorts), answers every query with the same (position, squared
/// distance), and agrees with brute force; out-of-order cells and wrong counts are errors.
#[test]
fn a_sorted_lattice_gives_the_grid_of_the_unsorted_one() {
    let mut rng = Pcg64::seed_from_u64(31);
    // A flat scene (z the short axis) and one long along y (the axes then differ from x, y, z),
    // with voxels of 1 to 6 points and columns holding cells with gaps along them.
    // The third spans 16 columns per cell and more: only its occupied columns have an entry.
    for (span, edge) in [
        ([20.0, 12.0, 2.0], 0.5),
        ([3.0, 25.0, 9.0], 0.7),
        ([300.0, 200.0, 2.0], 0.5),
    ] {
        let points: Vec<Point3<f64>> = (0..3000)
            .map(|_| {
                Point3::from(std::array::from_fn(|a| {
                    rng.random_range(0.0..span[a]) - 4.0
                }))
            })
            .collect();
        let radius = 0.9 * edge;
        let (mut unsorted, _) = lattice_grid(&points, radius, edge);
        unsorted.index_by_storage_order();
        let ordered: Vec<Point3<f64>> = unsorted.points_in_storage_order().collect();
        // The voxels in the grid's order, with their counts, from the ordered points.
        let key = |p: &Point3<f64>| [p.x, p.y, p.z].map(|c| crate::geometry::floor_i64(c / edge));
        let mut cells: Vec<([i64; 3], u32)> = Vec::new();
        for p in &ordered {
            match cells.last_mut() {
                Some((k, n)) if *k == key(p) => *n += 1,
                _ => cells.push((key(p), 1)),
            }
        }
        let sorted = RadiusGrid::from_sorted_lattice(
            &ordered,
            &cells,
            edge,
            radius,
            usize::MAX,
            Default::default(),
        )
        .unwrap()
        .unwrap();
        assert_eq!(sorted.is_sparse(), span[0] > 100.0);
        assert_eq!(unsorted.is_sparse(), span[0] > 100.0);
        assert!(sorted.points_in_storage_order().eq(ordered.iter().copied()));
        assert!(
            sorted
                .storage_index()
                .iter()
                .copied()
                .eq(0..ordered.len() as u32)
        );
        for _ in 0..3000 {
            let q = ordered[rng.random_range(0..ordered.len())]
                + nalgebra::Vector3::from_fn(|_, _| rng.random_range(-1.2..1.2) * radius);
            let found = sorted.nearest_within(&q);
            assert_eq!(found, unsorted.nearest_within(&q), "{q:?}");
            // Both index by storage order (one without reading its index): the same points.
            assert_eq!(
                sorted.nearest_within_point(&q),
                unsorted.nearest_within_point(&q),
                "{q:?}"
            );
            if let Some((s, _, p)) = sorted.nearest_within_point(&q) {
                assert_eq!(p, ordered[s as usize]);
            }
            assert_eq!(found.map(|(_, d)| d), oracle(&ordered, &q, radius));
            assert_eq!(sorted.any_within(&q), found.is_some());
        }
        // Two cells swapped, a count off by one: errors.
        let mut swapped = cells.clone();
        swapped.swap(3, 4);
        let mut miscounted = cells.clone();
        miscounted[0].1 += 1;
        for bad in [swapped, miscounted] {
            let r = RadiusGrid::from_sorted_lattice(
                &ordered,
                &bad,
                edge,
                radius,
                usize::MAX,
                Default::default(),
            );
            assert!(r.is_err());
        }
    }
}
