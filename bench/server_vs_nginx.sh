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
# GLB phase: the same tiles as 3D Tiles content, /tilesets/NAME/3dtiles/tiles/Z/X/Y/LEVEL.glb?v=…,
# from the same server in the same run. A GLB is made from its blob on the first request and then
# kept in the server's memory cache, so: (cold) one pass over every GLB URL on a freshly started
# server, by one curl process with 50 transfers in parallel on keep-alive connections
# (requests/s = URLs / wall time of the pass, p99 of curl's per-request time), 3 times (median);
# the same curl pass again once they are cached (warm, same client: the client's own cost);
# then wrk on the GLB URLs in every round next to the blob runs (warm). The served GLBs are
# checked against `terrastream export --format 3dtiles` of the same tileset (all bytes counted,
# every 7th file compared).
#
# BASELINE=PATH (another terrastream binary, e.g. main's release build) serves the same store on a
# third port and runs in every round too, so a change is measured before/after in the same run
# (it gets TOKIO_WORKER_THREADS=WORKERS as well, for builds from before `--threads`).
# SKIP_GLB=1 leaves out every GLB pass and round (blobs only).
# GLB_COMPRESSION=meshopt asks for the GLBs with `?glb=meshopt` (EXT_meshopt_compression) and
# checks them against `export --glb-compression meshopt`; GLB_COMPRESSION=draco the same with
# `?glb=draco` (KHR_draco_mesh_compression meshes).
#
# Needs wrk, nginx (/usr/sbin/nginx), jq and curl >= 7.66 (-Z): apt-get install wrk nginx jq curl
# Usage: bench/server_vs_nginx.sh [SIZE=2049] [DURATION_S=20] [WRK_THREADS=2] [WORKERS=2] [ROUNDS=3]
set -euo pipefail
cd "$(dirname "$0")/.."
size="${1:-2049}"
duration="${2:-20}"
wrk_threads="${3:-2}"
workers="${4:-2}"
rounds="${5:-3}"
conns=50
cold_passes=3
port_ts=18081
port_ng=18082
port_bl=18083
baseline="${BASELINE:-}"
skip_glb="${SKIP_GLB:-}"
glb_compression="${GLB_COMPRESSION:-none}"
case "$glb_compression" in
    none) glb_query="" ;;
    meshopt) glb_query="\&glb=meshopt" ;;
    draco) glb_query="\&glb=draco" ;;
    *) echo "GLB_COMPRESSION: none, meshopt or draco, not $glb_compression" >&2; exit 2 ;;
esac
bin="${BIN:-./target/release/terrastream}"
[ -x "$bin" ] || cargo build --release --quiet

source bench/lib.sh
bench_setup

echo "load average before: $(cut -d' ' -f1-3 /proc/loadavg)"
echo "command: $0 $size $duration $wrk_threads $workers $rounds ($(git describe --always --dirty 2>/dev/null || echo '?'))"
echo "machine: $(nproc) cores, $(awk '/MemTotal/ {printf "%.0f GiB", $2/1048576}' /proc/meminfo); wrk -t$wrk_threads -c$conns -d${duration}s; server and nginx: $workers workers each (terrastream --threads $workers)"
[ -z "$baseline" ] || echo "baseline: $baseline (same store, same rounds)"
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

# The 3D Tiles view's URIs carry the GLB revision after the content version (immutable only then).
glb_revision="$(sed -n 's/^pub const GLB_REVISION: &str = "\(.*\)";$/\1/p' src/formats/tiles3d/mod.rs)"
[ -n "$glb_revision" ] || { echo "GLB_REVISION not found in src/formats/tiles3d/mod.rs" >&2; exit 1; }
sed -E "s#^/tilesets/bench/tiles/(.*)\?v=(.*)\$#/tilesets/bench/3dtiles/tiles/\1.glb?v=\2${glb_revision}${glb_query}#" "$tmp/urls.txt" >"$tmp/glb-urls.txt"
"$bin" export "$tmp/store/bench" --format 3dtiles --glb-compression "$glb_compression" --out "$tmp/3dtiles" --quiet >/dev/null
glb_bytes=$(find "$tmp/3dtiles/tiles" -name '*.glb' -printf '%s\n' | awk '{s+=$1} END {print s}')
echo "GLBs (3D Tiles) of the same tiles: $(wc -l <"$tmp/glb-urls.txt") URLs, $glb_bytes bytes (mean $((glb_bytes / blobs)) B/GLB, $(awk -v a="$glb_bytes" -v b="$bytes" 'BEGIN {printf "%.2f", a / b}')x the blobs)"

wrk_url_script urls
# GLB rounds ask for gzip as browsers do (Chromium sends `gzip, deflate, br, zstd` and gets gzip):
# the server sends the compressed form it keeps in memory.
wrk_url_script glb-urls Accept-Encoding gzip

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

