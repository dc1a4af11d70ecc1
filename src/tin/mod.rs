//! Greedy error-driven triangulation of one node's height samples (Garland–Heckbert insertion
//! on a Delaunay triangulation from `spade`), crack-free borders, and the measured vertical error
//! of a mesh against the full-resolution raster. Pure: values in, values out.
//!
//! Borders: the vertices on each node edge are chosen from that edge's samples alone, by a 1-D
//! greedy simplification of the edge profile with the same error bound. Both neighbours of an
//! edge see the same samples, so they choose the same vertices and the shared edge is the same
//! polyline on both sides: no cracks, by construction. Interior insertion never adds a border
//! sample (the border polyline already meets the bound there), so the hull stays as chosen.

use spade::handles::FixedVertexHandle;
use spade::{DelaunayTriangulation, HasPosition, InsertionError, Point2, Triangulation};

use crate::geom::ErrorFigures;
use crate::tiling::{NodeGrid, Span};

#[derive(Debug, thiserror::Error)]
pub enum TinError {
    #[error("tin: {heights} heights given for a {cols}×{rows} sample grid")]
    SizeMismatch { heights: usize, cols: usize, rows: usize },
    #[error("tin: need at least 2×2 samples, got {cols}×{rows}")]
    TooSmall { cols: usize, rows: usize },
    #[error("tin: max error must be finite and ≥ 0, got {0}")]
    BadMaxError(f64),
    #[error("tin: non-finite height at sample ({col}, {row})")]
    NonFinite { col: u32, row: u32 },
    #[error("tin: triangulation failed: {0:?}")]
    Insertion(InsertionError),
    #[error("tin: the mesh leaves {missing} of {total} raster samples uncovered")]
    Uncovered { missing: u64, total: u64 },
    #[error("tin: greedy insertion stalled: sample ({col}, {row}) is already a vertex")]
    Stalled { col: u32, row: u32 },
}

/// A TIN over a node grid: vertices are (column, row) indices into the `NodeGrid` (so every
/// vertex is an actual raster sample), triangles are counter-clockwise in (col, row) space.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct Tin {
    pub vertices: Vec<[u32; 2]>,
    pub triangles: Vec<[u32; 3]>,
}

#[derive(Debug, Clone, Copy)]
struct Vertex {
    pos: Point2<f64>,
    /// The sample's height: scans read a face's corners from spade's vertices, which the
    /// insertion has just touched, instead of from a separate (cold) array.
    z: f64,
    i: u32,
    j: u32,
}

impl HasPosition for Vertex {
    type Scalar = f64;
    fn position(&self) -> Point2<f64> {
        self.pos
    }
}

/// The worst sample of a face. `rank` packs (error as f32 bits, !sample index) so one integer
/// comparison orders by larger error first, ties to the lowest (row, col): the build is
/// deterministic, and heap entries stay 16 bytes.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
struct Candidate {
    rank: u64,
    /// A vertex of the face, where spade's point location starts.
    hint: u32,
}

impl Candidate {
    fn new(err: f64, sample: u32, hint: u32) -> Self {
        // err ≥ 0, and the bits of non-negative floats order like the floats.
        Self { rank: (u64::from((err as f32).to_bits()) << 32) | u64::from(!sample), hint }
    }
    fn sample(self) -> u32 {
        !(self.rank as u32)
    }
}

/// A max-heap of faces keyed by each face's candidate, with O(log n) update and removal of any
/// face: an insertion changes exactly the faces of the new vertex's star, and those are re-keyed
/// in place, so the heap never holds stale entries. Keys live inline in the heap array (16-byte
/// entries) so that sifting compares without chasing indices; sifts move a hole instead of
/// swapping, which makes the same comparisons and so leaves the same order.
#[derive(Debug, Default)]
struct FaceHeap {
    heap: Vec<HeapEntry>,
    pos: Vec<u32>,
}

#[derive(Debug, Clone, Copy)]
struct HeapEntry {
    rank: u64,
    hint: u32,
    face: u32,
}

impl HeapEntry {
    fn new(c: Candidate, face: u32) -> Self {
        Self { rank: c.rank, hint: c.hint, face }
    }
}

impl FaceHeap {
    const NONE: u32 = u32::MAX;

    fn set(&mut self, face: usize, cand: Option<Candidate>) {
        if face >= self.pos.len() {
            self.pos.resize(face + 1, Self::NONE);
        }
        let p = self.pos[face];
        match (cand, p) {
            (Some(c), Self::NONE) => {
                self.heap.push(HeapEntry::new(c, face as u32));
                let last = self.heap.len() - 1;
                self.up(last);
            }
            (Some(c), p) => {
                let e = HeapEntry::new(c, face as u32);
                let p = self.up_with(p as usize, e);
                self.down(p);
            }
            (None, Self::NONE) => {}
            (None, p) => self.remove_at(p as usize),
        }
    }

    fn peek(&self) -> Option<Candidate> {
        self.heap.first().map(|e| Candidate { rank: e.rank, hint: e.hint })
    }

    fn remove_at(&mut self, p: usize) {
        let last = self.heap.len() - 1;
        self.swap(p, last);
        if let Some(e) = self.heap.pop() {
            self.pos[e.face as usize] = Self::NONE;
        }
        if p < self.heap.len() {
            let p = self.up(p);
            self.down(p);
        }
    }

    fn swap(&mut self, a: usize, b: usize) {
        self.heap.swap(a, b);
        self.pos[self.heap[a].face as usize] = a as u32;
        self.pos[self.heap[b].face as usize] = b as u32;
    }

    fn place(&mut self, p: usize, e: HeapEntry) {
        self.heap[p] = e;
        self.pos[e.face as usize] = p as u32;
    }

    fn up(&mut self, p: usize) -> usize {
        let e = self.heap[p];
        self.up_with(p, e)
    }

    /// Sifts `e` up from the hole at `p` and stores it; returns where it landed.
    fn up_with(&mut self, mut p: usize, e: HeapEntry) -> usize {
        while p > 0 {
            let parent = (p - 1) / ARITY;
            let q = self.heap[parent];
            if e.rank <= q.rank {
                break;
            }
            self.place(p, q);
            p = parent;
        }
        self.place(p, e);
        p
    }

    fn down(&mut self, mut p: usize) {
        let e = self.heap[p];
        let n = self.heap.len();
        loop {
            let first = ARITY * p + 1;
            let (mut best, mut key) = (p, e.rank);
            for c in first..(first + ARITY).min(n) {
                if self.heap[c].rank > key {
                    (best, key) = (c, self.heap[c].rank);
                }
            }
            if best == p {
                break;
            }
            let c = self.heap[best];
            self.place(p, c);
            p = best;
        }
        self.place(p, e);
    }
}

/// Children per heap node: a node's four 16-byte children lie in one or two cache lines, and the
/// heap is half as deep as a binary one (re-keying a face after an insertion mostly sifts it
/// down, through cold entries).
const ARITY: usize = 4;

/// Nodes with more samples than this are built as independent regions (in parallel), split on
/// a seam column or row whose vertices are chosen like a node border: by 1-D simplification of
/// the seam's own samples. The split depends on the node's size and data only, never on the
/// thread count, so the result is deterministic; default 257² leaf tiles are never split.
pub const REGION_SPLIT_SAMPLES: usize = 1 << 17;

/// Builds the TIN of `heights` (row-major over `grid.rows × grid.cols`) so that every sample is
/// within `max_error` (vertical, in height units) of the mesh.
pub fn build(grid: &NodeGrid, heights: &[f32], max_error: f64) -> Result<Tin, TinError> {
    build_split(grid, heights, max_error, [REGION_SPLIT_SAMPLES, LOCAL_SPLIT_SAMPLES], 0.0, true)
}

/// [`build`] for a surface that a client draws curved away below flat triangles: a triangle
/// (or border segment) whose longest edge is `L` grid units long has `chord·L²` less error
/// budget (the sag of its chord below the curve: `R·θ²/8` for an edge of `θ` radians gives
/// `chord = R·(radians per grid unit)²/8`). So large triangles are split where the curve, not
/// the heights, needs it, and each triangle's error plus its sag stays within `max_error`.
/// Border segments use their own length, so neighbours with the same `chord` still agree.
pub fn build_with_chord(
    grid: &NodeGrid,
    heights: &[f32],
    max_error: f64,
    chord: f64,
) -> Result<Tin, TinError> {
    if !chord.is_finite() || chord < 0.0 {
        return Err(TinError::BadMaxError(chord));
    }
    build_split(grid, heights, max_error, [REGION_SPLIT_SAMPLES, LOCAL_SPLIT_SAMPLES], chord, true)
}

