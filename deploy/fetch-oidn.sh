#!/bin/sh
# Fetches Intel Open Image Denoise 2.5.1, which Debian does not package, from
# the Python package index's `pyoidn` wheel (it ships libOpenImageDenoise
# with its core and CPU-device libraries under pyoidn/oidn/lib), unpacks it
# with Python's zipfile into DIR (default target/oidn) and prints the
# directory to give as OIDN_DIR. Nothing is fetched when DIR has it already.
#
#   OIDN_DIR=$(deploy/fetch-oidn.sh) cargo build --release -p trevi-submit --features denoise
#
# Used by .ci/run (the denoiser's tests) and deploy/build-images.sh (the
# image's trevi-submit denoises). Needs python3 with pip. Messages go to
# standard error; standard output is the directory alone.
set -eu
root=${1:-target/oidn}
version=2.5.1.0
if [ ! -e "$root/pyoidn/oidn/lib/libOpenImageDenoise.so" ]; then
    echo "fetch-oidn: pyoidn==$version from the Python package index into $root" >&2
    rm -rf "$root"
    mkdir -p "$root/wheel"
    python3 -m pip download --quiet --no-deps "pyoidn==$version" -d "$root/wheel" >&2
    python3 -m zipfile -e "$root"/wheel/pyoidn-*.whl "$root"
    rm -rf "$root/wheel"
fi
cd "$root/pyoidn/oidn" && pwd
