//! Loop closure of a whole trajectory: the settings, scaled to the log, and the pose graph that
//! joins the odometry with the verified loops.
//!
//! Nodes are every frame's odometry pose (`world_from_sensor`); node 0 is held fixed. Edges:
//! - odometry, between consecutive frames: the odometry's relative pose, with the information
//!   its own registration measured ([`Step::Measured`]: the ICP Hessian, calibrated,
//!   [`crate::odometry::uncertainty`]) on top of the prior of an unmeasured step, so that a
//!   frame whose geometry pinned a direction down poorly is weak in that direction; a frame
//!   registered without that measurement gets [`LoopConfig::odometry_sigma_m`] /
//!   [`LoopConfig::odometry_sigma_deg`], a failed frame (its pose is the fallback's) the prior
//!   alone, [`FAILED_FRAME_SIGMA_FACTOR`]× those deviations;
//! - loop, between a verified pair: the loop's relative pose, with the information of its own
//!   registration likewise (or [`LoopConfig::loop_sigma_m`] / [`LoopConfig::loop_sigma_deg`]
//!   without one).
//!
//! Every edge is robust: the Cauchy kernel ([`crate::graph`]) down-weights an edge the rest of the
//! graph contradicts, a false loop that slipped through as much as a broken odometry step that
//! several loops contradict.
//!
//! NOTE: robust odometry edges depart from the usual loop-closure graph (Open3D's multiway
//! registration, KISS-SLAM, SC-A-LOAM trust every odometry edge): a step registered wrongly
//! "with success" then outvoted the loops that spanned it (docs/LOOPS.md).

use nalgebra::{Isometry3, Matrix6};
use serde::Serialize;

use super::candidates::CandidateConfig;
use super::keyframes::KeyframeConfig;
use super::verify::VerifyConfig;
use crate::graph::{Edge, GraphOptions, GraphSolution, PoseGraph, optimize};
use crate::odometry::uncertainty::diagonal_information;
use crate::{Error, Result};

/// The first solve of [`optimize_trajectory`] runs at [`LoopConfig::kernel_scale`] times this
/// over [`ANNEALING_FACTOR`]: 100 (nearly least squares for misclosures under ~100 σ).
pub const ANNEALING_START: f64 = 1000.0;
/// Each solve of [`optimize_trajectory`] divides the kernel scale by this: 10.
pub const ANNEALING_FACTOR: f64 = 10.0;

/// Default [`LoopConfig::kernel_scale`]: 5 σ. With every edge's information its registration's,
/// calibrated (NEES ≈ 6), a right edge's Mahalanobis distance is χ(6)-distributed: 2.4 on
/// average, above 3.5 for one edge in 20 and above 5 for one in 3 000. At 1 σ (the kernel's
/// scale when loops had a fixed deviation of 3 odometry steps) most right edges of a calibrated
/// graph ended with weights of 0.04–0.4 (`tests/injected_steps.rs`); at 5 σ none of its 115
/// true loops ends below 0.5 and its broken steps still below 0.01.
pub const DEFAULT_LOOP_KERNEL_SCALE: f64 = 5.0;

/// Standard deviations of a failed frame's odometry edge, relative to a registered one's: 100.
/// Its pose came from a constant-velocity guess or the previous pose; a loop may pull it freely.
pub const FAILED_FRAME_SIGMA_FACTOR: f64 = 100.0;

/// A loop registration's information is this times what the odometry's calibration gives the
/// same ICP Hessian ([`crate::odometry::uncertainty::registration_information`]): 0.25, i.e.
/// twice the deviations. A loop registers two frames seen from further apart, with less
/// overlap and at most [`DEFAULT_LOOP_ICP_SOURCE_POINTS`] query points, where the odometry
/// registers a frame against a map of many: its error is the larger for the same Hessian.
/// Measured against the references of the shared real logs (docs/LOOPS.md): at 1 the loops'
/// normalised errors (NEES, 6 for a calibrated 6-DoF covariance) had medians of 8.5–51 (the
/// fixture 51, KAIST03 cut to a 70° cone 33: rotation errors of 0.2° against a predicted
/// 0.07°); the odometry's, at the same calibration, 2.8–17.
pub const LOOP_INFORMATION_SCALE: f64 = 0.25;

