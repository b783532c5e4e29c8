//! Writes the seed corpora of the fuzz targets into `fuzz/corpus/TARGET/` (committed; replayed
//! by `cargo test`, see tests/fuzz_replay.rs): real messages of the seed log
//! ([`mireg::fuzzing::small_log`]) and small valid files of every format the targets read.
//!
//! `cargo run --example make_fuzz_corpus` (from the repository root).

use std::path::Path;

use mcap::records::Record;
use mireg::fuzzing::{ChunkCompression, small_bag, small_log};
use mireg::io::codec::{self, cdr, ros1};
use nalgebra::{Isometry3, Point3, Translation3, UnitQuaternion};

fn put(target: &str, name: &str, bytes: &[u8]) {
    let dir = Path::new("fuzz/corpus").join(target);
    std::fs::create_dir_all(&dir).expect("corpus folder");
    std::fs::write(dir.join(name), bytes).expect("seed written");
}

fn main() {
    let chunked = |c| {
        mcap::WriteOptions::new()
            .chunk_size(Some(4 << 10))
            .compression(c)
    };
    let logs = [
        (
            "zstd.mcap",
            small_log(2, chunked(Some(mcap::Compression::Zstd))),
        ),
        (
            "lz4.mcap",
            small_log(2, chunked(Some(mcap::Compression::Lz4))),
        ),
        ("plain.mcap", small_log(2, chunked(None))),
        (
            "unchunked.mcap",
            small_log(2, mcap::WriteOptions::new().use_chunks(false)),
        ),
    ];
    for (name, bytes) in &logs {
        put("mcap_records", name, bytes);
        put("register_input", name, bytes);
    }
    message_seeds(&logs[2].1);
    file_seeds();
    bag_seeds();
    bomb_seeds();
    glitch_seeds();
    println!("corpus written to fuzz/corpus/");
}

/// Real messages of the seed log `plain` (one of each kind), and small messages of each kind.
fn message_seeds(plain: &[u8]) {
    let dir = tempfile::tempdir().expect("temporary directory");
    let path = dir.path().join("seed.mcap");
    std::fs::write(&path, plain).expect("seed log");
    let mut topics = std::collections::BTreeMap::new();
    let mut seen = std::collections::BTreeSet::new();
    mireg::io::mcap::read::for_each_record(&path, |r| {
        match r {
            Record::Channel(c) => {
                topics.insert(c.id, c.topic);
            }
            Record::Message { header, data } => {
                let topic = topics[&header.channel_id].as_str();
                if seen.insert(topic.to_string()) {
                    match topic {
                        "/points" => put("point_cloud2", "seed_cloud.cdr", &data),
                        "/ground_truth/pose" => put("pose_messages", "pose_stamped.cdr", &data),
                        _ => {}
                    }
                }
            }
            _ => {}
        }
        Ok(())
    })
    .expect("seed log reads");
    let header = codec::Header {
        stamp: codec::Time { sec: 1, nanosec: 2 },
        frame_id: "lidar".into(),
    };
    let pts = [
        Point3::new(1.0, 2.0, 3.0),
        Point3::new(-1.0, 0.5, f64::NAN),
        Point3::new(0.0, 0.0, 1.0),
    ];
    put(
        "point_cloud2",
        "three_with_intensity.cdr",
        &cdr::encode_point_cloud2(&header, &pts, Some(&[1.0, 2.0, 3.0])),
    );
    let pose = Isometry3::from_parts(
        Translation3::new(1.0, -2.0, 0.5),
        UnitQuaternion::from_euler_angles(0.1, 0.2, 0.3),
    );
    put(
        "pose_messages",
        "tf_message.cdr",
        &cdr::encode_tf_message(&[codec::TransformStamped {
            header: header.clone(),
            child_frame_id: "base".into(),
            transform: pose,
        }]),
    );
    put(
        "foxglove_point_cloud",
        "cloud.pb",
        &mireg::fuzzing::foxglove_seed_cloud(),
    );
    put(
        "pose_messages",
        "pose_in_frame.pb",
        &mireg::io::codec::foxglove::encode_pose_in_frame(5, "world", &pose),
    );
}

