#!/usr/bin/env bash
# Lays out the committed decompression-bomb seeds of fuzz/corpus (bomb_*, written by
# `cargo run --example make_fuzz_corpus`) as `mireg register` inputs in OUT (default
# target/bomb-inputs): the MCAP and ROS 1 bag files as they are, each rosbag2_compressed seed as a
# bag directory (its first byte the mode: even `file`, odd `message`; the rest the bag's file).
#   bash tools/bomb_inputs.sh [OUT]
# Peak RSS of each (docs/HARDENING.md):
#   for f in OUT/*; do TMPDIR=T /usr/bin/time -f "%M KB %e s rc %x" mireg register "$f" -o o.mcap --force --quiet; done
set -euo pipefail
cd "$(dirname "$0")/.."
out=${1:-target/bomb-inputs}
rm -rf "$out"
mkdir -p "$out"
cp fuzz/corpus/register_input/bomb_*.mcap fuzz/corpus/ros1_bag/bomb_*.bag "$out/"
for f in fuzz/corpus/rosbag2_compressed/bomb_*.bin; do
    d="$out/$(basename "$f" .bin)"
    mkdir -p "$d"
    if [ $(( $(head -c1 "$f" | od -An -tu1) % 2 )) -eq 0 ]; then
        file=bag_0.mcap.zstd mode=file
    else
        file=bag_0.mcap mode=message
    fi
    printf 'rosbag2_bagfile_information:\n  version: 5\n  storage_identifier: mcap\n  relative_file_paths:\n    - %s\n  compression_format: zstd\n  compression_mode: %s\n' \
        "$file" "$mode" > "$d/metadata.yaml"
    tail -c +2 "$f" > "$d/$file"
done
ls "$out"
