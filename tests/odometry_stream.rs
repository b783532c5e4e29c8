//! `StreamOdometry` (one raw cloud per call) against `mireg register` on the same log: the same
//! poses, bit for bit — on the ICL fixture (no point times) and the Livox fixture (deskewed from
//! the fourth frame on).

use std::ops::ControlFlow;
use std::path::{Path, PathBuf};

use mcap::records::Record;
use mireg::io::codec::{cdr, ros1};
use mireg::io::mcap::log::for_each_record;
use mireg::odometry::OdometryConfig;
use mireg::odometry::stream::StreamOdometry;
use mireg::register::for_each_cloud;
use nalgebra::Isometry3;

#[path = "common/cli.rs"]
mod cli;

fn fixture(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("fixtures")
        .join(name)
}

/// `/mireg/pose` of a register output.
fn register_poses(output: &Path) -> Vec<Isometry3<f64>> {
    let (mut channel, mut poses) = (None, Vec::new());
    for_each_record(output, |r| {
        match r {
            Record::Channel(c) if c.topic == "/mireg/pose" => {
                channel = Some((c.id, c.message_encoding.clone()))
            }
            Record::Message { header, data } => {
                if let Some((id, enc)) = &channel
                    && header.channel_id == *id
                {
                    let p = if enc == "ros1" {
                        ros1::decode_pose_stamped(&data)
                    } else {
                        cdr::decode_pose_stamped(&data)
                    };
                    poses.push(p.unwrap().1);
                }
            }
            _ => {}
        }
        Ok(())
    })
    .unwrap();
    poses
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
        let want = register_poses(&out);
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
