#!/usr/bin/env bash
# The scale goal of docs/benchmarks.md ("The farm at scale"), checked in one
# command on a machine with the cores for it: 1,000 simulated workers of 16
# cores on the cheap scene (about 3.4 Gpixel/s of demand) against one real
# coordinator, uploading the encoded PNG segments of a real 8192×6144 render
# of that scene, as Stage 7 ran it on two cores.
#
#   bench/scale-goal.sh                          # coordinator on CPUs 0-3, simulator on the rest
#   COORD_CPUS=0-7 SIM_CPUS=8-47 bench/scale-goal.sh
#   WORKERS=300 bench/scale-goal.sh              # another N
#   CHEAP_NS=4734 (the default) SECS=8 DATA_DIR=/dev/shm   # where its data dir is made
#
# 1. Renders examples/cornell.xml (camera `corner`) at 8192×6144 with
#    trevi-submit into target/scale-goal/c8k.png (written whole or not at
#    all), once (two minutes on two
#    cores; kept for later runs).
# 2. Starts a coordinator pinned to COORD_CPUS with a fresh data dir made
#    in DATA_DIR (tmpfs by default, as in Stage 7; removed at the end) and runs `farm_bench scale`
#    pinned to SIM_CPUS against it.
# 3. The simulator prints tiles/s against the modelled demand, the
#    coordinator's CPU and peak RSS, the time its locks were held, its own
#    CPU, and a verdict: the coordinator kept up when it took 95 % of the
#    demand or more. If the simulator used over 90 % of its cores the run is
#    not conclusive: give it more.
#
# The simulator needs less CPU than the coordinator for the same pixels
# (here 0.3-0.6 ns a pixel against the coordinator's 0.65-1.2, Stage 7 and
# Stage 8): the goal wants about 3 cores for the coordinator and 1-2 for
# the simulator, so a machine of 6 cores or more.
set -euo pipefail
cd "$(dirname "$0")/.."
ncpu=$(nproc)
coord_cpus=${COORD_CPUS:-0-3}
sim_cpus=${SIM_CPUS:-4-$((ncpu - 1))}
workers=${WORKERS:-1000}
cost=${CHEAP_NS:-4734}
if [ "$ncpu" -lt 6 ] && [ -z "${COORD_CPUS:-}" ]; then
    echo "this machine has $ncpu CPUs; the goal wants 6 or more (or set COORD_CPUS and SIM_CPUS)" >&2
    exit 2
fi

cargo build --release -p trevi-coordinator --bins --benches -p trevi-submit
B=$(ls -t target/release/deps/farm_bench-* | grep -v '[.]d$' | head -1)
mkdir -p target/scale-goal
render=target/scale-goal/c8k.png
if [ ! -s "$render" ]; then
    sed -e 's/width="480" height="360"/width="8192" height="6144"/' examples/cornell.xml \
        >target/scale-goal/cornell8k.xml
    grep -q 'width="8192" height="6144"' target/scale-goal/cornell8k.xml
    target/release/trevi-submit target/scale-goal/cornell8k.xml --camera corner -o "$render" -q
fi

# A directory of its own: a DATA_DIR given is never emptied.
data=$(mktemp -d "${DATA_DIR:-/dev/shm}/trevi-goal.XXXXXX")
out=$(mktemp)
trap 'kill $(jobs -p) 2>/dev/null || true; rm -rf "$data" "$out"' EXIT
taskset -c "$coord_cpus" target/release/trevi-coordinator --listen 127.0.0.1:0 \
    --http 127.0.0.1:0 --data-dir "$data" --max-jobs-per-submitter 100000 \
    --window-mib 256 >"$out" 2>&1 &
cp=$!
for _ in $(seq 100); do
    grep -q "monitor on" "$out" && break
    sleep 0.1
done
addr=$(sed -n 's/.*listening on \([0-9.:]*\).*/\1/p' "$out")
http=$(sed -n 's|.*monitor on http://\([0-9.:]*\).*|\1|p' "$out")
if [ -z "$addr" ] || [ -z "$http" ]; then
    echo "the coordinator did not start:" >&2
    cat "$out" >&2
    exit 1
fi
echo "coordinator on CPUs $coord_cpus, simulator on CPUs $sim_cpus, $workers workers of 16 cores, $cost ns a pixel"
taskset -c "$sim_cpus" "$B" scale --coordinator "http://$addr" --pid "$cp" --workers "$workers" \
    --cores 16 --cost-ns "$cost" --secs "${SECS:-8}" --segments-from "$render" --metrics "$http"
