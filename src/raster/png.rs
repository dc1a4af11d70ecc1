//! PNG heightfields via the `image` crate: 16-bit (or 8-bit) grayscale where the value is the
//! height, and 8-bit RGB(A) in the Mapbox terrain-RGB or Terrarium encodings. PNG carries no
//! georeference, so the frame is unit cells unless the user overrides it.

use std::io::{BufRead, Read, Seek, SeekFrom};
use std::path::Path;

use image::codecs::png::PngDecoder;
use image::{DynamicImage, ImageDecoder, ImageError};

use super::{Decoded, FileGeoref, HeightEncoding, LoadOptions, RasterError, check_size};

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

/// Checks the chunks before the image data against PNG's own rules where the `png` crate
/// trusts them: a `PLTE` must hold 1 to 256 three-byte entries (PNG §11.2.3). The crate indexes
/// past a palette of any other length (found by fuzzing: a 14-byte `PLTE` panicked in
/// `png::decoder::transform::palette`). Walks chunk headers only, up to the first `IDAT` or
/// `IEND` (the palette must come before the data) or the end of the file, each step at least
/// 12 bytes forward; what does not parse here is left to the decoder to report. The reader is
/// left at the start.
fn check_chunks(path: &Path, reader: &mut (impl Read + Seek)) -> Result<(), RasterError> {
    let io = |e| RasterError::io(path, e);
    let end = reader.seek(SeekFrom::End(0)).map_err(io)?;
    let mut at = 8u64;
    while at + 8 <= end {
        reader.seek(SeekFrom::Start(at)).map_err(io)?;
        let mut head = [0u8; 8];
        reader.read_exact(&mut head).map_err(io)?;
        let len = u64::from(u32::from_be_bytes([head[0], head[1], head[2], head[3]]));
        match &head[4..8] {
            b"IDAT" | b"IEND" => break,
            b"PLTE" if len == 0 || len > 768 || len % 3 != 0 => {
                return Err(RasterError::corrupt(
                    path,
                    FORMAT,
                    format!("PLTE chunk of {len} bytes; a palette holds 1 to 256 entries of 3 bytes"),
                ));
            }
            _ => {}
        }
        at += 12 + len;
    }
    reader.seek(SeekFrom::Start(0)).map_err(io)?;
    Ok(())
}

/// Decodes a PNG file whose signature was already checked. A panic inside the decoder (a bug
/// of the `png` or `image` crate on a hostile file) is reported as a corrupt file, not passed
/// on (see [`super::guard_decoder`]).
pub(super) fn decode(
    path: &Path,
    mut reader: impl BufRead + Seek,
    opts: &LoadOptions,
) -> Result<Decoded, RasterError> {
    check_chunks(path, &mut reader)?;
    super::guard_decoder(path, FORMAT, || decode_checked(path, reader, opts))
}

fn decode_checked(
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
    let color_name = color_words(color);
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
            if let Some(e @ (HeightEncoding::TerrainRgb | HeightEncoding::Terrarium)) = opts.encoding {
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
                Some(HeightEncoding::TerrainRgb) => terrain_rgb,
                Some(HeightEncoding::Terrarium) => terrarium,
                Some(e @ HeightEncoding::Gray16) => return Err(mismatch(e)),
                None => {
                    return Err(RasterError::MissingEncoding { path: path.to_owned(), color: color_name });
                }
            };
            let format = if opts.encoding == Some(HeightEncoding::TerrainRgb) {
                "png-terrain-rgb"
            } else {
                "png-terrarium"
            };
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
                    "its samples are {color_name}; expected 8/16-bit grayscale or 8-bit RGB/RGBA (terrain-RGB, Terrarium)"
                ),
            ));
        }
    };
    Ok(Decoded { width, height, values, georef: FileGeoref::None, crs: super::FileCrs::default(), format })
}