/// [`build`], splitting regions of more than `split[0]` samples, and of more than `split[1]`
/// where the seam is dense. `int_scans`: faces with corners on a regular grid are scanned by
/// integer edge walks (always in a build; off only in tests, which check that the float scan
/// finds the very same meshes).
fn build_split(
    grid: &NodeGrid,
    heights: &[f32],
    max_error: f64,
    [split_samples, local_split_samples]: [usize; 2],
    chord: f64,
    int_scans: bool,
) -> Result<Tin, TinError> {
    let (nc, nr) = (grid.cols.len(), grid.rows.len());
    if nc < 2 || nr < 2 {
        return Err(TinError::TooSmall { cols: nc, rows: nr });
    }
    if heights.len() != nc * nr {
        return Err(TinError::SizeMismatch { heights: heights.len(), cols: nc, rows: nr });
    }
    if !max_error.is_finite() || max_error < 0.0 {
        return Err(TinError::BadMaxError(max_error));
    }
    if let Some(k) = heights.iter().position(|h| !h.is_finite()) {
        return Err(TinError::NonFinite { col: grid.cols[k % nc], row: grid.rows[k / nc] });
    }
    let local_split_samples = local_split_samples.min(split_samples);
    let node = Node { grid, heights, nc, max_error, split_samples, local_split_samples, chord, int_scans };
    let whole = Region { i0: 0, i1: nc - 1, j0: 0, j1: nr - 1 };
    let borders = Borders {
        bottom: node.row_border(0, 0, nc - 1),
        top: node.row_border(nr - 1, 0, nc - 1),
        left: node.col_border(0, 0, nr - 1),
        right: node.col_border(nc - 1, 0, nr - 1),
    };
    build_region(&node, whole, borders)
}

/// The node being triangulated.
struct Node<'a> {
    grid: &'a NodeGrid,
    heights: &'a [f32],
    nc: usize,
    max_error: f64,
    split_samples: usize,
    /// Regions above this many samples split where the seam is dense.
    local_split_samples: usize,
    /// Sag of a chord per squared grid unit of its length (0: a flat surface).
    chord: f64,
    /// Integer scans where the grid is regular (see [`build_split`]).
    int_scans: bool,
}

impl Node<'_> {
    fn h(&self, i: usize, j: usize) -> f64 {
        f64::from(self.heights[j * self.nc + i])
    }

    /// Kept columns of row `j` between columns `i0` and `i1` (inclusive, node indices).
    fn row_border(&self, j: usize, i0: usize, i1: usize) -> Vec<usize> {
        let profile: Vec<(f64, f64)> =
            (i0..=i1).map(|i| (f64::from(self.grid.cols[i]), self.h(i, j))).collect();
        simplify_profile_chord(&profile, self.max_error, self.chord).into_iter().map(|k| i0 + k).collect()
    }

    /// Kept rows of column `i` between rows `j0` and `j1` (inclusive, node indices).
    fn col_border(&self, i: usize, j0: usize, j1: usize) -> Vec<usize> {
        let profile: Vec<(f64, f64)> =
            (j0..=j1).map(|j| (f64::from(self.grid.rows[j]), self.h(i, j))).collect();
        simplify_profile_chord(&profile, self.max_error, self.chord).into_iter().map(|k| j0 + k).collect()
    }
}

/// An inclusive rectangle of node sample indices.
#[derive(Debug, Clone, Copy)]
struct Region {
    i0: usize,
    i1: usize,
    j0: usize,
    j1: usize,
}

/// The kept vertices on a region's four edges, as node column (bottom, top) or row (left,
/// right) indices, ascending, endpoints included.
struct Borders {
    bottom: Vec<usize>,
    top: Vec<usize>,
    left: Vec<usize>,
    right: Vec<usize>,
}

/// The kept index closest to the middle of `lo..=hi` that both sides keep, if it lies in the
/// middle half: a seam must start and end at existing border vertices, or it would add a vertex
/// to the region's border that the neighbour across it does not have.
fn seam_at(a: &[usize], b: &[usize], lo: usize, hi: usize) -> Option<usize> {
    let mid = usize::midpoint(lo, hi);
    let quarter = (hi - lo) / 4;
    a.iter()
        .copied()
        .filter(|m| b.binary_search(m).is_ok() && m.abs_diff(mid) <= quarter && *m > lo && *m < hi)
        .min_by_key(|m| (m.abs_diff(mid), *m))
}

fn within(v: &[usize], lo: usize, hi: usize) -> Vec<usize> {
    v.iter().copied().filter(|&k| k >= lo && k <= hi).collect()
}

/// Regions with more samples than this are split further when the seam through them is dense
/// (see [`SEAM_DENSITY`]), on one thread as on many: a region's triangulation then fits in a
/// core's cache (spade's half-edges, the face heap and the heights of 64² samples take about
/// 0.5 MiB at full density), and greedy insertion, which jumps to wherever the worst sample is,
/// stops missing the cache on every step (fuji at 1 m: about 1.6× faster on one thread, 0.1 %
/// fewer vertices).
pub const LOCAL_SPLIT_SAMPLES: usize = 1 << 12;

/// A seam splits a region of at most [`REGION_SPLIT_SAMPLES`] samples only if its 1-D
/// simplification keeps at least one sample in this many: where the data is that dense, most
/// samples become vertices anyway, the triangulation outgrows the cache, and the seam costs few
/// extra vertices. Sparser meshes fit the cache whole and are left in one piece: seams there
/// shape the triangles around them (a 129² synthetic tile at 11 % density, split at 1 in 16,
/// coded to 0.53× quantized-mesh + gzip against the design's < 0.5×), and smooth data (a flat
/// sea: only the corners) is never cut.
pub const SEAM_DENSITY: usize = 4;

/// Builds one region: split on a seam when it is large and one is available, else greedily.
fn build_region(node: &Node, r: Region, b: Borders) -> Result<Tin, TinError> {
    let (w, h) = (r.i1 - r.i0 + 1, r.j1 - r.j0 + 1);
    let large = w * h > node.split_samples;
    if large || w * h > node.local_split_samples {
        // Split across the longer side first.
        let vertical = || seam_at(&b.bottom, &b.top, r.i0, r.i1).map(|m| (true, m));
        let horizontal = || seam_at(&b.left, &b.right, r.j0, r.j1).map(|m| (false, m));
        let split = if w >= h { vertical().or_else(horizontal) } else { horizontal().or_else(vertical) };
        if let Some((is_vertical, m)) = split {
            let (seam, len) = if is_vertical {
                (node.col_border(m, r.j0, r.j1), h)
            } else {
                (node.row_border(m, r.i0, r.i1), w)
            };
            if large || seam.len() * SEAM_DENSITY >= len {
                let (ra, ba, rb, bb) = if is_vertical {
                    (
                        Region { i1: m, ..r },
                        Borders {
                            bottom: within(&b.bottom, r.i0, m),
                            top: within(&b.top, r.i0, m),
                            left: b.left,
                            right: seam.clone(),
                        },
                        Region { i0: m, ..r },
                        Borders {
                            bottom: within(&b.bottom, m, r.i1),
                            top: within(&b.top, m, r.i1),
                            left: seam,
                            right: b.right,
                        },
                    )
                } else {
                    (
                        Region { j1: m, ..r },
                        Borders {
                            bottom: b.bottom,
                            top: seam.clone(),
                            left: within(&b.left, r.j0, m),
                            right: within(&b.right, r.j0, m),
                        },
                        Region { j0: m, ..r },
                        Borders {
                            bottom: seam,
                            top: b.top,
                            left: within(&b.left, m, r.j1),
                            right: within(&b.right, m, r.j1),
                        },
                    )
                };
                let (a, c) = if large {
                    rayon::join(|| build_region(node, ra, ba), || build_region(node, rb, bb))
                } else {
                    (build_region(node, ra, ba), build_region(node, rb, bb))
                };
                return Ok(merge(a?, &c?, usize::from(!is_vertical), m as u32));
            }
        }
    }
    greedy_region(node, r, &b)
}

/// Joins two TINs that share the vertices of their seam: node index `m` on axis `axis` (0: a
/// column, 1: a row). Only seam vertices can be shared, so only they are looked up.
fn merge(a: Tin, b: &Tin, axis: usize, m: u32) -> Tin {
    let other = 1 - axis;
    let mut seam: Vec<(u32, u32)> = a
        .vertices
        .iter()
        .enumerate()
        .filter(|(_, v)| v[axis] == m)
        .map(|(k, v)| (v[other], k as u32))
        .collect();
    seam.sort_unstable();
    let mut out = a;
    let remap: Vec<u32> = b
        .vertices
        .iter()
        .map(|&v| {
            let shared = (v[axis] == m)
                .then(|| seam.binary_search_by_key(&v[other], |&(t, _)| t).ok().map(|p| seam[p].1))
                .flatten();
            shared.unwrap_or_else(|| {
                out.vertices.push(v);
                (out.vertices.len() - 1) as u32
            })
        })
        .collect();
    out.triangles.extend(b.triangles.iter().map(|t| t.map(|k| remap[k as usize])));
    out
}

