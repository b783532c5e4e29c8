#!/usr/bin/env python3
"""Turn the MulRan KAIST03 keyframes (../shared/data/mulran_kaist03_keyframes: binary PCD scans,
KITTI-format poses, UNIX times) into a ROS 2 MCAP that `mireg register` and
tools/compare_kiss_icp.py read:

* ``/os1_cloud_node/points`` -- ``sensor_msgs/msg/PointCloud2``, fields x, y, z, intensity FLOAT32
  (point_step 16), frame_id ``os1_lidar``, stamped with times.txt;
* ``/ground_truth/pose`` -- ``geometry_msgs/msg/PoseStamped``, frame_id ``world``, the reference
  ``first_from_sensor_k = P_0^-1 P_k`` (SC-A-LOAM's loop-closed estimate, not survey ground truth).

``--frames 0-3,8-10,16-20`` keeps only those scans (irregular gaps, as when a recorder drops
messages). MulRan is CC BY-NC-SA 4.0: write the MCAP outside the repository (benchmarks only).

``--ouster-time`` adds the Ouster driver's per-point time field ``t`` (UINT32, ns since the scan
start, point_step 20), which the PCDs do not keep, inferred from each point's azimuth: the
OS1-64 spins clockwise at 10 Hz (MulRan's setting), firing its 1024 columns in turn, so a point
at azimuth ``a`` was measured ``((a0 - a) mod 360) / 360 * 100 ms`` after the first column. The
first point of each scan gives ``a0``. Each beam's azimuth offset (a few degrees on the OS1) makes
a time off by up to about 1 ms, and near the seam it cannot tell the scan's start from its end:
points within 6 degrees of ``a0`` (about 3 %) are left out. For testing deskewing on real LiDAR
motion; compare with and without deskewing on this same log (``--deskew on|off``).

Usage:
    bash tools/setup_venv.sh mcap
    python3 tools/toolbox.py make-kaist03-mcap --out /tmp/kaist03.mcap
    python3 tools/toolbox.py make-kaist03-mcap --frames 0-3,8-10,16-20 --out /tmp/kaist03_gaps.mcap
"""

import argparse
import math
import os
import struct
import sys

from mcap.writer import CompressionType
from mcap_ros2.writer import Writer as Ros2Writer

TOOLS_DIR = os.path.dirname(os.path.abspath(__file__))
import make_fixture_mcap as fx  # noqa: E402  (schemas, rigid-transform and message helpers)

DEFAULT_DATA = os.path.join(TOOLS_DIR, "..", "..", "shared", "data", "mulran_kaist03_keyframes")
CLOUD_TOPIC = "/os1_cloud_node/points"
CLOUD_FRAME = "os1_lidar"
FLOAT32 = 7
UINT32 = 6
SCAN_PERIOD_NS = 100_000_000  # MulRan's OS1-64 spins at 10 Hz
SEAM_DEG = 6.0  # azimuths this close to the first point's are ambiguous (start or end of scan?)


def with_ouster_time(data, n):
    """`data` (n points of x, y, z, intensity float32) with a uint32 `t` appended to each point
    (ns since the scan start, from the point's azimuth), without the points near the seam
    (module docstring); returns (points kept, bytes)."""
    points = list(struct.iter_unpack("<4f", data))
    azimuth = [math.degrees(math.atan2(p[1], p[0])) for p in points]
    first = azimuth[0]
    out = bytearray()
    kept = 0
    for p, a in zip(points, azimuth):
        behind = (first - a) % 360.0
        if behind < SEAM_DEG or behind > 360.0 - SEAM_DEG:
            continue
        out += struct.pack("<4fI", *p, round(behind / 360.0 * SCAN_PERIOD_NS))
        kept += 1
    return kept, bytes(out)


def read_pcd_xyzi(path):
    """(x, y, z, intensity) float32 bytes of a binary PCD v0.7 with exactly those fields."""
    with open(path, "rb") as f:
        blob = f.read()
    end = blob.index(b"DATA binary\n") + len(b"DATA binary\n")
    head = dict(line.split(" ", 1) for line in blob[:end].decode("ascii").splitlines() if line and line[0] != "#")
    if head["FIELDS"].split() != ["x", "y", "z", "intensity"] or head["TYPE"].split() != ["F"] * 4:
        raise SystemExit(f"{path}: expected float32 fields x y z intensity, got {head['FIELDS']} {head['TYPE']}")
    n = int(head["POINTS"])
    data = blob[end:end + 16 * n]
    if len(data) != 16 * n:
        raise SystemExit(f"{path}: {len(data)} data bytes, expected {16 * n}")
    return n, data


