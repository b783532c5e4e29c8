#!/usr/bin/env python3
"""Compare mireg's voxel grid, normals and FPFH with Open3D's on one cloud, and time both.

Usage (after `bash tools/setup_venv.sh peers` and `cargo build --release --example fpfh_dump`):
    python3 tools/toolbox.py fpfh-vs-open3d --cloud ../shared/data/3dmatch_redkitchen_0_6/ref.npy --voxel 0.05
    python3 tools/toolbox.py fpfh-vs-open3d --cloud ../shared/data/bunny/bun000.ply --voxel 0.005

Each stage is compared in isolation: normals and FPFH both run on Open3D's downsampled points, and
FPFH on both sides uses Open3D's normals. Parameters follow Open3D's registration recipe:
normals Hybrid(2*voxel, 30), FPFH Hybrid(5*voxel, 100).
"""
import argparse
import json
import os
import subprocess
import tempfile
import time

import numpy as np
import open3d as o3d

HERE = os.path.dirname(os.path.abspath(__file__))
DEFAULT_BIN = os.path.join(HERE, "..", "target", "release", "examples", "fpfh_dump")


def load_points(path):
    if path.endswith(".npy"):
        return np.load(path)[:, :3].astype(np.float64)
    return np.asarray(o3d.io.read_point_cloud(path).points, dtype=np.float64)


def run(binary, *args):
    return subprocess.run([binary, *map(str, args)], check=True, capture_output=True, text=True).stdout


def pct(x, qs=(50, 90, 99, 100)):
    return {f"p{q}": float(np.percentile(x, q)) for q in qs}


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--cloud", required=True)
    ap.add_argument("--voxel", type=float, required=True, help="voxel size [m]")
    ap.add_argument("--bin", default=DEFAULT_BIN, help="path to the fpfh_dump example binary")
    ap.add_argument("--repeats", type=int, default=5, help="timing repetitions (best is reported)")
    args = ap.parse_args()
    v = args.voxel
    pts = load_points(args.cloud)
    out = {"cloud": args.cloud, "input_points": len(pts), "voxel_m": v, "open3d": o3d.__version__}

    with tempfile.TemporaryDirectory() as tmp:
        f_in, f_out = os.path.join(tmp, "in.npy"), os.path.join(tmp, "out.npy")

        # Voxel grid: counts and centroids (Open3D's order is arbitrary: sort both).
        pcd = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(pts))
        down = pcd.voxel_down_sample(v)
        ref = np.asarray(down.points)
        np.save(f_in, pts)
        run(args.bin, "voxel", f_in, f_out, v)
        ours = np.load(f_out)
        a, b = ref[np.lexsort(ref.T[::-1])], ours[np.lexsort(ours.T[::-1])]
        out["voxel"] = {"open3d_count": len(ref), "ours_count": len(ours)}
        if len(a) == len(b):
            out["voxel"]["max_centroid_diff_m"] = float(np.abs(a - b).max())

        # Normals on Open3D's downsampled points.
        down.estimate_normals(o3d.geometry.KDTreeSearchParamHybrid(radius=2 * v, max_nn=30))
        n_ref = np.asarray(down.normals).copy()
        np.save(f_in, ref)
        run(args.bin, "normals", f_in, f_out, 2 * v, 30)
        n_ours = np.load(f_out)
        dots = np.sum(n_ref * n_ours, axis=1)
        ang = np.degrees(np.arccos(np.clip(np.abs(dots), 0.0, 1.0)))
        out["normals"] = {
            "unsigned_angle_deg": pct(ang),
            "same_sign_fraction": float(np.mean(dots > 0)),
        }

        # FPFH on Open3D's points + normals.
        fpfh = o3d.pipelines.registration.compute_fpfh_feature(
            down, o3d.geometry.KDTreeSearchParamHybrid(radius=5 * v, max_nn=100))
        f_ref = np.asarray(fpfh.data).T
        np.save(f_in, np.hstack([ref, n_ref]))
        run(args.bin, "fpfh", f_in, f_out, 5 * v, 100)
        f_ours = np.load(f_out).astype(np.float64)
        norm = np.linalg.norm(f_ref, axis=1)
        nz = norm > 0
        rel = np.linalg.norm(f_ours - f_ref, axis=1)[nz] / norm[nz]
        out["fpfh"] = {
            "relative_l2_diff": pct(rel),
            "fraction_below_1e-6": float(np.mean(rel < 1e-6)),
            "zero_descriptors_open3d": int((~nz).sum()),
            "zero_descriptors_ours": int((np.linalg.norm(f_ours, axis=1) == 0).sum()),
            "open3d_mean_sum": float(f_ref[nz].sum(axis=1).mean()),
        }

        # Timing: voxel + normals + FPFH, best of N, same process for Open3D.
        best = [float("inf")] * 4
        for _ in range(args.repeats):
            t0 = time.perf_counter()
            d = pcd.voxel_down_sample(v)
            t1 = time.perf_counter()
            d.estimate_normals(o3d.geometry.KDTreeSearchParamHybrid(radius=2 * v, max_nn=30))
            t2 = time.perf_counter()
            o3d.pipelines.registration.compute_fpfh_feature(
                d, o3d.geometry.KDTreeSearchParamHybrid(radius=5 * v, max_nn=100))
            t3 = time.perf_counter()
            best = [min(x, y) for x, y in zip(best, (t1 - t0, t2 - t1, t3 - t2, t3 - t0))]
        out["time_open3d_s"] = dict(zip(("voxel", "normals", "fpfh", "total"), best))
        np.save(f_in, pts)
        ours_t = json.loads(run(args.bin, "pipeline", f_in, v, args.repeats))
        out["time_ours_s"] = {k[:-2]: ours_t[k] for k in ("voxel_s", "normals_s", "fpfh_s", "total_s")}
        out["time_ours_s"]["threads"] = ours_t["threads"]
        out["cpu_count"] = os.cpu_count()

    print(json.dumps(out, indent=2))


if __name__ == "__main__":
    main()
