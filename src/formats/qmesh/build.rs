//! One quantized-mesh tile from its sample grid: heights quantized on a shared edge lattice, the
//! TIN by greedy insertion (borders by 1-D simplification, so neighbours agree), vertex normals
//! from the height field (so they agree across edges too), the header, the water mask. Pure.

use super::codec::{self, Header, QMAX, QmError, QmTile, WATERMASK_SIDE, WaterMask};
use super::grid::{CELLS, MIN_STEP, SAMPLES, TileId, cell_degrees, edge_lattice_for, zoom_error};
use crate::crs::ecef;
use crate::tiling::NodeGrid;

/// Samples per side of a tile's grid with its one-sample border.
pub const SIDE: usize = SAMPLES as usize + 2;

/// A tile's heights: `SIDE × SIDE` ellipsoidal heights (metres), row-major from the sample one
/// west and one south of the tile's south-west corner (the border feeds normals).
#[derive(Debug, Clone)]
pub struct TileSamples {
    pub id: TileId,
    pub heights: Vec<f64>,
    /// Per inner sample (`SAMPLES²`, row-major from the south-west): true where the source has
    /// no data and the height is the sea-level fill.
    pub nodata: Vec<bool>,
    /// The most relief any tile of the dataset can have (metres, ellipsoidal, the sea-level
    /// fill included), where known: the zoom's edge lattice is made coarse enough to hold it
    /// ([`edge_lattice_for`]), so no tile's height step outgrows its edges' lattice.
    pub relief: Option<f64>,
}

impl TileSamples {
    fn at(&self, i: i64, j: i64) -> f64 {
        self.heights[((j + 1) as usize) * SIDE + (i + 1) as usize]
    }
}

/// A built tile and what was measured on it.
#[derive(Debug, Clone)]
pub struct BuiltTile {
    /// The encoded tile with every extension (normals, water mask, and metadata when given).
    pub bytes: Vec<u8>,
    pub vertices: usize,
    pub triangles: usize,
    /// The bound the tile was built to (metres): the zoom's error.
    pub bound: f64,
    /// Measured: over the triangles, the largest vertical distance between the decoded mesh
    /// and a sample it covers plus the sag of its longest chord below the curved Earth.
    pub max_error: f64,
    /// Whether the tile's height step divides its zoom's edge lattice (so its edges decode to
    /// exactly its neighbours' heights): false only for a tile of more relief than 32,767 edge
    /// lattice steps.
    pub lattice_exact: bool,
}

