//! Loop closure in `mireg register`, end to end: every accepted loop of the fixture against the
//! reference trajectory, the optimised trajectory of a log that never revisits a place against
//! its odometry, and `--no-loops`.

use std::path::{Path, PathBuf};

use mireg::io::poses::read_mcap_pose_topic;
use mireg::pipeline::pose_error;

#[path = "common/cli.rs"]
mod cli;
#[path = "common/log_contents.rs"]
mod log_contents;
use log_contents::contents;
#[path = "common/loop_records.rs"]
mod loop_records;
use loop_records::{assert_accepted_loops_match, loops, poses_by_stamp};
#[path = "common/synthetic_log.rs"]
mod synthetic_log;

fn fixture() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("fixtures/icl_livingroom1.mcap")
}

/// `mireg ARGS`, which must succeed; its stdout.
fn mireg_stdout(args: &[&str]) -> String {
    String::from_utf8(cli::mireg_ok(args).stdout).unwrap()
}

fn s(p: &Path) -> &str {
    p.to_str().unwrap()
}

/// Every loop the fixture's run accepts is right: its relative pose within 2° and 2 voxels of
/// the reference's (the loop precision of 100 %), and each candidate tried is a message
/// with a verdict; the summary counts them.
#[test]
fn every_accepted_loop_of_the_fixture_matches_the_reference() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("out.mcap");
    let summary: serde_json::Value = serde_json::from_str(&mireg_stdout(&[
        "register",
        s(&fixture()),
        "-o",
        s(&out),
        "--json",
        "--quiet",
    ]))
    .unwrap();
    let voxel = summary["voxel_m"].as_f64().unwrap();
    let reference = poses_by_stamp(&out, "/ground_truth/pose");
    let tried = loops(&out);
    assert_eq!(tried.len() as u64, summary["loops"]["candidates"]);
    let accepted = assert_accepted_loops_match(&tried, &reference, voxel);
    assert_eq!(accepted as u64, summary["loops"]["accepted"]);
    assert!(accepted > 0, "the fixture revisits its room");
    for l in &tried {
        assert!(l["verdict"] == "accepted" || !l["reason"].as_str().unwrap().is_empty());
    }
    // The optimised trajectory covers every frame, at the odometry's stamps.
    let odometry = poses_by_stamp(&out, "/mireg/pose");
    let optimized = poses_by_stamp(&out, "/mireg/pose_optimized");
    let mut a: Vec<i64> = odometry.keys().copied().collect();
    let mut b: Vec<i64> = optimized.keys().copied().collect();
    a.sort_unstable();
    b.sort_unstable();
    assert_eq!(a, b);
}

/// A log that never returns: the synthetic camera moves away along a line, so no two frames far
/// apart in path are close in space; whatever loops appearance proposes must agree with the
/// odometry, and the optimised trajectory equals the odometry within 1 mm and 0.01°.
/// `--no-loops` writes neither topic.
#[test]
fn a_log_without_revisits_keeps_its_odometry() {
    let dir = tempfile::tempdir().unwrap();
    let log = dir.path().join("line.mcap");
    synthetic_log::write_log_full(&log, &(0..16).collect::<Vec<_>>(), None, |o| o);
    let out = dir.path().join("out.mcap");
    mireg_stdout(&["register", s(&log), "-o", s(&out), "--quiet"]);
    let odometry = poses_by_stamp(&out, "/mireg/pose");
    let optimized = poses_by_stamp(&out, "/mireg/pose_optimized");
    assert_eq!(odometry.len(), 16);
    for (stamp, p) in &odometry {
        let (deg, metres) = pose_error(p, &optimized[stamp]);
        assert!(deg < 0.01 && metres < 1e-3, "{stamp}: {deg}°, {metres} m");
    }

    let bare = dir.path().join("bare.mcap");
    mireg_stdout(&["register", s(&log), "-o", s(&bare), "--quiet", "--no-loops"]);
    let topics: Vec<String> = contents(&bare).messages.into_iter().map(|m| m.0).collect();
    assert!(
        !topics
            .iter()
            .any(|t| t == "/mireg/loops" || t == "/mireg/pose_optimized")
    );
    // The odometry does not depend on loop closure.
    assert_eq!(poses_by_stamp(&bare, "/mireg/pose"), odometry);
}

/// The same seed gives the same loop-closed trajectory on one thread and on two (candidates are
/// verified in parallel).
#[test]
fn loop_closure_is_independent_of_the_thread_count() {
    let dir = tempfile::tempdir().unwrap();
    let run = |threads: &str| {
        let out = dir.path().join(format!("out{threads}.mcap"));
        let status = std::process::Command::new(env!("CARGO_BIN_EXE_mireg"))
            .args(["register", s(&fixture()), "-o", s(&out), "--quiet"])
            .env("RAYON_NUM_THREADS", threads)
            .status()
            .unwrap();
        assert!(status.success());
        let t = read_mcap_pose_topic(&out, "/mireg/pose_optimized").unwrap();
        (t.stamps_ns, t.poses)
    };
    assert_eq!(run("1"), run("2"));
}

