#!/usr/bin/env python3
"""Loop closure side by side: mireg, KISS-SLAM and an Open3D pose graph on the same logs (those of
tools/make_loop_logs.py, or any log with clouds and a PoseStamped reference). One row per tool and
log: ATE [m], RPE [m/frame], loops accepted, loop precision, time [s], failed frames.

Scoring (the same code for every row, tools/compare_kiss_icp.py's `score`): poses are matched to the
reference by header stamp; both are made relative to the first cloud. ATE = RMSE of the positions
after an SE(3) Umeyama alignment (rotation + translation, no scale) of the estimate onto the
reference; RPE = mean over consecutive scored frames of |translation of (dRef^-1 dEst)| [m].
A loop (query q, match m, estimate match_from_query) is compared with the reference
ref_m^-1 ref_q: rotation error [deg] and translation error [m] of their difference; it is correct
when < 2 deg and < 2 voxels (`--voxel`, default mireg's own voxel from its JSON summary). Loop
precision = correct / accepted. Loop recall (mireg row, in its notes): the fraction of revisits
-- frames with an earlier frame within 8 voxels in the reference and at least 20 voxels of path
back -- within 10 voxels of path of a correct accepted loop's query frame (`loop_recall`).

Rows:

* **mireg**: ``mireg register LOG -o OUT --json [args after --]`` (binary ``--mireg``, default
  $MIREG_BIN or target/release/mireg). Trajectory: ``/mireg/pose_optimized`` when the output has it,
  else ``/mireg/pose`` (the row says which). ``/mireg/loops`` (JSON, one message per candidate
  tried: query_frame, match_frame, query_stamp_ns, match_stamp_ns, verdict accepted|rejected,
  reason, match_from_query {translation, rotation_xyzw}, inliers, fitness): accepted ones are
  counted, scored against the reference and listed. Without that topic the row is odometry only
  and says so. Time: wall time of the subprocess (reading, registration, writing).
* **KISS-SLAM** 0.0.2 through its Python API, as its own pipeline.py calls it (`process_scan`, then
  `generate_new_node`, `erase_last_local_map`, `fine_grained_optimization`), on the same clouds
  (x, y, z as float64, no per-point times). Settings: KISS-ICP's max_range = min(100 m, farthest
  point of the first cloud) and voxel = max_range / 100 (its own rule, as compare_kiss_icp.py);
  its outdoor defaults local_mapper.voxel_size = 0.5 m and loop_closer density_map_resolution =
  0.5 m are scaled by max_range / 100 (unchanged at 100 m); local_mapper.splitting_distance =
  ``--kiss-local-map`` metres, default *tuned to the log*: a quarter of the reference's largest
  distance from its start (KISS-SLAM splits a local map when the pose is that far from the map's
  first pose -- a displacement, not the distance travelled -- and queries each finished map
  against the earlier ones, so an out-and-back needs maps shorter than its reach to close a loop).
  Loops = its accepted closures (between local maps, so no per-frame loop precision). Time:
  process_scan + the final optimisation, clouds decoded beforehand.
* **Open3D pose graph** (Choi, Zhou & Koltun's multiway registration, Open3D 0.20
  ``o3d.pipelines.registration``): one node per frame; odometry edges (certain) from mireg's
  ``/mireg/pose`` relative poses; loop edges (uncertain) for the candidates of ``/mireg/loops``
  (all tried pairs, accepted or not), each registered query -> match by Open3D's FPFH RANSAC
  (voxel v, normals Hybrid(2v, 30), FPFH Hybrid(5v, 100), max distance 1.5v, ransac_n 3, checkers
  EdgeLength(0.9) + Distance(1.5v), RANSACConvergenceCriteria(100000, 0.999), seed 0) + point-to-plane
  ICP (max distance v); information matrices from get_information_matrix_from_point_clouds
  (1.5v); ``global_optimization`` with GlobalOptimizationLevenbergMarquardt, default convergence
  criteria, GlobalOptimizationOption(max_correspondence_distance = 1.5v, edge_prune_threshold =
  0.25, preference_loop_closure = 1.0, reference_node = 0) -- the values of Open3D's multiway
  registration tutorial. Loops accepted = uncertain edges the line process keeps. v = ``--o3d-voxel``,
  default the loop voxel. When the mireg output has no ``/mireg/loops`` the candidates are made here,
  and the row says so: for every frame q the nearest earlier frame m in mireg's odometry with
  q - m >= ``--min-separation`` frames and within ``--candidate-radius`` (default 3 x the median
  odometry step). Time: pairwise registration + optimisation (mireg's odometry not included).

After the table, an ``agreement`` line per pair of independent estimates (mireg and KISS-SLAM):
how far apart they lie, and how much of their error against the reference they share (see
``print_agreement``), which tells the reference's own error from the estimators'.

Usage:
    bash tools/setup_venv.sh loops
    python3 tools/toolbox.py compare-loops /tmp/loop_micro211_s4.mcap /tmp/loop_kaist03.mcap \\
        --mireg target/release/mireg [--tools mireg,kiss-slam,open3d] [--voxel V]
        [--kiss-local-map M] [--json-out rows.json] [-- MIREG_REGISTER_ARGS]
"""

