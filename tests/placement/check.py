#!/usr/bin/env python3
"""Independent placement check of terrastream's 3D Tiles.

    check.py --bin PATH --inputs DIR --work DIR [--only NAME,...] [--timeout S] [--lenient-flags]

For every input of DIR/manifest.json (written by make_inputs.py): `PATH bake`, then `PATH export
--format 3dtiles`, then read the exported tileset with no terrastream code (tileset JSON, external
tilesets, tile transforms, GLB/b3dm/glTF, node matrices, y-up to z-up, accessors, quantized and
normalized components, CESIUM_RTC) to get every vertex in ECEF (EPSG:4978), and compare with
where the source raster's own georeference (rasterio), PROJ (pyproj) and, for orthometric
heights, the EGM96 grid put the Earth's surface:

- corners: each file's four corner samples (of a mosaic in one CRS: those on the corners of the
  union of its files) within CORNER_TOL_M of a vertex of the finest meshes;
- vertices: every finest mesh vertex (skirts excepted) within its tile's geometricError +
  VERTEX_MARGIN_M of the raster height at its longitude/latitude (bilinear, + geoid if EGM96).

One table row per input, then `N passed, N failed`; exit 1 if any failed. README.md beside this
file says what each check means, the tolerances and the skirt rule.
"""

import argparse
import json
import math
import re
import shutil
import struct
import subprocess
import sys
import time
import urllib.parse
import warnings
from pathlib import Path

import numpy as np
import rasterio
import rasterio.errors
from pyproj import CRS, Transformer

CORNER_TOL_M = 0.05
VERTEX_MARGIN_M = 0.1
# A skirt vertex hangs under a border vertex of the top surface: within this fraction of the
# height difference horizontally (a cone of half-angle atan(0.25) = 14 degrees).
SKIRT_CONE = 0.25
# ... and within this fraction of the raster's sample spacing (a surface neighbour is a sample or
# more away).
SKIRT_MAX_OFFSET = 0.25
# Samples a vertex may lie outside the raster's sample centres before it counts as outside.
EDGE_EPS_PX = 1e-3
# A vertex this close to the Earth's axis is at a pole (its longitude means nothing).
POLE_AXIS_M = 0.01
GEOID_GTX = "/usr/share/proj/egm96_15.gtx"

ECEF = CRS.from_epsg(4978)
LLH = CRS.from_epsg(4979)
LL = CRS.from_epsg(4326)
TO_LLH = Transformer.from_crs(ECEF, LLH, always_xy=True)
TO_ECEF = Transformer.from_crs(LLH, ECEF, always_xy=True)

# glTF to 3D Tiles: glTF is y-up, 3D Tiles z-up (rotation of +90 degrees about x).
Y_UP_TO_Z_UP = np.array([[1, 0, 0, 0], [0, 0, -1, 0], [0, 1, 0, 0], [0, 0, 0, 1]], dtype=float)
COMPONENT = {5120: "i1", 5121: "u1", 5122: "<i2", 5123: "<u2", 5125: "<u4", 5126: "<f4"}
NORMALIZE = {5120: (127.0, True), 5121: (255.0, False), 5122: (32767.0, True), 5123: (65535.0, False)}
N_COMPONENTS = {"SCALAR": 1, "VEC2": 2, "VEC3": 3, "VEC4": 4, "MAT2": 4, "MAT3": 9, "MAT4": 16}
# Extensions that change where vertices are and that this checker does not decode.
GEOMETRY_EXTENSIONS = {
    "EXT_meshopt_compression": "meshopt-compressed buffers",
    "KHR_meshopt_compression": "meshopt-compressed buffers",
    "KHR_draco_mesh_compression": "Draco-compressed meshes",
    "EXT_mesh_gpu_instancing": "GPU instancing (positions repeated by per-instance transforms)",
}
# Extensions that do not move vertices (or that are decoded here).
HARMLESS_EXTENSIONS = {
    "KHR_mesh_quantization", "CESIUM_RTC", "KHR_materials_unlit", "KHR_texture_transform",
    "KHR_materials_emissive_strength", "EXT_structural_metadata", "EXT_mesh_features",
    "KHR_texture_basisu", "EXT_texture_webp", "CESIUM_primitive_outline",
}


class CheckError(Exception):
    """The tileset or an input cannot be checked: the message says why."""


# ---------------------------------------------------------------------------------------------
# EGM96


