//! The glTF 2.0 binary (GLB) of a decoded blob ([`glb`]). Positions keep the blob's integer
//! grid on one step for all three axes: glTF renders normals through the inverse transpose of
//! the node's transform, so a node scale that differs per axis (the blob's x/y step against its
//! far finer z step) would bend every normal towards the stretched axis. Each glTF axis stores
//! `k·q` (or `k·(Q − q)` where the axis is reversed), `k` the axis's step in units of the finest,
//! and the node's `translation` and uniform `scale` hold the grid's origin and step, so a position
//! decodes to exactly what the blob decodes to. Where that does not fit 16 bits a grid with a
//! coarser z step ([`CoarseGrid`]) keeps positions 16-bit within 1/8 of the measured error, and
//! where none does, positions are `FLOAT` metres (scale 1).

use serde_json::{Value, json};

use super::border::{self, BorderFans};
use super::earth;
use super::placement::{Axes, Placement};
use crate::codec::{Blob, Geometry};
use crate::crs::{Frame, PlaceError};
use crate::geom::{Bounds, Mesh, Skirted, add_skirts, skirt_depth};
use crate::tiling::TileKey;

/// Media type of a glTF binary.
pub const GLB_TYPE: &str = "model/gltf-binary";
/// Written into `asset.generator` of every tileset and glTF.
pub const GENERATOR: &str = concat!("terrastream ", env!("CARGO_PKG_VERSION"));

pub(crate) const GLTF_FLOAT: u32 = 5126;
pub(crate) const GLTF_U8: u32 = 5121;
pub(crate) const GLTF_U16: u32 = 5123;
pub(crate) const GLTF_U32: u32 = 5125;
const GLTF_I8: u32 = 5120;
pub(crate) const ARRAY_BUFFER: u32 = 34962;
pub(crate) const ELEMENT_ARRAY_BUFFER: u32 = 34963;
/// Largest vertex count drawn with 8-bit indices (255 is the restart index of `UNSIGNED_BYTE`).
pub(crate) const MAX_U8_VERTICES: usize = 255;
/// Largest vertex count drawn with 16-bit indices: 65535 is WebGL 2's primitive-restart index.
pub(crate) const MAX_U16_VERTICES: usize = 65_535;

/// Skirt depth of a tile mesh with error `own`: deep enough for a neighbour drawn one level
/// coarser (about twice the error), see [`skirt_depth`].
#[must_use]
pub fn mesh_skirt_depth(own: f64) -> f64 {
    skirt_depth(own, 2.0 * own)
}

/// The glTF binary of a decoded blob: a mesh as indexed triangles (with skirts `skirt` deep
/// below its borders, none on the dataset's outer border `outer`, when `skirt` is given), points
/// as `POINTS` with normals. Positions are the blob's integer grid: `UNSIGNED_SHORT` with
/// `KHR_mesh_quantization` when every axis fits 16 bits, else a mesh's go onto a coarser 16-bit
/// grid if its step is at most [`COARSE_GRID_ERROR_FRACTION`] of the measured error, else the
/// blob's integers as `FLOAT` (exact below 2²⁴); normals are `BYTE` normalized; indices 8, 16 or
/// 32 bits, the least that holds the vertex count.
///
/// A mesh vertex that `neighbours` (the [`BorderFans`] of the tiles around, of the same depth
/// and level) also have takes one normal summed over all their triangles, as theirs does, so
/// no seam shows between them ([`super::border`]); without neighbours each vertex's normal is
/// over the tile's own triangles. `neighbours` may hold this blob's own fans (its key), which
/// are then not made again.
///
/// On the Earth (`place.earth`), positions are `FLOAT` in the east-north-up frame at the node's
/// centre, which the node's `matrix` holds ([`super::earth`]); fails only for a point outside
/// its CRS's or geoid's domain.
pub fn glb(
    blob: &Blob,
    place: &Placement,
    skirt: Option<(f64, Option<&Bounds>)>,
    neighbours: &[&BorderFans],
) -> Result<Vec<u8>, PlaceError> {
    glb_and_normals(blob, place, skirt, neighbours).map(|(glb, _)| glb)
}

