"""Loop closure: the ``/mireg/loops`` candidates as edges, and ``--loop N``'s two clouds."""

from __future__ import annotations

import sys

import numpy as np

from ..run import Loop, Run
from .geometry import nearest_neighbours, transform, voxel_downsample
from .timeline import TIMELINE, colour_map, set_frame_time

ACCEPTED = [0, 255, 0]
REJECTED = [255, 0, 0]
# the loop message's fields shown on an edge (selection panel) and in its log line
EDGE_FIELDS = (
    "query_frame", "match_frame", "query_stamp_ns", "match_stamp_ns", "found_by",
    "descriptor_distance", "odometry_distance_m", "verdict", "reason", "inliers",
    "correspondences", "fitness", "inlier_rmse_m", "odometry_disagreement_m",
    "odometry_disagreement_deg", "weight",
)


def _fmt(v, digits=3) -> str:
    if isinstance(v, float):
        return f"{v:.{digits}g}"
    return "null" if v is None else str(v)


def loop_text(loop: Loop) -> str:
    """One line about a loop candidate: frames, verdict and reason, inliers, fitness, weight."""
    d = loop.data
    verdict = d.get("verdict", "?")
    if verdict != "accepted" and d.get("reason"):
        verdict += f" ({d['reason']})"
    return (
        f"loop {loop.number}: frame {d.get('query_frame')} -> {d.get('match_frame')} "
        f"(found by {d.get('found_by')}): {verdict}; inliers {_fmt(d.get('inliers'))}/"
        f"{_fmt(d.get('correspondences'))}, fitness {_fmt(d.get('fitness'))}, inlier rmse "
        f"{_fmt(d.get('inlier_rmse_m'))} m, vs odometry {_fmt(d.get('odometry_disagreement_m'))} m"
        f" / {_fmt(d.get('odometry_disagreement_deg'))} deg, weight {_fmt(d.get('weight'))}"
    )


def _set_loop_time(rr, loop: Loop) -> None:
    rr.set_time(TIMELINE, timestamp=np.datetime64(loop.log_time, "ns"))
    if loop.query is not None:
        rr.set_time("frame", sequence=loop.query.index)


def log_loops(rr, run: Run, args) -> None:
    """``world/loops/loop_NNNN``: one segment per loop candidate between the match and query
    frames' positions on the optimised trajectory (the odometry where a frame has no optimised
    pose), green if accepted, red if rejected, at the loop message's log time; the label and the
    AnyValues on the same entity carry the message's fields (hover / selection panel), and
    ``log/loops`` has one text line per loop."""
    for loop in run.loops:
        if args.hide_rejected and not loop.accepted:
            continue
        _set_loop_time(rr, loop)
        ends = [f.pose("optimized") if f is not None else None for f in (loop.match, loop.query)]
        text = loop_text(loop)
        if any(e is None for e in ends):
            rr.log("log/loops", rr.TextLog(text + "; a frame of it is not in this run or has "
                                           "no pose: not drawn", level=rr.TextLogLevel.WARN))
            continue
        segment = np.array([e[:3, 3] for e in ends])
        entity = f"world/loops/loop_{loop.number:04d}"
        rr.log(
            entity,
            rr.LineStrips3D(
                [segment],
                colors=[ACCEPTED if loop.accepted else REJECTED],
                radii=0.012 if loop.accepted else 0.006,
                labels=[text],
                show_labels=False,
            ),
        )
        values = {k: loop.data.get(k) for k in EDGE_FIELDS}
        values = {k: (v if not isinstance(v, bool) else str(v)) for k, v in values.items()}
        rr.log(entity, rr.AnyValues(**values))
        rr.log("log/loops", rr.TextLog(text, level=rr.TextLogLevel.INFO))


def log_loop_pair(rr, run: Run, args):
    """``--loop N``: the match cloud in its sensor frame (grey) and the query cloud moved into
    it by ``match_from_query`` (coloured by the distance to its nearest match point, turbo from 0
    to 3× the inlier threshold), both voxel-downsampled, with a yellow segment per query point
    within the inlier threshold; under ``world/loop_pair``, whose transform is the match frame's
    pose on the optimised trajectory, so the pair also sits in place in the world.

    Without a ``match_from_query`` (registration failed) the query cloud is placed by the
    odometry's relative pose instead, and the log line says so. Returns the drawn world points
    and a title (for the loop view's eye)."""
    loop = run.loops[args.loop]
    q, m = loop.query, loop.match
    if q is None or m is None:
        raise SystemExit(f"--loop {args.loop}: its frames are not in this run ({loop.data})")
    if q.points is None or m.points is None:
        raise SystemExit(f"--loop {args.loop}: the clouds of frames {q.index}/{m.index} are missing")
    world_from_match = m.pose("optimized")
    if world_from_match is None:
        raise SystemExit(f"--loop {args.loop}: frame {m.index} has no pose")
    match_from_query = loop.match_from_query()
    placed_by = "match_from_query"
    if match_from_query is None:
        if q.estimate is None or m.estimate is None:
            raise SystemExit(f"--loop {args.loop}: no match_from_query and no odometry poses")
        match_from_query = np.linalg.inv(m.estimate) @ q.estimate
        placed_by = "the odometry (the loop has no match_from_query)"
    cfg = run.pair_config
    voxel = float(cfg.get("voxel_size_m") or 0.05)
    threshold = float(cfg.get("inlier_threshold_m") or 1.5 * voxel)
    match_pts = voxel_downsample(m.points, voxel)
    query_pts = transform(match_from_query, voxel_downsample(q.points, voxel))
    idx, dist = nearest_neighbours(query_pts, match_pts)
    close = dist <= threshold
    set_frame_time(rr, q)
    rr.log(
        "world/loop_pair",
        rr.Transform3D(translation=world_from_match[:3, 3], mat3x3=world_from_match[:3, :3]),
    )
    rr.log("world/loop_pair/match", rr.Points3D(match_pts, colors=[170, 170, 170], radii=0.007))
    rr.log(
        "world/loop_pair/query",
        rr.Points3D(query_pts, colors=colour_map(dist, 0.0, 3.0 * threshold), radii=0.007),
    )
    rr.log(
        "world/loop_pair/inlier_pairs",
        rr.LineStrips3D(np.stack([query_pts[close], match_pts[idx[close]]], axis=1),
                        colors=[255, 255, 0, 80], radii=0.0015),
    )
    median = float(np.median(dist)) if len(dist) else float("nan")
    text = (
        f"{loop_text(loop)}. Drawn: match cloud {m.index} (grey) and query cloud {q.index} placed "
        f"by {placed_by}, voxel {voxel:.4g} m; {int(close.sum())}/{len(query_pts)} query points "
        f"within {threshold:.4g} m of a match point, median distance {median:.3g} m"
    )
    rr.log("log/loop_pair", rr.TextLog(text, level=rr.TextLogLevel.INFO))
    print(text, file=sys.stderr)
    world = transform(world_from_match, np.concatenate([match_pts, query_pts]))
    title = (f"match {m.index} grey, query {q.index} by distance (turbo), "
             f"{loop.data.get('verdict')}")
    return world, title
