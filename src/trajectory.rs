//! Trajectories for evaluation and export: a [`Trajectory`] type, parsers of TUM and KITTI text
//! (the files and MCAP topics are read by [`crate::io::poses`]), writers (TUM, KITTI in the
//! formats `evo` reads), association of an estimate with a reference, and [`evaluate`], which
//! joins them to the metrics of [`crate::evaluate`].
//!
//! Poses are `world_from_frame` (they map points in the frame into the world, metres);
//! stamps are nanoseconds since the epoch.
//!
//! Association ([`associate`]): when both trajectories have stamps, each estimate pose is paired
//! with the reference pose of the same stamp, else with the nearest reference stamp within
//! `max_dt_ns` (each reference pose used at most once; closest pairs first, like `evo`'s
//! `associate_trajectories`); estimate poses without a partner are dropped. When either has no
//! stamps (KITTI, Redwood), poses are paired by index and the lengths must agree.

use std::collections::HashMap;
use std::path::Path;

use nalgebra::{Isometry3, Matrix3, Quaternion, Translation3, UnitQuaternion, Vector3};

use crate::evaluate::{
    Drift, aligned_position_errors, ate_rmse, path_distances, path_drift, relative_pose_errors,
};
use crate::io::mcap::log::ChannelInfo;
use crate::io::{format_err, pose_file};
use crate::{Error, Result};

/// Topic of the estimated poses written by `mireg register`.
pub const DEFAULT_ESTIMATE_TOPIC: &str = "/mireg/pose";
/// Topic of the per-frame statistics (JSON) written by `mireg register`.
pub const DEFAULT_STATS_TOPIC: &str = "/mireg/stats";
/// Namespace of the topics of `mireg register` (`/mireg/pose`, `/mireg/stats`, `/mireg/tf`).
pub const MIREG_NAMESPACE: &str = "/mireg";

/// The namespace of run `n` (1-based): `/mireg` for the first, `/mireg_2`, `/mireg_3`, … for
/// logs registered again, so that a new run never mixes its poses with the input's.
pub fn mireg_namespace(n: u32) -> String {
    if n <= 1 {
        MIREG_NAMESPACE.to_string()
    } else {
        format!("{MIREG_NAMESPACE}_{n}")
    }
}

/// The run number of a `…/pose` or `…/stats` topic in a mireg namespace (`/mireg/pose` → 1,
/// `/mireg_3/stats` → 3); `None` for any other topic.
fn mireg_run_of(topic: &str) -> Option<u32> {
    let rest = topic.strip_prefix(MIREG_NAMESPACE)?;
    let (n, leaf) = rest.split_once('/')?;
    if !matches!(leaf, "pose" | "stats" | "tf") {
        return None;
    }
    match n.strip_prefix('_') {
        None if n.is_empty() => Some(1),
        Some(d) if !d.starts_with('0') => d.parse().ok().filter(|&k| k >= 2),
        _ => None,
    }
}

/// The namespace for a new run over a log with these topics: the first whose `pose`, `stats`
/// and `tf` topics are all absent.
pub fn free_mireg_namespace<'a>(topics: impl IntoIterator<Item = &'a str>) -> String {
    let last = topics
        .into_iter()
        .filter_map(mireg_run_of)
        .max()
        .unwrap_or(0);
    mireg_namespace(last + 1)
}

/// The namespace of the newest mireg run in a log (the highest run number with a `pose` topic);
/// `None` when no run wrote one.
pub fn newest_mireg_namespace(channels: &[ChannelInfo]) -> Option<String> {
    channels
        .iter()
        .filter(|c| c.topic.ends_with("/pose"))
        .filter_map(|c| mireg_run_of(&c.topic))
        .max()
        .map(mireg_namespace)
}

/// Whether a log has a loop-closed trajectory on `topic` (`…/pose_optimized`): a channel with
/// messages; one without any, left by a loop closure that failed, is no trajectory.
pub fn has_optimized_poses(channels: &[ChannelInfo], topic: &str) -> bool {
    channels
        .iter()
        .any(|c| c.topic == topic && c.message_count != Some(0))
}

