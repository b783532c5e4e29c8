//! Robust pose-graph optimisation on SE(3) for loop closure.
//!
//! A [`PoseGraph`] holds initial guesses `world_from_node` and relative-pose [`Edge`]s. [`optimize`]
//! minimises
//!
//! ```text
//! F(T) = Σ_edges ρ_e(√(e_eᵀ Ω_e e_e)),   e_e = Log(Z_e⁻¹ · T_from⁻¹ · T_to)
//! ```
//!
//! with `ρ(d) = ½ d²` for ordinary edges and an M-estimator ([`RobustKernel`]) for edges marked
//! `robust` — GTSAM's `BetweenFactor<Pose3>` with the full SE(3) logarithm (`Pose3::Logmap`), tangent
//! order **(rotation, translation)**. The solver is Levenberg–Marquardt on the manifold (Grisetti,
//! Kümmerle, Stachniss & Burgard 2010, "A tutorial on graph-based SLAM": linearise every edge, solve
//! the sparse system `H Δx = −b`, apply the increment through the manifold operator — here
//! `T ← T · Exp(δ)` — and remove the gauge freedom by fixing one node, node 0), with GTSAM's
//! `LevenbergMarquardtOptimizer` damping schedule and stopping rule, and
//! robust edges by iteratively reweighted least squares as GTSAM's `noiseModel::Robust`.
//!
//! The module is pure (slices and nalgebra types); [`g2o`] reads and writes the g2o text format.

pub mod g2o;
mod linear;
mod robust;
pub mod se3;

use nalgebra::{Isometry3, Matrix6, Vector6};

pub use robust::RobustKernel;

use crate::{Error, Result};
use linear::NormalEquations;

/// A relative-pose measurement between two nodes.
#[derive(Debug, Clone, PartialEq)]
pub struct Edge {
    /// Index of the first node.
    pub from: usize,
    /// Index of the second node (≠ `from`).
    pub to: usize,
    /// `from_T_to`: the pose of node `to` in node `from`'s frame, i.e. `poses[from]⁻¹ · poses[to]`
    /// when the graph is consistent. Translation in metres.
    pub measurement: Isometry3<f64>,
    /// Information matrix Ω (inverse covariance) of the error in (rotation \[rad\], translation \[m\])
    /// order; symmetric positive semi-definite. Units: 1/rad², 1/(rad·m), 1/m².
    pub information: Matrix6<f64>,
    /// Apply [`GraphOptions::kernel`] to this edge (loop closures that may be wrong).
    pub robust: bool,
}

/// Nodes (initial guesses) and edges of a pose graph.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct PoseGraph {
    /// `world_from_node` initial guesses; node 0 is held fixed by [`optimize`] (gauge).
    pub poses: Vec<Isometry3<f64>>,
    /// Relative-pose measurements.
    pub edges: Vec<Edge>,
}

/// GTSAM's default relative and absolute error-decrease tolerances
/// (`NonlinearOptimizerParams::relativeErrorTol`, `absoluteErrorTol`).
pub const DEFAULT_ERROR_TOL: f64 = 1e-5;
/// Default robust-kernel scale `k` \[σ, i.e. units of the Mahalanobis distance\]: an edge one
/// standard deviation off keeps weight ½ under Cauchy.
pub const DEFAULT_KERNEL_SCALE: f64 = 1.0;

/// Options of [`optimize`]. `Default` gives GTSAM's `LevenbergMarquardtParams` defaults.
#[derive(Debug, Clone, PartialEq)]
pub struct GraphOptions {
    /// Maximum number of LM iterations (accepted or finally rejected steps). Default: `100`.
    pub max_iterations: usize,
    /// Stop when the cost decreases by less than this fraction of itself in one iteration.
    /// Default: [`DEFAULT_ERROR_TOL`] (`1e-5`).
    pub relative_error_tol: f64,
    /// Stop when the cost decreases by less than this (cost units) in one iteration.
    /// Default: [`DEFAULT_ERROR_TOL`] (`1e-5`).
    pub absolute_error_tol: f64,
    /// M-estimator for edges with `robust = true`. Default: [`RobustKernel::Cauchy`].
    pub kernel: RobustKernel,
    /// Kernel scale `k` \[σ\]. Default: [`DEFAULT_KERNEL_SCALE`] (`1.0`).
    pub kernel_scale: f64,
    /// Initial damping λ (added as `λ I` to `H`). Default: `1e-5` (GTSAM `lambdaInitial`).
    pub lambda_initial: f64,
    /// Factor λ is divided by after a good step and multiplied by after a bad one.
    /// Default: `10` (GTSAM `lambdaFactor`).
    pub lambda_factor: f64,
    /// Give up an iteration when λ exceeds this. Default: `1e5` (GTSAM `lambdaUpperBound`).
    pub lambda_upper_bound: f64,
}

