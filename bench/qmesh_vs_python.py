#!/usr/bin/env python3
"""Quantized-mesh anchor: the Python pipeline closest to CTOD's (rasterio + pydelatin +
quantized-mesh-encoder), building the same geodetic tiles as `terrastream bake --terrain`, one
tile after another, each stage timed (issue 37).

    bench/qmesh_vs_python.py DEM --out DIR [--zooms A:B] [--error-scale S] [--sampler warp|numpy]
    bench/qmesh_vs_python.py latency --base-url URL --urls URLS.json [--limit-per-zoom N]

Tiling (the same rule as the Rust side):
- global geodetic TMS grid, EPSG:4326, two root tiles at z0: at zoom z, 2^(z+1) × 2^z tiles of
  180/2^z degrees; tile (z, x, y) has west = -180 + x·180/2^z, south = -90 + y·180/2^z (y from the
  south);
- a tile is 65 × 65 sample points: sample (i, j) at lon = -180 + (64x + i)·180/(64·2^z),
  lat = -90 + (64y + j)·180/(64·2^z), j = 0 on the south edge;
- heights: the DEM bilinearly at that point (lon/lat carried to the DEM's CRS by pyproj,
  always_xy), plus the EGM96 undulation (bilinear on /usr/share/proj/egm96_15.gtx, longitudes
  wrapping) unless --vertical-datum ellipsoid; points outside the DEM are sea level (0 + N);
- tiles: every tile of z in [A, B] whose rectangle overlaps the DEM's geographic bounding box (the
  DEM's cell-edge extent through rasterio.warp.transform_bounds, 21 points per edge), plus the
  other root tile at z0; B defaults to the smallest z whose tile cell 180/(64·2^z)° is at most the
  DEM's cell (the smaller of its two steps; metres / 111320 for projected CRSs);
- error bound e(z) = error_scale · 77067.34 / 2^z m (CesiumJS's level-0 geometric error for
  65-sample heightmaps on two root tiles, 6378137·2π·0.25 / (65·2), halved per zoom).

Samplers (--sampler):
- warp (default, CTOD-like): per tile, rasterio.warp.reproject of the DEM band into a 65 × 65
  EPSG:4326 destination whose pixel centres are the sample points (origin west - cell/2,
  north + cell/2), Resampling.bilinear, XSCALE=YSCALE=1 so GDAL interpolates at the point instead
  of widening its kernel when the tile is coarser than the DEM (without it, 111 m off at z9 on
  utm32n_vinschgau.tif); GDAL decides the DEM's edge (it gives values in the outer half cell).
  rasterio's reproject always uses GDAL's approximate transformer (0.125 source pixels): against
  exact point bilinear, p50 0.14 m, max 1.4 m at z11 and up to 21 m at z9 on the Alpine DEM.
- numpy: terrastream's rule in src/raster/warp.rs, done with numpy: a point is inside only between
  the outermost sample centres; the four samples around it, no-data left out and the others'
  weights renormalised; the window read with rasterio. Equal (0.0 m) to
  `gdalwarp -et 0 -wo XSCALE=1 -wo YSCALE=1 -r bilinear` on the same 65 × 65 grid.

Per tile: Delatin(heights, max_error=e(z)); quantized_mesh_encoder.encode(positions, triangles,
bounds = the tile rectangle, ellipsoid WGS84, defaults otherwise: header bounding sphere = the
smaller of its 'naive' and 'ritter' spheres, horizon occlusion point computed, no extensions, so
no normals, watermask or metadata); gzip level 6 (mtime 0). Written to DIR/{z}/{x}/{y}.terrain,
gzipped; one JSON line per tile in DIR/python_tiles.jsonl; one JSON summary line on stdout.

Timed per tile with time.perf_counter: sample (read + warp), geoid, delatin, encode, gzip; a
tile's time is their sum. File writes are timed apart (seconds_write); the error measurement
(max |mesh - samples| over the 65 × 65 grid, barycentric on pydelatin's own vertices and
triangles) is not timed.

The encoder casts positions to float32 before quantizing: a vertex on the east or north edge whose
float32 longitude or latitude rounds inward gets u or v 32766 and drops out of the edge lists
(a crack/skirt gap in the client). Counted per zoom as edge_vertices_dropped (0 up to z18, where
tile edges are exact in float32). The encoder writes pydelatin's vertex order as it is: its
high-water-mark index codes are then valid only modulo 2^16 (as CesiumJS's typed arrays read them),
not small, which costs gzip bytes.

Latency mode: each URL once, in order, one request per connection (urllib), Accept-Encoding gzip;
bytes are as sent on the wire; failures (non-200, connection errors) are counted, not timed.
"""
import argparse
import gzip
import io
import json
import math
import os
import sys
import time
import urllib.error
import urllib.request

