//! `--start` / `--end`: one segment of a log registers in the segment's own world, agrees with
//! the whole-log run up to that world change, and `--copy-window` copies only its messages.

use std::path::{Path, PathBuf};

use mireg::io::codec::cdr;
use mireg::odometry::OdometryConfig;
use mireg::pipeline::{PairConfig, pose_error};
use mireg::register::{RegisterOptions, WindowBound, register_log};
use nalgebra::Isometry3;

#[path = "common/log_contents.rs"]
mod log_contents;
use log_contents::contents;
#[path = "common/loop_records.rs"]
mod loop_records;
#[path = "common/synthetic_log.rs"]
mod synthetic_log;
use synthetic_log::{world_from_camera, write_log_full};

fn fixture() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("fixtures/icl_livingroom1.mcap")
}

fn options(output: &Path) -> RegisterOptions {
    options_for(&fixture(), output, 0.05, 2)
}

/// Registering `log` into `output` at `voxel` \[m\] with `seed`.
fn options_for(log: &Path, output: &Path, voxel: f64, seed: u64) -> RegisterOptions {
    let config = OdometryConfig {
        pair: PairConfig {
            voxel_size_m: voxel,
            seed,
            ..Default::default()
        },
        ..Default::default()
    };
    RegisterOptions::new(log, output, config)
}

fn poses(path: &Path) -> Vec<(i64, Isometry3<f64>)> {
    contents(path)
        .messages
        .iter()
        .filter(|m| m.0 == "/mireg/pose")
        .map(|m| {
            let (h, p) = cdr::decode_pose_stamped(&m.3).unwrap();
            (h.stamp.to_ns(), p)
        })
        .collect()
}

#[test]
fn a_segment_is_the_whole_run_seen_from_its_first_frame() {
    let dir = tempfile::tempdir().unwrap();
    let (full, seg) = (dir.path().join("full.mcap"), dir.path().join("seg.mcap"));
    register_log(&options(&full)).unwrap();
    let mut opts = options(&seg);
    opts.start = Some(WindowBound::Frame(30));
    opts.end = Some(WindowBound::Frame(50));
    let summary = register_log(&opts).unwrap();
    assert_eq!(summary.frames, 20);

    let (all, part) = (poses(&full), poses(&seg));
    assert_eq!(part.len(), 20);
    assert_eq!(part[0].1, Isometry3::identity(), "the segment's world");
    // Same stamps as frames 30..50 of the whole run.
    let stamps: Vec<i64> = all[30..50].iter().map(|p| p.0).collect();
    assert_eq!(part.iter().map(|p| p.0).collect::<Vec<_>>(), stamps);
    // The whole run re-expressed in frame 30's world: within a few millimetres of the segment
    // (each builds its own local map, so they are not identical).
    let world30_from_world = all[30].1.inverse();
    for (k, (_, p)) in part.iter().enumerate() {
        let q = world30_from_world * all[30 + k].1;
        let d = (p.translation.vector - q.translation.vector).norm();
        let a = p.rotation.angle_to(&q.rotation).to_degrees();
        assert!(d < 0.01 && a < 0.5, "frame {}: {d} m, {a} deg", 30 + k);
    }

    // Every input message is copied by default; the metadata records the segment.
    let c = contents(&seg);
    assert_eq!(summary.messages_copied, 142);
    let meta = &c.metadata.iter().find(|m| m.0 == "mireg").unwrap().1;
    let segment: serde_json::Value = serde_json::from_str(&meta["segment"]).unwrap();
    assert_eq!(segment["first_frame"], 30);
    assert_eq!(segment["start_ns"], stamps[0]);
    assert_eq!(segment["end_ns"], all[50].0);
}

