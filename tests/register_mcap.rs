//! `mireg register` end to end: pass-through of every input record, recovered motion against
//! known transforms, the reference trajectory of the fixture, and clean failure on bad input.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use mcap::records::{MessageHeader, Record};
use mireg::io::codec::{Header, Time, cdr};
use mireg::io::log_order::ChunkTimes;

#[path = "common/log_contents.rs"]
mod log_contents;
use log_contents::{Contents, assert_superset, contents};
#[path = "common/synthetic_log.rs"]
mod synthetic_log;
use mireg::io::mcap::log::for_each_record;
use mireg::odometry::OdometryConfig;
use mireg::pipeline::{PairConfig, pose_error};
use mireg::register::{RegisterOptions, register_log};
use nalgebra::{Isometry3, Translation3, UnitQuaternion};
use synthetic_log::{scene, world_from_camera, write_log_full};

fn fixture() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("fixtures/icl_livingroom1.mcap")
}

/// `mireg ARGS`, run to completion: its output, whatever its exit status.
fn mireg(args: &[&str]) -> std::process::Output {
    std::process::Command::new(env!("CARGO_BIN_EXE_mireg"))
        .args(args)
        .output()
        .unwrap()
}

/// [`mireg`], which must succeed (its stderr is the failure's message).
fn mireg_ok(args: &[&str]) -> std::process::Output {
    let run = mireg(args);
    assert!(
        run.status.success(),
        "{}",
        String::from_utf8_lossy(&run.stderr)
    );
    run
}

fn options(input: &Path, output: &Path, voxel: f64) -> RegisterOptions {
    let config = OdometryConfig {
        pair: PairConfig {
            voxel_size_m: voxel,
            seed: 3,
            ..Default::default()
        },
        ..Default::default()
    };
    RegisterOptions {
        force: false,
        command_line: "test".into(),
        ..RegisterOptions::new(input, output, config)
    }
}

fn poses(c: &Contents, topic: &str) -> Vec<(i64, Isometry3<f64>)> {
    c.messages
        .iter()
        .filter(|m| m.0 == topic)
        .map(|m| {
            let (h, p) = cdr::decode_pose_stamped(&m.3).unwrap();
            (h.stamp.to_ns(), p)
        })
        .collect()
}

#[test]
fn fixture_passes_through_and_follows_the_reference() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("out.mcap");
    let summary = register_log(&options(&fixture(), &out, 0.05)).unwrap();
    let (input, output) = (contents(&fixture()), contents(&out));
    assert_superset(&input, &output);
    let frames = input
        .messages
        .iter()
        .filter(|m| m.0 == "/camera/depth/points")
        .count();
    assert_eq!(summary.frames, frames);
    for topic in ["/tf", "/mireg/pose", "/mireg/stats"] {
        assert_eq!(
            output.messages.iter().filter(|m| m.0 == topic).count(),
            frames,
            "{topic}"
        );
    }
    let meta = &output
        .metadata
        .iter()
        .find(|m| m.0 == "mireg")
        .expect("mireg metadata")
        .1;
    for key in ["version", "config", "seed", "command_line"] {
        assert!(meta.contains_key(key), "metadata key {key}");
    }
    // Stats: one JSON object per frame with the documented fields.
    for m in output.messages.iter().filter(|m| m.0 == "/mireg/stats") {
        let v: serde_json::Value = serde_json::from_slice(&m.3).unwrap();
        for key in [
            "frame",
            "stamp_ns",
            "success",
            "failure_reason",
            "num_inliers",
            "inlier_ratio",
            "hypotheses",
            "fitness",
            "timings_s",
        ] {
            assert!(v.get(key).is_some(), "stats key {key}");
        }
    }
    // Against the fixture's reference poses (Open3D's reconstruction, first frame = identity).
    let est = poses(&output, "/mireg/pose");
    let reference: BTreeMap<i64, Isometry3<f64>> =
        poses(&output, "/ground_truth/pose").into_iter().collect();
    assert_eq!(est[0].1, Isometry3::identity());
    let mut worst = (0.0f64, 0.0f64);
    for (stamp, pose) in &est {
        let (r, t) = pose_error(&reference[stamp], pose);
        worst = (worst.0.max(r), worst.1.max(t));
    }
    // Frame-to-frame odometry drifts: 71 frames over a 3.7 m path; this bound catches gross
    // failures, the ATE/RPE bounds below judge accuracy.
    assert!(
        worst.0 < 8.0 && worst.1 < 0.20,
        "worst drift {:.2}° {:.3} m over the log",
        worst.0,
        worst.1
    );
    assert!(
        summary.failed_frames * 10 <= frames,
        "{} failed frames",
        summary.failed_frames
    );
    let r = summary.reference.expect("reference errors");
    assert!(r.ate_rmse_m < 0.05 && r.rpe_trans_mean_m < 0.02, "{r:?}");
}

