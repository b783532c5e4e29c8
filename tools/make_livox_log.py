#!/usr/bin/env python3
"""Simulate Livox LiDAR logs (``livox_ros_driver`` CustomMsg, not PointCloud2) by ray casting a
real world map along a smooth, time-parametrised trajectory, with per-point times, motion
distortion, range noise and tagged noise points; for testing and benchmarking mireg's Livox input,
tag filtering and deskewing.

Usage (from the repository root; the pinned packages come from `bash tools/setup_venv.sh rosbags`):

  python3 tools/toolbox.py make-livox-log --out-dir /tmp/livox
      Avia, KAIST03 world, 80 frames, skewed: /tmp/livox/livox_avia_kaist03/ (rosbag2 dir, one
      zstd MCAP), /tmp/livox/livox_avia_kaist03.bag (ROS 1, lz4) and .../livox_avia_kaist03_poses.tum
  python3 tools/toolbox.py make-livox-log --out-dir /tmp/livox --no-skew
      the same rays and noise, every point measured from the pose at the frame stamp (_noskew)
  python3 tools/toolbox.py make-livox-log --out-dir /tmp/livox --model mid360
  python3 tools/toolbox.py make-livox-log --fixture --out-dir /tmp/livox/fixture
      small committable log from the ICL-NUIM fixture (world icl, avia, 10 frames, 2500 rays):
      icl_livox.bag (ROS 1, bz2), icl_livox_ros2/ (rosbag2 dir, one MCAP, zstd level 19),
      icl_livox_poses.tum and icl_livox_expected.bin (see write_expected)

Conventions: 10 Hz frames; a frame's points have strictly increasing offset_time [ns] from 0 to
< 100 ms; header.stamp = timebase = the first point's capture time (start of the sweep, Livox
convention); each point is expressed in the sensor frame at its own capture time
timebase + offset_time (that motion distortion is what a deskewer must undo; --no-skew expresses
every point in the sensor frame at the stamp instead). The poses (TUM file and the
/ground_truth/pose topic, same stamps) are world_from_sensor at each frame's header stamp,
re-expressed so the first frame is the identity. tag: bits 0-1 spatial noise (0 normal,
1 high-, 2 moderate-, 3 low-confidence noise; injected noise points get 1), bits 2-3 intensity
noise (always 0 here), bits 4-5 return number (1; returns nearer than 1.5 m get 0).
"""

from __future__ import annotations

import argparse
import functools
import hashlib
import math
import shutil
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

if sys.version_info >= (3, 14):  # the zstd module rosbags' MCAP storage uses
    from compression import zstd
else:
    from backports import zstd
from mcap.reader import make_reader
from rosbags.highlevel import AnyReader
from rosbags.rosbag1 import Reader as Reader1
from rosbags.rosbag1 import Writer as Writer1
from rosbags.rosbag2 import StoragePlugin
from rosbags.rosbag2 import Writer as Writer2
from rosbags.rosbag2.enums import CompressionFormat, CompressionMode
from rosbags.typesys import Stores, get_types_from_msg, get_typestore
from rosbags.typesys.store import Typestore

from livox_scene import (
    POSE_TOPIC,
    Trajectory,
    World,
    icl_trajectory,
    kaist_trajectory,
    load_icl,
    load_kaist03,
    mat_to_quat,
    quat_to_mat,
    rotation_angle_deg,
)

TOOLS_DIR = Path(__file__).resolve().parent
REPO_ROOT = TOOLS_DIR.parent
DEFAULT_KAIST = REPO_ROOT.parent / "shared" / "data" / "mulran_kaist03_keyframes"
DEFAULT_ICL = REPO_ROOT / "fixtures" / "icl_livingroom1.mcap"

# The official livox_ros_driver (ROS 1) / livox_ros_driver2 message definitions: identical but for
# the header's type spelling (ROS 1 `Header`, ROS 2 `std_msgs/Header`). The writers store rosbags'
# normalised text with the dependencies appended (`MSG: std_msgs/Header`, `MSG: pkg/CustomPoint`),
# not these comments. ROS 1 md5sum of CustomMsg: LIVOX_ROS1_MD5 (same for livox_ros_driver2).
CUSTOM_MSG_ROS2 = """\
# Livox publish pointcloud msg format.

std_msgs/Header header    # ROS standard message header
uint64 timebase           # The time of first point
uint32 point_num          # Total number of pointclouds
uint8  lidar_id           # Lidar device id number
uint8[3]  rsvd            # Reserved use
CustomPoint[] points      # Pointcloud data
"""
CUSTOM_MSG_ROS1 = CUSTOM_MSG_ROS2.replace("std_msgs/Header header   ", "Header header            ")
LIVOX_ROS1_MD5 = "e4d6829bdfe657cb6c21a746c86b21a6"
CUSTOM_POINT = """\
# Livox costom pointcloud format.

uint32 offset_time      # offset time relative to the base time
float32 x               # X axis, unit:m
float32 y               # Y axis, unit:m
float32 z               # Z axis, unit:m
uint8 reflectivity      # reflectivity, 0~255
uint8 tag               # livox tag
uint8 line              # laser number in lidar
"""
ROS1_PKG = "livox_ros_driver"
ROS2_PKG = "livox_ros_driver2"
LIDAR_TOPIC = "/livox/lidar"
POSE_TYPE = "geometry_msgs/msg/PoseStamped"
LIDAR_FRAME = "livox_frame"  # livox_ros_driver's default frame_id
WORLD_FRAME = "world"

