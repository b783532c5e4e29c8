"""Smoke tests of the viewer (``mireg view``, ``mireg.viewer``) and the report
(``mireg.viewer.report``); pytest, ~10 s, with the viewer extra (rerun-sdk, matplotlib).

The end-to-end tests need a real mireg output MCAP, named by the environment variable
``MIREG_OUTPUT_MCAP`` (CI makes it with
``mireg register fixtures/icl_livingroom1.mcap -o "$MIREG_OUTPUT_MCAP" --force``); they are skipped
with a message when it is unset. They run ``python -m mireg.viewer --save`` and read the .rrd
back with ``rerun.chunk.RrdReader`` (rerun-sdk 0.41; there is no ``rerun.dataframe`` module in
0.41), then check the entities against what the MCAP holds: one cloud entity per ``--every``-th
frame, one trajectory/camera row and one value per stats series per frame, failures where the
stats say so, everything on the ``message_log_time`` timeline at the MCAP's log times. The
reference is drawn where ``mireg evaluate`` aligns it. The loop-closure tests need an output with
``/mireg/pose_optimized`` and ``/mireg/loops`` (``register``'s default); ``MIREG_ROS1_OUTPUT_MCAP``
(the output of ``fixtures/bags/icl4_lz4.bag``) adds the ROS 1 tests, and ``MIREG_BIN`` (a mireg
binary, default the package's own command) the Livox and ``mireg map`` ones.

Usage:
    pip install "./python[viewer,test]"
    MIREG_OUTPUT_MCAP=/tmp/out.mcap python -m pytest -q python/tests/test_viewer.py
"""

from __future__ import annotations

import json
import math
import os
import subprocess
import sys
from collections import defaultdict
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("rerun", reason="the viewer extra is not installed (pip install 'mireg[viewer]')")

import mireg  # noqa: E402
from mireg.viewer import mapfile, report  # noqa: E402
from mireg.viewer.scene import STAGES  # noqa: E402

REPO = Path(__file__).resolve().parents[2]
EVERY = 5


def mireg_command() -> list[str]:
    """``MIREG_BIN``, else the package's ``mireg`` command (``python -m mireg``)."""
    if os.environ.get("MIREG_BIN"):
        return [os.environ["MIREG_BIN"]]
    return [sys.executable, "-m", "mireg"]


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


@pytest.fixture(scope="module")
def run():
    return mireg.read_run(output_mcap(), load_clouds=False)


