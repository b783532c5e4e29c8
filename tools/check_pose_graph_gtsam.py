#!/usr/bin/env python3
"""Compare mireg's pose-graph optimum (src/graph, via examples/pose_graph_g2o.rs) with GTSAM's.

1. Builds seeded synthetic graphs — a noisy square loop and a sphere-like graph of rings, each with
loop edges, and both again with false loop edges under a Cauchy kernel — writes them as g2o, optimises
them with our example and with GTSAM's LevenbergMarquardtOptimizer on the same noise models
(noiseModel.Gaussian.Information; robust loop edges: noiseModel.Robust.Create(mEstimator.Cauchy.Create(k),
...) or GemanMcClure), node 0 fixed by a tight PriorFactorPose3, and prints per graph the maximum pose
difference (rotation angle [rad], translation [m]) and both final costs. Target: the same optimum to 1e-6.

2. The graph of tests/injected_steps.rs, seeded numpy instead of the test's PCG: an out-and-back of
120 frames with dense true loops and three odometry steps made 0.5–2 m and 2–5° wrong that keep a good
step's information: the test's three; three seeds with random ones, drawn so that at least 3 true loops
cross every cut the broken steps make; and one drawn case where a single loop crosses such a cut
(ambiguous: its decisions are printed, not judged). Every edge robust, as
mireg::loops::optimize_trajectory builds and solves it: Cauchy k = 5 annealed 500 -> 50 -> 5, each solve
from the last. Solved (a) by our example (`--robust-all --anneal 1000`), (b) by GTSAM LM with every
edge noiseModel.Robust(Cauchy(k)) on the same schedule — (a) and (b) must agree to 1e-6 — and (c) by
GTSAM's GncLMOptimizer (truncated least squares, and Geman–McClure) on the Gaussian graph, the node-0
prior the one known inlier, inlier threshold 0.5·d² <= 0.5·k² (d <= k, where the Cauchy weight is 1/2).
For (c) the decisions are compared: which edges end with weight < 0.5 under GNC and under mireg, and
every solver's ATE against the truth (a table; rows "no broken steps" and "oracle", the broken steps'
edges given the failed-frame prior alone, are mireg's on the same noise, for scale). GNC-GM's weight at
μ = 1 is (k²/(k²+d²))², below 1/2 from d = 0.64 k, so at the same threshold it calls more right loops
outliers than the others.

Exit status 1 if (a) and (b), or any graph of 1., differ by more than the target, or if GNC (either
loss) and mireg disagree on which injected broken steps are outliers in a graph that is not ambiguous.

The edge error must be GTSAM's BetweenFactor<Pose3> with the full SE(3) logarithm; the script checks
that BetweenFactorPose3's error equals Pose3.Logmap(Z^-1 * Ti^-1 * Tj) in this build (Pose3's chart is
Expmap when GTSAM_POSE3_EXPMAP is on) and otherwise falls back to a CustomFactor that uses Logmap.
The optimum does not depend on the retraction.

Usage:
    bash tools/setup_venv.sh gtsam
    cargo build --release --example pose_graph_g2o
    python3 tools/toolbox.py check-pose-graph-gtsam [--binary PATH] [--workdir DIR]
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


def gtsam_graph(edges, use_between, robust=None, scale=ROBUST_SCALE, robust_all=False):
    """The edge factors; robust (a KERNELS name) on loop edges, or on every edge with robust_all."""
    graph = gtsam.NonlinearFactorGraph()
    for i, j, z, info, loop in edges:
        model = gtsam.noiseModel.Gaussian.Information(info)
        if robust and (loop or robust_all):
            model = gtsam.noiseModel.Robust.Create(KERNELS[robust](scale), model)
        graph.add(gtsam.BetweenFactorPose3(i, j, z, model) if use_between else logmap_factor(i, j, z, model))
    return graph


def node0_prior(init):
    return gtsam.PriorFactorPose3(0, init[0], gtsam.noiseModel.Isotropic.Sigma(6, 1e-8))


def to_values(poses):
    values = gtsam.Values()
    for k, p in enumerate(poses):
        values.insert(k, p)
    return values


def lm_params():
    params = gtsam.LevenbergMarquardtParams()
    params.setRelativeErrorTol(REL_TOL)
    params.setAbsoluteErrorTol(ABS_TOL)
    params.setMaxIterations(MAX_ITERATIONS)
    return params


def gtsam_solve(init, edges, robust, use_between, scale=ROBUST_SCALE, robust_all=False):
    edges_only = gtsam_graph(edges, use_between, robust, scale, robust_all)
    graph = gtsam.NonlinearFactorGraph(edges_only)
    graph.add(node0_prior(init))
    values = to_values(init)
    opt = gtsam.LevenbergMarquardtOptimizer(graph, values, lm_params())
    result = opt.optimize()
    poses = [result.atPose3(k) for k in range(len(init))]
    return poses, edges_only.error(values), edges_only.error(result), opt.iterations()


def ours_solve(binary, workdir, name, init, edges, robust, extra=()):
    """Our optimum: (poses, the example's summary lines, every edge's final weight)."""
    src = os.path.join(workdir, f"{name}.g2o")
    dst = os.path.join(workdir, f"{name}_opt.g2o")
    weights = os.path.join(workdir, f"{name}_weights.txt")
    write_g2o(src, init, edges)
    cmd = [binary, src, dst, "--rel-tol", str(REL_TOL), "--abs-tol", str(ABS_TOL),
           "--max-iterations", str(MAX_ITERATIONS), "--weights", weights, *extra]
    if robust:
        cmd += ["--robust", robust]
    if robust and "--scale" not in extra:
        cmd += ["--scale", str(ROBUST_SCALE)]
    run = subprocess.run(cmd, capture_output=True, text=True)
    if run.returncode != 0:
        sys.exit(f"{' '.join(cmd)} failed:\n{run.stderr}")
    return read_g2o_poses(dst), run.stderr.strip(), np.loadtxt(weights, ndmin=1)


# --- Out-and-back with injected broken odometry steps: the graph of tests/injected_steps.rs ---------
# Every edge robust (Cauchy, k annealed as mireg::loops::optimize_trajectory anneals it), each edge
# with its own information; three odometry steps made 0.5–2 m and 2–5° wrong with a good step's
# information, dense true loops across them.

PLACES = 120  # places along the route; out via the even ones, back via the odd ones
PLACE_STEP_M = 0.5
STEP_SIGMA = (0.01, 0.1)  # good odometry step, each axis [m], [deg]
LOOP_SIGMA = (0.02, 0.2)  # loop relative pose, each axis [m], [deg]
# LoopConfig::for_voxel(0.5) odometry σ (0.05 m, 0.2°) × FAILED_FRAME_SIGMA_FACTOR (100): the prior
# mireg::loops::pose_graph adds to every measured edge's information.
EDGE_PRIOR_SIGMA = (0.05 * 100.0, 0.2 * 100.0)
MIN_LOOP_FRAMES = 5  # a loop joins frames at least this many apart
TEST_BROKEN = [(12, 1.0, 3.0), (40, 0.5, 2.0), (85, 2.0, 5.0)]  # (frame, m, deg), as the test's
LOOP_KERNEL_SCALE = 5.0  # mireg::loops::closure::DEFAULT_LOOP_KERNEL_SCALE [σ]
ANNEALING_START = 1000.0  # mireg::loops::closure::ANNEALING_START
ANNEALING_FACTOR = 10.0  # mireg::loops::closure::ANNEALING_FACTOR
OUTLIER_WEIGHT = 0.5  # an edge whose final weight is below this is called an outlier
MIN_CROSSING_LOOPS = 3  # fewer true loops across a cut of the broken steps: ambiguous, not judged
# Found by a random draw: broken steps at frames 46 and 75 (out and back at about the same place) cut
# off the turn, and only loop 45-74 crosses the cut. The annealed Cauchy optimum (GTSAM's too) keeps
# the more precise step 75 and discounts that loop, GNC-TLS the reverse. It is the cost, not the
# annealing: at this seed the Cauchy cost is 541.7 there and 544.5 at the Cauchy optimum reached from
# GNC-TLS's answer (which rejects all three steps), whose TLS cost is the lower by 364.3 to 366.0.
# Reported, not judged.
AMBIGUOUS_BROKEN = [(46, 1.85, 4.16), (75, 1.14, 4.76), (91, 0.95, -2.35)]


def diagonal_information(sigma_m, sigma_deg):
    """mireg::odometry::uncertainty::diagonal_information: (rotation, translation) order."""
    r, t = 1.0 / np.radians(sigma_deg) ** 2, 1.0 / sigma_m**2
    return np.diag([r, r, r, t, t, t])


def axis_noise(rng, sigma):
    sigma_m, sigma_deg = sigma
    t = rng.normal(size=3) * sigma_m
    r = rng.normal(size=3) * np.radians(sigma_deg)
    return pose(r, t)


def anneal_schedule(k, start=ANNEALING_START):
    """optimize_trajectory's kernel scales: k·start divided by ANNEALING_FACTOR per solve, down to k."""
    scales, scale = [], k * start
    while True:
        scale = max(scale / ANNEALING_FACTOR, k)
        scales.append(scale)
        if scale <= k:
            return scales


