//! Consecutive-frame registration: a stream of prepared frames → a trajectory. Pure; no file I/O.
//!
//! Frame `k` is registered globally (MI-RANSAC + ICP, no motion prior) to the last frame that had
//! usable data, giving `prev_from_curr`; the trajectory is `world_from_k = world_from_prev ·
//! prev_from_curr` with world = the first frame's sensor frame (../shared/docs/DESIGN.md §5). A frame that fails is
//! flagged with its reason and the trajectory continues on a constant-velocity prediction, refined by
//! ICP when that fits; one bad frame never stops the run.
//!
//! With [`OdometryConfig::local_map`] (the default) each frame is then refined against a local map
//! of the recent accepted frames in the world ([`LocalMap`]), so that small frame-to-frame errors
//! do not add up: point-to-plane ICP starts from each initial guess that makes sense — the global
//! estimate and the constant-velocity prediction — and the one that fits the map best wins
//! (docs/ODOMETRY.md). The global estimate stays prior-free, so a dropped frame, a jump or a kidnap
//! still recovers: its start wins where the prediction is wrong.

mod map_fit;
mod map_input;
pub mod retry;
pub mod stream;
pub mod suspect;
pub mod uncertainty;

pub use map_fit::keep_map_fine_points;
use map_fit::{map_icp_distance, map_target};
use map_input::add_to_map;

use nalgebra::{Isometry3, Matrix6};
use serde::{Deserialize, Serialize};

use crate::Result;
use crate::geometry::radius_grid::cell_edge;
use crate::pipeline::{
    FailureReason, PairConfig, PairResult, PreparedFrame, refine_prepared, register_prepared_coarse,
};
use crate::refine::icp::{IcpConfig, IcpHessian, IcpTarget, registration_icp_point_to_plane};
use crate::refine::local_map::{LocalMap, LocalMapConfig};

/// Acceptance thresholds on top of the pairwise configuration.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct OdometryConfig {
    /// Pairwise registration settings.
    pub pair: PairConfig,
    /// A registration with fewer RANSAC inliers is a failure. Default 12.
    pub min_inliers: usize,
    /// A registration whose ICP fitness is lower is a failure. Default 0.3.
    pub min_fitness: f64,
    /// Refine each frame against a local map of recent frames. Default `true`.
    pub local_map: bool,
    /// Points kept per map voxel (the map voxel is the ICP voxel). Default 5
    /// (KISS-ICP: 20; 5 gave the same fixture ATE at less cost, docs/ODOMETRY.md).
    pub map_max_points_per_voxel: usize,
    /// `mireg register` runs descriptors, matching and RANSAC on a coarser cloud of at most
    /// this many points when the voxel cloud of the first frame has more
    /// ([`crate::pipeline::feature_voxel_for_cloud`]); ICP and the local map keep the voxel
    /// cloud. 0 keeps everything on the voxel cloud. Default
    /// [`crate::pipeline::DEFAULT_FEATURE_POINTS`] (2 000).
    pub feature_points: usize,
    /// After ICP against the map, a last stage whose source is the frame's own input points
    /// ([`MAP_FINE_POINTS_PER_ICP_POINT`] per ICP-cloud point, at most [`MAP_FINE_MAX_POINTS`],
    /// a seeded uniform draw) at half the map distance, at most [`MAP_FINE_MAX_ITERATIONS`]
    /// updates. Default `true` (`--no-map-fine` turns it off).
    ///
    /// NOTE: on by default since 2026-12-02, by measurement (docs/ODOMETRY.md, median ATE over
    /// seeds 0–4): micro211 1.215 → 1.190 cm (KISS-ICP 1.202), KAIST03 2.42 → 2.24 cm, its gap
    /// logs 2.57 → 2.45 and 2.58 → 2.30 cm, the fixture 1.192 → 1.199 cm; the parked car's drift
    /// 4.9 → 1.4 mm (5.8 → 7.8 mm at a 0.5 m voxel); for about 10 % of the frame rate. Where
    /// consecutive frames sample the surface alike, the centroids' biases cancel between frame
    /// and map and the input points' do not: that is the parked car at 0.5 m.
    pub map_fine: bool,
    /// Refine each frame on the local map from the constant-velocity prediction first, and run
    /// global registration (features, matching, MI-RANSAC) only when that fit is doubtful
    /// ([`TRACK_FITNESS_RATIO`], [`DOUBTFUL_MAP_FITNESS`], [`TRACK_MIN_DEGENERACY`]). Default
    /// `true`; `false` (`--global-every-frame`) registers every frame globally, as the paper
    /// registers every pair.
    ///
    /// NOTE: on by default since 2026-12-07, by measurement (docs/ODOMETRY.md "Tracking
    /// first"): over seeds 0–7 of the eleven shared logs every median ATE is the same as
    /// registering every frame globally or lower, for 1.05–1.5× the frame rate where frames are
    /// tracked; the KITTI replay (whose frames alternate between two scans) and the 25° cone
    /// (every fit weak) track none and keep their poses bit for bit.
    pub track_first: bool,
}

