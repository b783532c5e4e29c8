//! [`build_map`]: the [`VoxelMap`] of a `mireg register` output, from its best trajectory.
//!
//! Two passes over the MCAP: the first reads the trajectory (one pose per frame, 64 bytes each)
//! and the run's `mireg` metadata; the second streams the clouds one at a time into the
//! accumulator. Clouds are used as stored in the log (not deskewed, whatever `register` did).

use std::collections::BTreeMap;
use std::io::Write;
use std::path::{Path, PathBuf};

use mcap::records::Record;
use nalgebra::Isometry3;

use super::VoxelMap;
use crate::io::atomic_file::PendingFile;
use crate::io::cloud_file::CloudFileFormat;
use crate::io::codec::PoseStampedDecoder;
use crate::io::mcap::log::{ChannelInfo, for_each_record, list_channels};
use crate::io::poses::check_pose_topic;
use crate::register::for_each_cloud;
use crate::trajectory;
use crate::{Error, Result};

/// Which trajectory places the clouds ([`MapOptions::trajectory`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum TrajectoryChoice {
    /// `…/pose`: the odometry of `mireg register`.
    Odometry,
    /// `…/pose_optimized`: the loop-closed trajectory (same message type).
    Optimized,
    /// `…/pose_merged`: the trajectory `mireg merge` put in its group's frame.
    Merged,
    /// `…/pose_merged` when the log has it, else `…/pose_optimized` when it has that, else
    /// `…/pose`.
    #[default]
    Auto,
}

/// How the map of a run is made: what [`build_map`] needs besides the log (`mireg map` maps its
/// flags onto it; [`write_map`] writes the result).
#[derive(Debug, Clone, Default, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(default)]
pub struct MapOptions {
    /// Voxel edge of the map \[m\]: one point (centroid, mean intensity) per occupied voxel.
    /// Default `None`: the `voxel_m` that `register` used, from the run's `mireg` metadata.
    pub voxel_m: Option<f64>,
    /// Trajectory placing the clouds (the newest run's topics). Default
    /// [`TrajectoryChoice::Auto`].
    pub trajectory: TrajectoryChoice,
    /// Point cloud topic. Default `None`: the one `register` read (its metadata), else the log's
    /// only cloud topic.
    pub topic: Option<String>,
}

/// What went into a map.
#[derive(Debug, Clone, serde::Serialize)]
pub struct MapSummary {
    /// Pose topic used.
    pub pose_topic: String,
    /// Point cloud topic read.
    pub cloud_topic: String,
    /// Voxel edge \[m\].
    pub voxel_m: f64,
    /// Where the voxel came from: `option` (`--voxel`) or `register_metadata`.
    pub voxel_source: &'static str,
    /// Poses on the pose topic.
    pub poses: usize,
    /// Clouds placed in the map.
    pub clouds_used: u64,
    /// Clouds skipped because no pose has their header stamp (e.g. frames a trajectory left out).
    pub clouds_without_pose: u64,
    /// Points accumulated.
    pub points_in: u64,
    /// Points skipped because too far from the origin for a voxel key.
    pub points_out_of_range: u64,
    /// Points of the map (occupied voxels).
    pub map_points: usize,
    /// Whether the map carries intensity: every cloud used had an `intensity` field.
    pub intensity: bool,
}

/// The pose topics of the newest `mireg` run of a log: (odometry, optimized, merged).
fn run_pose_topics(channels: &[ChannelInfo]) -> (String, String, String) {
    let ns = trajectory::newest_mireg_namespace(channels)
        .unwrap_or_else(|| trajectory::MIREG_NAMESPACE.to_string());
    (
        format!("{ns}/pose"),
        format!("{ns}/pose_optimized"),
        format!("{ns}/pose_merged"),
    )
}

/// Poses by header stamp \[ns\], and the `mireg` and `mireg_merge` metadata records of a log.
type PosesAndMetadata = (
    Vec<(i64, Isometry3<f64>)>,
    Vec<BTreeMap<String, String>>,
    Vec<BTreeMap<String, String>>,
);