wait_up() { # PORT
    for _ in $(seq 100); do
        curl -fs -o /dev/null "http://127.0.0.1:$1$(head -1 "$tmp/urls.txt")" && return 0
        sleep 0.1
    done
    echo "nothing answers on port $1" >&2; exit 1
}
start_ts() {
    TOKIO_WORKER_THREADS=$workers TERRASTREAM_THREADS=$workers "$bin" serve --store "$tmp/store" \
        --bind "127.0.0.1:$port_ts" --gpu off --log warn >>"$tmp/serve.log" 2>&1 &
    ts_pid=$!
    pids+=($ts_pid)
    wait_up $port_ts
}
start_ts
if [ -n "$baseline" ]; then
    cp "$baseline" "$tmp/baseline"
    TOKIO_WORKER_THREADS=$workers TERRASTREAM_THREADS=$workers "$tmp/baseline" serve --store "$tmp/store" \
        --bind "127.0.0.1:$port_bl" --gpu off --log warn >>"$tmp/baseline.log" 2>&1 &
    pids+=($!)
    wait_up $port_bl
fi
/usr/sbin/nginx -c "$tmp/nginx.conf" -p "$tmp" >"$tmp/nginx.out" 2>&1 &
pids+=($!)
wait_up $port_ng

# GLB, cold: the first request of every GLB (made from its blob on the fly), one curl process
# with $conns transfers in parallel on keep-alive connections.
curl_pass() { # NAME → prints "req/s p99_ms wall_s"; keeps per-request "code seconds bytes" in $tmp/NAME.curl
    awk -v base="http://127.0.0.1:$port_ts" '{printf "url = \"%s%s\"\noutput = \"/dev/null\"\n", base, $0}' \
        "$tmp/glb-urls.txt" >"$tmp/curl.cfg"
    local t0 t1 n bad
    t0=$(date +%s.%N)
    curl -s --no-progress-meter -Z --parallel-immediate --parallel-max $conns -K "$tmp/curl.cfg" \
        -w '%{http_code} %{time_total} %{size_download}\n' >"$tmp/$1.curl" 2>"$tmp/$1.err"
    t1=$(date +%s.%N)
    n=$(wc -l <"$tmp/$1.curl")
    bad=$(awk '$1 != 200' "$tmp/$1.curl" | wc -l)
    ((n == $(wc -l <"$tmp/glb-urls.txt") && bad == 0)) || { echo "$1: $n responses, $bad not 200" >&2; exit 1; }
    sort -k2 -g "$tmp/$1.curl" | awk -v t0="$t0" -v t1="$t1" \
        '{t[NR] = $2} END {i = int(NR * 0.99 + 0.999); printf "%.0f %.2f %.3f\n", NR / (t1 - t0), t[i] * 1000, t1 - t0}'
}
# $cold_passes cold passes, each on a freshly started server (nothing of the tileset in its
# memory: every GLB request reads, verifies and decodes its blob, then makes the GLB), then one
# warm pass with the same client. Cold figures: median requests/s and median p99 of the passes.
if [ -z "$skip_glb" ]; then
echo "GLB passes over all $(wc -l <"$tmp/glb-urls.txt") URLs (curl -Z --parallel-max $conns, keep-alive):"
for ((i = 1; i <= cold_passes; i++)); do
    if ((i > 1)); then kill "$ts_pid"; wait "$ts_pid" 2>/dev/null || true; start_ts; fi
    curl_pass glb-cold >"$tmp/cold.txt"
    read -r rps p99 wall <"$tmp/cold.txt"
    echo "$rps $p99" >>"$tmp/cold.sum"
    glb_served=$(awk '{s += $3} END {print s}' "$tmp/glb-cold.curl")
    [ "$glb_served" = "$glb_bytes" ] || { echo "served $glb_served GLB bytes, export wrote $glb_bytes" >&2; exit 1; }
    printf '  cold %d (fresh server)      %8d req/s   p99 %7.2f ms   (%.3f s, %d bytes)\n' "$i" "$rps" "$p99" "$wall" "$glb_served"
done
curl_pass glb-warm-curl >"$tmp/warm-curl.txt"
read -r cw_rps cw_p99 cw_wall <"$tmp/warm-curl.txt"
printf '  warm (cached), same client  %8d req/s   p99 %7.2f ms   (%.3f s)\n' "$cw_rps" "$cw_p99" "$cw_wall"
read -r cold_rps cold_p99 < <(sort -n "$tmp/cold.sum" | awk '{r[NR] = $1} END {printf "%d ", r[int((NR + 1) / 2)]}'; \
    sort -k2 -g "$tmp/cold.sum" | awk '{p[NR] = $2} END {print p[int((NR + 1) / 2)]}')
while read -r u; do
    f="${u%%\?*}"; f="$tmp/3dtiles/tiles/${f#/tilesets/bench/3dtiles/tiles/}"
    curl -fs "http://127.0.0.1:$port_ts$u" -o "$tmp/a"
    cmp -s "$tmp/a" "$f" || { echo "GLB $u differs from the export's $f" >&2; exit 1; }
done < <(awk 'NR % 7 == 1' "$tmp/glb-urls.txt")
echo "checked: the server's GLBs total the export's bytes, and are its bytes for every 7th URL"
fi