/// [`glb()`], and for a mesh the normals its `BYTE`s were rounded from ([`ExactNormals`]), which
/// a coarser encoding (Draco's octahedral normals) rounds again from these rather than from the
/// bytes.
///
/// # Errors
/// As [`glb()`].
pub fn glb_and_normals(
    blob: &Blob,
    place: &Placement,
    skirt: Option<(f64, Option<&Bounds>)>,
    neighbours: &[&BorderFans],
) -> Result<(Vec<u8>, Option<ExactNormals>), PlaceError> {
    let h = &blob.header;
    // The tile's own fans: given among `neighbours` (a memo's), else made here.
    let shared = if neighbours.iter().any(|n| n.key() != h.key) {
        let made;
        let own = if let Some(own) = neighbours.iter().find(|n| n.key() == h.key) {
            Some(*own)
        } else {
            made = BorderFans::of(blob, place)?;
            made.as_ref()
        };
        own.map_or_else(Vec::new, |own| own.shared_normals(neighbours))
    } else {
        Vec::new()
    };
    if let Some(frame) = &place.earth {
        return glb_on_earth(blob, frame, skirt, &shared);
    }
    let step = [h.quant.xy_step, h.quant.xy_step, h.quant.z_step];
    let min = h.bounds[0];
    match &blob.geometry {
        Geometry::Mesh(mesh) => {
            // Top triangles must face up (a terrain) or keep their winding (a model, unless the
            // placement mirrors it); skirt walls are built facing outward in the world frame, so
            // they turn only where the placement mirrors.
            let flip_top = turns(mesh, place);
            let depth = skirt.filter(|_| !mesh.triangles.is_empty());
            // The blob's own grid when it fits 16 bits on one step for all axes, else one with a
            // coarser z step (the finest that fits) within the error budget ([`CoarseGrid`]),
            // else `FLOAT` metres.
            let exact = with_skirts(mesh, min, step, depth, place);
            let coarse = if exact.1.uniform_steps().is_some() {
                None
            } else {
                let below = depth.map_or(0.0, |(d, _)| d);
                let budget = h.errors.max * COARSE_GRID_ERROR_FRACTION;
                let mut found = None;
                for k in exact.1.least_coarsening()..=MAX_COARSENING {
                    // None: this z step exceeds the budget (or nothing fits), so would a coarser.
                    let Some(grid) =
                        CoarseGrid::fit(&mesh.positions, &h.bounds, step, below, budget, [0, 0, k])
                    else {
                        break;
                    };
                    let snapped = Mesh {
                        positions: mesh.positions.iter().map(|p| grid.snap(*p)).collect(),
                        triangles: mesh.triangles.clone(),
                    };
                    let (s, p) = with_skirts(&snapped, grid.origin, grid.step, depth, place);
                    if p.uniform_steps().is_some() {
                        found = Some((snapped, s, p));
                        break;
                    }
                }
                found
            };
            let (base, skirted, pos) = match &coarse {
                Some((m, s, p)) => (m, s, p),
                None => (mesh, &exact.0, &exact.1),
            };
            let (all, tops, first_wall): (&Mesh, &[u32], usize) = match skirted {
                Some(s) => (&s.mesh, &s.skirt_tops, s.first_skirt_triangle),
                None => (base, &[], base.triangles.len()),
            };
            let mut tris = all.triangles.clone();
            for (i, t) in tris.iter_mut().enumerate() {
                let flip = if i < first_wall { flip_top } else { place.mirrored() };
                if flip {
                    t.swap(1, 2);
                }
            }
            let g: Vec<glam::DVec3> =
                all.positions.iter().map(|p| glam::DVec3::from_array(place.gltf_of(*p))).collect();
            let normals = mesh_normals(&g, &tris[..first_wall], tops, &shared);
            let mut gltf = Gltf::new(h.key, h.level);
            let acc = gltf.positions(pos);
            Ok((gltf.mesh(acc, pos.ints.len(), &tris, &normals.bytes()).finish(), Some(normals)))
        }
        Geometry::Points(points) => {
            let pos = Positions::new(&points.positions, min, step, place);
            let map = place.axis_map();
            let normals: Vec<[i8; 3]> =
                points.normals.iter().map(|n| oct_free_i8(map.map(|(a, s)| s * f64::from(n[a])))).collect();
            let mut gltf = Gltf::new(h.key, h.level);
            let acc = gltf.positions(&pos);
            Ok((gltf.points(acc, &normals).finish(), None))
        }
    }
}

/// How near a pole (degrees of latitude, 0.1 mm there) a geographic grid's sample is the pole.
const POLE_DEGREES: f64 = 1e-9;

