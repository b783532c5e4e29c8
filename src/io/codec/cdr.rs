//! ROS 2 message codecs for MCAP channels with message encoding `cdr` and schema encoding
//! `ros2msg`: `sensor_msgs/msg/PointCloud2` (decode and encode), `geometry_msgs/msg/PoseStamped`
//! and `tf2_msgs/msg/TFMessage` (encode and decode).
//!
//! Pure byte-level code, no file I/O. The wire format is classic CDR (XCDR1, what ROS 2's default
//! middlewares write):
//! - a 4-byte encapsulation header: byte 0 = 0x00, byte 1 = 0x01 for little-endian or 0x00 for
//!   big-endian CDR, bytes 2–3 = options (ignored on read, zero on write);
//! - every primitive aligned to its own size, counted from byte 4 (the start of the payload);
//! - strings as a `u32` length that includes the terminating NUL, the bytes, then the NUL;
//! - sequences as a `u32` element count followed by the elements.
//!
//! Units: positions and translations in metres, times in seconds + nanoseconds
//! (`builtin_interfaces/msg/Time`), [`Time::to_ns`] in nanoseconds.
//!
//! Robustness: as for every codec ([`super`]).

use nalgebra::{Isometry3, Point3};

use super::point_cloud2;
use super::{
    DecodeError, Header, PointCloud, Time, TransformStamped, WireRead, WireWrite, read_isometry,
    read_tf_body, truncated, write_isometry, write_tf_body,
};

/// MCAP message encoding of every message in this module.
pub const MESSAGE_ENCODING: &str = "cdr";
/// MCAP schema encoding of the `*_SCHEMA` texts in this module.
pub const SCHEMA_ENCODING: &str = "ros2msg";

/// Schema name of `sensor_msgs/msg/PointCloud2`.
pub const POINT_CLOUD2_SCHEMA_NAME: &str = "sensor_msgs/msg/PointCloud2";
/// Schema name of `geometry_msgs/msg/PoseStamped`.
pub const POSE_STAMPED_SCHEMA_NAME: &str = "geometry_msgs/msg/PoseStamped";
/// Schema name of `geometry_msgs/msg/PoseWithCovarianceStamped`.
pub const POSE_WITH_COVARIANCE_STAMPED_SCHEMA_NAME: &str =
    "geometry_msgs/msg/PoseWithCovarianceStamped";
/// Schema name of `tf2_msgs/msg/TFMessage`.
pub const TF_MESSAGE_SCHEMA_NAME: &str = "tf2_msgs/msg/TFMessage";

/// The dependency sections every stamped message's schema ends with: `std_msgs/Header` and
/// `builtin_interfaces/Time`, in the rosbag2 layout (a line of 80 `=`, `MSG: pkg/Type`, the text).
macro_rules! header_and_time_sections {
    () => {
        "
================================================================================
MSG: std_msgs/Header
builtin_interfaces/Time stamp
string frame_id

================================================================================
MSG: builtin_interfaces/Time
int32 sec
uint32 nanosec
"
    };
}

/// The `geometry_msgs/Quaternion` dependency section (ROS 2 defaults: `w` is 1).
macro_rules! quaternion_section {
    () => {
        "
================================================================================
MSG: geometry_msgs/Quaternion
float64 x 0
float64 y 0
float64 z 0
float64 w 1
"
    };
}

/// The `geometry_msgs/Pose`, `geometry_msgs/Point` and `geometry_msgs/Quaternion` dependency
/// sections, in that order.
macro_rules! pose_sections {
    () => {
        concat!(
            "
================================================================================
MSG: geometry_msgs/Pose
Point position
Quaternion orientation

================================================================================
MSG: geometry_msgs/Point
float64 x
float64 y
float64 z
",
            quaternion_section!()
        )
    };
}

