//! Cesium globe terrain (issue 37): `bake --terrain` writes quantized-mesh tiles whose
//! availability follows the data, whose neighbours share their edges exactly (positions,
//! heights and normals), whose heights are the source's plus the geoid within the stated error;
//! the server gives the baked tiles and builds the same bytes on demand, negotiating extensions
//! and gzip. Expectations come from the file name, the format and the source heights (the
//! independent decoder and CesiumJS checks are in `tests/interop/`).
#![allow(clippy::unwrap_used, clippy::expect_used)]

mod common;

use std::collections::BTreeMap;
use std::io::Read;
use std::path::Path;

use common::{bin, fails, get_with as get, ok, serve_store};
use serde_json::Value;
use terrastream::formats::qmesh::codec::{QmTile, decode};
use terrastream::formats::qmesh::grid::{TileId, cell_degrees, zoom_error};

const SIDE: usize = 1201;

fn hgt(dir: &Path, name: &str) -> (std::path::PathBuf, Vec<f32>) {
    let p = dir.join(name);
    let heights = terrastream::raster::synth::terrain(SIDE as u32, SIDE as u32, 11);
    let bytes: Vec<u8> = heights.iter().flat_map(|h| (*h as i16).to_be_bytes()).collect();
    std::fs::write(&p, bytes).unwrap();
    (p, heights.iter().map(|h| f32::from(*h as i16)).collect())
}

/// Bilinear height of the synthetic N46E010 tile at a point (rows from the north, 3″ cells).
fn source_height(h: &[f32], lon: f64, lat: f64) -> Option<f64> {
    let c = (lon - 10.0) * 1200.0;
    let r = (47.0 - lat) * 1200.0;
    if !(0.0..=1200.0).contains(&c) || !(0.0..=1200.0).contains(&r) {
        return None;
    }
    let (c0, r0) = ((c.floor() as usize).min(SIDE - 2), (r.floor() as usize).min(SIDE - 2));
    let (fx, fy) = (c - c0 as f64, r - r0 as f64);
    let v = |c: usize, r: usize| f64::from(h[r * SIDE + c]);
    Some(
        (v(c0, r0) * (1.0 - fx) + v(c0 + 1, r0) * fx) * (1.0 - fy)
            + (v(c0, r0 + 1) * (1.0 - fx) + v(c0 + 1, r0 + 1) * fx) * fy,
    )
}

/// Every tile of a baked terrain, decoded.
fn tiles(dir: &Path) -> BTreeMap<TileId, QmTile> {
    let mut out = BTreeMap::new();
    for z in std::fs::read_dir(dir.join("terrain")).unwrap() {
        let z = z.unwrap().path();
        let Some(zv) = z.file_name().and_then(|n| n.to_str()).and_then(|n| n.parse::<u8>().ok()) else {
            continue;
        };
        for x in std::fs::read_dir(&z).unwrap() {
            let x = x.unwrap().path();
            let xv: u32 = x.file_name().unwrap().to_str().unwrap().parse().unwrap();
            for y in std::fs::read_dir(&x).unwrap() {
                let y = y.unwrap().path();
                let yv: u32 = y.file_stem().unwrap().to_str().unwrap().parse().unwrap();
                let t = decode(&std::fs::read(&y).unwrap());
                assert!(t.is_ok(), "{}: {:?}", y.display(), t.err());
                let t = t.unwrap();
                out.insert(TileId::new(zv, xv, yv).unwrap(), t);
            }
        }
    }
    out
}

/// Asserts that every two same-zoom neighbours (east–west, also across the antimeridian, and
/// south–north) have the same edge vertices: position along the edge, decoded height, normal
/// bytes. Returns the pairs checked.
fn assert_edges_shared(all: &BTreeMap<TileId, QmTile>) -> usize {
    let mut pairs = 0;
    for (&id, t) in all {
        let cols = 2u32 << id.z;
        for (other, mine, west_of_other, along_v) in [
            (TileId { x: (id.x + 1) % cols, ..id }, &t.east, true, true),
            (TileId { y: id.y + 1, ..id }, &t.north, false, false),
        ] {
            let Some(o) = all.get(&other) else { continue };
            let theirs = if west_of_other { &o.west } else { &o.south };
            let key = |tile: &QmTile, k: u32| {
                let k = k as usize;
                let pos = if along_v { tile.v[k] } else { tile.u[k] };
                (pos, (height(tile, k) * 1e6).round() as i64, tile.normals.as_ref().unwrap()[k])
            };
            let a: Vec<_> = mine.iter().map(|&k| key(t, k)).collect();
            let b: Vec<_> = theirs.iter().map(|&k| key(o, k)).collect();
            assert_eq!(a, b, "{id} and {other} disagree on their edge");
            pairs += 1;
        }
    }
    pairs
}

