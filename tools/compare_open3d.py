#!/usr/bin/env python3
"""Side-by-side comparison of `mireg pair` with Open3D's feature-matching RANSAC (and, when the
`kiss_matcher` package is installed, KISS-Matcher's global registration) on real data.

Usage (from the repository root, after `bash tools/setup_venv.sh peers` and `cargo build --release`):

    python3 tools/toolbox.py compare-open3d                      # all pairs, 10 poses each
    python3 tools/toolbox.py compare-open3d --pairs 3dmatch icl --poses 3 --skip-mireg
    python3 tools/toolbox.py compare-open3d --mireg target/release/mireg \\
        --mireg-variant levy= --mireg-variant uniform="--sampler uniform" --json-out /tmp/cmp.json

Protocol
--------
For every pair and each of ``--poses`` random initial poses P (numpy RNG seeded by --seed and the
pair, so poses do not depend on the --pairs selection; uniform random
rotation from a normalised Gaussian quaternion, translation uniform in a ball of radius
``--max-translation``, default 1 m) the source points are transformed by P and written once to a
temporary float64 ``.npy``; the target is written to a float64 ``.npy`` as well, so Open3D and mireg
get bit-identical inputs. The ground truth for the perturbed source is ``gt · P⁻¹``.

KISS-Matcher (in this process, on the same float64 arrays cast to float32, timed around ``estimate``):
``KISSMatcherConfig(voxel)`` at the pair's voxel, its other settings at their defaults; a global
registration without refinement, so its peer rows are Open3D global and ``mireg --no-icp``. It
refuses voxels below 1 cm: for the bunny (5 mm) both clouds and the voxel are scaled ×10 (all its
radii and noise bounds are gains times the voxel) and the translation is scaled back.

Open3D (in this process, timed with ``time.perf_counter``, file reading excluded, settings of
../shared/docs/DESIGN.md §3): voxel_down_sample(v); estimate_normals(Hybrid(2v, 30)); compute_fpfh_feature
(Hybrid(5v, 100)); registration_ransac_based_on_feature_matching(mutual_filter=False, max distance
1.5v, PointToPoint, ransac_n=3, checkers [EdgeLength(0.9), Distance(1.5v)],
RANSACConvergenceCriteria(100000, 0.999)). ``o3d.utility.random.seed`` is set per trial.
"Open3D global" time = downsampling + normals + FPFH + RANSAC for both clouds.
"Open3D global+ICP" adds a point-to-plane ICP (``registration_icp``) set up like mireg's default
refinement, so that the two "+ICP" rows differ only in the global stage: both clouds voxel-downsampled
at ``--icp-voxel-factor``·v (default 1.0·v, i.e. the RANSAC clouds, as mireg's default; 0 = reuse the
RANSAC clouds and their normals), target normals Hybrid(2·factor·v, 30), max correspondence distance ``--icp-factor``·v (default 1.0·v), Open3D's
default criteria (30 iterations). Its time (downsampling + normals + ICP) is added to the global time.
With the Open3D tutorial's 0.4·v on the RANSAC clouds, recall was the same on 3dmatch/bunny/icl
(5 poses each), but mireg's wider refinement rescues RANSAC poses that are 40–50° off on the
bunny, so a narrower Open3D ICP would not be a like-for-like comparison.

mireg: ``mireg pair SRC.npy TGT.npy --voxel v --seed S --json [variant args]`` in a subprocess, by
default twice per trial: as is ("mireg", which ends with its own ICP) and with ``--no-icp``
("mireg --no-icp"). Each mireg row is compared with the matching Open3D row: ``--no-icp`` variants
with "Open3D global", the others with "Open3D global+ICP". We record mireg's own
``timings_s.total`` (compute only, excludes file reading) and the subprocess wall time (process
start, file reading, everything); both time ratios are printed.

Metrics
-------
RE = rotation angle of R_gtᵀ·R_est in degrees. TE = ‖t_est − t_gt‖ in metres, where both transforms
are expressed for the *original* (unperturbed) source frame, i.e. the estimate for the perturbed
source is composed with P first (T_est·P vs gt). RE is identical in either frame; TE in the
perturbed frame would grow with the random translation of P (a lever arm of up to 1 m that turns
every degree of rotation error into ~1.7 cm of translation error) and make TE depend on P rather than
on the registration. The perturbed-frame TE is kept in the JSON rows as ``te_perturbed_m``.
Recall = fraction of trials with RE < thr_RE and TE < thr_TE: 15°/0.30 m (3DMatch convention) for
3dmatch and icl; 5°/0.60 m for kitti; 15°/0.03 m for the bunny (a 15 cm object: 0.30 m would accept
anything; 0.03 m is what 15° amounts to at the bunny's ~11 cm distance from its frame's origin).
Medians of RE/TE are given over the successful trials and over all trials (a crashed mireg run counts
as RE = TE = inf). Time ratios = median time of the matching Open3D method / median mireg
``timings_s.total`` and / median mireg wall time (> 1: mireg is faster).

Pairs
-----
3dmatch  redkitchen fragments 0 <- 6 (src.npy -> ref.npy, gt.npy maps src -> ref), voxel 0.05 m
bunny45  bun045 -> bun000, GT from bun.conf (world = R(q)ᵀ·x + t), voxel 0.005 m (the bunny is
         ~15 cm: ~1300 points after downsampling, FPFH radius 2.5 cm ≈ 1/6 of the object)
bunny90  bun090 -> bun000, same, voxel 0.005 m (~56 % overlap: the hard pair)
icl      ICL-NUIM livingroom1 rgbd5 frame 4 -> frame 0 (fixture PLYs, GT T0⁻¹·T4), voxel 0.05 m
         (depth 1–2.7 m, ~3600 points after downsampling; the frames are only ~10 cm apart, so it is
         the random initial pose that makes this pair a global-registration problem)
kitti    KITTI 000001.bin -> 000000.bin, voxel 0.5 m. No ground truth: the reference is a dense
         point-to-plane ICP (Open3D, full clouds, normals radius 1.0 m, distances 1.0 m then 0.2 m)
         started from the better (by ICP fitness) of the identity and an Open3D global estimate.
For every pair the script prints, as a check that the GT really aligns the clouds, the median
nearest-neighbour distance of the source after GT to the target, the overlap fraction (neighbour
closer than one voxel) and the median inside the overlap (partial overlap inflates the plain median),
also for the untransformed source and, for the bunny, the rejected R(q)·x + t reading of bun.conf.

Output: the Markdown tables on stdout; with ``--json-out FILE`` every per-trial row (pose P, seeds,
estimate, RE/TE, times, mireg's full JSON) plus the per-pair GT and checks. Default paths are
resolved from the repository containing this script, so it can be run from any directory.
"""
from __future__ import annotations

