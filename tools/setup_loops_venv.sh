#!/usr/bin/env bash
# Create tools/.venv-loops with the pinned loop-closure peers (tools/requirements-loops.txt: kiss-slam,
# open3d, mcap, mcap-ros2-support, numpy) used by tools/compare_loops.py. tools/make_loop_logs.py only
# needs tools/.venv-mcap (bash tools/setup_mcap_venv.sh), but runs in this venv too.
# Usage: bash tools/setup_loops_venv.sh   (idempotent; re-run after editing requirements-loops.txt)
set -euo pipefail
here="$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)"
venv="$here/.venv-loops"
# Open3D's wheel links libusb-1.0 and libgomp (Debian: libusb-1.0-0, libgomp1).
if ! ldconfig -p | grep -q "libusb-1.0.so.0"; then
    apt-get install -y -qq libusb-1.0-0 libgomp1 || echo "install libusb-1.0-0 and libgomp1 for open3d" >&2
fi
if [ ! -x "$venv/bin/python" ]; then
    python3 -m venv "$venv"
fi
"$venv/bin/python" -m pip install --quiet --disable-pip-version-check -r "$here/requirements-loops.txt"
"$venv/bin/python" - <<'PY'
from importlib.metadata import version
import kiss_slam, open3d, mcap_ros2.decoder  # noqa: F401  (imports work, libusb found)
print(", ".join(f"{p} {version(p)}" for p in ("kiss-slam", "kiss-icp", "map-closures", "open3d", "numpy", "mcap", "mcap-ros2-support")))
PY
