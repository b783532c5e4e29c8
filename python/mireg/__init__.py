"""mireg on numpy arrays: MI-RANSAC pair registration, whole-log registration, a fast cloud
reader for MCAP files, ROS 1 bags and ROS 2 bag directories, and the reader of a registered run
(``read_run``, ``read_trajectory``). The package also installs the ``mireg`` command (the Rust
command line, ``python -m mireg``) and, with the ``viewer`` extra, ``mireg view``.

Every function runs the same Rust code as the ``mireg`` command, with the GIL released, and gives
its results bit for bit for the same configuration and seed. Units are metres and seconds.
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass, field
from typing import Any, Callable, Iterator, Optional, Union

import numpy as np

from . import _mireg
from .run import Run, read_run, read_trajectory

__all__ = ["Registration", "register_pair", "read_clouds", "register_log", "default_config",
           "Odometry", "Run", "read_run", "read_trajectory", "merge", "localize"]
__version__ = _mireg.__version__

PathLike = Union[str, "os.PathLike[str]"]


def default_config() -> dict:
    """The pair configuration's defaults (docs/CONFIG.md), as ``register_pair`` starts from."""
    return json.loads(_mireg.default_pair_config())


def _merge(base: dict, overrides: dict, where: str = "") -> dict:
    out = dict(base)
    for key, value in overrides.items():
        if key not in base:
            raise TypeError(f"unknown configuration key {where}{key!r} "
                            f"(known: {', '.join(sorted(base))})")
        if isinstance(base[key], dict) and isinstance(value, dict):
            # A table of another kind (e.g. sampler kind "uniform") replaces the default's.
            if value.get("kind", base[key].get("kind")) != base[key].get("kind"):
                out[key] = value
            else:
                out[key] = _merge(base[key], value, f"{where}{key}.")
        else:
            out[key] = value
    return out


def _points(a: Any, name: str) -> np.ndarray:
    """An (N, 3) C-contiguous float64 view of ``a`` (no copy when it already is one)."""
    arr = np.asarray(a)
    if arr.dtype not in (np.float32, np.float64):
        raise TypeError(f"{name}: expected a float32 or float64 array, got dtype {arr.dtype}")
    if arr.ndim != 2 or arr.shape[1] != 3:
        raise ValueError(f"{name}: expected an (N, 3) array of points, got shape {arr.shape}")
    return np.ascontiguousarray(arr, dtype=np.float64)


@dataclass(frozen=True)
class Registration:
    """The outcome of :func:`register_pair` (the fields of ``mireg pair --json``)."""

    transformation: np.ndarray
    """4×4 ``target_from_source``: maps source points onto the target (identity on failure)."""
    ransac_transformation: np.ndarray
    """4×4 MI-RANSAC estimate before ICP."""
    success: bool
    failure_reason: Optional[str]
    """``None`` on success, else e.g. ``"too_few_inliers"``."""
    inliers: int
    """RANSAC inliers among the correspondences."""
    correspondences: int
    fitness: float
    """Fraction of source points within the ICP distance of the target after alignment."""
    inlier_rmse: float
    """RMSE of those distances, metres."""
    hypotheses: int
    timings: dict
    """Seconds per stage (``total`` is the call's wall time)."""
    raw: dict = field(repr=False)
    """The whole JSON object, as ``mireg pair --json`` prints it."""


def register_pair(source: Any, target: Any, voxel: Optional[float] = None, seed: int = 0,
                  **config: Any) -> Registration:
    """Register ``source`` onto ``target`` with MI-RANSAC, then ICP.

    ``source``, ``target``: ``(N, 3)`` float32 or float64 arrays, metres (float64 C-contiguous
    arrays are used without a copy). ``voxel``: the voxel size in metres (default 0.05, as
    ``mireg pair``); normal, feature, inlier and ICP radii derive from it. ``seed``: the RNG
    seed (default 0). Other keyword arguments are fields of the pair configuration
    (docs/CONFIG.md), e.g. ``icp=False``, ``max_hypotheses=50000`` or
    ``sampler={"kind": "uniform"}``; an unknown name is a ``TypeError``.
    """
    s, t = _points(source, "source"), _points(target, "target")
    overrides = dict(config)
    if voxel is not None:
        overrides["voxel_size_m"] = float(voxel)
    overrides["seed"] = int(seed)
    cfg = _merge(default_config(), overrides)
    out = json.loads(_mireg.register_pair(s, t, json.dumps(cfg)))
    return Registration(
        transformation=np.array(out["target_from_source"], dtype=np.float64),
        ransac_transformation=np.array(out["ransac_target_from_source"], dtype=np.float64),
        success=bool(out["success"]),
        failure_reason=out["failure_reason"],
        inliers=int(out["num_inliers"]),
        correspondences=int(out["num_correspondences"]),
        fitness=float(out["fitness"]),
        inlier_rmse=float(out["inlier_rmse_m"]),
        hypotheses=int(out["hypotheses"]),
        timings=dict(out["timings_s"]),
        raw=out,
    )


