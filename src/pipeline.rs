//! Registration of a pair of point clouds: preprocess → FPFH → correspondences → rank → MI-RANSAC →
//! point-to-plane ICP. Pure: clouds in, poses and statistics out; no file I/O.
//!
//! Each cloud is prepared once ([`prepare_frame`]) so that a stream of consecutive frames computes
//! every frame's features a single time, whether it serves as source or as target.

use std::time::Instant;

use nalgebra::{Isometry3, Point3, Vector3};
use serde::{Deserialize, Serialize};

use crate::correspondence::matching::{
    MatchConfig, MatchTarget, match_features_against, match_features_with,
};
use crate::correspondence::ranking::{
    CountOrder, Ranking, rank_by_distance, rank_by_neighbour_count, rank_by_ratio,
};
use crate::features::fpfh::{Fpfh, compute_fpfh_from_neighbourhoods, compute_fpfh_with_tree};
use crate::geometry::grid;
use crate::geometry::kdtree::{KdTree, Neighbourhoods};
use crate::geometry::normals::{
    NormalEstimate, estimate_normals_from_neighbourhoods, estimate_normals_with_tree,
};
use crate::geometry::radius_grid::default_max_columns;
use crate::geometry::voxel::{voxel_downsample, voxel_downsample_indexed};
use crate::ransac::consensus::{Consensus, ConsensusConfig, Scoring, Termination};
use crate::ransac::levy::{DEFAULT_SCALE, DEFAULT_WINDOW};
use crate::ransac::{
    DenseRigidEstimator, Estimator, Levy, OverlapTarget, Prosac, RigidEstimator, TruncatedLevy,
    Uniform, run_consensus,
};
use crate::refine::icp::IcpTarget;
use crate::{Error, Result};

pub mod refine;
mod resolution;
use refine::{feature_tree, fine_sample, refine};
pub use resolution::{
    DEFAULT_FEATURE_POINTS, FEATURE_VOXEL_STEP, VOXEL_PER_MEDIAN_RANGE, feature_voxel_for_cloud,
    voxel_for_cloud, with_feature_voxel,
};

/// Which sampler draws RANSAC hypotheses.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "snake_case")]
pub enum SamplerConfig {
    /// Plain RANSAC.
    Uniform,
    /// MI-RANSAC's truncated Lévy law over the ranks (Zhang & Chen, Sec. III).
    Levy {
        /// Location μ (< 0). Paper's best for registration: −50.
        mu: f64,
        /// Scale c. Default 1.
        c: f64,
        /// Truncation window m. Default 100.
        window: f64,
        /// Allow repeated indices within a sample, as the authors' code. Default false.
        with_replacement: bool,
    },
    /// PROSAC (Chum & Matas 2005) with `T_N = growth_max_samples`.
    Prosac {
        /// `T_N`. Default 200 000.
        growth_max_samples: u64,
    },
}

impl Default for SamplerConfig {
    fn default() -> Self {
        SamplerConfig::Levy {
            mu: -50.0,
            c: DEFAULT_SCALE,
            window: DEFAULT_WINDOW,
            with_replacement: false,
        }
    }
}

/// How correspondences are ranked before sampling.
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "snake_case")]
pub enum RankingConfig {
    /// The paper's metric: target descriptors within `radius` of the source descriptor.
    NeighbourCount {
        /// Descriptor radius τ_d \[FPFH units\]. Authors: 12.
        radius: f32,
        /// Sort direction. Authors: most first.
        order: CountOrder,
    },
    /// Ascending descriptor distance.
    Distance,
    /// Ascending Lowe ratio d1/d2.
    #[default]
    Ratio,
}

/// What a RANSAC hypothesis is scored against.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Verification {
    /// The putative correspondences: a model's support is the correspondences it maps within the
    /// inlier threshold (the paper's Algorithm 1, the authors' code, PCL).
    Correspondences,
    /// The whole feature clouds: a model's support is the source points that land within the
    /// inlier threshold of some target point (Open3D's fitness). Costs a nearest-neighbour query
    /// per source point and verified hypothesis; edge-length pre-rejection keeps those few (a few
    /// hundred to a few thousand per pair). See [`crate::ransac::DenseRigidEstimator`].
    #[default]
    Dense,
}

