#!/usr/bin/env bash
# LAS/LAZ gridding (issue 14): a generated survey of N points (default 20 M) over W × H metres
# (default 4000 × 2500, 2 points per m², 70 % ground), written as LAS and as LAZ, then each
# gridded at 1 m in its own process (read, bucket, reduce, opening scan). Prints points/s and peak
# RSS for both and the LAZ/LAS time ratio; then bakes the LAZ end to end. Files go to $TMPDIR
# (about 0.6 GB for 20 M points as LAS) and are removed after.
#
# Usage: bench/lidar.sh [N] [W] [H]
set -euo pipefail
cd "$(dirname "$0")/.."
n="${1:-20000000}"; w="${2:-4000}"; h="${3:-2500}"
cargo build --release --quiet --examples
cargo build --release --quiet
ex=./target/release/examples/lidar_bench
tmp="$(mktemp -d)"
trap 'rm -rf "$tmp"' EXIT
echo "machine: $(nproc) cores, $(awk '/MemTotal/ {printf "%.0f GiB", $2/1048576}' /proc/meminfo)"
"$ex" write "$n" "$w" "$h" "$tmp/survey.las"
"$ex" write "$n" "$w" "$h" "$tmp/survey.laz"
las_out=$("$ex" grid "$tmp/survey.las" 1); echo "$las_out"
laz_out=$("$ex" grid "$tmp/survey.laz" 1); echo "$laz_out"
secs() { sed -nE 's/.* in ([0-9.]+) s:.*/\1/p' <<<"$1"; }
awk -v a="$(secs "$las_out")" -v b="$(secs "$laz_out")" 'BEGIN { printf "LAZ / LAS gridding time: %.2f×\n", b / a }'
echo "== bake of the LAZ at 1 m (default options)"
TMPDIR="$tmp" ./target/release/terrastream bake --quiet --cell-size 1 "$tmp/survey.laz" --out "$tmp/tiles" | grep -E "^baked|^peak memory"
