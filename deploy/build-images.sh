#!/usr/bin/env bash
# Builds the Trevi image with no container registry at all:
#
#   1. cargo builds the release binaries on this machine (a no-op when they
#      are up to date);
#   2. debootstrap makes a minimal Debian root file system from Debian's
#      packages (installing debootstrap with apt first if it is missing); the
#      tarball is cached under target/deploy-cache, so reruns skip this;
#   3. `docker import` turns the tarball into the base image;
#   4. deploy/Dockerfile.runtime copies the (stripped) binaries and the health
#      probe onto that base.
#
# Usage: deploy/build-images.sh            (tags trevi:latest)
# Environment:
#   TREVI_IMAGE        image to build (default trevi:latest)
#   TREVI_SUITE        Debian suite of the base (default bookworm: the binaries
#                      need a glibc at least as new as the build machine's)
#   TREVI_MIRROR       Debian mirror (default: the one apt uses here, else
#                      http://deb.debian.org/debian)
#   TREVI_DEPLOY_CACHE cache directory (default target/deploy-cache)
#   TREVI_BIN_DIR      where the binaries are (default target/release, built
#                      here with cargo; any other directory is used as it is,
#                      e.g. target/debug after `cargo test --workspace`, whose
#                      test profile optimizes too)
#   TREVI_SKIP_CARGO=1 use target/release as it is
#   TREVI_DENOISE=0    build trevi-submit without the `denoise` feature (by
#                      default the release build has it, with Open Image
#                      Denoise fetched by deploy/fetch-oidn.sh)
#
# When trevi-submit links Open Image Denoise (whichever directory it comes
# from), the library's CPU parts go into the image with it, under
# /usr/local/lib/trevi-oidn (registered with ldconfig), so `trevi-submit
# --denoise` runs in a container.
#
# With registry access, `docker build -f deploy/Dockerfile .` does the same
# from public base images instead (see deploy/README.md).
set -euo pipefail
cd "$(dirname "$0")/.."
root=$PWD

image=${TREVI_IMAGE:-trevi:latest}
suite=${TREVI_SUITE:-bookworm}
cache=${TREVI_DEPLOY_CACHE:-$root/target/deploy-cache}
# Packages on top of debootstrap's minbase: curl for the gRPC health probe.
include=curl,ca-certificates
mkdir -p "$cache"

say() { echo "[build-images] $*"; }

# ---------------------------------------------------------------- binaries
bins=(trevi-coordinator trevi-worker trevi-submit)
bindir=${TREVI_BIN_DIR:-target/release}
if [ "${TREVI_SKIP_CARGO:-0}" != 1 ] && [ "$bindir" = target/release ]; then
    if [ "${TREVI_DENOISE:-1}" = 1 ]; then
        say "cargo build --release (${bins[*]}; trevi-submit with the denoise feature)"
        OIDN_DIR=$(deploy/fetch-oidn.sh "$root/target/oidn") \
            cargo build --release -p trevi-coordinator -p trevi-worker -p trevi-submit \
            --features trevi-submit/denoise
    else
        say "cargo build --release (${bins[*]})"
        cargo build --release -p trevi-coordinator -p trevi-worker -p trevi-submit
    fi
fi
for b in "${bins[@]}"; do
    [ -x "$bindir/$b" ] || { say "$bindir/$b is missing"; exit 1; }
done

