//! Heightfield rasters: decoding (`OpenEXR`, 16-bit PNG, terrain-RGB/Terrarium PNG, `GeoTIFF`, SRTM
//! HGT), georeference, size limits and no-data filling. Reads files only.
//!
//! [`load`] detects the format (magic bytes first, `.hgt` by extension), lets the format's
//! decoder check the declared size against [`Limits`] before anything large is allocated, fills
//! no-data samples from their neighbours ([`fill`]), maps geographic rasters to a local metric
//! frame, and applies the user's [`Overrides`]. Every failure is a [`RasterError`] whose message
//! starts with the file path.

pub mod dataset;
mod from_bytes;
pub mod geotiff;
mod hgt;
pub mod las;
mod nodata;
mod open_files;
mod openexr;
mod parts;
mod png;
pub mod synth;
pub mod vrt;
pub mod warp;

use std::fs::File;
use std::io::{BufReader, Read, Seek, SeekFrom};
use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};

use crate::crs::{Crs, CrsGrid, Frame, VerticalDatum};

#[doc(hidden)]
pub use from_bytes::{load_bytes, load_hgt_bytes_any_side};

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
    /// Errors: a reader backed by files reports what it could not read.
    fn read_window(&self, cols: &[u32], rows: &[u32], out: &mut Vec<f32>) -> Result<(), RasterError>;
    /// The lowest and highest height any window holds (no-data filled within them), where the
    /// reader knows them; `None` where it does not.
    fn height_range(&self) -> Option<(f32, f32)> {
        None
    }
}

impl WindowReader for Heightfield {
    fn size(&self) -> (u32, u32) {
        (self.width, self.height)
    }
    fn height_range(&self) -> Option<(f32, f32)> {
        let finite = self.data.iter().copied().filter(|v| v.is_finite());
        let (lo, hi) = finite.fold((f32::INFINITY, f32::NEG_INFINITY), |(a, b), v| (a.min(v), b.max(v)));
        (lo <= hi).then_some((lo, hi))
    }
    fn read_window(&self, cols: &[u32], rows: &[u32], out: &mut Vec<f32>) -> Result<(), RasterError> {
        out.clear();
        out.reserve(cols.len() * rows.len());
        for &r in rows {
            let base = r as usize * self.width as usize;
            out.extend(cols.iter().map(|&c| self.data[base + c as usize]));
        }
        Ok(())
    }
}

pub use crate::crs::metres_per_degree;

/// World frame: `x = x0 + col·dx`, `y = y0 + row·dy`, `z = z0 + value·dz` (z already applied to
/// `Heightfield::data`, recorded for the manifest), and where that grid lies on the Earth.
///
/// The world frame is metric: with a CRS, `dx`, `dy` are the cell's ground size in metres at the
/// centre of the data (degrees times metres per degree for a geographic CRS; the CRS's unit and
/// its projection's point scale for a projected one), `x0`, `y0` the first sample's CRS
/// coordinates in metres (0, 0 for a geographic CRS). Placement on the Earth never uses that
/// approximation: [`Georef::frame`] maps a world point back to its CRS coordinates exactly
/// (`crs`: the grid in the CRS) and converts those.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Georef {
    pub x0: f64,
    pub y0: f64,
    pub dx: f64,
    pub dy: f64,
    pub z0: f64,
    pub dz: f64,
    /// The grid in its coordinate reference system; `None` for a local frame (a raster without
    /// georeference, or a metric grid that names no CRS).
    #[serde(default)]
    pub crs: Option<CrsGrid>,
    /// What the heights are measured from.
    #[serde(default = "ellipsoid")]
    pub vertical: VerticalDatum,
    /// The geoid grid file of `vertical`, when it is not the embedded EGM96.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub geoid_grid: Option<PathBuf>,
    /// A warped dataset's measured resampling error (metres, [`warp`]): added to every tile's
    /// error. 0 when nothing was resampled.
    #[serde(default, skip_serializing_if = "is_zero")]
    pub resample_error: f64,
}

#[allow(clippy::trivially_copy_pass_by_ref)]
fn is_zero(v: &f64) -> bool {
    *v == 0.0
}

fn ellipsoid() -> VerticalDatum {
    VerticalDatum::Ellipsoid
}

impl Default for Georef {
    /// The frame of a raster without georeference: unit cells, origin at sample (0, 0).
    fn default() -> Self {
        Self {
            x0: 0.0,
            y0: 0.0,
            dx: 1.0,
            dy: 1.0,
            z0: 0.0,
            dz: 1.0,
            crs: None,
            vertical: VerticalDatum::Ellipsoid,
            geoid_grid: None,
            resample_error: 0.0,
        }
    }
}

/// Why a georeferenced frame cannot be placed on the Earth.
#[derive(Debug, thiserror::Error)]
pub enum FrameError {
    #[error(transparent)]
    Geoid(#[from] crate::crs::GeoidError),
    #[error("heights on {0} need a geoid grid: give --geoid-grid FILE.gtx (PROJ's egm08_25.gtx for EGM2008)")]
    NoGrid(&'static str),
}

#[cfg(test)]
impl Georef {
    /// A test frame: the grid of EPSG `epsg` from `(e0, n0)` (metres), square cells of `d`
    /// going south, heights above EGM96; world coordinates are the CRS's own.
    pub(crate) fn projected_egm96(epsg: u32, e0: f64, n0: f64, d: f64) -> Self {
        let grid = CrsGrid { crs: Crs::from_epsg(epsg).expect("a known EPSG code"), e0, n0, de: d, dn: -d };
        Self {
            crs: Some(grid),
            vertical: VerticalDatum::Egm96,
            dx: d,
            dy: -d,
            x0: e0,
            y0: n0,
            ..Self::default()
        }
    }
}

impl Georef {
    /// The exact way from this world frame to the Earth; `None` for a local frame.
    pub fn frame(&self) -> Result<Option<Frame>, FrameError> {
        let Some(grid) = &self.crs else { return Ok(None) };
        let geoid = match (self.vertical, &self.geoid_grid) {
            (VerticalDatum::Ellipsoid, _) => None,
            (_, Some(path)) => Some(std::sync::Arc::new(crate::crs::Geoid::from_gtx(path)?)),
            (VerticalDatum::Egm96, None) => Some(crate::crs::Geoid::egm96()?),
            (v @ VerticalDatum::Egm2008, None) => return Err(FrameError::NoGrid(v.name())),
        };
        Ok(Some(Frame {
            x0: self.x0,
            y0: self.y0,
            dx: self.dx,
            dy: self.dy,
            grid: grid.clone(),
            vertical: self.vertical,
            geoid,
        }))
    }

    /// True when the frame lies on the Earth (it has a CRS).
    #[must_use]
    pub fn is_placed(&self) -> bool {
        self.crs.is_some()
    }
}

/// How a PNG's channels encode height.
#[cfg_attr(feature = "cli", derive(clap::ValueEnum))]
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub enum HeightEncoding {
    /// 16-bit grayscale, value = sample.
    Gray16,
    /// Mapbox terrain-RGB: −10000 + (R·65536 + G·256 + B)·0.1.
    TerrainRgb,
    /// Terrarium: R·256 + G + B/256 − 32768.
    Terrarium,
}

impl HeightEncoding {
    /// The name `--encoding` takes: `gray16`, `terrain-rgb`, `terrarium`.
    #[must_use]
    pub fn name(self) -> &'static str {
        match self {
            Self::Gray16 => "gray16",
            Self::TerrainRgb => "terrain-rgb",
            Self::Terrarium => "terrarium",
        }
    }
}

/// Smallest cell size accepted (world units, after the metric mapping of degree rasters).
pub const MIN_CELL_SIZE: f64 = 1e-6;
/// Largest cell size accepted: more than the Earth's circumference, so a global raster of a
/// few samples still loads.
pub const MAX_CELL_SIZE: f64 = 1e8;
/// Largest |x| or |y| of any sample (world units): 25 times the Earth's circumference in
/// metres, and small enough that f64 positions keep sub-micrometre steps.
pub const MAX_COORDINATE: f64 = 1e9;
/// Largest |height| after z scale and offset (world units): Earth's relief is ±11 km, and this
/// leaves room for heights in centimetres or millimetres.
pub const MAX_HEIGHT: f64 = 1e7;
/// Largest height range of a raster, in cells (of its smaller cell side): the point levels slice
/// tiles into cubic cells, so their work and quantized ranges grow with the relief in cells.
/// 2²⁰ cells is 31,000 km at 30 m cells and 10 km at 1 cm cells.
pub const MAX_RELIEF_CELLS: f64 = 1_048_576.0;

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

impl Limits {
    /// Budget for a decoder's own allocations: decoders hold up to 8 bytes per sample (RGBA16,
    /// f64) where we keep 4, plus room for their headers and scratch buffers.
    fn decoder_bytes(self) -> u64 {
        self.max_bytes.saturating_mul(2).saturating_add(64 << 20)
    }
}

/// User overrides of the file's georeference.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Overrides {
    /// Cell size of a raster without georeference (refused for one with a CRS).
    pub cell_size: Option<f64>,
    /// World position of sample (0, 0) of a raster without georeference (refused with a CRS).
    pub origin: Option<(f64, f64)>,
    pub z_scale: Option<f64>,
    pub z_offset: Option<f64>,
    /// `--crs`: the horizontal CRS of inputs that state none, or instead of what they state.
    pub crs: Option<Crs>,
    /// `--vertical-datum` (or the vertical part of `--crs EPSG:h+v`): instead of the input's.
    pub vertical: Option<VerticalDatum>,
    /// `--geoid-grid`: the geoid of `vertical` as a GTX file (else EGM96 is embedded).
    pub geoid_grid: Option<PathBuf>,
    /// `--target-crs`: warp the inputs onto a grid in this CRS (default: the first input's, when
    /// the inputs' CRSs differ).
    pub target_crs: Option<Crs>,
}

