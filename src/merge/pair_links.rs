//! One pair of sessions' linking kept in a file, so that the pairs of a merge can be linked
//! apart (each on its own machine: `mireg_ray run --merge`) and the merge solved from the files.
//!
//! - `mireg merge RUN... --pair A,B --links DIR` links sessions A and B alone and writes
//!   `DIR/pair_A_B.json` ([`link_pair_file`]).
//! - `mireg merge RUN... -o OUT --links DIR` reads each pair's file where there is one, links the
//!   other pairs and writes their files, then solves and writes the merge as usual.
//!
//! A file names what it was linked from: each session's index, name, frame count and a
//! fingerprint of its trajectory, the seed, the first session's voxels (the settings of every
//! registration) and the linking settings. A file that does not match the merge reading it is an
//! error naming the file and the field (`--force` links that pair again and replaces it).
//!
//! The links read back are the links written, bit for bit (the JSON numbers round-trip exactly),
//! so a merge from files writes what a merge in one process writes.

use std::io::Write;
use std::path::{Path, PathBuf};

use nalgebra::{Isometry3, Matrix6, Quaternion, Translation3, UnitQuaternion};
use serde::{Deserialize, Serialize};

use super::MergeConfig;
use super::job::{Attempt, MergeOptions, PairOutcome, PairReport};
use super::links::{AgreementConfig, LinkSource, SessionLink, Track};
use super::session::{Session, merge_settings};
use super::{Join, job::Linker};
use crate::io::atomic_file::PendingFile;
use crate::{Error, Result};

/// The `format` of a pair's file.
pub const PAIR_LINKS_FORMAT: &str = "mireg.pair_links/1";

/// The file of the pair `(a, b)` in `dir`: `pair_A_B.json`.
#[must_use]
pub fn pair_links_path(dir: &Path, (a, b): (usize, usize)) -> PathBuf {
    dir.join(format!("pair_{a}_{b}.json"))
}

/// What a pair was linked from (see the module doc).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub(super) struct Inputs {
    sessions: [SessionStamp; 2],
    seed: u64,
    voxel_m: f64,
    feature_voxel_m: f64,
    /// The merge's settings; `keyframe_memory_bytes` is 0 (it changes no link).
    config: MergeConfig,
}

/// A session as a pair's file names it.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
struct SessionStamp {
    index: usize,
    name: String,
    frames: usize,
    /// FNV-1a over the bits of its poses (translation, then quaternion i j k w), hex.
    poses_fnv1a: String,
}

impl Inputs {
    /// The inputs of linking sessions `a` and `b` in a merge whose first session is `first`.
    pub(super) fn new(
        first: &Session,
        [(a, sa), (b, sb)]: [(usize, &Session); 2],
        seed: u64,
        config: &MergeConfig,
    ) -> Self {
        let stamp = |index: usize, s: &Session| SessionStamp {
            index,
            name: s.name.clone(),
            frames: s.poses.len(),
            poses_fnv1a: format!("{:016x}", poses_fnv1a(&s.poses)),
        };
        Self {
            sessions: [stamp(a, sa), stamp(b, sb)],
            seed,
            voxel_m: first.voxel_m,
            feature_voxel_m: first.feature_voxel_m,
            config: MergeConfig {
                keyframe_memory_bytes: 0,
                ..*config
            },
        }
    }

    /// The first field (by name) where `self` and `other` differ.
    fn first_difference(&self, other: &Self) -> Option<String> {
        let (a, b) = (serde_json::to_value(self), serde_json::to_value(other));
        let (Ok(serde_json::Value::Object(a)), Ok(serde_json::Value::Object(b))) = (a, b) else {
            return Some("inputs".to_string());
        };
        a.iter()
            .find(|(k, v)| b.get(*k) != Some(v))
            .map(|(k, _)| format!("inputs.{k}"))
    }
}

/// FNV-1a (64-bit) over the bits of `poses`.
fn poses_fnv1a(poses: &[Isometry3<f64>]) -> u64 {
    let mut h: u64 = 0xcbf2_9ce4_8422_2325;
    for p in poses {
        let q = p.rotation.quaternion();
        let values = p.translation.vector.iter().chain(q.coords.iter());
        for byte in values.flat_map(|v| v.to_bits().to_le_bytes()) {
            h = (h ^ u64::from(byte)).wrapping_mul(0x0100_0000_01b3);
        }
    }
    h
}

