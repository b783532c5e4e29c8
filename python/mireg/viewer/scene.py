"""Logging a run to Rerun: clouds, map, trajectories, camera, stats, failures; the blueprint."""

from __future__ import annotations

import numpy as np

from ..run import Run
from .geometry import subsample, transform, voxel_downsample
from .loops import log_loop_pair, log_loops
from .mapfile import load_map
from .pair import log_pair
from .timeline import colour_map, set_frame_time, up_vector, value_range

MAX_FAILURE_LABELS = 8  # more failure boxes than this: labels hidden (hover shows them)
STAT_SERIES = (
    "num_inliers",
    "num_correspondences",
    "inlier_ratio",
    "hypotheses",
    "best_found_at",
    "fitness",
    "inlier_rmse_m",
    "icp_iterations",
)
# Entity names of the stats series (shorter than the JSON keys where that reads better).
STAT_ENTITY = {"num_inliers": "inliers", "num_correspondences": "correspondences"}
STAGES = (
    "decode",
    "downsample",
    "normals",
    "features",
    "matching",
    "ranking",
    "ransac",
    "icp",
    "register",
)
# (entity, Frame attribute, colour, radius) of the trajectories
TRAJECTORIES = (
    ("estimate", "estimate", [255, 255, 255], 0.006),  # odometry, /mireg/pose
    ("optimized", "optimized", [255, 150, 0], 0.006),  # loop-closed, /mireg/pose_optimized
    ("reference", "reference", [0, 200, 80], 0.004),  # /ground_truth/pose
)


def make_blueprint(rrb, eyes, collapse_panels: bool, run: Run, frame=None, loop=None):
    """Layout: 3-D world view left (with ``--frame K`` / ``--loop N`` above a second 3-D view of
    only the pair); stats plots and the logs (failures, loops, pair) right."""
    stat_plots = [
        rrb.TimeSeriesView(
            name="inliers / correspondences",
            origin="stats",
            contents=["stats/inliers", "stats/correspondences"],
        ),
        rrb.TimeSeriesView(name="inlier ratio", origin="stats", contents=["stats/inlier_ratio"]),
        rrb.TimeSeriesView(name="hypotheses", origin="stats", contents=["stats/hypotheses"]),
        rrb.TimeSeriesView(name="timings [ms]", origin="stats/timings_ms"),
        rrb.TextLogView(name="log", origin="log"),
    ]

    def eye_controls(eye):
        return rrb.EyeControls3D(
            kind=rrb.Eye3DKind.Orbital,
            position=eye["position"],
            look_target=eye["look_target"],
            eye_up=eye["eye_up"],
        )

    legend = ["odometry white"]
    if run.has_optimized:
        legend.append("optimised orange")
    if run.has_reference:
        legend.append("reference green")
    if run.loops:
        legend.append("loops: accepted green, rejected red")
    excluded = [p for p, on in (("pair", frame is not None), ("loop_pair", loop is not None)) if on]
    spatial = rrb.Spatial3DView(
        name=f"world ({', '.join(legend)})",
        origin="world",
        contents=["+ $origin/**"] + [f"- $origin/{p}/**" for p in excluded],
        eye_controls=eye_controls(eyes["map"]),
    )
    pair_views = []
    if frame is not None and "pair" in eyes:
        pair_views.append(rrb.Spatial3DView(
            name=f"frame {frame} -> {frame - 1}: target white, source magenta, "
            "inlier pairs yellow (recomputed)",
            origin="world",
            contents=["+ $origin/pair/**", "+ $origin/camera/**"],
            eye_controls=eye_controls(eyes["pair"]),
        ))
    if loop is not None and "loop_pair" in eyes:
        pair_views.append(rrb.Spatial3DView(
            name=f"loop {loop}: {eyes['loop_pair']['title']}",
            origin="world",
            contents=["+ $origin/loop_pair/**"],
            eye_controls=eye_controls(eyes["loop_pair"]),
        ))
    if pair_views:
        spatial = rrb.Vertical(spatial, *pair_views)
    return rrb.Blueprint(
        rrb.Horizontal(spatial, rrb.Vertical(*stat_plots), column_shares=[3, 2]),
        rrb.TimePanel(timeline="message_log_time",
                      state="collapsed" if collapse_panels else None),
        collapse_panels=collapse_panels,
    )


