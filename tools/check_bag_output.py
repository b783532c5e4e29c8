#!/usr/bin/env python3
"""Check that an output MCAP (e.g. mireg's) carries every message of a ROS bag input unchanged,
using third-party readers only: `rosbags` for the input, the official `mcap` reader (and
mcap-ros1-support's decoder) for the output.

INPUT is a ROS 1 .bag file, a rosbag2 directory (metadata.yaml + .db3/.mcap files) or a single
.mcap/.db3 file; it is read with rosbags' AnyReader, except a ROS 1 MCAP log (profile ros1),
which rosbags does not read: that one is read with the mcap reader. OUTPUT.mcap is read with ``mcap.reader``.

Checks (each failure is printed; exit status 1 if any, 0 if none, 2 on usage errors):

(a) messages: for every input topic, the output has exactly as many messages on that topic, and
    the multisets of (log time in ns, sha256 of the bytes) are equal -- i.e. every input message
    is present with the same topic, the same log time (= the bag's record / storage timestamp) and
    byte-identical serialised data (ROS 1 bytes for .bag inputs, CDR for rosbag2). Output topics
    that are not in the input (mireg's /tf, /mireg/pose, ...) are allowed;
(b) ROS 1 inputs only: every bag connection has an output channel on its topic whose metadata
    carries ``md5sum`` (= the connection's), ``callerid`` (= the connection's, checked when the
    connection has one) and ``latching`` (= the connection's value; "0" or absent when the
    connection has none), and whose schema has encoding ``ros1msg`` and data equal to the
    connection's message_definition text; every output channel on a copied topic must match one
    of the topic's connections. A schema name other than the ROS 1 type name is only a warning;
(c) ``--expect-topic T`` (repeatable): T has at least one message in the output;
(d) ``--ros1``: every message on the output's ``/tf`` (tf2_msgs/TFMessage), ``/mireg/pose``
    (geometry_msgs/PoseStamped) and ``/mireg/pose_cov`` (geometry_msgs/PoseWithCovarianceStamped)
    channels is decoded with mcap_ros1's DecoderFactory; the count and the last transform / pose are
    printed. Every covariance must be 36 finite values, symmetric, with a positive diagonal. The
    three topics must be present with ros1msg schemas.

Usage:
    bash tools/setup_venv.sh rosbags
    python3 tools/toolbox.py check-bag-output fixtures/bags/icl4_lz4.bag out.mcap \\
        --expect-topic /mireg/pose --ros1
    python3 tools/toolbox.py check-bag-output fixtures/bags/icl4_db3 out.mcap
    python3 tools/toolbox.py check-bag-output fixtures/icl_livingroom1.mcap \\
        fixtures/icl_livingroom1.mcap      # trivial self-check, passes
"""

import argparse
import hashlib
import math
import sys
from collections import Counter, defaultdict
from pathlib import Path
from types import SimpleNamespace

from mcap.reader import make_reader
from mcap_ros1.decoder import DecoderFactory as Ros1DecoderFactory
from rosbags.highlevel import AnyReader
from rosbags.typesys.msg import denormalize_msgtype

MAX_REPORTED = 5  # mismatching messages reported per topic
ROS1_TOPICS = ("/tf", "/mireg/pose", "/mireg/pose_cov")


def fmt_time(ns):
    return f"{ns // 10**9}.{ns % 10**9:09d}"


def read_input(path):
    """Per topic: Counter of (log_time, sha256); list of connections; whether it is ROS 1."""
    messages = defaultdict(Counter)
    with AnyReader([path]) as reader:
        is_ros1 = not reader.is2
        connections = defaultdict(list)
        for conn in reader.connections:
            connections[conn.topic].append(conn)
        for conn, timestamp, raw in reader.messages():
            messages[conn.topic][(timestamp, hashlib.sha256(raw).hexdigest())] += 1
    return messages, connections, is_ros1


