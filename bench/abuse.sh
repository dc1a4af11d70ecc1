#!/usr/bin/env bash
# Connection abuse at full scale against `terrastream serve` of a baked tileset (defaults:
# --max-connections 4096, --max-connections-per-client 256, --header-timeout 10,
# --idle-timeout 60): 2,000 idle connections (200 source addresses), 500 slowloris connections
# (50 addresses, request head at 1 byte/s) and 4,100 idle connections from one address, while a
# normal client requests /healthz and a blob every 0.5 s. Prints the normal client's latencies
# and failures, when the server closed each group of abusive sockets, and the server's
# connection metrics. Fails when the normal client saw a failure or an abusive group was not
# closed. Linux only (all of 127/8 is loopback).
#
# Usage: bench/abuse.sh [DURATION_S=75]   (BIN=path/to/terrastream to use another binary;
#        SERVE_FLAGS="--idle-timeout 5" to change the server's limits)
set -euo pipefail
cd "$(dirname "$0")/.."
duration="${1:-75}"
port=18085
bin="${BIN:-./target/release/terrastream}"
[ -x "$bin" ] || cargo build --release --quiet
ulimit -n 65536 2>/dev/null || ulimit -n "$(ulimit -Hn)"

tmp="$(mktemp -d)"
spid=""
cleanup() {
    [ -n "$spid" ] && kill "$spid" 2>/dev/null || true
    wait 2>/dev/null || true
    rm -rf "$tmp"
}
trap cleanup EXIT

echo "machine: $(nproc) cores; fd limit $(ulimit -n); binary $bin"
"$bin" synth --width 513 --seed 1 --out "$tmp/t.tif" >/dev/null
mkdir -p "$tmp/store"
"$bin" bake --gpu off --tile-size 128 --levels 2 "$tmp/t.tif" --out "$tmp/store/t" >/dev/null
# shellcheck disable=SC2086
"$bin" serve --store "$tmp/store" --bind "127.0.0.1:$port" --gpu off ${SERVE_FLAGS:-} --log warn \
    >"$tmp/serve.log" 2>&1 &
spid=$!
for _ in $(seq 300); do curl -fs -o /dev/null "http://127.0.0.1:$port/readyz" && break; sleep 0.1; done
echo "server flags: defaults ${SERVE_FLAGS:-}"
python3 bench/abuse.py "127.0.0.1:$port" /tilesets/t/tiles/1/0/0/0 "$duration" | tee "$tmp/out.txt"
curl -fs "http://127.0.0.1:$port/metrics" | grep -E '^terrastream_connections_' || true
kill -0 "$spid" 2>/dev/null || { echo "FAIL: the server died"; exit 1; }
fail=0
grep -q '^normal client failures: 0$' "$tmp/out.txt" || { echo "FAIL: the normal client saw failures"; fail=1; }
for g in idle slowloris greedy; do
    line="$(grep "^$g: " "$tmp/out.txt")"
    opened="$(echo "$line" | awk '{print $2}')"
    closed="$(echo "$line" | awk '{print $4}')"
    [ "$opened" = "$closed" ] || { echo "FAIL: $g: $closed of $opened closed"; fail=1; }
done
[ $fail = 0 ] && echo "PASS: the normal client was served throughout; every abusive connection was closed"
exit $fail
