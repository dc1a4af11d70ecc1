#!/usr/bin/env python3
"""Blob size benchmark: terrastream's blobs next to the anchors, on the same geometry.

Bakes fuji.png (terrain-RGB, 30 m cells) with terrastream, then for every tile:
- level 0 (mesh): the decoded mesh encoded as Cesium quantized-mesh-1.0 by
  `quantized-mesh-encoder` and gzipped (level 9), vs our `.tsb` blob;
- levels 1..K (points): the decoded points written as LAZ by `laspy[lazrs]` with the scale set to
  our quantization step (the same precision), vs our `.tsb` blob (which also carries normals,
  which the LAZ file does not).

    pip install quantized-mesh-encoder 'laspy[lazrs]' numpy
    python3 bench/codec_vs_anchors.py [--max-error 1] [--levels 4]
"""
import argparse
import gzip
import io
import json
import os
import subprocess
import sys
import tempfile

import laspy
import numpy as np
import quantized_mesh_encoder

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
DATA = os.environ.get("TERRASTREAM_DATA", os.path.join(ROOT, "..", "shared", "data"))
EXE = os.path.join(ROOT, "target", "release", "terrastream")


def read_ply(path):
    """Reads terrastream's binary PLY export: double xyz [+ float normals], int faces."""
    with open(path, "rb") as f:
        data = f.read()
    end = data.index(b"end_header\n") + len(b"end_header\n")
    header = data[:end].decode()
    nv = int(header.split("element vertex ")[1].split()[0])
    nf = int(header.split("element face ")[1].split()[0]) if "element face" in header else 0
    has_normals = "property float nx" in header
    vdt = np.dtype([("x", "<f8"), ("y", "<f8"), ("z", "<f8")] + ([("nx", "<f4"), ("ny", "<f4"), ("nz", "<f4")]
                                                               if has_normals else []))
    verts = np.frombuffer(data, vdt, nv, end)
    faces = None
    if nf:
        fdt = np.dtype([("n", "u1"), ("i", "<i4", 3)])
        faces = np.frombuffer(data, fdt, nf, end + nv * vdt.itemsize)["i"].astype(np.uint32)
    return verts, faces


