#!/usr/bin/env bash
# The farm at scale without a cluster (docs/benchmarks.md "The farm at
# scale"): one process of N simulated workers against one real coordinator
# on loopback, for N in a sweep, with one tile per lease, with leases
# sized from the measured cost (multi-tile), and with sized leases uploaded
# as encoded PNG segments (segments), on a cheap and an expensive scene's
# measured per-pixel cost.
#
#   bench/scale.sh [CORES] [N...]     # default 16 cores, N = 1 3 10 30 100 300 1000
#   CHEAP_NS=4734 EXPENSIVE_NS=31010 bench/scale.sh ...   # costs given, not measured
#   MODES="multi segments" bench/scale.sh ...   # some modes only (default: single multi segments)
#   SEG_SIZE=8192 bench/scale.sh ...   # the segments mode's frame edge (default 8192)
#   WINDOW_MIB=256 bench/scale.sh ...  # the coordinator's --window-mib (default: its own, 32)
#
# 1. `farm_bench cost` measures ns per pixel of examples/cornell.xml: camera
#    `corner` (Whitted: shadows, reflection, refraction; the cheap scene) and
#    camera `front` with ao-samples and diffuse-samples 16 (the expensive one).
#    The cost is wall time on one thread: on a loaded machine it comes out
#    several times too high, so CHEAP_NS / EXPENSIVE_NS can give the figures
#    of an idle run instead (sweeps that are compared must model the same
#    cost).
# 2. For each cost, mode and N: a fresh coordinator pinned to core 0, the
#    simulated workers (`farm_bench scale`) pinned to core 1; tiles/s
#    against the modelled demand, lease latency p50/p99, coordinator CPU and
#    peak RSS. The load average is printed with every line: on a shared
#    machine the figures are only as quiet as it is.
# 3. The segments mode (`scale --segments`): the workers announce the PNG
#    encoder and upload a `png_segments` lease as precomputed segments of
#    about 0.55 bytes a pixel (the cheap scene's) and preview sums; frames
#    of SEG_SIZE² (8192² by default, so that fewer frames are in flight:
#    1,000 workers with two leases of a second each need about 100 of them)
#    kept queued in a number derived from N (see farm_bench.rs), which the
#    coordinator is allowed (--max-jobs-per-submitter). Against a
#    coordinator without the segment path every lease is uploaded as floats
#    and the report says "0 of ... leases uploaded as segments".
set -euo pipefail
cd "$(dirname "$0")/.."
cores=${1:-16}
shift || true
ns=("$@")
[ ${#ns[@]} -gt 0 ] || ns=(1 3 10 30 100 300 1000)
R=target/release
cargo build --release -p trevi-coordinator --bins --benches
B=$(ls -t target/release/deps/farm_bench-* | grep -v '[.]d$' | head -1)
work=$(mktemp -d)
trap 'kill $(jobs -p) 2>/dev/null || true; rm -rf "$work"' EXIT
load() { cut -d' ' -f1 /proc/loadavg; }

sed -e 's/ao-samples="4"/ao-samples="16" diffuse-samples="16"/' examples/cornell.xml >"$work/expensive.xml"
grep -q 'diffuse-samples="16"' "$work/expensive.xml"
cost() { "$B" cost "$@" | tee /dev/stderr | sed -n 's/.*: \([0-9]*\) ns per pixel.*/\1/p'; }
cheap=${CHEAP_NS:-$(cost examples/cornell.xml --camera corner --tiles 16)}
expensive=${EXPENSIVE_NS:-$(cost "$work/expensive.xml" --camera front --tiles 4)}
echo "cost per pixel: cheap $cheap ns, expensive $expensive ns"

start_coordinator() {
    # The previous coordinator's port must not be read as this one's.
    rm -rf "$work/data" "$work/coord.out"
    taskset -c 0 $R/trevi-coordinator --listen 127.0.0.1:0 --data-dir "$work/data" \
        --max-jobs-per-submitter 100000 ${WINDOW_MIB:+--window-mib "$WINDOW_MIB"} >"$work/coord.out" 2>"$work/coord.err" &
    CP=$!
    for _ in $(seq 100); do
        PORT=$(sed -n 's/listening on .*:\([0-9]*\)/\1/p' "$work/coord.out" 2>/dev/null || true)
        [ -n "$PORT" ] && return 0
        sleep 0.05
    done
    echo "the coordinator did not start" >&2
    cat "$work/coord.err" >&2
    exit 1
}

for scene in cheap expensive; do
    cost=${!scene}
    for mode in ${MODES:-single multi segments}; do
        flag=()
        case $mode in
        single) ;;
        multi) flag=(--multi) ;;
        segments) flag=(--segments --width "${SEG_SIZE:-8192}" --height "${SEG_SIZE:-8192}") ;;
        *) echo "unknown mode $mode" >&2; exit 1 ;;
        esac
        for n in "${ns[@]}"; do
            start_coordinator
            echo -n "$scene $mode (load $(load)) "
            taskset -c 1 "$B" scale --coordinator "http://127.0.0.1:$PORT" --pid "$CP" \
                --workers "$n" --cores "$cores" --cost-ns "$cost" "${flag[@]}" --secs "${SECS:-8}"
            kill "$CP"; wait "$CP" 2>/dev/null || true
        done
    done
done
