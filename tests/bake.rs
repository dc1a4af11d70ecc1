//! End-to-end bakes through the `terrastream` binary and the library: real rasters in, tileset
//! directories out; errors, crack-free borders, determinism and resume checked on the result.

// Helpers outside `#[test]` functions unwrap too: a failure there is a test failure.
#![allow(clippy::unwrap_used, clippy::float_cmp)]

mod common;
use common::{bin, fails, fuji_or_generated, ok, tree};

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use terrastream::codec::{self, Geometry};
use terrastream::store::Store;
use terrastream::tiling::{Pyramid, TileKey};

fn bake_fuji(fuji: &Path, out: &Path) -> String {
    ok(bin()
        .args(["bake", "--quiet", "--encoding", "terrain-rgb", "--cell-size", "30", "--tile-size", "128"])
        .args(["--max-error", "2", "--levels", "3", "--out"])
        .arg(out)
        .arg(fuji))
}

fn decode(store: &Store, key: TileKey, level: u8) -> codec::Blob {
    codec::decode(&store.read_blob(key, level).unwrap().unwrap()).unwrap()
}

#[test]
fn fuji_bake_errors_borders_determinism_resume() {
    let tmp = tempfile::tempdir().unwrap();
    let fuji = fuji_or_generated(tmp.path(), "bake::fuji_bake_errors_borders_determinism_resume");
    let a = tmp.path().join("a");
    let summary = bake_fuji(&fuji, &a);
    assert!(summary.contains("baked 21 tiles"), "{summary}");

    let store = Store::new(&a);
    let m = store.manifest().unwrap();
    assert_eq!((m.source.width, m.source.height, m.tile_size, m.depth), (512, 512, 128, 2));
    let pyramid = Pyramid::new(512, 512, 128).unwrap();
    // Only levels that pay are stored, and the index says which (issue 13).
    let (nodes, stored, left_out) = common::assert_levels_pay(&a);
    assert_eq!((nodes, stored + left_out), (21, 21 * 4));
    let mut meshes = BTreeMap::new();
    for key in pyramid.nodes() {
        let node = store.node(key).unwrap().unwrap();
        let step = f64::from(pyramid.step(key.z));
        let blob = decode(&store, key, 0);
        // Leaves hold every full-resolution sample within the bound (plus half a z quantization
        // step of max_error / 64). Parents meet the scaled bound on their own downsampled grid;
        // their measured error is against full resolution, so it is larger, never smaller.
        let e = node.levels[0].errors;
        if key.z == pyramid.depth {
            let bound = 2.0 * (1.0 + 1.0 / 128.0) + 1e-6;
            assert!(e.max <= bound, "{key}: {} > {bound}", e.max);
        } else {
            assert!(e.max.is_finite() && e.max >= 2.0 * step * 0.5, "{key}: {}", e.max);
        }
        assert!(e.max > 0.0 && e.rms <= e.max);
        assert_eq!(blob.header.errors, node.levels[0].errors);
        for l in node.levels.iter().map(|l| l.level).filter(|&l| l > 0) {
            let pts = decode(&store, key, l);
            let e = node.level(l).unwrap().errors;
            let cell = 30.0 * step * f64::from(1u32 << l);
            assert!(matches!(pts.geometry, Geometry::Points(ref p) if !p.positions.is_empty()));
            // `max` is measured on the level as drawn: a point within half a cell of the surface,
            // its footprint's corners at most a cube's half-diagonal (√3 · 0.9 cells) further.
            let reach = (0.5 + 3f64.sqrt() * terrastream::lod::TERRAIN_FOOTPRINT_HALF) * cell;
            assert!(e.max < reach, "{key} level {l}: drawn distance {} vs cell {cell}", e.max);
            assert!(e.gap < 2.0 * cell, "{key} level {l}: gap {} vs cell {cell}", e.gap);
        }
        let Geometry::Mesh(mesh) = blob.geometry else { panic!("level 0 of {key} is not a mesh") };
        meshes.insert(key, mesh);
    }
    // Crack-free: neighbours at the same depth have identical vertices on their shared edge.
    for (key, mesh) in &meshes {
        for (dx, dy) in [(1, 0), (0, 1)] {
            let Some(other) = meshes.get(&TileKey::new(key.z, key.x + dx, key.y + dy)) else { continue };
            let span = pyramid.span(*key);
            let (axis, edge) =
                if dx == 1 { (0, f64::from(span.col1) * 30.0) } else { (1, f64::from(span.row1) * 30.0) };
            let on_edge = |m: &terrastream::geom::Mesh| {
                let mut v: Vec<[u64; 3]> = m
                    .positions
                    .iter()
                    .filter(|p| (p[axis] - edge).abs() < 1e-6)
                    .map(|p| p.map(f64::to_bits))
                    .collect();
                v.sort_unstable();
                v
            };
            let (ea, eb) = (on_edge(mesh), on_edge(other));
            assert!(ea.len() >= 2, "{key}: no vertices on its edge");
            assert_eq!(ea, eb, "{key}: border vertices differ from its neighbour's");
        }
    }

    // Deterministic: a second bake is byte-identical.
    let b = tmp.path().join("b");
    bake_fuji(&fuji, &b);
    let (ta, tb) = (tree(&a), tree(&b));
    assert_eq!(ta.keys().collect::<Vec<_>>(), tb.keys().collect::<Vec<_>>());
    assert!(ta == tb, "two bakes of the same input differ");

    // Resume: delete some blobs and the manifest, bake again, get the same tree.
    std::fs::remove_file(b.join("tileset.json")).unwrap();
    std::fs::remove_file(store_blob(&b, TileKey::new(2, 1, 2), 0)).unwrap();
    // A point blob lost since is baked again (the node's other levels say it was stored), and
    // so is a lost `unpaid` marker.
    let root = store.node(TileKey::new(0, 0, 0)).unwrap().unwrap();
    let kept = root.levels.last().unwrap().level;
    if kept > 0 {
        std::fs::remove_file(store_blob(&b, TileKey::new(0, 0, 0), kept)).unwrap();
    }
    for l in 1..4u8 {
        if root.level(l).is_none() {
            std::fs::remove_file(Store::new(&b).unpaid_path(TileKey::new(0, 0, 0), l)).unwrap();
            break;
        }
    }
    std::fs::remove_dir_all(b.join("index")).unwrap();
    let summary = bake_fuji(&fuji, &b);
    assert!(summary.contains("(19 resumed)"), "{summary}");
    assert!(tree(&b) == ta, "resumed bake differs from a fresh one");

    // A bake over it with other options is refused and changes nothing.
    let err = fails(
        bin()
            .args(["bake", "--quiet", "--encoding", "terrain-rgb", "--cell-size", "30"])
            .arg("--out")
            .arg(&b)
            .arg(&fuji),
    );
    assert!(err.contains("different options"), "{err}");
    assert!(tree(&b) == ta);

    // inspect and export work on the result.
    let text = ok(bin().arg("inspect").arg(&a));
    assert!(text.contains("mesh") && text.contains("points"), "{text}");
    let json: serde_json::Value =
        serde_json::from_str(&ok(bin().arg("inspect").arg(&a).arg("--json"))).unwrap();
    assert_eq!(json["depth"], 2);
    let node: serde_json::Value =
        serde_json::from_str(&ok(bin().arg("inspect").arg(&a).args(["--json", "--tile", "1/1/0"]))).unwrap();
    let stored_1_1_0 = store.node(TileKey::new(1, 1, 0)).unwrap().unwrap().levels.len();
    assert_eq!(node["levels"].as_array().unwrap().len(), stored_1_1_0);
    assert!(text.contains("levels per node"), "{text}");
    let ply = tmp.path().join("t.ply");
    ok(bin()
        .arg("export")
        .arg(&a)
        .args(["--tile", "2/3/3", "--level", "0", "--format", "ply", "--out"])
        .arg(&ply));
    let head = std::fs::read(&ply).unwrap();
    let n = meshes[&TileKey::new(2, 3, 3)].positions.len();
    assert!(String::from_utf8_lossy(&head[..200]).contains(&format!("element vertex {n}")));
    let obj = tmp.path().join("p.obj");
    ok(bin()
        .arg("export")
        .arg(&a)
        .args(["--tile", "0/0/0", "--level", "2", "--format", "obj", "--out"])
        .arg(&obj));
    assert!(std::fs::read_to_string(&obj).unwrap().contains("\nvn "));
}

