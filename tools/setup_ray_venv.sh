#!/usr/bin/env bash
# Create tools/.venv-ray with Ray (pinned in requirements-ray.txt) and the mireg_ray driver
# package (tools/mireg_ray, installed in editable mode).
# Usage: bash tools/setup_ray_venv.sh   (idempotent; re-run after editing requirements-ray.txt)
set -euo pipefail
here="$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)"
venv="$here/.venv-ray"
if [ ! -x "$venv/bin/python" ]; then
    python3 -m venv "$venv"
fi
"$venv/bin/python" -m pip install --quiet --disable-pip-version-check -r "$here/requirements-ray.txt"
# The mireg package (./python): its `mireg` command is what the driver runs.
"$venv/bin/python" -m pip install --quiet --disable-pip-version-check "$here/../python"
"$venv/bin/python" -m pip install --quiet --disable-pip-version-check --no-deps -e "$here/mireg_ray"
"$venv/bin/python" - <<'PY'
from importlib.metadata import version
print(", ".join(f"{p} {version(p)}" for p in ("ray", "mireg", "mireg-ray")))
PY
