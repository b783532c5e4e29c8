//! One session of a merge, read back from its `register` output: the best trajectory, the
//! keyframes and their prepared clouds.

use std::collections::{BTreeMap, BTreeSet};
use std::path::Path;

use nalgebra::{Isometry3, Point3};
use rayon::prelude::*;

use super::links::Track;
use super::map_prior::{TileIndex, percentile_range};
use crate::evaluate::path_distances;
use crate::io::format_err;
use crate::io::mcap::log::list_channels;
use crate::io::poses::read_mcap_pose_topic;
use crate::loops::{Descriptor, LoopConfig, select_keyframes};
use crate::odometry::OdometryConfig;
use crate::pipeline::{PairConfig, PreparedFrame, prepare_frame, with_feature_voxel};
use crate::register::{
    KeptKeyframes, Segment, for_each_cloud_where, loop_pair_config, read_segment,
};
use crate::{Error, Result};

/// A session: its output read back, the trajectory placing its frames, and its keyframes.
pub(super) struct Session {
    pub(super) output: Segment,
    /// The name in reports and links: the file's stem.
    pub(super) name: String,
    /// The topic whose poses are used (`…/pose_optimized` where loops were closed, else
    /// `…/pose`).
    pub(super) pose_topic: String,
    /// The pose namespace of the run (`/mireg`, or `/mireg_N` for a log registered N times).
    pub(super) namespace: String,
    /// `world_from_sensor` per frame, by stamp.
    pub(super) poses: Vec<Isometry3<f64>>,
    /// Path length to each frame \[m\].
    pub(super) travelled_m: Vec<f64>,
    /// The run's ICP voxel and feature voxel \[m\].
    pub(super) voxel_m: f64,
    pub(super) feature_voxel_m: f64,
    /// Keyframes (frame indices), with their descriptors and, while they fit the budget
    /// ([`Session::prepare_keyframes`]), their prepared clouds (keyframes whose cloud did not
    /// prepare are left out).
    pub(super) keyframes: Vec<usize>,
    pub(super) frames: Vec<Option<PreparedFrame>>,
    pub(super) descriptors: Vec<Descriptor>,
    /// Each keyframe's reach: the 90th percentile of its feature cloud's ranges \[m\] (what a
    /// map file's tiles are cut to, [`super::map_prior::tiling_for`]), measured as it was
    /// prepared, kept or not.
    pub(super) reach_m: Vec<Option<f64>>,
    /// A map file's points, which cut its tiles (the keyframes, at their poses) again where
    /// they were not kept; `None` for a run's output, whose clouds are read again.
    pub(super) tiles: Option<TileIndex>,
}

