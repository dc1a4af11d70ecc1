#!/usr/bin/env bash
# Builds deploy/Dockerfile with podman (no Docker daemon) and runs the image:
#   1. a base image for RUNTIME_IMAGE from Debian's packages (mmdebstrap, imported with podman
#      import), unless --runtime-image names one that is there already;
#   2. the image, with the binary built outside (BINARY_FROM=prebuilt, --bin; the default is the
#      debug binary `cargo test` built) or from source (--from-source, needs RUST_IMAGE);
#   3. a bake on the host (the reference), then the same bake in the image as its user 10001
#      on a mounted volume: byte-identical;
#   4. `serve` from the image, hardened as in deploy/k8s (read-only root and store, /tmp tmpfs,
#      no capabilities), port on 127.0.0.1: /healthz, /readyz, then the bytes of the manifest,
#      an index chunk, blobs and a glTF against a host `serve` of the same store;
#   5. the image's HEALTHCHECK (`podman healthcheck run`) on the running server, and its script
#      against a closed port (must fail);
#   6. the Indexed Job, played with containers: the plan, shards and finish Jobs of the rendered
#      deploy/k8s/base (args with their $(VAR)s from the ConfigMap, mounts, user, read-only
#      root, completions, parallelism, per-index retries and FailIndex codes), the shards run by
#      deploy/run-indexed-job.sh with JOB_COMPLETION_INDEX set per container: byte-identical
#      to the host's one-machine bake.
# Prints one line per check and closes with `image: N passed, N failed`; exits 1 on a failure.
# Removes its containers, its image (unless --keep-image) and its work files on exit.
#
#   deploy/image-smoke.sh [--bin PATH | --from-source] [--runtime-image IMAGE] [--work DIR]
#                         [--keep-image]
#
# Needs podman and runc (and mmdebstrap without --runtime-image), kubectl (kustomize), curl, and
# $PYTHON (default python3) with PyYAML. The input is
# $TERRASTREAM_DATA/geo/utm32n_pixelispoint_n00e010.tif (1,205², 39 tiles: enough leaves for the
# base's 16 shards). The base tar is kept in --work (default target/image-smoke) for the next run.
# Environment: IMAGE_SMOKE_WAIT_S (a server's /healthz, 60), IMAGE_SMOKE_STEP_S (any one step,
# 600), IMAGE_SMOKE_RUNTIME (runc), RUST_IMAGE (--from-source).
set -uo pipefail
cd "$(dirname "$0")/.." || exit 1

BIN=target/debug/terrastream
FROM_SOURCE=0
RUNTIME_IMAGE=""
WORK=target/image-smoke
KEEP_IMAGE=0
IMAGE=localhost/terrastream:smoke
BASE_IMAGE=localhost/terrastream-smoke-base:bookworm
DATA="${TERRASTREAM_DATA:-$(cd .. && pwd)/shared/data}"
INPUT="$DATA/geo/utm32n_pixelispoint_n00e010.tif"
# Seconds to wait for a server's /healthz, and for any one container.
WAIT_S="${IMAGE_SMOKE_WAIT_S:-60}"
STEP_S="${IMAGE_SMOKE_STEP_S:-600}"
while [ $# -gt 0 ]; do
  case "$1" in
    --bin) BIN="$2"; shift 2 ;;
    --from-source) FROM_SOURCE=1; shift ;;
    --runtime-image) RUNTIME_IMAGE="$2"; shift 2 ;;
    --work) WORK="$2"; shift 2 ;;
    --keep-image) KEEP_IMAGE=1; shift ;;
    *) echo "image-smoke: unknown option $1 (see the top of $0)" >&2; exit 2 ;;
  esac
done

passed=0 failed=0
pass() { passed=$((passed + 1)); echo "PASS $*"; }
fail() { failed=$((failed + 1)); echo "FAIL $*"; }
finish() {
  echo "image: $passed passed, $failed failed"
  [ "$failed" -eq 0 ] && [ "$passed" -gt 0 ] && exit 0
  exit 1
}

