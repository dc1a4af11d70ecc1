//! SRTM `.hgt` tiles: headerless big-endian i16 grids of 1201² (3 arc-second) or 3601²
//! (1 arc-second) samples covering one degree, with −32768 marking voids. The size comes from the
//! file length and the position from the file name (`N35E138.hgt`: the south-west corner), since
//! the file carries nothing else. Row 0 is the northern edge and the edge rows/columns are shared
//! with the neighbouring tiles, hence the `side − 1` steps per degree.

use std::io::Read;
use std::path::Path;

use super::{Decoded, FileCrs, FileGeoref, Limits, RasterError, check_size};

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
        b'S' if (1..=90).contains(&lat) => -lat,
        _ => return None,
    };
    let lon = match b[3].to_ascii_uppercase() {
        b'E' if lon <= 179 => lon,
        b'W' if (1..=180).contains(&lon) => -lon,
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
    Ok(samples(&bytes, side, south, west))
}

/// Decodes an SRTM tile held in memory; `path` names it (position from its file name) and
/// appears in errors. The same checks as [`decode`], with the length taken from `bytes`.
pub(super) fn decode_bytes(path: &Path, bytes: &[u8], limits: Limits) -> Result<Decoded, RasterError> {
    let name = path.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_default();
    let (south, west) = corner_from_name(&name)
        .ok_or_else(|| RasterError::HgtName { path: path.to_owned(), name: name.clone() })?;
    let len = bytes.len() as u64;
    let side = side_for_len(len).ok_or(RasterError::HgtLength { path: path.to_owned(), len })?;
    decode_side(path, bytes, side, south, west, limits)
}

/// [`decode_bytes`] for a square of any `side` (the bytes must hold `side²` samples): the
/// same name parsing, limits and sample decoding without the rule that SRTM tiles are 1201² or
/// 3601². Only for fuzzing, where a 2.9 MB input per execution would run at 100 exec/s.
pub(super) fn decode_bytes_any_side(
    path: &Path,
    bytes: &[u8],
    side: u32,
    limits: Limits,
) -> Result<Decoded, RasterError> {
    let name = path.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_default();
    let (south, west) = corner_from_name(&name)
        .ok_or_else(|| RasterError::HgtName { path: path.to_owned(), name: name.clone() })?;
    let len = bytes.len() as u64;
    if side < 2 || u64::from(side) * u64::from(side) * 2 != len {
        return Err(RasterError::HgtLength { path: path.to_owned(), len });
    }
    decode_side(path, bytes, side, south, west, limits)
}

fn decode_side(
    path: &Path,
    bytes: &[u8],
    side: u32,
    south: i32,
    west: i32,
    limits: Limits,
) -> Result<Decoded, RasterError> {
    check_size(path, side.into(), side.into(), limits)?;
    Ok(samples(bytes, side, south, west))
}

/// Samples (voids as NaN) of big-endian i16 bytes.
pub(super) fn values(bytes: &[u8]) -> Vec<f32> {
    let mut out = Vec::with_capacity(bytes.len() / 2);
    extend_values(bytes, &mut out);
    out
}

/// [`values`] appended to `out` (a block reader's reused buffer).
pub(super) fn extend_values(bytes: &[u8], out: &mut Vec<f32>) {
    out.extend(bytes.chunks_exact(2).map(|c| match i16::from_be_bytes([c[0], c[1]]) {
        VOID => f32::NAN,
        v => f32::from(v),
    }));
}

/// The georeference of a `side²` tile whose south-west corner is (`south`, `west`) degrees.
fn georef(side: u32, south: i32, west: i32) -> FileGeoref {
    let step = 1.0 / f64::from(side - 1);
    FileGeoref::Geographic { lon0: f64::from(west), lat0: f64::from(south) + 1.0, dlon: step, dlat: -step }
}