/// [`glb`] for a tileset on the Earth: every position from its world point through the exact
/// frame, relative to the east-north-up frame at the node's centre.
fn glb_on_earth(
    blob: &Blob,
    frame: &Frame,
    skirt: Option<(f64, Option<&Bounds>)>,
    shared: &[(u32, glam::DVec3)],
) -> Result<(Vec<u8>, Option<ExactNormals>), PlaceError> {
    let h = &blob.header;
    let b = Bounds::new(h.bounds[0], h.bounds[1]);
    let enu = earth::node_frame(frame, &b)?;
    let matrix = earth::gltf_matrix(&enu);
    let mirrored = earth::mirrored(frame, &b)?;
    match &blob.geometry {
        Geometry::Mesh(mesh) => {
            let skirted = match skirt {
                Some((depth, outer)) if !mesh.triangles.is_empty() => Some(add_skirts(mesh, depth, outer)),
                _ => None,
            };
            let (all, tops, first_wall): (&Mesh, &[u32], usize) = match &skirted {
                Some(s) => (&s.mesh, &s.skirt_tops, s.first_skirt_triangle),
                None => (mesh, &[], mesh.triangles.len()),
            };
            let g = earth::gltf_positions(frame, &enu, &all.positions)?;
            // Top triangles face up: the sign of their summed area seen from above (east, north
            // = glTF x, −z); walls face outward in the world frame, so turn where it mirrors.
            let area: f64 = all.triangles[..first_wall]
                .iter()
                .map(|t| {
                    let [a, b, c] = t.map(|i| g[i as usize]);
                    (b[0] - a[0]) * (-(c[2] - a[2])) - (-(b[2] - a[2])) * (c[0] - a[0])
                })
                .sum();
            let flip_top = area < 0.0;
            let mut tris = all.triangles.clone();
            for (i, t) in tris.iter_mut().enumerate() {
                if if i < first_wall { flip_top } else { mirrored } {
                    t.swap(1, 2);
                }
            }
            let dg: Vec<glam::DVec3> = g.iter().map(|p| glam::DVec3::from_array(*p)).collect();
            let mut shared: Vec<_> = shared.iter().map(|&(i, n)| (i, border::to_node(&enu, n))).collect();
            // On a geographic grid every sample of a pole's row is the pole: one point of the
            // Earth that many vertices draw (of this tile and of every tile along that row), each
            // with the normal of its own triangles, up to 24° apart on ETOPO1. All draw the
            // ellipsoid's normal there, as every tile does.
            if frame.grid.crs.is_geographic() {
                let first_skirt = all.positions.len() - tops.len();
                for (i, p) in all.positions.iter().enumerate().take(first_skirt) {
                    let lat = frame.crs_xy(p[0], p[1]).1;
                    if lat.abs() >= 90.0 - POLE_DEGREES {
                        shared.push((i as u32, border::to_node(&enu, glam::DVec3::Z * lat.signum())));
                    }
                }
            }
            let normals = mesh_normals(&dg, &tris[..first_wall], tops, &shared);
            let mut gltf = Gltf::new(h.key, h.level);
            let acc = gltf.float_positions(&g, matrix);
            Ok((gltf.mesh(acc, g.len(), &tris, &normals.bytes()).finish(), Some(normals)))
        }
        Geometry::Points(points) => {
            let g = earth::gltf_positions(frame, &enu, &points.positions)?;
            let normals = points
                .positions
                .iter()
                .zip(&points.normals)
                .map(|(p, n)| {
                    let d = earth::gltf_direction(frame, &enu, *p, n.map(f64::from))?;
                    Ok(oct_free_i8(d))
                })
                .collect::<Result<Vec<_>, PlaceError>>()?;
            let mut gltf = Gltf::new(h.key, h.level);
            let acc = gltf.float_positions(&g, matrix);
            Ok((gltf.points(acc, &normals).finish(), None))
        }
    }
}

/// A mesh's skirts (`depth` below its inner borders, rounded up to whole z steps of the grid so
/// skirt vertices stay on it) and its positions on the grid at `origin` with steps `step`.
fn with_skirts(
    mesh: &Mesh,
    origin: [f64; 3],
    step: [f64; 3],
    depth: Option<(f64, Option<&Bounds>)>,
    place: &Placement,
) -> (Option<Skirted>, Positions) {
    let skirted = depth.map(|(d, outer)| add_skirts(mesh, (d / step[2]).ceil().max(1.0) * step[2], outer));
    let pos =
        Positions::new(skirted.as_ref().map_or(&mesh.positions, |s| &s.mesh.positions), origin, step, place);
    (skirted, pos)
}

/// How far a GLB position may lie from its blob position, as a fraction of the blob's measured
/// error, when the blob's grid is too fine for 16 bits: the coarse step's at most this, so a
/// position moves by at most half a step (a step where it is clamped into the bounds).
pub const COARSE_GRID_ERROR_FRACTION: f64 = 1.0 / 8.0;

/// Most halvings of a grid's resolution [`CoarseGrid`] tries on one axis (a factor of 2³²).
const MAX_COARSENING: u32 = 32;

/// A grid `2^k` times coarser than the blob's on the axes whose span does not fit 16 bits, aligned
/// with the blob's global grid where the blob's origin lies on it (so neighbours of one depth,
/// whose z grids are one, round a shared border vertex alike): each integer `g` of the blob's
/// grid goes to `round(g / 2^k)` (halves up), clamped into the blob's bounds.
#[derive(Debug, Clone, Copy)]
pub(crate) struct CoarseGrid {
    /// The blob's grid: origin (`bounds.min`), steps, and the global index of the origin.
    min: [f64; 3],
    blob_step: [f64; 3],
    base: [i64; 3],
    /// `2^k` per axis, and the coarse indices the bounds allow.
    factor: [i64; 3],
    lo: [i64; 3],
    hi: [i64; 3],
    /// The coarse grid's origin (its index `lo`) and steps.
    pub(crate) origin: [f64; 3],
    pub(crate) step: [f64; 3],
}

