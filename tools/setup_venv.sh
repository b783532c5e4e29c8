#!/usr/bin/env bash
# Create tools/.venv with the pinned peer tools (Open3D, KISS-Matcher, numpy) used by tools/*.py.
# Usage: bash tools/setup_venv.sh   (idempotent; re-run after editing requirements.txt)
set -euo pipefail
here="$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)"
# Open3D's wheel links libusb-1.0 and libgomp (Debian: libusb-1.0-0, libgomp1).
if ! ldconfig -p | grep -q "libusb-1.0.so.0"; then
    apt-get install -y -qq libusb-1.0-0 libgomp1 || echo "install libusb-1.0-0 and libgomp1 for open3d" >&2
fi
python3 -m venv "$here/.venv"
"$here/.venv/bin/python" -m pip install --quiet -r "$here/requirements.txt"
"$here/.venv/bin/python" -c 'import open3d, numpy, matplotlib, kiss_matcher; print("open3d", open3d.__version__, "numpy", numpy.__version__, "matplotlib", matplotlib.__version__, "kiss_matcher imported")'
