#!/bin/sh
# A/B of two builds of trevi-bench on whole renders: user + system
# CPU-seconds of `trevi-bench render SCENE CAMERA --threads 1`, the two
# binaries alternating ROUNDS times so that a change in machine load hits
# both, with the mean pixel value (a changed image shows there) and the load
# average. Used for the shading round of docs/performance.md (1000x750 and
# 300x225 copies of bench/cornell-nefertiti.xml, made by changing the
# camera's width and height in a copy next to meshes/nefertiti.obj).
#
#   bench/ab-render.sh SCENE CAMERA BASE_BIN NEW_BIN
#
# Environment: ROUNDS (default 2).
set -eu
[ $# -eq 4 ] || { echo "usage: bench/ab-render.sh SCENE CAMERA BASE_BIN NEW_BIN" >&2; exit 2; }
scene=$1 camera=$2
OUT=$(mktemp -d /tmp/trevi-ab-render.XXXXXX)
for round in $(seq "${ROUNDS:-2}"); do
    for bin in "$3" "$4"; do
        /usr/bin/time -f "%U %S" -o "$OUT/time" "$bin" render "$scene" "$camera" --threads 1 > "$OUT/out"
        cpu=$(awk '{ print $1 + $2 }' "$OUT/time")
        mean=$(grep -o 'mean value [0-9.]*' "$OUT/out" | cut -d' ' -f3)
        echo "round $round  $bin  cpu $cpu s  mean $mean  load $(cut -d' ' -f1 /proc/loadavg)"
    done
done | tee "$OUT/ab.txt"
awk '{ if (NR % 2 == 1) base = $5; else { r = $5 / base; n++; s += log(r) } }
     END { if (n) printf "new / base CPU: geometric mean %.3f of %d rounds\n", exp(s / n), n }' "$OUT/ab.txt"
rm -rf "$OUT"
