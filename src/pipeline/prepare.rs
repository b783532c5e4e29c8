//! A cloud prepared once for registration as source or target ([`prepare_frame`]): downsampled,
//! with normals, FPFH and the ICP cloud.

use std::time::Instant;

use nalgebra::{Point3, Vector3};
use serde::{Deserialize, Serialize};

use super::PairConfig;
use super::refine::{self, fine_sample};
use crate::Result;
use crate::correspondence::matching::MatchTarget;
use crate::features::fpfh::{Fpfh, compute_fpfh_from_neighbourhoods, compute_fpfh_with_tree};
use crate::geometry::grid;
use crate::geometry::kdtree::{KdTree, Neighbourhoods};
use crate::geometry::normals::{
    NormalEstimate, estimate_normals_from_neighbourhoods, estimate_normals_with_tree,
};
use crate::geometry::radius_grid::default_max_columns;
use crate::geometry::voxel::{voxel_downsample, voxel_downsample_indexed};
use crate::refine::icp::IcpTarget;

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
    /// FPFH per feature-cloud point ([`PreparedFrame::features`]): computed while preparing, or
    /// on first use where preparing deferred them ([`prepare_frame_deferring_features`]).
    features: std::sync::OnceLock<Vec<Fpfh>>,
    /// How to compute the FPFH on first use, where preparing deferred them.
    deferred_features: Option<FeatureSettings>,
    /// The seconds that computing deferred features took (normals and features; zero until).
    deferred_timings: std::sync::OnceLock<FrameTimings>,
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
    /// Time spent preparing (features deferred to their first use not included:
    /// [`PreparedFrame::stage_timings`]).
    pub timings: FrameTimings,
}

impl PreparedFrame {
    /// The heap this frame holds now \[bytes\]: its feature cloud with FPFH, its ICP cloud
    /// ([`IcpTarget::heap_bytes`]), its drawn input points, and those search structures that
    /// have been built (the matching target counted at
    /// [`MatchTarget::APPROX_BYTES_PER_DESCRIPTOR`]). Capacities, not lengths. What a frame kept
    /// idle costs once [`PreparedFrame::drop_search_structures`] has run: for a KAIST03 scan at a
    /// 0.37 m voxel 0.67 MB before its first use, and more once it has served as a target (its
    /// ICP normals, which stay, its ICP grid and matching target): the grid is 1.3 MB of that
    /// since it keeps entries for occupied columns only (until 2026-12-07 10–14 MB, and the
    /// whole 14–15 MB).
    pub fn heap_bytes(&self) -> usize {
        let point = std::mem::size_of::<Point3<f64>>();
        let fpfh = self.features.get().map_or(0, Vec::capacity);
        let features = self.points.capacity() * point + fpfh * std::mem::size_of::<Fpfh>();
        let icp = self
            .icp
            .as_ref()
            .map_or(0, |t| t.heap_bytes() - t.grid_bytes());
        let fine = self.fine.capacity() * point + self.fine_voxels.capacity() * 4;
        features + icp + fine + self.structure_bytes()
    }

    /// What this frame holds idle once it has served as a registration's target \[bytes\]: its
    /// [`PreparedFrame::heap_bytes`] with its ICP cloud's normals estimated (a target keeps
    /// them) and without the search structures [`PreparedFrame::drop_search_structures`] drops.
    /// For a KAIST03 scan at a 0.37 m voxel, 1.05 MB against 0.67 MB before its first use.
    pub fn idle_bytes(&self) -> usize {
        let pending = self.icp.as_ref().map_or(0, IcpTarget::pending_normal_bytes);
        self.heap_bytes() - self.structure_bytes() + pending
    }

    /// The heap of the structures [`PreparedFrame::drop_search_structures`] drops, as far as
    /// they have been built \[bytes\].
    fn structure_bytes(&self) -> usize {
        let point = std::mem::size_of::<Point3<f64>>();
        let matching = self
            .match_target
            .get()
            .and_then(Option::as_ref)
            .map_or(0, |t| t.len() * MatchTarget::APPROX_BYTES_PER_DESCRIPTOR);
        let fine_target = self
            .fine_target
            .get()
            .and_then(Option::as_ref)
            .map_or(0, IcpTarget::heap_bytes);
        let fine_source = self.fine_source.get().map_or(0, |f| f.capacity() * point);
        let grid = self.icp.as_ref().map_or(0, IcpTarget::grid_bytes);
        matching + fine_target + fine_source + grid
    }

    /// Drops the structures a registration with this frame builds and keeps (its matching
    /// target, its ICP cloud's correspondence grid, the fine stage's target and source): the
    /// next registration builds them again, with the same answers. For a frame kept idle
    /// between uses.
    pub fn drop_search_structures(&mut self) {
        self.match_target = Default::default();
        self.fine_target = Default::default();
        self.fine_source = Default::default();
        if let Some(icp) = &mut self.icp {
            icp.drop_grid();
        }
    }

