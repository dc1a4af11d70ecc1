#!/usr/bin/env python3
"""Independent check of `POST /tilesets/{name}/heights` (issue 38).

    heights_check.py --bin PATH --work DIR [--data DIR] [--only NAME,...] [--mesh NAME,...]

For every GeoTIFF in DATA/geo (default: $TERRASTREAM_DATA or ../shared/data) and two copies
written here with a compound CRS (VerticalCSTypeGeoKey 5773, EGM96 heights): start `PATH serve
--store DIR/store --source d=DEM` on a free 127.0.0.1 port, POST a few hundred seeded WGS 84
points (inside, sample centres, the border half-cell, outside, far away; for geographic DEMs
0-360 longitudes, the antimeridian and the poles) with surface=source, interpolation=bilinear
nearest and cubic, datum=native, ellipsoid and geoid, and compare with heights computed here with no
terrastream code: rasterio reads the samples and the transform, pyproj puts lon/lat in the
DEM's CRS, numpy interpolates at the pixel position (relative to the first sample centre), and
the EGM96 grid (PROJ's egm96_15.gtx, read by check.py's Geoid, checked against PROJ's
vgridshift) gives the undulation where the GeoKeys say the heights are EGM96.

Then `PATH bake DEM --out DIR/store/m` for the --mesh DEMs and surface=mesh is checked at every
raster sample centre: within the answered error (1 + MESH_REL_MARGIN) + MESH_MARGIN_M of the
sample (+ geoid), at the finest depth and the next coarser one.

Tolerances: source heights and error bounds within ABS_TOL_M + |h| * REL_TOL (f32 samples,
f64 arithmetic in a different order and a different projection library). Points within
EDGE_AMBIGUOUS_PX of the no-data edge, or within that of a nearest-neighbour tie, are not held
to one answer. One line per DEM and request, then `heights: N passed, M failed`; exit 1 on any
failure. Failures name the DEM and the point.
"""

import argparse
import json
import os
import shutil
import socket
import struct
import subprocess
import sys
import time
import urllib.error
import urllib.request
import zlib
from pathlib import Path

import numpy as np
import rasterio
from pyproj import CRS, Transformer

sys.path.insert(0, str(Path(__file__).resolve().parent))
from check import GEOID_GTX, Geoid  # noqa: E402  (the placement checker's EGM96 reader)

ABS_TOL_M = 1e-3
REL_TOL = 2.0 ** -23
MESH_MARGIN_M = 0.01
# ... plus this share of the answered error: the bake measures a TIN in f32 on heights lowered by
# the Earth's drop below the node's tangent plane, ~1e6 m on nodes thousands of km wide (a global
# DEM's upper depths), whose f32 steps are decimetres; those nodes' errors are thousands of
# metres, so 1e-5 of it covers the steps (and adds 1e-5 m to a 1 m error).
MESH_REL_MARGIN = 1e-5
# terrastream embeds EGM96 rounded to whole centimetres (src/crs/geoid.rs: "<= 0.5 cm off the
# grid's values"); PROJ's grid is read here unrounded.
GEOID_TOL_M = 0.005
EDGE_AMBIGUOUS_PX = 1e-6
WGS84 = CRS.from_epsg(4326)