#[derive(Debug, Clone, Default)]
pub struct LoadOptions {
    /// PNG encoding; `None` = gray16 for 16-bit gray PNGs, error for RGB PNGs without it.
    pub encoding: Option<HeightEncoding>,
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
    /// Of those, the ones farther than the fill's reach, set from the fallback grid.
    pub nodata_fallback: u64,
    /// Short format name, e.g. "png-terrain-rgb", "geotiff", "exr", "hgt".
    pub format: String,
}

/// Everything that can go wrong loading a raster. Every message starts with the file path.
#[derive(Debug, thiserror::Error)]
pub enum RasterError {
    /// The file could not be opened or read.
    #[error("{}: cannot read file: {source}", path.display())]
    Io { path: PathBuf, source: std::io::Error },
    /// Neither the magic bytes nor the extension name a supported format.
    #[error(
        "{}: unrecognized raster format ({reason}); expected PNG, TIFF/GeoTIFF, OpenEXR, SRTM .hgt, GDAL VRT or LAS/LAZ",
        path.display()
    )]
    UnknownFormat { path: PathBuf, reason: String },
    /// The data is truncated or inconsistent.
    #[error("{}: corrupt or truncated {format} file: {message}", path.display())]
    Corrupt { path: PathBuf, format: &'static str, message: String },
    /// A valid file using a feature this loader does not handle (sample type, band count, ...).
    #[error("{}: unsupported {format} file: {message}", path.display())]
    Unsupported { path: PathBuf, format: &'static str, message: String },
    /// The raster declares a zero width or height.
    #[error("{}: raster has zero size ({width}×{height} samples)", path.display())]
    ZeroSize { path: PathBuf, width: u64, height: u64 },
    /// The declared size exceeds [`Limits`]; detected from the header, before decoding.
    #[error(
        "{}: raster of {width}×{height} samples exceeds the limits (at most {max_side} samples per \
         side and {max_bytes} decoded bytes at 4 bytes per sample)",
        path.display()
    )]
    TooLarge { path: PathBuf, width: u64, height: u64, max_side: u32, max_bytes: u64 },
    /// Every sample is no-data, so there is nothing to fill from.
    #[error("{}: every one of the {samples} samples is no-data", path.display())]
    AllNoData { path: PathBuf, samples: u64 },
    /// An RGB(A) PNG was given without saying how its channels encode height.
    #[error(
        "{}: PNG is {color} but no height encoding was given; pass --encoding terrain-rgb|terrarium",
        path.display()
    )]
    MissingEncoding { path: PathBuf, color: String },
    /// The requested encoding does not fit the PNG's colour type.
    #[error("{}: --encoding {} does not apply to this PNG: its samples are {color}", path.display(), encoding.name())]
    EncodingMismatch { path: PathBuf, encoding: HeightEncoding, color: String },
    /// `--encoding` was given for a file whose samples are heights already (not a PNG).
    #[error(
        "{}: --encoding applies to PNG files only; this {format} file's samples are heights already (remove --encoding)",
        path.display()
    )]
    EncodingNotApplicable { path: PathBuf, format: &'static str },
    /// The requested `OpenEXR` channel does not exist.
    #[error("{}: no channel named \"{name}\"; available channels: {available}", path.display())]
    ChannelNotFound { path: PathBuf, name: String, available: String },
    /// No `OpenEXR` channel holds floats and none was named.
    #[error("{}: no f32 or f16 channel to read heights from; available channels: {available}", path.display())]
    NoFloatChannel { path: PathBuf, available: String },
    /// An SRTM file whose name does not say where it lies.
    #[error(
        "{}: cannot georeference SRTM .hgt from file name \"{name}\"; expected a name like \
         N35E138.hgt or s12w077.hgt",
        path.display()
    )]
    HgtName { path: PathBuf, name: String },
    /// An SRTM file whose length matches neither 1201² nor 3601² samples.
    #[error(
        "{}: SRTM .hgt file is {len} bytes; expected 2884802 (1201², 3 arc-second) or 25934402 \
         (3601², 1 arc-second)",
        path.display()
    )]
    HgtLength { path: PathBuf, len: u64 },
    /// The coordinate system cannot be used: a CRS key or text that is not supported (named
    /// with its value), degrees without a datum, `--crs` on a file without a grid, or an
    /// override that a CRS makes meaningless.
    #[error("{}: coordinate system: {message}", path.display())]
    Crs { path: PathBuf, message: String },
    /// The file's own georeference is unusable (zero or non-finite cell size, ...).
    #[error("{}: invalid georeference in file: {message}", path.display())]
    BadGeoref { path: PathBuf, message: String },
    /// A user override is zero, negative where a size is meant, or not finite.
    #[error("{}: invalid {what} override {value:?}: must be {requirement}", path.display())]
    BadOverride { path: PathBuf, what: &'static str, value: f64, requirement: &'static str },
    /// A value of the world frame or a height lies outside the documented limits
    /// ([`MIN_CELL_SIZE`], [`MAX_CELL_SIZE`], [`MAX_COORDINATE`], [`MAX_HEIGHT`],
    /// [`MAX_RELIEF_CELLS`]); checked right after loading, before any bake work.
    #[error("{}: {message}", path.display())]
    OutOfLimits { path: PathBuf, message: String },
    /// An input that cannot join the dataset (no georeference, another CRS kind or cell size,
    /// off the grid, overlapping another file), or a dataset that cannot be read in blocks.
    #[error("{}: {message}", path.display())]
    Dataset { path: PathBuf, message: String },
    /// The input is not a regular file (a FIFO, a device, a socket, a directory where a file
    /// is named): refused before it is opened, since opening a FIFO waits for a writer and
    /// inputs are read by seeking.
    #[error(
        "{}: is {kind}, not a regular file; inputs are read by seeking, so pipes and devices cannot be \
         read (copy the data to a file)",
        path.display()
    )]
    NotRegular { path: PathBuf, kind: &'static str },
    /// The z scale/offset pushed heights beyond the f32 range.
    #[error(
        "{}: heights overflow f32 after z scale {dz} and offset {z0} (raw range {min}..{max})",
        path.display()
    )]
    HeightOverflow { path: PathBuf, z0: f64, dz: f64, min: f32, max: f32 },
}