/// Reference topic used by `mireg evaluate` when the log has it.
pub const DEFAULT_GROUND_TRUTH_TOPIC: &str = "/ground_truth/pose";
/// Default association tolerance \[ns\] (10 ms, `evo`'s default `--t_max_diff`).
pub const DEFAULT_MAX_DT_NS: i64 = 10_000_000;
/// Largest allowed deviation of a TUM quaternion's norm from 1 (unitless); TUM files are often
/// written with four decimals. Accepted quaternions are renormalised.
pub const TUM_QUATERNION_NORM_TOLERANCE: f64 = 1e-3;

const NANOS_PER_SEC: i64 = 1_000_000_000;
/// Path named in [`Error::Io`] when a writer's output stream fails (the caller knows the file).
pub const OUTPUT_STREAM: &str = "(output stream)";

/// A sequence of poses `world_from_frame` with optional stamps.
///
/// Invariant: `stamps_ns` is empty (a format without stamps: poses are identified by index) or
/// has one stamp \[ns\] per pose.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct Trajectory {
    /// Stamp of each pose [ns since the epoch]; empty when the source has no stamps.
    pub stamps_ns: Vec<i64>,
    /// `world_from_frame` per frame (translation in metres).
    pub poses: Vec<Isometry3<f64>>,
}

impl Trajectory {
    /// A trajectory without stamps (poses identified by index).
    pub fn unstamped(poses: Vec<Isometry3<f64>>) -> Self {
        Self {
            stamps_ns: Vec::new(),
            poses,
        }
    }

    /// A stamped trajectory. Panics if the lengths differ (a programming error).
    pub fn stamped(stamps_ns: Vec<i64>, poses: Vec<Isometry3<f64>>) -> Self {
        assert_eq!(stamps_ns.len(), poses.len(), "one stamp per pose");
        Self { stamps_ns, poses }
    }

    /// Number of poses.
    pub fn len(&self) -> usize {
        self.poses.len()
    }

    /// True when there is no pose.
    pub fn is_empty(&self) -> bool {
        self.poses.is_empty()
    }

    /// True when every pose has a stamp (and there is at least one pose).
    pub fn has_stamps(&self) -> bool {
        !self.poses.is_empty() && self.stamps_ns.len() == self.poses.len()
    }
}

/// Numbered lines that carry data: blank lines and lines starting with `#` are skipped.
fn data_lines(text: &str) -> impl Iterator<Item = (usize, &str)> {
    text.lines()
        .enumerate()
        .map(|(k, l)| (k + 1, l.trim()))
        .filter(|(_, l)| !l.is_empty() && !l.starts_with('#'))
}

fn parse_line_numbers(
    path: &Path,
    line_no: usize,
    line: &str,
    expected: usize,
    what: &str,
) -> Result<Vec<f64>> {
    let v: Vec<f64> = line
        .split_whitespace()
        .map(|t| {
            t.parse::<f64>()
                .ok()
                .filter(|x| x.is_finite())
                .ok_or_else(|| {
                    format_err(
                        path,
                        format!("line {line_no}: '{t}' is not a finite number"),
                    )
                })
        })
        .collect::<Result<_>>()?;
    if v.len() != expected {
        return Err(format_err(
            path,
            format!(
                "line {line_no}: expected {expected} numbers ({what}), found {}",
                v.len()
            ),
        ));
    }
    Ok(v)
}

// ---------------------------------------------------------------------------------------------
// TUM
// ---------------------------------------------------------------------------------------------

