//! TIFF/GeoTIFF: any bytes through the raster loader (the seeds carry the TIFF magic).
#![no_main]
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    terrastream_fuzz::check_raster("fuzz.tif", data, None, None);
});