import argparse
import json
import math
import os
import platform
import shlex
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass, field

import numpy as np
import open3d as o3d

try:  # KISS-Matcher (Lim et al., ICRA 2025): optional, compared when installed (the `peers` group of tools/pyproject.toml).
    import kiss_matcher
except ImportError:
    kiss_matcher = None

REG = o3d.pipelines.registration
REPO = os.path.normpath(os.path.join(os.path.dirname(os.path.abspath(__file__)), ".."))
ALL_PAIRS = ["3dmatch", "bunny45", "bunny90", "icl", "kitti"]
# KISS-Matcher's smallest accepted voxel [m] (1.0.2: 5 mm refused, 1 cm accepted), and the voxel a
# smaller one is scaled up to.
KISS_MATCHER_MIN_VOXEL = 0.01
KISS_MATCHER_SCALED_VOXEL = 0.05


# --------------------------------------------------------------------------------------------------
# Geometry helpers
# --------------------------------------------------------------------------------------------------

def transform(T: np.ndarray, pts: np.ndarray) -> np.ndarray:
    """Apply a 4×4 rigid transform to N×3 points."""
    return pts @ T[:3, :3].T + T[:3, 3]


def quat_to_rot(qx: float, qy: float, qz: float, qw: float) -> np.ndarray:
    """Rotation matrix of a (not necessarily unit) quaternion in x, y, z, w order."""
    q = np.array([qx, qy, qz, qw], dtype=np.float64)
    x, y, z, w = q / np.linalg.norm(q)
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
        [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
        [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
    ])


def random_pose(rng: np.random.Generator, max_translation: float) -> np.ndarray:
    """Uniformly random rotation (normalised Gaussian quaternion) and a translation uniform in a ball."""
    T = np.eye(4)
    T[:3, :3] = quat_to_rot(*rng.normal(size=4))
    direction = rng.normal(size=3)
    direction /= np.linalg.norm(direction)
    T[:3, 3] = direction * max_translation * rng.uniform() ** (1.0 / 3.0)
    return T


def pose_errors(T_est: np.ndarray, T_gt: np.ndarray) -> tuple[float, float]:
    """(RE in degrees, TE in metres): angle of R_gtᵀ·R_est and ‖t_est − t_gt‖."""
    R = T_gt[:3, :3].T @ T_est[:3, :3]
    cos = np.clip((np.trace(R) - 1.0) / 2.0, -1.0, 1.0)
    return math.degrees(math.acos(cos)), float(np.linalg.norm(T_est[:3, 3] - T_gt[:3, 3]))


def to_pcd(pts: np.ndarray) -> o3d.geometry.PointCloud:
    return o3d.geometry.PointCloud(o3d.utility.Vector3dVector(np.ascontiguousarray(pts, dtype=np.float64)))


def nn_distances(src: np.ndarray, tgt: np.ndarray) -> np.ndarray:
    """Distance from each source point to its nearest target point."""
    return np.asarray(to_pcd(src).compute_point_cloud_distance(to_pcd(tgt)))


def median_nn_distance(src: np.ndarray, tgt: np.ndarray) -> float:
    return float(np.median(nn_distances(src, tgt)))


def alignment_check(src: np.ndarray, tgt: np.ndarray, radius: float) -> dict:
    """How well src lies on tgt: median NN distance over all points, and (because partial overlap
    inflates that median) the fraction of points with a neighbour within `radius` and their median."""
    d = nn_distances(src, tgt)
    near = d[d < radius]
    return {"median_nn_m": float(np.median(d)), "overlap_fraction": float(len(near) / len(d)),
            "median_nn_in_overlap_m": float(np.median(near)) if len(near) else math.nan}


# --------------------------------------------------------------------------------------------------
# Data loading and pair definitions
# --------------------------------------------------------------------------------------------------

