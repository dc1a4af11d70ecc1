#!/usr/bin/env bash
# Quantized-mesh terrain: terrastream against the Python pipeline closest to CTOD's (rasterio +
# pydelatin + quantized-mesh-encoder, bench/qmesh_vs_python.py), on the same DEM and the same
# geodetic tiles, same machine, same run (issue 37).
#
#   bench/qmesh_vs_python.sh DEM [qmesh_vs_python.py options: --zooms A:B --error-scale S --sampler warp|numpy]
#
# 1. Makes the virtual environment $VENV (default ~/.cache/terrastream-bench-venv) from
#    bench/requirements-qmesh.txt if it is missing.
# 2. Builds every tile with the Python pipeline, serially, each stage timed (its JSON summary).
# 3. Bakes the same DEM with `terrastream bake DEM --out W/ts --terrain $TS_BAKE_ARGS` on one
#    thread (RAYON_NUM_THREADS=1, serial like Python) and reads W/ts/terrain/stats.json
#    (`tiles`, `seconds`, `bytes_raw`, `bytes_gzip`, `per_zoom`: {z: {tiles, mean_vertices,
#    max_error}}). A binary without `bake --terrain` gets a clear message and an empty column.
#    Zoom limits and error scale are not passed to the Rust side: give them in TS_BAKE_ARGS
#    (--terrain-max-zoom, --terrain-error-scale); tile counts that differ are flagged.
# 4. Prints both side by side: per zoom and overall, tiles, ms per tile, tiles/s, bytes raw and
#    gzipped per tile, vertices per tile, measured max error.
# 5. On-demand latency from a cold server: `terrastream serve --source od=DEM`, every tile the
#    Python side built requested once (each built on request), p50/p99 per zoom.
#
# Env: BIN (default ./target/release/terrastream, built if missing), VENV, TS_BAKE_ARGS, KEEP=1
# (keep the work folder).
set -euo pipefail
cd "$(dirname "$0")/.."
[ "$#" -ge 1 ] || { sed -n '2,25p' "$0"; exit 2; }
DEM="$(realpath "$1")"; shift
[ -f "$DEM" ] || { echo "no such DEM: $DEM" >&2; exit 2; }
BIN="${BIN:-./target/release/terrastream}"
VENV="${VENV:-$HOME/.cache/terrastream-bench-venv}"
PY="$VENV/bin/python"

if ! { [ -x "$PY" ] && "$PY" -c 'import numpy, rasterio, pyproj, pydelatin, quantized_mesh_encoder' 2>/dev/null; }; then
    echo "making $VENV (bench/requirements-qmesh.txt)"
    python3 -m venv "$VENV"
    "$VENV/bin/pip" install -q -r bench/requirements-qmesh.txt
fi

source bench/lib.sh
rust_note=""
if [ -x "$BIN" ] || [ "$BIN" = ./target/release/terrastream ]; then
    bench_setup "$BIN"
else
    bench_setup
    bin=""
    rust_note="no terrastream binary at $BIN: Rust column empty"
fi

echo "machine: $(nproc) cores, load $(cut -d' ' -f1-3 /proc/loadavg); DEM: $DEM"
echo "== Python: rasterio + pydelatin + quantized-mesh-encoder, serial"
"$PY" bench/qmesh_vs_python.py "$DEM" --out "$tmp/py" "$@" >"$tmp/py.json"

echo "== terrastream bake --terrain, RAYON_NUM_THREADS=1"
t0=$(date +%s.%N)
if [ -n "$rust_note" ]; then
    :
elif ! "$bin" bake --help 2>/dev/null | grep -q -- '--terrain'; then
    rust_note="this terrastream binary ($BIN) has no 'bake --terrain' (issue 37 not built yet): Rust column empty"
elif ! RAYON_NUM_THREADS=1 "$bin" bake "$DEM" --out "$tmp/ts" --terrain ${TS_BAKE_ARGS:-} >"$tmp/ts.log" 2>&1; then
    rust_note="terrastream bake --terrain failed: $(tail -3 "$tmp/ts.log" | tr '\n' ' ')"
