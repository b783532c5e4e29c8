//! A curved room scene sampled afresh for every seed (integration tests that register two
//! independent samplings of the same surfaces).

use nalgebra::{Point3, Vector3};
use rand::{RngExt, SeedableRng};
use rand_distr::{Distribution, UnitSphere};

/// `n` points on a room corner (floor and two walls, 4 m) with a ball and a box-shaped block:
/// a fresh sample of the same surfaces for every seed.
pub fn scene(n: usize, seed: u64) -> Vec<Point3<f64>> {
    let mut rng = rand_pcg::Pcg64::seed_from_u64(seed);
    (0..n)
        .map(|_| {
            let (u, v): (f64, f64) = (rng.random_range(0.0..4.0), rng.random_range(0.0..2.5));
            match rng.random_range(0..6u32) {
                0 | 1 => Point3::new(u, rng.random_range(0.0..4.0), 0.0),
                2 => Point3::new(u, 0.0, v),
                3 => Point3::new(0.0, u, v),
                4 => {
                    let d: [f64; 3] = UnitSphere.sample(&mut rng);
                    Point3::new(2.5, 1.5, 0.7) + 0.6 * Vector3::from(d)
                }
                _ => {
                    // A tilted cylinder, radius 0.3 m, axis along (0.2, 1, 0.3).
                    let a = rng.random_range(0.0..std::f64::consts::TAU);
                    let axis = Vector3::new(0.2, 1.0, 0.3).normalize();
                    let e1 = axis.cross(&Vector3::z()).normalize();
                    let e2 = axis.cross(&e1);
                    Point3::new(1.2, 2.8, 1.0)
                        + rng.random_range(-0.8..0.8) * axis
                        + 0.3 * (a.cos() * e1 + a.sin() * e2)
                }
            }
        })
        .collect()
}