import argparse
import contextlib
import json
import math
import os
import sys
import tempfile
import time

import numpy as np
from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory

import mireg_run
from compare_kiss_icp import pose_matrix, read_log, score, split_mireg_args, xyz  # noqa: E402

LOOP_DEG = 2.0  # a loop is correct below this rotation error ...
LOOP_VOXELS = 2.0  # ... and below this many voxels of translation error


# --- geometry ----------------------------------------------------------------------------------------


def matrix_from(translation, rotation_xyzw):
    x, y, z, w = rotation_xyzw
    n = math.sqrt(x * x + y * y + z * z + w * w)
    x, y, z, w = x / n, y / n, z / n, w / n
    p = type("P", (), {"position": type("V", (), dict(zip("xyz", translation))),
                       "orientation": type("Q", (), {"x": x, "y": y, "z": z, "w": w})})
    return pose_matrix(p)


def transform_error(estimate, truth):
    """(rotation error [deg], translation error [m]) of estimate vs truth (4x4 each)."""
    d = np.linalg.inv(truth) @ estimate
    angle = math.degrees(math.acos(max(-1.0, min(1.0, (np.trace(d[:3, :3]) - 1.0) / 2.0))))
    return angle, float(np.linalg.norm(d[:3, 3]))


def loop_truth(reference, q_stamp, m_stamp):
    """match_from_query of the reference, or None when a stamp has no reference pose."""
    if q_stamp not in reference or m_stamp not in reference:
        return None
    return np.linalg.inv(reference[m_stamp]) @ reference[q_stamp]


def score_loops(loops, reference, voxel):
    """Adds rot_err_deg / trans_err_m / correct to each loop dict; returns the number correct."""
    good = 0
    for lp in loops:
        truth = loop_truth(reference, lp["query_stamp_ns"], lp["match_stamp_ns"])
        if truth is None:
            lp["rot_err_deg"] = lp["trans_err_m"] = None
            lp["correct"] = False
            continue
        lp["rot_err_deg"], lp["trans_err_m"] = transform_error(lp["T"], truth)
        lp["correct"] = lp["rot_err_deg"] < LOOP_DEG and lp["trans_err_m"] < LOOP_VOXELS * voxel
        good += lp["correct"]
    return good


def loop_recall(loops, reference, stamps, voxel, radius_voxels=8.0, separation_voxels=20.0,
                cover_voxels=10.0):
    """Fraction of the log's revisits that correct accepted loops close.

    A frame is a *revisit* when an earlier frame lies within ``radius_voxels`` of it in the
    reference with at least ``separation_voxels`` of reference path between them (mireg's own
    candidate radius and separation at zero drift: a revisit any loop detector should find). A
    revisit is *closed* when a correct accepted loop's query frame lies within ``cover_voxels`` of
    path of it (mireg skips candidates within 10 voxels of an accepted loop). Returns (closed,
    revisits)."""
    pts = [reference[s][:3, 3] for s in stamps if s in reference]
    kept = [s for s in stamps if s in reference]
    path = np.concatenate([[0.0], np.cumsum([np.linalg.norm(b - a) for a, b in zip(pts, pts[1:])])])
    revisits = []
    for i in range(len(pts)):
        for j in range(i):
            if path[i] - path[j] >= separation_voxels * voxel and \
                    np.linalg.norm(pts[i] - pts[j]) <= radius_voxels * voxel:
                revisits.append(i)
                break
    index = {s: i for i, s in enumerate(kept)}
    queries = [index[lp["query_stamp_ns"]] for lp in loops
               if lp.get("correct") and lp["query_stamp_ns"] in index]
    closed = sum(1 for i in revisits if any(abs(path[i] - path[q]) <= cover_voxels * voxel for q in queries))
    return closed, len(revisits)


