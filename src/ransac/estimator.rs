//! Model estimators: what a minimal sample turns into, and how well each correspondence fits it.

use nalgebra::{Isometry3, Matrix3, Point3, Rotation3, Translation3, UnitQuaternion, Vector3};

/// Inlier count and MSAC cost of a model: by default over all correspondences; an estimator may
/// score against other data ([`DenseRigidEstimator`](super::DenseRigidEstimator): the whole source
/// cloud).
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct Score {
    /// Items (by default correspondences) with squared residual below the squared threshold.
    pub inliers: u32,
    /// Truncated-quadratic (MSAC, Torr & Zisserman 2000) cost `Σ min(r², τ²)` \[residual units²\].
    pub cost: f64,
}

/// A model family for the consensus loop, after rust-cv's `Estimator`: the data lives in the
/// estimator; samples are index slices into it.
pub trait Estimator: Sync {
    /// The fitted model.
    type Model: Clone + Send + Sync;

    /// Size of a minimal sample.
    fn min_samples(&self) -> usize;

    /// Number of data items (correspondences).
    fn num_items(&self) -> usize;

    /// A cheap test that may reject a sample before estimation (pre-rejection). Default: accept.
    fn accept_sample(&self, _sample: &[usize]) -> bool {
        true
    }

    /// Fits a model to a minimal (or larger) sample; `None` for a degenerate sample.
    fn estimate(&self, sample: &[usize]) -> Option<Self::Model>;

    /// A cheap test of the model fitted to `sample`, before it is scored (pre-rejection after
    /// estimation, e.g. Open3D's `CorrespondenceCheckerBasedOnDistance`). Default: accept.
    fn accept_model(&self, _model: &Self::Model, _sample: &[usize]) -> bool {
        true
    }

    /// Squared residual of item `i` under `model` \[residual units²\].
    fn residual_sq(&self, model: &Self::Model, i: usize) -> f64;

    /// Scores `model` with squared inlier threshold `threshold_sq`. Default: over all items with
    /// [`Estimator::residual_sq`]; override for speed, or to verify against other data than the
    /// items ([`DenseRigidEstimator`](super::DenseRigidEstimator)).
    fn score(&self, model: &Self::Model, threshold_sq: f64) -> Score {
        let mut s = Score::default();
        for i in 0..self.num_items() {
            let r = self.residual_sq(model, i);
            s.inliers += (r < threshold_sq) as u32;
            s.cost += r.min(threshold_sq);
        }
        s
    }

    /// [`Estimator::score`], allowed to stop early and return `None` as soon as the model provably
    /// cannot be strictly better than `bound` under `scoring` (more inliers, or a lower cost). The
    /// consensus loop passes the best score known before the hypothesis's batch, so stopping
    /// never changes which model wins. Default: scores fully.
    fn score_unless_worse(
        &self,
        model: &Self::Model,
        threshold_sq: f64,
        _bound: Option<&Score>,
        _scoring: super::Scoring,
    ) -> Option<Score> {
        Some(self.score(model, threshold_sq))
    }

    /// Least-squares refit on a (non-minimal) inlier set for local optimisation. Default: the
    /// minimal-sample estimator.
    fn refit(&self, inliers: &[usize]) -> Option<Self::Model> {
        self.estimate(inliers)
    }
}

/// Default edge-length similarity for pre-rejection (PCL's `SampleConsensusPrerejective` and Open3D's
/// `CorrespondenceCheckerBasedOnEdgeLength` use 0.9).
pub const DEFAULT_EDGE_SIMILARITY: f64 = 0.9;

/// Default degeneracy tolerance: a sample is rejected when the second singular value of its
/// cross-covariance is below this fraction of the first (≈ a point set narrower than 1 % of its
/// length, i.e. near-collinear).
pub const DEFAULT_MIN_SINGULAR_RATIO: f64 = 1e-4;

/// Rigid 3-D transform from point correspondences `source[i] ↔ target[i]` (Kabsch 1976; Umeyama 1991
/// without scale). The model maps source points into the target frame: `target_from_source`.
#[derive(Debug, Clone, Copy)]
pub struct RigidEstimator<'a> {
    source: &'a [Point3<f64>],
    target: &'a [Point3<f64>],
    edge_similarity: f64,
    min_singular_ratio: f64,
    /// Squared distance bound of the sample check (m²); `None`: no check.
    sample_distance_sq: Option<f64>,
}

impl<'a> RigidEstimator<'a> {
    /// Correspondences `source[i] ↔ target[i]` in rank order. Panics if the lengths differ.
    pub fn new(source: &'a [Point3<f64>], target: &'a [Point3<f64>]) -> Self {
        assert_eq!(
            source.len(),
            target.len(),
            "correspondence slices differ in length"
        );
        Self {
            source,
            target,
            edge_similarity: DEFAULT_EDGE_SIMILARITY,
            min_singular_ratio: DEFAULT_MIN_SINGULAR_RATIO,
            sample_distance_sq: None,
        }
    }

    /// Distance pre-rejection after estimation (Open3D's `CorrespondenceCheckerBasedOnDistance`):
    /// a model survives only if it maps every correspondence of its own sample strictly within
    /// `distance` \[m\] of its target point. `None` (the default) disables it.
    #[must_use]
    pub fn sample_distance(mut self, distance: Option<f64>) -> Self {
        if let Some(d) = distance {
            assert!(
                d.is_finite() && d > 0.0,
                "sample distance {d} not finite and > 0"
            );
        }
        self.sample_distance_sq = distance.map(|d| d * d);
        self
    }