/// Most samples a VRT (or a point cloud's grid) may declare per sample its sources cover
/// (unless [`dataset::DatasetOptions::allow_sparse`]): a few bytes of XML can declare a
/// continent of no-data, which a bake would fill and bake tile by tile. Here, not in `dataset`,
/// so that `las` names it without `dataset` and `las` importing each other.
pub const MAX_SPARSENESS: u64 = 64;

/// What a file that is not a regular file is, for messages; `None` for a regular file.
#[must_use]
pub fn irregular_kind(ty: std::fs::FileType) -> Option<&'static str> {
    use std::os::unix::fs::FileTypeExt;
    if ty.is_file() {
        None
    } else if ty.is_dir() {
        Some("a directory")
    } else if ty.is_fifo() {
        Some("a FIFO (named pipe)")
    } else if ty.is_char_device() {
        Some("a character device")
    } else if ty.is_block_device() {
        Some("a block device")
    } else if ty.is_socket() {
        Some("a socket")
    } else {
        Some("not a regular file")
    }
}

/// Opens the input file `path` for reading: a file that is not a regular file (symbolic links
/// followed) is refused without being opened ([`RasterError::NotRegular`]), and the opened file
/// is checked again (it may have been replaced in between).
pub(crate) fn open_input_file(path: &Path) -> Result<File, RasterError> {
    let md = std::fs::metadata(path).map_err(|e| RasterError::io(path, e))?;
    if let Some(kind) = irregular_kind(md.file_type()) {
        return Err(RasterError::NotRegular { path: path.to_owned(), kind });
    }
    let file = File::open(path).map_err(|e| RasterError::io(path, e))?;
    let md = file.metadata().map_err(|e| RasterError::io(path, e))?;
    if let Some(kind) = irregular_kind(md.file_type()) {
        return Err(RasterError::NotRegular { path: path.to_owned(), kind });
    }
    Ok(file)
}

impl RasterError {
    pub(crate) fn corrupt(path: &Path, format: &'static str, message: impl Into<String>) -> Self {
        Self::Corrupt { path: path.to_owned(), format, message: message.into() }
    }

    pub(crate) fn unsupported(path: &Path, format: &'static str, message: impl Into<String>) -> Self {
        Self::Unsupported { path: path.to_owned(), format, message: message.into() }
    }

    pub(crate) fn io(path: &Path, source: std::io::Error) -> Self {
        Self::Io { path: path.to_owned(), source }
    }
}

/// The coordinate system a file states, before `--crs` and `--vertical-datum`.
#[derive(Debug, Clone, Default, PartialEq)]
pub(crate) struct FileCrs {
    pub(crate) horizontal: Option<Crs>,
    pub(crate) vertical: Option<VerticalDatum>,
}

/// Georeference as the file states it, before the metric mapping and the overrides.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) enum FileGeoref {
    /// No georeference: unit cells at the origin.
    None,
    /// Sample (0, 0) centre at (x0, y0), steps dx, dy in the file's (metric) units.
    Projected { x0: f64, y0: f64, dx: f64, dy: f64 },
    /// Sample (0, 0) centre at (lon0, lat0) degrees, steps dlon, dlat degrees.
    Geographic { lon0: f64, lat0: f64, dlon: f64, dlat: f64 },
}

/// What a format decoder hands back: raw sample values (no-data already turned into NaN) and
/// the file's georeference.
#[derive(Debug)]
pub(crate) struct Decoded {
    width: u32,
    height: u32,
    values: Vec<f32>,
    georef: FileGeoref,
    crs: FileCrs,
    format: &'static str,
}

/// Checks a declared raster size against `limits`; decoders call it with the header's
/// dimensions before they allocate or decode.
fn check_size(path: &Path, width: u64, height: u64, limits: Limits) -> Result<(), RasterError> {
    if width == 0 || height == 0 {
        return Err(RasterError::ZeroSize { path: path.to_owned(), width, height });
    }
    let too_large = width > u64::from(limits.max_side)
        || height > u64::from(limits.max_side)
        || width.saturating_mul(height).saturating_mul(4) > limits.max_bytes;
    if too_large {
        return Err(RasterError::TooLarge {
            path: path.to_owned(),
            width,
            height,
            max_side: limits.max_side,
            max_bytes: limits.max_bytes,
        });
    }
    Ok(())
}

const PNG_MAGIC: &[u8] = b"\x89PNG\r\n\x1a\n";
const EXR_MAGIC: &[u8] = &[0x76, 0x2f, 0x31, 0x01];
const TIFF_MAGICS: [&[u8]; 4] = [b"II*\0", b"MM\0*", b"II+\0", b"MM\0+"];

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum Format {
    Png,
    Tiff,
    Exr,
    Hgt,
    /// A GDAL VRT mosaic (read by [`dataset`] only).
    Vrt,
    /// A LAS/LAZ point cloud (gridded by [`dataset`] only).
    Las,
}

/// Refuses a height encoding (`--encoding`) for a file that is not a PNG: only a PNG's samples
/// need one to become heights (a VRT passes it on to its sources). A dataset refuses it when
/// none of its inputs is a PNG or a VRT.
pub(crate) fn check_encoding(path: &Path, format: Format, opts: &LoadOptions) -> Result<(), RasterError> {
    let name = match format {
        Format::Png | Format::Vrt => return Ok(()),
        Format::Tiff => "GeoTIFF",
        Format::Exr => "OpenEXR",
        Format::Hgt => "SRTM HGT",
        Format::Las => "LAS/LAZ",
    };
    match opts.encoding {
        Some(_) => Err(RasterError::EncodingNotApplicable { path: path.to_owned(), format: name }),
        None => Ok(()),
    }
}

/// Magic bytes decide; the `.hgt` extension is the fallback because SRTM files have no header.
pub(crate) fn detect(path: &Path, head: &[u8]) -> Result<Format, RasterError> {
    if head.starts_with(PNG_MAGIC) {
        return Ok(Format::Png);
    }
    if head.starts_with(EXR_MAGIC) {
        return Ok(Format::Exr);
    }
    if TIFF_MAGICS.iter().any(|m| head.starts_with(m)) {
        return Ok(Format::Tiff);
    }
    if head.starts_with(b"LASF") {
        return Ok(Format::Las);
    }
    let ext = |x: &str| path.extension().is_some_and(|e| e.eq_ignore_ascii_case(x));
    if head.starts_with(b"<VRTData") || ext("vrt") {
        return Ok(Format::Vrt);
    }
    if ext("hgt") {
        return Ok(Format::Hgt);
    }
    let reason = if head.is_empty() {
        "the file is empty".to_owned()
    } else {
        let hex: Vec<String> = head.iter().take(8).map(|b| format!("{b:02x}")).collect();
        format!("first bytes {}", hex.join(" "))
    };
    Err(RasterError::UnknownFormat { path: path.to_owned(), reason })
}

