//! LiDAR point clouds (LAS 1.0–1.4 and LAZ) gridded into a heightfield, out of core.
//!
//! **Grid.** Cells of `cell` world units whose centres lie on whole multiples of the cell size
//! (so tiles of one survey gridded apart share a grid): a point at (x, y) belongs to the cell
//! centred at (round(x / cell)·cell, round(y / cell)·cell). The grid spans the union of the
//! files' header bounds, north up, in the files' coordinates (`--cell-size` in their units).
//!
//! **Coordinate system.** Each file's CRS comes from its (extended) VLRs: the WKT record
//! (`LASF_Projection` 2112, read by [`Crs::parse`]) when the header's WKT bit is set or it is the
//! only CRS record, else the GeoTIFF keys (`LASF_Projection` 34735–34737, read as a GeoTIFF's are:
//! [`super::geotiff::geokeys`]). All files must state the same CRS; `--crs` replaces one that was
//! read. Heights are the points' z, in metres (a GeoKey VLR stating other vertical units is
//! refused).
//!
//! **Rule.** A file is *classified* when it holds at least one ground point (ASPRS class 2). Of a
//! classified file only the ground points count, and a cell takes their **mean**: ground returns
//! sample one surface, and the mean averages their range noise. Of an unclassified file every
//! point counts, and a cell takes the **minimum**: vegetation, buildings and wires lie above the
//! ground, never below it, so the lowest return is the best estimate of the terrain (its risk, a
//! low outlier, is what classification would have removed). A cell with ground points takes
//! their mean; otherwise the minimum of the unclassified files' points; otherwise it is no-data,
//! filled like any raster's.
//!
//! **Out of core.** One streaming pass reads every file in batches and appends each point's cell
//! to a scratch file, bucketed by rows of [`BUCKET_ROWS`] cells. Each bucket is then reduced in
//! memory (in column ranges when it is wide, so the memory stays bounded) and written to a
//! scratch raster of [`BLOCK`]² blocks, which the dataset reads like any other file. The scratch
//! files are unnamed temporaries: they vanish when the dataset is dropped or the process dies.
//!
//! **Checks.** Before any point is read, each header is checked: a point count of zero, scales
//! that are not finite and positive (or absurdly large or small), offsets and bounds that are not
//! finite or out of order, a grid beyond the dataset's side limit, and (for LAS) a file shorter
//! than its header's point records. While reading, a file that ends early, a point outside its
//! header's bounds or a decoder failure stops the bake with an error naming the file.

use std::fs::File;
use std::io::{BufReader, Read, Seek, SeekFrom, Write};
use std::path::{Path, PathBuf};
use std::sync::{Mutex, PoisonError};

use super::geotiff::geokeys::{self, GeoKeys};
use super::{FileCrs, FileGeoref, RasterError};
use crate::crs::Crs;

/// Side of a block of the scratch raster (the dataset's block).
pub const BLOCK: u32 = 256;
/// Rows of cells per bucket of the point pass.
pub const BUCKET_ROWS: u32 = BLOCK;
/// Largest grid side, in cells.
const MAX_SIDE: u64 = 1 << 20;
/// Points decoded per batch.
const BATCH: u64 = 1 << 20;
/// Memory for the buckets' write buffers, all together, in bytes.
const BUCKET_BUFFERS: usize = 64 << 20;
/// Most points a bake reads, all files together: every point takes [`RECORD`] bytes of scratch
/// (2^36 points: 1.25 TiB), and a header's count is checked against it before reading.
pub const MAX_POINTS: u64 = 1 << 36;
/// The point data record formats LAS 1.0–1.4 define (LAZ sets bit 7, some writers bit 6 too).
const MAX_POINT_FORMAT: u8 = 10;
/// Bytes of a VLR's header, and of an EVLR's: the least each one takes.
const VLR_HEADER: u64 = 54;
const EVLR_HEADER: u64 = 60;
/// Memory for reducing one bucket, in bytes (the column range is narrowed to fit).
const REDUCE_BYTES: u64 = 256 << 20;
/// Bytes per point record in the scratch file: column u32, row u32, z f64, file u32 (top bit:
/// ground).
const RECORD: usize = 20;
/// Bytes per cell while reducing: ground sum f64, ground count u32, minimum f32.
const CELL_BYTES: u64 = 16;

