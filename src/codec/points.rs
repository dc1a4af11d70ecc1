//! Point payloads and octahedral normals (see the layout in the parent module's docs).
//!
//! Points of a level come from a voxel walk over a terrain surface: roughly one point per (x, y)
//! column, a few stacked where the surface is steep, neighbours with similar z and normals. So
//! the coder works like an image coder: it sorts points into rows and columns of cells, codes
//! the occupancy as runs, and predicts each z and normal from the cells to the left, above and
//! above-left (LOCO-I's median edge detector), leaving zstd small residuals.

use super::stream::{BucketReader, BucketWriter, Packed, Reader, Writer, pack, unpack};
use super::{CodecError, MAX_QUANT, QuantGrid};
use crate::geom::PointCloud;

const MODE_GRID: u8 = 0;
const STREAMS: [&str; 13] = [
    "points params",
    "points rows",
    "points cells",
    "points counts",
    "points fine x",
    "points fine y",
    "points z",
    "points z bits",
    "points stacked z",
    "points nu",
    "points nv",
    "points stacked nu",
    "points stacked nv",
];
/// Largest cell shift; keeps a fine offset in one byte.
const MAX_SHIFT: u32 = 8;
/// Octahedral coordinates use 0..=254 so that 0.0 (the straight-up normal of flat ground) is
/// exactly representable as 127.
const OCT_SCALE: f32 = 127.0;

/// Octahedral 8+8-bit encoding of a direction; `None` unless `n` is finite and non-zero. The
/// vector need not be unit length.
#[must_use]
pub fn oct_encode(n: [f32; 3]) -> Option<[u8; 2]> {
    let l1 = n[0].abs() + n[1].abs() + n[2].abs();
    if !(n.iter().all(|v| v.is_finite()) && l1 > 0.0 && l1.is_finite()) {
        return None;
    }
    let (mut u, mut v) = (n[0] / l1, n[1] / l1);
    if n[2] < 0.0 {
        (u, v) = ((1.0 - v.abs()) * sign(u), (1.0 - u.abs()) * sign(v));
    }
    let byte = |t: f32| ((t + 1.0) * OCT_SCALE).round().clamp(0.0, 2.0 * OCT_SCALE) as u8;
    Some([byte(u), byte(v)])
}

/// The unit normal an octahedral pair stands for (what decoding returns). Every pair decodes to
/// a unit vector; 255 is treated as 254.
///
/// Decoding is canonical: the result re-encodes to a pair that decodes to the same bits, so
/// decode → encode → decode is bit-exact. Pairs on the octahedron's folded seam (`|u| + |v| = 1`
/// below the equator, and the 255 rows) stand for a direction that another pair also stands
/// for, and the fold's arithmetic gives the two a different sign of zero or last bit; such a
/// pair decodes as the pair its direction encodes to (one step: that pair is its own
/// encoding, checked for all 65,536 pairs by the tests).
#[must_use]
pub fn oct_decode(b: [u8; 2]) -> [f32; 3] {
    let n = oct_decode_raw(b);
    match oct_encode(n) {
        Some(canonical) if canonical != b => oct_decode_raw(canonical),
        _ => n,
    }
}

/// The octahedral map's inverse, as computed from the pair itself.
fn oct_decode_raw(b: [u8; 2]) -> [f32; 3] {
    let t = |b: u8| (f32::from(b) / OCT_SCALE - 1.0).clamp(-1.0, 1.0);
    let (u, v) = (t(b[0]), t(b[1]));
    let z = 1.0 - u.abs() - v.abs();
    let (x, y) = if z < 0.0 { ((1.0 - v.abs()) * sign(u), (1.0 - u.abs()) * sign(v)) } else { (u, v) };
    // On the octahedron |x| + |y| + |z| = 1, so the length is at least 1/√3.
    let len = (x * x + y * y + z * z).sqrt();
    [x / len, y / len, z / len]
}

fn sign(v: f32) -> f32 {
    if v < 0.0 { -1.0 } else { 1.0 }
}

/// The normals as decoding returns them. Errors: a normal that is not a finite non-zero vector.
pub fn quantize_normals(normals: &[[f32; 3]]) -> Result<Vec<[f32; 3]>, CodecError> {
    normals
        .iter()
        .enumerate()
        .map(|(index, &n)| oct_encode(n).map(oct_decode).ok_or(CodecError::BadNormal { index, normal: n }))
        .collect()
}