/// Parses a decimal number of seconds into nanoseconds without going through `f64` when it is
/// written as plain decimal (`[-]digits[.digits]`; digits beyond the ninth decimal are rounded
/// half away from zero); other spellings (exponents) go through `f64`.
fn parse_seconds_ns(token: &str) -> Option<i64> {
    let (neg, body) = match token.strip_prefix('-') {
        Some(b) => (true, b),
        None => (false, token.strip_prefix('+').unwrap_or(token)),
    };
    let (int, frac) = body.split_once('.').unwrap_or((body, ""));
    let plain = !(int.is_empty() && frac.is_empty())
        && int.bytes().all(|b| b.is_ascii_digit())
        && frac.bytes().all(|b| b.is_ascii_digit());
    if !plain {
        let s: f64 = token.parse().ok()?;
        let ns = (s * 1e9).round();
        return (ns.is_finite() && ns.abs() < 9.0e18).then_some(ns as i64);
    }
    let sec: i64 = if int.is_empty() { 0 } else { int.parse().ok()? };
    let mut nanos: i64 = 0;
    for (k, b) in frac.bytes().enumerate() {
        let digit = i64::from(b - b'0');
        if k < 9 {
            nanos = nanos * 10 + digit;
        } else {
            if k == 9 && digit >= 5 {
                nanos += 1;
            }
            break;
        }
    }
    for _ in frac.len()..9 {
        nanos *= 10;
    }
    let total = sec.checked_mul(NANOS_PER_SEC)?.checked_add(nanos)?;
    Some(if neg { -total } else { total })
}

/// Formats nanoseconds as seconds with nine decimals (exact).
fn format_seconds(ns: i64) -> String {
    let sign = if ns < 0 { "-" } else { "" };
    let a = ns.unsigned_abs();
    let n = NANOS_PER_SEC.unsigned_abs();
    format!("{sign}{}.{:09}", a / n, a % n)
}

/// Parses a TUM trajectory: one pose per line, `timestamp tx ty tz qx qy qz qw` (timestamp in
/// seconds, translation in metres, unit quaternion with `w` last). Blank lines and lines starting
/// with `#` are skipped. `path` is used only in errors.
///
/// # Errors
/// [`Error::Format`] naming the line for a line without 8 finite numbers, a bad timestamp or a
/// quaternion whose norm is not within [`TUM_QUATERNION_NORM_TOLERANCE`] of 1.
pub fn parse_tum(text: &str, path: &Path) -> Result<Trajectory> {
    let mut out = Trajectory::default();
    for (no, line) in data_lines(text) {
        let v = parse_line_numbers(path, no, line, 8, "timestamp tx ty tz qx qy qz qw")?;
        let stamp_token = line.split_whitespace().next().unwrap_or_default();
        let stamp = parse_seconds_ns(stamp_token).ok_or_else(|| {
            format_err(
                path,
                format!("line {no}: timestamp '{stamp_token}' out of range"),
            )
        })?;
        let q = Quaternion::new(v[7], v[4], v[5], v[6]);
        let norm = q.norm();
        if (norm - 1.0).abs() > TUM_QUATERNION_NORM_TOLERANCE {
            return Err(format_err(
                path,
                format!(
                    "line {no}: quaternion norm {norm} is not within {TUM_QUATERNION_NORM_TOLERANCE:e} of 1"
                ),
            ));
        }
        out.stamps_ns.push(stamp);
        out.poses.push(Isometry3::from_parts(
            Translation3::new(v[1], v[2], v[3]),
            UnitQuaternion::new_normalize(q),
        ));
    }
    Ok(out)
}

/// Writes `trajectory` in TUM format (`evo`'s `file_interface.read_tum_trajectory_file`): one
/// line `timestamp tx ty tz qx qy qz qw` per pose, the timestamp in seconds with nine decimals
/// (exact nanoseconds), the other numbers in Rust's shortest round-trip notation (`{:?}`:
/// `1.0`, `-2.220446049250313e-16`).
///
/// # Errors
/// [`Error::InvalidInput`] if the trajectory has no stamps (TUM needs them).
pub fn write_tum(trajectory: &Trajectory, out: &mut impl std::io::Write) -> Result<()> {
    if !trajectory.is_empty() && !trajectory.has_stamps() {
        return Err(Error::InvalidInput(
            "TUM output needs a stamp per pose; this trajectory has none".into(),
        ));
    }
    let io = |source| Error::Io {
        path: OUTPUT_STREAM.into(),
        source,
    };
    for (stamp, pose) in trajectory.stamps_ns.iter().zip(&trajectory.poses) {
        let t = pose.translation.vector;
        let q = pose.rotation.quaternion();
        writeln!(
            out,
            "{} {:?} {:?} {:?} {:?} {:?} {:?} {:?}",
            format_seconds(*stamp),
            t.x,
            t.y,
            t.z,
            q.i,
            q.j,
            q.k,
            q.w
        )
        .map_err(io)?;
    }
    Ok(())
}

