//! `mireg map` end to end: the map of a registered fixture against a brute-force voxel mean of
//! its clouds and poses, a known-transform synthetic log whose frames must coincide, intensity
//! kept in every format, the trajectory choice, and clean failure on bad input.

use std::collections::{BTreeMap, HashMap};
use std::path::{Path, PathBuf};

use mcap::records::MessageHeader;
use mireg::io::codec::{Header, Time, cdr};
use nalgebra::{Isometry3, Point3, Translation3, UnitQuaternion};

fn fixture() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("fixtures/icl_livingroom1.mcap")
}

#[path = "common/cli.rs"]
mod cli;
use cli::{mireg, mireg_ok};

fn s(p: &Path) -> &str {
    p.to_str().unwrap()
}

/// `mireg map ARGS --json`: the summary.
fn map_json(args: &[&str]) -> serde_json::Value {
    let mut a = vec!["map"];
    a.extend(args);
    a.push("--json");
    serde_json::from_slice(&mireg_ok(&a).stdout).unwrap()
}

/// A map file read by a minimal parser independent of mireg's readers: the binary layouts
/// `mireg map` writes (PLY binary_little_endian, PCD DATA binary, NPY 1.0 `<f4`), all `f32`.
/// Returns (columns, flat values).
fn read_map(path: &Path) -> (usize, Vec<f32>) {
    let bytes = std::fs::read(path).unwrap();
    let ext = path.extension().unwrap().to_str().unwrap();
    let (header, data) = match ext {
        "npy" => {
            assert!(bytes.starts_with(b"\x93NUMPY\x01\x00"));
            let n = u16::from_le_bytes([bytes[8], bytes[9]]) as usize;
            assert_eq!((10 + n) % 64, 0, "npy header aligned to 64");
            (
                String::from_utf8(bytes[10..10 + n].to_vec()).unwrap(),
                &bytes[10 + n..],
            )
        }
        _ => {
            let end = if ext == "ply" {
                "end_header\n"
            } else {
                "DATA binary\n"
            };
            let text = String::from_utf8_lossy(&bytes);
            let at = text.find(end).unwrap() + end.len();
            (text[..at].to_string(), &bytes[at..])
        }
    };
    let (rows, cols) = match ext {
        "npy" => {
            assert!(header.contains("'descr': '<f4'"), "{header}");
            let shape = header.split("'shape': (").nth(1).unwrap();
            let dims: Vec<usize> = shape
                .split(')')
                .next()
                .unwrap()
                .split(',')
                .filter_map(|d| d.trim().parse().ok())
                .collect();
            (dims[0], dims[1])
        }
        "ply" => {
            let n = header
                .lines()
                .find_map(|l| l.strip_prefix("element vertex "))
                .unwrap()
                .parse()
                .unwrap();
            let props = header.matches("property float ").count();
            (n, props)
        }
        _ => {
            let n = header
                .lines()
                .find_map(|l| l.strip_prefix("POINTS "))
                .unwrap()
                .parse()
                .unwrap();
            let fields = header
                .lines()
                .find_map(|l| l.strip_prefix("FIELDS "))
                .unwrap()
                .split_whitespace()
                .count();
            (n, fields)
        }
    };
    if cols == 4 {
        assert!(
            header.contains("intensity") || ext == "npy",
            "{ext}: fourth column is intensity: {header}"
        );
    }
    assert_eq!(data.len(), rows * cols * 4, "{ext}: data size");
    let values = data
        .chunks_exact(4)
        .map(|c| f32::from_le_bytes(c.try_into().unwrap()))
        .collect();
    (cols, values)
}

type Key = [i64; 3];

fn key_of(p: &Point3<f64>, voxel: f64) -> Key {
    [
        (p.x / voxel).floor() as i64,
        (p.y / voxel).floor() as i64,
        (p.z / voxel).floor() as i64,
    ]
}

/// Brute-force voxel mean of clouds placed by poses: key → (centroid, mean intensity, count).
fn brute_force(
    voxel: f64,
    placed: impl Iterator<Item = Point3<f64>>,
) -> BTreeMap<Key, (Point3<f64>, u32)> {
    let mut m: BTreeMap<Key, ([f64; 3], u32)> = BTreeMap::new();
    for w in placed {
        let e = m.entry(key_of(&w, voxel)).or_default();
        e.0[0] += w.x;
        e.0[1] += w.y;
        e.0[2] += w.z;
        e.1 += 1;
    }
    m.into_iter()
        .map(|(k, (s, n))| {
            let n_f = f64::from(n);
            (k, (Point3::new(s[0] / n_f, s[1] / n_f, s[2] / n_f), n))
        })
        .collect()
}

