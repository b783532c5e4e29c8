//! Dense verification: score a rigid hypothesis by how much of the whole source cloud it lays onto
//! the target (Open3D's RANSAC criterion), instead of by how many putative correspondences agree.
//!
//! Why: a correspondence count only sees the matches FPFH produced. When the descriptors of a pair
//! are poor — on the Stanford bunny 0°↔90° pair the number of correct nearest-neighbour matches
//! swings between 0 and ~170 of ~1250 with the (random) pose of the source, identically in Open3D —
//! a wrong pose supported by ~35 coincidental matches out-scores the true pose supported by < 10,
//! while the true pose still lays ~56 % of the source onto the target against ≤ 45 % for the
//! wrong ones. The overlap does not depend on the descriptors.

use nalgebra::{Isometry3, Matrix3, Point3};
use rayon::prelude::*;

use super::Scoring;
use super::estimator::{Estimator, RigidEstimator, Score};
use crate::Result;
use crate::geometry::RadiusGrid;
use crate::geometry::radius_grid::default_max_columns;
use crate::refine::icp::IcpTarget;

/// The target cloud for overlap queries: a [`RadiusGrid`] at the inlier threshold when the cloud's
/// extent allows, else a kd-tree.
#[derive(Debug)]
pub enum OverlapTarget<'a> {
    /// Grid of cell edge = the inlier threshold.
    Grid(Box<RadiusGrid>),
    /// kd-tree (e.g. the ICP target's).
    Tree(&'a IcpTarget),
}

impl<'a> OverlapTarget<'a> {
    /// A grid over `points` at `threshold_m` \[m\] when it needs at most
    /// `max(64 · points, 2²⁰)` columns ([`RadiusGrid`]), else the kd-tree `tree()` returns (which must hold the same
    /// points; only called then).
    pub fn new(
        points: &[Point3<f64>],
        threshold_m: f64,
        tree: impl FnOnce() -> Result<&'a IcpTarget>,
    ) -> Result<Self> {
        let cap = default_max_columns(points.len());
        Ok(match RadiusGrid::new(points, threshold_m, cap)? {
            Some(grid) => OverlapTarget::Grid(Box::new(grid)),
            None => OverlapTarget::Tree(tree()?),
        })
    }

    /// Squared distance \[m²\] to the nearest target point, clamped to `threshold_sq` (which must
    /// be the grid's radius squared for [`OverlapTarget::Grid`]).
    #[inline]
    fn clamped_distance_sq(&self, q: &Point3<f64>, threshold_sq: f64) -> f64 {
        match self {
            OverlapTarget::Grid(g) => g.nearest_within_sq(q).unwrap_or(threshold_sq),
            OverlapTarget::Tree(t) => t.nearest_distance_squared(q).min(threshold_sq),
        }
    }

    /// Whether some target point is strictly closer than the threshold (`threshold_sq` must be
    /// the grid's radius squared for [`OverlapTarget::Grid`]).
    #[inline]
    fn any_within(&self, q: &Point3<f64>, threshold_sq: f64) -> bool {
        match self {
            OverlapTarget::Grid(g) => g.any_within(q),
            OverlapTarget::Tree(t) => t.nearest_distance_squared(q) < threshold_sq,
        }
    }
}

/// A [`RigidEstimator`] whose [`Estimator::score`] is the dense overlap of `source_cloud` with
/// the target cloud: `inliers` = source points whose nearest target point (after the model) is
/// strictly closer than the threshold (as Open3D), `cost` = `Σ min(d², τ²)` over all source
/// points. Sampling, pre-rejection, estimation, refits and [`Estimator::residual_sq`] are the
/// correspondences', so local optimisation still refits on correspondence inliers (a refit is kept
/// only when it raises the dense score) and adaptive termination still uses the probability of
/// drawing the best model's correspondence inliers.
///
/// With [`Scoring::InlierCount`] the best model is the one with the
/// highest fitness (`inliers / source_cloud.len()`): Open3D's `IsBetterRANSACThan` without its RMSE
/// tie-break (ties go to the earlier hypothesis, as everywhere in the consensus loop).
///
/// [`DenseRigidEstimator::scoring`]`(Scoring::InlierCount)` makes the scores count inliers only:
/// each source point stops at the first target point within the threshold instead of looking for
/// the nearest, and [`Score::cost`] is left at 0 (the consensus loop never reads it under that
/// scoring). Same inlier counts, hence the same models.
#[derive(Debug, Clone, Copy)]
pub struct DenseRigidEstimator<'a> {
    correspondences: RigidEstimator<'a>,
    source_cloud: &'a [Point3<f64>],
    target_cloud: &'a OverlapTarget<'a>,
    count_only: bool,
}

/// Source points per chunk of a dense score (the unit of its parallel sum).
const SCORE_CHUNK: usize = 1024;

/// The rotation matrix and translation of `model`.
fn rotation_translation(model: &Isometry3<f64>) -> (Matrix3<f64>, nalgebra::Vector3<f64>) {
    (
        model.rotation.to_rotation_matrix().into_inner(),
        model.translation.vector,
    )
}

impl<'a> DenseRigidEstimator<'a> {
    /// Squared distance from source point `p` moved by (`r`, `t`) to the nearest target point,
    /// clamped to `threshold_sq`.
    #[inline]
    fn distance_sq(
        &self,
        r: &Matrix3<f64>,
        t: &nalgebra::Vector3<f64>,
        p: &Point3<f64>,
        threshold_sq: f64,
    ) -> f64 {
        let q = Point3::from(r * p.coords + t);
        self.target_cloud.clamped_distance_sq(&q, threshold_sq)
    }

