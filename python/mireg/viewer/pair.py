"""``--frame K``: recompute frame K → K−1 with ``mireg.register_pair`` (what ``mireg pair`` runs)
and draw its geometric inlier pairs."""

from __future__ import annotations

import sys

import numpy as np

from .. import register_pair
from ..run import Run
from .geometry import nearest_neighbours, transform, voxel_downsample
from .timeline import set_frame_time


def log_pair(rr, run: Run, args):
    """Recompute frame K's registration with `mireg.register_pair` and draw its geometric inlier pairs.

    Returns the drawn world points and a title (for the pair view's eye)."""
    k = args.frame
    src, tgt = run.frames[k], run.frames[k - 1]
    world_from_target = tgt.pose(args.placing)
    if src.points is None or tgt.points is None or world_from_target is None:
        raise SystemExit(f"--frame {k}: clouds or pose missing")
    cfg = run.pair_config
    voxel = float(cfg.get("voxel_size_m") or 0.05)
    threshold = float(cfg.get("inlier_threshold_m") or 1.5 * voxel)
    # The run's whole pairwise configuration (sampler, ranking, ICP, seed, ...), as `register`
    # ran it; an older record without one gives the voxel and seed only.
    config = dict(cfg)
    seed = int(config.pop("seed", None) or run.metadata.get("seed") or 0)
    if not config:
        config = {"voxel_size_m": voxel}
    result = register_pair(src.points, tgt.points, seed=seed, **config).raw
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
        f"recomputed pair {k}->{k - 1} with mireg.register_pair (voxel {voxel} m, inlier threshold "
        f"{threshold} m): success {result.get('success')}, RANSAC inliers "
        f"{result.get('num_inliers')}, correspondences {result.get('num_correspondences')}; "
        f"{int(inlier.sum())}/{len(src_w)} downsampled source points within the threshold"
    )
    if src.stats:
        text += f"; the MCAP's run had {src.stats.get('num_inliers')} inliers"
    rr.log("log/pair", rr.TextLog(text, level=rr.TextLogLevel.INFO))
    print(text, file=sys.stderr)
    return np.concatenate([tgt_w, src_w]), f"frame {k} -> {k - 1}"

