//! `terrastream demo`: a deterministic synthetic terrain, baked once into a local store and
//! served. The terrain is generated (not shipped), so the demo works on a fresh checkout with
//! nothing but the crate: `synth::terrain` → GeoTIFF → the normal load and bake path.

use std::path::{Path, PathBuf};

use crate::bake::{BakeOptions, Progress};
use crate::lod::PointBaker;
use crate::store::Store;

/// Samples per side of the demo terrain.
pub const DEMO_SIDE: u32 = 1025;
/// Seed of the demo terrain.
pub const DEMO_SEED: u64 = 1;
/// Cell size of the demo terrain, metres.
pub const DEMO_CELL: f64 = 10.0;
/// Name of the demo tileset.
pub const DEMO_TILESET: &str = "demo";
/// Bake options of the demo: 4×4 leaf tiles of 256 cells, 3 point levels.
pub const DEMO_OPTIONS: BakeOptions =
    BakeOptions { tile_size: 256, max_error: 2.0, levels: 3, point_levels: crate::bake::PointLevels::Auto };

/// Generates the demo raster into `work` and bakes it into `store/demo` unless a complete bake
/// is there already (an interrupted one resumes). Returns the store directory to serve and
/// whether a bake ran. `baker` computes the point levels.
pub fn prepare(
    work: &Path,
    baker: &PointBaker,
    progress: &dyn Progress,
) -> Result<(PathBuf, bool), super::SourceError> {
    let store_dir = work.join("demo-store");
    let store = Store::new(&store_dir.join(DEMO_TILESET));
    if store.manifest().is_ok() {
        return Ok((store_dir, false));
    }
    std::fs::create_dir_all(&store_dir)
        .map_err(|source| crate::store::StoreError::Io { path: store_dir.clone(), source })?;
    let tif = work.join("demo-terrain.tif");
    let heights = crate::raster::synth::terrain(DEMO_SIDE, DEMO_SIDE, DEMO_SEED);
    let bytes = crate::raster::geotiff::encode_f32(
        DEMO_SIDE,
        DEMO_SIDE,
        &heights,
        (0.0, 0.0),
        (DEMO_CELL, -DEMO_CELL),
    )
    .map_err(|e| crate::store::StoreError::Invalid {
        path: tif.clone(),
        message: format!("encoding GeoTIFF: {e}"),
    })?;
    crate::store::write_atomic(&tif, &bytes)?;
    let raster = crate::raster::load(&tif, &crate::raster::LoadOptions::default())?;
    crate::bake::bake_terrain(&raster, "demo-terrain.tif", &DEMO_OPTIONS, baker, &store, progress)?;
    Ok((store_dir, true))
}
