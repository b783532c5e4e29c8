//! Point-to-plane ICP, following Open3D's `registration_icp` with
//! `TransformationEstimationPointToPlane` and `ICPConvergenceCriteria`.
//!
//! Each iteration pairs every source point (moved by the current `target_from_source`) with its
//! nearest target point, keeps pairs closer than `max_correspondence_distance_m`, and minimises the
//! point-to-plane error `Σ w_i ((T s_i − q_i) · n_i)²` of Chen & Medioni ("Object modelling by
//! registration of multiple range images", 1992), linearised with the small-angle approximation of
//! Low ("Linear least-squares optimization for point-to-plane ICP surface registration", TR04-004,
//! UNC 2004): `R ≈ I + [ω]ₓ`, which makes the residual linear in `x = (ω, t)`:
//! `r_i(x) ≈ r_i + (p_i × n_i) · ω + n_i · t` with `p_i = T s_i`.
//!
//! A target point whose normal is zero has no plane ([`crate::geometry::NO_PLANE`]: too few
//! neighbours to fit one). It is matched point to point: three rows, one per axis `e`, each a
//! point-to-plane row with `n = e`. The two kinds of rows are weighed by their shares of the
//! correspondences, as GenZ-ICP weighs its point-to-plane and point-to-point terms (Lee, Lim and
//! Han, RA-L 2025): `α` for the planar rows, `1 − α` for the others, `α = planar / all`.
//!
//! NOTE: not Open3D's, whose point-to-plane ICP reads every normal as a plane (and gives a point
//! without neighbours +z). Without zero normals the two are the same, bit for bit.

use nalgebra::{Isometry3, Matrix6, Point3, Translation3, UnitQuaternion, Vector6};
use rayon::prelude::*;

use crate::geometry::radius_grid::default_max_columns;
use crate::geometry::{NO_PLANE, RadiusGrid};
use crate::{Error, Result};

mod target;
pub use target::{ESTIMATE_ALL_FRACTION, IcpTarget};

/// Default [`IcpConfig::max_iterations`] (Open3D's `ICPConvergenceCriteria` default).
pub const DEFAULT_MAX_ITERATIONS: usize = 30;
/// Default [`IcpConfig::relative_fitness`] (Open3D's default), dimensionless.
pub const DEFAULT_RELATIVE_FITNESS: f64 = 1e-6;
/// Default [`IcpConfig::relative_rmse`] (Open3D's default), metres.
pub const DEFAULT_RELATIVE_RMSE_M: f64 = 1e-6;

/// Source points per work unit of the parallel correspondence pass. Partial sums are formed per
/// chunk and added in chunk order, so results are bit-identical for any number of threads.
const CHUNK_POINTS: usize = 512;

/// Robust kernel applied to point-to-plane residuals as iteratively reweighted least squares
/// (same weight functions as Open3D's `robust_kernel`).
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum RobustKernel {
    /// Plain least squares: every inlier has weight 1.
    L2,
    /// Huber: weight 1 for `|r| ≤ scale_m`, `scale_m / |r|` beyond.
    Huber {
        /// Residual at which the loss turns linear \[m\].
        scale_m: f64,
    },
    /// Tukey biweight: weight `(1 − (r/scale_m)²)²` for `|r| ≤ scale_m`, 0 beyond.
    Tukey {
        /// Residual beyond which a correspondence is ignored \[m\].
        scale_m: f64,
    },
}

impl RobustKernel {
    /// IRLS weight of a residual `residual_m` \[m\].
    pub fn weight(&self, residual_m: f64) -> f64 {
        let r = residual_m.abs();
        match *self {
            RobustKernel::L2 => 1.0,
            RobustKernel::Huber { scale_m } => {
                if r <= scale_m {
                    1.0
                } else {
                    scale_m / r
                }
            }
            RobustKernel::Tukey { scale_m } => {
                if r <= scale_m {
                    let u = r / scale_m;
                    (1.0 - u * u).powi(2)
                } else {
                    0.0
                }
            }
        }
    }

    fn validate(&self) -> Result<()> {
        match *self {
            RobustKernel::L2 => Ok(()),
            RobustKernel::Huber { scale_m } | RobustKernel::Tukey { scale_m } => {
                if scale_m.is_finite() && scale_m > 0.0 {
                    Ok(())
                } else {
                    Err(Error::InvalidInput(format!(
                        "robust kernel scale must be finite and > 0 m, got {scale_m}"
                    )))
                }
            }
        }
    }
}

