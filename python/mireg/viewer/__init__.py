"""Show a mireg output MCAP in the Rerun viewer (rerun-sdk 0.41), save it as .rrd, or screenshot it:
``mireg view OUT.mcap`` or ``python -m mireg.viewer OUT.mcap`` (``pip install "./python[viewer]"``).

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
The run is read by ``mireg.read_run`` (the crate's own readers, ROS 1 or ROS 2), not by a Python
MCAP decoder; an input that is not a ``register`` output (a raw bag or MCAP, a folder) is a
message saying to run ``mireg register`` first.

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
``world/trajectory/reference``    LineStrips3D (green) of ``/ground_truth/pose`` (if the topic exists),
                                  laid onto the ``--trajectory`` poses as ``mireg evaluate`` aligns
                                  them (SE(3) Umeyama over the stamp-paired poses)
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
                                  Scalars, one per ``/mireg/stats`` message (null fields are skipped:
                                  a frame tracked on the local map has no global registration)
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
this is a *recomputation*: clouds K (source) and K−1 (target) are registered again with
``mireg.register_pair`` (what ``mireg pair`` runs) with the pair configuration and seed of the
``mireg`` metadata record. Both clouds are voxel-downsampled, placed in the world by
world_from_(K−1) on ``--trajectory`` (source also by the pair's target_from_source), and every
source point whose nearest target point lies within the inlier threshold (1.5·voxel by default)
gets a line segment.
Those are geometric inlier pairs under the recomputed estimate, not the feature correspondences
RANSAC voted with, and the recomputed estimate can differ from the one in the MCAP if the run used
settings the flags here do not reproduce.

The modules: ``geometry`` (transforms, voxels, nearest neighbours), ``mapfile`` (``mireg map``
files), ``timeline`` (time, up vector, colours), ``scene`` (clouds, map, trajectories, stats,
failures, blueprint), ``loops`` (loop edges, ``--loop N``), ``pair`` (``--frame K``),
``screenshot`` (headless viewer), ``cli`` (main), ``report`` (the one-page PNG report:
``python -m mireg.viewer.report OUT.mcap -o report.png``). The reading is ``mireg.run``.

Output modes
------------
``--save out.rrd``        write a recording (no viewer, no display needed)
``--screenshot out.png``  write a temporary .rrd, then run the ``rerun`` binary shipped in the
                          rerun-sdk wheel with ``--headless --screenshot-to out.png`` (needs the
                          software Vulkan driver, e.g. Debian's ``mesa-vulkan-drivers``)
(default)                 open the viewer (bound to 127.0.0.1) when a display exists

Usage:
    pip install "./python[viewer]"
    mireg view /tmp/out.mcap --save /tmp/out.rrd
    mireg view /tmp/out.mcap --frame 12
    mireg view /tmp/out.mcap --loop 0 --map /tmp/map.ply
    python -m mireg.viewer /tmp/out.mcap --screenshot docs/viewer.png
"""
