//! TIFF/`GeoTIFF` heightfields via the `tiff` crate: one band of any integer or float sample type,
//! in strips or tiles, with the georeference taken from `ModelPixelScale` + `ModelTiepoint` (or a
//! rotation-free `ModelTransformation`), the model type and the coordinate system from the
//! GeoKeys ([`geokeys`]: EPSG codes and user-defined CRSs, units, the vertical datum), and the
//! no-data value from `GDAL_NODATA`.
//!
//! Pixel convention: `GeoTIFF` places raster coordinate (0, 0) at the outer corner of the first
//! pixel when `GTRasterTypeGeoKey` is `PixelIsArea` (the default) and at its centre for
//! `PixelIsPoint`. Our frame puts `x0, y0` at the *centre* of sample (0, 0), so `PixelIsArea`
//! files are shifted by half a cell. A geographic model's coordinates are converted from
//! `GeogAngularUnitsGeoKey`'s unit to degrees.

use std::io::{Read, Seek};
use std::path::Path;

use tiff::decoder::{ChunkType, Decoder, DecodingResult};
use tiff::tags::Tag;
use tiff::{ColorType, TiffError, TiffFormatError};

use super::{Decoded, FileCrs, FileGeoref, Limits, RasterError, check_size};

pub(crate) mod geokeys;
use geokeys::{GeoKeys, KeysCrs, MODEL_GEOGRAPHIC, MODEL_PROJECTED};

const FORMAT: &str = "TIFF";

const RASTER_PIXEL_IS_POINT: u16 = 2;

pub(super) fn map_err(path: &Path, e: TiffError) -> RasterError {
    match e {
        TiffError::FormatError(TiffFormatError::InvalidDimensions(w, h)) if w == 0 || h == 0 => {
            RasterError::ZeroSize { path: path.to_owned(), width: w.into(), height: h.into() }
        }
        TiffError::UnsupportedError(u) => RasterError::unsupported(path, FORMAT, u.to_string()),
        TiffError::LimitsExceeded => {
            RasterError::unsupported(path, FORMAT, "a tag or chunk exceeds the decoder's memory limits")
        }
        TiffError::IoError(io) if io.kind() == std::io::ErrorKind::UnexpectedEof => {
            RasterError::corrupt(path, FORMAT, format!("unexpected end of file ({io})"))
        }
        TiffError::IoError(io) => RasterError::io(path, io),
        other => RasterError::corrupt(path, FORMAT, other.to_string()),
    }
}

/// The coordinate system of a TIFF's GeoKeys ([`geokeys`]): the directory and its double and
/// ASCII value tags. A key whose value is not supported is refused, naming the key and the value.
fn keys_of<R: Read + Seek>(path: &Path, dec: &mut Decoder<R>) -> Result<KeysCrs, RasterError> {
    let Some(dir) = dec.find_tag(Tag::GeoKeyDirectoryTag).map_err(|e| map_err(path, e))? else {
        return Ok(KeysCrs::default());
    };
    let dir = dir.into_u16_vec().map_err(|e| map_err(path, e))?;
    let doubles = match dec.find_tag(Tag::GeoDoubleParamsTag).map_err(|e| map_err(path, e))? {
        Some(v) => v.into_f64_vec().map_err(|e| map_err(path, e))?,
        None => Vec::new(),
    };
    let ascii = match dec.find_tag(Tag::GeoAsciiParamsTag).map_err(|e| map_err(path, e))? {
        Some(v) => v.into_string().map_err(|e| map_err(path, e))?,
        None => String::new(),
    };
    geokeys::read(&GeoKeys { dir: &dir, doubles: &doubles, ascii: &ascii })
        .map_err(|message| RasterError::Crs { path: path.to_owned(), message })
}

/// The affine map from raster coordinates (I, J) to model (X, Y) without rotation:
/// `X = ax + I·sx`, `Y = ay + J·sy`.
struct Affine {
    ax: f64,
    sx: f64,
    ay: f64,
    sy: f64,
}

fn affine<R: Read + Seek>(path: &Path, dec: &mut Decoder<R>) -> Result<Option<Affine>, RasterError> {
    let f64s = |dec: &mut Decoder<R>, tag| -> Result<Option<Vec<f64>>, RasterError> {
        dec.find_tag(tag)
            .and_then(|v| v.map(tiff::decoder::ifd::Value::into_f64_vec).transpose())
            .map_err(|e| map_err(path, e))
    };
    let scale = f64s(dec, Tag::ModelPixelScaleTag)?;
    let tie = f64s(dec, Tag::ModelTiepointTag)?;
    let transform = f64s(dec, Tag::ModelTransformationTag)?;
    let short = |what: &str| RasterError::corrupt(path, FORMAT, format!("{what} tag has too few values"));
    match (scale, tie, transform) {
        (Some(scale), tie, _) => {
            let &[sx, sy, ..] = scale.as_slice() else { return Err(short("ModelPixelScale")) };
            // No tiepoint: raster (0, 0) sits at the model origin.
            let (i, j, x, y) = match tie.as_deref() {
                None => (0.0, 0.0, 0.0, 0.0),
                Some(&[i, j, _, x, y, ..]) => (i, j, x, y),
                Some(_) => return Err(short("ModelTiepoint")),
            };
            Ok(Some(Affine { ax: x - i * sx, sx, ay: y + j * sy, sy: -sy }))
        }
        (None, _, Some(m)) => {
            if m.len() < 16 {
                return Err(short("ModelTransformation"));
            }
            if m[1] != 0.0 || m[4] != 0.0 {
                return Err(RasterError::unsupported(
                    path,
                    FORMAT,
                    "rotated or sheared ModelTransformation; resample to a north-up grid first",
                ));
            }
            Ok(Some(Affine { ax: m[3], sx: m[0], ay: m[7], sy: m[5] }))
        }
        (None, Some(_), None) => Err(RasterError::unsupported(
            path,
            FORMAT,
            "tiepoints without ModelPixelScale (ground control points); warp to a regular grid first",
        )),
        (None, None, None) => Ok(None),
    }
}

