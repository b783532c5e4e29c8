//! Loops judged jointly: pairwise consistency of loops through the odometry and the largest set
//! of mutually consistent loops (Pairwise Consistency Maximisation, PCM: Mangelson, Dominic,
//! Eustice & Vasudevan 2018, "Pairwise Consistent Measurement Set Maximization for Robust
//! Multi-robot Map Merging", ICRA).
//!
//! Two loops `i` (match `mᵢ`, query `qᵢ`, measurement `Zᵢ = T_mᵢ⁻¹ T_qᵢ`) and `j` close a cycle
//! with the odometry:
//!
//! ```text
//! C_ij = Zᵢ · O(qᵢ → qⱼ) · Zⱼ⁻¹ · O(mⱼ → mᵢ),   O(a → b) = T_a⁻¹ T_b (the odometry's)
//! ```
//!
//! which is the identity when both loops and the odometry between their ends are right. PCM's
//! consistency measure (Mangelson et al. eq. 7) is the squared Mahalanobis distance of the
//! cycle's error, `d²ᵢⱼ = Log(C_ij)ᵀ Σ_C⁻¹ Log(C_ij)`, with `Σ_C` propagated to first order from
//! the loops' and the odometry steps' covariances (right perturbations, `T · Exp(ξ)`: a factor
//! `X` of a product `X · S` contributes `Ad(S⁻¹) Σ_X Ad(S⁻¹)ᵀ`). Loops `i`, `j` are consistent
//! when `d²ᵢⱼ` is at most a χ² bound; the loops kept are a maximum clique of that consistency
//! graph ([`maximum_clique`]).
//!
//! The odometry chain `O(a → b)` is a product of steps; with `S_b = Σ_{k ≤ b} Ad(T_k) Σ_k
//! Ad(T_k)ᵀ` (each step's covariance carried to the world frame) its covariance is
//! `Ad(T_b⁻¹) (S_b − S_a) Ad(T_b⁻¹)ᵀ` in either direction, so every pair costs O(1) after an
//! O(n) prefix sum.
//!
//! NOTE: PCM judges the loops against the odometry as it is, and an odometry step broken
//! "with success" (its registration's information that of a good step) then splits the true
//! loops into those that span it and those that do not, inconsistent with each other. Here a
//! step's covariance may be divided by a weight (`step_weights`): the robust weight a first
//! solve of the pose graph gave its edge, the information iteratively reweighted least squares
//! gives it at that optimum (`w Ω`). A step the loops outvoted is then as weak as it proved,
//! and only loops the graph could not reconcile stay inconsistent.
//!
//! Pure: slices and nalgebra types in, numbers out.

use nalgebra::{Isometry3, Matrix6, Vector6};

use super::closure::{LoopConfig, LoopEdge, Step, edge_prior};
use crate::graph::se3::{adjoint, log};
use crate::odometry::uncertainty::diagonal_information;
use crate::{Error, Result};

/// Default [`LoopConfig::consistency_chi2`]: 100, a cycle error of 10 σ. Far beyond χ²(6)'s
/// 99.99 % quantile (27.9): the loops' covariances are calibrated only to a median NEES of
/// 2–13 on the shared real logs, with means up to 17 (docs/LOOPS.md), and a pair sums two
/// loops' errors. A wrong loop 1.7–50 m off (the ones the issue reports) lies thousands of σ
/// off a loop whose σ is centimetres.
pub const DEFAULT_CONSISTENCY_CHI2: f64 = 100.0;

/// [`maximum_clique`] gives up the exact search after this many branches and returns the
/// largest clique found so far: 1 000 000.
pub const CLIQUE_BRANCH_BUDGET: usize = 1_000_000;

/// The smallest step weight [`PairwiseConsistency::new`] divides a covariance by: 1e-9.
const MIN_STEP_WEIGHT: f64 = 1e-9;

