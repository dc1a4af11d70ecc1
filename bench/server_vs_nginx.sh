#!/usr/bin/env bash
# Tile serving: `terrastream serve` against nginx serving the very same blob files, same
# machine, same run. A generated raster is baked with the release binary; nginx gets a
# generated config (non-root, `daemon off`, access_log off, worker_processes = the same count as
# the server's runtime threads) whose rewrite maps the server's URL layout
# (/tilesets/NAME/tiles/Z/X/Y/LEVEL) onto the store's files (NAME/tiles/Z/X/Y/LEVEL.tsb). wrk
# (50 connections) cycles through the URLs of every blob of every level, with the content
# version (?v=) as clients send it, against one server, then the other, for ROUNDS rounds that
# alternate which goes first (the machine may be shared: alternating spreads the noise over
# both); each server gets a 5 s warm-up pass first. Prints requests/s and p99 of every run, the
# mean requests/s and the median p99 of each server, and their ratios next to the targets.
#
# Usage: bench/server_vs_nginx.sh [SIZE=2049] [DURATION_S=30] [WRK_THREADS=2] [WORKERS=2] [ROUNDS=3]
set -euo pipefail
cd "$(dirname "$0")/.."
size="${1:-2049}"
duration="${2:-30}"
wrk_threads="${3:-2}"
workers="${4:-2}"
rounds="${5:-3}"
conns=50
port_ts=18081
port_ng=18082
bin=./target/release/terrastream
[ -x "$bin" ] || cargo build --release --quiet

tmp="$(mktemp -d)"
pids=()
cleanup() {
    for p in "${pids[@]}"; do kill "$p" 2>/dev/null || true; done
    wait 2>/dev/null || true
    rm -rf "$tmp"
}
trap cleanup EXIT
[ -n "${KEEP:-}" ] && trap - EXIT

echo "machine: $(nproc) cores, $(awk '/MemTotal/ {printf "%.0f GiB", $2/1048576}' /proc/meminfo); wrk -t$wrk_threads -c$conns -d${duration}s; server and nginx: $workers workers each"
"$bin" synth --width "$size" --cell-size 10 --out "$tmp/synth.tif"
mkdir -p "$tmp/store"
"$bin" bake --gpu off --tile-size 256 --levels 4 "$tmp/synth.tif" --out "$tmp/store/bench" >/dev/null
version="$(jq -r .content_version "$tmp/store/bench/tileset.json")"
(cd "$tmp/store/bench" && find tiles -name '*.tsb' | sort) \
    | sed -E "s#^tiles/(.*)\.tsb\$#/tilesets/bench/tiles/\1?v=$version#" >"$tmp/urls.txt"
blobs=$(wc -l <"$tmp/urls.txt")
bytes=$(find "$tmp/store/bench/tiles" -name '*.tsb' -printf '%s\n' | awk '{s+=$1} END {print s}')
echo "tileset: ${size}x${size} samples, $blobs blobs, $bytes bytes (mean $((bytes / blobs)) B/blob)"
find "$tmp/store/bench/tiles" -name '*.tsb' -printf '%s\n' | sort -n \
    | awk '{a[NR]=$1} END {printf "blob sizes: min %d, median %d, max %d bytes\n", a[1], a[int((NR+1)/2)], a[NR]}'

