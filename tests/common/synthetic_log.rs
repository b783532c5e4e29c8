//! A synthetic log with known motion for the integration tests: a room with boxes and spheres
//! seen from `world_from_camera(k)` (frame k at log time t0 + k · 0.1 s) on `/sensor/points`,
//! plus unrelated channels, a metadata record and an attachment.

#![allow(dead_code)]

use std::collections::BTreeMap;
use std::path::Path;

use mcap::records::MessageHeader;
use mireg::io::codec::{Header, Time, cdr};
use nalgebra::{Isometry3, Point3, Translation3, UnitQuaternion, Vector3};
use rand::{RngExt, SeedableRng};
use rand_distr::Distribution;

/// A room with boxes and spheres: enough structure for FPFH.
pub fn scene(seed: u64) -> Vec<Point3<f64>> {
    let mut rng = rand_pcg::Pcg64Mcg::seed_from_u64(seed);
    let mut pts = Vec::new();
    for _ in 0..6000 {
        let (u, v): (f64, f64) = (rng.random_range(-4.0..4.0), rng.random_range(0.0..3.0));
        match rng.random_range(0..3u32) {
            0 => pts.push(Point3::new(u, v - 1.5, 4.0)), // back wall
            1 => pts.push(Point3::new(-4.0, v - 1.5, u + 4.0)), // left wall
            _ => pts.push(Point3::new(u, 1.5, v * 2.5)), // floor (y down)
        }
    }
    add_spheres_and_boxes(&mut rng, &mut pts, 2.0..7.0, 500);
    pts
}

/// Appends 8 objects to `pts`, alternately a sphere and a box of radius (half-edge) 0.2–0.6 m,
/// centred at x ∈ [−3, 3), y ∈ [−1, 1.2), z ∈ `z`, each of `points_per_object` surface points.
pub fn add_spheres_and_boxes(
    rng: &mut rand_pcg::Pcg64Mcg,
    pts: &mut Vec<Point3<f64>>,
    z: std::ops::Range<f64>,
    points_per_object: usize,
) {
    for k in 0..8 {
        let c = Vector3::new(
            rng.random_range(-3.0..3.0),
            rng.random_range(-1.0..1.2),
            rng.random_range(z.clone()),
        );
        let r = rng.random_range(0.2..0.6);
        for _ in 0..points_per_object {
            let d = Vector3::new(
                rng.random_range(-1.0..1.0),
                rng.random_range(-1.0..1.0),
                rng.random_range(-1.0..1.0),
            );
            if k % 2 == 0 {
                let u: [f64; 3] = rand_distr::UnitSphere.sample(rng);
                pts.push(Point3::from(c + Vector3::from(u) * r)); // sphere
            } else {
                let mut e = d * r;
                let axis = rng.random_range(0..3usize);
                e[axis] = r * e[axis].signum(); // box face
                pts.push(Point3::from(c + e));
            }
        }
    }
}

pub fn world_from_camera(k: usize) -> Isometry3<f64> {
    let k = k as f64;
    Isometry3::from_parts(
        Translation3::new(0.08 * k, -0.02 * k, 0.05 * k),
        UnitQuaternion::from_euler_angles(0.01 * k, 0.04 * k, -0.02 * k),
    )
}

/// The synthetic log with every option: file order, chunking and writer options.
pub fn write_log_full(
    path: &Path,
    order: &[usize],
    frames_per_chunk: Option<usize>,
    opts: impl FnOnce(mcap::WriteOptions) -> mcap::WriteOptions,
) {
    let world = scene(1);
    let file = std::io::BufWriter::new(std::fs::File::create(path).unwrap());
    let mut w = opts(mcap::WriteOptions::new().profile("ros2"))
        .create(file)
        .unwrap();
    let cloud_schema = w
        .add_schema(
            cdr::POINT_CLOUD2_SCHEMA_NAME,
            "ros2msg",
            cdr::POINT_CLOUD2_SCHEMA.as_bytes(),
        )
        .unwrap();
    let clouds = w
        .add_channel(cloud_schema, "/sensor/points", "cdr", &BTreeMap::new())
        .unwrap();
    let json_schema = w
        .add_schema("Note", "jsonschema", br#"{"type":"object"}"#)
        .unwrap();
    let notes = w
        .add_channel(
            json_schema,
            "/notes",
            "json",
            &BTreeMap::from([("k".into(), "v".into())]),
        )
        .unwrap();
    let raw = w
        .add_channel(0, "/raw", "application/octet-stream", &BTreeMap::new())
        .unwrap();
    w.write_metadata(&mcap::records::Metadata {
        name: "robot".into(),
        metadata: BTreeMap::from([("id".into(), "r2".into())]),
    })
    .unwrap();
    w.attach(&mcap::Attachment {
        log_time: 5,
        create_time: 6,
        name: "calib.yaml".into(),
        media_type: "application/yaml".into(),
        data: std::borrow::Cow::Borrowed(b"fx: 525\n"),
    })
    .unwrap();
    let t0 = 1_700_000_000_000_000_000u64;
    for (i, &k) in order.iter().enumerate() {
        if frames_per_chunk.is_some_and(|n| i > 0 && i % n == 0) {
            w.flush().unwrap();
        }
        let t = t0 + k as u64 * 100_000_000;
        let cam_from_world = world_from_camera(k).inverse();
        let pts: Vec<Point3<f64>> = world.iter().map(|p| cam_from_world * p).collect();
        let header = Header {
            stamp: Time::from_ns(t as i64).unwrap(),
            frame_id: "lidar".into(),
        };
        let data = cdr::encode_point_cloud2(&header, &pts, None);
        w.write_to_known_channel(
            &MessageHeader {
                channel_id: clouds,
                sequence: k as u32,
                log_time: t,
                publish_time: t + 1,
            },
            &data,
        )
        .unwrap();
        let note = format!(r#"{{"k":{k}}}"#);
        w.write_to_known_channel(
            &MessageHeader {
                channel_id: notes,
                sequence: k as u32,
                log_time: t + 5,
                publish_time: t + 5,
            },
            note.as_bytes(),
        )
        .unwrap();
        w.write_to_known_channel(
            &MessageHeader {
                channel_id: raw,
                sequence: 7,
                log_time: t + 9,
                publish_time: t,
            },
            &[k as u8, 0, 255],
        )
        .unwrap();
    }
    w.finish().unwrap();
}
