#!/usr/bin/env bash
# docker-check: build the CPU image from the project's Dockerfile with podman and run it for
# real (issue 10). It
#   1. skips, printing "docker-check: SKIPPED: <reason>" and exiting 0, where podman cannot be
#      used (not root, no ../shared/container/setup.sh, setup failing, no podman after it);
#   2. builds sdcnet:cpu as ../shared/container/README.md says;
#   3. starts it serving on 127.0.0.1 (host networking, a free port) and times start to ready;
#   4. sends a generated frame with `sdc-client infer` from the host and holds the answer to a
#      direct onnxruntime run of the same model file on the host;
#   5. runs the image's HEALTHCHECK, checks the server is not root, and that the image holds no
#      torch, compilers, pip cache, sources or test data;
#   6. prints the image size, start to ready, and one request's latency in the container beside
#      the same request to sdc-serve on the host (same model, same threads); then PASS.
# Containers and the host service it starts are always removed, also on failure. Nothing is
# sent anywhere but 127.0.0.1.
#
# Usage: docker/check.sh [--model PATH]
#   default      bake in the repository's models/sdcnet.onnx (the build context is the repo)
#   --model PATH bake in PATH instead, from a scratch copy of the repository (git ls-files);
#                the image is then tagged sdcnet:cpu-check, and models/ is left untouched
# Environment: DOCKER_CHECK_THREADS (onnxruntime threads, container and host; default 2),
#   DOCKER_CHECK_READY_TIMEOUT (s, default 120), DOCKER_CHECK_BUILD_TIMEOUT (s, default 720),
#   DOCKER_CHECK_REPEAT (timed requests per service, default 5), VENV (default .venv).
set -euo pipefail