# --- mireg -------------------------------------------------------------------------------------------


def read_mireg_output(path):
    """{topic: ...} of a `mireg register` output: poses per pose topic {stamp: 4x4}, loops [dict]."""
    poses, loops, topics = {}, [], set()
    decoders = {}
    with open(path, "rb") as f:
        for schema, channel, message in make_reader(f).iter_messages():
            topics.add(channel.topic)
            if channel.topic in ("/mireg/pose", "/mireg/pose_optimized"):
                if schema.id not in decoders:
                    decoders[schema.id] = DecoderFactory().decoder_for(channel.message_encoding, schema)
                msg = decoders[schema.id](message.data)
                stamp = msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec
                poses.setdefault(channel.topic, {})[stamp] = pose_matrix(msg.pose)
            elif channel.topic == "/mireg/loops":
                lp = json.loads(message.data)
                mq = lp.get("match_from_query") or {}
                if "translation" in mq and "rotation_xyzw" in mq:
                    lp["T"] = matrix_from(mq["translation"], mq["rotation_xyzw"])
                loops.append(lp)
    return poses, loops, topics


def run_mireg(binary, log, extra, tmp):
    out = os.path.join(tmp, "mireg_out.mcap")
    summary, wall = mireg_run.register(binary, log, out, extra, summary=True)
    poses, loops, topics = read_mireg_output(out)
    return summary, poses, loops, topics, wall


# --- KISS-SLAM ---------------------------------------------------------------------------------------


def reach(reference, stamps):
    first = reference[stamps[0]][:3, 3]
    return max(float(np.linalg.norm(reference[s][:3, 3] - first)) for s in stamps if s in reference)


def run_kiss_slam(frames, local_map_m):
    """frames: [(stamp, points)]. Returns poses {stamp: 4x4}, closures, settings text, seconds."""
    from kiss_slam.config import load_config
    from kiss_slam.slam import KissSLAM

    config = load_config(None)
    max_range = float(min(config.odometry.preprocessing.max_range,
                          np.linalg.norm(frames[0][1], axis=1).max()))
    scale = max_range / 100.0
    config.odometry.preprocessing.max_range = max_range
    config.odometry.mapping.voxel_size = scale
    config.local_mapper.voxel_size = 0.5 * scale
    config.loop_closer.detector.density_map_resolution = 0.5 * scale
    config.local_mapper.splitting_distance = local_map_m
    with contextlib.redirect_stdout(sys.stderr):  # its "KissSLAM| ..." prints
        slam = KissSLAM(config)
        t0 = time.perf_counter()
        for _s, p in frames:
            slam.process_scan(p, np.zeros(0))
        slam.generate_new_node()
        slam.local_map_graph.erase_last_local_map()
        poses, _pgo = slam.fine_grained_optimization()
        elapsed = time.perf_counter() - t0
    if len(poses) != len(frames):
        raise SystemExit(f"KISS-SLAM returned {len(poses)} poses for {len(frames)} frames")
    first_inv = np.linalg.inv(poses[0])
    settings = (f"max_range {max_range:.2f} m, voxel {scale:.3f} m, local_mapper voxel {0.5 * scale:.3f} m, "
                f"splitting_distance {local_map_m:.3f} m, density_map_resolution {0.5 * scale:.3f} m, "
                f"overlap_threshold {config.loop_closer.overlap_threshold}, "
                f"{len(list(slam.local_map_graph.local_maps()))} local maps")
    return ({s: first_inv @ np.asarray(p) for (s, _p), p in zip(frames, poses)},
            list(slam.get_closures()), settings, elapsed)


# --- Open3D pose graph -------------------------------------------------------------------------------


def proximity_candidates(odometry, stamps, min_sep, radius):
    """For each frame the nearest earlier one (>= min_sep frames back) within radius in `odometry`."""
    pos = np.array([odometry[s][:3, 3] for s in stamps])
    out = []
    for q in range(len(stamps)):
        if q < min_sep:
            continue
        d = np.linalg.norm(pos[:q - min_sep + 1] - pos[q], axis=1)
        m = int(np.argmin(d))
        if d[m] <= radius:
            out.append({"query_frame": q, "match_frame": m,
                        "query_stamp_ns": stamps[q], "match_stamp_ns": stamps[m]})
    return out