/// Every knob of pairwise registration. Fields set to `None` derive from `voxel_size_m` the way
/// Open3D users expect; [`PairConfig::resolved`] fills them in.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct PairConfig {
    /// Voxel size of the feature cloud \[m\]. Default 0.05.
    pub voxel_size_m: f64,
    /// Normal search radius \[m\]. Default 2 · voxel.
    pub normal_radius_m: Option<f64>,
    /// At most this many neighbours per normal. Default 30.
    pub normal_max_nn: usize,
    /// FPFH search radius \[m\]. Default 5 · voxel.
    pub feature_radius_m: Option<f64>,
    /// At most this many neighbours per FPFH. Default 100.
    pub feature_max_nn: usize,
    /// Keep only mutual nearest neighbours in feature space. Default false (as Open3D's default).
    pub mutual_filter: bool,
    /// Default: [`RankingConfig::Ratio`].
    pub ranking: RankingConfig,
    /// Default: Lévy μ = −50, c = 1, window 100.
    pub sampler: SamplerConfig,
    /// RANSAC inlier threshold \[m\]. Default 1.5 · voxel.
    pub inlier_threshold_m: Option<f64>,
    /// Edge-length pre-rejection similarity (0 disables). Default 0.9.
    pub edge_similarity: f64,
    /// Distance pre-rejection after estimation: a hypothesis is scored only if it maps each of
    /// its own sampled correspondences within the inlier threshold (Open3D's
    /// `CorrespondenceCheckerBasedOnDistance`, which its registration examples use at the same
    /// 1.5 · voxel). Default true. It saves scoring hypotheses whose sample does not even agree
    /// with itself, which matters most for the dense verification.
    pub sample_distance_check: bool,
    /// Cap on hypotheses. Default [`DEFAULT_PAIR_MAX_HYPOTHESES`] (200 000).
    pub max_hypotheses: u64,
    /// Adaptive-termination confidence. Default 0.999.
    pub confidence: f64,
    /// Local-optimisation refits. Default 10.
    pub lo_iterations: u32,
    /// Default: inlier count.
    pub scoring: Scoring,
    /// What hypotheses are scored against. Default: [`Verification::Dense`].
    ///
    /// NOTE: departs from the paper, which counts correspondence inliers. On the Stanford bunny
    /// 0°↔90° pair at 5 mm (30 random poses, `tools/compare_open3d.py`) the correct FPFH matches
    /// drop to 0–10 of ~1250 in a third of the poses (Open3D's features give the same counts), and
    /// a wrong pose with 30–45 coincidental matches wins; the true pose still overlaps ~56 % of the
    /// source against ≤ 47 % for those. Recall 19/30 → 24/30 with ICP, 16/30 → 24/30 without.
    pub verification: Verification,
    /// Run point-to-plane ICP after RANSAC. Default true.
    pub icp: bool,
    /// Voxel size of the ICP clouds \[m\]; 0 uses the full clouds. Default: the feature voxel, so ICP
    /// reuses the feature cloud and its normals.
    pub icp_voxel_size_m: Option<f64>,
    /// ICP max correspondence distance \[m\]. Default 1 · voxel.
    pub icp_max_distance_m: Option<f64>,
    /// ICP iterations (of each stage). Default 30.
    pub icp_max_iterations: usize,
    /// After ICP of the ICP clouds, a fine stage: point-to-plane ICP of the source's input
    /// points against the target's, at [`Self::icp_fine_distance_m`]. Each cloud draws
    /// [`Self::icp_fine_points_per_icp_point`] input points per ICP-cloud point (seeded); the
    /// target uses all of them, each on the plane fitted to the drawn points of its voxel, the
    /// source [`refine::FINE_SOURCE_POINTS_PER_ICP_POINT`] of them. Default true.
    /// `mireg register` refines against its local map instead and ignores it.
    pub icp_fine: bool,
    /// Input points per ICP-cloud point that the fine stage draws from each cloud (at least 1).
    /// Default [`refine::FINE_POINTS_PER_ICP_POINT`] (6).
    pub icp_fine_points_per_icp_point: usize,
    /// The fine stage's max correspondence distance \[m\]. Default 0.5 · `icp_max_distance_m`.
    pub icp_fine_distance_m: Option<f64>,
    /// Orient normals towards this point (the sensor origin in the cloud's frame) when known.
    /// Default: none.
    pub sensor_origin: Option<[f64; 3]>,
    /// Without a `sensor_origin`, orient normals towards the centroid of the downsampled cloud;
    /// `false` leaves them unoriented (the eigenvector's arbitrary sign, as Open3D). Default true.
    ///
    /// NOTE: departs from Open3D, whose unoriented normals flip with the pose of the cloud: the
    /// sign of a PCA normal follows the covariance's coordinates, so the same surface gets
    /// opposite normals in two clouds that differ by a rotation, and the FPFH pair features of
    /// its points change. The centroid moves with the cloud, so the orientation does not depend
    /// on the pose. Measured with `tools/compare_open3d.py` (10 random poses per pair; see
    /// docs/PAIRWISE.md): correct correspondences on KITTI 362 → 2,424 of 11,832, bunny
    /// 000↔090 recall 7/10 → 10/10; 3DMatch, whose fragments are seen from inside a room, keeps
    /// 10/10 with fewer inliers (81 → 55).
    pub orient_to_centroid: bool,
    /// Seed of all randomness. Default 0.
    pub seed: u64,
}

/// Default cap on RANSAC hypotheses for a pair (and for each frame of `register`): 200 000.
///
/// NOTE: twice Open3D's `RANSACConvergenceCriteria` default of 100 000, which the consensus core
/// keeps ([`crate::ransac::consensus::DEFAULT_MAX_HYPOTHESES`]). Adaptive termination stops easy
/// pairs after tens to hundreds of hypotheses (bunny, ICL-NUIM, KITTI), so the cap only costs time
/// where the inliers are too few for the confidence to be reached: on the 3DMatch pair, 30 posed
/// sources × 10 seeds succeeded 291/300 times at 100 000 and 299/300 at 200 000, for a RANSAC stage
/// about twice as long (docs/PAIRWISE.md).
pub const DEFAULT_PAIR_MAX_HYPOTHESES: u64 = 200_000;

