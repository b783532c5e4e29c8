"""Many logs, one map in Rerun: the sessions of a ``mireg merge`` folder or a ``mireg localize``
output (``mireg view merged/``, ``mireg view today.localized.mcap``).

- ``world/sessions/NAME``: each session's merged trajectory (``/mireg/pose_merged``) in a colour
  of its own, its frames as points; sessions of different groups are in different frames and
  drawn where their own group puts them.
- ``world/session_links/link_NNNN``: every link tried between sessions (``/mireg/session_links``),
  a segment between its two frames, green if accepted, red if rejected, the message's fields on
  hover.
- a localised log: ``world/localized``, its frames coloured by status (localized green, tracking
  blue, outside_map orange; lost frames have no pose), and ``world/localized/links/link_NNNN``:
  every link tried against the map whose registration ran, a segment from the log's frame to
  where that registration puts the map's keyframe or tile (green if accepted, red if rejected,
  the reason as its label and the message's fields on hover).
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from .. import _mireg
from ..run import read_trajectory
from .geometry import quaternion_matrix

PALETTE = [[31, 119, 180], [255, 127, 14], [148, 103, 189], [23, 190, 207], [188, 189, 34],
           [227, 119, 194], [140, 86, 75], [127, 127, 127]]
ACCEPTED, REJECTED = [0, 200, 0], [220, 0, 0]
STATUS_COLOURS = {"localized": [0, 200, 0], "tracking": [31, 119, 180],
                  "outside_map": [255, 127, 14]}


def is_merge(path: Path) -> bool:
    return path.is_dir() and (path / "merge_report.json").is_file()


def metadata(path: Path) -> dict:
    records, _ = _mireg.read_json_topics(str(path), [])
    return {name: entries for name, entries in records}


def is_localized(path: Path) -> bool:
    """Whether ``path`` is a ``mireg localize`` output; anything unreadable is not (the register
    viewer then says what the input is and what to run)."""
    try:
        return path.is_file() and "mireg_localize" in metadata(path)
    except (OSError, ValueError):
        return False


def log_merge(rr, folder: Path) -> dict:
    """Logs the sessions and links of a merge folder; returns counts for the summary line."""
    report = json.loads((folder / "merge_report.json").read_text())
    positions = {}
    for k, s in enumerate(report["sessions"]):
        meta = metadata(Path(s["output"]))["mireg_merge"]
        stamps, poses = read_trajectory(s["output"], meta["merged_pose_topic"])
        xyz = poses[:, :3, 3]
        positions[s["name"]] = dict(zip(stamps.tolist(), xyz))
        colour = PALETTE[k % len(PALETTE)]
        rr.log(f"world/sessions/{s['name']}",
               rr.LineStrips3D([xyz], colors=[colour]), static=True)
        rr.log(f"world/sessions/{s['name']}/frames", rr.Points3D(xyz, colors=[colour]),
               static=True)
    seen, n = set(), {"accepted": 0, "rejected": 0}
    for s in report["sessions"]:
        topic = metadata(Path(s["output"]))["mireg_merge"]["session_links_topic"]
        _, messages = _mireg.read_json_topics(s["output"], [topic])
        for _, _, text in messages:
            d = json.loads(text)
            key = (d["session_a"], d["stamp_a_ns"], d["session_b"], d["stamp_b_ns"], d["found_by"])
            if key in seen:
                continue
            seen.add(key)
            a = positions.get(d["session_a"], {}).get(d["stamp_a_ns"])
            b = positions.get(d["session_b"], {}).get(d["stamp_b_ns"])
            if a is None or b is None:
                continue
            accepted = d["verdict"] == "accepted"
            n["accepted" if accepted else "rejected"] += 1
            fields = {k: v for k, v in d.items() if isinstance(v, (int, float, str))}
            rr.log(f"world/session_links/link_{len(seen) - 1:04d}",
                   rr.LineStrips3D([np.stack([a, b])], colors=[ACCEPTED if accepted else REJECTED],
                                   labels=[f"{d['verdict']}: {d['reason']}" if d["reason"]
                                           else d["verdict"]]),
                   rr.AnyValues(**fields), static=True)
    return {"sessions": len(report["sessions"]), "groups": report["groups"], **n}


def log_localized(rr, path: Path) -> dict:
    """Logs a localised log's frames coloured by status; returns the count per status."""
    meta = metadata(path)["mireg_localize"]
    stamps, poses = read_trajectory(path, meta["pose_topic"])
    _, messages = _mireg.read_json_topics(str(path), [meta["localization_topic"]])
    status = {}
    for _, _, text in messages:
        d = json.loads(text)
        status[d["stamp_ns"]] = d["status"]
    counts = {}
    for v in status.values():
        counts[v] = counts.get(v, 0) + 1
    if len(stamps):
        colours = [STATUS_COLOURS.get(status.get(s, ""), [127, 127, 127]) for s in stamps.tolist()]
        xyz = poses[:, :3, 3]
        rr.log("world/localized", rr.LineStrips3D([xyz], colors=[[127, 127, 127]]), static=True)
        rr.log("world/localized/frames", rr.Points3D(xyz, colors=colours), static=True)
    topic = meta.get("session_links_topic")
    if topic:
        counts["links_drawn"] = log_localized_links(rr, path, topic, dict(zip(stamps.tolist(), poses)))
    return counts


