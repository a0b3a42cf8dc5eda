#!/usr/bin/env bash
# Renders the README's example images from examples/*.xml with the current
# code, so that they cannot drift from what trevi-submit makes. Run it after
# any change to rendering and commit the images it writes:
#
#   docs/images/make.sh
#
# Environment: TREVI_SUBMIT, a trevi-submit binary to use (default: built
# here with `cargo build --release -p trevi-submit`; any profile renders the
# same bytes, e.g. target/debug/trevi-submit after `cargo test --workspace`).
#
# docs/images/monitor.png is not a render but a screenshot of the web
# monitor; the browser test takes one (tests/tests/monitor.rs; with
# TREVI_ARTIFACTS_DIR=DIR it is written to DIR/monitor.png).
#
# A sequence's frame is listed as NAME.NN.png (frame NN of the camera's
# sequence).
#
# tests/tests/repo.rs checks that this list and the README's image links agree.
set -euo pipefail
cd "$(dirname "$0")/../.."

# scene, camera, image in docs/images
images=(
    "examples/cornell.xml front cornell-front.png"
    "examples/cornell.xml corner cornell-corner.png"
    "examples/instancing.xml main instancing.png"
    "examples/cornell-path.xml whitted cornell-whitted.png"
    "examples/cornell-path.xml path cornell-path.png"
    "examples/textured.xml main textured.png"
    "examples/turntable.xml turntable turntable.00.png"
    "examples/turntable.xml turntable turntable.06.png"
    "examples/turntable.xml turntable turntable.12.png"
    "examples/turntable.xml turntable turntable.18.png"
)

submit=${TREVI_SUBMIT:-}
if [ -z "$submit" ]; then
    cargo build --release -p trevi-submit
    submit=target/release/trevi-submit
fi
for line in "${images[@]}"; do
    read -r scene camera image <<<"$line"
    echo "== $scene, camera $camera -> docs/images/$image"
    if [[ $image =~ ^(.*)\.([0-9]+)\.png$ ]]; then
        # A frame of a sequence: NAME.NN.png is frame NN, written through
        # the pattern NAME.##.png (as many # as digits).
        digits=${BASH_REMATCH[2]}
        pattern="${BASH_REMATCH[1]}.${digits//[0-9]/#}.png"
        "$submit" "$scene" --camera "$camera" --frames "$((10#$digits))" \
            -o "docs/images/$pattern" --quiet
    else
        "$submit" "$scene" --camera "$camera" -o "docs/images/$image" --quiet
    fi
done
