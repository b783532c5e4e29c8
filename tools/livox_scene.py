"""The scenes and paths of tools/make_livox_log.py: rotations, the world (real frames merged into
one point cloud with normals and a pseudo-reflectivity) and the sensor's trajectory through it.
"""

from __future__ import annotations

import math
import sys
from dataclasses import dataclass
from decimal import Decimal
from pathlib import Path

import numpy as np
from mcap.reader import make_reader
from rosbags.typesys import Stores, get_typestore

POSE_TOPIC = "/ground_truth/pose"

PLANAR_RATIO = 0.05  # neighbourhood planar when its smallest PCA eigenvalue is < 5 % of the sum
MIN_INT = 10  # pseudo-reflectivity range of world surfaces
MAX_INT = 130
TABLE_DT = 0.001  # trajectory table step [s]

# kaist03 trajectory
CAR_SPEED = 3.0  # [m/s] mean speed (--speed): 80 frames stay on the 23.6 m reference path
CAR_SPEED_AMP = 0.5  # [m/s] speed varies 2.5..3.5 m/s (scaled with --speed)
CAR_SPEED_PERIOD = 8.0  # [s]
WEAVE_AMP = 0.8  # [m] lateral weave (lane-change style) on the reference path
WEAVE_LENGTH = 20.0  # [m]
# icl trajectory: the reference's own timing; turn around smoothly over 2 * TURN_HALF.
TURN_HALF = 0.5  # [s]


# ---------------------------------------------------------------------------------------------
# rotations (quaternions x, y, z, w)

def quat_to_mat(q: np.ndarray) -> np.ndarray:
    q = np.asarray(q, dtype=np.float64)
    x, y, z, w = np.moveaxis(q, -1, 0)
    return np.stack([
        np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)], -1),
        np.stack([2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)], -1),
        np.stack([2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)], -1),
    ], -2)


def mat_to_quat(m: np.ndarray) -> np.ndarray:
    """Quaternion (x, y, z, w), w >= 0, of rotation matrices (..., 3, 3)."""
    m = np.asarray(m, dtype=np.float64)
    t = np.trace(m, axis1=-2, axis2=-1)
    cands = np.stack([
        np.stack([m[..., 2, 1] - m[..., 1, 2], m[..., 0, 2] - m[..., 2, 0],
                  m[..., 1, 0] - m[..., 0, 1], 1 + t], -1),
        np.stack([1 + 2 * m[..., 0, 0] - t, m[..., 0, 1] + m[..., 1, 0],
                  m[..., 0, 2] + m[..., 2, 0], m[..., 2, 1] - m[..., 1, 2]], -1),
        np.stack([m[..., 0, 1] + m[..., 1, 0], 1 + 2 * m[..., 1, 1] - t,
                  m[..., 1, 2] + m[..., 2, 1], m[..., 0, 2] - m[..., 2, 0]], -1),
        np.stack([m[..., 0, 2] + m[..., 2, 0], m[..., 1, 2] + m[..., 2, 1],
                  1 + 2 * m[..., 2, 2] - t, m[..., 1, 0] - m[..., 0, 1]], -1),
    ], -2)
    diag = np.stack([t, m[..., 0, 0], m[..., 1, 1], m[..., 2, 2]], -1)
    best = np.take_along_axis(cands, np.argmax(diag, -1)[..., None, None], -2)[..., 0, :]
    q = best / np.linalg.norm(best, axis=-1, keepdims=True)
    return np.where(q[..., 3:4] < 0, -q, q)


def slerp(q0: np.ndarray, q1: np.ndarray, u: np.ndarray) -> np.ndarray:
    q0, q1 = np.asarray(q0, float), np.asarray(q1, float)
    u = np.asarray(u, float)[..., None]
    dot = np.sum(q0 * q1, -1, keepdims=True)
    q1 = np.where(dot < 0, -q1, q1)
    dot = np.abs(dot)
    theta = np.arccos(np.clip(dot, -1.0, 1.0))
    small = theta < 1e-6
    s = np.sin(np.where(small, 1.0, theta))
    a = np.where(small, 1 - u, np.sin((1 - u) * theta) / s)
    b = np.where(small, u, np.sin(u * theta) / s)
    q = a * q0 + b * q1
    return q / np.linalg.norm(q, axis=-1, keepdims=True)


