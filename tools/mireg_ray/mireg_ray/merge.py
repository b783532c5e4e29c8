"""``python -m mireg_ray run GLOB --out DIR --merge MERGED``, after the registrations: each pair
of sessions is linked in a Ray task (``mireg merge RUNS --pair A,B --links MERGED/links``: the
verification of its candidates, the costly part of a merge), then the driver solves the merge
from the pairs' files (``mireg merge RUNS -o MERGED --links MERGED/links``), which give the
merge one process would.

``MERGED/links/manifest.jsonl`` holds one JSON object per pair, rewritten (atomically) as tasks
finish: ``input`` (``pair_A_B``), ``file``, ``status`` (``done``, ``failed`` or ``skipped``:
linked before from the same runs), ``error``, ``summary`` (mireg's report of the pair),
``signature`` (each run's path, size and mtime, in order, and the mireg binary's version) and
``elapsed_s``. A driver or a node lost during a merge loses only the pairs it was linking.
"""

from __future__ import annotations

import subprocess
import sys
import time
from pathlib import Path

from . import common, run, store


def pairs(n: int) -> list[tuple[int, int]]:
    """Every pair of sessions (a < b), in the order ``mireg merge`` links them."""
    return [(a, b) for b in range(1, n) for a in range(b)]


def link_task(binary: str, outputs: list[str], pair: tuple[int, int], links: str,
              threads: int) -> dict:
    """The body of one Ray task: ``mireg merge --pair``, which writes the pair's file
    atomically (a plain function, so it can be tested without Ray)."""
    a, b = pair
    common.maybe_kill_self(f"pair_{a}_{b}")
    start = time.monotonic()
    try:
        summary = common.run_mireg(
            binary, ["merge", *outputs, "--pair", f"{a},{b}", "--links", links, "--force"],
            threads)
        return {"status": "done", "error": None, "summary": summary,
                "elapsed_s": time.monotonic() - start}
    except common.ProcessKilled:
        raise
    except Exception as e:  # noqa: BLE001 -- mireg's error text is the result
        return {"status": "failed", "error": str(e), "summary": None,
                "elapsed_s": time.monotonic() - start}


def signature(binary: str, outputs: list[str]) -> dict:
    return {"runs": [[o, common.input_signature(Path(o))] for o in outputs],
            "mireg": common.mireg_version(binary)}


def merge(binary: str, outputs: list[str], target: str, args) -> int:
    """Links every pair of ``outputs`` (in the glob's order) on the cluster, then merges them
    into the folder ``target`` on the driver."""
    if store.is_remote(target) or any(store.is_remote(o) for o in outputs):
        print("error: --merge needs local outputs and a local folder", file=sys.stderr)
        return 2
    if len(outputs) < 2:
        print(f"nothing to merge: {len(outputs)} output(s)")
        return 0
    links = Path(target) / "links"
    links.mkdir(parents=True, exist_ok=True)
    manifest_path = str(links / "manifest.jsonl")
    entries = run.read_manifest(manifest_path, {})
    sig = signature(binary, outputs)
    todo, keys = [], {f"pair_{a}_{b}" for a, b in pairs(len(outputs))}
    for a, b in pairs(len(outputs)):
        key, file = f"pair_{a}_{b}", links / f"pair_{a}_{b}.json"
        old = entries.get(key)
        if (old and old["status"] in ("done", "skipped") and old.get("signature") == sig
                and file.is_file()):
            entries[key] = dict(old, status="skipped")
            continue
        todo.append(((a, b), key, str(file)))
    print(f"{len(outputs)} sessions, {len(keys)} pairs: {len(todo)} to link, "
          f"{len(keys) - len(todo)} up to date")
    run.write_manifest(manifest_path, entries, {})
    if todo:
        ray = common.init_ray(args.address, args.local_cpus)
        remote = ray.remote(link_task).options(
            num_cpus=args.cpus_per_task, max_retries=args.retries,
            retry_exceptions=[common.ProcessKilled])
        pending = {remote.remote(binary, outputs, pair, str(links), args.cpus_per_task):
                   (key, file) for pair, key, file in todo}

        def record(context, result):
            key, file = context
            entries[key] = {"input": key, "file": file, "signature": sig, **result}
            run.write_manifest(manifest_path, entries, {})
            return key

        common.gather(ray, pending, record)
        ray.shutdown()
    failed = [e for k, e in entries.items() if k in keys and e["status"] == "failed"]
    if failed:
        print("pairs that failed to link:", file=sys.stderr)
        for e in failed:
            print(f"  {e['input']}  {(e['error'] or '').splitlines()[0]}", file=sys.stderr)
        return 1
    p = subprocess.run([binary, "merge", *outputs, "-o", target, "--links", str(links),
                        "--force"], capture_output=True, text=True)
    print(p.stdout, end="")
    if p.returncode != 0:
        print(f"merge failed: {p.stderr.strip()}", file=sys.stderr)
        return 1
    return 0