# Every container carries the label terrastream-smoke=RUN_ID; the exit trap removes them by it.
RUN_ID="terrastream-smoke-$$"
LABEL="terrastream-smoke=$RUN_ID"
# runc, not crun (crun's setrlimit is refused in some sandboxes). Limits no higher than this
# process's own hard limits (a container may not raise them without CAP_SYS_RESOURCE; podman's
# defaults are higher), nproc at most pid_max.
PODMAN=(podman --runtime "${IMAGE_SMOKE_RUNTIME:-runc}")
ULIMITS=()
hn=$(ulimit -Hn)
[ "$hn" != unlimited ] && ULIMITS+=(--ulimit "nofile=$hn:$hn")
hu=$(ulimit -Hu)
pid_max=$(cat /proc/sys/kernel/pid_max 2> /dev/null || echo 32768)
if [ "$hu" = unlimited ] || [ "$hu" -gt "$pid_max" ]; then hu=$pid_max; fi
ULIMITS+=(--ulimit "nproc=$hu:$hu")

host_pid="" made_base=0
cleanup() {
  [ -n "$host_pid" ] && kill "$host_pid" 2> /dev/null && wait "$host_pid" 2> /dev/null
  local ids
  ids=$("${PODMAN[@]}" ps -aq --filter "label=$LABEL" 2> /dev/null)
  # shellcheck disable=SC2086
  [ -n "$ids" ] && "${PODMAN[@]}" rm -f -t 2 $ids > /dev/null 2>&1
  rm -f deploy/prebuilt/terrastream
  if [ "$KEEP_IMAGE" -eq 0 ]; then
    "${PODMAN[@]}" rmi -f "$IMAGE" > /dev/null 2>&1
    [ "$made_base" -eq 1 ] && "${PODMAN[@]}" rmi -f "$BASE_IMAGE" > /dev/null 2>&1
  fi
  # The volumes hold files of uid 10001; root (or the same user) removes them.
  rm -rf "$WORK/run"
}
trap cleanup EXIT
trap 'exit 130' INT TERM

# Runs "$@" with a time limit; the output goes to $log.
log=""
timed() { timeout --kill-after=10 "$STEP_S" "$@" > "$log" 2>&1; }
last() { grep -v '^\s*$' "$log" | tail -n "${1:-1}" | tr '\n' ' '; }

# --- tools --------------------------------------------------------------------------------------
PYTHON="${PYTHON:-python3}"
for tool in podman curl kubectl "$PYTHON" timeout cmp; do
  command -v "$tool" > /dev/null || { fail "tools: $tool not on PATH"; finish; }
done
command -v "${IMAGE_SMOKE_RUNTIME:-runc}" > /dev/null || { fail "tools: ${IMAGE_SMOKE_RUNTIME:-runc} not on PATH"; finish; }
"$PYTHON" -c 'import yaml' 2> /dev/null || { fail "tools: $PYTHON has no PyYAML (pip install PyYAML, or apt-get install python3-yaml)"; finish; }
[ -f "$INPUT" ] || { fail "input: $INPUT missing (TERRASTREAM_DATA=$DATA)"; finish; }
if [ "$FROM_SOURCE" -eq 0 ] && [ ! -x "$BIN" ]; then
  fail "binary: $BIN missing (cargo build, or --bin PATH)"
  finish
fi
# deploy/prebuilt/terrastream is this script's for the build, and removed after it: a different
# binary there is someone else's.
if [ -e deploy/prebuilt/terrastream ] && ! cmp -s deploy/prebuilt/terrastream "$BIN"; then
  fail "binary: deploy/prebuilt/terrastream exists and is not $BIN: move it away, or pass it with --bin"
  finish
fi
if [ "$FROM_SOURCE" -eq 1 ]; then BIN_HOST="${BIN_HOST:-$BIN}"; else BIN_HOST=$BIN; fi
[ -x "$BIN_HOST" ] || { fail "binary: the host's reference binary $BIN_HOST missing"; finish; }
# Containers of an earlier run that was killed (its process is gone).
"${PODMAN[@]}" ps -a --filter label=terrastream-smoke --format '{{.ID}} {{index .Labels "terrastream-smoke"}}' 2> /dev/null |
  while read -r id run; do
    kill -0 "${run##*-}" 2> /dev/null || "${PODMAN[@]}" rm -f -t 2 "$id" > /dev/null 2>&1
  done
pass "tools: $(podman --version), $("${IMAGE_SMOKE_RUNTIME:-runc}" --version | head -n 1), ulimits ${ULIMITS[*]}"

