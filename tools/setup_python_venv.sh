#!/usr/bin/env bash
# Create tools/.venv-python: the mireg package built from ./python with its viewer extra (PyO3 +
# maturin, fetched by pip as the build backend; the `mireg` command, `import mireg`, `mireg view`),
# the pinned test dependencies of python/tests, and the Ray driver (tools/mireg_ray) with its
# test dependencies, which runs the package's `mireg` command.
# Usage: bash tools/setup_python_venv.sh   (re-run after changing python/ or src/: it rebuilds)
set -euo pipefail
here="$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)"
venv="$here/.venv-python"
if [ ! -x "$venv/bin/python" ]; then
    python3 -m venv "$venv"
fi
pip=("$venv/bin/python" -m pip install --quiet --disable-pip-version-check)
"${pip[@]}" -r "$here/requirements-python.txt" -r "$here/requirements-ray.txt"
"${pip[@]}" "$here/../python[viewer]"   # a local folder is built and installed again each time
"${pip[@]}" --no-deps -e "$here/mireg_ray"
"$venv/bin/python" -c 'import mireg, mireg.viewer, mireg_ray; print("mireg", mireg.__version__, "from", mireg.__file__)'