/// Default [`LoopConfig::map_agreement_chi2`]: 16.81, the χ²(6) distribution's 99 % quantile.
pub const DEFAULT_MAP_AGREEMENT_CHI2: f64 = 16.812;

/// Everything loop closure needs, in metres and degrees. [`LoopConfig::for_voxel`] scales the
/// defaults to the log's voxel.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct LoopConfig {
    /// Path length \[m\] or rotation \[deg\] since the previous keyframe that makes a new one.
    pub keyframes: KeyframeConfig,
    /// The candidate search.
    pub candidates: CandidateConfig,
    /// The acceptance test.
    pub verify: VerifyConfig,
    /// Per-step standard deviation of an odometry edge's translation \[m\].
    pub odometry_sigma_m: f64,
    /// Per-step standard deviation of an odometry edge's rotation \[deg\].
    pub odometry_sigma_deg: f64,
    /// Standard deviation of a loop edge's translation \[m\].
    pub loop_sigma_m: f64,
    /// Standard deviation of a loop edge's rotation \[deg\].
    pub loop_sigma_deg: f64,
    /// The Cauchy kernel's scale on every edge \[σ\]. Default [`DEFAULT_LOOP_KERNEL_SCALE`].
    pub kernel_scale: f64,
    /// At most this many prepared frames are held at once while verifying. Default
    /// [`DEFAULT_FRAMES_IN_MEMORY`].
    pub frames_in_memory: usize,
    /// ... and at most as many as fit this budget \[bytes\] by what they hold idle
    /// ([`crate::pipeline::PreparedFrame::idle_bytes`]: the keyframes kept from the odometry at
    /// their own size, the frames read again by the first one's): small frames are held in
    /// larger numbers, so a long log is read fewer times. The search structures verification
    /// builds on a frame (its matching target and ICP grid) are kept for its next candidates
    /// while the frames in memory fit the budget, else dropped; at most one per thread exists
    /// beyond it. Default [`DEFAULT_LOOP_MEMORY_BYTES`].
    pub memory_budget_bytes: usize,
    /// The agreement test with the odometry applies up to this much path between the two
    /// frames \[m\]; beyond it the drift may be anything and only the robust graph judges.
    pub agreement_path_m: f64,
    /// A candidate whose query is within this much path \[m\] of an accepted loop's, and whose
    /// match is within as much path or odometry distance of that loop's match, is not tried: it
    /// would join the same two places again. 0 tries every candidate. Default
    /// 10 voxels: measured (`examples/loop_settings.rs`), it leaves 10 of KAIST03's 20 candidates
    /// and 17 of micro211's 50, the loop stage 0.44 → 0.27 s and 0.26 → 0.15 s, the loop-closed
    /// ATE 2.343 → 2.362 and 1.239 → 1.231 cm.
    pub redundant_path_m: f64,
    /// Verify with the pairwise fine ICP stage on the frames' input points
    /// ([`crate::pipeline::PairConfig::icp_fine`]). Default `false`: measured
    /// (`examples/loop_settings.rs`), without it KAIST03's loop stage took 0.53 s instead of 1.02 s
    /// and its loop-closed ATE was 2.34 cm instead of 2.39 (micro211: 1.239 against 1.234 cm).
    pub fine_icp: bool,
    /// At most this many query points in the verification's ICP
    /// ([`crate::pipeline::PairConfig::icp_max_source_points`]); `None` uses all. Default
    /// [`DEFAULT_LOOP_ICP_SOURCE_POINTS`].
    pub icp_source_points: Option<usize>,
    /// Keep the keyframes' frames that the odometry prepared, within the memory budget, so that
    /// verification need not read and prepare them again. `false` reads every candidate's frames
    /// again after the odometry (less memory while the odometry runs). Default `true`. Either
    /// way the loops found are the same.
    pub keep_odometry_frames: bool,
    /// A verified loop whose match's place the local map still held when the query registered
    /// ([`held_by_map`]), and that agrees with the odometry's relative pose of its two frames to
    /// a squared Mahalanobis distance at most this ([`map_agreement`]), stays out of the graph:
    /// the odometry measured the same relation. 0 puts every loop in the graph. Default
    /// [`DEFAULT_MAP_AGREEMENT_CHI2`].
    ///
    /// NOTE: not in the usual loop-closure graph, whose odometry edges are independent
    /// frame-to-frame steps. Ours register each frame against a local map that keeps every
    /// place within the sensor's range: on an out-and-back log the way back registers against
    /// the way out's points, and a loop between them repeats that measurement. Counted as new
    /// evidence it pulled trajectories without drift away from their odometry (docs/LOOPS.md).
    pub map_agreement_chi2: f64,
    /// Two accepted loops are consistent when the cycle they close through the odometry has a
    /// squared Mahalanobis error at most this (PCM, [`super::consistency`]); loops outside the
    /// largest mutually consistent set are dropped ([`super::judge_loops`]). 0 keeps every loop.
    /// Default [`super::consistency::DEFAULT_CONSISTENCY_CHI2`].
    pub consistency_chi2: f64,
    /// After the first solve, search for candidates again from the optimised poses and verify
    /// them, at most this many times, while new loops are accepted ([`super::close_in_rounds`]).
    /// 0 searches once, on the odometry. Default [`super::joint::DEFAULT_SEARCH_ROUNDS`].
    pub search_rounds: usize,
}