    /// Scores `correspondences`' models by the overlap of `source_cloud` (source frame) with
    /// `target_cloud` (target frame). The consensus loop's inlier threshold must be the one
    /// `target_cloud` was built for.
    pub fn new(
        correspondences: RigidEstimator<'a>,
        source_cloud: &'a [Point3<f64>],
        target_cloud: &'a OverlapTarget<'a>,
    ) -> Self {
        Self {
            correspondences,
            source_cloud,
            target_cloud,
            count_only: false,
        }
    }

    /// Tells the estimator which scoring the consensus loop uses: under
    /// [`Scoring::InlierCount`] only inliers are counted (faster; `cost` = 0). Default: costs
    /// are computed, as any scoring needs.
    pub fn scoring(mut self, scoring: Scoring) -> Self {
        self.count_only = scoring == Scoring::InlierCount;
        self
    }

    /// Whether source point `p` moved by (`r`, `t`) has a target point strictly within the
    /// threshold.
    #[inline]
    fn is_inlier(
        &self,
        r: &Matrix3<f64>,
        t: &nalgebra::Vector3<f64>,
        p: &Point3<f64>,
        threshold_sq: f64,
    ) -> bool {
        let q = Point3::from(r * p.coords + t);
        self.target_cloud.any_within(&q, threshold_sq)
    }
}

impl Estimator for DenseRigidEstimator<'_> {
    type Model = Isometry3<f64>;

    fn min_samples(&self) -> usize {
        self.correspondences.min_samples()
    }

    fn num_items(&self) -> usize {
        self.correspondences.num_items()
    }

    fn accept_sample(&self, sample: &[usize]) -> bool {
        self.correspondences.accept_sample(sample)
    }

    fn estimate(&self, sample: &[usize]) -> Option<Isometry3<f64>> {
        self.correspondences.estimate(sample)
    }

    fn accept_model(&self, model: &Isometry3<f64>, sample: &[usize]) -> bool {
        self.correspondences.accept_model(model, sample)
    }

    #[inline]
    fn residual_sq(&self, model: &Isometry3<f64>, i: usize) -> f64 {
        self.correspondences.residual_sq(model, i)
    }

    /// All source points, in parallel over fixed chunks summed in order: the same score as
    /// [`Estimator::score_unless_worse`] without a bound, on any thread count. (The local
    /// optimisation scores its refits one at a time, on the consensus loop's thread.)
    fn score(&self, model: &Isometry3<f64>, threshold_sq: f64) -> Score {
        let (r, t) = rotation_translation(model);
        let partials: Vec<(u32, f64)> = self
            .source_cloud
            .par_chunks(SCORE_CHUNK)
            .map(|chunk| {
                let (mut inliers, mut cost) = (0u32, 0.0);
                if self.count_only {
                    for p in chunk {
                        inliers += self.is_inlier(&r, &t, p, threshold_sq) as u32;
                    }
                    return (inliers, cost);
                }
                for p in chunk {
                    let d = self.distance_sq(&r, &t, p, threshold_sq);
                    inliers += (d < threshold_sq) as u32;
                    cost += d;
                }
                (inliers, cost)
            })
            .collect();
        let mut score = Score::default();
        for (inliers, cost) in partials {
            score.inliers += inliers;
            score.cost += cost;
        }
        score
    }

    /// Stops once the source points left cannot lift the inlier count above `bound`'s
    /// ([`Scoring::InlierCount`]) or the cost already exceeds `bound`'s ([`Scoring::Msac`]): most
    /// hypotheses are far from the best, so most stop after a fraction of the cloud. The cost is
    /// summed per chunk of [`SCORE_CHUNK`] points, as [`Estimator::score`].
    fn score_unless_worse(
        &self,
        model: &Isometry3<f64>,
        threshold_sq: f64,
        bound: Option<&Score>,
        scoring: Scoring,
    ) -> Option<Score> {
        let (r, t) = rotation_translation(model);
        let n = self.source_cloud.len();
        // Misses allowed before the count can no longer exceed the bound's; the cost ceiling.
        let (max_misses, max_cost) = match (bound, scoring) {
            (Some(b), Scoring::InlierCount) => {
                (n.saturating_sub(b.inliers as usize + 1), f64::INFINITY)
            }
            (Some(b), Scoring::Msac) => (usize::MAX, b.cost),
            (None, _) => (usize::MAX, f64::INFINITY),
        };
        let mut inliers = 0u32;
        let mut misses = 0usize;
        let mut cost = 0.0;
        if self.count_only && scoring == Scoring::InlierCount {
            for (k, p) in self.source_cloud.iter().enumerate() {
                let inlier = self.is_inlier(&r, &t, p, threshold_sq);
                inliers += inlier as u32;
                misses += !inlier as usize;
                if k % 64 == 63 && misses > max_misses {
                    return None;
                }
            }
            return (misses <= max_misses).then_some(Score { inliers, cost });
        }
        for chunk in self.source_cloud.chunks(SCORE_CHUNK) {
            let mut chunk_cost = 0.0;
            for (k, p) in chunk.iter().enumerate() {
                let d = self.distance_sq(&r, &t, p, threshold_sq);
                let inlier = d < threshold_sq;
                inliers += inlier as u32;
                misses += !inlier as usize;
                chunk_cost += d;
                // Checked every 64 points: keeps the loop tight; stopping later never changes a
                // result. The final cost is at least `cost + chunk_cost` (sums of non-negative
                // terms only grow).
                if k % 64 == 63 && (misses > max_misses || cost + chunk_cost >= max_cost) {
                    return None;
                }
            }
            cost += chunk_cost;
        }
        if misses > max_misses || cost >= max_cost {
            return None;
        }
        Some(Score { inliers, cost })
    }

    fn refit(&self, inliers: &[usize]) -> Option<Isometry3<f64>> {
        self.correspondences.refit(inliers)
    }
}
