//! Adaptive binary range coder and the context models built on it: what the points payload's
//! context mode (mode 1) codes with. Integer arithmetic only, so a payload is the same bytes on
//! every platform.
//!
//! The coder is LZMA's: 32-bit range, 12-bit probabilities, carries resolved through a cached
//! byte. The first byte LZMA writes is always zero and is left out. A probability adapts by
//! `1 / 2^shift` of its distance to the bit seen, with `shift` growing from 2 to
//! [`ADAPT_SHIFT`] over a context's first uses (fast learning on small blobs, stable estimates
//! on large ones); probabilities stay in `1..=4095`, so no symbol ever has a zero-width range.
//!
//! Decoding never panics on hostile input: past the end the decoder reads zeros and
//! [`Decoder::finish`] then fails; every loop over bits is bounded by a constant.

use super::CodecError;

/// Bits of a probability.
const PROB_BITS: u32 = 12;
/// Largest adaptation shift (slowest adaptation).
const ADAPT_SHIFT: u32 = 5;
/// The range is renormalized (a byte shifted out) when it falls below this.
const TOP: u32 = 1 << 24;
/// Exp-Golomb classes of a magnitude: up to `2^MAX_CLASS` (far above any lattice delta).
const MAX_CLASS: usize = 40;

/// Adaptation shift after `uses` uses: `min(⌊log2(uses + 1)⌋ + 2, ADAPT_SHIFT)`.
const SHIFTS: [u32; 16] = {
    let mut t = [0; 16];
    let mut i = 0;
    while i < 16 {
        let s = (i as u32 + 1).ilog2() + 2;
        t[i] = if s < ADAPT_SHIFT { s } else { ADAPT_SHIFT };
        i += 1;
    }
    t
};

/// One adaptive binary context: probability of a 0 in the low 12 bits, uses so far (capped at
/// 15) in the top 4.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Bit(u16);

impl Default for Bit {
    fn default() -> Self {
        Self(1 << (PROB_BITS - 1))
    }
}

impl Bit {
    fn p(self) -> u32 {
        u32::from(self.0 & 0x0fff)
    }

    fn update(&mut self, bit: bool) {
        let uses = u32::from(self.0 >> 12);
        let shift = SHIFTS[uses as usize];
        let p = self.p();
        let p = if bit { p - (p >> shift) } else { p + (((1 << PROB_BITS) - p) >> shift) };
        // p stays in 1..=4095: the steps above never reach 0 or 4096.
        self.0 = (p as u16) | (((uses + 1).min(15) as u16) << 12);
    }
}

/// Writes a range-coded stream.
#[derive(Debug)]
pub(crate) struct Encoder {
    low: u64,
    range: u32,
    cache: u8,
    pending: u64,
    /// Whether the always-zero first byte has been dropped.
    started: bool,
    out: Vec<u8>,
}

impl Default for Encoder {
    fn default() -> Self {
        Self { low: 0, range: u32::MAX, cache: 0, pending: 1, started: false, out: Vec::new() }
    }
}

impl Encoder {
    fn shift_low(&mut self) {
        if (self.low as u32) < 0xff00_0000 || (self.low >> 32) != 0 {
            let carry = (self.low >> 32) as u8;
            let mut byte = self.cache;
            while self.pending > 0 {
                if self.started {
                    self.out.push(byte.wrapping_add(carry));
                } else {
                    self.started = true;
                }
                byte = 0xff;
                self.pending -= 1;
            }
            self.cache = ((self.low >> 24) & 0xff) as u8;
        }
        self.pending += 1;
        self.low = (self.low & 0x00ff_ffff) << 8;
    }

    fn normalize(&mut self) {
        while self.range < TOP {
            self.range <<= 8;
            self.shift_low();
        }
    }

    pub(crate) fn bit(&mut self, p: &mut Bit, bit: bool) {
        let bound = (self.range >> PROB_BITS) * p.p();
        if bit {
            self.low += u64::from(bound);
            self.range -= bound;
        } else {
            self.range = bound;
        }
        p.update(bit);
        self.normalize();
    }

