"""The mireg command as the tools run it: which binary, `mireg register` with its summary, and the
poses `mireg export` gives of an output. Standard library only, so any tool's venv can import it.
"""

from __future__ import annotations

import json
import os
import subprocess
import time
from pathlib import Path

REPO = Path(__file__).resolve().parent.parent


def default_binary() -> str:
    """`$MIREG_BIN`, else the repository's release build (`target/release/mireg`)."""
    return os.environ.get("MIREG_BIN") or str(REPO / "target" / "release" / "mireg")


def checked_binary(binary: str) -> str:
    """`binary` if it is a file, else exits naming it and how to build one."""
    if not Path(binary).is_file():
        raise SystemExit(f"mireg binary {binary} not found: build it with `cargo build --release` "
                         "or pass --mireg PATH (or set MIREG_BIN)")
    return binary


def register(binary: str, log: str, out: str, flags=(), *, summary: bool = False) -> tuple[dict | None, float]:
    """`mireg register LOG -o OUT --force FLAGS...`: its JSON summary (with `summary`, else
    `None`, and the run is `--quiet`) and the wall time of the whole process [s]. Exits with
    mireg's message when it fails."""
    mode = ["--json"] if summary else ["--quiet"]
    cmd = [checked_binary(binary), "register", log, "-o", out, "--force", *mode, *flags]
    t0 = time.perf_counter()
    run = subprocess.run(cmd, capture_output=True, text=True)
    wall = time.perf_counter() - t0
    if run.returncode != 0:
        raise SystemExit(f"mireg register {log} failed ({run.returncode}): {run.stderr.strip()}")
    return (json.loads(run.stdout) if summary else None), wall


def exported_tum(binary: str, out: str, topic: str | None = None) -> dict[int, tuple[float, ...]]:
    """The poses `mireg export OUT --format tum` gives (the output's best trajectory, or `topic`):
    stamp [ns] -> (x, y, z, qx, qy, qz, qw)."""
    cmd = [checked_binary(binary), "export", out, "--format", "tum"]
    if topic:
        cmd += ["--topic", topic]
    tum = subprocess.run(cmd, capture_output=True, text=True, check=True).stdout
    poses = {}
    for line in tum.splitlines():
        words = line.split()
        # Stamps as written (seconds with nine decimals): exact in integers, not in a float.
        sec, _, frac = words[0].partition(".")
        poses[int(sec) * 1_000_000_000 + int((frac + "000000000")[:9])] = tuple(float(w) for w in words[1:8])
    return poses
