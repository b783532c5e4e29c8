//! What `mireg register` adds to the log: its channels (`/tf`, the pose and statistics topics, in
//! the input's message family), one message of each per frame, and the statistics' JSON Schema.

use std::collections::BTreeMap;

use nalgebra::Matrix6;
use serde_json::json;

use super::clouds::CloudKind;
use super::frames::FrameOut;
use crate::Result;
use crate::io::codec::{self, cdr, foxglove, ros1};
use crate::io::mcap::log::ChannelInfo;
use crate::io::mcap::log::OutputLog;
use crate::loops::Source;
use crate::odometry::uncertainty::{PoseUncertainty, uninformed_information};
use crate::trajectory::free_mireg_namespace;

/// The `callerid` of our channels in a ROS 1 log.
const ROS1_CALLERID: &str = "/mireg";

/// JSON Schema of the `/mireg/stats` messages.
pub fn stats_json_schema() -> serde_json::Value {
    let num = json!({"type": "number"});
    let int = json!({"type": "integer"});
    json!({
        "$schema": "https://json-schema.org/draft/2020-12/schema",
        "title": "mireg.FrameStats",
        "description": "Per-frame registration statistics written by mireg register",
        "type": "object",
        "properties": {
            "frame": int, "stamp_ns": int, "success": {"type": "boolean"},
            "failure_reason": {"type": ["string", "null"]},
            "failure_detail": {"type": ["string", "null"]}, "fallback": {"type": ["string", "null"]},
            "num_points": int, "num_dropped_non_finite": int, "num_dropped_far": int, "num_dropped_zero": int,
            "num_dropped_livox_tag": int, "num_dropped_time": int,
            "num_points_downsampled": int,
            "num_correspondences": {"type": ["integer", "null"], "description": "Feature correspondences of the frame's global registration (null: none ran, the frame was tracked, or it is the first)"},
            "num_inliers": {"type": ["integer", "null"], "description": "MI-RANSAC inliers among them (null: no global registration)"},
            "inlier_ratio": {"type": ["number", "null"]}, "hypotheses": {"type": ["integer", "null"]},
            "best_found_at": {"type": ["integer", "null"]},
            "fitness": {"type": ["number", "null"], "description": "ICP fitness of the frame-to-frame refinement of the global registration (null: no global registration; map_fitness is the fit to the local map)"},
            "inlier_rmse_m": {"type": ["number", "null"]},
            "icp_iterations": int,
            "deskewed": {"type": "boolean"}, "time_field": {"type": ["string", "null"]},
            "map_guess": {"type": ["string", "null"], "enum": ["global", "constant_velocity", "second_global", "coarse_global", "tracked", null]},
            "map_used": {"type": "boolean"}, "map_fitness": {"type": ["number", "null"]},
            "map_inlier_rmse_m": {"type": ["number", "null"]},
            "map_icp_iterations": {"type": ["integer", "null"]},
            "map_coarse_icp_iterations": {"type": ["integer", "null"]},
            "map_points": {"type": ["integer", "null"]},
            "map_rival_fitness": {"type": ["number", "null"], "description": "Map fitness of the best other start whose refinement ended beyond the map distance or 1 deg of the accepted pose (null: none did)"},
            "map_rival_offset_m": {"type": ["number", "null"], "description": "How far that start's pose is from the accepted one [m]"},
            "map_rival_offset_deg": {"type": ["number", "null"], "description": "... and its rotation from it [deg]"},
            "map_retry_rounds": {"type": ["integer", "null"], "description": "Rounds of retries of the frame's global registration (another RANSAC stream and a coarser scale each; 0: the first estimate was trusted)"},
            "sigma_m": {"type": "number", "description": "Predicted standard deviation of the frame's step along its least certain direction [m] (the covariance of /mireg/pose_cov)"},
            "sigma_deg": {"type": "number", "description": "Predicted standard deviation about the least certain rotation axis [deg]"},
            "degeneracy_translation": {"type": "number", "description": "Smallest over largest eigenvalue of the registration's translation information (0: a direction unconstrained, 1: all alike); 0 for a failed frame"},
            "degeneracy_rotation": {"type": "number", "description": "The same for the rotation"},
            "suspect": {"type": ["string", "null"], "enum": ["degenerate", "fitness_drop", "hypothesis_cap", "ambiguous", "unconfirmed", null], "description": "Why a registered frame is doubtful (its step's deviations are then 10x what its registration measured)"},
            "map_correspondences": {"type": ["integer", "null"], "description": "Point-to-plane correspondences of the map ICP at the final pose: what the covariance was measured on"},
            "timings_s": {"type": "object", "additionalProperties": num}
        },
        "required": ["frame", "stamp_ns", "success", "failure_reason", "num_points", "num_points_downsampled",
                     "num_correspondences", "num_inliers", "inlier_ratio", "hypotheses", "best_found_at",
                     "fitness", "inlier_rmse_m", "icp_iterations", "timings_s"]
    })
}

