use super::*;
use nalgebra::{Translation3, UnitQuaternion};

fn map(voxel: f64, cap: usize) -> LocalMap {
    LocalMap::new(LocalMapConfig {
        voxel_size_m: voxel,
        max_points_per_voxel: cap,
    })
    .unwrap()
}

#[test]
fn voxels_hold_at_most_their_cap_and_far_voxels_go() {
    let mut m = map(1.0, 2);
    let pts: Vec<Point3<f64>> = (0..5)
        .map(|k| Point3::new(0.1 * k as f64, 0.5, 0.5))
        .collect();
    let normals = vec![Vector3::z(); pts.len()];
    m.insert(&Isometry3::identity(), &pts, &normals, 100.0);
    assert_eq!(m.len(), 2, "one voxel, capped at two");
    // The same points seen from 10 m further along x land in another voxel.
    let moved = Isometry3::from_parts(
        Translation3::new(10.0, 0.0, 0.0),
        UnitQuaternion::identity(),
    );
    m.insert(&moved, &pts, &normals, 100.0);
    assert_eq!(m.len(), 4);
    // From 20 m on, with a 5 m range, the first voxel (10+ m away) is dropped.
    let far = Isometry3::from_parts(
        Translation3::new(12.0, 0.0, 0.0),
        UnitQuaternion::identity(),
    );
    m.insert(&far, &[], &[], 5.0);
    assert_eq!(m.len(), 2);
    let t = m.target(0.5).unwrap().unwrap();
    assert!(t.points().iter().all(|p| p.x >= 10.0));
}

/// Against a direct model of the map's rule (per voxel, the first `cap` points in arrival
/// order; voxels whose first point is beyond the range dropped after each frame), over frames
/// that move away so that voxels are dropped, their ids reused, and keys dropped and seen again
/// between two targets. The target holds the model's points and normals in the model's order:
/// voxels sorted by key with the two widest axes first (widest first, ties by axis index),
/// each voxel's points in arrival order.
#[test]
fn the_map_holds_what_the_rule_says_in_lattice_order() {
    use rand::{RngExt, SeedableRng};
    use std::collections::BTreeMap;
    let (voxel, cap, range) = (0.5, 3, 4.0);
    let mut m = map(voxel, cap);
    // Per voxel key, its points and normals in arrival order.
    type Voxels = BTreeMap<[i64; 3], Vec<(Point3<f64>, Vector3<f64>)>>;
    let mut model = Voxels::new();
    let mut rng = rand_pcg::Pcg64::seed_from_u64(7);
    let mut created = 0;
    for frame in 0..16 {
        // Along x, then along y (the widest axis changes), turning.
        let (x, y) = if frame < 8 {
            (0.7 * frame as f64, 0.1 * frame as f64)
        } else {
            (4.9, 0.7 + 0.9 * (frame - 7) as f64)
        };
        let pose = Isometry3::from_parts(
            Translation3::new(x, y, 0.0),
            UnitQuaternion::from_euler_angles(0.0, 0.0, 0.2 * frame as f64),
        );
        let pts: Vec<Point3<f64>> = (0..300)
            .map(|_| {
                Point3::new(
                    rng.random_range(-3.0..3.0),
                    rng.random_range(-3.0..3.0),
                    rng.random_range(-0.5..0.5),
                )
            })
            .collect();
        let normals: Vec<Vector3<f64>> = (0..pts.len())
            .map(|_| Vector3::new(rng.random_range(-1.0..1.0), 0.5, 1.0).normalize())
            .collect();
        m.insert(&pose, &pts, &normals, range);
        for (p, n) in pts.iter().zip(&normals) {
            let w = pose * p;
            let key = [0, 1, 2].map(|k| (w[k] / voxel).floor() as i64);
            created += usize::from(!model.contains_key(&key));
            let v = model.entry(key).or_default();
            if v.len() < cap {
                v.push((w, pose.rotation * n));
            }
        }
        let origin = Point3::from(pose.translation.vector);
        model.retain(|_, v| (v[0].0 - origin).norm() <= range);
        let expected: usize = model.values().map(Vec::len).sum();
        assert_eq!(m.len(), expected, "frame {frame}");
        // Every third frame builds no target: its points wait for the next one.
        if frame % 3 == 1 {
            continue;
        }
        let (lo, hi) = model
            .keys()
            .fold(([i64::MAX; 3], [i64::MIN; 3]), |(lo, hi), k| {
                (
                    std::array::from_fn(|a| lo[a].min(k[a])),
                    std::array::from_fn(|a| hi[a].max(k[a])),
                )
            });
        let mut axes = [0usize, 1, 2];
        axes.sort_by_key(|&a| (std::cmp::Reverse(hi[a] - lo[a]), a));
        let mut keys: Vec<&[i64; 3]> = model.keys().collect();
        keys.sort_by_key(|k| axes.map(|a| k[a]));
        let want: Vec<(Point3<f64>, Vector3<f64>)> = keys
            .iter()
            .flat_map(|k| model[*k].iter().copied())
            .collect();
        // 0.4 m: the voxels are the target's grid; 0.6 m: no grid, the same order.
        for distance in [0.4, 0.6] {
            let t = m.target(distance).unwrap().unwrap();
            let got: Vec<(Point3<f64>, Vector3<f64>)> = (t.points().iter().copied())
                .zip(t.normals().unwrap().iter().copied())
                .collect();
            assert!(got == want, "frame {frame}: the map differs from the model");
        }
        let probes: Vec<Point3<f64>> = want.iter().map(|(p, _)| p + Vector3::x() * 0.1).collect();
        let t = m.target(0.4).unwrap().unwrap();
        let eval =
            crate::refine::icp::evaluate_registration(&probes, t, &Isometry3::identity(), 0.4);
        let inliers = probes
            .iter()
            .filter(|q| want.iter().any(|(p, _)| (*q - p).norm() < 0.4))
            .count();
        assert_eq!(eval.unwrap().num_inliers, inliers, "frame {frame}");
    }
    // Voxels were dropped and their ids reused.
    assert!(
        m.voxels.len() < created,
        "{} ids for {created} voxels",
        m.voxels.len()
    );
}

