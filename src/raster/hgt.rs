//! SRTM `.hgt` tiles: headerless big-endian i16 grids of 1201² (3 arc-second) or 3601²
//! (1 arc-second) samples covering one degree, with −32768 marking voids. The size comes from the
//! file length and the position from the file name (`N35E138.hgt`: the south-west corner), since
//! the file carries nothing else. Row 0 is the northern edge and the edge rows/columns are shared
//! with the neighbouring tiles, hence the `side − 1` steps per degree.

use std::io::Read;
use std::path::Path;

use super::{Decoded, FileGeoref, Limits, RasterError, check_size};

const VOID: i16 = i16::MIN;

/// (samples per side, arc-seconds per sample) for a file of `len` bytes.
fn side_for_len(len: u64) -> Option<u32> {
    [1201_u32, 3601].into_iter().find(|&s| u64::from(s) * u64::from(s) * 2 == len)
}

/// South-west corner (lat, lon) in whole degrees from a name like `N35E138.hgt` or
/// `s12w077.SRTMGL1.hgt`.
fn corner_from_name(name: &str) -> Option<(i32, i32)> {
    let b = name.as_bytes();
    if b.len() < 7 || !(b.len() == 7 || b[7] == b'.') {
        return None;
    }
    let digits = |s: &[u8]| -> Option<i32> {
        s.iter().try_fold(0_i32, |acc, &c| c.is_ascii_digit().then(|| acc * 10 + i32::from(c - b'0')))
    };
    let lat = digits(&b[1..3])?;
    let lon = digits(&b[4..7])?;
    let lat = match b[0].to_ascii_uppercase() {
        b'N' if lat <= 89 => lat,
        b'S' if lat <= 90 && lat >= 1 => -lat,
        _ => return None,
    };
    let lon = match b[3].to_ascii_uppercase() {
        b'E' if lon <= 179 => lon,
        b'W' if lon <= 180 && lon >= 1 => -lon,
        _ => return None,
    };
    Some((lat, lon))
}

/// Decodes an SRTM tile chosen by its `.hgt` extension.
pub(super) fn decode(path: &Path, mut reader: impl Read, limits: Limits) -> Result<Decoded, RasterError> {
    let name = path.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_default();
    let (south, west) = corner_from_name(&name)
        .ok_or_else(|| RasterError::HgtName { path: path.to_owned(), name: name.clone() })?;
    let len = std::fs::metadata(path).map_err(|e| RasterError::io(path, e))?.len();
    let side = side_for_len(len).ok_or(RasterError::HgtLength { path: path.to_owned(), len })?;
    check_size(path, side.into(), side.into(), limits)?;

    let mut bytes = vec![0_u8; len as usize];
    reader.read_exact(&mut bytes).map_err(|e| {
        if e.kind() == std::io::ErrorKind::UnexpectedEof {
            RasterError::corrupt(path, "SRTM .hgt", "file shrank while being read")
        } else {
            RasterError::io(path, e)
        }
    })?;
    let values = bytes
        .chunks_exact(2)
        .map(|c| match i16::from_be_bytes([c[0], c[1]]) {
            VOID => f32::NAN,
            v => f32::from(v),
        })
        .collect();

    let step = 1.0 / f64::from(side - 1);
    let georef = FileGeoref::Geographic {
        lon0: f64::from(west),
        lat0: f64::from(south) + 1.0,
        dlon: step,
        dlat: -step,
    };
    Ok(Decoded { width: side, height: side, values, georef, format: "hgt" })
}
