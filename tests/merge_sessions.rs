//! `mireg merge` at the process boundary: the fixture split into sessions that each start at
//! their own origin (`register --start/--end`: a segment's world is its first frame), merged
//! without being told how they relate, and checked against the reference: where it puts each
//! session's first frame, the joint ATE against the whole log registered at once, every accepted
//! link against the reference's relative pose. A session of another place stays apart; the
//! poses do not depend on the thread count.

use std::path::{Path, PathBuf};
use std::process::Command;
use std::sync::OnceLock;

use mireg::evaluate::ate_rmse;
use mireg::io::poses::read_mcap_pose_topic;
use mireg::map::{MapOptions, build_map, build_map_of_runs};
use mireg::merge::{MergeConfig, MergeOptions, merge};
use mireg::trajectory::Trajectory;
use nalgebra::Isometry3;

#[path = "common/log_contents.rs"]
mod log_contents;
use log_contents::topic_messages;

const REFERENCE: &str = "/ground_truth/pose";

fn root() -> &'static Path {
    Path::new(env!("CARGO_MANIFEST_DIR"))
}

fn mireg(args: &[&str]) -> std::process::Output {
    Command::new(env!("CARGO_BIN_EXE_mireg"))
        .args(args)
        .output()
        .expect("mireg runs")
}

fn ok(args: &[&str]) {
    let out = mireg(args);
    assert!(
        out.status.success(),
        "mireg {args:?}: {}",
        String::from_utf8_lossy(&out.stderr)
    );
}

/// `mireg merge RUNS... -o dir`, which must succeed.
fn merge_into(dir: &Path, runs: &[&str]) {
    let mut args = vec!["merge"];
    args.extend_from_slice(runs);
    args.extend(["-o", dir.to_str().unwrap()]);
    ok(&args);
}

/// The fixture registered in segments `[start, end)` (clouds), each into its own file, and as a
/// whole; made once for every test of this file.
struct Sessions {
    _dir: tempfile::TempDir,
    dir: PathBuf,
    whole: PathBuf,
}

fn sessions() -> &'static Sessions {
    static SESSIONS: OnceLock<Sessions> = OnceLock::new();
    SESSIONS.get_or_init(|| {
        let tmp = tempfile::tempdir().unwrap();
        let dir = tmp.path().to_path_buf();
        let fixture = root().join("fixtures/icl_livingroom1.mcap");
        let fixture = fixture.to_str().unwrap();
        for (name, start, end) in [("a", 0, 30), ("b", 30, 71), ("t1", 24, 48), ("t2", 48, 71)] {
            let out = dir.join(format!("{name}.mcap"));
            let (start, end) = (start.to_string(), end.to_string());
            ok(&[
                "register",
                fixture,
                "--start",
                &start,
                "--end",
                &end,
                "--copy-window",
                "-o",
                out.to_str().unwrap(),
                "--quiet",
            ]);
        }
        let whole = dir.join("whole.mcap");
        ok(&[
            "register",
            fixture,
            "-o",
            whole.to_str().unwrap(),
            "--quiet",
        ]);
        Sessions {
            _dir: tmp,
            dir,
            whole,
        }
    })
}

fn session(name: &str) -> String {
    sessions()
        .dir
        .join(format!("{name}.mcap"))
        .to_str()
        .unwrap()
        .to_string()
}

fn merged(path: &Path) -> Trajectory {
    read_mcap_pose_topic(path, "/mireg/pose_merged").unwrap()
}

fn reference(path: &Path) -> Trajectory {
    read_mcap_pose_topic(path, REFERENCE).unwrap()
}

/// The poses of `t` at the stamps of `r` (every stamp must be there).
fn at_stamps(t: &Trajectory, r: &Trajectory) -> Vec<Isometry3<f64>> {
    r.stamps_ns
        .iter()
        .map(|s| {
            let k = t.stamps_ns.iter().position(|x| x == s).expect("stamp");
            t.poses[k]
        })
        .collect()
}

fn report(dir: &Path) -> serde_json::Value {
    serde_json::from_slice(&std::fs::read(dir.join("merge_report.json")).unwrap()).unwrap()
}

fn accepted_links(path: &Path) -> Vec<serde_json::Value> {
    topic_messages(path, "/mireg/session_links")
        .iter()
        .map(|m| serde_json::from_slice::<serde_json::Value>(m).unwrap())
        .filter(|v| v["verdict"] == "accepted")
        .collect()
}

