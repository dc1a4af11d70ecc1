//! Heights for simulators (issue 38): `POST/GET /tilesets/{name}/heights`. `surface=source`
//! answers the source raster's bilinear height (computed here from the raster's own samples),
//! on the EGM96 geoid or the ellipsoid (EGM96 from PROJ's `egm96_15.gtx`); `surface=mesh`
//! answers the finest TIN, within its stated error of the source at the raster's samples, with
//! the same numbers from a folder and from a `.tsa` archive. Bad points, bodies and options are
//! problem+json errors naming what is wrong.
#![allow(clippy::unwrap_used, clippy::expect_used, clippy::float_cmp)]

mod common;

use std::path::Path;

use common::{bin, ok, request, serve_store};
use serde_json::Value;

const SIDE: usize = 1201;

/// A synthetic 3″ SRTM tile N46E010 (WGS 84, EGM96 heights) and its samples.
fn hgt(dir: &Path) -> (std::path::PathBuf, Vec<f32>) {
    let p = dir.join("N46E010.hgt");
    let heights = terrastream::raster::synth::terrain(SIDE as u32, SIDE as u32, 5);
    let bytes: Vec<u8> = heights.iter().flat_map(|h| (*h as i16).to_be_bytes()).collect();
    std::fs::write(&p, bytes).unwrap();
    (p, heights.iter().map(|h| f32::from(*h as i16)).collect())
}

/// Bakes the tile `src` as one 256-sample level-0 mesh per node into `out`.
fn bake_mesh(src: &Path, out: &Path) {
    ok(bin()
        .args(["bake", "--levels", "1", "--tile-size", "256", "--gpu", "off", "-q", "--out"])
        .arg(out)
        .arg(src));
}

/// The `--source` of an on-demand tileset `od` of `src`, baked as [`bake_mesh`] does.
fn on_demand(src: &Path) -> String {
    format!("od={},tile_size=256,levels=1", src.display())
}

/// The raster's bilinear height at (lon, lat): rows from the north, 1/1200° cells.
fn bilinear(h: &[f32], lon: f64, lat: f64) -> f64 {
    let (c, r) = ((lon - 10.0) * 1200.0, (47.0 - lat) * 1200.0);
    let (c0, r0) = ((c.floor() as usize).min(SIDE - 2), (r.floor() as usize).min(SIDE - 2));
    let (fx, fy) = (c - c0 as f64, r - r0 as f64);
    let v = |c: usize, r: usize| f64::from(h[r * SIDE + c]);
    (v(c0, r0) * (1.0 - fx) + v(c0 + 1, r0) * fx) * (1.0 - fy)
        + (v(c0, r0 + 1) * (1.0 - fx) + v(c0 + 1, r0 + 1) * fx) * fy
}

fn post_json(addr: std::net::SocketAddr, path: &str, points: &[[f64; 2]]) -> Value {
    let body = serde_json::to_vec(points).unwrap();
    let (s, _, b) = request(addr, "POST", path, &[("Content-Type", "application/json")], &body);
    assert_eq!(s, 200, "{path}: {}", String::from_utf8_lossy(&b));
    let v = serde_json::from_slice(&b);
    assert!(v.is_ok(), "{path}: {:?}: {}", v.as_ref().err(), String::from_utf8_lossy(&b));
    v.unwrap()
}

/// (height, error, nodata) of every answer.
fn answers(v: &Value) -> Vec<(Option<f64>, Option<f64>, bool)> {
    v["heights"]
        .as_array()
        .unwrap()
        .iter()
        .map(|a| (a["h"].as_f64(), a["error"].as_f64(), a["nodata"].as_bool().unwrap()))
        .collect()
}

fn problem(addr: std::net::SocketAddr, method: &str, path: &str, ctype: &str, body: &[u8]) -> (u16, String) {
    let (s, h, b) = request(addr, method, path, &[("Content-Type", ctype)], body);
    assert_eq!(h.get("content-type").map(String::as_str), Some("application/problem+json"), "{path}");
    let v: Value = serde_json::from_slice(&b).unwrap();
    (s, v["detail"].as_str().unwrap().to_owned())
}

