//! Tests of the CDR codec against an independent, test-only byte builder.

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
                let c = decode_point_cloud2(&bytes)
                    .unwrap_or_else(|e| panic!("dt {dt} cdr_be {big_cdr} data_be {big_data}: {e}"));
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
                0.5 * row as f64 + 0.25,
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
        let c =
            decode_point_cloud2(&hand_cloud(&xyz_cloud(&pts, dt, false, false))).expect("valid");
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

mod round_trip;