rm -rf "$WORK/run"
mkdir -p "$WORK/run"
RUN=$(cd "$WORK/run" && pwd)
log="$RUN/step.log"

# --- 1. the base image ----------------------------------------------------------------------------
if [ -z "$RUNTIME_IMAGE" ]; then
  command -v mmdebstrap > /dev/null || { fail "tools: mmdebstrap not on PATH (or --runtime-image)"; finish; }
  # Cached across runs in $WORK (Debian's bookworm changes only with point releases).
  tar="$WORK/base-bookworm-minbase.tar"
  t0=$SECONDS
  if [ ! -s "$tar" ]; then
    if ! timed mmdebstrap --variant=minbase --format=tar bookworm "$tar.part"; then
      rm -f "$tar.part"
      fail "base: mmdebstrap --variant=minbase bookworm: $(last 2)"
      finish
    fi
    mv "$tar.part" "$tar"
  fi
  if timed "${PODMAN[@]}" import "$tar" "$BASE_IMAGE"; then
    pass "base: $BASE_IMAGE from mmdebstrap --variant=minbase bookworm ($((SECONDS - t0)) s)"
  else
    fail "base: podman import $tar: $(last 2)"
    finish
  fi
  RUNTIME_IMAGE=$BASE_IMAGE made_base=1
fi

# --- 2. the image ---------------------------------------------------------------------------------
build_args=(--build-arg "RUNTIME_IMAGE=$RUNTIME_IMAGE")
if [ "$FROM_SOURCE" -eq 0 ]; then
  cp "$BIN" deploy/prebuilt/terrastream
  build_args+=(--build-arg BINARY_FROM=prebuilt)
  what="prebuilt $BIN"
else
  [ -n "${RUST_IMAGE:-}" ] && build_args+=(--build-arg "RUST_IMAGE=$RUST_IMAGE")
  what="built from source"
fi
t0=$SECONDS
# --format docker keeps HEALTHCHECK (the OCI format has none); --pull=missing uses local bases.
if timed "${PODMAN[@]}" build --format docker --pull=missing --layers=false "${ULIMITS[@]}" \
  -f deploy/Dockerfile --ignorefile deploy/Dockerfile.dockerignore "${build_args[@]}" -t "$IMAGE" .; then
  pass "build: $IMAGE, $what, on $RUNTIME_IMAGE ($((SECONDS - t0)) s, $("${PODMAN[@]}" image inspect "$IMAGE" --format '{{.Size}}' | awk '{printf "%.0f MB", $1 / 1e6}'))"
else
  fail "build: podman build -f deploy/Dockerfile: $(last 3)"
  finish
fi
rm -f deploy/prebuilt/terrastream
user=$("${PODMAN[@]}" image inspect "$IMAGE" --format '{{.Config.User}}')
hc=$("${PODMAN[@]}" image inspect "$IMAGE" --format '{{if .Config.Healthcheck}}{{.Config.Healthcheck.Test}}{{end}}')
if [ "$user" = 10001:10001 ] && [ -n "$hc" ]; then
  pass "image config: USER $user, HEALTHCHECK $hc"
else
  fail "image config: USER '$user' (want 10001:10001), HEALTHCHECK '$hc'"
fi

# The hardening of deploy/k8s: user 10001, read-only root, /tmp a tmpfs, no capabilities.
HARDENED=(--user 10001:10001 --read-only --tmpfs /tmp:rw,size=1g --cap-drop ALL
  --security-opt no-new-privileges "${ULIMITS[@]}" --label "$LABEL")

# --- 3. a bake in the image against the host's ----------------------------------------------------
mkdir -p "$RUN/inputs" "$RUN/host" "$RUN/image"
cp "$INPUT" "$RUN/inputs/"
t0=$SECONDS
if timed "$BIN_HOST" bake "$RUN/inputs" --out "$RUN/host/terrain" --gpu off --quiet; then
  pass "host bake: $(head -n 1 "$log")"
else
  fail "host bake: $(last 2)"
  finish
