//! Error measurement of a point level against the mesh it was baked from (see
//! [`measure_points`] for the definitions). Uniform hash grids of triangles and of
//! points make the nearest-item queries local: each query visits rings of grid cells around
//! itself, nearest first, and stops as soon as nothing outside the visited box can be closer.
//! A heightfield (a terrain TIN) is gridded in columns rather than cubes, and each triangle is
//! bounded by its box before its exact distance is taken; neither changes a result.

use glam::DVec3;

// FxHash: cell keys come from geometry, not from a network, so SipHash's resistance to
// adversarial keys is not needed, and it costs several times the rest of a lookup.
use crate::geom::{Bounds, ErrorFigures, Mesh, PointCloud};
use rustc_hash::FxHashMap as FastMap;

/// Cap on the grid cells all triangle bounding boxes may cover together, as a multiple of the
/// item count (with a floor): a mesh of few huge triangles measured at a tiny `cell` would
/// otherwise fill memory with bounding-box cells; the grid is coarsened instead.
const GRID_BUDGET_PER_ITEM: f64 = 8.0;
const GRID_BUDGET_MIN: f64 = (1u64 << 20) as f64;

/// Queries whose cell index would exceed this (absurdly far from the mesh) are answered by a
/// linear scan instead of ring search, so index arithmetic never overflows.
const MAX_QUERY_INDEX: f64 = (1u64 << 40) as f64;

type V3 = DVec3;

/// Squared distance from `p` to segment `ab` (a point when a == b).
fn segment_dist2(p: V3, a: V3, b: V3) -> f64 {
    let ab = b - a;
    let len2 = ab.dot(ab);
    let t = if len2 > 0.0 { ((p - a).dot(ab) / len2).clamp(0.0, 1.0) } else { 0.0 };
    p.distance_squared(a + ab * t)
}

/// Squared distance from `p` to the closed triangle `t` (Ericson, Real-Time Collision
/// Detection §5.1.5). Degenerate triangles (collinear or coincident vertices) divide by zero in
/// that method, so they are measured as their three edges instead.
pub(crate) fn point_triangle_dist2(p: V3, t: &[V3; 3]) -> f64 {
    let [a, b, c] = *t;
    let ab = b - a;
    let ac = c - a;
    let n = ab.cross(ac);
    let n2 = n.dot(n);
    if n2 <= 1e-24 * ab.dot(ab) * ac.dot(ac) || !n2.is_finite() {
        return segment_dist2(p, a, b).min(segment_dist2(p, b, c)).min(segment_dist2(p, c, a));
    }
    let ap = p - a;
    let d1 = ab.dot(ap);
    let d2 = ac.dot(ap);
    if d1 <= 0.0 && d2 <= 0.0 {
        return p.distance_squared(a);
    }
    let bp = p - b;
    let d3 = ab.dot(bp);
    let d4 = ac.dot(bp);
    if d3 >= 0.0 && d4 <= d3 {
        return p.distance_squared(b);
    }
    let vc = d1 * d4 - d3 * d2;
    if vc <= 0.0 && d1 >= 0.0 && d3 <= 0.0 {
        return p.distance_squared(a + ab * (d1 / (d1 - d3)));
    }
    let cp = p - c;
    let d5 = ab.dot(cp);
    let d6 = ac.dot(cp);
    if d6 >= 0.0 && d5 <= d6 {
        return p.distance_squared(c);
    }
    let vb = d5 * d2 - d1 * d6;
    if vb <= 0.0 && d2 >= 0.0 && d6 <= 0.0 {
        return p.distance_squared(a + ac * (d2 / (d2 - d6)));
    }
    let va = d3 * d6 - d5 * d4;
    if va <= 0.0 && (d4 - d3) >= 0.0 && (d5 - d6) >= 0.0 {
        return p.distance_squared(b + (c - b) * ((d4 - d3) / ((d4 - d3) + (d5 - d6))));
    }
    let denom = 1.0 / (va + vb + vc);
    let q = (a + ab * (vb * denom)) + ac * (vc * denom);
    p.distance_squared(q)
}

/// `⌊x⌋`, by a truncating cast where that is exact: `f64::floor` is a libm call on baseline
/// x86-64, and this runs three times per query.
#[inline]
fn floor(x: f64) -> f64 {
    if x.abs() < 4_503_599_627_370_496.0 {
        let t = x as i64 as f64;
        if t > x { t - 1.0 } else { t }
    } else {
        x
    }
}