/// Greedy insertion over one region whose border vertices are given.
fn greedy_region(node: &Node, r: Region, b: &Borders) -> Result<Tin, TinError> {
    let (nc, nr) = (r.i1 - r.i0 + 1, r.j1 - r.j0 + 1);
    let (cols, rows) = (&node.grid.cols[r.i0..=r.i1], &node.grid.rows[r.j0..=r.j1]);
    let (ax, ay) = (Axis::of(cols), Axis::of(rows));
    let xs: Vec<f64> = cols.iter().map(|&c| f64::from(c)).collect();
    let ys: Vec<f64> = rows.iter().map(|&r| f64::from(r)).collect();
    let max_error = node.max_error;
    // Region-local sample indices from here on.
    let h = |i: usize, j: usize| node.h(r.i0 + i, r.j0 + j);

    let mut tri: DelaunayTriangulation<Vertex> = DelaunayTriangulation::new();
    let insert = |tri: &mut DelaunayTriangulation<Vertex>, i: usize, j: usize| {
        tri.insert(Vertex { pos: Point2::new(xs[i], ys[j]), z: h(i, j), i: i as u32, j: j as u32 })
            .map_err(TinError::Insertion)
    };
    // Borders: bottom and top rows, left and right columns; corners appear twice, and spade
    // keeps the first insertion of a position.
    for (j, kept) in [(0, &b.bottom), (nr - 1, &b.top)] {
        for &i in kept {
            insert(&mut tri, i - r.i0, j)?;
        }
    }
    for (i, kept) in [(0, &b.left), (nc - 1, &b.right)] {
        for &j in kept {
            insert(&mut tri, i, j - r.j0)?;
        }
    }

    let corner = |v: &Vertex| [v.pos.x, v.pos.y, v.z];
    let ij = |v: &Vertex| [v.i, v.j];
    // The first sample (in row-major order) of the largest error over the bound wins, so one
    // comparison per sample decides.
    // Inner spans never reach the last column, so a sample's x is `start + i·step` there
    // (`Axis::at` without its branch), and each row is one slice of the node's heights.
    let chord = node.chord;
    // A curved surface: the face's sag comes off its budget, and its own corners (error 0, and
    // so candidates once the budget is below 0) are never picked.
    let sag = |p: &[[f64; 3]; 3]| {
        let d2 = |a: [f64; 3], b: [f64; 3]| (a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2);
        chord * d2(p[0], p[1]).max(d2(p[1], p[2])).max(d2(p[2], p[0]))
    };
    // `corners`: the face's vertex handles; the one nearest the chosen sample becomes the
    // candidate's hint, where spade's point location starts (its walk then ends at once).
    let regular = node.int_scans && ax.uniform() && ay.uniform();
    let scan = |p: [[f64; 3]; 3], ij: [[u32; 2]; 3], corners: [u32; 3]| {
        // A face within one grid cell (most faces of a dense mesh) holds no sample but its own
        // corners, which the mesh passes through: nothing to scan.
        let (i_lo, i_hi) = (ij[0][0].min(ij[1][0]).min(ij[2][0]), ij[0][0].max(ij[1][0]).max(ij[2][0]));
        let (j_lo, j_hi) = (ij[0][1].min(ij[1][1]).min(ij[2][1]), ij[0][1].max(ij[1][1]).max(ij[2][1]));
        if i_hi - i_lo <= 1 && j_hi - j_lo <= 1 {
            return None;
        }
        let sag_p = if chord > 0.0 { sag(&p) } else { 0.0 };
        // Grid positions are integers, exact in f64: equality is exact here.
        #[allow(clippy::float_cmp)]
        let is_corner = |x: f64, y: f64| chord > 0.0 && p.iter().any(|c| c[0] == x && c[1] == y);
        let (mut worst, mut sample) = (max_error - sag_p, u32::MAX);
        let mut row_scan = |s: RowSpan| {
            let base = (r.j0 + s.j) * node.nc + r.i0;
            // Sample positions are integers (u32 grid coordinates), so stepping x by `step` is
            // exact: the same x, and so the same plane height, as `start + i·step`.
            let row = &node.heights[base + s.i0..base + s.i1];
            let first = s.j * nc + s.i0;
            let mut x = ax.start + s.i0 as i64 as f64 * ax.step;
            // Four samples at a time without branches; a block with an error over the current
            // worst is redone one by one, so the winner is the same as a plain sequential scan.
            let mut blocks = row.chunks_exact(4);
            let mut k = 0;
            for b in &mut blocks {
                let xq = [x, x + ax.step, x + 2.0 * ax.step, x + 3.0 * ax.step];
                let e: [f64; 4] = std::array::from_fn(|q| (f64::from(b[q]) - s.z(xq[q])).abs());
                // The largest error, NaN skipped like `f64::max` does, in plain comparisons.
                let top = e.iter().fold(f64::NEG_INFINITY, |m, &v| if v > m { v } else { m });
                if top > worst {
                    for (q, &eq) in e.iter().enumerate() {
                        if eq > worst && !is_corner(xq[q], ys[s.j]) {
                            worst = eq;
                            sample = (first + k + q) as u32;
                        }
                    }
                }
                x += 4.0 * ax.step;
                k += 4;
            }
            for &hv in blocks.remainder() {
                let e = (f64::from(hv) - s.z(x)).abs();
                if e > worst && !is_corner(x, ys[s.j]) {
                    worst = e;
                    sample = (first + k) as u32;
                }
                x += ax.step;
                k += 1;
            }
        };
        let (bi, bj) = (
            [(i_lo as usize).max(1), (i_hi as usize + 1).min(nc - 1)],
            [(j_lo as usize).max(1), (j_hi as usize + 1).min(nr - 1)],
        );
        if regular && bi[1] > bi[0] && bj[1] > bj[0] && (bi[1] - bi[0]) * (bj[1] - bj[0]) <= TINY_BOX_SAMPLES
        {
            // A few samples (most faces of a dense mesh): each tested against the three edges
            // in integers, the plane only once one is inside; the same samples, the same
            // heights and the same order as the rows below.
            let [a, mut b, mut c] = ij.map(|v| [i64::from(v[0]), i64::from(v[1])]);
            let det = (b[0] - a[0]) * (c[1] - a[1]) - (c[0] - a[0]) * (b[1] - a[1]);
            if det < 0 {
                std::mem::swap(&mut b, &mut c);
            }
            let edges = [(a, b), (b, c), (c, a)].map(|(u, v)| (u[0], u[1], v[0] - u[0], v[1] - u[1]));
            let mut plane = None;
            for (j, &y) in ys.iter().enumerate().take(bj[1]).skip(bj[0]) {
                let mut zrow = None;
                for i in bi[0]..bi[1] {
                    let (ii, jj) = (i as i64, j as i64);
                    if det == 0 || !edges.iter().all(|&(ux, uy, ex, ey)| ey * (ii - ux) <= ex * (jj - uy)) {
                        continue;
                    }
                    let Some(pl) = *plane.get_or_insert_with(|| Plane::of(p)) else {
                        break;
                    };
                    let s = *zrow.get_or_insert_with(|| pl.span(j, y, i, i + 1));
                    let x = ax.start + i as i64 as f64 * ax.step;
                    let e = (h(i, j) - s.z(x)).abs();
                    if e > worst && !is_corner(x, y) {
                        worst = e;
                        sample = (j * nc + i) as u32;
                    }
                }
            }
        } else if regular {
            // The rows from the integer edge walk.
            if let Some(plane) = Plane::of(p) {
                int_spans(ij, [1, nc - 1], 1..nr - 1, |j, s0, s1| row_scan(plane.span(j, ay.at(j), s0, s1)));
            }
        } else {
            // Irregular axes (a node clipped at the raster's edge): float spans. Without integer
            // scans (tests) the box comes from positions too, so nothing integer is left.
            let ij = node.int_scans.then_some(ij);
            scan_spans_in(p, ij, &ax, &ay, true, SMALL_BOX_SAMPLES, 0..usize::MAX, row_scan);
        }
        (sample != u32::MAX).then(|| {
            let (si, sj) = (sample % nc as u32, sample / nc as u32);
            let d2 = |c: [u32; 2]| u64::from(c[0].abs_diff(si)).pow(2) + u64::from(c[1].abs_diff(sj)).pow(2);
            let near = (0..3).min_by_key(|&k| d2(ij[k])).unwrap_or(0);
            Candidate::new(worst + sag_p, sample, corners[near])
        })
    };

    let mut heap = FaceHeap::default();
    for face in tri.fixed_inner_faces() {
        let vs = tri.face(face).vertices();
        let (p, ij) = (vs.map(|v| corner(v.data())), vs.map(|v| ij(v.data())));
        heap.set(face.index(), scan(p, ij, vs.map(|v| v.fix().index() as u32)));
    }
    while let Some(c) = heap.peek() {
        let hint = FixedVertexHandle::from_index(c.hint as usize);
        let (ci, cj) = (c.sample() % nc as u32, c.sample() / nc as u32);
        let before = tri.num_vertices();
        let v = tri
            .insert_with_hint(
                Vertex {
                    pos: Point2::new(xs[ci as usize], ys[cj as usize]),
                    z: h(ci as usize, cj as usize),
                    i: ci,
                    j: cj,
                },
                hint,
            )
            .map_err(TinError::Insertion)?;
        // Each round adds a vertex, so the loop ends within the region's sample count; a
        // candidate that is already a vertex would repeat forever, so it is an error instead
        // (a scan that strays outside its face; never seen).
        if tri.num_vertices() == before {
            return Err(TinError::Stalled {
                col: node.grid.cols[r.i0 + ci as usize],
                row: node.grid.rows[r.j0 + cj as usize],
            });
        }
        // Every face an insertion creates (by splitting or by the flips that follow) is incident
        // to the new vertex, so its star is all that needs a new scan. The face left of the
        // out-edge v→w is (v, w, next(w)).
        let vh = tri.vertex(v);
        let (pv, iv) = (corner(vh.data()), ij(vh.data()));
        for e in vh.out_edges() {
            if let Some(f) = e.face().as_inner() {
                let (wh, xh) = (e.to(), e.next().to());
                let (w, x) = (wh.data(), xh.data());
                let p = [pv, corner(w), corner(x)];
                let handles = [v.index() as u32, wh.fix().index() as u32, xh.fix().index() as u32];
                heap.set(f.fix().index(), scan(p, [iv, ij(w), ij(x)], handles));
            }
        }
        // The popped face is always in the star (the new vertex lies in it), so it was re-keyed.
    }

    let vertices = tri.vertices().map(|v| [v.data().i + r.i0 as u32, v.data().j + r.j0 as u32]).collect();
    let triangles = tri.inner_faces().map(|f| f.vertices().map(|v| v.fix().index() as u32)).collect();
    Ok(Tin { vertices, triangles })
}

