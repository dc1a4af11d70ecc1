#!/usr/bin/env python3
"""The Python half of bench/heights_vs_rasterio.sh (issue 38): points, rasterio, HTTP, table.

    heights_vs_rasterio.py points DEM DIR N        DIR/wgs84.f64, DIR/crs.f64 (seeded, N points)
    heights_vs_rasterio.py rasterio DEM DIR SECS   rasterio DatasetReader.sample on DIR/crs.f64
    heights_vs_rasterio.py http BASE DIR SECS      POST binary batches to BASE (a serve)
    heights_vs_rasterio.py table DIR               the table of DIR/*.jsonl

Every timed run goes over consecutive points in batches of 1, 100, 10,000 and 1,000,000 until
SECS have passed or the points run out, and appends `{"side", "what", "batch", "points",
"secs"}` to DIR/results.jsonl. The in-process lines of examples/heights_bench.rs are read from
DIR/inproc.txt.
"""

import http.client
import json
import sys
import time
import urllib.parse
from pathlib import Path

import numpy as np

BATCHES = [1, 100, 10_000, 1_000_000]
LATENCY_REQUESTS = 50


def record(d, **row):
    with open(Path(d) / "results.jsonl", "a") as f:
        f.write(json.dumps(row) + "\n")
    rate = row["points"] / row["secs"] if row["secs"] else float("nan")
    print(f"{row['side']:8} {row['what']:28} batch={row['batch']:<8} points={row['points']:<8} "
          f"secs={row['secs']:.3f} pts/s={rate:,.0f}", flush=True)


def timed(points, batch, secs, f):
    t0 = time.perf_counter()
    done = 0
    while done < len(points) and (done == 0 or time.perf_counter() - t0 < secs):
        end = min(done + batch, len(points))
        f(points[done:end])
        done = end
    return done, time.perf_counter() - t0


def cmd_points(dem, d, n):
    import rasterio
    from pyproj import CRS, Transformer
    d = Path(d)
    d.mkdir(parents=True, exist_ok=True)
    with rasterio.open(dem) as ds:
        t, w, h = ds.transform, ds.width, ds.height
        crs = CRS.from_wkt(ds.crs.to_wkt())
    rng = np.random.default_rng(38)
    # Uniform over the sample centres' extent (every point has data), in the DEM's CRS.
    c, r = rng.uniform(0, w - 1, n) + 0.5, rng.uniform(0, h - 1, n) + 0.5
    x, y = t.a * c + t.c, t.e * r + t.f
    horiz = crs.sub_crs_list[0] if crs.is_compound else crs
    lon, lat = Transformer.from_crs(horiz, CRS.from_epsg(4326), always_xy=True).transform(x, y)
    np.column_stack([lon, lat]).astype("<f8").tofile(d / "wgs84.f64")
    np.column_stack([x, y]).astype("<f8").tofile(d / "crs.f64")
    print(f"{n} points over {w} x {h} samples of {dem} ({horiz.name})")


def load(d, name):
    return np.fromfile(Path(d) / name, "<f8").reshape(-1, 2)


def cmd_rasterio(dem, d, secs):
    import rasterio
    from pyproj import CRS, Transformer
    xy = load(d, "crs.f64")
    ll = load(d, "wgs84.f64")
    with rasterio.open(dem) as ds:
        crs = CRS.from_wkt(ds.crs.to_wkt())
        horiz = crs.sub_crs_list[0] if crs.is_compound else crs
        to_crs = Transformer.from_crs(CRS.from_epsg(4326), horiz, always_xy=True)
        for batch in BATCHES:
            # What Open Topo Data's read does per request: the dataset's nearest sample at
            # points already in its CRS (a list of tuples, as its callers pass them).
            n, s = timed(xy, batch, secs, lambda p: list(ds.sample([tuple(q) for q in p], indexes=1)))
            record(d, side="rasterio", what="sample (CRS points)", batch=batch, points=n, secs=s)
        for batch in BATCHES:
            def f(p):
                x, y = to_crs.transform(p[:, 0], p[:, 1])
                return list(ds.sample(list(zip(x, y)), indexes=1))
            n, s = timed(ll, batch, secs, f)
            record(d, side="rasterio", what="pyproj + sample (WGS 84)", batch=batch, points=n, secs=s)


