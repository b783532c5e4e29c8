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

/// Complete `ros2msg` definition of `sensor_msgs/msg/PointCloud2` (ROS 2 `common_interfaces`,
/// comments stripped), with its dependencies `sensor_msgs/PointField`, `std_msgs/Header` and
/// `builtin_interfaces/Time` in the order rosbag2 writes them (each message's dependencies sorted
/// by name, depth first, each preceded by a line of 80 `=` and a `MSG: pkg/Type` line).
pub const POINT_CLOUD2_SCHEMA: &str = "\
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

================================================================================
MSG: std_msgs/Header
builtin_interfaces/Time stamp
string frame_id

================================================================================
MSG: builtin_interfaces/Time
int32 sec
uint32 nanosec
";

/// Complete `ros2msg` definition of `geometry_msgs/msg/PoseStamped` with `geometry_msgs/Pose`,
/// `geometry_msgs/Point`, `geometry_msgs/Quaternion`, `std_msgs/Header` and
/// `builtin_interfaces/Time` (rosbag2 order; see [`POINT_CLOUD2_SCHEMA`]). ROS 2's Quaternion
/// carries default values (`w` defaults to 1).
pub const POSE_STAMPED_SCHEMA: &str = "\
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

================================================================================
MSG: geometry_msgs/Quaternion
float64 x 0
float64 y 0
float64 z 0
float64 w 1

================================================================================
MSG: std_msgs/Header
builtin_interfaces/Time stamp
string frame_id

================================================================================
MSG: builtin_interfaces/Time
int32 sec
uint32 nanosec
";

/// Complete `ros2msg` definition of `tf2_msgs/msg/TFMessage` with
/// `geometry_msgs/TransformStamped`, `geometry_msgs/Transform`, `geometry_msgs/Quaternion`,
/// `geometry_msgs/Vector3`, `std_msgs/Header` and `builtin_interfaces/Time` (rosbag2 order; see
/// [`POINT_CLOUD2_SCHEMA`]).
pub const TF_MESSAGE_SCHEMA: &str = "\
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

================================================================================
MSG: geometry_msgs/Quaternion
float64 x 0
float64 y 0
float64 z 0
float64 w 1

================================================================================
MSG: geometry_msgs/Vector3
float64 x
float64 y
float64 z

================================================================================
MSG: std_msgs/Header
builtin_interfaces/Time stamp
string frame_id

================================================================================
MSG: builtin_interfaces/Time
int32 sec
uint32 nanosec
";

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

/// A numeric type of a packed point field.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum Scalar {
    I8,
    U8,
    I16,
    U16,
    I32,
    U32,
    F32,
    F64,
}

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

    /// Size in bytes.
    pub(crate) fn size(self) -> usize {
        match self {
            Self::I8 | Self::U8 => 1,
            Self::I16 | Self::U16 => 2,
            Self::I32 | Self::U32 | Self::F32 => 4,
            Self::F64 => 8,
        }
    }

    /// Reads one value from the start of `b` (which holds at least [`Scalar::size`] bytes).
    fn read(self, b: &[u8], big_endian: bool) -> f64 {
        fn arr<const N: usize>(b: &[u8], big_endian: bool) -> [u8; N] {
            let mut a = [0u8; N];
            a.copy_from_slice(&b[..N]);
            if big_endian {
                a.reverse();
            }
            a
        }
        match self {
            Self::I8 => f64::from(i8::from_le_bytes(arr(b, big_endian))),
            Self::U8 => f64::from(b[0]),
            Self::I16 => f64::from(i16::from_le_bytes(arr(b, big_endian))),
            Self::U16 => f64::from(u16::from_le_bytes(arr(b, big_endian))),
            Self::I32 => f64::from(i32::from_le_bytes(arr(b, big_endian))),
            Self::U32 => f64::from(u32::from_le_bytes(arr(b, big_endian))),
            Self::F32 => f64::from(f32::from_le_bytes(arr(b, big_endian))),
            Self::F64 => f64::from_le_bytes(arr(b, big_endian)),
        }
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
        }
    }
    Extracted {
        points,
        intensity,
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
    let layout = PackedLayout {
        xyz: [find("x", true)?, find("y", true)?, find("z", true)?],
        intensity: find("intensity", false)?,
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
    Ok(PointCloud {
        points: ex.points,
        intensity: ex.intensity,
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
