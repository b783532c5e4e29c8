#!/usr/bin/env python3
"""Score a `mireg merge` output folder against the reference, read with the official `mcap`
reader and `mcap_ros2` decoder (independent of mireg's own readers).

For every merged output in DIR (its `merge_report.json` lists them), the poses on
`…/pose_merged` and the reference poses (`--reference-topic`, default `/ground_truth/pose`) are
paired by header stamp. Printed:

* joint ATE: one rigid alignment (Umeyama/Horn, no scale) of all sessions' merged positions
  together onto the reference, then the RMSE; sessions of different groups are scored per group;
* per session: its ATE after that one alignment, and its ATE aligned alone (what the session's
  own trajectory is worth);
* the alignment check: each later session's first pose in the merged frame against where the
  reference puts it relative to the root session's first frame (translation m, rotation deg);
* the links: every accepted link on `…/session_links` against the reference's relative pose of
  its two frames; a link more than 0.5 m or 2 deg off counts as wrong.

Usage: python3 tools/toolbox.py merge-ate DIR [--reference-topic T] [--json]
(venv: `bash tools/setup_venv.sh merge`).
"""

import argparse
import json
import pathlib
import sys

import numpy as np
from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory


def read_links(path, topic):
    """The accepted links of one merged output's `…/session_links`."""
    with open(path, "rb") as f:
        reader = make_reader(f)
        return [json.loads(m.data) for _, _, m in reader.iter_messages(topics=[topic])
                if json.loads(m.data)["verdict"] == "accepted"]


