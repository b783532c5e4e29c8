//! ROS 1 message codecs for MCAP channels with message encoding `ros1` and schema encoding
//! `ros1msg`, and for ROS 1 bag connections: `sensor_msgs/PointCloud2` (decode),
//! `geometry_msgs/PoseStamped` and `tf2_msgs/TFMessage` (encode and decode).
//!
//! Pure byte-level code, no file I/O. The ROS 1 wire format (the `roscpp` serializer, documented
//! at wiki.ros.org/msg "Serialization"): every primitive little-endian with no alignment or
//! padding, strings as a `u32` byte length then the bytes (no NUL), variable-length arrays as a
//! `u32` element count then the elements, `time` as `u32` seconds + `u32` nanoseconds.
//!
//! Units: positions and translations in metres, times in seconds + nanoseconds.
//! `std_msgs/Header` carries a `seq` counter that [`super::Header`] drops; encoders write 0.
//! [`super::Time`] holds seconds as `i32` (as ROS 2 does), so a ROS 1 stamp after 2038-01-19
//! is a decode error, and our encoders write a negative second count as 0.
//!
//! Robustness: as for every codec ([`super`]).

use nalgebra::{Isometry3, Point3};

use super::point_cloud2;
use super::{
    DecodeError, Header, PointCloud, Time, TransformStamped, WireRead, WireWrite, read_isometry,
    read_tf_body, truncated, write_isometry, write_tf_body,
};

/// MCAP message encoding of every message in this module.
pub const MESSAGE_ENCODING: &str = "ros1";
/// MCAP schema encoding of the `*_SCHEMA` texts in this module.
pub const SCHEMA_ENCODING: &str = "ros1msg";

/// Type name of `sensor_msgs/PointCloud2`.
pub const POINT_CLOUD2_SCHEMA_NAME: &str = "sensor_msgs/PointCloud2";
/// Type name of `geometry_msgs/PoseStamped`.
pub const POSE_STAMPED_SCHEMA_NAME: &str = "geometry_msgs/PoseStamped";
/// Type name of `tf2_msgs/TFMessage`.
pub const TF_MESSAGE_SCHEMA_NAME: &str = "tf2_msgs/TFMessage";

/// ROS 1 MD5 sum of `geometry_msgs/PoseStamped` (the `md5sum` a connection of this type
/// declares; a function of the definition, not of its comments).
pub const POSE_STAMPED_MD5: &str = "d3812c3cbc69362b77dc0b19b345f8f5";
/// Type name of `geometry_msgs/PoseWithCovarianceStamped`.
pub const POSE_WITH_COVARIANCE_STAMPED_SCHEMA_NAME: &str =
    "geometry_msgs/PoseWithCovarianceStamped";
/// ROS 1 MD5 sum of `geometry_msgs/PoseWithCovarianceStamped`.
pub const POSE_WITH_COVARIANCE_STAMPED_MD5: &str = "953b798c0f514ff060a53a3498ce6246";
/// ROS 1 MD5 sum of `tf2_msgs/TFMessage`.
pub const TF_MESSAGE_MD5: &str = "94810edda583a504dfda3829e70d7eec";
/// ROS 1 MD5 sum of `sensor_msgs/PointCloud2`.
pub const POINT_CLOUD2_MD5: &str = "1158d486dd51d683ce2f1be655c3c181";

/// The dependency section of every stamped message: `std_msgs/Header` (ROS 1 `time` is a
/// primitive, so no further section), preceded by the line of 80 `=` and `MSG: pkg/Type` that
/// ROS 1's `gendeps --cat` writes.
macro_rules! ros1_header_section {
    () => {
        "
================================================================================
MSG: std_msgs/Header
uint32 seq
time stamp
string frame_id
"
    };
}

/// The `geometry_msgs/Quaternion` dependency section (ROS 1 has no default values).
macro_rules! ros1_quaternion_section {
    () => {
        "
================================================================================
MSG: geometry_msgs/Quaternion
float64 x
float64 y
float64 z
float64 w
"
    };
}