/// Point cloud files of `mireg pair`, and pose files.
fn file_seeds() {
    let ply = "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\nend_header\n0 0 0\n1 0 0\n0 1 0.5\n";
    put("cloud_files", "tiny.ply", ply.as_bytes());
    let mut bin_ply = b"ply\nformat binary_little_endian 1.0\nelement vertex 2\nproperty double x\nproperty double y\nproperty double z\nend_header\n".to_vec();
    for v in [0.0f64, 1.0, 2.0, 3.0, 4.0, 5.0] {
        bin_ply.extend(v.to_le_bytes());
    }
    put("cloud_files", "tiny_binary.ply", &bin_ply);
    let pcd = "# .PCD v0.7\nVERSION 0.7\nFIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nCOUNT 1 1 1\nWIDTH 2\nHEIGHT 1\nVIEWPOINT 0 0 0 1 0 0 0\nPOINTS 2\nDATA ascii\n0 0 0\n1 2 3\n";
    put("cloud_files", "tiny.pcd", pcd.as_bytes());
    let mut npy = b"\x93NUMPY\x01\x00".to_vec();
    let head = "{'descr': '<f8', 'fortran_order': False, 'shape': (2, 3), }";
    let pad = 64 - (10 + head.len() + 1) % 64;
    let head = format!("{head}{}\n", " ".repeat(pad));
    npy.extend((head.len() as u16).to_le_bytes());
    npy.extend(head.as_bytes());
    for v in [0.0f64, 1.0, 2.0, 3.0, 4.0, 5.0] {
        npy.extend(v.to_le_bytes());
    }
    put("cloud_files", "tiny.npy", &npy);
    let kitti: Vec<u8> = [1.0f32, 2.0, 3.0, 0.5, -1.0, 0.0, 2.0, 0.1]
        .iter()
        .flat_map(|v| v.to_le_bytes())
        .collect();
    put("cloud_files", "tiny.bin", &kitti);
    // Pose files.
    put(
        "pose_files",
        "matrix.txt",
        b"1 0 0 0.5\n0 1 0 0\n0 0 1 0\n0 0 0 1\n",
    );
    put(
        "pose_files",
        "trajectory.log",
        b"0 0 1\n1 0 0 0\n0 1 0 0\n0 0 1 0\n0 0 0 1\n",
    );
    put(
        "pose_files",
        "bun.conf",
        b"camera 0 0 0 0 0 0 1\nbmesh bun000.ply 0 0 0 0 0 0 1\n",
    );
    put(
        "pose_files",
        "est.tum",
        b"1.5 0 0 0 0 0 0 1\n1.6 0.1 0 0 0 0 0 1\n",
    );
    put("pose_files", "poses.kitti", b"1 0 0 0 0 1 0 0 0 0 1 0\n");
}

/// ROS 1: bags of each chunk compression, their messages, and rosbag2 metadata.
fn bag_seeds() {
    for (name, c) in [
        ("none.bag", ChunkCompression::None),
        ("bz2.bag", ChunkCompression::Bz2),
        ("lz4.bag", ChunkCompression::Lz4),
    ] {
        put("ros1_bag", name, &small_bag(2, c, None));
    }
    let header = codec::Header {
        stamp: codec::Time { sec: 7, nanosec: 9 },
        frame_id: "lidar".into(),
    };
    let pts = [Point3::new(1.0f32, 2.0, 3.0), Point3::new(-1.0, 0.5, 2.0)];
    put(
        "ros1_messages",
        "cloud",
        &ros1::encode_point_cloud2(&header, &pts, Some(&[1.0, 2.0])),
    );
    let pose = Isometry3::from_parts(
        Translation3::new(1.0, 2.0, 3.0),
        UnitQuaternion::from_euler_angles(0.1, 0.2, 0.3),
    );
    put(
        "ros1_messages",
        "pose",
        &ros1::encode_pose_stamped(&header, &pose),
    );
    put(
        "ros1_messages",
        "tf",
        &ros1::encode_tf_message(&[codec::TransformStamped {
            header: header.clone(),
            child_frame_id: "base".into(),
            transform: pose,
        }]),
    );
    for dir in ["icl4_split", "icl4_mcap"] {
        let text = std::fs::read(Path::new("fixtures/bags").join(dir).join("metadata.yaml"))
            .expect("fixtures/bags metadata");
        put("rosbag2_metadata", &format!("{dir}.yaml"), &text);
    }
}