/// One candidate tried, as the file keeps it.
#[derive(Debug, Clone, Serialize, Deserialize)]
struct AttemptRecord {
    frame_a: usize,
    frame_b: usize,
    /// x y z \[m\], qx qy qz qw.
    a_from_b: [f64; 7],
    /// The 36 entries of the information matrix, column after column.
    information: Option<Vec<f64>>,
    inliers: usize,
    found_by: LinkSource,
    verified: bool,
    reason: String,
    /// `None`: not a number (a failed registration's).
    fitness: Option<f64>,
    registered: bool,
}

/// A join, as the file keeps it.
#[derive(Debug, Clone, Serialize, Deserialize)]
struct JoinRecord {
    /// `world_a_from_world_b`: x y z \[m\], qx qy qz qw.
    a_from_b: [f64; 7],
    links: usize,
    /// The agreeing links, as indices into the file's attempts.
    agreeing: Vec<usize>,
}

/// A pair's file.
#[derive(Debug, Clone, Serialize, Deserialize)]
struct PairLinks {
    format: String,
    inputs: Inputs,
    report: PairReport,
    attempts: Vec<AttemptRecord>,
    join: Option<JoinRecord>,
}

fn pose_array(p: &Isometry3<f64>) -> [f64; 7] {
    let (t, q) = (p.translation.vector, p.rotation.quaternion().coords);
    [t.x, t.y, t.z, q.x, q.y, q.z, q.w]
}

/// The pose of [`pose_array`], its quaternion taken as written (normalising it again could
/// change its last bits).
fn array_pose(v: &[f64; 7]) -> Isometry3<f64> {
    let q = UnitQuaternion::new_unchecked(Quaternion::new(v[6], v[3], v[4], v[5]));
    Isometry3::from_parts(Translation3::new(v[0], v[1], v[2]), q)
}

/// Writes the pair's file in `dir`: `attempts` (the pair's, in order; `first` was the index of
/// the first among the merge's attempts) and its outcome.
pub(super) fn write_pair_links(
    dir: &Path,
    inputs: &Inputs,
    attempts: &[Attempt],
    first: usize,
    outcome: &PairOutcome,
    force: bool,
) -> Result<PathBuf> {
    let (a, b) = (inputs.sessions[0].index, inputs.sessions[1].index);
    let target = pair_links_path(dir, (a, b));
    let file = PairLinks {
        format: PAIR_LINKS_FORMAT.to_string(),
        inputs: inputs.clone(),
        report: outcome.report.clone(),
        attempts: attempts
            .iter()
            .map(|t| AttemptRecord {
                frame_a: t.link.frame_a,
                frame_b: t.link.frame_b,
                a_from_b: pose_array(&t.link.a_from_b),
                information: t.link.information.map(|m| m.as_slice().to_vec()),
                inliers: t.link.inliers,
                found_by: t.link.found_by,
                verified: t.verified,
                reason: t.reason.clone(),
                fitness: t.fitness.is_finite().then_some(t.fitness),
                registered: t.registered,
            })
            .collect(),
        join: outcome.join.as_ref().map(|(join, agreeing)| JoinRecord {
            a_from_b: pose_array(&join.a_from_b),
            links: join.links,
            agreeing: agreeing.iter().map(|k| k - first).collect(),
        }),
    };
    let finite = file.attempts.iter().all(|t| {
        t.a_from_b.iter().all(|v| v.is_finite())
            && t.information.iter().flatten().all(|v| v.is_finite())
    });
    if !finite {
        return Err(Error::InvalidInput(format!(
            "{}: a link of sessions {a} and {b} holds a non-finite pose or information",
            target.display()
        )));
    }
    let (mut out, pending) = PendingFile::create(&target, force)?;
    let text = serde_json::to_vec_pretty(&file).expect("JSON of plain values");
    out.write_all(&text)
        .and_then(|()| out.write_all(b"\n"))
        .map_err(|e| crate::io::io_err(&target, e))?;
    pending.commit(out)?;
    Ok(target)
}

