#!/usr/bin/env bash
# Create tools/.venv-viewer with the pinned viewer stack (rerun-sdk, mcap, mcap-ros2-support, numpy,
# matplotlib, pytest) used by tools/view.py, tools/report.py and tools/test_viewer.py.
#
# Usage: bash tools/setup_viewer_venv.sh [--screenshot]
#   idempotent; re-run after editing requirements-viewer.txt.
#   --screenshot  also `apt-get install -y mesa-vulkan-drivers` (software Vulkan, lavapipe), which the
#                 `rerun` viewer needs to render `--headless --screenshot-to` without a GPU/display.
#                 Needs root. The CI path (no flag) never touches apt.
set -euo pipefail
here="$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)"
venv="$here/.venv-viewer"
screenshot=0
for arg in "$@"; do
    case "$arg" in
        --screenshot) screenshot=1 ;;
        -h|--help) sed -n '2,10p' "$0"; exit 0 ;;
        *) echo "unknown argument: $arg" >&2; exit 2 ;;
    esac
done
if [ ! -x "$venv/bin/python" ]; then
    python3 -m venv "$venv"
fi
"$venv/bin/python" -m pip install --quiet --disable-pip-version-check -r "$here/requirements-viewer.txt"
if [ "$screenshot" = 1 ]; then
    if ! dpkg -s mesa-vulkan-drivers >/dev/null 2>&1; then
        apt-get update -qq
        DEBIAN_FRONTEND=noninteractive apt-get install -y -qq mesa-vulkan-drivers
    fi
fi
"$venv/bin/python" - <<'PY'
from importlib.metadata import version
pkgs = ("rerun-sdk", "mcap", "mcap-ros2-support", "numpy", "matplotlib", "pytest")
print(", ".join(f"{p} {version(p)}" for p in pkgs))
PY
