//! STL models: any bytes through `terrastream::model::parse`.
#![no_main]
use libfuzzer_sys::fuzz_target;
use terrastream::model::FileType;

fuzz_target!(|data: &[u8]| {
    terrastream_fuzz::check_model(data, FileType::Stl);
});
