//! Foxglove well-known message codecs (protobuf, via the `foxglove` crate's prost types):
//! decode `foxglove.PointCloud`, encode `foxglove.PoseInFrame` and `foxglove.FrameTransforms`,
//! and the schemas an MCAP writer registers for them (schema encoding `protobuf`, a serialized
//! `FileDescriptorSet`; message encoding `protobuf`).
//!
//! Pure byte-level code. Units: metres; timestamps in nanoseconds since the epoch
//! (`foxglove.Timestamp` is unsigned seconds + nanoseconds, so times before 1970 or after 2106
//! cannot be written).
//!
//! Schemas: <https://docs.foxglove.dev/docs/visualization/message-schemas/point-cloud>,
//! `…/pose-in-frame`, `…/frame-transforms`.

use foxglove::Encode;
use foxglove::schemas::packed_element_field::NumericType;
use foxglove::schemas::{
    FrameTransform, FrameTransforms, Pose, PoseInFrame, Quaternion, Timestamp, Vector3,
};
use nalgebra::Isometry3;
use prost::Message;

use super::ros2::{
    DecodeError, Header, PackedField, PackedLayout, PointCloud, Scalar, Time, check_field_fits,
    extract, isometry_from_parts,
};

/// MCAP message encoding of every message in this module.
pub const MESSAGE_ENCODING: &str = "protobuf";

/// A schema to register with an MCAP writer: `name` (e.g. `foxglove.PointCloud`),
/// `encoding` (`protobuf`) and `data` (a serialized protobuf `FileDescriptorSet`).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct SchemaInfo {
    /// Schema name, e.g. `foxglove.PoseInFrame`.
    pub name: String,
    /// Schema encoding (`protobuf`).
    pub encoding: String,
    /// Schema data.
    pub data: Vec<u8>,
}

fn schema_of<T: Encode>() -> SchemaInfo {
    // The foxglove crate returns `Some` for every well-known type.
    let s = T::get_schema().expect("foxglove well-known types carry a schema");
    SchemaInfo {
        name: s.name,
        encoding: s.encoding,
        data: s.data.into_owned(),
    }
}

/// Schema of `foxglove.PointCloud`.
pub fn point_cloud_schema() -> SchemaInfo {
    schema_of::<foxglove::schemas::PointCloud>()
}

/// Schema of `foxglove.PoseInFrame`.
pub fn pose_in_frame_schema() -> SchemaInfo {
    schema_of::<PoseInFrame>()
}

/// Schema of `foxglove.FrameTransforms`.
pub fn frame_transforms_schema() -> SchemaInfo {
    schema_of::<FrameTransforms>()
}

/// A `foxglove.Timestamp` for `ns` nanoseconds since the epoch, saturating at the largest
/// representable time (`u32::MAX` seconds, in 2106).
fn timestamp_from_ns(ns: u64) -> Timestamp {
    const NANOS: u64 = 1_000_000_000;
    match u32::try_from(ns / NANOS) {
        Ok(sec) => Timestamp::new(sec, (ns % NANOS) as u32),
        Err(_) => Timestamp::MAX,
    }
}

fn pose_of(iso: &Isometry3<f64>) -> Pose {
    let t = &iso.translation.vector;
    let q = iso.rotation.quaternion();
    Pose {
        position: Some(Vector3 {
            x: t.x,
            y: t.y,
            z: t.z,
        }),
        orientation: Some(Quaternion {
            x: q.i,
            y: q.j,
            z: q.k,
            w: q.w,
        }),
    }
}

/// Encodes a `foxglove.PoseInFrame`: `pose` (metres, unit quaternion) of a body in `frame_id`
/// at `stamp_ns` nanoseconds since the epoch (saturated at 2106).
pub fn encode_pose_in_frame(stamp_ns: u64, frame_id: &str, pose: &Isometry3<f64>) -> Vec<u8> {
    PoseInFrame {
        timestamp: Some(timestamp_from_ns(stamp_ns)),
        frame_id: frame_id.to_owned(),
        pose: Some(pose_of(pose)),
    }
    .encode_to_vec()
}

/// Encodes a `foxglove.FrameTransforms` from `(stamp_ns, parent_frame_id, child_frame_id,
/// parent_from_child)` tuples: each transform maps points in the child frame into the parent
/// frame (translation = child origin in the parent frame, metres).
pub fn encode_frame_transforms(transforms: &[(u64, &str, &str, Isometry3<f64>)]) -> Vec<u8> {
    FrameTransforms {
        transforms: transforms
            .iter()
            .map(|(stamp_ns, parent, child, iso)| {
                let Pose {
                    position,
                    orientation,
                } = pose_of(iso);
                FrameTransform {
                    timestamp: Some(timestamp_from_ns(*stamp_ns)),
                    parent_frame_id: (*parent).to_owned(),
                    child_frame_id: (*child).to_owned(),
                    translation: position,
                    rotation: orientation,
                }
            })
            .collect(),
    }
    .encode_to_vec()
}

