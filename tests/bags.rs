//! ROS 1 bags and ROS 2 bag directories written by a third-party writer (PyPI `rosbags`, see
//! fixtures/bags/README.md) from the first 4 frames of the ICL-NUIM fixture:
//! - every kind registers to exactly the poses of the same frames given as a ROS 2 MCAP;
//! - every input message reaches the output (ROS 2 bags: byte for byte the source MCAP's
//!   messages; ROS 1 bags: the same point data, re-serialized by rosbags);
//! - truncated bags, corrupt databases and missing metadata fail with a clear error and leave
//!   nothing behind.

use std::path::{Path, PathBuf};

use mireg::io::codec::{cdr, ros1};
use mireg::odometry::OdometryConfig;
use mireg::pipeline::PairConfig;
use mireg::register::{RegisterOptions, register_log};
use nalgebra::Isometry3;

#[path = "common/log_contents.rs"]
mod log_contents;
use log_contents::{Contents, contents};

const CLOUDS: &str = "/camera/depth/points";
const REFERENCE: &str = "/ground_truth/pose";
const FRAMES: usize = 4;

fn bags() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("fixtures/bags")
}

fn options(input: &Path, output: &Path) -> RegisterOptions {
    let config = OdometryConfig {
        pair: PairConfig {
            voxel_size_m: 0.05,
            seed: 5,
            ..Default::default()
        },
        ..Default::default()
    };
    RegisterOptions::new(input, output, config)
}

/// Registers `input` into a temporary directory; returns the output's contents.
fn register(input: &Path) -> Contents {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("out.mcap");
    let summary = register_log(&options(input, &out)).unwrap();
    assert_eq!(summary.frames, FRAMES, "{}", input.display());
    assert_eq!(summary.failed_frames, 0, "{}", input.display());
    assert_eq!(summary.messages_copied, 2 * FRAMES as u64);
    // The reference topic is read in either encoding.
    let reference = summary.reference.expect("reference poses found");
    assert_eq!(reference.frames, FRAMES, "{}", input.display());
    assert!(reference.ate_rmse_m < 0.01, "{}", input.display());
    contents(&out)
}

fn poses(c: &Contents) -> Vec<(i64, Isometry3<f64>)> {
    c.messages
        .iter()
        .filter(|m| m.0 == "/mireg/pose")
        .map(|m| {
            let (h, p) = cdr::decode_pose_stamped(&m.3)
                .or_else(|_| ros1::decode_pose_stamped(&m.3))
                .unwrap();
            (h.stamp.to_ns(), p)
        })
        .collect()
}

/// The source frames: the first 4 clouds and reference poses of the ROS 2 fixture, as (topic,
/// log time, bytes).
fn source_messages() -> Vec<(String, u64, Vec<u8>)> {
    let fixture = Path::new(env!("CARGO_MANIFEST_DIR")).join("fixtures/icl_livingroom1.mcap");
    let c = contents(&fixture);
    let mut out = Vec::new();
    for topic in [CLOUDS, REFERENCE] {
        let mut msgs: Vec<_> = c.messages.iter().filter(|m| m.0 == topic).collect();
        msgs.sort_by_key(|m| m.1);
        out.extend(
            msgs.iter()
                .take(FRAMES)
                .map(|m| (m.0.clone(), m.1, m.3.clone())),
        );
    }
    out.sort();
    out
}

fn input_messages_of(c: &Contents) -> Vec<(String, u64, Vec<u8>)> {
    let mut v: Vec<_> = c
        .messages
        .iter()
        .filter(|m| m.0 == CLOUDS || m.0 == REFERENCE)
        .map(|m| (m.0.clone(), m.1, m.3.clone()))
        .collect();
    v.sort();
    v
}