impl CoarseGrid {
    /// The least coarsening, at least `2^at_least` per axis, that fits `world` (with skirts
    /// `below` deep under it) in 16 bits per axis, or `None` when a coarse step would exceed
    /// `budget` or nothing fits.
    pub(crate) fn fit(
        world: &[[f64; 3]],
        bounds: &[[f64; 3]; 2],
        step: [f64; 3],
        below: f64,
        budget: f64,
        at_least: [u32; 3],
    ) -> Option<Self> {
        let [min, max] = *bounds;
        let mut grid = Self {
            min,
            blob_step: step,
            base: [0; 3],
            factor: [1; 3],
            lo: [0; 3],
            hi: [0; 3],
            origin: min,
            step,
        };
        for a in 0..3 {
            if !(step[a] > 0.0 && step[a].is_finite() && min[a].is_finite() && max[a].is_finite()) {
                return None;
            }
            let ratio = min[a] / step[a];
            let base = if ratio.abs() < 2f64.powi(50) && (ratio - ratio.round()).abs() < 1e-6 {
                ratio.round() as i64
            } else {
                0
            };
            let q = |v: f64| ((v - min[a]) / step[a]).round();
            let top = q(max[a]);
            if !(0.0..=f64::from(u32::MAX)).contains(&top) {
                return None;
            }
            let (mut glo, mut ghi) = (base, base + top as i64);
            let (mut plo, mut phi) = (i64::MAX, i64::MIN);
            for p in world {
                let g = q(p[a]);
                if !g.is_finite() || g.abs() > f64::from(u32::MAX) {
                    return None;
                }
                let g = base + g as i64;
                plo = plo.min(g);
                phi = phi.max(g);
            }
            if world.is_empty() {
                (plo, phi) = (glo, glo);
            }
            glo = glo.min(plo);
            ghi = ghi.max(phi);
            let mut k = at_least[a];
            loop {
                let m = 1i64 << k;
                let (lo, hi) = (div_ceil(glo, m), glo.max(ghi).div_euclid(m));
                let c = |g: i64| (g + m / 2).div_euclid(m).clamp(lo, hi);
                let extra = if a == 2 && below > 0.0 {
                    (below / (step[a] * m as f64)).ceil().max(1.0) as i64
                } else {
                    0
                };
                if lo <= hi && c(phi) - c(plo) + extra <= i64::from(u16::MAX) {
                    if k > 0 && step[a] * m as f64 > budget {
                        return None;
                    }
                    grid.base[a] = base;
                    grid.factor[a] = m;
                    grid.lo[a] = lo;
                    grid.hi[a] = hi;
                    grid.step[a] = step[a] * m as f64;
                    grid.origin[a] = min[a] + (lo * m - base) as f64 * step[a];
                    break;
                }
                k += 1;
                if k > MAX_COARSENING {
                    return None;
                }
            }
        }
        Some(grid)
    }

    /// The point of the coarse grid a blob position goes to.
    pub(crate) fn snap(&self, p: [f64; 3]) -> [f64; 3] {
        std::array::from_fn(|a| {
            let m = self.factor[a];
            if m == 1 {
                return p[a];
            }
            let g = self.base[a] + ((p[a] - self.min[a]) / self.blob_step[a]).round() as i64;
            let c = (g + m / 2).div_euclid(m).clamp(self.lo[a], self.hi[a]);
            self.origin[a] + (c - self.lo[a]) as f64 * self.step[a]
        })
    }
}

fn div_ceil(a: i64, m: i64) -> i64 {
    -((-a).div_euclid(m))
}

/// Whether a mesh's triangles must turn to face the way glTF expects (counter-clockwise seen from
/// outside). A model keeps its own winding unless the placement mirrors it; a terrain mesh is a
/// height field, so its triangles must face up: the sign of their summed area seen from above
/// in the tileset frame says which way they face (the TIN's winding follows the raster's rows,
/// whose direction in the world frame depends on the georeference).
fn turns(mesh: &Mesh, place: &Placement) -> bool {
    if place.axes == Axes::ModelYUp {
        return place.mirrored();
    }
    let area: f64 = mesh
        .triangles
        .iter()
        .map(|t| {
            let [a, b, c] = t.map(|i| place.enu_of(mesh.positions[i as usize]));
            (b[0] - a[0]) * (c[1] - a[1]) - (b[1] - a[1]) * (c[0] - a[0])
        })
        .sum();
    area < 0.0
}

/// A mesh GLB's vertex normals before they are rounded ([`glb_and_normals`]): each vertex's
/// direction (not of unit length) and what an encoder that rounds it coarser may do with it.
#[derive(Debug, Clone, PartialEq)]
pub struct ExactNormals {
    /// Per vertex, in glTF axes; `[0, 1, 0]` (up) for a vertex of no triangle.
    pub directions: Vec<[f64; 3]>,
    /// Per vertex, in the same order.
    pub roles: Vec<NormalRole>,
}

/// What an encoder may do with one vertex's normal when it rounds it ([`ExactNormals`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum NormalRole {
    /// The tile's own: any rounding within the encoder's stated bound.
    Own,
    /// Shared with the neighbouring tiles of a border, which draw the same direction: the
    /// nearest rounding only, as each of them does, so both sides draw the same bytes.
    Shared,
    /// A skirt vertex: exactly what vertex `top` (the border vertex above it) draws.
    Below(u32),
}

impl ExactNormals {
    /// As `BYTE` vectors (the plain GLB's).
    fn bytes(&self) -> Vec<[i8; 3]> {
        self.directions.iter().map(|d| oct_free_i8(*d)).collect()
    }
}