/// Why a tile cannot be built.
#[derive(Debug, thiserror::Error)]
pub enum BuildError {
    #[error("tile {tile}: {heights} heights for a {SIDE}×{SIDE} grid")]
    Size { tile: TileId, heights: usize },
    #[error("tile {tile}: non-finite height at sample ({i}, {j})")]
    NonFinite { tile: TileId, i: i64, j: i64 },
    #[error("tile {tile}: heights reach {lo:.0} … {hi:.0} m, beyond the ±32,000 m a tile can hold")]
    Range { tile: TileId, lo: f64, hi: f64 },
    #[error("tile {tile}: {0}", tile = .1)]
    Tin(crate::tin::TinError, TileId),
    #[error(transparent)]
    Codec(#[from] QmError),
}

const R: f64 = ecef::A;

/// The sag of a chord below the curved Earth per squared sample step of its length at zoom `z`
/// (metres): `R·θ²/8` for a chord of `θ` radians, a sample step being [`cell_degrees`]. Measured
/// along the grid's axes in degrees, so it is the largest sag at any latitude.
#[must_use]
pub fn chord_coefficient(z: u8) -> f64 {
    R * cell_degrees(z).to_radians().powi(2) / 8.0
}

fn pow2_at_least(v: f64) -> f64 {
    if v <= 0.0 { MIN_STEP } else { 2f64.powi(v.log2().ceil() as i32).max(MIN_STEP) }
}

/// Builds one tile. `error_scale` scales the zoom's error bound; `metadata` is the metadata
/// extension's JSON (child availability), for tiles that carry it.
pub fn build_tile(
    s: &TileSamples,
    error_scale: f64,
    metadata: Option<String>,
) -> Result<BuiltTile, BuildError> {
    let id = s.id;
    if s.heights.len() != SIDE * SIDE || s.nodata.len() != (SAMPLES * SAMPLES) as usize {
        return Err(BuildError::Size { tile: id, heights: s.heights.len() });
    }
    if let Some(k) = s.heights.iter().position(|h| !h.is_finite()) {
        return Err(BuildError::NonFinite { tile: id, i: (k % SIDE) as i64 - 1, j: (k / SIDE) as i64 - 1 });
    }
    let n = SAMPLES as usize;
    let last = n - 1;
    let bound = zoom_error(id.z, error_scale);
    let lattice = edge_lattice_for(id.z, s.relief);
    let chord = chord_coefficient(id.z);
    // Edge samples on the zoom's lattice: both tiles of an edge round the same heights alike.
    let mut h: Vec<f64> = Vec::with_capacity(n * n);
    for j in 0..n {
        for i in 0..n {
            let v = s.at(i as i64, j as i64);
            let edge = i == 0 || j == 0 || i == last || j == last;
            h.push(if edge { (v / lattice).round() * lattice } else { v });
        }
    }
    let (lo, hi) = h.iter().fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), &v| (a.min(v), b.max(v)));
    if lo.abs() > 32_000.0 || hi.abs() > 32_000.0 {
        return Err(BuildError::Range { tile: id, lo, hi });
    }
    let step = pow2_at_least((hi - lo) / f64::from(QMAX - 1));
    let min = (lo / step).floor() * step;
    let max = min + f64::from(QMAX) * step;
    let q: Vec<u16> =
        h.iter().map(|&v| ((v - min) / step).round().clamp(0.0, f64::from(QMAX)) as u16).collect();
    let decoded: Vec<f64> = q.iter().map(|&k| min + f64::from(k) * step).collect();

    let axis: Vec<u32> = (0..SAMPLES).collect();
    let grid = NodeGrid { cols: axis.clone(), rows: axis };
    let dec32: Vec<f32> = decoded.iter().map(|&v| v as f32).collect();
    let tin_bound = (bound - lattice / 2.0).max(0.0);
    let tin =
        crate::tin::build_with_chord(&grid, &dec32, tin_bound, chord).map_err(|e| BuildError::Tin(e, id))?;

    // Measured against the samples as given (before any rounding): per triangle, the largest
    // vertical distance to a sample it covers plus its longest chord's sag.
    let positions: Vec<[f64; 3]> = tin
        .vertices
        .iter()
        .map(|v| [f64::from(v[0]), f64::from(v[1]), decoded[v[1] as usize * n + v[0] as usize]])
        .collect();
    let axis = crate::tin::Axis::of(&grid.cols);
    let mut measured = 0.0f64;
    for t in &tin.triangles {
        let p = t.map(|k| positions[k as usize]);
        let mut worst = 0.0f64;
        let ij = t.map(|k| tin.vertices[k as usize]);
        crate::tin::scan_triangle_rows_ij(p, ij, &axis, &axis, false, |r| {
            // Sample (i, j) of the tile is (i + 1, j + 1) of the samples with their margin.
            let row = &s.heights[(r.j + 1) * SIDE + 1..][r.i0..r.i1];
            for (i, &v) in (r.i0..).zip(row) {
                // Unit axis from 0: sample i is at x = i.
                let e = (v - r.z(i as f64)).abs();
                worst = if e > worst { e } else { worst };
            }
        });
        let d2 = |a: [f64; 3], b: [f64; 3]| (a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2);
        measured = measured.max(worst + chord * d2(p[0], p[1]).max(d2(p[1], p[2])).max(d2(p[2], p[0])));
    }

    // Triangles in Morton order of their centroids, vertices numbered by first use: small
    // deltas and the high-water-mark order the format needs.
    let mut tris = tin.triangles.clone();
    let morton = |t: &[u32; 3]| {
        let c = |k: usize| t.iter().map(|&v| tin.vertices[v as usize][k]).sum::<u32>();
        crate::tiling::morton(c(0), c(1))
    };
    tris.sort_by_cached_key(morton);
    let mut order = vec![u32::MAX; tin.vertices.len()];
    let mut verts: Vec<usize> = Vec::with_capacity(tin.vertices.len());
    let triangles: Vec<[u32; 3]> = tris
        .iter()
        .map(|t| {
            t.map(|v| {
                let o = &mut order[v as usize];
                if *o == u32::MAX {
                    *o = verts.len() as u32;
                    verts.push(v as usize);
                }
                *o
            })
        })
        .collect();

    let mut t = QmTile { triangles, ..QmTile::default() };
    let quant =
        |k: u32| ((u64::from(k) * u64::from(QMAX) * 2 + u64::from(CELLS)) / (2 * u64::from(CELLS))) as u16;
    let mut ecef_pts = Vec::with_capacity(verts.len());
    let mut vert_h = Vec::with_capacity(verts.len());
    let mut normals = Vec::with_capacity(verts.len());
    let mut edges: [Vec<(u32, u32)>; 4] = Default::default();
    for (k, &v) in verts.iter().enumerate() {
        let [i, j] = tin.vertices[v];
        t.u.push(quant(i));
        t.v.push(quant(j));
        t.h.push(q[j as usize * n + i as usize]);
        let (lon, lat) = id.sample(i64::from(i), i64::from(j));
        let hv = decoded[j as usize * n + i as usize];
        ecef_pts.push(ecef::from_geodetic(lon, lat, hv));
        vert_h.push(hv);
        normals.push(codec::oct_encode(normal(s, i64::from(i), i64::from(j))));
        let k = k as u32;
        if i == 0 {
            edges[0].push((j, k));
        }
        if j == 0 {
            edges[1].push((i, k));
        }
        if i == CELLS {
            edges[2].push((j, k));
        }
        if j == CELLS {
            edges[3].push((i, k));
        }
    }
    for e in &mut edges {
        e.sort_unstable();
    }
    let [w, so, ea, no] = edges.map(|e| e.into_iter().map(|(_, k)| k).collect::<Vec<u32>>());
    (t.west, t.south, t.east, t.north) = (w, so, ea, no);
    t.normals = Some(normals);
    t.watermask = Some(watermask(&s.nodata));
    t.metadata = metadata;
    t.header = header(id, &ecef_pts, &vert_h, min, max);
    let bytes = codec::encode(&t)?;
    Ok(BuiltTile {
        bytes,
        vertices: verts.len(),
        triangles: t.triangles.len(),
        bound,
        max_error: measured,
        lattice_exact: step <= lattice,
    })
}