fn frame_stats(out: &FrameOut, u: &PoseUncertainty) -> serde_json::Value {
    let e = &out.est;
    let p = e.pair.as_ref();
    let t = p.map(|p| p.timings_s).unwrap_or_default();
    // A frame without a global registration (tracked, or the first) has none of its figures:
    // null, not 0, so that plots and means do not read them as a registration that found none.
    let num_corr = p.map(|p| p.num_correspondences);
    let num_inl = p.map(|p| p.num_inliers);
    let rival = e.map.and_then(|m| m.rival);
    json!({
        "frame": e.index,
        "stamp_ns": out.cloud.header.stamp.to_ns(),
        "success": e.success,
        "failure_reason": e.failure.map(|f| f.as_str()),
        "failure_detail": out.cloud.invalid.as_ref().map(|i| &i.1),
        "fallback": e.fallback.map(|f| match f {
            crate::odometry::Fallback::ConstantVelocityIcp => "constant_velocity_icp",
            crate::odometry::Fallback::ConstantVelocity => "constant_velocity",
        }),
        "num_points": e.num_points,
        "num_dropped_non_finite": out.cloud.dropped.non_finite,
        "num_dropped_far": out.cloud.dropped.far,
        "num_dropped_zero": out.cloud.dropped.zero,
        "num_dropped_livox_tag": out.cloud.dropped.tag,
        "num_dropped_time": out.cloud.dropped.time,
        "num_points_downsampled": e.num_points_downsampled,
        "num_correspondences": num_corr,
        "num_inliers": num_inl,
        "inlier_ratio": p.map(|p| if p.num_correspondences > 0 {
            p.num_inliers as f64 / p.num_correspondences as f64
        } else {
            0.0
        }),
        "hypotheses": p.map(|p| p.hypotheses),
        "best_found_at": p.and_then(|p| p.best_found_at),
        "fitness": p.map(|p| p.fitness),
        "inlier_rmse_m": p.map(|p| p.inlier_rmse_m),
        "icp_iterations": p.map_or(0, |p| p.icp_iterations) + e.fallback_icp_iterations,
        "deskewed": out.cloud.deskewed(),
        "time_field": out.cloud.time_field,
        "map_guess": e.map.map(|m| m.guess.as_str()),
        "map_used": e.map.is_some_and(|m| m.used),
        "map_fitness": e.map.map(|m| m.fitness),
        "map_inlier_rmse_m": e.map.map(|m| m.inlier_rmse_m),
        "map_icp_iterations": e.map.map(|m| m.iterations),
        "map_coarse_icp_iterations": e.map.map(|m| m.coarse_iterations),
        "map_fine_icp_iterations": e.map.map(|m| m.fine_iterations),
        "map_points": e.map.map(|m| m.map_points),
        "map_retry_rounds": e.map.map(|m| m.retry_rounds),
        "map_rival_fitness": rival.map(|r| r.fitness),
        "map_rival_offset_m": rival.map(|r| r.offset.translation.vector.norm()),
        "map_rival_offset_deg": rival.map(|r| r.offset.rotation.angle().to_degrees()),
        "map_correspondences": e.map.map(|m| m.hessian.count),
        "sigma_m": u.sigma_m,
        "sigma_deg": u.sigma_deg,
        "degeneracy_translation": u.degeneracy_translation,
        "degeneracy_rotation": u.degeneracy_rotation,
        "suspect": e.suspect.map(|s| s.as_str()),
        "timings_s": {
            "decode": out.cloud.decode_s,
            "downsample": out.prep.downsample,
            "normals": out.prep.normals,
            "features": out.prep.features,
            "matching": t.matching,
            "ranking": t.ranking,
            "ransac": t.ransac,
            "icp": t.icp,
            "map_target": e.map.map_or(0.0, |m| m.target_s),
            "map_icp": e.map.map_or(0.0, |m| m.icp_s),
            "register": out.register_s,
        }
    })
}