/// Smooth vertex normals in glTF axes: area-weighted sums over the top triangles (`top`,
/// already facing the right way), except the vertices `shared` with neighbouring tiles, whose
/// sums over all the tiles' triangles it gives; a skirt vertex takes the normal of the border
/// vertex it hangs below (`tops`, in order from the first skirt vertex), so a wall shades like
/// the surface above it, as Cesium's quantized-mesh skirts do.
fn mesh_normals(
    g: &[glam::DVec3],
    top: &[[u32; 3]],
    tops: &[u32],
    shared: &[(u32, glam::DVec3)],
) -> ExactNormals {
    let mut sums = vec![glam::DVec3::ZERO; g.len()];
    let mut roles = vec![NormalRole::Own; g.len()];
    for t in top {
        let [a, b, c] = t.map(|i| g[i as usize]);
        let n = (b - a).cross(c - a);
        for &i in t {
            sums[i as usize] += n;
        }
    }
    for &(i, n) in shared {
        if let Some(s) = sums.get_mut(i as usize) {
            *s = n;
            roles[i as usize] = NormalRole::Shared;
        }
    }
    let first_skirt = g.len() - tops.len();
    for (k, &top) in tops.iter().enumerate() {
        sums[first_skirt + k] = sums[top as usize];
        roles[first_skirt + k] = NormalRole::Below(top);
    }
    // A vertex of no triangle (there are none in a decoded mesh) points up.
    let directions =
        sums.iter().map(|s| if s.length() > 0.0 { s.to_array() } else { [0.0, 1.0, 0.0] }).collect();
    ExactNormals { directions, roles }
}

/// Positions on the blob's grid, per glTF axis: the stored integers, the node's translation
/// (relative to the placement origin) and scale (the grid step).
struct Positions {
    ints: Vec<[u32; 3]>,
    translation: [f64; 3],
    scale: [f64; 3],
    max: [u32; 3],
}

impl Positions {
    fn new(world: &[[f64; 3]], min: [f64; 3], step: [f64; 3], place: &Placement) -> Self {
        let q: Vec<[i64; 3]> = world
            .iter()
            .map(|p| std::array::from_fn(|a| ((p[a] - min[a]) / step[a]).round() as i64))
            .collect();
        let (mut lo, mut hi) = ([i64::MAX; 3], [i64::MIN; 3]);
        for p in &q {
            for a in 0..3 {
                lo[a] = lo[a].min(p[a]);
                hi[a] = hi[a].max(p[a]);
            }
        }
        if q.is_empty() {
            (lo, hi) = ([0; 3], [0; 3]);
        }
        let map = place.axis_map();
        let ints = q
            .iter()
            .map(|p| map.map(|(a, s)| if s > 0.0 { p[a] - lo[a] } else { hi[a] - p[a] } as u32))
            .collect();
        let translation = map.map(|(a, s)| {
            let base = if s > 0.0 { lo[a] } else { hi[a] };
            s * (min[a] + base as f64 * step[a] - place.origin[a])
        });
        let scale = map.map(|(a, _)| step[a]);
        let max = map.map(|(a, _)| (hi[a] - lo[a]) as u32);
        Self { ints, translation, scale, max }
    }

    /// The finest of the three steps.
    fn finest(&self) -> f64 {
        self.scale.iter().copied().fold(f64::INFINITY, f64::min)
    }

    /// The least `k ≥ 1` for which a `2^k` times coarser finest step could fit every axis in 16
    /// bits once on one step ([`Positions::uniform`]): where to start looking for a coarse grid.
    fn least_coarsening(&self) -> u32 {
        let s = self.finest();
        let need = (0..3).map(|a| f64::from(self.max[a]) * self.scale[a] / s).fold(0.0, f64::max)
            / f64::from(u16::MAX);
        if need.is_finite() && need > 1.0 { (need.log2().ceil() as u32).clamp(1, MAX_COARSENING) } else { 1 }
    }

    /// The one step and each axis's step in units of it, when the positions can go on one step
    /// for every axis ([`Positions::uniform`]); nothing is allocated (the grid search asks often).
    fn uniform_steps(&self) -> Option<(f64, [u32; 3])> {
        let s = self.finest();
        if !(s > 0.0 && s.is_finite()) {
            return None;
        }
        let mut k = [0u32; 3];
        for ((k, step), max) in k.iter_mut().zip(self.scale).zip(self.max) {
            let r = step / s;
            let whole = r.round();
            if !((1.0..=f64::from(u16::MAX)).contains(&whole) && (r - whole).abs() <= 1e-9 * whole) {
                return None;
            }
            *k = whole as u32;
            if u64::from(max) * u64::from(*k) > u64::from(u16::MAX) {
                return None;
            }
        }
        Some((s, k))
    }

    /// The same positions on one step for every axis, the finest of the three, when the others
    /// are whole multiples of it and every axis then fits 16 bits: glTF renders a normal through
    /// the inverse transpose of its node's transform, so a scale that differs per axis would bend
    /// the normals towards the stretched axis (`KHR_mesh_quantization` recommends a uniform one).
    fn uniform(&self) -> Option<Positions> {
        let (s, k) = self.uniform_steps()?;
        Some(Positions {
            ints: self.ints.iter().map(|p| std::array::from_fn(|a| p[a] * k[a])).collect(),
            translation: self.translation,
            scale: [s; 3],
            max: std::array::from_fn(|a| self.max[a] * k[a]),
        })
    }
}

/// The 27 offsets of −1, 0, +1 per component (x fastest), as a table: computing them with
/// integer division and powers per candidate took most of a cold GLB's time.
const OCT_OFFSETS: [[f64; 3]; 27] = {
    let mut t = [[0.0; 3]; 27];
    let mut d = 0;
    while d < 27 {
        t[d] = [(d % 3) as f64 - 1.0, (d / 3 % 3) as f64 - 1.0, (d / 9) as f64 - 1.0];
        d += 1;
    }
    t
};