/// Loads, validates and fills a raster file.
///
/// Runs a third-party decoder (PNG, OpenEXR) so that a panic inside it — a bug of that crate on
/// a hostile file — becomes [`RasterError::Corrupt`] naming the file, instead of unwinding into
/// (and, in a server, killing) the caller. The decoders run on the calling thread (OpenEXR with
/// its parallel decompression off), so their panics arrive here. The panic is still printed by
/// the process's panic hook; the decoders hold no state of ours, so nothing is left half-done.
pub(crate) fn guard_decoder<T>(
    path: &Path,
    format: &'static str,
    f: impl FnOnce() -> Result<T, RasterError>,
) -> Result<T, RasterError> {
    std::panic::catch_unwind(std::panic::AssertUnwindSafe(f)).unwrap_or_else(|panic| {
        let what = panic
            .downcast_ref::<&str>()
            .map(|s| (*s).to_owned())
            .or_else(|| panic.downcast_ref::<String>().cloned())
            .unwrap_or_else(|| "no message".into());
        Err(RasterError::corrupt(path, format, format!("the decoder failed on this file ({what})")))
    })
}

/// Errors: [`RasterError`], each naming the file: unreadable or unrecognized file, corrupt or
/// truncated data, unsupported sample type or band count, zero size, a declared size over
/// `opts.limits`, all samples no-data, an unusable georeference or override.
pub fn load(path: &Path, opts: &LoadOptions) -> Result<LoadedRaster, RasterError> {
    validate_overrides(path, &opts.overrides)?;
    let mut file = open_input_file(path)?;
    let mut head = Vec::with_capacity(8);
    (&mut file).take(8).read_to_end(&mut head).map_err(|e| RasterError::io(path, e))?;
    let format = detect(path, &head)?;
    check_encoding(path, format, opts)?;
    file.seek(SeekFrom::Start(0)).map_err(|e| RasterError::io(path, e))?;
    let reader = BufReader::new(file);
    let decoded = match format {
        Format::Png => png::decode(path, reader, opts)?,
        Format::Tiff => geotiff::decode(path, reader, opts.limits)?,
        Format::Exr => openexr::decode(path, reader, opts)?,
        Format::Hgt => hgt::decode(path, reader, opts.limits)?,
        Format::Vrt | Format::Las => return Err(not_in_memory(path, format)),
    };
    finish(path, decoded, &opts.overrides)
}

/// A VRT or a point cloud given to the in-memory loader (the server's `--source`, the demo).
pub(crate) fn not_in_memory(path: &Path, format: Format) -> RasterError {
    let what = if format == Format::Vrt { "GDAL VRT" } else { "LAS/LAZ" };
    RasterError::unsupported(
        path,
        what,
        "this command loads one raster file into memory; `terrastream bake` reads VRT mosaics and LAS/LAZ point clouds",
    )
}

/// Shared tail of every format: fill no-data, build the world frame, apply z.
fn finish(path: &Path, decoded: Decoded, overrides: &Overrides) -> Result<LoadedRaster, RasterError> {
    let Decoded { width, height, mut values, georef, crs, format } = decoded;
    // Decoders allocate exactly width·height; a mismatch would be a decoder bug, reported
    // rather than indexed past.
    if values.len() as u64 != u64::from(width) * u64::from(height) {
        return Err(RasterError::corrupt(
            path,
            format,
            format!("decoded {} samples for a {width}×{height} raster", values.len()),
        ));
    }
    let (nodata_filled, nodata_fallback) =
        nodata::fill_local(width as usize, height as usize, &mut values)
            .ok_or_else(|| RasterError::AllNoData { path: path.to_owned(), samples: values.len() as u64 })?;

    let mut frame = base_georef(path, georef, &crs, overrides, width, height)?;
    apply_overrides(&mut frame, overrides);
    check_frame(path, &frame, overrides, width, height)?;
    apply_z(path, &mut values, &frame)?;
    check_heights(path, &values, width, &frame)?;

    Ok(LoadedRaster {
        heights: Heightfield { width, height, data: values },
        georef: frame,
        nodata_filled,
        nodata_fallback,
        format: format.to_owned(),
    })
}

/// The world frame of a file's grid in its coordinate system ([`Georef`]): `--crs` or the file's
/// own CRS decides how the grid's numbers are read (degrees for a geographic CRS, the CRS's units
/// for a projected one); a grid without a CRS stays a local frame (metres, unplaced).
pub(crate) fn base_georef(
    path: &Path,
    georef: FileGeoref,
    file_crs: &FileCrs,
    o: &Overrides,
    width: u32,
    height: u32,
) -> Result<Georef, RasterError> {
    let bad = |message: String| RasterError::BadGeoref { path: path.to_owned(), message };
    let usable_step = |s: f64| s.is_finite() && s != 0.0;
    let horizontal = o.crs.clone().or_else(|| file_crs.horizontal.clone());
    let (x0, y0, dx, dy) = match georef {
        FileGeoref::None => {
            if let Some(c) = &o.crs {
                return Err(RasterError::Crs {
                    path: path.to_owned(),
                    message: format!(
                        "--crs {} needs a georeferenced grid and this file has none; give it one through a GDAL VRT \
                         (<SRS> and <GeoTransform>)",
                        c.definition()
                    ),
                });
            }
            return Ok(Georef::default());
        }
        FileGeoref::Projected { x0, y0, dx, dy } => (x0, y0, dx, dy),
        FileGeoref::Geographic { lon0, lat0, dlon, dlat } => {
            if horizontal.is_none() {
                return Err(RasterError::Crs {
                    path: path.to_owned(),
                    message:
                        "the grid is in degrees but names no geographic CRS (datum); give --crs, e.g. --crs \
                              EPSG:4326 for WGS 84"
                            .into(),
                });
            }
            (lon0, lat0, dlon, dlat)
        }
    };
    if !(usable_step(dx) && usable_step(dy) && x0.is_finite() && y0.is_finite()) {
        return Err(bad(format!("origin ({x0}, {y0}), cell size ({dx}, {dy})")));
    }
    let Some(crs) = horizontal else {
        // A metric grid that names no CRS: a local frame.
        return Ok(Georef { x0, y0, dx, dy, ..Georef::default() });
    };
    for (given, what) in [(o.cell_size.is_some(), "--cell-size"), (o.origin.is_some(), "--origin")] {
        if given {
            return Err(RasterError::Crs {
                path: path.to_owned(),
                message: format!(
                    "{what} applies to rasters without a coordinate system; this one is in {} (its grid gives \
                     the cell size and position): remove {what}",
                    crs.definition()
                ),
            });
        }
    }
    let vertical = o.vertical.or(file_crs.vertical).unwrap_or(VerticalDatum::Ellipsoid);
    let far = |v: f64, d: f64, n: u32| v + d * f64::from(n.saturating_sub(1));
    let (xc, yc) = (f64::midpoint(x0, far(x0, dx, width)), f64::midpoint(y0, far(y0, dy, height)));
    let grid = CrsGrid { crs: crs.clone(), e0: x0, n0: y0, de: dx, dn: dy };
    let base = Georef { crs: Some(grid), vertical, geoid_grid: o.geoid_grid.clone(), ..Georef::default() };
    if crs.is_geographic() {
        let last_lat = far(y0, dy, height);
        if y0.abs() > 90.0 || last_lat.abs() > 90.0 {
            return Err(bad(format!("latitudes {y0}°..{last_lat}° leave the range ±90°")));
        }
        let (m_lon, m_lat) = metres_per_degree(yc);
        // At a pole the east-west scale vanishes; the frame keeps cells square there.
        let m_lon = m_lon.max(m_lat * 1e-3);
        return Ok(Georef { x0: 0.0, y0: 0.0, dx: dx * m_lon, dy: dy * m_lat, ..base });
    }
    let (kx, ky) = crs.ground_scale(xc, yc).map_err(|e| RasterError::Crs {
        path: path.to_owned(),
        message: format!("the centre of the grid cannot be converted: {e}"),
    })?;
    // Conformal projections scale both axes alike; the numeric scales differ in their last
    // digits, and square cells must stay square (vertices then sit exactly on the grid).
    let (kx, ky) = if (kx / ky - 1.0).abs() < 1e-6 {
        let k = (kx * ky).sqrt();
        (k, k)
    } else {
        (kx, ky)
    };
    let unit = crs.unit_metres();
    Ok(Georef { x0: x0 * unit, y0: y0 * unit, dx: dx * kx, dy: dy * ky, ..base })
}

