//! mireg's voxel grid against Open3D 0.20's `voxel_down_sample` on a committed synthetic cloud
//! (`fixtures/golden/voxel_open3d_small.npy`, made by `tools/make_fpfh_golden.py`).

mod common;

use mireg::geometry::voxel_downsample;
use nalgebra::Point3;

const GOLDEN: &str = concat!(
    env!("CARGO_MANIFEST_DIR"),
    "/fixtures/golden/voxel_open3d_small.npy"
);

fn sorted(mut v: Vec<Point3<f64>>) -> Vec<Point3<f64>> {
    v.sort_by(|a, b| {
        a.x.total_cmp(&b.x)
            .then(a.y.total_cmp(&b.y))
            .then(a.z.total_cmp(&b.z))
    });
    v
}

#[test]
fn voxel_grid_matches_open3d() {
    let (rows, cols, values) = common::read_npy_f64(GOLDEN);
    assert_eq!(cols, 3);
    let (n_in, n_out, voxel_m) = (values[0] as usize, values[1] as usize, values[2]);
    assert_eq!(rows, 1 + n_in + n_out);
    let row = |r: usize| Point3::new(values[3 * r], values[3 * r + 1], values[3 * r + 2]);
    let input: Vec<Point3<f64>> = (1..=n_in).map(row).collect();
    let open3d = sorted((1 + n_in..rows).map(row).collect());

    let ours = voxel_downsample(&input, voxel_m).unwrap();
    assert_eq!(ours.len(), open3d.len(), "occupied voxel count");
    // Same grid anchoring, same per-voxel summation order: centroids agree bit for bit.
    assert_eq!(sorted(ours), open3d);
}
