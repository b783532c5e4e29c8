use super::*;
use rand::{RngExt, SeedableRng};

fn random_trajectory(n: usize, seed: u64) -> Trajectory {
    let mut rng = rand_pcg::Pcg64::seed_from_u64(seed);
    let mut stamps = Vec::new();
    let mut poses = Vec::new();
    for k in 0..n {
        stamps.push(1_700_000_000_000_000_000 + k as i64 * 33_333_333 + rng.random_range(0..7));
        poses.push(Isometry3::from_parts(
            Translation3::new(
                rng.random_range(-5.0..5.0),
                rng.random_range(-5.0..5.0),
                rng.random_range(-5.0..5.0),
            ),
            UnitQuaternion::from_euler_angles(
                rng.random_range(-3.0..3.0),
                rng.random_range(-1.5..1.5),
                rng.random_range(-3.0..3.0),
            ),
        ));
    }
    Trajectory::stamped(stamps, poses)
}

fn assert_same_poses(a: &[Isometry3<f64>], b: &[Isometry3<f64>], tol: f64) {
    assert_eq!(a.len(), b.len());
    for (k, (p, q)) in a.iter().zip(b).enumerate() {
        let e = p.inverse() * q;
        assert!(
            e.translation.vector.norm() < tol && e.rotation.angle() < tol,
            "pose {k}: {p} vs {q}"
        );
    }
}

#[test]
fn tum_round_trip_is_exact() {
    let t = random_trajectory(50, 11);
    let mut buf = Vec::new();
    write_tum(&t, &mut buf).expect("write");
    let back =
        parse_tum(std::str::from_utf8(&buf).expect("utf8"), Path::new("x.tum")).expect("parse");
    assert_eq!(back.stamps_ns, t.stamps_ns);
    // Shortest round-trip floats: the quaternion is renormalised on read (≤ 1 ulp-ish).
    assert_same_poses(&back.poses, &t.poses, 1e-12);
}

#[test]
fn tum_line_has_evo_layout() {
    let t = Trajectory::stamped(
        vec![1_700_000_000_033_333_333, -1_500_000_000],
        vec![
            Isometry3::from_parts(
                Translation3::new(1.0, -2.5, 0.25),
                UnitQuaternion::from_quaternion(Quaternion::new(0.5, 0.5, 0.5, 0.5)),
            ),
            Isometry3::identity(),
        ],
    );
    let mut buf = Vec::new();
    write_tum(&t, &mut buf).expect("write");
    assert_eq!(
        String::from_utf8(buf).expect("utf8"),
        "1700000000.033333333 1.0 -2.5 0.25 0.5 0.5 0.5 0.5\n-1.500000000 0.0 0.0 0.0 0.0 0.0 0.0 1.0\n"
    );
}

#[test]
fn tum_stamps_parse_to_exact_nanoseconds() {
    assert_eq!(
        parse_seconds_ns("1700000000.033333333"),
        Some(1_700_000_000_033_333_333)
    );
    assert_eq!(parse_seconds_ns("12"), Some(12_000_000_000));
    assert_eq!(parse_seconds_ns("0.5"), Some(500_000_000));
    assert_eq!(parse_seconds_ns("-1.5"), Some(-1_500_000_000));
    assert_eq!(parse_seconds_ns(".25"), Some(250_000_000));
    // The tenth decimal rounds.
    assert_eq!(parse_seconds_ns("1.0000000015"), Some(1_000_000_002));
    assert_eq!(parse_seconds_ns("1.0000000014"), Some(1_000_000_001));
    assert_eq!(parse_seconds_ns("1.5e3"), Some(1_500_000_000_000));
    assert_eq!(parse_seconds_ns("abc"), None);
    assert_eq!(parse_seconds_ns("."), None);
}

