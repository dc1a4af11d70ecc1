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
    found = check.find_skirts(p, h, tris, threshold=1.0, max_offset=2.5)
    assert sorted(np.nonzero(found)[0].tolist()) == skirts
    # Less deep than the threshold: not a skirt (then checked as a vertex, as it must pass).
    p, h, tris, _ = grid_mesh(skirt_depth=0.5)
    assert not check.find_skirts(p, h, tris, threshold=1.0, max_offset=2.5).any()
    # A vertex far below its neighbours but not under one (a pit 10 m across, 30 m deep) is no skirt.
    p, h, tris, _ = grid_mesh()
    p[5, 0] -= 30.0
    h[5] -= 30.0
    found = check.find_skirts(p, h, tris, threshold=1.0, max_offset=2.5)
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
    found = check.find_skirts(p, h, tris, threshold=1.0, max_offset=2.5)
    assert not found[5] and sorted(np.nonzero(found)[0].tolist()) == skirts


# ---------------------------------------------------------------------------------------------
# A positive control: a tileset written here, independently of terrastream, with every sample
# where PROJ puts it (per-tile east-north-up frames, float positions with a byteStride, skirts on
# inner borders, one external tileset). The checker must pass it, and fail it when it is moved
# by 6 cm or when the geoid is left out.


def enu_frame(lon, lat, h):
    lam, phi = np.radians(lon), np.radians(lat)
    east = [-np.sin(lam), np.cos(lam), 0.0]
    north = [-np.sin(phi) * np.cos(lam), -np.sin(phi) * np.sin(lam), np.cos(phi)]
    up = [np.cos(phi) * np.cos(lam), np.cos(phi) * np.sin(lam), np.sin(phi)]
    m = np.eye(4)
    m[:3, 0], m[:3, 1], m[:3, 2] = east, north, up
    m[:3, 3] = check.to_ecef(np.array([lon]), np.array([lat]), np.array([h]))[0]
    return m


def control_glb(ecef, tris, frame):
    local = (ecef - frame[:3, 3]) @ frame[:3, :3]  # (e, n, u): the frame is orthonormal
    gltf = np.stack([local[:, 0], local[:, 2], -local[:, 1]], axis=1).astype("<f4")
    verts = b"".join(v.tobytes() + b"\0\0\0\0" for v in gltf)  # byteStride 16
    idx = tris.astype("<u4").tobytes()
    doc = {
        "asset": {"version": "2.0"},
        "buffers": [{"byteLength": len(verts) + len(idx)}],
        "bufferViews": [{"buffer": 0, "byteLength": len(verts), "byteStride": 16},
                        {"buffer": 0, "byteOffset": len(verts), "byteLength": len(idx)}],
        "accessors": [{"bufferView": 0, "componentType": 5126, "count": len(gltf), "type": "VEC3"},
                      {"bufferView": 1, "componentType": 5125, "count": tris.size, "type": "SCALAR"}],
        "meshes": [{"primitives": [{"attributes": {"POSITION": 0}, "indices": 1}]}],
        "nodes": [{"mesh": 0}],
        "scenes": [{"nodes": [0]}],
    }
    return glb_bytes(doc, verts + idx)


