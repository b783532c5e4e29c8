//! The `evaluate` job: a `register` output's estimated trajectory against a reference (a pose
//! topic of the same log or a trajectory file), with the run's frame flags. [`EvaluateOptions`]
//! in, [`LogEvaluation`] (or [`EvaluateSummary`], the odometry beside a loop-closed trajectory)
//! out; `mireg evaluate` maps its flags onto the one and prints the other.

use std::path::PathBuf;

use serde::{Deserialize, Serialize};

use super::inputs::registered_log;
use crate::io::mcap::log::ChannelInfo;
use crate::trajectory::{self, DEFAULT_GROUND_TRUTH_TOPIC, Evaluation, Trajectory};
use crate::{Error, Result};

/// Format of a reference trajectory file ([`EvaluateOptions::gt_format`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum TrajectoryFormat {
    /// TUM: `timestamp tx ty tz qx qy qz qw` per line (seconds, metres); associated by stamp.
    #[default]
    Tum,
    /// KITTI: 12 numbers of the row-major 3×4 `[R | t]` per line; associated by index.
    Kitti,
    /// Redwood/ICL-NUIM `trajectory.log` (`world_from_camera` per record); associated by index.
    Redwood,
}

impl TrajectoryFormat {
    /// Its name: `tum`, `kitti` or `redwood`.
    pub fn name(self) -> &'static str {
        match self {
            TrajectoryFormat::Tum => "tum",
            TrajectoryFormat::Kitti => "kitti",
            TrajectoryFormat::Redwood => "redwood",
        }
    }
}

/// What to evaluate against what.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct EvaluateOptions {
    /// MCAP written by `register` (the estimate on a pose topic, the flags on its stats topic).
    /// Default empty.
    pub input: PathBuf,
    /// Reference pose topic in `input`. Default `None`: [`DEFAULT_GROUND_TRUTH_TOPIC`], when the
    /// log has it (ignored when `gt` is set).
    pub gt_topic: Option<String>,
    /// Reference trajectory file instead of a topic. Default `None`.
    pub gt: Option<PathBuf>,
    /// Format of `gt`. Default [`TrajectoryFormat::Tum`].
    pub gt_format: TrajectoryFormat,
    /// Estimated pose topic in `input`. Default `None`: the newest run's loop-closed trajectory
    /// (`/mireg/pose_optimized`) when present, else its odometry (`/mireg/pose`).
    pub est_topic: Option<String>,
    /// Evaluate the newest run's odometry even when the log has a loop-closed trajectory.
    /// Default `false`.
    pub odometry: bool,
    /// Largest stamp difference for pairing an estimate with a reference pose \[s\]. Default
    /// 0.01.
    pub max_dt_s: f64,
}

impl Default for EvaluateOptions {
    fn default() -> Self {
        Self {
            input: PathBuf::new(),
            gt_topic: None,
            gt: None,
            gt_format: TrajectoryFormat::Tum,
            est_topic: None,
            odometry: false,
            max_dt_s: 0.01,
        }
    }
}

/// One estimated trajectory evaluated.
#[derive(Debug, Clone, PartialEq)]
pub struct LogEvaluation {
    /// The errors.
    pub evaluation: Evaluation,
    /// The estimate's topic.
    pub estimate: String,
    /// Where the reference came from: its topic, or the file and its format (`gt.txt (tum)`).
    pub reference: String,
}

/// What `evaluate` reports: the chosen estimate, and, when that is the loop-closed trajectory
/// chosen by default, the odometry's evaluation beside it.
#[derive(Debug, Clone, PartialEq)]
pub struct EvaluateSummary {
    /// The estimate evaluated.
    pub main: LogEvaluation,
    /// The same run's odometry, when `main` is its loop-closed trajectory chosen by default.
    pub odometry: Option<LogEvaluation>,
}

/// `seconds` as nanoseconds, when a valid stamp tolerance.
fn max_dt_ns(seconds: f64) -> Result<i64> {
    if !(seconds.is_finite() && (0.0..=1e9).contains(&seconds)) {
        return Err(Error::InvalidInput(format!(
            "max_dt_s must be a non-negative number of seconds, got {seconds}"
        )));
    }
    Ok((seconds * 1e9).round() as i64)
}