fn nodata<R: Read + Seek>(path: &Path, dec: &mut Decoder<R>) -> Result<Option<f64>, RasterError> {
    let Some(value) = dec.find_tag(Tag::GdalNodata).map_err(|e| map_err(path, e))? else { return Ok(None) };
    let text = value.into_string().map_err(|e| map_err(path, e))?;
    let trimmed = text.trim_matches(|c: char| c == '\0' || c.is_whitespace());
    trimmed.parse::<f64>().map(Some).map_err(|_| {
        RasterError::corrupt(path, FORMAT, format!("GDAL_NODATA value \"{trimmed}\" is not a number"))
    })
}

/// Converts samples to f32, turning the no-data value into NaN, appended to `out`. Integers
/// compare exactly; floats also compare after rounding both to f32, because the nodata text
/// (e.g. "-3.4028235e+38") is often a rounded print of the stored f32.
#[allow(clippy::float_cmp)] // the no-data marker is an exact value by definition
fn extend_values<T: Copy>(
    samples: &[T],
    nodata: Option<f64>,
    exact: impl Fn(T) -> f64,
    float: bool,
    out: &mut Vec<f32>,
) {
    let nd32 = nodata.map(|n| n as f32);
    out.extend(samples.iter().map(|&s| {
        let v = exact(s);
        let f = v as f32;
        let is_nodata = nodata.is_some_and(|n| v == n || (float && Some(f) == nd32));
        if is_nodata { f32::NAN } else { f }
    }));
}

/// What a TIFF's first image says about itself, checked: size, no-data value, georeference.
pub(super) struct Header {
    pub width: u32,
    pub height: u32,
    pub nodata: Option<f64>,
    pub georef: FileGeoref,
    pub crs: FileCrs,
    /// Chunks (tiles or strips) the file does not store, sorted: offset or byte count 0, as GDAL
    /// writes with `SPARSE_OK=TRUE`. GDAL reads them as the no-data value, or 0 without one.
    pub sparse: Vec<u32>,
}

/// Opens a TIFF whose signature was already checked and reads its header: one band of a
/// supported sample type, a usable georeference. `buffer_bytes` bounds what one decode may
/// allocate (the whole image, or one chunk).
pub(super) fn open<R: Read + Seek>(
    path: &Path,
    reader: R,
    buffer_bytes: u64,
) -> Result<(Decoder<R>, Header), RasterError> {
    let dec = Decoder::new(reader).map_err(|e| map_err(path, e))?;
    let mut tiff_limits = tiff::decoder::Limits::default();
    tiff_limits.decoding_buffer_size = usize::try_from(buffer_bytes).unwrap_or(usize::MAX);
    let mut dec = dec.with_limits(tiff_limits);

    let (width, height) = dec.dimensions().map_err(|e| map_err(path, e))?;
    if width == 0 || height == 0 {
        return Err(RasterError::ZeroSize {
            path: path.to_owned(),
            width: width.into(),
            height: height.into(),
        });
    }
    let bands: u16 = dec.find_tag_unsigned(Tag::SamplesPerPixel).map_err(|e| map_err(path, e))?.unwrap_or(1);
    if bands != 1 {
        return Err(RasterError::unsupported(
            path,
            FORMAT,
            format!("{bands} bands per pixel; only single-band heightfields are supported"),
        ));
    }
    match dec.colortype().map_err(|e| map_err(path, e))? {
        ColorType::Gray(8 | 16 | 32 | 64) => {}
        ColorType::Gray(bits) => {
            return Err(RasterError::unsupported(
                path,
                FORMAT,
                format!("{bits}-bit samples; expected 8, 16, 32 or 64 bits"),
            ));
        }
        other => {
            return Err(RasterError::unsupported(
                path,
                FORMAT,
                format!("{}; expected a single grayscale band", colour_words(other)),
            ));
        }
    }

    let nodata = nodata(path, &mut dec)?;
    let affine = affine(path, &mut dec)?;
    let KeysCrs { model, raster, crs, degrees_per_unit } = keys_of(path, &mut dec)?;

    let georef = match affine {
        None => FileGeoref::None,
        Some(a) => {
            let off = if raster == Some(RASTER_PIXEL_IS_POINT) { 0.0 } else { 0.5 };
            let (x0, y0) = (a.ax + off * a.sx, a.ay + off * a.sy);
            match model {
                None | Some(MODEL_PROJECTED) => FileGeoref::Projected { x0, y0, dx: a.sx, dy: a.sy },
                Some(MODEL_GEOGRAPHIC) => {
                    // In GeogAngularUnitsGeoKey's unit: degrees from here on.
                    let d = degrees_per_unit;
                    FileGeoref::Geographic { lon0: x0 * d, lat0: y0 * d, dlon: a.sx * d, dlat: a.sy * d }
                }
                Some(other) => {
                    return Err(RasterError::unsupported(
                        path,
                        FORMAT,
                        format!("GTModelTypeGeoKey {other}; expected 1 (projected) or 2 (geographic)"),
                    ));
                }
            }
        }
    };

    check_extent(path, georef, width, height)?;
    let sparse = sparse_chunks(path, &mut dec)?;
    Ok((dec, Header { width, height, nodata, georef, crs, sparse }))
}

/// The chunks a file leaves out (see [`Header::sparse`]): read from the offset and byte count
/// tags, whose lengths the decoder has already checked against the chunk count.
fn sparse_chunks<R: Read + Seek>(path: &Path, dec: &mut Decoder<R>) -> Result<Vec<u32>, RasterError> {
    let (offsets, counts) = match dec.get_chunk_type() {
        ChunkType::Tile => (Tag::TileOffsets, Tag::TileByteCounts),
        ChunkType::Strip => (Tag::StripOffsets, Tag::StripByteCounts),
    };
    let offsets = dec.get_tag_u64_vec(offsets).map_err(|e| map_err(path, e))?;
    let counts = dec.get_tag_u64_vec(counts).map_err(|e| map_err(path, e))?;
    Ok((0u32..)
        .zip(offsets.iter().zip(&counts))
        .filter(|&(_, (&o, &c))| o == 0 || c == 0)
        .map(|(k, _)| k)
        .collect())
}