/// One occupied cell: its coordinates and the range of its points in sorted order.
#[derive(Debug, Clone, Copy)]
struct Cell {
    cx: i64,
    cy: i64,
    start: usize,
    count: usize,
}

/// A point in lattice units, as sorted and coded.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord)]
struct Key {
    cy: i64,
    cx: i64,
    z: i64,
    fy: i64,
    fx: i64,
    oct: [u8; 2],
}

/// A cloud on its lattice, ready for either mode.
struct Prepared {
    lattice: Vec<[i64; 3]>,
    oct: Vec<[u8; 2]>,
    /// The grid mode's lattice and cell shift (the context mode picks its own shift).
    grid: LatticeParams,
}

/// The parameters both modes store first: lattice point `l` is quantized position
/// `base + l·stride` on each axis, and cells are `2^shift` lattice steps wide.
#[derive(Debug, Clone, Copy)]
struct LatticeParams {
    base: [i64; 3],
    stride: [i64; 3],
    shift: u32,
}

impl LatticeParams {
    /// Base, stride and shift as varints, in that order.
    fn write(&self, w: &mut Writer) {
        for v in self.base.iter().chain(&self.stride) {
            w.varint(*v as u64);
        }
        w.varint(u64::from(self.shift));
    }

    /// What [`Self::write`] wrote, each value checked: a base within the frame, a stride of
    /// 1..=`MAX_QUANT + 1`, a shift of at most `MAX_SHIFT`.
    fn read(r: &mut Reader, frame: &QuantGrid) -> Result<Self, CodecError> {
        let mut base = [0i64; 3];
        let mut stride = [1i64; 3];
        for (a, b) in base.iter_mut().enumerate() {
            *b = r.count(frame.qmax[a] as usize)? as i64;
        }
        for s in &mut stride {
            *s = r.count(MAX_QUANT as usize + 1)? as i64;
            if *s == 0 {
                return Err(CodecError::Corrupt("points params"));
            }
        }
        let shift = r.count(MAX_SHIFT as usize)? as u32;
        Ok(Self { base, stride, shift })
    }

    /// The position of lattice point `l`; an error where it overflows or leaves the frame.
    fn position(&self, frame: &QuantGrid, l: [i64; 3]) -> Result<[f64; 3], CodecError> {
        let bad = || CodecError::Corrupt("points positions");
        let mut qp = [0i64; 3];
        for a in 0..3 {
            qp[a] =
                l[a].checked_mul(self.stride[a]).and_then(|v| v.checked_add(self.base[a])).ok_or_else(bad)?;
        }
        if !frame.contains(qp) {
            return Err(bad());
        }
        Ok(frame.position(qp))
    }
}

fn prepare(frame: &QuantGrid, pc: &PointCloud) -> Result<Prepared, CodecError> {
    let n = pc.positions.len();
    if pc.normals.len() != n {
        return Err(CodecError::NormalCountMismatch { points: n, normals: pc.normals.len() });
    }
    let q =
        pc.positions.iter().enumerate().map(|(i, &p)| frame.quantize(p, i)).collect::<Result<Vec<_>, _>>()?;
    let oct = pc
        .normals
        .iter()
        .enumerate()
        .map(|(index, &nv)| oct_encode(nv).ok_or(CodecError::BadNormal { index, normal: nv }))
        .collect::<Result<Vec<_>, _>>()?;
    // Points on a lattice (voxel centres, pixel centres) share a stride per axis: dividing it
    // out makes neighbours differ by small integers.
    let mut base = [0i64; 3];
    let mut stride = [1i64; 3];
    for a in 0..3 {
        base[a] = q.iter().map(|p| p[a]).min().unwrap_or(0);
        let g = q.iter().fold(0, |g, p| gcd(g, p[a] - base[a]));
        stride[a] = g.max(1);
    }
    let lattice: Vec<[i64; 3]> =
        q.iter().map(|p| std::array::from_fn(|a| (p[a] - base[a]) / stride[a])).collect();
    let shift = choose_shift(&lattice);
    Ok(Prepared { lattice, oct, grid: LatticeParams { base, stride, shift } })
}