/// Writes a log with a cloud topic seen from `world_from_camera(k)`, plus unrelated channels,
/// metadata and an attachment.
fn write_synthetic_log(path: &Path, frames: usize) {
    write_log_full(path, &(0..frames).collect::<Vec<_>>(), None, |o| o);
}

/// [`write_synthetic_log`] with writer options (compression, chunking, indexes) set by `opts`.
fn write_log_with(
    path: &Path,
    frames: usize,
    opts: impl FnOnce(mcap::WriteOptions) -> mcap::WriteOptions,
) {
    write_log_full(path, &(0..frames).collect::<Vec<_>>(), None, opts);
}

/// [`write_synthetic_log`] with the frames written in file order `order` (frame `k` keeps log
/// time `t0 + k · 0.1 s`), and a new chunk after every `frames_per_chunk` frames when given.
fn write_synthetic_log_in_order(path: &Path, order: &[usize], frames_per_chunk: Option<usize>) {
    write_log_full(path, order, frames_per_chunk, |o| o);
}

/// Poses on `topic` in file order.
fn poses_in_file_order(path: &Path, topic: &str) -> Vec<(i64, Isometry3<f64>)> {
    let mut channel = None;
    let mut out = Vec::new();
    for_each_record(path, |r| {
        match r {
            Record::Channel(ch) if ch.topic == topic => channel = Some(ch.id),
            Record::Message { header, data } if Some(header.channel_id) == channel => {
                let (h, p) = cdr::decode_pose_stamped(&data).unwrap();
                out.push((h.stamp.to_ns(), p));
            }
            _ => {}
        }
        Ok(())
    })
    .unwrap();
    out
}

/// Clouds written out of log-time order are registered in log-time order, both where the chunk
/// index proves the chunks ordered (each cloud waits only for its own chunk) and where it cannot
/// (chunks out of order: the reorder window).
#[test]
fn clouds_out_of_log_time_order_are_registered_in_log_time_order() {
    for (name, order, proven) in [
        ("swapped within ordered chunks", [1, 0, 3, 2, 5, 4], true),
        ("chunks out of order", [2, 3, 0, 1, 4, 5], false),
    ] {
        let dir = tempfile::tempdir().unwrap();
        let (input, out) = (dir.path().join("in.mcap"), dir.path().join("out.mcap"));
        write_synthetic_log_in_order(&input, &order, Some(2));
        let chunks = ChunkTimes::read(&input).unwrap();
        assert_eq!(chunks.is_some(), proven, "{name}: {chunks:?}");
        let summary = register_log(&options(&input, &out, 0.1)).unwrap();
        assert_eq!((summary.frames, summary.failed_frames), (6, 0), "{name}");
        let poses = poses_in_file_order(&out, "/mireg/pose");
        assert!(
            poses.is_sorted_by_key(|p| p.0),
            "{name}: poses not in log-time order"
        );
        for (k, (_, est)) in poses.iter().enumerate() {
            let truth = world_from_camera(0).inverse() * world_from_camera(k);
            let (r, t) = pose_error(&truth, est);
            assert!(r < 0.3 && t < 0.01, "{name}, frame {k}: {r:.3}° {t:.4} m");
        }
    }
}

#[test]
fn synthetic_log_recovers_known_motion_and_keeps_every_record() {
    let dir = tempfile::tempdir().unwrap();
    let (input, out) = (dir.path().join("in.mcap"), dir.path().join("out.mcap"));
    write_synthetic_log(&input, 6);
    let summary = register_log(&options(&input, &out, 0.1)).unwrap();
    assert_eq!(summary.frames, 6);
    assert_eq!(summary.failed_frames, 0);
    let (a, b) = (contents(&input), contents(&out));
    assert_superset(&a, &b);
    assert_eq!(b.metadata.len(), a.metadata.len() + 1);
    // world = the first camera: world_from_frame_k = camera_0_from_world · world_from_camera_k.
    for (k, (_, est)) in poses(&b, "/mireg/pose").iter().enumerate() {
        let truth = world_from_camera(0).inverse() * world_from_camera(k);
        let (r, t) = pose_error(&truth, est);
        assert!(r < 0.3 && t < 0.01, "frame {k}: {r:.3}° {t:.4} m");
    }
    // /tf carries the same pose, parent "world", child = the cloud's frame.
    for m in b.messages.iter().filter(|m| m.0 == "/tf") {
        let tfs = cdr::decode_tf_message(&m.3).unwrap();
        assert_eq!(
            (
                tfs[0].header.frame_id.as_str(),
                tfs[0].child_frame_id.as_str()
            ),
            ("world", "lidar")
        );
    }
}

