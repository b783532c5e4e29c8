//! `mireg evaluate`: clap arguments → [`crate::trajectory`] calls.

use std::io::Write;
use std::path::{Path, PathBuf};

use anyhow::{Context, Result, bail};
use clap::{Args, ValueEnum};

use super::inputs::registered_log;
use crate::io::mcap::log::list_channels;
use crate::trajectory::{self, DEFAULT_GROUND_TRUTH_TOPIC, DEFAULT_STATS_TOPIC, Evaluation};

/// Format of a reference trajectory file (`--gt-format`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum TrajectoryFormat {
    /// TUM: `timestamp tx ty tz qx qy qz qw` per line (seconds, metres); associated by stamp.
    Tum,
    /// KITTI: 12 numbers of the row-major 3×4 `[R | t]` per line; associated by index.
    Kitti,
    /// Redwood/ICL-NUIM `trajectory.log` (`world_from_camera` per record); associated by index.
    Redwood,
}

/// Arguments of `mireg evaluate`.
#[derive(Debug, Clone, Args)]
pub struct EvaluateArgs {
    /// MCAP written by `mireg register` (estimate on --est-topic, flags on /mireg/stats).
    pub input: PathBuf,
    /// Reference PoseStamped topic in INPUT [default: /ground_truth/pose when present].
    #[arg(long, value_name = "TOPIC", conflicts_with = "gt")]
    pub gt_topic: Option<String>,
    /// Reference trajectory file instead of a topic.
    #[arg(long, value_name = "FILE")]
    pub gt: Option<PathBuf>,
    /// Format of --gt.
    #[arg(long, value_enum, default_value_t = TrajectoryFormat::Tum, requires = "gt")]
    pub gt_format: TrajectoryFormat,
    /// Estimated PoseStamped topic in INPUT [default: the newest run's loop-closed trajectory,
    /// /mireg/pose_optimized, when present (the odometry's, /mireg/pose, is then evaluated too),
    /// else its odometry, /mireg/pose; /mireg_N/… for a log registered N times].
    #[arg(long, value_name = "TOPIC")]
    pub est_topic: Option<String>,
    /// Evaluate the newest run's odometry (/mireg/pose) even when the log has a loop-closed
    /// trajectory.
    #[arg(long, conflicts_with = "est_topic")]
    pub odometry: bool,
    /// Largest stamp difference for pairing an estimate with a reference pose, in seconds.
    #[arg(long, value_name = "SECONDS", default_value_t = 0.01)]
    pub max_dt: f64,
    /// Print one CSV row per associated frame
    /// (frame,stamp_ns,success,rpe_trans_m,rpe_rot_deg,ate_err_m).
    #[arg(long, conflicts_with = "json")]
    pub csv: bool,
    /// Print a JSON summary.
    #[arg(long)]
    pub json: bool,
}

/// CSV header of `mireg evaluate --csv`.
pub const EVALUATE_CSV_HEADER: &str = "frame,stamp_ns,success,rpe_trans_m,rpe_rot_deg,ate_err_m";

fn max_dt_ns(seconds: f64) -> Result<i64> {
    if !(seconds.is_finite() && (0.0..=1e9).contains(&seconds)) {
        bail!("--max-dt must be a non-negative number of seconds, got {seconds}");
    }
    Ok((seconds * 1e9).round() as i64)
}

/// Where the reference came from, for messages and JSON.
fn reference_name(args: &EvaluateArgs, topic: Option<&str>) -> String {
    match (&args.gt, topic) {
        (Some(p), _) => {
            let format = args
                .gt_format
                .to_possible_value()
                .map(|v| v.get_name().to_string())
                .unwrap_or_default();
            format!("{} ({format})", p.display())
        }
        (None, Some(t)) => t.to_string(),
        (None, None) => String::new(),
    }
}

