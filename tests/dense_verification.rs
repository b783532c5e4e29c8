//! Dense verification (`DenseRigidEstimator`): the failure mode it fixes, exactness of its
//! nearest-neighbour grid and of its early stop, and thread-count independence.

use mireg::geometry::RadiusGrid;
use mireg::ransac::{
    Consensus, ConsensusConfig, DenseRigidEstimator, Estimator, OverlapTarget, RigidEstimator,
    Score, Scoring, Uniform, run_consensus,
};
use mireg::refine::icp::{IcpTarget, evaluate_registration};
use nalgebra::{Isometry3, Point3, Translation3, UnitQuaternion, Vector3};
use rand::{RngExt, SeedableRng};
use rand_pcg::Pcg64Mcg;

const TAU: f64 = 0.03;

fn random_points(rng: &mut Pcg64Mcg, n: usize) -> Vec<Point3<f64>> {
    (0..n)
        .map(|_| Point3::from(Vector3::from_fn(|_, _| rng.random_range(-0.5..0.5))))
        .collect()
}

/// A blob of 800 source points; the target holds the ground truth image of the first 480 (60 %
/// overlap) plus 300 points of its own. 200 correspondences: 20 true ones, 40 that agree on a wrong
/// pose `wrong` (coincidental matches, as FPFH produces on a symmetric object), 140 random.
struct Scene {
    source_cloud: Vec<Point3<f64>>,
    target_cloud: Vec<Point3<f64>>,
    src: Vec<Point3<f64>>,
    tgt: Vec<Point3<f64>>,
    gt: Isometry3<f64>,
    wrong: Isometry3<f64>,
}

fn scene(seed: u64) -> Scene {
    let mut rng = Pcg64Mcg::seed_from_u64(seed);
    let gt = Isometry3::from_parts(
        Translation3::new(0.2, -0.1, 0.05),
        UnitQuaternion::from_euler_angles(0.4, -0.3, 1.2),
    );
    let wrong = Isometry3::from_parts(
        Translation3::new(-0.1, 0.3, 0.0),
        UnitQuaternion::from_euler_angles(2.5, 0.1, -0.7),
    );
    let source_cloud = random_points(&mut rng, 800);
    let mut target_cloud: Vec<Point3<f64>> = source_cloud[..480].iter().map(|p| gt * p).collect();
    target_cloud.extend(random_points(&mut rng, 300));
    let (mut src, mut tgt) = (Vec::new(), Vec::new());
    for k in 0..200 {
        // True matches pair overlapping points with their images.
        let i = rng.random_range(0..if k < 20 { 480 } else { 800 });
        let p = source_cloud[i];
        src.push(p);
        tgt.push(if k < 20 {
            gt * p
        } else if k < 60 {
            wrong * p
        } else {
            target_cloud[rng.random_range(0..target_cloud.len())]
        });
    }
    Scene {
        source_cloud,
        target_cloud,
        src,
        tgt,
        gt,
        wrong,
    }
}

fn config() -> ConsensusConfig {
    ConsensusConfig {
        inlier_threshold: TAU,
        max_hypotheses: 200_000,
        seed: 7,
        ..Default::default()
    }
}

fn pose_distance(a: &Isometry3<f64>, b: &Isometry3<f64>) -> (f64, f64) {
    let d = a.inverse() * b;
    (d.rotation.angle().to_degrees(), d.translation.vector.norm())
}