elif [ ! -f "$tmp/ts/terrain/stats.json" ]; then
    rust_note="terrastream bake --terrain wrote no $tmp/ts/terrain/stats.json: Rust column empty"
else
    t1=$(date +%s.%N)
    echo "wall $(awk -v a="$t0" -v b="$t1" 'BEGIN { printf "%.3f", b - a }') s (process, including start-up)"
fi
[ -z "$rust_note" ] || echo "!! $rust_note"

"$PY" - "$tmp/py.json" "$tmp/ts/terrain/stats.json" <<'PYEOF'
import json, os, sys
py = json.load(open(sys.argv[1]))
ts = json.load(open(sys.argv[2])) if os.path.exists(sys.argv[2]) else None
if ts and ts.get("per_zoom"):
    zs = [z for z in ts["per_zoom"].values() if z.get("tiles")]
    n = sum(z["tiles"] for z in zs)
    if "mean_vertices" not in ts and n and all("mean_vertices" in z for z in zs):
        ts["mean_vertices"] = sum(z["tiles"] * z["mean_vertices"] for z in zs) / n
    if "max_error" not in ts and zs and all("max_error" in z for z in zs):
        ts["max_error"] = max(z["max_error"] for z in zs)

def f(v, fmt):
    return "-" if v is None else format(v, fmt)

def per_tile(total, tiles):
    return total / tiles if (total is not None and tiles) else None

def row(label, p, t, p_sec=None, t_sec=None):
    """p, t: dicts with tiles, bytes_raw, bytes_gzip, mean_vertices, max_error (t may be None or partial)."""
    t = t or {}
    pt, tt = p.get("tiles"), t.get("tiles")
    p_ms = p.get("ms_mean") if p_sec is None else 1e3 * per_tile(p_sec, pt)
    t_ms = 1e3 * per_tile(t_sec, tt) if (t_sec is not None and tt) else None
    cols = [label,
            f(pt, "d"), f(tt, "d"),
            f(p_ms, ".3f"), f(t_ms, ".3f"),
            f(1e3 / p_ms if p_ms else None, ".0f"), f(1e3 / t_ms if t_ms else None, ".0f"),
            f(p_ms / t_ms if (p_ms and t_ms) else None, ".1f"),
            f(per_tile(p.get("bytes_raw"), pt), ".0f"), f(per_tile(t.get("bytes_raw"), tt), ".0f"),
            f(per_tile(p.get("bytes_gzip"), pt), ".0f"), f(per_tile(t.get("bytes_gzip"), tt), ".0f"),
            f(p.get("mean_vertices"), ".1f"), f(t.get("mean_vertices"), ".1f"),
            f(p.get("max_error"), ".2f"), f(t.get("max_error"), ".2f")]
    flag = "  <- tile counts differ" if (tt is not None and tt != pt) else ""
    print("{:>6} {:>6} {:>6} | {:>8} {:>8} | {:>7} {:>7} {:>6} | {:>7} {:>7} | {:>7} {:>7} | {:>7} {:>7} | {:>8} {:>8}".format(*cols) + flag)

v = py.get("versions", {})
print(f"\nPython: {py['sampler']} sampler, zooms {py['zooms'][0]}..{py['zooms'][1]}, error scale {py['error_scale']}, "
      f"pydelatin {v.get('pydelatin')}, quantized-mesh-encoder {v.get('quantized-mesh-encoder')}, "
      f"rasterio {v.get('rasterio')} (GDAL {v.get('gdal')}), numpy {v.get('numpy')}")
print(f"Python stage means (ms/tile): " + ", ".join(f"{k} {x:.3f}" for k, x in py["stage_ms_mean"].items())
      + f"; p50 {py['ms_p50']:.3f}, p99 {py['ms_p99']:.3f}; writes {py['seconds_write']:.3f} s")
print("ms per tile: Python = mean of its timed stages per zoom, overall = (stages + writes) / tiles; "
      "terrastream = stats.json build seconds / tiles (read + sample + TIN + encode, one thread, no write)\n"
      "bytes: both without extensions (what quantized-mesh-encoder makes)\n")