/// Input points per ICP-cloud point in the map ICP's fine stage ([`OdometryConfig::map_fine`]).
///
/// As the pairwise fine stage ([`crate::pipeline::refine`]), for the same reason: the ICP cloud's
/// voxel centroids are biased samples of the surface. Measured on micro211 and KAIST03
/// (docs/ODOMETRY.md): 8 per point with up to 30 updates took 50–64 % longer per log; 2 per point
/// with two updates gave the same ATE for 8–20 %.
pub const MAP_FINE_POINTS_PER_ICP_POINT: usize = 2;

/// Input points per ICP point that `mireg register`'s frames draw
/// ([`PairConfig::icp_fine_points_per_icp_point`]), of which the map's fine stage keeps
/// [`MAP_FINE_POINTS_PER_ICP_POINT`] ([`keep_map_fine_points`]).
///
/// NOTE: 8, the pairwise stage's draw when the map's fine stage was measured (docs/ODOMETRY.md);
/// the pairwise default moved to 6 with its new target, and a different draw would pick other
/// points and change the trajectories those figures describe.
///
/// [`PairConfig::icp_fine_points_per_icp_point`]: crate::pipeline::PairConfig::icp_fine_points_per_icp_point
pub const MAP_FINE_DRAW_PER_ICP_POINT: usize = 8;

/// At most this many input points in the map ICP's fine stage. What it averages out, the voxel
/// centroids' bias, needs a number of samples, not a fraction of a dense LiDAR frame. Median ATE
/// over seeds 0–4 (docs/ODOMETRY.md): 2 000 against 8 000 gave micro211 1.190 / 1.192 cm, KAIST03
/// 2.24 / 2.36 cm, its gap logs 2.45 / 2.43 and 2.30 / 2.46 cm, the fixture 1.199 / 1.193 cm, at
/// about 10 % of the frame rate instead of 15–18 %.
pub const MAP_FINE_MAX_POINTS: usize = 2_000;

/// Most updates of the map ICP's fine stage: it starts from the converged map ICP.
pub const MAP_FINE_MAX_ITERATIONS: usize = 2;

impl Default for OdometryConfig {
    fn default() -> Self {
        Self {
            pair: PairConfig::default(),
            min_inliers: 12,
            min_fitness: 0.3,
            local_map: true,
            map_max_points_per_voxel: 5,
            feature_points: crate::pipeline::DEFAULT_FEATURE_POINTS,
            map_fine: true,
            track_first: true,
        }
    }
}

/// Whether a fit lets tracking go on ([`OdometryConfig::track_first`]): ICP moved the
/// prediction by `miss` \[m\], at most [`TRACK_MAX_CORRECTION_DISTANCES`] map distances
/// (`distance` \[m\]), and the registration's information `omega` constrains every direction
/// (smallest over largest eigenvalue of the translation and rotation blocks,
/// [`uncertainty::degeneracy`], at least [`TRACK_MIN_DEGENERACY`]; `false` without one). The
/// rule a tracked fit must meet, and the one that lets the next frame try tracking.
fn tracks_on(miss: f64, distance: f64, omega: Option<&Matrix6<f64>>) -> bool {
    miss <= TRACK_MAX_CORRECTION_DISTANCES * distance
        && omega.is_some_and(|omega| {
            let (t, r) = uncertainty::degeneracy(omega);
            t.min(r) >= TRACK_MIN_DEGENERACY
        })
}

/// How a failed frame's pose was obtained.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Fallback {
    /// The previous relative motion, refined by ICP (fitness above the minimum).
    ConstantVelocityIcp,
    /// The previous relative motion, unrefined.
    ConstantVelocity,
}

/// Convergence of ICP against the local map: stop when fitness changes by less than this and the
/// inlier RMSE by less than this fraction of the correspondence distance (1e-4: 0.05 mm at a 0.5 m
/// distance). Open3D's 1e-6 took 10 iterations on the KAIST03 keyframes where the pose had
/// settled after a few (docs/ODOMETRY.md).
pub const MAP_ICP_RELATIVE_CHANGE: f64 = 1e-4;

/// ICP against the local map also stops once an update moves the pose by less than this
/// fraction of the correspondence distance and rotates it by less than this many degrees:
/// (0.003, 0.0057°), i.e. 1.1 mm and 1e-4 rad at KAIST03's 0.37 m voxel. On the KAIST03
/// keyframes the fitness and RMSE criteria alone took 9 iterations from the global estimate,
/// the last ones moving the pose by tenths of a millimetre (docs/ODOMETRY.md).
pub const MAP_ICP_MIN_UPDATE: (f64, f64) = (0.003, 0.0057);

