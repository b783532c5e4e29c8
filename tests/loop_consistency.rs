//! Loops judged jointly (`mireg::loops::judge_loops`, PCM through the odometry): a look-alike
//! loop 50 m off and a subtler one 1.7 m off are dropped while every true loop survives, across
//! odometry steps broken by 0.5–2 m and 2–5° (one marked weak by its σ, as a failed frame's
//! step is; two unflagged, with a good step's information). Oracles: the graph of the true loops
//! alone, a brute-force maximum clique, and χ²(6) for the cycle errors of true loops.

use mireg::loops::{
    LoopConfig, LoopDecision, LoopEdge, PairwiseConsistency, Step, judge_loops, maximum_clique,
    optimize_trajectory,
};
use mireg::odometry::uncertainty::diagonal_information;
use nalgebra::{Isometry3, Translation3, UnitQuaternion, Vector3};
use rand::{RngExt, SeedableRng};
use rand_pcg::Pcg64Mcg;

#[path = "common/position_rms.rs"]
mod position_rms;
use position_rms::position_rms;

#[path = "common/out_and_back_graph.rs"]
mod out_and_back_graph;
use out_and_back_graph::{LOOP_SIGMA, STEP_SIGMA, odometry, route, true_loops};

/// A look-alike: frame `q` registered onto frame `m` as if they stood `offset` apart (what a
/// revisit would look like), where the truth has them `truth[m]⁻¹ truth[q]` apart.
fn false_loop(q: usize, m: usize, offset: Isometry3<f64>) -> LoopEdge {
    LoopEdge {
        query: q,
        matched: m,
        match_from_query: offset,
        information: Some(diagonal_information(LOOP_SIGMA.0, LOOP_SIGMA.1)),
    }
}

#[test]
fn false_loops_are_dropped_while_true_loops_across_broken_steps_survive() {
    let (order, truth) = route();
    let n = truth.len();
    // Way out 1 m and 3° at frame 12 (its registration failed: a weak step), 0.5 m and 2° at
    // frame 40 and, on the way back, 2 m and 5° at frame 85 (both unflagged).
    let broken = [(12, 1.0, 3.0), (40, 0.5, 2.0), (85, 2.0, 5.0)];
    let mut steps = vec![Step::Measured(diagonal_information(STEP_SIGMA.0, STEP_SIGMA.1)); n];
    steps[12] = Step::Failed;
    let poses = odometry(&truth, &broken, 5);
    let mut loops = true_loops(&order, &truth, 9);
    let true_count = loops.len();
    // Frame 62 (way back, place 115) against frame 5 (place 10): 54 m apart, registered as if
    // 0.3 m apart; frame 70 (place 99) against frame 46 (place 92): 3.5 m
    // apart, registered 1.7 m off the truth.
    let look_alike = Isometry3::from_parts(
        Translation3::new(0.3, 0.0, 0.0),
        UnitQuaternion::from_axis_angle(&Vector3::z_axis(), 0.05),
    );
    assert!((truth[62].translation.vector - truth[5].translation.vector).norm() > 50.0);
    loops.push(false_loop(62, 5, look_alike));
    let off = truth[46].inverse() * truth[70] * Isometry3::translation(1.7, 0.0, 0.0);
    loops.push(false_loop(70, 46, off));
    let config = LoopConfig::for_voxel(0.5);
    let ranges = vec![None; n];

    let judged = judge_loops(&poses, &steps, &ranges, &loops, &config).unwrap();
    for (i, d) in judged.decisions.iter().enumerate() {
        let l = &loops[i];
        if i < true_count {
            assert!(
                matches!(d, LoopDecision::InGraph(w) if *w >= 0.5),
                "true loop {} → {} ends {d:?}",
                l.query,
                l.matched
            );
        } else {
            assert!(
                matches!(d, LoopDecision::Inconsistent { .. }),
                "false loop {} → {} ends {d:?}",
                l.query,
                l.matched
            );
        }
    }
    // The oracle: the graph of the true loops alone. Judged jointly, the trajectory is that one.
    let (oracle, _) = optimize_trajectory(&poses, &steps, &loops[..true_count], &config).unwrap();
    let (error, oracle_error) = (
        position_rms(&judged.optimized, &truth),
        position_rms(&oracle, &truth),
    );
    assert!(
        (error - oracle_error).abs() <= 1e-9,
        "{error} m against the true loops' graph's {oracle_error} m"
    );
    // PCM on the odometry as it is (no first solve's weights) splits the true loops at the
    // unflagged broken steps: many true loops would be dropped.
    let raw = PairwiseConsistency::new(&poses, &steps, None, &config).unwrap();
    let adjacent = raw.graph(&loops, config.consistency_chi2, &config);
    let kept = maximum_clique(&adjacent, &vec![0.0; loops.len()]);
    let dropped_true = true_count - kept.iter().filter(|&&i| i < true_count).count();
    eprintln!(
        "without the first solve's weights PCM drops {dropped_true} of {true_count} true loops"
    );
    assert!(dropped_true > 10, "{dropped_true} true loops dropped");
    // Without the joint judgement the look-alikes stay in the graph.
    let alone = LoopConfig {
        consistency_chi2: 0.0,
        ..config
    };
    let judged = judge_loops(&poses, &steps, &ranges, &loops, &alone).unwrap();
    assert!(
        judged.decisions[true_count..]
            .iter()
            .all(|d| matches!(d, LoopDecision::InGraph(_)))
    );
}

