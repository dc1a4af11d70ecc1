//! Byte streams inside a payload: LEB128 varints, zigzag signs, and the container that packs
//! several streams behind a small table of lengths.
//!
//! Each geometric quantity (gaps, run codes, residuals, normals…) gets its own stream so that the
//! zstd stage sees bytes of one statistic at a time; mixing them would dilute its literal
//! Huffman tables and hide repeats.

use std::io::Read;

use super::CodecError;

/// Most streams a container may hold; a decoded count above this is corruption.
pub(crate) const MAX_STREAMS: usize = 16;

/// An append-only byte stream.
#[derive(Debug, Default, Clone)]
pub(crate) struct Writer {
    pub(crate) bytes: Vec<u8>,
}

impl Writer {
    pub(crate) fn u8(&mut self, v: u8) {
        self.bytes.push(v);
    }

    /// Unsigned LEB128: 7 bits per byte, high bit set on all but the last byte.
    pub(crate) fn varint(&mut self, mut v: u64) {
        while v >= 0x80 {
            self.bytes.push((v as u8) | 0x80);
            v >>= 7;
        }
        self.bytes.push(v as u8);
    }

    /// Signed value as zigzag LEB128 so that small magnitudes of either sign stay one byte.
    pub(crate) fn signed(&mut self, v: i64) {
        self.varint(zigzag(v));
    }
}

/// A cursor over one stream; every read is bounds-checked and reports corruption instead of
/// panicking.
#[derive(Debug, Clone)]
pub(crate) struct Reader<'a> {
    bytes: &'a [u8],
    pos: usize,
    name: &'static str,
}

impl<'a> Reader<'a> {
    pub(crate) fn new(bytes: &'a [u8], name: &'static str) -> Self {
        Self { bytes, pos: 0, name }
    }

    pub(crate) fn len(&self) -> usize {
        self.bytes.len()
    }

    pub(crate) fn u8(&mut self) -> Result<u8, CodecError> {
        let v = *self.bytes.get(self.pos).ok_or(CodecError::Corrupt(self.name))?;
        self.pos += 1;
        Ok(v)
    }

    pub(crate) fn varint(&mut self) -> Result<u64, CodecError> {
        let mut v = 0u64;
        for shift in (0..64).step_by(7) {
            let b = self.u8()?;
            // The tenth byte may only carry the single remaining bit.
            if shift == 63 && b > 1 {
                return Err(CodecError::Corrupt(self.name));
            }
            v |= u64::from(b & 0x7f) << shift;
            if b & 0x80 == 0 {
                return Ok(v);
            }
        }
        Err(CodecError::Corrupt(self.name))
    }

    pub(crate) fn signed(&mut self) -> Result<i64, CodecError> {
        Ok(unzigzag(self.varint()?))
    }

    /// The bytes not read yet.
    pub(crate) fn rest(&self) -> &'a [u8] {
        self.bytes.get(self.pos..).unwrap_or_default()
    }

    /// A varint that must fit `usize` and be at most `max`.
    pub(crate) fn count(&mut self, max: usize) -> Result<usize, CodecError> {
        let v = self.varint()?;
        usize::try_from(v).ok().filter(|&v| v <= max).ok_or(CodecError::Corrupt(self.name))
    }

    /// Fails unless every byte was consumed: leftover bytes mean the counts and the streams
    /// disagree, which a checksum-valid blob from this encoder never does.
    pub(crate) fn finish(&self) -> Result<(), CodecError> {
        if self.pos == self.bytes.len() { Ok(()) } else { Err(CodecError::Corrupt(self.name)) }
    }
}

/// Values of wide range (residuals): a byte "bucket" symbol naming the bit length and the two
/// bits after the leading one, plus the remaining low bits verbatim in a second stream.
///
/// zstd's entropy stage is order-0 Huffman over bytes, so a varint's low byte — nearly uniform
/// when values are large — pollutes the statistics of the small ones. Bucketing keeps all the
/// skew in one byte stream (which zstd codes close to its entropy) and only the incompressible
/// low bits in the other, like Exp-Golomb coding with four sub-buckets per octave.
#[derive(Debug, Default, Clone)]
pub(crate) struct BucketWriter {
    pub(crate) symbols: Writer,
    pub(crate) bits: Writer,
    acc: u64,
    used: u32,
}

