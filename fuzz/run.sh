#!/usr/bin/env bash
# Runs the parsers' and decoders' fuzz targets with libFuzzer (docs/numerics.md, "Fuzzing").
#
#   fuzz/run.sh [SECONDS] [TARGET...]     # default: 60 s each of every target
#
# Every input runs under libFuzzer's limits: RSS_MB (default 2048) of
# resident memory for the process (-rss_limit_mb, also -malloc_limit_mb) and
# TIMEOUT seconds (default 10) per input (-timeout). An input past either is
# a failure with its input saved, like a crash: a parser's cost must be
# bounded before the work (docs/farm.md, "Limits of each file format").
#
# Installs cargo-fuzz if it is missing. Works on a stable toolchain
# (RUSTC_BOOTSTRAP=1, no sanitizer). Seeds each corpus with the project's own
# example files the first time, so the runs start past the headers. A crash
# leaves its input in fuzz/artifacts/TARGET/ and a non-zero exit.
set -euo pipefail
cd "$(dirname "$0")"
secs=${1:-60}
shift || true
targets=("$@")
[ ${#targets[@]} -gt 0 ] || targets=(aisxml obj mtl ply bundle png jpeg exr denoise_exr state duration farm_queries requeue aovs)
rss_mb=${RSS_MB:-2048}
timeout=${TIMEOUT:-10}

if ! cargo fuzz --version >/dev/null 2>&1; then
    echo "== cargo install cargo-fuzz --locked"
    cargo install cargo-fuzz --locked
fi

# Seeds: the examples, and the real meshes beside the project when present.
seed() {
    local target=$1 pattern=$2
    mkdir -p "corpus/$target"
    [ -n "$(ls -A "corpus/$target")" ] && return 0
    find ../examples ../core/tests ../../shared/meshes -maxdepth 2 -name "$pattern" \
        -size -256k 2>/dev/null | while read -r f; do
        cp "$f" "corpus/$target/"
    done || true # a missing directory (../../shared outside the main checkout) is no failure
}
seed aisxml '*.xml'
# A scene using every textured file of the aisxml target's bundle (see
# fuzz_targets/aisxml.rs): OBJ with vt and an MTL, PLY texcoord, <uvs>, and
# the texture attributes.
cat > corpus/aisxml/textured-seed.xml <<'XML'
<scene version="1"><settings background="0 0 0"/>
<mesh id="a" file="t.obj"/><mesh id="b" file="t.ply"/>
<mesh id="q"><vertices>0 0 0 1 0 0 1 1 0</vertices><uvs>0 0 1 0 1 1</uvs><triangles>0 1 2</triangles></mesh>
<model id="ma" mesh="a"/>
<model id="mb" mesh="b"><surface diffuse="1 1 1" diffuse-texture="t.png" texture-wrap="clamp" texture-scale="2 3"/></model>
<model id="mq" mesh="q"><surface diffuse-texture="t.png"/></model>
<light type="point" position="0 0 5"/>
<camera id="c" position="0 0 5" lookat="0 0 0" fov="50"><render width="4" height="3"/></camera></scene>
XML
seed obj '*.obj'
seed mtl '*.mtl'
seed ply '*.ply'
seed png '*.png'
seed jpeg '*.jpg'
seed exr '*.exr'
seed denoise_exr '*.exr'
# The project has no JPEG or EXR files: small ones made by seeds/make.py.
for t in jpeg exr denoise_exr; do
    [ -n "$(ls -A "corpus/$t")" ] || python3 seeds/make.py seeds/out
    [ -n "$(ls -A "corpus/$t")" ] || cp seeds/out/${t#denoise_}/* "corpus/$t/"
done
mkdir -p corpus/bundle
# The state decoder starts from a valid state: a header and one empty pixel.
mkdir -p corpus/state
[ -n "$(ls -A corpus/state)" ] || python3 -c '
import struct, sys
h = b"TVPS" + struct.pack("<HHIIIIII", 1, 0, 0, 0, 1, 1, 0, 0)
sys.stdout.buffer.write(h + bytes(64))' > corpus/state/empty-pixel
# The farm's queries start from one valid input of each parser (the first
# byte picks it: see fuzz_targets/farm_queries.rs).
mkdir -p corpus/farm_queries
[ -n "$(ls -A corpus/farm_queries)" ] || {
    printf '\000frame=3&x=10&y=20&errors=1' > corpus/farm_queries/log
    printf '\0017d\nworker' > corpus/farm_queries/usage
    printf '\0020.25' > corpus/farm_queries/cost
    printf '\00390d' > corpus/farm_queries/retention
    printf '\004alice tok-a\nbob tok-b' > corpus/farm_queries/tokens
    printf '\005render-7' > corpus/farm_queries/unblock
}
# The requeue grammar starts from a body, a range and a rect.
mkdir -p corpus/requeue
[ -n "$(ls -A corpus/requeue)" ] || {
    printf '%s' '{"frames": "2-4", "rect": [0, 1, 2, 3]}' > corpus/requeue/body
    printf '%s' '3-7' > corpus/requeue/frames
    printf '%s' '1,2,30,40' > corpus/requeue/rect
}
# The duration grammar starts from each unit.
mkdir -p corpus/duration
[ -n "$(ls -A corpus/duration)" ] || for d in 90s 10m 2h 7d; do
    printf '%s' "$d" > "corpus/duration/$d"
done

export RUSTC_BOOTSTRAP=1
for t in "${targets[@]}"; do
    echo "== $t: ${secs} s, -rss_limit_mb=$rss_mb -timeout=$timeout"
    mkdir -p "corpus/$t"
    cargo fuzz run --sanitizer none "$t" "corpus/$t" -- -max_total_time="$secs" \
        -rss_limit_mb="$rss_mb" -malloc_limit_mb="$rss_mb" -timeout="$timeout" \
        -report_slow_units=1 -print_final_stats=1
done