def read_ros1_mcap_input(path):
    """Like read_input for a ROS 1 MCAP log (which rosbags does not read), with the official
    mcap reader; each channel stands in for a bag connection (its metadata holds the header)."""
    messages = defaultdict(Counter)
    connections = defaultdict(list)
    with open(path, "rb") as f:
        reader = make_reader(f)
        summary = reader.get_summary()
        for ch in summary.channels.values():
            sc = summary.schemas.get(ch.schema_id)
            md = ch.metadata
            connections[ch.topic].append(SimpleNamespace(
                id=ch.id, topic=ch.topic, digest=md.get("md5sum"),
                msgtype=sc.name if sc else "",
                msgdef=SimpleNamespace(data=sc.data.decode() if sc else ""),
                ext=SimpleNamespace(callerid=md.get("callerid"), latching=md.get("latching"))))
        for _sc, ch, msg in reader.iter_messages(log_time_order=False):
            messages[ch.topic][(msg.log_time, hashlib.sha256(msg.data).hexdigest())] += 1
    return messages, connections, True


def is_ros1_mcap(path):
    if path.suffix != ".mcap" or not path.is_file():
        return False
    with open(path, "rb") as f:
        return make_reader(f).get_header().profile == "ros1"


def read_output(path):
    """Per topic: Counter of (log_time, sha256); list of (channel, schema)."""
    messages = defaultdict(Counter)
    channels = defaultdict(list)
    with open(path, "rb") as f:
        reader = make_reader(f)
        summary = reader.get_summary()
        if summary is not None:
            for channel in summary.channels.values():
                channels[channel.topic].append((channel, summary.schemas.get(channel.schema_id)))
        seen = {c.id for lst in channels.values() for c, _ in lst}
        for schema, channel, message in reader.iter_messages(log_time_order=False):
            if channel.id not in seen:  # file without a summary, or an incomplete one
                seen.add(channel.id)
                channels[channel.topic].append((channel, schema))
            messages[channel.topic][(message.log_time, hashlib.sha256(message.data).hexdigest())] += 1
    return messages, channels


def compare_messages(topic, want, got, failures):
    """Print a summary line for `topic` and record mismatches."""
    n_in, n_out = sum(want.values()), sum(got.values())
    missing = want - got
    extra = got - want
    ok = n_in == n_out and not missing and not extra
    print(f"{topic}: input {n_in}, output {n_out} messages: {'OK' if ok else 'MISMATCH'}")
    if ok:
        return
    if n_in != n_out:
        failures.append(f"{topic}: message count differs: input {n_in}, output {n_out}")
    if not n_out:
        failures.append(f"{topic}: no output message on this topic")
        return
    out_times = Counter(t for t, _ in got.elements())
    out_digests = defaultdict(list)
    for t, digest in extra:
        out_digests[digest].append(t)
    reported = 0
    for (t, digest), count in sorted(missing.items()):
        if reported == MAX_REPORTED:
            failures.append(f"{topic}: ... {sum(missing.values()) - reported} more missing/changed")
            break
        if out_digests[digest]:
            what = ("the same bytes are in the output at log time(s) "
                    + ", ".join(str(x) for x in sorted(out_digests[digest])[:3]))
        elif out_times[t]:
            what = "bytes differ (an output message has this log time with other bytes)"
        else:
            what = "no output message has this log time"
        failures.append(f"{topic}: input message at log time {fmt_time(t)} ns={t} "
                        f"(sha256 {digest[:12]}, x{count}) not in output: {what}")
        reported += 1
    if extra and not missing:
        failures.append(f"{topic}: output has {sum(extra.values())} message(s) not in the input")


def channel_mismatches(conn, channel, schema):
    """Why an output channel does not carry a ROS 1 bag connection's header (empty = it does)."""
    md = channel.metadata
    why = []
    if md.get("md5sum") != conn.digest:
        why.append(f"md5sum {md.get('md5sum')!r} != {conn.digest!r}")
    callerid, latching = conn.ext.callerid, conn.ext.latching
    if callerid is not None and md.get("callerid") != callerid:
        why.append(f"callerid {md.get('callerid')!r} != {callerid!r}")
    if latching is not None:
        if md.get("latching") != str(latching):
            why.append(f"latching {md.get('latching')!r} != {str(latching)!r}")
    elif md.get("latching") not in (None, "0"):
        why.append(f"latching {md.get('latching')!r}, connection has none (expected '0' or absent)")
    if schema is None:
        why.append("channel has no schema")
    else:
        if schema.encoding != "ros1msg":
            why.append(f"schema encoding {schema.encoding!r} != 'ros1msg'")
        text = schema.data.decode("utf-8", "replace")
        if text != conn.msgdef.data:
            why.append(f"schema data ({len(schema.data)} bytes) != the connection's "
                       f"message_definition ({len(conn.msgdef.data.encode())} bytes)")
    if channel.message_encoding != "ros1":
        why.append(f"message encoding {channel.message_encoding!r} != 'ros1'")
    return why