// ---------------------------------------------------------------------------------------------
// KITTI
// ---------------------------------------------------------------------------------------------

/// A pose from a row-major 3×4 `[R | t]`, the rotation checked within
/// [`pose_file::ROTATION_TOLERANCE`] and snapped to the nearest rotation.
fn isometry_from_3x4(v: &[f64]) -> std::result::Result<Isometry3<f64>, String> {
    let r = Matrix3::new(v[0], v[1], v[2], v[4], v[5], v[6], v[8], v[9], v[10]);
    let t = Vector3::new(v[3], v[7], v[11]);
    pose_file::isometry_from_rotation_translation(&r, &t, pose_file::ROTATION_TOLERANCE)
}

/// Parses a KITTI odometry pose file: one pose per line, 12 numbers = the first three rows of
/// the 4×4 `world_from_frame`, row-major (`r11 r12 r13 tx r21 … tz`, metres). No stamps: the
/// result is [`Trajectory::unstamped`]. Blank lines are skipped; `path` is used only in errors.
///
/// # Errors
/// [`Error::Format`] naming the line for a line without 12 finite numbers or a rotation block
/// that is not a rotation within [`pose_file::ROTATION_TOLERANCE`].
pub fn parse_kitti(text: &str, path: &Path) -> Result<Trajectory> {
    let mut poses = Vec::new();
    for (no, line) in data_lines(text) {
        let v = parse_line_numbers(path, no, line, 12, "a row-major 3×4 [R | t]")?;
        poses.push(isometry_from_3x4(&v).map_err(|d| format_err(path, format!("line {no}: {d}")))?);
    }
    Ok(Trajectory::unstamped(poses))
}

/// Writes `trajectory` in KITTI format (`evo`'s `read_kitti_poses_file`): per pose one line of
/// the 12 numbers of `[R | t]` row-major, Rust's shortest round-trip notation (`{:?}`). Stamps are not
/// written.
///
/// # Errors
/// [`Error::Io`] if writing fails.
pub fn write_kitti(trajectory: &Trajectory, out: &mut impl std::io::Write) -> Result<()> {
    for pose in &trajectory.poses {
        let h = pose.to_homogeneous();
        let row: Vec<String> = (0..3)
            .flat_map(|r| (0..4).map(move |c| (r, c)))
            .map(|(r, c)| format!("{:?}", h[(r, c)]))
            .collect();
        writeln!(out, "{}", row.join(" ")).map_err(|source| Error::Io {
            path: OUTPUT_STREAM.into(),
            source,
        })?;
    }
    Ok(())
}

/// Outcome of one frame's registration, from a `/mireg/stats` message.
#[derive(Debug, Clone, PartialEq, Eq, serde::Deserialize, serde::Serialize)]
pub struct FrameFlag {
    /// Frame index in the registered cloud topic (0 = the first cloud).
    pub frame: u64,
    /// The cloud's header stamp \[ns\] (equal to the pose's stamp on `/mireg/pose`).
    pub stamp_ns: i64,
    /// False when global registration failed and the pose came from a fallback.
    pub success: bool,
    /// Why it failed (`None` on success).
    pub failure_reason: Option<String>,
}

// ---------------------------------------------------------------------------------------------
// Association
// ---------------------------------------------------------------------------------------------

/// How estimate and reference poses were paired.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "snake_case")]
pub enum AssociationMethod {
    /// By stamp: exact, or nearest within the tolerance.
    Stamp,
    /// By index (a trajectory without stamps).
    Index,
}

/// Pairs of indices `(estimate, reference)`, in increasing estimate index.
#[derive(Debug, Clone, PartialEq)]
pub struct Association {
    /// How the pairs were formed.
    pub method: AssociationMethod,
    /// `(estimate index, reference index)` per pair.
    pub pairs: Vec<(usize, usize)>,
    /// Largest |stamp difference| over the pairs \[ns\] (0 for index association).
    pub max_dt_ns: i64,
}

