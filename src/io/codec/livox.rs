//! Livox's own point message, `CustomMsg`, as `livox_ros_driver` (ROS 1) and
//! `livox_ros_driver2` (ROS 1 and ROS 2) publish it with `xfer_format` 1, and as every FAST-LIO
//! dataset records it:
//!
//! ```text
//! std_msgs/Header header   # stamp: the first point's time (the driver sets it from timebase)
//! uint64 timebase          # the first point's time, ns
//! uint32 point_num
//! uint8  lidar_id
//! uint8[3] rsvd
//! CustomPoint[] points     # uint32 offset_time (ns after timebase), float32 x, y, z (m),
//!                          # uint8 reflectivity, uint8 tag, uint8 line
//! ```
//!
//! A point is 19 bytes in ROS 1 (packed) and 20 in CDR (the next point's `offset_time` aligns
//! to 4). `offset_time` becomes the cloud's per-point times (relative to the header stamp, so a
//! header stamp that differs from `timebase` is allowed for), `reflectivity` its intensity, and
//! `tag` decides which points are kept ([`LivoxTags`]). Points at exactly (0, 0, 0) are Livox's
//! "no return" and are dropped, like non-finite ones, and so are points whose time is a glitch
//! (more than [`crate::io::point_time::POINT_TIME_BOUND_S`] from the cloud's median point time).

use nalgebra::Point3;

use super::cdr::{self, CdrReader};
use super::ros1::{self, Ros1Reader};
use super::{DecodeError, Header, PointCloud, WireRead};
use crate::io::point_time::{PointTimes, TimeConvention};

/// Bytes of one `CustomPoint` on the wire, packed (ROS 1).
const POINT_BYTES: usize = 19;

/// Whether a channel's schema is a Livox `CustomMsg`: `livox_ros_driver/CustomMsg`,
/// `livox_ros_driver2/msg/CustomMsg` and the like (any `livox…` package; `/msg/` optional).
pub fn is_custom_msg(schema_name: &str) -> bool {
    let name = schema_name.replace("/msg/", "/");
    name.strip_suffix("/CustomMsg")
        .is_some_and(|pkg| pkg.starts_with("livox") && !pkg.contains('/'))
}

/// Which Livox points are kept, by their `tag` byte (Livox's manuals: bits 0–1 the noise
/// confidence from the spatial position, 00 normal, 01 high, 10 moderate, 11 low; bits 2–3 from
/// the intensity, 00 normal, 01 noise; bits 4–5 the return number). `--livox-tags`; default
/// [`LivoxTags::DropNoise`].
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum LivoxTags {
    /// Drop the points tagged as noise with high or moderate confidence by their spatial position
    /// (bits 0–1 = 01 or 10) or as noise by their intensity (bits 2–3 = 01): rain, dust, fog
    /// and the stray returns at object edges. Low-confidence noise (11) is kept.
    #[default]
    #[serde(alias = "drop-noise")]
    DropNoise,
    /// Keep every point whatever its tag.
    #[serde(alias = "keep-all")]
    KeepAll,
    /// Keep returns 0 and 1 only (bits 4–5 = 00 or 01), whatever the noise bits, as FAST-LIO's
    /// Livox front end does.
    #[serde(alias = "first-returns")]
    FirstReturns,
}

impl LivoxTags {
    /// Whether a point with `tag` is kept.
    pub fn keeps(self, tag: u8) -> bool {
        match self {
            LivoxTags::KeepAll => true,
            LivoxTags::DropNoise => {
                let spatial = tag & 0b11;
                let intensity = (tag >> 2) & 0b11;
                spatial != 0b01 && spatial != 0b10 && intensity != 0b01
            }
            LivoxTags::FirstReturns => (tag >> 4) & 0b11 <= 1,
        }
    }
}