/// The `BYTE`-normalized unit vector nearest in direction to `n` whose length passes glTF
/// validators (|len − 1| small): rounding each component alone can miss by 0.7 %.
fn oct_free_i8(n: [f64; 3]) -> [i8; 3] {
    let len = (n[0] * n[0] + n[1] * n[1] + n[2] * n[2]).sqrt();
    let u = if len > 0.0 && len.is_finite() { n.map(|c| c / len) } else { [0.0, 0.0, 1.0] };
    let base = u.map(|c| (c * 127.0).round());
    let mut best = (f64::INFINITY, [0i8; 3]);
    for off in &OCT_OFFSETS {
        let c: [f64; 3] = std::array::from_fn(|a| (base[a] + off[a]).clamp(-127.0, 127.0));
        let l = (c[0] * c[0] + c[1] * c[1] + c[2] * c[2]).sqrt() / 127.0;
        if l == 0.0 {
            continue;
        }
        let cos = (c[0] * u[0] + c[1] * u[1] + c[2] * u[2]) / (l * 127.0);
        let score = (1.0 - cos) + (l - 1.0).abs() * 4.0;
        if score < best.0 {
            best = (score, c.map(|v| v as i8));
        }
    }
    best.1
}

/// A glTF document being put together: its JSON and its one binary buffer (also the 3D Tiles
/// terrain's, `formats::qmesh::tiles3d`).
pub(crate) struct Gltf {
    pub(crate) json: Value,
    pub(crate) bin: Vec<u8>,
}

impl Gltf {
    fn new(key: TileKey, level: u8) -> Self {
        Self {
            json: json!({
                "asset": { "version": "2.0", "generator": GENERATOR },
                "scene": 0,
                "scenes": [{ "nodes": [0] }],
                "bufferViews": [],
                "accessors": [],
                "extras": { "terrastream": { "key": key.to_string(), "level": level } },
            }),
            bin: Vec::new(),
        }
    }

    /// Appends a buffer view (4-byte aligned) and returns its index.
    pub(crate) fn view(&mut self, bytes: &[u8], stride: Option<usize>, target: u32) -> usize {
        while !self.bin.len().is_multiple_of(4) {
            self.bin.push(0);
        }
        let mut v =
            json!({ "buffer": 0, "byteOffset": self.bin.len(), "byteLength": bytes.len(), "target": target });
        if let Some(s) = stride {
            v["byteStride"] = json!(s);
        }
        self.bin.extend_from_slice(bytes);
        push(&mut self.json, "bufferViews", v)
    }

    pub(crate) fn accessor(&mut self, a: Value) -> usize {
        push(&mut self.json, "accessors", a)
    }

    /// Positions as `UNSIGNED_SHORT` on one step for every axis ([`Positions::uniform`]), the
    /// node's `scale` that step, else as `FLOAT` metres (scale 1).
    fn positions(&mut self, p: &Positions) -> usize {
        let count = p.ints.len();
        let (view, component, scale, lo, hi) = if let Some(u) = p.uniform() {
            let mut b = Vec::with_capacity(count * 8);
            for v in &u.ints {
                for c in v {
                    b.extend_from_slice(&(*c as u16).to_le_bytes());
                }
                b.extend_from_slice(&[0, 0]);
            }
            let (lo, hi) = extent(u.ints.iter().map(|v| v.map(f64::from)));
            // Whole numbers in the JSON, as the integer components they bound.
            let (lo, hi) = (json!(lo.map(|v| v as u32)), json!(hi.map(|v| v as u32)));
            (self.view(&b, Some(8), ARRAY_BUFFER), GLTF_U16, u.scale, lo, hi)
        } else {
            // Metres from the node's origin; a blob whose extent overflows `f32` (only a
            // hand-made one) keeps its integers and per-axis steps instead, a valid glTF.
            let metres = |scale: [f64; 3]| -> Vec<[f32; 3]> {
                p.ints.iter().map(|v| std::array::from_fn(|a| (f64::from(v[a]) * scale[a]) as f32)).collect()
            };
            let (values, scale) = match metres(p.scale) {
                m if m.iter().flatten().all(|c| c.is_finite()) => (m, [1.0; 3]),
                _ => (metres([1.0; 3]), p.scale),
            };
            let b: Vec<u8> = values.iter().flatten().flat_map(|c| c.to_le_bytes()).collect();
            let (lo, hi) = extent(values.iter().map(|v| v.map(f64::from)));
            (self.view(&b, Some(12), ARRAY_BUFFER), GLTF_FLOAT, scale, json!(lo), json!(hi))
        };
        let acc = self.accessor(json!({
            "bufferView": view, "componentType": component, "count": count, "type": "VEC3",
            "min": lo, "max": hi,
        }));
        if component == GLTF_U16 {
            self.json["extensionsUsed"] = json!(["KHR_mesh_quantization"]);
            self.json["extensionsRequired"] = json!(["KHR_mesh_quantization"]);
        }
        self.json["nodes"] = json!([{ "mesh": 0, "translation": p.translation, "scale": scale }]);
        acc
    }

