//! 3D Tiles 1.1 from a baked tileset: `export --format 3dtiles` and the server's `/3dtiles/`
//! routes give the same documents; every stored (tile, level) is one tile whose GLB holds
//! exactly the blob's positions placed in the tileset frame; external tilesets per index chunk;
//! caching semantics as for blobs; on-demand tilesets list what is not baked yet.

#![allow(
    clippy::unwrap_used,
    clippy::float_cmp,
    clippy::panic,
    clippy::format_push_string,
    clippy::large_futures
)]

mod common;

use std::collections::{BTreeSet, HashMap};
use std::net::SocketAddr;
use std::path::{Path, PathBuf};

use common::Running;
use serde_json::Value;

use terrastream::bake::BakeOptions;
use terrastream::bake::PointLevels;
use terrastream::bake::export;
use terrastream::codec::{self, Geometry};
use terrastream::formats::tiles3d::{Anchor, AnchorFrom, GLB_REVISION};
use terrastream::raster::{self, LoadOptions};
use terrastream::server::PartialConfig;
use terrastream::store::Store;
use terrastream::tiling::TileKey;

/// 257² samples in 16-cell leaves: depth 4, so the root chunk has 256 external tilesets below.
const SIDE: u32 = 257;
const OPTS: BakeOptions =
    BakeOptions { tile_size: 16, max_error: 0.5, levels: 2, point_levels: PointLevels::All };

/// The synthetic terrain (UTM-like coordinates) baked into `dir/store/t`.
fn baked(dir: &Path) -> PathBuf {
    let tif = dir.join("t.tif");
    common::write_synth_geotiff(&tif, (SIDE, SIDE), 3, (500_000.0, 4_000_000.0));
    let out = dir.join("store/t");
    common::bake_file(&tif, &OPTS, &out);
    out
}

/// A parsed GLB: its JSON and binary chunk.
struct Glb {
    json: Value,
    bin: Vec<u8>,
}

fn parse_glb(b: &[u8]) -> Glb {
    assert_eq!(&b[0..4], b"glTF");
    assert_eq!(u32::from_le_bytes(b[4..8].try_into().unwrap()), 2);
    assert_eq!(u32::from_le_bytes(b[8..12].try_into().unwrap()) as usize, b.len());
    let jl = u32::from_le_bytes(b[12..16].try_into().unwrap()) as usize;
    assert_eq!(&b[16..20], b"JSON");
    let json = serde_json::from_slice(&b[20..20 + jl]).unwrap();
    let bl = u32::from_le_bytes(b[20 + jl..24 + jl].try_into().unwrap()) as usize;
    assert_eq!(&b[24 + jl..28 + jl], b"BIN\0");
    Glb { json, bin: b[28 + jl..28 + jl + bl].to_vec() }
}

impl Glb {
    /// The accessor's elements as f64 (components per element from its type).
    fn accessor(&self, i: u64) -> Vec<Vec<f64>> {
        let a = &self.json["accessors"][i as usize];
        let v = &self.json["bufferViews"][a["bufferView"].as_u64().unwrap() as usize];
        let n = match a["type"].as_str().unwrap() {
            "VEC3" => 3,
            "SCALAR" => 1,
            t => panic!("type {t}"),
        };
        let ct = a["componentType"].as_u64().unwrap();
        let size = match ct {
            5120 | 5121 => 1,
            5123 => 2,
            5125 | 5126 => 4,
            c => panic!("component type {c}"),
        };
        let stride = v["byteStride"].as_u64().map_or(n * size, |s| s as usize);
        let base =
            v["byteOffset"].as_u64().unwrap_or(0) as usize + a["byteOffset"].as_u64().unwrap_or(0) as usize;
        (0..a["count"].as_u64().unwrap() as usize)
            .map(|e| {
                (0..n)
                    .map(|c| {
                        let o = base + e * stride + c * size;
                        let s = &self.bin[o..o + size];
                        match ct {
                            5120 => f64::from(s[0] as i8) / 127.0,
                            5121 => f64::from(s[0]),
                            5123 => f64::from(u16::from_le_bytes([s[0], s[1]])),
                            5125 => f64::from(u32::from_le_bytes(s.try_into().unwrap())),
                            _ => f64::from(f32::from_le_bytes(s.try_into().unwrap())),
                        }
                    })
                    .collect()
            })
            .collect()
    }

    /// The normals a renderer draws: `NORMAL` through the inverse transpose of node 0's
    /// transform (its `scale`: inverse), normalized.
    fn rendered_normals(&self) -> Vec<[f64; 3]> {
        let node = &self.json["nodes"][0];
        let s: Vec<f64> = node["scale"].as_array().unwrap().iter().map(|v| v.as_f64().unwrap()).collect();
        let prim = &self.json["meshes"][0]["primitives"][0];
        self.accessor(prim["attributes"]["NORMAL"].as_u64().unwrap())
            .into_iter()
            .map(|n| std::array::from_fn(|a| n[a] / s[a]))
            .collect()
    }

    /// Positions as the glTF defines them: translation + scale · attribute.
    fn positions(&self) -> Vec<[f64; 3]> {
        let node = &self.json["nodes"][0];
        let t: Vec<f64> =
            node["translation"].as_array().unwrap().iter().map(|v| v.as_f64().unwrap()).collect();
        let s: Vec<f64> = node["scale"].as_array().unwrap().iter().map(|v| v.as_f64().unwrap()).collect();
        let prim = &self.json["meshes"][0]["primitives"][0];
        self.accessor(prim["attributes"]["POSITION"].as_u64().unwrap())
            .into_iter()
            .map(|p| std::array::from_fn(|a| t[a] + s[a] * p[a]))
            .collect()
    }
}

/// Every content tile of a tileset on disk: (key, level) → its tile JSON; external tilesets
/// are followed (each must be referenced once).
fn walk(dir: &Path) -> (HashMap<(String, u64), Value>, usize) {
    let mut tiles = HashMap::new();
    let mut docs = 0;
    let mut todo = vec![dir.join("tileset.json")];
    while let Some(path) = todo.pop() {
        docs += 1;
        let doc: Value = serde_json::from_slice(&std::fs::read(&path).unwrap()).unwrap();
        assert_eq!(doc["asset"]["version"], "1.1");
        let mut stack = vec![doc["root"].clone()];
        while let Some(t) = stack.pop() {
            assert!(t["geometricError"].as_f64().unwrap() >= 0.0);
            assert_eq!(t["boundingVolume"]["box"].as_array().unwrap().len(), 12);
            if let Some(uri) = t["content"]["uri"].as_str() {
                let file = path.parent().unwrap().join(uri);
                assert!(file.is_file(), "{} referenced from {} is missing", uri, path.display());
                if Path::new(uri).extension().is_some_and(|e| e == "json") {
                    assert!(t.get("children").is_none(), "a tile with an external tileset has no children");
                    todo.push(file);
                } else {
                    let e = &t["extras"]["terrastream"];
                    let k = (e["key"].as_str().unwrap().to_owned(), e["level"].as_u64().unwrap());
                    assert!(tiles.insert(k.clone(), t.clone()).is_none(), "{k:?} twice");
                }
            }
            if let Some(c) = t["children"].as_array() {
                stack.extend(c.iter().cloned());
            }
        }
    }
    (tiles, docs)
}

