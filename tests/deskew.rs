//! Deskewing: a spinning scan taken while the sensor moves (constant body velocity, integrated
//! numerically in 100 000 small steps — independent of the SE(3) exponential under test) is
//! recovered to < 1 mm; per-point time fields of each driver convention decode from PointCloud2.

use mireg::geometry::deskew::deskew;
use mireg::io::codec::{self, WireWrite, cdr, cdr::CdrWriter};
use mireg::io::point_time::TimeConvention;
use nalgebra::{Isometry3, Matrix3, Point3, Rotation3, Translation3, UnitQuaternion, Vector3};
use rand::{RngExt, SeedableRng};

#[path = "common/walls_room.rs"]
mod walls_room;
use walls_room::walls_room;

const SCAN_S: f64 = 0.1;

/// Sensor poses (in the sensor frame at t = 0) every `SCAN_S / steps` seconds, for body velocity
/// `v` \[m/s\] and angular rate `w` \[rad/s\], by first-order integration.
fn trajectory(v: Vector3<f64>, w: Vector3<f64>, steps: usize) -> Vec<Isometry3<f64>> {
    let h = SCAN_S / steps as f64;
    let (mut r, mut p) = (Matrix3::identity(), Vector3::zeros());
    let mut out = Vec::with_capacity(steps + 1);
    for _ in 0..=steps {
        let rot = Rotation3::from_matrix(&r);
        out.push(Isometry3::from_parts(
            Translation3::from(p),
            UnitQuaternion::from_rotation_matrix(&rot),
        ));
        p += r * v * h;
        r *= Matrix3::identity() + w.cross_matrix() * h;
        r = Rotation3::from_matrix(&r).into_inner(); // re-orthonormalise
    }
    out
}

#[test]
fn a_spinning_scan_of_a_moving_sensor_is_recovered_to_a_millimetre() {
    let steps = 100_000;
    // A car at 10 m/s turning at 35°/s.
    let poses = trajectory(
        Vector3::new(10.0, 0.0, 0.0),
        Vector3::new(0.0, 0.0, 0.6),
        steps,
    );
    let mut rng = rand_pcg::Pcg64Mcg::seed_from_u64(8);
    let (mut measured, mut truth, mut times) = (Vec::new(), Vec::new(), Vec::new());
    for _ in 0..20_000 {
        // A point of the world (frame: sensor at t = 0), seen when the beam sweeps its azimuth.
        let azimuth = rng.random_range(0.0..std::f64::consts::TAU);
        let range = rng.random_range(3.0..60.0);
        let w = Point3::new(
            range * azimuth.cos(),
            range * azimuth.sin(),
            rng.random_range(-2.0..2.0),
        );
        let k = ((azimuth / std::f64::consts::TAU) * steps as f64) as usize;
        let t = k as f64 * SCAN_S / steps as f64;
        measured.push(poses[k].inverse() * w);
        truth.push(w);
        times.push(t);
    }
    let before = measured
        .iter()
        .zip(&truth)
        .map(|(a, b)| (a - b).norm())
        .fold(0.0, f64::max);
    // Constant velocity: the motion over the last scan period is the one during this scan.
    deskew(&mut measured, &times, &poses[steps], SCAN_S);
    let after = measured
        .iter()
        .zip(&truth)
        .map(|(a, b)| (a - b).norm())
        .fold(0.0, f64::max);
    assert!(before > 0.5, "the scan should be skewed: {before} m");
    assert!(
        after < 1e-3,
        "worst point {after} m after deskewing ({before} m before)"
    );
}

/// A PointCloud2 with x, y, z (FLOAT32) and one time field of the given name and datatype.
fn cloud_with_time(name: &str, datatype: u8, stamp: codec::Time, values: &[f64]) -> Vec<u8> {
    let size = if datatype == 8 { 8 } else { 4 };
    let step = 12 + size;
    let mut w = CdrWriter::new();
    w.i32(stamp.sec);
    w.u32(stamp.nanosec);
    w.string("lidar");
    w.u32(1);
    w.u32(values.len() as u32);
    w.sequence_len(4);
    for (i, (n, dt)) in [("x", 7u8), ("y", 7), ("z", 7), (name, datatype)]
        .iter()
        .enumerate()
    {
        w.string(n);
        w.u32(4 * i as u32);
        w.u8(*dt);
        w.u32(1);
    }
    w.bool(false);
    w.u32(step as u32);
    w.u32((step * values.len()) as u32);
    w.u32((step * values.len()) as u32);
    for (k, v) in values.iter().enumerate() {
        for c in [k as f32, 1.0, 2.0] {
            w.raw(&c.to_le_bytes());
        }
        match datatype {
            6 => w.raw(&(*v as u32).to_le_bytes()),
            7 => w.raw(&(*v as f32).to_le_bytes()),
            _ => w.raw(&v.to_le_bytes()),
        }
    }
    w.bool(true);
    w.finish()
}

