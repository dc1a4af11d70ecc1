// Stored values are compared bit for bit: the subtree and GLB keep them exactly.
#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic, clippy::float_cmp)]

use serde_json::Value;

use super::*;
use crate::formats::qmesh::grid::Rect;
use crate::formats::qmesh::{TileSamples, build_tile, decode, layer::layer_json};

/// A real built tile: rolling terrain (a few hundred metres of relief) at tile `id`.
fn built(id: TileId) -> QmTile {
    let s = TileSamples::from_fn(
        id,
        |lon, lat| Some(800.0 + 300.0 * (lon * 40.0).sin() * (lat * 30.0).cos()),
        |_, _| 0.0,
    );
    decode(&build_tile(&s, 1.0, None).unwrap().bytes).unwrap()
}

/// GLB → (JSON, BIN), checking the container (magic, version, lengths, chunk types, padding).
fn parse_glb(b: &[u8]) -> (Value, Vec<u8>) {
    let u = |at: usize| u32::from_le_bytes(b[at..at + 4].try_into().unwrap()) as usize;
    assert_eq!(&b[0..4], b"glTF");
    assert_eq!(u(4), 2);
    assert_eq!(u(8), b.len());
    let jlen = u(12);
    assert_eq!(u(16), 0x4E4F_534A);
    assert_eq!(jlen % 4, 0);
    let json: Value = serde_json::from_slice(&b[20..20 + jlen]).unwrap();
    let at = 20 + jlen;
    let blen = u(at);
    assert_eq!(u(at + 4), 0x004E_4942);
    assert_eq!(at + 8 + blen, b.len());
    (json, b[at + 8..].to_vec())
}

/// An accessor's values as f64 (FLOAT, UNSIGNED_SHORT, UNSIGNED_INT), tightly packed.
fn read(json: &Value, bin: &[u8], acc: usize) -> Vec<f64> {
    let a = &json["accessors"][acc];
    let v = &json["bufferViews"][a["bufferView"].as_u64().unwrap() as usize];
    let off = v["byteOffset"].as_u64().unwrap() as usize + a["byteOffset"].as_u64().unwrap_or(0) as usize;
    let per = match a["type"].as_str().unwrap() {
        "SCALAR" => 1,
        "VEC3" => 3,
        t => panic!("{t}"),
    };
    let count = a["count"].as_u64().unwrap() as usize * per;
    // Float32Array / Uint16Array views need their offsets aligned (CesiumJS makes such views).
    let size = match a["componentType"].as_u64().unwrap() {
        5126 | 5125 => 4,
        5123 => 2,
        c => panic!("{c}"),
    };
    assert_eq!(off % size, 0, "accessor {acc} misaligned");
    assert!(
        off + count * size
            <= v["byteOffset"].as_u64().unwrap() as usize + v["byteLength"].as_u64().unwrap() as usize
    );
    (0..count)
        .map(|k| {
            let p = off + k * size;
            match a["componentType"].as_u64().unwrap() {
                5126 => f64::from(f32::from_le_bytes(bin[p..p + 4].try_into().unwrap())),
                5125 => f64::from(u32::from_le_bytes(bin[p..p + 4].try_into().unwrap())),
                _ => f64::from(u16::from_le_bytes(bin[p..p + 2].try_into().unwrap())),
            }
        })
        .collect()
}