import numpy as np

GRID = 65
CELLS = GRID - 1
# CesiumJS: Ellipsoid.maximumRadius · 2π · 0.25 / (heightmap width 65 · level-zero tiles in x 2).
LEVEL0_ERROR_M = 6378137.0 * 2.0 * math.pi * 0.25 / (65 * 2)
METRES_PER_DEGREE = 111320.0
GEOID_GTX = "/usr/share/proj/egm96_15.gtx"
GZIP_LEVEL = 6
STAGES = ("sample", "geoid", "delatin", "encode", "gzip")
QM_MAX = 32767
ACCEPT = "application/vnd.quantized-mesh,application/octet-stream;q=0.9"


class Geoid:
    """A GTX geoid grid, interpolated as terrastream's crs::geoid does (bilinear, wrapping)."""

    def __init__(self, path):
        head = np.fromfile(path, dtype=">f8", count=4)
        rows, cols = (int(v) for v in np.fromfile(path, dtype=">i4", count=2, offset=32))
        self.lat0, self.lon0, self.dlat, self.dlon = (float(v) for v in head)
        if self.lon0 >= 180.0:
            self.lon0 -= 360.0
        v = np.fromfile(path, dtype=">f4", offset=40).astype(np.float64)
        if v.size != rows * cols:
            raise SystemExit(f"{path}: {v.size} values, a {rows}×{cols} grid needs {rows * cols}")
        v[np.abs(v + 88.8888) < 1e-3] = np.nan
        self.values = v.reshape(rows, cols)
        self.rows, self.cols = rows, cols
        self.wraps = abs(cols * self.dlon - 360.0) < self.dlon * 1e-6

    def undulation(self, lon, lat):
        fr = np.clip((lat - self.lat0) / self.dlat, 0.0, self.rows - 1)
        fc = (lon - self.lon0) / self.dlon
        fc = np.mod(fc, self.cols) if self.wraps else np.clip(fc, 0.0, self.cols - 1)
        r0 = np.floor(fr).astype(np.int64)
        c0 = np.floor(fc).astype(np.int64)
        tr, tc = fr - r0, fc - c0
        r1 = np.minimum(r0 + 1, self.rows - 1)
        c1 = (c0 + 1) % self.cols if self.wraps else np.minimum(c0 + 1, self.cols - 1)
        g = self.values
        south = g[r0, c0] * (1 - tc) + g[r0, c1] * tc
        north = g[r1, c0] * (1 - tc) + g[r1, c1] * tc
        return south * (1 - tr) + north * tr