#[test]
fn heights_from_the_source_and_the_mesh_agree_with_the_raster() {
    let tmp = tempfile::tempdir().unwrap();
    let (src, h) = hgt(tmp.path());
    let store = tmp.path().join("store");
    bake_mesh(&src, &store.join("baked"));
    ok(bin().arg("pack").arg(store.join("baked")).arg("--out").arg(store.join("packed.tsa")));
    let server = serve_store(&store, &[on_demand(&src)]);
    let a = server.addr;
    // Points: pseudo-random inside the tile, every 7th on a raster sample, one outside.
    let mut pts: Vec<[f64; 2]> = (0..200u32)
        .map(|k| {
            let t = f64::from(k);
            let (u, v) = ((t * 0.618_033_988_75).fract(), (t * 0.754_877_666_2).fract());
            if k % 7 == 0 {
                let (c, r) = ((u * 1200.0).round(), (v * 1200.0).round());
                [10.0 + c / 1200.0, 47.0 - r / 1200.0]
            } else {
                [10.0 + u, 46.0 + v]
            }
        })
        .collect();
    pts.push([20.0, 46.5]);
    pts.push([10.5, 46.5]);

    // surface=source: the raster's bilinear height, on the geoid as stored.
    let native = answers(&post_json(a, "/tilesets/od/heights?surface=source&datum=native", &pts));
    let geoid = answers(&post_json(a, "/tilesets/od/heights?surface=source&datum=geoid", &pts));
    let ell = answers(&post_json(a, "/tilesets/od/heights?surface=source", &pts));
    for (k, p) in pts.iter().enumerate() {
        if p[0] > 11.0 {
            assert_eq!(native[k], (None, None, true), "outside the data: {p:?}");
            continue;
        }
        let want = bilinear(&h, p[0], p[1]);
        let (got, err, nodata) = native[k];
        assert!(!nodata);
        assert!((got.unwrap() - want).abs() < 1e-6, "{p:?}: {got:?} vs {want}");
        assert!(err.unwrap() >= 0.0);
        assert!((geoid[k].0.unwrap() - want).abs() < 1e-6, "an EGM96 source on the geoid is as stored");
    }
    // EGM96 at 10.5° E, 46.5° N: 50.392 m (bilinear in PROJ's egm96_15.gtx).
    let last = pts.len() - 1;
    assert!((ell[last].0.unwrap() - native[last].0.unwrap() - 50.392).abs() < 0.01, "{:?}", ell[last]);

    // surface=mesh: within the stated error of the raster at its samples; the same from the
    // archive; the binary form carries the same numbers.
    let mesh = answers(&post_json(a, "/tilesets/baked/heights?datum=native", &pts));
    let packed = answers(&post_json(a, "/tilesets/packed/heights?datum=native", &pts));
    assert_eq!(mesh, packed, "folder and archive answer alike");
    let mut on_samples = 0;
    for (k, p) in pts.iter().enumerate() {
        let (got, err, nodata) = mesh[k];
        if p[0] > 11.0 {
            assert!(nodata);
            continue;
        }
        let (got, err) = (got.unwrap(), err.unwrap());
        assert!(err > 0.0 && err < 100.0, "{p:?}: error {err}");
        if k % 7 == 0 && k < 200 {
            let want = bilinear(&h, p[0], p[1]);
            assert!((got - want).abs() <= err + 1e-3, "{p:?}: mesh {got} vs raster {want}, error {err}");
            on_samples += 1;
        }
    }
    assert!(on_samples > 20);
    let bin_body: Vec<u8> = pts.iter().flat_map(|p| p.iter().flat_map(|v| v.to_le_bytes())).collect();
    let (s, hd, b) = request(
        a,
        "POST",
        "/tilesets/baked/heights?datum=native",
        &[("Content-Type", "application/octet-stream"), ("Accept", "application/octet-stream")],
        &bin_body,
    );
    assert_eq!(s, 200);
    assert_eq!(hd["content-type"], "application/octet-stream");
    assert_eq!(b.len(), pts.len() * 16);
    for (k, c) in b.chunks_exact(16).enumerate() {
        let hv = f64::from_le_bytes(c[..8].try_into().unwrap());
        let flags = u32::from_le_bytes(c[12..16].try_into().unwrap());
        match mesh[k].0 {
            Some(v) => assert!(hv == v && flags == 0, "point {k}: {hv} vs {v}"),
            None => assert!(hv.is_nan() && flags == 1, "point {k}"),
        }
    }
    // GET for a few points; the same as POST.
    let (s, _, b) =
        request(a, "GET", "/tilesets/baked/heights?datum=native&points=10.5,46.5;20,46.5", &[], &[]);
    assert_eq!(s, 200);
    let v: Value = serde_json::from_slice(&b).unwrap();
    assert_eq!(answers(&v), vec![mesh[last], mesh[last - 1]]);
}

