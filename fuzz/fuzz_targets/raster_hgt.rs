//! SRTM .hgt: the file name (which gives the position) and the samples. Input: a name up to
//! the first `\n` (at most 40 bytes), then the data. SRTM tiles are only valid at 1201² or
//! 3601² samples (2.9 or 26 MB), far above any useful fuzz input, so when the name ends in `!`
//! the data is repeated to a full 1201² tile, so that the decode, fill and georeference paths
//! run too; else the bytes are used as they are (mostly the length error).
#![no_main]
use libfuzzer_sys::fuzz_target;

const TILE_3S: usize = 1201 * 1201 * 2;

fuzz_target!(|data: &[u8]| {
    let split = data.iter().take(41).position(|&b| b == b'\n');
    let (name, body) = match split {
        Some(i) => (&data[..i], &data[i + 1..]),
        None => (&b"N35E138.hgt"[..], data),
    };
    let Ok(name) = std::str::from_utf8(name) else { return };
    // Path separators would make `name` a directory path: keep it one file name.
    if name.contains('/') || name.contains('\0') {
        return;
    }
    let (name, tile) = match name.strip_suffix('!') {
        Some(n) => (n, true),
        None => (name, false),
    };
    if name.is_empty() {
        return;
    }
    if tile && !body.is_empty() {
        let full: Vec<u8> = body.iter().copied().cycle().take(TILE_3S).collect();
        terrastream_fuzz::check_raster(name, &full, None, None);
    } else {
        terrastream_fuzz::check_raster(name, body, None, None);
    }
});