fn height(t: &QmTile, k: usize) -> f64 {
    let (lo, hi) = (f64::from(t.header.min_height), f64::from(t.header.max_height));
    lo + (hi - lo) * f64::from(t.h[k]) / 32767.0
}

fn lonlat(id: TileId, t: &QmTile, k: usize) -> (f64, f64) {
    let r = id.rect();
    (
        r.west + (r.east - r.west) * f64::from(t.u[k]) / 32767.0,
        r.south + (r.north - r.south) * f64::from(t.v[k]) / 32767.0,
    )
}

#[test]
fn baked_terrain_covers_the_data_shares_edges_and_holds_the_source_heights() {
    let tmp = tempfile::tempdir().unwrap();
    let (src, heights) = hgt(tmp.path(), "N46E010.hgt");
    let out = tmp.path().join("t");
    let printed = ok(bin()
        .args([
            "bake",
            "--levels",
            "1",
            "--tile-size",
            "256",
            "--gpu",
            "off",
            "--terrain",
            "--terrain-max-zoom",
            "10",
            "--out",
        ])
        .arg(&out)
        .arg(&src));
    assert!(printed.contains("quantized-mesh tiles"), "{printed}");
    let layer: Value =
        serde_json::from_slice(&std::fs::read(out.join("terrain/layer.json")).unwrap()).unwrap();
    assert_eq!(
        (layer["format"].as_str(), layer["scheme"].as_str()),
        (Some("quantized-mesh-1.0"), Some("tms"))
    );
    assert_eq!(layer["maxzoom"], 10);
    assert_eq!(layer["metadataAvailability"], 10);
    let available = layer["available"].as_array().unwrap();
    assert_eq!(available.len(), 11);
    // Zoom 0: both roots. Deeper: the tiles over 10–11° E, 46–47° N (plus half a cell, the
    // .hgt's samples being points), from the tiling's definition.
    assert_eq!(available[0], serde_json::json!([{"startX": 0, "startY": 0, "endX": 1, "endY": 0}]));
    let half = 0.5 / 1200.0;
    for (z, ranges) in available.iter().enumerate().skip(1) {
        let s = 180.0 / f64::from(1u32 << z);
        let want = serde_json::json!([{
            "startX": ((10.0 - half + 180.0) / s).floor() as u32,
            "startY": ((46.0 - half + 90.0) / s).floor() as u32,
            "endX": ((11.0 + half + 180.0) / s).floor() as u32,
            "endY": ((47.0 + half + 90.0) / s).floor() as u32,
        }]);
        assert_eq!(ranges, &want, "zoom {z}");
    }
    let all = tiles(&out);
    let listed: usize = available
        .iter()
        .flat_map(|l| l.as_array().unwrap())
        .map(|r| {
            let n = |k: &str| r[k].as_u64().unwrap() as usize;
            (n("endX") - n("startX") + 1) * (n("endY") - n("startY") + 1)
        })
        .sum();
    assert_eq!(all.len(), listed, "one file per available tile");

    let stats: Value =
        serde_json::from_slice(&std::fs::read(out.join("terrain/stats.json")).unwrap()).unwrap();
    for (z, s) in stats["per_zoom"].as_object().unwrap() {
        let z: u8 = z.parse().unwrap();
        assert!(s["max_error"].as_f64().unwrap() <= zoom_error(z, 1.0), "zoom {z}: {s}");
    }

    let pairs = assert_edges_shared(&all);
    assert!(pairs > 100, "{pairs} neighbour pairs");

    // Heights at the finest zoom: the source's (bilinear) plus EGM96's undulation, within the
    // edge lattice's rounding (vertices are samples; the TIN's error is between them).
    let geoid = terrastream::crs::Geoid::egm96().unwrap();
    let mut checked = 0;
    for (&id, t) in all.iter().filter(|(id, _)| id.z == 10) {
        for k in 0..t.u.len() {
            let (lon, lat) = lonlat(id, t, k);
            // u/v are quantized to 1/32767 of the tile: compare at the sample the vertex stands
            // for, recovered from its u/v.
            let step = cell_degrees(10);
            let r = id.rect();
            let (slon, slat) = (
                r.west + ((lon - r.west) / step).round() * step,
                r.south + ((lat - r.south) / step).round() * step,
            );
            let Some(h) = source_height(&heights, slon, slat) else { continue };
            let want = h + geoid.undulation(slon, slat).unwrap();
            // Edge heights are rounded to the zoom's lattice, the others to the tile's step.
            let edge = t.u[k] == 0 || t.v[k] == 0 || t.u[k] == 32767 || t.v[k] == 32767;
            let tile_step = f64::from(t.header.max_height - t.header.min_height) / 32767.0;
            let tol = if edge { terrastream::formats::qmesh::grid::edge_lattice(10) } else { tile_step }
                / 2.0
                + 1e-3;
            assert!(
                (height(t, k) - want).abs() <= tol,
                "{id} vertex {k} at {slon}, {slat}: {} vs {want}",
                height(t, k)
            );
            checked += 1;
        }
    }
    assert!(checked > 500, "{checked} vertices checked");
}

