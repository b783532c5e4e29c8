//! `StreamOdometry` (one raw cloud per call) against `mireg register` on the same log: the same
//! poses, bit for bit — on the ICL fixture (no point times) and the Livox fixture (deskewed from
//! the fourth frame on).

use std::ops::ControlFlow;
use std::path::{Path, PathBuf};

use mireg::io::codec::cdr;
use mireg::odometry::OdometryConfig;
use mireg::odometry::stream::StreamOdometry;
use mireg::register::for_each_cloud;
use mireg::trajectory::read_mcap_pose_topic;

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
