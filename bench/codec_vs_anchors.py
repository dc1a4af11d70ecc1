#!/usr/bin/env python3
"""Blob size benchmark: terrastream's blobs next to the anchors, on the same geometry.

Bakes fuji.png (terrain-RGB, 30 m cells) with terrastream, then for every tile:
- level 0 (mesh): the decoded mesh encoded as Cesium quantized-mesh-1.0 by
  `quantized-mesh-encoder` and gzipped (level 9), vs our `.tsb` blob;
- levels 1..K (points): the decoded points written as LAZ by `laspy[lazrs]` with the scale set to
  our quantization step (the same precision), vs our `.tsb` blob (which also carries normals,
  which the LAZ file does not).

Then the same tileset goes through `terrastream export --format 3dtiles`, and each (tile, level)'s
GLB (what `GET …/3dtiles/tiles/{z}/{x}/{y}/{level}.glb` serves: the very same bytes) is measured
against its blob and its anchor: raw, gzip -9 and zstd -19 (what `serve` sends when the request's
`Accept-Encoding` allows: its gzip is level 6, within 0.1 % of -9 on GLBs; zstd needs the `zstd`
command, else that column is skipped). Bytes per
item always divide by the blob's vertices or points (a mesh GLB also holds its skirts' vertices,
counted in the `GLB verts` column). The same GLBs are measured as our own exports with
`--glb-compression meshopt` (EXT_meshopt_compression) and `--glb-compression draco`
(KHR_draco_mesh_compression for the meshes, meshopt for the points). If gltfpack (meshoptimizer's CLI; the npm package is a wasm
build) is found — $GLTFPACK, `gltfpack` on the PATH, or /tmp/gltfpack/node_modules/.bin/gltfpack
(`npm install --prefix /tmp/gltfpack gltfpack`) — every GLB also goes through
`gltfpack -i in.glb -o out.glb FLAGS` for a few FLAGS (EXT_meshopt_compression; its own
re-quantization, so an estimate of what meshopt would save rather than an exact re-encoding).

    python3 -m venv bench/.venv && bench/.venv/bin/pip install quantized-mesh-encoder 'laspy[lazrs]' numpy
    bench/.venv/bin/python bench/codec_vs_anchors.py [--max-error 1] [--levels 4]
"""
import argparse
import gzip
import io
import json
import os
import shutil
import struct
import subprocess
import sys
import tempfile

import laspy
import numpy as np
import quantized_mesh_encoder

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
DATA = os.environ.get("TERRASTREAM_DATA", os.path.join(ROOT, "..", "shared", "data"))
# $TERRASTREAM_BIN measures another build (say, main's, for a before/after in one sitting).
EXE = os.environ.get("TERRASTREAM_BIN") or os.path.join(ROOT, "target", "release", "terrastream")
# `--glb-compression` options measured on every (tile, level): name → what it is.
COMPRESSIONS = {
    "meshopt": "EXT_meshopt_compression, normals through its octahedral filter",
    "draco": "KHR_draco_mesh_compression for meshes, EXT_meshopt_compression for points",
}

# gltfpack flag sets measured on every GLB: (label, flags). -c / -cc: EXT_meshopt_compression
# (normal / higher ratio); -vp 16: 16-bit positions (gltfpack's default is 14 bits, coarser
# than our grid on large tiles).
MESHOPT = [("-c -vp 16", ["-c", "-vp", "16"]), ("-cc -vp 16", ["-cc", "-vp", "16"]), ("-cc", ["-cc"])]


def zstd19(data):
    """zstd -19 of `data` by the `zstd` command (None without it): what `serve` sends for zstd."""
    exe = shutil.which("zstd")
    if not exe:
        return None
    return len(subprocess.run([exe, "-q", "-c", "-19"], input=data, capture_output=True, check=True).stdout)


def find_gltfpack():
    for c in (os.environ.get("GLTFPACK"), shutil.which("gltfpack"), "/tmp/gltfpack/node_modules/.bin/gltfpack"):
        if c and os.path.isfile(c) and os.access(c, os.X_OK):
            return c
    return None


COMPONENT = {5121: "u8", 5123: "u16", 5125: "u32", 5126: "float"}