/// The world frame within the limits: cell sizes in [`MIN_CELL_SIZE`]..=[`MAX_CELL_SIZE`] and
/// every sample's x, y within ±[`MAX_COORDINATE`]. Messages say whether a value came from the
/// file or from an option.
pub(crate) fn check_frame(
    path: &Path,
    g: &Georef,
    o: &Overrides,
    width: u32,
    height: u32,
) -> Result<(), RasterError> {
    let limit = |message: String| RasterError::OutOfLimits { path: path.to_owned(), message };
    let from = |overridden: bool| if overridden { "--cell-size" } else { "the file's georeference" };
    for (axis, d) in [("x", g.dx), ("y", g.dy)] {
        if !(MIN_CELL_SIZE..=MAX_CELL_SIZE).contains(&d.abs()) {
            return Err(limit(format!(
                "cell size {:?} along {axis} (from {}) is outside the supported {MIN_CELL_SIZE:e}..{MAX_CELL_SIZE:e} \
                 world units",
                d.abs(),
                from(o.cell_size.is_some()),
            )));
        }
    }
    let last = |v0: f64, d: f64, n: u32| v0 + d * f64::from(n.saturating_sub(1));
    let xs = [g.x0, last(g.x0, g.dx, width)];
    let ys = [g.y0, last(g.y0, g.dy, height)];
    if xs.iter().chain(&ys).any(|v| v.is_nan() || v.abs() > MAX_COORDINATE) {
        let origin = if o.origin.is_some() { "--origin" } else { "the file's georeference" };
        return Err(limit(format!(
            "samples span x {:?}..{:?}, y {:?}..{:?} (origin from {origin}, cell size from {}), beyond the supported \
             ±{MAX_COORDINATE:e} world units",
            xs[0],
            xs[1],
            ys[0],
            ys[1],
            from(o.cell_size.is_some()),
        )));
    }
    Ok(())
}

/// Heights within ±[`MAX_HEIGHT`] (the first sample beyond is named) and a relief of at most
/// [`MAX_RELIEF_CELLS`] cells.
fn check_heights(path: &Path, values: &[f32], width: u32, g: &Georef) -> Result<(), RasterError> {
    let limit = |message: String| RasterError::OutOfLimits { path: path.to_owned(), message };
    let (mut min, mut max) = (f32::INFINITY, f32::NEG_INFINITY);
    for (i, &v) in values.iter().enumerate() {
        if v.is_nan() || f64::from(v).abs() > MAX_HEIGHT {
            let w = width.max(1) as usize;
            return Err(limit(format!(
                "sample at column {}, row {} has height {v:?} (after z scale {:?} and offset {:?}), beyond the \
                 supported ±{MAX_HEIGHT:e}; is it an undeclared no-data value?",
                i % w,
                i / w,
                g.dz,
                g.z0,
            )));
        }
        min = min.min(v);
        max = max.max(v);
    }
    let cell = g.dx.abs().min(g.dy.abs());
    let relief = f64::from(max) - f64::from(min);
    if relief > MAX_RELIEF_CELLS * cell {
        return Err(limit(format!(
            "heights span {min:?}..{max:?} ({relief:?} world units), more than {MAX_RELIEF_CELLS} cells of {cell:?}; \
             check the cell size and the z scale (heights and cells must be in the same units)"
        )));
    }
    Ok(())
}

pub(crate) fn validate_overrides(path: &Path, o: &Overrides) -> Result<(), RasterError> {
    let bad = |what, value, requirement| RasterError::BadOverride {
        path: path.to_owned(),
        what,
        value,
        requirement,
    };
    // A negative cell size would silently mirror the raster; the signs come from the file.
    if let Some(c) = o.cell_size
        && !(c.is_finite() && c > 0.0)
    {
        return Err(bad("cell size", c, "finite and positive"));
    }
    if let Some(c) = o.cell_size
        && !(MIN_CELL_SIZE..=MAX_CELL_SIZE).contains(&c)
    {
        return Err(bad("cell size", c, "between 1e-6 and 1e8 world units"));
    }
    if let Some((x, y)) = o.origin {
        for v in [x, y] {
            if !v.is_finite() {
                return Err(bad("origin", v, "finite"));
            }
            if v.abs() > MAX_COORDINATE {
                return Err(bad("origin", v, "within ±1e9 world units"));
            }
        }
    }
    if let Some(s) = o.z_scale
        && !(s.is_finite() && s != 0.0)
    {
        return Err(bad("z scale", s, "finite and non-zero"));
    }
    if let Some(z) = o.z_offset
        && !(z.is_finite() && z.abs() <= MAX_HEIGHT)
    {
        return Err(bad("z offset", z, "finite and within ±1e7 world units"));
    }
    Ok(())
}

pub(crate) fn apply_overrides(g: &mut Georef, o: &Overrides) {
    // With a CRS, [`base_georef`] refused both.
    if let Some(c) = o.cell_size {
        g.dx = c.copysign(g.dx);
        g.dy = c.copysign(g.dy);
    }
    if let Some((x, y)) = o.origin {
        g.x0 = x;
        g.y0 = y;
    }
    g.dz = o.z_scale.unwrap_or(1.0);
    g.z0 = o.z_offset.unwrap_or(0.0);
}

/// Applies `z = z0 + value·dz` in f64 and rejects results that no longer fit in f32, so the
/// "never NaN/inf" promise of [`Heightfield`] survives the user's scale.
fn apply_z(path: &Path, values: &mut [f32], g: &Georef) -> Result<(), RasterError> {
    let (mut min, mut max) = (f32::INFINITY, f32::NEG_INFINITY);
    let mut overflow = false;
    for v in values.iter_mut() {
        min = min.min(*v);
        max = max.max(*v);
        let z = (g.z0 + f64::from(*v) * g.dz) as f32;
        overflow |= !z.is_finite();
        *v = z;
    }
    if overflow {
        return Err(RasterError::HeightOverflow { path: path.to_owned(), z0: g.z0, dz: g.dz, min, max });
    }
    Ok(())
}

/// Directory of the shared test data (`fuji.png`, ...): `$TERRASTREAM_DATA`, else
/// `../shared/data` beside the crate.
#[doc(hidden)]
#[must_use]
pub fn test_data_dir() -> PathBuf {
    std::env::var_os("TERRASTREAM_DATA")
        .map_or_else(|| Path::new(env!("CARGO_MANIFEST_DIR")).join("../shared/data"), PathBuf::from)
}