fn pose_of(v: &serde_json::Value) -> Isometry3<f64> {
    let t: Vec<f64> = serde_json::from_value(v["translation"].clone()).unwrap();
    let q: Vec<f64> = serde_json::from_value(v["rotation_xyzw"].clone()).unwrap();
    Isometry3::from_parts(
        nalgebra::Translation3::new(t[0], t[1], t[2]),
        nalgebra::UnitQuaternion::from_quaternion(nalgebra::Quaternion::new(
            q[3], q[0], q[1], q[2],
        )),
    )
}

/// Translation \[m\] and rotation \[deg\] between two poses.
fn apart(a: &Isometry3<f64>, b: &Isometry3<f64>) -> (f64, f64) {
    let d = a.inverse() * b;
    (d.translation.vector.norm(), d.rotation.angle().to_degrees())
}

#[test]
fn two_halves_join_where_the_reference_puts_them() {
    let out = tempfile::tempdir().unwrap();
    let dir = out.path().join("merged");
    merge_into(&dir, &[&session("a"), &session("b")]);
    let r = report(&dir);
    assert_eq!(r["groups"], 1, "{r:#}");
    assert_eq!(r["pairs"][0]["joined"], true, "{r:#}");
    let (a, b) = (dir.join("a.mcap"), dir.join("b.mcap"));
    let (ma, mb, ra, rb) = (merged(&a), merged(&b), reference(&a), reference(&b));
    // The root session's world is its first frame.
    assert!(apart(&ma.poses[0], &Isometry3::identity()).0 < 1e-12);
    // Where the reference puts b's first frame in a's first frame (measured 1.2 cm / 0.42°).
    let truth = ra.poses[0].inverse() * rb.poses[0];
    let (m, deg) = apart(&truth, &mb.poses[0]);
    assert!(
        m < 0.05 && deg < 1.5,
        "b's origin {m:.4} m / {deg:.3} deg off"
    );
    // Joint ATE (one alignment for both) against the whole log registered with loop closure
    // (measured 1.31 against 1.20 cm).
    let est: Vec<_> = [at_stamps(&ma, &ra), at_stamps(&mb, &rb)].concat();
    let truth: Vec<_> = [ra.poses.clone(), rb.poses.clone()].concat();
    let joint = ate_rmse(&est, &truth);
    let whole = read_mcap_pose_topic(&sessions().whole, "/mireg/pose_optimized").unwrap();
    let rw = reference(&sessions().whole);
    let single = ate_rmse(&at_stamps(&whole, &rw), &rw.poses);
    assert!(
        joint <= 1.25 * single,
        "joint ATE {joint:.4} m, one log {single:.4} m"
    );
    // Every accepted link agrees with the reference's relative pose of its frames (measured:
    // at most 3 cm / 1.55°; the reference is itself an estimate).
    let links = accepted_links(&a);
    assert!(links.len() >= 2);
    for l in &links {
        let at = |t: &Trajectory, s: &serde_json::Value| {
            t.poses[t
                .stamps_ns
                .iter()
                .position(|x| *x == s.as_i64().unwrap())
                .unwrap()]
        };
        let truth = at(&ra, &l["stamp_a_ns"]).inverse() * at(&rb, &l["stamp_b_ns"]);
        let (m, deg) = apart(&truth, &pose_of(&l["a_from_b"]));
        assert!(
            m < 0.1 && deg < 2.5,
            "link {l}: {m:.4} m / {deg:.3} deg off"
        );
    }
}

#[test]
fn three_sessions_join_in_one_frame() {
    let out = tempfile::tempdir().unwrap();
    let dir = out.path().join("merged");
    merge_into(&dir, &[&session("a"), &session("t1"), &session("t2")]);
    let r = report(&dir);
    assert_eq!(r["groups"], 1, "{r:#}");
    let ra = reference(&dir.join("a.mcap"));
    for name in ["t1", "t2"] {
        let path = dir.join(format!("{name}.mcap"));
        let truth = ra.poses[0].inverse() * reference(&path).poses[0];
        let (m, deg) = apart(&truth, &merged(&path).poses[0]);
        assert!(
            m < 0.05 && deg < 1.5,
            "{name}'s origin {m:.4} m / {deg:.3} deg off"
        );
    }
}