impl Default for PairConfig {
    fn default() -> Self {
        Self {
            voxel_size_m: 0.05,
            normal_radius_m: None,
            normal_max_nn: 30,
            feature_radius_m: None,
            feature_max_nn: 100,
            mutual_filter: false,
            ranking: RankingConfig::default(),
            sampler: SamplerConfig::default(),
            inlier_threshold_m: None,
            edge_similarity: crate::ransac::estimator::DEFAULT_EDGE_SIMILARITY,
            sample_distance_check: true,
            max_hypotheses: DEFAULT_PAIR_MAX_HYPOTHESES,
            confidence: crate::ransac::consensus::DEFAULT_CONFIDENCE,
            lo_iterations: crate::ransac::consensus::DEFAULT_LO_ITERATIONS,
            scoring: Scoring::InlierCount,
            verification: Verification::default(),
            icp: true,
            icp_voxel_size_m: None,
            icp_max_distance_m: None,
            icp_max_iterations: crate::refine::icp::DEFAULT_MAX_ITERATIONS,
            icp_fine: true,
            icp_fine_points_per_icp_point: refine::FINE_POINTS_PER_ICP_POINT,
            icp_fine_distance_m: None,
            sensor_origin: None,
            orient_to_centroid: true,
            seed: 0,
        }
    }
}

impl PairConfig {
    /// A copy with every derived field filled in, after validation.
    pub fn resolved(&self) -> Result<Self> {
        let v = self.voxel_size_m;
        if !(v.is_finite() && v > 0.0) {
            return Err(Error::InvalidInput(format!(
                "voxel_size_m must be finite and > 0, got {v}"
            )));
        }
        if !(self.confidence > 0.0 && self.confidence < 1.0) {
            return Err(Error::InvalidInput(format!(
                "confidence must be in (0, 1), got {}",
                self.confidence
            )));
        }
        if !(0.0..=1.0).contains(&self.edge_similarity) {
            return Err(Error::InvalidInput(format!(
                "edge_similarity must be in [0, 1], got {}",
                self.edge_similarity
            )));
        }
        if self.icp_fine_points_per_icp_point == 0 {
            return Err(Error::InvalidInput(
                "icp_fine_points_per_icp_point must be at least 1, got 0".into(),
            ));
        }
        let mut r = self.clone();
        r.normal_radius_m.get_or_insert(2.0 * v);
        r.feature_radius_m.get_or_insert(5.0 * v);
        r.inlier_threshold_m.get_or_insert(1.5 * v);
        // NOTE: measured, not Open3D's habit of refining on a denser cloud: on the fixture log the
        // feature cloud gives ATE 1.66 cm vs 2.60 cm at voxel / 2 and 78 vs 52 frames/s (KITTI-size:
        // 7.4 vs 5.7 frames/s); on the ICL pair 4.8 vs 4.0 mm (docs/BENCHMARKS.md).
        r.icp_voxel_size_m.get_or_insert(v);
        let icp_distance = *r.icp_max_distance_m.get_or_insert(v);
        r.icp_fine_distance_m.get_or_insert(0.5 * icp_distance);
        for (name, x) in [
            ("normal_radius_m", r.normal_radius_m),
            ("feature_radius_m", r.feature_radius_m),
            ("inlier_threshold_m", r.inlier_threshold_m),
            ("icp_max_distance_m", r.icp_max_distance_m),
            ("icp_fine_distance_m", r.icp_fine_distance_m),
        ] {
            let x = x.unwrap_or(f64::NAN);
            if !(x.is_finite() && x > 0.0) {
                return Err(Error::InvalidInput(format!(
                    "{name} must be finite and > 0, got {x}"
                )));
            }
        }
        Ok(r)
    }
}

/// Wall-clock seconds per stage.
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize, Deserialize)]
pub struct FrameTimings {
    /// Voxel downsampling (feature and ICP clouds).
    pub downsample: f64,
    /// kd-tree + normals.
    pub normals: f64,
    /// FPFH.
    pub features: f64,
}

/// A cloud prepared once for registration as source or target.
#[derive(Debug)]
pub struct PreparedFrame {
    /// Points of the input cloud (finite ones).
    pub num_points: usize,
    /// Voxel-downsampled feature cloud.
    pub points: Vec<Point3<f64>>,
    /// FPFH per feature-cloud point.
    pub features: Vec<Fpfh>,
    /// The ICP cloud with normals and its kd-tree (as target); its points serve as ICP source.
    pub icp: Option<IcpTarget>,
    /// Input points drawn for the fine ICP stage ([`PairConfig::icp_fine`]); empty without.
    pub fine: Vec<Point3<f64>>,
    /// The voxel of the ICP cloud of each point of `fine` (its index there).
    fine_voxels: Vec<u32>,
    /// The search structures over `features` when the frame is a matching target, built on
    /// first use ([`PreparedFrame::match_target`]).
    match_target: std::sync::OnceLock<Option<MatchTarget>>,
    /// The fine stage's target made from `fine`, built when the frame first serves as a target
    /// ([`PreparedFrame::fine_target`]).
    fine_target: std::sync::OnceLock<Option<IcpTarget>>,
    /// The seed of the draw `fine`, which also seeds [`PreparedFrame::fine_source`]'s.
    fine_seed: u64,
    /// The fine stage's source made from `fine`, built when the frame first serves as a source.
    fine_source: std::sync::OnceLock<Vec<Point3<f64>>>,
    /// Time spent.
    pub timings: FrameTimings,
}