fn no_partial_files(dir: &Path) {
    let left: Vec<_> = std::fs::read_dir(dir)
        .unwrap()
        .map(|e| e.unwrap().file_name())
        .collect();
    assert!(
        left.iter()
            .all(|n| !n.to_string_lossy().contains("partial")),
        "left behind: {left:?}"
    );
}

#[test]
fn truncated_and_corrupt_logs_fail_cleanly() {
    let dir = tempfile::tempdir().unwrap();
    let bytes = std::fs::read(fixture()).unwrap();
    let truncated = dir.path().join("truncated.mcap");
    std::fs::write(&truncated, &bytes[..bytes.len() / 2]).unwrap();
    let mut flipped = bytes.clone();
    for b in &mut flipped[bytes.len() / 3..bytes.len() / 3 + 64] {
        *b ^= 0x5a;
    }
    let corrupt = dir.path().join("corrupt.mcap");
    std::fs::write(&corrupt, &flipped).unwrap();
    for input in [&truncated, &corrupt] {
        let out = dir.path().join("out.mcap");
        let err = register_log(&options(input, &out, 0.05))
            .unwrap_err()
            .to_string();
        assert!(
            err.contains(&input.display().to_string()),
            "error does not name the file: {err}"
        );
        assert!(!out.exists(), "output left behind for {}", input.display());
        no_partial_files(dir.path());
    }
}

#[test]
fn never_overwrites_without_force_and_never_the_input() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("out.mcap");
    std::fs::write(&out, b"precious").unwrap();
    let err = register_log(&options(&fixture(), &out, 0.05))
        .unwrap_err()
        .to_string();
    assert!(err.contains("--force"), "{err}");
    assert_eq!(std::fs::read(&out).unwrap(), b"precious");
    let input = dir.path().join("in.mcap");
    std::fs::copy(fixture(), &input).unwrap();
    let mut opts = options(&input, &input, 0.05);
    opts.force = true;
    assert!(register_log(&opts).is_err());
    assert_eq!(
        std::fs::read(&input).unwrap(),
        std::fs::read(fixture()).unwrap()
    );
}

#[test]
fn real_rosbag2_log_passes_through_untouched() {
    let nav2 =
        Path::new(env!("CARGO_MANIFEST_DIR")).join("../shared/data/mcap/nav2_turtlebot.mcap");
    if !nav2.exists() {
        eprintln!(
            "skipping: {} not found (../shared/data is absent)",
            nav2.display()
        );
        return;
    }
    // The nav2 log has no clouds: append a cloud channel to a copy of its records.
    let dir = tempfile::tempdir().unwrap();
    let (input, out) = (
        dir.path().join("nav2_with_clouds.mcap"),
        dir.path().join("out.mcap"),
    );
    {
        let mut log = mireg::io::mcap::log::OutputLog::create(&input, false, "ros2").unwrap();
        let mut first = None;
        for_each_record(&nav2, |r| {
            if let Record::Message { header, .. } = &r {
                first.get_or_insert(header.log_time);
            }
            log.copy(&r)
        })
        .unwrap();
        let ch = log
            .add_channel(
                "/scan/points",
                cdr::POINT_CLOUD2_SCHEMA_NAME,
                "ros2msg",
                cdr::POINT_CLOUD2_SCHEMA.as_bytes(),
                "cdr",
            )
            .unwrap();
        let world = scene(2);
        for k in 0..3 {
            let t = first.unwrap() + k as u64 * 1_000_000_000;
            let pts: Vec<_> = world
                .iter()
                .map(|p| world_from_camera(k).inverse() * p)
                .collect();
            let header = Header {
                stamp: Time::from_ns(t as i64).unwrap(),
                frame_id: "base_scan".into(),
            };
            log.write(ch, t, t, &cdr::encode_point_cloud2(&header, &pts, None))
                .unwrap();
        }
        log.finish().unwrap();
    }
    let summary = register_log(&options(&input, &out, 0.1)).unwrap();
    assert_eq!(summary.tf_topic, "/mireg/tf", "the log has /tf already");
    let (original, output) = (contents(&nav2), contents(&out));
    assert_superset(&original, &output);
    assert_eq!(
        output
            .messages
            .iter()
            .filter(|m| m.0 == "/mireg/tf")
            .count(),
        3
    );
}