/// Most updates of map ICP with the whole ICP cloud as source after a coarse stage (a uniform
/// stride of the same cloud, as many points as the global-registration cloud) has converged:
/// that stage's optimum is the whole cloud's up to its sampling, so the whole cloud only
/// finishes it. Measured on KAIST03 (docs/ODOMETRY.md): ATE 2.46 → 2.42 cm against the
/// feature cloud first and the ICP cloud run to convergence, 1.30–1.48 → 1.10–1.27 s of CPU.
pub const MAP_ICP_MAX_ITERATIONS_AFTER_COARSE: usize = 2;

/// Where the map ICP's coarse source is every k-th point of the ICP cloud with k at least this
/// (4: at most a quarter of it), and the fine stage follows ([`OdometryConfig::map_fine`]), the
/// fine stage starts from the converged coarse stage: the whole ICP cloud's updates between them
/// ([`MAP_ICP_MAX_ITERATIONS_AFTER_COARSE`]) are skipped. The fine stage still measures the final
/// pose on the whole ICP cloud (fitness, Hessian). A coarse stage stopped by its iteration cap
/// is finished by the whole cloud as before.
///
/// NOTE: departs from the coarse-to-fine order measured when the fine stage came in: with a
/// sparse coarse source the whole cloud's one or two updates were most of the map ICP's
/// searches (the KITTI replay: every 8th point of the ICP cloud in the coarse stage), and the
/// fine stage that follows moves the pose again. Measured 2026-12-07 (docs/ODOMETRY.md "The
/// fine stage finishes a sparse coarse stage"): wall time −15 % on the KITTI replay, −13 % on
/// KAIST03, −10 % on its gap log; ATE median over seeds 0–7 within 2 % on KAIST03 and its gap
/// logs (two of five lower by 3 %, one higher by 2.0 %) and 0.048 → 0.050 cm on the replay;
/// logs whose coarse source is denser keep their poses bit for bit. With k ≥ 2 (the 5–7
/// k-point cones too) the 40° cone with gaps rose 3.76 → 4.35 cm; without the cap's exception a
/// frame after a gap stepped 6 cm wrong.
pub const MAP_FINE_FINISHES_MIN_STRIDE: usize = 4;

/// A frame whose global estimate fits the local map with a fitness below this is doubtful: global
/// registration is retried on another RANSAC stream ([`SECOND_OPINION_SEED_OFFSET`]) and at a
/// coarser scale ([`retry`]), and the start that fits the map best wins. Default of the rule,
/// not a setting: 0.5.
///
/// NOTE: not in the paper. MI-RANSAC stops when the ranking's mass on the best model's inliers
/// makes a better model unlikely (`src/ransac/consensus.rs`); where a wrong model's inliers are
/// top-ranked correspondences (repeated structure) it can stop on that model. Measured on the
/// KITTI replay at its own voxel (docs/ODOMETRY.md): 3 of 16 seeds accepted such a frame (map
/// fitness 0.35–0.77 where the right pose fits at ~1.0) and the ATE rose from 0.07 cm to
/// 0.2–51 cm. On the real logs (KAIST03, micro211, the fixtures) no frame's map fitness is
/// below 0.73 or below 0.8× the frame before it: the rule costs them only the first frame's
/// second opinion ([`MAP_FITNESS_DROP`]).
pub const DOUBTFUL_MAP_FITNESS: f64 = 0.5;

/// ... or below this fraction of the previous accepted frame's map fitness: 0.8. The first frame
/// registered to the map has no previous fit to compare with and always gets the second opinion
/// (one more global registration per log): on the KITTI replay, seed 10's frame 1 fitted at 0.77
/// where the right pose fits at 0.81, and the ATE was 0.227 cm instead of 0.067.
pub const MAP_FITNESS_DROP: f64 = 0.8;

/// With [`OdometryConfig::track_first`], the prediction refined on the map is accepted without
/// global registration when its fitness is at least this fraction of the previous accepted
/// frame's (and at least [`DOUBTFUL_MAP_FITNESS`]): 0.9.
///
/// NOTE: not in the paper, which registers every pair globally. On a log whose motion the
/// prediction follows, global registration only confirms it, and it is most of a frame's cost
/// on small clouds (docs/ODOMETRY.md); a frame the prediction does not fit as well as the last
/// one gets the global registration as before.
pub const TRACK_FITNESS_RATIO: f64 = 0.9;

/// With [`OdometryConfig::track_first`], a tracked fit is accepted only if its registration
/// constrains every direction: the smallest over largest eigenvalue of its information
/// (translation and rotation blocks, [`uncertainty::degeneracy`]) at least this, 0.05
/// ([`suspect::UNCONFIRMED_DEGENERACY`], the lowest of any frame the shared logs register).
/// Along a weak direction (a floor alone, a corridor) the tracked pose is the prediction's,
/// confirmed by nothing: such a frame is registered globally, with its second opinions.
pub const TRACK_MIN_DEGENERACY: f64 = suspect::UNCONFIRMED_DEGENERACY;

