#!/usr/bin/env python3
"""Check an MCAP file with the official Python readers (mcap + mcap_ros2), independently of mireg.

What it does:

(a) prints a summary per topic: schema name and encoding, message encoding, message count and the
    first/last log time;
(b) decodes every message of every channel whose encoding it understands -- ros2msg schema + cdr
    messages (mcap_ros2's schema-driven decoder; PointCloud2 messages are also checked for a
    consistent layout), jsonschema/schemaless + json messages -- and reports failures; channels in
    other encodings (protobuf, ros2idl, ...) are listed as "not decoded", which is not a failure;
(c) with ``--compare-input IN.mcap``: every message of IN must appear in the checked file with the
    same topic, log_time, publish_time and byte-identical data (multiset comparison by
    (topic, log_time, publish_time, sha256(data))), and IN's metadata records and attachments must
    be present too (extra messages, e.g. poses added by mireg, are allowed);
(d) ``--expect-topic NAME`` (repeatable) asserts that a topic is present with >= 1 message.

The file is read linearly record by record with CRC validation (chunk and data-section CRCs), so a
file without summary/index still checks; if a summary is present, its statistics and its chunk
index are cross-checked against the linear pass. Exit status: 0 if all checks pass, 1 otherwise,
2 on usage errors.

Usage:
    bash tools/setup_venv.sh mcap
    python3 tools/toolbox.py check-mcap fixtures/icl_livingroom1.mcap \\
        --expect-topic /camera/depth/points --expect-topic /ground_truth/pose
    python3 tools/toolbox.py check-mcap out.mcap --compare-input in.mcap
"""

import argparse
import datetime
import hashlib
import json
import sys
from collections import Counter

from mcap.reader import make_reader
from mcap.records import Attachment, Channel, Header, Message, Metadata, Schema, Statistics
from mcap.stream_reader import StreamReader
from mcap_ros2.decoder import DecoderFactory as Ros2DecoderFactory

MAX_REPORTED_FAILURES = 5  # per channel


class ChannelInfo:
    """What the linear pass learned about one channel."""

    def __init__(self, channel, schema):
        self.channel = channel
        self.schema = schema
        self.count = 0
        self.first_log_time = None
        self.last_log_time = None
        self.decoded = 0
        self.failures = []  # (log_time, error text), at most MAX_REPORTED_FAILURES
        self.failure_count = 0
        self.decode_mode = None  # "ros2", "json" or None (not decodable here)
        self.decoder = None

    @property
    def schema_name(self):
        return self.schema.name if self.schema else "(none)"

    @property
    def schema_encoding(self):
        return self.schema.encoding if self.schema else "(schemaless)"


class Scan:
    """Result of reading a whole MCAP: channels, message keys, metadata, attachments, problems."""

    def __init__(self, path):
        self.path = path
        self.profile = None
        self.library = None
        self.schemas = {}
        self.channels = {}  # channel id -> ChannelInfo
        self.message_keys = Counter()  # (topic, log_time, publish_time, sha256) -> count
        self.metadata = []  # (name, dict)
        self.attachments = []  # (name, media_type, log_time, create_time, sha256)
        self.statistics = None
        self.errors = []  # file-level problems (each makes the check fail)


def sha256(data):
    return hashlib.sha256(data).hexdigest()