#[test]
fn export_writes_every_stored_level_as_a_tile_with_the_blobs_positions() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = baked(tmp.path());
    let store = Store::new(&dir);
    let anchor = Anchor { lon: 10.5, lat: 47.25, height: 100.0 };
    export::write_anchor(&store, anchor).unwrap();
    let out = tmp.path().join("3d");
    let r = export::export_3dtiles(&store, &out, None, &|_, _| {}).unwrap();
    let pyramid = terrastream::tiling::Pyramid::new(SIDE, SIDE, OPTS.tile_size).unwrap();
    let nodes = store.all_nodes(&pyramid).unwrap();
    let stored: BTreeSet<(String, u64)> = nodes
        .iter()
        .flat_map(|n| n.levels.iter().map(move |l| (n.key.to_string(), u64::from(l.level))))
        .collect();
    let (tiles, docs) = walk(&out);
    // Every mesh is listed; a stored point level only where the chain's errors allow it (no
    // tile's geometricError above its parent's: `common::assert_tiles3d_monotone`).
    let listed = tiles.keys().cloned().collect::<BTreeSet<_>>();
    assert!(listed.is_subset(&stored));
    let meshes: BTreeSet<(String, u64)> = nodes.iter().map(|n| (n.key.to_string(), 0)).collect();
    assert!(meshes.is_subset(&listed));
    assert!(listed.len() > meshes.len(), "no point level listed at all");
    eprintln!(
        "{} of {} stored point levels listed",
        listed.len() - meshes.len(),
        stored.len() - meshes.len()
    );
    assert!(common::assert_tiles3d_monotone(&dir) >= listed.len());
    assert_eq!(r.glbs as usize, stored.len());
    // The root tileset and one external tileset per chunk below it (z = 4: 256 of them).
    assert_eq!(docs, 1 + 256);
    assert_eq!(r.documents as usize, docs);

    let root: Value = serde_json::from_slice(&std::fs::read(out.join("tileset.json")).unwrap()).unwrap();
    let transform: Vec<f64> =
        root["root"]["transform"].as_array().unwrap().iter().map(|v| v.as_f64().unwrap()).collect();
    assert_eq!(transform, anchor.enu_to_ecef().to_vec());
    assert_eq!(root["asset"]["extras"]["terrastream"]["anchor"]["from"], "option");
    // A projected GeoTIFF: y is north.
    assert_eq!(root["asset"]["extras"]["terrastream"]["local_frame"]["north"], "+y");

    let info = export::tiles3d_info(&store, "t", None, String::new()).unwrap();
    assert_eq!(info.place.from, AnchorFrom::Option);
    // The surface's normals at every sample a mesh GLB draws, per (depth, level): area-weighted
    // over the top triangles of all the depth's GLBs of that level, as placed (x, −north).
    let at = |p: [f64; 3]| [(p[0] * 1e3).round() as i64, (p[2] * 1e3).round() as i64];
    let mut surface: HashMap<(u8, u8, [i64; 2]), [f64; 3]> = HashMap::new();
    for n in &nodes {
        for l in &n.levels {
            let Ok(bytes) =
                std::fs::read(out.join(format!("tiles/{}/{}/{}/{}.glb", n.key.z, n.key.x, n.key.y, l.level)))
            else {
                continue;
            };
            let header = codec::decode(&store.read_blob(n.key, l.level).unwrap().unwrap()).unwrap().header;
            if header.triangle_count == 0 {
                continue;
            }
            let glb = parse_glb(&bytes);
            let got = glb.positions();
            let idx = glb.accessor(glb.json["meshes"][0]["primitives"][0]["indices"].as_u64().unwrap());
            for t in idx.chunks(3).take(header.triangle_count as usize) {
                let [a, b, c] = [0, 1, 2].map(|k| got[t[k][0] as usize]);
                let (u, v) = ([0, 1, 2].map(|k| b[k] - a[k]), [0, 1, 2].map(|k| c[k] - a[k]));
                let x = [u[1] * v[2] - u[2] * v[1], u[2] * v[0] - u[0] * v[2], u[0] * v[1] - u[1] * v[0]];
                for i in t {
                    let s = surface.entry((n.key.z, l.level, at(got[i[0] as usize]))).or_default();
                    *s = [0, 1, 2].map(|k| s[k] + x[k]);
                }
            }
        }
    }
    let mut checked = 0;
    let mut shared = 0;
    let mut coarse = 0;
    for n in &nodes {
        for l in &n.levels {
            let Some(t) = tiles.get(&(n.key.to_string(), u64::from(l.level))) else { continue };
            // A mesh measured above its parent's error is listed with its parent's.
            let e = t["geometricError"].as_f64().unwrap();
            if l.level == 0 {
                assert!(e <= l.errors.geometric());
            } else {
                assert_eq!(e, l.errors.geometric());
            }
            assert_eq!(t["refine"], "REPLACE");
            // Every few nodes: the GLB's positions are the blob's, placed.
            if (n.key.x + n.key.y) % 5 != 0 {
                continue;
            }
            let glb = parse_glb(
                &std::fs::read(
                    out.join(format!("tiles/{}/{}/{}/{}.glb", n.key.z, n.key.x, n.key.y, l.level)),
                )
                .unwrap(),
            );
            let blob = codec::decode(&store.read_blob(n.key, l.level).unwrap().unwrap()).unwrap();
            let world = match &blob.geometry {
                Geometry::Mesh(m) => m.positions.clone(),
                Geometry::Points(p) => p.positions.clone(),
            };
            let got = glb.positions();
            // Meshes carry skirts after their own vertices; those hang below the borders.
            assert!(got.len() >= world.len());
            // On the blob's grid the positions are the blob's; where that grid does not fit 16
            // bits (steep tiles) the GLB's is coarser and they lie within 1/8 of the measured error.
            let q = blob.header.quant;
            let scale = &glb.json["nodes"][0]["scale"];
            let on_blob_grid = (0..3).all(|a| {
                let s = scale[a].as_f64().unwrap();
                s == q.xy_step || s == q.z_step
            });
            let tol = if on_blob_grid { 1e-6 } else { blob.header.errors.max / 8.0 + 1e-9 };
            coarse += usize::from(!on_blob_grid);
            if !on_blob_grid {
                assert_eq!(glb.json["accessors"][0]["componentType"], 5123, "a coarser grid is 16-bit");
            }
            for (w, g) in world.iter().zip(&got) {
                let want = info.place.gltf_of(*w);
                for a in 0..3 {
                    assert!((want[a] - g[a]).abs() <= tol, "{} level {}: {want:?} vs {g:?}", n.key, l.level);
                }
            }
            if let Geometry::Mesh(m) = &blob.geometry {
                // Triangles face up in the tileset frame (east, north, up) = (x, −z, y).
                let prim = &glb.json["meshes"][0]["primitives"][0];
                let idx = glb.accessor(prim["indices"].as_u64().unwrap());
                let mut area = 0.0;
                for t in idx.chunks(3).take(m.triangles.len()) {
                    let p: Vec<[f64; 3]> = t.iter().map(|i| got[i[0] as usize]).collect();
                    let en = |q: [f64; 3]| [q[0], -q[2]];
                    let (a, b, c) = (en(p[0]), en(p[1]), en(p[2]));
                    area += (b[0] - a[0]) * (c[1] - a[1]) - (b[1] - a[1]) * (c[0] - a[0]);
                }
                assert!(area > 0.0, "{}: triangles face down", n.key);
                // Drawn through the node's transform, each vertex's normal is its surface's
                // (area-weighted over its triangles, from the positions as placed), over the
                // triangles of every tile of the depth around it where it lies on a border
                // (so neighbours draw a shared vertex alike: no lighting seam).
                let mut own = vec![[0.0f64; 3]; got.len()];
                for t in idx.chunks(3).take(m.triangles.len()) {
                    let [a, b, c] = [0, 1, 2].map(|k| got[t[k][0] as usize]);
                    let (u, v) = ([0, 1, 2].map(|k| b[k] - a[k]), [0, 1, 2].map(|k| c[k] - a[k]));
                    let x = [u[1] * v[2] - u[2] * v[1], u[2] * v[0] - u[0] * v[2], u[0] * v[1] - u[1] * v[0]];
                    for i in t {
                        own[i[0] as usize] = [0, 1, 2].map(|k| own[i[0] as usize][k] + x[k]);
                    }
                }
                let drawn = glb.rendered_normals();
                for (i, p) in got.iter().enumerate().take(world.len()) {
                    let want = surface[&(n.key.z, l.level, at(*p))];
                    shared += usize::from(angle_deg(want, own[i]) > 1e-9);
                    let angle = angle_deg(drawn[i], want);
                    assert!(
                        angle < 2.0,
                        "{} level {} vertex {i}: drawn normal {angle:.1}° off",
                        n.key,
                        l.level
                    );
                }
            }
            if let Geometry::Points(p) = &blob.geometry {
                let drawn = glb.rendered_normals();
                for (i, (w, nrm)) in p.positions.iter().zip(&p.normals).enumerate() {
                    let tip = info.place.gltf_of([0, 1, 2].map(|k| w[k] + f64::from(nrm[k])));
                    let base = info.place.gltf_of(*w);
                    let angle = angle_deg(drawn[i], [0, 1, 2].map(|k| tip[k] - base[k]));
                    assert!(
                        angle < 2.0,
                        "{} level {} point {i}: drawn normal {angle:.1}° off",
                        n.key,
                        l.level
                    );
                }
            }
            checked += 1;
        }
    }
    assert!(checked > 20);
    assert!(shared > 100, "border vertices whose neighbours bend their normal: {shared}");
    assert!(coarse < checked, "most tiles keep the blob's grid ({coarse} of {checked} coarser)");

    // An export never writes into a folder that holds anything; the folder is left alone.
    let e = export::export_3dtiles(&store, &out, None, &|_, _| {}).unwrap_err();
    assert!(e.to_string().contains("not an empty directory"), "{e}");
    assert!(out.join("tileset.json").is_file());
    // Nothing is left beside it (the staging folder is gone).
    let names: Vec<String> = std::fs::read_dir(tmp.path())
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .collect();
    assert!(names.iter().all(|n| !n.contains("partial")), "{names:?}");
}

