"""Reading a mireg output MCAP: clouds, poses (odometry, optimised, reference), stats, loops.

Also used by tools/report.py (through tools/view.py). Only ``mcap`` and numpy are imported at
module load; the ROS 2 (``mcap_ros2``) and ROS 1 (``mcap_ros1``) decoders are imported the first
time a channel of that encoding is decoded, so a log that needs neither family's package does not
need it installed, and one that does gets a :class:`MissingDecoder` (a ``SystemExit`` with the
package to install, no traceback).
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from mcap.reader import make_reader

from .geometry import quaternion_matrix

POSE_TOPIC = "/mireg/pose"
STATS_TOPIC = "/mireg/stats"
POSE_OPTIMIZED_SUFFIX = "/pose_optimized"
LOOPS_SUFFIX = "/loops"
REFERENCE_TOPIC = "/ground_truth/pose"
POINTCLOUD2 = "sensor_msgs/msg/PointCloud2"
POINTCLOUD2_TYPES = (POINTCLOUD2, "sensor_msgs/PointCloud2")  # ROS 2, ROS 1

# sensor_msgs/PointField datatype -> numpy scalar type code
_POINTFIELD_DTYPE = {1: "i1", 2: "u1", 3: "i2", 4: "u2", 5: "i4", 6: "u4", 7: "f4", 8: "f8"}

# message encoding -> (module, pip package) of the decoder factory
_DECODERS = {
    "cdr": ("mcap_ros2.decoder", "mcap-ros2-support"),
    "ros1": ("mcap_ros1.decoder", "mcap-ros1-support"),
}


class MissingDecoder(SystemExit):
    """A channel needs a decoder package that is not installed (message, exit status 1)."""


@dataclass
class Frame:
    """One cloud of the log and what mireg wrote for it (matched by log_time)."""

    index: int  # position among the clouds of the cloud topic, 0-based (= stats "frame")
    log_time: int  # ns
    frame_id: str = ""
    stamp_ns: int | None = None  # the cloud's header stamp (from its /mireg/pose or stats)
    points: np.ndarray | None = None  # float64 N×3 in the sensor frame (finite points only)
    intensity: np.ndarray | None = None  # float64 N, if the cloud has an "intensity" field
    estimate: np.ndarray | None = None  # 4×4 world_from_frame from /mireg/pose (odometry)
    optimized: np.ndarray | None = None  # 4×4 world_from_frame from /mireg/pose_optimized
    reference: np.ndarray | None = None  # 4×4 from /ground_truth/pose
    stats: dict | None = None  # the /mireg/stats object

    def pose(self, which: str) -> np.ndarray | None:
        """``"optimized"`` (falling back to the odometry), ``"estimate"`` or ``"reference"``."""
        if which == "optimized":
            return self.optimized if self.optimized is not None else self.estimate
        return getattr(self, which)


@dataclass
class Loop:
    """One ``/mireg/loops`` message (a loop candidate tried), resolved to the run's frames."""

    number: int  # position among the loops messages, 0-based (``--loop N``)
    log_time: int  # ns (= the query cloud's log time)
    data: dict  # the JSON object as written
    query: Frame | None = None
    match: Frame | None = None

    @property
    def accepted(self) -> bool:
        return self.data.get("verdict") == "accepted"

    def match_from_query(self) -> np.ndarray | None:
        """4×4 p_match = T·p_query, or None when the loop's registration failed."""
        t = self.data.get("match_from_query")
        if not t:
            return None
        m = quaternion_matrix(t["rotation_xyzw"])
        m[:3, 3] = t["translation"]
        return m


@dataclass
class Run:
    """Everything read from one mireg output MCAP."""

    path: Path
    cloud_topic: str
    frames: list[Frame]
    metadata: dict = field(default_factory=dict)  # the "mireg" metadata record (config parsed)
    has_reference: bool = False
    has_optimized: bool = False
    loops: list[Loop] = field(default_factory=list)
    topics: dict = field(default_factory=dict)  # kind -> topic read ("pose", "loops", ...)

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
    m = quaternion_matrix([q.x, q.y, q.z, q.w])
    m[:3, 3] = [pose.position.x, pose.position.y, pose.position.z]
    return m