const FORMAT_LAS: &str = "LAS";
const FORMAT_LAZ: &str = "LAZ";

/// What the point pass read, for the dataset summary.
#[derive(Debug, Clone, Default, PartialEq, Eq, serde::Serialize)]
pub struct PointStats {
    /// Points in the files.
    pub points: u64,
    /// Points that counted (ground points of classified files, all points of the others).
    pub used: u64,
    /// Files holding ground points (class 2).
    pub classified_files: usize,
    /// Files compressed (LAZ).
    pub compressed_files: usize,
    /// Cells that got a value (the rest are no-data, filled).
    pub cells_with_points: u64,
}

/// A gridded point cloud: a scratch raster of [`BLOCK`]² blocks, row-major blocks, each block
/// row-major and full size (edge blocks padded).
pub struct Gridded {
    pub width: u32,
    pub height: u32,
    pub(crate) georef: FileGeoref,
    /// The coordinate system the files' VLRs state.
    pub(crate) crs: FileCrs,
    pub stats: PointStats,
    raster: Mutex<File>,
}

/// One file's header facts, checked.
#[derive(Debug, Clone, Copy)]
struct HeaderFacts {
    points: u64,
    min: (f64, f64),
    max: (f64, f64),
    compressed: bool,
}

fn bad(path: &Path, compressed: bool, message: impl Into<String>) -> RasterError {
    RasterError::corrupt(path, if compressed { FORMAT_LAZ } else { FORMAT_LAS }, message)
}

/// Checks a raw header against the file's length (pure).
fn check_header(path: &Path, h: &las::raw::Header, file_len: u64) -> Result<HeaderFacts, RasterError> {
    let format = h.point_data_record_format;
    if format & 0x3f > MAX_POINT_FORMAT {
        // Not a LAZ file either: LAZ marks one of the defined formats with bit 7 (or 6).
        return Err(RasterError::unsupported(
            path,
            FORMAT_LAS,
            format!(
                "point data record format {format} is not one LAS defines (0 to {MAX_POINT_FORMAT}; LAZ sets bit \
                 128 on one of them)"
            ),
        ));
    }
    let compressed = format & 0xc0 != 0;
    let bad = |m: String| bad(path, compressed, m);
    let points = h.large_file.map_or(u64::from(h.number_of_point_records), |l| {
        if l.number_of_point_records == 0 {
            u64::from(h.number_of_point_records)
        } else {
            l.number_of_point_records
        }
    });
    if points == 0 {
        return Err(bad("the header says it holds zero points; there is nothing to grid".into()));
    }
    if points > MAX_POINTS {
        return Err(RasterError::unsupported(
            path,
            if compressed { FORMAT_LAZ } else { FORMAT_LAS },
            format!(
                "the header says it holds {points} points, more than the {MAX_POINTS} a bake reads (each takes \
                 {RECORD} bytes of scratch space); split the cloud, or its point count is wrong"
            ),
        ));
    }
    // The records' offsets and counts, before a reader seeks to them or allocates by them.
    let header_size = u64::from(h.header_size);
    let point_data = u64::from(h.offset_to_point_data);
    if point_data > file_len || point_data < header_size {
        return Err(bad(format!(
            "the point data starts at byte {point_data}, outside the file's {file_len} bytes after its {header_size}-byte header"
        )));
    }
    let vlrs = u64::from(h.number_of_variable_length_records);
    if vlrs.saturating_mul(VLR_HEADER) > point_data - header_size {
        return Err(bad(format!(
            "the header says it has {vlrs} variable length records, but only {} bytes lie between the header and the \
             point data ({VLR_HEADER} bytes each at least)",
            point_data - header_size
        )));
    }
    if let Some(e) = h.evlr.filter(|e| e.number_of_evlrs > 0) {
        let room = file_len.saturating_sub(e.start_of_first_evlr);
        if e.start_of_first_evlr < point_data
            || e.start_of_first_evlr > file_len
            || u64::from(e.number_of_evlrs).saturating_mul(EVLR_HEADER) > room
        {
            return Err(bad(format!(
                "the header says it has {} extended variable length records from byte {}, which do not fit the file's \
                 {file_len} bytes after its point data (byte {point_data})",
                e.number_of_evlrs, e.start_of_first_evlr
            )));
        }
    }
    for (axis, s, o) in [
        ("x", h.x_scale_factor, h.x_offset),
        ("y", h.y_scale_factor, h.y_offset),
        ("z", h.z_scale_factor, h.z_offset),
    ] {
        if !(s.is_finite() && (1e-12..=1e3).contains(&s)) {
            return Err(bad(format!("{axis} scale factor {s:?} is not a positive number in 1e-12..=1e3")));
        }
        if !(o.is_finite() && o.abs() <= 1e10) {
            return Err(bad(format!("{axis} offset {o:?} is not a finite number within ±1e10")));
        }
    }
    for (axis, lo, hi) in [("x", h.min_x, h.max_x), ("y", h.min_y, h.max_y), ("z", h.min_z, h.max_z)] {
        if !(lo.is_finite() && hi.is_finite() && lo <= hi && lo.abs() <= 1e10 && hi.abs() <= 1e10) {
            return Err(bad(format!(
                "{axis} bounds {lo:?}..{hi:?} are not finite, ordered and within ±1e10"
            )));
        }
    }
    let record = u64::from(h.point_data_record_length);
    if record == 0 {
        return Err(bad("the point record length is zero".into()));
    }
    if !compressed {
        let need = u64::from(h.offset_to_point_data).saturating_add(points.saturating_mul(record));
        if need > file_len {
            return Err(bad(format!(
                "the header says {points} points of {record} bytes from byte {}, which needs {need} bytes, but the \
                 file has {file_len}; it is truncated or its point count is wrong",
                h.offset_to_point_data
            )));
        }
    }
    Ok(HeaderFacts { points, min: (h.min_x, h.min_y), max: (h.max_x, h.max_y), compressed })
}