/// A grid cell index; hashed as three words (the array's own `Hash` goes through a byte
/// slice, several times slower).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
struct GridKey([i64; 3]);

impl std::hash::Hash for GridKey {
    #[inline]
    fn hash<H: std::hash::Hasher>(&self, state: &mut H) {
        state.write_u64(self.0[0] as u64);
        state.write_u64(self.0[1] as u64);
        state.write_u64(self.0[2] as u64);
    }
}

/// A sparse uniform grid: items listed per cell in one flat array (CSR), so building it costs
/// one sort instead of one allocation per cell.
struct HashGrid {
    origin: V3,
    /// Cell edge per axis: a cube, or for a heightfield columns one layer tall (see
    /// [`cell_edges`]).
    h: V3,
    /// Cell → range in `items`.
    cells: FastMap<GridKey, (u32, u32)>,
    /// The same ranges as a dense array over the occupied box, when that box is small enough
    /// (terrain tiles): an index computation instead of a hash look-up per visited cell.
    dense: Option<Vec<(u32, u32)>>,
    items: Vec<u32>,
    /// Inclusive index box of the occupied cells.
    lo: [i64; 3],
    hi: [i64; 3],
}

impl HashGrid {
    #[inline]
    fn coord(origin: V3, h: V3, p: V3) -> [f64; 3] {
        [floor((p[0] - origin[0]) / h[0]), floor((p[1] - origin[1]) / h[1]), floor((p[2] - origin[2]) / h[2])]
    }

    /// Builds from (item, inclusive index box) pairs.
    fn build(origin: V3, h: V3, boxes: impl Iterator<Item = (u32, [i64; 3], [i64; 3])>) -> Self {
        let boxes: Vec<(u32, [i64; 3], [i64; 3])> = boxes.collect();
        let mut lo = [i64::MAX; 3];
        let mut hi = [i64::MIN; 3];
        let mut pairs_len = 0u64;
        for (_, a, b) in &boxes {
            for d in 0..3 {
                lo[d] = lo[d].min(a[d]);
                hi[d] = hi[d].max(b[d]);
            }
            pairs_len += (0..3).map(|d| (b[d] - a[d] + 1).max(0) as u64).product::<u64>();
        }
        let dims: Vec<u64> = (0..3).map(|d| (hi[d] - lo[d] + 1).max(0) as u64).collect();
        let volume = dims.iter().product::<u64>();
        let each_cell = |a: &[i64; 3], b: &[i64; 3], f: &mut dyn FnMut([i64; 3])| {
            for z in a[2]..=b[2] {
                for y in a[1]..=b[1] {
                    for x in a[0]..=b[0] {
                        f([x, y, z]);
                    }
                }
            }
        };
        if !boxes.is_empty() && volume <= (4 * pairs_len).max(1 << 16) {
            // Dense: a counting sort over the occupied box, no hashing and no comparison sort.
            let index = |c: [i64; 3]| {
                (((c[2] - lo[2]) as u64 * dims[1] + (c[1] - lo[1]) as u64) * dims[0] + (c[0] - lo[0]) as u64)
                    as usize
            };
            let mut start = vec![0u32; volume as usize + 1];
            for (_, a, b) in &boxes {
                each_cell(a, b, &mut |c| start[index(c) + 1] += 1);
            }
            for k in 1..start.len() {
                start[k] += start[k - 1];
            }
            let mut fill = start.clone();
            let mut items = vec![0u32; pairs_len as usize];
            for (item, a, b) in &boxes {
                each_cell(a, b, &mut |c| {
                    let slot = &mut fill[index(c)];
                    items[*slot as usize] = *item;
                    *slot += 1;
                });
            }
            let dense = start.windows(2).map(|w| (w[0], w[1])).collect();
            return Self { origin, h, cells: FastMap::default(), dense: Some(dense), items, lo, hi };
        }
        let mut pairs: Vec<([i64; 3], u32)> = Vec::with_capacity(pairs_len as usize);
        for (item, a, b) in &boxes {
            each_cell(a, b, &mut |c| pairs.push((c, *item)));
        }
        pairs.sort_unstable();
        let mut cells = FastMap::default();
        cells.reserve(pairs.len() / 2 + 1);
        let mut items = Vec::with_capacity(pairs.len());
        let mut start = 0usize;
        while start < pairs.len() {
            let key = pairs[start].0;
            let mut end = start;
            while end < pairs.len() && pairs[end].0 == key {
                items.push(pairs[end].1);
                end += 1;
            }
            cells.insert(GridKey(key), (start as u32, end as u32));
            start = end;
        }
        Self { origin, h, cells, dense: None, items, lo, hi }
    }

