#!/usr/bin/env bash
# A mosaic of 16 generated SRTM .hgt tiles (4° × 4°, 3 arc-seconds: 4801² samples) against the
# same area as one geographic GeoTIFF: both baked with the same options; prints both bakes'
# summaries and compares their blobs and index byte for byte (the manifest may differ only where
# it names its sources). Exit 1 on any difference.
#
# Usage: bench/hgt_mosaic.sh [extra bake flags…]
set -euo pipefail
cd "$(dirname "$0")/.."
cargo build --release --quiet --examples
bin=./target/release/terrastream
tmp="$(mktemp -d)"
trap 'rm -rf "$tmp"' EXIT
./target/release/examples/hgt_mosaic "$tmp/tiles" "$tmp/whole.tif"
echo "machine: $(nproc) cores"
echo "== 16 .hgt tiles"; "$bin" bake "$tmp"/tiles/*.hgt --out "$tmp/a" -q "$@"
echo "== one GeoTIFF";   "$bin" bake "$tmp/whole.tif" --out "$tmp/b" -q "$@"
if diff -r "$tmp/a/tiles" "$tmp/b/tiles" >/dev/null && diff -r "$tmp/a/index" "$tmp/b/index" >/dev/null; then
    echo "blobs and index: identical ($(find "$tmp/a/tiles" -type f | wc -l) files)"
else
    echo "blobs or index differ"; exit 1
fi