    /// `n ≤ 64` low bits of `v`, each with probability ½, most significant first.
    pub(crate) fn direct(&mut self, v: u64, n: u32) {
        for i in (0..n).rev() {
            self.range >>= 1;
            if (v >> i) & 1 == 1 {
                self.low += u64::from(self.range);
            }
            self.normalize();
        }
    }

    /// The coded bytes, at least `min_len` of them (zero-padded).
    pub(crate) fn finish(mut self, min_len: usize) -> Vec<u8> {
        for _ in 0..5 {
            self.shift_low();
        }
        if self.out.len() < min_len {
            self.out.resize(min_len, 0);
        }
        self.out
    }
}

/// Reads what [`Encoder`] wrote.
#[derive(Debug)]
pub(crate) struct Decoder<'a> {
    data: &'a [u8],
    pos: usize,
    range: u32,
    code: u32,
    name: &'static str,
}

impl<'a> Decoder<'a> {
    pub(crate) fn new(data: &'a [u8], name: &'static str) -> Self {
        let mut d = Self { data, pos: 0, range: u32::MAX, code: 0, name };
        for _ in 0..4 {
            d.code = (d.code << 8) | u32::from(d.next_byte());
        }
        d
    }

    fn next_byte(&mut self) -> u8 {
        let b = self.data.get(self.pos).copied().unwrap_or(0);
        self.pos = self.pos.saturating_add(1);
        b
    }

    fn normalize(&mut self) {
        while self.range < TOP {
            self.range <<= 8;
            self.code = (self.code << 8) | u32::from(self.next_byte());
        }
    }

    pub(crate) fn bit(&mut self, p: &mut Bit) -> bool {
        let bound = (self.range >> PROB_BITS) * p.p();
        let bit = self.code >= bound;
        if bit {
            self.code -= bound;
            self.range -= bound;
        } else {
            self.range = bound;
        }
        p.update(bit);
        self.normalize();
        bit
    }

    pub(crate) fn direct(&mut self, n: u32) -> u64 {
        let mut v = 0u64;
        for _ in 0..n {
            self.range >>= 1;
            let bit = self.code >= self.range;
            if bit {
                self.code -= self.range;
            }
            v = (v << 1) | u64::from(bit);
            self.normalize();
        }
        v
    }

    /// Fails unless the decoder read exactly the coded bytes and what follows them is the
    /// encoder's zero padding up to `min_len`.
    pub(crate) fn finish(&self, min_len: usize) -> Result<(), CodecError> {
        let bad = Err(CodecError::Corrupt(self.name));
        if self.pos > self.data.len() {
            return bad;
        }
        let tail = &self.data[self.pos..];
        if tail.is_empty() || (self.data.len() == min_len && tail.iter().all(|&b| b == 0)) {
            Ok(())
        } else {
            bad
        }
    }

    pub(crate) fn corrupt(&self) -> CodecError {
        CodecError::Corrupt(self.name)
    }
}

/// Both sides of the coder behind one interface, so a payload's model is written once and
/// walked by the encoder (which passes the true values and gets them back) and the decoder
/// (which ignores them and returns what it reads).
pub(crate) trait Coder {
    fn bit(&mut self, p: &mut Bit, bit: bool) -> bool;
    fn direct(&mut self, v: u64, n: u32) -> u64;
    /// A corruption error naming the stream (never produced by the encoder).
    fn corrupt(&self) -> CodecError;
}

impl Coder for Encoder {
    fn bit(&mut self, p: &mut Bit, bit: bool) -> bool {
        Encoder::bit(self, p, bit);
        bit
    }

    fn direct(&mut self, v: u64, n: u32) -> u64 {
        Encoder::direct(self, v, n);
        if n >= 64 { v } else { v & ((1u64 << n) - 1) }
    }