/// Default [`LoopConfig::icp_source_points`]: 4 000. Measured on the out-and-back logs
/// (docs/LOOPS.md): a KAIST03 query's ICP cloud has ~16 k points, and ICP was 64 % of a loop's
/// verification; at 4 000 the loop stage took 0.27 → 0.19 s (medians of 5 interleaved runs), the
/// loop-closed ATE 2.362 → 2.395 cm (its gap log 2.465 → 2.451 cm; the odometry's: 2.440 and
/// 2.489 cm), every loop still accepted; micro211's clouds are smaller and unchanged.
pub const DEFAULT_LOOP_ICP_SOURCE_POINTS: usize = 4000;
/// Default [`LoopConfig::frames_in_memory`]: 256 prepared frames.
pub const DEFAULT_FRAMES_IN_MEMORY: usize = 256;
/// Default [`LoopConfig::memory_budget_bytes`]: 128 MiB of idle frames (measured: 128 KAIST03
/// Ouster keyframes at a 0.37 m voxel, 1.05 MB each; micro211 depth frames, 0.37 MB each, are
/// held up to [`DEFAULT_FRAMES_IN_MEMORY`]).
pub const DEFAULT_LOOP_MEMORY_BYTES: usize = 128 << 20;

impl LoopConfig {
    /// The defaults for a log registered at an ICP voxel of `voxel_m` metres: lengths in voxels,
    /// so that a room-scale RGB-D log (voxel ~5 cm) and a street LiDAR log (~0.4 m) get the same
    /// behaviour. In voxels `v`: keyframes every 2.5 v of path or 10°; place radius 8 v growing
    /// by 2 % of the path between the frames up to 80 v; at least 20 v of path and 5 frames
    /// between the two frames of a loop; agreement with the odometry required up to 200 v of
    /// path; at most 2 candidates per keyframe, none within 10 v of path (both ends) of an accepted
    /// loop. Odometry edges σ = 0.1 v and 0.2° per step; loop
    /// edges 3× that, 0.3 v and 0.6°.
    ///
    /// Measured (`examples/loop_settings.rs`, docs/LOOPS.md) on the out-and-back logs of
    /// `tools/make_loop_logs.py`: loop σ at 1× the odometry's, the optimised ATE was above the
    /// odometry's on KAIST03 (2.58 against 2.44 cm); at 3×, 2.39 cm (and its gap log 2.45 against
    /// 2.49 cm), micro211 1.23 cm either way. A loop joins two frames seen from further apart
    /// than consecutive ones, with less overlap: its registration is the less certain.
    pub fn for_voxel(voxel_m: f64) -> Self {
        let v = voxel_m;
        Self {
            keyframes: KeyframeConfig {
                keyframe_distance_m: 2.5 * v,
                keyframe_angle_deg: 10.0,
            },
            candidates: CandidateConfig {
                place_radius_m: 8.0 * v,
                drift_fraction: 0.02,
                max_place_radius_m: 80.0 * v,
                min_path_separation_m: 20.0 * v,
                min_frame_separation: 5,
                max_per_query: 2,
                ..CandidateConfig::default()
            },
            verify: VerifyConfig::default(),
            odometry_sigma_m: 0.1 * v,
            odometry_sigma_deg: 0.2,
            loop_sigma_m: 0.3 * v,
            loop_sigma_deg: 0.6,
            kernel_scale: DEFAULT_LOOP_KERNEL_SCALE,
            frames_in_memory: DEFAULT_FRAMES_IN_MEMORY,
            memory_budget_bytes: DEFAULT_LOOP_MEMORY_BYTES,
            agreement_path_m: 200.0 * v,
            fine_icp: false,
            icp_source_points: Some(DEFAULT_LOOP_ICP_SOURCE_POINTS),
            keep_odometry_frames: true,
            redundant_path_m: 10.0 * v,
            map_agreement_chi2: DEFAULT_MAP_AGREEMENT_CHI2,
            consistency_chi2: super::consistency::DEFAULT_CONSISTENCY_CHI2,
            search_rounds: super::joint::DEFAULT_SEARCH_ROUNDS,
        }
    }