/// With [`OdometryConfig::track_first`], a tracked fit is accepted only if ICP moved the
/// prediction by at most this many map correspondence distances: 3. Farther, the prediction
/// missed by more than the ICP's reach and its convergence from there proves little. Tracking is
/// tried only while the last accepted frame's prediction missed by no more
/// ([`Odometry::track_next`]): a rejected attempt costs its ICP and runs the global
/// registration after it rather than beside the map's update.
///
/// Measured 2026-12-07 (docs/ODOMETRY.md): the prediction's misses on KAIST03's keyframes are
/// 0.3–1.2 distances but at the turn (3.4, 10.8), on micro211 (a handheld depth camera, every
/// fourth frame) 0.4–4.3, median 1; on the KITTI replay, whose frames alternate between two
/// scans, 5.4 every frame, and ICP from there took 22 coarse updates where the global start took 8.
pub const TRACK_MAX_CORRECTION_DISTANCES: f64 = 3.0;

/// The second opinion's RANSAC seed is the configured seed plus this (the 64-bit golden ratio,
/// SplitMix64's increment): another stream, the same for any thread count.
pub const SECOND_OPINION_SEED_OFFSET: u64 = 0x9E37_79B9_7F4A_7C15;

/// Where the local-map refinement of a frame started.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum InitialGuess {
    /// The global (MI-RANSAC + frame-to-frame ICP) estimate.
    Global,
    /// The previous motion applied once more.
    ConstantVelocity,
    /// A second global estimate, from another RANSAC stream, where the first fitted the map
    /// doubtfully ([`DOUBTFUL_MAP_FITNESS`], [`MAP_FITNESS_DROP`]) and the second fitted better.
    SecondGlobal,
    /// A global estimate on clouds at [`retry::RETRY_VOXEL_FACTOR`] times the feature voxel,
    /// where the first (and second) fitted the map doubtfully or disagreed with the prediction,
    /// and it fitted better.
    CoarseGlobal,
    /// The prediction, accepted without global registration ([`OdometryConfig::track_first`]).
    Tracked,
}

impl InitialGuess {
    /// The snake_case name used in JSON output.
    pub fn as_str(&self) -> &'static str {
        match self {
            InitialGuess::Global => "global",
            InitialGuess::ConstantVelocity => "constant_velocity",
            InitialGuess::SecondGlobal => "second_global",
            InitialGuess::CoarseGlobal => "coarse_global",
            InitialGuess::Tracked => "tracked",
        }
    }

    /// Whether the start was a global registration's estimate (the first, or a retry's).
    pub fn is_global(&self) -> bool {
        matches!(
            self,
            InitialGuess::Global | InitialGuess::SecondGlobal | InitialGuess::CoarseGlobal
        )
    }
}

/// How a frame fitted the local map.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MapFit {
    /// The initial guess whose refinement fitted best.
    pub guess: InitialGuess,
    /// Fraction of the frame's ICP points within the correspondence distance of the map.
    pub fitness: f64,
    /// RMSE of those correspondences \[m\].
    pub inlier_rmse_m: f64,
    /// ICP iterations of the winning refinement (with the ICP cloud as source).
    pub iterations: usize,
    /// ICP iterations before those, with every k-th ICP point as source, as many as the
    /// global-registration cloud has (0 when global registration runs on the ICP cloud).
    pub coarse_iterations: usize,
    /// Updates of the fine stage after them, with the frame's input points as source
    /// ([`OdometryConfig::map_fine`]; 0 without).
    pub fine_iterations: usize,
    /// Points in the map it was registered to.
    pub map_points: usize,
    /// Whether the refined pose was used (its fitness reached `min_fitness`).
    pub used: bool,
    /// Seconds spent building the map target (points, normals, search grid).
    pub target_s: f64,
    /// Seconds spent in ICP against the map (every start).
    pub icp_s: f64,
    /// The winning refinement's point-to-plane normal matrix at its pose (its ICP cloud against
    /// the map, at the map distance): the frame's uncertainty ([`uncertainty`]).
    pub hessian: IcpHessian,
    /// Rounds of retries its global registration got ([`retry`]: another RANSAC stream and a
    /// coarser scale each), 0 when the first estimate was trusted.
    pub retry_rounds: usize,
    /// The best-fitting other start whose refinement ended elsewhere (beyond the map distance
    /// or 1° of the accepted pose), if any: a second answer the frame's registrations gave.
    pub rival: Option<Rival>,
}

/// A start of a frame's map refinement that fitted the map but ended away from the accepted
/// pose ([`MapFit::rival`]).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Rival {
    /// Its fitness on the map (as [`MapFit::fitness`]).
    pub fitness: f64,
    /// Its pose relative to the accepted one (`accepted⁻¹ · rival`).
    pub offset: Isometry3<f64>,
}

