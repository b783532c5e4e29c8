"""Rigid transforms, voxel downsampling and brute-force nearest neighbours (numpy only)."""

from __future__ import annotations

import numpy as np


def quaternion_matrix(xyzw) -> np.ndarray:
    """4×4 homogeneous rotation of a quaternion (x, y, z, w), normalised first."""
    x, y, z, w = (float(v) for v in xyzw)
    n = np.sqrt(x * x + y * y + z * z + w * w)
    x, y, z, w = x / n, y / n, z / n, w / n
    m = np.eye(4)
    m[:3, :3] = [
        [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
        [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
        [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
    ]
    return m


def transform(m: np.ndarray, pts: np.ndarray) -> np.ndarray:
    """Apply a 4×4 rigid transform to N×3 points."""
    return pts @ m[:3, :3].T + m[:3, 3]


def voxel_downsample(pts: np.ndarray, voxel: float, values: np.ndarray | None = None):
    """Centroid of the points in each occupied voxel of edge ``voxel`` (same idea as mireg's).

    With ``values`` (one per point) returns ``(centroids, mean value per voxel)``."""
    if len(pts) == 0:
        return pts if values is None else (pts, values)
    keys = np.floor(pts / voxel).astype(np.int64)
    _, inverse, counts = np.unique(keys, axis=0, return_inverse=True, return_counts=True)
    inverse = inverse.reshape(-1)
    sums = np.zeros((len(counts), 3))
    np.add.at(sums, inverse, pts)
    if values is None:
        return sums / counts[:, None]
    vsum = np.zeros(len(counts))
    np.add.at(vsum, inverse, values)
    return sums / counts[:, None], vsum / counts


def nearest_neighbours(query: np.ndarray, ref: np.ndarray, chunk=2048):
    """Index into ``ref`` and distance of the nearest neighbour of each query point (brute force)."""
    idx = np.empty(len(query), dtype=np.int64)
    dist = np.empty(len(query))
    ref_sq = (ref * ref).sum(axis=1)
    for s in range(0, len(query), chunk):
        q = query[s : s + chunk]
        d2 = (q * q).sum(axis=1)[:, None] - 2.0 * q @ ref.T + ref_sq[None, :]
        i = d2.argmin(axis=1)
        idx[s : s + chunk] = i
        dist[s : s + chunk] = np.sqrt(np.maximum(d2[np.arange(len(q)), i], 0.0))
    return idx, dist


def subsample(rng, n: int, at_most: int) -> np.ndarray | slice:
    """Indices of at most ``at_most`` of ``n`` items, drawn without replacement (all if fewer)."""
    if n <= at_most:
        return slice(None)
    return rng.choice(n, at_most, replace=False)