    /// Edge-length pre-rejection: a sample survives only if for every pair of its correspondences
    /// `min(|pᵢ−pⱼ|, |qᵢ−qⱼ|) ≥ similarity · max(…)`. `0` disables it. Default:
    /// [`DEFAULT_EDGE_SIMILARITY`].
    #[must_use]
    pub fn edge_similarity(mut self, similarity: f64) -> Self {
        assert!(
            (0.0..=1.0).contains(&similarity),
            "edge similarity {similarity} not in [0, 1]"
        );
        self.edge_similarity = similarity;
        self
    }

    /// Degeneracy tolerance; default [`DEFAULT_MIN_SINGULAR_RATIO`].
    #[must_use]
    pub fn min_singular_ratio(mut self, ratio: f64) -> Self {
        self.min_singular_ratio = ratio;
        self
    }
}

impl Estimator for RigidEstimator<'_> {
    type Model = Isometry3<f64>;

    fn min_samples(&self) -> usize {
        3
    }

    fn num_items(&self) -> usize {
        self.source.len()
    }

    fn accept_sample(&self, sample: &[usize]) -> bool {
        if self.edge_similarity <= 0.0 {
            return true;
        }
        for (a, &i) in sample.iter().enumerate() {
            for &j in &sample[a + 1..] {
                let ds = (self.source[i] - self.source[j]).norm();
                let dt = (self.target[i] - self.target[j]).norm();
                if ds < self.edge_similarity * dt || dt < self.edge_similarity * ds {
                    return false;
                }
            }
        }
        true
    }

    fn estimate(&self, sample: &[usize]) -> Option<Isometry3<f64>> {
        kabsch_indexed(self.source, self.target, sample, self.min_singular_ratio)
    }

    fn accept_model(&self, model: &Isometry3<f64>, sample: &[usize]) -> bool {
        self.sample_distance_sq
            .is_none_or(|bound| sample.iter().all(|&i| self.residual_sq(model, i) < bound))
    }

    #[inline]
    fn residual_sq(&self, model: &Isometry3<f64>, i: usize) -> f64 {
        (model * self.source[i] - self.target[i]).norm_squared()
    }

    fn score(&self, model: &Isometry3<f64>, threshold_sq: f64) -> Score {
        // Hot path: rotation as a plain matrix, branch-free accumulation.
        let r: Matrix3<f64> = model.rotation.to_rotation_matrix().into_inner();
        let t = model.translation.vector;
        let mut inliers = 0u32;
        let mut cost = 0.0;
        for (p, q) in self.source.iter().zip(self.target) {
            let d = r * p.coords + t - q.coords;
            let e = d.norm_squared();
            inliers += (e < threshold_sq) as u32;
            cost += e.min(threshold_sq);
        }
        Score { inliers, cost }
    }
}

/// Least-squares rigid transform `target_from_source` minimising `Σ |R·pᵢ + t − qᵢ|²` (Kabsch 1976).
///
/// Returns `None` when the points are degenerate: fewer than 3, coincident, or near-collinear (second
/// singular value of the cross-covariance below `min_singular_ratio` times the first).
pub fn kabsch(
    source: &[Point3<f64>],
    target: &[Point3<f64>],
    min_singular_ratio: f64,
) -> Option<Isometry3<f64>> {
    assert_eq!(
        source.len(),
        target.len(),
        "correspondence slices differ in length"
    );
    let all: Vec<usize> = (0..source.len()).collect();
    kabsch_indexed(source, target, &all, min_singular_ratio)
}

/// [`kabsch`] over the correspondences `idx` only (no copying).
pub fn kabsch_indexed(
    source: &[Point3<f64>],
    target: &[Point3<f64>],
    idx: &[usize],
    min_singular_ratio: f64,
) -> Option<Isometry3<f64>> {
    if idx.len() < 3 {
        return None;
    }
    let inv = 1.0 / idx.len() as f64;
    let (mut cs, mut ct) = (Vector3::zeros(), Vector3::zeros());
    for &i in idx {
        cs += source[i].coords;
        ct += target[i].coords;
    }
    cs *= inv;
    ct *= inv;
    // Cross-covariance H = Σ (p − p̄)(q − q̄)ᵀ.
    let mut h = Matrix3::zeros();
    for &i in idx {
        h += (source[i].coords - cs) * (target[i].coords - ct).transpose();
    }
    let svd = h.svd(true, true);
    let mut sv = [
        svd.singular_values[0],
        svd.singular_values[1],
        svd.singular_values[2],
    ];
    sv.sort_unstable_by(|a, b| b.total_cmp(a));
    if sv[0].is_nan() || sv[0] <= 0.0 || sv[1] < min_singular_ratio * sv[0] {
        return None;
    }
    let (u, v_t) = (svd.u?, svd.v_t?);
    let v = v_t.transpose();
    // R = V · diag(1, 1, sign(det(V Uᵀ))) · Uᵀ: the proper rotation closest to the unconstrained fit.
    let mut d = Matrix3::identity();
    if (v * u.transpose()).determinant() < 0.0 {
        d[(2, 2)] = -1.0;
    }
    let rot = v * d * u.transpose();
    let rotation = UnitQuaternion::from_rotation_matrix(&Rotation3::from_matrix_unchecked(rot));
    let translation = ct - rotation * cs;
    Some(Isometry3::from_parts(
        Translation3::from(translation),
        rotation,
    ))
}