REPO=$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)
CONTAINER_TOOLS=$(realpath -m -- "$REPO/../shared/container")
VENV=${VENV:-.venv}
[[ $VENV == /* ]] || VENV="$REPO/$VENV" # relative to the repository
THREADS=${DOCKER_CHECK_THREADS:-2}
READY_TIMEOUT=${DOCKER_CHECK_READY_TIMEOUT:-120}
BUILD_TIMEOUT=${DOCKER_CHECK_BUILD_TIMEOUT:-720}
REPEAT=${DOCKER_CHECK_REPEAT:-5}

MODEL="$REPO/models/sdcnet.onnx" # the model baked into the image and run on the host
IMAGE=sdcnet:cpu
CUSTOM_MODEL=0

# State that cleanup() undoes.
SCRATCH=""         # temporary folder: build context copy, frame, answers, logs
CONTAINERS=()      # names of every container this script may have created
HOST_PID=""        # sdc-serve started on the host
STEP="starting"    # what is being done, for the FAIL line
FINISHED=0         # 1 once PASS or SKIPPED is printed

# ---------------------------------------------------------------------------------------------
# Messages and clean-up

# say MESSAGE...: one progress line.
say() { echo "docker-check: $*"; }

# step DESCRIPTION: announce the next step; a failure inside it names it.
step() {
  STEP=$1
  say "-- $1"
}

# skip REASON: podman cannot be used here; exit 0 with a line no one can take for a pass.
skip() {
  echo "docker-check: SKIPPED: $1"
  FINISHED=1
  exit 0
}

# fail MESSAGE [LOG]: print the FAIL line (and the end of LOG, if given) and exit 1.
fail() {
  if [[ -n ${2:-} && -f $2 ]]; then
    echo "---- last lines of $(basename "$2") ----" >&2
    tail -n 40 "$2" >&2
    echo "----" >&2
  fi
  echo "docker-check: FAIL: $1" >&2
  FINISHED=1
  exit 1
}

# cleanup: on every exit, remove the containers, stop the host service, delete scratch files;
# a non-zero exit that did not come through fail() (set -e) still gets a FAIL line.
cleanup() {
  local status=$?
  trap - EXIT INT TERM
  if ((${#CONTAINERS[@]})); then
    podman rm --force --ignore --time 5 "${CONTAINERS[@]}" >/dev/null 2>&1 || true
  fi
  if [[ -n $HOST_PID ]]; then
    stop_host_service
  fi
  if [[ -n $SCRATCH ]]; then
    rm -rf "$SCRATCH"
  fi
  if ((status != 0 && FINISHED == 0)); then
    echo "docker-check: FAIL: while $STEP (exit status $status)" >&2
  fi
  exit "$status"
}

# stop_host_service: SIGTERM to the host's sdc-serve, SIGKILL if it is still there after 15 s.
stop_host_service() {
  local pid=$HOST_PID
  HOST_PID=""
  kill "$pid" 2>/dev/null || return 0
  for _ in $(seq 150); do
    kill -0 "$pid" 2>/dev/null || break
    sleep 0.1
  done
  kill -KILL "$pid" 2>/dev/null || true
  wait "$pid" 2>/dev/null || true
}

# ---------------------------------------------------------------------------------------------
# Steps

# parse_args "$@": --model PATH, --help.
parse_args() {
  while (($#)); do
    case $1 in
      --model)
        [[ $# -ge 2 ]] || fail "--model needs a path"
        MODEL=$(realpath -- "$2")
        IMAGE=sdcnet:cpu-check
        CUSTOM_MODEL=1
        shift 2
        ;;
      -h | --help)
        sed -n '2,/^set -euo/p' "${BASH_SOURCE[0]}" | sed '$d; s/^# \{0,1\}//'
        FINISHED=1
        exit 0
        ;;
      *) fail "unknown argument: $1 (usage: docker/check.sh [--model PATH])" ;;
    esac
  done
}

# podman_possible: skip at once where podman cannot be set up (before anything slow).
podman_possible() {
  step "podman"
  [[ $(id -u) -eq 0 ]] || skip "podman needs root here and this runs as uid $(id -u)"
  [[ -x $CONTAINER_TOOLS/setup.sh ]] || skip "no $CONTAINER_TOOLS/setup.sh on this machine"
}

# set_up_podman: run the machine's container set-up (skip if it fails), point podman at it.
set_up_podman() {
  # Idempotent: ~3 min the first time on a machine (packages, the python:3.11-slim stand-in),
  # about a second afterwards.
  local started=$SECONDS
  if ! "$CONTAINER_TOOLS/setup.sh" >"$SCRATCH/setup.log" 2>&1; then
    tail -n 20 "$SCRATCH/setup.log"
    skip "$CONTAINER_TOOLS/setup.sh failed (its last lines above)"
  fi
  # shellcheck source=/dev/null
  source "$CONTAINER_TOOLS/env.sh"
  command -v podman >/dev/null || skip "podman is missing after $CONTAINER_TOOLS/setup.sh"
  say "podman $(podman version --format '{{.Client.Version}}') ready ($((SECONDS - started)) s)"
}

# need_host_tools: what the host side needs (the project's virtual environment, curl, git).
need_host_tools() {
  [[ -x $VENV/bin/python && -x $VENV/bin/sdc-client && -x $VENV/bin/sdc-serve ]] \
    || fail "no project virtual environment at $VENV: run make test (or make docker-check)"
  command -v curl >/dev/null || fail "curl is needed to poll readiness"
  [[ $THREADS =~ ^[1-9][0-9]*$ && $REPEAT =~ ^[1-9][0-9]*$ && $READY_TIMEOUT =~ ^[0-9]+$ ]] \
    || fail "DOCKER_CHECK_THREADS, _REPEAT must be positive integers, _READY_TIMEOUT an integer"
  if ((CUSTOM_MODEL)); then
    [[ -f $MODEL ]] || fail "--model $MODEL: no such file"
  else
    [[ -f $MODEL ]] || fail "models/sdcnet.onnx is missing: export the model first (sdc-export), \
or try the image with another model: docker/check.sh --model PATH"
  fi
}

# build_context: the folder to build from. The repository itself by default (.dockerignore
# keeps data, checkpoints and virtual environments out); with --model, a scratch copy of its
# files (tracked or not ignored, as git lists them) with that model as models/sdcnet.onnx.
build_context() {
  if ((CUSTOM_MODEL == 0)); then
    CONTEXT=$REPO
    return
  fi
  CONTEXT="$SCRATCH/context"
  mkdir -p "$CONTEXT"
  git -C "$REPO" ls-files -z --cached --others --exclude-standard \
    | tar -C "$REPO" --null --files-from=- --ignore-failed-read -cf - 2>/dev/null \
    | tar -C "$CONTEXT" -xf -
  mkdir -p "$CONTEXT/models"
  cp -- "$MODEL" "$CONTEXT/models/sdcnet.onnx"
}

# build_image: podman build as ../shared/container/README.md says; the log goes to a file.
build_image() {
  step "building $IMAGE"
  build_context
  local started=$SECONDS
  (cd "$CONTEXT" && timeout "$BUILD_TIMEOUT" \
    podman build --pull=never --isolation chroot --format docker -t "$IMAGE" .) \
    >"$SCRATCH/build.log" 2>&1 \
    || fail "podman build failed or took over $BUILD_TIMEOUT s" "$SCRATCH/build.log"
  BUILD_S=$((SECONDS - started))
  IMAGE_MB=$(($(podman image inspect --format '{{.Size}}' "$IMAGE") / 1000000))
  say "built $IMAGE in $BUILD_S s: $IMAGE_MB MB"
}

# free_port: a TCP port free on 127.0.0.1 now.
free_port() { "$VENV/bin/python" "$REPO/docker/check_frame.py" port; }

# now_ms: milliseconds since the epoch.
now_ms() { echo $(($(date +%s%N) / 1000000)); }

# wait_ready URL WHAT ALIVE_COMMAND...: poll URL/v2/health/ready every 0.1 s until it answers
# 200; fail after READY_TIMEOUT s, at once on an answer other than 503 (not ready yet), or as
# soon as ALIVE_COMMAND says the server is gone.
wait_ready() {
  local url=$1 what=$2
  shift 2
  local deadline=$((SECONDS + READY_TIMEOUT)) polls=0 code
  while true; do
    code=$(curl -s --max-time 2 -o /dev/null -w '%{http_code}' "$url/v2/health/ready" || true)
    case $code in
      200) return 0 ;;
      000 | 503) ;; # not listening yet, or loading the model
      *)
        echo "$what answered HTTP $code on /v2/health/ready" >&2
        return 1
        ;;
    esac
    ((SECONDS < deadline)) || return 1
    if ((++polls % 10 == 0)) && ! "$@"; then
      echo "$what stopped before it was ready" >&2
      return 1
    fi
    sleep 0.1
  done
}

# container_running NAME: is the container still running?
container_running() {
  [[ $(podman container inspect --format '{{.State.Running}}' "$1" 2>/dev/null) == true ]]
}

# host_service_running: is the host's sdc-serve still running?
host_service_running() { kill -0 "$HOST_PID" 2>/dev/null; }

# start_container: serve on 127.0.0.1:PORT with host networking; time podman run to ready.
start_container() {
  step "starting $IMAGE on 127.0.0.1"
  PORT=$(free_port)
  NAME="sdcnet-check-$$"
  CONTAINERS+=("$NAME")
  local started
  started=$(now_ms)
  # Without systemd, podman logs that it cannot set a health-check timer: into run.log.
  podman run -d --name "$NAME" --network host \
    -e SDCNET_HOST=127.0.0.1 -e SDCNET_PORT="$PORT" -e SDCNET_THREADS="$THREADS" \
    "$IMAGE" >/dev/null 2>"$SCRATCH/run.log" || fail "podman run failed" "$SCRATCH/run.log"
  if ! wait_ready "http://127.0.0.1:$PORT" "the container" container_running "$NAME"; then
    podman logs "$NAME" >"$SCRATCH/container.log" 2>&1 || true
    fail "the container did not become ready (timeout $READY_TIMEOUT s)" "$SCRATCH/container.log"
  fi
  READY_MS=$(($(now_ms) - started))
  say "container $NAME ready on 127.0.0.1:$PORT, $READY_MS ms after podman run"
}

# infer_and_compare: a generated frame through sdc-client infer, held to the host's own run.
infer_and_compare() {
  step "sdc-client infer against the container, compared with onnxruntime on the host"
  FRAME="$SCRATCH/frame"
  "$VENV/bin/python" "$REPO/docker/check_frame.py" generate "$FRAME"
  "$VENV/bin/sdc-client" infer "$FRAME/gray.png" "$FRAME/sparse.npy" \
    --url "http://127.0.0.1:$PORT" --out "$SCRATCH/answer" --retries 0 \
    || fail "sdc-client infer against the container failed"
  "$VENV/bin/python" "$REPO/docker/check_frame.py" compare \
    "$MODEL" "$FRAME" "$SCRATCH/answer" --threads "$THREADS" --url "http://127.0.0.1:$PORT" \
    || fail "the container's answer differs from onnxruntime on the host"
}

# probe PODMAN_RUN_ARGS...: run a throw-away container of the image, without network or
# health check (named, so that cleanup removes it even when interrupted); podman's and the
# command's stderr go to probe.log, shown if the check fails.
probe() {
  local name
  name="sdcnet-check-$$-probe-$((${#CONTAINERS[@]}))"
  CONTAINERS+=("$name")
  podman run --rm --name "$name" --network none --no-healthcheck "$@" 2>>"$SCRATCH/probe.log"
}

# check_image: HEALTHCHECK, non-root server, no torch, no compilers, caches, sources, test data;
# the model inside is the one the host runs.
check_image() {
  step "HEALTHCHECK and image hygiene"
  podman healthcheck run "$NAME" >/dev/null || fail "podman healthcheck run $NAME: unhealthy"
  say "HEALTHCHECK: healthy"

  local uid users
  uid=$(podman exec "$NAME" id -u)
  users=$(podman top "$NAME" user | tail -n +2 | sort -u | tr '\n' ' ')
  [[ $uid != 0 && $users != *root* ]] \
    || fail "the server runs as root (id -u: $uid; podman top users: $users)"
  say "server process: uid $uid, podman top user(s): $users"

  probe --entrypoint python "$IMAGE" \
    -c "import importlib.util,sys; sys.exit(importlib.util.find_spec('torch') is not None)" \
    || fail "torch is importable in the image" "$SCRATCH/probe.log"
  say "torch: absent"

  local inside
  inside=$(probe --entrypoint python "$IMAGE" -c "
import hashlib, importlib.resources as r, onnxruntime
model = r.files('sdcnet.models') / 'sdcnet.onnx'
print(hashlib.sha256(model.read_bytes()).hexdigest(), onnxruntime.__version__)")
  [[ ${inside%% *} == "$(sha256sum "$MODEL" | cut -d' ' -f1)" ]] \
    || fail "the model in the image is not $MODEL" "$SCRATCH/probe.log"
  say "model in the image: same sha256 as $(basename "$MODEL"); onnxruntime ${inside##* } inside"

  # As root inside (to see /root too): list what must not be there; any output is a failure.
  local found
  # shellcheck disable=SC2016 # the script runs in the container's sh, which expands it
  found=$(probe --user 0 --entrypoint sh "$IMAGE" -c '
    exec 2>&1
    for c in gcc cc c++ g++ clang make; do command -v "$c" && echo "  ^ compiler"; done
    for d in /root/.cache /tmp/pip-* /src /work /data /tests; do [ -e "$d" ] && echo "$d"; done
    find / -xdev \( -path /proc -o -path /sys \) -prune -o \
      \( -type d \( -path "*/.cache/pip" -o -name .pytest_cache -o -name .ruff_cache \) \) -print
    site=$(python -c "import sdcnet, os; print(os.path.dirname(sdcnet.__file__))")
    find "$site" \( -name tests -o -name "*.npz" -o -name "*.npy" -o -name "*.pt" \
      -o -name "*.png" -o -name "*.h5" \) -print
    ls /var/lib/apt/lists 2>/dev/null | grep -v -e "^lock$" -e "^partial$" || true
  ') || fail "could not inspect the image: $found" "$SCRATCH/probe.log"
  [[ -z $found ]] || fail "the image holds what it should not:
$found"
  say "no compilers, pip or apt caches, sources or test data in the image"
}

# start_host_service: sdc-serve on the host, same model and threads, on another free port.
start_host_service() {
  step "sdc-serve on the host (same model, $THREADS threads)"
  HOST_PORT=$(free_port)
  "$VENV/bin/sdc-serve" --model "$MODEL" --host 127.0.0.1 --port "$HOST_PORT" \
    --threads "$THREADS" --log-level warning >"$SCRATCH/host-serve.log" 2>&1 &
  HOST_PID=$!
  wait_ready "http://127.0.0.1:$HOST_PORT" "sdc-serve on the host" host_service_running \
    || fail "sdc-serve on the host did not become ready (timeout $READY_TIMEOUT s)" \
      "$SCRATCH/host-serve.log"
}

# latency URL: median round trip and server inference (ms) of REPEAT requests, as JSON.
latency() {
  "$VENV/bin/python" "$REPO/docker/check_frame.py" latency "$1" "$FRAME" --repeat "$REPEAT"
}

# json_field JSON KEY: one value of a flat JSON object.
json_field() {
  "$VENV/bin/python" -c 'import json, sys; print(json.loads(sys.argv[1])[sys.argv[2]])' "$1" "$2"
}

# compare_latency: the same frame to the container and to the host service, one after the other.
compare_latency() {
  step "latency: container against sdc-serve on the host"
  CONTAINER_LATENCY=$(latency "http://127.0.0.1:$PORT") || fail "timing the container failed"
  HOST_LATENCY=$(latency "http://127.0.0.1:$HOST_PORT") || fail "timing the host service failed"
}

# report: the figures, then PASS.
report() {
  local c_rt c_inf h_rt h_inf
  c_rt=$(json_field "$CONTAINER_LATENCY" round_trip_ms)
  c_inf=$(json_field "$CONTAINER_LATENCY" inference_ms)
  h_rt=$(json_field "$HOST_LATENCY" round_trip_ms)
  h_inf=$(json_field "$HOST_LATENCY" inference_ms)
  echo
  echo "docker-check: results ($IMAGE, model $MODEL, $THREADS onnxruntime threads)"
  printf '  %-28s %s MB\n' "image size" "$IMAGE_MB"
  printf '  %-28s %s s\n' "build" "$BUILD_S"
  printf '  %-28s %s ms\n' "start to ready (cold)" "$READY_MS"
  printf '  %-28s %8s %14s\n' "one 1024x1024 frame, median" "round trip" "inference"
  printf '  %-28s %8s ms %11s ms\n' "  in the container" "$c_rt" "$c_inf"
  printf '  %-28s %8s ms %11s ms\n' "  sdc-serve on the host" "$h_rt" "$h_inf"
  echo "  (median of $REPEAT requests after one warm-up; round trip from the host's client)"
  FINISHED=1
  echo "docker-check: PASS: $IMAGE builds, starts, serves the same depth as onnxruntime on the" \
    "host, is healthy, runs as non-root, holds no torch, compilers or caches"
}

main() {
  parse_args "$@"
  trap cleanup EXIT
  trap 'exit 130' INT
  trap 'exit 143' TERM
  SCRATCH=$(mktemp -d "${TMPDIR:-/tmp}/docker-check.XXXXXX")
  podman_possible
  need_host_tools
  set_up_podman
  build_image
  start_container
  infer_and_compare
  check_image
  start_host_service
  compare_latency
  report
}

main "$@"
