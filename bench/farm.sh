#!/usr/bin/env bash
# The farm's benchmarks of docs/benchmarks.md in one run:
#
#   bench/farm.sh [ROUNDS]        # default 3
#
# 1. Coordinator ingest: the coordinator pinned to core 0, a synthetic worker
#    (8 connections) pinned to core 1 replaying ready 64×64 tiles of a
#    4096×4096 PNG frame; tiles per second from submission to the file in
#    place (coordinator/benches/farm_bench.rs, mode `ingest`).
# 2. One worker through the coordinator against the embedded render and a
#    direct render (no farm) of the same frame: examples/cornell.xml camera
#    `front` at 960×960, supersample 2; wall and CPU seconds, interleaved
#    rounds, outputs compared byte for byte.
#
# Needs taskset (util-linux). Run it on an otherwise idle machine: the load
# average is printed with every figure.
set -euo pipefail
cd "$(dirname "$0")/.."
rounds=${1:-3}
R=target/release
cargo build --release -p trevi-coordinator -p trevi-worker -p trevi-submit --bins --benches
B=$(ls -t target/release/deps/farm_bench-* | grep -v '[.]d$' | head -1)
work=$(mktemp -d)
trap 'kill $(jobs -p) 2>/dev/null || true; rm -rf "$work"' EXIT
load() { cut -d' ' -f1 /proc/loadavg; }

# Starts a coordinator (extra args: taskset prefix); sets CP and PORT.
start_coordinator() {
    rm -rf "$work/data"
    "$@" $R/trevi-coordinator --listen 127.0.0.1:0 --data-dir "$work/data" >"$work/coord.out" 2>"$work/coord.err" &
    CP=$!
    for _ in $(seq 100); do
        PORT=$(sed -n 's/listening on .*:\([0-9]*\)/\1/p' "$work/coord.out")
        [ -n "$PORT" ] && return 0
        sleep 0.05
    done
    echo "the coordinator did not start" >&2
    cat "$work/coord.err" >&2
    exit 1
}

echo "== ingest: 4096x4096 PNG, 64x64 tiles, 8 synthetic connections"
for i in $(seq "$rounds"); do
    start_coordinator taskset -c 0
    echo "round $i (load $(load))"
    taskset -c 1 "$B" ingest --coordinator "http://127.0.0.1:$PORT" --pid "$CP" \
        --width 4096 --height 4096 --tile 64 --workers 8 --format png
    kill "$CP"; wait "$CP" 2>/dev/null || true
done

echo "== one worker through the coordinator vs embedded vs direct (960x960, supersample 2)"
sed -e 's/width="480" height="480" supersample="2"/width="960" height="960" supersample="2"/' \
    examples/cornell.xml >"$work/mid.xml"
grep -q 'width="960"' "$work/mid.xml"
cpu() { # user+system seconds of a finished or running PID's /proc stat
    awk '{print ($14 + $15) / 100}' "/proc/$1/stat"
}
printf '%-6s %-22s %-22s %-34s\n' round "direct wall/CPU s" "embedded wall/CPU s" "farm wall/CPU s (coord+worker+submit)"
for i in $(seq "$rounds"); do
    l=$(load)
    t0=$(date +%s.%N)
    /usr/bin/time -f "%U %S" -o "$work/t.direct" "$B" direct "$work/mid.xml" "$work/direct.png" >/dev/null 2>&1
    t1=$(date +%s.%N)
    /usr/bin/time -f "%U %S" -o "$work/t.emb" $R/trevi-submit "$work/mid.xml" --camera front -o "$work/emb.png" --quiet
    t2=$(date +%s.%N)
    start_coordinator
    $R/trevi-worker --coordinator "http://127.0.0.1:$PORT" --priority normal 2>"$work/worker.err" &
    WP=$!
    sleep 0.3
    t3=$(date +%s.%N)
    /usr/bin/time -f "%U %S" -o "$work/t.sub" $R/trevi-submit "$work/mid.xml" --camera front -o "$work/farm.png" --quiet \
        --coordinator "http://127.0.0.1:$PORT"
    t4=$(date +%s.%N)
    cc=$(cpu "$CP"); wc=$(cpu "$WP")
    kill "$WP" "$CP"; wait "$WP" "$CP" 2>/dev/null || true
    sum() { awk '{print $1 + $2}' "$1"; }
    dw=$(echo "$t1 - $t0" | bc); ew=$(echo "$t2 - $t1" | bc); fw=$(echo "$t4 - $t3" | bc)
    fc=$(echo "$cc + $wc + $(sum "$work/t.sub")" | bc)
    printf '%-6s %-22s %-22s %-34s load %s\n' "$i" "$dw / $(sum "$work/t.direct")" "$ew / $(sum "$work/t.emb")" \
        "$fw / $fc ($cc+$wc+$(sum "$work/t.sub"))" "$l"
    cmp "$work/direct.png" "$work/emb.png"
    cmp "$work/emb.png" "$work/farm.png"
done
echo "outputs byte-identical in every round (cmp)"
