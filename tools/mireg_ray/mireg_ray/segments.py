"""``python -m mireg_ray segments LOG --segments K --out OUT.mcap``: one long log in K
overlapping segments, registered as parallel Ray tasks, then stitched by ``mireg stitch``.

Segment i covers clouds ``[i·N/K, (i+1)·N/K + overlap)`` (the last one runs to the end), so
consecutive segments share ``overlap`` frames; each segment's output keeps only its window's
messages (``--copy-window``) and lives in a temporary directory beside OUT. ``mireg stitch``
aligns each segment on the later half of the frames it shares with the one before and writes
one output that
copies the whole log, with ``/tf``, ``/mireg/pose`` and ``/mireg/stats`` over all of it, then
closes loops once over the stitched whole (``/mireg/loops``, ``/mireg/pose_optimized``; the
segments themselves run with ``--no-loops``).
"""

from __future__ import annotations

import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from . import common, store


def bounds(n: int, k: int, overlap: int) -> list[tuple[int, int | None]]:
    """``[start, end)`` cloud indices of each segment (``None``: to the end)."""
    k = max(1, min(k, n))
    starts = [i * n // k for i in range(k)]
    out = []
    for i, s in enumerate(starts):
        end = None if i == k - 1 else min(n, starts[i + 1] + overlap)
        out.append((s, end))
    return out


def segment_task(binary: str, log: str, start: int, end: int | None, output: str,
                 mireg_args: list[str], threads: int) -> dict:
    common.maybe_kill_self(f"{log}#{start}")
    # No loop closure per segment: `mireg stitch` closes loops once over the stitched whole.
    args = ["register", log, "-o", output, "--force", "--quiet", "--copy-window", "--no-loops",
            "--start", str(start)]
    if end is not None:
        args += ["--end", str(end)]
    t = time.monotonic()
    summary = common.run_mireg(binary, args + mireg_args, threads)
    return {"summary": summary, "elapsed_s": time.monotonic() - t}


def main(args, mireg_args: list[str]) -> int:
    binary = common.mireg_bin()
    if store.is_remote(args.log) or store.is_remote(args.out):
        # The segments' outputs go from the workers to the driver through a directory beside
        # OUT, which an object store is not.
        print("error: segments reads and writes local (or shared) paths only; object-store "
              "URLs work with `run`", file=sys.stderr)
        return 2
    log = Path(store.local_path(args.log))
    info = json.loads(subprocess.run([binary, "info", str(log), "--json"], capture_output=True,
                                     text=True, check=True).stdout)
    n = info.get("cloud_messages") or 0
    if n < 2:
        print(f"{log}: {n} clouds, nothing to split")
        return 2
    plan = bounds(n, args.segments, args.overlap)
    out = Path(store.local_path(args.out))
    out.parent.mkdir(parents=True, exist_ok=True)
    print(f"{log}: {n} clouds on {info['cloud_topic']}, {len(plan)} segments overlapping by "
          f"{args.overlap} frames: {plan}")
    start = time.monotonic()
    with tempfile.TemporaryDirectory(prefix=".mireg-segments-", dir=out.parent) as tmp:
        ray = common.init_ray(args.address, args.local_cpus)
        remote = ray.remote(segment_task).options(
            num_cpus=args.cpus_per_task, max_retries=args.retries,
            retry_exceptions=[common.ProcessKilled])
        outputs = [str(Path(tmp) / f"segment_{i:04d}.mcap") for i in range(len(plan))]
        refs = [remote.remote(binary, str(log), s, e, o, mireg_args, args.cpus_per_task)
                for (s, e), o in zip(plan, outputs)]
        results = [None] * len(refs)
        left = list(refs)
        while left:
            ready, left = ray.wait(left, num_returns=1)
            i = refs.index(ready[0])
            results[i] = ray.get(ready[0])
            common.progress(len(refs) - len(left), len(refs), f"segment {i}")
        ray.shutdown()
        stitched = json.loads(subprocess.run(
            [binary, "stitch", str(log), *outputs, "-o", str(out), "--force", "--json"],
            capture_output=True, text=True, check=True).stdout)
    elapsed = time.monotonic() - start
    report = {"output": str(out), "frames": stitched["frames"], "segments": len(plan),
              "seams": stitched["seams"], "elapsed_s": elapsed,
              "segment_elapsed_s": [r["elapsed_s"] for r in results]}
    print(json.dumps(report, indent=2))
    return 0