/// A target asked for at a distance that is not finite and positive is an error that leaves
/// the map as it was.
#[test]
fn a_bad_distance_leaves_the_map_as_it_was() {
    let mut m = map(0.5, 20);
    let pts = [Point3::new(1.0, 0.0, 0.0), Point3::new(2.0, 0.3, 0.0)];
    m.insert(&Isometry3::identity(), &pts, &[Vector3::z(); 2], 100.0);
    let before = m.target(0.4).unwrap().unwrap().points().to_vec();
    for bad in [0.0, -1.0, f64::NAN, f64::INFINITY] {
        assert!(m.target(bad).is_err());
        let gather = |at: &[u32]| vec![Vector3::z(); at.len()];
        assert!(
            m.insert_and_target(&Isometry3::identity(), &[], gather, 100.0, bad)
                .is_err()
        );
    }
    assert_eq!(m.len(), 2);
    assert_eq!(m.target(0.4).unwrap().unwrap().points(), &before[..]);
}

#[test]
fn points_and_normals_go_to_the_world_frame() {
    let mut m = map(0.5, 20);
    let pose = Isometry3::from_parts(
        Translation3::new(1.0, 2.0, 3.0),
        UnitQuaternion::from_euler_angles(0.0, 0.0, std::f64::consts::FRAC_PI_2),
    );
    m.insert(&pose, &[Point3::new(1.0, 0.0, 0.0)], &[Vector3::x()], 100.0);
    let t = m.target(0.5).unwrap().unwrap();
    assert!((t.points()[0] - Point3::new(1.0, 3.0, 3.0)).norm() < 1e-12);
    assert!((t.normals().unwrap()[0] - Vector3::y()).norm() < 1e-12);
    assert!(map(0.5, 20).target(0.2).unwrap().is_none());
    assert!(
        LocalMap::new(LocalMapConfig {
            voxel_size_m: f64::NAN,
            max_points_per_voxel: 1
        })
        .is_err()
    );
}

