#!/usr/bin/env bash
# Create tools/.venv-gtsam with the pinned GTSAM + numpy used by tools/check_pose_graph_gtsam.py
# (compares src/graph's Levenberg–Marquardt optimum with GTSAM's on the same g2o graphs).
# Usage: bash tools/setup_gtsam_venv.sh   (idempotent; re-run after editing requirements-gtsam.txt)
set -euo pipefail
here="$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)"
venv="$here/.venv-gtsam"
if [ ! -x "$venv/bin/python" ]; then
    python3 -m venv "$venv"
fi
"$venv/bin/python" -m pip install --quiet --disable-pip-version-check -r "$here/requirements-gtsam.txt"
"$venv/bin/python" - <<'PY'
from importlib.metadata import version
print(", ".join(f"{p} {version(p)}" for p in ("gtsam", "numpy")))
PY