#[test]
fn glb_vertices_are_the_quantized_mesh_vertices() {
    let id = TileId::new(10, 1_100, 700).unwrap();
    let t = built(id);
    let (json, bin) = parse_glb(&glb(&t, id).unwrap());
    let prim = &json["meshes"][0]["primitives"][0];
    let m = json["nodes"][0]["matrix"].as_array().unwrap();
    let m: Vec<f64> = m.iter().map(|v| v.as_f64().unwrap()).collect();
    // Identity rotation, translation = the header centre in y-up axes.
    assert_eq!(&m[..12], &[1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0]);
    let c = t.header.center;
    assert_eq!((m[12], m[13], m[14]), (c[0], c[2], -c[1]));
    let pos = read(&json, &bin, prim["attributes"]["POSITION"].as_u64().unwrap() as usize);
    assert_eq!(pos.len(), 3 * t.u.len());
    let r: Rect = id.rect();
    // The format's own decoding (quantized-mesh-1.0: u, v, h over 0..32767 across the tile's
    // rectangle and the header's height range), against the GLB's y-up f32 offsets.
    let mut worst: f64 = 0.0;
    for k in 0..t.u.len() {
        let s = |q: u16| f64::from(q) / 32767.0;
        let lon = r.west + (r.east - r.west) * s(t.u[k]);
        let lat = r.south + (r.north - r.south) * s(t.v[k]);
        let h =
            f64::from(t.header.min_height) + f64::from(t.header.max_height - t.header.min_height) * s(t.h[k]);
        let e = ecef::from_geodetic(lon, lat, h);
        let g = [pos[3 * k] + m[12], pos[3 * k + 1] + m[13], pos[3 * k + 2] + m[14]];
        let back = [g[0], -g[2], g[1]];
        worst = worst.max((0..3).map(|a| (back[a] - e[a]).abs()).fold(0.0, f64::max));
    }
    // Zoom 10: a 20 km tile; an f32 offset rounds by at most 2⁻²⁴ of it per axis (≈ 1 mm).
    assert!(worst < 2e-3, "worst vertex {worst} m from its quantized-mesh position");
    // Triangles: the tile's own, in order.
    let idx = read(&json, &bin, prim["indices"].as_u64().unwrap() as usize);
    let want: Vec<f64> = t.triangles.iter().flatten().map(|&i| f64::from(i)).collect();
    assert_eq!(idx, want);
    // They face outwards (away from the Earth's centre): counter-clockwise seen from above.
    let p =
        |i: usize| glam::DVec3::new(pos[3 * i] + m[12], -(pos[3 * i + 2] + m[14]), pos[3 * i + 1] + m[13]);
    for tri in &t.triangles {
        let [a, b, c] = tri.map(|i| p(i as usize));
        assert!((b - a).cross(c - a).dot(a) > 0.0, "triangle {tri:?} faces down");
    }
}

#[test]
fn glb_edges_and_normals() {
    let id = TileId::new(7, 200, 90).unwrap();
    let t = built(id);
    let (json, bin) = parse_glb(&glb(&t, id).unwrap());
    assert_eq!(json["extensionsUsed"], json!(["CESIUM_tile_edges"]));
    assert!(json.get("extensionsRequired").is_none());
    let prim = &json["meshes"][0]["primitives"][0];
    let edges = &prim["extensions"]["CESIUM_tile_edges"];
    // Each list: the quantized-mesh tile's vertices of that edge, in the order CesiumJS hangs
    // skirts in: left south → north, bottom east → west, right north → south, top west → east.
    let coord = |i: f64, by_u: bool| if by_u { t.u[i as usize] } else { t.v[i as usize] };
    for (name, list, by_u, rising) in [
        ("left", &t.west, false, true),
        ("bottom", &t.south, true, false),
        ("right", &t.east, false, false),
        ("top", &t.north, true, true),
    ] {
        let got = read(&json, &bin, edges[name].as_u64().unwrap() as usize);
        let mut a: Vec<u32> = got.iter().map(|&i| i as u32).collect();
        let mut b = list.clone();
        a.sort_unstable();
        b.sort_unstable();
        assert_eq!(a, b, "{name}");
        assert!(!got.is_empty());
        for w in got.windows(2) {
            let (p, q) = (coord(w[0], by_u), coord(w[1], by_u));
            assert!(if rising { p < q } else { p > q }, "{name}: {p} then {q}");
        }
    }
    // West edge vertices lie on the tile's west meridian (u = 0), north ones on its north
    // parallel (v = 32767): the edge lists name the right vertices.
    assert!(t.west.iter().all(|&i| t.u[i as usize] == 0));
    assert!(t.north.iter().all(|&i| t.v[i as usize] == 32767));
    let nrm = read(&json, &bin, prim["attributes"]["NORMAL"].as_u64().unwrap() as usize);
    let oct = t.normals.as_ref().unwrap();
    for (k, o) in oct.iter().enumerate() {
        let n = [nrm[3 * k], nrm[3 * k + 1], nrm[3 * k + 2]];
        let len = (n[0] * n[0] + n[1] * n[1] + n[2] * n[2]).sqrt();
        assert!((len - 1.0).abs() < 1e-6, "normal {k} has length {len}");
        let d = oct_decode(*o);
        let dl = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt();
        let cos = (n[0] * d[0] + n[1] * d[2] - n[2] * d[1]) / dl;
        assert!(cos > 0.999_999, "normal {k}: {n:?} vs oct {d:?}");
    }
}