def load_points(path: str) -> np.ndarray:
    """N×3 float64 points from .npy, KITTI .bin (float32 x,y,z,intensity), .ply or .pcd."""
    ext = os.path.splitext(path)[1].lower()
    if ext == ".npy":
        return np.load(path)[:, :3].astype(np.float64)
    if ext == ".bin":
        return np.fromfile(path, dtype=np.float32).reshape(-1, 4)[:, :3].astype(np.float64)
    pts = np.asarray(o3d.io.read_point_cloud(path).points, dtype=np.float64)
    if len(pts) == 0:
        raise ValueError(f"no points read from {path}")
    return pts


def read_redwood_log(path: str) -> dict[int, np.ndarray]:
    """Redwood/3DMatch .log: per entry a header line whose first number is the frame id, then 4 rows."""
    with open(path) as f:
        lines = [ln.split() for ln in f if ln.strip()]
    poses = {}
    for k in range(0, len(lines), 5):
        poses[int(lines[k][0])] = np.array(lines[k + 1:k + 5], dtype=np.float64)
    return poses


def read_bun_conf(path: str) -> dict[str, np.ndarray]:
    """Stanford bun.conf `bmesh FILE tx ty tz qx qy qz qw` -> world_from_scan, world = R(q)ᵀ·x + t."""
    poses = {}
    with open(path) as f:
        for line in f:
            tok = line.split()
            if tok and tok[0] == "bmesh":
                t = np.array(tok[2:5], dtype=np.float64)
                T = np.eye(4)
                T[:3, :3] = quat_to_rot(*map(float, tok[5:9])).T
                T[:3, 3] = t
                poses[tok[1]] = T
    return poses


@dataclass
class Pair:
    """One registration problem: source -> target with the ground truth target_from_source."""
    name: str
    source: np.ndarray
    target: np.ndarray
    gt: np.ndarray
    voxel: float
    re_thr_deg: float
    te_thr_m: float
    gt_note: str
    checks: dict = field(default_factory=dict)


class Missing(Exception):
    """Raised when a pair's files are absent (the pair is then skipped with a message)."""


def need(*paths: str) -> None:
    missing = [p for p in paths if not os.path.exists(p)]
    if missing:
        raise Missing("missing " + ", ".join(missing))


def nearest_rigid(T: np.ndarray) -> np.ndarray:
    """T with its rotation block replaced by the nearest rotation (U·Vᵀ of its SVD, det > 0)."""
    U, _, Vt = np.linalg.svd(T[:3, :3])
    if np.linalg.det(U @ Vt) < 0:
        raise ValueError("ground-truth rotation block is a reflection")
    out = T.copy()
    out[:3, :3] = U @ Vt
    return out


def make_3dmatch(data: str, fixtures: str) -> Pair:
    d = os.path.join(data, "3dmatch_redkitchen_0_6")
    need(*(os.path.join(d, f) for f in ("src.npy", "ref.npy", "gt.npy")))
    # gt.npy's rotation block is not orthonormal (singular values 0.99996–0.99997): measured
    # against it, even its own nearest rotation shows a rotation error of 0.58° (acos of a
    # trace below 3). Snap it to the nearest rotation, as `mireg pair --gt` does
    # (tools/check_3dmatch_gt.py prints both).
    gt = nearest_rigid(np.load(os.path.join(d, "gt.npy")))
    return Pair("3dmatch", load_points(os.path.join(d, "src.npy")), load_points(os.path.join(d, "ref.npy")),
                gt, 0.05, 15.0, 0.30, "gt.npy (3DMatch gt.log entry 0 6), rotation snapped to SO(3)")


def make_bunny(angle: int):
    def build(data: str, fixtures: str) -> Pair:
        d = os.path.join(data, "bunny")
        src_name = f"bun{angle:03d}.ply"
        need(os.path.join(d, "bun000.ply"), os.path.join(d, src_name), os.path.join(d, "bun.conf"))
        poses = read_bun_conf(os.path.join(d, "bun.conf"))
        gt = np.linalg.inv(poses["bun000.ply"]) @ poses[src_name]
        src, tgt = load_points(os.path.join(d, src_name)), load_points(os.path.join(d, "bun000.ply"))
        # The "obvious" reading R(q)·x + t, to show that the README's convention is the right one.
        wrong = {k: v.copy() for k, v in poses.items()}
        for v in wrong.values():
            v[:3, :3] = v[:3, :3].T
        gt_wrong = np.linalg.inv(wrong["bun000.ply"]) @ wrong[src_name]
        checks = {"with R(q)·x + t instead": alignment_check(transform(gt_wrong, src), tgt, 0.005)}
        return Pair(f"bunny{angle}", src, tgt, gt, 0.005, 15.0, 0.03, "bun.conf, world = R(q)ᵀ·x + t", checks)
    return build


def make_icl(data: str, fixtures: str) -> Pair:
    d = os.path.join(fixtures, "icl_nuim")
    paths = [os.path.join(d, f) for f in ("rgbd5_00004.ply", "rgbd5_00000.ply", "trajectory.log")]
    need(*paths)
    poses = read_redwood_log(paths[2])
    gt = np.linalg.inv(poses[0]) @ poses[4]
    return Pair("icl", load_points(paths[0]), load_points(paths[1]), gt, 0.05, 15.0, 0.30,
                "trajectory.log, T0⁻¹·T4")


def open3d_features(pts: np.ndarray, voxel: float):
    """Open3D recipe: voxel grid, normals Hybrid(2v, 30), FPFH Hybrid(5v, 100)."""
    down = to_pcd(pts).voxel_down_sample(voxel)
    down.estimate_normals(o3d.geometry.KDTreeSearchParamHybrid(radius=2 * voxel, max_nn=30))
    fpfh = REG.compute_fpfh_feature(down, o3d.geometry.KDTreeSearchParamHybrid(radius=5 * voxel, max_nn=100))
    return down, fpfh


