#!/usr/bin/env python3
"""Success rate of `mireg pair` over posed sources × RANSAC seeds, on the pairs of compare_open3d.py.

Usage (from the repository root, after ``bash tools/setup_venv.sh peers`` and ``cargo build --release``):

    python3 tools/toolbox.py seed-sweep --pair 3dmatch --poses 30 --seeds 10
    python3 tools/toolbox.py seed-sweep --pair 3dmatch --poses 30 --seeds 10 -- --max-hypotheses 100000

The posed sources are exactly compare_open3d.py's (same pose generator, seeded by --pose-seed and
the pair); each is registered with ``--seed 1..SEEDS`` plus any arguments after ``--``. A run
succeeds under the pair's recall thresholds (RE < 15°, TE < 0.30 m; bunny TE < 0.03 m; KITTI
RE < 5°, TE < 0.60 m). Prints the success count and the failing (pose, seed, RE, TE). Open3D is
not run: this measures how often mireg's own randomness fails, which 10 poses cannot show.
"""

import argparse
import json
import os
import subprocess
import sys
import tempfile

import numpy as np

import compare_open3d as C  # noqa: E402  (the pairs, pose generator and error measures)
import mireg_run

MAKERS = {
    "3dmatch": C.make_3dmatch,
    "bunny45": C.make_bunny(45),
    "bunny90": C.make_bunny(90),
    "icl": C.make_icl,
    "kitti": C.make_kitti,
}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--pair", choices=sorted(MAKERS), default="3dmatch")
    ap.add_argument("--poses", type=int, default=30)
    ap.add_argument("--seeds", type=int, default=10)
    ap.add_argument("--pose-seed", type=int, default=0, help="compare_open3d.py's --seed (default 0)")
    ap.add_argument("--max-translation", type=float, default=1.0)
    ap.add_argument("--mireg", default=mireg_run.default_binary())
    ap.add_argument("--data", default=os.path.join("..", "shared", "data"))
    ap.add_argument("--fixtures", default="fixtures")
    ap.add_argument("extra", nargs="*", help="arguments passed to every `mireg pair` (after --)")
    args = ap.parse_args()
    try:
        pair = MAKERS[args.pair](args.data, args.fixtures)
    except C.Missing as e:
        print(f"skipped: {e}")
        return 0
    rng = np.random.default_rng([args.pose_seed, C.ALL_PAIRS.index(args.pair)])
    ok, total, failures = 0, 0, []
    with tempfile.TemporaryDirectory(prefix="mireg_sweep_") as tmp:
        tgt_path = os.path.join(tmp, "target.npy")
        np.save(tgt_path, pair.target)
        for trial in range(args.poses):
            P = C.random_pose(rng, args.max_translation)
            src_path = os.path.join(tmp, "source.npy")
            np.save(src_path, C.transform(P, pair.source))
            for seed in range(1, args.seeds + 1):
                cmd = [args.mireg, "pair", src_path, tgt_path, "--voxel", str(pair.voxel),
                       "--seed", str(seed), "--json", *args.extra]
                # exit 1: the registration failed its checks, its result still printed.
                proc = subprocess.run(cmd, capture_output=True, text=True)
                if proc.returncode not in (0, 1):
                    raise SystemExit(f"{' '.join(cmd)}: exit {proc.returncode}: {proc.stderr}")
                out = proc.stdout
                T = np.array(json.loads(out)["target_from_source"])
                e = C.evaluate(pair, T, P)
                total += 1
                if e["success"]:
                    ok += 1
                else:
                    failures.append((trial, seed, round(e["re_deg"], 1), round(e["te_m"], 3)))
    print(f"{args.pair} {' '.join(args.extra)}: {ok}/{total} succeeded")
    for f in failures:
        print(f"  failed: pose {f[0]}, seed {f[1]}: RE {f[2]}°, TE {f[3]} m")
    return 0


if __name__ == "__main__":
    sys.exit(main())