#[test]
fn glb_refuses_broken_tiles_naming_them() {
    let id = TileId::new(7, 200, 90).unwrap();
    let mut t = built(id);
    t.south.clear();
    let e = glb(&t, id).unwrap_err();
    assert!(e.to_string().contains("7/200/90") && e.to_string().contains("south"), "{e}");
    let mut t = built(id);
    t.triangles[0][1] = t.u.len() as u32;
    assert!(glb(&t, id).is_err());
    assert!(glb(&QmTile::default(), id).is_err());
}

#[test]
fn implicit_coordinates() {
    // Zoom 3: 16 × 8 tiles; x 11 lies in the eastern root (x ≥ 8), 3rd column there.
    let id = TileId::new(3, 11, 5).unwrap();
    let i = Implicit::of(id);
    assert_eq!(i, Implicit { root: 1, level: 3, x: 3, y: 5 });
    assert_eq!(i.tile().unwrap(), id);
    assert_eq!(Implicit::of(TileId::new(0, 0, 0).unwrap()), Implicit { root: 0, level: 0, x: 0, y: 0 });
    assert!(Implicit { root: 2, level: 0, x: 0, y: 0 }.tile().is_err());
    assert!(Implicit { root: 0, level: 2, x: 4, y: 0 }.tile().is_err());
    assert_eq!(glb_rel(id), "tiles/1/3/3/5.glb");
    assert_eq!(subtree_rel(Implicit { root: 0, level: 2, x: 1, y: 3 }), "subtrees/0/2/1/3.subtree");
    // Morton order, x in the low bit.
    assert_eq!(level_order(1).collect::<Vec<_>>(), vec![(0, 0), (1, 0), (0, 1), (1, 1)]);
    assert_eq!(level_order(2).nth(6), Some((2, 1)));
}

/// A subtree file → (JSON, binary), checking the container.
fn parse_subtree(b: &[u8]) -> (Value, Vec<u8>) {
    assert_eq!(&b[0..4], b"subt");
    assert_eq!(u32::from_le_bytes(b[4..8].try_into().unwrap()), 1);
    let jl = u64::from_le_bytes(b[8..16].try_into().unwrap()) as usize;
    let bl = u64::from_le_bytes(b[16..24].try_into().unwrap()) as usize;
    assert_eq!(jl % 8, 0);
    assert_eq!(bl % 8, 0);
    assert_eq!(24 + jl + bl, b.len());
    (serde_json::from_slice(&b[24..24 + jl]).unwrap(), b[24 + jl..].to_vec())
}

fn bit(json: &Value, bin: &[u8], avail: &Value, i: usize) -> bool {
    if let Some(c) = avail.get("constant") {
        return c.as_u64() == Some(1);
    }
    let v = &json["bufferViews"][avail["bitstream"].as_u64().unwrap() as usize];
    assert_eq!(v["byteOffset"].as_u64().unwrap() % 8, 0);
    let off = v["byteOffset"].as_u64().unwrap() as usize;
    (bin[off + i / 8] >> (i % 8)) & 1 == 1
}

fn f64s(json: &Value, bin: &[u8], prop: &str) -> Vec<f64> {
    let view = json["propertyTables"][0]["properties"][prop]["values"].as_u64().unwrap() as usize;
    let v = &json["bufferViews"][view];
    let (off, len) = (v["byteOffset"].as_u64().unwrap() as usize, v["byteLength"].as_u64().unwrap() as usize);
    assert_eq!(off % 8, 0);
    bin[off..off + len].chunks(8).map(|c| f64::from_le_bytes(c.try_into().unwrap())).collect()
}

fn alps() -> Coverage {
    Coverage { rects: vec![Rect { west: 10.5, south: 46.5, east: 10.9, north: 46.8 }], max_zoom: 9 }
}