#[test]
fn dense_overlap_picks_the_true_pose_where_the_correspondence_count_picks_the_wrong_one() {
    let s = scene(1);
    let rigid = RigidEstimator::new(&s.src, &s.tgt).edge_similarity(0.0);
    let sampler = Uniform::new(s.src.len());
    let by_count = run_consensus(&sampler, &rigid, &config());
    let tree = IcpTarget::points_only(&s.target_cloud).unwrap();
    let overlap = OverlapTarget::new(&s.target_cloud, TAU, || Ok(&tree)).unwrap();
    let dense = DenseRigidEstimator::new(rigid, &s.source_cloud, &overlap);
    let by_overlap = run_consensus(&sampler, &dense, &config());

    // The oracle: the scene's two poses and what each criterion says about them.
    assert!(rigid.score(&s.wrong, TAU * TAU).inliers > rigid.score(&s.gt, TAU * TAU).inliers);
    assert!(dense.score(&s.gt, TAU * TAU).inliers > 2 * dense.score(&s.wrong, TAU * TAU).inliers);

    let (re, te) = pose_distance(&s.wrong, &by_count.model.unwrap());
    assert!(
        re < 1.0 && te < 0.01,
        "count: {re}° {te} m from the wrong pose"
    );
    let (re, te) = pose_distance(&s.gt, &by_overlap.model.unwrap());
    assert!(
        re < 1.0 && te < 0.01,
        "overlap: {re}° {te} m from the truth"
    );
    // Reported inliers stay correspondence inliers: the 20 true ones (plus any random match
    // that happens to fit).
    assert!(
        (20..30).contains(&by_overlap.num_inliers),
        "{}",
        by_overlap.num_inliers
    );
}

/// Brute force: source points whose nearest target point is strictly within τ, Σ min(d², τ²).
fn brute_force(
    model: &Isometry3<f64>,
    source: &[Point3<f64>],
    target: &[Point3<f64>],
) -> (u32, f64) {
    let mut inliers = 0;
    let mut cost = 0.0;
    for p in source {
        let q = model * p;
        let d = target
            .iter()
            .map(|t| (q - t).norm_squared())
            .min_by(f64::total_cmp)
            .unwrap();
        inliers += (d < TAU * TAU) as u32;
        cost += d.min(TAU * TAU);
    }
    (inliers, cost)
}

#[test]
fn grid_and_kd_tree_scores_equal_brute_force_and_open3d_fitness() {
    let s = scene(2);
    let rigid = RigidEstimator::new(&s.src, &s.tgt);
    let tree = IcpTarget::points_only(&s.target_cloud).unwrap();
    let grid = OverlapTarget::Grid(Box::new(
        RadiusGrid::new(&s.target_cloud, TAU, usize::MAX)
            .unwrap()
            .unwrap(),
    ));
    let kd = OverlapTarget::Tree(&tree);
    let mut rng = Pcg64Mcg::seed_from_u64(3);
    let mut models = vec![s.gt, s.wrong, Isometry3::identity()];
    for _ in 0..30 {
        // Around the truth (partial overlaps) and anywhere.
        let small = Isometry3::from_parts(
            Translation3::from(Vector3::from_fn(|_, _| rng.random_range(-0.03..0.03))),
            UnitQuaternion::from_scaled_axis(Vector3::from_fn(|_, _| {
                rng.random_range(-0.05..0.05)
            })),
        );
        models.push(small * s.gt);
        models.push(Isometry3::from_parts(
            Translation3::from(Vector3::from_fn(|_, _| rng.random_range(-0.3..0.3))),
            UnitQuaternion::from_scaled_axis(Vector3::from_fn(|_, _| rng.random_range(-3.0..3.0))),
        ));
    }
    let mut seen_partial = false;
    for m in &models {
        let (inliers, cost) = brute_force(m, &s.source_cloud, &s.target_cloud);
        seen_partial |= inliers > 100 && inliers < 470;
        for target in [&grid, &kd] {
            let score =
                DenseRigidEstimator::new(rigid, &s.source_cloud, target).score(m, TAU * TAU);
            assert_eq!(score.inliers, inliers);
            assert!(
                (score.cost - cost).abs() <= 1e-12 * cost.max(1.0),
                "{} vs {cost}",
                score.cost
            );
        }
        let e = evaluate_registration(&s.source_cloud, &tree, m, TAU).unwrap();
        assert_eq!(e.num_inliers, inliers as usize);
    }
    assert!(seen_partial);
}

