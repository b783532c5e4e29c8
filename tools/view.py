#!/usr/bin/env python3
"""Show a mireg output MCAP in the Rerun viewer (rerun-sdk 0.41), save it as .rrd, or screenshot it.

Input: the MCAP written by ``mireg register IN.mcap -o OUT.mcap``. It holds the input channels
unchanged (the PointCloud2 topic, e.g. ``/camera/depth/points``, and ``/ground_truth/pose`` =
reference first_from_camera_k when the input had it) plus ``/tf``, ``/mireg/pose`` (PoseStamped
world_from_frame, world = the first cloud's sensor frame), ``/mireg/stats`` (one JSON object per
frame) and a metadata record ``mireg`` (version, config, seed, command_line, input, topic).
Every output message has the log_time of the cloud it belongs to; that is how clouds, poses and
stats are matched here.

Everything is logged on the ``message_log_time`` timeline (a timestamp in ns, the same name and
unit Rerun's own MCAP importer uses, so ``rerun OUT.mcap`` data lines up with ours) and on a
``frame`` sequence timeline (index of the cloud in the log).

Entity paths
------------
``world``                         static view coordinates (RDF for ``*optical_frame`` clouds, else RFU)
``world/clouds/frame_NNNN``       every ``--every``-th cloud, transformed into the world frame by its
                                  ``/mireg/pose``, at most ``--max-points`` points, coloured by height
                                  (−y for optical frames, +z otherwise) or by ``intensity`` if the
                                  cloud has that field. One entity per cloud so the map accumulates.
``world/trajectory/estimate``     LineStrips3D of the ``/mireg/pose`` positions up to the current frame
``world/trajectory/reference``    LineStrips3D of ``/ground_truth/pose`` (only if the topic exists)
``world/camera``                  Transform3D of the current estimated pose …
``world/camera/axes``             … with Arrows3D for its x (red), y (green), z (blue) axes
``world/failures``                Boxes3D (red) at the pose of every failed frame so far, labelled
``log/failures``                  TextLog (WARN) per failed frame: reason and fallback
``stats/inliers``, ``stats/correspondences``, ``stats/inlier_ratio``, ``stats/hypotheses``,
``stats/best_found_at``, ``stats/fitness``, ``stats/inlier_rmse_m``, ``stats/icp_iterations``
                                  Scalars, one per ``/mireg/stats`` message (null fields are skipped)
``stats/timings_ms/<stage>``      Scalars per stage of ``timings_s`` (decode, downsample, normals,
                                  features, matching, ranking, ransac, icp, register), in ms
``world/pair/target`` (white), ``world/pair/source`` (magenta), ``world/pair/correspondences``
(yellow), ``log/pair``            only with ``--frame K``, see below; shown in a second 3-D view
                                  (the map view leaves them out)

``--frame K`` (correspondences of frame K → K−1): the MCAP does **not** store correspondences, so
this is a *recomputation*: clouds K (source) and K−1 (target) are written as float64 N×3 ``.npy``
files in a temp dir and registered again with ``mireg pair SOURCE TARGET --json`` (binary from
``--mireg``, default ``target/release/mireg``) using the voxel size, inlier threshold and seed of the
``mireg`` metadata record. Both clouds are voxel-downsampled, placed in the world by
world_from_(K−1) (source also by the pair's target_from_source), and every source point whose
nearest target point lies within the inlier threshold (1.5·voxel by default) gets a line segment.
Those are geometric inlier pairs under the recomputed estimate, not the feature correspondences
RANSAC voted with, and the recomputed estimate can differ from the one in the MCAP if the run used
settings the flags here do not reproduce.

Output modes
------------
``--save out.rrd``        write a recording (no viewer, no display needed)
``--screenshot out.png``  write a temporary .rrd, then run the ``rerun`` binary shipped in the
                          rerun-sdk wheel with ``--headless --screenshot-to out.png`` (needs the
                          software Vulkan driver: ``bash tools/setup_viewer_venv.sh --screenshot``)
(default)                 open the viewer (bound to 127.0.0.1) when a display exists

Usage:
    bash tools/setup_viewer_venv.sh
    tools/.venv-viewer/bin/python tools/view.py /tmp/out.mcap --save /tmp/out.rrd
    tools/.venv-viewer/bin/python tools/view.py /tmp/out.mcap --frame 12
    tools/.venv-viewer/bin/python tools/view.py /tmp/out.mcap --screenshot docs/viewer.png
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from mcap.reader import make_reader
from mcap_ros1.decoder import DecoderFactory as Ros1DecoderFactory
from mcap_ros2.decoder import DecoderFactory

TIMELINE = "message_log_time"
MAX_FAILURE_LABELS = 8  # more failure boxes than this: labels hidden (hover shows them)
SCREENSHOT_SETTLE_S = 6.0  # seconds between seeking and shooting (toasts fade, views repaint)
POSE_TOPIC = "/mireg/pose"
STATS_TOPIC = "/mireg/stats"
REFERENCE_TOPIC = "/ground_truth/pose"
POINTCLOUD2 = "sensor_msgs/msg/PointCloud2"
POINTCLOUD2_TYPES = (POINTCLOUD2, "sensor_msgs/PointCloud2")  # ROS 2, ROS 1
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

# sensor_msgs/PointField datatype -> numpy scalar type code
_POINTFIELD_DTYPE = {1: "i1", 2: "u1", 3: "i2", 4: "u2", 5: "i4", 6: "u4", 7: "f4", 8: "f8"}


# --------------------------------------------------------------------------------------------------
# Reading the MCAP (also used by tools/report.py)
# --------------------------------------------------------------------------------------------------


@dataclass
class Frame:
    """One cloud of the log and what mireg wrote for it (matched by log_time)."""

    index: int  # position among the clouds of the cloud topic, 0-based (= stats "frame")
    log_time: int  # ns
    frame_id: str = ""
    points: np.ndarray | None = None  # float64 N×3 in the sensor frame (finite points only)
    intensity: np.ndarray | None = None  # float64 N, if the cloud has an "intensity" field
    estimate: np.ndarray | None = None  # 4×4 world_from_frame from /mireg/pose
    reference: np.ndarray | None = None  # 4×4 from /ground_truth/pose
    stats: dict | None = None  # the /mireg/stats object


@dataclass
class Run:
    """Everything read from one mireg output MCAP."""

    path: Path
    cloud_topic: str
    frames: list[Frame]
    metadata: dict = field(default_factory=dict)  # the "mireg" metadata record (config parsed)
    has_reference: bool = False

    @property
    def config(self) -> dict:
        """The run's configuration from the metadata (``{"pair": {...}, "min_inliers": ...}``)."""
        return self.metadata.get("config") or {}

    @property
    def pair_config(self) -> dict:
        """The pairwise registration config (the ``pair`` table of the run config, if nested)."""
        cfg = self.config
        return cfg.get("pair", cfg) if isinstance(cfg, dict) else {}


