//! Fragment accumulation: fragments keyed by (cell, view axis) in one buffer, radix-sorted and
//! summed in fixed point per cell (the module doc's *Accumulation*).

use super::rasterize::{centre_ranges, rasterize};
use super::{
    Acc, BakeStats, CellKey, Codec, Frag, Mesh, NORMAL_LIMIT, NORMAL_ONE, POS_HALF, floor_i64,
    triangle_normal,
};

/// Keys of 64 bits: indices relative to the mesh's cell box, packed with just the bits each
/// axis needs. Fits any box whose three extents need at most 62 bits together (e.g. 2^20 cells
/// on each axis), which is every tile; sorted by a radix sort over the used bits.
pub(super) struct PackedCodec {
    min: [i64; 3],
    /// Bits for i, j, k.
    bits: [u32; 3],
}

impl PackedCodec {
    pub(super) fn new(lo: [i64; 3], hi: [i64; 3]) -> Option<Self> {
        let bits = [0, 1, 2].map(|d| u64::BITS - ((hi[d] - lo[d]) as u64).leading_zeros());
        (bits.iter().sum::<u32>() <= 62).then_some(Self { min: lo, bits })
    }
}

impl Codec for PackedCodec {
    type Key = u64;

    #[inline]
    fn encode(&self, idx: [i32; 3], axis: usize) -> u64 {
        let rel = |d: usize| (i64::from(idx[d]) - self.min[d]) as u64;
        let rel = [rel(0), rel(1), rel(2)];
        let cell = (((rel[2] << self.bits[1]) | rel[1]) << self.bits[0]) | rel[0];
        (cell << 2) | axis as u64
    }

    #[inline]
    fn decode(&self, key: u64) -> [i32; 3] {
        let cell = key >> 2;
        let mask = |b: u32| (1u64 << b) - 1;
        let i = cell & mask(self.bits[0]);
        let j = (cell >> self.bits[0]) & mask(self.bits[1]);
        let k = cell >> (self.bits[0] + self.bits[1]);
        [(i as i64 + self.min[0]) as i32, (j as i64 + self.min[1]) as i32, (k as i64 + self.min[2]) as i32]
    }

    #[inline]
    fn axis(key: u64) -> usize {
        (key & 3) as usize
    }

    #[inline]
    fn same_cell(a: u64, b: u64) -> bool {
        a >> 2 == b >> 2
    }

    fn sort(&self, frags: &mut Vec<Frag<u64>>) {
        // The axis bits need no sorting: sums within a cell do not depend on order.
        radix_sort(frags, 2, self.bits.iter().sum());
    }
}

/// Keys of 128 bits for boxes too large to pack: each index with its sign bit flipped (so
/// unsigned order is signed order), sorted by comparison.
pub(super) struct WideCodec;

impl Codec for WideCodec {
    type Key = u128;

    #[inline]
    fn encode(&self, idx: [i32; 3], axis: usize) -> u128 {
        let u = idx.map(|v| u128::from(v as u32 ^ 0x8000_0000));
        (u[2] << 66) | (u[1] << 34) | (u[0] << 2) | axis as u128
    }

    #[inline]
    fn decode(&self, key: u128) -> [i32; 3] {
        let field = |shift: u32| ((key >> shift) as u32 ^ 0x8000_0000) as i32;
        [field(2), field(34), field(66)]
    }

    #[inline]
    fn axis(key: u128) -> usize {
        (key & 3) as usize
    }

    #[inline]
    fn same_cell(a: u128, b: u128) -> bool {
        a >> 2 == b >> 2
    }

    fn sort(&self, frags: &mut Vec<Frag<u128>>) {
        frags.sort_unstable_by_key(|f| f.key);
    }
}

