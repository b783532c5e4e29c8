//! Trajectories read from files: the poses of an MCAP's `geometry_msgs/PoseStamped` topics
//! (ROS 2 in CDR or ROS 1) and the per-frame flags of `mireg register`'s statistics, and TUM,
//! KITTI and Redwood `.log` files, parsed by [`crate::trajectory`].

use std::collections::HashMap;
use std::path::Path;

use mcap::records::Record;
use nalgebra::Isometry3;

use crate::io::codec::{PoseStampedDecoder, cdr, pose_stamped_decoder, ros1};
use crate::io::mcap::log::{ChannelInfo, for_each_record, list_channels};
use crate::io::{format_err, pose_file, read_text};
use crate::trajectory::{FrameFlag, Trajectory, parse_kitti, parse_tum};
use crate::{Error, Result};

/// Reads a TUM trajectory file (see [`parse_tum`]).
///
/// # Errors
/// [`Error::Io`] if the file cannot be read, else as [`parse_tum`].
pub fn read_tum(path: &Path) -> Result<Trajectory> {
    parse_tum(&read_text(path)?, path)
}

/// Reads a KITTI pose file (see [`parse_kitti`]).
///
/// # Errors
/// [`Error::Io`] if the file cannot be read, else as [`parse_kitti`].
pub fn read_kitti(path: &Path) -> Result<Trajectory> {
    parse_kitti(&read_text(path)?, path)
}

// ---------------------------------------------------------------------------------------------
// Redwood
// ---------------------------------------------------------------------------------------------

/// Reads a Redwood/ICL-NUIM `trajectory.log` (records `k k k+1` + `world_from_camera_k`, see
/// [`pose_file::parse_log`]) as an unstamped trajectory in record order.
///
/// # Errors
/// As [`pose_file::read_log`].
pub fn read_redwood(path: &Path) -> Result<Trajectory> {
    let records = pose_file::read_log(path)?;
    Ok(Trajectory::unstamped(
        records.into_iter().map(|r| r.pose).collect(),
    ))
}

// ---------------------------------------------------------------------------------------------
// MCAP
// ---------------------------------------------------------------------------------------------

/// Topics of `channels` that carry `geometry_msgs/PoseStamped` (ROS 2 in CDR or ROS 1).
pub fn pose_stamped_topics(channels: &[ChannelInfo]) -> Vec<String> {
    let mut t: Vec<String> = channels
        .iter()
        .filter(|c| pose_stamped_decoder(&c.schema_name, &c.message_encoding).is_some())
        .map(|c| c.topic.clone())
        .collect();
    t.dedup();
    t
}

fn pose_topic_error(path: &Path, channels: &[ChannelInfo], detail: String) -> Error {
    let topics = pose_stamped_topics(channels);
    Error::InvalidInput(format!(
        "{}: {detail}; PoseStamped topics in this log: {}",
        path.display(),
        if topics.is_empty() {
            "none".to_string()
        } else {
            topics.join(", ")
        }
    ))
}

/// Checks that `topic` exists in `channels` and carries `geometry_msgs/PoseStamped` (ROS 2 in CDR
/// or ROS 1), and returns its decoder.
///
/// # Errors
/// [`Error::InvalidInput`] naming the file and topic and listing the PoseStamped topics.
pub fn check_pose_topic(
    path: &Path,
    channels: &[ChannelInfo],
    topic: &str,
) -> Result<PoseStampedDecoder> {
    let matching: Vec<&ChannelInfo> = channels.iter().filter(|c| c.topic == topic).collect();
    if matching.is_empty() {
        return Err(pose_topic_error(
            path,
            channels,
            format!("no topic {topic:?}"),
        ));
    }
    let decoders: Vec<Option<PoseStampedDecoder>> = matching
        .iter()
        .map(|c| pose_stamped_decoder(&c.schema_name, &c.message_encoding))
        .collect();
    if let Some(k) = decoders.iter().position(|d| d.is_none()) {
        let c = matching[k];
        return Err(pose_topic_error(
            path,
            channels,
            format!(
                "topic {topic:?} carries {} ({}), not {} (cdr) or {} (ros1)",
                c.schema_name,
                c.message_encoding,
                cdr::POSE_STAMPED_SCHEMA_NAME,
                ros1::POSE_STAMPED_SCHEMA_NAME
            ),
        ));
    }
    let first = decoders[0].expect("checked");
    if matching
        .iter()
        .any(|c| c.message_encoding != matching[0].message_encoding)
    {
        return Err(pose_topic_error(
            path,
            channels,
            format!("topic {topic:?} mixes ROS 1 and ROS 2 channels"),
        ));
    }
    Ok(first)
}