def stamp_ns(header) -> int:
    """A ROS 2 (sec/nanosec) or ROS 1 (secs/nsecs) header stamp in ns."""
    s = header.stamp
    sec = getattr(s, "sec", None)
    if sec is None:
        return int(s.secs) * 1_000_000_000 + int(s.nsecs)
    return int(sec) * 1_000_000_000 + int(s.nanosec)


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


def is_livox(schema_name: str) -> bool:
    """Whether a schema is a Livox CustomMsg (livox_ros_driver/CustomMsg,
    livox_ros_driver2/msg/CustomMsg, ...), as mireg recognises it."""
    pkg, _, name = schema_name.replace("/msg/", "/").partition("/")
    return name == "CustomMsg" and pkg.startswith("livox")


def decode_livox(msg) -> tuple[np.ndarray, np.ndarray]:
    """Points (float64 N×3) and reflectivity of a decoded Livox CustomMsg, every tag kept (the
    viewer shows what the sensor sent), the (0, 0, 0) "no return" and non-finite points dropped
    as mireg drops them."""
    pts = msg.points
    xyz = np.array([(p.x, p.y, p.z) for p in pts], dtype=np.float64).reshape(-1, 3)
    refl = np.array([p.reflectivity for p in pts], dtype=np.float64)
    keep = np.isfinite(xyz).all(axis=1) & (xyz != 0).any(axis=1)
    return xyz[keep], refl[keep]


def decode_cloud(schema, msg) -> tuple[np.ndarray, np.ndarray | None]:
    """Points and intensity of a decoded PointCloud2 or Livox CustomMsg."""
    if schema is not None and is_livox(schema.name):
        return decode_livox(msg)
    return decode_pointcloud2(msg)


def run_topics(metadata: dict, reference_topic: str = REFERENCE_TOPIC) -> dict:
    """kind -> topic of one run. A log registered more than once has its runs' topics in
    namespaces (/mireg_2/...); the run's metadata names its own, and topics that older metadata
    does not name (pose_optimized, loops) are taken from the pose topic's namespace."""
    pose = metadata.get("pose_topic", POSE_TOPIC)
    ns = pose[: -len("/pose")] if pose.endswith("/pose") else "/mireg"
    return {
        "pose": pose,
        "stats": metadata.get("stats_topic", ns + "/stats"),
        "optimized": metadata.get("pose_optimized_topic", ns + POSE_OPTIMIZED_SUFFIX),
        "loops": metadata.get("loops_topic", ns + LOOPS_SUFFIX),
        "reference": reference_topic,
    }