impl Default for GraphOptions {
    fn default() -> Self {
        Self {
            max_iterations: 100,
            relative_error_tol: DEFAULT_ERROR_TOL,
            absolute_error_tol: DEFAULT_ERROR_TOL,
            kernel: RobustKernel::Cauchy,
            kernel_scale: DEFAULT_KERNEL_SCALE,
            lambda_initial: 1e-5,
            lambda_factor: 10.0,
            lambda_upper_bound: 1e5,
        }
    }
}

/// GTSAM's `minModelFidelity`: a step is accepted when the actual cost decrease is more than this
/// fraction of the decrease the linear model predicted.
const MIN_MODEL_FIDELITY: f64 = 1e-3;

/// Result of [`optimize`].
#[derive(Debug, Clone, PartialEq)]
pub struct GraphSolution {
    /// Optimised `world_from_node`; `poses[0]` equals the input's.
    pub poses: Vec<Isometry3<f64>>,
    /// LM iterations performed.
    pub iterations: usize,
    /// Cost `F` at the initial guess.
    pub initial_cost: f64,
    /// Cost `F` at `poses`.
    pub final_cost: f64,
    /// IRLS weight `w(d) ∈ (0, 1]` of every edge at `poses`; `1` for non-robust edges.
    pub edge_weights: Vec<f64>,
    /// The relative/absolute tolerance was met (or no step could lower the cost while the model
    /// predicted a gain below tolerance); `false` after `max_iterations` or when LM gave up.
    pub converged: bool,
}

/// Error `e = Log(Z⁻¹ · T_from⁻¹ · T_to)` of `edge` at `poses`, (rotation \[rad\], translation \[m\]).
#[must_use]
pub fn edge_error(poses: &[Isometry3<f64>], edge: &Edge) -> Vector6<f64> {
    se3::log(&(edge.measurement.inverse() * poses[edge.from].inverse() * poses[edge.to]))
}

/// Error and its Jacobians `(e, ∂e/∂δ_from, ∂e/∂δ_to)` for right perturbations
/// `T ← T · Exp(δ)`: `∂e/∂δ_to = J_r(e)⁻¹` and `∂e/∂δ_from = −J_r(e)⁻¹ · Ad(T_to⁻¹ T_from)`.
#[must_use]
pub fn edge_jacobians(
    poses: &[Isometry3<f64>],
    edge: &Edge,
) -> (Vector6<f64>, Matrix6<f64>, Matrix6<f64>) {
    let (from, to) = (&poses[edge.from], &poses[edge.to]);
    let e = se3::log(&(edge.measurement.inverse() * from.inverse() * to));
    let jr_inv = se3::right_jacobian_inv(&e);
    let j_from = -jr_inv * se3::adjoint(&(to.inverse() * from));
    (e, j_from, jr_inv)
}

/// Mahalanobis distance `√(eᵀ Ω e)` (0 if rounding makes the form negative).
fn mahalanobis(e: &Vector6<f64>, information: &Matrix6<f64>) -> f64 {
    (e.dot(&(information * e))).max(0.0).sqrt()
}

/// Cost `ρ(d)` and IRLS weight of one edge.
fn edge_cost_weight(edge: &Edge, e: &Vector6<f64>, options: &GraphOptions) -> (f64, f64) {
    let d = mahalanobis(e, &edge.information);
    if edge.robust {
        (
            options.kernel.loss(d, options.kernel_scale),
            options.kernel.weight(d, options.kernel_scale),
        )
    } else {
        (0.5 * d * d, 1.0)
    }
}

/// Total cost `F` of `graph`'s edges evaluated at `poses` (not `graph.poses`).
#[must_use]
pub fn total_cost(graph: &PoseGraph, poses: &[Isometry3<f64>], options: &GraphOptions) -> f64 {
    graph
        .edges
        .iter()
        .map(|edge| edge_cost_weight(edge, &edge_error(poses, edge), options).0)
        .sum()
}