    /// Unit normals as `BYTE` normalized (`KHR_mesh_quantization`), padded to 4 bytes each.
    fn normals(&mut self, normals: &[[i8; 3]]) -> usize {
        let b: Vec<u8> = normals.iter().flat_map(|n| [n[0] as u8, n[1] as u8, n[2] as u8, 0]).collect();
        let view = self.view(&b, Some(4), ARRAY_BUFFER);
        self.json["extensionsUsed"] = json!(["KHR_mesh_quantization"]);
        self.json["extensionsRequired"] = json!(["KHR_mesh_quantization"]);
        self.accessor(json!({
            "bufferView": view, "componentType": GLTF_I8, "normalized": true, "count": normals.len(), "type": "VEC3",
        }))
    }

    fn material(&mut self, rgb: [f64; 3], points: bool) {
        self.json["materials"] = json!([{
            "name": if points { "points" } else { "terrain" },
            "pbrMetallicRoughness": {
                "baseColorFactor": [rgb[0], rgb[1], rgb[2], 1.0],
                "metallicFactor": 0.0,
                "roughnessFactor": 1.0,
            },
        }]);
    }

    /// `FLOAT` positions in the frame `matrix` (the glTF node's, column-major).
    fn float_positions(&mut self, g: &[[f64; 3]], matrix: [f64; 16]) -> usize {
        let mut b = Vec::with_capacity(g.len() * 12);
        let (mut lo, mut hi) = ([f32::INFINITY; 3], [f32::NEG_INFINITY; 3]);
        for p in g {
            for a in 0..3 {
                let v = p[a] as f32;
                lo[a] = lo[a].min(v);
                hi[a] = hi[a].max(v);
                b.extend_from_slice(&v.to_le_bytes());
            }
        }
        if g.is_empty() {
            (lo, hi) = ([0.0; 3], [0.0; 3]);
        }
        let view = self.view(&b, Some(12), ARRAY_BUFFER);
        let acc = self.accessor(json!({
            "bufferView": view, "componentType": GLTF_FLOAT, "count": g.len(), "type": "VEC3", "min": lo, "max": hi,
        }));
        self.json["nodes"] = json!([{ "mesh": 0, "matrix": matrix }]);
        acc
    }

    fn mesh(mut self, pos: usize, vertices: usize, tris: &[[u32; 3]], normals: &[[i8; 3]]) -> Self {
        let g = &mut self;
        let nrm = g.normals(normals);
        let (view, component) = if vertices <= MAX_U8_VERTICES {
            let b: Vec<u8> = tris.iter().flatten().map(|&i| i as u8).collect();
            (g.view(&b, None, ELEMENT_ARRAY_BUFFER), GLTF_U8)
        } else if vertices <= MAX_U16_VERTICES {
            let b: Vec<u8> = tris.iter().flatten().flat_map(|&i| (i as u16).to_le_bytes()).collect();
            (g.view(&b, None, ELEMENT_ARRAY_BUFFER), GLTF_U16)
        } else {
            let b: Vec<u8> = tris.iter().flatten().flat_map(|&i| i.to_le_bytes()).collect();
            (g.view(&b, None, ELEMENT_ARRAY_BUFFER), GLTF_U32)
        };
        let idx =
            g.accessor(json!({ "bufferView": view, "componentType": component, "count": tris.len() * 3, "type": "SCALAR" }));
        g.material([0.64, 0.60, 0.50], false);
        g.json["meshes"] = json!([{ "primitives": [{ "attributes": { "POSITION": pos, "NORMAL": nrm }, "indices": idx, "mode": 4, "material": 0 }] }]);
        self
    }

    fn points(mut self, pos: usize, normals: &[[i8; 3]]) -> Self {
        let nrm = self.normals(normals);
        self.material([0.78, 0.70, 0.52], true);
        self.json["meshes"] = json!([{
            "primitives": [{ "attributes": { "POSITION": pos, "NORMAL": nrm }, "mode": 0, "material": 0 }]
        }]);
        self
    }

    /// The GLB of this document ([`write_glb`]), its one buffer the BIN chunk.
    pub(crate) fn finish(mut self) -> Vec<u8> {
        while !self.bin.len().is_multiple_of(4) {
            self.bin.push(0);
        }
        self.json["buffers"] = json!([{ "byteLength": self.bin.len() }]);
        write_glb(&self.json, self.bin)
    }
}

/// A GLB container of `json` and `bin`: the 12-byte header, the JSON chunk (space-padded) and
/// the BIN chunk (zero-padded to 4 bytes). The one writer of every GLB in 3D Tiles: the plain
/// ones ([`glb()`]) and their `EXT_meshopt_compression` form ([`super::meshopt::compress_glb`]).
#[must_use]
pub fn write_glb(json: &Value, mut bin: Vec<u8>) -> Vec<u8> {
    while !bin.len().is_multiple_of(4) {
        bin.push(0);
    }
    let mut text = serde_json::to_vec(json).unwrap_or_default();
    while !text.len().is_multiple_of(4) {
        text.push(b' ');
    }
    let total = 12 + 8 + text.len() + 8 + bin.len();
    let mut out = Vec::with_capacity(total);
    out.extend_from_slice(b"glTF");
    out.extend_from_slice(&2u32.to_le_bytes());
    out.extend_from_slice(&(total as u32).to_le_bytes());
    out.extend_from_slice(&(text.len() as u32).to_le_bytes());
    out.extend_from_slice(&0x4E4F_534Au32.to_le_bytes());
    out.extend_from_slice(&text);
    out.extend_from_slice(&(bin.len() as u32).to_le_bytes());
    out.extend_from_slice(&0x004E_4942u32.to_le_bytes());
    out.extend_from_slice(&bin);
    out
}