impl PreparedFrame {
    /// The search structures over this frame's descriptors as a matching target
    /// ([`MatchTarget`]), built on the first call; `None` without descriptors.
    pub fn match_target(&self) -> Option<&MatchTarget> {
        self.match_target
            .get_or_init(|| MatchTarget::new(&self.features))
            .as_ref()
    }

    /// The fine stage's target when this frame is the target ([`refine::fine_target`] of its
    /// drawn points and its ICP cloud), built on the first call. `None` without drawn points
    /// or ICP cloud.
    pub(crate) fn fine_target(&self) -> Result<Option<&IcpTarget>> {
        if let Some(built) = self.fine_target.get() {
            return Ok(built.as_ref());
        }
        let built = match &self.icp {
            Some(icp) if self.fine_voxels.len() == self.fine.len() => {
                refine::fine_target(&self.fine, &self.fine_voxels, icp)?
            }
            _ => None,
        };
        // Another thread may have built it meanwhile: both are the same.
        let _ = self.fine_target.set(built);
        Ok(self.fine_target.get().expect("just set").as_ref())
    }

    /// The fine stage's source when this frame is the source: a uniform draw of
    /// [`refine::FINE_SOURCE_POINTS_PER_ICP_POINT`] per ICP point from the drawn points (all of
    /// them when there are no more), seeded by the frame's own draw, built on the first call.
    pub(crate) fn fine_source(&self) -> &[Point3<f64>] {
        self.fine_source.get_or_init(|| {
            let icp_points = self.icp.as_ref().map_or(0, |icp| icp.points().len());
            let per_point = refine::FINE_SOURCE_POINTS_PER_ICP_POINT;
            // A seed of its own: the same seed would start the same random sequence.
            let seed = self.fine_seed ^ 0x9e37_79b9_7f4a_7c15;
            refine::fine_sample(&self.fine, None, icp_points, per_point, seed).0
        })
    }

    /// Replaces the drawn points by `kept` (a subset, for a caller that uses them only as a
    /// source); their voxels are dropped, so the frame no longer makes a fine target.
    pub(crate) fn keep_fine(&mut self, kept: Vec<Point3<f64>>) {
        self.fine = kept;
        self.fine_voxels = Vec::new();
        self.fine_target = Default::default();
        self.fine_source = Default::default();
    }
}

/// Storage that [`prepare_frame_with`] reuses from one frame to the next: a stream of similar
/// clouds allocates its largest intermediate, the FPFH neighbourhoods (~8 MB at HDL-64 size with a
/// 0.5 m voxel), once instead of mapping and unmapping it for every frame.
#[derive(Debug, Default)]
pub struct PrepareScratch {
    neighbourhoods: Neighbourhoods,
}

/// Mean of `points` (non-empty), summed in order.
fn centroid(points: &[Point3<f64>]) -> Point3<f64> {
    let sum = points
        .iter()
        .fold(nalgebra::Vector3::zeros(), |acc, p| acc + p.coords);
    Point3::from(sum / points.len() as f64)
}

/// Downsamples, estimates normals and FPFH, and builds the ICP cloud. `config` must be
/// [`resolved`](PairConfig::resolved).
pub fn prepare_frame(points: &[Point3<f64>], config: &PairConfig) -> Result<PreparedFrame> {
    prepare_frame_with(points, config, &mut PrepareScratch::default())
}

