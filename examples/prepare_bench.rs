//! Times the stages of preparing one real cloud (voxel grid, FPFH neighbourhoods, normals, FPFH,
//! and the ICP cloud's normals by kd-tree and by radius grid, as `mireg register` makes them)
//! on the current thread pool, and prints a checksum of the neighbourhoods and descriptors so
//! that a speed-up can be checked to leave the results bit-identical.
//!
//! ```sh
//! cargo run --release --example prepare_bench -- ../shared/data/kitti_pair/000000.bin 0.5 20
//! ```
//! Arguments: CLOUD VOXEL_M [REPEATS (default 10)]. Radii and caps are the pipeline defaults
//! (normals 2·voxel / 30, FPFH 5·voxel / 100).

use std::time::Instant;

use mireg::features::fpfh::compute_fpfh_from_neighbourhoods;
use mireg::geometry::{
    KdTree, Neighbourhoods, estimate_normals_from_neighbourhoods, estimate_normals_with_grid,
    estimate_normals_with_tree, grid, voxel_downsample,
};

/// Minimum and median of `repeats` runs of `f`, in ms, and its last result.
fn time<T>(repeats: usize, mut f: impl FnMut() -> T) -> (f64, f64, T) {
    let mut times = Vec::with_capacity(repeats);
    let mut out = None;
    for _ in 0..repeats {
        let start = Instant::now();
        out = Some(f());
        times.push(start.elapsed().as_secs_f64() * 1e3);
    }
    times.sort_by(f64::total_cmp);
    (times[0], times[repeats / 2], out.expect("repeats ≥ 1"))
}

fn mix(h: u64, x: u64) -> u64 {
    (h.rotate_left(5) ^ x).wrapping_mul(0x9E37_79B9_7F4A_7C15)
}

fn main() {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let [cloud, voxel, rest @ ..] = args.as_slice() else {
        eprintln!("usage: prepare_bench CLOUD VOXEL_M [REPEATS]");
        std::process::exit(2);
    };
    let voxel: f64 = voxel.parse().expect("voxel size in metres");
    let repeats: usize = rest.first().map_or(10, |r| r.parse().expect("repeats"));
    assert!(repeats >= 1, "repeats must be ≥ 1");
    let points =
        mireg::io::cloud_file::read_points(std::path::Path::new(cloud)).expect("readable cloud");
    println!(
        "threads {}, {} points",
        rayon::current_num_threads(),
        points.len()
    );

    let (min, med, down) = time(repeats, || {
        voxel_downsample(&points, voxel).expect("voxel grid")
    });
    println!(
        "voxel grid     {min:7.2} / {med:7.2} ms  ({} points)",
        down.len()
    );

    let mut nbhd = Neighbourhoods::default();
    let (min, med, _) = time(repeats, || {
        assert!(
            grid::self_neighbourhoods_into(&down, 5.0 * voxel, 100, &mut nbhd).expect("search"),
            "extent too large for the grid"
        )
    });
    let mut h = 0u64;
    let mut total = 0usize;
    for i in 0..nbhd.len() {
        let (idx, d2) = nbhd.get(i);
        total += idx.len();
        for (&j, &d) in idx.iter().zip(d2) {
            h = mix(mix(h, u64::from(j)), d.to_bits());
        }
    }
    println!("neighbourhoods {min:7.2} / {med:7.2} ms  ({total} neighbours, checksum {h:016x})");

    let (min, med, normals) = time(repeats, || {
        estimate_normals_from_neighbourhoods(&down, &nbhd, 2.0 * voxel, 30, None).expect("normals")
    });
    let h = normals
        .iter()
        .fold(0u64, |h, n| n.iter().fold(h, |h, c| mix(h, c.to_bits())));
    println!("normals        {min:7.2} / {med:7.2} ms  (checksum {h:016x})");

    let (min, med, features) = time(repeats, || {
        compute_fpfh_from_neighbourhoods(&down, &normals, &nbhd).expect("fpfh")
    });
    let h = features.iter().fold(0u64, |h, f| {
        f.iter().fold(h, |h, c| mix(h, u64::from(c.to_bits())))
    });
    println!("fpfh           {min:7.2} / {med:7.2} ms  (checksum {h:016x})");

    // The ICP cloud's normals in `mireg register`: the voxel cloud, radius 2·voxel, 30 nearest.
    let (radius, origin) = (2.0 * voxel, Some(nalgebra::Point3::origin()));
    let (min, med, by_tree) = time(repeats, || {
        let tree = KdTree::new(&down).expect("tree");
        estimate_normals_with_tree(&down, &tree, radius, 30, origin).expect("normals")
    });
    println!("ICP normals, kd-tree (with its build) {min:7.2} / {med:7.2} ms");
    let (min, med, by_grid) = time(repeats, || {
        estimate_normals_with_grid(&down, radius, 30, origin, 1 << 24)
            .expect("normals")
            .expect("the grid takes the cloud")
    });
    let same = if by_tree == by_grid {
        "bit-identical"
    } else {
        "DIFFERENT"
    };
    println!("ICP normals, radius grid              {min:7.2} / {med:7.2} ms  ({same})");
}
