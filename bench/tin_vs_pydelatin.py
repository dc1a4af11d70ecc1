#!/usr/bin/env python3
"""TIN benchmark: terrastream's tin::build next to pydelatin on the same heights, same run.

For each max error, both are timed (best of 3), their vertex counts compared, and both meshes'
max errors verified by the same code (terrastream's measure_vertical over every sample).
terrastream is timed on one thread (RAYON_NUM_THREADS=1) and on all cores: a node larger than
tin::REGION_SPLIT_SAMPLES is built as regions in parallel (the same mesh either way);
pydelatin is single-threaded.

    pip install pydelatin numpy pillow
    python3 bench/tin_vs_pydelatin.py [fuji.png] [max errors…]
"""
import json
import os
import struct
import subprocess
import sys
import tempfile
import time

import numpy as np
from PIL import Image
from pydelatin import Delatin

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
DATA = os.environ.get("TERRASTREAM_DATA", os.path.join(ROOT, "..", "shared", "data"))


def main():
    png = sys.argv[1] if len(sys.argv) > 1 else os.path.join(DATA, "fuji.png")
    errors = [float(e) for e in sys.argv[2:]] or [1.0, 10.0, 30.0]
    subprocess.run(["cargo", "build", "--release", "--quiet", "--example", "tin_fuji"], cwd=ROOT, check=True)
    exe = os.path.join(ROOT, "target", "release", "examples", "tin_fuji")

    rgb = np.asarray(Image.open(png).convert("RGB")).astype(np.float64)
    heights = (-10000 + (rgb[..., 0] * 65536 + rgb[..., 1] * 256 + rgb[..., 2]) * 0.1).astype(np.float32)
    print(f"{os.path.basename(png)}: {heights.shape[1]}×{heights.shape[0]} samples, "
          f"{heights.min():.1f}–{heights.max():.1f} m\n")
    cores = os.cpu_count()
    print(f"{'max err':>8} | {'terrastream':>34} | {'pydelatin':>26} | {'time ratio':>17} {'vertex ratio':>12}")
    print(f"{'':>8} | {'vertices':>9} {'s 1 thr':>7} {'s ' + str(cores) + ' thr':>7} {'meas.':>8} | "
          f"{'vertices':>9} {'s':>7} {'meas.':>8} | {'1 thr':>8} {str(cores) + ' thr':>8}")
    one = dict(os.environ, RAYON_NUM_THREADS="1")
    for e in errors:
        ours = json.loads(subprocess.run([exe, png, str(e)], check=True, capture_output=True, text=True).stdout)
        ours1 = json.loads(subprocess.run([exe, png, str(e)], check=True, capture_output=True, text=True,
                                          env=one).stdout)
        assert ours1["vertices"] == ours["vertices"], "thread count changed the mesh"
        best = float("inf")
        for _ in range(3):
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
        theirs = json.loads(subprocess.run([exe, png, "--measure", f.name], check=True, capture_output=True,
                                           text=True).stdout)
        os.unlink(f.name)
        print(f"{e:>8g} | {ours['vertices']:>9} {ours1['seconds']:>7.3f} {ours['seconds']:>7.3f} "
              f"{ours['measured_max_error']:>8.3f} | "
              f"{len(verts):>9} {best:>7.3f} {theirs['measured_max_error']:>8.3f} | "
              f"{ours1['seconds'] / best:>8.2f} {ours['seconds'] / best:>8.2f} {ours['vertices'] / len(verts):>12.3f}")
    print("\ntime ratio < 1: terrastream faster; vertex ratio: terrastream / pydelatin (target within 5%)")


if __name__ == "__main__":
    main()
