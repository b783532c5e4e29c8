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
//! Robustness: every decoder returns [`DecodeError`] (naming the offending field, e.g.
//! `fields[2].datatype`) for malformed input instead of panicking, and never allocates more than
//! the payload's length can justify — counts read from the message are checked against the bytes
//! that remain before any allocation.

use nalgebra::{Isometry3, Point3, Quaternion, Translation3, UnitQuaternion};

use super::scalar::Scalar;

/// MCAP message encoding of every message in this module.
pub const MESSAGE_ENCODING: &str = "cdr";
/// MCAP schema encoding of the `*_SCHEMA` texts in this module.
pub const SCHEMA_ENCODING: &str = "ros2msg";

/// Schema name of `sensor_msgs/msg/PointCloud2`.
pub const POINT_CLOUD2_SCHEMA_NAME: &str = "sensor_msgs/msg/PointCloud2";
/// Schema name of `geometry_msgs/msg/PoseStamped`.
pub const POSE_STAMPED_SCHEMA_NAME: &str = "geometry_msgs/msg/PoseStamped";
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
    quaternion_section!(),
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

/// `sensor_msgs/msg/PointField` datatype constants (`INT8 = 1` … `FLOAT64 = 8`).
pub mod datatype {
    /// `int8`.
    pub const INT8: u8 = 1;
    /// `uint8`.
    pub const UINT8: u8 = 2;
    /// `int16`.
    pub const INT16: u8 = 3;
    /// `uint16`.
    pub const UINT16: u8 = 4;
    /// `int32`.
    pub const INT32: u8 = 5;
    /// `uint32`.
    pub const UINT32: u8 = 6;
    /// `float32`.
    pub const FLOAT32: u8 = 7;
    /// `float64`.
    pub const FLOAT64: u8 = 8;
}

const NANOS_PER_SEC: i64 = 1_000_000_000;

/// A message could not be decoded. `field` names the offending field as a path into the
/// message (`header.frame_id`, `fields[2].datatype`, `data`, …); the caller adds file, topic and
/// log-time context.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("{field}: {detail}")]
pub struct DecodeError {
    /// Path of the offending field inside the message.
    pub field: String,
    /// What is wrong with it.
    pub detail: String,
}

impl DecodeError {
    /// Builds an error for `field`.
    pub fn new(field: impl Into<String>, detail: impl Into<String>) -> Self {
        Self {
            field: field.into(),
            detail: detail.into(),
        }
    }
}

/// `builtin_interfaces/msg/Time`: seconds and nanoseconds since the epoch. The represented time
/// is `sec + nanosec·1e-9` seconds (so −1.7 s is `{sec: −2, nanosec: 300_000_000}`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash, Default)]
pub struct Time {
    /// Whole seconds (may be negative).
    pub sec: i32,
    /// Nanoseconds added to `sec`, normally in `[0, 1e9)`.
    pub nanosec: u32,
}

impl Time {
    /// The time in nanoseconds since the epoch, `sec·1e9 + nanosec`, as `i64` (signed because
    /// `sec` is; every `(i32, u32)` pair fits without overflow).
    pub fn to_ns(self) -> i64 {
        i64::from(self.sec) * NANOS_PER_SEC + i64::from(self.nanosec)
    }

    /// The time `ns` nanoseconds since the epoch, or `None` if the seconds do not fit the
    /// message's `i32` (before 1901 or after 2038-01-19).
    pub fn from_ns(ns: i64) -> Option<Self> {
        let sec = i32::try_from(ns.div_euclid(NANOS_PER_SEC)).ok()?;
        let nanosec = u32::try_from(ns.rem_euclid(NANOS_PER_SEC)).ok()?;
        Some(Self { sec, nanosec })
    }
}

/// `std_msgs/msg/Header`: acquisition time and coordinate frame of stamped data.
#[derive(Debug, Clone, PartialEq, Eq, Default)]
pub struct Header {
    /// Acquisition time.
    pub stamp: Time,
    /// Coordinate frame the data is expressed in.
    pub frame_id: String,
}

/// `geometry_msgs/msg/TransformStamped`: the pose of `child_frame_id` in `header.frame_id`.
#[derive(Debug, Clone, PartialEq)]
pub struct TransformStamped {
    /// Time and parent frame.
    pub header: Header,
    /// Frame whose pose is given.
    pub child_frame_id: String,
    /// `parent_from_child`: maps points in the child frame into the parent frame (metres).
    pub transform: Isometry3<f64>,
}