/// Complete `ros1msg` definition of `sensor_msgs/PointCloud2` (ROS 1 `common_msgs`, comments
/// stripped) with `std_msgs/Header` and `sensor_msgs/PointField`.
pub const POINT_CLOUD2_SCHEMA: &str = concat!(
    "\
Header header
uint32 height
uint32 width
PointField[] fields
bool is_bigendian
uint32 point_step
uint32 row_step
uint8[] data
bool is_dense
",
    ros1_header_section!(),
    "
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
"
);

/// The `geometry_msgs/Pose`, `geometry_msgs/Point` and `geometry_msgs/Quaternion` sections, in
/// the order `gendeps --cat` writes them.
macro_rules! ros1_pose_sections {
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
            ros1_quaternion_section!()
        )
    };
}

/// Complete `ros1msg` definition of `geometry_msgs/PoseStamped` with `std_msgs/Header`,
/// `geometry_msgs/Pose`, `geometry_msgs/Point` and `geometry_msgs/Quaternion`, in the order
/// `gendeps --cat` writes them.
pub const POSE_STAMPED_SCHEMA: &str = concat!(
    "\
Header header
geometry_msgs/Pose pose
",
    ros1_header_section!(),
    ros1_pose_sections!()
);

/// Complete `ros1msg` definition of `geometry_msgs/PoseWithCovarianceStamped` with
/// `std_msgs/Header`, `geometry_msgs/PoseWithCovariance`, `geometry_msgs/Pose`,
/// `geometry_msgs/Point` and `geometry_msgs/Quaternion`, in the order `gendeps --cat` writes them.
pub const POSE_WITH_COVARIANCE_STAMPED_SCHEMA: &str = concat!(
    "\
Header header
geometry_msgs/PoseWithCovariance pose
",
    ros1_header_section!(),
    "
================================================================================
MSG: geometry_msgs/PoseWithCovariance
geometry_msgs/Pose pose
float64[36] covariance
",
    ros1_pose_sections!()
);

/// Complete `ros1msg` definition of `tf2_msgs/TFMessage` with
/// `geometry_msgs/TransformStamped`, `std_msgs/Header`, `geometry_msgs/Transform`,
/// `geometry_msgs/Vector3` and `geometry_msgs/Quaternion`.
pub const TF_MESSAGE_SCHEMA: &str = concat!(
    "\
geometry_msgs/TransformStamped[] transforms

================================================================================
MSG: geometry_msgs/TransformStamped
Header header
string child_frame_id
Transform transform
",
    ros1_header_section!(),
    "
================================================================================
MSG: geometry_msgs/Transform
Vector3 translation
Quaternion rotation

================================================================================
MSG: geometry_msgs/Vector3
float64 x
float64 y
float64 z
",
    ros1_quaternion_section!()
);

// ---------------------------------------------------------------------------------------------
// ROS 1 reader / writer
// ---------------------------------------------------------------------------------------------

/// A ROS 1 reader over one serialized message. Reads fail with [`DecodeError`] naming the field
/// passed in, never panic.
#[derive(Debug, Clone)]
pub struct Ros1Reader<'a> {
    message: &'a [u8],
    pos: usize,
}

impl<'a> Ros1Reader<'a> {
    /// A reader at the start of `message`.
    pub fn new(message: &'a [u8]) -> Self {
        Self { message, pos: 0 }
    }

    /// Offset of the next read from the start of the message.
    pub fn position(&self) -> usize {
        self.pos
    }

    fn array<const N: usize>(&mut self, field: &str) -> Result<[u8; N], DecodeError> {
        let mut out = [0u8; N];
        out.copy_from_slice(self.bytes(N, field)?);
        Ok(out)
    }
}

impl<'a> WireRead<'a> for Ros1Reader<'a> {
    fn remaining(&self) -> usize {
        self.message.len() - self.pos
    }

    fn bytes(&mut self, n: usize, field: &str) -> Result<&'a [u8], DecodeError> {
        if n > self.remaining() {
            return Err(truncated(field, n, self.remaining()));
        }
        let out = &self.message[self.pos..self.pos + n];
        self.pos += n;
        Ok(out)
    }

    fn u32(&mut self, field: &str) -> Result<u32, DecodeError> {
        Ok(u32::from_le_bytes(self.array(field)?))
    }

    fn i32(&mut self, field: &str) -> Result<i32, DecodeError> {
        Ok(i32::from_le_bytes(self.array(field)?))
    }

    fn u64(&mut self, field: &str) -> Result<u64, DecodeError> {
        Ok(u64::from_le_bytes(self.array(field)?))
    }

    fn f64(&mut self, field: &str) -> Result<f64, DecodeError> {
        Ok(f64::from_le_bytes(self.array(field)?))
    }

    /// A `u32` byte length, then the bytes (no terminator).
    fn string(&mut self, field: &str) -> Result<String, DecodeError> {
        let len = self.u32(field)? as usize;
        let bytes = self.bytes(len, field)?;
        String::from_utf8(bytes.to_vec())
            .map_err(|e| DecodeError::new(field, format!("string is not UTF-8: {e}")))
    }
}

