//! Reading a `mireg register` output through the crate's own readers, for `mireg.read_run` and
//! `mireg.read_trajectory` (python/mireg/run.py) and the viewer: channels, PoseStamped topics
//! (ROS 1 or ROS 2), JSON topics and metadata records, and the alignment `mireg evaluate` uses.

use std::collections::BTreeMap;
use std::path::PathBuf;

use mcap::records::Record;
use pyo3::exceptions::PyValueError;
use pyo3::prelude::*;

use mireg::io::mcap::log::list_channels;
use mireg::io::mcap::read::for_each_record;
use mireg::io::poses;
use mireg::trajectory::{self, Trajectory};

use crate::py_err;

/// One channel: topic, schema name, message encoding, message count (when the summary says).
type Channel = (String, String, String, Option<u64>);

/// `channels(path) -> [(topic, schema_name, message_encoding, message_count or None)]`.
#[pyfunction]
pub fn channels(py: Python<'_>, path: PathBuf) -> PyResult<Vec<Channel>> {
    let infos = py.detach(|| list_channels(&path)).map_err(|e| py_err(&e))?;
    Ok(infos
        .into_iter()
        .map(|c| (c.topic, c.schema_name, c.message_encoding, c.message_count))
        .collect())
}

/// Stamps \[ns\] and `world_from_frame` matrices (16 row-major values each) of a trajectory.
type Flat = (Vec<i64>, Vec<f64>);

fn flat(t: &Trajectory) -> Flat {
    let mut values = Vec::with_capacity(16 * t.poses.len());
    for pose in &t.poses {
        let m = pose.to_homogeneous();
        values.extend((0..4).flat_map(|r| (0..4).map(move |c| m[(r, c)])));
    }
    (t.stamps_ns.clone(), values)
}

/// `read_pose_topics(path, topics) -> [(stamps_ns, 16·N values)]`: PoseStamped topics (ROS 1 or
/// ROS 2), each sorted by header stamp, read in one pass as `mireg evaluate` reads them.
#[pyfunction]
pub fn read_pose_topics(py: Python<'_>, path: PathBuf, topics: Vec<String>) -> PyResult<Vec<Flat>> {
    let names: Vec<&str> = topics.iter().map(String::as_str).collect();
    let read = py
        .detach(|| poses::read_mcap_pose_topics(&path, &names))
        .map_err(|e| py_err(&e))?;
    Ok(read.iter().map(flat).collect())
}

/// Metadata records (name, entries) and messages (topic index, log time \[ns\], text).
type JsonRecords = (
    Vec<(String, BTreeMap<String, String>)>,
    Vec<(usize, u64, String)>,
);

/// `read_json_topics(path, topics) -> (metadata, messages)`: every metadata record as
/// `(name, {key: value})`, and every message on `topics` as `(topic index, log_time, text)` in
/// file order (JSON topics such as `/mireg/stats` and `/mireg/loops`).
#[pyfunction]
pub fn read_json_topics(
    py: Python<'_>,
    path: PathBuf,
    topics: Vec<String>,
) -> PyResult<JsonRecords> {
    let read = py.detach(|| {
        let mut ids: BTreeMap<u16, usize> = BTreeMap::new();
        let (mut metadata, mut messages) = (Vec::new(), Vec::new());
        for_each_record(&path, |record| {
            match record {
                Record::Metadata(m) => metadata.push((m.name, m.metadata)),
                Record::Channel(c) => {
                    if let Some(k) = topics.iter().position(|t| *t == c.topic) {
                        ids.insert(c.id, k);
                    }
                }
                Record::Message { header, data } => {
                    if let Some(&k) = ids.get(&header.channel_id) {
                        let text = String::from_utf8_lossy(&data).into_owned();
                        messages.push((k, header.log_time, text));
                    }
                }
                _ => {}
            }
            Ok(())
        })
        .map(|()| (metadata, messages))
    });
    read.map_err(|e| py_err(&e))
}

/// `evaluate_topics(path, estimate, reference, stats, max_dt_s) -> (evaluation JSON,
/// reference_from_estimate as 16 row-major values)`: `mireg evaluate`'s evaluation of one pose
/// topic against another (association by stamp within `max_dt_s`, Umeyama SE(3) alignment, ATE,
/// RPE), with the alignment it used.
#[pyfunction]
#[pyo3(signature = (path, estimate, reference, stats=None, max_dt_s=0.01))]
pub fn evaluate_topics(
    py: Python<'_>,
    path: PathBuf,
    estimate: String,
    reference: String,
    stats: Option<String>,
    max_dt_s: f64,
) -> PyResult<(String, Vec<f64>)> {
    if !(max_dt_s.is_finite() && (0.0..=1e9).contains(&max_dt_s)) {
        return Err(PyValueError::new_err(format!(
            "max_dt_s must be a non-negative number of seconds, got {max_dt_s}"
        )));
    }
    let max_dt_ns = (max_dt_s * 1e9).round() as i64;
    let evaluation = py.detach(|| {
        let mut v = poses::read_mcap_pose_topics(&path, &[&estimate, &reference])?;
        let (reference, estimate) = (v.pop().unwrap_or_default(), v.pop().unwrap_or_default());
        let flags = match &stats {
            Some(topic) => poses::read_frame_flags(&path, topic)?,
            None => None,
        };
        trajectory::evaluate(&estimate, &reference, flags.as_deref(), max_dt_ns)
    });
    let evaluation = evaluation.map_err(|e| py_err(&e))?;
    let m = evaluation.reference_from_estimate.to_homogeneous();
    let rows = (0..4)
        .flat_map(|r| (0..4).map(move |c| m[(r, c)]))
        .collect();
    let text =
        serde_json::to_string(&evaluation).map_err(|e| PyValueError::new_err(e.to_string()))?;
    Ok((text, rows))
}
