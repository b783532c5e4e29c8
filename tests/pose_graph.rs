//! The robust pose-graph solver (`mireg::graph`): fixed point, drift removal by loop closure,
//! outlier loop edges under the Cauchy kernel, Jacobians against finite differences, g2o I/O.

use mireg::graph::g2o::{read_g2o, write_g2o};
use mireg::graph::{
    Edge, GraphOptions, PoseGraph, RobustKernel, edge_error, edge_jacobians, optimize, se3,
    total_cost,
};
use nalgebra::{Isometry3, Matrix6, Vector6};
use rand::{RngExt, SeedableRng};
use rand_distr::{Distribution, StandardNormal};
use rand_pcg::Pcg64;

// Absolute trajectory error without alignment: node 0 is held at the truth's first pose by the
// solver and by dead reckoning alike.
#[path = "common/position_rms.rs"]
mod position_rms;
use position_rms::position_rms as ate;

fn gaussian6(rng: &mut Pcg64, sigma_rot: f64, sigma_trans: f64) -> Vector6<f64> {
    Vector6::from_fn(|i, _| {
        let n: f64 = StandardNormal.sample(rng);
        n * if i < 3 { sigma_rot } else { sigma_trans }
    })
}

fn diag_information(sigma_rot: f64, sigma_trans: f64) -> Matrix6<f64> {
    let (r, t) = (sigma_rot.powi(-2), sigma_trans.powi(-2));
    Matrix6::from_diagonal(&Vector6::new(r, r, r, t, t, t))
}

/// A 10 m square walked once in 40 one-metre steps, with a little height and tilt wobble.
fn square_truth() -> Vec<Isometry3<f64>> {
    let per_side = 10;
    (0..4 * per_side)
        .map(|k| {
            let (corner, s) = (k / per_side, k % per_side);
            let yaw = corner as f64 * std::f64::consts::FRAC_PI_2;
            let start = [(0.0, 0.0), (10.0, 0.0), (10.0, 10.0), (0.0, 10.0)][corner];
            let step = s as f64;
            let x = start.0 + step * yaw.cos();
            let y = start.1 + step * yaw.sin();
            let kf = k as f64;
            Isometry3::new(
                nalgebra::Vector3::new(x, y, 0.1 * (0.3 * kf).sin()),
                nalgebra::Vector3::new(0.01 * kf.sin(), 0.01 * kf.cos(), 0.0),
            ) * Isometry3::rotation(nalgebra::Vector3::new(0.0, 0.0, yaw))
        })
        .collect()
}

/// Noise of a synthetic square: σ's in rad (rotation) and m (translation).
#[derive(Clone, Copy)]
struct Noise {
    /// Odometry σ: both the injected noise and the edges' information.
    odo: (f64, f64),
    /// Yaw bias added to every odometry step [rad]: drift the information does not explain.
    yaw_bias_rad: f64,
    /// Loop-edge σ (injected and modelled).
    loop_sigma: (f64, f64),
    /// Loop edges are marked `robust`.
    robust_loops: bool,
}

/// Drift dominated by a 0.005 rad/step yaw bias (2.5 σ per step), precise odometry otherwise.
const BIASED: Noise = Noise {
    odo: (0.002, 0.01),
    yaw_bias_rad: 0.005,
    loop_sigma: (0.01, 0.05),
    robust_loops: false,
};

/// Unbiased random-walk drift whose size the odometry information describes, precise robust loops.
// NOTE: with an M-estimator the drifted start can be a local minimum. For one loop with misclosure D
// and chain standard deviation σ_chain = √n·σ_odo, the robust cost along the correction has a second
// stationary point near "no correction" once D ≳ 2·k·σ_chain (Cauchy, scale k): drift beyond what
// the odometry information admits is then left uncorrected, as in GTSAM. So the robust tests use
// drift the information explains.
const RANDOM_WALK: Noise = Noise {
    odo: (0.01, 0.05),
    yaw_bias_rad: 0.0,
    loop_sigma: (0.005, 0.02),
    robust_loops: true,
};

