#!/usr/bin/env python3
"""Lighting seams between 3D Tiles GLBs: the drawn normals of the vertices two neighbouring tiles
of one depth share.

Bakes fuji.png (terrain-RGB, 30 m cells, `--max-error 1`, 256-cell tiles) with the binary under
test (TERRASTREAM_BIN, default target/release/terrastream), exports it as plain 3D Tiles, and for
every level-0 (mesh) GLB reads each vertex's placed position (node translation + scale ·
POSITION) and its normal as a renderer draws it (NORMAL through the inverse transpose of the
node's scale, normalized). Vertices at the same placed position in two tiles of one depth are a
border both draw; a renderer lights each side with its own normal, so the angle between the two
is a visible seam where it is large. Prints, per depth: shared vertices and the angle's median,
90th percentile and maximum. A tile's normals are area-weighted over its own triangles only,
which is why they differ (neither tile has the other's triangles).

With `--source FILE` (a DEM with a coordinate system, e.g. ../shared/data/geo/*.tif) the
tileset is placed on the Earth: each GLB's node `matrix` (east-north-up at its node's centre)
takes positions and drawn normals to ECEF, and positions within 5 cm are one vertex (f32
positions relative to two node centres differ by millimetres).

Usage: bench/.venv/bin/python bench/glb_border_normals.py [--keep DIR] [--source FILE] [--tile-size N]
                                                          [--max-error E]
"""
import argparse
import collections
import glob
import json
import os
import struct
import subprocess
import tempfile

import numpy as np

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
DATA = os.environ.get("TERRASTREAM_DATA", os.path.join(ROOT, "..", "shared", "data"))
EXE = os.environ.get("TERRASTREAM_BIN", os.path.join(ROOT, "target", "release", "terrastream"))
COMPONENT = {5120: ("i1", 127.0), 5123: ("<u2", 1.0), 5126: ("<f4", 1.0)}


def placed(path):
    """(positions, drawn unit normals) of a mesh GLB's one primitive; None for points."""
    b = open(path, "rb").read()
    jl = struct.unpack("<I", b[12:16])[0]
    doc = json.loads(b[20:20 + jl])
    binary = b[28 + jl:]
    prim = doc["meshes"][0]["primitives"][0]
    if prim.get("mode", 4) != 4:
        return None

    def accessor(i):
        a = doc["accessors"][i]
        view = doc["bufferViews"][a["bufferView"]]
        dt, norm = COMPONENT[a["componentType"]]
        size = np.dtype(dt).itemsize
        stride = view.get("byteStride", 3 * size)
        n = a["count"]
        raw = np.frombuffer(binary, np.uint8, n * stride, view.get("byteOffset", 0)).reshape(n, stride)
        return raw[:, :3 * size].copy().view(dt).reshape(n, 3).astype(np.float64) / norm

    node = doc["nodes"][0]
    scale = np.array(node.get("scale", [1.0, 1.0, 1.0]))
    translation = np.array(node.get("translation", [0.0, 0.0, 0.0]))
    pos = translation + accessor(prim["attributes"]["POSITION"]) * scale
    drawn = accessor(prim["attributes"]["NORMAL"]) / scale
    if "matrix" in node:
        # glTF y-up → 3D Tiles z-up, then the node's own matrix (column-major) to ECEF.
        m = np.array(node["matrix"], dtype=np.float64).reshape(4, 4).T
        y_up_to_z_up = np.array([[1.0, 0, 0], [0, 0, -1.0], [0, 1.0, 0]])
        rot = y_up_to_z_up @ m[:3, :3]
        off = y_up_to_z_up @ m[:3, 3]
        pos = pos @ rot.T + off
        drawn = drawn @ np.linalg.inv(rot)
    drawn /= np.linalg.norm(drawn, axis=1, keepdims=True)
    return pos, drawn


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--keep", help="bake and export into this folder (kept) instead of a temporary one")
    ap.add_argument("--source", help="a DEM with a coordinate system instead of fuji.png (placed on the Earth)")
    ap.add_argument("--tile-size", default="256")
    ap.add_argument("--max-error", default="1")
    args = ap.parse_args()
    tmp = args.keep or tempfile.mkdtemp()
    store, t3d = os.path.join(tmp, "tileset"), os.path.join(tmp, "3dtiles")
    src = [args.source] if args.source else [os.path.join(DATA, "fuji.png"), "--encoding", "terrain-rgb",
                                             "--cell-size", "30"]
    bake = [EXE, "bake", "--quiet", *src, "--max-error", args.max_error, "--tile-size", args.tile_size,
            "--out", store]
    subprocess.run(bake, check=True, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    subprocess.run([EXE, "export", store, "--format", "3dtiles", "--out", t3d, "--quiet"], check=True,
                   stdout=subprocess.DEVNULL)
    print(f"command: {' '.join(bake[1:]).replace(tmp, '$TMP')}; export --format 3dtiles; binary {EXE}")
    by_depth = collections.defaultdict(list)
    for path in sorted(glob.glob(os.path.join(t3d, "tiles", "*", "*", "*", "0.glb"))):
        got = placed(path)
        if got is not None:
            by_depth[int(path.split(os.sep)[-4])].append(got)
    for depth, tiles in sorted(by_depth.items()):
        seen = {}
        angles = []
        quantum = 0.05 if args.source else 0.001
        for t, (pos, drawn) in enumerate(tiles):
            for k, p in enumerate(np.round(pos / quantum)):
                key = tuple(p)
                other = seen.get(key)
                if other is None:
                    seen[key] = (t, k)
                elif other[0] != t:
                    d = float(np.clip(np.dot(tiles[other[0]][1][other[1]], drawn[k]), -1.0, 1.0))
                    angles.append(np.degrees(np.arccos(d)))
        if not angles:
            print(f"depth {depth}: {len(tiles)} mesh GLBs, no shared vertices")
            continue
        a = np.array(angles)
        print(f"depth {depth}: {len(tiles)} mesh GLBs, {len(a)} shared vertices; drawn-normal angle between the two "
              f"sides: median {np.median(a):.2f}°, p90 {np.percentile(a, 90):.2f}°, max {a.max():.2f}°")


if __name__ == "__main__":
    main()
