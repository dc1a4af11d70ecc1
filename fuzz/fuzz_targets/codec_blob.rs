//! Blobs: any bytes through `codec::decode`; an `Ok` blob must agree with `decode_header`,
//! stay inside its bounds and re-encode to the same geometry.
//!
//! A mutated blob almost never keeps its two CRC-32s right, so the bytes are decoded twice:
//! as they are (the checksum and length checks), and with `payload_len`, the payload checksum
//! and the header checksum rewritten to fit them, so the fuzzer reaches the header values and
//! the payload decoders behind the checksums.
#![no_main]
use libfuzzer_sys::fuzz_target;
use terrastream::codec::PREFIX_LEN;

fuzz_target!(|data: &[u8]| {
    terrastream_fuzz::check_blob(data);
    if data.len() >= PREFIX_LEN {
        let mut b = data.to_vec();
        let payload_len = (b.len() - PREFIX_LEN) as u32;
        b[124..128].copy_from_slice(&payload_len.to_le_bytes());
        let crc = crc32fast::hash(&b[PREFIX_LEN..]);
        b[128..132].copy_from_slice(&crc.to_le_bytes());
        let crc = crc32fast::hash(&b[..132]);
        b[132..136].copy_from_slice(&crc.to_le_bytes());
        terrastream_fuzz::check_blob(&b);
    }
});
