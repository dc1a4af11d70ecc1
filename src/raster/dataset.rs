//! Datasets: one heightfield made of one or many raster files, read in blocks through a bounded
//! cache, so a bake never holds the whole raster in memory.
//!
//! [`Dataset::open`] places every file on one grid — GeoTIFF/COG by its georeference, SRTM
//! `.hgt` by its name, a single file of any format at the origin — after checking that all of
//! them share the CRS kind, the cell size and the grid alignment (an error names the file that
//! does not fit). Gaps between files are no-data. Files may share an edge of one sample (SRTM and
//! Copernicus tiles repeat their border rows and columns); there the first file in input order
//! with a valid sample gives it. Any wider overlap is refused, naming both files.
//!
//! Samples are read per file block (a TIFF tile or strip, 256 rows of an `.hgt`, 256² of a file
//! decoded whole) into a least-recently-used cache of bounded size, and served per dataset block
//! of [`BLOCK`]² samples, filled and with the z scale applied, from a second cache. No-data
//! filling is local: the wavefront of [`super::nodata`] reaches [`FILL_REACH`] cells from the
//! nearest valid sample, so a block filled with a halo that wide gets exactly the values a
//! whole-raster fill gives; a cell farther from every valid sample takes the fallback grid (the
//! means of the valid samples of each 256² block, interpolated bilinearly between block
//! centres). The in-memory [`super::load`] fills by the same rule, so both give the same heights.
//!
//! Opening makes one streaming pass over the dataset (two when it has no-data): it counts no-data,
//! builds the fallback grid, checks heights against the limits and computes the checksum the bake
//! records, with progress reported per block row.

use std::collections::{BTreeMap, HashMap};
use std::fs::File;
use std::io::{BufReader, Read, Seek, SeekFrom};
use std::path::{Path, PathBuf};
use std::sync::{Arc, Mutex, PoisonError};

use rayon::prelude::*;
use serde::{Deserialize, Serialize};
use tiff::decoder::ChunkType;

use super::nodata::{self, FALLBACK_BLOCK};
use super::open_files::{self, Handle};
pub use super::parts::MAX_DATASET_SIDE;
use super::parts::{BlockSource, Part, whole_part};
use super::{
    FileCrs, FileGeoref, Format, Georef, LoadOptions, MAX_HEIGHT, MAX_RELIEF_CELLS, RasterError,
    WindowReader, geotiff, hgt,
};
use super::{las, vrt};

pub use super::nodata::FILL_REACH;

/// Side of a dataset block in samples (the unit of the filled-block cache and of the fill).
pub const BLOCK: u32 = FALLBACK_BLOCK as u32;
/// Default block cache budget (both caches together), in bytes.
pub const DEFAULT_CACHE_BYTES: u64 = 512 << 20;
/// Smallest block cache budget accepted, in bytes.
pub const MIN_CACHE_BYTES: u64 = 4 << 20;

/// What opening a dataset needs besides its files.
#[derive(Debug, Clone)]
pub struct DatasetOptions {
    /// PNG encoding, EXR channel, per-file decode limits (files decoded whole) and overrides.
    pub load: LoadOptions,
    /// Budget of the block caches, in bytes.
    pub cache_bytes: u64,
    /// Directory for scratch files (the gridded point clouds); `None` = the system's temporary
    /// directory.
    pub scratch: Option<PathBuf>,
    /// Accept a VRT whose extent is more than [`MAX_SPARSENESS`] times what its sources
    /// cover (the rest is no-data, filled and baked as flat terrain).
    pub allow_sparse: bool,
}

impl Default for DatasetOptions {
    fn default() -> Self {
        Self {
            load: LoadOptions::default(),
            cache_bytes: DEFAULT_CACHE_BYTES,
            scratch: None,
            allow_sparse: false,
        }
    }
}

pub use super::MAX_SPARSENESS;

/// What a dataset is made of, for the bake's summary and manifest.
#[derive(Debug, Clone, Serialize)]
pub struct DatasetSummary {
    pub files: Vec<PathBuf>,
    /// The files' format ("geotiff", "hgt", …; "mixed" when they differ).
    pub format: String,
    pub width: u32,
    pub height: u32,
    /// The CRS (`EPSG:n` or a PROJ string); "local" for a metric grid that names none, "none"
    /// without georeference.
    pub crs: String,
    /// What the heights are measured from (with a CRS).
    pub vertical: Option<crate::crs::VerticalDatum>,
    /// Extent of the sample centres in the files' own units: [x_min, y_min, x_max, y_max].
    pub extent: [f64; 4],
    pub nodata_filled: u64,
    /// Of the filled samples, those beyond [`FILL_REACH`] (set from the fallback grid).
    pub nodata_fallback: u64,
    /// CRC-32 of every filled height, row-major, little-endian f32 (the bake's source checksum).
    pub crc32: String,
    /// Point clouds: what the gridding read and used.
    pub points: Option<las::PointStats>,
    /// A warped dataset: what the resampling measured.
    pub warp: Option<super::warp::WarpStats>,
}

/// What the opening scan of a dataset found ([`Dataset::scan_record`]), so that the same files
/// can be opened again without reading every sample ([`Dataset::open_scanned`]).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ScanRecord {
    /// The files as scanned: a file whose length or modification time differs is scanned again.
    pub files: Vec<FileStamp>,
    pub width: u32,
    pub height: u32,
    pub nodata_filled: u64,
    pub nodata_fallback: u64,
    pub crc32: String,
    /// The fallback grid's shape and the CRC-32 of its bytes, when the dataset has no-data.
    pub fallback: Option<FallbackRecord>,
    /// The lowest and highest height ([`Dataset::height_range`]); absent from the records of
    /// older builds, which are then scanned again.
    #[serde(default)]
    pub heights: Option<[f32; 2]>,
}

// The recorded heights are finite (the scan refuses others), so equality is an equivalence.
impl Eq for ScanRecord {}

impl ScanRecord {
    /// The length in bytes of the recorded fallback grid, when there is one and its shape is
    /// that of a dataset of the recorded size (at most [`MAX_DATASET_SIDE`] a side): what a
    /// reader checks the stored grid's size against before reading it.
    #[must_use]
    pub fn fallback_len(&self) -> Option<u64> {
        let f = self.fallback.as_ref()?;
        let fits = self.width.max(self.height) <= MAX_DATASET_SIDE
            && (f.cols, f.rows) == (self.width.div_ceil(BLOCK), self.height.div_ceil(BLOCK));
        fits.then(|| u64::from(f.cols) * u64::from(f.rows) * 4)
    }
}

/// A file's path, length and modification time (nanoseconds since the Unix epoch).
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct FileStamp {
    pub path: PathBuf,
    pub len: u64,
    pub modified_ns: u64,
}

/// Why a [`ScanRecord`] cannot stand for the files being opened ([`Dataset::open_scanned`]): the
/// caller scans them instead.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum ScanMismatch {
    #[error("point clouds are gridded on every open")]
    PointClouds,
    #[error("a warped dataset measures its resampling error in its scan")]
    Warped,
    #[error(
        "{} has changed since the scan (length {} bytes, modified {} ns; recorded {} bytes, {} ns)",
        .now.path.display(), .now.len, .now.modified_ns, .recorded.len, .recorded.modified_ns
    )]
    FileChanged { now: FileStamp, recorded: FileStamp },
    #[error("{files} input files; the scan recorded {recorded}")]
    FileCount { files: usize, recorded: usize },
    #[error("the dataset is {width}x{height} samples; the scan recorded {recorded_width}x{recorded_height}")]
    Size { width: u32, height: u32, recorded_width: u32, recorded_height: u32 },
    #[error("the recorded fallback grid is missing or does not match the dataset")]
    Fallback,
    #[error("the scan record has no height range (made by an older build)")]
    NoHeights,
}

/// The shape of a recorded fallback grid (block columns and rows) and its bytes' CRC-32.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct FallbackRecord {
    pub cols: u32,
    pub rows: u32,
    pub crc32: String,
}

fn file_stamps(paths: &[PathBuf]) -> Result<Vec<FileStamp>, RasterError> {
    paths
        .iter()
        .map(|p| {
            let md = std::fs::metadata(p).map_err(|e| RasterError::Io { path: p.clone(), source: e })?;
            let modified_ns = md
                .modified()
                .ok()
                .and_then(|t| t.duration_since(std::time::UNIX_EPOCH).ok())
                .map_or(0, |d| u64::try_from(d.as_nanos()).unwrap_or(u64::MAX));
            Ok(FileStamp { path: p.clone(), len: md.len(), modified_ns })
        })
        .collect()
}