def check_ros1_channels(topic, conns, out_channels, failures, warnings):
    if not out_channels:
        return  # reported by the message comparison (or the topic had no messages)
    n_before = len(failures)
    matched = set()
    all_conns_matched = True
    for conn in conns:
        results = [(ch, sc, channel_mismatches(conn, ch, sc)) for ch, sc in out_channels]
        good = [(ch, sc) for ch, sc, why in results if not why]
        if not good:
            all_conns_matched = False
            desc = f"connection {conn.id} (callerid {conn.ext.callerid!r})"
            for ch, _, why in results:
                failures.append(f"{topic}: output channel {ch.id} does not carry bag {desc}: "
                                + "; ".join(why))
        for ch, sc in good:
            matched.add(ch.id)
            ros1_type = (denormalize_msgtype(conn.msgtype) if "/msg/" in conn.msgtype
                         else conn.msgtype)
            if sc.name != ros1_type:
                warnings.append(f"{topic}: channel {ch.id} schema name {sc.name!r} is not the "
                                f"ROS 1 type {ros1_type!r}")
    if all_conns_matched:  # otherwise the unmatched channels were reported above
        for ch, _ in out_channels:
            if ch.id not in matched:
                failures.append(f"{topic}: output channel {ch.id} matches none of the topic's "
                                f"{len(conns)} bag connection(s)")
    if len(failures) == n_before:
        ids = ", ".join(str(ch.id) for ch, _ in out_channels)
        print(f"{topic}: output channel(s) {ids} carry the bag connection header "
              f"({len(conns)} connection(s): md5sum, callerid, latching, ros1msg definition): OK")