#[test]
fn normals_asked_for_the_kept_points_only_give_the_same_map() {
    // Two overlapping frames of a noisy slab: the second lands mostly in voxels the first
    // filled up.
    use rand::{RngExt, SeedableRng};
    let mut rng = rand_pcg::Pcg64::seed_from_u64(9);
    let frame: Vec<Point3<f64>> = (0..4000)
        .map(|_| {
            Point3::new(
                rng.random_range(0.0..4.0),
                rng.random_range(0.0..4.0),
                rng.random_range(0.0..0.3),
            )
        })
        .collect();
    let normals: Vec<Vector3<f64>> = frame
        .iter()
        .map(|p| Vector3::new(p.x, 1.0, p.y).normalize())
        .collect();
    let poses = [
        Isometry3::identity(),
        Isometry3::from_parts(
            Translation3::new(0.3, 0.1, 0.0),
            UnitQuaternion::from_euler_angles(0.0, 0.0, 0.05),
        ),
    ];
    let (mut all, mut lazy) = (map(0.5, 3), map(0.5, 3));
    let mut asked = Vec::new();
    for pose in &poses {
        all.insert(pose, &frame, &normals, 100.0);
        lazy.insert_with(
            pose,
            &frame,
            |at| {
                asked.push(at.to_vec());
                at.iter().map(|&i| normals[i as usize]).collect()
            },
            100.0,
        );
    }
    assert_eq!(all.len(), lazy.len());
    let (a, b) = (
        all.target(0.5).unwrap().unwrap(),
        lazy.target(0.5).unwrap().unwrap(),
    );
    assert_eq!(a.points(), b.points());
    assert_eq!(a.normals(), b.normals());
    // Inserting and building the target in one call (normals estimated beside the grid)
    // gives the same target, frame after frame, with its grid at the distance asked.
    let mut fused = map(0.5, 3);
    for pose in &poses {
        let gather = |at: &[u32]| at.iter().map(|&i| normals[i as usize]).collect();
        let t = fused
            .insert_and_target(pose, &frame, gather, 100.0, 0.4)
            .unwrap()
            .unwrap();
        assert_eq!(t.points().len(), fused.len());
    }
    // At 0.4 m the voxels are its grid; at 0.5 m (just above the voxel) there is no grid: the
    // same points with the same normals.
    let f = fused.built_target().unwrap();
    let pairs = |t: &IcpTarget| {
        let mut v: Vec<[f64; 6]> = (t.points().iter().zip(t.normals().unwrap()))
            .map(|(p, n)| [p.x, p.y, p.z, n.x, n.y, n.z])
            .collect();
        v.sort_by(|a, b| a.partial_cmp(b).unwrap());
        v
    };
    assert_eq!(pairs(f), pairs(a));
    let probes = [Point3::new(1.0, 1.0, 0.1), Point3::new(3.3, 0.2, 0.25)];
    let id = Isometry3::identity();
    assert_eq!(
        crate::refine::icp::evaluate_registration(&probes, f, &id, 0.4).unwrap(),
        crate::refine::icp::evaluate_registration(&probes, a, &id, 0.4).unwrap()
    );
    // Asked once per frame, in increasing order, for exactly the points kept.
    assert_eq!(asked.len(), 2);
    assert!(asked.iter().all(|at| at.windows(2).all(|w| w[0] < w[1])));
    assert_eq!(asked.iter().map(Vec::len).sum::<usize>(), all.len());
    assert!(asked[1].len() < frame.len() / 2, "{}", asked[1].len());
}

#[test]
fn merging_in_place_gives_the_sorted_union() {
    use rand::{RngExt, SeedableRng};
    let mut rng = rand_pcg::Pcg64::seed_from_u64(7);
    for _ in 0..200 {
        let mut draw = || -> Vec<i64> {
            let n = rng.random_range(0..20);
            let mut v: Vec<i64> = (0..n).map(|_| rng.random_range(-50..50)).collect();
            v.sort_unstable();
            v
        };
        let (mut order, fresh) = (draw(), draw());
        let mut expected = [order.clone(), fresh.clone()].concat();
        expected.sort();
        super::merge_into(&mut order, &fresh, |x| *x);
        assert_eq!(order, expected);
    }
}