#[test]
fn export_places_geographic_and_unreferenced_sources() {
    let tmp = tempfile::tempdir().unwrap();
    // A PNG has no georeference: placed at the default anchor, north = −y (row 0 is north).
    let png =
        common::fuji_or_generated(tmp.path(), "tiles3d::export_places_geographic_and_unreferenced_sources");
    let r = raster::load(
        &png,
        &LoadOptions {
            encoding: Some(raster::HeightEncoding::TerrainRgb),
            overrides: raster::Overrides { cell_size: Some(30.0), ..Default::default() },
            ..Default::default()
        },
    )
    .unwrap();
    let dir = tmp.path().join("fuji");
    let o = BakeOptions { tile_size: 256, max_error: 4.0, levels: 1, point_levels: PointLevels::All };
    common::bake_cpu(&r, "fuji.png", &o, &dir);
    let info = export::tiles3d_info(&Store::new(&dir), "fuji", None, String::new()).unwrap();
    assert_eq!(info.place.from, AnchorFrom::Default);
    assert_eq!(info.place.anchor, terrastream::formats::tiles3d::DEFAULT_ANCHOR);
    // Row 0 (y = 0) is the north edge.
    assert!(info.place.enu_of([0.0, 0.0, 0.0])[1] > info.place.enu_of([0.0, 30.0, 0.0])[1]);
    let out = tmp.path().join("x/3d");
    export::export_3dtiles(
        &Store::new(&dir),
        &out,
        Some(Anchor { lon: 138.73, lat: 35.36, height: 0.0 }),
        &|_, _| {},
    )
    .unwrap();
    let root: Value = serde_json::from_slice(&std::fs::read(out.join("tileset.json")).unwrap()).unwrap();
    assert_eq!(root["asset"]["extras"]["terrastream"]["anchor"]["from"], "option");
    assert_eq!(root["asset"]["extras"]["terrastream"]["local_frame"]["north"], "-y");

    // A geographic GeoTIFF knows its anchor: the centre of its data.
    let geo = tmp.path().join("geo.tif");
    let side = 65;
    let heights = raster::synth::terrain(side, side, 5);
    let mut f = std::fs::File::create(&geo).unwrap();
    raster::geotiff::write_tiled_f32(
        &mut f,
        (side, side),
        32,
        raster::geotiff::Model::Geographic,
        (138.5, 35.5),
        (1.0 / 1200.0, -1.0 / 1200.0),
        None,
        false,
        |c, r| heights[(r * side + c) as usize],
    )
    .unwrap();
    drop(f);
    let dir = tmp.path().join("geo");
    let o = BakeOptions { tile_size: 32, max_error: 1.0, levels: 1, point_levels: PointLevels::All };
    common::bake_file(&geo, &o, &dir);
    let info = export::tiles3d_info(&Store::new(&dir), "geo", None, String::new()).unwrap();
    assert_eq!(info.place.from, AnchorFrom::Source);
    // Sample (0, 0) at 138.5° E, 35.5° N (PixelIsPoint), 64 cells across: the centre is 32 in
    // (to the centimetre: the bounds are the blobs', grown to their quantization grid).
    assert!((info.place.anchor.lon - (138.5 + 32.0 / 1200.0)).abs() < 1e-7, "{:?}", info.place.anchor);
    assert!((info.place.anchor.lat - (35.5 - 32.0 / 1200.0)).abs() < 1e-7, "{:?}", info.place.anchor);

    // On the Earth each GLB has its own east-north-up frame (node `matrix`), yet the vertices two
    // neighbours both draw are drawn with one normal (each rounded to bytes in its own frame).
    let out = tmp.path().join("geo3d");
    export::export_3dtiles(&Store::new(&dir), &out, None, &|_, _| {}).unwrap();
    let ecef = ecef_mesh;
    let tiles: Vec<_> = (0..2)
        .flat_map(|x| (0..2).map(move |y| (x, y)))
        .map(|(x, y)| ecef(&parse_glb(&std::fs::read(out.join(format!("tiles/1/{x}/{y}/0.glb"))).unwrap())))
        .collect();
    let (mut shared, mut worst) = (0, 0.0f64);
    for (a, (pa, na)) in tiles.iter().enumerate() {
        for (pb, nb) in &tiles[a + 1..] {
            for (p, n) in pa.iter().zip(na) {
                let near = pb.iter().position(|q| (0..3).all(|k| (p[k] - q[k]).abs() < 0.01));
                if let Some(j) = near {
                    shared += 1;
                    worst = worst.max(angle_deg(*n, nb[j]));
                }
            }
        }
    }
    assert!(shared >= 30, "{shared} shared vertices");
    assert!(worst < 2.0, "neighbours draw a shared vertex {worst:.2}° apart");
}

