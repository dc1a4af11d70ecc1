//! Inputs the `cargo fuzz` targets in `fuzz/` found breaking a decoder, kept as ordinary tests
//! so they run in plain `cargo test` (stable, no fuzzer). Each test names the target that found
//! it and what went wrong; the inputs are minimised (`cargo fuzz tmin`) and live under
//! `tests/fuzz-cases/` or inline. The checks are the fuzz targets' invariants (`fuzz/src/lib.rs`).
//! A case left `#[ignore]`d shows a known, documented defect that is not fixed yet.

// Helpers outside `#[test]` functions unwrap and panic too: a failure there is a test failure.
#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic, clippy::float_cmp)]

use std::path::Path;

use terrastream::bake::PointLevels;
use terrastream::raster::{self, Limits, LoadOptions, RasterError};

/// The limits the raster fuzz targets run with.
const LIMITS: Limits = Limits { max_side: 4096, max_bytes: 16 << 20 };

fn case(name: &str) -> Vec<u8> {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/fuzz-cases").join(name);
    std::fs::read(&path).unwrap_or_else(|e| panic!("{}: {e}", path.display()))
}

/// Decodes a raster as the fuzz targets do and checks their invariants on `Ok`.
fn load_raster(name: &str, bytes: &[u8]) -> Result<raster::LoadedRaster, RasterError> {
    let opts = LoadOptions { limits: LIMITS, ..LoadOptions::default() };
    let r = raster::load_bytes(Path::new(name), bytes, &opts)?;
    let (h, g) = (&r.heights, &r.georef);
    assert_eq!(h.width as usize * h.height as usize, h.data.len());
    assert!(h.data.iter().all(|v| v.is_finite()));
    for v in [g.x0, g.y0, g.dx, g.dy, g.z0, g.dz] {
        assert!(v.is_finite(), "{g:?}");
    }
    let far = (g.x0 + g.dx * f64::from(h.width - 1), g.y0 + g.dy * f64::from(h.height - 1));
    assert!(far.0.is_finite() && far.1.is_finite(), "far corner {far:?} of {g:?}");
    Ok(r)
}

/// `raster_png_terrarium` and `raster_png_terrain_rgb`: a `PLTE` chunk whose length is not a
/// multiple of 3 (14 bytes here; 4 in the second) made the `png` crate (0.18.1,
/// `decoder/transform/palette.rs`) index past the palette and panic — in release builds too,
/// so one hostile upload would have panicked a bake. Refused before decoding by
/// `raster::png::check_chunks` (PNG §11.2.3: 1 to 256 entries of 3 bytes).
#[test]
fn png_palette_with_a_partial_entry_is_corrupt() {
    use terrastream::raster::HeightEncoding;
    for (file, encoding) in [
        ("png-plte-14-bytes.png", HeightEncoding::Terrarium),
        ("png-plte-partial-terrain-rgb.png", HeightEncoding::TerrainRgb),
    ] {
        let opts = LoadOptions { limits: LIMITS, encoding: Some(encoding), ..LoadOptions::default() };
        let e = raster::load_bytes(Path::new(file), &case(file), &opts).unwrap_err();
        assert!(matches!(e, RasterError::Corrupt { .. }), "{file}: {e}");
        assert!(e.to_string().contains("PLTE chunk of"), "{file}: {e}");
    }
}

/// `raster_openexr`: a B44-compressed block whose 14-byte header makes exr's `unpack14`
/// (exr 1.74.2, `compression/b44/mod.rs:186`) subtract past zero in `u32`. Two defects: in an
/// overflow-checked build it panicked, and it panicked on exr's rayon pool — where a panic
/// aborts the whole process (a server with it), and where it surfaced during a later input. Now
/// the decoder runs on the calling thread under `raster::guard_decoder`, and exr is built as
/// release builds it (its B44 arithmetic wraps, as OpenEXR's C code does): the file decodes or
/// is refused, without a panic.
#[test]
fn exr_b44_block_underflow_neither_panics_nor_aborts() {
    match load_raster("fuzz.exr", &case("exr-b44-overflow.exr")) {
        Ok(r) => assert!(r.heights.width > 0 && r.heights.height > 0),
        Err(e) => assert!(
            matches!(
                e,
                RasterError::Corrupt { .. } | RasterError::Unsupported { .. } | RasterError::AllNoData { .. }
            ),
            "{e}"
        ),
    }
}