/// Decompression bombs (issue 49) in each container and mode.
fn bomb_seeds() {
    use mireg::fuzzing::{
        lz4_zero_chunk, message_mode_file, with_first_chunk, zstd_zero_chunk, zstd_zeros,
    };
    let zstd_log = small_log(
        2,
        mcap::WriteOptions::new().compression(Some(mcap::Compression::Zstd)),
    );
    // MCAP chunks: claiming 512 MiB for 1 MiB of zeros (zstd, lz4); claiming 1 MiB for 128 MiB.
    for (name, chunk) in [
        (
            "bomb_zstd_chunk_claims_512mib.mcap",
            zstd_zero_chunk(1 << 20, 512 << 20),
        ),
        (
            "bomb_lz4_chunk_claims_512mib.mcap",
            lz4_zero_chunk(1 << 20, 512 << 20),
        ),
        (
            "bomb_zstd_chunk_overruns_claim.mcap",
            zstd_zero_chunk(128 << 20, 1 << 20),
        ),
    ] {
        let log = with_first_chunk(&zstd_log, &chunk);
        put("mcap_records", name, &log);
        put("register_input", name, &log);
    }
    // ROS 1 chunks declaring 1 GiB.
    for (name, c) in [
        ("bomb_bz2_chunk_claims_1gib.bag", ChunkCompression::Bz2),
        ("bomb_lz4_chunk_claims_1gib.bag", ChunkCompression::Lz4),
    ] {
        put("ros1_bag", name, &small_bag(2, c, Some(1 << 30)));
    }
    // rosbag2, zstd: the first byte is the mode (0 file, 1 message), the rest the bag's file.
    let plain = small_log(2, mcap::WriteOptions::new().compression(None));
    let seed = |mode: u8, file: &[u8]| [&[mode][..], file].concat();
    put(
        "rosbag2_compressed",
        "file_mode.bin",
        &seed(0, &zstd::bulk::compress(&plain, 3).expect("in memory")),
    );
    put(
        "rosbag2_compressed",
        "message_mode.bin",
        &seed(1, &message_mode_file(&plain, None)),
    );
    put(
        "rosbag2_compressed",
        "bomb_file_mode_256mib.bin",
        &seed(0, &zstd_zeros(b"\x89MCAP0\r\n", 256 << 20)),
    );
    put(
        "rosbag2_compressed",
        "bomb_message_mode_256mib.bin",
        &seed(
            1,
            &message_mode_file(&plain, Some(&zstd_zeros(b"", 256 << 20))),
        ),
    );
}

/// Per-point times that are not finite or absurd, and points far beyond any sensor's range
/// (issue 49).
fn glitch_seeds() {
    use mireg::fuzzing::{glitched_times, small_log_with, timed_cloud_cdr};
    // Per-point times: glitches in every cloud, the second cloud's times all NaN.
    let timed = small_log_with(
        2,
        mcap::WriteOptions::new().compression(Some(mcap::Compression::Zstd)),
        &|k, header, points| {
            let stamp = header.stamp.sec as u64 * 1_000_000_000 + header.stamp.nanosec as u64;
            let times = glitched_times(points.len(), k == 1);
            let pts: Vec<_> = points.iter().copied().zip(times).collect();
            timed_cloud_cdr(stamp, &pts)
        },
    );
    put("register_input", "time_glitches.mcap", &timed);
    let cloud: Vec<_> = [
        [1.0, 2.0, 3.0],
        [-1.0, 0.5, 2.0],
        [0.0, 1.0, 1.0],
        [2.0, 0.0, 1.0],
        [1.0, 1.0, 1.0],
        [0.5, 0.5, 0.5],
        [3.0, 1.0, 0.0],
    ]
    .iter()
    .map(|&[x, y, z]| Point3::new(x, y, z))
    .zip(glitched_times(7, false))
    .collect();
    put(
        "point_cloud2",
        "time_glitches.cdr",
        &timed_cloud_cdr(1_700_000_000_000_000_000, &cloud),
    );
    // Far points: 1e9 m in the first cloud, 3e7 m and exactly the bound in the second.
    let far = small_log_with(
        2,
        mcap::WriteOptions::new().compression(Some(mcap::Compression::Zstd)),
        &|k, header, points| {
            let mut pts = points.to_vec();
            if k == 0 {
                pts.push(Point3::new(1e9, 0.0, 0.0));
            } else {
                pts.extend([Point3::new(3e7, 1.0, 1.0), Point3::new(0.0, -1e6, 0.0)]);
            }
            cdr::encode_point_cloud2(header, &pts, None)
        },
    );
    put("register_input", "far_points.mcap", &far);
    let header = codec::Header {
        stamp: codec::Time { sec: 1, nanosec: 2 },
        frame_id: "lidar".into(),
    };
    let pts = [
        Point3::new(1.0, 2.0, 3.0),
        Point3::new(1e9, 0.0, 0.0),
        Point3::new(0.0, -1e6, 1.0),
        Point3::new(0.0, 0.0, 1.0),
    ];
    put(
        "point_cloud2",
        "far_points.cdr",
        &cdr::encode_point_cloud2(&header, &pts, None),
    );
    let pts32: Vec<Point3<f32>> = pts.iter().map(|p| p.cast()).collect();
    put(
        "ros1_messages",
        "far_points",
        &ros1::encode_point_cloud2(&header, &pts32, None),
    );
    put(
        "foxglove_point_cloud",
        "far_points.pb",
        &mireg::fuzzing::foxglove_seed_cloud_of(&pts),
    );
}
