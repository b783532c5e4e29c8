#!/usr/bin/env bash
# Create tools/.venv-rosbags with the pinned ROS bag packages (rosbags, mcap, mcap-ros1-support and
# their dependencies) used by tools/make_bag_fixtures.py and tools/check_bag_output.py.
# Usage: bash tools/setup_rosbags_venv.sh   (idempotent; re-run after editing requirements-rosbags.txt)
set -euo pipefail
here="$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)"
venv="$here/.venv-rosbags"
if [ ! -x "$venv/bin/python" ]; then
    python3 -m venv "$venv"
fi
"$venv/bin/python" -m pip install --quiet --disable-pip-version-check -r "$here/requirements-rosbags.txt"
"$venv/bin/python" - <<'PY'
from importlib.metadata import version
print(", ".join(f"{p} {version(p)}" for p in ("rosbags", "mcap", "mcap-ros1-support", "zstandard", "lz4", "numpy")))
PY
