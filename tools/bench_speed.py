#!/usr/bin/env python3
"""The speed table: `mireg register` (loop closure on), KISS-ICP and GenZ-ICP on the same logs in
one run, frames/s and ATE side by side, as docs/BENCHMARKS.md quotes it.

Per log and round, in this order: mireg with its defaults, mireg with each `--variant` (e.g.
`--global-every-frame`), KISS-ICP 1.3, GenZ-ICP 0.3. Rounds alternate so that a change in the machine's
load hits every row; ratios are taken within a round and the table shows the median over rounds
(and the range of the ratio).

- mireg's frames/s is its whole process: reading, decoding, registration, loop closure and the
  pose graph, writing the output MCAP (frames / wall time of the `register` process).
- The peers' frames/s counts `register_frame` only, on clouds decoded beforehand (x/y/z as
  float64); they write nothing.
- Both peers run with their defaults but for the voxel, which each derives as KISS-ICP's own
  pipeline does for short data: max_range = min(100 m, the farthest point of the first cloud),
  voxel = max_range / 100 (GenZ-ICP's package default is a fixed 0.3 m, too coarse for the
  indoor logs). No deskewing (it needs per-point times).
- ATE: RMSE after SE(3) alignment (no scale) against the log's reference PoseStamped topic, poses
  associated by stamp, the same code for every row (`compare_kiss_icp.score`); mireg's best
  trajectory (`mireg export`: optimised where it closed loops).

Usage:
    bash tools/setup_venv.sh odometry
    python3 tools/toolbox.py bench-speed LOG.mcap... [--rounds 3]
        [--variant=--global-every-frame] [--mireg target/release/mireg] [--reference-topic T]

The logs docs/BENCHMARKS.md uses: the KITTI replay (`cargo run --release --example
make_lidar_mcap -- 40 /tmp/k40.mcap`), and from `tools/make_loop_logs.py --all --out-dir /tmp`
the KAIST03 out-and-back, its 70 degree cone (~7k points, Livox-like) and micro211; plus
fixtures/icl_livingroom1.mcap; and a 10 Hz Livox Avia log (`tools/make_livox_log.py --out-dir
/tmp/livox`: 80 frames ray cast into the KAIST03 world, ~15k points a frame, a Livox CustomMsg
log, read for the peers as mireg reads it by default, noise-tagged points dropped; the peers do
not deskew, mireg does by the points' offset_time).
"""

import argparse
import os
import statistics
import subprocess
import sys
import tempfile

import numpy as np
from genz_icp.config import load_config as genz_config
from genz_icp.genz_icp import GenZICP

import mireg_run
from compare_kiss_icp import exported_poses, read_log, run_kiss, run_odometry, score, xyz  # noqa: E402


def run_mireg(binary, log, extra):
    """(poses by stamp [ns], frames/s of the whole process)."""
    with tempfile.TemporaryDirectory() as tmp:
        out = os.path.join(tmp, "out.mcap")
        _summary, wall = mireg_run.register(binary, log, out, extra)
        poses = exported_poses(binary, out)
    return poses, len(poses) / wall


def bench_log(args, log):
    topic, clouds, reference = read_log(log, args.topic, args.reference_topic)
    if not clouds:
        raise SystemExit(f"{log}: no sensor_msgs/msg/PointCloud2 or Livox CustomMsg topic")
    if not reference:
        raise SystemExit(f"{log}: no PoseStamped on {args.reference_topic}")
    points = statistics.mean(len(xyz(msg)) for _s, msg, _m in clouds)
    first = np.linalg.inv(reference[clouds[0][0]])
    reference = {s: first @ p for s, p in reference.items()}
    rows = {}  # name -> [(fps, ate)]
    names = ["mireg"] + [f"mireg {v}" for v in args.variant] + ["KISS-ICP", "GenZ-ICP"]
    for _ in range(args.rounds):
        for name, extra in [("mireg", [])] + [(f"mireg {v}", v.split()) for v in args.variant]:
            poses, fps = run_mireg(args.mireg, log, extra)
            rows.setdefault(name, []).append((fps, score(poses, reference)[0]))
        poses, fps, _voxel = run_kiss(clouds)
        rows.setdefault("KISS-ICP", []).append((fps, score(poses, reference)[0]))
        poses, fps, _voxel = run_odometry(clouds, genz_config(None), GenZICP)
        rows.setdefault("GenZ-ICP", []).append((fps, score(poses, reference)[0]))
    print(f"\n{log} ({topic}, {len(clouds)} clouds, {points:.0f} points/cloud, {args.rounds} rounds)")
    print(f"| {'':22} | {'frames/s':>9} | {'/ KISS-ICP':>18} | {'/ GenZ-ICP':>18} | {'ATE [cm]':>9} |")
    print(f"|{'-' * 24}|{'-' * 11}|{'-' * 20}|{'-' * 20}|{'-' * 11}|")
    for name in names:
        fps = [f for f, _a in rows[name]]
        ate = statistics.median(a for _f, a in rows[name])
        ratios = []
        for peer in ("KISS-ICP", "GenZ-ICP"):
            r = [f / p for f, (p, _a) in zip(fps, rows[peer])]
            ratios.append(f"{statistics.median(r):5.2f} ({min(r):.2f}-{max(r):.2f})")
        print(f"| {name:22} | {statistics.median(fps):9.1f} | {ratios[0]:>18} | {ratios[1]:>18} | "
              f"{100 * ate:9.2f} |")
    sys.stdout.flush()


def main(argv):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("logs", nargs="+")
    ap.add_argument("--mireg", default=mireg_run.default_binary())
    ap.add_argument("--topic")
    ap.add_argument("--reference-topic", default="/ground_truth/pose")
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--variant", action="append", default=[],
                    help="extra mireg flags for one more row, e.g. --variant=--global-every-frame")
    args = ap.parse_args(argv)
    rev = subprocess.run(["git", "rev-parse", "--short", "HEAD"], capture_output=True, text=True).stdout.strip()
    print(f"mireg {args.mireg} at {rev or '?'}, {os.cpu_count()} CPUs")
    for log in args.logs:
        bench_log(args, log)


if __name__ == "__main__":
    main(sys.argv[1:])