    fn is_empty(&self) -> bool {
        self.items.is_empty()
    }

    /// Smallest `q.distance_squared(item)` over all items, found by ring search, and the item. Returns
    /// early, with some value ≤ `stop2`, as soon as an item within `sqrt(stop2)` is found (pass
    /// 0 for the exact nearest). `dist2(item, best)` measures one item, and may return any value
    /// ≥ `best` for an item it can tell is no nearer than `best` (a cheap bound first); `all` is
    /// the item count, for the linear fallback. `init` is a known (distance², item) pair to
    /// start from, such as the answer for a nearby query (`(f64::INFINITY, u32::MAX)` for
    /// none): the search then only looks for something nearer, and returns `init` when
    /// nothing is. The item is `u32::MAX` when there are none.
    fn nearest2(
        &self,
        q: V3,
        stop2: f64,
        all: u32,
        init: (f64, u32),
        dist2: impl Fn(u32, f64) -> f64,
    ) -> (f64, u32) {
        let mut best = init;
        if self.is_empty() || best.0 <= stop2 {
            return best;
        }
        let consider = |best: &mut (f64, u32), item: u32| {
            let d = dist2(item, best.0);
            if d < best.0 {
                *best = (d, item);
            }
        };
        let c = Self::coord(self.origin, self.h, q);
        if c.iter().any(|v| !v.is_finite() || v.abs() > MAX_QUERY_INDEX) {
            (0..all).for_each(|item| consider(&mut best, item));
            return best;
        }
        // Rings are centred on the occupied cell nearest the query: rings around any centre
        // partition the cells, and the bound below holds for any centre, so this only saves
        // the empty rings between a query outside the box and the box (and keeps a query above
        // a one-layer grid on its layer).
        let c: [i64; 3] = std::array::from_fn(|d| (c[d] as i64).clamp(self.lo[d], self.hi[d]));
        let mut r = 0;
        loop {
            self.visit_ring(c, r, |item| consider(&mut best, item));
            if best.0 <= stop2 {
                return best;
            }
            // Everything not yet visited lies outside the box of rings 0..=r: bound its distance
            // by the nearest face of that box that does not already contain the occupied box.
            let mut bound = f64::INFINITY;
            let mut covered = true;
            for d in 0..3 {
                if c[d] - r > self.lo[d] {
                    covered = false;
                    bound = bound.min(q[d] - (self.origin[d] + (c[d] - r) as f64 * self.h[d]));
                }
                if c[d] + r < self.hi[d] {
                    covered = false;
                    bound = bound.min(self.origin[d] + (c[d] + r + 1) as f64 * self.h[d] - q[d]);
                }
            }
            if covered {
                return best;
            }
            let bound = bound.max(0.0);
            if best.0 <= bound * bound {
                return best;
            }
            r += 1;
        }
    }

    /// Calls `f` for every item in the cells at Chebyshev distance exactly `r` from `c`,
    /// restricted to the occupied box.
    fn visit_ring(&self, c: [i64; 3], r: i64, mut f: impl FnMut(u32)) {
        let z0 = (c[2] - r).max(self.lo[2]);
        let z1 = (c[2] + r).min(self.hi[2]);
        let y0 = (c[1] - r).max(self.lo[1]);
        let y1 = (c[1] + r).min(self.hi[1]);
        let x0 = (c[0] - r).max(self.lo[0]);
        let x1 = (c[0] + r).min(self.hi[0]);
        let (nx, ny) = (self.hi[0] - self.lo[0] + 1, self.hi[1] - self.lo[1] + 1);
        let mut cell = |x: i64, y: i64, z: i64| {
            let range = match &self.dense {
                // Ring cells are clamped to the occupied box, so the index is in range.
                Some(d) => d
                    .get((((z - self.lo[2]) * ny + (y - self.lo[1])) * nx + (x - self.lo[0])) as usize)
                    .copied(),
                None => self.cells.get(&GridKey([x, y, z])).copied(),
            };
            if let Some((s, e)) = range {
                for &item in &self.items[s as usize..e as usize] {
                    f(item);
                }
            }
        };
        for z in z0..=z1 {
            let z_on = (z - c[2]).abs() == r;
            for y in y0..=y1 {
                if z_on || (y - c[1]).abs() == r {
                    for x in x0..=x1 {
                        cell(x, y, z);
                    }
                } else {
                    // Interior of the shell's cross-section: only its two x walls.
                    if c[0] - r >= x0 {
                        cell(c[0] - r, y, z);
                    }
                    if r > 0 && c[0] + r <= x1 {
                        cell(c[0] + r, y, z);
                    }
                }
            }
        }
    }
}

