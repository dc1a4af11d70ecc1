#!/usr/bin/env bash
# Bake throughput with and without reprojection and warping, and gdalwarp warping the same
# mosaic to the same grid, side by side in one run (issue 36).
#
#   bench/warp_vs_gdalwarp.sh [BIN] [SIDE]
#
# Generates three adjacent SIDE×SIDE float32 GeoTIFFs of 30 m cells along 48° N: once all in
# EPSG:32632 ("one CRS"), once without any CRS ("local"), once one per UTM zone 31/32/33
# ("three zones", warped onto EPSG:32631 — terrastream's default: the first file's CRS and cells).
# Times: terrastream bake of each; terrastream export to 3D Tiles of the local and the one-CRS
# bakes (the second places every vertex through the CRS and the geoid); gdalwarp of the
# three-zone mosaic to EPSG:32631 at 30 m, bilinear (GDAL 3.6, Debian's gdal-bin).
set -euo pipefail
cd "$(dirname "$0")/.."
BIN="${1:-target/release/terrastream}"
SIDE="${2:-1500}"
PY="${PYTHON:-$HOME/.cache/terrastream-ci-venv/bin/python}"
W="$(mktemp -d)"
trap 'rm -rf "$W"' EXIT
"$PY" - "$W" "$SIDE" <<'PYEOF'
import sys, numpy as np, rasterio
from rasterio.transform import from_origin
from pyproj import Transformer
out, side = sys.argv[1], int(sys.argv[2])
cell = 30.0
def relief(x, y):
    return (400 + 300 * np.sin(x / 4000.0) * np.cos(y / 5000.0) + 50 * np.sin(x / 700.0 + y / 900.0)).astype("float32")
def write(path, crs, x0, y0):
    cols = np.arange(side) * cell + x0 + cell / 2
    rows = y0 - cell / 2 - np.arange(side) * cell
    X, Y = np.meshgrid(cols, rows)
    with rasterio.open(path, "w", driver="GTiff", width=side, height=side, count=1, dtype="float32",
                       crs=crs, transform=from_origin(x0, y0, cell, cell), tiled=True,
                       blockxsize=256, blockysize=256) as d:
        d.write(relief(X, Y), 1)
# One CRS / local: three files side by side in EPSG:32632 around 9° E, 48° N.
t = Transformer.from_crs(4326, 32632, always_xy=True)
x, y = t.transform(9.0, 48.0)
x0, y0 = round(x / cell) * cell, round(y / cell) * cell
for k in range(3):
    write(f"{out}/one_{k}.tif", "EPSG:32632", x0 + k * (side - 1) * cell, y0)
    write(f"{out}/local_{k}.tif", None, x0 + k * (side - 1) * cell, y0)
# Three zones: file k in zone 31+k, placed k·(side−1)·30 m east of the first on the ground.
t31 = Transformer.from_crs(32632, 4326, always_xy=True)
for k, zone in enumerate((31, 32, 33)):
    lon, lat = t31.transform(x0 + k * (side - 1) * cell, y0)
    tz = Transformer.from_crs(4326, 32600 + zone, always_xy=True)
    zx, zy = tz.transform(lon, lat)
    write(f"{out}/zone_{zone}.tif", f"EPSG:{32600 + zone}", round(zx / cell) * cell, round(zy / cell) * cell)
PYEOF
samples=$((3 * SIDE * SIDE))
run() { # label, command...
  local label="$1"; shift
  local t0 t1
  t0=$(date +%s.%N)
  /usr/bin/time -f '%M' -o "$W/rss" "$@" > "$W/log" 2>&1 || { echo "$label: FAILED"; tail -5 "$W/log"; exit 1; }
  t1=$(date +%s.%N)
  python3 -c "import sys; s=float(sys.argv[2])-float(sys.argv[1]); print(f'{sys.argv[3]:<44} {s:8.2f} s  {int(sys.argv[4])/s/1e6:6.2f} M samples/s  peak RSS {int(sys.argv[5])/1024:6.0f} MiB')" "$t0" "$t1" "$label" "$samples" "$(tail -1 "$W/rss")"
}
echo "inputs: 3 × ${SIDE}² float32 GeoTIFFs, 30 m cells ($samples samples); $(nproc) cores; $(gdalwarp --version)"
run "terrastream bake, local frame (no CRS)" "$BIN" bake --quiet --gpu off --levels 1 --out "$W/b-local" "$W"/local_*.tif
run "terrastream bake, one CRS (EPSG:32632)" "$BIN" bake --quiet --gpu off --levels 1 --out "$W/b-one" "$W"/one_*.tif
run "terrastream bake, three UTM zones (warped)" "$BIN" bake --quiet --gpu off --levels 1 --out "$W/b-zones" "$W"/zone_31.tif "$W"/zone_32.tif "$W"/zone_33.tif
run "gdalwarp three zones → EPSG:32631, bilinear" gdalwarp -q -overwrite -t_srs EPSG:32631 -tr 30 30 -r bilinear -co TILED=YES "$W"/zone_31.tif "$W"/zone_32.tif "$W"/zone_33.tif "$W/gdalwarp.tif"
run "terrastream export 3D Tiles, local frame" "$BIN" export --quiet --format 3dtiles --out "$W/t-local" "$W/b-local"
run "terrastream export 3D Tiles, placed (CRS)" "$BIN" export --quiet --format 3dtiles --out "$W/t-one" "$W/b-one"
