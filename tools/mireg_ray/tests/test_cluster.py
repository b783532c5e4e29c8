"""The Ray driver on Ray's own multi-node cluster on one machine (``ray.cluster_utils.Cluster``:
a head and two worker nodes of 1 CPU each): a worker node is removed while the run is under way,
and one task's mireg process is killed. Every input must end ``done`` exactly once in the
manifest, no output may be partial or left twice, and each output's poses must be byte-identical
to a sequential run's.

    MIREG_BIN=target/debug/mireg tools/.venv-ray/bin/python -m pytest -q tools/mireg_ray/tests
    MIREG_RAY_REPEAT=5 ...   # the same scenario five times over (the benchmark's "0 lost over 5 runs")
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import threading
import time
from pathlib import Path

import pytest

from mireg_ray import __main__ as cli
from mireg_ray import common

REPO = Path(__file__).resolve().parents[3]
FIXTURE = REPO / "fixtures" / "icl_livingroom1.mcap"
LOGS = 8


def pose_bytes(path: Path) -> list[bytes]:
    """The /mireg/pose messages' bytes (stats carry timings; poses must not differ at all)."""
    from mcap.reader import make_reader

    with open(path, "rb") as f:
        return [m.data for _, _, m in make_reader(f).iter_messages(topics=["/mireg/pose"])]


def run_once(tmp: Path, binary: str, sequential: list[bytes], monkeypatch) -> None:
    from ray.cluster_utils import Cluster

    logs = tmp / "logs"
    logs.mkdir()
    for i in range(LOGS):
        shutil.copy(FIXTURE, logs / f"log{i}.mcap")
    out, markers = tmp / "out", tmp / "markers"
    monkeypatch.chdir(tmp)
    monkeypatch.setenv(common.KILL_ONCE_ENV, f"log5:{markers}")
    cluster = Cluster(initialize_head=True, head_node_args={"num_cpus": 1})
    try:
        workers = [cluster.add_node(num_cpus=1) for _ in range(2)]
        cluster.wait_for_nodes()
        result = {}
        driver = threading.Thread(target=lambda: result.setdefault("code", cli.main(
            ["run", "logs/*.mcap", "--out", str(out), "--address", cluster.address,
             "--retries", "3", "--", "--no-loops"])))
        driver.start()
        # Remove a worker node once the first log is done: the others are then under way.
        manifest = out / "manifest.jsonl"
        deadline = time.time() + 120
        while time.time() < deadline and driver.is_alive():
            text = manifest.read_text() if manifest.exists() else ""
            if '"status": "done"' in text:
                break
            time.sleep(0.02)
        removed = driver.is_alive()
        if removed:
            cluster.remove_node(workers[0])
        driver.join(timeout=300)
        assert not driver.is_alive(), "the driver did not finish"
    finally:
        cluster.shutdown()
    assert result.get("code") == 0
    assert removed, "the run ended before a node could be removed"
    lines = [json.loads(line) for line in (out / "manifest.jsonl").read_text().splitlines()]
    inputs = [e["input"] for e in lines]
    assert sorted(inputs) == sorted(f"logs/log{i}.mcap" for i in range(LOGS)), inputs
    assert all(e["status"] == "done" for e in lines), lines
    assert len(list(markers.iterdir())) == 1, "the log5 task's process was killed once"
    # No partial or extra file: exactly one output per input beside the manifest.
    names = sorted(p.name for p in out.iterdir())
    assert names == sorted([f"log{i}.mireg.mcap" for i in range(LOGS)] + ["manifest.jsonl"]), names
    for e in lines:
        assert pose_bytes(Path(e["output"])) == sequential, e["input"]


def test_a_node_removed_and_a_task_killed_lose_nothing(tmp_path, binary, monkeypatch):
    pytest.importorskip("ray.cluster_utils")
    seq = tmp_path / "sequential.mcap"
    subprocess.run([binary, "register", str(FIXTURE), "-o", str(seq), "--quiet", "--no-loops"],
                   check=True, env=dict(os.environ, RAYON_NUM_THREADS="1"))
    sequential = pose_bytes(seq)
    assert len(sequential) == 71
    for k in range(int(os.environ.get("MIREG_RAY_REPEAT", "1"))):
        run_dir = tmp_path / f"run{k}"
        run_dir.mkdir()
        run_once(run_dir, binary, sequential, monkeypatch)
