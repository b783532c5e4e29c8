#!/usr/bin/env python3
"""How much of a trajectory's error no loop closure can remove, on an out-and-back log.

A loop edge measures the pose of a frame on the way back relative to a frame on the way out at
the same place. An error both legs share at that place leaves every such edge satisfied, so the
pose graph cannot see it; only the legs' *differential* error is loop closure's to remove. This
splits the ATE of each estimate of `mireg register` outputs accordingly:

    python3 tools/toolbox.py leg-error OUT.mcap... [--mireg BIN]

For each frame, after SE(3) alignment (Umeyama, positions matched by stamp) to
``/ground_truth/pose``: its error e, and that of the frame of the other half of the log nearest
to it in the reference (the same place on the other leg), e'. The shared part (e + e') / 2,
re-aligned, is the ATE a loop closure that made the legs agree perfectly would still leave
(a bound, not a prediction); the differential part (e − e') / 2 is what it can remove. Needs
numpy (tools/setup_venv.sh loops makes that venv).
"""

from __future__ import annotations

import argparse
import subprocess
import sys

import numpy as np

import mireg_run

TOPICS = ("/mireg/pose", "/mireg/pose_optimized")


def positions(binary: str, log: str, topic: str) -> dict[str, np.ndarray]:
    """TUM stamp string -> position [m] of `topic` in `log` (empty when the topic is absent)."""
    p = subprocess.run([binary, "export", log, "--format", "tum", "--topic", topic],
                       capture_output=True, text=True)
    if p.returncode != 0:
        if "no topic" in p.stderr:
            return {}
        sys.exit(f"mireg export {log} --topic {topic}: {p.stderr.strip()}")
    out = {}
    for line in p.stdout.splitlines():
        if line.strip() and not line.startswith("#"):
            v = line.split()
            out[v[0]] = np.array([float(x) for x in v[1:4]])
    return out


def align(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Errors of `x` after the rigid motion that best puts it on `y` (Umeyama 1991, no scale)."""
    mx, my = x.mean(0), y.mean(0)
    u, _, vt = np.linalg.svd((y - my).T @ (x - mx))
    w = np.diag([1.0, 1.0, np.sign(np.linalg.det(u) * np.linalg.det(vt))])
    r = u @ w @ vt
    return (r @ (x - mx).T).T + my - y


def rms(e: np.ndarray) -> float:
    return float(np.sqrt((e**2).sum(1).mean()))


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("outputs", nargs="+")
    ap.add_argument("--mireg", default=mireg_run.default_binary())
    args = ap.parse_args()
    for log in args.outputs:
        ref = positions(args.mireg, log, "/ground_truth/pose")
        if not ref:
            sys.exit(f"{log}: no /ground_truth/pose to judge against")
        judged = 0
        for topic in TOPICS:
            est = positions(args.mireg, log, topic)
            stamps = sorted(set(est) & set(ref), key=float)
            if len(stamps) < 4:
                continue
            judged += 1
            x = np.array([est[s] for s in stamps])
            y = np.array([ref[s] for s in stamps])
            e = align(x, y)
            n = len(stamps)
            half = n // 2
            other = np.empty(n, dtype=int)
            for i in range(n):
                leg = np.arange(half, n) if i < half else np.arange(0, half)
                other[i] = leg[np.linalg.norm(y[leg] - y[i], axis=1).argmin()]
            shared = rms(align(y + (e + e[other]) / 2, y))
            diff = rms((e - e[other]) / 2)
            ate = rms(e)
            print(f"{log} {topic}: ATE {100 * ate:.3f} cm; shared by both legs "
                  f"{100 * shared:.3f} cm ({shared / ate:.3f}x); differential {100 * diff:.3f} cm")
        if not judged:
            print(f"{log}: no estimate ({', '.join(TOPICS)}) with 4 stamps of the reference; "
                  "is it a mireg register output?")
    return 0


if __name__ == "__main__":
    sys.exit(main())
