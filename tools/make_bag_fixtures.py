#!/usr/bin/env python3
"""Write third-party ROS bag fixtures (fixtures/bags/) with the `rosbags` package from the first 4
frames of fixtures/icl_livingroom1.mcap.

Input: the first ``--frames`` (4) messages of ``/camera/depth/points`` (sensor_msgs/msg/PointCloud2,
cdr) of the source MCAP and the ``/ground_truth/pose`` (geometry_msgs/msg/PoseStamped, cdr)
messages with the same log times, read with the official ``mcap`` reader.

Output (every file is written by rosbags' writers; no byte is written by hand except the composed
metadata.yaml of the split bag, see below). Every name starts with ``icl{frames}_`` (``icl4_``
with the default ``--frames 4``):

* ROS 1 bags, format 2.0 (``rosbags.rosbag1.Writer``): ``icl4_none.bag``, ``icl4_bz2.bag``,
  ``icl4_lz4.bag`` -- chunk compression none / bz2 / lz4, chunk threshold ``--chunk-threshold``
  (100,000 bytes of uncompressed chunk data) so each bag has several chunks (at least 3; 3 with 4
  frames). The CDR messages are deserialised with rosbags' ROS 2 (jazzy) typestore and re-built as
  ROS 1 noetic messages (``sensor_msgs/PointCloud2``, ``geometry_msgs/PoseStamped``; header seq =
  frame index 0..frames-1, same stamp and frame_id, the point data bytes unchanged) and serialised
  with ``serialize_ros1`` of the noetic typestore. Connections: message definition and md5sum from
  the noetic typestore; ``/camera/depth/points`` has callerid ``/icl_player`` and latching 0,
  ``/ground_truth/pose`` has latching 0 and no callerid (so readers see both cases). Message time =
  the MCAP log_time.
* rosbag2 bags, metadata version 9 (``rosbags.rosbag2.Writer``): ``icl4_mcap/`` (storage mcap,
  uncompressed), ``icl4_db3/`` (storage sqlite3) -- the source's CDR bytes copied unchanged
  (``Writer.write`` takes the serialised bytes), timestamps = log_time; type definitions and RIHS01
  hashes from rosbags' ROS 2 jazzy typestore; no QoS profiles.
* compressed rosbag2 bags, the same messages with rosbags' zstd compression:
  ``icl4_mcap_zstd_file/`` and ``icl4_db3_zstd_file/`` (``compression_mode: file``: each storage
  file compressed whole, ``icl4_..._0.mcap.zstd`` / ``.db3.zstd``), ``icl4_mcap_zstd_message/`` and
  ``icl4_db3_zstd_message/`` (``compression_mode: message``: each message's bytes a zstd frame).
* ``icl4_split/``: one rosbag2 sqlite3 bag in two files. rosbags cannot split a bag, so each half
  (the first frames // 2 frames' messages, then the rest: frames 0-1 and 2-3 by default) is written
  as its own bag by rosbags, the two .db3 files are moved into icl4_split/ as ``icl4_split_0.db3`` /
  ``icl4_split_1.db3`` and one metadata.yaml is composed from the two halves' rosbags-written
  metadata.yaml (same keys, same ruamel.yaml dumper settings as rosbags): relative_file_paths and
  files list both files with their own starting times, durations and counts, the totals and
  per-topic counts are the sums. Each .db3 keeps its own ``metadata`` table row, which describes
  only its half.

Checks after writing: every bag is read back with rosbags' AnyReader (counts per topic, times,
bytes: CDR identical for rosbag2, ROS 1 messages re-decoded and their point data identical to the
source's). Nothing depends on the wall clock, so two runs give the same bytes (the MCAP header
names the rosbags version; the sqlite files depend on the stdlib sqlite3 library version).

Usage (from anywhere; paths default relative to the repository root):
    bash tools/setup_venv.sh rosbags
    python3 tools/toolbox.py make-bag-fixtures
It replaces the fixture files/directories it writes (and only those) under ``--out``.
"""

import argparse
import hashlib
import shutil
import sys
import tempfile
from io import StringIO
from pathlib import Path

import numpy as np
from mcap.reader import make_reader
from rosbags.highlevel import AnyReader
from rosbags.rosbag1 import Writer as Writer1
from rosbags.rosbag2 import StoragePlugin
from rosbags.rosbag2 import Writer as Writer2
from rosbags.rosbag2.enums import CompressionFormat, CompressionMode
from rosbags.typesys import Stores, get_typestore
from ruamel.yaml import YAML

