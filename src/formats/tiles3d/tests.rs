#![allow(clippy::float_cmp)] // placements of exact values are exact

use serde_json::{Value, json};

use super::*;
use crate::codec::{Geometry, Quantization, decode, encode_mesh, encode_points};
use crate::geom::{Bounds, ErrorFigures, Mesh, PointCloud};
use crate::raster::Georef;
use crate::store::{LevelTotals, Manifest, SUBTREE_LEVELS, SourceInfo, TilesetKind};
use crate::tiling::TileKey;

#[test]
fn anchors_parse_and_are_range_checked() {
    assert_eq!(Anchor::parse("138.7,35.3").unwrap(), Anchor { lon: 138.7, lat: 35.3, height: 0.0 });
    assert_eq!(
        Anchor::parse(" -70.5 , -33.4 , 520 ").unwrap(),
        Anchor { lon: -70.5, lat: -33.4, height: 520.0 }
    );
    for bad in ["200,0", "0,95", "a,b", "1", "1,2,3,4", "0,0,1e300", "NaN,0", "inf,0", ""] {
        let e = Anchor::parse(bad).unwrap_err().to_string();
        assert!(e.contains("anchor"), "{bad}: {e}");
    }
    let e = |s: &str| Anchor::parse(s).unwrap_err().to_string();
    assert_eq!(e("1"), r#"anchor "1": expected LON,LAT or LON,LAT,HEIGHT"#);
    assert_eq!(e("a,0"), r#"anchor "a,0": longitude "a" is not a number"#);
    assert_eq!(e("0,95"), r#"anchor "0,95": latitude 95 is not within -90..90 degrees"#);
    assert_eq!(e("200,0"), r#"anchor "200,0": longitude 200 is not within -180..180 degrees"#);
    assert_eq!(e("0,0,2e7"), r#"anchor "0,0,2e7": height 20000000 is not within ±1e7 m"#);
}

#[test]
fn enu_frame_at_the_anchor() {
    let m = Anchor { lon: 0.0, lat: 0.0, height: 0.0 }.enu_to_ecef();
    let close = |a: &[f64], b: &[f64]| a.iter().zip(b).all(|(x, y)| (x - y).abs() < 1e-9);
    assert!(close(&m[0..3], &[0.0, 1.0, 0.0]), "east {:?}", &m[0..3]);
    assert!(close(&m[4..7], &[0.0, 0.0, 1.0]), "north {:?}", &m[4..7]);
    assert!(close(&m[8..11], &[1.0, 0.0, 0.0]), "up {:?}", &m[8..11]);
    assert!(close(&m[12..16], &[6_378_137.0, 0.0, 0.0, 1.0]));
    let pole = Anchor { lon: 0.0, lat: 90.0, height: 0.0 }.ecef();
    assert!((pole[2] - 6_356_752.314_245).abs() < 1e-3, "{pole:?}");
    // 100 m up is 100 m along the up vector.
    let a = Anchor { lon: 138.7, lat: 35.3, height: 0.0 };
    let b = Anchor { height: 100.0, ..a };
    let (pa, pb, up) = (a.ecef(), b.ecef(), &a.enu_to_ecef()[8..11]);
    for i in 0..3 {
        assert!((pb[i] - pa[i] - 100.0 * up[i]).abs() < 1e-6);
    }
}

fn manifest(frame: Georef, bounds: Bounds) -> Manifest {
    Manifest {
        format: crate::store::MANIFEST_FORMAT.into(),
        version: 1,
        content_version: "00000000".into(),
        source: SourceInfo { file: "t".into(), format: "t".into(), width: 33, height: 33, nodata_filled: 0 },
        frame,
        tile_size: 32,
        depth: 0,
        subtree_levels: SUBTREE_LEVELS,
        bounds,
        levels: Vec::new(),
        totals: vec![LevelTotals::default()],
        options: Value::Null,
        point_baker: String::new(),
    }
}

/// A 5×5-sample grid mesh (cells `cell`), heights from `h`, CCW in (col, row) space.
fn grid_mesh(cell: [f64; 2], h: impl Fn(usize, usize) -> f64) -> Mesh {
    let mut m = Mesh::default();
    for r in 0..5 {
        for c in 0..5 {
            m.positions.push([c as f64 * cell[0], r as f64 * cell[1], h(c, r)]);
        }
    }
    for r in 0..4u32 {
        for c in 0..4u32 {
            let i = r * 5 + c;
            m.triangles.push([i, i + 1, i + 6]);
            m.triangles.push([i, i + 6, i + 5]);
        }
    }
    m
}

fn read_positions(glb: &[u8]) -> (Value, Vec<[f64; 3]>) {
    let jl = u32::from_le_bytes(glb[12..16].try_into().unwrap()) as usize;
    let json: Value = serde_json::from_slice(&glb[20..20 + jl]).unwrap();
    let bin = &glb[28 + jl..];
    let acc = &json["accessors"][0];
    let view = &json["bufferViews"][acc["bufferView"].as_u64().unwrap() as usize];
    let off = view["byteOffset"].as_u64().unwrap() as usize;
    let stride = view["byteStride"].as_u64().unwrap() as usize;
    let node = &json["nodes"][0];
    let t: Vec<f64> = node["translation"].as_array().unwrap().iter().map(|v| v.as_f64().unwrap()).collect();
    let s: Vec<f64> = node["scale"].as_array().unwrap().iter().map(|v| v.as_f64().unwrap()).collect();
    let u16s = acc["componentType"] == 5123;
    let pos = (0..acc["count"].as_u64().unwrap() as usize)
        .map(|i| {
            std::array::from_fn(|a| {
                let o = off + i * stride;
                let q = if u16s {
                    f64::from(u16::from_le_bytes([bin[o + 2 * a], bin[o + 2 * a + 1]]))
                } else {
                    f64::from(f32::from_le_bytes(bin[o + 4 * a..o + 4 * a + 4].try_into().unwrap()))
                };
                t[a] + s[a] * q
            })
        })
        .collect();
    (json, pos)
}

/// The triangle indices of a GLB's mesh, whatever their width (8, 16 or 32 bits).
fn read_indices(glb: &[u8]) -> Vec<usize> {
    let jl = u32::from_le_bytes(glb[12..16].try_into().unwrap()) as usize;
    let json: Value = serde_json::from_slice(&glb[20..20 + jl]).unwrap();
    let bin = &glb[28 + jl..];
    let acc = &json["accessors"][json["meshes"][0]["primitives"][0]["indices"].as_u64().unwrap() as usize];
    let off = json["bufferViews"][acc["bufferView"].as_u64().unwrap() as usize]["byteOffset"]
        .as_u64()
        .unwrap() as usize;
    let width = match acc["componentType"].as_u64().unwrap() {
        5121 => 1,
        5123 => 2,
        5125 => 4,
        other => panic!("index component type {other}"),
    };
    (0..acc["count"].as_u64().unwrap() as usize)
        .map(|i| {
            let b = &bin[off + width * i..off + width * (i + 1)];
            b.iter().rev().fold(0usize, |v, &x| v << 8 | usize::from(x))
        })
        .collect()
}

#[test]
fn glb_positions_are_the_blobs_grid_placed_and_triangles_face_up() {
    // North-up (dy < 0) and image rows (dy > 0); a small z range (16-bit) and a large one (float).
    for (dy, z_step, relief) in [(-10.0, 0.25, 40.0), (10.0, 0.25, 40.0), (-10.0, 1.0 / 64.0, 3000.0)] {
        let frame = Georef { dx: 10.0, dy, ..Georef::default() };
        let mesh = grid_mesh([10.0, dy], |c, r| (c * r) as f64 * relief / 16.0 + 0.3);
        let bounds = Bounds::of_points(&mesh.positions);
        let q = Quantization { xy_step: 10.0, z_step };
        let bytes =
            encode_mesh(TileKey::new(0, 0, 0), 0, &bounds, q, &mesh, ErrorFigures::default()).unwrap();
        let blob = decode(&bytes).unwrap();
        let m = manifest(frame, bounds);
        let place = Placement::of(&m, TilesetKind::Terrain, None).unwrap();
        let glb = glb(&blob, &place, None, &[]).unwrap();
        let (json, got) = read_positions(&glb);
        let big = relief / z_step > 65_535.0;
        assert_eq!(json["accessors"][0]["componentType"], if big { 5126 } else { 5123 });
        // Normals are bytes (KHR_mesh_quantization) whatever the positions are.
        assert_eq!(json["extensionsRequired"], json!(["KHR_mesh_quantization"]));
        let Geometry::Mesh(world) = &blob.geometry else { panic!() };
        for (w, g) in world.positions.iter().zip(&got) {
            let want = place.gltf_of(*w);
            for a in 0..3 {
                assert!((want[a] - g[a]).abs() < 1e-9, "{want:?} vs {g:?}");
            }
        }
        // Indices follow the positions: triangles face up (east, north) = (x, −z) in glTF.
        let idx = read_indices(&glb);
        for t in idx.chunks(3) {
            let en = |i: usize| [got[i][0], -got[i][2]];
            let (a, b, c) = (en(t[0]), en(t[1]), en(t[2]));
            assert!(
                (b[0] - a[0]) * (c[1] - a[1]) - (b[1] - a[1]) * (c[0] - a[0]) > 0.0,
                "dy {dy}: a triangle faces down"
            );
        }
    }
}

#[test]
fn skirts_hang_on_the_grid_below_inner_borders_only() {
    let frame = Georef { dx: 10.0, dy: -10.0, ..Georef::default() };
    let mesh = grid_mesh([10.0, -10.0], |c, _| c as f64);
    let bounds = Bounds::of_points(&mesh.positions);
    let q = Quantization { xy_step: 10.0, z_step: 0.125 };
    let blob =
        decode(&encode_mesh(TileKey::new(0, 0, 0), 0, &bounds, q, &mesh, ErrorFigures::default()).unwrap())
            .unwrap();
    let place = Placement::of(&manifest(frame, bounds), TilesetKind::Terrain, None).unwrap();
    let plain = read_positions(&glb(&blob, &place, None, &[]).unwrap()).1;
    // The dataset is larger than the tile on every side but the west one: no skirt there.
    let outer = Bounds::new([0.0, -100.0, 0.0], [100.0, 40.0, 10.0]);
    let (_, skirted) = read_positions(&glb(&blob, &place, Some((0.3, Some(&outer))), &[]).unwrap());
    assert_eq!(plain.len(), 25);
    // 16 border vertices, less the 4 on the west edge that get no wall (the corners stay).
    assert!(skirted.len() > 25, "{}", skirted.len());
    for p in &skirted[25..] {
        // 0.3 rounded up to whole steps of 0.125: 0.375 below a border vertex.
        let above = plain.iter().find(|q| (q[0] - p[0]).abs() < 1e-9 && (q[2] - p[2]).abs() < 1e-9).unwrap();
        assert!((above[1] - p[1] - 0.375).abs() < 1e-9, "{p:?} under {above:?}");
    }
    // Walls face outward in the tileset frame, for a north-up frame and a mirrored (image) one.
    for dy in [-10.0, 10.0] {
        let frame = Georef { dx: 10.0, dy, ..Georef::default() };
        let mesh = grid_mesh([10.0, dy], |c, _| c as f64);
        let bounds = Bounds::of_points(&mesh.positions);
        let blob = decode(
            &encode_mesh(TileKey::new(0, 0, 0), 0, &bounds, q, &mesh, ErrorFigures::default()).unwrap(),
        )
        .unwrap();
        let place = Placement::of(&manifest(frame, bounds), TilesetKind::Terrain, None).unwrap();
        let g = glb(&blob, &place, Some((0.3, None)), &[]).unwrap();
        let (_, pos) = read_positions(&g);
        let idx = read_indices(&g);
        let centre = pos[..25]
            .iter()
            .fold([0.0; 3], |a, p| [a[0] + p[0] / 25.0, a[1] + p[1] / 25.0, a[2] + p[2] / 25.0]);
        let walls = idx.chunks(3).skip(32).collect::<Vec<_>>();
        assert_eq!(walls.len(), 32, "two triangles under each of the 16 border edges");
        for t in walls {
            let [a, b, c] = [pos[t[0]], pos[t[1]], pos[t[2]]].map(glam::DVec3::from_array);
            let n = (b - a).cross(c - a);
            let out = (a + b + c) / 3.0 - glam::DVec3::from_array(centre);
            assert!(n.x * out.x + n.z * out.z > 0.0, "dy {dy}: a wall faces inward");
        }
    }
}

#[test]
fn point_normals_are_unit_bytes_in_gltf_axes() {
    let positions = vec![[0.0, 0.0, 1.0], [1.0, 0.0, 2.0], [0.0, 1.0, 3.0], [1.0, 1.0, 4.0]];
    let normals =
        vec![[0.0, 0.0, 1.0], [0.6, 0.0, 0.8], [0.0, -0.6, 0.8], [0.577_350_3, 0.577_350_3, 0.577_350_3]];
    let pc = PointCloud { positions: positions.clone(), normals: normals.clone() };
    let bounds = Bounds::of_points(&positions);
    let q = Quantization { xy_step: 0.01, z_step: 0.01 };
    let blob =
        decode(&encode_points(TileKey::new(0, 0, 0), 1, &bounds, q, &pc, ErrorFigures::default()).unwrap())
            .unwrap();
    let frame = Georef { dx: 1.0, dy: -1.0, ..Georef::default() };
    let place = Placement::of(&manifest(frame, bounds), TilesetKind::Terrain, None).unwrap();
    let glb = glb(&blob, &place, None, &[]).unwrap();
    let jl = u32::from_le_bytes(glb[12..16].try_into().unwrap()) as usize;
    let json: Value = serde_json::from_slice(&glb[20..20 + jl]).unwrap();
    let bin = &glb[28 + jl..];
    assert_eq!(json["meshes"][0]["primitives"][0]["mode"], 0);
    let acc = &json["accessors"][1];
    assert_eq!((acc["componentType"].as_u64(), acc["normalized"].as_bool()), (Some(5120), Some(true)));
    let off = json["bufferViews"][acc["bufferView"].as_u64().unwrap() as usize]["byteOffset"]
        .as_u64()
        .unwrap() as usize;
    let Geometry::Points(decoded) = &blob.geometry else { panic!() };
    for (i, n) in decoded.normals.iter().enumerate() {
        let g: [f64; 3] = std::array::from_fn(|a| f64::from(bin[off + 4 * i + a] as i8) / 127.0);
        let len = (g[0] * g[0] + g[1] * g[1] + g[2] * g[2]).sqrt();
        assert!((len - 1.0).abs() < 0.005, "length {len}");
        // glTF (x, y, z) = (east, up, −north) = (x, z, −y) for a north-up frame.
        let want = [f64::from(n[0]), f64::from(n[2]), -f64::from(n[1])];
        let cos = (g[0] * want[0] + g[1] * want[1] + g[2] * want[2]) / len;
        assert!(cos > 0.9995, "{g:?} vs {want:?}");
    }
}

#[test]
fn models_stand_on_their_base_at_the_anchor() {
    let bounds = Bounds::new([-1.0, 2.0, -3.0], [1.0, 6.0, 5.0]);
    let m = manifest(Georef::default(), bounds);
    let a = Anchor { lon: 1.0, lat: 2.0, height: 3.0 };
    let place = Placement::of(&m, TilesetKind::Model, Some(a)).unwrap();
    assert_eq!((place.from, place.anchor), (AnchorFrom::Option, a));
    // The base centre is the origin; +y is up, −z is north (glTF's own axes).
    assert_eq!(place.enu_of([0.0, 2.0, 1.0]), [0.0, 0.0, 0.0]);
    assert_eq!(place.enu_of([0.0, 5.0, 1.0]), [0.0, 0.0, 3.0]);
    assert_eq!(place.enu_of([0.0, 2.0, 0.0]), [0.0, 1.0, 0.0]);
    assert!(!place.mirrored());
}

/// Every tile under `t` (and `t`) has a geometric error at most its parent's (`cap`).
fn walk_chain(t: &Value, cap: f64, n: &mut usize) {
    let e = t["geometricError"].as_f64().unwrap();
    assert!(e <= cap, "{e} under {cap}");
    *n += 1;
    for c in t["children"].as_array().into_iter().flatten() {
        walk_chain(c, e, n);
    }
}

/// The 3D Tiles chain stays monotone whatever the measured errors: a child mesh measured above
/// its parent's, point levels finer than their own mesh, coarser than the tile above, out of
/// order — a child's `geometricError` never exceeds its parent's, and a listed point level keeps
/// its own error.
#[test]
fn error_chain_is_monotone_for_any_measured_errors() {
    use crate::store::{IndexChunk, NodeEntry, NodeLevel};
    let bounds = Bounds::new([0.0, 0.0, 0.0], [64.0, 64.0, 10.0]);
    let mut m = manifest(Georef { dx: 1.0, dy: 1.0, ..Georef::default() }, bounds);
    m.source.width = 65;
    m.source.height = 65;
    m.depth = 2;
    let info = TilesetInfo::new(
        "t",
        TilesetKind::Terrain,
        m.clone(),
        Placement::of(&m, TilesetKind::Terrain, None).unwrap(),
        String::new(),
    );
    let level = |level: u8, e: f64| NodeLevel {
        level,
        errors: ErrorFigures { max: e, rms: 0.0, gap: 0.0 },
        count: 10,
        triangles: 0,
        bytes: 10,
        checksum: 0,
    };
    let p = info.pyramid.unwrap();
    let mut seed = 9u64;
    for _ in 0..50 {
        let mut nodes = Vec::new();
        for key in p.nodes() {
            let mut next = || {
                seed = seed.wrapping_mul(6_364_136_223_846_793_005).wrapping_add(1_442_695_040_888_963_407);
                ((seed >> 33) % 100) as f64
            };
            let levels = (0..4).map(|l| level(l, next())).collect();
            nodes.push(NodeEntry { key, bounds: info.planned_bounds(key), levels });
        }
        let chunk = IndexChunk { root: TileKey::new(0, 0, 0), nodes: nodes.clone() };
        let doc = chunk_tileset(&info, &chunk, true, f64::INFINITY).unwrap();
        let mut n = 0;
        walk_chain(&doc["root"], f64::INFINITY, &mut n);
        assert!(n >= nodes.len());
    }
}

#[test]
fn steep_meshes_get_16_bit_positions_within_an_eighth_of_their_error() {
    // 3,000 m of relief in steps of 1/64 m: 192,000 steps, too many for 16 bits. With a measured
    // error of 1 m the GLB may use steps of 1/8 m at most: 4× the blob's (1/16 m) fits.
    let frame = Georef { dx: 10.0, dy: -10.0, ..Georef::default() };
    let mesh = grid_mesh([10.0, -10.0], |c, r| (c * r) as f64 * 3000.0 / 16.0 + 0.3 + (c as f64) / 64.0);
    let bounds = Bounds::of_points(&mesh.positions);
    let q = Quantization { xy_step: 10.0, z_step: 1.0 / 64.0 };
    for (max_error, coarse) in [(1.0, true), (0.4, false), (0.0, false)] {
        let errors = ErrorFigures { max: max_error, ..ErrorFigures::default() };
        let blob =
            decode(&encode_mesh(TileKey::new(0, 0, 0), 0, &bounds, q, &mesh, errors).unwrap()).unwrap();
        let place = Placement::of(&manifest(frame.clone(), blob.header.bounds()), TilesetKind::Terrain, None)
            .unwrap();
        for skirt in [None, Some((0.7, None))] {
            let glb = glb(&blob, &place, skirt, &[]).unwrap();
            let (json, got) = read_positions(&glb);
            assert_eq!(
                json["accessors"][0]["componentType"],
                if coarse { 5123 } else { 5126 },
                "{max_error}"
            );
            // One step on every axis (normals render as written): the coarse grid's, or metres.
            let scale = json["nodes"][0]["scale"][1].as_f64().unwrap();
            assert_eq!(scale, if coarse { 1.0 / 16.0 } else { 1.0 });
            assert_eq!(json["nodes"][0]["scale"], json!([scale, scale, scale]));
            let Geometry::Mesh(world) = &blob.geometry else { panic!() };
            let (lo, hi) = (place.gltf_of(blob.header.bounds[0]), place.gltf_of(blob.header.bounds[1]));
            for (w, g) in world.positions.iter().zip(&got) {
                let want = place.gltf_of(*w);
                for a in 0..3 {
                    let d = (want[a] - g[a]).abs();
                    assert!(d <= max_error / 8.0 + 1e-9, "{want:?} vs {g:?}");
                    if !coarse {
                        assert!(d < 1e-9);
                    }
                    assert!(
                        g[a] >= lo[a].min(hi[a]) - 1e-9 && g[a] <= lo[a].max(hi[a]) + 1e-9,
                        "{g:?} outside"
                    );
                }
            }
            if let Some((depth, _)) = skirt {
                // Skirt vertices hang whole z steps (0.7 → 0.75 coarse) below a surface vertex.
                let n = world.positions.len();
                assert!(got.len() > n);
                for p in &got[n..] {
                    let above = got[..n]
                        .iter()
                        .find(|t| (t[0] - p[0]).abs() < 1e-9 && (t[2] - p[2]).abs() < 1e-9)
                        .unwrap();
                    let d = above[1] - p[1];
                    let z = if coarse { scale } else { q.z_step };
                    assert!(d >= depth && ((d / z).round() * z - d).abs() < 1e-9, "{d}");
                }
            }
        }
    }
}

#[test]
fn coarse_grids_of_neighbours_agree_and_stay_in_bounds() {
    use super::glb::CoarseGrid;
    // Two blobs on one global z grid (steps of 1/64 from different origins) round a shared height
    // to the same coarse height, whatever their own origins.
    let step = [10.0, 10.0, 1.0 / 64.0];
    let a = [[0.0, 0.0, 3.0 / 64.0], [100.0, 100.0, 3000.0]];
    let b = [[100.0, 0.0, 7.0 / 64.0], [200.0, 100.0, 3000.0]];
    let shared = [100.0, 50.0, 1234.0 + 5.0 / 64.0];
    let ga = CoarseGrid::fit(&[a[0], a[1], shared], &a, step, 0.0, 1.0, [0; 3]).unwrap();
    let gb = CoarseGrid::fit(&[b[0], b[1], shared], &b, step, 0.0, 1.0, [0; 3]).unwrap();
    assert_eq!(ga.step, [10.0, 10.0, 1.0 / 16.0]);
    assert_eq!(ga.snap(shared), gb.snap(shared));
    // Seeded random grids: every snapped point in the bounds, within a coarse step, 16 bits.
    let mut s = 0x2545_f491_4f6c_dd1du64;
    let mut next = || {
        s ^= s << 13;
        s ^= s >> 7;
        s ^= s << 17;
        (s >> 11) as f64 / (1u64 << 53) as f64
    };
    for _ in 0..200 {
        let st = 2f64.powi(-(next() * 10.0) as i32);
        let min = [0.0, 0.0, (next() * 1e5).round() * st];
        let max = [50.0, 50.0, min[2] + (next() * 300_000.0).round() * st];
        let pts: Vec<[f64; 3]> = (0..50)
            .map(|_| {
                [
                    (next() * 50.0).round(),
                    (next() * 50.0).round(),
                    min[2] + (next() * (max[2] - min[2]) / st).round() * st,
                ]
            })
            .collect();
        let Some(g) = CoarseGrid::fit(&pts, &[min, max], [1.0, 1.0, st], 3.0 * st, f64::INFINITY, [0; 3])
        else {
            panic!()
        };
        let (mut lo, mut hi) = (f64::INFINITY, f64::NEG_INFINITY);
        for p in &pts {
            let c = g.snap(*p);
            assert!((c[2] - p[2]).abs() <= g.step[2] + 1e-9 * max[2].abs().max(1.0));
            assert!(c[2] >= min[2] - 1e-9 && c[2] <= max[2] + 1e-9, "{c:?} outside {min:?}..{max:?}");
            lo = lo.min(c[2]);
            hi = hi.max(c[2]);
        }
        assert!(((hi - lo) / g.step[2]).round() <= 65_535.0);
    }
    // Nonsense in, no grid out (and no panic).
    for bad in [f64::NAN, f64::INFINITY, 0.0, -1.0] {
        assert!(
            CoarseGrid::fit(&[[0.0; 3]], &[[0.0; 3], [1.0; 3]], [1.0, 1.0, bad], 0.0, 1.0, [0; 3]).is_none()
        );
    }
    assert!(CoarseGrid::fit(&[[f64::NAN; 3]], &[[0.0; 3], [1.0; 3]], [1.0; 3], 0.0, 1.0, [0; 3]).is_none());
    assert!(CoarseGrid::fit(&[[0.0; 3]], &[[0.0; 3], [1e300; 3]], [1e-300; 3], 0.0, 1.0, [0; 3]).is_none());
}

#[test]
fn glb_container_pads_both_chunks_and_reads_back() {
    for bin_len in 0..9usize {
        let doc = json!({ "asset": { "version": "2.0" }, "n": bin_len });
        let bin: Vec<u8> = (1..=bin_len as u8).collect();
        let out = glb::write_glb(&doc, bin.clone());
        assert_eq!(&out[..4], b"glTF");
        assert_eq!(u32::from_le_bytes(out[8..12].try_into().unwrap()) as usize, out.len());
        let jlen = u32::from_le_bytes(out[12..16].try_into().unwrap()) as usize;
        assert_eq!(jlen % 4, 0);
        let blen = u32::from_le_bytes(out[20 + jlen..24 + jlen].try_into().unwrap()) as usize;
        assert_eq!(blen, bin_len.next_multiple_of(4));
        assert_eq!(out.len(), 28 + jlen + blen);
        let (j, b) = meshopt::read_glb(&out).unwrap();
        assert_eq!(j, doc);
        assert_eq!(&b[..bin_len], &bin[..]);
        assert!(b[bin_len..].iter().all(|&z| z == 0), "BIN is zero-padded");
        assert!(out[20..20 + jlen].ends_with(b"}") || out[20..20 + jlen].ends_with(b" "));
    }
}

/// The normals a renderer draws: glTF transforms a `NORMAL` by the inverse transpose of its
/// node's transform (here `scale`, rotations aside), then normalizes it.
fn rendered_normals(glb: &[u8]) -> Vec<[f64; 3]> {
    let jl = u32::from_le_bytes(glb[12..16].try_into().unwrap()) as usize;
    let json: Value = serde_json::from_slice(&glb[20..20 + jl]).unwrap();
    let bin = &glb[28 + jl..];
    let acc = &json["accessors"]
        [json["meshes"][0]["primitives"][0]["attributes"]["NORMAL"].as_u64().unwrap() as usize];
    assert_eq!(acc["componentType"], 5120);
    let view = &json["bufferViews"][acc["bufferView"].as_u64().unwrap() as usize];
    let off = view["byteOffset"].as_u64().unwrap() as usize;
    let s: Vec<f64> =
        json["nodes"][0]["scale"].as_array().unwrap().iter().map(|v| v.as_f64().unwrap()).collect();
    (0..acc["count"].as_u64().unwrap() as usize)
        .map(|i| {
            let n: [f64; 3] = std::array::from_fn(|a| f64::from(bin[off + 4 * i + a] as i8) / 127.0 / s[a]);
            let l = (n[0] * n[0] + n[1] * n[1] + n[2] * n[2]).sqrt();
            n.map(|c| c / l)
        })
        .collect()
}

#[test]
fn normals_render_as_the_surfaces_whatever_the_grids_steps() {
    // A plane rising 1 m per 2 m east (26.6°). With 10 m cells and 1/64 m height steps the
    // blob's grid is 640× finer in z than in x and y. Drawn through the node's transform, every
    // normal must be the plane's: on the blob's own grid, a coarse one, or in metres (0.3 m cells
    // are no whole number of height steps).
    let want = glam::DVec3::new(-0.5, 1.0, 0.0).normalize(); // glTF: x east, y up
    for (xy_step, z_step) in [(10.0, 1.0 / 64.0), (10.0, 0.25), (1.0, 1.0 / 64.0), (0.3, 1.0 / 64.0)] {
        let mesh = grid_mesh([xy_step, -xy_step], |c, _| c as f64 * xy_step * 0.5 + 100.0);
        let bounds = Bounds::of_points(&mesh.positions);
        let q = Quantization { xy_step, z_step };
        let errors = ErrorFigures { max: 1.0, ..ErrorFigures::default() };
        let blob =
            decode(&encode_mesh(TileKey::new(0, 0, 0), 0, &bounds, q, &mesh, errors).unwrap()).unwrap();
        let frame = Georef { dx: xy_step, dy: -xy_step, ..Georef::default() };
        let place =
            Placement::of(&manifest(frame, blob.header.bounds()), TilesetKind::Terrain, None).unwrap();
        for skirt in [None, Some((0.7, None))] {
            let glb = glb(&blob, &place, skirt, &[]).unwrap();
            for n in &rendered_normals(&glb)[..25] {
                let angle = glam::DVec3::from_array(*n).angle_between(want).to_degrees();
                assert!(angle < 1.5, "{xy_step} {z_step} {skirt:?}: {n:?} is {angle:.1}° off");
            }
        }
    }
}

#[test]
fn glbs_of_random_grids_are_valid_with_one_scale_and_compress() {
    // Seeded random meshes on grids of many cell and height steps (dyadic or not, tiny and
    // huge), reliefs and errors, north-up and row-order frames, with and without skirts: every
    // GLB has one finite scale for all axes, JSON without a null (a non-finite number), its
    // positions within the allowed distance of the blob's, and meshopt and Draco compress it
    // and decode it back.
    let mut seed = 0x9e37_79b9_7f4a_7c15_u64;
    let mut next = || {
        seed ^= seed << 13;
        seed ^= seed >> 7;
        seed ^= seed << 17;
        seed
    };
    let cells = [10.0, 30.0, 0.3, 1.0, 1.0 / 1024.0, 92.6, 1e4];
    let zs = [1.0 / 64.0, 1.0 / 8.0, 0.25, 1e-6, 3.0];
    let reliefs = [1.0, 1e3, 1e5];
    let errors = [0.0, 0.1, 1.0, 100.0];
    let mut checked = 0;
    for _ in 0..120 {
        let pick = |v: &[f64], r: u64| v[(r % v.len() as u64) as usize];
        let (cell, z_step) = (pick(&cells, next()), pick(&zs, next()));
        let (relief, max_error) = (pick(&reliefs, next()), pick(&errors, next()));
        let dy = if next() % 2 == 0 { -cell } else { cell };
        let hs: Vec<f64> = (0..25).map(|_| (next() % 10_000) as f64 / 10_000.0 * relief).collect();
        let mesh = grid_mesh([cell, dy], |c, r| hs[r * 5 + c]);
        let bounds = Bounds::of_points(&mesh.positions);
        let q = Quantization { xy_step: cell, z_step };
        let errs = ErrorFigures { max: max_error, ..ErrorFigures::default() };
        let Ok(bytes) = encode_mesh(TileKey::new(0, 0, 0), 0, &bounds, q, &mesh, errs) else { continue };
        let blob = decode(&bytes).unwrap();
        let frame = Georef { dx: cell, dy, ..Georef::default() };
        let place =
            Placement::of(&manifest(frame, blob.header.bounds()), TilesetKind::Terrain, None).unwrap();
        let Geometry::Mesh(world) = &blob.geometry else { panic!() };
        for skirt in [None, Some((max_error.max(0.5) * 2.0, None))] {
            let what = format!("cell {cell} z {z_step} relief {relief} error {max_error} dy {dy} {skirt:?}");
            let glb = glb(&blob, &place, skirt, &[]).unwrap();
            let (json, got) = read_positions(&glb);
            assert!(!json.to_string().contains("null"), "{what}: {json}");
            let s: Vec<f64> =
                json["nodes"][0]["scale"].as_array().unwrap().iter().map(|v| v.as_f64().unwrap()).collect();
            assert!(s[0] > 0.0 && s[0].is_finite() && s.iter().all(|v| *v == s[0]), "{what}: scale {s:?}");
            // 16-bit grids: exact or within 1/8 of the error; FLOAT metres: within f32 rounding.
            let span = (0..3).map(|a| (bounds.max[a] - bounds.min[a]).abs()).fold(1.0, f64::max);
            let tol = (max_error / 8.0).max(span * 1e-6) + 1e-9;
            for (w, g) in world.positions.iter().zip(&got) {
                let want = place.gltf_of(*w);
                for a in 0..3 {
                    assert!((want[a] - g[a]).abs() <= tol, "{what}: {want:?} vs {g:?}");
                }
            }
            let m = GlbCompression::Meshopt.apply(glb.clone()).unwrap();
            meshopt::decompress_glb(&m).unwrap();
            let d = GlbCompression::Draco.apply(glb).unwrap();
            draco::decompress_glb(&d).unwrap();
            checked += 1;
        }
    }
    assert!(checked > 100, "{checked}");
}

/// Two tiles of one depth share a column of vertices: with each other's fans both draw one
/// normal there, the normal of the surface over both tiles' triangles (what one tile over the
/// whole would draw), whatever the order of the neighbours given; alone each draws its own.
#[test]
fn neighbours_draw_one_normal_on_their_shared_border() {
    let cell = 10.0;
    let h = |x: f64, y: f64| 40.0 * (x / 23.0).sin() * (y / 17.0).cos() + 0.02 * x * y;
    // A 5×5 grid mesh whose first column is sample column `col0` of the whole.
    let tile = |col0: usize| grid_mesh([cell, cell], |c, r| h(((c + col0) as f64) * cell, r as f64 * cell));
    let offset = |m: Mesh, dx: f64| Mesh {
        positions: m.positions.iter().map(|p| [p[0] + dx, p[1], p[2]]).collect(),
        ..m
    };
    let q = Quantization { xy_step: 1.0 / 64.0, z_step: 1.0 / 64.0 };
    let errors = ErrorFigures { max: 1.0, ..ErrorFigures::default() };
    let blob = |key: TileKey, m: &Mesh| {
        decode(&encode_mesh(key, 0, &Bounds::of_points(&m.positions), q, m, errors).unwrap()).unwrap()
    };
    let (left, right) = (tile(0), offset(tile(4), 4.0 * cell));
    let (bl, br) = (blob(TileKey::new(1, 0, 0), &left), blob(TileKey::new(1, 1, 0), &right));
    // The whole: 9 × 5 samples; the reference normals over all its triangles.
    let mut whole = Mesh::default();
    for r in 0..5u32 {
        for c in 0..9u32 {
            let (x, y) = (f64::from(c) * cell, f64::from(r) * cell);
            whole.positions.push([x, y, h(x, y)]);
        }
    }
    for r in 0..4u32 {
        for c in 0..8u32 {
            let i = r * 9 + c;
            whole.triangles.push([i, i + 1, i + 10]);
            whole.triangles.push([i, i + 10, i + 9]);
        }
    }
    let all = Bounds::of_points(&whole.positions);
    let frame = Georef { dx: cell, dy: cell, ..Georef::default() };
    let place = Placement::of(&manifest(frame, all), TilesetKind::Terrain, None).unwrap();
    let sums = crate::geom::vertex_normal_sums(
        &whole.positions.iter().map(|p| place.gltf_of(*p)).collect::<Vec<_>>(),
        &whole.triangles,
    );
    let reference = |p: [f64; 3]| {
        let k = whole.positions.iter().position(|w| (w[0] - p[0]).abs() < 1e-6 && (w[1] - p[1]).abs() < 1e-6);
        let n = sums[k.unwrap()];
        if n.y < 0.0 { -n } else { n }
    };
    let (fl, fr) =
        (BorderFans::of(&bl, &place).unwrap().unwrap(), BorderFans::of(&br, &place).unwrap().unwrap());
    // Vertices of one sample are shared though each blob rounds its position its own way
    // (here 5 cm, 3.2 steps, apart: a blob's grid starts at its own corner).
    let nudged = offset(tile(4), 4.0 * cell + 0.05);
    let fnudged = BorderFans::of(&blob(TileKey::new(1, 1, 0), &nudged), &place).unwrap().unwrap();
    assert_eq!(fl.shared_normals(&[&fnudged]).len(), 5);
    assert_eq!(fl.shared_normals(&[&fr]).len(), 5);
    // A tile of the other end shares nothing and changes nothing.
    let far = offset(tile(40), 40.0 * cell);
    let ff = BorderFans::of(&blob(TileKey::new(1, 3, 3), &far), &place).unwrap().unwrap();
    for skirt in [None, Some((2.0, None))] {
        let gl = glb(&bl, &place, skirt, &[&fr]).unwrap();
        assert_eq!(
            gl,
            glb(&bl, &place, skirt, &[&ff, &fr, &fl]).unwrap(),
            "order and strangers do not matter"
        );
        let gr = glb(&br, &place, skirt, &[&fl, &ff]).unwrap();
        let alone = glb(&bl, &place, skirt, &[]).unwrap();
        assert_eq!(alone, glb(&bl, &place, skirt, &[&ff]).unwrap());
        let (nl, nr, na) = (rendered_normals(&gl), rendered_normals(&gr), rendered_normals(&alone));
        let (pl, pr) = (read_positions(&gl).1, read_positions(&gr).1);
        let mut shared = 0;
        let mut worst_alone = 0.0f64;
        let Geometry::Mesh(decoded) = &bl.geometry else { panic!("a mesh") };
        for (i, p) in pl.iter().enumerate().take(25) {
            let w = place.gltf_of(decoded.positions[i]);
            assert!((0..3).all(|a| (w[a] - p[a]).abs() < 1e-6), "{w:?} {p:?}");
            let want = reference(decoded.positions[i]);
            let a = glam::DVec3::from_array(nl[i]).angle_between(want).to_degrees();
            assert!(a < 1.5, "{skirt:?} vertex {i}: {a:.2}° off the whole's normal");
            // One sample: the same x and y (heights are on each blob's own z grid).
            if let Some(j) =
                pr.iter().take(25).position(|q| [0, 2].iter().all(|&a| (q[a] - p[a]).abs() < 1e-6))
            {
                shared += 1;
                assert_eq!(nl[i], nr[j], "{skirt:?}: vertex {i} is drawn with two normals");
                worst_alone =
                    worst_alone.max(glam::DVec3::from_array(na[i]).angle_between(want).to_degrees());
            }
        }
        assert_eq!(shared, 5);
        assert!(worst_alone > 3.0, "the test's surface must bend across the border ({worst_alone:.2}°)");
        if skirt.is_some() {
            // Skirt vertices hang below the border and take its normal.
            for (k, p) in pl.iter().enumerate().skip(25) {
                let top = pl.iter().take(25).position(|t| t[0] == p[0] && t[2] == p[2]).unwrap();
                assert_eq!(nl[k], nl[top]);
            }
        }
    }
}

/// The memo of fans makes each entry once while it holds it, and never holds more than its
/// budget: full, it starts over.
#[test]
fn fan_memo_makes_once_and_stays_within_its_budget() {
    let memo = border::FanCache::new(1000);
    let made = std::cell::Cell::new(0);
    let get = |k: u32| {
        memo.get_or_make(k, || {
            made.set(made.get() + 1);
            Ok::<_, ()>(None)
        })
        .unwrap()
    };
    get(1);
    get(1);
    assert_eq!(made.get(), 1);
    for k in (0..100).chain(0..100) {
        get(k);
        let (entries, bytes) = memo.held();
        assert!(bytes <= 1000 && entries >= 1, "{entries} entries, {bytes} bytes");
    }
    assert!(made.get() > 150, "entries were forgotten and made again: {}", made.get());
    // An entry larger than the whole budget is returned, not kept.
    let tiny = border::FanCache::new(10);
    tiny.get_or_make(0, || Ok::<_, ()>(None)).unwrap();
    assert_eq!(tiny.held(), (0, 0));
}

/// Draco GLBs round normals from the exact directions: a tile's own vertex moves at most
/// [`draco::STEER_DEGREES`] (to Draco's own prediction, which then costs no correction, so the
/// stream is smaller than the bytes' rounding), a vertex shared with a neighbour takes the
/// nearest rounding on both sides (one normal on the border, as in plain GLBs), a skirt vertex
/// exactly its top's.
#[test]
fn draco_normals_steer_within_their_bound_and_keep_borders_whole() {
    use super::glb::{NormalRole, glb_and_normals};
    let (cell, n) = (10.0, 17usize);
    let h = |x: f64, y: f64| 60.0 * (x / 47.0).sin() * (y / 31.0).cos() + 0.03 * x * y;
    let tile = |col0: usize| {
        let mut m = Mesh::default();
        for r in 0..n {
            for c in 0..n {
                let x = (c + col0) as f64 * cell;
                m.positions.push([x, r as f64 * cell, h(x, r as f64 * cell)]);
            }
        }
        for r in 0..n as u32 - 1 {
            for c in 0..n as u32 - 1 {
                let i = r * n as u32 + c;
                m.triangles.push([i, i + 1, i + n as u32 + 1]);
                m.triangles.push([i, i + n as u32 + 1, i + n as u32]);
            }
        }
        m
    };
    let q = Quantization { xy_step: 1.0 / 16.0, z_step: 1.0 / 16.0 };
    let errors = ErrorFigures { max: 1.0, ..ErrorFigures::default() };
    let blob = |key: TileKey, m: &Mesh| {
        decode(&encode_mesh(key, 0, &Bounds::of_points(&m.positions), q, m, errors).unwrap()).unwrap()
    };
    let (left, right) = (tile(0), tile(n - 1));
    let (bl, br) = (blob(TileKey::new(1, 0, 0), &left), blob(TileKey::new(1, 1, 0), &right));
    let all = Bounds::of_points(&[left.positions.clone(), right.positions.clone()].concat());
    let frame = Georef { dx: cell, dy: cell, ..Georef::default() };
    let place = Placement::of(&manifest(frame, all), TilesetKind::Terrain, None).unwrap();
    let (fl, fr) =
        (BorderFans::of(&bl, &place).unwrap().unwrap(), BorderFans::of(&br, &place).unwrap().unwrap());
    let skirt = Some((2.0, None));
    // Per side: (plain positions, exact normals, decoded Draco normals in plain order).
    let side = |b: &crate::codec::Blob| {
        let (plain, exact) = glb_and_normals(b, &place, skirt, &[&fl, &fr]).unwrap();
        let exact = exact.unwrap();
        let steered = draco::compress_glb_with(&plain, Some(&exact)).unwrap();
        let unsteered = draco::compress_glb(&plain).unwrap();
        assert!(
            steered.len() * 100 < unsteered.len() * 97,
            "steering saves nothing: {} vs {} bytes",
            steered.len(),
            unsteered.len()
        );
        let (json, pos) = read_positions(&plain);
        let [d] = &draco::decompress_glb(&steered).unwrap()[..] else { panic!("one primitive") };
        let t: Vec<f64> =
            json["nodes"][0]["translation"].as_array().unwrap().iter().map(|v| v.as_f64().unwrap()).collect();
        let s = json["nodes"][0]["scale"][0].as_f64().unwrap();
        let normals: Vec<[f64; 3]> = pos
            .iter()
            .map(|p| {
                let k = d
                    .positions
                    .iter()
                    .position(|q| (0..3).all(|a| (t[a] + s * f64::from(q[a]) - p[a]).abs() < 1e-9));
                d.normals.as_ref().unwrap()[k.expect("every vertex decoded")].map(f64::from)
            })
            .collect();
        (pos, exact, normals)
    };
    let (pl, el, nl) = side(&bl);
    let (pr, _, nr) = side(&br);
    let (mut own, mut shared, mut skirts) = (0, 0, 0);
    for (i, role) in el.roles.iter().enumerate() {
        let angle = glam::DVec3::from_array(el.directions[i])
            .angle_between(glam::DVec3::from_array(nl[i]))
            .to_degrees();
        match *role {
            NormalRole::Own => {
                own += 1;
                assert!(angle <= draco::STEER_DEGREES + 1e-3, "vertex {i}: {angle:.3}° off");
            }
            NormalRole::Shared => {
                shared += 1;
                assert!(angle <= 1.0, "shared vertex {i}: {angle:.3}° off");
                let j = pr.iter().position(|q| [0, 2].iter().all(|&a| (q[a] - pl[i][a]).abs() < 1e-6));
                assert_eq!(nl[i], nr[j.expect("on the neighbour")], "vertex {i}: two normals on the border");
            }
            NormalRole::Below(top) => {
                skirts += 1;
                assert_eq!(nl[i], nl[top as usize], "skirt vertex {i}");
            }
        }
    }
    assert_eq!(shared, n);
    assert!(own > 200 && skirts > 40, "{own} own, {skirts} skirt vertices");
}
