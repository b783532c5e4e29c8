//! The summary of `mireg register` names the failed and suspect frames (index, stamp, reason; at
//! most ten, then a count) and warns when one step carries most of the error against the
//! reference (issue 47, item 5).

use std::borrow::Cow;
use std::path::Path;

use mireg::fuzzing::small_log;
use mireg::io::codec::cdr;
use nalgebra::{Isometry3, Translation3};

#[path = "common/cli.rs"]
mod cli;

/// Frames of the test log.
const FRAMES: usize = 20;
/// Frames whose cloud is replaced by bytes that do not decode: 3..=14, twelve failed frames.
const BROKEN: std::ops::RangeInclusive<usize> = 3..=14;
/// From this frame on, the reference is moved 1 m along x: one broken step in the reference.
const JUMP_AT: usize = 17;

/// [`small_log`] of [`FRAMES`] frames with the clouds of [`BROKEN`] replaced by garbage and the
/// reference poses from [`JUMP_AT`] on moved 1 m.
fn log_with_failures_and_a_jump(path: &Path) {
    let input = small_log(FRAMES, mcap::WriteOptions::new());
    let mut out = std::io::BufWriter::new(std::fs::File::create(path).unwrap());
    let mut w = mcap::WriteOptions::new()
        .profile("ros2")
        .create(&mut out)
        .unwrap();
    for m in mcap::MessageStream::new(&input).unwrap() {
        let mut m = m.unwrap();
        let k = m.sequence as usize;
        if m.channel.topic == "/points" && BROKEN.contains(&k) {
            m.data = Cow::Owned(b"not a point cloud".to_vec());
        }
        if m.channel.topic == "/ground_truth/pose" && k >= JUMP_AT {
            let (header, pose) = cdr::decode_pose_stamped(&m.data).unwrap();
            let moved =
                Isometry3::from_parts(Translation3::new(1.0, 0.0, 0.0), Default::default()) * pose;
            m.data = Cow::Owned(cdr::encode_pose_stamped(&header, &moved));
        }
        w.write(&m).unwrap();
    }
    w.finish().unwrap();
}

#[test]
fn the_summary_names_failed_frames_and_the_step_that_broke_the_trajectory() {
    let dir = tempfile::tempdir().unwrap();
    let input = dir.path().join("broken.mcap");
    log_with_failures_and_a_jump(&input);
    let output = dir.path().join("out.mcap");
    let (input, output) = (input.to_str().unwrap(), output.to_str().unwrap());
    let args = |extra: &[&'static str]| {
        let mut a = vec![
            "register",
            input,
            "-o",
            output,
            "--voxel",
            "0.05",
            "--no-loops",
            "--force",
        ];
        a.extend_from_slice(extra);
        a
    };

    let run = cli::mireg_ok(&args(&["--json"]));
    let summary: serde_json::Value = serde_json::from_slice(&run.stdout).unwrap();
    assert_eq!(summary["failed_frames"], BROKEN.count());
    let flagged = summary["flagged"].as_array().unwrap();
    assert_eq!(flagged.len(), 10, "at most ten listed: {flagged:?}");
    let t0 = 1_700_000_000_000_000_000i64;
    for (f, k) in flagged.iter().zip(BROKEN) {
        assert_eq!(f["frame"], k, "{f}");
        assert_eq!(f["stamp_ns"], t0 + k as i64 * 100_000_000, "{f}");
        assert_eq!(f["flag"], "failed", "{f}");
        assert_eq!(f["reason"], "invalid_cloud", "{f}");
    }
    let dominant = &summary["reference"]["dominant_step"];
    assert_eq!(dominant["frame"], JUMP_AT, "{dominant}");
    assert_eq!(dominant["error"], "translation", "{dominant}");
    assert!(
        (dominant["value"].as_f64().unwrap() - 1.0).abs() < 0.05,
        "the 1 m jump: {dominant}"
    );
    assert!(dominant["share"].as_f64().unwrap() > 0.5, "{dominant}");

    let run = cli::mireg_ok(&args(&[]));
    let text = String::from_utf8_lossy(&run.stdout).into_owned();
    assert!(
        text.contains(&format!(
            "flagged frames ({} failed, 0 suspect",
            BROKEN.count()
        )),
        "{text}"
    );
    for k in BROKEN.take(10) {
        let ns = t0 + k as i64 * 100_000_000;
        let stamp = format!("{}.{:09} s", ns / 1_000_000_000, ns % 1_000_000_000);
        assert!(
            text.contains(&format!("frame {k} (stamp {stamp}): failed, invalid_cloud")),
            "frame {k}: {text}"
        );
    }
    assert!(!text.contains("frame 13 (stamp"), "{text}");
    assert!(text.contains("... and 2 more"), "{text}");
    assert!(
        text.contains(&format!(
            "odometry: warning: the step to frame {JUMP_AT} (stamp 1700000001.700000000 s) carries"
        )),
        "{text}"
    );
}

/// A clean run lists nothing and warns of nothing.
#[test]
fn a_clean_run_flags_nothing() {
    let dir = tempfile::tempdir().unwrap();
    let input = dir.path().join("clean.mcap");
    std::fs::write(&input, small_log(8, mcap::WriteOptions::new())).unwrap();
    let output = dir.path().join("out.mcap");
    let run = cli::mireg_ok(&[
        "register",
        input.to_str().unwrap(),
        "-o",
        output.to_str().unwrap(),
        "--voxel",
        "0.05",
        "--no-loops",
    ]);
    let text = String::from_utf8_lossy(&run.stdout).into_owned();
    assert!(text.contains("failed frames 0"), "{text}");
    assert!(
        !text.contains("flagged frames") && !text.contains("warning"),
        "{text}"
    );
}
