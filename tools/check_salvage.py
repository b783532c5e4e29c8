#!/usr/bin/env python3
"""Cut logs at every STEP % of their length, register each cut with mireg, and check every output
with the official Python ``mcap`` reader (and ``rosbags`` for ROS 1 bag inputs).

For each INPUT and each cut k = STEP, 2*STEP, ... < 100 % of its bytes:

(a) ``mireg register CUT -o OUT`` exits 0 with a "damaged" warning on stderr, or 2 with an error
    naming the file and no output left (a cut before the first cloud leaves nothing to register);
    never anything else (a crash is exit 101 or a signal);
(b) OUT is a valid, complete MCAP by the official reader, checked as ``mcap doctor`` would: the
    magic at both ends, a summary whose statistics' message count equals the messages streamed,
    every chunk's CRC (``validate_crcs``), and the indexed reader yielding the same messages as the
    stream reader;
(c) every input message in OUT is one of the whole log's messages, byte for byte, on its topic at
    its log time, and OUT holds at least the messages of every chunk the cut left whole (for MCAP
    inputs: what the official stream reader yields from the cut file before it stops; for bags:
    what rosbags reads from the whole bag in the chunks before the cut, by their index records);
(d) ``--strict`` refuses the cut with exit 2 and no output.

Prints one row per input: cuts tried, registered, refused, messages kept against the whole log,
and exits 1 if any check failed.

Usage:
    bash tools/setup_venv.sh rosbags
    cargo build --release
    python3 tools/toolbox.py check-salvage --mireg target/release/mireg \\
        fixtures/icl_livingroom1.mcap fixtures/ouster_os1_ros1.mcap \\
        fixtures/bags/icl4_none.bag fixtures/bags/icl4_lz4.bag fixtures/bags/icl4_bz2.bag
"""

import argparse
import hashlib
import io
import struct
import subprocess
import sys
import tempfile
import time
from collections import Counter
from pathlib import Path

from mcap.reader import make_reader
from mcap.records import Channel, Message
from mcap.stream_reader import StreamReader
from rosbags.rosbag1 import Reader as Ros1Reader

import mireg_run


def key(topic, log_time, data):
    return (topic, log_time, hashlib.sha256(bytes(data)).hexdigest())


def mcap_stream_messages(data):
    """Messages the official stream reader yields from ``data`` before it stops."""
    out = []
    channels = {}
    try:
        reader = StreamReader(io.BytesIO(data), skip_magic=False, emit_chunks=False,
                              validate_crcs=True)
        for record in reader.records:
            if isinstance(record, Channel):
                channels[record.id] = record.topic
            elif isinstance(record, Message):
                out.append(key(channels[record.channel_id], record.log_time, record.data))
    except Exception:  # noqa: BLE001 -- the cut: stop where the reader stops
        pass
    return out


def bag_messages(path):
    """Every message of a whole ROS 1 bag by rosbags, in file order, with the chunk it is in."""
    with Ros1Reader(path) as reader:
        msgs = [(key(c.topic, t, raw), c.topic) for c, t, raw in reader.messages()]
        # rosbags yields in time order; a message's chunk comes from the index records below.
    return [m for m, _ in msgs]


def bag_chunk_ends(data):
    """(end offset of each chunk, messages in it), from the top-level records' index data."""
    pos, out = 13, []
    while pos < len(data):
        header_len = struct.unpack_from("<I", data, pos)[0]
        fields, h = {}, pos + 4
        while h < pos + 4 + header_len:
            n = struct.unpack_from("<I", data, h)[0]
            name, _, value = data[h + 4:h + 4 + n].partition(b"=")
            fields[name.decode()] = value
            h += 4 + n
        data_len = struct.unpack_from("<I", data, pos + 4 + header_len)[0]
        end = pos + 8 + header_len + data_len
        if fields["op"] == b"\x05":
            out.append([end, 0])
        elif fields["op"] == b"\x04" and out:
            out[-1][1] += struct.unpack("<I", fields["count"])[0]
        pos = end
    return out