/// Valid triangles of `mesh` (indices in range, coordinates finite) as vertex triples, with
/// which of their edges `(v0, v1)`, `(v1, v2)`, `(v2, v0)` they own for gap sampling. An edge
/// shared by two triangles is sampled once: by the triangle where it runs from the smaller
/// vertex index to the larger, or by every triangle holding it when no triangle runs it that
/// way (a border edge, or inconsistent orientation).
fn valid_triangles(mesh: &Mesh) -> Vec<([V3; 3], [bool; 3])> {
    let valid: Vec<([u32; 3], [V3; 3])> = mesh
        .triangles
        .iter()
        .filter_map(|t| {
            let v = [
                DVec3::from_array(*mesh.positions.get(t[0] as usize)?),
                DVec3::from_array(*mesh.positions.get(t[1] as usize)?),
                DVec3::from_array(*mesh.positions.get(t[2] as usize)?),
            ];
            v.iter().all(|c| c.is_finite()).then_some((*t, v))
        })
        .collect();
    let edge = |a: u32, b: u32| (u64::from(a) << 32) | u64::from(b);
    let mut rising: Vec<u64> = valid
        .iter()
        .flat_map(|(t, _)| [(t[0], t[1]), (t[1], t[2]), (t[2], t[0])])
        .filter(|(a, b)| a < b)
        .map(|(a, b)| edge(a, b))
        .collect();
    rising.sort_unstable();
    valid
        .into_iter()
        .map(|(t, v)| {
            let owns = |a: u32, b: u32| a < b || rising.binary_search(&edge(b, a)).is_err();
            (v, [owns(t[0], t[1]), owns(t[1], t[2]), owns(t[2], t[0])])
        })
        .collect()
}

/// Most samples along one edge or row of [`sample_triangle`].
const MAX_SEGMENTS: u64 = 1 << 20;

/// Calls `f` with surface samples of triangle `t` at spacing ≤ `s`: points along the edges
/// it owns (its vertices excluded: the caller samples every mesh vertex once) and rows parallel to its longest edge, one row per ≤ `s`
/// of height, each sampled at ≤ `s`. Rows parallel to the longest edge keep slivers cheap: the
/// count grows with area/s² + perimeter/s, not with (longest edge/s)².
fn sample_triangle(t: &[V3; 3], owned: [bool; 3], s: f64, mut f: impl FnMut(V3)) {
    // Never unbounded: a length that is not finite, or an absurd ratio, is sampled at the cap
    // (inputs are limited long before it: `raster::MAX_RELIEF_CELLS`, tile sizes).
    let segments = |len: f64| {
        let n = (len / s).ceil();
        if n.is_finite() { n.clamp(1.0, MAX_SEGMENTS as f64) as u64 } else { 1 }
    };
    let mut edge_len = [0.0; 3];
    for e in 0..3 {
        let a = t[e];
        let d = t[(e + 1) % 3] - a;
        edge_len[e] = d.dot(d).sqrt();
        if owned[e] {
            // Endpoints are mesh vertices, which the caller samples once each.
            let n = segments(edge_len[e]);
            for i in 1..n {
                f(a + d * (i as f64 / n as f64));
            }
        }
    }
    // Longest edge e: p0 → p1, apex opposite.
    let e = (0..3).fold(0, |m, i| if edge_len[i] > edge_len[m] { i } else { m });
    let (p0, p1, apex) = (t[e], t[(e + 1) % 3], t[(e + 2) % 3]);
    let len = edge_len[e];
    if len <= 0.0 {
        return;
    }
    let height = (p1 - p0).cross(apex - p0);
    let height = height.dot(height).sqrt() / len;
    let rows = segments(height);
    // Row 0 is the longest edge, sampled above; the last row degenerates to the apex.
    for j in 1..rows {
        let w = j as f64 / rows as f64;
        let a = p0 + (apex - p0) * w;
        let b = p1 + (apex - p1) * w;
        let d = b - a;
        let n = segments((1.0 - w) * len);
        for i in 0..=n {
            f(a + d * (i as f64 / n as f64));
        }
    }
}

