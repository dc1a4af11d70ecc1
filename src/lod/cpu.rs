//! CPU reference of the first paper's 6-direction orthographic slicing: bakes one point level of
//! a tile's TIN, and measures a point level against its mesh.
//!
//! The GPU bake (`lod::gpu`) must reproduce this module cell by cell (≥ 99.5 % of occupied
//! cells agree, agreeing cells' points within 1/1000 of a cell), so what follows is the
//! specification, stated to the operation.
//!
//! # Grid
//!
//! A cubic grid of edge `cell` anchored at `grid_origin`: cell `(i, j, k)` spans
//! `origin + [i, i+1)·cell × [j, j+1)·cell × [k, k+1)·cell`. All sampling works in grid units,
//! `g = (p − origin) / cell`, computed once per vertex in f64 (the GPU should do this on the
//! host in f64 and upload f32 grid coordinates, so large world coordinates cost no precision).
//! Triangles with a non-finite grid coordinate, one beyond ±2^30 ([`MAX_GRID_COORD`]), or a
//! vertex index out of range are skipped and counted in [`BakeStats::skipped_triangles`].
//!
//! A level's resolution is this one `cell`: the paper's framebuffer size T3 is the tile's
//! extent / `cell` and its slice count T1 the height range / `cell` (cubic cells keep the three
//! views alike). The paper's point size T2 is for the renderer, not the bake.
//!
//! # Views
//!
//! The view along axis `a` (0 = X, 1 = Y, 2 = Z) projects onto the plane of the axes
//! `(u, v) = ((a+1) mod 3, (a+2) mod 3)`: X → (Y, Z), Y → (Z, X), Z → (X, Y). Its framebuffer
//! pixel `(pu, pv)` has its centre at `(pu + ½, pv + ½)` in grid units, so pixel centres are
//! cell centres, and a fragment's slice is its cell index along `a`. The paper renders six
//! directions, ±X, ±Y, ±Z; rendering here has no depth test and no back-face culling, so the
//! views along `+a` and `−a` produce exactly the same fragments, and one rasterization per
//! axis stands for both. Merging the six views "without duplicates" is the per-cell
//! accumulation below: a cell yields one point however many views hit it.
//!
//! # Rasterization (per triangle, per axis)
//!
//! 1. The triangle's vertices are rotated (orientation kept) so its smallest vertex index comes
//!    first: the result then does not depend on how a mesh writer rotated them.
//! 2. Its unit normal `n` is [`triangle_normal`] of the world positions in that order (the
//!    right-hand normal, used as is: no flipping toward a view).
//! 3. Edge function of the directed edge `a → b` at `p`, evaluated *canonically*: order the
//!    endpoints lexicographically by `(u, v)` as `P ≤ Q`, let
//!    `f = (Q_u − P_u)·(p_v − P_v) − (Q_v − P_v)·(p_u − P_u)` and `E = f` if `a = P`, else
//!    `E = −f`. Two triangles sharing an edge thus compute bit-identical magnitudes, and the
//!    coverage decisions on the shared edge are exactly complementary.
//! 4. Oriented area `A = E_{v0→v1}(v2)`. `A = 0` (a projection of zero area) produces no
//!    fragments for this axis; `A < 0` swaps `v1` and `v2` so the vertices run
//!    counter-clockwise in `(u, v)`.
//! 5. Pixel centre `p` is covered when, for each of the three counter-clockwise edges `a → b`,
//!    `E(p) > 0`, or `E(p) = 0` and the edge is a *tie edge*: `d = b − a` has `d_v < 0`, or
//!    `d_v = 0` and `d_u > 0`. It equals nudging `p` by `(+ε, +ε²)`, so a pixel centre on an
//!    edge or vertex shared by triangles that tile the projection is produced exactly once. In a
//!    framebuffer with `x = u` and `y = v`, `y` pointing down as in Vulkan and Direct3D, this is
//!    their top-left rule, so a hardware rasterizer breaks the ties the same way.
//! 6. Depth: with `E_i` the edge function of the edge opposite vertex `i`,
//!    `t = (E_0·d_0 + E_1·d_1 + E_2·d_2) / (E_0 + E_1 + E_2)`, clamped to `[min d, max d]`
//!    (linear interpolation of the triangle's plane at the pixel centre; a fragment whose
//!    `E_0 + E_1 + E_2` is not positive, possible only by underflow, is dropped). Slice
//!    `s = ⌊t⌋`; offset in the slice `q = min(⌊(t − s)·2^16 + ½⌋, 2^16 − 1)`.
//!
//! # Accumulation (fixed point, independent of order)
//!
//! A fragment of the view along `a` at pixel `(pu, pv)`, slice `s`, adds to the cell whose index
//! is `s` on `a`, `pu` on `u` and `pv` on `v`:
//! - position offsets from the cell's min corner in units of `cell / 2^16`: `q` on `a`, `2^15`
//!   (the pixel centre) on `u` and `v`;
//! - normal `⌊n·2^15 + ½⌋` per component, clamped to ±(2^15 − 1);
//! - a count of one.
//!
//! Integer sums make the result independent of summation order, as with GPU atomics. The CPU
//! sums in u64/i64; u32/i32 atomics have headroom for 2^16 fragments per cell, and a cell gets
//! a handful (one per view and surface sheet crossing it).
//!
//! # Hole filling (the paper's median filter)
//!
//! One pass per axis `a`, every pass reading only the merged occupancy before filling, so the
//! result does not depend on scan order. A *column* is the set of cells with one `(u, v)`
//! index; it is occupied when any of its cells is. An empty column is a hole when the 3×3
//! median of the column occupancy is 1 — at least [`FILL_MIN_NEIGHBOURS`] (5) of its 8
//! neighbour columns are occupied — *and* its 4 edge neighbours (±u, ±v) are all occupied.
//! The median alone also rounds concave corners of silhouettes (the top of a terrain's side
//! view dips between two ridges) and puts points there that the surface never reaches: on a
//! synthetic terrain tile that raised the measured `max` from 0.06 to 1.1 cells. Requiring the
//! edge neighbours keeps fills to holes enclosed by surface; the price is that one-pixel
//! cracks longer than one pixel, which the plain median closes, stay open. A hole gets up to
//! two points, one for the view along `+a` (front) and one along `−a` (back):
//! - each occupied neighbour offers its front cell (lowest index along `a`) or back cell
//!   (highest), and that cell's key `K = s·2^16 + ⌊(Σq_a + c/2) / c⌋` (its slice and rounded
//!   mean offset along `a`; `c` its count);
//! - the keys are sorted ascending (ties by the cells' output order) and the front fill takes
//!   the lower median, index `(n−1)/2`, the back fill the upper median, index `n/2` (the
//!   lower median seen from `−a`);
//! - the fill goes to the cell with slice `⌊K / 2^16⌋` in the empty column, position offset
//!   `K mod 2^16` on `a` and `2^15` (the pixel centre) on `u` and `v`, and normal
//!   `⌊m·2^15 + ½⌋` where `m` is the normalized sum of the normal sums of the `n` offered
//!   cells (zero if that sum is zero), with a count of one.
//!
//! Fills that land in the same cell (front and back of a single sheet, or two axes) accumulate
//! like fragments. A fill never lands in an occupied cell: its column is empty along `a`.
//!
//! # Output
//!
//! One point per occupied or filled cell, sorted by cell index `(k, j, i)`:
//! `position = origin + (index + Σoffset / (count·2^16))·cell` per component, which always lies
//! inside the cell; `normal = Σnormal / |Σnormal|` as f32, or `+Z` when the sum is zero
//! (opposite sheets cancelling in one cell).
//!
//! # Cost
//!
//! Time grows with the triangle count (a setup per triangle and view) and the fragment count,
//! about the mesh's surface area / cell² times the sum of its absolute normal components.
//! Fragments go to one flat buffer (16 bytes each, twice during the radix sort that groups
//! them by cell), so memory follows the fragments and occupied cells, never the bounding
//! volume. Nothing allocates per fragment or runs in parallel: callers parallelise over tiles.