#[test]
fn subtree_bitstreams_are_the_coverage() {
    let c = alps();
    let avail = Availability::of(&c);
    for z in (0..=c.max_zoom).step_by(usize::from(SUBTREE_LEVELS)) {
        let (cols, rows) = tiles_at(z);
        for gy in 0..rows {
            for gx in 0..cols {
                let id = TileId::new(z, gx, gy).unwrap();
                let root = Implicit::of(id);
                let tiles = subtree_tiles(&avail, root).unwrap();
                if !c.has(id) {
                    assert!(tiles.is_empty());
                    assert!(subtree(&avail, root, &[]).is_err());
                    continue;
                }
                // Headers that tell the tiles apart: min height = the tile's index in the list.
                let headers: Vec<Header> = (0..tiles.len())
                    .map(|k| Header {
                        min_height: k as f32,
                        max_height: 1000.0 + k as f32,
                        ..Header::default()
                    })
                    .collect();
                let (json, bin) = parse_subtree(&subtree(&avail, root, &headers).unwrap());
                // Every tile of the subtree's two levels, by its bit: the coverage's answer.
                let mut order = Vec::new();
                let mut bitno = 0;
                for l in 0..SUBTREE_LEVELS {
                    let side = 1u32 << l;
                    // Bits of a level in Morton order: the k-th bit is the tile whose x, y
                    // interleave to k.
                    for k in 0..side * side {
                        let (mut lx, mut ly) = (0, 0);
                        for b in 0..l {
                            lx |= ((k >> (2 * b)) & 1) << b;
                            ly |= ((k >> (2 * b + 1)) & 1) << b;
                        }
                        let t = TileId { z: z + l, x: (id.x << l) + lx, y: (id.y << l) + ly };
                        let want = z + l <= c.max_zoom && c.has(t);
                        assert_eq!(bit(&json, &bin, &json["tileAvailability"], bitno), want, "{t}");
                        assert_eq!(bit(&json, &bin, &json["contentAvailability"][0], bitno), want, "{t}");
                        if want {
                            order.push(t);
                        }
                        bitno += 1;
                    }
                }
                assert_eq!(order, tiles);
                assert_eq!(json["tileAvailability"]["availableCount"], tiles.len());
                // Child subtrees: the 16 tiles two levels down.
                for k in 0..16u32 {
                    let (mut lx, mut ly) = (0, 0);
                    for b in 0..2 {
                        lx |= ((k >> (2 * b)) & 1) << b;
                        ly |= ((k >> (2 * b + 1)) & 1) << b;
                    }
                    let t = TileId { z: z + 2, x: (id.x << 2) + lx, y: (id.y << 2) + ly };
                    let want = z + 2 <= c.max_zoom && c.has(t);
                    assert_eq!(bit(&json, &bin, &json["childSubtreeAvailability"], k as usize), want, "{t}");
                }
                // Metadata: one row per available tile, in bit order.
                let t = &json["propertyTables"][0];
                assert_eq!(t["count"], tiles.len());
                assert_eq!(json["tileMetadata"], 0);
                let mins = f64s(&json, &bin, "minimumHeight");
                assert_eq!(mins, (0..tiles.len()).map(|k| k as f64).collect::<Vec<_>>());
                assert_eq!(f64s(&json, &bin, "maximumHeight")[0], 1000.0);
                assert_eq!(f64s(&json, &bin, "boundingSphere").len(), 4 * tiles.len());
                assert_eq!(f64s(&json, &bin, "horizonOcclusionPoint").len(), 3 * tiles.len());
            }
        }
    }
}

#[test]
fn subtree_metadata_is_the_tiles_header() {
    let id = TileId::new(0, 1, 0).unwrap();
    let c = Coverage { rects: vec![Rect { west: 10.5, south: 46.5, east: 10.9, north: 46.8 }], max_zoom: 1 };
    let avail = Availability::of(&c);
    let tiles = subtree_tiles(&avail, Implicit::of(id)).unwrap();
    assert_eq!(tiles, vec![id, TileId { z: 1, x: 2, y: 1 }]);
    let headers: Vec<Header> = tiles.iter().map(|t| built(*t).header).collect();
    let (json, bin) = parse_subtree(&subtree(&avail, Implicit::of(id), &headers).unwrap());
    let sphere = f64s(&json, &bin, "boundingSphere");
    let horizon = f64s(&json, &bin, "horizonOcclusionPoint");
    for (k, h) in headers.iter().enumerate() {
        assert_eq!(f64s(&json, &bin, "minimumHeight")[k], f64::from(h.min_height));
        assert_eq!(
            &sphere[4 * k..4 * k + 4],
            &[h.sphere_center[0], h.sphere_center[1], h.sphere_center[2], h.sphere_radius]
        );
        assert_eq!(&horizon[3 * k..3 * k + 3], &h.horizon);
    }
    // Beyond the deepest zoom: no child subtrees at all.
    assert_eq!(json["childSubtreeAvailability"], json!({ "constant": 0 }));
    // A subtree must start at an even level; the header count must match.
    assert!(subtree_tiles(&avail, Implicit { root: 1, level: 1, x: 0, y: 0 }).is_err());
    assert!(subtree(&avail, Implicit::of(id), &headers[..1]).is_err());
}

