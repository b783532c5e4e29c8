//! Writes the hostile logs whose cost docs/HARDENING.md reports, into DIR:
//! - `bomb_2gib.mcap`: the seed log with its first chunk replaced by 2 GiB of zeros (zstd, ~68 KB);
//! - `random_5m.mcap`: two clouds of 5 000 000 uniformly random points in a 2 km cube;
//! - `random_100k.mcap`: two clouds of 100 000 such points (every descriptor zero: the
//!   matching worst case without the duplicate grouping);
//! - `bomb_file_mode/`: a rosbag2 directory in zstd `file` mode whose one file is an MCAP magic
//!   and 3 GiB of zeros (~100 KB);
//! - `bomb_message_mode/`: a rosbag2 directory in zstd `message` mode, 24 clouds each a
//!   PointCloud2 of 5 000 000 points at (0, 0, 0) (60 MB, under the 64 MiB expansion floor, so
//!   each is decompressed and held) in a zstd frame of ~6 KB;
//! - `bomb_bz2_1.bag`, `bomb_bz2_24.bag`: ROS 1 bags of 1 and 24 bz2 chunks each declaring 1 GiB.
//!
//! `cargo run --release --example hostile_logs -- DIR`, then e.g.
//! `/usr/bin/time -v target/release/mireg register DIR/random_5m.mcap -o /tmp/o.mcap --force`.

use std::collections::BTreeMap;
use std::path::PathBuf;

use mcap::records::MessageHeader;
use mireg::io::codec::{self, cdr};
use nalgebra::Point3;
use rand::{RngExt, SeedableRng};

fn random_clouds(points: usize) -> Vec<u8> {
    let mut rng = rand_pcg::Pcg64Mcg::seed_from_u64(1);
    let mut out = std::io::Cursor::new(Vec::new());
    let mut w = mcap::WriteOptions::new()
        .profile("ros2")
        .create(&mut out)
        .expect("writer");
    let s = w
        .add_schema(
            cdr::POINT_CLOUD2_SCHEMA_NAME,
            cdr::SCHEMA_ENCODING,
            cdr::POINT_CLOUD2_SCHEMA.as_bytes(),
        )
        .expect("schema");
    let c = w
        .add_channel(s, "/points", "cdr", &BTreeMap::new())
        .expect("channel");
    for k in 0..2u64 {
        let pts: Vec<Point3<f32>> = (0..points)
            .map(|_| {
                Point3::new(
                    rng.random_range(-1000.0..1000.0),
                    rng.random_range(-1000.0..1000.0),
                    rng.random_range(-1000.0..1000.0),
                )
            })
            .collect();
        let t = 1_000_000_000 + k * 100_000_000;
        let header = codec::Header {
            stamp: codec::Time::from_ns(t as i64).expect("in range"),
            frame_id: "lidar".into(),
        };
        let data = cdr::encode_point_cloud2(&header, &pts, None);
        let h = MessageHeader {
            channel_id: c,
            sequence: k as u32,
            log_time: t,
            publish_time: t,
        };
        w.write_to_known_channel(&h, &data).expect("message");
    }
    w.finish().expect("finish");
    drop(w);
    out.into_inner()
}

/// The seed log with its first chunk replaced by one of `zeros` zero bytes (zstd).
fn bomb(zeros: u64) -> Vec<u8> {
    let log = mireg::fuzzing::small_log(
        2,
        mcap::WriteOptions::new().compression(Some(mcap::Compression::Zstd)),
    );
    mireg::fuzzing::with_first_chunk(&log, &mireg::fuzzing::zstd_zero_chunk(zeros, zeros))
}

/// `head` then `zeros` zero bytes, one zstd stream (streamed, never held whole).
fn zstd_zeros(head: &[u8], zeros: u64) -> Vec<u8> {
    let mut enc = zstd::stream::Encoder::new(Vec::new(), 1).expect("in memory");
    std::io::Write::write_all(&mut enc, head).expect("in memory");
    let block = vec![0u8; 1 << 20];
    let mut left = zeros;
    while left > 0 {
        let n = left.min(block.len() as u64) as usize;
        std::io::Write::write_all(&mut enc, &block[..n]).expect("in memory");
        left -= n as u64;
    }
    enc.finish().expect("in memory")
}

