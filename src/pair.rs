//! The `pair` job: two cloud files registered ([`crate::pipeline::register_pair`]) and, with a
//! ground truth, the estimate's error. [`PairOptions`] in, [`PairOutcome`] out; `mireg pair`
//! maps its flags onto the one (the registration settings through
//! [`crate::settings::PairSettings`]) and prints the other.

use std::path::{Path, PathBuf};

use nalgebra::Isometry3;
use serde::{Deserialize, Serialize};

use crate::io::{cloud_file, pose_file};
use crate::pipeline::{PairConfig, PairResult, pose_error, register_pair};
use crate::{Error, Result};

/// Format of a ground-truth file ([`GroundTruth::format`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum GtFormat {
    /// 16 numbers: the 4×4 `target_from_source`, row-major (metres).
    #[default]
    Matrix,
    /// 3DMatch `gt.log`: the record `TARGET SOURCE n` (needs [`GroundTruth::pair`]).
    GtLog,
    /// Redwood/ICL-NUIM `trajectory.log` of `world_from_camera` per frame (needs
    /// [`GroundTruth::pair`]).
    Trajectory,
    /// Stanford `bun.conf`: the scans looked up by the source and target file names.
    Bunny,
}

impl GtFormat {
    /// Whether the format needs [`GroundTruth::pair`] to find the pose.
    pub fn needs_pair(self) -> bool {
        matches!(self, GtFormat::GtLog | GtFormat::Trajectory)
    }
}

/// A ground-truth pose to compare the estimate against.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct GroundTruth {
    /// The file. Default empty.
    pub path: PathBuf,
    /// Its format. Default [`GtFormat::Matrix`].
    pub format: GtFormat,
    /// For [`GtFormat::GtLog`] and [`GtFormat::Trajectory`]: the (target, source) record or
    /// frame indices. Default `None`.
    pub pair: Option<(usize, usize)>,
}

/// What to register.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct PairOptions {
    /// Source cloud (.ply, .pcd, .npy, KITTI .bin). Default empty.
    pub source: PathBuf,
    /// Target cloud; the result maps source points into its frame. Default empty.
    pub target: PathBuf,
    /// The registration settings. Default [`PairConfig::default`] (a 0.05 m voxel).
    pub config: PairConfig,
    /// Ground truth to compare against. Default `None`.
    pub gt: Option<GroundTruth>,
}

/// What [`pair_clouds`] found.
#[derive(Debug, Clone, PartialEq)]
pub struct PairOutcome {
    /// The registration (its `failure` set when it failed the checks).
    pub result: PairResult,
    /// With a ground truth: the rotation \[deg\] and translation \[m\] errors of the estimate
    /// ([`pose_error`]).
    pub errors: Option<(f64, f64)>,
    /// Points dropped from the source and the target cloud for a coordinate of
    /// [`crate::io::codec::MAX_COORDINATE_M`] (10⁶ m) or more.
    pub num_dropped_far: [usize; 2],
}

/// Runs the job: the ground truth read (if any), the two clouds read, registered, and the
/// estimate compared with the ground truth.
///
/// # Errors
/// A cloud or ground-truth file that cannot be read, a ground truth without the pose asked for,
/// an invalid configuration. A registration that fails its checks is no error: its
/// [`PairResult::failure`] says why.
pub fn pair_clouds(opts: &PairOptions) -> Result<PairOutcome> {
    let gt = opts
        .gt
        .as_ref()
        .map(|gt| read_ground_truth(gt, &opts.source, &opts.target))
        .transpose()?;
    let (source, target) = rayon::join(
        || cloud_file::read_cloud(&opts.source),
        || cloud_file::read_cloud(&opts.target),
    );
    let (source, target) = (source?, target?);
    let num_dropped_far = [source.num_dropped_far, target.num_dropped_far];
    let result = register_pair(&source.points, &target.points, &opts.config)?;
    let errors = gt.map(|gt| pose_error(&gt, &result.target_from_source));
    Ok(PairOutcome {
        result,
        errors,
        num_dropped_far,
    })
}

/// The ground-truth `target_from_source` of the clouds `source` and `target` (their file names
/// are looked up in a [`GtFormat::Bunny`] file).
pub fn read_ground_truth(gt: &GroundTruth, source: &Path, target: &Path) -> Result<Isometry3<f64>> {
    let path = &gt.path;
    let need_pair = || {
        gt.pair.ok_or_else(|| {
            Error::InvalidInput(format!(
                "{}: a ground truth in format {:?} needs the (target, source) pair",
                path.display(),
                gt.format
            ))
        })
    };
    let not_found = |detail: String| Error::Format {
        path: path.clone(),
        detail,
    };
    Ok(match gt.format {
        GtFormat::Matrix => pose_file::read_matrix4(path)?,
        GtFormat::GtLog => {
            let (t, s) = need_pair()?;
            let records = pose_file::read_log(path)?;
            pose_file::find_log_pair(&records, t, s)
                .ok_or_else(|| not_found(format!("no record for pair {t} {s}")))?
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
                    .ok_or_else(|| not_found(format!("no pose for frame {k}")))
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
            let world_from_src = pose_file::bunny_pose(&text, &name(source))?;
            let world_from_tgt = pose_file::bunny_pose(&text, &name(target))?;
            world_from_tgt.inverse() * world_from_src
        }
    })
}