/// The one "shared data or skip" rule of the tests: `name` under [`test_data_dir`] when it
/// exists; else `None` after printing (to stderr, past the test harness's capture) that `what`
/// is skipped. A clone without `../shared` beside it runs the default suite that way; under
/// `TERRASTREAM_REQUIRE_DATA=1` (CI sets it) a missing file fails the test instead.
#[doc(hidden)]
#[must_use]
pub fn shared_test_data(name: &str, what: &str) -> Option<PathBuf> {
    use std::io::Write as _;
    let path = test_data_dir().join(name);
    if path.exists() {
        return Some(path);
    }
    // A test helper: under TERRASTREAM_REQUIRE_DATA=1 a missing file is the test failing.
    assert!(
        !std::env::var("TERRASTREAM_REQUIRE_DATA").is_ok_and(|v| v == "1"),
        "{what}: TERRASTREAM_REQUIRE_DATA=1 but {} is missing (set TERRASTREAM_DATA to the shared data)",
        path.display()
    );
    let _ = writeln!(
        std::io::stderr(),
        "skipping {what}: {} not found (the shared test data: set TERRASTREAM_DATA, or \
         TERRASTREAM_REQUIRE_DATA=1 to fail instead)",
        path.display()
    );
    None
}

#[cfg(test)]
#[allow(clippy::unwrap_used)]
pub(crate) mod test_util {
    //! Helpers shared by the format tests: temp files and default options.

    use std::io::Cursor;
    use std::path::{Path, PathBuf};

    use tiff::encoder::TiffEncoder;
    use tiff::tags::Tag;

    use super::{LoadOptions, LoadedRaster, RasterError};

    /// Writes `bytes` to `name` inside `dir` and returns the path.
    pub fn write(dir: &Path, name: &str, bytes: &[u8]) -> PathBuf {
        let p = dir.join(name);
        std::fs::write(&p, bytes).unwrap();
        p
    }

    pub fn load(path: &Path) -> Result<LoadedRaster, RasterError> {
        super::load(path, &LoadOptions::default())
    }

    /// A tiled u16 TIFF (tiles of `tile`², row-major) leaving the tiles `skip` out (offset and byte count 0, as GDAL's
    /// `SPARSE_OK=TRUE` writes them), with an optional GDAL_NODATA.
    pub fn sparse_tiff(
        dir: &Path,
        w: u32,
        h: u32,
        tile: u32,
        data: &[u16],
        skip: &[usize],
        nodata: Option<&str>,
    ) -> PathBuf {
        let mut buf = Cursor::new(Vec::new());
        let mut enc = TiffEncoder::new(&mut buf).unwrap();
        let mut d = enc.image_directory().unwrap();
        let (mut offsets, mut counts) = (Vec::new(), Vec::new());
        for ty in 0..h.div_ceil(tile) {
            for tx in 0..w.div_ceil(tile) {
                if skip.contains(&offsets.len()) {
                    offsets.push(0);
                    counts.push(0);
                    continue;
                }
                let mut t = vec![0_u16; (tile * tile) as usize];
                for r in 0..tile {
                    for c in 0..tile {
                        let (col, row) = (tx * tile + c, ty * tile + r);
                        if col < w && row < h {
                            t[(r * tile + c) as usize] = data[(row * w + col) as usize];
                        }
                    }
                }
                offsets.push(d.write_data(&t[..]).unwrap() as u32);
                counts.push(tile * tile * 2);
            }
        }
        d.write_tag(Tag::ImageWidth, w).unwrap();
        d.write_tag(Tag::ImageLength, h).unwrap();
        d.write_tag(Tag::BitsPerSample, 16_u16).unwrap();
        d.write_tag(Tag::SamplesPerPixel, 1_u16).unwrap();
        d.write_tag(Tag::PhotometricInterpretation, 1_u16).unwrap();
        d.write_tag(Tag::Compression, 1_u16).unwrap();
        d.write_tag(Tag::TileWidth, tile).unwrap();
        d.write_tag(Tag::TileLength, tile).unwrap();
        d.write_tag(Tag::TileOffsets, &offsets[..]).unwrap();
        d.write_tag(Tag::TileByteCounts, &counts[..]).unwrap();
        if let Some(n) = nodata {
            d.write_tag(Tag::GdalNodata, n).unwrap();
        }
        d.finish().unwrap();
        write(dir, "tiled.tif", &buf.into_inner())
    }

    /// The error's message must start with the path, as every `RasterError` promises.
    pub fn assert_names_path(e: &RasterError, path: &Path) {
        let msg = e.to_string();
        assert!(msg.starts_with(&format!("{}: ", path.display())), "{msg}");
    }
}

#[cfg(test)]
// A failed unwrap is the test failing; exact float comparisons are of exactly representable values.
#[allow(clippy::unwrap_used, clippy::float_cmp)]
mod tests {
    use std::time::Instant;

    use image::{ImageBuffer, Luma};

    use super::test_util::{assert_names_path, write};
    use super::*;

    /// A panic inside a decoder comes back as a corrupt-file error naming the file and the
    /// panic's message (string and formatted messages alike); a decoder's own result passes.
    #[test]
    fn decoder_panics_become_corrupt_file_errors() {
        let p = Path::new("x.exr");
        let e =
            guard_decoder::<()>(p, "OpenEXR", || panic!("attempt to subtract with overflow")).unwrap_err();
        assert!(matches!(e, RasterError::Corrupt { .. }), "{e}");
        let text = e.to_string();
        assert!(text.contains("x.exr") && text.contains("attempt to subtract with overflow"), "{text}");
        let n = 3;
        let e = guard_decoder::<()>(p, "PNG", || panic!("index {n} out of range")).unwrap_err();
        assert!(e.to_string().contains("index 3 out of range"), "{e}");
        assert_eq!(guard_decoder(p, "PNG", || Ok(7)).unwrap(), 7);
    }

    fn gray16(dir: &Path, w: u32, h: u32, data: Vec<u16>) -> PathBuf {
        let p = dir.join("g.png");
        ImageBuffer::<Luma<u16>, _>::from_raw(w, h, data).unwrap().save(&p).unwrap();
        p
    }

    /// A small valid file: 0 = 16-bit PNG, 1 = `GeoTIFF` (i16, georeferenced, nodata), 2 = EXR.
    fn valid_file(kind: usize) -> Vec<u8> {
        let (w, h) = (9_u32, 7_u32);
        let vals: Vec<u16> = (0..w * h).map(|i| (i * 37 % 1000) as u16).collect();
        let mut out = std::io::Cursor::new(Vec::new());
        match kind {
            0 => {
                let img = ImageBuffer::<Luma<u16>, _>::from_raw(w, h, vals).unwrap();
                img.write_to(&mut out, image::ImageFormat::Png).unwrap();
            }
            1 => {
                use tiff::encoder::{TiffEncoder, colortype::GrayI16};
                use tiff::tags::Tag;
                let data: Vec<i16> = vals.iter().map(|&v| v as i16 - 500).collect();
                let mut enc = TiffEncoder::new(&mut out).unwrap();
                let mut img = enc.new_image::<GrayI16>(w, h).unwrap();
                img.rows_per_strip(3).unwrap();
                let e = img.encoder();
                e.write_tag(Tag::ModelPixelScaleTag, &[10.0, 10.0, 0.0][..]).unwrap();
                e.write_tag(Tag::ModelTiepointTag, &[0.0, 0.0, 0.0, 5.0, 50.0, 0.0][..]).unwrap();
                e.write_tag(Tag::GeoKeyDirectoryTag, &[1_u16, 1, 0, 1, 1024, 0, 1, 2][..]).unwrap();
                e.write_tag(Tag::GdalNodata, "-500").unwrap();
                img.write_data(&data).unwrap();
            }
            _ => {
                use exr::prelude::{
                    AnyChannel, AnyChannels, FlatSamples, Layer, LayerAttributes, WritableImage,
                };
                let z = FlatSamples::F32(vals.iter().map(|&v| f32::from(v)).collect());
                let layer = Layer::new(
                    (w as usize, h as usize),
                    LayerAttributes::default(),
                    exr::prelude::Encoding::SMALL_LOSSLESS,
                    AnyChannels::sort(vec![AnyChannel::new("Z", z)].into()),
                );
                exr::prelude::Image::from_layer(layer).write().to_buffered(&mut out).unwrap();
            }
        }
        out.into_inner()
    }