/// Each odometry step's covariance, as [`super::pose_graph`] gives its edge the information:
/// a measured step's information plus the prior of an unmeasured one, a registered step
/// without it the configured deviations, a failed one the prior alone; divided by its weight.
fn step_covariances(
    steps: &[Step],
    weights: Option<&[f64]>,
    config: &LoopConfig,
) -> Result<Vec<Matrix6<f64>>> {
    let prior = edge_prior(config);
    let odometry = diagonal_information(config.odometry_sigma_m, config.odometry_sigma_deg);
    steps
        .iter()
        .enumerate()
        .map(|(k, s)| {
            let omega = match s {
                Step::Measured(o) => o + prior,
                Step::Registered => odometry,
                Step::Failed => prior,
            };
            let w = weights
                .and_then(|w| w.get(k).copied())
                .unwrap_or(1.0)
                .max(MIN_STEP_WEIGHT);
            omega
                .try_inverse()
                .filter(|c| c.iter().all(|v| v.is_finite()))
                .map(|c| c / w)
                .ok_or_else(|| {
                    Error::InvalidInput(format!("odometry step {k}: information not invertible"))
                })
        })
        .collect()
}

/// A loop's covariance: its information with the graph's prior, inverted (or the configured
/// deviations' without one), as [`super::pose_graph`] gives its edge.
fn loop_covariance(l: &LoopEdge, config: &LoopConfig) -> Option<Matrix6<f64>> {
    let omega = match &l.information {
        Some(o) if o.iter().all(|v| v.is_finite()) => o + edge_prior(config),
        _ => diagonal_information(config.loop_sigma_m, config.loop_sigma_deg),
    };
    omega.try_inverse()
}

/// The odometry's relative poses and their covariances between any two frames of a trajectory
/// (module doc): the prefix sums of the steps' covariances in the world frame.
pub struct PairwiseConsistency<'a> {
    poses: &'a [Isometry3<f64>],
    /// `S_k`, the sum over the steps into frames 1..=k of `Ad(T_k) Σ_k Ad(T_k)ᵀ`.
    prefix: Vec<Matrix6<f64>>,
}

impl<'a> PairwiseConsistency<'a> {
    /// For the odometry `poses` (`world_from_sensor`), with `steps[k]` what is known of the step
    /// into frame `k` (`steps[0]` unused) and, optionally, each step's weight `weights[k]` in
    /// (0, 1] dividing its covariance (module doc; `None`: 1).
    ///
    /// # Errors
    /// [`Error::InvalidInput`] for mismatched lengths or a step information that cannot be
    /// inverted.
    pub fn new(
        poses: &'a [Isometry3<f64>],
        steps: &[Step],
        weights: Option<&[f64]>,
        config: &LoopConfig,
    ) -> Result<Self> {
        if poses.len() != steps.len() || weights.is_some_and(|w| w.len() != poses.len()) {
            return Err(Error::InvalidInput(format!(
                "pairwise consistency: {} poses, {} steps, {:?} weights",
                poses.len(),
                steps.len(),
                weights.map(<[f64]>::len)
            )));
        }
        let covariances = step_covariances(steps, weights, config)?;
        let mut prefix = Vec::with_capacity(poses.len());
        let mut sum = Matrix6::zeros();
        for (k, pose) in poses.iter().enumerate() {
            if k > 0 {
                let ad = adjoint(pose);
                sum += ad * covariances[k] * ad.transpose();
            }
            prefix.push(sum);
        }
        Ok(Self { poses, prefix })
    }

    /// The odometry's `O(a → b) = T_a⁻¹ T_b` and its covariance (right perturbation).
    #[must_use]
    pub fn chain(&self, a: usize, b: usize) -> (Isometry3<f64>, Matrix6<f64>) {
        let relative = self.poses[a].inverse() * self.poses[b];
        let ad = adjoint(&self.poses[b].inverse());
        let sum = if b >= a {
            self.prefix[b] - self.prefix[a]
        } else {
            self.prefix[a] - self.prefix[b]
        };
        (relative, ad * sum * ad.transpose())
    }