/// Checks indices, finiteness and that every node is connected to node 0 (otherwise its pose is
/// not determined).
fn validate(graph: &PoseGraph, options: &GraphOptions) -> Result<()> {
    let n = graph.poses.len();
    if n == 0 {
        return Err(Error::InvalidInput("pose graph has no nodes".into()));
    }
    if !(options.kernel_scale > 0.0 && options.kernel_scale.is_finite()) {
        return Err(Error::InvalidInput(format!(
            "kernel scale must be positive and finite, got {}",
            options.kernel_scale
        )));
    }
    for (k, p) in graph.poses.iter().enumerate() {
        if !(p.translation.vector.iter().all(|v| v.is_finite())
            && p.rotation.coords.iter().all(|v| v.is_finite()))
        {
            return Err(Error::InvalidInput(format!("pose {k} is not finite")));
        }
    }
    let mut parent: Vec<usize> = (0..n).collect();
    fn root(parent: &mut [usize], mut a: usize) -> usize {
        while parent[a] != a {
            parent[a] = parent[parent[a]];
            a = parent[a];
        }
        a
    }
    for (k, e) in graph.edges.iter().enumerate() {
        let m = &e.measurement;
        if !(m.translation.vector.iter().all(|v| v.is_finite())
            && m.rotation.coords.iter().all(|v| v.is_finite()))
        {
            return Err(Error::InvalidInput(format!(
                "edge {k}: measurement is not finite"
            )));
        }
        if e.from >= n || e.to >= n || e.from == e.to {
            return Err(Error::InvalidInput(format!(
                "edge {k} joins nodes {} and {} of a {n}-node graph",
                e.from, e.to
            )));
        }
        let sym = (e.information - e.information.transpose()).abs().max();
        if !e.information.iter().all(|v| v.is_finite()) || sym > 1e-9 * e.information.abs().max() {
            return Err(Error::InvalidInput(format!(
                "edge {k}: information matrix is not finite and symmetric"
            )));
        }
        let (a, b) = (root(&mut parent, e.from), root(&mut parent, e.to));
        parent[a] = b;
    }
    let r0 = root(&mut parent, 0);
    if let Some(k) = (0..n).find(|&k| root(&mut parent, k) != r0) {
        return Err(Error::InvalidInput(format!(
            "node {k} is not connected to node 0 by edges"
        )));
    }
    Ok(())
}

/// Linearises every edge at `poses` into `system` and returns the IRLS weights.
fn linearize(
    graph: &PoseGraph,
    poses: &[Isometry3<f64>],
    options: &GraphOptions,
    system: &mut NormalEquations,
) -> Vec<f64> {
    system.clear();
    let mut weights = Vec::with_capacity(graph.edges.len());
    for (k, edge) in graph.edges.iter().enumerate() {
        let (e, j_from, j_to) = edge_jacobians(poses, edge);
        let (_, w) = edge_cost_weight(edge, &e, options);
        weights.push(w);
        system.add_edge(k, &j_from, &j_to, &(edge.information * w), &e);
    }
    weights
}

/// `poses · Exp(δ)` for every free node (δ in the system's block positions).
fn retract(
    poses: &[Isometry3<f64>],
    delta: &nalgebra::DVector<f64>,
    system: &NormalEquations,
) -> Vec<Isometry3<f64>> {
    let mut out = poses.to_vec();
    for (k, pose) in out.iter_mut().enumerate().skip(1) {
        let p = system.position(k - 1);
        let d = Vector6::from_column_slice(delta.rows(6 * p, 6).as_slice());
        *pose *= se3::exp(&d);
    }
    out
}

