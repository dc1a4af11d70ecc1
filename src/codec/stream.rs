//! Byte streams inside a payload: LEB128 varints, zigzag signs, and the container that packs
//! several streams behind a small table of lengths.
//!
//! Each geometric quantity (gaps, run codes, residuals, normals…) gets its own stream so that the
//! zstd stage sees bytes of one statistic at a time; mixing them would dilute its literal
//! Huffman tables and hide repeats.

use super::CodecError;

/// Most streams a container may hold; a decoded count above this is corruption.
const MAX_STREAMS: usize = 16;

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

pub(crate) fn zigzag(v: i64) -> u64 {
    ((v << 1) ^ (v >> 63)) as u64
}

pub(crate) fn unzigzag(v: u64) -> i64 {
    ((v >> 1) as i64) ^ -((v & 1) as i64)
}

/// Packs `mode` and `streams` as `mode u8 | count u8 | len u32 LE × count | bytes…`.
pub(crate) fn pack(mode: u8, streams: &[&Writer]) -> Result<Vec<u8>, CodecError> {
    let total: usize = streams.iter().map(|s| s.bytes.len()).sum::<usize>() + 2 + 4 * streams.len();
    let mut out = Vec::with_capacity(total);
    out.push(mode);
    out.push(u8::try_from(streams.len()).map_err(|_| CodecError::Corrupt("stream table"))?);
    for s in streams {
        let len = u32::try_from(s.bytes.len()).map_err(|_| CodecError::TooLarge {
            what: "payload stream bytes",
            count: s.bytes.len(),
            max: u32::MAX as usize,
        })?;
        out.extend_from_slice(&len.to_le_bytes());
    }
    for s in streams {
        out.extend_from_slice(&s.bytes);
    }
    Ok(out)
}

/// Splits a container made by [`pack`]; the stream count must be `expected` and the lengths must
/// cover the buffer exactly.
pub(crate) fn unpack<'a>(
    raw: &'a [u8],
    expected: usize,
    names: &[&'static str],
) -> Result<(u8, Vec<Reader<'a>>), CodecError> {
    let bad = CodecError::Corrupt("stream table");
    let (&mode, rest) = raw.split_first().ok_or(CodecError::Corrupt("stream table"))?;
    let (&count, mut rest) = rest.split_first().ok_or(CodecError::Corrupt("stream table"))?;
    let count = usize::from(count);
    if count != expected || count > MAX_STREAMS || names.len() != count {
        return Err(bad);
    }
    let mut lens = Vec::with_capacity(count);
    for _ in 0..count {
        let (len, tail) = rest.split_first_chunk::<4>().ok_or(CodecError::Corrupt("stream table"))?;
        lens.push(u32::from_le_bytes(*len) as usize);
        rest = tail;
    }
    let mut readers = Vec::with_capacity(count);
    for (&len, &name) in lens.iter().zip(names) {
        if len > rest.len() {
            return Err(CodecError::Corrupt("stream table"));
        }
        let (head, tail) = rest.split_at(len);
        readers.push(Reader::new(head, name));
        rest = tail;
    }
    if rest.is_empty() { Ok((mode, readers)) } else { Err(bad) }
}

#[cfg(test)]
mod tests {
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
        fn unpack_never_panics(bytes in proptest::collection::vec(any::<u8>(), 0..64)) {
            let _ = unpack(&bytes, 2, &["a", "b"]);
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
        a.varint(300);
        let b = Writer::default();
        let raw = pack(7, &[&a, &b]).unwrap();
        let (mode, rs) = unpack(&raw, 2, &["a", "b"]).unwrap();
        assert_eq!(mode, 7);
        assert_eq!(rs[0].len(), 2);
        assert_eq!(rs[1].len(), 0);
        assert!(unpack(&raw[..raw.len() - 1], 2, &["a", "b"]).is_err());
        assert!(unpack(&raw, 3, &["a", "b", "c"]).is_err());
    }
}