TOOLS_DIR = Path(__file__).resolve().parent
REPO_ROOT = TOOLS_DIR.parent
DEFAULT_SRC = REPO_ROOT / "fixtures" / "icl_livingroom1.mcap"
DEFAULT_OUT = REPO_ROOT / "fixtures" / "bags"

CLOUD_TOPIC = "/camera/depth/points"
POSE_TOPIC = "/ground_truth/pose"
CLOUD_TYPE = "sensor_msgs/msg/PointCloud2"
POSE_TYPE = "geometry_msgs/msg/PoseStamped"
CALLERID = "/icl_player"
ROSBAG2_VERSION = 9

ROS1_COMPRESSIONS = (("none", None), ("bz2", Writer1.CompressionFormat.BZ2),
                     ("lz4", Writer1.CompressionFormat.LZ4))


def read_source(path, frames):
    """The first `frames` clouds and the poses with the same log times, in file order, as
    (topic, log_time, cdr_bytes) tuples; plus the list of cloud log times."""
    msgs = []
    with open(path, "rb") as f:
        reader = make_reader(f)
        for _schema, channel, message in reader.iter_messages(topics=[CLOUD_TOPIC, POSE_TOPIC],
                                                             log_time_order=True):
            msgs.append((channel.topic, message.log_time, message.publish_time, bytes(message.data)))
    clouds = [m for m in msgs if m[0] == CLOUD_TOPIC][:frames]
    if len(clouds) != frames:
        sys.exit(f"source has only {len(clouds)} clouds, need {frames}")
    stamps = [m[1] for m in clouds]
    out = []
    for topic, log_time, publish_time, data in msgs:
        if log_time not in stamps:
            continue
        if topic == CLOUD_TOPIC and (topic, log_time, publish_time, data) not in clouds:
            continue
        if log_time != publish_time:
            sys.exit(f"source message {topic}@{log_time} has publish_time {publish_time}")
        out.append((topic, log_time, data))
    poses = [m for m in out if m[0] == POSE_TOPIC]
    if [m[1] for m in poses] != stamps:
        sys.exit("source poses do not match the cloud stamps one to one")
    return out, stamps


def to_ros1(ts1, ts2, topic, cdr, seq):
    """ROS 1 serialisation of a CDR message (rebuilt as a noetic message, header seq = `seq`)."""
    if topic == CLOUD_TOPIC:
        m = ts2.deserialize_cdr(cdr, CLOUD_TYPE)
        T = ts1.types
        header = T["std_msgs/msg/Header"](
            seq=seq, stamp=T["builtin_interfaces/msg/Time"](sec=m.header.stamp.sec,
                                                            nanosec=m.header.stamp.nanosec),
            frame_id=m.header.frame_id)
        fields = [T["sensor_msgs/msg/PointField"](name=f.name, offset=f.offset,
                                                  datatype=f.datatype, count=f.count)
                  for f in m.fields]
        msg = T[CLOUD_TYPE](header=header, height=m.height, width=m.width, fields=fields,
                            is_bigendian=m.is_bigendian, point_step=m.point_step,
                            row_step=m.row_step, data=np.asarray(m.data, dtype=np.uint8),
                            is_dense=m.is_dense)
        return bytes(ts1.serialize_ros1(msg, CLOUD_TYPE)), m.data.tobytes()
    m = ts2.deserialize_cdr(cdr, POSE_TYPE)
    T = ts1.types
    header = T["std_msgs/msg/Header"](
        seq=seq, stamp=T["builtin_interfaces/msg/Time"](sec=m.header.stamp.sec,
                                                        nanosec=m.header.stamp.nanosec),
        frame_id=m.header.frame_id)
    p, q = m.pose.position, m.pose.orientation
    pose = T["geometry_msgs/msg/Pose"](
        position=T["geometry_msgs/msg/Point"](x=p.x, y=p.y, z=p.z),
        orientation=T["geometry_msgs/msg/Quaternion"](x=q.x, y=q.y, z=q.z, w=q.w))
    msg = T[POSE_TYPE](header=header, pose=pose)
    return bytes(ts1.serialize_ros1(msg, POSE_TYPE)), None


