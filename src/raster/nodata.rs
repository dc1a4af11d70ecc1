//! No-data filling: replaces every non-finite sample (NaN, ±inf; decoders turn their own no-data
//! markers into NaN) with values grown inwards from the valid samples around it.
//!
//! The fill is a multi-source wavefront: each pass fills every no-data cell that has at least one
//! valid 8-neighbour with the mean of those neighbours *as they were before the pass*, then the
//! filled cells count as valid for the next pass. Reading only the previous pass makes the result
//! independent of the order cells are visited in, so it is deterministic, and each cell is
//! visited a bounded number of times, so it is linear in the raster size.

/// 8-neighbour offsets (dcol, drow) in a fixed order, so the float sums are reproducible.
const NEIGHBOURS: [(isize, isize); 8] =
    [(-1, -1), (0, -1), (1, -1), (-1, 0), (1, 0), (-1, 1), (0, 1), (1, 1)];

/// The in-grid 8-neighbours of cell `i` of a `width × height` grid.
fn neighbours(i: usize, width: usize, height: usize) -> impl Iterator<Item = usize> {
    let (col, row) = ((i % width) as isize, (i / width) as isize);
    NEIGHBOURS.iter().filter_map(move |&(dc, dr)| {
        let (c, r) = (col + dc, row + dr);
        (c >= 0 && r >= 0 && (c as usize) < width && (r as usize) < height)
            .then(|| r as usize * width + c as usize)
    })
}

/// Cell states: valid since the last pass, no-data not yet reached, no-data in the current or
/// next wavefront. One byte per cell keeps the bookkeeping at a quarter of the data's size.
const VALID: u8 = 0;
const MISSING: u8 = 1;
const QUEUED: u8 = 2;

/// Fills every non-finite sample of the row-major `width × height` grid `data` in place and
/// returns how many were filled; `None` when no sample is valid (nothing to fill from).
pub(super) fn fill_nodata(width: usize, height: usize, data: &mut [f32]) -> Option<u64> {
    debug_assert_eq!(data.len(), width * height);
    // The common case (no holes) costs one scan and no allocation.
    if data.iter().all(|v| v.is_finite()) {
        return Some(0);
    }
    if data.iter().all(|v| !v.is_finite()) {
        return None;
    }
    // Unbounded: the wavefront stops when it has reached every cell.
    Some(fill_within(width, height, data, usize::MAX))
}

/// How far (in cells, Chebyshev distance) the wavefront fill reaches from the nearest valid
/// sample. Within it the fill is exactly the unbounded wavefront's; a cell's value depends only on
/// the cells within this distance, so a block read with a halo this wide fills on its own.
pub const FILL_REACH: usize = 64;

/// Side of the blocks whose means make the fallback grid (in cells, from sample (0, 0)).
pub const FALLBACK_BLOCK: usize = 256;

/// The wavefront of [`fill_nodata`], stopped after `reach` passes: cells farther than `reach`
/// from every valid cell stay non-finite. Returns how many cells it filled.
pub(super) fn fill_within(width: usize, height: usize, data: &mut [f32], reach: usize) -> u64 {
    debug_assert_eq!(data.len(), width * height);
    if data.iter().all(|v| v.is_finite()) || data.iter().all(|v| !v.is_finite()) {
        return 0;
    }
    let mut state: Vec<u8> = data.iter().map(|v| if v.is_finite() { VALID } else { MISSING }).collect();
    let mut front: Vec<usize> = (0..data.len())
        .filter(|&i| state[i] == MISSING && neighbours(i, width, height).any(|j| state[j] == VALID))
        .collect();
    for &i in &front {
        state[i] = QUEUED;
    }
    let (mut fresh, mut next, mut filled) = (Vec::new(), Vec::new(), 0u64);
    for _ in 0..reach {
        if front.is_empty() {
            break;
        }
        fresh.clear();
        fresh.extend(front.iter().map(|&i| {
            let (sum, n) = neighbours(i, width, height)
                .filter(|&j| state[j] == VALID)
                .fold((0.0_f64, 0_u32), |(s, n), j| (s + f64::from(data[j]), n + 1));
            (sum / f64::from(n.max(1))) as f32
        }));
        for (&i, &v) in front.iter().zip(&fresh) {
            data[i] = v;
            state[i] = VALID;
        }
        filled += front.len() as u64;
        next.clear();
        for &i in &front {
            for j in neighbours(i, width, height) {
                if state[j] == MISSING {
                    state[j] = QUEUED;
                    next.push(j);
                }
            }
        }
        std::mem::swap(&mut front, &mut next);
    }
    filled
}

/// Mean of the finite values of one fallback block (row-major sum in f64), NaN when it has none.
pub(super) fn block_mean(values: impl Iterator<Item = f32>) -> f32 {
    let (sum, n) =
        values.filter(|v| v.is_finite()).fold((0.0f64, 0u64), |(s, n), v| (s + f64::from(v), n + 1));
    if n == 0 { f32::NAN } else { (sum / n as f64) as f32 }
}

