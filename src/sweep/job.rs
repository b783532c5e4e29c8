//! The `sweep` job: frames and pairs from a log with a reference trajectory (or from a
//! Redwood/3DMatch `gt.log` or a Stanford `bun.conf`), prepared once, then [`super::sweep`].
//! [`SweepOptions`] in; [`prepare_sweep`] gives a [`PreparedSweep`] (what will run, and the notes
//! worth telling before it does), whose [`PreparedSweep::run`] gives the table. `mireg sweep` maps
//! its flags onto the options and prints the notes and the table.

use std::collections::BTreeMap;
use std::ops::ControlFlow;
use std::path::{Path, PathBuf};

use nalgebra::{Isometry3, Point3};
use serde::{Deserialize, Serialize};

use super::{
    Acceptance, CHOI_MAX_ERROR, CellResult, PAPER_MUS, SweepConfig, SweepPair, Thresholds,
    pairs_from_trajectory, samplers, sweep,
};
use crate::pipeline::{PairConfig, PreparedFrame, prepare_frame, voxel_for_cloud};
use crate::{Error, Result};

/// What to sweep. Unset options take their documented defaults, some of them smaller with
/// `quick`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct SweepOptions {
    /// A log with point clouds and a reference pose topic; with `gt_log`, the folder of the
    /// clouds. Default empty.
    pub input: PathBuf,
    /// Pairs and ground truth from a file instead of a log: a Redwood/3DMatch `gt.log` (clouds
    /// `cloud_bin_{i}.ply|.pcd|.npy|.bin` in `input`; pairs whose clouds are absent are skipped)
    /// or a Stanford `bun.conf`. Default `None`.
    pub gt_log: Option<PathBuf>,
    /// Choi et al.'s information matrices for the `gt.log` pairs. Default `None`: `gt.info`
    /// beside the `gt.log`, when there is one.
    pub gt_info: Option<PathBuf>,
    /// Largest information-matrix error of a correct registration \[m²\]. Default
    /// [`CHOI_MAX_ERROR`].
    pub max_info_error: f64,
    /// Point cloud topic. Default `None`: the only one.
    pub topic: Option<String>,
    /// Reference pose topic, matched to clouds by stamp. Default
    /// [`crate::trajectory::DEFAULT_GROUND_TRUTH_TOPIC`].
    pub reference_topic: String,
    /// Frame gaps k of the pairs (i, i + k) \[frames\]. Default 5, 10, 20.
    pub gaps: Vec<usize>,
    /// Seeded runs per pair and cell. Default `None`: 20 (3 with `quick`).
    pub runs: Option<usize>,
    /// First seed (run r uses seed + r). Default 0.
    pub seed: u64,
    /// Rankings by name ([`super::ranking`]). Default `None`: ratio, distance, count_most
    /// (ratio, count_most with `quick`).
    pub rankings: Option<Vec<String>>,
    /// Lévy locations μ. Default `None`: [`PAPER_MUS`] (−1, −50, −1e3, −1e6 with `quick`).
    pub mus: Option<Vec<f64>>,
    /// At most this many pairs, evenly spaced over all of them. Default `None`: all (20 with
    /// `quick`).
    pub max_pairs: Option<usize>,
    /// Smaller defaults for `runs`, `mus`, `rankings` and `max_pairs`. Default `false`.
    pub quick: bool,
    /// Voxel size \[m\]. Default `None`: from the first cloud, as `register`.
    pub voxel: Option<f64>,
    /// A reported registration is correct within this rotation error \[deg\]. Default 2.
    pub max_re_deg: f64,
    /// ... and this translation error \[m\]. Default `None`: one voxel.
    pub max_te_m: Option<f64>,
    /// Reported needs at least this many RANSAC inliers. Default [`Acceptance`]'s.
    pub min_inliers: usize,
    /// ... and at least this ICP fitness. Default [`Acceptance`]'s.
    pub min_fitness: f64,
    /// Dataset name in the table. Default `None`: the input's file stem.
    pub dataset: Option<String>,
}

impl Default for SweepOptions {
    fn default() -> Self {
        let acceptance = Acceptance::default();
        Self {
            input: PathBuf::new(),
            gt_log: None,
            gt_info: None,
            max_info_error: CHOI_MAX_ERROR,
            topic: None,
            reference_topic: crate::trajectory::DEFAULT_GROUND_TRUTH_TOPIC.to_string(),
            gaps: vec![5, 10, 20],
            runs: None,
            seed: 0,
            rankings: None,
            mus: None,
            max_pairs: None,
            quick: false,
            voxel: None,
            max_re_deg: 2.0,
            max_te_m: None,
            min_inliers: acceptance.min_inliers,
            min_fitness: acceptance.min_fitness,
            dataset: None,
        }
    }
}