# ---------------------------------------------------------------- root fs
mirror=${TREVI_MIRROR:-}
if [ -z "$mirror" ]; then
    mirror=$(grep -hoE '^(URIs:|deb) +[^ ]+' /etc/apt/sources.list /etc/apt/sources.list.d/*.sources \
        /etc/apt/sources.list.d/*.list 2>/dev/null | awk '{print $2}' | grep -E '/debian/?$' | head -n1 || true)
    mirror=${mirror:-http://deb.debian.org/debian}
fi
key=$(printf '%s\n' "$suite" "$include" minbase v1 | sha256sum | cut -c1-12)
tarball=$cache/rootfs-$suite-$key.tar
base=trevi-base:$suite-$key

if ! docker image inspect "$base" >/dev/null 2>&1; then
    if [ ! -s "$tarball" ]; then
        if ! command -v debootstrap >/dev/null 2>&1; then
            say "installing debootstrap with apt"
            apt-get -o DPkg::Lock::Timeout=600 update -qq || true
            DEBIAN_FRONTEND=noninteractive apt-get -o DPkg::Lock::Timeout=600 install -y -qq debootstrap
        fi
        dir=$cache/rootfs-$suite-$key.tmp
        rm -rf "$dir"
        say "debootstrap --variant=minbase $suite from $mirror (once; cached as $tarball)"
        debootstrap --variant=minbase --include="$include" "$suite" "$dir" "$mirror" \
            >"$cache/debootstrap.log" 2>&1 || {
            tail -n 30 "$cache/debootstrap.log"
            say "debootstrap failed (log: $cache/debootstrap.log)"
            exit 1
        }
        # Nothing the image needs: package caches, indexes, docs.
        rm -rf "$dir"/var/cache/apt/archives/*.deb "$dir"/var/lib/apt/lists/* \
            "$dir"/usr/share/doc/* "$dir"/usr/share/man/* "$dir"/usr/share/locale/* \
            "$dir"/var/log/* "$dir"/tmp/*
        tar --numeric-owner -C "$dir" -cf "$tarball.tmp" .
        mv "$tarball.tmp" "$tarball"
        rm -rf "$dir"
    else
        say "root file system from the cache: $tarball"
    fi
    say "docker import $tarball as $base"
    docker import "$tarball" "$base" >/dev/null
else
    say "base image $base is already loaded"
fi

# ---------------------------------------------------------------- image
ctx=$cache/context
mkdir -p "$ctx"
for b in "${bins[@]}"; do
    # Stripped copies, refreshed only when the build changed, so docker's
    # layer cache holds when nothing did.
    sum=$(sha256sum <"$bindir/$b")
    if [ ! -e "$ctx/$b" ] || [ "$sum" != "$(cat "$cache/$b.sha256" 2>/dev/null)" ]; then
        strip -o "$ctx/$b.tmp" "$bindir/$b" 2>/dev/null || cp "$bindir/$b" "$ctx/$b.tmp"
        mv "$ctx/$b.tmp" "$ctx/$b"
        echo "$sum" >"$cache/$b.sha256"
    fi
done
cp -p deploy/trevi-health "$ctx/trevi-health"
# Open Image Denoise's CPU libraries when trevi-submit links them (its GPU
# devices stay out: no GPU in these containers). An empty directory
# otherwise, which Dockerfile.runtime copies all the same.
rm -rf "$ctx/oidn" && mkdir -p "$ctx/oidn"
if readelf -d "$bindir/trevi-submit" | grep -q 'libOpenImageDenoise'; then
    oidn=$(deploy/fetch-oidn.sh "$root/target/oidn")
    for lib in libOpenImageDenoise.so.2 libOpenImageDenoise_core.so.2.5.1 \
        libOpenImageDenoise_device_cpu.so.2.5.1 libtbb.so.12; do
        cp -L "$oidn/lib/$lib" "$ctx/oidn/$lib"
    done
    say "trevi-submit denoises: Open Image Denoise's CPU libraries go in ($(du -sh "$ctx/oidn" | cut -f1))"
fi
cp deploy/Dockerfile.runtime "$ctx/Dockerfile"
say "docker build $image (base $base)"
previous=$(docker image inspect -f '{{.Id}}' "$image" 2>/dev/null || true)
DOCKER_BUILDKIT=0 docker build -q --build-arg BASE_IMAGE="$base" -t "$image" "$ctx" >/dev/null 2>"$cache/docker-build.log" || {
    cat "$cache/docker-build.log"
    say "docker build failed"
    exit 1
}
# The image this one replaces, now untagged: remove it unless a container
# still uses it.
current=$(docker image inspect -f '{{.Id}}' "$image")
if [ -n "$previous" ] && [ "$previous" != "$current" ]; then
    docker rmi "$previous" >/dev/null 2>&1 || true
fi
say "built $image: $(docker image inspect -f '{{.Size}}' "$image" | awk '{printf "%.0f MB", $1/1e6}')"
