//! The consensus loop on synthetic correspondences with a known transform.

use mireg::ransac::{
    ConsensusConfig, Levy, Prosac, RigidEstimator, Sampler, TruncatedLevy, Uniform, hypothesis_rng,
    run_consensus,
};
use nalgebra::{Isometry3, Point3, Translation3, UnitQuaternion, Vector3};
use rand::{RngExt, SeedableRng};
use rand_pcg::Pcg64Mcg;

struct Scene {
    source: Vec<Point3<f64>>,
    target: Vec<Point3<f64>>,
    is_inlier: Vec<bool>,
    gt: Isometry3<f64>,
}

/// `n` correspondences in rank order; inliers at the ranks in `inlier_ranks`, the rest map to random
/// points. Inliers carry `noise_m` uniform noise per axis.
fn scene(seed: u64, n: usize, inlier_ranks: &[usize], noise_m: f64) -> Scene {
    let mut rng = Pcg64Mcg::seed_from_u64(seed);
    let gt = Isometry3::from_parts(
        Translation3::new(1.0, -0.5, 0.3),
        UnitQuaternion::from_euler_angles(0.3, -0.2, 1.1),
    );
    let mut is_inlier = vec![false; n];
    for &r in inlier_ranks {
        is_inlier[r] = true;
    }
    let mut p = || Point3::from(Vector3::from_fn(|_, _| rng.random_range(-5.0..5.0)));
    let source: Vec<_> = (0..n).map(|_| p()).collect();
    let mut rng = Pcg64Mcg::seed_from_u64(seed ^ 0xabcdef);
    let target = source
        .iter()
        .zip(&is_inlier)
        .map(|(s, &inl)| {
            if inl {
                gt * s + Vector3::from_fn(|_, _| rng.random_range(-noise_m..=noise_m))
            } else {
                Point3::from(Vector3::from_fn(|_, _| rng.random_range(-5.0..5.0)))
            }
        })
        .collect();
    Scene {
        source,
        target,
        is_inlier,
        gt,
    }
}

fn errors(a: &Isometry3<f64>, b: &Isometry3<f64>) -> (f64, f64) {
    let d = a.inverse() * b;
    (d.rotation.angle().to_degrees(), d.translation.vector.norm())
}

#[test]
fn recovers_transform_with_95_percent_outliers() {
    let n = 2000;
    let mut rng = Pcg64Mcg::seed_from_u64(1);
    let mut ranks: Vec<usize> = (0..n).collect();
    // 100 inliers at random ranks: the uninformed case.
    for i in 0..100 {
        let j = rng.random_range(i..n);
        ranks.swap(i, j);
    }
    let s = scene(3, n, &ranks[..100], 0.005);
    let est = RigidEstimator::new(&s.source, &s.target);
    let config = ConsensusConfig {
        inlier_threshold: 0.03,
        max_hypotheses: 200_000,
        seed: 9,
        ..Default::default()
    };
    let result = run_consensus(&Uniform::new(n), &est, &config);
    let model = result.model.expect("a model");
    let (rot_deg, trans_m) = errors(&s.gt, &model);
    assert!(
        rot_deg < 0.2 && trans_m < 0.01,
        "error {rot_deg}° {trans_m} m"
    );
    let true_found = result.inliers.iter().filter(|&&i| s.is_inlier[i]).count();
    assert!(true_found >= 98, "found {true_found} of 100 true inliers");
    assert!(
        result.num_inliers <= 105,
        "{} inliers claimed",
        result.num_inliers
    );
    assert!(result.converged);
    assert!(result.prerejected > 0 && result.verified > 0);
    assert_eq!(
        result.hypotheses,
        result.prerejected + result.degenerate + result.verified
    );
}

#[test]
fn no_consensus_is_a_value() {
    // Pure outliers: whatever model wins supports only a handful of random points.
    let n = 300;
    let s = scene(4, n, &[], 0.0);
    let est = RigidEstimator::new(&s.source, &s.target);
    let config = ConsensusConfig {
        inlier_threshold: 0.01,
        max_hypotheses: 2000,
        ..Default::default()
    };
    let r = run_consensus(&Uniform::new(n), &est, &config);
    assert!(r.num_inliers < 10);
    assert!(!r.converged);
    // Too few correspondences for a minimal sample.
    let few = scene(4, 2, &[0, 1], 0.0);
    let est = RigidEstimator::new(&few.source, &few.target);
    let r = run_consensus(&Uniform::new(2), &est, &config);
    assert!(r.model.is_none() && r.hypotheses == 0);
}

/// Hypotheses up to and including the first all-inlier sample, drawn exactly as the loop draws them.
fn first_clean(sampler: &impl Sampler, inlier: &[bool], seed: u64, cap: u64) -> u64 {
    let mut buf = [0usize; 3];
    for h in 0..cap {
        sampler.draw(h, &mut hypothesis_rng(seed, h), &mut buf);
        if buf.iter().all(|&i| inlier[i]) {
            return h + 1;
        }
    }
    cap
}