    /// The translation bound of the agreement test for two frames `path_m` of path apart:
    /// the place radius there ([`CandidateConfig::place_radius_for`]), or `None` beyond
    /// [`Self::agreement_path_m`].
    pub fn drift_allowance(&self, path_m: f64) -> Option<f64> {
        (path_m <= self.agreement_path_m).then(|| self.candidates.place_radius_for(path_m))
    }
}

/// A verified loop between two frames of the trajectory.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LoopEdge {
    /// The later frame (0-based index in the trajectory).
    pub query: usize,
    /// The earlier frame.
    pub matched: usize,
    /// The query frame's pose in the match frame (`p_match = T · p_query`).
    pub match_from_query: Isometry3<f64>,
    /// The calibrated information of `match_from_query` from its registration
    /// ([`crate::odometry::uncertainty::registration_information`]); `None` uses
    /// [`LoopConfig::loop_sigma_m`] and [`LoopConfig::loop_sigma_deg`].
    pub information: Option<Matrix6<f64>>,
}

/// What the pose graph knows of one odometry step (the motion into a frame from the one before).
// One per frame, held only while the graph is built: the size of the matrix is the point.
#[allow(clippy::large_enum_variant)]
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Step {
    /// Registered, with the calibrated information its registration measured
    /// ([`crate::odometry::FrameEstimate::information`]).
    Measured(Matrix6<f64>),
    /// Registered, without a measured information: [`LoopConfig::odometry_sigma_m`] and
    /// [`LoopConfig::odometry_sigma_deg`].
    Registered,
    /// Its registration failed: [`FAILED_FRAME_SIGMA_FACTOR`] times those deviations.
    Failed,
}

impl Step {
    /// [`Step::Registered`] or [`Step::Failed`].
    #[must_use]
    pub fn from_registered(registered: bool) -> Self {
        if registered {
            Self::Registered
        } else {
            Self::Failed
        }
    }
}

/// The information every measured edge of [`pose_graph`] has on top of its own: a failed
/// frame's, [`FAILED_FRAME_SIGMA_FACTOR`] times the configured odometry deviations, so that a
/// direction the registration did not measure is not free.
#[must_use]
pub fn edge_prior(config: &LoopConfig) -> Matrix6<f64> {
    diagonal_information(config.odometry_sigma_m, config.odometry_sigma_deg)
        / (FAILED_FRAME_SIGMA_FACTOR * FAILED_FRAME_SIGMA_FACTOR)
}