/// Complete `ros2msg` definition of `sensor_msgs/msg/PointCloud2` (ROS 2 `common_interfaces`,
/// comments stripped), with its dependencies `sensor_msgs/PointField`, `std_msgs/Header` and
/// `builtin_interfaces/Time` in the order rosbag2 writes them (each message's dependencies sorted
/// by name, depth first, each preceded by a line of 80 `=` and a `MSG: pkg/Type` line).
pub const POINT_CLOUD2_SCHEMA: &str = concat!(
    "\
std_msgs/Header header
uint32 height
uint32 width
PointField[] fields
bool is_bigendian
uint32 point_step
uint32 row_step
uint8[] data
bool is_dense

================================================================================
MSG: sensor_msgs/PointField
uint8 INT8 = 1
uint8 UINT8 = 2
uint8 INT16 = 3
uint8 UINT16 = 4
uint8 INT32 = 5
uint8 UINT32 = 6
uint8 FLOAT32 = 7
uint8 FLOAT64 = 8
string name
uint32 offset
uint8 datatype
uint32 count
",
    header_and_time_sections!()
);

/// Complete `ros2msg` definition of `geometry_msgs/msg/PoseStamped` with `geometry_msgs/Pose`,
/// `geometry_msgs/Point`, `geometry_msgs/Quaternion`, `std_msgs/Header` and
/// `builtin_interfaces/Time` (rosbag2 order; see [`POINT_CLOUD2_SCHEMA`]). ROS 2's Quaternion
/// carries default values (`w` defaults to 1).
pub const POSE_STAMPED_SCHEMA: &str = concat!(
    "\
std_msgs/Header header
Pose pose
",
    pose_sections!(),
    "",
    header_and_time_sections!()
);

/// Complete `ros2msg` definition of `geometry_msgs/msg/PoseWithCovarianceStamped` with
/// `geometry_msgs/PoseWithCovariance`, `geometry_msgs/Pose`, `geometry_msgs/Point`,
/// `geometry_msgs/Quaternion`, `std_msgs/Header` and `builtin_interfaces/Time` (rosbag2 order;
/// see [`POINT_CLOUD2_SCHEMA`]).
pub const POSE_WITH_COVARIANCE_STAMPED_SCHEMA: &str = concat!(
    "\
std_msgs/Header header
PoseWithCovariance pose

================================================================================
MSG: geometry_msgs/PoseWithCovariance
Pose pose
float64[36] covariance
",
    pose_sections!(),
    "",
    header_and_time_sections!()
);

/// Complete `ros2msg` definition of `tf2_msgs/msg/TFMessage` with
/// `geometry_msgs/TransformStamped`, `geometry_msgs/Transform`, `geometry_msgs/Quaternion`,
/// `geometry_msgs/Vector3`, `std_msgs/Header` and `builtin_interfaces/Time` (rosbag2 order; see
/// [`POINT_CLOUD2_SCHEMA`]).
pub const TF_MESSAGE_SCHEMA: &str = concat!(
    "\
geometry_msgs/TransformStamped[] transforms

================================================================================
MSG: geometry_msgs/TransformStamped
std_msgs/Header header
string child_frame_id
Transform transform

================================================================================
MSG: geometry_msgs/Transform
Vector3 translation
Quaternion rotation
",
    quaternion_section!(),
    "
================================================================================
MSG: geometry_msgs/Vector3
float64 x
float64 y
float64 z
",
    header_and_time_sections!()
);

/// A ROS 2 message type as an MCAP channel declares it: schema name and complete `ros2msg` text
/// (schema encoding [`SCHEMA_ENCODING`], message encoding [`MESSAGE_ENCODING`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct MessageType {
    /// Schema name, e.g. `sensor_msgs/msg/PointCloud2`.
    pub name: &'static str,
    /// The schema text, dependencies included.
    pub schema: &'static str,
}