class Dem:
    """The source DEM: its CRS, geographic bounding box, cell size and the two samplers."""

    def __init__(self, path):
        import rasterio
        from pyproj import CRS, Transformer
        from rasterio.warp import transform_bounds

        self.path = path
        self.ds = rasterio.open(path)
        if self.ds.crs is None:
            raise SystemExit(f"{path}: no CRS; a globe tiling needs one")
        t = self.ds.transform
        if t.b != 0 or t.d != 0:
            raise SystemExit(f"{path}: rotated geotransform {tuple(t)[:6]} is not supported")
        self.crs = CRS.from_user_input(self.ds.crs.to_wkt())
        self.geographic = self.crs.is_geographic
        self.to_src = Transformer.from_crs("EPSG:4326", self.crs, always_xy=True)
        w, s, e, n = transform_bounds(self.ds.crs, "EPSG:4326", *self.ds.bounds, densify_pts=21)
        self.bbox = (max(w, -180.0), max(s, -90.0), min(e, 180.0), min(n, 90.0))
        step = min(abs(t.a), abs(t.e))
        self.cell_deg = step if self.geographic else step / METRES_PER_DEGREE
        # Sample (0, 0)'s centre and the steps (rasterio has already moved PixelIsPoint rasters'
        # transforms to cell corners).
        self.x0, self.y0 = t.c + t.a / 2, t.f + t.e / 2
        self.dx, self.dy = t.a, t.e
        self.width, self.height = self.ds.width, self.ds.height
        self.nodata = self.ds.nodata
        # Geographic reach for the numpy sampler: the bbox widened by two cells, as warp.rs does.
        pad = 2 * self.cell_deg
        self.reach = (self.bbox[0] - pad, self.bbox[1] - pad, self.bbox[2] + pad, self.bbox[3] + pad)

    def sample_warp(self, west, north, step):
        """rasterio.warp.reproject into 65 × 65 pixels centred on the sample points; NaN outside.
        Row 0 is the north edge."""
        import rasterio
        from rasterio.transform import Affine
        from rasterio.warp import Resampling, reproject

        dst = np.full((GRID, GRID), np.nan, dtype=np.float32)
        reproject(
            source=rasterio.band(self.ds, 1),
            destination=dst,
            src_nodata=self.nodata,
            dst_transform=Affine(step, 0.0, west - step / 2, 0.0, -step, north + step / 2),
            dst_crs="EPSG:4326",
            dst_nodata=np.nan,
            resampling=Resampling.bilinear,
            XSCALE=1,
            YSCALE=1,
        )
        return dst.astype(np.float64)

    def sample_numpy(self, lon, lat):
        """terrastream's warp.rs rule at the points (lon, lat) (2-D arrays); NaN outside."""
        from rasterio.windows import Window

        out = np.full(lon.shape, np.nan)
        rw, rs, re, rn = self.reach
        near = (lon >= rw) & (lon <= re) & (lat >= rs) & (lat <= rn)
        if not near.any():
            return out
        sx, sy = self.to_src.transform(lon[near], lat[near])
        sx, sy = np.asarray(sx, dtype=np.float64), np.asarray(sy, dtype=np.float64)
        fc = (sx - self.x0) / self.dx
        fr = (sy - self.y0) / self.dy
        if self.geographic:
            # A longitude a turn away from the raster's columns (rasters past ±180°).
            for turn in (-360.0, 360.0):
                alt = (sx + turn - self.x0) / self.dx
                better = (fc < 0) | (fc > self.width - 1)
                better &= (alt >= 0) & (alt <= self.width - 1)
                fc = np.where(better, alt, fc)
        eps = 1e-9
        ok = np.isfinite(fc) & np.isfinite(fr)
        ok &= (fc >= -eps) & (fc <= self.width - 1 + eps) & (fr >= -eps) & (fr <= self.height - 1 + eps)
        if not ok.any():
            return out
        fc = np.clip(fc[ok], 0.0, self.width - 1)
        fr = np.clip(fr[ok], 0.0, self.height - 1)
        c0, r0 = np.floor(fc).astype(np.int64), np.floor(fr).astype(np.int64)
        c1, r1 = np.minimum(c0 + 1, self.width - 1), np.minimum(r0 + 1, self.height - 1)
        wc0, wr0 = int(c0.min()), int(r0.min())
        win = Window(wc0, wr0, int(c1.max()) - wc0 + 1, int(r1.max()) - wr0 + 1)
        a = self.ds.read(1, window=win).astype(np.float64)
        if self.nodata is not None:
            a[a == np.float64(np.asarray(self.nodata, dtype=self.ds.dtypes[0]))] = np.nan
        tc, tr = fc - c0, fr - r0
        total = np.zeros(fc.shape)
        weight = np.zeros(fc.shape)
        for c, r, w in ((c0, r0, (1 - tc) * (1 - tr)), (c1, r0, tc * (1 - tr)),
                        (c0, r1, (1 - tc) * tr), (c1, r1, tc * tr)):
            v = a[r - wr0, c - wc0]
            use = (w > 1e-12) & np.isfinite(v)
            total += np.where(use, w * np.where(use, v, 0.0), 0.0)
            weight += np.where(use, w, 0.0)
        value = np.where(weight > 1e-12, total / np.where(weight > 1e-12, weight, 1.0), np.nan)
        inner = out[near]
        inner[ok] = value.astype(np.float32)
        out[near] = inner
        return out


