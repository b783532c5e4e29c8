#!/usr/bin/env bash
# For each log: `mireg register` wall time [s] and peak RSS [MB] (GNU time), and the md5 of the
# odometry and loop-closed poses it gives (`mireg export ... --format tum`), one row per log. For
# comparing the same frames in different containers (e.g. a bag and its compressed versions:
# docs/BENCHMARKS_ARCHIVE.md, "Compressed ROS 2 bags").
#
# Usage: tools/bench_logs.sh path/to/mireg LOG [LOG...]   (extra register flags in $MIREG_FLAGS)
set -euo pipefail
bin=$1
shift
work=$(mktemp -d)
trap 'rm -rf "$work"' EXIT
printf '%-8s %-8s %-32s %-32s %s\n' wall_s rss_mb odometry_md5 optimized_md5 log
for log in "$@"; do
    /usr/bin/time -f '%e %M' -o "$work/time" \
        "$bin" register "$log" -o "$work/out.mcap" --force --quiet ${MIREG_FLAGS:-} >/dev/null
    read -r wall rss_kb < "$work/time"
    "$bin" export "$work/out.mcap" --odometry --format tum -o "$work/odo.tum" >/dev/null
    "$bin" export "$work/out.mcap" --format tum -o "$work/opt.tum" >/dev/null
    printf '%-8s %-8s %-32s %-32s %s\n' "$wall" "$((rss_kb / 1024))" \
        "$(md5sum < "$work/odo.tum" | cut -d' ' -f1)" "$(md5sum < "$work/opt.tum" | cut -d' ' -f1)" "$log"
done