class Dem:
    """One raster as rasterio reads it: samples (NaN = no-data), transform, CRS, vertical."""

    def __init__(self, name, path):
        self.name, self.path = name, Path(path)
        with rasterio.open(self.path) as ds:
            crs = CRS.from_wkt(ds.crs.to_wkt())
            self.t = ds.transform
            self.w, self.h = ds.width, ds.height
            a = ds.read(1, masked=True).astype(float)
            self.v = a.filled(np.nan) * ds.scales[0] + ds.offsets[0]
        self.horiz = crs.sub_crs_list[0] if crs.is_compound else crs
        vert = crs.sub_crs_list[1] if crs.is_compound else None
        # The GeoKeys say EGM96 (VerticalCSTypeGeoKey 5773) or nothing (heights taken as they are).
        self.vertical = "egm96" if vert is not None and vert.to_epsg() == 5773 else "ellipsoid"
        if vert is not None and self.vertical != "egm96":
            raise SystemExit(f"{path}: vertical CRS {vert.name} not handled by this checker")
        self.geographic = self.horiz.is_geographic
        self.to_crs = Transformer.from_crs(WGS84, self.horiz, always_xy=True)
        self.to_ll = Transformer.from_crs(self.horiz, WGS84, always_xy=True)
        # Cells per 360 degrees of longitude (geographic rasters may hold a longitude twice).
        self.turn = 360.0 / abs(self.t.a) if self.geographic else None

    def pixel(self, lon, lat):
        """Fractional (col, row) relative to the first sample centre of WGS 84 points."""
        lon = np.asarray(lon, float)
        lon = np.where(lon >= 180.0, lon - 360.0, lon)
        with np.errstate(all="ignore"):
            x, y = self.to_crs.transform(lon, np.asarray(lat, float), errcheck=False)
        inv = ~self.t
        x, y = np.asarray(x, float), np.asarray(y, float)
        col = inv.a * x + inv.b * y + inv.c - 0.5
        row = inv.d * x + inv.e * y + inv.f - 0.5
        return col, row

    def lonlat(self, col, row):
        x = self.t.a * (col + 0.5) + self.t.c
        y = self.t.e * (row + 0.5) + self.t.f
        lon, lat = self.to_ll.transform(x, y)
        return np.asarray(lon, float), np.asarray(lat, float)

    def margin(self, c, r):
        """How far inside the data (in samples) a pixel position is; negative outside."""
        return min(c + 0.5, r + 0.5, self.w - 0.5 - c, self.h - 0.5 - r)

    def at(self, c, r, interp):
        """[(value, error bound), ...] at (c, r), or None when a weighed sample is no-data. A
        position within EDGE_AMBIGUOUS_PX of a sample row or column lies in two 2x2
        neighbourhoods (the error bound is that of either): both are returned."""
        def starts(x):
            k = round(x)
            return [k - 1, k] if abs(x - k) < EDGE_AMBIGUOUS_PX else [int(np.floor(x))]
        out = []
        for c0 in starts(c):
            for r0 in starts(r):
                fx, fy = c - c0, r - r0
                if interp == "cubic":
                    # Keys' cubic convolution (a = -0.5) over the 4x4 samples around the point,
                    # clamped at the raster's edge; written here from the published kernel.
                    cs = [min(max(k, 0), self.w - 1) for k in range(c0 - 1, c0 + 3)]
                    rs = [min(max(k, 0), self.h - 1) for k in range(r0 - 1, r0 + 3)]
                    s = np.array([[self.v[rr, cc] for cc in cs] for rr in rs])
                    if np.isnan(s).any():
                        return None
                    wx, wy = keys_weights(fx), keys_weights(fy)
                    v = float(wy @ s @ wx)
                    out.append((v, max(v - s.min(), s.max() - v)))
                    continue
                cs = [min(max(k, 0), self.w - 1) for k in (c0, c0 + 1)]
                rs = [min(max(k, 0), self.h - 1) for k in (r0, r0 + 1)]
                s = np.array([[self.v[rr, cc] for cc in cs] for rr in rs])
                if np.isnan(s).any():
                    return None
                lo, hi = s.min(), s.max()
                if interp == "nearest":
                    out.append((s[int(fy >= 0.5), int(fx >= 0.5)], hi - lo))
                    continue
                v = (s[0, 0] * (1 - fx) + s[0, 1] * fx) * (1 - fy) + (s[1, 0] * (1 - fx) + s[1, 1] * fx) * fy
                out.append((v, max(v - lo, hi - v)))
        return out

    def candidates(self, c, r):
        """The pixel positions a point may have (a geographic raster may hold it at ±360°)."""
        out = [(c, r)]
        if self.geographic:
            out += [(c + self.turn, r), (c - self.turn, r)]
        return out


def keys_weights(t):
    """Keys (1981) cubic convolution weights, a = -0.5, of the samples at -1, 0, 1, 2 from t."""
    a = -0.5

    def w(x):
        x = abs(x)
        if x <= 1:
            return (a + 2) * x**3 - (a + 3) * x**2 + 1
        if x < 2:
            return a * x**3 - 5 * a * x**2 + 8 * a * x - 4 * a
        return 0.0
    return np.array([w(1 + t), w(t), w(1 - t), w(2 - t)])


