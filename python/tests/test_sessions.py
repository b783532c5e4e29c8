"""``mireg.merge`` and ``mireg.localize`` against the ``mireg`` command on the same inputs (the
merged and localised poses bit for bit, read with the official ``mcap`` reader) and their errors.

Needs the package installed and the CLI built (``MIREG_BIN``); tests skip without it.
"""

from __future__ import annotations

import json
import subprocess
import sys

import pytest
from test_mireg import FIXTURES, cli

import mireg


def messages(path, topic):
    mcap_reader = pytest.importorskip("mcap.reader")
    with open(path, "rb") as f:
        return [m.data for _, _, m in mcap_reader.make_reader(f).iter_messages(topics=[topic])]


@pytest.fixture(scope="module")
def sessions(tmp_path_factory):
    d = tmp_path_factory.mktemp("sessions")
    log = FIXTURES / "icl_livingroom1.mcap"
    a, b = d / "a.mcap", d / "b.mcap"
    mireg.register_log(log, a, end=30, copy_window=True)
    mireg.register_log(log, b, start=30, copy_window=True)
    return a, b


def test_merge_is_the_cli(tmp_path, sessions):
    a, b = sessions
    report = mireg.merge([a, b], tmp_path / "py")
    subprocess.run([str(cli()), "merge", str(a), str(b), "-o", str(tmp_path / "cli")],
                   check=True, capture_output=True)
    want = json.loads((tmp_path / "cli" / "merge_report.json").read_text())
    assert report["groups"] == want["groups"] == 1
    assert [p["joined"] for p in report["pairs"]] == [True]
    for name in ("a.mcap", "b.mcap"):
        assert (messages(tmp_path / "py" / name, "/mireg/pose_merged")
                == messages(tmp_path / "cli" / name, "/mireg/pose_merged"))
    with pytest.raises(ValueError, match="at least two"):
        mireg.merge([a], tmp_path / "one")


def test_merge_from_a_pair_linked_apart_is_the_merge(tmp_path, sessions):
    a, b = sessions
    links = tmp_path / "links"
    subprocess.run([str(cli()), "merge", str(a), str(b), "--pair", "0,1", "--links", str(links)],
                   check=True, capture_output=True)
    assert (links / "pair_0_1.json").is_file()
    mireg.merge([a, b], tmp_path / "files", links_dir=links)
    mireg.merge([a, b], tmp_path / "whole")
    for name in ("a.mcap", "b.mcap"):
        assert (messages(tmp_path / "files" / name, "/mireg/pose_merged")
                == messages(tmp_path / "whole" / name, "/mireg/pose_merged"))
    # Another seed is other links: the file is refused, named.
    with pytest.raises(ValueError, match="pair_0_1.json"):
        mireg.merge([a, b], tmp_path / "seed", seed=1, links_dir=links)


def test_localize_is_the_cli(tmp_path, sessions):
    _, b = sessions
    log = FIXTURES / "icl_livingroom1.mcap"
    summary = mireg.localize(log, b, tmp_path / "py.mcap")
    subprocess.run([str(cli()), "localize", str(log), "--map", str(b), "-o",
                    str(tmp_path / "cli.mcap")], check=True, capture_output=True)
    assert summary["frames"] == 71 and summary["lost"] == 0
    assert messages(tmp_path / "py.mcap", "/mireg/pose") == messages(tmp_path / "cli.mcap",
                                                                       "/mireg/pose")
    with pytest.raises(ValueError, match="register"):
        mireg.localize(log, log, tmp_path / "x.mcap")
    assert not summary["log_loops_closed"]
    with pytest.raises(ValueError, match="log_loops"):
        mireg.localize(log, b, tmp_path / "y.mcap", log_loops="sometimes")
    with pytest.raises(ValueError, match="map_reach_m"):
        mireg.localize(log, b, tmp_path / "z.mcap", map_reach_m=0.0)
    assert not (tmp_path / "z.mcap").exists()


def test_view_of_a_merge_draws_sessions_and_links(tmp_path, sessions):
    pytest.importorskip("rerun", reason="the viewer extra is not installed")
    from rerun.chunk import RrdReader

    a, b = sessions
    report = mireg.merge([a, b], tmp_path / "merged")
    rrd = tmp_path / "m.rrd"
    p = subprocess.run([sys.executable, "-m", "mireg.viewer", str(tmp_path / "merged"), "--save",
                        str(rrd)], capture_output=True, text=True)
    assert p.returncode == 0, p.stderr
    entities = {c.entity_path.lstrip("/") for c in RrdReader(rrd).stream()}
    assert {"world/sessions/a", "world/sessions/b"} <= entities
    links = [e for e in entities if e.startswith("world/session_links/")]
    # every candidate tried, once (each is on both sessions' outputs)
    tried = sum(p["appearance_candidates"] + p["place_candidates"] for p in report["pairs"])
    assert len(links) == tried


def test_view_of_a_localized_log_draws_its_links(tmp_path, sessions):
    pytest.importorskip("rerun", reason="the viewer extra is not installed")
    from rerun.chunk import RrdReader

    _, b = sessions
    out = tmp_path / "loc.mcap"
    summary = mireg.localize(FIXTURES / "icl_livingroom1.mcap", b, out)
    links = [json.loads(m) for m in messages(out, summary["session_links_topic"])]
    registered = [d for d in links if d["a_from_b"] is not None]
    assert any(d["verdict"] == "accepted" for d in registered)
    rrd = tmp_path / "l.rrd"
    p = subprocess.run([sys.executable, "-m", "mireg.viewer", str(out), "--save", str(rrd)],
                       capture_output=True, text=True)
    assert p.returncode == 0, p.stderr
    entities = {c.entity_path.lstrip("/") for c in RrdReader(rrd).stream()}
    drawn = [e for e in entities if e.startswith("world/localized/links/")]
    # every frame of the fixture is placed, so every registered link is drawn, once
    assert len(drawn) == len(registered)


def test_a_links_map_frame_is_placed_by_the_inverse_of_its_registration():
    np = pytest.importorskip("numpy")
    from mireg.viewer.sessions import map_frame_position

    def iso(yaw, t):
        c, s = np.cos(yaw), np.sin(yaw)
        m = np.eye(4)
        m[:3, :3] = [[c, -s, 0], [s, c, 0], [0, 0, 1]]
        m[:3, 3] = t
        return m

    world_from_b, a_from_b = iso(0.3, [1.0, 2.0, 0.5]), iso(-1.1, [0.4, -0.2, 0.1])
    half = -1.1 / 2
    pose = {"translation": a_from_b[:3, 3].tolist(),
            "rotation_xyzw": [0.0, 0.0, np.sin(half), np.cos(half)]}
    want = (world_from_b @ np.linalg.inv(a_from_b))[:3, 3]
    assert np.allclose(map_frame_position(world_from_b, pose), want)