fn store_blob(dir: &Path, key: TileKey, level: u8) -> PathBuf {
    Store::new(dir).blob_path(key, level)
}

#[test]
fn bad_inputs_fail_cleanly_and_write_nothing() {
    let tmp = tempfile::tempdir().unwrap();
    let fuji = fuji_or_generated(tmp.path(), "bake::bad_inputs_fail_cleanly_and_write_nothing");
    let out = tmp.path().join("out");
    let missing = tmp.path().join("nope.png");
    let err = fails(bin().arg("bake").arg(&missing).arg("--out").arg(&out));
    assert!(err.contains("nope.png"), "{err}");
    assert!(!out.exists());

    let garbage = tmp.path().join("garbage.tif");
    std::fs::write(&garbage, b"II*\0garbage garbage").unwrap();
    let err = fails(bin().arg("bake").arg(&garbage).arg("--out").arg(&out));
    assert!(err.contains("garbage.tif"), "{err}");
    assert!(!out.exists());

    let err = fails(
        bin()
            .arg("bake")
            .arg(&fuji)
            .args(["--encoding", "terrain-rgb", "--max-side", "100", "--out"])
            .arg(&out),
    );
    assert!(err.contains("fuji.png"), "{err}");
    assert!(!out.exists());

    let err = fails(
        bin().arg("bake").arg(&fuji).args(["--encoding", "terrain-rgb", "--max-error=-1", "--out"]).arg(&out),
    );
    assert!(err.contains("max-error"), "{err}");
    assert!(!out.exists());

    let err = fails(bin().arg("inspect").arg(tmp.path()));
    assert!(err.contains("tileset.json"), "{err}");
}

