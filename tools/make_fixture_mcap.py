#!/usr/bin/env python3
"""Build the embedded default fixture fixtures/icl_livingroom1.mcap from the ICL-NUIM livingroom1
"micro211" frames (clean depth PNGs 0-210 and Open3D's estimated trajectory).

The file looks like a small rosbag2 recording (profile "ros2", zstd-compressed chunks):

* ``/camera/depth/points`` -- ``sensor_msgs/msg/PointCloud2`` (cdr; schema encoding ``ros2msg`` with the
  full concatenated dependency text, as rosbag2 writes it). One unorganised cloud (height 1,
  is_dense true) per kept frame with fields x, y, z FLOAT32 (point_step 12), frame_id
  ``camera_depth_optical_frame`` (x right, y down, z forward, metres). Every ``--pixel-stride``-th
  pixel in u and v with nonzero depth is back-projected with fx = fy = 525, cx = 319.5, cy = 239.5,
  depth scale 1000 (the decoder and back-projection are imported from tools/make_icl_fixture.py).
* ``/ground_truth/pose`` -- ``geometry_msgs/msg/PoseStamped`` (cdr, full dependency text), frame_id
  ``world``, one per cloud with the same stamp, holding ``first_from_camera_k = T_0^-1 * T_k`` where
  ``T_k`` is the camera-to-world pose of the kept frame k in trajectory_o3d_estimated.log (Redwood
  format). The first pose is the identity, so it compares directly with a trajectory whose world
  is the first cloud's sensor frame. These poses are Open3D's reconstruction estimate, NOT ground
  truth; a metadata record ``fixture`` says so.

Stamps follow the source frame numbers at the sequence's 30 Hz: frame k is stamped
``--start-sec`` + k/30 s (rounded to the nanosecond), so with a frame stride of 3 the messages are
10 Hz apart. log_time = publish_time = stamp. Nothing depends on the wall clock and the writer is
pinned (the `mcap` group of tools/pyproject.toml), so every run produces the same bytes.

Messages are encoded by mcap_ros2's schema-driven CDR writer (an implementation independent of
mireg's hand-written decoder, which is the point of the fixture). After writing, the file is read
back with the mcap reader + mcap_ros2 decoder and checked: message counts, schema texts, points
equal to the float32 inputs bit for bit, poses equal to the computed ones.

Usage (any working directory; paths default relative to the repository root):
    bash tools/setup_venv.sh mcap
    python3 tools/toolbox.py make-fixture-mcap
    python3 tools/toolbox.py make-fixture-mcap --frame-stride 3 --pixel-stride 8 \\
        --data ../shared/data/icl_nuim_livingroom1/micro211 --out fixtures/icl_livingroom1.mcap
"""

import argparse
import math
import os
import struct
import sys

from mcap.reader import make_reader
from mcap.writer import CompressionType
from mcap_ros2.decoder import DecoderFactory
from mcap_ros2.writer import Writer as Ros2Writer

TOOLS_DIR = os.path.dirname(os.path.abspath(__file__))
REPO_ROOT = os.path.dirname(TOOLS_DIR)
import make_icl_fixture as icl  # noqa: E402  (stdlib PNG decoder + back-projection, reused)

DEFAULT_DATA = os.path.join(REPO_ROOT, "..", "shared", "data", "icl_nuim_livingroom1", "micro211")
DEFAULT_OUT = os.path.join(REPO_ROOT, "fixtures", "icl_livingroom1.mcap")

CLOUD_TOPIC = "/camera/depth/points"
POSE_TOPIC = "/ground_truth/pose"
CLOUD_FRAME = "camera_depth_optical_frame"
WORLD_FRAME = "world"
SOURCE_RATE_HZ = 30
NS_PER_S = 1_000_000_000
FLOAT32 = 7  # sensor_msgs/PointField datatype constant

# --- ROS 2 message definitions (ros2msg) ------------------------------------------------------------
# Field declarations and constants of the ROS 2 interfaces (Humble and later); comments are ours and
# short. Dependencies are appended the way rosbag2 stores them: a line of 80 '=' and "MSG: pkg/Type".

MSG_TIME = """\
# Time since the epoch: seconds and nanoseconds in [0, 1e9).
int32 sec
uint32 nanosec
"""

MSG_HEADER = """\
# Timestamp and coordinate frame of stamped data.
builtin_interfaces/Time stamp

string frame_id
"""