/// A ROS 2 MCAP log of `frames` (points in metres, their `t` field in ns) on `/points`, 100 ms
/// apart from 1 s on.
fn timed_cloud_log(frames: impl IntoIterator<Item = (Vec<Point3<f64>>, Vec<f64>)>) -> Vec<u8> {
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
        .add_channel(schema, "/points", "cdr", &Default::default())
        .unwrap();
    for (k, (pts, times)) in frames.into_iter().enumerate() {
        let t = 1_000_000_000 + k as u64 * 100_000_000;
        let stamp = codec::Time::from_ns(t as i64).unwrap();
        let mut msg = cloud_with_time("t", 6, stamp, &times);
        // Real coordinates instead of the helper's placeholders (x, y, z at the start of each point).
        let data_start = msg.len() - 1 - 16 * pts.len();
        for (i, p) in pts.iter().enumerate() {
            for (j, c) in [p.x, p.y, p.z].iter().enumerate() {
                let at = data_start + 16 * i + 4 * j;
                msg[at..at + 4].copy_from_slice(&(*c as f32).to_le_bytes());
            }
        }
        let header = mcap::records::MessageHeader {
            channel_id: ch,
            sequence: k as u32,
            log_time: t,
            publish_time: t,
        };
        w.write_to_known_channel(&header, &msg).unwrap();
    }
    w.finish().unwrap();
    drop(w);
    out.into_inner()
}