def tiles_for(bbox, zooms):
    """(z, x, y) of every tile overlapping bbox at each zoom, z ascending, then y, then x; both
    root tiles at z0."""
    w, s, e, n = bbox
    out = []
    for z in zooms:
        size = 180.0 / 2 ** z
        nx, ny = 2 ** (z + 1), 2 ** z
        if z == 0:
            xs, ys = range(2), range(1)
        else:
            xs = range(max(0, math.floor((w + 180.0) / size)), min(nx, math.ceil((e + 180.0) / size)))
            ys = range(max(0, math.floor((s + 90.0) / size)), min(ny, math.ceil((n + 90.0) / size)))
        out.extend((z, x, y) for y in ys for x in xs)
    return out


def max_zoom(cell_deg):
    z = 0
    while 180.0 / (CELLS * 2 ** z) > cell_deg and z < 30:
        z += 1
    return z


def mesh_error(heights_sn, verts, tris):
    """max |mesh - samples| over the 65 × 65 grid; heights_sn[j, i] with j from the south (as
    pydelatin's y). Barycentric over each triangle's bounding box of grid points."""
    xy = verts[:, :2].astype(np.float64)
    z = verts[:, 2].astype(np.float64)
    a, b, c = xy[tris[:, 0]], xy[tris[:, 1]], xy[tris[:, 2]]
    lo = np.floor(np.minimum(np.minimum(a, b), c)).astype(np.int64)
    hi = np.ceil(np.maximum(np.maximum(a, b), c)).astype(np.int64)
    w = hi[:, 0] - lo[:, 0] + 1
    h = hi[:, 1] - lo[:, 1] + 1
    n = w * h
    t = np.repeat(np.arange(len(tris)), n)
    k = np.arange(n.sum()) - np.repeat(np.cumsum(n) - n, n)
    px = lo[t, 0] + k % w[t]
    py = lo[t, 1] + k // w[t]
    det = (b[t, 1] - c[t, 1]) * (a[t, 0] - c[t, 0]) + (c[t, 0] - b[t, 0]) * (a[t, 1] - c[t, 1])
    l1 = ((b[t, 1] - c[t, 1]) * (px - c[t, 0]) + (c[t, 0] - b[t, 0]) * (py - c[t, 1])) / det
    l2 = ((c[t, 1] - a[t, 1]) * (px - c[t, 0]) + (a[t, 0] - c[t, 0]) * (py - c[t, 1])) / det
    l3 = 1.0 - l1 - l2
    inside = (l1 >= -1e-9) & (l2 >= -1e-9) & (l3 >= -1e-9)
    t, px, py = t[inside], px[inside], py[inside]
    zi = l1[inside] * z[tris[t, 0]] + l2[inside] * z[tris[t, 1]] + l3[inside] * z[tris[t, 2]]
    covered = np.zeros((GRID, GRID), dtype=bool)
    covered[py, px] = True
    if not covered.all():
        return float("inf")
    return float(np.abs(zi - heights_sn[py, px]).max())


def dropped_edge_vertices(positions, grid_xy, bounds):
    """Vertices on the tile's east/north edge (pydelatin x or y = 64) or west/south (= 0) that the
    encoder leaves out of its edge lists (its u/v from float32 positions, as encode computes)."""
    minx, miny, maxx, maxy = bounds
    u = np.interp(positions[:, 0].astype(np.float32), (minx, maxx), (0, QM_MAX)).astype(np.int16)
    v = np.interp(positions[:, 1].astype(np.float32), (miny, maxy), (0, QM_MAX)).astype(np.int16)
    gx, gy = grid_xy[:, 0], grid_xy[:, 1]
    return int(((gx == 0) & (u != 0)).sum() + ((gx == CELLS) & (u != QM_MAX)).sum()
               + ((gy == 0) & (v != 0)).sum() + ((gy == CELLS) & (v != QM_MAX)).sum())


def pct(values, q):
    return float(np.percentile(np.asarray(values), q)) if len(values) else None