def run_open3d(frames, odometry, candidates, voxel):
    """Pose graph over frames [(stamp, points)] with odometry {stamp: 4x4} and loop candidates."""
    import open3d as o3d

    reg = o3d.pipelines.registration
    o3d.utility.set_verbosity_level(o3d.utility.VerbosityLevel.Error)
    t0 = time.perf_counter()
    clouds, feats = {}, {}
    index = {s: i for i, (s, _p) in enumerate(frames)}

    def cloud(i):
        if i not in clouds:
            pc = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(frames[i][1]))
            pc = pc.voxel_down_sample(voxel)
            pc.estimate_normals(o3d.geometry.KDTreeSearchParamHybrid(radius=2 * voxel, max_nn=30))
            clouds[i] = pc
        return clouds[i]

    def fpfh(i):
        if i not in feats:
            feats[i] = reg.compute_fpfh_feature(cloud(i), o3d.geometry.KDTreeSearchParamHybrid(radius=5 * voxel, max_nn=100))
        return feats[i]

    graph = reg.PoseGraph()
    stamps = [s for s, _p in frames]
    for s in stamps:
        graph.nodes.append(reg.PoseGraphNode(odometry[s]))
    for i in range(len(stamps) - 1):
        t = np.linalg.inv(odometry[stamps[i + 1]]) @ odometry[stamps[i]]  # (i+1)_from_i
        info = reg.get_information_matrix_from_point_clouds(cloud(i), cloud(i + 1), 1.5 * voxel, t)
        graph.edges.append(reg.PoseGraphEdge(i, i + 1, t, info, uncertain=False))
    registered = []
    o3d.utility.random.seed(0)
    for c in candidates:
        q, m = index.get(c["query_stamp_ns"]), index.get(c["match_stamp_ns"])
        if q is None or m is None or q == m:
            continue
        ransac = reg.registration_ransac_based_on_feature_matching(
            cloud(q), cloud(m), fpfh(q), fpfh(m), False, 1.5 * voxel,
            reg.TransformationEstimationPointToPoint(False), 3,
            [reg.CorrespondenceCheckerBasedOnEdgeLength(0.9), reg.CorrespondenceCheckerBasedOnDistance(1.5 * voxel)],
            reg.RANSACConvergenceCriteria(100000, 0.999))
        icp = reg.registration_icp(cloud(q), cloud(m), voxel, ransac.transformation,
                                   reg.TransformationEstimationPointToPlane())
        info = reg.get_information_matrix_from_point_clouds(cloud(q), cloud(m), 1.5 * voxel, icp.transformation)
        graph.edges.append(reg.PoseGraphEdge(q, m, icp.transformation, info, uncertain=True))
        registered.append({"query_frame": q, "match_frame": m, "query_stamp_ns": stamps[q],
                           "match_stamp_ns": stamps[m], "T": np.asarray(icp.transformation).copy(),
                           "fitness": icp.fitness})
    option = reg.GlobalOptimizationOption(max_correspondence_distance=1.5 * voxel, edge_prune_threshold=0.25,
                                          preference_loop_closure=1.0, reference_node=0)
    reg.global_optimization(graph, reg.GlobalOptimizationLevenbergMarquardt(),
                            reg.GlobalOptimizationConvergenceCriteria(), option)
    elapsed = time.perf_counter() - t0
    kept = {(e.source_node_id, e.target_node_id) for e in graph.edges if e.uncertain}
    accepted = [r for r in registered if (r["query_frame"], r["match_frame"]) in kept]
    poses = {s: np.asarray(graph.nodes[i].pose).copy() for i, s in enumerate(stamps)}
    first_inv = np.linalg.inv(poses[stamps[0]])
    return {s: first_inv @ p for s, p in poses.items()}, registered, accepted, elapsed


# --- driver ------------------------------------------------------------------------------------------


def fmt(x, spec):
    return "-" if x is None else format(x, spec)


def print_loops(name, loops, voxel):
    for lp in loops:
        err = ("no reference" if lp.get("rot_err_deg") is None else
               f"{lp['rot_err_deg']:.2f} deg, {lp['trans_err_m']:.3f} m -> {'correct' if lp['correct'] else 'WRONG'}")
        extra = "".join(f", {k} {lp[k]:.3g}" if isinstance(lp.get(k), float) else (f", {k} {lp[k]}" if k in lp else "")
                        for k in ("inliers", "fitness"))
        print(f"    {name} loop q={lp['query_frame']} m={lp['match_frame']}: {err}{extra}")


