#!/usr/bin/env python3
"""How precise is the KITTI pair's reference pose of tools/compare_open3d.py?

Usage (from the repository root, after ``bash tools/setup_venv.sh peers``):

    python3 tools/toolbox.py check-kitti-reference [DATA_DIR] [--compare-json FILE]

DATA_DIR defaults to ../shared/data/kitti_pair (000000.bin, 000001.bin). The pair has no ground
truth; compare_open3d.py uses dense point-to-plane ICP of the full clouds (target normals radius
1.0 m, distances 1.0 then 0.2 m, from the identity) as its reference. This script reruns that ICP
with other reasonable settings (normal radius 0.5 m; last distance 0.1, 0.3 or 0.5 m; one more
stage at 0.1 m) and prints each result's rotation and translation error against the reference:
the reference cannot resolve errors smaller than that spread.

With ``--compare-json FILE`` (the ``--json-out`` of tools/compare_open3d.py, with the kitti pair),
it also scores every method of that run against every variant: the median RE and TE of its
trials, each estimate composed with its random pose as compare_open3d.py does. A method that is
closer than another against one reasonable reference and farther against the next is not
resolved by this pair.
"""
import argparse
import json
import math
import os
import statistics
import sys

import numpy as np
import open3d as o3d

REG = o3d.pipelines.registration


def load(path: str) -> np.ndarray:
    return np.fromfile(path, dtype=np.float32).reshape(-1, 4)[:, :3].astype(np.float64)


def cloud(points: np.ndarray) -> o3d.geometry.PointCloud:
    pcd = o3d.geometry.PointCloud()
    pcd.points = o3d.utility.Vector3dVector(points)
    return pcd


def errors(a: np.ndarray, b: np.ndarray) -> tuple[float, float]:
    r = a[:3, :3].T @ b[:3, :3]
    angle = math.degrees(math.acos(max(-1.0, min(1.0, (np.trace(r) - 1) / 2))))
    return angle, float(np.linalg.norm(a[:3, 3] - b[:3, 3]))


def score_runs(path: str, results: dict) -> None:
    """Median RE/TE of each method's kitti trials in a compare_open3d.py JSON, per variant."""
    with open(path) as f:
        run = json.load(f)
    trials: dict[str, list[np.ndarray]] = {}
    for row in run["rows"]:
        if row["pair"] == "kitti" and row.get("success"):
            # The estimate maps the posed source P·x; composed with P it maps the original source.
            trials.setdefault(row["method"], []).append(np.array(row["T"]) @ np.array(row["P"]))
    if not trials:
        sys.exit(f"{path} has no successful kitti trials")
    methods = sorted(trials)
    print()
    print("median RE [deg] / TE [mm] of each method's trials against each reference variant")
    print("normal radius [m] | ICP distances [m] | " + " | ".join(methods))
    for (radius, schedule), reference in results.items():
        cells = []
        for m in methods:
            errs = [errors(reference, t) for t in trials[m]]
            re = statistics.median(e[0] for e in errs)
            te = statistics.median(e[1] for e in errs)
            cells.append(f"{re:.4f} / {1000 * te:.2f}")
        print(f"{radius} | {' → '.join(map(str, schedule))} | " + " | ".join(cells))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("data", nargs="?", default=os.path.join("..", "shared", "data", "kitti_pair"))
    ap.add_argument("--compare-json", help="a compare_open3d.py --json-out file to score per variant")
    args = ap.parse_args()
    paths = [os.path.join(args.data, f) for f in ("000001.bin", "000000.bin")]
    if not all(os.path.exists(p) for p in paths):
        sys.exit(f"skipped: {args.data} has no 000000.bin / 000001.bin")
    src, tgt = (cloud(load(p)) for p in paths)
    results = {}
    for radius in (1.0, 0.5):
        tgt.estimate_normals(o3d.geometry.KDTreeSearchParamHybrid(radius=radius, max_nn=30))
        for schedule in ((1.0, 0.2), (1.0, 0.1), (1.0, 0.3), (1.0, 0.5), (1.0, 0.2, 0.1)):
            t = np.eye(4)
            for distance in schedule:
                t = REG.registration_icp(src, tgt, distance, t, REG.TransformationEstimationPointToPlane(),
                                         REG.ICPConvergenceCriteria(max_iteration=60)).transformation
            results[(radius, schedule)] = t
    reference = results[(1.0, (1.0, 0.2))]
    print("normal radius [m] | ICP distances [m] | RE vs reference [deg] | TE vs reference [mm]")
    for (radius, schedule), t in results.items():
        re, te = errors(reference, t)
        print(f"{radius} | {' → '.join(map(str, schedule))} | {re:.4f} | {1000 * te:.2f}")
    if args.compare_json:
        score_runs(args.compare_json, results)


if __name__ == "__main__":
    main()
