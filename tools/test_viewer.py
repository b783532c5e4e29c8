"""Smoke tests of tools/view.py and tools/report.py (pytest, ~10 s).

The end-to-end tests need a real mireg output MCAP, named by the environment variable
``MIREG_OUTPUT_MCAP`` (CI makes it with
``mireg register fixtures/icl_livingroom1.mcap -o "$MIREG_OUTPUT_MCAP" --force``); they are skipped
with a message when it is unset. They run ``view.py --save`` and read the .rrd back with
``rerun.chunk.RrdReader`` (rerun-sdk 0.41; there is no ``rerun.dataframe`` module in 0.41), then
check the entities against what the MCAP holds: one cloud entity per ``--every``-th frame, one
trajectory/camera row and one value per stats series per frame, failures where the stats say so,
everything on the ``message_log_time`` timeline at the MCAP's log times.
The ``--frame`` test also needs the mireg binary (``MIREG_BIN`` or ``target/release/mireg``).
The unit tests (PointCloud2 decoding with padded layouts, RPE, TOML writer) need nothing.

Usage:
    bash tools/setup_viewer_venv.sh
    MIREG_OUTPUT_MCAP=/tmp/out.mcap tools/.venv-viewer/bin/python -m pytest -q tools/test_viewer.py
"""

from __future__ import annotations

import math
import os
import subprocess
import sys
import tomllib
from collections import defaultdict
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

TOOLS = Path(__file__).resolve().parent
REPO = TOOLS.parent
sys.path.insert(0, str(TOOLS))

import report  # noqa: E402
import view  # noqa: E402

EVERY = 5
STAGES = view.STAGES


def output_mcap() -> Path:
    value = os.environ.get("MIREG_OUTPUT_MCAP")
    if not value:
        pytest.skip(
            "MIREG_OUTPUT_MCAP is unset: set it to the output of "
            "`mireg register fixtures/icl_livingroom1.mcap -o OUT.mcap` to run the viewer smoke tests"
        )
    path = Path(value)
    if not path.is_file():
        pytest.fail(f"MIREG_OUTPUT_MCAP={value} does not exist")
    return path


def read_rrd(path: Path) -> dict:
    """entity path -> {"rows": n, "timelines": set, "batches": [RecordBatch]} of the recording."""
    from rerun.chunk import RrdReader

    reader = RrdReader(path)
    assert reader.recordings(), "no recording store in the .rrd"
    assert reader.blueprints(), "no blueprint store in the .rrd"
    entities = defaultdict(lambda: {"rows": 0, "timelines": set(), "batches": []})
    for chunk in reader.stream():
        e = entities[chunk.entity_path.lstrip("/")]
        if not chunk.is_static:
            e["rows"] += chunk.num_rows
        e["timelines"].update(chunk.timeline_names)
        e["batches"].append(chunk.to_record_batch())
    return dict(entities)


def column(entity: dict, suffix: str) -> list:
    """Values of the column whose name ends with ``suffix``, ordered by message_log_time."""
    pairs = []
    for batch in entity["batches"]:
        names = batch.schema.names
        if "message_log_time" not in names:
            continue
        name = next(n for n in names if n.endswith(suffix))
        times = batch.column("message_log_time").cast("int64").to_pylist()
        pairs += zip(times, batch.column(name).to_pylist())
    return sorted(pairs, key=lambda p: p[0])


@pytest.fixture(scope="module")
def run():
    return view.read_run(output_mcap(), load_clouds=False)