def points_for(dem, rng):
    """(lon, lat, kind) of the seeded points asked about, WGS 84."""
    pts = []

    def add_px(cs, rs, kind):
        lon, lat = dem.lonlat(np.asarray(cs, float), np.asarray(rs, float))
        pts.extend((float(a), float(b), kind) for a, b in zip(np.atleast_1d(lon), np.atleast_1d(lat)))

    w, h = dem.w, dem.h
    if dem.geographic:
        lon = rng.uniform(-180, 180, 200)
        lat = rng.uniform(-90, 90, 200)
        lon[::2] = np.mod(lon[::2], 360.0)  # half of them in the 0-360 convention
        pts += [(float(a), float(b), "inside") for a, b in zip(lon, lat)]
        for lo in (-180.0, 180.0, 179.99, -179.99, 180.01, 359.999, 0.0, 360.0):
            for la in (-90.0, -89.95, -60.3, 0.0, 45.7, 89.95, 90.0):
                pts.append((lo, la, "antimeridian/pole"))
        for lo in rng.uniform(-180, 360, 20):
            pts += [(float(lo), 90.0, "pole"), (float(lo), -90.0, "pole"),
                    (float(lo), float(rng.uniform(89.5, 90)), "near pole"),
                    (float(lo), float(rng.uniform(-90, -89.5)), "near pole")]
        # The sample centres themselves.
        add_px(rng.integers(0, w, 30), rng.integers(0, h, 30), "centre")
        return pts
    add_px(rng.uniform(-0.5, w - 0.5, 160), rng.uniform(-0.5, h - 0.5, 160), "inside")
    add_px(rng.integers(0, w, 30), rng.integers(0, h, 30), "centre")
    add_px([0, w - 1, 0, w - 1], [0, 0, h - 1, h - 1], "corner")
    # The border half-cell: just inside (data, clamped) and just outside (no data).
    u = rng.uniform(0.01, 0.45, 20)
    for sign, kind in ((1, "border in"), (-1, "border out")):
        d = -0.5 + sign * u
        along_c, along_r = rng.uniform(0, w - 1, 20), rng.uniform(0, h - 1, 20)
        add_px(d[:5], along_r[:5], kind)
        add_px(w - 1 - d[5:10], along_r[5:10], kind)
        add_px(along_c[10:15], d[10:15], kind)
        add_px(along_c[15:], h - 1 - d[15:], kind)
    # Outside by 1..20 cells.
    k = rng.uniform(1, 20, 20)
    add_px(-k[:10], rng.uniform(0, h - 1, 10), "outside")
    add_px(rng.uniform(0, w - 1, 10), h - 1 + k[10:], "outside")
    return pts


def far_points(dem):
    """Places on the Earth far from a projected DEM (its projection may not reach them)."""
    return [(lo, la, "far") for lo, la in
            ((190.0, 0.0), (-170.0, 50.0), (100.0, -30.0), (0.0, 90.0), (0.0, -90.0), (-80.0, 0.0))]


# ---------------------------------------------------------------------------------------------
# The server


def free_port():
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


class Server:
    def __init__(self, binary, store, sources, log):
        self.port = free_port()
        self.base = f"http://127.0.0.1:{self.port}"
        args = [binary, "serve", "--store", str(store), "--bind", f"127.0.0.1:{self.port}"]
        for name, path in sources:
            args += ["--source", f"{name}={path}"]
        self.log = open(log, "w")
        self.proc = subprocess.Popen(args, stdout=self.log, stderr=subprocess.STDOUT)

    def wait(self, name, timeout=60):
        end = time.time() + timeout
        while time.time() < end:
            if self.proc.poll() is not None:
                raise RuntimeError(f"serve exited with {self.proc.returncode} (see {self.log.name})")
            try:
                with urllib.request.urlopen(f"{self.base}/tilesets/{name}", timeout=5) as r:
                    return json.loads(r.read())
            except (urllib.error.URLError, ConnectionError):
                time.sleep(0.2)
        raise RuntimeError(f"serve did not answer /tilesets/{name} in {timeout} s")

    def post(self, path, points, binary=False):
        if binary:
            body = np.asarray(points, "<f8").tobytes()
            headers = {"Content-Type": "application/octet-stream", "Accept": "application/octet-stream"}
        else:
            body = json.dumps(points).encode()
            headers = {"Content-Type": "application/json"}
        req = urllib.request.Request(self.base + path, data=body, headers=headers, method="POST")
        try:
            with urllib.request.urlopen(req, timeout=300) as r:
                return r.status, r.read()
        except urllib.error.HTTPError as e:
            return e.code, e.read()

    def stop(self):
        self.proc.terminate()
        try:
            self.proc.wait(10)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            self.proc.wait()
        self.log.close()