/// Chunk `index`'s samples as f32 (no-data as NaN), appended to `out`; a chunk the file leaves
/// out reads as GDAL reads it: no-data where the file declares a no-data value, else 0.
pub(super) fn extend_chunk_values<R: Read + Seek>(
    path: &Path,
    dec: &mut Decoder<R>,
    index: u32,
    nodata: Option<f64>,
    sparse: &[u32],
    out: &mut Vec<f32>,
) -> Result<(), RasterError> {
    if sparse.binary_search(&index).is_ok() {
        let (w, h) = dec.chunk_data_dimensions(index);
        let fill = if nodata.is_some() { f32::NAN } else { 0.0 };
        out.extend(std::iter::repeat_n(fill, w as usize * h as usize));
        return Ok(());
    }
    let chunk = dec.read_chunk(index).map_err(|e| map_err(path, e))?;
    extend_values_of(&chunk, nodata, out);
    Ok(())
}

/// Converts one decoded image or chunk to f32 values, no-data as NaN.
pub(super) fn values_of(result: &DecodingResult, nodata: Option<f64>) -> Vec<f32> {
    let mut out = Vec::new();
    extend_values_of(result, nodata, &mut out);
    out
}

/// [`values_of`] appended to `out`.
pub(super) fn extend_values_of(result: &DecodingResult, nodata: Option<f64>, out: &mut Vec<f32>) {
    match result {
        DecodingResult::U8(v) => extend_values(v, nodata, f64::from, false, out),
        DecodingResult::U16(v) => extend_values(v, nodata, f64::from, false, out),
        DecodingResult::U32(v) => extend_values(v, nodata, f64::from, false, out),
        DecodingResult::U64(v) => extend_values(v, nodata, |s| s as f64, false, out),
        DecodingResult::I8(v) => extend_values(v, nodata, f64::from, false, out),
        DecodingResult::I16(v) => extend_values(v, nodata, f64::from, false, out),
        DecodingResult::I32(v) => extend_values(v, nodata, f64::from, false, out),
        DecodingResult::I64(v) => extend_values(v, nodata, |s| s as f64, false, out),
        DecodingResult::F16(v) => extend_values(v, nodata, f64::from, true, out),
        DecodingResult::F32(v) => extend_values(v, nodata, f64::from, true, out),
        DecodingResult::F64(v) => extend_values(v, nodata, |s| s, true, out),
    }
}

/// Decodes a TIFF file whose signature was already checked.
pub(super) fn decode(path: &Path, reader: impl Read + Seek, limits: Limits) -> Result<Decoded, RasterError> {
    let (mut dec, h) = open(path, reader, limits.decoder_bytes())?;
    check_size(path, h.width.into(), h.height.into(), limits)?;
    let values = if h.sparse.is_empty() {
        values_of(&dec.read_image().map_err(|e| map_err(path, e))?, h.nodata)
    } else {
        sparse_image(path, &mut dec, &h)?
    };
    Ok(Decoded { width: h.width, height: h.height, values, georef: h.georef, crs: h.crs, format: "geotiff" })
}

/// The whole image of a file that leaves chunks out, put together chunk by chunk.
fn sparse_image<R: Read + Seek>(
    path: &Path,
    dec: &mut Decoder<R>,
    h: &Header,
) -> Result<Vec<f32>, RasterError> {
    let (tw, th) = dec.chunk_dimensions();
    let (w, hh) = (h.width as usize, h.height as usize);
    let across = match dec.get_chunk_type() {
        ChunkType::Tile => h.width.div_ceil(tw.max(1)),
        ChunkType::Strip => 1,
    };
    let chunks = across as usize * hh.div_ceil(th.max(1) as usize);
    let mut image = vec![f32::NAN; w * hh];
    let mut chunk = Vec::new();
    for k in 0..chunks {
        let index = k as u32;
        chunk.clear();
        extend_chunk_values(path, dec, index, h.nodata, &h.sparse, &mut chunk)?;
        let (cw, ch) = dec.chunk_data_dimensions(index);
        let (c0, r0) = ((index % across) as usize * tw as usize, (index / across) as usize * th as usize);
        let (cw, ch) = (cw as usize, ch as usize);
        if chunk.len() != cw * ch || c0 + cw > w || r0 + ch > hh {
            return Err(RasterError::corrupt(path, FORMAT, format!("chunk {index} does not fit the image")));
        }
        for (r, row) in chunk.chunks_exact(cw).enumerate() {
            image[(r0 + r) * w + c0..][..cw].copy_from_slice(row);
        }
    }
    Ok(image)
}

/// Rejects a georeference whose far corner cannot be represented: finite origin and steps can
/// still put sample (width − 1, height − 1) at ±inf (a step near `f64::MAX`), and every later
/// stage (tiling, bounds, blob quantization) would work on infinities. A geographic raster must
/// also keep its longitudes within ±360° (both the −180..180 and the 0..360 conventions fit),
/// and its steps within the globe, so the metric frame built from it (metres per degree ×
/// degrees) stays finite; latitudes are checked against ±90° when that frame is built.
fn check_extent(path: &Path, georef: FileGeoref, width: u32, height: u32) -> Result<(), RasterError> {
    let far = |o: f64, step: f64, n: u32| o + step * f64::from(n.saturating_sub(1));
    let bad = |message: String| Err(RasterError::BadGeoref { path: path.to_owned(), message });
    match georef {
        FileGeoref::None => Ok(()),
        FileGeoref::Projected { x0, y0, dx, dy } => {
            let (x1, y1) = (far(x0, dx, width), far(y0, dy, height));
            if x1.is_finite() && y1.is_finite() {
                Ok(())
            } else {
                bad(format!(
                    "origin ({x0}, {y0}) and cell size ({dx}, {dy}) put the far corner at ({x1}, {y1})"
                ))
            }
        }
        FileGeoref::Geographic { lon0, dlon, dlat, .. } => {
            let lon1 = far(lon0, dlon, width);
            // The steps too, for a one-sample-wide or -high raster whose far corner is its origin.
            let within = |v: f64, limit: f64| v.abs() <= limit;
            if !(within(lon0, 360.0) && within(lon1, 360.0) && within(dlon, 360.0)) {
                bad(format!("longitudes {lon0}°..{lon1}° (step {dlon}°) leave the range ±360°"))
            } else if dlat.abs() > 180.0 {
                bad(format!("latitude step {dlat}° is more than 180°"))
            } else {
                Ok(())
            }
        }
    }
}

