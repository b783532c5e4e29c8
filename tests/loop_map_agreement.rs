//! Loops that repeat what the odometry's local map measured (`mireg::loops::held_by_map`,
//! `mireg::loops::map_agreement`): which places the map still held when a frame registered,
//! checked against a brute-force replay of the map's dropping rule, and the squared Mahalanobis
//! distance between a loop and the odometry, checked against its closed form on diagonal
//! covariances.

use mireg::loops::{LoopConfig, LoopEdge, Step, edge_prior, held_by_map, map_agreement};
use mireg::odometry::uncertainty::diagonal_information;
use nalgebra::{Isometry3, Matrix6, Translation3, UnitQuaternion, Vector3};
use rand::{RngExt, SeedableRng};
use rand_pcg::Pcg64Mcg;

fn at(x: f64, y: f64, yaw_deg: f64) -> Isometry3<f64> {
    Isometry3::from_parts(
        Translation3::new(x, y, 0.0),
        UnitQuaternion::from_axis_angle(&Vector3::z_axis(), yaw_deg.to_radians()),
    )
}

/// The oracle: replays the map frame by frame. A place (frame `m`'s origin) enters when `m`
/// joins, and each later frame that joins drops it if it lies beyond that frame's range.
fn replayed(poses: &[Isometry3<f64>], ranges: &[Option<f64>], m: usize, q: usize) -> bool {
    let mut held = false;
    for k in 0..q {
        let Some(range) = ranges[k] else { continue };
        if k == m {
            held = true;
        }
        let d = (poses[k].translation.vector - poses[m].translation.vector).norm();
        if k > m && d > range {
            held = false;
        }
    }
    held && m < q
}

#[test]
fn held_by_map_matches_a_replay_of_the_map() {
    let mut rng = Pcg64Mcg::seed_from_u64(7);
    for _ in 0..50 {
        let n = 40;
        // A random walk that wanders out and back, ranges 5–30 m, some frames not joining.
        let mut x = 0.0;
        let mut poses = Vec::new();
        let mut ranges = Vec::new();
        for _ in 0..n {
            x += rng.random_range(-3.0..4.0);
            poses.push(at(x, rng.random_range(-1.0..1.0), 0.0));
            ranges.push((rng.random::<f64>() > 0.15).then(|| rng.random_range(5.0..30.0)));
        }
        for q in 0..n {
            for m in 0..n {
                assert_eq!(
                    held_by_map(&poses, &ranges, m, q),
                    replayed(&poses, &ranges, m, q),
                    "m {m}, q {q}"
                );
            }
        }
    }
}

#[test]
fn a_place_left_behind_is_no_longer_held() {
    // Out along x 2 m a frame to 40 m and back; every frame keeps 15 m around it.
    let poses: Vec<_> = (0..=20)
        .chain((0..20).rev())
        .map(|i| at(2.0 * i as f64, 0.0, 0.0))
        .collect();
    let ranges = vec![Some(15.0); poses.len()];
    let back_at_start = poses.len() - 1;
    // The start was dropped once the way out passed 15 m: the way back did not see it in the map.
    assert!(!held_by_map(&poses, &ranges, 0, back_at_start));
    // The turn's neighbourhood stayed within range all along.
    assert!(held_by_map(&poses, &ranges, 18, 23));
    // Nothing is held without a map.
    let none = vec![None; poses.len()];
    assert!(!held_by_map(&poses, &none, 18, 23));
}

/// Three frames on a line, the query registered against the match's place; steps with diagonal
/// information.
fn line() -> (Vec<Isometry3<f64>>, Vec<Option<f64>>, LoopConfig) {
    let poses = vec![at(0.0, 0.0, 0.0), at(1.0, 0.0, 5.0), at(2.0, 0.5, 10.0)];
    (poses, vec![Some(50.0); 3], LoopConfig::for_voxel(0.1))
}

#[test]
fn map_agreement_is_the_closed_form_mahalanobis_distance() {
    let (poses, ranges, config) = line();
    let (sq_m, sq_deg) = (0.02, 0.3);
    let (sl_m, sl_deg) = (0.05, 0.5);
    let omega_q = diagonal_information(sq_m, sq_deg);
    let omega_l = diagonal_information(sl_m, sl_deg);
    let steps = vec![
        Step::Registered,
        Step::Measured(omega_q),
        Step::Measured(omega_q),
    ];
    let prior = edge_prior(&config);
    let odometry = poses[0].inverse() * poses[2];
    // The loop differs from the odometry by δ along the query's x and ε about its z.
    let (delta, eps_deg) = (0.04, 0.2);
    let loop_pose = odometry * at(-delta, 0.0, -eps_deg);
    let edge = LoopEdge {
        query: 2,
        matched: 0,
        match_from_query: loop_pose,
        information: Some(omega_l),
    };
    let d2 = map_agreement(&poses, &steps, &ranges, &edge, &config).expect("held and measured");
    // Closed form per axis: variances add, each with the prior's information on top.
    let var = |s: f64, p: f64| 1.0 / (1.0 / (s * s) + p);
    let var_t = var(sq_m, prior[(3, 3)]) + var(sl_m, prior[(3, 3)]);
    let var_r = var(sq_deg.to_radians(), prior[(0, 0)]) + var(sl_deg.to_radians(), prior[(0, 0)]);
    // Log of a small planar pose: rotation ε, translation δ up to second order in ε.
    let expected = delta * delta / var_t + eps_deg.to_radians().powi(2) / var_r;
    assert!(
        (d2 - expected).abs() < 2e-3 * expected,
        "d² {d2} against {expected}"
    );
    // The same loop as the odometry's relative pose: distance 0.
    let exact = LoopEdge {
        match_from_query: odometry,
        ..edge
    };
    let zero = map_agreement(&poses, &steps, &ranges, &exact, &config).unwrap();
    assert!(zero < 1e-20, "{zero}");
}

#[test]
fn no_agreement_where_the_odometry_did_not_measure_the_relation() {
    let (poses, ranges, config) = line();
    let omega = Matrix6::identity() * 1e4;
    let edge = LoopEdge {
        query: 2,
        matched: 0,
        match_from_query: poses[0].inverse() * poses[2],
        information: Some(omega),
    };
    let measured = vec![
        Step::Registered,
        Step::Measured(omega),
        Step::Measured(omega),
    ];
    assert!(map_agreement(&poses, &measured, &ranges, &edge, &config).is_some());
    // A failed step in between: the odometry's relation is a fallback's.
    let failed = vec![Step::Registered, Step::Failed, Step::Measured(omega)];
    assert!(map_agreement(&poses, &failed, &ranges, &edge, &config).is_none());
    // The match's place was dropped: the query did not register against it.
    let dropped = vec![Some(50.0), Some(0.5), Some(50.0)];
    assert!(map_agreement(&poses, &measured, &dropped, &edge, &config).is_none());
    // A loop without a measured information is not judged.
    let blind = LoopEdge {
        information: None,
        ..edge
    };
    assert!(map_agreement(&poses, &measured, &ranges, &blind, &config).is_none());
}