/// `raster_geotiff`: a ModelPixelScale of about −1.6e308 with a finite tiepoint gave a finite
/// origin and cell size (so `load` accepted it) but a far corner at −inf, and every later stage
/// would have worked on infinities. Fixed in `raster::geotiff::check_extent`.
#[test]
fn geotiff_far_corner_overflow_is_a_georef_error() {
    let e = load_raster("fuzz.tif", &case("geotiff-far-corner-overflow.tif")).unwrap_err();
    assert!(matches!(e, RasterError::BadGeoref { .. }), "{e}");
}

/// `codec_blob` / `codec_roundtrip` bounds check (defect D1, being fixed on main): with
/// `(max − min) / step` rounding up, the largest grid index lies beyond `max`, so a position
/// the encoder accepts (here x = max = 1.0, index round(1 / 0.6) = 2) decodes to 1.2, outside
/// the header bounds the format lets clients cull by.
#[test]
fn decoded_positions_stay_inside_the_header_bounds() {
    use terrastream::codec::{self, Geometry, Quantization};
    use terrastream::geom::{Bounds, ErrorFigures, Mesh};
    use terrastream::tiling::TileKey;

    let bounds = Bounds::new([0.0; 3], [1.0; 3]);
    let q = Quantization { xy_step: 0.6, z_step: 0.6 };
    let mesh = Mesh {
        positions: vec![[0.0, 0.0, 0.0], [1.0, 0.0, 0.5], [0.0, 1.0, 1.0]],
        triangles: vec![[0, 1, 2]],
    };
    let errors = ErrorFigures { max: 0.0, rms: 0.0, gap: 0.0 };
    let blob = codec::encode_mesh(TileKey { z: 0, x: 0, y: 0 }, 0, &bounds, q, &mesh, errors).unwrap();
    // The header states the bounds grown to the rounded-up position (1.2), and every decoded
    // position lies inside what it states.
    let blob = codec::decode(&blob).unwrap();
    let b = blob.header.bounds();
    assert_eq!(b.max.to_array(), [1.2, 1.2, 1.2]);
    let Geometry::Mesh(m) = blob.geometry else { panic!("not a mesh") };
    for p in &m.positions {
        assert!((0..3).all(|a| b.min[a] <= p[a] && p[a] <= b.max[a]), "{p:?} outside {b:?}");
    }
}

/// `http_router`: a store whose manifest states depth 255 (any depth ≥ 64) and a request for a
/// tile or index chunk at z ≥ 64: `parse_key` (src/server/http.rs:390) computes `1u64 << z`,
/// which overflows — a panic with overflow checks (`cargo test`, debug builds), a wrong range
/// check in release. The fuzz target found it with
/// `GET /tilesets/deep/tiles/64/…`; a manifest's depth is not checked against 63 anywhere.
#[test]
#[cfg(feature = "server")]
fn tile_key_at_z_64_is_a_client_error() {
    use terrastream::bake::{BakeOptions, NoProgress};
    use terrastream::raster::{Georef, Heightfield, LoadedRaster};
    use terrastream::server::{Config, Server};
    use terrastream::store::Store;
    use tower::ServiceExt;

    let dir = tempfile::tempdir().unwrap();
    let raster = LoadedRaster {
        heights: Heightfield { width: 17, height: 17, data: terrastream::raster::synth::terrain(17, 17, 1) },
        georef: Georef::default(),
        nodata_filled: 0,
        nodata_fallback: 0,
        format: "synthetic".into(),
    };
    let opts = BakeOptions { tile_size: 16, max_error: 1.0, levels: 1, point_levels: PointLevels::Auto };
    let store = dir.path().join("deep");
    terrastream::bake::bake_terrain(
        &raster,
        "s",
        &opts,
        &terrastream::lod::PointBaker::Cpu,
        &Store::new(&store),
        &NoProgress,
    )
    .unwrap();
    let manifest = store.join("tileset.json");
    let mut m: serde_json::Value = serde_json::from_slice(&std::fs::read(&manifest).unwrap()).unwrap();
    m["depth"] = 64.into();
    std::fs::write(&manifest, serde_json::to_vec(&m).unwrap()).unwrap();

    let mut config = Config::for_store(dir.path()).unwrap();
    config.bind = "127.0.0.1:0".parse().unwrap();
    config.gpu = terrastream::lod::GpuMode::Off;
    let rt = tokio::runtime::Builder::new_current_thread().enable_all().build().unwrap();
    rt.block_on(async {
        let server = Server::bind(config).await.unwrap();
        for path in ["/tilesets/deep/tiles/64/0/0/0", "/tilesets/deep/index/64/0/0.json"] {
            let req = axum::extract::Request::get(path).body(axum::body::Body::empty()).unwrap();
            let status = server.service().oneshot(req).await.unwrap().status();
            assert!(status.is_client_error(), "{path}: {status}");
        }
    });
}