def print_agreement(trajectories, ates):
    """How far two independent estimates lie from each other, next to their ATEs.

    With a, b their ATEs against the reference and d their ATE against each other (same
    alignment), the error they share against the reference is about sqrt((a² + b² − d²) / 2),
    if their own errors are uncorrelated with each other and with the reference's. A shared part
    near a and b says the reference (or the data itself) carries that error, and no estimate
    can come closer to the reference than it without copying the reference's error. Open3D's
    pose graph is left out: it starts from mireg's odometry, so it is not independent of mireg.
    """
    names = sorted(trajectories)
    for i, x in enumerate(names):
        for y in names[i + 1:]:
            d, _rpe, n = score(trajectories[x], trajectories[y])
            a, b = ates[x], ates[y]
            shared = math.sqrt(max(0.0, (a * a + b * b - d * d) / 2.0))
            print(f"    agreement: {x} vs {y} {d:.4f} m apart over {n} frames (ATE of one against the "
                  f"other); error both share against the reference ~ {shared:.4f} m of {a:.4f} / {b:.4f} m")


def compare(log, args, extra):
    topic, clouds, reference = read_log(log, args.topic, args.reference_topic)
    if not clouds:
        raise SystemExit(f"{log}: no PointCloud2 topic")
    if not reference:
        raise SystemExit(f"{log}: no reference poses on {args.reference_topic}")
    first = np.linalg.inv(reference[clouds[0][0]])
    reference = {s: first @ p for s, p in reference.items()}
    stamps = [s for s, _m, _r in clouds]
    frames = [(s, xyz(msg)) for s, msg, _r in clouds]
    tools = args.tools.split(",")
    rows = []
    print(f"\n{log}: {topic}, {len(clouds)} frames, reference {args.reference_topic}, "
          f"reach {reach(reference, stamps):.3f} m")

    summary = mireg_poses = None
    loops = []
    trajectories = {}  # tool -> its trajectory {stamp: 4x4}, for the agreement lines
    with tempfile.TemporaryDirectory() as tmp:
        if "mireg" in tools or "open3d" in tools:
            summary, mireg_poses, loops, topics, wall = run_mireg(args.mireg, log, extra, tmp)
    voxel = args.voxel if args.voxel else (summary["voxel_m"] if summary else None)
    if summary is not None:
        traj = "/mireg/pose_optimized" if "/mireg/pose_optimized" in mireg_poses else "/mireg/pose"
        ate, rpe, n = score(mireg_poses[traj], reference)
        if "/mireg/loops" in topics:
            accepted = [lp for lp in loops if lp.get("verdict") == "accepted" and "T" in lp]
            good = score_loops(accepted, reference, voxel)
            loop_cell, prec = len(accepted), (good / len(accepted) if accepted else None)
            closed, revisits = loop_recall(accepted, reference, stamps, voxel)
            note = (f"{traj}; /mireg/loops: {len(loops)} candidates tried, {len(accepted)} accepted; "
                    f"recall {closed}/{revisits} revisits closed")
        else:
            accepted, loop_cell, prec = [], "no topic", None
            note = f"{traj}; no /mireg/loops in the output: odometry only"
        trajectories["mireg"] = mireg_poses[traj]
        rows.append(dict(tool="mireg", ate=ate, rpe=rpe, loops=loop_cell, precision=prec, time=wall,
                         failed=summary["failed_frames"], scored=n,
                         note=f"{note}; voxel {summary['voxel_m']:.3f} m ({summary['voxel_source']})"))
        row_loops = {"mireg": accepted}
    else:
        row_loops = {}

    if "kiss-slam" in tools:
        local_map = args.kiss_local_map or reach(reference, stamps) / 4.0
        poses, closures, settings, elapsed = run_kiss_slam(frames, local_map)
        ate, rpe, n = score(poses, reference)
        trajectories["KISS-SLAM"] = poses
        rows.append(dict(tool="KISS-SLAM", ate=ate, rpe=rpe, loops=len(closures), precision=None, time=elapsed,
                         failed="-", scored=n,
                         note=f"{settings}" + ("" if args.kiss_local_map else " (splitting = reach / 4)")
                         + f"; closures (local maps) {closures}"))

    if "open3d" in tools:
        odometry = mireg_poses["/mireg/pose"]
        if "/mireg/loops" in topics:
            cands = [lp for lp in loops if "query_stamp_ns" in lp and "match_stamp_ns" in lp]
            source = f"the {len(cands)} candidates of /mireg/loops"
        else:
            steps = [np.linalg.norm(odometry[b][:3, 3] - odometry[a][:3, 3]) for a, b in zip(stamps, stamps[1:])]
            radius = args.candidate_radius or 3.0 * float(np.median(steps))
            cands = proximity_candidates(odometry, stamps, args.min_separation, radius)
            source = (f"no /mireg/loops: {len(cands)} proximity candidates (nearest earlier frame in /mireg/pose, "
                      f">= {args.min_separation} frames back, within {radius:.3f} m)")
        o3d_voxel = args.o3d_voxel or voxel
        poses, registered, accepted, elapsed = run_open3d(frames, odometry, cands, o3d_voxel)
        score_loops(registered, reference, voxel)
        good = sum(lp["correct"] for lp in accepted)
        ate, rpe, n = score(poses, reference)
        rows.append(dict(tool="Open3D PG", ate=ate, rpe=rpe, loops=len(accepted),
                         precision=(good / len(accepted) if accepted else None), time=elapsed, failed="-", scored=n,
                         note=(f"odometry edges from /mireg/pose, loop edges: {source}, {len(registered)} registered, "
                               f"{sum(lp['correct'] for lp in registered)} of them correct; voxel {o3d_voxel:.3f} m")))
        row_loops["Open3D PG"] = accepted

    print(f"ATE = position RMSE after SE(3) Umeyama alignment (no scale), matched by stamp; RPE = mean "
          f"translation error per consecutive frame pair; loop correct if < {LOOP_DEG:g} deg and "
          f"< {LOOP_VOXELS:g} voxels = {LOOP_VOXELS * voxel:.3f} m" if voxel else "")
    print(f"{'tool':10} {'ATE (m)':>9} {'RPE (m)':>9} {'loops acc.':>10} {'loop prec.':>10} {'time (s)':>9} "
          f"{'failed':>7}  notes")
    for r in rows:
        print(f"{r['tool']:10} {r['ate']:9.4f} {r['rpe']:9.4f} {str(r['loops']):>10} {fmt(r['precision'], '10.2f'):>10} "
              f"{r['time']:9.2f} {str(r['failed']):>7}  {r['scored']} frames scored; {r['note']}")
    for name, lps in row_loops.items():
        print_loops(name, lps, voxel)
    print_agreement(trajectories, {r["tool"]: r["ate"] for r in rows})
    for r in rows:
        r["log"] = log
    return rows, row_loops


