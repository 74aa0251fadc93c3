#!/usr/bin/env bash
# End-to-end test of deploy/docker-compose.yml with real containers:
#   check the image's `tessera render --denoise` (Open Image Denoise in the image);
#   run the README's compose commands verbatim, in an empty environment, and compare the EXR;
#   then build the image (base images from deploy/airgap-base-images.sh when none can be pulled),
#   bring up a coordinator and 3 workers with a token, submit the Cornell box from the host CLI,
#   `docker kill` one worker and cut another off the network for longer than a lease mid-job,
#   check the EXR is bit-identical to `tessera render`, that the dashboard wants the token and
#   Prometheus (the monitoring profile) scrapes the coordinator's metrics with it, and that
#   `down -v` leaves nothing.
#
#   deploy/e2e-compose.sh [--image-only]
set -euo pipefail
cd "$(dirname "$0")/.."
PROJECT=tessera-e2e-$$
COMPOSE=(docker-compose)
docker compose version >/dev/null 2>&1 && COMPOSE=(docker compose)
dc() { "${COMPOSE[@]}" -p "$PROJECT" -f deploy/docker-compose.yml "$@"; }
OUT=$(mktemp -d)
cleanup() {
  dc --profile monitoring down -v --remove-orphans >/dev/null 2>&1 || true
  rm -rf "$OUT"
}
trap cleanup EXIT

if ! docker image inspect rust:1-slim-bookworm >/dev/null 2>&1 || ! docker image inspect debian:bookworm-slim >/dev/null 2>&1; then
  docker pull -q rust:1-slim-bookworm && docker pull -q debian:bookworm-slim \
    || deploy/airgap-base-images.sh
fi
echo "== [$((SECONDS / 60))m$((SECONDS % 60))s] base images present"
# `--image-only`: the base images and the compose file's image, nothing else (.ci/run builds it
# in the background while the tests run, and this script then finds it built).
if [[ ${1:-} == --image-only ]]; then
  docker-compose -f deploy/docker-compose.yml build -q
  echo "== [$((SECONDS / 60))m$((SECONDS % 60))s] the image is built"
  exit 0
fi
cargo build --release -q -p tessera-cli
T=$PWD/target/release/tessera