def read_poses(path, topics):
    """{topic: {stamp_ns: 4x4}} for PoseStamped topics of one MCAP."""
    out = {t: {} for t in topics}
    with open(path, "rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        for _, channel, _, msg in reader.iter_decoded_messages(topics=topics):
            h, p = msg.header, msg.pose
            q = [p.orientation.w, p.orientation.x, p.orientation.y, p.orientation.z]
            t = [p.position.x, p.position.y, p.position.z]
            out[channel.topic][h.stamp.sec * 1_000_000_000 + h.stamp.nanosec] = matrix(q, t)
    return out


def matrix(q, t):
    w, x, y, z = q / np.linalg.norm(q)
    r = np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
        [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
        [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
    ])
    m = np.eye(4)
    m[:3, :3], m[:3, 3] = r, t
    return m


def angle_deg(m):
    """The rotation angle of the 4x4 transform ``m`` [deg]."""
    return float(np.degrees(np.arccos(np.clip((np.trace(m[:3, :3]) - 1) / 2, -1, 1))))


def align(est, ref):
    """Rigid transform (4x4) taking the points est (N×3) onto ref (Umeyama without scale)."""
    me, mr = est.mean(0), ref.mean(0)
    u, _, vt = np.linalg.svd((ref - mr).T @ (est - me))
    d = np.sign(np.linalg.det(u @ vt))
    r = u @ np.diag([1, 1, d]) @ vt
    m = np.eye(4)
    m[:3, :3], m[:3, 3] = r, mr - r @ me
    return m


def ate(est, ref, m):
    moved = est @ m[:3, :3].T + m[:3, 3]
    return float(np.sqrt(np.mean(np.sum((moved - ref) ** 2, axis=1))))


def link_errors(report, reference_topic):
    """Each accepted link (once, from its first session's output) against the reference."""
    refs, seen, errors = {}, set(), []
    for s in report["sessions"]:
        refs[s["name"]] = read_poses(s["output"], [reference_topic])[reference_topic]
    for s in report["sessions"]:
        ns = s["pose_topic"].rsplit("/", 1)[0]
        for link in read_links(s["output"], f"{ns}/session_links"):
            key = (link["session_a"], link["stamp_a_ns"], link["session_b"], link["stamp_b_ns"])
            if key in seen:
                continue
            seen.add(key)
            ra, rb = refs[link["session_a"]].get(key[1]), refs[link["session_b"]].get(key[3])
            if ra is None or rb is None:
                continue
            t, q = link["a_from_b"]["translation"], link["a_from_b"]["rotation_xyzw"]
            est = matrix(np.array([q[3], q[0], q[1], q[2]]), t)
            d = np.linalg.inv(np.linalg.inv(ra) @ rb) @ est
            errors.append((float(np.linalg.norm(d[:3, 3])), angle_deg(d)))
    wrong = sum(1 for m, deg in errors if m > 0.5 or deg > 2.0)
    return {"accepted": len(errors), "wrong": wrong,
            "max_error_m": max((m for m, _ in errors), default=0.0),
            "max_error_deg": max((d for _, d in errors), default=0.0)}


def main(argv):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("dir", type=pathlib.Path)
    ap.add_argument("--reference-topic", default="/ground_truth/pose")
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args(argv)
    report = json.loads((args.dir / "merge_report.json").read_text())
    sessions = []
    for s in report["sessions"]:
        ns = s["pose_topic"].rsplit("/", 1)[0]
        topic = f"{ns}/pose_merged"
        poses = read_poses(s["output"], [topic, args.reference_topic])
        merged, ref = poses[topic], poses[args.reference_topic]
        stamps = sorted(set(merged) & set(ref))
        if not stamps:
            sys.exit(f"{s['output']}: no stamps shared by {topic} and {args.reference_topic}")
        sessions.append({
            "name": s["name"], "group": s["group"], "stamps": stamps,
            "est": np.array([merged[k] for k in stamps]),
            "ref": np.array([ref[k] for k in stamps]),
        })
    result = {"groups": {}, "sessions": {}, "links": link_errors(report, args.reference_topic)}
    for g in sorted({s["group"] for s in sessions}):
        members = [s for s in sessions if s["group"] == g]
        est = np.concatenate([s["est"][:, :3, 3] for s in members])
        ref = np.concatenate([s["ref"][:, :3, 3] for s in members])
        m = align(est, ref)
        result["groups"][g] = {"sessions": [s["name"] for s in members], "frames": len(est),
                               "joint_ate_m": ate(est, ref, m)}
        root = members[0]
        for s in members:
            e, r = s["est"][:, :3, 3], s["ref"][:, :3, 3]
            entry = {"ate_joint_alignment_m": ate(e, r, m),
                     "ate_own_alignment_m": ate(e, r, align(e, r))}
            if s is not root:
                # Where the reference puts this session's first frame in the root's first frame,
                # against the merged trajectory's placement.
                truth = np.linalg.inv(root["ref"][0]) @ s["ref"][0]
                est0 = np.linalg.inv(root["est"][0]) @ s["est"][0]
                d = np.linalg.inv(truth) @ est0
                entry["first_pose_error_m"] = float(np.linalg.norm(d[:3, 3]))
                entry["first_pose_error_deg"] = angle_deg(d)
            result["sessions"][s["name"]] = entry
    if args.json:
        print(json.dumps(result, indent=2))
        return
    for g, r in result["groups"].items():
        print(f"group {g}: {', '.join(r['sessions'])}: {r['frames']} frames, joint ATE {r['joint_ate_m']:.4f} m")
    lk = result["links"]
    print(f"links: {lk['accepted']} accepted, {lk['wrong']} wrong (> 0.5 m or 2 deg), "
          f"max error {lk['max_error_m']:.4f} m / {lk['max_error_deg']:.3f} deg")
    for name, e in result["sessions"].items():
        extra = ""
        if "first_pose_error_m" in e:
            extra = f", first pose vs reference {e['first_pose_error_m']:.4f} m / {e['first_pose_error_deg']:.3f} deg"
        print(f"  {name}: ATE {e['ate_joint_alignment_m']:.4f} m (joint alignment), "
              f"{e['ate_own_alignment_m']:.4f} m (own){extra}")


if __name__ == "__main__":
    main(sys.argv[1:])
