//! Writes the hostile logs whose cost docs/HARDENING.md reports, into DIR:
//! - `bomb_2gib.mcap`: the seed log with its first chunk replaced by 2 GiB of zeros (zstd, ~68 KB);
//! - `random_5m.mcap`: two clouds of 5 000 000 uniformly random points in a 2 km cube;
//! - `random_100k.mcap`: two clouds of 100 000 such points (every descriptor zero: the
//!   matching worst case without the duplicate grouping).
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

fn main() {
    let dir = PathBuf::from(std::env::args().nth(1).expect("usage: hostile_logs DIR"));
    std::fs::create_dir_all(&dir).expect("output folder");
    std::fs::write(dir.join("bomb_2gib.mcap"), bomb(2 << 30)).expect("write");
    std::fs::write(dir.join("random_100k.mcap"), random_clouds(100_000)).expect("write");
    std::fs::write(dir.join("random_5m.mcap"), random_clouds(5_000_000)).expect("write");
    println!("wrote {}", dir.display());
}