/// A TIFF read chunk by chunk (tiles or strips): decoders of the file come from the process's
/// pool of open files ([`open_files`]), so threads read in parallel and a dataset of many files
/// holds a bounded number open.
struct TiffSource {
    owner: u64,
    chunk: (u32, u32),
    tiles_across: u32,
    nodata: Option<f64>,
    /// The chunks the file leaves out ([`geotiff::Header::sparse`]).
    sparse: Vec<u32>,
    buffer_bytes: u64,
}

impl Drop for TiffSource {
    fn drop(&mut self) {
        open_files::POOL.forget(self.owner);
    }
}

impl BlockSource for TiffSource {
    fn block_size(&self) -> (u32, u32) {
        self.chunk
    }
    fn read_block(&self, path: &Path, bx: u32, by: u32, out: &mut Vec<f32>) -> Result<(), RasterError> {
        let mut dec = if let Some(Handle::Tiff(d)) = open_files::POOL.take(self.owner) {
            d
        } else {
            let file = super::open_input_file(path)?;
            let (dec, h) = geotiff::open(path, BufReader::new(file), self.buffer_bytes)?;
            // Reopened: the file must still be the one opened first.
            if dec.chunk_dimensions() != self.chunk
                || h.nodata.map(f64::to_bits) != self.nodata.map(f64::to_bits)
                || h.sparse != self.sparse
            {
                return Err(RasterError::corrupt(path, "TIFF", "the file changed while being read"));
            }
            Box::new(dec)
        };
        let index = by * self.tiles_across + bx;
        super::guard_decoder(path, "TIFF", || {
            geotiff::extend_chunk_values(path, &mut dec, index, self.nodata, &self.sparse, out)
        })?;
        open_files::POOL.give(self.owner, Handle::Tiff(dec));
        Ok(())
    }
}

/// Rows of an SRTM tile per block.
const HGT_BLOCK_ROWS: u32 = 256;

/// An SRTM tile read by rows, through the pool of open files.
struct HgtSource {
    owner: u64,
    side: u32,
}

impl Drop for HgtSource {
    fn drop(&mut self) {
        open_files::POOL.forget(self.owner);
    }
}

impl BlockSource for HgtSource {
    fn block_size(&self) -> (u32, u32) {
        (self.side, HGT_BLOCK_ROWS)
    }
    fn read_block(&self, path: &Path, _bx: u32, by: u32, out: &mut Vec<f32>) -> Result<(), RasterError> {
        let r0 = by * HGT_BLOCK_ROWS;
        let rows = HGT_BLOCK_ROWS.min(self.side - r0);
        let mut bytes = vec![0u8; rows as usize * self.side as usize * 2];
        let mut f = match open_files::POOL.take(self.owner) {
            Some(Handle::File(f)) => f,
            _ => super::open_input_file(path)?,
        };
        f.seek(SeekFrom::Start(u64::from(r0) * u64::from(self.side) * 2))
            .map_err(|e| RasterError::io(path, e))?;
        f.read_exact(&mut bytes).map_err(|e| {
            if e.kind() == std::io::ErrorKind::UnexpectedEof {
                RasterError::corrupt(path, "SRTM .hgt", "file shrank while being read")
            } else {
                RasterError::io(path, e)
            }
        })?;
        open_files::POOL.give(self.owner, Handle::File(f));
        hgt::extend_values(&bytes, out);
        Ok(())
    }
}

/// A file decoded whole (PNG, OpenEXR), served in blocks.
struct MemorySource {
    width: u32,
    height: u32,
    values: Vec<f32>,
}

impl BlockSource for MemorySource {
    fn block_size(&self) -> (u32, u32) {
        (BLOCK, BLOCK)
    }
    fn read_block(&self, _path: &Path, bx: u32, by: u32, out: &mut Vec<f32>) -> Result<(), RasterError> {
        let (c0, r0) = (bx * BLOCK, by * BLOCK);
        let (c1, r1) = ((c0 + BLOCK).min(self.width), (r0 + BLOCK).min(self.height));
        let w = self.width as usize;
        for r in r0..r1 {
            out.extend_from_slice(&self.values[r as usize * w + c0 as usize..r as usize * w + c1 as usize]);
        }
        Ok(())
    }
}

/// A gridded point cloud served in blocks.
struct LasSource {
    grid: las::Gridded,
    scratch: PathBuf,
}

impl BlockSource for LasSource {
    fn block_size(&self) -> (u32, u32) {
        (las::BLOCK, las::BLOCK)
    }
    fn read_block(&self, _path: &Path, bx: u32, by: u32, out: &mut Vec<f32>) -> Result<(), RasterError> {
        self.grid.read_block(&self.scratch, bx, by, out)
    }
}

type Key = (u32, u32, u32);

/// A least-recently-used cache of blocks, bounded in bytes.
///
/// Evicted blocks are not freed but kept (up to [`SPARE_BUFFERS`]) for the next load to fill:
/// blocks are loaded on one thread and evicted on another, and with glibc a freed block goes
/// back to the arena of the thread that allocated it, so freeing them let every thread's arena
/// grow towards the whole budget (peak RSS grew with the raster; see docs/benchmarks.md). With
/// the buffers reused, the blocks' memory stays at the budget.
struct Cache {
    budget: u64,
    inner: Mutex<CacheInner>,
}

/// Evicted block buffers a cache keeps for reuse (loads take one each; evictions give one
/// back, so a few cover the threads loading at once), and at most 1/[`SPARE_BUDGET_SHARE`] of
/// its budget in them (an `.hgt` block is a whole 256-row strip of the file).
const SPARE_BUFFERS: usize = 16;
const SPARE_BUDGET_SHARE: u64 = 8;

#[derive(Default)]
struct CacheInner {
    map: HashMap<Key, (Arc<Vec<f32>>, u64)>,
    order: BTreeMap<u64, Key>,
    tick: u64,
    bytes: u64,
    spare: Vec<Vec<f32>>,
}

impl CacheInner {
    /// Keeps `buffer` for the next load if the spares stay within their bounds.
    fn keep_spare(&mut self, buffer: Vec<f32>, budget: u64) {
        let held: u64 = self.spare.iter().map(|b| b.capacity() as u64 * 4).sum();
        if self.spare.len() < SPARE_BUFFERS
            && held + buffer.capacity() as u64 * 4 <= budget / SPARE_BUDGET_SHARE
        {
            self.spare.push(buffer);
        }
    }
}

impl Cache {
    fn new(budget: u64) -> Self {
        Self { budget, inner: Mutex::new(CacheInner::default()) }
    }

    /// The block `key`, loaded by `load` (which appends it to the empty buffer it is given)
    /// when it is not cached.
    fn get_or_load(
        &self,
        key: Key,
        load: impl FnOnce(&mut Vec<f32>) -> Result<(), RasterError>,
    ) -> Result<Arc<Vec<f32>>, RasterError> {
        let mut buffer = {
            let mut c = self.inner.lock().unwrap_or_else(PoisonError::into_inner);
            c.tick += 1;
            let tick = c.tick;
            if let Some((block, old)) = c.map.get_mut(&key) {
                let (block, old_tick) = (Arc::clone(block), *old);
                *old = tick;
                c.order.remove(&old_tick);
                c.order.insert(tick, key);
                return Ok(block);
            }
            c.spare.pop().unwrap_or_default()
        };
        // Loaded outside the lock: two threads may load the same block; both get equal data.
        buffer.clear();
        if let Err(e) = load(&mut buffer) {
            self.give_back(buffer);
            return Err(e);
        }
        let block = Arc::new(buffer);
        let size = block.len() as u64 * 4;
        let mut c = self.inner.lock().unwrap_or_else(PoisonError::into_inner);
        c.tick += 1;
        let tick = c.tick;
        if let Some((_, old)) = c.map.insert(key, (Arc::clone(&block), tick)) {
            c.order.remove(&old);
            c.bytes -= size;
        }
        c.order.insert(tick, key);
        c.bytes += size;
        while c.bytes > self.budget {
            let Some((_, oldest)) = c.order.pop_first() else { break };
            if let Some((b, _)) = c.map.remove(&oldest) {
                c.bytes -= b.len() as u64 * 4;
                // A block a reader still holds is freed when it lets go.
                if let Ok(b) = Arc::try_unwrap(b) {
                    c.keep_spare(b, self.budget);
                }
            }
        }
        Ok(block)
    }

    /// Keeps a buffer a failed load was given.
    fn give_back(&self, buffer: Vec<f32>) {
        self.inner.lock().unwrap_or_else(PoisonError::into_inner).keep_spare(buffer, self.budget);
    }
}

/// The fallback grid of a dataset with no-data: (values, block columns, block rows).
struct Fallback {
    grid: Vec<f32>,
    cols: usize,
    rows: usize,
}

