"""Tests of the checker's own readers (pytest): a checker that reads GLBs wrongly would pass or
fail terrastream for the wrong reason. Run: python -m pytest tests/placement/test_check.py"""

import json
import struct
import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).parent))
import check  # noqa: E402


def glb_bytes(doc, binary):
    j = json.dumps(doc).encode()
    j += b" " * (-len(j) % 4)
    binary += b"\0" * (-len(binary) % 4)
    body = struct.pack("<II", len(j), 0x4E4F534A) + j + struct.pack("<II", len(binary), 0x004E4942) + binary
    return struct.pack("<4sII", b"glTF", 2, 12 + len(body)) + body


def quantized_triangle(node, extra=None):
    """One triangle, u16 positions interleaved with padding (byteStride 8), u16 indices."""
    q = [(0, 0, 0), (100, 5, 0), (0, 7, 200)]
    verts = b"".join(struct.pack("<HHHH", *p, 0xBEEF) for p in q)
    idx = struct.pack("<HHH", 0, 1, 2) + b"\0\0"
    doc = {
        "asset": {"version": "2.0"},
        "extensionsUsed": ["KHR_mesh_quantization"],
        "extensionsRequired": ["KHR_mesh_quantization"],
        "buffers": [{"byteLength": len(verts) + len(idx)}],
        "bufferViews": [
            {"buffer": 0, "byteOffset": 0, "byteLength": len(verts), "byteStride": 8},
            {"buffer": 0, "byteOffset": len(verts), "byteLength": 6},
        ],
        "accessors": [
            {"bufferView": 0, "componentType": 5123, "count": 3, "type": "VEC3"},
            {"bufferView": 1, "componentType": 5123, "count": 3, "type": "SCALAR"},
        ],
        "meshes": [{"primitives": [{"attributes": {"POSITION": 0}, "indices": 1, "mode": 4}]}],
        "nodes": [dict(node, mesh=0)],
        "scenes": [{"nodes": [0]}],
        "scene": 0,
    }
    if extra:
        doc.update(extra)
    return glb_bytes(doc, verts + idx), q


def test_quantized_positions_node_trs_and_y_up(tmp_path):
    b, q = quantized_triangle({"translation": [10.0, 20.0, 30.0], "scale": [0.5, 0.25, 2.0]})
    p = tmp_path / "t.glb"
    p.write_bytes(b)
    world = check.translation([1000.0, 2000.0, 3000.0])
    [(mode, ecef, tris)] = check.read_content(p, world)
    assert mode == 4 and tris.tolist() == [[0, 1, 2]]
    for (x, y, z), e in zip(q, ecef):
        g = np.array([10 + 0.5 * x, 20 + 0.25 * y, 30 + 2.0 * z])  # glTF, y-up
        zup = np.array([g[0], -g[2], g[1]])  # 3D Tiles: +90 degrees about x
        assert np.allclose(e, zup + [1000, 2000, 3000])


def test_node_rotation_matrix_and_rtc(tmp_path):
    # A quarter turn about glTF y, as a quaternion on a child under a matrix parent.
    s = np.sqrt(0.5)
    b, q = quantized_triangle({"rotation": [0.0, s, 0.0, s]},
                              extra={"extensions": {"CESIUM_RTC": {"center": [5.0, 6.0, 7.0]}}})
    doc, binary = check.parse_glb(b, "x")
    doc["nodes"] = [{"matrix": [1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0, 3, 0, 0, 1], "children": [1]},
                    {"rotation": [0.0, s, 0.0, s], "mesh": 0}]
    p = tmp_path / "r.glb"
    p.write_bytes(glb_bytes(doc, binary))
    [(_, ecef, _)] = check.read_content(p, np.eye(4))
    for (x, y, z), e in zip(q, ecef):
        g = np.array([z, y, -x]) + [3.0, 0.0, 0.0]  # +90 degrees about y: x -> -z, z -> x
        assert np.allclose(e, np.array([g[0], -g[2], g[1]]) + [5, 6, 7])


def test_normalized_and_meshopt(tmp_path):
    verts = struct.pack("<3h", 32767, -32767, 16384) + b"\0\0"
    doc = {
        "asset": {"version": "2.0"},
        "buffers": [{"byteLength": 8}],
        "bufferViews": [{"buffer": 0, "byteLength": 8}],
        "accessors": [{"bufferView": 0, "componentType": 5122, "normalized": True, "count": 1, "type": "VEC3"}],
    }
    a = check.read_accessor(doc, [verts], 0, "x")
    assert np.allclose(a, [[1.0, -1.0, 16384 / 32767]])
    b, _ = quantized_triangle({}, extra={"extensionsUsed": ["EXT_meshopt_compression"]})
    p = tmp_path / "m.glb"
    p.write_bytes(b)
    with pytest.raises(check.CheckError, match="EXT_meshopt_compression"):
        check.read_content(p, np.eye(4))


