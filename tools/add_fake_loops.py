#!/usr/bin/env python3
"""Copy a ``mireg register`` output MCAP and append made-up loop-closure topics (viewer tests).

For an output registered with ``--no-loops`` this makes loop-closure input for ``mireg view``:
every record of IN is copied to OUT (schemas, channels, messages, metadata) and two topics are
added in the run's namespace (``/mireg/...`` or ``/mireg_N/...``, from the ``mireg`` metadata):

``…/pose_optimized``  one message per ``…/pose`` message, same schema, channel metadata, header
                      stamp and bytes except the position: frame k's position + k·OFFSET (a known
                      perturbation; the rotation is unchanged). Written at the end of the log
                      (log_time = the last message's + 1), so a reader has to match them by stamp.
``…/loops``           JSON (``jsonschema`` / ``json``) loop candidates, log_time = the query
                      cloud's: one accepted (query = the last frame, match = 10 frames earlier or
                      frame 0, ``match_from_query`` = the odometry's relative pose) and one
                      rejected (query = the frame at 2/3 or frame 2, match = frame 1,
                      ``match_from_query`` null), in log-time order.

The ``mireg`` metadata record gains ``pose_optimized_topic`` and ``loops_topic``. A log that
already has either topic is refused (exit 3): it has real loop-closure output.

Usage:
    python3 tools/toolbox.py add-fake-loops /tmp/out.mcap /tmp/out_loops.mcap
"""

from __future__ import annotations

import argparse
import json
import struct
import sys
from pathlib import Path

import numpy as np
from mcap.reader import make_reader
from mcap.writer import Writer

from mireg.run import read_run, run_topics

OFFSET = (0.01, 0.0, -0.005)  # metres per frame index
LOOP_SCHEMA = {
    "$schema": "https://json-schema.org/draft/2020-12/schema",
    "title": "mireg.LoopCandidate",
    "type": "object",
}


class AlreadyHasLoops(Exception):
    """The input already has loop-closure topics."""


def rotation_xyzw(m: np.ndarray) -> list[float]:
    """Unit quaternion (x, y, z, w) of a rotation matrix (w >= 0 branch, then the largest axis)."""
    r = m[:3, :3]
    tr = np.trace(r)
    if tr > 0:
        s = 2.0 * np.sqrt(tr + 1.0)
        q = [(r[2, 1] - r[1, 2]) / s, (r[0, 2] - r[2, 0]) / s, (r[1, 0] - r[0, 1]) / s, s / 4]
    else:
        i = int(np.argmax(np.diag(r)))
        j, k = (i + 1) % 3, (i + 2) % 3
        s = 2.0 * np.sqrt(1.0 + r[i, i] - r[j, j] - r[k, k])
        q = [0.0, 0.0, 0.0, (r[k, j] - r[j, k]) / s]
        q[i] = s / 4
        q[j] = (r[j, i] + r[i, j]) / s
        q[k] = (r[k, i] + r[i, k]) / s
    return [float(v) for v in q]


def perturbed_pose_bytes(data: bytes, encoding: str, delta) -> bytes:
    """A PoseStamped (ROS 2 CDR or ROS 1) with ``delta`` added to its position. Both end with
    the 7 float64 of the pose (position xyz, orientation xyzw), little-endian here."""
    if encoding == "cdr" and data[1] != 0x01:
        raise ValueError("big-endian CDR is not handled")
    pos = np.array(struct.unpack_from("<3d", data, len(data) - 56)) + np.asarray(delta)
    return data[:-56] + struct.pack("<3d", *pos) + data[-32:]


def loop_message(run, number, query, match, accepted: bool) -> dict:
    fq, fm = run.frames[query], run.frames[match]
    t = None
    if accepted:
        m = np.linalg.inv(fm.estimate) @ fq.estimate
        t = {"translation": [float(v) for v in m[:3, 3]], "rotation_xyzw": rotation_xyzw(m)}
    return {
        "query_frame": query, "match_frame": match,
        "query_stamp_ns": fq.stamp_ns, "match_stamp_ns": fm.stamp_ns,
        "found_by": "both" if accepted else "appearance",
        "descriptor_distance": 0.12 if accepted else 0.31,
        "odometry_distance_m": float(np.linalg.norm(fq.estimate[:3, 3] - fm.estimate[:3, 3])),
        "verdict": "accepted" if accepted else "rejected",
        "reason": "" if accepted else "too few inliers (test)",
        "match_from_query": t,
        "inliers": 812 if accepted else 9, "correspondences": 2400 if accepted else 1900,
        "fitness": 0.83 if accepted else 0.04, "inlier_rmse_m": 0.011 if accepted else 0.034,
        "odometry_disagreement_m": 0.0 if accepted else 0.9,
        "odometry_disagreement_deg": 0.0 if accepted else 21.0,
        "weight": 0.97 if accepted else 0.0,
    }