#[test]
fn levy_needs_far_fewer_hypotheses_than_uniform_when_ranking_is_informative() {
    let n = 1000;
    let levy_inliers = Levy::new(TruncatedLevy::new(-10.0, 1.0, 100.0).unwrap(), n).unwrap();
    let levy = Levy::new(TruncatedLevy::new(-1.0, 1.0, 100.0).unwrap(), n).unwrap();
    let uniform = Uniform::new(n);
    let (mut lv, mut un) = (Vec::new(), Vec::new());
    for seed in 0..200u64 {
        // 10 % inliers concentrated at the top ranks, as in the paper's simulation.
        let mut rng = Pcg64Mcg::seed_from_u64(seed);
        let mut inlier = vec![false; n];
        let mut placed = 0;
        while placed < 100 {
            let i = levy_inliers.draw_rank(&mut rng);
            placed += !inlier[i] as usize;
            inlier[i] = true;
        }
        lv.push(first_clean(&levy, &inlier, seed, 1_000_000));
        un.push(first_clean(&uniform, &inlier, seed, 1_000_000));
    }
    lv.sort_unstable();
    un.sort_unstable();
    let (ml, mu) = (lv[100], un[100]);
    // Uniform's expectation is 1/(0.1·0.099·0.098) ≈ 1030; require a 5× margin for Lévy.
    assert!(mu > 300, "uniform median {mu} implausibly small");
    assert!(ml * 5 < mu, "Lévy median {ml} vs uniform median {mu}");
}

#[test]
fn informed_sampler_finds_the_model_earlier_in_the_loop() {
    let n = 1000;
    let s = scene(21, n, &(0..60).collect::<Vec<_>>(), 0.002);
    let est = RigidEstimator::new(&s.source, &s.target);
    let config = ConsensusConfig {
        inlier_threshold: 0.02,
        max_hypotheses: 100_000,
        seed: 2,
        ..Default::default()
    };
    let levy = Levy::new(TruncatedLevy::new(-1.0, 1.0, 100.0).unwrap(), n).unwrap();
    let a = run_consensus(&levy, &est, &config);
    let b = run_consensus(&Uniform::new(n), &est, &config);
    let p = run_consensus(&Prosac::new(n, 3, 200_000).unwrap(), &est, &config);
    for r in [&a, &b, &p] {
        let (rot, trans) = errors(&s.gt, r.model.as_ref().unwrap());
        assert!(rot < 0.2 && trans < 0.01);
    }
    // The inliers hold the top ranks: Lévy finds the model sooner and, since its law puts most mass on
    // them, its adaptive termination also stops sooner.
    assert!(
        a.best_found_at < b.best_found_at,
        "{:?} vs {:?}",
        a.best_found_at,
        b.best_found_at
    );
    assert!(
        a.hypotheses * 10 < b.hypotheses,
        "Lévy {} vs uniform {}",
        a.hypotheses,
        b.hypotheses
    );
    assert!(a.converged && b.converged);
}

fn in_pool<T: Send>(threads: usize, f: impl FnOnce() -> T + Send) -> T {
    rayon::ThreadPoolBuilder::new()
        .num_threads(threads)
        .build()
        .unwrap()
        .install(f)
}

#[test]
fn bit_identical_on_one_and_two_threads() {
    let n = 1500;
    let mut rng = Pcg64Mcg::seed_from_u64(5);
    let ranks: Vec<usize> = (0..n)
        .filter(|_| rng.random_range(0.0..1.0) < 0.15)
        .collect();
    let s = scene(5, n, &ranks, 0.01);
    let est = RigidEstimator::new(&s.source, &s.target);
    for seed in [0u64, 1, 77] {
        let config = ConsensusConfig {
            inlier_threshold: 0.04,
            seed,
            ..Default::default()
        };
        let levy = Levy::new(TruncatedLevy::new(-50.0, 1.0, 100.0).unwrap(), n).unwrap();
        let one = in_pool(1, || run_consensus(&levy, &est, &config));
        let two = in_pool(2, || run_consensus(&levy, &est, &config));
        let m1 = one.model.unwrap().to_homogeneous();
        let m2 = two.model.unwrap().to_homogeneous();
        let bits = |m: &nalgebra::Matrix4<f64>| m.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
        assert_eq!(bits(&m1), bits(&m2), "seed {seed}");
        assert_eq!(one.inliers, two.inliers);
        assert_eq!(
            (
                one.hypotheses,
                one.prerejected,
                one.verified,
                one.best_found_at
            ),
            (
                two.hypotheses,
                two.prerejected,
                two.verified,
                two.best_found_at
            )
        );
    }
}

#[test]
fn prosac_termination_stops_early_on_ranked_inliers() {
    // 80 inliers in the top 100 ranks of 1500: PROSAC's non-randomness + maximality rule (Chum &
    // Matas 2005, Sec. 2.3) may stop long before the uniform rule would (w = 80/1500).
    use mireg::ransac::Termination;
    let n = 1500;
    let ranks: Vec<usize> = (0..100).filter(|r| r % 5 != 0).collect();
    let s = scene(31, n, &ranks, 0.002);
    let est = RigidEstimator::new(&s.source, &s.target);
    let base = ConsensusConfig {
        inlier_threshold: 0.02,
        max_hypotheses: 100_000,
        seed: 4,
        ..Default::default()
    };
    let prosac = Prosac::new(n, 3, 200_000).unwrap();
    let adaptive = run_consensus(&prosac, &est, &base);
    let with_rule = run_consensus(
        &prosac,
        &est,
        &ConsensusConfig {
            termination: Termination::Prosac {
                beta: 0.05,
                psi: 0.05,
            },
            ..base.clone()
        },
    );
    for r in [&adaptive, &with_rule] {
        let (rot, trans) = errors(&s.gt, r.model.as_ref().unwrap());
        assert!(rot < 0.2 && trans < 0.01);
        assert!(r.converged);
    }
    assert!(
        with_rule.hypotheses * 10 < adaptive.hypotheses,
        "PROSAC rule {} vs adaptive {}",
        with_rule.hypotheses,
        adaptive.hypotheses
    );
}