/// The `LASF_Projection` record ids: WKT, and the GeoTIFF key directory, doubles and ASCII.
const WKT_RECORD: u16 = 2112;
const GEO_KEY_RECORD: u16 = 34735;

/// The coordinate system a file's (E)VLRs state: the WKT record when the header's WKT bit says
/// so or it is the only CRS record, else the GeoTIFF keys; none without either.
fn crs_of_header(path: &Path, h: &las::Header) -> Result<FileCrs, RasterError> {
    let record = |id: u16| {
        h.all_vlrs()
            .find(|v| {
                v.record_id == id && v.user_id.trim_end_matches('\0').eq_ignore_ascii_case("LASF_Projection")
            })
            .map(|v| v.data.as_slice())
    };
    let refuse = |message: String| RasterError::Crs { path: path.to_owned(), message };
    let keys = record(GEO_KEY_RECORD);
    if let Some(wkt) = record(WKT_RECORD).filter(|_| h.has_wkt_crs() || keys.is_none()) {
        let text = String::from_utf8_lossy(wkt);
        let text = text.trim_matches(|c: char| c == '\0' || c.is_whitespace());
        let (horizontal, vertical) = Crs::parse(text)
            .map_err(|e| refuse(format!("the WKT VLR (LASF_Projection {WKT_RECORD}): {e}")))?;
        return Ok(FileCrs { horizontal: Some(horizontal), vertical });
    }
    let Some(dir) = keys else { return Ok(FileCrs::default()) };
    let dir: Vec<u16> = dir.chunks_exact(2).map(|b| u16::from_le_bytes([b[0], b[1]])).collect();
    let doubles: Vec<f64> = record(geokeys::GEO_DOUBLE_PARAMS).map_or_else(Vec::new, |b| {
        b.chunks_exact(8).map(|b| f64::from_le_bytes(b.try_into().unwrap_or([0; 8]))).collect()
    });
    let ascii = record(geokeys::GEO_ASCII_PARAMS).map(String::from_utf8_lossy).unwrap_or_default();
    let k = geokeys::read(&GeoKeys { dir: &dir, doubles: &doubles, ascii: &ascii })
        .map_err(|m| refuse(format!("the GeoKey VLRs (LASF_Projection {GEO_KEY_RECORD}): {m}")))?;
    if (k.degrees_per_unit - 1.0).abs() > f64::EPSILON {
        return Err(refuse(format!(
            "the GeoKey VLRs: GeogAngularUnitsGeoKey gives {}° per unit; point coordinates must be in \
             degrees",
            k.degrees_per_unit
        )));
    }
    Ok(k.crs)
}

