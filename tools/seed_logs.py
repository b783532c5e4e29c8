#!/usr/bin/env python3
"""`mireg register` over RANSAC seeds 0-7 on logs with a reference: per log the median and largest
ATE (the loop-closed trajectory where there is one, SE(3)-aligned, against /ground_truth/pose) and
the accepted loops within 0.5 m and 2 deg of the reference's relative pose (loop precision).

Usage: python3 tools/toolbox.py seed-logs BIN LOG... [-- REGISTER_FLAG...] (venv:
`bash tools/setup_venv.sh odometry`; logs from tools/make_loop_logs.py and the fixture). Flags after
`--` go to every `mireg register` run, e.g. `-- --voxel 0.5`.
"""

import os
import statistics
import sys
import tempfile

import numpy as np

import mireg_run
from compare_kiss_icp import read_log, score
from compare_loops import loop_truth, read_mireg_output, transform_error

SEEDS = range(8)
LOOP_M, LOOP_DEG = 0.5, 2.0


def main(argv):
    flags = argv[argv.index("--") + 1:] if "--" in argv else []
    argv = argv[:argv.index("--")] if "--" in argv else argv
    binary, logs = argv[0], argv[1:]
    for log in logs:
        _, clouds, reference = read_log(log, None, "/ground_truth/pose")
        first = np.linalg.inv(reference[clouds[0][0]])
        reference = {s: first @ p for s, p in reference.items()}
        ates, accepted, right = [], 0, 0
        with tempfile.TemporaryDirectory() as tmp:
            for seed in SEEDS:
                out = os.path.join(tmp, f"out_{seed}.mcap")
                mireg_run.register(binary, log, out, ["--seed", str(seed), *flags])
                poses, loops, _topics = read_mireg_output(out)
                traj = "/mireg/pose_optimized" if "/mireg/pose_optimized" in poses else "/mireg/pose"
                ates.append(score(poses[traj], reference)[0])
                for lp in loops:
                    if lp.get("verdict") != "accepted" or "T" not in lp:
                        continue
                    accepted += 1
                    truth = loop_truth(reference, lp["query_stamp_ns"], lp["match_stamp_ns"])
                    if truth is not None:
                        rot, trans = transform_error(lp["T"], truth)
                        right += rot < LOOP_DEG and trans < LOOP_M
        med = statistics.median(ates)
        print(f"{os.path.basename(log)}: ATE median {100 * med:.2f} cm, max {100 * max(ates):.2f} cm "
              f"(max/median {max(ates) / med:.2f}); accepted loops {accepted} over {len(SEEDS)} seeds, "
              f"within {LOOP_M} m and {LOOP_DEG} deg: {right}; per seed (cm): "
              + " ".join(f"{100 * a:.1f}" for a in ates))


if __name__ == "__main__":
    main(sys.argv[1:])