/// A dataset opened and scanned: a [`WindowReader`] over its filled heights.
pub struct Dataset {
    width: u32,
    height: u32,
    georef: Georef,
    parts: Vec<Part>,
    raw: Cache,
    filled: Cache,
    fallback: Option<Fallback>,
    summary: DatasetSummary,
    /// A warped dataset: what warping measures as its blocks are read (complete after the scan).
    warp: Option<Arc<Mutex<super::warp::WarpStats>>>,
    /// The lowest and highest height of the dataset (found by the scan).
    heights: Option<(f32, f32)>,
}

/// An input that names no file of a supported kind, or a dataset that cannot be assembled.
fn dataset_error(path: &Path, message: impl Into<String>) -> RasterError {
    RasterError::Dataset { path: path.to_owned(), message: message.into() }
}

/// The format of a file, from its first bytes (and its extension).
fn format_of(path: &Path) -> Result<(File, Format), RasterError> {
    let mut file = super::open_input_file(path)?;
    let mut head = Vec::with_capacity(8);
    (&mut file).take(8).read_to_end(&mut head).map_err(|e| RasterError::io(path, e))?;
    let format = super::detect(path, &head)?;
    file.seek(SeekFrom::Start(0)).map_err(|e| RasterError::io(path, e))?;
    Ok((file, format))
}

/// `g` moved by (`dc`, `dr`) samples.
fn shifted(g: FileGeoref, dc: u32, dr: u32) -> FileGeoref {
    let (dc, dr) = (f64::from(dc), f64::from(dr));
    match g {
        FileGeoref::None => FileGeoref::None,
        FileGeoref::Projected { x0, y0, dx, dy } => {
            FileGeoref::Projected { x0: x0 + dc * dx, y0: y0 + dr * dy, dx, dy }
        }
        FileGeoref::Geographic { lon0, lat0, dlon, dlat } => {
            FileGeoref::Geographic { lon0: lon0 + dc * dlon, lat0: lat0 + dr * dlat, dlon, dlat }
        }
    }
}

/// Opens one input as parts: a raster file is one part; a VRT is one part per source, and its
/// extent goes to `frames` (the dataset covers it even where no source paints).
fn open_input(
    path: &Path,
    opts: &DatasetOptions,
    frames: &mut Vec<(FileGeoref, u32, u32)>,
) -> Result<Vec<(Part, FileGeoref, FileCrs)>, RasterError> {
    let (file, format) = format_of(path)?;
    if format != Format::Vrt {
        return Ok(vec![open_part(path, file, format, opts)?]);
    }
    let len = file.metadata().map_err(|e| RasterError::io(path, e))?.len();
    if len > vrt::MAX_VRT_BYTES {
        return Err(RasterError::unsupported(
            path,
            "GDAL VRT",
            format!("the file is {len} bytes, more than the {} MiB a VRT may have", vrt::MAX_VRT_BYTES >> 20),
        ));
    }
    let mut text = String::new();
    // At most one byte past the limit, whatever the size said (a file that grows).
    BufReader::new(file.take(vrt::MAX_VRT_BYTES + 1)).read_to_string(&mut text).map_err(|e| {
        if e.kind() == std::io::ErrorKind::InvalidData {
            RasterError::corrupt(path, "GDAL VRT", "the file is not UTF-8 text")
        } else {
            RasterError::io(path, e)
        }
    })?;
    if text.len() as u64 > vrt::MAX_VRT_BYTES {
        return Err(RasterError::unsupported(
            path,
            "GDAL VRT",
            format!(
                "the file grew past the {} MiB a VRT may have while being read",
                vrt::MAX_VRT_BYTES >> 20
            ),
        ));
    }
    let v = vrt::parse(path, &text)?;
    frames.push((v.georef, v.width, v.height));
    let mut parts = Vec::with_capacity(v.sources.len());
    for src in &v.sources {
        let (file, format) = format_of(&src.file).map_err(|e| in_vrt(path, &src.element, &e))?;
        if matches!(format, Format::Vrt | Format::Las) {
            return Err(dataset_error(
                path,
                format!(
                    "the {} reads {}, a {}; a VRT's sources must be raster files",
                    src.element,
                    src.file.display(),
                    if format == Format::Vrt { "VRT (nested VRTs are not read)" } else { "point cloud" }
                ),
            ));
        }
        let (mut part, _own_georef, _own_crs) =
            open_part(&src.file, file, format, opts).map_err(|e| in_vrt(path, &src.element, &e))?;
        if let Some((w, h)) = src.whole_file
            && (w, h) != (part.file_width, part.file_height)
        {
            return Err(RasterError::unsupported(
                path,
                "GDAL VRT",
                format!(
                    "the {} has no SrcRect, so it maps all of {} ({}×{}) onto a {w}×{h} DstRect, which needs resampling",
                    src.element,
                    src.file.display(),
                    part.file_width,
                    part.file_height
                ),
            ));
        }
        let (sx, sy, w, h) = src.src;
        if sx >= part.file_width || sy >= part.file_height {
            continue; // the window lies past the file's end: GDAL paints nothing
        }
        part.win_col = sx;
        part.win_row = sy;
        part.width = w.min(part.file_width - sx);
        part.height = h.min(part.file_height - sy);
        part.nodata = src.nodata.iter().filter(|v| !v.is_nan()).map(|&v| v as f32).collect();
        // The VRT's <SRS> says what its grid means; its sources' own keys are not read.
        parts.push((part, shifted(v.georef, src.dst.0, src.dst.1), v.crs.clone()));
    }
    let declared = u64::from(v.width) * u64::from(v.height);
    let covered: u64 = parts.iter().map(|(p, _, _)| u64::from(p.width) * u64::from(p.height)).sum();
    if !opts.allow_sparse && covered > 0 && declared / MAX_SPARSENESS > covered {
        return Err(dataset_error(
            path,
            format!(
                "declares {}×{} samples ({declared}) but its {} sources cover at most {covered}: {:.1} % of it would be \
                 no-data, filled and baked as flat terrain ({} samples for each one of data; at most \
                 {MAX_SPARSENESS} are accepted). Fix the VRT's rasterXSize/rasterYSize, or pass --allow-sparse \
                 to bake it anyway",
                v.width,
                v.height,
                parts.len(),
                100.0 * (1.0 - covered as f64 / declared as f64),
                declared / covered,
            ),
        ));
    }
    Ok(parts)
}

/// An error opening a VRT's source, with the VRT and the element named.
fn in_vrt(vrt_path: &Path, element: &str, e: &RasterError) -> RasterError {
    dataset_error(vrt_path, format!("its {element}: {e}"))
}

/// Opens one raster file as a block source, with its georeference and size.
fn open_part(
    path: &Path,
    file: File,
    format: Format,
    opts: &DatasetOptions,
) -> Result<(Part, FileGeoref, FileCrs), RasterError> {
    let part =
        |source: Box<dyn BlockSource>, format, width, height| whole_part(path, source, format, width, height);
    match format {
        Format::Tiff => {
            // One chunk may take at most a quarter of the cache (and never more than 1 GiB).
            let buffer_bytes = (opts.cache_bytes / 4).clamp(1 << 20, 1 << 30);
            let (dec, h) = geotiff::open(path, BufReader::new(file), buffer_bytes)?;
            let chunk = dec.chunk_dimensions();
            let tiles_across = match dec.get_chunk_type() {
                ChunkType::Tile => h.width.div_ceil(chunk.0.max(1)),
                ChunkType::Strip => 1,
            };
            let chunk_bytes = u64::from(chunk.0) * u64::from(chunk.1) * 8;
            if chunk.0 == 0 || chunk.1 == 0 || chunk_bytes > buffer_bytes {
                return Err(dataset_error(
                    path,
                    format!(
                        "its {} of {}×{} samples is larger than a quarter of the block cache ({} MiB); rewrite \
                         it tiled (gdal_translate -co TILED=YES) or raise --cache-mib",
                        if tiles_across > 1 || dec.get_chunk_type() == ChunkType::Tile {
                            "tile"
                        } else {
                            "strip"
                        },
                        chunk.0,
                        chunk.1,
                        opts.cache_bytes >> 20
                    ),
                ));
            }
            // A sparse file declares chunks it does not store: as a VRT of a vast extent, a few
            // bytes can declare a continent of no-data.
            let chunks = u64::from(tiles_across) * u64::from(h.height.div_ceil(chunk.1.max(1)));
            let stored =
                chunks.saturating_sub(h.sparse.len() as u64) * u64::from(chunk.0) * u64::from(chunk.1);
            let declared = u64::from(h.width) * u64::from(h.height);
            if !h.sparse.is_empty() && !opts.allow_sparse && declared / super::MAX_SPARSENESS > stored {
                return Err(dataset_error(
                    path,
                    format!(
                        "is a sparse GeoTIFF storing {} of its {chunks} {}s: at most {stored} of its {}×{} samples \
                         ({declared}) are stored, the rest would be {} and baked as flat terrain (at most {} \
                         samples for each stored one are accepted); pass --allow-sparse to bake it anyway",
                        chunks - h.sparse.len() as u64,
                        if dec.get_chunk_type() == ChunkType::Tile { "tile" } else { "strip" },
                        h.width,
                        h.height,
                        if h.nodata.is_some() { "no-data, filled" } else { "0" },
                        super::MAX_SPARSENESS,
                    ),
                ));
            }
            let owner = open_files::new_owner();
            open_files::POOL.give(owner, Handle::Tiff(Box::new(dec)));
            let source =
                TiffSource { owner, chunk, tiles_across, nodata: h.nodata, sparse: h.sparse, buffer_bytes };
            Ok((part(Box::new(source), "geotiff", h.width, h.height), h.georef, h.crs))
        }
        Format::Hgt => {
            let (side, georef) = hgt::header(path)?;
            let owner = open_files::new_owner();
            open_files::POOL.give(owner, Handle::File(file));
            let part = part(Box::new(HgtSource { owner, side }), "hgt", side, side);
            Ok((part, georef, hgt::file_crs()))
        }
        Format::Png | Format::Exr => {
            let reader = BufReader::new(file);
            let d = if format == Format::Png {
                super::png::decode(path, reader, &opts.load)?
            } else {
                super::openexr::decode(path, reader, &opts.load)?
            };
            if d.values.len() as u64 != u64::from(d.width) * u64::from(d.height) {
                return Err(RasterError::corrupt(
                    path,
                    d.format,
                    "decoded sample count does not match the size",
                ));
            }
            let src = MemorySource { width: d.width, height: d.height, values: d.values };
            Ok((part(Box::new(src), d.format, d.width, d.height), d.georef, d.crs))
        }
        Format::Vrt | Format::Las => Err(dataset_error(path, "a VRT or point cloud is not one raster file")),
    }
}

