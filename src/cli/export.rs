//! `mireg export`: clap arguments → [`crate::evaluate::ExportOptions`], the trajectory read
//! ([`crate::evaluate::read_export`]) and written to stdout, or the job with an output file
//! ([`crate::evaluate::export_to_file`]).

use std::io::Write;
use std::path::PathBuf;

use anyhow::{Context, Result};
use clap::{Args, ValueEnum};

use crate::evaluate::{ExportFormat, ExportOptions, export_to_file, read_export, write_trajectory};

use super::evaluate::ignore_broken_pipe;

/// Output format of `mireg export` ([`ExportFormat`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum ExportFormatArg {
    /// TUM (`evo_ape tum`): stamps in seconds with nine decimals.
    Tum,
    /// KITTI (`evo_ape kitti`): 12 numbers per line, no stamps.
    Kitti,
}

impl From<ExportFormatArg> for ExportFormat {
    fn from(a: ExportFormatArg) -> Self {
        match a {
            ExportFormatArg::Tum => ExportFormat::Tum,
            ExportFormatArg::Kitti => ExportFormat::Kitti,
        }
    }
}

/// Arguments of `mireg export`.
#[derive(Debug, Args)]
pub struct ExportArgs {
    /// MCAP written by `mireg register` (or any log with a PoseStamped topic).
    pub input: PathBuf,
    /// Output format.
    #[arg(long, value_enum)]
    pub format: ExportFormatArg,
    /// Output file (replaced if it exists) [default: stdout].
    #[arg(short, long, value_name = "FILE")]
    pub output: Option<PathBuf>,
    /// PoseStamped topic to export [default: the newest run's loop-closed trajectory,
    /// /mireg/pose_optimized, when present, else its odometry, /mireg/pose; /mireg_N/… for a
    /// log registered N times].
    #[arg(long, value_name = "TOPIC")]
    pub topic: Option<String>,
    /// Export the newest run's odometry (/mireg/pose) even when the log has a loop-closed
    /// trajectory.
    #[arg(long, conflicts_with = "topic")]
    pub odometry: bool,
}

impl ExportArgs {
    /// The flags as the job's options.
    pub fn options(&self) -> ExportOptions {
        ExportOptions {
            input: self.input.clone(),
            format: self.format.into(),
            output: self.output.clone(),
            topic: self.topic.clone(),
            odometry: self.odometry,
        }
    }
}

/// Runs `mireg export`.
pub(super) fn run_export(args: &ExportArgs) -> Result<()> {
    let opts = args.options();
    if let Some(path) = &opts.output {
        export_to_file(&opts, path)?;
        return Ok(());
    }
    let (_, t) = read_export(&opts)?;
    let stdout = std::io::stdout();
    let mut w = std::io::BufWriter::new(stdout.lock());
    ignore_broken_pipe(
        write_trajectory(&t, opts.format, &mut w)
            .map_err(anyhow::Error::from)
            .and_then(|()| w.flush().context("writing stdout")),
    )
}