    #[test]
    fn fuji_terrain_rgb() {
        let Some(path) = shared_test_data("fuji.png", "raster::tests::fuji_terrain_rgb") else { return };
        let opts = LoadOptions { encoding: Some(HeightEncoding::TerrainRgb), ..LoadOptions::default() };
        let r = load(&path, &opts).unwrap();
        assert_eq!((r.heights.width, r.heights.height), (512, 512));
        assert_eq!(r.format, "png-terrain-rgb");
        assert_eq!(r.nodata_filled, 0);
        let min = r.heights.data.iter().copied().fold(f32::INFINITY, f32::min);
        let max = r.heights.data.iter().copied().fold(f32::NEG_INFINITY, f32::max);
        assert!((13.0..14.5).contains(&min), "min {min}");
        assert!((3750.0..3752.0).contains(&max), "max {max}");
        assert_eq!(r.georef, Georef::default());
    }

    /// A terrain-RGB PNG of generated heights (0.1 m steps, as the encoding stores them).
    fn terrain_rgb_png(dir: &Path, w: u32, h: u32) -> (PathBuf, Vec<f32>) {
        let heights = synth::terrain(w, h, 3);
        let mut rgb = Vec::with_capacity(heights.len() * 3);
        let mut stored = Vec::with_capacity(heights.len());
        for &z in &heights {
            let v = ((f64::from(z) + 10_000.0) * 10.0).round() as u32;
            rgb.extend_from_slice(&[(v >> 16) as u8, (v >> 8) as u8, v as u8]);
            stored.push((-10_000.0 + f64::from(v) * 0.1) as f32);
        }
        let p = dir.join("generated-terrain-rgb.png");
        ImageBuffer::<image::Rgb<u8>, _>::from_raw(w, h, rgb).unwrap().save(&p).unwrap();
        (p, stored)
    }

    /// What `fuji_terrain_rgb` checks on the real tile, on generated heights (no shared data).
    #[test]
    fn generated_terrain_rgb() {
        let dir = tempfile::tempdir().unwrap();
        let (path, want) = terrain_rgb_png(dir.path(), 64, 48);
        let opts = LoadOptions { encoding: Some(HeightEncoding::TerrainRgb), ..LoadOptions::default() };
        let r = load(&path, &opts).unwrap();
        assert_eq!((r.heights.width, r.heights.height), (64, 48));
        assert_eq!(r.format, "png-terrain-rgb");
        assert_eq!(r.nodata_filled, 0);
        for (got, want) in r.heights.data.iter().zip(&want) {
            assert!((got - want).abs() < 1e-3, "{got} vs {want}");
        }
        assert_eq!(r.georef, Georef::default());
    }

    #[test]
    fn rgb_without_encoding_asks_for_it() {
        let dir = tempfile::tempdir().unwrap();
        let generated = terrain_rgb_png(dir.path(), 8, 8).0;
        let fuji =
            shared_test_data("fuji.png", "raster::tests::rgb_without_encoding_asks_for_it on fuji.png");
        for path in std::iter::once(generated).chain(fuji) {
            let e = load(&path, &LoadOptions::default()).unwrap_err();
            assert!(matches!(e, RasterError::MissingEncoding { .. }), "{e}");
            assert!(e.to_string().contains("--encoding terrain-rgb|terrarium"), "{e}");
            assert_names_path(&e, &path);
        }
    }