    /// PCM's squared Mahalanobis distance `d²ᵢⱼ` of the cycle closed by loops `i` and `j` through
    /// the odometry (module doc); `None` where a covariance cannot be inverted or a loop names
    /// a frame outside the trajectory.
    #[must_use]
    pub fn distance2(&self, i: &LoopEdge, j: &LoopEdge, config: &LoopConfig) -> Option<f64> {
        let n = self.poses.len();
        if [i.query, i.matched, j.query, j.matched]
            .iter()
            .any(|&f| f >= n)
        {
            return None;
        }
        let (oq, sigma_oq) = self.chain(i.query, j.query);
        let (om, sigma_om) = self.chain(j.matched, i.matched);
        let (zi, zj) = (&i.match_from_query, &j.match_from_query);
        let zj_inv = zj.inverse();
        // Z_j⁻¹ perturbed through Z_j: Exp(−ξ) on the left, Ad(Z_j) ξ on the right.
        let ad_zj = adjoint(zj);
        let sigma_zj_inv = ad_zj * loop_covariance(j, config)? * ad_zj.transpose();
        let sigma_zi = loop_covariance(i, config)?;
        // C = Zᵢ · O_q · Zⱼ⁻¹ · O_m; each factor's suffix S, carried by Ad(S⁻¹).
        let suffixes = [oq * zj_inv * om, zj_inv * om, om, Isometry3::identity()];
        let factors = [sigma_zi, sigma_oq, sigma_zj_inv, sigma_om];
        let mut sigma = Matrix6::zeros();
        for (s, f) in suffixes.iter().zip(&factors) {
            let ad = adjoint(&s.inverse());
            sigma += ad * f * ad.transpose();
        }
        let e: Vector6<f64> = log(&(zi * oq * zj_inv * om));
        let d2 = (e.transpose() * sigma.try_inverse()? * e)[(0, 0)];
        d2.is_finite().then_some(d2)
    }

    /// The consistency graph of `loops`: `adjacent[i][j]` when `d²ᵢⱼ ≤ chi2` (a pair whose
    /// distance cannot be computed is inconsistent). Symmetric, `false` on the diagonal.
    #[must_use]
    pub fn graph(&self, loops: &[LoopEdge], chi2: f64, config: &LoopConfig) -> Vec<Vec<bool>> {
        let n = loops.len();
        let mut adjacent = vec![vec![false; n]; n];
        for i in 0..n {
            for j in i + 1..n {
                let ok = self
                    .distance2(&loops[i], &loops[j], config)
                    .is_some_and(|d2| d2 <= chi2);
                adjacent[i][j] = ok;
                adjacent[j][i] = ok;
            }
        }
        adjacent
    }
}

/// A maximum clique of the undirected graph `adjacent` (symmetric; the diagonal is ignored), its
/// vertices in increasing order: exact branch and bound (Carraghan & Pardalos 1990: extend the
/// clique by each candidate vertex in turn, prune a branch that cannot beat the best clique
/// found), vertices tried by decreasing degree and then by increasing `rank` (ties: the lower
/// index), so the answer is the same on every run. After [`CLIQUE_BRANCH_BUDGET`] branches the
/// largest clique found so far is returned (PCM's heuristic variant, Mangelson et al. §V-B,
/// likewise returns a clique that may not be maximum).
///
/// # Panics
/// If `rank` is shorter than `adjacent`.
#[must_use]
pub fn maximum_clique(adjacent: &[Vec<bool>], rank: &[f64]) -> Vec<usize> {
    let n = adjacent.len();
    let degree: Vec<usize> = (0..n)
        .map(|v| (0..n).filter(|&w| w != v && adjacent[v][w]).count())
        .collect();
    let mut order: Vec<usize> = (0..n).collect();
    order.sort_by(|&a, &b| {
        degree[b]
            .cmp(&degree[a])
            .then(rank[a].total_cmp(&rank[b]))
            .then(a.cmp(&b))
    });
    let mut search = CliqueSearch {
        adjacent,
        best: Vec::new(),
        budget: CLIQUE_BRANCH_BUDGET,
    };
    search.expand(&mut Vec::new(), &order);
    let mut best = search.best;
    best.sort_unstable();
    best
}

/// The state of [`maximum_clique`]'s search.
struct CliqueSearch<'a> {
    adjacent: &'a [Vec<bool>],
    best: Vec<usize>,
    budget: usize,
}

impl CliqueSearch<'_> {
    /// Extends `clique` by each of `candidates` (all adjacent to every vertex of `clique`).
    fn expand(&mut self, clique: &mut Vec<usize>, candidates: &[usize]) {
        if clique.len() > self.best.len() {
            self.best.clone_from(clique);
        }
        for (i, &v) in candidates.iter().enumerate() {
            if clique.len() + candidates.len() - i <= self.best.len() || self.budget == 0 {
                return;
            }
            self.budget -= 1;
            let next: Vec<usize> = candidates[i + 1..]
                .iter()
                .copied()
                .filter(|&w| self.adjacent[v][w])
                .collect();
            clique.push(v);
            self.expand(clique, &next);
            clique.pop();
        }
    }
}