class Geoid:
    """EGM96 undulations (metres) from a GTX grid, bilinear; checked against PROJ's vgridshift."""

    def __init__(self, path):
        b = Path(path).read_bytes()
        if len(b) < 40:
            raise CheckError(f"{path}: {len(b)} bytes, shorter than a GTX header")
        self.lat0, self.lon0, self.dlat, self.dlon = struct.unpack(">4d", b[:32])
        self.rows, self.cols = struct.unpack(">2i", b[32:40])
        if len(b) != 40 + 4 * self.rows * self.cols:
            raise CheckError(f"{path}: {len(b)} bytes, not a {self.rows} x {self.cols} GTX grid")
        self.grid = np.frombuffer(b, ">f4", self.rows * self.cols, 40).reshape(self.rows, self.cols).astype(float)
        span = self.cols * self.dlon
        self.wraps = abs(span - 360.0) < 1e-9
        if not (self.wraps or abs(span - 360.0 - self.dlon) < 1e-9):
            raise CheckError(f"{path}: not a global grid ({span} degrees of longitude)")
        self.path = path

    def undulation(self, lon, lat):
        lon, lat = np.asarray(lon, float), np.asarray(lat, float)
        r = np.clip((lat - self.lat0) / self.dlat, 0.0, self.rows - 1.0)
        c = np.mod(lon - self.lon0, 360.0) / self.dlon
        r0 = np.minimum(np.floor(r).astype(int), self.rows - 2)
        c0 = np.floor(c).astype(int)
        fr, fc = r - r0, c - c0
        if self.wraps:
            c0 %= self.cols
            c1 = (c0 + 1) % self.cols
        else:
            c0 = np.minimum(c0, self.cols - 2)
            fc = c - c0
            c1 = c0 + 1
        g = self.grid
        return ((g[r0, c0] * (1 - fc) + g[r0, c1] * fc) * (1 - fr)
                + (g[r0 + 1, c0] * (1 - fc) + g[r0 + 1, c1] * fc) * fr)

    def self_check(self):
        """Compares with PROJ's vgridshift on the same file at seeded points, poles and the
        antimeridian included; returns the largest difference (metres)."""
        rng = np.random.default_rng(0)
        lon = np.concatenate([rng.uniform(-180, 180, 200), [179.9, -179.9, 180.0, 0.0, 10.0]])
        lat = np.concatenate([rng.uniform(-89.9, 89.9, 200), [65.5, -40.0, 90.0, -90.0, 0.0]])
        pipe = Transformer.from_pipeline(
            "+proj=pipeline +step +proj=unitconvert +xy_in=deg +xy_out=rad "
            f"+step +proj=vgridshift +grids={self.path} +multiplier=1 "
            "+step +proj=unitconvert +xy_in=rad +xy_out=deg")
        _, _, n = pipe.transform(lon, lat, np.zeros_like(lon))
        return float(np.max(np.abs(np.asarray(n) - self.undulation(lon, lat))))


# ---------------------------------------------------------------------------------------------
# Source rasters


class Source:
    """One raster file: its georeference as rasterio reads it, its heights (NaN = no-data)."""

    def __init__(self, path, heights_override=None):
        self.path = Path(path)
        with rasterio.open(self.path) as ds:
            if ds.crs is None:
                raise CheckError(f"{path}: no CRS")
            crs = CRS.from_wkt(ds.crs.to_wkt())
            self.transform = ds.transform
            self.width, self.height = ds.width, ds.height
            if heights_override and "terrain_rgb" in heights_override:
                self.values = terrain_rgb(heights_override["terrain_rgb"], ds.width, ds.height)
            else:
                a = ds.read(1, masked=True).astype(float)
                self.values = a.filled(np.nan) * ds.scales[0] + ds.offsets[0]
        if not self.transform.is_rectilinear:
            raise CheckError(f"{path}: a rotated georeference; not handled by this checker")
        self.crs = crs.sub_crs_list[0] if crs.is_compound else crs
        # A compound CRS's vertical part says the heights' unit (e.g. metres under a feet grid).
        self.vertical = crs.sub_crs_list[1] if crs.is_compound and len(crs.sub_crs_list) > 1 else None
        if self.vertical is not None and self.vertical.axis_info:
            self.values = self.values * self.vertical.axis_info[0].unit_conversion_factor
        self.geographic = self.crs.is_geographic
        self.to_ll = Transformer.from_crs(self.crs, LL, always_xy=True)
        self.from_ll = Transformer.from_crs(LL, self.crs, always_xy=True)
        self.inverse = ~self.transform

    def sample_lonlat(self, cols, rows):
        """WGS 84 longitude/latitude of sample centres (rasterio's transform maps pixel corners,
        for PixelIsPoint files too: GDAL shifts those by half a pixel)."""
        x, y = affine(self.transform, np.asarray(cols, float) + 0.5, np.asarray(rows, float) + 0.5)
        lon, lat = self.to_ll.transform(x, y)
        return np.asarray(lon, float), np.asarray(lat, float)

    def locate(self, lon, lat):
        """Fractional sample coordinates (col, row; 0 = the first sample centre) of WGS 84
        positions: one candidate for a projected CRS, and for a geographic one the longitude as
        is and shifted by +-360 degrees (files written 0..360, or with columns on both -180 and
        180)."""
        x, y = self.from_ll.transform(lon, lat)
        x, y = np.asarray(x, float), np.asarray(y, float)
        shifts = (0.0, -360.0, 360.0) if self.geographic else (0.0,)
        out = []
        for s in shifts:
            c, r = affine(self.inverse, x + s, y)
            out.append((np.asarray(c, float) - 0.5, np.asarray(r, float) - 0.5))
        return out

    def inside(self, c, r):
        return ((c >= -EDGE_EPS_PX) & (c <= self.width - 1 + EDGE_EPS_PX)
                & (r >= -EDGE_EPS_PX) & (r <= self.height - 1 + EDGE_EPS_PX))

    def bilinear(self, c, r):
        """Bilinear heights at fractional sample coordinates (inside); NaN where a sample with a
        non-zero weight is no-data."""
        c = np.clip(c, 0.0, self.width - 1.0)
        r = np.clip(r, 0.0, self.height - 1.0)
        c0 = np.minimum(np.floor(c).astype(int), max(self.width - 2, 0))
        r0 = np.minimum(np.floor(r).astype(int), max(self.height - 2, 0))
        c1 = np.minimum(c0 + 1, self.width - 1)
        r1 = np.minimum(r0 + 1, self.height - 1)
        fc, fr = c - c0, r - r0
        v = self.values
        total = np.zeros_like(c)
        for rr, cc, w in ((r0, c0, (1 - fr) * (1 - fc)), (r0, c1, (1 - fr) * fc),
                          (r1, c0, fr * (1 - fc)), (r1, c1, fr * fc)):
            s = v[rr, cc]
            used = w > 1e-9
            total = total + np.where(used, s * w, 0.0)
            total = np.where(used & np.isnan(s), np.nan, total)
        return total


def affine(t, u, v):
    """An affine georeference applied to arrays (column, row) -> (x, y), or its inverse."""
    return t.a * u + t.b * v + t.c, t.d * u + t.e * v + t.f