/// LSD radix sort of `frags` by key bits `[lo_bit, lo_bit + bits)`, 11 bits per pass.
pub(super) fn radix_sort(frags: &mut Vec<Frag<u64>>, lo_bit: u32, bits: u32) {
    const DIGIT: u32 = 11;
    if frags.len() < 2 || bits == 0 {
        return;
    }
    let mut buf = vec![Frag::default(); frags.len()];
    let mut counts = vec![0usize; 1 << DIGIT];
    let end = lo_bit + bits;
    let mut shift = lo_bit;
    while shift < end {
        let width = DIGIT.min(end - shift);
        let mask = (1u64 << width) - 1;
        let counts = &mut counts[..1 << width];
        counts.fill(0);
        for f in frags.iter() {
            counts[((f.key >> shift) & mask) as usize] += 1;
        }
        let mut total = 0;
        for c in counts.iter_mut() {
            let n = *c;
            *c = total;
            total += n;
        }
        for f in frags.iter() {
            let digit = ((f.key >> shift) & mask) as usize;
            buf[counts[digit]] = *f;
            counts[digit] += 1;
        }
        std::mem::swap(frags, &mut buf);
        shift += width;
    }
}

/// The bakeable triangles of `mesh`, each rotated so its smallest vertex index leads
/// (orientation, and so the normal, kept), with its vertices in grid units.
pub(super) fn valid_triangles<'a>(
    mesh: &'a Mesh,
    grid: &'a [Option<[f64; 3]>],
) -> impl Iterator<Item = ([u32; 3], [[f64; 3]; 3])> + 'a {
    mesh.triangles.iter().filter_map(move |tri| {
        let lead = if tri[0] <= tri[1] && tri[0] <= tri[2] {
            0
        } else if tri[1] <= tri[2] {
            1
        } else {
            2
        };
        let ids = [tri[lead], tri[(lead + 1) % 3], tri[(lead + 2) % 3]];
        let g = |id: u32| grid.get(id as usize).copied().flatten();
        Some((ids, [g(ids[0])?, g(ids[1])?, g(ids[2])?]))
    })
}

/// Rasterizes every triangle in the three views and sums the fragments per cell; returns the
/// occupied cells sorted by `(k, j, i)`.
pub(super) fn accumulate<C: Codec>(
    codec: &C,
    mesh: &Mesh,
    grid: &[Option<[f64; 3]>],
    estimate: usize,
    stats: &mut BakeStats,
) -> Vec<(CellKey, Acc)> {
    let mut frags: Vec<Frag<C::Key>> = Vec::with_capacity(estimate);
    for (ids, g) in valid_triangles(mesh, grid) {
        let world = [
            mesh.positions[ids[0] as usize],
            mesh.positions[ids[1] as usize],
            mesh.positions[ids[2] as usize],
        ];
        let n = triangle_normal(world[0], world[1], world[2]);
        let quantize = |c: f64| floor_i64(c * NORMAL_ONE + 0.5).clamp(-NORMAL_LIMIT, NORMAL_LIMIT) as i16;
        let n = [quantize(n[0]), quantize(n[1]), quantize(n[2])];
        let ranges = centre_ranges(&g);
        for axis in 0..3 {
            stats.fragments[axis] += rasterize(&g, &ranges, axis, |idx, q| {
                frags.push(Frag { key: codec.encode(idx, axis), q, n });
            });
        }
    }
    codec.sort(&mut frags);

    let mut cells = Vec::new();
    let mut start = 0;
    while start < frags.len() {
        let key = frags[start].key;
        let mut acc = Acc::default();
        let mut end = start;
        while end < frags.len() && C::same_cell(frags[end].key, key) {
            let f = &frags[end];
            let axis = C::axis(f.key);
            for d in 0..3 {
                acc.pos[d] += if d == axis { u64::from(f.q) } else { POS_HALF };
                acc.normal[d] += i64::from(f.n[d]);
            }
            acc.count += 1;
            end += 1;
        }
        cells.push((CellKey::from_index(codec.decode(key)), acc));
        start = end;
    }
    cells
}