    /// The search structures over this frame's descriptors as a matching target
    /// ([`MatchTarget`]), built on the first call; `None` without descriptors.
    pub fn match_target(&self) -> Option<&MatchTarget> {
        self.match_target
            .get_or_init(|| MatchTarget::new(self.features()))
            .as_ref()
    }

    /// The FPFH of the feature cloud, one per point of [`PreparedFrame::points`]; computed on
    /// the first call where preparing deferred them (the same values: the same cloud, settings
    /// and code). Empty for a cloud of fewer than 3 points.
    ///
    /// The first call on a deferred frame runs parallel loops: callers that fan out over
    /// registrations sharing a frame call it first, so that no task waits for another's
    /// initialisation on its own thread.
    pub fn features(&self) -> &[Fpfh] {
        self.features.get_or_init(|| {
            let Some(settings) = &self.deferred_features else {
                return Vec::new();
            };
            let mut timings = FrameTimings::default();
            let computed = normals_and_features(
                &self.points,
                settings,
                &mut PrepareScratch::default(),
                &mut timings,
            );
            let _ = self.deferred_timings.set(timings);
            // The same computation succeeded for other frames of the stream; a cloud it fails
            // on (none known) has no features, as a cloud too small to have them.
            computed.map_or_else(|_| Vec::new(), |(_, features, _)| features)
        })
    }

    /// [`PreparedFrame::timings`] with the seconds that computing deferred features took, once
    /// they have been.
    pub fn stage_timings(&self) -> FrameTimings {
        let mut t = self.timings;
        if let Some(deferred) = self.deferred_timings.get() {
            t.normals += deferred.normals;
            t.features += deferred.features;
        }
        t
    }