/// (kind name, x0, y0, dx, dy) of a file georeference.
fn frame_of(g: FileGeoref) -> (&'static str, f64, f64, f64, f64) {
    match g {
        FileGeoref::None => ("none", 0.0, 0.0, 1.0, 1.0),
        FileGeoref::Projected { x0, y0, dx, dy } => ("projected", x0, y0, dx, dy),
        FileGeoref::Geographic { lon0, lat0, dlon, dlat } => ("geographic", lon0, lat0, dlon, dlat),
    }
}

/// Cell sizes agree when within this relative difference (text-printed tags round).
const CELL_TOLERANCE: f64 = 1e-9;
/// Files are aligned when their offset is within this many cells of a whole number.
const ALIGN_TOLERANCE: f64 = 1e-6;

impl Dataset {
    /// Opens the files of one dataset (in the order given: it decides shared edges), places them
    /// on one grid and scans it. `progress(done, total)` is called per block row of each pass.
    pub fn open(
        paths: &[PathBuf],
        opts: &DatasetOptions,
        progress: &(dyn Fn(&str, u64, u64) + Sync),
    ) -> Result<Self, RasterError> {
        let mut ds = Self::open_unscanned(paths, opts, progress)?;
        ds.scan(progress)?;
        ds.take_warp_figures();
        Ok(ds)
    }

    /// After the scan has read every block once: a warped dataset's measured resampling error
    /// goes into its frame (and so into every tile's error) and its figures into the summary.
    fn take_warp_figures(&mut self) {
        if let Some(w) = &self.warp {
            let s = *w.lock().unwrap_or_else(PoisonError::into_inner);
            self.georef.resample_error = s.max_twist;
            self.summary.warp = Some(s);
        }
    }

    /// Opens the dataset as [`Dataset::open`] does, taking what its scan finds from `record`
    /// (made by [`Dataset::scan_record`] of the same files, with `fallback` its fallback grid's
    /// bytes) instead of reading every sample: what the shards of a sharded bake do, its plan
    /// having scanned once. `Ok(Err(why))` when the record cannot stand for these files — a
    /// file's length or modification time differs from the record's, the record does not fit
    /// the dataset, or the inputs are point clouds (gridded on every open) — and the caller
    /// scans instead (the checksum then tells whether the heights changed).
    pub fn open_scanned(
        paths: &[PathBuf],
        opts: &DatasetOptions,
        record: &ScanRecord,
        fallback: Option<&[u8]>,
        progress: &(dyn Fn(&str, u64, u64) + Sync),
    ) -> Result<Result<Self, ScanMismatch>, RasterError> {
        if paths.iter().any(|p| format_of(p).is_ok_and(|(_, f)| f == Format::Las)) {
            return Ok(Err(ScanMismatch::PointClouds));
        }
        let mut ds = Self::open_unscanned(paths, opts, progress)?;
        if ds.warp.is_some() {
            return Ok(Err(ScanMismatch::Warped));
        }
        let stamps = ds.stamps()?;
        if let Some((now, then)) = stamps.iter().zip(&record.files).find(|(a, b)| a != b) {
            return Ok(Err(ScanMismatch::FileChanged { now: now.clone(), recorded: then.clone() }));
        }
        if stamps.len() != record.files.len() {
            return Ok(Err(ScanMismatch::FileCount { files: stamps.len(), recorded: record.files.len() }));
        }
        if (ds.width, ds.height) != (record.width, record.height) {
            return Ok(Err(ScanMismatch::Size {
                width: ds.width,
                height: ds.height,
                recorded_width: record.width,
                recorded_height: record.height,
            }));
        }
        let (bc, br) = (ds.width.div_ceil(BLOCK), ds.height.div_ceil(BLOCK));
        match (&record.fallback, fallback) {
            (None, _) if record.nodata_filled == 0 => {}
            (Some(f), Some(bytes))
                if (f.cols, f.rows) == (bc, br)
                    && bytes.len() as u64 == u64::from(bc) * u64::from(br) * 4
                    && format!("{:08x}", crc32fast::hash(bytes)) == f.crc32 =>
            {
                let grid =
                    bytes.chunks_exact(4).map(|b| f32::from_le_bytes([b[0], b[1], b[2], b[3]])).collect();
                ds.fallback = Some(Fallback { grid, cols: bc as usize, rows: br as usize });
            }
            _ => {
                return Ok(Err(ScanMismatch::Fallback));
            }
        }
        let Some([lo, hi]) = record.heights.filter(|[lo, hi]| lo <= hi) else {
            return Ok(Err(ScanMismatch::NoHeights));
        };
        ds.summary.nodata_filled = record.nodata_filled;
        ds.summary.nodata_fallback = record.nodata_fallback;
        ds.summary.crc32.clone_from(&record.crc32);
        ds.heights = Some((lo, hi));
        Ok(Ok(ds))
    }

    /// What the scan found, for [`Dataset::open_scanned`]: the record and the fallback grid's
    /// bytes (little-endian f32, block rows top to bottom), when the dataset has no-data.
    pub fn scan_record(&self) -> Result<(ScanRecord, Option<Vec<u8>>), RasterError> {
        let bytes =
            self.fallback.as_ref().map(|f| f.grid.iter().flat_map(|v| v.to_le_bytes()).collect::<Vec<u8>>());
        let record = ScanRecord {
            files: self.stamps()?,
            width: self.width,
            height: self.height,
            nodata_filled: self.summary.nodata_filled,
            nodata_fallback: self.summary.nodata_fallback,
            crc32: self.summary.crc32.clone(),
            fallback: self.fallback.as_ref().zip(bytes.as_ref()).map(|(f, b)| FallbackRecord {
                cols: f.cols as u32,
                rows: f.rows as u32,
                crc32: format!("{:08x}", crc32fast::hash(b)),
            }),
            heights: self.heights.map(|(lo, hi)| [lo, hi]),
        };
        Ok((record, bytes))
    }

    /// Stamps of the files given and of the files they name (a VRT's sources), each once.
    fn stamps(&self) -> Result<Vec<FileStamp>, RasterError> {
        let mut seen: std::collections::HashSet<&Path> = std::collections::HashSet::new();
        let paths: Vec<PathBuf> = self
            .summary
            .files
            .iter()
            .chain(self.parts.iter().map(|p| &p.path))
            .filter(|p| seen.insert(p.as_path()))
            .cloned()
            .collect();
        file_stamps(&paths)
    }