def route_order():
    """The place of each frame: out via the even places, back via the odd ones."""
    return list(range(0, PLACES, 2)) + list(range(PLACES - 1, 0, -2))


def loop_pairs(order):
    """True loops (m, q): each frame q of the way back to the frames m of the way out at its two
    neighbouring places, at least MIN_LOOP_FRAMES apart."""
    frame_of = {place: f for f, place in enumerate(order)}
    pairs = []
    for q, place in enumerate(order):
        if place % 2 == 0:
            continue
        for neighbour in (place - 1, place + 1):
            m = frame_of.get(neighbour)
            if m is not None and m + MIN_LOOP_FRAMES <= q:
                pairs.append((m, q))
    return pairs


def weakest_cut(n, pairs, broken):
    """The fewest true loops that join a union of the blocks the broken steps cut the chain into to
    the rest. Moving such a union rigidly trades the broken steps around it for the loops across it:
    with one loop across, the truth and the alternative discard as many edges, and no robust cost
    can tell them apart by counting."""
    cuts = sorted(f for f, _, _ in broken)
    block = np.searchsorted(cuts, np.arange(n), side="right")
    fewest = len(pairs)
    for mask in range(2, 2 ** (len(cuts) + 1), 2):  # unions without block 0 (it holds node 0)
        fewest = min(fewest, sum(1 for m, q in pairs if (mask >> block[m]) & 1 != (mask >> block[q]) & 1))
    return fewest


