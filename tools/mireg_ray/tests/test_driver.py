"""The Ray driver on a local Ray (2 CPUs), against the mireg binary (``MIREG_BIN``, else
target/release/mireg): several copies of the fixture and a corrupt log, a task killed once,
re-runs, a changed config, and one log in stitched segments against a sequential run.

    MIREG_BIN=target/debug/mireg tools/.venv-ray/bin/python -m pytest -q tools/mireg_ray/tests
"""

from __future__ import annotations

import json
import re
import shutil
import subprocess
from pathlib import Path

from mireg_ray import __main__ as cli
from mireg_ray import common

REPO = Path(__file__).resolve().parents[3]
FIXTURE = REPO / "fixtures" / "icl_livingroom1.mcap"


def manifest(out: Path) -> dict[str, dict]:
    return {e["input"]: e for e in map(json.loads, (out / "manifest.jsonl").read_text().split("\n")[:-1])}


def test_many_logs_kill_retry_rerun_and_config_change(tmp_path, monkeypatch, binary):
    logs = tmp_path / "logs"
    (logs / "a").mkdir(parents=True)
    (logs / "b").mkdir()
    for name in ("a/one.mcap", "a/killme.mcap", "b/two.mcap"):
        shutil.copy(FIXTURE, logs / name)
    # Bytes changed inside the fixture's one chunk: its CRC fails (a log cut short would be
    # read as far as it goes, so corruption is what must fail).
    corrupt = bytearray(FIXTURE.read_bytes())
    for i in range(len(corrupt) // 3, len(corrupt) // 3 + 64):
        corrupt[i] ^= 0x5A
    (logs / "b" / "corrupt.mcap").write_bytes(bytes(corrupt))
    out = tmp_path / "out"
    markers = tmp_path / "markers"
    monkeypatch.chdir(tmp_path)
    monkeypatch.setenv(common.KILL_ONCE_ENV, f"killme:{markers}")
    args = ["run", "logs/**/*.mcap", "--out", str(out), "--local-cpus", "2"]

    assert cli.main(args) == 1  # one failure
    m = manifest(out)
    assert sorted(m) == ["logs/a/killme.mcap", "logs/a/one.mcap", "logs/b/corrupt.mcap",
                         "logs/b/two.mcap"]
    assert len(list(markers.iterdir())) == 1, "the killme task's worker was killed once"
    for key, e in m.items():
        assert {"input", "output", "status", "error", "summary"} <= set(e)
        if key.endswith("corrupt.mcap"):
            assert e["status"] == "failed"
            assert "corrupt.mcap" in e["error"] and "chunk at offset" in e["error"]
            assert not Path(e["output"]).exists()
        else:
            assert e["status"] == "done", e
            assert e["error"] is None
            assert Path(e["output"]).is_file()
            assert Path(e["output"]) == out / Path(key).relative_to("logs").with_suffix(".mireg.mcap")
            assert e["summary"]["frames"] == 71 and e["summary"]["failed_frames"] == 0
            assert Path(e["summary"]["output"]) == Path(e["output"])
    done = {k: Path(e["output"]).stat().st_mtime_ns for k, e in m.items() if e["status"] == "done"}

    # A re-run recomputes nothing that is done (the corrupt log is tried again, and fails again).
    assert cli.main(args) == 1
    m2 = manifest(out)
    for k, mtime in done.items():
        assert m2[k]["status"] == "skipped"
        assert m2[k]["summary"] == m[k]["summary"]
        assert Path(m2[k]["output"]).stat().st_mtime_ns == mtime
    assert m2["logs/b/corrupt.mcap"]["status"] == "failed"

    # A changed config recomputes.
    assert cli.main(args + ["--", "--voxel", "0.06"]) == 1
    m3 = manifest(out)
    for k in done:
        assert m3[k]["status"] == "done"
        assert m3[k]["config_hash"] != m[k]["config_hash"]
        assert m3[k]["summary"]["voxel_m"] == 0.06


def ate_between(binary: str, est: Path, ref: Path, tmp: Path) -> float:
    tum = tmp / "ref.tum"
    subprocess.run([binary, "export", str(ref), "-o", str(tum), "--format", "tum"], check=True)
    # The odometry of both: stitching joins the segments' odometry (/mireg/pose).
    out = subprocess.run([binary, "evaluate", str(est), "--odometry", "--gt", str(tum), "--gt-format", "tum"],
                         capture_output=True, text=True, check=True).stdout
    return float(re.search(r"ATE RMSE\s+([0-9.]+) m", out).group(1))


def test_segments_are_stitched_into_the_sequential_trajectory(tmp_path, binary):
    seq = tmp_path / "sequential.mcap"
    # Against the sequential odometry: stitching joins the segments' odometry (/mireg/pose).
    subprocess.run([binary, "register", str(FIXTURE), "-o", str(seq), "--quiet", "--no-loops"],
                   check=True)
    out = tmp_path / "stitched.mcap"
    assert cli.main(["segments", str(FIXTURE), "--segments", "3", "--out", str(out),
                     "--local-cpus", "2"]) == 0
    assert ate_between(binary, out, seq, tmp_path) < 0.001  # target: within 1 mm
    info = json.loads(subprocess.run([binary, "info", str(out), "--json"], capture_output=True,
                                     text=True, check=True).stdout)
    counts = {c["topic"]: c["message_count"] for c in info["channels"]}
    assert counts["/mireg/pose"] == counts["/camera/depth/points"] == 71
    # ... and `segments` closes loops over the stitched whole.
    assert counts["/mireg/pose_optimized"] == 71 and counts["/mireg/loops"] > 0
    assert not list(tmp_path.glob(".mireg-segments-*")), "segment outputs removed"


def test_symlinked_inputs_keep_their_place_under_the_root(tmp_path):
    """An input that is a symbolic link to a file outside the glob's root is written under the
    output directory by its own name (it used to raise: the link was resolved first)."""
    from mireg_ray import run

    elsewhere = tmp_path / "elsewhere.mcap"
    elsewhere.write_bytes(b"")
    logs = tmp_path / "logs" / "day1"
    logs.mkdir(parents=True)
    (logs / "a.mcap").symlink_to(elsewhere)
    root = tmp_path / "logs"
    assert Path(run.output_for(str(tmp_path / "out"), root, logs / "a.mcap")) == \
        tmp_path / "out" / "day1" / "a.mireg.mcap"


def test_logs_of_one_site_are_registered_then_merged(tmp_path, monkeypatch, binary):
    """Three copies of the fixture as sessions: each pair linked in its own task (one task's
    worker killed once), the merge solved from the pairs' files, against `mireg merge` of the
    same runs in one process; a re-run links nothing again."""
    logs = tmp_path / "logs"
    logs.mkdir()
    for name in ("one.mcap", "two.mcap", "three.mcap"):
        shutil.copy(FIXTURE, logs / name)
    monkeypatch.chdir(tmp_path)
    markers = tmp_path / "markers"
    monkeypatch.setenv(common.KILL_ONCE_ENV, f"pair_0_2:{markers}")
    merged = tmp_path / "merged"
    args = ["run", "logs/*.mcap", "--out", str(tmp_path / "out"), "--local-cpus", "2",
            "--merge", str(merged)]
    assert cli.main(args) == 0
    assert len(list(markers.iterdir())) == 1, "the pair_0_2 task's worker was killed once"
    report = json.loads((merged / "merge_report.json").read_text())
    assert report["groups"] == 1
    names = ["one.mireg", "three.mireg", "two.mireg"]  # the glob's order
    assert [s["name"] for s in report["sessions"]] == names
    # The same log thrice: every session lands on the first (its world is the same frame).
    for s in report["sessions"][1:]:
        t = s["alignment"]
        assert max(abs(v) for v in t[:3]) < 0.01 and abs(abs(t[6]) - 1.0) < 1e-4
    links = merged / "links"
    pairs = manifest(links)
    assert sorted(pairs) == ["pair_0_1", "pair_0_2", "pair_1_2"]
    assert all(e["status"] == "done" and Path(e["file"]).is_file() for e in pairs.values())
    # The oracle: the same runs merged in one process, no files.
    runs = [str(tmp_path / "out" / f"{n}.mcap") for n in names]
    whole = tmp_path / "whole"
    subprocess.run([binary, "merge", *runs, "-o", str(whole)], check=True, capture_output=True)
    for n in names:
        assert poses_merged(binary, merged / f"{n}.mcap", tmp_path) == \
            poses_merged(binary, whole / f"{n}.mcap", tmp_path), n
    # A re-run: registrations and pairs up to date, the merge solved again from the files.
    mtimes = {k: Path(e["file"]).stat().st_mtime_ns for k, e in pairs.items()}
    assert cli.main(args) == 0
    again = manifest(links)
    for k, mtime in mtimes.items():
        assert again[k]["status"] == "skipped"
        assert Path(again[k]["file"]).stat().st_mtime_ns == mtime


def poses_merged(binary: str, path: Path, tmp: Path) -> str:
    """The TUM text of a merged output's `/mireg/pose_merged`."""
    tum = tmp / "merged.tum"
    subprocess.run([binary, "export", str(path), "--topic", "/mireg/pose_merged", "--format",
                    "tum", "-o", str(tum)], check=True, capture_output=True)
    return tum.read_text()
