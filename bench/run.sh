#!/bin/sh
# Trevi's performance benchmark, side by side with Embree 3 (docs/performance.md).
#
#   bench/run.sh            # micro-benchmarks + both full-size frames
#   bench/run.sh micro      # build and traversal only (a few minutes)
#   bench/run.sh render     # the two 3000x2250 frames only (trevi-bench, then trevi-submit,
#                           # then trevi-bench mix: a sample of their tiles end to end
#                           # against traversal alone on the same recorded rays)
#
# Needs ../shared/meshes/nefertiti.obj beside the checkout. Installs Debian's
# libembree-dev (Embree 3) with apt-get when it is missing. Environment:
# REPS (default 5), THREADS (default 2), OUT (default a temporary directory),
# MESHES (default ../shared/meshes), CARGO_TARGET_DIR as for cargo;
# BEFORE=<rev>: also render both frames with trevi-bench built from that
# commit (in a worktree at target/before-src, built into target/before), in
# the same run, each frame after then before, rays per CPU-second side by
# side (and the same-mix figures of both); SUBMIT=0 skips the trevi-submit
# renders of the frames; CAMERAS (default "whitted effects") picks the
# full-size frames rendered; MIX=0 skips the same-mix figures.
set -eu
cd "$(dirname "$0")/.."
ROOT=$(pwd)
MESHES=${MESHES:-"$ROOT/../shared/meshes"}
REPS=${REPS:-5}
THREADS=${THREADS:-2}
OUT=${OUT:-$(mktemp -d /tmp/trevi-bench.XXXXXX)}
WHAT=${1:-all}
mkdir -p "$OUT"

if [ ! -f /usr/include/embree3/rtcore.h ]; then
    SUDO=""
    [ "$(id -u)" -eq 0 ] || SUDO=sudo
    $SUDO apt-get update
    $SUDO apt-get install -y libembree-dev
fi
cc -O2 -std=c11 -Wall -o "$OUT/embree_bench" bench/embree/embree_bench.c -lembree3 -lpthread -lm
if [ "${SUBMIT:-1}" = 0 ] || [ "$WHAT" = micro ]; then
    cargo build --release -p trevi-bench
else
    cargo build --release -p trevi-bench -p trevi-submit
fi
BIN="$ROOT/target/release/trevi-bench"
[ -n "${CARGO_TARGET_DIR:-}" ] && BIN="$CARGO_TARGET_DIR/release/trevi-bench"
SUBMIT_BIN="$(dirname "$BIN")/trevi-submit"
BEFORE_BIN=""
if [ -n "${BEFORE:-}" ] && [ "$WHAT" != micro ]; then
    if [ -d target/before-src ]; then
        git -C target/before-src checkout -q --detach "$BEFORE"
    else
        git worktree add -q --detach target/before-src "$BEFORE"
    fi
    (cd target/before-src && CARGO_TARGET_DIR="$ROOT/target/before" cargo build --release -p trevi-bench)
    BEFORE_BIN="$ROOT/target/before/release/trevi-bench"
    BEFORE_REV=$(git rev-parse --short "$BEFORE")
fi

echo "# $(date -u '+%Y-%m-%d %H:%M UTC'), $(nproc) CPUs: $(grep -m1 'model name' /proc/cpuinfo | cut -d: -f2 | sed 's/^ //')," \
    "family $(grep -m1 'cpu family' /proc/cpuinfo | cut -d: -f2 | tr -d ' ')" \
    "model $(grep -m1 '^model[[:space:]]' /proc/cpuinfo | cut -d: -f2 | tr -d ' ')," \
    "$(grep -m1 '^flags' /proc/cpuinfo | grep -o -w -E 'avx2|avx512f' | tr '\n' ' ')"
REV=$(git rev-parse --short HEAD 2>/dev/null || echo "${TREVI_REV:-?}")
echo "# node test path: TREVI_SIMD=${TREVI_SIMD:-unset (the best this machine runs: avx where it runs, else sse on x86_64)}"
echo "# trevi $REV, embree $(dpkg-query -W -f='${Version}' libembree-dev 2>/dev/null || echo '?'), load average $(cut -d' ' -f1-3 /proc/loadavg)"

