//! Inputs the `cargo fuzz` targets in `fuzz/` found breaking a decoder, kept as ordinary tests
//! so they run in plain `cargo test` (stable, no fuzzer). Each test names the target that found
//! it and what went wrong; the inputs are minimised (`cargo fuzz tmin`) and live under
//! `tests/fuzz-cases/` or inline. The checks are the fuzz targets' invariants (`fuzz/src/lib.rs`).

use std::path::Path;

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
    let (h, g) = (&r.heights, r.georef);
    assert_eq!(h.width as usize * h.height as usize, h.data.len());
    assert!(h.data.iter().all(|v| v.is_finite()));
    for v in [g.x0, g.y0, g.dx, g.dy, g.z0, g.dz] {
        assert!(v.is_finite(), "{g:?}");
    }
    let far = (g.x0 + g.dx * f64::from(h.width - 1), g.y0 + g.dy * f64::from(h.height - 1));
    assert!(far.0.is_finite() && far.1.is_finite(), "far corner {far:?} of {g:?}");
    Ok(r)
}

/// `raster_geotiff`: a ModelPixelScale of about −1.6e308 with a finite tiepoint gave a finite
/// origin and cell size (so `load` accepted it) but a far corner at −inf, and every later stage
/// would have worked on infinities. Fixed in `raster::geotiff::check_extent`.
#[test]
fn geotiff_far_corner_overflow_is_a_georef_error() {
    let e = load_raster("fuzz.tif", &case("geotiff-far-corner-overflow.tif")).unwrap_err();
    assert!(matches!(e, RasterError::BadGeoref { .. }), "{e}");
}
