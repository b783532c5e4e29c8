"""``python -m mireg_ray run GLOB --out DIR``: one Ray task per log.

Each input gets ``DIR/<its path below the glob's fixed prefix>.mireg.mcap``, written atomically by
mireg itself. ``DIR/manifest.jsonl`` holds one JSON object per input and is rewritten (atomically)
as tasks finish: ``input``, ``output``, ``status`` (``done``, ``failed`` or ``skipped``: done
before, with the same input and config), ``error``, ``summary`` (mireg's JSON summary),
``signature`` (size and mtime of the input), ``config_hash`` and ``elapsed_s``.
"""

from __future__ import annotations

import glob
import json
import os
import time
from pathlib import Path

from . import common


def expand(pattern: str) -> tuple[Path, list[Path]]:
    """The inputs a glob names (files, and bag directories holding a metadata.yaml), and the
    fixed directory prefix outputs are named relative to."""
    parts = Path(pattern).parts
    fixed = []
    for p in parts:
        if glob.has_magic(p):
            break
        fixed.append(p)
    root = Path(*fixed) if fixed else Path(".")
    if root == Path(pattern):  # no magic: one input
        root = root.parent
    found = sorted({Path(p) for p in glob.glob(pattern, recursive=True)})
    inputs = [p for p in found if p.is_file() or (p / "metadata.yaml").is_file()]
    return root, inputs


def output_for(out_dir: Path, root: Path, path: Path) -> Path:
    # Absolute but not resolved: an input that is a symbolic link to a file elsewhere keeps
    # its place under the root.
    rel = (Path(os.path.abspath(path)).relative_to(os.path.abspath(root))
           if root != Path(".") else path)
    name = rel.name[: -len(rel.suffix)] if rel.suffix and path.is_file() else rel.name
    return out_dir / rel.parent / f"{name}.mireg.mcap"


def read_manifest(path: Path) -> dict[str, dict]:
    if not path.exists():
        return {}
    entries = {}
    for line in path.read_text().splitlines():
        if line.strip():
            e = json.loads(line)
            entries[e["input"]] = e
    return entries


def write_manifest(path: Path, entries: dict[str, dict]) -> None:
    tmp = path.with_name(f".{path.name}.tmp")
    with open(tmp, "w") as f:
        for key in sorted(entries):
            f.write(json.dumps(entries[key], sort_keys=True) + "\n")
        f.flush()
        os.fsync(f.fileno())
    os.replace(tmp, path)


def register_task(binary: str, input_path: str, output: str, mireg_args: list[str],
                  threads: int) -> dict:
    """The body of one Ray task (a plain function, so it can be tested without Ray)."""
    common.maybe_kill_self(input_path)
    start = time.monotonic()
    try:
        summary = common.run_mireg(
            binary, ["register", input_path, "-o", output, "--force", "--quiet", *mireg_args],
            threads)
        return {"status": "done", "error": None, "summary": summary,
                "elapsed_s": time.monotonic() - start}
    except common.ProcessKilled:
        raise
    except Exception as e:  # noqa: BLE001 -- mireg's error text is the result
        return {"status": "failed", "error": str(e), "summary": None,
                "elapsed_s": time.monotonic() - start}


def main(args, mireg_args: list[str]) -> int:
    binary = common.mireg_bin()
    out_dir = Path(args.out)
    out_dir.mkdir(parents=True, exist_ok=True)
    manifest_path = out_dir / "manifest.jsonl"
    entries = read_manifest(manifest_path)
    chash = common.config_hash(binary, mireg_args)
    root, inputs = expand(args.glob)
    if not inputs:
        print(f"no input matches {args.glob!r}")
        return 2

    todo = []
    for path in inputs:
        key = str(path)
        output = output_for(out_dir, root, path)
        sig = common.input_signature(path)
        old = entries.get(key)
        if (old and old["status"] in ("done", "skipped") and old.get("signature") == sig
                and old.get("config_hash") == chash and Path(old["output"]).exists()):
            entries[key] = dict(old, status="skipped")
            continue
        todo.append((key, output, sig))
    skipped = len(inputs) - len(todo)
    print(f"{len(inputs)} inputs: {len(todo)} to run, {skipped} up to date "
          f"(config {chash}, {binary})")
    write_manifest(manifest_path, entries)

    if todo:
        ray = common.init_ray(args.address, args.local_cpus)
        remote = ray.remote(register_task).options(
            num_cpus=args.cpus_per_task, max_retries=args.retries,
            retry_exceptions=[common.ProcessKilled])
        pending = {}
        for key, output, sig in todo:
            output.parent.mkdir(parents=True, exist_ok=True)
            ref = remote.remote(binary, key, str(output), mireg_args, args.cpus_per_task)
            pending[ref] = (key, output, sig)
        done = 0
        while pending:
            ready, _ = ray.wait(list(pending), num_returns=1)
            key, output, sig = pending.pop(ready[0])
            try:
                result = ray.get(ready[0])
            except Exception as e:  # noqa: BLE001 -- retries exhausted: a failure like any
                result = {"status": "failed", "error": f"{type(e).__name__}: {e}",
                          "summary": None, "elapsed_s": None}
            entries[key] = {"input": key, "output": str(output), "signature": sig,
                            "config_hash": chash, **result}
            write_manifest(manifest_path, entries)
            done += 1
            common.progress(done, len(todo), f"{result['status']}: {key}")
        ray.shutdown()

    failed = [e for e in entries.values() if e["status"] == "failed" and e["input"] in
              {str(p) for p in inputs}]
    counts = {s: sum(1 for e in entries.values() if e["status"] == s)
              for s in ("done", "skipped", "failed")}
    print(f"done {counts['done']}, skipped {counts['skipped']}, failed {counts['failed']}; "
          f"manifest {manifest_path}")
    if failed:
        print("failures:")
        width = max(len(e["input"]) for e in failed)
        for e in failed:
            print(f"  {e['input']:<{width}}  {(e['error'] or '').splitlines()[0]}")
    return 1 if failed else 0
