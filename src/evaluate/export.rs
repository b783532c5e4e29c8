//! The `export` job: the estimated trajectory of a `register` output as TUM or KITTI text.
//! [`ExportOptions`] in; [`read_export`] reads the trajectory (the newest run's, as `evaluate`
//! chooses it), [`write_export`] writes it to a file (whole or not at all) or
//! [`write_trajectory`] to a stream; `mireg export` maps its flags onto the options and checks
//! that the output is not the input.

use std::io::Write;
use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};

use super::inputs::registered_log;
use super::job::run_topics;
use crate::io::atomic_file::{PendingFile, check_not_an_input, check_target};
use crate::trajectory::{self, Trajectory};
use crate::{Error, Result};

/// Text format of an exported trajectory ([`ExportOptions::format`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum ExportFormat {
    /// TUM (`evo_ape tum`): `timestamp tx ty tz qx qy qz qw` per line, the stamp in seconds with
    /// nine decimals, metres.
    #[default]
    Tum,
    /// KITTI (`evo_ape kitti`): the 12 numbers of the row-major 3×4 `[R | t]` per line (metres),
    /// no stamps.
    Kitti,
}

/// What to export, from where.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct ExportOptions {
    /// MCAP written by `register` (or any log with a PoseStamped topic, with `topic`). Default
    /// empty.
    pub input: PathBuf,
    /// Output format. Default [`ExportFormat::Tum`].
    pub format: ExportFormat,
    /// Output file, replaced if it exists. Default `None`: the caller's stream (`mireg export`
    /// writes to stdout).
    pub output: Option<PathBuf>,
    /// PoseStamped topic to export. Default `None`: the newest run's loop-closed trajectory
    /// (`/mireg/pose_optimized`) when present, else its odometry (`/mireg/pose`);
    /// `/mireg_N/…` for a log registered N times.
    pub topic: Option<String>,
    /// Export the newest run's odometry (`/mireg/pose`) even when the log has a loop-closed
    /// trajectory. Default `false`.
    pub odometry: bool,
}

/// The trajectory `opts` asks for: `opts.input` checked to be a `register` output (unless a
/// topic is given), the topic chosen, its poses read. Returns the topic and its trajectory; an
/// error if the topic has no messages.
pub fn read_export(opts: &ExportOptions) -> Result<(String, Trajectory)> {
    let channels = registered_log(&opts.input, "export", opts.topic.is_some())?;
    let (topic, _) = run_topics(&channels, opts.topic.as_deref(), opts.odometry);
    let t = crate::io::poses::read_mcap_pose_topic(&opts.input, &topic)?;
    if t.is_empty() {
        return Err(Error::Format {
            path: opts.input.clone(),
            detail: format!("topic {topic} has no messages"),
        });
    }
    Ok((topic, t))
}

/// The export job with an output file: the trajectory `opts` asks for ([`read_export`]) written
/// to `path` ([`write_export`]). Returns the topic and the poses written.
///
/// # Errors
/// [`Error::InvalidInput`] for a `path` that is the input, and [`check_target`]'s errors for
/// one in a missing folder, both before the input is read; then [`read_export`]'s and
/// [`write_export`]'s.
pub fn export_to_file(opts: &ExportOptions, path: &Path) -> Result<(String, usize)> {
    check_not_an_input(path, [opts.input.as_path()], "the input")?;
    check_target(path, true)?;
    let (topic, t) = read_export(opts)?;
    write_export(&t, opts.format, path)?;
    Ok((topic, t.len()))
}

/// Writes `t` in `format` to `out`; a write error names [`trajectory::OUTPUT_STREAM`].
pub fn write_trajectory(t: &Trajectory, format: ExportFormat, out: &mut impl Write) -> Result<()> {
    match format {
        ExportFormat::Tum => trajectory::write_tum(t, out),
        ExportFormat::Kitti => trajectory::write_kitti(t, out),
    }
}

/// Writes `t` in `format` to the file `path` (replaced if it exists): written beside it and
/// moved into place when complete, so that a full disk or an interruption never leaves a
/// truncated file there. Errors name `path`.
pub fn write_export(t: &Trajectory, format: ExportFormat, path: &Path) -> Result<()> {
    let (file, pending) = PendingFile::create(path, true)?;
    let mut w = std::io::BufWriter::new(file);
    write_trajectory(t, format, &mut w).map_err(|e| match e {
        Error::Io { path: p, source } if p == Path::new(trajectory::OUTPUT_STREAM) => Error::Io {
            path: path.to_path_buf(),
            source,
        },
        e => e,
    })?;
    let file = w.into_inner().map_err(|e| Error::Io {
        path: path.to_path_buf(),
        source: e.into_error(),
    })?;
    pending.commit(file)
}
