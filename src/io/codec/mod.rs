//! Message codecs: the bytes of one message to and from our types, for each message encoding
//! an MCAP channel (or a bag connection) can carry.
//!
//! - [`cdr`]: ROS 2 (`cdr` messages, `ros2msg` schemas);
//! - [`ros1`]: ROS 1 (`ros1` messages, `ros1msg` schemas), as in ROS 1 bags and ROS 1 MCAP logs;
//! - [`foxglove`]: Foxglove's well-known protobuf messages;
//! - [`livox`]: Livox's `CustomMsg` point message, in either ROS encoding.
//!
//! Containers (MCAP files, ROS 1 bags, ROS 2 bag directories) live beside this module in
//! [`crate::io`]; a codec never touches a file.
//!
//! The ROS codecs share the message layouts (`sensor_msgs/PointCloud2`,
//! `geometry_msgs/PoseStamped`, `tf2_msgs/TFMessage`) through the [`WireRead`] / [`WireWrite`]
//! primitives, which each encoding implements with its own alignment and string rules.
//!
//! Robustness: every decoder returns [`DecodeError`] (naming the offending field, e.g.
//! `fields[2].datatype`) for malformed input instead of panicking, and never allocates more than
//! the payload's length can justify: counts read from the message are checked against the bytes
//! that remain before any allocation.

pub mod cdr;
pub mod foxglove;
pub mod livox;
pub(crate) mod packed;
pub(crate) mod point_cloud2;
pub mod ros1;

use nalgebra::{Isometry3, Point3, Quaternion, Translation3, UnitQuaternion};

/// Largest coordinate magnitude a decoded point may have \[m\]: 10⁶ m (1000 km). A sensor sees
/// a few kilometres at most; a point at or beyond this bound (a driver glitch, a cloud with
/// `is_bigendian` or `point_step` wrong, a hostile message) is dropped and counted
/// ([`PointCloud::num_dropped_far`]) at decoding, so that one such point cannot stretch a
/// cloud's extent past what the voxel grids index (`i32` voxel indices: a cloud spanning
/// 2·10⁶ m needs voxels of at least 1 mm). Clouds in a geodetic frame (UTM, ECEF) are outside
/// this bound and must be expressed in the sensor or a local frame.
pub const MAX_COORDINATE_M: f64 = 1e6;

/// Whether each coordinate of `(x, y, z)` is finite and of magnitude below
/// [`MAX_COORDINATE_M`].
#[inline(always)]
pub(crate) fn within_bound(x: f64, y: f64, z: f64) -> bool {
    x.abs() < MAX_COORDINATE_M && y.abs() < MAX_COORDINATE_M && z.abs() < MAX_COORDINATE_M
}

/// `sensor_msgs/PointField` datatype constants (`INT8 = 1` … `FLOAT64 = 8`), the same in ROS 1
/// and ROS 2.
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

/// A decoded point cloud (from `sensor_msgs/PointCloud2` in [`cdr`] or [`ros1`], or
/// `foxglove.PointCloud` in [`foxglove`]).
#[derive(Debug, Clone, PartialEq)]
pub struct PointCloud {
    /// Time and frame of the cloud.
    pub header: Header,
    /// Finite points in `header.frame_id` (metres), in row-major message order.
    pub points: Vec<Point3<f64>>,
    /// Per-point intensity parallel to `points`, if the message has an `intensity` field.
    pub intensity: Option<Vec<f32>>,
    /// Per-point acquisition times parallel to `points`, if the message has a time field
    /// ([`crate::io::point_time::TIME_FIELDS`]).
    pub times: Option<crate::io::point_time::PointTimes>,
    /// Points per row in the message (before dropping non-finite points).
    pub width: u32,
    /// Rows in the message (1 for unorganised clouds).
    pub height: u32,
    /// Points skipped because a coordinate was NaN or ±Inf.
    pub num_dropped_non_finite: usize,
    /// Points skipped because a (finite) coordinate's magnitude was at least
    /// [`MAX_COORDINATE_M`].
    pub num_dropped_far: usize,
    /// Points of an organised cloud (`height > 1`) skipped because they are exactly (0, 0, 0):
    /// how LiDAR drivers (Ouster, Hesai) and depth cameras mark "no return" (and Livox points
    /// at (0, 0, 0), organised or not).
    pub num_dropped_zero: usize,
    /// Livox points dropped by their `tag` ([`livox::LivoxTags`]); 0 for other messages.
    pub num_dropped_tag: usize,
    /// Points dropped because their per-point time was not finite or further than
    /// [`crate::io::point_time::POINT_TIME_BOUND_S`] from the cloud's median point time (a glitch
    /// that deskewing would move anywhere); 0 without a time field.
    pub num_dropped_time: usize,
}