/// The topics of this run: a log registered before keeps its mireg topics and this run's go to
/// the next namespace (`/mireg_2/…`), so that no topic mixes two runs; transforms go to `/tf`
/// unless the log has one.
pub(super) struct Topics {
    pub(super) tf: String,
    pub(super) pose: String,
    pub(super) stats: String,
    /// Each frame's pose with its covariance (`geometry_msgs/PoseWithCovarianceStamped`).
    pub(super) pose_cov: String,
    /// Loop closure's: the optimised poses, their transforms, the candidates tried.
    pub(super) pose_optimized: String,
    pub(super) tf_optimized: String,
    pub(super) loops: String,
}

impl Topics {
    pub(super) fn for_input(channels: &[ChannelInfo]) -> Self {
        let namespace = free_mireg_namespace(channels.iter().map(|c| c.topic.as_str()));
        let tf = if channels.iter().any(|c| c.topic == "/tf") {
            format!("{namespace}/tf")
        } else {
            "/tf".to_string()
        };
        Self {
            tf,
            pose: format!("{namespace}/pose"),
            stats: format!("{namespace}/stats"),
            pose_cov: format!("{namespace}/pose_cov"),
            pose_optimized: format!("{namespace}/pose_optimized"),
            tf_optimized: format!("{namespace}/tf_optimized"),
            loops: format!("{namespace}/loops"),
        }
    }
}

pub(super) struct Outputs {
    kind: CloudKind,
    tf: u16,
    pose: u16,
    stats: u16,
    /// The pose-with-covariance channel and the prior information of an unmeasured step
    /// ([`crate::odometry::uncertainty::uninformed_information`]); `None` for foxglove inputs
    /// (no such message in that family) and where the caller has no per-frame information.
    pose_cov: Option<(u16, Matrix6<f64>)>,
    /// Loop closure's channels, when it runs.
    pub(super) loops: Option<LoopChannels>,
}

/// The channels of loop closure: the optimised trajectory (`/tf` variant and poses) and the
/// candidates tried.
pub(super) struct LoopChannels {
    tf: u16,
    pose: u16,
    loops: u16,
}