struct Scenario {
    truth: Vec<Isometry3<f64>>,
    graph: PoseGraph,
}

/// Noisy (and possibly biased) odometry + correct loop edges between the end and the start of the
/// square; initial guess = dead reckoning.
fn drifted_square(seed: u64, noise: Noise) -> Scenario {
    let truth = square_truth();
    let n = truth.len();
    let mut rng = Pcg64::seed_from_u64(seed);
    let mut edges = Vec::new();
    for k in 0..n - 1 {
        let mut xi = gaussian6(&mut rng, noise.odo.0, noise.odo.1);
        xi[2] += noise.yaw_bias_rad;
        edges.push(Edge {
            from: k,
            to: k + 1,
            measurement: truth[k].inverse() * truth[k + 1] * se3::exp(&xi),
            information: diag_information(noise.odo.0, noise.odo.1),
            robust: false,
        });
    }
    for (i, j) in [(0, n - 1), (0, n - 2), (1, n - 1), (2, n - 1)] {
        let xi = gaussian6(&mut rng, noise.loop_sigma.0, noise.loop_sigma.1);
        edges.push(Edge {
            from: i,
            to: j,
            measurement: truth[i].inverse() * truth[j] * se3::exp(&xi),
            information: diag_information(noise.loop_sigma.0, noise.loop_sigma.1),
            robust: noise.robust_loops,
        });
    }
    let mut poses = vec![truth[0]];
    for e in &edges[..n - 1] {
        let next = poses[e.from] * e.measurement;
        poses.push(next);
    }
    Scenario {
        truth,
        graph: PoseGraph { poses, edges },
    }
}

/// Adds `count` false loop edges: random node pairs, random relative poses (up to ~1 rad, 5 m).
fn add_false_loops(graph: &mut PoseGraph, count: usize, seed: u64) {
    let n = graph.poses.len();
    let mut rng = Pcg64::seed_from_u64(seed);
    for _ in 0..count {
        let i = rng.random_range(0..n - 3);
        let j = rng.random_range(i + 2..n);
        let xi = Vector6::from_fn(|r, _| {
            if r < 3 {
                rng.random_range(-0.6..0.6)
            } else {
                rng.random_range(-5.0..5.0)
            }
        });
        graph.edges.push(Edge {
            from: i,
            to: j,
            measurement: se3::exp(&xi),
            information: diag_information(RANDOM_WALK.loop_sigma.0, RANDOM_WALK.loop_sigma.1),
            robust: true,
        });
    }
}

#[test]
fn consistent_graph_stays_at_its_poses() {
    let mut rng = Pcg64::seed_from_u64(1);
    let poses: Vec<Isometry3<f64>> = (0..30)
        .map(|_| se3::exp(&gaussian6(&mut rng, 1.0, 5.0)))
        .collect();
    let mut edges = Vec::new();
    let mut add = |from: usize, to: usize| {
        edges.push(Edge {
            from,
            to,
            measurement: poses[from].inverse() * poses[to],
            information: diag_information(0.01, 0.1),
            robust: from + 1 != to,
        })
    };
    for k in 0..29 {
        add(k, k + 1);
    }
    for (i, j) in [(0, 29), (3, 17), (10, 25), (5, 6)] {
        add(i, j);
    }
    let graph = PoseGraph {
        poses: poses.clone(),
        edges,
    };
    let sol = optimize(&graph, &GraphOptions::default()).unwrap();
    assert!(sol.converged);
    assert!(
        sol.initial_cost < 1e-18,
        "initial cost {}",
        sol.initial_cost
    );
    for (a, b) in sol.poses.iter().zip(&poses) {
        let d = se3::log(&(a.inverse() * b)).norm();
        assert!(d < 1e-9, "moved by {d:e}");
    }
    assert!(sol.edge_weights.iter().all(|&w| (w - 1.0).abs() < 1e-12));
}