impl BucketWriter {
    pub(crate) fn put(&mut self, u: u64) {
        if u < 4 {
            self.symbols.u8(u as u8);
            return;
        }
        let b = 64 - u.leading_zeros();
        let top = (u >> (b - 3)) & 3;
        self.symbols.u8((4 + 4 * (b - 3) + top as u32) as u8);
        self.put_bits(u & ((1u64 << (b - 3)) - 1), b - 3);
    }

    pub(crate) fn signed(&mut self, v: i64) {
        self.put(zigzag(v));
    }

    fn put_bits(&mut self, v: u64, n: u32) {
        // Split so the accumulator never needs more than 64 bits.
        let (lo, hi) = if n > 32 { (v & 0xffff_ffff, n - 32) } else { (v, 0) };
        let nlo = n - hi;
        self.acc |= lo << self.used;
        self.used += nlo;
        while self.used >= 8 {
            self.bits.u8(self.acc as u8);
            self.acc >>= 8;
            self.used -= 8;
        }
        if hi > 0 {
            self.put_bits(v >> 32, hi);
        }
    }

    /// Flushes the last partial byte (zero-padded).
    pub(crate) fn finish(mut self) -> (Writer, Writer) {
        if self.used > 0 {
            self.bits.u8(self.acc as u8);
        }
        (self.symbols, self.bits)
    }
}

/// Reads what [`BucketWriter`] wrote.
#[derive(Debug, Clone)]
pub(crate) struct BucketReader<'a> {
    symbols: Reader<'a>,
    bits: &'a [u8],
    pos: usize,
    acc: u64,
    used: u32,
}

impl<'a> BucketReader<'a> {
    pub(crate) fn new(symbols: Reader<'a>, bits: &Reader<'a>) -> Self {
        Self { symbols, bits: bits.bytes, pos: 0, acc: 0, used: 0 }
    }

    /// Number of values present at most (one symbol byte each).
    pub(crate) fn len(&self) -> usize {
        self.symbols.len()
    }

    pub(crate) fn get(&mut self) -> Result<u64, CodecError> {
        let s = u32::from(self.symbols.u8()?);
        if s < 4 {
            return Ok(u64::from(s));
        }
        let b = (s - 4) / 4 + 3;
        if b > 64 {
            return Err(CodecError::Corrupt(self.symbols.name));
        }
        let top = u64::from((s - 4) % 4);
        let low = self.get_bits(b - 3)?;
        Ok(((4 | top) << (b - 3)) | low)
    }

    pub(crate) fn signed(&mut self) -> Result<i64, CodecError> {
        Ok(unzigzag(self.get()?))
    }

    fn get_bits(&mut self, n: u32) -> Result<u64, CodecError> {
        if n > 32 {
            let lo = self.get_bits(32)?;
            return Ok(lo | (self.get_bits(n - 32)? << 32));
        }
        while self.used < n {
            let b = *self.bits.get(self.pos).ok_or(CodecError::Corrupt(self.symbols.name))?;
            self.pos += 1;
            self.acc |= u64::from(b) << self.used;
            self.used += 8;
        }
        let v = self.acc & ((1u64 << n) - 1);
        self.acc >>= n;
        self.used -= n;
        Ok(v)
    }

    /// Fails unless both streams were consumed exactly (padding bits zero).
    pub(crate) fn finish(&self) -> Result<(), CodecError> {
        self.symbols.finish()?;
        if self.pos == self.bits.len() && self.acc == 0 {
            Ok(())
        } else {
            Err(CodecError::Corrupt(self.symbols.name))
        }
    }
}

pub(crate) fn zigzag(v: i64) -> u64 {
    ((v << 1) ^ (v >> 63)) as u64
}