    /// Everything [`Dataset::open`] does but the scan.
    fn open_unscanned(
        paths: &[PathBuf],
        opts: &DatasetOptions,
        progress: &(dyn Fn(&str, u64, u64) + Sync),
    ) -> Result<Self, RasterError> {
        let Some(first_path) = paths.first() else {
            return Err(dataset_error(Path::new("bake"), "no input files"));
        };
        super::validate_overrides(first_path, &opts.load.overrides)?;
        // `--encoding` is a PNG's: refused when no input is one (or a VRT, whose sources may be).
        if opts.load.encoding.is_some() {
            let formats: Vec<(&PathBuf, Format)> =
                paths.iter().filter_map(|p| format_of(p).ok().map(|(_, f)| (p, f))).collect();
            if let Some((p, f)) = formats.first()
                && formats.iter().all(|(_, f)| !matches!(f, Format::Png | Format::Vrt))
            {
                super::check_encoding(p, *f, &opts.load)?;
            }
        }
        if opts.cache_bytes < MIN_CACHE_BYTES {
            return Err(dataset_error(
                first_path,
                format!(
                    "block cache of {} bytes is below the minimum of {MIN_CACHE_BYTES}",
                    opts.cache_bytes
                ),
            ));
        }
        let mut parts = Vec::with_capacity(paths.len());
        let mut georefs = Vec::with_capacity(paths.len());
        let mut crss: Vec<(PathBuf, FileCrs)> = Vec::with_capacity(paths.len());
        let mut frames = Vec::new();
        let mut points = None;
        let las_files: Vec<&PathBuf> =
            paths.iter().filter(|p| format_of(p).is_ok_and(|(_, f)| f == Format::Las)).collect();
        if las_files.is_empty() {
            for p in paths {
                for (part, g, c) in open_input(p, opts, &mut frames)? {
                    parts.push(part);
                    georefs.push(g);
                    crss.push((p.clone(), c));
                }
            }
        } else {
            if let Some(other) = paths.iter().find(|p| !las_files.contains(p)) {
                return Err(dataset_error(
                    other,
                    format!(
                        "is a raster but {} is a point cloud; bake point clouds and rasters separately",
                        las_files[0].display()
                    ),
                ));
            }
            let cell = opts.load.overrides.cell_size.unwrap_or(f64::NAN);
            let scratch = opts.scratch.clone().unwrap_or_else(std::env::temp_dir);
            let grid = las::grid(paths, cell, &scratch, opts.allow_sparse, progress)?;
            let format = match grid.stats.compressed_files {
                0 => "las",
                n if n == paths.len() => "laz",
                _ => "las+laz",
            };
            let (w, h, g) = (grid.width, grid.height, grid.georef);
            let grid_crs = grid.crs.clone();
            points = Some(grid.stats.clone());
            let source = LasSource { grid, scratch };
            parts.push(whole_part(first_path, Box::new(source), format, w, h));
            georefs.push(g);
            crss.push((first_path.clone(), grid_crs));
        }
        if parts.is_empty() {
            return Err(dataset_error(first_path, "no source of the VRT lies inside its files"));
        }
        // Inputs in several CRSs (or --target-crs another one) are warped onto one grid.
        let o = &opts.load.overrides;
        if o.crs.is_some() {
            for (_, c) in &mut crss {
                c.horizontal.clone_from(&o.crs);
            }
        }
        let first_crs = crss.first().and_then(|c| c.1.horizontal.clone());
        let differ = crss.iter().any(|(_, c)| c.horizontal != first_crs);
        let retarget = o.target_crs.is_some() && o.target_crs != first_crs;
        let mut warp_stats = None;
        if points.is_none() && (differ || retarget) {
            let (part, georef, crs, stats) =
                super::warp::warp(std::mem::take(&mut parts), &georefs, &crss, o.target_crs.clone())?;
            parts = vec![part];
            georefs = vec![georef];
            crss = vec![(first_path.clone(), crs)];
            frames.clear();
            warp_stats = Some(stats);
        }
        unwrap_longitudes(&parts, &mut georefs);
        let (width, height, file_georef) = place(&mut parts, &georefs, &frames)?;
        if width < 2 || height < 2 {
            return Err(dataset_error(
                first_path,
                format!(
                    "{} {width}×{height} samples; a heightfield needs at least 2×2 to be tiled",
                    if paths.len() == 1 { "is" } else { "the dataset is" }
                ),
            ));
        }
        // Files far apart make a dataset of mostly no-data, as a VRT of a vast extent does.
        let declared = u64::from(width) * u64::from(height);
        let covered: u64 = parts.iter().map(|p| u64::from(p.width) * u64::from(p.height)).sum();
        if !opts.allow_sparse && covered > 0 && declared / MAX_SPARSENESS > covered {
            return Err(dataset_error(
                first_path,
                format!(
                    "its {} inputs span {width}×{height} samples ({declared}) but cover at most {covered}: {:.1} % of \
                     the dataset would be no-data, filled and baked as flat terrain ({} samples for each one of data; \
                     at most {MAX_SPARSENESS} are accepted). Bake the files apart, or pass --allow-sparse to bake \
                     them together anyway",
                    parts.len(),
                    100.0 * (1.0 - covered as f64 / declared as f64),
                    declared / covered,
                ),
            ));
        }
        let file_crs = crss.first().map(|c| c.1.clone()).unwrap_or_default();
        // Point clouds: --cell-size is the gridding cell, not an override of a georeference.
        let overrides = if points.is_some() {
            super::Overrides { cell_size: None, ..opts.load.overrides.clone() }
        } else {
            opts.load.overrides.clone()
        };
        let mut georef = super::base_georef(first_path, file_georef, &file_crs, &overrides, width, height)?;
        super::apply_overrides(&mut georef, &overrides);
        super::check_frame(first_path, &georef, &overrides, width, height)?;

        let (_, x0, y0, dx, dy) = frame_of(file_georef);
        let far = |o: f64, d: f64, n: u32| o + d * f64::from(n - 1);
        let (xa, xb, ya, yb) = (x0, far(x0, dx, width), y0, far(y0, dy, height));
        let extent = [xa.min(xb), ya.min(yb), xa.max(xb), ya.max(yb)];
        let vertical = georef.crs.as_ref().map(|_| georef.vertical);
        let crs_name = match &georef.crs {
            Some(g) => g.crs.definition().to_owned(),
            None if matches!(file_georef, FileGeoref::None) => "none".to_owned(),
            None => "local".to_owned(),
        };
        let formats: Vec<&str> = parts.iter().map(|p| p.format).collect();
        let format = if formats.iter().all(|f| *f == formats[0]) { formats[0] } else { "mixed" };
        // Half to the files' blocks, half to the filled dataset blocks.
        let ds = Self {
            width,
            height,
            georef,
            parts,
            raw: Cache::new(opts.cache_bytes / 2),
            filled: Cache::new(opts.cache_bytes / 2),
            fallback: None,
            summary: DatasetSummary {
                files: paths.to_vec(),
                format: format.to_owned(),
                width,
                height,
                crs: crs_name,
                vertical,
                extent,
                nodata_filled: 0,
                nodata_fallback: 0,
                crc32: String::new(),
                points,
                warp: None,
            },
            warp: warp_stats,
            heights: None,
        };
        Ok(ds)
    }

    #[must_use]
    pub fn georef(&self) -> &Georef {
        &self.georef
    }

    #[must_use]
    pub fn summary(&self) -> &DatasetSummary {
        &self.summary
    }

    /// The file holding dataset sample (col, row), for messages (the first one placed there).
    fn file_at(&self, col: u32, row: u32) -> &Path {
        self.parts
            .iter()
            .find(|p| (p.col..p.col + p.width).contains(&col) && (p.row..p.row + p.height).contains(&row))
            .map_or_else(|| self.parts[0].path.as_path(), |p| p.path.as_path())
    }

    /// Raw samples (no-data NaN, no z scale) of the window at (c0, r0) of `w × h` samples.
    fn raw_window(&self, c0: u32, r0: u32, w: u32, h: u32) -> Result<Vec<f32>, RasterError> {
        let mut out = Vec::new();
        self.raw_window_into(c0, r0, w, h, &mut out)?;
        Ok(out)
    }

