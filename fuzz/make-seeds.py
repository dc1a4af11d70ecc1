#!/usr/bin/env python3
"""Writes the hand-made seed inputs under fuzz/seeds/<target>/: tiny valid files of every
format and variant the decoders handle (so the fuzzer starts inside each parser rather than
at its magic-number check). Blob, manifest and index-chunk seeds come from a real bake; see
fuzz/README.md. Deterministic: run it again and nothing changes."""
import os, struct, zlib, json, sys

ROOT = os.path.join(os.path.dirname(os.path.abspath(__file__)), "seeds")

def put(target, name, data):
    d = os.path.join(ROOT, target)
    os.makedirs(d, exist_ok=True)
    if isinstance(data, str):
        data = data.encode()
    with open(os.path.join(d, name), "wb") as f:
        f.write(data)

# ---- PNG ----
def chunk(t, d):
    return struct.pack(">I", len(d)) + t + d + struct.pack(">I", zlib.crc32(t + d) & 0xffffffff)

def png(w, h, depth, color, rows, extra=b""):
    raw = b"".join(b"\0" + r for r in rows)
    return (b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", struct.pack(">IIBBBBB", w, h, depth, color, 0, 0, 0))
            + extra + chunk(b"IDAT", zlib.compress(raw)) + chunk(b"IEND", b""))

g16 = [b"".join(struct.pack(">H", (x * 300 + y * 7) & 0xffff) for x in range(4)) for y in range(3)]
put("raster_png_gray", "gray16.png", png(4, 3, 16, 0, g16))
put("raster_png_gray", "gray8.png", png(5, 2, 8, 0, [bytes(range(y, y + 5)) for y in range(2)]))
put("raster_png_gray", "gray16-ga.png", png(2, 2, 16, 4, [b"\x01\x00\xff\xff\x02\x00\x00\x00"] * 2))
rgb = [bytes([1, 134, 160 + x, 1, 135, x] * 1)[:3] * 1 for x in range(3)]
rgb_rows = [b"".join(bytes([1, 134 + y, (x * 40) & 255]) for x in range(3)) for y in range(3)]
rgba_rows = [b"".join(bytes([128, y, x, 255]) for x in range(2)) for y in range(2)]
for t in ("raster_png_terrain_rgb", "raster_png_terrarium"):
    put(t, "rgb.png", png(3, 3, 8, 2, rgb_rows))
    put(t, "rgba.png", png(2, 2, 8, 6, rgba_rows))
    put(t, "palette.png", png(2, 1, 8, 3, [b"\x00\x01"], chunk(b"PLTE", b"\x01\x86\xa0\x80\x00\x00")))
put("raster_png_gray", "interlaced-gray16.png",
    b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", struct.pack(">IIBBBBB", 3, 3, 16, 0, 0, 0, 1))
    + chunk(b"IDAT", zlib.compress(b"\0\x00\x10" + b"\0\x00\x20" + b"\0\x00\x30\x00\x40" + b"\0\x00\x50\x00\x60" * 1
                                   + b"\0\x00\x70\x00\x80\x00\x90" + b"\0" * 20)) + chunk(b"IEND", b""))