/// [`prepare_frame`] reusing `scratch` (keep one per stream of frames). The result does not
/// depend on what `scratch` held.
pub fn prepare_frame_with(
    points: &[Point3<f64>],
    config: &PairConfig,
    scratch: &mut PrepareScratch,
) -> Result<PreparedFrame> {
    let c = config.resolved()?;
    let origin = c.sensor_origin.map(Point3::from);
    let mut timings = FrameTimings::default();
    let t = Instant::now();
    let icp_voxel = c.icp_voxel_size_m.unwrap();
    // NOTE: with an ICP cloud finer than the feature cloud (`mireg register` on a dense LiDAR
    // frame), the feature cloud is downsampled from the ICP cloud, not from the input: a tenth
    // of the points to bucket (the KITTI scans: 124k input, 11k ICP points); its centroids are
    // means of centroids, which global registration does not notice.
    // The fine stage's draw keeps each drawn point's voxel of the ICP cloud (for the planes of
    // `refine::fine_target`); the downsampling that makes the ICP cloud records them.
    let draw_fine = c.icp && c.icp_fine && icp_voxel > 0.0;
    let (finer_icp_cloud, finer_ids) = if c.icp && icp_voxel > 0.0 && icp_voxel < c.voxel_size_m {
        let (cloud, ids) = downsample(points, icp_voxel, draw_fine)?;
        (Some(cloud), ids)
    } else {
        (None, None)
    };
    let (down, down_ids) = match &finer_icp_cloud {
        Some(finer) => (voxel_downsample(finer, c.voxel_size_m)?, None),
        None => downsample(
            points,
            c.voxel_size_m,
            draw_fine && icp_voxel == c.voxel_size_m,
        )?,
    };
    timings.downsample = t.elapsed().as_secs_f64();
    let origin =
        origin.or_else(|| (c.orient_to_centroid && !down.is_empty()).then(|| centroid(&down)));
    if down.len() < 3 {
        return Ok(PreparedFrame {
            num_points: points.len(),
            points: down,
            features: Vec::new(),
            icp: None,
            fine: Vec::new(),
            fine_voxels: Vec::new(),
            match_target: Default::default(),
            fine_target: Default::default(),
            fine_seed: c.seed,
            fine_source: Default::default(),
            timings,
        });
    }
    // The fine draw reads only the input points and the ICP cloud's size and voxels: when those
    // are already known it runs beside the features, on the core they leave idle at their ends.
    let icp_len = match &finer_icp_cloud {
        Some(cloud) => Some(cloud.len()),
        None => (icp_voxel == c.voxel_size_m).then_some(down.len()),
    };
    let early = icp_len.zip(finer_ids.or(down_ids)).filter(|_| draw_fine);
    let per_icp_point = c.icp_fine_points_per_icp_point;
    let (described, early_fine) = rayon::join(
        || {
            describe(
                points,
                &down,
                finer_icp_cloud,
                &c,
                origin,
                scratch,
                &mut timings,
            )
        },
        || early.map(|(n, ids)| fine_sample(points, Some(&ids), n, per_icp_point, c.seed)),
    );
    let Described {
        features,
        icp,
        icp_voxels: late_ids,
    } = described?;
    let (fine, fine_voxels) = match (early_fine, &icp) {
        (Some(drawn), _) => drawn,
        (None, Some(t)) if draw_fine => {
            let n = t.points().len();
            fine_sample(points, late_ids.as_deref(), n, per_icp_point, c.seed)
        }
        _ => (Vec::new(), Vec::new()),
    };
    Ok(PreparedFrame {
        num_points: points.len(),
        points: down,
        features,
        icp,
        fine,
        fine_voxels,
        match_target: Default::default(),
        fine_target: Default::default(),
        fine_seed: c.seed,
        fine_source: Default::default(),
        timings,
    })
}

/// A downsampled cloud and, when asked for, each input point's voxel in it.
type Downsampled = (Vec<Point3<f64>>, Option<Vec<u32>>);

/// [`voxel_downsample`] of `cloud`, with each point's voxel ([`voxel_downsample_indexed`]) when
/// `indexed`.
fn downsample(cloud: &[Point3<f64>], voxel_m: f64, indexed: bool) -> Result<Downsampled> {
    if indexed {
        voxel_downsample_indexed(cloud, voxel_m).map(|(down, ids)| (down, Some(ids)))
    } else {
        voxel_downsample(cloud, voxel_m).map(|down| (down, None))
    }
}

/// What [`describe`] makes of a downsampled frame.
struct Described {
    features: Vec<Fpfh>,
    icp: Option<IcpTarget>,
    /// Each input point's voxel of the ICP cloud, when the fine stage draws and the ICP cloud
    /// was made by [`describe`].
    icp_voxels: Option<Vec<u32>>,
}

