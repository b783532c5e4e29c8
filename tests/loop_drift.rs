//! Metres of drift: a 200 m square driven once, whose odometry turns a little too much at every
//! step (a yaw bias, the drift a miscalibrated or degenerate odometry has, which the pose
//! graph's random-walk model of the odometry does not explain), closed by true loops between
//! its last frames and its first. The loops must pull the trajectory back to the truth, not be
//! discounted by the robust kernel as outliers.

use mireg::loops::{LoopConfig, LoopEdge, Step, optimize_trajectory};
use nalgebra::{Isometry3, Translation3, UnitQuaternion, Vector3};
use rand::{RngExt, SeedableRng};

#[path = "common/position_rms.rs"]
mod position_rms;
use position_rms::position_rms;

/// Frames per side of the square.
const SIDE: usize = 100;
/// Step between frames [m].
const STEP_M: f64 = 0.5;

/// The true poses: `4 · SIDE` steps of [`STEP_M`] along x, turning 90° left at each corner.
fn square() -> Vec<Isometry3<f64>> {
    let mut truth = vec![Isometry3::identity()];
    for k in 1..=4 * SIDE {
        let turn = if k % SIDE == 0 {
            90f64.to_radians()
        } else {
            0.0
        };
        let step = Isometry3::from_parts(
            Translation3::new(STEP_M, 0.0, 0.0),
            UnitQuaternion::from_axis_angle(&Vector3::z_axis(), turn),
        );
        truth.push(truth[k - 1] * step);
    }
    truth
}

#[test]
fn true_loops_close_a_square_whose_odometry_drifts_by_metres() {
    let truth = square();
    let n = truth.len();
    // The graph's model at a 0.5 m voxel: 0.2° a step. The bias adds 0.05° and 0.1° to every
    // step, 20° and 40° over the square: 5× and 10× the model's random walk (√400 · 0.2° = 4°).
    for bias_deg in [0.05f64, 0.1] {
        let mut rng = rand_pcg::Pcg64Mcg::seed_from_u64(1);
        let mut odometry = vec![Isometry3::identity()];
        for k in 1..n {
            let noise = Isometry3::from_parts(
                Translation3::new(
                    rng.random_range(-0.01..0.01),
                    rng.random_range(-0.01..0.01),
                    rng.random_range(-0.01..0.01),
                ),
                UnitQuaternion::from_axis_angle(
                    &Vector3::z_axis(),
                    (bias_deg + rng.random_range(-0.05f64..0.05)).to_radians(),
                ),
            );
            odometry.push(odometry[k - 1] * truth[k - 1].inverse() * truth[k] * noise);
        }
        let end_error =
            (odometry[n - 1].translation.vector - truth[n - 1].translation.vector).norm();
        assert!(end_error > 10.0, "the drift is metres: {end_error} m");
        // The last 10 frames each seen again from the first 10, exactly.
        let loops: Vec<LoopEdge> = (0..10)
            .map(|i| LoopEdge {
                query: n - 1 - i,
                matched: i,
                match_from_query: truth[i].inverse() * truth[n - 1 - i],
                information: None,
            })
            .collect();
        let config = LoopConfig::for_voxel(0.5);
        let (optimised, solution) =
            optimize_trajectory(&odometry, &vec![Step::Registered; n], &loops, &config).unwrap();
        let solution = solution.expect("loops were given");
        let (before, after) = (
            position_rms(&odometry, &truth),
            position_rms(&optimised, &truth),
        );
        // The loop edges follow the n − 1 odometry edges.
        let weights = &solution.edge_weights[n - 1..];
        let min_weight = weights.iter().copied().fold(f64::INFINITY, f64::min);
        eprintln!(
            "bias {bias_deg}°/step: end error {end_error:.2} m, RMS {before:.3} -> {after:.3} m, \
             smallest loop weight {min_weight:.3}"
        );
        assert!(
            after < 0.5 && after < 0.1 * before,
            "bias {bias_deg}°: RMS {before} m -> {after} m"
        );
        // None is discounted as an outlier.
        assert_eq!(weights.len(), loops.len());
        assert!(
            weights.iter().all(|&w| w > 0.5),
            "bias {bias_deg}°: {weights:?}"
        );
    }
}