/// `sensor_msgs/msg/PointCloud2` ([`POINT_CLOUD2_SCHEMA`]).
pub const POINT_CLOUD2: MessageType = MessageType {
    name: POINT_CLOUD2_SCHEMA_NAME,
    schema: POINT_CLOUD2_SCHEMA,
};
/// `geometry_msgs/msg/PoseStamped` ([`POSE_STAMPED_SCHEMA`]).
pub const POSE_STAMPED: MessageType = MessageType {
    name: POSE_STAMPED_SCHEMA_NAME,
    schema: POSE_STAMPED_SCHEMA,
};
/// `geometry_msgs/msg/PoseWithCovarianceStamped` ([`POSE_WITH_COVARIANCE_STAMPED_SCHEMA`]).
pub const POSE_WITH_COVARIANCE_STAMPED: MessageType = MessageType {
    name: POSE_WITH_COVARIANCE_STAMPED_SCHEMA_NAME,
    schema: POSE_WITH_COVARIANCE_STAMPED_SCHEMA,
};
/// `tf2_msgs/msg/TFMessage` ([`TF_MESSAGE_SCHEMA`]).
pub const TF_MESSAGE: MessageType = MessageType {
    name: TF_MESSAGE_SCHEMA_NAME,
    schema: TF_MESSAGE_SCHEMA,
};

// ---------------------------------------------------------------------------------------------
// CDR reader / writer
// ---------------------------------------------------------------------------------------------

/// A classic-CDR (XCDR1) reader over one serialized message (encapsulation header included).
///
/// Reads fail with [`DecodeError`] naming the field passed in, never panic.
#[derive(Debug, Clone)]
pub struct CdrReader<'a> {
    payload: &'a [u8],
    pos: usize,
    big_endian: bool,
}

impl<'a> CdrReader<'a> {
    /// Checks the 4-byte encapsulation header of `message` and positions the reader at the
    /// start of the payload.
    ///
    /// # Errors
    /// `encapsulation` if the message is shorter than 4 bytes or its representation identifier
    /// is not plain CDR (`00 00` big-endian, `00 01` little-endian).
    pub fn new(message: &'a [u8]) -> Result<Self, DecodeError> {
        let Some((head, payload)) = message.split_first_chunk::<4>() else {
            return Err(DecodeError::new(
                "encapsulation",
                format!(
                    "message is {} bytes, shorter than the 4-byte CDR encapsulation header",
                    message.len()
                ),
            ));
        };
        let big_endian = match (head[0], head[1]) {
            (0x00, 0x00) => true,
            (0x00, 0x01) => false,
            (a, b) => {
                return Err(DecodeError::new(
                    "encapsulation",
                    format!(
                        "representation identifier 0x{a:02x}{b:02x} is not plain CDR \
                         (0x0000 big-endian or 0x0001 little-endian); parameter-list and \
                         XCDR2 encodings are not supported"
                    ),
                ));
            }
        };
        Ok(Self {
            payload,
            pos: 0,
            big_endian,
        })
    }

    /// Whether the payload is big-endian CDR.
    pub fn is_big_endian(&self) -> bool {
        self.big_endian
    }

    /// Offset of the next read from the start of the payload (byte 4 of the message).
    pub fn position(&self) -> usize {
        self.pos
    }

    /// Skips padding so the position is a multiple of `n`.
    fn align(&mut self, n: usize, field: &str) -> Result<(), DecodeError> {
        let pad = (n - self.pos % n) % n;
        if pad > self.remaining() {
            return Err(truncated(field, pad, self.remaining()));
        }
        self.pos += pad;
        Ok(())
    }

    fn array<const N: usize>(&mut self, field: &str) -> Result<[u8; N], DecodeError> {
        self.align(N, field)?;
        let mut out = [0u8; N];
        out.copy_from_slice(self.bytes(N, field)?);
        if self.big_endian {
            out.reverse();
        }
        Ok(out) // now little-endian
    }
}

