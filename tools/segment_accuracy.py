#!/usr/bin/env python3
"""Segments against the reference (issue 34, item 3): registers a log in K overlapping segments
exactly as ``mireg_ray segments`` does (``register --copy-window --no-loops --start/--end``, the
split of ``mireg_ray.segments.bounds``), stitches them (``mireg stitch``, ``--no-loops`` unless
``--loops``), and prints the stitched ATE against the log's reference next to the sequential
run's, and the seams' RPE against the median RPE. No Ray: the segments run one after the other, so the numbers are the
stitching's, not the cluster's.

    tools/segment_accuracy.py /tmp/kaist03.mcap --segments 2 4 --overlap 4 6 [--loops]
        [--seeds 0 1 2 3] [--mireg BIN] [-- ARGS]

With several ``--seeds`` every run is repeated with ``register --seed S`` and the verdict is the
ratio of the mean ATEs over the seeds (one seed's ATE on the KITTI replay moves by ±10 %).

With ``--loops``, the sequential run and the stitch close loops (their default, and what
``mireg_ray segments`` delivers: one pose graph over the stitched log, with the seam pairs), and
both are judged on their optimised trajectories (``/mireg/pose_optimized``).

ATE: ``mireg evaluate --json`` (position RMSE after SE(3) alignment, frames matched by stamp).
RPE of a step: the translation error of the relative pose between consecutive frames, from
``mireg export --format tum`` of the estimate and the reference. A seam's step is the one from
the anchor (the last frame the two segments share) to the next frame, the first whose pose comes
from the later segment. Runs in the venv of `bash tools/setup_venv.sh ray` (it imports the
driver's own split, mireg_ray.segments).
"""

from __future__ import annotations

import argparse
import json
import math
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

import mireg_run
from mireg_ray.segments import bounds  # noqa: E402  (the driver's own split)


def run(cmd: list[str]) -> str:
    p = subprocess.run(cmd, capture_output=True, text=True)
    if p.returncode != 0:
        sys.exit(f"{' '.join(cmd)}: {p.stderr.strip()}")
    return p.stdout


def tum(binary: str, log: Path, topic: str | None = None) -> dict[int, tuple]:
    """Stamp [ns] -> (translation, quaternion xyzw) of a log's trajectory."""
    cmd = [binary, "export", str(log), "--format", "tum"] + (["--topic", topic] if topic else [])
    poses = {}
    for line in run(cmd).splitlines():
        if line.strip() and not line.startswith("#"):
            v = line.split()
            sec, _, frac = v[0].partition(".")
            poses[int(sec) * 10**9 + int(frac.ljust(9, "0"))] = (
                tuple(map(float, v[1:4])), tuple(map(float, v[4:8])))
    return poses


def qmul(a, b):
    ax, ay, az, aw = a
    bx, by, bz, bw = b
    return (aw * bx + ax * bw + ay * bz - az * by, aw * by - ax * bz + ay * bw + az * bx,
            aw * bz + ax * by - ay * bx + az * bw, aw * bw - ax * bx - ay * by - az * bz)


def rotate(q, v):
    x, y, z, w = q
    p = qmul(qmul(q, (*v, 0.0)), (-x, -y, -z, w))
    return p[:3]


def relative(p, q):
    """p⁻¹ q as (translation, quaternion)."""
    inv = (-p[1][0], -p[1][1], -p[1][2], p[1][3])
    d = tuple(b - a for a, b in zip(p[0], q[0]))
    return rotate(inv, d), qmul(inv, q[1])


def step_errors(est, ref):
    """(first stamp, last stamp, translation error [m]) of each step between consecutive frames
    that have a reference, in stamp order (a reference on every other frame gives two-frame
    steps)."""
    stamps = sorted(set(est) & set(ref))
    errs = []
    for a, b in zip(stamps, stamps[1:]):
        (te, _qe), (tr, qr) = relative(est[a], est[b]), relative(ref[a], ref[b])
        # (ref step)⁻¹ (est step): translation part.
        inv = (-qr[0], -qr[1], -qr[2], qr[3])
        errs.append((a, b, math.dist(rotate(inv, te), rotate(inv, tr))))
    return errs