def rot_z(angle: np.ndarray) -> np.ndarray:
    c, s = np.cos(angle), np.sin(angle)
    o, z = np.ones_like(c), np.zeros_like(c)
    return np.stack([np.stack([c, -s, z], -1), np.stack([s, c, z], -1),
                     np.stack([z, z, o], -1)], -2)


def rotation_angle_deg(r: np.ndarray) -> np.ndarray:
    c = (np.trace(r, axis1=-2, axis2=-1) - 1) / 2
    return np.degrees(np.arccos(np.clip(c, -1.0, 1.0)))


# ---------------------------------------------------------------------------------------------
# worlds

@dataclass
class World:
    name: str
    xyz: np.ndarray  # (n, 3) float64, world frame [m]
    refl: np.ndarray  # (n,) uint8 pseudo-reflectivity
    spacing: float  # [m] point spacing (the voxel size)
    normal: np.ndarray  # (n, 3) unit surface normal (PCA of the points within ~3 voxels)
    flat: np.ndarray  # (n,) bool: the neighbourhood is planar (normal meaningful)
    ref_pos: np.ndarray  # (k, 3) reference sensor path (keyframe positions)
    ref_rot: np.ndarray  # (k, 3, 3) reference world_from_sensor rotations
    start_ns: int  # stamp of the first frame


def voxel_downsample(xyz: np.ndarray, voxel: float) -> np.ndarray:
    """Centroid of the points in each occupied voxel, in voxel-key order (deterministic)."""
    cell = np.floor(xyz / voxel).astype(np.int64)
    cell -= cell.min(0)
    dims = cell.max(0) + 1
    key = (cell[:, 0] * dims[1] + cell[:, 1]) * dims[2] + cell[:, 2]
    uniq, inv = np.unique(key, return_inverse=True)
    count = np.bincount(inv, minlength=len(uniq)).astype(np.float64)
    out = np.empty((len(uniq), 3))
    for c in range(3):
        out[:, c] = np.bincount(inv, weights=xyz[:, c], minlength=len(uniq)) / count
    return out


