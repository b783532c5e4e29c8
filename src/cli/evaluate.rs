//! `mireg evaluate`: clap arguments → [`crate::evaluate::evaluate_run`], printed.

use std::io::Write;
use std::path::{Path, PathBuf};

use anyhow::{Result, bail};
use clap::{Args, ValueEnum};

use crate::evaluate::{EvaluateOptions, EvaluateSummary, TrajectoryFormat, evaluate_run};
use crate::trajectory::{self, DEFAULT_STATS_TOPIC, Evaluation};

/// Format of a reference trajectory file (`--gt-format`; [`TrajectoryFormat`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum TrajectoryFormatArg {
    /// TUM: `timestamp tx ty tz qx qy qz qw` per line (seconds, metres); associated by stamp.
    Tum,
    /// KITTI: 12 numbers of the row-major 3×4 `[R | t]` per line; associated by index.
    Kitti,
    /// Redwood/ICL-NUIM `trajectory.log` (`world_from_camera` per record); associated by index.
    Redwood,
}

impl From<TrajectoryFormatArg> for TrajectoryFormat {
    fn from(a: TrajectoryFormatArg) -> Self {
        match a {
            TrajectoryFormatArg::Tum => TrajectoryFormat::Tum,
            TrajectoryFormatArg::Kitti => TrajectoryFormat::Kitti,
            TrajectoryFormatArg::Redwood => TrajectoryFormat::Redwood,
        }
    }
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
    #[arg(long, value_enum, default_value_t = TrajectoryFormatArg::Tum, requires = "gt")]
    pub gt_format: TrajectoryFormatArg,
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

impl EvaluateArgs {
    /// The flags as the job's options.
    pub fn options(&self) -> EvaluateOptions {
        EvaluateOptions {
            input: self.input.clone(),
            gt_topic: self.gt_topic.clone(),
            gt: self.gt.clone(),
            gt_format: self.gt_format.into(),
            est_topic: self.est_topic.clone(),
            odometry: self.odometry,
            max_dt_s: self.max_dt,
        }
    }
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
    if !(args.max_dt.is_finite() && (0.0..=1e9).contains(&args.max_dt)) {
        bail!(
            "--max-dt must be a non-negative number of seconds, got {}",
            args.max_dt
        );
    }
    let summary = evaluate_run(&args.options())?;
    let EvaluateSummary { main, odometry } = &summary;
    let stdout = std::io::stdout();
    let mut out = stdout.lock();
    if args.csv {
        write_csv(&mut out, &main.evaluation)?;
    } else if args.json {
        writeln!(out, "{}", serde_json::to_string_pretty(&summary.json())?)?;
    } else {
        let (ev, estimate, reference) = (&main.evaluation, &main.estimate, &main.reference);
        write_text(&mut out, ev, &args.input, estimate, reference)?;
        if let Some(o) = odometry {
            writeln!(out)?;
            write_text(&mut out, &o.evaluation, &args.input, &o.estimate, reference)?;
        }
    }
    Ok(())
}