/// A rosbag2 `metadata.yaml` of one MCAP file `file` in zstd compression `mode`.
fn metadata(file: &str, mode: &str) -> String {
    format!(
        "rosbag2_bagfile_information:\n  version: 5\n  storage_identifier: mcap\n  \
         relative_file_paths:\n    - {file}\n  compression_format: zstd\n  \
         compression_mode: {mode}\n"
    )
}

/// The MCAP file of `bomb_message_mode/`: `clouds` cloud messages of `points` points at the
/// origin, each one zstd frame.
fn message_mode_mcap(clouds: u64, points: usize) -> Vec<u8> {
    let mut out = std::io::Cursor::new(Vec::new());
    let mut w = mcap::WriteOptions::new()
        .profile("ros2")
        .create(&mut out)
        .expect("writer");
    let s = w
        .add_schema(
            cdr::POINT_CLOUD2_SCHEMA_NAME,
            cdr::SCHEMA_ENCODING,
            cdr::POINT_CLOUD2_SCHEMA.as_bytes(),
        )
        .expect("schema");
    let c = w
        .add_channel(s, "/points", "cdr", &BTreeMap::new())
        .expect("channel");
    let zeros = vec![Point3::<f32>::origin(); points];
    for k in 0..clouds {
        let t = 1_000_000_000 + k * 100_000_000;
        let header = codec::Header {
            stamp: codec::Time::from_ns(t as i64).expect("in range"),
            frame_id: "lidar".into(),
        };
        let cloud = cdr::encode_point_cloud2(&header, &zeros, None);
        let data = zstd::bulk::compress(&cloud, 1).expect("in memory");
        let h = MessageHeader {
            channel_id: c,
            sequence: k as u32,
            log_time: t,
            publish_time: t,
        };
        w.write_to_known_channel(&h, &data).expect("message");
    }
    w.finish().expect("finish");
    drop(w);
    out.into_inner()
}

fn main() {
    let dir = PathBuf::from(std::env::args().nth(1).expect("usage: hostile_logs DIR"));
    std::fs::create_dir_all(&dir).expect("output folder");
    std::fs::write(dir.join("bomb_2gib.mcap"), bomb(2 << 30)).expect("write");
    std::fs::write(dir.join("random_100k.mcap"), random_clouds(100_000)).expect("write");
    std::fs::write(dir.join("random_5m.mcap"), random_clouds(5_000_000)).expect("write");
    let file_mode = dir.join("bomb_file_mode");
    std::fs::create_dir_all(&file_mode).expect("output folder");
    std::fs::write(
        file_mode.join("metadata.yaml"),
        metadata("b.mcap.zstd", "FILE"),
    )
    .expect("write");
    std::fs::write(
        file_mode.join("b.mcap.zstd"),
        zstd_zeros(mcap::MAGIC, 3 << 30),
    )
    .expect("write");
    let message_mode = dir.join("bomb_message_mode");
    std::fs::create_dir_all(&message_mode).expect("output folder");
    std::fs::write(
        message_mode.join("metadata.yaml"),
        metadata("b.mcap", "MESSAGE"),
    )
    .expect("write");
    std::fs::write(
        message_mode.join("b.mcap"),
        message_mode_mcap(24, 5_000_000),
    )
    .expect("write");
    let bz2 = mireg::fuzzing::ChunkCompression::Bz2;
    for n in [1, 24] {
        std::fs::write(
            dir.join(format!("bomb_bz2_{n}.bag")),
            mireg::fuzzing::small_bag(n, bz2, Some(1 << 30)),
        )
        .expect("write");
    }
    println!("wrote {}", dir.display());
}