/// Indices of the samples kept by greedy simplification of a 1-D profile `(t, h)` so that linear
/// interpolation between kept samples is within `max_error` of every sample. Endpoints are kept.
#[must_use]
pub fn simplify_profile(profile: &[(f64, f64)], max_error: f64) -> Vec<usize> {
    simplify_profile_chord(profile, max_error, 0.0)
}

/// [`simplify_profile`] of a profile drawn curved away below its chords: a segment `(a, b)` has
/// `chord·(t_b − t_a)²` less error budget (see [`build_with_chord`]).
#[must_use]
pub fn simplify_profile_chord(profile: &[(f64, f64)], max_error: f64, chord: f64) -> Vec<usize> {
    let n = profile.len();
    if n <= 2 {
        return (0..n).collect();
    }
    let mut keep = vec![false; n];
    keep[0] = true;
    keep[n - 1] = true;
    // Splitting a segment only depends on that segment, so a stack gives the same result as a
    // global priority order would.
    let mut stack = vec![(0, n - 1)];
    while let Some((a, b)) = stack.pop() {
        let (ta, ha) = profile[a];
        let (tb, hb) = profile[b];
        let budget = max_error - chord * (tb - ta) * (tb - ta);
        let mut worst: Option<(f64, usize)> = None;
        for (k, &(t, hk)) in profile.iter().enumerate().take(b).skip(a + 1) {
            let z = ha + (hb - ha) * (t - ta) / (tb - ta);
            let e = (hk - z).abs();
            if e > budget && worst.is_none_or(|(w, _)| e > w) {
                worst = Some((e, k));
            }
        }
        if let Some((_, k)) = worst {
            keep[k] = true;
            stack.push((a, k));
            stack.push((k, b));
        }
    }
    (0..n).filter(|&k| keep[k]).collect()
}

/// A sorted axis of sample positions: regular steps from `start`, except that the last position
/// may be closer to the one before (a node clipped at the raster edge). Index look-ups are O(1).
#[derive(Debug, Clone, Copy)]
pub struct Axis {
    start: f64,
    step: f64,
    n: usize,
    last: f64,
    /// `step == 1`.
    unit: bool,
}

impl Axis {
    /// The axis of `positions`, which must be `start + k·step` for all but the last entry.
    #[must_use]
    pub fn of(positions: &[u32]) -> Self {
        let n = positions.len();
        let start = positions.first().map_or(0.0, |&p| f64::from(p));
        let step = if n >= 2 { f64::from(positions[1]) - start } else { 1.0 };
        let last = positions.last().map_or(0.0, |&p| f64::from(p));
        Self { start, step, n, last, unit: step.to_bits() == 1f64.to_bits() }
    }

    #[must_use]
    pub fn len(&self) -> usize {
        self.n
    }

    /// Every position is `start + k·step`, the last one too, with small integer indices.
    #[allow(clippy::float_cmp)]
    fn uniform(&self) -> bool {
        // Positions are integers (u32), so the comparison is exact.
        self.n > 0
            && self.n < (1 << 24)
            && self.step > 0.0
            && self.last == self.start + (self.n - 1) as i64 as f64 * self.step
    }

    #[must_use]
    pub fn is_empty(&self) -> bool {
        self.n == 0
    }

    #[must_use]
    pub fn at(&self, i: usize) -> f64 {
        // Through i64: one instruction, where usize → f64 takes several (indices are < 2⁶³).
        if i + 1 == self.n { self.last } else { self.start + i as i64 as f64 * self.step }
    }

    /// `d / step`, without the division on a unit axis (where it is exact anyway): scans look
    /// indices up several times per triangle row.
    #[inline]
    fn steps(&self, d: f64) -> f64 {
        if self.unit { d } else { d / self.step }
    }

    /// Index of the first position ≥ `v` (`len()` if none).
    fn first_ge(&self, v: f64) -> usize {
        if self.n == 0 || v <= self.start {
            return 0;
        }
        // v > start here, so the quotient is positive and truncation is floor (no libm call);
        // i64 ↔ f64 are single instructions, unlike usize ↔ f64.
        let q = self.steps(v - self.start);
        let t = q as i64;
        let k = if (t as f64) < q { t.saturating_add(1) } else { t } as usize;
        if k < self.n - 1 {
            k
        } else if v <= self.last {
            self.n - 1
        } else {
            self.n
        }
    }

    /// Number of positions ≤ `v`.
    fn count_le(&self, v: f64) -> usize {
        if self.n == 0 || v < self.start {
            return 0;
        }
        if v >= self.last {
            return self.n;
        }
        let k = self.steps(v - self.start) as i64 as usize + 1;
        k.min(self.n - 1)
    }
}

/// Faces of the greedy insertion whose bounding box (inner samples) holds at most this many
/// samples are tested sample by sample in integers.
const TINY_BOX_SAMPLES: usize = 12;

/// Triangles whose bounding box holds at most this many samples are scanned sample by sample.
const SMALL_BOX_SAMPLES: usize = 48;

/// The samples of one row inside a triangle: columns `i0..i1` of row `j`, where the triangle's
/// plane is `z = zrow + gx·(x − x0)`.
#[derive(Debug, Clone, Copy)]
pub struct RowSpan {
    pub j: usize,
    pub i0: usize,
    pub i1: usize,
    zrow: f64,
    gx: f64,
    x0: f64,
}

impl RowSpan {
    /// The plane's height at `x` on this row.
    #[inline]
    #[must_use]
    pub fn z(&self, x: f64) -> f64 {
        self.zrow + self.gx * (x - self.x0)
    }
}

/// A triangle's plane `z = a.z + gx·(x − a.x) + gy·(y − a.y)`, and its corners' orientation.
#[derive(Debug, Clone, Copy)]
struct Plane {
    a: [f64; 3],
    gx: f64,
    gy: f64,
    /// Twice the signed area in (x, y).
    det: f64,
}

impl Plane {
    /// `None` for a degenerate (or non-finite) triangle.
    #[inline]
    fn of([a, b, c]: [[f64; 3]; 3]) -> Option<Self> {
        let det = (b[0] - a[0]) * (c[1] - a[1]) - (c[0] - a[0]) * (b[1] - a[1]);
        if det == 0.0 || !det.is_finite() {
            return None;
        }
        let gx = ((b[2] - a[2]) * (c[1] - a[1]) - (c[2] - a[2]) * (b[1] - a[1])) / det;
        let gy = ((c[2] - a[2]) * (b[0] - a[0]) - (b[2] - a[2]) * (c[0] - a[0])) / det;
        Some(Self { a, gx, gy, det })
    }