    fn corrupt(&self) -> CodecError {
        CodecError::Corrupt("points coded")
    }
}

impl Coder for Decoder<'_> {
    fn bit(&mut self, p: &mut Bit, _: bool) -> bool {
        Decoder::bit(self, p)
    }

    fn direct(&mut self, _: u64, n: u32) -> u64 {
        Decoder::direct(self, n)
    }

    fn corrupt(&self) -> CodecError {
        Decoder::corrupt(self)
    }
}

/// Signed integers in contexts: a zero flag, a sign, the Exp-Golomb class of the magnitude in
/// unary (one adaptive bit per class) and its two leading bits below the top one adaptive, the
/// rest direct. Small residuals cost a few well-predicted bits; large ones stay bounded.
#[derive(Debug, Clone)]
pub(crate) struct IntModel {
    contexts: Vec<IntContext>,
}

/// The adaptive bits of one context of an [`IntModel`], kept together for locality.
#[derive(Debug, Clone, Copy)]
struct IntContext {
    zero: Bit,
    sign: Bit,
    class: [Bit; MAX_CLASS],
    mantissa: [[Bit; 3]; MAX_CLASS],
}

impl Default for IntContext {
    fn default() -> Self {
        let b = Bit::default();
        Self { zero: b, sign: b, class: [b; MAX_CLASS], mantissa: [[b; 3]; MAX_CLASS] }
    }
}

impl IntModel {
    pub(crate) fn new(contexts: usize) -> Self {
        Self { contexts: vec![IntContext::default(); contexts.max(1)] }
    }

    /// Codes `v` in context `ctx` (the last context for any beyond it); returns the value
    /// coded. Errors: a decoded class beyond the largest (corruption).
    pub(crate) fn code<C: Coder>(&mut self, c: &mut C, ctx: usize, v: i64) -> Result<i64, CodecError> {
        let last = self.contexts.len() - 1;
        let m = &mut self.contexts[ctx.min(last)];
        if !c.bit(&mut m.zero, v != 0) {
            return Ok(0);
        }
        let negative = c.bit(&mut m.sign, v < 0);
        // |v| ≥ 1 lies in 2^k..2^(k+1).
        let m1 = v.unsigned_abs();
        let k_true = if m1 == 0 { 0 } else { m1.ilog2() as usize };
        let mut k = 0;
        while c.bit(&mut m.class[k], k < k_true) {
            k += 1;
            if k + 1 >= MAX_CLASS {
                return Err(c.corrupt());
            }
        }
        let mut mag = 1u64;
        if k >= 1 {
            let rest = m1.wrapping_sub(1 << k);
            let b1 = c.bit(&mut m.mantissa[k][0], (rest >> (k - 1)) & 1 == 1);
            mag = (mag << 1) | u64::from(b1);
            if k >= 2 {
                let b2 = c.bit(&mut m.mantissa[k][1 + usize::from(b1)], (rest >> (k - 2)) & 1 == 1);
                mag = (mag << 1) | u64::from(b2);
                let n = (k - 2) as u32;
                mag = (mag << n) | c.direct(rest & ((1u64 << n) - 1), n);
            }
        }
        // k < MAX_CLASS − 1 keeps the magnitude below 2^39: no overflow.
        let mag = mag as i64;
        Ok(if negative { -mag } else { mag })
    }
}

/// Symbols of `bits` bits (≤ 8) as a binary tree of adaptive bits, per context.
#[derive(Debug, Clone)]
pub(crate) struct TreeModel {
    nodes: Vec<Bit>,
    bits: u32,
}

impl TreeModel {
    pub(crate) fn new(contexts: usize, bits: u32) -> Self {
        let bits = bits.min(8);
        Self { nodes: vec![Bit::default(); contexts.max(1) << bits], bits }
    }