def read_clouds(path: PathLike, topic: Optional[str] = None
                ) -> Iterator[tuple[int, np.ndarray, dict]]:
    """Iterate ``(stamp_ns, points, fields)`` over the point clouds of a log (any log
    ``mireg register`` reads: MCAP, ROS 1 .bag, ROS 2 bag directory, compressed or cut off).

    ``topic``: the cloud topic (default: the only one). ``points``: ``(N, 3)`` float64 in the
    cloud's frame, NaN and "no return" points dropped as ``register`` drops them; ``fields``:
    ``intensity`` (float32) and ``time`` (float64, seconds after the header stamp) when the
    cloud has them. Decoding runs on a thread of its own, at most two clouds ahead, so memory
    stays bounded whatever the log's length.
    """
    return _mireg.CloudReader(os.fspath(path), topic)


def register_log(path: PathLike, output: Optional[PathLike] = None,
                 progress: Optional[Callable[[int, int], Any]] = None, **flags: Any) -> dict:
    """``mireg register PATH``: register every cloud of a log and write poses, statistics and
    the loop-closed trajectory into a new MCAP (``output``, default ``PATH.mireg.mcap`` beside
    it). Keyword arguments are the command's flags by name, with typed values: ``voxel=0.5`` is
    ``--voxel 0.5``, ``no_loops=True`` is ``--no-loops``, ``force=True`` replaces an existing
    output, ``livox_tags="keep-all"``, ``start=120`` or ``start="1700000012.5s"``; ``None``
    leaves a flag at its default; an unknown name is a ``TypeError``, a value of the wrong type a
    ``ValueError``. ``progress``: called as ``progress(frames_written, frames_in_log)`` after
    each frame (``frames_in_log`` is 0 when the log does not say). Returns the ``--json``
    summary as a dict.
    """
    defaults = json.loads(_mireg.default_register_settings())
    given = {k: os.fspath(v) if isinstance(v, os.PathLike) else v for k, v in flags.items()}
    _merge(defaults, given)  # an unknown name: TypeError, as register_pair and Odometry
    settings = {k: v for k, v in given.items() if v is not None}
    out = None if output is None else os.fspath(output)
    return json.loads(_mireg.register_log(os.fspath(path), out,
                                          json.dumps(settings), progress))


def merge(runs: list, output_dir: PathLike, force: bool = False, seed: int = 0,
          min_links: int = 2, links_dir: Optional[PathLike] = None) -> dict:
    """``mireg merge RUN... -o OUTPUT_DIR``: ``register`` outputs of one site, each in its own
    frame, put into one (docs/SESSIONS.md). Each run is copied into ``output_dir`` with
    ``/mireg/pose_merged``, ``/mireg/tf_merged`` and ``/mireg/session_links``; returns the report
    (``merge_report.json``) as a dict: per session its group and alignment, per pair of sessions
    whether they joined and why. ``min_links``: agreeing links, at distinct keyframes, that join
    two sessions. ``links_dir``: each pair of sessions' links read from ``pair_A_B.json`` there
    where present (``mireg merge --pair A,B --links DIR`` writes one), written for the pairs
    linked. Bad input is a ``ValueError`` naming the file, an unreadable one ``OSError``.
    """
    links = None if links_dir is None else os.fspath(links_dir)
    return json.loads(_mireg.merge([os.fspath(r) for r in runs], os.fspath(output_dir),
                                   force, seed, min_links, links))


