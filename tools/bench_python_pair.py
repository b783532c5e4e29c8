#!/usr/bin/env python3
"""The Python package's pair registration against the CLI's on the same clouds, interleaved:
``mireg pair SRC.npy TGT.npy --json`` (its ``timings_s.total``, compute only) and
``mireg.register_pair`` timed around the call in this process (array hand-over, configuration
and result conversion included). Checks both give the same transformation, bit for bit.

Usage:
    tools/.venv-peers/bin/pip install ./python       # any venv with numpy
    python3 tools/toolbox.py bench-python-pair [--mireg target/release/mireg] [--runs 15]
Clouds: the ICL-NUIM fixture pair (fixtures/icl_nuim/rgbd5_00004.ply -> rgbd5_00000.ply).
"""

import argparse
import json
import statistics
import subprocess
import tempfile
import time
from pathlib import Path

import numpy as np

import mireg
import mireg_run

REPO = Path(__file__).resolve().parent.parent


def read_ply(path: Path) -> np.ndarray:
    """x, y, z of a binary little-endian PLY whose vertices are three float32s."""
    data = path.read_bytes()
    end = data.index(b"end_header\n") + len(b"end_header\n")
    n = int(next(line.split()[2] for line in data[:end].decode().splitlines()
                 if line.startswith("element vertex")))
    return np.frombuffer(data, "<f4", 3 * n, end).reshape(n, 3).astype(np.float64)


def main():
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--mireg", default=mireg_run.default_binary())
    ap.add_argument("--runs", type=int, default=15)
    args = ap.parse_args()
    src = read_ply(REPO / "fixtures/icl_nuim/rgbd5_00004.ply")
    tgt = read_ply(REPO / "fixtures/icl_nuim/rgbd5_00000.ply")
    cli, call, inner = [], [], []
    with tempfile.TemporaryDirectory() as tmp:
        s, t = Path(tmp) / "s.npy", Path(tmp) / "t.npy"
        np.save(s, src)
        np.save(t, tgt)
        for _ in range(args.runs):
            run = subprocess.run([args.mireg, "pair", str(s), str(t), "--voxel", "0.05", "--json"],
                                 capture_output=True, text=True, check=True)
            out = json.loads(run.stdout)
            cli.append(out["timings_s"]["total"])
            t0 = time.perf_counter()
            r = mireg.register_pair(src, tgt, voxel=0.05)
            call.append(time.perf_counter() - t0)
            inner.append(r.timings["total"])
            assert r.raw["target_from_source"] == out["target_from_source"], "different results"
    mc, mp, mi = (statistics.median(v) for v in (cli, call, inner))
    print(f"ICL fixture pair, {args.runs} interleaved runs: CLI {mc * 1e3:.2f} ms (timings total), "
          f"package {mp * 1e3:.2f} ms around the call ({mi * 1e3:.2f} ms inside); "
          f"package / CLI = {mp / mc:.3f}; same transformation every run")


if __name__ == "__main__":
    main()