def scan_path(data, k):
    return os.path.join(data, "Scans", f"{k:06d}.pcd")


def read_times(data):
    """UNIX time [s] of each scan (times.txt)."""
    with open(os.path.join(data, "times.txt")) as f:
        return [float(x) for x in f.read().split()]


def cloud_message(t_ns, n, data, ouster_time=False):
    """The PointCloud2 message of one scan (`n` points of x, y, z, intensity float32 in `data`),
    with the inferred per-point time `t` when `ouster_time`; also used by tools/make_loop_logs.py."""
    fields = [{"name": c, "offset": 4 * i, "datatype": FLOAT32, "count": 1}
              for i, c in enumerate(("x", "y", "z", "intensity"))]
    step = 16
    if ouster_time:
        n, data = with_ouster_time(data, n)
        fields.append({"name": "t", "offset": 16, "datatype": UINT32, "count": 1})
        step = 20
    return {
        "header": fx.header(t_ns, CLOUD_FRAME),
        "height": 1,
        "width": n,
        "fields": fields,
        "is_bigendian": False,
        "point_step": step,
        "row_step": step * n,
        "data": data,
        "is_dense": True,
    }


def read_kitti_poses(path):
    poses = []
    with open(path) as f:
        for line in f:
            v = [float(x) for x in line.split()]
            if len(v) == 12:
                poses.append([v[0:4], v[4:8], v[8:12], [0.0, 0.0, 0.0, 1.0]])
    return poses


def parse_frames(text, count):
    if not text:
        return list(range(count))
    out = []
    for part in text.split(","):
        a, _, b = part.partition("-")
        out.extend(range(int(a), int(b or a) + 1))
    return out


def main(argv):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--data", default=DEFAULT_DATA)
    ap.add_argument("--out", required=True)
    ap.add_argument("--frames", default="", help="scans to keep, e.g. 0-3,8-10,16-20 (default: all)")
    ap.add_argument("--ouster-time", action="store_true",
                    help="add the Ouster per-point time field t, inferred from azimuth (see above)")
    args = ap.parse_args(argv)
    if not os.path.isdir(args.data):
        raise SystemExit(f"{args.data}: not found (the KAIST03 keyframes live in ../shared/data)")
    poses = read_kitti_poses(os.path.join(args.data, "poses_kitti.txt"))
    times = read_times(args.data)
    frames = parse_frames(args.frames, len(poses))
    first_inv = fx.rigid_inverse(poses[frames[0]])
    tmp = args.out + ".tmp"
    with open(tmp, "wb") as f:
        writer = Ros2Writer(f, compression=CompressionType.ZSTD)
        cloud_schema = writer.register_msgdef("sensor_msgs/msg/PointCloud2", fx.POINT_CLOUD2_SCHEMA)
        pose_schema = writer.register_msgdef("geometry_msgs/msg/PoseStamped", fx.POSE_STAMPED_SCHEMA)
        for seq, k in enumerate(frames):
            n, data = read_pcd_xyzi(scan_path(args.data, k))
            t_ns = round(times[k] * 1e9)
            cloud = cloud_message(t_ns, n, data, args.ouster_time)
            writer.write_message(CLOUD_TOPIC, cloud_schema, cloud, log_time=t_ns, publish_time=t_ns, sequence=seq)
            pose = fx.pose_message(t_ns, fx.mat_mul(first_inv, poses[k]))
            writer.write_message(fx.POSE_TOPIC, pose_schema, pose, log_time=t_ns, publish_time=t_ns, sequence=seq)
        writer.finish()
    os.replace(tmp, args.out)
    print(f"{args.out}: {len(frames)} scans ({args.frames or 'all'}), {os.path.getsize(args.out)} bytes")


if __name__ == "__main__":
    main(sys.argv[1:])
