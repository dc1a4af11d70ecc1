//! Blobs: any bytes through `codec::decode`; an `Ok` blob must agree with `decode_header`,
//! stay inside its bounds and re-encode to the same geometry.
#![no_main]
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    terrastream_fuzz::check_blob(data);
});