/// The pair's file in `dir`, when there is one, appended to `attempts` (its agreeing links
/// renumbered) as the pair's outcome. `None` without a file, or with one that does not match
/// `inputs` when `force` (that pair is to be linked again).
///
/// # Errors
/// A file that does not parse, is of another format, or does not match `inputs` (without
/// `force`), naming the file and the field.
pub(super) fn read_pair_links(
    dir: &Path,
    inputs: &Inputs,
    attempts: &mut Vec<Attempt>,
    force: bool,
) -> Result<Option<PairOutcome>> {
    let (a, b) = (inputs.sessions[0].index, inputs.sessions[1].index);
    let path = pair_links_path(dir, (a, b));
    let text = match std::fs::read(&path) {
        Ok(text) => text,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(None),
        Err(e) => return Err(crate::io::io_err(&path, e)),
    };
    let bad = |what: String| Error::InvalidInput(format!("{}: {what}", path.display()));
    let file: PairLinks = serde_json::from_slice(&text)
        .map_err(|e| bad(format!("not a pair's links of `mireg merge --links`: {e}")))?;
    if file.format != PAIR_LINKS_FORMAT {
        return Err(bad(format!(
            "format is {:?}, not {PAIR_LINKS_FORMAT:?}",
            file.format
        )));
    }
    if let Some(field) = file.inputs.first_difference(inputs) {
        if force {
            return Ok(None);
        }
        return Err(bad(format!(
            "{field} differs from this merge's: linked from other runs or settings \
             (--force links the pair again and replaces the file)"
        )));
    }
    let first = attempts.len();
    let n = file.attempts.len();
    for t in file.attempts {
        let information = match t.information {
            Some(v) if v.len() == 36 => Some(Matrix6::from_column_slice(&v)),
            Some(v) => return Err(bad(format!("information has {} entries, not 36", v.len()))),
            None => None,
        };
        attempts.push(Attempt {
            link: SessionLink {
                a,
                frame_a: t.frame_a,
                b,
                frame_b: t.frame_b,
                a_from_b: array_pose(&t.a_from_b),
                information,
                inliers: t.inliers,
                found_by: t.found_by,
            },
            verified: t.verified,
            reason: t.reason,
            fitness: t.fitness.unwrap_or(f64::NAN),
            registered: t.registered,
        });
    }
    let frames = (inputs.sessions[0].frames, inputs.sessions[1].frames);
    if attempts[first..]
        .iter()
        .any(|t| t.link.frame_a >= frames.0 || t.link.frame_b >= frames.1)
    {
        return Err(bad("a link names a frame beyond its session".to_string()));
    }
    let join = match file.join {
        Some(j) if j.agreeing.iter().all(|&k| k < n) => Some((
            Join {
                a,
                b,
                a_from_b: array_pose(&j.a_from_b),
                links: j.links,
            },
            j.agreeing.iter().map(|k| k + first).collect(),
        )),
        Some(_) => return Err(bad("join.agreeing names an attempt it lacks".to_string())),
        None => None,
    };
    Ok(Some(PairOutcome {
        report: file.report,
        join,
    }))
}

/// Links sessions `a` and `b` of the merge `opts` (reading only them and the first session)
/// and writes their file in `opts.links_dir`: what `mireg merge --links` reads instead of
/// linking that pair. Returns the pair's report and the file.
///
/// # Errors
/// [`Error::InvalidInput`] without `links_dir`, for `a` not below `b` or `b` beyond the runs, a
/// file that exists without `opts.force`; the readers' errors.
pub fn link_pair_file(
    opts: &MergeOptions,
    (a, b): (usize, usize),
) -> Result<(PairReport, PathBuf)> {
    let Some(dir) = opts.links_dir.as_deref() else {
        return Err(Error::InvalidInput(
            "linking one pair needs the folder of the links (--links)".to_string(),
        ));
    };
    if a >= b || b >= opts.runs.len() {
        return Err(Error::InvalidInput(format!(
            "--pair {a},{b}: needs A < B < {} (the runs, from 0)",
            opts.runs.len()
        )));
    }
    if !dir.is_dir() {
        std::fs::create_dir(dir).map_err(|e| crate::io::io_err(dir, e))?;
    }
    crate::io::atomic_file::check_target(&pair_links_path(dir, (a, b)), opts.force)?;
    let first = Session::read(&opts.runs[0])?;
    let mut pair = [Session::read(&opts.runs[a])?, Session::read(&opts.runs[b])?];
    let (loops, config) = merge_settings(&first, opts.config.keyframe_memory_bytes, opts.seed);
    for s in &mut pair {
        s.prepare_keyframes(&loops, &config)?;
    }
    let tracks: Vec<Track<'_>> = pair.iter().map(Session::track).collect();
    let mut linker = Linker::new(&pair, &tracks, &config, &loops, &opts.config);
    // Links agree by the merge's first session's voxel, as in the whole merge.
    linker.agreement = AgreementConfig::for_voxel(first.voxel_m);
    let mut attempts = Vec::new();
    let mut outcome = linker.link_pair((0, 1), &mut attempts)?;
    for t in &mut attempts {
        (t.link.a, t.link.b) = (a, b);
    }
    if let Some((join, _)) = &mut outcome.join {
        (join.a, join.b) = (a, b);
    }
    let inputs = Inputs::new(
        &first,
        [(a, &pair[0]), (b, &pair[1])],
        opts.seed,
        &opts.config,
    );
    let path = write_pair_links(dir, &inputs, &attempts, 0, &outcome, opts.force)?;
    Ok((outcome.report, path))
}