# Both serve the very same bytes.
while read -r u; do
    curl -fs "http://127.0.0.1:$port_ts$u" -o "$tmp/a"
    curl -fs "http://127.0.0.1:$port_ng$u" -o "$tmp/b"
    cmp -s "$tmp/a" "$tmp/b" || { echo "different bytes for $u" >&2; exit 1; }
done < <(awk 'NR % 7 == 1' "$tmp/urls.txt")
echo "checked: both servers send identical bytes for every 7th URL"

run() { # NAME PORT [URL LIST]
    wrk -t"$wrk_threads" -c$conns -d"${duration}s" --latency -s "$tmp/${3:-urls}.lua" "http://127.0.0.1:$2" >"$tmp/$1.txt"
    wrk_report "$tmp/$1.txt" "$1" 16 "$tmp/$1.sum"
}
for port in $port_ng $port_ts ${baseline:+$port_bl}; do
    wrk -t"$wrk_threads" -c$conns -d5s -s "$tmp/urls.lua" "http://127.0.0.1:$port" >/dev/null
done
[ -n "$skip_glb" ] || wrk -t"$wrk_threads" -c$conns -d5s -s "$tmp/glb-urls.lua" "http://127.0.0.1:$port_ts" >/dev/null
for ((r = 1; r <= rounds; r++)); do
    echo "round $r:"
    order=(nginx terrastream)
    [ -z "$baseline" ] || order+=(baseline)
    [ -n "$skip_glb" ] || order+=(terrastream-glb)
    if ! ((r % 2)); then order=($(printf '%s\n' "${order[@]}" | tac)); fi
    for name in "${order[@]}"; do
        case $name in
            nginx) run nginx $port_ng ;;
            terrastream) run terrastream $port_ts ;;
            baseline) run baseline $port_bl ;;
            terrastream-glb) run terrastream-glb $port_ts glb-urls ;;
        esac
    done
done
summary() { # FILE → "mean_rps median_p99_ms"
    sort -k2 -n "$1" | awk '{rps += $1; p[NR] = $2} END {printf "%.0f %.2f\n", rps / NR, (NR % 2) ? p[(NR + 1) / 2] : (p[NR / 2] + p[NR / 2 + 1]) / 2}'
}
read -r ng_rps ng_p99 < <(summary "$tmp/nginx.sum")
read -r ts_rps ts_p99 < <(summary "$tmp/terrastream.sum")
echo "over $rounds rounds of ${duration} s (mean requests/s, median p99):"
printf '  nginx, blobs             %8d req/s   p99 %7.2f ms\n' "$ng_rps" "$ng_p99"
printf '  terrastream, blobs       %8d req/s   p99 %7.2f ms\n' "$ts_rps" "$ts_p99"
if [ -n "$baseline" ]; then
    read -r bl_rps bl_p99 < <(summary "$tmp/baseline.sum")
    printf '  baseline, blobs          %8d req/s   p99 %7.2f ms   (%s)\n' "$bl_rps" "$bl_p99" "$baseline"
fi
if [ -z "$skip_glb" ]; then
    read -r glb_rps glb_p99 < <(summary "$tmp/terrastream-glb.sum")
    printf '  terrastream, GLB (warm)  %8d req/s   p99 %7.2f ms\n' "$glb_rps" "$glb_p99"
    printf '  terrastream, GLB (cold)  %8d req/s   p99 %7.2f ms   (median of %d curl passes on a fresh server; warm, same client: %d req/s, p99 %.2f ms)\n' "$cold_rps" "$cold_p99" "$cold_passes" "$cw_rps" "$cw_p99"
fi
# Issue 41's goals for the blobs: at least 1.1x nginx's requests/s, at most its p99.
awk -v a="$ts_rps" -v b="$ng_rps" -v c="$ts_p99" -v d="$ng_p99" 'BEGIN {
    r = a / b; p = c / d
    printf "requests/s: terrastream / nginx = %.2f   (goal >= 1.10: %s)\n", r, (r >= 1.10) ? "met" : "NOT met"
    printf "p99:        terrastream / nginx = %.2f   (goal <= 1.00: %s)\n", p, (p <= 1.00) ? "met" : "NOT met"
}'
[ -z "$baseline" ] || awk -v a="$ts_rps" -v b="$bl_rps" -v c="$ts_p99" -v d="$bl_p99" -v e="$ng_rps" -v f="$ng_p99" 'BEGIN {
    printf "requests/s: terrastream / baseline = %.2f   (baseline / nginx = %.2f)\n", a / b, b / e
    printf "p99:        terrastream / baseline = %.2f   (baseline / nginx = %.2f)\n", c / d, d / f
}'
[ -n "$skip_glb" ] || awk -v a="$ts_rps" -v c="$ts_p99" -v g="$glb_rps" -v h="$glb_p99" 'BEGIN {
    printf "requests/s: GLB (warm) / blobs  = %.2f\n", g / a
    printf "p99:        GLB (warm) / blobs  = %.2f\n", h / c
}'
echo "load average after: $(cut -d' ' -f1-3 /proc/loadavg)"
