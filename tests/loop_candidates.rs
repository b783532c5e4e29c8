//! Loop candidates: the descriptor's rotation invariance on prepared synthetic frames, place and
//! appearance search on synthetic trajectories, bounds, determinism and keyframe selection.

#[path = "common/synthetic_log.rs"]
mod synthetic_log;

use mireg::evaluate::path_distances;
use mireg::features::fpfh::FPFH_BINS;
use mireg::loops::descriptor::SHAPE_BINS;
use mireg::loops::{
    Candidate, CandidateConfig, Descriptor, Keyframe, KeyframeConfig, Source, find_candidates,
    select_keyframes,
};
use mireg::pipeline::{PairConfig, prepare_frame};
use nalgebra::{Isometry3, Point3, Rotation3, Translation3, Unit, UnitQuaternion, Vector3};
use rand::{RngExt, SeedableRng};

fn descriptor_of(points: &[Point3<f64>]) -> Descriptor {
    let config = PairConfig {
        voxel_size_m: 0.1,
        icp: false,
        icp_fine: false,
        ..PairConfig::default()
    };
    Descriptor::from_prepared(&prepare_frame(points, &config).unwrap())
}

#[test]
fn descriptor_is_invariant_to_yaw_and_other_rotations_of_a_prepared_frame() {
    let scene = synthetic_log::scene(7);
    let base = descriptor_of(&scene);
    // The scene's up axis is −y (y down, as a camera).
    let rotations = [
        (Vector3::y(), 30.0),
        (Vector3::y(), 90.0),
        (Vector3::y(), 200.0),
        (Vector3::x(), 45.0),
        (Vector3::new(1.0, -2.0, 0.5), 130.0),
    ];
    let mut worst: f64 = 0.0;
    for (axis, deg) in rotations {
        let r = Rotation3::from_axis_angle(&Unit::new_normalize(axis), f64::to_radians(deg));
        let rotated: Vec<_> = scene.iter().map(|p| r * p).collect();
        worst = worst.max(base.distance(&descriptor_of(&rotated)));
    }
    // Another room: the same walls, other objects elsewhere.
    let other = base.distance(&descriptor_of(&synthetic_log::scene(8)));
    assert!(
        worst < 0.4 * other,
        "rotated copies at {worst:.4}, another scene at {other:.4}"
    );
}

/// A distinct descriptor per index: one-hot FPFH and shape bins, far apart (distance ≥ 1/3).
fn distinct(k: usize) -> Descriptor {
    let mut fpfh = [0.0f32; FPFH_BINS];
    let mut shape = [0.0f32; SHAPE_BINS];
    fpfh[k % FPFH_BINS] = 1.0;
    shape[(k / FPFH_BINS) % SHAPE_BINS] = 1.0;
    Descriptor {
        fpfh,
        shape,
        range: [0.0; SHAPE_BINS],
    }
}

/// Keyframes `frame = 10 · k` at `positions`, each with `descriptors[k]`.
fn keyframes(positions: &[Vector3<f64>], descriptors: &[Descriptor]) -> Vec<Keyframe> {
    let poses: Vec<Isometry3<f64>> = positions
        .iter()
        .map(|t| Isometry3::from_parts(Translation3::from(*t), UnitQuaternion::identity()))
        .collect();
    let travelled = path_distances(&poses);
    (0..poses.len())
        .map(|k| Keyframe {
            frame: 10 * k,
            stamp_ns: 100_000_000 * k as u64,
            pose: poses[k],
            travelled_m: travelled[k],
            descriptor: descriptors[k],
        })
        .collect()
}

/// A 20 m square driven once and back to the start, a keyframe per metre (81 keyframes; 0 and 80
/// are the same true place), seen through odometry whose heading drifts by 2° per side, so that
/// the last keyframe's odometry is ~1.9 m from the first.
fn drifting_square() -> Vec<Vector3<f64>> {
    let mut out = vec![Vector3::zeros()];
    let (mut p, mut heading) = (Vector3::zeros(), 0.0f64);
    for side in 0..4 {
        for _ in 0..20 {
            p += Vector3::new(heading.cos(), heading.sin(), 0.0);
            out.push(p);
        }
        heading = f64::to_radians(92.0 * f64::from(side + 1));
    }
    out
}