def open3d_ransac(src_down, tgt_down, src_fpfh, tgt_fpfh, voxel: float):
    dist = 1.5 * voxel
    return REG.registration_ransac_based_on_feature_matching(
        src_down, tgt_down, src_fpfh, tgt_fpfh, False, dist,
        REG.TransformationEstimationPointToPoint(False), 3,
        [REG.CorrespondenceCheckerBasedOnEdgeLength(0.9), REG.CorrespondenceCheckerBasedOnDistance(dist)],
        REG.RANSACConvergenceCriteria(100000, 0.999))


def make_kitti(data: str, fixtures: str) -> Pair:
    """KITTI has no GT here: build a reference with dense point-to-plane ICP (see module docstring)."""
    d = os.path.join(data, "kitti_pair")
    need(os.path.join(d, "000001.bin"), os.path.join(d, "000000.bin"))
    src, tgt = load_points(os.path.join(d, "000001.bin")), load_points(os.path.join(d, "000000.bin"))
    voxel = 0.5
    o3d.utility.random.seed(0)
    sd, sf = open3d_features(src, voxel)
    td, tf = open3d_features(tgt, voxel)
    global_est = open3d_ransac(sd, td, sf, tf, voxel).transformation
    src_pcd, tgt_pcd = to_pcd(src), to_pcd(tgt)
    tgt_pcd.estimate_normals(o3d.geometry.KDTreeSearchParamHybrid(radius=1.0, max_nn=30))
    best = None
    for label, init in (("identity", np.eye(4)), ("open3d_global", global_est)):
        T = init
        for thr in (1.0, 0.2):
            res = REG.registration_icp(src_pcd, tgt_pcd, thr, T, REG.TransformationEstimationPointToPlane(),
                                       REG.ICPConvergenceCriteria(max_iteration=60))
            T = res.transformation
        if best is None or (res.fitness, -res.inlier_rmse) > (best[1].fitness, -best[1].inlier_rmse):
            best = (label, res)
    label, res = best
    T = res.transformation
    yaw = math.degrees(math.atan2(T[1, 0], T[0, 0]))
    angle = pose_errors(T, np.eye(4))[0]
    note = (f"NO GT: dense point-to-plane ICP reference (from {label}; fitness {res.fitness:.3f}, "
            f"rmse {res.inlier_rmse:.3f} m; t = [{T[0, 3]:.3f}, {T[1, 3]:.3f}, {T[2, 3]:.3f}] m, "
            f"rotation {angle:.2f}°, yaw {yaw:.2f}°)")
    re_g, te_g = pose_errors(global_est, T)
    checks = {"reference_from": label, "open3d_global_vs_reference_RE_deg": re_g,
              "open3d_global_vs_reference_TE_m": te_g}
    return Pair("kitti", src, tgt, T, voxel, 5.0, 0.60, note, checks)


BUILDERS = {"3dmatch": make_3dmatch, "bunny45": make_bunny(45), "bunny90": make_bunny(90),
            "icl": make_icl, "kitti": make_kitti}


# --------------------------------------------------------------------------------------------------
# The two methods
# --------------------------------------------------------------------------------------------------

def run_open3d(src: np.ndarray, tgt: np.ndarray, voxel: float, seed: int, icp_factor: float,
               icp_voxel_factor: float) -> dict:
    """Open3D global registration (+ point-to-plane ICP), timed per stage (file reading excluded)."""
    o3d.utility.random.seed(seed)
    t0 = time.perf_counter()
    src_down, src_fpfh = open3d_features(src, voxel)
    tgt_down, tgt_fpfh = open3d_features(tgt, voxel)
    t1 = time.perf_counter()
    ransac = open3d_ransac(src_down, tgt_down, src_fpfh, tgt_fpfh, voxel)
    t2 = time.perf_counter()
    if icp_voxel_factor > 0:
        icp_voxel = icp_voxel_factor * voxel
        src_icp, tgt_icp = to_pcd(src).voxel_down_sample(icp_voxel), to_pcd(tgt).voxel_down_sample(icp_voxel)
        tgt_icp.estimate_normals(o3d.geometry.KDTreeSearchParamHybrid(radius=2 * icp_voxel, max_nn=30))
    else:
        src_icp, tgt_icp = src_down, tgt_down
    icp = REG.registration_icp(src_icp, tgt_icp, icp_factor * voxel, ransac.transformation,
                               REG.TransformationEstimationPointToPlane(), REG.ICPConvergenceCriteria())
    t3 = time.perf_counter()
    return {
        "global": {"T": ransac.transformation, "time_s": t2 - t0, "features_s": t1 - t0, "ransac_s": t2 - t1,
                   "fitness": ransac.fitness, "inlier_rmse_m": ransac.inlier_rmse,
                   "num_inliers": len(ransac.correspondence_set),
                   "src_down": len(src_down.points), "tgt_down": len(tgt_down.points)},
        "global+icp": {"T": icp.transformation, "time_s": t3 - t0, "icp_s": t3 - t2,
                       "fitness": icp.fitness, "inlier_rmse_m": icp.inlier_rmse},
    }


