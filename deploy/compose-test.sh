#!/usr/bin/env bash
# The compose test: a real farm in containers, a worker killed and another cut
# off mid-render, and the output still byte-identical to the embedded render.
#
#   1. build the images (deploy/build-images.sh), `up` a coordinator and
#      three workers;
#   2. from the host, `trevi-submit` a scene with enough tiles to take a while;
#   3. while it renders, `docker kill` one worker and
#      `docker network disconnect` another;
#   4. the job completes; its output is byte-identical to the embedded render
#      (`trevi-submit` without --coordinator) of the same scene;
#   5. when trevi-submit has the denoiser, `trevi-submit --denoise` inside
#      the image gives the host's bytes;
#   6. always `down -v` at the end, pass or fail, and check that no container,
#      network or volume of the project is left.
#
# Environment: TREVI_BIN_DIR (default target/release, built with cargo if
# needed), TREVI_IMAGE (default trevi:latest), TREVI_SKIP_BUILD=1 to use the
# image as it is, TREVI_REQUIRE_DENOISE=1 to fail when trevi-submit cannot
# denoise (step 5). Only 127.0.0.1 and the project's own private network are
# used: the coordinator is published on 127.0.0.1 at a free port.
set -euo pipefail
cd "$(dirname "$0")/.."
root=$PWD
t_start=$(date +%s)
say() { echo "[compose-test +$(($(date +%s) - t_start))s] $*"; }
fail() {
    say "FAIL: $*"
    exit 1
}