/// A ROS 1 message writer.
#[derive(Debug, Clone, Default)]
pub struct Ros1Writer {
    buf: Vec<u8>,
}

impl Ros1Writer {
    /// An empty writer with room for `bytes` bytes.
    pub fn with_capacity(bytes: usize) -> Self {
        Self {
            buf: Vec::with_capacity(bytes),
        }
    }

    /// The serialized message.
    pub fn finish(self) -> Vec<u8> {
        self.buf
    }
}

impl WireWrite for Ros1Writer {
    fn u8(&mut self, v: u8) {
        self.buf.push(v);
    }

    fn u32(&mut self, v: u32) {
        self.buf.extend_from_slice(&v.to_le_bytes());
    }

    fn i32(&mut self, v: i32) {
        self.buf.extend_from_slice(&v.to_le_bytes());
    }

    fn f64(&mut self, v: f64) {
        self.buf.extend_from_slice(&v.to_le_bytes());
    }

    fn string(&mut self, s: &str) {
        self.u32(u32::try_from(s.len()).expect("ROS 1 string shorter than 4 GiB"));
        self.buf.extend_from_slice(s.as_bytes());
    }

    fn raw(&mut self, bytes: &[u8]) {
        self.buf.extend_from_slice(bytes);
    }
}

// ---------------------------------------------------------------------------------------------
// Messages
// ---------------------------------------------------------------------------------------------

/// Reads a `std_msgs/Header` (`seq` is read and dropped).
pub(crate) fn read_header(r: &mut Ros1Reader<'_>, prefix: &str) -> Result<Header, DecodeError> {
    let _seq = r.u32(&format!("{prefix}seq"))?;
    let secs_field = format!("{prefix}stamp.secs");
    let secs = r.u32(&secs_field)?;
    let nanosec = r.u32(&format!("{prefix}stamp.nsecs"))?;
    let sec = i32::try_from(secs).map_err(|_| {
        DecodeError::new(
            secs_field,
            format!("{secs} s is after 2038-01-19, beyond the stamps mireg handles (i32 seconds)"),
        )
    })?;
    let frame_id = r.string(&format!("{prefix}frame_id"))?;
    Ok(Header {
        stamp: Time { sec, nanosec },
        frame_id,
    })
}

/// Writes a `std_msgs/Header` with `seq` 0.
fn write_header(w: &mut Ros1Writer, header: &Header) {
    w.u32(0);
    w.u32(u32::try_from(header.stamp.sec).unwrap_or(0));
    w.u32(header.stamp.nanosec);
    w.string(&header.frame_id);
}

/// Decodes a ROS 1 `sensor_msgs/PointCloud2`; the body as in [`point_cloud2::decode_body`]
/// (fields x, y, z of any datatype, optional intensity and time fields, non-finite points and
/// the zero returns of organised clouds dropped and counted).
///
/// # Errors
/// [`DecodeError`] naming the field, as for [`super::cdr::decode_point_cloud2`].
pub fn decode_point_cloud2(payload: &[u8]) -> Result<PointCloud, DecodeError> {
    decode_point_cloud2_reusing(payload, Vec::new())
}

/// The header of a ROS 1 `sensor_msgs/PointCloud2` and the points it declares
/// (`height · width`), read without decoding the rest; `None` when the message is too short.
pub fn point_cloud2_declared_points(payload: &[u8]) -> Option<(Header, u64)> {
    let mut r = Ros1Reader::new(payload);
    let header = read_header(&mut r, "header.").ok()?;
    let (height, width) = (r.u32("height").ok()?, r.u32("width").ok()?);
    Some((header, u64::from(height) * u64::from(width)))
}