FRAME_NS = 100_000_000  # 10 Hz frames
TAG_NOISE_HIGH = 0x01  # bits 0-1 = 01: spatial-position noise, high confidence
TAG_RETURN_1 = 0x10  # bits 4-5 = 01: return 1 (first object return)
RETURN0_RANGE = 1.5  # [m] closer returns merge into return 0 (tag bits 4-5 = 00)
NOISE_RANGE = (0.5, 5.0)  # [m] injected dust/rain noise points
GRAZING_COS = 0.087  # rays within 5 deg of a surface's plane use the sphere through the point
PLANE_TOL = 0.25  # [m] a ray's hit may lie this far (+ PLANE_TOL_REL * range) from the point
PLANE_TOL_REL = 0.02
KEY_BITS = 22  # z-buffer key = range_mm << KEY_BITS | point index
KEY_EMPTY = np.iinfo(np.int64).max
LEVELS = 6  # z-buffer pyramid: fine bin, 2x, 4x, ... 32x
BASE_BIN_DEG = 0.4  # pyramid levels up to this bin size are always usable
ZSTD_DEFAULT_LEVEL = 3  # zstd's (and so rosbags') default
EXPECTED_MAGIC = b"LIVOXEXP1\n"
EXPECTED_POINT = np.dtype([("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("offset_time", "<u4"),
                           ("reflectivity", "u1"), ("tag", "u1"), ("line", "u1"), ("pad", "u1")])


@dataclass(frozen=True)
class Model:
    """A Livox sensor: field of view, scan pattern and range specs."""
    name: str
    lines: int
    points: int  # rays per 100 ms frame
    min_range: float  # [m]
    max_range: float  # [m]
    sigma: float  # [m] 1-sigma range noise
    az_range: tuple[float, float]  # z-buffer grid [deg], with margin for in-frame rotation
    el_range: tuple[float, float]
    fine_bin: float  # [deg]


AVIA = Model("avia", 6, 24_000, 1.0, 190.0, 0.02, (-41.6, 41.6), (-44.8, 44.8), 0.1)
MID360 = Model("mid360", 4, 20_000, 0.1, 70.0, 0.02, (-180.0, 181.6), (-12.0, 58.4), 0.1)
MODELS = {m.name: m for m in (AVIA, MID360)}

# Avia rosette: two counter-rotating prisms; the beam direction is the mean of two unit phasors
# turning at F1 and -F2. Each pass through the centre is one petal stroke: F1 + F2 strokes per
# second per laser; the strokes' orientation turns at (F1 - F2) / 2 rev/s. Incommensurate, so the
# pattern never repeats and consecutive frames sample different directions.
AVIA_HALF_FOV = (35.2, 38.6)  # [deg] horizontal, vertical half angles (70.4 x 77.2)
AVIA_F1 = 505.1857  # [Hz]
AVIA_F2 = 494.8143
# Mid-360: the head spins at MID_F_AZ; each laser's elevation sweeps -7..+52 deg as a triangle
# wave at MID_F_EL; the 4 lasers are 90 deg apart in azimuth and a quarter period apart in
# elevation.
MID_EL = (-7.0, 52.0)
MID_F_AZ = 10.0371  # [rev/s]
MID_F_EL = 423.7  # [Hz]

# ---------------------------------------------------------------------------------------------
# scan patterns

def pattern(model: Model, t: np.ndarray, k: np.ndarray) -> np.ndarray:
    """Unit beam directions (n, 3), sensor frame, of ray `k` fired at time `t` [s since start]."""
    line = k % model.lines
    if model.name == "avia":
        a, b = 2 * math.pi * AVIA_F1 * t, 2 * math.pi * AVIA_F2 * t
        u = (np.cos(a) + np.cos(b)) / 2
        v = (np.sin(a) - np.sin(b)) / 2
        rot = 2 * math.pi * line / model.lines  # lasers: the rosette turned by 60 deg each
        u, v = u * np.cos(rot) - v * np.sin(rot), u * np.sin(rot) + v * np.cos(rot)
        az, el = np.radians(u * AVIA_HALF_FOV[0]), np.radians(v * AVIA_HALF_FOV[1])
    else:
        az = 2 * math.pi * (MID_F_AZ * t + line / model.lines)
        phase = (MID_F_EL * t + line / model.lines) % 1.0
        tri = 1 - 2 * np.abs(2 * phase - 1)  # -1..1
        el = np.radians(MID_EL[0] + (tri + 1) / 2 * (MID_EL[1] - MID_EL[0]))
        az = (az + math.pi) % (2 * math.pi) - math.pi
    return np.stack([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)], -1)