/// Calls `f(topic index, log time \[ns\], payload)` for every message on one of `topics`, in file
/// order, in one pass (once per index when a topic is listed twice).
fn for_each_message_on(
    path: &Path,
    topics: &[&str],
    mut f: impl FnMut(usize, u64, &[u8]) -> Result<()>,
) -> Result<()> {
    let mut channel_topics: HashMap<u16, Vec<usize>> = HashMap::new();
    for_each_record(path, |record| {
        match record {
            Record::Channel(c) => {
                let ks: Vec<usize> = (0..topics.len())
                    .filter(|&k| topics[k] == c.topic)
                    .collect();
                if !ks.is_empty() {
                    channel_topics.insert(c.id, ks);
                }
            }
            Record::Message { header, data } => {
                for &k in channel_topics.get(&header.channel_id).into_iter().flatten() {
                    f(k, header.log_time, &data)?;
                }
            }
            _ => {}
        }
        Ok(())
    })
}

/// Reads several `geometry_msgs/msg/PoseStamped` topics of an MCAP in one pass; each
/// trajectory is stamped with the messages' header stamps and sorted by stamp (stable).
///
/// # Errors
/// [`Error::InvalidInput`] for a missing topic or one of another type (naming the file and
/// listing the PoseStamped topics), [`Error::Format`] for an undecodable message (naming file,
/// topic and log time) or an unreadable MCAP.
pub fn read_mcap_pose_topics(path: &Path, topics: &[&str]) -> Result<Vec<Trajectory>> {
    let channels = list_channels(path)?;
    let decoders = topics
        .iter()
        .map(|t| check_pose_topic(path, &channels, t))
        .collect::<Result<Vec<_>>>()?;
    let mut out: Vec<Vec<(i64, Isometry3<f64>)>> = vec![Vec::new(); topics.len()];
    for_each_message_on(path, topics, |k, log_time, data| {
        let (header, pose) = decoders[k](data).map_err(|e| {
            format_err(
                path,
                format!(
                    "message on {} at log time {log_time} ns: field {}: {}",
                    topics[k], e.field, e.detail
                ),
            )
        })?;
        out[k].push((header.stamp.to_ns(), pose));
        Ok(())
    })?;
    Ok(out
        .into_iter()
        .map(|mut v| {
            v.sort_by_key(|(s, _)| *s);
            let (stamps, poses) = v.into_iter().unzip();
            Trajectory::stamped(stamps, poses)
        })
        .collect())
}

/// Reads one PoseStamped topic (see [`read_mcap_pose_topics`]).
///
/// # Errors
/// As [`read_mcap_pose_topics`].
pub fn read_mcap_pose_topic(path: &Path, topic: &str) -> Result<Trajectory> {
    let mut v = read_mcap_pose_topics(path, &[topic])?;
    Ok(v.pop().unwrap_or_default())
}

/// Reads the per-frame flags of `mireg register`'s statistics topic; `Ok(None)` when the log
/// has no such topic (e.g. a log not written by `mireg register`).
///
/// # Errors
/// [`Error::Format`] naming file, topic and log time for a message that is not the expected
/// JSON, or an unreadable MCAP.
pub fn read_frame_flags(path: &Path, topic: &str) -> Result<Option<Vec<FrameFlag>>> {
    let channels = list_channels(path)?;
    if !channels.iter().any(|c| c.topic == topic) {
        return Ok(None);
    }
    let mut flags = Vec::new();
    for_each_message_on(path, &[topic], |_, log_time, data| {
        let f: FrameFlag = serde_json::from_slice(data).map_err(|e| {
            format_err(
                path,
                format!("message on {topic} at log time {log_time} ns: {e}"),
            )
        })?;
        flags.push(f);
        Ok(())
    })?;
    flags.sort_by_key(|f| f.frame);
    Ok(Some(flags))
}