/// A time-field case: field, PointField datatype, raw values, convention, seconds after the stamp.
type Case = (&'static str, u8, Vec<f64>, TimeConvention, Vec<f64>);

#[test]
fn time_fields_of_each_driver_decode_as_seconds_after_the_stamp() {
    let stamp = codec::Time {
        sec: 1_700_000_000,
        nanosec: 500_000_000,
    };
    let abs = 1_700_000_000.5;
    // (field, PointField datatype, raw values, convention, seconds after the stamp)
    let cases: [Case; 5] = [
        (
            "t",
            6,
            vec![0.0, 25e6, 50e6],
            TimeConvention::RelativeNs,
            vec![0.0, 0.025, 0.05],
        ),
        (
            "offset_time",
            6,
            vec![1e6, 2e6],
            TimeConvention::RelativeNs,
            vec![0.001, 0.002],
        ),
        (
            "time",
            7,
            vec![-0.1, -0.05],
            TimeConvention::RelativeS,
            vec![-0.1, -0.05],
        ),
        (
            "timestamp",
            8,
            vec![abs, abs + 0.04],
            TimeConvention::AbsoluteS,
            vec![0.0, 0.04],
        ),
        (
            "time_stamp",
            8,
            vec![abs + 0.01],
            TimeConvention::AbsoluteS,
            vec![0.01],
        ),
    ];
    for (name, dt, raw, convention, seconds) in cases {
        let c = cdr::decode_point_cloud2(&cloud_with_time(name, dt, stamp, &raw)).unwrap();
        let t = c.times.unwrap_or_else(|| panic!("{name}: no times"));
        assert_eq!((t.field.as_str(), t.convention), (name, convention));
        for (a, b) in t.seconds.iter().zip(&seconds) {
            assert!((a - b).abs() < 1e-6, "{name}: {a} vs {b}");
        }
    }
    // No time field: no times.
    let plain = cdr::encode_point_cloud2(
        &codec::Header {
            stamp,
            frame_id: "l".into(),
        },
        &[Point3::new(1.0f32, 2.0, 3.0)],
        None,
    );
    assert!(cdr::decode_point_cloud2(&plain).unwrap().times.is_none());
}

/// A log of spinning scans (a room, `t` in ns, the sensor moving 0.1 m per scan): the stats say
/// which frames were deskewed (from the fourth on, with the motion of the second; none with `off`),
/// and `on` refuses a
/// log without a time field.
#[test]
fn register_deskews_from_the_fourth_frame_and_says_so() {
    use mireg::register::{DeskewMode, RegisterOptions, register_log};
    let dir = tempfile::tempdir().unwrap();
    let room = walls_room(6000, 2);
    let frames = (0..8u64).map(|k| {
        let sensor = Isometry3::translation(0.1 * k as f64, 0.0, 0.0);
        let pts: Vec<Point3<f64>> = room.iter().map(|p| sensor.inverse() * p).collect();
        let times: Vec<f64> = pts
            .iter()
            .map(|p| (p.y.atan2(p.x) + std::f64::consts::PI) / std::f64::consts::TAU * 1e8)
            .collect();
        (pts, times)
    });
    let input = dir.path().join("spin.mcap");
    std::fs::write(&input, timed_cloud_log(frames)).unwrap();
    let stats = |mode: DeskewMode| -> Vec<serde_json::Value> {
        let output = dir.path().join("out.mcap");
        let config = mireg::odometry::OdometryConfig {
            pair: mireg::pipeline::PairConfig {
                voxel_size_m: 0.2,
                ..Default::default()
            },
            ..Default::default()
        };
        let opts = RegisterOptions {
            force: true,
            deskew: mode,
            ..RegisterOptions::new(&input, &output, config)
        };
        register_log(&opts).unwrap();
        let mut v = Vec::new();
        let mut stats_channel = None;
        mireg::io::mcap::read::for_each_record(&output, |r| {
            match r {
                mcap::records::Record::Channel(c) if c.topic == "/mireg/stats" => {
                    stats_channel = Some(c.id)
                }
                mcap::records::Record::Message { header, data }
                    if Some(header.channel_id) == stats_channel =>
                {
                    v.push(serde_json::from_slice(&data).unwrap())
                }
                _ => {}
            }
            Ok(())
        })
        .unwrap();
        v
    };
    let auto = stats(DeskewMode::Auto);
    let deskewed: Vec<bool> = auto
        .iter()
        .map(|s| s["deskewed"].as_bool().unwrap())
        .collect();
    assert_eq!(
        deskewed,
        [false, false, false, true, true, true, true, true]
    );
    assert!(auto.iter().all(|s| s["time_field"] == "t"));
    assert!(
        stats(DeskewMode::Off)
            .iter()
            .all(|s| s["deskewed"] == false)
    );
    // `on` with a log without times.
    let plain = dir.path().join("plain.mcap");
    std::fs::write(
        &plain,
        mireg::fuzzing::small_log(2, mcap::WriteOptions::new()),
    )
    .unwrap();
    let config = mireg::odometry::OdometryConfig::default();
    let out = dir.path().join("p.mcap");
    let opts = RegisterOptions {
        deskew: DeskewMode::On,
        ..RegisterOptions::new(&plain, &out, config)
    };
    let e = register_log(&opts).unwrap_err().to_string();
    assert!(e.contains("--deskew on") && e.contains("plain.mcap"), "{e}");
    assert!(!out.exists());
}

/// A forward-looking sensor (100° wide, like a Livox) sweeping left to right over each 100 ms
/// frame while it moves at a varying 1.5–2.5 m/s and 10–30°/s: each point is measured from the
/// pose at its own time, so the clouds are truly skewed, and the constant velocity deskewing
/// assumes is never quite right. Registered with deskewing, the worst frame's motion error must
/// be at most half (translation) and three quarters (rotation) of the same log's registered
/// without deskewing. (Before the motion for deskewing was taken between mean point times, the stamps'
/// poses absorbed each deskew's error and fed it to the next, and the motions oscillated.)
#[test]
fn deskewing_a_truly_skewed_log_recovers_its_motion_without_oscillating() {
    use mireg::register::{DeskewMode, RegisterOptions, register_log};
    let dir = tempfile::tempdir().unwrap();
    let mut rng = rand_pcg::Pcg64Mcg::seed_from_u64(7);
    let room: Vec<Point3<f64>> = (0..12000)
        .map(|_| {
            let (u, v): (f64, f64) = (rng.random_range(-8.0..8.0), rng.random_range(-1.0..3.0));
            match rng.random_range(0..6u32) {
                0 => Point3::new(u, 8.0, v),
                1 => Point3::new(u, -8.0, v),
                2 => Point3::new(8.0, u, v),
                3 => Point3::new(-8.0, u, v),
                4 => Point3::new(u * 0.2 + 3.0, u * 0.1 - 2.0, v), // a slanted pillar
                _ => Point3::new(u, rng.random_range(-8.0..8.0), -1.0),
            }
        })
        .collect();
    // World = the first frame's sensor frame. Frame k moves by a constant body twist over its
    // 100 ms, a different one each frame.
    let twist = |k: usize| {
        let k = k as f64;
        let yaw = (20.0 + 10.0 * (0.7 * k).cos()).to_radians() * SCAN_S;
        let speed = 2.0 + 0.5 * (0.9 * k).sin();
        (
            Vector3::new(0.0, 0.0, yaw),
            Vector3::new(speed * SCAN_S, 0.0, 0.0),
        )
    };
    let step = |k: usize, share: f64| {
        let (omega, v) = twist(k);
        mireg::geometry::deskew::exp_twist(&(omega * share), &(v * share))
    };
    let mut stamps = vec![Isometry3::identity()];
    for k in 0..FRAMES as usize {
        stamps.push(stamps[k] * step(k, 1.0));
    }
    const FRAMES: u64 = 14;
    let frames = (0..FRAMES as usize).map(|k| {
        let (mut pts, mut times) = (Vec::new(), Vec::new());
        for p in &room {
            let q = stamps[k].inverse() * p;
            // The sweep crosses the field of view from left to right in 100 ms.
            let share = (0.5 - q.y.atan2(q.x) / 100f64.to_radians()).clamp(0.0, 1.0);
            if q.x > 0.0 && share > 0.0 && share < 1.0 {
                pts.push((stamps[k] * step(k, share)).inverse() * p);
                times.push(share * 1e8);
            }
        }
        (pts, times)
    });
    let input = dir.path().join("skewed.mcap");
    std::fs::write(&input, timed_cloud_log(frames)).unwrap();
    // The worst frame-to-frame error (m, degrees) from frame 4 on, the first deskewed frames
    // having settled.
    let errors = |mode: DeskewMode| -> (f64, f64) {
        let output = dir.path().join("out.mcap");
        let config = mireg::odometry::OdometryConfig {
            pair: mireg::pipeline::PairConfig {
                voxel_size_m: 0.1,
                ..Default::default()
            },
            ..Default::default()
        };
        let opts = RegisterOptions {
            force: true,
            deskew: mode,
            loops: false,
            ..RegisterOptions::new(&input, &output, config)
        };
        register_log(&opts).unwrap();
        let poses = mireg::io::poses::read_mcap_pose_topic(&output, "/mireg/pose")
            .unwrap()
            .poses;
        assert_eq!(poses.len(), FRAMES as usize);
        poses
            .windows(2)
            .enumerate()
            .skip(4)
            .map(|(k, p)| {
                let e = step(k, 1.0).inverse() * (p[0].inverse() * p[1]);
                (e.translation.vector.norm(), e.rotation.angle().to_degrees())
            })
            .fold((0.0, 0.0), |(t, r), (et, er)| {
                (f64::max(t, et), f64::max(r, er))
            })
    };
    let (on, off) = (errors(DeskewMode::Auto), errors(DeskewMode::Off));
    // Measured: deskewed 2.0 cm and 0.33°, raw 4.7 cm and 0.55°; with the motions between
    // stamps, deskewed 14 cm and 1.4°.
    assert!(
        on.0 < 0.5 * off.0 && on.1 < 0.75 * off.1,
        "deskewed: {on:?}, raw: {off:?}"
    );
}

/// A time field that holds one value for every point (Livox drivers that leave `offset_time` at
/// zero) measures no sweep: no frame is reported `deskewed`, the field is still named, and the
/// poses are those of the same log registered with `--deskew off`.
#[test]
fn times_that_do_not_vary_deskew_nothing_and_say_so() {
    use mireg::register::{DeskewMode, RegisterOptions, register_log};
    let dir = tempfile::tempdir().unwrap();
    let room = walls_room(4000, 5);
    let frames = (0..6u64).map(|k| {
        let sensor = Isometry3::translation(0.1 * k as f64, 0.0, 0.0);
        let pts: Vec<Point3<f64>> = room.iter().map(|p| sensor.inverse() * p).collect();
        let times = vec![0.0; pts.len()];
        (pts, times)
    });
    let input = dir.path().join("zero_times.mcap");
    std::fs::write(&input, timed_cloud_log(frames)).unwrap();
    let run = |mode: DeskewMode, name: &str| {
        let output = dir.path().join(name);
        let config = mireg::odometry::OdometryConfig {
            pair: mireg::pipeline::PairConfig {
                voxel_size_m: 0.2,
                ..Default::default()
            },
            ..Default::default()
        };
        let opts = RegisterOptions {
            deskew: mode,
            loops: false,
            ..RegisterOptions::new(&input, &output, config)
        };
        register_log(&opts).unwrap();
        let poses = mireg::io::poses::read_mcap_pose_topic(&output, "/mireg/pose").unwrap();
        let mut stats: Vec<serde_json::Value> = Vec::new();
        let mut channel = None;
        mireg::io::mcap::read::for_each_record(&output, |r| {
            match r {
                mcap::records::Record::Channel(c) if c.topic == "/mireg/stats" => {
                    channel = Some(c.id)
                }
                mcap::records::Record::Message { header, data }
                    if Some(header.channel_id) == channel =>
                {
                    stats.push(serde_json::from_slice(&data).unwrap())
                }
                _ => {}
            }
            Ok(())
        })
        .unwrap();
        (poses, stats)
    };
    let (auto_poses, auto) = run(DeskewMode::Auto, "auto.mcap");
    assert_eq!(auto.len(), 6);
    assert!(auto.iter().all(|s| s["time_field"] == "t"), "{auto:?}");
    let deskewed: Vec<&serde_json::Value> = auto.iter().map(|s| &s["deskewed"]).collect();
    assert!(deskewed.iter().all(|d| **d == false), "{deskewed:?}");
    let (off_poses, _) = run(DeskewMode::Off, "off.mcap");
    assert_eq!(auto_poses, off_poses);
}
