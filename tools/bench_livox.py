#!/usr/bin/env python3
"""Register Livox logs (from tools/make_livox_log.py) with each given mireg binary and flag set,
interleaved, and print one row per (log, binary, flags): failed frames, odometry ATE and RPE
against the generating poses (the log's /ground_truth/pose), frames per second.

Usage:
    tools/bench_livox.py --mireg target/release/mireg [--mireg /tmp/base/mireg] \\
        --flags "--deskew off" --flags "" /tmp/livox/livox_avia_kaist03 ...
Each run is `mireg register LOG -o TMP --force --json --no-loops FLAGS`; only the standard
library is needed.
"""
import argparse
import json
import shlex
import subprocess
import tempfile
from pathlib import Path


def main():
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("logs", nargs="+", type=Path)
    ap.add_argument("--mireg", action="append", required=True)
    ap.add_argument("--flags", action="append", default=None,
                    help="one flag set per run (repeatable) [no flags]")
    args = ap.parse_args()
    flag_sets = args.flags or [""]
    print(f"{'log':<34} {'binary':<24} {'flags':<34} {'failed':>6} {'ATE m':>8} "
          f"{'RPE m':>8} {'RPE deg':>8} {'fps':>6}")
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "out.mcap"
        for log in args.logs:
            for flags in flag_sets:
                for binary in args.mireg:
                    cmd = [binary, "register", str(log), "-o", str(out), "--force", "--json",
                           "--no-loops", *shlex.split(flags)]
                    run = subprocess.run(cmd, capture_output=True, text=True, check=True)
                    s = json.loads(run.stdout)
                    r = s["reference"]
                    print(f"{log.name:<34} {binary[-24:]:<24} {flags or '(defaults)':<34} "
                          f"{s['failed_frames']:>6} {r['ate_rmse_m']:>8.4f} "
                          f"{r['rpe_trans_mean_m']:>8.4f} {r['rpe_rot_mean_deg']:>8.3f} "
                          f"{s['frames_per_s']:>6.1f}")


if __name__ == "__main__":
    main()
