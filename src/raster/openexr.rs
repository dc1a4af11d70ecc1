//! `OpenEXR` heightfields via the `exr` crate: one channel of the largest resolution level, chosen
//! by name or, by default, the first f32/f16 channel. The header is read on its own first so the
//! declared size is checked before any pixel memory exists (the `exr` crate has no allocation
//! limit of its own). `OpenEXR` has no georeference; NaN/inf samples are no-data.

use std::io::{BufRead, Seek, SeekFrom};
use std::path::Path;

use exr::compression::Compression;
use exr::image::read::image::ReadLayers;
use exr::image::read::layers::ReadChannels;
use exr::image::read::read;
use exr::image::read::specific_channels::ReadSpecificChannel;
use exr::meta::MetaData;
use exr::meta::attribute::{ChannelDescription, SampleType};
use exr::meta::header::Header;

use super::{Decoded, FileGeoref, LoadOptions, RasterError, check_size};

const FORMAT: &str = "OpenEXR";

fn map_err(path: &Path, e: exr::error::Error) -> RasterError {
    match e {
        exr::error::Error::NotSupported(m) => RasterError::unsupported(path, FORMAT, m),
        exr::error::Error::Io(io) if io.kind() == std::io::ErrorKind::UnexpectedEof => {
            RasterError::corrupt(path, FORMAT, format!("unexpected end of file ({io})"))
        }
        // A seek to a garbage chunk offset fails with EINVAL ("Invalid argument"): that is the
        // file's fault, not the disk's.
        exr::error::Error::Io(io)
            if matches!(io.kind(), std::io::ErrorKind::InvalidInput | std::io::ErrorKind::InvalidData) =>
        {
            RasterError::corrupt(
                path,
                FORMAT,
                format!("a chunk offset or size points outside the file ({io})"),
            )
        }
        exr::error::Error::Io(io) => RasterError::io(path, io),
        other => RasterError::corrupt(path, FORMAT, other.to_string()),
    }
}

fn type_name(t: SampleType) -> &'static str {
    match t {
        SampleType::F16 => "f16",
        SampleType::F32 => "f32",
        SampleType::U32 => "u32",
    }
}

/// "Y (f32), Z (f16)" over every layer, for error messages.
fn available(headers: &[Header]) -> String {
    let names: Vec<String> = headers
        .iter()
        .flat_map(|h| h.channels.list.iter())
        .map(|c| format!("{} ({})", c.name, type_name(c.sample_type)))
        .collect();
    if names.is_empty() { "none".to_owned() } else { names.join(", ") }
}

/// The layer and channel to read: the first layer holding the named channel, else the first
/// float channel of any layer (the same layer `first_valid_layer` will pick when reading).
fn choose<'h>(
    path: &Path,
    headers: &'h [Header],
    name: Option<&str>,
) -> Result<(&'h Header, &'h ChannelDescription), RasterError> {
    let mut all = headers.iter().flat_map(|h| h.channels.list.iter().map(move |c| (h, c)));
    let found = match name {
        Some(n) => all.find(|(_, c)| c.name.eq(n)),
        None => all.find(|(_, c)| matches!(c.sample_type, SampleType::F16 | SampleType::F32)),
    };
    found.ok_or_else(|| match name {
        Some(n) => RasterError::ChannelNotFound {
            path: path.to_owned(),
            name: n.to_owned(),
            available: available(headers),
        },
        None => RasterError::NoFloatChannel { path: path.to_owned(), available: available(headers) },
    })
}

/// The most a compression method can shrink pixel data, generously rounded up: RLE codes at
/// most 128 bytes in 2; zlib (ZIP, PXR24) at most 1,032:1 (PXR24 first drops a quarter of f32
/// data); B44 packs 32 bytes into at least 3; PIZ (Huffman with run codes) and DWA have no tight
/// bound, so a loose one.
fn max_ratio(c: Compression) -> u64 {
    match c {
        Compression::Uncompressed => 1,
        Compression::RLE => 64,
        Compression::ZIP1 | Compression::ZIP16 => 1_100,
        Compression::PXR24 => 1_400,
        Compression::B44 | Compression::B44A => 11,
        _ => 8_192,
    }
}

