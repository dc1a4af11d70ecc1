#!/usr/bin/env python3
"""Packs the EGM96 15' geoid grid (Debian proj-data's /usr/share/proj/egm96_15.gtx, public
domain, NGA) into the form terrastream embeds: src/crs/egm96_15.tsg.

Format (all little-endian): magic b"TSGEOID1", lat0, lon0, dlat, dlon (f64, degrees: the south-west
node and the steps), rows, cols (u32), then zstd of rows*cols int16: the undulations in
centimetres (rounded, so at most 0.5 cm off the grid's values), differenced along each row and
then down the columns (second differences of a smooth field compress 6.9x). Decoding: cumulative
sums down the columns, then along each row.

Usage: pack_egm96.py [GTX] [OUT]
"""
import struct, sys, subprocess
import numpy as np

src = sys.argv[1] if len(sys.argv) > 1 else "/usr/share/proj/egm96_15.gtx"
out = sys.argv[2] if len(sys.argv) > 2 else "src/crs/egm96_15.tsg"
b = open(src, "rb").read()
lat0, lon0, dlat, dlon = struct.unpack(">4d", b[:32])
rows, cols = struct.unpack(">2i", b[32:40])
g = np.frombuffer(b[40:], ">f4").reshape(rows, cols).astype(np.float64)
cm = np.round(g * 100).astype(np.int64)
d = np.diff(cm, axis=1, prepend=0)
d2 = np.diff(d, axis=0, prepend=0)
assert np.abs(d2).max() < 32767
raw = d2.astype("<i2").tobytes()
z = subprocess.run(["zstd", "-19", "-q", "-c"], input=raw, capture_output=True, check=True).stdout
with open(out, "wb") as f:
    f.write(b"TSGEOID1" + struct.pack("<4d2I", lat0, lon0, dlat, dlon, rows, cols) + z)
print(f"{out}: {rows}x{cols} from {src}, {len(z)} bytes of payload, max rounding {np.abs(cm / 100 - g).max():.4f} m")