def terrain_rgb(path, width, height):
    """Mapbox terrain-RGB: -10000 + (R*65536 + G*256 + B) * 0.1 metres."""
    with warnings.catch_warnings():
        # A PNG has no georeference: the VRT gives it.
        warnings.simplefilter("ignore", rasterio.errors.NotGeoreferencedWarning)
        ds = rasterio.open(path)
    with ds:
        if ds.count < 3 or (ds.width, ds.height) != (width, height):
            raise CheckError(f"{path}: not a {width} x {height} RGB image")
        rgb = ds.read([1, 2, 3]).astype(float)
    return -10000.0 + (rgb[0] * 65536.0 + rgb[1] * 256.0 + rgb[2]) * 0.1


# ---------------------------------------------------------------------------------------------
# 3D Tiles and glTF


def column_major(m, what):
    if not isinstance(m, list) or len(m) != 16:
        raise CheckError(f"{what}: a transform is 16 numbers, got {m!r}")
    return np.array(m, dtype=float).reshape(4, 4).T


def translation(t):
    m = np.eye(4)
    m[:3, 3] = t
    return m


def node_matrix(node):
    if "matrix" in node:
        return column_major(node["matrix"], "glTF node matrix")
    t = translation(node.get("translation", [0.0, 0.0, 0.0]))
    x, y, z, w = node.get("rotation", [0.0, 0.0, 0.0, 1.0])
    r = np.eye(4)
    r[:3, :3] = [[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                 [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                 [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]]
    s = np.diag(list(node.get("scale", [1.0, 1.0, 1.0])) + [1.0])
    return t @ r @ s


class Tile:
    def __init__(self, world, error, contents, leaf, where):
        self.world, self.error, self.contents, self.leaf, self.where = world, error, contents, leaf, where


def uri_path(base, uri):
    u = urllib.parse.urlsplit(uri)
    if u.scheme or u.netloc:
        raise CheckError(f"content URI {uri!r} is not relative to the tileset folder")
    return (base / urllib.parse.unquote(u.path)).resolve()


def walk_tileset(path):
    """Every tile of a tileset and its external tilesets: world transform (3D Tiles 1.1: a
    tile's transform is relative to its parent's; an external tileset's root is relative to the
    tile that references it), geometricError, glTF contents, and whether it is a leaf."""
    tiles = []
    seen = set()

    def load(p):
        if p in seen:
            raise CheckError(f"{p}: external tileset referenced twice (a cycle?)")
        seen.add(p)
        try:
            doc = json.loads(p.read_text())
        except (OSError, ValueError) as e:
            raise CheckError(f"{p}: {e}") from e
        version = doc.get("asset", {}).get("version")
        if version not in ("1.0", "1.1"):
            raise CheckError(f"{p}: asset.version {version!r} is not 3D Tiles 1.0 or 1.1")
        return doc

    def walk(tile, parent, base, where):
        if "implicitTiling" in tile:
            raise CheckError(f"{where}: implicit tiling is not read by this checker")
        world = parent @ column_major(tile["transform"], where) if "transform" in tile else parent
        contents = [tile["content"]] if "content" in tile else list(tile.get("contents", []))
        gltf, external = [], 0
        for c in contents:
            uri = c.get("uri", c.get("url"))
            if not uri:
                raise CheckError(f"{where}: content without a uri")
            p = uri_path(base, uri)
            if p.suffix.lower() == ".json":
                doc = load(p)
                walk(doc["root"], world, p.parent, f"{p}#root")
                external += 1
            else:
                gltf.append(p)
        children = tile.get("children", [])
        for i, ch in enumerate(children):
            walk(ch, world, base, f"{where}/children/{i}")
        tiles.append(Tile(world, float(tile.get("geometricError", 0.0)), gltf, not children and not external, where))

    root_path = Path(path).resolve()
    doc = load(root_path)
    walk(doc["root"], np.eye(4), root_path.parent, f"{root_path}#root")
    return tiles


def parse_glb(b, where):
    if len(b) < 12:
        raise CheckError(f"{where}: {len(b)} bytes, shorter than a GLB header")
    magic, version, length = struct.unpack("<4sII", b[:12])
    if magic != b"glTF" or version != 2:
        raise CheckError(f"{where}: not a glTF 2.0 binary (magic {magic!r}, version {version})")
    if length > len(b):
        raise CheckError(f"{where}: header says {length} bytes, the file has {len(b)}")
    off, doc, binary = 12, None, b""
    while off + 8 <= length:
        clen, ctype = struct.unpack("<II", b[off:off + 8])
        chunk = b[off + 8:off + 8 + clen]
        if len(chunk) != clen:
            raise CheckError(f"{where}: chunk at byte {off} runs past the end")
        if ctype == 0x4E4F534A:
            doc = json.loads(chunk)
        elif ctype == 0x004E4942 and not binary:
            binary = chunk
        off += 8 + clen
    if doc is None:
        raise CheckError(f"{where}: no JSON chunk")
    return doc, binary


def gltf_buffers(doc, binary, base, where):
    out = []
    for i, buf in enumerate(doc.get("buffers", [])):
        uri = buf.get("uri")
        if uri is None:
            if i != 0:
                raise CheckError(f"{where}: buffer {i} has no uri (only buffer 0 is the GLB's BIN chunk)")
            data = binary
        elif uri.startswith("data:"):
            import base64
            data = base64.b64decode(uri.split(",", 1)[1])
        else:
            data = uri_path(base, uri).read_bytes()
        if len(data) < buf.get("byteLength", 0):
            raise CheckError(f"{where}: buffer {i} has {len(data)} bytes, byteLength says {buf['byteLength']}")
        out.append(data)
    return out


def read_accessor(doc, buffers, index, where):
    try:
        a = doc["accessors"][index]
    except (IndexError, KeyError, TypeError) as e:
        raise CheckError(f"{where}: no accessor {index}") from e
    ct, count = a["componentType"], a["count"]
    if ct not in COMPONENT:
        raise CheckError(f"{where}: accessor {index} has componentType {ct}")
    n = N_COMPONENTS[a["type"]]
    dt = np.dtype(COMPONENT[ct])

    def view(bv_index, offset, dtype, ncomp, cnt):
        bv = doc["bufferViews"][bv_index]
        buf = buffers[bv["buffer"]]
        start = bv.get("byteOffset", 0) + offset
        esize = dtype.itemsize * ncomp
        stride = bv.get("byteStride") or esize
        end = start + stride * (cnt - 1) + esize if cnt else start
        if end > bv.get("byteOffset", 0) + bv["byteLength"] or end > len(buf):
            raise CheckError(f"{where}: accessor {index} runs past its bufferView")
        if cnt == 0:
            return np.zeros((0, ncomp), dtype)
        return np.ndarray((cnt, ncomp), dtype=dtype, buffer=buf, offset=start, strides=(stride, dtype.itemsize)).copy()

    arr = view(a["bufferView"], a.get("byteOffset", 0), dt, n, count) if "bufferView" in a else np.zeros((count, n), dt)
    if "sparse" in a:
        s = a["sparse"]
        idt = np.dtype(COMPONENT[s["indices"]["componentType"]])
        idx = view(s["indices"]["bufferView"], s["indices"].get("byteOffset", 0), idt, 1, s["count"])[:, 0]
        vals = view(s["values"]["bufferView"], s["values"].get("byteOffset", 0), dt, n, s["count"])
        arr[idx.astype(np.int64)] = vals
    out = arr.astype(float)
    if a.get("normalized"):
        if ct not in NORMALIZE:
            raise CheckError(f"{where}: accessor {index} is normalized with componentType {ct}")
        d, signed = NORMALIZE[ct]
        out = np.maximum(out / d, -1.0) if signed else out / d
    return out


def triangles_of(mode, idx):
    if mode == 4:
        return idx[: len(idx) // 3 * 3].reshape(-1, 3)
    if mode == 5:
        t = [(idx[i], idx[i + 1], idx[i + 2]) if i % 2 == 0 else (idx[i + 1], idx[i], idx[i + 2]) for i in range(len(idx) - 2)]
        return np.array(t, dtype=np.int64).reshape(-1, 3)
    if mode == 6:
        return np.array([(idx[0], idx[i], idx[i + 1]) for i in range(1, len(idx) - 1)], dtype=np.int64).reshape(-1, 3)
    return None


def read_content(path, world):
    """Primitives of one content file as (mode, ECEF positions, triangles or None)."""
    where = str(path)
    try:
        b = path.read_bytes()
    except OSError as e:
        raise CheckError(f"{where}: {e}") from e
    rtc = None
    if b[:4] == b"b3dm":
        _, _, length, ftj, ftb, btj, btb = struct.unpack("<4s6I", b[:28])
        ft = json.loads(b[28:28 + ftj] or b"{}")
        if "RTC_CENTER" in ft:
            rtc = ft["RTC_CENTER"]
        doc, binary = parse_glb(b[28 + ftj + ftb + btj + btb:length], where)
        base = path.parent
    elif b[:4] == b"glTF":
        doc, binary = parse_glb(b, where)
        base = path.parent
    elif b[:4] in (b"pnts", b"i3dm", b"cmpt"):
        raise CheckError(f"{where}: {b[:4].decode()} content is not read by this checker")
    elif b.lstrip()[:1] == b"{":
        doc, binary, base = json.loads(b), b"", path.parent
    else:
        raise CheckError(f"{where}: unknown content (starts with {b[:4]!r})")

    version = doc.get("asset", {}).get("version")
    if version != "2.0":
        raise CheckError(f"{where}: glTF asset.version {version!r}, not 2.0")
    used = set(doc.get("extensionsUsed", [])) | set(doc.get("extensionsRequired", []))
    for ext in sorted(used):
        if ext in GEOMETRY_EXTENSIONS:
            raise CheckError(f"{where}: uses {ext} ({GEOMETRY_EXTENSIONS[ext]}), which this checker does not decode")
    for ext in sorted(set(doc.get("extensionsRequired", [])) - HARMLESS_EXTENSIONS):
        raise CheckError(f"{where}: requires the unknown extension {ext}")
    rtc = doc.get("extensions", {}).get("CESIUM_RTC", {}).get("center", rtc)
    top = world @ (translation(rtc) if rtc is not None else np.eye(4)) @ Y_UP_TO_Z_UP
    buffers = gltf_buffers(doc, binary, base, where)

    scenes = doc.get("scenes", [])
    if not scenes:
        raise CheckError(f"{where}: no scene")
    roots = scenes[doc.get("scene", 0)].get("nodes", [])
    nodes = doc.get("nodes", [])
    prims = []
    stack = [(i, top, 0) for i in roots]
    while stack:
        i, parent, depth = stack.pop()
        if depth > 64:
            raise CheckError(f"{where}: node hierarchy deeper than 64 (a cycle?)")
        node = nodes[i]
        m = parent @ node_matrix(node)
        if "mesh" in node:
            for p in doc["meshes"][node["mesh"]]["primitives"]:
                if "POSITION" not in p.get("attributes", {}):
                    continue
                if "extensions" in p and set(p["extensions"]) & set(GEOMETRY_EXTENSIONS):
                    raise CheckError(f"{where}: a primitive uses {sorted(p['extensions'])}, not decoded here")
                pos = read_accessor(doc, buffers, p["attributes"]["POSITION"], where)
                if pos.shape[1] != 3:
                    raise CheckError(f"{where}: POSITION is not VEC3")
                ecef = pos @ m[:3, :3].T + m[:3, 3]
                mode = p.get("mode", 4)
                idx = (read_accessor(doc, buffers, p["indices"], where)[:, 0].astype(np.int64)
                       if "indices" in p else np.arange(len(pos)))
                if len(idx) and (idx.min() < 0 or idx.max() >= len(pos)):
                    raise CheckError(f"{where}: an index is out of range")
                prims.append((mode, ecef, triangles_of(mode, idx)))
        for ch in node.get("children", []):
            stack.append((ch, m, depth + 1))
    return prims


# ---------------------------------------------------------------------------------------------
# Checks


def to_llh(p):
    lon, lat, h = TO_LLH.transform(p[:, 0], p[:, 1], p[:, 2])
    return np.asarray(lon, float), np.asarray(lat, float), np.asarray(h, float)


def to_ecef(lon, lat, h):
    x, y, z = TO_ECEF.transform(lon, lat, h)
    return np.stack([np.asarray(x, float), np.asarray(y, float), np.asarray(z, float)], axis=-1)


def find_skirts(p, h, tris, threshold, max_offset):
    """Skirt vertices of one mesh tile (see README): a vertex on the border of the tile's mesh
    (an edge of it belongs to one triangle only) that shares a triangle with a vertex lying more
    than `threshold` above it and directly below it: horizontally within SKIRT_CONE of the
    height difference and within `max_offset` (a fraction of the raster's sample spacing). A
    heightfield TIN has one vertex per horizontal position, its neighbours a sample or more
    apart, and its interior vertices on no border, so only walls hanging from the border
    qualify."""
    n = len(p)
    skirt = np.zeros(n, bool)
    if tris is None or len(tris) == 0:
        return skirt
    e = np.concatenate([tris[:, [0, 1]], tris[:, [1, 2]], tris[:, [2, 0]]])
    uniq, counts = np.unique(np.sort(e, axis=1), axis=0, return_counts=True)
    border = np.zeros(n, bool)
    border[uniq[counts == 1].ravel()] = True
    both = np.concatenate([e, e[:, ::-1]])  # (upper, lower) both ways
    up, lo = both[:, 0], both[:, 1]
    dh = h[up] - h[lo]
    d2 = np.sum((p[up] - p[lo]) ** 2, axis=1)
    horiz = np.sqrt(np.maximum(d2 - dh * dh, 0.0))
    under = (dh > threshold) & (horiz < SKIRT_CONE * dh) & (horiz < max_offset)
    skirt[lo[under]] = True
    return skirt & border


def sample_spacing(sources):
    """The smallest ground distance (m) between neighbouring sample centres of the files, taken
    at each file's centre and corners (distances under 1 mm, e.g. along a row on a pole, left
    out)."""
    best = math.inf
    for s in sources:
        cs = np.array([0, s.width - 1, 0, s.width - 1, (s.width - 1) // 2], float)
        rs = np.array([0, 0, s.height - 1, s.height - 1, (s.height - 1) // 2], float)
        a = to_ecef(*s.sample_lonlat(cs, rs), np.zeros(5))
        for dc, dr in ((1, 0), (0, 1)):
            c2 = np.where(cs + dc > s.width - 1, cs - dc, cs + dc)
            r2 = np.where(rs + dr > s.height - 1, rs - dr, rs + dr)
            b = to_ecef(*s.sample_lonlat(c2, r2), np.zeros(5))
            d = np.linalg.norm(a - b, axis=1)
            d = d[d > 1e-3]
            if len(d):
                best = min(best, float(d.min()))
    return best


def nearest_distance(targets, points, horizontal_only=None):
    """Distance from each target to its nearest point (ECEF metres). Where horizontal_only is
    true the height difference (ellipsoidal, taken from `hp` / `ht`) is removed."""
    out = np.full(len(targets), np.inf)
    for i, t in enumerate(targets):
        d2 = np.sum((points - t) ** 2, axis=1)
        if horizontal_only is not None and horizontal_only[0][i]:
            ht, hp = horizontal_only[1][i], horizontal_only[2]
            d2 = np.maximum(d2 - (hp - ht) ** 2, 0.0)
        out[i] = math.sqrt(float(d2.min())) if len(d2) else math.inf
    return out


def expected_heights(sources, lon, lat, h, geoid, datum, ecef):
    """Per vertex: expected ellipsoidal height (nearest to the vertex among the candidates: the
    files that contain it, longitude shifts of geographic files, a whole pole row), whether it
    was inside a file, whether no-data decided it, and the horizontal offset to the nearest
    sample centre."""
    n = len(lon)
    best = np.full(n, np.nan)
    inside_any = np.zeros(n, bool)
    hoff = np.full(n, np.nan)
    undulation = geoid.undulation(lon, lat) if datum == "egm96" else np.zeros(n)
    at_pole = np.hypot(ecef[:, 0], ecef[:, 1]) < POLE_AXIS_M
    for s in sources:
        for c, r in s.locate(lon, lat):
            ins = s.inside(c, r)
            if not ins.any():
                continue
            inside_any |= ins
            v = np.full(n, np.nan)
            v[ins] = s.bilinear(c[ins], r[ins])
            if s.geographic and at_pole.any():
                # At a pole the longitude is arbitrary: any sample of a row on that pole is the
                # same point.
                for k in np.nonzero(at_pole & ins)[0]:
                    row = int(round(r[k]))
                    if abs(r[k] - row) < EDGE_EPS_PX:
                        vals = s.values[row]
                        vals = vals[~np.isnan(vals)]
                        if len(vals):
                            v[k] = vals[np.argmin(np.abs(vals + undulation[k] - h[k]))]
            exp = v + undulation
            better = ~np.isnan(exp) & (np.isnan(best) | (np.abs(h - exp) < np.abs(h - best)))
            if better.any():
                best[better] = exp[better]
                k = np.nonzero(better)[0]
                sc = np.clip(np.round(c[k]), 0, s.width - 1)
                sr = np.clip(np.round(r[k]), 0, s.height - 1)
                slon, slat = s.sample_lonlat(sc, sr)
                sp = to_ecef(slon, slat, h[k])
                hoff[k] = np.linalg.norm(sp - ecef[k], axis=1)
    return best, inside_any, hoff


def check_placement(entry, tileset, sources, geoid):
    """Figures of one exported tileset against its sources (dict)."""
    tiles = walk_tileset(tileset)
    datum = entry["datum"]
    if datum not in ("ellipsoid", "egm96"):
        raise CheckError(f"datum {datum!r}: no expected heights for it here")
    for s in sources:
        code = s.vertical.to_epsg() if s.vertical is not None else None
        if code is not None and {5773: "egm96"}.get(code) != datum:
            raise CheckError(f"{s.path.name}: its vertical CRS is EPSG:{code}, the manifest says {datum!r}")
    pts, hs, lons, lats, allowed, skirts = [], [], [], [], [], 0
    max_offset = SKIRT_MAX_OFFSET * sample_spacing(sources)
    finest = 0
    for t in tiles:
        if not t.leaf or not t.contents:
            continue
        prims = [pr for c in t.contents for pr in read_content(c, t.world)]
        meshes = [pr for pr in prims if pr[2] is not None]
        if not meshes:
            continue
        finest += 1
        p = np.concatenate([m[1] for m in meshes])
        offs = np.cumsum([0] + [len(m[1]) for m in meshes])
        tris = np.concatenate([m[2] + o for m, o in zip(meshes, offs)])
        lon, lat, h = to_llh(p)
        sk = find_skirts(p, h, tris, max(t.error, VERTEX_MARGIN_M), max_offset)
        used = np.zeros(len(p), bool)
        used[tris.ravel()] = True
        keep = used & ~sk
        skirts += int(sk.sum())
        pts.append(p[keep])
        hs.append(h[keep])
        lons.append(lon[keep])
        lats.append(lat[keep])
        allowed.append(np.full(int(keep.sum()), t.error + VERTEX_MARGIN_M))
    if not finest:
        raise CheckError("no leaf tile has a triangle mesh")
    p, h, lon, lat, allowed = (np.concatenate(a) for a in (pts, hs, lons, lats, allowed))
    if not len(p):
        raise CheckError("the finest mesh tiles have no vertex")

    # Corners: of each file, and of a mosaic only those on the corners of the union of its files
    # (a file corner inside the mosaic is an ordinary sample, which a TIN need not keep). The
    # union is taken in the files' own coordinates, longitudes unwrapped against the first file.
    def crs_xy(s, cols, rows):
        return affine(s.transform, np.asarray(cols, float) + 0.5, np.asarray(rows, float) + 0.5)

    def unwrap(s, x):
        if not s.geographic:
            return np.asarray(x, float)
        ref = crs_xy(sources[0], [(sources[0].width - 1) / 2], [0])[0][0]
        return np.asarray(x, float) + 360.0 * np.round((ref - np.asarray(x, float)) / 360.0)

    same_crs = all(s.crs == sources[0].crs for s in sources)
    if len(sources) > 1 and same_crs:
        xs, ys = [], []
        for s in sources:
            x, y = crs_xy(s, [0, s.width - 1], [0, s.height - 1])
            xs.extend(unwrap(s, x))
            ys.extend(np.asarray(y, float))
        union = (min(xs), max(xs), min(ys), max(ys))
        cell = abs(sources[0].transform.a)
    corner_rows = []
    if not same_crs:
        # A mosaic warped onto one grid: the files' own corners are not samples of it (their
        # grids turn against each other by the grid convergence). The target grid follows the
        # documented rule (docs/frames.md, "Warping"): the first file's CRS and cells, aligned to
        # its grid, covering the union of the files' sample-centre extents. Its four corners are
        # checked where a file covers them, their heights bilinear from that file.
        f0 = sources[0]
        tx, ty = [], []
        for s in sources:
            to_first = Transformer.from_crs(s.crs, f0.crs, always_xy=True)
            t = np.linspace(0.0, 1.0, 33)
            uu = np.concatenate([t, t, np.zeros_like(t), np.ones_like(t)]) * (s.width - 1)
            vv = np.concatenate([np.zeros_like(t), np.ones_like(t), t, t]) * (s.height - 1)
            x, y = crs_xy(s, uu, vv)
            x, y = to_first.transform(x, y)
            tx.extend(np.asarray(x, float))
            ty.extend(np.asarray(y, float))
        (ox, oy) = crs_xy(f0, [0], [0])
        ox, oy = float(ox[0]), float(oy[0])
        dx, dy = f0.transform.a, f0.transform.e
        x0 = ox + math.floor((min(tx) - ox) / dx) * dx
        y0 = oy + math.floor((max(ty) - oy) / dy) * dy
        cols = math.floor((max(tx) - x0) / dx) + 1
        rows = math.floor((y0 - min(ty)) / -dy) + 1
        xs = np.array([x0, x0 + (cols - 1) * dx, x0, x0 + (cols - 1) * dx])
        ys = np.array([y0, y0, y0 + (rows - 1) * dy, y0 + (rows - 1) * dy])
        clon, clat = f0.to_ll.transform(xs, ys)
        clon, clat = np.asarray(clon, float), np.asarray(clat, float)
        exp, inside, _ = expected_heights(sources, clon, clat, np.zeros(4), geoid, datum, to_ecef(clon, clat, np.zeros(4)))
        for k in range(4):
            if np.isnan(exp[k]):
                res_note = f"target corner {k} lies outside every file (filled no-data): not checked"
                corner_rows.append(dict(file="target grid", col=int(k % 2), row=int(k // 2), lon=float(clon[k]),
                                        lat=float(clat[k]), height=None, distance_m=0.0, horizontal_only=True,
                                        note=res_note))
                continue
            target = to_ecef(clon[k:k + 1], clat[k:k + 1], exp[k:k + 1])
            d = nearest_distance(target, p, (np.zeros(1, bool), exp[k:k + 1], h))
            corner_rows.append(dict(file="target grid", col=int(k % 2), row=int(k // 2), lon=float(clon[k]),
                                    lat=float(clat[k]), height=float(exp[k]), distance_m=float(d[0]),
                                    horizontal_only=False))
    for s in (sources if same_crs else []):
        cc = np.array([0, s.width - 1, 0, s.width - 1])
        rr = np.array([0, 0, s.height - 1, s.height - 1])
        if len(sources) > 1 and same_crs:
            x, y = crs_xy(s, cc, rr)
            x = unwrap(s, x)
            tol = 1e-6 * cell
            on = ((np.isclose(x, union[0], atol=tol) | np.isclose(x, union[1], atol=tol))
                  & (np.isclose(y, union[2], atol=tol) | np.isclose(y, union[3], atol=tol)))
            cc, rr = cc[on], rr[on]
            if not len(cc):
                continue
        clon, clat = s.sample_lonlat(cc, rr)
        v = s.values[rr, cc]
        nodata = np.isnan(v)
        und = geoid.undulation(clon, clat) if datum == "egm96" else np.zeros(len(cc))
        ch = np.where(nodata, 0.0, v + und)
        target = to_ecef(clon, clat, ch)
        d = nearest_distance(target, p, (nodata, ch, h))
        for k in range(len(cc)):
            corner_rows.append(dict(file=s.path.name, col=int(cc[k]), row=int(rr[k]), lon=float(clon[k]),
                                    lat=float(clat[k]), height=None if nodata[k] else float(ch[k]),
                                    distance_m=float(d[k]), horizontal_only=bool(nodata[k])))
    corner_max = max((c["distance_m"] for c in corner_rows), default=0.0)

    # Vertices.
    exp, inside, hoff = expected_heights(sources, lon, lat, h, geoid, datum, p)
    checked = ~np.isnan(exp)
    nodata_skipped = int((inside & ~checked).sum())
    outside = int((~inside).sum())
    err = h - exp
    over = checked & (np.abs(err) > allowed)
    worst = []
    if checked.any():
        order = np.argsort(-np.where(checked, np.abs(err) - allowed, -np.inf))[:5]
        worst = [dict(lon=float(lon[k]), lat=float(lat[k]), h=float(h[k]), expected=float(exp[k]),
                      allowed=float(allowed[k])) for k in order if checked[k]]
    abs_err = np.abs(err[checked])
    return dict(
        finest_tiles=finest, vertices=int(len(p)), skirt_vertices=skirts, checked=int(checked.sum()),
        nodata_skipped=nodata_skipped, outside=outside, over_tolerance=int(over.sum()),
        corner_max_m=corner_max, corners=corner_rows,
        vertical_max_m=float(abs_err.max()) if len(abs_err) else None,
        vertical_median_m=float(np.median(abs_err)) if len(abs_err) else None,
        allowed_max_m=float(allowed.max()), allowed_min_m=float(allowed.min()),
        horizontal_offset_max_m=float(np.nanmax(hoff)) if checked.any() else None,
        horizontal_offset_median_m=float(np.nanmedian(hoff)) if checked.any() else None,
        worst=worst,
    )


# ---------------------------------------------------------------------------------------------
# Driver


def known_flags(binary, sub):
    out = subprocess.run([binary, sub, "--help"], capture_output=True, text=True, timeout=60)
    return set(re.findall(r"--[a-z0-9][a-z0-9-]*", out.stdout + out.stderr))


def drop_unknown(args, known):
    kept, dropped, i = [], [], 0
    while i < len(args):
        a = args[i]
        if a.startswith("--") and a not in known:
            dropped.append(a)
            i += 2 if i + 1 < len(args) and not args[i + 1].startswith("-") else 1
            continue
        kept.append(a)
        i += 1
    return kept, dropped


def message_of(proc):
    text = (proc.stderr or "") + (proc.stdout or "")
    lines = [ln.strip() for ln in text.splitlines() if ln.strip()]
    errs = [ln for ln in lines if re.match(r"(?i)^(error|caused by)", ln)]
    return " | ".join(errs or lines[-2:])[:400]


def run(cmd, timeout):
    t0 = time.monotonic()
    try:
        p = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout)
    except subprocess.TimeoutExpired:
        return None, time.monotonic() - t0
    return p, time.monotonic() - t0


def check_one(entry, args, geoid, bake_known):
    name = entry["name"]
    work = args.work / name
    if work.exists():
        shutil.rmtree(work)
    work.mkdir(parents=True)
    res = dict(name=name, crs=entry["crs"], datum=entry["datum"], notes=[])
    files = [str(Path(f) if Path(f).is_absolute() else args.inputs / f) for f in entry["files"]]
    bake_args = list(entry["bake_args"])
    if args.lenient_flags:
        bake_args, dropped = drop_unknown(bake_args, bake_known)
        if dropped:
            res["notes"].append(f"flags unknown to this binary, left out: {' '.join(dropped)}")
    store, out3d = work / "store", work / "3dtiles"
    bake = [str(args.bin), "bake", *files, "--out", str(store), *bake_args, "-q"]
    res["bake_cmd"] = " ".join(bake)
    p, dt = run(bake, args.timeout)
    res["bake_s"] = round(dt, 1)
    refusal = entry.get("expect_refusal")
    if p is None:
        return fail(res, f"bake ran past {args.timeout} s")
    if p.returncode != 0:
        msg = message_of(p)
        if refusal:
            missing = [s for s in refusal["contains"] if s not in (p.stderr + p.stdout)]
            if missing:
                return fail(res, f"refused, but the message does not name {missing}: {msg}")
            res["notes"].append(f"refused as expected: {msg}")
            res["result"] = "PASS"
            return res
        return fail(res, f"bake refused it: {msg}")
    if refusal:
        return fail(res, f"expected a refusal naming {refusal['contains']}; the bake succeeded")
    export = [str(args.bin), "export", str(store), "--format", "3dtiles", "--out", str(out3d), "-q"]
    p, dt = run(export, args.timeout)
    res["export_s"] = round(dt, 1)
    if p is None:
        return fail(res, f"export ran past {args.timeout} s")
    if p.returncode != 0:
        return fail(res, f"export failed: {message_of(p)}")
    try:
        sources = [Source(f, entry.get("heights")) for f in files]
        for s in sources:
            desc = s.to_ll.description
            if s.to_ll.accuracy not in (0.0, -1.0) or "Ballpark" in desc:
                res["notes"].append(f"{Path(s.path).name} -> WGS 84 by PROJ: {desc} (accuracy {s.to_ll.accuracy} m)")
        t0 = time.monotonic()
        res.update(check_placement(entry, out3d / "tileset.json", sources, geoid))
        res["check_s"] = round(time.monotonic() - t0, 1)
    except CheckError as e:
        return fail(res, str(e))
    why = []
    if res["corner_max_m"] > CORNER_TOL_M:
        why.append(f"a corner is {res['corner_max_m']:.3f} m from the nearest vertex (> {CORNER_TOL_M} m)")
    if res["over_tolerance"]:
        why.append(f"{res['over_tolerance']} of {res['checked']} vertices beyond geometricError + {VERTEX_MARGIN_M} m")
    if res["outside"] and not entry.get("warped"):
        why.append(f"{res['outside']} vertices lie outside the raster")
    elif res["outside"]:
        res["notes"].append(f"{res['outside']} vertices outside every file (a warped mosaic's target grid)")
    if res["checked"] == 0:
        why.append("no vertex could be checked")
    if res["nodata_skipped"]:
        res["notes"].append(f"{res['nodata_skipped']} vertices next to no-data samples not checked")
    if why:
        return fail(res, "; ".join(why))
    res["result"] = "PASS"
    return res


def fail(res, why):
    res["result"] = "FAIL"
    res["why"] = why
    return res


def fmt(v, digits=3):
    if v is None:
        return "-"
    if v >= 1e5:
        return f"{v:.3g}"
    return f"{v:.{digits}f}"


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--bin", required=True, type=Path, help="the terrastream binary")
    ap.add_argument("--inputs", required=True, type=Path, help="folder written by make_inputs.py")
    ap.add_argument("--work", required=True, type=Path, help="folder for stores, exports and report.json")
    ap.add_argument("--only", help="comma-separated input names")
    ap.add_argument("--timeout", type=float, default=300.0, help="seconds one bake or export may take")
    ap.add_argument("--lenient-flags", action="store_true",
                    help="leave out bake flags the binary does not know (said in the row's notes)")
    args = ap.parse_args()
    args.inputs = args.inputs.resolve()
    args.work = args.work.resolve()
    args.work.mkdir(parents=True, exist_ok=True)
    manifest = json.loads((args.inputs / "manifest.json").read_text())
    geoid = Geoid(manifest.get("geoid", GEOID_GTX))
    diff = geoid.self_check()
    if diff > 1e-3:
        sys.exit(f"EGM96 bilinear read of {geoid.path} differs from PROJ vgridshift by {diff} m")
    entries = manifest["inputs"]
    if args.only:
        names = set(args.only.split(","))
        unknown = names - {e["name"] for e in entries}
        if unknown:
            sys.exit(f"--only: no input named {sorted(unknown)} in the manifest")
        entries = [e for e in entries if e["name"] in names]
    bake_known = known_flags(args.bin, "bake")
    cols = ["input", "CRS", "datum", "corners m", "vert max m", "vert med m", "allowed m", "vertices",
            "hoff max m", "time s", "result"]
    widths = [20, 24, 9, 10, 10, 10, 9, 9, 10, 7, 6]
    print(" ".join(c.ljust(w) for c, w in zip(cols, widths)), flush=True)
    results = []
    for e in entries:
        t0 = time.monotonic()
        r = check_one(e, args, geoid, bake_known)
        r["total_s"] = round(time.monotonic() - t0, 1)
        results.append(r)
        row = [r["name"], r["crs"], r["datum"], fmt(r.get("corner_max_m")), fmt(r.get("vertical_max_m")),
               fmt(r.get("vertical_median_m")), fmt(r.get("allowed_max_m")),
               str(r.get("checked", "-")), fmt(r.get("horizontal_offset_max_m")), f"{r['total_s']:.0f}", r["result"]]
        print(" ".join(str(c)[:w].ljust(w) for c, w in zip(row, widths)), flush=True)
        for n in r["notes"]:
            print(f"    note: {n}", flush=True)
        if r["result"] == "FAIL":
            print(f"    FAIL: {r['why']}", flush=True)
    (args.work / "report.json").write_text(json.dumps(results, indent=2) + "\n")
    passed = sum(r["result"] == "PASS" for r in results)
    failed = len(results) - passed
    print(f"{passed} passed, {failed} failed (details: {args.work / 'report.json'})")
    sys.exit(1 if failed else 0)


if __name__ == "__main__":
    main()