def write_ros1(path, compression, msgs, stamps, ts1, ts2, chunk_threshold):
    writer = Writer1(path)
    if compression is not None:
        writer.set_compression(compression)
    writer.chunk_threshold = chunk_threshold
    with writer:
        conns = {
            CLOUD_TOPIC: writer.add_connection(CLOUD_TOPIC, CLOUD_TYPE, typestore=ts1,
                                               callerid=CALLERID, latching=0),
            POSE_TOPIC: writer.add_connection(POSE_TOPIC, POSE_TYPE, typestore=ts1, latching=0),
        }
        for topic, log_time, cdr in msgs:
            data, _ = to_ros1(ts1, ts2, topic, cdr, stamps.index(log_time))
            writer.write(conns[topic], log_time, data)
    return len([c for c in writer.chunks if c.pos != -1])


def write_ros2(path, storage, msgs, ts2, compression=None):
    writer = Writer2(path, version=ROSBAG2_VERSION, storage_plugin=storage)
    if compression is not None:
        writer.set_compression(compression, CompressionFormat.ZSTD)
    with writer:
        conns = {CLOUD_TOPIC: writer.add_connection(CLOUD_TOPIC, CLOUD_TYPE, typestore=ts2),
                 POSE_TOPIC: writer.add_connection(POSE_TOPIC, POSE_TYPE, typestore=ts2)}
        for topic, log_time, cdr in msgs:
            writer.write(conns[topic], log_time, cdr)


def yaml_dumper():
    """The ruamel.yaml settings rosbags' rosbag2 Writer uses for metadata.yaml."""
    yaml = YAML(typ="safe")
    yaml.default_flow_style = False
    return yaml


