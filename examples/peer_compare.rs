//! mireg side of the Open3D comparison on real data (see `tools/peer_open3d_match_icp.py`, which
//! exports Open3D's points, normals and FPFH features as `.npy` and prints Open3D's timings).
//!
//! `cargo run --release --example peer_compare -- /tmp/mireg_peer`

use std::path::Path;
use std::time::Instant;

use mireg::correspondence::matching::{Fpfh, MatchConfig, MatchMethod, match_features_with};
use mireg::refine::{IcpConfig, IcpTarget, evaluate_registration, registration_icp_point_to_plane};
use nalgebra::{
    Isometry3, Matrix4, Point3, Rotation3, Translation3, Unit, UnitQuaternion, Vector3,
};

/// Minimal reader for little-endian, C-order 2-D `.npy` arrays (`<f8` or `<f4`), as f64.
fn read_npy(path: &Path) -> (Vec<f64>, usize) {
    let bytes = std::fs::read(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    assert_eq!(&bytes[..6], b"\x93NUMPY", "{}: not .npy", path.display());
    let (header_len, start) = if bytes[6] == 1 {
        (u16::from_le_bytes([bytes[8], bytes[9]]) as usize, 10)
    } else {
        (
            u32::from_le_bytes(bytes[8..12].try_into().unwrap()) as usize,
            12,
        )
    };
    let header = std::str::from_utf8(&bytes[start..start + header_len]).unwrap();
    assert!(header.contains("'fortran_order': False"), "{header}");
    let shape = &header[header.find("'shape': (").unwrap() + 10..];
    let dims: Vec<usize> = shape[..shape.find(')').unwrap()]
        .split(',')
        .filter_map(|d| d.trim().parse().ok())
        .collect();
    let data = &bytes[start + header_len..];
    let values: Vec<f64> = if header.contains("'<f8'") {
        data.chunks_exact(8)
            .map(|c| f64::from_le_bytes(c.try_into().unwrap()))
            .collect()
    } else if header.contains("'<f4'") {
        data.chunks_exact(4)
            .map(|c| f32::from_le_bytes(c.try_into().unwrap()) as f64)
            .collect()
    } else {
        panic!("{}: unsupported dtype in {header}", path.display())
    };
    (values, dims.get(1).copied().unwrap_or(1))
}

fn points(path: &Path) -> Vec<Point3<f64>> {
    read_npy(path)
        .0
        .chunks_exact(3)
        .map(|c| Point3::new(c[0], c[1], c[2]))
        .collect()
}

fn fpfh(path: &Path) -> Vec<Fpfh> {
    let (v, cols) = read_npy(path);
    assert_eq!(cols, 33);
    v.chunks_exact(33)
        .map(|c| std::array::from_fn(|k| c[k] as f32))
        .collect()
}

fn best_of<T>(n: usize, mut f: impl FnMut() -> T) -> (f64, T) {
    let mut best = f64::INFINITY;
    let mut out = None;
    for _ in 0..n {
        let start = Instant::now();
        out = Some(f());
        best = best.min(start.elapsed().as_secs_f64() * 1e3);
    }
    (best, out.unwrap())
}

fn main() {
    let dir = std::env::args().nth(1).unwrap_or("/tmp/mireg_peer".into());
    let dir = Path::new(&dir);
    let src = points(&dir.join("src_points.npy"));
    let ref_points = points(&dir.join("ref_points.npy"));
    let ref_normals: Vec<Vector3<f64>> = points(&dir.join("ref_normals.npy"))
        .iter()
        .map(|p| p.coords)
        .collect();
    let src_fpfh = fpfh(&dir.join("src_fpfh.npy"));
    let ref_fpfh = fpfh(&dir.join("ref_fpfh.npy"));
    let gt = Matrix4::from_row_slice(&read_npy(&dir.join("gt.npy")).0);
    let rotation = Rotation3::from_matrix(&gt.fixed_view::<3, 3>(0, 0).into_owned());
    let gt = Isometry3::from_parts(
        Translation3::new(gt[(0, 3)], gt[(1, 3)], gt[(2, 3)]),
        UnitQuaternion::from_rotation_matrix(&rotation),
    );
    println!(
        "threads {} | src {} pts, ref {} pts | FPFH row sums: {:.1}",
        rayon::current_num_threads(),
        src.len(),
        ref_points.len(),
        src_fpfh[0].iter().sum::<f32>()
    );

    for method in [MatchMethod::BruteForce, MatchMethod::KdTree] {
        for (mutual, count_radius) in [(false, None), (false, Some(12.0)), (true, None)] {
            let config = MatchConfig {
                mutual,
                count_radius,
                method,
            };
            let (ms, m) = best_of(3, || match_features_with(&src_fpfh, &ref_fpfh, &config));
            println!(
                "match {method:?} mutual={mutual} count_radius={count_radius:?}: {ms:.1} ms, {} pairs",
                m.len()
            );
        }
    }

    let delta = Isometry3::from_parts(
        Translation3::new(0.06, -0.05, 0.06),
        UnitQuaternion::from_axis_angle(
            &Unit::new_normalize(Vector3::new(1.0, 1.0, 0.2)),
            5f64.to_radians(),
        ),
    );
    let init = gt * delta;
    let (build_ms, target) = best_of(3, || IcpTarget::new(&ref_points, &ref_normals).unwrap());
    let config = IcpConfig::new(0.1);
    let (ms, r) = best_of(3, || {
        registration_icp_point_to_plane(&src, &target, &init, &config).unwrap()
    });
    let err = gt.inverse() * r.target_from_source;
    println!(
        "ICP point-to-plane (max dist 0.1 m): {ms:.1} ms (+ kd-tree build {build_ms:.1} ms), {} iterations, converged {}, fitness {:.4}, rmse {:.2} mm, error vs gt {:.3} deg / {:.1} mm",
        r.iterations,
        r.converged,
        r.fitness,
        r.inlier_rmse_m * 1e3,
        err.rotation.angle().to_degrees(),
        err.translation.vector.norm() * 1e3
    );
    let e = evaluate_registration(&src, &target, &r.target_from_source, 0.1).unwrap();
    println!(
        "evaluate_registration at that pose: fitness {:.9} rmse {:.9}",
        e.fitness, e.inlier_rmse_m
    );

    let open3d_pose = dir.join("open3d_icp_target_from_source.npy");
    if open3d_pose.exists() {
        let m = Matrix4::from_row_slice(&read_npy(&open3d_pose).0);
        let rotation = Rotation3::from_matrix_unchecked(m.fixed_view::<3, 3>(0, 0).into_owned());
        let pose = Isometry3::from_parts(
            Translation3::new(m[(0, 3)], m[(1, 3)], m[(2, 3)]),
            UnitQuaternion::from_rotation_matrix(&rotation),
        );
        let e = evaluate_registration(&src, &target, &pose, 0.1).unwrap();
        println!(
            "evaluate_registration at Open3D's ICP pose: fitness {:.9} rmse {:.9}",
            e.fitness, e.inlier_rmse_m
        );
    }
}