/// A GLB's mesh on the Earth: positions and normals in ECEF (through its node's `matrix`).
fn ecef_mesh(glb: &Glb) -> (Vec<[f64; 3]>, Vec<[f64; 3]>) {
    let node = &glb.json["nodes"][0];
    let m: Vec<f64> = node["matrix"].as_array().unwrap().iter().map(|v| v.as_f64().unwrap()).collect();
    let prim = &glb.json["meshes"][0]["primitives"][0];
    // glTF y-up → 3D Tiles z-up after the node's matrix (column-major).
    let apply = |v: &[f64], w: f64| {
        let r: [f64; 3] =
            std::array::from_fn(|row| (0..3).map(|c| m[c * 4 + row] * v[c]).sum::<f64>() + w * m[12 + row]);
        [r[0], -r[2], r[1]]
    };
    let pos = glb
        .accessor(prim["attributes"]["POSITION"].as_u64().unwrap())
        .iter()
        .map(|p| apply(p, 1.0))
        .collect();
    let nrm =
        glb.accessor(prim["attributes"]["NORMAL"].as_u64().unwrap()).iter().map(|n| apply(n, 0.0)).collect();
    (pos, nrm)
}

/// A geographic grid's pole row is one point of the Earth, drawn by a vertex per sample in every
/// tile along it: all draw the pole's up, so no seam meets there (each triangle fan alone gave
/// them directions tens of degrees apart).
#[test]
fn a_geographic_grids_pole_is_drawn_with_one_normal() {
    let tmp = tempfile::tempdir().unwrap();
    let side = 65;
    let heights = raster::synth::terrain(side, side, 9);
    let dir = tmp.path().join("cap");
    for (name, lat0, dy) in [("north.tif", 90.0, -0.5), ("south.tif", -90.0, 0.5)] {
        let geo = tmp.path().join(name);
        let mut f = std::fs::File::create(&geo).unwrap();
        raster::geotiff::write_tiled_f32(
            &mut f,
            (side, side),
            32,
            raster::geotiff::Model::Geographic,
            (-20.0, lat0),
            (0.5, dy),
            None,
            false,
            |c, r| 1000.0 + 30.0 * heights[(r * side + c) as usize],
        )
        .unwrap();
        drop(f);
        let _ = std::fs::remove_dir_all(&dir);
        let o = BakeOptions { tile_size: 32, max_error: 1.0, levels: 1, point_levels: PointLevels::All };
        common::bake_file(&geo, &o, &dir);
        let out = tmp.path().join(format!("{name}.3d"));
        export::export_3dtiles(&Store::new(&dir), &out, None, &|_, _| {}).unwrap();
        let mut at_pole = 0;
        for (rel, bytes) in common::tree(&out.join("tiles")) {
            let (pos, nrm) = ecef_mesh(&parse_glb(&bytes));
            for (p, n) in pos.iter().zip(&nrm) {
                if p[0].hypot(p[1]) < 1.0 && p[2].signum() == lat0.signum() {
                    at_pole += 1;
                    let off = angle_deg(*n, [0.0, 0.0, lat0.signum()]);
                    assert!(off < 1.5, "{name} {rel}: a pole vertex drawn {off:.2}° off up");
                }
            }
        }
        assert!(at_pole >= 64, "{name}: {at_pole} pole vertices");
    }
}

/// A geographic grid that goes around the Earth (its last column on the meridian of its first)
/// has the antimeridian as a border like any other: the tiles on both sides of it draw their
/// shared vertices with one normal.
#[test]
fn a_grid_around_the_earth_draws_one_normal_across_the_antimeridian() {
    let tmp = tempfile::tempdir().unwrap();
    let (w, h) = (65, 17);
    let heights = raster::synth::terrain(w, h, 4);
    let geo = tmp.path().join("globe.tif");
    let mut f = std::fs::File::create(&geo).unwrap();
    let step = 360.0 / f64::from(w - 1);
    raster::geotiff::write_tiled_f32(
        &mut f,
        (w, h),
        32,
        raster::geotiff::Model::Geographic,
        (-180.0, 45.0),
        (step, -step),
        None,
        false,
        // The last column is the first's meridian: the same heights.
        |c, r| heights[(r * w + c % (w - 1)) as usize],
    )
    .unwrap();
    drop(f);
    let dir = tmp.path().join("globe");
    let o = BakeOptions { tile_size: 16, max_error: 1.0, levels: 1, point_levels: PointLevels::All };
    common::bake_file(&geo, &o, &dir);
    let out = tmp.path().join("globe3d");
    export::export_3dtiles(&Store::new(&dir), &out, None, &|_, _| {}).unwrap();
    // Depth 2: four tiles around the Earth; x = 0 starts at −180°, x = 3 ends at +180°.
    let tile =
        |x: u32| ecef_mesh(&parse_glb(&std::fs::read(out.join(format!("tiles/2/{x}/0/0.glb"))).unwrap()));
    let ((pw, nw), (pe, ne)) = (tile(0), tile(3));
    let (mut shared, mut worst) = (0, 0.0f64);
    for (p, n) in pw.iter().zip(&nw) {
        // One place (cells are 625 km wide; f32 positions of 90°-wide tiles round by centimetres).
        if let Some(j) = pe.iter().position(|q| (0..3).all(|k| (p[k] - q[k]).abs() < 1.0)) {
            shared += 1;
            worst = worst.max(angle_deg(*n, ne[j]));
        }
    }
    assert!(shared >= 10, "{shared} vertices on the antimeridian");
    assert!(worst < 2.5, "the antimeridian's vertices drawn {worst:.2}° apart");
}

/// One GET ([`common::get_async`]); these routes never answer chunked.
async fn get(addr: SocketAddr, path: &str, headers: &[(&str, &str)]) -> common::Answer {
    let r = common::get_async(addr, path, headers).await;
    assert!(!r.1.contains_key("transfer-encoding"), "chunked answers are not expected here");
    r
}