impl<'a> WireRead<'a> for CdrReader<'a> {
    /// Bytes left after the current position.
    fn remaining(&self) -> usize {
        self.payload.len() - self.pos
    }

    /// The next `n` raw bytes (no alignment).
    ///
    /// # Errors
    /// `field` if fewer than `n` bytes remain.
    fn bytes(&mut self, n: usize, field: &str) -> Result<&'a [u8], DecodeError> {
        if n > self.remaining() {
            return Err(truncated(field, n, self.remaining()));
        }
        let out = &self.payload[self.pos..self.pos + n];
        self.pos += n;
        Ok(out)
    }

    /// Reads an aligned `uint32`.
    fn u32(&mut self, field: &str) -> Result<u32, DecodeError> {
        Ok(u32::from_le_bytes(self.array(field)?))
    }

    /// Reads an aligned `int32`.
    fn i32(&mut self, field: &str) -> Result<i32, DecodeError> {
        Ok(i32::from_le_bytes(self.array(field)?))
    }

    /// Reads an aligned `uint64`.
    fn u64(&mut self, field: &str) -> Result<u64, DecodeError> {
        Ok(u64::from_le_bytes(self.array(field)?))
    }

    /// Reads an aligned `float64`.
    fn f64(&mut self, field: &str) -> Result<f64, DecodeError> {
        Ok(f64::from_le_bytes(self.array(field)?))
    }

    /// Reads a `string`: `u32` length including the NUL, the bytes, the NUL. A length of 0 is
    /// accepted as the empty string.
    ///
    /// # Errors
    /// `field` if truncated, not NUL-terminated or not UTF-8.
    fn string(&mut self, field: &str) -> Result<String, DecodeError> {
        let len = self.u32(field)? as usize;
        let bytes = self.bytes(len, field)?;
        let Some((&last, text)) = bytes.split_last() else {
            return Ok(String::new());
        };
        if last != 0 {
            return Err(DecodeError::new(
                field,
                format!("string of length {len} is not NUL-terminated"),
            ));
        }
        String::from_utf8(text.to_vec())
            .map_err(|e| DecodeError::new(field, format!("string is not UTF-8: {e}")))
    }
}

/// A little-endian classic-CDR writer; starts with the encapsulation header `00 01 00 00`.
#[derive(Debug, Clone)]
pub struct CdrWriter {
    buf: Vec<u8>,
}

impl Default for CdrWriter {
    fn default() -> Self {
        Self::new()
    }
}

impl CdrWriter {
    /// A writer holding only the little-endian encapsulation header.
    pub fn new() -> Self {
        Self::with_capacity(0)
    }

    /// Like [`CdrWriter::new`] with room for `payload_bytes` more bytes.
    pub fn with_capacity(payload_bytes: usize) -> Self {
        let mut buf = Vec::with_capacity(payload_bytes + 4);
        buf.extend_from_slice(&[0x00, 0x01, 0x00, 0x00]);
        Self { buf }
    }

    fn align(&mut self, n: usize) {
        while !(self.buf.len() - 4).is_multiple_of(n) {
            self.buf.push(0);
        }
    }

    /// The serialized message.
    pub fn finish(self) -> Vec<u8> {
        self.buf
    }
}

impl WireWrite for CdrWriter {
    /// Writes a `uint8`.
    fn u8(&mut self, v: u8) {
        self.buf.push(v);
    }

    /// Writes an aligned `uint32`.
    fn u32(&mut self, v: u32) {
        self.align(4);
        self.buf.extend_from_slice(&v.to_le_bytes());
    }

    /// Writes an aligned `int32`.
    fn i32(&mut self, v: i32) {
        self.align(4);
        self.buf.extend_from_slice(&v.to_le_bytes());
    }

    /// Writes an aligned `float64`.
    fn f64(&mut self, v: f64) {
        self.align(8);
        self.buf.extend_from_slice(&v.to_le_bytes());
    }

    /// Writes a `string` (length including NUL, bytes, NUL).
    ///
    /// # Panics
    /// If the string is 4 GiB or longer.
    fn string(&mut self, s: &str) {
        let len = u32::try_from(s.len() + 1).expect("CDR string shorter than 4 GiB");
        self.u32(len);
        self.buf.extend_from_slice(s.as_bytes());
        self.buf.push(0);
    }

