//! Which clouds `register` reads: the message kinds, the choice of the cloud topic, and what to
//! tell a user whose log carries another kind of point message.

use std::path::Path;

use crate::io::codec::livox::{self, LivoxTags};
use crate::io::codec::{self, cdr, foxglove, ros1};
use crate::io::mcap::log::ChannelInfo;
use crate::{Error, Result};

/// The point cloud message types `register` reads.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum CloudKind {
    /// ROS 2 `sensor_msgs/msg/PointCloud2`, cdr.
    Ros2,
    /// ROS 1 `sensor_msgs/PointCloud2`, ros1.
    Ros1,
    /// `foxglove.PointCloud`, protobuf (its `pose` applied).
    Foxglove,
    /// Livox `CustomMsg` (`livox_ros_driver2/msg/CustomMsg`), cdr, with its points kept by tag.
    LivoxRos2(LivoxTags),
    /// Livox `CustomMsg` (`livox_ros_driver/CustomMsg`), ros1, with its points kept by tag.
    LivoxRos1(LivoxTags),
}

const FOXGLOVE_POINT_CLOUD: &str = "foxglove.PointCloud";

pub(super) fn cloud_kind(c: &ChannelInfo) -> Option<CloudKind> {
    if c.schema_name == cdr::POINT_CLOUD2_SCHEMA_NAME && c.message_encoding == cdr::MESSAGE_ENCODING
    {
        Some(CloudKind::Ros2)
    } else if c.schema_name == ros1::POINT_CLOUD2_SCHEMA_NAME
        && c.message_encoding == ros1::MESSAGE_ENCODING
    {
        Some(CloudKind::Ros1)
    } else if c.schema_name == FOXGLOVE_POINT_CLOUD
        && c.message_encoding == foxglove::MESSAGE_ENCODING
    {
        Some(CloudKind::Foxglove)
    } else if livox::is_custom_msg(&c.schema_name) && c.message_encoding == cdr::MESSAGE_ENCODING {
        Some(CloudKind::LivoxRos2(LivoxTags::default()))
    } else if livox::is_custom_msg(&c.schema_name) && c.message_encoding == ros1::MESSAGE_ENCODING {
        Some(CloudKind::LivoxRos1(LivoxTags::default()))
    } else {
        None
    }
}

impl CloudKind {
    /// The MCAP profile of a log whose clouds are of this kind (and so of ours).
    pub(super) fn profile(self) -> &'static str {
        match self.family() {
            CloudKind::Ros1 => "ros1",
            _ => "ros2",
        }
    }

    /// The message family of our outputs for clouds of this kind: Livox clouds are ROS clouds.
    pub(super) fn family(self) -> CloudKind {
        match self {
            CloudKind::LivoxRos2(_) => CloudKind::Ros2,
            CloudKind::LivoxRos1(_) => CloudKind::Ros1,
            other => other,
        }
    }

    /// This kind with Livox points kept by `tags` (no change for other kinds).
    pub(super) fn with_livox_tags(self, tags: LivoxTags) -> CloudKind {
        match self {
            CloudKind::LivoxRos2(_) => CloudKind::LivoxRos2(tags),
            CloudKind::LivoxRos1(_) => CloudKind::LivoxRos1(tags),
            other => other,
        }
    }

    pub(super) fn decode(
        self,
        payload: &[u8],
    ) -> std::result::Result<codec::PointCloud, codec::DecodeError> {
        self.decode_reusing(payload, Vec::new())
    }

    /// The header and the points a cloud message declares, read before decoding it (and before
    /// allocating for its points): `height · width` of a PointCloud2, the data's length over
    /// `point_stride` of a foxglove.PointCloud, the points sequence's count of a Livox
    /// `CustomMsg`; `None` when the message is too short or malformed to say.
    pub(super) fn declared_points(self, payload: &[u8]) -> Option<(codec::Header, u64)> {
        match self {
            CloudKind::Ros2 => cdr::point_cloud2_declared_points(payload),
            CloudKind::Ros1 => ros1::point_cloud2_declared_points(payload),
            CloudKind::Foxglove => foxglove::point_cloud_declared_points(payload),
            CloudKind::LivoxRos2(_) => livox::declared_points_cdr(payload),
            CloudKind::LivoxRos1(_) => livox::declared_points_ros1(payload),
        }
    }

    /// [`Self::decode`] writing the points into `points` (cleared first: the previous cloud's
    /// buffer, reused).
    pub(super) fn decode_reusing(
        self,
        payload: &[u8],
        points: Vec<nalgebra::Point3<f64>>,
    ) -> std::result::Result<codec::PointCloud, codec::DecodeError> {
        match self {
            CloudKind::Ros2 => cdr::decode_point_cloud2_reusing(payload, points),
            CloudKind::Ros1 => ros1::decode_point_cloud2_reusing(payload, points),
            CloudKind::Foxglove => foxglove::decode_foxglove_point_cloud_reusing(payload, points),
            CloudKind::LivoxRos2(tags) => livox::decode_cdr_reusing(payload, points, tags),
            CloudKind::LivoxRos1(tags) => livox::decode_ros1_reusing(payload, points, tags),
        }
    }
}

/// The cloud messages `register` reads, for error messages.
const CLOUD_TYPES: &str = "sensor_msgs/PointCloud2 or livox_ros_driver(2)/CustomMsg in ros1 or cdr, or foxglove.PointCloud in protobuf";