/// The grid of a set of header bounds: (first column index, last row index, width, height) in
/// whole cells, or an error when it is beyond the side limit.
fn grid_of(first: &Path, facts: &[HeaderFacts], cell: f64) -> Result<(i64, i64, u32, u32), RasterError> {
    let (mut x0, mut y0, mut x1, mut y1) =
        (f64::INFINITY, f64::INFINITY, f64::NEG_INFINITY, f64::NEG_INFINITY);
    for f in facts {
        x0 = x0.min(f.min.0);
        y0 = y0.min(f.min.1);
        x1 = x1.max(f.max.0);
        y1 = y1.max(f.max.1);
    }
    let (c0, c1, r0, r1) =
        ((x0 / cell).round(), (x1 / cell).round(), (y0 / cell).round(), (y1 / cell).round());
    let (w, h) = (c1 - c0 + 1.0, r1 - r0 + 1.0);
    if !(w.is_finite() && h.is_finite()) || w > MAX_SIDE as f64 || h > MAX_SIDE as f64 {
        return Err(RasterError::Dataset {
            path: first.to_owned(),
            message: format!(
                "the points span x {x0}..{x1}, y {y0}..{y1}: at --cell-size {cell} that is a grid of {w}×{h} cells, \
                 beyond {MAX_SIDE} per side; use a larger cell size or fewer files"
            ),
        });
    }
    Ok((c0 as i64, r1 as i64, w as u32, h as u32))
}

/// Appends records to per-bucket chunks of one scratch file.
struct Buckets {
    file: File,
    end: u64,
    cap: usize,
    buffers: Vec<Vec<u8>>,
    /// Per bucket: (offset, length) of its chunks in the file.
    chunks: Vec<Vec<(u64, u32)>>,
}

impl Buckets {
    fn new(file: File, count: usize) -> Self {
        let cap = (BUCKET_BUFFERS / count.max(1)).clamp(4 << 10, 1 << 20) / RECORD * RECORD;
        Self { file, end: 0, cap, buffers: vec![Vec::new(); count], chunks: vec![Vec::new(); count] }
    }

    fn push(&mut self, bucket: usize, record: &[u8; RECORD]) -> std::io::Result<()> {
        let buf = &mut self.buffers[bucket];
        if buf.capacity() == 0 {
            buf.reserve_exact(self.cap);
        }
        buf.extend_from_slice(record);
        if buf.len() + RECORD > self.cap {
            self.flush(bucket)?;
        }
        Ok(())
    }

    fn flush(&mut self, bucket: usize) -> std::io::Result<()> {
        let buf = &mut self.buffers[bucket];
        if buf.is_empty() {
            return Ok(());
        }
        self.file.write_all(buf)?;
        self.chunks[bucket].push((self.end, buf.len() as u32));
        self.end += buf.len() as u64;
        buf.clear();
        Ok(())
    }

    fn flush_all(&mut self) -> std::io::Result<()> {
        for b in 0..self.buffers.len() {
            self.flush(b)?;
            self.buffers[b] = Vec::new();
        }
        self.file.flush()
    }
}

/// Per-cell accumulator of one bucket's column range.
#[derive(Clone, Copy)]
struct Cell {
    sum: f64,
    count: u32,
    min: f32,
}

