#!/usr/bin/env bash
# Heights per second (issue 38): terrastream in-process (examples/heights_bench.rs: SourceSampler
# and MeshSampler) and over HTTP (`serve`, binary bodies; surface=source bilinear and
# surface=mesh) against rasterio's DatasetReader.sample (what Open Topo Data runs on), in one
# run on one machine, on the same DEM and the same seeded random points (N, default 1,000,000,
# inside the DEM), in batches of 1, 100, 10,000 and 1,000,000 points; latency p50/p99 of
# 10,000-point batches over HTTP (50 requests). Prints a table with both sides.
#
#   bench/heights_vs_rasterio.sh [DEM]     (default: the shared 1205 x 1197 SRTM subset, UTM 32N)
#
# Env: BIN (default ./target/release/terrastream), PY (the bench venv's python), N, SECS (time
# per batch size and side, default 3), KEEP=1 keeps the temporary folder.
set -euo pipefail
cd "$(dirname "$0")/.."
source bench/lib.sh

DATA="${TERRASTREAM_DATA:-../shared/data}"
DEM="$(realpath "${1:-$DATA/geo/utm32n_pixelispoint_n00e010.tif}")"
PY="${PY:-$HOME/.cache/terrastream-bench-venv/bin/python}"
N="${N:-1000000}"
SECS="${SECS:-3}"
TARGET="${CARGO_TARGET_DIR:-target}"

cargo build --release --quiet --bin terrastream --example heights_bench
bench_setup "${BIN:-./target/release/terrastream}"
cp "$TARGET/release/examples/heights_bench" "$tmp/heights_bench"

echo "== machine: $(nproc) CPUs, $(grep -m1 'model name' /proc/cpuinfo | cut -d: -f2 | xargs), $(date -u +%FT%TZ)"
"$PY" bench/heights_vs_rasterio.py points "$DEM" "$tmp" "$N"
"$bin" bake "$DEM" --out "$tmp/store/m" --levels 1 --gpu off -q
echo "== in-process (one thread)"
"$tmp/heights_bench" "$DEM" "$tmp/store/m" "$tmp/wgs84.f64" "$SECS" | tee "$tmp/inproc.txt"

port="$(free_port)"
"$bin" serve --store "$tmp/store" --bind "127.0.0.1:$port" --source "d=$DEM" >"$tmp/serve.log" 2>&1 &
pids+=($!)
for _ in $(seq 100); do curl -sf "http://127.0.0.1:$port/tilesets/d" >/dev/null && break; sleep 0.2; done
echo "== over HTTP (one keep-alive connection, Python http.client, sequential requests)"
"$PY" bench/heights_vs_rasterio.py http "http://127.0.0.1:$port" "$tmp" "$SECS"
echo "== rasterio $("$PY" -c 'import rasterio; print(rasterio.__version__, "GDAL", rasterio.__gdal_version__)')"
"$PY" bench/heights_vs_rasterio.py rasterio "$DEM" "$tmp" "$SECS"
echo
"$PY" bench/heights_vs_rasterio.py table "$tmp"