/// The feature cloud's normals and FPFH, the ICP target (`None` without ICP) and, when the
/// fine stage draws and the ICP cloud is made here, each input point's voxel of it: the part of
/// [`prepare_frame_with`] after downsampling. `down` has at least 3 points.
fn describe(
    points: &[Point3<f64>],
    down: &[Point3<f64>],
    finer_icp_cloud: Option<Vec<Point3<f64>>>,
    c: &PairConfig,
    origin: Option<Point3<f64>>,
    scratch: &mut PrepareScratch,
    timings: &mut FrameTimings,
) -> Result<Described> {
    let icp_voxel = c.icp_voxel_size_m.unwrap();
    let mut icp_ids = None;
    let t = Instant::now();
    // NOTE: the kd-tree is built only where a search needs it: the grid answers the
    // neighbourhoods of most clouds, and ICP builds its own tree on first use. Building it for
    // every frame cost 2 % of a bunny pair's instructions, and `mireg register` dropped it unused.
    let mut tree = None;
    let (normal_radius, feature_radius) = (c.normal_radius_m.unwrap(), c.feature_radius_m.unwrap());
    let (normals, features) =
        if feature_radius >= normal_radius && c.feature_max_nn >= c.normal_max_nn {
            // One neighbourhood pass serves both: the normals' neighbourhoods are prefixes of the
            // FPFH ones (timed as features).
            let nbhd = &mut scratch.neighbourhoods;
            if !grid::self_neighbourhoods_into(down, feature_radius, c.feature_max_nn, nbhd)? {
                let built = tree.insert(KdTree::new(down)?);
                built.hybrid_neighbourhoods_into(down, feature_radius, c.feature_max_nn, nbhd);
            }
            timings.features = t.elapsed().as_secs_f64();
            let t = Instant::now();
            let normals = estimate_normals_from_neighbourhoods(
                down,
                nbhd,
                normal_radius,
                c.normal_max_nn,
                origin,
            )?;
            timings.normals = t.elapsed().as_secs_f64();
            let t = Instant::now();
            let features = compute_fpfh_from_neighbourhoods(down, &normals, nbhd)?;
            timings.features += t.elapsed().as_secs_f64();
            (normals, features)
        } else {
            let tree = tree.insert(KdTree::new(down)?);
            let normals =
                estimate_normals_with_tree(down, tree, normal_radius, c.normal_max_nn, origin)?;
            timings.normals = t.elapsed().as_secs_f64();
            let t = Instant::now();
            let features =
                compute_fpfh_with_tree(down, &normals, tree, feature_radius, c.feature_max_nn)?;
            timings.features = t.elapsed().as_secs_f64();
            (normals, features)
        };

    let icp = if !c.icp {
        None
    } else if icp_voxel == 0.0 || (icp_voxel > 0.0 && icp_voxel != c.voxel_size_m) {
        // A separate ICP cloud: the finite input points (0) or another voxel grid, with normals
        // over the same neighbourhood scaled to its resolution.
        let t = Instant::now();
        let (cloud, radius) = if icp_voxel == 0.0 {
            let finite = points
                .iter()
                .copied()
                .filter(|p| p.coords.iter().all(|x| x.is_finite()));
            (finite.collect::<Vec<_>>(), normal_radius)
        } else {
            let cloud = match finer_icp_cloud {
                Some(cloud) => cloud,
                None => {
                    let (cloud, ids) = downsample(points, icp_voxel, c.icp_fine)?;
                    icp_ids = ids;
                    cloud
                }
            };
            (cloud, normal_radius * icp_voxel / c.voxel_size_m)
        };
        timings.downsample += t.elapsed().as_secs_f64();
        // NOTE: the normals are estimated when first needed, and only where: all of them when
        // the frame is an ICP target (`mireg pair`'s target, a fallback to frame-to-frame ICP),
        // for a few points when `mireg register` adds the frame to its local map (only those
        // landing in voxels not yet full: 6 % of the ICP points on the KITTI replay log, 69 % on
        // the KAIST03 keyframes), never for a source. Through a radius grid streamed point by
        // point, not the stored neighbourhoods the features use (on the KAIST03 and KITTI ICP
        // clouds, 0.37 m / 0.5 m voxels, 16k / 11k points, those took 29–35 / 21–22 ms a frame
        // against the kd-tree's 18 / 17–19 ms), nor the kd-tree (a quarter of a KAIST03 run's
        // instructions): the same normals, bit for bit, for a fraction of the work
        // (docs/BENCHMARKS.md).
        let estimate = NormalEstimate::new(
            radius,
            c.normal_max_nn,
            origin,
            default_max_columns(cloud.len()),
        )?;
        Some(IcpTarget::with_deferred_normals(cloud, estimate)?)
    } else if let Some(tree) = tree {
        Some(IcpTarget::with_tree(down, &normals, tree)?)
    } else {
        Some(IcpTarget::new(down, &normals)?)
    };
    Ok(Described {
        features,
        icp,
        icp_voxels: icp_ids,
    })
}

/// Wall-clock seconds per stage of one registration.
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize, Deserialize)]
pub struct PairTimings {
    /// Downsampling of both clouds.
    pub downsample: f64,
    /// Normals of both clouds.
    pub normals: f64,
    /// FPFH of both clouds.
    pub features: f64,
    /// Nearest neighbours in feature space.
    pub matching: f64,
    /// Ranking.
    pub ranking: f64,
    /// MI-RANSAC.
    pub ransac: f64,
    /// ICP.
    pub icp: f64,
    /// Everything above.
    pub total: f64,
}

/// Why a registration produced no trustworthy pose.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum FailureReason {
    /// A cloud has fewer than 3 points after downsampling.
    TooFewPoints,
    /// Fewer than 3 feature correspondences.
    TooFewCorrespondences,
    /// RANSAC found no model with at least 3 inliers.
    NoConsensus,
    /// Fewer RANSAC inliers than the caller's minimum (odometry: [`crate::odometry::OdometryConfig`]).
    TooFewInliers,
    /// Fitness after ICP below the caller's minimum.
    LowFitness,
    /// The cloud could not be decoded or prepared (e.g. a missing field, or coordinates so large
    /// the voxel grid overflows).
    InvalidCloud,
    /// The cloud has more points than the caller's bound (`mireg register --max-points`).
    TooManyPoints,
}

impl FailureReason {
    /// The snake_case name used in JSON output.
    pub fn as_str(&self) -> &'static str {
        match self {
            FailureReason::TooFewPoints => "too_few_points",
            FailureReason::TooFewCorrespondences => "too_few_correspondences",
            FailureReason::NoConsensus => "no_consensus",
            FailureReason::TooFewInliers => "too_few_inliers",
            FailureReason::LowFitness => "low_fitness",
            FailureReason::InvalidCloud => "invalid_cloud",
            FailureReason::TooManyPoints => "too_many_points",
        }
    }
}