    /// Appends raw bytes (no alignment).
    fn raw(&mut self, bytes: &[u8]) {
        self.buf.extend_from_slice(bytes);
    }
}

// ---------------------------------------------------------------------------------------------
// std_msgs/Header
// ---------------------------------------------------------------------------------------------

pub(crate) fn read_header(r: &mut CdrReader<'_>, prefix: &str) -> Result<Header, DecodeError> {
    let sec = r.i32(&format!("{prefix}stamp.sec"))?;
    let nanosec = r.u32(&format!("{prefix}stamp.nanosec"))?;
    let frame_id = r.string(&format!("{prefix}frame_id"))?;
    Ok(Header {
        stamp: Time { sec, nanosec },
        frame_id,
    })
}

fn write_header(w: &mut CdrWriter, header: &Header) {
    w.i32(header.stamp.sec);
    w.u32(header.stamp.nanosec);
    w.string(&header.frame_id);
}

// ---------------------------------------------------------------------------------------------
// sensor_msgs/msg/PointCloud2
// ---------------------------------------------------------------------------------------------

/// Decodes a CDR-serialized `sensor_msgs/msg/PointCloud2` (encapsulation header included); the
/// body as in [`point_cloud2::decode_body`]:
///
///
/// - Coordinates come from the fields named `x`, `y`, `z` and the optional `intensity`, each of
///   any `PointField` datatype (INT8 … FLOAT64), converted to `f64` (`f32` for intensity). If
///   several fields share a name, the first is used.
/// - A field with `count > 1` contributes its element 0; `count == 0` is read like 1.
/// - The point data's byte order is `is_bigendian`, independent of the CDR byte order.
/// - Point `(row, col)` starts at `row·row_step + col·point_step` in `data`; `row_step` is
///   only used (and must be ≥ `width·point_step`) when `height > 1`. Padding inside a point and
///   after each row is skipped; extra bytes after the last point are ignored.
/// - Points with a NaN or ±Inf coordinate are dropped and counted in
///   [`PointCloud::num_dropped_non_finite`].
/// - An empty cloud (`width·height == 0`) decodes without requiring `x`, `y`, `z` fields.
/// - Fields other than x, y, z, intensity are not validated.
///
/// # Errors
/// [`DecodeError`] naming the field for a bad encapsulation header, a truncated message, a
/// missing `x`/`y`/`z`, an unknown datatype (`fields[i].datatype`), a field that does not fit in
/// `point_step` (`fields[i]`), `row_step < width·point_step` with `height > 1` (`row_step`), or
/// `data` shorter than `(height−1)·row_step + width·point_step` (`data`).
pub fn decode_point_cloud2(payload: &[u8]) -> Result<PointCloud, DecodeError> {
    decode_point_cloud2_reusing(payload, Vec::new())
}

/// The header of a `sensor_msgs/msg/PointCloud2` and the points it declares (`height · width`),
/// read without decoding the rest: what a cloud would take is known before it is decoded.
/// `None` when the message is too short to say.
pub fn point_cloud2_declared_points(payload: &[u8]) -> Option<(Header, u64)> {
    let mut r = CdrReader::new(payload).ok()?;
    let header = read_header(&mut r, "header.").ok()?;
    let (height, width) = (r.u32("height").ok()?, r.u32("width").ok()?);
    Some((header, u64::from(height) * u64::from(width)))
}

/// [`decode_point_cloud2`] writing the points into `points` (cleared first): a stream of clouds
/// reuses one buffer, that of the previous cloud, instead of allocating (and faulting in) a new
/// one for each.
pub fn decode_point_cloud2_reusing(
    payload: &[u8],
    points: Vec<Point3<f64>>,
) -> Result<PointCloud, DecodeError> {
    let mut r = CdrReader::new(payload)?;
    let header = read_header(&mut r, "header.")?;
    point_cloud2::decode_body(&mut r, header, points)
}