    /// Row `j` (at `y`), columns `i0..i1`.
    #[inline]
    fn span(&self, j: usize, y: f64, i0: usize, i1: usize) -> RowSpan {
        RowSpan { j, i0, i1, zrow: self.a[2] + self.gy * (y - self.a[1]), gx: self.gx, x0: self.a[0] }
    }
}

/// Calls `f(i, j, z)` for every grid sample `(xs.at(i), ys.at(j))` inside or on triangle `p`
/// (x, y, z), with `z` the triangle's plane at that sample. With `inner`, samples on the first
/// and last row and column are skipped.
pub fn scan_triangle(
    p: [[f64; 3]; 3],
    xs: &Axis,
    ys: &Axis,
    inner: bool,
    mut f: impl FnMut(usize, usize, f64),
) {
    scan_spans(p, xs, ys, inner, SMALL_BOX_SAMPLES, 0..usize::MAX, |s| {
        for i in s.i0..s.i1 {
            f(i, s.j, s.z(xs.at(i)));
        }
    });
}

/// The rows of [`scan_triangle`] of a triangle whose corners are the samples `ij` (column, row
/// indices): `f` gets each row's span, whose [`RowSpan::z`] at `xs.at(i)` is the height that
/// [`scan_triangle`] gives sample `i`. Found faster on regular axes, and the caller's loop over
/// a row's samples is its own.
pub fn scan_triangle_rows_ij(
    p: [[f64; 3]; 3],
    ij: [[u32; 2]; 3],
    xs: &Axis,
    ys: &Axis,
    inner: bool,
    f: impl FnMut(RowSpan),
) {
    scan_spans_in(p, Some(ij), xs, ys, inner, SMALL_BOX_SAMPLES, 0..usize::MAX, f);
}

/// [`scan_triangle`] restricted to the rows `rows` of `ys`: the same samples with the same
/// heights as the whole scan gives on those rows (the scan method is chosen from the whole
/// triangle's box, so a strip sees exactly what the whole scan would).
pub fn scan_triangle_rows(
    p: [[f64; 3]; 3],
    xs: &Axis,
    ys: &Axis,
    rows: std::ops::Range<usize>,
    mut f: impl FnMut(usize, usize, f64),
) {
    scan_spans(p, xs, ys, false, SMALL_BOX_SAMPLES, rows, |s| {
        for i in s.i0..s.i1 {
            f(i, s.j, s.z(xs.at(i)));
        }
    });
}

/// Calls `f` with each row's span of samples inside or on triangle `p` (see [`scan_triangle`]).
/// When the bounding box holds at most `box_limit` samples they are tested one by one against
/// the three edge functions (no divisions: most triangles of a fine TIN cover a handful of
/// samples); otherwise each row's span is computed from the edges. Both give the same samples:
/// those within EPS of the closed triangle.
fn scan_spans(
    p: [[f64; 3]; 3],
    xs: &Axis,
    ys: &Axis,
    inner: bool,
    box_limit: usize,
    rows: std::ops::Range<usize>,
    f: impl FnMut(RowSpan),
) {
    scan_spans_in(p, None, xs, ys, inner, box_limit, rows, f);
}

/// [`scan_spans`] where the caller may know the triangle's corners as sample indices: `ij`
/// (column, row of each corner) gives the bounding box's samples without looking positions up
/// on the axes (the same samples: corners are samples, and the axes are increasing).
#[allow(clippy::too_many_arguments)]
fn scan_spans_in(
    p: [[f64; 3]; 3],
    ij: Option<[[u32; 2]; 3]>,
    xs: &Axis,
    ys: &Axis,
    inner: bool,
    box_limit: usize,
    rows: std::ops::Range<usize>,
    mut f: impl FnMut(RowSpan),
) {
    const EPS: f64 = 1e-9;
    let [a, b, c] = p;
    let Some(plane) = Plane::of(p) else {
        return;
    };
    let det = plane.det;
    let span = |j: usize, y: f64, i0: usize, i1: usize| plane.span(j, y, i0, i1);
    let (lo, hi) = (usize::from(inner), |n: usize| if inner { n.saturating_sub(1) } else { n });
    let iend = hi(xs.len());
    if let Some(ij) = ij.filter(|_| xs.uniform() && ys.uniform()) {
        // Corners on regular axes: the same samples, from exact integer edge walks.
        let rows = rows.start.max(lo)..rows.end.min(hi(ys.len()));
        int_spans(ij, [lo, iend], rows, |j, s0, s1| f(span(j, ys.at(j), s0, s1)));
        return;
    }
    let ([i0, i1], [j0, j1]) = (
        [xs.first_ge(a[0].min(b[0]).min(c[0]) - EPS), xs.count_le(a[0].max(b[0]).max(c[0]) + EPS)],
        [ys.first_ge(a[1].min(b[1]).min(c[1]) - EPS), ys.count_le(a[1].max(b[1]).max(c[1]) + EPS)],
    );
    let (j0, j1) = (j0.max(lo), j1.min(hi(ys.len())));
    if j1 <= j0 {
        return;
    }
    let (i0, i1) = (i0.max(lo), i1.min(iend));
    if i1 <= i0 {
        return;
    }
    let small = (j1 - j0) * (i1 - i0) <= box_limit;
    let (j0, j1) = (j0.max(rows.start), j1.min(rows.end));
    if j1 <= j0 {
        return;
    }
    if small {
        let s = det.signum();
        let edge = |u: [f64; 3], v: [f64; 3]| {
            let (ex, ey) = ((v[0] - u[0]) * s, (v[1] - u[1]) * s);
            (u[0], u[1], ex, ey, -EPS * ex.abs().max(ey.abs()))
        };
        let es = [edge(a, b), edge(b, c), edge(c, a)];
        for j in j0..j1 {
            let y = ys.at(j);
            // The inside samples of a row are contiguous: the triangle is convex.
            let inside = |i: usize| {
                let x = xs.at(i);
                es.iter().all(|&(ux, uy, ex, ey, tol)| ex * (y - uy) - ey * (x - ux) >= tol)
            };
            if let Some(first) = (i0..i1).find(|&i| inside(i)) {
                let end = (first + 1..i1).find(|&i| !inside(i)).unwrap_or(i1);
                f(span(j, y, first, end));
            }
        }
        return;
    }
    // Each edge from its lower to its upper end, with 1/Δy (0 for a flat edge).
    let edges = [(a, b), (b, c), (c, a)].map(|(u, v)| {
        let (lo, hi) = if u[1] <= v[1] { (u, v) } else { (v, u) };
        let dy = hi[1] - lo[1];
        (lo, hi, if dy <= EPS { 0.0 } else { 1.0 / dy })
    });
    for j in j0..j1 {
        let y = ys.at(j);
        let mut xl = f64::INFINITY;
        let mut xr = f64::NEG_INFINITY;
        for (lo, hi, inv_dy) in edges {
            if y < lo[1] - EPS || y > hi[1] + EPS {
                continue;
            }
            if inv_dy == 0.0 {
                xl = xl.min(lo[0].min(hi[0]));
                xr = xr.max(lo[0].max(hi[0]));
            } else {
                let t = ((y - lo[1]) * inv_dy).clamp(0.0, 1.0);
                let x = lo[0] + t * (hi[0] - lo[0]);
                xl = xl.min(x);
                xr = xr.max(x);
            }
        }
        if xl > xr {
            continue;
        }
        let (s0, s1) = (xs.first_ge(xl - EPS).max(lo), xs.count_le(xr + EPS).min(iend));
        if s0 < s1 {
            f(span(j, y, s0, s1));
        }
    }
}

