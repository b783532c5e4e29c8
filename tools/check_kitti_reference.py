#!/usr/bin/env python3
"""How precise is the KITTI pair's reference pose of tools/compare_open3d.py?

Usage (from the repository root, after ``bash tools/setup_venv.sh``):

    tools/.venv/bin/python tools/check_kitti_reference.py [DATA_DIR]

DATA_DIR defaults to ../shared/data/kitti_pair (000000.bin, 000001.bin). The pair has no ground
truth; compare_open3d.py uses dense point-to-plane ICP of the full clouds (target normals radius
1.0 m, distances 1.0 then 0.2 m, from the identity) as its reference. This script reruns that ICP
with other reasonable settings (normal radius 0.5 m; last distance 0.1, 0.3 or 0.5 m; one more
stage at 0.1 m) and prints each result's rotation and translation error against the reference:
the reference cannot resolve errors smaller than that spread.
"""
import math
import os
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


def main() -> None:
    data = sys.argv[1] if len(sys.argv) > 1 else os.path.join("..", "shared", "data", "kitti_pair")
    paths = [os.path.join(data, f) for f in ("000001.bin", "000000.bin")]
    if not all(os.path.exists(p) for p in paths):
        sys.exit(f"skipped: {data} has no 000000.bin / 000001.bin")
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


if __name__ == "__main__":
    main()