#[test]
fn a_session_of_another_place_stays_apart() {
    let out = tempfile::tempdir().unwrap();
    let ouster = out.path().join("ouster.mcap");
    let fixture = root().join("fixtures/ouster_os1_ros1.mcap");
    ok(&[
        "register",
        fixture.to_str().unwrap(),
        "-o",
        ouster.to_str().unwrap(),
        "--quiet",
    ]);
    let dir = out.path().join("merged");
    merge_into(&dir, &[&session("a"), ouster.to_str().unwrap()]);
    let r = report(&dir);
    assert_eq!(r["groups"], 2, "{r:#}");
    assert_eq!(r["links_accepted"], 0, "{r:#}");
    assert_eq!(r["pairs"][0]["joined"], false);
    assert!(accepted_links(&dir.join("a.mcap")).is_empty());
    // Apart, each keeps its own trajectory in its own frame.
    let own = read_mcap_pose_topic(&ouster, "/mireg/pose").unwrap();
    let m = read_mcap_pose_topic(&dir.join("ouster.mcap"), "/mireg/pose_merged").unwrap();
    assert_eq!(own.poses.len(), m.poses.len());
    for (p, q) in own.poses.iter().zip(&m.poses) {
        assert!(apart(p, q).0 < 1e-9);
    }
}

#[test]
fn the_same_poses_on_one_and_two_threads() {
    let out = tempfile::tempdir().unwrap();
    let mut poses = Vec::new();
    for threads in ["1", "2"] {
        let dir = out.path().join(threads);
        let o = Command::new(env!("CARGO_BIN_EXE_mireg"))
            .env("RAYON_NUM_THREADS", threads)
            .args([
                "merge",
                &session("a"),
                &session("b"),
                "-o",
                dir.to_str().unwrap(),
            ])
            .output()
            .unwrap();
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        poses.push(merged(&dir.join("b.mcap")).poses);
    }
    assert_eq!(poses[0], poses[1]);
}

#[test]
fn wrong_inputs_are_named_and_nothing_is_written() {
    let out = tempfile::tempdir().unwrap();
    let dir = out.path().join("merged");
    let d = dir.to_str().unwrap();
    // One run.
    let o = mireg(&["merge", &session("a"), "-o", d]);
    assert!(!o.status.success());
    // A log never registered.
    let raw = root().join("fixtures/icl_livingroom1.mcap");
    let o = mireg(&["merge", &session("a"), raw.to_str().unwrap(), "-o", d]);
    assert!(!o.status.success());
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(
        err.contains("icl_livingroom1.mcap") && err.contains("register"),
        "{err}"
    );
    assert!(!dir.join("a.mcap").exists() && !dir.join("merge_report.json").exists());
    // Two runs of one name.
    let o = mireg(&["merge", &session("a"), &session("a"), "-o", d]);
    assert!(!o.status.success());
    assert!(String::from_utf8_lossy(&o.stderr).contains("rename"));
}

#[test]
fn one_map_of_the_merged_sessions() {
    let out = tempfile::tempdir().unwrap();
    let dir = out.path().join("merged");
    merge_into(&dir, &[&session("a"), &session("b")]);
    let runs = [dir.join("a.mcap"), dir.join("b.mcap")];
    let opts = MapOptions::default();
    let (merged, summary) = build_map_of_runs(&runs, &opts).unwrap();
    assert_eq!(summary.pose_topic, "/mireg/pose_merged");
    assert_eq!(summary.clouds_used, 71);
    // The same room from one frame: as many occupied voxels as the whole log's map (measured
    // 6,138 against 6,137); b misplaced by its own origin would add most of its voxels again.
    let (whole, _) = build_map(&sessions().whole, &opts).unwrap();
    let ratio = merged.len() as f64 / whole.len() as f64;
    assert!(
        (0.97..1.03).contains(&ratio),
        "{} against {} voxels",
        merged.len(),
        whole.len()
    );
    let unmerged = [PathBuf::from(session("a")), PathBuf::from(session("b"))];
    let e = build_map_of_runs(&unmerged, &opts).unwrap_err().to_string();
    assert!(e.contains("pose_merged"), "{e}");
    // Runs of two different merges are not one frame.
    let other = out.path().join("other");
    merge_into(&other, &[&session("a"), &session("t2")]);
    let mixed = [dir.join("a.mcap"), other.join("t2.mcap")];
    let e = build_map_of_runs(&mixed, &opts).unwrap_err().to_string();
    assert!(e.contains("one merge group"), "{e}");
}

