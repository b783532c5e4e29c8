//! `mireg pair`: register two cloud files, print the pose (text or JSON).

use std::io::Write;

use super::flags::RegistrationFlags;
use anyhow::{Context, Result};
use clap::Args;

use std::path::{Path, PathBuf};

use clap::ValueEnum;
use nalgebra::Isometry3;

use crate::io::{cloud_file, pose_file};
use crate::pipeline::{PairResult, pose_error, register_pair};

/// Ground-truth file formats for `--gt`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum GtFormat {
    /// 16 numbers: the 4×4 target_from_source, row-major.
    Matrix,
    /// 3DMatch `gt.log`: the record `TARGET SOURCE n` (needs --gt-pair).
    GtLog,
    /// Redwood/ICL-NUIM `trajectory.log` of world_from_camera per frame (needs --gt-pair).
    Trajectory,
    /// Stanford `bun.conf`: scans looked up by the SRC and TGT file names.
    Bunny,
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
    #[arg(long)]
    pub gt: Option<PathBuf>,
    /// Format of --gt.
    #[arg(long, value_enum, default_value_t = GtFormat::Matrix)]
    pub gt_format: GtFormat,
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

fn load_gt(args: &PairArgs, path: &Path) -> Result<Isometry3<f64>> {
    let need_pair = || {
        args.gt_pair.with_context(|| {
            format!(
                "--gt-format {:?} needs --gt-pair TARGET,SOURCE",
                args.gt_format
            )
        })
    };
    Ok(match args.gt_format {
        GtFormat::Matrix => pose_file::read_matrix4(path)?,
        GtFormat::GtLog => {
            let (t, s) = need_pair()?;
            let records = pose_file::read_log(path)?;
            pose_file::find_log_pair(&records, t, s)
                .with_context(|| format!("{}: no record for pair {t} {s}", path.display()))?
                .pose
        }
        GtFormat::Trajectory => {
            let (t, s) = need_pair()?;
            let records = pose_file::read_log(path)?;
            let frame = |k: usize| {
                records
                    .iter()
                    .find(|r| r.i == k)
                    .map(|r| r.pose)
                    .with_context(|| format!("{}: no pose for frame {k}", path.display()))
            };
            frame(t)?.inverse() * frame(s)?
        }
        GtFormat::Bunny => {
            let text = crate::io::read_text(path)?;
            let name = |p: &Path| {
                p.file_name()
                    .map(|n| n.to_string_lossy().into_owned())
                    .unwrap_or_default()
            };
            let world_from_src = pose_file::bunny_pose(&text, &name(&args.source))?;
            let world_from_tgt = pose_file::bunny_pose(&text, &name(&args.target))?;
            world_from_tgt.inverse() * world_from_src
        }
    })
}

pub(super) fn run_pair(args: &PairArgs) -> Result<()> {
    crate::heap::keep_freed_memory();
    let config = args.flags.config()?;
    let gt = args.gt.as_deref().map(|p| load_gt(args, p)).transpose()?;
    let (source, target) = rayon::join(
        || cloud_file::read_cloud(&args.source),
        || cloud_file::read_cloud(&args.target),
    );
    let (source, target) = (source?, target?);
    let far = [source.num_dropped_far, target.num_dropped_far];
    let result = register_pair(&source.points, &target.points, &config)?;
    let errors = gt.map(|gt| pose_error(&gt, &result.target_from_source));
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