#[test]
fn place_finds_the_revisit_of_a_drifting_square_loop_and_not_the_neighbours_in_time() {
    let positions = drifting_square();
    let end_error = (positions[80] - positions[0]).norm();
    assert!(end_error > 1.5, "drift {end_error} m");
    let descriptors: Vec<_> = (0..positions.len()).map(distinct).collect();
    let kf = keyframes(&positions, &descriptors);
    let config = CandidateConfig {
        place_radius_m: 1.0,
        drift_fraction: 0.02,
        min_path_separation_m: 10.0,
        appearance_k: 0,
        ..CandidateConfig::default()
    };
    let found = find_candidates(&kf, &config).unwrap();
    assert!(
        found
            .iter()
            .any(|c| c.query == 80 && c.matched == 0 && c.by == Source::Place),
        "{found:?}"
    );
    for c in &found {
        // Only the closing metres of the loop meet its first metres.
        assert!(c.query >= 75 && c.matched <= 5, "{c:?}");
        assert!(c.odometry_distance_m <= config.place_radius_for(80.0));
    }
    // Without the drift allowance the revisit is out of reach.
    let rigid = CandidateConfig {
        drift_fraction: 0.0,
        ..config
    };
    let without = find_candidates(&kf, &rigid).unwrap();
    assert!(!without.iter().any(|c| c.query == 80 && c.matched == 0));
}

/// Out 30 m along x and back, a keyframe per metre, through odometry whose heading drifted by
/// 25° at the turn: the way back runs off at 155° instead of 180°, so keyframe 58, back where
/// keyframe 2 was, is 12 m from it in the odometry.
fn drifted_out_and_back() -> Vec<Vector3<f64>> {
    let back = Vector3::new(
        f64::to_radians(155.0).cos(),
        f64::to_radians(155.0).sin(),
        0.0,
    );
    (0..=60)
        .map(|k| {
            if k <= 30 {
                Vector3::new(k as f64, 0.0, 0.0)
            } else {
                Vector3::new(30.0, 0.0, 0.0) + back * (k - 30) as f64
            }
        })
        .collect()
}

#[test]
fn appearance_finds_a_revisit_whose_odometry_is_metres_off() {
    let positions = drifted_out_and_back();
    let mut descriptors: Vec<_> = (0..positions.len()).map(distinct).collect();
    let mut revisit = descriptors[2];
    revisit.fpfh[2] = 0.97;
    revisit.fpfh[3] = 0.03;
    descriptors[58] = revisit;
    let kf = keyframes(&positions, &descriptors);
    let config = CandidateConfig::default();
    let apart = (positions[58] - positions[2]).norm();
    // Beyond the place radius, but the sensor came back: a revisit by the ratio test.
    assert!(
        apart > 12.0 && apart > config.place_radius_for(56.0),
        "{apart}"
    );
    let found = find_candidates(&kf, &config).unwrap();
    assert_eq!(found.len(), 1, "{found:?}");
    let c = found[0];
    assert_eq!((c.query, c.matched, c.by), (58, 2, Source::Appearance));
    assert!((c.odometry_distance_m - apart).abs() < 1e-9);
    assert!((c.descriptor_distance - 0.01).abs() < 1e-6);
}

/// (query, matched, source) of each candidate [`find_candidates`] finds.
fn found_pairs(kf: &[Keyframe], config: &CandidateConfig) -> Vec<(usize, usize, Source)> {
    find_candidates(kf, config)
        .unwrap()
        .into_iter()
        .map(|c| (c.query, c.matched, c.by))
        .collect()
}