/// Most triangles, as a fraction, that may face against the rest for a mesh to be measured
/// as a heightfield.
const HEIGHTFIELD_AGAINST: f64 = 0.01;

/// The grids' layer height when `tris` form a heightfield (a terrain TIN: all triangles face
/// one way along z, give or take [`HEIGHTFIELD_AGAINST`]; vertical ones, such as skirts, face
/// neither): the whole z extent, so each grid cell is a column over the surface, holding the
/// few triangles (or points) there. A cubic grid would spread such a surface over many
/// layers, and a query would search them all in every ring it visits. `None` otherwise
/// (models). Either grid gives the same distances; this only decides how fast.
fn heightfield_layer(tris: &[([V3; 3], [bool; 3])], bounds: &Bounds) -> Option<f64> {
    let (mut up, mut down) = (0usize, 0usize);
    for ([a, b, c], _) in tris {
        let n = (*b - *a).cross(*c - *a);
        let tol = 1e-9 * n.length();
        if n.z > tol {
            up += 1;
        } else if n.z < -tol {
            down += 1;
        }
    }
    let extent = bounds.size().z;
    (up.min(down) as f64 <= HEIGHTFIELD_AGAINST * tris.len() as f64 && extent.is_finite()).then_some(extent)
}

/// Grid cell edges for a horizontal edge `h`: cubes, or columns of the layer height `column`.
fn cell_edges(h: f64, column: Option<f64>) -> V3 {
    match column {
        Some(z) => DVec3::new(h, h, z.max(h)),
        None => DVec3::splat(h),
    }
}

