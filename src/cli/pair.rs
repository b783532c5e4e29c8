//! `mireg pair`: clap arguments → [`crate::pair::PairOptions`], the job
//! ([`crate::pair::pair_clouds`]), the pose printed (text or JSON).

use std::io::Write;
use std::path::PathBuf;

use anyhow::{Result, bail};
use clap::{Args, ValueEnum};
use nalgebra::Isometry3;

use super::flags::RegistrationFlags;
use crate::pair::{GroundTruth, GtFormat, PairOptions, PairOutcome, pair_clouds};
use crate::pipeline::PairResult;

/// Ground-truth file formats for `--gt` ([`GtFormat`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum GtFormatArg {
    /// 16 numbers: the 4×4 target_from_source, row-major.
    Matrix,
    /// 3DMatch `gt.log`: the record `TARGET SOURCE n` (needs --gt-pair).
    GtLog,
    /// Redwood/ICL-NUIM `trajectory.log` of world_from_camera per frame (needs --gt-pair).
    Trajectory,
    /// Stanford `bun.conf`: scans looked up by the SRC and TGT file names.
    Bunny,
}

impl From<GtFormatArg> for GtFormat {
    fn from(a: GtFormatArg) -> Self {
        match a {
            GtFormatArg::Matrix => GtFormat::Matrix,
            GtFormatArg::GtLog => GtFormat::GtLog,
            GtFormatArg::Trajectory => GtFormat::Trajectory,
            GtFormatArg::Bunny => GtFormat::Bunny,
        }
    }
}

/// Arguments of `mireg pair`.
#[derive(Debug, Args)]
pub struct PairArgs {
    /// Source cloud (.ply, .pcd, .npy, KITTI .bin).
    pub source: PathBuf,
    /// Target cloud; the result maps source points into its frame.
    pub target: PathBuf,
    /// Registration settings.
    #[command(flatten)]
    pub flags: RegistrationFlags,
    /// Ground truth to compare against (adds rotation/translation errors).
    #[arg(long, value_name = "FILE")]
    pub gt: Option<PathBuf>,
    /// Format of --gt.
    #[arg(long, value_enum, default_value_t = GtFormatArg::Matrix)]
    pub gt_format: GtFormatArg,
    /// For gt-log / trajectory: the TARGET,SOURCE record or frame indices.
    #[arg(long, value_parser = parse_pair, value_name = "TARGET,SOURCE")]
    pub gt_pair: Option<(usize, usize)>,
    /// Print one JSON object instead of text.
    #[arg(long)]
    pub json: bool,
}

fn parse_pair(s: &str) -> std::result::Result<(usize, usize), String> {
    let (a, b) = s
        .split_once(',')
        .ok_or_else(|| format!("expected TARGET,SOURCE, got {s:?}"))?;
    let p = |x: &str| x.trim().parse::<usize>().map_err(|e| format!("{x:?}: {e}"));
    Ok((p(a)?, p(b)?))
}

impl PairArgs {
    /// The flags as the job's options: the registration settings resolved and checked, the
    /// ground truth if given. An error for a `--gt-format` that needs `--gt-pair` without it.
    pub fn options(&self) -> Result<PairOptions> {
        let config = self.flags.config()?;
        let gt = self.gt.as_ref().map(|path| GroundTruth {
            path: path.clone(),
            format: self.gt_format.into(),
            pair: self.gt_pair,
        });
        if let Some(gt) = &gt
            && gt.format.needs_pair()
            && gt.pair.is_none()
        {
            bail!(
                "--gt-format {:?} needs --gt-pair TARGET,SOURCE",
                self.gt_format
            );
        }
        Ok(PairOptions {
            source: self.source.clone(),
            target: self.target.clone(),
            config,
            gt,
        })
    }
}