use std::hash::{Hash, Hasher};

use super::fasthash::FastMap;
use crate::geom::{Errors, Mesh, PointCloud, triangle_normal};

/// Fractional bits of the fixed-point position offsets: units of `cell / 2^16`.
pub const POSITION_FRACTION_BITS: u32 = 16;
/// Fractional bits of the fixed-point normal components: units of `1 / 2^15`.
pub const NORMAL_FRACTION_BITS: u32 = 15;
/// Occupied neighbour columns (of 8) that make an empty column a hole to fill (the 3×3 median);
/// the 4 edge neighbours must be among them.
pub const FILL_MIN_NEIGHBOURS: usize = 5;
/// Largest magnitude of a vertex grid coordinate `(p − origin) / cell` that is baked; beyond,
/// the triangle is skipped (cell indices must stay far inside `i32`).
pub const MAX_GRID_COORD: f64 = (1u64 << 30) as f64;

const POS_ONE: f64 = (1u64 << POSITION_FRACTION_BITS) as f64;
const POS_MASK: i64 = (1i64 << POSITION_FRACTION_BITS) - 1;
const POS_HALF: u64 = 1u64 << (POSITION_FRACTION_BITS - 1);
const NORMAL_ONE: f64 = (1u64 << NORMAL_FRACTION_BITS) as f64;
/// Quantized normal components are clamped to ±(2^15 − 1) so they fit an `i16`.
const NORMAL_LIMIT: i64 = (1 << NORMAL_FRACTION_BITS) - 1;

/// Options of one bake.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct SliceOptions {
    /// Run the hole-filling median filter (on by default; off shows the raw slicing).
    pub fill_holes: bool,
}

impl Default for SliceOptions {
    fn default() -> Self {
        Self { fill_holes: true }
    }
}

/// What one bake did.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct BakeStats {
    /// Fragments rasterized per view axis (X, Y, Z); each stands for both directions.
    pub fragments: [u64; 3],
    /// Cells hit by at least one fragment.
    pub occupied: usize,
    /// Cells added by hole filling.
    pub filled: usize,
    /// Triangles skipped: vertex index out of range, non-finite coordinate, or beyond
    /// [`MAX_GRID_COORD`]. All of them when `cell` or `grid_origin` is invalid.
    pub skipped_triangles: usize,
}

/// One output point with the cell it belongs to: what a GPU bake is compared against.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct BakedCell {
    /// Cell index `(i, j, k)` along X, Y, Z.
    pub index: [i32; 3],
    /// The point, inside the cell.
    pub position: [f64; 3],
    /// Unit normal.
    pub normal: [f32; 3],
    /// Fragments (or fill contributions) averaged into the point.
    pub samples: u64,
    /// Whether the point came from hole filling.
    pub filled: bool,
}

/// Bakes one point level of `mesh` on a cubic cell grid of edge `cell` anchored at
/// `grid_origin` (see the module doc for the exact sampling). An invalid `cell` (not finite and
/// positive) or `grid_origin` (not finite) gives an empty cloud.
#[must_use]
pub fn bake_points(mesh: &Mesh, grid_origin: [f64; 3], cell: f64) -> PointCloud {
    bake_points_with_stats(mesh, grid_origin, cell).0
}

/// [`bake_points`] with default options, also returning what the bake did.
#[must_use]
pub fn bake_points_with_stats(mesh: &Mesh, grid_origin: [f64; 3], cell: f64) -> (PointCloud, BakeStats) {
    let (cells, stats) = bake_cells(mesh, grid_origin, cell, &SliceOptions::default());
    let cloud = PointCloud {
        positions: cells.iter().map(|c| c.position).collect(),
        normals: cells.iter().map(|c| c.normal).collect(),
    };
    (cloud, stats)
}

/// The bake with its cell indices, sorted by `(k, j, i)`: the form a GPU bake is compared
/// against cell by cell.
#[must_use]
pub fn bake_cells(
    mesh: &Mesh,
    grid_origin: [f64; 3],
    cell: f64,
    options: &SliceOptions,
) -> (Vec<BakedCell>, BakeStats) {
    let mut stats = BakeStats::default();
    if !(cell.is_finite() && cell > 0.0) || grid_origin.iter().any(|c| !c.is_finite()) {
        stats.skipped_triangles = mesh.triangles.len();
        return (Vec::new(), stats);
    }
    let grid: Vec<Option<[f64; 3]>> = mesh
        .positions
        .iter()
        .map(|p| {
            let g = [
                (p[0] - grid_origin[0]) / cell,
                (p[1] - grid_origin[1]) / cell,
                (p[2] - grid_origin[2]) / cell,
            ];
            g.iter().all(|c| c.is_finite() && c.abs() <= MAX_GRID_COORD).then_some(g)
        })
        .collect();

    // First pass: the cell box (for the key codec) and the fragment estimate (the three
    // projected areas, in pixels), so the second pass rasterizes into one right-sized buffer
    // without keeping per-triangle data around.
    let mut lo = [f64::INFINITY; 3];
    let mut hi = [f64::NEG_INFINITY; 3];
    let mut area = 0.0;
    let mut valid = 0usize;
    for (_, g) in valid_triangles(mesh, &grid) {
        for v in g {
            for d in 0..3 {
                lo[d] = lo[d].min(v[d]);
                hi[d] = hi[d].max(v[d]);
            }
        }
        let u = [g[1][0] - g[0][0], g[1][1] - g[0][1], g[1][2] - g[0][2]];
        let v = [g[2][0] - g[0][0], g[2][1] - g[0][1], g[2][2] - g[0][2]];
        area += 0.5
            * ((u[1] * v[2] - u[2] * v[1]).abs()
                + (u[2] * v[0] - u[0] * v[2]).abs()
                + (u[0] * v[1] - u[1] * v[0]).abs());
        valid += 1;
    }
    stats.skipped_triangles = mesh.triangles.len() - valid;
    // Capped so absurd inputs do not reserve absurd memory up front.
    let estimate = ((area * 1.1) as usize + 64).min(1 << 24);

    let cells = if valid == 0 {
        Vec::new()
    } else {
        // Every cell index lies within the vertices' floor box; one cell of margin besides.
        let lo = [floor_i64(lo[0]) - 1, floor_i64(lo[1]) - 1, floor_i64(lo[2]) - 1];
        let hi = [floor_i64(hi[0]) + 1, floor_i64(hi[1]) + 1, floor_i64(hi[2]) + 1];
        match PackedCodec::new(lo, hi) {
            Some(codec) => accumulate(&codec, mesh, &grid, estimate, &mut stats),
            None => accumulate(&WideCodec, mesh, &grid, estimate, &mut stats),
        }
    };
    stats.occupied = cells.len();

    let mut out: Vec<BakedCell> =
        cells.iter().map(|(k, a)| finish(*k, a, grid_origin, cell, false)).collect();
    if options.fill_holes {
        let fills = fill_holes(&cells);
        stats.filled = fills.len();
        if !fills.is_empty() {
            // Both lists are sorted and disjoint (fills only land in empty cells): merge them.
            let cells_out = std::mem::take(&mut out);
            out.reserve(cells_out.len() + fills.len());
            let mut fills = fills.iter().map(|(k, a)| finish(*k, a, grid_origin, cell, true)).peekable();
            let order = |c: &BakedCell| (c.index[2], c.index[1], c.index[0]);
            for c in cells_out {
                while let Some(f) = fills.next_if(|f| order(f) < order(&c)) {
                    out.push(f);
                }
                out.push(c);
            }
            out.extend(fills);
        }
    }
    (out, stats)
}