/// The estimate and statistics topics of a log: `est_topic` when given (its run's statistics
/// when it is a mireg topic), else the newest mireg run's: its loop-closed trajectory
/// (`…/pose_optimized`) when the log has one and `odometry` is false, else its odometry
/// (`…/pose`).
pub fn run_topics(
    channels: &[ChannelInfo],
    est_topic: Option<&str>,
    odometry: bool,
) -> (String, String) {
    let ns = match est_topic {
        Some(t) => t
            .strip_suffix("/pose")
            .or_else(|| t.strip_suffix("/pose_optimized"))
            .filter(|ns| ns.starts_with(trajectory::MIREG_NAMESPACE))
            .map(str::to_string),
        None => trajectory::newest_mireg_namespace(channels),
    };
    let ns = ns.unwrap_or_else(|| trajectory::MIREG_NAMESPACE.to_string());
    let optimized = format!("{ns}/pose_optimized");
    let est = match est_topic {
        Some(t) => t.to_string(),
        None if !odometry && trajectory::has_optimized_poses(channels, &optimized) => optimized,
        None => format!("{ns}/pose"),
    };
    (est, format!("{ns}/stats"))
}

/// An error about `path`'s content.
fn format_err(path: &std::path::Path, detail: String) -> Error {
    Error::Format {
        path: path.to_path_buf(),
        detail,
    }
}

/// The reference topic: `gt_topic`, else [`DEFAULT_GROUND_TRUTH_TOPIC`] when the log has it.
fn reference_topic(opts: &EvaluateOptions, channels: &[ChannelInfo]) -> Result<String> {
    if let Some(t) = &opts.gt_topic {
        return Ok(t.clone());
    }
    if channels
        .iter()
        .any(|c| c.topic == DEFAULT_GROUND_TRUTH_TOPIC)
    {
        return Ok(DEFAULT_GROUND_TRUTH_TOPIC.to_string());
    }
    let topics = crate::io::poses::pose_stamped_topics(channels);
    Err(format_err(
        &opts.input,
        format!(
            "no reference topic {DEFAULT_GROUND_TRUTH_TOPIC}; choose one with --gt-topic (PoseStamped topics: {}) or pass a file with --gt",
            if topics.is_empty() {
                "none".to_string()
            } else {
                topics.join(", ")
            }
        ),
    ))
}

/// The reference file `gt`, read as `opts.gt_format`.
fn read_reference_file(opts: &EvaluateOptions, path: &std::path::Path) -> Result<Trajectory> {
    let reference = match opts.gt_format {
        TrajectoryFormat::Tum => crate::io::poses::read_tum(path)?,
        TrajectoryFormat::Kitti => crate::io::poses::read_kitti(path)?,
        TrajectoryFormat::Redwood => crate::io::poses::read_redwood(path)?,
    };
    if reference.is_empty() {
        return Err(format_err(path, "no poses".into()));
    }
    Ok(reference)
}