pub(super) fn run_pair(args: &PairArgs) -> Result<()> {
    crate::heap::keep_freed_memory();
    let PairOutcome {
        result,
        errors,
        num_dropped_far: far,
    } = pair_clouds(&args.options()?)?;
    let stdout = std::io::stdout();
    let mut out = stdout.lock();
    if args.json {
        let mut v = pair_json(&result, errors);
        v["num_dropped_far"] = serde_json::json!(far);
        writeln!(out, "{v}")?;
    } else {
        write_pair_text(&mut out, &result, errors)?;
        if far != [0, 0] {
            writeln!(
                out,
                "far points dropped {} / {} (a coordinate of {} m or more)",
                far[0],
                far[1],
                crate::io::codec::MAX_COORDINATE_M
            )?;
        }
    }
    match result.failure {
        None => Ok(()),
        Some(reason) => Err(RegistrationFailed(reason.as_str().to_string()).into()),
    }
}

/// `mireg pair` ran but its registration failed the checks (the result was still printed):
/// exit code 1, where errors exit 2.
#[derive(Debug, thiserror::Error)]
#[error("registration failed: {0}")]
pub struct RegistrationFailed(pub String);

fn matrix_rows(m: &Isometry3<f64>) -> Vec<Vec<f64>> {
    let h = m.to_homogeneous();
    (0..4)
        .map(|r| (0..4).map(|c| h[(r, c)]).collect())
        .collect()
}

/// The `--json` object of `mireg pair`.
pub fn pair_json(r: &PairResult, errors: Option<(f64, f64)>) -> serde_json::Value {
    let mut v = serde_json::json!({
        "target_from_source": matrix_rows(&r.target_from_source),
        "ransac_target_from_source": matrix_rows(&r.ransac_target_from_source),
        "success": r.failure.is_none(),
        "failure_reason": r.failure,
        "num_points": r.num_points,
        "num_points_downsampled": r.num_points_downsampled,
        "num_correspondences": r.num_correspondences,
        "num_inliers": r.num_inliers,
        "hypotheses": r.hypotheses,
        "prerejected": r.prerejected,
        "verified": r.verified,
        "best_found_at": r.best_found_at,
        "converged": r.converged,
        "fitness": r.fitness,
        "inlier_rmse_m": r.inlier_rmse_m,
        "icp_iterations": r.icp_iterations,
        "timings_s": r.timings_s,
    });
    if let Some((rot, trans)) = errors {
        v["rotation_error_deg"] = rot.into();
        v["translation_error_m"] = trans.into();
    }
    v
}

fn write_pair_text(
    out: &mut impl Write,
    r: &PairResult,
    errors: Option<(f64, f64)>,
) -> std::io::Result<()> {
    match r.failure {
        None => writeln!(out, "registration succeeded")?,
        Some(reason) => writeln!(out, "registration FAILED: {reason:?}")?,
    }
    writeln!(out, "target_from_source:")?;
    for row in matrix_rows(&r.target_from_source) {
        writeln!(
            out,
            "  {:>12.6} {:>12.6} {:>12.6} {:>12.6}",
            row[0], row[1], row[2], row[3]
        )?;
    }
    writeln!(
        out,
        "points {} / {} (downsampled {} / {}), correspondences {}, inliers {}",
        r.num_points[0],
        r.num_points[1],
        r.num_points_downsampled[0],
        r.num_points_downsampled[1],
        r.num_correspondences,
        r.num_inliers
    )?;
    writeln!(
        out,
        "hypotheses {} (pre-rejected {}, best first found at {}), converged {}",
        r.hypotheses,
        r.prerejected,
        r.best_found_at.map_or("-".into(), |h| h.to_string()),
        r.converged
    )?;
    writeln!(
        out,
        "fitness {:.4}, inlier RMSE {:.4} m, ICP iterations {}",
        r.fitness, r.inlier_rmse_m, r.icp_iterations
    )?;
    let t = &r.timings_s;
    writeln!(
        out,
        "time {:.3} s (downsample {:.3}, normals {:.3}, features {:.3}, matching {:.3}, ranking {:.3}, ransac {:.3}, icp {:.3})",
        t.total, t.downsample, t.normals, t.features, t.matching, t.ranking, t.ransac, t.icp
    )?;
    if let Some((rot, trans)) = errors {
        writeln!(
            out,
            "error vs ground truth: rotation {rot:.3} deg, translation {trans:.4} m"
        )?;
    }
    Ok(())
}