/// A decoded point cloud (from `sensor_msgs/msg/PointCloud2` here or `foxglove.PointCloud` in
/// [`super::foxglove_msgs`]).
#[derive(Debug, Clone, PartialEq)]
pub struct PointCloud {
    /// Time and frame of the cloud.
    pub header: Header,
    /// Finite points in `header.frame_id` (metres), in row-major message order.
    pub points: Vec<Point3<f64>>,
    /// Per-point intensity parallel to `points`, if the message has an `intensity` field.
    pub intensity: Option<Vec<f32>>,
    /// Per-point acquisition times parallel to `points`, if the message has a time field
    /// ([`super::point_time::TIME_FIELDS`]).
    pub times: Option<super::point_time::PointTimes>,
    /// Points per row in the message (before dropping non-finite points).
    pub width: u32,
    /// Rows in the message (1 for unorganised clouds).
    pub height: u32,
    /// Points skipped because a coordinate was NaN or ±Inf.
    pub num_dropped_non_finite: usize,
}

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

    /// Bytes left after the current position.
    pub fn remaining(&self) -> usize {
        self.payload.len() - self.pos
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

    /// The next `n` raw bytes (no alignment).
    ///
    /// # Errors
    /// `field` if fewer than `n` bytes remain.
    pub fn bytes(&mut self, n: usize, field: &str) -> Result<&'a [u8], DecodeError> {
        if n > self.remaining() {
            return Err(truncated(field, n, self.remaining()));
        }
        let out = &self.payload[self.pos..self.pos + n];
        self.pos += n;
        Ok(out)
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

    /// Reads a `uint8`.
    pub fn u8(&mut self, field: &str) -> Result<u8, DecodeError> {
        Ok(self.bytes(1, field)?[0])
    }

    /// Reads a `bool` (any non-zero byte is `true`).
    pub fn bool(&mut self, field: &str) -> Result<bool, DecodeError> {
        Ok(self.u8(field)? != 0)
    }

    /// Reads an aligned `uint32`.
    pub fn u32(&mut self, field: &str) -> Result<u32, DecodeError> {
        Ok(u32::from_le_bytes(self.array(field)?))
    }

    /// Reads an aligned `int32`.
    pub fn i32(&mut self, field: &str) -> Result<i32, DecodeError> {
        Ok(i32::from_le_bytes(self.array(field)?))
    }

    /// Reads an aligned `float64`.
    pub fn f64(&mut self, field: &str) -> Result<f64, DecodeError> {
        Ok(f64::from_le_bytes(self.array(field)?))
    }

    /// Reads a `string`: `u32` length including the NUL, the bytes, the NUL. A length of 0 is
    /// accepted as the empty string.
    ///
    /// # Errors
    /// `field` if truncated, not NUL-terminated or not UTF-8.
    pub fn string(&mut self, field: &str) -> Result<String, DecodeError> {
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

    /// Reads a sequence's `u32` element count and checks that `count` elements of at least
    /// `min_element_bytes` each can fit in the bytes that remain, so the count can bound an
    /// allocation.
    ///
    /// # Errors
    /// `field` if truncated or the count cannot fit.
    pub fn sequence_len(
        &mut self,
        field: &str,
        min_element_bytes: usize,
    ) -> Result<usize, DecodeError> {
        let count = self.u32(field)? as usize;
        let need = count.saturating_mul(min_element_bytes);
        if need > self.remaining() {
            return Err(DecodeError::new(
                field,
                format!(
                    "sequence of {count} elements (at least {need} bytes) does not fit in the \
                     {} bytes that remain",
                    self.remaining()
                ),
            ));
        }
        Ok(count)
    }
}

fn truncated(field: &str, need: usize, have: usize) -> DecodeError {
    DecodeError::new(
        field,
        format!("message truncated: need {need} more bytes, {have} remain"),
    )
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

    /// Writes a `uint8`.
    pub fn u8(&mut self, v: u8) {
        self.buf.push(v);
    }

    /// Writes a `bool` as one byte 0/1.
    pub fn bool(&mut self, v: bool) {
        self.buf.push(u8::from(v));
    }

    /// Writes an aligned `uint32`.
    pub fn u32(&mut self, v: u32) {
        self.align(4);
        self.buf.extend_from_slice(&v.to_le_bytes());
    }

    /// Writes an aligned `int32`.
    pub fn i32(&mut self, v: i32) {
        self.align(4);
        self.buf.extend_from_slice(&v.to_le_bytes());
    }

    /// Writes an aligned `float64`.
    pub fn f64(&mut self, v: f64) {
        self.align(8);
        self.buf.extend_from_slice(&v.to_le_bytes());
    }

    /// Writes a `string` (length including NUL, bytes, NUL).
    ///
    /// # Panics
    /// If the string is 4 GiB or longer.
    pub fn string(&mut self, s: &str) {
        let len = u32::try_from(s.len() + 1).expect("CDR string shorter than 4 GiB");
        self.u32(len);
        self.buf.extend_from_slice(s.as_bytes());
        self.buf.push(0);
    }

    /// Writes a sequence length.
    ///
    /// # Panics
    /// If `len` does not fit in `u32`.
    pub fn sequence_len(&mut self, len: usize) {
        self.u32(u32::try_from(len).expect("CDR sequence shorter than 2^32 elements"));
    }

    /// Appends raw bytes (no alignment).
    pub fn raw(&mut self, bytes: &[u8]) {
        self.buf.extend_from_slice(bytes);
    }

    /// The serialized message.
    pub fn finish(self) -> Vec<u8> {
        self.buf
    }
}

// ---------------------------------------------------------------------------------------------
// Shared message parts
// ---------------------------------------------------------------------------------------------

fn read_header(r: &mut CdrReader<'_>, prefix: &str) -> Result<Header, DecodeError> {
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

/// Writes `geometry_msgs/Point`/`Vector3` then `geometry_msgs/Quaternion` (x, y, z, w).
fn write_isometry(w: &mut CdrWriter, iso: &Isometry3<f64>) {
    let t = &iso.translation.vector;
    let q = iso.rotation.quaternion();
    for v in [t.x, t.y, t.z, q.i, q.j, q.k, q.w] {
        w.f64(v);
    }
}

/// Reads a translation and a quaternion; rejects non-finite values and quaternions whose norm
/// is not within 1e-3 of 1 (the rotation is renormalised exactly).
fn read_isometry(
    r: &mut CdrReader<'_>,
    translation: &str,
    rotation: &str,
) -> Result<Isometry3<f64>, DecodeError> {
    let mut v = [0.0; 7];
    for (i, slot) in v.iter_mut().enumerate() {
        let (name, comp) = if i < 3 {
            (translation, ["x", "y", "z"][i])
        } else {
            (rotation, ["x", "y", "z", "w"][i - 3])
        };
        let field = format!("{name}.{comp}");
        *slot = r.f64(&field)?;
        if !slot.is_finite() {
            return Err(DecodeError::new(field, format!("non-finite value {slot}")));
        }
    }
    isometry_from_parts([v[0], v[1], v[2]], [v[3], v[4], v[5], v[6]], rotation)
}

/// Tolerance on the quaternion norm accepted by the decoders.
const QUATERNION_NORM_TOLERANCE: f64 = 1e-3;

/// Builds an isometry from a translation and an `[x, y, z, w]` quaternion, normalising the
/// quaternion; errors (naming `rotation_field`) if its norm is not within
/// [`QUATERNION_NORM_TOLERANCE`] of 1.
pub(crate) fn isometry_from_parts(
    t: [f64; 3],
    xyzw: [f64; 4],
    rotation_field: &str,
) -> Result<Isometry3<f64>, DecodeError> {
    let q = Quaternion::new(xyzw[3], xyzw[0], xyzw[1], xyzw[2]);
    let norm = q.norm();
    if !norm.is_finite() || (norm - 1.0).abs() > QUATERNION_NORM_TOLERANCE {
        return Err(DecodeError::new(
            rotation_field,
            format!("quaternion {xyzw:?} (x, y, z, w) has norm {norm}, not 1"),
        ));
    }
    Ok(Isometry3::from_parts(
        Translation3::new(t[0], t[1], t[2]),
        UnitQuaternion::from_quaternion(q),
    ))
}

// ---------------------------------------------------------------------------------------------
// Packed point extraction (shared with the foxglove.PointCloud decoder)
// ---------------------------------------------------------------------------------------------

impl Scalar {
    /// From a `sensor_msgs/PointField` datatype constant.
    fn from_ros(datatype: u8) -> Option<Self> {
        Some(match datatype {
            datatype::INT8 => Self::I8,
            datatype::UINT8 => Self::U8,
            datatype::INT16 => Self::I16,
            datatype::UINT16 => Self::U16,
            datatype::INT32 => Self::I32,
            datatype::UINT32 => Self::U32,
            datatype::FLOAT32 => Self::F32,
            datatype::FLOAT64 => Self::F64,
            _ => return None,
        })
    }
}

/// A validated field: `offset + kind.size() <= point_step`.
#[derive(Debug, Clone, Copy)]
pub(crate) struct PackedField {
    pub(crate) offset: usize,
    pub(crate) kind: Scalar,
}

/// Validated layout of a packed cloud. Coordinates that are `None` read as 0 (foxglove allows
/// 2-D clouds; the PointCloud2 decoder requires all three).
#[derive(Debug, Clone, Copy)]
pub(crate) struct PackedLayout {
    pub(crate) xyz: [Option<PackedField>; 3],
    pub(crate) intensity: Option<PackedField>,
    /// A per-point time field (read as `f64`).
    pub(crate) time: Option<PackedField>,
    pub(crate) big_endian: bool,
}

/// Checks that `kind` at `offset` fits in `point_step`, naming `field` otherwise.
pub(crate) fn check_field_fits(
    field: &str,
    offset: u64,
    kind: Scalar,
    count: u64,
    point_step: u64,
) -> Result<PackedField, DecodeError> {
    let end = offset + kind.size() as u64 * count.max(1);
    if end > point_step {
        return Err(DecodeError::new(
            field,
            format!(
                "offset {offset} + {} element(s) of {} bytes ends at byte {end}, beyond point \
                 step {point_step}",
                count.max(1),
                kind.size()
            ),
        ));
    }
    // offset < point_step <= u32::MAX fits usize on every supported target.
    Ok(PackedField {
        offset: offset as usize,
        kind,
    })
}

/// Points and intensities extracted from packed data.
pub(crate) struct Extracted {
    pub(crate) points: Vec<Point3<f64>>,
    pub(crate) intensity: Option<Vec<f32>>,
    pub(crate) times: Option<Vec<f64>>,
    pub(crate) num_dropped_non_finite: usize,
}

/// Reads `rows × cols` points starting at `row·row_step + col·point_step` in `data`. The caller
/// has checked that every point lies inside `data` and every field inside `point_step`.
pub(crate) fn extract(
    data: &[u8],
    layout: &PackedLayout,
    rows: usize,
    cols: usize,
    row_step: usize,
    point_step: usize,
) -> Extracted {
    let n = rows * cols;
    let mut points = Vec::with_capacity(n);
    let mut intensity = layout.intensity.map(|_| Vec::with_capacity(n));
    let mut times = layout.time.map(|_| Vec::with_capacity(n));
    let mut dropped = 0;
    let read = |point: &[u8], f: Option<PackedField>| {
        f.map_or(0.0, |f| f.kind.read(&point[f.offset..], layout.big_endian))
    };
    for row in 0..rows {
        for col in 0..cols {
            let start = row * row_step + col * point_step;
            let point = &data[start..start + point_step];
            let (x, y, z) = (
                read(point, layout.xyz[0]),
                read(point, layout.xyz[1]),
                read(point, layout.xyz[2]),
            );
            if !(x.is_finite() && y.is_finite() && z.is_finite()) {
                dropped += 1;
                continue;
            }
            points.push(Point3::new(x, y, z));
            if let Some(out) = intensity.as_mut() {
                out.push(read(point, layout.intensity) as f32);
            }
            if let Some(out) = times.as_mut() {
                out.push(read(point, layout.time));
            }
        }
    }
    Extracted {
        points,
        intensity,
        times,
        num_dropped_non_finite: dropped,
    }
}

// ---------------------------------------------------------------------------------------------
// sensor_msgs/msg/PointCloud2
// ---------------------------------------------------------------------------------------------

/// Smallest serialized `PointField`: empty name (4) + offset (4) + datatype (1) + padding (3) +
/// count (4).
const MIN_POINT_FIELD_BYTES: usize = 16;

struct RawField {
    name: String,
    offset: u32,
    datatype: u8,
    count: u32,
}

/// Decodes a CDR-serialized `sensor_msgs/msg/PointCloud2` (encapsulation header included).
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
    let mut r = CdrReader::new(payload)?;
    let header = read_header(&mut r, "header.")?;
    let height = r.u32("height")?;
    let width = r.u32("width")?;
    let n_fields = r.sequence_len("fields", MIN_POINT_FIELD_BYTES)?;
    let mut fields = Vec::with_capacity(n_fields);
    for i in 0..n_fields {
        let name = r.string(&format!("fields[{i}].name"))?;
        let offset = r.u32(&format!("fields[{i}].offset"))?;
        let datatype = r.u8(&format!("fields[{i}].datatype"))?;
        let count = r.u32(&format!("fields[{i}].count"))?;
        fields.push(RawField {
            name,
            offset,
            datatype,
            count,
        });
    }
    let is_bigendian = r.bool("is_bigendian")?;
    let point_step = r.u32("point_step")?;
    let row_step = r.u32("row_step")?;
    let data_len = r.sequence_len("data", 1)?;
    let data = r.bytes(data_len, "data")?;
    let _is_dense = r.bool("is_dense")?;

    let empty = PointCloud {
        header,
        points: Vec::new(),
        intensity: None,
        times: None,
        width,
        height,
        num_dropped_non_finite: 0,
    };
    if width == 0 || height == 0 {
        return Ok(empty);
    }

    let find = |name: &str, required: bool| -> Result<Option<PackedField>, DecodeError> {
        let Some(i) = fields.iter().position(|f| f.name == name) else {
            return if required {
                let names: Vec<&str> = fields.iter().map(|f| f.name.as_str()).collect();
                Err(DecodeError::new(
                    "fields",
                    format!("no field named '{name}' (fields: {names:?})"),
                ))
            } else {
                Ok(None)
            };
        };
        let f = &fields[i];
        let kind = Scalar::from_ros(f.datatype).ok_or_else(|| {
            DecodeError::new(
                format!("fields[{i}].datatype"),
                format!(
                    "unknown datatype {} for field '{name}' (expected 1..=8, INT8..FLOAT64)",
                    f.datatype
                ),
            )
        })?;
        check_field_fits(
            &format!("fields[{i}]"),
            u64::from(f.offset),
            kind,
            u64::from(f.count),
            u64::from(point_step),
        )
        .map(Some)
    };
    let mut time_field = None;
    for name in super::point_time::TIME_FIELDS {
        if let Some(f) = find(name, false)? {
            time_field = Some((name, f));
            break;
        }
    }
    let layout = PackedLayout {
        xyz: [find("x", true)?, find("y", true)?, find("z", true)?],
        intensity: find("intensity", false)?,
        time: time_field.map(|(_, f)| f),
        big_endian: is_bigendian,
    };

    let (w, h, ps, rs) = (
        u64::from(width),
        u64::from(height),
        u64::from(point_step),
        u64::from(row_step),
    );
    let row_bytes = w * ps; // < 2^64
    if h > 1 && rs < row_bytes {
        return Err(DecodeError::new(
            "row_step",
            format!(
                "row step {rs} is smaller than width {w} × point step {ps} = {row_bytes}, so \
                 rows would overlap"
            ),
        ));
    }
    let need = (h - 1)
        .checked_mul(rs)
        .and_then(|v| v.checked_add(row_bytes));
    match need {
        Some(need) if need <= data.len() as u64 => {}
        _ => {
            return Err(DecodeError::new(
                "data",
                format!(
                    "{} bytes, but height {h}, width {w}, point step {ps} and row step {rs} \
                     need (height−1)·row_step + width·point_step = {} bytes",
                    data.len(),
                    need.map_or_else(|| "more than 2^64".to_string(), |n| n.to_string())
                ),
            ));
        }
    }
    // All of these are ≤ data.len(), so they fit usize.
    let ex = extract(
        data,
        &layout,
        height as usize,
        width as usize,
        if height > 1 { row_step as usize } else { 0 },
        point_step as usize,
    );
    let stamp_s = empty.header.stamp.to_ns() as f64 * 1e-9;
    let times = time_field
        .zip(ex.times)
        .map(|((name, f), raw)| super::point_time::point_times(name, f.kind, raw, stamp_s));
    Ok(PointCloud {
        points: ex.points,
        intensity: ex.intensity,
        times,
        num_dropped_non_finite: ex.num_dropped_non_finite,
        ..empty
    })
}

/// Encodes a little-endian `sensor_msgs/msg/PointCloud2` with FLOAT32 fields `x`, `y`, `z`
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
    if let Some(i) = intensity {
        assert_eq!(
            i.len(),
            points.len(),
            "intensity must have one value per point"
        );
    }
    let names: &[&str] = if intensity.is_some() {
        &["x", "y", "z", "intensity"]
    } else {
        &["x", "y", "z"]
    };
    let point_step = 4 * names.len();
    let data_len = points.len() * point_step;
    let width = u32::try_from(points.len()).expect("fewer than 2^32 points");
    let data_len_u32 = u32::try_from(data_len).expect("point data shorter than 4 GiB");

    let mut w = CdrWriter::with_capacity(data_len + 128 + header.frame_id.len());
    write_header(&mut w, header);
    w.u32(1); // height
    w.u32(width);
    w.sequence_len(names.len());
    for (i, name) in names.iter().enumerate() {
        w.string(name);
        w.u32(4 * i as u32);
        w.u8(datatype::FLOAT32);
        w.u32(1);
    }
    w.bool(false); // is_bigendian
    w.u32(point_step as u32);
    w.u32(data_len_u32); // row_step
    w.u32(data_len_u32);
    let mut dense = true;
    for (k, p) in points.iter().enumerate() {
        for c in [p.x, p.y, p.z] {
            let c: f64 = c.into();
            dense &= c.is_finite();
            w.raw(&(c as f32).to_le_bytes());
        }
        if let Some(i) = intensity {
            w.raw(&i[k].to_le_bytes());
        }
    }
    w.bool(dense);
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
    w.sequence_len(transforms.len());
    for t in transforms {
        write_header(&mut w, &t.header);
        w.string(&t.child_frame_id);
        write_isometry(&mut w, &t.transform);
    }
    w.finish()
}

