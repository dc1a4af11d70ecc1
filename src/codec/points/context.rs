//! Points, mode 1 ("context"): the sorted lattice range-coded with adaptive context models
//! (see the layout in the codec module's docs).
//!
//! A terrain point level comes from voxel cells of edge `2^shift` lattice steps: one point per
//! occupied cell, the mean of the fragments the six views put there. A cell's Z-view fragment
//! sits at the column centre, an X-view fragment at the centre of its (y, z) pixel, so a point
//! is either centred in x (and y) or pulled off centre by an X (Y) fragment exactly as far as
//! its z is pulled toward the slice centre. The coder uses that: z first (median edge
//! detector, contexts from the neighbours' activity), then per axis a flag "centred" and, when
//! not, the offset predicted from z and the local slope. Normals come after all positions and
//! are predicted from the surface gradient of the four neighbour cells, so only the facet
//! noise around the smooth surface is left to code.

use super::super::rangecoder::{Bit, Coder, Decoder, Encoder, IntModel, TreeModel};
use super::super::stream::{Packed, Reader, Writer, pack_stored, unpack};
use super::super::{CodecError, MAX_QUANT, QuantGrid};
use super::{Cell, Key, LatticeParams, MAX_SHIFT, Prepared, group_cells, med, oct_decode};
use crate::geom::PointCloud;

/// The payload's mode byte.
pub(in crate::codec) const MODE_CONTEXT: u8 = 1;
pub(super) const STREAMS: [&str; 1] = ["points coded"];
/// A context payload's coded bytes are at least one per this many points (the encoder pads
/// with zeros), so a decoder checks the header's point count against the bytes before it
/// allocates anything sized by it.
pub(in crate::codec) const POINTS_PER_BYTE: usize = 16;
/// Fixed-point fraction bits of the gradient scales (world z step over world x, y step).
const SCALE_BITS: u32 = 12;
/// Largest gradient scale accepted.
const MAX_SCALE: i64 = 1 << 24;

/// One point in phased lattice units: `x`, `y` hold the cell and fine offset, `x >> shift` is
/// the cell column.
#[derive(Debug, Clone, Copy, Default)]
struct Pt {
    x: i64,
    y: i64,
    z: i64,
    oct: [u8; 2],
}

/// Per-blob parameters, stored as varints before the coded bytes.
#[derive(Debug, Clone, Copy)]
struct Params {
    shift: u32,
    /// Added to the lattice x, y, z so that the most common offset in a cell is its centre.
    phase: [i64; 3],
    /// `stride_z · z_step / (stride_a · xy_step)` for a = x, y, in units of 2^-12.
    scale: [i64; 2],
}

/// Neighbour cells of a cell (indices into the cell list).
#[derive(Debug, Clone, Copy, Default)]
struct Nb {
    left: Option<usize>,
    right: Option<usize>,
    up: Option<usize>,
    up_left: Option<usize>,
    up_right: Option<usize>,
    down: Option<usize>,
}

/// Every adaptive model of a payload; fresh for each blob.
struct Models {
    rows: IntModel,
    counts: IntModel,
    z: IntModel,
    stacked_z: IntModel,
    centred: [[Bit; 8]; 2],
    fine: IntModel,
    stacked_fine: [TreeModel; 2],
    nu: IntModel,
    nv: IntModel,
    stacked_n: IntModel,
}

impl Models {
    fn new(shift: u32) -> Self {
        Self {
            rows: IntModel::new(4),
            counts: IntModel::new(2),
            z: IntModel::new(16),
            stacked_z: IntModel::new(4),
            centred: [[Bit::default(); 8]; 2],
            fine: IntModel::new(16),
            stacked_fine: [TreeModel::new(1, shift), TreeModel::new(1, shift)],
            nu: IntModel::new(8),
            nv: IntModel::new(32),
            stacked_n: IntModel::new(2),
        }
    }
}

/// Row-model contexts.
const ROW_GAP: usize = 0;
const ROW_FIRST: usize = 1;
const ROW_LEN: usize = 2;
const CELL_GAP: usize = 3;