    /// [`Self::raw_window`] written to `out`, which is resized to the window.
    fn raw_window_into(
        &self,
        c0: u32,
        r0: u32,
        w: u32,
        h: u32,
        out: &mut Vec<f32>,
    ) -> Result<(), RasterError> {
        out.clear();
        out.resize(w as usize * h as usize, f32::NAN);
        for (pi, part) in self.parts.iter().enumerate() {
            // The intersection in dataset coordinates.
            let (x0, x1) = (c0.max(part.col), (c0 + w).min(part.col + part.width));
            let (y0, y1) = (r0.max(part.row), (r0 + h).min(part.row + part.height));
            if x0 >= x1 || y0 >= y1 {
                continue;
            }
            let (bw, bh) = part.source.block_size();
            // The intersection in file coordinates.
            let (fx0, fx1) = (x0 - part.col + part.win_col, x1 - part.col + part.win_col);
            let (fy0, fy1) = (y0 - part.row + part.win_row, y1 - part.row + part.win_row);
            // Dataset column of file column fx: fx + shift_x (as i64: a window may start inside).
            let (shift_x, shift_y) = (
                i64::from(part.col) - i64::from(part.win_col),
                i64::from(part.row) - i64::from(part.win_row),
            );
            for by in fy0 / bh..=(fy1 - 1) / bh {
                for bx in fx0 / bw..=(fx1 - 1) / bw {
                    let key = (pi as u32, bx, by);
                    let block =
                        self.raw.get_or_load(key, |out| part.source.read_block(&part.path, bx, by, out))?;
                    let cw = bw.min(part.file_width - bx * bw);
                    let ch = bh.min(part.file_height - by * bh);
                    if block.len() != cw as usize * ch as usize {
                        return Err(RasterError::corrupt(
                            &part.path,
                            part.format,
                            format!("block ({bx}, {by}) holds {} samples, expected {cw}×{ch}", block.len()),
                        ));
                    }
                    let (bc0, br0) = (bx * bw, by * bh);
                    for fy in fy0.max(br0)..fy1.min(br0 + ch) {
                        let src = &block[((fy - br0) * cw) as usize..][..cw as usize];
                        let orow = (i64::from(fy) + shift_y - i64::from(r0)) as usize * w as usize;
                        for fx in fx0.max(bc0)..fx1.min(bc0 + cw) {
                            let o = &mut out[orow + (i64::from(fx) + shift_x - i64::from(c0)) as usize];
                            let v = src[(fx - bc0) as usize];
                            if o.is_nan() && !part.nodata.contains(&v) {
                                *o = v;
                            }
                        }
                    }
                }
            }
        }
        Ok(())
    }

    /// (c0, r0, w, h) of dataset block (bx, by).
    fn block_rect(&self, bx: u32, by: u32) -> (u32, u32, u32, u32) {
        let (c0, r0) = (bx * BLOCK, by * BLOCK);
        (c0, r0, BLOCK.min(self.width - c0), BLOCK.min(self.height - r0))
    }

    /// Dataset block (bx, by): filled and with the z scale applied.
    fn filled_block(&self, bx: u32, by: u32) -> Result<Arc<Vec<f32>>, RasterError> {
        self.filled.get_or_load((u32::MAX, bx, by), |v| {
            let (c0, r0, w, h) = self.block_rect(bx, by);
            self.raw_window_into(c0, r0, w, h, v)?;
            if v.iter().any(|x| !x.is_finite()) {
                self.fill_block(c0, r0, w, h, v)?;
            }
            let g = &self.georef;
            for x in v.iter_mut() {
                *x = (g.z0 + f64::from(*x) * g.dz) as f32;
            }
            Ok(())
        })
    }

    /// Fills the no-data of one block (`v`, raw) from a window with a halo of [`FILL_REACH`],
    /// then from the fallback grid.
    fn fill_block(&self, c0: u32, r0: u32, w: u32, h: u32, v: &mut [f32]) -> Result<(), RasterError> {
        let reach = FILL_REACH as u32;
        let (hc0, hr0) = (c0.saturating_sub(reach), r0.saturating_sub(reach));
        let (hc1, hr1) = ((c0 + w + reach).min(self.width), (r0 + h + reach).min(self.height));
        let (hw, hh) = (hc1 - hc0, hr1 - hr0);
        let mut win = self.raw_window(hc0, hr0, hw, hh)?;
        nodata::fill_within(hw as usize, hh as usize, &mut win, FILL_REACH);
        for r in 0..h {
            for c in 0..w {
                let x = win[((r + r0 - hr0) * hw + (c + c0 - hc0)) as usize];
                let cell = &mut v[(r * w + c) as usize];
                *cell = if x.is_finite() {
                    x
                } else if let Some(f) = &self.fallback {
                    nodata::fallback_at(&f.grid, f.cols, f.rows, u64::from(c0 + c), u64::from(r0 + r))
                } else {
                    x
                };
            }
        }
        Ok(())
    }

    /// The opening scan: no-data count, fallback grid, height limits, checksum.
    fn scan(&mut self, progress: &(dyn Fn(&str, u64, u64) + Sync)) -> Result<(), RasterError> {
        // Per block: (no-data count, mean, min z, max z).
        type Stats = (u64, f32, f32, f32);
        let (bc, br) = (self.width.div_ceil(BLOCK), self.height.div_ceil(BLOCK));
        let g = self.georef.clone();
        let mut means = Vec::with_capacity(bc as usize * br as usize);
        let (mut nodata, mut min, mut max) = (0u64, f32::INFINITY, f32::NEG_INFINITY);
        let mut crc = crc32fast::Hasher::new();
        for by in 0..br {
            let blocks: Vec<(Vec<f32>, Stats)> = (0..bc)
                .into_par_iter()
                .map(|bx| {
                    let (c0, r0, w, h) = self.block_rect(bx, by);
                    let mut v = self.raw_window(c0, r0, w, h)?;
                    let missing = v.iter().filter(|x| !x.is_finite()).count() as u64;
                    let mean = nodata::block_mean(v.iter().copied());
                    let (mut lo, mut hi) = (f32::INFINITY, f32::NEG_INFINITY);
                    for (i, x) in v.iter_mut().enumerate() {
                        if !x.is_finite() {
                            continue;
                        }
                        let z = (g.z0 + f64::from(*x) * g.dz) as f32;
                        if !z.is_finite() || f64::from(z).abs() > MAX_HEIGHT {
                            let (c, r) = (c0 + i as u32 % w, r0 + i as u32 / w);
                            return Err(RasterError::OutOfLimits {
                                path: self.file_at(c, r).to_owned(),
                                message: format!(
                                    "dataset sample at column {c}, row {r} has height {z:?} (raw {x:?}, z scale {:?}, \
                                     offset {:?}), beyond the supported ±{MAX_HEIGHT:e}; is it an undeclared no-data \
                                     value?",
                                    g.dz, g.z0
                                ),
                            });
                        }
                        lo = lo.min(z);
                        hi = hi.max(z);
                        *x = z;
                    }
                    Ok((v, (missing, mean, lo, hi)))
                })
                .collect::<Result<_, RasterError>>()?;
            for (_, (missing, mean, lo, hi)) in &blocks {
                nodata += missing;
                means.push(*mean);
                min = min.min(*lo);
                max = max.max(*hi);
            }
            if nodata == 0 {
                hash_rows(
                    &mut crc,
                    &blocks.iter().map(|(v, _)| v.as_slice()).collect::<Vec<_>>(),
                    self.width,
                );
            }
            progress("scanning", u64::from(by) + 1, u64::from(br));
        }
        if nodata == u64::from(self.width) * u64::from(self.height) {
            return Err(RasterError::AllNoData { path: self.parts[0].path.clone(), samples: nodata });
        }
        let cell = g.dx.abs().min(g.dy.abs());
        let relief = f64::from(max) - f64::from(min);
        if relief > MAX_RELIEF_CELLS * cell {
            return Err(RasterError::OutOfLimits {
                path: self.parts[0].path.clone(),
                message: format!(
                    "heights span {min:?}..{max:?} ({relief:?} world units), more than {MAX_RELIEF_CELLS} cells of \
                     {cell:?}; check the cell size and the z scale (heights and cells must be in the same units)"
                ),
            });
        }
        // No-data is filled from its neighbours' values (weighted means), so within these too.
        self.heights = Some((min, max));
        self.summary.nodata_filled = nodata;
        if nodata > 0 {
            let grid = nodata::fallback_grid(bc as usize, br as usize, means).ok_or_else(|| {
                RasterError::AllNoData { path: self.parts[0].path.clone(), samples: nodata }
            })?;
            self.fallback = Some(Fallback { grid, cols: bc as usize, rows: br as usize });
            crc = crc32fast::Hasher::new();
            let mut beyond = 0u64;
            for by in 0..br {
                let blocks: Vec<(Arc<Vec<f32>>, u64)> = (0..bc)
                    .into_par_iter()
                    .map(|bx| {
                        let (c0, r0, w, h) = self.block_rect(bx, by);
                        let filled = self.filled_block(bx, by)?;
                        // Count the cells the reach did not get to (the fill is recomputed here
                        // only for blocks with no-data).
                        let raw = self.raw_window(c0, r0, w, h)?;
                        let mut n = 0;
                        if raw.iter().any(|x| !x.is_finite()) {
                            let reach = FILL_REACH as u32;
                            let (hc0, hr0) = (c0.saturating_sub(reach), r0.saturating_sub(reach));
                            let (hc1, hr1) =
                                ((c0 + w + reach).min(self.width), (r0 + h + reach).min(self.height));
                            let mut win = self.raw_window(hc0, hr0, hc1 - hc0, hr1 - hr0)?;
                            nodata::fill_within(
                                (hc1 - hc0) as usize,
                                (hr1 - hr0) as usize,
                                &mut win,
                                FILL_REACH,
                            );
                            for r in r0..r0 + h {
                                for c in c0..c0 + w {
                                    n += u64::from(
                                        !win[((r - hr0) * (hc1 - hc0) + (c - hc0)) as usize].is_finite(),
                                    );
                                }
                            }
                        }
                        Ok((filled, n))
                    })
                    .collect::<Result<_, RasterError>>()?;
                beyond += blocks.iter().map(|b| b.1).sum::<u64>();
                hash_rows(
                    &mut crc,
                    &blocks.iter().map(|(v, _)| v.as_slice()).collect::<Vec<_>>(),
                    self.width,
                );
                progress("filling no-data", u64::from(by) + 1, u64::from(br));
            }
            self.summary.nodata_fallback = beyond;
        }
        self.summary.crc32 = format!("{:08x}", crc.finalize());
        Ok(())
    }
}