def read_run(path: str | Path, cloud_topic: str | None = None, load_clouds=True,
             reference_topic: str = REFERENCE_TOPIC) -> Run:
    """Read a mireg output MCAP (of a ROS 2 or ROS 1 input: ROS messages in ``cdr`` or ``ros1``).

    ``load_clouds``: True (decode every cloud), False (none; only poses, stats and loops), or a
    set of cloud indices to decode (the others keep ``points = None``). ``reference_topic``: the
    PoseStamped topic drawn as the reference trajectory, when the log has it.

    Odometry poses, stats and reference poses are matched to clouds by log_time (mireg writes them
    at the cloud's log_time). Optimised poses are matched by header stamp to the odometry pose of
    the same stamp (their log time is not specified), falling back to log_time; loops by
    ``query_stamp_ns`` / ``match_stamp_ns``, falling back to ``query_frame`` / ``match_frame``.
    """
    path = Path(path)
    decoders = {}  # channel id -> callable(bytes) -> message
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
                if schema is not None and (schema.name in POINTCLOUD2_TYPES
                                           or is_livox(schema.name)):
                    cloud_topic = ch.topic
                    break
        if cloud_topic is None:
            raise SystemExit(f"{path}: no {POINTCLOUD2} channel found (pass --cloud-topic)")
        topics = run_topics(metadata, reference_topic)
        topics["cloud"] = cloud_topic
        present = {ch.topic for ch in channels}
        has_reference = reference_topic in present
        has_optimized = topics["optimized"] in present

        frames: list[Frame] = []
        by_time: dict[int, Frame] = {}
        pending = {}  # log_time -> [(kind, value)] for outputs seen before their cloud
        optimized = []  # (stamp_ns, log_time, 4×4), resolved once every frame's stamp is known
        loop_msgs = []  # (log_time, dict)

        def attach(frame: Frame, kind: str, value):
            if kind == "stamp":
                frame.stamp_ns = frame.stamp_ns if frame.stamp_ns is not None else value
            else:
                setattr(frame, kind, value)

        wanted_topics = [cloud_topic, topics["pose"], topics["stats"], reference_topic,
                         topics["optimized"], topics["loops"]]
        # log_time_order=True: messages come sorted by log_time, cloud before its outputs is not
        # guaranteed for equal times, hence `pending`.
        for schema, channel, message in reader.iter_messages(
            topics=list(dict.fromkeys(wanted_topics)), log_time_order=True
        ):
            t = message.log_time
            topic = channel.topic
            if topic == cloud_topic:
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
                msg = _decode(decoders, schema, channel, message)
                frame.frame_id = msg.header.frame_id
                frame.points, frame.intensity = decode_cloud(schema, msg)
                continue
            if topic == topics["loops"]:
                loop_msgs.append((t, json.loads(message.data)))
                continue
            if topic == topics["stats"]:
                s = json.loads(message.data)
                values = [("stats", s)]
                if isinstance(s.get("stamp_ns"), int):
                    values.append(("stamp", s["stamp_ns"]))
            else:
                msg = _decode(decoders, schema, channel, message)
                pose = pose_to_matrix(msg.pose)
                values = []  # one topic may be two kinds (--reference-topic /mireg/pose)
                if topic == topics["optimized"]:
                    optimized.append((stamp_ns(msg.header), t, pose))
                if topic == topics["pose"]:
                    values += [("estimate", pose), ("stamp", stamp_ns(msg.header))]
                if topic == reference_topic:
                    values.append(("reference", pose))
            for kind, value in values:
                if t in by_time:
                    attach(by_time[t], kind, value)
                else:
                    pending.setdefault(t, []).append((kind, value))

    by_stamp = {f.stamp_ns: f for f in frames if f.stamp_ns is not None}
    for stamp, t, pose in optimized:
        frame = by_stamp.get(stamp) or by_time.get(t)
        if frame is not None:
            frame.optimized = pose
    loops = []
    for number, (t, data) in enumerate(loop_msgs):
        loop = Loop(number, t, data)
        for end in ("query", "match"):
            frame = by_stamp.get(data.get(f"{end}_stamp_ns"))
            k = data.get(f"{end}_frame")
            if frame is None and isinstance(k, int) and 0 <= k < len(frames):
                frame = frames[k]
            setattr(loop, end, frame)
        loops.append(loop)
    return Run(path, cloud_topic, frames, metadata, has_reference, has_optimized, loops, topics)


def _decoder_factory(encoding: str, topic: str):
    module, package = _DECODERS.get(encoding, (None, None))
    if module is None:
        raise SystemExit(f"cannot decode {topic}: message encoding {encoding!r} is not supported "
                         "(ROS 2 'cdr' and ROS 1 'ros1' are)")
    import importlib

    try:
        return importlib.import_module(module).DecoderFactory()
    except ImportError as e:
        raise MissingDecoder(
            f"{topic} is {encoding!r}-encoded and decoding it needs the Python package {package} "
            f"({e}); install it: pip install -r tools/requirements-viewer.txt "
            "(or bash tools/setup_viewer_venv.sh)"
        ) from None


def _decode(decoders, schema, channel, message):
    dec = decoders.get(channel.id)
    if dec is None:
        factory = _decoder_factory(channel.message_encoding, channel.topic)
        dec = factory.decoder_for(channel.message_encoding, schema)
        if dec is None:
            raise SystemExit(f"cannot decode {channel.topic} ({channel.message_encoding}, "
                             f"schema {schema.name if schema else None})")
        decoders[channel.id] = dec
    return dec(message.data)
