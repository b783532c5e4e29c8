"""``--frame K``: recompute frame K → K−1 with ``mireg pair`` and draw its geometric inlier pairs."""

from __future__ import annotations

import json
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

from .geometry import nearest_neighbours, transform, voxel_downsample
from .reading import Run
from .timeline import set_frame_time


def _toml_value(v) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, (int, float)):
        return repr(float(v)) if isinstance(v, float) else str(v)
    if isinstance(v, str):
        return json.dumps(v)  # a JSON string of plain text is a valid TOML basic string
    if isinstance(v, (list, tuple)):
        return "[" + ", ".join(_toml_value(x) for x in v) + "]"
    raise TypeError(f"cannot write {v!r} as TOML")


def to_toml(d: dict, prefix: str = "") -> str:
    """Minimal TOML for a JSON-like config: scalars/arrays first, then nested tables; None (an
    unset Option in mireg's config) is left out so mireg derives the default."""
    lines, tables = [], []
    for key, value in d.items():
        if value is None:
            continue
        if isinstance(value, dict):
            tables.append((key, value))
        else:
            lines.append(f"{key} = {_toml_value(value)}")
    text = "\n".join(lines) + ("\n" if lines else "")
    for key, value in tables:
        name = f"{prefix}{key}"
        text += f"\n[{name}]\n" + to_toml(value, prefix=name + ".")
    return text



def log_pair(rr, run: Run, args):
    """Recompute frame K's registration with `mireg pair` and draw its geometric inlier pairs.

    Returns the drawn world points and a title (for the pair view's eye)."""
    k = args.frame
    src, tgt = run.frames[k], run.frames[k - 1]
    world_from_target = tgt.pose(args.placing)
    if src.points is None or tgt.points is None or world_from_target is None:
        raise SystemExit(f"--frame {k}: clouds or pose missing")
    cfg = run.pair_config
    voxel = float(cfg.get("voxel_size_m") or 0.05)
    threshold = float(cfg.get("inlier_threshold_m") or 1.5 * voxel)
    cmd = [str(args.mireg), "pair"]
    with tempfile.TemporaryDirectory(prefix="mireg_view_") as tmp:
        src_path, tgt_path = Path(tmp, "source.npy"), Path(tmp, "target.npy")
        np.save(src_path, np.ascontiguousarray(src.points, dtype=np.float64))
        np.save(tgt_path, np.ascontiguousarray(tgt.points, dtype=np.float64))
        cmd += [str(src_path), str(tgt_path), "--json"]
        if cfg:
            # the run's full pairwise configuration (sampler, ranking, ICP, seed, ...) as TOML
            config_path = Path(tmp, "pair.toml")
            config_path.write_text(to_toml(cfg))
            cmd += ["--config", str(config_path)]
        else:
            cmd += ["--voxel", repr(voxel)]
            if run.metadata.get("seed") not in (None, ""):
                cmd += ["--seed", str(run.metadata["seed"])]
        proc = subprocess.run(cmd, capture_output=True, text=True, timeout=300)
    if proc.returncode != 0:
        raise SystemExit(f"{' '.join(cmd)} failed ({proc.returncode}):\n{proc.stderr}")
    result = json.loads(proc.stdout)
    target_from_source = np.array(result["target_from_source"], dtype=np.float64)
    tgt_w = transform(world_from_target, voxel_downsample(tgt.points, voxel))
    src_w = transform(world_from_target @ target_from_source, voxel_downsample(src.points, voxel))
    idx, dist = nearest_neighbours(src_w, tgt_w)
    inlier = dist <= threshold
    segments = np.stack([src_w[inlier], tgt_w[idx[inlier]]], axis=1)
    set_frame_time(rr, src)
    rr.log("world/pair/target", rr.Points3D(tgt_w, colors=[255, 255, 255], radii=0.007))
    rr.log("world/pair/source", rr.Points3D(src_w, colors=[255, 0, 255], radii=0.007))
    rr.log(
        "world/pair/correspondences",
        rr.LineStrips3D(segments, colors=[255, 255, 0], radii=0.004),
    )
    text = (
        f"recomputed pair {k}->{k - 1} with `mireg pair` (voxel {voxel} m, inlier threshold "
        f"{threshold} m): success {result.get('success')}, RANSAC inliers "
        f"{result.get('num_inliers')}, correspondences {result.get('num_correspondences')}; "
        f"{int(inlier.sum())}/{len(src_w)} downsampled source points within the threshold"
    )
    if src.stats:
        text += f"; the MCAP's run had {src.stats.get('num_inliers')} inliers"
    rr.log("log/pair", rr.TextLog(text, level=rr.TextLogLevel.INFO))
    print(text, file=sys.stderr)
    return np.concatenate([tgt_w, src_w]), f"frame {k} -> {k - 1}"

