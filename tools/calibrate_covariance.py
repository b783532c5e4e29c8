#!/usr/bin/env python3
"""How well each frame's predicted covariance (``/mireg/pose_cov``) matches its real error: the
normalised estimation error squared (NEES) of every odometry step against a reference.

For consecutive frames k-1, k with estimated poses P and reference poses R (matched by header
stamp), the step error is d = the right perturbation taking the estimated step Z_e = P_{k-1}^-1 P_k
to the reference step Z_r = R_{k-1}^-1 R_k (Z_r = Z_e Exp(d), d in ROS order: translation, then
rotation vector), and NEES_k = d^T S_k^-1 d with S_k the 6x6 covariance of frame k's
PoseWithCovarianceStamped. A calibrated covariance gives a mean NEES of 6 (6 degrees of freedom)
and about 95 % of the steps under the chi-square 95 % bound 12.59. The reference's own step error
adds to d: on references that are estimates themselves (KAIST03's SLAM, micro211's reconstruction)
the NEES of a calibrated covariance is above 6.

Printed per log: steps scored, mean and median NEES, the fraction under 12.59, the scale the
covariance would need for a mean of 6 (``scale_for_6``) and for a median of 5.35 (the chi-square(6)
median, ``scale_for_median``, less sensitive to the few broken steps), the median predicted sigma and
the median real step error.

Usage (a registered output, or a log to register with ``--register``):
    bash tools/setup_venv.sh mcap
    python3 tools/toolbox.py calibrate-covariance OUT.mcap [OUT2.mcap ...]
    python3 tools/toolbox.py calibrate-covariance --register fixtures/icl_livingroom1.mcap \\
        /tmp/loop_micro211_s4.mcap /tmp/loop_kaist03.mcap
The reference topic is ``/ground_truth/pose`` (``--reference`` sets it); covariance topic
``/mireg/pose_cov``.
"""

import argparse
import json
import math
import os
import statistics
import subprocess
import sys
import tempfile

from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory

import mireg_run

CHI2_6_95 = 12.5916
CHI2_6_MEDIAN = 5.3481