def run_kiss_matcher(src: np.ndarray, tgt: np.ndarray, voxel: float) -> dict:
    """KISS-Matcher's global registration at the pair's voxel (its other settings at their defaults),
    timed in-process around `estimate` (its downsampling, features, matching and solver).

    KISS-Matcher refuses voxels below 1 cm. Its radii and noise bounds are all gains times the voxel,
    so below that the clouds and the voxel are scaled up together (the bunny: ×10, to 5 cm) and the
    translation is scaled back: the same registration at another unit."""
    scale = 1.0 if voxel >= KISS_MATCHER_MIN_VOXEL else KISS_MATCHER_SCALED_VOXEL / voxel
    matcher = kiss_matcher.KISSMatcher(kiss_matcher.KISSMatcherConfig(voxel * scale))
    src32, tgt32 = (scale * src).astype(np.float32), (scale * tgt).astype(np.float32)
    t0 = time.perf_counter()
    solution = matcher.estimate(src32, tgt32)
    t1 = time.perf_counter()
    T = np.eye(4)
    T[:3, :3] = np.asarray(solution.rotation, dtype=np.float64)
    T[:3, 3] = np.asarray(solution.translation, dtype=np.float64).reshape(3) / scale
    return {"T": T, "time_s": t1 - t0, "valid": bool(solution.valid), "scale": scale,
            "num_inliers": int(matcher.get_num_final_inliers())}


def run_mireg(binary: str, src_path: str, tgt_path: str, voxel: float, seed: int, extra: list[str],
              timeout: float) -> dict:
    """`mireg pair ... --json` in a subprocess; returns the parsed JSON plus wall time, or an error."""
    cmd = [binary, "pair", src_path, tgt_path, "--voxel", repr(voxel), "--seed", str(seed), "--json", *extra]
    t0 = time.perf_counter()
    try:
        proc = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout)
    except subprocess.TimeoutExpired:
        return {"error": f"timeout after {timeout} s", "wall_s": time.perf_counter() - t0, "cmd": cmd}
    wall = time.perf_counter() - t0
    # exit 1: the registration failed its checks (its result is still printed); 2: an error.
    if proc.returncode not in (0, 1):
        return {"error": f"exit {proc.returncode}: {proc.stderr.strip()[-500:]}", "wall_s": wall, "cmd": cmd}
    try:
        out = json.loads(proc.stdout)
        T = np.array(out["target_from_source"], dtype=np.float64).reshape(4, 4)
        total = float(out["timings_s"]["total"])
    except (ValueError, KeyError, TypeError) as e:
        return {"error": f"bad JSON ({e}): {proc.stdout[:300]!r}", "wall_s": wall, "cmd": cmd}
    return {"T": T, "time_s": total, "wall_s": wall, "json": out, "cmd": cmd}


# --------------------------------------------------------------------------------------------------
# Evaluation and reporting
# --------------------------------------------------------------------------------------------------

def evaluate(pair: Pair, T_est: np.ndarray | None, P: np.ndarray) -> dict:
    """RE/TE of an estimate for the perturbed source, in the original source frame (see docstring)."""
    if T_est is None:
        return {"re_deg": math.inf, "te_m": math.inf, "te_perturbed_m": math.inf, "success": False}
    re, te = pose_errors(T_est @ P, pair.gt)
    _, te_p = pose_errors(T_est, pair.gt @ np.linalg.inv(P))
    return {"re_deg": re, "te_m": te, "te_perturbed_m": te_p,
            "success": bool(re < pair.re_thr_deg and te < pair.te_thr_m)}


def median(values) -> float:
    vals = [v for v in values if v is not None and not (isinstance(v, float) and math.isnan(v))]
    return float(np.median(vals)) if vals else math.nan


def fmt(x: float, digits: int = 3) -> str:
    if x is None or (isinstance(x, float) and math.isnan(x)):
        return "–"
    if math.isinf(x):
        return "inf"
    return f"{x:.{digits}f}"


def times(ratio: float) -> str:
    return "–" if math.isnan(ratio) else f"{ratio:.2f}×"


def summarise(rows: list[dict], pairs: list[Pair], methods: list[str], baselines: dict[str, str]) -> str:
    """Markdown table: one line per (pair, method); mireg rows carry time ratios vs their baseline."""
    head = ("| pair | method | trials | recall | med RE succ (°) | med TE succ (m) | med RE all (°) "
            "| med TE all (m) | med time (s) | med wall (s) | O3D / mireg time | O3D / mireg wall |")
    lines = [head, "|" + "---|" * (head.count("|") - 1)]
    for pair in pairs:
        for method in methods:
            rs = [r for r in rows if r["pair"] == pair.name and r["method"] == method]
            if not rs:
                continue
            ok = [r for r in rs if r["success"]]
            errors = sum(1 for r in rs if r.get("error"))
            t = median(r["time_s"] for r in rs if not r.get("error"))
            wall = median(r.get("wall_s") for r in rs if r.get("wall_s") is not None and not r.get("error"))
            ratios = "| | "
            if method in baselines:
                base = baselines[method]
                o3d_time = median(r["time_s"] for r in rows if r["pair"] == pair.name and r["method"] == base)
                short = base.replace("open3d ", "")
                ratios = f"| {times(o3d_time / t)} (vs {short}) | {times(o3d_time / wall)} "
            label = method + (f" ({errors} errors)" if errors else "")
            lines.append(
                f"| {pair.name} | {label} | {len(rs)} | {len(ok)}/{len(rs)} = {len(ok) / len(rs):.2f} "
                f"| {fmt(median(r['re_deg'] for r in ok), 2)} | {fmt(median(r['te_m'] for r in ok))} "
                f"| {fmt(median(r['re_deg'] for r in rs), 2)} | {fmt(median(r['te_m'] for r in rs))} "
                f"| {fmt(t)} | {fmt(wall)} {ratios}|")
    return "\n".join(lines)


