#!/usr/bin/env bash
# Tile serving from three kinds of store, same machine, same run: `terrastream serve --store`
# on (1) a directory holding the tileset as a folder NAME/, (2) a directory holding it as one
# archive NAME.tsa (`terrastream pack`), (3) a bucket prefix s3://bench/store holding the folder
# as objects (`bake --out s3://…` into moto's S3 server on 127.0.0.1). A generated raster is
# baked once (--tile-size 256 --levels 4, as server_vs_nginx.sh); the bucket gets the same bake
# (compared object by object with the directory's files by MD5).
#
# The three servers run at once on free ports of 127.0.0.1, in two modes, one after the other:
#   cache off: --cache-bytes 0, every request reads its blob from its store (the file, a range
#              of the archive, an object of the bucket) and verifies it;
#   cache on:  the server's default memory cache (256 MiB: the whole tileset), after warm-up.
# First a check: for every 7th blob URL, the three send byte-identical bodies and the same ETag.
# Then wrk (50 connections, WRK_THREADS threads) cycles through the URLs of every blob of every
# level, with the content version (?v=) as clients send it, against each server for DURATION_S,
# for ROUNDS rounds; the order rotates each round (every source is first, second and third once
# in 3 rounds: the machine may be shared); each server gets a 5 s warm-up pass first. Prints
# requests/s and p99 of every run, the mean requests/s and median p99 per source and mode, and
# the ratios to the directory next to the targets (this bench's): archive ≥ 0.90 × the
# directory's requests/s and ≤ 1.25 × its p99 in both modes; bucket the same with the cache on.
# The bucket without cache has no target: moto is a Python server on the same cores, its
# figures are moto's, not S3's.
#
# The archive source is skipped with a message when `terrastream pack --help` fails, the bucket
# when moto's server is not installed or the server refuses the s3:// store.
# Needs wrk, curl and jq (apt-get install wrk curl jq); moto's server and boto3 in
# $TERRASTREAM_CI_VENV (default ~/.cache/terrastream-ci-venv, as .ci/run makes).
# Env: BIN (default target/release/terrastream, built if missing), WRK_THREADS (2), WORKERS
# (runtime threads of each server, 2), CACHES ("off on"), KEEP=1 keeps the temp dir.
# Usage: bench/serve_sources.sh [SIZE=2049] [DURATION_S=10] [ROUNDS=3]
set -euo pipefail
cd "$(dirname "$0")/.."
size="${1:-2049}"
duration="${2:-10}"
rounds="${3:-3}"
wrk_threads="${WRK_THREADS:-2}"
workers="${WORKERS:-2}"
caches="${CACHES:-off on}"
conns=50
venv="${TERRASTREAM_CI_VENV:-$HOME/.cache/terrastream-ci-venv}"
py="$venv/bin/python"

source bench/lib.sh
BIN="${BIN:-./target/release/terrastream}"
bench_setup "$BIN"

echo "load average before: $(cut -d' ' -f1-3 /proc/loadavg)"
echo "command: $0 $size $duration $rounds (WRK_THREADS=$wrk_threads WORKERS=$workers CACHES=\"$caches\" BIN=$BIN; $(git describe --always --dirty 2>/dev/null || echo '?'))"
echo "machine: $(nproc) cores, $(awk '/MemTotal/ {printf "%.0f GiB", $2/1048576}' /proc/meminfo); wrk -t$wrk_threads -c$conns -d${duration}s; each server: $workers runtime threads"
"$bin" synth --width "$size" --cell-size 10 --out "$tmp/synth.tif" >/dev/null
mkdir -p "$tmp/dir" "$tmp/arch"
bake_opts=(--gpu off --tile-size 256 --levels 4 -q)
"$bin" bake "$tmp/synth.tif" --out "$tmp/dir/bench" "${bake_opts[@]}" >/dev/null
version="$(jq -r .content_version "$tmp/dir/bench/tileset.json")"
(cd "$tmp/dir/bench" && find tiles -name '*.tsb' | sort) \
    | sed -E "s#^tiles/(.*)\.tsb\$#/tilesets/bench/tiles/\1?v=$version#" >"$tmp/urls.txt"
