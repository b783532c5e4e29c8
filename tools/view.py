#!/usr/bin/env python3
"""Show a mireg output MCAP in the Rerun viewer (rerun-sdk 0.41), save it as .rrd, or screenshot it.

Input: the MCAP written by ``mireg register IN.mcap -o OUT.mcap``. It holds the input channels
unchanged (the PointCloud2 topic, e.g. ``/camera/depth/points``, and ``/ground_truth/pose`` =
reference first_from_camera_k when the input had it) plus ``/tf``, ``/mireg/pose`` (PoseStamped
world_from_frame, world = the first cloud's sensor frame), ``/mireg/stats`` (one JSON object per
frame) and a metadata record ``mireg`` (version, config, seed, command_line, input, topic).
Every output message has the log_time of the cloud it belongs to; that is how clouds, poses and
stats are matched here.

Everything is logged on the ``message_log_time`` timeline (a timestamp in ns, the same name and
unit Rerun's own MCAP importer uses, so ``rerun OUT.mcap`` data lines up with ours) and on a
``frame`` sequence timeline (index of the cloud in the log).

Entity paths
------------
``world``                         static view coordinates (RDF for ``*optical_frame`` clouds, else RFU)
``world/clouds/frame_NNNN``       every ``--every``-th cloud, transformed into the world frame by its
                                  ``/mireg/pose``, at most ``--max-points`` points, coloured by height
                                  (−y for optical frames, +z otherwise) or by ``intensity`` if the
                                  cloud has that field. One entity per cloud so the map accumulates.
``world/trajectory/estimate``     LineStrips3D of the ``/mireg/pose`` positions up to the current frame
``world/trajectory/reference``    LineStrips3D of ``/ground_truth/pose`` (only if the topic exists)
``world/camera``                  Transform3D of the current estimated pose …
``world/camera/axes``             … with Arrows3D for its x (red), y (green), z (blue) axes
``world/failures``                Boxes3D (red) at the pose of every failed frame so far, labelled
``log/failures``                  TextLog (WARN) per failed frame: reason and fallback
``stats/inliers``, ``stats/correspondences``, ``stats/inlier_ratio``, ``stats/hypotheses``,
``stats/best_found_at``, ``stats/fitness``, ``stats/inlier_rmse_m``, ``stats/icp_iterations``
                                  Scalars, one per ``/mireg/stats`` message (null fields are skipped)
``stats/timings_ms/<stage>``      Scalars per stage of ``timings_s`` (decode, downsample, normals,
                                  features, matching, ranking, ransac, icp, register), in ms
``world/pair/target`` (white), ``world/pair/source`` (magenta), ``world/pair/correspondences``
(yellow), ``log/pair``            only with ``--frame K``, see below; shown in a second 3-D view
                                  (the map view leaves them out)

``--frame K`` (correspondences of frame K → K−1): the MCAP does **not** store correspondences, so
this is a *recomputation*: clouds K (source) and K−1 (target) are written as float64 N×3 ``.npy``
files in a temp dir and registered again with ``mireg pair SOURCE TARGET --json`` (binary from
``--mireg``, default ``target/release/mireg``) using the voxel size, inlier threshold and seed of the
``mireg`` metadata record. Both clouds are voxel-downsampled, placed in the world by
world_from_(K−1) (source also by the pair's target_from_source), and every source point whose
nearest target point lies within the inlier threshold (1.5·voxel by default) gets a line segment.
Those are geometric inlier pairs under the recomputed estimate, not the feature correspondences
RANSAC voted with, and the recomputed estimate can differ from the one in the MCAP if the run used
settings the flags here do not reproduce.

Output modes
------------
``--save out.rrd``        write a recording (no viewer, no display needed)
``--screenshot out.png``  write a temporary .rrd, then run the ``rerun`` binary shipped in the
                          rerun-sdk wheel with ``--headless --screenshot-to out.png`` (needs the
                          software Vulkan driver: ``bash tools/setup_viewer_venv.sh --screenshot``)
(default)                 open the viewer (bound to 127.0.0.1) when a display exists

Usage:
    bash tools/setup_viewer_venv.sh
    tools/.venv-viewer/bin/python tools/view.py /tmp/out.mcap --save /tmp/out.rrd
    tools/.venv-viewer/bin/python tools/view.py /tmp/out.mcap --frame 12
    tools/.venv-viewer/bin/python tools/view.py /tmp/out.mcap --screenshot docs/viewer.png
"""

from __future__ import annotations

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

# The names other tools use (tools/report.py, tools/test_viewer.py) stay importable from here.
from viewer.cli import main as _main, parse_args  # noqa: E402,F401
from viewer.geometry import nearest_neighbours, transform, voxel_downsample  # noqa: E402,F401
from viewer.mapfile import load_map  # noqa: E402,F401
from viewer.pair import to_toml  # noqa: E402,F401
from viewer.reading import (  # noqa: E402,F401
    Frame, Loop, MissingDecoder, Run, decode_pointcloud2, pose_to_matrix, read_run, run_topics,
)
from viewer.scene import STAGES, STAT_SERIES  # noqa: E402,F401
from viewer.timeline import TIMELINE, colour_map, up_vector  # noqa: E402,F401


def main(argv=None) -> int:
    return _main(argv, description=__doc__.split("\n\n")[0])


if __name__ == "__main__":
    sys.exit(main())