/// Configuration of [`registration_icp_point_to_plane`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct IcpConfig {
    /// Source/target pairs farther apart than this (point-to-point, after moving the source) are
    /// not correspondences \[m\]. No default: it depends on the data (Open3D requires it too).
    pub max_correspondence_distance_m: f64,
    /// Maximum number of transformation updates. Default: [`DEFAULT_MAX_ITERATIONS`] (`30`).
    pub max_iterations: usize,
    /// Stop when fitness changes by less than this between iterations (together with
    /// [`Self::relative_rmse`]). Dimensionless. Default: [`DEFAULT_RELATIVE_FITNESS`] (`1e-6`).
    pub relative_fitness: f64,
    /// Stop when the inlier RMSE changes by less than this between iterations (together with
    /// [`Self::relative_fitness`]). Despite Open3D's name this is an absolute change \[m\].
    /// Default: [`DEFAULT_RELATIVE_RMSE_M`] (`1e-6` m).
    pub relative_rmse: f64,
    /// Weighting of residuals. Default: [`RobustKernel::L2`].
    pub robust_kernel: RobustKernel,
    /// Also stop once an update translates by less than `.0` \[m\] and rotates by less than
    /// `.1` \[rad\] (KISS-ICP's criterion, on the update itself). Default: `None` (Open3D's
    /// criteria only).
    pub min_update: Option<(f64, f64)>,
    /// Whether the correspondence pass after the last update still runs: after an update below
    /// [`Self::min_update`], or after the [`Self::max_iterations`]-th. That pass only measures
    /// the final pose; without it the result's fitness, RMSE and Hessian are those of the pose
    /// before the last update, and the pose is the same. For callers that measure the final
    /// pose themselves (the fine stage, and the stages a fine stage follows). Default: `true`.
    pub measure_final_pose: bool,
}

impl IcpConfig {
    /// Open3D's defaults with the given correspondence distance \[m\].
    pub fn new(max_correspondence_distance_m: f64) -> Self {
        Self {
            max_correspondence_distance_m,
            max_iterations: DEFAULT_MAX_ITERATIONS,
            relative_fitness: DEFAULT_RELATIVE_FITNESS,
            relative_rmse: DEFAULT_RELATIVE_RMSE_M,
            robust_kernel: RobustKernel::L2,
            min_update: None,
            measure_final_pose: true,
        }
    }

    /// Sets [`Self::max_iterations`]. Default: `30`.
    #[must_use]
    pub fn max_iterations(mut self, max_iterations: usize) -> Self {
        self.max_iterations = max_iterations;
        self
    }

    /// Sets [`Self::relative_fitness`]. Default: `1e-6`.
    #[must_use]
    pub fn relative_fitness(mut self, relative_fitness: f64) -> Self {
        self.relative_fitness = relative_fitness;
        self
    }

    /// Sets [`Self::relative_rmse`] \[m\]. Default: `1e-6`.
    #[must_use]
    pub fn relative_rmse(mut self, relative_rmse_m: f64) -> Self {
        self.relative_rmse = relative_rmse_m;
        self
    }

    /// Sets [`Self::min_update`]: translation \[m\] and rotation \[rad\]. Default: none.
    #[must_use]
    pub fn min_update(mut self, translation_m: f64, rotation_rad: f64) -> Self {
        self.min_update = Some((translation_m, rotation_rad));
        self
    }

    /// Sets [`Self::measure_final_pose`]. Default: `true`.
    #[must_use]
    pub fn measure_final_pose(mut self, measure: bool) -> Self {
        self.measure_final_pose = measure;
        self
    }

    /// Sets [`Self::robust_kernel`]. Default: [`RobustKernel::L2`].
    #[must_use]
    pub fn robust_kernel(mut self, robust_kernel: RobustKernel) -> Self {
        self.robust_kernel = robust_kernel;
        self
    }