/// The JSON with every `?v=…` query taken off its URIs (the served documents carry them).
fn strip_queries(v: &mut Value) {
    match v {
        Value::String(s) => {
            if let Some(i) = s.find("?v=") {
                s.truncate(i);
            }
        }
        Value::Array(a) => a.iter_mut().for_each(strip_queries),
        Value::Object(o) => o.values_mut().for_each(strip_queries),
        _ => {}
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 4)]
async fn served_3d_tiles_are_the_exported_ones_with_blob_caching() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = baked(tmp.path());
    let out = tmp.path().join("3d");
    export::export_3dtiles(&Store::new(&dir), &out, None, &|_, _| {}).unwrap();
    let cv = Store::new(&dir).manifest().unwrap().content_version;
    let srv =
        Running::start(PartialConfig { store: Some(tmp.path().join("store")), ..PartialConfig::default() })
            .await;
    let a = srv.addr;

    let (s, h, body) = get(a, "/tilesets/t/3dtiles/tileset.json", &[]).await;
    assert_eq!(s, 200);
    assert_eq!(h["cache-control"], "public, max-age=10, must-revalidate");
    assert_eq!(h["access-control-allow-origin"], "*");
    let mut served: Value = serde_json::from_slice(&body).unwrap();
    assert!(
        body.windows(3 + cv.len() + GLB_REVISION.len())
            .any(|w| w == format!("?v={cv}{GLB_REVISION}").as_bytes()),
        "URIs name the content version and the GLB revision"
    );
    strip_queries(&mut served);
    let exported: Value = serde_json::from_slice(&std::fs::read(out.join("tileset.json")).unwrap()).unwrap();
    assert_eq!(served, exported);
    let (s, _, _) = get(a, "/tilesets/t/3dtiles/tileset.json", &[("If-None-Match", &h["etag"])]).await;
    assert_eq!(s, 304);

    let (s, h, body) =
        get(a, &format!("/tilesets/t/3dtiles/index/4/3/5.json?v={cv}{GLB_REVISION}"), &[]).await;
    assert_eq!(s, 200);
    assert_eq!(h["cache-control"], "public, max-age=31536000, immutable");
    let mut served: Value = serde_json::from_slice(&body).unwrap();
    strip_queries(&mut served);
    let exported: Value =
        serde_json::from_slice(&std::fs::read(out.join("index/4/3/5.json")).unwrap()).unwrap();
    assert_eq!(served, exported);

    for (key, level) in [("0/0/0", 0), ("0/0/0", 2), ("2/1/3", 0), ("4/15/15", 0)] {
        let path = format!("/tilesets/t/3dtiles/tiles/{key}/{level}.glb");
        let file = std::fs::read(out.join(format!("tiles/{key}/{level}.glb"))).ok();
        let (s, h, body) = get(a, &format!("{path}?v={cv}{GLB_REVISION}"), &[]).await;
        let Some(file) = file else {
            // A level the node does not store (it did not pay).
            assert_eq!(s, 404, "{path}");
            continue;
        };
        assert_eq!(s, 200, "{path}: {}", String::from_utf8_lossy(&body));
        assert_eq!(h["content-type"], "model/gltf-binary");
        assert_eq!(h["cache-control"], "public, max-age=31536000, immutable");
        assert_eq!(body, file, "{path}: served and exported GLBs differ");
        let (s, h2, _) = get(a, &path, &[]).await;
        assert_eq!((s, h2["cache-control"].as_str()), (200, "public, max-age=60, must-revalidate"));
        assert_eq!(h2["etag"], h["etag"]);
        // A URI of an older GLB revision (the bare content version) is not immutable: caches
        // holding GLBs of another encoding revalidate them.
        let (s, h3, _) = get(a, &format!("{path}?v={cv}"), &[]).await;
        assert_eq!((s, h3["cache-control"].as_str()), (200, "public, max-age=60, must-revalidate"));
        let (s, _, _) = get(a, &path, &[("If-None-Match", &h["etag"])]).await;
        assert_eq!(s, 304);
        let (s, h3, part) = get(a, &path, &[("Range", "bytes=0-11")]).await;
        assert_eq!(s, 206);
        assert_eq!(part, file[..12].to_vec());
        assert_eq!(h3["content-range"], format!("bytes 0-11/{}", file.len()));
    }
    for (path, status) in [
        ("/tilesets/t/3dtiles/tiles/0/0/0/9.glb", 404),
        ("/tilesets/t/3dtiles/tiles/0/0/0/0.tsb", 400),
        ("/tilesets/t/3dtiles/tiles/9/0/0/0.glb", 404),
        ("/tilesets/t/3dtiles/index/2/0/0.json", 404),
        ("/tilesets/t/3dtiles/index/0/0/0.json", 404),
        ("/tilesets/T/3dtiles/tileset.json", 400),
        ("/tilesets/nope/3dtiles/tileset.json", 404),
    ] {
        let (s, h, body) = get(a, path, &[]).await;
        assert_eq!(s, status, "{path}: {}", String::from_utf8_lossy(&body));
        assert_eq!(h["content-type"], "application/problem+json", "{path}");
    }
    let (s, h, body) = get(a, "/viewer?tileset=t", &[]).await;
    assert_eq!(s, 200);
    assert!(h["content-type"].starts_with("text/html"));
    assert!(String::from_utf8_lossy(&body).contains("3dtiles/tileset.json"));
    srv.stop().await;
}

/// A GLB's mesh as position sets: its vertices' positions (as `f32`) and its triangles over them
/// (each rotated to start at its least vertex, winding kept), so two listings of one mesh
/// compare equal; and each position's unit normal, to compare within a tolerance.
type MeshSets = (Vec<[u32; 3]>, Vec<[[u32; 3]; 3]>, HashMap<[u32; 3], [f64; 3]>);

fn mesh_sets_of(positions: &[[f32; 3]], normals: &[[f64; 3]], idx: Option<&[usize]>) -> MeshSets {
    let key = |k: usize| positions[k].map(f32::to_bits);
    let mut vertices: Vec<[u32; 3]> = (0..positions.len()).map(key).collect();
    vertices.sort_unstable();
    let mut tris = Vec::new();
    for t in idx.unwrap_or(&[]).chunks(3) {
        let v = [key(t[0]), key(t[1]), key(t[2])];
        let r = (0..3).map(|k| [v[k], v[(k + 1) % 3], v[(k + 2) % 3]]).min().unwrap();
        tris.push(r);
    }
    tris.sort_unstable();
    let by_pos = (0..positions.len())
        .map(|k| {
            let n = normals[k];
            let l = (n[0] * n[0] + n[1] * n[1] + n[2] * n[2]).sqrt();
            (key(k), n.map(|c| c / l))
        })
        .collect();
    (vertices, tris, by_pos)
}