#[test]
fn cli_register_json_summary() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("o.mcap");
    let (input, output) = (fixture(), out.to_str().unwrap().to_string());
    // --quiet suppresses the summary unless --json asks for it.
    let run = mireg_ok(&[
        "register",
        input.to_str().unwrap(),
        "-o",
        &output,
        "--json",
        "--quiet",
    ]);
    let v: serde_json::Value = serde_json::from_slice(&run.stdout).unwrap();
    assert_eq!(v["frames"], 71);
    assert!(out.exists());
    let again = mireg(&["register", input.to_str().unwrap(), "-o", &output]);
    assert_eq!(again.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&again.stderr).contains("exists"));
}

#[test]
fn foxglove_point_clouds_get_foxglove_poses() {
    use foxglove::schemas::packed_element_field::NumericType;
    use foxglove::schemas::{PackedElementField, PointCloud, Timestamp};
    use prost::Message;

    let dir = tempfile::tempdir().unwrap();
    let (input, out) = (dir.path().join("fox.mcap"), dir.path().join("out.mcap"));
    let schema = mireg::io::codec::foxglove::point_cloud_schema();
    {
        let file = std::io::BufWriter::new(std::fs::File::create(&input).unwrap());
        let mut w = mcap::WriteOptions::new().create(file).unwrap();
        let s = w
            .add_schema(&schema.name, &schema.encoding, &schema.data)
            .unwrap();
        let ch = w
            .add_channel(s, "/lidar", "protobuf", &BTreeMap::new())
            .unwrap();
        let world = scene(4);
        for k in 0..4u32 {
            let cam_from_world = world_from_camera(k as usize).inverse();
            let mut data = Vec::new();
            for p in &world {
                let q = cam_from_world * p;
                for c in [q.x as f32, q.y as f32, q.z as f32] {
                    data.extend(c.to_le_bytes());
                }
            }
            let field = |name: &str, offset| PackedElementField {
                name: name.into(),
                offset,
                r#type: NumericType::Float32 as i32,
            };
            let msg = PointCloud {
                timestamp: Some(Timestamp::new(1_700_000_000 + k, 0)),
                frame_id: "lidar".into(),
                pose: None,
                point_stride: 12,
                fields: vec![field("x", 0), field("y", 4), field("z", 8)],
                data: data.into(),
            };
            let t = (1_700_000_000 + k as u64) * 1_000_000_000;
            w.write_to_known_channel(
                &MessageHeader {
                    channel_id: ch,
                    sequence: k,
                    log_time: t,
                    publish_time: t,
                },
                &msg.encode_to_vec(),
            )
            .unwrap();
        }
        w.finish().unwrap();
    }
    let summary = register_log(&options(&input, &out, 0.1)).unwrap();
    assert_eq!((summary.frames, summary.failed_frames), (4, 0));
    let mut schemas = BTreeMap::new();
    let mut pose_channel = None;
    let mut poses = Vec::new();
    for_each_record(&out, |r| {
        match r {
            Record::Schema { header, .. } => {
                schemas.insert(header.id, header.name);
            }
            Record::Channel(c) if c.topic == "/mireg/pose" => {
                assert_eq!(schemas[&c.schema_id], "foxglove.PoseInFrame");
                pose_channel = Some(c.id);
            }
            Record::Channel(c) if c.topic == "/tf" => {
                assert_eq!(schemas[&c.schema_id], "foxglove.FrameTransforms")
            }
            Record::Message { header, data } if Some(header.channel_id) == pose_channel => {
                let p = foxglove::schemas::PoseInFrame::decode(&data[..]).unwrap();
                assert_eq!(p.frame_id, "world");
                poses.push(p);
            }
            _ => {}
        }
        Ok(())
    })
    .unwrap();
    assert_eq!(poses.len(), 4);
    for (k, p) in poses.iter().enumerate() {
        let pose = p.pose.as_ref().unwrap();
        let (t, q) = (
            pose.position.as_ref().unwrap(),
            pose.orientation.as_ref().unwrap(),
        );
        let est = Isometry3::from_parts(
            Translation3::new(t.x, t.y, t.z),
            UnitQuaternion::from_quaternion(nalgebra::Quaternion::new(q.w, q.x, q.y, q.z)),
        );
        let truth = world_from_camera(0).inverse() * world_from_camera(k);
        let (r, e) = pose_error(&truth, &est);
        assert!(r < 0.3 && e < 0.01, "frame {k}: {r:.3}° {e:.4} m");
    }
}

