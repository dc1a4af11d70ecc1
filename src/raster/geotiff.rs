//! TIFF/`GeoTIFF` heightfields via the `tiff` crate: one band of any integer or float sample type,
//! in strips or tiles, with the georeference taken from `ModelPixelScale` + `ModelTiepoint` (or a
//! rotation-free `ModelTransformation`), the model type (projected or geographic) from the
//! `GeoKeyDirectory`, and the no-data value from `GDAL_NODATA`.
//!
//! Pixel convention: `GeoTIFF` places raster coordinate (0, 0) at the outer corner of the first
//! pixel when `GTRasterTypeGeoKey` is `PixelIsArea` (the default) and at its centre for
//! `PixelIsPoint`. Our frame puts `x0, y0` at the *centre* of sample (0, 0), so `PixelIsArea`
//! files are shifted by half a cell. Angular units are assumed to be degrees.

use std::io::{Read, Seek};
use std::path::Path;

use tiff::decoder::{Decoder, DecodingResult};
use tiff::tags::Tag;
use tiff::{ColorType, TiffError, TiffFormatError};

use super::{Decoded, FileGeoref, Limits, RasterError, check_size};

const FORMAT: &str = "TIFF";

const GT_MODEL_TYPE: u16 = 1024;
const GT_RASTER_TYPE: u16 = 1025;
const MODEL_PROJECTED: u16 = 1;
const MODEL_GEOGRAPHIC: u16 = 2;
const RASTER_PIXEL_IS_POINT: u16 = 2;

fn map_err(path: &Path, e: TiffError) -> RasterError {
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

/// `GTModelTypeGeoKey` and `GTRasterTypeGeoKey` from a `GeoKeyDirectory`; keys stored outside
/// the directory (location ≠ 0) are not short values and are skipped.
fn geokeys(dir: &[u16]) -> (Option<u16>, Option<u16>) {
    let count = dir.get(3).map_or(0, |&n| usize::from(n));
    let (mut model, mut raster) = (None, None);
    for key in dir.get(4..).unwrap_or(&[]).chunks_exact(4).take(count) {
        if key[1] == 0 {
            match key[0] {
                GT_MODEL_TYPE => model = Some(key[3]),
                GT_RASTER_TYPE => raster = Some(key[3]),
                _ => {}
            }
        }
    }
    (model, raster)
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

/// Converts samples to f32, turning the no-data value into NaN. Integers compare exactly; floats
/// also compare after rounding both to f32, because the nodata text (e.g. "-3.4028235e+38")
/// is often a rounded print of the stored f32.
#[allow(clippy::float_cmp)] // the no-data marker is an exact value by definition
fn to_values<T: Copy>(samples: &[T], nodata: Option<f64>, exact: impl Fn(T) -> f64, float: bool) -> Vec<f32> {
    let nd32 = nodata.map(|n| n as f32);
    samples
        .iter()
        .map(|&s| {
            let v = exact(s);
            let f = v as f32;
            let is_nodata = nodata.is_some_and(|n| v == n || (float && Some(f) == nd32));
            if is_nodata { f32::NAN } else { f }
        })
        .collect()
}

/// Decodes a TIFF file whose signature was already checked.
pub(super) fn decode(path: &Path, reader: impl Read + Seek, limits: Limits) -> Result<Decoded, RasterError> {
    let dec = Decoder::new(reader).map_err(|e| map_err(path, e))?;
    let mut tiff_limits = tiff::decoder::Limits::default();
    tiff_limits.decoding_buffer_size = usize::try_from(limits.decoder_bytes()).unwrap_or(usize::MAX);
    let mut dec = dec.with_limits(tiff_limits);

    let (width, height) = dec.dimensions().map_err(|e| map_err(path, e))?;
    check_size(path, width.into(), height.into(), limits)?;

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
                format!("colour type {other:?}; expected a single grayscale band"),
            ));
        }
    }

    let nodata = nodata(path, &mut dec)?;
    let affine = affine(path, &mut dec)?;
    let keys = dec.find_tag(Tag::GeoKeyDirectoryTag).map_err(|e| map_err(path, e))?;
    let (model, raster) = match keys {
        Some(v) => geokeys(&v.into_u16_vec().map_err(|e| map_err(path, e))?),
        None => (None, None),
    };

    let georef = match affine {
        None => FileGeoref::None,
        Some(a) => {
            let off = if raster == Some(RASTER_PIXEL_IS_POINT) { 0.0 } else { 0.5 };
            let (x0, y0) = (a.ax + off * a.sx, a.ay + off * a.sy);
            match model {
                None | Some(MODEL_PROJECTED) => FileGeoref::Projected { x0, y0, dx: a.sx, dy: a.sy },
                Some(MODEL_GEOGRAPHIC) => {
                    FileGeoref::Geographic { lon0: x0, lat0: y0, dlon: a.sx, dlat: a.sy }
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

    let values = match dec.read_image().map_err(|e| map_err(path, e))? {
        DecodingResult::U8(v) => to_values(&v, nodata, f64::from, false),
        DecodingResult::U16(v) => to_values(&v, nodata, f64::from, false),
        DecodingResult::U32(v) => to_values(&v, nodata, f64::from, false),
        DecodingResult::U64(v) => to_values(&v, nodata, |s| s as f64, false),
        DecodingResult::I8(v) => to_values(&v, nodata, f64::from, false),
        DecodingResult::I16(v) => to_values(&v, nodata, f64::from, false),
        DecodingResult::I32(v) => to_values(&v, nodata, f64::from, false),
        DecodingResult::I64(v) => to_values(&v, nodata, |s| s as f64, false),
        DecodingResult::F16(v) => to_values(&v, nodata, f64::from, true),
        DecodingResult::F32(v) => to_values(&v, nodata, f64::from, true),
        DecodingResult::F64(v) => to_values(&v, nodata, |s| s, true),
    };
    Ok(Decoded { width, height, values, georef, format: "geotiff" })
}