#[test]
fn tum_skips_comments_and_reports_bad_lines() {
    let p = Path::new("traj.txt");
    let ok = "# timestamp tx ty tz qx qy qz qw\n\n1.0 0 0 0 0 0 0 1\n";
    assert_eq!(parse_tum(ok, p).expect("valid").len(), 1);
    let short = "1.0 0 0 0 0 0 0 1\n2.0 0 0 0 0 0 1\n";
    let e = parse_tum(short, p).expect_err("7 numbers").to_string();
    assert!(
        e.contains("traj.txt") && e.contains("line 2") && e.contains("found 7"),
        "{e}"
    );
    let nan = "1.0 0 0 0 0 0 0 1\n\n2.0 0 x 0 0 0 0 1\n";
    let e = parse_tum(nan, p).expect_err("not a number").to_string();
    assert!(
        e.contains("traj.txt") && e.contains("line 3") && e.contains("'x'"),
        "{e}"
    );
    let bad_q = "1.0 0 0 0 0 0 0 2\n";
    let e = parse_tum(bad_q, p).expect_err("norm 2").to_string();
    assert!(e.contains("line 1") && e.contains("quaternion"), "{e}");
}

#[test]
fn kitti_round_trip_is_exact_up_to_snapping() {
    let t = random_trajectory(40, 12);
    let mut buf = Vec::new();
    write_kitti(&t, &mut buf).expect("write");
    let text = String::from_utf8(buf).expect("utf8");
    assert_eq!(text.lines().count(), 40);
    assert!(text.lines().all(|l| l.split_whitespace().count() == 12));
    let back = parse_kitti(&text, Path::new("poses.txt")).expect("parse");
    assert!(back.stamps_ns.is_empty());
    assert_same_poses(&back.poses, &t.poses, 1e-12);
}

#[test]
fn kitti_rows_are_row_major_r_then_t() {
    // R_z(90°): x → y. Row-major [R | t] = 0 -1 0 1 / 1 0 0 2 / 0 0 1 3.
    let text = "0 -1 0 1 1 0 0 2 0 0 1 3\n";
    let t = parse_kitti(text, Path::new("k.txt")).expect("parse");
    let p = t.poses[0] * nalgebra::Point3::new(1.0, 0.0, 0.0);
    assert!(
        (p - nalgebra::Point3::new(1.0, 3.0, 3.0)).norm() < 1e-12,
        "{p}"
    );
    let mut buf = Vec::new();
    write_kitti(&t, &mut buf).expect("write");
    // Written back in the same order (up to the quaternion's rounding, ~1e-16).
    let back = parse_line_numbers(
        Path::new("k.txt"),
        1,
        std::str::from_utf8(&buf).expect("utf8").trim(),
        12,
        "3×4",
    )
    .expect("12 numbers");
    let want = [0.0, -1.0, 0.0, 1.0, 1.0, 0.0, 0.0, 2.0, 0.0, 0.0, 1.0, 3.0];
    for (a, b) in back.iter().zip(want) {
        assert!((a - b).abs() < 1e-15, "{back:?}");
    }
}

#[test]
fn kitti_errors_name_file_and_line() {
    let p = Path::new("seq00.txt");
    let e = parse_kitti("1 0 0 0 0 1 0 0 0 0 1 0\n1 0 0 0 0 1 0 0 0 0 1\n", p)
        .expect_err("11 numbers")
        .to_string();
    assert!(
        e.contains("seq00.txt") && e.contains("line 2") && e.contains("found 11"),
        "{e}"
    );
    let e = parse_kitti("2 0 0 0 0 1 0 0 0 0 1 0\n", p)
        .expect_err("not a rotation")
        .to_string();
    assert!(e.contains("line 1") && e.contains("orthonormal"), "{e}");
    let e = parse_kitti("-1 0 0 0 0 1 0 0 0 0 1 0\n", p)
        .expect_err("reflection")
        .to_string();
    assert!(e.contains("line 1") && e.contains("reflection"), "{e}");
}

#[test]
fn tum_refuses_unstamped_trajectories() {
    let t = Trajectory::unstamped(vec![Isometry3::identity()]);
    assert!(write_tum(&t, &mut Vec::new()).is_err());
}