    fn validate(&self) -> Result<()> {
        let d = self.max_correspondence_distance_m;
        if !(d.is_finite() && d > 0.0) {
            return Err(Error::InvalidInput(format!(
                "max_correspondence_distance_m must be finite and > 0, got {d}"
            )));
        }
        let non_negative = |x: f64| x >= 0.0;
        let (min_t, min_r) = self.min_update.unwrap_or((0.0, 0.0));
        if ![self.relative_fitness, self.relative_rmse, min_t, min_r]
            .into_iter()
            .all(non_negative)
        {
            return Err(Error::InvalidInput(format!(
                "convergence thresholds must be >= 0, got relative_fitness {} relative_rmse {} min_update {:?}",
                self.relative_fitness, self.relative_rmse, self.min_update
            )));
        }
        self.robust_kernel.validate()
    }
}

/// Outcome of [`registration_icp_point_to_plane`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct IcpResult {
    /// Estimated pose mapping source-frame points into the target frame.
    pub target_from_source: Isometry3<f64>,
    /// Inlier correspondences / source points at `target_from_source`, in [0, 1] (Open3D's
    /// `fitness`).
    pub fitness: f64,
    /// Root mean square point-to-point distance over the inlier correspondences at
    /// `target_from_source` \[m\]; 0 when there are none (Open3D's `inlier_rmse`).
    pub inlier_rmse_m: f64,
    /// Number of transformation updates applied.
    pub iterations: usize,
    /// Whether the fitness/RMSE changes fell below the thresholds before `max_iterations`.
    pub converged: bool,
    /// The point-to-plane normal equations of the last correspondence pass (at
    /// `target_from_source`, or at the pose one update before it when
    /// [`IcpConfig::measure_final_pose`] is off): what the pose's covariance follows from.
    pub hessian: IcpHessian,
}

/// The Gauss–Newton normal matrix of a point-to-plane registration at its pose, and the
/// residuals it came from: `JᵀJ = Σ w J Jᵀ` with `J = (p × n, n)` (Low 2004, eq. 8 onwards) over
/// the correspondences, `p` the source point moved into the target frame and `n` its partner's
/// normal, for the left perturbation `T ← Exp(δ)·T` with `δ = (ω, t)` in the target frame.
///
/// Under independent residuals of variance `σ²` the estimate's covariance is `σ² (JᵀJ)⁻¹`
/// (the Gauss–Newton covariance, e.g. Censi, "An accurate closed-form estimate of ICP's
/// covariance", ICRA 2007, its first term); [`Self::information_in_source`] gives its inverse in
/// the source frame.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct IcpHessian {
    /// `Σ w J Jᵀ` in (rotation, translation) order. Units: m² (rotation block), m (mixed), 1
    /// (translation block).
    pub jtj: Matrix6<f64>,
    /// `Σ w r²` of the point-to-plane residuals `r = (p − q) · n` \[m²\] (with point-to-point
    /// rows, each kind weighed by its share: see the module doc).
    pub residual_sq_sum_m2: f64,
    /// Rows that contributed (weight above 0): one per point-to-plane correspondence, up to
    /// three per point-to-point one.
    pub count: usize,
}

impl IcpHessian {
    /// No correspondence: zero information.
    pub const ZERO: Self = Self {
        jtj: Matrix6::new(
            0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0,
            0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0,
            0.0, 0.0,
        ),
        residual_sq_sum_m2: 0.0,
        count: 0,
    };

    /// The residual variance `σ² = Σ w r² / (n − 6)` \[m²\] (six parameters estimated);
    /// `None` with 6 correspondences or fewer.
    #[must_use]
    pub fn residual_variance_m2(&self) -> Option<f64> {
        (self.count > 6).then(|| self.residual_sq_sum_m2 / (self.count - 6) as f64)
    }

    /// The information matrix `Ω = Ad(T)ᵀ (JᵀJ / σ²) Ad(T)` of the pose `T = target_from_source`
    /// for the right perturbation `T · Exp(δ)`, `δ` in the source frame, (rotation \[rad\],
    /// translation \[m\]) order — the pose graph's convention ([`crate::graph::se3`]): a left
    /// perturbation `ε` equals the right one `Ad(T⁻¹) ε`. `None` without a residual variance or
    /// when it is 0 or not finite.
    #[must_use]
    pub fn information_in_source(
        &self,
        target_from_source: &Isometry3<f64>,
    ) -> Option<Matrix6<f64>> {
        let variance = self.residual_variance_m2()?;
        if !(variance.is_finite() && variance > 0.0) {
            return None;
        }
        let ad = crate::graph::se3::adjoint(target_from_source);
        let omega = ad.transpose() * (self.jtj / variance) * ad;
        omega
            .iter()
            .all(|v| v.is_finite())
            .then(|| 0.5 * (omega + omega.transpose()))
    }
}