def kiss_table(rows: list[dict], pairs: list[Pair], labels: list[str]) -> str:
    """Per pair: KISS-Matcher's recall and median time against each mireg variant's, and the ratio of
    the median times (> 1: mireg is faster)."""
    head = "| pair | KISS-Matcher recall, med time (s) | mireg variant | recall, med time (s) | KISS-Matcher / mireg time |"
    lines = [head, "|" + "---|" * (head.count("|") - 1)]
    for pair in pairs:
        def cell(method):
            rs = [r for r in rows if r["pair"] == pair.name and r["method"] == method]
            ok = sum(1 for r in rs if r["success"])
            return rs, ok, median(r["time_s"] for r in rs if r.get("time_s") is not None)
        krs, kok, kt = cell("kiss-matcher")
        if not krs:
            continue
        for label in labels:
            mrs, mok, mt = cell(label)
            if mrs:
                lines.append(f"| {pair.name} | {kok}/{len(krs)}, {fmt(kt)} | {label} | {mok}/{len(mrs)}, {fmt(mt)} "
                             f"| {times(kt / mt)} |")
    return "\n".join(lines)


def details(rows: list[dict], pairs: list[Pair], methods: list[str]) -> str:
    """Second table: per-stage times and search statistics (medians)."""
    head = ("| pair | method | features (s) | RANSAC (s) | ICP (s) | hypotheses | best_found_at | prerejected "
            "| correspondences | inliers | fitness |")
    lines = [head, "|" + "---|" * (head.count("|") - 1)]
    for pair in pairs:
        for method in methods:
            rs = [r for r in rows if r["pair"] == pair.name and r["method"] == method and not r.get("error")]
            if not rs:
                continue

            def m(key):
                return median(r.get(key) for r in rs)
            lines.append(f"| {pair.name} | {method} | {fmt(m('features_s'))} | {fmt(m('ransac_s'))} "
                         f"| {fmt(m('icp_s'))} | {fmt(m('hypotheses'), 0)} | {fmt(m('best_found_at'), 0)} "
                         f"| {fmt(m('prerejected'), 0)} "
                         f"| {fmt(m('num_correspondences'), 0)} | {fmt(m('num_inliers'), 0)} "
                         f"| {fmt(m('fitness'))} |")
    return "\n".join(lines)


def machine_header() -> str:
    model, cores = platform.processor() or "?", os.cpu_count()
    try:
        out = subprocess.run(["lscpu"], capture_output=True, text=True).stdout
        info = dict(ln.split(":", 1) for ln in out.splitlines() if ":" in ln)
        model = info.get("Model name", model).strip()
        per_socket = int(info.get("Core(s) per socket", "0"))
        sockets = int(info.get("Socket(s)", "1"))
        cores = f"{per_socket * sockets} cores, {info.get('CPU(s)', '?').strip()} CPUs"
    except (OSError, ValueError):
        pass
    load = ", load average %.2f" % os.getloadavg()[0] if hasattr(os, "getloadavg") else ""
    return f"machine: {model}, {cores}{load}; Open3D {o3d.__version__}; numpy {np.__version__}; Python {platform.python_version()}"


def binary_identity(path: str) -> str:
    """`mireg --version` and a short SHA-256 of the binary, so results can be tied to a build."""
    import hashlib
    try:
        out = subprocess.run([path, "--version"], capture_output=True, text=True, timeout=10).stdout.strip()
        version = out.splitlines()[0] if out else "?"
    except (OSError, subprocess.TimeoutExpired):
        version = "?"
    with open(path, "rb") as f:
        digest = hashlib.sha256(f.read()).hexdigest()[:12]
    built = time.strftime("%Y-%m-%d %H:%M", time.localtime(os.path.getmtime(path)))
    return f"{os.path.abspath(path)} ({version or '?'}, sha256 {digest}, built {built})"