/// Matches every map point to the brute-force centroid of its voxel (or a neighbour's, for an
/// `f32` rounding across a voxel face) within `tol` metres; every voxel is matched exactly once.
fn assert_matches(points: &[Point3<f64>], truth: &BTreeMap<Key, (Point3<f64>, u32)>, voxel: f64) {
    assert_eq!(points.len(), truth.len(), "map points vs occupied voxels");
    let mut used: HashMap<Key, usize> = HashMap::new();
    for (n, p) in points.iter().enumerate() {
        let k = key_of(p, voxel);
        let mut best: Option<(f64, Key)> = None;
        for dx in -1..=1 {
            for dy in -1..=1 {
                for dz in -1..=1 {
                    let q = [k[0] + dx, k[1] + dy, k[2] + dz];
                    if let Some((c, _)) = truth.get(&q) {
                        let d = (c - p).norm();
                        if best.is_none_or(|b| d < b.0) {
                            best = Some((d, q));
                        }
                    }
                }
            }
        }
        let (d, q) = best.unwrap_or_else(|| panic!("map point {n} {p:?} in no occupied voxel"));
        assert!(
            d < 1e-4,
            "map point {n} {p:?} is {d} m from its voxel's mean"
        );
        if let Some(m) = used.insert(q, n) {
            panic!("map points {m} and {n} in one voxel {q:?}");
        }
    }
}

fn xyz(cols: usize, values: &[f32]) -> Vec<Point3<f64>> {
    values
        .chunks_exact(cols)
        .map(|r| Point3::new(r[0].into(), r[1].into(), r[2].into()))
        .collect()
}

#[test]
fn fixture_map_is_the_voxel_mean_of_the_registered_clouds() {
    let dir = tempfile::tempdir().unwrap();
    let reg = dir.path().join("reg.mcap");
    mireg_ok(&["register", s(&fixture()), "-o", s(&reg)]);
    // The default voxel is register's, recorded in the output's metadata.
    let ply = dir.path().join("map.ply");
    let summary = map_json(&[s(&reg), "-o", s(&ply)]);
    assert_eq!(summary["voxel_source"], "register_metadata");
    // Loop closure is on by default: the best trajectory is the optimised one.
    assert_eq!(summary["pose_topic"], "/mireg/pose_optimized");
    assert_eq!(summary["clouds_used"], 71);
    assert_eq!(summary["clouds_without_pose"], 0);
    assert_eq!(summary["intensity"], false);
    let voxel = summary["voxel_m"].as_f64().unwrap();
    assert!(voxel > 0.01 && voxel < 0.2, "{voxel}");

    // Brute force from the clouds and poses of the output, read by the library.
    let traj = mireg::io::poses::read_mcap_pose_topic(&reg, "/mireg/pose_optimized").unwrap();
    let pose_of: HashMap<i64, Isometry3<f64>> = traj
        .stamps_ns
        .iter()
        .copied()
        .zip(traj.poses.iter().copied())
        .collect();
    let mut placed = Vec::new();
    mireg::register::for_each_cloud(&reg, None, |_, c| {
        let pose = pose_of[&c.header.stamp.to_ns()];
        placed.extend(c.points.iter().map(|p| pose * p));
        Ok(std::ops::ControlFlow::Continue(()))
    })
    .unwrap();
    assert_eq!(summary["points_in"], placed.len());
    let truth = brute_force(voxel, placed.into_iter());
    assert!(truth.len() > 1000, "{}", truth.len());
    assert_eq!(summary["map_points"], truth.len());

    let (cols, values) = read_map(&ply);
    assert_eq!(cols, 3);
    assert_matches(&xyz(3, &values), &truth, voxel);
    // mireg's own reader agrees with the minimal parser.
    assert_eq!(
        mireg::io::cloud_file::read_points(&ply).unwrap(),
        xyz(3, &values)
    );
    // --voxel overrides; a coarser voxel gives fewer points.
    let coarse = dir.path().join("coarse.npy");
    let c = map_json(&[s(&reg), "-o", s(&coarse), "--voxel", "0.2"]);
    assert_eq!(c["voxel_source"], "option");
    assert!(c["map_points"].as_u64().unwrap() < truth.len() as u64 / 4);
}