/// Reads the poses on `topic` (sorted by header stamp) and the `mireg` metadata records in
/// one pass.
fn read_poses_and_metadata(
    path: &Path,
    topic: &str,
    decode: PoseStampedDecoder,
) -> Result<PosesAndMetadata> {
    let mut ids = Vec::new();
    let mut poses = Vec::new();
    let mut metas = Vec::new();
    let mut merges = Vec::new();
    for_each_record(path, |r| {
        match r {
            Record::Channel(c) if c.topic == topic => ids.push(c.id),
            Record::Metadata(m) if m.name == "mireg" => metas.push(m.metadata),
            Record::Metadata(m) if m.name == "mireg_merge" => merges.push(m.metadata),
            Record::Message { header, data } if ids.contains(&header.channel_id) => {
                let (h, pose) = decode(&data).map_err(|e| {
                    crate::io::format_err(
                        path,
                        format!(
                            "message on {topic} at log time {} ns: field {}: {}",
                            header.log_time, e.field, e.detail
                        ),
                    )
                })?;
                poses.push((h.stamp.to_ns(), pose));
            }
            _ => {}
        }
        Ok(())
    })?;
    poses.sort_by_key(|p| p.0);
    Ok((poses, metas, merges))
}

/// Builds the map of `input`, a `mireg register` output (MCAP holding the clouds and the
/// poses): each cloud on the cloud topic is placed by the pose with its header stamp and
/// accumulated into a [`VoxelMap`]; clouds without a pose are skipped and counted.
///
/// # Errors
/// [`Error::InvalidInput`] naming the file when it has no pose topic of the chosen kind, no
/// poses on it, no voxel (neither `voxel_m` nor `mireg` metadata), or no cloud topic;
/// [`Error::Io`] / [`Error::Format`] for an unreadable or malformed file.
pub fn build_map(input: &Path, opts: &MapOptions) -> Result<(VoxelMap, MapSummary)> {
    build_map_of_runs(&[input.to_path_buf()], opts)
}

/// One map of several runs in one frame: the outputs of one `mireg merge` (their merged
/// trajectories, `…/pose_merged`, all in the same merged frame), accumulated as [`build_map`]
/// accumulates one run. The voxel is the first run's (or `opts.voxel_m`); the summary's counts
/// are summed over the runs, its topics the first run's.
///
/// # Errors
/// As [`build_map`] for each run; [`Error::InvalidInput`] when several runs are given and one
/// has no merged trajectory, or two were merged into different frames.
pub fn build_map_of_runs(inputs: &[PathBuf], opts: &MapOptions) -> Result<(VoxelMap, MapSummary)> {
    let Some(first) = inputs.first() else {
        return Err(Error::InvalidInput("a map needs at least one run".into()));
    };
    let mut opts = opts.clone();
    if inputs.len() > 1 {
        opts.trajectory = match opts.trajectory {
            TrajectoryChoice::Auto | TrajectoryChoice::Merged => TrajectoryChoice::Merged,
            _ => {
                return Err(Error::InvalidInput(
                    "a map of several runs places them by their merged trajectories \
                     (`mireg merge`); --trajectory must be merged or auto"
                        .into(),
                ));
            }
        };
    }
    let (mut map, mut summary, frame) = add_run(None, first, &opts)?;
    for input in &inputs[1..] {
        let (m, s, f) = add_run(Some(map), input, &opts)?;
        if f != frame {
            return Err(Error::InvalidInput(format!(
                "{} was merged into {}, {} into {}: a map of several runs needs runs of one merge \
                 group",
                first.display(),
                frame.as_deref().unwrap_or("no merged frame"),
                input.display(),
                f.as_deref().unwrap_or("no merged frame"),
            )));
        }
        map = m;
        summary.poses += s.poses;
        summary.clouds_used += s.clouds_used;
        summary.clouds_without_pose += s.clouds_without_pose;
        summary.intensity &= s.intensity;
    }
    summary.points_in = map.points_added();
    summary.points_out_of_range = map.points_out_of_range();
    summary.map_points = map.len();
    Ok((map, summary))
}

/// The map's voxel \[m\] and where it came from: the map's own when it has one (an earlier
/// run's), else `opts.voxel_m`, else the `voxel_m` of the run's `mireg` metadata `meta`.
fn map_voxel(
    input: &Path,
    opts: &MapOptions,
    map: Option<&VoxelMap>,
    meta: Option<&BTreeMap<String, String>>,
) -> Result<(f64, &'static str)> {
    Ok(match (opts.voxel_m, map) {
        (_, Some(m)) => (m.voxel_m(), "first_run"),
        (Some(v), None) => (v, "option"),
        (None, None) => {
            let v = meta
                .and_then(|m| m.get("voxel_m"))
                .and_then(|v| v.parse::<f64>().ok())
                .ok_or_else(|| {
                    Error::InvalidInput(format!(
                        "{}: no mireg metadata with voxel_m (not written by `mireg register`?); \
                         set the map's voxel with --voxel",
                        input.display()
                    ))
                })?;
            (v, "register_metadata")
        }
    })
}