#[test]
fn copy_window_keeps_only_the_segments_messages_and_time_bounds_work() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("w.mcap");
    let mut opts = options(&out);
    // Frames 20..25 of the fixture: stamps 1.7e9 s + 2.0 s .. + 2.5 s.
    opts.start = Some("1700000002s".parse().unwrap());
    opts.end = Some("1700000002500000000ns".parse().unwrap());
    opts.copy_window_only = true;
    let summary = register_log(&opts).unwrap();
    assert_eq!(summary.frames, 5);
    let input = contents(&fixture());
    let want: Vec<_> = input
        .messages
        .iter()
        .filter(|m| (1_700_000_002_000_000_000..1_700_000_002_500_000_000).contains(&m.1))
        .collect();
    assert_eq!(want.len(), 10, "5 clouds and 5 reference poses");
    assert_eq!(summary.messages_copied, 10);
    let output = contents(&out);
    for m in want {
        assert!(output.messages.contains(m), "{} at {}", m.0, m.1);
    }
    let outside = output
        .messages
        .iter()
        .filter(|m| !m.0.starts_with("/mireg") && m.0 != "/tf")
        .count();
    assert_eq!(outside, 10, "nothing from outside the window");
    // Metadata records of the input are still copied.
    for m in &input.metadata {
        assert!(output.metadata.contains(m), "{}", m.0);
    }
}

#[test]
fn an_empty_segment_is_an_error_naming_the_log_extent() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("e.mcap");
    let mut opts = options(&out);
    opts.start = Some(WindowBound::Frame(71));
    let e = register_log(&opts).unwrap_err().to_string();
    assert!(
        e.contains("no cloud in the segment") && e.contains("71 clouds"),
        "{e}"
    );
    assert!(!out.exists());
}

fn segment(dir: &Path, name: &str, start: Option<u64>, end: Option<u64>) -> PathBuf {
    let out = dir.join(name);
    let mut opts = options(&out);
    opts.start = start.map(WindowBound::Frame);
    opts.end = end.map(WindowBound::Frame);
    register_log(&opts).unwrap();
    out
}

#[test]
fn stitched_segments_follow_the_sequential_run() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let full = segment(d, "full.mcap", None, None);
    // Three segments overlapping by 12 frames.
    let segs = vec![
        segment(d, "s0.mcap", None, Some(36)),
        segment(d, "s1.mcap", Some(24), Some(60)),
        segment(d, "s2.mcap", Some(48), None),
    ];
    let out = d.join("stitched.mcap");
    let s = mireg::register::stitch(&fixture(), &segs, &out, false, "test", false).unwrap();
    assert_eq!((s.frames, s.segments, s.messages_copied), (71, 3, 142));
    assert_eq!(s.seams.len(), 2);
    for seam in &s.seams {
        assert_eq!(seam.shared_frames, 12);
        assert!(seam.max_translation_m < 0.01, "{seam:?}");
    }
    let (a, b) = (poses(&full), poses(&out));
    assert_eq!(
        a.iter().map(|p| p.0).collect::<Vec<_>>(),
        b.iter().map(|p| p.0).collect::<Vec<_>>()
    );
    // Both start in frame 0's world: compare directly.
    let worst = a
        .iter()
        .zip(&b)
        .map(|(x, y)| (x.1.translation.vector - y.1.translation.vector).norm())
        .fold(0.0, f64::max);
    assert!(worst < 0.005, "stitched vs sequential: {worst} m");
    // Up to the first anchor (frame 35) the stitched trajectory is segment 0's, bit for bit.
    assert_eq!(poses(&segs[0])[..36], b[..36]);
    // Statistics cover the log, renumbered, each naming its segment.
    let stats: Vec<serde_json::Value> = contents(&out)
        .messages
        .iter()
        .filter(|m| m.0 == "/mireg/stats")
        .map(|m| serde_json::from_slice(&m.3).unwrap())
        .collect();
    assert_eq!(stats.len(), 71);
    assert_eq!(stats[70]["frame"], 70);
    assert_eq!(stats[70]["segment"], 2);
    assert_eq!(stats[0]["segment"], 0);

    // Segments that do not overlap are refused, and nothing is written.
    let gap = segment(d, "gap.mcap", Some(40), None);
    let e = mireg::register::stitch(
        &fixture(),
        &[segs[0].clone(), gap],
        &d.join("g.mcap"),
        false,
        "t",
        false,
    )
    .unwrap_err()
    .to_string();
    assert!(e.contains("shares no frame"), "{e}");
    assert!(!d.join("g.mcap").exists());
}