#[test]
fn terrain_across_the_antimeridian_is_one_surface() {
    let tmp = tempfile::tempdir().unwrap();
    let tif = tmp.path().join("fiji.tif");
    let side = 121;
    let mut f = std::fs::File::create(&tif).unwrap();
    // 179.5° E to 180.5° E (that is, −179.5°), 16° S to 17° S; heights smooth across 180°.
    terrastream::raster::geotiff::write_tiled_f32(
        &mut f,
        (side, side),
        32,
        terrastream::raster::geotiff::Model::Geographic,
        (179.5, -16.0),
        (1.0 / 120.0, -1.0 / 120.0),
        None,
        false,
        |c, r| 300.0 + 200.0 * (f64::from(c) / 9.0).sin() as f32 * (f64::from(r) / 13.0).cos() as f32,
    )
    .unwrap();
    drop(f);
    let out = tmp.path().join("t");
    ok(bin()
        .args([
            "bake",
            "--levels",
            "1",
            "--tile-size",
            "64",
            "--gpu",
            "off",
            "--terrain",
            "--terrain-max-zoom",
            "7",
            "--out",
        ])
        .arg(&out)
        .arg(&tif));
    let layer: Value =
        serde_json::from_slice(&std::fs::read(out.join("terrain/layer.json")).unwrap()).unwrap();
    for z in 1..=7usize {
        let ranges = layer["available"][z].as_array().unwrap();
        let xs: Vec<u64> = ranges
            .iter()
            .flat_map(|r| [r["startX"].as_u64().unwrap(), r["endX"].as_u64().unwrap()])
            .collect();
        assert!(
            xs.contains(&0) && xs.contains(&((2u64 << z) - 1)),
            "zoom {z}: tiles on both sides of 180°: {ranges:?}"
        );
    }
    let all = tiles(&out);
    let across = all
        .keys()
        .filter(|id| id.z > 0 && id.x == (2u32 << id.z) - 1 && all.contains_key(&TileId { x: 0, ..**id }))
        .count();
    assert!(across >= 7, "{across} tile pairs meet at the antimeridian");
    assert!(assert_edges_shared(&all) >= across);
}

#[test]
fn terrain_needs_a_placed_input() {
    let tmp = tempfile::tempdir().unwrap();
    let png = tmp.path().join("local.png");
    common::write_terrain_rgb_png(&png, 64, 64, 3);
    let out = tmp.path().join("t");
    let e = fails(
        bin()
            .args([
                "bake",
                "--levels",
                "1",
                "--gpu",
                "off",
                "--terrain",
                "--encoding",
                "terrain-rgb",
                "--out",
            ])
            .arg(&out)
            .arg(&png),
    );
    assert!(e.contains("--terrain") && e.contains("coordinate reference system"), "{e}");
    assert!(!out.join("tileset.json").exists(), "refused before baking");
    // A shard of a plan does not bake terrain: said, not silently ignored.
    let e = fails(bin().args(["bake", "--plan"]).arg(tmp.path().join("plan")).args([
        "--shard",
        "0",
        "--terrain",
    ]));
    assert!(e.contains("--terrain") && e.contains("--plan"), "{e}");
}