# ---------------------------------------------------------------------------------------------
# ray casting

def zbuffer_pyramid(model: Model, local: np.ndarray, rng_: np.ndarray) -> list[np.ndarray]:
    """Nearest point per angular bin (key = range_mm << KEY_BITS | index), fine bin and each
    coarser level (2x per level)."""
    az = np.degrees(np.arctan2(local[:, 1], local[:, 0]))
    el = np.degrees(np.arcsin(np.clip(local[:, 2] / rng_, -1, 1)))
    w = round((model.az_range[1] - model.az_range[0]) / model.fine_bin)
    h = round((model.el_range[1] - model.el_range[0]) / model.fine_bin)
    ia = np.floor((az - model.az_range[0]) / model.fine_bin).astype(np.int64)
    ie = np.floor((el - model.el_range[0]) / model.fine_bin).astype(np.int64)
    ok = (ia >= 0) & (ia < w) & (ie >= 0) & (ie < h)
    key = (np.round(rng_ * 1000).astype(np.int64) << KEY_BITS) | np.arange(len(rng_))
    buf = np.full(h * w, KEY_EMPTY, np.int64)
    np.minimum.at(buf, ie[ok] * w + ia[ok], key[ok])
    levels = [buf.reshape(h, w)]
    for _ in range(LEVELS - 1):
        b = levels[-1]
        levels.append(b.reshape(b.shape[0] // 2, 2, b.shape[1] // 2, 2).min(axis=(1, 3)))
    return levels


def cast(model: Model, world: World, rot: np.ndarray, origin: np.ndarray,
         rays: np.ndarray) -> np.ndarray:
    """World point index hit by each ray (rays: unit directions in the sensor frame at
    (rot, origin)), -1 for no return. The map is a set of points, so a ray takes the nearest
    point in its angular bin; where the fine bin is empty (the map is sparse) a coarser bin is
    used, but only up to the point's own footprint (atan(spacing / range)) beyond BASE_BIN_DEG,
    and a coarser, nearer surface occludes a farther point seen through a gap."""
    d = world.xyz - origin
    r2 = np.einsum("ij,ij->i", d, d)
    sel = np.flatnonzero((r2 >= model.min_range**2) & (r2 <= model.max_range**2))
    local = d[sel] @ rot
    levels = zbuffer_pyramid(model, local, np.sqrt(r2[sel]))
    az = np.degrees(np.arctan2(rays[:, 1], rays[:, 0]))
    el = np.degrees(np.arcsin(np.clip(rays[:, 2], -1, 1)))
    ia = np.floor((az - model.az_range[0]) / model.fine_bin).astype(np.int64)
    ie = np.floor((el - model.el_range[0]) / model.fine_bin).astype(np.int64)
    h, w = levels[0].shape
    inside = (ia >= 0) & (ia < w) & (ie >= 0) & (ie < h)
    ia, ie = np.clip(ia, 0, w - 1), np.clip(ie, 0, h - 1)
    keys = np.stack([lv[ie >> k, ia >> k] for k, lv in enumerate(levels)], -1)
    empty = keys == KEY_EMPTY
    depth = np.where(empty, np.inf, (keys >> KEY_BITS) / 1000.0)
    bins = model.fine_bin * 2.0 ** np.arange(LEVELS)
    with np.errstate(divide="ignore"):
        footprint = np.degrees(np.arctan(world.spacing / depth))
    usable = ~empty & (bins <= np.maximum(BASE_BIN_DEG, footprint))
    occluder = np.where(usable, depth, np.inf).min(axis=1)
    near = depth <= (occluder + 0.15 + 0.03 * occluder)[:, None]
    level = np.argmax(near, axis=1)
    hit = inside & np.isfinite(occluder)
    key = np.where(hit, keys[np.arange(len(rays)), level], 0)
    return np.where(hit, sel[key & ((1 << KEY_BITS) - 1)], -1)


# ---------------------------------------------------------------------------------------------
# frames

POINT_DTYPE = np.dtype([("offset_time", "<u4"), ("x", "<f4"), ("y", "<f4"), ("z", "<f4"),
                        ("reflectivity", "u1"), ("tag", "u1"), ("line", "u1")])


@dataclass
class Frame:
    stamp_ns: int  # header stamp = timebase [ns]
    points: np.ndarray  # POINT_DTYPE
    noise: int  # injected noise points
    rays: int


def simulate_frame(model: Model, world: World, traj: Trajectory, f: int, n: int, seed: int,
                   noise_fraction: float, skew: bool, start_ns: int) -> Frame:
    k = np.arange(n)
    off = (k * FRAME_NS) // n  # ns since the frame's nominal start
    t0 = f * FRAME_NS
    t = (t0 + off) / 1e9
    dirs = pattern(model, t, k)
    rot, pos = traj.at(t)
    rot_mid, pos_mid = traj.at(np.array([(t0 + FRAME_NS // 2) / 1e9]))
    # each ray leaves the sensor at its own time: its direction seen from the mid-frame pose
    rays_mid = np.einsum("ji,njk,nk->ni", rot_mid[0], rot, dirs)
    widx = cast(model, world, rot_mid[0], pos_mid[0], rays_mid)

    rng = np.random.default_rng([seed, f])
    gauss = rng.standard_normal(n)
    is_noise = rng.random(n) < noise_fraction
    noise_range = rng.uniform(*NOISE_RANGE, n)
    noise_refl = rng.integers(0, 8, n)

    # the ray from the sensor at its own time meets the selected point's tangent plane (or, off
    # planar surfaces, the sphere through it); too far from that point -> no return
    hit = widx >= 0
    p_sel = world.xyz[np.where(hit, widx, 0)]
    nrm = world.normal[np.where(hit, widx, 0)]
    dir_w = np.einsum("nij,nj->ni", rot, dirs)
    rel = p_sel - pos
    sphere = np.linalg.norm(rel, axis=1)
    denom = np.einsum("ni,ni->n", dir_w, nrm)
    flat = world.flat[np.where(hit, widx, 0)] & (np.abs(denom) > GRAZING_COS)
    with np.errstate(divide="ignore", invalid="ignore"):
        plane = np.einsum("ni,ni->n", rel, nrm) / denom
    lam = np.where(flat, plane, sphere)
    q = pos + lam[:, None] * dir_w  # the ray's hit point, world frame
    hit &= (lam >= model.min_range) & (lam <= model.max_range) & \
        (np.linalg.norm(q - p_sel, axis=1) <= PLANE_TOL + PLANE_TOL_REL * sphere)
    is_noise &= hit  # dust/rain in front of the surface replaces its return
    keep = hit
    hit = keep & ~is_noise
    k0 = int(np.argmax(keep))
    timebase = t0 + int(off[k0])

    if skew:  # measured from the sensor pose at the point's own time: exactly along the ray
        meas = lam[:, None] * dirs
    else:  # every point measured from the pose at the frame's stamp
        r1, p1 = traj.at(np.array([timebase / 1e9]))
        meas = (q - p1[0]) @ r1[0]
    meas = np.where(hit[:, None], meas, 0.0)
    rng_ = np.linalg.norm(meas, axis=1)
    meas *= (1 + model.sigma * gauss / np.maximum(rng_, 1e-6))[:, None]
    meas = np.where(is_noise[:, None], dirs * noise_range[:, None], meas)
    meas = np.round(meas * 1000) / 1000  # Livox reports Cartesian coordinates in mm

    rng_out = np.linalg.norm(meas, axis=1)
    tag = np.where(rng_out < RETURN0_RANGE, 0, TAG_RETURN_1) | np.where(is_noise, TAG_NOISE_HIGH, 0)
    refl = np.where(is_noise, noise_refl, world.refl[np.where(hit, widx, 0)])

    pts = np.zeros(int(keep.sum()), POINT_DTYPE)
    pts["offset_time"] = off[keep] - off[k0]
    pts["x"], pts["y"], pts["z"] = meas[keep].T.astype(np.float32)
    pts["reflectivity"] = refl[keep]
    pts["tag"] = tag[keep]
    pts["line"] = (k % model.lines)[keep]
    return Frame(start_ns + timebase, pts, int((is_noise & keep).sum()), n)


# ---------------------------------------------------------------------------------------------
# messages and bags

def typestores() -> tuple[Typestore, Typestore]:
    ts1 = get_typestore(Stores.ROS1_NOETIC)
    ts2 = get_typestore(Stores.ROS2_JAZZY)
    for ts, pkg, text in ((ts1, ROS1_PKG, CUSTOM_MSG_ROS1), (ts2, ROS2_PKG, CUSTOM_MSG_ROS2)):
        types = {}
        types.update(get_types_from_msg(CUSTOM_POINT, f"{pkg}/msg/CustomPoint"))
        types.update(get_types_from_msg(text, f"{pkg}/msg/CustomMsg"))
        ts.register(types)
    return ts1, ts2


def header(ts: Typestore, ros1: bool, seq: int, stamp_ns: int, frame_id: str):
    T = ts.types
    stamp = T["builtin_interfaces/msg/Time"](sec=stamp_ns // 10**9, nanosec=stamp_ns % 10**9)
    if ros1:
        return T["std_msgs/msg/Header"](seq=seq, stamp=stamp, frame_id=frame_id)
    return T["std_msgs/msg/Header"](stamp=stamp, frame_id=frame_id)


def lidar_msg(ts: Typestore, ros1: bool, seq: int, frame: Frame):
    pkg = ROS1_PKG if ros1 else ROS2_PKG
    point = ts.types[f"{pkg}/msg/CustomPoint"]
    p = frame.points
    cols = [p[c].tolist() for c in POINT_DTYPE.names]
    points = [point(offset_time=o, x=x, y=y, z=z, reflectivity=r, tag=g, line=ln)
              for o, x, y, z, r, g, ln in zip(*cols)]
    return ts.types[f"{pkg}/msg/CustomMsg"](
        header=header(ts, ros1, seq, frame.stamp_ns, LIDAR_FRAME), timebase=frame.stamp_ns,
        point_num=len(points), lidar_id=0, rsvd=np.zeros(3, np.uint8), points=points)


def pose_msg(ts: Typestore, ros1: bool, seq: int, stamp_ns: int, pose: np.ndarray):
    T = ts.types
    q = mat_to_quat(pose[:3, :3])
    return T[POSE_TYPE](
        header=header(ts, ros1, seq, stamp_ns, WORLD_FRAME),
        pose=T["geometry_msgs/msg/Pose"](
            position=T["geometry_msgs/msg/Point"](x=float(pose[0, 3]), y=float(pose[1, 3]),
                                                  z=float(pose[2, 3])),
            orientation=T["geometry_msgs/msg/Quaternion"](x=float(q[0]), y=float(q[1]),
                                                          z=float(q[2]), w=float(q[3]))))


def remove(path: Path) -> None:
    if path.is_dir():
        shutil.rmtree(path)
    elif path.exists():
        path.unlink()


def write_ros2(path: Path, ts: Typestore, frames: list[Frame], poses: list[np.ndarray],
               zstd_level: int) -> None:
    """rosbag2 directory `path` with one MCAP file (`path.name`.mcap, zstd chunks, schemas with
    the full ros2msg dependency text) and metadata.yaml."""
    remove(path)
    writer = Writer2(path, version=9, storage_plugin=StoragePlugin.MCAP)
    writer.set_compression(CompressionMode.STORAGE, CompressionFormat.ZSTD)
    with writer:
        if zstd_level != ZSTD_DEFAULT_LEVEL:
            # rosbags' MCAP storage compresses each chunk with zstd.compress at its default level
            # 3 and has no option for it (rosbags is pinned; checked against 0.11.9)
            storage = writer.storage
            if getattr(storage, "compressor", None) is None:
                sys.exit("--zstd-level: this rosbags version has no MCAP compressor to adjust")
            storage.compressor = functools.partial(zstd.compress, level=zstd_level)
        lidar = writer.add_connection(LIDAR_TOPIC, f"{ROS2_PKG}/msg/CustomMsg", typestore=ts)
        pose = writer.add_connection(POSE_TOPIC, POSE_TYPE, typestore=ts)
        for i, (fr, T) in enumerate(zip(frames, poses)):
            writer.write(lidar, fr.stamp_ns, ts.serialize_cdr(lidar_msg(ts, False, i, fr),
                                                               lidar.msgtype))
            writer.write(pose, fr.stamp_ns, ts.serialize_cdr(pose_msg(ts, False, i, fr.stamp_ns, T),
                                                              POSE_TYPE))


def write_ros1(path: Path, ts: Typestore, frames: list[Frame], poses: list[np.ndarray],
               compression: str) -> None:
    """ROS 1 bag v2.0; connection headers carry rosbags' message_definition (dependencies
    appended) and md5sum."""
    remove(path)
    writer = Writer1(path)
    if compression != "none":
        writer.set_compression(Writer1.CompressionFormat[compression.upper()])
    with writer:
        lidar = writer.add_connection(LIDAR_TOPIC, f"{ROS1_PKG}/msg/CustomMsg", typestore=ts)
        pose = writer.add_connection(POSE_TOPIC, POSE_TYPE, typestore=ts)
        for i, (fr, T) in enumerate(zip(frames, poses)):
            writer.write(lidar, fr.stamp_ns, ts.serialize_ros1(lidar_msg(ts, True, i, fr),
                                                                lidar.msgtype))
            writer.write(pose, fr.stamp_ns,
                         ts.serialize_ros1(pose_msg(ts, True, i, fr.stamp_ns, T), POSE_TYPE))


def write_tum(path: Path, frames: list[Frame], poses: list[np.ndarray]) -> None:
    lines = []
    for fr, T in zip(frames, poses):
        q = mat_to_quat(T[:3, :3])
        lines.append(f"{fr.stamp_ns // 10**9}.{fr.stamp_ns % 10**9:09d} "
                     + " ".join(f"{v:.9f}" for v in (*T[:3, 3], *q)))
    path.write_text("\n".join(lines) + "\n")


# ---------------------------------------------------------------------------------------------
# checks

def fail(msg: str) -> None:
    sys.exit(f"check failed: {msg}")


def read_back(path: Path, ts: Typestore, frames: list[Frame],
              poses: list[np.ndarray]) -> list[np.ndarray]:
    """Decode a written bag with AnyReader and check it against the frames; returns the decoded
    point arrays."""
    got: dict[str, list] = {LIDAR_TOPIC: [], POSE_TOPIC: []}
    with AnyReader([path], default_typestore=ts) as reader:
        counts = {c.topic: c.msgcount for c in reader.connections}
        for conn, t, raw in reader.messages():
            got[conn.topic].append((t, reader.deserialize(raw, conn.msgtype)))
    if counts != {LIDAR_TOPIC: len(frames), POSE_TOPIC: len(frames)}:
        fail(f"{path}: topic counts {counts}")
    arrays = []
    for (t, m), (tp, pm), fr, T in zip(got[LIDAR_TOPIC], got[POSE_TOPIC], frames, poses):
        stamp = m.header.stamp.sec * 10**9 + m.header.stamp.nanosec
        pstamp = pm.header.stamp.sec * 10**9 + pm.header.stamp.nanosec
        if not (t == tp == stamp == pstamp == m.timebase == fr.stamp_ns):
            fail(f"{path}: stamps differ at {fr.stamp_ns}")
        if m.point_num != len(m.points) or m.point_num != len(fr.points):
            fail(f"{path}@{t}: point_num {m.point_num}, {len(m.points)} points")
        arr = np.array([(p.offset_time, p.x, p.y, p.z, p.reflectivity, p.tag, p.line)
                        for p in m.points], POINT_DTYPE)
        if len(arr) == 0:
            fail(f"{path}@{t}: empty frame")
        if arr["offset_time"].min() != 0 or arr["offset_time"].max() > FRAME_NS \
                or np.any(np.diff(arr["offset_time"].astype(np.int64)) < 0):
            fail(f"{path}@{t}: offset_time not monotonic within [0, 100 ms] from 0")
        if arr.tobytes() != fr.points.tobytes():
            fail(f"{path}@{t}: decoded points differ from the simulated ones")
        p, q = pm.pose.position, pm.pose.orientation
        if np.abs(np.array([p.x, p.y, p.z]) - T[:3, 3]).max() > 1e-9 or \
                np.abs(quat_to_mat(np.array([q.x, q.y, q.z, q.w])) - T[:3, :3]).max() > 1e-9:
            fail(f"{path}@{t}: pose differs")
        arrays.append(arr)
    return arrays


def check_mcap(path: Path, frames: int) -> None:
    """The official mcap reader sees the same message counts in the rosbag2 storage file."""
    counts: dict[str, int] = {}
    for f in sorted(path.glob("*.mcap")):
        with open(f, "rb") as fh:
            for _s, channel, _m in make_reader(fh).iter_messages():
                counts[channel.topic] = counts.get(channel.topic, 0) + 1
    if counts != {LIDAR_TOPIC: frames, POSE_TOPIC: frames}:
        fail(f"{path}: mcap reader counts {counts}")


def check_definitions(ros1: Path | None, ros2: Path | None) -> None:
    """The ROS 1 connection carries the official md5sum and a message_definition with the
    std_msgs/Header and CustomPoint texts appended; the MCAP schema is ros2msg with the
    std_msgs/Header, builtin_interfaces/Time and CustomPoint texts appended."""
    sep = "=" * 80 + "\n"
    if ros1 is not None:
        with Reader1(ros1) as reader:
            conn = next(c for c in reader.connections if c.topic == LIDAR_TOPIC)
        text = conn.msgdef.data
        if conn.digest != LIVOX_ROS1_MD5 or conn.msgtype != f"{ROS1_PKG}/msg/CustomMsg" or any(
                f"{sep}MSG: {t}\n" not in text
                for t in ("std_msgs/Header", f"{ROS1_PKG}/CustomPoint")):
            fail(f"{ros1}: lidar connection {conn.msgtype} md5 {conn.digest}, definition:\n{text}")
    if ros2 is not None:
        for f in sorted(ros2.glob("*.mcap")):
            with open(f, "rb") as fh:
                summary = make_reader(fh).get_summary()
            schema = next(x for x in summary.schemas.values()
                          if x.name == f"{ROS2_PKG}/msg/CustomMsg")
            text = schema.data.decode()
            if schema.encoding != "ros2msg" or any(
                    f"{sep}MSG: {t}\n" not in text for t in (
                        "std_msgs/Header", "builtin_interfaces/Time", f"{ROS2_PKG}/CustomPoint")):
                fail(f"{f}: schema {schema.encoding}:\n{text}")


def decode_ros1_lidar(path: Path) -> list[tuple[int, int, np.ndarray]]:
    """(header stamp ns, timebase, points as EXPECTED_POINT) of each lidar message in a ROS 1 bag,
    decoded by rosbags with a typestore built only from the bag's own message_definition (not the
    simulator's types or arrays)."""
    out = []
    with Reader1(path) as reader:
        conns = [c for c in reader.connections if c.topic == LIDAR_TOPIC]
        ts = get_typestore(Stores.EMPTY)
        for c in conns:
            ts.register(get_types_from_msg(c.msgdef.data, c.msgtype))
        for conn, _t, raw in reader.messages(connections=conns):
            m = ts.deserialize_ros1(raw, conn.msgtype)
            arr = np.zeros(len(m.points), EXPECTED_POINT)
            for i, pt in enumerate(m.points):
                arr[i] = (pt.x, pt.y, pt.z, pt.offset_time, pt.reflectivity, pt.tag, pt.line, 0)
            out.append((m.header.stamp.sec * 10**9 + m.header.stamp.nanosec, int(m.timebase), arr))
    return out


EXPECTED_FRAMES = 3  # frames in the --expected file


def write_expected(path: Path, frames: list[tuple[int, int, np.ndarray]]) -> None:
    """The first EXPECTED_FRAMES frames (to keep the fixture small), little-endian: magic
    b"LIVOXEXP1\\n", u32 frame count, then per frame u64 header stamp
    [ns], u64 timebase, u32 n, then n records (f32 x, y, z, u32 offset_time, u8 reflectivity,
    u8 tag, u8 line, u8 0), 20 bytes each."""
    frames = frames[:EXPECTED_FRAMES]
    parts = [EXPECTED_MAGIC, np.uint32(len(frames)).astype("<u4").tobytes()]
    for stamp, timebase, arr in frames:
        parts.append(np.array([stamp, timebase], "<u8").tobytes())
        parts.append(np.uint32(len(arr)).astype("<u4").tobytes())
        parts.append(arr.astype(EXPECTED_POINT).tobytes())
    path.write_bytes(b"".join(parts))


def files_of(path: Path) -> list[Path]:
    return sorted(p for p in path.rglob("*") if p.is_file()) if path.is_dir() else [path]


def size_of(path: Path) -> int:
    return sum(p.stat().st_size for p in path.rglob("*") if p.is_file()) if path.is_dir() \
        else path.stat().st_size


# ---------------------------------------------------------------------------------------------

def main(argv: list[str]) -> None:
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--world", choices=("kaist03", "icl"), default="kaist03")
    ap.add_argument("--model", choices=sorted(MODELS), default="avia")
    ap.add_argument("--frames", type=int, default=80, help="10 Hz frames [%(default)s]")
    ap.add_argument("--points", type=int, default=0,
                    help="rays per frame (default: avia 24000, mid360 20000)")
    ap.add_argument("--seed", type=int, default=0, help="noise seed [%(default)s]")
    ap.add_argument("--no-skew", action="store_true",
                    help="measure every point at the frame-start pose (name gets _noskew)")
    ap.add_argument("--formats", default="ros2,ros1,tum",
                    help="comma list of ros2, ros1, tum [%(default)s]")
    ap.add_argument("--out-dir", type=Path, default=Path("/tmp"), help="[%(default)s]")
    ap.add_argument("--kaist-data", type=Path, default=DEFAULT_KAIST, help="[%(default)s]")
    ap.add_argument("--icl-mcap", type=Path, default=DEFAULT_ICL, help="[%(default)s]")
    ap.add_argument("--voxel", type=float, default=0.0,
                    help="world voxel size [m] (default: kaist03 0.1, icl 0.03)")
    ap.add_argument("--noise-fraction", type=float, default=0.015,
                    help="fraction of returns replaced by tagged noise points [%(default)s]")
    ap.add_argument("--name", default="",
                    help="output base name (default: livox_<model>_<world>[_noskew])")
    ap.add_argument("--ros1-compression", choices=("none", "lz4", "bz2"), default="lz4",
                    help="ROS 1 bag chunk compression [%(default)s]")
    ap.add_argument("--zstd-level", type=int, default=ZSTD_DEFAULT_LEVEL,
                    help="zstd level of the MCAP chunks [%(default)s]")
    ap.add_argument("--expected", action="store_true",
                    help="also write <name>_expected.bin, decoded from the ROS 1 bag")
    ap.add_argument("--fixture", action="store_true",
                    help="small committable test log: defaults become --world icl --model avia "
                         "--frames 10 --points 2500 --name icl_livox --ros1-compression bz2 "
                         "--zstd-level 19 --expected, ROS 2 dir <name>_ros2 (explicit options "
                         "still win)")
    ap.add_argument("--speed", type=float, default=3.0,
                    help="kaist03 world: mean car speed in m/s, varying by a sixth either way "
                         "[%(default)s]; at 6 m/s (MulRan's car) 80 frames overrun the 23.6 m "
                         "reference path, whose map thins out beyond its ends")
    args = ap.parse_args(argv)
    if args.fixture:
        ap.set_defaults(world="icl", model="avia", frames=10, points=2500, name="icl_livox",
                        ros1_compression="bz2", zstd_level=19, expected=True)
        args = ap.parse_args(argv)
    if args.expected and "ros1" not in args.formats.split(","):
        sys.exit("--expected decodes the ROS 1 bag: --formats must include ros1")
    formats = set(args.formats.split(","))
    if not formats or formats - {"ros2", "ros1", "tum"} or args.frames < 1:
        sys.exit("--formats takes ros2, ros1, tum; --frames must be >= 1")
    globals().update(CAR_SPEED=args.speed, CAR_SPEED_AMP=args.speed / 6.0)
    model = MODELS[args.model]
    n = args.points or model.points
    if n < model.lines:
        sys.exit(f"--points must be at least {model.lines}")

    started = time.time()
    if args.world == "kaist03":
        world = load_kaist03(args.kaist_data, args.voxel or 0.1)
        pos, quat, info = kaist_trajectory(world, args.frames * 0.1)
    else:
        world = load_icl(args.icl_mcap, args.voxel or 0.03)
        pos, quat, info = icl_trajectory(world, args.frames * 0.1)
    traj = Trajectory(pos, quat)
    frames = [simulate_frame(model, world, traj, f, n, args.seed, args.noise_fraction,
                             not args.no_skew, world.start_ns) for f in range(args.frames)]

    # ground truth: world_from_sensor at each stamp, re-expressed so the first frame is identity
    rel = np.array([(fr.stamp_ns - world.start_ns) / 1e9 for fr in frames])
    rots, trans = traj.at(rel)
    mats = np.tile(np.eye(4), (len(frames), 1, 1))
    mats[:, :3, :3], mats[:, :3, 3] = rots, trans
    first_inv = np.linalg.inv(mats[0])
    poses = [first_inv @ m for m in mats]
    r_end, p_end = traj.at(rel + 0.1)
    motion_t = np.linalg.norm(p_end - trans, axis=1)
    motion_r = rotation_angle_deg(np.einsum("nji,njk->nik", rots, r_end))

    name = args.name or f"livox_{model.name}_{world.name}" + ("_noskew" if args.no_skew else "")
    args.out_dir.mkdir(parents=True, exist_ok=True)
    ts1, ts2 = typestores()
    outputs = []
    decoded = {}
    ros1_path = ros2_path = None
    if "ros2" in formats:
        ros2_path = path = args.out_dir / (f"{name}_ros2" if args.fixture else name)
        write_ros2(path, ts2, frames, poses, args.zstd_level)
        check_mcap(path, len(frames))
        decoded["ros2"] = read_back(path, ts2, frames, poses)
        outputs.append(path)
    if "ros1" in formats:
        ros1_path = path = args.out_dir / f"{name}.bag"
        write_ros1(path, ts1, frames, poses, args.ros1_compression)
        decoded["ros1"] = read_back(path, ts1, frames, poses)
        outputs.append(path)
    if "ros1" in decoded and "ros2" in decoded and any(
            a.tobytes() != b.tobytes() for a, b in zip(decoded["ros1"], decoded["ros2"])):
        fail("ROS 1 and ROS 2 bags decode to different points")
    check_definitions(ros1_path, ros2_path)
    if args.expected:
        assert ros1_path is not None
        exp = decode_ros1_lidar(ros1_path)
        if len(exp) != len(frames) or any(
                st != fr.stamp_ns or tb != fr.stamp_ns
                or [arr[c].tobytes() for c in POINT_DTYPE.names]
                != [fr.points[c].tobytes() for c in POINT_DTYPE.names]
                for (st, tb, arr), fr in zip(exp, frames)):
            fail(f"{ros1_path}: independent decode differs from the simulated frames")
        path = args.out_dir / f"{name}_expected.bin"
        write_expected(path, exp)
        outputs.append(path)
    if "tum" in formats:
        path = args.out_dir / f"{name}_poses.tum"
        write_tum(path, frames, poses)
        outputs.append(path)

    counts = np.array([len(fr.points) for fr in frames])
    noise = sum(fr.noise for fr in frames)
    print(f"{name}: world {world.name} ({len(world.xyz)} map points, voxel {world.spacing} m), "
          f"model {model.name}, seed {args.seed}, {'no skew' if args.no_skew else 'skewed'}")
    print(f"  trajectory: {info['path']}")
    print(f"  frames {len(frames)}, rays/frame {n}, points/frame {counts.min()}..{counts.max()} "
          f"(mean {counts.mean():.0f}, {counts.mean() / n:.1%} of rays)")
    print(f"  motion per 100 ms frame: translation {motion_t.min():.3f}..{motion_t.max():.3f} m "
          f"(mean {motion_t.mean():.3f}), rotation {motion_r.min():.2f}..{motion_r.max():.2f} deg "
          f"(mean {motion_r.mean():.2f})")
    print(f"  noise points {noise} = {noise / counts.sum():.2%} of points (tag & 0x03 == 0x01)")
    for path in outputs:
        print(f"  {size_of(path):>10} bytes  {path}{'/' if path.is_dir() else ''}")
        for f in files_of(path):
            print(f"      md5 {hashlib.md5(f.read_bytes()).hexdigest()}  {f.stat().st_size:>10}  "
                  f"{f.relative_to(args.out_dir)}")
    checked = " and ".join(sorted(decoded))
    print(f"  checks passed ({checked or 'no bags'}); {time.time() - started:.1f} s")


if __name__ == "__main__":
    main(sys.argv[1:])