#[test]
fn availability_reads_back_from_layer_json() {
    let c = alps();
    let layer = layer_json("t", &c, "", "v1");
    assert_eq!(Availability::from_layer(&layer).unwrap(), Availability::of(&c));
    let mut bad = layer.clone();
    bad["available"][3][0]["endX"] = json!(1_000);
    assert!(Availability::from_layer(&bad).unwrap_err().to_string().contains("available[3]"));
    assert!(Availability::from_layer(&json!({})).is_err());
    assert!(Availability::from_layer(&json!({"available": [[{"startX": -1}]]})).is_err());
}

#[test]
fn tileset_has_two_implicit_hemispheres() {
    let avail = Availability::of(&alps());
    let t = tileset_json(&avail, 77_067.0, "abc");
    assert_eq!(t["asset"]["version"], "1.1");
    let kids = t["root"]["children"].as_array().unwrap();
    assert_eq!(kids.len(), 2);
    let pi = std::f64::consts::PI;
    for (r, k) in kids.iter().enumerate() {
        let reg: Vec<f64> =
            k["boundingVolume"]["region"].as_array().unwrap().iter().map(|v| v.as_f64().unwrap()).collect();
        assert_eq!(reg[0], -pi + r as f64 * pi);
        assert_eq!(reg[2], r as f64 * pi);
        assert_eq!(k["implicitTiling"]["subdivisionScheme"], "QUADTREE");
        assert_eq!(k["implicitTiling"]["availableLevels"], 10);
        assert_eq!(k["implicitTiling"]["subtreeLevels"], SUBTREE_LEVELS);
        assert_eq!(k["content"]["uri"], format!("tiles/{r}/{{level}}/{{x}}/{{y}}.glb?v=abc"));
        assert_eq!(
            k["implicitTiling"]["subtrees"]["uri"],
            format!("subtrees/{r}/{{level}}/{{x}}/{{y}}.subtree?v=abc")
        );
        assert_eq!(k["geometricError"], 77_067.0);
    }
    let props = &t["schema"]["classes"]["tile"]["properties"];
    let semantics: Vec<&str> = ["minimumHeight", "maximumHeight", "boundingSphere", "horizonOcclusionPoint"]
        .iter()
        .map(|p| props[p]["semantic"].as_str().unwrap())
        .collect();
    assert_eq!(
        semantics,
        [
            "TILE_MINIMUM_HEIGHT",
            "TILE_MAXIMUM_HEIGHT",
            "TILE_BOUNDING_SPHERE",
            "TILE_HORIZON_OCCLUSION_POINT"
        ]
    );
    assert_eq!(
        tileset_json(&avail, 1.0, "")["root"]["children"][0]["content"]["uri"],
        "tiles/0/{level}/{x}/{y}.glb"
    );
}

#[test]
fn tileset_from_a_layer_document() {
    let layer = layer_json("t", &alps(), "", "v7");
    assert_eq!(layer_version(&layer), "v7");
    assert_eq!(layer_version(&json!({"tiles": ["{z}/{x}/{y}.terrain"]})), "");
    let t: Value = serde_json::from_slice(&tileset_from_layer(&layer, 5.0).unwrap()).unwrap();
    assert_eq!(t["root"]["children"][1]["content"]["uri"], "tiles/1/{level}/{x}/{y}.glb?v=v7");
    assert_eq!(t["root"]["children"][1]["implicitTiling"]["availableLevels"], 10);
    assert_eq!(t["root"]["geometricError"], 10.0);
    assert!(tileset_from_layer(&json!({"tiles": []}), 5.0).is_err());
    let stats = json!({"per_zoom": {"0": {"bound": 38_533.5}, "1": {"bound": 1.0}}});
    assert_eq!(level0_error_of_stats(&stats), Some(38_533.5));
    assert_eq!(level0_error_of_stats(&json!({"per_zoom": {"0": {"bound": -1.0}}})), None);
}