echo "== [$((SECONDS / 60))m$((SECONDS % 60))s] the README's docker compose commands, exactly as written, with no extra environment"
# The block under "Or everything on one box with docker compose" in README.md, run as a user
# would paste it into a fresh shell: nothing but PATH and HOME (and DOCKER_HOST, if the host
# uses one). Compose then passes `TESSERA_WORKER_THREADS=` and `TESSERA_TOKEN=` as empty
# variables, which must mean "not set".
README_BLOCK=$(awk '/^Or everything on one box with docker compose/ {f = 1; next}
                    f && /^```sh/ {b = 1; next}
                    b && /^```/ {exit}
                    b {print}' README.md)
[[ $README_BLOCK == *"docker-compose -f deploy/docker-compose.yml up"* ]] \
  || { echo "README.md has no docker compose block where expected" >&2; exit 1; }
[[ ! -e cornell-box.exr ]] || { echo "cornell-box.exr is in the way; move it" >&2; exit 1; }
readme_cleanup() {
  docker-compose -f deploy/docker-compose.yml down -v >/dev/null 2>&1 || true
  rm -f cornell-box.exr
  cleanup
}
trap readme_cleanup EXIT
# The image is built first, untimed (a cold build on 2 cores takes many minutes); the block's
# own `up --build` then finds it current, as it would for a user who built it before.
docker-compose -f deploy/docker-compose.yml build -q
echo "== [$((SECONDS / 60))m$((SECONDS % 60))s] the image is built"
# The image carries Open Image Denoise where the binary looks for it (/usr/local/oidn/lib).
docker run --rm -v "$PWD/scenes:/scenes:ro" tessera:local render /scenes/cornell-box.toml \
  --spp 2 --resolution 32x32 --denoise --output /tmp/denoised.exr >/dev/null \
  || { echo "the image's tessera cannot denoise" >&2; exit 1; }
echo "== [$((SECONDS / 60))m$((SECONDS % 60))s] the image's tessera render --denoise works"
printf '%s\n' "$README_BLOCK" | sed 's/^/  $ /'
timeout 1200 env -i PATH="$PATH" HOME="$HOME" ${DOCKER_HOST:+DOCKER_HOST="$DOCKER_HOST"} \
  bash -euo pipefail -c "$README_BLOCK" \
  || { echo "the README's docker compose commands failed" >&2; exit 1; }
"$T" render scenes/cornell-box.toml --spp 256 --output "$OUT/readme-local.exr" >/dev/null
cmp cornell-box.exr "$OUT/readme-local.exr" \
  || { echo "the README's compose EXR differs from tessera render's" >&2; exit 1; }
rm -f cornell-box.exr
trap cleanup EXIT
echo "== [$((SECONDS / 60))m$((SECONDS % 60))s] README commands: bit-identical to tessera render"

free_port() { python3 -c 'import socket; s = socket.socket(); s.bind(("127.0.0.1", 0)); print(s.getsockname()[1])'; }
export TESSERA_PORT=$(free_port)
export TESSERA_HTTP_PORT=$(free_port)
export TESSERA_PROMETHEUS_PORT=$(free_port)
export TESSERA_TOKEN=$(od -An -N32 -tx1 /dev/urandom | tr -d ' \n')
export TESSERA_LEASE_TIMEOUT=4
export TESSERA_WORKER_THREADS=1
export TESSERA_COORDINATOR=http://127.0.0.1:$TESSERA_PORT
LEASE=$TESSERA_LEASE_TIMEOUT

echo "== [$((SECONDS / 60))m$((SECONDS % 60))s] build and up (project $PROJECT, port $TESSERA_PORT)"
dc build -q
dc up -d --scale worker=3
for i in $(seq 120); do "$T" status >/dev/null 2>&1 && break; sleep 1; done
"$T" status >/dev/null

echo "== [$((SECONDS / 60))m$((SECONDS % 60))s] submit from the host"
SPP=256
JOB=$("$T" submit scenes/cornell-box.toml --spp $SPP)
echo "$JOB"
progress() { "$T" status "$JOB" | awk '/progress/ {split($2, a, "/"); print a[1], a[2]}'; }
until read -r done total < <(progress) && ((done * 10 >= total)); do sleep 0.2; done
echo "at $done/$total units:"

mapfile -t WORKERS < <(dc ps -q worker)
((${#WORKERS[@]} == 3)) || { echo "expected 3 workers, got ${#WORKERS[@]}" >&2; exit 1; }
NET=$(docker inspect -f '{{range $k, $v := .NetworkSettings.Networks}}{{$k}}{{end}}' "${WORKERS[1]}")
docker kill "${WORKERS[0]}" >/dev/null
echo "  docker kill ${WORKERS[0]:0:12}"
docker network disconnect "$NET" "${WORKERS[1]}"
echo "  docker network disconnect $NET ${WORKERS[1]:0:12} for $((LEASE * 2)) s (lease: $LEASE s)"
sleep $((LEASE * 2))
docker network connect "$NET" "${WORKERS[1]}"
echo "  reconnected"

"$T" fetch "$JOB" --wait --output "$OUT/farm.exr"
"$T" render scenes/cornell-box.toml --spp $SPP --output "$OUT/local.exr" >/dev/null
cmp "$OUT/farm.exr" "$OUT/local.exr" || { echo "compose EXR differs from tessera render's" >&2; exit 1; }
echo "== [$((SECONDS / 60))m$((SECONDS % 60))s] bit-identical to tessera render"
"$T" status "$JOB" | grep -q "(0 leased)" || { echo "leases left behind" >&2; exit 1; }
# The worker that was cut off comes back by itself (its name is its container's host name).
# Its capped backoff (up to 10 s a step) may still be running when the job ends, so it gets
# 30 s to show up as alive again.
back=
for _ in $(seq 60); do
  "$T" workers >"$OUT/workers"
  awk -v n="${WORKERS[1]:0:12}" '$2 == n && $4 == "alive" {ok = 1} END {exit !ok}' \
    "$OUT/workers" && { back=1; break; }
  sleep 0.5
done
cat "$OUT/workers"
[[ -n $back ]] || { echo "the disconnected worker did not come back within 30 s" >&2; exit 1; }

echo "== [$((SECONDS / 60))m$((SECONDS % 60))s] the dashboard and Prometheus (monitoring profile, Debian's prometheus package)"
DASH=http://127.0.0.1:$TESSERA_HTTP_PORT
code=$(curl -s -o /dev/null -w '%{http_code}' "$DASH/metrics")
[[ $code == 401 ]] || { echo "/metrics without the token answered $code" >&2; exit 1; }
curl -fsS -H "Authorization: Bearer $TESSERA_TOKEN" "$DASH/api/jobs/$JOB" | grep -q '"state":"done"' \
  || { echo "the dashboard does not show $JOB done" >&2; exit 1; }
curl -fsS -H "Authorization: Bearer $TESSERA_TOKEN" "$DASH/metrics" >"$OUT/metrics"
dc --profile monitoring build -q prometheus
dc --profile monitoring up -d prometheus
# Prometheus' own linter on what the coordinator exports.
dc --profile monitoring exec -T prometheus promtool check metrics <"$OUT/metrics" \
  || { echo "promtool check metrics failed" >&2; exit 1; }
total=$("$T" status "$JOB" | awk '/progress/ {split($2, a, "/"); print a[2]}')
scraped=
for _ in $(seq 90); do
  scraped=$(curl -fsS "http://127.0.0.1:$TESSERA_PROMETHEUS_PORT/api/v1/query?query=tessera_units_merged_total" 2>/dev/null \
    | python3 -c 'import json, sys; r = json.load(sys.stdin)["data"]["result"]; print(r[0]["value"][1] if r else "")' 2>/dev/null || true)
  [[ $scraped == "$total" ]] && break
  sleep 1
done
[[ $scraped == "$total" ]] \
  || { echo "Prometheus scraped tessera_units_merged_total=${scraped:-nothing}, the job has $total units" >&2; exit 1; }
echo "Prometheus scraped tessera_units_merged_total = $scraped = the job's units"

echo "== [$((SECONDS / 60))m$((SECONDS % 60))s] down -v"
dc --profile monitoring down -v --remove-orphans
left=$(docker ps -aq --filter "label=com.docker.compose.project=$PROJECT"; \
       docker volume ls -q --filter "label=com.docker.compose.project=$PROJECT"; \
       docker network ls -q --filter "label=com.docker.compose.project=$PROJECT")
[[ -z "$left" ]] || { echo "left behind: $left" >&2; exit 1; }
echo "compose end to end: passed"