/// Encodes a single-band float32 GeoTIFF (strips, projected, PixelIsPoint) whose sample (0, 0)
/// lies at (`x0`, `y0`) with cell steps `dx`, `dy` (dy < 0 for north-up). Bytes out, no I/O:
/// used for generated test and benchmark terrain.
pub fn encode_f32(
    width: u32,
    height: u32,
    data: &[f32],
    (x0, y0): (f64, f64),
    (dx, dy): (f64, f64),
) -> Result<Vec<u8>, TiffError> {
    use tiff::encoder::{TiffEncoder, colortype};
    let mut buf = std::io::Cursor::new(Vec::new());
    let mut enc = TiffEncoder::new(&mut buf)?;
    let mut img = enc.new_image::<colortype::Gray32Float>(width, height)?;
    img.rows_per_strip(64.min(height))?;
    let e = img.encoder();
    // GeoTIFF scales rows by −ScaleY from the tiepoint, so ScaleY = −dy (positive = north-up).
    e.write_tag(Tag::ModelPixelScaleTag, &[dx.abs(), -dy, 0.0][..])?;
    e.write_tag(Tag::ModelTiepointTag, &[0.0, 0.0, 0.0, x0, y0, 0.0][..])?;
    // Version 1.1.0, 2 keys: GTModelType = projected (1), GTRasterType = PixelIsPoint (2).
    e.write_tag(Tag::GeoKeyDirectoryTag, &[1u16, 1, 0, 2, 1024, 0, 1, 1, 1025, 0, 1, 2][..])?;
    img.write_data(data)?;
    Ok(buf.into_inner())
}

/// The model of a written GeoTIFF: projected (metres) or geographic (degrees).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Model {
    Projected,
    Geographic,
}

/// Writes a single-band float32 GeoTIFF in `tile`² tiles, uncompressed, PixelIsPoint, sample
/// (0, 0) at `origin` with steps `step` (dy < 0 for north-up), optionally with a `GDAL_NODATA`
/// value; BigTIFF when `big` (needed past 4 GiB). Samples come from `sample(col, row)`, one tile
/// at a time, so a raster larger than memory can be written. Used for generated test and
/// benchmark terrain (the `synth` command); the layout is header, tiles, then the directory.
#[allow(clippy::too_many_arguments)]
pub fn write_tiled_f32<W: std::io::Write + Seek>(
    out: &mut W,
    (width, height): (u32, u32),
    tile: u32,
    model: Model,
    origin: (f64, f64),
    step: (f64, f64),
    nodata: Option<f64>,
    big: bool,
    mut sample: impl FnMut(u32, u32) -> f32,
) -> std::io::Result<()> {
    use std::io::{Error, ErrorKind, SeekFrom};
    if tile == 0 || !tile.is_multiple_of(16) || width == 0 || height == 0 {
        return Err(Error::new(
            ErrorKind::InvalidInput,
            "tile side must be a positive multiple of 16, size non-zero",
        ));
    }
    let (across, down) = (width.div_ceil(tile), height.div_ceil(tile));
    let tile_bytes = u64::from(tile) * u64::from(tile) * 4;
    let data_start: u64 = if big { 16 } else { 8 };
    let data_end = data_start + u64::from(across) * u64::from(down) * tile_bytes;
    if !big && data_end + (1 << 20) > u64::from(u32::MAX) {
        return Err(Error::new(ErrorKind::InvalidInput, "larger than 4 GiB: write it as BigTIFF"));
    }
    out.seek(SeekFrom::Start(0))?;
    out.write_all(if big { b"II+\0\x08\0\0\0\0\0\0\0\0\0\0\0" } else { b"II*\0\0\0\0\0" })?;
    let mut buf = Vec::with_capacity(tile_bytes as usize);
    for ty in 0..down {
        for tx in 0..across {
            buf.clear();
            for r in ty * tile..(ty + 1) * tile {
                for c in tx * tile..(tx + 1) * tile {
                    let v = if r < height && c < width { sample(c, r) } else { 0.0 };
                    buf.extend_from_slice(&v.to_le_bytes());
                }
            }
            out.write_all(&buf)?;
        }
    }
    // (tag, type, count, payload bytes), sorted by tag.
    let n = u64::from(across) * u64::from(down);
    let u16s = |v: &[u16]| v.iter().flat_map(|x| x.to_le_bytes()).collect::<Vec<u8>>();
    let offsets: Vec<u64> = (0..n).map(|k| data_start + k * tile_bytes).collect();
    let longs = |v: &[u64]| -> Vec<u8> {
        if big {
            v.iter().flat_map(|x| x.to_le_bytes()).collect()
        } else {
            v.iter().flat_map(|&x| (x as u32).to_le_bytes()).collect()
        }
    };
    let (long_type, long_count) = (if big { 16u16 } else { 4u16 }, n);
    let f64s = |v: &[f64]| v.iter().flat_map(|x| x.to_le_bytes()).collect::<Vec<u8>>();
    let model_key = if model == Model::Geographic { 2 } else { 1 };
    let mut entries: Vec<(u16, u16, u64, Vec<u8>)> = vec![
        (256, 4, 1, width.to_le_bytes().to_vec()),
        (257, 4, 1, height.to_le_bytes().to_vec()),
        (258, 3, 1, u16s(&[32])),
        (259, 3, 1, u16s(&[1])),
        (262, 3, 1, u16s(&[1])),
        (277, 3, 1, u16s(&[1])),
        (284, 3, 1, u16s(&[1])),
        (322, 4, 1, tile.to_le_bytes().to_vec()),
        (323, 4, 1, tile.to_le_bytes().to_vec()),
        (324, long_type, long_count, longs(&offsets)),
        (325, long_type, long_count, longs(&vec![tile_bytes; n as usize])),
        (339, 3, 1, u16s(&[3])),
        (33550, 12, 3, f64s(&[step.0.abs(), -step.1, 0.0])),
        (33922, 12, 6, f64s(&[0.0, 0.0, 0.0, origin.0, origin.1, 0.0])),
        // Geographic: WGS 84 (GeographicTypeGeoKey 4326); projected: no CRS (a local frame).
        if model == Model::Geographic {
            (34735, 3, 16, u16s(&[1, 1, 0, 3, 1024, 0, 1, model_key, 1025, 0, 1, 2, 2048, 0, 1, 4326]))
        } else {
            (34735, 3, 12, u16s(&[1, 1, 0, 2, 1024, 0, 1, model_key, 1025, 0, 1, 2]))
        },
    ];
    if let Some(nd) = nodata {
        let mut text = format!("{nd}").into_bytes();
        text.push(0);
        entries.push((42113, 2, text.len() as u64, text));
    }
    // External payloads after the data, then the directory.
    let slot = if big { 8 } else { 4 };
    let mut pos = data_end;
    let mut external = Vec::new();
    let mut placed = Vec::with_capacity(entries.len());
    for (tag, ty, count, payload) in &entries {
        if payload.len() <= slot {
            let mut v = payload.clone();
            v.resize(slot, 0);
            placed.push((*tag, *ty, *count, v));
        } else {
            let at = pos + external.len() as u64;
            external.extend_from_slice(payload);
            if external.len() % 2 == 1 {
                external.push(0);
            }
            let v = if big { at.to_le_bytes().to_vec() } else { (at as u32).to_le_bytes().to_vec() };
            placed.push((*tag, *ty, *count, v));
        }
    }
    out.write_all(&external)?;
    pos += external.len() as u64;
    let ifd = pos;
    let mut dir = Vec::new();
    if big {
        dir.extend_from_slice(&(placed.len() as u64).to_le_bytes());
    } else {
        dir.extend_from_slice(&(placed.len() as u16).to_le_bytes());
    }
    for (tag, ty, count, v) in &placed {
        dir.extend_from_slice(&tag.to_le_bytes());
        dir.extend_from_slice(&ty.to_le_bytes());
        if big {
            dir.extend_from_slice(&count.to_le_bytes());
        } else {
            dir.extend_from_slice(&(*count as u32).to_le_bytes());
        }
        dir.extend_from_slice(v);
    }
    dir.extend_from_slice(&vec![0u8; slot]);
    out.write_all(&dir)?;
    out.seek(SeekFrom::Start(if big { 8 } else { 4 }))?;
    if big {
        out.write_all(&ifd.to_le_bytes())?;
    } else {
        out.write_all(&(ifd as u32).to_le_bytes())?;
    }
    out.seek(SeekFrom::End(0))?;
    out.flush()
}