/// Decodes a ROS 1 (`ros1`) Livox `CustomMsg`, writing the points into `points` (cleared first).
///
/// # Errors
/// [`DecodeError`] naming the field for a truncated message or a point count that cannot fit.
pub fn decode_ros1_reusing(
    payload: &[u8],
    points: Vec<Point3<f64>>,
    tags: LivoxTags,
) -> Result<PointCloud, DecodeError> {
    let mut r = Ros1Reader::new(payload);
    let header = ros1::read_header(&mut r, "header.")?;
    let (timebase, n) = read_fixed(&mut r)?;
    let raw = r.bytes(n * POINT_BYTES, "points")?;
    Ok(decode_points(
        header,
        timebase,
        raw,
        n,
        POINT_BYTES,
        false,
        points,
        tags,
    ))
}

/// Decodes a CDR (`cdr`, ROS 2) Livox `CustomMsg`, writing the points into `points` (cleared
/// first). Big-endian CDR is read too.
///
/// # Errors
/// As [`decode_ros1_reusing`], and `encapsulation` for a message that is not plain CDR.
pub fn decode_cdr_reusing(
    payload: &[u8],
    points: Vec<Point3<f64>>,
    tags: LivoxTags,
) -> Result<PointCloud, DecodeError> {
    let mut r = CdrReader::new(payload)?;
    let header = cdr::read_header(&mut r, "header.")?;
    let (timebase, n) = read_fixed(&mut r)?;
    // Each point but the last is followed by one byte of padding (the next offset_time aligns
    // to 4; the sequence's count left the first one aligned).
    let stride = POINT_BYTES + 1;
    let raw = r.bytes((n * stride).saturating_sub(1), "points")?;
    Ok(decode_points(
        header,
        timebase,
        raw,
        n,
        stride,
        r.is_big_endian(),
        points,
        tags,
    ))
}

/// The header of a ROS 1 Livox `CustomMsg` and the points it holds (its `points` sequence's
/// count, checked against what remains of the message), read without decoding them: what a
/// cloud would take is known before it is decoded. `None` when the message does not say.
pub fn declared_points_ros1(payload: &[u8]) -> Option<(Header, u64)> {
    let mut r = Ros1Reader::new(payload);
    let header = ros1::read_header(&mut r, "header.").ok()?;
    let (_, n) = read_fixed(&mut r).ok()?;
    Some((header, n as u64))
}

/// [`declared_points_ros1`] for a CDR (ROS 2) Livox `CustomMsg`.
pub fn declared_points_cdr(payload: &[u8]) -> Option<(Header, u64)> {
    let mut r = CdrReader::new(payload).ok()?;
    let header = cdr::read_header(&mut r, "header.").ok()?;
    let (_, n) = read_fixed(&mut r).ok()?;
    Some((header, n as u64))
}

/// `timebase`, `point_num`, `lidar_id` and `rsvd`, then the points' count, checked against
/// what remains.
fn read_fixed<'a>(r: &mut impl WireRead<'a>) -> Result<(u64, usize), DecodeError> {
    let timebase = r.u64("timebase")?;
    let _point_num = r.u32("point_num")?;
    let _lidar_id = r.u8("lidar_id")?;
    r.bytes(3, "rsvd")?;
    let n = r.sequence_len("points", POINT_BYTES)?;
    Ok((timebase, n))
}

