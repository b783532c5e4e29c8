#!/usr/bin/env python3
"""Compare mireg's pose-graph optimum (src/graph, via examples/pose_graph_g2o.rs) with GTSAM's.

Builds seeded synthetic graphs — a noisy square loop and a sphere-like graph of rings, each with loop
edges, and both again with false loop edges under a Cauchy kernel — writes them as g2o, optimises them
with our example and with GTSAM's LevenbergMarquardtOptimizer on the same noise models
(noiseModel.Gaussian.Information; robust loop edges: noiseModel.Robust.Create(mEstimator.Cauchy.Create(k),
...) or GemanMcClure), node 0 fixed by a tight PriorFactorPose3, and prints per graph the maximum pose difference
(rotation angle [rad], translation [m]) and both final costs. Target: the same optimum to 1e-6.

The edge error must be GTSAM's BetweenFactor<Pose3> with the full SE(3) logarithm; the script checks
that BetweenFactorPose3's error equals Pose3.Logmap(Z^-1 * Ti^-1 * Tj) in this build (Pose3's chart is
Expmap when GTSAM_POSE3_EXPMAP is on) and otherwise falls back to a CustomFactor that uses Logmap.
The optimum does not depend on the retraction.

Usage:
    bash tools/setup_gtsam_venv.sh
    cargo build --release --example pose_graph_g2o
    tools/.venv-gtsam/bin/python tools/check_pose_graph_gtsam.py [--binary PATH] [--workdir DIR]
        [--default-tolerances]
"""

import argparse
import os
import subprocess
import sys
import tempfile
from importlib.metadata import version

import gtsam
import numpy as np

ROBUST_SCALE = 1.0  # Cauchy k [sigma], = mireg::graph::DEFAULT_KERNEL_SCALE
REL_TOL = 1e-12
ABS_TOL = 1e-14
MAX_ITERATIONS = 500
TARGET = 1e-6


def pose(rot_vec, t):
    return gtsam.Pose3(gtsam.Rot3.Expmap(np.asarray(rot_vec, float)), np.asarray(t, float))


def information(rng, sigma_rot, sigma_trans):
    """A full SPD information matrix in GTSAM's (rotation, translation) order."""
    cov = np.diag([sigma_rot**2] * 3 + [sigma_trans**2] * 3)
    q, _ = np.linalg.qr(rng.normal(size=(6, 6)))
    # Mix the axes a little so that off-diagonal (and rotation-translation) entries are exercised.
    mix = np.eye(6) + 0.3 * (q - np.eye(6))
    cov = mix @ cov @ mix.T
    info = np.linalg.inv(cov)
    return 0.5 * (info + info.T)


def noisy(rng, z, info):
    cov = np.linalg.inv(info)
    xi = rng.multivariate_normal(np.zeros(6), cov)
    return z.compose(gtsam.Pose3.Expmap(xi))


def build(truth, pairs_odo, pairs_loop, rng, n_outliers, sig_odo, sig_loop):
    """Edges (i, j, Z, info, is_loop) and the dead-reckoned initial guess."""
    edges = []
    for i, j in pairs_odo:
        info = information(rng, *sig_odo)
        edges.append((i, j, noisy(rng, truth[i].between(truth[j]), info), info, False))
    for i, j in pairs_loop:
        info = information(rng, *sig_loop)
        edges.append((i, j, noisy(rng, truth[i].between(truth[j]), info), info, True))
    n = len(truth)
    for _ in range(n_outliers):
        i, j = sorted(rng.choice(n, size=2, replace=False))
        if j == i + 1:
            j = (j + 5) % n
            i, j = min(i, j), max(i, j)
        z = pose(rng.normal(scale=1.0, size=3), rng.uniform(-5, 5, size=3))
        edges.append((int(i), int(j), z, information(rng, *sig_loop), True))
    init = [truth[0]]
    odo = {(i, j): z for i, j, z, _, loop in edges if not loop}
    for k in range(1, n):
        init.append(init[-1].compose(odo[(k - 1, k)]))
    return truth, init, edges


def square_loop(rng, n_outliers):
    n, side = 40, 10.0
    per = n // 4
    truth = []
    for k in range(n):
        corner, s = divmod(k, per)
        yaw = corner * np.pi / 2
        start = [(0, 0), (side, 0), (side, side), (0, side)][corner]
        step = side / per * s
        xy = np.array(start) + step * np.array([np.cos(yaw), np.sin(yaw)])
        truth.append(pose([0.01 * np.sin(k), 0.02 * np.cos(k), yaw], [xy[0], xy[1], 0.1 * np.sin(0.3 * k)]))
    odo = [(k, k + 1) for k in range(n - 1)]
    loops = [(0, n - 1), (0, n - 2), (1, n - 1), (per - 1, per + 1), (2 * per, 2 * per + 2)]
    return build(truth, odo, loops, rng, n_outliers, (0.01, 0.05), (0.01, 0.05))