pub(super) fn encode(frame: &QuantGrid, pc: &PointCloud) -> Result<Packed, CodecError> {
    let p = prepare(frame, pc)?;
    let grid = encode_grid(&p)?;
    let context = context::encode(frame, &p)?;
    // The context mode is the smaller on every terrain level measured; the grid mode stays
    // the fallback for clouds it models worse, so no blob grows.
    Ok(if context.payload.len() < grid.payload.len() { context } else { grid })
}

/// The payload of one mode (`MODE_GRID` or `context::MODE_CONTEXT`), for tests and figures.
#[cfg(test)]
pub(super) fn encode_mode(frame: &QuantGrid, pc: &PointCloud, mode: u8) -> Result<Packed, CodecError> {
    let p = prepare(frame, pc)?;
    if mode == MODE_GRID { encode_grid(&p) } else { context::encode(frame, &p) }
}

/// Mode 0: the sorted lattice in zstd'ed residual streams.
fn encode_grid(p: &Prepared) -> Result<Packed, CodecError> {
    let Prepared { lattice, oct, grid } = p;
    let shift = grid.shift;
    let n = lattice.len();
    let mask = (1i64 << shift) - 1;
    let mut keys: Vec<Key> = lattice
        .iter()
        .zip(oct)
        .map(|(l, &oct)| Key {
            cy: l[1] >> shift,
            cx: l[0] >> shift,
            z: l[2],
            fy: l[1] & mask,
            fx: l[0] & mask,
            oct,
        })
        .collect();
    keys.sort_unstable();

    let mut params = Writer::default();
    grid.write(&mut params);
    let [mut rows, mut cells_w, mut counts, mut fxs, mut fys] = std::array::from_fn(|_| Writer::default());
    let cells = group_cells(&keys);
    let mut prev_cy = 0i64;
    let mut prev_first_cx = 0i64;
    let mut i = 0;
    while i < cells.len() {
        let cy = cells[i].cy;
        let len = cells[i..].iter().take_while(|c| c.cy == cy).count();
        rows.varint((cy - prev_cy - i64::from(i > 0)) as u64);
        rows.varint(len as u64 - 1);
        cells_w.signed(cells[i].cx - prev_first_cx);
        for w in cells[i..i + len].windows(2) {
            cells_w.varint((w[1].cx - w[0].cx - 1) as u64);
        }
        for c in &cells[i..i + len] {
            counts.varint(c.count as u64 - 1);
        }
        prev_cy = cy;
        prev_first_cx = cells[i].cx;
        i += len;
    }
    if shift > 0 {
        for k in &keys {
            fxs.u8(k.fx as u8);
            fys.u8(k.fy as u8);
        }
    }
    let mut zs = BucketWriter::default();
    let [mut zs2, mut nus, mut nvs, mut nus2, mut nvs2] = std::array::from_fn(|_| Writer::default());
    walk(&cells, n, |i, stacked, pz, pn| {
        let k = keys[i];
        let (du, dv) = (k.oct[0].wrapping_sub(pn[0]), k.oct[1].wrapping_sub(pn[1]));
        if stacked {
            zs2.signed(k.z - pz);
            nus2.u8(du);
            nvs2.u8(dv);
        } else {
            zs.signed(k.z - pz);
            nus.u8(du);
            nvs.u8(dv);
        }
        Ok((k.z, k.oct))
    })?;
    let (zs, zbits) = zs.finish();
    pack(
        MODE_GRID,
        &[&params, &rows, &cells_w, &counts, &fxs, &fys, &zs, &zbits, &zs2, &nus, &nvs, &nus2, &nvs2],
    )
}

fn gcd(mut a: i64, mut b: i64) -> i64 {
    while b != 0 {
        (a, b) = (b, a % b);
    }
    a.abs()
}

/// The smallest cell shift that leaves at most about 2·√n occupied rows: lattice data (one point
/// per column) gets 0, continuous positions get cells about one point-spacing wide.
fn choose_shift(lattice: &[[i64; 3]]) -> u32 {
    let mut ys: Vec<i64> = lattice.iter().map(|p| p[1]).collect();
    ys.sort_unstable();
    let n = ys.len();
    for shift in 0..MAX_SHIFT {
        let mut rows = 0usize;
        let mut last = None;
        for &y in &ys {
            if last != Some(y >> shift) {
                rows += 1;
                last = Some(y >> shift);
            }
        }
        if rows * rows <= 4 * n {
            return shift;
        }
    }
    MAX_SHIFT
}