def octahedral(nx, ny, nz):
    """Unit normals → two bytes each (octahedral mapping, 8 bits per component)."""
    n = np.stack([nx, ny, nz], axis=1).astype(np.float64)
    n /= np.abs(n).sum(axis=1, keepdims=True)
    x, y = n[:, 0].copy(), n[:, 1].copy()
    low = n[:, 2] < 0
    x[low], y[low] = ((1 - np.abs(n[low, 1])) * np.sign(n[low, 0]), (1 - np.abs(n[low, 0])) * np.sign(n[low, 1]))
    q = lambda c: np.clip(np.round((c + 1) * 127.5), 0, 255).astype(np.uint8)
    return q(x), q(y)


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--max-error", default="1")
    ap.add_argument("--levels", default="4")
    ap.add_argument("--tile-size", default="256")
    args = ap.parse_args()
    subprocess.run(["cargo", "build", "--release", "--quiet"], cwd=ROOT, check=True)
    tmp = tempfile.mkdtemp()
    out = os.path.join(tmp, "fuji")
    subprocess.run([EXE, "bake", "--quiet", os.path.join(DATA, "fuji.png"), "--encoding", "terrain-rgb",
                    "--cell-size", "30", "--max-error", args.max_error, "--levels", args.levels,
                    "--tile-size", args.tile_size, "--out", out], check=True, stdout=subprocess.DEVNULL)
    manifest = json.load(open(os.path.join(out, "tileset.json")))
    levels = manifest["levels"]
    ours = {l["level"]: 0 for l in levels}
    anchor = dict(ours)
    anchor_xyz = dict(ours)
    items = dict(ours)
    for root, _, files in os.walk(os.path.join(out, "index")):
        for name in files:
            for node in json.load(open(os.path.join(root, name)))["nodes"]:
                z, x, y = node["key"]["z"], node["key"]["x"], node["key"]["y"]
                for spec, lv in zip(levels, node["levels"]):
                    level = spec["level"]
                    ply = os.path.join(tmp, "t.ply")
                    subprocess.run([EXE, "export", out, "--tile", f"{z}/{x}/{y}", "--level", str(level),
                                    "--format", "ply", "--out", ply], check=True, stdout=subprocess.DEVNULL)
                    verts, faces = read_ply(ply)
                    ours[level] += os.path.getsize(os.path.join(out, "tiles", str(z), str(x), str(y),
                                                                f"{level}.tsb"))
                    items[level] += len(verts)
                    if spec["kind"] == "mesh":
                        pos = np.stack([verts["x"], verts["y"], verts["z"]], axis=1).astype(np.float32)
                        b = node["bounds"]
                        buf = io.BytesIO()
                        quantized_mesh_encoder.encode(buf, pos, faces.flatten(),
                                                      bounds=(b["min"][0], b["min"][1], b["max"][0], b["max"][1]))
                        anchor[level] += len(gzip.compress(buf.getvalue(), 9))
                    else:
                        step = (30.0 * (2 ** (manifest["depth"] - z)) * spec["cell_leaf_cells"]
                                / spec["precision_per_cell"])
                        hdr = laspy.LasHeader(point_format=0, version="1.2")
                        hdr.scales = [step, step, step]
                        hdr.offsets = [b for b in node["bounds"]["min"]]
                        las = laspy.LasData(hdr)
                        las.x, las.y, las.z = verts["x"], verts["y"], verts["z"]
                        buf = io.BytesIO()
                        las.write(buf, do_compress=True, laz_backend=laspy.LazBackend.Lazrs)
                        anchor_xyz[level] += len(buf.getvalue())
                        # The same points with their normals at our precision (octahedral 8+8
                        # bits) as two LAS extra bytes: the like-for-like comparison.
                        hdr = laspy.LasHeader(point_format=0, version="1.4")
                        hdr.scales = [step, step, step]
                        hdr.offsets = [b for b in node["bounds"]["min"]]
                        hdr.add_extra_dims([laspy.ExtraBytesParams(name="octu", type=np.uint8),
                                            laspy.ExtraBytesParams(name="octv", type=np.uint8)])
                        las = laspy.LasData(hdr)
                        las.x, las.y, las.z = verts["x"], verts["y"], verts["z"]
                        u, v = octahedral(verts["nx"], verts["ny"], verts["nz"])
                        las.octu, las.octv = u, v
                        buf = io.BytesIO()
                        las.write(buf, do_compress=True, laz_backend=laspy.LazBackend.Lazrs)
                        anchor[level] += len(buf.getvalue())
    print(f"fuji.png, 30 m cells, max error {args.max_error} m, tile size {args.tile_size}; "
          f"{sum(1 for _ in os.walk(os.path.join(out, 'tiles')))} dirs\n")
    print(f"{'level':>5} {'kind':>6} {'items':>9} | {'ours B':>9} {'B/item':>7} | {'anchor':>14} {'B':>9} "
          f"{'B/item':>7} | {'ratio':>6} | {'LAZ xyz only':>12} {'B/item':>7}")
    for spec in levels:
        l = spec["level"]
        name = "QM-1.0+gzip" if spec["kind"] == "mesh" else "LAZ+normals"
        extra = (f" | {anchor_xyz[l]:>12} {anchor_xyz[l] / items[l]:>7.2f}" if spec["kind"] != "mesh" else "")
        print(f"{l:>5} {spec['kind']:>6} {items[l]:>9} | {ours[l]:>9} {ours[l] / items[l]:>7.2f} | "
              f"{name:>14} {anchor[l]:>9} {anchor[l] / items[l]:>7.2f} | {ours[l] / anchor[l]:>6.3f}{extra}")
    print("\nratio = terrastream / anchor (targets: mesh ≤ 0.5 of QM+gzip, points ≤ 1.0 of LAZ at the same precision,")
    print("normals included on both sides; 'LAZ xyz only' drops the normals our blobs carry)")


if __name__ == "__main__":
    sys.exit(main())
