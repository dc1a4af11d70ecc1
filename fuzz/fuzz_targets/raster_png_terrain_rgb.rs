//! PNG as Mapbox terrain-RGB: any bytes through the raster loader.
#![no_main]
use libfuzzer_sys::fuzz_target;
use terrastream::raster::HeightEncoding;

fuzz_target!(|data: &[u8]| {
    terrastream_fuzz::check_raster("fuzz.png", data, Some(HeightEncoding::TerrainRgb), None);
});