/// Calls `f(j, i0, i1)` for each row `j` in `rows` of the closed triangle whose corners are the
/// sample indices `ij`, with its columns `i0..i1` (within `cols`, half-open; empty rows are
/// skipped), top row first. On a regular grid these are exactly the samples within
/// [`scan_spans`]'s EPS of the triangle: a sample off an edge is at least 1/|Δ| grid steps from
/// it, far more than EPS. A scanline walk in integers: the long edge (top to bottom corner)
/// bounds one side of every row, the two short edges the other side of theirs, each edge's
/// column on a row being `ux + ⌊ex·(j − uy) / ey⌋` (or its ceiling), stepped from row to row by
/// quotient and remainder (a division per edge to set up, none in the loop). Nothing for a
/// degenerate triangle.
fn int_spans(
    ij: [[u32; 2]; 3],
    [c0, c1]: [usize; 2],
    rows: std::ops::Range<usize>,
    mut f: impl FnMut(usize, usize, usize),
) {
    let mut v = ij.map(|p| [i64::from(p[0]), i64::from(p[1])]);
    v.sort_unstable_by_key(|p| p[1]);
    let [t, m, b] = v;
    // > 0: the middle corner lies left of the long edge, so the short edges bound the left.
    let cross = (b[0] - t[0]) * (m[1] - t[1]) - (m[0] - t[0]) * (b[1] - t[1]);
    let (lo, hi) = (c0 as i64, c1 as i64 - 1);
    let (r0, r1) = (rows.start.max(t[1] as usize), rows.end.min(b[1] as usize + 1));
    if cross == 0 || r0 >= r1 || lo > hi {
        return;
    }
    let short_left = cross > 0;
    let long = Edge::new(t, b, r0 as i64);
    // Rows of the first short edge: to the middle row, or through it when the bottom edge is
    // flat (then the middle row's other bound is the bottom corner, on the long edge).
    let split = if m[1] == b[1] { m[1] + 1 } else { m[1] } as usize;
    let mut long = long;
    let mut run = |short: &mut Edge, from: usize, to: usize, long: &mut Edge| {
        for j in from..to {
            let (l, r) = if short_left { (short.ceil(), long.floor()) } else { (long.ceil(), short.floor()) };
            let (l, r) = (l.max(lo), r.min(hi));
            if l <= r {
                f(j, l as usize, r as usize + 1);
            }
            short.step();
            long.step();
        }
    };
    if m[1] > t[1] && r0 < split {
        let to = split.min(r1);
        run(&mut Edge::new(t, m, r0 as i64), r0, to, &mut long);
    }
    if b[1] > m[1] && split.max(r0) < r1 {
        let from = split.max(r0);
        run(&mut Edge::new(m, b, from as i64), from, r1, &mut long);
    }
}

/// A triangle edge from `u` to `v` (`v` on a later row) as the column `ux + q + r / d` where it
/// crosses the current row, with `0 ≤ r < d`, and the per-row steps of `q` and `r`.
struct Edge {
    x: i64,
    q: i64,
    r: i64,
    qs: i64,
    rs: i64,
    d: i64,
}

impl Edge {
    /// At row `y` (`u`'s row or later). Values stay below 2⁴⁸: indices are below 2²⁴
    /// (`Axis::uniform`).
    #[inline]
    fn new(u: [i64; 2], v: [i64; 2], y: i64) -> Self {
        let (ex, d) = (v[0] - u[0], v[1] - u[1]);
        let num = ex * (y - u[1]);
        let (q, r) = if num == 0 { (0, 0) } else { (num.div_euclid(d), num.rem_euclid(d)) };
        Self { x: u[0], q, r, qs: ex.div_euclid(d), rs: ex.rem_euclid(d), d }
    }

    #[inline]
    fn floor(&self) -> i64 {
        self.x + self.q
    }

    #[inline]
    fn ceil(&self) -> i64 {
        self.x + self.q + i64::from(self.r > 0)
    }

    #[inline]
    fn step(&mut self) {
        self.r += self.rs;
        let carry = i64::from(self.r >= self.d);
        self.q += self.qs + carry;
        self.r -= carry * self.d;
    }
}

/// Vertical error of a mesh against every full-resolution sample of `span`.
///
/// `positions` are (col, row, height) in full-resolution sample coordinates; `heights` holds the
/// span's samples row-major. Every sample is counted once (shared edges are not counted twice),
/// and a sample no triangle covers is an error: a node's mesh must cover its whole span.
pub fn measure_vertical(
    positions: &[[f64; 3]],
    triangles: &[[u32; 3]],
    span: Span,
    heights: &[f32],
) -> Result<ErrorFigures, TinError> {
    let (nc, nr) = (span.cols() as usize, span.rows() as usize);
    if heights.len() != nc * nr {
        return Err(TinError::SizeMismatch { heights: heights.len(), cols: nc, rows: nr });
    }
    measure_vertical_strips(positions, triangles, span, usize::MAX, |r0, r1, out| {
        out.clear();
        out.extend_from_slice(&heights[(r0 - span.row0) as usize * nc..(r1 - span.row0 + 1) as usize * nc]);
        Ok::<(), std::convert::Infallible>(())
    })
    .map_err(|e| match e {
        StripError::Tin(t) => t,
        StripError::Read(never) => match never {},
    })
}

/// Samples per strip of [`measure_vertical_strips`] as the bake uses it: a span of at most
/// this many samples is measured in one strip, exactly as [`measure_vertical`] does.
pub const MEASURE_STRIP_SAMPLES: usize = 2049 * 2049;

/// What stops a streamed measurement: the mesh or the reader.
#[derive(Debug)]
pub enum StripError<E> {
    Tin(TinError),
    Read(E),
}