/// The declared image against what the file can hold, before any pixel memory exists: the
/// chunk offset table alone takes 8 bytes per chunk, and the pixel data of every channel can
/// shrink at most by [`max_ratio`] of the header's compression. A small file declaring a huge
/// image is refused here instead of after the `exr` crate allocated it.
fn check_holdable(path: &Path, header: &Header, file_len: u64) -> Result<(), RasterError> {
    let (w, h) = (header.layer_size.width() as u64, header.layer_size.height() as u64);
    let chunks = header.chunk_count as u64;
    let table = chunks.saturating_mul(8);
    let pixel_bytes: u64 = header
        .channels
        .list
        .iter()
        .map(|c| match c.sample_type {
            SampleType::F16 => 2u64,
            SampleType::F32 | SampleType::U32 => 4,
        })
        .sum::<u64>()
        .saturating_mul(w)
        .saturating_mul(h);
    let ratio = max_ratio(header.compression);
    let holdable = file_len.saturating_sub(table).saturating_mul(ratio);
    if table > file_len || pixel_bytes > holdable {
        return Err(RasterError::corrupt(
            path,
            FORMAT,
            format!(
                "the header declares {w}×{h} pixels ({pixel_bytes} bytes of samples in {chunks} chunks, \
                 {:?} compression) but the file is only {file_len} bytes, which can hold at most {holdable}",
                header.compression
            ),
        ));
    }
    Ok(())
}

/// Decodes an `OpenEXR` file whose magic number was already checked.
pub(super) fn decode(
    path: &Path,
    mut reader: impl BufRead + Seek,
    opts: &LoadOptions,
) -> Result<Decoded, RasterError> {
    let meta = MetaData::read_from_buffered(&mut reader, false).map_err(|e| map_err(path, e))?;
    let (header, channel) = choose(path, &meta.headers, opts.channel.as_deref())?;
    if header.deep {
        return Err(RasterError::unsupported(path, FORMAT, "deep data; expected a flat image"));
    }
    if channel.sampling.x() != 1 || channel.sampling.y() != 1 {
        return Err(RasterError::unsupported(
            path,
            FORMAT,
            format!("channel {} is subsampled; expected one sample per pixel", channel.name),
        ));
    }
    let (w, h) = (header.layer_size.width(), header.layer_size.height());
    check_size(path, w as u64, h as u64, opts.limits)?;
    let file_len = reader.seek(SeekFrom::End(0)).map_err(|e| RasterError::io(path, e))?;
    check_holdable(path, header, file_len)?;
    let name = channel.name.clone();

    reader.seek(SeekFrom::Start(0)).map_err(|e| RasterError::io(path, e))?;
    // On this thread, so that a panic of the decoder reaches `guard_decoder` (exr's parallel
    // decompression runs blocks on a rayon pool, where a panic aborts the whole process).
    let image = super::guard_decoder(path, FORMAT, || {
        read()
            .no_deep_data()
            .largest_resolution_level()
            .specific_channels()
            .required(name)
            .collect_pixels(
                |size, _| (size.width(), vec![f32::NAN; size.area()]),
                |(width, values): &mut (usize, Vec<f32>), pos, (v,): (f32,)| {
                    // Positions come from the layer's own size; `get_mut` keeps a malformed block
                    // from indexing past the buffer.
                    if let Some(slot) = values.get_mut(pos.y() * *width + pos.x()) {
                        *slot = v;
                    }
                },
            )
            .first_valid_layer()
            .all_attributes()
            .non_parallel()
            .from_buffered(reader)
            .map_err(|e| map_err(path, e))
    })?;

    let layer = image.layer_data;
    let (width, height) = (layer.size.width(), layer.size.height());
    check_size(path, width as u64, height as u64, opts.limits)?;
    let (_, values) = layer.channel_data.pixels;
    Ok(Decoded {
        width: width as u32,
        height: height as u32,
        values,
        georef: FileGeoref::None,
        crs: super::FileCrs::default(),
        format: "exr",
    })
}