/// What an SRTM tile's coordinates mean: WGS 84 longitude and latitude, heights above the EGM96
/// geoid (the SRTM product specification).
pub(super) fn file_crs() -> FileCrs {
    FileCrs { horizontal: Some(crate::crs::Crs::wgs84()), vertical: Some(crate::crs::VerticalDatum::Egm96) }
}

/// A tile's side and georeference from its name and length, without reading it.
pub(super) fn header(path: &Path) -> Result<(u32, FileGeoref), RasterError> {
    let name = path.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_default();
    let (south, west) = corner_from_name(&name)
        .ok_or_else(|| RasterError::HgtName { path: path.to_owned(), name: name.clone() })?;
    let len = std::fs::metadata(path).map_err(|e| RasterError::io(path, e))?.len();
    let side = side_for_len(len).ok_or(RasterError::HgtLength { path: path.to_owned(), len })?;
    Ok((side, georef(side, south, west)))
}

/// The samples of a `side²` tile whose south-west corner is (`south`, `west`) degrees.
fn samples(bytes: &[u8], side: u32, south: i32, west: i32) -> Decoded {
    Decoded {
        width: side,
        height: side,
        values: values(bytes),
        georef: georef(side, south, west),
        crs: file_crs(),
        format: "hgt",
    }
}

#[cfg(test)]
// A failed unwrap is the test failing; exact float comparisons are of exactly representable values.
#[allow(clippy::unwrap_used, clippy::float_cmp)]
mod tests {
    use super::super::test_util::{assert_names_path, load, write};
    use super::super::{LoadOptions, RasterError, load as load_with, metres_per_degree};
    use super::{Limits, corner_from_name};
    use std::path::Path;

    /// Big-endian i16 samples of a `side²` tile: value = row·10 + col % 7, voids where `void`.
    fn tile(side: usize, void: impl Fn(usize, usize) -> bool) -> Vec<u8> {
        let mut out = Vec::with_capacity(side * side * 2);
        for row in 0..side {
            for col in 0..side {
                let v = if void(col, row) { i16::MIN } else { (row * 10 + col % 7) as i16 };
                out.extend_from_slice(&v.to_be_bytes());
            }
        }
        out
    }

    #[test]
    fn names() {
        assert_eq!(corner_from_name("N35E138.hgt"), Some((35, 138)));
        assert_eq!(corner_from_name("s12w077.HGT"), Some((-12, -77)));
        assert_eq!(corner_from_name("N00E000.SRTMGL1.hgt"), Some((0, 0)));
        for bad in [
            "foo.hgt",
            "N35E13.hgt",
            "X35E138.hgt",
            "N35Q138.hgt",
            "N95E138.hgt",
            "N35E181.hgt",
            "N35E138x.hgt",
            "",
        ] {
            assert_eq!(corner_from_name(bad), None, "{bad}");
        }
    }

    #[test]
    fn three_arc_second_tile_with_voids() {
        let dir = tempfile::tempdir().unwrap();
        let voids = |c: usize, r: usize| (c == 5 && r == 5) || (r == 1200 && c < 3);
        let p = write(dir.path(), "N35E138.hgt", &tile(1201, voids));
        let r = load(&p).unwrap();
        assert_eq!((r.heights.width, r.heights.height, r.format.as_str()), (1201, 1201, "hgt"));
        assert_eq!(r.heights.get(0, 0), 0.0);
        assert_eq!(r.heights.get(6, 3), 36.0);
        assert_eq!(r.nodata_filled, 4);
        // (5, 5): neighbours are rows 4..6, cols 4..6 → mean of 44,45,46,54,56,64,65,66 = 55.
        assert!((r.heights.get(5, 5) - 55.0).abs() < 1e-4);
        // Bottom-left corner void run: (2, 1200) first from (1..3, 1199) and (3, 1200).
        assert!(r.heights.data.iter().all(|v| v.is_finite()));

        let g = r.georef;
        let m = g.crs.clone().unwrap();
        let step = 1.0 / 1200.0;
        assert_eq!((m.e0, m.n0, m.de, m.dn), (138.0, 36.0, step, -step));
        assert_eq!((m.crs.epsg(), g.vertical), (Some(4326), crate::crs::VerticalDatum::Egm96));
        let (m_lon, m_lat) = metres_per_degree(35.5);
        assert!((g.dx - step * m_lon).abs() < 1e-9 && (g.dy + step * m_lat).abs() < 1e-9);
        assert!((g.dx - 75.6).abs() < 0.5 && (g.dy + 92.4).abs() < 0.5, "{} {}", g.dx, g.dy);
    }