/// [`mesh_sets_of`] a plain GLB (or a meshopt one decoded to its plain layout).
fn mesh_sets(json: &Value, bin: &[u8]) -> MeshSets {
    let prim = &json["meshes"][0]["primitives"][0];
    let values = |a: &Value| -> Vec<f64> {
        let acc = &json["accessors"][a.as_u64().unwrap() as usize];
        let v = &json["bufferViews"][acc["bufferView"].as_u64().unwrap() as usize];
        let o = v["byteOffset"].as_u64().unwrap_or(0) as usize;
        let n = if acc["type"] == "SCALAR" { 1 } else { 3 };
        let ct = acc["componentType"].as_u64().unwrap();
        let size = match ct {
            5120 | 5121 => 1,
            5122 | 5123 => 2,
            _ => 4,
        };
        let stride = v["byteStride"].as_u64().map_or(n * size, |s| s as usize);
        let count = acc["count"].as_u64().unwrap() as usize;
        (0..count)
            .flat_map(|k| (0..n).map(move |c| o + k * stride + c * size))
            .map(|at| {
                let b = &bin[at..at + size];
                match ct {
                    5120 => f64::from(b[0] as i8),
                    5121 => f64::from(b[0]),
                    5123 => f64::from(u16::from_le_bytes([b[0], b[1]])),
                    5125 => f64::from(u32::from_le_bytes([b[0], b[1], b[2], b[3]])),
                    _ => f64::from(f32::from_le_bytes([b[0], b[1], b[2], b[3]])),
                }
            })
            .collect()
    };
    let pos: Vec<[f32; 3]> = values(&prim["attributes"]["POSITION"])
        .chunks(3)
        .map(|c| [c[0] as f32, c[1] as f32, c[2] as f32])
        .collect();
    let nrm: Vec<[f64; 3]> =
        values(&prim["attributes"]["NORMAL"]).chunks(3).map(|c| c.try_into().unwrap()).collect();
    let idx: Option<Vec<usize>> =
        prim.get("indices").map(|i| values(i).iter().map(|&v| v as usize).collect());
    mesh_sets_of(&pos, &nrm, idx.as_deref())
}

/// The same mesh, with every normal within `degrees` of the other's.
fn assert_same_mesh(got: &MeshSets, want: &MeshSets, degrees: f64, what: &str) {
    assert_eq!(got.0, want.0, "{what}: not the plain GLB's vertices");
    assert_eq!(got.1, want.1, "{what}: not the plain GLB's triangles");
    let cos = degrees.to_radians().cos();
    for (k, n) in &want.2 {
        let m = got.2[k];
        let d = n[0] * m[0] + n[1] * m[1] + n[2] * m[2];
        assert!(d >= cos, "{what}: a normal {:.2}° off", d.clamp(-1.0, 1.0).acos().to_degrees());
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 4)]
async fn meshopt_3d_tiles_served_and_exported_alike_and_decode_to_the_plain_mesh() {
    compressed_3d_tiles(terrastream::formats::tiles3d::GlbCompression::Meshopt).await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 4)]
async fn draco_3d_tiles_served_and_exported_alike_and_decode_to_the_plain_mesh() {
    compressed_3d_tiles(terrastream::formats::tiles3d::GlbCompression::Draco).await;
}

/// An export with `glb` compression against the plain export and the server's `?glb=` form:
/// every GLB decodes (our decoders; the interop suite uses meshoptimizer's and Google's) to the
/// plain GLB's mesh, normals within 2° (the octahedral filter's 8-bit octahedral normals
/// against the plain `BYTE` vectors; Draco's, rounded from the exact directions as the bytes
/// are, within both roundings' bounds), and the server gives the export's bytes.
async fn compressed_3d_tiles(glb: terrastream::formats::tiles3d::GlbCompression) {
    use terrastream::formats::tiles3d::{GlbCompression, draco, meshopt};
    let name = glb.name();
    let tmp = tempfile::tempdir().unwrap();
    let dir = baked(tmp.path());
    let plain = tmp.path().join("plain");
    let out = tmp.path().join("mo");
    export::export_3dtiles(&Store::new(&dir), &plain, None, &|_, _| {}).unwrap();
    let r = export::export_3dtiles_with(&Store::new(&dir), &out, None, glb, &|_, _| {}).unwrap();
    // Every GLB: the extension declared and required, the same mesh as the plain GLB, fewer bytes.
    let (mut plain_bytes, mut mo_bytes, mut meshes, mut dracos) = (0, 0, 0, 0);
    for (rel, mo) in common::tree(&out.join("tiles")) {
        let p = std::fs::read(plain.join("tiles").join(&rel)).unwrap();
        let (json, _) = meshopt::read_glb(&mo).unwrap();
        let (pj, pb) = meshopt::read_glb(&p).unwrap();
        let want = mesh_sets(&pj, &pb);
        let is_mesh = pj["meshes"][0]["primitives"][0].get("indices").is_some();
        let ext = if glb == GlbCompression::Draco && is_mesh { draco::EXT } else { meshopt::EXT };
        for list in ["extensionsUsed", "extensionsRequired"] {
            assert!(json[list].as_array().unwrap().iter().any(|e| e == ext), "{rel}: {ext} not in {list}");
        }
        if ext == draco::EXT {
            let [d] = &draco::decompress_glb(&mo).unwrap()[..] else { panic!("{rel}: one primitive") };
            let idx: Vec<usize> = d.triangles.iter().flatten().map(|&i| i as usize).collect();
            let nrm: Vec<[f64; 3]> = d.normals.as_ref().unwrap().iter().map(|n| n.map(f64::from)).collect();
            // Draco's normals are rounded from the exact directions (within STEER_DEGREES of
            // them), the plain GLB's `BYTE`s too (within 1.14°).
            let bound = draco::STEER_DEGREES + 1.14;
            assert_same_mesh(&mesh_sets_of(&d.positions, &nrm, Some(&idx)), &want, bound, &rel);
            assert!(
                json["accessors"].as_array().unwrap().iter().all(|a| a.get("bufferView").is_none()),
                "{rel}"
            );
            dracos += 1;
        } else {
            assert_eq!(json["buffers"][1]["extensions"]["EXT_meshopt_compression"]["fallback"], true);
            let (dj, db) = meshopt::decompress_glb(&mo).unwrap();
            assert_same_mesh(&mesh_sets(&dj, &db), &want, 2.0, &rel);
        }
        meshes += usize::from(is_mesh);
        plain_bytes += p.len();
        mo_bytes += mo.len();
    }
    assert!(meshes > 10, "{meshes} meshes");
    assert_eq!(dracos, if glb == GlbCompression::Draco { meshes } else { 0 });
    assert_eq!(r.glb_bytes, mo_bytes as u64);
    // Tiny 16-cell tiles: the JSON chunk weighs (meshopt 0.74× measured; fuji's big tiles 0.35×).
    assert!(mo_bytes * 10 < plain_bytes * 9, "{name} {mo_bytes} bytes, plain {plain_bytes}");
    // The documents are the plain export's.
    assert_eq!(
        std::fs::read(out.join("tileset.json")).unwrap(),
        std::fs::read(plain.join("tileset.json")).unwrap()
    );

    let cv = Store::new(&dir).manifest().unwrap().content_version;
    let srv =
        Running::start(PartialConfig { store: Some(tmp.path().join("store")), ..PartialConfig::default() })
            .await;
    let a = srv.addr;
    // The root and an external tileset: every URI carries the option; otherwise the export's.
    for (path, file) in [("tileset.json", "tileset.json"), ("index/4/3/5.json", "index/4/3/5.json")] {
        let (s, _, body) =
            get(a, &format!("/tilesets/t/3dtiles/{path}?v={cv}{GLB_REVISION}&glb={name}"), &[]).await;
        assert_eq!(s, 200, "{path}");
        let text = String::from_utf8_lossy(&body);
        assert!(
            text.contains(&format!("?v={cv}{GLB_REVISION}&glb={name}"))
                && !text.contains(&format!("?v={cv}{GLB_REVISION}\"")),
            "{path}"
        );
        let mut served: Value = serde_json::from_slice(&body).unwrap();
        strip_queries(&mut served);
        let exported: Value = serde_json::from_slice(&std::fs::read(out.join(file)).unwrap()).unwrap();
        assert_eq!(served, exported, "{path}");
    }
    for (key, level) in [("0/0/0", 0), ("0/0/0", 2), ("2/1/3", 0), ("4/15/15", 0)] {
        let Ok(file) = std::fs::read(out.join(format!("tiles/{key}/{level}.glb"))) else { continue };
        let path = format!("/tilesets/t/3dtiles/tiles/{key}/{level}.glb");
        for coding in [None, Some("gzip"), Some("zstd")] {
            let headers: Vec<(&str, &str)> = coding.map(|c| ("Accept-Encoding", c)).into_iter().collect();
            let (s, h, body) = get(a, &format!("{path}?v={cv}{GLB_REVISION}&glb={name}"), &headers).await;
            assert_eq!(s, 200, "{path}");
            assert_eq!(h.get("content-encoding").map(String::as_str), coding, "{path}");
            assert_eq!(
                decoded(coding, &body),
                file,
                "{path} ({coding:?}): served and exported {name} GLBs differ"
            );
        }
        // The plain form stays apart (its own cache entry): the plain export's bytes.
        let (_, _, body) = get(a, &format!("{path}?v={cv}{GLB_REVISION}"), &[]).await;
        assert_eq!(body, std::fs::read(plain.join(format!("tiles/{key}/{level}.glb"))).unwrap(), "{path}");
        let (_, _, body) = get(a, &format!("{path}?glb=none"), &[]).await;
        assert_eq!(body, std::fs::read(plain.join(format!("tiles/{key}/{level}.glb"))).unwrap(), "{path}");
    }
    for path in ["tileset.json?glb=brotli", "index/4/3/5.json?glb=", "tiles/0/0/0/0.glb?glb=MESHOPT"] {
        let (s, _, body) = get(a, &format!("/tilesets/t/3dtiles/{path}"), &[]).await;
        assert_eq!(s, 400, "{path}");
        assert!(String::from_utf8_lossy(&body).contains("glb=meshopt, glb=draco"), "{path}");
    }
    srv.stop().await;
}