pub(crate) fn unzigzag(v: u64) -> i64 {
    ((v >> 1) as i64) ^ -((v & 1) as i64)
}

/// Stream stored as is (zstd would not make it smaller).
const STORED: u8 = 0;
/// Stream stored as one zstd frame.
const ZSTD: u8 = 1;
/// Bytes of the table entry of one stream: method, raw length, stored length.
const ENTRY: usize = 9;

/// A payload ready to store, and the total size of its streams once decompressed.
#[derive(Debug, Clone)]
pub(crate) struct Packed {
    pub(crate) payload: Vec<u8>,
    pub(crate) raw_len: usize,
}

/// Packs `mode` and `streams` as `mode u8 | count u8 | (method u8, raw_len u32, stored_len u32)
/// × count | stored bytes…`, each stream compressed on its own.
///
/// Separate frames let zstd build entropy tables per stream; one frame over the concatenation
/// measured 5–7 % larger because its blocks straddle streams. A stream zstd cannot shrink
/// (the verbatim low bits of residuals) is stored.
pub(crate) fn pack(mode: u8, streams: &[&Writer]) -> Result<Packed, CodecError> {
    let too_large = |count: usize| CodecError::TooLarge {
        what: "payload bytes",
        count,
        max: super::MAX_RAW_LEN as usize,
    };
    let mut table = vec![mode, u8::try_from(streams.len()).map_err(|_| CodecError::Corrupt("stream table"))?];
    let mut data = Vec::new();
    let mut raw_len = 0usize;
    for s in streams {
        let raw = &s.bytes;
        raw_len += raw.len();
        let z = compress(raw)?;
        let (method, stored) =
            if z.len() < raw.len() { (ZSTD, z.as_slice()) } else { (STORED, raw.as_slice()) };
        table.push(method);
        table.extend_from_slice(&u32::try_from(raw.len()).map_err(|_| too_large(raw.len()))?.to_le_bytes());
        table.extend_from_slice(
            &u32::try_from(stored.len()).map_err(|_| too_large(stored.len()))?.to_le_bytes(),
        );
        data.extend_from_slice(stored);
    }
    if raw_len > super::MAX_RAW_LEN as usize {
        return Err(too_large(raw_len));
    }
    table.extend_from_slice(&data);
    Ok(Packed { payload: table, raw_len })
}

/// As [`pack`], but every stream stored as is: for streams that are already entropy coded
/// (zstd would only cost time to find it cannot shrink them).
pub(crate) fn pack_stored(mode: u8, streams: &[&Writer]) -> Result<Packed, CodecError> {
    let too_large = |count: usize| CodecError::TooLarge {
        what: "payload bytes",
        count,
        max: super::MAX_RAW_LEN as usize,
    };
    let mut table = vec![mode, u8::try_from(streams.len()).map_err(|_| CodecError::Corrupt("stream table"))?];
    let mut raw_len = 0usize;
    for s in streams {
        let len = u32::try_from(s.bytes.len()).map_err(|_| too_large(s.bytes.len()))?.to_le_bytes();
        raw_len += s.bytes.len();
        table.push(STORED);
        table.extend_from_slice(&len);
        table.extend_from_slice(&len);
    }
    if raw_len > super::MAX_RAW_LEN as usize {
        return Err(too_large(raw_len));
    }
    for s in streams {
        table.extend_from_slice(&s.bytes);
    }
    Ok(Packed { payload: table, raw_len })
}

thread_local! {
    /// One compression context per thread, reused: creating a zstd context (and zeroing its
    /// tables) cost 70 % of encoding a small blob. A reused context starts every frame afresh,
    /// so the bytes are those of a new context's (the golden hashes hold them).
    static COMPRESSOR: std::cell::RefCell<Option<zstd::bulk::Compressor<'static>>> =
        const { std::cell::RefCell::new(None) };
}