/// Loads estimate, reference and flags and evaluates the one estimate `opts` chooses.
///
/// # Errors
/// An input that is not a `register` output (saying what to run first), a reference that is
/// missing or empty, an empty estimate, or fewer than two poses that associate.
pub fn evaluate_log(opts: &EvaluateOptions) -> Result<LogEvaluation> {
    let input = &opts.input;
    let max_dt = max_dt_ns(opts.max_dt_s)?;
    // A reference file is read first: a wrong one is named before the log is looked at.
    let gt_file = match &opts.gt {
        Some(path) => Some(read_reference_file(opts, path)?),
        None => None,
    };
    let channels = registered_log(input, "evaluate", opts.est_topic.is_some())?;
    let (est_topic, stats_topic) = run_topics(&channels, opts.est_topic.as_deref(), opts.odometry);
    let (estimate, reference, name) = match (gt_file, &opts.gt) {
        (Some(reference), Some(path)) => {
            let estimate = crate::io::poses::read_mcap_pose_topic(input, &est_topic)?;
            let name = format!("{} ({})", path.display(), opts.gt_format.name());
            (estimate, reference, name)
        }
        _ => {
            let topic = reference_topic(opts, &channels)?;
            let mut v = crate::io::poses::read_mcap_pose_topics(input, &[&est_topic, &topic])?;
            let reference = v.pop().unwrap_or_default();
            let estimate = v.pop().unwrap_or_default();
            if reference.is_empty() {
                return Err(format_err(input, format!("topic {topic} has no messages")));
            }
            (estimate, reference, topic)
        }
    };
    if estimate.is_empty() {
        return Err(format_err(
            input,
            format!("topic {est_topic} has no messages"),
        ));
    }
    let flags = crate::io::poses::read_frame_flags(input, &stats_topic)?;
    let evaluation = trajectory::evaluate(&estimate, &reference, flags.as_deref(), max_dt)
        .map_err(|e| {
            let detail = match e {
                Error::InvalidInput(d) => d,
                e => e.to_string(),
            };
            Error::InvalidInput(format!(
                "evaluating {} against {name}: {detail}",
                input.display()
            ))
        })?;
    Ok(LogEvaluation {
        evaluation,
        estimate: est_topic,
        reference: name,
    })
}

/// [`evaluate_log`], and when the estimate is the loop-closed trajectory chosen by default
/// (no `est_topic`), the same run's odometry beside it.
///
/// # Errors
/// As [`evaluate_log`].
pub fn evaluate_run(opts: &EvaluateOptions) -> Result<EvaluateSummary> {
    let main = evaluate_log(opts)?;
    let odometry = if opts.est_topic.is_none() && main.estimate.ends_with("/pose_optimized") {
        let odometry_opts = EvaluateOptions {
            est_topic: None,
            odometry: true,
            ..opts.clone()
        };
        Some(evaluate_log(&odometry_opts)?)
    } else {
        None
    };
    Ok(EvaluateSummary { main, odometry })
}

/// The JSON object of one evaluation (`mireg evaluate --json`): `frames`, `failed_frames`
/// (null without statistics), `ate_rmse_m`, `rpe_trans_mean_m`, `rpe_rot_mean_deg`,
/// `rpe_trans_rmse_m`, `path_length_m`, association details and, when a drift segment fits,
/// `drift_trans_pct`, `drift_rot_deg_per_m`, `drift_segments` and `drift` (per length).
pub fn evaluation_json(ev: &Evaluation, estimate: &str, reference: &str) -> serde_json::Value {
    let mut v = serde_json::json!({
        "estimate": estimate,
        "reference": reference,
        "association": ev.association,
        "estimate_poses": ev.estimate_poses,
        "reference_poses": ev.reference_poses,
        "max_pair_dt_ns": ev.max_pair_dt_ns,
        "frames": ev.rows.len(),
        "failed_frames": ev.failed_frames,
        "ate_rmse_m": ev.ate_rmse_m,
        "rpe_trans_mean_m": ev.rpe_trans_mean_m,
        "rpe_trans_rmse_m": ev.rpe_trans_rmse_m,
        "rpe_rot_mean_deg": ev.rpe_rot_mean_deg,
        "path_length_m": ev.path_length_m,
    });
    if let Some(d) = &ev.drift {
        v["drift_trans_pct"] = d.trans_drift_pct.into();
        v["drift_rot_deg_per_m"] = d.rot_drift_deg_per_m.into();
        v["drift_segments"] = d.segments.into();
        v["drift"] = serde_json::json!(d.per_length);
    }
    v
}

impl EvaluateSummary {
    /// The JSON object of `mireg evaluate --json`: [`evaluation_json`] of the main estimate,
    /// with the odometry's under `odometry` when there is one.
    pub fn json(&self) -> serde_json::Value {
        let m = &self.main;
        let mut v = evaluation_json(&m.evaluation, &m.estimate, &m.reference);
        if let Some(o) = &self.odometry {
            v["odometry"] = evaluation_json(&o.evaluation, &o.estimate, &o.reference);
        }
        v
    }
}