    #[test]
    fn one_arc_second_tile_southern_western() {
        let dir = tempfile::tempdir().unwrap();
        let p = write(dir.path(), "s12w077.HGT", &tile(3601, |_, _| false));
        let r = load(&p).unwrap();
        assert_eq!((r.heights.width, r.heights.height), (3601, 3601));
        let m = r.georef.crs.unwrap();
        assert_eq!((m.e0, m.n0, m.de, m.dn), (-77.0, -11.0, 1.0 / 3600.0, -1.0 / 3600.0));
    }

    #[test]
    fn limits_checked_from_length() {
        let dir = tempfile::tempdir().unwrap();
        let p = write(dir.path(), "N35E138.hgt", &tile(1201, |_, _| false));
        let limits = Limits { max_side: 1000, ..Limits::default() };
        let e = load_with(&p, &LoadOptions { limits, ..LoadOptions::default() }).unwrap_err();
        assert!(matches!(e, RasterError::TooLarge { width: 1201, .. }), "{e}");
    }

    #[test]
    fn malformed() {
        let dir = tempfile::tempdir().unwrap();
        let p = write(dir.path(), "N35E138.hgt", &[0; 1000]);
        let e = load(&p).unwrap_err();
        assert!(matches!(e, RasterError::HgtLength { len: 1000, .. }), "{e}");
        assert_names_path(&e, &p);
        let p = write(dir.path(), "N35E138.hgt", &[]);
        assert!(matches!(load(&p), Err(RasterError::HgtLength { len: 0, .. })));

        let p = write(dir.path(), "elevation.hgt", &tile(1201, |_, _| false));
        let e = load(&p).unwrap_err();
        assert!(matches!(e, RasterError::HgtName { .. }), "{e}");
        assert_names_path(&e, &p);

        let p = write(dir.path(), "N01W001.hgt", &tile(1201, |_, _| true));
        let e = load(&p).unwrap_err();
        assert!(matches!(e, RasterError::AllNoData { samples: 1_442_401, .. }), "{e}");
    }

    /// The fuzzing entry decodes a small square exactly as a full tile's corner would decode,
    /// and still refuses a length that is not `side² · 2` and a name without a position.
    #[test]
    fn any_side_for_fuzzing() {
        use super::super::load_hgt_bytes_any_side as any;
        let opts = LoadOptions::default();
        let voids = |c: usize, r: usize| c == 1 && r == 2;
        let r = any(Path::new("N35E138.hgt"), &tile(5, voids), 5, &opts).unwrap();
        assert_eq!((r.heights.width, r.heights.height, r.nodata_filled), (5, 5, 1));
        assert_eq!(r.heights.get(4, 3), 34.0);
        let m = r.georef.crs.clone().unwrap();
        assert_eq!((m.e0, m.n0, m.de, m.dn), (138.0, 36.0, 0.25, -0.25));
        for (bytes, side) in [(tile(5, voids), 4), (tile(1, |_, _| false), 1), (vec![0; 7], 2)] {
            let e = any(Path::new("N35E138.hgt"), &bytes, side, &opts).unwrap_err();
            assert!(matches!(e, RasterError::HgtLength { .. }), "{e}");
        }
        let e = any(Path::new("x.hgt"), &tile(5, voids), 5, &opts).unwrap_err();
        assert!(matches!(e, RasterError::HgtName { .. }), "{e}");
    }
}
