#!/usr/bin/env python3
"""Show a mireg output MCAP in the Rerun viewer (rerun-sdk 0.41), save it as .rrd, or screenshot it.

Input: the MCAP written by ``mireg register IN.mcap -o OUT.mcap``. It holds the input channels
unchanged (the PointCloud2 topic, e.g. ``/camera/depth/points``, and ``/ground_truth/pose`` =
reference first_from_camera_k when the input had it) plus ``/tf``, ``/mireg/pose`` (PoseStamped
world_from_frame, world = the first cloud's sensor frame), ``/mireg/stats`` (one JSON object per
frame) and a metadata record ``mireg`` (version, config, seed, command_line, input, topic, the
run's topics). With loop closure also ``/mireg/pose_optimized`` (the loop-closed trajectory, same
type and stamps as ``/mireg/pose``) and ``/mireg/loops`` (JSON, one per loop candidate tried, at
the query cloud's log_time). Odometry poses and stats are matched to clouds by log_time, optimised
poses by header stamp, loops by their frames' stamps (else ``query_frame`` / ``match_frame``).
A log registered N times has its runs' topics under ``/mireg_N/``; the metadata names them.

Everything is logged on the ``message_log_time`` timeline (a timestamp in ns, the same name and
unit Rerun's own MCAP importer uses, so ``rerun OUT.mcap`` data lines up with ours) and on a
``frame`` sequence timeline (index of the cloud in the log).

Entity paths
------------
``world``                         static view coordinates (RDF for ``*optical_frame`` clouds, else RFU)
``world/clouds/frame_NNNN``       every ``--every``-th cloud, transformed into the world frame by its
                                  pose on ``--trajectory`` (default: optimised if the log has it,
                                  else ``/mireg/pose``), at most ``--max-points`` points, coloured by height
                                  (−y for optical frames, +z otherwise) or by ``intensity`` if the
                                  cloud has that field. One entity per cloud so the map accumulates.
``world/map``                     static Points3D: ``--map FILE`` (from ``mireg map``), or with
                                  ``--map-voxel V`` every cloud placed by ``--trajectory``, voxelised
``world/trajectory/estimate``     LineStrips3D (white) of the ``/mireg/pose`` (odometry) positions up
                                  to the current frame
``world/trajectory/optimized``    LineStrips3D (orange) of ``/mireg/pose_optimized`` (if the topic exists)
``world/trajectory/reference``    LineStrips3D (green) of ``/ground_truth/pose`` (if the topic exists)
``world/loops/loop_NNNN``         per ``/mireg/loops`` message N: a segment between the match and the
                                  query frame on the optimised trajectory, green accepted, red
                                  rejected, at the query's log time; label (hover) and AnyValues
                                  (selection panel) with the message's fields
``log/loops``                     TextLog per loop: frames, verdict, reason, inliers, fitness, weight
``world/camera``                  Transform3D of the current pose on ``--trajectory`` …
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
``world/loop_pair`` (Transform3D world_from_match), ``…/match`` (white), ``…/query`` (turbo by
nearest-match distance), ``…/inlier_pairs`` (yellow), ``log/loop_pair``
                                  only with ``--loop N``: the N-th loop message's two clouds in the
                                  match sensor frame, the query moved by ``match_from_query`` (by
                                  the odometry when that is null); in a 3-D view of their own

``--frame K`` (correspondences of frame K → K−1): the MCAP does **not** store correspondences, so
this is a *recomputation*: clouds K (source) and K−1 (target) are written as float64 N×3 ``.npy``
files in a temp dir and registered again with ``mireg pair SOURCE TARGET --json`` (binary from
``--mireg``, default ``target/release/mireg``) using the voxel size, inlier threshold and seed of the
``mireg`` metadata record. Both clouds are voxel-downsampled, placed in the world by
world_from_(K−1) on ``--trajectory`` (source also by the pair's target_from_source), and every
source point whose nearest target point lies within the inlier threshold (1.5·voxel by default)
gets a line segment.
Those are geometric inlier pairs under the recomputed estimate, not the feature correspondences
RANSAC voted with, and the recomputed estimate can differ from the one in the MCAP if the run used
settings the flags here do not reproduce.

The code is in tools/viewer/ (reading, geometry, mapfile, timeline, scene, loops, pair,
screenshot, cli); this file is the entry point and keeps the names tools/report.py imports.

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
    tools/.venv-viewer/bin/python tools/view.py /tmp/out.mcap --loop 0 --map /tmp/map.ply
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