@pytest.fixture(scope="module")
def saved(tmp_path_factory, run):
    rrd = tmp_path_factory.mktemp("view") / "out.rrd"
    cmd = [sys.executable, str(TOOLS / "view.py"), str(run.path), "--save", str(rrd),
           "--every", str(EVERY)]
    proc = subprocess.run(cmd, capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr
    assert rrd.stat().st_size > 0
    return read_rrd(rrd)


def test_clouds_one_per_every_frame(saved, run):
    n = len(run.frames)
    assert n > 1
    clouds = sorted(p for p in saved if p.startswith("world/clouds/"))
    expected = [f"world/clouds/frame_{k:04d}" for k in range(0, n, EVERY)]
    assert clouds == expected
    for path in clouds:
        assert saved[path]["rows"] == 1
        assert "message_log_time" in saved[path]["timelines"]
    # the cloud of frame k is logged at frame k's log time
    k = expected[-1]
    (t, _), = column(saved[k], "Points3D:positions")
    assert t == run.frames[(n - 1) // EVERY * EVERY].log_time


def test_trajectories(saved, run):
    n_est = sum(f.estimate is not None for f in run.frames)
    assert n_est == len(run.frames)
    assert saved["world/trajectory/estimate"]["rows"] == n_est
    assert saved["world/camera"]["rows"] == n_est
    assert saved["world/camera/axes"]["rows"] == n_est
    strips = column(saved["world/trajectory/estimate"], "LineStrips3D:strips")
    assert [t for t, _ in strips] == [f.log_time for f in run.frames]
    last = np.array(strips[-1][1][0])
    assert last.shape == (n_est, 3)  # the strip grows to the whole trajectory
    np.testing.assert_allclose(last[-1], run.frames[-1].estimate[:3, 3], atol=1e-5)
    if run.has_reference:
        n_ref = sum(f.reference is not None for f in run.frames)
        assert saved["world/trajectory/reference"]["rows"] == n_ref
    else:
        assert "world/trajectory/reference" not in saved


def test_stats_series_one_value_per_frame(saved, run):
    stats = [f for f in run.frames if f.stats is not None]
    assert len(stats) == len(run.frames)
    inliers = column(saved["stats/inliers"], "Scalars:scalars")
    assert [t for t, _ in inliers] == [f.log_time for f in stats]
    assert [v[0] for _, v in inliers] == [float(f.stats["num_inliers"]) for f in stats]
    for name in ("correspondences", "inlier_ratio", "hypotheses", "fitness", "inlier_rmse_m"):
        assert saved[f"stats/{name}"]["rows"] == len(stats), name
    for stage in STAGES:
        assert saved[f"stats/timings_ms/{stage}"]["rows"] == len(stats), stage
        assert "message_log_time" in saved[f"stats/timings_ms/{stage}"]["timelines"]


def test_failures_marked(saved, run):
    failed = [f for f in run.frames if f.stats and f.stats.get("success") is False]
    if failed:
        assert saved["world/failures"]["rows"] == len(failed)
        assert saved["log/failures"]["rows"] == len(failed)
        texts = [v for _, v in column(saved["log/failures"], "TextLog:text")]
        assert all(f"frame {f.index} " in str(text) for f, text in zip(failed, texts))
    else:
        assert "world/failures" not in saved
        assert "log/failures" not in saved


def test_frame_pair_recomputation(tmp_path, run):
    mireg = Path(os.environ.get("MIREG_BIN", REPO / "target/release/mireg"))
    if not mireg.is_file():
        pytest.skip(f"no mireg binary at {mireg} (set MIREG_BIN)")
    rrd = tmp_path / "pair.rrd"
    k = min(12, len(run.frames) - 1)
    cmd = [sys.executable, str(TOOLS / "view.py"), str(run.path), "--save", str(rrd),
           "--every", "1000", "--frame", str(k), "--mireg", str(mireg)]
    proc = subprocess.run(cmd, capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr
    saved = read_rrd(rrd)
    for path in ("world/pair/source", "world/pair/target", "world/pair/correspondences",
                 "log/pair", f"world/clouds/frame_{k:04d}"):
        assert saved[path]["rows"] == 1, path
    (t, strips), = column(saved["world/pair/correspondences"], "LineStrips3D:strips")
    assert t == run.frames[k].log_time
    assert len(strips) > 10  # consecutive fixture frames overlap: many inlier pairs
    assert all(len(s) == 2 for s in strips)


def test_report_writes_png(tmp_path, run):
    png = tmp_path / "report.png"
    proc = subprocess.run(
        [sys.executable, str(TOOLS / "report.py"), str(run.path), "-o", str(png)],
        capture_output=True, text=True, timeout=120,
    )
    assert proc.returncode == 0, proc.stderr
    data = png.read_bytes()
    assert data[:8] == b"\x89PNG\r\n\x1a\n"
    assert len(data) > 10_000
    assert "frames: " in proc.stdout


# ------------------------------------------------------------------------------------------------
# unit tests (no MCAP needed)
# ------------------------------------------------------------------------------------------------


def _cloud_msg(points, intensity, point_step, big_endian=False, width=None, height=1, row_pad=0):
    """A PointCloud2-like object: x, y, z FLOAT32 at 0/4/8, intensity FLOAT32 at 16, padding."""
    endian = ">" if big_endian else "<"
    dtype = np.dtype({"names": ["x", "y", "z", "intensity"],
                      "formats": [endian + "f4"] * 4, "offsets": [0, 4, 8, 16],
                      "itemsize": point_step})
    arr = np.zeros(len(points), dtype=dtype)
    arr["x"], arr["y"], arr["z"] = points.T
    arr["intensity"] = intensity
    width = width or len(points)
    rows = [arr[r * width:(r + 1) * width].tobytes() + b"\xee" * row_pad for r in range(height)]
    fields = [SimpleNamespace(name=n, offset=o, datatype=7, count=1)
              for n, o in (("x", 0), ("y", 4), ("z", 8), ("intensity", 16))]
    return SimpleNamespace(fields=fields, is_bigendian=big_endian, point_step=point_step,
                           row_step=width * point_step + row_pad, width=width, height=height,
                           data=b"".join(rows))


@pytest.mark.parametrize("point_step,big_endian,height,row_pad",
                         [(20, False, 1, 0), (32, False, 1, 0), (24, True, 1, 0), (32, False, 2, 8)])
def test_decode_pointcloud2_layouts(point_step, big_endian, height, row_pad):
    rng = np.random.default_rng(1)
    pts = rng.normal(size=(6, 3)).astype(np.float32)
    pts[2] = np.nan  # non-finite points are dropped
    inten = np.arange(6, dtype=np.float32)
    msg = _cloud_msg(pts, inten, point_step, big_endian, width=6 // height, height=height,
                     row_pad=row_pad)
    xyz, i = view.decode_pointcloud2(msg)
    keep = [0, 1, 3, 4, 5]
    np.testing.assert_array_equal(xyz, pts[keep].astype(np.float64))
    np.testing.assert_array_equal(i, inten[keep])


def _pose(yaw_deg, t):
    m = np.eye(4)
    c, s = math.cos(math.radians(yaw_deg)), math.sin(math.radians(yaw_deg))
    m[:2, :2] = [[c, -s], [s, c]]
    m[:3, 3] = t
    return m


def test_rpe():
    ref = [_pose(0, [0, 0, 0]), _pose(10, [1, 0, 0]), _pose(20, [2, 0, 0])]
    trans, rot = report.rpe(ref, ref)
    assert math.isnan(trans[0]) and np.allclose(trans[1:], 0) and np.allclose(rot[1:], 0, atol=1e-6)
    est = [ref[0], ref[1], ref[1] @ np.linalg.inv(ref[1]) @ ref[2] @ _pose(3, [0, 0.05, 0])]
    trans, rot = report.rpe(est, ref)
    assert np.isclose(trans[2], 0.05) and np.isclose(rot[2], 3.0)


def test_to_toml_round_trip():
    cfg = {"voxel_size_m": 0.05, "normal_radius_m": None, "icp": True, "seed": 0,
           "sampler": {"kind": "levy", "mu": -50.0}, "ranking": {"kind": "ratio"},
           "sensor_origin": [0.0, 1.5, -2.0]}
    parsed = tomllib.loads(view.to_toml(cfg))
    assert parsed == {k: v for k, v in cfg.items() if v is not None}


def ros1_output_mcap() -> Path:
    value = os.environ.get("MIREG_ROS1_OUTPUT_MCAP")
    if not value:
        pytest.skip(
            "MIREG_ROS1_OUTPUT_MCAP is unset: set it to the output of "
            "`mireg register fixtures/bags/icl4_lz4.bag -o OUT.mcap` to run the ROS 1 test"
        )
    return Path(value)


def test_ros1_output_reads_with_its_reference_and_a_chosen_reference_topic():
    """A ROS 1 bag's output: clouds, estimates and reference poses decode (mcap_ros1), and
    --reference-topic picks another PoseStamped topic (here the estimate itself)."""
    run = view.read_run(ros1_output_mcap(), load_clouds=True)
    assert run.has_reference
    assert len(run.frames) == 4
    for f in run.frames:
        assert f.points is not None and len(f.points) > 1000
        assert f.estimate is not None and f.reference is not None
    # The first estimate is the identity; the reference starts at the identity too.
    np.testing.assert_allclose(run.frames[0].estimate, np.eye(4), atol=1e-12)
    assert max(np.linalg.norm(f.estimate[:3, 3] - f.reference[:3, 3]) for f in run.frames) < 0.02
    same = view.read_run(ros1_output_mcap(), load_clouds=False, reference_topic="/mireg/pose")
    for f in same.frames:
        np.testing.assert_array_equal(f.reference, f.estimate)
    none = view.read_run(ros1_output_mcap(), load_clouds=False, reference_topic="/no/such/topic")
    assert not none.has_reference