def format_time(ns):
    if ns is None:
        return "-"
    utc = datetime.datetime.fromtimestamp(ns // 1_000_000_000, tz=datetime.timezone.utc)
    return f"{ns} ({utc:%Y-%m-%d %H:%M:%S}.{ns % 1_000_000_000:09d} UTC)"


def check_point_cloud2(msg):
    """Layout checks on a decoded sensor_msgs/msg/PointCloud2; raises ValueError on inconsistency."""
    n_data = len(msg.data)
    if msg.row_step * msg.height != n_data:
        raise ValueError(f"data has {n_data} bytes, row_step {msg.row_step} x height {msg.height}")
    if msg.point_step * msg.width > msg.row_step:
        raise ValueError(f"point_step {msg.point_step} x width {msg.width} > row_step {msg.row_step}")
    sizes = {1: 1, 2: 1, 3: 2, 4: 2, 5: 4, 6: 4, 7: 4, 8: 8}
    for f in msg.fields:
        if f.datatype not in sizes:
            raise ValueError(f"field {f.name!r}: unknown datatype {f.datatype}")
        if f.offset + sizes[f.datatype] * max(f.count, 1) > msg.point_step:
            raise ValueError(f"field {f.name!r} exceeds point_step {msg.point_step}")


def make_decoder(info, ros2_factory):
    """Pick how to decode a channel's messages; returns (mode, callable) or (None, None)."""
    enc = info.channel.message_encoding
    schema = info.schema
    if enc == "cdr" and schema is not None and schema.encoding == "ros2msg":
        decode = ros2_factory.decoder_for(enc, schema)  # raises if the schema text does not parse
        if schema.name in ("sensor_msgs/msg/PointCloud2", "sensor_msgs/PointCloud2"):

            def decode_cloud(data):
                msg = decode(data)
                check_point_cloud2(msg)
                return msg

            return "ros2", decode_cloud
        return "ros2", decode
    if enc == "json" and (schema is None or schema.encoding in ("jsonschema", "")):
        if schema is not None and schema.encoding == "jsonschema":
            json.loads(schema.data)  # the schema itself must be JSON

        return "json", lambda data: json.loads(data.decode("utf-8"))
    return None, None


def scan(path, decode=True):
    """Read every record of `path` in file order with CRC validation; decode messages if asked."""
    result = Scan(path)
    ros2_factory = Ros2DecoderFactory()
    try:
        with open(path, "rb") as f:
            for record in StreamReader(f, validate_crcs=True).records:
                if isinstance(record, Schema):
                    result.schemas[record.id] = record
                elif isinstance(record, Channel):
                    if record.id not in result.channels:
                        schema = result.schemas.get(record.schema_id) if record.schema_id else None
                        if record.schema_id and schema is None:
                            result.errors.append(f"channel {record.topic}: unknown schema id {record.schema_id}")
                        info = ChannelInfo(record, schema)
                        result.channels[record.id] = info
                elif isinstance(record, Message):
                    info = result.channels.get(record.channel_id)
                    if info is None:
                        result.errors.append(f"message on unknown channel id {record.channel_id}")
                        continue
                    add_message(result, info, record, decode, ros2_factory)
                elif isinstance(record, Metadata):
                    result.metadata.append((record.name, dict(record.metadata)))
                elif isinstance(record, Attachment):
                    result.attachments.append(
                        (record.name, record.media_type, record.log_time, record.create_time, sha256(record.data))
                    )
                elif isinstance(record, Statistics):
                    result.statistics = record
                elif isinstance(record, Header):
                    result.profile, result.library = record.profile, record.library
    except Exception as exc:  # a truncated or corrupt file, a CRC mismatch, ...
        result.errors.append(f"reading failed: {type(exc).__name__}: {exc}")
    if result.profile is None:
        result.errors.append("no Header record")
    cross_check_summary(result)
    return result


def add_message(result, info, msg, decode, ros2_factory):
    """Account for one message: counts, times, key for comparison, decoding."""
    info.count += 1
    t = msg.log_time
    info.first_log_time = t if info.first_log_time is None else min(info.first_log_time, t)
    info.last_log_time = t if info.last_log_time is None else max(info.last_log_time, t)
    result.message_keys[(info.channel.topic, t, msg.publish_time, sha256(msg.data))] += 1
    if not decode:
        return
    if info.decode_mode is None and info.decoder is None and info.count == 1:
        try:
            info.decode_mode, info.decoder = make_decoder(info, ros2_factory)
        except Exception as exc:
            info.decode_mode = "broken schema"
            info.decoder = None
            info.failures.append((t, f"schema {info.schema_name} unusable: {type(exc).__name__}: {exc}"))
    if info.decode_mode == "broken schema":
        info.failure_count += 1
        return
    if info.decoder is None:
        return
    try:
        info.decoder(msg.data)
        info.decoded += 1
    except Exception as exc:
        info.failure_count += 1
        if len(info.failures) < MAX_REPORTED_FAILURES:
            info.failures.append((t, f"{type(exc).__name__}: {exc}"))


def cross_check_summary(result):
    """Compare the summary's statistics and chunk index with what the linear pass found."""
    per_channel = {cid: info.count for cid, info in result.channels.items()}
    total = sum(per_channel.values())
    stats = result.statistics
    if stats is not None:
        if stats.message_count != total:
            result.errors.append(f"summary says {stats.message_count} messages, file holds {total}")
        for cid, n in per_channel.items():
            if stats.channel_message_counts.get(cid, 0) != n:
                result.errors.append(
                    f"summary count for channel {cid} is {stats.channel_message_counts.get(cid, 0)}, file holds {n}"
                )
        if stats.metadata_count != len(result.metadata) or stats.attachment_count != len(result.attachments):
            result.errors.append("summary metadata/attachment counts disagree with the file")
    # Reading through the chunk index must find the same messages.
    try:
        with open(result.path, "rb") as f:
            reader = make_reader(f)
            if reader.get_summary() is not None:
                indexed = Counter(m.channel_id for _s, _c, m in reader.iter_messages(log_time_order=False))
                if dict(indexed) != {cid: n for cid, n in per_channel.items() if n}:
                    result.errors.append(f"indexed read finds {sum(indexed.values())} messages, linear read {total}")
    except Exception as exc:
        result.errors.append(f"indexed read failed: {type(exc).__name__}: {exc}")


def print_summary(result):
    print(f"{result.path}: profile {result.profile!r}, library {result.library!r}")
    print(
        f"  {sum(i.count for i in result.channels.values())} messages on {len(result.channels)} channels, "
        f"{len(result.metadata)} metadata records, {len(result.attachments)} attachments"
    )
    for info in sorted(result.channels.values(), key=lambda i: i.channel.topic):
        ch = info.channel
        if info.decode_mode in ("ros2", "json"):
            decoded = f"decoded {info.decoded}/{info.count}"
        elif info.decode_mode == "broken schema":
            decoded = "schema does not parse"
        else:
            decoded = "not decoded (unsupported encoding)" if info.count else "no messages"
        print(f"  {ch.topic}")
        print(f"    schema {info.schema_name} [{info.schema_encoding}], messages [{ch.message_encoding}]")
        print(f"    {info.count} messages, {decoded}")
        print(f"    first log time {format_time(info.first_log_time)}")
        print(f"    last  log time {format_time(info.last_log_time)}")
        for t, err in info.failures:
            print(f"    FAIL at log time {t}: {err}")
        if info.failure_count > len(info.failures):
            print(f"    ... {info.failure_count - len(info.failures)} more failures")
    for name, data in result.metadata:
        print(f"  metadata {name!r}: " + ", ".join(f"{k}={v!r}" for k, v in sorted(data.items())))
    for name, media_type, log_time, _create, digest in result.attachments:
        print(f"  attachment {name!r} [{media_type}] log time {log_time}, sha256 {digest[:16]}...")


def compare(output, reference):
    """Problems if `reference`'s messages, metadata or attachments are missing from `output`."""
    problems = []
    missing = reference.message_keys - output.message_keys
    if missing:
        by_topic = Counter()
        for (topic, _lt, _pt, _h), n in missing.items():
            by_topic[topic] += n
        for topic, n in sorted(by_topic.items()):
            problems.append(f"{n} message(s) of input topic {topic} missing or changed in the output")
        for (topic, lt, pt, h), _n in sorted(missing.items())[:MAX_REPORTED_FAILURES]:
            problems.append(f"  e.g. {topic} log_time {lt} publish_time {pt} sha256 {h[:16]}...")
    out_channels = {i.channel.topic: i for i in output.channels.values()}
    for info in reference.channels.values():
        out = out_channels.get(info.channel.topic)
        if out is None:
            if info.count == 0:
                problems.append(f"input channel {info.channel.topic} (no messages) missing")
            continue
        if (out.schema_name, out.schema_encoding, out.channel.message_encoding) != (
            info.schema_name,
            info.schema_encoding,
            info.channel.message_encoding,
        ):
            problems.append(f"topic {info.channel.topic}: schema/encoding changed")
        elif info.schema is not None and out.schema is not None and info.schema.data != out.schema.data:
            problems.append(f"topic {info.channel.topic}: schema text changed")
    out_meta = Counter(json.dumps([n, d], sort_keys=True) for n, d in output.metadata)
    ref_meta = Counter(json.dumps([n, d], sort_keys=True) for n, d in reference.metadata)
    for key in ref_meta - out_meta:
        problems.append(f"input metadata record {json.loads(key)[0]!r} missing or changed")
    for att in Counter(reference.attachments) - Counter(output.attachments):
        problems.append(f"input attachment {att[0]!r} missing or changed")
    return problems


def main(argv):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("mcap", help="MCAP file to check")
    ap.add_argument("--compare-input", metavar="IN.mcap", help="input whose content must all be present")
    ap.add_argument("--expect-topic", metavar="NAME", action="append", default=[], help="topic that must be present")
    ap.add_argument("--no-decode", action="store_true", help="skip decoding (counts and comparison only)")
    args = ap.parse_args(argv)

    result = scan(args.mcap, decode=not args.no_decode)
    print_summary(result)
    problems = list(result.errors)
    for info in result.channels.values():
        if info.failure_count:
            problems.append(f"{info.channel.topic}: {info.failure_count} message(s) failed to decode")
    topics = {i.channel.topic: i.count for i in result.channels.values()}
    for topic in args.expect_topic:
        if not topics.get(topic):
            problems.append(f"expected topic {topic} is missing or empty")
    if args.compare_input:
        reference = scan(args.compare_input, decode=False)
        problems += [f"input {args.compare_input}: {e}" for e in reference.errors]
        found = compare(result, reference)
        problems += found
        if not found:
            n = sum(reference.message_keys.values())
            print(
                f"compare: all {n} messages, {len(reference.metadata)} metadata records and "
                f"{len(reference.attachments)} attachments of {args.compare_input} are present unchanged"
            )
    if problems:
        print(f"FAILED: {sum(1 for p in problems if not p.startswith(' '))} problem(s)")
        for p in problems:
            print(f"  {p}")
        return 1
    print("OK")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
