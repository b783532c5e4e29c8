#!/usr/bin/env python3
"""KISS-ICP and `mireg register` on the same log, in one run: one row each with ATE (after SE(3)
alignment, no scale), mean RPE per frame, frames/s and failed frames, against the log's reference
PoseStamped topic.

Both see the same clouds (the PointCloud2 messages of the log, x/y/z as float64). KISS-ICP 1.3 runs
with its defaults (no deskewing, which needs per-point times), its voxel = max_range / 100 where
max_range is min(100 m, its default; the farthest point of the first cloud), as its own pipeline
does for data shorter than 100 m. Its frames/s counts `register_frame` only (clouds decoded
beforehand); mireg's is its whole run (reading, decoding, registration, writing the output MCAP),
from its JSON summary. The same ATE/RPE code scores both, from poses associated by stamp.

Usage:
    bash tools/setup_venv.sh odometry
    python3 tools/toolbox.py compare-kiss-icp LOG.mcap [--mireg target/release/mireg]
        [--reference-topic /ground_truth/pose] [--topic T] [--frames 0-3,8-10] [-- MIREG_ARGS]

`--frames` keeps only those cloud indices for both (irregular gaps, as when messages are dropped);
mireg then reads a copy of the log holding only them.
"""

import argparse
import os
import sys
import tempfile
import time

import numpy as np
from kiss_icp.config import load_config
from kiss_icp.kiss_icp import KissICP
from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory
from mcap_ros2.writer import Writer as Ros2Writer

import mireg_run
from make_kaist03_mcap import parse_frames  # noqa: E402

CLOUD = "sensor_msgs/msg/PointCloud2"
# Livox CustomMsg (ROS 2 driver packages), read as mireg reads it with its default --livox-tags
# drop-noise: spatial noise bits 01 or 10, or intensity noise bits 01, dropped.
LIVOX = ("livox_ros_driver2/msg/CustomMsg", "livox_ros_driver/msg/CustomMsg")
POSE = "geometry_msgs/msg/PoseStamped"
DTYPES = {7: "<f4", 8: "<f8"}


def stamp_ns(h):
    return h.stamp.sec * 1_000_000_000 + h.stamp.nanosec


def livox_xyz(msg):
    """The points of a Livox CustomMsg that mireg keeps by default (x, y, z as float64)."""
    keep = [p for p in msg.points if (p.tag & 0x3) not in (1, 2) and (p.tag >> 2) & 0x3 != 1]
    p = np.array([(q.x, q.y, q.z) for q in keep], dtype=np.float64).reshape(-1, 3)
    p = p[np.all(np.isfinite(p), axis=1)]
    return p[np.any(p != 0.0, axis=1)]


def xyz(msg):
    if hasattr(msg, "points") and not hasattr(msg, "fields"):
        return livox_xyz(msg)
    fields = {f.name: f for f in msg.fields}
    step = msg.point_step
    data = np.frombuffer(bytes(msg.data), dtype=np.uint8)
    n = msg.width * msg.height
    cols = []
    for c in "xyz":
        f = fields[c]
        dt = np.dtype(DTYPES[f.datatype])
        view = np.lib.stride_tricks.as_strided(data[f.offset:], shape=(n, dt.itemsize), strides=(step, 1))
        cols.append(np.ascontiguousarray(view).view(dt).reshape(n).astype(np.float64))
    p = np.stack(cols, axis=1)
    p = p[np.all(np.isfinite(p), axis=1)]
    return p[np.any(p != 0.0, axis=1)]


def pose_matrix(p):
    """A ROS Pose as a 4x4 matrix."""
    q, t = p.orientation, p.position
    return tum_matrix((t.x, t.y, t.z, q.x, q.y, q.z, q.w))


def tum_matrix(pose):
    """(x, y, z, qx, qy, qz, qw) as a 4x4 matrix."""
    px, py, pz, x, y, z, w = pose
    r = np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
        [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
        [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
    ])
    t = np.eye(4)
    t[:3, :3] = r
    t[:3, 3] = [px, py, pz]
    return t


def read_log(path, topic, reference_topic):
    clouds, reference, cloud_topic = [], {}, topic
    with open(path, "rb") as f:
        for schema, channel, message, msg in make_reader(f, decoder_factories=[DecoderFactory()]).iter_decoded_messages():
            if schema.name in (CLOUD, *LIVOX) and (cloud_topic is None or channel.topic == cloud_topic):
                cloud_topic = channel.topic
                clouds.append((stamp_ns(msg.header), msg, message))
            elif schema.name == POSE and channel.topic == reference_topic:
                reference[stamp_ns(msg.header)] = pose_matrix(msg.pose)
    return cloud_topic, clouds, reference


def write_subset(src, topic, clouds, reference_topic, out):
    """A copy of the log with only the kept clouds and the reference poses at their times."""
    keep = {m.log_time for _s, _msg, m in clouds}
    decoders, schemas = {}, {}
    with open(src, "rb") as f, open(out, "wb") as g:
        w = Ros2Writer(g)
        for schema, channel, message in make_reader(f).iter_messages(topics=[topic, reference_topic]):
            if message.log_time not in keep:
                continue
            if schema.id not in schemas:
                schemas[schema.id] = w.register_msgdef(schema.name, schema.data.decode())
                decoders[schema.id] = DecoderFactory().decoder_for("cdr", schema)
            w.write_message(channel.topic, schemas[schema.id], decoders[schema.id](message.data),
                            log_time=message.log_time, publish_time=message.publish_time)
        w.finish()