/// Measures a point level against the mesh it was baked from, in world units:
/// - `max` / `rms`: the distance from each point to its nearest triangle (exact point–triangle
///   distance);
/// - `gap`: the largest distance from a surface sample to its nearest point, samples taken on
///   every triangle along its edges (vertices included) and in rows across it at a spacing of
///   at most `cell / 4` — so `gap` is the true value within `cell / 8`.
///
/// Invalid triangles (index out of range, non-finite vertex) and non-finite points are left
/// out. An empty mesh gives zeros; no points give `gap` = the mesh's bounding-box diagonal (the
/// whole surface is a hole). An invalid `cell` (not finite and positive) falls back to
/// 1/256 of that diagonal. Cost grows with the surface area / cell² (the gap samples).
#[must_use]
pub fn measure_points(mesh: &Mesh, points: &PointCloud, cell: f64) -> Errors {
    super::measure::measure(mesh, points, cell)
}

/// Cell key, ordered as the output: by `k`, then `j`, then `i`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord)]
struct CellKey {
    k: i32,
    j: i32,
    i: i32,
}

impl CellKey {
    #[inline]
    fn from_index(idx: [i32; 3]) -> Self {
        Self { k: idx[2], j: idx[1], i: idx[0] }
    }

    #[inline]
    fn index(self) -> [i32; 3] {
        [self.i, self.j, self.k]
    }
}

impl Hash for CellKey {
    #[inline]
    fn hash<H: Hasher>(&self, state: &mut H) {
        // Two words instead of three field writes.
        state.write_u64((u64::from(self.k as u32) << 32) | u64::from(self.j as u32));
        state.write_u32(self.i as u32);
    }
}

/// Fixed-point sums of one cell.
#[derive(Debug, Clone, Copy, Default)]
struct Acc {
    /// Position offsets from the cell's min corner, units of cell / 2^16.
    pos: [u64; 3],
    /// Normals, units of 1 / 2^15.
    normal: [i64; 3],
    count: u64,
}

impl Acc {
    /// Rounded mean offset along `axis`, in units of cell / 2^16.
    #[inline]
    fn mean_offset(&self, axis: usize) -> u64 {
        (self.pos[axis] + self.count / 2) / self.count.max(1)
    }
}

/// One fragment waiting to be summed into its cell. Fragments are appended in triangle order
/// and then sorted by `key` (cell, then view axis): sequential writes and a radix sort cost far
/// less than a hash-map update per fragment, whose random accesses miss the cache.
#[derive(Debug, Clone, Copy, Default)]
struct Frag<K> {
    key: K,
    /// Offset along the view axis, units of cell / 2^16.
    q: u16,
    /// The triangle's quantized normal.
    n: [i16; 3],
}

/// Encodes (cell index, view axis) into an integer key whose order is the output order
/// `(k, j, i)`, with the axis in the two lowest bits.
trait Codec {
    type Key: Copy + Ord + Default;
    fn encode(&self, idx: [i32; 3], axis: usize) -> Self::Key;
    fn decode(&self, key: Self::Key) -> [i32; 3];
    fn axis(key: Self::Key) -> usize;
    fn same_cell(a: Self::Key, b: Self::Key) -> bool;
    fn sort(&self, frags: &mut Vec<Frag<Self::Key>>);
}

/// Keys of 64 bits: indices relative to the mesh's cell box, packed with just the bits each
/// axis needs. Fits any box whose three extents need at most 62 bits together (e.g. 2^20 cells
/// on each axis), which is every tile; sorted by a radix sort over the used bits.
struct PackedCodec {
    min: [i64; 3],
    /// Bits for i, j, k.
    bits: [u32; 3],
}

