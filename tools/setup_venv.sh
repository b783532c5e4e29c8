#!/usr/bin/env bash
# Create tools/.venv-GROUP[-GROUP...] with the packages of the optional-dependency groups of
# tools/pyproject.toml named on the command line, exactly as tools/uv.lock pins them (idempotent;
# re-run after editing the groups and renewing the lock with `tools/.venv-uv/bin/uv lock --project
# tools`). uv itself is installed once into tools/.venv-uv.
#
# Usage: bash tools/setup_venv.sh GROUP... [--screenshot]
#   groups: mcap rosbags python ray peers odometry loops map gtsam evo lint (tools/pyproject.toml)
#   python, ray   also build and install the mireg package from ./python with its viewer extra (the
#                 `mireg` command, `import mireg`, `mireg view`; re-run after changing python/ or
#                 src/), and the Ray driver tools/mireg_ray (editable)
#   peers, map, loops  Open3D's wheel links libusb-1.0 and libgomp: apt-get installs them if missing
#   --screenshot  apt-get install mesa-vulkan-drivers (Vulkan on the CPU), which the `rerun` viewer
#                 needs for `mireg view --screenshot` without a GPU; needs root
# e.g. `bash tools/setup_venv.sh mcap` makes tools/.venv-mcap; `bash tools/setup_venv.sh python ray`
# makes tools/.venv-python-ray (what .ci/run uses).
set -euo pipefail
here="$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)"
groups=()
screenshot=0
for arg in "$@"; do
    case "$arg" in
        --screenshot) screenshot=1 ;;
        -h|--help) sed -n '2,16p' "$0"; exit 0 ;;
        -*) echo "unknown option: $arg" >&2; exit 2 ;;
        *)
            if ! grep -q "^$arg = \[" "$here/pyproject.toml"; then
                echo "unknown group: $arg (the optional-dependency groups of tools/pyproject.toml)" >&2
                exit 2
            fi
            groups+=("$arg") ;;
    esac
done
if [ ${#groups[@]} -eq 0 ]; then
    sed -n '2,16p' "$0" >&2
    exit 2
fi
venv="$here/.venv-$(IFS=-; echo "${groups[*]}")"
if [ ! -x "$venv/bin/python" ]; then
    python3 -m venv "$venv"
fi
uv="$here/.venv-uv/bin/uv"
if [ ! -x "$uv" ]; then
    python3 -m venv "$here/.venv-uv"
    "$here/.venv-uv/bin/python" -m pip install --quiet --disable-pip-version-check uv==0.13.8
fi
extras=()
for group in "${groups[@]}"; do extras+=(--extra "$group"); done
# The lock's versions, nothing else (--frozen); packages installed beside them stay (--inexact: the
# mireg package below); genz-icp from its wheel only, never built from source here.
UV_PROJECT_ENVIRONMENT="$venv" "$uv" sync --quiet --project "$here" --frozen --inexact \
    --no-install-project --no-build-package genz-icp "${extras[@]}"
pip=("$venv/bin/python" -m pip install --quiet --disable-pip-version-check)
mireg=0 open3d=0
for group in "${groups[@]}"; do
    case "$group" in
        python|ray) mireg=1 ;;
        peers|map|loops) open3d=1 ;;
    esac
done
if [ "$mireg" = 1 ]; then
    "${pip[@]}" "$here/../python[viewer]"   # a local folder is built and installed each time
    "${pip[@]}" --no-deps -e "$here/mireg_ray"
fi
if [ "$open3d" = 1 ] && ! ldconfig -p | grep -q "libusb-1.0.so.0"; then
    apt-get install -y -qq libusb-1.0-0 libgomp1 || echo "install libusb-1.0-0 and libgomp1 for open3d" >&2
fi
if [ "$screenshot" = 1 ] && ! dpkg -s mesa-vulkan-drivers >/dev/null 2>&1; then
    apt-get update -qq
    DEBIAN_FRONTEND=noninteractive apt-get install -y -qq mesa-vulkan-drivers
fi
echo "$venv: $("$venv/bin/python" -m pip list --format=freeze --disable-pip-version-check | grep -c ==) packages"
