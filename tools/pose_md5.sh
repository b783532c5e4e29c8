#!/usr/bin/env bash
# Prints the md5 of the odometry poses `mireg register` gives on each log (`mireg export --topic
# /mireg/pose --format tum` of its output), for checking that a change leaves the poses bit-identical: run it with the build
# before and after and compare the lines.
#
# Usage: tools/pose_md5.sh path/to/mireg LOG [LOG...]   (extra register flags in $MIREG_FLAGS)
set -euo pipefail
bin=$1
shift
work=$(mktemp -d)
trap 'rm -rf "$work"' EXIT
for log in "$@"; do
    "$bin" register "$log" -o "$work/out.mcap" --force --quiet ${MIREG_FLAGS:-} >/dev/null
    "$bin" export "$work/out.mcap" --topic /mireg/pose --format tum -o "$work/poses.tum" >/dev/null
    echo "$(md5sum < "$work/poses.tum" | cut -d' ' -f1)  $log"
done