def quat_to_matrix(x, y, z, w):
    n = math.sqrt(x * x + y * y + z * z + w * w)
    x, y, z, w = x / n, y / n, z / n, w / n
    return [
        [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
        [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
        [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
    ]


def pose(p):
    q = p.orientation
    return (quat_to_matrix(q.x, q.y, q.z, q.w), [p.position.x, p.position.y, p.position.z])


def mat_t(a):
    return [list(r) for r in zip(*a)]


def mat_mul(a, b):
    return [[sum(a[i][k] * b[k][j] for k in range(len(b))) for j in range(len(b[0]))] for i in range(len(a))]


def mat_vec(a, v):
    return [sum(a[i][k] * v[k] for k in range(len(v))) for i in range(len(a))]


def inverse(p):
    r, t = p
    rt = mat_t(r)
    return (rt, [-x for x in mat_vec(rt, t)])


def compose(a, b):
    return (mat_mul(a[0], b[0]), [x + y for x, y in zip(mat_vec(a[0], b[1]), a[1])])


def rotvec(r):
    c = max(-1.0, min(1.0, (r[0][0] + r[1][1] + r[2][2] - 1) / 2))
    angle = math.acos(c)
    v = [r[2][1] - r[1][2], r[0][2] - r[2][0], r[1][0] - r[0][1]]
    if angle < 1e-9:
        return [0.5 * x for x in v]
    s = angle / (2 * math.sin(angle))
    return [s * x for x in v]


def solve(a, b):
    """Gaussian elimination with partial pivoting (6x6)."""
    n = len(b)
    m = [list(a[i]) + [b[i]] for i in range(n)]
    for c in range(n):
        p = max(range(c, n), key=lambda r: abs(m[r][c]))
        m[c], m[p] = m[p], m[c]
        if m[c][c] == 0:
            raise ZeroDivisionError("singular covariance")
        for r in range(n):
            if r != c:
                f = m[r][c] / m[c][c]
                for k in range(c, n + 1):
                    m[r][k] -= f * m[c][k]
    return [m[i][n] / m[i][i] for i in range(n)]


def read(path, reference_topic, cov_topic, stats_topic):
    cov, ref, count = {}, {}, {}
    with open(path, "rb") as f:
        reader = make_reader(f)
        factory, decoders = DecoderFactory(), {}
        for schema, channel, message in reader.iter_messages(topics=[cov_topic, reference_topic, stats_topic]):
            if channel.topic == stats_topic:
                s = json.loads(message.data)
                count[s["stamp_ns"]] = s.get("map_correspondences")
                continue
            if channel.id not in decoders:
                decoders[channel.id] = factory.decoder_for(channel.message_encoding, schema)
            msg = decoders[channel.id](message.data)
            stamp = msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec
            if channel.topic == cov_topic:
                cov[stamp] = (pose(msg.pose.pose), [list(msg.pose.covariance[6 * i:6 * i + 6]) for i in range(6)])
            else:
                ref[stamp] = pose(msg.pose)
    return cov, ref, count


def score(path, reference_topic, cov_topic, stats_topic):
    cov, ref, count = read(path, reference_topic, cov_topic, stats_topic)
    stamps = sorted(s for s in cov if s in ref)
    nees, sigmas, errors, per_point = [], [], [], []
    for a, b in zip(stamps, stamps[1:]):
        (pa, _), (pb, s) = cov[a], cov[b]
        ze = compose(inverse(pa), pb)
        zr = compose(inverse(ref[a]), ref[b])
        d_pose = compose(inverse(ze), zr)
        d = d_pose[1] + rotvec(d_pose[0])
        try:
            x = solve(s, d)
        except ZeroDivisionError:
            continue
        nees.append(sum(u * v for u, v in zip(d, x)))
        if count.get(b):
            per_point.append(nees[-1] / count[b])
        sigmas.append(math.sqrt(max(s[0][0], s[1][1], s[2][2])))
        errors.append(math.sqrt(sum(v * v for v in d[:3])))
    if not nees:
        return None
    return {
        "steps": len(nees),
        "mean": statistics.fmean(nees),
        "median": statistics.median(nees),
        "under_95": sum(n < CHI2_6_95 for n in nees) / len(nees),
        "scale_for_6": statistics.fmean(nees) / 6,
        "scale_for_median": statistics.median(nees) / CHI2_6_MEDIAN,
        "sigma_m": statistics.median(sigmas),
        "error_m": statistics.median(errors),
        # NEES of a covariance that does not shrink with the number of correspondences n
        # (sigma^2 (J^T J / n)^-1, the scale for its median): per correspondence.
        "per_point_scale": statistics.median(per_point) / CHI2_6_MEDIAN if per_point else float("nan"),
    }


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("paths", nargs="+")
    ap.add_argument("--register", action="store_true", help="register each path first (mireg register PATH -o tmp)")
    ap.add_argument("--mireg", default=mireg_run.default_binary())
    ap.add_argument("--reference", default="/ground_truth/pose")
    ap.add_argument("--cov-topic", default="/mireg/pose_cov")
    ap.add_argument("--stats-topic", default="/mireg/stats")
    ap.add_argument("--seed", type=int, default=None)
    ap.add_argument("extra", nargs=argparse.REMAINDER, help="after --: more mireg register flags")
    args = ap.parse_args()
    extra = [a for a in args.extra if a != "--"]
    print("| log | steps | mean NEES | median NEES | < 12.59 | scale for mean 6 | scale for median | median sigma [m] | median error [m] | scale per correspondence |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    with tempfile.TemporaryDirectory() as tmp:
        for path in args.paths:
            out = path
            if args.register:
                out = os.path.join(tmp, os.path.basename(path) + ".out.mcap")
                cmd = [args.mireg, "register", path, "-o", out, "--quiet", "--no-loops"] + extra
                if args.seed is not None:
                    cmd += ["--seed", str(args.seed)]
                subprocess.run(cmd, check=True)
            r = score(out, args.reference, args.cov_topic, args.stats_topic)
            if r is None:
                print(f"| {os.path.basename(path)} | no step with both a covariance and a reference | | | | | | | |")
                continue
            print(f"| {os.path.basename(path)} | {r['steps']} | {r['mean']:.3g} | {r['median']:.3g} | "
                  f"{100 * r['under_95']:.0f} % | {r['scale_for_6']:.3g} | {r['scale_for_median']:.3g} | "
                  f"{r['sigma_m']:.2g} | {r['error_m']:.2g} | {r['per_point_scale']:.3g} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