fn group_cells(keys: &[Key]) -> Vec<Cell> {
    let mut cells: Vec<Cell> = Vec::new();
    for (i, k) in keys.iter().enumerate() {
        match cells.last_mut() {
            Some(c) if c.cx == k.cx && c.cy == k.cy => c.count += 1,
            _ => cells.push(Cell { cx: k.cx, cy: k.cy, start: i, count: 1 }),
        }
    }
    cells
}

/// Visits points in coded order with their z and normal predictions; `point(i, stacked, z, n)`
/// returns the actual values (the encoder knows them, the decoder adds residuals); `stacked` is
/// false for the first point of a cell. The predictions are part of the format.
fn walk(
    cells: &[Cell],
    n: usize,
    mut point: impl FnMut(usize, bool, i64, [u8; 2]) -> Result<(i64, [u8; 2]), CodecError>,
) -> Result<(), CodecError> {
    let mut zs: Vec<i64> = Vec::with_capacity(n);
    let mut ns: Vec<[u8; 2]> = Vec::with_capacity(n);
    // Typical rise between stacked points of one cell, learnt as we go.
    let mut stack_step = 1i64;
    let mut prev_row = 0..0;
    let mut row_start = 0;
    for (ci, c) in cells.iter().enumerate() {
        if ci == 0 || cells[ci - 1].cy != c.cy {
            // Only an adjacent row is a useful "above".
            prev_row = if ci > 0 && cells[ci - 1].cy + 1 == c.cy { row_start..ci } else { ci..ci };
            row_start = ci;
        }
        let above = |cx: i64| {
            let row = &cells[prev_row.clone()];
            row.binary_search_by_key(&cx, |d| d.cx).ok().map(|j| row[j].start)
        };
        let left = (ci > row_start && cells[ci - 1].cx + 1 == c.cx).then(|| cells[ci - 1].start);
        let (up, up_left) = (above(c.cx), above(c.cx - 1));
        let pz = match (left, up, up_left) {
            (Some(a), Some(b), Some(d)) => med(zs[a], zs[b], zs[d]),
            (Some(a), Some(b), None) => (zs[a] + zs[b]).div_euclid(2),
            (Some(a), None, _) | (None, Some(a), _) => zs[a],
            (None, None, _) => zs.last().copied().unwrap_or(0),
        };
        // Normals are noisy at 8 bits: the plain average of the two neighbours measured about
        // 0.25 bit per point better than the median edge detector.
        let pn = match (left, up) {
            (Some(a), Some(b)) => [0, 1].map(|k| u8::midpoint(ns[a][k], ns[b][k])),
            (Some(a), None) | (None, Some(a)) => ns[a],
            (None, None) => ns.last().copied().unwrap_or([127, 127]),
        };
        let (z, nv) = point(c.start, false, pz, pn)?;
        zs.push(z);
        ns.push(nv);
        for i in c.start + 1..c.start + c.count {
            let prev = zs[i - 1];
            let (z, nv) = point(i, true, prev.saturating_add(stack_step), ns[i - 1])?;
            stack_step = z.saturating_sub(prev);
            zs.push(z);
            ns.push(nv);
        }
    }
    Ok(())
}

/// LOCO-I median edge detector: the median of a, b and a + b − c (both modes' z predictor).
fn med(a: i64, b: i64, c: i64) -> i64 {
    if c >= a.max(b) {
        a.min(b)
    } else if c <= a.min(b) {
        a.max(b)
    } else {
        a + b - c
    }
}

