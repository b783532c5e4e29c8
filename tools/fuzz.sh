#!/usr/bin/env bash
# Runs every fuzz target (fuzz/, cargo-fuzz + libFuzzer with AddressSanitizer) for SECONDS each
# (default 600), starting from the committed corpus, with a 2 GiB RSS limit; new crashes land in
# fuzz/artifacts/TARGET/. Prints one line per target: executions, corpus size, crashes.
#   bash tools/fuzz.sh [SECONDS] [TARGET...]
# Needs cargo-fuzz (`cargo install cargo-fuzz`); on a stable toolchain RUSTC_BOOTSTRAP=1 lets it
# use the nightly flags it needs.
set -euo pipefail
cd "$(dirname "$0")/.."
seconds=${1:-600}
shift || true
targets=("$@")
if [ ${#targets[@]} -eq 0 ]; then
    mapfile -t targets < <(cd fuzz && cargo fuzz list)
fi
export RUSTC_BOOTSTRAP=1
for t in "${targets[@]}"; do
    mkdir -p "fuzz/corpus/$t" "fuzz/artifacts/$t" "target/fuzz-work/$t"
    # New inputs go to a scratch corpus; the committed seeds stay as they are.
    log="target/fuzz-work/$t.log"
    set +e
    (cd fuzz && cargo fuzz run "$t" "../target/fuzz-work/$t" "corpus/$t" -- \
        -max_total_time="$seconds" -rss_limit_mb=2048 -timeout=10 -max_len=65536 \
        -print_final_stats=1) > "$log" 2>&1
    rc=$?
    set -e
    execs=$(grep -o 'stat::number_of_executed_units: *[0-9]*' "$log" | grep -o '[0-9]*$' || echo "?")
    crashes=$(find "fuzz/artifacts/$t" -type f | wc -l)
    echo "$t: exit $rc, ${execs} executions in ${seconds} s, corpus $(ls "target/fuzz-work/$t" | wc -l) files, artifacts $crashes"
done