const EMPTY: Cell = Cell { sum: 0.0, count: 0, min: f32::INFINITY };

impl Cell {
    /// The rule: the ground mean, else the minimum of unclassified files' points, else no-data.
    fn value(self) -> f32 {
        if self.count > 0 {
            (self.sum / f64::from(self.count)) as f32
        } else if self.min.is_finite() {
            self.min
        } else {
            f32::NAN
        }
    }
}

/// Grids the point clouds at `paths` into cells of `cell`, with scratch files in `scratch`.
/// `progress(stage, done, total)` reports points read, then bucket rows reduced.
pub fn grid(
    paths: &[PathBuf],
    cell: f64,
    scratch: &Path,
    allow_sparse: bool,
    progress: &(dyn Fn(&str, u64, u64) + Sync),
) -> Result<Gridded, RasterError> {
    let first = paths.first().map_or(Path::new("bake"), PathBuf::as_path);
    if !(cell.is_finite() && cell > 0.0) {
        return Err(RasterError::Dataset {
            path: first.to_owned(),
            message: "LAS/LAZ input needs --cell-size (the grid's cell, in the points' units)".into(),
        });
    }
    let mut facts = Vec::with_capacity(paths.len());
    let mut crs: Option<FileCrs> = None;
    for p in paths {
        let mut f = super::open_input_file(p)?;
        let len = f.metadata().map_err(|e| RasterError::io(p, e))?.len();
        let raw = las::raw::Header::read_from(BufReader::new(&mut f))
            .map_err(|e| bad(p, false, format!("cannot read the header: {e}")))?;
        let fact = check_header(p, &raw, len)?;
        // The header again with its (E)VLRs, for the coordinate system.
        f.seek(SeekFrom::Start(0)).map_err(|e| RasterError::io(p, e))?;
        let format = if fact.compressed { FORMAT_LAZ } else { FORMAT_LAS };
        let header = super::guard_decoder(p, format, || {
            las::Header::new(BufReader::new(&mut f))
                .map_err(|e| bad(p, fact.compressed, format!("cannot read the header's records: {e}")))
        })?;
        let this = crs_of_header(p, &header)?;
        match &crs {
            None => crs = Some(this),
            Some(first_crs) if *first_crs != this => {
                let name = |c: &FileCrs| {
                    let h = c.horizontal.as_ref().map_or("no CRS", Crs::definition);
                    c.vertical.map_or_else(|| h.to_owned(), |v| format!("{h} with {} heights", v.name()))
                };
                return Err(RasterError::Dataset {
                    path: p.clone(),
                    message: format!(
                        "is in {} but {} is in {}; point clouds gridded together must share one coordinate system",
                        name(&this),
                        first.display(),
                        name(first_crs),
                    ),
                });
            }
            Some(_) => {}
        }
        facts.push(fact);
    }
    let total: u64 = facts.iter().fold(0u64, |t, f| t.saturating_add(f.points));
    if total > MAX_POINTS {
        return Err(RasterError::Dataset {
            path: first.to_owned(),
            message: format!(
                "the {} files' headers say they hold {total} points, more than the {MAX_POINTS} a bake reads (each \
                 takes {RECORD} bytes of scratch space); bake them in parts",
                paths.len()
            ),
        });
    }
    let (c0, rtop, width, height) = grid_of(first, &facts, cell)?;
    let cells = u64::from(width) * u64::from(height);
    if !allow_sparse && cells / super::MAX_SPARSENESS > total {
        return Err(RasterError::Dataset {
            path: first.to_owned(),
            message: format!(
                "at --cell-size {cell} the points make a grid of {width}×{height} cells ({cells}) but there are only \
                 {total} points: at least {:.1} % of it would be no-data, filled and baked as flat terrain (at most \
                 {} cells per point are accepted). Use a larger --cell-size, or pass --allow-sparse to grid it anyway",
                100.0 * (1.0 - total as f64 / cells as f64),
                super::MAX_SPARSENESS
            ),
        });
    }
    let scratch_err = |e: std::io::Error| RasterError::io(scratch, e);
    let bucket_count = height.div_ceil(BUCKET_ROWS) as usize;
    let mut buckets = Buckets::new(tempfile::tempfile_in(scratch).map_err(scratch_err)?, bucket_count);
    let compressed_files = facts.iter().filter(|f| f.compressed).count();
    let mut stats = PointStats { points: total, compressed_files, ..PointStats::default() };
    let mut classified = vec![false; paths.len()];
    let mut done = 0u64;
    for (fi, (p, f)) in paths.iter().zip(&facts).enumerate() {
        let bad = |m: String| bad(p, f.compressed, m);
        let file = super::open_input_file(p)?;
        let format = if f.compressed { FORMAT_LAZ } else { FORMAT_LAS };
        let mut reader = super::guard_decoder(p, format, || {
            las::Reader::new(BufReader::with_capacity(1 << 20, file))
                .map_err(|e| bad(format!("cannot open: {e}")))
        })?;
        let mut data = las::PointDataBuilder::new().for_header(reader.header()).build();
        // Points may lie a rounding step outside the header's bounds.
        let tol = (cell * 0.5).max(1e-6);
        let mut read = 0u64;
        while read < f.points {
            let n = super::guard_decoder(p, format, || {
                reader.fill_points(BATCH.min(f.points - read), &mut data).map_err(|e| {
                    bad(format!(
                        "reading points {read}.. of {}: {e} (truncated or a wrong point count?)",
                        f.points
                    ))
                })
            })?;
            if n == 0 {
                return Err(bad(format!(
                    "the header says {} points but the file ends after {read}; it is truncated or its point count is \
                     wrong",
                    f.points
                )));
            }
            for (i, (((x, y), z), class)) in
                data.x().zip(data.y()).zip(data.z()).zip(data.classification()).enumerate()
            {
                let outside =
                    x < f.min.0 - tol || x > f.max.0 + tol || y < f.min.1 - tol || y > f.max.1 + tol;
                if outside || !z.is_finite() {
                    return Err(bad(format!(
                        "point {} at ({x}, {y}, {z}) lies outside the header's bounds x {}..{}, y {}..{}",
                        read + i as u64,
                        f.min.0,
                        f.max.0,
                        f.min.1,
                        f.max.1
                    )));
                }
                // In range: the header bounds are inside the grid, and the tolerance is half a cell.
                let col = ((x / cell).round() as i64 - c0).clamp(0, i64::from(width) - 1) as u32;
                let row = (rtop - (y / cell).round() as i64).clamp(0, i64::from(height) - 1) as u32;
                let ground = class == 2;
                classified[fi] |= ground;
                let mut rec = [0u8; RECORD];
                rec[0..4].copy_from_slice(&col.to_le_bytes());
                rec[4..8].copy_from_slice(&row.to_le_bytes());
                rec[8..16].copy_from_slice(&z.to_le_bytes());
                rec[16..20].copy_from_slice(&(fi as u32 | u32::from(ground) << 31).to_le_bytes());
                buckets.push((row / BUCKET_ROWS) as usize, &rec).map_err(scratch_err)?;
            }
            read += n;
            done += n;
            progress("reading points", done, total);
        }
    }
    buckets.flush_all().map_err(scratch_err)?;
    stats.classified_files = classified.iter().filter(|c| **c).count();

    // Reduce bucket by bucket into the scratch raster.
    let mut raster = tempfile::tempfile_in(scratch).map_err(scratch_err)?;
    let (bc, block_len) = (width.div_ceil(BLOCK) as usize, BLOCK as usize * BLOCK as usize);
    let range_cols =
        ((REDUCE_BYTES / (CELL_BYTES * u64::from(BUCKET_ROWS))) as u32 / BLOCK * BLOCK).max(BLOCK);
    let mut bytes = Vec::new();
    for (b, chunks) in buckets.chunks.iter().enumerate() {
        let r0 = b as u32 * BUCKET_ROWS;
        let rows = BUCKET_ROWS.min(height - r0) as usize;
        let mut cs = 0u32;
        while cs < width {
            let ce = (cs + range_cols).min(width);
            let cw = (ce - cs) as usize;
            let mut cells = vec![EMPTY; cw * rows];
            for &(off, len) in chunks {
                bytes.resize(len as usize, 0);
                buckets.file.seek(SeekFrom::Start(off)).map_err(scratch_err)?;
                buckets.file.read_exact(&mut bytes).map_err(scratch_err)?;
                for rec in bytes.chunks_exact(RECORD) {
                    let word = |i: usize| u32::from_le_bytes([rec[i], rec[i + 1], rec[i + 2], rec[i + 3]]);
                    let (col, row, meta) = (word(0), word(4), word(16));
                    if !(cs..ce).contains(&col) {
                        continue;
                    }
                    let z = f64::from_le_bytes(rec[8..16].try_into().unwrap_or([0; 8]));
                    let (file, ground) = ((meta & !(1 << 31)) as usize, meta >> 31 == 1);
                    let c = &mut cells[(row - r0) as usize * cw + (col - cs) as usize];
                    if classified[file] {
                        if ground {
                            c.sum += z;
                            c.count += 1;
                            stats.used += 1;
                        }
                    } else {
                        c.min = c.min.min(z as f32);
                        stats.used += 1;
                    }
                }
            }
            // The range's blocks, whole (the range is a multiple of BLOCK wide), padded with NaN.
            let blocks = cw.div_ceil(BLOCK as usize);
            let mut out = vec![f32::NAN; blocks * block_len];
            for r in 0..rows {
                for c in 0..cw {
                    let v = cells[r * cw + c].value();
                    stats.cells_with_points += u64::from(!v.is_nan());
                    out[(c / BLOCK as usize) * block_len + r * BLOCK as usize + c % BLOCK as usize] = v;
                }
            }
            let first_block = (b * bc + (cs / BLOCK) as usize) as u64;
            raster.seek(SeekFrom::Start(first_block * block_len as u64 * 4)).map_err(scratch_err)?;
            let block_bytes: Vec<u8> = out.iter().flat_map(|v| v.to_le_bytes()).collect();
            raster.write_all(&block_bytes).map_err(scratch_err)?;
            cs = ce;
        }
        progress("gridding points", b as u64 + 1, bucket_count as u64);
    }
    raster.flush().map_err(scratch_err)?;
    let georef = FileGeoref::Projected { x0: c0 as f64 * cell, y0: rtop as f64 * cell, dx: cell, dy: -cell };
    Ok(Gridded { width, height, georef, crs: crs.unwrap_or_default(), stats, raster: Mutex::new(raster) })
}