def ms_stats(seconds):
    return {"ms_mean": 1e3 * float(np.mean(seconds)), "ms_p50": 1e3 * pct(seconds, 50),
            "ms_p99": 1e3 * pct(seconds, 99)}


def build(args):
    from pydelatin import Delatin
    import quantized_mesh_encoder as qme

    t_wall = time.perf_counter()
    dem = Dem(args.dem)
    geoid = Geoid(args.geoid) if args.vertical_datum == "egm96" else None
    zmax_auto = max_zoom(dem.cell_deg)
    if args.zooms:
        a, _, b = args.zooms.partition(":")
        zooms = range(int(a), int(b or a) + 1)
    else:
        zooms = range(0, zmax_auto + 1)
    tiles = tiles_for(dem.bbox, zooms)
    seconds_setup = time.perf_counter() - t_wall
    print(f"{os.path.basename(args.dem)}: bbox {tuple(round(v, 6) for v in dem.bbox)}, cell "
          f"{dem.cell_deg:.6g}°, zmax {zmax_auto}; building {len(tiles)} tiles at z{zooms.start}..z{zooms.stop - 1}"
          f" ({args.sampler} sampler)", file=sys.stderr)

    os.makedirs(args.out, exist_ok=True)
    log = open(os.path.join(args.out, "python_tiles.jsonl"), "w")
    per = {}
    seconds_write = 0.0
    done_at = time.perf_counter()
    for n_done, (z, x, y) in enumerate(tiles):
        step = 180.0 / (CELLS * 2 ** z)
        west, south = -180.0 + x * 180.0 / 2 ** z, -90.0 + y * 180.0 / 2 ** z
        east, north = -180.0 + (x + 1) * 180.0 / 2 ** z, -90.0 + (y + 1) * 180.0 / 2 ** z
        err_bound = args.error_scale * LEVEL0_ERROR_M / 2 ** z
        t = {}

        t0 = time.perf_counter()
        # Row 0 is the north edge (row r holds j = 64 - r), as pydelatin reads it (its y = 64 - row).
        ii = np.arange(GRID)
        lon = -180.0 + (x * CELLS + ii) * step
        lat = -90.0 + (y * CELLS + (CELLS - ii)) * step
        if args.sampler == "warp":
            h = dem.sample_warp(west, north, step)
        else:
            h = dem.sample_numpy(*np.meshgrid(lon, lat))
        h = np.where(np.isfinite(h), h, 0.0)  # outside the DEM: sea level
        t1 = time.perf_counter()
        if geoid is not None:
            lon2, lat2 = np.meshgrid(lon, lat)
            h = h + geoid.undulation(lon2, lat2)
        heights = h.astype(np.float32)
        t2 = time.perf_counter()
        d = Delatin(heights, width=GRID, height=GRID, max_error=err_bound)
        verts, tris = d.vertices, d.triangles
        t3 = time.perf_counter()
        positions = np.empty((len(verts), 3), dtype=np.float64)
        positions[:, 0] = -180.0 + (x * CELLS + verts[:, 0].astype(np.float64)) * step
        positions[:, 1] = -90.0 + (y * CELLS + verts[:, 1].astype(np.float64)) * step
        positions[:, 2] = verts[:, 2]
        buf = io.BytesIO()
        qme.encode(buf, positions, tris, bounds=(west, south, east, north), ellipsoid=qme.WGS84)
        raw = buf.getvalue()
        t4 = time.perf_counter()
        gz = gzip.compress(raw, compresslevel=GZIP_LEVEL, mtime=0)
        t5 = time.perf_counter()
        t = dict(zip(STAGES, (t1 - t0, t2 - t1, t3 - t2, t4 - t3, t5 - t4)))

        tw = time.perf_counter()
        d_dir = os.path.join(args.out, str(z), str(x))
        os.makedirs(d_dir, exist_ok=True)
        with open(os.path.join(d_dir, f"{y}.terrain"), "wb") as f:
            f.write(gz)
        seconds_write += time.perf_counter() - tw

        measured = mesh_error(heights[::-1].astype(np.float64), verts, tris)
        dropped = dropped_edge_vertices(positions, verts[:, :2], (west, south, east, north))
        rec = {"z": z, "x": x, "y": y, "vertices": int(len(verts)), "triangles": int(len(tris)),
               "bytes_raw": len(raw), "bytes_gzip": len(gz), "error_bound": err_bound,
               "max_error": measured, "max_error_pydelatin": float(d.error),
               "edge_vertices_dropped": dropped,
               "ms": {k: round(1e3 * v, 4) for k, v in t.items()}}
        log.write(json.dumps(rec) + "\n")
        p = per.setdefault(z, {"recs": [], "t": []})
        p["recs"].append(rec)
        p["t"].append(t)
        if time.perf_counter() - done_at > 10:
            done_at = time.perf_counter()
            print(f"  {n_done + 1}/{len(tiles)} tiles", file=sys.stderr)
    log.close()

    def summarise(recs, ts):
        total = [sum(t.values()) for t in ts]
        out = {"tiles": len(recs)}
        out.update(ms_stats(total))
        out["stage_ms_mean"] = {s: 1e3 * float(np.mean([t[s] for t in ts])) for s in STAGES}
        out["seconds_build"] = float(sum(total))
        out["bytes_raw"] = int(sum(r["bytes_raw"] for r in recs))
        out["bytes_gzip"] = int(sum(r["bytes_gzip"] for r in recs))
        out["mean_vertices"] = float(np.mean([r["vertices"] for r in recs]))
        out["mean_triangles"] = float(np.mean([r["triangles"] for r in recs]))
        out["max_error"] = float(max(r["max_error"] for r in recs))
        out["max_error_pydelatin"] = float(max(r["max_error_pydelatin"] for r in recs))
        out["edge_vertices_dropped"] = int(sum(r["edge_vertices_dropped"] for r in recs))
        out["tiles_with_dropped_edge_vertices"] = int(sum(r["edge_vertices_dropped"] > 0 for r in recs))
        return out

    per_zoom = {}
    for z, p in sorted(per.items()):
        s = summarise(p["recs"], p["t"])
        s["error_bound"] = args.error_scale * LEVEL0_ERROR_M / 2 ** z
        per_zoom[str(z)] = s
    all_recs = [r for p in per.values() for r in p["recs"]]
    all_t = [t for p in per.values() for t in p["t"]]
    summary = {"side": "python", "dem": os.path.abspath(args.dem), "sampler": args.sampler,
               "vertical_datum": args.vertical_datum, "error_scale": args.error_scale,
               "bbox": list(dem.bbox), "dem_cell_deg": dem.cell_deg, "zmax_auto": zmax_auto,
               "zooms": [zooms.start, zooms.stop - 1]}
    summary.update(summarise(all_recs, all_t))
    summary["seconds_write"] = seconds_write
    summary["seconds_setup"] = seconds_setup
    summary["seconds"] = summary["seconds_build"] + seconds_write
    summary["tiles_per_s"] = summary["tiles"] / summary["seconds"] if summary["seconds"] else None
    summary["seconds_wall"] = time.perf_counter() - t_wall
    summary["per_zoom"] = per_zoom
    summary["versions"] = versions()
    summary["load_avg"] = list(os.getloadavg())
    print(json.dumps(summary))