    /// Whether the frame has FPFH (computed, or deferred for a cloud of at least 3 points),
    /// without computing deferred ones.
    pub fn has_features(&self) -> bool {
        self.features
            .get()
            .map_or(self.deferred_features.is_some(), |f| !f.is_empty())
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
    prepare(points, config, scratch, false)
}

/// [`prepare_frame_with`], the FPFH (and the feature cloud's normals, which only they use)
/// deferred to their first use ([`PreparedFrame::features`]) where the ICP cloud is a cloud of
/// its own; where it is the feature cloud, its normals are needed now and the FPFH come with
/// them. The same frame, features and all, once they are computed.
///
/// NOTE: `mireg register`'s odometry refines most frames of a 10 Hz log on its local map from
/// the motion's prediction ([`crate::odometry::OdometryConfig::track_first`]); such a frame's
/// features serve only if the next frame needs a global registration, or the frame is a
/// keyframe of loop closure (its descriptor). Deferred, they cost a simulated 10 Hz Livox Avia
/// log (77 of 80 frames tracked, 19 keyframes) 15 % less CPU, the ICL-NUIM fixture 22 %
/// (docs/ODOMETRY.md, "Features only where they are used").
pub fn prepare_frame_deferring_features(
    points: &[Point3<f64>],
    config: &PairConfig,
    scratch: &mut PrepareScratch,
) -> Result<PreparedFrame> {
    prepare(points, config, scratch, true)
}

/// [`prepare_frame_with`], deferring the features where `defer` and the ICP cloud is a cloud
/// of its own ([`prepare_frame_deferring_features`]).
fn prepare(
    points: &[Point3<f64>],
    config: &PairConfig,
    scratch: &mut PrepareScratch,
    defer: bool,
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
            features: std::sync::OnceLock::from(Vec::new()),
            deferred_features: None,
            deferred_timings: Default::default(),
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
                (&c, origin, defer),
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
    let (features, deferred_features) = match features {
        Some(features) => (std::sync::OnceLock::from(features), None),
        None => (
            std::sync::OnceLock::new(),
            Some(feature_settings(&c, origin)),
        ),
    };
    Ok(PreparedFrame {
        num_points: points.len(),
        points: down,
        features,
        deferred_features,
        deferred_timings: Default::default(),
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
    /// `None`: deferred.
    features: Option<Vec<Fpfh>>,
    icp: Option<IcpTarget>,
    /// Each input point's voxel of the ICP cloud, when the fine stage draws and the ICP cloud
    /// was made by [`describe`].
    icp_voxels: Option<Vec<u32>>,
}

/// The feature cloud's normals and FPFH (unless deferred: `defer` and an ICP cloud of its own),
/// the ICP target (`None` without ICP) and, when the fine stage draws and the ICP cloud is made
/// here, each input point's voxel of it: the part of [`prepare`] after downsampling. `down` has
/// at least 3 points; `origin` orients the normals.
fn describe(
    points: &[Point3<f64>],
    down: &[Point3<f64>],
    finer_icp_cloud: Option<Vec<Point3<f64>>>,
    (c, origin, defer): (&PairConfig, Option<Point3<f64>>, bool),
    scratch: &mut PrepareScratch,
    timings: &mut FrameTimings,
) -> Result<Described> {
    let icp_voxel = c.icp_voxel_size_m.unwrap();
    let mut icp_ids = None;
    let separate = icp_voxel == 0.0 || (icp_voxel > 0.0 && icp_voxel != c.voxel_size_m);
    if c.icp && separate && defer {
        let (icp, ids) = separate_icp_target(points, finer_icp_cloud, c, origin, timings)?;
        return Ok(Described {
            features: None,
            icp: Some(icp),
            icp_voxels: ids,
        });
    }
    let settings = feature_settings(c, origin);
    let (normals, features, tree) = normals_and_features(down, &settings, scratch, timings)?;
    let icp = if !c.icp {
        None
    } else if separate {
        let (icp, ids) = separate_icp_target(points, finer_icp_cloud, c, origin, timings)?;
        icp_ids = ids;
        Some(icp)
    } else if let Some(tree) = tree {
        Some(IcpTarget::with_tree(down, &normals, tree)?)
    } else {
        Some(IcpTarget::new(down, &normals)?)
    };
    Ok(Described {
        features: Some(features),
        icp,
        icp_voxels: icp_ids,
    })
}

/// What the feature cloud's normals and FPFH are computed with ([`normals_and_features`]).
#[derive(Debug, Clone, Copy)]
struct FeatureSettings {
    normal_radius_m: f64,
    normal_max_nn: usize,
    feature_radius_m: f64,
    feature_max_nn: usize,
    /// Orient the normals towards this point.
    origin: Option<Point3<f64>>,
}

/// The [`FeatureSettings`] of the resolved `c`, the normals oriented towards `origin`.
fn feature_settings(c: &PairConfig, origin: Option<Point3<f64>>) -> FeatureSettings {
    FeatureSettings {
        normal_radius_m: c.normal_radius_m.unwrap(),
        normal_max_nn: c.normal_max_nn,
        feature_radius_m: c.feature_radius_m.unwrap(),
        feature_max_nn: c.feature_max_nn,
        origin,
    }
}

/// The normals, FPFH and kd-tree (if a search built one) of a feature cloud
/// ([`normals_and_features`]).
type NormalsAndFeatures = (Vec<Vector3<f64>>, Vec<Fpfh>, Option<KdTree>);

/// The normals and FPFH of the feature cloud `down`, and the kd-tree built on it if a search
/// needed one: through one neighbourhood pass for both when the FPFH neighbourhoods contain the
/// normals' (the radius grid's, or the kd-tree's where the grid declines), else through a
/// kd-tree.
fn normals_and_features(
    down: &[Point3<f64>],
    c: &FeatureSettings,
    scratch: &mut PrepareScratch,
    timings: &mut FrameTimings,
) -> Result<NormalsAndFeatures> {
    let t = Instant::now();
    // NOTE: the kd-tree is built only where a search needs it: the grid answers the
    // neighbourhoods of most clouds, and ICP builds its own tree on first use. Building it for
    // every frame cost 2 % of a bunny pair's instructions, and `mireg register` dropped it unused.
    let mut tree = None;
    let (normal_radius, feature_radius, origin) = (c.normal_radius_m, c.feature_radius_m, c.origin);
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
    Ok((normals, features, tree))
}

/// An ICP target on a cloud of its own: the finite input points (ICP voxel 0) or another voxel
/// grid (`finer_icp_cloud` if given, else `points` downsampled, with each point's voxel when
/// the fine stage draws), with normals over the same neighbourhood scaled to its resolution.
fn separate_icp_target(
    points: &[Point3<f64>],
    finer_icp_cloud: Option<Vec<Point3<f64>>>,
    c: &PairConfig,
    origin: Option<Point3<f64>>,
    timings: &mut FrameTimings,
) -> Result<(IcpTarget, Option<Vec<u32>>)> {
    let (icp_voxel, normal_radius) = (c.icp_voxel_size_m.unwrap(), c.normal_radius_m.unwrap());
    let mut icp_ids = None;
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
    // (docs/BENCHMARKS_ARCHIVE.md).
    let estimate = NormalEstimate::new(
        radius,
        c.normal_max_nn,
        origin,
        default_max_columns(cloud.len()),
    )?;
    Ok((IcpTarget::with_deferred_normals(cloud, estimate)?, icp_ids))
}
