//! PNG as 16-bit (or 8-bit) grayscale heights: any bytes through the raster loader.
#![no_main]
use libfuzzer_sys::fuzz_target;
use terrastream::raster::HeightEncoding;

fuzz_target!(|data: &[u8]| {
    // Both ways a gray PNG is read: the default (None) and the explicit encoding.
    terrastream_fuzz::check_raster("fuzz.png", data, None, None);
    terrastream_fuzz::check_raster("fuzz.png", data, Some(HeightEncoding::Gray16), None);
});