blobs=$(wc -l <"$tmp/urls.txt")
bytes=$(find "$tmp/dir/bench/tiles" -name '*.tsb' -printf '%s\n' | awk '{s+=$1} END {print s}')
echo "tileset: ${size}x${size} samples, $blobs blobs, $bytes bytes (mean $((bytes / blobs)) B/blob), $(find "$tmp/dir/bench" -type f | wc -l) files"

# The sources: "name store" lines; a skipped one gets a "name: why" line in $tmp/skipped.
sources=("dir $tmp/dir")
: >"$tmp/skipped"
if "$bin" pack --help >/dev/null 2>&1; then
    "$bin" pack "$tmp/dir/bench" --out "$tmp/arch/bench.tsa" -q >"$tmp/pack.log"
    echo "archive: $(stat -c %s "$tmp/arch/bench.tsa") bytes ($(head -1 "$tmp/pack.log"))"
    sources+=("archive $tmp/arch")
else
    echo "archive: skipped: \`terrastream pack --help\` fails (this binary has no pack yet)" | tee -a "$tmp/skipped"
fi
if [ -x "$venv/bin/moto_server" ] && "$py" -c 'import boto3' 2>/dev/null; then
    start_moto "$venv" bench
    t0=$(date +%s.%N)
    "$bin" bake "$tmp/synth.tif" --out s3://bench/store/bench "${bake_opts[@]}" >/dev/null
    t1=$(date +%s.%N)
    same=$("$py" bench/s3_upload.py compare s3://bench/store/bench "$tmp/dir/bench") \
        || { echo "bucket: the bake into s3://bench/store/bench differs from the directory's: $same" >&2; exit 1; }
    echo "bucket: moto on 127.0.0.1:$moto_port, bake into s3://bench/store/bench in $(awk -v a="$t0" -v b="$t1" 'BEGIN {printf "%.2f", b - a}') s; $same"
    sources+=("s3 s3://bench/store")
else
    echo "s3: skipped: no moto_server/boto3 in $venv (python3 -m venv $venv && $venv/bin/pip install 'moto[server]' boto3)" | tee -a "$tmp/skipped"
fi

wrk_url_script urls

declare -A port=() spid=()
up() { # NAME → 0 once it answers the first URL; 1 if its process ended
    local p=${port[$1]} pid=${spid[$1]}
    for _ in $(seq 300); do
        curl -fs -o /dev/null "http://127.0.0.1:$p$(head -1 "$tmp/urls.txt")" && return 0
        kill -0 "$pid" 2>/dev/null || return 1
        sleep 0.1
    done
    echo "$1: nothing answers on port $p after 30 s" >&2; exit 1
}
start_all() { # CACHE_BYTES (empty: the default) → starts a server per source; drops sources that refuse
    local kept=() name store
    for s in "${sources[@]}"; do
        read -r name store <<<"$s"
        port[$name]=$(free_port)
        TOKIO_WORKER_THREADS=$workers "$bin" serve --store "$store" --bind "127.0.0.1:${port[$name]}" --gpu off \
            --log warn ${1:+--cache-bytes "$1"} >"$tmp/serve-$name.log" 2>&1 &
        spid[$name]=$!
        pids+=($!)
    done
    for s in "${sources[@]}"; do
        read -r name store <<<"$s"
        if up "$name"; then
            kept+=("$s")
        elif [ "$name" = dir ]; then
            echo "the directory store does not serve: $(tail -3 "$tmp/serve-$name.log")" >&2; exit 1
        else
            echo "$name: skipped: serve --store $store ended: $(tail -1 "$tmp/serve-$name.log")" | tee -a "$tmp/skipped"
        fi
    done
    sources=("${kept[@]}")
}
stop_all() {
    local name
    for s in "${sources[@]}"; do
        read -r name _ <<<"$s"
        kill "${spid[$name]}" 2>/dev/null || true
        wait "${spid[$name]}" 2>/dev/null || true
    done
}

# Every 7th URL: the same status, body and ETag from every source.
check_same() {
    local n=0 name u ref_etag etag
    while read -r u; do
        n=$((n + 1))
        ref_etag=""
        for s in "${sources[@]}"; do
            read -r name _ <<<"$s"
            curl -fs -D "$tmp/h-$name" -o "$tmp/b-$name" "http://127.0.0.1:${port[$name]}$u" \
                || { echo "$name: GET $u failed" >&2; exit 1; }
            etag=$(awk 'tolower($1) == "etag:" {sub(/\r$/, ""); print $2}' "$tmp/h-$name")
            [ -n "$etag" ] || { echo "$name: no ETag for $u" >&2; exit 1; }
            if [ -z "$ref_etag" ]; then
                ref_etag=$etag
            else
                cmp -s "$tmp/b-dir" "$tmp/b-$name" || { echo "$name: other bytes than the directory's for $u" >&2; exit 1; }
                [ "$etag" = "$ref_etag" ] || { echo "$name: ETag $etag, the directory's $ref_etag, for $u" >&2; exit 1; }
            fi
        done
    done < <(awk 'NR % 7 == 1' "$tmp/urls.txt")
    echo "checked: $n URLs (every 7th), identical bodies and ETags from: $(printf '%s\n' "${sources[@]}" | cut -d' ' -f1 | tr '\n' ' ')"
}

run() { # MODE NAME
    local f="$tmp/$1-$2"
    wrk -t"$wrk_threads" -c$conns -d"${duration}s" --latency -s "$tmp/urls.lua" "http://127.0.0.1:${port[$2]}" >"$f.txt"
    wrk_report "$f.txt" "$2" 10 "$f.sum"
}
summary() { # FILE → "mean_rps median_p99_ms"
    sort -k2 -g "$1" | awk '{rps += $1; p[NR] = $2} END {printf "%.0f %.2f\n", rps / NR, (NR % 2) ? p[(NR + 1) / 2] : (p[NR / 2] + p[NR / 2 + 1]) / 2}'
}

all_sources=("${sources[@]}")
for mode in $caches; do
    case "$mode" in
        off) cache_bytes=0; what="cache off (--cache-bytes 0: every request reads its store)" ;;
        on) cache_bytes=""; what="cache on (the default memory cache, warmed)" ;;
        *) echo "CACHES: off and/or on, not $mode" >&2; exit 2 ;;
    esac
    echo
    echo "== $what"
    sources=("${all_sources[@]}")
    start_all "$cache_bytes"
    all_sources=("${sources[@]}") # a source that refused stays out of the next mode too
    check_same
    names=()
    for s in "${sources[@]}"; do read -r name _ <<<"$s"; names+=("$name"); done
    for name in "${names[@]}"; do
        wrk -t"$wrk_threads" -c$conns -d5s -s "$tmp/urls.lua" "http://127.0.0.1:${port[$name]}" >/dev/null
    done
    n=${#names[@]}
    for ((r = 1; r <= rounds; r++)); do
        order=()
        for ((i = 0; i < n; i++)); do order+=("${names[$(((i + r - 1) % n))]}"); done
        echo "round $r: ${order[*]}"
        for name in "${order[@]}"; do run "$mode" "$name"; done
    done
    stop_all
    echo "$mode: over $rounds rounds of ${duration} s (mean requests/s, median p99):"
    read -r d_rps d_p99 < <(summary "$tmp/$mode-dir.sum")
    for name in "${names[@]}"; do
        read -r rps p99 < <(summary "$tmp/$mode-$name.sum")
        if [ "$name" = dir ]; then
            target=""
        elif [ "$name" = s3 ] && [ "$mode" = off ]; then
            target="(no target: moto's figures, not S3's)"
        else
            target="(targets: ≥ 0.90, ≤ 1.25)"
        fi
        awk -v n="$name" -v a="$rps" -v b="$p99" -v c="$d_rps" -v d="$d_p99" -v t="$target" 'BEGIN {
            printf "  %-10s %8d req/s   p99 %8.2f ms", n, a, b
            if (n != "dir") printf "   / dir: requests/s %.2f, p99 %.2f %s", a / c, b / d, t
            printf "\n"
        }'
    done
done
if [ -s "$tmp/skipped" ]; then
    echo "skipped:"; sed 's/^/  /' "$tmp/skipped"
fi
echo "load average after: $(cut -d' ' -f1-3 /proc/loadavg)"