/// Decodes a `tf2_msgs/msg/TFMessage`.
///
/// # Errors
/// [`DecodeError`] naming `transforms[i]…` as for [`decode_pose_stamped`].
pub fn decode_tf_message(payload: &[u8]) -> Result<Vec<TransformStamped>, DecodeError> {
    let mut r = CdrReader::new(payload)?;
    let n = r.sequence_len("transforms", MIN_TRANSFORM_STAMPED_BYTES)?;
    let mut out = Vec::with_capacity(n);
    for i in 0..n {
        let header = read_header(&mut r, &format!("transforms[{i}].header."))?;
        let child_frame_id = r.string(&format!("transforms[{i}].child_frame_id"))?;
        let transform = read_isometry(
            &mut r,
            &format!("transforms[{i}].transform.translation"),
            &format!("transforms[{i}].transform.rotation"),
        )?;
        out.push(TransformStamped {
            header,
            child_frame_id,
            transform,
        });
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::Vector3;
    use rand::{RngExt, SeedableRng};
    use rand_pcg::Pcg64;

    // -----------------------------------------------------------------------------------------
    // An independent, test-only CDR byte builder: every primitive asserts its own alignment, so
    // padding must be written explicitly by the test.
    // -----------------------------------------------------------------------------------------

    struct Hand {
        b: Vec<u8>,
        big: bool,
    }

    impl Hand {
        fn new(big: bool) -> Self {
            Self {
                b: vec![0x00, if big { 0x00 } else { 0x01 }, 0x00, 0x00],
                big,
            }
        }
        fn pos(&self) -> usize {
            self.b.len() - 4
        }
        fn pad(&mut self, n: usize) -> &mut Self {
            self.b.extend(std::iter::repeat_n(0u8, n));
            self
        }
        fn u8(&mut self, v: u8) -> &mut Self {
            self.b.push(v);
            self
        }
        fn u32(&mut self, v: u32) -> &mut Self {
            assert_eq!(self.pos() % 4, 0, "test forgot padding before a u32");
            let bytes = if self.big {
                v.to_be_bytes()
            } else {
                v.to_le_bytes()
            };
            self.b.extend(bytes);
            self
        }
        fn i32(&mut self, v: i32) -> &mut Self {
            self.u32(v as u32)
        }
        fn f64(&mut self, v: f64) -> &mut Self {
            assert_eq!(self.pos() % 8, 0, "test forgot padding before a f64");
            let bytes = if self.big {
                v.to_be_bytes()
            } else {
                v.to_le_bytes()
            };
            self.b.extend(bytes);
            self
        }
        /// A string; the caller pads afterwards.
        fn string(&mut self, s: &str) -> &mut Self {
            self.u32(s.len() as u32 + 1);
            self.b.extend(s.as_bytes());
            self.b.push(0);
            self
        }
        /// Zero bytes up to the next multiple of 4 (test-side alignment).
        fn pad4(&mut self) -> &mut Self {
            let n = (4 - self.pos() % 4) % 4;
            self.pad(n)
        }
    }

    struct F<'a> {
        name: &'a str,
        offset: u32,
        dt: u8,
        count: u32,
    }

    fn f(name: &str, offset: u32, dt: u8) -> F<'_> {
        F {
            name,
            offset,
            dt,
            count: 1,
        }
    }

    struct Cloud<'a> {
        big_cdr: bool,
        fields: Vec<F<'a>>,
        is_bigendian: bool,
        height: u32,
        width: u32,
        point_step: u32,
        row_step: u32,
        data: Vec<u8>,
    }

    fn hand_cloud(c: &Cloud<'_>) -> Vec<u8> {
        let mut h = Hand::new(c.big_cdr);
        h.i32(-3).u32(250_000_000).string("lidar").pad4();
        h.u32(c.height).u32(c.width).u32(c.fields.len() as u32);
        for fl in &c.fields {
            h.string(fl.name)
                .pad4()
                .u32(fl.offset)
                .u8(fl.dt)
                .pad(3)
                .u32(fl.count);
        }
        h.u8(u8::from(c.is_bigendian)).pad(3);
        h.u32(c.point_step).u32(c.row_step).u32(c.data.len() as u32);
        h.b.extend(&c.data);
        h.u8(1);
        h.b
    }

    /// Writes `v` at `data[at..]` as PointField datatype `dt`.
    fn put(data: &mut [u8], at: usize, dt: u8, v: f64, big: bool) {
        macro_rules! w {
            ($t:ty) => {{
                let x = v as $t;
                let b = if big {
                    x.to_be_bytes()
                } else {
                    x.to_le_bytes()
                };
                data[at..at + b.len()].copy_from_slice(&b);
            }};
        }
        match dt {
            1 => w!(i8),
            2 => w!(u8),
            3 => w!(i16),
            4 => w!(u16),
            5 => w!(i32),
            6 => w!(u32),
            7 => w!(f32),
            8 => w!(f64),
            _ => unreachable!(),
        }
    }

    fn size_of(dt: u8) -> usize {
        [0, 1, 1, 2, 2, 4, 4, 4, 8][dt as usize]
    }

    fn xyz_cloud(points: &[[f64; 3]], dt: u8, big_cdr: bool, big_data: bool) -> Cloud<'static> {
        let s = size_of(dt);
        // x, y, z, intensity then 3 bytes of padding: an odd point_step.
        let point_step = 4 * s + 3;
        let mut data = vec![0xAB; points.len() * point_step];
        for (k, p) in points.iter().enumerate() {
            for (j, &c) in p.iter().enumerate() {
                put(&mut data, k * point_step + j * s, dt, c, big_data);
            }
            put(
                &mut data,
                k * point_step + 3 * s,
                dt,
                2.0 + k as f64,
                big_data,
            );
        }
        Cloud {
            big_cdr,
            fields: vec![
                f("x", 0, dt),
                f("y", s as u32, dt),
                f("z", 2 * s as u32, dt),
                f("intensity", 3 * s as u32, dt),
            ],
            is_bigendian: big_data,
            height: 1,
            width: points.len() as u32,
            point_step: point_step as u32,
            row_step: (points.len() * point_step) as u32,
            data,
        }
    }

    fn p(x: f64, y: f64, z: f64) -> Point3<f64> {
        Point3::new(x, y, z)
    }

    // -----------------------------------------------------------------------------------------
    // Literal byte vectors
    // -----------------------------------------------------------------------------------------

    /// Little-endian CDR, FLOAT32 x/y/z with point_step 16 (4 bytes of padding per point).
    #[rustfmt::skip]
    fn literal_le() -> Vec<u8> {
        let mut v = vec![
            0x00, 0x01, 0x00, 0x00,             // encapsulation: CDR_LE
            0x07, 0x00, 0x00, 0x00,             // @0  stamp.sec = 7
            0xF4, 0x01, 0x00, 0x00,             // @4  stamp.nanosec = 500
            0x04, 0x00, 0x00, 0x00,             // @8  frame_id length 4
            b'm', b'a', b'p', 0x00,             // @12 "map\0"
            0x01, 0x00, 0x00, 0x00,             // @16 height 1
            0x02, 0x00, 0x00, 0x00,             // @20 width 2
            0x03, 0x00, 0x00, 0x00,             // @24 3 fields
            0x02, 0x00, 0x00, 0x00, b'x', 0x00, // @28 name "x"
            0x00, 0x00,                         // @34 padding
            0x00, 0x00, 0x00, 0x00,             // @36 offset 0
            0x07, 0x00, 0x00, 0x00,             // @40 FLOAT32 + 3 padding
            0x01, 0x00, 0x00, 0x00,             // @44 count 1
            0x02, 0x00, 0x00, 0x00, b'y', 0x00, 0x00, 0x00, // @48 "y" + padding
            0x04, 0x00, 0x00, 0x00,             // @56 offset 4
            0x07, 0x00, 0x00, 0x00,             // @60 FLOAT32
            0x01, 0x00, 0x00, 0x00,             // @64 count 1
            0x02, 0x00, 0x00, 0x00, b'z', 0x00, 0x00, 0x00, // @68 "z"
            0x08, 0x00, 0x00, 0x00,             // @76 offset 8
            0x07, 0x00, 0x00, 0x00,             // @80 FLOAT32
            0x01, 0x00, 0x00, 0x00,             // @84 count 1
            0x00, 0x00, 0x00, 0x00,             // @88 is_bigendian false + padding
            0x10, 0x00, 0x00, 0x00,             // @92 point_step 16
            0x20, 0x00, 0x00, 0x00,             // @96 row_step 32
            0x20, 0x00, 0x00, 0x00,             // @100 data length 32
        ];
        // @104 data: (1.5, -2, 0.25) and (3, 4, -5), each followed by 4 garbage bytes.
        for pt in [[1.5f32, -2.0, 0.25], [3.0, 4.0, -5.0]] {
            for c in pt {
                v.extend(c.to_le_bytes());
            }
            v.extend([0xFF; 4]);
        }
        v.push(0x01); // @136 is_dense
        v
    }

    #[test]
    fn literal_little_endian_cloud_with_padded_point_step() {
        let c = decode_point_cloud2(&literal_le()).expect("valid");
        assert_eq!(
            c.header.stamp,
            Time {
                sec: 7,
                nanosec: 500
            }
        );
        assert_eq!(c.header.frame_id, "map");
        assert_eq!((c.width, c.height), (2, 1));
        assert_eq!(c.points, vec![p(1.5, -2.0, 0.25), p(3.0, 4.0, -5.0)]);
        assert_eq!(c.intensity, None);
        assert_eq!(c.num_dropped_non_finite, 0);
    }

    /// Big-endian CDR with big-endian point data (is_bigendian = 1) and FLOAT64 x/y/z.
    #[test]
    #[rustfmt::skip]
    fn literal_big_endian_cloud_with_big_endian_data() {
        let mut v = vec![
            0x00, 0x00, 0x00, 0x00,             // encapsulation: CDR_BE
            0xFF, 0xFF, 0xFF, 0xFE,             // @0  stamp.sec = -2
            0x11, 0xE1, 0xA3, 0x00,             // @4  stamp.nanosec = 300_000_000
            0x00, 0x00, 0x00, 0x02,             // @8  frame_id length 2
            b'b', 0x00, 0x00, 0x00,             // @12 "b\0" + 2 padding
            0x00, 0x00, 0x00, 0x01,             // @16 height 1
            0x00, 0x00, 0x00, 0x01,             // @20 width 1
            0x00, 0x00, 0x00, 0x03,             // @24 3 fields
            0x00, 0x00, 0x00, 0x02, b'z', 0x00, 0x00, 0x00, // @28 "z" (fields out of order)
            0x00, 0x00, 0x00, 0x10,             // @36 offset 16
            0x08, 0x00, 0x00, 0x00,             // @40 FLOAT64
            0x00, 0x00, 0x00, 0x01,             // @44 count
            0x00, 0x00, 0x00, 0x02, b'x', 0x00, 0x00, 0x00, // @48 "x"
            0x00, 0x00, 0x00, 0x00,             // @56 offset 0
            0x08, 0x00, 0x00, 0x00,             // @60 FLOAT64
            0x00, 0x00, 0x00, 0x01,             // @64 count
            0x00, 0x00, 0x00, 0x02, b'y', 0x00, 0x00, 0x00, // @68 "y"
            0x00, 0x00, 0x00, 0x08,             // @76 offset 8
            0x08, 0x00, 0x00, 0x00,             // @80 FLOAT64
            0x00, 0x00, 0x00, 0x01,             // @84 count
            0x01, 0x00, 0x00, 0x00,             // @88 is_bigendian true
            0x00, 0x00, 0x00, 0x18,             // @92 point_step 24
            0x00, 0x00, 0x00, 0x18,             // @96 row_step 24
            0x00, 0x00, 0x00, 0x18,             // @100 data length 24
        ];
        for c in [10.5f64, -20.25, 1e-3] {
            v.extend(c.to_be_bytes());
        }
        v.push(0x01);
        let c = decode_point_cloud2(&v).expect("valid");
        assert_eq!(c.header.stamp, Time { sec: -2, nanosec: 300_000_000 });
        assert_eq!(c.header.stamp.to_ns(), -1_700_000_000);
        assert_eq!(c.header.frame_id, "b");
        assert_eq!(c.points, vec![p(10.5, -20.25, 1e-3)]);
    }

    #[test]
    fn encoder_matches_hand_built_bytes() {
        let header = Header {
            stamp: Time {
                sec: -3,
                nanosec: 250_000_000,
            },
            frame_id: "lidar".into(),
        };
        let pts = [p(1.0, 2.0, 3.0), p(-0.5, 0.25, 8.0)];
        let inten = [0.5f32, 7.0];
        let mut data = Vec::new();
        for (q, i) in pts.iter().zip(inten) {
            for c in [q.x, q.y, q.z] {
                data.extend((c as f32).to_le_bytes());
            }
            data.extend(i.to_le_bytes());
        }
        let expected = hand_cloud(&Cloud {
            big_cdr: false,
            fields: vec![
                f("x", 0, 7),
                f("y", 4, 7),
                f("z", 8, 7),
                f("intensity", 12, 7),
            ],
            is_bigendian: false,
            height: 1,
            width: 2,
            point_step: 16,
            row_step: 32,
            data,
        });
        assert_eq!(encode_point_cloud2(&header, &pts, Some(&inten)), expected);
    }

    // -----------------------------------------------------------------------------------------
    // Datatypes, endianness, layout
    // -----------------------------------------------------------------------------------------

    #[test]
    fn every_datatype_in_both_cdr_and_both_data_byte_orders() {
        for dt in 1..=8u8 {
            let signed = matches!(dt, 1 | 3 | 5 | 7 | 8);
            let pts: Vec<[f64; 3]> = if signed {
                vec![[-5.0, 17.0, 100.0], [0.0, -100.0, 3.0]]
            } else {
                vec![[5.0, 17.0, 100.0], [0.0, 255.0, 3.0]]
            };
            for big_cdr in [false, true] {
                for big_data in [false, true] {
                    let bytes = hand_cloud(&xyz_cloud(&pts, dt, big_cdr, big_data));
                    let c = decode_point_cloud2(&bytes).unwrap_or_else(|e| {
                        panic!("dt {dt} cdr_be {big_cdr} data_be {big_data}: {e}")
                    });
                    let want: Vec<_> = pts.iter().map(|q| p(q[0], q[1], q[2])).collect();
                    assert_eq!(c.points, want, "dt {dt} {big_cdr} {big_data}");
                    assert_eq!(c.intensity, Some(vec![2.0, 3.0]), "dt {dt}");
                    assert_eq!(
                        c.header.stamp,
                        Time {
                            sec: -3,
                            nanosec: 250_000_000
                        }
                    );
                    assert_eq!(c.header.frame_id, "lidar");
                }
            }
        }
    }

    #[test]
    fn count_greater_than_one_uses_element_zero() {
        // x has 3 FLOAT32 elements (offsets 0, 4, 8); y at 12, z at 16 (UINT8), point_step 20.
        let mut data = vec![0u8; 20];
        for (k, v) in [1.25f32, 99.0, 98.0, -4.0].into_iter().enumerate() {
            put(&mut data, 4 * k, 7, f64::from(v), false);
        }
        data[16] = 200;
        let mut fields = vec![f("x", 0, 7), f("y", 12, 7), f("z", 16, 2)];
        fields[0].count = 3;
        let bytes = hand_cloud(&Cloud {
            big_cdr: false,
            fields,
            is_bigendian: false,
            height: 1,
            width: 1,
            point_step: 20,
            row_step: 20,
            data,
        });
        let c = decode_point_cloud2(&bytes).expect("valid");
        assert_eq!(c.points, vec![p(1.25, -4.0, 200.0)]);
    }

    #[test]
    fn organised_2x3_cloud_honours_row_step_padding() {
        // point_step 12, 3 points per row = 36 bytes + 8 bytes of row padding: row_step 44.
        // The last row has no padding: data is exactly (2-1)*44 + 3*12 = 80 bytes.
        let mut data = vec![0xFF; 80]; // 0xFF..: NaN as f32 if misread
        let mut want = Vec::new();
        for row in 0..2 {
            for col in 0..3 {
                let q = [
                    row as f64 * 10.0 + col as f64,
                    -(col as f64),
                    0.5 * row as f64,
                ];
                for (j, c) in q.iter().enumerate() {
                    put(&mut data, row * 44 + col * 12 + 4 * j, 7, *c, false);
                }
                want.push(p(q[0], q[1], q[2]));
            }
        }
        let cloud = Cloud {
            big_cdr: true,
            fields: vec![f("x", 0, 7), f("y", 4, 7), f("z", 8, 7)],
            is_bigendian: false,
            height: 2,
            width: 3,
            point_step: 12,
            row_step: 44,
            data,
        };
        let c = decode_point_cloud2(&hand_cloud(&cloud)).expect("valid");
        assert_eq!((c.width, c.height), (3, 2));
        assert_eq!(c.points, want);
        assert_eq!(c.num_dropped_non_finite, 0);

        // One byte less than (height−1)·row_step + width·point_step is an error.
        let mut short = cloud;
        short.data.pop();
        let e = decode_point_cloud2(&hand_cloud(&short)).unwrap_err();
        assert_eq!(e.field, "data", "{e}");
    }

    #[test]
    fn non_finite_points_are_dropped_and_counted() {
        let pts = [
            [1.0, 2.0, 3.0],
            [f64::NAN, 0.0, 0.0],
            [4.0, f64::INFINITY, 0.0],
            [0.0, 0.0, f64::NEG_INFINITY],
            [5.0, 6.0, 7.0],
        ];
        for dt in [7u8, 8] {
            let c = decode_point_cloud2(&hand_cloud(&xyz_cloud(&pts, dt, false, false)))
                .expect("valid");
            assert_eq!(c.points, vec![p(1.0, 2.0, 3.0), p(5.0, 6.0, 7.0)]);
            assert_eq!(c.num_dropped_non_finite, 3);
            // Intensity stays parallel to the kept points: 2 + index.
            assert_eq!(c.intensity, Some(vec![2.0, 6.0]));
            assert_eq!(c.width, 5);
        }
    }

    #[test]
    fn empty_cloud_needs_no_fields() {
        let bytes = hand_cloud(&Cloud {
            big_cdr: false,
            fields: vec![],
            is_bigendian: false,
            height: 1,
            width: 0,
            point_step: 0,
            row_step: 0,
            data: vec![],
        });
        let c = decode_point_cloud2(&bytes).expect("valid");
        assert!(c.points.is_empty());
        assert_eq!(c.width, 0);
    }

    // -----------------------------------------------------------------------------------------
    // Errors
    // -----------------------------------------------------------------------------------------

    fn base() -> Cloud<'static> {
        xyz_cloud(&[[1.0, 2.0, 3.0], [4.0, 5.0, 6.0]], 7, false, false)
    }

    fn err_of(c: &Cloud<'_>) -> DecodeError {
        decode_point_cloud2(&hand_cloud(c)).expect_err("must be rejected")
    }

    #[test]
    fn rejects_other_representation_ids_and_short_headers() {
        for id in [[0x00, 0x03], [0x00, 0x02], [0x00, 0x07], [0x01, 0x01]] {
            let mut b = literal_le();
            b[..2].copy_from_slice(&id);
            let e = decode_point_cloud2(&b).unwrap_err();
            assert_eq!(e.field, "encapsulation");
            assert!(e.detail.contains("not plain CDR"), "{e}");
        }
        assert_eq!(
            decode_point_cloud2(&[0, 1, 0]).unwrap_err().field,
            "encapsulation"
        );
    }

    #[test]
    fn missing_coordinate_field_is_named() {
        for (k, name) in ["x", "y", "z"].iter().enumerate() {
            let mut c = base();
            c.fields.remove(k);
            let e = err_of(&c);
            assert_eq!(e.field, "fields");
            assert!(e.detail.contains(&format!("'{name}'")), "{e}");
        }
    }

    #[test]
    fn unknown_datatype_is_named() {
        for bad in [0u8, 9, 255] {
            let mut c = base();
            c.fields[1].dt = bad;
            assert_eq!(err_of(&c).field, "fields[1].datatype");
        }
    }

    #[test]
    fn field_beyond_point_step_is_named() {
        let mut c = base(); // FLOAT32, point_step 19
        c.fields[2].offset = 16; // 16 + 4 > 19
        assert_eq!(err_of(&c).field, "fields[2]");
        let mut c = base();
        c.fields[0].count = 5; // 0 + 5·4 > 19
        assert_eq!(err_of(&c).field, "fields[0]");
        let mut c = base();
        c.fields[1].offset = u32::MAX;
        assert_eq!(err_of(&c).field, "fields[1]");
    }

    #[test]
    fn short_data_and_overlapping_rows_are_rejected() {
        let mut c = base();
        c.data.truncate(c.data.len() - 1);
        assert_eq!(err_of(&c).field, "data");

        let mut c = base();
        c.width = 1;
        c.height = 2;
        c.row_step = c.point_step - 1;
        assert_eq!(err_of(&c).field, "row_step");
    }

    #[test]
    fn absurd_sizes_are_rejected_without_allocating() {
        let mut c = base();
        c.width = u32::MAX;
        assert_eq!(err_of(&c).field, "data");
        let mut c = base();
        c.width = 1;
        c.height = u32::MAX;
        c.row_step = c.point_step;
        assert_eq!(err_of(&c).field, "data");

        // A fields count of 2^32−1 or a data length of 2^32−1 in a tiny message.
        let b = hand_cloud(&base());
        let mut huge_fields = b.clone();
        huge_fields[4 + 28..4 + 32].copy_from_slice(&u32::MAX.to_le_bytes()); // after "lidar\0"+pad
        assert_eq!(
            decode_point_cloud2(&huge_fields).unwrap_err().field,
            "fields"
        );
    }

    #[test]
    fn huge_data_length_is_rejected() {
        let c = base();
        let mut b = hand_cloud(&c);
        // data length sits right before the data: total − 1 (is_dense) − data − 4.
        let at = b.len() - 1 - c.data.len() - 4;
        assert_eq!(&b[at..at + 4], &(c.data.len() as u32).to_le_bytes());
        b[at..at + 4].copy_from_slice(&u32::MAX.to_le_bytes());
        assert_eq!(decode_point_cloud2(&b).unwrap_err().field, "data");
    }

    #[test]
    fn bad_strings_are_rejected() {
        let mut b = literal_le();
        b[4 + 15] = b'X'; // frame_id "map\0" → "mapX"
        assert_eq!(
            decode_point_cloud2(&b).unwrap_err().field,
            "header.frame_id"
        );
        let mut b = literal_le();
        b[4 + 12] = 0xC3; // lone UTF-8 lead byte followed by 'a'
        assert_eq!(
            decode_point_cloud2(&b).unwrap_err().field,
            "header.frame_id"
        );
    }

    #[test]
    fn every_truncation_errors_and_byte_flips_never_panic() {
        let full = hand_cloud(&base());
        for len in 0..full.len() {
            assert!(
                decode_point_cloud2(&full[..len]).is_err(),
                "truncated to {len}"
            );
        }
        let pose = encode_pose_stamped(&Header::default(), &Isometry3::identity());
        for len in 0..pose.len() {
            assert!(
                decode_pose_stamped(&pose[..len]).is_err(),
                "pose truncated to {len}"
            );
        }
        let tf = encode_tf_message(&[sample_tf(1), sample_tf(2)]);
        for len in 0..tf.len() {
            assert!(
                decode_tf_message(&tf[..len]).is_err(),
                "tf truncated to {len}"
            );
        }

        let mut rng = Pcg64::seed_from_u64(0xC0DEC);
        let organised = hand_cloud(&Cloud {
            height: 2,
            width: 1,
            row_step: 24,
            data: vec![0u8; 24 + 19],
            ..base()
        });
        let mut accepted = 0;
        for trial in 0..20_000 {
            let src = match trial % 4 {
                0 => &full,
                1 => &organised,
                2 => &pose,
                _ => &tf,
            };
            let mut b = src.clone();
            for _ in 0..rng.random_range(1..4) {
                let i = rng.random_range(0..b.len());
                b[i] = rng.random();
            }
            let ok = match trial % 4 {
                0 | 1 => decode_point_cloud2(&b).is_ok(),
                2 => decode_pose_stamped(&b).is_ok(),
                _ => decode_tf_message(&b).is_ok(),
            };
            accepted += usize::from(ok);
        }
        // Flips in the point data or the stamp decode fine; flips in the layout usually don't.
        assert!(accepted > 1000 && accepted < 19_000, "accepted {accepted}");
    }

    // -----------------------------------------------------------------------------------------
    // Round trips
    // -----------------------------------------------------------------------------------------

    fn random_iso(rng: &mut Pcg64) -> Isometry3<f64> {
        let t = Vector3::new(
            rng.random_range(-50.0..50.0),
            rng.random_range(-50.0..50.0),
            rng.random_range(-5.0..5.0),
        );
        let axis = Vector3::new(rng.random::<f64>() - 0.5, rng.random::<f64>() - 0.5, 0.3);
        Isometry3::new(t, axis * rng.random_range(0.1..3.0))
    }

    fn sample_tf(k: i32) -> TransformStamped {
        let mut rng = Pcg64::seed_from_u64(k as u64);
        TransformStamped {
            header: Header {
                stamp: Time {
                    sec: 1_700_000_000 + k,
                    nanosec: 123,
                },
                frame_id: "odom".into(),
            },
            child_frame_id: format!("base_{k}"),
            transform: random_iso(&mut rng),
        }
    }

    fn assert_iso_close(a: &Isometry3<f64>, b: &Isometry3<f64>) {
        assert!((a.translation.vector - b.translation.vector).norm() < 1e-12);
        assert!(a.rotation.angle_to(&b.rotation) < 1e-9);
    }

    #[test]
    fn point_cloud2_round_trip_f32_and_f64_with_and_without_intensity() {
        let mut rng = Pcg64::seed_from_u64(11);
        let pts64: Vec<Point3<f64>> = (0..257)
            .map(|_| {
                p(
                    rng.random_range(-80.0..80.0),
                    rng.random_range(-80.0..80.0),
                    rng.random(),
                )
            })
            .collect();
        let pts32: Vec<Point3<f32>> = pts64.iter().map(|q| q.cast::<f32>()).collect();
        let inten: Vec<f32> = (0..257).map(|i| i as f32 * 0.5).collect();
        let header = Header {
            stamp: Time {
                sec: 42,
                nanosec: 999_999_999,
            },
            frame_id: "velodyne".into(),
        };
        // Expected: coordinates rounded to f32, from construction.
        let want: Vec<Point3<f64>> = pts32.iter().map(|q| q.cast::<f64>()).collect();

        let c = decode_point_cloud2(&encode_point_cloud2(&header, &pts64, Some(&inten))).unwrap();
        assert_eq!(c.header, header);
        assert_eq!(c.points, want);
        assert_eq!(c.intensity.as_deref(), Some(&inten[..]));
        assert_eq!((c.width, c.height), (257, 1));

        let c = decode_point_cloud2(&encode_point_cloud2(&header, &pts32, None)).unwrap();
        assert_eq!(c.points, want);
        assert_eq!(c.intensity, None);

        let empty: [Point3<f32>; 0] = [];
        let c = decode_point_cloud2(&encode_point_cloud2(&header, &empty, None)).unwrap();
        assert!(c.points.is_empty());
    }

    #[test]
    fn pose_stamped_round_trip_and_layout() {
        let mut rng = Pcg64::seed_from_u64(5);
        for frame in ["", "ab", "map", "world_frame"] {
            let header = Header {
                stamp: Time {
                    sec: -5,
                    nanosec: 7,
                },
                frame_id: frame.into(),
            };
            let iso = random_iso(&mut rng);
            let bytes = encode_pose_stamped(&header, &iso);
            // Layout oracle: stamp (8) + string (4 + len + 1), then padding to 8.
            let pos_at = 4 + (8 + 4 + frame.len() + 1).div_ceil(8) * 8;
            let x = f64::from_le_bytes(bytes[pos_at..pos_at + 8].try_into().unwrap());
            assert_eq!(x, iso.translation.vector.x);
            let w_at = pos_at + 6 * 8;
            let w = f64::from_le_bytes(bytes[w_at..w_at + 8].try_into().unwrap());
            assert_eq!(w, iso.rotation.w);
            assert_eq!(bytes.len(), w_at + 8);

            let (h, back) = decode_pose_stamped(&bytes).unwrap();
            assert_eq!(h, header);
            assert_iso_close(&back, &iso);
        }
    }

    #[test]
    fn pose_stamped_decodes_hand_built_big_endian() {
        let mut h = Hand::new(true);
        h.i32(10).u32(20).string("map").pad(0); // @8 len, @12 "map\0" → @16, 8-aligned
        h.f64(1.0).f64(-2.0).f64(3.5);
        // 90° about z: (x, y, z, w) = (0, 0, sin 45°, cos 45°)
        let s = std::f64::consts::FRAC_1_SQRT_2;
        h.f64(0.0).f64(0.0).f64(s).f64(s);
        let (hd, iso) = decode_pose_stamped(&h.b).unwrap();
        assert_eq!(
            hd.stamp,
            Time {
                sec: 10,
                nanosec: 20
            }
        );
        assert_eq!(hd.frame_id, "map");
        let q = iso * p(1.0, 0.0, 0.0);
        assert!((q - p(1.0, -1.0, 3.5)).norm() < 1e-12, "{q}");
    }

    #[test]
    fn pose_stamped_rejects_bad_orientations() {
        for q in [
            [0.0, 0.0, 0.0, 0.0],
            [0.0, 0.0, 0.0, 2.0],
            [f64::NAN, 0.0, 0.0, 1.0],
        ] {
            let mut h = Hand::new(false);
            h.i32(0)
                .u32(0)
                .string("m")
                .pad(2)
                .f64(0.0)
                .f64(0.0)
                .f64(0.0);
            for c in q {
                h.f64(c);
            }
            let e = decode_pose_stamped(&h.b).unwrap_err();
            assert!(e.field.starts_with("pose.orientation"), "{e}");
        }
        let mut h = Hand::new(false);
        h.i32(0).u32(0).string("m").pad(2).f64(f64::INFINITY);
        let e = decode_pose_stamped(&h.b).unwrap_err();
        assert_eq!(e.field, "pose.position.x");
    }

    #[test]
    fn tf_message_round_trip() {
        let tfs: Vec<_> = (0..5).map(sample_tf).collect();
        let back = decode_tf_message(&encode_tf_message(&tfs)).unwrap();
        assert_eq!(back.len(), 5);
        for (a, b) in tfs.iter().zip(&back) {
            assert_eq!(a.header, b.header);
            assert_eq!(a.child_frame_id, b.child_frame_id);
            assert_iso_close(&a.transform, &b.transform);
        }
        assert!(
            decode_tf_message(&encode_tf_message(&[]))
                .unwrap()
                .is_empty()
        );
        // A count of 2^32−1 in an 8-byte message is rejected by the count check.
        let mut h = Hand::new(false);
        h.u32(u32::MAX);
        assert_eq!(decode_tf_message(&h.b).unwrap_err().field, "transforms");
    }

    #[test]
    fn time_nanoseconds() {
        assert_eq!(Time { sec: 1, nanosec: 5 }.to_ns(), 1_000_000_005);
        assert_eq!(
            Time {
                sec: -1,
                nanosec: 0
            }
            .to_ns(),
            -1_000_000_000
        );
        assert_eq!(
            Time::from_ns(-1),
            Some(Time {
                sec: -1,
                nanosec: 999_999_999
            })
        );
        assert_eq!(
            Time::from_ns(1_700_000_000_123_456_789),
            Some(Time {
                sec: 1_700_000_000,
                nanosec: 123_456_789
            })
        );
        assert_eq!(Time::from_ns(i64::MAX), None);
        let extreme = Time {
            sec: i32::MIN,
            nanosec: u32::MAX,
        };
        assert_eq!(
            extreme.to_ns(),
            i64::from(i32::MIN) * 1_000_000_000 + i64::from(u32::MAX)
        );
    }

    // -----------------------------------------------------------------------------------------
    // Schema texts
    // -----------------------------------------------------------------------------------------

    /// Splits a ros2msg text into (type name, body) sections and checks the delimiter format.
    fn sections(text: &str) -> Vec<(String, String)> {
        let delim = format!("\n{}\n", "=".repeat(80));
        let mut out = Vec::new();
        for (i, part) in text.split(&delim).enumerate() {
            if i == 0 {
                assert!(!part.starts_with("MSG:"));
                out.push((String::new(), part.to_string()));
            } else {
                let (first, body) = part.split_once('\n').expect("MSG line");
                let name = first.strip_prefix("MSG: ").expect("'MSG: ' prefix");
                out.push((name.to_string(), body.to_string()));
            }
        }
        out
    }

    fn check_schema(text: &str, root_pkg: &str, want_order: &[&str]) {
        const PRIMITIVES: &[&str] = &[
            "bool", "byte", "char", "float32", "float64", "int8", "uint8", "int16", "uint16",
            "int32", "uint32", "int64", "uint64", "string",
        ];
        let secs = sections(text);
        let names: Vec<&str> = secs[1..].iter().map(|(n, _)| n.as_str()).collect();
        assert_eq!(names, want_order);
        for (k, (name, body)) in secs.iter().enumerate() {
            let pkg = if k == 0 {
                root_pkg
            } else {
                name.split('/').next().unwrap()
            };
            for line in body.lines().filter(|l| !l.trim().is_empty()) {
                let ty = line.split_whitespace().next().unwrap();
                let ty = ty.split('[').next().unwrap();
                if PRIMITIVES.contains(&ty) {
                    continue;
                }
                let full = if ty.contains('/') {
                    ty.to_string()
                } else {
                    format!("{pkg}/{ty}")
                };
                assert!(
                    names.contains(&full.as_str()),
                    "{full} referenced but not defined"
                );
            }
        }
    }

    #[test]
    fn schema_texts_have_every_dependency_in_rosbag2_format() {
        check_schema(
            POINT_CLOUD2_SCHEMA,
            "sensor_msgs",
            &[
                "sensor_msgs/PointField",
                "std_msgs/Header",
                "builtin_interfaces/Time",
            ],
        );
        check_schema(
            POSE_STAMPED_SCHEMA,
            "geometry_msgs",
            &[
                "geometry_msgs/Pose",
                "geometry_msgs/Point",
                "geometry_msgs/Quaternion",
                "std_msgs/Header",
                "builtin_interfaces/Time",
            ],
        );
        check_schema(
            TF_MESSAGE_SCHEMA,
            "tf2_msgs",
            &[
                "geometry_msgs/TransformStamped",
                "geometry_msgs/Transform",
                "geometry_msgs/Quaternion",
                "geometry_msgs/Vector3",
                "std_msgs/Header",
                "builtin_interfaces/Time",
            ],
        );
        // PointField constants as in sensor_msgs/msg/PointField.msg.
        for (name, v) in [
            ("INT8", 1),
            ("UINT8", 2),
            ("INT16", 3),
            ("UINT16", 4),
            ("INT32", 5),
            ("UINT32", 6),
            ("FLOAT32", 7),
            ("FLOAT64", 8),
        ] {
            assert!(
                POINT_CLOUD2_SCHEMA.contains(&format!("uint8 {name} = {v}\n")),
                "{name}"
            );
        }
    }
}