#[test]
fn keyframes_prepared_again_give_the_same_poses() {
    let out = tempfile::tempdir().unwrap();
    let mut poses = Vec::new();
    for (name, budget) in [("kept", 128 << 20), ("none_kept", 0)] {
        let opts = MergeOptions {
            runs: vec![PathBuf::from(session("a")), PathBuf::from(session("b"))],
            output_dir: out.path().join(name),
            force: false,
            seed: 0,
            config: MergeConfig {
                keyframe_memory_bytes: budget,
                ..MergeConfig::default()
            },
            command_line: String::new(),
            links_dir: None,
        };
        let summary = merge(&opts).unwrap();
        assert_eq!(summary.groups, 1);
        poses.push(merged(&out.path().join(name).join("b.mcap")).poses);
    }
    assert_eq!(poses[0], poses[1]);
}

#[test]
fn pairs_linked_apart_merge_as_in_one_process() {
    let out = tempfile::tempdir().unwrap();
    let runs = [session("a"), session("t1"), session("t2")];
    let whole = out.path().join("whole");
    merge_into(&whole, &[&runs[0], &runs[1], &runs[2]]);
    // Each pair on its own (as cluster tasks run them), then the merge from their files.
    let links = out.path().join("links");
    let l = links.to_str().unwrap();
    for pair in ["0,1", "0,2", "1,2"] {
        ok(&[
            "merge", &runs[0], &runs[1], &runs[2], "--pair", pair, "--links", l,
        ]);
    }
    for file in ["pair_0_1.json", "pair_0_2.json", "pair_1_2.json"] {
        assert!(links.join(file).is_file(), "{file}");
    }
    let apart = out.path().join("apart");
    let a = apart.to_str().unwrap();
    ok(&["merge", &runs[0], &runs[1], &runs[2], "-o", a, "--links", l]);
    for name in ["a", "t1", "t2"] {
        let (p, q) = (
            whole.join(format!("{name}.mcap")),
            apart.join(format!("{name}.mcap")),
        );
        assert_eq!(merged(&p).poses, merged(&q).poses, "{name}");
        let topic = "/mireg/session_links";
        assert_eq!(
            topic_messages(&p, topic),
            topic_messages(&q, topic),
            "{name}"
        );
    }
    let (mut r, mut s) = (report(&whole), report(&apart));
    for v in [&mut r, &mut s] {
        let o = v.as_object_mut().unwrap();
        o.remove("elapsed_s");
        o.remove("output_dir");
        for session in o["sessions"].as_array_mut().unwrap() {
            session.as_object_mut().unwrap().remove("output");
        }
    }
    assert_eq!(r, s);
    // A pair's accepted links are the accepted links the merged output carries for it.
    let file: serde_json::Value =
        serde_json::from_slice(&std::fs::read(links.join("pair_0_1.json")).unwrap()).unwrap();
    let in_file = file["join"]["agreeing"].as_array().unwrap().len();
    let on_topic = accepted_links(&apart.join("t1.mcap"))
        .iter()
        .filter(|v| v["session_a"] == "a")
        .count();
    assert_eq!(in_file, on_topic);
    assert!(in_file >= 2, "{file:#}");
    // Files of other settings are refused, named with the field; nothing is written.
    let other = out.path().join("other");
    let o = mireg(&[
        "merge",
        &runs[0],
        &runs[1],
        &runs[2],
        "-o",
        other.to_str().unwrap(),
        "--links",
        l,
        "--seed",
        "1",
    ]);
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success());
    assert!(
        err.contains("pair_0_1.json") && err.contains("inputs.seed"),
        "{err}"
    );
    assert!(!other.join("a.mcap").exists());
    // Runs given in another order are other sessions.
    let o = mireg(&[
        "merge",
        &runs[1],
        &runs[0],
        &runs[2],
        "-o",
        other.to_str().unwrap(),
        "--links",
        l,
    ]);
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success());
    assert!(err.contains("inputs.sessions"), "{err}");
}