impl PackedCodec {
    fn new(lo: [i64; 3], hi: [i64; 3]) -> Option<Self> {
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
struct WideCodec;

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
fn radix_sort(frags: &mut Vec<Frag<u64>>, lo_bit: u32, bits: u32) {
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
fn valid_triangles<'a>(
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
fn accumulate<C: Codec>(
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

/// One edge of a counter-clockwise triangle, prepared for the canonical edge function.
#[derive(Clone, Copy)]
struct Edge {
    /// Lexicographically smaller endpoint.
    p: [f64; 2],
    /// `Q − P`.
    d: [f64; 2],
    /// +1 when the edge runs P → Q, −1 when Q → P.
    sign: f64,
    /// Whether a pixel centre exactly on the edge is covered (top-left rule).
    tie: bool,
}

impl Edge {
    #[inline]
    fn new(a: [f64; 2], b: [f64; 2]) -> Self {
        let du = b[0] - a[0];
        let dv = b[1] - a[1];
        let tie = dv < 0.0 || (dv == 0.0 && du > 0.0);
        let forward = (a[0], a[1]) <= (b[0], b[1]);
        let (p, q) = if forward { (a, b) } else { (b, a) };
        let sign = if forward { 1.0 } else { -1.0 };
        Self { p, d: [q[0] - p[0], q[1] - p[1]], sign, tie }
    }

    /// The same edge run the other way: bit-identical to `Edge::new(b, a)`. (`d = 0` never
    /// gets here: it makes the area zero.)
    #[inline]
    fn reversed(self) -> Self {
        Self { sign: -self.sign, tie: !self.tie, ..self }
    }

    #[inline]
    fn eval(&self, x: f64, y: f64) -> f64 {
        self.sign * (self.d[0] * (y - self.p[1]) - self.d[1] * (x - self.p[0]))
    }

    #[inline]
    fn covers(&self, e: f64) -> bool {
        e > 0.0 || (e == 0.0 && self.tie)
    }
}

/// `⌊x⌋` for finite `x` well inside the `i64` range, by a truncating cast: `f64::floor` is a
/// libm call on baseline x86-64, and this runs per fragment and per triangle.
#[inline]
fn floor_i64(x: f64) -> i64 {
    let t = x as i64;
    if t as f64 > x { t - 1 } else { t }
}

/// `⌈x⌉`, as [`floor_i64`].
#[inline]
fn ceil_i64(x: f64) -> i64 {
    let t = x as i64;
    if (t as f64) < x { t + 1 } else { t }
}

/// The pixel columns of row centre `y` that can be inside triangle `p`, within `[i0, i1]`: the
/// row's crossing of the triangle widened by a pixel. Only a speed-up (slivers would otherwise
/// walk their whole bounding box); the edge tests decide coverage.
fn row_span(p: &[[f64; 2]; 3], y: f64, i0: i64, i1: i64) -> (i64, i64) {
    let mut lo = f64::INFINITY;
    let mut hi = f64::NEG_INFINITY;
    for (a, b) in [(p[0], p[1]), (p[1], p[2]), (p[2], p[0])] {
        if (a[1] <= y && y <= b[1]) || (b[1] <= y && y <= a[1]) {
            let dv = b[1] - a[1];
            if dv == 0.0 {
                lo = lo.min(a[0]).min(b[0]);
                hi = hi.max(a[0]).max(b[0]);
            } else {
                let x = a[0] + (y - a[1]) * (b[0] - a[0]) / dv;
                lo = lo.min(x);
                hi = hi.max(x);
            }
        }
    }
    if lo > hi {
        return (1, 0);
    }
    ((ceil_i64(lo - 0.5) - 1).max(i0), (floor_i64(hi - 0.5) + 1).min(i1))
}

/// The pixel-centre index ranges of triangle `g` (grid units) along each axis: centres
/// `c + ½` inside `[min, max]`, so `c` from `⌈min − ½⌉` to `⌊max − ½⌋`. Each view uses two of
/// the three, so they are computed once per triangle.
fn centre_ranges(g: &[[f64; 3]; 3]) -> [(i64, i64); 3] {
    let range = |c: usize| {
        let lo = g[0][c].min(g[1][c]).min(g[2][c]);
        let hi = g[0][c].max(g[1][c]).max(g[2][c]);
        (ceil_i64(lo - 0.5), floor_i64(hi - 0.5))
    };
    [range(0), range(1), range(2)]
}

/// Rasterizes triangle `g` (grid units) in the view along `axis`, passing each fragment's cell
/// index and offset along `axis` to `emit`; returns the fragment count. `ranges` is
/// [`centre_ranges`] of `g`.
fn rasterize(
    g: &[[f64; 3]; 3],
    ranges: &[(i64, i64); 3],
    axis: usize,
    mut emit: impl FnMut([i32; 3], u16),
) -> u64 {
    let (ua, va) = ((axis + 1) % 3, (axis + 2) % 3);
    let ((i0, i1), (j0, j1)) = (ranges[ua], ranges[va]);
    // Most triangles of a level are a pixel or two across, and many cover no pixel centre in
    // some view: leave before any edge setup.
    if i0 > i1 || j0 > j1 {
        return 0;
    }
    // Explicit arrays rather than `array::map`, which does not always inline in this loop.
    let p = [[g[0][ua], g[0][va]], [g[1][ua], g[1][va]], [g[2][ua], g[2][va]]];
    let mut d = [g[0][axis], g[1][axis], g[2][axis]];
    // Edge i is opposite vertex i, so its edge function is vertex i's barycentric weight.
    let mut edges = [Edge::new(p[1], p[2]), Edge::new(p[2], p[0]), Edge::new(p[0], p[1])];
    let area = edges[2].eval(p[2][0], p[2][1]);
    if area == 0.0 {
        return 0;
    }
    if area < 0.0 {
        // Counter-clockwise order (v0, v2, v1): its edges are the reversed ones, each opposite
        // the same vertex as before.
        edges = [edges[0].reversed(), edges[2].reversed(), edges[1].reversed()];
        d.swap(1, 2);
    }
    let dmin = d[0].min(d[1]).min(d[2]);
    let dmax = d[0].max(d[1]).max(d[2]);
    // Narrow rows only when the box is wide enough for it to pay.
    let narrow = i1 - i0 > 2;

    let mut count = 0;
    let mut idx = [0i32; 3];
    for pj in j0..=j1 {
        let y = pj as f64 + 0.5;
        let (ia, ib) = if narrow { row_span(&p, y, i0, i1) } else { (i0, i1) };
        // The y half of each edge function, once per row (the same operations as `eval`).
        let ay = [
            edges[0].d[0] * (y - edges[0].p[1]),
            edges[1].d[0] * (y - edges[1].p[1]),
            edges[2].d[0] * (y - edges[2].p[1]),
        ];
        for pi in ia..=ib {
            let x = pi as f64 + 0.5;
            let e = [
                edges[0].sign * (ay[0] - edges[0].d[1] * (x - edges[0].p[0])),
                edges[1].sign * (ay[1] - edges[1].d[1] * (x - edges[1].p[0])),
                edges[2].sign * (ay[2] - edges[2].d[1] * (x - edges[2].p[0])),
            ];
            if !(edges[0].covers(e[0]) && edges[1].covers(e[1]) && edges[2].covers(e[2])) {
                continue;
            }
            let sum = e[0] + e[1] + e[2];
            if sum <= 0.0 {
                // Only reachable through underflow on a near-degenerate projection.
                continue;
            }
            let t = ((e[0] * d[0] + e[1] * d[1] + e[2] * d[2]) / sum).clamp(dmin, dmax);
            // ⌊x + ½⌋ for x ≥ 0 by a truncating cast (see `floor_i64`).
            let s = floor_i64(t);
            let q = (((t - s as f64) * POS_ONE + 0.5) as u32).min(u32::from(u16::MAX));
            idx[axis] = s as i32;
            idx[ua] = pi as i32;
            idx[va] = pj as i32;
            emit(idx, q as u16);
            count += 1;
        }
    }
    count
}

/// Turns a cell's sums into its output point.
fn finish(key: CellKey, a: &Acc, origin: [f64; 3], cell: f64, filled: bool) -> BakedCell {
    let index = key.index();
    let denom = a.count.max(1) as f64 * POS_ONE;
    let coord = |d: usize| origin[d] + (f64::from(index[d]) + a.pos[d] as f64 / denom) * cell;
    let position = [coord(0), coord(1), coord(2)];
    let n = [a.normal[0] as f64, a.normal[1] as f64, a.normal[2] as f64];
    let len = (n[0] * n[0] + n[1] * n[1] + n[2] * n[2]).sqrt();
    let normal = if len > 0.0 {
        [(n[0] / len) as f32, (n[1] / len) as f32, (n[2] / len) as f32]
    } else {
        [0.0, 0.0, 1.0]
    };
    BakedCell { index, position, normal, samples: a.count, filled }
}

/// Per-column summary of the occupancy along one axis.
#[derive(Clone, Copy)]
struct Column {
    /// Column index on (u, v).
    uv: [i32; 2],
    /// Positions in the sorted cell list of the lowest and highest occupied cell along the axis.
    front: usize,
    back: usize,
    /// Their slices.
    front_s: i32,
    back_s: i32,
}

/// Finds a column by its (u, v) index: a dense table over the columns' bounding rectangle when
/// that is not much larger than the column count (the usual case: a tile's projections are
/// compact), a hash map otherwise (sparse models in large empty volumes).
enum ColumnLookup {
    Dense { min: [i64; 2], width: i64, height: i64, slots: Vec<u32> },
    Sparse(FastMap<[i32; 2], u32>),
}

impl ColumnLookup {
    fn new(min: [i64; 2], max: [i64; 2], cells: usize) -> Self {
        // One ring of margin so neighbour lookups of edge columns stay in the table.
        let width = max[0] - min[0] + 3;
        let height = max[1] - min[1] + 3;
        let area = width as f64 * height as f64;
        if area <= (8.0 * cells as f64).max(65_536.0) {
            Self::Dense {
                min: [min[0] - 1, min[1] - 1],
                width,
                height,
                slots: vec![u32::MAX; (width * height) as usize],
            }
        } else {
            Self::Sparse(FastMap::default())
        }
    }

    #[inline]
    fn get(&self, uv: [i32; 2]) -> Option<u32> {
        match self {
            Self::Dense { min, width, height, slots } => {
                let x = i64::from(uv[0]) - min[0];
                let y = i64::from(uv[1]) - min[1];
                if x < 0 || y < 0 || x >= *width || y >= *height {
                    return None;
                }
                let s = slots[(y * width + x) as usize];
                (s != u32::MAX).then_some(s)
            }
            Self::Sparse(map) => map.get(&uv).copied(),
        }
    }

    #[inline]
    fn insert(&mut self, uv: [i32; 2], id: u32) {
        match self {
            Self::Dense { min, width, slots, .. } => {
                let x = i64::from(uv[0]) - min[0];
                let y = i64::from(uv[1]) - min[1];
                slots[(y * *width + x) as usize] = id;
            }
            Self::Sparse(map) => {
                map.insert(uv, id);
            }
        }
    }
}

/// The median filter over the pre-filter occupancy `cells` (sorted), all three axes.
fn fill_holes(cells: &[(CellKey, Acc)]) -> Vec<(CellKey, Acc)> {
    let mut fills: FastMap<CellKey, Acc> = FastMap::default();
    if cells.is_empty() {
        return Vec::new();
    }
    for axis in 0..3 {
        fill_axis(cells, axis, &mut fills);
    }
    let mut out: Vec<(CellKey, Acc)> = fills.into_iter().collect();
    out.sort_unstable_by_key(|c| c.0);
    out
}

/// The 8 neighbour columns, as (u, v) offsets.
const NEIGHBOURS: [[i32; 2]; 8] = [[-1, -1], [0, -1], [1, -1], [-1, 0], [1, 0], [-1, 1], [0, 1], [1, 1]];

fn fill_axis(cells: &[(CellKey, Acc)], axis: usize, fills: &mut FastMap<CellKey, Acc>) {
    let (ua, va) = ((axis + 1) % 3, (axis + 2) % 3);
    let uv_of = |k: CellKey| {
        let idx = k.index();
        [idx[ua], idx[va]]
    };
    let mut min = [i64::MAX; 2];
    let mut max = [i64::MIN; 2];
    for (k, _) in cells {
        let uv = uv_of(*k);
        for d in 0..2 {
            min[d] = min[d].min(i64::from(uv[d]));
            max[d] = max[d].max(i64::from(uv[d]));
        }
    }
    let mut lookup = ColumnLookup::new(min, max, cells.len());
    let mut columns: Vec<Column> = Vec::new();
    for (n, (k, _)) in cells.iter().enumerate() {
        let uv = uv_of(*k);
        let s = k.index()[axis];
        if let Some(id) = lookup.get(uv) {
            let c = &mut columns[id as usize];
            if s < c.front_s {
                (c.front, c.front_s) = (n, s);
            }
            if s > c.back_s {
                (c.back, c.back_s) = (n, s);
            }
        } else {
            lookup.insert(uv, columns.len() as u32);
            columns.push(Column { uv, front: n, back: n, front_s: s, back_s: s });
        }
    }

    // A hole has all four edge neighbours occupied, so it is an edge neighbour of some column.
    let mut holes: Vec<[i32; 2]> = Vec::new();
    for c in &columns {
        for o in [[0, -1], [-1, 0], [1, 0], [0, 1]] {
            let uv = [c.uv[0] + o[0], c.uv[1] + o[1]];
            if lookup.get(uv).is_none() {
                holes.push(uv);
            }
        }
    }
    holes.sort_unstable();
    holes.dedup();

    let key_of = |cell: usize| {
        let (k, a) = &cells[cell];
        (i64::from(k.index()[axis]) << POSITION_FRACTION_BITS) + a.mean_offset(axis) as i64
    };
    for uv in holes {
        let mut around = [0usize; 8];
        let mut n = 0;
        let mut edge_neighbours = 0;
        for o in NEIGHBOURS {
            if let Some(id) = lookup.get([uv[0] + o[0], uv[1] + o[1]]) {
                around[n] = id as usize;
                n += 1;
                if o[0] == 0 || o[1] == 0 {
                    edge_neighbours += 1;
                }
            }
        }
        if n < FILL_MIN_NEIGHBOURS || edge_neighbours < 4 {
            continue;
        }
        for back in [false, true] {
            let mut offered = [(0i64, 0usize); 8];
            let mut normal = [0i64; 3];
            for (slot, &id) in offered.iter_mut().zip(&around[..n]) {
                let col = &columns[id];
                let cell = if back { col.back } else { col.front };
                *slot = (key_of(cell), cell);
                for (sum, c) in normal.iter_mut().zip(cells[cell].1.normal) {
                    *sum += c;
                }
            }
            let offered = &mut offered[..n];
            offered.sort_unstable();
            let key = offered[if back { n / 2 } else { (n - 1) / 2 }].0;
            let mut idx = [0i32; 3];
            idx[axis] = (key >> POSITION_FRACTION_BITS) as i32;
            idx[ua] = uv[0];
            idx[va] = uv[1];
            let mut offset = [POS_HALF; 3];
            offset[axis] = (key & POS_MASK) as u64;
            let m = normal.map(|c| c as f64);
            let len = (m[0] * m[0] + m[1] * m[1] + m[2] * m[2]).sqrt();
            let nq = if len > 0.0 { m.map(|c| (c / len * NORMAL_ONE + 0.5).floor() as i64) } else { [0; 3] };
            let a = fills.entry(CellKey::from_index(idx)).or_default();
            for d in 0..3 {
                a.pos[d] += offset[d];
                a.normal[d] += nq[d];
            }
            a.count += 1;
        }
    }
}

#[cfg(test)]
// Exact float equality is what the fixed-point definition promises, so tests assert it; the
// index loops mirror the per-axis formulas of the module doc; unwrap is fine in tests.
#[allow(clippy::float_cmp, clippy::needless_range_loop, clippy::unwrap_used)]
mod tests {
    use super::*;
    use crate::lod::measure::point_triangle_dist2;
    use proptest::prelude::*;

    /// Deterministic xorshift for test inputs.
    struct Rng(u64);
    impl Rng {
        fn next(&mut self) -> f64 {
            self.0 ^= self.0 << 13;
            self.0 ^= self.0 >> 7;
            self.0 ^= self.0 << 17;
            (self.0 >> 11) as f64 / (1u64 << 53) as f64
        }
    }

    /// A regular grid mesh over [x0, x0 + nx·step] × [y0, y0 + ny·step] with z = f(x, y),
    /// leaving out the quads for which `hole(qx, qy)` is true.
    fn grid_mesh(
        nx: u32,
        ny: u32,
        x0: f64,
        y0: f64,
        step: f64,
        f: impl Fn(f64, f64) -> f64,
        hole: impl Fn(u32, u32) -> bool,
    ) -> Mesh {
        let mut m = Mesh::default();
        for y in 0..=ny {
            for x in 0..=nx {
                let (px, py) = (x0 + f64::from(x) * step, y0 + f64::from(y) * step);
                m.positions.push([px, py, f(px, py)]);
            }
        }
        let id = |x: u32, y: u32| y * (nx + 1) + x;
        for y in 0..ny {
            for x in 0..nx {
                if hole(x, y) {
                    continue;
                }
                m.triangles.push([id(x, y), id(x + 1, y), id(x + 1, y + 1)]);
                m.triangles.push([id(x, y), id(x + 1, y + 1), id(x, y + 1)]);
            }
        }
        m
    }

    /// Icosphere of radius `r` around `c`, outward right-hand triangles.
    fn icosphere(c: [f64; 3], r: f64, subdivisions: u32) -> Mesh {
        let t = f64::midpoint(1.0, 5.0f64.sqrt());
        let mut v: Vec<[f64; 3]> = vec![
            [-1.0, t, 0.0],
            [1.0, t, 0.0],
            [-1.0, -t, 0.0],
            [1.0, -t, 0.0],
            [0.0, -1.0, t],
            [0.0, 1.0, t],
            [0.0, -1.0, -t],
            [0.0, 1.0, -t],
            [t, 0.0, -1.0],
            [t, 0.0, 1.0],
            [-t, 0.0, -1.0],
            [-t, 0.0, 1.0],
        ];
        let mut f: Vec<[u32; 3]> = vec![
            [0, 11, 5],
            [0, 5, 1],
            [0, 1, 7],
            [0, 7, 10],
            [0, 10, 11],
            [1, 5, 9],
            [5, 11, 4],
            [11, 10, 2],
            [10, 7, 6],
            [7, 1, 8],
            [3, 9, 4],
            [3, 4, 2],
            [3, 2, 6],
            [3, 6, 8],
            [3, 8, 9],
            [4, 9, 5],
            [2, 4, 11],
            [6, 2, 10],
            [8, 6, 7],
            [9, 8, 1],
        ];
        let norm = |p: [f64; 3]| {
            let l = (p[0] * p[0] + p[1] * p[1] + p[2] * p[2]).sqrt();
            [p[0] / l, p[1] / l, p[2] / l]
        };
        for p in &mut v {
            *p = norm(*p);
        }
        for _ in 0..subdivisions {
            let mut mid = std::collections::HashMap::new();
            let mut next = Vec::new();
            for tri in &f {
                let mut m = [0u32; 3];
                for e in 0..3 {
                    let (a, b) = (tri[e], tri[(e + 1) % 3]);
                    let key = (a.min(b), a.max(b));
                    m[e] = *mid.entry(key).or_insert_with(|| {
                        let (pa, pb) = (v[a as usize], v[b as usize]);
                        v.push(norm([pa[0] + pb[0], pa[1] + pb[1], pa[2] + pb[2]]));
                        (v.len() - 1) as u32
                    });
                }
                next.push([tri[0], m[0], m[2]]);
                next.push([tri[1], m[1], m[0]]);
                next.push([tri[2], m[2], m[1]]);
                next.push([m[0], m[1], m[2]]);
            }
            f = next;
        }
        Mesh {
            positions: v.iter().map(|p| [c[0] + r * p[0], c[1] + r * p[1], c[2] + r * p[2]]).collect(),
            triangles: f,
        }
    }

    fn dist_to_mesh(mesh: &Mesh, p: [f64; 3]) -> f64 {
        mesh.triangles
            .iter()
            .map(|t| {
                let tri = t.map(|i| glam::DVec3::from_array(mesh.positions[i as usize]));
                point_triangle_dist2(glam::DVec3::from_array(p), &tri)
            })
            .fold(f64::INFINITY, f64::min)
            .sqrt()
    }

    /// Synthetic terrain: smooth hills plus a steep ridge, on a jittered grid.
    fn terrain(n: u32, step: f64, seed: u64) -> Mesh {
        let mut rng = Rng(seed);
        let mut m = grid_mesh(
            n,
            n,
            0.0,
            0.0,
            step,
            |x, y| {
                20.0 * (x * 0.03).sin() * (y * 0.025).cos()
                    + 8.0 * (x * 0.11 + y * 0.07).sin()
                    + 30.0 / (1.0 + (-(x - 0.6 * y - 40.0) * 0.5).exp())
            },
            |_, _| false,
        );
        let edge = f64::from(n) * step;
        for p in &mut m.positions {
            if p[0] > 0.0 && p[0] < edge && p[1] > 0.0 && p[1] < edge {
                p[0] += (rng.next() - 0.5) * 0.3 * step;
                p[1] += (rng.next() - 0.5) * 0.3 * step;
            }
        }
        m
    }

    #[test]
    fn flat_square_gives_one_point_per_column_on_the_plane() {
        let m = grid_mesh(1, 1, 0.0, 0.0, 10.0, |_, _| 3.25, |_, _| false);
        let (cells, stats) = bake_cells(&m, [0.0; 3], 1.0, &SliceOptions::default());
        assert_eq!(cells.len(), 100);
        assert_eq!(stats.fragments, [0, 0, 100], "edge-on views have zero area");
        assert_eq!(stats.filled, 0);
        for c in &cells {
            assert_eq!(c.index[2], 3);
            assert_eq!(c.position, [f64::from(c.index[0]) + 0.5, f64::from(c.index[1]) + 0.5, 3.25]);
            assert_eq!(c.normal, [0.0, 0.0, 1.0]);
        }
        let cloud = bake_points(&m, [0.0; 3], 1.0);
        let e = measure_points(&m, &cloud, 1.0);
        assert!(e.max < 1e-12 && e.rms < 1e-12, "{e:?}");
        // Corners of the square are √½ from the nearest pixel centre.
        assert!((e.gap - 0.5f64.sqrt()).abs() < 0.01, "{e:?}");
    }

    #[test]
    fn plane_off_the_fixed_point_lattice_is_within_rounding() {
        let (origin, cell) = ([-3.0, 7.0, 100.0], 0.37);
        let m = grid_mesh(3, 3, -2.9, 7.05, 1.1, |_, _| 101.123_456_7, |_, _| false);
        let cloud = bake_points(&m, origin, cell);
        assert!(!cloud.positions.is_empty());
        for p in &cloud.positions {
            assert!((p[2] - 101.123_456_7).abs() <= cell / POS_ONE, "{p:?}");
        }
    }

    #[test]
    fn pixel_centres_on_shared_edges_and_vertices_are_produced_once() {
        // Vertices and diagonals on pixel centres: every centre is a tie for several triangles.
        let m = grid_mesh(8, 8, 0.5, 0.5, 1.0, |_, _| 0.5, |_, _| false);
        let (cells, stats) = bake_cells(&m, [0.0; 3], 1.0, &SliceOptions { fill_holes: false });
        // Centres 0.5 ..= 8.5 on each axis lie on the closed square; those on its far
        // boundary edges fall on non-tie edges and are left to the (absent) neighbour tile.
        assert_eq!(stats.fragments[2], cells.len() as u64);
        assert_eq!(cells.len(), 64, "one fragment per centre of the half-open square");
        // A mirrored diagonal split must give the same coverage.
        let mut m2 = m.clone();
        for t in &mut m2.triangles {
            t.swap(1, 2);
        }
        let (cells2, stats2) = bake_cells(&m2, [0.0; 3], 1.0, &SliceOptions { fill_holes: false });
        assert_eq!(stats2.fragments[2], 64);
        let idx: Vec<_> = cells.iter().map(|c| c.index).collect();
        let idx2: Vec<_> = cells2.iter().map(|c| c.index).collect();
        assert_eq!(idx, idx2);
    }

    #[test]
    fn tilted_plane_points_lie_on_it_without_holes() {
        let f = |x: f64, y: f64| 0.3 * x + 0.2 * y + 1.1;
        let m = grid_mesh(6, 6, 0.0, 0.0, 2.0, f, |_, _| false);
        let cell = 0.5;
        let (cloud, stats) = bake_points_with_stats(&m, [0.0; 3], cell);
        assert!(stats.fragments.iter().all(|&n| n > 0), "{stats:?}");
        for p in &cloud.positions {
            // Means of points of one plane stay on it, up to the fixed-point rounding.
            let n = (0.3f64 * 0.3 + 0.2 * 0.2 + 1.0).sqrt();
            assert!((p[2] - f(p[0], p[1])).abs() / n < 2.0 * cell / POS_ONE, "{p:?}");
        }
        let e = measure_points(&m, &cloud, cell);
        assert!(e.max < 1e-4 * cell && e.gap < cell, "{e:?}");
    }

    #[test]
    fn steep_slope_is_covered_by_the_side_views() {
        // 3:1 slope: the top view alone would leave 3-cell vertical gaps between its points.
        let f = |x: f64, y: f64| 3.0 * x + 0.5 * y;
        let m = grid_mesh(4, 4, 0.0, 0.0, 2.5, f, |_, _| false);
        let cell = 1.0;
        let (cloud, stats) = bake_points_with_stats(&m, [0.0; 3], cell);
        assert!(stats.fragments[0] > 2 * stats.fragments[2], "{stats:?}");
        let e = measure_points(&m, &cloud, cell);
        assert!(e.gap < cell && e.max < 1e-4, "{e:?}");
    }

    #[test]
    fn closed_sphere_gets_points_on_all_sides_and_none_inside() {
        let (c, r) = ([10.3, -4.2, 7.7], 6.0);
        let m = icosphere(c, r, 3);
        let cell = 0.8;
        let (cells, stats) = bake_cells(&m, [0.0; 3], cell, &SliceOptions::default());
        assert!(stats.skipped_triangles == 0 && cells.len() > 300, "{stats:?}");
        let mut extremes = [f64::INFINITY, f64::NEG_INFINITY].repeat(3);
        for cell_pt in &cells {
            let p = cell_pt.position;
            let d = [p[0] - c[0], p[1] - c[1], p[2] - c[2]];
            let len = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt();
            // The mesh is inscribed in the sphere: its faces sit at most ~1 % inside.
            assert!(len > 0.97 * r && len < 1.001 * r, "{p:?} at {len}");
            let n = cell_pt.normal.map(f64::from);
            assert!(n[0] * d[0] + n[1] * d[1] + n[2] * d[2] > 0.5 * len, "inward normal at {p:?}");
            for a in 0..3 {
                extremes[2 * a] = extremes[2 * a].min(d[a]);
                extremes[2 * a + 1] = extremes[2 * a + 1].max(d[a]);
            }
        }
        for (a, e) in extremes.iter().enumerate() {
            assert!(e.abs() > r - cell, "side {a}: {e}");
        }
        let cloud = bake_points(&m, [0.0; 3], cell);
        let e = measure_points(&m, &cloud, cell);
        assert!(e.max < 0.1 * cell && e.gap < cell, "{e:?}");
    }

    #[test]
    fn cube_faces_each_come_from_one_view() {
        let (a, b) = (0.3, 4.3);
        let v = |i: u32| {
            [if i & 1 == 0 { a } else { b }, if i & 2 == 0 { a } else { b }, if i & 4 == 0 { a } else { b }]
        };
        let m = Mesh {
            positions: (0..8).map(v).collect(),
            triangles: vec![
                [0, 2, 1],
                [1, 2, 3],
                [4, 5, 6],
                [5, 7, 6],
                [0, 1, 4],
                [1, 5, 4],
                [2, 6, 3],
                [3, 6, 7],
                [0, 4, 2],
                [2, 4, 6],
                [1, 3, 5],
                [3, 7, 5],
            ],
        };
        let (cells, stats) = bake_cells(&m, [0.0; 3], 1.0, &SliceOptions::default());
        // Each face's 4×4 pixel centres, from its axis's view only.
        assert_eq!(stats.fragments, [32, 32, 32]);
        assert_eq!(stats.filled, 0);
        assert_eq!(cells.iter().map(|c| c.samples).sum::<u64>(), 96);
        let on = |p: f64| (p - a).abs() < 1e-4 || (p - b).abs() < 1e-4;
        for c in &cells {
            let p = c.position;
            // Cells along the cube's edges average fragments of two or three faces.
            let faces: Vec<usize> = (0..3).filter(|&d| on(p[d])).collect();
            let mut expect = [0.0f64; 3];
            for d in 0..3 {
                let lo = f64::from(c.index[d]) < a + 0.5;
                let hi = f64::from(c.index[d]) > b - 1.0;
                if lo || hi {
                    expect[d] = if lo { -1.0 } else { 1.0 };
                }
            }
            if c.samples == 1 {
                assert_eq!(faces.len(), 1, "{c:?}");
                let d = faces[0];
                assert_eq!(f64::from(c.normal[d]), expect[d], "{c:?}");
            } else {
                // Inside the cube there are no points; edge cells point diagonally out.
                let dot: f64 = (0..3).map(|d| f64::from(c.normal[d]) * expect[d]).sum();
                assert!(dot > 0.99 * (c.samples as f64).sqrt(), "{c:?}");
            }
        }
    }

    #[test]
    fn output_is_deterministic_and_independent_of_triangle_order() {
        let m = terrain(24, 3.0, 7);
        let cell = 2.0;
        let origin = [0.0, 0.0, -40.0];
        let a = bake_cells(&m, origin, cell, &SliceOptions::default());
        let b = bake_cells(&m, origin, cell, &SliceOptions::default());
        assert_eq!(a, b);
        let mut shuffled = m.clone();
        let mut rng = Rng(99);
        for i in (1..shuffled.triangles.len()).rev() {
            let j = (rng.next() * (i + 1) as f64) as usize;
            shuffled.triangles.swap(i, j);
        }
        for (n, t) in shuffled.triangles.iter_mut().enumerate() {
            t.rotate_left(n % 3);
        }
        let c = bake_cells(&shuffled, origin, cell, &SliceOptions::default());
        assert_eq!(a, c);
        let keys: Vec<_> = a.0.iter().map(|c| (c.index[2], c.index[1], c.index[0])).collect();
        assert!(keys.windows(2).all(|w| w[0] < w[1]), "sorted by (k, j, i), unique");
    }

    #[test]
    fn hole_filler_fills_a_single_pixel_but_not_a_large_hole() {
        // Quads are pixels here: quad (qx, qy) holds pixel centre (qx + ½, qy + ½).
        let f = |_: f64, _: f64| 2.4;
        let one = grid_mesh(9, 9, 0.0, 0.0, 1.0, f, |x, y| x == 4 && y == 5);
        let (cells, stats) = bake_cells(&one, [0.0; 3], 1.0, &SliceOptions::default());
        assert_eq!(stats.filled, 1, "{stats:?}");
        let filled: Vec<_> = cells.iter().filter(|c| c.filled).collect();
        assert_eq!(filled[0].index, [4, 5, 2]);
        // z carries the neighbours' fixed-point rounding.
        assert_eq!(filled[0].position, [4.5, 5.5, 2.0 + (0.4 * POS_ONE + 0.5).floor() / POS_ONE]);
        assert_eq!(filled[0].normal, [0.0, 0.0, 1.0]);
        let without = bake_cells(&one, [0.0; 3], 1.0, &SliceOptions { fill_holes: false });
        assert_eq!(without.0.len() + 1, cells.len());

        // A 6×6 hole stays open, corners included (they lack two edge neighbours).
        let big = grid_mesh(12, 12, 0.0, 0.0, 1.0, f, |x, y| (3..9).contains(&x) && (3..9).contains(&y));
        let (_, stats) = bake_cells(&big, [0.0; 3], 1.0, &SliceOptions::default());
        assert_eq!(stats.filled, 0, "{stats:?}");
        // So does a concave corner of the outline (an L-shaped region).
        let ell = grid_mesh(8, 8, 0.0, 0.0, 1.0, f, |x, y| x >= 4 && y >= 4);
        let (_, stats) = bake_cells(&ell, [0.0; 3], 1.0, &SliceOptions::default());
        assert_eq!(stats.filled, 0, "{stats:?}");
    }

    #[test]
    fn hole_filler_uses_the_median_neighbour_depth() {
        // Neighbours at different heights: the fill takes the lower median of their keys.
        // Separate horizontal pixel quads around an empty centre, each at its own height.
        let heights = [[0.2, 0.3, 0.9], [0.1, 0.0, 1.4], [2.6, 0.6, 0.7]];
        let mut m = Mesh::default();
        for (qy, row) in heights.iter().enumerate() {
            for (qx, &h) in row.iter().enumerate() {
                if qx == 1 && qy == 1 {
                    continue;
                }
                let base = m.positions.len() as u32;
                let (x, y) = (qx as f64, qy as f64);
                m.positions.extend([[x, y, h], [x + 1.0, y, h], [x + 1.0, y + 1.0, h], [x, y + 1.0, h]]);
                m.triangles.push([base, base + 1, base + 2]);
                m.triangles.push([base, base + 2, base + 3]);
            }
        }
        let (cells, stats) = bake_cells(&m, [0.0; 3], 1.0, &SliceOptions::default());
        assert_eq!(stats.filled, 1, "{stats:?}");
        let fill: Vec<_> = cells.iter().filter(|c| c.filled).collect();
        assert_eq!(fill[0].index[..2], [1, 1]);
        // Sorted neighbour heights 0.1 0.2 0.3 0.6 0.7 0.9 1.4 2.6: lower median 0.6, upper 0.7:
        // same slice, so one cell at their mean.
        let expected = 0.5 * ((0.6 * POS_ONE + 0.5).floor() + (0.7 * POS_ONE + 0.5).floor()) / POS_ONE;
        assert!((fill[0].position[2] - expected).abs() < 1e-12, "{:?}", fill[0]);
        assert_eq!(fill[0].samples, 2);
    }

    #[test]
    fn measure_matches_brute_force() {
        let mut rng = Rng(3);
        let mut m = Mesh::default();
        for _ in 0..40 {
            m.positions.push([rng.next() * 6.0, rng.next() * 6.0, rng.next() * 3.0]);
        }
        for _ in 0..25 {
            let pick = |r: &mut Rng| (r.next() * 40.0) as u32;
            m.triangles.push([pick(&mut rng), pick(&mut rng), pick(&mut rng)]);
        }
        let points = PointCloud {
            positions: (0..60)
                .map(|_| [rng.next() * 8.0 - 1.0, rng.next() * 8.0 - 1.0, rng.next() * 5.0 - 1.0])
                .collect(),
            normals: vec![[0.0, 0.0, 1.0]; 60],
        };
        let cell = 0.7;
        let e = measure_points(&m, &points, cell);
        let d: Vec<f64> = points.positions.iter().map(|&p| dist_to_mesh(&m, p)).collect();
        let max = d.iter().copied().fold(0.0, f64::max);
        let rms = (d.iter().map(|v| v * v).sum::<f64>() / d.len() as f64).sqrt();
        assert!((e.max - max).abs() < 1e-9 && (e.rms - rms).abs() < 1e-9, "{e:?} vs {max} {rms}");
        // Brute-force gap on a denser sampling: equal within the sampling spacing.
        let mut gap = 0.0f64;
        for t in &m.triangles {
            let tri = t.map(|i| m.positions[i as usize]);
            for i in 0..=60 {
                for j in 0..=(60 - i) {
                    let (u, v) = (f64::from(i) / 60.0, f64::from(j) / 60.0);
                    let q = [0, 1, 2]
                        .map(|a| tri[0][a] + u * (tri[1][a] - tri[0][a]) + v * (tri[2][a] - tri[0][a]));
                    let near = points
                        .positions
                        .iter()
                        .map(|p| {
                            ((p[0] - q[0]).powi(2) + (p[1] - q[1]).powi(2) + (p[2] - q[2]).powi(2)).sqrt()
                        })
                        .fold(f64::INFINITY, f64::min);
                    gap = gap.max(near);
                }
            }
        }
        assert!((e.gap - gap).abs() < cell / 4.0, "{} vs {gap}", e.gap);
    }

    #[test]
    fn degenerate_inputs_give_empty_results() {
        let m = grid_mesh(2, 2, 0.0, 0.0, 1.0, |_, _| 0.0, |_, _| false);
        for cell in [0.0, -1.0, f64::NAN, f64::INFINITY] {
            let (cloud, stats) = bake_points_with_stats(&m, [0.0; 3], cell);
            assert!(cloud.positions.is_empty() && stats.skipped_triangles == m.triangles.len());
        }
        assert!(bake_points(&m, [f64::NAN, 0.0, 0.0], 1.0).positions.is_empty());
        assert!(bake_points(&Mesh::default(), [0.0; 3], 1.0).positions.is_empty());
        let mut bad = m.clone();
        bad.triangles.push([0, 1, 99]);
        bad.positions[8] = [f64::NAN, 0.0, 0.0];
        let (_, stats) = bake_points_with_stats(&bad, [0.0; 3], 1.0);
        // The bad index, and the two triangles at the NaN corner.
        assert_eq!(stats.skipped_triangles, 3);

        let cloud = bake_points(&m, [0.0; 3], 0.5);
        assert_eq!(measure_points(&Mesh::default(), &cloud, 0.5), Errors::default());
        let e = measure_points(&m, &PointCloud::default(), 0.5);
        assert!(e.max == 0.0 && (e.gap - 8.0f64.sqrt()).abs() < 1e-12, "{e:?}");
    }

    #[test]
    fn terrain_tile_has_no_holes() {
        let m = terrain(32, 4.0, 11);
        let cell = 2.0;
        let (cloud, stats) = bake_points_with_stats(&m, [0.0, 0.0, -50.0], cell);
        assert!(stats.fragments[0] > 0 && stats.fragments[1] > 0, "{stats:?}");
        let e = measure_points(&m, &cloud, cell);
        // Inside the tile the side views keep the gap under a cell; along the tile's border
        // the surface beyond the last pixel centre (half a cell) is sampled only where it
        // crosses a slice, so the gap there reaches about √½·√(1 + slope²) cells.
        assert!(e.gap < 1.2 * cell && e.max < 0.1 * cell, "{e:?}");
    }

    #[test]
    fn huge_index_boxes_take_the_wide_keys_with_the_same_result() {
        let near = icosphere([3.1, -2.2, 5.3], 4.0, 2);
        let mut far = near.clone();
        // A second triangle 2^26 cells away on every axis: too wide for 64-bit keys.
        let base = far.positions.len() as u32;
        let off = 67_108_864.0;
        far.positions.extend([[off, off, off], [off + 1.0, off, off], [off, off + 1.0, off + 0.5]]);
        far.triangles.push([base, base + 1, base + 2]);
        assert!(PackedCodec::new([-1, -1, -1], [67_108_866; 3]).is_none());
        let (a, sa) = bake_cells(&near, [0.0; 3], 0.5, &SliceOptions::default());
        let (b, sb) = bake_cells(&far, [0.0; 3], 0.5, &SliceOptions::default());
        assert_eq!(sb.skipped_triangles, 0);
        assert!(sb.occupied > sa.occupied);
        assert_eq!(a[..], b[..a.len()]);
        for c in &b[a.len()..] {
            assert!(c.index.iter().all(|&v| v >= 134_217_000), "{c:?}");
        }
    }

    #[test]
    fn codecs_round_trip() {
        let packed = PackedCodec::new([-7, 3, -100], [20, 9, 400]).unwrap();
        for idx in [[-7, 3, -100], [20, 9, 400], [0, 5, 0], [-1, 4, 399]] {
            for axis in 0..3 {
                let k = packed.encode(idx, axis);
                assert_eq!((packed.decode(k), PackedCodec::axis(k)), (idx, axis));
                let w = WideCodec.encode(idx, axis);
                assert_eq!((WideCodec.decode(w), WideCodec::axis(w)), (idx, axis));
            }
        }
        let order = |i: [i32; 3]| (i[2], i[1], i[0]);
        let pairs = [([-7, 9, 0], [20, 3, 1]), ([0, 3, -100], [-7, 4, -100]), ([5, 5, 5], [6, 5, 5])];
        for (x, y) in pairs {
            assert_eq!(packed.encode(x, 2) < packed.encode(y, 0), order(x) < order(y));
            assert_eq!(WideCodec.encode(x, 2) < WideCodec.encode(y, 0), order(x) < order(y));
        }
        assert!(WideCodec.encode([i32::MIN, 0, -1], 0) < WideCodec.encode([i32::MAX, 0, -1], 0));
    }

    /// Timing of a 256×256 terrain tile at cell = 2 (run with `--release --ignored`).
    #[test]
    #[ignore = "timing; run in release"]
    fn time_terrain_tile() {
        for (n, step) in [(85, 3.0), (102, 2.5)] {
            let m = terrain(n, step * 256.0 / (f64::from(n) * step), 5);
            let cell = 2.0;
            let origin = [0.0, 0.0, -50.0];
            // The minimum of many runs: the least disturbed by other work on the machine.
            let mut stats = BakeStats::default();
            let mut cloud = PointCloud::default();
            let mut times = Vec::new();
            for _ in 0..40 {
                let t = std::time::Instant::now();
                (cloud, stats) = bake_points_with_stats(&m, origin, cell);
                times.push(t.elapsed().as_secs_f64());
            }
            times.sort_by(f64::total_cmp);
            let (bake, median) = (times[0], times[times.len() / 2]);
            let t = std::time::Instant::now();
            let e = measure_points(&m, &cloud, cell);
            let measure = t.elapsed().as_secs_f64();
            eprintln!(
                "{} triangles: bake {:.2} ms (median {:.2}; {} points, {stats:?}), measure {:.1} ms {e:?}",
                m.triangles.len(),
                bake * 1e3,
                median * 1e3,
                cloud.positions.len(),
                measure * 1e3
            );
        }
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(48))]
        #[test]
        fn points_lie_in_their_cells_near_the_mesh(
            seed in 1u64..u64::MAX,
            cell in 0.2f64..3.0,
            ox in -5.0f64..5.0, oy in -5.0f64..5.0, oz in -5.0f64..5.0,
        ) {
            let mut rng = Rng(seed);
            let mut m = Mesh::default();
            for _ in 0..12 {
                m.positions.push([rng.next() * 8.0, rng.next() * 8.0, rng.next() * 8.0]);
            }
            for _ in 0..8 {
                let pick = |r: &mut Rng| (r.next() * 12.0) as u32;
                m.triangles.push([pick(&mut rng), pick(&mut rng), pick(&mut rng)]);
            }
            let origin = [ox, oy, oz];
            let (cells, _) = bake_cells(&m, origin, cell, &SliceOptions::default());
            let eps = 1e-9 * (1.0 + cell);
            for c in &cells {
                for d in 0..3 {
                    let lo = origin[d] + f64::from(c.index[d]) * cell;
                    prop_assert!(c.position[d] >= lo - eps && c.position[d] <= lo + cell + eps, "{:?}", c);
                }
                let dist = dist_to_mesh(&m, c.position);
                // A fill copies a neighbour's depth one pixel away: allow two more cells.
                let bound = if c.filled { cell * (3.0f64.sqrt() + 2.2) } else { cell * 3.0f64.sqrt() };
                prop_assert!(dist <= bound, "{:?} at {}", c, dist);
                let n = c.normal;
                let len = f32::sqrt(n[0] * n[0] + n[1] * n[1] + n[2] * n[2]);
                prop_assert!((len - 1.0).abs() < 1e-5);
            }
        }
    }
}