/// Pairs `estimate` with `reference` (see the module docs): by stamp when both are stamped
/// (exact, else nearest within `max_dt_ns`, each reference pose used once, closest first),
/// otherwise by index. Panics if `max_dt_ns < 0` (a programming error).
///
/// # Errors
/// [`Error::InvalidInput`] when index association is needed and the lengths differ.
pub fn associate(
    estimate: &Trajectory,
    reference: &Trajectory,
    max_dt_ns: i64,
) -> Result<Association> {
    assert!(max_dt_ns >= 0, "max_dt_ns must be non-negative");
    if !(estimate.has_stamps() && reference.has_stamps()) {
        if estimate.len() != reference.len() {
            return Err(Error::InvalidInput(format!(
                "association by index (a trajectory without stamps) needs equal lengths: estimate has {} poses, reference {}",
                estimate.len(),
                reference.len()
            )));
        }
        return Ok(Association {
            method: AssociationMethod::Index,
            pairs: (0..estimate.len()).map(|k| (k, k)).collect(),
            max_dt_ns: 0,
        });
    }
    let mut order: Vec<usize> = (0..reference.len()).collect();
    order.sort_by_key(|&k| reference.stamps_ns[k]);
    let sorted: Vec<i64> = order.iter().map(|&k| reference.stamps_ns[k]).collect();
    // Candidates: every reference pose within the tolerance of each estimate stamp.
    let mut candidates: Vec<(i64, usize, usize)> = Vec::new();
    for (i, &s) in estimate.stamps_ns.iter().enumerate() {
        let lo = sorted.partition_point(|&r| r < s.saturating_sub(max_dt_ns));
        for (off, &r) in sorted[lo..].iter().enumerate() {
            let dt = r.abs_diff(s);
            if r > s.saturating_add(max_dt_ns) {
                break;
            }
            candidates.push((i64::try_from(dt).unwrap_or(i64::MAX), i, order[lo + off]));
        }
    }
    candidates.sort();
    let mut used_est = vec![false; estimate.len()];
    let mut used_ref = vec![false; reference.len()];
    let mut pairs = Vec::new();
    let mut max_dt = 0;
    for (dt, i, j) in candidates {
        if !used_est[i] && !used_ref[j] {
            used_est[i] = true;
            used_ref[j] = true;
            pairs.push((i, j));
            max_dt = max_dt.max(dt);
        }
    }
    pairs.sort_unstable();
    Ok(Association {
        method: AssociationMethod::Stamp,
        pairs,
        max_dt_ns: max_dt,
    })
}

// ---------------------------------------------------------------------------------------------
// Evaluation
// ---------------------------------------------------------------------------------------------

/// Errors of one associated frame.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct FrameErrors {
    /// Frame index: from the statistics when available, else the estimate's index.
    pub frame: u64,
    /// Estimate stamp \[ns\], when stamped.
    pub stamp_ns: Option<i64>,
    /// Registration succeeded (from the statistics; `None` without them).
    pub success: Option<bool>,
    /// Failure reason (from the statistics).
    pub failure_reason: Option<String>,
    /// RPE translation against the previous associated frame \[m\] (`None` for the first).
    pub rpe_trans_m: Option<f64>,
    /// RPE rotation against the previous associated frame \[deg\] (`None` for the first).
    pub rpe_rot_deg: Option<f64>,
    /// Position error after SE(3) alignment of the whole trajectory \[m\].
    pub ate_err_m: f64,
}

/// Result of [`evaluate`].
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct Evaluation {
    /// How poses were paired.
    pub association: AssociationMethod,
    /// Poses in the estimate.
    pub estimate_poses: usize,
    /// Poses in the reference.
    pub reference_poses: usize,
    /// Largest stamp difference of a pair \[ns\].
    pub max_pair_dt_ns: i64,
    /// Per associated frame.
    pub rows: Vec<FrameErrors>,
    /// Associated frames flagged as failed; `None` without statistics.
    pub failed_frames: Option<usize>,
    /// ATE: RMSE of position errors after SE(3) Umeyama alignment \[m\].
    pub ate_rmse_m: f64,
    /// Mean RPE translation per frame \[m\].
    pub rpe_trans_mean_m: f64,
    /// RMSE of RPE translation per frame \[m\].
    pub rpe_trans_rmse_m: f64,
    /// Mean RPE rotation per frame \[deg\].
    pub rpe_rot_mean_deg: f64,
    /// Length of the reference path over the associated frames \[m\].
    pub path_length_m: f64,
    /// KITTI-style drift ([`crate::evaluate::path_drift`]), when a segment fits.
    pub drift: Option<Drift>,
    /// The alignment `reference_from_estimate` used for ATE.
    #[serde(skip)]
    pub reference_from_estimate: Isometry3<f64>,
}