def main(argv):
    argv, extra = split_mireg_args(argv)
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("logs", nargs="+")
    ap.add_argument("--mireg", default=mireg_run.default_binary())
    ap.add_argument("--topic")
    ap.add_argument("--reference-topic", default="/ground_truth/pose")
    ap.add_argument("--tools", default="mireg,kiss-slam,open3d", help="comma list of mireg, kiss-slam, open3d")
    ap.add_argument("--voxel", type=float, help="voxel [m] of the loop-precision threshold (default: mireg's)")
    ap.add_argument("--kiss-local-map", type=float, help="KISS-SLAM splitting_distance [m] (default: reach / 4)")
    ap.add_argument("--o3d-voxel", type=float, help="Open3D registration voxel [m] (default: --voxel)")
    ap.add_argument("--min-separation", type=int, default=5, help="fallback candidates: frames apart (default 5)")
    ap.add_argument("--candidate-radius", type=float, help="fallback candidates: radius [m] (default 3 x median step)")
    ap.add_argument("--json-out", help="write all rows and loops as JSON")
    args = ap.parse_args(argv)
    if ("open3d" in args.tools or "mireg" in args.tools) and not os.path.exists(args.mireg):
        raise SystemExit(f"{args.mireg}: no mireg binary (cargo build --release, or --mireg PATH); "
                         f"the Open3D rows use its odometry, or run with --tools kiss-slam")
    if "kiss-slam" not in args.tools and args.voxel is None and "mireg" not in args.tools and "open3d" not in args.tools:
        ap.error("nothing to run")
    out = []
    for log in args.logs:
        rows, loops = compare(log, args, extra)
        for r in rows:
            r["loop_list"] = [{k: v for k, v in lp.items() if k != "T"} for lp in loops.get(r["tool"], [])]
        out.extend(rows)
    if args.json_out:
        with open(args.json_out, "w") as f:
            json.dump(out, f, indent=1, default=float)


if __name__ == "__main__":
    main(sys.argv[1:])
