//! The merged outputs: each session's run copied whole, with its trajectory in the group's frame
//! (`…/pose_merged`, `…/tf_merged`) and the links tried with other sessions
//! (`…/session_links`), and the report.

use std::collections::{BTreeMap, BTreeSet};
use std::io::Write;
use std::path::Path;

use nalgebra::Isometry3;
use serde_json::json;

use super::job::{Attempt, MergeOptions, MergeSummary};
use super::links::LinkSource;
use super::session::Session;
use crate::io::atomic_file::PendingFile;
use crate::io::codec::Time;
use crate::io::input_log::InputLog;
use crate::io::mcap::log::OutputLog;
use crate::register::{
    CloudKind, StampedPose, encode_pose, pose_channels, relative_pose_json, relative_pose_schema,
};
use crate::{Error, Result};

/// A link's verdict on `…/session_links`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "snake_case")]
pub(super) enum Verdict {
    /// In the graph.
    Accepted,
    /// Not.
    Rejected,
}

/// One candidate tried between two sessions, as `…/session_links` carries it
/// ([`session_links_json_schema`]).
#[derive(Debug, Clone, serde::Serialize)]
pub(super) struct LinkRecord {
    session_a: String,
    frame_a: usize,
    stamp_a_ns: i64,
    session_b: String,
    frame_b: usize,
    stamp_b_ns: i64,
    found_by: LinkSource,
    verdict: Verdict,
    reason: String,
    a_from_b: Option<serde_json::Value>,
    inliers: usize,
    fitness: f64,
    weight: f64,
    /// Session indices, to route the record (not written).
    #[serde(skip)]
    ends: (usize, usize),
}

impl LinkRecord {
    pub(super) fn new(
        sessions: &[Session],
        t: &Attempt,
        verdict: Verdict,
        reason: String,
        weight: f64,
    ) -> Self {
        let l = &t.link;
        let (sa, sb) = (&sessions[l.a], &sessions[l.b]);
        Self {
            session_a: sa.name.clone(),
            frame_a: l.frame_a,
            stamp_a_ns: sa.output.frames[l.frame_a].stamp_ns,
            session_b: sb.name.clone(),
            frame_b: l.frame_b,
            stamp_b_ns: sb.output.frames[l.frame_b].stamp_ns,
            found_by: l.found_by,
            verdict,
            reason,
            a_from_b: t.registered.then(|| relative_pose_json(&l.a_from_b)),
            inliers: l.inliers,
            fitness: if t.fitness.is_finite() {
                t.fitness
            } else {
                0.0
            },
            weight,
            ends: (l.a, l.b),
        }
    }

    /// Its frame in session b.
    pub(super) fn frame_b(&self) -> usize {
        self.frame_b
    }
}

/// Writes `records` on `channel`, each at its `log_time`, in time order (a stable sort: records of
/// one time keep their order).
pub(super) fn write_links<'r>(
    out: &mut OutputLog,
    channel: u16,
    records: impl IntoIterator<Item = &'r LinkRecord>,
    log_time: impl Fn(&LinkRecord) -> u64,
) -> Result<()> {
    let mut timed: Vec<(u64, &LinkRecord)> =
        records.into_iter().map(|r| (log_time(r), r)).collect();
    timed.sort_by_key(|(t, _)| *t);
    for (t, r) in timed {
        out.write(channel, t, t, &serde_json::to_vec(r).expect("JSON"))?;
    }
    Ok(())
}

/// The JSON schema of `…/session_links`.
#[must_use]
pub fn session_links_json_schema() -> serde_json::Value {
    let num = json!({"type": "number"});
    let int = json!({"type": "integer"});
    let text = json!({"type": "string"});
    json!({
        "$schema": "https://json-schema.org/draft/2020-12/schema",
        "title": "mireg.SessionLink",
        "description": "A candidate link between two sessions tried by mireg merge (or between a prior map, session a, and a log by mireg localize): the two frames (0-based indices of each run's clouds, header stamps), how it was found, the MI-RANSAC + ICP registration of session b's frame against session a's, the verdict and why, and the link's robust weight in the merged pose graph",
        "type": "object",
        "properties": {
            "session_a": text, "frame_a": int, "stamp_a_ns": int,
            "session_b": text, "frame_b": int, "stamp_b_ns": int,
            "found_by": {"type": "string", "enum": ["appearance", "place"]},
            "verdict": {"type": "string", "enum": ["accepted", "rejected"]},
            "reason": text,
            "a_from_b": relative_pose_schema(
                "Session b's sensor pose in session a's sensor frame (p_a = T p_b); null when the registration failed"
            ),
            "inliers": int, "fitness": num,
            "weight": {"description": "The link's robust weight at the optimum; 0 when not in the graph", "type": "number"}
        },
        "required": ["session_a", "frame_a", "stamp_a_ns", "session_b", "frame_b", "stamp_b_ns",
                     "found_by", "verdict", "reason", "a_from_b", "inliers", "fitness", "weight"]
    })
}