def out_and_back(rng, broken):
    """(truth, drifted odometry = initial guess, edges): odometry edges k-1 -> k first, then the loops."""
    places = []
    for i in range(PLACES):
        s = i * PLACE_STEP_M
        places.append(pose([0.0, 0.0, 0.6 * np.sin(s / 15.0)], [s, 8.0 * (1.0 - np.cos(s / 15.0)), 0.0]))
    order = route_order()
    truth = [places[i] for i in order]
    n = len(truth)
    prior = diagonal_information(*EDGE_PRIOR_SIGMA)
    step_info = diagonal_information(*STEP_SIGMA) + prior
    loop_info = diagonal_information(*LOOP_SIGMA) + prior
    wrong = {k: (m, deg) for k, m, deg in broken}
    init, edges = [truth[0]], []
    for k in range(1, n):
        step = truth[k - 1].between(truth[k]).compose(axis_noise(rng, STEP_SIGMA))
        if k in wrong:
            m, deg = wrong[k]
            step = step.compose(pose([0.0, 0.0, np.radians(deg)], [0.6 * m, 0.8 * m, 0.0]))
        init.append(init[-1].compose(step))
        edges.append((k - 1, k, step, step_info, False))
    for m, q in loop_pairs(order):
        z = truth[m].between(truth[q]).compose(axis_noise(rng, LOOP_SIGMA))
        edges.append((m, q, z, loop_info, True))
    return truth, init, edges


def random_broken(rng, n, count=3, gap=10):
    """count steps 0.5–2 m and 2–5° wrong, at least gap frames apart, placed so that at least
    MIN_CROSSING_LOOPS true loops cross every cut they make (weakest_cut): the loops outvote them."""
    pairs = loop_pairs(route_order())
    while True:
        frames = sorted(int(f) for f in rng.choice(np.arange(1, n), size=count, replace=False))
        if (all(b - a >= gap for a, b in zip(frames, frames[1:]))
                and weakest_cut(n, pairs, [(f, 0, 0) for f in frames]) >= MIN_CROSSING_LOOPS):
            break
    return [(int(k), float(rng.uniform(0.5, 2.0)), float(rng.uniform(2.0, 5.0) * rng.choice([-1, 1])))
            for k in frames]