/// The estimate for one frame.
#[derive(Debug, Clone, PartialEq)]
pub struct FrameEstimate {
    /// 0-based frame number.
    pub index: usize,
    /// Pose of this frame in the world (the first frame's sensor frame).
    pub world_from_frame: Isometry3<f64>,
    /// Motion from this frame into the previous one used.
    pub prev_from_curr: Isometry3<f64>,
    /// `true` when global registration met the thresholds (always true for the first frame).
    pub success: bool,
    /// Why it failed, if it did.
    pub failure: Option<FailureReason>,
    /// How the pose was obtained after a failure.
    pub fallback: Option<Fallback>,
    /// Pairwise statistics (`None` for the first frame and frames without usable data).
    pub pair: Option<PairResult>,
    /// ICP iterations of the fallback refinement, if any.
    pub fallback_icp_iterations: usize,
    /// Input points.
    pub num_points: usize,
    /// Points after downsampling.
    pub num_points_downsampled: usize,
    /// The fit to the local map (`None` for the first frame, without a map, or without data).
    pub map: Option<MapFit>,
    /// The calibrated information of this frame's step ([`uncertainty::registration_information`]:
    /// right perturbation of `world_from_frame`, (rotation, translation) order) from the
    /// registration its pose came from: the map ICP's, or the frame-to-frame ICP's without a
    /// map fit, divided by [`suspect::SUSPECT_SIGMA_FACTOR`]² when the frame is suspect. `None`
    /// for the first frame and for failed frames.
    pub information: Option<Matrix6<f64>>,
    /// Why a registered frame is doubtful ([`suspect::judge`]), if it is.
    pub suspect: Option<suspect::Suspect>,
    /// When the frame joins the local map, the map keeps only what lies within this distance of
    /// its pose \[m\] (its farthest ICP point's range); `None` without a map or when the frame
    /// does not join it. Loop closure reads from these which places a later frame registered
    /// against ([`crate::loops::held_by_map`]).
    pub map_range_m: Option<f64>,
}

impl FrameEstimate {
    /// Frame `index` before registration: a success at the identity until found otherwise.
    fn new(index: usize, frame: &PreparedFrame) -> Self {
        Self::with_counts(index, frame.num_points, frame.points.len())
    }

    /// [`Self::new`] for a frame of `num_points` input points, `num_points_downsampled` after
    /// downsampling.
    fn with_counts(index: usize, num_points: usize, num_points_downsampled: usize) -> Self {
        Self {
            index,
            world_from_frame: Isometry3::identity(),
            prev_from_curr: Isometry3::identity(),
            success: true,
            failure: None,
            fallback: None,
            pair: None,
            fallback_icp_iterations: 0,
            num_points,
            num_points_downsampled,
            map: None,
            information: None,
            suspect: None,
            map_range_m: None,
        }
    }
}

/// The running state of consecutive-frame registration.
#[derive(Debug)]
pub struct Odometry {
    config: OdometryConfig,
    previous: Option<(PreparedFrame, Isometry3<f64>)>,
    velocity: Isometry3<f64>,
    frames: usize,
    map: Option<LocalMap>,
    /// The previous frame was accepted and is still to be added to the map: that happens while
    /// the next frame is registered globally (the two overlap on two cores).
    map_pending: bool,
    /// The previous frame's index.
    previous_index: usize,
    /// Frames the odometry is done with are kept here for [`Self::take_retired`] instead of
    /// being dropped ([`Self::keep_retired`]).
    keep_retired: bool,
    retired: Option<(usize, PreparedFrame)>,
    /// The last accepted frame's fit to the map (fitness), for [`MAP_FITNESS_DROP`].
    last_map_fitness: Option<f64>,
    /// How far the prediction was from each of the last [`retry::RECENT_MISSES`] frames
    /// accepted on the map \[m\], oldest first.
    prediction_misses: std::collections::VecDeque<f64>,
    /// Whether the next frame tries tracking ([`OdometryConfig::track_first`]): the last frame
    /// was accepted on the map, its prediction missed by at most
    /// [`TRACK_MAX_CORRECTION_DISTANCES`] map distances, and its fit constrained every direction
    /// ([`TRACK_MIN_DEGENERACY`]). An attempt bound to be rejected would cost its ICP and run the
    /// global registration after it rather than beside the map's update (a cone of 25° whose
    /// every fit is weak: 10 % of the frame rate).
    track_next: bool,
    /// The coarse retry's prepared frames, kept for the next retry.
    coarse_frames: retry::CoarseFrames,
}

