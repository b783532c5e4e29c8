#!/usr/bin/env python3
"""Build logs that revisit places, from real frames with a known reference, for loop-closure work
(issue "Globally consistent trajectories"): ROS 2 MCAPs laid out exactly like the existing builders'
(tools/make_fixture_mcap.py for ICL-NUIM micro211, tools/make_kaist03_mcap.py for MulRan KAIST03):
the clouds and ``/ground_truth/pose`` messages come from those modules' own functions.

Kinds (``--kind``):

* ``out-and-back``: the source frames F = [f0, f1, ..., f(n-1)] (micro211: ``--first..--last`` step
  ``--frame-stride``) are played out on the even ones f0, f2, f4, ... and back on the odd ones in
  reverse ..., f5, f3, f1. The return passes the same places as the way out, with *different*
  scans (never the same frame twice), so a loop detector has real revisits and no trivial
  self-matches.
* ``gap``: the out-and-back with the messages ``--gap-start .. --gap-start + --gap-len - 1``
  (indices in the out-and-back sequence; default: ``--gap-len`` 2 from a quarter of the log, i.e.
  midway along the way out) dropped, stamps of the others unchanged, so odometry must bridge a time
  gap and a jump in space (2 dropped messages = 3 x 2 source frames between the kept neighbours;
  not at the turn, where the frames on both sides of a gap are source neighbours: a time gap with
  no jump in space).
* ``--repeat N`` (either kind): the out-and-back played N times in a row, stamps continuing, e.g.
  ``--repeat 10`` for a 10x longer log (memory-bound measurements). With ``gap`` the gap is cut
  from the whole repeated sequence.

Stamps: message i is stamped ``--start-sec`` + i * period (log_time = publish_time = header stamp,
strictly increasing; the gap keeps the dropped stamps unused). The period is the source's frame
period between kept frames: micro211 ``--frame-stride`` / 30 s (what the fixture builder gives),
KAIST03 the median interval of its times.txt (the keyframes are irregular, 0.2-6 s apart); override
with ``--period-ms``. The reference pose of each message is that frame's own reference, relative to
the log's first frame (first_from_sensor = T_f0^-1 T_k, identity on the first message), as the
builders write it.

A metadata record ``loop_log`` lists the source frame of every message, the kind and the
licence. After writing, the file is read back with the official ``mcap`` reader (+ mcap_ros2
decoder) and checked: message counts per topic, header stamp = log_time, stamps strictly
increasing, one reference pose per cloud at the same stamp, cloud sizes and poses as written.

MulRan is CC BY-NC-SA 4.0 (benchmarks only): write the logs outside the repository, e.g. /tmp.
ICL-NUIM is CC BY 3.0.

Usage:
    bash tools/setup_venv.sh mcap
    python3 tools/toolbox.py make-loop-logs --source micro211 --kind out-and-back \\
        --frame-stride 4 --out /tmp/loop_micro211_s4.mcap
    python3 tools/toolbox.py make-loop-logs --source kaist03 --kind out-and-back \\
        --out /tmp/loop_kaist03.mcap
    python3 tools/toolbox.py make-loop-logs --source kaist03 --kind gap --gap-start 4 \\
        --gap-len 2 --out /tmp/loop_kaist03_gap.mcap
    python3 tools/toolbox.py make-loop-logs --source kaist03 --kind out-and-back \\
        --repeat 10 --out /tmp/loop_kaist03_x10.mcap
    python3 tools/toolbox.py make-loop-logs --source kaist03 --kind out-and-back \\
        --cone 70 --out /tmp/loop_kaist03_cone70.mcap   # a Livox-like 70 deg field of view
    python3 tools/toolbox.py make-loop-logs --source kaist03 --kind out-and-back \\
        --degenerate 5,14 --out /tmp/loop_kaist03_degenerate.mcap   # two frames of road alone
    python3 tools/toolbox.py make-loop-logs --source kaist03 --kind out-and-back \
        --cone 25 --out /tmp/loop_kaist03_cone25.mcap   # a narrow view whose features repeat
    python3 tools/toolbox.py make-loop-logs --source kaist03 --kind gap --cone 40 \
        --gap-len 3 --out /tmp/loop_kaist03_cone40_gap3.mcap   # ... and a jump of 9 m
    python3 tools/toolbox.py make-loop-logs --source kaist03 --kind gap --cone 25 \
        --out /tmp/loop_kaist03_cone25_gap.mcap   # the narrowest view, and a jump of 7 m
    python3 tools/toolbox.py make-loop-logs --source kaist03 --kind out-and-back \
        --ring-stride 4 --out /tmp/loop_kaist03_r16.mcap   # 16 of the 64 beams: VLP-16-like
    python3 tools/toolbox.py make-loop-logs --all --out-dir /tmp   # the set above + micro211 gap/x10
"""

