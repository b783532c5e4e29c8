//! `/mireg/loops` records of a `register` or `stitch` output, decoded, and their check against a
//! reference trajectory.

#![allow(dead_code)]

use std::collections::HashMap;
use std::path::Path;

use mireg::io::poses::read_mcap_pose_topic;
use mireg::pipeline::pose_error;
use nalgebra::{Isometry3, Quaternion, Translation3, UnitQuaternion};

use super::log_contents::contents;

/// Poses of a PoseStamped topic by header stamp.
pub fn poses_by_stamp(path: &Path, topic: &str) -> HashMap<i64, Isometry3<f64>> {
    let t = read_mcap_pose_topic(path, topic).unwrap();
    t.stamps_ns.iter().copied().zip(t.poses).collect()
}

/// The `/mireg/loops` messages, decoded.
pub fn loops(path: &Path) -> Vec<serde_json::Value> {
    contents(path)
        .messages
        .into_iter()
        .filter(|m| m.0 == "/mireg/loops")
        .map(|m| serde_json::from_slice(&m.3).unwrap())
        .collect()
}

/// A record's `match_from_query`.
pub fn pose_of_json(v: &serde_json::Value) -> Isometry3<f64> {
    let t: Vec<f64> = serde_json::from_value(v["translation"].clone()).unwrap();
    let q: Vec<f64> = serde_json::from_value(v["rotation_xyzw"].clone()).unwrap();
    Isometry3::from_parts(
        Translation3::new(t[0], t[1], t[2]),
        UnitQuaternion::from_quaternion(Quaternion::new(q[3], q[0], q[1], q[2])),
    )
}

/// Asserts that every accepted loop of `tried` is within 2° and 2 voxels of `reference`'s
/// relative pose (the loop precision of 100 %); returns how many were accepted.
pub fn assert_accepted_loops_match(
    tried: &[serde_json::Value],
    reference: &HashMap<i64, Isometry3<f64>>,
    voxel: f64,
) -> usize {
    let accepted: Vec<&serde_json::Value> = tried
        .iter()
        .filter(|l| l["verdict"] == "accepted")
        .collect();
    for l in &accepted {
        let (q, m) = (
            l["query_stamp_ns"].as_i64().unwrap(),
            l["match_stamp_ns"].as_i64().unwrap(),
        );
        let truth = reference[&m].inverse() * reference[&q];
        let (deg, metres) = pose_error(&truth, &pose_of_json(&l["match_from_query"]));
        assert!(
            deg < 2.0 && metres < 2.0 * voxel,
            "loop {} → {}: {deg:.2}°, {metres:.3} m off the reference",
            l["query_frame"],
            l["match_frame"]
        );
    }
    accepted.len()
}