@pytest.fixture(scope="module")
def saved(tmp_path_factory, run):
    rrd = tmp_path_factory.mktemp("view") / "out.rrd"
    cmd = [sys.executable, "-m", "mireg.viewer", str(run.path), "--save", str(rrd),
           "--every", str(EVERY)]
    proc = subprocess.run(cmd, capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr
    assert rrd.stat().st_size > 0
    return read_rrd(rrd)


def values(entity: dict, name: str) -> list:
    """(log time, value) of every row that has the column ``name`` (exact or ``…:name``)."""
    pairs = []
    for batch in entity["batches"]:
        names = batch.schema.names
        col = next((n for n in names if n == name or n.endswith(":" + name)), None)
        if col is None or "message_log_time" not in names:
            continue
        times = batch.column("message_log_time").cast("int64").to_pylist()
        pairs += zip(times, batch.column(col).to_pylist())
    return sorted(pairs, key=lambda p: p[0])


def run_view(*args, timeout=120):
    cmd = [sys.executable, "-m", "mireg", "view", *map(str, args)]
    return subprocess.run(cmd, capture_output=True, text=True, timeout=timeout, cwd=REPO)


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
    (t, _), = values(saved[k], "Points3D:positions")
    assert t == run.frames[(n - 1) // EVERY * EVERY].log_time


def test_trajectories(saved, run):
    n_est = sum(f.estimate is not None for f in run.frames)
    assert n_est == len(run.frames)
    assert saved["world/trajectory/estimate"]["rows"] == n_est
    assert saved["world/camera"]["rows"] == n_est
    assert saved["world/camera/axes"]["rows"] == n_est
    strips = values(saved["world/trajectory/estimate"], "LineStrips3D:strips")
    assert [t for t, _ in strips] == [f.log_time for f in run.frames]
    last = np.array(strips[-1][1][0])
    assert last.shape == (n_est, 3)  # the strip grows to the whole trajectory
    np.testing.assert_allclose(last[-1], run.frames[-1].estimate[:3, 3], atol=1e-5)
    if run.has_reference:
        n_ref = sum(f.reference is not None for f in run.frames)
        assert saved["world/trajectory/reference"]["rows"] == n_ref
    else:
        assert "world/trajectory/reference" not in saved


def test_reference_drawn_where_evaluate_aligns_it(saved, run):
    """The reference strip is the reference laid onto the drawn trajectory by the alignment of
    `mireg evaluate` (the same ATE, to the last bits of a float)."""
    if not run.has_reference:
        pytest.skip("this output has no reference")
    proc = subprocess.run([*mireg_command(), "evaluate", str(run.path), "--json"],
                          capture_output=True, text=True, check=True)
    want = json.loads(proc.stdout)
    got = run.evaluate()
    assert got["ate_rmse_m"] == pytest.approx(want["ate_rmse_m"], rel=1e-12, abs=1e-15)
    align = run.estimate_from_reference("optimized")
    refs = [f.reference for f in run.frames if f.reference is not None]
    strips = values(saved["world/trajectory/reference"], "LineStrips3D:strips")
    drawn = np.array(strips[-1][1][0])
    np.testing.assert_allclose(drawn, [(align @ m)[:3, 3] for m in refs], atol=1e-5)


def test_no_loop_topics_nothing_drawn(saved, run):
    """A log without the loop-closure topics: no optimised trajectory, no loop edges, no error."""
    if run.has_optimized or run.loops:
        pytest.skip("this output has loop-closure topics")
    for path in saved:
        assert not path.startswith(("world/loops", "world/loop_pair", "log/loop")), path
    assert "world/trajectory/optimized" not in saved
    assert "world/map" not in saved


def test_stats_series_one_value_per_frame(saved, run):
    """One value per frame that has the figure: a frame tracked on the local map (or the first)
    ran no global registration, and its inliers and the like are null in ``/mireg/stats``."""
    stats = [f for f in run.frames if f.stats is not None]
    assert len(stats) == len(run.frames)
    registered = [f for f in stats if f.stats["num_inliers"] is not None]
    assert registered
    inliers = values(saved["stats/inliers"], "Scalars:scalars")
    assert [t for t, _ in inliers] == [f.log_time for f in registered]
    assert [v[0] for _, v in inliers] == [float(f.stats["num_inliers"]) for f in registered]
    for name, key in (("correspondences", "num_correspondences"), ("inlier_ratio", "inlier_ratio"),
                      ("hypotheses", "hypotheses"), ("fitness", "fitness"),
                      ("inlier_rmse_m", "inlier_rmse_m")):
        having = sum(f.stats[key] is not None for f in stats)
        assert saved[f"stats/{name}"]["rows"] == having, name
    for stage in STAGES:
        assert saved[f"stats/timings_ms/{stage}"]["rows"] == len(stats), stage
        assert "message_log_time" in saved[f"stats/timings_ms/{stage}"]["timelines"]


def test_failures_marked(saved, run):
    failed = [f for f in run.frames if f.stats and f.stats.get("success") is False]
    if failed:
        assert saved["world/failures"]["rows"] == len(failed)
        assert saved["log/failures"]["rows"] == len(failed)
        texts = [v for _, v in values(saved["log/failures"], "TextLog:text")]
        assert all(f"frame {f.index} " in str(text) for f, text in zip(failed, texts))
    else:
        assert "world/failures" not in saved
        assert "log/failures" not in saved


def test_frame_pair_recomputation(tmp_path, run):
    rrd = tmp_path / "pair.rrd"
    k = min(12, len(run.frames) - 1)
    proc = run_view(run.path, "--save", rrd, "--every", "1000", "--frame", str(k))
    assert proc.returncode == 0, proc.stderr
    saved = read_rrd(rrd)
    for path in ("world/pair/source", "world/pair/target", "world/pair/correspondences",
                 "log/pair", f"world/clouds/frame_{k:04d}"):
        assert saved[path]["rows"] == 1, path
    (t, strips), = values(saved["world/pair/correspondences"], "LineStrips3D:strips")
    assert t == run.frames[k].log_time
    assert len(strips) > 10  # consecutive fixture frames overlap: many inlier pairs
    assert all(len(s) == 2 for s in strips)


def test_report_writes_png(tmp_path, run):
    png = tmp_path / "report.png"
    proc = subprocess.run(
        [sys.executable, "-m", "mireg.viewer.report", str(run.path), "-o", str(png)],
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
    run = mireg.read_run(ros1_output_mcap(), load_clouds=True)
    assert run.has_reference
    assert len(run.frames) == 4
    for f in run.frames:
        assert f.points is not None and len(f.points) > 1000
        assert f.estimate is not None and f.reference is not None
    # The first estimate is the identity; the reference starts at the identity too.
    np.testing.assert_allclose(run.frames[0].estimate, np.eye(4), atol=1e-12)
    assert max(np.linalg.norm(f.estimate[:3, 3] - f.reference[:3, 3]) for f in run.frames) < 0.02
    same = mireg.read_run(ros1_output_mcap(), load_clouds=False, reference_topic="/mireg/pose")
    for f in same.frames:
        np.testing.assert_array_equal(f.reference, f.estimate)
    none = mireg.read_run(ros1_output_mcap(), load_clouds=False, reference_topic="/no/such/topic")
    assert not none.has_reference


# ------------------------------------------------------------------------------------------------
# loop closure: /mireg/pose_optimized, /mireg/loops, --loop, --map
# ------------------------------------------------------------------------------------------------


def with_loops(src: Path, dst: Path) -> tuple[Path, dict | None]:
    """``src``, which has loop-closure topics (``register`` writes them unless ``--no-loops``;
    tools/add_fake_loops.py adds made-up ones to an output without)."""
    run = mireg.read_run(src, load_clouds=False)
    if not run.has_optimized:
        pytest.skip(f"{src} has no loop-closure topics (registered with --no-loops?)")
    return src, None


@pytest.fixture(scope="module")
def loop_mcap(tmp_path_factory):
    return with_loops(output_mcap(), tmp_path_factory.mktemp("loops") / "loops.mcap")


@pytest.fixture(scope="module")
def loop_run(loop_mcap):
    return mireg.read_run(loop_mcap[0], load_clouds=False)


@pytest.fixture(scope="module")
def loop_saved(tmp_path_factory, loop_mcap):
    rrd = tmp_path_factory.mktemp("loops_view") / "loops.rrd"
    proc = run_view(loop_mcap[0], "--save", rrd, "--every", EVERY)
    assert proc.returncode == 0, proc.stderr
    return read_rrd(rrd)


def test_both_trajectories(loop_saved, loop_run):
    assert loop_run.has_optimized
    for name, attr in (("estimate", "estimate"), ("optimized", "optimized")):
        frames = [f for f in loop_run.frames if getattr(f, attr) is not None]
        strips = values(loop_saved[f"world/trajectory/{name}"], "LineStrips3D:strips")
        assert [t for t, _ in strips] == [f.log_time for f in frames], name
        last = np.array(strips[-1][1][0])
        expected = np.array([getattr(f, attr)[:3, 3] for f in frames])
        np.testing.assert_allclose(last, expected, atol=1e-5)
    colours = {name: values(loop_saved[f"world/trajectory/{name}"], "colors")[0][1]
               for name in ("estimate", "optimized")}
    assert colours["estimate"] != colours["optimized"]


def test_camera_follows_the_optimized_trajectory_by_default(loop_saved, loop_run):
    """--trajectory auto: clouds and camera are placed by /mireg/pose_optimized."""
    cams = values(loop_saved["world/camera"], "Transform3D:translation")
    assert [t for t, _ in cams] == [f.log_time for f in loop_run.frames]
    for (_, translation), f in zip(cams, loop_run.frames):
        np.testing.assert_allclose(translation[0], f.optimized[:3, 3], atol=1e-5)


def rgba(rgb) -> int:
    r, g, b = rgb
    return (r << 24) | (g << 16) | (b << 8) | 0xFF


def test_loop_edges_coloured_by_verdict_on_the_optimized_trajectory(loop_saved, loop_run):
    loops = loop_run.loops
    assert loops
    edges = sorted(p for p in loop_saved if p.startswith("world/loops/"))
    assert edges == [f"world/loops/loop_{loop.number:04d}" for loop in loops]
    for loop in loops:
        e = loop_saved[f"world/loops/loop_{loop.number:04d}"]
        (t, strips), = values(e, "LineStrips3D:strips")
        assert t == loop.log_time == loop.query.log_time
        segment = np.array(strips[0])
        np.testing.assert_allclose(segment, [loop.match.optimized[:3, 3],
                                             loop.query.optimized[:3, 3]], atol=1e-5)
        (_, colours), = values(e, "LineStrips3D:colors")
        assert colours == [rgba([0, 255, 0] if loop.accepted else [255, 0, 0])]
        (_, labels), = values(e, "LineStrips3D:labels")
        assert f"inliers {loop.data['inliers']}/" in labels[0]
        assert loop.data["verdict"] in labels[0]
        # the message's fields as AnyValues on the same entity (the selection panel)
        assert values(e, "verdict")[0][1] == [loop.data["verdict"]]
        if loop.data["reason"]:  # an accepted loop's empty reason is no value in the recording
            assert values(e, "reason")[0][1] == [loop.data["reason"]]
        assert values(e, "fitness")[0][1] == [pytest.approx(loop.data["fitness"])]
    texts = [v[0] for _, v in values(loop_saved["log/loops"], "TextLog:text")]
    assert len(texts) == len(loops)


LOOP_PAIR_COLUMN = {"world/loop_pair": "Transform3D:translation", "log/loop_pair": "TextLog:text",
                    "world/loop_pair/inlier_pairs": "LineStrips3D:strips"}


@pytest.mark.parametrize("verdict", ["accepted", "rejected"])
def test_loop_pair(tmp_path, loop_mcap, loop_run, verdict):
    loop = next((x for x in loop_run.loops if x.data["verdict"] == verdict), None)
    if loop is None:
        pytest.skip(f"no {verdict} loop in this output")
    rrd = tmp_path / "loop.rrd"
    proc = run_view(loop_mcap[0], "--save", rrd, "--every", 1000, "--loop", loop.number)
    assert proc.returncode == 0, proc.stderr
    saved = read_rrd(rrd)
    for path in ("world/loop_pair", "world/loop_pair/match", "world/loop_pair/query",
                 "world/loop_pair/inlier_pairs", "log/loop_pair"):
        assert saved[path]["rows"] == 1, path
        assert [t for t, _ in values(saved[path], LOOP_PAIR_COLUMN.get(path, "Points3D:positions"))
                ] == [loop.query.log_time], path
    (_, translation), = values(saved["world/loop_pair"], "Transform3D:translation")
    np.testing.assert_allclose(translation[0], loop.match.optimized[:3, 3], atol=1e-5)
    (_, query), = values(saved["world/loop_pair/query"], "Points3D:positions")
    (_, colours), = values(saved["world/loop_pair/query"], "Points3D:colors")
    assert len(query) > 100 and len(colours) == len(query)
    assert len(set(colours)) > 1  # coloured by nearest-neighbour distance
    if loop_mcap[1] is not None:
        # made-up loops: the query cloud is placed by the odometry, so the clouds overlap
        (_, pairs), = values(saved["world/loop_pair/inlier_pairs"], "LineStrips3D:strips")
        assert len(pairs) > 0.5 * len(query) if verdict == "accepted" else len(pairs) > 10


def test_loop_out_of_range_is_a_message(loop_mcap, loop_run):
    proc = run_view(loop_mcap[0], "--save", "/dev/null", "--loop", len(loop_run.loops))
    assert proc.returncode == 1 and "Traceback" not in proc.stderr
    assert f"the log has {len(loop_run.loops)} loop messages" in proc.stderr


def write_ply(path: Path, pts: np.ndarray, intensity: np.ndarray) -> None:
    """A binary little-endian PLY as `mireg map` writes it (float x y z intensity)."""
    header = (f"ply\nformat binary_little_endian 1.0\nelement vertex {len(pts)}\n"
              "property float x\nproperty float y\nproperty float z\nproperty float intensity\n"
              "end_header\n").encode()
    rows = np.concatenate([pts, intensity[:, None]], axis=1).astype("<f4")
    path.write_bytes(header + rows.tobytes())


@pytest.mark.parametrize("ext", ["ply", "npy", "pcd", "mireg"])
def test_map_file(tmp_path, loop_mcap, ext):
    rng = np.random.default_rng(3)
    pts = rng.uniform(-2, 2, size=(500, 3)).astype(np.float32)
    inten = rng.uniform(0, 100, size=500).astype(np.float32)
    if ext == "mireg":  # the real `mireg map`
        path = tmp_path / "map.ply"
        proc = subprocess.run([*mireg_command(), "map", str(loop_mcap[0]), "-o", str(path)],
                              capture_output=True, text=True, timeout=300)
        assert proc.returncode == 0, proc.stderr
        pts, _ = mapfile.load_map(path)
    else:
        path = tmp_path / f"map.{ext}"
        if ext == "ply":
            write_ply(path, pts, inten)
        elif ext == "npy":
            np.save(path, np.concatenate([pts, inten[:, None]], axis=1))
        else:
            path.write_bytes(b"VERSION 0.7\nFIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nCOUNT 1 1 1\n"
                             b"WIDTH 500\nHEIGHT 1\nPOINTS 500\nDATA binary\n" + pts.tobytes())
        got, got_i = mapfile.load_map(path)
        np.testing.assert_array_equal(got, pts.astype(np.float64))
        if ext != "pcd":
            np.testing.assert_array_equal(got_i, inten.astype(np.float64))
    rrd = tmp_path / "map.rrd"
    proc = run_view(loop_mcap[0], "--save", rrd, "--every", 1000, "--map", path)
    assert proc.returncode == 0, proc.stderr
    saved = read_rrd(rrd)
    (positions,) = [b.column("Points3D:positions").to_pylist()[0]
                    for b in saved["world/map"]["batches"]]
    assert len(positions) == len(pts)


def test_coarse_map_from_the_clouds(tmp_path, loop_mcap):
    rrd = tmp_path / "coarse.rrd"
    proc = run_view(loop_mcap[0], "--save", rrd, "--every", 1000, "--map-voxel", 0.1,
                    "--max-points", 2000)
    assert proc.returncode == 0, proc.stderr
    saved = read_rrd(rrd)
    (positions,) = [b.column("Points3D:positions").to_pylist()[0]
                    for b in saved["world/map"]["batches"]]
    keys = np.floor(np.array(positions) / 0.1).astype(int)
    assert len(positions) > 100 and len(np.unique(keys, axis=0)) == len(positions)


def test_bad_map_file_is_a_message(tmp_path, loop_mcap):
    bad = tmp_path / "map.ply"
    bad.write_bytes(b"not a ply")
    proc = run_view(loop_mcap[0], "--save", tmp_path / "x.rrd", "--map", bad)
    assert proc.returncode == 1 and "Traceback" not in proc.stderr and "--map" in proc.stderr


def test_run_topics_follow_the_pose_namespace():
    topics = mireg.run.run_topics({"pose_topic": "/mireg_2/pose", "stats_topic": "/mireg_2/stats"})
    assert topics["optimized"] == "/mireg_2/pose_optimized"
    assert topics["loops"] == "/mireg_2/loops"
    named = mireg.run.run_topics({"pose_topic": "/mireg_2/pose", "loops_topic": "/x/loops"})
    assert named["loops"] == "/x/loops"


def test_ros1_output_with_loops():
    """The made-up topics on a ROS 1 output: ROS 1 optimised poses decode, loops resolve."""
    src = ros1_output_mcap()
    import tempfile

    with tempfile.TemporaryDirectory() as tmp:
        path, _ = with_loops(src, Path(tmp, "ros1_loops.mcap"))
        run = mireg.read_run(path, load_clouds=False)
        assert run.has_optimized
        assert all(f.optimized is not None for f in run.frames)
        assert all(loop.query is not None and loop.match is not None for loop in run.loops)
        if not run.loops:  # a real output of a log too short for loop candidates
            return
        proc = run_view(path, "--save", Path(tmp, "r.rrd"), "--loop", 0)
        assert proc.returncode == 0, proc.stderr


def test_wrong_inputs_are_a_message_saying_what_to_run(tmp_path):
    """A raw log, a folder, a text file: the viewer and the report name the input and say to run
    `mireg register` first, without a traceback."""
    text = tmp_path / "notes.bag"
    text.write_text("not a log")
    for bad in (REPO / "fixtures/bags/icl4_lz4.bag", REPO / "fixtures/icl_livingroom1.mcap",
                REPO / "fixtures/bags/icl4_mcap", text):
        for cmd in ([sys.executable, "-m", "mireg", "view", str(bad), "--save",
                     str(tmp_path / "x.rrd")],
                    [sys.executable, "-m", "mireg.viewer.report", str(bad), "-o",
                     str(tmp_path / "x.png")]):
            proc = subprocess.run(cmd, capture_output=True, text=True, timeout=120)
            assert proc.returncode == 1, (cmd, proc.stderr)
            assert "Traceback" not in proc.stderr, proc.stderr
            assert str(bad) in proc.stderr and "mireg register" in proc.stderr, proc.stderr
    assert not (tmp_path / "x.rrd").exists()


def livox_expected() -> list[np.ndarray]:
    """The first frames of fixtures/livox as rosbags decoded them (tools/make_livox_log.py's
    write_expected): x, y, z per point."""
    data = (REPO / "fixtures/livox/icl_livox_expected.bin").read_bytes()
    magic = b"LIVOXEXP1\n"
    assert data.startswith(magic)
    at = len(magic)
    (frames,) = np.frombuffer(data, "<u4", 1, at)
    at += 4
    point = np.dtype([("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("offset_time", "<u4"),
                      ("reflectivity", "u1"), ("tag", "u1"), ("line", "u1"), ("pad", "u1")])
    out = []
    for _ in range(frames):
        at += 16
        (n,) = np.frombuffer(data, "<u4", 1, at)
        at += 4
        pts = np.frombuffer(data, point, n, at)
        at += n * point.itemsize
        out.append(np.stack([pts["x"], pts["y"], pts["z"]], axis=1).astype(np.float64))
    return out


@pytest.mark.parametrize("log", ["icl_livox_ros2", "icl_livox.bag"])
def test_livox_outputs_show_the_points_register_read(tmp_path, log):
    """A registered Livox CustomMsg log (ROS 2 and ROS 1): the run finds the cloud topic and
    each frame holds the points `register` read (mireg.read_clouds of the input), which are
    those rosbags decoded, minus the tags register drops."""
    out = tmp_path / "livox.mcap"
    subprocess.run([*mireg_command(), "register", str(REPO / "fixtures/livox" / log), "-o",
                    str(out), "--quiet"], check=True)
    run = mireg.read_run(out, load_clouds=True)
    assert run.cloud_topic == "/livox/lidar"
    assert len(run.frames) == 10
    clouds = list(mireg.read_clouds(REPO / "fixtures/livox" / log))
    for frame, (_, want, _), sent in zip(run.frames, clouds, livox_expected()):
        np.testing.assert_array_equal(frame.points, want)
        assert 0 < len(frame.points) <= len(sent)
        assert frame.estimate is not None
