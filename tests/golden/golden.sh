#!/usr/bin/env bash
# Golden outputs for refactors that must not change behaviour: every file of three bakes (the
# fuji bake of docs/cli.md, `bake-model` of the bunny, the demo tileset), their summaries on
# stdout (timings and peak memory masked), and status line, headers (Date dropped) and body of a
# fixed list of HTTP requests to `serve` over those three.
#
# The outputs themselves are committed in tests/golden/expected/, readable (summarize.py): text
# as it is, each blob's header decoded field by field, other binary bodies as size + sha256 +
# first bytes, and `files.sha256` pinning every file's exact bytes. A change shows as a diff.
#
#   tests/golden/golden.sh record   # rewrites tests/golden/expected/ (only for a change meant
#                                   # to alter output; review `git diff tests/golden` and say so
#                                   # in the commit)
#   tests/golden/golden.sh check    # recomputes and diffs against it; exit 1 on any difference
#
# BIN (default target/release/terrastream, built if missing), DATA (default ../shared/data) and
# PORT (default 18123, on 127.0.0.1) and KEEP (a folder to keep the outputs in) can be set. Every
# bake runs with --gpu off, the deterministic CPU reference; the GPU path has its own equality
# tests (tests/gpu.rs).
set -euo pipefail

ROOT=$(cd "$(dirname "$0")/../.." && pwd)
BIN=${BIN:-$ROOT/target/release/terrastream}
DATA=${DATA:-$ROOT/../shared/data}
PORT=${PORT:-18123}
GOLDEN=$ROOT/tests/golden/expected
mode=${1:-}
case $mode in record|check) ;; *) echo "usage: $0 record|check" >&2; exit 2 ;; esac
[ -x "$BIN" ] || (cd "$ROOT" && cargo build --release --quiet)
BIN=$(cd "$(dirname "$BIN")" && pwd)/$(basename "$BIN")

WORK=$(mktemp -d)
SERVER=
cleanup() {
    [ -n "$SERVER" ] && kill "$SERVER" 2>/dev/null && wait "$SERVER" 2>/dev/null
    rm -rf "$WORK"
}
trap cleanup EXIT
cd "$WORK"
mkdir -p store out

# Timings, rates and peak memory vary run to run; everything else in a summary is behaviour.
mask() {
    sed -E -e 's/ in [0-9.]+ s( \([^)]*\))?/ in T s/' -e 's/[0-9.]+ M (samples|points)\/s/R \1\/s/' \
        -e '/^peak memory/d'
}

"$BIN" bake "$DATA/fuji.png" --encoding terrain-rgb --cell-size 30 --gpu off --out store/fuji \
    2>/dev/null | mask >out/bake-fuji.stdout
"$BIN" bake-model "$DATA/stanford-bunny.obj" --gpu off --out store/bunny 2>/dev/null \
    | mask >out/bake-model-bunny.stdout
"$BIN" demo --no-serve --dir demo --gpu off 2>/dev/null | mask >out/demo.stdout
mv demo/demo-store/demo store/demo

"$BIN" serve --store store --bind "127.0.0.1:$PORT" >out/serve.log 2>&1 &
SERVER=$!
for _ in $(seq 100); do
    curl -sf -o /dev/null "http://127.0.0.1:$PORT/readyz" && break
    sleep 0.1
done
curl -sf -o /dev/null "http://127.0.0.1:$PORT/readyz" || { echo "server did not become ready" >&2; cat out/serve.log >&2; exit 1; }

n=0
# request NAME METHOD PATH [curl header args…]: status line + headers (minus Date) and body.
request() {
    local name=$1 method=$2 path=$3
    shift 3
    n=$((n + 1))
    local f
    f=out/http-$(printf %02d "$n")-$name
    local how=(-X "$method")
    [ "$method" = HEAD ] && how=(-I)
    curl -s --path-as-is "${how[@]}" "$@" -D "$f.head" -o "$f.body" "http://127.0.0.1:$PORT$path" || true
    grep -v -i '^date:' "$f.head" >"$f.h" && mv "$f.h" "$f.head"
    # `curl -I` writes the head to the body file too (Date and all): a HEAD has no body.
    [ "$method" = HEAD ] && : >"$f.body"
    return 0
}
blob=/tilesets/demo/tiles/1/0/1/0
request healthz GET /healthz
request readyz GET /readyz
request openapi GET /openapi.json
request list GET /tilesets
for t in demo fuji bunny; do
    request "summary-$t" GET "/tilesets/$t"
    request "manifest-$t" GET "/tilesets/$t/tileset.json"
done
request index-chunk GET /tilesets/demo/index/0/0/0.json
request manifest-gzip GET /tilesets/demo/tileset.json -H 'Accept-Encoding: gzip'
request blob-root GET /tilesets/demo/tiles/0/0/0/0
request blob GET "$blob"
etag=$(sed -n 's/^etag: *//Ip' "out/http-$(printf %02d "$n")-blob.head" | tr -d '\r')
request blob-deep GET /tilesets/demo/tiles/2/3/3/3
request blob-fuji GET /tilesets/fuji/tiles/0/0/0/0
request blob-bunny GET /tilesets/bunny/tiles/0/0/0/2
request blob-head HEAD "$blob"
request blob-range GET "$blob" -H 'Range: bytes=0-99'
request blob-range-suffix GET "$blob" -H 'Range: bytes=-10'
request blob-range-unsatisfiable GET "$blob" -H 'Range: bytes=100000-'
request blob-not-modified GET "$blob" -H "If-None-Match: $etag"
request blob-modified GET "$blob" -H 'If-None-Match: "0000000000000000"'
request blob-cors GET "$blob" -H 'Origin: https://example.com'
request preflight OPTIONS "$blob" -H 'Origin: https://example.com' -H 'Access-Control-Request-Method: GET'
request missing-tileset GET /tilesets/nope
request missing-level GET /tilesets/demo/tiles/1/0/1/9
request unpaid-level GET /tilesets/demo/tiles/2/3/3/1
request out-of-range-key GET /tilesets/demo/tiles/1/5/0/0
request too-deep GET /tilesets/demo/tiles/9/0/0/0
request bad-key GET /tilesets/demo/tiles/x/0/0/0
request bad-method PUT "$blob"
request unknown-path GET /nope
request upload-no-token POST /tilesets/demo
request delete-no-token DELETE /tilesets/demo
request unknown-job GET /jobs/0123456789abcdef

rm -f out/serve.log
summary=$WORK/summary
mkdir -p "$WORK/all" "$summary"
cp -r store out "$WORK/all"/
python3 "$ROOT/tests/golden/summarize.py" "$WORK/all" "$summary"

# KEEP=DIR: keep the outputs there to look at.
[ -n "${KEEP:-}" ] && mkdir -p "$KEEP" && cp -r out store "$KEEP"/
if [ "$mode" = record ]; then
    rm -rf "$GOLDEN"
    cp -r "$summary" "$GOLDEN"
    echo "golden: recorded $(wc -l <"$GOLDEN/files.sha256") files in ${GOLDEN#"$ROOT"/}"
else
    if diff -ru "$GOLDEN" "$summary"; then
        echo "golden: all $(wc -l <"$GOLDEN/files.sha256") files identical"
    else
        keep=$(mktemp -d /tmp/golden-diff.XXXXXX)
        cp -r out store "$keep"/
        echo "golden: DIFFERENT (outputs kept in $keep)" >&2
        exit 1
    fi
fi
