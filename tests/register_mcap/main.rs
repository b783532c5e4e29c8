//! `mireg register` end to end: pass-through of every input record, recovered motion against
//! known transforms, the reference trajectory of the fixture, and clean failure on bad input.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use mcap::records::{MessageHeader, Record};
use mireg::io::codec::{Header, Time, cdr};
use mireg::io::log_order::ChunkTimes;

#[path = "../common/log_contents.rs"]
mod log_contents;
use log_contents::{Contents, assert_superset, contents, topic_messages};
#[path = "../common/synthetic_log.rs"]
mod synthetic_log;
use mireg::io::mcap::log::for_each_record;
use mireg::odometry::OdometryConfig;
use mireg::pipeline::{PairConfig, pose_error};
use mireg::register::{RegisterOptions, register_log};
use nalgebra::{Isometry3, Translation3, UnitQuaternion};
use synthetic_log::{scene, world_from_camera, write_log_full};

mod records;

fn fixture() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("fixtures/icl_livingroom1.mcap")
}

#[path = "../common/cli.rs"]
mod cli;
use cli::{mireg, mireg_ok};

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
    topic_messages(path, topic)
        .iter()
        .map(|data| {
            let (h, p) = cdr::decode_pose_stamped(data).unwrap();
            (h.stamp.to_ns(), p)
        })
        .collect()
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

/// With `--strict` (a cut log is read as far as it goes by default: tests/salvage.rs).
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
        let strict = RegisterOptions {
            read_policy: mireg::io::damage::ReadPolicy::STRICT,
            ..options(input, &out, 0.05)
        };
        let err = register_log(&strict).unwrap_err().to_string();
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
            .add_cdr_channel("/scan/points", cdr::POINT_CLOUD2)
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

/// Tracking first is the default (per-frame statistics `map_guess` `"tracked"` on the fixture,
/// whose depth camera moves smoothly), `--global-every-frame` registers every frame globally
/// (no frame tracked, each refined from a global start), and `--track-first` (the old opt-in)
/// changes nothing but conflicts with `--global-every-frame`. A tracked frame has no global
/// registration: its RANSAC figures are null, not 0, and the summary counts it as tracked and
/// leaves it out of the mean inliers.
#[test]
fn cli_tracks_first_by_default_and_can_register_every_frame_globally() {
    let dir = tempfile::tempdir().unwrap();
    // Per frame after the first: the map guess and the RANSAC inliers; and the summary.
    let run = |extra: &[&str]| -> (Vec<(String, Option<u64>)>, serde_json::Value) {
        let out = dir.path().join("guess.mcap");
        let (input, output) = (fixture(), out.to_str().unwrap().to_string());
        let mut args = vec!["register", input.to_str().unwrap(), "-o", &output];
        args.extend(["--force", "--quiet", "--no-loops", "--json"]);
        args.extend(extra);
        let summary: serde_json::Value = serde_json::from_slice(&mireg_ok(&args).stdout).unwrap();
        let c = contents(&out);
        let frames = (c.messages.iter().filter(|m| m.0 == "/mireg/stats"))
            .filter_map(|m| {
                let v: serde_json::Value = serde_json::from_slice(&m.3).unwrap();
                let guess = v["map_guess"].as_str()?.to_string();
                Some((guess, v["num_inliers"].as_u64()))
            })
            .collect();
        (frames, summary)
    };
    let (default, summary) = run(&[]);
    let tracked: Vec<_> = default.iter().filter(|(g, _)| g == "tracked").collect();
    assert!(tracked.len() > default.len() / 2, "{default:?}");
    assert!(tracked.iter().all(|(_, n)| n.is_none()), "{default:?}");
    let global: Vec<u64> = default
        .iter()
        .filter(|(g, _)| g != "tracked")
        .map(|(g, n)| n.unwrap_or_else(|| panic!("a {g} frame without inliers")))
        .collect();
    assert_eq!(
        summary["tracked_frames"].as_u64(),
        Some(tracked.len() as u64)
    );
    let mean = global.iter().sum::<u64>() as f64 / global.len() as f64;
    let reported = summary["mean_inliers"].as_f64().unwrap();
    assert!((reported - mean).abs() < 1e-9, "{reported} against {mean}");
    assert_eq!(run(&["--track-first"]).0, default);
    let (global, summary) = run(&["--global-every-frame"]);
    assert_eq!(global.len(), default.len());
    assert!(
        global
            .iter()
            .all(|(g, n)| g.ends_with("global") && n.is_some_and(|n| n > 0)),
        "{global:?}"
    );
    assert_eq!(summary["tracked_frames"].as_u64(), Some(0));
    assert_usage_error(&["--track-first", "--global-every-frame"]);
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
    assert_usage_error(&["--map-fine", "--no-map-fine"]);
}

/// `mireg register` of the fixture with `flags` exits with clap's usage error (2).
fn assert_usage_error(flags: &[&str]) {
    let input = fixture();
    let mut args = vec!["register", input.to_str().unwrap()];
    args.extend(flags);
    let run = mireg(&args);
    assert_eq!(run.status.code(), Some(2), "{flags:?}");
}