def add_loop_topics(src: Path, dst: Path, offset=OFFSET) -> dict:
    """Write ``dst`` = ``src`` + the two topics; returns {"topics", "loops", "offset"}."""
    run = read_run(src, load_clouds=False)
    topics = run_topics(run.metadata)
    n = len(run.frames)
    if n < 3:
        raise ValueError(f"{src}: {n} clouds, need at least 3 for the made-up loops")
    if any(f.estimate is None or f.stamp_ns is None for f in run.frames):
        raise ValueError(f"{src}: a cloud without a {topics['pose']} pose")
    loops = [loop_message(run, 0, n - 1, max(0, n - 11), True),
             loop_message(run, 1, max(2, 2 * n // 3), 1, False)]
    with open(src, "rb") as f_in, open(dst, "wb") as f_out:
        reader = make_reader(f_in)
        summary = reader.get_summary()
        present = {c.topic for c in summary.channels.values()}
        if topics["optimized"] in present or topics["loops"] in present:
            raise AlreadyHasLoops(f"{src} already has {topics['optimized']} or {topics['loops']}")
        writer = Writer(f_out)
        writer.start(profile=reader.get_header().profile, library="mireg add_fake_loops.py")
        schema_ids = {sid: writer.register_schema(s.name, s.encoding, s.data)
                      for sid, s in summary.schemas.items()}
        channel_ids, poses, last = {}, [], 0
        for cid, c in summary.channels.items():
            channel_ids[cid] = writer.register_channel(
                c.topic, c.message_encoding, schema_ids.get(c.schema_id, 0), dict(c.metadata))
        for _, channel, message in reader.iter_messages(log_time_order=True):
            writer.add_message(channel_ids[channel.id], message.log_time, message.data,
                               message.publish_time, message.sequence)
            last = max(last, message.log_time)
            if channel.topic == topics["pose"]:
                poses.append((channel, message))
        pose_channel = poses[0][0]
        meta = dict(pose_channel.metadata)
        if "topic" in meta:
            meta["topic"] = topics["optimized"]
        opt = writer.register_channel(topics["optimized"], pose_channel.message_encoding,
                                      schema_ids[pose_channel.schema_id], meta)
        for k, (channel, message) in enumerate(poses):
            data = perturbed_pose_bytes(message.data, channel.message_encoding,
                                        k * np.asarray(offset))
            writer.add_message(opt, last + 1, data, last + 1, k)
        loop_schema = writer.register_schema("mireg.LoopCandidate", "jsonschema",
                                             json.dumps(LOOP_SCHEMA).encode())
        loop_channel = writer.register_channel(topics["loops"], "json", loop_schema)
        for k, loop in enumerate(loops):
            t = run.frames[loop["query_frame"]].log_time
            writer.add_message(loop_channel, t, json.dumps(loop).encode(), t, k)
        records = list(reader.iter_metadata())
        newest = max((i for i, r in enumerate(records) if r.name == "mireg"), default=None)
        for i, record in enumerate(records):  # the newest run's record (read_run reads that)
            data = dict(record.metadata)
            if i == newest:
                data["pose_optimized_topic"] = topics["optimized"]
                data["loops_topic"] = topics["loops"]
            writer.add_metadata(record.name, data)
        writer.finish()
    return {"topics": topics, "loops": loops, "offset": list(offset)}


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("input", type=Path, help="output MCAP of `mireg register`")
    p.add_argument("output", type=Path, help="the copy with the made-up topics")
    args = p.parse_args(argv)
    if args.input.resolve() == args.output.resolve():
        p.error("output is the input")
    try:
        info = add_loop_topics(args.input, args.output)
    except AlreadyHasLoops as e:
        print(e, file=sys.stderr)
        return 3
    print(f"wrote {args.output}: {info['topics']['optimized']} (offset {info['offset']} m per "
          f"frame), {info['topics']['loops']} ({len(info['loops'])} loops)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