#[test]
fn generated_geotiff_bakes_with_its_georeference() {
    let tmp = tempfile::tempdir().unwrap();
    let tif = tmp.path().join("synth.tif");
    ok(bin().args(["synth", "--width", "300", "--height", "200", "--cell-size", "5", "--out"]).arg(&tif));
    let out = tmp.path().join("t");
    let summary = ok(bin()
        .args(["bake", "--quiet", "--tile-size", "64", "--levels", "2", "--out"])
        .arg(&out)
        .arg(&tif));
    assert!(summary.contains("baked"), "{summary}");
    let m = Store::new(&out).manifest().unwrap();
    assert_eq!((m.source.format.as_str(), m.source.width, m.source.height), ("geotiff", 300, 200));
    assert_eq!((m.frame.dx, m.frame.dy), (5.0, -5.0));
    // North-up: rows go south, so the world y range is [-199·5, 0].
    assert_eq!(m.bounds.max[1], 0.0);
    assert_eq!(m.bounds.min[1], -995.0);
    assert_eq!(m.bounds.max[0], 1495.0);
    // Triangles face up in world coordinates even though rows run south.
    let blob =
        codec::decode(&Store::new(&out).read_blob(TileKey::new(0, 0, 0), 0).unwrap().unwrap()).unwrap();
    let Geometry::Mesh(mesh) = blob.geometry else { panic!("not a mesh") };
    for t in &mesh.triangles {
        let [a, b, c] = t.map(|i| mesh.positions[i as usize]);
        let n = terrastream::geom::triangle_normal(a, b, c);
        assert!(n[2] > 0.0, "downward triangle {t:?}");
    }
}

#[test]
fn srtm_hgt_with_voids_bakes_in_a_local_metric_frame() {
    let tmp = tempfile::tempdir().unwrap();
    let hgt = tmp.path().join("N35E138.hgt");
    let heights = terrastream::raster::synth::terrain(1201, 1201, 5);
    let mut bytes = Vec::with_capacity(1201 * 1201 * 2);
    for (k, h) in heights.iter().enumerate() {
        // A block of voids in the middle, filled from its neighbours.
        let (r, c) = (k / 1201, k % 1201);
        let v: i16 = if (600..610).contains(&r) && (300..320).contains(&c) { -32768 } else { *h as i16 };
        bytes.extend_from_slice(&v.to_be_bytes());
    }
    std::fs::write(&hgt, bytes).unwrap();
    let out = tmp.path().join("t");
    let summary =
        ok(bin().args(["bake", "--quiet", "--levels", "1", "--max-error", "5", "--out"]).arg(&out).arg(&hgt));
    assert!(summary.contains("200 no-data samples filled"), "{summary}");
    let m = Store::new(&out).manifest().unwrap();
    let geo = m.frame.crs.clone().expect("hgt is geographic");
    assert_eq!((geo.e0, geo.n0, geo.crs.definition()), (138.0, 36.0, "EPSG:4326"));
    assert_eq!(m.frame.vertical, terrastream::crs::VerticalDatum::Egm96);
    // 3 arc-seconds is about 92 m north-south and 75 m east-west at 35.5° N.
    assert!((m.frame.dy + 92.5).abs() < 1.0, "dy {}", m.frame.dy);
    assert!((m.frame.dx - 75.5).abs() < 1.0, "dx {}", m.frame.dx);
    assert_eq!(m.source.nodata_filled, 200);
}