def edge_weights(poses, edges, k):
    """Cauchy IRLS weights k²/(k² + d²) of every edge at poses (d: Mahalanobis distance)."""
    w = []
    for i, j, z, info, _ in edges:
        e = gtsam.Pose3.Logmap(z.inverse().compose(poses[i].between(poses[j])))
        w.append(k * k / (k * k + float(e @ info @ e)))
    return np.array(w)


def gtsam_annealed(init, edges, use_between, k):
    """GTSAM LM, every edge Robust(Cauchy(scale)), one solve per scale of anneal_schedule(k)."""
    poses, iters = init, 0
    for scale in anneal_schedule(k):
        poses, _, cost, it = gtsam_solve(poses, edges, "cauchy", use_between, scale=scale, robust_all=True)
        iters += it
    return poses, cost, iters


GNC_LOSSES = {"TLS": gtsam.GncLossType.TLS, "GM": gtsam.GncLossType.GM}


def gtsam_gnc(init, edges, use_between, loss, k):
    """GTSAM GncLMOptimizer on the Gaussian graph; the node-0 prior is the one known inlier; an edge
    is an inlier at 0.5·d² <= 0.5·k² (d <= k, where mireg's Cauchy weight is 1/2)."""
    graph = gtsam_graph(edges, use_between)
    graph.add(node0_prior(init))
    params = gtsam.GncLMParams(lm_params())
    params.setLossType(GNC_LOSSES[loss])
    params.setKnownInliers([len(edges)])
    opt = gtsam.GncLMOptimizer(graph, to_values(init), params)
    opt.setInlierCostThresholds(0.5 * k * k)
    result = opt.optimize()
    return [result.atPose3(i) for i in range(len(init))], np.asarray(opt.getWeights())[: len(edges)]


def edge_name(edges, e):
    i, j, _, _, loop = edges[e]
    return f"loop {i}-{j}" if loop else f"step {j}"


