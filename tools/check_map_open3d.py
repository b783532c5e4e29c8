#!/usr/bin/env python3
"""Read maps written by `mireg map` with independent readers and print counts and bounds:
Open3D's ``read_point_cloud`` for .ply and .pcd, numpy's ``load`` for .npy (N x 3, or N x 4
with intensity). Exits non-zero when a file reads as empty or with non-finite points, or when
maps of one log in several formats disagree on the point count.

Usage:
    bash tools/setup_venv.sh map        # unless tools/.venv-loops exists
    python3 tools/toolbox.py check-map-open3d map.ply map.pcd map.npy
"""

import sys

import numpy as np


def read(path):
    """(xyz as float64 N x 3, intensity or None, reader name)."""
    if path.lower().endswith(".npy"):
        a = np.load(path)
        if a.ndim != 2 or a.shape[1] not in (3, 4):
            raise SystemExit(f"{path}: shape {a.shape}, expected (N, 3) or (N, 4)")
        return a[:, :3].astype(np.float64), (a[:, 3] if a.shape[1] == 4 else None), f"numpy {a.dtype}"
    import open3d as o3d

    pc = o3d.io.read_point_cloud(path)
    # Open3D's PointCloud has no intensity attribute: it reads x, y, z (and colours/normals).
    return np.asarray(pc.points), None, f"open3d {o3d.__version__}"


def main(paths):
    if not paths:
        raise SystemExit(__doc__)
    counts = {}
    ok = True
    for p in paths:
        xyz, inten, reader = read(p)
        n = len(xyz)
        counts[p] = n
        line = f"{p}: {n} points ({reader})"
        if n:
            lo, hi = xyz.min(axis=0), xyz.max(axis=0)
            line += f", bounds min {np.round(lo, 3).tolist()} max {np.round(hi, 3).tolist()} m"
            if not np.isfinite(xyz).all():
                line += ", NON-FINITE points"
                ok = False
        else:
            ok = False
        if inten is not None:
            line += f", intensity {float(inten.min()):.3f}..{float(inten.max()):.3f}"
        print(line)
    if len(set(counts.values())) > 1:
        print("point counts differ between files")
        ok = False
    sys.exit(0 if ok else 1)


if __name__ == "__main__":
    main(sys.argv[1:])
