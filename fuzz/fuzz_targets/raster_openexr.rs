//! OpenEXR: any bytes through the raster loader, with the first float channel and by name.
#![no_main]
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    terrastream_fuzz::check_raster("fuzz.exr", data, None, None);
    terrastream_fuzz::check_raster("fuzz.exr", data, None, Some("Z"));
});