export TREVI_IMAGE=${TREVI_IMAGE:-trevi:latest}
bindir=${TREVI_BIN_DIR:-target/release}
case $bindir in /*) ;; *) bindir=$root/$bindir ;; esac
export TREVI_BIN_DIR=$bindir

if docker compose version >/dev/null 2>&1; then
    compose_cmd=(docker compose)
elif command -v docker-compose >/dev/null 2>&1; then
    compose_cmd=(docker-compose)
else
    fail "neither 'docker compose' nor docker-compose is installed"
fi
project=trevi-ci-$$
# Short leases so that the killed and the cut-off workers' tiles come back
# quickly; a free host port on 127.0.0.1.
export TREVI_LEASE_TTL_MS=3000 TREVI_PUBLISH=127.0.0.1: TREVI_HTTP_PUBLISH=127.0.0.1:
compose() { "${compose_cmd[@]}" -p "$project" -f "$root/deploy/docker-compose.yml" "$@"; }

work=$(mktemp -d "${TMPDIR:-/tmp}/trevi-compose-test.XXXXXX")
submit_pid=
passed=0
cleanup() {
    local rc=$?
    set +e
    [ -n "$submit_pid" ] && kill "$submit_pid" 2>/dev/null
    if [ "$passed" != 1 ]; then
        say "logs of the farm (last 40 lines per container):"
        compose logs --no-color --tail 40 2>&1 | sed 's/^/    /'
        [ -s "$work/submit.log" ] && { say "trevi-submit's log:"; sed 's/^/    /' "$work/submit.log"; }
    fi
    say "step 6: docker compose down -v"
    compose down -v --remove-orphans -t 10 >"$work/down.log" 2>&1 || cat "$work/down.log"
    local left
    left=$(
        docker ps -aq --filter "label=com.docker.compose.project=$project"
        docker network ls -q --filter "label=com.docker.compose.project=$project"
        docker volume ls -q --filter "label=com.docker.compose.project=$project"
    )
    if [ -n "$left" ]; then
        say "FAIL: left behind: $(echo $left)"
        rc=1
    else
        say "no container, network or volume of $project is left"
    fi
    rm -rf "$work"
    if [ "$rc" = 0 ]; then
        say "PASS in $(($(date +%s) - t_start)) s"
        echo "compose-test: 1 passed, 0 failed"
    else
        say "FAILED (exit $rc) after $(($(date +%s) - t_start)) s"
        echo "compose-test: 0 passed, 1 failed"
    fi
    exit "$rc"
}
trap cleanup EXIT
trap 'exit 130' INT TERM

# ------------------------------------------------------------------ step 1
say "step 1: build the images ($TREVI_IMAGE from $bindir)"
if [ "${TREVI_SKIP_BUILD:-0}" != 1 ]; then
    deploy/build-images.sh
fi
docker image inspect "$TREVI_IMAGE" >/dev/null || fail "no image $TREVI_IMAGE"
submit=$bindir/trevi-submit
[ -x "$submit" ] || fail "$submit is missing"

say "step 1: ${compose_cmd[*]} -p $project up -d --scale worker=3"
compose up -d --scale worker=3 >"$work/up.log" 2>&1 || {
    cat "$work/up.log"
    fail "compose up failed"
}
port=$(compose port coordinator 50051 | tail -n1)
port=${port##*:}
[ -n "$port" ] || fail "the coordinator's port is not published"
case $(compose port coordinator 50051 | tail -n1) in
127.0.0.1:*) ;;
*) fail "the coordinator is published on $(compose port coordinator 50051), not 127.0.0.1" ;;
esac
url=http://127.0.0.1:$port
say "step 1: coordinator at $url; waiting for every container to be healthy"
mapfile -t workers < <(compose ps -q worker)
[ "${#workers[@]}" = 3 ] || fail "expected 3 workers, found ${#workers[@]}"
coord=$(compose ps -q coordinator)
deadline=$(($(date +%s) + 90))
while :; do
    states=$(for c in "$coord" "${workers[@]}"; do docker inspect -f '{{.State.Health.Status}}' "$c"; done | sort | uniq -c | xargs)
    [ "$states" = "4 healthy" ] && break
    [ "$(date +%s)" -lt "$deadline" ] || fail "containers not healthy after 90 s: $states"
    sleep 1
done
say "step 1: coordinator and 3 workers healthy (gRPC health checks)"
"$root/deploy/trevi-health" "127.0.0.1:$port" || fail "the published port does not answer the gRPC health check"
http_port=$(compose port coordinator 8080 | tail -n1)
http_port=${http_port##*:}
if command -v curl >/dev/null 2>&1; then
    curl -fsS "http://127.0.0.1:$http_port/healthz" >/dev/null ||
        fail "the monitor's /healthz does not answer on 127.0.0.1:$http_port"
    say "step 1: the monitor answers on http://127.0.0.1:$http_port/"
fi

# ------------------------------------------------------------------ step 2
# 12x8 = 96 tiles of 64x64 at supersample 4 with soft shadows and AO: tens
# of seconds of rendering on two cores.
cat >"$work/scene.xml" <<'EOF'
<scene version="1">
  <settings background="0.1 0.1 0.2" ambient="0.2 0.2 0.2"/>
  <sphere id="ball" center="0 1 0" radius="1">
    <surface diffuse="0.8 0.3 0.2" specular="0.5 0.5 0.5" reflectivity="0.2"/>
  </sphere>
  <sphere id="glass" center="1.6 0.6 1" radius="0.6">
    <surface diffuse="0.1 0.1 0.1" specular="0.8 0.8 0.8" shininess="80" opacity="0.3" ior="1.5"/>
  </sphere>
  <plane id="ground" point="0 0 0" normal="0 1 0"> <surface diffuse="0.5 0.5 0.5" reflectivity="0.1"/> </plane>
  <light type="point" position="2 5 3" color="1 1 1" intensity="1" radius="0.5"/>
  <camera id="main" position="0 2 6" lookat="0 1 0" up="0 1 0" fov="50">
    <render width="768" height="512" supersample="4" shadow-samples="8" ao-samples="16" output="out.png"/>
  </camera>
</scene>
EOF
say "step 2: trevi-submit scene.xml --coordinator $url (768x512, 96 tiles)"
"$submit" "$work/scene.xml" --coordinator "$url" -o "$work/farm.png" >"$work/submit.log" 2>&1 &
submit_pid=$!

job_line() { "$submit" list --coordinator "$url" 2>/dev/null | tail -n1; }
# list's row: ID STATE SCENE CAMERA WxH DONE/TOTAL ... (submit/src/cli.rs, list_row)
tiles_done() { job_line | sed -nE 's|.*[0-9]x[0-9]+ +([0-9]+)/[0-9]+ .*|\1|p'; }
deadline=$(($(date +%s) + 120))
while :; do
    kill -0 "$submit_pid" 2>/dev/null || fail "trevi-submit ended before the workers were disturbed"
    done_now=$(tiles_done)
    [ "${done_now:-0}" -ge 12 ] && break
    [ "$(date +%s)" -lt "$deadline" ] || fail "the job made no progress in 120 s: $(job_line)"
    sleep 0.5
done
say "step 2: rendering: $(job_line | xargs)"

# ------------------------------------------------------------------ step 3
victim=${workers[0]}
cut=${workers[1]}
network=$(docker inspect -f '{{range $k, $v := .NetworkSettings.Networks}}{{$k}}{{end}}' "$cut")
say "step 3: docker kill $(docker inspect -f '{{.Name}}' "$victim" | tr -d /)"
docker kill "$victim" >/dev/null
say "step 3: docker network disconnect $network $(docker inspect -f '{{.Name}}' "$cut" | tr -d /)"
docker network disconnect "$network" "$cut"
line=$(job_line)
kill -0 "$submit_pid" 2>/dev/null || fail "the job had already finished when the workers were disturbed"
say "step 3: both done while the job is at: $(echo "$line" | xargs)"

# ------------------------------------------------------------------ step 4
say "step 4: waiting for the job to complete with the one remaining worker"
deadline=$(($(date +%s) + 420))
while kill -0 "$submit_pid" 2>/dev/null; do
    [ "$(date +%s)" -lt "$deadline" ] || fail "the job did not complete in 420 s: $(job_line)"
    sleep 1
done
wait "$submit_pid" || {
    submit_pid=
    fail "trevi-submit failed"
}
submit_pid=
say "step 4: job complete: $(job_line | xargs)"
[ -s "$work/farm.png" ] || fail "no output file"
# The disturbed workers stayed out of it to the end: one dead, one running
# but cut off from the project's network.
[ "$(docker inspect -f '{{.State.Running}}' "$victim")" = false ] || fail "the killed worker is running again"
[ -z "$(docker inspect -f '{{range $k, $v := .NetworkSettings.Networks}}{{$k}}{{end}}' "$cut")" ] ||
    fail "the cut-off worker is back on a network"
say "step 4: the killed worker stayed dead, the cut-off worker stayed off the network"
say "step 4: embedded render of the same scene (trevi-submit without --coordinator)"
"$submit" "$work/scene.xml" -o "$work/embedded.png" --quiet >"$work/embedded.log" 2>&1 || {
    cat "$work/embedded.log"
    fail "the embedded render failed"
}
cmp "$work/farm.png" "$work/embedded.png" || fail "the farm's output differs from the embedded render"
say "step 4: farm output is byte-identical to the embedded render ($(stat -c %s "$work/farm.png") bytes, sha256 $(sha256sum <"$work/farm.png" | cut -c1-16))"

# ------------------------------------------------------------------ step 5
# The image's trevi-submit denoises when it was built with the `denoise`
# feature (build-images.sh then puts Open Image Denoise's CPU libraries in
# the image): a still rendered and denoised inside a container is the one
# the host's trevi-submit makes (same code, same library, same CPU, one
# thread). TREVI_REQUIRE_DENOISE=1 makes a build without the feature a
# failure instead of a skip.
if readelf -d "$submit" 2>/dev/null | grep -q libOpenImageDenoise; then
    say "step 5: trevi-submit --denoise inside the image and on the host"
    cat >"$work/small.xml" <<'EOF2'
<scene version="1">
  <settings background="0.1 0.1 0.2" ambient="0.1 0.1 0.1"/>
  <sphere id="ball" center="0 1 0" radius="1"> <surface diffuse="0.8 0.3 0.2"/> </sphere>
  <plane id="ground" point="0 0 0" normal="0 1 0"> <surface diffuse="0.5 0.5 0.5"/> </plane>
  <light type="point" position="2 5 3" color="1 1 1" intensity="1" radius="1"/>
  <camera id="main" position="0 2 6" lookat="0 1 0" up="0 1 0" fov="50">
    <render width="96" height="64" shadow-samples="1" ao-samples="1" output="small.png"/>
  </camera>
</scene>
EOF2
    chmod 0777 "$work"
    docker run --rm -v "$work:/w" --entrypoint trevi-submit "$TREVI_IMAGE" \
        /w/small.xml --denoise --threads 1 --quiet -o /w/image-denoised.png >"$work/image-denoise.log" 2>&1 || {
        cat "$work/image-denoise.log"
        fail "trevi-submit --denoise failed inside the image"
    }
    "$submit" "$work/small.xml" --denoise --threads 1 --quiet -o "$work/host-denoised.png" \
        >"$work/host-denoise.log" 2>&1 || {
        cat "$work/host-denoise.log"
        fail "trevi-submit --denoise failed on the host"
    }
    cmp "$work/image-denoised.png" "$work/host-denoised.png" ||
        fail "the image's denoised frame differs from the host's"
    say "step 5: the image's denoised frame is the host's ($(stat -c %s "$work/image-denoised.png") bytes)"
elif [ "${TREVI_REQUIRE_DENOISE:-0}" = 1 ]; then
    fail "$submit has no denoiser (build it with --features trevi-submit/denoise; TREVI_REQUIRE_DENOISE=1)"
else
    say "step 5: SKIPPED: $submit was built without the denoise feature"
fi
passed=1