/// A sweep ready to run: its frames prepared, its pairs chosen, its configuration settled.
pub struct PreparedSweep {
    /// The frames, prepared once for every cell.
    pub frames: Vec<PreparedFrame>,
    /// The pairs registered in each cell.
    pub pairs: Vec<SweepPair>,
    /// The voxel used \[m\].
    pub voxel_m: f64,
    /// What runs.
    pub config: SweepConfig,
    /// What is worth telling before it runs, in order (the information matrices found, pairs
    /// skipped, pairs too small for the thresholds), one line each.
    pub notes: Vec<String>,
}

impl PreparedSweep {
    /// Runs every cell: the table's rows ([`super::sweep`]).
    ///
    /// # Errors
    /// As [`super::sweep`].
    pub fn run(&self) -> Result<Vec<CellResult>> {
        sweep(&self.frames, &self.pairs, &self.config)
    }
}

/// The clouds of a sweep and its pairs (indices into them).
type CloudsAndPairs = (Vec<Vec<Point3<f64>>>, Vec<SweepPair>);

/// An error about `path`'s content.
fn format_err(path: &Path, detail: String) -> Error {
    Error::Format {
        path: path.to_path_buf(),
        detail,
    }
}

/// Loads the clouds and pairs of `opts`, prepares the frames and settles the configuration.
///
/// # Errors
/// Unreadable inputs, no pair to register, or fewer than two clouds with a reference pose.
pub fn prepare_sweep(opts: &SweepOptions) -> Result<PreparedSweep> {
    let mut notes = Vec::new();
    let (clouds, mut pairs) = match &opts.gt_log {
        Some(gt) => pairs_from_file(&opts.input, gt, opts.gt_info.as_deref(), &mut notes)?,
        None => log_pairs(opts)?,
    };
    if pairs.is_empty() {
        let why = if notes.is_empty() {
            String::new()
        } else {
            format!(" ({})", notes.join("; "))
        };
        return Err(format_err(&opts.input, format!("no pair to register{why}")));
    }
    let voxel = match opts.voxel {
        Some(v) => v,
        None => voxel_for_cloud(&clouds[0]).unwrap_or(PairConfig::default().voxel_size_m),
    };
    let pair = PairConfig {
        voxel_size_m: voxel,
        ..Default::default()
    };
    let frames = clouds
        .iter()
        .map(|p| prepare_frame(p, &pair))
        .collect::<Result<Vec<_>>>()?;
    // `quick` changes the defaults only: an option set explicitly wins.
    let max_pairs = opts.max_pairs.or(opts.quick.then_some(20));
    if let Some(m) = max_pairs.filter(|&m| m < pairs.len()) {
        let n = pairs.len();
        pairs = (0..m).map(|i| pairs[i * n / m].clone()).collect();
    }
    let thresholds = Thresholds {
        max_re_deg: opts.max_re_deg,
        max_te_m: opts.max_te_m.unwrap_or(voxel),
        max_info_error: opts.max_info_error,
    };
    // Pairs whose motion is within the thresholds would count the identity as correct.
    let trivial = pairs
        .iter()
        .filter(|p| thresholds.correct(p, &Isometry3::identity()))
        .count();
    if trivial > 0 {
        notes.push(format!(
            "warning: {trivial} of {} pairs move less than the thresholds ({} deg, {} m): the identity would count as correct there; use larger --gaps or smaller --max-re-deg/--max-te-m",
            pairs.len(),
            thresholds.max_re_deg,
            thresholds.max_te_m
        ));
    }
    let config = sweep_config(opts, pair, thresholds);
    Ok(PreparedSweep {
        frames,
        pairs,
        voxel_m: voxel,
        config,
        notes,
    })
}

/// The configuration of `opts` (its defaults settled) with `pair` and `thresholds`.
fn sweep_config(opts: &SweepOptions, pair: PairConfig, thresholds: Thresholds) -> SweepConfig {
    let mus = opts.mus.clone().unwrap_or_else(|| {
        if opts.quick {
            vec![-1.0, -50.0, -1e3, -1e6]
        } else {
            PAPER_MUS.to_vec()
        }
    });
    let rankings = opts.rankings.clone().unwrap_or_else(|| {
        let names: &[&str] = if opts.quick {
            &["ratio", "count_most"]
        } else {
            &["ratio", "distance", "count_most"]
        };
        names.iter().map(|s| s.to_string()).collect()
    });
    SweepConfig {
        dataset: opts.dataset.clone().unwrap_or_else(|| {
            opts.input
                .file_stem()
                .map(|s| s.to_string_lossy().into_owned())
                .unwrap_or_default()
        }),
        rankings,
        samplers: samplers(&mus),
        runs: opts.runs.unwrap_or(if opts.quick { 3 } else { 20 }),
        seed: opts.seed,
        pair,
        acceptance: Acceptance {
            min_inliers: opts.min_inliers,
            min_fitness: opts.min_fitness,
        },
        thresholds,
    }
}