/// Writes `session`'s merged output to `target`: its run copied whole, then `merged` (one pose
/// per frame, in the frame `frame_id`) on `…/pose_merged` and `…/tf_merged`, and the `records`
/// that name session `index` on `…/session_links` (at the log time of its end of the link).
pub(super) fn write_session(
    session: &Session,
    target: &Path,
    opts: &MergeOptions,
    merged: &[Isometry3<f64>],
    frame_id: &str,
    records: &[LinkRecord],
    index: usize,
) -> Result<()> {
    let run = &session.output;
    let ns = &session.namespace;
    let (pose_topic, tf_topic, links_topic) = (
        format!("{ns}/pose_merged"),
        format!("{ns}/tf_merged"),
        format!("{ns}/session_links"),
    );
    let (input, catalog) = InputLog::open(&run.path)?;
    let channels = catalog.channel_infos();
    if let Some(c) = channels
        .iter()
        .find(|c| [&pose_topic, &tf_topic, &links_topic].contains(&&c.topic))
    {
        return Err(Error::InvalidInput(format!(
            "{}: already has {}: merge the outputs of `mireg register`, not merged ones",
            run.path.display(),
            c.topic
        )));
    }
    let profile = match run.kind {
        CloudKind::Ros1 | CloudKind::LivoxRos1(_) => "ros1",
        _ => "ros2",
    };
    let mut out = OutputLog::create(target, opts.force, profile)?;
    out.declare_input(&run.path, &catalog)?;
    let (tf, pose) = pose_channels(&mut out, run.kind, &tf_topic, &pose_topic)?;
    let links = out.add_json_channel(
        &links_topic,
        "mireg.SessionLink",
        &session_links_json_schema(),
    )?;
    input.pass_through(&mut out, &BTreeSet::new(), None, |_, _, _| Ok(()))?;
    for (f, p) in run.frames.iter().zip(merged) {
        let stamped = StampedPose {
            stamp: Time::from_ns(f.stamp_ns).unwrap_or_default(),
            child_frame: &f.child_frame,
            world_from_frame: *p,
            log_time: f.log_time,
            publish_time: f.publish_time,
        };
        let (pose_msg, tf_msg) = encode_pose(run.kind, frame_id, &stamped);
        out.write(tf, f.log_time, f.publish_time, &tf_msg)?;
        out.write(pose, f.log_time, f.publish_time, &pose_msg)?;
    }
    let mine = records
        .iter()
        .filter(|r| r.ends.0 == index || r.ends.1 == index);
    write_links(&mut out, links, mine, |r| {
        let frame = if r.ends.0 == index {
            r.frame_a
        } else {
            r.frame_b
        };
        run.frames[frame].log_time
    })?;
    let meta = BTreeMap::from([
        ("version".to_string(), env!("CARGO_PKG_VERSION").to_string()),
        ("command_line".to_string(), opts.command_line.clone()),
        ("merged_from".to_string(), run.path.display().to_string()),
        ("merged_pose_topic".to_string(), pose_topic),
        ("merged_tf_topic".to_string(), tf_topic),
        ("session_links_topic".to_string(), links_topic),
        ("merged_frame".to_string(), frame_id.to_string()),
        ("merge_id".to_string(), merge_id(opts)),
        ("trajectory_used".to_string(), session.pose_topic.clone()),
    ]);
    out.write_metadata("mireg_merge", meta)?;
    out.finish()
}

/// What tells one merge's outputs from another's: a hash of the runs' paths and sizes, the
/// seed and the command line, in hex.
fn merge_id(opts: &MergeOptions) -> String {
    use std::hash::{Hash, Hasher};
    let mut h = std::collections::hash_map::DefaultHasher::new();
    for r in &opts.runs {
        r.hash(&mut h);
        std::fs::metadata(r)
            .map(|m| m.len())
            .unwrap_or(0)
            .hash(&mut h);
    }
    opts.seed.hash(&mut h);
    opts.command_line.hash(&mut h);
    format!("{:016x}", h.finish())
}

/// Writes the report as pretty JSON to `target`, whole or not at all.
pub(super) fn write_report(target: &Path, summary: &MergeSummary, force: bool) -> Result<()> {
    let (mut file, pending) = PendingFile::create(target, force)?;
    let text = serde_json::to_vec_pretty(summary).expect("JSON of plain values");
    file.write_all(&text)
        .and_then(|()| file.write_all(b"\n"))
        .map_err(|e| crate::io::io_err(target, e))?;
    pending.commit(file)
}
