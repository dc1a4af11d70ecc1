//! Per triangle and view axis, the cells whose centres it covers (the module doc's
//! *Rasterization*): edge functions with the top-left rule, rows of pixel centres.

use super::POS_ONE;

/// One edge of a counter-clockwise triangle, prepared for the canonical edge function.
#[derive(Clone, Copy)]
pub(super) struct Edge {
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
pub(super) fn floor_i64(x: f64) -> i64 {
    let t = x as i64;
    if t as f64 > x { t - 1 } else { t }
}

/// `⌈x⌉`, as [`floor_i64`].
#[inline]
pub(super) fn ceil_i64(x: f64) -> i64 {
    let t = x as i64;
    if (t as f64) < x { t + 1 } else { t }
}

/// The pixel columns of row centre `y` that can be inside triangle `p`, within `[i0, i1]`: the
/// row's crossing of the triangle widened by a pixel. Only a speed-up (slivers would otherwise
/// walk their whole bounding box); the edge tests decide coverage.
pub(super) fn row_span(p: &[[f64; 2]; 3], y: f64, i0: i64, i1: i64) -> (i64, i64) {
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
pub(super) fn centre_ranges(g: &[[f64; 3]; 3]) -> [(i64, i64); 3] {
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
pub(super) fn rasterize(
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
