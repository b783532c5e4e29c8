//! Finding 4 of the third round: a per-point time field of NaN, ±Inf or 1e300 gave exit 0, no
//! warning, and NaN in `/mireg/pose`, `/mireg/pose_optimized` and `/tf` from the first deskewed
//! frame on.

use super::*;
use mireg::fuzzing::{TIME_GLITCHES as GLITCHES, timed_cloud_cdr};
use mireg::io::codec::cdr;
use nalgebra::{Isometry3, Point3};

/// Frame `k`'s time field: the clouds of frames 5 and 6 hold 1e300 and NaN for every point (a
/// field on another clock, a field without a time); the others a 100 ms sweep by azimuth with
/// the first [`GLITCHES`].len() points' times replaced by the glitches.
fn times_of(k: usize, points: &[Point3<f64>]) -> Vec<f64> {
    points
        .iter()
        .enumerate()
        .map(|(i, p)| match (k, GLITCHES.get(i)) {
            (5, _) => 1e300,
            (6, _) => f64::NAN,
            (_, Some(&g)) => g,
            _ => (p.y.atan2(p.x) + std::f64::consts::PI) / std::f64::consts::TAU * 0.1,
        })
        .collect()
}

const FRAMES: usize = 9;

/// A ROS 2 MCAP log of [`FRAMES`] clouds of the room on `/points`, the sensor moving 0.1 m per
/// 100 ms frame.
fn log() -> Vec<u8> {
    let room = walls_room(6000, 3);
    let mut out = std::io::Cursor::new(Vec::new());
    let mut w = mcap::WriteOptions::new()
        .profile("ros2")
        .create(&mut out)
        .unwrap();
    let schema = w
        .add_schema(
            cdr::POINT_CLOUD2_SCHEMA_NAME,
            "ros2msg",
            cdr::POINT_CLOUD2_SCHEMA.as_bytes(),
        )
        .unwrap();
    let ch = w
        .add_channel(schema, "/points", "cdr", &BTreeMap::new())
        .unwrap();
    for k in 0..FRAMES {
        let sensor = Isometry3::translation(0.1 * k as f64, 0.0, 0.0);
        let pts: Vec<Point3<f64>> = room.iter().map(|p| sensor.inverse() * p).collect();
        let times = times_of(k, &pts);
        let points: Vec<_> = pts.into_iter().zip(times).collect();
        let t = 1_000_000_000 + k as u64 * 100_000_000;
        let header = MessageHeader {
            channel_id: ch,
            sequence: k as u32,
            log_time: t,
            publish_time: t,
        };
        w.write_to_known_channel(&header, &timed_cloud_cdr(t, &points))
            .unwrap();
    }
    w.finish().unwrap();
    drop(w);
    out.into_inner()
}

fn assert_finite(what: &str, t: u64, pose: &Isometry3<f64>) {
    let m = pose.to_homogeneous();
    assert!(m.iter().all(|v| v.is_finite()), "{what} at {t}: {m}");
}

#[test]
fn non_finite_and_absurd_point_times_never_reach_a_pose() {
    let dir = tempfile::tempdir().unwrap();
    let input = dir.path().join("times.mcap");
    std::fs::write(&input, log()).unwrap();
    let out = dir.path().join("out.mcap");
    let run = mireg(&[
        "register",
        input.to_str().unwrap(),
        "-o",
        out.to_str().unwrap(),
        "--voxel",
        "0.2",
        "--quiet",
    ]);
    let err = stderr(&run);
    assert!(run.status.success(), "{err}");

    // Every pose on every topic, each finite.
    let m = messages(&out);
    let mut counts = BTreeMap::new();
    for (c, t, data) in &m.messages {
        let topic = m.channels[c].0.as_str();
        match topic {
            "/mireg/pose" | "/mireg/pose_optimized" => {
                let (_, pose) = cdr::decode_pose_stamped(data).unwrap();
                assert_finite(topic, *t, &pose);
            }
            "/tf" | "/mireg/tf_optimized" => {
                for tf in cdr::decode_tf_message(data).unwrap() {
                    assert_finite(topic, *t, &tf.transform);
                }
            }
            _ => continue,
        }
        *counts.entry(topic).or_insert(0) += 1;
    }
    assert_eq!(counts["/mireg/pose"], FRAMES, "{counts:?}");
    assert_eq!(counts["/tf"], FRAMES, "{counts:?}");
    assert_eq!(counts["/mireg/pose_optimized"], FRAMES, "{counts:?}");

    // The glitches dropped and counted: 6 points in each of the 7 clouds with a usable field;
    // the clouds of frames 5 and 6 kept whole and not deskewed.
    let stats = stats(&out);
    for (k, s) in stats.iter().enumerate() {
        let whole = k == 5 || k == 6;
        let want = if whole { 6000 } else { 6000 - GLITCHES.len() };
        assert_eq!(s["num_points"], want, "frame {k}: {s}");
        let dropped = if whole { 0 } else { GLITCHES.len() };
        assert_eq!(s["num_dropped_time"], dropped, "frame {k}: {s}");
        assert_eq!(s["deskewed"], k >= 3 && !whole, "frame {k}: {s}");
        assert_eq!(s["time_field"], "time", "frame {k}: {s}");
    }
    assert!(
        err.contains("42 points of 7 clouds on /points dropped")
            && err.contains("field time")
            && err.contains(input.to_str().unwrap()),
        "{err}"
    );
    assert!(err.contains("2 clouds on /points not deskewed"), "{err}");
    // The output is mireg's own to read again.
    let o = out.to_str().unwrap();
    let map = dir.path().join("map.ply");
    for args in [
        vec!["export", o, "--format", "tum"],
        vec![
            "evaluate",
            o,
            "--gt-topic",
            "/mireg/pose_optimized",
            "--json",
        ],
        vec!["map", o, "-o", map.to_str().unwrap()],
    ] {
        let run = mireg(&args);
        assert!(run.status.success(), "{args:?}: {}", stderr(&run));
    }
}
