//! Criterion benchmarks of the MI-RANSAC core. Figures and machine: docs/BENCHMARKS_ARCHIVE.md.
//!
//! `cargo bench --bench core`; single-threaded figures with `RAYON_NUM_THREADS=1`.

use criterion::{BenchmarkId, Criterion, Throughput, criterion_group, criterion_main};
use mireg::ransac::estimator::Estimator;
use mireg::ransac::{
    ConsensusConfig, Levy, RigidEstimator, Sampler, TruncatedLevy, Uniform, hypothesis_rng,
    run_consensus,
};
use nalgebra::{Isometry3, Point3, Translation3, UnitQuaternion, Vector3};
use rand::{RngExt, SeedableRng};
use std::hint::black_box;

fn levy_draws(c: &mut Criterion) {
    let mut g = c.benchmark_group("levy_draw");
    const DRAWS: u64 = 100_000;
    g.throughput(Throughput::Elements(DRAWS));
    for mu in [-1.0, -1e6] {
        let sampler = Levy::new(TruncatedLevy::new(mu, 1.0, 100.0).unwrap(), 5000).unwrap();
        g.bench_function(BenchmarkId::new("rank", mu), |b| {
            let mut rng = hypothesis_rng(1, 0);
            b.iter(|| {
                let mut acc = 0usize;
                for _ in 0..DRAWS {
                    acc = acc.wrapping_add(sampler.draw_rank(&mut rng));
                }
                black_box(acc)
            })
        });
        let dist = *sampler.distribution();
        g.bench_function(BenchmarkId::new("continuous_inverse_cdf", mu), |b| {
            let mut rng = hypothesis_rng(1, 0);
            b.iter(|| {
                let mut acc = 0.0;
                for _ in 0..DRAWS {
                    acc += dist.sample(&mut rng);
                }
                black_box(acc)
            })
        });
    }
    let sampler = Levy::new(TruncatedLevy::new(-50.0, 1.0, 100.0).unwrap(), 5000).unwrap();
    g.throughput(Throughput::Elements(DRAWS));
    g.bench_function("sample_of_3_with_fresh_rng", |b| {
        let mut buf = [0usize; 3];
        b.iter(|| {
            for h in 0..DRAWS {
                sampler.draw(h, &mut hypothesis_rng(1, h), &mut buf);
                black_box(&buf);
            }
        })
    });
    g.finish();
}

fn scene(n: usize) -> (Vec<Point3<f64>>, Vec<Point3<f64>>) {
    let mut rng = rand_pcg::Pcg64Mcg::seed_from_u64(3);
    let gt = Isometry3::from_parts(
        Translation3::new(0.5, 0.1, -0.2),
        UnitQuaternion::from_euler_angles(0.1, 0.2, 0.3),
    );
    let src: Vec<_> = (0..n)
        .map(|_| Point3::from(Vector3::from_fn(|_, _| rng.random_range(-5.0..5.0))))
        .collect();
    let tgt = src
        .iter()
        .enumerate()
        .map(|(i, p)| {
            if i % 10 == 0 {
                gt * p
            } else {
                Point3::from(Vector3::from_fn(|_, _| rng.random_range(-5.0..5.0)))
            }
        })
        .collect();
    (src, tgt)
}

fn verification(c: &mut Criterion) {
    let mut g = c.benchmark_group("verify");
    for n in [1000usize, 5000] {
        let (src, tgt) = scene(n);
        let est = RigidEstimator::new(&src, &tgt);
        let model = Isometry3::from_parts(
            Translation3::new(0.5, 0.1, -0.2),
            UnitQuaternion::from_euler_angles(0.1, 0.2, 0.3),
        );
        g.throughput(Throughput::Elements(n as u64));
        g.bench_function(BenchmarkId::new("score_one_hypothesis", n), |b| {
            b.iter(|| black_box(est.score(black_box(&model), 0.05 * 0.05)))
        });
        // Whole loop at a fixed budget of 1000 hypotheses (confidence ~1 so it never stops early).
        for (name, sim) in [
            ("loop_1000_prerejection", 0.9),
            ("loop_1000_no_prerejection", 0.0),
        ] {
            let est = RigidEstimator::new(&src, &tgt).edge_similarity(sim);
            let config = ConsensusConfig {
                inlier_threshold: 0.05,
                max_hypotheses: 1000,
                confidence: 1.0 - 1e-15,
                lo_iterations: 0,
                ..Default::default()
            };
            g.throughput(Throughput::Elements(1000));
            g.bench_function(BenchmarkId::new(name, n), |b| {
                b.iter(|| black_box(run_consensus(&Uniform::new(n), &est, &config).verified))
            });
        }
    }
    g.finish();
}

criterion_group!(benches, levy_draws, verification);
criterion_main!(benches);
