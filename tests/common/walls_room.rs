//! A room of three walls (12 m apart, 3 m high) and a floor, for tests that register or deskew
//! scans of it.

use nalgebra::Point3;
use rand::{RngExt, SeedableRng};

/// `n` points drawn uniformly on the walls at y = ±6 m and x = 6 m (z in −1..2 m) and on the
/// floor at z = −1 m, from `seed`.
pub fn walls_room(n: usize, seed: u64) -> Vec<Point3<f64>> {
    let mut rng = rand_pcg::Pcg64Mcg::seed_from_u64(seed);
    (0..n)
        .map(|_| {
            let (u, v): (f64, f64) = (rng.random_range(-6.0..6.0), rng.random_range(-1.0..2.0));
            match rng.random_range(0..4u32) {
                0 => Point3::new(u, 6.0, v),
                1 => Point3::new(u, -6.0, v),
                2 => Point3::new(6.0, u, v),
                _ => Point3::new(u, rng.random_range(-6.0..6.0), -1.0),
            }
        })
        .collect()
}