if [ "$WHAT" = all ] || [ "$WHAT" = micro ]; then
    "$BIN" micro --out "$OUT" --meshes "$MESHES" --embree "$OUT/embree_bench" \
        --reps "$REPS" --threads "$THREADS"
fi

if [ "$WHAT" = all ] || [ "$WHAT" = render ]; then
    # A bundle may not reach outside its directory: copy scene and mesh.
    mkdir -p "$OUT/bundle/meshes"
    cp bench/cornell-nefertiti.xml "$OUT/bundle/"
    cp "$MESHES/nefertiti.obj" "$OUT/bundle/meshes/"
    # One frame with one build of trevi-bench: its own line, then a table
    # row (rays, CPU = user + system of the whole process, rays per
    # CPU-second, wall, peak RSS, mean pixel value).
    frame() { # LABEL BIN CAMERA
        /usr/bin/time -f "%U %S %e %M" -o "$OUT/time-$1-$3.txt" "$2" render \
            "$OUT/bundle/cornell-nefertiti.xml" "$3" --threads "$THREADS" > "$OUT/render-$1-$3.txt"
        cat "$OUT/render-$1-$3.txt"
        rays=$(grep -o '[0-9]* rays,' "$OUT/render-$1-$3.txt" | cut -d' ' -f1)
        mean=$(grep -o 'mean value [0-9.]*' "$OUT/render-$1-$3.txt" | cut -d' ' -f3)
        read -r user sys wall rss < "$OUT/time-$1-$3.txt"
        echo "$3 $1 $rays $user $sys $wall $rss $mean" |
            awk '{ cpu = $4 + $5; printf "| %s | %s | %s | %.2f s | **%.2f** | %.1f s | %.1f MiB | %s |\n",
                   $1, $2, $3, cpu, $3 / cpu / 1e6, $6, $7 / 1024, $8 }' >> "$OUT/frames.md"
    }
    : > "$OUT/frames.md"
    for cam in ${CAMERAS:-whitted effects}; do
        frame "$REV" "$BIN" "$cam"
        [ -n "$BEFORE_BIN" ] && frame "$BEFORE_REV" "$BEFORE_BIN" "$cam"
        [ "${SUBMIT:-1}" = 0 ] && continue
        # The same frame as users render it: trevi-submit's embedded farm,
        # tiles stitched into a streamed PNG.
        echo "trevi-submit $cam:"
        /usr/bin/time -v "$SUBMIT_BIN" "$OUT/bundle/cornell-nefertiti.xml" --camera "$cam" \
            -o "$OUT/$cam.png" --threads "$THREADS" --quiet 2> "$OUT/time-submit-$cam.txt"
        grep -E "Elapsed|Maximum resident|User time|System time" "$OUT/time-submit-$cam.txt"
    done
    echo "# the 3000x2250 frames, trevi-bench render --threads $THREADS (load average $(cut -d' ' -f1-3 /proc/loadavg) at the end):"
    echo "| camera | build | rays | CPU (user + system) | M rays/CPU-s | wall | peak RSS | mean pixel value |"
    echo "|---|---|---:|---:|---:|---:|---:|---:|"
    cat "$OUT/frames.md"
    # Same ray mix: every 8th tile of the whitted frame, every 64th of the
    # effects frame (about 12 M and 28 M rays, recorded in memory).
    [ "${MIX:-1}" = 0 ] || for bin in "$BIN" $BEFORE_BIN; do
        echo "# mix with $bin"
        "$bin" mix "$OUT/bundle/cornell-nefertiti.xml" whitted --every 8 --reps 3 --threads "$THREADS"
        "$bin" mix "$OUT/bundle/cornell-nefertiti.xml" effects --every 64 --reps 3 --threads "$THREADS"
    done
fi
echo "# load average at the end $(cut -d' ' -f1-3 /proc/loadavg); files in $OUT"
