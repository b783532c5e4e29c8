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
use nalgebra::{Isometry3, Point3};
use prost::Message;

use super::packed::{PackedField, PackedLayout, check_field_fits, extract};
use super::{DecodeError, Header, PointCloud, Time, isometry_from_parts};
use crate::io::scalar::Scalar;

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
    decode_foxglove_point_cloud_reusing(payload, Vec::new())
}

/// [`decode_foxglove_point_cloud`] writing the points into `points` (cleared first), as
/// [`super::cdr::decode_point_cloud2_reusing`].
pub fn decode_foxglove_point_cloud_reusing(
    payload: &[u8],
    points: Vec<Point3<f64>>,
) -> Result<PointCloud, DecodeError> {
    let msg = foxglove::schemas::PointCloud::decode(payload)
        .map_err(|e| DecodeError::new("PointCloud", format!("invalid protobuf: {e}")))?;
    let header = header_of(msg.timestamp, msg.frame_id.clone())?;
    let data = &msg.data[..];
    if data.is_empty() {
        return Ok(cloud_of(header, Default::default(), 0));
    }
    let (xyz, intensity) = coordinate_fields(&msg)?;
    let (n, width) = point_count(data.len(), msg.point_stride)?;
    let pose = cloud_pose(msg.pose.as_ref())?;
    let layout = PackedLayout {
        xyz,
        intensity,
        time: None,
        big_endian: false,
    };
    let stride = msg.point_stride as usize;
    let mut ex = extract(data, &layout, 1, n, 0, stride, points);
    if pose != Isometry3::identity() {
        for p in &mut ex.points {
            *p = pose * *p;
        }
    }
    Ok(cloud_of(header, ex, width))
}

/// The cloud of `header` with the points `ex` extracted from a message of `width` points.
fn cloud_of(header: Header, ex: super::packed::Extracted, width: u32) -> PointCloud {
    PointCloud {
        header,
        points: ex.points,
        intensity: ex.intensity,
        times: None,
        width,
        height: 1,
        num_dropped_non_finite: ex.num_dropped_non_finite,
        num_dropped_far: ex.num_dropped_far,
        num_dropped_zero: ex.num_dropped_zero,
        num_dropped_tag: 0,
        num_dropped_time: 0,
    }
}