/// Fitness and inlier RMSE of a pose, as Open3D's `evaluate_registration`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RegistrationEvaluation {
    /// Inlier correspondences / source points, in [0, 1].
    pub fitness: f64,
    /// RMSE of point-to-point distances over inliers \[m\]; 0 when there are none.
    pub inlier_rmse_m: f64,
    /// Number of source points whose nearest target point is closer than the threshold.
    pub num_inliers: usize,
}

/// Least-squares sums of one kind of residual row: `Σ w J Jᵀ` (upper triangle, row-major),
/// `Σ w J r`, `Σ w r²` and the rows summed.
#[derive(Clone, Copy)]
struct RowSums {
    jtj_upper: [f64; 21],
    jtr: [f64; 6],
    residual_sq_sum: f64,
    rows: usize,
}

impl RowSums {
    const ZERO: Self = Self {
        jtj_upper: [0.0; 21],
        jtr: [0.0; 6],
        residual_sq_sum: 0.0,
        rows: 0,
    };

    /// Adds the row `r ≈ residual + jac · x` at weight `w`.
    fn add_row(&mut self, jac: &[f64; 6], residual: f64, w: f64) {
        self.residual_sq_sum += w * residual * residual;
        self.rows += 1;
        // Upper triangle only; mirrored once per pass.
        let mut u = 0;
        for a in 0..6 {
            let wa = w * jac[a];
            for jb in &jac[a..] {
                self.jtj_upper[u] += wa * jb;
                u += 1;
            }
            self.jtr[a] += wa * residual;
        }
    }

    fn add(&mut self, other: &Self) {
        for (a, b) in self.jtj_upper.iter_mut().zip(&other.jtj_upper) {
            *a += b;
        }
        for (a, b) in self.jtr.iter_mut().zip(&other.jtr) {
            *a += b;
        }
        self.residual_sq_sum += other.residual_sq_sum;
        self.rows += other.rows;
    }

    /// `self · a + other · b`, term by term.
    fn blend(&self, a: f64, other: &Self, b: f64) -> Self {
        let mut out = Self::ZERO;
        for (o, (x, y)) in out
            .jtj_upper
            .iter_mut()
            .zip(self.jtj_upper.iter().zip(&other.jtj_upper))
        {
            *o = a * x + b * y;
        }
        for (o, (x, y)) in out.jtr.iter_mut().zip(self.jtr.iter().zip(&other.jtr)) {
            *o = a * x + b * y;
        }
        out.residual_sq_sum = a * self.residual_sq_sum + b * other.residual_sq_sum;
        out.rows = self.rows + other.rows;
        out
    }
}

/// Sums over one pass of correspondence search at a fixed pose.
#[derive(Clone, Copy)]
struct PassSums {
    /// Point-to-plane rows, `J = (p × n, n)`.
    plane: RowSums,
    /// Point-to-point rows of the targets with no plane (zero normal): one per axis `e`,
    /// `J = (p × e, e)`, three per correspondence.
    point: RowSums,
    /// Correspondences that gave point-to-point rows.
    point_pairs: usize,
    /// `Σ |p − q|²` over inliers \[m²\].
    squared_distance_sum: f64,
    num_inliers: usize,
}

impl PassSums {
    fn zero() -> Self {
        Self {
            plane: RowSums::ZERO,
            point: RowSums::ZERO,
            point_pairs: 0,
            squared_distance_sum: 0.0,
            num_inliers: 0,
        }
    }

    fn add(&mut self, other: &Self) {
        self.plane.add(&other.plane);
        self.point.add(&other.point);
        self.point_pairs += other.point_pairs;
        self.squared_distance_sum += other.squared_distance_sum;
        self.num_inliers += other.num_inliers;
    }

    /// The rows of both kinds as one system: each kind weighted by its share of the
    /// correspondences, `α = planar / (planar + point)` for the point-to-plane rows and `1 − α`
    /// for the point-to-point ones, the adaptive weight of GenZ-ICP (Lee, Lim and Han, "GenZ-ICP:
    /// Generalizable and Degeneracy-Robust LiDAR Odometry Using an Adaptive Weighting", RA-L
    /// 2025). Without point-to-point rows, the point-to-plane sums unchanged.
    fn combined(&self) -> RowSums {
        if self.point.rows == 0 {
            return self.plane;
        }
        let (planar, point) = (self.plane.rows as f64, self.point_pairs as f64);
        let alpha = planar / (planar + point);
        self.plane.blend(alpha, &self.point, 1.0 - alpha)
    }