/// The largest clique by trying every subset, as a bit mask.
fn brute_force_clique(adjacent: &[Vec<bool>]) -> usize {
    let n = adjacent.len();
    (0u32..1 << n)
        .filter(|mask| {
            (0..n).all(|i| {
                mask & (1 << i) == 0 || (i + 1..n).all(|j| mask & (1 << j) == 0 || adjacent[i][j])
            })
        })
        .map(u32::count_ones)
        .max()
        .unwrap_or(0) as usize
}

fn is_clique(adjacent: &[Vec<bool>], vertices: &[usize]) -> bool {
    vertices
        .iter()
        .all(|&a| vertices.iter().all(|&b| a == b || adjacent[a][b]))
}

#[test]
fn the_clique_is_maximum_on_random_graphs() {
    let mut rng = Pcg64Mcg::seed_from_u64(45);
    for trial in 0..300 {
        let n = rng.random_range(0..=13);
        let density: f64 = rng.random_range(0.1..0.95);
        let mut adjacent = vec![vec![false; n]; n];
        let edges: Vec<(usize, usize)> = (0..n)
            .flat_map(|i| (i + 1..n).map(move |j| (i, j)))
            .collect();
        for (i, j) in edges {
            let e = rng.random_bool(density);
            adjacent[i][j] = e;
            adjacent[j][i] = e;
        }
        let rank: Vec<f64> = (0..n).map(|_| rng.random()).collect();
        let clique = maximum_clique(&adjacent, &rank);
        assert!(is_clique(&adjacent, &clique), "trial {trial}: not a clique");
        assert_eq!(
            clique.len(),
            brute_force_clique(&adjacent),
            "trial {trial}: n {n}, density {density:.2}"
        );
        assert_eq!(clique, maximum_clique(&adjacent, &rank), "deterministic");
    }
}

#[test]
fn pcm_on_a_small_graph_keeps_the_brute_force_maximum_consistent_set() {
    // Every fifth true loop and three look-alikes that agree with one another (a wrong place
    // seen thrice) but not with the true loops: 12 loops, small enough for every subset.
    let (order, truth) = route();
    let n = truth.len();
    let steps = vec![Step::Measured(diagonal_information(STEP_SIGMA.0, STEP_SIGMA.1)); n];
    let poses = odometry(&truth, &[], 3);
    let mut loops: Vec<LoopEdge> = true_loops(&order, &truth, 4)
        .into_iter()
        .step_by(12)
        .collect();
    loops.truncate(9);
    let shift = Isometry3::translation(3.0, 0.0, 0.0);
    for (q, m) in [(100, 20), (101, 19), (102, 18)] {
        loops.push(false_loop(q, m, truth[m].inverse() * truth[q] * shift));
    }
    let config = LoopConfig::for_voxel(0.5);
    let pcm = PairwiseConsistency::new(&poses, &steps, None, &config).unwrap();
    let adjacent = pcm.graph(&loops, config.consistency_chi2, &config);
    // The look-alikes agree with one another: a clique of three that is not the largest.
    assert!(is_clique(&adjacent, &[9, 10, 11]));
    let clique = maximum_clique(&adjacent, &[0.0; 12]);
    assert_eq!(clique.len(), brute_force_clique(&adjacent));
    assert_eq!(clique, (0..9).collect::<Vec<_>>());
}

#[test]
fn true_loop_pairs_have_chi2_cycle_errors() {
    // The cycle of two true loops through a noisy odometry, all noise drawn from the covariances
    // the graph is told: PCM's distance is χ²(6), mean 6 (std of the mean of 600: 0.14).
    let (order, truth) = route();
    let n = truth.len();
    let steps = vec![Step::Measured(diagonal_information(STEP_SIGMA.0, STEP_SIGMA.1)); n];
    let mut config = LoopConfig::for_voxel(0.5);
    // The graph's prior of an unmeasured step is added to every edge; make it negligible.
    config.odometry_sigma_m = 1e3;
    config.odometry_sigma_deg = 1e3;
    let mut rng = Pcg64Mcg::seed_from_u64(11);
    let mut sum = 0.0;
    let trials = 600;
    for t in 0..trials {
        let poses = odometry(&truth, &[], 100 + t);
        let loops = true_loops(&order, &truth, 1000 + t);
        let pcm = PairwiseConsistency::new(&poses, &steps, None, &config).unwrap();
        let i = rng.random_range(0..loops.len());
        let j = (i + rng.random_range(1..loops.len())) % loops.len();
        sum += pcm.distance2(&loops[i], &loops[j], &config).unwrap();
    }
    let mean = sum / trials as f64;
    assert!((mean - 6.0).abs() < 0.6, "mean d² {mean}");
}
