#!/usr/bin/env bash
# What a worker costs the owner of a spare machine (docs/farm.md, "A worker
# on a spare machine"): a CPU-bound foreground program, `gzip -9` of a fixed
# 64 MiB file on every core, timed
#   1. alone,
#   2. beside a worker at its default priority (idle) rendering on every core,
#   3. beside a worker at `--priority normal` rendering on every core;
# the foreground's slowdown against (1) for each, over interleaved rounds.
#
#   bench/spare.sh [ROUNDS]        # default 3
#
# Uses the release binaries (built here). Run it on an otherwise idle
# machine: the load average is printed with every round.
set -euo pipefail
cd "$(dirname "$0")/.."
rounds=${1:-3}
R=target/release
cargo build --release -p trevi-coordinator -p trevi-worker -p trevi-submit --bins
work=$(mktemp -d)
trap 'kill $(jobs -p) 2>/dev/null || true; rm -rf "$work"' EXIT
cores=$(nproc)

# The fixed input: 64 MiB of text that compresses (the repository's own
# sources, repeated), the same bytes every run.
while [ "$(stat -c %s "$work/input" 2>/dev/null || echo 0)" -lt $((64 << 20)) ]; do
    git ls-files -z '*.rs' | xargs -0 cat >>"$work/input"
done
truncate -s $((64 << 20)) "$work/input"

# The foreground: one gzip -9 per core, all at once; prints wall seconds.
foreground() {
    local t0 t1
    t0=$(date +%s.%N)
    local pids=()
    for _ in $(seq "$cores"); do
        gzip -9 -c "$work/input" >/dev/null &
        pids+=($!)
    done
    wait "${pids[@]}"
    t1=$(date +%s.%N)
    echo "$t1 - $t0" | bc
}

start_coordinator() {
    rm -rf "$work/data"
    $R/trevi-coordinator --listen 127.0.0.1:0 --data-dir "$work/data" >"$work/coord.out" 2>"$work/coord.err" &
    CP=$!
    for _ in $(seq 100); do
        PORT=$(sed -n 's/listening on .*:\([0-9]*\)/\1/p' "$work/coord.out")
        [ -n "$PORT" ] && return 0
        sleep 0.05
    done
    echo "the coordinator did not start" >&2
    exit 1
}

# A job far longer than the foreground: the Cornell box at 2048x2048,
# supersample 4.
sed -e 's/width="480" height="480" supersample="2"/width="2048" height="2048" supersample="4"/' \
    examples/cornell.xml >"$work/long.xml"
grep -q 'width="2048"' "$work/long.xml"

# Runs the foreground beside a busy worker started with extra args "$@".
beside_worker() {
    start_coordinator
    $R/trevi-worker --coordinator "http://127.0.0.1:$PORT" --threads "$cores" "$@" 2>"$work/worker.err" &
    WP=$!
    $R/trevi-submit "$work/long.xml" --camera front -o "$work/long.png" --quiet --detach 2>"$work/submit.err" \
        --coordinator "http://127.0.0.1:$PORT" >/dev/null
    # Wait until the worker renders (its CPU time grows).
    for _ in $(seq 100); do
        [ "$(awk '{print $14}' "/proc/$WP/stat")" -gt 50 ] && break
        sleep 0.1
    done
    foreground
    kill "$WP" "$CP"; wait "$WP" "$CP" 2>/dev/null || true
    unset WP CP
}

printf '%-6s %-12s %-24s %-24s %s\n' round "alone s" "beside idle worker s" "beside normal worker s" load
for i in $(seq "$rounds"); do
    l=$(cut -d' ' -f1 /proc/loadavg)
    a=$(foreground)
    b=$(beside_worker)
    c=$(beside_worker --priority normal)
    printf '%-6s %-12s %-24s %-24s %s\n' "$i" "$a" "$b ($(echo "scale=1; 100 * ($b - $a) / $a" | bc) %)" \
        "$c ($(echo "scale=1; 100 * ($c - $a) / $a" | bc) %)" "$l"
done