def sphere(rng, n_outliers):
    rings, per_ring, radius = 8, 25, 10.0
    truth = []
    for r in range(rings):
        lat = -np.pi / 2 + (r + 1) * np.pi / (rings + 1)
        for s in range(per_ring):
            lon = 2 * np.pi * s / per_ring
            p = radius * np.array([np.cos(lat) * np.cos(lon), np.cos(lat) * np.sin(lon), np.sin(lat)])
            truth.append(pose([0.0, -lat, lon + np.pi / 2], p))
    n = len(truth)
    odo = [(k, k + 1) for k in range(n - 1)]
    loops = [(k, k + per_ring) for k in range(n - per_ring) if k % 3 == 0]
    return build(truth, odo, loops, rng, n_outliers, (0.02, 0.1), (0.02, 0.1))


def ate(poses, truth):
    """RMS translation error [m]; node 0 starts at the truth, so no alignment."""
    return float(np.sqrt(np.mean([np.sum((a.translation() - b.translation()) ** 2) for a, b in zip(poses, truth)])))


def write_g2o(path, init, edges):
    def fmt(p):
        t, q = p.translation(), p.rotation().toQuaternion()
        return " ".join(repr(float(v)) for v in (*t, q.x(), q.y(), q.z(), q.w()))

    with open(path, "w") as f:
        for k, p in enumerate(init):
            f.write(f"VERTEX_SE3:QUAT {k} {fmt(p)}\n")
        for i, j, z, info, _ in edges:
            # g2o's information is in (translation, rotation) order.
            perm = [3, 4, 5, 0, 1, 2]
            g = info[np.ix_(perm, perm)]
            upper = " ".join(repr(float(g[r, c])) for r in range(6) for c in range(r, 6))
            f.write(f"EDGE_SE3:QUAT {i} {j} {fmt(z)} {upper}\n")


def read_g2o_poses(path):
    poses = {}
    with open(path) as f:
        for line in f:
            tok = line.split()
            if tok and tok[0] == "VERTEX_SE3:QUAT":
                x, y, z, qx, qy, qz, qw = map(float, tok[2:9])
                poses[int(tok[1])] = gtsam.Pose3(gtsam.Rot3.Quaternion(qw, qx, qy, qz), np.array([x, y, z]))
    return [poses[k] for k in range(len(poses))]


def logmap_factor(i, j, z, model):
    """BetweenFactor<Pose3> with e = Logmap(Z^-1 * Ti^-1 * Tj), Jacobians for right perturbations."""

    def error(this, values, jacobians):
        ti, tj = values.atPose3(this.keys()[0]), values.atPose3(this.keys()[1])
        e_pose = z.inverse().compose(ti.inverse().compose(tj))
        e = gtsam.Pose3.Logmap(e_pose)
        if jacobians is not None:
            jr_inv = gtsam.Pose3.LogmapDerivative(e)
            jacobians[1] = jr_inv
            jacobians[0] = -jr_inv @ tj.inverse().compose(ti).AdjointMap()
        return e

    return gtsam.CustomFactor(model, [i, j], error)


def between_is_logmap():
    rng = np.random.default_rng(7)
    worst = 0.0
    for _ in range(20):
        ti, tj, z = (pose(rng.normal(size=3), rng.normal(size=3)) for _ in range(3))
        f = gtsam.BetweenFactorPose3(0, 1, z, gtsam.noiseModel.Unit.Create(6))
        v = gtsam.Values()
        v.insert(0, ti)
        v.insert(1, tj)
        e_gtsam = f.unwhitenedError(v)
        e_log = gtsam.Pose3.Logmap(z.inverse().compose(ti.between(tj)))
        worst = max(worst, float(np.abs(e_gtsam - e_log).max()))
    return worst


KERNELS = {
    "cauchy": lambda k: gtsam.noiseModel.mEstimator.Cauchy.Create(k),
    "geman-mcclure": lambda k: gtsam.noiseModel.mEstimator.GemanMcClure.Create(k),
}