#[test]
fn bad_points_bodies_and_options_are_refused_clearly() {
    let tmp = tempfile::tempdir().unwrap();
    let (src, _) = hgt(tmp.path());
    let store = tmp.path().join("store");
    bake_mesh(&src, &store.join("t"));
    // A model tileset: heights do not apply.
    let obj = tmp.path().join("quad.obj");
    std::fs::write(&obj, "v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0.5\nf 1 2 3\nf 1 3 4\n").unwrap();
    ok(bin().args(["bake-model", "--gpu", "off", "-q", "--out"]).arg(store.join("mdl")).arg(&obj));
    let server = serve_store(&store, &[]);
    let a = server.addr;
    let url = "/tilesets/t/heights";
    let json = "application/json";
    for (path, ctype, body, status, says) in [
        (url, json, b"[[10.5, 46.5], [10.5, 91]]".to_vec(), 400, "point 1: latitude 91"),
        (url, json, b"[[10.5, 46.5], [361, 0]]".to_vec(), 400, "point 1: longitude 361"),
        (url, json, b"[[10.5, null]]".to_vec(), 400, "JSON body"),
        (url, json, b"{\"points\": [[1, 2]], \"datum\": \"x\"}".to_vec(), 400, "unknown field"),
        (url, "text/plain", b"10.5 46.5".to_vec(), 415, "Content-Type"),
        (url, "application/octet-stream", vec![0u8; 17], 400, "16 bytes each"),
        (
            url,
            "application/octet-stream",
            [f64::NAN.to_le_bytes(), 1f64.to_le_bytes()].concat(),
            400,
            "point 0: coordinate NaN",
        ),
        ("/tilesets/t/heights?datum=sea", json, b"[]".to_vec(), 400, "datum=\"sea\""),
        ("/tilesets/t/heights?frame=x", json, b"[]".to_vec(), 400, "unknown query parameter"),
        ("/tilesets/t/heights?surface=source", json, b"[[10.5, 46.5]]".to_vec(), 409, "--source"),
        ("/tilesets/t/heights?depth=30", json, b"[[10.5, 46.5]]".to_vec(), 404, "depth"),
        ("/tilesets/nope/heights", json, b"[]".to_vec(), 404, "no tileset"),
        (
            "/tilesets/mdl/heights?coords=local&datum=native",
            json,
            b"[[0.5, 0.5]]".to_vec(),
            409,
            "not a terrain",
        ),
    ] {
        let (s, detail) = problem(a, "POST", path, ctype, &body);
        assert_eq!(s, status, "{path} {:?}: {detail}", String::from_utf8_lossy(&body));
        assert!(detail.contains(says), "{path}: {detail:?} should say {says:?}");
    }
    let many: Vec<String> = (0..1001).map(|_| "10.5,46.5".to_owned()).collect();
    let (s, detail) = problem(a, "GET", &format!("{url}?points={}", many.join(";")), json, &[]);
    assert_eq!(s, 413, "{detail}");
    let (s, detail) = problem(a, "GET", &format!("{url}?points=10.5"), json, &[]);
    assert!(s == 400 && detail.contains("point 0"), "{detail}");
    // An empty batch is an empty answer.
    let v = post_json(a, url, &[]);
    assert_eq!(v["count"], 0);
    assert!(v["heights"].as_array().unwrap().is_empty());
}

/// A PNG tile's heights in `enc`, row-major from the north-west.
fn png_heights(bytes: &[u8], enc: terrastream::formats::heightmap::Encoding) -> Vec<f64> {
    let img = image::load_from_memory(bytes).unwrap().to_rgb8();
    assert_eq!(img.dimensions(), (256, 256));
    img.pixels().map(|p| enc.height(p.0)).collect()
}