/// The estimate and statistics topics of a log: `est_topic` when given (its run's statistics
/// when it is a mireg topic), else the newest mireg run's: its loop-closed trajectory
/// (`…/pose_optimized`) when the log has one and `odometry` is false, else its odometry
/// (`…/pose`).
pub(super) fn run_topics(
    channels: &[crate::io::mcap::log::ChannelInfo],
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

/// Loads estimate, reference and flags as `mireg evaluate` does; returns the evaluation and
/// the reference's name.
pub fn evaluate_log(args: &EvaluateArgs) -> Result<(Evaluation, String)> {
    let input = &args.input;
    let max_dt = max_dt_ns(args.max_dt)?;
    // A --gt file is read first: a wrong one is named before the log is looked at.
    let gt_file = match &args.gt {
        Some(path) => {
            let reference = match args.gt_format {
                TrajectoryFormat::Tum => crate::io::poses::read_tum(path)?,
                TrajectoryFormat::Kitti => crate::io::poses::read_kitti(path)?,
                TrajectoryFormat::Redwood => crate::io::poses::read_redwood(path)?,
            };
            if reference.is_empty() {
                bail!("{}: no poses", path.display());
            }
            Some(reference)
        }
        None => None,
    };
    let channels = registered_log(input, "evaluate", args.est_topic.is_some())?;
    let (est_topic, stats_topic) = run_topics(&channels, args.est_topic.as_deref(), args.odometry);
    let (estimate, reference, name) = match gt_file {
        Some(reference) => {
            let estimate = crate::io::poses::read_mcap_pose_topic(input, &est_topic)?;
            (estimate, reference, reference_name(args, None))
        }
        None => {
            let topic = match &args.gt_topic {
                Some(t) => t.clone(),
                None => {
                    if !channels
                        .iter()
                        .any(|c| c.topic == DEFAULT_GROUND_TRUTH_TOPIC)
                    {
                        let topics = crate::io::poses::pose_stamped_topics(&channels);
                        bail!(
                            "{}: no reference topic {DEFAULT_GROUND_TRUTH_TOPIC}; choose one with --gt-topic (PoseStamped topics: {}) or pass a file with --gt",
                            input.display(),
                            if topics.is_empty() {
                                "none".to_string()
                            } else {
                                topics.join(", ")
                            }
                        );
                    }
                    DEFAULT_GROUND_TRUTH_TOPIC.to_string()
                }
            };
            let mut v = crate::io::poses::read_mcap_pose_topics(input, &[&est_topic, &topic])?;
            let reference = v.pop().unwrap_or_default();
            let estimate = v.pop().unwrap_or_default();
            if reference.is_empty() {
                bail!("{}: topic {topic} has no messages", input.display());
            }
            (estimate, reference, reference_name(args, Some(&topic)))
        }
    };
    if estimate.is_empty() {
        bail!("{}: topic {} has no messages", input.display(), est_topic);
    }
    let flags = crate::io::poses::read_frame_flags(input, &stats_topic)?;
    let ev = trajectory::evaluate(&estimate, &reference, flags.as_deref(), max_dt)
        .with_context(|| format!("evaluating {} against {name}", input.display()))?;
    Ok((ev, name))
}

/// The `--json` object of `mireg evaluate`: `frames`, `failed_frames` (null without
/// statistics), `ate_rmse_m`, `rpe_trans_mean_m`, `rpe_rot_mean_deg`, `rpe_trans_rmse_m`,
/// `path_length_m`, association details and, when a drift segment fits, `drift_trans_pct`,
/// `drift_rot_deg_per_m`, `drift_segments` and `drift` (per length).
pub fn evaluation_json(
    ev: &Evaluation,
    estimate: &str,
    reference: &str,
) -> Result<serde_json::Value> {
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
        v["drift"] = serde_json::to_value(&d.per_length)?;
    }
    Ok(v)
}

fn opt(v: Option<f64>) -> String {
    v.map_or(String::new(), |x| format!("{x}"))
}

fn write_csv(out: &mut impl Write, ev: &Evaluation) -> std::io::Result<()> {
    writeln!(out, "{EVALUATE_CSV_HEADER}")?;
    for r in &ev.rows {
        writeln!(
            out,
            "{},{},{},{},{},{}",
            r.frame,
            r.stamp_ns.map_or(String::new(), |s| s.to_string()),
            r.success.map_or(String::new(), |s| s.to_string()),
            opt(r.rpe_trans_m),
            opt(r.rpe_rot_deg),
            r.ate_err_m
        )?;
    }
    Ok(())
}