impl Outputs {
    /// Registers our channels in the input's message family: ROS 2 messages for ROS 2 inputs,
    /// ROS 1 messages (with the ROS 1 profile's channel metadata) for ROS 1 inputs, foxglove
    /// protobuf messages for foxglove inputs. With `voxel_m` (the ICP voxel \[m\]), also each
    /// frame's pose with its covariance, but for foxglove inputs.
    pub(super) fn create(
        log: &mut OutputLog,
        kind: CloudKind,
        topics: &Topics,
        loops: bool,
        voxel_m: Option<f64>,
    ) -> Result<Self> {
        let (tf, pose) = pose_channels(log, kind, &topics.tf, &topics.pose)?;
        let stats =
            log.add_json_channel(&topics.stats, "mireg.FrameStats", &stats_json_schema())?;
        let pose_cov = match (kind, voxel_m) {
            (CloudKind::Foxglove, _) | (_, None) => None,
            (_, Some(voxel_m)) => Some((
                pose_cov_channel(log, kind, &topics.pose_cov)?,
                uninformed_information(voxel_m),
            )),
        };
        let loops = if loops {
            let (tf, pose) =
                pose_channels(log, kind, &topics.tf_optimized, &topics.pose_optimized)?;
            let loops =
                log.add_json_channel(&topics.loops, "mireg.LoopCandidate", &loops_json_schema())?;
            Some(LoopChannels { tf, pose, loops })
        } else {
            None
        };
        Ok(Self {
            kind,
            tf,
            pose,
            stats,
            pose_cov,
            loops,
        })
    }
}

/// The metadata of a channel of ours in a ROS 1 log: what the ROS 1 profile (and `mcap convert`
/// from a bag) writes.
fn ros1_channel_metadata(topic: &str, md5: &str) -> BTreeMap<String, String> {
    BTreeMap::from([
        ("callerid".to_string(), ROS1_CALLERID.to_string()),
        ("latching".to_string(), "0".to_string()),
        ("md5sum".to_string(), md5.to_string()),
        ("topic".to_string(), topic.to_string()),
    ])
}

/// A `geometry_msgs/PoseWithCovarianceStamped` channel on `topic` (ROS 1 or ROS 2 families).
fn pose_cov_channel(log: &mut OutputLog, kind: CloudKind, topic: &str) -> Result<u16> {
    match kind {
        CloudKind::Ros1 | CloudKind::LivoxRos1(_) => log.add_channel_with_metadata(
            topic,
            ros1::POSE_WITH_COVARIANCE_STAMPED_SCHEMA_NAME,
            ros1::SCHEMA_ENCODING,
            ros1::POSE_WITH_COVARIANCE_STAMPED_SCHEMA.as_bytes(),
            ros1::MESSAGE_ENCODING,
            ros1_channel_metadata(topic, ros1::POSE_WITH_COVARIANCE_STAMPED_MD5),
        ),
        _ => log.add_cdr_channel(topic, cdr::POSE_WITH_COVARIANCE_STAMPED),
    }
}

/// A `/tf` and a pose channel in `kind`'s message family, on `tf_topic` and `pose_topic`.
pub(crate) fn pose_channels(
    log: &mut OutputLog,
    kind: CloudKind,
    tf_topic: &str,
    pose_topic: &str,
) -> Result<(u16, u16)> {
    Ok(match kind {
        CloudKind::Ros2 | CloudKind::LivoxRos2(_) => (
            log.add_cdr_channel(tf_topic, cdr::TF_MESSAGE)?,
            log.add_cdr_channel(pose_topic, cdr::POSE_STAMPED)?,
        ),
        CloudKind::Ros1 | CloudKind::LivoxRos1(_) => {
            let meta = ros1_channel_metadata;
            (
                log.add_channel_with_metadata(
                    tf_topic,
                    ros1::TF_MESSAGE_SCHEMA_NAME,
                    ros1::SCHEMA_ENCODING,
                    ros1::TF_MESSAGE_SCHEMA.as_bytes(),
                    ros1::MESSAGE_ENCODING,
                    meta(tf_topic, ros1::TF_MESSAGE_MD5),
                )?,
                log.add_channel_with_metadata(
                    pose_topic,
                    ros1::POSE_STAMPED_SCHEMA_NAME,
                    ros1::SCHEMA_ENCODING,
                    ros1::POSE_STAMPED_SCHEMA.as_bytes(),
                    ros1::MESSAGE_ENCODING,
                    meta(pose_topic, ros1::POSE_STAMPED_MD5),
                )?,
            )
        }
        CloudKind::Foxglove => {
            let (t, p) = (
                foxglove::frame_transforms_schema(),
                foxglove::pose_in_frame_schema(),
            );
            (
                log.add_channel(
                    tf_topic,
                    &t.name,
                    &t.encoding,
                    &t.data,
                    foxglove::MESSAGE_ENCODING,
                )?,
                log.add_channel(
                    pose_topic,
                    &p.name,
                    &p.encoding,
                    &p.data,
                    foxglove::MESSAGE_ENCODING,
                )?,
            )
        }
    })
}