/// Top-level records of an MCAP file, walked independently of mireg and of the `mcap` crate:
/// (offset, opcode, body), from the header to the footer.
fn walk_records(bytes: &[u8]) -> Vec<(u64, u8, &[u8])> {
    assert_eq!(&bytes[..8], mcap::MAGIC, "leading magic");
    assert_eq!(&bytes[bytes.len() - 8..], mcap::MAGIC, "trailing magic");
    let mut out = Vec::new();
    let mut pos = 8usize;
    loop {
        let opcode = bytes[pos];
        let len = u64::from_le_bytes(bytes[pos + 1..pos + 9].try_into().unwrap()) as usize;
        out.push((pos as u64, opcode, &bytes[pos + 9..pos + 9 + len]));
        pos += 9 + len;
        if opcode == mcap::records::op::FOOTER {
            assert_eq!(pos, bytes.len() - 8, "footer followed by the magic");
            return out;
        }
    }
}

/// Each chunk record of the data section with the message-index records right after it, as raw
/// bytes (opcode, length and body of each record).
fn chunk_groups(bytes: &[u8]) -> Vec<Vec<u8>> {
    use mcap::records::op;
    let mut groups: Vec<Vec<u8>> = Vec::new();
    let mut in_group = false;
    for (offset, opcode, body) in walk_records(bytes) {
        let raw = &bytes[offset as usize..offset as usize + 9 + body.len()];
        match opcode {
            op::CHUNK => {
                groups.push(raw.to_vec());
                in_group = true;
            }
            op::MESSAGE_INDEX if in_group => groups.last_mut().unwrap().extend_from_slice(raw),
            op::DATA_END => break,
            _ => in_group = false,
        }
    }
    groups
}

/// Every CRC of the file (chunks, data section, summary section) checked by the `mcap` crate's
/// linear reader.
fn check_crcs(bytes: &[u8]) {
    use mcap::sans_io::{LinearReadEvent, LinearReader, LinearReaderOptions};
    let mut reader = LinearReader::new_with_options(
        LinearReaderOptions::default()
            .with_validate_chunk_crcs(true)
            .with_validate_data_section_crc(true)
            .with_validate_summary_section_crc(true),
    );
    let mut rest = bytes;
    while let Some(event) = reader.next_event() {
        match event.expect("valid MCAP with matching CRCs") {
            LinearReadEvent::ReadRequest(need) => {
                let n = need.min(rest.len());
                reader.insert(n).copy_from_slice(&rest[..n]);
                reader.notify_read(n);
                rest = &rest[n..];
            }
            LinearReadEvent::Record { .. } => {}
        }
    }
}

