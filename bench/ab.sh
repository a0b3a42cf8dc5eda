#!/bin/sh
# A/B of two builds of trevi-bench on the traversal micro-benchmark: rays per
# CPU-second of one tracing thread, the two binaries alternating ROUNDS times
# so that a change in machine load hits both. Used for the "tried" table in
# docs/performance.md.
#
#   git worktree add /tmp/base HEAD~1
#   (cd /tmp/base && CARGO_TARGET_DIR=/tmp/base-target cargo build --release -p trevi-bench)
#   cargo build --release -p trevi-bench
#   bench/ab.sh /tmp/base-target/release/trevi-bench target/release/trevi-bench
#
# Environment: ROUNDS (default 2), REPS per run (default 2), MESHES as for run.sh.
set -eu
[ $# -eq 2 ] || { echo "usage: bench/ab.sh BASE_BIN NEW_BIN" >&2; exit 2; }
cd "$(dirname "$0")/.."
MESHES=${MESHES:-"$(pwd)/../shared/meshes"}
OUT=$(mktemp -d /tmp/trevi-ab.XXXXXX)
for round in $(seq "${ROUNDS:-2}"); do
    for bin in "$1" "$2"; do
        echo "== round $round: $bin"
        "$bin" micro --out "$OUT" --meshes "$MESHES" --reps "${REPS:-2}" --threads 1 2>/dev/null |
            grep -E '\| (primary|shadow|incoherent) \|' |
            awk -F'|' '{ printf "%-18s %-11s %s M rays/CPU-s\n", $2, $3, $10 }'
    done
done | tee "$OUT/ab.txt"
# new/base per (round, mesh, ray type); their geometric mean, smallest, largest.
awk '/^== round/ { side = (++runs % 2 == 1) ? "base" : "new"; next }
     { key = $1 " " $2; if (side == "base") base[key] = $3; else { r = $3 / base[key]; n++; s += log(r);
       if (min == "" || r < min) min = r; if (r > max) max = r } }
     END { if (n) printf "new / base: geometric mean %.3f of %d ratios (%.2f-%.2f)\n", exp(s / n), n, min, max }' "$OUT/ab.txt"
rm -rf "$OUT"