/// A PNG's colour type in the words of its format's users ("8-bit RGB", "16-bit grayscale").
fn color_words(color: image::ColorType) -> String {
    use image::ColorType as C;
    match color {
        C::L8 => "8-bit grayscale",
        C::La8 => "8-bit grayscale with alpha",
        C::Rgb8 => "8-bit RGB",
        C::Rgba8 => "8-bit RGBA",
        C::L16 => "16-bit grayscale",
        C::La16 => "16-bit grayscale with alpha",
        C::Rgb16 => "16-bit RGB",
        C::Rgba16 => "16-bit RGBA",
        C::Rgb32F => "32-bit float RGB",
        C::Rgba32F => "32-bit float RGBA",
        _ => {
            return format!(
                "{} bits per pixel in {} channels",
                color.bits_per_pixel(),
                color.channel_count()
            );
        }
    }
    .to_owned()
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

#[cfg(test)]
// A failed unwrap is the test failing; exact float comparisons are of exactly representable values.
#[allow(clippy::unwrap_used, clippy::float_cmp)]
mod tests {
    use std::path::{Path, PathBuf};
    use std::time::Instant;

    use image::{ImageBuffer, Luma, Rgb, Rgba};

    use super::super::test_util::{assert_names_path, load, write};
    use super::super::{HeightEncoding, LoadOptions, RasterError, load as load_with};

    fn with_encoding(
        path: &Path,
        encoding: HeightEncoding,
    ) -> Result<super::super::LoadedRaster, RasterError> {
        load_with(path, &LoadOptions { encoding: Some(encoding), ..LoadOptions::default() })
    }

    /// A PNG chunk: length, type, data, CRC over type + data.
    fn chunk(kind: [u8; 4], data: &[u8]) -> Vec<u8> {
        let mut out = (data.len() as u32).to_be_bytes().to_vec();
        out.extend_from_slice(&kind);
        out.extend_from_slice(data);
        let mut crc = crc32fast::Hasher::new();
        crc.update(&kind);
        crc.update(data);
        out.extend_from_slice(&crc.finalize().to_be_bytes());
        out
    }

    /// A PNG that declares `w × h` 16-bit gray samples but carries only a token IDAT.
    fn declared_png(w: u32, h: u32) -> Vec<u8> {
        let mut ihdr = w.to_be_bytes().to_vec();
        ihdr.extend_from_slice(&h.to_be_bytes());
        ihdr.extend_from_slice(&[16, 0, 0, 0, 0]);
        let mut png = b"\x89PNG\r\n\x1a\n".to_vec();
        png.extend(chunk(*b"IHDR", &ihdr));
        png.extend(chunk(*b"IDAT", &[0x78, 0x9c, 0x03, 0x00, 0x00, 0x00, 0x00, 0x01]));
        png.extend(chunk(*b"IEND", &[]));
        png
    }

    fn save_rgb(dir: &Path, pixels: &[[u8; 3]]) -> PathBuf {
        let p = dir.join("rgb.png");
        let raw: Vec<u8> = pixels.iter().flatten().copied().collect();
        ImageBuffer::<Rgb<u8>, _>::from_raw(pixels.len() as u32, 1, raw).unwrap().save(&p).unwrap();
        p
    }

    #[test]
    fn gray16_values() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("h.png");
        let data: Vec<u16> = (0..12).map(|i| i * 5000).collect();
        ImageBuffer::<Luma<u16>, _>::from_raw(4, 3, data.clone()).unwrap().save(&p).unwrap();
        let r = load(&p).unwrap();
        assert_eq!((r.heights.width, r.heights.height, r.format.as_str()), (4, 3, "png-gray16"));
        assert_eq!(r.heights.data, data.iter().map(|&v| f32::from(v)).collect::<Vec<_>>());
        assert_eq!(r.heights.get(3, 2), 55_000.0);
        assert_eq!(r.nodata_filled, 0);
        // Explicit Gray16 gives the same.
        assert_eq!(with_encoding(&p, HeightEncoding::Gray16).unwrap().heights.data, r.heights.data);
        // A gray PNG is not terrain-RGB.
        let e = with_encoding(&p, HeightEncoding::TerrainRgb).unwrap_err();
        assert!(matches!(e, RasterError::EncodingMismatch { .. }), "{e}");
        assert_names_path(&e, &p);
    }

    #[test]
    fn gray8_values_are_not_widened() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("h8.png");
        ImageBuffer::<Luma<u8>, _>::from_raw(3, 1, vec![0, 7, 255]).unwrap().save(&p).unwrap();
        let r = load(&p).unwrap();
        assert_eq!(r.format, "png-gray8");
        assert_eq!(r.heights.data, [0.0, 7.0, 255.0]);
    }

    #[test]
    fn terrain_rgb_and_terrarium() {
        let dir = tempfile::tempdir().unwrap();
        // terrain-RGB: (1, 134, 160) = 100000 → 0 m; (1, 134, 170) → 1 m.
        let p = save_rgb(dir.path(), &[[1, 134, 160], [1, 134, 170], [128, 100, 128]]);
        let r = with_encoding(&p, HeightEncoding::TerrainRgb).unwrap();
        assert_eq!(r.format, "png-terrain-rgb");
        assert!(
            r.heights.data[0].abs() < 1e-3 && (r.heights.data[1] - 1.0).abs() < 1e-3,
            "{:?}",
            r.heights.data
        );
        let r = with_encoding(&p, HeightEncoding::Terrarium).unwrap();
        assert_eq!(r.format, "png-terrarium");
        assert_eq!(r.heights.data[2], 100.5);
        let e = load(&p).unwrap_err();
        assert!(matches!(e, RasterError::MissingEncoding { .. }), "{e}");
        let e = with_encoding(&p, HeightEncoding::Gray16).unwrap_err();
        assert!(matches!(e, RasterError::EncodingMismatch { .. }), "{e}");
    }

    #[test]
    fn rgba_ignores_alpha() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("rgba.png");
        ImageBuffer::<Rgba<u8>, _>::from_raw(1, 1, vec![128, 1, 0, 0]).unwrap().save(&p).unwrap();
        assert_eq!(with_encoding(&p, HeightEncoding::Terrarium).unwrap().heights.data, [1.0]);
    }

    #[test]
    fn rgb16_is_unsupported() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("rgb16.png");
        ImageBuffer::<Rgb<u16>, _>::from_raw(1, 1, vec![1, 2, 3]).unwrap().save(&p).unwrap();
        let e = with_encoding(&p, HeightEncoding::TerrainRgb).unwrap_err();
        assert!(matches!(e, RasterError::Unsupported { .. }), "{e}");
        assert_names_path(&e, &p);
    }

    #[test]
    fn truncated_png() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("t.png");
        let data: Vec<u16> = (0..64 * 64).map(|i| (i * 7919 % 65_536) as u16).collect();
        ImageBuffer::<Luma<u16>, _>::from_raw(64, 64, data).unwrap().save(&p).unwrap();
        let bytes = std::fs::read(&p).unwrap();
        for cut in [20, 40, bytes.len() / 2, bytes.len() - 13] {
            let t = write(dir.path(), "cut.png", &bytes[..cut]);
            let e = load(&t).unwrap_err();
            assert!(matches!(e, RasterError::Corrupt { .. }), "cut {cut}: {e}");
            assert_names_path(&e, &t);
        }
    }

    #[test]
    fn huge_declared_size_fails_fast() {
        let dir = tempfile::tempdir().unwrap();
        let p = write(dir.path(), "huge.png", &declared_png(100_000, 100_000));
        let start = Instant::now();
        let e = load(&p).unwrap_err();
        assert!(matches!(e, RasterError::TooLarge { width: 100_000, height: 100_000, .. }), "{e}");
        assert!(start.elapsed().as_millis() < 500);
        assert_names_path(&e, &p);
    }

    #[test]
    fn zero_size_png_is_an_error() {
        let dir = tempfile::tempdir().unwrap();
        let p = write(dir.path(), "zero.png", &declared_png(0, 10));
        let e = load(&p).unwrap_err();
        assert!(matches!(e, RasterError::Corrupt { .. } | RasterError::ZeroSize { .. }), "{e}");
        assert_names_path(&e, &p);
    }
}
