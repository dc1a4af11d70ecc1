#!/usr/bin/env python3
"""TIN benchmark: terrastream's tin::build next to pydelatin on the same heights, same run.

DEMs: fuji.png and every GeoTIFF in ../shared/data/geo/ by default (or the files given before
the errors); the heights come from terrastream's own reader (`tin_fuji DEM --dump`: no-data
filled as a bake fills it), so both triangulate exactly the same samples.
For each DEM and max error, both are timed (best of 3), their vertex counts compared, and both meshes'
max errors verified by the same code (terrastream's measure_vertical over every sample).
terrastream is timed on one thread (RAYON_NUM_THREADS=1) and on all cores: a node larger than
tin::REGION_SPLIT_SAMPLES is built as regions in parallel (the same mesh either way);
pydelatin is single-threaded.

    pip install pydelatin numpy pillow
    python3 bench/tin_vs_pydelatin.py [DEM…] [max errors…]
"""
import json
import os
import struct
import subprocess
import sys
import tempfile
import time

import numpy as np
from pydelatin import Delatin

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
DATA = os.environ.get("TERRASTREAM_DATA", os.path.join(ROOT, "..", "shared", "data"))


def is_number(a):
    try:
        float(a)
        return True
    except ValueError:
        return False


def main():
    args = sys.argv[1:]
    dems = [a for a in args if not is_number(a)]
    errors = [float(e) for e in args if is_number(e)] or [1.0, 10.0, 30.0]
    if not dems:
        geo = os.path.join(DATA, "geo")
        dems = [os.path.join(DATA, "fuji.png")] + sorted(
            os.path.join(geo, f) for f in os.listdir(geo) if f.endswith(".tif"))
    subprocess.run(["cargo", "build", "--release", "--quiet", "--example", "tin_fuji"], cwd=ROOT, check=True)
    exe = os.path.join(ROOT, "target", "release", "examples", "tin_fuji")
    cores = os.cpu_count()
    one = dict(os.environ, RAYON_NUM_THREADS="1")
    worst = 0.0
    for dem in dems:
        with tempfile.NamedTemporaryFile(suffix=".f32", delete=False) as f:
            dump = f.name
        shape = json.loads(subprocess.run([exe, dem, "--dump", dump], check=True, capture_output=True,
                                          text=True).stdout)
        heights = np.fromfile(dump, dtype="<f4").reshape(shape["height"], shape["width"])
        os.unlink(dump)
        print(f"\n{os.path.basename(dem)}: {heights.shape[1]}×{heights.shape[0]} samples, "
              f"{heights.min():.1f}–{heights.max():.1f} m")
        print(f"{'max err':>8} | {'terrastream':>34} | {'pydelatin':>26} | {'time ratio':>17} {'vertex ratio':>12}")
        print(f"{'':>8} | {'vertices':>9} {'s 1 thr':>7} {'s ' + str(cores) + ' thr':>7} {'meas.':>8} | "
              f"{'vertices':>9} {'s':>7} {'meas.':>8} | {'1 thr':>8} {str(cores) + ' thr':>8}")
        for e in errors:
            ours = json.loads(subprocess.run([exe, dem, str(e)], check=True, capture_output=True, text=True).stdout)
            ours1 = json.loads(subprocess.run([exe, dem, str(e)], check=True, capture_output=True, text=True,
                                              env=one).stdout)
            assert ours1["vertices"] == ours["vertices"], "thread count changed the mesh"
            best = float("inf")
            for _ in range(5):
                t = time.perf_counter()
                d = Delatin(heights, max_error=e)
                verts, tris = d.vertices, d.triangles
                best = min(best, time.perf_counter() - t)
            with tempfile.NamedTemporaryFile(suffix=".bin", delete=False) as f:
                f.write(struct.pack("<II", len(verts), len(tris)))
                # pydelatin's y runs bottom-up: row = (rows − 1) − y.
                cols_rows = np.stack([verts[:, 0], heights.shape[0] - 1 - verts[:, 1]], axis=1)
                f.write(np.asarray(cols_rows, dtype="<f8").tobytes())
                f.write(np.asarray(tris, dtype="<u4").tobytes())
            theirs = json.loads(subprocess.run([exe, dem, "--measure", f.name], check=True, capture_output=True,
                                               text=True).stdout)
            os.unlink(f.name)
            ratio = ours1["seconds"] / best
            worst = max(worst, ratio)
            print(f"{e:>8g} | {ours['vertices']:>9} {ours1['seconds']:>7.4f} {ours['seconds']:>7.4f} "
                  f"{ours['measured_max_error']:>8.3f} | "
                  f"{len(verts):>9} {best:>7.4f} {theirs['measured_max_error']:>8.3f} | "
                  f"{ratio:>8.2f} {ours['seconds'] / best:>8.2f} {ours['vertices'] / len(verts):>12.3f}")
    print("\ntime ratio < 1: terrastream faster (best of 5 each); vertex ratio: terrastream / pydelatin")
    print(f"worst one-thread time ratio: {worst:.2f} (goal <= 0.80)")


if __name__ == "__main__":
    main()