/// `codec_blob`: a point blob whose normal bytes lie on the octahedral map's lower seam
/// (`|v| = 1`, e.g. the pair (100, 0)) decoded to a normal that re-encodes to the mirrored pair
/// (154, 0): the same direction, but decoded as a vector differing in the sign of a zero and
/// about an ulp ([-0.0, 0.9924124, -0.12295376] against [0.0, 0.9924124, -0.12295368] in the
/// fuzz case), so decode → encode → decode was not bit-exact. `codec::oct_decode` now decodes
/// such a pair as the pair its direction encodes to.
#[test]
fn decoded_normals_are_a_fixed_point_of_quantization() {
    use terrastream::codec::{oct_decode, oct_encode};
    for u in 0..=254_u8 {
        for v in 0..=254_u8 {
            let n = oct_decode([u, v]);
            let again = oct_encode(n).map(oct_decode).unwrap();
            assert!(n.map(f32::to_bits) == again.map(f32::to_bits), "({u}, {v}): {n:?} then {again:?}");
        }
    }
}

/// The same defect D1 as `codec_blob` found it: `tests/fuzz-cases/codec-blob-d1-overshoot.tsb`
/// (278 bytes, the fuzzer's artifact with its checksums repaired as the target repairs them), a
/// mesh blob with bounds [-1, 1]³ whose vertex 0 decodes to x = 1.0000004842877388.
#[test]
fn fuzzed_blob_stays_inside_its_header_bounds() {
    // Such a blob is refused: no accepted blob has a position outside its header bounds.
    let e = terrastream::codec::decode(&case("codec-blob-d1-overshoot.tsb")).unwrap_err();
    assert!(matches!(e, terrastream::codec::CodecError::OutOfBounds { index: 0, .. }), "{e}");
}

/// `store_archive`: a tileset archive (`tests/fuzz-cases/archive-page-count-alloc.tsa`, 232
/// bytes, the fuzzer's artifact with its checksums and footer count repaired as the target
/// repairs them) whose root says its one 90-byte directory page holds 1,073,741,827 files. The
/// reader reserved room for that many entries before parsing the page (`Vec::with_capacity`,
/// 51.5 GB) and aborted the process on the first lookup — one hostile archive in a bucket would
/// have taken `serve` down. `Archive::open` now refuses a page whose count cannot fit its length
/// (at least 23 bytes a file), naming the root entry.
#[test]
fn archive_page_counting_more_files_than_fit_is_refused_on_open() {
    use terrastream::store::archive::{Archive, FileSource};
    let bytes = case("archive-page-count-alloc.tsa");
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("hostile.tsa");
    std::fs::write(&path, &bytes).unwrap();
    let file = std::fs::File::open(&path).unwrap();
    let e = Archive::open(Box::new(FileSource(file)), bytes.len() as u64).unwrap_err();
    assert!(e.to_string().contains("entry 0 counts 1073741827 files in a page of 90 bytes"), "{e}");
}
