#!/usr/bin/env bash
# Create tools/.venv with the pinned peer tools (Open3D, numpy) used by tools/*.py.
# Usage: bash tools/setup_venv.sh   (idempotent; re-run after editing requirements.txt)
set -euo pipefail
here="$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)"
python3 -m venv "$here/.venv"
"$here/.venv/bin/python" -m pip install --quiet -r "$here/requirements.txt"
"$here/.venv/bin/python" -c 'import open3d, numpy; print("open3d", open3d.__version__, "numpy", numpy.__version__)'