// ---------------------------------------------------------------------------------------------
// A synthetic "register output": clouds with intensity and chosen pose topics
// ---------------------------------------------------------------------------------------------

const VOXEL: f64 = 0.25;
const T0: i64 = 1_700_000_000_000_000_000;

/// World points at voxel centres (never near a voxel face), intensity = index.
fn world_scene() -> (Vec<Point3<f64>>, Vec<f32>) {
    let mut pts = Vec::new();
    for i in -6..6 {
        for j in -4..4 {
            for k in 0..3 {
                if (i + 2 * j + 3 * k) % 3 != 0 {
                    pts.push(Point3::new(
                        (f64::from(i) + 0.5) * VOXEL,
                        (f64::from(j) + 0.5) * VOXEL,
                        (f64::from(k) + 0.5) * VOXEL + 3.0,
                    ));
                }
            }
        }
    }
    let inten = (0..pts.len()).map(|n| n as f32 * 0.5).collect();
    (pts, inten)
}

fn world_from_frame(k: usize) -> Isometry3<f64> {
    let k = k as f64;
    Isometry3::from_parts(
        Translation3::new(0.3 * k, -0.1 * k, 0.2 * k),
        UnitQuaternion::from_euler_angles(0.05 * k, 0.3 * k, -0.1 * k),
    )
}

/// Poses of some frames: (frame, world_from_frame).
type FramePoses = Vec<(usize, Isometry3<f64>)>;

/// Writes `frames` clouds (the scene seen from [`world_from_frame`]) and, per `(topic, poses)`,
/// a PoseStamped channel with `poses[k]` for the frames it covers; `voxel` in the `mireg`
/// metadata when given.
fn write_log(path: &Path, frames: usize, pose_topics: &[(&str, FramePoses)], voxel: Option<f64>) {
    let (world, inten) = world_scene();
    let file = std::io::BufWriter::new(std::fs::File::create(path).unwrap());
    let mut w = mcap::WriteOptions::new()
        .profile("ros2")
        .create(file)
        .unwrap();
    let cloud_schema = w
        .add_schema(
            cdr::POINT_CLOUD2_SCHEMA_NAME,
            "ros2msg",
            cdr::POINT_CLOUD2_SCHEMA.as_bytes(),
        )
        .unwrap();
    let clouds = w
        .add_channel(cloud_schema, "/lidar/points", "cdr", &BTreeMap::new())
        .unwrap();
    let pose_schema = w
        .add_schema(
            cdr::POSE_STAMPED_SCHEMA_NAME,
            "ros2msg",
            cdr::POSE_STAMPED_SCHEMA.as_bytes(),
        )
        .unwrap();
    let pose_channels: Vec<u16> = pose_topics
        .iter()
        .map(|(t, _)| {
            w.add_channel(pose_schema, t, "cdr", &BTreeMap::new())
                .unwrap()
        })
        .collect();
    let stamp = |k: usize| T0 + k as i64 * 100_000_000;
    let header = |k: usize, frame: &str| Header {
        stamp: Time::from_ns(stamp(k)).unwrap(),
        frame_id: frame.into(),
    };
    let msg = |channel_id: u16, k: usize| MessageHeader {
        channel_id,
        sequence: k as u32,
        log_time: stamp(k) as u64,
        publish_time: stamp(k) as u64,
    };
    for k in 0..frames {
        let frame_from_world = world_from_frame(k).inverse();
        let pts: Vec<Point3<f64>> = world.iter().map(|p| frame_from_world * p).collect();
        let data = cdr::encode_point_cloud2(&header(k, "lidar"), &pts, Some(&inten));
        w.write_to_known_channel(&msg(clouds, k), &data).unwrap();
    }
    for ((_, poses), &ch) in pose_topics.iter().zip(&pose_channels) {
        for (k, pose) in poses {
            let data = cdr::encode_pose_stamped(&header(*k, "world"), pose);
            w.write_to_known_channel(&msg(ch, *k), &data).unwrap();
        }
    }
    if let Some(v) = voxel {
        w.write_metadata(&mcap::records::Metadata {
            name: "mireg".into(),
            metadata: BTreeMap::from([
                ("voxel_m".into(), v.to_string()),
                ("pose_topic".into(), "/mireg/pose".into()),
                ("topic".into(), "/lidar/points".into()),
            ]),
        })
        .unwrap();
    }
    w.finish().unwrap();
}