def eye_on(centre, extent, up, forward, back=0.7, above=0.6) -> dict:
    """An orbital eye behind and above ``centre`` at a distance proportional to ``extent``."""
    return {"position": centre - forward * back * extent + up * above * extent,
            "look_target": centre, "eye_up": up}


def bounds_of(pts: np.ndarray) -> tuple[np.ndarray, float]:
    """Centre and diagonal of the 5–95 % box of ``pts``."""
    lo, hi = np.percentile(pts, 5, axis=0), np.percentile(pts, 95, axis=0)
    return (lo + hi) / 2, float(np.linalg.norm(hi - lo)) or 1.0


def log_map(rr, run: Run, args, up, rng) -> np.ndarray:
    """``world/map`` (static): the ``--map`` file, or with ``--map-voxel V`` a map built here
    from every cloud placed by the placing trajectory. Returns the logged points."""
    if args.map is not None:
        pts, inten = load_map(args.map)
        source = f"{args.map}"
    elif args.map_voxel:
        parts, parts_i = [], []
        for f in run.frames:
            pose = f.pose(args.placing)
            if f.points is None or pose is None:
                continue
            sel = subsample(rng, len(f.points), args.max_points)
            parts.append(transform(pose, f.points[sel]))
            parts_i.append(f.intensity[sel] if f.intensity is not None else None)
        if not parts:
            return np.zeros((0, 3))
        pts = np.concatenate(parts)
        if all(i is not None for i in parts_i):
            pts, inten = voxel_downsample(pts, args.map_voxel, np.concatenate(parts_i))
        else:
            pts, inten = voxel_downsample(pts, args.map_voxel), None
        source = f"{len(parts)} clouds by {args.placing}, voxel {args.map_voxel} m"
    else:
        return np.zeros((0, 3))
    sel = subsample(rng, len(pts), args.map_max_points)
    pts, inten = pts[sel], (inten[sel] if inten is not None else None)
    values = inten if inten is not None else pts @ up
    colours = colour_map(values, *value_range(values))
    rr.log("world/map", rr.Points3D(pts, colors=colours, radii=args.point_radius), static=True)
    rr.log("log/map", rr.TextLog(f"map: {len(pts)} points from {source}"), static=True)
    return pts