#[test]
fn a_straight_drive_has_no_revisit_even_where_keyframes_look_alike() {
    // A straight 60 m drive: keyframe 55 looks like keyframe 5, 50 m back along the line (as a
    // LiDAR scan sees far ahead). The odometry went on, it did not come back: no candidate,
    // unless the ratio test is turned off.
    let positions: Vec<_> = (0..60).map(|k| Vector3::new(k as f64, 0.0, 0.0)).collect();
    let mut descriptors: Vec<_> = (0..60).map(distinct).collect();
    descriptors[55] = descriptors[5];
    let kf = keyframes(&positions, &descriptors);
    let config = CandidateConfig::default();
    assert!(!config.revisits(50.0, 50.0) && config.revisits(0.8 * 50.0, 50.0));
    assert_eq!(find_candidates(&kf, &config).unwrap(), vec![]);
    let off = CandidateConfig {
        max_distance_per_path: 1.0,
        ..config
    };
    let found = found_pairs(&kf, &off);
    assert_eq!(found, vec![(55, 5, Source::Appearance)]);
}

#[test]
fn appearance_needs_the_path_separation_too() {
    // A straight 60 m drive, a keyframe per metre (10 log frames apart): keyframe 40 looks like
    // keyframe 30, 10 m back (enough frames apart, too little path), and keyframe 59 like
    // keyframe 5, 54 m back.
    let positions: Vec<_> = (0..60).map(|k| Vector3::new(k as f64, 0.0, 0.0)).collect();
    let mut descriptors: Vec<_> = (0..60).map(distinct).collect();
    descriptors[40] = descriptors[30];
    descriptors[59] = descriptors[5];
    let kf = keyframes(&positions, &descriptors);
    // A straight drive: the revisit test off, to isolate the path separation.
    let config = CandidateConfig {
        max_distance_per_path: 1.0,
        ..CandidateConfig::default()
    };
    assert!(kf[40].frame - kf[30].frame >= config.min_frame_separation);
    assert!(kf[40].travelled_m - kf[30].travelled_m < config.min_path_separation_m);
    let found = found_pairs(&kf, &config);
    assert_eq!(found, vec![(59, 5, Source::Appearance)]);
    // With the separation down to 5 m, the neighbour is a candidate as well.
    let near = CandidateConfig {
        min_path_separation_m: 5.0,
        ..config
    };
    let found: Vec<_> = find_candidates(&kf, &near)
        .unwrap()
        .into_iter()
        .map(|c| (c.query, c.matched))
        .collect();
    assert!(
        found.contains(&(40, 30)) && found.contains(&(59, 5)),
        "{found:?}"
    );
}

/// Five laps of a 30 m circle (a keyframe per metre), every keyframe of a place alike.
fn laps() -> Vec<Keyframe> {
    let mut rng = rand_pcg::Pcg64Mcg::seed_from_u64(3);
    let positions: Vec<_> = (0..150)
        .map(|k| {
            let a = std::f64::consts::TAU * (k % 30) as f64 / 30.0;
            let r = 30.0 / std::f64::consts::TAU;
            Vector3::new(r * a.cos(), r * a.sin(), 0.0)
                + Vector3::repeat(rng.random_range(-0.05..0.05))
        })
        .collect();
    let descriptors: Vec<_> = (0..150)
        .map(|k| {
            let mut d = distinct(k % 30);
            d.shape[15] = rng.random_range(0.0..0.02); // small appearance noise
            d
        })
        .collect();
    keyframes(&positions, &descriptors)
}

#[test]
fn candidates_are_bounded_unique_earlier_and_deterministic() {
    let kf = laps();
    let config = CandidateConfig {
        max_per_query: 4,
        ..CandidateConfig::default()
    };
    let found = find_candidates(&kf, &config).unwrap();
    assert!(!found.is_empty());
    let mut pairs: Vec<(usize, usize)> = found.iter().map(|c| (c.query, c.matched)).collect();
    for q in 0..kf.len() {
        assert!(found.iter().filter(|c| c.query == q).count() <= 4);
    }
    assert!(found.iter().all(|c| c.matched < c.query));
    assert!(found.windows(2).all(|w| w[0].query <= w[1].query));
    let n = pairs.len();
    pairs.sort();
    pairs.dedup();
    assert_eq!(pairs.len(), n, "duplicate pairs");
    // The fifth lap finds earlier laps of the same place, both ways.
    assert!(
        found
            .iter()
            .any(|c| c.query == 140 && c.matched % 30 == 20 && c.by == Source::Both)
    );
    // One thread or many, the same list.
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(1)
        .build()
        .unwrap();
    let single: Vec<Candidate> = pool.install(|| find_candidates(&kf, &config).unwrap());
    assert_eq!(single, found);
    assert_eq!(find_candidates(&kf, &config).unwrap(), found);
}