/// A body in the named content coding, decoded.
fn decoded(coding: Option<&str>, body: &[u8]) -> Vec<u8> {
    use std::io::Read as _;
    match coding {
        None => body.to_vec(),
        Some("gzip") => {
            let mut out = Vec::new();
            flate2::read::GzDecoder::new(body).read_to_end(&mut out).unwrap();
            out
        }
        Some("zstd") => zstd::decode_all(body).unwrap(),
        Some(other) => panic!("unexpected coding {other}"),
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 4)]
async fn glbs_and_tileset_json_are_sent_compressed_as_asked() {
    let tmp = tempfile::tempdir().unwrap();
    baked(tmp.path());
    let srv =
        Running::start(PartialConfig { store: Some(tmp.path().join("store")), ..PartialConfig::default() })
            .await;
    let a = srv.addr;
    let offers = [
        ("gzip", Some("gzip")),
        ("zstd", Some("zstd")),
        ("gzip, deflate, br, zstd", Some("gzip")),
        ("zstd;q=0.5, gzip", Some("gzip")),
        ("gzip;q=0.5, zstd", Some("zstd")),
        ("br, zstd", Some("zstd")),
        ("x-gzip", Some("gzip")),
        ("*", Some("gzip")),
        ("*;q=0.1, gzip;q=0", Some("zstd")),
        ("br, deflate", None),
        ("gzip;q=0, zstd;q=0", None),
        ("gzip;q=nonsense", None),
        ("identity", None),
        ("", None),
    ];
    let long = format!("{}, gzip", "x".repeat(2000));
    for path in [
        "/tilesets/t/3dtiles/tiles/0/0/0/0.glb",
        "/tilesets/t/3dtiles/tiles/2/1/3/0.glb",
        "/tilesets/t/3dtiles/index/4/3/5.json",
        "/tilesets/t/3dtiles/tileset.json",
    ] {
        let (s, h, plain) = get(a, path, &[]).await;
        assert_eq!(s, 200, "{path}");
        assert!(!h.contains_key("content-encoding"), "{path}: compressed unasked");
        assert!(h["vary"].to_ascii_lowercase().contains("accept-encoding"), "{path}: {:?}", h["vary"]);
        let mut tags = vec![h["etag"].clone()];
        for (accept, coding) in offers.iter().copied().chain([(long.as_str(), None)]) {
            for round in 0..2 {
                // The second round is served from the cache: the same bytes and tag.
                let (s, h2, body) = get(a, path, &[("Accept-Encoding", accept)]).await;
                assert_eq!(s, 200, "{path} {accept:?}");
                assert_eq!(h2.get("content-encoding").map(String::as_str), coding, "{path} {accept:?}");
                assert!(h2["vary"].to_ascii_lowercase().contains("accept-encoding"));
                assert_eq!(decoded(coding, &body), plain, "{path} {accept:?} round {round}");
                assert_eq!(h2["content-length"], body.len().to_string());
                if coding.is_none() {
                    assert_eq!(h2["etag"], h["etag"]);
                    continue;
                }
                assert!(body.len() < plain.len(), "{path} {accept:?}: {} ≥ {}", body.len(), plain.len());
                if !tags.contains(&h2["etag"]) {
                    tags.push(h2["etag"].clone());
                }
                let (s, _, none) =
                    get(a, path, &[("Accept-Encoding", accept), ("If-None-Match", &h2["etag"])]).await;
                assert_eq!((s, none.len()), (304, 0), "{path} {accept:?}");
                let (s, h3, part) =
                    get(a, path, &[("Accept-Encoding", accept), ("Range", "bytes=0-9")]).await;
                assert_eq!(s, 206);
                assert_eq!(part, body[..10].to_vec());
                assert_eq!(h3["content-range"], format!("bytes 0-9/{}", body.len()));
                assert_eq!(h3.get("content-encoding").map(String::as_str), coding);
            }
        }
        // One strong tag per coding: plain, gzip, zstd.
        assert_eq!(tags.len(), 3, "{path}: {tags:?}");
    }
    srv.stop().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 4)]