def gtsam_solve(init, edges, robust, use_between):
    graph = gtsam.NonlinearFactorGraph()
    for i, j, z, info, loop in edges:
        model = gtsam.noiseModel.Gaussian.Information(info)
        if robust and loop:
            model = gtsam.noiseModel.Robust.Create(KERNELS[robust](ROBUST_SCALE), model)
        graph.add(gtsam.BetweenFactorPose3(i, j, z, model) if use_between else logmap_factor(i, j, z, model))
    edges_only = gtsam.NonlinearFactorGraph(graph)
    graph.add(gtsam.PriorFactorPose3(0, init[0], gtsam.noiseModel.Isotropic.Sigma(6, 1e-8)))
    values = gtsam.Values()
    for k, p in enumerate(init):
        values.insert(k, p)
    params = gtsam.LevenbergMarquardtParams()
    params.setRelativeErrorTol(REL_TOL)
    params.setAbsoluteErrorTol(ABS_TOL)
    params.setMaxIterations(MAX_ITERATIONS)
    opt = gtsam.LevenbergMarquardtOptimizer(graph, values, params)
    result = opt.optimize()
    poses = [result.atPose3(k) for k in range(len(init))]
    return poses, edges_only.error(values), edges_only.error(result), opt.iterations()


def ours_solve(binary, workdir, name, init, edges, robust):
    src = os.path.join(workdir, f"{name}.g2o")
    dst = os.path.join(workdir, f"{name}_opt.g2o")
    write_g2o(src, init, edges)
    cmd = [binary, src, dst, "--rel-tol", str(REL_TOL), "--abs-tol", str(ABS_TOL),
           "--max-iterations", str(MAX_ITERATIONS)]
    if robust:
        cmd += ["--robust", robust, "--scale", str(ROBUST_SCALE)]
    run = subprocess.run(cmd, capture_output=True, text=True)
    if run.returncode != 0:
        sys.exit(f"{' '.join(cmd)} failed:\n{run.stderr}")
    return read_g2o_poses(dst), run.stderr.strip()


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    here = os.path.dirname(os.path.abspath(__file__))
    target_dir = os.environ.get("CARGO_TARGET_DIR", os.path.join(here, "..", "target"))
    ap.add_argument("--binary", default=os.path.join(target_dir, "release", "examples", "pose_graph_g2o"))
    ap.add_argument("--workdir", default=None, help="keep the g2o files here (default: a temporary dir)")
    ap.add_argument("--default-tolerances", action="store_true",
                    help="both solvers with GTSAM's defaults (1e-5 relative/absolute, 100 iterations) "
                         "instead of 1e-12/1e-14/500")
    args = ap.parse_args()
    if args.default_tolerances:
        global REL_TOL, ABS_TOL, MAX_ITERATIONS
        REL_TOL, ABS_TOL, MAX_ITERATIONS = 1e-5, 1e-5, 100
    workdir = args.workdir or tempfile.mkdtemp(prefix="pose_graph_gtsam_")
    os.makedirs(workdir, exist_ok=True)

    diff = between_is_logmap()
    use_between = diff < 1e-9
    print(f"gtsam {version('gtsam')}: "
          f"BetweenFactorPose3 error vs Pose3.Logmap max |diff| = {diff:.2e} -> "
          f"{'BetweenFactorPose3' if use_between else 'CustomFactor(Logmap)'}")

    cases = [
        ("square", square_loop, 0, None),
        ("square_outliers_cauchy", square_loop, 4, "cauchy"),
        ("sphere", sphere, 0, None),
        ("sphere_outliers_cauchy", sphere, 10, "cauchy"),
        ("sphere_outliers_geman_mcclure", sphere, 10, "geman-mcclure"),
    ]
    worst = 0.0
    for seed, (name, make, outliers, robust) in enumerate(cases):
        rng = np.random.default_rng(1000 + seed)
        truth, init, edges = make(rng, outliers)
        ours, summary = ours_solve(args.binary, workdir, name, init, edges, robust)
        ref, cost0, cost1, iters = gtsam_solve(init, edges, robust, use_between)
        rot = max(np.linalg.norm(gtsam.Rot3.Logmap(a.rotation().between(b.rotation()))) for a, b in zip(ours, ref))
        trans = max(np.linalg.norm(a.translation() - b.translation()) for a, b in zip(ours, ref))
        worst = max(worst, rot, trans)
        print(f"{name}: {len(init)} nodes, {len(edges)} edges ({outliers} false loops)"
              f"{f', {robust} k={ROBUST_SCALE} on loop edges' if robust else ''}")
        print(f"  gtsam: {iters} iterations, cost {cost0:.9e} -> {cost1:.9e}")
        print(f"  mireg: {summary}")
        print(f"  max pose difference: rotation {rot:.3e} rad, translation {trans:.3e} m")
        print(f"  ATE vs truth [m]: initial {ate(init, truth):.4f}, mireg {ate(ours, truth):.4f}, "
              f"gtsam {ate(ref, truth):.4f}")
    verdict = "PASS" if worst < TARGET else "FAIL"
    print(f"{verdict}: worst difference {worst:.3e} (target {TARGET:g}); g2o files in {workdir}")
    return 0 if worst < TARGET else 1


if __name__ == "__main__":
    sys.exit(main())
