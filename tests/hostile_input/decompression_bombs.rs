//! Finding 2 of the third round: decompression bombs were bounded only by the sizes they
//! claimed. A 96 KB zstd `file`-mode bag wrote 3 GiB to `$TMPDIR` before failing (naming the
//! temporary copy); a `message`-mode bag peaked at 3.96 GB; a 5.4 KB ROS 1 bag with one bz2 chunk
//! declaring 1 GiB peaked at 3.15 GB. Now every decompression stops at
//! `mireg::io::expansion_limit` of its compressed size (1000×, at least 64 MiB), a `file`-mode
//! copy also at the free space of `$TMPDIR` and only after its first bytes proved an MCAP or
//! SQLite file, and the errors name the input.

use super::*;
use mireg::fuzzing::{ChunkCompression, small_bag, zstd_zeros};
use mireg::io::bag::ros1::Bag;

/// A `file`-mode rosbag2 directory of one `bag_0.mcap.zstd` holding `data`.
fn file_mode_bag(dir: &Path, data: &[u8]) -> PathBuf {
    let bag = dir.join("bag");
    std::fs::create_dir(&bag).unwrap();
    std::fs::write(
        bag.join("metadata.yaml"),
        "rosbag2_bagfile_information:\n  version: 5\n  storage_identifier: mcap\n  \
         relative_file_paths:\n    - bag_0.mcap.zstd\n  compression_format: zstd\n  \
         compression_mode: FILE\n",
    )
    .unwrap();
    std::fs::write(bag.join("bag_0.mcap.zstd"), data).unwrap();
    bag
}

/// mireg `args` with `$TMPDIR` set to `tmp`.
fn mireg_in(tmp: &Path, args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_mireg"))
        .args(args)
        .env("TMPDIR", tmp)
        .output()
        .unwrap()
}

/// A `file`-mode bag whose 256 MiB of zeros follow an MCAP magic is stopped at 64 MiB (its
/// compressed size × 1000 is less), naming the input; one whose zeros start at once is refused
/// on its first bytes; nothing is left in `$TMPDIR` either way.
#[test]
fn a_file_mode_bomb_stops_at_its_expansion_limit_and_names_the_input() {
    let dir = tempfile::tempdir().unwrap();
    let tmp = dir.path().join("tmp");
    std::fs::create_dir(&tmp).unwrap();
    for (name, head, needle) in [
        (
            "magic",
            &b"\x89MCAP0\r\n"[..],
            "decompresses to more than 67108864 bytes",
        ),
        (
            "zeros",
            &b""[..],
            "decompresses to neither an MCAP nor an SQLite file",
        ),
    ] {
        let case = dir.path().join(name);
        std::fs::create_dir(&case).unwrap();
        let bomb = zstd_zeros(head, 256 << 20);
        assert!(bomb.len() < 64 << 10, "{} bytes", bomb.len());
        let bag = file_mode_bag(&case, &bomb);
        let out = case.join("out.mcap");
        let run = mireg_in(
            &tmp,
            &[
                "register",
                bag.to_str().unwrap(),
                "-o",
                out.to_str().unwrap(),
            ],
        );
        let e = stderr(&run);
        assert_eq!(run.status.code(), Some(2), "{e}");
        assert!(e.contains("bag/bag_0.mcap.zstd: "), "{e}");
        assert!(e.contains(needle), "{e}");
        assert!(!e.contains(tmp.to_str().unwrap()), "names the copy: {e}");
        assert!(!out.exists());
        assert!(listing(&tmp).is_empty(), "{:?}", listing(&tmp));
    }
}

/// A `message`-mode bag whose cloud messages are 8 KB zstd frames of 256 MiB of zeros: the
/// first is stopped at 64 MiB, an error naming the file and the message's time.
#[test]
fn a_message_mode_bomb_stops_at_its_expansion_limit() {
    let dir = tempfile::tempdir().unwrap();
    let fixture =
        Path::new(env!("CARGO_MANIFEST_DIR")).join("fixtures/bags/icl4_mcap_zstd_message");
    let bag = dir.path().join("bag");
    std::fs::create_dir(&bag).unwrap();
    let mut file = None;
    for e in std::fs::read_dir(&fixture).unwrap() {
        let e = e.unwrap();
        std::fs::copy(e.path(), bag.join(e.file_name())).unwrap();
        if e.path().extension().is_some_and(|x| x == "mcap") {
            file = Some(bag.join(e.file_name()));
        }
    }
    let file = file.unwrap();
    let mut m = messages(&file);
    let bomb = zstd_zeros(b"", 256 << 20);
    for (c, _, data) in &mut m.messages {
        if m.channels[c].1.ends_with("PointCloud2") {
            data.clone_from(&bomb);
        }
    }
    let order: Vec<usize> = (0..m.messages.len()).collect();
    std::fs::write(&file, rewrite(&m, &order, mcap::WriteOptions::new())).unwrap();
    let out = dir.path().join("out.mcap");
    let e = register_log(&options(&bag, &out)).unwrap_err().to_string();
    assert!(e.contains(file.to_str().unwrap()), "{e}");
    assert!(
        e.contains("decompresses to more than 67108864 bytes"),
        "{e}"
    );
    assert!(!out.exists());
}