pub(super) fn decode(
    frame: &QuantGrid,
    n: usize,
    payload: &[u8],
    raw_len: usize,
) -> Result<PointCloud, CodecError> {
    if payload.first() == Some(&context::MODE_CONTEXT) {
        return context::decode(frame, n, payload, raw_len);
    }
    let u = unpack(payload, raw_len, &STREAMS)?;
    let mut s = u.readers();
    if u.mode != MODE_GRID {
        return Err(CodecError::Corrupt("unknown points mode"));
    }
    let [params, rows, cells_r, counts, fxs, fys, zs, zbits, zs2, nus, nvs, nus2, nvs2] = &mut s[..] else {
        return Err(CodecError::Corrupt("stream table"));
    };
    let mut zs = BucketReader::new(zs.clone(), zbits);
    // Every point costs at least a byte of z and exactly one of each normal coordinate: checked
    // before allocating anything sized by the header.
    if zs.len() + zs2.len() < n || nus.len() + nus2.len() != n || nvs.len() + nvs2.len() != n {
        return Err(CodecError::Corrupt("point count does not match the streams"));
    }
    let bad = CodecError::Corrupt;
    let lp = LatticeParams::read(params, frame)?;
    let shift = lp.shift;
    params.finish()?;

    let mut cells = Vec::new();
    let (mut cy, mut first_cx, mut total) = (0i64, 0i64, 0usize);
    while total < n {
        let dy = rows.varint()?;
        let dy = i64::try_from(dy).map_err(|_| bad("points rows"))?;
        cy = cy
            .checked_add(dy)
            .and_then(|y| y.checked_add(i64::from(!cells.is_empty())))
            .ok_or(bad("points rows"))?;
        let len = rows.count(n - total)? + 1;
        first_cx = first_cx.checked_add(cells_r.signed()?).ok_or(bad("points cells"))?;
        let mut cx = first_cx;
        for j in 0..len {
            if j > 0 {
                let d = i64::try_from(cells_r.varint()?).map_err(|_| bad("points cells"))?;
                cx = cx.checked_add(d).and_then(|v| v.checked_add(1)).ok_or(bad("points cells"))?;
            }
            let count = counts.count(n)? + 1;
            if count > n - total {
                return Err(bad("points counts"));
            }
            // Lattice coordinates never exceed MAX_QUANT; checking here keeps the neighbour
            // arithmetic in `walk` far from overflow.
            let limit = MAX_QUANT >> shift;
            if !(0..=limit).contains(&cx) || !(0..=limit).contains(&cy) {
                return Err(bad("points cells"));
            }
            cells.push(Cell { cx, cy, start: total, count });
            total += count;
        }
    }
    rows.finish()?;
    cells_r.finish()?;
    counts.finish()?;

    let mut fine = Vec::with_capacity(n);
    for _ in 0..n {
        if shift == 0 {
            fine.push([0, 0]);
        } else {
            let (fx, fy) = (i64::from(fxs.u8()?), i64::from(fys.u8()?));
            if fx >> shift != 0 || fy >> shift != 0 {
                return Err(bad("points fine"));
            }
            fine.push([fx, fy]);
        }
    }
    fxs.finish()?;
    fys.finish()?;

    let mut positions = vec![[0.0; 3]; n];
    let mut normals = vec![[0.0f32; 3]; n];
    let mut cell_of = vec![0usize; n];
    for (ci, c) in cells.iter().enumerate() {
        cell_of[c.start..c.start + c.count].fill(ci);
    }
    walk(&cells, n, |i, stacked, pz, pn| {
        let (dz, du, dv) = if stacked {
            (zs2.signed()?, nus2.u8()?, nvs2.u8()?)
        } else {
            (zs.signed()?, nus.u8()?, nvs.u8()?)
        };
        let z = pz.checked_add(dz).ok_or(bad("points z"))?;
        let oct = [pn[0].wrapping_add(du), pn[1].wrapping_add(dv)];
        let c = cells[cell_of[i]];
        let lattice = [lattice_xy(c.cx, fine[i][0], shift)?, lattice_xy(c.cy, fine[i][1], shift)?, z];
        positions[i] = lp.position(frame, lattice)?;
        normals[i] = oct_decode(oct);
        Ok((z, oct))
    })?;
    zs.finish()?;
    zs2.finish()?;
    Ok(PointCloud { positions, normals })
}

fn lattice_xy(cell: i64, fine: i64, shift: u32) -> Result<i64, CodecError> {
    cell.checked_mul(1 << shift)
        .map(|v| v | fine)
        .filter(|&v| (0..=MAX_QUANT).contains(&v))
        .ok_or(CodecError::Corrupt("points cells"))
}

mod context;
#[cfg(test)]
mod tests;
