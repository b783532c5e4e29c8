"""The modules behind tools/view.py (Rerun viewer of a mireg output MCAP).

``reading`` (MCAP → Run: frames, poses, stats, loops), ``geometry`` (transforms, voxels, nearest
neighbours), ``mapfile`` (``mireg map`` files), ``timeline`` (time, up vector, colours), ``scene``
(clouds, map, trajectories, stats, failures, blueprint), ``loops`` (loop edges, ``--loop N``),
``pair`` (``--frame K`` via ``mireg pair``), ``screenshot`` (headless viewer), ``cli`` (main).
"""