/// A ROS 1 bag whose chunks (bz2, lz4) declare 1 GiB is refused on the ratio of that claim to
/// the chunk's bytes, before anything is allocated for it.
#[test]
fn a_ros1_chunk_claiming_far_more_than_its_bytes_is_refused() {
    let dir = tempfile::tempdir().unwrap();
    for c in [ChunkCompression::Bz2, ChunkCompression::Lz4] {
        let bomb = dir.path().join("bomb.bag");
        std::fs::write(&bomb, small_bag(2, c, Some(1 << 30))).unwrap();
        let (r, largest) = largest_allocation(|| {
            Bag::open(&bomb)
                .and_then(|b| b.for_each_message(|_, _, _| Ok(std::ops::ControlFlow::Continue(()))))
        });
        let e = r.unwrap_err().to_string();
        assert!(e.contains("bomb.bag") && e.contains("offset"), "{c:?}: {e}");
        assert!(e.contains("decompression bomb"), "{c:?}: {e}");
        assert!(largest < MODEST, "{c:?}: {largest} bytes at once");
    }
}

/// An MCAP chunk of 64 KB claiming 512 MiB (under the 1 GiB chunk limit) is refused on its
/// ratio by every reader, before its buffer is allocated.
#[test]
fn an_mcap_chunk_claiming_far_more_than_its_bytes_is_refused() {
    let dir = tempfile::tempdir().unwrap();
    let base = small_log(
        2,
        mcap::WriteOptions::new().compression(Some(mcap::Compression::Zstd)),
    );
    let bomb = dir.path().join("bomb.mcap");
    let chunk = mireg::fuzzing::zstd_zero_chunk(1 << 20, 512 << 20);
    std::fs::write(&bomb, mireg::fuzzing::with_first_chunk(&base, &chunk)).unwrap();
    let (r, largest) = largest_allocation(|| for_each_record(&bomb, |_| Ok(())));
    let e = r.unwrap_err().to_string();
    assert!(e.contains("decompression bomb"), "{e}");
    assert!(largest < MODEST, "{largest} bytes at once");
    let e = register_log(&options(&bomb, &dir.path().join("out.mcap")))
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("bomb.mcap") && e.contains("decompression bomb"),
        "{e}"
    );
}

/// A `foxglove.PointCloud` or Livox `CustomMsg` declaring more points than `--max-points` was
/// decoded whole before it was flagged (PointCloud2 was flagged on what it declares); now each is
/// flagged on its declared count, before its points are decoded or allocated: the frame's
/// `failure_detail` says "declares N points".
#[test]
fn foxglove_and_livox_clouds_over_max_points_are_flagged_before_decoding() {
    let dir = tempfile::tempdir().unwrap();
    // Two foxglove clouds of 300 points each, ROS 2 profile.
    let foxglove = dir.path().join("foxglove.mcap");
    let mut out = std::io::Cursor::new(Vec::new());
    let mut w = mcap::WriteOptions::new()
        .profile("ros2")
        .create(&mut out)
        .unwrap();
    let schema = mireg::io::codec::foxglove::point_cloud_schema();
    let s = w
        .add_schema(&schema.name, &schema.encoding, &schema.data)
        .unwrap();
    let ch = w
        .add_channel(s, "/cloud", "protobuf", &BTreeMap::new())
        .unwrap();
    let mut rng = rand_pcg::Pcg64Mcg::seed_from_u64(3);
    for k in 0..2u32 {
        let pts: Vec<nalgebra::Point3<f64>> = (0..300)
            .map(|_| {
                nalgebra::Point3::new(
                    rng.random_range(-2.0..2.0),
                    rng.random_range(-2.0..2.0),
                    rng.random_range(1.0..4.0),
                )
            })
            .collect();
        let t = 1_700_000_000_000_000_000 + u64::from(k) * 100_000_000;
        let header = MessageHeader {
            channel_id: ch,
            sequence: k,
            log_time: t,
            publish_time: t,
        };
        let msg = mireg::fuzzing::foxglove_seed_cloud_of(&pts);
        w.write_to_known_channel(&header, &msg).unwrap();
    }
    w.finish().unwrap();
    drop(w);
    std::fs::write(&foxglove, out.into_inner()).unwrap();
    let livox = Path::new(env!("CARGO_MANIFEST_DIR")).join("fixtures/livox");
    for input in [
        foxglove,
        livox.join("icl_livox.bag"),
        livox.join("icl_livox_ros2"),
    ] {
        let out = dir.path().join("out.mcap");
        let opts = RegisterOptions {
            max_points_per_cloud: 100,
            ..options(&input, &out)
        };
        let s = register_log(&opts).unwrap();
        assert_eq!(s.failed_frames, s.frames, "{}", input.display());
        for f in stats(&out) {
            assert_eq!(f["failure_reason"], "too_many_points", "{f}");
            let detail = f["failure_detail"].as_str().unwrap();
            assert!(
                detail.starts_with("declares ") && detail.contains("more than the bound of 100"),
                "{}: {detail}",
                input.display()
            );
        }
    }
}