/// Per-axis least and greatest of `values` (zeros when there are none), as accessor bounds.
fn extent(values: impl Iterator<Item = [f64; 3]>) -> ([f64; 3], [f64; 3]) {
    let mut b = Bounds::empty();
    values.for_each(|v| b.extend(v));
    if b.min.x > b.max.x { ([0.0; 3], [0.0; 3]) } else { (b.min.to_array(), b.max.to_array()) }
}

fn push(doc: &mut Value, array: &str, v: Value) -> usize {
    if let Some(a) = doc.get_mut(array).and_then(Value::as_array_mut) {
        a.push(v);
        a.len() - 1
    } else {
        doc[array] = json!([v]);
        0
    }
}

#[cfg(test)]
#[allow(clippy::float_cmp)] // powers of two and their multiples are exact
mod tests {
    use super::*;

    fn positions(scale: [f64; 3], ints: Vec<[u32; 3]>) -> Positions {
        let max = std::array::from_fn(|a| ints.iter().map(|p| p[a]).max().unwrap_or(0));
        Positions { ints, translation: [1.0, 2.0, 3.0], scale, max }
    }

    #[test]
    fn uniform_positions_take_the_finest_step_when_the_others_are_whole_multiples() {
        // 10 m cells, 1/16 m heights: x and z (glTF) count sixteenths of a metre.
        let p = positions([10.0, 1.0 / 16.0, 10.0], vec![[0, 5, 0], [256, 40, 3]]);
        let u = p.uniform().unwrap();
        assert_eq!(u.scale, [1.0 / 16.0; 3]);
        assert_eq!(u.ints, vec![[0, 5, 0], [256 * 160, 40, 480]]);
        assert_eq!(u.max, [256 * 160, 40, 480]);
        assert_eq!(u.translation, p.translation);
        // The same points in metres, either way.
        for (a, b) in p.ints.iter().zip(&u.ints) {
            for k in 0..3 {
                assert_eq!(f64::from(a[k]) * p.scale[k], f64::from(b[k]) * u.scale[k]);
            }
        }
        // The finest step on any axis (degree rasters: x/y finer than z).
        let u = positions([1.0 / 64.0, 0.25, 1.0 / 64.0], vec![[7, 3, 9]]).uniform().unwrap();
        assert_eq!((u.scale, u.ints), ([1.0 / 64.0; 3], vec![[7, 48, 9]]));
    }

    #[test]
    fn no_uniform_positions_where_steps_are_not_multiples_or_do_not_fit() {
        // 0.3 m cells are no whole number of 1/64 m steps.
        assert!(positions([0.3, 1.0 / 64.0, 0.3], vec![[1, 1, 1]]).uniform().is_none());
        // 256 cells of 10 m in 1/64 m steps: 163,840 > 65,535.
        assert!(positions([10.0, 1.0 / 64.0, 10.0], vec![[256, 0, 0]]).uniform().is_none());
        assert_eq!(positions([10.0, 1.0 / 64.0, 10.0], vec![[256, 0, 0]]).least_coarsening(), 2);
        // A ratio beyond 16 bits, non-finite and zero steps.
        assert!(positions([1e6, 1e-3, 1e6], vec![[0, 0, 0]]).uniform().is_none());
        for bad in [f64::NAN, f64::INFINITY, 0.0, -1.0] {
            let p = positions([1.0, bad, 1.0], vec![[1, 1, 1]]);
            assert!(p.uniform().is_none(), "{bad}");
            assert!((1..=MAX_COARSENING).contains(&p.least_coarsening()));
        }
        // Already uniform and in range: kept as is; empty: fine.
        let p = positions([0.5; 3], vec![[65_535, 0, 1]]);
        assert_eq!(p.uniform().unwrap().ints, p.ints);
        assert!(positions([0.5; 3], vec![]).uniform().is_some());
    }

    #[test]
    fn float_positions_are_metres_and_stay_finite_beyond_f32() {
        // 0.3 m cells: no uniform grid, so metres from the origin with scale 1.
        let mut g = Gltf::new(TileKey::new(0, 0, 0), 0);
        let acc = g.positions(&positions([0.3, 1.0 / 64.0, 0.3], vec![[0, 0, 0], [10, 64, 20]]));
        assert_eq!(g.json["accessors"][acc]["max"], json!([3.0, 1.0, 6.0]));
        assert_eq!(g.json["nodes"][0]["scale"], json!([1.0, 1.0, 1.0]));
        // A (hand-made) extent past f32's range keeps integers and per-axis steps: no infinity,
        // which JSON would write as null.
        let mut g = Gltf::new(TileKey::new(0, 0, 0), 0);
        let acc = g.positions(&positions([1e35, 1e-3, 1e35], vec![[0, 0, 0], [100_000, 7, 3]]));
        for m in ["min", "max"] {
            let v = g.json["accessors"][acc][m].as_array().unwrap().clone();
            assert!(v.iter().all(|c| c.as_f64().is_some_and(f64::is_finite)), "{m}: {v:?}");
        }
        assert_eq!(g.json["nodes"][0]["scale"], json!([1e35, 1e-3, 1e35]));
    }
}