/// Bit length of `|v|`, capped: the context of a magnitude.
fn class(v: i64, max: usize) -> usize {
    (64 - v.unsigned_abs().leading_zeros() as usize).min(max)
}

/// The largest cell shift that keeps at least half as many occupied cells as points: voxel
/// points get cells of their voxels (one point each, the fine offsets small), lattice points
/// (one per column) get 0.
fn cell_shift(lattice: &[[i64; 3]]) -> u32 {
    let n = lattice.len();
    let mut cols: Vec<(i64, i64)> = Vec::with_capacity(n);
    for shift in 1..=MAX_SHIFT {
        cols.clear();
        cols.extend(lattice.iter().map(|l| (l[1] >> shift, l[0] >> shift)));
        cols.sort_unstable();
        cols.dedup();
        if 2 * cols.len() < n {
            return shift - 1;
        }
    }
    MAX_SHIFT
}

/// The residue of `values` modulo `2^shift` seen most often (the smallest on ties), moved to
/// the centre `2^(shift−1)`: the phase to add.
fn phase(values: impl Iterator<Item = i64>, shift: u32) -> i64 {
    if shift == 0 {
        return 0;
    }
    let m = 1i64 << shift;
    let mut hist = vec![0usize; 1 << shift];
    for v in values {
        hist[v.rem_euclid(m) as usize] += 1;
    }
    let mut best = 0;
    for (r, &c) in hist.iter().enumerate() {
        if c > hist[best] {
            best = r;
        }
    }
    (m / 2 - best as i64).rem_euclid(m)
}

pub(in crate::codec) fn encode(frame: &QuantGrid, prepared: &Prepared) -> Result<Packed, CodecError> {
    let Prepared { lattice, oct, grid } = prepared;
    let shift = cell_shift(lattice);
    let lp = LatticeParams { shift, ..*grid };
    let stride = lp.stride;
    let n = lattice.len();
    let phase = [0, 1, 2].map(|a| phase(lattice.iter().map(|l| l[a]), shift));
    let scale = [0, 1].map(|a| {
        let s = (stride[2] as f64 * frame.step[2]) / (stride[a] as f64 * frame.step[a]);
        let fx = (s * f64::from(1u32 << SCALE_BITS)).round();
        if fx.is_finite() { (fx as i64).clamp(0, MAX_SCALE) } else { MAX_SCALE }
    });
    let p = Params { shift, phase, scale };
    let mask = (1i64 << shift) - 1;
    let mut keys: Vec<Key> = lattice
        .iter()
        .zip(oct)
        .map(|(l, &oct)| {
            let (x, y) = (l[0] + phase[0], l[1] + phase[1]);
            Key { cy: y >> shift, cx: x >> shift, z: l[2], fy: y & mask, fx: x & mask, oct }
        })
        .collect();
    keys.sort_unstable();
    let cells = group_cells(&keys);
    let mut pts: Vec<Pt> = keys
        .iter()
        .map(|k| Pt { x: (k.cx << shift) | k.fx, y: (k.cy << shift) | k.fy, z: k.z, oct: k.oct })
        .collect();

    let mut params = Writer::default();
    lp.write(&mut params);
    for v in phase.iter().chain(&scale) {
        params.varint(*v as u64);
    }
    let mut e = Encoder::default();
    let mut m = Models::new(shift);
    encode_cells(&mut e, &mut m, &cells)?;
    code_points(&mut e, &mut m, &Layout { p, cells: &cells, nb: neighbours(&cells) }, &mut pts)?;
    params.bytes.extend_from_slice(&e.finish(n.div_ceil(POINTS_PER_BYTE)));
    pack_stored(MODE_CONTEXT, &[&params])
}