def test_transforms_compose_through_external_tilesets(tmp_path):
    t1 = check.translation([1.0, 0.0, 0.0])
    t2 = np.diag([2.0, 2.0, 2.0, 1.0])
    t3 = check.translation([0.0, 0.0, 5.0])
    cm = lambda m: m.T.ravel().tolist()  # noqa: E731 (column-major)
    (tmp_path / "sub").mkdir()
    (tmp_path / "sub" / "ext.json").write_text(json.dumps({
        "asset": {"version": "1.1"}, "geometricError": 1,
        "root": {"transform": cm(t3), "geometricError": 0.5, "content": {"uri": "a.glb"}}}))
    (tmp_path / "tileset.json").write_text(json.dumps({
        "asset": {"version": "1.1"}, "geometricError": 10,
        "root": {"transform": cm(t1), "geometricError": 4, "content": {"uri": "root.glb"}, "children": [
            {"transform": cm(t2), "geometricError": 2, "content": {"uri": "sub/ext.json?v=3"}}]}}))
    tiles = {str(t.contents[0].name) if t.contents else "ref": t for t in check.walk_tileset(tmp_path / "tileset.json")}
    assert np.allclose(tiles["a.glb"].world, t1 @ t2 @ t3)
    assert tiles["a.glb"].leaf and not tiles["root.glb"].leaf
    assert not tiles["ref"].leaf and tiles["a.glb"].error == 0.5


def grid_mesh(n=4, spacing=10.0, skirt_depth=30.0, cliff=None):
    """A flat n x n grid at ECEF-like coordinates near (x=R) with skirts on its east border;
    heights along +x. Returns positions, heights, triangles, the skirt indices."""
    pts, h = [], []
    for j in range(n):
        for i in range(n):
            z = 100.0 + (cliff if cliff and i == n - 1 and j == 1 else 0.0)
            h.append(z)
            pts.append((6.4e6 + z, i * spacing, j * spacing))
    tris = []
    for j in range(n - 1):
        for i in range(n - 1):
            a, b, c, d = j * n + i, j * n + i + 1, (j + 1) * n + i, (j + 1) * n + i + 1
            tris += [(a, b, d), (a, d, c)]
    skirts = []
    east = [j * n + n - 1 for j in range(n)]
    for top in east:
        skirts.append(len(pts))
        pts.append((pts[top][0] - skirt_depth, pts[top][1] + 0.3, pts[top][2]))  # slightly off plumb
        h.append(h[top] - skirt_depth)
    for k in range(n - 1):
        a, b, sa, sb = east[k], east[k + 1], skirts[k], skirts[k + 1]
        tris += [(b, a, sa), (b, sa, sb)]
    return np.array(pts), np.array(h), np.array(tris), skirts


def test_skirt_rule():
    p, h, tris, skirts = grid_mesh()
    found = check.find_skirts(p, h, tris, threshold=1.0)
    assert sorted(np.nonzero(found)[0].tolist()) == skirts
    # Less deep than the threshold: not a skirt (then checked as a vertex, as it must pass).
    p, h, tris, _ = grid_mesh(skirt_depth=0.5)
    assert not check.find_skirts(p, h, tris, threshold=1.0).any()
    # A vertex far below its neighbours but not under one (a pit 10 m across, 30 m deep) is no skirt.
    p, h, tris, _ = grid_mesh()
    p[5, 0] -= 30.0
    h[5] -= 30.0
    found = check.find_skirts(p, h, tris, threshold=1.0)
    assert not found[5]


def test_bilinear_nodata_and_wrap(tmp_path):
    import rasterio
    from rasterio.transform import Affine
    data = np.arange(12, dtype=np.float32).reshape(3, 4)
    data[2, 3] = -9999
    path = tmp_path / "g.tif"
    with rasterio.open(path, "w", driver="GTiff", width=4, height=3, count=1, dtype="float32",
                       crs="EPSG:4326", transform=Affine(1, 0, 178.5, 0, -1, 10.5), nodata=-9999) as d:
        d.write(data, 1)
    s = check.Source(path)
    # Sample centres at 179..182 E, i.e. 179, 180, -179, -178.
    lon, lat = s.sample_lonlat([2], [0])
    assert np.allclose([lon[0], lat[0]], [181.0, 10.0])
    hits = [(c, r) for c, r in s.locate(np.array([-179.0]), np.array([10.0])) if s.inside(c, r)[0]]
    assert len(hits) == 1 and np.allclose([hits[0][0][0], hits[0][1][0]], [2.0, 0.0])
    assert np.allclose(s.bilinear(np.array([0.5]), np.array([0.5])), [(0 + 1 + 4 + 5) / 4])
    assert np.isnan(s.bilinear(np.array([2.5]), np.array([1.5])))[0]
    assert s.bilinear(np.array([2.0]), np.array([2.0]))[0] == 10.0


def test_geoid_matches_proj():
    g = check.Geoid(check.GEOID_GTX)
    assert g.self_check() < 1e-3
    # Known magnitudes: about +41 m at Mt Fuji, about -28 m at Dallas.
    assert 35 < g.undulation(138.73, 35.36) < 45
    assert -32 < g.undulation(-97.05, 32.85) < -24


def test_deep_pit_is_no_skirt():
    # 50 m deep under 10 m cells (78 degree slopes): under its neighbours, but not on the border.
    p, h, tris, skirts = grid_mesh()
    p[5, 0] -= 50.0
    h[5] -= 50.0
    found = check.find_skirts(p, h, tris, threshold=1.0)
    assert not found[5] and sorted(np.nonzero(found)[0].tolist()) == skirts