/// The keyframes kept from the odometry verify exactly as the same frames read and prepared
/// again: the same candidates, verdicts, relative poses and loop-closed trajectory, bit for bit,
/// with and without [`LoopConfig::keep_odometry_frames`] (and with a thinned ICP source, so that
/// the ICP cloud's point order matters too).
#[test]
fn frames_kept_from_the_odometry_verify_as_frames_read_again() {
    use mireg::loops::LoopConfig;
    use mireg::odometry::OdometryConfig;
    use mireg::register::{RegisterOptions, register_log};

    let dir = tempfile::tempdir().unwrap();
    let input = fixture();
    let options = |name: &str| RegisterOptions {
        derive_voxel: true,
        force: true,
        ..RegisterOptions::new(&input, &dir.path().join(name), OdometryConfig::default())
    };
    // The voxel `register` derives, from a run without loops.
    let voxel = register_log(&RegisterOptions {
        loops: false,
        ..options("voxel.mcap")
    })
    .unwrap()
    .voxel_m;
    let run = |name: &str, keep: bool| {
        let opts = RegisterOptions {
            loop_config: Some(LoopConfig {
                keep_odometry_frames: keep,
                icp_source_points: Some(300),
                ..LoopConfig::for_voxel(voxel)
            }),
            ..options(name)
        };
        let output = opts.output.clone();
        let summary = register_log(&opts).unwrap();
        let records: Vec<serde_json::Value> = loops(&output)
            .into_iter()
            .map(|mut r| {
                let o = r.as_object_mut().unwrap();
                o.remove("verify_s");
                o.remove("timings_s");
                r
            })
            .collect();
        let t = read_mcap_pose_topic(&output, "/mireg/pose_optimized").unwrap();
        (summary, records, t.poses)
    };
    let (kept_summary, kept, kept_poses) = run("kept.mcap", true);
    let (read_summary, read, read_poses) = run("read.mcap", false);
    let loops_of = |s: &mireg::register::RegisterSummary| s.loops.clone().unwrap();
    assert!(loops_of(&kept_summary).accepted > 0);
    assert_eq!(
        loops_of(&kept_summary).passes,
        0,
        "the fixture's keyframes all fit"
    );
    assert!(
        loops_of(&read_summary).passes > 0,
        "{:?}",
        loops_of(&read_summary)
    );
    // The kept frames are counted, idle, within the budget; none without keeping.
    let budget = LoopConfig::for_voxel(voxel).memory_budget_bytes;
    let k = loops_of(&kept_summary);
    assert!(
        k.kept_frames > 0 && k.kept_bytes > 0 && k.kept_bytes <= budget,
        "{k:?}"
    );
    assert_eq!(loops_of(&read_summary).kept_frames, 0);
    assert_eq!(loops_of(&read_summary).kept_bytes, 0);
    assert_eq!(kept, read);
    assert_eq!(kept_poses, read_poses);
}

/// `--loop-memory 0` keeps no frame from the odometry: every candidate's frames are read again
/// (at least one pass) and every search structure is dropped after each use and built again,
/// yet each candidate verifies as with the default budget; the budget is recorded with the
/// other loop settings.
#[test]
fn loop_memory_zero_reads_the_frames_again() {
    let dir = tempfile::tempdir().unwrap();
    let default_out = dir.path().join("default.mcap");
    mireg_stdout(&["register", s(&fixture()), "-o", s(&default_out), "--quiet"]);
    let out = dir.path().join("out.mcap");
    let summary: serde_json::Value = serde_json::from_str(&mireg_stdout(&[
        "register",
        s(&fixture()),
        "-o",
        s(&out),
        "--json",
        "--quiet",
        "--loop-memory",
        "0",
    ]))
    .unwrap();
    assert!(
        summary["loops"]["accepted"].as_u64().unwrap() > 0,
        "{summary}"
    );
    assert!(
        summary["loops"]["passes"].as_u64().unwrap() >= 1,
        "{summary}"
    );
    let meta = contents(&out)
        .metadata
        .into_iter()
        .find(|(name, _)| name == "mireg")
        .expect("mireg metadata")
        .1;
    let config: serde_json::Value = serde_json::from_str(&meta["loop_config"]).unwrap();
    assert_eq!(config["memory_budget_bytes"], 0, "{config}");
    assert_eq!(summary["loops"]["kept_frames"], 0, "{summary}");

    // Each candidate both runs tried verifies the same, bit for bit (which ones are skipped as
    // redundant follows the order the passes verify them in).
    let verdicts =
        |path: &std::path::Path| -> std::collections::BTreeMap<(u64, u64), serde_json::Value> {
            loops(path)
                .into_iter()
                .map(|r| {
                    let key = (
                        r["query_frame"].as_u64().unwrap(),
                        r["match_frame"].as_u64().unwrap(),
                    );
                    let v = serde_json::json!([
                        r["verdict"],
                        r["match_from_query"],
                        r["inliers"],
                        r["fitness"],
                        r["icp_iterations"]
                    ]);
                    (key, v)
                })
                .collect()
        };
    let (zero, default) = (verdicts(&out), verdicts(&default_out));
    let both: Vec<_> = zero.keys().filter(|k| default.contains_key(k)).collect();
    assert!(
        both.len() >= zero.len().min(default.len()) / 2,
        "{zero:?} {default:?}"
    );
    for k in both {
        assert_eq!(zero[k], default[k], "candidate {k:?}");
    }
}
