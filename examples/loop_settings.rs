//! Loop-closure settings against the reference, for choosing the defaults by measurement: runs
//! `register_log` on a log with the default settings scaled by the factors given, and prints
//! the odometry's and the optimised trajectory's ATE against `/ground_truth/pose`, the loops
//! accepted and the stage's time.
//!
//! ```text
//! cargo run --release --example loop_settings -- LOG [odometry_sigma=1] [loop_sigma=1] [kernel=1] [inliers=30] [fitness=0.5] [per_query=2] [fine_icp=0] [keyframe_distance_factor=1] [redundant_path_voxels=0] [keep_odometry_frames=1] [seed=0]
//! ```
//! Sigma factors multiply [`LoopConfig::for_voxel`]'s deviations (translation and rotation).

use std::path::PathBuf;

use mireg::loops::LoopConfig;
use mireg::odometry::OdometryConfig;
use mireg::register::{RegisterOptions, register_log};

fn main() -> mireg::Result<()> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let input = PathBuf::from(args.first().expect("LOG"));
    let factor = |i: usize, default: f64| -> f64 {
        args.get(i)
            .map_or(default, |s| s.parse().expect("a number"))
    };
    let dir = tempfile::tempdir().map_err(|e| mireg::Error::InvalidInput(e.to_string()))?;
    let output = dir.path().join("out.mcap");
    // The voxel from the first cloud, as `mireg register` without --voxel: run once without
    // loops to learn it.
    let mut opts = RegisterOptions {
        derive_voxel: true,
        loops: false,
        force: true,
        ..RegisterOptions::new(&input, &output, OdometryConfig::default())
    };
    opts.config.pair.seed = factor(11, 0.0) as u64;
    let voxel = register_log(&opts)?.voxel_m;
    let mut c = LoopConfig::for_voxel(voxel);
    let (so, sl) = (factor(1, 1.0), factor(2, 1.0));
    c.odometry_sigma_m *= so;
    c.odometry_sigma_deg *= so;
    c.loop_sigma_m *= sl;
    c.loop_sigma_deg *= sl;
    c.kernel_scale = factor(3, c.kernel_scale);
    c.verify.min_inliers = factor(4, c.verify.min_inliers as f64) as usize;
    c.verify.min_fitness = factor(5, c.verify.min_fitness);
    c.candidates.max_per_query = factor(6, c.candidates.max_per_query as f64) as usize;
    c.fine_icp = factor(7, f64::from(u8::from(c.fine_icp))) != 0.0;
    c.keyframes.keyframe_distance_m *= factor(8, 1.0);
    c.redundant_path_m = factor(9, 0.0) * voxel;
    // The kept keyframes drop the fine stage's points: `fine_icp` needs them read again.
    c.keep_odometry_frames = factor(10, 1.0) != 0.0;
    opts.loops = true;
    opts.loop_config = Some(c);
    let s = register_log(&opts)?;
    let ate = |r: &Option<mireg::register::ReferenceErrors>| {
        r.as_ref().map_or(f64::NAN, |r| r.ate_rmse_m)
    };
    let l = s.loops.expect("loops ran");
    println!(
        "{} odometry_sigma x{so} loop_sigma x{sl} kernel {} inliers {} fitness {} per_query {} fine {} keyframes every {:.3} m: ATE odometry {:.5} m, optimised {:.5} m; {} keyframes, {} candidates, {} accepted, {} redundant, {} down-weighted; loops {:.3} s of {:.3} s",
        input.display(),
        c.kernel_scale,
        c.verify.min_inliers,
        c.verify.min_fitness,
        c.candidates.max_per_query,
        c.fine_icp,
        c.keyframes.keyframe_distance_m,
        ate(&s.reference),
        ate(&s.reference_optimized),
        l.keyframes,
        l.candidates,
        l.accepted,
        l.redundant,
        l.down_weighted,
        l.elapsed_s,
        s.elapsed_s
    );
    Ok(())
}