impl Odometry {
    /// A new trajectory; fails if the pairwise configuration is invalid.
    pub fn new(mut config: OdometryConfig) -> Result<Self> {
        // Frames are refined against the local map (or, where it does not fit, frame to frame
        // as before): the pairwise fine stage is not part of odometry.
        config.pair.icp_fine = false;
        if !(0.0..=1.0).contains(&config.min_fitness) {
            return Err(crate::Error::InvalidInput(format!(
                "min_fitness must be a fraction in [0, 1], got {}",
                config.min_fitness
            )));
        }
        let c = config.pair.resolved()?;
        let map = config
            .local_map
            .then(|| {
                LocalMap::new(LocalMapConfig {
                    // NOTE: a hair (1e-6) above the ICP voxel, as the cells of a radius grid at
                    // the ICP distance: the map's voxels then serve as that grid
                    // (`LocalMap::target`), not re-bucketed every frame.
                    voxel_size_m: cell_edge(c.icp_voxel_size_m.unwrap_or(c.voxel_size_m)),
                    max_points_per_voxel: config.map_max_points_per_voxel,
                })
            })
            .transpose()?;
        Ok(Self {
            config,
            previous: None,
            velocity: Isometry3::identity(),
            frames: 0,
            map,
            map_pending: false,
            previous_index: 0,
            keep_retired: false,
            retired: None,
            last_map_fitness: None,
            prediction_misses: std::collections::VecDeque::with_capacity(retry::RECENT_MISSES),
            track_next: false,
            coarse_frames: retry::CoarseFrames::default(),
        })
    }

    /// Hand back each frame the odometry is done with ([`Self::take_retired`]) instead of
    /// dropping it: a frame is held as the previous frame until a later one replaces it. Off by
    /// default.
    pub fn keep_retired(&mut self, keep: bool) {
        self.keep_retired = keep;
    }

    /// The frame (with its index) that the last [`Self::push`] retired, when
    /// [`Self::keep_retired`] is on; each frame once. A frame too poor to register is never held
    /// and never retired.
    pub fn take_retired(&mut self) -> Option<(usize, PreparedFrame)> {
        self.retired.take()
    }

    /// The frame the odometry holds as the previous one, with its index: after [`Self::push`],
    /// the frame pushed unless it was too poor to register.
    pub fn previous_frame(&self) -> Option<(usize, &PreparedFrame)> {
        self.previous
            .as_ref()
            .map(|(f, _)| (self.previous_index, f))
    }

    /// The frame the odometry holds as the previous one (with its index), taking it: for the
    /// end of a trajectory, after which the odometry registers no more frames.
    pub fn take_previous(&mut self) -> Option<(usize, PreparedFrame)> {
        let index = self.previous_index;
        self.previous.take().map(|(f, _)| (index, f))
    }

    /// Makes `frame` (frame `index`, at `pose`) the previous frame, retiring the one before.
    fn set_previous(&mut self, index: usize, frame: PreparedFrame, pose: Isometry3<f64>) {
        let old = self.previous.replace((frame, pose));
        if self.keep_retired {
            self.retired = old.map(|(f, _)| (self.previous_index, f));
        }
        self.previous_index = index;
    }

    /// The configuration in force.
    pub fn config(&self) -> &OdometryConfig {
        &self.config
    }

    /// Registers the next frame and returns its estimate.
    pub fn push(&mut self, frame: PreparedFrame) -> Result<FrameEstimate> {
        let index = self.frames;
        self.frames += 1;
        let mut est = FrameEstimate::new(index, &frame);
        let last_map_fitness = self.last_map_fitness;
        let max_hypotheses = self.config.pair.max_hypotheses;
        let usable = frame.points.len() >= 3 && frame.icp.is_some();
        let Some((_, world_from_prev)) = &self.previous else {
            // The first frame defines the world.
            if usable {
                est.map_range_m = self.map_range(&frame);
                self.set_previous(index, frame, Isometry3::identity());
                self.map_pending = true;
            } else {
                est.success = false;
                est.failure = Some(FailureReason::TooFewPoints);
                est.fallback = Some(Fallback::ConstantVelocity);
            }
            return Ok(est);
        };
        let world_from_prev = *world_from_prev;
        if !usable {
            return Ok(self.skip_unusable(est, &world_from_prev));
        }

        // The constant-velocity prediction, before this frame updates the velocity.
        let predicted = world_from_prev * self.velocity;
        // Global registration, and meanwhile the map (with the previous frame added) as an ICP
        // target for this frame's refinements.
        let distance = map_icp_distance(&self.config.pair)?;
        let tracking = self.config.track_first && std::mem::take(&mut self.track_next);
        let Self {
            config,
            previous,
            map,
            map_pending,
            ..
        } = &mut *self;
        let (prev, _) = previous.as_ref().expect("checked above");
        let (pair, target) = if tracking {
            // The map first: the prediction refined on it may make global registration needless.
            let target = map_target(map, map_pending, &frame, prev, &world_from_prev, distance);
            if let Some(s) = target.as_ref().ok().copied().flatten()
                && let Some(tracked) =
                    self.track(&frame, s, (&predicted, distance), last_map_fitness)?
            {
                return Ok(self.accept_map_fit(est, frame, tracked, &world_from_prev, distance));
            }
            let (prev, _) = self.previous.as_ref().expect("checked above");
            (
                register_prepared_coarse(&frame, prev, &self.config.pair),
                target,
            )
        } else {
            rayon::join(
                || register_prepared_coarse(&frame, prev, &config.pair),
                || map_target(map, map_pending, &frame, prev, &world_from_prev, distance),
            )
        };
        let (mut pair, target_s) = (pair?, target?);
        let target = target_s.and_then(|s| {
            let map = self.map.as_ref()?;
            Some((map.built_target()?, s))
        });
        let (prev, _) = self.previous.as_ref().expect("checked above");
        // With a map, the RANSAC model is refined against it directly; only where that does not
        // fit is it refined frame to frame, as without a map.
        if let Some(target) = &target
            && let Some(fit) = self.global_on_map(
                (index, &frame),
                prev,
                *target,
                &mut pair,
                &world_from_prev,
                &predicted,
            )?
        {
            est.pair = Some(pair);
            return Ok(self.accept_map_fit(est, frame, fit, &world_from_prev, distance));
        }
        self.frame_to_frame(&mut est, &mut pair, &frame, prev)?;
        if est.success {
            self.velocity = est.prev_from_curr;
        }
        est.pair = Some(pair);
        est.world_from_frame = world_from_prev * est.prev_from_curr;
        if let Some(target) = target
            && let Some(fitness) =
                self.settle_on_map(&mut est, &frame, target, &world_from_prev, &predicted)?
        {
            self.velocity = est.prev_from_curr;
            self.last_map_fitness = Some(fitness);
        }
        suspect::judge(&mut est, last_map_fitness, max_hypotheses);
        self.map_pending = est.success || est.map.is_some_and(|m| m.used);
        if self.map_pending {
            est.map_range_m = self.map_range(&frame);
        }
        self.set_previous(index, frame, est.world_from_frame);
        Ok(est)
    }