/// The fallback grid: one mean per [`FALLBACK_BLOCK`]² block (`cols × rows` blocks), blocks
/// without a valid sample filled by the unbounded wavefront. `None` when no block has one.
pub(super) fn fallback_grid(cols: usize, rows: usize, mut means: Vec<f32>) -> Option<Vec<f32>> {
    fill_nodata(cols, rows, &mut means)?;
    Some(means)
}

/// The fallback height at sample (col, row): the fallback grid interpolated bilinearly between
/// block centres (clamped at the edges), for cells beyond [`FILL_REACH`].
pub(super) fn fallback_at(grid: &[f32], cols: usize, rows: usize, col: u64, row: u64) -> f32 {
    let b = FALLBACK_BLOCK as f64;
    let coord = |v: u64, n: usize| ((v as f64 + 0.5) / b - 0.5).clamp(0.0, (n.max(1) - 1) as f64);
    let (u, v) = (coord(col, cols), coord(row, rows));
    let (i0, j0) = (u.floor() as usize, v.floor() as usize);
    let (i1, j1) = ((i0 + 1).min(cols - 1), (j0 + 1).min(rows - 1));
    let (tu, tv) = (u - i0 as f64, v - j0 as f64);
    let g = |i: usize, j: usize| f64::from(grid[j * cols + i]);
    let top = g(i0, j0) * (1.0 - tu) + g(i1, j0) * tu;
    let bottom = g(i0, j1) * (1.0 - tu) + g(i1, j1) * tu;
    (top * (1.0 - tv) + bottom * tv) as f32
}

/// The bake's fill of a whole in-memory raster: the wavefront within [`FILL_REACH`], the
/// fallback grid beyond it; the same values a block-by-block fill of a dataset gives. Returns
/// (filled, of which beyond the reach), `None` when no sample is valid.
pub(super) fn fill_local(width: usize, height: usize, data: &mut [f32]) -> Option<(u64, u64)> {
    if data.iter().all(|v| v.is_finite()) {
        return Some((0, 0));
    }
    let missing = data.iter().filter(|v| !v.is_finite()).count() as u64;
    let (bc, br) = (width.div_ceil(FALLBACK_BLOCK), height.div_ceil(FALLBACK_BLOCK));
    let mut means = Vec::with_capacity(bc * br);
    for by in 0..br {
        for bx in 0..bc {
            let (c0, c1) = (bx * FALLBACK_BLOCK, ((bx + 1) * FALLBACK_BLOCK).min(width));
            let (r0, r1) = (by * FALLBACK_BLOCK, ((by + 1) * FALLBACK_BLOCK).min(height));
            means.push(block_mean(
                (r0..r1).flat_map(|r| data[r * width + c0..r * width + c1].iter().copied()),
            ));
        }
    }
    let grid = fallback_grid(bc, br, means)?;
    let within = fill_within(width, height, data, FILL_REACH);
    for (i, v) in data.iter_mut().enumerate() {
        if !v.is_finite() {
            *v = fallback_at(&grid, bc, br, (i % width) as u64, (i / width) as u64);
        }
    }
    Some((missing, missing - within))
}

#[cfg(test)]
// A failed unwrap is the test failing; exact float comparisons are of exactly representable values.
#[allow(clippy::unwrap_used, clippy::float_cmp)]
mod tests {
    use super::fill_nodata;

    #[test]
    fn nothing_to_fill() {
        let mut d = vec![1.0, 2.0, 3.0, 4.0];
        assert_eq!(fill_nodata(2, 2, &mut d), Some(0));
        assert_eq!(d, [1.0, 2.0, 3.0, 4.0]);
    }

    #[test]
    fn all_missing_is_none() {
        let mut d = vec![f32::NAN, f32::INFINITY, f32::NEG_INFINITY];
        assert_eq!(fill_nodata(3, 1, &mut d), None);
    }

    #[test]
    fn single_hole_gets_mean_of_neighbours() {
        let n = f32::NAN;
        let mut d = vec![1.0, 2.0, 3.0, 4.0, n, 6.0, 7.0, 8.0, 9.0];
        assert_eq!(fill_nodata(3, 3, &mut d), Some(1));
        assert!((d[4] - 5.0).abs() < 1e-6);
    }

    #[test]
    fn wavefront_reads_previous_pass_only() {
        // Row: 10, NaN, NaN, NaN, 20. Pass 1 fills cols 1 and 3 from 10 and 20; pass 2 fills
        // col 2 from both (15), not from whichever was filled first.
        let n = f32::NAN;
        let mut d = vec![10.0, n, n, n, 20.0];
        assert_eq!(fill_nodata(5, 1, &mut d), Some(3));
        assert_eq!(d, [10.0, 10.0, 15.0, 20.0, 20.0]);
    }

    #[test]
    fn fills_large_gap_from_one_corner() {
        let (w, h) = (7, 5);
        let mut d = vec![f32::NAN; w * h];
        d[0] = 3.5;
        assert_eq!(fill_nodata(w, h, &mut d), Some((w * h - 1) as u64));
        assert!(d.iter().all(|&v| (v - 3.5).abs() < 1e-6));
    }
}