    #[test]
    fn missing_file() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("nope.png");
        let e = load(&p, &LoadOptions::default()).unwrap_err();
        assert!(matches!(e, RasterError::Io { .. }), "{e}");
        assert_names_path(&e, &p);
    }

    #[test]
    fn unknown_magic_and_empty_file() {
        let dir = tempfile::tempdir().unwrap();
        let p = write(dir.path(), "x.dem", b"hello world, not a raster");
        let e = load(&p, &LoadOptions::default()).unwrap_err();
        assert!(matches!(e, RasterError::UnknownFormat { .. }), "{e}");
        assert!(e.to_string().contains("68 65 6c 6c"), "{e}");
        assert_names_path(&e, &p);
        let p = write(dir.path(), "empty.png", b"");
        let e = load(&p, &LoadOptions::default()).unwrap_err();
        assert!(e.to_string().contains("empty"), "{e}");
    }

    #[test]
    fn magic_wins_over_extension() {
        let dir = tempfile::tempdir().unwrap();
        let p = gray16(dir.path(), 2, 1, vec![5, 6]);
        let renamed = dir.path().join("N35E138.hgt");
        std::fs::rename(&p, &renamed).unwrap();
        let r = load(&renamed, &LoadOptions::default()).unwrap();
        assert_eq!(r.format, "png-gray16");
    }

    #[test]
    fn overrides_apply_on_top() {
        let dir = tempfile::tempdir().unwrap();
        let p = gray16(dir.path(), 2, 2, vec![0, 100, 200, 300]);
        let overrides = Overrides {
            cell_size: Some(30.0),
            origin: Some((1000.0, -5.0)),
            z_scale: Some(0.5),
            z_offset: Some(-10.0),
            ..Overrides::default()
        };
        let r = load(&p, &LoadOptions { overrides, ..LoadOptions::default() }).unwrap();
        let g = r.georef;
        assert_eq!((g.x0, g.y0, g.dx, g.dy, g.z0, g.dz), (1000.0, -5.0, 30.0, 30.0, -10.0, 0.5));
        assert_eq!(r.heights.data, [-10.0, 40.0, 90.0, 140.0]);
    }

    #[test]
    fn cell_size_keeps_signs() {
        let mut g = Georef { dx: 2.0, dy: -2.0, ..Georef::default() };
        apply_overrides(&mut g, &Overrides { cell_size: Some(5.0), ..Overrides::default() });
        assert_eq!((g.dx, g.dy), (5.0, -5.0));
    }

    #[test]
    fn bad_overrides_are_errors() {
        let dir = tempfile::tempdir().unwrap();
        let p = gray16(dir.path(), 1, 1, vec![1]);
        let cases = [
            Overrides { cell_size: Some(0.0), ..Overrides::default() },
            Overrides { cell_size: Some(-1.0), ..Overrides::default() },
            Overrides { cell_size: Some(f64::NAN), ..Overrides::default() },
            Overrides { z_scale: Some(0.0), ..Overrides::default() },
            Overrides { z_scale: Some(f64::INFINITY), ..Overrides::default() },
            Overrides { z_offset: Some(f64::NAN), ..Overrides::default() },
            Overrides { origin: Some((0.0, f64::NEG_INFINITY)), ..Overrides::default() },
        ];
        for overrides in cases {
            let e = load(&p, &LoadOptions { overrides, ..LoadOptions::default() }).unwrap_err();
            assert!(matches!(e, RasterError::BadOverride { .. }), "{e}");
            assert_names_path(&e, &p);
        }
    }

    #[test]
    fn z_overflow_is_an_error() {
        let dir = tempfile::tempdir().unwrap();
        let p = gray16(dir.path(), 1, 1, vec![60_000]);
        let overrides = Overrides { z_scale: Some(1e36), ..Overrides::default() };
        let e = load(&p, &LoadOptions { overrides, ..LoadOptions::default() }).unwrap_err();
        assert!(matches!(e, RasterError::HeightOverflow { .. }), "{e}");
    }

    #[test]
    fn size_checks() {
        let p = Path::new("a.tif");
        let l = Limits { max_side: 100, max_bytes: 4 * 50 * 50 };
        assert!(check_size(p, 50, 50, l).is_ok());
        assert!(matches!(check_size(p, 0, 5, l), Err(RasterError::ZeroSize { .. })));
        assert!(matches!(check_size(p, 101, 1, l), Err(RasterError::TooLarge { .. })));
        assert!(matches!(check_size(p, 51, 50, l), Err(RasterError::TooLarge { .. })));
        assert!(matches!(
            check_size(p, u64::MAX, u64::MAX, Limits::default()),
            Err(RasterError::TooLarge { .. })
        ));
    }

    #[test]
    fn limits_apply_to_png() {
        let dir = tempfile::tempdir().unwrap();
        let p = gray16(dir.path(), 8, 4, vec![1; 32]);
        let limits = Limits { max_side: 7, max_bytes: DEFAULT_MAX_BYTES };
        let start = Instant::now();
        let e = load(&p, &LoadOptions { limits, ..LoadOptions::default() }).unwrap_err();
        assert!(matches!(e, RasterError::TooLarge { width: 8, height: 4, .. }), "{e}");
        assert!(start.elapsed().as_secs() < 2);
    }

    proptest::proptest! {
        #![proptest_config(proptest::prelude::ProptestConfig::with_cases(96))]

        /// Arbitrary bytes behind each magic number decode or fail with an error, never panic;
        /// tight limits keep a random header from asking for gigabytes.
        #[test]
        fn arbitrary_bytes_never_panic(kind in 0_usize..4, body in proptest::collection::vec(proptest::num::u8::ANY, 0..600)) {
            let dir = tempfile::tempdir().unwrap();
            let magic: &[u8] = [PNG_MAGIC, EXR_MAGIC, TIFF_MAGICS[0], TIFF_MAGICS[1]][kind];
            let mut bytes = magic.to_vec();
            bytes.extend_from_slice(&body);
            let p = write(dir.path(), "fuzz.bin", &bytes);
            let limits = Limits { max_side: 4096, max_bytes: 16 << 20 };
            if let Ok(r) = load(&p, &LoadOptions { limits, encoding: Some(HeightEncoding::Terrarium), ..LoadOptions::default() }) {
                proptest::prop_assert!(r.heights.data.iter().all(|v| v.is_finite()));
            }
        }

        /// Valid small files with a few bytes corrupted (and maybe cut short) decode or fail
        /// with an error, never panic.
        #[test]
        fn mutated_files_never_panic(
            kind in 0_usize..3,
            flips in proptest::collection::vec((proptest::num::usize::ANY, 1_u8..=255), 1..6),
            cut in proptest::option::of(proptest::num::usize::ANY),
        ) {
            let mut bytes = valid_file(kind);
            let n = bytes.len();
            for (at, x) in flips {
                bytes[at % n] ^= x;
            }
            if let Some(c) = cut {
                bytes.truncate(c % n);
            }
            let dir = tempfile::tempdir().unwrap();
            let p = write(dir.path(), "fuzz.bin", &bytes);
            let limits = Limits { max_side: 4096, max_bytes: 16 << 20 };
            let opts = LoadOptions { limits, encoding: Some(HeightEncoding::Gray16), ..LoadOptions::default() };
            if let Ok(r) = load(&p, &opts) {
                proptest::prop_assert!(r.heights.data.iter().all(|v| v.is_finite()));
            }
        }

        /// Filling leaves valid samples alone, fills every hole within the valid range, and
        /// counts exactly the holes.
        #[test]
        fn fill_invariants(w in 1_usize..12, h in 1_usize..12, seed in proptest::collection::vec(proptest::num::u8::ANY, 144)) {
            let orig: Vec<f32> = (0..w * h).map(|i| if seed[i] % 3 == 0 { f32::NAN } else { f32::from(seed[i]) }).collect();
            let holes = orig.iter().filter(|v| v.is_nan()).count() as u64;
            let mut d = orig.clone();
            match nodata::fill_nodata(w, h, &mut d) {
                None => proptest::prop_assert_eq!(holes, (w * h) as u64),
                Some(n) => {
                    proptest::prop_assert_eq!(n, holes);
                    for (a, b) in orig.iter().zip(&d) {
                        proptest::prop_assert!(b.is_finite() && (0.0..=255.0).contains(b));
                        if a.is_finite() {
                            proptest::prop_assert_eq!(a, b);
                        }
                    }
                }
            }
        }
    }

    #[test]
    fn metres_per_degree_matches_known_values() {
        let (lon, lat) = metres_per_degree(0.0);
        assert!((lat - 110_574.0).abs() < 2.0 && (lon - 111_319.0).abs() < 2.0, "{lon} {lat}");
        let (lon, lat) = metres_per_degree(45.0);
        assert!((lat - 111_132.0).abs() < 2.0 && (lon - 78_847.0).abs() < 2.0, "{lon} {lat}");
    }

    #[test]
    fn geographic_mapping_uses_central_latitude() {
        let wgs84 = FileCrs { horizontal: Some(Crs::wgs84()), vertical: None };
        let o = Overrides::default();
        let geo = FileGeoref::Geographic { lon0: 10.0, lat0: 46.0, dlon: 0.5, dlat: -0.5 };
        let g = base_georef(Path::new("x"), geo, &wgs84, &o, 5, 5).unwrap();
        let m = g.crs.clone().unwrap();
        assert_eq!((m.e0, m.n0, m.de, m.dn), (10.0, 46.0, 0.5, -0.5));
        let (m_lon, m_lat) = metres_per_degree(45.0);
        assert_eq!((g.x0, g.y0), (0.0, 0.0));
        assert!((g.dx - 0.5 * m_lon).abs() < 1e-9 && (g.dy + 0.5 * m_lat).abs() < 1e-9);
        assert_eq!(g.vertical, VerticalDatum::Ellipsoid);
        let bad = FileGeoref::Projected { x0: 0.0, y0: 0.0, dx: 0.0, dy: 1.0 };
        let e = base_georef(Path::new("x"), bad, &FileCrs::default(), &o, 1, 1);
        assert!(matches!(e, Err(RasterError::BadGeoref { .. })));
        // Degrees without a datum are refused, not guessed; --cell-size with a CRS too.
        let e = base_georef(Path::new("x"), geo, &FileCrs::default(), &o, 5, 5).unwrap_err().to_string();
        assert!(e.contains("--crs") && e.contains("degrees"), "{e}");
        let cell = Overrides { cell_size: Some(90.0), ..Overrides::default() };
        let e = base_georef(Path::new("x"), geo, &wgs84, &cell, 5, 5).unwrap_err().to_string();
        assert!(e.contains("--cell-size") && e.contains("EPSG:4326"), "{e}");
        // A projected CRS in US survey feet: cells in ground metres.
        let feet = FileCrs { horizontal: Some(Crs::from_epsg(2276).unwrap()), vertical: None };
        let grid = FileGeoref::Projected { x0: 2_400_000.0, y0: 7_000_000.0, dx: 10.0, dy: -10.0 };
        let g = base_georef(Path::new("x"), grid, &feet, &o, 100, 100).unwrap();
        assert!((g.dx / 3.048 - 1.0).abs() < 2e-3 && (g.dy / -3.048 - 1.0).abs() < 2e-3, "{} {}", g.dx, g.dy);
    }
}
