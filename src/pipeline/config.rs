//! The settings of a pair registration ([`PairConfig`]): sampler, ranking, verification, voxels.

use serde::{Deserialize, Serialize};

use crate::correspondence::ranking::CountOrder;
use crate::ransac::consensus::Scoring;
use crate::ransac::levy::{DEFAULT_SCALE, DEFAULT_WINDOW};
use crate::{Error, Result};

use super::refine;

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
    /// At most this many source points in ICP: a larger source ICP cloud is thinned to an even
    /// stride of its points (the target keeps all of its own). `None` (the default) uses all.
    /// Loop verification sets it ([`crate::loops::LoopConfig::icp_source_points`]): a loop edge
    /// needs a pose good to a fraction of its σ, not a pair's best.
    pub icp_max_source_points: Option<usize>,
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
            icp_max_source_points: None,
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
        // 7.4 vs 5.7 frames/s); on the ICL pair 4.8 vs 4.0 mm (docs/BENCHMARKS_ARCHIVE.md).
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
