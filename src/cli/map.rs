//! `mireg map`: clap arguments → [`crate::map::MapOptions`]; the job ([`crate::map::map_runs`]:
//! the voxel-downsampled world map of `register` outputs written as `.ply`, `.pcd` or `.npy`),
//! its summary printed.

use std::path::PathBuf;

use anyhow::Result;
use clap::{Args, ValueEnum};

use crate::map::{MapOptions, TrajectoryChoice, map_runs};

/// `--trajectory` of `mireg map` ([`TrajectoryChoice`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum TrajectoryArg {
    /// `/mireg/pose`: register's odometry.
    Odometry,
    /// `/mireg/pose_optimized`: the loop-closed trajectory (an error if the log lacks it).
    Optimized,
    /// `/mireg/pose_merged`: the trajectory `mireg merge` put in its group's frame.
    Merged,
    /// `/mireg/pose_merged`, else `/mireg/pose_optimized`, else `/mireg/pose`: the first present.
    Auto,
}

impl From<TrajectoryArg> for TrajectoryChoice {
    fn from(a: TrajectoryArg) -> Self {
        match a {
            TrajectoryArg::Odometry => TrajectoryChoice::Odometry,
            TrajectoryArg::Optimized => TrajectoryChoice::Optimized,
            TrajectoryArg::Merged => TrajectoryChoice::Merged,
            TrajectoryArg::Auto => TrajectoryChoice::Auto,
        }
    }
}

/// Arguments of `mireg map`.
#[derive(Debug, Args)]
pub struct MapArgs {
    /// MCAP written by `mireg register` (it holds the clouds and their poses), or several
    /// outputs of one `mireg merge` (placed by their merged trajectories, in one frame).
    #[arg(required = true)]
    pub inputs: Vec<PathBuf>,
    /// Output map: `.ply` (binary), `.pcd` (binary) or `.npy` (float32, N×3, or N×4 with
    /// intensity), chosen by extension.
    #[arg(short, long, value_name = "FILE")]
    pub output: PathBuf,
    /// Voxel edge of the map [m]: one point (centroid, mean intensity) per occupied voxel
    /// [default: the voxel `register` used, from the output's `mireg` metadata (`voxel_m`)].
    #[arg(long, value_name = "METRES")]
    pub voxel: Option<f64>,
    /// Trajectory placing the clouds (the newest run's topics, `/mireg_N/…` for a log
    /// registered N times).
    #[arg(long, value_enum, default_value = "auto")]
    pub trajectory: TrajectoryArg,
    /// Point cloud topic [default: the one `register` read].
    #[arg(long, value_name = "TOPIC")]
    pub topic: Option<String>,
    /// Replace an existing output.
    #[arg(long)]
    pub force: bool,
    /// Print the summary as JSON.
    #[arg(long)]
    pub json: bool,
}

impl MapArgs {
    /// The flags as the job's options.
    pub fn options(&self) -> MapOptions {
        MapOptions {
            voxel_m: self.voxel,
            trajectory: self.trajectory.into(),
            topic: self.topic.clone(),
        }
    }
}

/// Runs `mireg map`.
pub(super) fn run_map(args: &MapArgs) -> Result<()> {
    let out = &args.output;
    let summary = map_runs(&args.inputs, out, args.force, &args.options())?;
    if args.json {
        println!("{}", serde_json::to_string_pretty(&summary)?);
    } else {
        println!(
            "map of {} clouds ({} without a pose, skipped) on {} -> {}: {} points ({} in), voxel {:.3} m ({}){}",
            summary.clouds_used,
            summary.clouds_without_pose,
            summary.pose_topic,
            out.display(),
            summary.map_points,
            summary.points_in,
            summary.voxel_m,
            summary.voxel_source,
            if summary.intensity {
                ", with intensity"
            } else {
                ""
            }
        );
    }
    Ok(())
}