def pose_to_matrix(pose) -> np.ndarray:
    """4×4 homogeneous matrix of a geometry_msgs/Pose (position + unit quaternion)."""
    q = pose.orientation
    x, y, z, w = q.x, q.y, q.z, q.w
    n = np.sqrt(x * x + y * y + z * z + w * w)
    x, y, z, w = x / n, y / n, z / n, w / n
    m = np.eye(4)
    m[:3, :3] = [
        [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
        [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
        [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
    ]
    m[:3, 3] = [pose.position.x, pose.position.y, pose.position.z]
    return m


def decode_pointcloud2(msg) -> tuple[np.ndarray, np.ndarray | None]:
    """Points (float64 N×3, finite only) and optional intensity of a decoded PointCloud2.

    Builds a numpy structured dtype from ``msg.fields`` (name, offset, datatype, count) with
    ``itemsize = point_step``, so padding and extra fields of any layout are skipped; honours
    ``is_bigendian`` and a ``row_step`` larger than ``width * point_step``.
    """
    endian = ">" if msg.is_bigendian else "<"
    names, formats, offsets = [], [], []
    for f in msg.fields:
        code = _POINTFIELD_DTYPE.get(f.datatype)
        if code is None or f.name in names:
            continue
        fmt = np.dtype(endian + code)
        names.append(f.name)
        formats.append(fmt if f.count <= 1 else (fmt, (f.count,)))
        offsets.append(f.offset)
    for axis in "xyz":
        if axis not in names:
            raise ValueError(f"PointCloud2 has no field {axis!r} (fields: {names})")
    dtype = np.dtype(
        {"names": names, "formats": formats, "offsets": offsets, "itemsize": msg.point_step}
    )
    data = msg.data if isinstance(msg.data, (bytes, bytearray, memoryview)) else bytes(msg.data)
    width, height = msg.width, msg.height
    if height <= 1 or msg.row_step == width * msg.point_step:
        arr = np.frombuffer(data, dtype=dtype, count=width * height)
    else:
        arr = np.concatenate(
            [
                np.frombuffer(data, dtype=dtype, count=width, offset=r * msg.row_step)
                for r in range(height)
            ]
        )
    xyz = np.stack([arr["x"], arr["y"], arr["z"]], axis=1).astype(np.float64)
    keep = np.isfinite(xyz).all(axis=1)
    if height > 1:  # organised clouds mark "no return" with (0, 0, 0), as mireg drops them
        keep &= (xyz != 0).any(axis=1)
    intensity = None
    if "intensity" in names and arr["intensity"].ndim == 1:
        intensity = arr["intensity"].astype(np.float64)[keep]
    return xyz[keep], intensity


def read_run(path: str | Path, cloud_topic: str | None = None, load_clouds=True,
             reference_topic: str = REFERENCE_TOPIC) -> Run:
    """Read a mireg output MCAP (of a ROS 2, ROS 1 or foxglove-free input: ROS messages in
    ``cdr`` or ``ros1``).

    ``load_clouds``: True (decode every cloud), False (none; only poses and stats), or a set of
    cloud indices to decode (the others keep ``points = None``). ``reference_topic``: the
    PoseStamped topic drawn as the reference trajectory, when the log has it.
    """
    path = Path(path)
    decoders = {}  # channel id -> callable(bytes) -> message
    factory = (DecoderFactory(), Ros1DecoderFactory())
    with open(path, "rb") as f:
        reader = make_reader(f)
        summary = reader.get_summary()
        metadata = {}
        for record in reader.iter_metadata():
            if record.name == "mireg":
                metadata = dict(record.metadata)
                for key in ("config",):
                    if isinstance(metadata.get(key), str):
                        try:
                            metadata[key] = json.loads(metadata[key])
                        except json.JSONDecodeError:
                            pass
        channels = summary.channels.values() if summary else []
        schemas = summary.schemas if summary else {}
        if cloud_topic is None:
            cloud_topic = metadata.get("topic")
        if cloud_topic is None:
            for ch in channels:
                schema = schemas.get(ch.schema_id)
                if schema is not None and schema.name in POINTCLOUD2_TYPES:
                    cloud_topic = ch.topic
                    break
        if cloud_topic is None:
            raise SystemExit(f"{path}: no {POINTCLOUD2} channel found (pass --cloud-topic)")
        has_reference = any(ch.topic == reference_topic for ch in channels)
        # A log registered more than once has its runs' topics in namespaces (/mireg_2/...);
        # the run's metadata names its own.
        pose_topic = metadata.get("pose_topic", POSE_TOPIC)
        stats_topic = metadata.get("stats_topic", STATS_TOPIC)

        frames: list[Frame] = []
        by_time: dict[int, Frame] = {}
        pending = {}  # log_time -> [(kind, value)] for outputs seen before their cloud

        def attach(frame: Frame, kind: str, value):
            setattr(frame, kind, value)

        topics = list(dict.fromkeys([cloud_topic, pose_topic, stats_topic, reference_topic]))
        # log_time_order=True: messages come sorted by log_time, cloud before its outputs is not
        # guaranteed for equal times, hence `pending`.
        for schema, channel, message in reader.iter_messages(topics=topics, log_time_order=True):
            t = message.log_time
            if channel.topic == cloud_topic:
                frame = Frame(index=len(frames), log_time=t)
                frames.append(frame)
                by_time[t] = frame
                wanted = load_clouds is True or (
                    not isinstance(load_clouds, bool) and frame.index in load_clouds
                )
                for kind, value in pending.pop(t, []):
                    attach(frame, kind, value)
                if not wanted:
                    continue
                msg = _decode(decoders, factory, schema, channel, message)
                frame.frame_id = msg.header.frame_id
                frame.points, frame.intensity = decode_pointcloud2(msg)
                continue
            if channel.topic == stats_topic:
                values = [("stats", json.loads(message.data))]
            else:
                pose = pose_to_matrix(_decode(decoders, factory, schema, channel, message).pose)
                # One topic may be both (--reference-topic /mireg/pose).
                values = [(kind, pose) for kind, topic in (("estimate", pose_topic),
                                                           ("reference", reference_topic))
                          if channel.topic == topic]
            for kind, value in values:
                if t in by_time:
                    attach(by_time[t], kind, value)
                else:
                    pending.setdefault(t, []).append((kind, value))
    return Run(path, cloud_topic, frames, metadata, has_reference)


def _decode(decoders, factory, schema, channel, message):
    dec = decoders.get(channel.id)
    if dec is None:
        dec = next((d for d in (f.decoder_for(channel.message_encoding, schema) for f in factory)
                    if d is not None), None)
        if dec is None:
            raise SystemExit(f"cannot decode {channel.topic} ({channel.message_encoding})")
        decoders[channel.id] = dec
    return dec(message.data)


def _toml_value(v) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, (int, float)):
        return repr(float(v)) if isinstance(v, float) else str(v)
    if isinstance(v, str):
        return json.dumps(v)  # a JSON string of plain text is a valid TOML basic string
    if isinstance(v, (list, tuple)):
        return "[" + ", ".join(_toml_value(x) for x in v) + "]"
    raise TypeError(f"cannot write {v!r} as TOML")


def to_toml(d: dict, prefix: str = "") -> str:
    """Minimal TOML for a JSON-like config: scalars/arrays first, then nested tables; None (an
    unset Option in mireg's config) is left out so mireg derives the default."""
    lines, tables = [], []
    for key, value in d.items():
        if value is None:
            continue
        if isinstance(value, dict):
            tables.append((key, value))
        else:
            lines.append(f"{key} = {_toml_value(value)}")
    text = "\n".join(lines) + ("\n" if lines else "")
    for key, value in tables:
        name = f"{prefix}{key}"
        text += f"\n[{name}]\n" + to_toml(value, prefix=name + ".")
    return text


def transform(m: np.ndarray, pts: np.ndarray) -> np.ndarray:
    """Apply a 4×4 rigid transform to N×3 points."""
    return pts @ m[:3, :3].T + m[:3, 3]


def voxel_downsample(pts: np.ndarray, voxel: float) -> np.ndarray:
    """Centroid of the points in each occupied voxel of edge ``voxel`` (same idea as mireg's)."""
    if len(pts) == 0:
        return pts
    keys = np.floor(pts / voxel).astype(np.int64)
    _, inverse, counts = np.unique(keys, axis=0, return_inverse=True, return_counts=True)
    inverse = inverse.reshape(-1)
    sums = np.zeros((len(counts), 3))
    np.add.at(sums, inverse, pts)
    return sums / counts[:, None]


def nearest_neighbours(query: np.ndarray, ref: np.ndarray, chunk=2048):
    """Index into ``ref`` and distance of the nearest neighbour of each query point (brute force)."""
    idx = np.empty(len(query), dtype=np.int64)
    dist = np.empty(len(query))
    ref_sq = (ref * ref).sum(axis=1)
    for s in range(0, len(query), chunk):
        q = query[s : s + chunk]
        d2 = (q * q).sum(axis=1)[:, None] - 2.0 * q @ ref.T + ref_sq[None, :]
        i = d2.argmin(axis=1)
        idx[s : s + chunk] = i
        dist[s : s + chunk] = np.sqrt(np.maximum(d2[np.arange(len(q)), i], 0.0))
    return idx, dist


# --------------------------------------------------------------------------------------------------
# Logging to Rerun
# --------------------------------------------------------------------------------------------------


def up_vector(frame_id: str) -> np.ndarray:
    """'Up' in the world (= first sensor) frame: −y for optical frames (y down), else +z (REP 103)."""
    return np.array([0.0, -1.0, 0.0]) if frame_id.endswith("optical_frame") else np.array([0, 0, 1.0])


def colour_map(values: np.ndarray, lo: float, hi: float) -> np.ndarray:
    """uint8 RGB colours of ``values`` on matplotlib's turbo map between lo and hi."""
    from matplotlib import colormaps

    v = np.clip((values - lo) / max(hi - lo, 1e-9), 0.0, 1.0)
    return (colormaps["turbo"](v)[:, :3] * 255).astype(np.uint8)


def set_frame_time(rr, frame: Frame):
    rr.set_time(TIMELINE, timestamp=np.datetime64(frame.log_time, "ns"))
    rr.set_time("frame", sequence=frame.index)


def make_blueprint(rrb, eyes, collapse_panels: bool, with_reference: bool, frame=None):
    """Layout: 3-D world view left (with ``--frame K`` above a second 3-D view of only the pair);
    stats plots and the failure log right."""
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

    spatial = rrb.Spatial3DView(
        name="world (estimate: white line, reference: green)" if with_reference else "world",
        origin="world",
        contents=["+ $origin/**", "- $origin/pair/**"] if frame is not None else "$origin/**",
        eye_controls=eye_controls(eyes["map"]),
    )
    if frame is not None and "pair" in eyes:
        pair_view = rrb.Spatial3DView(
            name=f"frame {frame} -> {frame - 1}: target white, source magenta, "
            "inlier pairs yellow (recomputed)",
            origin="world",
            contents=["+ $origin/pair/**", "+ $origin/camera/**"],
            eye_controls=eye_controls(eyes["pair"]),
        )
        spatial = rrb.Vertical(spatial, pair_view)
    return rrb.Blueprint(
        rrb.Horizontal(spatial, rrb.Vertical(*stat_plots), column_shares=[3, 2]),
        rrb.TimePanel(timeline=TIMELINE, state="collapsed" if collapse_panels else None),
        collapse_panels=collapse_panels,
    )


def log_run(rr, run: Run, args) -> dict:
    """Log everything; returns the eye placement for the blueprint."""
    frames = run.frames
    frame_id = next((f.frame_id for f in frames if f.frame_id), "")
    up = up_vector(frame_id)
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
        if f.estimate is None:
            continue
        pts, inten = f.points, f.intensity
        if len(pts) > args.max_points:
            sel = rng.choice(len(pts), args.max_points, replace=False)
            pts = pts[sel]
            inten = inten[sel] if inten is not None else None
        world_pts[f.index] = (transform(f.estimate, pts), inten)
    all_pts = (
        np.concatenate([p for p, _ in world_pts.values()]) if world_pts else np.zeros((0, 3))
    )
    use_intensity = bool(world_pts) and all(i is not None for _, i in world_pts.values())
    if use_intensity:
        all_i = np.concatenate([i for _, i in world_pts.values()])
        lo, hi = np.percentile(all_i, [2, 98]) if len(all_i) else (0.0, 1.0)
    else:
        heights = all_pts @ up
        lo, hi = np.percentile(heights, [2, 98]) if len(heights) else (0.0, 1.0)

    est_positions, ref_positions, failures = [], [], []
    for f in frames:
        set_frame_time(rr, f)
        if f.index in world_pts:
            pts, inten = world_pts[f.index]
            colours = colour_map(inten if use_intensity else pts @ up, lo, hi)
            rr.log(
                f"world/clouds/frame_{f.index:04d}",
                rr.Points3D(pts, colors=colours, radii=args.point_radius),
            )
        if f.estimate is not None:
            est_positions.append(f.estimate[:3, 3].copy())
            rr.log(
                "world/trajectory/estimate",
                rr.LineStrips3D([np.array(est_positions)], colors=[255, 255, 255], radii=0.006),
            )
            rr.log(
                "world/camera",
                rr.Transform3D(translation=f.estimate[:3, 3], mat3x3=f.estimate[:3, :3]),
            )
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
        if f.reference is not None:
            ref_positions.append(f.reference[:3, 3].copy())
            rr.log(
                "world/trajectory/reference",
                rr.LineStrips3D([np.array(ref_positions)], colors=[0, 200, 80], radii=0.004),
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
            reason = s.get("failure_reason") or "unknown"
            fallback = s.get("fallback")
            where = f.estimate[:3, 3] if f.estimate is not None else np.zeros(3)
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

    pair_box = log_pair(rr, run, args) if args.frame is not None else None

    # Camera: look at the middle of the map from behind and above the first sensor.
    # Box = 5–95 % of the map points plus the whole trajectory, so both are in the picture.
    traj = np.array(est_positions or [[0.0, 0.0, 0.0]])
    lo_b, hi_b = traj.min(axis=0), traj.max(axis=0)
    if len(all_pts):
        lo_b = np.minimum(lo_b, np.percentile(all_pts, 5, axis=0))
        hi_b = np.maximum(hi_b, np.percentile(all_pts, 95, axis=0))
    centre = (lo_b + hi_b) / 2
    extent = float(np.linalg.norm(hi_b - lo_b)) or 1.0
    forward = np.array([0.0, 0.0, 1.0]) if frame_id.endswith("optical_frame") else np.array([1.0, 0, 0])
    position = centre - forward * 0.8 * extent + up * 0.85 * extent
    eyes = {"map": {"position": position, "look_target": centre, "eye_up": up}}
    if pair_box is not None:
        pc, pe = pair_box
        eyes["pair"] = {
            "position": pc - forward * 0.7 * pe + up * 0.6 * pe,
            "look_target": pc,
            "eye_up": up,
        }
    return eyes


def log_pair(rr, run: Run, args):
    """Recompute frame K's registration with `mireg pair` and draw its geometric inlier pairs."""
    k = args.frame
    src, tgt = run.frames[k], run.frames[k - 1]
    if src.points is None or tgt.points is None or tgt.estimate is None:
        raise SystemExit(f"--frame {k}: clouds or pose missing")
    cfg = run.pair_config
    voxel = float(cfg.get("voxel_size_m") or 0.05)
    threshold = float(cfg.get("inlier_threshold_m") or 1.5 * voxel)
    cmd = [str(args.mireg), "pair"]
    with tempfile.TemporaryDirectory(prefix="mireg_view_") as tmp:
        src_path, tgt_path = Path(tmp, "source.npy"), Path(tmp, "target.npy")
        np.save(src_path, np.ascontiguousarray(src.points, dtype=np.float64))
        np.save(tgt_path, np.ascontiguousarray(tgt.points, dtype=np.float64))
        cmd += [str(src_path), str(tgt_path), "--json"]
        if cfg:
            # the run's full pairwise configuration (sampler, ranking, ICP, seed, ...) as TOML
            config_path = Path(tmp, "pair.toml")
            config_path.write_text(to_toml(cfg))
            cmd += ["--config", str(config_path)]
        else:
            cmd += ["--voxel", repr(voxel)]
            if run.metadata.get("seed") not in (None, ""):
                cmd += ["--seed", str(run.metadata["seed"])]
        proc = subprocess.run(cmd, capture_output=True, text=True, timeout=300)
    if proc.returncode != 0:
        raise SystemExit(f"{' '.join(cmd)} failed ({proc.returncode}):\n{proc.stderr}")
    result = json.loads(proc.stdout)
    target_from_source = np.array(result["target_from_source"], dtype=np.float64)
    world_from_target = tgt.estimate
    tgt_w = transform(world_from_target, voxel_downsample(tgt.points, voxel))
    src_w = transform(world_from_target @ target_from_source, voxel_downsample(src.points, voxel))
    idx, dist = nearest_neighbours(src_w, tgt_w)
    inlier = dist <= threshold
    segments = np.stack([src_w[inlier], tgt_w[idx[inlier]]], axis=1)
    set_frame_time(rr, src)
    rr.log("world/pair/target", rr.Points3D(tgt_w, colors=[255, 255, 255], radii=0.007))
    rr.log("world/pair/source", rr.Points3D(src_w, colors=[255, 0, 255], radii=0.007))
    rr.log(
        "world/pair/correspondences",
        rr.LineStrips3D(segments, colors=[255, 255, 0], radii=0.004),
    )
    text = (
        f"recomputed pair {k}->{k - 1} with `mireg pair` (voxel {voxel} m, inlier threshold "
        f"{threshold} m): success {result.get('success')}, RANSAC inliers "
        f"{result.get('num_inliers')}, correspondences {result.get('num_correspondences')}; "
        f"{int(inlier.sum())}/{len(src_w)} downsampled source points within the threshold"
    )
    if src.stats:
        text += f"; the MCAP's run had {src.stats.get('num_inliers')} inliers"
    rr.log("log/pair", rr.TextLog(text, level=rr.TextLogLevel.INFO))
    print(text, file=sys.stderr)
    both = np.concatenate([tgt_w, src_w])
    lo_b, hi_b = np.percentile(both, 5, axis=0), np.percentile(both, 95, axis=0)
    return (lo_b + hi_b) / 2, float(np.linalg.norm(hi_b - lo_b)) or 1.0


# --------------------------------------------------------------------------------------------------
# main
# --------------------------------------------------------------------------------------------------


def rerun_binary() -> str:
    """The `rerun` CLI shipped in the rerun-sdk wheel (next to this interpreter), else PATH's."""
    candidate = Path(sys.executable).parent / "rerun"
    if candidate.exists():
        return str(candidate)
    found = shutil.which("rerun")
    if found is None:
        raise SystemExit("the `rerun` binary was not found (install rerun-sdk in this venv)")
    return found


def free_port() -> int:
    """A currently free TCP port on 127.0.0.1 (for the headless viewer's gRPC server)."""
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return sock.getsockname()[1]


def stop_group(proc: subprocess.Popen) -> None:
    """SIGTERM the process group led by ``proc`` (started with start_new_session=True), SIGKILL
    after 10 s."""
    for sig in (signal.SIGTERM, signal.SIGKILL):
        try:
            os.killpg(proc.pid, sig)
        except ProcessLookupError:
            break
        deadline = time.monotonic() + 10
        while time.monotonic() < deadline:
            try:
                os.killpg(proc.pid, 0)  # any member left?
            except ProcessLookupError:
                proc.wait()
                return
            proc.poll()
            time.sleep(0.1)
    proc.wait()


def screenshot(
    rrd: Path, png: Path, window_size: str, timeout: float, end_ns: int | None, colors: int = 0
) -> None:
    """Render ``rrd`` with the headless viewer and write ``png``.

    Starts ``rerun RRD --headless --bind 127.0.0.1 --port <free>`` (the binary from the rerun-sdk
    wheel), drives it with ``rerun.experimental.ViewerClient``: waits until the recording is
    loaded up to ``end_ns`` on ``message_log_time``, puts the time cursor there (paused, so the
    whole accumulated map is shown), lets start-up notifications fade, takes the screenshot and
    stops the viewer. ``colors`` > 0 quantizes the PNG to that many colours (smaller file).
    ``rerun --screenshot-to`` alone shoots the first painted frame, before the
    data has loaded, which is why it is not used here.
    """
    from rerun.experimental import ViewerClient

    png.parent.mkdir(parents=True, exist_ok=True)
    port = free_port()
    cmd = [rerun_binary(), str(rrd), "--headless", "--window-size", window_size,
           "--bind", "127.0.0.1", "--port", str(port)]
    env = dict(os.environ, RERUN_ANALYTICS="0")
    log = tempfile.TemporaryFile(mode="w+")
    # Own session: the wheel's `rerun` is a Python launcher that starts the real viewer binary as a
    # child, so the whole process group has to be stopped afterwards, not just the launcher.
    proc = subprocess.Popen(
        cmd, stdout=log, stderr=subprocess.STDOUT, env=env, start_new_session=True
    )
    deadline = time.monotonic() + timeout

    def fail(why: str):
        log.seek(0)
        tail = log.read()[-3000:]
        raise SystemExit(
            f"screenshot failed: {why}\n{' '.join(cmd)}\n{tail}\nHeadless rendering needs a "
            "Vulkan driver (mesa lavapipe): bash tools/setup_viewer_venv.sh --screenshot"
        )

    try:
        client, last_error = None, None
        while client is None:
            if proc.poll() is not None:
                fail(f"viewer exited with {proc.returncode}")
            if time.monotonic() > deadline:
                fail(f"no connection to the viewer: {last_error}")
            try:
                candidate = ViewerClient.connect(f"rerun+http://127.0.0.1:{port}/proxy")
                candidate.get_state()
                client = candidate
            except Exception as e:  # not listening yet
                last_error = e
                time.sleep(0.5)
        while True:  # wait for the data (the viewer streams the .rrd in lazily)
            state = client.get_state()
            ends = [t.end for r in state.recordings for t in r.timelines if t.name == TIMELINE]
            if not state.loading and ends and (end_ns is None or max(ends) >= end_ns):
                break
            if time.monotonic() > deadline:
                fail("the recording did not finish loading")
            time.sleep(0.3)
        seek = end_ns if end_ns is not None else max(ends)
        client.set_time(TIMELINE, timestamp=np.datetime64(seek, "ns"), play_state="paused")
        time.sleep(SCREENSHOT_SETTLE_S)  # let the views render and the toasts fade
        data = client.take_screenshot()
        if not data:
            fail("empty screenshot")
        png.write_bytes(data)
        if colors:
            from PIL import Image  # Pillow comes with matplotlib

            with Image.open(png) as image:
                image.convert("RGB").quantize(colors=colors).save(png, optimize=True)
    finally:
        stop_group(proc)
        log.close()


def parse_args(argv=None):
    p = argparse.ArgumentParser(
        description=__doc__.split("\n\n")[0],
        formatter_class=argparse.RawDescriptionHelpFormatter,
        epilog="Entity paths and the --frame recomputation are described in the module docstring.",
    )
    p.add_argument("mcap", type=Path, help="output MCAP of `mireg register`")
    out = p.add_mutually_exclusive_group()
    out.add_argument("--save", type=Path, metavar="OUT.rrd", help="write a .rrd recording")
    out.add_argument("--screenshot", type=Path, metavar="OUT.png", help="headless screenshot")
    p.add_argument("--every", type=int, default=1, metavar="N", help="show every N-th cloud")
    p.add_argument("--max-points", type=int, default=10000, help="points per cloud at most")
    p.add_argument("--frame", type=int, metavar="K", help="recompute and draw the correspondences "
                   "of frame K -> K-1 (calls mireg pair)")
    p.add_argument("--mireg", type=Path, default=Path("target/release/mireg"),
                   help="mireg binary for --frame (default: %(default)s)")
    p.add_argument("--cloud-topic", help="PointCloud2 topic (default: from the mireg metadata)")
    p.add_argument("--reference-topic", default=REFERENCE_TOPIC, metavar="TOPIC",
                   help="PoseStamped topic drawn as the reference trajectory, when present "
                        "(default %(default)s)")
    p.add_argument("--point-radius", type=float, default=0.01, help="point radius [m]")
    p.add_argument("--axis-length", type=float, default=0.15, help="pose axes length [m]")
    p.add_argument("--window-size", default="1280x800", help="screenshot size (default %(default)s)")
    p.add_argument("--timeout", type=float, default=180.0, help="screenshot timeout [s]")
    p.add_argument("--png-colors", type=int, default=0, metavar="N",
                   help="quantize the screenshot to N colours (e.g. 256 for docs), 0 = keep")
    args = p.parse_args(argv)
    if args.every < 1:
        p.error("--every must be >= 1")
    if args.max_points < 1:
        p.error("--max-points must be >= 1")
    if args.frame is not None and args.frame < 1:
        p.error("--frame K needs K >= 1 (frame 0 has no predecessor)")
    return args


def main(argv=None) -> int:
    args = parse_args(argv)
    import rerun as rr
    import rerun.blueprint as rrb

    run = read_run(args.mcap, args.cloud_topic, load_clouds=True,
                   reference_topic=args.reference_topic)
    if args.frame is not None and args.frame >= len(run.frames):
        raise SystemExit(f"--frame {args.frame}: the log has {len(run.frames)} clouds")
    has_display = bool(os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY"))
    if args.save is None and args.screenshot is None and not has_display:
        raise SystemExit("no display: use --save out.rrd or --screenshot out.png")

    rr.init("mireg_view", spawn=False)
    rr.set_log_time_enabled(False)  # no wall-clock "log_time" timeline next to message_log_time
    tmpdir = None
    if args.save is not None:
        rrd = args.save
        rrd.parent.mkdir(parents=True, exist_ok=True)
    else:
        tmpdir = tempfile.TemporaryDirectory(prefix="mireg_view_")
        rrd = Path(tmpdir.name, "view.rrd")
    # Until a sink is set the recording stream buffers everything; rr.save then writes the buffer,
    # so the blueprint (whose camera depends on the data) can be made after logging.
    eyes = log_run(rr, run, args)
    blueprint = make_blueprint(
        rrb,
        eyes,
        collapse_panels=args.screenshot is not None,
        with_reference=run.has_reference,
        frame=args.frame,
    )
    rr.save(rrd, default_blueprint=blueprint)
    n_failed = sum(1 for f in run.frames if f.stats and not f.stats.get("success", True))
    print(
        f"{args.mcap}: {len(run.frames)} clouds on {run.cloud_topic}, "
        f"{n_failed} failed, reference {'yes' if run.has_reference else 'no'}",
        file=sys.stderr,
    )
    try:
        if args.save is not None:
            print(f"wrote {rrd}", file=sys.stderr)
        elif args.screenshot is not None:
            # with --frame K show the scene at frame K (its pair on top of the map so far)
            end_ns = (
                run.frames[args.frame].log_time
                if args.frame is not None
                else max((f.log_time for f in run.frames), default=None)
            )
            screenshot(
                rrd, args.screenshot, args.window_size, args.timeout, end_ns, args.png_colors
            )
            print(f"wrote {args.screenshot}", file=sys.stderr)
        else:
            subprocess.run([rerun_binary(), str(rrd), "--bind", "127.0.0.1"], check=False)
    finally:
        if tmpdir is not None:
            tmpdir.cleanup()
    return 0


if __name__ == "__main__":
    sys.exit(main())