/// Against known motion: a synthetic log (a room seen from `world_from_camera(k)`), registered
/// in three overlapping segments and stitched, recovers every frame's true pose in frame 0's
/// world, and matches the sequential run, which recovers it too.
#[test]
fn stitched_segments_recover_known_motion() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let log = d.join("synthetic.mcap");
    let frames = 14;
    write_log_full(&log, &(0..frames).collect::<Vec<_>>(), None, |o| o);
    let run = |name: &str, start: Option<u64>, end: Option<u64>| {
        let out = d.join(name);
        let mut opts = options_for(&log, &out, 0.1, 3);
        opts.start = start.map(WindowBound::Frame);
        opts.end = end.map(WindowBound::Frame);
        let summary = register_log(&opts).unwrap();
        assert_eq!(summary.failed_frames, 0, "{name}");
        out
    };
    let full = run("full.mcap", None, None);
    let segs = vec![
        run("s0.mcap", None, Some(6)),
        run("s1.mcap", Some(3), Some(11)),
        run("s2.mcap", Some(8), None),
    ];
    let out = d.join("stitched.mcap");
    let s = mireg::register::stitch(&log, &segs, &out, false, "test", false).unwrap();
    assert_eq!((s.frames, s.segments), (frames, 3));
    assert_eq!(
        s.seams.iter().map(|m| m.shared_frames).collect::<Vec<_>>(),
        [3, 3]
    );
    let (sequential, stitched) = (poses(&full), poses(&out));
    assert_eq!(stitched.len(), frames);
    for (k, ((_, seq), (_, st))) in sequential.iter().zip(&stitched).enumerate() {
        // world = the first camera: world_from_frame_k = camera_0_from_world · world_from_camera_k.
        let truth = world_from_camera(0).inverse() * world_from_camera(k);
        for (name, est) in [("sequential", seq), ("stitched", st)] {
            let (r, t) = pose_error(&truth, est);
            assert!(r < 0.3 && t < 0.01, "{name} frame {k}: {r:.3}° {t:.4} m");
        }
        let apart = (seq.translation.vector - st.translation.vector).norm();
        assert!(
            apart < 0.005,
            "frame {k}: stitched {apart} m from sequential"
        );
    }
}

/// Loop closure over the stitched whole (`stitch` with loops): candidates across the seams,
/// the seam pairs (the later segment's first three output frames against the frame before its
/// window), every accepted loop right against the fixture's reference, an optimised pose for
/// every frame, and the summary counting what was tried.
#[test]
fn stitched_segments_close_loops_over_the_whole_log() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let (end0, start1) = (40, 28);
    let segs = vec![
        segment(d, "s0.mcap", None, Some(end0)),
        segment(d, "s1.mcap", Some(start1), None),
    ];
    let out = d.join("stitched.mcap");
    let s = mireg::register::stitch(&fixture(), &segs, &out, false, "test", true).unwrap();
    let summary = s.loops.expect("loops ran");
    let tried = loop_records::loops(&out);
    assert_eq!(tried.len(), summary.candidates);
    let reference = loop_records::poses_by_stamp(&out, "/ground_truth/pose");
    let voxel = 0.05;
    let accepted = loop_records::assert_accepted_loops_match(&tried, &reference, voxel);
    assert_eq!(accepted, summary.accepted);
    assert!(accepted > 0);
    // The anchor is segment 0's last frame; segment 1's window starts at `start1`.
    let (anchor, before) = (end0 - 1, start1 - 1);
    let mut seams: Vec<(u64, u64, &str)> = tried
        .iter()
        .filter(|r| r["found_by"] == "seam")
        .map(|r| {
            let f = |k: &str| r[k].as_u64().unwrap();
            (
                f("query_frame"),
                f("match_frame"),
                r["verdict"].as_str().unwrap(),
            )
        })
        .collect();
    seams.sort();
    assert_eq!(
        seams,
        [
            (anchor + 1, before, "accepted"),
            (anchor + 2, before, "accepted"),
            (anchor + 3, before, "accepted")
        ]
    );
    let optimized = loop_records::poses_by_stamp(&out, "/mireg/pose_optimized");
    assert_eq!(optimized.len(), 71);
}
