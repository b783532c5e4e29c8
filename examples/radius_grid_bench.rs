//! Times nearest-within-radius queries on a real pair, as dense RANSAC verification and ICP ask
//! them: every downsampled source point, moved by a pose, against the downsampled target's
//! [`RadiusGrid`] at 1.5·voxel, and the grid's build. Prints a checksum of the answers so that a
//! speed-up can be checked to leave them bit-identical.
//!
//! ```sh
//! cargo run --release --example radius_grid_bench -- \
//!     ../shared/data/kitti_pair/000001.bin ../shared/data/kitti_pair/000000.bin 0.5 0.68 20
//! ```
//! Arguments: SOURCE TARGET VOXEL_M [FORWARD_M (x translation of the pose, default 0)]
//! [REPEATS (default 10)]. One thread.

use std::time::Instant;

use mireg::geometry::{RadiusGrid, voxel_downsample};
use nalgebra::{Point3, Vector3};

fn main() {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let [source, target, voxel, rest @ ..] = args.as_slice() else {
        eprintln!("usage: radius_grid_bench SOURCE TARGET VOXEL_M [FORWARD_M] [REPEATS]");
        std::process::exit(2);
    };
    let voxel: f64 = voxel.parse().expect("voxel size in metres");
    let forward: f64 = rest
        .first()
        .map_or(0.0, |r| r.parse().expect("forward metres"));
    let repeats: usize = rest.get(1).map_or(10, |r| r.parse().expect("repeats"));
    let read = |p: &str| {
        let points = mireg::io::cloud_file::read_points(std::path::Path::new(p)).expect("cloud");
        voxel_downsample(&points, voxel).expect("voxel grid")
    };
    let (source, target) = (read(source), read(target));
    let build = || {
        RadiusGrid::new(&target, 1.5 * voxel, usize::MAX)
            .expect("valid input")
            .expect("grid")
    };
    let mut builds: Vec<f64> = (0..repeats)
        .map(|_| {
            let start = Instant::now();
            let grid = build();
            let ms = start.elapsed().as_secs_f64() * 1e3;
            drop(grid);
            ms
        })
        .collect();
    builds.sort_by(f64::total_cmp);
    let grid = build();
    let queries: Vec<Point3<f64>> = source
        .iter()
        .map(|p| p + Vector3::new(forward, 0.0, 0.0))
        .collect();
    let mut times = Vec::new();
    let mut checksum = (0usize, 0u64, 0.0f64);
    for _ in 0..repeats {
        let start = Instant::now();
        checksum = queries
            .iter()
            .fold((0, 0, 0.0), |(n, h, s), q| match grid.nearest_within(q) {
                Some((j, d)) => (n + 1, h.rotate_left(7) ^ u64::from(j), s + d),
                None => (n, h, s),
            });
        times.push(start.elapsed().as_secs_f64() * 1e3);
    }
    times.sort_by(f64::total_cmp);
    let (found, h, sum) = checksum;
    println!(
        "{} queries, {} targets: min {:.2} ms, median {:.2} ms; {found} found, checksum {h:016x} {sum:.12e}; \
         build median {:.2} ms, {} kB",
        queries.len(),
        target.len(),
        times[0],
        times[repeats / 2],
        builds[repeats / 2],
        grid.heap_bytes() / 1000
    );
}
