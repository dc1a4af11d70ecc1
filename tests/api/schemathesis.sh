#!/usr/bin/env bash
# Property-based API test: schemathesis against /openapi.json of a running `terrastream serve`
# with a baked tileset (and the admin API enabled), on 127.0.0.1. Fails on any 5xx, on any
# response the document does not describe, and on a server crash. One check is off:
# ensure_resource_availability expects what a POST created to exist at once, but an upload is
# answered 202 and baked by a job (which may fail on the bytes schemathesis sends), so its
# tileset appears only when the job is done. And use_after_free expects a DELETEd resource to
# be gone, but DELETE /jobs/{id} cancels a job, which stays readable (state "cancelled") until
# --job-ttl so its owner can see how it ended — as the document says. schemathesis_hooks.py
# tells it the shape of the binary heights body (pairs of f64), which OpenAPI cannot.
# Usage: tests/api/schemathesis.sh TERRASTREAM_BINARY SCHEMATHESIS_BINARY [MAX_EXAMPLES]
set -euo pipefail
bin=$1
st=$2
examples=${3:-60}
data="${TERRASTREAM_DATA:-$(cd "$(dirname "$0")/../../.." && pwd)/shared/data}"
work=$(mktemp -d)
server_pid=""
cleanup() {
  if [ -n "$server_pid" ]; then kill "$server_pid" 2>/dev/null || true; wait "$server_pid" 2>/dev/null || true; fi
  rm -rf "$work"
}
trap cleanup EXIT

"$bin" bake --quiet --gpu off --encoding terrain-rgb --cell-size 30 --tile-size 128 --levels 2 \
  --out "$work/store/fuji" "$data/fuji.png"
port=$(python3 -c 'import socket; s=socket.socket(); s.bind(("127.0.0.1",0)); print(s.getsockname()[1])')
"$bin" serve --store "$work/store" --bind "127.0.0.1:$port" --gpu off --admin-token schemathesis-token \
  --log warn >"$work/server.log" 2>&1 &
server_pid=$!
for _ in $(seq 1 100); do
  if curl -fs "http://127.0.0.1:$port/readyz" >/dev/null 2>&1; then break; fi
  sleep 0.1
done
curl -fs "http://127.0.0.1:$port/readyz" >/dev/null

set +e
SCHEMATHESIS_HOOKS="$(cd "$(dirname "$0")" && pwd)/schemathesis_hooks.py" "$st" run "http://127.0.0.1:$port/openapi.json" \
  --checks all --exclude-checks ensure_resource_availability,use_after_free \
  --max-examples "$examples" --generation-deterministic \
  --header "Authorization: Bearer schemathesis-token" \
  --max-response-time 10 --suppress-health-check all 2>&1 | tee "$work/st.log"
rc=${PIPESTATUS[0]}
set -e
if ! kill -0 "$server_pid" 2>/dev/null; then
  echo "schemathesis: the server died"; cat "$work/server.log"; rc=1
fi
if grep -q "panicked" "$work/server.log"; then
  echo "schemathesis: the server panicked"; grep -m5 -A3 panicked "$work/server.log"; rc=1
fi
exit "$rc"
