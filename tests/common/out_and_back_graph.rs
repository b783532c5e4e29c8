//! The pose graph of a synthetic out-and-back, for tests of the loop back-end alone: true poses
//! along a gentle S-bend, an odometry with noise (and steps made wrong on request), and the true
//! loops between the way back and the way out, each seeded.

use mireg::loops::LoopEdge;
use mireg::odometry::uncertainty::diagonal_information;
use nalgebra::{Isometry3, Translation3, UnitQuaternion, Vector3};
use rand::SeedableRng;
use rand_distr::{Distribution, StandardNormal};
use rand_pcg::Pcg64Mcg;

/// Places along the route, 0.5 m apart; the way out visits the even ones, the way back the odd
/// ones.
pub const PLACES: usize = 120;
/// Noise of a good odometry step (each axis): translation \[m\] and rotation \[deg\].
pub const STEP_SIGMA: (f64, f64) = (0.01, 0.1);
/// Noise of a loop's relative pose (each axis).
pub const LOOP_SIGMA: (f64, f64) = (0.02, 0.2);

/// The route out and back: (place index of each frame, the true poses).
pub fn route() -> (Vec<usize>, Vec<Isometry3<f64>>) {
    let place = |i: usize| {
        let s = i as f64 * 0.5;
        Isometry3::from_parts(
            Translation3::new(s, 8.0 * (1.0 - (s / 15.0).cos()), 0.0),
            UnitQuaternion::from_axis_angle(&Vector3::z_axis(), 0.6 * (s / 15.0).sin()),
        )
    };
    let mut order: Vec<usize> = (0..PLACES).step_by(2).collect();
    order.extend((1..PLACES).step_by(2).rev());
    let truth = order.iter().map(|&i| place(i)).collect();
    (order, truth)
}

/// A random pose with the given standard deviations per axis (translation \[m\], rotation
/// \[deg\]).
pub fn noise(rng: &mut Pcg64Mcg, (sigma_m, sigma_deg): (f64, f64)) -> Isometry3<f64> {
    let mut g = || -> f64 { StandardNormal.sample(rng) };
    let t = Vector3::new(g(), g(), g()) * sigma_m;
    let r = Vector3::new(g(), g(), g()) * sigma_deg.to_radians();
    Isometry3::from_parts(Translation3::from(t), UnitQuaternion::from_scaled_axis(r))
}

/// The odometry: true steps with noise, and `broken` steps (frame, translation error \[m\],
/// rotation error \[deg\]) made wrong on top.
pub fn odometry(
    truth: &[Isometry3<f64>],
    broken: &[(usize, f64, f64)],
    seed: u64,
) -> Vec<Isometry3<f64>> {
    let mut rng = Pcg64Mcg::seed_from_u64(seed);
    let mut poses = vec![truth[0]];
    for k in 1..truth.len() {
        let mut step = truth[k - 1].inverse() * truth[k] * noise(&mut rng, STEP_SIGMA);
        if let Some(&(_, m, deg)) = broken.iter().find(|b| b.0 == k) {
            step *= Isometry3::from_parts(
                Translation3::new(0.6 * m, 0.8 * m, 0.0),
                UnitQuaternion::from_axis_angle(&Vector3::z_axis(), deg.to_radians()),
            );
        }
        poses.push(poses[k - 1] * step);
    }
    poses
}

/// True loops: every frame on the way back matched to the frames of the way out at its two
/// neighbouring places (as the candidate search pairs them: two per query), at least 5 frames
/// apart, with loop-sized noise and the information of that noise.
pub fn true_loops(order: &[usize], truth: &[Isometry3<f64>], seed: u64) -> Vec<LoopEdge> {
    let mut rng = Pcg64Mcg::seed_from_u64(seed);
    let frame_of = |place: usize| order.iter().position(|&p| p == place);
    let information = diagonal_information(LOOP_SIGMA.0, LOOP_SIGMA.1);
    let mut loops = Vec::new();
    for (q, &place) in order.iter().enumerate().filter(|(_, p)| *p % 2 == 1) {
        for neighbour in [place - 1, place + 1] {
            if let Some(m) = frame_of(neighbour).filter(|&m| m + 5 <= q) {
                loops.push(LoopEdge {
                    query: q,
                    matched: m,
                    match_from_query: truth[m].inverse() * truth[q] * noise(&mut rng, LOOP_SIGMA),
                    information: Some(information),
                });
            }
        }
    }
    loops
}