    /// Codes the low `bits` bits of `v` in context `ctx` (modulo the context count).
    pub(crate) fn code<C: Coder>(&mut self, c: &mut C, ctx: usize, v: u32) -> u32 {
        let contexts = self.nodes.len() >> self.bits;
        let base = (ctx % contexts) << self.bits;
        let mut node = 1usize;
        for i in (0..self.bits).rev() {
            let b = c.bit(&mut self.nodes[base + node], (v >> i) & 1 == 1);
            node = 2 * node + usize::from(b);
        }
        (node - (1 << self.bits)) as u32
    }
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]

    use super::*;
    use proptest::prelude::*;

    fn round_trip(values: &[i64], bits: &[bool], min_len: usize) {
        let mut e = Encoder::default();
        let mut m = IntModel::new(3);
        let mut b = Bit::default();
        let mut t = TreeModel::new(2, 6);
        for (i, &v) in values.iter().enumerate() {
            m.code(&mut e, i, v).unwrap();
            t.code(&mut e, i, v as u32 & 63);
        }
        for &x in bits {
            Encoder::bit(&mut e, &mut b, x);
        }
        Encoder::direct(&mut e, 0xdead_beef_1234, 48);
        let bytes = e.finish(min_len);
        assert!(bytes.len() >= min_len);
        let mut d = Decoder::new(&bytes, "t");
        let mut m = IntModel::new(3);
        let mut b = Bit::default();
        let mut t = TreeModel::new(2, 6);
        for (i, &v) in values.iter().enumerate() {
            assert_eq!(m.code(&mut d, i, 0).unwrap(), v);
            assert_eq!(t.code(&mut d, i, 0), v as u32 & 63);
        }
        for &x in bits {
            assert_eq!(Decoder::bit(&mut d, &mut b), x);
        }
        assert_eq!(Decoder::direct(&mut d, 48), 0xdead_beef_1234);
        d.finish(min_len).unwrap();
    }

    proptest! {
        #[test]
        fn values_round_trip(
            values in proptest::collection::vec(-(1i64 << 38)..(1i64 << 38), 0..300),
            bits in proptest::collection::vec(any::<bool>(), 0..300),
            min_len in 0usize..50,
        ) {
            round_trip(&values, &bits, min_len);
        }

        #[test]
        fn random_bytes_never_panic(bytes in proptest::collection::vec(any::<u8>(), 0..64)) {
            let mut d = Decoder::new(&bytes, "t");
            let mut m = IntModel::new(2);
            let mut t = TreeModel::new(1, 8);
            for i in 0..200 {
                let _ = m.code(&mut d, i, 0);
                t.code(&mut d, 0, 0);
            }
            let _ = d.finish(0);
        }
    }

    #[test]
    fn skewed_bits_cost_little_and_extremes_round_trip() {
        round_trip(&vec![0; 5000], &vec![false; 5000], 0);
        round_trip(&[i64::from(i32::MAX) * 4, -(1 << 38), 1, -1], &[true; 100], 0);
        let mut e = Encoder::default();
        let mut b = Bit::default();
        for _ in 0..100_000 {
            Encoder::bit(&mut e, &mut b, false);
        }
        // Probabilities cap at 4095/4096: about 0.0004 bit each at best, 0.02 at the slow rate.
        assert!(e.finish(0).len() < 400);
    }

    #[test]
    fn trailing_garbage_and_truncation_are_errors() {
        let mut e = Encoder::default();
        let mut m = IntModel::new(1);
        for v in 0..100 {
            m.code(&mut e, 0, v * 37 - 1000).unwrap();
        }
        let bytes = e.finish(0);
        let decode = |bytes: &[u8]| -> Result<(), CodecError> {
            let mut d = Decoder::new(bytes, "t");
            let mut m = IntModel::new(1);
            for _ in 0..100 {
                m.code(&mut d, 0, 0)?;
            }
            d.finish(0)
        };
        decode(&bytes).unwrap();
        let mut longer = bytes.clone();
        longer.push(0);
        assert!(decode(&longer).is_err());
        assert!(decode(&bytes[..bytes.len() - 1]).is_err());
    }
}