/// Adds the clouds of one run to `map` (a new map at the run's voxel when `None`); returns the
/// map, the run's summary and the merged frame it was put in (`mireg_merge` metadata), if any.
fn add_run(
    map: Option<VoxelMap>,
    input: &Path,
    opts: &MapOptions,
) -> Result<(VoxelMap, MapSummary, Option<String>)> {
    let channels = list_channels(input)?;
    let (odometry, optimized, merged) = run_pose_topics(&channels);
    let pose_topic = match opts.trajectory {
        TrajectoryChoice::Odometry => odometry.clone(),
        TrajectoryChoice::Optimized => optimized,
        TrajectoryChoice::Merged => merged,
        TrajectoryChoice::Auto if trajectory::has_optimized_poses(&channels, &merged) => merged,
        TrajectoryChoice::Auto if trajectory::has_optimized_poses(&channels, &optimized) => {
            optimized
        }
        TrajectoryChoice::Auto => odometry.clone(),
    };
    let decode = check_pose_topic(input, &channels, &pose_topic).map_err(|e| match e {
        Error::InvalidInput(m) => Error::InvalidInput(format!(
            "{m} (mireg map needs the poses of a `mireg register` or `mireg merge` output)"
        )),
        e => e,
    })?;
    let (poses, metas, merge_metas) = read_poses_and_metadata(input, &pose_topic, decode)?;
    if poses.is_empty() {
        return Err(Error::InvalidInput(format!(
            "{}: no poses: topic {pose_topic} has no messages",
            input.display()
        )));
    }
    let frame = merge_metas
        .iter()
        .rev()
        .find(|m| m.get("merged_pose_topic") == Some(&pose_topic))
        .and_then(|m| {
            Some(format!(
                "{} of merge {}",
                m.get("merged_frame")?,
                m.get("merge_id")?
            ))
        });
    // The metadata of the run that wrote these poses (the last one when none names them).
    let meta = metas
        .iter()
        .rev()
        .find(|m| m.get("pose_topic") == Some(&odometry))
        .or(metas.last());
    let (voxel_m, voxel_source) = map_voxel(input, opts, map.as_ref(), meta)?;
    let mut map = match map {
        Some(m) => m,
        None => VoxelMap::new(voxel_m)?,
    };
    let topic = opts
        .topic
        .clone()
        .or_else(|| meta.and_then(|m| m.get("topic").cloned()));
    let mut used = 0u64;
    let mut without_pose = 0u64;
    let mut all_intensity = true;
    let cloud_topic = for_each_cloud(input, topic.as_deref(), |_, cloud| {
        let stamp = cloud.header.stamp.to_ns();
        match poses.binary_search_by_key(&stamp, |p| p.0) {
            Ok(k) => {
                all_intensity &= cloud.intensity.is_some();
                map.add_cloud(&poses[k].1, &cloud.points, cloud.intensity.as_deref());
                used += 1;
            }
            Err(_) => without_pose += 1,
        }
        Ok(std::ops::ControlFlow::Continue(()))
    })?;
    let summary = MapSummary {
        pose_topic,
        cloud_topic,
        voxel_m,
        voxel_source,
        poses: poses.len(),
        clouds_used: used,
        clouds_without_pose: without_pose,
        points_in: map.points_added(),
        points_out_of_range: map.points_out_of_range(),
        map_points: map.len(),
        intensity: used > 0 && all_intensity,
    };
    Ok((map, summary, frame))
}

/// Writes `map` to `path` in `format` ([`CloudFileFormat::from_path`] of it): one row per
/// occupied voxel, x y z (float32, metres, the world frame of the trajectory used) and, when
/// `intensity`, the mean intensity. Written beside the target and moved into place when
/// complete; an existing file is replaced only when `force`. Errors name `path`.
pub fn write_map(
    map: VoxelMap,
    intensity: bool,
    format: CloudFileFormat,
    path: &Path,
    force: bool,
) -> Result<()> {
    let cols = if intensity { 4 } else { 3 };
    let rows = map.to_rows(intensity);
    drop(map);
    let (file, pending) = PendingFile::create(path, force)?;
    let io = |e: std::io::Error| Error::Io {
        path: path.to_path_buf(),
        source: e,
    };
    let mut w = std::io::BufWriter::new(file);
    format.write(&rows, cols, &mut w).map_err(io)?;
    w.flush().map_err(io)?;
    let file = w.into_inner().map_err(|e| io(e.into_error()))?;
    pending.commit(file)
}