import argparse
import json
import math
import os
import statistics
import struct
import sys

from mcap.reader import make_reader
from mcap.writer import CompressionType
from mcap_ros2.decoder import DecoderFactory
from mcap_ros2.writer import Writer as Ros2Writer

import make_fixture_mcap as fx  # noqa: E402  (schemas, micro211 clouds, pose messages)
import make_kaist03_mcap as kaist  # noqa: E402  (KAIST03 scans and cloud messages)

NS_PER_S = 1_000_000_000


def out_and_back(frames):
    """Even entries of `frames` forward, then the odd ones in reverse."""
    return frames[0::2] + frames[1::2][::-1]


def sequence(frames, kind, repeat, gap_start, gap_len):
    """[(message index, source frame)] of the log: the out-and-back, `repeat` times, with the gap
    cut out for kind 'gap'. The message index fixes the stamp (so the gap leaves a time gap)."""
    seq = list(enumerate(out_and_back(frames) * repeat))
    if kind == "gap":
        if gap_start is None:
            gap_start = len(seq) // 4
        if not (0 < gap_start and gap_start + gap_len < len(seq) and gap_len > 0):
            raise SystemExit(f"gap {gap_start}+{gap_len} must lie inside the {len(seq)} messages, not at an end")
        seq = seq[:gap_start] + seq[gap_start + gap_len:]
    return seq


class Micro211:
    """ICL-NUIM livingroom1 micro211 frames, clouds as tools/make_fixture_mcap.py makes them."""

    licence = "CC BY 3.0 (ICL-NUIM / Redwood livingroom1; Choi, Zhou & Koltun CVPR 2015; Handa et al. ICRA 2014)"
    cloud_topic = fx.CLOUD_TOPIC

    def __init__(self, args):
        self.data = args.data or fx.DEFAULT_DATA
        self.pixel_stride = args.pixel_stride
        self.poses = fx.read_redwood_log(os.path.join(self.data, "trajectory_o3d_estimated.log"))
        last = min(args.last, max(self.poses))
        self.frames = list(range(args.first, last + 1, args.frame_stride))
        self.period_ns = round(args.frame_stride * NS_PER_S / fx.SOURCE_RATE_HZ)
        self.describe = f"micro211 frames {self.frames[0]}..{self.frames[-1]} step {args.frame_stride}, pixel stride {self.pixel_stride}"
        self._cache = {}

    def cloud(self, k, t_ns):
        if k not in self._cache:
            self._cache[k] = fx.frame_points(self.data, k, self.pixel_stride)
        return fx.cloud_message(t_ns, self._cache[k])

    def pose(self, k):
        return self.poses[k]


class Kaist03:
    """MulRan KAIST03 keyframes, clouds as tools/make_kaist03_mcap.py makes them."""

    licence = "CC BY-NC-SA 4.0 (MulRan KAIST03, Kim et al. ICRA 2020): benchmarks only, never fixtures"
    cloud_topic = kaist.CLOUD_TOPIC

    def __init__(self, args):
        self.data = args.data or kaist.DEFAULT_DATA
        self.ouster_time = args.ouster_time
        self.cone = (args.cone, args.cone_azimuth) if args.cone else None
        self.ring_stride = args.ring_stride
        poses = kaist.read_kitti_poses(os.path.join(self.data, "poses_kitti.txt"))
        self.poses = dict(enumerate(poses))
        self.frames = kaist.parse_frames(args.frames, len(poses))
        times = kaist.read_times(self.data)
        self.period_ns = round(statistics.median(b - a for a, b in zip(times, times[1:])) * NS_PER_S)
        self.describe = f"KAIST03 keyframes {args.frames or 'all'} ({len(self.frames)})"
        if self.cone:
            self.describe += f", cut to a {args.cone:g} deg cone about azimuth {args.cone_azimuth:g} deg"
        if self.ring_stride > 1:
            self.describe += f", every {self.ring_stride}th of the 64 beams"
        self._cache = {}

    def cloud(self, k, t_ns):
        if k not in self._cache:
            n, data = kaist.read_pcd_xyzi(kaist.scan_path(self.data, k))
            if self.cone:
                n, data = cut_to_cone(n, data, *self.cone)
            if self.ring_stride > 1:
                n, data = keep_rings(n, data, self.ring_stride)
            self._cache[k] = (n, data)
        n, data = self._cache[k]
        return kaist.cloud_message(t_ns, n, data, self.ouster_time)

    def pose(self, k):
        return self.poses[k]