pub(super) fn write_frame(
    log: &mut OutputLog,
    ch: &Outputs,
    world_frame: &str,
    out: &FrameOut,
) -> Result<()> {
    let prior = ch.pose_cov.map_or_else(Matrix6::zeros, |(_, prior)| prior);
    let uncertainty = PoseUncertainty::new(out.est.information.as_ref(), &prior);
    let stats = serde_json::to_vec(&frame_stats(out, &uncertainty)).expect("JSON of plain values");
    let pose = StampedPose {
        stamp: out.cloud.header.stamp,
        child_frame: &out.cloud.header.frame_id,
        world_from_frame: out.est.world_from_frame,
        log_time: out.cloud.log_time,
        publish_time: out.cloud.publish_time,
    };
    write_pose(log, ch, world_frame, &pose, &stats)?;
    if let Some((channel, _)) = ch.pose_cov {
        let header = codec::Header {
            stamp: pose.stamp,
            frame_id: world_frame.to_string(),
        };
        let covariance = uncertainty.ros_covariance();
        let message = match ch.kind {
            CloudKind::Ros1 | CloudKind::LivoxRos1(_) => ros1::encode_pose_with_covariance_stamped(
                &header,
                &pose.world_from_frame,
                &covariance,
            ),
            _ => cdr::encode_pose_with_covariance_stamped(
                &header,
                &pose.world_from_frame,
                &covariance,
            ),
        };
        log.write(channel, pose.log_time, pose.publish_time, &message)?;
    }
    Ok(())
}

/// One frame's pose as our channels carry it.
pub(crate) struct StampedPose<'a> {
    pub(crate) stamp: codec::Time,
    /// The cloud's frame: the child of `/tf`'s transform.
    pub(crate) child_frame: &'a str,
    pub(crate) world_from_frame: nalgebra::Isometry3<f64>,
    pub(crate) log_time: u64,
    pub(crate) publish_time: u64,
}

/// Writes a frame's `/tf`, pose and statistics messages in the channels' family.
pub(super) fn write_pose(
    log: &mut OutputLog,
    ch: &Outputs,
    world_frame: &str,
    p: &StampedPose<'_>,
    stats: &[u8],
) -> Result<()> {
    let (pose, tf) = encode_pose(ch.kind, world_frame, p);
    log.write(ch.tf, p.log_time, p.publish_time, &tf)?;
    log.write(ch.pose, p.log_time, p.publish_time, &pose)?;
    log.write(ch.stats, p.log_time, p.publish_time, stats)
}

/// One frame's optimised pose on loop closure's channels (its `/tf` variant and poses), at the
/// frame's own log time.
pub(super) fn write_optimized_pose(
    log: &mut OutputLog,
    ch: &Outputs,
    loops: &LoopChannels,
    world_frame: &str,
    p: &StampedPose<'_>,
) -> Result<()> {
    let (pose, tf) = encode_pose(ch.kind, world_frame, p);
    log.write(loops.tf, p.log_time, p.publish_time, &tf)?;
    log.write(loops.pose, p.log_time, p.publish_time, &pose)
}

/// One `/mireg/loops` message (JSON, [`loops_json_schema`]).
pub(super) fn write_loop(
    log: &mut OutputLog,
    loops: &LoopChannels,
    log_time: u64,
    publish_time: u64,
    json: &[u8],
) -> Result<()> {
    log.write(loops.loops, log_time, publish_time, json)
}