def parse_variants(specs: list[str] | None) -> list[tuple[str, list[str]]]:
    """`--mireg-variant LABEL=ARGS` -> [("mireg LABEL", [args...])]; default: as is and --no-icp."""
    if not specs:
        return [("mireg", []), ("mireg --no-icp", ["--no-icp"])]
    out = []
    for spec in specs:
        label, _, argstr = spec.partition("=")
        out.append((f"mireg {label}".strip(), shlex.split(argstr)))
    return out


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--pairs", nargs="+", choices=ALL_PAIRS, default=ALL_PAIRS, help="pairs to run (default all)")
    ap.add_argument("--poses", type=int, default=10, help="random initial poses per pair (default 10)")
    ap.add_argument("--seed", type=int, default=0, help="seed of the pose RNG and of the per-trial seeds")
    ap.add_argument("--max-translation", type=float, default=1.0, help="radius of the random translation [m]")
    ap.add_argument("--data", default=os.path.relpath(os.path.join(REPO, "..", "shared", "data")),
                    help="shared data directory (default: ../shared/data next to the repository)")
    ap.add_argument("--fixtures", default=os.path.relpath(os.path.join(REPO, "fixtures")),
                    help="fixtures directory with icl_nuim/ (default: the repository's fixtures)")
    ap.add_argument("--mireg", default=os.path.relpath(os.path.join(REPO, "target", "release", "mireg")),
                    help="mireg binary (default: the repository's target/release/mireg)")
    ap.add_argument("--mireg-variant", action="append", metavar="LABEL=ARGS",
                    help="extra `mireg pair` arguments under a label, repeatable, e.g. "
                         "uniform=\"--sampler uniform\" (default: `levy=` and `--no-icp=--no-icp`)")
    ap.add_argument("--skip-mireg", action="store_true", help="run the Open3D side only")
    ap.add_argument("--skip-kiss-matcher", action="store_true",
                    help="leave KISS-Matcher out (it is run when the kiss_matcher package is installed)")
    ap.add_argument("--timeout", type=float, default=300.0, help="timeout per mireg run [s]")
    ap.add_argument("--icp-factor", type=float, default=1.0,
                    help="ICP max correspondence distance in voxels for 'open3d global+icp' (default 1.0)")
    ap.add_argument("--icp-voxel-factor", type=float, default=1.0,
                    help="ICP cloud voxel in voxels for 'open3d global+icp' (default 1.0, as mireg; 0 = RANSAC clouds)")
    ap.add_argument("--json-out", help="write all per-trial rows (and pair info) to this JSON file")
    ap.add_argument("--inprocess", action="store_true",
                    help="also run mireg in this process through its Python package (pip install "
                         "./python): row 'mireg (in-process)', timed like Open3D with perf_counter "
                         "around the call, beside its own timings_s.total")
    args = ap.parse_args()
    mireg_py = None
    if args.inprocess:
        try:
            import mireg as mireg_py
        except ImportError as e:
            ap.error(f"--inprocess needs the mireg Python package in this venv ({e}): "
                     "tools/.venv-peers/bin/pip install ./python")

    variants = [] if args.skip_mireg else parse_variants(args.mireg_variant)
    if variants and not os.path.isfile(args.mireg):
        ap.error(f"mireg binary not found at {args.mireg} (build it or pass --mireg PATH / --skip-mireg)")
    with_kiss = kiss_matcher is not None and not args.skip_kiss_matcher
    methods = (["open3d global", "open3d global+icp"] + (["kiss-matcher"] if with_kiss else [])
               + [label for label, _ in variants] + (["mireg (in-process)"] if mireg_py else []))
    baselines = {label: "open3d global" if "--no-icp" in extra else "open3d global+icp" for label, extra in variants}
    baselines["mireg (in-process)"] = "open3d global+icp"

    mireg_id = binary_identity(args.mireg) if variants else "not run (--skip-mireg)"
    print(f"# mireg pair vs Open3D RANSAC\n\n{machine_header()}\nmireg: {mireg_id}")
    print("KISS-Matcher: " + (f"kiss_matcher {getattr(kiss_matcher, '__version__', '?')}" if with_kiss
                              else "not run" + (" (--skip-kiss-matcher)" if kiss_matcher else " (not installed)")))
    print(f"poses per pair: {args.poses}, seed {args.seed}, random translation ≤ {args.max_translation} m; "
          f"Open3D ICP: distance {args.icp_factor}·voxel on clouds at {args.icp_voxel_factor}·voxel\n")

    rows: list[dict] = []
    pairs: list[Pair] = []
    with tempfile.TemporaryDirectory(prefix="mireg_cmp_") as tmp:
        for name in args.pairs:
            try:
                pair = BUILDERS[name](args.data, args.fixtures)
            except Missing as e:
                print(f"SKIP {name}: {e}", flush=True)
                continue
            pairs.append(pair)
            print(f"{name}: {len(pair.source)} -> {len(pair.target)} points, voxel {pair.voxel} m, "
                  f"recall RE < {pair.re_thr_deg}° and TE < {pair.te_thr_m} m; GT: {pair.gt_note}")
            pair.checks["after GT"] = alignment_check(transform(pair.gt, pair.source), pair.target, pair.voxel)
            pair.checks["untransformed"] = alignment_check(pair.source, pair.target, pair.voxel)
            print(f"  GT check (overlap = NN distance < voxel {pair.voxel} m):")
            for label, value in pair.checks.items():
                if isinstance(value, dict):
                    print(f"    {label:>24}: median NN {value['median_nn_m'] * 1000:.2f} mm, overlap "
                          f"{value['overlap_fraction']:.2f}, median NN in overlap "
                          f"{value['median_nn_in_overlap_m'] * 1000:.2f} mm")
                else:
                    print(f"    {label:>24}: {fmt(value, 4) if isinstance(value, float) else value}")
            sys.stdout.flush()
            # One RNG per pair, so a pair's poses do not depend on which other pairs were selected.
            rng = np.random.default_rng([args.seed, ALL_PAIRS.index(name)])
            tgt_path = os.path.join(tmp, f"{name}_target.npy")
            np.save(tgt_path, pair.target)
            for trial in range(args.poses):
                P = random_pose(rng, args.max_translation)
                seed = args.seed * 100003 + trial + 1
                src = transform(P, pair.source)
                src_path = os.path.join(tmp, f"{name}_source_{trial}.npy")
                np.save(src_path, src)
                base = {"pair": name, "trial": trial, "seed": seed, "P": P.tolist(), "voxel": pair.voxel}

                o3d_res = run_open3d(src, pair.target, pair.voxel, seed, args.icp_factor, args.icp_voxel_factor)
                for method, res in (("open3d global", o3d_res["global"]), ("open3d global+icp", o3d_res["global+icp"])):
                    row = {**base, "method": method, **{k: v for k, v in res.items() if k != "T"},
                           "T": res["T"].tolist(), **evaluate(pair, res["T"], P)}
                    rows.append(row)
                line = [f"  [{name} {trial + 1}/{args.poses}] O3D RE {rows[-2]['re_deg']:.2f}° "
                        f"TE {rows[-2]['te_m']:.3f} m {rows[-2]['time_s']:.2f} s; +ICP RE {rows[-1]['re_deg']:.2f}°"]
                if with_kiss:
                    res = run_kiss_matcher(src, pair.target, pair.voxel)
                    rows.append({**base, "method": "kiss-matcher", **{k: v for k, v in res.items() if k != "T"},
                                 "T": res["T"].tolist(), **evaluate(pair, res["T"], P)})
                    line.append(f"KISS-Matcher RE {rows[-1]['re_deg']:.2f}° TE {rows[-1]['te_m']:.3f} m "
                                f"{rows[-1]['time_s']:.2f} s")

                for label, extra_args in variants:
                    res = run_mireg(args.mireg, src_path, tgt_path, pair.voxel, seed, extra_args, args.timeout)
                    row = {**base, "method": label, "cmd": " ".join(res["cmd"]), "wall_s": res["wall_s"]}
                    if "error" in res:
                        row.update(error=res["error"], time_s=None, **evaluate(pair, None, P))
                        line.append(f"{label} ERROR {res['error'][:120]}")
                    else:
                        j = res["json"]
                        row.update({k: j.get(k) for k in ("num_correspondences", "num_inliers", "hypotheses",
                                                          "best_found_at", "prerejected", "converged", "fitness",
                                                          "inlier_rmse_m")})
                        stages = j.get("timings_s") or {}
                        row.update(time_s=res["time_s"], timings_s=stages, T=res["T"].tolist(),
                                   features_s=sum(stages.get(k, 0.0) for k in ("downsample", "normals", "features")),
                                   ransac_s=sum(stages.get(k, 0.0) for k in ("matching", "ranking", "ransac")),
                                   icp_s=stages.get("icp"),
                                   mireg_json=j, **evaluate(pair, res["T"], P))
                        line.append(f"{label} RE {row['re_deg']:.2f}° TE {row['te_m']:.3f} m "
                                    f"{row['time_s']:.2f} s (wall {row['wall_s']:.2f} s)")
                    rows.append(row)
                if mireg_py is not None:
                    t0 = time.perf_counter()
                    r = mireg_py.register_pair(src, pair.target, voxel=pair.voxel, seed=seed)
                    t1 = time.perf_counter()
                    row = {**base, "method": "mireg (in-process)", "time_s": t1 - t0,
                           "rust_total_s": r.timings["total"], "T": r.transformation.tolist(),
                           "num_inliers": r.inliers, "fitness": r.fitness,
                           **evaluate(pair, r.transformation, P)}
                    rows.append(row)
                    line.append(f"in-process RE {row['re_deg']:.2f}° {row['time_s']:.3f} s "
                                f"(Rust total {row['rust_total_s']:.3f} s)")
                print("; ".join(line), flush=True)
                os.remove(src_path)

    if not pairs:
        print("no pair could be run (all skipped)", file=sys.stderr)
        return 1
    print("\n## Results\n")
    print(summarise(rows, pairs, methods, baselines))
    if with_kiss:
        print("\n## KISS-Matcher side by side (global registration, no refinement)\n")
        print(kiss_table(rows, pairs, [label for label, _ in variants]))
    print("\n## Details (medians)\n")
    print(details(rows, pairs, methods))
    print("\nRE = angle(R_gtᵀ R_est); TE = ‖t_est − t_gt‖ in the original source frame (estimate composed "
          "with the random pose). 'med time' is compute only (Open3D: in-process perf_counter, downsampling "
          "to RANSAC/ICP; mireg: its timings_s.total); 'med wall' is mireg's subprocess wall time (process "
          "start and file reading included). Ratios: median time of the Open3D row named in brackets / "
          "mireg's median time or wall time; > 1 means mireg is faster.")
    over = [r for r in rows if r.get("time_s") is not None and r.get("wall_s") is not None
            and r["time_s"] > r["wall_s"]]
    if over:
        print(f"WARNING: in {len(over)} mireg runs timings_s.total exceeds the process wall time "
              f"(e.g. {over[0]['time_s']:.3f} s > {over[0]['wall_s']:.3f} s): mireg's 'total' is not a "
              "wall-clock time (stages that run concurrently are summed?); the wall ratio is the safer one.")
    for pair in pairs:
        if pair.name == "kitti":
            print(f"kitti: {pair.gt_note}")

    if args.json_out:
        out = {"machine": machine_header(), "mireg": mireg_id, "args": vars(args),
               "pairs": [{"name": p.name, "voxel": p.voxel, "gt": p.gt.tolist(), "gt_note": p.gt_note,
                          "re_thr_deg": p.re_thr_deg, "te_thr_m": p.te_thr_m, "checks": p.checks,
                          "source_points": len(p.source), "target_points": len(p.target)} for p in pairs],
               "rows": rows}
        with open(args.json_out, "w") as f:
            json.dump(out, f, indent=1, default=lambda x: x.tolist() if isinstance(x, np.ndarray) else str(x))
        print(f"\nper-trial rows written to {args.json_out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