#[cfg(test)]
// A failed unwrap is the test failing; exact float comparisons are of exactly representable values.
#[allow(clippy::unwrap_used, clippy::float_cmp)]
mod tests {
    use std::path::{Path, PathBuf};
    use std::time::Instant;

    use exr::prelude::{
        AnyChannel, AnyChannels, FlatSamples, Image, Layer, LayerAttributes, WritableImage, f16,
    };

    use super::super::test_util::{assert_names_path, load, write};
    use super::super::{LoadOptions, RasterError, load as load_with};

    /// Writes a `w × h` EXR with the given channels (the writer sorts them by name).
    fn write_exr(dir: &Path, w: usize, h: usize, channels: Vec<AnyChannel<FlatSamples>>) -> PathBuf {
        let p = dir.join("h.exr");
        let layer = Layer::new(
            (w, h),
            LayerAttributes::default(),
            exr::prelude::Encoding::SMALL_LOSSLESS,
            AnyChannels::sort(channels.into()),
        );
        Image::from_layer(layer).write().to_file(&p).unwrap();
        p
    }

    fn three_channels(dir: &Path) -> PathBuf {
        let z: Vec<f32> = (0..12).map(|i| i as f32 * 1.5).collect();
        write_exr(
            dir,
            4,
            3,
            vec![
                AnyChannel::new("Z", FlatSamples::F32(z)),
                AnyChannel::new(
                    "H",
                    FlatSamples::F16((0..12).map(|i| f16::from_f32(i as f32 + 0.5)).collect()),
                ),
                AnyChannel::new("B", FlatSamples::U32(vec![7; 12])),
            ],
        )
    }

    fn with_channel(p: &Path, name: &str) -> Result<super::super::LoadedRaster, RasterError> {
        load_with(p, &LoadOptions { channel: Some(name.to_owned()), ..LoadOptions::default() })
    }

    #[test]
    fn default_is_first_float_channel() {
        let dir = tempfile::tempdir().unwrap();
        let p = three_channels(dir.path());
        let r = load(&p).unwrap();
        assert_eq!((r.heights.width, r.heights.height, r.format.as_str()), (4, 3, "exr"));
        assert_eq!(r.heights.data, (0..12).map(|i| i as f32 + 0.5).collect::<Vec<_>>());
    }

    #[test]
    fn channel_by_name() {
        let dir = tempfile::tempdir().unwrap();
        let p = three_channels(dir.path());
        let r = with_channel(&p, "Z").unwrap();
        assert_eq!(r.heights.get(3, 2), 16.5);
        // A u32 channel named explicitly is read as values.
        assert_eq!(with_channel(&p, "B").unwrap().heights.data, [7.0; 12]);
        let e = with_channel(&p, "height").unwrap_err();
        assert!(matches!(e, RasterError::ChannelNotFound { .. }), "{e}");
        assert!(e.to_string().contains("B (u32), H (f16), Z (f32)"), "{e}");
        assert_names_path(&e, &p);
    }

    #[test]
    fn no_float_channel() {
        let dir = tempfile::tempdir().unwrap();
        let p = write_exr(dir.path(), 2, 2, vec![AnyChannel::new("id", FlatSamples::U32(vec![1; 4]))]);
        let e = load(&p).unwrap_err();
        assert!(matches!(e, RasterError::NoFloatChannel { .. }), "{e}");
        assert!(e.to_string().contains("id (u32)"), "{e}");
    }

    #[test]
    fn nan_and_inf_are_filled() {
        let dir = tempfile::tempdir().unwrap();
        let z = vec![1.0, 2.0, 3.0, f32::NAN, 5.0, f32::INFINITY, 7.0, 8.0, 9.0];
        let p = write_exr(dir.path(), 3, 3, vec![AnyChannel::new("Z", FlatSamples::F32(z))]);
        let r = load(&p).unwrap();
        assert_eq!(r.nodata_filled, 2);
        // (0,1): neighbours 1, 2, 5, 7, 8 → 4.6; (2,1): 2, 3, 5, 8, 9 → 5.4.
        assert!((r.heights.get(0, 1) - 4.6).abs() < 1e-5, "{:?}", r.heights.data);
        assert!((r.heights.get(2, 1) - 5.4).abs() < 1e-5, "{:?}", r.heights.data);
        let all_nan =
            write_exr(dir.path(), 2, 1, vec![AnyChannel::new("Z", FlatSamples::F32(vec![f32::NAN; 2]))]);
        assert!(matches!(load(&all_nan), Err(RasterError::AllNoData { .. })));
    }

