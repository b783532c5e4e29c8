#!/usr/bin/env python3
"""Frames per second of `mireg register` and KISS-ICP on the same log, in one run, interleaved.

Each round runs mireg (its whole run: reading, decoding, registration with MI-RANSAC on every
frame, writing the output MCAP; `frames_per_s` of its JSON summary) and then KISS-ICP 1.3
(`register_frame` only, on clouds decoded beforehand, its defaults and voxel as in
`compare_kiss_icp.py`). Rounds alternate so that a change in the machine's load hits both; the
ratio is taken within a round. No reference poses are needed: this is speed only (accuracy:
`compare_kiss_icp.py`).

Usage:
    bash tools/setup_venv.sh odometry
    python3 tools/toolbox.py compare-fps LOG.mcap [--rounds 3] [--topic T]
        [--mireg target/release/mireg] [-- MIREG_ARGS]
"""

import json
import os
import subprocess
import sys
import tempfile

from compare_kiss_icp import CLOUD, log_parser, read_log, run_kiss, split_mireg_args  # noqa: E402


def mireg_fps(binary, log, extra):
    with tempfile.TemporaryDirectory() as tmp:
        out = os.path.join(tmp, "out.mcap")
        run = subprocess.run([binary, "register", log, "-o", out, "--json", "--quiet", *extra],
                             capture_output=True, text=True)
        if run.returncode != 0:
            raise SystemExit(f"mireg register failed ({run.returncode}): {run.stderr}")
        return json.loads(run.stdout)


def main(argv):
    argv, extra = split_mireg_args(argv)
    ap = log_parser(__doc__)
    ap.add_argument("--rounds", type=int, default=3)
    args = ap.parse_args(argv)
    topic, clouds, _reference = read_log(args.log, args.topic, None)
    if not clouds:
        raise SystemExit(f"{args.log}: no {CLOUD} topic")
    print(f"{args.log} ({topic}, {len(clouds)} frames), mireg args: {' '.join(extra) or '(none)'}")
    print(f"{'round':>5} {'mireg f/s':>10} {'failed':>7} {'KISS-ICP f/s':>13} {'mireg/KISS':>11}  mireg voxel / feature voxel")
    for r in range(args.rounds):
        s = mireg_fps(args.mireg, args.log, extra)
        _poses, kiss, _voxel = run_kiss(clouds)
        print(f"{r + 1:5d} {s['frames_per_s']:10.1f} {s['failed_frames']:7d} {kiss:13.1f} "
              f"{s['frames_per_s'] / kiss:11.2f}  {s['voxel_m']:.3f} / {s.get('feature_voxel_m', s['voxel_m']):.3f} m")


if __name__ == "__main__":
    main(sys.argv[1:])