def estimate_normals(xyz: np.ndarray, cell: float) -> tuple[np.ndarray, np.ndarray]:
    """Per-point surface normal and planarity: PCA of the points in the 3x3x3 block of `cell`
    cells around the point's cell (smallest-eigenvalue eigenvector; planar when that eigenvalue
    is under PLANAR_RATIO of the sum)."""
    c = np.floor(xyz / cell).astype(np.int64)
    c -= c.min(0) - 1
    dims = c.max(0) + 2
    key = (c[:, 0] * dims[1] + c[:, 1]) * dims[2] + c[:, 2]
    cells, inv = np.unique(key, return_inverse=True)
    m = len(cells)
    outer = xyz[:, :, None] * xyz[:, None, :]
    cnt = np.bincount(inv, minlength=m).astype(np.float64)
    s1 = np.stack([np.bincount(inv, xyz[:, i], m) for i in range(3)], -1)
    s2 = np.stack([np.bincount(inv, outer[:, i, j], m) for i in range(3) for j in range(3)],
                  -1).reshape(m, 3, 3)
    cc = np.stack([cells // (dims[1] * dims[2]), cells // dims[2] % dims[1], cells % dims[2]], -1)
    n_sum, s1_sum, s2_sum = np.zeros(m), np.zeros((m, 3)), np.zeros((m, 3, 3))
    for off in np.stack(np.meshgrid(*[[-1, 0, 1]] * 3, indexing="ij"), -1).reshape(-1, 3):
        nc = cc + off
        nk = (nc[:, 0] * dims[1] + nc[:, 1]) * dims[2] + nc[:, 2]
        pos = np.clip(np.searchsorted(cells, nk), 0, m - 1)
        found = cells[pos] == nk
        n_sum[found] += cnt[pos[found]]
        s1_sum[found] += s1[pos[found]]
        s2_sum[found] += s2[pos[found]]
    mean = s1_sum / n_sum[:, None]
    cov = s2_sum / n_sum[:, None, None] - mean[:, :, None] * mean[:, None, :]
    w, v = np.linalg.eigh(cov)
    flat = (w[:, 0] < PLANAR_RATIO * np.maximum(w.sum(1), 1e-12)) & (n_sum >= 5)
    return v[:, :, 0][inv], flat[inv]


def pseudo_reflectivity(xyz: np.ndarray, patch: float = 0.5) -> np.ndarray:
    """Piecewise-constant reflectivity MIN_INT..MAX_INT per `patch`-metre cell (an integer hash of
    the cell), so surfaces have stable texture; the source clouds carry no reflectance."""
    c = np.floor(xyz / patch).astype(np.int64) & 0xFFFFF
    h = (c[:, 0] * 73856093) ^ (c[:, 1] * 19349663) ^ (c[:, 2] * 83492791)
    h = (h ^ (h >> 13)) * 0x5BD1E995
    h = (h ^ (h >> 15)) & 0xFFFF
    return (MIN_INT + h * (MAX_INT - MIN_INT) // 0xFFFF).astype(np.uint8)


def read_pcd_xyzi(path: Path) -> np.ndarray:
    """(n, 4) float32 x, y, z, intensity of a binary PCD v0.7 with exactly those fields."""
    blob = path.read_bytes()
    end = blob.index(b"DATA binary\n") + len(b"DATA binary\n")
    head = dict(line.split(" ", 1) for line in blob[:end].decode("ascii").splitlines()
                if line and line[0] != "#")
    if head["FIELDS"].split() != ["x", "y", "z", "intensity"] or head["TYPE"].split() != ["F"] * 4:
        sys.exit(f"{path}: expected float32 fields x y z intensity")
    n = int(head["POINTS"])
    if len(blob) - end < 16 * n:
        sys.exit(f"{path}: truncated ({len(blob) - end} data bytes for {n} points)")
    return np.frombuffer(blob, np.float32, 4 * n, end).reshape(n, 4)


def load_kaist03(data: Path, voxel: float) -> World:
    if not data.is_dir():
        sys.exit(f"{data}: not found (the KAIST03 keyframes live in ../shared/data)")
    poses = np.loadtxt(data / "poses_kitti.txt").reshape(-1, 3, 4)
    times = (data / "times.txt").read_text().split()
    clouds = []
    for k, pose in enumerate(poses):
        pts = read_pcd_xyzi(data / "Scans" / f"{k:06d}.pcd")[:, :3].astype(np.float64)
        clouds.append(pts @ pose[:, :3].T + pose[:, 3])
    xyz = voxel_downsample(np.concatenate(clouds), voxel)
    start_ns = int(Decimal(times[0]) * 10**9)
    return World("kaist03", xyz, pseudo_reflectivity(xyz), voxel,
                 *estimate_normals(xyz, 2 * voxel), poses[:, :, 3].copy(),
                 poses[:, :, :3].copy(), start_ns)


def load_icl(path: Path, voxel: float) -> World:
    ts = get_typestore(Stores.ROS2_JAZZY)
    clouds, poses = {}, {}
    with open(path, "rb") as f:
        for schema, channel, message in make_reader(f).iter_messages(
                topics=["/camera/depth/points", POSE_TOPIC], log_time_order=True):
            msg = ts.deserialize_cdr(bytes(message.data), schema.name)
            if channel.topic == POSE_TOPIC:
                p, q = msg.pose.position, msg.pose.orientation
                poses[message.log_time] = (np.array([p.x, p.y, p.z]),
                                           quat_to_mat(np.array([q.x, q.y, q.z, q.w])))
            else:
                if [(fl.name, fl.offset, fl.datatype) for fl in msg.fields[:3]] != \
                        [("x", 0, 7), ("y", 4, 7), ("z", 8, 7)]:
                    sys.exit(f"{path}: cloud fields are not x, y, z float32 at 0, 4, 8")
                rec = np.frombuffer(msg.data.tobytes(), np.uint8).reshape(-1, msg.point_step)
                clouds[message.log_time] = rec[:, :12].copy().view(np.float32).astype(np.float64)
    stamps = sorted(set(clouds) & set(poses))
    if len(stamps) < 4:
        sys.exit(f"{path}: only {len(stamps)} clouds with poses")
    merged = [clouds[t] @ poses[t][1].T + poses[t][0] for t in stamps]
    xyz = voxel_downsample(np.concatenate(merged), voxel)
    return World("icl", xyz, pseudo_reflectivity(xyz, 0.2), voxel,
                 *estimate_normals(xyz, 2 * voxel), np.array([poses[t][0] for t in stamps]),
                 np.array([poses[t][1] for t in stamps]), stamps[0])


# ---------------------------------------------------------------------------------------------
# trajectories

def catmull_rom(points: np.ndarray, per_segment: int) -> tuple[np.ndarray, np.ndarray]:
    """Uniform Catmull-Rom spline through `points` (ends extended by reflection): samples (m, 3)
    and their knot parameter (segment index + fraction)."""
    p = np.concatenate([2 * points[:1] - points[1:2], points, 2 * points[-1:] - points[-2:-1]])
    u = np.linspace(0, 1, per_segment, endpoint=False)[:, None]
    out = []
    for k in range(len(points) - 1):
        p0, p1, p2, p3 = p[k], p[k + 1], p[k + 2], p[k + 3]
        out.append(0.5 * (2 * p1 + (p2 - p0) * u + (2 * p0 - 5 * p1 + 4 * p2 - p3) * u**2
                          + (3 * p1 - p0 - 3 * p2 + p3) * u**3))
    out.append(points[-1:])
    knot = np.concatenate([k + u[:, 0] for k in range(len(points) - 1)] + [[len(points) - 1.0]])
    return np.concatenate(out), knot


def knot_rotations(rots: np.ndarray, knot: np.ndarray) -> np.ndarray:
    """Slerp of the keyframe rotations at knot parameters (quaternions)."""
    q = mat_to_quat(rots)
    k = np.clip(np.floor(knot).astype(int), 0, len(rots) - 2)
    return slerp(q[k], q[k + 1], knot - k)


def interp_rows(x: np.ndarray, xp: np.ndarray, fp: np.ndarray) -> np.ndarray:
    return np.stack([np.interp(x, xp, fp[:, c]) for c in range(fp.shape[1])], -1)


def kaist_trajectory(world: World, duration: float) -> tuple[np.ndarray, np.ndarray, dict]:
    """Dense (t, 3) positions and (t, 4) quaternions of the simulated car-mounted sensor."""
    centre, knot = catmull_rom(world.ref_pos, 64)
    quats = knot_rotations(world.ref_rot, knot)
    arc = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(centre, axis=0), axis=1))])
    length = arc[-1]
    # sensor x along the direction of travel: yaw of the travel direction in the keyframes' frame
    travel = world.ref_rot[0].T @ (world.ref_pos[-1] - world.ref_pos[0])
    mount = rot_z(np.array(math.atan2(travel[1], travel[0])))
    t = np.arange(0.0, duration + 2 * TABLE_DT, TABLE_DT)
    w = 2 * math.pi / CAR_SPEED_PERIOD
    dist = CAR_SPEED * t + CAR_SPEED_AMP / w * (1 - np.cos(w * t))
    total = dist[-1]
    s = dist + (length - total) / 2  # centred on the reference path, extrapolated at both ends

    def centre_at(si: np.ndarray) -> np.ndarray:
        pos = interp_rows(np.clip(si, 0, length), arc, centre)
        t0 = centre[1] - centre[0]
        t1 = centre[-1] - centre[-2]
        pos += np.where(si[:, None] < 0, si[:, None] * t0 / np.linalg.norm(t0), 0)
        pos += np.where(si[:, None] > length, (si[:, None] - length) * t1 / np.linalg.norm(t1), 0)
        return pos

    tangent = centre_at(s + 0.5) - centre_at(s - 0.5)
    tangent /= np.linalg.norm(tangent, axis=1, keepdims=True)
    normal = np.cross([0.0, 0.0, 1.0], tangent)
    normal /= np.linalg.norm(normal, axis=1, keepdims=True)
    x = dist / total
    lat = WEAVE_AMP * np.sin(2 * math.pi * dist / WEAVE_LENGTH) * np.sin(math.pi * x) ** 2
    dlat = np.gradient(lat, dist)
    pos = centre_at(s) + lat[:, None] * normal
    qi = np.stack([np.interp(np.clip(s, 0, length), arc, quats[:, c]) for c in range(4)], -1)
    rot = rot_z(np.arctan(dlat)) @ quat_to_mat(qi / np.linalg.norm(qi, axis=1, keepdims=True)) @ mount
    info = {"path": f"reference path {length:.1f} m (21 keyframes), driven {total:.1f} m "
                    f"({s[0]:+.1f} .. {s[-1]:.1f} m along it)"}
    return pos, mat_to_quat(rot), info