/// Checks that `output`'s summary section agrees with its records: statistics against a
/// brute-force count of the messages, chunk indexes against the chunk and message-index records
/// they point at, the channel and schema lists against the records of the data section, and that
/// reading through the indexes finds every message.
fn check_summary(output: &Path) {
    use mcap::records::{ChunkHeader, MessageIndex, op};
    let bytes = std::fs::read(output).unwrap();
    check_crcs(&bytes);
    let summary = mcap::Summary::read(&bytes).unwrap().expect("a summary");
    let stats = summary.stats.as_ref().expect("statistics");

    // Brute force: every message of the file, linearly.
    let mut counts: BTreeMap<u16, u64> = BTreeMap::new();
    let (mut first, mut last) = (u64::MAX, 0u64);
    for m in mcap::MessageStream::new(&bytes).unwrap() {
        let m = m.unwrap();
        *counts.entry(m.channel.id).or_default() += 1;
        first = first.min(m.log_time);
        last = last.max(m.log_time);
    }
    let total: u64 = counts.values().sum();
    assert!(total > 0);
    assert_eq!(stats.message_count, total);
    assert_eq!(stats.channel_message_counts, counts);
    assert_eq!(
        (stats.message_start_time, stats.message_end_time),
        (first, last)
    );

    // Schemas and channels: every record of the data section is listed, identical.
    let records = walk_records(&bytes);
    let (mut schemas, mut channels, mut chunks, mut metadata, mut attachments) =
        (BTreeMap::new(), BTreeMap::new(), 0u32, 0u32, 0u32);
    for &(_, opcode, body) in records.iter().take_while(|r| r.1 != op::DATA_END) {
        match mcap::parse_record(opcode, body).unwrap() {
            Record::Schema { header, data } => {
                schemas.insert(header.id, (header.name, header.encoding, data.to_vec()));
            }
            Record::Channel(c) => {
                channels.insert(c.id, c);
            }
            Record::Chunk { header, data } => {
                chunks += 1;
                for r in mcap::read::ChunkReader::new(header, &data).unwrap() {
                    match r.unwrap() {
                        Record::Schema { header, data } => {
                            schemas
                                .insert(header.id, (header.name, header.encoding, data.to_vec()));
                        }
                        Record::Channel(c) => {
                            channels.insert(c.id, c);
                        }
                        _ => {}
                    }
                }
            }
            Record::Metadata(_) => metadata += 1,
            Record::Attachment { .. } => attachments += 1,
            _ => {}
        }
    }
    assert_eq!(stats.channel_count as usize, channels.len());
    assert_eq!(stats.schema_count as usize, schemas.len());
    assert_eq!(
        (
            stats.chunk_count,
            stats.metadata_count,
            stats.attachment_count
        ),
        (chunks, metadata, attachments)
    );
    for (id, c) in &channels {
        let s = &summary.channels[id];
        assert_eq!(
            (&s.topic, &s.message_encoding, &s.metadata),
            (&c.topic, &c.message_encoding, &c.metadata)
        );
        assert_eq!(s.schema.as_ref().map_or(0, |s| s.id), c.schema_id);
    }
    for (id, (name, encoding, data)) in &schemas {
        let s = &summary.schemas[id];
        assert_eq!(
            (&s.name, &s.encoding, &s.data[..]),
            (name, encoding, &data[..])
        );
    }

    // Chunk indexes point at the chunk records and their message indexes.
    assert_eq!(summary.chunk_indexes.len() as u32, chunks);
    let at: BTreeMap<u64, (u8, &[u8])> = records.iter().map(|&(o, op, b)| (o, (op, b))).collect();
    let mut indexed = 0u64;
    for ci in &summary.chunk_indexes {
        let (opcode, body) = at[&ci.chunk_start_offset];
        assert_eq!(opcode, op::CHUNK);
        assert_eq!(ci.chunk_length, 9 + body.len() as u64);
        let Record::Chunk { header, .. } = mcap::parse_record(opcode, body).unwrap() else {
            unreachable!()
        };
        let ChunkHeader {
            message_start_time,
            message_end_time,
            uncompressed_size,
            compression,
            compressed_size,
            ..
        } = header;
        assert_eq!(
            (
                ci.message_start_time,
                ci.message_end_time,
                ci.uncompressed_size,
                &ci.compression,
                ci.compressed_size
            ),
            (
                message_start_time,
                message_end_time,
                uncompressed_size,
                &compression,
                compressed_size
            )
        );
        let mut index_bytes = 0;
        for (&channel, &offset) in &ci.message_index_offsets {
            let (opcode, body) = at[&offset];
            assert_eq!(opcode, op::MESSAGE_INDEX);
            let Record::MessageIndex(MessageIndex { channel_id, .. }) =
                mcap::parse_record(opcode, body).unwrap()
            else {
                unreachable!()
            };
            assert_eq!(channel_id, channel);
            index_bytes += 9 + body.len() as u64;
        }
        assert_eq!(ci.message_index_length, index_bytes);
        let in_chunk = summary.stream_chunk(&bytes, ci).unwrap().count() as u64;
        // Message indexes are optional (an unindexed input's chunks have none).
        if !ci.message_index_offsets.is_empty() {
            let through_index = summary
                .read_message_indexes(&bytes, ci)
                .unwrap()
                .values()
                .map(|v| v.len() as u64)
                .sum::<u64>();
            assert_eq!(
                through_index, in_chunk,
                "message index of chunk at {}",
                ci.chunk_start_offset
            );
        }
        indexed += in_chunk;
    }
    assert_eq!(indexed, total, "reading through the chunk indexes");
    // Metadata and attachment indexes point at their records.
    for mi in &summary.metadata_indexes {
        let m = mcap::read::metadata(&bytes, mi).unwrap();
        assert_eq!(m.name, mi.name);
    }
    for ai in &summary.attachment_indexes {
        let a = mcap::read::attachment(&bytes, ai).unwrap();
        assert_eq!(
            (a.name.as_str(), a.data.len() as u64),
            (ai.name.as_str(), ai.data_size)
        );
    }
}