/// How to turn a point message mireg does not read into one it does, for the types users meet.
fn conversion_hint(schema_name: &str) -> Option<&'static str> {
    let name = schema_name.replace("/msg/", "/");
    Some(match name.as_str() {
        "sensor_msgs/PointCloud" => {
            "the old sensor_msgs/PointCloud is not supported; convert it to PointCloud2 (ROS 1 point_cloud_converter, or sensor_msgs::convertPointCloudToPointCloud2)"
        }
        "velodyne_msgs/VelodyneScan" => {
            "these are raw Velodyne packets; turn them into PointCloud2 with velodyne_pointcloud (its transform or cloud node) while replaying the log, and record that"
        }
        "ouster_ros/PacketMsg" | "ouster_sensor_msgs/PacketMsg" => {
            "these are raw Ouster packets; turn them into PointCloud2 with ouster_ros's os_cloud node while replaying the log, and record that"
        }
        "sensor_msgs/LaserScan" => "2-D laser scans are not supported",
        _ => return None,
    })
}

/// The point cloud topic `register` reads from `channels` of `path`: `requested` if it carries
/// clouds, else the only cloud topic.
///
/// # Errors
/// [`Error::InvalidInput`] as `register` reports it: no cloud topic, several, or `requested`
/// missing or not a cloud.
pub fn point_cloud_topic(
    path: &Path,
    channels: &[ChannelInfo],
    requested: Option<&str>,
) -> Result<String> {
    choose_topic(path, channels, requested).map(|(t, _)| t)
}

/// Picks the point cloud channel: the one named `requested`, or the only cloud topic.
pub(super) fn choose_topic(
    path: &Path,
    channels: &[ChannelInfo],
    requested: Option<&str>,
) -> Result<(String, CloudKind)> {
    let clouds: Vec<&ChannelInfo> = channels
        .iter()
        .filter(|c| cloud_kind(c).is_some())
        .collect();
    if let Some(topic) = requested {
        let c = channels.iter().find(|c| c.topic == topic).ok_or_else(|| {
            Error::InvalidInput(format!(
                "{}: no topic {topic:?} (topics: {})",
                path.display(),
                channels
                    .iter()
                    .map(|c| c.topic.as_str())
                    .collect::<Vec<_>>()
                    .join(", ")
            ))
        })?;
        let kind = cloud_kind(c).ok_or_else(|| {
            Error::InvalidInput(format!(
                "{}: topic {topic:?} carries {} ({}), not a point cloud mireg reads ({CLOUD_TYPES}){}",
                path.display(),
                c.schema_name,
                c.message_encoding,
                conversion_hint(&c.schema_name)
                    .map(|h| format!("; {h}"))
                    .unwrap_or_default()
            ))
        })?;
        return Ok((topic.to_string(), kind));
    }
    match clouds.as_slice() {
        [] => Err(Error::InvalidInput(format!(
            "{}: no point cloud topic ({CLOUD_TYPES}); topics: {}{}",
            path.display(),
            channels
                .iter()
                .map(|c| format!("{} [{}]", c.topic, c.schema_name))
                .collect::<Vec<_>>()
                .join(", "),
            channels
                .iter()
                .find_map(|c| conversion_hint(&c.schema_name)
                    .map(|h| format!("; topic {:?}: {h}", c.topic)))
                .unwrap_or_default()
        ))),
        // Several channels on one topic (e.g. two recorder sessions) are one stream.
        [first, rest @ ..]
            if rest
                .iter()
                .all(|c| c.topic == first.topic && cloud_kind(c) == cloud_kind(first)) =>
        {
            Ok((first.topic.clone(), cloud_kind(first).expect("filtered")))
        }
        many => {
            let topics: std::collections::BTreeSet<&str> =
                many.iter().map(|c| c.topic.as_str()).collect();
            let detail = if topics.len() == 1 {
                format!(
                    "topic {:?} has channels of different point cloud types; mireg registers one type per run",
                    many[0].topic
                )
            } else {
                format!(
                    "several point cloud topics, choose one with --topic: {}",
                    topics.into_iter().collect::<Vec<_>>().join(", ")
                )
            };
            Err(Error::InvalidInput(format!("{}: {detail}", path.display())))
        }
    }
}

/// Calls `f(log time [ns], cloud)` for every cloud on the point cloud topic of `input` (any
/// container; `topic` as `register --topic`), in file order, until `f` breaks; a cloud that does
/// not decode is skipped. Returns the topic.
///
/// # Errors
/// As `register` for the input and the topic choice; `f`'s errors.
pub fn for_each_cloud(
    input: &Path,
    topic: Option<&str>,
    f: impl FnMut(u64, codec::PointCloud) -> Result<std::ops::ControlFlow<()>>,
) -> Result<String> {
    for_each_cloud_where(input, topic, |_| true, f)
}

/// [`for_each_cloud`] over the clouds whose log time \[ns\] `wanted` accepts: the others are
/// not decoded (a reader that wants a few keyframes of a long log pays for those only).
///
/// # Errors
/// As [`for_each_cloud`].
pub fn for_each_cloud_where(
    input: &Path,
    topic: Option<&str>,
    wanted: impl Fn(u64) -> bool,
    mut f: impl FnMut(u64, codec::PointCloud) -> Result<std::ops::ControlFlow<()>>,
) -> Result<String> {
    let (log, catalog) = crate::io::input_log::InputLog::open(input)?;
    let channels = catalog.channel_infos();
    let (topic, kind) = choose_topic(input, &channels, topic)?;
    let ids: Vec<u16> = channels
        .iter()
        .filter(|c| c.topic == topic)
        .map(|c| c.id)
        .collect();
    log.for_each_message_until(|h, data| {
        if ids.contains(&h.channel_id)
            && wanted(h.log_time)
            && let Ok(cloud) = kind.decode(data)
        {
            return f(h.log_time, cloud);
        }
        Ok(std::ops::ControlFlow::Continue(()))
    })?;
    Ok(topic)
}