/// Poses of frames `ks`, each `world_from_frame(k)` moved by `error`.
fn poses(ks: &[usize], error: Isometry3<f64>) -> FramePoses {
    ks.iter()
        .map(|&k| (k, error * world_from_frame(k)))
        .collect()
}

#[test]
fn correctly_posed_frames_coincide_and_keep_intensity_in_every_format() {
    let dir = tempfile::tempdir().unwrap();
    let log = dir.path().join("log.mcap");
    let wrong = Isometry3::translation(0.2, 0.0, 0.0);
    // Odometry is off by 20 cm (most of a voxel) from frame 1 on; the optimized trajectory is exact and lacks
    // frame 2 (as a trajectory that failed there would).
    let odometry = [(0, world_from_frame(0))]
        .into_iter()
        .chain(poses(&[1, 2], wrong))
        .collect();
    write_log(
        &log,
        3,
        &[
            ("/mireg/pose", odometry),
            (
                "/mireg/pose_optimized",
                poses(&[0, 1], Isometry3::identity()),
            ),
        ],
        Some(VOXEL),
    );
    let (world, inten) = world_scene();
    for ext in ["ply", "pcd", "npy"] {
        let out = dir.path().join(format!("map.{ext}"));
        let summary = map_json(&[s(&log), "-o", s(&out)]);
        assert_eq!(summary["pose_topic"], "/mireg/pose_optimized", "auto");
        assert_eq!(summary["clouds_used"], 2);
        assert_eq!(summary["clouds_without_pose"], 1);
        assert_eq!(summary["intensity"], true);
        assert_eq!(summary["voxel_m"], VOXEL);
        let (cols, values) = read_map(&out);
        assert_eq!(cols, 4, "{ext}");
        // Both frames put each world point in its own voxel: one map point per world point,
        // at it, with its intensity.
        assert_eq!(values.len(), 4 * world.len(), "{ext}");
        let by_voxel: HashMap<Key, usize> = world
            .iter()
            .enumerate()
            .map(|(n, p)| (key_of(p, VOXEL), n))
            .collect();
        let mut seen = std::collections::HashSet::new();
        for r in values.chunks_exact(4) {
            let p = Point3::new(r[0].into(), r[1].into(), r[2].into());
            let n = by_voxel[&key_of(&p, VOXEL)];
            assert!(seen.insert(n), "{ext}: two map points in one voxel");
            assert!(
                (p - world[n]).norm() < 1e-5,
                "{ext}: {p:?} vs {:?}",
                world[n]
            );
            assert!((r[3] - inten[n]).abs() < 1e-4, "{ext}: intensity {}", r[3]);
        }
    }
    // The odometry's misplaced frames do not coincide: more points, each the mean of what fell
    // in its voxel.
    let out = dir.path().join("odometry.npy");
    let summary = map_json(&[s(&log), "-o", s(&out), "--trajectory", "odometry"]);
    assert_eq!(summary["pose_topic"], "/mireg/pose");
    assert_eq!(summary["clouds_used"], 3);
    let placed = (0..3).flat_map(|k| {
        let pose = if k == 0 {
            world_from_frame(0)
        } else {
            wrong * world_from_frame(k)
        };
        let from_world = world_from_frame(k).inverse();
        // The frame's points as the cloud stores them (f32), placed by the pose.
        world
            .iter()
            .map(move |p| {
                let c = from_world * p;
                pose * Point3::new(c.x as f32 as f64, c.y as f32 as f64, c.z as f32 as f64)
            })
            .collect::<Vec<_>>()
    });
    let truth = brute_force(VOXEL, placed);
    assert!(truth.len() > world.len());
    let (cols, values) = read_map(&out);
    assert_eq!(cols, 4);
    assert_matches(&xyz(4, &values), &truth, VOXEL);
}