async fn on_demand_3d_tiles_list_unbaked_nodes_and_bake_them_when_asked() {
    let tmp = tempfile::tempdir().unwrap();
    let tif = tmp.path().join("src.tif");
    common::write_synth_geotiff(&tif, (SIDE, SIDE), 9, (0.0, 0.0));
    let store = tmp.path().join("store");
    std::fs::create_dir_all(&store).unwrap();
    let spec = format!("od={},tile_size=64,max_error=1,levels=1", tif.display());
    let srv = Running::start(PartialConfig {
        store: Some(store.clone()),
        sources: vec![spec.parse().unwrap()],
        ..PartialConfig::default()
    })
    .await;
    let a = srv.addr;
    let (s, _, body) = get(a, "/tilesets/od/3dtiles/tileset.json", &[]).await;
    assert_eq!(s, 200);
    let doc: Value = serde_json::from_slice(&body).unwrap();
    assert_eq!(doc["asset"]["extras"]["terrastream"]["on_demand"], true);
    // Nothing is baked: every node of the quadtree (1 + 4 + 16) is listed with its mesh only.
    let text = String::from_utf8_lossy(&body).into_owned();
    assert_eq!(text.matches("\"provisional\":true").count(), 21);
    assert!(!store.join("od/tiles/2/1/1").exists());
    let (s, _, glb) = get(a, "/tilesets/od/3dtiles/tiles/2/1/1/0.glb", &[]).await;
    assert_eq!(s, 200);
    let glb = parse_glb(&glb);
    assert!(!glb.positions().is_empty());
    // Its border normals are shared with the tiles around it, so those are baked too (and only
    // those): the GLB's bytes never depend on what else was asked for first.
    for (x, y) in (0..4).flat_map(|x| (0..4).map(move |y| (x, y))) {
        let around = x <= 2 && y <= 2;
        assert_eq!(store.join(format!("od/tiles/2/{x}/{y}/0.tsb")).is_file(), around, "2/{x}/{y}");
    }
    let (_, h, body) = get(a, "/tilesets/od/3dtiles/tileset.json", &[]).await;
    assert_eq!(h["cache-control"], "no-cache", "it changes as nodes bake");
    // The baked nodes now have their measured levels.
    assert_eq!(String::from_utf8_lossy(&body).matches("\"provisional\":true").count(), 21 - 9);
    // A neighbour draws the vertices they share with the same normals.
    let (s, _, east) = get(a, "/tilesets/od/3dtiles/tiles/2/2/1/0.glb", &[]).await;
    assert_eq!(s, 200);
    let east = parse_glb(&east);
    let (pw, nw, pe, ne) =
        (glb.positions(), glb.rendered_normals(), east.positions(), east.rendered_normals());
    let at = |p: [f64; 3]| [(p[0] * 1e3).round() as i64, (p[2] * 1e3).round() as i64];
    let west: HashMap<[i64; 2], [f64; 3]> = pw.iter().zip(&nw).map(|(p, n)| (at(*p), *n)).collect();
    let mut shared = 0;
    for (p, n) in pe.iter().zip(&ne) {
        if let Some(w) = west.get(&at(*p)) {
            shared += 1;
            assert!(angle_deg(*w, *n) < 1e-6, "{p:?}: {w:?} vs {n:?}");
        }
    }
    assert!(shared >= 10, "{shared} shared vertices");
    srv.stop().await;
    let _ = TileKey::new(0, 0, 0);
}

#[test]
fn cli_anchor_and_export_3dtiles() {
    use common::{bin, fails, ok};
    let tmp = tempfile::tempdir().unwrap();
    let tif = tmp.path().join("t.tif");
    common::write_synth_geotiff(&tif, (65, 65), 4, (0.0, 0.0));
    let dir = tmp.path().join("t");
    // A bad anchor is refused before anything is baked, naming the value and the range.
    let e = fails(
        bin().arg("bake").arg(&tif).arg("--out").arg(&dir).args(["--anchor", "200,10", "--gpu", "off", "-q"]),
    );
    assert!(e.contains("longitude 200") && e.contains("-180..180"), "{e}");
    assert!(!dir.exists());
    ok(bin()
        .arg("bake")
        .arg(&tif)
        .arg("--out")
        .arg(&dir)
        .args(["--tile-size", "32", "--anchor", "-70.5,-33.4,520"])
        .args(["--gpu", "off", "-q"]));
    let p: Value = serde_json::from_slice(&std::fs::read(dir.join("placement.json")).unwrap()).unwrap();
    assert_eq!(p["anchor"], serde_json::json!({"lon": -70.5, "lat": -33.4, "height": 520.0}));
    let out = tmp.path().join("3d");
    let text = ok(bin().arg("export").arg(&dir).args(["--format", "3dtiles", "--out"]).arg(&out).arg("-q"));
    assert!(text.contains("GLBs") && text.contains("tileset.json"), "{text}");
    let root: Value = serde_json::from_slice(&std::fs::read(out.join("tileset.json")).unwrap()).unwrap();
    assert_eq!(root["asset"]["extras"]["terrastream"]["anchor"]["lat"], -33.4);
    // Into a folder that holds something: refused, the folder untouched.
    let e = fails(bin().arg("export").arg(&dir).args(["--format", "3dtiles", "--out"]).arg(&out));
    assert!(e.contains("not an empty directory"), "{e}");
    let e = fails(
        bin()
            .arg("export")
            .arg(&dir)
            .args(["--format", "3dtiles", "--tile", "0/0/0", "--out"])
            .arg(tmp.path().join("x")),
    );
    assert!(e.contains("whole tileset"), "{e}");
    let e =
        fails(bin().arg("export").arg(&dir).args(["--format", "obj", "--out"]).arg(tmp.path().join("x.obj")));
    assert!(e.contains("--tile"), "{e}");
    // --glb-compression: meshopt GLBs; refused for other formats and for unknown values.
    let mo = tmp.path().join("mo");
    ok(bin()
        .arg("export")
        .arg(&dir)
        .args(["--format", "3dtiles", "--glb-compression", "meshopt", "-q", "--out"])
        .arg(&mo));
    let glb = std::fs::read(mo.join("tiles/0/0/0/0.glb")).unwrap();
    assert!(String::from_utf8_lossy(&glb[..glb.len().min(4096)]).contains("EXT_meshopt_compression"));
    let e = fails(
        bin()
            .arg("export")
            .arg(&dir)
            .args([
                "--format",
                "ply",
                "--tile",
                "0/0/0",
                "--level",
                "0",
                "--glb-compression",
                "meshopt",
                "--out",
            ])
            .arg(tmp.path().join("x.ply")),
    );
    assert!(e.contains("3D Tiles only"), "{e}");
    let e = fails(
        bin()
            .arg("export")
            .arg(&dir)
            .args(["--format", "3dtiles", "--glb-compression", "brotli", "--out"])
            .arg(tmp.path().join("w")),
    );
    assert!(e.contains("none, meshopt or draco"), "{e}");
    // A placement record that is not JSON, or out of range: refused naming the file.
    for (bad, want) in
        [("{\"anchor\": {\"lon\": 500, \"lat\": 0}}", "longitude 500"), ("not json", "invalid JSON")]
    {
        std::fs::write(dir.join("placement.json"), bad).unwrap();
        let e = fails(
            bin().arg("export").arg(&dir).args(["--format", "3dtiles", "--out"]).arg(tmp.path().join("z")),
        );
        assert!(e.contains("placement.json") && e.contains(want), "{e}");
        assert!(!tmp.path().join("z").exists());
    }
    // Not a tileset at all.
    let e = fails(
        bin().arg("export").arg(tmp.path()).args(["--format", "3dtiles", "--out"]).arg(tmp.path().join("y")),
    );
    assert!(e.contains("tileset.json"), "{e}");
    assert!(!tmp.path().join("y").exists());
}

/// The angle between two directions, in degrees.
fn angle_deg(a: [f64; 3], b: [f64; 3]) -> f64 {
    glam::DVec3::from_array(a).angle_between(glam::DVec3::from_array(b)).to_degrees()
}