/// Forwards everything but the early stop.
struct NoEarlyStop<'a>(DenseRigidEstimator<'a>);

impl Estimator for NoEarlyStop<'_> {
    type Model = Isometry3<f64>;
    fn min_samples(&self) -> usize {
        self.0.min_samples()
    }
    fn num_items(&self) -> usize {
        self.0.num_items()
    }
    fn accept_sample(&self, sample: &[usize]) -> bool {
        self.0.accept_sample(sample)
    }
    fn estimate(&self, sample: &[usize]) -> Option<Isometry3<f64>> {
        self.0.estimate(sample)
    }
    fn residual_sq(&self, model: &Isometry3<f64>, i: usize) -> f64 {
        self.0.residual_sq(model, i)
    }
    fn score(&self, model: &Isometry3<f64>, threshold_sq: f64) -> Score {
        self.0.score(model, threshold_sq)
    }
    fn refit(&self, inliers: &[usize]) -> Option<Isometry3<f64>> {
        self.0.refit(inliers)
    }
}

#[test]
fn early_stop_never_changes_the_result_and_threads_do_not_either() {
    let s = scene(4);
    let rigid = RigidEstimator::new(&s.src, &s.tgt).edge_similarity(0.0);
    let tree = IcpTarget::points_only(&s.target_cloud).unwrap();
    let overlap = OverlapTarget::new(&s.target_cloud, TAU, || Ok(&tree)).unwrap();
    assert!(matches!(overlap, OverlapTarget::Grid(_)));
    let dense = DenseRigidEstimator::new(rigid, &s.source_cloud, &overlap);
    let sampler = Uniform::new(s.src.len());
    for scoring in [Scoring::InlierCount, Scoring::Msac] {
        let c = ConsensusConfig {
            scoring,
            max_hypotheses: 3000,
            ..config()
        };
        let run = |threads: usize, early: bool| -> Consensus<Isometry3<f64>> {
            rayon::ThreadPoolBuilder::new()
                .num_threads(threads)
                .build()
                .unwrap()
                .install(|| {
                    if early {
                        run_consensus(&sampler, &dense, &c)
                    } else {
                        run_consensus(&sampler, &NoEarlyStop(dense), &c)
                    }
                })
        };
        let reference = run(1, false);
        assert!(reference.model.is_some());
        // The early stop does happen here: the best model's bound rejects most hypotheses.
        let best = Score {
            inliers: dense.score(&s.gt, TAU * TAU).inliers,
            cost: dense.score(&s.gt, TAU * TAU).cost,
        };
        assert_eq!(
            dense.score_unless_worse(&s.wrong, TAU * TAU, Some(&best), scoring),
            None
        );
        assert_eq!(
            dense.score_unless_worse(&s.gt, TAU * TAU, None, scoring),
            Some(dense.score(&s.gt, TAU * TAU))
        );
        assert_eq!(run(1, true), reference, "{scoring:?}");
        assert_eq!(run(2, true), reference, "{scoring:?}");
        assert_eq!(run(3, true), reference, "{scoring:?}");
        if scoring == Scoring::InlierCount {
            // Counting only (first target point within τ, no nearest search): same counts, so
            // the same consensus, on any thread count.
            let counting = dense.scoring(Scoring::InlierCount);
            for m in [&s.gt, &s.wrong] {
                assert_eq!(
                    counting.score(m, TAU * TAU).inliers,
                    dense.score(m, TAU * TAU).inliers
                );
            }
            for threads in [1, 2, 3] {
                let pool = rayon::ThreadPoolBuilder::new()
                    .num_threads(threads)
                    .build()
                    .unwrap();
                let got = pool.install(|| run_consensus(&sampler, &counting, &c));
                assert_eq!(got, reference, "counting only, {threads} threads");
            }
        }
    }
}
