"""Shared bits of the Rerun logging: timelines, the world's up direction, colours."""

from __future__ import annotations

import numpy as np

TIMELINE = "message_log_time"


def set_frame_time(rr, frame) -> None:
    """Put the following logs at ``frame``'s log time and index."""
    rr.set_time(TIMELINE, timestamp=np.datetime64(frame.log_time, "ns"))
    rr.set_time("frame", sequence=frame.index)


def up_vector(frame_id: str) -> np.ndarray:
    """'Up' in the world (= first sensor) frame: −y for optical frames (y down), else +z (REP 103)."""
    return np.array([0.0, -1.0, 0.0]) if frame_id.endswith("optical_frame") else np.array([0, 0, 1.0])


def colour_map(values: np.ndarray, lo: float, hi: float) -> np.ndarray:
    """uint8 RGB colours of ``values`` on matplotlib's turbo map between lo and hi."""
    from matplotlib import colormaps

    v = np.clip((values - lo) / max(hi - lo, 1e-9), 0.0, 1.0)
    return (colormaps["turbo"](v)[:, :3] * 255).astype(np.uint8)


def value_range(values: np.ndarray) -> tuple[float, float]:
    """The 2nd and 98th percentile (the colour range of a cloud), (0, 1) when empty."""
    if len(values) == 0:
        return 0.0, 1.0
    lo, hi = np.percentile(values, [2, 98])
    return float(lo), float(hi)