    fn hessian(&self) -> IcpHessian {
        let rows = self.combined();
        IcpHessian {
            jtj: upper_to_full(&rows.jtj_upper),
            residual_sq_sum_m2: rows.residual_sq_sum,
            count: rows.rows,
        }
    }

    /// The normal equations `(Σ w J Jᵀ, Σ w J r)`.
    fn normal_equations(&self) -> (Matrix6<f64>, Vector6<f64>) {
        let rows = self.combined();
        (upper_to_full(&rows.jtj_upper), Vector6::from(rows.jtr))
    }

    fn evaluation(&self, num_source: usize) -> RegistrationEvaluation {
        let (fitness, inlier_rmse_m) = if self.num_inliers == 0 {
            (0.0, 0.0)
        } else {
            (
                self.num_inliers as f64 / num_source as f64,
                (self.squared_distance_sum / self.num_inliers as f64).sqrt(),
            )
        };
        RegistrationEvaluation {
            fitness,
            inlier_rmse_m,
            num_inliers: self.num_inliers,
        }
    }
}

/// The symmetric matrix of an upper triangle stored row-major.
fn upper_to_full(upper: &[f64; 21]) -> Matrix6<f64> {
    let mut m = Matrix6::zeros();
    let mut u = 0;
    for a in 0..6 {
        for b in a..6 {
            m[(a, b)] = upper[u];
            m[(b, a)] = upper[u];
            u += 1;
        }
    }
    m
}

/// One parallel correspondence pass. With `kernel` set, also accumulates the normal equations
/// (target normals must be present). Deterministic: fixed chunks, summed in chunk order.
fn correspondence_pass(
    source: &[Point3<f64>],
    target: &IcpTarget,
    grid: Option<&RadiusGrid>,
    target_from_source: &Isometry3<f64>,
    max_distance_m: f64,
    kernel: Option<RobustKernel>,
) -> PassSums {
    let max_squared = max_distance_m * max_distance_m;
    // Only a pass that linearises reads the normals: asking for them estimates deferred ones
    // (all of a frame's ICP cloud), which a fitness alone (`evaluate_registration`, the loop's
    // overlap the other way on the query frame) does not need.
    let normals = kernel.and_then(|_| target.normals());
    let partials: Vec<PassSums> = source
        .par_chunks(CHUNK_POINTS)
        .map(|chunk| {
            let mut sums = PassSums::zero();
            for s in chunk {
                let p = target_from_source * s;
                // The grid hands back the point's coordinates with its index (its own copy, in
                // cache after the scan): no second read of the target's points.
                let nearest = match grid {
                    Some(grid) => grid
                        .nearest_within_point(&p)
                        .map(|(j, d, q)| (j as usize, d, q)),
                    None => target
                        .nearest(&p, max_squared)
                        .map(|(j, d)| (j, d, target.points[j])),
                };
                let Some((j, squared, q)) = nearest else {
                    continue;
                };
                // NOTE: strict `<` like Open3D's nanoflann radius search.
                if squared >= max_squared {
                    continue;
                }
                sums.num_inliers += 1;
                sums.squared_distance_sum += squared;
                if let (Some(kernel), Some(normals)) = (kernel, normals) {
                    let n = normals[j];
                    let d = p - q;
                    if n != NO_PLANE {
                        let residual = d.dot(&n);
                        let w = kernel.weight(residual);
                        if w != 0.0 {
                            let pxn = p.coords.cross(&n);
                            let jac = [pxn.x, pxn.y, pxn.z, n.x, n.y, n.z];
                            sums.plane.add_row(&jac, residual, w);
                        }
                    } else {
                        // No plane at `q`: the three axes' rows, each residual through the
                        // kernel (`p × e` for the unit axes e).
                        let p = p.coords;
                        let rows = [
                            ([0.0, p.z, -p.y, 1.0, 0.0, 0.0], d.x),
                            ([-p.z, 0.0, p.x, 0.0, 1.0, 0.0], d.y),
                            ([p.y, -p.x, 0.0, 0.0, 0.0, 1.0], d.z),
                        ];
                        let before = sums.point.rows;
                        for (jac, residual) in rows {
                            let w = kernel.weight(residual);
                            if w != 0.0 {
                                sums.point.add_row(&jac, residual, w);
                            }
                        }
                        sums.point_pairs += usize::from(sums.point.rows > before);
                    }
                }
            }
            sums
        })
        .collect();
    let mut total = PassSums::zero();
    for partial in &partials {
        total.add(partial);
    }
    total
}