/// The outcome of [`register_prepared`].
#[derive(Debug, Clone, PartialEq)]
pub struct PairResult {
    /// Final estimate (identity on failure).
    pub target_from_source: Isometry3<f64>,
    /// RANSAC's estimate before ICP (identity on failure).
    pub ransac_target_from_source: Isometry3<f64>,
    /// `None` on success.
    pub failure: Option<FailureReason>,
    /// Points in the source / target input clouds.
    pub num_points: [usize; 2],
    /// Points after downsampling (source, target).
    pub num_points_downsampled: [usize; 2],
    /// Putative correspondences.
    pub num_correspondences: usize,
    /// RANSAC inliers among them.
    pub num_inliers: usize,
    /// Hypotheses drawn.
    pub hypotheses: u64,
    /// Hypotheses removed by edge-length pre-rejection.
    pub prerejected: u64,
    /// Hypotheses scored.
    pub verified: u64,
    /// Hypothesis index at which the final best model was first found.
    pub best_found_at: Option<u64>,
    /// RANSAC stopped by its adaptive rule.
    pub converged: bool,
    /// Fraction of source points (ICP cloud) within the ICP distance of the target after alignment.
    pub fitness: f64,
    /// RMSE of those inlier distances \[m\].
    pub inlier_rmse_m: f64,
    /// ICP iterations run (0 without ICP).
    pub icp_iterations: usize,
    /// Per-stage seconds.
    pub timings_s: PairTimings,
}

fn make_ranking(
    matches: &crate::correspondence::matching::Matches,
    num_target: usize,
    r: RankingConfig,
) -> Ranking {
    match r {
        RankingConfig::NeighbourCount { order, .. } => {
            rank_by_neighbour_count(&matches.count_within, num_target, order)
        }
        RankingConfig::Distance => rank_by_distance(&matches.distance),
        RankingConfig::Ratio => rank_by_ratio(&matches.distance, &matches.second_distance),
    }
}

/// Runs the configured sampler over `estimator`'s correspondences.
pub fn run_sampler<E: Estimator<Model = Isometry3<f64>>>(
    sampler: SamplerConfig,
    estimator: &E,
    consensus: &ConsensusConfig,
) -> Result<Consensus<Isometry3<f64>>> {
    let n = estimator.num_items();
    Ok(match sampler {
        SamplerConfig::Uniform => run_consensus(&Uniform::new(n), estimator, consensus),
        SamplerConfig::Levy {
            mu,
            c,
            window,
            with_replacement,
        } => {
            let s = Levy::new(TruncatedLevy::new(mu, c, window)?, n)?
                .with_replacement(with_replacement);
            run_consensus(&s, estimator, consensus)
        }
        SamplerConfig::Prosac { growth_max_samples } => run_consensus(
            &Prosac::new(n, 3, growth_max_samples)?,
            estimator,
            consensus,
        ),
    })
}

/// Registers prepared `source` to prepared `target`: the pose maps source points into the target
/// frame. Never fails on data: a failed registration is a [`PairResult`] with `failure` set.
pub fn register_prepared(
    source: &PreparedFrame,
    target: &PreparedFrame,
    config: &PairConfig,
) -> Result<PairResult> {
    register_prepared_with(source, target, config, true)
}

/// [`register_prepared`] up to the RANSAC model, without the ICP refinement: `target_from_source`
/// is the RANSAC model, `fitness` and `inlier_rmse_m` are 0. For callers that refine elsewhere
/// (odometry against its local map), or later with [`refine_prepared`].
pub fn register_prepared_coarse(
    source: &PreparedFrame,
    target: &PreparedFrame,
    config: &PairConfig,
) -> Result<PairResult> {
    register_prepared_with(source, target, config, false)
}

/// The ICP step of [`register_prepared`] on a result of [`register_prepared_coarse`] with a
/// model: refines `out.ransac_target_from_source` and sets pose, fitness, RMSE, iterations and
/// the ICP timing (and the total).
pub fn refine_prepared(
    out: &mut PairResult,
    source: &PreparedFrame,
    target: &PreparedFrame,
    config: &PairConfig,
) -> Result<()> {
    let c = config.resolved()?;
    let t = Instant::now();
    let built = std::cell::OnceCell::new();
    refine(out, source, target, &c, || feature_tree(target, &built))?;
    let icp_s = t.elapsed().as_secs_f64();
    out.timings_s.icp = icp_s;
    out.timings_s.total += icp_s;
    Ok(())
}

