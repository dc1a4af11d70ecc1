#!/usr/bin/env bash
# Soak: `terrastream serve` under 256 connections for DURATION_S seconds (default 300) with a mix
# of requests: 70% blobs of a baked tileset (a quarter of them conditional, If-None-Match → 304),
# 20% tiles of an on-demand tileset (--source; missing at first, baked on first request, then
# served from the store; 503 + Retry-After while the bake queue is full), 10% invalid requests
# (bad keys → 400, unknown tilesets/tiles → 404). Counts every status; fails when a status
# other than 200/304/400/404/503 or any socket error or timeout occurs. Reports the server's
# RSS (VmRSS) at the start, every 15 s, and at the end.
#
# wrk is one client address with 256 connections: the server runs with
# --max-connections-per-client 1024 so that the per-client cap (default 256) is not what is
# measured here (bench/abuse.sh measures it).
#
# Usage: bench/soak.sh [DURATION_S=300] [WRK_THREADS=2]   (BIN=path/to/terrastream to use another binary)
set -euo pipefail
cd "$(dirname "$0")/.."
duration="${1:-300}"
wrk_threads="${2:-2}"
conns=256
port=18083
bin="${BIN:-./target/release/terrastream}"
[ -x "$bin" ] || cargo build --release --quiet

tmp="$(mktemp -d)"
pids=()
cleanup() {
    for p in "${pids[@]}"; do kill "$p" 2>/dev/null || true; done
    wait 2>/dev/null || true
    rm -rf "$tmp"
}
trap cleanup EXIT

echo "machine: $(nproc) cores; wrk -t$wrk_threads -c$conns -d${duration}s --timeout 35s (the server's request timeout is 30 s)"
"$bin" synth --width 1025 --seed 1 --out "$tmp/baked.tif" >/dev/null
"$bin" synth --width 4097 --seed 2 --out "$tmp/od.tif" >/dev/null
mkdir -p "$tmp/store"
"$bin" bake --gpu off --tile-size 256 --levels 3 "$tmp/baked.tif" --out "$tmp/store/baked" >/dev/null
version="$(jq -r .content_version "$tmp/store/baked/tileset.json")"
(cd "$tmp/store/baked" && find tiles -name '*.tsb' | sort) \
    | sed -E "s#^tiles/(.*)\.tsb\$#/tilesets/baked/tiles/\1?v=$version#" >"$tmp/cached.txt"
# The on-demand tileset: 4097² samples in 128-cell tiles → z 0..5, levels 0..2, nothing baked.
for z in 0 1 2 3 4 5; do
    n=$((1 << z))
    for ((x = 0; x < n; x++)); do for ((y = 0; y < n; y++)); do for l in 0 1 2; do
        echo "/tilesets/od/tiles/$z/$x/$y/$l"
    done; done; done
done >"$tmp/od.txt"
cat >"$tmp/invalid.txt" <<'EOF'
/tilesets/baked/tiles/9/0/0/0
/tilesets/baked/tiles/1/5/0/0
/tilesets/baked/tiles/0/0/0/17
/tilesets/baked/tiles/x/0/0/0
/tilesets/BAD/tileset.json
/tilesets/nope/tiles/0/0/0/0
/tilesets/nope/tileset.json
/tilesets/baked/index/1/0/0.json
/tilesets/..%2F..%2Fetc/tileset.json
/no/such/route
EOF
echo "URLs: $(wc -l <"$tmp/cached.txt") baked blobs, $(wc -l <"$tmp/od.txt") on-demand blobs, $(wc -l <"$tmp/invalid.txt") invalid"

cat >"$tmp/soak.lua" <<EOF
local function load(f)
    local t = {}
    for line in io.lines(f) do t[#t + 1] = line end
    return t
end
local cached = load("$tmp/cached.txt")
local od = load("$tmp/od.txt")
local invalid = load("$tmp/invalid.txt")
local threads = {}
function setup(thread) table.insert(threads, thread) end
function init(args)
    statuses = {}
    math.randomseed(os.time() + tonumber(tostring({}):sub(8), 16))
end
function request()
    local r = math.random(100)
    if r <= 70 then
        local u = cached[math.random(#cached)]
        if r <= 18 then return wrk.format("GET", u, { ["If-None-Match"] = "*" }) end
        return wrk.format("GET", u)
    elseif r <= 90 then
        return wrk.format("GET", od[math.random(#od)])
    else
        return wrk.format("GET", invalid[math.random(#invalid)])
    end
end
function response(status, headers, body)
    statuses[status] = (statuses[status] or 0) + 1
end
function done(summary, latency, requests)
    local total = {}
    for _, t in ipairs(threads) do
        for k, v in pairs(t:get("statuses")) do total[k] = (total[k] or 0) + v end
    end
    local keys = {}
    for k in pairs(total) do keys[#keys + 1] = k end
    table.sort(keys)
    for _, k in ipairs(keys) do io.write(string.format("status %d: %d\n", k, total[k])) end
    local e = summary.errors
    io.write(string.format("errors: connect %d, read %d, write %d, timeout %d\n",
        e.connect, e.read, e.write, e.timeout))
    io.write(string.format("requests %d in %.1f s: %.0f req/s, p50 %.2f ms, p99 %.2f ms, max %.2f ms\n",
        summary.requests, summary.duration / 1e6, summary.requests / (summary.duration / 1e6),
        latency:percentile(50) / 1e3, latency:percentile(99) / 1e3, latency.max / 1e3))
end
EOF

"$bin" serve --store "$tmp/store" --bind "127.0.0.1:$port" --gpu off --max-connections-per-client 1024 \
    --source "od=$tmp/od.tif,tile_size=128,levels=2" --log warn >"$tmp/serve.log" 2>&1 &
spid=$!
pids+=($spid)
for _ in $(seq 300); do curl -fs -o /dev/null "http://127.0.0.1:$port/readyz" && break; sleep 0.1; done
rss() { awk '/VmRSS/ {print $2 " kB"}' "/proc/$spid/status"; }
echo "RSS at start: $(rss)"
(
    for ((t = 15; t < duration; t += 15)); do
        sleep 15
        echo "  RSS at ${t} s: $(rss)"
    done
) &
sampler=$!
pids+=($sampler)
wrk -t"$wrk_threads" -c$conns -d"${duration}s" --timeout 35s -s "$tmp/soak.lua" "http://127.0.0.1:$port" >"$tmp/wrk.txt"
kill "$sampler" 2>/dev/null || true
echo "RSS at end:   $(rss)"
grep -E '^(status|errors|requests)' "$tmp/wrk.txt"
metrics="$(curl -fs "http://127.0.0.1:$port/metrics")"
echo "$metrics" | grep -E '^terrastream_(bakes_done|bakes_failed|corrupt_blobs|shed|cache_hits|cache_misses)[a-z_]* ' || true
kill -0 "$spid" 2>/dev/null || { echo "FAIL: the server died"; exit 1; }
fail=0
if grep -E '^status ' "$tmp/wrk.txt" | awk '{sub(":", "", $2); print $2}' | grep -vqE '^(200|304|400|404|503)$'; then
    echo "FAIL: unexpected statuses"; fail=1
fi
if ! grep -q '^errors: connect 0, read 0, write 0, timeout 0$' "$tmp/wrk.txt"; then
    echo "FAIL: socket errors or timeouts"; fail=1
fi
if grep -qiE 'panic' "$tmp/serve.log"; then
    echo "FAIL: the server log mentions a panic"; fail=1
fi
[ $fail = 0 ] && echo "PASS: only expected statuses, no socket errors, no timeouts"
exit $fail
