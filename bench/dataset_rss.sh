#!/usr/bin/env bash
# Out-of-core bake (issue 14): generated float32 GeoTIFFs in 256² tiles (BigTIFF past 4 GiB) of
# 8193², 16385² and 32769² samples, each baked end to end with the default options and the
# default 512 MiB block cache. Prints per size the bake's throughput and the process's peak RSS
# (VmHWM, as `bake` reports it) next to the targets: peak RSS at most 1 GiB at every size and
# flat in the size; at least 3.1 M samples/s (the in-memory bake's figure at 16385² before the
# change), goal 5 M. The rasters are written to $TMPDIR (4.3 GB at 32769²) and removed after.
#
# Usage: bench/dataset_rss.sh [SIZES="8193 16385 32769"] [extra bake flags…]
set -euo pipefail
cd "$(dirname "$0")/.."
sizes="${1:-8193 16385 32769}"; shift || true
cargo build --release --quiet
bin=./target/release/terrastream
tmp="$(mktemp -d)"
trap 'rm -rf "$tmp"' EXIT
echo "machine: $(nproc) cores, $(awk '/MemTotal/ {printf "%.0f GiB", $2/1048576}' /proc/meminfo)"
printf '%-8s %14s %14s %12s   %s\n' size "M samples/s" "peak RSS MiB" "tiles" "targets: ≥ 3.1 M samples/s (goal 5), ≤ 1024 MiB"
for n in $sizes; do
    "$bin" synth --tiled 256 --width "$n" --cell-size 10 --out "$tmp/dem.tif" >/dev/null
    out=$("$bin" bake --quiet "$tmp/dem.tif" --out "$tmp/tiles" "$@")
    rate=$(sed -nE 's/.*: ([0-9.]+) M samples\/s.*/\1/p' <<<"$out" | head -1)
    rss=$(sed -nE 's/^peak memory \(RSS\): ([0-9]+) MiB/\1/p' <<<"$out")
    tiles=$(sed -nE 's/^baked ([0-9]+) tiles.*/\1/p' <<<"$out")
    printf '%-8s %14s %14s %12s\n' "${n}²" "$rate" "$rss" "$tiles"
    rm -rf "$tmp/tiles" "$tmp/dem.tif"
done