def cmd_http(base, d, secs):
    u = urllib.parse.urlsplit(base)
    ll = load(d, "wgs84.f64")
    conn = http.client.HTTPConnection(u.hostname, u.port, timeout=600)
    head = {"Content-Type": "application/octet-stream", "Accept": "application/octet-stream"}

    def post(path, p):
        conn.request("POST", path, body=np.ascontiguousarray(p, "<f8").tobytes(), headers=head)
        r = conn.getresponse()
        body = r.read()
        if r.status != 200 or len(body) != 16 * len(p):
            raise SystemExit(f"POST {path}: HTTP {r.status}, {len(body)} bytes: {body[:300]!r}")
        return body

    routes = [("source bilinear", "/tilesets/d/heights?surface=source&interpolation=bilinear"),
              ("mesh", "/tilesets/m/heights?surface=mesh")]
    for what, path in routes:
        post(path, ll[:1000])  # warm-up: the mesh tiles read once, the connection open
        for batch in BATCHES:
            n, s = timed(ll, batch, secs, lambda p: post(path, p))
            record(d, side="http", what=what, batch=batch, points=n, secs=s)
        lat = []
        for k in range(LATENCY_REQUESTS):
            p = ll[(k * 10_000) % len(ll):][:10_000]
            t0 = time.perf_counter()
            post(path, p)
            lat.append(time.perf_counter() - t0)
        lat = np.array(lat) * 1000
        row = dict(side="latency", what=what, batch=10_000, requests=len(lat),
                   p50_ms=float(np.percentile(lat, 50)), p99_ms=float(np.percentile(lat, 99)))
        with open(Path(d) / "results.jsonl", "a") as f:
            f.write(json.dumps(row) + "\n")
        print(f"latency  {what:28} 10k-point batches: {len(lat)} requests, p50 {row['p50_ms']:.1f} ms, "
              f"p99 {row['p99_ms']:.1f} ms", flush=True)


def cmd_table(d):
    d = Path(d)
    rows = [json.loads(x) for x in (d / "results.jsonl").read_text().splitlines()]
    for line in (d / "inproc.txt").read_text().splitlines():
        if line.startswith("inproc "):
            kv = dict(x.split("=", 1) for x in line.split()[2:])
            rows.append(dict(side="in-process", what=line.split()[1], batch=int(kv["batch"]),
                             points=int(kv["points"]), secs=float(kv["secs"])))
    rate = {}
    for r in rows:
        if "secs" in r:
            rate[(r["side"], r["what"], r["batch"])] = r["points"] / r["secs"]
    whats = [("in-process", "source-bilinear"), ("in-process", "mesh"), ("http", "source bilinear"),
             ("http", "mesh"), ("rasterio", "sample (CRS points)"), ("rasterio", "pyproj + sample (WGS 84)")]
    print("| points/s | " + " | ".join(f"batch {b:,}" for b in BATCHES) + " |")
    print("|---|" + "---:|" * len(BATCHES))
    for side, what in whats:
        cells = [f"{rate[(side, what, b)]:,.0f}" if (side, what, b) in rate else "–" for b in BATCHES]
        print(f"| {side}: {what} | " + " | ".join(cells) + " |")
    ref = ("rasterio", "sample (CRS points)")
    for what in ("source bilinear", "mesh"):
        cells = []
        for b in BATCHES:
            a, r = rate.get(("http", what, b)), rate.get((*ref, b))
            cells.append(f"{a / r:.1f}×" if a and r else "–")
        print(f"| HTTP {what} ÷ rasterio sample | " + " | ".join(cells) + " |")
    for r in rows:
        if r["side"] == "latency":
            print(f"\nHTTP {r['what']}, 10,000-point batches, {r['requests']} requests: "
                  f"p50 {r['p50_ms']:.1f} ms, p99 {r['p99_ms']:.1f} ms", end="")
    print()


def main():
    a = sys.argv[1:]
    if a[:1] == ["points"] and len(a) == 4:
        cmd_points(a[1], a[2], int(a[3]))
    elif a[:1] == ["rasterio"] and len(a) == 4:
        cmd_rasterio(a[1], a[2], float(a[3]))
    elif a[:1] == ["http"] and len(a) == 4:
        cmd_http(a[1], a[2], float(a[3]))
    elif a[:1] == ["table"] and len(a) == 2:
        cmd_table(a[1])
    else:
        sys.exit(__doc__)


if __name__ == "__main__":
    main()