print("{:>6} {:>6} {:>6} | {:>8} {:>8} | {:>7} {:>7} {:>6} | {:>7} {:>7} | {:>7} {:>7} | {:>7} {:>7} | {:>8} {:>8}".format(
    "zoom", "tiles", "", "ms/tile", "", "tiles/s", "", "py/ts", "raw B", "", "gzip B", "", "verts", "", "max err", ""))
print("{:>6} {:>6} {:>6} | {:>8} {:>8} | {:>7} {:>7} {:>6} | {:>7} {:>7} | {:>7} {:>7} | {:>7} {:>7} | {:>8} {:>8}".format(
    "", "py", "ts", "py", "ts", "py", "ts", "time", "py", "ts", "py", "ts", "py", "ts", "py m", "ts m"))
tz = (ts or {}).get("per_zoom", {})
for z, p in py["per_zoom"].items():
    t = tz.get(z) or tz.get(int(z)) if isinstance(tz, dict) else None
    row(f"z{z}", p, t, None, (t or {}).get("seconds"))
row("all", py, ts, py["seconds"], (ts or {}).get("build_seconds", (ts or {}).get("seconds")))
if ts:
    print(f"\nterrastream: build {1e3 * ts['build_seconds'] / ts['tiles']:.3f} ms/tile (p50 {ts['ms_p50']:.3f}, p99 {ts['ms_p99']:.3f}); "
          f"baked (one thread, each tile written durably: fsync) {ts['tiles'] / ts['seconds']:.0f} tiles/s; "
          f"with every extension {ts['bytes_raw_all'] / ts['tiles']:.0f} B raw, {ts['bytes_gzip_all'] / ts['tiles']:.0f} B gzipped per tile")
extra = set(map(str, tz)) - set(py["per_zoom"])
if extra:
    print(f"terrastream built zooms Python did not: {sorted(extra, key=int)}")
print("\npy/ts time > 1: terrastream faster (issue 37's bar: >= 10x); bytes: terrastream no larger at the same error")
PYEOF

# On-demand latency, per zoom, from a cold server.
ondemand_latency() {
    [ -n "$bin" ] && [ -f "$tmp/py/python_tiles.jsonl" ] || return 0
    local port name=od
    port=$(free_port)
    mkdir -p "$tmp/store"
    "$bin" serve --store "$tmp/store" --bind "127.0.0.1:$port" --source "$name=$DEM" >"$tmp/serve.log" 2>&1 &
    pids+=($!)
    for _ in $(seq 300); do curl -fs -o /dev/null "http://127.0.0.1:$port/readyz" && break; sleep 0.1; done
    echo "== on-demand latency: terrastream serve --source, each tile once, cold (built on request), one client"
    "$PY" bench/qmesh_vs_python.py latency --base-url "http://127.0.0.1:$port/tilesets/$name/terrain/" \
        --urls "$tmp/py/python_tiles.jsonl" >"$tmp/latency.json"
    "$PY" - "$tmp/latency.json" "$tmp/py.json" <<'PYEOF'
import json, sys
lat, py = json.load(open(sys.argv[1])), json.load(open(sys.argv[2]))
print("{:>6} {:>6} {:>9} {:>9} {:>9} | {:>12}".format("zoom", "tiles", "p50 ms", "p99 ms", "failed", "python ms"))
for z, v in sorted(lat["per_zoom"].items(), key=lambda kv: int(kv[0])):
    p = py["per_zoom"].get(str(z), {})
    print("{:>6} {:>6} {:>9.2f} {:>9.2f} {:>9} | {:>12.3f}".format(
        f"z{z}", v["requests"], v["ms_p50"] or 0, v["ms_p99"] or 0, v["failures"], p.get("ms_mean", float("nan"))))
print(f"all: {lat['requests']} requests, p50 {lat['ms_p50'] or 0:.2f} ms, p99 {lat['ms_p99'] or 0:.2f} ms, {lat['failures']} failed")
PYEOF
}
ondemand_latency
