//! The loop acceptance tests that need no odometry: the overlap must hold both ways, and the
//! registration must pin every direction down. Each pair below registers convincingly one way.

use mireg::loops::{LoopConfig, VerifyConfig, verify};
use mireg::pipeline::{PairConfig, prepare_frame};
use nalgebra::{Isometry3, Point3};
use rand::{RngExt, SeedableRng};

#[path = "common/synthetic_log.rs"]
mod synthetic_log;

fn pair_config() -> PairConfig {
    PairConfig {
        voxel_size_m: 0.1,
        seed: 7,
        ..PairConfig::default()
    }
}

#[test]
fn a_query_that_sees_a_corner_of_the_match_overlaps_one_way_only() {
    let room = synthetic_log::scene(3);
    // The query sees the room's left third only: all of it lies on the match frame's surfaces,
    // a third of the match frame on the query's.
    let corner: Vec<Point3<f64>> = room.iter().copied().filter(|p| p.x < -1.5).collect();
    let pair = pair_config();
    let (query, matched) = (
        prepare_frame(&corner, &pair).unwrap(),
        prepare_frame(&room, &pair).unwrap(),
    );
    let config = LoopConfig::for_voxel(0.1);
    let v = verify(
        &query,
        &matched,
        &Isometry3::identity(),
        config.drift_allowance(12.0),
        &pair,
        &VerifyConfig::default(),
    )
    .unwrap();
    assert!(
        v.pair.failure.is_none() && v.pair.fitness > 0.9,
        "{:?}",
        v.pair
    );
    assert!(!v.accepted);
    assert!(v.reason.contains("the other way"), "{}", v.reason);
    // The full room against itself is accepted.
    let again = prepare_frame(&synthetic_log::scene(3), &pair).unwrap();
    let v = verify(
        &again,
        &matched,
        &Isometry3::identity(),
        config.drift_allowance(12.0),
        &pair,
        &VerifyConfig::default(),
    )
    .unwrap();
    assert!(v.accepted, "{}", v.reason);
}

#[test]
fn a_corridor_registers_anywhere_along_it_and_is_rejected() {
    // Two parallel walls and nothing else, 12 m long: any shift along the corridor fits.
    let corridor = |seed: u64| -> Vec<Point3<f64>> {
        let mut rng = rand_pcg::Pcg64Mcg::seed_from_u64(seed);
        (0..8000)
            .map(|i| {
                let (u, v): (f64, f64) = (rng.random_range(-6.0..6.0), rng.random_range(0.0..3.0));
                // Ribbed walls (a few cm of relief across the corridor) so that features exist.
                let relief = 0.05 * (3.0 * v).sin();
                if i % 2 == 0 {
                    Point3::new(-1.5 + relief, v, u)
                } else {
                    Point3::new(1.5 - relief, v, u)
                }
            })
            .collect()
    };
    let pair = pair_config();
    let (query, matched) = (
        prepare_frame(&corridor(1), &pair).unwrap(),
        prepare_frame(&corridor(2), &pair).unwrap(),
    );
    // As many inliers as odometry asks for pass here (this corridor gives 20; a real one with
    // repeated structure gives plenty), so that the test below is the one that decides.
    let config = VerifyConfig {
        min_inliers: 12,
        ..VerifyConfig::default()
    };
    let v = verify(
        &query,
        &matched,
        &Isometry3::identity(),
        None,
        &pair,
        &config,
    )
    .unwrap();
    assert!(v.pair.fitness > 0.5, "{:?}", v.pair);
    assert!(!v.accepted, "a corridor loop was accepted: {:?}", v.pair);
    assert!(
        v.reason.contains("leaves a direction free"),
        "rejected for another reason: {} ({:?})",
        v.reason,
        v.pair
    );
}
