//! SRTM .hgt: the file name (which gives the position) and the samples. Input: a name up to
//! the first `\n` (at most 40 bytes), then the data. SRTM tiles are only valid at 1201² or
//! 3601² samples (2.9 or 26 MB), far above any useful fuzz input (a full 1201² tile per
//! execution runs at 100 exec/s), so when the name ends in `!` the first data byte chooses a
//! side of 2..=129 and the rest is repeated to `side²` samples, decoded by the same decoder,
//! filling, frame and limits through `load_hgt_bytes_any_side`; else the bytes go to
//! `load_bytes` as they are (the name and length checks). The full-size path is covered by the
//! unit tests in `src/raster/hgt.rs`.
#![no_main]
use libfuzzer_sys::fuzz_target;

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
    let (name, small) = match name.strip_suffix('!') {
        Some(n) => (n, true),
        None => (name, false),
    };
    if name.is_empty() {
        return;
    }
    match body.split_first() {
        Some((&s, rest)) if small && !rest.is_empty() => {
            let side = 2 + u32::from(s % 128);
            let n = side as usize * side as usize * 2;
            let full: Vec<u8> = rest.iter().copied().cycle().take(n).collect();
            terrastream_fuzz::check_hgt_any_side(name, &full, side);
        }
        _ => terrastream_fuzz::check_raster(name, body, None, None),
    }
});