impl PointCloud {
    /// Drops the points whose time is a glitch ([`crate::io::point_time::glitches`]) with their
    /// intensities, counting them in [`Self::num_dropped_time`].
    pub(crate) fn drop_time_glitches(&mut self) {
        let Some(times) = self.times.as_mut() else {
            return;
        };
        if times.seconds.len() != self.points.len() {
            return;
        }
        let Some(glitch) = crate::io::point_time::glitches(&times.seconds) else {
            return;
        };
        retain_unmasked(&mut times.seconds, &glitch);
        retain_unmasked(&mut self.points, &glitch);
        if let Some(intensity) = self.intensity.as_mut() {
            retain_unmasked(intensity, &glitch);
        }
        self.num_dropped_time += glitch.iter().filter(|&&g| g).count();
    }
}

/// Keeps the elements of `v` whose `drop` is false (`v` unchanged unless of `drop`'s length).
fn retain_unmasked<T>(v: &mut Vec<T>, drop: &[bool]) {
    if v.len() == drop.len() {
        let mut i = 0;
        v.retain(|_| {
            i += 1;
            !drop[i - 1]
        });
    }
}

// ---------------------------------------------------------------------------------------------
// Wire primitives shared by the ROS encodings
// ---------------------------------------------------------------------------------------------