#[test]
fn heightmap_tiles_carry_the_source_heights_in_web_mercator() {
    use terrastream::formats::heightmap::{Encoding, Xyz, tile_range};
    let tmp = tempfile::tempdir().unwrap();
    let (src, h) = hgt(tmp.path());
    let store = tmp.path().join("store");
    bake_mesh(&src, &store.join("baked"));
    let server = serve_store(&store, &[on_demand(&src)]);
    let a = server.addr;
    let (s, _, b) = request(a, "GET", "/tilesets/od/heightmap/tiles.json", &[], &[]);
    assert_eq!(s, 200, "{}", String::from_utf8_lossy(&b));
    let tj: Value = serde_json::from_slice(&b).unwrap();
    // 3″ cells are ≈ 64 m east–west at 46.5° N: zoom 11's pixels (≈ 53 m) are the first finer.
    assert_eq!(tj["maxzoom"], 11, "{tj}");
    assert_eq!(tj["encoding"], "terrarium");
    let bounds: Vec<f64> = tj["bounds"].as_array().unwrap().iter().map(|v| v.as_f64().unwrap()).collect();
    assert!((bounds[0] - 10.0).abs() < 0.02 && (bounds[3] - 47.0).abs() < 0.02, "{bounds:?}");
    assert!(
        tj["tiles"][0]
            .as_str()
            .unwrap()
            .contains("/tilesets/od/heightmap/{z}/{x}/{y}.png?encoding=terrarium")
    );

    // A zoom-10 tile inside the data: each pixel is the raster's bilinear height at its centre
    // (an EGM96 source: on the geoid as stored) within the encoding's rounding.
    let (x, _, y, _) = tile_range(10, 10.5, 46.5, 10.5, 46.5).unwrap();
    let t = Xyz::new(10, x, y).unwrap();
    for (enc, name) in [(Encoding::Terrarium, "terrarium"), (Encoding::TerrainRgb, "terrain-rgb")] {
        let url = format!("/tilesets/od/heightmap/10/{x}/{y}.png?encoding={name}&surface=source");
        let (s, hd, b) = request(a, "GET", &url, &[], &[]);
        assert_eq!(s, 200, "{url}: {}", String::from_utf8_lossy(&b));
        assert_eq!(hd["content-type"], "image/png");
        let got = png_heights(&b, enc);
        let mut checked = 0;
        for j in (0..256).step_by(5) {
            for i in (0..256).step_by(5) {
                let (lon, lat) = t.pixel_lonlat(i, j);
                if !(10.0..=11.0).contains(&lon) || !(46.0..=47.0).contains(&lat) {
                    continue;
                }
                let want = bilinear(&h, lon, lat);
                let g = got[(j * 256 + i) as usize];
                assert!((g - want).abs() <= enc.step() / 2.0 + 1e-3, "{url} pixel ({i}, {j}): {g} vs {want}");
                checked += 1;
            }
        }
        assert!(checked > 1000, "{checked}");
    }
    // The float32 form of the default (mesh) surface, and its PNG, agree; both are within the
    // TIN's error of the source.
    let (s, _, f) = request(a, "GET", &format!("/tilesets/baked/heightmap/10/{x}/{y}.f32"), &[], &[]);
    assert_eq!((s, f.len()), (200, 256 * 256 * 4));
    let (_, _, p) = request(a, "GET", &format!("/tilesets/baked/heightmap/10/{x}/{y}.png"), &[], &[]);
    let png = png_heights(&p, Encoding::Terrarium);
    let (lon, lat) = t.pixel_lonlat(128, 128);
    let probe = post_json(a, "/tilesets/baked/heights?datum=geoid", &[[lon, lat]]);
    let err = probe["heights"][0]["error"].as_f64().unwrap();
    for (k, c) in f.chunks_exact(4).enumerate() {
        let v = f64::from(f32::from_le_bytes(c.try_into().unwrap()));
        if v.is_nan() {
            continue;
        }
        assert!((v - png[k]).abs() <= 1.0 / 512.0 + 1e-3, "pixel {k}: f32 {v} vs png {}", png[k]);
    }
    let mid = f32::from_le_bytes(f[(128 * 256 + 128) * 4..][..4].try_into().unwrap());
    assert!(
        (f64::from(mid) - bilinear(&h, lon, lat)).abs() <= err.max(1.0) * 4.0,
        "{mid} (coarser TIN than the finest)"
    );

    // Baked through export: the same bytes as served, and a TileJSON over them.
    let out = tmp.path().join("hm");
    ok(bin()
        .arg("export")
        .arg(store.join("baked"))
        .args(["--format", "heightmap", "--zooms", "9:10", "-q", "--out"])
        .arg(&out));
    assert_eq!(std::fs::read(out.join(format!("10/{x}/{y}.png"))).unwrap(), p, "exported = served");
    let tj: Value = serde_json::from_slice(&std::fs::read(out.join("tiles.json")).unwrap()).unwrap();
    assert_eq!((tj["minzoom"].as_u64(), tj["maxzoom"].as_u64()), (Some(9), Some(10)));
    assert!(out.join(format!("9/{}/{}.png", x / 2, y / 2)).is_file());

    // Outside the data, off the grid, bad options.
    assert_eq!(request(a, "GET", "/tilesets/od/heightmap/10/0/0.png", &[], &[]).0, 404);
    assert_eq!(request(a, "GET", "/tilesets/od/heightmap/23/0/0.png", &[], &[]).0, 404);
    assert_eq!(request(a, "GET", "/tilesets/od/heightmap/1/2/0.png", &[], &[]).0, 404);
    assert_eq!(request(a, "GET", &format!("/tilesets/od/heightmap/10/{x}/{y}.jpg"), &[], &[]).0, 404);
    let (s, _, b) = request(a, "GET", &format!("/tilesets/od/heightmap/10/{x}/{y}.png?encoding=x"), &[], &[]);
    assert!(s == 400 && String::from_utf8_lossy(&b).contains("terrarium"));
}

