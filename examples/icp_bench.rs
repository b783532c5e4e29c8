//! Timing of point-to-plane ICP on a synthetic box corner + sphere scene.
//!
//! `cargo run --release --example icp_bench -- [spacing_m]` (default 0.01 m ≈ 110k target
//! points; the source is every third point with 2 mm Gaussian noise, seen from a pose 25° / 46 cm
//! away, and ICP starts 5° / 10 cm off the truth).

use std::time::Instant;

use mireg::refine::{IcpConfig, IcpTarget, evaluate_registration, registration_icp_point_to_plane};
use nalgebra::{Isometry3, Point3, Translation3, Unit, UnitQuaternion, Vector3};
use rand::SeedableRng;
use rand_distr::Distribution;
use rand_pcg::Pcg64Mcg;

fn scene(spacing: f64) -> (Vec<Point3<f64>>, Vec<Vector3<f64>>) {
    let offset = Vector3::new(-1.0, -1.0, -0.5);
    let (mut points, mut normals) = (Vec::new(), Vec::new());
    let steps = |len: f64| (0..(len / spacing) as usize).map(move |i| (i as f64 + 0.5) * spacing);
    for a in steps(2.0) {
        for b in steps(2.0) {
            points.push(Point3::new(a, b, 0.0) + offset);
            normals.push(Vector3::z());
        }
        for b in steps(1.5) {
            points.push(Point3::new(0.0, a, b) + offset);
            normals.push(Vector3::x());
            points.push(Point3::new(a, 0.0, b) + offset);
            normals.push(Vector3::y());
        }
    }
    let centre = Point3::new(1.2, 1.1, 0.5) + offset;
    let radius = 0.35;
    let n = (4.0 * std::f64::consts::PI * radius * radius / (spacing * spacing)) as usize;
    let golden = std::f64::consts::PI * (3.0 - 5f64.sqrt());
    for i in 0..n {
        let z = 1.0 - 2.0 * (i as f64 + 0.5) / n as f64;
        let r = (1.0 - z * z).sqrt();
        let phi = golden * i as f64;
        let dir = Vector3::new(r * phi.cos(), r * phi.sin(), z);
        points.push(centre + radius * dir);
        normals.push(dir);
    }
    (points, normals)
}

fn gaussian(rng: &mut Pcg64Mcg) -> f64 {
    rand_distr::StandardNormal.sample(rng)
}

fn main() {
    let spacing: f64 = std::env::args()
        .nth(1)
        .map_or(0.01, |a| a.parse().expect("spacing_m"));
    let (points, normals) = scene(spacing);
    let truth = Isometry3::from_parts(
        Translation3::new(0.4, -0.2, 0.1),
        UnitQuaternion::from_axis_angle(
            &Unit::new_normalize(Vector3::new(0.3, -0.5, 0.8)),
            25f64.to_radians(),
        ),
    );
    let mut rng = Pcg64Mcg::seed_from_u64(5);
    let source: Vec<_> = points
        .iter()
        .step_by(3)
        .map(|p| {
            let noise = Vector3::new(gaussian(&mut rng), gaussian(&mut rng), gaussian(&mut rng));
            truth.inverse() * (p + 0.002 * noise)
        })
        .collect();
    let start = Instant::now();
    let target = IcpTarget::new(&points, &normals).expect("target");
    let build_ms = start.elapsed().as_secs_f64() * 1e3;
    let init = truth
        * Isometry3::from_parts(
            Translation3::new(0.06, -0.05, 0.06),
            UnitQuaternion::from_axis_angle(
                &Unit::new_normalize(Vector3::new(1.0, 1.0, 0.2)),
                5f64.to_radians(),
            ),
        );
    let config = IcpConfig::new(0.2).max_iterations(50);
    let mut best = f64::INFINITY;
    let mut result = None;
    for _ in 0..10 {
        let start = Instant::now();
        result =
            Some(registration_icp_point_to_plane(&source, &target, &init, &config).expect("icp"));
        best = best.min(start.elapsed().as_secs_f64() * 1e3);
    }
    let result = result.expect("ran");
    let mut eval_ms = f64::INFINITY;
    for _ in 0..10 {
        let start = Instant::now();
        let e = evaluate_registration(&source, &target, &init, 0.2).expect("evaluate");
        eval_ms = eval_ms.min(start.elapsed().as_secs_f64() * 1e3);
        assert!(e.fitness > 0.5);
    }
    let delta = truth.inverse() * result.target_from_source;
    println!(
        "threads {} | target {} pts (kd-tree build {build_ms:.1} ms) | source {} pts",
        rayon::current_num_threads(),
        points.len(),
        source.len()
    );
    println!(
        "evaluate_registration at the initial pose (nearest-neighbour pass only) {eval_ms:.2} ms"
    );
    println!(
        "ICP {:.1} ms, {} iterations ({:.2} ms/iteration), converged {}, fitness {:.4}, rmse {:.2} mm, error {:.4} deg / {:.3} mm",
        best,
        result.iterations,
        best / (result.iterations + 1) as f64,
        result.converged,
        result.fitness,
        result.inlier_rmse_m * 1e3,
        delta.rotation.angle().to_degrees(),
        delta.translation.vector.norm() * 1e3
    );
}