#[test]
fn every_kind_of_bag_gives_the_poses_of_the_same_frames_in_mcap() {
    // The same frames as a ROS 2 MCAP file (rosbags' own MCAP, read as a plain file).
    let reference = register(&bags().join("icl4_mcap/icl4_mcap.mcap"));
    let want = poses(&reference);
    assert_eq!(want.len(), FRAMES);
    for input in [
        "icl4_mcap",
        "icl4_db3",
        "icl4_split",
        "icl4_mcap_zstd_file",
        "icl4_mcap_zstd_message",
        "icl4_db3_zstd_file",
        "icl4_db3_zstd_message",
        // A compressed storage file given on its own.
        "icl4_mcap_zstd_file/icl4_mcap_zstd_file.mcap.zstd",
        "icl4_db3_zstd_file/icl4_db3_zstd_file.db3.zstd",
        "icl4_none.bag",
        "icl4_bz2.bag",
        "icl4_lz4.bag",
    ] {
        let got = poses(&register(&bags().join(input)));
        assert_eq!(got, want, "{input}");
    }
    // A bag directory named by its metadata.yaml is the same bag.
    let got = poses(&register(&bags().join("icl4_split/metadata.yaml")));
    assert_eq!(got, want, "icl4_split/metadata.yaml");
}

#[test]
fn ros2_bags_keep_every_source_message_byte_for_byte() {
    let want = source_messages();
    assert_eq!(want.len(), 2 * FRAMES);
    for input in [
        "icl4_mcap",
        "icl4_db3",
        "icl4_split",
        // Compressed bags: the output holds the messages decompressed, as the source's bytes.
        "icl4_mcap_zstd_file",
        "icl4_mcap_zstd_message",
        "icl4_db3_zstd_file",
        "icl4_db3_zstd_message",
    ] {
        let out = register(&bags().join(input));
        assert_eq!(input_messages_of(&out), want, "{input}");
    }
}

#[test]
fn ros1_bags_keep_every_message_and_the_source_point_data() {
    let source = source_messages();
    for input in ["icl4_none.bag", "icl4_bz2.bag", "icl4_lz4.bag"] {
        let out = register(&bags().join(input));
        let got = input_messages_of(&out);
        assert_eq!(got.len(), 2 * FRAMES, "{input}");
        for ((topic, t, bytes), (want_topic, want_t, want_bytes)) in got.iter().zip(&source) {
            assert_eq!((topic, t), (want_topic, want_t), "{input}");
            if topic == CLOUDS {
                let a = ros1::decode_point_cloud2(bytes).unwrap();
                let b = cdr::decode_point_cloud2(want_bytes).unwrap();
                assert_eq!(a.points, b.points, "{input} at {t}");
                assert_eq!(a.header, b.header, "{input} at {t}");
            } else {
                let a = ros1::decode_pose_stamped(bytes).unwrap();
                let b = cdr::decode_pose_stamped(want_bytes).unwrap();
                assert_eq!(a, b, "{input} at {t}");
            }
        }
    }
}

/// The offset of the bag header's `index_pos` value in `bytes`.
fn index_pos_field(bytes: &[u8]) -> usize {
    let key = b"index_pos=";
    bytes[..4096]
        .windows(key.len())
        .position(|w| w == key)
        .expect("bag header has index_pos")
        + key.len()
}

#[test]
fn a_bag_whose_index_was_never_written_is_scanned() {
    // What a killed recorder leaves: index_pos 0 and nothing after the last chunk.
    let mut bytes = std::fs::read(bags().join("icl4_lz4.bag")).unwrap();
    let at = index_pos_field(&bytes);
    let index_pos = u64::from_le_bytes(bytes[at..at + 8].try_into().unwrap()) as usize;
    bytes.truncate(index_pos);
    bytes[at..at + 8].fill(0);
    let dir = tempfile::tempdir().unwrap();
    let unindexed = dir.path().join("unindexed.bag");
    std::fs::write(&unindexed, &bytes).unwrap();
    let want = poses(&register(&bags().join("icl4_lz4.bag")));
    assert_eq!(poses(&register(&unindexed)), want);
}

