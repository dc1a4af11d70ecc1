#!/usr/bin/env bash
# Point-level bake throughput, GPU path (`lod::gpu` on whatever adapter wgpu finds: Mesa's
# lavapipe where there is no GPU) against the CPU reference (`lod::cpu`, all cores), same input,
# same run:
#   1. the point-level stage alone (examples/lod_throughput.rs: TINs built first, untimed, then
#      every node's levels baked by each path): points/s, tiles/s, GPU batches and peak bytes,
#      and the GPU path's host work (lod::gpu::BatchReport: host seconds per million points by
#      phase, bytes uploaded and read back per point, submissions and dispatches per batch, and
#      the host threads' CPU time from /proc); the same on the Stanford bunny and on a generated
#      dense mesh (a noisy sphere of SPHERE_TRIANGLES triangles, default 10,000,000; 0 skips it);
#   2. the whole bake, `bake --gpu off` then `bake --gpu on` (TIN, measurement, encoding and
#      writes are the same in both): tiles/s and point levels' points/s end to end, and the
#      GPU memory peak per batch against the --gpu-budget-mib flag.
# Usage: bench/gpu_vs_cpu.sh [SIZE] [extra bake flags…]   (SIZE defaults to 4097)
# SPHERE_TRIANGLES=N sizes the dense mesh (on lavapipe, size it down: 2,000,000 was measured there).
# BIN and LOD_THROUGHPUT name prebuilt binaries (a GPU machine that cannot build), else both are
# built here.
set -euo pipefail
cd "$(dirname "$0")/.."
size="${1:-4097}"; shift || true
if [ -z "${BIN:-}" ]; then
  cargo build --release --quiet --bin terrastream --example lod_throughput
fi
bin="${BIN:-./target/release/terrastream}"
lod="${LOD_THROUGHPUT:-./target/release/examples/lod_throughput}"
tmp="$(mktemp -d)"
trap 'rm -rf "$tmp"' EXIT
$bin synth --width "$size" --cell-size 10 --out "$tmp/synth.tif"
echo "machine: $(nproc) cores, GPU: $(nvidia-smi --query-gpu=name,driver_version --format=csv,noheader 2>/dev/null || echo none), $(awk '/MemTotal/ {printf "%.0f GiB", $2/1048576}' /proc/meminfo), input: generated ${size}x${size} raster, 10 m cells"

echo "== point-level stage alone (same level jobs, both paths)"
$lod "$tmp/synth.tif" "$@"
bunny="${TERRASTREAM_DATA:-../shared/data}/stanford-bunny.obj"
if [ -f "$bunny" ]; then
  echo "== point-level stage alone: the Stanford bunny, grids of 512, 256, 128, 64 cells"
  $lod --model "$bunny"
fi
sphere="${SPHERE_TRIANGLES:-10000000}"
if [ "$sphere" -gt 0 ]; then
  echo "== point-level stage alone: generated noisy sphere of about $sphere triangles, grids of 512, 256, 128, 64 cells"
  $lod --sphere "$sphere"
fi

# Points of the point levels (levels 1..) in a bake summary's level table.
points_of() { awk '$2 == "points" { n += $4 } END { print n + 0 }' "$1"; }
tiles_of() { sed -n 's/^baked \([0-9]*\) tiles.* in \([0-9.]*\) s.*/\1 \2/p' "$1"; }

for mode in off on; do
  echo "== bake --gpu $mode"
  $bin bake --quiet --gpu "$mode" "$tmp/synth.tif" --out "$tmp/tiles-$mode" "$@" | tee "$tmp/summary-$mode.txt"
  read -r tiles secs < <(tiles_of "$tmp/summary-$mode.txt")
  pts=$(points_of "$tmp/summary-$mode.txt")
  awk -v m="$mode" -v t="$tiles" -v s="$secs" -v p="$pts" 'BEGIN {
    printf "bake --gpu %s end to end: %d tiles in %.2f s = %.1f tiles/s; %d level points = %.3f M points/s\n", m, t, s, t / s, p, p / s / 1e6 }'
done
# The Stanford bunny through bake-model: the default ladder (the paper's Table 3 sizes) and a
# finer one (T = 512, 384, 256, 128) where the point stage dominates. "bake" is the point
# levels baked, measured and encoded (reading the OBJ excluded).
if [ -f "$bunny" ]; then
  for res in 80 512; do
    for mode in off on; do
      $bin bake-model --gpu "$mode" --resolution "$res" --out "$tmp/bunny-$res-$mode" "$bunny" 2>/dev/null > "$tmp/bunny.txt"
      secs=$(sed -n 's/.*bake \([0-9.]*\) s).*/\1/p' "$tmp/bunny.txt")
      pts=$(awk '$2 == "points" { n += $5 } END { print n + 0 }' "$tmp/bunny.txt")
      awk -v m="$mode" -v r="$res" -v s="$secs" -v p="$pts" 'BEGIN {
        printf "bunny T=%d bake-model --gpu %s: %d level points in %.3f s = %.3f M points/s\n", r, m, p, s, p / s / 1e6 }'
    done
  done
fi
echo "targets: GPU path at least as fast as the CPU path on this machine; >= 50 M points/s on a data-centre GPU"