/// Decodes a protobuf `foxglove.PointCloud` into the same [`PointCloud`] as the ROS decoder.
///
/// - `header.frame_id` is the message's `frame_id`; `header.stamp` its `timestamp`
///   (normalised; 0 if absent).
/// - Coordinates come from the `fields` named `x`, `y`, `z` (any `NumericType`, little-endian
///   as the schema specifies), `intensity` is optional. As in Foxglove, one of x/y/z may be
///   missing (read as 0); at least two are required.
/// - Points are stored in the frame given by `pose` relative to `frame_id`; the result is
///   expressed in `frame_id`: `p' = pose · p` (an absent pose, position or orientation is the
///   identity).
/// - The message has no rows: `height` is 1 and `width` = `data.len() / point_stride`.
/// - Non-finite points are dropped and counted.
///
/// # Errors
/// [`DecodeError`] for invalid protobuf (`PointCloud`), fewer than two coordinate fields
/// (`fields`), an unknown numeric type (`fields[i].type`), a field beyond `point_stride`
/// (`fields[i]`), a zero `point_stride` or data that is not a whole number of points (`data`),
/// a non-finite or non-unit pose (`pose.position`, `pose.orientation`), or a timestamp whose
/// seconds exceed `i32` (`timestamp`).
pub fn decode_foxglove_point_cloud(payload: &[u8]) -> Result<PointCloud, DecodeError> {
    let msg = foxglove::schemas::PointCloud::decode(payload)
        .map_err(|e| DecodeError::new("PointCloud", format!("invalid protobuf: {e}")))?;

    let stamp = match msg.timestamp {
        None => Time::default(),
        Some(ts) => {
            let ts = ts
                .normalize()
                .ok_or_else(|| DecodeError::new("timestamp", "nanoseconds overflow the seconds"))?;
            let sec = i32::try_from(ts.sec()).map_err(|_| {
                DecodeError::new(
                    "timestamp.sec",
                    format!("{} s does not fit builtin_interfaces/Time (i32)", ts.sec()),
                )
            })?;
            Time {
                sec,
                nanosec: ts.nsec(),
            }
        }
    };
    let header = Header {
        stamp,
        frame_id: msg.frame_id,
    };

    let data = &msg.data[..];
    if data.is_empty() {
        return Ok(PointCloud {
            header,
            points: Vec::new(),
            intensity: None,
            width: 0,
            height: 1,
            num_dropped_non_finite: 0,
        });
    }
    let stride = u64::from(msg.point_stride);
    let find = |name: &str| -> Result<Option<PackedField>, DecodeError> {
        let Some(i) = msg.fields.iter().position(|f| f.name == name) else {
            return Ok(None);
        };
        let f = &msg.fields[i];
        let kind = match NumericType::try_from(f.r#type) {
            Ok(NumericType::Uint8) => Scalar::U8,
            Ok(NumericType::Int8) => Scalar::I8,
            Ok(NumericType::Uint16) => Scalar::U16,
            Ok(NumericType::Int16) => Scalar::I16,
            Ok(NumericType::Uint32) => Scalar::U32,
            Ok(NumericType::Int32) => Scalar::I32,
            Ok(NumericType::Float32) => Scalar::F32,
            Ok(NumericType::Float64) => Scalar::F64,
            Ok(NumericType::Unknown) | Err(_) => {
                return Err(DecodeError::new(
                    format!("fields[{i}].type"),
                    format!(
                        "unknown numeric type {} for field '{name}' (expected 1..=8, \
                         UINT8..FLOAT64)",
                        f.r#type
                    ),
                ));
            }
        };
        check_field_fits(
            &format!("fields[{i}]"),
            u64::from(f.offset),
            kind,
            1,
            stride,
        )
        .map(Some)
    };
    let xyz = [find("x")?, find("y")?, find("z")?];
    let intensity = find("intensity")?;

    if xyz.iter().filter(|f| f.is_some()).count() < 2 {
        let names: Vec<&str> = msg.fields.iter().map(|f| f.name.as_str()).collect();
        return Err(DecodeError::new(
            "fields",
            format!("need at least two of the fields x, y, z (fields: {names:?})"),
        ));
    }
    let stride = msg.point_stride as usize;
    if stride == 0 || !data.len().is_multiple_of(stride) {
        return Err(DecodeError::new(
            "data",
            format!(
                "{} bytes is not a whole number of points of point_stride {stride}",
                data.len()
            ),
        ));
    }
    let n = data.len() / stride;
    let width = u32::try_from(n).map_err(|_| {
        DecodeError::new(
            "data",
            format!("{n} points exceed the u32 width of a cloud"),
        )
    })?;

    let pose = match &msg.pose {
        None => Isometry3::identity(),
        Some(p) => {
            let t = p.position.as_ref().map_or([0.0; 3], |v| [v.x, v.y, v.z]);
            if t.iter().any(|c| !c.is_finite()) {
                return Err(DecodeError::new(
                    "pose.position",
                    format!("non-finite position {t:?}"),
                ));
            }
            let q = p
                .orientation
                .as_ref()
                .map_or([0.0, 0.0, 0.0, 1.0], |q| [q.x, q.y, q.z, q.w]);
            isometry_from_parts(t, q, "pose.orientation")?
        }
    };

    let layout = PackedLayout {
        xyz,
        intensity,
        big_endian: false,
    };
    let mut ex = extract(data, &layout, 1, n, 0, stride);
    if pose != Isometry3::identity() {
        for p in &mut ex.points {
            *p = pose * *p;
        }
    }
    Ok(PointCloud {
        header,
        points: ex.points,
        intensity: ex.intensity,
        width,
        height: 1,
        num_dropped_non_finite: ex.num_dropped_non_finite,
    })
}
