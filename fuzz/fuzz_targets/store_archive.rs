//! Tileset archives (`.tsa`, `store::archive`), as `serve` reads them from a file, a bucket or
//! any host answering range requests: any bytes through `Archive::open`, its directory pages
//! and file reads; an `Ok` archive must keep the promises `check_archive` lists.
//!
//! A mutated archive almost never keeps its checksums right, so the bytes are read twice: as
//! they are, and with the footer's, the root's and every page's CRC-32 rewritten to fit them
//! (`fix_archive_checksums`), so the fuzzer reaches the directory values behind the checksums.
#![no_main]
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    terrastream_fuzz::check_archive(data);
    let mut b = data.to_vec();
    terrastream_fuzz::fix_archive_checksums(&mut b);
    if b != data {
        terrastream_fuzz::check_archive(&b);
    }
});