def log_run(rr, run: Run, args) -> dict:
    """Log everything; returns the eye placements for the blueprint."""
    frames = run.frames
    frame_id = next((f.frame_id for f in frames if f.frame_id), "")
    up = up_vector(frame_id)
    placing = args.placing
    rr.log(
        "world",
        rr.ViewCoordinates.RDF if frame_id.endswith("optical_frame") else rr.ViewCoordinates.RFU,
        static=True,
    )
    rng = np.random.default_rng(0)
    shown = [f for f in frames if f.index % args.every == 0 and f.points is not None]
    if args.frame is not None:
        # the frame of interest is always shown, whatever --every says
        extra = [frames[args.frame]] if frames[args.frame] not in shown else []
        shown = sorted(shown + extra, key=lambda f: f.index)

    # World points of the shown clouds (subsampled), for colours and the camera placement.
    world_pts = {}
    for f in shown:
        pose = f.pose(placing)
        if pose is None:
            continue
        pts, inten = f.points, f.intensity
        sel = subsample(rng, len(pts), args.max_points)
        pts, inten = pts[sel], (inten[sel] if inten is not None else None)
        world_pts[f.index] = (transform(pose, pts), inten)
    all_pts = (
        np.concatenate([p for p, _ in world_pts.values()]) if world_pts else np.zeros((0, 3))
    )
    use_intensity = bool(world_pts) and all(i is not None for _, i in world_pts.values())
    if use_intensity:
        lo, hi = value_range(np.concatenate([i for _, i in world_pts.values()]))
    else:
        lo, hi = value_range(all_pts @ up)
    map_pts = log_map(rr, run, args, up, rng)

    # The reference laid onto the trajectory placing the clouds as `mireg evaluate` aligns them
    # (SE(3) Umeyama over the stamp-paired poses): a reference in a frame of its own (a rotated
    # start, another origin) is drawn where it belongs, not as a failure.
    aligned = {"reference": run.estimate_from_reference(placing)} if run.has_reference else {}
    positions = {name: [] for name, *_ in TRAJECTORIES}
    failures = []
    for f in frames:
        set_frame_time(rr, f)
        if f.index in world_pts:
            pts, inten = world_pts[f.index]
            colours = colour_map(inten if use_intensity else pts @ up, lo, hi)
            rr.log(
                f"world/clouds/frame_{f.index:04d}",
                rr.Points3D(pts, colors=colours, radii=args.point_radius),
            )
        for name, attr, colour, radius in TRAJECTORIES:
            pose = getattr(f, attr)
            if pose is None:
                continue
            if name in aligned:
                pose = aligned[name] @ pose
            positions[name].append(pose[:3, 3].copy())
            rr.log(
                f"world/trajectory/{name}",
                rr.LineStrips3D([np.array(positions[name])], colors=[colour], radii=radius),
            )
        pose = f.pose(placing)
        if pose is not None:
            rr.log("world/camera", rr.Transform3D(translation=pose[:3, 3], mat3x3=pose[:3, :3]))
            axis = args.axis_length
            rr.log(
                "world/camera/axes",
                rr.Arrows3D(
                    origins=np.zeros((3, 3)),
                    vectors=np.eye(3) * axis,
                    colors=[[255, 0, 0], [0, 255, 0], [0, 0, 255]],
                    radii=axis * 0.04,
                ),
            )
        s = f.stats
        if s is None:
            continue
        for key in STAT_SERIES:
            value = s.get(key)
            if value is not None:
                rr.log(f"stats/{STAT_ENTITY.get(key, key)}", rr.Scalars(float(value)))
        for stage, value in (s.get("timings_s") or {}).items():
            if value is not None:
                rr.log(f"stats/timings_ms/{stage}", rr.Scalars(1000.0 * float(value)))
        if not s.get("success", True):
            log_failure(rr, f, pose, failures)

    log_loops(rr, run, args)
    eyes = {}
    if args.frame is not None:
        eyes["pair"] = log_pair(rr, run, args)
    if args.loop is not None:
        eyes["loop_pair"] = log_loop_pair(rr, run, args)

    # Camera: look at the middle of the map from behind and above the first sensor.
    # Box = 5–95 % of the map points plus the whole (placing) trajectory, so both are in the picture.
    placed = [f.pose(placing)[:3, 3] for f in frames if f.pose(placing) is not None]
    traj = np.array(placed or [[0.0, 0.0, 0.0]])
    lo_b, hi_b = traj.min(axis=0), traj.max(axis=0)
    cloud_pts = all_pts if len(all_pts) else map_pts
    if len(cloud_pts):
        lo_b = np.minimum(lo_b, np.percentile(cloud_pts, 5, axis=0))
        hi_b = np.maximum(hi_b, np.percentile(cloud_pts, 95, axis=0))
    centre = (lo_b + hi_b) / 2
    extent = float(np.linalg.norm(hi_b - lo_b)) or 1.0
    forward = np.array([0.0, 0.0, 1.0]) if frame_id.endswith("optical_frame") else np.array([1.0, 0, 0])
    out = {"map": eye_on(centre, extent, up, forward, back=0.8, above=0.85)}
    for key, value in eyes.items():
        if value is not None:
            pts, title = value
            out[key] = dict(eye_on(*bounds_of(pts), up, forward), title=title)
    return out


def log_failure(rr, f, pose, failures: list) -> None:
    """Red boxes at every failed frame so far, and a WARN log line for this one."""
    s = f.stats
    reason = s.get("failure_reason") or "unknown"
    fallback = s.get("fallback")
    where = pose[:3, 3] if pose is not None else np.zeros(3)
    failures.append((where, f"frame {f.index}: {reason}"))
    rr.log(
        "world/failures",
        rr.Boxes3D(
            centers=[w for w, _ in failures],
            half_sizes=[[0.05, 0.05, 0.05]] * len(failures),
            colors=[255, 0, 0],
            labels=[label for _, label in failures],
            show_labels=len(failures) <= MAX_FAILURE_LABELS,
            radii=0.006,
        ),
    )
    rr.log(
        "log/failures",
        rr.TextLog(
            f"frame {f.index} (log_time {f.log_time} ns) failed: {reason}; "
            f"fallback: {fallback or 'none'}; inliers {s.get('num_inliers')}, "
            f"correspondences {s.get('num_correspondences')}",
            level=rr.TextLogLevel.WARN,
        ),
    )