def versions():
    import importlib.metadata as md
    import rasterio
    out = {"python": sys.version.split()[0], "gdal": rasterio.__gdal_version__}
    for p in ("numpy", "rasterio", "pyproj", "pydelatin", "quantized-mesh-encoder"):
        try:
            out[p] = md.version(p)
        except md.PackageNotFoundError:
            out[p] = None
    return out


def latency(argv):
    """Fetches every tile URL once (cold: each the first request for it), in order, and prints one
    JSON line: per zoom, count, failures, status codes, bytes and p50/p99/mean/max latency in ms
    (time to the last body byte)."""
    ap = argparse.ArgumentParser(prog="qmesh_vs_python.py latency", description=latency.__doc__)
    ap.add_argument("--base-url", required=True, help="prefix of the URLs, e.g. http://127.0.0.1:8080/tilesets/t/terrain/")
    ap.add_argument("--urls", required=True,
                    help='JSON {"z": ["z/x/y.terrain", …]} (paths relative to --base-url, or absolute URLs), '
                         "or a python_tiles.jsonl of a Python build (its tiles)")
    ap.add_argument("--limit-per-zoom", type=int, default=0,
                    help="at most N tiles per zoom, spread evenly over the list (0: all)")
    ap.add_argument("--accept", default=ACCEPT)
    ap.add_argument("--timeout", type=float, default=60.0)
    a = ap.parse_args(argv)
    print(json.dumps(fetch_cold(a.base_url, load_urls(a.urls), a.limit_per_zoom, a.accept, a.timeout)))