const ALL: &str = "application/vnd.quantized-mesh;extensions=octvertexnormals-watermask-metadata,*/*;q=0.01";

#[test]
fn served_terrain_is_the_baked_one_and_on_demand_builds_the_same_bytes() {
    let tmp = tempfile::tempdir().unwrap();
    let (src, _) = hgt(tmp.path(), "N46E010.hgt");
    let store = tmp.path().join("store");
    ok(bin()
        .args([
            "bake",
            "--levels",
            "1",
            "--tile-size",
            "256",
            "--gpu",
            "off",
            "--terrain",
            "--terrain-max-zoom",
            "8",
            "--out",
        ])
        .arg(store.join("baked"))
        .arg(&src));
    let server =
        serve_store(&store, &[format!("od={},tile_size=256,levels=1,terrain_max_zoom=8", src.display())]);
    let a = server.addr;
    let baked = tiles(&store.join("baked"));
    assert!(baked.len() > 10, "{} tiles", baked.len());
    for (i, (id, _)) in baked.iter().enumerate() {
        if i % 3 != 0 && id.z > 2 {
            continue;
        }
        let path = |ts: &str| format!("/tilesets/{ts}/terrain/{}/{}/{}.terrain", id.z, id.x, id.y);
        let file =
            std::fs::read(store.join(format!("baked/terrain/{}/{}/{}.terrain", id.z, id.x, id.y))).unwrap();
        let (s, h, body) = get(a, &path("baked"), &[("Accept", ALL)]);
        assert_eq!(s, 200, "{}", path("baked"));
        assert_eq!(body, file, "{}: the stored tile, every extension asked for", path("baked"));
        assert_eq!(
            h["content-type"],
            "application/vnd.quantized-mesh;extensions=octvertexnormals-watermask-metadata"
        );
        assert_eq!(h["vary"], "accept, accept-encoding");
        let (s, _, od) = get(a, &path("od"), &[("Accept", ALL)]);
        assert_eq!(s, 200, "{}", path("od"));
        assert!(od == body, "{id}: built on demand differs from baked");
        // No extension asked for: none sent.
        let (_, h, plain) = get(
            a,
            &path("baked"),
            &[("Accept", "application/vnd.quantized-mesh,application/octet-stream;q=0.9")],
        );
        assert_eq!(h["content-type"], "application/vnd.quantized-mesh");
        let d = decode(&plain).unwrap();
        assert!(d.normals.is_none() && d.watermask.is_none() && d.metadata.is_none());
        assert_eq!(d.triangles, decode(&file).unwrap().triangles);
        // Gzip when allowed: the same bytes once inflated.
        let (_, h, gz) = get(a, &path("od"), &[("Accept", ALL), ("Accept-Encoding", "gzip, br")]);
        assert_eq!(h["content-encoding"], "gzip");
        let mut inflated = Vec::new();
        flate2::read::GzDecoder::new(&gz[..]).read_to_end(&mut inflated).unwrap();
        assert_eq!(inflated, file);
        let (s, _, _) = get(
            a,
            &path("od"),
            &[("Accept", ALL), ("Accept-Encoding", "gzip"), ("If-None-Match", &h["etag"])],
        );
        assert_eq!(s, 304);
    }
    // Metadata at zoom 0 names the data's tiles below it.
    let root = decode(&get(a, "/tilesets/od/terrain/0/1/0.terrain", &[("Accept", ALL)]).2).unwrap();
    let m: Value = serde_json::from_str(root.metadata.as_deref().unwrap()).unwrap();
    assert_eq!(m["available"].as_array().unwrap().len(), 8);
    // Both layer documents list the same tiles.
    let lb: Value = serde_json::from_slice(&get(a, "/tilesets/baked/terrain/layer.json", &[]).2).unwrap();
    let lo: Value = serde_json::from_slice(&get(a, "/tilesets/od/terrain/layer.json", &[]).2).unwrap();
    assert_eq!(lb["available"], lo["available"]);
    for (path, headers, status) in [
        ("/tilesets/od/terrain/8/0/0.terrain", vec![], 404),
        ("/tilesets/baked/terrain/8/0/0.terrain", vec![], 404),
        ("/tilesets/od/terrain/0/2/0.terrain", vec![], 404),
        ("/tilesets/od/terrain/30/0/0.terrain", vec![], 404),
        ("/tilesets/od/terrain/0/0/0.png", vec![], 400),
        ("/tilesets/od/terrain/0/0/x.terrain", vec![], 400),
        ("/tilesets/od/terrain/0/0/0.terrain", vec![("Accept", "image/png")], 406),
        ("/tilesets/nope/terrain/layer.json", vec![], 404),
    ] {
        let (s, h, body) = get(a, path, &headers);
        assert_eq!(s, status, "{path}: {}", String::from_utf8_lossy(&body));
        assert_eq!(h["content-type"], "application/problem+json", "{path}");
    }
}

