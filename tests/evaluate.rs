//! `mireg evaluate` / `mireg export` on small MCAPs built here with known relationships between
//! `/mireg/pose` and `/ground_truth/pose`: through the library and at the process boundary.

use std::path::Path;
use std::process::Command;

use mireg::evaluate::{EvaluateOptions, TrajectoryFormat, evaluate_log};
use mireg::io::codec::{Header, Time, cdr};
use mireg::io::mcap::log::OutputLog;
use mireg::trajectory::{self, Trajectory};
use nalgebra::{Isometry3, Translation3, UnitQuaternion};

const T0_NS: i64 = 1_700_000_000_000_000_000;
const DT_NS: i64 = 100_000_000;
/// Reference stamps lag the estimate's by 3 ms: association must use the nearest stamp.
const GT_LAG_NS: i64 = 3_000_000;

/// A curvy ground-truth path of `n` poses.
fn reference_path(n: usize) -> Vec<Isometry3<f64>> {
    (0..n)
        .map(|k| {
            let a = 0.15 * k as f64;
            Isometry3::from_parts(
                Translation3::new(2.0 * a.sin(), 1.5 * (1.0 - a.cos()), 0.05 * k as f64),
                UnitQuaternion::from_euler_angles(0.1 * a.sin(), 0.05 * a, a),
            )
        })
        .collect()
}

fn pose_msg(stamp_ns: i64, pose: &Isometry3<f64>) -> Vec<u8> {
    let header = Header {
        stamp: Time::from_ns(stamp_ns).expect("stamp in range"),
        frame_id: "world".into(),
    };
    cdr::encode_pose_stamped(&header, pose)
}

/// Writes an MCAP with `/mireg/pose` (= `est`, stamps T0 + k·DT), `/ground_truth/pose` (= `gt`,
/// stamps lagging by [`GT_LAG_NS`]) and `/mireg/stats` flagging `failed` frames.
fn write_log(path: &Path, est: &[Isometry3<f64>], gt: &[Isometry3<f64>], failed: &[usize]) {
    let mut log = OutputLog::create(path, true, "ros2").expect("create");
    let add_pose_channel = |log: &mut OutputLog, topic: &str| {
        log.add_cdr_channel(topic, cdr::POSE_STAMPED)
            .expect("channel")
    };
    let est_ch = add_pose_channel(&mut log, "/mireg/pose");
    let gt_ch = add_pose_channel(&mut log, "/ground_truth/pose");
    let stats_ch = log
        .add_channel(
            "/mireg/stats",
            "mireg.FrameStats",
            "jsonschema",
            b"{}",
            "json",
        )
        .expect("stats channel");
    for (k, (e, g)) in est.iter().zip(gt).enumerate() {
        let s = T0_NS + k as i64 * DT_NS;
        let t = s as u64;
        log.write(gt_ch, t, t, &pose_msg(s + GT_LAG_NS, g))
            .expect("gt");
        log.write(est_ch, t, t, &pose_msg(s, e)).expect("est");
        let ok = !failed.contains(&k);
        let stats = serde_json::json!({
            "frame": k, "stamp_ns": s, "success": ok,
            "failure_reason": if ok { None } else { Some("too_few_inliers") },
            "num_inliers": 10,
        });
        log.write(stats_ch, t, t, stats.to_string().as_bytes())
            .expect("stats");
    }
    log.finish().expect("finish");
}

fn args(input: &Path) -> EvaluateOptions {
    EvaluateOptions {
        input: input.to_path_buf(),
        est_topic: Some("/mireg/pose".into()),
        ..Default::default()
    }
}

fn mireg(a: &[&str]) -> std::process::Output {
    Command::new(env!("CARGO_BIN_EXE_mireg"))
        .args(a)
        .output()
        .expect("run mireg")
}