def map_frame_position(world_from_b: np.ndarray, a_from_b: dict) -> np.ndarray:
    """Where a link puts its map frame's origin: ``world_from_b · a_from_b⁻¹ · 0``."""
    r = quaternion_matrix(a_from_b["rotation_xyzw"])[:3, :3]
    in_b = -r.T @ np.asarray(a_from_b["translation"])
    return world_from_b[:3, :3] @ in_b + world_from_b[:3, 3]


def log_localized_links(rr, path: Path, topic: str, placed: dict) -> int:
    """Logs each link of ``topic`` whose registration ran and whose log frame was placed;
    returns how many."""
    _, messages = _mireg.read_json_topics(str(path), [topic])
    drawn = 0
    for _, _, text in messages:
        d = json.loads(text)
        world_from_b = placed.get(d["stamp_b_ns"])
        if d["a_from_b"] is None or world_from_b is None:
            continue
        a = map_frame_position(world_from_b, d["a_from_b"])
        accepted = d["verdict"] == "accepted"
        fields = {k: v for k, v in d.items() if isinstance(v, (int, float, str))}
        rr.log(f"world/localized/links/link_{drawn:04d}",
               rr.LineStrips3D([np.stack([world_from_b[:3, 3], a])],
                               colors=[ACCEPTED if accepted else REJECTED],
                               labels=[f"{d['verdict']}: {d['reason']}" if d["reason"]
                                       else d["verdict"]]),
               rr.AnyValues(**fields), static=True)
        drawn += 1
    return drawn


def view(path: Path, save: Path | None) -> int:
    """``mireg view`` of a merge folder or a localised log: a recording saved to ``save``, or
    shown in the viewer."""
    import subprocess
    import tempfile

    import rerun as rr

    from .screenshot import rerun_binary

    rr.init("mireg_view", spawn=False)
    counts = log_merge(rr, path) if is_merge(path) else log_localized(rr, path)
    tmp = None
    if save is None:
        tmp = tempfile.TemporaryDirectory(prefix="mireg_view_")
        rrd = Path(tmp.name, "view.rrd")
    else:
        save.parent.mkdir(parents=True, exist_ok=True)
        rrd = save
    rr.save(rrd)
    print(f"{path}: {counts}")
    try:
        if save is None:
            subprocess.run([rerun_binary(), str(rrd), "--bind", "127.0.0.1"], check=False)
        else:
            print(f"wrote {rrd}")
    finally:
        if tmp is not None:
            tmp.cleanup()
    return 0
