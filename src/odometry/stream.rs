//! Odometry over a stream of raw clouds, one call per cloud, as `mireg register` runs it but
//! without a log: the first cloud sizes the voxel and the feature voxel, each cloud with
//! per-point times is deskewed by an earlier frame's motion, prepared, and registered against
//! the local map. `register` runs the same steps on two threads (`src/register/`), through
//! [`resolve_config`], [`deskew_for`], [`prepare`] and [`MeanTimeMotions`]; this runs them in
//! order, for callers that hold the clouds themselves (the Python package's `Odometry`).

use nalgebra::{Isometry3, Point3};

use super::keep_map_fine_points;
use super::{FrameEstimate, MAP_FINE_DRAW_PER_ICP_POINT, Odometry, OdometryConfig};
use crate::Result;
use crate::geometry::deskew::{deskew, screw_fraction};
use crate::pipeline::{
    FailureReason, PrepareScratch, PreparedFrame, feature_voxel_for_cloud, prepare_frame,
    prepare_frame_deferring_features, voxel_for_cloud, with_feature_voxel,
};

/// `config` as `register` runs it once it has seen its first usable cloud `first`: the voxel
/// from the cloud's median range when `derive_voxel` (and the cloud can size one), the feature
/// voxel for [`OdometryConfig::feature_points`], and the map's fine stage drawing input points.
///
/// # Errors
/// A voxel the downsampling refuses.
pub fn resolve_config(
    config: &OdometryConfig,
    first: Option<&[Point3<f64>]>,
    derive_voxel: bool,
) -> Result<Resolved> {
    let mut config = config.clone();
    let mut derived = false;
    if derive_voxel && let Some(v) = first.and_then(voxel_for_cloud) {
        config.pair.voxel_size_m = v;
        derived = true;
    }
    // Read before the feature voxel replaces `pair.voxel_size_m`.
    let voxel_m = config.pair.voxel_size_m;
    if let Some(points) = first {
        let fv = feature_voxel_for_cloud(points, voxel_m, config.feature_points)?;
        config.pair = with_feature_voxel(&config.pair, fv);
    }
    // Frames carry input points for the map ICP's fine stage, not for the pairwise one, which
    // the local map replaces (`Odometry::new` turns that off).
    config.pair.icp_fine = config.map_fine;
    config.pair.icp_fine_points_per_icp_point = MAP_FINE_DRAW_PER_ICP_POINT;
    Ok(Resolved {
        config,
        voxel_m,
        voxel_derived: derived,
    })
}

/// What [`resolve_config`] makes of a configuration.
#[derive(Debug, Clone)]
pub struct Resolved {
    /// The configuration to run: `pair.voxel_size_m` is the *feature* voxel of global
    /// registration from here on ([`with_feature_voxel`]).
    pub config: OdometryConfig,
    /// The run's voxel \[m\]: the local map's and ICP's, which loop closure and the map scale
    /// with (not the feature voxel).
    pub voxel_m: f64,
    /// Whether the voxel came from the first cloud (else it is the configured one).
    pub voxel_derived: bool,
}

/// Which earlier frame's motion deskews frame `k`: frame `k − 2`'s (the latest one surely known
/// while frame `k − 1` is being registered), so the result does not depend on thread timing;
/// `None` for the first three frames.
pub fn deskew_for(k: usize) -> Option<usize> {
    k.checked_sub(2).filter(|&m| m >= 1)
}

/// A deskewed cloud: the motion it was deskewed by (`prev_from_curr`, seconds) and the mean of
/// its points' times, seconds after its stamp.
pub type Deskewed = Option<(Isometry3<f64>, f64, f64)>;

/// Deskews `points` (times `times_s` after the stamp) by `motion` over `dt` seconds; returns what
/// [`MeanTimeMotions`] needs to know of it.
pub fn deskew_cloud(
    points: &mut [Point3<f64>],
    times_s: &[f64],
    motion: Isometry3<f64>,
    dt: f64,
) -> (Isometry3<f64>, f64, f64) {
    deskew(points, times_s, &motion, dt);
    let mean = if times_s.is_empty() {
        0.0
    } else {
        times_s.iter().sum::<f64>() / times_s.len() as f64
    };
    (motion, dt, mean)
}

/// `points` prepared for registration ([`prepare_frame_deferring_features`]: the features
/// computed where first needed; the map's fine points kept), or
/// an empty frame and why, for a cloud that cannot be prepared.
///
/// # Errors
/// Only when even the empty frame cannot be made (an invalid configuration).
pub fn prepare(
    points: &[Point3<f64>],
    config: &OdometryConfig,
    scratch: &mut PrepareScratch,
) -> Result<(PreparedFrame, Option<(FailureReason, String)>)> {
    match prepare_frame_deferring_features(points, &config.pair, scratch) {
        Ok(mut frame) => {
            keep_map_fine_points(&mut frame);
            Ok((frame, None))
        }
        Err(e) => prepare_frame(&[], &config.pair)
            .map(|f| (f, Some((FailureReason::InvalidCloud, e.to_string())))),
    }
}

