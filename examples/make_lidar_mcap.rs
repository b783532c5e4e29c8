//! Builds LiDAR-size MCAP logs for the `register` benchmarks (docs/BENCHMARKS_ARCHIVE.md).
//!
//! `cargo run --release --example make_lidar_mcap -- FRAMES OUT.mcap [PASSTHROUGH_MB]`
//!
//! Frame `k` is KITTI scan `k % 2` of `../shared/data/kitti_pair` (HDL-64, ~124k points) moved by a
//! known extra motion (0.2 m and 0.5° yaw per frame), as a ROS 2 PointCloud2 (x, y, z, intensity).
//! With `PASSTHROUGH_MB`, a 1 MB/message binary channel of that many MB (incompressible bytes) is
//! interleaved, to measure the pass-through of non-cloud data against `cp`.
//!
//! The reference, on `/ground_truth/pose` (PoseStamped in the first frame's world): a frame of
//! scan 0 is that scan seen from `motion_k⁻¹`, which is therefore its true pose relative to
//! frame 0, exactly. A frame of scan 1 also carries scan 1's own pose relative to scan 0, which
//! the data set does not give, so the odd frames have no reference.

use std::path::Path;

use mireg::io::cloud_file::read_points;
use mireg::io::codec::{Header, Time, cdr};
use mireg::io::mcap::log::OutputLog;
use nalgebra::{Isometry3, Translation3, UnitQuaternion};

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args: Vec<String> = std::env::args().collect();
    if args.len() < 3 {
        eprintln!("usage: make_lidar_mcap FRAMES OUT.mcap [PASSTHROUGH_MB]");
        std::process::exit(2);
    }
    let frames: usize = args[1].parse()?;
    let out = Path::new(&args[2]);
    let passthrough_mb: usize = args.get(3).map(|s| s.parse()).transpose()?.unwrap_or(0);
    let data = Path::new(env!("CARGO_MANIFEST_DIR")).join("../shared/data/kitti_pair");
    let scans = [
        read_points(&data.join("000000.bin"))?,
        read_points(&data.join("000001.bin"))?,
    ];

    let mut log = OutputLog::create(out, true, "ros2")?;
    let clouds = log.add_cdr_channel("/velodyne_points", cdr::POINT_CLOUD2)?;
    let reference = log.add_cdr_channel("/ground_truth/pose", cdr::POSE_STAMPED)?;
    let blob = log.add_channel("/camera/raw", "", "", &[], "application/octet-stream")?;
    let mut state = 0x2545_f491_4f6c_dd1du64;
    let mut noise = vec![0u8; 1 << 20];
    let blobs_per_frame = passthrough_mb.div_ceil(frames.max(1));
    let mut blobs_written = 0;
    for k in 0..frames {
        let t = 1_700_000_000_000_000_000u64 + k as u64 * 100_000_000;
        let motion = Isometry3::from_parts(
            Translation3::new(0.2 * k as f64, 0.0, 0.0),
            UnitQuaternion::from_euler_angles(0.0, 0.0, (0.5 * k as f64).to_radians()),
        );
        let pts: Vec<_> = scans[k % 2].iter().map(|p| motion * p).collect();
        let intensity: Vec<f32> = (0..pts.len()).map(|i| (i % 100) as f32 / 100.0).collect();
        let header = Header {
            stamp: Time::from_ns(t as i64).ok_or("stamp")?,
            frame_id: "velodyne".into(),
        };
        log.write(
            clouds,
            t,
            t,
            &cdr::encode_point_cloud2(&header, &pts, Some(&intensity)),
        )?;
        if k % 2 == 0 {
            let world = Header {
                stamp: header.stamp,
                frame_id: "velodyne_first".into(),
            };
            let pose = cdr::encode_pose_stamped(&world, &motion.inverse());
            log.write(reference, t, t, &pose)?;
        }
        for _ in 0..blobs_per_frame {
            if blobs_written == passthrough_mb {
                break;
            }
            for b in noise.chunks_mut(8) {
                // xorshift64: incompressible filler.
                state ^= state << 13;
                state ^= state >> 7;
                state ^= state << 17;
                b.copy_from_slice(&state.to_le_bytes()[..b.len()]);
            }
            log.write(blob, t + 1, t + 1, &noise)?;
            blobs_written += 1;
        }
    }
    log.finish()?;
    eprintln!(
        "wrote {} ({frames} frames, {blobs_written} MB pass-through)",
        out.display()
    );
    Ok(())
}