impl Session {
    /// Its trajectory as links see it.
    pub(super) fn track(&self) -> Track<'_> {
        Track {
            poses: &self.poses,
            travelled_m: &self.travelled_m,
        }
    }

    /// Reads `path`'s trajectory and metadata (not its clouds).
    pub(super) fn read(path: &Path) -> Result<Self> {
        let output = read_segment(path).map_err(|e| match e {
            Error::InvalidInput(m) => Error::InvalidInput(format!(
                "{m} (mireg merge takes the outputs of `mireg register`)"
            )),
            e => e,
        })?;
        let number = |key: &str| -> Result<f64> {
            output
                .meta
                .get(key)
                .and_then(|v| v.parse::<f64>().ok())
                .filter(|v| v.is_finite() && *v > 0.0)
                .ok_or_else(|| {
                    format_err(
                        path,
                        format!("its mireg metadata has no positive {key}: not a `mireg register` output?"),
                    )
                })
        };
        let voxel_m = number("voxel_m")?;
        let feature_voxel_m = number("feature_voxel_m").unwrap_or(voxel_m);
        let odometry_topic = output.meta.get("pose_topic").cloned().unwrap_or_default();
        let namespace = odometry_topic
            .strip_suffix("/pose")
            .unwrap_or("/mireg")
            .to_string();
        let optimized = format!("{namespace}/pose_optimized");
        let channels = list_channels(path)?;
        let mut poses: Vec<Isometry3<f64>> = output.frames.iter().map(|f| f.pose).collect();
        let mut pose_topic = odometry_topic;
        if crate::trajectory::has_optimized_poses(&channels, &optimized) {
            let best = read_mcap_pose_topic(path, &optimized)?;
            let by_stamp: BTreeMap<i64, Isometry3<f64>> =
                best.stamps_ns.iter().copied().zip(best.poses).collect();
            for (p, f) in poses.iter_mut().zip(&output.frames) {
                if let Some(q) = by_stamp.get(&f.stamp_ns) {
                    *p = *q;
                }
            }
            pose_topic = optimized;
        }
        let name = path.file_stem().map_or_else(
            || "session".to_string(),
            |s| s.to_string_lossy().into_owned(),
        );
        Ok(Self {
            travelled_m: path_distances(&poses),
            output,
            name,
            pose_topic,
            namespace,
            poses,
            voxel_m,
            feature_voxel_m,
            keyframes: Vec::new(),
            frames: Vec::new(),
            descriptors: Vec::new(),
            reach_m: Vec::new(),
            tiles: None,
        })
    }

    /// Selects the keyframes by `config`'s rule and prepares their clouds with `pair`, streaming
    /// the output's clouds once: each keyframe's descriptor is kept, its prepared cloud only
    /// while the kept ones stay within [`LoopConfig::memory_budget_bytes`] (by
    /// [`PreparedFrame::idle_bytes`]); the others are prepared again when a candidate needs them
    /// ([`Session::load`]).
    pub(super) fn prepare_keyframes(
        &mut self,
        config: &LoopConfig,
        pair: &PairConfig,
    ) -> Result<()> {
        self.prepare_keyframes_from(config, pair, None)
    }

    /// [`Session::prepare_keyframes`], taking the keyframes' frames from `kept` where it has
    /// them and was prepared by the same `config.keyframes` and `pair` (the frames `register`'s
    /// odometry prepared, [`crate::register::register_log_keeping_keyframes`]): only the others
    /// are read and prepared. The keyframes come in frame order either way.
    pub(super) fn prepare_keyframes_from(
        &mut self,
        config: &LoopConfig,
        pair: &PairConfig,
        kept: Option<KeptKeyframes>,
    ) -> Result<()> {
        let keys = select_keyframes(&self.poses, &self.travelled_m, &config.keyframes)?;
        let mut reused: BTreeMap<usize, PreparedFrame> = kept
            .filter(|kept| kept.pair == *pair && kept.loops.keyframes == config.keyframes)
            .map(|kept| kept.frames)
            .unwrap_or_default();
        reused.retain(|k, _| keys.binary_search(k).is_ok());
        let missing: Vec<usize> = keys
            .iter()
            .copied()
            .filter(|k| !reused.contains_key(k))
            .collect();
        let mut bytes = 0usize;
        let budget = config.memory_budget_bytes;
        let (mut keyframes, mut frames, mut descriptors) = (Vec::new(), Vec::new(), Vec::new());
        let mut reach = Vec::new();
        let mut add = |k: usize, frame: PreparedFrame| {
            descriptors.push(Descriptor::from_prepared(&frame));
            reach.push(percentile_range(&frame.points, 0.9));
            keyframes.push(k);
            frames.push(keep_within(&mut bytes, budget, frame));
        };
        // The reused frames before each one prepared, so that all come in frame order.
        self.for_each_prepared(&missing, pair, |k, frame| {
            while let Some(entry) = reused.first_entry().filter(|e| *e.key() < k) {
                let (r, f) = entry.remove_entry();
                add(r, f);
            }
            add(k, frame);
        })?;
        while let Some((r, f)) = reused.pop_first() {
            add(r, f);
        }
        (self.keyframes, self.frames, self.descriptors) = (keyframes, frames, descriptors);
        self.reach_m = reach;
        Ok(())
    }

    /// The prepared clouds of the keyframes `wanted` (indices into [`Session::keyframes`]) that
    /// are not kept, prepared again from the output (or cut again from the map's points).
    pub(super) fn load(
        &self,
        wanted: &BTreeSet<usize>,
        pair: &PairConfig,
    ) -> Result<BTreeMap<usize, PreparedFrame>> {
        let missing: Vec<usize> = wanted
            .iter()
            .copied()
            .filter(|&k| self.frames[k].is_none())
            .collect();
        let mut out = BTreeMap::new();
        if missing.is_empty() {
            return Ok(out);
        }
        if let Some(index) = &self.tiles {
            let prepared: Vec<Option<PreparedFrame>> = missing
                .par_iter()
                .map(|&k| {
                    let centre = Point3::from(self.poses[self.keyframes[k]].translation.vector);
                    index.prepare(&centre, pair)
                })
                .collect();
            for (k, frame) in missing.into_iter().zip(prepared) {
                if let Some(frame) = frame {
                    out.insert(k, frame);
                }
            }
            return Ok(out);
        }
        let frames: Vec<usize> = missing.iter().map(|&k| self.keyframes[k]).collect();
        self.for_each_prepared(&frames, pair, |f, frame| {
            if let Some(i) = missing.iter().position(|&k| self.keyframes[k] == f) {
                out.insert(missing[i], frame);
            }
        })?;
        Ok(out)
    }

    /// Streams the output's clouds once, calling `f(frame, prepared)` for each frame of `keys`
    /// (frame indices) whose cloud prepares with features, in the file's order, one at a time.
    /// Only those clouds are decoded; they are prepared [`PREPARE_BATCH_PER_THREAD`] a thread
    /// at a time, in parallel.
    fn for_each_prepared(
        &self,
        keys: &[usize],
        pair: &PairConfig,
        mut f: impl FnMut(usize, PreparedFrame),
    ) -> Result<()> {
        let frames = &self.output.frames;
        let by_stamp: BTreeMap<i64, usize> =
            keys.iter().map(|&k| (frames[k].stamp_ns, k)).collect();
        let logged: BTreeSet<u64> = keys.iter().map(|&k| frames[k].log_time).collect();
        let batch = PREPARE_BATCH_PER_THREAD * rayon::current_num_threads().max(1);
        let mut pending: Vec<(usize, Vec<Point3<f64>>)> = Vec::with_capacity(batch);
        let mut flush = |pending: &mut Vec<(usize, Vec<Point3<f64>>)>| {
            let prepared: Vec<(usize, Option<PreparedFrame>)> = pending
                .par_drain(..)
                .map(|(k, points)| {
                    let frame = prepare_frame(&points, pair)
                        .ok()
                        .filter(|frame| frame.has_features());
                    (k, frame)
                })
                .collect();
            for (k, frame) in prepared {
                if let Some(frame) = frame {
                    f(k, frame);
                }
            }
        };
        let mut seen = BTreeSet::new();
        let topic = self.output.meta.get("topic").cloned();
        let wanted = |log_time: u64| logged.contains(&log_time);
        for_each_cloud_where(&self.output.path, topic.as_deref(), wanted, |_, cloud| {
            if let Some(&k) = by_stamp.get(&cloud.header.stamp.to_ns())
                && seen.insert(k)
            {
                pending.push((k, cloud.points));
                if pending.len() == batch {
                    flush(&mut pending);
                }
            }
            Ok(std::ops::ControlFlow::Continue(()))
        })?;
        flush(&mut pending);
        Ok(())
    }
}