/// Occupancy, row by row: the gap to the previous row, the first cell's column against the
/// previous row's, the cell count against the previous row's, the gaps between cells, then
/// each cell's point count. A full rectangle costs next to nothing.
fn encode_cells(e: &mut Encoder, m: &mut Models, cells: &[Cell]) -> Result<(), CodecError> {
    let (mut prev_cy, mut prev_first, mut prev_len) = (-1i64, 0i64, 0i64);
    let mut i = 0;
    while i < cells.len() {
        let cy = cells[i].cy;
        let len = cells[i..].iter().take_while(|c| c.cy == cy).count();
        m.rows.code(e, ROW_GAP, cy - prev_cy - 1)?;
        m.rows.code(e, ROW_FIRST, cells[i].cx - prev_first)?;
        m.rows.code(e, ROW_LEN, len as i64 - prev_len)?;
        for w in cells[i..i + len].windows(2) {
            m.rows.code(e, CELL_GAP, w[1].cx - w[0].cx - 1)?;
        }
        let mut stacked = false;
        for c in &cells[i..i + len] {
            m.counts.code(e, usize::from(stacked), c.count as i64 - 1)?;
            stacked = c.count > 1;
        }
        (prev_cy, prev_first, prev_len) = (cy, cells[i].cx, len as i64);
        i += len;
    }
    Ok(())
}

/// Reads what [`encode_cells`] wrote, for `n` points; cell columns and rows stay in
/// `0..=limit`.
fn decode_cells(d: &mut Decoder, m: &mut Models, n: usize, limit: i64) -> Result<Vec<Cell>, CodecError> {
    let bad = || CodecError::Corrupt("points cells");
    let mut cells: Vec<Cell> = Vec::new();
    let (mut prev_cy, mut prev_first, mut prev_len) = (-1i64, 0i64, 0i64);
    let mut total = 0usize;
    // Every row holds at least one point: at most n rows.
    while total < n {
        let gap = nonneg(m.rows.code(d, ROW_GAP, 0)?)?;
        let cy = prev_cy.checked_add(1).and_then(|v| v.checked_add(gap));
        let cy = cy.filter(|v| (0..=limit).contains(v)).ok_or_else(bad)?;
        let first = prev_first.checked_add(m.rows.code(d, ROW_FIRST, 0)?).filter(|v| (0..=limit).contains(v));
        let first = first.ok_or_else(bad)?;
        let len = prev_len.checked_add(m.rows.code(d, ROW_LEN, 0)?).ok_or_else(bad)?;
        let len = usize::try_from(len).ok().filter(|&l| l >= 1 && l <= n - total).ok_or_else(bad)?;
        let row_start = cells.len();
        let mut cx = first;
        for j in 0..len {
            if j > 0 {
                let gap = nonneg(m.rows.code(d, CELL_GAP, 0)?)?;
                cx = cx
                    .checked_add(1)
                    .and_then(|v| v.checked_add(gap))
                    .filter(|v| *v <= limit)
                    .ok_or_else(bad)?;
            }
            cells.push(Cell { cx, cy, start: 0, count: 0 });
        }
        let mut stacked = false;
        for j in 0..len {
            let extra = nonneg(m.counts.code(d, usize::from(stacked), 0)?)?;
            // Every later cell of the row needs a point of its own.
            let room = n - total - (len - 1 - j);
            let count = usize::try_from(extra).ok().and_then(|e| e.checked_add(1)).filter(|&c| c <= room);
            let count = count.ok_or(CodecError::Corrupt("points counts"))?;
            let c = &mut cells[row_start + j];
            c.start = total;
            c.count = count;
            total += count;
            stacked = count > 1;
        }
        (prev_cy, prev_first, prev_len) = (cy, first, len as i64);
    }
    Ok(cells)
}

fn nonneg(v: i64) -> Result<i64, CodecError> {
    if v >= 0 { Ok(v) } else { Err(CodecError::Corrupt("points cells")) }
}