MSG_POINT_FIELD = """\
# One named field of a PointCloud2 point: byte offset, datatype and element count.
int8 INT8    = 1
int8 UINT8   = 2
int8 INT16   = 3
int8 UINT16  = 4
int8 INT32   = 5
int8 UINT32  = 6
int8 FLOAT32 = 7
int8 FLOAT64 = 8

string name
uint32 offset
uint8  datatype
uint32 count
"""

MSG_POINT_CLOUD2 = """\
# A collection of N-dimensional points; the layout of a point is given by `fields`.
# Unorganised clouds have height 1.

std_msgs/Header header

uint32 height
uint32 width

PointField[] fields

bool    is_bigendian
uint32  point_step
uint32  row_step
uint8[] data

bool is_dense
"""

MSG_POINT = """\
# A position in free space.
float64 x
float64 y
float64 z
"""

MSG_QUATERNION = """\
# An orientation as a unit quaternion.
float64 x 0
float64 y 0
float64 z 0
float64 w 1
"""

MSG_POSE = """\
# A pose in free space: position and orientation.
Point position
Quaternion orientation
"""

MSG_POSE_STAMPED = """\
# A pose with a reference coordinate frame and timestamp.
std_msgs/Header header
Pose pose
"""

SEPARATOR = "=" * 80


def concat_msgdef(main_text, dependencies):
    """Concatenate a main .msg text with its dependencies [(\"pkg/Type\", text), ...] like rosbag2."""
    parts = [main_text]
    for name, text in dependencies:
        parts.append(f"\n{SEPARATOR}\nMSG: {name}\n{text}")
    return "".join(parts)


POINT_CLOUD2_SCHEMA = concat_msgdef(
    MSG_POINT_CLOUD2,
    [
        ("std_msgs/Header", MSG_HEADER),
        ("builtin_interfaces/Time", MSG_TIME),
        ("sensor_msgs/PointField", MSG_POINT_FIELD),
    ],
)

POSE_STAMPED_SCHEMA = concat_msgdef(
    MSG_POSE_STAMPED,
    [
        ("std_msgs/Header", MSG_HEADER),
        ("builtin_interfaces/Time", MSG_TIME),
        ("geometry_msgs/Pose", MSG_POSE),
        ("geometry_msgs/Point", MSG_POINT),
        ("geometry_msgs/Quaternion", MSG_QUATERNION),
    ],
)

# --- small 4x4 rigid-transform helpers (row-major lists, float64) ----------------------------------


def read_redwood_log(path):
    """Read a Redwood .log trajectory: per frame a header line and 4 rows. Returns {frame: 4x4}."""
    with open(path) as f:
        lines = [ln.split() for ln in f if ln.strip()]
    if len(lines) % 5:
        raise ValueError(f"{path}: {len(lines)} non-empty lines, not a multiple of 5")
    poses = {}
    for i in range(0, len(lines), 5):
        frame = int(lines[i][0])
        rows = [[float(x) for x in lines[i + r]] for r in range(1, 5)]
        if any(len(row) != 4 for row in rows):
            raise ValueError(f"{path}: frame {frame}: expected 4x4 matrix")
        poses[frame] = rows
    return poses


def mat_mul(a, b):
    return [[sum(a[i][k] * b[k][j] for k in range(4)) for j in range(4)] for i in range(4)]


def rigid_inverse(t):
    """Inverse of a rigid transform [R t; 0 1] as [R^T -R^T t; 0 1]."""
    r_t = [[t[j][i] for j in range(3)] for i in range(3)]
    trans = [-sum(r_t[i][k] * t[k][3] for k in range(3)) for i in range(3)]
    return [r_t[i] + [trans[i]] for i in range(3)] + [[0.0, 0.0, 0.0, 1.0]]


def quat_from_rotation(r):
    """Unit quaternion (x, y, z, w) with w >= 0 from a 3x3 rotation (Shepperd's method)."""
    trace = r[0][0] + r[1][1] + r[2][2]
    if trace > 0.0:
        s = 2.0 * math.sqrt(1.0 + trace)
        w, x, y, z = 0.25 * s, (r[2][1] - r[1][2]) / s, (r[0][2] - r[2][0]) / s, (r[1][0] - r[0][1]) / s
    elif r[0][0] > r[1][1] and r[0][0] > r[2][2]:
        s = 2.0 * math.sqrt(1.0 + r[0][0] - r[1][1] - r[2][2])
        w, x, y, z = (r[2][1] - r[1][2]) / s, 0.25 * s, (r[0][1] + r[1][0]) / s, (r[0][2] + r[2][0]) / s
    elif r[1][1] > r[2][2]:
        s = 2.0 * math.sqrt(1.0 + r[1][1] - r[0][0] - r[2][2])
        w, x, y, z = (r[0][2] - r[2][0]) / s, (r[0][1] + r[1][0]) / s, 0.25 * s, (r[1][2] + r[2][1]) / s
    else:
        s = 2.0 * math.sqrt(1.0 + r[2][2] - r[0][0] - r[1][1])
        w, x, y, z = (r[1][0] - r[0][1]) / s, (r[0][2] + r[2][0]) / s, (r[1][2] + r[2][1]) / s, 0.25 * s
    n = math.sqrt(w * w + x * x + y * y + z * z)
    if w < 0.0:
        n = -n
    return (x / n, y / n, z / n, w / n)


