"""``python -m mireg_ray run GLOB --out DIR``: one Ray task per log.

Each input gets ``DIR/<its path below the glob's fixed prefix>.mireg.mcap``, written atomically by
mireg itself. ``DIR/manifest.jsonl`` holds one JSON object per input and is rewritten (atomically)
as tasks finish: ``input``, ``output``, ``status`` (``done``, ``failed`` or ``skipped``: done
before, with the same input and config), ``error``, ``summary`` (mireg's JSON summary),
``signature`` (size and mtime of the input), ``config_hash`` and ``elapsed_s``.

GLOB and DIR may also be object-store URLs (``s3://bucket/logs/*.mcap``, see store.py): a task
then downloads its input to the worker's local disk, runs mireg there, and uploads the output
atomically; the manifest is an object beside the outputs, written by the driver alone, and a
remote input's signature is its size and ETag.
"""

from __future__ import annotations

import contextlib
import glob
import json
import os
import posixpath
import sys
import tempfile
import time
from pathlib import Path, PurePosixPath

from . import common, merge, store


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


def output_name(name: str, is_file: bool) -> str:
    """``x.mcap`` → ``x.mireg.mcap``; a bag directory ``x`` → ``x.mireg.mcap``."""
    suffix = PurePosixPath(name).suffix
    stem = name[: -len(suffix)] if suffix and is_file else name
    return f"{stem}.mireg.mcap"


def output_for(out: str, root: Path, path: Path) -> str:
    """The output of a local input: ``out`` (a directory or a URL) / its path below root."""
    # Absolute but not resolved: an input that is a symbolic link to a file elsewhere keeps
    # its place under the root.
    rel = (Path(os.path.abspath(path)).relative_to(os.path.abspath(root))
           if root != Path(".") else path)
    return store.join(out, *rel.parent.parts, output_name(rel.name, path.is_file()))


def plan(pattern: str, out: str, options: dict) -> list[tuple[str, str, dict]]:
    """(input, output, signature) of every input the glob names."""
    if store.is_remote(pattern):
        return [(url, store.join(out, posixpath.dirname(rel),
                                 output_name(posixpath.basename(rel), is_file)), sig)
                for url, rel, is_file, sig in store.expand(pattern, options)]
    root, paths = expand(pattern)
    return [(str(p), output_for(out, root, p), common.input_signature(p)) for p in paths]


def read_manifest(url: str, options: dict) -> dict[str, dict]:
    if store.is_remote(url):
        text = store.read_text(url, options)
    else:
        text = Path(url).read_text() if Path(url).exists() else None
    entries = {}
    for line in (text or "").splitlines():
        if line.strip():
            e = json.loads(line)
            entries[e["input"]] = e
    return entries


def write_manifest(url: str, entries: dict[str, dict], options: dict) -> None:
    text = "".join(json.dumps(entries[key], sort_keys=True) + "\n" for key in sorted(entries))
    if store.is_remote(url):
        store.write_bytes(url, text.encode(), options)
        return
    path = Path(url)
    tmp = path.with_name(f".{path.name}.tmp")
    with open(tmp, "w") as f:
        f.write(text)
        f.flush()
        os.fsync(f.fileno())
    os.replace(tmp, path)


def register_task(binary: str, input_path: str, output: str, mireg_args: list[str],
                  threads: int, options: dict) -> dict:
    """The body of one Ray task (a plain function, so it can be tested without Ray). A remote
    input is downloaded, and a remote output written, in a local temporary directory that is
    removed however the task ends; the output is then uploaded atomically."""
    common.maybe_kill_self(input_path)
    start = time.monotonic()
    local_in = input_path
    try:
        with contextlib.ExitStack() as stack:
            local_out = output
            if store.is_remote(input_path) or store.is_remote(output):
                tmp = stack.enter_context(tempfile.TemporaryDirectory(prefix="mireg-ray-"))
                if store.is_remote(input_path):
                    local_in = store.download(input_path, tmp, options)
                if store.is_remote(output):
                    local_out = os.path.join(tmp, "output.mcap")
            summary = common.run_mireg(
                binary, ["register", local_in, "-o", local_out, "--force", "--quiet", *mireg_args],
                threads)
            if local_out != output:
                store.upload(local_out, output, options)
                summary["output"] = output
        return {"status": "done", "error": None, "summary": summary,
                "elapsed_s": time.monotonic() - start}
    except common.ProcessKilled:
        raise
    except Exception as e:  # noqa: BLE001 -- mireg's or the store's error text is the result
        # mireg names the file it read: a downloaded copy is named by its URL instead.
        return {"status": "failed", "error": str(e).replace(local_in, input_path),
                "summary": None, "elapsed_s": time.monotonic() - start}


