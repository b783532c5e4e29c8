//! Finding 5 of the third round: one point at ≥ ~1e8 m in the first cloud ended the whole run
//! ("voxel_size_m … too small for a cloud spanning 1e9 m", naming no file, topic or frame). A
//! point with a coordinate of `mireg::io::codec::MAX_COORDINATE_M` (10⁶ m) or more is now
//! dropped at decoding and counted per frame (`num_dropped_far` in `/mireg/stats`); an error
//! that remains (a voxel too small for a cloud within the bound) names file, topic and log time.

use super::*;
use mireg::io::codec::{MAX_COORDINATE_M, cdr};
use nalgebra::Point3;

/// The small log with `extra[k]` points added to cloud `k`.
fn with_far_points(extra: &[&[[f64; 3]]]) -> Vec<u8> {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("small.mcap");
    std::fs::write(&path, small(extra.len())).unwrap();
    let mut m = messages(&path);
    let mut k = 0;
    for (c, _, data) in &mut m.messages {
        if m.channels[c].0 != "/points" {
            continue;
        }
        let cloud = cdr::decode_point_cloud2(data).unwrap();
        let mut points = cloud.points.clone();
        points.extend(extra[k].iter().map(|&[x, y, z]| Point3::new(x, y, z)));
        *data = cdr::encode_point_cloud2(&cloud.header, &points, None);
        k += 1;
    }
    assert_eq!(k, extra.len());
    let order: Vec<usize> = (0..m.messages.len()).collect();
    rewrite(&m, &order, mcap::WriteOptions::new())
}

/// A point at 1e9 m in the first cloud, and far points (one exactly at the bound) in a later
/// one: the run completes, every frame registers, the far points are counted in their frame's
/// stats and in a warning, and every pose is finite.
#[test]
fn a_far_point_is_dropped_and_counted_not_the_end_of_the_run() {
    let dir = tempfile::tempdir().unwrap();
    let (input, output) = (dir.path().join("far.mcap"), dir.path().join("out.mcap"));
    let b = MAX_COORDINATE_M;
    let far: [&[[f64; 3]]; 5] = [
        &[[1e9, 0.0, 0.0]],
        &[],
        &[[3e7, 1.0, 1.0], [0.0, -b, 0.0], [0.5, 0.5, 0.9 * b]],
        &[],
        &[],
    ];
    std::fs::write(&input, with_far_points(&far)).unwrap();
    let s = register_log(&options(&input, &output)).expect("the run completes");
    assert_eq!((s.frames, s.failed_frames), (5, 0));
    let stats = stats(&output);
    let dropped: Vec<u64> = stats
        .iter()
        .map(|f| f["num_dropped_far"].as_u64().unwrap())
        .collect();
    // The point at 0.9 × the bound is kept (it is within it); f32 rounding keeps 1e6 at 1e6.
    assert_eq!(dropped, [1, 0, 2, 0, 0]);
    let m = messages(&output);
    let mut poses = 0;
    for (c, _, data) in &m.messages {
        if m.channels[c].0 == "/mireg/pose" {
            let (_, pose) = cdr::decode_pose_stamped(data).unwrap();
            assert!(pose.to_homogeneous().iter().all(|v| v.is_finite()));
            poses += 1;
        }
    }
    assert_eq!(poses, 5);

    // Through the command line: the warning names the input, the topic and the first cloud.
    let run = mireg(&[
        "register",
        input.to_str().unwrap(),
        "-o",
        output.to_str().unwrap(),
        "--force",
        "--no-loops",
        "--voxel",
        "0.05",
    ]);
    let e = stderr(&run);
    assert_eq!(run.status.code(), Some(0), "{e}");
    assert!(
        e.contains("3 points of 2 clouds on /points dropped: a coordinate is 1000000 m or more"),
        "{e}"
    );
    assert!(e.contains(input.to_str().unwrap()), "{e}");
}

