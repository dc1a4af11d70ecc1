//! `OpenEXR` heightfields via the `exr` crate: one channel of the largest resolution level, chosen
//! by name or, by default, the first f32/f16 channel. The header is read on its own first so the
//! declared size is checked before any pixel memory exists (the `exr` crate has no allocation
//! limit of its own). `OpenEXR` has no georeference; NaN/inf samples are no-data.

use std::io::{BufRead, Seek, SeekFrom};
use std::path::Path;

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
    let name = channel.name.clone();

    reader.seek(SeekFrom::Start(0)).map_err(|e| RasterError::io(path, e))?;
    let image = read()
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
        .from_buffered(reader)
        .map_err(|e| map_err(path, e))?;

    let layer = image.layer_data;
    let (width, height) = (layer.size.width(), layer.size.height());
    check_size(path, width as u64, height as u64, opts.limits)?;
    let (_, values) = layer.channel_data.pixels;
    Ok(Decoded {
        width: width as u32,
        height: height as u32,
        values,
        georef: FileGeoref::None,
        format: "exr",
    })
}