/// A fine DEM (2 m cells) of a plateau 2.4–2.6 km above sea level: at its deepest zooms the
/// tiles on its edge hold the plateau and the sea-level fill beside it, more relief than the
/// zoom's own edge lattice (1/32 m at zoom 17) holds in a tile's 15 bits. The lattice follows the
/// dataset's relief instead: every same-zoom pair shares its edges, no tile misses the lattice,
/// and every zoom's measured error is within its bound.
#[test]
fn a_high_plateau_at_fine_resolution_keeps_its_edges_and_its_bound() {
    let tmp = tempfile::tempdir().unwrap();
    let (w, h) = (300u32, 300u32);
    let heights: Vec<f32> = (0..w * h)
        .map(|k| {
            let (c, r) = (f64::from(k % w), f64::from(k / w));
            (2_500.0 + 80.0 * (c / 23.0).sin() * (r / 31.0).cos() + 0.02 * c) as f32
        })
        .collect();
    let tif = tmp.path().join("plateau.tif");
    let bytes =
        terrastream::raster::geotiff::encode_f32(w, h, &heights, (650_000.0, 5_170_000.0), (2.0, -2.0))
            .unwrap();
    std::fs::write(&tif, bytes).unwrap();
    let out = tmp.path().join("t");
    ok(bin()
        .args(["bake", "--levels", "1", "--gpu", "off", "--terrain", "--crs", "EPSG:32632", "--out"])
        .arg(&out)
        .arg(&tif));
    let stats: Value =
        serde_json::from_slice(&std::fs::read(out.join("terrain/stats.json")).unwrap()).unwrap();
    assert_eq!(stats["lattice_misses"], 0, "{stats}");
    let deepest = stats["max_zoom"].as_u64().unwrap();
    assert!(deepest >= 17, "2 m cells reach zoom 17: {deepest}");
    for (z, s) in stats["per_zoom"].as_object().unwrap() {
        let (e, b) = (s["max_error"].as_f64().unwrap(), s["bound"].as_f64().unwrap());
        assert!(e <= b, "zoom {z}: measured {e} over the bound {b}");
    }
    let all = tiles(&out);
    let edge_tiles = all
        .iter()
        .filter(|(id, t)| u64::from(id.z) == deepest && t.header.max_height - t.header.min_height > 2_000.0);
    assert!(edge_tiles.count() > 0, "tiles hold the plateau's edge");
    assert!(assert_edges_shared(&all) > 0);
    // On demand (the server finds the same relief in its copy of the raster): the same bytes.
    let store = tmp.path().join("store");
    std::fs::create_dir_all(&store).unwrap();
    let server = serve_store(&store, &[format!("od={},levels=1,crs=EPSG:32632", tif.display())]);
    for (i, id) in all.keys().filter(|id| u64::from(id.z) + 1 >= deepest).enumerate() {
        if i % 7 != 0 {
            continue;
        }
        let file = std::fs::read(out.join(format!("terrain/{}/{}/{}.terrain", id.z, id.x, id.y))).unwrap();
        let path = format!("/tilesets/od/terrain/{}/{}/{}.terrain", id.z, id.x, id.y);
        let (s, _, od) = get(server.addr, &path, &[("Accept", ALL)]);
        assert_eq!(s, 200, "{path}");
        assert!(od == file, "{id}: built on demand differs from baked");
    }
}