/// A TIFF colour type in a user's words ("8-bit palette colour"), not the decoder's type name.
fn colour_words(c: ColorType) -> String {
    let (what, bits) = match c {
        ColorType::Gray(b) => ("grayscale", b),
        ColorType::RGB(b) => ("RGB", b),
        ColorType::Palette(b) => ("palette colour", b),
        ColorType::GrayA(b) => ("grayscale with alpha", b),
        ColorType::RGBA(b) => ("RGB with alpha", b),
        ColorType::CMYK(b) => ("CMYK", b),
        ColorType::CMYKA(b) => ("CMYK with alpha", b),
        ColorType::YCbCr(b) => ("YCbCr colour", b),
        ColorType::Lab(b) => ("CIE L*a*b* colour", b),
        ColorType::Multiband { bit_depth, num_samples } => {
            return format!("{num_samples} bands of {bit_depth}-bit samples");
        }
        _ => return format!("a colour type of {}-bit samples this reader does not know", c.bit_depth()),
    };
    format!("{bits}-bit {what}")
}

#[cfg(test)]
// A failed unwrap is the test failing; exact float comparisons are of exactly representable values.
#[allow(clippy::unwrap_used, clippy::float_cmp)]
mod tests {
    use std::io::Cursor;
    use std::path::{Path, PathBuf};
    use std::time::Instant;

    use tiff::encoder::{TiffEncoder, colortype};
    use tiff::tags::Tag;

    use super::super::test_util::{assert_names_path, load, sparse_tiff, write};
    use super::super::{FileGeoref, Georef, RasterError, metres_per_degree};