/// Clouds and pairs from a `gt.log` (with `gt.info`, see [`SweepOptions::gt_info`]) or a
/// `bun.conf` (see [`SweepOptions::gt_log`]); what is worth telling goes to `notes`.
fn pairs_from_file(
    dir: &Path,
    gt: &Path,
    gt_info: Option<&Path>,
    notes: &mut Vec<String>,
) -> Result<CloudsAndPairs> {
    use crate::io::{cloud_file, pose_file};
    let mut clouds = Vec::new();
    let mut index: BTreeMap<String, usize> = BTreeMap::new();
    let mut load = |file: PathBuf| -> Result<usize> {
        let key = file.display().to_string();
        if let Some(&k) = index.get(&key) {
            return Ok(k);
        }
        clouds.push(cloud_file::read_points(&file)?);
        index.insert(key, clouds.len() - 1);
        Ok(clouds.len() - 1)
    };
    let mut pairs = Vec::new();
    let text = crate::io::read_text(gt)?;
    if text.lines().any(|l| l.starts_with("bmesh")) {
        let scans = pose_file::parse_bunny_conf(&text, gt)?;
        for (a, sa) in scans.iter().enumerate() {
            for sb in &scans[a + 1..] {
                pairs.push(SweepPair {
                    target: load(dir.join(&sa.file))?,
                    source: load(dir.join(&sb.file))?,
                    target_from_source: sa.world_from_scan.inverse() * sb.world_from_scan,
                    information: None,
                });
            }
        }
    } else {
        let find = |i: usize| {
            ["ply", "pcd", "npy", "bin"]
                .iter()
                .map(|e| dir.join(format!("cloud_bin_{i}.{e}")))
                .find(|p| p.is_file())
        };
        let (mut skipped, records) = (0, pose_file::parse_log(&text, gt)?);
        let beside = gt.with_file_name("gt.info");
        let info_path = gt_info.or_else(|| beside.is_file().then_some(beside.as_path()));
        let information: BTreeMap<(usize, usize), nalgebra::Matrix6<f64>> = match info_path {
            Some(path) => pose_file::read_info(path)?
                .into_iter()
                .map(|r| ((r.i, r.j), r.information))
                .collect(),
            None => BTreeMap::new(),
        };
        for r in &records {
            match (find(r.i), find(r.j)) {
                (Some(ti), Some(sj)) => pairs.push(SweepPair {
                    target: load(ti)?,
                    source: load(sj)?,
                    target_from_source: r.pose,
                    information: information.get(&(r.i, r.j)).copied(),
                }),
                _ => skipped += 1,
            }
        }
        if let Some(path) = info_path {
            let with = pairs.iter().filter(|p| p.information.is_some()).count();
            notes.push(format!(
                "{}: information matrices for {with} of {} pairs (Choi's criterion, error ≤ max-info-error); the others by RE/TE",
                path.display(),
                pairs.len()
            ));
        }
        if skipped > 0 {
            notes.push(format!(
                "{}: {skipped} of {} pairs skipped: their clouds are not in {}",
                gt.display(),
                records.len(),
                dir.display()
            ));
        }
    }
    Ok((clouds, pairs))
}

/// Clouds matched to the reference topic by stamp, and the pairs (i, i + k) of the gaps.
fn log_pairs(opts: &SweepOptions) -> Result<CloudsAndPairs> {
    let reference = crate::io::poses::read_mcap_pose_topic(&opts.input, &opts.reference_topic)?;
    let by_stamp: BTreeMap<i64, Isometry3<f64>> = reference
        .stamps_ns
        .iter()
        .copied()
        .zip(reference.poses.iter().copied())
        .collect();
    let mut clouds: Vec<(Vec<Point3<f64>>, Isometry3<f64>)> = Vec::new();
    crate::register::for_each_cloud(&opts.input, opts.topic.as_deref(), |_, cloud| {
        if let Some(pose) = by_stamp.get(&cloud.header.stamp.to_ns()) {
            clouds.push((cloud.points, *pose));
        }
        Ok(ControlFlow::Continue(()))
    })?;
    if clouds.len() < 2 {
        return Err(format_err(
            &opts.input,
            format!(
                "{} clouds have a pose on {} at the same stamp; a sweep needs at least 2",
                clouds.len(),
                opts.reference_topic
            ),
        ));
    }
    let poses: Vec<Isometry3<f64>> = clouds.iter().map(|c| c.1).collect();
    let pairs = pairs_from_trajectory(&poses, &opts.gaps);
    Ok((clouds.into_iter().map(|c| c.0).collect(), pairs))
}