fn stdout_of(a: &[&str]) -> String {
    let out = mireg(a);
    assert!(
        out.status.success(),
        "mireg {a:?}: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    String::from_utf8(out.stdout).expect("utf8")
}

#[test]
fn gt_composed_with_fixed_se3_has_zero_ate_and_rpe() {
    let dir = tempfile::tempdir().expect("tempdir");
    let path = dir.path().join("offset.mcap");
    let est = reference_path(40);
    let x = Isometry3::from_parts(
        Translation3::new(3.0, -1.0, 0.5),
        UnitQuaternion::from_euler_angles(0.3, -0.4, 2.0),
    );
    let gt: Vec<_> = est.iter().map(|e| x * e).collect();
    write_log(&path, &est, &gt, &[7, 8]);

    let run = evaluate_log(&args(&path)).expect("evaluates");
    let (ev, reference) = (run.evaluation, run.reference);
    assert_eq!(reference, "/ground_truth/pose");
    assert_eq!(ev.rows.len(), 40);
    assert_eq!(ev.max_pair_dt_ns, GT_LAG_NS);
    assert_eq!(ev.failed_frames, Some(2));
    assert!(ev.ate_rmse_m < 1e-9, "{}", ev.ate_rmse_m);
    assert!(ev.rpe_trans_mean_m < 1e-9 && ev.rpe_rot_mean_deg < 1e-6);
    // The alignment recovers X.
    let e = ev.reference_from_estimate.inverse() * x;
    assert!(e.translation.vector.norm() < 1e-9 && e.rotation.angle() < 1e-9);

    let json: serde_json::Value = serde_json::from_str(&stdout_of(&[
        "evaluate",
        path.to_str().expect("utf8"),
        "--json",
    ]))
    .expect("JSON");
    assert_eq!(json["frames"], 40);
    assert_eq!(json["failed_frames"], 2);
    assert!(json["ate_rmse_m"].as_f64().expect("number") < 1e-9);
    assert!(json["rpe_trans_mean_m"].as_f64().expect("number") < 1e-9);
    assert!(json["rpe_rot_mean_deg"].as_f64().expect("number") < 1e-6);
    assert!(json["drift_trans_pct"].as_f64().expect("drift computed") < 1e-6);
}

#[test]
fn known_per_step_drift_gives_known_rpe_in_library_csv_and_json() {
    // est_k = est_{k−1} · (gt_{k−1}⁻¹ gt_k) · T(2 cm along x) ⇒ RPE = 0.02 m, 0 deg per frame.
    let dir = tempfile::tempdir().expect("tempdir");
    let path = dir.path().join("drift.mcap");
    let gt = reference_path(30);
    let bias = Isometry3::translation(0.02, 0.0, 0.0);
    let mut est = vec![gt[0]];
    for k in 1..gt.len() {
        let step = gt[k - 1].inverse() * gt[k];
        est.push(est[k - 1] * step * bias);
    }
    write_log(&path, &est, &gt, &[]);

    let ev = evaluate_log(&args(&path)).expect("evaluates").evaluation;
    assert_eq!(ev.failed_frames, Some(0));
    assert!((ev.rpe_trans_mean_m - 0.02).abs() < 1e-9);
    assert!(ev.rpe_rot_mean_deg < 1e-6);
    assert!(ev.ate_rmse_m > 0.01, "drift accumulates: {}", ev.ate_rmse_m);

    let csv = stdout_of(&["evaluate", path.to_str().expect("utf8"), "--csv"]);
    let mut lines = csv.lines();
    assert_eq!(
        lines.next(),
        Some("frame,stamp_ns,success,rpe_trans_m,rpe_rot_deg,ate_err_m")
    );
    let rows: Vec<Vec<&str>> = lines.map(|l| l.split(',').collect()).collect();
    assert_eq!(rows.len(), 30);
    assert_eq!(rows[0][..4], ["0", &T0_NS.to_string(), "true", ""]);
    for (k, r) in rows.iter().enumerate().skip(1) {
        assert_eq!(r[0], k.to_string());
        assert_eq!(r[1], (T0_NS + k as i64 * DT_NS).to_string());
        let rpe: f64 = r[3].parse().expect("rpe number");
        assert!((rpe - 0.02).abs() < 1e-9, "row {k}: {rpe}");
    }
    let json: serde_json::Value = serde_json::from_str(&stdout_of(&[
        "evaluate",
        path.to_str().expect("utf8"),
        "--json",
    ]))
    .expect("JSON");
    assert!((json["rpe_trans_mean_m"].as_f64().expect("number") - 0.02).abs() < 1e-9);
    let text = stdout_of(&["evaluate", path.to_str().expect("utf8")]);
    assert!(
        text.contains("ATE RMSE") && text.contains("30 frames"),
        "{text}"
    );
}

#[test]
fn export_tum_and_kitti_reproduce_the_estimate() {
    let dir = tempfile::tempdir().expect("tempdir");
    let path = dir.path().join("export.mcap");
    let est = reference_path(12);
    write_log(&path, &est, &est, &[]);
    let p = path.to_str().expect("utf8");

    let tum = stdout_of(&["export", p, "--format", "tum"]);
    let t = trajectory::parse_tum(&tum, Path::new("stdout")).expect("TUM");
    let want: Vec<i64> = (0..12).map(|k| T0_NS + k * DT_NS).collect();
    assert_eq!(t.stamps_ns, want);
    assert!(tum.starts_with("1700000000.000000000 "), "{tum}");
    assert_poses_equal(&t, &est);

    let out = dir.path().join("est.kitti");
    stdout_of(&[
        "export",
        p,
        "--format",
        "kitti",
        "-o",
        out.to_str().expect("utf8"),
    ]);
    let k = mireg::io::poses::read_kitti(&out).expect("KITTI");
    assert!(k.stamps_ns.is_empty());
    assert_poses_equal(&k, &est);

    // The KITTI export is a valid --gt by index: estimate against itself.
    let mut a = args(&path);
    a.gt = Some(out);
    a.gt_format = TrajectoryFormat::Kitti;
    let ev = evaluate_log(&a).expect("evaluates").evaluation;
    assert_eq!(ev.association, trajectory::AssociationMethod::Index);
    assert!(ev.ate_rmse_m < 1e-9);
}

fn assert_poses_equal(t: &Trajectory, want: &[Isometry3<f64>]) {
    assert_eq!(t.len(), want.len());
    for (a, b) in t.poses.iter().zip(want) {
        let e = a.inverse() * b;
        assert!(e.translation.vector.norm() < 1e-12 && e.rotation.angle() < 1e-12);
    }
}

#[test]
fn bad_inputs_name_the_file_and_topic() {
    let dir = tempfile::tempdir().expect("tempdir");
    let path = dir.path().join("nogt.mcap");
    {
        let mut log = OutputLog::create(&path, true, "ros2").expect("create");
        let ch = log
            .add_cdr_channel("/odom/pose", cdr::POSE_STAMPED)
            .expect("channel");
        log.write(ch, 1, 1, &pose_msg(1, &Isometry3::identity()))
            .expect("msg");
        log.finish().expect("finish");
    }
    let p = path.to_str().expect("utf8");
    // No estimate: the log was never registered (issue 47); the PoseStamped topic it has is named
    // as the one --est-topic could choose.
    let out = mireg(&["evaluate", p]);
    assert_eq!(out.status.code(), Some(2));
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        err.contains("nogt.mcap")
            && err.contains("run `mireg register")
            && err.contains("--est-topic: /odom/pose"),
        "{err}"
    );
    // An estimate but no reference: the reference topic is named, and the topics to choose from.
    let out = mireg(&["evaluate", p, "--est-topic", "/odom/pose"]);
    assert_eq!(out.status.code(), Some(2));
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        err.contains("nogt.mcap")
            && err.contains("/ground_truth/pose")
            && err.contains("/odom/pose"),
        "{err}"
    );
    let out = mireg(&["export", p, "--format", "tum"]);
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        !out.status.success() && err.contains("/mireg/pose") && err.contains("/odom/pose"),
        "{err}"
    );
    // A malformed --gt file: the error names the file and line.
    let gt = dir.path().join("gt.tum");
    std::fs::write(&gt, "1.0 0 0 0 0 0 0 1\n2.0 0 0 0 oops 0 0 1\n").expect("write");
    let out = mireg(&[
        "evaluate",
        p,
        "--est-topic",
        "/odom/pose",
        "--gt",
        gt.to_str().expect("utf8"),
    ]);
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        !out.status.success() && err.contains("gt.tum") && err.contains("line 2"),
        "{err}"
    );
}