def check_output(out_path, whole, floor, problems, label):
    """(b) and (c) for one output; returns how many input messages it holds."""
    data = out_path.read_bytes()
    magic = b"\x89MCAP0\r\n"
    if not (data.startswith(magic) and data.endswith(magic)):
        problems.append(f"{label}: output lacks the MCAP magic at an end")
        return 0
    with open(out_path, "rb") as f:
        reader = make_reader(f, validate_crcs=True)
        summary = reader.get_summary()
        if summary is None or summary.statistics is None:
            problems.append(f"{label}: output has no summary statistics")
            return 0
        indexed = [key(c.topic, m.log_time, m.data) for _, c, m in reader.iter_messages()]
    streamed = mcap_stream_messages(data)
    if len(streamed) != summary.statistics.message_count:
        problems.append(f"{label}: statistics say {summary.statistics.message_count} messages, "
                        f"the stream holds {len(streamed)}")
    if Counter(indexed) != Counter(streamed):
        problems.append(f"{label}: indexed and streamed readers disagree")
    whole_set = Counter(whole)
    topics = {k[0] for k in whole}
    kept = [k for k in streamed if k[0] in topics]
    extra = Counter(kept) - whole_set
    if extra:
        problems.append(f"{label}: {sum(extra.values())} input-topic messages not in the whole log")
    if len(kept) < floor:
        problems.append(f"{label}: {len(kept)} input messages kept, the whole chunks hold {floor}")
    return len(kept)


def main():
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("inputs", nargs="+", type=Path)
    ap.add_argument("--mireg", default=mireg_run.default_binary())
    ap.add_argument("--step", type=int, default=1, help="percent between cuts [%(default)s]")
    args = ap.parse_args()
    problems = []
    started = time.time()
    print(f"{'input':<28} {'cuts':>4} {'registered':>10} {'refused':>7} "
          f"{'kept at 50 %':>14} {'kept at 99 %':>14}")
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        for inp in args.inputs:
            data = inp.read_bytes()
            is_bag = data.startswith(b"#ROSBAG V2.0\n")
            whole = bag_messages(inp) if is_bag else mcap_stream_messages(data)
            chunks = bag_chunk_ends(data) if is_bag else None
            counts = Counter()
            kept_at = {}
            for k in range(args.step, 100, args.step):
                at = len(data) * k // 100
                cut = tmp / f"cut{inp.suffix}"
                cut.write_bytes(data[:at])
                out = tmp / "out.mcap"
                out.unlink(missing_ok=True)
                label = f"{inp.name} cut at {k} %"
                run = subprocess.run([args.mireg, "register", str(cut), "-o", str(out), "--quiet"],
                                     capture_output=True, text=True)
                if run.returncode == 0:
                    counts["registered"] += 1
                    if "damaged" not in run.stderr:
                        problems.append(f"{label}: no damage warning")
                    floor = (sum(n for end, n in chunks if end <= at) if is_bag
                             else len(mcap_stream_messages(data[:at])))
                    kept_at[k] = check_output(out, whole, floor, problems, label)
                elif run.returncode == 2 and cut.name in run.stderr and not out.exists():
                    counts["refused"] += 1
                else:
                    problems.append(f"{label}: exit {run.returncode}: {run.stderr.strip()[-300:]}")
                out.unlink(missing_ok=True)
                run = subprocess.run([args.mireg, "register", str(cut), "-o", str(out), "--quiet",
                                      "--strict"], capture_output=True, text=True)
                if run.returncode != 2 or out.exists():
                    problems.append(f"{label}: --strict exit {run.returncode}")
                counts["cuts"] += 1

            def share(k):
                return f"{kept_at[k]}/{len(whole)}" if k in kept_at else "-"
            print(f"{inp.name:<28} {counts['cuts']:>4} {counts['registered']:>10} "
                  f"{counts['refused']:>7} {share(50):>14} {share(99):>14}")
    for p in problems[:40]:
        print("FAIL", p)
    print(f"{len(problems)} problems; {time.time() - started:.1f} s")
    sys.exit(1 if problems else 0)


if __name__ == "__main__":
    main()