#[test]
fn bad_input_fails_cleanly_and_writes_nothing() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("map.ply");
    let fail = |args: &[&str], wants: &[&str]| {
        let run = mireg(args);
        let err = String::from_utf8_lossy(&run.stderr).to_string();
        assert!(!run.status.success(), "{args:?} succeeded");
        assert!(!err.contains("panicked"), "{err}");
        for w in wants {
            assert!(err.contains(w), "{args:?}: {err:?} lacks {w:?}");
        }
    };
    // A log that was never registered: no poses.
    let fx = fixture();
    fail(
        &["map", s(&fx), "-o", s(&out)],
        &["icl_livingroom1.mcap", "/mireg/pose"],
    );
    assert!(!out.exists());
    // A pose topic without messages.
    let empty = dir.path().join("empty.mcap");
    write_log(&empty, 2, &[("/mireg/pose", vec![])], Some(VOXEL));
    fail(
        &["map", s(&empty), "-o", s(&out)],
        &["empty.mcap", "no poses"],
    );
    // Poses of no cloud: an empty map is an error, not an empty file.
    let none = dir.path().join("none.mcap");
    write_log(
        &none,
        1,
        &[("/mireg/pose", poses(&[5], Isometry3::identity()))],
        Some(VOXEL),
    );
    fail(&["map", s(&none), "-o", s(&out)], &["none.mcap", "without"]);
    // No voxel recorded and none given.
    let novox = dir.path().join("novox.mcap");
    write_log(
        &novox,
        1,
        &[("/mireg/pose", poses(&[0], Isometry3::identity()))],
        None,
    );
    fail(
        &["map", s(&novox), "-o", s(&out)],
        &["novox.mcap", "--voxel"],
    );
    fail(&["map", s(&novox), "-o", s(&out), "--voxel=-1"], &["voxel"]);
    // --trajectory optimized on a log without it.
    fail(
        &[
            "map",
            s(&novox),
            "-o",
            s(&out),
            "--voxel",
            "0.1",
            "--trajectory",
            "optimized",
        ],
        &["novox.mcap", "/mireg/pose_optimized"],
    );
    assert!(!out.exists());
    // Unknown extension, unreadable input.
    let xyz = dir.path().join("map.xyz");
    fail(
        &["map", s(&novox), "-o", s(&xyz), "--voxel", "0.1"],
        &["map.xyz", ".ply"],
    );
    let missing = dir.path().join("missing.mcap");
    fail(&["map", s(&missing), "-o", s(&out)], &["missing.mcap"]);
    let garbage = dir.path().join("garbage.mcap");
    std::fs::write(&garbage, b"not an mcap at all").unwrap();
    fail(&["map", s(&garbage), "-o", s(&out)], &["garbage.mcap"]);
    assert!(!out.exists() && !xyz.exists());
    // An existing output is kept unless --force.
    std::fs::write(&out, b"keep me").unwrap();
    fail(
        &["map", s(&novox), "-o", s(&out), "--voxel", "0.1"],
        &["exists", "--force"],
    );
    assert_eq!(std::fs::read(&out).unwrap(), b"keep me");
    mireg_ok(&["map", s(&novox), "-o", s(&out), "--voxel", "0.1", "--force"]);
    assert_ne!(std::fs::read(&out).unwrap(), b"keep me");
}

/// The map and export jobs of the library check their paths themselves, before reading (they
/// were the command line's checks): an output that is the input is refused and the input's
/// bytes stay; an output in a missing folder is named before the input is looked at (here it
/// does not even exist).
#[test]
fn the_map_and_export_jobs_refuse_an_output_that_is_an_input_before_reading() {
    use mireg::evaluate::{ExportOptions, export_to_file};
    use mireg::map::{MapOptions, map_runs};
    let dir = tempfile::tempdir().unwrap();
    let input = dir.path().join("run.npy");
    std::fs::write(&input, b"not a run").unwrap();
    let e = map_runs(
        std::slice::from_ref(&input),
        &input,
        true,
        &MapOptions::default(),
    )
    .unwrap_err()
    .to_string();
    assert!(e.contains("is the input"), "{e}");
    let opts = ExportOptions {
        input: input.clone(),
        ..ExportOptions::default()
    };
    let e = export_to_file(&opts, &input).unwrap_err().to_string();
    assert!(e.contains("is the input"), "{e}");
    assert_eq!(std::fs::read(&input).unwrap(), b"not a run");
    let missing = dir.path().join("no_such_folder/map.ply");
    let absent = dir.path().join("absent.mcap");
    let e = map_runs(
        std::slice::from_ref(&absent),
        &missing,
        false,
        &MapOptions::default(),
    )
    .unwrap_err()
    .to_string();
    assert!(e.contains("no_such_folder"), "{e}");
    let opts = ExportOptions {
        input: absent,
        ..ExportOptions::default()
    };
    let e = export_to_file(&opts, &missing).unwrap_err().to_string();
    assert!(e.contains("no_such_folder"), "{e}");
    let listing: Vec<_> = std::fs::read_dir(dir.path()).unwrap().collect();
    assert_eq!(listing.len(), 1, "nothing written beside the input");
}
