"""Open3D 0.20 side of the matching / ICP comparison (peer timing, not needed by cargo test).

Usage: python tools/peer_open3d_match_icp.py [DATA_DIR] [OUT_DIR] [VOXEL_M]
DATA_DIR defaults to ../shared/data/3dmatch_redkitchen_0_6 (src.npy, ref.npy, gt.npy).
Writes OUT_DIR/{src,ref}_{points,normals,fpfh}.npy (float64 xyz, float32 FPFH N×33) for
`cargo run --release --example peer_compare -- OUT_DIR`, and prints Open3D's timings for
FPFH correspondence search and point-to-plane ICP on the same data.
"""
import sys
import time

import numpy as np
import open3d as o3d

data = sys.argv[1] if len(sys.argv) > 1 else "../shared/data/3dmatch_redkitchen_0_6"
out = sys.argv[2] if len(sys.argv) > 2 else "/tmp/mireg_peer"
voxel = float(sys.argv[3]) if len(sys.argv) > 3 else 0.0
import os

os.makedirs(out, exist_ok=True)
reg = o3d.pipelines.registration


def prepare(name):
    pcd = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(np.load(f"{data}/{name}.npy")))
    if voxel > 0:
        pcd = pcd.voxel_down_sample(voxel)
    v = voxel if voxel > 0 else 0.05
    pcd.estimate_normals(o3d.geometry.KDTreeSearchParamHybrid(radius=2 * v, max_nn=30))
    fpfh = reg.compute_fpfh_feature(pcd, o3d.geometry.KDTreeSearchParamHybrid(radius=5 * v, max_nn=100))
    np.save(f"{out}/{name}_points.npy", np.asarray(pcd.points))
    np.save(f"{out}/{name}_normals.npy", np.asarray(pcd.normals))
    np.save(f"{out}/{name}_fpfh.npy", np.asarray(fpfh.data).T.astype(np.float32).copy())
    return pcd, fpfh


src, src_fpfh = prepare("src")
ref, ref_fpfh = prepare("ref")
gt = np.load(f"{data}/gt.npy")
# 3DMatch's gt.log is printed with few digits: its rotation is off-orthonormal by ~7e-5, and
# Open3D's ICP carries that into its result. Use the nearest rotation (SVD), as mireg does.
u, _, vt = np.linalg.svd(gt[:3, :3])
gt[:3, :3] = u @ np.diag([1.0, 1.0, np.linalg.det(u @ vt)]) @ vt
np.save(f"{out}/gt.npy", gt)
print(f"Open3D {o3d.__version__}, threads: default; src {len(src.points)} pts, ref {len(ref.points)} pts")


def best_of(n, f):
    best, result = float("inf"), None
    for _ in range(n):
        t = time.perf_counter()
        result = f()
        best = min(best, time.perf_counter() - t)
    return best, result


for mutual in (False, True):
    t, corr = best_of(3, lambda: reg.correspondences_from_features(src_fpfh, ref_fpfh, mutual_filter=mutual))
    print(f"correspondences_from_features mutual={mutual}: {t * 1e3:.1f} ms, {len(corr)} pairs")

# ICP from the ground truth perturbed by 5 deg about (1,1,0.2) and (0.06,-0.05,0.06) m,
# the same perturbation as examples/peer_compare.rs.
axis = np.array([1.0, 1.0, 0.2])
axis /= np.linalg.norm(axis)
delta = np.eye(4)
delta[:3, :3] = o3d.geometry.get_rotation_matrix_from_axis_angle(axis * np.deg2rad(5.0))
delta[:3, 3] = [0.06, -0.05, 0.06]
init = gt @ delta
crit = reg.ICPConvergenceCriteria(relative_fitness=1e-6, relative_rmse=1e-6, max_iteration=30)
t, res = best_of(3, lambda: reg.registration_icp(src, ref, 0.1, init, reg.TransformationEstimationPointToPlane(), crit))
err = np.linalg.inv(gt) @ res.transformation
angle = np.degrees(np.arccos(np.clip((np.trace(err[:3, :3]) - 1) / 2, -1, 1)))
print(f"registration_icp point-to-plane (max dist 0.1 m): {t * 1e3:.1f} ms, fitness {res.fitness:.4f}, "
      f"rmse {res.inlier_rmse * 1e3:.2f} mm, error vs gt {angle:.3f} deg / {np.linalg.norm(err[:3, 3]) * 1e3:.1f} mm")
ev = reg.evaluate_registration(src, ref, 0.1, res.transformation)
print(f"evaluate_registration at that pose: fitness {ev.fitness:.9f} rmse {ev.inlier_rmse:.9f}")
np.save(f"{out}/open3d_icp_target_from_source.npy", np.ascontiguousarray(res.transformation))