/// The cloud of `n` points laid out every `stride` bytes in `raw`.
#[allow(clippy::too_many_arguments)] // the wire layout's parts, each used once
fn decode_points(
    header: Header,
    timebase: u64,
    raw: &[u8],
    n: usize,
    stride: usize,
    big_endian: bool,
    mut points: Vec<Point3<f64>>,
    tags: LivoxTags,
) -> PointCloud {
    let u32_at = |b: &[u8]| {
        let b: [u8; 4] = b[..4].try_into().expect("4 bytes");
        if big_endian {
            u32::from_be_bytes(b)
        } else {
            u32::from_le_bytes(b)
        }
    };
    let f32_at = |b: &[u8]| f32::from_bits(u32_at(b));
    // Point times relative to the header stamp, which the driver sets from timebase (and which
    // may differ from it by rounding): offset_time counts from timebase.
    let base_s = (i128::from(timebase) - i128::from(header.stamp.to_ns())) as f64 * 1e-9;
    points.clear();
    points.reserve(n);
    let (mut intensity, mut seconds) = (Vec::with_capacity(n), Vec::with_capacity(n));
    let (mut non_finite, mut far, mut zero, mut tag_dropped) = (0, 0, 0, 0);
    for i in 0..n {
        let p = &raw[i * stride..i * stride + POINT_BYTES];
        let (x, y, z) = (f32_at(&p[4..]), f32_at(&p[8..]), f32_at(&p[12..]));
        let (reflectivity, tag) = (p[16], p[17]);
        if !(x.is_finite() && y.is_finite() && z.is_finite()) {
            non_finite += 1;
        } else if !super::within_bound(f64::from(x), f64::from(y), f64::from(z)) {
            far += 1;
        } else if x == 0.0 && y == 0.0 && z == 0.0 {
            zero += 1;
        } else if !tags.keeps(tag) {
            tag_dropped += 1;
        } else {
            points.push(Point3::new(f64::from(x), f64::from(y), f64::from(z)));
            intensity.push(f32::from(reflectivity));
            seconds.push(base_s + f64::from(u32_at(p)) * 1e-9);
        }
    }
    let mut cloud = PointCloud {
        header,
        points,
        intensity: Some(intensity),
        times: Some(PointTimes {
            field: "offset_time".to_string(),
            convention: TimeConvention::RelativeNs,
            seconds,
        }),
        width: u32::try_from(n).unwrap_or(u32::MAX),
        height: 1,
        num_dropped_non_finite: non_finite,
        num_dropped_far: far,
        num_dropped_zero: zero,
        num_dropped_tag: tag_dropped,
        num_dropped_time: 0,
    };
    cloud.drop_time_glitches();
    cloud
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::io::codec::WireWrite;
    use crate::io::codec::ros1::Ros1Writer;

    /// (offset_time, x, y, z, reflectivity, tag, line).
    type Pt = (u32, f32, f32, f32, u8, u8, u8);

    const POINTS: [Pt; 5] = [
        (0, 1.0, 2.0, 3.0, 10, 0x00, 0),
        (1000, 0.0, 0.0, 0.0, 0, 0x00, 1),  // no return
        (2000, 4.0, 5.0, 6.0, 20, 0x01, 2), // high-confidence noise
        (3000, f32::NAN, 1.0, 1.0, 30, 0x00, 3),
        (99_000_000, -7.5, 8.25, -9.0, 255, 0x13, 4), // low-confidence noise, return 1
    ];

    /// Messages are written field by field after the official definition (CDR aligning each
    /// field), independently of the decoder's stride arithmetic.
    fn ros1_message(stamp: (u32, u32), timebase: u64, pts: &[Pt]) -> Vec<u8> {
        let mut w = Ros1Writer::with_capacity(256);
        w.u32(7); // seq
        w.u32(stamp.0);
        w.u32(stamp.1);
        w.string("livox_frame");
        w.raw(&timebase.to_le_bytes());
        w.u32(pts.len() as u32);
        w.u8(3); // lidar_id
        w.raw(&[0, 0, 0]);
        w.u32(pts.len() as u32);
        for &(t, x, y, z, r, tag, line) in pts {
            w.u32(t);
            for v in [x, y, z] {
                w.raw(&v.to_le_bytes());
            }
            w.raw(&[r, tag, line]);
        }
        w.finish()
    }

    /// CDR: alignment is counted from the end of the 4-byte encapsulation header.
    fn cdr_message(stamp: (i32, u32), timebase: u64, pts: &[Pt]) -> Vec<u8> {
        let mut b: Vec<u8> = vec![0, 1, 0, 0];
        let align = |b: &mut Vec<u8>, n: usize| {
            while !(b.len() - 4).is_multiple_of(n) {
                b.push(0);
            }
        };
        b.extend(stamp.0.to_le_bytes());
        b.extend(stamp.1.to_le_bytes());
        let frame = b"livox_frame\0";
        b.extend((frame.len() as u32).to_le_bytes());
        b.extend(frame);
        align(&mut b, 8);
        b.extend(timebase.to_le_bytes());
        b.extend((pts.len() as u32).to_le_bytes());
        b.push(3);
        b.extend([0, 0, 0]);
        align(&mut b, 4);
        b.extend((pts.len() as u32).to_le_bytes());
        for &(t, x, y, z, r, tag, line) in pts {
            align(&mut b, 4);
            b.extend(t.to_le_bytes());
            for v in [x, y, z] {
                b.extend(v.to_le_bytes());
            }
            b.extend([r, tag, line]);
        }
        b
    }

    fn check(c: &PointCloud, stamp_ns: i64, timebase: u64, tags: LivoxTags) {
        assert_eq!(c.header.stamp.to_ns(), stamp_ns);
        assert_eq!(c.header.frame_id, "livox_frame");
        assert_eq!((c.width, c.height), (5, 1));
        assert_eq!((c.num_dropped_non_finite, c.num_dropped_zero), (1, 1));
        let kept: Vec<&Pt> = POINTS
            .iter()
            .filter(|p| p.1.is_finite() && (p.1, p.2, p.3) != (0.0, 0.0, 0.0))
            .filter(|p| tags.keeps(p.5))
            .collect();
        assert_eq!(c.num_dropped_tag, 3 - kept.len());
        assert_eq!(c.points.len(), kept.len());
        let times = c.times.as_ref().unwrap();
        for (i, p) in kept.iter().enumerate() {
            let want = Point3::new(f64::from(p.1), f64::from(p.2), f64::from(p.3));
            assert_eq!(c.points[i], want);
            assert_eq!(c.intensity.as_ref().unwrap()[i], f32::from(p.4));
            let t_ns = timebase as i64 + i64::from(p.0) - stamp_ns;
            assert!((times.seconds[i] - t_ns as f64 * 1e-9).abs() < 1e-15);
        }
    }

    /// The count read before decoding is the decoded width, with the same header.
    #[test]
    fn declared_points_are_the_decoded_width() {
        let ros1 = ros1_message((5, 6), 5_000_000_006, &POINTS);
        let cdr = cdr_message((5, 6), 5_000_000_006, &POINTS);
        let d = decode_ros1_reusing(&ros1, Vec::new(), LivoxTags::KeepAll).unwrap();
        assert_eq!(declared_points_ros1(&ros1), Some((d.header, 5)));
        let d = decode_cdr_reusing(&cdr, Vec::new(), LivoxTags::KeepAll).unwrap();
        assert_eq!(declared_points_cdr(&cdr), Some((d.header, 5)));
        assert_eq!(declared_points_ros1(&ros1[..ros1.len() - 1]), None);
    }

    #[test]
    fn ros1_and_cdr_messages_decode_to_the_points_written() {
        // The header stamp 100 ns after timebase, as the ROS 1 driver's double rounding leaves it.
        let timebase = 1_700_000_000_123_456_789u64;
        let stamp_ns = timebase as i64 + 100;
        let (sec, nsec) = (
            (stamp_ns / 1_000_000_000) as u32,
            (stamp_ns % 1_000_000_000) as u32,
        );
        for tags in [
            LivoxTags::DropNoise,
            LivoxTags::KeepAll,
            LivoxTags::FirstReturns,
        ] {
            let m = ros1_message((sec, nsec), timebase, &POINTS);
            check(
                &decode_ros1_reusing(&m, Vec::new(), tags).unwrap(),
                stamp_ns,
                timebase,
                tags,
            );
            let m = cdr_message((sec as i32, nsec), timebase, &POINTS);
            check(
                &decode_cdr_reusing(&m, Vec::new(), tags).unwrap(),
                stamp_ns,
                timebase,
                tags,
            );
        }
    }

    /// An `offset_time` glitch (4 s into a 100 ms sweep) is dropped with its intensity and
    /// counted; a `timebase` 10 s off the stamp drops nothing but makes the cloud undeskewable.
    #[test]
    fn time_glitches_are_dropped_and_counted() {
        let pts: [Pt; 4] = [
            (0, 1.0, 0.0, 0.0, 1, 0, 0),
            (50_000_000, 2.0, 0.0, 0.0, 2, 0, 0),
            (4_000_000_000, 3.0, 0.0, 0.0, 3, 0, 0),
            (99_000_000, 4.0, 0.0, 0.0, 4, 0, 0),
        ];
        let stamp = 1_700_000_000u64 * 1_000_000_000;
        let m = ros1_message((1_700_000_000, 0), stamp, &pts);
        let c = decode_ros1_reusing(&m, Vec::new(), LivoxTags::KeepAll).unwrap();
        assert_eq!(c.num_dropped_time, 1);
        let xs: Vec<f64> = c.points.iter().map(|p| p.x).collect();
        assert_eq!(xs, [1.0, 2.0, 4.0]);
        assert_eq!(c.intensity.unwrap(), [1.0, 2.0, 4.0]);
        let times = c.times.unwrap();
        assert_eq!(times.seconds.len(), 3);
        assert!(times.deskewable());
        let m = ros1_message((1_700_000_000, 0), stamp + 10_000_000_000, &pts[..2]);
        let c = decode_ros1_reusing(&m, Vec::new(), LivoxTags::KeepAll).unwrap();
        assert_eq!((c.num_dropped_time, c.points.len()), (0, 2));
        assert!(!c.times.unwrap().deskewable());
    }

    #[test]
    fn tags_follow_the_livox_bit_layout() {
        let drop_noise: Vec<u8> = (0..=255u8)
            .filter(|&t| LivoxTags::DropNoise.keeps(t))
            .collect();
        // Spatial 00 or 11, intensity not 01: 2 × 3 of the 16 low-nibble values, × 16.
        assert_eq!(drop_noise.len(), 6 * 16);
        assert!(LivoxTags::DropNoise.keeps(0x00) && LivoxTags::DropNoise.keeps(0x03));
        assert!(!LivoxTags::DropNoise.keeps(0x01) && !LivoxTags::DropNoise.keeps(0x02));
        assert!(!LivoxTags::DropNoise.keeps(0x04) && LivoxTags::DropNoise.keeps(0x08));
        assert!(LivoxTags::FirstReturns.keeps(0x10) && !LivoxTags::FirstReturns.keeps(0x20));
        assert!((0..=255u8).all(|t| LivoxTags::KeepAll.keeps(t)));
    }

    #[test]
    fn truncated_messages_and_impossible_counts_name_the_field() {
        let m = ros1_message((1, 0), 1_000_000_000, &POINTS);
        for cut in [10, 40, m.len() - 1] {
            let e = decode_ros1_reusing(&m[..cut], Vec::new(), LivoxTags::default()).unwrap_err();
            assert!(!e.field.is_empty(), "{e}");
        }
        let mut m = cdr_message((1, 0), 1_000_000_000, &POINTS);
        let e = decode_cdr_reusing(&m[..m.len() - 1], Vec::new(), LivoxTags::default());
        assert_eq!(e.unwrap_err().field, "points");
        // The count claims 2^31 points: refused before any allocation.
        let count_at = m.len() - (5 * 20 - 1) - 4;
        m[count_at..count_at + 4].copy_from_slice(&(1u32 << 31).to_le_bytes());
        let e = decode_cdr_reusing(&m, Vec::new(), LivoxTags::default()).unwrap_err();
        assert_eq!(e.field, "points");
        assert!(is_custom_msg("livox_ros_driver/CustomMsg"));
        assert!(is_custom_msg("livox_ros_driver2/msg/CustomMsg"));
        assert!(!is_custom_msg("sensor_msgs/msg/PointCloud2"));
        assert!(!is_custom_msg("my_pkg/CustomMsg"));
    }
}