/// [`measure_vertical`] over a span read in strips of rows, so a span larger than memory can be
/// measured: `read(row0, row1, out)` fills `out` with rows `row0..=row1` of the span's columns.
/// Strips hold `max(1, strip_samples / cols)` rows from the span's first row, so the strips (and
/// the order of the float sums: triangle order within a strip, strips in row order) depend only
/// on the span; a span of at most `strip_samples` samples is one strip and gives exactly what
/// [`measure_vertical`] gives. The maximum is the same whatever the strips.
pub fn measure_vertical_strips<E>(
    positions: &[[f64; 3]],
    triangles: &[[u32; 3]],
    span: Span,
    strip_samples: usize,
    mut read: impl FnMut(u32, u32, &mut Vec<f32>) -> Result<(), E>,
) -> Result<ErrorFigures, StripError<E>> {
    let (nc, nr) = (span.cols() as usize, span.rows() as usize);
    let strip_rows = (strip_samples / nc.max(1)).clamp(1, nr.max(1));
    let xs = Axis { start: f64::from(span.col0), step: 1.0, n: nc, last: f64::from(span.col1), unit: true };
    let ys = Axis { start: f64::from(span.row0), step: 1.0, n: nr, last: f64::from(span.row1), unit: true };
    let tris: Vec<[[f64; 3]; 3]> = triangles
        .iter()
        .map(|t| t.map(|k| positions.get(k as usize).copied().unwrap_or([f64::NAN; 3])))
        .collect();
    // Each triangle's row range (in span rows), to skip it in strips it cannot touch.
    let row_range: Vec<(f64, f64)> = tris
        .iter()
        .map(|p| {
            let lo = p[0][1].min(p[1][1]).min(p[2][1]) - f64::from(span.row0) - 1.0;
            let hi = p[0][1].max(p[1][1]).max(p[2][1]) - f64::from(span.row0) + 1.0;
            (lo, hi)
        })
        .collect();
    let (mut max, mut sum2, mut count) = (0.0f64, 0.0f64, 0u64);
    let mut heights = Vec::new();
    let mut seen = Vec::new();
    let mut j0 = 0usize;
    while j0 < nr {
        let j1 = (j0 + strip_rows).min(nr);
        read(span.row0 + j0 as u32, span.row0 + j1 as u32 - 1, &mut heights).map_err(StripError::Read)?;
        if heights.len() != (j1 - j0) * nc {
            return Err(StripError::Tin(TinError::SizeMismatch {
                heights: heights.len(),
                cols: nc,
                rows: j1 - j0,
            }));
        }
        seen.clear();
        seen.resize((j1 - j0) * nc, false);
        let mut strip_sum = 0.0f64;
        for (p, &(lo, hi)) in tris.iter().zip(&row_range) {
            // NaN ranges (a missing vertex) still go to the scan, which skips them.
            if hi < j0 as f64 || lo > j1 as f64 {
                continue;
            }
            scan_triangle_rows(*p, &xs, &ys, j0..j1, |i, j, z| {
                let k = (j - j0) * nc + i;
                if !seen[k] {
                    seen[k] = true;
                    let e = (f64::from(heights[k]) - z).abs();
                    max = max.max(e);
                    strip_sum += e * e;
                    count += 1;
                }
            });
        }
        sum2 += strip_sum;
        j0 = j1;
    }
    let total = (nc * nr) as u64;
    if count != total {
        return Err(StripError::Tin(TinError::Uncovered { missing: total - count, total }));
    }
    Ok(ErrorFigures { max, rms: (sum2 / total as f64).sqrt(), gap: 0.0 })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::tiling::{Pyramid, TileKey};

    /// A deterministic rough terrain: a few sines plus hashed noise.
    fn terrain(w: u32, h: u32, seed: u64) -> Vec<f32> {
        let mut out = Vec::with_capacity((w * h) as usize);
        for r in 0..h {
            for c in 0..w {
                let (x, y) = (f64::from(c), f64::from(r));
                let mut v = 40.0 * (x / 23.0).sin() * (y / 31.0).cos() + 15.0 * ((x + 2.0 * y) / 9.0).sin();
                let mut s = seed ^ (u64::from(c) << 32 | u64::from(r));
                s = s.wrapping_mul(0x9E37_79B9_7F4A_7C15);
                s ^= s >> 29;
                v += (s % 1000) as f64 / 500.0;
                out.push(v as f32);
            }
        }
        out
    }

    fn grid(w: u32, h: u32) -> NodeGrid {
        NodeGrid { cols: (0..w).collect(), rows: (0..h).collect() }
    }

    fn positions(g: &NodeGrid, heights: &[f32], tin: &Tin) -> Vec<[f64; 3]> {
        tin.vertices
            .iter()
            .map(|&[i, j]| {
                let z = heights[j as usize * g.cols.len() + i as usize];
                [f64::from(g.cols[i as usize]), f64::from(g.rows[j as usize]), f64::from(z)]
            })
            .collect()
    }

    #[test]
    fn strips_measure_what_the_whole_span_measures() {
        for (w, h, e) in [(65, 65, 0.5), (100, 37, 2.0), (33, 2, 0.1), (129, 97, 1.0)] {
            let hs = terrain(w, h, 3);
            let g = grid(w, h);
            let tin = build(&g, &hs, e).unwrap();
            let span = Span { col0: 0, col1: w - 1, row0: 0, row1: h - 1 };
            let pos = positions(&g, &hs, &tin);
            let whole = measure_vertical(&pos, &tin.triangles, span, &hs).unwrap();
            for strip in [1usize, 7 * w as usize, 10 * w as usize + 3, usize::MAX] {
                let mut reads = Vec::new();
                let s = measure_vertical_strips(&pos, &tin.triangles, span, strip, |r0, r1, out| {
                    reads.push((r0, r1));
                    out.clear();
                    out.extend_from_slice(&hs[(r0 * w) as usize..((r1 + 1) * w) as usize]);
                    Ok::<(), ()>(())
                })
                .unwrap();
                // Every row read exactly once, in order.
                assert_eq!(reads.first().unwrap().0, 0);
                assert_eq!(reads.last().unwrap().1, h - 1);
                assert!(reads.windows(2).all(|p| p[1].0 == p[0].1 + 1));
                assert_eq!(s.max.to_bits(), whole.max.to_bits(), "{w}×{h} strip {strip}");
                assert!((s.rms - whole.rms).abs() <= 1e-12 * whole.rms.max(1e-300), "{w}×{h} strip {strip}");
                if strip == usize::MAX {
                    assert_eq!(s.rms.to_bits(), whole.rms.to_bits());
                }
            }
        }
    }

    #[test]
    fn max_error_holds_at_every_sample() {
        for (w, h, e) in [(65, 65, 0.5), (100, 37, 2.0), (2, 2, 0.0), (33, 2, 0.1), (40, 40, 0.0)] {
            let hs = terrain(w, h, 7);
            let g = grid(w, h);
            let tin = build(&g, &hs, e).unwrap();
            let span = Span { col0: 0, col1: w - 1, row0: 0, row1: h - 1 };
            let err = measure_vertical(&positions(&g, &hs, &tin), &tin.triangles, span, &hs).unwrap();
            assert!(err.max <= e + 1e-9, "{w}×{h} at {e}: measured {}", err.max);
            assert!(err.rms <= err.max);
        }
    }

    #[test]
    fn split_regions_keep_the_bound_and_tile_the_node() {
        let (w, h, e) = (150, 121, 0.5);
        let hs = terrain(w, h, 11);
        let g = grid(w, h);
        let span = Span { col0: 0, col1: w - 1, row0: 0, row1: h - 1 };
        let whole = build_split(&g, &hs, e, [usize::MAX; 2], 0.0, true).unwrap();
        let split = build_split(&g, &hs, e, [2_000, usize::MAX], 0.0, true).unwrap();
        assert_ne!(whole, split, "the small threshold must split the node");
        for tin in [&whole, &split] {
            let pos = positions(&g, &hs, tin);
            let err = measure_vertical(&pos, &tin.triangles, span, &hs).unwrap();
            assert!(err.max <= e + 1e-9, "measured {}", err.max);
            // Triangles tile the rectangle: no overlap (areas add up) and no duplicate vertex.
            let area: f64 = tin
                .triangles
                .iter()
                .map(|t| {
                    let [a, b, c] = t.map(|k| pos[k as usize]);
                    ((b[0] - a[0]) * (c[1] - a[1]) - (c[0] - a[0]) * (b[1] - a[1])) / 2.0
                })
                .sum();
            assert!((area - f64::from((w - 1) * (h - 1))).abs() < 1e-6, "area {area}");
            let mut vs = tin.vertices.clone();
            vs.sort_unstable();
            vs.dedup();
            assert_eq!(vs.len(), tin.vertices.len());
        }
        let ratio = split.vertices.len() as f64 / whole.vertices.len() as f64;
        assert!((0.9..1.1).contains(&ratio), "{} vs {}", split.vertices.len(), whole.vertices.len());
    }

    #[test]
    fn local_splits_keep_the_bound_and_the_vertex_count() {
        // Dense data (fine bound): split into cache-sized regions, same bound, about the same
        // vertex count as one region; the split never depends on the thread count.
        let (w, h, e) = (200, 180, 0.3);
        let hs = terrain(w, h, 5);
        let g = grid(w, h);
        let span = Span { col0: 0, col1: w - 1, row0: 0, row1: h - 1 };
        let whole = build_split(&g, &hs, e, [usize::MAX; 2], 0.0, true).unwrap();
        let local = build(&g, &hs, e).unwrap();
        assert_ne!(whole, local, "dense data must be split locally");
        let err = measure_vertical(&positions(&g, &hs, &local), &local.triangles, span, &hs).unwrap();
        assert!(err.max <= e + 1e-9, "measured {}", err.max);
        let ratio = local.vertices.len() as f64 / whole.vertices.len() as f64;
        assert!((0.97..1.03).contains(&ratio), "{} vs {}", local.vertices.len(), whole.vertices.len());
        let one = rayon::ThreadPoolBuilder::new().num_threads(1).build().unwrap();
        assert_eq!(one.install(|| build(&g, &hs, e).unwrap()), local);
        // Smooth data is not cut into pieces: a large flat node stays two triangles, a plane too.
        let flat = build(&grid(300, 250), &vec![7.0; 300 * 250], 0.01).unwrap();
        assert_eq!((flat.vertices.len(), flat.triangles.len()), (4, 2));
        let plane: Vec<f32> =
            (0..300 * 250).map(|k| (k % 300) as f32 * 0.5 + (k / 300) as f32 * 0.25).collect();
        let tin = build(&grid(300, 250), &plane, 0.01).unwrap();
        assert_eq!((tin.vertices.len(), tin.triangles.len()), (4, 2));
    }

    #[test]
    fn flat_terrain_needs_only_corners() {
        let g = grid(50, 30);
        let tin = build(&g, &vec![3.0; 50 * 30], 0.01).unwrap();
        assert_eq!(tin.vertices.len(), 4);
        assert_eq!(tin.triangles.len(), 2);
    }

    #[test]
    fn neighbour_tiles_share_border_vertices() {
        let (w, h) = (300, 260);
        let hs = terrain(w, h, 3);
        let p = Pyramid::new(w, h, 64).unwrap();
        let tin_of = |key: TileKey| {
            let g = p.grid(key);
            let mut vals = Vec::new();
            for &r in &g.rows {
                for &c in &g.cols {
                    vals.push(hs[(r * w + c) as usize]);
                }
            }
            let tin = build(&g, &vals, 1.0).unwrap();
            let pts: Vec<(u32, u32)> =
                tin.vertices.iter().map(|&[i, j]| (g.cols[i as usize], g.rows[j as usize])).collect();
            pts
        };
        for z in 0..=p.depth {
            let (nx, ny) = p.nodes_at(z);
            for y in 0..ny {
                for x in 0..nx {
                    let a = tin_of(TileKey::new(z, x, y));
                    if x + 1 < nx {
                        let b = tin_of(TileKey::new(z, x + 1, y));
                        let edge = p.span(TileKey::new(z, x, y)).col1;
                        let mut ea: Vec<_> = a.iter().filter(|v| v.0 == edge).collect();
                        let mut eb: Vec<_> = b.iter().filter(|v| v.0 == edge).collect();
                        ea.sort();
                        eb.sort();
                        assert_eq!(ea, eb, "vertical edge at z={z} x={x} y={y}");
                    }
                    if y + 1 < ny {
                        let b = tin_of(TileKey::new(z, x, y + 1));
                        let edge = p.span(TileKey::new(z, x, y)).row1;
                        let mut ea: Vec<_> = a.iter().filter(|v| v.1 == edge).collect();
                        let mut eb: Vec<_> = b.iter().filter(|v| v.1 == edge).collect();
                        ea.sort();
                        eb.sort();
                        assert_eq!(ea, eb, "horizontal edge at z={z} x={x} y={y}");
                    }
                }
            }
        }
    }

    #[test]
    fn deterministic() {
        let hs = terrain(129, 129, 11);
        let g = grid(129, 129);
        assert_eq!(build(&g, &hs, 0.7).unwrap(), build(&g, &hs, 0.7).unwrap());
    }

    #[test]
    fn rejects_bad_input() {
        let g = grid(3, 3);
        assert!(matches!(build(&g, &[0.0; 8], 1.0), Err(TinError::SizeMismatch { .. })));
        assert!(matches!(build(&g, &[0.0; 9], -1.0), Err(TinError::BadMaxError(_))));
        let mut hs = [0.0f32; 9];
        hs[4] = f32::NAN;
        assert!(matches!(build(&g, &hs, 1.0), Err(TinError::NonFinite { col: 1, row: 1 })));
    }

    #[test]
    fn profile_simplification_bounds_error() {
        let prof: Vec<(f64, f64)> =
            (0..200).map(|k| (f64::from(k), (f64::from(k) / 7.0).sin() * 10.0)).collect();
        let keep = simplify_profile(&prof, 0.25);
        assert_eq!(keep.first(), Some(&0));
        assert_eq!(keep.last(), Some(&199));
        for w in keep.windows(2) {
            let (a, b) = (prof[w[0]], prof[w[1]]);
            for &(t, h) in &prof[w[0]..=w[1]] {
                let z = a.1 + (b.1 - a.1) * (t - a.0) / (b.0 - a.0);
                assert!((h - z).abs() <= 0.25 + 1e-12);
            }
        }
    }

    #[test]
    fn uncovered_samples_are_reported() {
        let pos = [[0.0, 0.0, 0.0], [4.0, 0.0, 0.0], [0.0, 4.0, 0.0]];
        let span = Span { col0: 0, col1: 4, row0: 0, row1: 4 };
        let err = measure_vertical(&pos, &[[0, 1, 2]], span, &[0.0; 25]).unwrap_err();
        assert!(matches!(err, TinError::Uncovered { missing: 10, total: 25 }));
    }

    /// Integer scans (edge walks and the per-sample test of tiny faces) find the very same
    /// meshes as the float scan, on flat and curved surfaces, regular grids of unit and wider
    /// steps, tie-heavy (rounded) heights and coarse to fine bounds.
    #[test]
    fn integer_scans_build_the_float_scans_meshes() {
        for (w, h, step, seed) in [(65, 65, 1, 1), (100, 37, 1, 2), (33, 129, 3, 3), (80, 80, 2, 4)] {
            let g = NodeGrid {
                cols: (0..w).map(|k| 7 + k * step).collect(),
                rows: (0..h).map(|k| k * step).collect(),
            };
            for rounded in [false, true] {
                let mut hs = terrain(w, h, seed);
                if rounded {
                    for v in &mut hs {
                        *v = (*v / 4.0).round() * 4.0;
                    }
                }
                for (e, chord) in [(0.2, 0.0), (2.0, 0.0), (8.0, 0.0), (2.0, 1e-3), (0.5, 0.05)] {
                    let split = [REGION_SPLIT_SAMPLES, LOCAL_SPLIT_SAMPLES];
                    let int = build_split(&g, &hs, e, split, chord, true).unwrap();
                    let float = build_split(&g, &hs, e, split, chord, false).unwrap();
                    assert!(int.vertices.len() > 4, "{w}×{h} at {e}: too coarse to test anything");
                    assert_eq!(
                        int, float,
                        "{w}×{h} step {step}, rounded {rounded}, error {e}, chord {chord}"
                    );
                }
            }
        }
    }

    proptest::proptest! {
        /// On regular axes (any start, any step), a triangle whose corners are samples gets
        /// exactly the float scan's rows from the integer edge walk: the same samples and the
        /// same plane heights bit for bit, whole or restricted to some rows; thin, flat and
        /// degenerate triangles included.
        #[test]
        fn integer_and_float_spans_agree(
            v in proptest::collection::vec((0u32..30, 0u32..30, -50.0f64..50.0), 3),
            start in 0u32..1000,
            (sx, sy) in (1u32..4, 1u32..4),
            inner: bool,
            limit in proptest::sample::select(vec![0usize, 48, usize::MAX]),
            (r0, r1) in (0usize..30, 0usize..31),
        ) {
            let cols: Vec<u32> = (0..30).map(|k| start + k * sx).collect();
            let rows: Vec<u32> = (0..30).map(|k| start / 2 + k * sy).collect();
            let (xs, ys) = (Axis::of(&cols), Axis::of(&rows));
            proptest::prop_assert!(xs.uniform() && ys.uniform());
            let ij: [[u32; 2]; 3] = std::array::from_fn(|k| [v[k].0, v[k].1]);
            let p: [[f64; 3]; 3] = std::array::from_fn(|k| [xs.at(v[k].0 as usize), ys.at(v[k].1 as usize), v[k].2]);
            for rows in [0..usize::MAX, r0..r1] {
                let collect = |ij| {
                    let mut out = Vec::new();
                    scan_spans_in(p, ij, &xs, &ys, inner, limit, rows.clone(), |s| {
                        out.extend((s.i0..s.i1).map(|i| (i, s.j, s.z(xs.at(i)).to_bits())));
                    });
                    out
                };
                proptest::prop_assert_eq!(collect(Some(ij)), collect(None));
            }
        }

        /// The per-sample box test and the row-span walk visit the same samples with the same
        /// plane heights, for triangles on and off the sample grid and a clipped last column.
        #[test]
        fn box_and_span_scans_agree(
            v in proptest::collection::vec((0u32..40, 0u32..40, -50.0f64..50.0), 3),
            off in proptest::collection::vec(-1.0f64..1.0, 6),
            on_grid: bool,
            inner: bool,
        ) {
            let cols: Vec<u32> = (0..20).map(|k| k * 2).chain([39]).collect();
            let rows: Vec<u32> = (0..=40).collect();
            let (xs, ys) = (Axis::of(&cols), Axis::of(&rows));
            let p: [[f64; 3]; 3] = std::array::from_fn(|k| {
                let (x, y, z) = v[k];
                let d = if on_grid { (0.0, 0.0) } else { (off[2 * k], off[2 * k + 1]) };
                [f64::from(x) + d.0, f64::from(y) + d.1, z]
            });
            let collect = |limit| {
                let mut out = Vec::new();
                scan_spans(p, &xs, &ys, inner, limit, 0..usize::MAX, |s| {
                    out.extend((s.i0..s.i1).map(|i| (i, s.j, s.z(xs.at(i)))));
                });
                out
            };
            let (boxed, spans) = (collect(usize::MAX), collect(0));
            proptest::prop_assert_eq!(boxed.len(), spans.len());
            for (a, b) in boxed.iter().zip(&spans) {
                proptest::prop_assert_eq!((a.0, a.1), (b.0, b.1));
                proptest::prop_assert!((a.2 - b.2).abs() <= 1e-9 * (1.0 + a.2.abs()));
            }
        }

        /// A triangle whose corners are samples scans the very same spans whether its box comes
        /// from the corners' indices or from their positions on the axes (a clipped last column
        /// included).
        #[test]
        fn index_and_position_boxes_agree(
            v in proptest::collection::vec((0usize..21, 0usize..41, -50.0f64..50.0), 3),
            inner: bool,
            limit in proptest::sample::select(vec![0usize, 48, usize::MAX]),
        ) {
            let cols: Vec<u32> = (0..20).map(|k| k * 2).chain([39]).collect();
            let rows: Vec<u32> = (0..=40).collect();
            let (xs, ys) = (Axis::of(&cols), Axis::of(&rows));
            let p: [[f64; 3]; 3] = std::array::from_fn(|k| [xs.at(v[k].0), ys.at(v[k].1), v[k].2]);
            let ij: [[u32; 2]; 3] = std::array::from_fn(|k| [v[k].0 as u32, v[k].1 as u32]);
            let collect = |ij| {
                let mut out = Vec::new();
                scan_spans_in(p, ij, &xs, &ys, inner, limit, 0..usize::MAX, |s| {
                    out.extend((s.i0..s.i1).map(|i| (i, s.j, s.z(xs.at(i)).to_bits())));
                });
                out
            };
            proptest::prop_assert_eq!(collect(Some(ij)), collect(None));
        }
    }
}