/// Keyframe clouds prepared at once per thread of the pool, each on one thread: 2. A cloud's
/// own preparation keeps two cores busy only part of the time.
pub const PREPARE_BATCH_PER_THREAD: usize = 2;

/// `frame`, counted into `kept_bytes`, while the frames kept and it fit `budget` bytes (by
/// [`PreparedFrame::idle_bytes`]); else `None` (it is prepared again when needed).
pub(super) fn keep_within(
    kept_bytes: &mut usize,
    budget: usize,
    frame: PreparedFrame,
) -> Option<PreparedFrame> {
    let b = frame.idle_bytes();
    (*kept_bytes + b <= budget).then(|| {
        *kept_bytes += b;
        frame
    })
}

/// The loop settings (at the first session's voxel, keyframes kept within `keyframe_memory_bytes`)
/// and the registration settings of a merge or localisation, with every session's keyframes
/// prepared by them.
pub(super) fn prepare_sessions(
    sessions: &mut [Session],
    keyframe_memory_bytes: usize,
    seed: u64,
) -> Result<(LoopConfig, PairConfig)> {
    let (loops, pair) = merge_settings(&sessions[0], keyframe_memory_bytes, seed);
    for s in sessions.iter_mut() {
        s.prepare_keyframes(&loops, &pair)?;
    }
    Ok((loops, pair))
}

/// The loop and registration settings of a merge whose first session is `first`: at its voxel,
/// keyframes kept within `keyframe_memory_bytes`, with `seed`.
pub(super) fn merge_settings(
    first: &Session,
    keyframe_memory_bytes: usize,
    seed: u64,
) -> (LoopConfig, PairConfig) {
    let loops = LoopConfig {
        memory_budget_bytes: keyframe_memory_bytes,
        ..LoopConfig::for_voxel(first.voxel_m)
    };
    let pair = merge_pair_config(first, &loops, seed);
    (loops, pair)
}

/// The registration settings of a merge: a loop verification's at `session`'s voxels, with
/// `seed`.
fn merge_pair_config(session: &Session, loops: &LoopConfig, seed: u64) -> PairConfig {
    let mut pair = OdometryConfig::default().pair;
    pair.voxel_size_m = session.voxel_m;
    pair.seed = seed;
    let pair = with_feature_voxel(&pair, session.feature_voxel_m);
    loop_pair_config(&pair, loops)
}