def load_urls(path):
    if path.endswith(".jsonl"):
        urls = {}
        with open(path) as f:
            for line in f:
                r = json.loads(line)
                urls.setdefault(str(r["z"]), []).append(f"{r['z']}/{r['x']}/{r['y']}.terrain")
        return urls
    with open(path) as f:
        return {str(z): list(v) for z, v in json.load(f).items()}


def fetch_cold(base_url, urls_per_zoom, limit_per_zoom=0, accept=ACCEPT, timeout=60.0):
    base = base_url if base_url.endswith("/") else base_url + "/"
    out = {"side": "latency", "base_url": base_url, "per_zoom": {}}
    all_ms = []
    for z in sorted(urls_per_zoom, key=int):
        urls = urls_per_zoom[z]
        if limit_per_zoom and len(urls) > limit_per_zoom:
            pick = np.linspace(0, len(urls) - 1, limit_per_zoom).round().astype(int)
            urls = [urls[i] for i in sorted(set(pick.tolist()))]
        ms, codes, failures, nbytes = [], {}, 0, 0
        for u in urls:
            url = u if "://" in u else base + u.lstrip("/")
            req = urllib.request.Request(url, headers={"Accept": accept, "Accept-Encoding": "gzip"})
            t0 = time.perf_counter()
            try:
                with urllib.request.urlopen(req, timeout=timeout) as r:
                    body = r.read()
                    code = r.status
            except urllib.error.HTTPError as e:
                body, code = e.read(), e.code
            except (urllib.error.URLError, OSError) as e:
                body, code = b"", type(e).__name__
            dt = 1e3 * (time.perf_counter() - t0)
            codes[str(code)] = codes.get(str(code), 0) + 1
            if code != 200:
                failures += 1
                continue
            ms.append(dt)
            nbytes += len(body)
        all_ms += ms
        out["per_zoom"][z] = {"requests": len(urls), "failures": failures, "status": codes, "bytes": nbytes,
                              "ms_p50": pct(ms, 50), "ms_p99": pct(ms, 99),
                              "ms_mean": float(np.mean(ms)) if ms else None, "ms_max": max(ms) if ms else None}
    out["requests"] = sum(p["requests"] for p in out["per_zoom"].values())
    out["failures"] = sum(p["failures"] for p in out["per_zoom"].values())
    out["ms_p50"], out["ms_p99"] = pct(all_ms, 50), pct(all_ms, 99)
    return out


def main():
    if len(sys.argv) > 1 and sys.argv[1] == "latency":
        return latency(sys.argv[2:])
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("dem", help="source DEM (any GDAL raster with a CRS; heights orthometric unless --vertical-datum ellipsoid)")
    ap.add_argument("--out", required=True, help="output folder: {z}/{x}/{y}.terrain (gzipped), python_tiles.jsonl")
    ap.add_argument("--zooms", help="A:B (inclusive) or Z; default 0:zmax of the DEM's cell size")
    ap.add_argument("--error-scale", type=float, default=1.0, help="e(z) = S · 77067.34 / 2^z m (default 1)")
    ap.add_argument("--sampler", choices=("warp", "numpy"), default="warp",
                    help="warp: rasterio.warp.reproject per tile (CTOD-like, default); numpy: terrastream's warp.rs rule")
    ap.add_argument("--vertical-datum", choices=("egm96", "ellipsoid"), default="egm96",
                    help="what the DEM's heights are measured from (default egm96: add the EGM96 undulation)")
    ap.add_argument("--geoid", default=GEOID_GTX, help=f"GTX geoid grid (default {GEOID_GTX})")
    build(ap.parse_args())


if __name__ == "__main__":
    main()