def umeyama_rigid(a, b):
    """R, t minimising |R a + t - b| (rows are points)."""
    ca, cb = a.mean(axis=0), b.mean(axis=0)
    h = (a - ca).T @ (b - cb)
    u, _s, vt = np.linalg.svd(h)
    d = np.sign(np.linalg.det(vt.T @ u.T))
    r = vt.T @ np.diag([1.0, 1.0, d]) @ u.T
    return r, cb - r @ ca


def score(estimate, reference):
    """ATE RMSE after SE(3) alignment and mean RPE translation per frame [m], over common stamps."""
    stamps = [s for s in sorted(estimate) if s in reference]
    est = np.array([estimate[s][:3, 3] for s in stamps])
    ref = np.array([reference[s][:3, 3] for s in stamps])
    r, t = umeyama_rigid(est, ref)
    ate = float(np.sqrt(np.mean(np.sum((est @ r.T + t - ref) ** 2, axis=1))))
    rpe = []
    for s0, s1 in zip(stamps, stamps[1:]):
        de = np.linalg.inv(estimate[s0]) @ estimate[s1]
        dr = np.linalg.inv(reference[s0]) @ reference[s1]
        rpe.append(np.linalg.norm((np.linalg.inv(dr) @ de)[:3, 3]))
    return ate, float(np.mean(rpe)) if rpe else 0.0, len(stamps)


def run_odometry(clouds, config, make):
    """A KISS-ICP-style odometry (`make(config)`: `register_frame`, `last_pose`) on the decoded
    clouds, its voxel derived as KISS-ICP's pipeline does for short data (max_range = min(its
    max_range, the farthest point of the first cloud), voxel = max_range / 100): (poses by stamp
    relative to the first, frames/s of `register_frame`, the voxel)."""
    first = xyz(clouds[0][1])
    config.data.max_range = float(min(config.data.max_range, np.linalg.norm(first, axis=1).max()))
    config.mapping.voxel_size = config.data.max_range / 100.0
    odom = make(config)
    frames = [(s, xyz(msg)) for s, msg, _m in clouds]
    poses = {}
    t0 = time.perf_counter()
    for s, p in frames:
        odom.register_frame(p, np.zeros(0))
        poses[s] = np.asarray(odom.last_pose).copy()
    elapsed = time.perf_counter() - t0
    first_inv = np.linalg.inv(poses[frames[0][0]])
    return {s: first_inv @ p for s, p in poses.items()}, len(frames) / elapsed, config.mapping.voxel_size


def run_kiss(clouds):
    return run_odometry(clouds, load_config(None), KissICP)


def exported_poses(binary, out):
    """The poses `mireg export` gives of the output `out` (its best trajectory), by stamp [ns]."""
    return {s: tum_matrix(p) for s, p in mireg_run.exported_tum(binary, out).items()}


def run_mireg(binary, log, extra):
    with tempfile.TemporaryDirectory() as tmp:
        out = os.path.join(tmp, "out.mcap")
        summary, _wall = mireg_run.register(binary, log, out, extra, summary=True)
        poses = exported_poses(binary, out)
    return poses, summary


def split_mireg_args(argv):
    """(own arguments, arguments after `--` passed on to `mireg register`)."""
    if "--" in argv:
        k = argv.index("--")
        return argv[:k], argv[k + 1:]
    return argv, []


def log_parser(description):
    """The arguments the comparison scripts share: LOG, --mireg (default $MIREG_BIN, else
    target/release/mireg) and --topic."""
    ap = argparse.ArgumentParser(description=description, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("log")
    ap.add_argument("--mireg", default=mireg_run.default_binary())
    ap.add_argument("--topic")
    return ap


def main(argv):
    argv, extra = split_mireg_args(argv)
    ap = log_parser(__doc__)
    ap.add_argument("--reference-topic", default="/ground_truth/pose")
    ap.add_argument("--frames", default="", help="cloud indices to keep, e.g. 0-3,8-10,16-20")
    args = ap.parse_args(argv)
    topic, clouds, reference = read_log(args.log, args.topic, args.reference_topic)
    if not clouds:
        raise SystemExit(f"{args.log}: no {CLOUD} topic")
    if not reference:
        raise SystemExit(f"{args.log}: no {POSE} messages on {args.reference_topic}")
    keep = parse_frames(args.frames, len(clouds))
    clouds = [clouds[k] for k in keep]
    # Reference relative to the first kept frame, as both trajectories are.
    first = np.linalg.inv(reference[clouds[0][0]])
    reference = {s: first @ p for s, p in reference.items()}
    log = args.log
    with tempfile.TemporaryDirectory() as tmp:
        if args.frames:
            log = os.path.join(tmp, "subset.mcap")
            write_subset(args.log, topic, clouds, args.reference_topic, log)
        mireg_poses, summary = run_mireg(args.mireg, log, extra)
    kiss_poses, kiss_fps, kiss_voxel = run_kiss(clouds)
    print(f"{args.log} ({topic}, {len(clouds)} frames{', frames ' + args.frames if args.frames else ''}) "
          f"vs {args.reference_topic}")
    print(f"{'':10} {'ATE [m]':>9} {'RPE [m/frame]':>14} {'frames/s':>9} {'failed':>7}  voxel")
    ate, rpe, n = score(mireg_poses, reference)
    print(f"{'mireg':10} {ate:9.4f} {rpe:14.4f} {summary['frames_per_s']:9.1f} {summary['failed_frames']:7d}  "
          f"{summary['voxel_m']:.3f} m ({summary['voxel_source']}), {n} frames scored")
    ate, rpe, n = score(kiss_poses, reference)
    print(f"{'KISS-ICP':10} {ate:9.4f} {rpe:14.4f} {kiss_fps:9.1f} {'-':>7}  {kiss_voxel:.3f} m (max_range / 100), "
          f"{n} frames scored")


if __name__ == "__main__":
    main(sys.argv[1:])