def pingpong_time(t: np.ndarray, end: float) -> np.ndarray:
    """Reference time played forward at real speed, turning around smoothly (cosine velocity
    ramp over 2 * TURN_HALF) before each end of [0, end]."""
    tau = np.empty_like(t)
    pos, direction, turn_start = 0.0, 1.0, None
    stop = 2 * TURN_HALF / math.pi  # distance covered while decelerating to zero
    for i, ti in enumerate(t):
        if i:
            dt = ti - t[i - 1]
            if turn_start is None:
                v = direction
                if (direction > 0 and pos >= end - stop) or (direction < 0 and pos <= stop):
                    turn_start = ti
            else:
                u = (ti - turn_start) / (2 * TURN_HALF)
                v = direction * math.cos(math.pi * min(u, 1.0))
                if u >= 1.0:
                    direction, turn_start = -direction, None
            pos += v * dt
        tau[i] = pos
    return tau


def icl_trajectory(world: World, duration: float) -> tuple[np.ndarray, np.ndarray, dict]:
    """The ICL reference camera path at its own timing (0.1 s per keyframe), sensor x along the
    camera's optical axis (the map holds only what the camera saw)."""
    centre, knot = catmull_rom(world.ref_pos, 100)
    quats = knot_rotations(world.ref_rot, knot)
    end = (len(world.ref_pos) - 1) * 0.1
    t = np.arange(0.0, duration + 2 * TABLE_DT, TABLE_DT)
    tau = pingpong_time(t, end) if duration > end - 0.05 else t
    kt = tau / 0.1
    pos = interp_rows(kt, knot, centre)
    qi = np.stack([np.interp(kt, knot, quats[:, c]) for c in range(4)], -1)
    # camera optical frame (x right, y down, z forward) -> Livox (x forward, y left, z up)
    cam_from_sensor = np.array([[0.0, -1.0, 0.0], [0.0, 0.0, -1.0], [1.0, 0.0, 0.0]])
    rot = quat_to_mat(qi / np.linalg.norm(qi, axis=1, keepdims=True)) @ cam_from_sensor
    info = {"path": f"reference path {end:.1f} s, played at real speed"
                    + (" with smooth turnarounds" if duration > end - 0.05 else "")}
    return pos, mat_to_quat(rot), info


class Trajectory:
    """world_from_sensor pose at any time since the first frame's start (1 ms table, linear
    position and normalised-lerp orientation between table entries)."""

    def __init__(self, pos: np.ndarray, quat: np.ndarray):
        self.pos, self.quat = pos, quat
        d = np.sum(quat[1:] * quat[:-1], axis=1) < 0  # keep consecutive quaternions aligned
        sign = np.concatenate([[1.0], np.where(np.cumsum(d) % 2 == 1, -1.0, 1.0)])
        self.quat = quat * sign[:, None]

    def at(self, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        x = np.asarray(t, float) / TABLE_DT
        i = np.clip(np.floor(x).astype(int), 0, len(self.pos) - 2)
        u = (x - i)[:, None]
        p = self.pos[i] * (1 - u) + self.pos[i + 1] * u
        q = self.quat[i] * (1 - u) + self.quat[i + 1] * u
        return quat_to_mat(q / np.linalg.norm(q, axis=1, keepdims=True)), p