/// Evaluates `estimate` against `reference`: associates them ([`associate`]), then computes
/// per-frame RPE, ATE after alignment and drift on the associated poses. `flags` (from
/// [`read_frame_flags`]) are matched to estimate poses by stamp.
///
/// # Errors
/// [`Error::InvalidInput`] when fewer than two poses associate (the message says how many poses
/// and stamps each side had), or as [`associate`].
pub fn evaluate(
    estimate: &Trajectory,
    reference: &Trajectory,
    flags: Option<&[FrameFlag]>,
    max_dt_ns: i64,
) -> Result<Evaluation> {
    let assoc = associate(estimate, reference, max_dt_ns)?;
    if assoc.pairs.len() < 2 {
        let span = |t: &Trajectory| match (t.stamps_ns.first(), t.stamps_ns.last()) {
            (Some(a), Some(b)) if t.has_stamps() => format!("stamps {a}..{b} ns"),
            _ => "no stamps".into(),
        };
        return Err(Error::InvalidInput(format!(
            "only {} pose pairs associate (need 2): estimate {} poses ({}), reference {} poses ({}), max dt {max_dt_ns} ns",
            assoc.pairs.len(),
            estimate.len(),
            span(estimate),
            reference.len(),
            span(reference)
        )));
    }
    let est: Vec<_> = assoc
        .pairs
        .iter()
        .map(|&(i, _)| estimate.poses[i])
        .collect();
    let gt: Vec<_> = assoc
        .pairs
        .iter()
        .map(|&(_, j)| reference.poses[j])
        .collect();
    let rpe = relative_pose_errors(&est, &gt);
    let ate = aligned_position_errors(&est, &gt);
    let by_stamp: HashMap<i64, &FrameFlag> = flags
        .unwrap_or_default()
        .iter()
        .map(|f| (f.stamp_ns, f))
        .collect();
    let rows: Vec<FrameErrors> = assoc
        .pairs
        .iter()
        .enumerate()
        .map(|(k, &(i, _))| {
            let stamp = estimate.has_stamps().then(|| estimate.stamps_ns[i]);
            let flag = stamp.and_then(|s| by_stamp.get(&s));
            FrameErrors {
                frame: flag.map_or(i as u64, |f| f.frame),
                stamp_ns: stamp,
                success: flag.map(|f| f.success),
                failure_reason: flag.and_then(|f| f.failure_reason.clone()),
                rpe_trans_m: (k > 0).then(|| rpe[k - 1].0),
                rpe_rot_deg: (k > 0).then(|| rpe[k - 1].1),
                ate_err_m: ate[k],
            }
        })
        .collect();
    let n = rpe.len() as f64;
    Ok(Evaluation {
        association: assoc.method,
        estimate_poses: estimate.len(),
        reference_poses: reference.len(),
        max_pair_dt_ns: assoc.max_dt_ns,
        failed_frames: flags.map(|_| rows.iter().filter(|r| r.success == Some(false)).count()),
        ate_rmse_m: ate_rmse(&est, &gt),
        rpe_trans_mean_m: rpe.iter().map(|r| r.0).sum::<f64>() / n,
        rpe_trans_rmse_m: (rpe.iter().map(|r| r.0 * r.0).sum::<f64>() / n).sqrt(),
        rpe_rot_mean_deg: rpe.iter().map(|r| r.1).sum::<f64>() / n,
        path_length_m: path_distances(&gt).last().copied().unwrap_or(0.0),
        drift: path_drift(&est, &gt),
        reference_from_estimate: crate::evaluate::align_positions(&est, &gt),
        rows,
    })
}

#[cfg(test)]
mod tests;