/// Solves `jtj · x = −jtr` for the 6-vector update `(ω, t)`. Cholesky first; if the system is
/// not positive definite (degenerate geometry) falls back to an SVD least-squares solve that
/// leaves unconstrained directions at zero. `None` if both fail or give non-finite values.
fn solve_update(jtj: &Matrix6<f64>, jtr: &Vector6<f64>) -> Option<Vector6<f64>> {
    let rhs = -jtr;
    let finite = |x: &Vector6<f64>| x.iter().all(|v| v.is_finite());
    if let Some(cholesky) = jtj.cholesky() {
        let x = cholesky.solve(&rhs);
        if finite(&x) {
            return Some(x);
        }
    }
    let svd = jtj.svd(true, true);
    let largest = svd.singular_values.max();
    if largest.is_nan() || largest <= 0.0 {
        return None;
    }
    svd.solve(&rhs, largest * 1e-12).ok().filter(finite)
}

/// `(α, β, γ, tx, ty, tz)` → pose with rotation `Rz(γ)·Ry(β)·Rx(α)` and translation `t`
/// (Open3D's `TransformVector6dToMatrix4d`).
fn update_from_vector(x: &Vector6<f64>) -> Isometry3<f64> {
    Isometry3::from_parts(
        Translation3::new(x[3], x[4], x[5]),
        UnitQuaternion::from_euler_angles(x[0], x[1], x[2]),
    )
}

/// A grid over the target at the correspondence distance, where its extent allows: every
/// correspondence search then scans a few cells instead of descending the kd-tree. Measured on
/// the KITTI pair at 0.5 m (docs/PAIRWISE.md). Same pairs as the tree except between exactly
/// equidistant target points. Built once per target for the first distance asked for (kept in
/// the target); a distance down to a quarter of that one reuses it, another builds a grid for
/// that call.
fn correspondence_grid(
    target: &IcpTarget,
    max_distance_m: f64,
) -> Result<std::borrow::Cow<'_, Option<RadiusGrid>>> {
    let cap = default_max_columns(target.points.len());
    let build = || RadiusGrid::new(&target.points, max_distance_m, cap);
    let (d, grid) = match target.grid.get() {
        Some(kept) => kept,
        None => {
            let spare =
                std::mem::take(&mut *target.spare.lock().unwrap_or_else(|e| e.into_inner()));
            let grid = RadiusGrid::new_reusing(&target.points, max_distance_m, cap, spare)?;
            // Another thread may have set it meanwhile: either answers the same.
            let _ = target.grid.set((max_distance_m, grid));
            target.grid.get().expect("just set")
        }
    };
    // A kept grid of a larger radius answers a smaller one exactly: its nearest point within
    // `d` is the nearest within `max_distance_m` whenever one is (the caller checks the
    // distance). Up to 4× the radius; beyond, a grid of its own is cheaper to query.
    Ok(if *d >= max_distance_m && *d <= 4.0 * max_distance_m {
        std::borrow::Cow::Borrowed(grid)
    } else {
        std::borrow::Cow::Owned(build()?)
    })
}

/// Fitness and inlier RMSE of `target_from_source`, exactly as Open3D's `evaluate_registration`:
/// each source point moved into the target frame is paired with its nearest target point; pairs
/// closer than `max_correspondence_distance_m` \[m\] (strictly) are inliers; fitness = inliers /
/// source points, RMSE = sqrt(mean squared point-to-point distance over inliers) \[m\].
pub fn evaluate_registration(
    source: &[Point3<f64>],
    target: &IcpTarget,
    target_from_source: &Isometry3<f64>,
    max_correspondence_distance_m: f64,
) -> Result<RegistrationEvaluation> {
    if source.is_empty() {
        return Err(Error::InvalidInput("source cloud is empty".into()));
    }
    let d = max_correspondence_distance_m;
    if !(d.is_finite() && d > 0.0) {
        return Err(Error::InvalidInput(format!(
            "max_correspondence_distance_m must be finite and > 0, got {d}"
        )));
    }
    let grid = correspondence_grid(target, d)?;
    let sums = correspondence_pass(
        source,
        target,
        grid.as_ref().as_ref(),
        target_from_source,
        d,
        None,
    );
    Ok(sums.evaluation(source.len()))
}