impl Gridded {
    /// Block (bx, by) of the grid, clipped at the right and bottom edges; no-data as NaN;
    /// appended to `v`.
    pub fn read_block(&self, scratch: &Path, bx: u32, by: u32, v: &mut Vec<f32>) -> Result<(), RasterError> {
        let bc = u64::from(self.width.div_ceil(BLOCK));
        let block_len = u64::from(BLOCK) * u64::from(BLOCK);
        let mut bytes = vec![0u8; block_len as usize * 4];
        {
            let mut f = self.raster.lock().unwrap_or_else(PoisonError::into_inner);
            f.seek(SeekFrom::Start((u64::from(by) * bc + u64::from(bx)) * block_len * 4))
                .map_err(|e| RasterError::io(scratch, e))?;
            f.read_exact(&mut bytes).map_err(|e| RasterError::io(scratch, e))?;
        }
        let (cw, ch) =
            (BLOCK.min(self.width - bx * BLOCK) as usize, BLOCK.min(self.height - by * BLOCK) as usize);
        v.reserve(cw * ch);
        for r in 0..ch {
            let row = &bytes[r * BLOCK as usize * 4..][..cw * 4];
            v.extend(row.chunks_exact(4).map(|b| f32::from_le_bytes([b[0], b[1], b[2], b[3]])));
        }
        Ok(())
    }
}