/// The primitive reads of a ROS message encoding. Every read names the field it reads, for the
/// error if it fails; none panics.
pub trait WireRead<'a> {
    /// Bytes left after the current position.
    fn remaining(&self) -> usize;

    /// The next `n` raw bytes (no alignment).
    ///
    /// # Errors
    /// `field` if fewer than `n` bytes remain.
    fn bytes(&mut self, n: usize, field: &str) -> Result<&'a [u8], DecodeError>;

    /// Reads a `uint8`.
    fn u8(&mut self, field: &str) -> Result<u8, DecodeError> {
        Ok(self.bytes(1, field)?[0])
    }

    /// Reads a `bool` (any non-zero byte is `true`).
    fn bool(&mut self, field: &str) -> Result<bool, DecodeError> {
        Ok(self.u8(field)? != 0)
    }

    /// Reads a `uint32`.
    fn u32(&mut self, field: &str) -> Result<u32, DecodeError>;

    /// Reads an `int32`.
    fn i32(&mut self, field: &str) -> Result<i32, DecodeError>;

    /// Reads a `uint64`.
    fn u64(&mut self, field: &str) -> Result<u64, DecodeError>;

    /// Reads a `float64`.
    fn f64(&mut self, field: &str) -> Result<f64, DecodeError>;

    /// Reads a `string`.
    ///
    /// # Errors
    /// `field` if truncated or not UTF-8 (or, in CDR, not NUL-terminated).
    fn string(&mut self, field: &str) -> Result<String, DecodeError>;

    /// Reads a sequence's `u32` element count and checks that `count` elements of at least
    /// `min_element_bytes` each can fit in the bytes that remain, so the count can bound an
    /// allocation.
    ///
    /// # Errors
    /// `field` if truncated or the count cannot fit.
    fn sequence_len(
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

/// The primitive writes of a ROS message encoding (little-endian).
pub trait WireWrite {
    /// Writes a `uint8`.
    fn u8(&mut self, v: u8);

    /// Writes a `bool` as one byte 0/1.
    fn bool(&mut self, v: bool) {
        self.u8(u8::from(v));
    }

    /// Writes a `uint32`.
    fn u32(&mut self, v: u32);

    /// Writes an `int32`.
    fn i32(&mut self, v: i32);

    /// Writes a `float64`.
    fn f64(&mut self, v: f64);

    /// Writes a `string`.
    ///
    /// # Panics
    /// If the string is 4 GiB or longer.
    fn string(&mut self, s: &str);

    /// Writes a sequence length.
    ///
    /// # Panics
    /// If `len` does not fit in `u32`.
    fn sequence_len(&mut self, len: usize) {
        self.u32(u32::try_from(len).expect("sequence shorter than 2^32 elements"));
    }

    /// Appends raw bytes (no alignment).
    fn raw(&mut self, bytes: &[u8]);
}

/// A read of `need` bytes with only `have` left.
pub(crate) fn truncated(field: &str, need: usize, have: usize) -> DecodeError {
    DecodeError::new(
        field,
        format!("message truncated: need {need} more bytes, {have} remain"),
    )
}

// ---------------------------------------------------------------------------------------------
// Shared message parts
// ---------------------------------------------------------------------------------------------

/// Writes `geometry_msgs/Point`/`Vector3` then `geometry_msgs/Quaternion` (x, y, z, w).
pub(crate) fn write_isometry(w: &mut impl WireWrite, iso: &Isometry3<f64>) {
    let t = &iso.translation.vector;
    let q = iso.rotation.quaternion();
    for v in [t.x, t.y, t.z, q.i, q.j, q.k, q.w] {
        w.f64(v);
    }
}

/// Reads a translation and a quaternion; rejects non-finite values and quaternions whose norm
/// is not within 1e-3 of 1 (the rotation is renormalised exactly).
pub(crate) fn read_isometry<'a>(
    r: &mut impl WireRead<'a>,
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

/// Writes the `transforms` sequence of a `tf2_msgs/TFMessage` (the same fields in ROS 1 and
/// ROS 2), each header with the codec's `write_header`.
pub(crate) fn write_tf_body<W: WireWrite>(
    w: &mut W,
    transforms: &[TransformStamped],
    write_header: fn(&mut W, &Header),
) {
    w.sequence_len(transforms.len());
    for t in transforms {
        write_header(w, &t.header);
        w.string(&t.child_frame_id);
        write_isometry(w, &t.transform);
    }
}

/// Reads the `transforms` sequence of a `tf2_msgs/TFMessage`, each header with the codec's
/// `read_header` (called with the field prefix `transforms[i].header.`); `min_transform_bytes`
/// is the smallest serialized `TransformStamped` of the encoding, which bounds the count.
pub(crate) fn read_tf_body<'a, R: WireRead<'a>>(
    r: &mut R,
    min_transform_bytes: usize,
    read_header: fn(&mut R, &str) -> Result<Header, DecodeError>,
) -> Result<Vec<TransformStamped>, DecodeError> {
    let n = r.sequence_len("transforms", min_transform_bytes)?;
    let mut out = Vec::with_capacity(n);
    for i in 0..n {
        let header = read_header(r, &format!("transforms[{i}].header."))?;
        let child_frame_id = r.string(&format!("transforms[{i}].child_frame_id"))?;
        let transform = read_isometry(
            r,
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

/// A `geometry_msgs/PoseStamped` decoder: the header and the pose it carries.
pub type PoseStampedDecoder = fn(&[u8]) -> Result<(Header, Isometry3<f64>), DecodeError>;

/// The decoder for a channel that carries `geometry_msgs/PoseStamped`: ROS 2
/// (`geometry_msgs/msg/PoseStamped` in `cdr`) or ROS 1 (`geometry_msgs/PoseStamped` in `ros1`);
/// `None` for any other channel.
pub fn pose_stamped_decoder(
    schema_name: &str,
    message_encoding: &str,
) -> Option<PoseStampedDecoder> {
    match (schema_name, message_encoding) {
        (cdr::POSE_STAMPED_SCHEMA_NAME, cdr::MESSAGE_ENCODING) => Some(cdr::decode_pose_stamped),
        (ros1::POSE_STAMPED_SCHEMA_NAME, ros1::MESSAGE_ENCODING) => Some(ros1::decode_pose_stamped),
        _ => None,
    }
}