fn write_text(
    out: &mut impl Write,
    ev: &Evaluation,
    input: &Path,
    estimate: &str,
    reference: &str,
) -> std::io::Result<()> {
    writeln!(
        out,
        "{}: {estimate} vs {reference}: {} frames associated by {} ({} estimate / {} reference poses, max dt {:.3} ms)",
        input.display(),
        ev.rows.len(),
        match ev.association {
            trajectory::AssociationMethod::Stamp => "stamp",
            trajectory::AssociationMethod::Index => "index",
        },
        ev.estimate_poses,
        ev.reference_poses,
        ev.max_pair_dt_ns as f64 * 1e-6
    )?;
    match ev.failed_frames {
        Some(f) => writeln!(
            out,
            "failed frames      {f} ({:.1} %)",
            100.0 * f as f64 / ev.rows.len().max(1) as f64
        )?,
        None => writeln!(out, "failed frames      unknown (no {DEFAULT_STATS_TOPIC})")?,
    }
    writeln!(
        out,
        "ATE RMSE           {:.4} m (after SE(3) alignment)",
        ev.ate_rmse_m
    )?;
    writeln!(
        out,
        "RPE per frame      {:.4} m mean ({:.4} m RMSE), {:.3} deg mean",
        ev.rpe_trans_mean_m, ev.rpe_trans_rmse_m, ev.rpe_rot_mean_deg
    )?;
    writeln!(out, "path length        {:.3} m", ev.path_length_m)?;
    match &ev.drift {
        Some(d) => {
            writeln!(
                out,
                "drift              {:.3} %, {:.4} deg/m over {} segments",
                d.trans_drift_pct, d.rot_drift_deg_per_m, d.segments
            )?;
            for s in &d.per_length {
                writeln!(
                    out,
                    "  {:>9.3} m       {:.3} %, {:.4} deg/m ({} segments)",
                    s.length_m, s.trans_drift_pct, s.rot_drift_deg_per_m, s.segments
                )?;
            }
        }
        None => writeln!(out, "drift              - (path too short for any segment)")?,
    }
    Ok(())
}

/// A closed stdout (`mireg export … | head`) ends the output quietly, like other Unix tools.
pub(super) fn ignore_broken_pipe(r: Result<()>) -> Result<()> {
    match r {
        Err(e)
            if e.chain().any(|c| {
                c.downcast_ref::<std::io::Error>()
                    .is_some_and(|io| io.kind() == std::io::ErrorKind::BrokenPipe)
            }) =>
        {
            Ok(())
        }
        r => r,
    }
}

/// Runs `mireg evaluate`.
pub(super) fn run_evaluate(args: &EvaluateArgs) -> Result<()> {
    ignore_broken_pipe(evaluate_to_stdout(args))
}

fn evaluate_to_stdout(args: &EvaluateArgs) -> Result<()> {
    let (ev, reference) = evaluate_log(args)?;
    let channels = list_channels(&args.input)?;
    let (estimate, _) = run_topics(&channels, args.est_topic.as_deref(), args.odometry);
    // The loop-closed trajectory chosen by default: the odometry's errors beside it.
    let odometry = if args.est_topic.is_none() && estimate.ends_with("/pose_optimized") {
        let odometry_args = EvaluateArgs {
            est_topic: None,
            odometry: true,
            csv: false,
            json: false,
            ..args.clone()
        };
        let topic = run_topics(&channels, None, true).0;
        Some((evaluate_log(&odometry_args)?.0, topic))
    } else {
        None
    };
    let stdout = std::io::stdout();
    let mut out = stdout.lock();
    if args.csv {
        write_csv(&mut out, &ev)?;
    } else if args.json {
        let mut v = evaluation_json(&ev, &estimate, &reference)?;
        if let Some((odo, topic)) = &odometry {
            v["odometry"] = evaluation_json(odo, topic, &reference)?;
        }
        writeln!(out, "{}", serde_json::to_string_pretty(&v)?)?;
    } else if let Some((odo, topic)) = &odometry {
        write_text(&mut out, &ev, &args.input, &estimate, &reference)?;
        writeln!(out)?;
        write_text(&mut out, odo, &args.input, topic, &reference)?;
    } else {
        write_text(&mut out, &ev, &args.input, &estimate, &reference)?;
    }
    Ok(())
}