def write_split(path, msgs, stamps, ts2, tmp):
    """One sqlite3 rosbag2 bag in two files: the first half of the frames, then the rest (frames
    0-1, then 2-3 with 4 frames; see the module docstring)."""
    half = stamps[len(stamps) // 2]
    parts = [[m for m in msgs if m[1] < half], [m for m in msgs if m[1] >= half]]
    infos = []
    path.mkdir()
    for i, part in enumerate(parts):
        name = f"{path.name}_{i}"
        write_ros2(tmp / name, StoragePlugin.SQLITE3, part, ts2)
        infos.append(YAML(typ="safe").load((tmp / name / "metadata.yaml").read_text())
                     ["rosbag2_bagfile_information"])
        shutil.move(str(tmp / name / f"{name}.db3"), str(path / f"{name}.db3"))
    first, second = infos
    start = min(x["starting_time"]["nanoseconds_since_epoch"] for x in infos)
    end = max(x["starting_time"]["nanoseconds_since_epoch"] + x["duration"]["nanoseconds"]
              for x in infos)
    info = dict(first)  # same keys and key order as rosbags writes
    info["relative_file_paths"] = first["relative_file_paths"] + second["relative_file_paths"]
    info["duration"] = {"nanoseconds": end - start}
    info["starting_time"] = {"nanoseconds_since_epoch": start}
    info["message_count"] = first["message_count"] + second["message_count"]
    topics = []
    for a, b in zip(first["topics_with_message_count"], second["topics_with_message_count"]):
        if a["topic_metadata"] != b["topic_metadata"]:
            sys.exit("split halves disagree on topic metadata")
        topics.append({"topic_metadata": a["topic_metadata"],
                       "message_count": a["message_count"] + b["message_count"]})
    info["topics_with_message_count"] = topics
    info["files"] = first["files"] + second["files"]
    stream = StringIO()
    yaml_dumper().dump({"rosbag2_bagfile_information": info}, stream)
    (path / "metadata.yaml").write_text(stream.getvalue(), "utf8")


def verify(path, msgs, stamps, ts1, ts2, ros1):
    """Read a written bag back with AnyReader and compare it with the source messages."""
    want = {CLOUD_TOPIC: [], POSE_TOPIC: []}
    for topic, log_time, cdr in msgs:
        want[topic].append((log_time, cdr))
    got = {CLOUD_TOPIC: [], POSE_TOPIC: []}
    with AnyReader([path]) as reader:
        counts = {c.topic: c.msgcount for c in reader.connections}
        for conn, t, raw in reader.messages():
            got[conn.topic].append((t, bytes(raw)))
            reader.deserialize(raw, conn.msgtype)  # must decode with the bag's own definitions
    for topic in want:
        if [t for t, _ in got[topic]] != [t for t, _ in want[topic]]:
            sys.exit(f"{path}: {topic}: times differ")
        if counts.get(topic) != len(want[topic]):
            sys.exit(f"{path}: {topic}: connection msgcount {counts.get(topic)} != {len(want[topic])}")
        for (t, raw), (_, cdr) in zip(got[topic], want[topic]):
            if not ros1:
                if raw != cdr:
                    sys.exit(f"{path}: {topic}@{t}: CDR bytes differ")
                continue
            expect, points = to_ros1(ts1, ts2, topic, cdr, stamps.index(t))
            if raw != expect:
                sys.exit(f"{path}: {topic}@{t}: ROS 1 bytes differ from the conversion")
            m = ts1.deserialize_ros1(raw, CLOUD_TYPE if topic == CLOUD_TOPIC else POSE_TYPE)
            if m.header.seq != stamps.index(t) or \
                    m.header.stamp.sec * 10**9 + m.header.stamp.nanosec != t:
                sys.exit(f"{path}: {topic}@{t}: header seq/stamp wrong")
            if topic == CLOUD_TOPIC and m.data.tobytes() != points:
                sys.exit(f"{path}: {topic}@{t}: point data bytes differ from the source")
            if topic == CLOUD_TOPIC and raw[-1 - len(points):-1] != points:
                sys.exit(f"{path}: {topic}@{t}: point data not verbatim in the ROS 1 bytes")
    return {k: len(v) for k, v in got.items()}


def digest(path):
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--src", type=Path, default=DEFAULT_SRC, help="source MCAP [%(default)s]")
    ap.add_argument("--out", type=Path, default=DEFAULT_OUT, help="output directory [%(default)s]")
    ap.add_argument("--frames", type=int, default=4, help="clouds to take [%(default)s]")
    ap.add_argument("--cloud-topic", default=CLOUD_TOPIC,
                    help="cloud topic of the source, kept in the bags [%(default)s]; with --prefix, "
                         "for benchmark bags of other logs (e.g. /os1_cloud_node/points of "
                         "tools/make_kaist03_mcap.py's log)")
    ap.add_argument("--prefix", default=None,
                    help="name prefix of the written bags [icl{frames}]")
    ap.add_argument("--chunk-threshold", type=int, default=100_000,
                    help="ROS 1 chunk threshold, uncompressed bytes [%(default)s]")
    args = ap.parse_args()
    globals()["CLOUD_TOPIC"] = args.cloud_topic
    if args.frames < 2:
        sys.exit("--frames must be at least 2 (the split bag has two halves)")
    prefix = args.prefix or f"icl{args.frames}"
    ros1 = [(f"{prefix}_{kind}.bag", compression) for kind, compression in ROS1_COMPRESSIONS]
    ros2 = ((f"{prefix}_mcap", StoragePlugin.MCAP, None),
            (f"{prefix}_db3", StoragePlugin.SQLITE3, None))
    file_mode, message_mode = CompressionMode.FILE, CompressionMode.MESSAGE
    ros2 += tuple((f"{prefix}_{kind}_zstd_{mode.name.lower()}", storage, mode)
                  for kind, storage in (("mcap", StoragePlugin.MCAP), ("db3", StoragePlugin.SQLITE3))
                  for mode in (file_mode, message_mode))
    split = f"{prefix}_split"

    ts1 = get_typestore(Stores.ROS1_NOETIC)
    ts2 = get_typestore(Stores.ROS2_JAZZY)
    msgs, stamps = read_source(args.src, args.frames)
    args.out.mkdir(parents=True, exist_ok=True)
    for name in [n for n, _ in ros1] + [n for n, _, _ in ros2] + [split]:
        target = args.out / name
        if target.is_dir():
            shutil.rmtree(target)
        elif target.exists():
            target.unlink()

    for name, compression in ros1:
        chunks = write_ros1(args.out / name, compression, msgs, stamps, ts1, ts2,
                            args.chunk_threshold)
        if chunks < 3:
            sys.exit(f"{name}: only {chunks} chunks; lower --chunk-threshold")
        print(f"{name}: {chunks} chunks")
    for name, storage, compression in ros2:
        write_ros2(args.out / name, storage, msgs, ts2, compression)
    with tempfile.TemporaryDirectory() as tmp:
        write_split(args.out / split, msgs, stamps, ts2, Path(tmp))

    for name, _ in ros1:
        print(f"{name}: read back {verify(args.out / name, msgs, stamps, ts1, ts2, True)}")
    for name in [n for n, _, _ in ros2] + [split]:
        print(f"{name}/: read back {verify(args.out / name, msgs, stamps, ts1, ts2, False)}")

    total = 0
    for p in sorted(args.out.rglob("*")):
        if p.is_file() and p.name != "README.md":
            total += p.stat().st_size
            print(f"{p.stat().st_size:>9}  {digest(p)}  {p.relative_to(args.out)}")
    print(f"{total:>9}  total (without README.md)")


if __name__ == "__main__":
    main()