def ground_only(cloud, ground_z):
    """The cloud message with only its points below `ground_z` metres (KAIST03's x, y, z,
    intensity float32 layout): the road around the sensor and little else, a frame whose
    registration leaves x, y and yaw nearly free (a degenerate frame, issue "Loops that hold")."""
    step = cloud["point_step"]
    data = cloud["data"]
    kept = bytearray()
    for i in range(0, len(data), step):
        if struct.unpack_from("<f", data, i + 8)[0] < ground_z:
            kept += data[i:i + step]
    n = len(kept) // step
    return {**cloud, "width": n, "row_step": step * n, "data": bytes(kept)}


def cut_to_cone(n, data, width_deg, azimuth_deg):
    """The points (x, y, z, intensity float32, 16 bytes each) whose azimuth atan2(y, x) lies within
    width/2 of `azimuth_deg`: a narrow field of view like a Livox Avia's (70 deg), from a spinning
    LiDAR's scan. KAIST03's keyframes have no points near +x (the vehicle), so 180 deg is the
    default."""
    half = math.radians(width_deg) / 2
    centre = math.radians(azimuth_deg)

    def inside(x, y, _z):
        d = math.atan2(y, x) - centre
        d = (d + math.pi) % (2 * math.pi) - math.pi
        return abs(d) <= half

    return keep_points(n, data, inside)


def keep_points(n, data, keep):
    """The points (x, y, z, intensity float32, 16 bytes each) for which keep(x, y, z) holds, in
    order: (count, bytes)."""
    kept = bytearray()
    for (x, y, z, _i), raw in zip(struct.iter_unpack("<4f", data), (data[i:i + 16] for i in range(0, 16 * n, 16))):
        if keep(x, y, z):
            kept += raw
    return len(kept) // 16, bytes(kept)


# The OS1-64's beams in KAIST03's keyframes: elevations from -15.7 to 17.8 deg, 64 of them about
# 0.532 deg apart (peaks of the elevation histogram of scan 0, 0.05 deg bins).
OS1_LOWEST_BEAM_DEG = -15.7
OS1_BEAM_SPACING_DEG = (17.8 - -15.7) / 63


def keep_rings(n, data, stride):
    """The points (x, y, z, intensity float32, 16 bytes each) of every `stride`-th beam of the
    OS1-64, the beam found by elevation atan2(z, hypot(x, y)): with stride 4, 16 beams 2.1 deg
    apart, the vertical density of a Velodyne VLP-16 (2 deg), from the same real scans."""

    def on_a_kept_beam(x, y, z):
        elevation = math.degrees(math.atan2(z, math.hypot(x, y)))
        return round((elevation - OS1_LOWEST_BEAM_DEG) / OS1_BEAM_SPACING_DEG) % stride == 0

    return keep_points(n, data, on_a_kept_beam)


SOURCES = {"micro211": Micro211, "kaist03": Kaist03}