def localize(log: PathLike, map: PathLike, output: Optional[PathLike] = None,
             force: bool = False, seed: int = 0, min_links: int = 2,
             topic: Optional[str] = None, log_loops: str = "auto",
             map_reach_m: Optional[float] = None) -> dict:
    """``mireg localize LOG --map MAP``: the log placed in a prior map (a ``register`` or
    ``merge`` output, or a ``.ply``/``.pcd``/``.npy`` map file as ``mireg map`` writes it),
    wherever it starts, the map held fixed (docs/SESSIONS.md). The output (default
    ``LOG.localized.mcap`` beside the log) keeps the log's messages and adds ``/mireg/pose``,
    ``/tf`` and ``/mireg/localization`` (per frame: localized, tracking, outside_map, lost).
    ``log_loops``: ``"auto"`` closes the log's own loops only where a frame ends outside the map,
    ``"always"`` in its one registration (``--log-loops``). ``map_reach_m``: how far from the
    map's nearest keyframe a frame still counts as tracking, metres (``--map-reach``; default
    80 voxels). Returns the summary as a dict.
    """
    log = os.fspath(log)
    if output is None:
        stem = os.path.splitext(os.path.basename(log.rstrip("/")))[0]
        output = os.path.join(os.path.dirname(log.rstrip("/")), f"{stem}.localized.mcap")
    return json.loads(_mireg.localize(log, os.fspath(map), os.fspath(output), force, seed,
                                      min_links, topic, log_loops, map_reach_m))


class Odometry:
    """``mireg register``'s odometry, one cloud at a time, like KISS-ICP's Python pipeline: each
    frame is tracked on a local map from the motion so far where that fit holds up, registered
    prior-free (MI-RANSAC) where it is in doubt (``track_first=False``: on every frame), and
    refined against the local map; clouds with per-point times are deskewed. The same clouds in the same order give ``mireg register``'s
    poses (``--no-loops``; loop closure needs the whole log: use :func:`register_log`).

    ``voxel``: metres; default ``None`` sizes it from the first cloud's median range as
    ``register`` does. ``deskew``: deskew clouds given ``timestamps`` (default ``True``).
    ``seed``: the RNG seed (default 0). Other keyword arguments are fields of the odometry
    configuration (``min_inliers``, ``min_fitness``, ``local_map``, ``map_max_points_per_voxel``,
    ``feature_points``, ``map_fine``, ``track_first``) or of the pair configuration
    (docs/CONFIG.md).
    """

    def __init__(self, voxel: Optional[float] = None, deskew: bool = True, seed: int = 0,
                 **config: Any) -> None:
        base = json.loads(_mireg.Odometry.default_config_json())
        pair_keys = set(base["pair"])
        odometry = {k: v for k, v in config.items() if k not in pair_keys}
        pair = {k: v for k, v in config.items() if k in pair_keys}
        if voxel is not None:
            pair["voxel_size_m"] = float(voxel)
        pair["seed"] = int(seed)
        cfg = _merge(base, {**odometry, "pair": pair})
        self._inner = _mireg.Odometry(json.dumps(cfg), voxel is None, bool(deskew))
        self.poses: list[np.ndarray] = []
        """``world_from_frame`` (4×4) of every frame so far; world = the first frame's sensor
        frame."""
        self.estimates: list[dict] = []
        """Per frame: ``success``, ``failure_reason``, point counts."""

    @property
    def config(self) -> dict:
        """The configuration in use (once the first cloud has sized the voxel, the resolved one)."""
        return json.loads(self._inner.config_json())

    def register_frame(self, points: Any, timestamps: Any = None,
                       stamp_ns: Optional[int] = None) -> np.ndarray:
        """Register the next cloud and return its pose ``world_from_frame`` (4×4).

        ``points``: ``(N, 3)`` float32/float64, metres, sensor frame. ``timestamps``: per point,
        seconds after the cloud's stamp (for deskewing), or ``None``. ``stamp_ns``: the cloud's
        stamp in nanoseconds (default: 100 ms after the previous one, a 10 Hz sensor).
        """
        pts = _points(points, "points")
        times = None
        if timestamps is not None:
            times = np.ascontiguousarray(np.asarray(timestamps, dtype=np.float64))
            if times.ndim != 1:
                raise ValueError(f"timestamps: expected a 1-D array, got shape {times.shape}")
        if stamp_ns is None:
            stamp_ns = len(self.poses) * 100_000_000
        rows, info = self._inner.register_frame(pts, times, int(stamp_ns))
        pose = np.array(rows, dtype=np.float64).reshape(4, 4)
        self.poses.append(pose)
        self.estimates.append(json.loads(info))
        return pose