/// Feeds the rows of one block row (its blocks left to right) to the checksum, row-major.
fn hash_rows(crc: &mut crc32fast::Hasher, blocks: &[&[f32]], width: u32) {
    let Some(first) = blocks.first() else { return };
    let bw0 = BLOCK.min(width) as usize;
    let rows = first.len() / bw0.max(1);
    let mut bytes = Vec::with_capacity(width as usize * 4);
    for r in 0..rows {
        bytes.clear();
        for (bx, b) in blocks.iter().enumerate() {
            let w = (BLOCK.min(width - bx as u32 * BLOCK)) as usize;
            bytes.extend(b[r * w..(r + 1) * w].iter().flat_map(|v| v.to_le_bytes()));
        }
        crc.update(&bytes);
    }
}

/// Places the parts on one grid: checks CRS kind, cell size, alignment and overlaps; returns
/// the dataset size and its georeference (that of sample (0, 0)).
/// Geographic files whose longitudes are written in another turn of the circle (a mosaic across
/// the antimeridian: 179.5°..180° beside −180°..−179.5°, or 0–360 beside −180–180) are moved by
/// whole turns to lie next to the first file: each file's centre within 180° of the first's.
fn unwrap_longitudes(parts: &[Part], georefs: &mut [FileGeoref]) {
    let centre = |g: &FileGeoref, p: &Part| match *g {
        FileGeoref::Geographic { lon0, dlon, .. } => {
            Some(lon0 + dlon * f64::from(p.width.saturating_sub(1)) / 2.0)
        }
        _ => None,
    };
    let Some(first) = georefs.first().zip(parts.first()).and_then(|(g, p)| centre(g, p)) else { return };
    for (g, p) in georefs.iter_mut().zip(parts) {
        if let (Some(c), FileGeoref::Geographic { lon0, .. }) = (centre(g, p), g) {
            let turns = ((first - c) / 360.0).round();
            *lon0 += turns * 360.0;
        }
    }
}

fn place(
    parts: &mut [Part],
    georefs: &[FileGeoref],
    frames: &[(FileGeoref, u32, u32)],
) -> Result<(u32, u32, FileGeoref), RasterError> {
    let (kind, _, _, dx, dy) = frame_of(georefs[0]);
    if parts.len() > 1 {
        for (p, &g) in parts.iter().zip(georefs) {
            let (k, _, _, pdx, pdy) = frame_of(g);
            if k == "none" {
                return Err(dataset_error(
                    &p.path,
                    "has no georeference; every file of a mosaic must say where it lies (GeoTIFF tags or an SRTM name)",
                ));
            }
            if k != kind {
                return Err(dataset_error(
                    &p.path,
                    format!(
                        "is {k} but {} is {kind}; a dataset's files must share the CRS kind",
                        parts[0].path.display()
                    ),
                ));
            }
            let close = |a: f64, b: f64| (a - b).abs() <= CELL_TOLERANCE * a.abs().max(b.abs());
            if !(close(pdx, dx) && close(pdy, dy)) {
                return Err(dataset_error(
                    &p.path,
                    format!(
                        "has cells of {pdx:?} × {pdy:?} but {} has {dx:?} × {dy:?}; a dataset's files must share the \
                         cell size",
                        parts[0].path.display()
                    ),
                ));
            }
        }
    }
    // The dataset's sample (0, 0): the smallest offset along each axis's direction.
    let (_, mut ox, mut oy, _, _) = frame_of(georefs[0]);
    for &g in georefs.iter().chain(frames.iter().map(|f| &f.0)) {
        let (_, x, y, _, _) = frame_of(g);
        if (x - ox) / dx < 0.0 {
            ox = x;
        }
        if (y - oy) / dy < 0.0 {
            oy = y;
        }
    }
    let (mut width, mut height) = (0u64, 0u64);
    let first_name = parts[0].path.display().to_string();
    for (p, &g) in parts.iter_mut().zip(georefs) {
        let (_, x, y, _, _) = frame_of(g);
        let (fc, fr) = ((x - ox) / dx, (y - oy) / dy);
        let (c, r) = (fc.round(), fr.round());
        if (fc - c).abs() > ALIGN_TOLERANCE || (fr - r).abs() > ALIGN_TOLERANCE {
            return Err(dataset_error(
                &p.path,
                format!(
                    "is not aligned with the grid of {first_name}: its first sample lies {fc:.6} columns, {fr:.6} rows \
                     from the dataset's; files must share the grid (resample it first)"
                ),
            ));
        }
        if c + f64::from(p.width) > f64::from(MAX_DATASET_SIDE)
            || r + f64::from(p.height) > f64::from(MAX_DATASET_SIDE)
        {
            return Err(dataset_error(
                &p.path,
                format!(
                    "lies {c} columns, {r} rows into the dataset, beyond {MAX_DATASET_SIDE} samples per side"
                ),
            ));
        }
        p.col = c as u32;
        p.row = r as u32;
        width = width.max(u64::from(p.col) + u64::from(p.width));
        height = height.max(u64::from(p.row) + u64::from(p.height));
    }
    // A VRT covers its whole extent (its own grid is its sources', so it is aligned).
    for &(g, w, h) in frames {
        let (_, x, y, _, _) = frame_of(g);
        let (c, r) = (((x - ox) / dx).round(), ((y - oy) / dy).round());
        width = width.max((c + f64::from(w)) as u64);
        height = height.max((r + f64::from(h)) as u64);
    }
    if width > u64::from(MAX_DATASET_SIDE) || height > u64::from(MAX_DATASET_SIDE) {
        return Err(dataset_error(
            &parts[0].path,
            format!("the dataset is {width}×{height} samples, beyond {MAX_DATASET_SIDE} per side"),
        ));
    }
    for (i, a) in parts.iter().enumerate() {
        for b in &parts[..i] {
            let iw = (a.col + a.width).min(b.col + b.width).saturating_sub(a.col.max(b.col));
            let ih = (a.row + a.height).min(b.row + b.height).saturating_sub(a.row.max(b.row));
            if iw > 1 && ih > 1 {
                return Err(dataset_error(
                    &a.path,
                    format!(
                        "overlaps {} by {iw}×{ih} samples; files may share an edge of one sample, not more",
                        b.path.display()
                    ),
                ));
            }
        }
    }
    let file_georef = match georefs[0] {
        FileGeoref::None => FileGeoref::None,
        FileGeoref::Projected { .. } => FileGeoref::Projected { x0: ox, y0: oy, dx, dy },
        FileGeoref::Geographic { .. } => FileGeoref::Geographic { lon0: ox, lat0: oy, dlon: dx, dlat: dy },
    };
    Ok((width as u32, height as u32, file_georef))
}

impl WindowReader for Dataset {
    fn size(&self) -> (u32, u32) {
        (self.width, self.height)
    }

    fn height_range(&self) -> Option<(f32, f32)> {
        self.heights
    }

    fn read_window(&self, cols: &[u32], rows: &[u32], out: &mut Vec<f32>) -> Result<(), RasterError> {
        out.clear();
        out.reserve(cols.len() * rows.len());
        // The distinct block columns, and each column's (block index, column within it).
        let mut bxs: Vec<u32> = cols.iter().map(|&c| c / BLOCK).collect();
        bxs.sort_unstable();
        bxs.dedup();
        let at: Vec<(usize, usize)> =
            cols.iter().map(|&c| (bxs.partition_point(|&b| b < c / BLOCK), (c % BLOCK) as usize)).collect();
        let mut i = 0;
        while i < rows.len() {
            let by = rows[i] / BLOCK;
            let end = rows[i..].iter().position(|&r| r / BLOCK != by).map_or(rows.len(), |p| i + p);
            let blocks: Vec<(Arc<Vec<f32>>, usize)> = bxs
                .iter()
                .map(|&bx| Ok((self.filled_block(bx, by)?, self.block_rect(bx, by).2 as usize)))
                .collect::<Result<_, RasterError>>()?;
            for &r in &rows[i..end] {
                let lr = (r % BLOCK) as usize;
                out.extend(at.iter().map(|&(b, lc)| {
                    let (block, w) = &blocks[b];
                    block[lr * w + lc]
                }));
            }
            i = end;
        }
        Ok(())
    }
}