#[test]
fn the_mesh_surface_is_the_decoded_level_0_tin() {
    // A raster without a CRS (flat world frame): the mesh surface is exactly the TIN's planar
    // triangles, checked against the finest nodes' blobs decoded here.
    let tmp = tempfile::tempdir().unwrap();
    let tif = tmp.path().join("t.tif");
    ok(bin().args(["synth", "--width", "129", "--height", "97", "--seed", "3", "--out"]).arg(&tif));
    let store = tmp.path().join("store");
    ok(bin()
        .args(["bake", "--tile-size", "32", "--levels", "1", "--gpu", "off", "-q", "--out"])
        .arg(store.join("t"))
        .arg(&tif));
    let server = serve_store(&store, &[]);
    let m: Value = serde_json::from_slice(&std::fs::read(store.join("t/tileset.json")).unwrap()).unwrap();
    let depth = m["depth"].as_u64().unwrap();
    let mut pts = Vec::new();
    let mut want = Vec::new();
    let leaves = store.join(format!("t/tiles/{depth}"));
    for x in std::fs::read_dir(&leaves).unwrap() {
        for y in std::fs::read_dir(x.unwrap().path()).unwrap() {
            let blob = std::fs::read(y.unwrap().path().join("0.tsb")).unwrap();
            let b = terrastream::codec::decode(&blob).unwrap();
            let terrastream::codec::Geometry::Mesh(mesh) = b.geometry else { unreachable!() };
            for t in mesh.triangles.iter().step_by(7) {
                let p = t.map(|v| mesh.positions[v as usize]);
                // A vertex, and the centroid: the mean of the corners' heights.
                pts.push([p[0][0], p[0][1]]);
                want.push((p[0][2], b.header.errors.max));
                let c = [0, 1, 2].map(|k| (p[0][k] + p[1][k] + p[2][k]) / 3.0);
                pts.push([c[0], c[1]]);
                want.push((c[2], b.header.errors.max));
            }
        }
    }
    assert!(pts.len() > 100, "{} points", pts.len());
    let got = answers(&post_json(server.addr, "/tilesets/t/heights?coords=local&datum=native", &pts));
    for (k, ((h, err, nodata), (w, e))) in got.iter().zip(&want).enumerate() {
        assert!(!nodata, "point {k} {:?}", pts[k]);
        assert!((h.unwrap() - w).abs() < 1e-6, "point {k} {:?}: {h:?} vs the blob's {w}", pts[k]);
        // A vertex on a node border may be answered by the neighbour: its error, not this one's.
        assert!(err.unwrap() > 0.0 && (k % 2 == 0 || (err.unwrap() - e).abs() < 1e-12));
    }
}
