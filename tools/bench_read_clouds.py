#!/usr/bin/env python3
"""Read every point cloud of a log with the mireg Python package (``mireg.read_clouds``) and
with what a Python user has without it, the same arrays out of both: rosbags' AnyReader plus
numpy for ROS 2 logs and bags, the official ``mcap`` reader with ``mcap-ros1-support`` plus numpy
for ROS 1 MCAP logs (rosbags does not read those). Interleaved runs; prints the median seconds
of each and their ratio, after checking that both give the same points (float64, NaN dropped).

Usage:
    bash tools/setup_venv.sh rosbags && tools/.venv-rosbags/bin/pip install ./python
    python3 tools/toolbox.py bench-read-clouds fixtures/ouster_os1_ros1.mcap /tmp/kaist03.mcap
"""

import argparse
import statistics
import time
from pathlib import Path

import numpy as np

import mireg

DTYPES = {1: "i1", 2: "u1", 3: "<i2", 4: "<u2", 5: "<i4", 6: "<u4", 7: "<f4", 8: "<f8"}


def xyz_of(msg) -> np.ndarray:
    """x, y, z of a decoded PointCloud2 as float64, non-finite points and an organised cloud's
    (0, 0, 0) "no return" points dropped (what mireg does)."""
    fields = {f.name: f for f in msg.fields}
    dtype = np.dtype({"names": ["x", "y", "z"],
                      "formats": [DTYPES[fields[a].datatype] for a in "xyz"],
                      "offsets": [fields[a].offset for a in "xyz"],
                      "itemsize": msg.point_step})
    arr = np.frombuffer(bytes(msg.data), dtype, msg.width * msg.height)
    xyz = np.stack([arr["x"], arr["y"], arr["z"]], axis=1).astype(np.float64)
    keep = np.isfinite(xyz).all(axis=1)
    if msg.height > 1:
        keep &= (xyz != 0).any(axis=1)
    return xyz[keep]


def peer(path: Path) -> list[np.ndarray]:
    from mcap.reader import make_reader
    profile = ""
    if path.suffix == ".mcap":
        with open(path, "rb") as f:
            profile = make_reader(f).get_header().profile
    if profile == "ros1":
        from mcap_ros1.decoder import DecoderFactory
        out = []
        with open(path, "rb") as f:
            reader = make_reader(f, decoder_factories=[DecoderFactory()])
            for schema, _, _, msg in reader.iter_decoded_messages():
                if schema.name == "sensor_msgs/PointCloud2":
                    out.append(xyz_of(msg))
        return out
    from rosbags.highlevel import AnyReader
    with AnyReader([path]) as reader:
        conns = [c for c in reader.connections if c.msgtype == "sensor_msgs/msg/PointCloud2"]
        return [xyz_of(reader.deserialize(raw, c.msgtype))
                for c, _, raw in reader.messages(connections=conns)]


def ours(path: Path) -> list[np.ndarray]:
    return [points for _, points, _ in mireg.read_clouds(path)]


def main():
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("logs", nargs="+", type=Path)
    ap.add_argument("--runs", type=int, default=5)
    args = ap.parse_args()
    print(f"{'log':<36} {'clouds':>6} {'points':>10} {'mireg s':>8} {'peer s':>8} {'peer/mireg':>10}")
    for log in args.logs:
        a, b = ours(log), peer(log)
        assert len(a) == len(b), (len(a), len(b))
        assert all(np.array_equal(x, y) for x, y in zip(a, b)), "different points"
        t_ours, t_peer = [], []
        for _ in range(args.runs):
            t0 = time.perf_counter()
            ours(log)
            t1 = time.perf_counter()
            peer(log)
            t2 = time.perf_counter()
            t_ours.append(t1 - t0)
            t_peer.append(t2 - t1)
        mo, mp = statistics.median(t_ours), statistics.median(t_peer)
        print(f"{log.name:<36} {len(a):>6} {sum(len(x) for x in a):>10} {mo:>8.3f} {mp:>8.3f} "
              f"{mp / mo:>9.2f}x")


if __name__ == "__main__":
    main()
