//! `mireg localize` at the process boundary: the fixture localised in prior maps made of parts of
//! it (`register --start … --copy-window`: each prior's world is its own first frame, so the log
//! starts metres and tens of degrees from the prior's origin), checked unaligned against where
//! the reference puts each frame in the prior's world; a map of another place refused (every
//! frame lost, no pose written); the same poses on one and two threads.

use std::path::{Path, PathBuf};
use std::process::Command;

use mcap::records::Record;
use mireg::io::mcap::log::for_each_record;
use mireg::io::poses::read_mcap_pose_topic;
use mireg::trajectory::Trajectory;
use nalgebra::Isometry3;

fn root() -> &'static Path {
    Path::new(env!("CARGO_MANIFEST_DIR"))
}

fn fixture() -> PathBuf {
    root().join("fixtures/icl_livingroom1.mcap")
}

fn mireg(args: &[&str], threads: Option<&str>) {
    let mut c = Command::new(env!("CARGO_BIN_EXE_mireg"));
    if let Some(t) = threads {
        c.env("RAYON_NUM_THREADS", t);
    }
    let out = c.args(args).output().expect("mireg runs");
    assert!(
        out.status.success(),
        "mireg {args:?}: {}",
        String::from_utf8_lossy(&out.stderr)
    );
}

/// A prior map: the fixture's clouds from `start` on, registered.
fn prior(dir: &Path, start: usize) -> PathBuf {
    let out = dir.join(format!("prior_{start}.mcap"));
    let fixture = fixture();
    mireg(
        &[
            "register",
            fixture.to_str().unwrap(),
            "--start",
            &start.to_string(),
            "--copy-window",
            "-o",
            out.to_str().unwrap(),
            "--quiet",
        ],
        None,
    );
    out
}

fn localize(log: &Path, prior: &Path, out: &Path, threads: Option<&str>) {
    mireg(
        &[
            "localize",
            log.to_str().unwrap(),
            "--map",
            prior.to_str().unwrap(),
            "-o",
            out.to_str().unwrap(),
        ],
        threads,
    );
}

fn statuses(path: &Path) -> Vec<String> {
    let mut id = None;
    let mut out = Vec::new();
    for_each_record(path, |r| {
        match r {
            Record::Channel(c) if c.topic == "/mireg/localization" => id = Some(c.id),
            Record::Message { header, data } if Some(header.channel_id) == id => {
                let v: serde_json::Value = serde_json::from_slice(&data).unwrap();
                out.push(v["status"].as_str().unwrap().to_string());
            }
            _ => {}
        }
        Ok(())
    })
    .unwrap();
    out
}

fn reference(path: &Path) -> Trajectory {
    read_mcap_pose_topic(path, "/ground_truth/pose").unwrap()
}

#[test]
fn the_log_localizes_in_priors_that_start_elsewhere() {
    let dir = tempfile::tempdir().unwrap();
    let reference_log = reference(&fixture());
    for start in [30, 50] {
        let prior = prior(dir.path(), start);
        let out = dir.path().join(format!("loc_{start}.mcap"));
        localize(&fixture(), &prior, &out, None);
        let status = statuses(&out);
        assert_eq!(status.len(), 71);
        assert!(status.iter().all(|s| s != "lost"), "{status:?}");
        assert!(
            status.iter().filter(|s| *s == "localized").count() >= 5,
            "{status:?}"
        );
        // Where the reference puts each frame in the prior's world (its first frame).
        let origin = reference(&prior).poses[0];
        let placed = read_mcap_pose_topic(&out, "/mireg/pose").unwrap();
        assert_eq!(placed.stamps_ns, reference_log.stamps_ns);
        // The log starts far from the prior's origin: no alignment could hide a failure.
        let start_offset = (origin.inverse() * reference_log.poses[0])
            .translation
            .vector
            .norm();
        assert!(start_offset > 0.3, "{start_offset}");
        let errors: Vec<f64> = placed
            .poses
            .iter()
            .zip(&reference_log.poses)
            .map(|(p, r)| {
                let truth: Isometry3<f64> = origin.inverse() * r;
                (truth.translation.vector - p.translation.vector).norm()
            })
            .collect();
        let rmse = (errors.iter().map(|e| e * e).sum::<f64>() / errors.len() as f64).sqrt();
        let max = errors.iter().copied().fold(0.0, f64::max);
        // Measured with the prior from 30: RMSE 1.7 cm, max 3.2 cm.
        assert!(
            rmse < 0.035 && max < 0.07,
            "prior from {start}: RMSE {rmse:.4} m, max {max:.4} m"
        );
    }
}

#[test]
fn a_map_of_another_place_localizes_nothing() {
    let dir = tempfile::tempdir().unwrap();
    let prior = prior(dir.path(), 30);
    let ouster = root().join("fixtures/ouster_os1_ros1.mcap");
    let out = dir.path().join("loc.mcap");
    localize(&ouster, &prior, &out, None);
    let status = statuses(&out);
    assert!(
        !status.is_empty() && status.iter().all(|s| s == "lost"),
        "{status:?}"
    );
    // No pose guessed.
    assert!(
        read_mcap_pose_topic(&out, "/mireg/pose")
            .unwrap()
            .poses
            .is_empty()
    );
}

#[test]
fn the_same_poses_on_one_and_two_threads() {
    let dir = tempfile::tempdir().unwrap();
    let prior = prior(dir.path(), 30);
    let mut runs = Vec::new();
    for t in ["1", "2"] {
        let out = dir.path().join(format!("loc_{t}.mcap"));
        localize(&fixture(), &prior, &out, Some(t));
        runs.push(read_mcap_pose_topic(&out, "/mireg/pose").unwrap().poses);
    }
    assert_eq!(runs[0], runs[1]);
}
