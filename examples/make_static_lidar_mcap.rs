//! A parked car: FRAMES copies of KITTI scan 000000 (`../shared/data/kitti_pair`, HDL-64) with
//! independent Gaussian noise of NOISE_M metres per coordinate (default 0.01), 0.1 s apart, as ROS 2
//! PointCloud2 on `/velodyne_points`. The true trajectory is the identity: the last pose of
//! `mireg register` is its drift (docs/BENCHMARKS_ARCHIVE.md).
//!
//! `cargo run --release --example make_static_lidar_mcap -- FRAMES OUT.mcap [NOISE_M]`

use std::path::Path;

use mireg::io::cloud_file::read_points;
use mireg::io::codec::{Header, Time, cdr};
use mireg::io::mcap::log::OutputLog;
use nalgebra::{Point3, Vector3};
use rand::SeedableRng;
use rand_distr::{Distribution, Normal};

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args: Vec<String> = std::env::args().collect();
    if args.len() < 3 {
        eprintln!("usage: make_static_lidar_mcap FRAMES OUT.mcap [NOISE_M]");
        std::process::exit(2);
    }
    let frames: usize = args[1].parse()?;
    let out = Path::new(&args[2]);
    let sigma: f64 = args.get(3).map(|s| s.parse()).transpose()?.unwrap_or(0.01);
    let data = Path::new(env!("CARGO_MANIFEST_DIR")).join("../shared/data/kitti_pair/000000.bin");
    let scan = read_points(&data)?;
    let noise = Normal::new(0.0, sigma)?;
    let mut rng = rand_pcg::Pcg64Mcg::seed_from_u64(17);
    let mut log = OutputLog::create(out, true, "ros2")?;
    let clouds = log.add_cdr_channel("/velodyne_points", cdr::POINT_CLOUD2)?;
    for k in 0..frames {
        let t = 1_700_000_000_000_000_000u64 + k as u64 * 100_000_000;
        let pts: Vec<Point3<f64>> = scan
            .iter()
            .map(|p| p + Vector3::from_fn(|_, _| noise.sample(&mut rng)))
            .collect();
        let header = Header {
            stamp: Time::from_ns(t as i64).ok_or("stamp")?,
            frame_id: "velodyne".into(),
        };
        log.write(clouds, t, t, &cdr::encode_point_cloud2(&header, &pts, None))?;
    }
    log.finish()?;
    println!("wrote {} ({frames} frames, noise {sigma} m)", out.display());
    Ok(())
}