def build(args, out):
    src = SOURCES[args.source](args)
    seq = sequence(src.frames, args.kind, args.repeat, args.gap_start, args.gap_len)
    period = round(args.period_ms * 1e6) if args.period_ms else src.period_ns
    start = args.start_sec * NS_PER_S
    first_inv = fx.rigid_inverse(src.pose(seq[0][1]))
    expected = []  # (stamp, cloud width, first_from_sensor)
    degenerate = {int(i) for i in args.degenerate.split(",") if i.strip()} if args.degenerate else set()
    if degenerate and args.source != "kaist03":
        raise SystemExit("--degenerate needs --source kaist03 (its clouds are x, y, z, intensity)")
    if any(not 0 <= i < len(seq) for i in degenerate):
        raise SystemExit(f"--degenerate: message indices must lie in 0..{len(seq) - 1}")
    tmp = out + ".tmp"
    os.makedirs(os.path.dirname(os.path.abspath(out)), exist_ok=True)
    with open(tmp, "wb") as f:
        writer = Ros2Writer(f, compression=CompressionType.ZSTD)
        cloud_schema = writer.register_msgdef("sensor_msgs/msg/PointCloud2", fx.POINT_CLOUD2_SCHEMA)
        pose_schema = writer.register_msgdef("geometry_msgs/msg/PoseStamped", fx.POSE_STAMPED_SCHEMA)
        for seq_no, (i, k) in enumerate(seq):
            t_ns = start + i * period
            cloud = src.cloud(k, t_ns)
            if seq_no in degenerate:
                cloud = ground_only(cloud, args.ground_z)
            ref = fx.mat_mul(first_inv, src.pose(k))
            writer.write_message(src.cloud_topic, cloud_schema, cloud, log_time=t_ns, publish_time=t_ns, sequence=seq_no)
            writer.write_message(fx.POSE_TOPIC, pose_schema, fx.pose_message(t_ns, ref),
                                 log_time=t_ns, publish_time=t_ns, sequence=seq_no)
            expected.append((t_ns, cloud["width"], ref))
        writer.add_metadata("loop_log", {
            "kind": args.kind,
            "repeat": str(args.repeat),
            "source": src.describe,
            "source_frames": json.dumps([k for _i, k in seq]),
            "period_ns": str(period),
            "gap": json.dumps(gap_description(args, seq)),
            "degenerate": json.dumps({"messages": sorted(degenerate), "ground_z_m": args.ground_z} if degenerate else None),
            "licence": src.licence,
            "pose_source": "the frame's own reference (micro211: Open3D's estimate; KAIST03: SC-A-LOAM's), not ground truth",
            "poses": "first_from_sensor_k = T_first^-1 * T_k, frame world",
        })
        writer.finish()
    try:
        verify(tmp, src.cloud_topic, expected)
    except BaseException:
        os.remove(tmp)
        raise
    os.replace(tmp, out)
    frames = [k for _i, k in seq]
    print(f"{out}: {args.kind} x{args.repeat} of {src.describe}: {len(seq)} clouds + {len(seq)} poses, "
          f"period {period / 1e6:.3f} ms, {os.path.getsize(out)} bytes; source frames "
          f"{frames if len(frames) <= 60 else str(frames[:30])[:-1] + ', ...]'}")
    return out


def gap_description(args, seq):
    if args.kind != "gap":
        return None
    idx = [i for i, _k in seq]
    missing = sorted(set(range(idx[-1] + 1)) - set(idx))
    return {"dropped_message_indices": missing}