/// `register --strict` on `input` fails with an error holding every needle, and leaves nothing.
fn assert_fails_cleanly(input: &Path, needles: &[&str]) {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("out.mcap");
    let strict = RegisterOptions {
        read_policy: mireg::io::damage::ReadPolicy::STRICT,
        ..options(input, &out)
    };
    let e = register_log(&strict).unwrap_err().to_string();
    for n in needles {
        assert!(e.contains(n), "error {e:?} should mention {n:?}");
    }
    assert_eq!(
        std::fs::read_dir(dir.path()).unwrap().count(),
        0,
        "nothing left behind for {}",
        input.display()
    );
}

#[test]
fn truncated_bags_corrupt_databases_and_missing_metadata_are_clear_errors() {
    let dir = tempfile::tempdir().unwrap();
    let bag = std::fs::read(bags().join("icl4_bz2.bag")).unwrap();

    // Cut inside the chunks (the index is gone too).
    let cut = dir.path().join("cut.bag");
    std::fs::write(&cut, &bag[..bag.len() / 2]).unwrap();
    assert_fails_cleanly(&cut, &["cut.bag", "truncated"]);

    // Cut inside the index at the end.
    let cut_index = dir.path().join("cut_index.bag");
    std::fs::write(&cut_index, &bag[..bag.len() - 10]).unwrap();
    assert_fails_cleanly(&cut_index, &["cut_index.bag", "truncated"]);

    // A bz2 chunk with flipped bytes.
    let mut flipped = bag.clone();
    let mid = flipped.len() / 3;
    for b in &mut flipped[mid..mid + 64] {
        *b ^= 0x5a;
    }
    let corrupt_bag = dir.path().join("corrupt.bag");
    std::fs::write(&corrupt_bag, &flipped).unwrap();
    assert_fails_cleanly(&corrupt_bag, &["corrupt.bag"]);

    // A .db3 whose pages were overwritten, in an otherwise intact bag directory.
    let broken = dir.path().join("broken_db3");
    std::fs::create_dir(&broken).unwrap();
    std::fs::copy(
        bags().join("icl4_db3/metadata.yaml"),
        broken.join("metadata.yaml"),
    )
    .unwrap();
    let mut db = std::fs::read(bags().join("icl4_db3/icl4_db3.db3")).unwrap();
    db[100..8192].fill(0xff);
    std::fs::write(broken.join("icl4_db3.db3"), &db).unwrap();
    assert_fails_cleanly(&broken, &["icl4_db3.db3", "SQLite"]);

    // A file-compressed bag whose zstd file was cut short, and a message-compressed one whose
    // metadata claims a format rosbag2 does not write.
    let cut_zstd = dir.path().join("cut_zstd");
    std::fs::create_dir(&cut_zstd).unwrap();
    let src = bags().join("icl4_db3_zstd_file");
    std::fs::copy(src.join("metadata.yaml"), cut_zstd.join("metadata.yaml")).unwrap();
    let z = std::fs::read(src.join("icl4_db3_zstd_file.db3.zstd")).unwrap();
    std::fs::write(
        cut_zstd.join("icl4_db3_zstd_file.db3.zstd"),
        &z[..z.len() / 2],
    )
    .unwrap();
    assert_fails_cleanly(&cut_zstd, &["icl4_db3_zstd_file.db3.zstd", "zstd"]);
    let lz4 = dir.path().join("lz4_message");
    std::fs::create_dir(&lz4).unwrap();
    let src = bags().join("icl4_mcap_zstd_message");
    let meta = std::fs::read_to_string(src.join("metadata.yaml")).unwrap();
    std::fs::write(
        lz4.join("metadata.yaml"),
        meta.replace("compression_format: zstd", "compression_format: lz4"),
    )
    .unwrap();
    std::fs::copy(
        src.join("icl4_mcap_zstd_message.mcap"),
        lz4.join("icl4_mcap_zstd_message.mcap"),
    )
    .unwrap();
    assert_fails_cleanly(&lz4, &["metadata.yaml", "compression_format \"lz4\""]);

    // A directory without metadata.yaml, and metadata naming a missing file.
    let no_meta = dir.path().join("no_meta");
    std::fs::create_dir(&no_meta).unwrap();
    std::fs::copy(
        bags().join("icl4_db3/icl4_db3.db3"),
        no_meta.join("icl4_db3.db3"),
    )
    .unwrap();
    assert_fails_cleanly(&no_meta, &["no_meta", "metadata.yaml", "ROS 1 bag (.bag)"]);
    let missing = dir.path().join("missing_file");
    std::fs::create_dir(&missing).unwrap();
    std::fs::copy(
        bags().join("icl4_split/metadata.yaml"),
        missing.join("metadata.yaml"),
    )
    .unwrap();
    std::fs::copy(
        bags().join("icl4_split/icl4_split_0.db3"),
        missing.join("icl4_split_0.db3"),
    )
    .unwrap();
    assert_fails_cleanly(&missing, &["metadata.yaml", "icl4_split_1.db3"]);

    // No such path: the reason once, and what is accepted.
    let e = register_log(&options(
        &dir.path().join("nope"),
        &dir.path().join("o.mcap"),
    ))
    .unwrap_err()
    .to_string();
    assert_eq!(e.matches("no such file").count(), 1, "{e}");
    assert!(e.contains("ROS 2 bag directory"), "{e}");
}

