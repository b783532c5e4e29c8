#!/usr/bin/env python3
"""Generate the Open3D goldens in fixtures/golden/ from seeded synthetic clouds (no licensed data).

fpfh_open3d_small.npy: a synthetic cloud with Open3D normals and FPFH.
voxel_open3d_small.npy: VOXEL_INPUT_POINTS random points followed by Open3D's voxel_down_sample
  (VOXEL_M) centroids; float64 rows of xyz, the first row holding (n_input, n_output, VOXEL_M).

Usage: python3 tools/toolbox.py make-fpfh-golden   (Open3D version pinned in the `peers` group of tools/pyproject.toml)

The shape (no licensed data): 260 points on a bumpy sphere of radius ~1 m centred at z = 0.2,
and 140 points on the square z = -1 m below it, drawn with numpy's default_rng(20261123).
Columns (float64, N×39): xyz [m], Open3D normal (Hybrid(NORMAL_RADIUS_M, NORMAL_MAX_NN), default
unoriented sign), Open3D FPFH (Hybrid(FPFH_RADIUS_M, FPFH_MAX_NN)). The Rust test
tests/fpfh_golden.rs hard-codes the same parameters.
"""
import os

import numpy as np
import open3d as o3d

SEED = 20261123
NORMAL_RADIUS_M, NORMAL_MAX_NN = 0.35, 30
FPFH_RADIUS_M, FPFH_MAX_NN = 0.7, 100
VOXEL_INPUT_POINTS, VOXEL_M = 2000, 0.1
GOLDEN_DIR = os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "fixtures", "golden")
OUT = os.path.join(GOLDEN_DIR, "fpfh_open3d_small.npy")
VOXEL_OUT = os.path.join(GOLDEN_DIR, "voxel_open3d_small.npy")


def main():
    rng = np.random.default_rng(SEED)
    d = rng.normal(size=(260, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    r = 1.0 + 0.12 * np.sin(3 * d[:, 0]) * np.cos(2 * d[:, 1]) + 0.08 * d[:, 2] ** 2
    sphere = d * r[:, None] + np.array([0.0, 0.0, 0.2])
    plane = np.column_stack([rng.uniform(-1.5, 1.5, 140), rng.uniform(-1.5, 1.5, 140), np.full(140, -1.0)])
    pts = np.vstack([sphere, plane])

    pcd = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(pts))
    pcd.estimate_normals(o3d.geometry.KDTreeSearchParamHybrid(radius=NORMAL_RADIUS_M, max_nn=NORMAL_MAX_NN))
    fpfh = o3d.pipelines.registration.compute_fpfh_feature(
        pcd, o3d.geometry.KDTreeSearchParamHybrid(radius=FPFH_RADIUS_M, max_nn=FPFH_MAX_NN))
    table = np.hstack([pts, np.asarray(pcd.normals), np.asarray(fpfh.data).T]).astype("<f8")
    np.save(OUT, table)
    print(f"wrote {OUT}: {table.shape}, open3d {o3d.__version__}")

    # Voxel grid: a 1.0 x 0.7 x 0.3 m box offset from the origin, so the grid anchoring
    # (min bound - voxel/2) matters; Open3D's output order is arbitrary, the test sorts.
    box = rng.uniform([0.13, -0.41, 1.07], [1.13, 0.29, 1.37], size=(VOXEL_INPUT_POINTS, 3))
    down = np.asarray(o3d.geometry.PointCloud(o3d.utility.Vector3dVector(box)).voxel_down_sample(VOXEL_M).points)
    table = np.vstack([[len(box), len(down), VOXEL_M], box, down]).astype("<f8")
    np.save(VOXEL_OUT, table)
    print(f"wrote {VOXEL_OUT}: {len(box)} -> {len(down)} points")


if __name__ == "__main__":
    main()
