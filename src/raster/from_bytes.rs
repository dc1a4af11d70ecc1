//! [`load_bytes`]: [`super::load`] for a raster already in memory, so fuzz targets and tests
//! can drive every decoder without a file. Same detection, decoders, limits, filling and frame.

use std::io::Cursor;
use std::path::Path;

use super::{Format, LoadOptions, LoadedRaster, RasterError, detect, finish, geotiff, hgt, openexr, png};

/// Decodes `bytes` as [`super::load`] decodes a file: `name` stands for the file's path (it
/// chooses `.hgt` by extension, gives an SRTM tile its position and starts every error message).
///
/// Errors: as [`super::load`], without the I/O ones.
pub fn load_bytes(name: &Path, bytes: &[u8], opts: &LoadOptions) -> Result<LoadedRaster, RasterError> {
    super::validate_overrides(name, &opts.overrides)?;
    let format = detect(name, &bytes[..bytes.len().min(8)])?;
    super::check_encoding(name, format, opts)?;
    let reader = Cursor::new(bytes);
    let decoded = match format {
        Format::Png => png::decode(name, reader, opts)?,
        Format::Tiff => geotiff::decode(name, reader, opts.limits)?,
        Format::Exr => openexr::decode(name, reader, opts)?,
        Format::Hgt => hgt::decode_bytes(name, bytes, opts.limits)?,
        Format::Vrt | Format::Las => return Err(super::not_in_memory(name, format)),
    };
    finish(name, decoded, &opts.overrides)
}

/// [`load_bytes`] of an SRTM `.hgt` tile with `side` samples a side instead of the format's
/// 1201 or 3601, through the same decoder, filling, frame and limits; for fuzz targets, which
/// cannot afford a 2.9 MB input per execution. Files never take this path.
///
/// Errors: as [`load_bytes`]; a length other than `side² · 2` is [`RasterError::HgtLength`].
#[doc(hidden)]
pub fn load_hgt_bytes_any_side(
    name: &Path,
    bytes: &[u8],
    side: u32,
    opts: &LoadOptions,
) -> Result<LoadedRaster, RasterError> {
    super::validate_overrides(name, &opts.overrides)?;
    let decoded = hgt::decode_bytes_any_side(name, bytes, side, opts.limits)?;
    finish(name, decoded, &opts.overrides)
}

#[cfg(test)]
#[allow(clippy::unwrap_used)]
mod tests {
    use std::path::Path;

    use super::super::test_util::write;
    use super::super::{HeightEncoding, LoadOptions, RasterError, load};
    use super::load_bytes;

    /// Whatever the format, bytes and file give the same raster or the same error.
    #[test]
    fn agrees_with_load() {
        let dir = tempfile::tempdir().unwrap();
        let png = {
            let img = image::ImageBuffer::<image::Luma<u16>, _>::from_fn(5, 3, |x, y| {
                image::Luma([(x * 7 + y) as u16])
            });
            let mut out = Vec::new();
            img.write_to(&mut std::io::Cursor::new(&mut out), image::ImageFormat::Png).unwrap();
            out
        };
        let mut hgt = vec![0_u8; 1201 * 1201 * 2];
        hgt[1] = 9;
        let cases: [(&str, Vec<u8>); 4] = [
            ("a.png", png.clone()),
            ("N35E138.hgt", hgt.clone()),
            ("x.hgt", hgt),
            ("short.hgt", vec![0; 10]),
        ];
        for (name, bytes) in cases {
            // `--encoding` applies to PNGs only (other files are refused with it).
            let encoding = (name == "a.png").then_some(HeightEncoding::Gray16);
            let opts = LoadOptions { encoding, ..LoadOptions::default() };
            let path = write(dir.path(), name, &bytes);
            match (load(&path, &opts), load_bytes(&path, &bytes, &opts)) {
                (Ok(a), Ok(b)) => {
                    assert_eq!(a.heights, b.heights, "{name}");
                    assert_eq!((a.georef, a.format), (b.georef, b.format), "{name}");
                }
                (Err(a), Err(b)) => assert_eq!(a.to_string(), b.to_string(), "{name}"),
                (a, b) => panic!("{name}: load {:?} but load_bytes {:?}", a.err(), b.err()),
            }
        }
        let e = load_bytes(Path::new("empty"), &[], &LoadOptions::default()).unwrap_err();
        assert!(matches!(e, RasterError::UnknownFormat { .. }), "{e}");
    }
}