#[test]
fn bad_knobs_and_keyframes_out_of_order_are_errors() {
    let kf = laps();
    let bad = CandidateConfig {
        drift_fraction: f64::NAN,
        ..CandidateConfig::default()
    };
    assert!(find_candidates(&kf, &bad).is_err());
    let mut swapped = kf.clone();
    swapped.swap(3, 4);
    assert!(find_candidates(&swapped, &CandidateConfig::default()).is_err());
    assert!(
        find_candidates(&[], &CandidateConfig::default())
            .unwrap()
            .is_empty()
    );
}

#[test]
fn keyframe_selector_on_a_known_path() {
    // 0.3 m steps along x for 10 frames, then turns in place by 4° per frame for 6 frames.
    let mut poses = Vec::new();
    for k in 0..10 {
        poses.push(Isometry3::translation(0.3 * k as f64, 0.0, 0.0));
    }
    for k in 1..=6 {
        let r =
            UnitQuaternion::from_axis_angle(&Vector3::z_axis(), f64::to_radians(4.0 * k as f64));
        poses.push(Isometry3::from_parts(Translation3::new(2.7, 0.0, 0.0), r));
    }
    let travelled = path_distances(&poses);
    let keys = select_keyframes(&poses, &travelled, &KeyframeConfig::default()).unwrap();
    // Path 1.2 m at frame 4 and 8; then frame 12 turned 12° from frame 8, frame 15 12° from 12.
    assert_eq!(keys, vec![0, 4, 8, 12, 15]);
    let every = KeyframeConfig {
        keyframe_distance_m: 0.0,
        keyframe_angle_deg: 0.0,
    };
    assert_eq!(
        select_keyframes(&poses, &travelled, &every).unwrap(),
        (0..16).collect::<Vec<_>>()
    );
    assert!(select_keyframes(&poses, &travelled[1..], &every).is_err());
}

#[test]
fn appearance_finds_a_rotated_revisit_of_a_prepared_scene() {
    // Eight rooms along a 70 m drive, then the third seen again turned by 120° about its up axis,
    // its odometry 40 m from where it was first seen.
    let mut descriptors: Vec<Descriptor> = (0..8)
        .map(|k| descriptor_of(&synthetic_log::scene(10 + k)))
        .collect();
    let turn = Rotation3::from_axis_angle(&Vector3::y_axis(), f64::to_radians(120.0));
    let revisit: Vec<_> = synthetic_log::scene(12).iter().map(|p| turn * p).collect();
    descriptors.push(descriptor_of(&revisit));
    let mut positions: Vec<_> = (0..8)
        .map(|k| Vector3::new(10.0 * k as f64, 0.0, 0.0))
        .collect();
    positions.push(Vector3::new(20.0, 40.0, 0.0));
    let kf = keyframes(&positions, &descriptors);
    let config = CandidateConfig {
        min_frame_separation: 10,
        ..CandidateConfig::default()
    };
    let found = find_candidates(&kf, &config).unwrap();
    let of_revisit: Vec<&Candidate> = found.iter().filter(|c| c.query == 8).collect();
    assert!(!of_revisit.is_empty(), "{found:?}");
    assert_eq!(
        (of_revisit[0].matched, of_revisit[0].by),
        (2, Source::Appearance)
    );
    // Other rooms may pass the gate (few earlier keyframes make a loose median), never as close.
    let d = of_revisit[0].descriptor_distance;
    assert!(
        found
            .iter()
            .filter(|c| c.matched != 2)
            .all(|c| c.descriptor_distance > 5.0 * d),
        "{found:?}"
    );
}
