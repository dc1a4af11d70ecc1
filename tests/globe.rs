//! Tilesets on the Earth (issue 36): an SRTM tile's 3D Tiles carry regions that cover the degree
//! square its name states, no root transform, and a node frame per GLB; a local-frame tileset
//! keeps its anchor. Expectations come from the file name and the 3D Tiles spec, not from the
//! project's transforms (the vertex-level check is `tests/placement/`, run in CI).
#![allow(clippy::unwrap_used, clippy::expect_used)]

mod common;

use common::{bin, ok};
use serde_json::Value;

fn hgt(dir: &std::path::Path, name: &str) -> std::path::PathBuf {
    let p = dir.join(name);
    let heights = terrastream::raster::synth::terrain(1201, 1201, 7);
    let bytes: Vec<u8> = heights.iter().flat_map(|h| (*h as i16).to_be_bytes()).collect();
    std::fs::write(&p, bytes).unwrap();
    p
}

#[test]
fn srtm_tile_is_placed_by_its_name_with_regions() {
    let tmp = tempfile::tempdir().unwrap();
    let src = hgt(tmp.path(), "S12W077.hgt");
    let store = tmp.path().join("t");
    ok(bin()
        .args(["bake", "--levels", "1", "--tile-size", "256", "--gpu", "off", "--out"])
        .arg(&store)
        .arg(&src));
    let m = terrastream::store::Store::new(&store).manifest().unwrap();
    let grid = m.frame.crs.clone().expect("an SRTM tile has a CRS");
    assert_eq!((grid.crs.definition(), m.frame.vertical.name()), ("EPSG:4326", "egm96"));
    let tiles = tmp.path().join("3d");
    ok(bin().args(["export", "--format", "3dtiles", "--out"]).arg(&tiles).arg(&store));
    let root: Value = serde_json::from_slice(&std::fs::read(tiles.join("tileset.json")).unwrap()).unwrap();
    assert!(root["root"].get("transform").is_none(), "placed per GLB, no root transform");
    let r: Vec<f64> = root["root"]["boundingVolume"]["region"]
        .as_array()
        .expect("a region")
        .iter()
        .map(|v| v.as_f64().unwrap())
        .collect();
    // The tile spans 77° W..76° W, 12° S..11° S (its name), within the region's 1 % margin.
    let deg: Vec<f64> = r[..4].iter().map(|v| v.to_degrees()).collect();
    assert!(deg[0] <= -77.0 && deg[0] > -77.02 && deg[2] >= -76.0 && deg[2] < -75.98, "{deg:?}");
    assert!(deg[1] <= -12.0 && deg[1] > -12.02 && deg[3] >= -11.0 && deg[3] < -10.98, "{deg:?}");
    // EGM96 is 10–40 m off the ellipsoid there: the heights are not the raster's any more.
    assert!(r[4] < r[5]);
    let extras = &root["asset"]["extras"]["terrastream"];
    assert_eq!(extras["placement"], "exact", "{extras}");
    assert_eq!(extras["frame"]["vertical_datum"], "egm96");
    // Every GLB's node holds a matrix with an Earth-sized translation.
    let glb = std::fs::read(tiles.join("tiles/0/0/0/0.glb")).unwrap();
    let jl = u32::from_le_bytes(glb[12..16].try_into().unwrap()) as usize;
    let json: Value = serde_json::from_slice(&glb[20..20 + jl]).unwrap();
    let m: Vec<f64> =
        json["nodes"][0]["matrix"].as_array().unwrap().iter().map(|v| v.as_f64().unwrap()).collect();
    let t = (m[12] * m[12] + m[13] * m[13] + m[14] * m[14]).sqrt();
    assert!((6.3e6..6.4e6).contains(&t), "node translation {t} m from the Earth's centre");
}

#[test]
fn unsupported_crs_is_refused_by_name_and_nothing_is_written() {
    let tmp = tempfile::tempdir().unwrap();
    let src = hgt(tmp.path(), "N35E138.hgt");
    let store = tmp.path().join("t");
    let e = common::fails(bin().args(["bake", "--crs", "EPSG:99999", "--out"]).arg(&store).arg(&src));
    assert!(e.contains("EPSG:99999"), "{e}");
    let e = common::fails(bin().args(["bake", "--cell-size", "90", "--out"]).arg(&store).arg(&src));
    assert!(e.contains("--cell-size") && e.contains("EPSG:4326"), "{e}");
    assert!(!store.exists(), "nothing written");
}
