"""The Python package against oracles: the ``mireg`` command on the same inputs (bit for bit),
known transforms forward and inverse, and the official ``mcap`` reader for ``read_clouds``.

Needs the package installed (``pip install ./python``) and the CLI built (``MIREG_BIN``, default
``target/release/mireg``); tests that need the CLI skip without it.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import mireg

REPO = Path(__file__).resolve().parents[2]
FIXTURES = REPO / "fixtures"


def cli() -> Path:
    b = Path(os.environ.get("MIREG_BIN", REPO / "target/release/mireg"))
    if not b.is_file():
        pytest.skip(f"no mireg binary at {b} (set MIREG_BIN)")
    return b


def read_ply(path: Path) -> np.ndarray:
    """x, y, z of a binary little-endian PLY whose vertices are three float32s."""
    data = path.read_bytes()
    end = data.index(b"end_header\n") + len(b"end_header\n")
    header = data[:end].decode()
    n = int(next(line.split()[2] for line in header.splitlines()
                 if line.startswith("element vertex")))
    assert "property float x\nproperty float y\nproperty float z\nend_header" in header
    return np.frombuffer(data, "<f4", 3 * n, end).reshape(n, 3)


@pytest.fixture(scope="module")
def icl_pair():
    return (read_ply(FIXTURES / "icl_nuim/rgbd5_00004.ply"),
            read_ply(FIXTURES / "icl_nuim/rgbd5_00000.ply"))


def test_pair_is_the_cli_bit_for_bit(tmp_path, icl_pair):
    source, target = icl_pair
    for seed in (0, 3):
        got = mireg.register_pair(source, target, voxel=0.05, seed=seed)
        cfg = tmp_path / "c.toml"
        cfg.write_text(f"seed = {seed}\n")
        run = subprocess.run([str(cli()), "pair", str(FIXTURES / "icl_nuim/rgbd5_00004.ply"),
                              str(FIXTURES / "icl_nuim/rgbd5_00000.ply"), "--voxel", "0.05",
                              "--config", str(cfg), "--json"],
                             capture_output=True, text=True, check=True)
        want = json.loads(run.stdout)
        assert got.success and want["success"]
        # JSON numbers round-trip f64 exactly: the same bits.
        assert got.raw["target_from_source"] == want["target_from_source"]
        for key in ("num_inliers", "num_correspondences", "hypotheses", "fitness",
                    "inlier_rmse_m", "best_found_at"):
            assert got.raw[key] == want[key], key
        assert np.array_equal(got.transformation, np.array(want["target_from_source"]))


def test_the_package_command_is_the_cli(tmp_path):
    """`mireg` of the package (`python -m mireg`, the console script's code) runs the CLI: the
    same --version, the same pair result, the same exit status and message for a bad flag or a
    missing file (2)."""
    package = [sys.executable, "-m", "mireg"]

    def both(*args):
        return [subprocess.run([*cmd, *map(str, args)], capture_output=True, text=True)
                for cmd in (package, [str(cli())])]

    got, want = both("--version")
    assert got.returncode == want.returncode == 0 and got.stdout == want.stdout
    src, tgt = FIXTURES / "icl_nuim/rgbd5_00004.ply", FIXTURES / "icl_nuim/rgbd5_00000.ply"
    got, want = both("pair", src, tgt, "--voxel", "0.05", "--json")
    assert got.returncode == want.returncode == 0, got.stderr
    a, b = json.loads(got.stdout), json.loads(want.stdout)
    assert a["target_from_source"] == b["target_from_source"]
    for args in (("pair", src, tgt, "--no-such-flag"), ("evaluate", tmp_path / "missing.mcap")):
        got, want = both(*args)
        assert got.returncode == want.returncode == 2, got.stderr
        assert got.stderr.splitlines()[0] == want.stderr.splitlines()[0]  # usage names argv[0]


def rot(axis, deg):
    axis = np.asarray(axis, float) / np.linalg.norm(axis)
    k = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    a = np.radians(deg)
    return np.eye(3) + np.sin(a) * k + (1 - np.cos(a)) * k @ k


def test_known_transform_forward_and_inverse(icl_pair):
    cloud = icl_pair[1].astype(np.float64)
    t = np.eye(4)
    t[:3, :3] = rot([0.3, 1.0, 0.2], 25.0)
    t[:3, 3] = [0.4, -0.2, 0.3]
    moved = cloud @ t[:3, :3].T + t[:3, 3]
    # source = moved, target = cloud: target_from_source = inverse of t; and the other way.
    for source, target, want in ((moved, cloud, np.linalg.inv(t)), (cloud, moved, t)):
        r = mireg.register_pair(source, target, voxel=0.05, seed=1)
        assert r.success, r.failure_reason
        err = np.linalg.inv(want) @ r.transformation
        angle = np.degrees(np.arccos(np.clip((np.trace(err[:3, :3]) - 1) / 2, -1, 1)))
        assert angle < 0.1 and np.linalg.norm(err[:3, 3]) < 0.005, (angle, err[:3, 3])


def test_float32_and_float64_give_the_same_result(icl_pair):
    source, target = icl_pair
    a = mireg.register_pair(source, target, seed=2)
    b = mireg.register_pair(source.astype(np.float64), target.astype(np.float64), seed=2)
    assert np.array_equal(a.transformation, b.transformation)


def test_bad_arrays_and_config_name_the_argument():
    good = np.zeros((10, 3))
    with pytest.raises(ValueError, match="source: expected an \\(N, 3\\) array"):
        mireg.register_pair(np.zeros((10, 2)), good)
    with pytest.raises(ValueError, match="target: expected an \\(N, 3\\) array"):
        mireg.register_pair(good, np.zeros(30))
    with pytest.raises(TypeError, match="source: expected a float32 or float64 array"):
        mireg.register_pair(np.zeros((10, 3), dtype=np.int32), good)
    with pytest.raises(TypeError, match="unknown configuration key 'voxle'"):
        mireg.register_pair(good, good, voxle=0.1)
    with pytest.raises(ValueError, match="configuration"):
        mireg.register_pair(good, good, max_hypotheses="many")


def test_read_clouds_matches_the_official_mcap_reader():
    mcap_reader = pytest.importorskip("mcap.reader")
    ros2 = pytest.importorskip("mcap_ros2.decoder")
    path = FIXTURES / "icl_livingroom1.mcap"
    want = []
    with open(path, "rb") as f:
        reader = mcap_reader.make_reader(f, decoder_factories=[ros2.DecoderFactory()])
        for _, channel, _, msg in reader.iter_decoded_messages(topics=["/camera/depth/points"]):
            xyz = np.frombuffer(bytes(msg.data), "<f4").reshape(-1, msg.point_step // 4)[:, :3]
            stamp = msg.header.stamp.sec * 10**9 + msg.header.stamp.nanosec
            want.append((stamp, xyz[np.isfinite(xyz).all(axis=1)].astype(np.float64)))
    got = list(mireg.read_clouds(path))
    assert len(got) == len(want) == 71
    for (stamp, points, fields), (w_stamp, w_points) in zip(got, want):
        assert stamp == w_stamp
        assert np.array_equal(points, w_points)
        assert fields == {}


def test_read_clouds_of_a_livox_bag_has_intensity_and_times():
    clouds = list(mireg.read_clouds(FIXTURES / "livox/icl_livox.bag"))
    assert len(clouds) == 10
    stamp, points, fields = clouds[0]
    assert points.shape[1] == 3 and len(points) > 1000
    assert set(fields) == {"intensity", "time"}
    assert len(fields["time"]) == len(points) and fields["time"].min() >= 0
    assert fields["time"].max() < 0.1


def test_read_clouds_errors_and_early_stop(tmp_path):
    with pytest.raises(ValueError, match="nothing.mcap"):
        mireg.read_clouds(tmp_path / "nothing.mcap")
    reader = mireg.read_clouds(FIXTURES / "icl_livingroom1.mcap")
    assert reader.topic == "/camera/depth/points"
    next(reader)
    reader.close()  # stops the reading thread; nothing more comes
    assert next(reader, None) is None


def test_register_log_is_the_cli(tmp_path):
    out_py, out_cli = tmp_path / "py.mcap", tmp_path / "cli.mcap"
    summary = mireg.register_log(FIXTURES / "bags/icl4_lz4.bag", out_py, no_loops=True,
                                 voxel=0.05)
    run = subprocess.run([str(cli()), "register", str(FIXTURES / "bags/icl4_lz4.bag"), "-o",
                          str(out_cli), "--no-loops", "--voxel", "0.05", "--json"],
                         capture_output=True, text=True, check=True)
    want = json.loads(run.stdout)
    assert summary["frames"] == want["frames"] == 4
    assert summary["reference"] == want["reference"]
    # The poses, bit for bit: the /mireg/pose messages' bytes.
    mcap_reader = pytest.importorskip("mcap.reader")

    def poses(p):
        with open(p, "rb") as f:
            return [m.data for _, _, m in mcap_reader.make_reader(f).iter_messages(
                topics=["/mireg/pose"])]
    assert poses(out_py) == poses(out_cli)
    calls = []
    mireg.register_log(FIXTURES / "bags/icl4_lz4.bag", tmp_path / "p.mcap", no_loops=True,
                       progress=lambda done, total: calls.append((done, total)))
    assert calls == [(1, 4), (2, 4), (3, 4), (4, 4)]
    # An unknown name is a TypeError, as in register_pair and Odometry; a bad value a ValueError.
    with pytest.raises(TypeError, match="unknown configuration key 'no_such_flag'"):
        mireg.register_log(FIXTURES / "bags/icl4_lz4.bag", tmp_path / "x.mcap", no_such_flag=1)
    with pytest.raises(ValueError, match="settings"):
        mireg.register_log(FIXTURES / "bags/icl4_lz4.bag", tmp_path / "x.mcap", voxel="big")


def pose_matrices(path: Path, topic: str = "/mireg/pose") -> list[np.ndarray]:
    mcap_reader = pytest.importorskip("mcap.reader")
    ros2 = pytest.importorskip("mcap_ros2.decoder")
    out = []
    with open(path, "rb") as f:
        reader = mcap_reader.make_reader(f, decoder_factories=[ros2.DecoderFactory()])
        for _, _, _, msg in reader.iter_decoded_messages(topics=[topic]):
            q, t = msg.pose.orientation, msg.pose.position
            x, y, z, w = q.x, q.y, q.z, q.w
            m = np.eye(4)
            m[:3, :3] = [[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                         [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                         [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]]
            m[:3, 3] = [t.x, t.y, t.z]
            out.append(m)
    return out


@pytest.mark.parametrize("log", ["icl_livingroom1.mcap", "livox/icl_livox_ros2"])
def test_odometry_gives_register_s_poses(tmp_path, log):
    """Odometry fed read_clouds' clouds (with their times: the Livox log is deskewed) gives the
    poses mireg register writes (--no-loops), to the last bits the pose message keeps."""
    out = tmp_path / "out.mcap"
    mireg.register_log(FIXTURES / log, out, no_loops=True)
    want = pose_matrices(out)
    odometry = mireg.Odometry()
    for stamp, points, fields in mireg.read_clouds(FIXTURES / log):
        odometry.register_frame(points, fields.get("time"), stamp)
    assert len(odometry.poses) == len(want) > 5
    for got, w in zip(odometry.poses, want):
        np.testing.assert_allclose(got, w, rtol=0, atol=1e-12)
    assert all(e["success"] for e in odometry.estimates)
    assert odometry.config["pair"]["voxel_size_m"] != default_config()["voxel_size_m"]


def default_config():
    return mireg.default_config()


def test_odometry_bad_input_names_the_argument():
    odometry = mireg.Odometry(voxel=0.05)
    with pytest.raises(ValueError, match="points: expected an \\(N, 3\\) array"):
        odometry.register_frame(np.zeros((5, 4)))
    with pytest.raises(ValueError, match="timestamps: 3 values for 5 points"):
        odometry.register_frame(np.zeros((5, 3)), np.zeros(3))
    with pytest.raises(TypeError, match="unknown configuration key 'min_inlier'"):
        mireg.Odometry(min_inlier=3)
