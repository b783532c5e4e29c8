//! Livox `CustomMsg` logs (issue 33): the fixture `fixtures/livox/` was written by rosbags from
//! the official message definitions (`tools/make_livox_log.py --fixture`), once as a ROS 1 bag
//! and once as a ROS 2 bag, and its first frames decoded back by rosbags into
//! `icl_livox_expected.bin`. mireg must decode both bags to exactly those points, keep and drop
//! them by tag as documented, and register both to the same poses.

use std::ops::ControlFlow;
use std::path::{Path, PathBuf};

use mireg::io::codec::PointCloud;
use mireg::io::codec::livox::{self, LivoxTags};
use mireg::io::input_log::InputLog;
use mireg::io::poses::read_mcap_pose_topic;
use mireg::trajectory::Trajectory;

#[path = "common/cli.rs"]
mod cli;
#[path = "common/log_contents.rs"]
mod log_contents;

fn fixture(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("fixtures/livox")
        .join(name)
}

/// One frame of the expected file: header stamp [ns], timebase [ns], and the points as
/// (x, y, z, offset_time, reflectivity, tag, line).
struct Expected {
    stamp_ns: u64,
    timebase: u64,
    points: Vec<([f32; 3], u32, u8, u8, u8)>,
}

/// `icl_livox_expected.bin`: see `write_expected` in tools/make_livox_log.py.
fn expected() -> Vec<Expected> {
    let b = std::fs::read(fixture("icl_livox_expected.bin")).unwrap();
    let magic = b"LIVOXEXP1\n";
    assert!(b.starts_with(magic));
    let mut at = magic.len();
    let mut take = |n: usize| {
        at += n;
        &b[at - n..at]
    };
    let u32_of = |s: &[u8]| u32::from_le_bytes(s.try_into().unwrap());
    let frames = u32_of(take(4));
    (0..frames)
        .map(|_| {
            let stamp_ns = u64::from_le_bytes(take(8).try_into().unwrap());
            let timebase = u64::from_le_bytes(take(8).try_into().unwrap());
            let n = u32_of(take(4));
            let points = (0..n)
                .map(|_| {
                    let p = take(20);
                    let f = |i: usize| f32::from_le_bytes(p[i..i + 4].try_into().unwrap());
                    ([f(0), f(4), f(8)], u32_of(&p[12..16]), p[16], p[17], p[18])
                })
                .collect();
            Expected {
                stamp_ns,
                timebase,
                points,
            }
        })
        .collect()
}

/// Every Livox cloud of `path`, decoded by mireg with `tags`.
fn decoded(path: &Path, tags: LivoxTags) -> Vec<PointCloud> {
    let (log, catalog) = InputLog::open(path).unwrap();
    let channel = catalog
        .channel_infos()
        .into_iter()
        .find(|c| livox::is_custom_msg(&c.schema_name))
        .expect("a Livox channel");
    let mut out = Vec::new();
    log.for_each_message_until(|h, data| {
        if h.channel_id == channel.id {
            let c = match channel.message_encoding.as_str() {
                "ros1" => livox::decode_ros1_reusing(data, Vec::new(), tags),
                _ => livox::decode_cdr_reusing(data, Vec::new(), tags),
            };
            out.push(c.unwrap());
        }
        Ok(ControlFlow::Continue(()))
    })
    .unwrap();
    out
}

#[test]
fn both_bags_decode_to_the_points_rosbags_decoded() {
    let want = expected();
    assert_eq!(want.len(), 3);
    for path in [fixture("icl_livox.bag"), fixture("icl_livox_ros2")] {
        for tags in [
            LivoxTags::KeepAll,
            LivoxTags::DropNoise,
            LivoxTags::FirstReturns,
        ] {
            let got = decoded(&path, tags);
            assert_eq!(got.len(), 10, "{}", path.display());
            for (c, e) in got.iter().zip(&want) {
                assert_eq!(c.header.stamp.to_ns() as u64, e.stamp_ns);
                let kept: Vec<_> = e.points.iter().filter(|p| tags.keeps(p.3)).collect();
                assert_eq!(c.points.len(), kept.len(), "{} {tags:?}", path.display());
                assert_eq!(c.num_dropped_tag, e.points.len() - kept.len());
                assert_eq!((c.num_dropped_non_finite, c.num_dropped_zero), (0, 0));
                let times = &c.times.as_ref().unwrap().seconds;
                let intensity = c.intensity.as_ref().unwrap();
                for (i, (xyz, offset, refl, _, _)) in kept.iter().enumerate() {
                    let p = c.points[i];
                    assert_eq!([p.x, p.y, p.z], xyz.map(f64::from));
                    assert_eq!(intensity[i], f32::from(*refl));
                    let t_ns = (e.timebase + u64::from(*offset)) as i64 - e.stamp_ns as i64;
                    assert!((times[i] - t_ns as f64 * 1e-9).abs() < 1e-12);
                }
            }
        }
    }
}

/// The `/mireg/pose` trajectory and the stats JSON by frame of a `register` output.
fn outputs(path: &Path) -> (Trajectory, Vec<serde_json::Value>) {
    let poses = read_mcap_pose_topic(path, "/mireg/pose").unwrap();
    let stats = log_contents::contents(path)
        .messages
        .iter()
        .filter(|m| m.0 == "/mireg/stats")
        .map(|m| serde_json::from_slice(&m.3).unwrap())
        .collect();
    (poses, stats)
}

#[test]
fn ros1_and_ros2_livox_logs_register_to_the_same_poses() {
    let dir = tempfile::tempdir().unwrap();
    let mut runs = Vec::new();
    for (input, name) in [
        ("icl_livox.bag", "ros1.mcap"),
        ("icl_livox_ros2", "ros2.mcap"),
    ] {
        let out = dir.path().join(name);
        let input = fixture(input);
        cli::mireg_ok(&[
            "register",
            input.to_str().unwrap(),
            "-o",
            out.to_str().unwrap(),
            "--quiet",
        ]);
        runs.push(outputs(&out));
    }
    let (ros1_poses, stats) = &runs[0];
    let (ros2_poses, _) = &runs[1];
    assert_eq!(ros1_poses.poses.len(), 10);
    assert_eq!(
        ros1_poses, ros2_poses,
        "the same points give the same poses"
    );
    let want = expected();
    for (s, e) in stats.iter().zip(&want) {
        assert_eq!(s["success"], true);
        assert_eq!(s["time_field"], "offset_time");
        let noise = e.points.iter().filter(|p| !LivoxTags::DropNoise.keeps(p.3));
        assert_eq!(s["num_dropped_livox_tag"], noise.count());
        assert_eq!(
            s["num_points"],
            e.points.len() - s["num_dropped_livox_tag"].as_u64().unwrap() as usize
        );
    }
    assert!(
        stats.iter().all(|s| s["success"] == true),
        "0 failed frames"
    );
    // Deskewed from the third frame on, with the time field.
    assert!(stats[3..].iter().all(|s| s["deskewed"] == true));

    let out = dir.path().join("keep_all.mcap");
    cli::mireg_ok(&[
        "register",
        fixture("icl_livox.bag").to_str().unwrap(),
        "-o",
        out.to_str().unwrap(),
        "--quiet",
        "--livox-tags",
        "keep-all",
    ]);
    let (_, keep_all) = outputs(&out);
    for (s, e) in keep_all.iter().zip(&want) {
        assert_eq!(s["num_dropped_livox_tag"], 0);
        assert_eq!(s["num_points"], e.points.len());
    }
}