/// Optimises `graph` with Levenberg–Marquardt; node 0 stays at `graph.poses[0]`.
///
/// Each iteration linearises all edges (robust ones with IRLS weights from the current errors),
/// then tries `(H + λI) δ = −g` with λ rising by [`GraphOptions::lambda_factor`] until a step's
/// actual/predicted cost decrease exceeds GTSAM's `minModelFidelity` (1e-3); λ then falls by the
/// same factor. It stops when one iteration lowers the cost by less than the relative or absolute
/// tolerance (GTSAM's `checkConvergence`), after `max_iterations`, or when λ exceeds its bound.
///
/// # Errors
/// [`Error::InvalidInput`] for an empty graph, a non-finite pose or measurement, an edge index out
/// of range or joining a node to itself, a non-finite or asymmetric information matrix, a node not connected to node 0, or a
/// non-positive kernel scale.
pub fn optimize(graph: &PoseGraph, options: &GraphOptions) -> Result<GraphSolution> {
    validate(graph, options)?;
    let mut poses = graph.poses.clone();
    let initial_cost = total_cost(graph, &poses, options);
    let mut cost = initial_cost;
    if graph.poses.len() == 1 {
        return Ok(GraphSolution {
            poses,
            iterations: 0,
            initial_cost,
            final_cost: cost,
            edge_weights: vec![1.0; graph.edges.len()],
            converged: true,
        });
    }
    let pairs: Vec<(usize, usize)> = graph.edges.iter().map(|e| (e.from, e.to)).collect();
    let mut system = NormalEquations::new(graph.poses.len(), &pairs);
    let mut lambda = options.lambda_initial;
    let mut iterations = 0;
    let mut converged = cost <= 0.0;
    while !converged && iterations < options.max_iterations {
        iterations += 1;
        linearize(graph, &poses, options, &mut system);
        // The Gauss–Newton gain the first (least damped) attempt predicts: used to tell "at the
        // optimum, nothing left to gain" from "stuck" when λ runs out.
        let mut first_predicted: Option<f64> = None;
        let mut accepted = None;
        while lambda <= options.lambda_upper_bound {
            let step = system.solve(lambda).map(|delta| {
                let predicted = -system.model_change(&delta);
                (delta, predicted)
            });
            if let Some((delta, predicted)) = step {
                first_predicted.get_or_insert(predicted);
                if predicted >= 0.0 {
                    let candidate = retract(&poses, &delta, &system);
                    let new_cost = total_cost(graph, &candidate, options);
                    let actual = cost - new_cost;
                    // NOTE: like GTSAM, a step whose predicted gain is ~0 (below round-off) counts as
                    // successful when it does not raise the cost.
                    let good = if predicted > f64::EPSILON * cost {
                        actual / predicted > MIN_MODEL_FIDELITY
                    } else {
                        actual >= 0.0
                    };
                    if good {
                        accepted = Some((candidate, new_cost));
                        break;
                    }
                }
            }
            lambda *= options.lambda_factor;
        }
        match accepted {
            Some((candidate, new_cost)) => {
                lambda = (lambda / options.lambda_factor).max(f64::MIN_POSITIVE);
                let decrease = cost - new_cost;
                poses = candidate;
                converged = new_cost <= 0.0
                    || decrease <= options.absolute_error_tol
                    || decrease <= options.relative_error_tol * cost;
                cost = new_cost;
            }
            None => {
                // NOTE: GTSAM stops here with a warning; we call it converged only if the model
                // itself promised less than the tolerance.
                let gain = first_predicted.unwrap_or(f64::INFINITY);
                converged = gain
                    <= options
                        .absolute_error_tol
                        .max(options.relative_error_tol * cost);
                break;
            }
        }
    }
    let edge_weights = graph
        .edges
        .iter()
        .map(|edge| edge_cost_weight(edge, &edge_error(&poses, edge), options).1)
        .collect();
    Ok(GraphSolution {
        poses,
        iterations,
        initial_cost,
        final_cost: cost,
        edge_weights,
        converged,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn edge(poses: &[Isometry3<f64>], from: usize, to: usize) -> Edge {
        Edge {
            from,
            to,
            measurement: poses[from].inverse() * poses[to],
            information: Matrix6::identity() * 100.0,
            robust: false,
        }
    }

    #[test]
    fn disconnected_node_is_an_error() {
        let poses = vec![Isometry3::identity(); 3];
        let graph = PoseGraph {
            edges: vec![edge(&poses, 0, 1)],
            poses,
        };
        let err = optimize(&graph, &GraphOptions::default()).unwrap_err();
        assert!(err.to_string().contains("node 2"), "{err}");
    }

    #[test]
    fn self_edge_is_an_error() {
        let poses = vec![Isometry3::identity(); 2];
        let graph = PoseGraph {
            edges: vec![edge(&poses, 1, 1)],
            poses,
        };
        assert!(optimize(&graph, &GraphOptions::default()).is_err());
    }

    #[test]
    fn iteration_cap_is_not_convergence() {
        // A 6-node ring whose start is far from its optimum: one iteration cannot meet 1e-5.
        let truth: Vec<Isometry3<f64>> = (0..6)
            .map(|k| se3::exp(&Vector6::new(0.0, 0.0, k as f64, 3.0 * k as f64, 0.0, 0.0)))
            .collect();
        let edges = (0..6).map(|k| edge(&truth, k, (k + 1) % 6)).collect();
        let poses = (0..6)
            .map(|k| truth[k] * se3::exp(&Vector6::repeat(0.2 * k as f64)))
            .collect();
        let graph = PoseGraph { poses, edges };
        let capped = GraphOptions {
            max_iterations: 1,
            ..GraphOptions::default()
        };
        let one = optimize(&graph, &capped).unwrap();
        assert_eq!(one.iterations, 1);
        assert!(!one.converged);
        assert!(one.final_cost < one.initial_cost);
        let full = optimize(&graph, &GraphOptions::default()).unwrap();
        assert!(full.converged && full.final_cost < 1e-12, "{full:?}");
    }

    #[test]
    fn two_nodes_move_to_the_measurement() {
        let poses = vec![Isometry3::identity(); 2];
        let truth = se3::exp(&Vector6::new(0.3, -0.2, 0.1, 1.0, 2.0, -0.5));
        let mut e = edge(&poses, 0, 1);
        e.measurement = truth;
        let graph = PoseGraph {
            edges: vec![e],
            poses,
        };
        let sol = optimize(&graph, &GraphOptions::default()).unwrap();
        assert!(sol.converged);
        assert!(se3::log(&(sol.poses[1].inverse() * truth)).norm() < 1e-9);
        assert!(sol.final_cost < 1e-15);
    }
}
