#!/usr/bin/env bash
# Create tools/.venv-mcap with the pinned light MCAP packages (mcap, mcap-ros2-support, zstandard,
# lz4) used by tools/make_fixture_mcap.py and tools/check_mcap.py.
# Usage: bash tools/setup_mcap_venv.sh   (idempotent; re-run after editing requirements-mcap.txt)
set -euo pipefail
here="$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)"
venv="$here/.venv-mcap"
if [ ! -x "$venv/bin/python" ]; then
    python3 -m venv "$venv"
fi
"$venv/bin/python" -m pip install --quiet --disable-pip-version-check -r "$here/requirements-mcap.txt"
"$venv/bin/python" - <<'PY'
from importlib.metadata import version
print(", ".join(f"{p} {version(p)}" for p in ("mcap", "mcap-ros2-support", "zstandard", "lz4")))
PY
