"""What both commands share: finding the mireg command, running it, connecting to Ray."""

from __future__ import annotations

import hashlib
import json
import os
import shutil
import signal
import subprocess
import sys
import sysconfig
from pathlib import Path

# Test hook: "SUBSTRING:MARKER_DIR" makes the first attempt of every task whose input path
# contains SUBSTRING kill its own Ray worker, once per input (a marker file remembers it), so that
# the retry on worker loss can be tested.
KILL_ONCE_ENV = "MIREG_RAY_TEST_KILL_ONCE"


class ProcessKilled(RuntimeError):
    """mireg was ended by a signal (OOM killer, preemption): worth a retry, unlike an error."""


def mireg_bin() -> str:
    """``$MIREG_BIN`` (e.g. a cargo build), else the ``mireg`` command of the mireg Python package
    this driver depends on (installed beside this Python), else ``mireg`` on PATH."""
    if os.environ.get("MIREG_BIN"):
        return os.environ["MIREG_BIN"]
    try:
        import mireg  # noqa: F401  (the package whose console script is the command)
    except ImportError:
        pass
    else:
        for scripts in (sysconfig.get_path("scripts"), str(Path(sys.executable).parent)):
            candidate = Path(scripts) / "mireg"
            if candidate.is_file() and os.access(candidate, os.X_OK):
                return str(candidate)
    found = shutil.which("mireg")
    if found:
        return found
    raise SystemExit("no mireg command: pip install the mireg package (./python) into this "
                     "environment, or set MIREG_BIN to a mireg binary")


def mireg_version(binary: str) -> str:
    out = subprocess.run([binary, "--version"], capture_output=True, text=True, check=True)
    return out.stdout.strip()


def config_hash(binary: str, mireg_args: list[str]) -> str:
    """What decides an output besides its input: the mireg version and the extra arguments."""
    blob = json.dumps({"mireg": mireg_version(binary), "args": mireg_args})
    return hashlib.sha256(blob.encode()).hexdigest()[:16]


def input_signature(path: Path) -> dict:
    """Size and newest mtime of a log (a file, or the files of a bag directory)."""
    files = [path] if path.is_file() else sorted(p for p in path.rglob("*") if p.is_file())
    stats = [p.stat() for p in files]
    return {"size": sum(s.st_size for s in stats),
            "mtime_ns": max((s.st_mtime_ns for s in stats), default=0)}


def maybe_kill_self(input_path: str) -> None:
    spec = os.environ.get(KILL_ONCE_ENV)
    if not spec:
        return
    substring, _, marker_dir = spec.partition(":")
    if substring not in input_path:
        return
    marker = Path(marker_dir) / hashlib.sha256(input_path.encode()).hexdigest()
    try:
        marker.parent.mkdir(parents=True, exist_ok=True)
        marker.touch(exist_ok=False)
    except FileExistsError:
        return
    os.kill(os.getpid(), signal.SIGKILL)  # the whole worker, as a lost node would


def run_mireg(binary: str, args: list[str], threads: int) -> dict:
    """Runs ``mireg ARGS --json``; returns the summary. Raises ProcessKilled when a signal ended
    it, RuntimeError with mireg's own error text otherwise."""
    env = dict(os.environ, RAYON_NUM_THREADS=str(threads))
    proc = subprocess.run([binary, *args, "--json"], capture_output=True, text=True, env=env)
    if proc.returncode < 0:
        raise ProcessKilled(f"mireg ended by signal {-proc.returncode}")
    if proc.returncode != 0:
        raise RuntimeError(proc.stderr.strip() or f"mireg exited {proc.returncode}")
    return json.loads(proc.stdout)


def init_ray(address: str | None, cpus: int | None):
    import ray

    # The S3 endpoint too, so that workers on other nodes reach the store the driver reads
    # (credentials are not shipped: each node has its own, the usual way).
    forwarded = ("MIREG_BIN", KILL_ONCE_ENV, "AWS_ENDPOINT_URL", "AWS_ENDPOINT_URL_S3")
    env_vars = {k: v for k, v in os.environ.items() if k in forwarded}
    os.environ.setdefault("RAY_USAGE_STATS_ENABLED", "0")  # no usage reports from our runs
    kwargs = {"runtime_env": {"env_vars": env_vars}, "log_to_driver": False}
    if address:
        ray.init(address=address, **kwargs)
    else:
        ray.init(num_cpus=cpus or os.cpu_count(), include_dashboard=False, **kwargs)
    return ray


def progress(done: int, total: int, what: str) -> None:
    width = 30
    filled = width * done // max(total, 1)
    print(f"[{'#' * filled}{'.' * (width - filled)}] {done}/{total} {what}", file=sys.stderr,
          flush=True)


def gather(ray, pending: dict, record) -> None:
    """Waits for the tasks of ``pending`` (object ref -> its context) as they finish, each
    passed to ``record(context, result)`` (which returns its name for the progress line) with
    its result, or with a failure where its retries ran out."""
    total, done = len(pending), 0
    while pending:
        ready, _ = ray.wait(list(pending), num_returns=1)
        context = pending.pop(ready[0])
        try:
            result = ray.get(ready[0])
        except Exception as e:  # noqa: BLE001 -- retries exhausted: a failure like any
            result = {"status": "failed", "error": f"{type(e).__name__}: {e}",
                      "summary": None, "elapsed_s": None}
        name = record(context, result)
        done += 1
        progress(done, total, f"{result['status']}: {name}")