/// Encodes a little-endian CDR `sensor_msgs/msg/PointCloud2` with FLOAT32 fields `x`, `y`, `z`
/// (offsets 0, 4, 8) and, if `intensity` is given, `intensity` (offset 12): `point_step` 12 or
/// 16, `height` 1, `width` = number of points, `row_step` = `width·point_step`,
/// `is_bigendian` false, `is_dense` true unless a coordinate is non-finite. Coordinates are in
/// metres and rounded to `f32`.
///
/// # Panics
/// If `intensity` has a different length from `points`, or the data would exceed 4 GiB.
pub fn encode_point_cloud2<T>(
    header: &Header,
    points: &[Point3<T>],
    intensity: Option<&[f32]>,
) -> Vec<u8>
where
    T: nalgebra::Scalar + Copy + Into<f64>,
{
    let data_len = point_cloud2::data_len(points.len(), intensity.is_some());
    let mut w = CdrWriter::with_capacity(data_len + 128 + header.frame_id.len());
    write_header(&mut w, header);
    point_cloud2::encode_body(&mut w, points, intensity);
    w.finish()
}

// ---------------------------------------------------------------------------------------------
// geometry_msgs/msg/PoseStamped and tf2_msgs/msg/TFMessage
// ---------------------------------------------------------------------------------------------

/// Encodes a `geometry_msgs/msg/PoseStamped` (little-endian CDR): the pose of some body in
/// `header.frame_id` (position in metres, orientation as a unit quaternion).
pub fn encode_pose_stamped(header: &Header, pose: &Isometry3<f64>) -> Vec<u8> {
    let mut w = CdrWriter::with_capacity(16 + header.frame_id.len() + 64);
    write_header(&mut w, header);
    write_isometry(&mut w, pose);
    w.finish()
}

/// Encodes a `geometry_msgs/msg/PoseWithCovarianceStamped` (little-endian CDR): `pose` in
/// `header.frame_id` and its `covariance` (ROS order: x, y, z, rotation about x, y, z;
/// row-major; m², m·rad, rad²).
pub fn encode_pose_with_covariance_stamped(
    header: &Header,
    pose: &Isometry3<f64>,
    covariance: &[f64; 36],
) -> Vec<u8> {
    let mut w = CdrWriter::with_capacity(16 + header.frame_id.len() + 64 + 8 * 36);
    write_header(&mut w, header);
    write_isometry(&mut w, pose);
    for &v in covariance {
        w.f64(v);
    }
    w.finish()
}

/// Decodes a `geometry_msgs/msg/PoseStamped`.
///
/// # Errors
/// [`DecodeError`] for a bad header, truncation, non-finite values, or an orientation whose
/// norm is not within 1e-3 of 1 (`pose.orientation`); the orientation is renormalised.
pub fn decode_pose_stamped(payload: &[u8]) -> Result<(Header, Isometry3<f64>), DecodeError> {
    let mut r = CdrReader::new(payload)?;
    let header = read_header(&mut r, "header.")?;
    let pose = read_isometry(&mut r, "pose.position", "pose.orientation")?;
    Ok((header, pose))
}

/// Smallest serialized `TransformStamped`: stamp (8) + two empty strings (8) + 7 float64 (56).
const MIN_TRANSFORM_STAMPED_BYTES: usize = 72;

/// Encodes a `tf2_msgs/msg/TFMessage` (little-endian CDR).
pub fn encode_tf_message(transforms: &[TransformStamped]) -> Vec<u8> {
    let mut w = CdrWriter::with_capacity(8 + transforms.len() * 128);
    write_tf_body(&mut w, transforms, write_header);
    w.finish()
}

/// Decodes a `tf2_msgs/msg/TFMessage`.
///
/// # Errors
/// [`DecodeError`] naming `transforms[i]…` as for [`decode_pose_stamped`].
pub fn decode_tf_message(payload: &[u8]) -> Result<Vec<TransformStamped>, DecodeError> {
    let mut r = CdrReader::new(payload)?;
    read_tf_body(&mut r, MIN_TRANSFORM_STAMPED_BYTES, read_header)
}
#[cfg(test)]
mod tests;