/// [`decode_point_cloud2`] writing the points into `points` (cleared first), as
/// [`super::cdr::decode_point_cloud2_reusing`].
pub fn decode_point_cloud2_reusing(
    payload: &[u8],
    points: Vec<Point3<f64>>,
) -> Result<PointCloud, DecodeError> {
    let mut r = Ros1Reader::new(payload);
    let header = read_header(&mut r, "header.")?;
    point_cloud2::decode_body(&mut r, header, points)
}

/// Encodes a ROS 1 `sensor_msgs/PointCloud2` with FLOAT32 fields `x`, `y`, `z` (and
/// `intensity` if given), laid out as [`super::cdr::encode_point_cloud2`] lays them out.
///
/// # Panics
/// If `intensity` has a different length from `points`, or the data would exceed 4 GiB.
pub fn encode_point_cloud2<T>(
    header: &Header,
    points: &[nalgebra::Point3<T>],
    intensity: Option<&[f32]>,
) -> Vec<u8>
where
    T: nalgebra::Scalar + Copy + Into<f64>,
{
    let data_len = point_cloud2::data_len(points.len(), intensity.is_some());
    let mut w = Ros1Writer::with_capacity(data_len + 128 + header.frame_id.len());
    write_header(&mut w, header);
    point_cloud2::encode_body(&mut w, points, intensity);
    w.finish()
}

/// Encodes a ROS 1 `geometry_msgs/PoseStamped`: the pose of some body in `header.frame_id`
/// (position in metres, orientation as a unit quaternion).
pub fn encode_pose_stamped(header: &Header, pose: &Isometry3<f64>) -> Vec<u8> {
    let mut w = Ros1Writer::with_capacity(16 + header.frame_id.len() + 56);
    write_header(&mut w, header);
    write_isometry(&mut w, pose);
    w.finish()
}

/// Encodes a ROS 1 `geometry_msgs/PoseWithCovarianceStamped`: `pose` in `header.frame_id` and
/// its `covariance` (x, y, z, rotation about x, y, z; row-major; m², m·rad, rad²).
pub fn encode_pose_with_covariance_stamped(
    header: &Header,
    pose: &Isometry3<f64>,
    covariance: &[f64; 36],
) -> Vec<u8> {
    let mut w = Ros1Writer::with_capacity(16 + header.frame_id.len() + 56 + 8 * 36);
    write_header(&mut w, header);
    write_isometry(&mut w, pose);
    for &v in covariance {
        w.f64(v);
    }
    w.finish()
}

/// Decodes a ROS 1 `geometry_msgs/PoseStamped`.
///
/// # Errors
/// [`DecodeError`] for truncation, non-finite values, or an orientation whose norm is not
/// within 1e-3 of 1 (`pose.orientation`); the orientation is renormalised.
pub fn decode_pose_stamped(payload: &[u8]) -> Result<(Header, Isometry3<f64>), DecodeError> {
    let mut r = Ros1Reader::new(payload);
    let header = read_header(&mut r, "header.")?;
    let pose = read_isometry(&mut r, "pose.position", "pose.orientation")?;
    Ok((header, pose))
}

/// Smallest serialized `TransformStamped`: seq + stamp (12) + two empty strings (8) + 7 float64
/// (56).
const MIN_TRANSFORM_STAMPED_BYTES: usize = 76;

/// Encodes a ROS 1 `tf2_msgs/TFMessage`.
pub fn encode_tf_message(transforms: &[TransformStamped]) -> Vec<u8> {
    let mut w = Ros1Writer::with_capacity(4 + transforms.len() * 128);
    write_tf_body(&mut w, transforms, write_header);
    w.finish()
}

