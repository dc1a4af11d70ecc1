//! OBJ models: any bytes through `terrastream::mesh::parse`.
#![no_main]
use libfuzzer_sys::fuzz_target;
use terrastream::mesh::FileType;

fuzz_target!(|data: &[u8]| {
    terrastream_fuzz::check_model(data, FileType::Obj);
});
