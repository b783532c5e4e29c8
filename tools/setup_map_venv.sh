#!/usr/bin/env bash
# Create tools/.venv-map with Open3D and numpy for tools/check_map_open3d.py
# (equivalently: pip install open3d-cpu numpy, versions in requirements-map.txt).
# Usage: bash tools/setup_map_venv.sh   (idempotent)
# tools/check_map_open3d.py uses tools/.venv-loops instead when that exists.
set -euo pipefail
here="$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)"
venv="$here/.venv-map"
# Open3D's wheel links libusb-1.0 and libgomp (Debian: libusb-1.0-0, libgomp1).
if ! ldconfig -p | grep -q "libusb-1.0.so.0"; then
    apt-get install -y -qq libusb-1.0-0 libgomp1 || echo "install libusb-1.0-0 and libgomp1 for open3d" >&2
fi
if [ ! -x "$venv/bin/python" ]; then
    python3 -m venv "$venv"
fi
"$venv/bin/python" -m pip install --quiet --disable-pip-version-check -r "$here/requirements-map.txt"
"$venv/bin/python" -c 'import open3d, numpy; print("open3d", open3d.__version__, "numpy", numpy.__version__)'
