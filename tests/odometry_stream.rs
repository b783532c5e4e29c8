//! `StreamOdometry` (one raw cloud per call) against `mireg register` on the same log: the same
//! poses, bit for bit — on the ICL fixture (no point times) and the Livox fixture (deskewed from
//! the fourth frame on).

use std::ops::ControlFlow;
use std::path::{Path, PathBuf};

use mireg::io::codec::cdr;
use mireg::io::poses::read_mcap_pose_topic;
use mireg::odometry::OdometryConfig;
use mireg::odometry::stream::StreamOdometry;
use mireg::register::for_each_cloud;

#[path = "common/cli.rs"]
mod cli;

fn fixture(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("fixtures")
        .join(name)
}

#[test]
fn stream_odometry_gives_register_s_poses_bit_for_bit() {
    let dir = tempfile::tempdir().unwrap();
    for log in [
        fixture("icl_livingroom1.mcap"),
        fixture("livox/icl_livox.bag"),
    ] {
        let out = dir.path().join("out.mcap");
        cli::mireg_ok(&[
            "register",
            log.to_str().unwrap(),
            "-o",
            out.to_str().unwrap(),
            "--no-loops",
            "--quiet",
            "--force",
        ]);
        let want = read_mcap_pose_topic(&out, "/mireg/pose").unwrap().poses;
        let mut odometry = StreamOdometry::new(OdometryConfig::default(), true, true);
        let mut got = Vec::new();
        for_each_cloud(&log, None, |_, cloud| {
            let times = cloud.times.as_ref().map(|t| t.seconds.clone());
            let stamp = cloud.header.stamp.to_ns();
            let est = odometry
                .push(cloud.points.clone(), times.as_deref(), stamp)
                .unwrap();
            // Through the pose message and back, as the output's poses went (the decoder
            // normalises the quaternion).
            let msg = cdr::encode_pose_stamped(&cloud.header, &est.world_from_frame);
            got.push(cdr::decode_pose_stamped(&msg).unwrap().1);
            Ok(ControlFlow::Continue(()))
        })
        .unwrap();
        assert!(!want.is_empty());
        assert_eq!(got, want, "{}", log.display());
    }
}

#[path = "common/room_scene.rs"]
mod room_scene;

/// A library caller's times that are not finite or far off the stamp never deskew: every pose
/// stays finite (with the times passed through unchecked, NaN reached every pose from the
/// first deskewed frame on).
#[test]
fn stream_odometry_ignores_times_that_cannot_deskew() {
    use mireg::odometry::OdometryConfig;
    use mireg::odometry::stream::StreamOdometry;
    use nalgebra::{Isometry3, Translation3};
    for bad in [f64::NAN, f64::INFINITY, 1e300, -30.0] {
        let mut odometry = StreamOdometry::new(OdometryConfig::default(), true, true);
        for k in 0..6u64 {
            let world_from_frame = Isometry3::from(Translation3::new(0.05 * k as f64, 0.0, 0.0));
            let points: Vec<_> = room_scene::scene(6000, k)
                .iter()
                .map(|p| world_from_frame.inverse() * p)
                .collect();
            let mut times: Vec<f64> = (0..points.len()).map(|i| i as f64 * 1e-5).collect();
            times[17] = bad;
            let est = odometry
                .push(points, Some(&times), (k * 100_000_000) as i64)
                .unwrap();
            let p = est.world_from_frame;
            assert!(
                p.translation.vector.iter().all(|v| v.is_finite())
                    && p.rotation.coords.iter().all(|v| v.is_finite()),
                "time {bad}: frame {k} pose {p}"
            );
        }
    }
}