/// The motions that deskew later frames, taken between the frames' mean point times, and the
/// pose of each deskewed frame referred back to its stamp by its own motion.
///
/// NOTE: registration places a deskewed cloud; if the motion it was deskewed by is off by δ, the
/// cloud is shifted by about δ · (mean time / dt) as a whole, and the stamp's pose takes that
/// shift. Motions between stamp poses would carry it into the next deskew: on Livox's 100 ms
/// forward-looking sweeps the loop oscillated (0.14, 0.39, 0.18, 0.42 m per frame for a true
/// 0.30–0.33 m). Between mean-time poses it cancels to first order (docs/ODOMETRY.md).
#[derive(Debug, Clone)]
pub struct MeanTimeMotions {
    previous_stamp_ns: Option<i64>,
    /// The previous frame's pose at its mean point time, in the frame at its stamp.
    previous_from_mean: Isometry3<f64>,
}

impl Default for MeanTimeMotions {
    fn default() -> Self {
        Self {
            previous_stamp_ns: None,
            previous_from_mean: Isometry3::identity(),
        }
    }
}

impl MeanTimeMotions {
    /// Takes frame `est` (stamped `stamp_ns`, deskewed as `deskewed` says): corrects its pose
    /// to the stamp when it was deskewed, and returns the motion (`prev_from_curr` between mean
    /// times) and its seconds, for deskewing a later frame (NaN seconds for the first frame).
    pub fn push(
        &mut self,
        est: &mut FrameEstimate,
        stamp_ns: i64,
        deskewed: Deskewed,
    ) -> (Isometry3<f64>, f64) {
        let dt = self
            .previous_stamp_ns
            .map_or(f64::NAN, |p| (stamp_ns - p) as f64 * 1e-9);
        self.previous_stamp_ns = Some(stamp_ns);
        let from_mean = match deskewed {
            Some((motion, d, mean)) if mean != 0.0 => screw_fraction(&motion, mean / d),
            _ => Isometry3::identity(),
        };
        let motion = if deskewed.is_some() || self.previous_from_mean != Isometry3::identity() {
            self.previous_from_mean.inverse() * est.prev_from_curr * from_mean
        } else {
            est.prev_from_curr
        };
        self.previous_from_mean = from_mean;
        if let Some((_, _, mean)) = deskewed
            && dt.is_finite()
            && dt > 0.0
        {
            est.world_from_frame =
                est.world_from_frame * from_mean * screw_fraction(&motion, -mean / dt);
        }
        (motion, dt)
    }
}

/// [`Odometry`] fed one raw cloud at a time.
pub struct StreamOdometry {
    config: OdometryConfig,
    derive_voxel: bool,
    deskew: bool,
    odometry: Option<Odometry>,
    scratch: PrepareScratch,
    motions: Vec<(Isometry3<f64>, f64)>,
    mean_time: MeanTimeMotions,
}

impl StreamOdometry {
    /// Odometry with `config`; the voxel comes from the first usable cloud when `derive_voxel`
    /// (`register`'s default), and clouds with times are deskewed when `deskew`.
    pub fn new(config: OdometryConfig, derive_voxel: bool, deskew: bool) -> Self {
        Self {
            config,
            derive_voxel,
            deskew,
            odometry: None,
            scratch: PrepareScratch::default(),
            motions: Vec::new(),
            mean_time: MeanTimeMotions::default(),
        }
    }

    /// The configuration in use: the given one until the first usable cloud, then as resolved
    /// by it ([`resolve_config`]).
    pub fn config(&self) -> &OdometryConfig {
        &self.config
    }

    /// Registers the next cloud: `points` in the sensor frame (metres), `times_s` per point in
    /// seconds after `stamp_ns` (the cloud's stamp, ns) when known; a cloud with a time that is
    /// not finite or further than [`crate::io::point_time::POINT_TIME_BOUND_S`] from the stamp
    /// is not deskewed. Returns its estimate, the
    /// pose `world_from_frame` with world the first frame's sensor frame.
    ///
    /// # Errors
    /// An invalid configuration; a bad cloud is a flagged estimate, not an error.
    pub fn push(
        &mut self,
        mut points: Vec<Point3<f64>>,
        times_s: Option<&[f64]>,
        stamp_ns: i64,
    ) -> Result<FrameEstimate> {
        if self.odometry.is_none() {
            // NOTE: `register` sizes the voxel on the log's first cloud that can size one,
            // looking ahead; a stream cannot, so the first cloud sizes it, or, when it cannot,
            // the configuration is used as given.
            let first = voxel_for_cloud(&points)
                .is_some()
                .then_some(points.as_slice());
            self.config = resolve_config(&self.config, first, self.derive_voxel)?.config;
            self.odometry = Some(Odometry::new(self.config.clone())?);
        }
        let k = self.motions.len();
        let mut deskewed = None;
        // Times that are not finite or not within the bound of the stamp cannot deskew: they
        // would move points (and the pose) anywhere (`crate::io::point_time`).
        let bounded = |t: &[f64]| {
            t.iter()
                .all(|t| t.abs() <= crate::io::point_time::POINT_TIME_BOUND_S)
        };
        if let Some(times) =
            times_s.filter(|t| self.deskew && t.len() == points.len() && bounded(t))
            && let Some(&(motion, dt)) = deskew_for(k).and_then(|m| self.motions.get(m))
            && dt.is_finite()
            && dt > 0.0
        {
            deskewed = Some(deskew_cloud(&mut points, times, motion, dt));
        }
        let (frame, invalid) = prepare(&points, &self.config, &mut self.scratch)?;
        let odometry = self.odometry.as_mut().expect("made by the first cloud");
        let mut est = odometry.push(frame)?;
        if let Some((reason, _)) = invalid {
            est.failure = Some(reason);
        }
        let motion = self.mean_time.push(&mut est, stamp_ns, deskewed);
        self.motions.push(motion);
        Ok(est)
    }
}