/// Input chunks (with their message indexes) appear in the output byte for byte, in order.
fn assert_chunks_copied(input: &Path, output: &Path) {
    let (a, b) = (
        std::fs::read(input).unwrap(),
        std::fs::read(output).unwrap(),
    );
    let (ins, outs) = (chunk_groups(&a), chunk_groups(&b));
    assert!(!ins.is_empty(), "{} has chunks", input.display());
    let mut next = 0;
    for (k, g) in ins.iter().enumerate() {
        let found = outs[next..]
            .iter()
            .position(|o| o == g)
            .unwrap_or_else(|| panic!("input chunk {k} is not in the output byte for byte"));
        next += found + 1;
    }
}

#[test]
fn input_chunks_are_copied_byte_for_byte() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("fixture_out.mcap");
    register_log(&options(&fixture(), &out, 0.05)).unwrap();
    assert_chunks_copied(&fixture(), &out);
    check_summary(&out);
    for (name, compression) in [
        ("zstd", Some(mcap::Compression::Zstd)),
        ("lz4", Some(mcap::Compression::Lz4)),
        ("none", None),
    ] {
        let (input, out) = (
            dir.path().join(format!("{name}.mcap")),
            dir.path().join(format!("{name}_out.mcap")),
        );
        write_log_with(&input, 4, |o| {
            o.compression(compression).chunk_size(Some(4096))
        });
        let summary = register_log(&options(&input, &out, 0.1)).unwrap();
        assert_eq!((summary.frames, summary.failed_frames), (4, 0), "{name}");
        assert_chunks_copied(&input, &out);
        assert_superset(&contents(&input), &contents(&out));
        check_summary(&out);
    }
}

#[test]
fn output_summary_matches_a_brute_force_count() {
    let dir = tempfile::tempdir().unwrap();
    let (input, out) = (dir.path().join("in.mcap"), dir.path().join("out.mcap"));
    write_synthetic_log(&input, 5);
    let summary = register_log(&options(&input, &out, 0.1)).unwrap();
    check_summary(&out);
    let bytes = std::fs::read(&out).unwrap();
    let s = mcap::Summary::read(&bytes).unwrap().unwrap();
    // 5 frames: 5 messages on each of the 3 input channels and on each of ours.
    let by_topic: BTreeMap<String, u64> = s
        .channels
        .values()
        .map(|c| {
            (
                c.topic.clone(),
                s.stats
                    .as_ref()
                    .unwrap()
                    .channel_message_counts
                    .get(&c.id)
                    .copied()
                    .unwrap_or(0),
            )
        })
        .collect();
    for topic in [
        "/sensor/points",
        "/notes",
        "/raw",
        "/tf",
        "/mireg/pose",
        "/mireg/stats",
    ] {
        assert_eq!(by_topic[topic], 5, "{topic}");
    }
    assert_eq!(summary.messages_copied, 15);
    // The input's channel ids are kept; ours come after them.
    let input_bytes = std::fs::read(&input).unwrap();
    let s_in = mcap::Summary::read(&input_bytes).unwrap().unwrap();
    for (id, c) in &s_in.channels {
        assert_eq!(s.channels[id].topic, c.topic);
    }
    let max_in = *s_in.channels.keys().max().unwrap();
    for c in s
        .channels
        .values()
        .filter(|c| c.topic.starts_with("/mireg") || c.topic == "/tf")
    {
        assert!(c.id > max_in, "{} has id {}", c.topic, c.id);
    }
}