/// A pose's message and its `/tf` message in `kind`'s family.
pub(crate) fn encode_pose(
    kind: CloudKind,
    world_frame: &str,
    p: &StampedPose<'_>,
) -> (Vec<u8>, Vec<u8>) {
    let world_from_frame = p.world_from_frame;
    let header = codec::Header {
        stamp: p.stamp,
        frame_id: world_frame.to_string(),
    };
    let transforms = [codec::TransformStamped {
        header: header.clone(),
        child_frame_id: p.child_frame.to_string(),
        transform: world_from_frame,
    }];
    match kind {
        CloudKind::Ros2 | CloudKind::LivoxRos2(_) => (
            cdr::encode_pose_stamped(&header, &world_from_frame),
            cdr::encode_tf_message(&transforms),
        ),
        CloudKind::Ros1 | CloudKind::LivoxRos1(_) => (
            ros1::encode_pose_stamped(&header, &world_from_frame),
            ros1::encode_tf_message(&transforms),
        ),
        CloudKind::Foxglove => {
            let stamp = u64::try_from(p.stamp.to_ns()).unwrap_or(0);
            (
                foxglove::encode_pose_in_frame(stamp, world_frame, &world_from_frame),
                foxglove::encode_frame_transforms(&[(
                    stamp,
                    world_frame,
                    p.child_frame,
                    world_from_frame,
                )]),
            )
        }
    }
}

/// How a loop candidate was found: `found_by` of `/mireg/loops` ([`loops_json_schema`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "snake_case")]
pub(super) enum FoundBy {
    /// Odometry positions close, allowing for drift.
    Place,
    /// Descriptors close.
    Appearance,
    /// Both searches.
    Both,
    /// A stitched segment's first frame against the frame before its window (`mireg stitch`).
    Seam,
}

impl FoundBy {
    /// Every value, in the schema's order.
    pub(super) const ALL: [Self; 4] = [Self::Place, Self::Appearance, Self::Both, Self::Seam];
}

impl From<Source> for FoundBy {
    fn from(s: Source) -> Self {
        match s {
            Source::Place => Self::Place,
            Source::Appearance => Self::Appearance,
            Source::Both => Self::Both,
            Source::Seam => Self::Seam,
        }
    }
}

/// What verification decided of a loop candidate: `verdict` of `/mireg/loops`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "snake_case")]
pub(super) enum Verdict {
    /// A loop (in the pose graph, or left out of it when the odometry's map measured it).
    Accepted,
    /// Not a loop; `reason` says why.
    Rejected,
}

impl Verdict {
    /// Every value, in the schema's order.
    pub(super) const ALL: [Self; 2] = [Self::Accepted, Self::Rejected];
}

/// The JSON strings of `values`, as the schema's `enum` lists them.
fn json_names<T: serde::Serialize>(values: &[T]) -> Vec<serde_json::Value> {
    values
        .iter()
        .map(|v| serde_json::to_value(v).expect("a unit variant serialises to a string"))
        .collect()
}

/// A relative pose as the JSON topics (`/mireg/loops`, `/mireg/session_links`) carry it:
/// `{"translation": [x, y, z], "rotation_xyzw": [qx, qy, qz, qw]}` (metres, unit quaternion).
pub(crate) fn relative_pose_json(p: &nalgebra::Isometry3<f64>) -> serde_json::Value {
    let (t, q) = (p.translation.vector, p.rotation.coords);
    json!({"translation": [t.x, t.y, t.z], "rotation_xyzw": [q.x, q.y, q.z, q.w]})
}

