//! PNG heightfields via the `image` crate: 16-bit (or 8-bit) grayscale where the value is the
//! height, and 8-bit RGB(A) in the Mapbox terrain-RGB or Terrarium encodings. PNG carries no
//! georeference, so the frame is unit cells unless the user overrides it.

use std::io::{BufRead, Seek};
use std::path::Path;

use image::codecs::png::PngDecoder;
use image::{DynamicImage, ImageDecoder, ImageError};

use super::{Decoded, Encoding, FileGeoref, LoadOptions, RasterError, check_size};

const FORMAT: &str = "PNG";

fn map_err(path: &Path, e: ImageError) -> RasterError {
    match e {
        ImageError::IoError(io) if io.kind() != std::io::ErrorKind::UnexpectedEof => {
            RasterError::io(path, io)
        }
        ImageError::Unsupported(u) => RasterError::unsupported(path, FORMAT, u.to_string()),
        ImageError::Limits(l) => {
            RasterError::unsupported(path, FORMAT, format!("decoder memory limit exceeded: {l}"))
        }
        other => RasterError::corrupt(path, FORMAT, other.to_string()),
    }
}

/// Decodes a PNG file whose signature was already checked.
pub(super) fn decode(
    path: &Path,
    reader: impl BufRead + Seek,
    opts: &LoadOptions,
) -> Result<Decoded, RasterError> {
    // The decoder's own allocation budget guards what it allocates while reading the header
    // and chunks; our size check below then rejects the declared size before any pixel buffer.
    let mut limits = image::Limits::default();
    limits.max_alloc = Some(opts.limits.decoder_bytes());
    let decoder = PngDecoder::with_limits(reader, limits).map_err(|e| map_err(path, e))?;
    let (width, height) = decoder.dimensions();
    check_size(path, u64::from(width), u64::from(height), opts.limits)?;

    let color = decoder.color_type();
    let color_name = format!("{color:?}");
    let image = DynamicImage::from_decoder(decoder).map_err(|e| map_err(path, e))?;
    let mismatch = |encoding| RasterError::EncodingMismatch {
        path: path.to_owned(),
        encoding,
        color: color_name.clone(),
    };

    let (values, format): (Vec<f32>, &'static str) = match image {
        DynamicImage::ImageLuma16(_)
        | DynamicImage::ImageLumaA16(_)
        | DynamicImage::ImageLuma8(_)
        | DynamicImage::ImageLumaA8(_) => {
            if let Some(e @ (Encoding::TerrainRgb | Encoding::Terrarium)) = opts.encoding {
                return Err(mismatch(e));
            }
            // Alpha, if any, is ignored: heights have no transparency. 8-bit samples are taken as
            // they are (not widened to 16 bits) so the value stays the stored number.
            if matches!(image, DynamicImage::ImageLuma8(_) | DynamicImage::ImageLumaA8(_)) {
                (image.into_luma8().into_raw().into_iter().map(f32::from).collect(), "png-gray8")
            } else {
                (image.into_luma16().into_raw().into_iter().map(f32::from).collect(), "png-gray16")
            }
        }
        DynamicImage::ImageRgb8(_) | DynamicImage::ImageRgba8(_) => {
            let decode_rgb: fn([u8; 3]) -> f32 = match opts.encoding {
                Some(Encoding::TerrainRgb) => terrain_rgb,
                Some(Encoding::Terrarium) => terrarium,
                Some(e @ Encoding::Gray16) => return Err(mismatch(e)),
                None => {
                    return Err(RasterError::MissingEncoding { path: path.to_owned(), color: color_name });
                }
            };
            let format =
                if opts.encoding == Some(Encoding::TerrainRgb) { "png-terrain-rgb" } else { "png-terrarium" };
            let values = match &image {
                DynamicImage::ImageRgba8(img) => {
                    img.as_raw().chunks_exact(4).map(|p| decode_rgb([p[0], p[1], p[2]])).collect()
                }
                _ => {
                    image.to_rgb8().as_raw().chunks_exact(3).map(|p| decode_rgb([p[0], p[1], p[2]])).collect()
                }
            };
            (values, format)
        }
        _ => {
            return Err(RasterError::unsupported(
                path,
                FORMAT,
                format!(
                    "colour type {color_name}; expected 8/16-bit grayscale or 8-bit RGB/RGBA (terrain-RGB, Terrarium)"
                ),
            ));
        }
    };
    Ok(Decoded { width, height, values, georef: FileGeoref::None, format })
}

/// Mapbox terrain-RGB: −10000 + (R·65536 + G·256 + B)·0.1 metres.
fn terrain_rgb([r, g, b]: [u8; 3]) -> f32 {
    let v = u32::from(r) << 16 | u32::from(g) << 8 | u32::from(b);
    (-10_000.0 + f64::from(v) * 0.1) as f32
}

/// Terrarium: R·256 + G + B/256 − 32768 metres.
fn terrarium([r, g, b]: [u8; 3]) -> f32 {
    (f64::from(r) * 256.0 + f64::from(g) + f64::from(b) / 256.0 - 32_768.0) as f32
}