/// Point-to-plane ICP from `init_target_from_source` (Open3D's `registration_icp` with
/// `TransformationEstimationPointToPlane`): iterate correspondence search, one linearised
/// Gauss-Newton step (Low 2004), and `target_from_source ← update · target_from_source`, until
/// both the fitness and the inlier RMSE change by less than the thresholds or
/// `config.max_iterations` updates were applied.
///
/// `target` must have normals ([`IcpTarget::new`]). Fitness and RMSE in the result are those
/// of the returned pose.
pub fn registration_icp_point_to_plane(
    source: &[Point3<f64>],
    target: &IcpTarget,
    init_target_from_source: &Isometry3<f64>,
    config: &IcpConfig,
) -> Result<IcpResult> {
    config.validate()?;
    if source.is_empty() {
        return Err(Error::InvalidInput("source cloud is empty".into()));
    }
    if target.normals().is_none() {
        return Err(Error::InvalidInput(
            "point-to-plane ICP needs target normals (use IcpTarget::new)".into(),
        ));
    }
    let max_distance_m = config.max_correspondence_distance_m;
    let kernel = Some(config.robust_kernel);
    let mut target_from_source = *init_target_from_source;
    let grid = correspondence_grid(target, max_distance_m)?;
    let pass = |pose: &Isometry3<f64>| {
        correspondence_pass(
            source,
            target,
            grid.as_ref().as_ref(),
            pose,
            max_distance_m,
            kernel,
        )
    };
    let mut sums = pass(&target_from_source);
    let mut evaluation = sums.evaluation(source.len());
    let mut iterations = 0;
    let mut converged = false;
    while iterations < config.max_iterations {
        // NOTE: Open3D keeps iterating with an identity update when there are no
        // correspondences (or the solve fails) and then reports convergence; we stop and report
        // `converged = false`.
        if sums.num_inliers == 0 {
            break;
        }
        let (jtj, jtr) = sums.normal_equations();
        let Some(x) = solve_update(&jtj, &jtr) else {
            break;
        };
        target_from_source = update_from_vector(&x) * target_from_source;
        target_from_source.rotation.renormalize();
        iterations += 1;
        let small_update = config.min_update.is_some_and(|(t, r)| {
            x.fixed_rows::<3>(3).norm() < t && x.fixed_rows::<3>(0).norm() < r
        });
        let last = small_update || iterations == config.max_iterations;
        if last && !config.measure_final_pose {
            converged = small_update;
            break;
        }
        sums = pass(&target_from_source);
        let next = sums.evaluation(source.len());
        let small_change = small_update
            || ((next.fitness - evaluation.fitness).abs() < config.relative_fitness
                && (next.inlier_rmse_m - evaluation.inlier_rmse_m).abs() < config.relative_rmse);
        evaluation = next;
        if small_change {
            converged = true;
            break;
        }
    }
    Ok(IcpResult {
        target_from_source,
        fitness: evaluation.fitness,
        inlier_rmse_m: evaluation.inlier_rmse_m,
        iterations,
        converged,
        hessian: sums.hessian(),
    })
}

/// [`evaluate_registration`] and the point-to-plane normal matrix at the same pose, in one pass
/// (plain least-squares weights). `target` must have normals.
pub(crate) fn evaluate_with_hessian(
    source: &[Point3<f64>],
    target: &IcpTarget,
    target_from_source: &Isometry3<f64>,
    max_correspondence_distance_m: f64,
) -> Result<(RegistrationEvaluation, IcpHessian)> {
    let grid = correspondence_grid(target, max_correspondence_distance_m)?;
    let sums = correspondence_pass(
        source,
        target,
        grid.as_ref().as_ref(),
        target_from_source,
        max_correspondence_distance_m,
        Some(RobustKernel::L2),
    );
    Ok((sums.evaluation(source.len()), sums.hessian()))
}

#[cfg(test)]
mod tests;
#[cfg(test)]
mod tests_covariance;
#[cfg(test)]
mod tests_no_plane;