def write_control(folder, sources, geoid, datum, shift=(0.0, 0.0, 0.0), leave_out_geoid=False):
    folder.mkdir(parents=True, exist_ok=True)
    children = []
    for f, s in enumerate(sources):
        halves_c = [(0, s.width // 2), (s.width // 2, s.width - 1)]
        halves_r = [(0, s.height // 2), (s.height // 2, s.height - 1)]
        for i, (c0, c1) in enumerate(halves_c):
            for j, (r0, r1) in enumerate(halves_r):
                cc, rr = np.meshgrid(np.arange(c0, c1 + 1), np.arange(r0, r1 + 1))
                lon, lat = s.sample_lonlat(cc.ravel(), rr.ravel())
                h = s.values[rr.ravel(), cc.ravel()].copy()
                if datum == "egm96" and not leave_out_geoid:
                    h += geoid.undulation(lon, lat)
                ecef = check.to_ecef(lon, lat, h) + np.asarray(shift)
                w = c1 - c0 + 1
                tris = []
                for y in range(r1 - r0):
                    for x in range(c1 - c0):
                        a, b, c, d = y * w + x, y * w + x + 1, (y + 1) * w + x, (y + 1) * w + x + 1
                        tris += [(a, b, d), (a, d, c)]
                # Skirts 3 m deep along the ellipsoid normal below the inner borders.
                inner = [k for k in range(len(lon))
                         if (i == 0 and cc.ravel()[k] == c1) or (j == 0 and rr.ravel()[k] == r1)]
                first = len(ecef)
                sk = check.to_ecef(lon[inner], lat[inner], h[inner] - 3.0) + np.asarray(shift)
                ecef = np.concatenate([ecef, sk])
                pos = {k: first + n for n, k in enumerate(inner)}
                for y in range(r1 - r0 + 1):
                    for x in range(c1 - c0 + 1):
                        for dx, dy in ((1, 0), (0, 1)):
                            a, b = y * w + x, (y + dy) * w + x + dx
                            if a in pos and b in pos and x + dx <= c1 - c0 and y + dy <= r1 - r0:
                                tris += [(b, a, pos[a]), (b, pos[a], pos[b])]
                k = len(lon) // 2
                frame = enu_frame(lon[k], lat[k], float(h[k]))
                name = f"f{f}_{i}{j}.glb"
                (folder / name).write_bytes(control_glb(ecef, np.array(tris), frame))
                tile = {"transform": frame.T.ravel().tolist(), "geometricError": 0.0,
                        "boundingVolume": {"sphere": [0, 0, 0, 1e6]}, "content": {"uri": name}}
                if (i, j) == (1, 1):  # through an external tileset whose parent moves it back
                    away = check.translation([0.0, 0.0, -1000.0])
                    (folder / f"ext{f}.json").write_text(json.dumps(
                        {"asset": {"version": "1.1"}, "geometricError": 0.0, "root": tile}))
                    tile = {"transform": away.T.ravel().tolist(), "geometricError": 1.0,
                            "boundingVolume": {"sphere": [0, 0, 0, 1e6]}, "content": {"uri": f"ext{f}.json"}}
                    inner_tile = json.loads((folder / f"ext{f}.json").read_text())
                    back = np.linalg.inv(away) @ frame
                    inner_tile["root"]["transform"] = back.T.ravel().tolist()
                    (folder / f"ext{f}.json").write_text(json.dumps(inner_tile))
                children.append(tile)
    (folder / "tileset.json").write_text(json.dumps({
        "asset": {"version": "1.1"}, "geometricError": 100.0,
        "root": {"geometricError": 100.0, "boundingVolume": {"sphere": [0, 0, 0, 1e7]}, "children": children}}))
    return folder / "tileset.json"


def control_raster(path, crs, transform, w, h, seed):
    import rasterio
    rng = np.random.default_rng(seed)
    data = (300 + 50 * np.sin(np.arange(w * h) / 7.0) + rng.normal(size=w * h)).astype(np.float32).reshape(h, w)
    with rasterio.open(path, "w", driver="GTiff", width=w, height=h, count=1, dtype="float32", crs=crs,
                       transform=transform) as d:
        d.write(data, 1)
    return check.Source(path)


@pytest.mark.parametrize("case", ["utm_egm96", "antimeridian_0360", "north_pole"])
def test_positive_control(tmp_path, case):
    from rasterio.transform import Affine
    geoid = check.Geoid(check.GEOID_GTX)
    if case == "utm_egm96":
        src = [control_raster(tmp_path / "a.tif", "EPSG:32632", Affine(90, 0, 600000, 0, -90, 5200000), 21, 17, 1)]
        datum = "egm96"
    elif case == "antimeridian_0360":
        src = [control_raster(tmp_path / "a.tif", "EPSG:4326", Affine(0.01, 0, 179.9, 0, -0.01, 65.1), 20, 12, 2)]
        datum = "ellipsoid"
    else:
        src = [control_raster(tmp_path / "a.tif", "EPSG:4326", Affine(30, 0, -180, 0, -0.02, 90.01), 12, 9, 3)]
        datum = "ellipsoid"
        src[0].values[0, :] = src[0].values[0, 0]  # one height at the pole
    entry = {"datum": datum}
    good = check.check_placement(entry, write_control(tmp_path / "good", src, geoid, datum), src, geoid)
    assert good["corner_max_m"] < 0.005, good
    assert good["over_tolerance"] == 0 and good["outside"] == 0 and good["checked"] > 0, good
    assert good["skirt_vertices"] > 0 and good["vertical_max_m"] < 0.01, good
    moved = check.check_placement(entry, write_control(tmp_path / "moved", src, geoid, datum, shift=(0.06, 0, 0)),
                                  src, geoid)
    assert moved["corner_max_m"] > check.CORNER_TOL_M
    if datum == "egm96":
        flat = check.check_placement(entry, write_control(tmp_path / "nogeoid", src, geoid, datum,
                                                          leave_out_geoid=True), src, geoid)
        assert flat["over_tolerance"] == flat["checked"] > 0


def test_steep_border_vertex_is_no_skirt():
    # A border vertex 50 m below its neighbour one 10 m sample away (78 degrees): inside the cone,
    # but a sample away horizontally, so not under it.
    p, h, tris, skirts = grid_mesh(cliff=50.0)
    found = check.find_skirts(p, h, tris, threshold=1.0, max_offset=2.5)
    assert sorted(np.nonzero(found)[0].tolist()) == skirts
    assert check.find_skirts(p, h, tris, threshold=1.0, max_offset=20.0)[3]  # the cone alone would take it
