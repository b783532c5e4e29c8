#!/usr/bin/env python3
"""`mireg register` on one log with deskewing off and on: trajectory error against the log's
reference poses (ATE, RPE, from mireg's JSON summary) and how well each frame fits the local map
(medians over frames of `map_inlier_rmse_m` and `map_fitness` in ``/mireg/stats``). A correct
deskew makes the scans fit the map better; whether the trajectory gets closer to the reference
also depends on which instant of the sweep the reference's poses refer to (docs/ODOMETRY.md).

Usage:
    bash tools/setup_venv.sh mcap && cargo build --release
    python3 tools/toolbox.py make-kaist03-mcap --ouster-time --out /tmp/kaist03_t.mcap
    python3 tools/toolbox.py compare-deskew /tmp/kaist03_t.mcap [--mireg BIN] [-- MIREG_ARGS]
"""

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile

from mcap.reader import make_reader

ROOT = os.path.join(os.path.dirname(os.path.abspath(__file__)), "..")


def stats_rows(path):
    with open(path, "rb") as f:
        return [json.loads(m.data) for _, _, m in make_reader(f).iter_messages(topics=["/mireg/stats"])]


def median_of(rows, key):
    values = [r[key] for r in rows if r.get(key) is not None]
    return statistics.median(values) if values else float("nan")


def main(argv):
    extra = []
    if "--" in argv:
        cut = argv.index("--")
        argv, extra = argv[:cut], argv[cut + 1:]
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("log")
    ap.add_argument("--mireg", default=os.path.join(ROOT, "target", "release", "mireg"))
    args = ap.parse_args(argv)
    print(f"{args.log}, mireg args: {' '.join(extra) or '(none)'}")
    print("deskew  deskewed  failed  ATE cm  RPE mm  RPE deg  map RMSE mm  map fitness")
    with tempfile.TemporaryDirectory() as tmp:
        for mode in ("off", "on"):
            out = os.path.join(tmp, f"{mode}.mcap")
            run = subprocess.run(
                [args.mireg, "register", args.log, "-o", out, "--force", "--json", "--deskew", mode, *extra],
                capture_output=True, text=True)
            if run.returncode != 0:
                raise SystemExit(f"mireg register --deskew {mode} failed: {run.stderr.strip()}")
            summary = json.loads(run.stdout)
            ref = summary.get("reference")
            if not ref:
                raise SystemExit(f"{args.log}: no reference poses (/ground_truth/pose) to compare with")
            rows = stats_rows(out)
            deskewed = sum(1 for r in rows if r.get("deskewed"))
            print(f"{mode:6s}  {deskewed:3d}/{len(rows):<4d} {summary['failed_frames']:6d}  "
                  f"{ref['ate_rmse_m'] * 100:6.3f}  {ref['rpe_trans_mean_m'] * 1000:6.2f}  "
                  f"{ref['rpe_rot_mean_deg']:7.4f}  {median_of(rows, 'map_inlier_rmse_m') * 1000:11.2f}  "
                  f"{median_of(rows, 'map_fitness'):11.4f}")


if __name__ == "__main__":
    main(sys.argv[1:])
