//! Round trips through our encoders and the schema texts.

use super::*;

// -----------------------------------------------------------------------------------------
// Round trips
// -----------------------------------------------------------------------------------------

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

    // Into the buffer of a larger cloud decoded before: the same cloud, none of the old points.
    let stale = vec![p(1.0, 2.0, 3.0); 1000];
    let c = decode_point_cloud2_reusing(&encode_point_cloud2(&header, &pts32, None), stale);
    assert_eq!(c.unwrap().points, want);

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
        "bool", "byte", "char", "float32", "float64", "int8", "uint8", "int16", "uint16", "int32",
        "uint32", "int64", "uint64", "string",
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
