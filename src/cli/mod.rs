//! Command-line interface: clap arguments → library calls, one file per subcommand. No
//! algorithm lives here.

use anyhow::Result;
use clap::{Parser, Subcommand};

mod evaluate;
mod export;
mod flags;
mod info;
mod localize;
mod map;
mod merge;
mod pair;
mod process;
mod register;
mod simulate;
mod stitch;
mod sweep;

pub use evaluate::{EVALUATE_CSV_HEADER, EvaluateArgs, TrajectoryFormatArg};
pub use export::{ExportArgs, ExportFormatArg};
pub use flags::{
    DeskewArg, LivoxTagsArg, OutputMessagesArg, RankingArg, RegistrationFlags, SamplerArg,
    VerificationArg,
};
pub use info::InfoArgs;
pub use localize::LocalizeArgs;
pub use map::MapArgs;
pub use merge::MergeArgs;
pub use pair::{GtFormatArg, PairArgs, RegistrationFailed, pair_json};
pub use process::error_text;
pub use register::{DEFAULT_FIXTURE, RegisterArgs, register_options};
pub use simulate::SimulateArgs;
pub use stitch::StitchArgs;
pub use sweep::SweepArgs;

/// mireg: register point clouds in robotics logs with MI-RANSAC.
#[derive(Debug, Parser)]
#[command(name = "mireg", version, about)]
pub struct Cli {
    /// What to do.
    #[command(subcommand)]
    pub command: Option<Command>,
}

/// Subcommands.
#[derive(Debug, Subcommand)]
pub enum Command {
    /// Reproduce the paper's sampling simulation (Zhang & Chen, Fig. 5).
    Simulate(SimulateArgs),
    /// Register one point cloud (SRC) to another (TGT): prints target_from_source.
    Pair(PairArgs),
    /// Register consecutive point clouds of a log (MCAP, ROS 1 bag or ROS 2 bag directory);
    /// write poses and statistics to a new MCAP.
    Register(RegisterArgs),
    /// Compare the estimated trajectory of a `register` output with a reference (ATE, RPE, drift).
    Evaluate(EvaluateArgs),
    /// Write the estimated trajectory of a `register` output as TUM or KITTI text.
    Export(ExportArgs),
    /// List a log's channels and message counts, and the point cloud topic `register` reads.
    Info(InfoArgs),
    /// Join the outputs of overlapping `register --start/--end` segments into one output.
    Stitch(StitchArgs),
    /// The paper's registration experiment (Fig. 6): recall and precision per sampler, μ and
    /// ranking on frame pairs of a log with a reference trajectory.
    Sweep(SweepArgs),
    /// The voxel-downsampled world map of a `register` output, as .ply, .pcd or .npy.
    Map(MapArgs),
    /// Put several `register` outputs of one site (sessions, each in its own frame) into one
    /// frame: links between sessions found and verified prior-free, one robust pose graph.
    Merge(MergeArgs),
    /// Place a log in a prior map (a `register` output), prior-free: each frame localized,
    /// tracking, outside the map, or lost.
    Localize(LocalizeArgs),
}

/// Runs the parsed command line.
pub fn run(cli: Cli) -> Result<()> {
    // Ctrl-C and SIGTERM end a run at once, leaving no partial output behind.
    crate::io::atomic_file::install_signal_handlers();
    match cli.command {
        Some(Command::Simulate(args)) => simulate::run_simulate(&args),
        Some(Command::Pair(args)) => pair::run_pair(&args),
        Some(Command::Register(args)) => register::run_register(&args),
        Some(Command::Evaluate(args)) => evaluate::run_evaluate(&args),
        Some(Command::Export(args)) => export::run_export(&args),
        Some(Command::Info(args)) => info::run_info(&args),
        Some(Command::Stitch(args)) => stitch::run_stitch(&args),
        Some(Command::Sweep(args)) => sweep::run_sweep(&args),
        Some(Command::Map(args)) => map::run_map(&args),
        Some(Command::Merge(args)) => merge::run_merge(&args),
        Some(Command::Localize(args)) => localize::run_localize(&args),
        None => register::run_default(),
    }
}

#[cfg(test)]
mod tests {
    use std::collections::BTreeMap;

    use clap::CommandFactory;

    use super::Cli;

    /// Every option that takes a value, over the subcommands: (subcommand, long name, value name).
    fn options() -> Vec<(String, String, String)> {
        let cli = Cli::command();
        let mut all = Vec::new();
        for sub in cli.get_subcommands() {
            for arg in sub.get_arguments() {
                let (Some(long), Some(names)) = (arg.get_long(), arg.get_value_names()) else {
                    continue;
                };
                // Flags, and choices (their help lists the values).
                if !arg.get_action().takes_values() || !arg.get_possible_values().is_empty() {
                    continue;
                }
                let name = names
                    .iter()
                    .map(|n| n.as_str())
                    .collect::<Vec<_>>()
                    .join(" ");
                all.push((sub.get_name().to_string(), long.to_string(), name));
            }
        }
        all
    }

    /// A flag means one thing across the subcommands: the same value name wherever it appears
    /// (`merge -o` names a folder, the others a file).
    #[test]
    fn a_flag_shared_by_subcommands_names_its_value_alike() {
        let mut seen: BTreeMap<String, Vec<(String, String)>> = BTreeMap::new();
        for (sub, long, name) in options() {
            if (sub.as_str(), long.as_str(), name.as_str()) != ("merge", "output", "DIR") {
                seen.entry(long).or_default().push((sub, name));
            }
        }
        let differ: Vec<_> = seen
            .iter()
            .filter(|(_, uses)| uses.iter().any(|(_, n)| *n != uses[0].1))
            .collect();
        assert!(differ.is_empty(), "{differ:?}");
    }

    /// A value name says what to give (`METRES`, `N`, `FILE`, ...), not clap's default, the
    /// flag's own name in capitals (`--voxel <VOXEL>`), except where that name is the thing given.
    #[test]
    fn value_names_say_what_to_give() {
        const OWN_NAME_IS_THE_ANSWER: [&str; 5] = ["topic", "seed", "mu", "format", "trajectory"];
        let bare: Vec<_> = options()
            .into_iter()
            .filter(|(_, long, name)| {
                *name == long.to_uppercase().replace('-', "_")
                    && !OWN_NAME_IS_THE_ANSWER.contains(&long.as_str())
            })
            .collect();
        assert!(bare.is_empty(), "{bare:?}");
    }
}