def main(args, mireg_args: list[str]) -> int:
    try:
        return drive(args, mireg_args)
    except store.StoreError as e:  # one line naming the URL, not a traceback
        print(f"error: {e}", file=sys.stderr)
        return 2


def drive(args, mireg_args: list[str]) -> int:
    binary = common.mireg_bin()
    options = store.parse_options(args.storage_option)
    pattern, out = store.local_path(args.glob), store.local_path(args.out)
    if store.is_remote(out):
        store.require(out, options)
    else:
        Path(out).mkdir(parents=True, exist_ok=True)
    manifest_path = store.join(out, "manifest.jsonl")
    entries = read_manifest(manifest_path, options)
    chash = common.config_hash(binary, mireg_args)
    inputs = plan(pattern, out, options)
    if not inputs:
        print(f"no input matches {args.glob!r}")
        return 2

    todo = []
    for key, output, sig in inputs:
        old = entries.get(key)
        if (old and old["status"] in ("done", "skipped") and old.get("signature") == sig
                and old.get("config_hash") == chash and store.exists(old["output"], options)):
            entries[key] = dict(old, status="skipped")
            continue
        todo.append((key, output, sig))
    skipped = len(inputs) - len(todo)
    print(f"{len(inputs)} inputs: {len(todo)} to run, {skipped} up to date "
          f"(config {chash}, {binary})")
    write_manifest(manifest_path, entries, options)

    if todo:
        ray = common.init_ray(args.address, args.local_cpus)
        remote = ray.remote(register_task).options(
            num_cpus=args.cpus_per_task, max_retries=args.retries,
            retry_exceptions=[common.ProcessKilled])
        pending = {}
        for key, output, sig in todo:
            if not store.is_remote(output):
                Path(output).parent.mkdir(parents=True, exist_ok=True)
            ref = remote.remote(binary, key, output, mireg_args, args.cpus_per_task, options)
            pending[ref] = (key, output, sig)

        def record(context, result):
            key, output, sig = context
            entries[key] = {"input": key, "output": output, "signature": sig,
                            "config_hash": chash, **result}
            write_manifest(manifest_path, entries, options)
            return key

        common.gather(ray, pending, record)
        ray.shutdown()
    if store.is_remote(out):
        # Temporary objects of this run's outputs (and of the manifest) that a task or driver
        # killed between its upload and its copy could not remove.
        left = store.sweep([output for _, output, _ in todo] + [manifest_path], options)
        if left:
            print(f"removed {left} temporary object(s) left by killed uploads")

    failed = [e for e in entries.values() if e["status"] == "failed" and e["input"] in
              {key for key, _, _ in inputs}]
    counts = {s: sum(1 for e in entries.values() if e["status"] == s)
              for s in ("done", "skipped", "failed")}
    print(f"done {counts['done']}, skipped {counts['skipped']}, failed {counts['failed']}; "
          f"manifest {manifest_path}")
    if failed:
        print("failures:")
        width = max(len(e["input"]) for e in failed)
        for e in failed:
            print(f"  {e['input']:<{width}}  {(e['error'] or '').splitlines()[0]}")
        return 1
    if getattr(args, "merge", None):
        return merge.merge(binary, [entries[key]["output"] for key, _, _ in inputs], args.merge,
                           args)
    return 0