/// Decodes a ROS 1 `tf2_msgs/TFMessage`.
///
/// # Errors
/// [`DecodeError`] naming `transforms[i]…` as for [`decode_pose_stamped`].
pub fn decode_tf_message(payload: &[u8]) -> Result<Vec<TransformStamped>, DecodeError> {
    let mut r = Ros1Reader::new(payload);
    read_tf_body(&mut r, MIN_TRANSFORM_STAMPED_BYTES, read_header)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::io::codec::{cdr, datatype};
    use nalgebra::{Point3, Translation3, UnitQuaternion, Vector3};

    /// Little-endian bytes of each value, concatenated: the test's own serializer.
    fn le(parts: &[&[u8]]) -> Vec<u8> {
        parts.concat()
    }

    fn header_bytes(seq: u32, sec: u32, nsec: u32, frame: &str) -> Vec<u8> {
        le(&[
            &seq.to_le_bytes(),
            &sec.to_le_bytes(),
            &nsec.to_le_bytes(),
            &(frame.len() as u32).to_le_bytes(),
            frame.as_bytes(),
        ])
    }

    /// An organised 2×2 cloud by hand: x, y, z FLOAT32 at 0, 4, 8, `t` UINT32 at 12, point step
    /// 16 with no padding; point (1, 0) is a zero return and (1, 1) has a NaN.
    fn literal_cloud() -> Vec<u8> {
        let mut b = header_bytes(7, 100, 5, "os1");
        b.extend(2u32.to_le_bytes()); // height
        b.extend(2u32.to_le_bytes()); // width
        b.extend(4u32.to_le_bytes()); // fields
        for (name, off, dt) in [
            ("x", 0u32, datatype::FLOAT32),
            ("y", 4, datatype::FLOAT32),
            ("z", 8, datatype::FLOAT32),
            ("t", 12, datatype::UINT32),
        ] {
            b.extend((name.len() as u32).to_le_bytes());
            b.extend(name.as_bytes());
            b.extend(off.to_le_bytes());
            b.push(dt);
            b.extend(1u32.to_le_bytes());
        }
        b.push(0); // is_bigendian
        b.extend(16u32.to_le_bytes()); // point_step
        b.extend(32u32.to_le_bytes()); // row_step
        b.extend(64u32.to_le_bytes()); // data length
        let pts: [([f32; 3], u32); 4] = [
            ([1.0, 2.0, 3.0], 0),
            ([-1.5, 0.25, 8.0], 1_000),
            ([0.0, 0.0, 0.0], 2_000),
            ([f32::NAN, 1.0, 1.0], 3_000),
        ];
        for (p, t) in pts {
            for c in p {
                b.extend(c.to_le_bytes());
            }
            b.extend(t.to_le_bytes());
        }
        b.push(0); // is_dense
        b
    }

    #[test]
    fn literal_organised_cloud_drops_zero_returns_and_non_finite_points() {
        let c = decode_point_cloud2(&literal_cloud()).unwrap();
        assert_eq!(
            c.header.stamp,
            Time {
                sec: 100,
                nanosec: 5
            }
        );
        assert_eq!(c.header.frame_id, "os1");
        assert_eq!((c.width, c.height), (2, 2));
        assert_eq!(
            c.points,
            vec![Point3::new(1.0, 2.0, 3.0), Point3::new(-1.5, 0.25, 8.0)]
        );
        assert_eq!(c.num_dropped_zero, 1);
        assert_eq!(c.num_dropped_non_finite, 1);
        let times = c.times.expect("t field");
        assert_eq!(times.field, "t");
        // Ouster `t`: integer nanoseconds since the scan start.
        assert_eq!(times.seconds.len(), 2);
        assert_eq!(times.seconds[0], 0.0);
        assert!((times.seconds[1] - 1e-6).abs() < 1e-15);
    }

    #[test]
    fn unorganised_clouds_keep_points_at_the_origin() {
        let header = Header {
            stamp: Time { sec: 1, nanosec: 2 },
            frame_id: "f".into(),
        };
        let pts = [Point3::new(0.0f32, 0.0, 0.0), Point3::new(1.0, 2.0, 3.0)];
        let c = decode_point_cloud2(&encode_point_cloud2(&header, &pts, None)).unwrap();
        assert_eq!(c.points.len(), 2);
        assert_eq!(c.num_dropped_zero, 0);
    }

    #[test]
    fn every_truncation_of_a_cloud_is_an_error_never_a_panic() {
        let b = literal_cloud();
        for n in 0..b.len() - 1 {
            assert!(decode_point_cloud2(&b[..n]).is_err(), "prefix of {n} bytes");
        }
    }

    #[test]
    fn same_cloud_in_ros1_and_cdr_decodes_the_same() {
        let header = Header {
            stamp: Time {
                sec: 1_600_000_000,
                nanosec: 123,
            },
            frame_id: "lidar".into(),
        };
        let pts: Vec<Point3<f64>> = (0..50)
            .map(|i| Point3::new(i as f64 * 0.5, -(i as f64), 3.25))
            .collect();
        let inten: Vec<f32> = (0..50).map(|i| i as f32).collect();
        let a = decode_point_cloud2(&encode_point_cloud2(&header, &pts, Some(&inten))).unwrap();
        let b = cdr::decode_point_cloud2(&cdr::encode_point_cloud2(&header, &pts, Some(&inten)))
            .unwrap();
        assert_eq!(a, b);
    }

    #[test]
    fn pose_stamped_matches_hand_built_bytes_both_ways() {
        let pose = Isometry3::from_parts(
            Translation3::new(1.0, -2.0, 0.5),
            UnitQuaternion::from_axis_angle(&Vector3::z_axis(), 0.3),
        );
        let header = Header {
            stamp: Time {
                sec: 12,
                nanosec: 34,
            },
            frame_id: "world".into(),
        };
        let q = pose.rotation.quaternion();
        let mut want = header_bytes(0, 12, 34, "world");
        for v in [1.0f64, -2.0, 0.5, q.i, q.j, q.k, q.w] {
            want.extend(v.to_le_bytes());
        }
        assert_eq!(encode_pose_stamped(&header, &pose), want);
        let (h, p) = decode_pose_stamped(&want).unwrap();
        assert_eq!(h, header);
        assert!((p.translation.vector - pose.translation.vector).norm() < 1e-15);
        assert!(p.rotation.angle_to(&pose.rotation) < 1e-12);
    }

    #[test]
    fn tf_message_round_trip_and_size() {
        let t = |k: i32| TransformStamped {
            header: Header {
                stamp: Time { sec: k, nanosec: 9 },
                frame_id: "world".into(),
            },
            child_frame_id: format!("c{k}"),
            transform: Isometry3::translation(k as f64, 0.0, 1.0),
        };
        let tfs = vec![t(1), t(2)];
        let bytes = encode_tf_message(&tfs);
        // count + per transform: header 12 + "world" 9 + "cK" 6 + 56.
        assert_eq!(bytes.len(), 4 + 2 * (12 + 9 + 6 + 56));
        assert_eq!(decode_tf_message(&bytes).unwrap(), tfs);
        assert!(decode_tf_message(&bytes[..bytes.len() - 1]).is_err());
    }

    #[test]
    fn stamps_after_2038_and_absurd_counts_are_named() {
        let mut b = header_bytes(0, u32::MAX, 0, "");
        b.extend([0u8; 56]);
        let e = decode_pose_stamped(&b).unwrap_err();
        assert_eq!(e.field, "header.stamp.secs");
        let e = decode_tf_message(&u32::MAX.to_le_bytes()).unwrap_err();
        assert_eq!(e.field, "transforms");
    }

    #[test]
    fn schema_texts_name_every_type_they_use() {
        for (text, deps) in [
            (
                POINT_CLOUD2_SCHEMA,
                &["std_msgs/Header", "sensor_msgs/PointField"][..],
            ),
            (
                POSE_STAMPED_SCHEMA,
                &[
                    "std_msgs/Header",
                    "geometry_msgs/Pose",
                    "geometry_msgs/Point",
                    "geometry_msgs/Quaternion",
                ][..],
            ),
            (
                POSE_WITH_COVARIANCE_STAMPED_SCHEMA,
                &[
                    "std_msgs/Header",
                    "geometry_msgs/PoseWithCovariance",
                    "geometry_msgs/Pose",
                    "geometry_msgs/Point",
                    "geometry_msgs/Quaternion",
                ][..],
            ),
            (
                TF_MESSAGE_SCHEMA,
                &[
                    "geometry_msgs/TransformStamped",
                    "std_msgs/Header",
                    "geometry_msgs/Transform",
                    "geometry_msgs/Vector3",
                    "geometry_msgs/Quaternion",
                ][..],
            ),
        ] {
            let sections: Vec<&str> = text
                .lines()
                .filter_map(|l| l.strip_prefix("MSG: "))
                .collect();
            assert_eq!(sections, deps);
            let sep = "=".repeat(80);
            assert_eq!(text.matches(&sep).count(), deps.len());
        }
    }
}
