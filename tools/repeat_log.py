#!/usr/bin/env python3
"""Make an N-times longer `mireg register` output from one: the clouds and poses of IN (ROS 2,
CDR) written N times, each repetition's header stamps and log times shifted by the log's span
plus one second, with IN's `mireg` metadata. The map of the result has N times the frames of
IN's map and the same voxels: for measuring that `mireg map`'s memory does not grow with the
number of frames. Only the cloud and pose topics are kept (`/tf` and statistics are dropped).

Usage:
    bash tools/setup_venv.sh mcap
    python3 tools/toolbox.py repeat-log IN.mcap OUT.mcap --times 10
"""

import argparse
import struct

from mcap.reader import make_reader
from mcap.writer import Writer


def shift_cdr_stamp(data, ns):
    """A CDR message whose first field is a std_msgs/Header, with its stamp moved by ns."""
    sec, nsec = struct.unpack_from("<iI", data, 4)
    t = sec * 1_000_000_000 + nsec + ns
    out = bytearray(data)
    struct.pack_into("<iI", out, 4, t // 1_000_000_000, t % 1_000_000_000)
    return bytes(out)


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("input")
    ap.add_argument("output")
    ap.add_argument("--times", type=int, default=10)
    args = ap.parse_args()
    with open(args.input, "rb") as f:
        reader = make_reader(f)
        metas = [m for m in reader.iter_metadata() if m.name == "mireg"]
        if not metas:
            raise SystemExit(f"{args.input}: no mireg metadata (not a mireg register output)")
        meta = dict(metas[-1].metadata)
        keep = {meta["topic"], meta["pose_topic"]}
        msgs = [
            (s, c, m)
            for s, c, m in reader.iter_messages(topics=sorted(keep))
            if c.message_encoding == "cdr"
        ]
    if not msgs:
        raise SystemExit(f"{args.input}: no CDR messages on {sorted(keep)}")
    span = max(m.log_time for _, _, m in msgs) - min(m.log_time for _, _, m in msgs)
    step = span + 1_000_000_000
    with open(args.output, "wb") as f:
        w = Writer(f)
        w.start(profile="ros2", library="tools/repeat_log.py")
        schemas, channels = {}, {}
        for s, c, _ in msgs:
            if s.id not in schemas:
                schemas[s.id] = w.register_schema(s.name, s.encoding, s.data)
            if c.id not in channels:
                channels[c.id] = w.register_channel(c.topic, c.message_encoding, schemas[s.id], c.metadata)
        for r in range(args.times):
            for _, c, m in msgs:
                w.add_message(
                    channels[c.id],
                    log_time=m.log_time + r * step,
                    publish_time=m.publish_time + r * step,
                    data=shift_cdr_stamp(m.data, r * step),
                    sequence=m.sequence,
                )
        w.add_metadata("mireg", meta)
        w.finish()
    clouds = sum(1 for _, c, _ in msgs if c.topic == meta["topic"])
    print(f"{args.output}: {args.times} x {clouds} clouds and their poses")


if __name__ == "__main__":
    main()