def glb_info(data):
    """(POSITION count, its component type, index component type or "-") of a GLB."""
    magic, _, _ = struct.unpack_from("<4sII", data, 0)
    assert magic == b"glTF", "not a GLB"
    jlen, jtype = struct.unpack_from("<I4s", data, 12)
    assert jtype == b"JSON"
    doc = json.loads(data[20:20 + jlen])
    prim = doc["meshes"][0]["primitives"][0]
    acc = doc["accessors"][prim["attributes"]["POSITION"]]
    idx = COMPONENT.get(doc["accessors"][prim["indices"]]["componentType"], "?") if "indices" in prim else "-"
    return acc["count"], COMPONENT.get(acc["componentType"], str(acc["componentType"])), idx


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
    if not os.environ.get("TERRASTREAM_BIN"):
        subprocess.run(["cargo", "build", "--release", "--quiet"], cwd=ROOT, check=True)
    tmp = tempfile.mkdtemp()
    out = os.path.join(tmp, "fuji")
    subprocess.run([EXE, "bake", "--quiet", os.path.join(DATA, "fuji.png"), "--encoding", "terrain-rgb",
                    "--cell-size", "30", "--max-error", args.max_error, "--levels", args.levels,
                    "--tile-size", args.tile_size, "--out", out], check=True, stdout=subprocess.DEVNULL)
    manifest = json.load(open(os.path.join(out, "tileset.json")))
    levels = manifest["levels"]
    t3d = os.path.join(tmp, "3dtiles")
    export_cmd = [EXE, "export", out, "--format", "3dtiles", "--out", t3d, "--quiet"]
    export_msg = subprocess.run(export_cmd, check=True, capture_output=True, text=True).stdout.strip()
    # The same export compressed: EXT_meshopt_compression (`--glb-compression meshopt`,
    # `?glb=meshopt`) and KHR_draco_mesh_compression for meshes (`--glb-compression draco`).
    comp_exports = {}
    for cname in COMPRESSIONS:
        cdir = os.path.join(tmp, f"3dtiles-{cname}")
        ccmd = [EXE, "export", out, "--format", "3dtiles", "--glb-compression", cname, "--out", cdir, "--quiet"]
        comp_exports[cname] = (cdir, ccmd, subprocess.run(ccmd, check=True, capture_output=True, text=True).stdout.strip())
    gltfpack = find_gltfpack()
    ours = {l["level"]: 0 for l in levels}
    anchor = dict(ours)
    anchor_xyz = dict(ours)
    items = dict(ours)
    ours_gz = dict(ours)
    glb = dict(ours)
    glb_gz = dict(ours)
    glb_zst = dict(ours)
    glb_verts = dict(ours)
    glb_types = {l: set() for l in ours}
    comp = {c: dict(ours) for c in COMPRESSIONS}
    comp_gz = {c: dict(ours) for c in COMPRESSIONS}
    packed = {l: {label: 0 for label, _ in MESHOPT} for l in ours}
    packed_gz = {l: {label: 0 for label, _ in MESHOPT} for l in ours}
    packed_verts = {l: {label: 0 for label, _ in MESHOPT} for l in ours}
    for root, _, files in os.walk(os.path.join(out, "index")):
        for name in files:
            for node in json.load(open(os.path.join(root, name)))["nodes"]:
                z, x, y = node["key"]["z"], node["key"]["x"], node["key"]["y"]
                for spec, lv in zip(levels, node["levels"]):
                    level = spec["level"]
                    ply = os.path.join(tmp, "t.ply")
                    if os.path.exists(ply):
                        os.remove(ply)  # export refuses to overwrite a file
                    subprocess.run([EXE, "export", out, "--tile", f"{z}/{x}/{y}", "--level", str(level),
                                    "--format", "ply", "--out", ply], check=True, stdout=subprocess.DEVNULL)
                    verts, faces = read_ply(ply)
                    blob = open(os.path.join(out, "tiles", str(z), str(x), str(y), f"{level}.tsb"), "rb").read()
                    ours[level] += len(blob)
                    ours_gz[level] += len(gzip.compress(blob, 9))
                    items[level] += len(verts)
                    glb_path = os.path.join(t3d, "tiles", str(z), str(x), str(y), f"{level}.glb")
                    data = open(glb_path, "rb").read()
                    glb[level] += len(data)
                    glb_gz[level] += len(gzip.compress(data, 9))
                    zb = zstd19(data)
                    glb_zst[level] = None if zb is None or glb_zst[level] is None else glb_zst[level] + zb
                    for cname, (cdir, _, _) in comp_exports.items():
                        cdata = open(os.path.join(cdir, "tiles", str(z), str(x), str(y), f"{level}.glb"), "rb").read()
                        comp[cname][level] += len(cdata)
                        comp_gz[cname][level] += len(gzip.compress(cdata, 9))
                    count, ctype, itype = glb_info(data)
                    glb_verts[level] += count
                    glb_types[level].add(f"{ctype}/{itype}")
                    if gltfpack:
                        packed_path = os.path.join(tmp, "packed.glb")
                        for label, flags in MESHOPT:
                            subprocess.run([gltfpack, "-i", glb_path, "-o", packed_path] + flags, check=True,
                                           stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
                            p = open(packed_path, "rb").read()
                            packed[level][label] += len(p)
                            packed_verts[level][label] += glb_info(p)[0]
                            packed_gz[level][label] += len(gzip.compress(p, 9))
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
    describe = subprocess.run(["git", "describe", "--always", "--dirty"], cwd=ROOT, capture_output=True,
                              text=True).stdout.strip() or "?"
    print(f"command: {' '.join(sys.argv)} ({describe}; binary {EXE})")
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

    print(f"\n3D Tiles GLBs of the same (tile, level)s: `{' '.join(export_cmd[1:]).replace(tmp, '$TMP')}`")
    print(f"  {export_msg.replace(tmp, '$TMP')}")
    print("B/item = bytes / the blob's vertices (mesh) or points; gz = gzip -9 of each file; "
          "anchor = QM-1.0+gzip (mesh), LAZ+normals (points)\n")
    print(f"{'level':>5} {'kind':>6} {'items':>9} {'GLB verts':>9} {'pos/idx':>13} | {'blob':>6} {'blob gz':>7} "
          f"{'anchor':>6} | {'GLB B':>9} {'B/item':>7} {'GLB gz B':>9} {'B/item':>7} {'zstd B':>9} {'B/item':>7} | "
          f"{'GLB/blob':>8} {'gz/blob':>7} {'gz/anchor':>9} {'zst/anchor':>10}")
    tot = {k: 0 for k in ("glb", "gz", "zst", "blob", "blobgz", "anchor", "mesh_gz", "mesh_zst", "mesh_anchor")}
    have_zst = all(v is not None for v in glb_zst.values())
    zs = lambda v, n: f"{v:>9} {v / n:>7.2f}" if have_zst else f"{'-':>9} {'-':>7}"
    for spec in levels:
        l = spec["level"]
        n = items[l]
        tot["glb"] += glb[l]; tot["gz"] += glb_gz[l]; tot["blob"] += ours[l]; tot["blobgz"] += ours_gz[l]
        tot["anchor"] += anchor[l]
        if have_zst:
            tot["zst"] += glb_zst[l]
        if spec["kind"] == "mesh":
            tot["mesh_gz"] += glb_gz[l]; tot["mesh_anchor"] += anchor[l]
            tot["mesh_zst"] += glb_zst[l] if have_zst else 0
        zst_ratio = f"{glb_zst[l] / anchor[l]:>10.2f}" if have_zst else f"{'-':>10}"
        print(f"{l:>5} {spec['kind']:>6} {n:>9} {glb_verts[l]:>9} {','.join(sorted(glb_types[l])):>13} | "
              f"{ours[l] / n:>6.2f} {ours_gz[l] / n:>7.2f} {anchor[l] / n:>6.2f} | {glb[l]:>9} {glb[l] / n:>7.2f} "
              f"{glb_gz[l]:>9} {glb_gz[l] / n:>7.2f} {zs(glb_zst[l], n)} | {glb[l] / ours[l]:>8.2f} "
              f"{glb_gz[l] / ours[l]:>7.2f} {glb_gz[l] / anchor[l]:>9.2f} {zst_ratio}")
    print(f"{'all':>5} {'':>6} {sum(items.values()):>9} {'':>9} {'':>13} | {'':>6} {'':>7} {'':>6} | "
          f"{tot['glb']:>9} {'':>7} {tot['gz']:>9} {'':>7} {(tot['zst'] if have_zst else '-'):>9} {'':>7} | "
          f"{tot['glb'] / tot['blob']:>8.2f} {tot['gz'] / tot['blob']:>7.2f} {tot['gz'] / tot['anchor']:>9.2f} "
          + (f"{tot['zst'] / tot['anchor']:>10.2f}" if have_zst else f"{'-':>10}"))
    print(f"meshes: GLB gzip / QM+gzip {tot['mesh_gz'] / tot['mesh_anchor']:.2f}"
          + (f", GLB zstd / QM+gzip {tot['mesh_zst'] / tot['mesh_anchor']:.2f}" if have_zst else "")
          + f"; all levels on the wire: GLB gzip / blobs raw {tot['gz'] / tot['blob']:.2f}"
          + (f", GLB zstd / blobs raw {tot['zst'] / tot['blob']:.2f}" if have_zst else ""))
    print(f"(blobs: {tot['blob']} B raw, {tot['blobgz']} B gzip -9 — gzip saves "
          f"{100 * (1 - tot['blobgz'] / tot['blob']):.1f} % on them)")

    for cname, (_, ccmd, cmsg) in comp_exports.items():
        mo, mo_gz = comp[cname], comp_gz[cname]
        print(f"\nThe same GLBs with --glb-compression {cname} ({COMPRESSIONS[cname]}): "
              f"`{' '.join(ccmd[1:]).replace(tmp, '$TMP')}`")
        print(f"  {cmsg.replace(tmp, '$TMP')}")
        print(f"{'level':>5} {'kind':>6} {'items':>9} | {'B':>9} {'B/item':>7} {'gz B':>9} {'B/item':>7} | "
              f"{'/blob':>7} {'gz/blob':>7} {'gz/anchor':>9} {'/plain':>8} {'gz/plain gz':>11}")
        mt = {k: 0 for k in ("mo", "gz", "mesh_mo", "mesh_gz", "mesh_blob", "mesh_anchor")}
        for spec in levels:
            l = spec["level"]
            n = items[l]
            mt["mo"] += mo[l]; mt["gz"] += mo_gz[l]
            if spec["kind"] == "mesh":
                mt["mesh_mo"] += mo[l]; mt["mesh_gz"] += mo_gz[l]; mt["mesh_blob"] += ours[l]
                mt["mesh_anchor"] += anchor[l]
            print(f"{l:>5} {spec['kind']:>6} {n:>9} | {mo[l]:>9} {mo[l] / n:>7.2f} {mo_gz[l]:>9} {mo_gz[l] / n:>7.2f} | "
                  f"{mo[l] / ours[l]:>7.2f} {mo_gz[l] / ours[l]:>7.2f} {mo_gz[l] / anchor[l]:>9.2f} "
                  f"{mo[l] / glb[l]:>8.2f} {mo_gz[l] / glb_gz[l]:>11.2f}")
        print(f"{'all':>5} {'':>6} {sum(items.values()):>9} | {mt['mo']:>9} {'':>7} {mt['gz']:>9} {'':>7} | "
              f"{mt['mo'] / tot['blob']:>7.2f} {mt['gz'] / tot['blob']:>7.2f} {mt['gz'] / tot['anchor']:>9.2f} "
              f"{mt['mo'] / tot['glb']:>8.2f} {mt['gz'] / tot['gz']:>11.2f}")
        print(f"{cname}: all levels raw / blobs raw {mt['mo'] / tot['blob']:.2f} (target ≤ 2); meshes gzip / QM+gzip "
              f"{mt['mesh_gz'] / max(mt['mesh_anchor'], 1):.2f} (target ≤ 1.0); meshes raw / mesh blobs raw "
              f"{mt['mesh_mo'] / max(mt['mesh_blob'], 1):.2f}; all levels gzip / anchors {mt['gz'] / tot['anchor']:.2f}")

    if not gltfpack:
        print("\nmeshopt: skipped, gltfpack not found (set $GLTFPACK, or "
              "`npm install --prefix /tmp/gltfpack gltfpack`)")
        return 0
    version = subprocess.run([gltfpack, "-v"], capture_output=True, text=True).stdout.strip().splitlines()
    print(f"\nEXT_meshopt_compression: `gltfpack -i GLB -o OUT FLAGS` ({version[0] if version else gltfpack}) "
          "on every GLB above, B/item (+gz: gzip -9 of the packed file); gltfpack re-quantizes positions "
          "(default 14 bits, -vp 16: 16), so these are size estimates, not exact re-encodings\n")
    head = f"{'level':>5} {'kind':>6} | {'blob':>6} {'anchor':>6} {'GLB':>6} {'GLB gz':>6} |"
    for label, _ in MESHOPT:
        head += f" {label:>10} {'+gz':>6} |"
    print(head + f" {'best/GLB gz':>11}")
    ptot = {label: [0, 0] for label, _ in MESHOPT}
    for spec in levels:
        l = spec["level"]
        n = items[l]
        row = (f"{l:>5} {spec['kind']:>6} | {ours[l] / n:>6.2f} {anchor[l] / n:>6.2f} {glb[l] / n:>6.2f} "
               f"{glb_gz[l] / n:>6.2f} |")
        best = glb_gz[l]
        for label, _ in MESHOPT:
            row += f" {packed[l][label] / n:>10.2f} {packed_gz[l][label] / n:>6.2f} |"
            ptot[label][0] += packed[l][label]
            ptot[label][1] += packed_gz[l][label]
            best = min(best, packed[l][label], packed_gz[l][label])
        print(row + f" {best / glb_gz[l]:>11.2f}")
    print("best/GLB gz = the smallest meshopt file (raw or gzipped, any flags) / the GLB gzipped")
    print(f"all levels, bytes: blobs {tot['blob']}, GLB {tot['glb']}, GLB gz {tot['gz']}; "
          + "; ".join(f"{label} {ptot[label][0]} (+gz {ptot[label][1]})" for label, _ in MESHOPT))
    for spec in levels:
        l = spec["level"]
        for label, _ in MESHOPT:
            if packed_verts[l][label] != glb_verts[l]:
                print(f"note: level {l}, {label}: gltfpack's output has {packed_verts[l][label]} vertices "
                      f"(the GLBs {glb_verts[l]})")


if __name__ == "__main__":
    sys.exit(main())