#[test]
fn association_exact_then_nearest_within_tolerance() {
    let pose = Isometry3::identity();
    let est = Trajectory::stamped(vec![0, 100, 200, 300, 400], vec![pose; 5]);
    // 100 exact; 206 and 197 both within 10 of 200, 197 nearer; 310 exactly 10 from 300
    // (the tolerance is inclusive); 0 and 400 have no partner within 10.
    let gt = Trajectory::stamped(vec![100, 206, 197, 310, 425], vec![pose; 5]);
    let a = associate(&est, &gt, 10).expect("stamped");
    assert_eq!(a.method, AssociationMethod::Stamp);
    assert_eq!(a.pairs, vec![(1, 0), (2, 2), (3, 3)]);
    assert_eq!(a.max_dt_ns, 10);
    // Each reference pose once: two estimates at the same distance of one reference.
    let est = Trajectory::stamped(vec![90, 110], vec![pose; 2]);
    let gt = Trajectory::stamped(vec![100], vec![pose]);
    assert_eq!(associate(&est, &gt, 10).expect("ok").pairs.len(), 1);
}

#[test]
fn association_by_index_needs_equal_lengths() {
    let pose = Isometry3::identity();
    let est = Trajectory::stamped(vec![0, 1, 2], vec![pose; 3]);
    let gt = Trajectory::unstamped(vec![pose; 3]);
    let a = associate(&est, &gt, 0).expect("equal lengths");
    assert_eq!(a.method, AssociationMethod::Index);
    assert_eq!(a.pairs, vec![(0, 0), (1, 1), (2, 2)]);
    let gt = Trajectory::unstamped(vec![pose; 4]);
    let e = associate(&est, &gt, 0)
        .expect_err("lengths differ")
        .to_string();
    assert!(e.contains("3 poses") && e.contains("reference 4"), "{e}");
}

#[test]
fn evaluate_flags_and_known_step_error() {
    // GT: 1 m steps along x. Estimate: 1.1 m steps ⇒ RPE 0.1 m per frame. Frame 2 failed.
    let n = 6;
    let stamps: Vec<i64> = (0..n).map(|k| 1_000 + 100 * k).collect();
    let gt = Trajectory::stamped(
        stamps.clone(),
        (0..n)
            .map(|k| Isometry3::translation(k as f64, 0.0, 0.0))
            .collect(),
    );
    let est = Trajectory::stamped(
        stamps.clone(),
        (0..n)
            .map(|k| Isometry3::translation(1.1 * k as f64, 0.0, 0.0))
            .collect(),
    );
    let flags: Vec<FrameFlag> = stamps
        .iter()
        .enumerate()
        .map(|(k, &s)| FrameFlag {
            frame: k as u64,
            stamp_ns: s,
            success: k != 2,
            failure_reason: (k == 2).then(|| "too_few_inliers".to_string()),
        })
        .collect();
    let ev = evaluate(&est, &gt, Some(&flags), 0).expect("evaluates");
    assert_eq!(ev.rows.len(), 6);
    assert_eq!(ev.failed_frames, Some(1));
    assert_eq!(ev.rows[2].success, Some(false));
    assert_eq!(
        ev.rows[2].failure_reason.as_deref(),
        Some("too_few_inliers")
    );
    assert_eq!(ev.rows[0].rpe_trans_m, None);
    for r in &ev.rows[1..] {
        assert!((r.rpe_trans_m.expect("k > 0") - 0.1).abs() < 1e-12);
    }
    assert!((ev.rpe_trans_mean_m - 0.1).abs() < 1e-12);
    assert!((ev.path_length_m - 5.0).abs() < 1e-12);
    // Centroid-aligned line: errors 0.1·|k − 2.5|, RMSE 0.1·sqrt((6² − 1)/12).
    assert!((ev.ate_rmse_m - 0.1 * (35.0_f64 / 12.0).sqrt()).abs() < 1e-9);
    // Without flags: success unknown, failed_frames unknown.
    let ev = evaluate(&est, &gt, None, 0).expect("evaluates");
    assert_eq!((ev.failed_frames, ev.rows[2].success), (None, None));
}

#[test]
fn evaluate_needs_two_pairs() {
    let pose = Isometry3::identity();
    let est = Trajectory::stamped(vec![0, 1_000_000_000], vec![pose; 2]);
    let gt = Trajectory::stamped(vec![500_000_000, 1_500_000_000], vec![pose; 2]);
    let e = evaluate(&est, &gt, None, DEFAULT_MAX_DT_NS)
        .expect_err("nothing associates")
        .to_string();
    assert!(e.contains("only 0 pose pairs"), "{e}");
}