# ---------------------------------------------------------------------------------------------
# Checks


class Tally:
    def __init__(self):
        self.passed = self.failed = 0

    def row(self, ok, text, problems=()):
        if ok:
            self.passed += 1
        else:
            self.failed += 1
        print(f"{'PASS' if ok else 'FAIL'} {text}")
        for p in list(problems)[:8]:
            print(f"     {p}")
        if len(problems) > 8:
            print(f"     ... and {len(problems) - 8} more")
        sys.stdout.flush()


def tol(h):
    return ABS_TOL_M + abs(h) * REL_TOL


def expect_source(dem, geoid, lon, lat, interp, datum):
    """('nodata' | 'ambiguous' | 'skip' | [(h, err), ...]) for one point."""
    c, r = dem.pixel([lon], [lat])
    c, r = float(c[0]), float(r[0])
    if not (np.isfinite(c) and np.isfinite(r)):
        return "nodata"
    answers, ambiguous = [], False
    for cc, rr in dem.candidates(c, r):
        m = dem.margin(cc, rr)
        if abs(m) < EDGE_AMBIGUOUS_PX:
            ambiguous = True
        if m < 0:
            continue
        if interp == "nearest":
            fx, fy = cc - np.floor(cc), rr - np.floor(rr)
            if abs(fx - 0.5) < EDGE_AMBIGUOUS_PX or abs(fy - 0.5) < EDGE_AMBIGUOUS_PX:
                ambiguous = True
        got = dem.at(cc, rr, interp)
        if got is None:
            return "skip"
        lon_n = lon - 360.0 if lon >= 180.0 else lon
        n = float(geoid.undulation(lon_n, lat))
        for v, e in got:
            ell = v + n if dem.vertical == "egm96" else v
            h = {"native": v, "ellipsoid": ell, "geoid": ell - n}[datum]
            answers.append((h, e))
    if ambiguous:
        return "ambiguous"
    return answers or "nodata"


def check_source(dem, geoid, binary, work, tally, only_interps=("bilinear", "nearest", "cubic")):
    store = work / "store"
    shutil.rmtree(store, ignore_errors=True)
    store.mkdir(parents=True)
    srv = Server(binary, store, [("d", dem.path)], work / f"serve-{dem.name}.log")
    try:
        summary = srv.wait("d")
        served = summary.get("frame", {}).get("vertical")
        want = "egm96" if dem.vertical == "egm96" else "ellipsoid"
        tally.row(served == want, f"{dem.name}: served frame.vertical {served!r}, GeoKeys say {want!r}")
        rng = np.random.default_rng(zlib.crc32(dem.name.encode()))
        pts = points_for(dem, rng)
        coords = [[p[0], p[1]] for p in pts]
        for interp in only_interps:
            for datum in ("native", "ellipsoid", "geoid"):
                q = f"/tilesets/d/heights?surface=source&interpolation={interp}&datum={datum}"
                status, body = srv.post(q, coords)
                label = f"{dem.name}: source {interp} {datum}, {len(pts)} points"
                if status != 200:
                    tally.row(False, f"{label}: HTTP {status}", [body.decode(errors="replace")[:300]])
                    continue
                got = json.loads(body)["heights"]
                problems, n_cmp, n_nodata, n_skip, worst = [], 0, 0, 0, 0.0
                for (lon, lat, kind), a in zip(pts, got):
                    want = expect_source(dem, geoid, lon, lat, interp, datum)
                    where = f"({lon!r}, {lat!r}) [{kind}]"
                    if want in ("ambiguous", "skip"):
                        n_skip += 1
                        continue
                    if want == "nodata":
                        n_nodata += 1
                        if not a["nodata"]:
                            problems.append(f"{where}: expected no data, got h={a['h']}")
                        continue
                    if a["nodata"] or a["h"] is None:
                        problems.append(f"{where}: no data answered, expected h={want[0][0]:.6f}")
                        continue
                    n_cmp += 1
                    geo = GEOID_TOL_M if (datum == "geoid") != (dem.vertical == "egm96") else 0.0
                    # The candidate (±360 degrees, neighbourhood) nearest in height and bound.
                    best = min(want, key=lambda he: (abs(he[0] - a["h"]) > tol(he[0]) + geo,
                                                     abs(he[1] - a["error"]), abs(he[0] - a["h"])))
                    dh, de = abs(a["h"] - best[0]), abs(a["error"] - best[1])
                    worst = max(worst, dh)
                    if dh > tol(best[0]) + geo or de > tol(best[1]):
                        problems.append(f"{where}: h={a['h']!r} err={a['error']!r}, expected "
                                        f"h={float(best[0])!r} err={float(best[1])!r} (|dh|={dh:.3g} m)")
                tally.row(not problems and n_cmp > 0,
                          f"{label}: {n_cmp} compared (max |dh| {worst:.2e} m), {n_nodata} no-data, "
                          f"{n_skip} not held (edge tie / no-data sample)", problems)
                if interp == "bilinear" and datum == "ellipsoid":
                    check_binary(srv, q, coords, got, dem, tally)
        if not dem.geographic:
            far = far_points(dem)
            status, body = srv.post("/tilesets/d/heights?surface=source", [[p[0], p[1]] for p in far])
            if status != 200:
                tally.row(False, f"{dem.name}: far points (expected no data): HTTP {status}",
                          [body.decode(errors="replace")[:300]])
            else:
                bad = [f"({p[0]}, {p[1]}): h={a['h']}" for p, a in zip(far, json.loads(body)["heights"])
                       if not a["nodata"]]
                tally.row(not bad, f"{dem.name}: {len(far)} far points answer no data", bad)
    finally:
        srv.stop()