fn register_prepared_with(
    source: &PreparedFrame,
    target: &PreparedFrame,
    config: &PairConfig,
    refined: bool,
) -> Result<PairResult> {
    let c = config.resolved()?;
    let start = Instant::now();
    let mut out = PairResult {
        target_from_source: Isometry3::identity(),
        ransac_target_from_source: Isometry3::identity(),
        failure: None,
        num_points: [source.num_points, target.num_points],
        num_points_downsampled: [source.points.len(), target.points.len()],
        num_correspondences: 0,
        num_inliers: 0,
        hypotheses: 0,
        prerejected: 0,
        verified: 0,
        best_found_at: None,
        converged: false,
        fitness: 0.0,
        inlier_rmse_m: 0.0,
        icp_iterations: 0,
        timings_s: PairTimings {
            downsample: source.timings.downsample + target.timings.downsample,
            normals: source.timings.normals + target.timings.normals,
            features: source.timings.features + target.timings.features,
            ..Default::default()
        },
    };
    let finish = |mut out: PairResult| {
        let t = &mut out.timings_s;
        t.total = t.downsample + t.normals + t.features + start.elapsed().as_secs_f64();
        out
    };
    if source.points.len() < 3 || target.points.len() < 3 {
        out.failure = Some(FailureReason::TooFewPoints);
        return Ok(finish(out));
    }

    let count_radius = match c.ranking {
        RankingConfig::NeighbourCount { radius, .. } => Some(radius),
        _ => None,
    };
    // The ICP stages' sources, targets and correspondence grids are built (once per frame)
    // beside the matching: single passes that fill the gaps of the matching's parallel loops.
    let build_fine = refined && c.icp && c.icp_fine && !source.fine.is_empty();
    let prepare_targets = || -> Result<()> {
        let Some(icp) = target.icp.as_ref().filter(|_| refined && c.icp) else {
            return Ok(());
        };
        if build_fine {
            source.fine_source();
        }
        icp.prepare_for_distance(c.icp_max_distance_m.unwrap())?;
        if let Some(fine) = build_fine
            .then(|| target.fine_target())
            .transpose()?
            .flatten()
        {
            fine.prepare_for_distance(c.icp_fine_distance_m.unwrap())?;
        }
        Ok(())
    };
    let (matched, prepared) = rayon::join(
        || {
            let t = Instant::now();
            let config = MatchConfig {
                mutual: c.mutual_filter,
                count_radius,
                ..Default::default()
            };
            let (s, t_features) = (&source.features, &target.features);
            // The prepared structures serve the search without a count radius only: the
            // other builds its own.
            let prepared = count_radius.is_none().then(|| target.match_target());
            let matches = match prepared.flatten() {
                Some(prepared) => match_features_against(s, t_features, prepared, &config),
                None => match_features_with(s, t_features, &config),
            };
            (matches, t.elapsed().as_secs_f64())
        },
        prepare_targets,
    );
    let (matches, matching_s) = matched;
    prepared?;
    out.timings_s.matching = matching_s;
    out.num_correspondences = matches.len();
    if matches.len() < 3 {
        out.failure = Some(FailureReason::TooFewCorrespondences);
        return Ok(finish(out));
    }

    let t = Instant::now();
    let ranking = make_ranking(&matches, target.points.len(), c.ranking);
    let src = ranking.gather(&matches.source_index, &source.points);
    let tgt = ranking.gather(&matches.target_index, &target.points);
    out.timings_s.ranking = t.elapsed().as_secs_f64();

    let t = Instant::now();
    let estimator = RigidEstimator::new(&src, &tgt)
        .edge_similarity(c.edge_similarity)
        .sample_distance(
            c.sample_distance_check
                .then(|| c.inlier_threshold_m.expect("resolved")),
        );
    let consensus = ConsensusConfig {
        inlier_threshold: c.inlier_threshold_m.unwrap(),
        scoring: c.scoring,
        confidence: c.confidence,
        max_hypotheses: c.max_hypotheses,
        lo_iterations: c.lo_iterations,
        termination: Termination::Adaptive,
        seed: c.seed,
    };
    // The target feature cloud's kd-tree, built on first use unless the ICP target is that cloud.
    let built_tree = std::cell::OnceCell::new();
    let target_tree = || feature_tree(target, &built_tree);
    let result = match c.verification {
        Verification::Correspondences => run_sampler(c.sampler, &estimator, &consensus)?,
        Verification::Dense => {
            let overlap =
                OverlapTarget::new(&target.points, consensus.inlier_threshold, target_tree)?;
            run_sampler(
                c.sampler,
                &DenseRigidEstimator::new(estimator, &source.points, &overlap).scoring(c.scoring),
                &consensus,
            )?
        }
    };
    out.timings_s.ransac = t.elapsed().as_secs_f64();
    out.hypotheses = result.hypotheses;
    out.prerejected = result.prerejected;
    out.verified = result.verified;
    out.best_found_at = result.best_found_at;
    out.converged = result.converged;
    out.num_inliers = result.num_inliers;
    let Some(model) = result.model.filter(|_| result.num_inliers >= 3) else {
        out.failure = Some(FailureReason::NoConsensus);
        return Ok(finish(out));
    };
    out.ransac_target_from_source = model;
    out.target_from_source = model;
    if !refined {
        return Ok(finish(out));
    }
    let t = Instant::now();
    refine(&mut out, source, target, &c, target_tree)?;
    out.timings_s.icp = t.elapsed().as_secs_f64();
    Ok(finish(out))
}

/// [`prepare_frame`] both clouds (in parallel) and [`register_prepared`] them. The per-stage
/// timings of the two frames add up; `timings_s.total` is the wall-clock time of the whole call.
pub fn register_pair(
    source: &[Point3<f64>],
    target: &[Point3<f64>],
    config: &PairConfig,
) -> Result<PairResult> {
    let start = Instant::now();
    let (s, t) = rayon::join(
        || prepare_frame(source, config),
        || prepare_frame(target, config),
    );
    let mut result = register_prepared(&s?, &t?, config)?;
    result.timings_s.total = start.elapsed().as_secs_f64();
    Ok(result)
}

/// Rotation error \[deg\] and translation error \[m\] of `estimate` against `truth`: the angle of
/// `R_truthᵀ·R_est` and `‖t_est − t_truth‖`.
pub fn pose_error(truth: &Isometry3<f64>, estimate: &Isometry3<f64>) -> (f64, f64) {
    let r = truth.rotation.inverse() * estimate.rotation;
    let dt: Vector3<f64> = estimate.translation.vector - truth.translation.vector;
    (r.angle().to_degrees(), dt.norm())
}