/// The surface normal at sample `(i, j)` (ECEF, unit): the ellipsoid's up tilted by the height
/// field's central differences over the sample spacing in metres (meridian and prime-vertical
/// radii at the sample). A function of the global sample position and its neighbours' heights
/// only, so the two tiles of an edge give its vertices the same normal.
fn normal(s: &TileSamples, i: i64, j: i64) -> [f64; 3] {
    let (lon, lat) = s.id.sample(i, j);
    let lon = super::grid::canonical_lon(lon);
    let (sl, cl) = lon.to_radians().sin_cos();
    let (sp, cp) = lat.to_radians().sin_cos();
    let h = s.at(i, j);
    let w = (1.0 - ecef::E2 * sp * sp).sqrt();
    let (n_radius, m_radius) = (ecef::A / w, ecef::A * (1.0 - ecef::E2) / (w * w * w));
    let step = cell_degrees(s.id.z).to_radians();
    let dx = 2.0 * step * (n_radius + h) * cp;
    let dy = 2.0 * step * (m_radius + h);
    let up = [cp * cl, cp * sl, sp];
    let east = [-sl, cl, 0.0];
    let north = [-sp * cl, -sp * sl, cp];
    // At a pole the east spacing vanishes: the slope along it is taken as flat.
    let gx = if dx.abs() > 1e-6 { (s.at(i + 1, j) - s.at(i - 1, j)) / dx } else { 0.0 };
    let gy = if dy.abs() > 1e-6 { (s.at(i, j + 1) - s.at(i, j - 1)) / dy } else { 0.0 };
    let v = [0, 1, 2].map(|k| up[k] - gx * east[k] - gy * north[k]);
    let l = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
    if l.is_finite() && l > 0.0 { v.map(|c| c / l) } else { up }
}

