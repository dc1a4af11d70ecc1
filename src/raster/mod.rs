//! Heightfield rasters: decoding (`OpenEXR`, 16-bit PNG, terrain-RGB/Terrarium PNG, `GeoTIFF`, SRTM
//! HGT), georeference, size limits and no-data filling. Reads files only.
//!
//! CONTRACT STUB: the helper replaces the bodies; signatures are what the rest of the crate uses.

use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};

/// Default limit on either side of a raster, in samples.
pub const DEFAULT_MAX_SIDE: u32 = 65_536;
/// Default limit on the decoded size (f32 samples), in bytes: 4 GiB.
pub const DEFAULT_MAX_BYTES: u64 = 4 << 30;

/// A decoded heightfield: `width × height` world heights (metres, z scale/offset applied),
/// row-major, row 0 first as stored in the file. Never contains NaN after `load`.
#[derive(Debug, Clone, PartialEq)]
pub struct Heightfield {
    pub width: u32,
    pub height: u32,
    pub data: Vec<f32>,
}

impl Heightfield {
    #[must_use]
    pub fn get(&self, col: u32, row: u32) -> f32 {
        self.data[row as usize * self.width as usize + col as usize]
    }
}

/// Reads samples of a raster by column/row lists, so a chunked reader for rasters larger than
/// memory can replace the in-memory one without touching later stages.
pub trait WindowReader: Sync {
    /// (width, height) in samples.
    fn size(&self) -> (u32, u32);
    /// Fills `out` (cleared first) with the samples at every (col, row) of `cols × rows`,
    /// row-major over `rows`.
    fn read_window(&self, cols: &[u32], rows: &[u32], out: &mut Vec<f32>);
}

impl WindowReader for Heightfield {
    fn size(&self) -> (u32, u32) {
        (self.width, self.height)
    }
    fn read_window(&self, cols: &[u32], rows: &[u32], out: &mut Vec<f32>) {
        out.clear();
        out.reserve(cols.len() * rows.len());
        for &r in rows {
            let base = r as usize * self.width as usize;
            out.extend(cols.iter().map(|&c| self.data[base + c as usize]));
        }
    }
}

/// How a geographic (degree) raster was mapped to the local metric frame.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct GeographicMapping {
    /// Longitude/latitude (degrees) of sample (0, 0).
    pub lon0: f64,
    pub lat0: f64,
    /// Degrees per column / per row (row step is negative for north-up rasters).
    pub dlon: f64,
    pub dlat: f64,
    /// Metres per degree used for the mapping (at the raster's central latitude).
    pub metres_per_deg_lon: f64,
    pub metres_per_deg_lat: f64,
}

/// World frame: `x = x0 + col·dx`, `y = y0 + row·dy`, `z = z0 + value·dz` (z already applied to
/// `Heightfield::data`, recorded for the manifest).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Georef {
    pub x0: f64,
    pub y0: f64,
    pub dx: f64,
    pub dy: f64,
    pub z0: f64,
    pub dz: f64,
    /// Present when the source was in degrees.
    pub geographic: Option<GeographicMapping>,
}

/// How a PNG's channels encode height.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub enum Encoding {
    /// 16-bit grayscale, value = sample.
    Gray16,
    /// Mapbox terrain-RGB: −10000 + (R·65536 + G·256 + B)·0.1.
    TerrainRgb,
    /// Terrarium: R·256 + G + B/256 − 32768.
    Terrarium,
}

/// Size limits checked before any large allocation.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Limits {
    pub max_side: u32,
    pub max_bytes: u64,
}

impl Default for Limits {
    fn default() -> Self {
        Self { max_side: DEFAULT_MAX_SIDE, max_bytes: DEFAULT_MAX_BYTES }
    }
}

/// User overrides of the file's georeference.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct Overrides {
    pub cell_size: Option<f64>,
    pub origin: Option<(f64, f64)>,
    pub z_scale: Option<f64>,
    pub z_offset: Option<f64>,
}

#[derive(Debug, Clone, Default)]
pub struct LoadOptions {
    /// PNG encoding; `None` = gray16 for 16-bit gray PNGs, error for RGB PNGs without it.
    pub encoding: Option<Encoding>,
    /// `OpenEXR` channel name; `None` = first float channel.
    pub channel: Option<String>,
    pub limits: Limits,
    pub overrides: Overrides,
}

/// A loaded, validated, no-data-filled raster.
#[derive(Debug, Clone)]
pub struct LoadedRaster {
    pub heights: Heightfield,
    pub georef: Georef,
    /// Samples that were no-data and filled from neighbours.
    pub nodata_filled: u64,
    /// Short format name, e.g. "png-terrain-rgb", "geotiff", "exr", "hgt".
    pub format: String,
}

#[derive(Debug, thiserror::Error)]
pub enum RasterError {
    #[error("{path}: {message}")]
    Invalid { path: PathBuf, message: String },
}

/// Loads, validates and fills a raster file.
pub fn load(path: &Path, _opts: &LoadOptions) -> Result<LoadedRaster, RasterError> {
    Err(RasterError::Invalid { path: path.to_owned(), message: "not implemented yet".into() })
}
