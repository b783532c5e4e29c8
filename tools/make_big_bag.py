"""A large ROS 1 bag for the pass-through benchmark (docs/BENCHMARKS_ARCHIVE.md, "Bags"): the 4 clouds
and poses of fixtures/bags/icl4_none.bag plus BALLAST incompressible messages of MB megabytes
(std_msgs/UInt8MultiArray with random bytes) on /ballast, interleaved with the clouds, written by
rosbags with uncompressed chunks (rosbag record's default).

    python3 tools/toolbox.py make-big-bag /tmp/big.bag --ballast 1000 --mb 1
"""
import argparse
import os
import struct
from pathlib import Path

from rosbags.highlevel import AnyReader
from rosbags.rosbag1 import Writer
from rosbags.typesys import Stores, get_typestore

ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
ap.add_argument("out", type=Path)
ap.add_argument("--ballast", type=int, default=1000)
ap.add_argument("--mb", type=float, default=1.0)
ap.add_argument("--seed", type=int, default=1)
args = ap.parse_args()

src = Path(__file__).resolve().parent.parent / "fixtures/bags/icl4_none.bag"
typestore = get_typestore(Stores.ROS1_NOETIC)
rng_bytes = __import__("random").Random(args.seed).randbytes
size = int(args.mb * 1_000_000)
with AnyReader([src]) as reader:
    msgs = [(c, t, raw) for c, t, raw in reader.messages()]
    conns = {c.id: c for c, _, _ in msgs}
if args.out.exists():
    args.out.unlink()
with Writer(args.out) as w:
    out_conns = {
        cid: w.add_connection(c.topic, c.msgtype, typestore=typestore, callerid="/icl_player")
        for cid, c in conns.items()
    }
    ballast = w.add_connection("/ballast", "std_msgs/msg/UInt8MultiArray", typestore=typestore)
    t0 = msgs[0][1]
    span = msgs[-1][1] - t0
    k = 0
    for i in range(args.ballast):
        t = t0 + span * i // max(args.ballast, 1)
        while k < len(msgs) and msgs[k][1] <= t:
            c, tm, raw = msgs[k]
            w.write(out_conns[c.id], tm, raw)
            k += 1
        # UInt8MultiArray: layout.dim (empty), layout.data_offset, data (u32 length + bytes).
        payload = struct.pack("<III", 0, 0, size) + rng_bytes(size)
        w.write(ballast, t, payload)
    for c, tm, raw in msgs[k:]:
        w.write(out_conns[c.id], tm, raw)
print(f"{args.out}: {os.path.getsize(args.out)} bytes")