def check_binary(srv, q, coords, got_json, dem, tally):
    status, body = srv.post(q, coords, binary=True)
    if status != 200 or len(body) != 16 * len(coords):
        tally.row(False, f"{dem.name}: binary body: HTTP {status}, {len(body)} bytes for {len(coords)} points")
        return
    problems = []
    for k, a in enumerate(got_json):
        h, e, flags = struct.unpack_from("<dfI", body, 16 * k)
        nod = bool(flags & 1)
        if nod != a["nodata"] or (not nod and (h != a["h"] or e != np.float32(a["error"]))):
            problems.append(f"{coords[k]}: binary ({h}, {e}, {flags}) vs JSON {a}")
    tally.row(not problems, f"{dem.name}: binary answers identical to JSON ({len(coords)} points)", problems)


def check_mesh(dem, geoid, binary, work, tally):
    store = work / "store"
    shutil.rmtree(store, ignore_errors=True)
    store.mkdir(parents=True)
    cmd = [binary, "bake", str(dem.path), "--out", str(store / "m"), "--tile-size", "64",
           "--levels", "1", "--gpu", "off", "-q"]
    t0 = time.time()
    r = subprocess.run(cmd, capture_output=True, text=True)
    if r.returncode != 0:
        tally.row(False, f"{dem.name}: bake failed: {' '.join(cmd)}", [r.stderr[-500:]])
        return
    print(f"     baked {dem.name} in {time.time() - t0:.1f} s")
    srv = Server(binary, store, [], work / f"serve-mesh-{dem.name}.log")
    try:
        summary = srv.wait("m")
        rows, cols = np.mgrid[0:dem.h, 0:dem.w]
        rows, cols = rows.ravel(), cols.ravel()
        keep = ~np.isnan(dem.v[rows, cols])
        rows, cols = rows[keep], cols[keep]
        lon, lat = dem.lonlat(cols.astype(float), rows.astype(float))
        finest = int(summary["depth"])
        for depth, datum in [(finest, "native"), (finest, "ellipsoid"), (max(finest - 1, 0), "native")]:
            status, body = srv.post(f"/tilesets/m/heights?surface=mesh&datum={datum}&depth={depth}",
                                    np.column_stack([lon, lat]).tolist())
            label = f"{dem.name}: mesh depth {depth} {datum} at {len(lon)} sample centres"
            if status != 200:
                tally.row(False, f"{label}: HTTP {status}", [body.decode(errors="replace")[:300]])
                continue
            got = json.loads(body)["heights"]
            egm = dem.vertical == "egm96" and datum == "ellipsoid"
            n = geoid.undulation(lon, lat) if egm else 0.0
            margin = MESH_MARGIN_M + (GEOID_TOL_M if egm else 0.0)
            want = dem.v[rows, cols] + n
            problems, worst, max_err, edge, inner, off = [], -np.inf, 0.0, 0, 0, 0
            for k, a in enumerate(got):
                where = f"sample (col {cols[k]}, row {rows[k]}) at ({float(lon[k])!r}, {float(lat[k])!r})"
                on_edge = cols[k] in (0, dem.w - 1) or rows[k] in (0, dem.h - 1)
                if a["nodata"] or a["h"] is None:
                    problems.append(f"{where}: no data answered, expected {want[k]:.3f}")
                    edge, inner = edge + on_edge, inner + (not on_edge)
                    continue
                dh = abs(a["h"] - want[k])
                worst, max_err = max(worst, dh - a["error"]), max(max_err, a["error"])
                if dh > a["error"] * (1 + MESH_REL_MARGIN) + margin:
                    off += 1
                    problems.append(f"{where}: h={a['h']:.3f}, expected {want[k]:.3f} "
                                    f"(|dh| {dh:.3f} > error {a['error']:.3f} + {margin})")
            tally.row(not problems, f"{label}: largest error answered {max_err:.3f} m, largest "
                      f"|dh| - error {worst:+.3f} m; no data at {edge} edge and {inner} inner "
                      f"samples, {off} beyond error + {margin} m", problems)
    finally:
        srv.stop()