    /// `GeoTIFF` tags to attach to a test image.
    #[derive(Default)]
    struct Geo<'a> {
        scale: Option<[f64; 3]>,
        tie: Option<[f64; 6]>,
        transform: Option<[f64; 16]>,
        keys: Option<&'a [u16]>,
        nodata: Option<&'a str>,
    }

    fn geokeys(model: u16, raster: u16) -> Vec<u16> {
        vec![1, 1, 0, 2, 1024, 0, 1, model, 1025, 0, 1, raster]
    }

    /// Writes a strip TIFF of colour type `C` with the given `GeoTIFF` tags.
    fn strip_tiff<C: colortype::ColorType>(
        dir: &Path,
        w: u32,
        h: u32,
        data: &[C::Inner],
        geo: &Geo,
    ) -> PathBuf
    where
        [C::Inner]: tiff::encoder::TiffValue,
    {
        let mut buf = Cursor::new(Vec::new());
        let mut enc = TiffEncoder::new(&mut buf).unwrap();
        let mut img = enc.new_image::<C>(w, h).unwrap();
        img.rows_per_strip(2).unwrap();
        let e = img.encoder();
        if let Some(s) = geo.scale {
            e.write_tag(Tag::ModelPixelScaleTag, &s[..]).unwrap();
        }
        if let Some(t) = geo.tie {
            e.write_tag(Tag::ModelTiepointTag, &t[..]).unwrap();
        }
        if let Some(m) = geo.transform {
            e.write_tag(Tag::ModelTransformationTag, &m[..]).unwrap();
        }
        if let Some(k) = geo.keys {
            e.write_tag(Tag::GeoKeyDirectoryTag, k).unwrap();
        }
        if let Some(n) = geo.nodata {
            e.write_tag(Tag::GdalNodata, n).unwrap();
        }
        img.write_data(data).unwrap();
        write(dir, "t.tif", &buf.into_inner())
    }

    /// Writes a tiled u16 TIFF by hand (the encoder only writes strips): `tile`² tiles, edge
    /// tiles padded as the format requires.
    fn tiled_tiff(dir: &Path, w: u32, h: u32, tile: u32, data: &[u16]) -> PathBuf {
        sparse_tiff(dir, w, h, tile, data, &[], None)
    }

    /// A header-only strip TIFF declaring `w × h` u16 samples (one tiny strip).
    fn declared_tiff(dir: &Path, w: u32, h: u32) -> PathBuf {
        let mut buf = Cursor::new(Vec::new());
        let mut enc = TiffEncoder::new(&mut buf).unwrap();
        let mut d = enc.image_directory().unwrap();
        let off = d.write_data(&[0_u16][..]).unwrap() as u32;
        d.write_tag(Tag::ImageWidth, w).unwrap();
        d.write_tag(Tag::ImageLength, h).unwrap();
        d.write_tag(Tag::BitsPerSample, 16_u16).unwrap();
        d.write_tag(Tag::SamplesPerPixel, 1_u16).unwrap();
        d.write_tag(Tag::PhotometricInterpretation, 1_u16).unwrap();
        d.write_tag(Tag::RowsPerStrip, h.max(1)).unwrap();
        d.write_tag(Tag::StripOffsets, &[off][..]).unwrap();
        d.write_tag(Tag::StripByteCounts, &[2_u32][..]).unwrap();
        d.finish().unwrap();
        write(dir, "declared.tif", &buf.into_inner())
    }

    #[test]
    fn projected_pixel_is_area() {
        let dir = tempfile::tempdir().unwrap();
        let data: Vec<i16> = (0..12).map(|i| i * 100 - 300).collect();
        let keys = geokeys(1, 1);
        let geo = Geo {
            scale: Some([30.0, 30.0, 0.0]),
            tie: Some([0.0, 0.0, 0.0, 500_000.0, 4_000_000.0, 0.0]),
            keys: Some(&keys),
            ..Geo::default()
        };
        let p = strip_tiff::<colortype::GrayI16>(dir.path(), 4, 3, &data, &geo);
        let r = load(&p).unwrap();
        assert_eq!(r.format, "geotiff");
        assert_eq!(r.heights.data, data.iter().map(|&v| f32::from(v)).collect::<Vec<_>>());
        let g = r.georef;
        assert_eq!((g.x0, g.y0, g.dx, g.dy), (500_015.0, 3_999_985.0, 30.0, -30.0));
        assert_eq!(g.crs, None);
    }

    #[test]
    fn pixel_is_point_and_no_geokeys() {
        let dir = tempfile::tempdir().unwrap();
        let keys = geokeys(1, 2);
        let tie = [1.0, 1.0, 0.0, 100.0, 200.0, 0.0];
        let geo = Geo { scale: Some([2.0, 2.0, 0.0]), tie: Some(tie), keys: Some(&keys), ..Geo::default() };
        let p = strip_tiff::<colortype::Gray16>(dir.path(), 2, 2, &[1, 2, 3, 4], &geo);
        let g = load(&p).unwrap().georef;
        assert_eq!((g.x0, g.y0, g.dx, g.dy), (98.0, 202.0, 2.0, -2.0));
        // Without geokeys: projected, PixelIsArea.
        let geo = Geo { scale: Some([2.0, 2.0, 0.0]), tie: Some(tie), ..Geo::default() };
        let p = strip_tiff::<colortype::Gray16>(dir.path(), 2, 2, &[1, 2, 3, 4], &geo);
        let g = load(&p).unwrap().georef;
        assert_eq!((g.x0, g.y0, g.dx, g.dy), (99.0, 201.0, 2.0, -2.0));
    }

    #[test]
    fn model_transformation() {
        let dir = tempfile::tempdir().unwrap();
        let mut m = [0.0; 16];
        (m[0], m[3], m[5], m[7], m[15]) = (10.0, 1000.0, -10.0, 5000.0, 1.0);
        let geo = Geo { transform: Some(m), ..Geo::default() };
        let p = strip_tiff::<colortype::Gray32Float>(dir.path(), 2, 1, &[1.5, 2.5], &geo);
        let r = load(&p).unwrap();
        assert_eq!(r.heights.data, [1.5, 2.5]);
        let g = r.georef;
        assert_eq!((g.x0, g.y0, g.dx, g.dy), (1005.0, 4995.0, 10.0, -10.0));
        m[1] = 0.5;
        let geo = Geo { transform: Some(m), ..Geo::default() };
        let p = strip_tiff::<colortype::Gray32Float>(dir.path(), 2, 1, &[1.5, 2.5], &geo);
        assert!(matches!(load(&p), Err(RasterError::Unsupported { .. })));
    }

    /// Found by the `raster_geotiff` fuzz target: finite origins and steps whose far corner, or
    /// whose metric frame, is infinite.
    #[test]
    fn far_corner_must_be_finite() {
        let dir = tempfile::tempdir().unwrap();
        let projected = Geo { scale: Some([1.6e308, 1.0, 0.0]), tie: Some([0.0; 6]), ..Geo::default() };
        let keys = geokeys(2, 1);
        let wide = Geo { scale: Some([200.0, 1.0, 0.0]), keys: Some(&keys), ..Geo::default() };
        let huge_step = Geo { scale: Some([1e300, 1.0, 0.0]), keys: Some(&keys), ..Geo::default() };
        for (w, geo) in [(3, &projected), (3, &wide), (1, &huge_step)] {
            let p = strip_tiff::<colortype::Gray16>(dir.path(), w, 1, &vec![1; w as usize], geo);
            let e = load(&p).unwrap_err();
            assert!(matches!(e, RasterError::BadGeoref { .. }), "{e}");
            assert_names_path(&e, &p);
        }
        // The whole globe in either longitude convention is fine (on WGS 84: GeographicTypeGeoKey).
        let mut wgs84 = keys.clone();
        wgs84[3] = 3;
        wgs84.extend([2048, 0, 1, 4326]);
        let globe = Geo {
            scale: Some([120.0, 1.0, 0.0]),
            tie: Some([0.0, 0.0, 0.0, 0.0, 0.0, 0.0]),
            keys: Some(&wgs84),
            ..Geo::default()
        };
        let p = strip_tiff::<colortype::Gray16>(dir.path(), 3, 1, &[1; 3], &globe);
        load(&p).unwrap();
    }

    #[test]
    fn geographic_maps_to_metres() {
        let dir = tempfile::tempdir().unwrap();
        let mut keys = geokeys(2, 1);
        // GeographicTypeGeoKey 4326: WGS 84.
        keys[3] = 3;
        keys.extend([2048, 0, 1, 4326]);
        let step = 1.0 / 3600.0;
        let geo = Geo {
            scale: Some([step, step, 0.0]),
            tie: Some([0.0, 0.0, 0.0, 138.0, 36.0, 0.0]),
            keys: Some(&keys),
            ..Geo::default()
        };
        let p = strip_tiff::<colortype::Gray16>(dir.path(), 3, 3, &[1; 9], &geo);
        let g = load(&p).unwrap().georef;
        let m = g.crs.clone().unwrap();
        let (lon0, lat0) = (138.0 + step / 2.0, 36.0 - step / 2.0);
        assert_eq!((m.e0, m.n0, m.de, m.dn), (lon0, lat0, step, -step));
        assert_eq!(m.crs.epsg(), Some(4326));
        let (m_lon, m_lat) = metres_per_degree(lat0 - step);
        assert_eq!((g.x0, g.y0), (0.0, 0.0));
        assert!((g.dx - step * m_lon).abs() < 1e-9 && (g.dy + step * m_lat).abs() < 1e-9);
        assert!((g.dx - 25.0).abs() < 0.5, "about 25 m per arc-second of longitude at 36°N: {}", g.dx);
    }

    #[test]
    fn gdal_nodata_is_filled() {
        let dir = tempfile::tempdir().unwrap();
        let nd = -9999.0_f32;
        let data = [1.0, 2.0, 3.0, 4.0, nd, 6.0, 7.0, 8.0, 9.0, nd, nd, nd];
        let geo = Geo { nodata: Some("-9999"), ..Geo::default() };
        let p = strip_tiff::<colortype::Gray32Float>(dir.path(), 3, 4, &data, &geo);
        let r = load(&p).unwrap();
        assert_eq!(r.nodata_filled, 4);
        assert!((r.heights.get(1, 1) - 5.0).abs() < 1e-6);
        // Bottom row: pass 1 sees row 2 (7, 8, 9) only.
        assert!((r.heights.get(0, 3) - 7.5).abs() < 1e-6);
        assert!((r.heights.get(1, 3) - 8.0).abs() < 1e-6);
        assert!((r.heights.get(2, 3) - 8.5).abs() < 1e-6);
        assert_eq!(r.georef, Georef::default());
        // f32 nodata printed as its shortest f32 form (not exact in f64) still matches.
        let data = [f32::MIN, 1.0];
        let geo = Geo { nodata: Some(" -3.4028235e+38 "), ..Geo::default() };
        let p = strip_tiff::<colortype::Gray32Float>(dir.path(), 2, 1, &data, &geo);
        let r = load(&p).unwrap();
        assert_eq!((r.nodata_filled, r.heights.data.clone()), (1, vec![1.0, 1.0]));
    }

    #[test]
    fn integer_nodata_and_all_nodata() {
        let dir = tempfile::tempdir().unwrap();
        let geo = Geo { nodata: Some("-32768"), ..Geo::default() };
        let p = strip_tiff::<colortype::GrayI16>(dir.path(), 2, 1, &[-32768, 12], &geo);
        assert_eq!(load(&p).unwrap().heights.data, [12.0, 12.0]);
        let p = strip_tiff::<colortype::GrayI16>(dir.path(), 2, 2, &[-32768; 4], &geo);
        let e = load(&p).unwrap_err();
        assert!(matches!(e, RasterError::AllNoData { samples: 4, .. }), "{e}");
        assert_names_path(&e, &p);
        let geo = Geo { nodata: Some("none"), ..Geo::default() };
        let p = strip_tiff::<colortype::GrayI16>(dir.path(), 2, 1, &[1, 2], &geo);
        assert!(matches!(load(&p), Err(RasterError::Corrupt { .. })));
    }

    #[test]
    fn nan_samples_are_filled() {
        let dir = tempfile::tempdir().unwrap();
        let p =
            strip_tiff::<colortype::Gray32Float>(dir.path(), 3, 1, &[2.0, f32::NAN, 4.0], &Geo::default());
        let r = load(&p).unwrap();
        assert_eq!((r.nodata_filled, r.heights.data), (1, vec![2.0, 3.0, 4.0]));
    }

    #[test]
    fn sample_types() {
        let dir = tempfile::tempdir().unwrap();
        let g = Geo::default();
        let p = strip_tiff::<colortype::Gray8>(dir.path(), 2, 1, &[0, 255], &g);
        assert_eq!(load(&p).unwrap().heights.data, [0.0, 255.0]);
        let p = strip_tiff::<colortype::GrayI32>(dir.path(), 2, 1, &[-100_000, 7], &g);
        assert_eq!(load(&p).unwrap().heights.data, [-100_000.0, 7.0]);
        let p = strip_tiff::<colortype::Gray64Float>(dir.path(), 2, 1, &[0.25, -1.5], &g);
        assert_eq!(load(&p).unwrap().heights.data, [0.25, -1.5]);
        let p = strip_tiff::<colortype::Gray16>(dir.path(), 2, 1, &[65_535, 1], &g);
        assert_eq!(load(&p).unwrap().heights.data, [65_535.0, 1.0]);
    }

    #[test]
    fn tiled_with_padding() {
        let dir = tempfile::tempdir().unwrap();
        let (w, h) = (20, 20);
        let data: Vec<u16> = (0..w * h).map(|i| (i * 3) as u16).collect();
        let p = tiled_tiff(dir.path(), w, h, 16, &data);
        let r = load(&p).unwrap();
        assert_eq!((r.heights.width, r.heights.height), (w, h));
        assert_eq!(r.heights.data, data.iter().map(|&v| f32::from(v)).collect::<Vec<_>>());
    }

    #[test]
    fn sparse_tiles_read_as_gdal_reads_them() {
        let dir = tempfile::tempdir().unwrap();
        let (w, h) = (40, 36);
        let data: Vec<u16> = (0..w * h).map(|i| (i % 977) as u16 + 100).collect();
        // 3 × 3 tiles of 16: leave out the first, the centre and the last (a padded edge tile).
        let skip = [0, 4, 8];
        let skipped = |k: u32| {
            let (c, r) = (k % w, k / w);
            skip.contains(&((r / 16 * 3 + c / 16) as usize))
        };
        // Without a no-data value the missing tiles are 0, as GDAL reads them.
        let p = sparse_tiff(dir.path(), w, h, 16, &data, &skip, None);
        let r = load(&p).unwrap();
        assert_eq!(r.nodata_filled, 0);
        for (k, (&got, &v)) in (0u32..).zip(r.heights.data.iter().zip(&data)) {
            assert_eq!(got, if skipped(k) { 0.0 } else { f32::from(v) }, "sample {k}");
        }
        // With one they are no-data, filled like any other; every stored sample is kept.
        let p = sparse_tiff(dir.path(), w, h, 16, &data, &skip, Some("-9999"));
        let r = load(&p).unwrap();
        let missing = (0..w * h).filter(|&k| skipped(k)).count() as u64;
        assert_eq!(r.nodata_filled, missing);
        for (k, (&got, &v)) in (0u32..).zip(r.heights.data.iter().zip(&data)) {
            if !skipped(k) {
                assert_eq!(got, f32::from(v), "sample {k}");
            }
            assert!((100.0..=1076.0).contains(&got), "sample {k}: {got}");
        }
        // The out-of-core reader: `dataset::tests::sparse_tiffs_read_block_by_block_as_whole`.
    }

    #[test]
    fn three_bands_unsupported() {
        let dir = tempfile::tempdir().unwrap();
        let p = strip_tiff::<colortype::RGB8>(dir.path(), 2, 1, &[1, 2, 3, 4, 5, 6], &Geo::default());
        let e = load(&p).unwrap_err();
        assert!(matches!(e, RasterError::Unsupported { .. }), "{e}");
        assert!(e.to_string().contains("3 bands"), "{e}");
        assert_names_path(&e, &p);
    }

    #[test]
    fn huge_declared_size_fails_fast() {
        let dir = tempfile::tempdir().unwrap();
        let p = declared_tiff(dir.path(), 100_000, 100_000);
        let start = Instant::now();
        let e = load(&p).unwrap_err();
        assert!(matches!(e, RasterError::TooLarge { width: 100_000, height: 100_000, .. }), "{e}");
        assert!(start.elapsed().as_millis() < 500);
        assert_names_path(&e, &p);
    }

    #[test]
    fn zero_size() {
        let dir = tempfile::tempdir().unwrap();
        let p = declared_tiff(dir.path(), 0, 5);
        let e = load(&p).unwrap_err();
        assert!(matches!(e, RasterError::ZeroSize { .. }), "{e}");
        assert_names_path(&e, &p);
    }

    #[test]
    fn truncated_and_garbage() {
        let dir = tempfile::tempdir().unwrap();
        let data: Vec<u16> = (0..400).collect();
        let p = strip_tiff::<colortype::Gray16>(dir.path(), 20, 20, &data, &Geo::default());
        let bytes = std::fs::read(&p).unwrap();
        // The encoder writes strips first and the IFD last; cutting anywhere loses one or both.
        for cut in [4, 9, 300, bytes.len() - 20] {
            let t = write(dir.path(), "cut.tif", &bytes[..cut]);
            let e = load(&t).unwrap_err();
            assert!(matches!(e, RasterError::Corrupt { .. }), "cut {cut}: {e}");
            assert_names_path(&e, &t);
        }
        let t = write(dir.path(), "garbage.tif", b"II*\0\xff\xff\xff\x7fgarbage");
        assert!(matches!(load(&t), Err(RasterError::Corrupt { .. })));
    }

    #[test]
    fn geokey_parsing_tolerates_short_directories() {
        use super::geokeys::{GeoKeys, read};
        let of = |dir: &[u16]| read(&GeoKeys { dir, ..GeoKeys::default() }).map(|k| (k.model, k.raster));
        assert_eq!(of(&[]), Ok((None, None)));
        assert_eq!(of(&[1, 1, 0, 5, 1024, 0, 1]), Ok((None, None)));
        assert_eq!(of(&[1, 1, 0, 1, 1024, 0, 1, 2]), Ok((Some(2), None)));
        let _ = FileGeoref::None;
    }

    /// Colour types are named in words, never by the decoder's type names.
    #[test]
    fn colour_types_are_said_in_words() {
        use super::colour_words;
        use tiff::ColorType;
        assert_eq!(colour_words(ColorType::Palette(8)), "8-bit palette colour");
        assert_eq!(colour_words(ColorType::RGB(16)), "16-bit RGB");
        assert_eq!(
            colour_words(ColorType::Multiband { bit_depth: 8, num_samples: 5 }),
            "5 bands of 8-bit samples"
        );
        for c in [
            ColorType::GrayA(8),
            ColorType::RGBA(8),
            ColorType::CMYK(8),
            ColorType::YCbCr(8),
            ColorType::Lab(8),
        ] {
            let w = colour_words(c);
            assert!(!w.contains('(') && !w.contains("RGBA") && !w.contains("GrayA"), "{w}");
        }
    }
}