/// The neighbour cells of every cell (cells sorted by row, then column).
fn neighbours(cells: &[Cell]) -> Vec<Nb> {
    let mut rows: Vec<(i64, usize, usize)> = Vec::new();
    for (i, c) in cells.iter().enumerate() {
        match rows.last_mut() {
            Some(r) if r.0 == c.cy => r.2 = i + 1,
            _ => rows.push((c.cy, i, i + 1)),
        }
    }
    let mut out = Vec::with_capacity(cells.len());
    for (r, &(cy, a, b)) in rows.iter().enumerate() {
        // Cursors walk the adjacent rows alongside this one (all sorted by column).
        let adjacent = |row: Option<&(i64, usize, usize)>, y: i64| {
            row.filter(|row| row.0 == y).map_or((0, 0), |row| (row.1, row.2))
        };
        let (mut ja, ea) = adjacent(r.checked_sub(1).and_then(|r| rows.get(r)), cy - 1);
        let (mut jb, eb) = adjacent(rows.get(r + 1), cy + 1);
        let at = |j: usize, end: usize, x: i64| (j < end && cells[j].cx == x).then_some(j);
        for i in a..b {
            let cx = cells[i].cx;
            while ja < ea && cells[ja].cx < cx - 1 {
                ja += 1;
            }
            while jb < eb && cells[jb].cx < cx {
                jb += 1;
            }
            let up_left = at(ja, ea, cx - 1);
            let k = ja + usize::from(up_left.is_some());
            let up = at(k, ea, cx);
            out.push(Nb {
                left: (i > a && cells[i - 1].cx + 1 == cx).then(|| i - 1),
                right: (i + 1 < b && cells[i + 1].cx == cx + 1).then_some(i + 1),
                up,
                up_left,
                up_right: at(k + usize::from(up.is_some()), ea, cx + 1),
                down: at(jb, eb, cx),
            });
        }
    }
    out
}

/// What the position and normal coders read: the blob's parameters, its cells in order and
/// each cell's neighbours.
struct Layout<'a> {
    p: Params,
    cells: &'a [Cell],
    nb: Vec<Nb>,
}

/// Every point after the occupancy: all positions, then all normals (predicted from the
/// positions). The encoder and the decoder run the same code with their own [`Coder`].
fn code_points<C: Coder>(c: &mut C, m: &mut Models, g: &Layout, pts: &mut [Pt]) -> Result<(), CodecError> {
    code_positions(c, m, g, pts)?;
    code_normals(c, m, g, pts)
}