#[test]
fn unchunked_unindexed_and_summaryless_inputs_pass_through() {
    let dir = tempfile::tempdir().unwrap();
    for name in ["unchunked", "unindexed", "no summary"] {
        let (input, out) = (
            dir.path().join(format!("{name}.mcap")),
            dir.path().join(format!("{name}_out.mcap")),
        );
        write_log_with(&input, 4, |o| match name {
            "unchunked" => o.use_chunks(false),
            "unindexed" => o.emit_message_indexes(false).chunk_size(Some(4096)),
            _ => o
                .chunk_size(Some(4096))
                .emit_summary_records(false)
                .emit_statistics(false)
                .emit_chunk_indexes(false)
                .emit_attachment_indexes(false)
                .emit_metadata_indexes(false)
                .emit_summary_offsets(false),
        });
        let bytes = std::fs::read(&input).unwrap();
        let records = walk_records(&bytes);
        let count = |opcode| records.iter().filter(|r| r.1 == opcode).count();
        use mcap::records::op;
        let intended = match name {
            "unchunked" => count(op::CHUNK) == 0 && count(op::MESSAGE) == 12,
            "unindexed" => count(op::CHUNK) > 0 && count(op::MESSAGE_INDEX) == 0,
            // Channels only inside chunks, none in a summary: found by a pre-scan.
            _ => count(op::CHUNK) > 0 && count(op::CHANNEL) == 0 && count(op::CHUNK_INDEX) == 0,
        };
        assert!(intended, "{name}: the input is as intended");
        let summary = register_log(&options(&input, &out, 0.1)).unwrap();
        assert_eq!((summary.frames, summary.failed_frames), (4, 0), "{name}");
        assert_eq!(summary.messages_copied, 12, "{name}");
        let (a, b) = (contents(&input), contents(&out));
        assert_superset(&a, &b);
        assert_eq!(b.metadata.len(), a.metadata.len() + 1);
        check_summary(&out);
        if name != "unchunked" {
            assert_chunks_copied(&input, &out);
        }
    }
}

#[test]
fn corrupt_chunk_that_is_only_copied_fails_cleanly() {
    let dir = tempfile::tempdir().unwrap();
    let input = dir.path().join("in.mcap");
    // Uncompressed chunks: a flipped payload byte can only be caught by the chunk CRC.
    write_log_with(&input, 4, |o| o.compression(None).chunk_size(Some(4096)));
    let bytes = std::fs::read(&input).unwrap();
    // The last chunk holding a /raw message and no cloud: only copied and validated.
    let summary = mcap::Summary::read(&bytes).unwrap().unwrap();
    let raw = summary
        .channels
        .values()
        .find(|c| c.topic == "/raw")
        .unwrap()
        .id;
    let clouds = summary
        .channels
        .values()
        .find(|c| c.topic == "/sensor/points")
        .unwrap()
        .id;
    let ci = summary
        .chunk_indexes
        .iter()
        .rev()
        .find(|ci| {
            ci.message_index_offsets.contains_key(&raw)
                && !ci.message_index_offsets.contains_key(&clouds)
        })
        .expect("a chunk without clouds");
    let mut corrupt = bytes.clone();
    let last_byte = (ci.chunk_start_offset + ci.chunk_length - 1) as usize;
    corrupt[last_byte] ^= 0x01;
    let path = dir.path().join("corrupt.mcap");
    std::fs::write(&path, &corrupt).unwrap();
    let out = dir.path().join("out.mcap");
    let err = register_log(&options(&path, &out, 0.1))
        .unwrap_err()
        .to_string();
    assert!(
        err.contains(&path.display().to_string()) && err.contains("CRC"),
        "{err}"
    );
    assert!(!out.exists());
    no_partial_files(dir.path());
}

/// The map's fine stage runs by default, `--no-map-fine` turns it off (per-frame statistics
/// `map_fine_icp_iterations`), and `--map-fine` with `--no-map-fine` is a usage error.
#[test]
fn cli_map_fine_is_on_by_default_and_can_be_turned_off() {
    let dir = tempfile::tempdir().unwrap();
    let fine_iterations = |extra: &[&str]| -> Vec<u64> {
        let out = dir.path().join("fine.mcap");
        let (input, output) = (fixture(), out.to_str().unwrap().to_string());
        let mut args = vec!["register", input.to_str().unwrap(), "-o", &output];
        args.extend(["--force", "--quiet"]);
        args.extend(extra);
        mireg_ok(&args);
        let c = contents(&out);
        (c.messages.iter().filter(|m| m.0 == "/mireg/stats"))
            .filter_map(|m| {
                let v: serde_json::Value = serde_json::from_slice(&m.3).unwrap();
                v["map_fine_icp_iterations"].as_u64()
            })
            .collect()
    };
    let on = fine_iterations(&[]);
    assert!(
        on.iter().filter(|&&n| n > 0).count() > on.len() / 2,
        "{on:?}"
    );
    assert_eq!(fine_iterations(&["--map-fine"]), on);
    let off = fine_iterations(&["--no-map-fine"]);
    assert!(!off.is_empty() && off.iter().all(|&n| n == 0), "{off:?}");
    let input = fixture();
    let both = mireg(&[
        "register",
        input.to_str().unwrap(),
        "--map-fine",
        "--no-map-fine",
    ]);
    assert_eq!(both.status.code(), Some(2));
}
