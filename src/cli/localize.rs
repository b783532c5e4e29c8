//! `mireg localize`: a log placed in a prior map ([`crate::merge::localize`]).

use anyhow::Result;
use clap::Args;
use std::path::PathBuf;

use crate::merge::{LocalizeOptions, LogLoops, MergeConfig};

/// Arguments of `mireg localize`.
#[derive(Debug, Args)]
pub struct LocalizeArgs {
    /// The log to localise (MCAP, ROS 1 bag or ROS 2 bag directory).
    pub log: PathBuf,
    /// The prior map: an output of `mireg register` or `mireg merge` (its clouds and best
    /// trajectory), or a map file as `mireg map` writes it (`.ply`, `.pcd`, `.npy`: cut into
    /// tiles as wide as the log's scans reach; the output's transforms then have the parent `map`).
    #[arg(long, value_name = "RUN|MAP")]
    pub map: PathBuf,
    /// Output MCAP [default: LOG's name with `.localized.mcap`, beside it].
    #[arg(short, long, value_name = "FILE")]
    pub output: Option<PathBuf>,
    /// Point cloud topic of the log [default: as `register` chooses].
    #[arg(long)]
    pub topic: Option<String>,
    /// Agreeing links to the map, at distinct keyframes, needed to localise.
    #[arg(long, value_name = "N", default_value_t = crate::merge::DEFAULT_MIN_LINKS)]
    pub min_links: usize,
    /// Seed of the registrations' randomness.
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Memory for the prior's and the logs' prepared keyframes (a map file's tiles too), MiB, by
    /// their size on the heap: those beyond it are prepared again for the candidates that need
    /// them. A candidate verifies the same either way; 0 keeps none.
    #[arg(long, value_name = "MIB", default_value_t = crate::loops::closure::DEFAULT_LOOP_MEMORY_BYTES >> 20)]
    pub keyframe_memory: usize,
    /// When the log's own loops are closed: `auto` only where a frame ends outside the map (the
    /// log is then registered a second time, with loop closure: inside the map its links to the
    /// map close its loops), `always` in its one registration.
    #[arg(long, value_enum, value_name = "WHEN", default_value_t = LogLoopsArg::Auto)]
    pub log_loops: LogLoopsArg,
    /// How far from the map's nearest keyframe (or tile) a frame placed by its own trajectory
    /// still counts as `tracking`, metres; farther it is `outside_map` (and with `--log-loops
    /// auto` the log's own loops are closed) [default: 80 voxels, as loop closure's largest
    /// place radius].
    #[arg(long, value_name = "METRES")]
    pub map_reach: Option<f64>,
    /// Replace an existing output.
    #[arg(long)]
    pub force: bool,
    /// Print the summary as JSON.
    #[arg(long)]
    pub json: bool,
}

/// `--log-loops`: see [`LogLoops`].
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum LogLoopsArg {
    /// Only where a frame ends outside the map.
    Auto,
    /// Always.
    Always,
}

/// `mireg localize`.
pub(super) fn run_localize(args: &LocalizeArgs) -> Result<()> {
    let output = args.output.clone().unwrap_or_else(|| {
        let stem = args
            .log
            .file_stem()
            .map_or_else(|| "log".into(), |s| s.to_string_lossy().into_owned());
        args.log.with_file_name(format!("{stem}.localized.mcap"))
    });
    let opts = LocalizeOptions {
        log: args.log.clone(),
        prior: args.map.clone(),
        output,
        force: args.force,
        seed: args.seed,
        config: MergeConfig {
            min_links: args.min_links,
            keyframe_memory_bytes: args.keyframe_memory.saturating_mul(1 << 20),
            ..MergeConfig::default()
        },
        topic: args.topic.clone(),
        log_loops: match args.log_loops {
            LogLoopsArg::Auto => LogLoops::Auto,
            LogLoopsArg::Always => LogLoops::Always,
        },
        map_reach_m: args.map_reach,
        command_line: super::process::command_line(),
    };
    let s = crate::merge::localize(&opts)?;
    if args.json {
        println!("{}", serde_json::to_string_pretty(&s)?);
        return Ok(());
    }
    println!(
        "localized {} of {} frames in {} ({} tracking, {} outside the map, {} lost), {} links of {} \
         candidates, {:.2} s (register {:.2}, prepare {:.2}, link {:.2}, write {:.2}) -> {}",
        s.localized,
        s.frames,
        s.map_frame,
        s.tracking,
        s.outside_map,
        s.lost,
        s.links,
        s.candidates,
        s.elapsed_s,
        s.timings_s.register,
        s.timings_s.prepare,
        s.timings_s.link,
        s.timings_s.write,
        s.output.display()
    );
    println!("  {}", s.reason);
    Ok(())
}