def check_ros1_decoding(path, failures):
    counts = Counter()
    last = {}
    with open(path, "rb") as f:
        reader = make_reader(f, decoder_factories=[Ros1DecoderFactory()])
        summary = reader.get_summary()
        if summary is not None:
            for ch in summary.channels.values():
                if ch.topic in ROS1_TOPICS:
                    sc = summary.schemas.get(ch.schema_id)
                    if sc is None or sc.encoding != "ros1msg" or ch.message_encoding != "ros1":
                        failures.append(f"--ros1: {ch.topic} channel {ch.id} is not ros1msg/ros1 "
                                        f"(schema {sc.encoding if sc else None!r}, "
                                        f"messages {ch.message_encoding!r})")
        try:
            for _sc, ch, _msg, decoded in reader.iter_decoded_messages(topics=list(ROS1_TOPICS),
                                                                       log_time_order=False):
                counts[ch.topic] += 1
                last[ch.topic] = decoded
                if ch.topic == "/mireg/pose_cov":
                    c = list(decoded.pose.covariance)
                    ok = (len(c) == 36 and all(math.isfinite(v) for v in c)
                          and all(c[7 * i] > 0 for i in range(6))
                          and all(abs(c[6 * i + j] - c[6 * j + i]) <= 1e-12 * max(1.0, abs(c[6 * i + j]))
                                  for i in range(6) for j in range(6)))
                    if not ok:
                        failures.append(f"--ros1: {ch.topic} covariance is not 36 finite symmetric values "
                                        f"with a positive diagonal: {c}")
        except Exception as err:  # noqa: BLE001 -- any decoder failure is a check failure
            failures.append(f"--ros1: decoding failed: {type(err).__name__}: {err}")
    for topic in ROS1_TOPICS:
        if not counts[topic]:
            failures.append(f"--ros1: output has no decodable message on {topic}")
            continue
        m = last[topic]
        if topic == "/tf":
            n_tf = len(m.transforms)
            if not n_tf:
                print(f"{topic}: decoded {counts[topic]} TFMessage(s); the last is empty")
                continue
            t = m.transforms[-1]
            tr, q = t.transform.translation, t.transform.rotation
            print(f"{topic}: decoded {counts[topic]} TFMessage(s); last transform "
                  f"{t.header.frame_id} -> {t.child_frame_id} at "
                  f"{t.header.stamp.secs}.{t.header.stamp.nsecs:09d}: "
                  f"t = ({tr.x:.6f}, {tr.y:.6f}, {tr.z:.6f}), "
                  f"q (x, y, z, w) = ({q.x:.6f}, {q.y:.6f}, {q.z:.6f}, {q.w:.6f})")
        elif topic == "/mireg/pose_cov":
            c = m.pose.covariance
            print(f"{topic}: decoded {counts[topic]} PoseWithCovarianceStamped; last sigma x y z "
                  f"({math.sqrt(c[0]):.3g}, {math.sqrt(c[7]):.3g}, {math.sqrt(c[14]):.3g}) m")
        else:
            p, q = m.pose.position, m.pose.orientation
            print(f"{topic}: decoded {counts[topic]} PoseStamped; last pose in "
                  f"{m.header.frame_id!r} at {m.header.stamp.secs}.{m.header.stamp.nsecs:09d} "
                  f"(seq {m.header.seq}): t = ({p.x:.6f}, {p.y:.6f}, {p.z:.6f}), "
                  f"q (x, y, z, w) = ({q.x:.6f}, {q.y:.6f}, {q.z:.6f}, {q.w:.6f})")


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("input", type=Path, help="ROS 1 .bag, rosbag2 directory, or .mcap/.db3 file")
    ap.add_argument("output", type=Path, help="output MCAP to check")
    ap.add_argument("--expect-topic", action="append", default=[], metavar="T",
                    help="topic that must have >= 1 message in the output (repeatable)")
    ap.add_argument("--ros1", action="store_true",
                    help="decode the output's /tf and /mireg/pose with mcap_ros1")
    args = ap.parse_args()
    for p in (args.input, args.output):
        if not p.exists():
            print(f"error: {p} does not exist", file=sys.stderr)
            return 2

    failures, warnings = [], []
    try:
        if is_ros1_mcap(args.input):
            in_msgs, in_conns, is_ros1 = read_ros1_mcap_input(args.input)
        else:
            in_msgs, in_conns, is_ros1 = read_input(args.input)
    except Exception as err:  # noqa: BLE001 -- report unreadable inputs plainly
        print(f"FAIL: cannot read input {args.input} with rosbags: {type(err).__name__}: {err}")
        return 1
    try:
        out_msgs, out_channels = read_output(args.output)
    except Exception as err:  # noqa: BLE001
        print(f"FAIL: cannot read output {args.output} with the mcap reader: "
              f"{type(err).__name__}: {err}")
        return 1
    kind = ("ROS 1 MCAP" if is_ros1_mcap(args.input) else "ROS 1 bag" if is_ros1 else "rosbag2 directory" if args.input.is_dir()
            else f"rosbag2 {args.input.suffix} file")
    print(f"input {args.input} ({kind}): {sum(sum(c.values()) for c in in_msgs.values())} messages "
          f"on {len(in_conns)} topic(s); output {args.output}: "
          f"{sum(sum(c.values()) for c in out_msgs.values())} messages on "
          f"{len(out_channels)} topic(s)")

    for topic in sorted(in_conns):
        compare_messages(topic, in_msgs.get(topic, Counter()), out_msgs.get(topic, Counter()),
                         failures)
        if is_ros1:
            check_ros1_channels(topic, in_conns[topic], out_channels.get(topic, []), failures,
                                warnings)
    for topic in args.expect_topic:
        n = sum(out_msgs.get(topic, Counter()).values())
        print(f"{topic}: expected topic: {n} message(s) in the output: {'OK' if n else 'MISSING'}")
        if not n:
            failures.append(f"expected topic {topic} has no message in the output")
    if args.ros1:
        check_ros1_decoding(args.output, failures)

    for w in warnings:
        print(f"warning: {w}")
    if failures:
        for f in failures:
            print(f"FAIL: {f}")
        print(f"{len(failures)} check(s) failed")
        return 1
    print("all checks passed")
    return 0


if __name__ == "__main__":
    sys.exit(main())
