"""Reading a ``mireg register`` output: its trajectories, per-frame statistics, loops and clouds,
through the crate's own MCAP readers (the same code as ``mireg evaluate``), no Python decoder.

``read_trajectory`` gives one PoseStamped topic as arrays; ``read_run`` gives a whole run (the
newest one of the log, or the one a metadata record names) as :class:`Run`, which the viewer and
the report draw.
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Optional, Union

import numpy as np

from . import _mireg

PathLike = Union[str, "os.PathLike[str]"]

POSE_TOPIC = "/mireg/pose"
REFERENCE_TOPIC = "/ground_truth/pose"
POINTCLOUD2_TYPES = ("sensor_msgs/msg/PointCloud2", "sensor_msgs/PointCloud2")  # ROS 2, ROS 1
MCAP_MAGIC = b"\x89MCAP0\r\n"
# evaluate's default for pairing a pose with a reference pose by stamp [s] (`--max-dt`)
MAX_DT_S = 0.01


def _matrices(values) -> np.ndarray:
    return np.asarray(values, dtype=np.float64).reshape(-1, 4, 4)


def _quaternion_matrix(xyzw) -> np.ndarray:
    x, y, z, w = (float(v) for v in xyzw)
    n = x * x + y * y + z * z + w * w
    s = 2.0 / n if n > 0 else 0.0
    m = np.eye(4)
    m[:3, :3] = [
        [1 - s * (y * y + z * z), s * (x * y - z * w), s * (x * z + y * w)],
        [s * (x * y + z * w), 1 - s * (x * x + z * z), s * (y * z - x * w)],
        [s * (x * z - y * w), s * (y * z + x * w), 1 - s * (x * x + y * y)],
    ]
    return m


def _check_output(path: Path) -> None:
    """A message naming ``path`` and what to run when it is not an MCAP file (a bag, a folder)."""
    hint = (f"`mireg register {path}` registers a log (MCAP, ROS 1 bag or ROS 2 bag directory) "
            "and writes the output this reads")
    if path.is_dir():
        raise ValueError(f"{path}: a directory, not a mireg output MCAP; {hint}")
    with open(path, "rb") as f:
        if f.read(len(MCAP_MAGIC)) != MCAP_MAGIC:
            raise ValueError(f"{path}: not an MCAP file; {hint}")


def read_trajectory(path: PathLike, topic: Optional[str] = None
                    ) -> tuple[np.ndarray, np.ndarray]:
    """``(stamps_ns, poses)`` of a PoseStamped topic of an MCAP (ROS 1 or ROS 2), sorted by
    header stamp: ``stamps_ns`` int64 ``(N,)``, ``poses`` float64 ``(N, 4, 4)``
    ``world_from_frame``. ``topic``: default the trajectory ``mireg evaluate`` scores (the newest
    run's loop-closed one when the log has it, else its odometry)."""
    path = Path(os.fspath(path))
    _check_output(path)
    if topic is None:
        topic = _default_estimate_topic(path)
    (stamps, values), = _mireg.read_pose_topics(path, [topic])
    return np.asarray(stamps, dtype=np.int64), _matrices(values)


def _default_estimate_topic(path: Path) -> str:
    run = read_run(path, load_clouds=False)
    return run.topics["optimized"] if run.has_optimized else run.topics["pose"]


@dataclass
class Frame:
    """One registered cloud of the run, with what mireg wrote for it."""

    index: int
    """Position among the clouds of the cloud topic, 0-based (the stats' ``frame``)."""
    log_time: int
    """Log time of the cloud [ns] (the stats message's)."""
    frame_id: str = ""
    stamp_ns: Optional[int] = None
    """The cloud's header stamp [ns] (= the stamp of its poses)."""
    points: Optional[np.ndarray] = None
    """float64 ``(N, 3)`` in the sensor frame, as ``mireg.read_clouds`` reads them."""
    intensity: Optional[np.ndarray] = None
    """float64 ``(N,)``, when the cloud has intensities."""
    estimate: Optional[np.ndarray] = None
    """4×4 ``world_from_frame`` of the odometry (``/mireg/pose``)."""
    optimized: Optional[np.ndarray] = None
    """4×4 ``world_from_frame`` after loop closure (``/mireg/pose_optimized``)."""
    reference: Optional[np.ndarray] = None
    """4×4 reference pose paired by stamp, in the reference's own world (see
    :meth:`Run.estimate_from_reference`)."""
    stats: Optional[dict] = None
    """The frame's ``/mireg/stats`` object."""

    def pose(self, which: str) -> Optional[np.ndarray]:
        """``"optimized"`` (falling back to the odometry), ``"estimate"`` or ``"reference"``."""
        if which == "optimized":
            return self.optimized if self.optimized is not None else self.estimate
        return getattr(self, which)


@dataclass
class Loop:
    """One ``/mireg/loops`` message (a loop candidate tried), resolved to the run's frames."""

    number: int
    """Position among the loop messages, 0-based."""
    log_time: int
    """ns (= the query cloud's log time)."""
    data: dict
    """The JSON object as written."""
    query: Optional[Frame] = None
    match: Optional[Frame] = None

    @property
    def accepted(self) -> bool:
        return self.data.get("verdict") == "accepted"

    def match_from_query(self) -> Optional[np.ndarray]:
        """4×4 ``p_match = T·p_query``, or None when the loop's registration failed."""
        t = self.data.get("match_from_query")
        if not t:
            return None
        m = _quaternion_matrix(t["rotation_xyzw"])
        m[:3, 3] = t["translation"]
        return m


@dataclass
class Run:
    """One run of ``mireg register`` read from its output MCAP."""

    path: Path
    cloud_topic: str
    frames: list
    """:class:`Frame` per registered cloud, in order."""
    metadata: dict = field(default_factory=dict)
    """The run's ``mireg`` metadata record (``config`` parsed)."""
    has_reference: bool = False
    has_optimized: bool = False
    loops: list = field(default_factory=list)
    topics: dict = field(default_factory=dict)
    """kind -> topic read (``pose``, ``stats``, ``optimized``, ``loops``, ``reference``,
    ``cloud``)."""

    @property
    def config(self) -> dict:
        """The run's configuration (``{"pair": {...}, "min_inliers": ...}``)."""
        return self.metadata.get("config") or {}

    @property
    def pair_config(self) -> dict:
        """The pairwise registration configuration (the ``pair`` table of the run's)."""
        cfg = self.config
        return cfg.get("pair", cfg) if isinstance(cfg, dict) else {}

    def evaluate(self, trajectory: str = "optimized", max_dt_s: float = MAX_DT_S) -> dict:
        """``mireg evaluate``'s evaluation of the run's ``"optimized"`` (loop-closed, else
        odometry) or ``"estimate"`` (odometry) trajectory against the reference topic: ATE, RPE,
        drift, per-frame rows, and ``reference_from_estimate`` (4×4, the SE(3) alignment ATE
        uses)."""
        if not self.has_reference:
            raise ValueError(f"{self.path}: no reference poses on {self.topics['reference']}")
        topic = (self.topics["optimized"] if trajectory == "optimized" and self.has_optimized
                 else self.topics["pose"])
        text, rows = _mireg.evaluate_topics(self.path, topic, self.topics["reference"],
                                            self.topics["stats"], max_dt_s)
        out = json.loads(text)
        out["reference_from_estimate"] = _matrices(rows)[0]
        return out

    def estimate_from_reference(self, trajectory: str = "optimized") -> np.ndarray:
        """4×4 that lays the reference onto the estimate as ``mireg evaluate`` aligns them (the
        inverse of its ``reference_from_estimate``); the identity when the run has no reference
        or too few poses pair up."""
        try:
            return np.linalg.inv(self.evaluate(trajectory)["reference_from_estimate"])
        except ValueError:
            return np.eye(4)


def run_topics(metadata: dict, reference_topic: str = REFERENCE_TOPIC) -> dict:
    """kind -> topic of one run. A log registered more than once has its runs' topics in
    namespaces (``/mireg_2/...``); the run's metadata names its own, and topics older metadata
    does not name (pose_optimized, loops) are taken from the pose topic's namespace."""
    pose = metadata.get("pose_topic", POSE_TOPIC)
    ns = pose[: -len("/pose")] if pose.endswith("/pose") else "/mireg"
    return {
        "pose": pose,
        "stats": metadata.get("stats_topic", ns + "/stats"),
        "optimized": metadata.get("pose_optimized_topic", ns + "/pose_optimized"),
        "loops": metadata.get("loops_topic", ns + "/loops"),
        "reference": reference_topic,
    }


def _is_cloud_schema(name: str) -> bool:
    pkg, _, msg = name.replace("/msg/", "/").partition("/")
    return name in POINTCLOUD2_TYPES or (msg == "CustomMsg" and pkg.startswith("livox"))


def _nearest(stamps: np.ndarray, stamp: int, max_dt_ns: int) -> Optional[int]:
    """Index of the stamp nearest ``stamp`` within ``max_dt_ns`` (``stamps`` sorted)."""
    if len(stamps) == 0:
        return None
    i = int(np.searchsorted(stamps, stamp))
    best = min((j for j in (i - 1, i) if 0 <= j < len(stamps)),
               key=lambda j: abs(int(stamps[j]) - stamp))
    return best if abs(int(stamps[best]) - stamp) <= max_dt_ns else None


def read_run(path: PathLike, cloud_topic: Optional[str] = None, load_clouds=True,
             reference_topic: str = REFERENCE_TOPIC) -> Run:
    """Read the newest run of a ``mireg register`` output MCAP (ROS 1 or ROS 2).

    ``load_clouds``: True (every cloud's points), False (none: poses, stats and loops only; the
    first cloud is still read for its ``frame_id``), or a set of frame indices. Frames are the
    run's ``/mireg/stats`` messages; odometry, loop-closed and reference poses are paired with
    them by header stamp (the reference within ``mireg evaluate``'s default 10 ms), clouds by
    log time, loops by their frames' stamps (else ``query_frame`` / ``match_frame``).
    ``reference_topic``: the PoseStamped topic read as the reference, when the log has it.

    Raises ``ValueError`` naming the file for an input that is not a ``mireg register`` output
    (a raw bag or MCAP, a folder), with what to run first.
    """
    path = Path(os.fspath(path))
    _check_output(path)
    channels = _mireg.channels(path)
    present = {c[0] for c in channels}
    json_topics = sorted({c[0] for c in channels if c[2] == "json"})
    records, messages = _mireg.read_json_topics(path, json_topics)
    metadata: dict = {}
    for name, entries in records:
        if name == "mireg":  # the newest run's record is the last one written
            metadata = dict(entries)
    if isinstance(metadata.get("config"), str):
        try:
            metadata["config"] = json.loads(metadata["config"])
        except json.JSONDecodeError:
            pass
    topics = run_topics(metadata, reference_topic)
    if topics["pose"] not in present or topics["stats"] not in present:
        raise ValueError(
            f"{path}: not a mireg register output (no {topics['pose']} and {topics['stats']} "
            f"topics); run `mireg register {path}` first and open the output it writes")
    if cloud_topic is None:
        cloud_topic = metadata.get("topic")
    if cloud_topic is None:
        cloud_topic = next((c[0] for c in channels if _is_cloud_schema(c[1])), None)
    if cloud_topic is None or cloud_topic not in present:
        raise ValueError(f"{path}: no point cloud topic {cloud_topic or ''} (pass cloud_topic)")
    topics["cloud"] = cloud_topic
    has_reference = reference_topic in present
    has_optimized = topics["optimized"] in present

    stats_k, loops_k = (json_topics.index(topics[k]) if topics[k] in json_topics else -1
                        for k in ("stats", "loops"))
    frames: list[Frame] = []
    loop_msgs = []
    for k, log_time, text in messages:
        if k == stats_k:
            s = json.loads(text)
            stamp = s.get("stamp_ns") if isinstance(s.get("stamp_ns"), int) else None
            frames.append(Frame(index=int(s.get("frame", len(frames))), log_time=log_time,
                                stamp_ns=stamp, stats=s))
        elif k == loops_k:
            loop_msgs.append((log_time, json.loads(text)))
    frames.sort(key=lambda f: f.index)

    wanted = [topics["pose"]] + [t for t, on in ((topics["optimized"], has_optimized),
                                                 (reference_topic, has_reference)) if on]
    poses = dict(zip(wanted, _mireg.read_pose_topics(path, wanted)))
    by_stamp = {f.stamp_ns: f for f in frames if f.stamp_ns is not None}
    for topic, attr in ((topics["pose"], "estimate"), (topics["optimized"], "optimized")):
        if topic in poses:
            stamps, values = poses[topic]
            for stamp, m in zip(stamps, _matrices(values)):
                frame = by_stamp.get(stamp)
                if frame is not None:
                    setattr(frame, attr, m)
    if has_reference:
        stamps, values = poses[reference_topic]
        stamps, mats = np.asarray(stamps, dtype=np.int64), _matrices(values)
        for f in frames:
            j = None if f.stamp_ns is None else _nearest(stamps, f.stamp_ns,
                                                         round(MAX_DT_S * 1e9))
            if j is not None:
                f.reference = mats[j]

    by_time = {f.log_time: f for f in frames}
    reader = _mireg.CloudReader(os.fspath(path), cloud_topic)
    try:
        for _, points, fields in reader:
            frame = by_time.get(reader.log_time)
            if frame is None:
                continue
            frame.frame_id = reader.frame_id
            if load_clouds is False:
                break
            if load_clouds is True or frame.index in load_clouds:
                frame.points = points
                if "intensity" in fields:
                    frame.intensity = fields["intensity"].astype(np.float64)
    finally:
        reader.close()
    if load_clouds is False or not isinstance(load_clouds, bool):
        frame_id = next((f.frame_id for f in frames if f.frame_id), "")
        for f in frames:
            f.frame_id = f.frame_id or frame_id

    loops = []
    for number, (t, data) in enumerate(loop_msgs):
        loop = Loop(number, t, data)
        for end in ("query", "match"):
            frame = by_stamp.get(data.get(f"{end}_stamp_ns"))
            k = data.get(f"{end}_frame")
            if frame is None and isinstance(k, int):
                frame = next((f for f in frames if f.index == k), None)
            setattr(loop, end, frame)
        loops.append(loop)
    return Run(path, cloud_topic, frames, metadata, has_reference, has_optimized, loops, topics)
