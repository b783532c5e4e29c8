//! Entry points of the fuzz targets (`fuzz/`, cargo-fuzz) and of their replay in `cargo test`
//! (`tests/fuzz_replay.rs`): one function per input surface, taking arbitrary bytes. Each must
//! return — an `Err` is the expected answer to bad input — and never panic, abort, hang or
//! allocate beyond what the input can justify; a fuzzer flags any of those as a crash.
//!
//! [`TARGETS`] lists them by the names of their fuzz targets and corpus folders.

use std::path::{Path, PathBuf};

use crate::io::codec::{self, cdr, foxglove, ros1};
use crate::io::{cloud_file, pose_file};
use crate::odometry::OdometryConfig;
use crate::pipeline::PairConfig;
use crate::register::{RegisterOptions, register_log};

mod hostile;
mod small_bag;
pub use hostile::{
    TIME_GLITCHES, compressed_bag_metadata, glitched_times, lz4_zero_chunk, lz4_zeros,
    message_mode_file, timed_cloud_cdr, with_first_chunk, zstd_zero_chunk, zstd_zeros,
};
pub use small_bag::{ChunkCompression, small_bag};

/// A fuzzed file surface: name (fuzz target and corpus folder) and entry point.
pub type Target = (&'static str, fn(&[u8]));

/// Every fuzz target.
pub const TARGETS: &[Target] = &[
    ("point_cloud2", point_cloud2),
    ("foxglove_point_cloud", foxglove_point_cloud),
    ("pose_messages", pose_messages),
    ("mcap_records", mcap_records),
    ("register_input", register_input),
    ("cloud_files", cloud_files),
    ("pose_files", pose_files),
    ("ros1_messages", ros1_messages),
    ("ros1_bag", ros1_bag),
    ("rosbag2_metadata", rosbag2_metadata),
    ("rosbag2_compressed", rosbag2_compressed),
];

/// Whether `c` holds what a decoder may hand on: finite points within
/// [`codec::MAX_COORDINATE_M`], and per-point times (one per point) either all finite (the
/// glitches dropped) or none (a field without a time, which deskews nothing).
fn decoded_cloud_is_sound(c: &codec::PointCloud) -> bool {
    let points = c.points.iter().all(|p| {
        p.coords
            .iter()
            .all(|v| v.is_finite() && v.abs() < codec::MAX_COORDINATE_M)
    });
    let times = c.times.as_ref().is_none_or(|t| {
        t.seconds.len() == c.points.len()
            && (t.seconds.iter().all(|s| s.is_finite()) || t.seconds.iter().all(|s| !s.is_finite()))
    });
    points && times
}

/// `sensor_msgs/msg/PointCloud2` (cdr) decoding, and Livox `CustomMsg` in cdr and ros1; a
/// decoded cloud holds only finite points.
pub fn point_cloud2(data: &[u8]) {
    use crate::io::codec::livox::{self, LivoxTags};
    for (c, declared) in [
        (
            livox::decode_cdr_reusing(data, Vec::new(), LivoxTags::KeepAll),
            livox::declared_points_cdr(data),
        ),
        (
            livox::decode_ros1_reusing(data, Vec::new(), LivoxTags::KeepAll),
            livox::declared_points_ros1(data),
        ),
    ] {
        let Ok(c) = c else { continue };
        assert_eq!(declared.map(|d| d.1), Some(u64::from(c.width)));
        assert!(decoded_cloud_is_sound(&c));
        assert_eq!(c.times.map(|t| t.seconds.len()), Some(c.points.len()));
    }
    if let Ok(c) = cdr::decode_point_cloud2(data) {
        assert!(decoded_cloud_is_sound(&c));
    }
}

/// `foxglove.PointCloud` (protobuf) decoding, and the point count read before decoding.
pub fn foxglove_point_cloud(data: &[u8]) {
    if let Ok(c) = foxglove::decode_foxglove_point_cloud(data) {
        assert!(decoded_cloud_is_sound(&c));
        // What `register` checks against --max-points before decoding is what decodes.
        if c.width > 0 {
            assert_eq!(
                foxglove::point_cloud_declared_points(data).map(|d| d.1),
                Some(u64::from(c.width))
            );
        }
    }
}

/// `geometry_msgs/msg/PoseStamped` and `tf2_msgs/msg/TFMessage` (cdr) decoding.
pub fn pose_messages(data: &[u8]) {
    let _ = cdr::decode_pose_stamped(data);
    let _ = cdr::decode_tf_message(data);
}

/// ROS 1 `sensor_msgs/PointCloud2`, `geometry_msgs/PoseStamped` and `tf2_msgs/TFMessage`
/// decoding.
pub fn ros1_messages(data: &[u8]) {
    if let Ok(c) = ros1::decode_point_cloud2(data) {
        assert!(decoded_cloud_is_sound(&c));
    }
    let _ = ros1::decode_pose_stamped(data);
    let _ = ros1::decode_tf_message(data);
}

/// A ROS 1 bag: opened (catalogue from the index, or a scan), every message read, then the
/// whole `mireg register` path on it.
pub fn ros1_bag(data: &[u8]) {
    let path = scratch("in.bag");
    write(&path, data);
    let skip = crate::io::damage::ReadPolicy {
        strict: false,
        skip_corrupt: true,
    };
    if let Ok(bag) = crate::io::bag::ros1::Bag::open_with(&path, skip) {
        let _ = bag.for_each_message(|_, _, _| Ok(std::ops::ControlFlow::Continue(())));
    }
    if let Ok(bag) = crate::io::bag::ros1::Bag::open(&path) {
        let _ = bag.catalog();
        let _ = bag.for_each_message(|_, _, _| Ok(std::ops::ControlFlow::Continue(())));
    }
    register_file("in.bag", data);
}

/// The `metadata.yaml` of a ROS 2 bag directory.
pub fn rosbag2_metadata(data: &[u8]) {
    if let Ok(text) = std::str::from_utf8(data) {
        let _ = crate::io::bag::rosbag2::parse_metadata(text);
    }
}

/// A zstd-compressed ROS 2 bag directory of MCAP storage, one file: the first byte chooses the
/// mode (even: `file`, the rest the compressed file; odd: `message`, the rest the MCAP file of
/// compressed messages), then the whole `mireg register` path on the directory. Decompression
/// bombs in either mode end in an error naming the input, within the expansion limit.
pub fn rosbag2_compressed(data: &[u8]) {
    let Some((&mode, file)) = data.split_first() else {
        return;
    };
    let bag = scratch("bag");
    let _ = std::fs::remove_dir_all(&bag);
    std::fs::create_dir(&bag).expect("scratch directory made");
    let (metadata, name) = compressed_bag_metadata(mode % 2 == 0);
    write(&bag.join("metadata.yaml"), metadata.as_bytes());
    write(&bag.join(name), file);
    register_path(&bag);
}

/// A scratch file for inputs that are read from a path: in a temporary directory of this
/// process, one per thread (the replay test runs targets in parallel).
fn scratch(name: &str) -> PathBuf {
    thread_local! {
        static DIR: tempfile::TempDir = tempfile::tempdir().expect("temporary directory");
    }
    DIR.with(|d| d.path().join(name))
}

fn write(path: &Path, data: &[u8]) {
    std::fs::write(path, data).expect("scratch file written");
}

/// MCAP as `mireg evaluate` and `export` read it: the catalogue (summary, or a scan without
/// one), every record in file order, and the pose and statistics topics; and as `register`
/// reads a damaged log (a cut salvaged, corrupt chunks skipped).
pub fn mcap_records(data: &[u8]) {
    let path = scratch("in.mcap");
    write(&path, data);
    let _ = crate::io::mcap::log::list_channels(&path);
    let _ = crate::io::mcap::read::for_each_record(&path, |_| Ok(()));
    // As `register` reads a damaged log: salvaging a cut, skipping corrupt chunks.
    let salvage = crate::io::damage::ReadPolicy {
        strict: false,
        skip_corrupt: true,
    };
    let _ = crate::io::mcap::log::InputCatalog::read_with(&path, salvage);
    let _ = crate::io::mcap::read::for_each_record_with(&path, salvage, |_| {
        Ok(std::ops::ControlFlow::Continue(()))
    });
    let _ = crate::io::poses::read_mcap_pose_topic(&path, "/mireg/pose");
    let _ = crate::io::poses::read_frame_flags(&path, "/mireg/stats");
}

/// The whole `mireg register` path: catalogue, chunk index, pass-through with validation, cloud
/// decoding and registration, output. On error no output may be left behind.
pub fn register_input(data: &[u8]) {
    register_file("in.mcap", data);
}

/// `mireg register` on `data` saved as `name`; on error no output may be left behind.
fn register_file(name: &str, data: &[u8]) {
    let input = scratch(name);
    write(&input, data);
    register_path(&input);
}

/// `mireg register` on the log at `input`; on error no output may be left behind.
fn register_path(input: &Path) {
    let output = scratch("out.mcap");
    let _ = std::fs::remove_file(&output);
    let config = OdometryConfig {
        pair: PairConfig {
            voxel_size_m: 0.05,
            max_hypotheses: 1000,
            ..Default::default()
        },
        ..Default::default()
    };
    let opts = RegisterOptions {
        force: true,
        // Small bounds: a fuzzer's inputs are small, and its time is better spent elsewhere.
        max_points_per_cloud: 20_000,
        ..RegisterOptions::new(input, &output, config)
    };
    if register_log(&opts).is_err() {
        assert!(!output.exists(), "an error left an output behind");
    }
}

/// The point cloud files of `mireg pair`: PLY, PCD, NumPy `.npy`, KITTI `.bin`.
pub fn cloud_files(data: &[u8]) {
    let p = Path::new("fuzz");
    let _ = cloud_file::parse_ply(data, p);
    let _ = cloud_file::parse_pcd(data, p);
    let _ = cloud_file::parse_npy(data, p);
    let _ = cloud_file::parse_kitti_bin(data, p);
}

/// The pose files of `mireg pair --gt` and `mireg evaluate --gt`: 4×4 matrices, Redwood `.log`,
/// Stanford `bun.conf`, TUM, KITTI.
pub fn pose_files(data: &[u8]) {
    let Ok(text) = std::str::from_utf8(data) else {
        return;
    };
    let p = Path::new("fuzz");
    let _ = pose_file::parse_matrix4(text, p);
    let _ = pose_file::parse_log(text, p);
    let _ = pose_file::parse_bunny_conf(text, p);
    let _ = crate::trajectory::parse_tum(text, p);
    let _ = crate::trajectory::parse_kitti(text, p);
}

/// The room of [`small_log`] and [`small_bag`]: walls and four boxes, ≈1 200 points (metres).
fn small_scene() -> Vec<nalgebra::Point3<f64>> {
    use nalgebra::{Point3, Vector3};
    use rand::{RngExt, SeedableRng};
    let mut rng = rand_pcg::Pcg64Mcg::seed_from_u64(5);
    let mut world = Vec::new();
    for _ in 0..700 {
        let (u, v): (f64, f64) = (rng.random_range(-2.0..2.0), rng.random_range(0.0..2.0));
        world.push(match rng.random_range(0..3u32) {
            0 => Point3::new(u, v - 1.0, 3.0),
            1 => Point3::new(-2.0, v - 1.0, u + 3.0),
            _ => Point3::new(u, 1.0, v * 1.5 + 1.0),
        });
    }
    for k in 0..4 {
        let c = Vector3::new(
            rng.random_range(-1.5..1.5),
            rng.random_range(-0.5..0.5),
            rng.random_range(1.5..2.8),
        );
        for _ in 0..120 {
            let d = Vector3::new(
                rng.random_range(-1.0..1.0),
                rng.random_range(-1.0..1.0),
                rng.random_range(-1.0..1.0),
            );
            let mut e: Vector3<f64> = d * 0.3;
            let axis = (k + rng.random_range(0..3usize)) % 3;
            e[axis] = 0.3 * e[axis].signum();
            world.push(Point3::from(c + e));
        }
    }
    world
}

/// The camera of [`small_log`] and [`small_bag`] at frame `k`: 4 cm and 1.1° per frame.
fn small_camera(k: usize) -> nalgebra::Isometry3<f64> {
    use nalgebra::{Isometry3, Translation3, UnitQuaternion};
    Isometry3::from_parts(
        Translation3::new(0.04 * k as f64, 0.0, 0.01 * k as f64),
        UnitQuaternion::from_euler_angles(0.0, 0.02 * k as f64, 0.0),
    )
}

/// A small valid `mireg register` input, the seed of the MCAP corpora and of the hostile-input
/// suite: `frames` clouds of a room with boxes (≈1 200 points, voxel 0.05 m works) on
/// `/points` (ROS 2 PointCloud2), seen from a camera moving 4 cm and 1.1° per frame 0.1 s apart,
/// its reference poses on `/ground_truth/pose`, a JSON channel, a metadata record and an
/// attachment. `options` sets compression, chunking and indexes.
pub fn small_log(frames: usize, options: mcap::WriteOptions) -> Vec<u8> {
    small_log_with(frames, options, &|_, header, points| {
        cdr::encode_point_cloud2(header, points, None)
    })
}

/// A frame's cloud message of [`small_log_with`], from the frame's index, the cloud's header
/// and the room's points in the camera frame (metres).
pub type CloudWriter<'a> = &'a dyn Fn(usize, &codec::Header, &[nalgebra::Point3<f64>]) -> Vec<u8>;

/// [`small_log`] with each frame's cloud message written by `cloud` (extra fields or points, a
/// hostile message), on the same schema (`sensor_msgs/msg/PointCloud2`).
pub fn small_log_with(frames: usize, options: mcap::WriteOptions, cloud: CloudWriter) -> Vec<u8> {
    use mcap::records::MessageHeader;
    use nalgebra::Point3;
    use std::collections::BTreeMap;

    let world = small_scene();
    let mut out = std::io::Cursor::new(Vec::new());
    let mut w = options.profile("ros2").create(&mut out).expect("writer");
    let cloud_schema = w
        .add_schema(
            cdr::POINT_CLOUD2_SCHEMA_NAME,
            cdr::SCHEMA_ENCODING,
            cdr::POINT_CLOUD2_SCHEMA.as_bytes(),
        )
        .expect("schema");
    let clouds = w
        .add_channel(cloud_schema, "/points", "cdr", &BTreeMap::new())
        .expect("channel");
    let pose_schema = w
        .add_schema(
            cdr::POSE_STAMPED_SCHEMA_NAME,
            cdr::SCHEMA_ENCODING,
            cdr::POSE_STAMPED_SCHEMA.as_bytes(),
        )
        .expect("schema");
    let poses = w
        .add_channel(pose_schema, "/ground_truth/pose", "cdr", &BTreeMap::new())
        .expect("channel");
    let json = w
        .add_schema("Note", "jsonschema", br#"{"type":"object"}"#)
        .expect("schema");
    let notes = w
        .add_channel(json, "/notes", "json", &BTreeMap::new())
        .expect("channel");
    w.write_metadata(&mcap::records::Metadata {
        name: "robot".into(),
        metadata: BTreeMap::from([("id".into(), "r2".into())]),
    })
    .expect("metadata");
    w.attach(&mcap::Attachment {
        log_time: 1,
        create_time: 2,
        name: "calib.yaml".into(),
        media_type: "application/yaml".into(),
        data: std::borrow::Cow::Borrowed(b"fx: 525\n"),
    })
    .expect("attachment");
    let t0 = 1_700_000_000_000_000_000u64;
    for k in 0..frames {
        let t = t0 + k as u64 * 100_000_000;
        let world_from_camera = small_camera(k);
        let header = codec::Header {
            stamp: codec::Time::from_ns(t as i64).expect("in range"),
            frame_id: "camera".into(),
        };
        let camera_from_world = world_from_camera.inverse();
        let pts: Vec<Point3<f64>> = world.iter().map(|p| camera_from_world * p).collect();
        let m = |channel_id, sequence| MessageHeader {
            channel_id,
            sequence,
            log_time: t,
            publish_time: t,
        };
        w.write_to_known_channel(&m(clouds, k as u32), &cloud(k, &header, &pts))
            .expect("cloud");
        let reference = codec::Header {
            frame_id: "world".into(),
            ..header
        };
        let pose = cdr::encode_pose_stamped(&reference, &world_from_camera);
        w.write_to_known_channel(&m(poses, k as u32), &pose)
            .expect("pose");
        let note = format!(r#"{{"k":{k}}}"#);
        w.write_to_known_channel(&m(notes, k as u32), note.as_bytes())
            .expect("note");
    }
    w.finish().expect("finish");
    drop(w);
    out.into_inner()
}

/// A small `foxglove.PointCloud` (protobuf): three points, FLOAT32 x, y, z at offsets 0, 4, 8.
pub fn foxglove_seed_cloud() -> Vec<u8> {
    use nalgebra::Point3;
    foxglove_seed_cloud_of(&[
        Point3::new(1.0, 2.0, 3.0),
        Point3::new(-1.0, 0.5, 2.0),
        Point3::new(0.0, 0.0, 1.0),
    ])
}

/// A `foxglove.PointCloud` (protobuf) of `points` (metres, written as FLOAT32 x, y, z at offsets
/// 0, 4, 8), frame `lidar`, no pose.
pub fn foxglove_seed_cloud_of(points: &[nalgebra::Point3<f64>]) -> Vec<u8> {
    use ::foxglove::schemas::packed_element_field::NumericType;
    use ::foxglove::schemas::{PackedElementField, PointCloud, Timestamp};
    use prost::Message;
    let field = |name: &str, offset| PackedElementField {
        name: name.into(),
        offset,
        r#type: NumericType::Float32 as i32,
    };
    let data: Vec<u8> = points
        .iter()
        .flat_map(|p| p.coords.iter().map(|&v| v as f32).collect::<Vec<_>>())
        .flat_map(|v| v.to_le_bytes())
        .collect();
    PointCloud {
        timestamp: Some(Timestamp::new(1_700_000_000, 5)),
        frame_id: "lidar".into(),
        pose: None,
        point_stride: 12,
        fields: vec![field("x", 0), field("y", 4), field("z", 8)],
        data: data.into(),
    }
    .encode_to_vec()
}
