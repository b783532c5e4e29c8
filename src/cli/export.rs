//! `mireg export`: the estimated trajectory of a `register` output as TUM or KITTI text.

use std::io::Write;
use std::path::{Path, PathBuf};

use anyhow::{Context, Result, bail};
use clap::{Args, ValueEnum};

use crate::evaluate::{registered_log, run_topics};
use crate::io::atomic_file::{PendingFile, check_target, same_file};
use crate::trajectory::{self, Trajectory};

use super::evaluate::ignore_broken_pipe;

/// Output format of `mireg export`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum ExportFormat {
    /// TUM (`evo_ape tum`): stamps in seconds with nine decimals.
    Tum,
    /// KITTI (`evo_ape kitti`): 12 numbers per line, no stamps.
    Kitti,
}

/// Arguments of `mireg export`.
#[derive(Debug, Args)]
pub struct ExportArgs {
    /// MCAP written by `mireg register` (or any log with a PoseStamped topic).
    pub input: PathBuf,
    /// Output format.
    #[arg(long, value_enum)]
    pub format: ExportFormat,
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

fn write_trajectory(t: &Trajectory, format: ExportFormat, out: &mut impl Write) -> Result<()> {
    match format {
        ExportFormat::Tum => trajectory::write_tum(t, out)?,
        ExportFormat::Kitti => trajectory::write_kitti(t, out)?,
    }
    Ok(())
}

/// Runs `mireg export`.
pub(super) fn run_export(args: &ExportArgs) -> Result<()> {
    if let Some(path) = &args.output {
        // Before the log is read: an output in a missing folder fails at once.
        check_target(path, true)?;
    }
    let channels = registered_log(&args.input, "export", args.topic.is_some())?;
    let (topic, _) = run_topics(&channels, args.topic.as_deref(), args.odometry);
    let t = crate::io::poses::read_mcap_pose_topic(&args.input, &topic)?;
    if t.is_empty() {
        bail!("{}: topic {topic} has no messages", args.input.display());
    }
    match &args.output {
        Some(path) => {
            if same_file(&args.input, path) {
                bail!(
                    "output {} is the input; mireg never writes over its input",
                    path.display()
                );
            }
            // Written beside the target and moved into place when complete: a full disk or an
            // interruption never leaves a truncated file there.
            let (file, pending) = PendingFile::create(path, true)?;
            let mut w = std::io::BufWriter::new(file);
            let named = |e: crate::Error| match e {
                crate::Error::Io { path: p, source }
                    if p == Path::new(trajectory::OUTPUT_STREAM) =>
                {
                    crate::Error::Io {
                        path: path.clone(),
                        source,
                    }
                }
                e => e,
            };
            write_trajectory(&t, args.format, &mut w).map_err(|e| match e.downcast() {
                Ok(e) => anyhow::Error::from(named(e)),
                Err(e) => e,
            })?;
            let file = w.into_inner().map_err(|e| crate::Error::Io {
                path: path.clone(),
                source: e.into_error(),
            })?;
            pending.commit(file)?;
        }
        None => {
            let stdout = std::io::stdout();
            let mut w = std::io::BufWriter::new(stdout.lock());
            ignore_broken_pipe(
                write_trajectory(&t, args.format, &mut w)
                    .and_then(|()| w.flush().context("writing stdout")),
            )?;
        }
    }
    Ok(())
}