def rotation_from_quat(q):
    x, y, z, w = q
    return [
        [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
        [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
        [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
    ]


# --- message construction ---------------------------------------------------------------------------


def stamp_ns(start_sec, frame):
    """Stamp of source frame `frame` at 30 Hz after start_sec, rounded to the nanosecond."""
    return start_sec * NS_PER_S + (frame * NS_PER_S + SOURCE_RATE_HZ // 2) // SOURCE_RATE_HZ


def header(t_ns, frame_id):
    return {"stamp": {"sec": t_ns // NS_PER_S, "nanosec": t_ns % NS_PER_S}, "frame_id": frame_id}


def cloud_message(t_ns, points):
    data = b"".join(struct.pack("<3f", *p) for p in points)
    return {
        "header": header(t_ns, CLOUD_FRAME),
        "height": 1,
        "width": len(points),
        "fields": [
            {"name": name, "offset": 4 * i, "datatype": FLOAT32, "count": 1}
            for i, name in enumerate(("x", "y", "z"))
        ],
        "is_bigendian": False,
        "point_step": 12,
        "row_step": 12 * len(points),
        "data": data,
        "is_dense": True,
    }


def pose_message(t_ns, t):
    qx, qy, qz, qw = quat_from_rotation([row[:3] for row in t[:3]])
    return {
        "header": header(t_ns, WORLD_FRAME),
        "pose": {
            "position": {"x": t[0][3], "y": t[1][3], "z": t[2][3]},
            "orientation": {"x": qx, "y": qy, "z": qz, "w": qw},
        },
    }


def fixture_metadata(args, frames):
    """The `fixture` metadata record: provenance, licence and the (path-independent) command."""
    return {
        "source": (
            "Augmented ICL-NUIM / Redwood livingroom1, clean depth frames 0-210 and "
            "trajectory_o3d_estimated.log from the Open3D repository test data "
            "(examples/test_data/reconstruction_system/livingroom1_clean_micro at "
            "c759fe1332d8a7d06773d208e66176bc93335728^)"
        ),
        "licence": "CC BY 3.0 (https://creativecommons.org/licenses/by/3.0/)",
        "attribution": (
            "S. Choi, Q.-Y. Zhou, V. Koltun, 'Robust Reconstruction of Indoor Scenes', CVPR 2015; "
            "derived from ICL-NUIM: A. Handa, T. Whelan, J. McDonald, A. J. Davison, 'A Benchmark for "
            "RGB-D Visual Odometry, 3D Reconstruction and SLAM', ICRA 2014. Changes: depth images "
            "subsampled and back-projected to point clouds; poses re-expressed relative to the first "
            "kept frame."
        ),
        "pose_source": "reference estimate (Open3D reconstruction pipeline), not ground truth",
        "command": command_line(args),
        "frames": f"{frames[0]}..{frames[-1]} step {args.frame_stride} ({len(frames)} frames)",
        "pixel_stride": str(args.pixel_stride),
        "intrinsics": "fx=525 fy=525 cx=319.5 cy=239.5 depth_scale=1000 (640x480)",
        "stamps": f"{args.start_sec} s + source_frame/30 s; log_time = publish_time = header stamp",
        "poses": "first_from_camera_k = T_0^-1 * T_k (Redwood camera-to-world), frame world",
    }


def command_line(args):
    """The command that reproduces the file from the repository root (paths left at defaults)."""
    return (
        "bash tools/setup_venv.sh mcap && python3 tools/toolbox.py make-fixture-mcap "
        f"--frame-stride {args.frame_stride} --pixel-stride {args.pixel_stride} "
        f"--first {args.first} --last {args.last} --start-sec {args.start_sec}"
    )


def frame_points(data, k, pixel_stride):
    """Back-projected points [(x, y, z), ...] of depth frame k of the micro211 folder `data`
    (every `pixel_stride`-th pixel in u and v with nonzero depth); also used by
    tools/make_loop_logs.py, so its logs hold the same clouds as the fixture."""
    _w, _h, rows, _filters = icl.read_png_gray16(os.path.join(data, "depth", f"{k:05d}.png"))
    return icl.depth_to_points(rows, pixel_stride)


# --- write and verify --------------------------------------------------------------------------------


def build(args):
    """Decode the depth frames, write the MCAP to a temporary file, verify it, then rename."""
    poses = read_redwood_log(os.path.join(args.data, "trajectory_o3d_estimated.log"))
    frames = list(range(args.first, args.last + 1, args.frame_stride))
    missing = [k for k in frames if k not in poses]
    if missing:
        raise SystemExit(f"no pose for frames {missing}")
    first_inv = rigid_inverse(poses[frames[0]])

    expected = []  # (stamp, float32 point bytes, first_from_camera 4x4) per kept frame
    tmp = args.out + ".tmp"
    os.makedirs(os.path.dirname(os.path.abspath(args.out)), exist_ok=True)
    with open(tmp, "wb") as f:
        writer = Ros2Writer(f, chunk_size=args.chunk_size, compression=CompressionType.ZSTD)
        cloud_schema = writer.register_msgdef("sensor_msgs/msg/PointCloud2", POINT_CLOUD2_SCHEMA)
        pose_schema = writer.register_msgdef("geometry_msgs/msg/PoseStamped", POSE_STAMPED_SCHEMA)
        for seq, k in enumerate(frames):
            points = frame_points(args.data, k, args.pixel_stride)
            t_ns = stamp_ns(args.start_sec, k)
            first_from_cam = mat_mul(first_inv, poses[k])
            cloud = cloud_message(t_ns, points)
            writer.write_message(CLOUD_TOPIC, cloud_schema, cloud, log_time=t_ns, publish_time=t_ns, sequence=seq)
            writer.write_message(
                POSE_TOPIC, pose_schema, pose_message(t_ns, first_from_cam), log_time=t_ns, publish_time=t_ns, sequence=seq
            )
            expected.append((t_ns, cloud["data"], first_from_cam))
            if args.verbose:
                print(f"frame {k:3d}: {len(points)} points, t = {t_ns} ns", file=sys.stderr)
        writer.add_metadata("fixture", fixture_metadata(args, frames))
        writer.finish()
    try:
        verify(tmp, expected)
    except BaseException:
        os.remove(tmp)  # never leave a half-checked file behind
        raise
    os.replace(tmp, args.out)
    npts = [len(data) // 12 for _t, data, _p in expected]
    last = expected[-1][2]
    print(
        f"{args.out}: {os.path.getsize(args.out)} bytes, {len(frames)} frames "
        f"({frames[0]}..{frames[-1]} step {args.frame_stride}), pixel stride {args.pixel_stride}, "
        f"points per frame min {min(npts)} mean {sum(npts) / len(npts):.0f} max {max(npts)}, "
        f"last pose t = ({last[0][3]:.3f}, {last[1][3]:.3f}, {last[2][3]:.3f}) m"
    )


def verify(path, expected):
    """Re-read `path` and check counts, schemas, points (float32 bit-exact) and poses."""
    clouds, pose_msgs = [], []
    with open(path, "rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        summary = reader.get_summary()
        for schema, channel, message, decoded in reader.iter_decoded_messages(log_time_order=False):
            if message.log_time != message.publish_time:
                raise AssertionError(f"{channel.topic}: log_time != publish_time")
            stamp = decoded.header.stamp.sec * NS_PER_S + decoded.header.stamp.nanosec
            if stamp != message.log_time:
                raise AssertionError(f"{channel.topic}: header stamp {stamp} != log_time {message.log_time}")
            if channel.topic == CLOUD_TOPIC:
                if schema.data.decode() != POINT_CLOUD2_SCHEMA or channel.message_encoding != "cdr":
                    raise AssertionError("cloud schema/encoding mismatch")
                clouds.append((message.log_time, decoded))
            elif channel.topic == POSE_TOPIC:
                if schema.data.decode() != POSE_STAMPED_SCHEMA:
                    raise AssertionError("pose schema mismatch")
                pose_msgs.append((message.log_time, decoded))
            else:
                raise AssertionError(f"unexpected topic {channel.topic}")
        meta = {m.name: m.metadata for m in reader.iter_metadata()}
    if len(clouds) != len(expected) or len(pose_msgs) != len(expected):
        raise AssertionError(f"{len(clouds)} clouds, {len(pose_msgs)} poses, expected {len(expected)} each")
    if summary.statistics.message_count != 2 * len(expected):
        raise AssertionError("summary message count mismatch")
    if "not ground truth" not in meta.get("fixture", {}).get("pose_source", ""):
        raise AssertionError("metadata record 'fixture' missing or incomplete")
    worst_rot = worst_norm = 0.0
    for (t_ns, data, t_exp), (tc, cloud), (tp, pose) in zip(expected, clouds, pose_msgs):
        if tc != t_ns or tp != t_ns:
            raise AssertionError(f"stamp mismatch at {t_ns}")
        n = len(data) // 12
        if (cloud.height, cloud.width, cloud.point_step, cloud.row_step) != (1, n, 12, 12 * n):
            raise AssertionError(f"cloud layout mismatch at {t_ns}")
        if [(fd.name, fd.offset, fd.datatype, fd.count) for fd in cloud.fields] != [
            ("x", 0, FLOAT32, 1),
            ("y", 4, FLOAT32, 1),
            ("z", 8, FLOAT32, 1),
        ]:
            raise AssertionError("cloud fields mismatch")
        if cloud.is_bigendian or not cloud.is_dense or cloud.header.frame_id != CLOUD_FRAME:
            raise AssertionError("cloud flags/frame mismatch")
        # Decoded points, compared value by value to the float32-rounded inputs.
        got = struct.unpack(f"<{3 * n}f", bytes(cloud.data))
        want = struct.unpack(f"<{3 * n}f", data)
        if got != want:
            raise AssertionError(f"point data mismatch at {t_ns}")
        p, q = pose.pose.position, pose.pose.orientation
        if pose.header.frame_id != WORLD_FRAME:
            raise AssertionError("pose frame mismatch")
        if (p.x, p.y, p.z) != (t_exp[0][3], t_exp[1][3], t_exp[2][3]):
            raise AssertionError(f"pose translation mismatch at {t_ns}")
        r = rotation_from_quat((q.x, q.y, q.z, q.w))
        worst_rot = max(worst_rot, max(abs(r[i][j] - t_exp[i][j]) for i in range(3) for j in range(3)))
        worst_norm = max(worst_norm, abs(math.sqrt(q.x**2 + q.y**2 + q.z**2 + q.w**2) - 1.0))
    first = pose_msgs[0][1].pose
    if (first.position.x, first.position.y, first.position.z) != (0.0, 0.0, 0.0) or first.orientation.w != 1.0:
        raise AssertionError("first pose is not the identity")
    # The log's rotations carry 8 decimals, so quaternion -> matrix agrees to ~1e-8.
    if worst_rot > 1e-6 or worst_norm > 1e-12:
        raise AssertionError(f"pose round trip: rotation error {worst_rot:.2e}, |q| - 1 = {worst_norm:.2e}")
    print(
        f"verified {path}: {len(clouds)} clouds + {len(pose_msgs)} poses decode back; points bit-exact; "
        f"pose rotation round trip max |dR| {worst_rot:.1e}",
        file=sys.stderr,
    )


def main(argv):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--data", default=DEFAULT_DATA, help="micro211 folder (default: ../shared/data/.../micro211)")
    ap.add_argument("--out", default=DEFAULT_OUT, help="output MCAP (default: fixtures/icl_livingroom1.mcap)")
    ap.add_argument("--frame-stride", type=int, default=3, help="keep every n-th frame (default: 3)")
    ap.add_argument("--pixel-stride", type=int, default=8, help="keep every n-th pixel in u and v (default: 8)")
    ap.add_argument("--first", type=int, default=0, help="first frame (default: 0)")
    ap.add_argument("--last", type=int, default=210, help="last frame, inclusive (default: 210)")
    ap.add_argument("--start-sec", type=int, default=1_700_000_000, help="stamp of frame 0 [s] (default: 1700000000)")
    ap.add_argument("--chunk-size", type=int, default=4 * 1024 * 1024, help="MCAP chunk size [bytes] (default: 4 MiB)")
    ap.add_argument("-v", "--verbose", action="store_true", help="print one line per frame")
    args = ap.parse_args(argv)
    if args.frame_stride < 1 or args.pixel_stride < 1:
        ap.error("strides must be >= 1")
    if not 0 <= args.first <= args.last:
        ap.error("need 0 <= --first <= --last")
    build(args)


if __name__ == "__main__":
    main(sys.argv[1:])
