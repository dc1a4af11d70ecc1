#!/usr/bin/env python3
"""Write a reviewable copy of the golden outputs: SRC (the bakes' and requests' files) -> DEST.

- `DEST/files.sha256`: sha256, size and path of every file (the byte-exact check);
- text files (UTF-8, no NUL) as they are; a JSON file with lines over 200 characters is written
  pretty-printed (the hash list still pins its bytes);
- a blob (`TSB1`) as `PATH.txt`: its 136-byte prefix decoded field by field (bincode 2,
  little-endian, fixed-width integers; docs/formats.md), the payload's size and sha256. The decoder
  is written here from the format's documentation, independently of the Rust codec;
- a gzip body as `PATH.txt` naming the compressed size, then the decompressed text;
- any other binary file as `PATH.txt`: size, sha256 and its first 64 bytes in hex.

So a change to any output shows as a diff of readable lines, not only as a changed hash.

usage: summarize.py SRC DEST
"""

import gzip
import hashlib
import json
import os
import struct
import sys

TSB_PREFIX = 136
HEADER = struct.Struct("<HIBIIB6d2dII3dIIII")
assert HEADER.size == 128


def tsb(data: bytes) -> str:
    if len(data) < TSB_PREFIX:
        return (
            f"TSB1 blob cut short (a range?): {len(data)} bytes,"
            f" sha256 {hashlib.sha256(data).hexdigest()}\nfirst bytes: {data[:64].hex(' ')}\n"
        )
    (header_len,) = struct.unpack_from("<I", data, 4)
    f = HEADER.unpack_from(data, 8)
    version, kind, z, x, y, level = f[0:6]
    bmin, bmax = f[6:9], f[9:12]
    xy_step, z_step = f[12:14]
    vertices, triangles = f[14:16]
    e_max, e_rms, e_gap = f[16:19]
    raw_len, payload_len, crc, header_crc = f[19:23]
    payload = data[TSB_PREFIX:]
    kinds = {0: "mesh", 1: "points"}
    lines = [
        f"magic TSB1, header length {header_len}, format version {version}",
        f"kind {kinds.get(kind, f'unknown({kind})')}, tile {z}/{x}/{y}, level {level}",
        f"bounds min {list(bmin)!r}",
        f"bounds max {list(bmax)!r}",
        f"quantization xy_step {xy_step!r}, z_step {z_step!r}",
        f"vertices/points {vertices}, triangles {triangles}",
        f"errors max {e_max!r}, rms {e_rms!r}, gap {e_gap!r}",
        f"payload raw {raw_len} bytes, stored {payload_len} bytes (present {len(payload)}),"
        f" crc32 {crc:08x}, header crc32 {header_crc:08x}",
        f"payload sha256 {hashlib.sha256(payload).hexdigest()}",
    ]
    return "\n".join(lines) + "\n"


def is_text(data: bytes) -> bool:
    if b"\0" in data:
        return False
    try:
        data.decode("utf-8")
    except UnicodeDecodeError:
        return False
    return True


def readable(data: bytes):
    """(suffix, text) for one file's bytes."""
    if data[:4] == b"TSB1":
        return ".txt", tsb(data)
    if data[:2] == b"\x1f\x8b":
        try:
            inner = gzip.decompress(data)
        except (OSError, EOFError) as e:
            return ".txt", f"gzip, {len(data)} bytes, does not decompress: {e}\n"
        _, text = readable(inner)
        return ".txt", f"gzip, {len(data)} bytes compressed, {len(inner)} decompressed:\n{text}"
    if is_text(data):
        text = data.decode("utf-8")
        if any(len(line) > 200 for line in text.splitlines()):
            try:
                value = json.loads(text)
            except ValueError:
                return "", text
            return "", json.dumps(value, indent=1, ensure_ascii=False) + "\n"
        return "", text
    head = data[:64].hex(" ")
    return ".txt", (
        f"binary, {len(data)} bytes, sha256 {hashlib.sha256(data).hexdigest()}\nfirst bytes: {head}\n"
    )


def main() -> int:
    if len(sys.argv) != 3:
        print(__doc__.strip().splitlines()[-1], file=sys.stderr)
        return 2
    src, dest = sys.argv[1], sys.argv[2]
    paths = []
    for root, _dirs, files in os.walk(src):
        for name in files:
            paths.append(os.path.relpath(os.path.join(root, name), src))
    paths.sort(key=lambda p: p.encode())
    listing = []
    for rel in paths:
        with open(os.path.join(src, rel), "rb") as fh:
            data = fh.read()
        listing.append(f"{hashlib.sha256(data).hexdigest()}  {len(data):>8}  {rel}\n")
        suffix, text = readable(data)
        out = os.path.join(dest, rel + suffix)
        os.makedirs(os.path.dirname(out), exist_ok=True)
        with open(out, "w", encoding="utf-8", newline="") as fh:
            fh.write(text)
    with open(os.path.join(dest, "files.sha256"), "w", encoding="utf-8") as fh:
        fh.writelines(listing)
    return 0


if __name__ == "__main__":
    sys.exit(main())