/// Whether every entry of `m` is finite.
fn finite(m: &Matrix6<f64>) -> bool {
    m.iter().all(|v| v.is_finite())
}

/// The pose graph of a trajectory (`poses`, with `steps[k]` what is known of the step into
/// frame `k`; `steps[0]` is not used) and its verified `loops`; see the module doc for the edges.
///
/// # Errors
/// [`Error::InvalidInput`] for mismatched lengths, a loop naming a frame outside the trajectory
/// or itself, non-positive standard deviations, or a non-finite information matrix.
pub fn pose_graph(
    poses: &[Isometry3<f64>],
    steps: &[Step],
    loops: &[LoopEdge],
    config: &LoopConfig,
) -> Result<PoseGraph> {
    if poses.len() != steps.len() {
        return Err(Error::InvalidInput(format!(
            "pose_graph: {} poses but {} odometry steps",
            poses.len(),
            steps.len()
        )));
    }
    for (name, s) in [
        ("odometry_sigma_m", config.odometry_sigma_m),
        ("odometry_sigma_deg", config.odometry_sigma_deg),
        ("loop_sigma_m", config.loop_sigma_m),
        ("loop_sigma_deg", config.loop_sigma_deg),
    ] {
        if !(s.is_finite() && s > 0.0) {
            return Err(Error::InvalidInput(format!(
                "{name} must be finite and > 0, got {s}"
            )));
        }
    }
    let odometry = diagonal_information(config.odometry_sigma_m, config.odometry_sigma_deg);
    let failed = edge_prior(config);
    let mut edges: Vec<Edge> = Vec::with_capacity(poses.len() + loops.len());
    for k in 1..poses.len() {
        let information = match &steps[k] {
            // The prior keeps a direction the registration did not measure from being free.
            Step::Measured(omega) if finite(omega) => omega + failed,
            Step::Measured(_) => {
                return Err(Error::InvalidInput(format!(
                    "odometry step {k}: its information is not finite"
                )));
            }
            Step::Registered => odometry,
            Step::Failed => failed,
        };
        edges.push(Edge {
            from: k - 1,
            to: k,
            measurement: poses[k - 1].inverse() * poses[k],
            information,
            robust: true,
        });
    }
    let loop_information = diagonal_information(config.loop_sigma_m, config.loop_sigma_deg);
    for l in loops {
        if l.query >= poses.len() || l.matched >= poses.len() || l.query == l.matched {
            return Err(Error::InvalidInput(format!(
                "loop {} → {} outside a trajectory of {} frames",
                l.query,
                l.matched,
                poses.len()
            )));
        }
        edges.push(Edge {
            from: l.matched,
            to: l.query,
            measurement: l.match_from_query,
            information: match &l.information {
                Some(omega) if finite(omega) => omega + failed,
                _ => loop_information,
            },
            robust: true,
        });
    }
    Ok(PoseGraph {
        poses: poses.to_vec(),
        edges,
    })
}

/// Whether the local map still held the place of frame `matched` when frame `query` registered
/// against it: `matched` joined the map (`ranges[matched]`, [`crate::odometry::FrameEstimate::map_range_m`]),
/// and no frame in between dropped it (each frame that joined kept what lies within its range
/// of its pose; `matched`'s origin stands for its place). `poses` are the odometry's.
#[must_use]
pub fn held_by_map(
    poses: &[Isometry3<f64>],
    ranges: &[Option<f64>],
    matched: usize,
    query: usize,
) -> bool {
    if matched >= query || query > poses.len() || query > ranges.len() {
        return false;
    }
    let place = poses[matched].translation.vector;
    ranges[matched].is_some()
        && (matched..query)
            .all(|k| ranges[k].is_none_or(|r| (poses[k].translation.vector - place).norm() <= r))
}