/// Compresses one stream as one zstd frame at [`super::ZSTD_LEVEL`].
fn compress(raw: &[u8]) -> Result<Vec<u8>, CodecError> {
    COMPRESSOR.with(|cell| {
        let mut slot = cell.borrow_mut();
        let c = match &mut *slot {
            Some(c) => c,
            None => {
                slot.insert(zstd::bulk::Compressor::new(super::ZSTD_LEVEL).map_err(CodecError::Compress)?)
            }
        };
        c.compress(raw).map_err(CodecError::Compress)
    })
}

/// The streams of a payload, decompressed.
#[derive(Debug, Clone)]
pub(crate) struct Unpacked {
    pub(crate) mode: u8,
    bufs: Vec<Vec<u8>>,
    names: Vec<&'static str>,
}

impl Unpacked {
    /// Flips bits in one decompressed stream and packs again, so fuzz tests reach the decoders
    /// behind the zstd frames.
    #[cfg(test)]
    pub(crate) fn mutate_and_pack(&self, stream: usize, flips: &[(usize, u8)]) -> Result<Packed, CodecError> {
        let mut bufs = self.bufs.clone();
        let s = stream % bufs.len();
        for &(at, bit) in flips {
            if !bufs[s].is_empty() {
                let len = bufs[s].len();
                bufs[s][at % len] ^= 1 << (bit % 8);
            }
        }
        let writers: Vec<Writer> = bufs.into_iter().map(|bytes| Writer { bytes }).collect();
        let refs: Vec<&Writer> = writers.iter().collect();
        pack(self.mode, &refs)
    }

    pub(crate) fn readers(&self) -> Vec<Reader<'_>> {
        self.bufs.iter().zip(&self.names).map(|(b, &n)| Reader::new(b, n)).collect()
    }
}