/// The cloud's header: `frame_id` and the `timestamp` (normalised; 0 if absent).
fn header_of(timestamp: Option<Timestamp>, frame_id: String) -> Result<Header, DecodeError> {
    let stamp = match timestamp {
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
    Ok(Header { stamp, frame_id })
}

/// The fields `x`, `y`, `z` (at least two) and `intensity` of `msg`, each checked to fit in
/// `point_stride`.
fn coordinate_fields(
    msg: &foxglove::schemas::PointCloud,
) -> Result<([Option<PackedField>; 3], Option<PackedField>), DecodeError> {
    let stride = u64::from(msg.point_stride);
    let find = |name: &str| -> Result<Option<PackedField>, DecodeError> {
        let Some(i) = msg.fields.iter().position(|f| f.name == name) else {
            return Ok(None);
        };
        let f = &msg.fields[i];
        let kind = scalar_of(f.r#type).ok_or_else(|| {
            DecodeError::new(
                format!("fields[{i}].type"),
                format!(
                    "unknown numeric type {} for field '{name}' (expected 1..=8, \
                     UINT8..FLOAT64)",
                    f.r#type
                ),
            )
        })?;
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
    Ok((xyz, intensity))
}

/// The scalar of a `foxglove.NumericType` value; `None` for an unknown one.
fn scalar_of(numeric_type: i32) -> Option<Scalar> {
    Some(match NumericType::try_from(numeric_type) {
        Ok(NumericType::Uint8) => Scalar::U8,
        Ok(NumericType::Int8) => Scalar::I8,
        Ok(NumericType::Uint16) => Scalar::U16,
        Ok(NumericType::Int16) => Scalar::I16,
        Ok(NumericType::Uint32) => Scalar::U32,
        Ok(NumericType::Int32) => Scalar::I32,
        Ok(NumericType::Float32) => Scalar::F32,
        Ok(NumericType::Float64) => Scalar::F64,
        Ok(NumericType::Unknown) | Err(_) => return None,
    })
}

/// The number of points in `data_len` bytes of `point_stride` each, and as the cloud's width.
fn point_count(data_len: usize, point_stride: u32) -> Result<(usize, u32), DecodeError> {
    let stride = point_stride as usize;
    if stride == 0 || !data_len.is_multiple_of(stride) {
        return Err(DecodeError::new(
            "data",
            format!("{data_len} bytes is not a whole number of points of point_stride {stride}"),
        ));
    }
    let n = data_len / stride;
    let width = u32::try_from(n).map_err(|_| {
        DecodeError::new(
            "data",
            format!("{n} points exceed the u32 width of a cloud"),
        )
    })?;
    Ok((n, width))
}

/// The cloud's `pose` in its frame (identity when absent; an absent position or orientation is
/// zero or the identity rotation).
fn cloud_pose(pose: Option<&Pose>) -> Result<Isometry3<f64>, DecodeError> {
    let Some(p) = pose else {
        return Ok(Isometry3::identity());
    };
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
    isometry_from_parts(t, q, "pose.orientation")
}

/// The fields of a `foxglove.PointCloud` that say what it holds, decoded without its `data`,
/// `fields` and `pose` (which prost skips as unknown fields, allocating nothing).
#[derive(Clone, PartialEq, prost::Message)]
struct PointCloudHead {
    #[prost(message, optional, tag = "1")]
    timestamp: Option<Timestamp>,
    #[prost(string, tag = "2")]
    frame_id: String,
    #[prost(fixed32, tag = "4")]
    point_stride: u32,
}

/// The header of a `foxglove.PointCloud` and the points its `data` declares (its length over
/// `point_stride`), read without decoding or copying the data: what a cloud would take is known
/// before it is decoded, as [`super::cdr::point_cloud2_declared_points`] for PointCloud2.
/// `None` when the message does not say (invalid protobuf, no data, a zero `point_stride`).
pub fn point_cloud_declared_points(payload: &[u8]) -> Option<(Header, u64)> {
    let head = PointCloudHead::decode(payload).ok()?;
    let data_len = last_length_delimited(payload, 6)?;
    if head.point_stride == 0 {
        return None;
    }
    let header = header_of(head.timestamp, head.frame_id).ok()?;
    Some((header, data_len / u64::from(head.point_stride)))
}

/// The length of the last top-level length-delimited field `tag` of a protobuf message (as
/// protobuf reads a repeated scalar field: the last one wins), the other fields skipped as prost
/// skips them (groups included); `None` if absent or malformed.
fn last_length_delimited(mut b: &[u8], tag: u32) -> Option<u64> {
    use prost::encoding::{DecodeContext, WireType, decode_key, decode_varint, skip_field};
    let mut found = None;
    while !b.is_empty() {
        let (key, wire_type) = decode_key(&mut b).ok()?;
        if key == tag && wire_type == WireType::LengthDelimited {
            let len = decode_varint(&mut b).ok()?;
            b = b.get(usize::try_from(len).ok()?..)?;
            found = Some(len);
        } else {
            skip_field(wire_type, key, &mut b, DecodeContext::default()).ok()?;
        }
    }
    found
}

#[cfg(test)]
mod tests {
    use super::*;
    use foxglove::schemas::PackedElementField;
    use nalgebra::{Point3, Translation3, UnitQuaternion, Vector3 as V3};
    use rand::{RngExt, SeedableRng};
    use rand_pcg::Pcg64;

    fn field(name: &str, offset: u32, t: NumericType) -> PackedElementField {
        PackedElementField {
            name: name.into(),
            offset,
            r#type: t as i32,
        }
    }

    /// A cloud of FLOAT32 x, y, z + UINT16 intensity at offsets 0, 4, 8, 12, stride 16.
    fn cloud(points: &[[f32; 3]], pose: Option<Pose>) -> foxglove::schemas::PointCloud {
        let mut data = Vec::new();
        for (k, q) in points.iter().enumerate() {
            for c in q {
                data.extend(c.to_le_bytes());
            }
            data.extend((100 + k as u16).to_le_bytes());
            data.extend([0xEE, 0xEE]);
        }
        foxglove::schemas::PointCloud {
            timestamp: Some(Timestamp::new(1_700_000_000, 5)),
            frame_id: "lidar".into(),
            pose,
            point_stride: 16,
            fields: vec![
                field("x", 0, NumericType::Float32),
                field("y", 4, NumericType::Float32),
                field("z", 8, NumericType::Float32),
                field("intensity", 12, NumericType::Uint16),
            ],
            data: data.into(),
        }
    }

    /// The count read before decoding is the decoded width, with the same header, whatever
    /// else the message holds (a pose, fields after the data); an empty or strideless message
    /// declares nothing.
    #[test]
    fn declared_points_are_the_decoded_width() {
        let pose = Pose {
            position: Some(Vector3 {
                x: 1.0,
                y: 2.0,
                z: 3.0,
            }),
            orientation: None,
        };
        let pts = [[1.0f32, 2.0, 3.0], [4.0, 5.0, 6.0], [f32::NAN, 0.0, 1.0]];
        for msg in [cloud(&pts, None), cloud(&pts, Some(pose))] {
            let bytes = msg.encode_to_vec();
            let decoded = decode_foxglove_point_cloud(&bytes).unwrap();
            let (header, n) = point_cloud_declared_points(&bytes).unwrap();
            assert_eq!((header, n), (decoded.header, u64::from(decoded.width)));
            assert_eq!(n, 3);
        }
        // A group before the data (fuzz/regressions/foxglove_point_cloud): skipped as prost
        // skips it.
        let mut grouped = vec![0x5b, 0x08, 0x0a, 0x5c];
        grouped.extend(cloud(&pts, None).encode_to_vec());
        let decoded = decode_foxglove_point_cloud(&grouped).unwrap();
        assert_eq!(
            point_cloud_declared_points(&grouped).map(|d| d.1),
            Some(u64::from(decoded.width))
        );
        let mut none = cloud(&[], None);
        none.point_stride = 0;
        assert_eq!(point_cloud_declared_points(&none.encode_to_vec()), None);
        assert_eq!(point_cloud_declared_points(&[0xff, 0xff]), None);
    }

    #[test]
    fn point_cloud_identity_pose_and_fields() {
        let pts = [[1.0, 2.0, 3.0], [f32::NAN, 0.0, 0.0], [-4.5, 0.25, 8.0]];
        let c = decode_foxglove_point_cloud(&cloud(&pts, None).encode_to_vec()).unwrap();
        assert_eq!(c.header.frame_id, "lidar");
        assert_eq!(
            c.header.stamp,
            Time {
                sec: 1_700_000_000,
                nanosec: 5
            }
        );
        assert_eq!(
            c.points,
            vec![Point3::new(1.0, 2.0, 3.0), Point3::new(-4.5, 0.25, 8.0)]
        );
        assert_eq!(c.intensity, Some(vec![100.0, 102.0]));
        assert_eq!(c.num_dropped_non_finite, 1);
        assert_eq!((c.width, c.height), (3, 1));
    }

    #[test]
    fn point_cloud_pose_is_applied() {
        // Pose: translate (10, 0, -1), rotate 90° about z. (1, 0, 0) → (10, 1, -1);
        // (0, 2, 0) → (8, 0, -1); computed by hand from the rotation (x, y) → (−y, x).
        let s = std::f64::consts::FRAC_1_SQRT_2;
        let pose = Pose {
            position: Some(Vector3 {
                x: 10.0,
                y: 0.0,
                z: -1.0,
            }),
            orientation: Some(Quaternion {
                x: 0.0,
                y: 0.0,
                z: s,
                w: s,
            }),
        };
        let msg = cloud(&[[1.0, 0.0, 0.0], [0.0, 2.0, 0.0]], Some(pose));
        let c = decode_foxglove_point_cloud(&msg.encode_to_vec()).unwrap();
        let want = [Point3::new(10.0, 1.0, -1.0), Point3::new(8.0, 0.0, -1.0)];
        for (a, b) in c.points.iter().zip(&want) {
            assert!((a - b).norm() < 1e-12, "{a} vs {b}");
        }
        assert_eq!(c.points.len(), 2);
    }

    #[test]
    fn point_cloud_two_coordinates_and_other_types() {
        // 2-D cloud: x as INT8, y as FLOAT64, no z; stride 9.
        let mut data = Vec::new();
        for (x, y) in [(-3i8, 0.5f64), (7, -1.5)] {
            data.push(x as u8);
            data.extend(y.to_le_bytes());
        }
        let msg = foxglove::schemas::PointCloud {
            timestamp: None,
            frame_id: "f".into(),
            pose: None,
            point_stride: 9,
            fields: vec![
                field("x", 0, NumericType::Int8),
                field("y", 1, NumericType::Float64),
            ],
            data: data.into(),
        };
        let c = decode_foxglove_point_cloud(&msg.encode_to_vec()).unwrap();
        assert_eq!(
            c.points,
            vec![Point3::new(-3.0, 0.5, 0.0), Point3::new(7.0, -1.5, 0.0)]
        );
        assert_eq!(c.header.stamp, Time::default());
    }

    #[test]
    fn point_cloud_bad_input_errors() {
        let base = cloud(&[[1.0, 2.0, 3.0]], None);
        let field_of = |m: foxglove::schemas::PointCloud| {
            decode_foxglove_point_cloud(&m.encode_to_vec())
                .unwrap_err()
                .field
        };

        let mut m = base.clone();
        m.fields.retain(|f| f.name == "x" || f.name == "intensity");
        assert_eq!(field_of(m), "fields");

        let mut m = base.clone();
        m.fields[1].r#type = 0;
        assert_eq!(field_of(m), "fields[1].type");
        let mut m = base.clone();
        m.fields[2].r#type = 42;
        assert_eq!(field_of(m), "fields[2].type");

        let mut m = base.clone();
        m.fields[2].offset = 13; // 13 + 4 > 16
        assert_eq!(field_of(m), "fields[2]");

        let mut m = base.clone();
        m.point_stride = 15; // 16 bytes of data is not a whole number of 15-byte points
        m.fields[3].offset = 0;
        assert_eq!(field_of(m), "data");

        let mut m = base.clone();
        m.point_stride = 0;
        m.fields.clear();
        m.fields.push(field("x", 0, NumericType::Uint8));
        assert_eq!(field_of(m), "fields[0]");

        let mut m = base.clone();
        m.pose = Some(Pose {
            position: None,
            orientation: Some(Quaternion {
                x: 0.0,
                y: 0.0,
                z: 0.0,
                w: 0.0,
            }),
        });
        assert_eq!(field_of(m), "pose.orientation");

        let mut m = base.clone();
        m.timestamp = Some(Timestamp::new(u32::MAX, 0));
        assert_eq!(field_of(m), "timestamp.sec");

        // Not protobuf at all, and every truncation: Err or Ok, never a panic.
        assert_eq!(
            decode_foxglove_point_cloud(&[0xFF, 0xFF, 0xFF])
                .unwrap_err()
                .field,
            "PointCloud"
        );
        let full = base.encode_to_vec();
        for len in 0..full.len() {
            let _ = decode_foxglove_point_cloud(&full[..len]);
        }
        let mut rng = Pcg64::seed_from_u64(99);
        for _ in 0..5000 {
            let mut b = full.clone();
            let i = rng.random_range(0..b.len());
            b[i] = rng.random();
            let _ = decode_foxglove_point_cloud(&b);
        }
    }

    fn iso(rng: &mut Pcg64) -> Isometry3<f64> {
        Isometry3::from_parts(
            Translation3::new(rng.random(), rng.random(), rng.random_range(-9.0..9.0)),
            UnitQuaternion::from_scaled_axis(V3::new(0.3, -1.1, rng.random_range(-2.0..2.0))),
        )
    }

    #[test]
    fn pose_in_frame_round_trip_through_prost() {
        let mut rng = Pcg64::seed_from_u64(3);
        let pose = iso(&mut rng);
        let bytes = encode_pose_in_frame(1_700_000_000_123_456_789, "world", &pose);
        let m = PoseInFrame::decode(&bytes[..]).unwrap();
        assert_eq!(m.frame_id, "world");
        let ts = m.timestamp.unwrap();
        assert_eq!((ts.sec(), ts.nsec()), (1_700_000_000, 123_456_789));
        let p = m.pose.unwrap();
        let (t, q) = (p.position.unwrap(), p.orientation.unwrap());
        let v = pose.translation.vector;
        assert_eq!([t.x, t.y, t.z], [v.x, v.y, v.z]);
        let r = pose.rotation;
        assert_eq!([q.x, q.y, q.z, q.w], [r.i, r.j, r.k, r.w]);

        // Saturates beyond 2106 instead of wrapping.
        let m = PoseInFrame::decode(&encode_pose_in_frame(u64::MAX, "w", &pose)[..]).unwrap();
        assert_eq!(m.timestamp.unwrap(), Timestamp::MAX);
    }

    #[test]
    fn frame_transforms_round_trip_through_prost() {
        let mut rng = Pcg64::seed_from_u64(4);
        let a = iso(&mut rng);
        let b = iso(&mut rng);
        let bytes = encode_frame_transforms(&[
            (5, "world", "base", a),
            (2_000_000_001, "base", "lidar", b),
        ]);
        let m = FrameTransforms::decode(&bytes[..]).unwrap();
        assert_eq!(m.transforms.len(), 2);
        for (t, (ns, parent, child, want)) in m.transforms.iter().zip([
            (5u64, "world", "base", a),
            (2_000_000_001, "base", "lidar", b),
        ]) {
            assert_eq!(t.timestamp.unwrap().total_nanos(), ns);
            assert_eq!(
                (t.parent_frame_id.as_str(), t.child_frame_id.as_str()),
                (parent, child)
            );
            let tr = t.translation.as_ref().unwrap();
            let q = t.rotation.as_ref().unwrap();
            let got = isometry_from_parts([tr.x, tr.y, tr.z], [q.x, q.y, q.z, q.w], "r").unwrap();
            // Child origin maps to the translation; exact component copies.
            assert_eq!(got.translation.vector, want.translation.vector);
            assert!(got.rotation.angle_to(&want.rotation) < 1e-12);
        }
    }

    #[test]
    fn schemas_are_named_protobuf_descriptors() {
        for (s, name) in [
            (point_cloud_schema(), "foxglove.PointCloud"),
            (pose_in_frame_schema(), "foxglove.PoseInFrame"),
            (frame_transforms_schema(), "foxglove.FrameTransforms"),
        ] {
            assert_eq!(s.name, name);
            assert_eq!(s.encoding, "protobuf");
            // A FileDescriptorSet naming the message: the type name appears in the bytes.
            let short = name.trim_start_matches("foxglove.");
            assert!(
                s.data.windows(short.len()).any(|w| w == short.as_bytes()),
                "{name} descriptor"
            );
        }
    }
}
