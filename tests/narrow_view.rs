//! Retries at a second scale (`src/odometry/retry.rs`): on a narrow view, one RANSAC stream at the
//! voxel derived from the first cloud can settle on a model of almost no motion while the vehicle
//! moves metres, and whether a log registered right hinged on the seed.
//!
//! The log: MulRan KAIST03's 21 keyframes (`../shared/data/mulran_kaist03_keyframes`; skipped
//! when absent) cut to a 25° cone about azimuth 180° (about 2 800 points a scan), played out on
//! the even keyframes and back on the odd ones, as `tools/make_loop_logs.py --source kaist03
//! --cone 25` builds it. The oracle is the data set's reference (SC-A-LOAM's loop-closed poses,
//! good to a few cm). Measured before the retries, default flags, seeds 0–7: ATE 3.8, 720, 241,
//! 4.1, 4.3, 589, 3.9 and 190 cm. The same log with a gap follows.

use mireg::io::cloud_file::read_points;
use mireg::io::codec::{Header, Time, cdr};
use mireg::io::mcap::log::OutputLog;
use mireg::odometry::OdometryConfig;
use mireg::register::{RegisterOptions, register_log};
use nalgebra::{Isometry3, Matrix3, Point3, Rotation3, Translation3, UnitQuaternion};

#[path = "common/log_contents.rs"]
mod log_contents;
#[path = "common/loop_records.rs"]
mod loop_records;
#[path = "common/shared_data.rs"]
mod shared;
use loop_records::poses_by_stamp;
use shared::shared_data;

const T0: i64 = 1_700_000_000_000_000_000;
const PERIOD_NS: i64 = 200_000_000;
const CONE_DEG: f64 = 25.0;
const SCANS: usize = 21;

/// The keyframes' reference poses (`poses_kitti.txt`: one 3×4 row-major world_from_sensor per
/// line).
fn reference(text: &str) -> Vec<Isometry3<f64>> {
    text.lines()
        .take(SCANS)
        .map(|line| {
            let v: Vec<f64> = line
                .split_whitespace()
                .map(|x| x.parse().unwrap())
                .collect();
            let r = Matrix3::new(v[0], v[1], v[2], v[4], v[5], v[6], v[8], v[9], v[10]);
            let q = UnitQuaternion::from_rotation_matrix(&Rotation3::from_matrix(&r));
            Isometry3::from_parts(Translation3::new(v[3], v[7], v[11]), q)
        })
        .collect()
}

/// The points whose azimuth lies within `CONE_DEG / 2` of 180°.
fn cone(points: &[Point3<f64>]) -> Vec<Point3<f64>> {
    let half = (CONE_DEG / 2.0).to_radians();
    points
        .iter()
        .filter(|p| (std::f64::consts::PI - p.y.atan2(p.x).abs()) <= half)
        .copied()
        .collect()
}

/// Registers the cone log of `messages` (each a keyframe and its message slot, stamped
/// `T0 + slot × PERIOD_NS`) with seeds 0–7, loops off; per seed the largest position error
/// against the reference, unaligned (both trajectories start at the identity). `None` without
/// the shared data.
fn largest_errors(messages: &[(usize, usize)]) -> Option<Vec<f64>> {
    let data = shared_data("mulran_kaist03_keyframes")?;
    let truth = reference(&std::fs::read_to_string(data.join("poses_kitti.txt")).unwrap());
    let dir = tempfile::tempdir().unwrap();
    let log_path = dir.path().join("cone25.mcap");
    let mut log = OutputLog::create(&log_path, false, "ros2").unwrap();
    let clouds = log
        .add_cdr_channel("/os1_points", cdr::POINT_CLOUD2)
        .unwrap();
    let stamp = |slot: usize| T0 + slot as i64 * PERIOD_NS;
    for &(k, slot) in messages {
        let scan = read_points(&data.join(format!("Scans/{k:06}.pcd"))).unwrap();
        let t = stamp(slot);
        let header = Header {
            stamp: Time::from_ns(t).unwrap(),
            frame_id: "os1".into(),
        };
        let msg = cdr::encode_point_cloud2(&header, &cone(&scan), None);
        log.write(clouds, t as u64, t as u64, &msg).unwrap();
    }
    log.finish().unwrap();

    let first_inv = truth[messages[0].0].inverse();
    let mut worst = Vec::new();
    for seed in 0..8 {
        let out = dir.path().join(format!("out_{seed}.mcap"));
        let mut config = OdometryConfig::default();
        config.pair.seed = seed;
        let opts = RegisterOptions {
            derive_voxel: true,
            loops: false,
            ..RegisterOptions::new(&log_path, &out, config)
        };
        register_log(&opts).unwrap();
        let poses = poses_by_stamp(&out, "/mireg/pose");
        let largest = messages
            .iter()
            .map(|&(k, slot)| {
                let est = poses[&stamp(slot)];
                ((first_inv * truth[k]).inverse() * est)
                    .translation
                    .vector
                    .norm()
            })
            .fold(0.0, f64::max);
        worst.push(largest);
    }
    Some(worst)
}

/// Out on the even keyframes, back on the odd ones, one message slot each.
fn out_and_back() -> Vec<(usize, usize)> {
    (0..SCANS)
        .step_by(2)
        .chain((1..SCANS).step_by(2).rev())
        .enumerate()
        .map(|(slot, k)| (k, slot))
        .collect()
}

#[test]
fn a_narrow_view_registers_right_for_every_seed() {
    let Some(worst) = largest_errors(&out_and_back()) else {
        return;
    };
    assert!(
        worst.iter().all(|&e| e < 0.5),
        "largest position error per seed [m]: {worst:.3?}"
    );
}

/// The same with messages 5 and 6 dropped (a jump of 7 m over three periods, as
/// `tools/make_loop_logs.py --kind gap --cone 25` drops them): after it the prediction is the
/// jump, and a frame whose every estimate stays far from it is retried again. Measured: before
/// the retries 332–700 cm of ATE on every seed; with one round of retries 4.1–4.4 cm but for
/// seed 1, 270 cm (frame 6 took a model of no motion at map fitness 0.61, and the frames after
/// it followed); with further rounds while the best stays far from the prediction, 4.1–4.4 cm.
#[test]
fn a_narrow_view_with_a_gap_registers_right_for_every_seed() {
    let messages: Vec<(usize, usize)> = out_and_back()
        .into_iter()
        .filter(|&(_, slot)| !(5..7).contains(&slot))
        .collect();
    let Some(worst) = largest_errors(&messages) else {
        return;
    };
    assert!(
        worst.iter().all(|&e| e < 0.5),
        "largest position error per seed [m]: {worst:.3?}"
    );
}
