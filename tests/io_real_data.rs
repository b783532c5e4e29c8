//! Readers against the real data sets in `../shared/data` (skipped with a message when absent)
//! and the committed ICL-NUIM fixture in `fixtures/icl_nuim`.

use std::path::Path;

use nalgebra::{Isometry3, Point3};

use mireg::io::cloud_file::read_points;
use mireg::io::pose_file::{bunny_pose, find_log_pair, read_log};

#[path = "common/shared_data.rs"]
mod shared;
use shared::shared_data;

/// Median distance from (a subsample of about `samples`) `source` points to their nearest
/// `target` point, by brute force.
fn median_nn_distance(source: &[Point3<f64>], target: &[Point3<f64>], samples: usize) -> f64 {
    let d = nn_distances(source, target, samples);
    d[d.len() / 2]
}

/// Sorted nearest-neighbour distances from a subsample of about `samples` `source` points to
/// `target`, by brute force.
fn nn_distances(source: &[Point3<f64>], target: &[Point3<f64>], samples: usize) -> Vec<f64> {
    let step = (source.len() / samples).max(1);
    let mut d: Vec<f64> = source
        .iter()
        .step_by(step)
        .map(|s| {
            target
                .iter()
                .map(|t| (s - t).norm_squared())
                .fold(f64::INFINITY, f64::min)
                .sqrt()
        })
        .collect();
    d.sort_by(f64::total_cmp);
    d
}

fn transform(iso: &Isometry3<f64>, pts: &[Point3<f64>]) -> Vec<Point3<f64>> {
    pts.iter().map(|p| iso * p).collect()
}

/// The `element vertex N` count in a PLY header, read here independently of the reader.
fn ply_header_vertex_count(path: &Path) -> usize {
    let bytes = std::fs::read(path).unwrap();
    let text = String::from_utf8_lossy(&bytes[..4096.min(bytes.len())]).into_owned();
    let line = text
        .lines()
        .find(|l| l.starts_with("element vertex"))
        .unwrap();
    line.split_whitespace().nth(2).unwrap().parse().unwrap()
}

#[test]
fn bunny_ply_counts_and_metre_scale() {
    for name in ["bun000.ply", "bun045.ply", "bun090.ply"] {
        let Some(path) = shared_data(&format!("bunny/{name}")) else {
            return;
        };
        let pts = read_points(&path).unwrap();
        assert_eq!(pts.len(), ply_header_vertex_count(&path), "{name}");
        let (mut lo, mut hi) = (pts[0], pts[0]);
        for p in &pts {
            lo = lo.inf(p);
            hi = hi.sup(p);
        }
        let extent = (hi - lo).max();
        eprintln!("{name}: {} points, bbox extent {extent:.4} m", pts.len());
        // The bunny is ~15 cm tall: metres, not millimetres or centimetres.
        assert!((0.08..0.3).contains(&extent), "{name}: extent {extent}");
    }
}

#[test]
fn bunny_conf_convention_aligns_scans() {
    let Some(conf) = shared_data("bunny/bun.conf") else {
        return;
    };
    let conf = std::fs::read_to_string(conf).unwrap();
    // Neighbouring scans (45° apart) overlap enough for a median to measure alignment.
    for (source, target) in [("bun045.ply", "bun000.ply"), ("bun090.ply", "bun045.ply")] {
        let (Some(sp), Some(tp)) = (
            shared_data(&format!("bunny/{source}")),
            shared_data(&format!("bunny/{target}")),
        ) else {
            return;
        };
        let (src, tgt) = (read_points(&sp).unwrap(), read_points(&tp).unwrap());
        let world_from_s = bunny_pose(&conf, source).unwrap();
        let world_from_t = bunny_pose(&conf, target).unwrap();
        let target_from_source = world_from_t.inverse() * world_from_s;
        let aligned = median_nn_distance(&transform(&target_from_source, &src), &tgt, 2000);
        // The "obvious" reading world = R·x + t: rotation q instead of q⁻¹.
        let wrong = |w: Isometry3<f64>| Isometry3::from_parts(w.translation, w.rotation.inverse());
        let wrong_t_s = wrong(world_from_t).inverse() * wrong(world_from_s);
        let misaligned = median_nn_distance(&transform(&wrong_t_s, &src), &tgt, 2000);
        let untransformed = median_nn_distance(&src, &tgt, 2000);
        eprintln!(
            "{source}→{target} median NN: R(q)ᵀ convention {aligned:.5} m, R(q) convention {misaligned:.5} m, identity {untransformed:.5} m"
        );
        assert!(aligned < 0.002, "{source}: aligned median {aligned}");
        assert!(
            misaligned > 5.0 * aligned,
            "{source}: wrong convention {misaligned} vs {aligned}"
        );
    }
}