fi
host_s=$((SECONDS - t0))
# The volume belongs to the image's user, as a PersistentVolume with fsGroup 10001 would.
chown 10001:10001 "$RUN/image"
t0=$SECONDS
if timed "${PODMAN[@]}" run --rm "${HARDENED[@]}" -v "$RUN/inputs:/data/inputs:ro" \
  -v "$RUN/image:/store" "$IMAGE" bake /data/inputs --out /store/terrain --gpu off --quiet; then
  owner=$(stat -c %u "$RUN/image/terrain/tileset.json" 2> /dev/null)
  if diff -r "$RUN/host/terrain" "$RUN/image/terrain" > "$RUN/diff" 2>&1 && [ "$owner" = 10001 ]; then
    pass "image bake as uid 10001: byte-identical to the host's ($(find "$RUN/image/terrain" -type f | wc -l) files; $((SECONDS - t0)) s, host $host_s s)"
  else
    fail "image bake: differs from the host's (owner uid $owner): $(head -n 3 "$RUN/diff" | tr '\n' ' ')"
  fi
else
  fail "image bake as uid 10001: $(last 2)"
fi

# --- 4. serve from the image against serve on the host --------------------------------------------
free_port() { "$PYTHON" -c 'import socket; s=socket.socket(); s.bind(("127.0.0.1", 0)); print(s.getsockname()[1])'; }
wait_healthz() { # URL [CONTAINER]: 0 once it answers 200; 1 after WAIT_S s, or when CONTAINER stopped
  local end=$((SECONDS + WAIT_S))
  while [ $SECONDS -lt $end ]; do
    curl -sf -m 2 -o /dev/null "$1/healthz" && return 0
    if [ -n "${2:-}" ] && [ "$("${PODMAN[@]}" inspect -f '{{.State.Running}}' "$2" 2> /dev/null)" != true ]; then
      return 1
    fi
    sleep 0.2
  done
  return 1
}
img_port=$(free_port)
host_port=$(free_port)
# The store read-only, as serve needs no more; the health check's systemd timer is off (no
# systemd here): `podman healthcheck run` runs it on demand.
if timed "${PODMAN[@]}" run -d --name "$RUN_ID-serve" "${HARDENED[@]}" --health-interval disable \
  -p "127.0.0.1:$img_port:8080" -v "$RUN/host:/store:ro" -e TERRASTREAM_POLL_MS=500 "$IMAGE"; then
  if wait_healthz "http://127.0.0.1:$img_port" "$RUN_ID-serve"; then
    pass "serve in the image: /healthz 200 on 127.0.0.1:$img_port"
  else
    fail "serve in the image: no /healthz within $WAIT_S s (running: $("${PODMAN[@]}" inspect -f '{{.State.Running}} {{.State.ExitCode}}' "$RUN_ID-serve" 2>&1)): $("${PODMAN[@]}" logs "$RUN_ID-serve" 2>&1 | tail -n 3 | tr '\n' ' ')"
  fi
else
  fail "serve in the image: podman run: $(last 2)"
fi
"$BIN_HOST" serve --store "$RUN/host" --bind "127.0.0.1:$host_port" > "$RUN/host-serve.log" 2>&1 &
host_pid=$!
if ! wait_healthz "http://127.0.0.1:$host_port"; then
  fail "serve on the host: no /healthz within $WAIT_S s: $(tail -n 2 "$RUN/host-serve.log" | tr '\n' ' ')"
fi
ready=$(curl -s -m 5 "http://127.0.0.1:$img_port/readyz" | tr -d ' \n')
if [[ "$ready" == *'"tilesets":1'* ]]; then pass "serve in the image: /readyz $ready"; else fail "serve in the image: /readyz $ready"; fi
# The deepest tile of the bake and the root: the mesh and the coarsest point level.
deep=$(cd "$RUN/host/terrain/tiles" && find . -name '0.tsb' | sort -t/ -k2,2n | tail -n 1 | sed 's|^\./||; s|/0\.tsb$||')
same=0 differ=()
for path in tileset.json index/0/0/0.json tiles/0/0/0/0 tiles/0/0/0/1 "tiles/$deep/0" "3dtiles/tiles/$deep/0.glb"; do
  url="/tilesets/terrain/$path"
  a=$(curl -s -m 10 -o "$RUN/a" -w '%{http_code}' "http://127.0.0.1:$img_port$url")
  b=$(curl -s -m 10 -o "$RUN/b" -w '%{http_code}' "http://127.0.0.1:$host_port$url")
  if [ "$a" = 200 ] && [ "$b" = 200 ] && cmp -s "$RUN/a" "$RUN/b"; then
    same=$((same + 1))
  else
    differ+=("$url (image $a, host $b$(cmp -s "$RUN/a" "$RUN/b" || echo ', bytes differ'))")
  fi