#[test]
fn nothing_in_the_bag_directory_is_altered() {
    let dir = tempfile::tempdir().unwrap();
    let copy = dir.path().join("icl4_split");
    std::fs::create_dir(&copy).unwrap();
    for f in ["metadata.yaml", "icl4_split_0.db3", "icl4_split_1.db3"] {
        std::fs::copy(bags().join("icl4_split").join(f), copy.join(f)).unwrap();
    }
    let before: Vec<_> = std::fs::read_dir(&copy)
        .unwrap()
        .map(|e| {
            let p = e.unwrap().path();
            (p.clone(), std::fs::read(&p).unwrap())
        })
        .collect();
    let out = dir.path().join("out.mcap");
    register_log(&options(&copy, &out)).unwrap();
    let mut after: Vec<_> = std::fs::read_dir(&copy)
        .unwrap()
        .map(|e| {
            let p = e.unwrap().path();
            (p.clone(), std::fs::read(&p).unwrap())
        })
        .collect();
    let mut before = before;
    before.sort();
    after.sort();
    assert_eq!(before, after, "no file added, removed or changed");
}

#[test]
fn hand_written_bags_of_each_compression_register_and_chunk_sizes_are_bounded() {
    use mireg::fuzzing::{ChunkCompression, small_bag};
    let dir = tempfile::tempdir().unwrap();
    let mut want = None;
    for c in [
        ChunkCompression::None,
        ChunkCompression::Bz2,
        ChunkCompression::Lz4,
    ] {
        let input = dir.path().join("seed.bag");
        std::fs::write(&input, small_bag(3, c, None)).unwrap();
        let out = dir.path().join("seed.mcap");
        let _ = std::fs::remove_file(&out);
        let s = register_log(&options(&input, &out)).unwrap();
        assert_eq!((s.frames, s.failed_frames), (3, 0), "{c:?}");
        let p = poses(&contents(&out));
        assert_eq!(*want.get_or_insert_with(|| p.clone()), p, "{c:?}");

        // A chunk that decompresses to more than it declares (a decompression bomb is one that
        // declares little and holds much) is refused; so is a declared size over the limit,
        // before any allocation.
        for (declared, needle) in [(100, "declares 100"), (u32::MAX, "limit")] {
            let bomb = dir.path().join("bomb.bag");
            std::fs::write(&bomb, small_bag(1, c, Some(declared))).unwrap();
            let e = register_log(&options(&bomb, &dir.path().join("b.mcap")))
                .unwrap_err()
                .to_string();
            assert!(e.contains(needle), "{c:?}, declared {declared}: {e}");
            assert!(!dir.path().join("b.mcap").exists());
        }
    }
}