# ---- TIFF / GeoTIFF (little and big endian, strips and tiles, several sample types) ----
def tiff(w, h, fmt, bps, data, be=False, geo=True, tiled=False, nodata=None, geographic=False, transform=False):
    e = ">" if be else "<"
    entries = []
    def tag(t, typ, vals):
        entries.append((t, typ, vals))
    tag(256, 3, [w]); tag(257, 3, [h]); tag(258, 3, [bps]); tag(259, 3, [1]); tag(262, 3, [1])
    tag(277, 3, [1]); tag(284, 3, [1]); tag(339, 3, [fmt])
    if tiled:
        tag(322, 3, [16]); tag(323, 3, [16])
        tile = bytearray(16 * 16 * (bps // 8))
        rb = w * (bps // 8)
        for y in range(h):
            tile[y * 16 * (bps // 8): y * 16 * (bps // 8) + rb] = data[y * rb:(y + 1) * rb]
        payload = bytes(tile)
        tag(324, 4, ["DATA"]); tag(325, 4, [len(payload)])
    else:
        payload = data
        tag(273, 4, ["DATA"]); tag(278, 3, [h]); tag(279, 4, [len(payload)])
    if geo:
        if transform:
            tag(34264, 12, [10.0, 0, 0, 500.0, 0, -10.0, 0, 900.0, 0, 0, 1, 0, 0, 0, 0, 1])
        else:
            s = 0.001 if geographic else 30.0
            tag(33550, 12, [s, s, 0.0])
            tag(33922, 12, [0, 0, 0, 138.5 if geographic else 350000.0, 35.5 if geographic else 3900000.0, 0])
        model = 2 if geographic else 1
        tag(34735, 3, [1, 1, 0, 2, 1024, 0, 1, model, 1025, 0, 1, 1])
    if nodata is not None:
        tag(42113, 2, nodata)
    entries.sort()
    sizes = {2: 1, 3: 2, 4: 4, 12: 8}
    codes = {3: "H", 4: "I", 12: "d"}
    n = len(entries)
    ifd_off = 8
    ext_off = ifd_off + 2 + n * 12 + 4
    ext = bytearray()
    data_off = None
    body = bytearray()
    fixups = []
    for t, typ, vals in entries:
        if typ == 2:
            raw = vals.encode() + b"\0"
            cnt = len(raw)
        else:
            cnt = len(vals)
            raw = b"".join(struct.pack(e + codes[typ], 0 if v == "DATA" else v) for v in vals)
        if len(raw) <= 4:
            field = raw.ljust(4, b"\0")
            pos = None
        else:
            pos = ext_off + len(ext)
            ext += raw
            if len(ext) % 2: ext += b"\0"
            field = struct.pack(e + "I", pos)
        body += struct.pack(e + "HHI", t, typ, cnt) + field
        if vals == ["DATA"]:
            fixups.append(len(body) - 4)
    data_off = ext_off + len(ext)
    for f in fixups:
        body[f:f + 4] = struct.pack(e + "I", data_off)
    head = (b"MM\0*" if be else b"II*\0") + struct.pack(e + "I", ifd_off)
    return head + struct.pack(e + "H", n) + bytes(body) + struct.pack(e + "I", 0) + bytes(ext) + payload

w, h = 4, 3
f32 = b"".join(struct.pack("<f", 100.0 + i * 1.5) for i in range(w * h))
put("raster_geotiff", "f32-strip.tif", tiff(w, h, 3, 32, f32))
put("raster_geotiff", "f32-nodata.tif", tiff(w, h, 3, 32, f32[:-4] + struct.pack("<f", -9999.0), nodata="-9999"))
put("raster_geotiff", "f32-tiled.tif", tiff(w, h, 3, 32, f32, tiled=True))
put("raster_geotiff", "f32-geographic.tif", tiff(w, h, 3, 32, f32, geographic=True))
put("raster_geotiff", "f32-transform.tif", tiff(w, h, 3, 32, f32, transform=True))
be16 = b"".join(struct.pack(">h", i * 10 - 30) for i in range(w * h))
put("raster_geotiff", "i16-be.tif", tiff(w, h, 2, 16, be16, be=True))
put("raster_geotiff", "u8-plain.tif", tiff(w, h, 1, 8, bytes(range(w * h)), geo=False))
put("raster_geotiff", "f64.tif", tiff(2, 2, 3, 64, b"".join(struct.pack("<d", v) for v in (1, 2, 3, 4))))
put("raster_geotiff", "u32.tif", tiff(2, 2, 1, 32, b"".join(struct.pack("<I", v) for v in (1, 2, 3, 4))))

# ---- OpenEXR: scanline, one FLOAT or HALF channel, no compression or zip ----
def exr(w, h, ptype, values, name=b"Z", compression=0):
    def attr(n, t, v):
        return n + b"\0" + t + b"\0" + struct.pack("<i", len(v)) + v
    ch = name + b"\0" + struct.pack("<iBBBBii", ptype, 0, 0, 0, 0, 1, 1) + b"\0"
    hdr = (attr(b"channels", b"chlist", ch) + attr(b"compression", b"compression", bytes([compression]))
           + attr(b"dataWindow", b"box2i", struct.pack("<iiii", 0, 0, w - 1, h - 1))
           + attr(b"displayWindow", b"box2i", struct.pack("<iiii", 0, 0, w - 1, h - 1))
           + attr(b"lineOrder", b"lineOrder", b"\0")
           + attr(b"pixelAspectRatio", b"float", struct.pack("<f", 1.0))
           + attr(b"screenWindowCenter", b"v2f", struct.pack("<ff", 0, 0))
           + attr(b"screenWindowWidth", b"float", struct.pack("<f", 1.0)) + b"\0")
    size = 4 if ptype == 2 else 2
    lines_per_block = 1 if compression in (0, 2) else 16
    blocks = []
    for y0 in range(0, h, lines_per_block):
        rows = b""
        for y in range(y0, min(h, y0 + lines_per_block)):
            for x in range(w):
                v = values[y * w + x]
                rows += struct.pack("<f", v) if ptype == 2 else struct.pack("<e", v)
        if compression == 3:
            # ZIP: predictor + interleave, then zlib.
            t = bytearray(len(rows))
            half = (len(rows) + 1) // 2
            t[:half] = rows[0::2]; t[half:] = rows[1::2]
            p = t[0]
            out = bytearray([t[0]])
            for b in t[1:]:
                out.append((b - p + 128 + 256) & 255); p = b
            rows = zlib.compress(bytes(out))
        blocks.append(struct.pack("<ii", y0, len(rows)) + rows)
    start = 8 + len(hdr) + 8 * len(blocks)
    table, off = b"", start
    for b in blocks:
        table += struct.pack("<Q", off); off += len(b)
    return b"\x76\x2f\x31\x01" + struct.pack("<I", 2) + hdr + table + b"".join(blocks)

vals = [10.0 + i for i in range(12)]
put("raster_openexr", "f32-z.exr", exr(4, 3, 2, vals))
put("raster_openexr", "f16-z.exr", exr(4, 3, 1, vals))
put("raster_openexr", "f32-other-name.exr", exr(3, 2, 2, vals[:6], name=b"height"))
put("raster_openexr", "f32-zip.exr", exr(4, 3, 2, vals, compression=3))

# ---- HGT: name line then data; with `!` the first data byte picks a side 2..=129 and the ----
# ---- rest is repeated to side² samples (see fuzz_targets/raster_hgt.rs) ----
put("raster_hgt", "tile-N35E138", b"N35E138.hgt!\n" + bytes([14]) + struct.pack(">hhhh", 1, 2, 3, -32768))
put("raster_hgt", "tile-s12w077", b"s12w077.SRTMGL1.hgt!\n" + bytes([127]) + struct.pack(">hh", 500, 501))
put("raster_hgt", "short", b"N00E000.hgt\n" + b"\0" * 16)
put("raster_hgt", "bad-name", b"elevation.hgt!\n\0\1")

# ---- models ----
put("model_obj", "tri.obj", "# t\nv 0 0 0\nv 1 0 0\nv 0 1 0\nvn 0 0 1\nf 1//1 2//1 3//1\n")
put("model_obj", "quad.obj", "o q\nv 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 1e-3\nvt 0 0\nf -4/1 -3/1 -2/1 -1/1\ng x\nusemtl m\ns 1\nl 1 2\n")
put("model_stl", "ascii.stl", "solid t\nfacet normal 0 0 1\nouter loop\nvertex 0 0 0\nvertex 1 0 0\nvertex 0 1 0\nendloop\nendfacet\n"
    "facet normal 0 0 1\nouter loop\nvertex 1 0 0\nvertex 1 1 0\nvertex 0 1 0\nendloop\nendfacet\nendsolid t\n")
tri = lambda n, a, b, c: struct.pack("<12fH", *n, *a, *b, *c, 0)
put("model_stl", "binary.stl", b"binary stl".ljust(80, b" ") + struct.pack("<I", 2)
    + tri((0, 0, 1), (0, 0, 0), (1, 0, 0), (0, 1, 0)) + tri((0, 0, 1), (1, 0, 0), (1, 1, 0), (0, 1, 0)))
ply_head = lambda fmt, extra="": (f"ply\nformat {fmt} 1.0\ncomment c\nelement vertex 4\nproperty float x\nproperty float y\n"
    f"property float z\nproperty float nx\nproperty float ny\nproperty float nz\n{extra}element face 2\n"
    "property list uchar int vertex_indices\nend_header\n")
vs = [(0, 0, 0), (1, 0, 0), (1, 1, 0), (0, 1, 0)]
put("model_ply", "ascii.ply", ply_head("ascii") + "".join(f"{x} {y} {z} 0 0 1\n" for x, y, z in vs) + "3 0 1 2\n4 0 2 3 1\n")
for fmt, e in (("binary_little_endian", "<"), ("binary_big_endian", ">")):
    body = b"".join(struct.pack(e + "6f", *v, 0, 0, 1) for v in vs)
    body += struct.pack(e + "B3i", 3, 0, 1, 2) + struct.pack(e + "B3i", 3, 0, 2, 3)
    put("model_ply", f"{fmt}.ply", ply_head(fmt).encode() + body)
put("model_ply", "ascii-extra.ply", "ply\nformat ascii 1.0\nelement vertex 3\nproperty double x\nproperty double y\nproperty double z\n"
    "property uchar red\nelement face 1\nproperty list uint8 uint32 vertex_index\nelement edge 0\nproperty int a\nend_header\n"
    "0 0 0 255\n1 0 0 0\n0 1 0 9\n3 0 1 2\n")

# ---- flights ----
put("flight_json", "orbit.json", json.dumps({"name": "orbit", "frame": "normalized", "keys": [
    {"t": 0.0, "eye": [0.5, -0.2, 0.4], "target": [0.5, 0.5, 0.05], "up": [0, 0, 1]},
    {"t": 5.0, "eye": [1.2, 0.5, 0.2], "target": [0.5, 0.5, 0.05]},
    {"t": 9.5, "eye": [0.5, 1.2, 0.3], "target": [0.5, 0.5, 0.0], "up": [0, 1, 1]}]}))
put("flight_json", "world.json", '{"description":"d","frame":"world","keys":[{"t":-1,"eye":[0,0,10],"target":[1,1,0]}]}')

# ---- server config ----
put("config_toml", "full.toml", """store = "/srv/tiles"
bind = "0.0.0.0:9000"
max_connections = 100
max_in_flight = 10
request_timeout_s = 5
max_body_bytes = 1048576
bake_workers = 2
bake_queue = 8
cache_bytes = 1000000
poll_ms = 100
rate_limit = 50
shutdown_timeout_s = 3
admin_token = "secret-token-1"
read_token = "reader-token-2"
log_format = "json"
gpu = "off"
gpu_budget_mib = 64

[[sources]]
name = "fuji"
raster = "data/fuji.png"
encoding = "terrain-rgb"
cell_size = 30.0
tile_size = 128
max_error = 0.5
levels = 3
""")
put("config_toml", "min.toml", 'store = "s"\n')

# ---- HTTP requests (arbitrary-encoded; any bytes work, these only give a start) ----
put("http_router", "zeros", b"\0" * 64)
put("http_router", "ones", b"\x01" * 64)
put("http_router", "mixed", bytes(range(0, 256, 3)))

# ---- tileset archives (.tsa; layout in docs/formats.md) ----
def tsa(files, page_entries=4096):
    out = bytearray(b"TSARC\x00\x01\n")
    entries, root = [], []
    for path, data in sorted(files):
        p = path.encode()
        entries.append((p, len(out), len(data), zlib.crc32(data) & 0xffffffff))
        out += data
    data_end = len(out)
    for i in range(0, len(entries), page_entries):
        page = entries[i:i + page_entries]
        buf = b"".join(struct.pack("<H", len(p)) + p + struct.pack("<QQI", o, n, c) for p, o, n, c in page)
        root.append((page[0][0], len(out), len(buf), zlib.crc32(buf) & 0xffffffff, len(page)))
        out += buf
    rbuf = b"".join(struct.pack("<H", len(p)) + p + struct.pack("<QIII", o, n, c, k) for p, o, n, c, k in root)
    root_off = len(out)
    out += rbuf
    f = b"TSARCHV1" + struct.pack("<IIQQIIQQI", 1, 0, root_off, len(rbuf), zlib.crc32(rbuf) & 0xffffffff,
                                  0, len(entries), data_end, 0)
    return bytes(out + f + struct.pack("<I", zlib.crc32(f) & 0xffffffff))

put("store_archive", "empty.tsa", tsa([]))
put("store_archive", "three.tsa", tsa([("a.json", b"{}"), ("tiles/0/0/0/0.tsb", bytes(range(40))), ("z", b"")]))
put("store_archive", "pages.tsa", tsa([("f%02d" % i, bytes([i]) * (i % 5)) for i in range(9)], page_entries=4))