done
if [ ${#differ[@]} -eq 0 ]; then
  pass "serve in the image: $same responses byte-identical to the host's (manifest, index, blobs of 0/0/0 and $deep, glTF)"
else
  fail "serve in the image vs the host: ${differ[*]}"
fi
kill "$host_pid" 2> /dev/null && wait "$host_pid" 2> /dev/null
host_pid=""

# --- 5. the image's health check ------------------------------------------------------------------
if out=$(timeout 30 "${PODMAN[@]}" healthcheck run "$RUN_ID-serve" 2>&1); then
  pass "HEALTHCHECK: podman healthcheck run: ${out:-healthy}"
else
  fail "HEALTHCHECK: podman healthcheck run on a serving container: $out"
fi
if timeout 30 "${PODMAN[@]}" exec -e TERRASTREAM_BIND=127.0.0.1:1 "$RUN_ID-serve" \
  /usr/local/bin/terrastream-healthcheck > /dev/null 2>&1; then
  fail "HEALTHCHECK: the script exits 0 against a closed port"
else
  pass "HEALTHCHECK: the script fails against a closed port"
fi
# SIGTERM to PID 1 (the binary itself: no init in the image) must stop it, well within
# terminationGracePeriodSeconds (30 s), exit status 0.
t0=$SECONDS
timeout 60 "${PODMAN[@]}" stop -t 25 "$RUN_ID-serve" > /dev/null 2>&1
code=$("${PODMAN[@]}" inspect "$RUN_ID-serve" --format '{{.State.ExitCode}}' 2> /dev/null)
if [ "$code" = 0 ] && [ $((SECONDS - t0)) -lt 20 ]; then
  pass "serve in the image: SIGTERM stops it in $((SECONDS - t0)) s, exit 0"
else
  fail "serve in the image: SIGTERM: exit status '$code' after $((SECONDS - t0)) s (podman stop -t 25): $("${PODMAN[@]}" logs "$RUN_ID-serve" 2>&1 | tail -n 2 | tr '\n' ' ')"
fi
"${PODMAN[@]}" rm -f -t 5 "$RUN_ID-serve" > /dev/null 2>&1

# --- 6. the Indexed Job, played with containers ---------------------------------------------------
# The Jobs as deploy/k8s/base renders them, each as a file of NUL-separated words:
#   JOB.args: the container's args, $(VAR) expanded from the ConfigMap (TERRASTREAM_STORE
#             replaced by the local volume /store: no bucket here);
#   JOB.opts: podman run options for its mounts, user and security context;
#   JOB.spec: completions parallelism retries fail-codes (one line).
if ! kubectl kustomize deploy/k8s/base > "$RUN/base.yaml" 2> "$log"; then
  fail "Indexed Job: kubectl kustomize deploy/k8s/base: $(last 2)"
  finish
fi
if ! "$PYTHON" - "$RUN/base.yaml" "$RUN" "$RUN/jobs.env" > "$log" 2>&1 << 'EOF'; then
import re, sys, yaml

docs = [d for d in yaml.safe_load_all(open(sys.argv[1])) if d]
out = sys.argv[2]
cm = next(d for d in docs if d["kind"] == "ConfigMap" and d["metadata"]["name"].startswith("terrastream"))
env = dict(cm["data"])
env["TERRASTREAM_STORE"] = "/store"  # a mounted volume instead of the bucket
with open(sys.argv[3], "w") as f:
    for k, v in env.items():
        f.write(f"{k}={v}\n")
for job in (d for d in docs if d["kind"] == "Job"):
    name = job["metadata"]["labels"]["app.kubernetes.io/component"]  # bake-plan, bake-shards, …
    spec = job["spec"]
    pod = spec["template"]["spec"]
    c = next(c for c in pod["containers"] if c["name"] == "terrastream")
    args = [re.sub(r"\$\((\w+)\)", lambda m: env[m.group(1)], a) for a in c.get("args", [])]
    vols = {v["name"]: v for v in pod.get("volumes", [])}
    opts = []
    for m in c.get("volumeMounts", []):
        v = vols[m["name"]]
        if "emptyDir" in v:
            opts += ["--tmpfs", m["mountPath"]]
        elif m["mountPath"] == "/data/inputs":
            opts += ["-v", f"{out}/inputs:{m['mountPath']}" + (":ro" if m.get("readOnly") else "")]
        else:
            sys.exit(f"{name}: volume {m['name']} has no local stand-in")
    psc, csc = pod.get("securityContext", {}), c.get("securityContext", {})
    opts += ["--user", f"{csc.get('runAsUser', psc['runAsUser'])}:{csc.get('runAsGroup', psc['runAsGroup'])}"]
    if csc.get("readOnlyRootFilesystem"):
        opts += ["--read-only"]
    if csc.get("allowPrivilegeEscalation") is False:
        opts += ["--security-opt", "no-new-privileges"]
    for cap in csc.get("capabilities", {}).get("drop", []):
        opts += ["--cap-drop", cap]
    codes = [
        v
        for r in spec.get("podFailurePolicy", {}).get("rules", [])
        if r["action"] in ("FailIndex", "FailJob") and "onExitCodes" in r
        for v in r["onExitCodes"]["values"]
    ]
    indexed = spec.get("completionMode") == "Indexed"
    retries = spec["backoffLimitPerIndex"] if indexed else spec.get("backoffLimit", 6)
    for ext, words in (("args", args), ("opts", opts)):
        with open(f"{out}/{name}.{ext}", "w") as f:
            f.write("".join(w + "\0" for w in words))
    with open(f"{out}/{name}.spec", "w") as f:
        f.write(f"{spec.get('completions', 1)} {spec.get('parallelism', 1)} {retries} {','.join(map(str, codes))} {int(indexed)}\n")
EOF
  fail "Indexed Job: reading the rendered Jobs: $(last 2)"
  finish
fi
mkdir -p "$RUN/jobs"
chown 10001:10001 "$RUN/jobs"
play() { # JOB: runs it as the Job controller would, with run-indexed-job.sh
  local job=$1 args opts completions parallelism retries codes indexed t0=$SECONDS
  mapfile -d '' -t args < "$RUN/$job.args"
  mapfile -d '' -t opts < "$RUN/$job.opts"
  read -r completions parallelism retries codes indexed < "$RUN/$job.spec"
  local index_env=()
  # Only an Indexed Job's pods get JOB_COMPLETION_INDEX.
  [ "$indexed" = 1 ] && index_env=(-e JOB_COMPLETION_INDEX)
  if timed deploy/run-indexed-job.sh --completions "$completions" --parallelism "$parallelism" \
    --backoff-limit-per-index "$retries" --fail-index-codes "$codes" --retry-delay 1 -- \
    "${PODMAN[@]}" run --rm "${ULIMITS[@]}" --label "$LABEL" --cap-drop ALL "${opts[@]}" \
    --env-file "$RUN/jobs.env" "${index_env[@]}" -v "$RUN/jobs:/store" "$IMAGE" "${args[@]}"; then
    pass "Indexed Job: $job (${args[*]}; $completions × $parallelism at a time; $((SECONDS - t0)) s): $(tail -n 1 "$log")"
  else
    fail "Indexed Job: $job (${args[*]}): $(last 3)"
    return 1
  fi
}
if play bake-plan && play bake-shards && play bake-finish; then
  tileset=$(grep '^BAKE_TILESET=' "$RUN/jobs.env" | cut -d= -f2-)
  if diff -r "$RUN/host/terrain" "$RUN/jobs/$tileset" > "$RUN/diff" 2>&1; then
    pass "Indexed Job: /store/$tileset byte-identical to the host's one-machine bake ($(find "$RUN/jobs/$tileset" -type f | wc -l) files)"
  else
    fail "Indexed Job: /store/$tileset differs from the one-machine bake: $(head -n 3 "$RUN/diff" | tr '\n' ' ')"
  fi
fi
left=$("${PODMAN[@]}" ps -aq --filter "label=$LABEL" | wc -l)
if [ "$left" -eq 0 ]; then pass "containers: none left running"; else fail "containers: $left left behind"; fi
finish