    #[test]
    fn truncated() {
        let dir = tempfile::tempdir().unwrap();
        let z: Vec<f32> = (0..64 * 64).map(|i| (i as f32).sin()).collect();
        let p = write_exr(dir.path(), 64, 64, vec![AnyChannel::new("Z", FlatSamples::F32(z))]);
        let bytes = std::fs::read(&p).unwrap();
        for cut in [6, 50, bytes.len() / 2, bytes.len() - 10] {
            let t = write(dir.path(), "cut.exr", &bytes[..cut]);
            let e = load(&t).unwrap_err();
            assert!(matches!(e, RasterError::Corrupt { .. }), "cut {cut}: {e}");
            assert_names_path(&e, &t);
        }
    }

    #[test]
    fn huge_declared_size_fails_fast() {
        let dir = tempfile::tempdir().unwrap();
        let p = write_exr(dir.path(), 2, 2, vec![AnyChannel::new("Z", FlatSamples::F32(vec![1.0; 4]))]);
        let mut bytes = std::fs::read(&p).unwrap();
        // dataWindow is a box2i: xmin, ymin, xmax, ymax (i32 LE) after name, type and size.
        let key = b"dataWindow\0box2i\0";
        let at = bytes.windows(key.len()).position(|w| w == key).unwrap() + key.len() + 4;
        bytes[at + 8..at + 12].copy_from_slice(&99_999_i32.to_le_bytes());
        bytes[at + 12..at + 16].copy_from_slice(&99_999_i32.to_le_bytes());
        let t = write(dir.path(), "huge.exr", &bytes);
        let start = Instant::now();
        let e = load(&t).unwrap_err();
        assert!(matches!(e, RasterError::TooLarge { width: 100_000, height: 100_000, .. }), "{e}");
        assert!(start.elapsed().as_millis() < 500);
    }

    /// D5: a header within the size limits (32000² f32 is 3.8 GiB, under the default 4 GiB) in
    /// a file of a few hundred bytes is refused from the header, before the `exr` crate
    /// allocates the declared image.
    #[test]
    fn declared_size_beyond_what_the_file_holds() {
        let dir = tempfile::tempdir().unwrap();
        let p = write_exr(dir.path(), 2, 2, vec![AnyChannel::new("Z", FlatSamples::F32(vec![1.0; 4]))]);
        let mut bytes = std::fs::read(&p).unwrap();
        let key = b"dataWindow\0box2i\0";
        let at = bytes.windows(key.len()).position(|w| w == key).unwrap() + key.len() + 4;
        bytes[at + 8..at + 12].copy_from_slice(&31_999_i32.to_le_bytes());
        bytes[at + 12..at + 16].copy_from_slice(&31_999_i32.to_le_bytes());
        let t = write(dir.path(), "big.exr", &bytes);
        let e = load(&t).unwrap_err();
        assert!(matches!(e, RasterError::Corrupt { .. }), "{e}");
        assert!(e.to_string().contains("32000×32000") && e.to_string().contains("can hold"), "{e}");
        assert_names_path(&e, &t);
    }

    /// D8: the seek to a garbage chunk offset fails with EINVAL; that is corruption of the
    /// file, not "Invalid argument (os error 22)" from the disk.
    #[test]
    fn bad_offsets_are_corruption() {
        let p = Path::new("x.exr");
        let e = super::map_err(p, exr::error::Error::Io(std::io::Error::from_raw_os_error(22)));
        assert!(matches!(e, RasterError::Corrupt { .. }), "{e}");
        let e = super::map_err(p, exr::error::Error::Io(std::io::Error::from_raw_os_error(5)));
        assert!(matches!(e, RasterError::Io { .. }), "{e}");
    }
}