def verify(path, cloud_topic, expected):
    """Re-read with the official mcap reader: counts, stamps increasing, clouds/poses as written."""
    clouds, poses = [], []
    with open(path, "rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        summary = reader.get_summary()
        for _schema, channel, message, decoded in reader.iter_decoded_messages(log_time_order=False):
            stamp = decoded.header.stamp.sec * NS_PER_S + decoded.header.stamp.nanosec
            if stamp != message.log_time or message.log_time != message.publish_time:
                raise AssertionError(f"{channel.topic}: header stamp {stamp}, log_time {message.log_time}, "
                                     f"publish_time {message.publish_time} differ")
            if channel.topic == cloud_topic:
                clouds.append((stamp, decoded.width))
            elif channel.topic == fx.POSE_TOPIC:
                poses.append((stamp, decoded.pose))
            else:
                raise AssertionError(f"unexpected topic {channel.topic}")
        meta = {m.name: m.metadata for m in reader.iter_metadata()}
    n = len(expected)
    if len(clouds) != n or len(poses) != n or summary.statistics.message_count != 2 * n:
        raise AssertionError(f"{len(clouds)} clouds, {len(poses)} poses, "
                             f"{summary.statistics.message_count} messages; expected {n} + {n}")
    for topic, msgs in ((cloud_topic, clouds), (fx.POSE_TOPIC, poses)):
        if any(b[0] <= a[0] for a, b in zip(msgs, msgs[1:])):
            raise AssertionError(f"{topic}: stamps not strictly increasing")
    worst = 0.0
    for (t, width, ref), (tc, wc), (tp, pose) in zip(expected, clouds, poses):
        if (tc, tp, wc) != (t, t, width):
            raise AssertionError(f"message at {t}: cloud ({tc}, {wc} points), pose {tp}; expected {width} points")
        p = pose.position
        r = fx.rotation_from_quat((pose.orientation.x, pose.orientation.y, pose.orientation.z, pose.orientation.w))
        worst = max(worst, math.dist((p.x, p.y, p.z), [ref[i][3] for i in range(3)]),
                    max(abs(r[i][j] - ref[i][j]) for i in range(3) for j in range(3)))
    if worst > 1e-6:
        raise AssertionError(f"reference poses differ from the written ones by {worst:.2e}")
    if json.loads(meta["loop_log"]["source_frames"]).__len__() != n:
        raise AssertionError("metadata loop_log: wrong frame count")
    print(f"verified {path} with the mcap reader: {n} clouds + {n} poses, stamps strictly increasing "
          f"({clouds[0][0]} .. {clouds[-1][0]} ns), pose round trip {worst:.1e}", file=sys.stderr)


# `--all`: the set of logs the loop-closure work uses (name, source, kind, options).
ALL = [
    ("loop_micro211_s4", "micro211", "out-and-back", {"frame_stride": 4}),
    ("loop_micro211_s4_gap", "micro211", "gap", {"frame_stride": 4}),
    ("loop_micro211_s4_x10", "micro211", "out-and-back", {"frame_stride": 4, "repeat": 10}),
    ("loop_kaist03", "kaist03", "out-and-back", {}),
    ("loop_kaist03_gap", "kaist03", "gap", {}),
    ("loop_kaist03_x10", "kaist03", "out-and-back", {"repeat": 10}),
    ("loop_kaist03_cone70", "kaist03", "out-and-back", {"cone": 70.0}),
    ("loop_kaist03_cone25", "kaist03", "out-and-back", {"cone": 25.0}),
    ("loop_kaist03_cone40_gap3", "kaist03", "gap", {"cone": 40.0, "gap_len": 3}),
    ("loop_kaist03_cone25_gap", "kaist03", "gap", {"cone": 25.0}),
    ("loop_kaist03_r16", "kaist03", "out-and-back", {"ring_stride": 4}),
]


def main(argv):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--source", choices=sorted(SOURCES), help="micro211 (ICL-NUIM) or kaist03 (MulRan)")
    ap.add_argument("--kind", choices=["out-and-back", "gap"], default="out-and-back")
    ap.add_argument("--out", help="output MCAP (outside the repository: MulRan is CC BY-NC-SA)")
    ap.add_argument("--all", action="store_true", help="write the standard set (see ALL) into --out-dir")
    ap.add_argument("--out-dir", default="/tmp", help="folder for --all (default /tmp)")
    ap.add_argument("--data", help="source folder (default: the builder's default under ../shared/data)")
    ap.add_argument("--repeat", type=int, default=1, help="play the out-and-back N times (default 1)")
    ap.add_argument("--gap-start", type=int, help="kind gap: first dropped message (default: a quarter of the log)")
    ap.add_argument("--gap-len", type=int, default=2, help="kind gap: messages dropped (default 2)")
    ap.add_argument("--period-ms", type=float, help="stamp step [ms] (default: the source's frame period)")
    ap.add_argument("--start-sec", type=int, default=1_700_000_000, help="stamp of the first message [s]")
    # micro211 options, as tools/make_fixture_mcap.py names them
    ap.add_argument("--frame-stride", "--stride", type=int, default=4, help="micro211: keep every n-th frame (default 4)")
    ap.add_argument("--pixel-stride", type=int, default=8, help="micro211: every n-th pixel in u and v (default 8)")
    ap.add_argument("--first", type=int, default=0, help="micro211: first frame (default 0)")
    ap.add_argument("--last", type=int, default=210, help="micro211: last frame, inclusive (default 210)")
    # KAIST03 options, as tools/make_kaist03_mcap.py names them
    ap.add_argument("--frames", default="", help="kaist03: scans to use, e.g. 0-3,8-10 (default: all 21)")
    ap.add_argument("--cone", type=float, help="kaist03: keep only a cone this wide [deg] (e.g. 70, Livox-like)")
    ap.add_argument("--cone-azimuth", type=float, default=180.0, help="kaist03: the cone's centre azimuth [deg] (default 180)")
    ap.add_argument("--ring-stride", type=int, default=1, help="kaist03: keep every n-th of the 64 beams (4: 16 beams 2.1 deg apart, VLP-16-like)")
    ap.add_argument("--degenerate", help="kaist03: messages (indices in the log, e.g. 5,12) cut to their ground points")
    ap.add_argument("--ground-z", type=float, default=-1.5, help="--degenerate: keep points below this z [m] (default -1.5: KAIST03's road lies at about -1.6 to -1.9 m)")
    ap.add_argument("--ouster-time", action="store_true", help="kaist03: add the inferred per-point time t")
    args = ap.parse_args(argv)
    if args.repeat < 1 or args.frame_stride < 1 or args.pixel_stride < 1 or args.ring_stride < 1:
        ap.error("--repeat and the strides must be >= 1")
    if args.all:
        for name, source, kind, opts in ALL:
            one = argparse.Namespace(**{**vars(args), "source": source, "kind": kind, "repeat": 1,
                                        "gap_start": None, **opts})
            build(one, os.path.join(args.out_dir, name + ".mcap"))
        return
    if not args.source or not args.out:
        ap.error("--source and --out are required (or --all)")
    build(args, args.out)


if __name__ == "__main__":
    main(sys.argv[1:])