    /// With [`OdometryConfig::track_first`]: the prediction refined on the built map target
    /// (built in `target_s` seconds; `distance` \[m\] the map's correspondence distance), if it
    /// fits well enough to skip global registration.
    fn track(
        &self,
        frame: &PreparedFrame,
        target_s: f64,
        (predicted, distance): (&Isometry3<f64>, f64),
        last_map_fitness: Option<f64>,
    ) -> Result<Option<(Isometry3<f64>, MapFit)>> {
        let (Some(target), Some(last)) = (
            self.map.as_ref().and_then(LocalMap::built_target),
            last_map_fitness,
        ) else {
            return Ok(None);
        };
        let Some((pose, fit)) = self.refine_on_map(frame, (target, target_s), None, predicted)?
        else {
            return Ok(None);
        };
        let good = fit.used
            && fit.fitness >= DOUBTFUL_MAP_FITNESS
            && fit.fitness >= TRACK_FITNESS_RATIO * last
            && tracks_on(
                retry::prediction_miss(&pose, predicted),
                distance,
                uncertainty::registration_information(&fit.hessian, &pose).as_ref(),
            );
        Ok(good.then_some((
            pose,
            MapFit {
                guess: InitialGuess::Tracked,
                ..fit
            },
        )))
    }

    /// Accepts `frame` at the pose its map fit found (a global start's or, with
    /// [`OdometryConfig::track_first`], the prediction's, [`Self::track`]): the step, the
    /// velocity, the information, the suspect rules, and the frame as the map's next one.
    fn accept_map_fit(
        &mut self,
        mut est: FrameEstimate,
        frame: PreparedFrame,
        (pose, fit): (Isometry3<f64>, MapFit),
        world_from_prev: &Isometry3<f64>,
        distance: f64,
    ) -> FrameEstimate {
        let last_map_fitness = self.last_map_fitness;
        // The first step's prediction is the identity, not a measured motion: not a miss.
        let mut miss = None;
        if last_map_fitness.is_some() {
            let predicted = world_from_prev * self.velocity;
            if self.prediction_misses.len() == retry::RECENT_MISSES {
                self.prediction_misses.pop_front();
            }
            let m = retry::prediction_miss(&pose, &predicted);
            self.prediction_misses.push_back(m);
            miss = Some(m);
        }
        est.prev_from_curr = world_from_prev.inverse() * pose;
        self.velocity = est.prev_from_curr;
        est.world_from_frame = pose;
        est.information = uncertainty::registration_information(&fit.hessian, &pose);
        self.track_next = miss.is_some_and(|m| tracks_on(m, distance, est.information.as_ref()));
        est.map = Some(fit);
        suspect::judge(&mut est, last_map_fitness, self.config.pair.max_hypotheses);
        self.last_map_fitness = Some(fit.fitness);
        est.map_range_m = self.map_range(&frame);
        self.set_previous(est.index, frame, pose);
        self.map_pending = true;
        est
    }