/// Splits and decompresses a payload made by [`pack`]. The stream count must be `names.len()`,
/// the raw lengths must add up to `raw_len` (from the header), every stream must decompress to
/// exactly its raw length, and the stored lengths must cover the payload exactly.
pub(crate) fn unpack(payload: &[u8], raw_len: usize, names: &[&'static str]) -> Result<Unpacked, CodecError> {
    let bad = || CodecError::Corrupt("stream table");
    let (&mode, rest) = payload.split_first().ok_or_else(bad)?;
    let (&count, mut rest) = rest.split_first().ok_or_else(bad)?;
    let count = usize::from(count);
    if count != names.len() || count > MAX_STREAMS || rest.len() < count * ENTRY {
        return Err(bad());
    }
    let mut entries = Vec::with_capacity(count);
    let mut total = 0usize;
    for _ in 0..count {
        let (e, tail) = rest.split_first_chunk::<ENTRY>().ok_or_else(bad)?;
        let raw = u32::from_le_bytes([e[1], e[2], e[3], e[4]]) as usize;
        let stored = u32::from_le_bytes([e[5], e[6], e[7], e[8]]) as usize;
        total = total.checked_add(raw).ok_or_else(bad)?;
        entries.push((e[0], raw, stored));
        rest = tail;
    }
    if total != raw_len {
        return Err(CodecError::RawLength { declared: raw_len, actual: total });
    }
    let mut bufs = Vec::with_capacity(count);
    for (method, raw, stored) in entries {
        if stored > rest.len() {
            return Err(bad());
        }
        let (head, tail) = rest.split_at(stored);
        rest = tail;
        bufs.push(match method {
            STORED if stored == raw => head.to_vec(),
            ZSTD => decompress(head, raw)?,
            _ => return Err(bad()),
        });
    }
    if !rest.is_empty() {
        return Err(bad());
    }
    Ok(Unpacked { mode, bufs, names: names.to_vec() })
}

/// Decompresses one frame to exactly `raw_len` bytes, never holding more than `raw_len + 1`.
fn decompress(frame: &[u8], raw_len: usize) -> Result<Vec<u8>, CodecError> {
    let mut decoder =
        zstd::stream::read::Decoder::with_buffer(frame).map_err(CodecError::Decompress)?.single_frame();
    decoder.window_log_max(super::ZSTD_WINDOW_LOG_MAX).map_err(CodecError::Decompress)?;
    // Grow as data arrives rather than trusting raw_len up front: a forged table cannot make us
    // reserve memory the frame does not fill.
    let mut out = Vec::with_capacity(raw_len.min(1 << 16));
    decoder.take(raw_len as u64 + 1).read_to_end(&mut out).map_err(CodecError::Decompress)?;
    if out.len() != raw_len {
        return Err(CodecError::RawLength { declared: raw_len, actual: out.len() });
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    // Exact float equality is the point of these tests: decoding must be bit-exact.
    #![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic, clippy::float_cmp)]

    use super::*;
    use proptest::prelude::*;

    proptest! {
        #[test]
        fn varint_round_trip(v in any::<u64>(), s in any::<i64>()) {
            let mut w = Writer::default();
            w.varint(v);
            w.signed(s);
            let mut r = Reader::new(&w.bytes, "t");
            prop_assert_eq!(r.varint().unwrap(), v);
            prop_assert_eq!(r.signed().unwrap(), s);
            prop_assert!(r.finish().is_ok());
        }

        #[test]
        fn varint_never_panics(bytes in proptest::collection::vec(any::<u8>(), 0..16)) {
            let mut r = Reader::new(&bytes, "t");
            let _ = r.varint();
        }

        #[test]
        fn unpack_never_panics(bytes in proptest::collection::vec(any::<u8>(), 0..64), raw in 0usize..100) {
            let _ = unpack(&bytes, raw, &["a", "b"]);
        }
    }

    #[test]
    fn small_values_are_one_byte() {
        let mut w = Writer::default();
        w.varint(127);
        w.signed(-64);
        w.signed(63);
        assert_eq!(w.bytes.len(), 3);
    }

    #[test]
    fn overlong_varint_is_corrupt() {
        let bytes = [0xffu8; 11];
        assert!(Reader::new(&bytes, "t").varint().is_err());
        let mut ten = [0x80u8; 10];
        ten[9] = 0x02;
        assert!(Reader::new(&ten, "t").varint().is_err());
    }

    #[test]
    fn pack_unpack_round_trip() {
        let mut a = Writer::default();
        for i in 0..1000u64 {
            a.varint(i % 7);
        }
        let b = Writer::default();
        let mut c = Writer::default();
        c.varint(300);
        let p = pack(7, &[&a, &b, &c]).unwrap();
        assert_eq!(p.raw_len, a.bytes.len() + 2);
        // The repetitive stream is compressed, the tiny one stored.
        assert_eq!(p.payload[2], ZSTD);
        assert_eq!(p.payload[2 + 2 * ENTRY], STORED);
        let u = unpack(&p.payload, p.raw_len, &["a", "b", "c"]).unwrap();
        assert_eq!(u.mode, 7);
        let rs = u.readers();
        assert_eq!(rs[0].len(), a.bytes.len());
        assert_eq!(rs[1].len(), 0);
        assert_eq!(rs[2].bytes, c.bytes.as_slice());
        assert!(unpack(&p.payload[..p.payload.len() - 1], p.raw_len, &["a", "b", "c"]).is_err());
        assert!(unpack(&p.payload, p.raw_len + 1, &["a", "b", "c"]).is_err());
        assert!(unpack(&p.payload, p.raw_len, &["a", "b"]).is_err());
    }

    #[test]
    fn zstd_bomb_is_capped() {
        // A frame that expands far beyond its declared raw length.
        let big = zstd::bulk::compress(&vec![0u8; 1 << 22], 3).unwrap();
        let mut payload = vec![0, 1, ZSTD];
        payload.extend_from_slice(&100u32.to_le_bytes());
        payload.extend_from_slice(&(big.len() as u32).to_le_bytes());
        payload.extend_from_slice(&big);
        assert!(matches!(unpack(&payload, 100, &["a"]), Err(CodecError::RawLength { declared: 100, .. })));
    }
}
