#!/usr/bin/env bash
# Create tools/.venv-python with the mireg Python package built from ./python (PyO3 + maturin,
# fetched by pip as the build backend) and its tests' pinned dependencies.
# Usage: bash tools/setup_python_venv.sh   (re-run after changing python/ or src/: it rebuilds)
set -euo pipefail
here="$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)"
venv="$here/.venv-python"
if [ ! -x "$venv/bin/python" ]; then
    python3 -m venv "$venv"
fi
"$venv/bin/python" -m pip install --quiet --disable-pip-version-check -r "$here/requirements-python.txt"
"$venv/bin/python" -m pip install --quiet --disable-pip-version-check --force-reinstall --no-deps "$here/../python"
"$venv/bin/python" -c 'import mireg; print("mireg", mireg.__version__, "from", mireg.__file__)'