/// Measures a point level against the mesh it was baked from, in world units:
/// - `max`: the largest distance to the nearest triangle (exact point–triangle distance) from
///   the level *as drawn*: each point and the corners of its footprint, its tangent plane
///   clipped to the cube of half-width `footprint_half · cell` centred on it
///   (the corners reach farthest; where a footprint sticks out past a silhouette or across a
///   thin part, they measure how far);
/// - `rms`: the root mean square of the points' own distances;
/// - `gap`: the largest distance from a surface sample to its nearest point, samples taken on
///   every triangle along its edges (vertices included) and in rows across it at a spacing of
///   at most `cell / 4` — so `gap` is the true value within `cell / 8`.
///
/// Invalid triangles (index out of range, non-finite vertex) and non-finite points are left
/// out. An empty mesh gives zeros; no points give `gap` = the mesh's bounding-box diagonal (the
/// whole surface is a hole). An invalid `cell` (not finite and positive) falls back to
/// 1/256 of that diagonal. Cost grows with the surface area / cell² (the gap samples).
#[must_use]
pub fn measure_points(mesh: &Mesh, points: &PointCloud, cell: f64, footprint_half: f64) -> ErrorFigures {
    let tris = valid_triangles(mesh);
    if tris.is_empty() {
        return ErrorFigures::default();
    }
    let mut bounds = Bounds::empty();
    for (t, _) in &tris {
        for &v in t {
            bounds.extend(v.to_array());
        }
    }
    let diag = bounds.size().length();
    let pts: Vec<V3> =
        points.positions.iter().map(|&p| DVec3::from_array(p)).filter(|p| p.is_finite()).collect();
    if pts.is_empty() {
        return ErrorFigures { max: 0.0, rms: 0.0, gap: diag };
    }

    let base = if cell.is_finite() && cell > 0.0 {
        cell
    } else if diag > 0.0 {
        diag / 256.0
    } else {
        1.0
    };
    let origin = bounds.min;
    let column = heightfield_layer(&tris, &bounds);
    let tri_bounds: Vec<(V3, V3)> =
        tris.iter().map(|([a, b, c], _)| (a.min(*b).min(*c), a.max(*b).max(*c))).collect();
    let tri_box = |(lo, hi): &(V3, V3), h: V3| {
        let a = HashGrid::coord(origin, h, *lo);
        let c = HashGrid::coord(origin, h, *hi);
        ([a[0] as i64, a[1] as i64, a[2] as i64], [c[0] as i64, c[1] as i64, c[2] as i64])
    };
    let budget = (GRID_BUDGET_PER_ITEM * (tris.len() + pts.len()) as f64).max(GRID_BUDGET_MIN);
    // Cells of the level's size, coarsened until the triangle boxes fit the budget. Bounded:
    // h doubles each round, so 2,100 rounds pass the f64 range whatever the input (a NaN count
    // would otherwise never satisfy the test).
    let mut h = base;
    for _ in 0..2100 {
        let edges = cell_edges(h, column);
        let cells: f64 = tri_bounds
            .iter()
            .map(|t| {
                let (a, b) = tri_box(t, edges);
                (0..3).map(|d| (b[d] - a[d] + 1) as f64).product::<f64>()
            })
            .sum();
        if cells <= budget {
            break;
        }
        h *= 2.0;
    }
    let h = cell_edges(h, column);

    let tri_grid = HashGrid::build(
        origin,
        h,
        tri_bounds.iter().enumerate().map(|(i, t)| {
            let (a, b) = tri_box(t, h);
            (i as u32, a, b)
        }),
    );
    let pt_grid = HashGrid::build(
        origin,
        h,
        pts.iter().enumerate().map(|(i, &p)| {
            // Absurdly far points are clamped into a remote cell so indices stay in range; the
            // ring search's bounds are taken from the cells, so queries stay correct.
            let c = HashGrid::coord(origin, h, p).map(|v| v.clamp(-MAX_QUERY_INDEX, MAX_QUERY_INDEX) as i64);
            (i as u32, c, c)
        }),
    );

    // The exact distance of every point (the rms needs each), each search starting from the
    // triangle that answered the point before: level points come in cell order, so that
    // triangle is usually near, and its distance lets the box bound rule out the rest early.
    let nearest = |q: V3, stop2: f64, init: (f64, u32)| {
        tri_grid.nearest2(q, stop2, tris.len() as u32, init, |i, best| {
            // The distance to the triangle's box bounds its own from below, at a fraction
            // of the cost: most triangles in the visited cells are ruled out by it.
            let (lo, hi) = tri_bounds[i as usize];
            let outside = (lo - q).max(q - hi).max(DVec3::ZERO);
            if outside.length_squared() >= best {
                return f64::INFINITY;
            }
            point_triangle_dist2(q, &tris[i as usize].0)
        })
    };
    let from = |q: V3, tri: u32| match tris.get(tri as usize) {
        Some((t, _)) => (point_triangle_dist2(q, t), tri),
        None => (f64::INFINITY, u32::MAX),
    };
    let mut max2 = 0.0f64;
    let mut sum2 = 0.0f64;
    let mut answer = vec![u32::MAX; points.positions.len()];
    let mut last = u32::MAX;
    for (i, &p) in points.positions.iter().enumerate() {
        let p = DVec3::from_array(p);
        if !p.is_finite() {
            continue;
        }
        let (d2, tri) = nearest(p, 0.0, from(p, last));
        max2 = max2.max(d2);
        sum2 += d2;
        answer[i] = tri;
        last = tri;
    }
    // The level as drawn: the footprint's corners reach farthest from the point. They only
    // count toward the max, so a corner with any triangle within the max found so far cannot
    // raise it: its point's triangle is tried first, and a search stops at the first such
    // triangle. The max comes out the same as taking every corner's exact distance.
    let mut corners = Vec::with_capacity(12);
    for (i, &p) in points.positions.iter().enumerate() {
        let p = DVec3::from_array(p);
        if !p.is_finite() {
            continue;
        }
        let n = points
            .normals
            .get(i)
            .map_or(DVec3::Z, |n| DVec3::new(f64::from(n[0]), f64::from(n[1]), f64::from(n[2])));
        super::footprint::footprint_corners(p, n, footprint_half * base, &mut corners);
        for &q in &corners {
            max2 = max2.max(nearest(q, max2, from(q, answer[i])).0);
        }
    }

    // Only samples farther than the current gap can raise it, so each query may stop at the
    // first point within the gap found so far.
    let s = base / 4.0;
    let mut used = vec![false; mesh.positions.len()];
    for t in &mesh.triangles {
        for &v in t {
            if let Some(u) = used.get_mut(v as usize) {
                *u = true;
            }
        }
    }
    // Consecutive samples are close together, so the point that answered the last query very
    // often lies within the gap of the next one too: each search starts from it, which skips
    // most searches, and the result is the same (a sample with a point within the gap cannot
    // raise it).
    // (gap², the point that answered the last sample)
    let mut state = (0.0f64, u32::MAX);
    let gap_sample = |(gap2, last): &mut (f64, u32), q: V3| {
        let init =
            pts.get(*last as usize).map_or((f64::INFINITY, u32::MAX), |&p| (q.distance_squared(p), *last));
        let (d2, item) =
            pt_grid.nearest2(q, *gap2, pts.len() as u32, init, |i, _| q.distance_squared(pts[i as usize]));
        *gap2 = gap2.max(d2);
        *last = item;
    };
    for (q, _) in mesh.positions.iter().zip(&used).filter(|(p, u)| **u && p.iter().all(|c| c.is_finite())) {
        gap_sample(&mut state, DVec3::from_array(*q));
    }
    for (t, owned) in &tris {
        // Distance to a point is convex, so a triangle whose vertices all lie within the gap
        // of one point has every sample within it too: none can raise the gap, and the
        // triangle is skipped whole (with a margin far above the samples' rounding).
        let (gap2, last) = state;
        if pts
            .get(last as usize)
            .is_some_and(|&p| t.iter().all(|v| v.distance_squared(p) <= gap2 * (1.0 - 1e-9)))
        {
            continue;
        }
        sample_triangle(t, *owned, s, |q| gap_sample(&mut state, q));
    }
    let gap2 = state.0;

    ErrorFigures { max: max2.sqrt(), rms: (sum2 / pts.len() as f64).sqrt(), gap: gap2.sqrt() }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn brute_segment_tri(p: V3, t: &[V3; 3]) -> f64 {
        // Dense barycentric sampling: an upper bound converging to the true distance.
        let n = 400;
        let mut best = f64::INFINITY;
        for i in 0..=n {
            for j in 0..=(n - i) {
                let (u, v) = (f64::from(i) / f64::from(n), f64::from(j) / f64::from(n));
                let q = (t[0] + (t[1] - t[0]) * u) + (t[2] - t[0]) * v;
                best = best.min(p.distance_squared(q));
            }
        }
        best.sqrt()
    }

    #[test]
    fn point_triangle_matches_dense_sampling() {
        let t = [[0.0, 0.0, 0.0], [4.0, 0.5, 1.0], [1.0, 3.0, -0.5]].map(DVec3::from_array);
        let probes = [
            [1.0, 1.0, 2.0],
            [-2.0, -1.0, 0.0],
            [5.0, 1.0, 1.0],
            [1.0, 4.0, 0.0],
            [3.0, 3.0, 3.0],
            [2.0, -2.0, 0.0],
            [1.5, 1.0, 0.3],
        ];
        for p in probes.map(DVec3::from_array) {
            let exact = point_triangle_dist2(p, &t).sqrt();
            let approx = brute_segment_tri(p, &t);
            assert!(exact <= approx + 1e-12 && approx - exact < 0.02, "{p:?}: {exact} vs {approx}");
        }
    }

    #[test]
    fn degenerate_triangles_measure_as_segments() {
        let line = [[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [2.0, 0.0, 0.0]].map(DVec3::from_array);
        assert!((point_triangle_dist2(DVec3::new(1.0, 1.0, 0.0), &line) - 1.0).abs() < 1e-12);
        let dot3 = [DVec3::ONE; 3];
        assert!((point_triangle_dist2(DVec3::new(1.0, 1.0, 3.0), &dot3) - 4.0).abs() < 1e-12);
    }

    /// Errors by brute force: every query against every triangle, every gap sample against
    /// every point.
    fn brute(mesh: &Mesh, pc: &PointCloud, cell: f64, half: f64) -> ErrorFigures {
        let tris = valid_triangles(mesh);
        let near = |q: V3| tris.iter().map(|(t, _)| point_triangle_dist2(q, t)).fold(f64::INFINITY, f64::min);
        let (mut max2, mut sum2) = (0.0f64, 0.0f64);
        let mut corners = Vec::new();
        for (p, n) in pc.positions.iter().zip(&pc.normals) {
            let p = DVec3::from_array(*p);
            let d2 = near(p);
            max2 = max2.max(d2);
            sum2 += d2;
            let n = DVec3::new(f64::from(n[0]), f64::from(n[1]), f64::from(n[2]));
            super::super::footprint::footprint_corners(p, n, half * cell, &mut corners);
            for &q in &corners {
                max2 = max2.max(near(q));
            }
        }
        let pts: Vec<V3> = pc.positions.iter().map(|p| DVec3::from_array(*p)).collect();
        let mut gap2 = 0.0f64;
        let mut sample = |q: V3| {
            gap2 = gap2.max(pts.iter().map(|p| p.distance_squared(q)).fold(f64::INFINITY, f64::min));
        };
        for v in &mesh.positions {
            sample(DVec3::from_array(*v));
        }
        for (t, owned) in &tris {
            sample_triangle(t, *owned, cell / 4.0, &mut sample);
        }
        ErrorFigures { max: max2.sqrt(), rms: (sum2 / pts.len() as f64).sqrt(), gap: gap2.sqrt() }
    }

    #[test]
    fn grid_search_matches_brute_force_on_heightfields_and_not() {
        // A rough 12×12 heightfield (relief ten times its cell) and points scattered in and far
        // beyond its box, above and below: the column grid (all triangles up), then the cubic
        // grid (every third triangle flipped, so the mesh is no longer one-sided; the distances
        // are the same), each against brute force.
        let mut seed = 0x2545_f491_4f6c_dd1du64;
        let mut rnd = move || {
            seed ^= seed << 13;
            seed ^= seed >> 7;
            seed ^= seed << 17;
            (seed >> 11) as f64 / (1u64 << 53) as f64
        };
        let n = 12u32;
        let mut mesh = Mesh::default();
        for j in 0..n {
            for i in 0..n {
                mesh.positions.push([f64::from(i), f64::from(j), 10.0 * rnd()]);
            }
        }
        for j in 0..n - 1 {
            for i in 0..n - 1 {
                let v = j * n + i;
                mesh.triangles.push([v, v + 1, v + n + 1]);
                mesh.triangles.push([v, v + n + 1, v + n]);
            }
        }
        let mut pc = PointCloud::default();
        for _ in 0..300 {
            pc.positions.push([40.0 * rnd() - 14.0, 40.0 * rnd() - 14.0, 60.0 * rnd() - 25.0]);
            let nz = rnd() as f32;
            pc.normals.push([rnd() as f32 - 0.5, rnd() as f32 - 0.5, nz]);
        }
        let cell = 2.0;
        let tris = valid_triangles(&mesh);
        let bounds = Bounds::of_points(&mesh.positions);
        assert!(heightfield_layer(&tris, &bounds).is_some());
        let want = brute(&mesh, &pc, cell, 0.9);
        let got = measure_points(&mesh, &pc, cell, 0.9);
        assert_eq!(got, want);
        for t in mesh.triangles.iter_mut().step_by(3) {
            t.swap(1, 2);
        }
        assert!(heightfield_layer(&valid_triangles(&mesh), &bounds).is_none());
        assert_eq!(measure_points(&mesh, &pc, cell, 0.9), brute(&mesh, &pc, cell, 0.9));
        assert_eq!(measure_points(&mesh, &pc, cell, 0.9), want);
    }

    #[test]
    fn samples_cover_a_sliver_within_spacing() {
        let t = [[0.0, 0.0, 0.0], [100.0, 0.0, 0.0], [50.0, 0.3, 0.0]].map(DVec3::from_array);
        let s = 0.25;
        let mut samples = Vec::new();
        sample_triangle(&t, [true; 3], s, |q| samples.push(q));
        // Area/s² + perimeter/s is ~ 240 + 800; (longest/s)² would be 160,000.
        assert!(samples.len() < 2_000, "{}", samples.len());
        for i in 0..=1000 {
            let x = f64::from(i) * 0.1;
            let top = if x <= 50.0 { 0.3 * x / 50.0 } else { 0.3 * (100.0 - x) / 50.0 };
            for y in [0.0, top * 0.5, top] {
                let q = DVec3::new(x, y, 0.0);
                let d = samples.iter().map(|&p| p.distance_squared(q)).fold(f64::INFINITY, f64::min).sqrt();
                assert!(d <= s, "{q:?}: {d}");
            }
        }
    }
}