def injected_family(binary, workdir, use_between):
    """Solve the family three ways, print the table; returns (worst (a)-(b) difference, failures)."""
    k = LOOP_KERNEL_SCALE
    cases = ([("injected_test", TEST_BROKEN)] + [(f"injected_random{s}", None) for s in (1, 2, 3)]
             + [("injected_ambiguous", AMBIGUOUS_BROKEN)])
    print(f"\nout-and-back with injected broken odometry steps (tests/injected_steps.rs): every edge "
          f"Cauchy, k = {k:g} annealed {' -> '.join(f'{s:g}' for s in anneal_schedule(k))}; "
          f"GNC inlier threshold d <= {k:g}; outlier = final weight < {OUTLIER_WEIGHT}")
    worst, failures, rows = 0.0, [], []
    mireg_flags = ["--robust-all", "--scale", str(k), "--anneal", str(ANNEALING_START)]
    for seed, (name, broken) in enumerate(cases):
        if broken is None:
            broken = random_broken(np.random.default_rng(3000 + seed), PLACES)
        truth, init, edges = out_and_back(np.random.default_rng(2000 + seed), broken)
        # The same noise without the broken steps, and the oracle: the graph told which steps broke
        # (their edges carry the prior alone, as a failed frame's in tests/injected_steps.rs).
        clean_truth, clean_init, clean_edges = out_and_back(np.random.default_rng(2000 + seed), [])
        assert all(a.equals(b, 0.0) for a, b in zip(clean_truth, truth))
        clean, _, _ = ours_solve(binary, workdir, f"{name}_clean", clean_init, clean_edges, "cauchy", mireg_flags)
        told = list(edges)
        for f, _, _ in broken:
            i, j, z, _, loop = told[f - 1]
            told[f - 1] = (i, j, z, diagonal_information(*EDGE_PRIOR_SIGMA), loop)
        oracle, _, _ = ours_solve(binary, workdir, f"{name}_oracle", init, told, "cauchy", mireg_flags)
        n_loops = sum(1 for e in edges if e[4])
        cut = weakest_cut(len(init), [(i, j) for i, j, _, _, loop in edges if loop], broken)
        judged = cut >= MIN_CROSSING_LOOPS
        print(f"{name}: {len(init)} nodes, {len(edges) - n_loops} odometry + {n_loops} loop edges; broken steps "
              + ", ".join(f"{f} ({m:.2f} m, {d:+.2f} deg)" for f, m, d in broken)
              + f"; weakest cut crossed by {cut} true loops"
              + ("" if judged else f" (< {MIN_CROSSING_LOOPS}: ambiguous, decisions reported, not judged)"))
        ours, summary, w_ours = ours_solve(binary, workdir, name, init, edges, "cauchy", mireg_flags)
        for line in summary.splitlines():
            print(f"  mireg: {line}")
        lm, lm_cost, lm_iters = gtsam_annealed(init, edges, use_between, k)
        print(f"  gtsam LM: {lm_iters} iterations over the schedule, final cost {lm_cost:.9e}")
        rot = max(np.linalg.norm(gtsam.Rot3.Logmap(a.rotation().between(b.rotation()))) for a, b in zip(ours, lm))
        trans = max(np.linalg.norm(a.translation() - b.translation()) for a, b in zip(ours, lm))
        worst = max(worst, rot, trans)
        print(f"  (a) mireg vs (b) gtsam LM: max pose difference rotation {rot:.3e} rad, translation {trans:.3e} m")
        w_check = float(np.abs(edge_weights(ours, edges, k) - w_ours).max())
        print(f"  mireg's weights vs k²/(k²+d²) at its poses: max |diff| {w_check:.1e}")
        solvers = [("odometry", init, None), ("mireg, no broken steps", clean, None),
                   ("mireg, oracle", oracle, None), ("mireg annealed", ours, w_ours),
                   ("gtsam LM annealed", lm, edge_weights(lm, edges, k))]
        for loss in GNC_LOSSES:
            poses, w = gtsam_gnc(init, edges, use_between, loss, k)
            solvers.append((f"gtsam GNC {loss}", poses, w))
        broken_edges = [f - 1 for f, _, _ in broken]  # odometry edge f-1 is the step into frame f
        outliers_ours = set(np.flatnonzero(w_ours < OUTLIER_WEIGHT))
        for solver, poses, w in solvers:
            if w is None:
                rows.append((name, solver, ate(poses, truth), "-", "-", "-"))
                continue
            outliers = set(np.flatnonzero(w < OUTLIER_WEIGHT))
            flagged = " ".join(str(edges[e][1]) for e in broken_edges if e in outliers) or "none"
            others = " ".join(edge_name(edges, e) for e in sorted(outliers - set(broken_edges))) or "none"
            weights = " ".join(f"{w[e]:.1e}" for e in broken_edges)
            rows.append((name, solver, ate(poses, truth), flagged, weights, others))
            if solver.startswith("gtsam GNC"):
                if {e for e in broken_edges if e in outliers} != {e for e in broken_edges if e in outliers_ours}:
                    message = f"{name}: {solver} and mireg disagree on the broken steps"
                    if judged:
                        failures.append(message)
                    else:
                        print(f"  note: {message} (ambiguous graph, not judged)")
                if outliers != outliers_ours:
                    diff = " ".join(edge_name(edges, e) for e in sorted(outliers ^ outliers_ours))
                    print(f"  note: {solver} and mireg differ on these edges: {diff}")
    header = ("graph", "solver", "ATE [m]", "broken steps w<0.5", "broken-step weights", "other edges w<0.5")
    widths = [max(len(str(r[c])) if c != 2 else 8 for r in rows + [header]) for c in range(len(header))]
    print()
    print("  ".join(h.ljust(wd) for h, wd in zip(header, widths)).rstrip())
    for r in rows:
        cells = [r[0], r[1], f"{r[2]:.4f}", r[3], r[4], r[5]]
        print("  ".join(c.ljust(wd) for c, wd in zip(cells, widths)).rstrip())
    return worst, failures


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
        ours, summary, _ = ours_solve(args.binary, workdir, name, init, edges, robust)
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
    fam_worst, failures = injected_family(args.binary, workdir, use_between)
    worst = max(worst, fam_worst)
    ok = worst < TARGET and not failures
    for f in failures:
        print(f"FAIL: {f}")
    print(f"{'PASS' if ok else 'FAIL'}: worst difference mireg vs GTSAM LM {worst:.3e} (target {TARGET:g}); "
          f"GNC and mireg {'disagree' if failures else 'agree'} on the injected broken steps; "
          f"g2o files in {workdir}")
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