/// How far loop `l` lies from the odometry's relative pose of its two frames, `P = T_m⁻¹ T_q`,
/// where the odometry measured that relation itself: the query registered against the map
/// while it held the match's place ([`held_by_map`]) and every step between them registered
/// with a measured information. Then `P`'s error is the query's registration error (the match's
/// points sit at the match's pose either way), and the squared Mahalanobis distance is
/// `eᵀ (Σ_l + Σ_q)⁻¹ e`, `e = Log(Z⁻¹ P)` (the graph's residual of the loop edge `Z`), each
/// covariance the edge's information with the graph's prior ([`pose_graph`]) inverted. `None`
/// where the odometry did not measure the relation, or the loop has no information.
#[must_use]
pub fn map_agreement(
    poses: &[Isometry3<f64>],
    steps: &[Step],
    ranges: &[Option<f64>],
    l: &LoopEdge,
    config: &LoopConfig,
) -> Option<f64> {
    let (m, q) = (l.matched, l.query);
    if q >= steps.len() || !held_by_map(poses, ranges, m, q) {
        return None;
    }
    let prior = edge_prior(config);
    if !steps[m + 1..=q]
        .iter()
        .all(|s| matches!(s, Step::Measured(o) if finite(o)))
    {
        return None;
    }
    let Step::Measured(omega_q) = &steps[q] else {
        return None;
    };
    let omega_l = l.information.filter(finite)?;
    let sigma = (omega_l + prior).try_inverse()? + (omega_q + prior).try_inverse()?;
    let e = crate::graph::se3::log(&(l.match_from_query.inverse() * poses[m].inverse() * poses[q]));
    let d2 = (e.transpose() * sigma.try_inverse()? * e)[(0, 0)];
    d2.is_finite().then_some(d2)
}

/// The optimised trajectory: [`pose_graph`] solved by [`optimize`] with the Cauchy kernel, its
/// scale annealed from [`ANNEALING_START`]`/`[`ANNEALING_FACTOR`] times [`LoopConfig::kernel_scale`]
/// down to it (one solve per scale, each from the last). Without loops the graph is consistent and the trajectory is the
/// odometry's, returned as it is (no solve). Returns the poses and, with loops, the solution
/// (whose `edge_weights` end with one weight per loop, in order).
///
/// # Errors
/// As [`pose_graph`] and [`optimize`].
pub fn optimize_trajectory(
    poses: &[Isometry3<f64>],
    steps: &[Step],
    loops: &[LoopEdge],
    config: &LoopConfig,
) -> Result<(Vec<Isometry3<f64>>, Option<GraphSolution>)> {
    if loops.is_empty() || poses.len() < 2 {
        return Ok((poses.to_vec(), None));
    }
    let graph = pose_graph(poses, steps, loops, config)?;
    let solution = solve_annealed(graph, config.kernel_scale)?;
    Ok((solution.poses.clone(), Some(solution)))
}

/// `graph` solved by [`optimize`] with the Cauchy kernel, its scale annealed from
/// [`ANNEALING_START`]`/`[`ANNEALING_FACTOR`] times `kernel_scale` down to it (one solve per
/// scale, each from the last); the solution's `iterations` are summed over the solves.
///
/// # Errors
/// As [`optimize`].
pub fn solve_annealed(mut graph: PoseGraph, kernel_scale: f64) -> Result<GraphSolution> {
    // NOTE: graduated, as in graduated non-convexity (Yang et al. 2020) but on the Cauchy
    // kernel's scale: from a drifted start, a loop whose misclosure is many σ of the odometry
    // chain sits where the kernel is flat, and the drifted trajectory is a local minimum. Each
    // solve starts from the last, with the scale falling by ANNEALING_FACTOR to the configured
    // one: a nearly quadratic first solve pulls the trajectory towards the loops, the last
    // judges them.
    let mut scale = kernel_scale * ANNEALING_START;
    let mut iterations = 0;
    loop {
        scale = (scale / ANNEALING_FACTOR).max(kernel_scale);
        let options = GraphOptions {
            kernel_scale: scale,
            ..GraphOptions::default()
        };
        let mut solution = optimize(&graph, &options)?;
        iterations += solution.iterations;
        if scale <= kernel_scale {
            solution.iterations = iterations;
            return Ok(solution);
        }
        graph.poses.clone_from(&solution.poses);
    }
}