/// The water mask: texels over samples without data (filled at sea level) are water.
fn watermask(nodata: &[bool]) -> WaterMask {
    if nodata.iter().all(|&b| !b) {
        return WaterMask::Uniform(0);
    }
    if nodata.iter().all(|&b| b) {
        return WaterMask::Uniform(255);
    }
    let n = SAMPLES as usize;
    let side = WATERMASK_SIDE;
    // Texel centres mapped to the nearest sample: rows from the north, columns from the west.
    let at = |k: usize, flip: bool| {
        let t = (k as f64 + 0.5) / side as f64;
        ((if flip { 1.0 - t } else { t }) * f64::from(CELLS)).round() as usize
    };
    let cols: Vec<usize> = (0..side).map(|c| at(c, false).min(n - 1)).collect();
    let mut g = Vec::with_capacity(side * side);
    for r in 0..side {
        let row = &nodata[at(r, true).min(n - 1) * n..][..n];
        g.extend(cols.iter().map(|&i| if row[i] { 255 } else { 0 }));
    }
    WaterMask::Grid(g)
}

/// The header of a tile whose vertices are `pts` (ECEF) and heights span `min..=max`.
fn header(id: TileId, pts: &[[f64; 3]], heights: &[f64], min: f64, max: f64) -> Header {
    let r = id.rect();
    let (mut lo, mut hi) = ([f64::INFINITY; 3], [f64::NEG_INFINITY; 3]);
    for p in pts {
        for k in 0..3 {
            lo[k] = lo[k].min(p[k]);
            hi[k] = hi[k].max(p[k]);
        }
    }
    let c = [0, 1, 2].map(|k| f64::midpoint(lo[k], hi[k]));
    let radius = pts
        .iter()
        .map(|p| ((p[0] - c[0]).powi(2) + (p[1] - c[1]).powi(2) + (p[2] - c[2]).powi(2)).sqrt())
        .fold(0.0, f64::max);
    let lo_h = heights.iter().copied().fold(f64::INFINITY, f64::min);
    let hi_h = heights.iter().copied().fold(f64::NEG_INFINITY, f64::max);
    let center = ecef::from_geodetic(
        f64::midpoint(r.west, r.east),
        f64::midpoint(r.south, r.north),
        f64::midpoint(lo_h, hi_h),
    );
    Header {
        center,
        min_height: min as f32,
        max_height: max as f32,
        sphere_center: c,
        sphere_radius: radius,
        horizon: horizon_point(c, pts),
    }
}

/// The horizon-occlusion point (CesiumJS's `EllipsoidalOccluder`
/// `computeHorizonCullingPointFromVertices`), in ellipsoid-scaled coordinates: the point on
/// the ray towards `direction` from which, once below the horizon, every vertex is. For tiles so
/// large that no such point exists (a hemisphere), a point far out along the ray: never culled
/// while any of the tile can be seen.
#[must_use]
pub fn horizon_point(direction: [f64; 3], pts: &[[f64; 3]]) -> [f64; 3] {
    let radii = [ecef::A, ecef::A, ecef::A * (1.0 - ecef::F)];
    let scale = |p: [f64; 3]| [p[0] / radii[0], p[1] / radii[1], p[2] / radii[2]];
    let d = scale(direction);
    let dl = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt();
    if dl == 0.0 || !dl.is_finite() {
        return [0.0, 0.0, 0.0];
    }
    let d = [d[0] / dl, d[1] / dl, d[2] / dl];
    let mut best = 0.0f64;
    for &p in pts {
        let s = scale(p);
        let mag2 = s[0] * s[0] + s[1] * s[1] + s[2] * s[2];
        let mag = mag2.sqrt();
        let dir = [s[0] / mag, s[1] / mag, s[2] / mag];
        let (mag2, mag) = (mag2.max(1.0), mag.max(1.0));
        let cos_a = dir[0] * d[0] + dir[1] * d[1] + dir[2] * d[2];
        let cr =
            [dir[1] * d[2] - dir[2] * d[1], dir[2] * d[0] - dir[0] * d[2], dir[0] * d[1] - dir[1] * d[0]];
        let sin_a = (cr[0] * cr[0] + cr[1] * cr[1] + cr[2] * cr[2]).sqrt();
        let cos_b = 1.0 / mag;
        let sin_b = (mag2 - 1.0).sqrt() * cos_b;
        let denom = cos_a * cos_b - sin_a * sin_b;
        if denom <= 1e-9 {
            best = f64::INFINITY;
            break;
        }
        best = best.max(1.0 / denom);
    }
    let m = if best.is_finite() && best > 0.0 { best } else { 1.0e6 };
    [d[0] * m, d[1] * m, d[2] * m]
}

#[cfg(test)]
mod tests;