cat >"$tmp/mix.lua" <<EOF
local urls = {}
for line in io.lines("$tmp/urls.txt") do urls[#urls + 1] = line end
local i = 0
function init(args)
    -- Threads start at different points of the list.
    i = math.random(#urls)
end
function request()
    i = i % #urls + 1
    return wrk.format("GET", urls[i])
end
EOF

# nginx started as root drops its workers to `nobody`: let them read the store.
chmod -R a+rX "$tmp"
cat >"$tmp/nginx.conf" <<EOF
worker_processes $workers;
daemon off;
pid $tmp/nginx.pid;
error_log $tmp/nginx-error.log warn;
events { worker_connections 4096; }
http {
    access_log off;
    client_body_temp_path $tmp/ngx-body;
    proxy_temp_path $tmp/ngx-proxy;
    fastcgi_temp_path $tmp/ngx-fastcgi;
    uwsgi_temp_path $tmp/ngx-uwsgi;
    scgi_temp_path $tmp/ngx-scgi;
    sendfile on;
    tcp_nopush on;
    keepalive_requests 1000000;
    open_file_cache max=10000 inactive=60s;
    default_type application/octet-stream;
    server {
        listen 127.0.0.1:$port_ng;
        root $tmp/store;
        location /tilesets/ {
            rewrite "^/tilesets/([a-z0-9_-]{1,64})/tiles/([0-9]+)/([0-9]+)/([0-9]+)/([0-9]+)\$" /\$1/tiles/\$2/\$3/\$4/\$5.tsb break;
            return 404;
        }
    }
}
EOF

TOKIO_WORKER_THREADS=$workers "$bin" serve --store "$tmp/store" --bind "127.0.0.1:$port_ts" --gpu off \
    --log warn >"$tmp/serve.log" 2>&1 &
pids+=($!)
/usr/sbin/nginx -c "$tmp/nginx.conf" -p "$tmp" >"$tmp/nginx.out" 2>&1 &
pids+=($!)
for port in $port_ts $port_ng; do
    for _ in $(seq 100); do
        curl -fs -o /dev/null "http://127.0.0.1:$port$(head -1 "$tmp/urls.txt")" && break
        sleep 0.1
    done
done

# Both serve the very same bytes.
while read -r u; do
    curl -fs "http://127.0.0.1:$port_ts$u" -o "$tmp/a"
    curl -fs "http://127.0.0.1:$port_ng$u" -o "$tmp/b"
    cmp -s "$tmp/a" "$tmp/b" || { echo "different bytes for $u" >&2; exit 1; }
done < <(awk 'NR % 7 == 1' "$tmp/urls.txt")
echo "checked: both servers send identical bytes for every 7th URL"

run() { # NAME PORT
    wrk -t"$wrk_threads" -c$conns -d"${duration}s" --latency -s "$tmp/mix.lua" "http://127.0.0.1:$2" >"$tmp/$1.txt"
    local rps p99 bad errs
    rps=$(awk '/^Requests\/sec:/ {print $2}' "$tmp/$1.txt")
    p99=$(awk '$1 == "99%" {print $2}' "$tmp/$1.txt")
    bad=$(awk '/Non-2xx or 3xx responses:/ {print $NF}' "$tmp/$1.txt")
    errs=$(awk '/Socket errors:/ {sub(/.*Socket errors: /, ""); print}' "$tmp/$1.txt")
    printf '  %-12s %12s req/s   p99 %9s   non-2xx: %s   socket errors: %s\n' "$1" "$rps" "$p99" "${bad:-0}" "${errs:-none}"
    echo "$rps $(to_ms "$p99")" >>"$tmp/$1.sum"
}
to_ms() { # wrk latency (e.g. 812.00us, 3.21ms, 1.02s) → ms
    awk -v v="$1" 'BEGIN { n = v + 0; if (v ~ /us$/) n /= 1000; else if (v ~ /ms$/) n *= 1; else if (v ~ /s$/) n *= 1000; print n }'
}
for port in $port_ng $port_ts; do
    wrk -t"$wrk_threads" -c$conns -d5s -s "$tmp/mix.lua" "http://127.0.0.1:$port" >/dev/null
done
for ((r = 1; r <= rounds; r++)); do
    echo "round $r:"
    if ((r % 2)); then run nginx $port_ng; run terrastream $port_ts; else run terrastream $port_ts; run nginx $port_ng; fi
done
summary() { # FILE → "mean_rps median_p99_ms"
    sort -k2 -n "$1" | awk '{rps += $1; p[NR] = $2} END {printf "%.0f %.2f\n", rps / NR, (NR % 2) ? p[(NR + 1) / 2] : (p[NR / 2] + p[NR / 2 + 1]) / 2}'
}
read -r ng_rps ng_p99 < <(summary "$tmp/nginx.sum")
read -r ts_rps ts_p99 < <(summary "$tmp/terrastream.sum")
echo "over $rounds rounds of ${duration} s (mean requests/s, median p99):"
printf '  nginx        %8d req/s   p99 %7.2f ms\n' "$ng_rps" "$ng_p99"
printf '  terrastream  %8d req/s   p99 %7.2f ms\n' "$ts_rps" "$ts_p99"
awk -v a="$ts_rps" -v b="$ng_rps" -v c="$ts_p99" -v d="$ng_p99" 'BEGIN {
    printf "requests/s: terrastream / nginx = %.2f   (target >= 0.80)\n", a / b
    printf "p99:        terrastream / nginx = %.2f   (target <= 1.50)\n", c / d
}'