#[test]
fn loop_closure_removes_odometry_drift() {
    // A constant per-step yaw bias b makes dead reckoning's heading error grow linearly (k·b) and its
    // position error quadratically along the square. The loop edges measure the whole misclosure n·b;
    // least squares spreads a misclosure evenly over the n equally weighted odometry edges (to first
    // order, the heading correction at node k is k·(n·b)/n = k·b), which cancels a constant bias
    // exactly, so only the zero-mean noise (σ = 0.01 m, 0.002 rad per step) is left.
    // (Loop edges are not robust here: see `RANDOM_WALK`'s note.)
    let s = drifted_square(7, BIASED);
    let drifted = ate(&s.graph.poses, &s.truth);
    let sol = optimize(&s.graph, &GraphOptions::default()).unwrap();
    let closed = ate(&sol.poses, &s.truth);
    eprintln!(
        "ATE dead reckoning {drifted:.4} m, optimised {closed:.4} m ({} iterations)",
        sol.iterations
    );
    assert!(sol.converged);
    assert!(drifted > 0.5, "the drift is injected: {drifted}");
    assert!(
        closed < drifted / 5.0 && closed < 0.15,
        "{closed} vs {drifted}"
    );
}

#[test]
fn cauchy_kernel_resists_false_loops() {
    let clean = drifted_square(21, RANDOM_WALK);
    let options = GraphOptions::default();
    let start = ate(&clean.graph.poses, &clean.truth);
    let base = ate(
        &optimize(&clean.graph, &options).unwrap().poses,
        &clean.truth,
    );

    let mut polluted = clean.graph.clone();
    add_false_loops(&mut polluted, 10, 12);
    let robust = optimize(&polluted, &options).unwrap();
    let robust_ate = ate(&robust.poses, &clean.truth);

    let mut plain = polluted.clone();
    plain.edges.iter_mut().for_each(|e| e.robust = false);
    let plain_ate = ate(&optimize(&plain, &options).unwrap().poses, &clean.truth);
    eprintln!(
        "ATE dead reckoning {start:.4} m, clean {base:.4} m, 10 false loops with Cauchy \
         {robust_ate:.4} m, without kernel {plain_ate:.4} m"
    );
    assert!(robust.converged);
    // The robust loops did close the loop (the start is not a trap here) …
    assert!(base < 0.5 * start, "{base} vs dead reckoning {start}");
    // … the false loops barely move the optimum, and they would wreck plain least squares.
    assert!(robust_ate < 1.1 * base, "{robust_ate} vs {base}");
    assert!(plain_ate > 5.0 * base, "{plain_ate} vs {base}");
    // The false edges are the ones switched off.
    let n_true = clean.graph.edges.len();
    let false_w = robust.edge_weights[n_true..]
        .iter()
        .copied()
        .fold(0.0, f64::max);
    let true_w = robust.edge_weights[clean.truth.len() - 1..n_true]
        .iter()
        .copied()
        .fold(1.0, f64::min);
    // NOTE: Cauchy with k = 1 σ also discounts a correct but few-σ loop edge (the lowest correct
    // weight is ≈ 0.03 here, i.e. ≈ 5.7 σ); the false ones end far lower (< 1e-4).
    eprintln!("robust weights: correct loops ≥ {true_w:.3e}, false loops ≤ {false_w:.3e}");
    assert!(
        false_w < 1e-3 && true_w > 100.0 * false_w,
        "false ≤ {false_w}, true ≥ {true_w}"
    );
}