/// A voxel too small for the first cloud's extent within the bound is still an error, but it
/// names the file, the topic and the cloud's log time; nothing is written.
#[test]
fn a_voxel_too_small_for_the_first_cloud_names_file_topic_and_time() {
    let dir = tempfile::tempdir().unwrap();
    let (input, output) = (dir.path().join("wide.mcap"), dir.path().join("out.mcap"));
    std::fs::write(&input, with_far_points(&[&[[9e5, 0.0, 0.0]], &[]])).unwrap();
    let run = mireg(&[
        "register",
        input.to_str().unwrap(),
        "-o",
        output.to_str().unwrap(),
        "--voxel",
        "0.0001",
    ]);
    let e = stderr(&run);
    assert_eq!(run.status.code(), Some(2), "{e}");
    assert!(e.contains(input.to_str().unwrap()), "{e}");
    assert!(
        e.contains("first cloud on /points at log time 1700000000000000000 ns"),
        "{e}"
    );
    assert!(e.contains("too small for a cloud spanning"), "{e}");
    assert!(!output.exists());
}

/// `mireg pair` read its clouds (PLY, PCD, `.npy`, KITTI `.bin`) without the bound: a point at
/// 1e9 m in the source made the voxel too small for the cloud and ended the run. Far points are
/// now dropped and counted as in the logs (`num_dropped_far` per cloud in the JSON, a line in
/// the text), and the pair registers.
#[test]
fn pair_clouds_drop_and_count_far_points() {
    use mireg::io::cloud_file::{CloudFileFormat, read_points};
    let dir = tempfile::tempdir().unwrap();
    let icl = Path::new(env!("CARGO_MANIFEST_DIR")).join("fixtures/icl_nuim");
    let rows = |file: &str, far: &[[f32; 3]]| -> (usize, Vec<f32>) {
        let pts = read_points(&icl.join(file)).unwrap();
        let mut rows: Vec<f32> = pts
            .iter()
            .flat_map(|p| [p.x as f32, p.y as f32, p.z as f32])
            .collect();
        rows.extend(far.iter().flatten());
        (pts.len(), rows)
    };
    let (n_src, src) = rows("rgbd5_00004.ply", &[[1e9, 0.0, 0.0], [0.0, 3e7, 0.0]]);
    let (n_tgt, tgt) = rows("rgbd5_00000.ply", &[[0.0, 0.0, -1e6]]);
    let write = |name: &str, rows: &[f32]| {
        let path = dir.path().join(name);
        if name.ends_with(".bin") {
            let bytes: Vec<u8> = rows
                .chunks(3)
                .flat_map(|p| [p[0], p[1], p[2], 0.5])
                .flat_map(f32::to_le_bytes)
                .collect();
            std::fs::write(&path, bytes).unwrap();
        } else {
            let format = CloudFileFormat::from_path(&path).unwrap();
            let mut out = Vec::new();
            format.write(rows, 3, &mut out).unwrap();
            std::fs::write(&path, out).unwrap();
        }
        path.to_str().unwrap().to_string()
    };
    for ext in ["ply", "pcd", "npy", "bin"] {
        let s = write(&format!("src.{ext}"), &src);
        let t = write(&format!("tgt.{ext}"), &tgt);
        let run = mireg(&["pair", &s, &t, "--voxel", "0.05", "--json"]);
        assert_eq!(run.status.code(), Some(0), "{ext}: {}", stderr(&run));
        let v: serde_json::Value = serde_json::from_slice(&run.stdout).unwrap();
        assert_eq!(
            v["num_dropped_far"],
            serde_json::json!([2, 1]),
            "{ext}: {v}"
        );
        assert_eq!(
            v["num_points"],
            serde_json::json!([n_src, n_tgt]),
            "{ext}: {v}"
        );
        if ext == "ply" {
            let run = mireg(&["pair", &s, &t, "--voxel", "0.05"]);
            let text = String::from_utf8_lossy(&run.stdout);
            assert!(text.contains("far points dropped 2 / 1"), "{text}");
        }
    }
}
