#!/usr/bin/env bash
# Whole-bake throughput (CPU path): a generated 4097×4097 raster baked end to end with the
# default options; prints the bake summary (samples/s, peak memory, per-level figures) and the
# target next to it. Usage: bench/bake_throughput.sh [SIZE] [extra bake flags…]
set -euo pipefail
cd "$(dirname "$0")/.."
size="${1:-4097}"; shift || true
cargo build --release --quiet
tmp="$(mktemp -d)"
trap 'rm -rf "$tmp"' EXIT
./target/release/terrastream synth --width "$size" --cell-size 10 --out "$tmp/synth.tif"
echo "machine: $(nproc) cores, $(awk '/MemTotal/ {printf "%.0f GiB", $2/1048576}' /proc/meminfo)"
./target/release/terrastream bake --quiet "$tmp/synth.tif" --out "$tmp/tiles" "$@"
du -sh "$tmp/tiles" | awk '{print "tileset size on disk: " $1}'
echo "target: at least 1.00 M samples/s end to end on a 2-core machine"
