#!/usr/bin/env bash
# Runs the libFuzzer targets of fuzz/ (one at a time, one process each) and prints a table
# of executions and crashes.
#
#   scripts/fuzz.sh [TARGET...] [--runs N] [--max-time SECONDS] [--no-studio]
#
# TARGET: puppet tracks_json live_link_csv mapping session image video (default: all, the
# puppet last). --runs: executions per target (default 1000000); --max-time: the time cap
# per target (default 14400 s); --no-studio: build without the app (the session target
# then checks the tracking crate's reader only).
#
# Installs a nightly toolchain (rustup) and cargo-fuzz (crates.io) when missing. Seeds are
# read from fuzz/corpus/<target>/ (committed; `cargo run -p likeness-fuzzing --example
# make_corpus` writes them), inputs libFuzzer finds go to fuzz/work/<target>/, crashes to
# fuzz/artifacts/<target>/, logs to fuzz/logs/<target>.log (all ignored by git). A crash
# stops its target; reproduce it with `cargo +nightly fuzz run <target> <file>`, and keep
# the input in fuzz/regressions/<target>/ once it is understood (the stable test
# `cargo test -p likeness-fuzzing` runs every file there).
set -euo pipefail
cd "$(dirname "$0")/.."

ALL=(tracks_json live_link_csv mapping session image video puppet)
targets=()
runs=1000000
max_time=14400
features=()
while [ $# -gt 0 ]; do
    case "$1" in
        --runs) runs="$2"; shift 2 ;;
        --max-time) max_time="$2"; shift 2 ;;
        --no-studio) features=(--no-default-features); shift ;;
        -h|--help) sed -n '2,19p' "$0"; exit 0 ;;
        -*) echo "unknown option $1" >&2; exit 2 ;;
        *)
            if [[ " ${ALL[*]} " != *" $1 "* ]]; then
                echo "unknown target $1 (one of: ${ALL[*]})" >&2
                exit 2
            fi
            targets+=("$1"); shift ;;
    esac
done
[ ${#targets[@]} -gt 0 ] || targets=("${ALL[@]}")

# The toolchain and cargo-fuzz.
if ! rustup run nightly rustc --version >/dev/null 2>&1; then
    rustup toolchain install nightly --profile minimal
fi
if ! cargo fuzz --version >/dev/null 2>&1; then
    cargo install cargo-fuzz --locked
fi

# Builds share the machine: one job unless told otherwise.
export CARGO_BUILD_JOBS="${CARGO_BUILD_JOBS:-1}"
cargo +nightly fuzz build "${features[@]}"

mkdir -p fuzz/logs
rows=()
failed=0
for t in "${targets[@]}"; do
    mkdir -p "fuzz/work/$t" "fuzz/artifacts/$t"
    log="fuzz/logs/$t.log"
    dict=()
    [ "$t" = image ] || dict=(-dict=fuzz/likeness.dict)
    echo "== $t: $runs runs, at most $max_time s (log: $log)"
    start=$(date +%s)
    status=0
    # Allocations are bounded: image decoding and puppets allocate, but never 2 GB.
    cargo +nightly fuzz run "${features[@]}" "$t" "fuzz/work/$t" "fuzz/corpus/$t" -- \
        -runs="$runs" -max_total_time="$max_time" -timeout=30 \
        -rss_limit_mb=2048 -malloc_limit_mb=2048 -print_final_stats=1 \
        "${dict[@]}" >"$log" 2>&1 || status=$?
    seconds=$(( $(date +%s) - start ))
    # Executions: libFuzzer's final count, else the last status line before a crash.
    execs=$(sed -n 's/^stat::number_of_executed_units: *\([0-9]*\).*/\1/p' "$log" | tail -1)
    [ -n "$execs" ] || execs=$(sed -n 's/^Done \([0-9]*\) runs.*/\1/p' "$log" | tail -1)
    [ -n "$execs" ] || execs=$(sed -n 's/^#\([0-9]*\)[[:space:]].*/\1/p' "$log" | tail -1)
    crashes=$(grep -c 'Test unit written to' "$log" || true)
    if [ "$status" -ne 0 ] && [ "$crashes" -eq 0 ]; then
        crashes="1 (exit $status)"
    fi
    [ "$crashes" = 0 ] || failed=1
    rows+=("$(printf '%-14s %12s %10s %8s' "$t" "${execs:-?}" "$crashes" "$seconds")")
    grep 'Test unit written to' "$log" || true
done

echo
printf '%-14s %12s %10s %8s\n' target executions crashes seconds
for r in "${rows[@]}"; do echo "$r"; done
exit "$failed"