/// The JSON schema of [`relative_pose_json`], nullable, with `description`.
pub(crate) fn relative_pose_schema(description: &str) -> serde_json::Value {
    let num = json!({"type": "number"});
    json!({
        "description": description,
        "type": ["object", "null"],
        "properties": {
            "translation": {"type": "array", "items": num, "minItems": 3, "maxItems": 3},
            "rotation_xyzw": {"type": "array", "items": num, "minItems": 4, "maxItems": 4}
        },
        "required": ["translation", "rotation_xyzw"]
    })
}

/// JSON Schema of the `/mireg/loops` messages: one per loop candidate tried.
pub fn loops_json_schema() -> serde_json::Value {
    let num = json!({"type": "number"});
    let int = json!({"type": "integer"});
    let nullable_num = json!({"type": ["number", "null"]});
    json!({
        "$schema": "https://json-schema.org/draft/2020-12/schema",
        "title": "mireg.LoopCandidate",
        "description": "A loop-closure candidate tried by mireg register: the two frames (0-based indices of the run's clouds, header stamps), how it was found, the MI-RANSAC + ICP registration of the query frame against the match frame, the verdict and why, and the loop edge's robust weight in the optimised pose graph",
        "type": "object",
        "properties": {
            "query_frame": int, "match_frame": int, "query_stamp_ns": int, "match_stamp_ns": int,
            "found_by": {"type": "string", "enum": json_names(&FoundBy::ALL)},
            "descriptor_distance": nullable_num, "odometry_distance_m": num, "path_between_m": num,
            "verdict": {"type": "string", "enum": json_names(&Verdict::ALL)},
            "reason": {"type": "string"},
            "match_from_query": relative_pose_schema(
                "The query sensor's pose in the match sensor's frame (p_match = T p_query); null when the registration failed"
            ),
            "inliers": int, "correspondences": int, "fitness": num, "inlier_rmse_m": num,
            "icp_iterations": int,
            "odometry_disagreement_m": nullable_num, "odometry_disagreement_deg": nullable_num,
            "sigma_m": {"description": "An accepted loop's predicted deviation along its least certain translation direction [m]; null otherwise", "type": ["number", "null"]},
            "sigma_deg": {"description": "... and rotation direction [deg]", "type": ["number", "null"]},
            "covariance": {
                "description": "An accepted loop's covariance, ROS order (x, y, z, rotation about x, y, z), row-major; null otherwise",
                "type": ["array", "null"], "items": num, "minItems": 36, "maxItems": 36
            },
            "weight": {"description": "The loop edge's robust weight at the optimum; 0 for a rejected candidate, null for an accepted loop left out of the graph (the odometry's map had measured it)", "type": ["number", "null"]},
            "verify_s": num,
            "timings_s": {"type": ["object", "null"], "additionalProperties": num}
        },
        "required": ["query_frame", "match_frame", "query_stamp_ns", "match_stamp_ns", "found_by",
                     "verdict", "reason", "match_from_query", "inliers", "fitness", "weight"]
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// `found_by` and `verdict` were strings: as enums they must write the same JSON strings,
    /// the ones the schema has always listed, and every search's candidates must map onto one.
    #[test]
    fn loop_record_enums_write_the_strings_the_schema_lists() {
        let schema = loops_json_schema();
        let listed = |field: &str| schema["properties"][field]["enum"].clone();
        assert_eq!(
            listed("found_by"),
            json!(["place", "appearance", "both", "seam"])
        );
        assert_eq!(listed("verdict"), json!(["accepted", "rejected"]));
        let sources = [
            (Source::Place, "place"),
            (Source::Appearance, "appearance"),
            (Source::Both, "both"),
            (Source::Seam, "seam"),
        ];
        for (source, name) in sources {
            assert_eq!(
                serde_json::to_string(&FoundBy::from(source)).unwrap(),
                format!("\"{name}\"")
            );
        }
        assert_eq!(
            serde_json::to_string(&Verdict::Accepted).unwrap(),
            "\"accepted\""
        );
        assert_eq!(
            serde_json::to_string(&Verdict::Rejected).unwrap(),
            "\"rejected\""
        );
    }
}