def egm96_copy(src, out, vertical_crs):
    """A copy of `src` whose CRS is compound with EGM96 height (VerticalCSTypeGeoKey 5773)."""
    with rasterio.open(src) as ds:
        profile = ds.profile.copy()
        data = ds.read(1)
        horiz = CRS.from_wkt(ds.crs.to_wkt())
        profile.update(crs=f"EPSG:{horiz.to_epsg()}+{vertical_crs}", driver="GTiff")
        profile.pop("blockxsize", None)
        profile.pop("blockysize", None)
        profile["tiled"] = False
    with rasterio.open(out, "w", **profile) as dst:
        dst.write(data, 1)
    return out


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--bin", required=True)
    ap.add_argument("--work", required=True)
    ap.add_argument("--data", default=os.environ.get("TERRASTREAM_DATA", "../shared/data"))
    ap.add_argument("--only", default="")
    ap.add_argument("--mesh", default="utm32n_vinschgau,etopo1_global_1deg_egm96",
                    help="DEMs baked and checked with surface=mesh")
    a = ap.parse_args()
    binary = str(Path(a.bin).resolve())
    work = Path(a.work).resolve()
    work.mkdir(parents=True, exist_ok=True)
    geoid = Geoid(GEOID_GTX)
    diff = geoid.self_check()
    if diff > 1e-3:
        sys.exit(f"EGM96 bilinear read of {GEOID_GTX} differs from PROJ vgridshift by {diff} m")
    print(f"EGM96 grid {GEOID_GTX}: agrees with PROJ vgridshift to {diff:.1e} m")
    geo = Path(a.data) / "geo"
    files = sorted(geo.glob("*.tif"))
    if not files:
        sys.exit(f"no GeoTIFF in {geo}")
    inputs = work / "inputs"
    inputs.mkdir(exist_ok=True)
    dems = [(f.stem, f) for f in files]
    # The shared DEMs carry no vertical GeoKey: copies that say EGM96 exercise the geoid.
    for stem in ("etopo1_global_1deg", "utm32n_pixelispoint_n00e010"):
        if (geo / f"{stem}.tif").exists():
            dems.append((f"{stem}_egm96", egm96_copy(geo / f"{stem}.tif", inputs / f"{stem}_egm96.tif", 5773)))
    only = {s for s in a.only.split(",") if s}
    tally = Tally()
    t0 = time.time()
    for name, path in dems:
        if only and name not in only:
            continue
        dem = Dem(name, path)
        print(f"== {name}: {dem.w} x {dem.h}, {dem.horiz.name}, heights {dem.vertical}")
        try:
            check_source(dem, geoid, binary, work, tally)
            if name in a.mesh.split(","):
                check_mesh(dem, geoid, binary, work, tally)
        except RuntimeError as e:
            tally.row(False, f"{name}: {e}")
    print(f"({time.time() - t0:.0f} s)")
    print(f"heights: {tally.passed} passed, {tally.failed} failed")
    sys.exit(1 if tally.failed else 0)


if __name__ == "__main__":
    main()