    /// [`FrameEstimate::map_range_m`] of `frame`, which joins the map.
    fn map_range(&self, frame: &PreparedFrame) -> Option<f64> {
        self.map.as_ref().and_then(|_| map_input::map_range(frame))
    }

    /// Whether a global start's fit to the map is doubtful: below [`DOUBTFUL_MAP_FITNESS`], or
    /// below [`MAP_FITNESS_DROP`] times the last accepted frame's, or there is no such frame yet.
    fn doubtful(&self, fitness: f64) -> bool {
        self.last_map_fitness.is_none() || self.fits_poorly(fitness)
    }

    /// `frame` registered frame to frame: the RANSAC model in `pair` refined by ICP on `prev`,
    /// or, where that fails or does not pass the thresholds, the constant-velocity fallback.
    /// Sets `est`'s step, success, failure, fallback and information.
    fn frame_to_frame(
        &self,
        est: &mut FrameEstimate,
        pair: &mut PairResult,
        frame: &PreparedFrame,
        prev: &PreparedFrame,
    ) -> Result<()> {
        if pair.failure.is_none() {
            refine_prepared(pair, frame, prev, &self.config.pair)?;
        }
        let failure = pair
            .failure
            .or(if pair.num_inliers < self.config.min_inliers {
                Some(FailureReason::TooFewInliers)
            } else if pair.fitness < self.config.min_fitness {
                Some(FailureReason::LowFitness)
            } else {
                None
            });
        if failure.is_none() {
            est.prev_from_curr = pair.target_from_source;
            est.information = pair
                .icp_hessian
                .and_then(|h| uncertainty::registration_information(&h, &pair.target_from_source));
        } else {
            est.success = false;
            est.failure = failure;
            let (pose, fallback, iterations) = self.constant_velocity(frame, prev)?;
            est.prev_from_curr = pose;
            est.fallback = Some(fallback);
            est.fallback_icp_iterations = iterations;
        }
        Ok(())
    }

    /// A frame registered frame to frame (or on its fallback), refined on the map from that
    /// pose (where it succeeded) or the prediction: where that fits, it is the frame's pose, and
    /// its fitness is returned.
    fn settle_on_map(
        &self,
        est: &mut FrameEstimate,
        frame: &PreparedFrame,
        target: (&IcpTarget, f64),
        world_from_prev: &Isometry3<f64>,
        predicted: &Isometry3<f64>,
    ) -> Result<Option<f64>> {
        let global = est.success.then_some(est.world_from_frame);
        let Some((pose, fit)) = self.refine_on_map(frame, target, global.as_ref(), predicted)?
        else {
            return Ok(None);
        };
        est.map = Some(fit);
        if !fit.used {
            return Ok(None);
        }
        est.world_from_frame = pose;
        if est.success {
            est.information = uncertainty::registration_information(&fit.hessian, &pose);
        }
        est.prev_from_curr = world_from_prev.inverse() * pose;
        Ok(Some(fit.fitness))
    }

    /// A frame too poor to register (after the first): flagged, placed on the constant-velocity
    /// prediction; the previous frame stays the reference, its prediction one step further.
    fn skip_unusable(
        &mut self,
        mut est: FrameEstimate,
        world_from_prev: &Isometry3<f64>,
    ) -> FrameEstimate {
        // The previous frame's pose is about to change: add it at the pose it was accepted at.
        self.flush_map();
        self.track_next = false;
        est.success = false;
        est.failure = Some(FailureReason::TooFewPoints);
        est.fallback = Some(Fallback::ConstantVelocity);
        est.prev_from_curr = self.velocity;
        est.world_from_frame = world_from_prev * self.velocity;
        self.previous = self.previous.take().map(|(f, _)| (f, est.world_from_frame));
        est
    }

    /// Adds the previous frame to the map now if it is pending.
    fn flush_map(&mut self) {
        if let (Some(map), Some((prev, pose))) = (&mut self.map, &self.previous)
            && std::mem::take(&mut self.map_pending)
        {
            add_to_map(map, prev, pose);
        }
    }

    fn constant_velocity(
        &self,
        frame: &PreparedFrame,
        prev: &PreparedFrame,
    ) -> Result<(Isometry3<f64>, Fallback, usize)> {
        let c = self.config.pair.resolved()?;
        if let (Some(src), Some(tgt)) = (&frame.icp, &prev.icp) {
            let icp = IcpConfig::new(c.icp_max_distance_m.unwrap_or(c.voxel_size_m))
                .max_iterations(c.icp_max_iterations);
            let r = registration_icp_point_to_plane(src.points(), tgt, &self.velocity, &icp)?;
            if r.fitness >= self.config.min_fitness {
                return Ok((
                    r.target_from_source,
                    Fallback::ConstantVelocityIcp,
                    r.iterations,
                ));
            }
        }
        Ok((self.velocity, Fallback::ConstantVelocity, 0))
    }
}
