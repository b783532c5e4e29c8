#!/usr/bin/env bash
# Create tools/.venv-odometry with KISS-ICP and the MCAP packages (tools/requirements-odometry.txt)
# used by tools/compare_kiss_icp.py and tools/make_kaist03_mcap.py.
# Usage: bash tools/setup_odometry_venv.sh   (idempotent)
set -euo pipefail
here="$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)"
venv="$here/.venv-odometry"
if [ ! -x "$venv/bin/python" ]; then
    python3 -m venv "$venv"
fi
"$venv/bin/python" -m pip install --quiet --disable-pip-version-check -r "$here/requirements-odometry.txt"
"$venv/bin/python" -c 'import kiss_icp, numpy, mcap; print("kiss-icp", kiss_icp.__version__, "numpy", numpy.__version__)'