/// Positions, cell by cell: the first point's z, then its fine x and y; then the cell's other
/// points (fine offsets as symbols, z as the rise over the point below).
fn code_positions<C: Coder>(c: &mut C, m: &mut Models, g: &Layout, pts: &mut [Pt]) -> Result<(), CodecError> {
    let Layout { p, cells, nb } = g;
    let s = p.shift;
    let bad_z = || CodecError::Corrupt("points z");
    let mut stack_step = 0i64;
    for (ci, cell) in cells.iter().enumerate() {
        let first = |j: Option<usize>, pts: &[Pt]| j.map(|j| pts[cells[j].start]);
        let n = nb[ci];
        let (l, u, ul, ur) =
            (first(n.left, pts), first(n.up, pts), first(n.up_left, pts), first(n.up_right, pts));
        let (pz, ctx) = match (l, u, ul) {
            (Some(a), Some(b), Some(d)) => {
                let act = (a.z - d.z).abs() + (b.z - d.z).abs() + ur.map_or(0, |r| (r.z - b.z).abs());
                (med(a.z, b.z, d.z), class(act, 14))
            }
            (Some(a), Some(b), None) => ((a.z + b.z).div_euclid(2), 15),
            (Some(a), None, _) | (None, Some(a), _) => (a.z, 15),
            (None, None, _) => (ci.checked_sub(1).map_or(0, |j| pts[cells[j].start].z), 15),
        };
        let i = cell.start;
        let z = pz
            .checked_add(m.z.code(c, ctx, pts[i].z.wrapping_sub(pz))?)
            .filter(|z| (0..=MAX_QUANT).contains(z))
            .ok_or_else(bad_z)?;
        pts[i].z = z;
        let (cx, cy) = (cell.cx << s, cell.cy << s);
        if s == 0 {
            (pts[i].x, pts[i].y) = (cx, cy);
        } else {
            let centre = 1i64 << (s - 1);
            let zc = (((z + p.phase[2]) >> s) << s) + centre - p.phase[2];
            let here = Pt { x: cx + centre, y: cy + centre, z, oct: [0; 2] };
            // The slope along each axis from the neighbours known so far.
            let slope = |a: Option<Pt>, b: Option<Pt>, axis: usize| {
                let (a, b) = (a?, b?);
                let (pa, pb) = if axis == 0 { (a.x, b.x) } else { (a.y, b.y) };
                (pb > pa).then(|| (b.z - a.z, pb - pa))
            };
            let slopes =
                [slope(l, Some(here), 0).or(slope(ul, ur, 0)), slope(u, Some(here), 1).or(slope(ul, l, 1))];
            for (axis, sl) in slopes.into_iter().enumerate() {
                // An X (Y) fragment moves the mean off centre by −(z − zc) / slope.
                let pred = sl.and_then(|(dz, d)| {
                    if dz == 0 {
                        return None;
                    }
                    let off = i128::from(zc - z) * i128::from(d) / i128::from(dz);
                    (off.abs() < i128::from(centre)).then(|| centre + off as i64)
                });
                let ctx = pred.map_or(0, |v| 1 + class(v - centre, 6));
                let cc = if axis == 0 { cx } else { cy };
                let actual = if axis == 0 { pts[i].x } else { pts[i].y };
                let f = actual - cc;
                let fine = if c.bit(&mut m.centred[axis][ctx], f != centre) {
                    let pv = pred.unwrap_or(centre);
                    pv.checked_add(m.fine.code(c, ctx + 8 * axis, f.wrapping_sub(pv))?)
                        .filter(|f| (0..1 << s).contains(f))
                        .ok_or(CodecError::Corrupt("points fine"))?
                } else {
                    centre
                };
                if axis == 0 {
                    pts[i].x = cc | fine;
                } else {
                    pts[i].y = cc | fine;
                }
            }
        }
        for i in cell.start + 1..cell.start + cell.count {
            if s > 0 {
                let mask = (1i64 << s) - 1;
                let fx = m.stacked_fine[0].code(c, 0, (pts[i].x & mask) as u32);
                let fy = m.stacked_fine[1].code(c, 0, (pts[i].y & mask) as u32);
                pts[i].x = cx | i64::from(fx);
                pts[i].y = cy | i64::from(fy);
            } else {
                (pts[i].x, pts[i].y) = (cx, cy);
            }
            let below = pts[i - 1].z;
            let rise = m.stacked_z.code(c, class(stack_step, 3), pts[i].z.wrapping_sub(below))?;
            let z = below.checked_add(rise).filter(|z| (0..=MAX_QUANT).contains(z)).ok_or_else(bad_z)?;
            pts[i].z = z;
            stack_step = rise;
        }
    }
    Ok(())
}

/// The octahedral pair of the direction `(nx, ny, nz)` (integer arithmetic; `(127, 127)`, up,
/// for the zero vector), as [`super::oct_encode`] maps directions up to rounding.
fn oct_of(nx: i128, ny: i128, nz: i128) -> [u8; 2] {
    let l1 = nx.abs() + ny.abs() + nz.abs();
    if l1 == 0 {
        return [127, 127];
    }
    let (a, b) =
        if nz >= 0 { (nx, ny) } else { (nx.signum() * (l1 - ny.abs()), ny.signum() * (l1 - nx.abs())) };
    let byte = |t: i128| ((127 * l1 + 127 * t) * 2 + l1).div_euclid(2 * l1).clamp(0, 254) as u8;
    [byte(a), byte(b)]
}