#[test]
fn threedmatch_npy_and_gt_log() {
    let (Some(ref_p), Some(src_p), Some(gt_log)) = (
        shared_data("3dmatch_redkitchen_0_6/ref.npy"),
        shared_data("3dmatch_redkitchen_0_6/src.npy"),
        shared_data(
            "3dmatch_redkitchen_0_6/3dmatch_benchmark_gt/3DMatch/7-scenes-redkitchen/gt.log",
        ),
    ) else {
        return;
    };
    let reference = read_points(&ref_p).unwrap();
    let source = read_points(&src_p).unwrap();
    assert_eq!(reference.len(), 18_977);
    assert_eq!(source.len(), 15_953);
    let records = read_log(&gt_log).unwrap();
    let ref_from_src = find_log_pair(&records, 0, 6).unwrap().pose;
    // gt.npy (GeoTransformer's src → ref) is the same transform: 4×4 little-endian f64 after
    // the 128-byte header, decoded here independently of the npy reader.
    if let Some(gt_npy) = shared_data("3dmatch_redkitchen_0_6/gt.npy") {
        let bytes = std::fs::read(gt_npy).unwrap();
        let m: Vec<f64> = bytes[128..]
            .chunks_exact(8)
            .map(|b| f64::from_le_bytes(b.try_into().unwrap()))
            .collect();
        let gt = nalgebra::Matrix4::from_row_slice(&m);
        let diff = (ref_from_src.to_homogeneous() - gt).abs().max();
        assert!(diff < 1e-4, "gt.log(0 6) vs gt.npy differ by {diff}");
    }
    // Partial overlap: compare the fraction of source points within 5 cm of the reference.
    let near = |iso: &Isometry3<f64>| {
        let d = nn_distances(&transform(iso, &source), &reference, 2000);
        d.iter().filter(|&&x| x < 0.05).count() as f64 / d.len() as f64
    };
    let aligned = near(&ref_from_src);
    let inverse = near(&ref_from_src.inverse());
    eprintln!(
        "3DMatch redkitchen 6→0, fraction of source points within 5 cm of ref: gt.log(0 6) {aligned:.3}, its inverse {inverse:.3} ({} records)",
        records.len()
    );
    assert!(aligned > 0.35, "aligned {aligned}");
    assert!(aligned > 2.0 * inverse, "inverse {inverse} vs {aligned}");
}

#[test]
fn kitti_bin_point_count() {
    let Some(path) = shared_data("kitti_pair/000000.bin") else {
        return;
    };
    let pts = read_points(&path).unwrap();
    assert_eq!(pts.len(), 124_668);
    // HDL-64 ranges: up to ~120 m, never more.
    let max_range = pts.iter().map(|p| p.coords.norm()).fold(0.0, f64::max);
    assert!((20.0..150.0).contains(&max_range), "max range {max_range}");
}

#[test]
fn icl_nuim_fixture_aligns_with_ground_truth_trajectory() {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("fixtures/icl_nuim");
    let frame0 = read_points(&dir.join("rgbd5_00000.ply")).unwrap();
    let frame4 = read_points(&dir.join("rgbd5_00004.ply")).unwrap();
    let trajectory = read_log(&dir.join("trajectory.log")).unwrap();
    assert_eq!(trajectory.len(), 5);
    // trajectory.log headers are `k k k+1`; poses are world_from_camera_k.
    let world_from_0 = find_log_pair(&trajectory, 0, 0).unwrap().pose;
    let world_from_4 = find_log_pair(&trajectory, 4, 4).unwrap().pose;
    let target_from_source = world_from_0.inverse() * world_from_4;
    // Depths of a living room seen from ~2 m: positive, under 6 m.
    for p in frame0.iter().chain(&frame4) {
        assert!(p.z > 0.3 && p.z < 6.0, "depth {}", p.z);
    }
    let aligned = median_nn_distance(&transform(&target_from_source, &frame4), &frame0, 2000);
    let raw = median_nn_distance(&frame4, &frame0, 2000);
    // The inverse composition (T4⁻¹·T0) applies the motion the wrong way round.
    let backwards = world_from_4.inverse() * world_from_0;
    let wrong = median_nn_distance(&transform(&backwards, &frame4), &frame0, 2000);
    eprintln!(
        "ICL-NUIM frame 4→0 median NN: ground truth {aligned:.4} m, identity {raw:.4} m, T4⁻¹·T0 {wrong:.4} m ({} / {} points)",
        frame4.len(),
        frame0.len()
    );
    assert!(aligned < 0.01, "aligned median {aligned}");
    assert!(raw > 3.0 * aligned, "identity {raw} vs aligned {aligned}");
    assert!(
        wrong > 3.0 * aligned,
        "T4⁻¹·T0 {wrong} vs aligned {aligned}"
    );
}