/// The files an input names: a file itself; a directory's raster and point-cloud files (`.tif`,
/// `.tiff`, `.hgt`, `.png`, `.exr`, `.vrt`, `.las`, `.laz`; not recursive); or a pattern whose last component holds `*` or `?`. Directory
/// and pattern matches are sorted by name.
pub fn expand_inputs(inputs: &[PathBuf]) -> Result<Vec<PathBuf>, RasterError> {
    const EXTS: [&str; 8] = ["tif", "tiff", "hgt", "png", "exr", "vrt", "las", "laz"];
    let mut out = Vec::new();
    for input in inputs {
        let name = input.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_default();
        let list_dir = |dir: &Path, keep: &dyn Fn(&Path) -> bool| -> Result<Vec<PathBuf>, RasterError> {
            let mut v: Vec<PathBuf> = std::fs::read_dir(dir)
                .map_err(|e| RasterError::io(dir, e))?
                .filter_map(Result::ok)
                .map(|e| e.path())
                .filter(|p| p.is_file() && keep(p))
                .collect();
            v.sort();
            Ok(v)
        };
        if name.contains(['*', '?']) {
            let dir = input.parent().filter(|d| !d.as_os_str().is_empty()).unwrap_or(Path::new("."));
            let found = list_dir(dir, &|p: &Path| {
                p.file_name().is_some_and(|n| glob_match(name.as_bytes(), n.to_string_lossy().as_bytes()))
            })?;
            if found.is_empty() {
                return Err(dataset_error(input, "the pattern matches no file"));
            }
            out.extend(found);
        } else if input.is_dir() {
            let found = list_dir(input, &|p: &Path| {
                p.extension().is_some_and(|e| EXTS.iter().any(|x| e.eq_ignore_ascii_case(x)))
            })?;
            if found.is_empty() {
                return Err(dataset_error(
                    input,
                    "the directory holds no .tif, .tiff, .hgt, .png, .exr, .vrt, .las or .laz file",
                ));
            }
            out.extend(found);
        } else {
            out.push(input.clone());
        }
    }
    Ok(out)
}

/// `*` (any run) and `?` (one character) against a file name.
fn glob_match(pat: &[u8], name: &[u8]) -> bool {
    // Iterative with one backtrack point: linear in practice, bounded by |pat|·|name|.
    let (mut p, mut n, mut star, mut mark) = (0, 0, None, 0);
    while n < name.len() {
        if p < pat.len() && (pat[p] == b'?' || pat[p] == name[n]) {
            p += 1;
            n += 1;
        } else if p < pat.len() && pat[p] == b'*' {
            star = Some(p);
            mark = n;
            p += 1;
        } else if let Some(s) = star {
            p = s + 1;
            mark += 1;
            n = mark;
        } else {
            return false;
        }
    }
    pat[p..].iter().all(|&c| c == b'*')
}

#[cfg(test)]
mod tests {
    use super::*;

    fn block(seed: u32, len: usize) -> Vec<f32> {
        (0..len).map(|i| (seed * 1000 + i as u32) as f32).collect()
    }

    /// The cache stays within its budget, gives every block its own values whatever buffer it
    /// was loaded into (a reused one is emptied first), and reuses evicted buffers instead of
    /// allocating: after warming up, a load's buffer already has the capacity of a block.
    #[test]
    fn cache_reuses_evicted_buffers_and_keeps_values_and_budget() {
        let len = 1000;
        let cache = Cache::new(16 * len as u64 * 4);
        let mut fresh = 0;
        for round in 0..3u32 {
            for k in 0..40u32 {
                let got = cache
                    .get_or_load((0, k, 0), |out| {
                        assert!(out.is_empty());
                        fresh += usize::from(out.capacity() == 0);
                        out.extend(block(k, len));
                        Ok(())
                    })
                    .unwrap();
                assert_eq!(*got, block(k, len), "round {round}, block {k}");
                let c = cache.inner.lock().unwrap();
                assert!(c.bytes <= cache.budget);
                assert!(c.spare.len() <= SPARE_BUFFERS);
                let held: usize = c.spare.iter().map(Vec::capacity).sum();
                assert!(held as u64 * 4 <= cache.budget / SPARE_BUDGET_SHARE);
            }
        }
        // 120 loads (40 blocks, 16 cached, cycled three times): a fresh buffer for the first 17
        // only (the 17th load is the first to evict), the rest reuse.
        assert_eq!(fresh, 17);
        // A failed load is an error and its buffer goes back for the next load.
        let spare_before = cache.inner.lock().unwrap().spare.len();
        let e = cache.get_or_load((0, 99, 0), |out| {
            out.push(1.0);
            Err(RasterError::corrupt(Path::new("x.tif"), "TIFF", "bad block"))
        });
        assert!(e.is_err());
        assert_eq!(cache.inner.lock().unwrap().spare.len(), spare_before.max(1));
        let got = cache.get_or_load((0, 99, 0), |out| {
            out.extend(block(99, 3));
            Ok(())
        });
        assert_eq!(*got.unwrap(), block(99, 3));
    }

    /// The fallback grid's length follows from the record's shape only when that shape is the
    /// recorded dataset's (so a damaged record cannot ask for a large read).
    #[test]
    fn fallback_len_only_for_a_shape_that_fits() {
        let record = |width, height, cols, rows| ScanRecord {
            files: vec![],
            width,
            height,
            nodata_filled: 1,
            nodata_fallback: 1,
            crc32: String::new(),
            fallback: Some(FallbackRecord { cols, rows, crc32: String::new() }),
            heights: Some([0.0, 1.0]),
        };
        assert_eq!(record(600, 400, 3, 2).fallback_len(), Some(24));
        assert_eq!(record(600, 400, 3, 3).fallback_len(), None);
        let side = MAX_DATASET_SIDE / BLOCK;
        assert_eq!(record(MAX_DATASET_SIDE, 1, side, 1).fallback_len(), Some(u64::from(side) * 4));
        assert_eq!(
            record(u32::MAX, u32::MAX, u32::MAX / BLOCK + 1, u32::MAX / BLOCK + 1).fallback_len(),
            None
        );
        assert_eq!(ScanRecord { fallback: None, ..record(600, 400, 3, 2) }.fallback_len(), None);
    }

    /// A sparse GeoTIFF read block by block gives what the whole-file decode gives.
    #[test]
    fn sparse_tiffs_read_block_by_block_as_whole() {
        let dir = tempfile::tempdir().unwrap();
        let (w, h) = (40, 36);
        let data: Vec<u16> = (0..w * h).map(|i| (i % 977) as u16 + 100).collect();
        let p = crate::raster::test_util::sparse_tiff(dir.path(), w, h, 16, &data, &[0, 4, 8], Some("-9999"));
        let whole = crate::raster::test_util::load(&p).unwrap();
        let ds = Dataset::open(std::slice::from_ref(&p), &DatasetOptions::default(), &|_, _, _| {}).unwrap();
        let (cols, rows): (Vec<u32>, Vec<u32>) = ((0..w).collect(), (0..h).collect());
        let mut got = Vec::new();
        ds.read_window(&cols, &rows, &mut got).unwrap();
        assert_eq!(got, whole.heights.data);
        assert_eq!(ds.summary().nodata_filled, whole.nodata_filled);
    }

    /// A sparse file storing 1 of 100 tiles declares 100 times its data: refused as a VRT of a
    /// vast extent is, unless --allow-sparse.
    #[test]
    fn mostly_missing_sparse_files_are_refused_unless_allowed() {
        let dir = tempfile::tempdir().unwrap();
        let (w, h) = (160, 160);
        let data = vec![7_u16; (w * h) as usize];
        let skip: Vec<usize> = (1..100).collect();
        let p = crate::raster::test_util::sparse_tiff(dir.path(), w, h, 16, &data, &skip, Some("0"));
        let e =
            Dataset::open(std::slice::from_ref(&p), &DatasetOptions::default(), &|_, _, _| {}).err().unwrap();
        let msg = e.to_string();
        assert!(
            msg.contains("tiled.tif") && msg.contains("sparse") && msg.contains("--allow-sparse"),
            "{msg}"
        );
        let opts = DatasetOptions { allow_sparse: true, ..DatasetOptions::default() };
        let ds = Dataset::open(&[p], &opts, &|_, _, _| {}).unwrap();
        assert_eq!(ds.summary().nodata_filled, u64::from(w * h) - 256);
    }
}