#[test]
fn geman_mcclure_refines_from_the_cauchy_optimum() {
    // NOTE: Geman–McClure is redescending (influence ∝ k⁴/d³): started from dead reckoning, where the
    // correct loop edges are many σ off, it stays there (measured on this graph: ATE 0.7427 m →
    // 0.7424 m, least squares reaches 0.22 m). The usual cascade — Cauchy first, then Geman–McClure
    // from its optimum — is what this test checks.
    let clean = drifted_square(21, RANDOM_WALK);
    let cauchy = GraphOptions::default();
    let gm = GraphOptions {
        kernel: RobustKernel::GemanMcClure,
        ..GraphOptions::default()
    };
    let cascade = |graph: &PoseGraph| {
        let mut g = graph.clone();
        g.poses = optimize(graph, &cauchy).unwrap().poses;
        optimize(&g, &gm).unwrap()
    };
    let start = ate(&clean.graph.poses, &clean.truth);
    let base = ate(&cascade(&clean.graph).poses, &clean.truth);
    let mut polluted = clean.graph.clone();
    add_false_loops(&mut polluted, 10, 22);
    let sol = cascade(&polluted);
    let got = ate(&sol.poses, &clean.truth);
    eprintln!(
        "Cauchy → Geman–McClure ATE dead reckoning {start:.4} m, clean {base:.4} m, \
         10 false loops {got:.4} m"
    );
    assert!(sol.converged);
    assert!(base < 0.5 * start, "{base} vs dead reckoning {start}");
    assert!(got < 1.1 * base, "{got} vs {base}");
    let false_w = sol.edge_weights[clean.graph.edges.len()..]
        .iter()
        .copied()
        .fold(0.0, f64::max);
    assert!(false_w < 1e-6, "{false_w}");
}

/// Central finite differences of `f(δ)` at δ = 0 for a 6-vector perturbation.
fn numeric_jacobian(f: impl Fn(&Vector6<f64>) -> Vector6<f64>) -> Matrix6<f64> {
    let h = 1e-6;
    let mut j = Matrix6::zeros();
    for k in 0..6 {
        let mut d = Vector6::zeros();
        d[k] = h;
        j.set_column(k, &((f(&d) - f(&(-d))) / (2.0 * h)));
    }
    j
}

#[test]
fn jacobians_and_gradient_match_finite_differences() {
    let mut rng = Pcg64::seed_from_u64(5);
    for trial in 0..20 {
        let poses = vec![
            se3::exp(&gaussian6(&mut rng, 1.0, 3.0)),
            se3::exp(&gaussian6(&mut rng, 1.0, 3.0)),
        ];
        // Large errors in some trials (up to ~1 rad), tiny in others.
        let scale = if trial % 2 == 0 { 0.5 } else { 1e-4 };
        let edge = Edge {
            from: 0,
            to: 1,
            measurement: poses[0].inverse()
                * poses[1]
                * se3::exp(&gaussian6(&mut rng, scale, scale)),
            information: diag_information(0.1, 0.3),
            robust: true,
        };
        let (e, j_from, j_to) = edge_jacobians(&poses, &edge);
        assert!((e - edge_error(&poses, &edge)).norm() < 1e-15);
        let perturbed = |node: usize, d: &Vector6<f64>| {
            let mut p = poses.clone();
            p[node] *= se3::exp(d);
            edge_error(&p, &edge)
        };
        let fd_from = numeric_jacobian(|d| perturbed(0, d));
        let fd_to = numeric_jacobian(|d| perturbed(1, d));
        assert!(
            (j_from - fd_from).abs().max() < 1e-6,
            "trial {trial}: ∂e/∂δ_from"
        );
        assert!((j_to - fd_to).abs().max() < 1e-6, "trial {trial}: ∂e/∂δ_to");

        // Gradient of the robust cost: w(d) Jᵀ Ω e (what IRLS assembles) vs finite differences.
        let options = GraphOptions::default();
        let graph = PoseGraph {
            poses: poses.clone(),
            edges: vec![edge.clone()],
        };
        let d = e.dot(&(edge.information * e)).sqrt();
        let w = options.kernel.weight(d, options.kernel_scale);
        let analytic = j_to.transpose() * edge.information * e * w;
        let h = 1e-6;
        for k in 0..6 {
            let mut dv = Vector6::zeros();
            dv[k] = h;
            let cost = |sign: f64| {
                let mut p = poses.clone();
                p[1] *= se3::exp(&(dv * sign));
                total_cost(&graph, &p, &options)
            };
            let fd = (cost(1.0) - cost(-1.0)) / (2.0 * h);
            let tol = 1e-5 * (1.0 + analytic[k].abs());
            assert!(
                (fd - analytic[k]).abs() < tol,
                "trial {trial} k {k}: {fd} vs {}",
                analytic[k]
            );
        }
    }
}