/// Normals: a cell's first point from the surface gradient over its left/right and up/down
/// neighbours (central differences where both exist, one-sided where one does, flat where
/// none), the others from the point below them.
fn code_normals<C: Coder>(c: &mut C, m: &mut Models, g: &Layout, pts: &mut [Pt]) -> Result<(), CodecError> {
    let Layout { p, cells, nb } = g;
    let bad = || CodecError::Corrupt("points normals");
    // The residual of each cell's first point, for its right and lower neighbours' contexts.
    let mut res: Vec<[i64; 2]> = Vec::with_capacity(cells.len());
    for (ci, cell) in cells.iter().enumerate() {
        let i = cell.start;
        let here = pts[i];
        let first = |j: Option<usize>| j.map(|j| pts[cells[j].start]);
        let n = nb[ci];
        let grad = |a: Option<Pt>, b: Option<Pt>, axis: usize| -> (i128, i128) {
            let pos = |q: Pt| if axis == 0 { q.x } else { q.y };
            let (a, b) = match (a, b) {
                (Some(a), Some(b)) => (a, b),
                (Some(a), None) => (a, here),
                (None, Some(b)) => (here, b),
                (None, None) => return (0, 1),
            };
            let d = pos(b) - pos(a);
            if d > 0 { (i128::from(b.z - a.z), i128::from(d)) } else { (0, 1) }
        };
        let (dzx, dx) = grad(first(n.left), first(n.right), 0);
        let (dzy, dy) = grad(first(n.up), first(n.down), 1);
        let (kx, ky) = (i128::from(p.scale[0]), i128::from(p.scale[1]));
        let pred = oct_of(-dzx * kx * dy, -dzy * ky * dx, dx * dy * (1 << SCALE_BITS));
        let near = |j: Option<usize>, k: usize| j.map_or(4, |j| res[j][k].abs());
        let act = [0, 1].map(|k| near(n.left, k) + near(n.up, k));
        let du = m.nu.code(c, class(act[0], 7), i64::from(here.oct[0]) - i64::from(pred[0]))?;
        let dv =
            m.nv.code(c, class(act[1], 7) + 8 * class(du, 3), i64::from(here.oct[1]) - i64::from(pred[1]))?;
        let byte = |p: u8, d: i64| u8::try_from(i64::from(p) + d).map_err(|_| bad());
        pts[i].oct = [byte(pred[0], du)?, byte(pred[1], dv)?];
        res.push([du, dv]);
        for i in cell.start + 1..cell.start + cell.count {
            let prev = pts[i - 1].oct;
            let mut oct = [0u8; 2];
            for k in 0..2 {
                let d = m.stacked_n.code(c, k, i64::from(pts[i].oct[k]) - i64::from(prev[k]))?;
                oct[k] = byte(prev[k], d)?;
            }
            pts[i].oct = oct;
        }
    }
    Ok(())
}

pub(in crate::codec) fn decode(
    frame: &QuantGrid,
    n: usize,
    payload: &[u8],
    raw_len: usize,
) -> Result<PointCloud, CodecError> {
    let u = unpack(payload, raw_len, &STREAMS)?;
    let readers = u.readers();
    let [r] = &readers[..] else { return Err(CodecError::Corrupt("stream table")) };
    let mut r: Reader = r.clone();
    let bad = CodecError::Corrupt;
    let lp = LatticeParams::read(&mut r, frame)?;
    let shift = lp.shift;
    let mut phase = [0i64; 3];
    for ph in &mut phase {
        *ph = r.count((1usize << shift) - 1)? as i64;
    }
    let mut scale = [0i64; 2];
    for s in &mut scale {
        *s = r.count(MAX_SCALE as usize)? as i64;
    }
    let p = Params { shift, phase, scale };
    let coded = r.rest();
    let min_len = n.div_ceil(POINTS_PER_BYTE);
    // Checked before anything sized by n is allocated.
    if coded.len() < min_len {
        return Err(bad("point count does not match the streams"));
    }
    let mut d = Decoder::new(coded, "points coded");
    let mut m = Models::new(shift);
    let limit = (MAX_QUANT + (1 << shift)) >> shift;
    let cells = decode_cells(&mut d, &mut m, n, limit)?;
    let mut pts = vec![Pt::default(); n];
    code_points(&mut d, &mut m, &Layout { p, cells: &cells, nb: neighbours(&cells) }, &mut pts)?;
    d.finish(min_len)?;

    let mut positions = Vec::with_capacity(n);
    let mut normals = Vec::with_capacity(n);
    for pt in &pts {
        let lattice = [pt.x - phase[0], pt.y - phase[1], pt.z];
        if lattice.iter().any(|&l| l < 0) {
            return Err(bad("points positions"));
        }
        positions.push(lp.position(frame, lattice)?);
        normals.push(oct_decode(pt.oct));
    }
    Ok(PointCloud { positions, normals })
}