def main() -> int:
    argv = sys.argv[1:]
    extra = argv[argv.index("--") + 1:] if "--" in argv else []
    argv = argv[: argv.index("--")] if "--" in argv else argv
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("log", type=Path)
    ap.add_argument("--segments", type=int, nargs="+", default=[2, 4])
    ap.add_argument("--overlap", type=int, nargs="+", default=[4])
    ap.add_argument("--loops", action="store_true",
                    help="close loops in the sequential run and over the stitched log")
    ap.add_argument("--seeds", type=int, nargs="+", default=[0],
                    help="run everything once per seed (register --seed); with several, also print "
                         "the ratio of the mean ATEs")
    ap.add_argument("--mireg", default=mireg_run.default_binary())
    args = ap.parse_args(argv)
    b = args.mireg
    n = json.loads(run([b, "info", str(args.log), "--json"]))["cloud_messages"]
    no_loops = [] if args.loops else ["--no-loops"]
    pose_topic = "/mireg/pose_optimized" if args.loops else "/mireg/pose"
    configs = [(k, overlap) for k in args.segments for overlap in args.overlap]
    # (k, overlap) -> per seed: (stitched ATE, sequential ATE, median RPE, seam RPEs)
    results: dict[tuple[int, int], list[tuple[float, float, float, list[float]]]] = {
        c: [] for c in configs}
    print(f"{args.log}: {n} clouds; {'loops closed' if args.loops else 'odometry, --no-loops'}; "
          f"seeds {' '.join(map(str, args.seeds))}")
    print("seed  K  overlap  segments                       seq ATE  ATE (cm)  vs seq  "
          "median RPE (cm)  seam RPE (cm)  worst seam / median")
    with tempfile.TemporaryDirectory() as tmp:
        for seed in args.seeds:
            opts = [*extra, "--seed", str(seed)]
            seq = Path(tmp) / f"seq{seed}.mcap"
            run([b, "register", str(args.log), "-o", str(seq), "--quiet", *no_loops, *opts])
            seq_ate = json.loads(run([b, "evaluate", str(seq), "--json"]))["ate_rmse_m"]
            ref = tum(b, seq, "/ground_truth/pose")
            for k, overlap in configs:
                plan = bounds(n, k, overlap)
                outs = []
                for i, (start, end) in enumerate(plan):
                    out = Path(tmp) / f"s{seed}_{k}_{overlap}_{i}.mcap"
                    window = ["--start", str(start)] + (["--end", str(end)] if end else [])
                    run([b, "register", str(args.log), "-o", str(out), "--quiet", "--copy-window",
                         "--no-loops", *window, *opts])
                    outs.append(str(out))
                st = Path(tmp) / f"st{seed}_{k}_{overlap}.mcap"
                run([b, "stitch", str(args.log), *outs, "-o", str(st), *no_loops])
                ate = json.loads(run([b, "evaluate", str(st), "--json"]))["ate_rmse_m"]
                est = tum(b, st, pose_topic)
                steps = step_errors(est, ref)
                med = statistics.median(e for _, _, e in steps)
                # The anchor of each seam: the last frame the later segment shares with the
                # earlier one (the later segment's frames start after it). A seam's step is the
                # one that spans the anchor and the frame after it.
                order = sorted(est)
                seams = [min(plan[i][1], n) - 1 for i in range(len(plan) - 1)]
                seam_errs = [e for s in seams if s + 1 < len(order)
                             for a, b_, e in steps if a <= order[s] and order[s + 1] <= b_]
                worst = max(seam_errs) / med if seam_errs else float("nan")
                results[(k, overlap)].append((ate, seq_ate, med, seam_errs))
                print(f"{seed:<5} {k:<2} {overlap:<8} {str(plan):<30} {100 * seq_ate:7.3f}  "
                      f"{100 * ate:8.3f}  {ate / seq_ate:6.3f}  {100 * med:15.2f}  "
                      f"{' '.join(f'{100 * e:.2f}' for e in seam_errs):<13}  {worst:.2f}",
                      flush=True)
    if len(args.seeds) > 1:
        # One seed's ATE moves by ±10 % from seed to seed (the sampler's draw), more than the
        # stitching's effect: the verdict is the ratio of the means over the seeds.
        print(f"over {len(args.seeds)} seeds: K  overlap  mean seq ATE  mean ATE (cm)  vs seq  "
              "worst seam / median RPE (mean over seeds)")
        for (k, overlap), rs in results.items():
            seq_mean = statistics.fmean(r[1] for r in rs)
            ate_mean = statistics.fmean(r[0] for r in rs)
            seam = statistics.fmean(max(r[3]) / r[2] for r in rs if r[3])
            print(f"{'':<15}{k:<2} {overlap:<8} {100 * seq_mean:12.3f}  {100 * ate_mean:13.3f}  "
                  f"{ate_mean / seq_mean:6.3f}  {seam:.2f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