#[test]
fn g2o_round_trip_and_bad_lines() {
    let s = drifted_square(3, BIASED);
    let mut graph = s.graph.clone();
    // A full information matrix so that the (translation, rotation) swap is exercised.
    graph.edges[0].information = Matrix6::from_fn(|i, j| {
        if i == j {
            10.0 + i as f64
        } else {
            0.1 * (i + j) as f64
        }
    });
    let text = write_g2o(&graph);
    let back = read_g2o(&text).unwrap();
    assert_eq!(back.poses.len(), graph.poses.len());
    assert_eq!(back.edges.len(), graph.edges.len());
    for (a, b) in back.poses.iter().zip(&graph.poses) {
        assert!(se3::log(&(a.inverse() * b)).norm() < 1e-14);
    }
    for (a, b) in back.edges.iter().zip(&graph.edges) {
        assert_eq!((a.from, a.to), (b.from, b.to));
        assert!(se3::log(&(a.measurement.inverse() * b.measurement)).norm() < 1e-14);
        assert_eq!(a.information, b.information);
    }
    // g2o's first information entry is the x–x translation one: ours is at (3, 3).
    let first_edge = text.lines().find(|l| l.starts_with("EDGE")).unwrap();
    let fields: Vec<&str> = first_edge.split_whitespace().collect();
    assert_eq!(
        fields[10].parse::<f64>().unwrap(),
        graph.edges[0].information[(3, 3)]
    );

    let vertex = "VERTEX_SE3:QUAT 0 0 0 0 0 0 0 1\nVERTEX_SE3:QUAT 1 1 0 0 0 0 0 1\n";
    let info = "1 0 0 0 0 0 1 0 0 0 0 1 0 0 0 1 0 0 1 0 1";
    let cases = [
        (
            format!("{vertex}EDGE_SE3:QUAT 0 1 1 0 0 0 0 0 1 {info} 7\n"),
            "line 3",
            "end of line",
        ),
        (
            format!("{vertex}EDGE_SE3:QUAT 0 1 1 0 0 0 0 0 1\n"),
            "line 3",
            "info[0]",
        ),
        (
            format!("{vertex}EDGE_SE3:QUAT 0 9 1 0 0 0 0 0 1 {info}\n"),
            "line 3",
            "id_to",
        ),
        (
            "VERTEX_SE3:QUAT 0 0 0 zero 0 0 0 1\n".to_owned(),
            "line 1",
            "field z",
        ),
        (
            "# comment\n\nVERTEX_SE3:QUAT 0 0 0 0 0 0 0 2\n".to_owned(),
            "line 3",
            "qw",
        ),
        (
            "VERTEX_SE3:QUAT 0 0 0 0 0 0 0 nan\n".to_owned(),
            "line 1",
            "qw",
        ),
        (
            format!("{vertex}VERTEX_SE3:QUAT 1 0 0 0 0 0 0 1\n"),
            "line 3",
            "duplicate",
        ),
        ("VERTEX_SE2 0 0 0 0\n".to_owned(), "line 1", "tag"),
        (format!("{vertex}FIX 1\n"), "line 3", "first vertex"),
        (
            format!(
                "{vertex}EDGE_SE3:QUAT 0 1 1 0 0 0 0 0 1 {}\n",
                info.replacen('1', "0", 1)
            ),
            "line 3",
            "positive",
        ),
    ];
    for (text, line, needle) in &cases {
        let err = read_g2o(text).expect_err(text).to_string();
        assert!(
            err.contains(line) && err.contains(needle),
            "{text:?}: {err}"
        );
    }
    assert!(read_g2o(&format!("{vertex}FIX 0\n")).is_ok());
}
