//! One node of a terrain pyramid: its TIN (level 0), quantized exactly as its blob stores it and
//! measured against every full-resolution sample it covers, its point levels (1..=K) baked by a
//! [`PointBaker`], and their blobs. [`bake_node`] is the entry point for a single node (what the
//! server's on-demand baker calls); the whole-raster bake in `terrain` runs the same steps per
//! node, so both write the same bytes.

use crate::codec::{self, Quantization};
use crate::geom::{Bounds, ErrorFigures, Mesh, PointCloud};
use crate::lod::{self, PointBaker};
use crate::raster::{Georef, LoadedRaster, WindowReader};
use crate::store::{self, NodeEntry, NodeLevel, SkipReason, SkippedLevel, Store, StoreError};
use crate::tiling::{Pyramid, TileKey};
use crate::tin;

use super::{
    BakeError, BakeOptions, MESH_Z_STEPS_PER_ERROR, POINT_STEPS_PER_CELL, PointLevels, check_options,
};

/// Bakes one node (every level) of `raster` and writes its blobs into `store`, exactly as
/// [`super::bake_terrain`] would (same bytes); returns its index entry (the index and manifest
/// are the caller's). Used by the server to bake tiles on first request: the caller has prepared
/// the store with [`Store::begin_bake`] and [`super::options_record`].
pub fn bake_node(
    raster: &LoadedRaster,
    key: TileKey,
    opts: &BakeOptions,
    baker: &PointBaker,
    store: &Store,
) -> Result<NodeEntry, BakeError> {
    check_options(opts)?;
    let hf = &raster.heights;
    let pyramid = Pyramid::new(hf.width, hf.height, opts.tile_size)?;
    if !pyramid.contains(key) {
        return Err(BakeError::OutsidePyramid(key));
    }
    let parent = match parent_key(key) {
        Some(p) if opts.point_levels == PointLevels::Auto => {
            Some(parent_info(&pyramid, hf, &raster.georef, p, opts, Some(store))?)
        }
        _ => None,
    };
    bake_node_in(&pyramid, hf, &raster.georef, key, opts, baker, store, parent)
}

/// The parent of `key` in the quadtree, if it has one.
#[must_use]
pub(crate) fn parent_key(key: TileKey) -> Option<TileKey> {
    (key.z > 0).then(|| TileKey::new(key.z - 1, key.x / 2, key.y / 2))
}

/// What a node's parent leaves its point levels ([`lod::reach`]): the error of the parent's
/// finest level (its mesh) and its box (which holds the centres of the nodes whose refinement
/// keeps the parent split).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ParentInfo {
    pub error: f64,
    pub bounds: Bounds,
}

impl ParentInfo {
    /// From the parent's index entry (a baked or resumed node).
    #[must_use]
    pub fn of_entry(e: &NodeEntry) -> Self {
        Self { error: e.levels.first().map_or(f64::INFINITY, |l| l.errors.geometric()), bounds: e.bounds }
    }

    /// From the parent's level 0 as built.
    #[must_use]
    pub fn of_mesh(nm: &NodeMesh) -> Self {
        Self { error: nm.mesh_errors.geometric(), bounds: nm.bounds }
    }
}

/// [`ParentInfo`] of `parent`: from its mesh blob when `store` holds it whole, else by building
/// its level 0 (the same figures: a blob's header holds the errors and box it was built with).
pub(crate) fn parent_info(
    pyramid: &Pyramid,
    reader: &dyn WindowReader,
    georef: &Georef,
    parent: TileKey,
    opts: &BakeOptions,
    store: Option<&Store>,
) -> Result<ParentInfo, BakeError> {
    if let Some(store) = store
        && let Some(bytes) = store.read_blob(parent, 0)?
        && let Ok(b) = codec::decode(&bytes)
        && b.header.key == parent
        && b.header.level == 0
    {
        return Ok(ParentInfo {
            error: b.header.errors.geometric(),
            bounds: Bounds::new(b.header.bounds[0], b.header.bounds[1]),
        });
    }
    Ok(ParentInfo::of_mesh(&node_mesh(pyramid, reader, georef, parent, opts)?))
}

/// [`bake_node`] inside a pyramid already checked: TIN, the point levels its plan bakes (by
/// `baker`; on the GPU all of them in one submission), blobs written. `parent` is required for
/// `--point-levels auto` below the root ([`NodeMesh::plan_levels`]).
#[allow(clippy::too_many_arguments)]
pub(super) fn bake_node_in(
    pyramid: &Pyramid,
    reader: &dyn WindowReader,
    georef: &Georef,
    key: TileKey,
    opts: &BakeOptions,
    baker: &PointBaker,
    store: &Store,
    parent: Option<ParentInfo>,
) -> Result<NodeEntry, BakeError> {
    let nm = node_mesh(pyramid, reader, georef, key, opts)?;
    let plan = nm.plan_levels(opts, parent);
    let clouds = baker.bake_levels(&nm.mesh, &plan.grids(&nm))?.0;
    write_node(&nm, &plan, clouds, store)
}

/// Which point levels of a node are baked ([`NodeMesh::plan_levels`]).
#[derive(Debug, Clone, PartialEq)]
pub struct LevelPlan {
    /// Per point level (1, 2, …): `None` to bake it, or why it is not baked.
    pub levels: Vec<(u8, Option<SkipReason>)>,
    /// A baked level is kept only if its measured error is under this ([`lod::reach`]).
    pub reach: f64,
}

impl LevelPlan {
    /// The grids of the levels to bake, in order.
    #[must_use]
    pub fn grids(&self, nm: &NodeMesh) -> Vec<([f64; 3], f64)> {
        self.to_bake().map(|l| nm.level_grid(l)).collect()
    }

    /// The levels to bake, in order.
    pub fn to_bake(&self) -> impl Iterator<Item = u8> + '_ {
        self.levels.iter().filter(|(_, s)| s.is_none()).map(|&(l, _)| l)
    }
}

/// The world frame of a node sample grid.
struct GridFrame<'a> {
    g: &'a Georef,
}

impl GridFrame<'_> {
    fn world(&self, col: f64, row: f64, z: f64) -> [f64; 3] {
        [self.g.x0 + col * self.g.dx, self.g.y0 + row * self.g.dy, z]
    }
    fn cell(&self) -> f64 {
        self.g.dx.abs().max(self.g.dy.abs())
    }
}

/// Mean radius of the Earth, metres: the curvature [`Curvature`] takes into the TIN.
const EARTH_RADIUS: f64 = crate::crs::ecef::MEAN_RADIUS;

/// A tileset placed on the Earth draws a node's flat triangles as chords in ECEF, which dip below
/// the ellipsoid by up to L²/8R between their vertices (2 m for a 10 km edge). The TIN is
/// therefore built and measured on heights lowered by the drop of the Earth's surface below the
/// plane tangent at the node's centre, d²/2R: a planar interpolation of those heights errs as
/// the chords do (to second order in d/R), so the greedy insertion keeps the chords within the
/// bound and the measured error includes them. Vertices keep their true heights. A local frame
/// (no CRS) is flat: no drop.
struct Curvature {
    centre: Option<(f64, f64)>,
}

impl Curvature {
    fn drop(&self, x: f64, y: f64) -> f64 {
        self.centre.map_or(0.0, |(xc, yc)| ((x - xc).powi(2) + (y - yc).powi(2)) / (2.0 * EARTH_RADIUS))
    }
}

/// A node's level 0: its quantized TIN with measured errors, what its point levels are baked
/// from.
pub struct NodeMesh {
    pub key: TileKey,
    pub bounds: Bounds,
    pub mesh: Mesh,
    pub mesh_errors: ErrorFigures,
    pub quantization: Quantization,
    /// Edge of the node's level-1 cell (doubling per level).
    pub level1_cell: f64,
}

impl NodeMesh {
    /// The cubic grid of point level `level` (≥ 1): (origin, cell edge).
    #[must_use]
    pub fn level_grid(&self, level: u8) -> ([f64; 3], f64) {
        let cell = self.level1_cell * f64::from(1u32 << (level - 1));
        let origin = [self.bounds.min[0], self.bounds.min[1], (self.bounds.min[2] / cell).floor() * cell];
        (origin, cell)
    }

    /// Quantizes a baked cloud of `level` as its blob stores it and measures its errors.
    #[must_use]
    pub fn finish_level(&self, level: u8, pc: PointCloud) -> (PointCloud, ErrorFigures, Quantization) {
        let (pc, q) = self.quantize_level(level, pc);
        let errors = self.measure_level(level, &pc);
        (pc, errors, q)
    }

    /// A baked cloud of `level` on its blob's quantization grid, and that grid.
    #[must_use]
    pub fn quantize_level(&self, level: u8, mut pc: PointCloud) -> (PointCloud, Quantization) {
        let (_, cell) = self.level_grid(level);
        let q = Quantization {
            xy_step: cell / f64::from(POINT_STEPS_PER_CELL),
            z_step: cell / f64::from(POINT_STEPS_PER_CELL),
        };
        // Into the node's box as well as onto the grid: a slice's centre can lie above the
        // surface's top, and the blob header promises its bounds hold every point. If the
        // bounds are unusable the encoder reports it.
        pc.positions = codec::snap_positions(&pc.positions, &self.bounds, q)
            .unwrap_or_else(|_| codec::quantize_positions(&pc.positions, &self.bounds, q));
        (pc, q)
    }

    /// Which point levels to bake: none with `--point-levels none`; all with `all` or at the
    /// root; with `auto` below the root, those whose error is not already bounded (by their
    /// spacing, [`lod::reach::gap_lower_bound`]) at or above what the parent leaves them to
    /// reach ([`lod::reach::reach`]: the parent's mesh error plus the threshold angle times the
    /// distance from this node's centre to the farthest corner of the parent's box).
    #[must_use]
    pub fn plan_levels(&self, opts: &BakeOptions, parent: Option<ParentInfo>) -> LevelPlan {
        let reach = match (opts.point_levels, parent) {
            (PointLevels::Auto, Some(p)) => {
                lod::reach::reach(p.error, lod::reach::farthest_corner(self.bounds.center(), &p.bounds))
            }
            _ => f64::INFINITY,
        };
        let footprint = (self.bounds.max.x - self.bounds.min.x) * (self.bounds.max.y - self.bounds.min.y);
        let levels = (1..=opts.levels)
            .map(|l| {
                let skip = if opts.point_levels == PointLevels::None {
                    Some(SkipReason::Policy)
                } else if reach.is_finite() && {
                    let (origin, cell) = self.level_grid(l);
                    // The bound never exceeds about 0.44 cell (a covering by N ≥ A / cell²
                    // discs): not worth computing below that.
                    cell * 0.5 >= reach
                        && lod::reach::gap_lower_bound(&self.mesh, origin, cell, footprint) >= reach
                } {
                    Some(SkipReason::PredictedUnreachable)
                } else {
                    None
                };
                (l, skip)
            })
            .collect();
        LevelPlan { levels, reach }
    }

    /// The errors of a quantized cloud of `level` against this node's mesh.
    #[must_use]
    pub fn measure_level(&self, level: u8, pc: &PointCloud) -> ErrorFigures {
        let (_, cell) = self.level_grid(level);
        lod::cpu::measure_points(&self.mesh, pc, cell, lod::TERRAIN_FOOTPRINT_HALF)
    }
}

/// A node's TIN, quantized as the blob stores it, with its errors measured against every
/// full-resolution sample it covers. Pure apart from reading the raster window.
pub fn node_mesh(
    pyramid: &Pyramid,
    reader: &dyn WindowReader,
    georef: &Georef,
    key: TileKey,
    opts: &BakeOptions,
) -> Result<NodeMesh, BakeError> {
    let frame = GridFrame { g: georef };
    let step = pyramid.step(key.z);
    let grid = pyramid.grid(key);
    let mut heights = Vec::new();
    reader.read_window(&grid.cols, &grid.rows, &mut heights)?;
    let node_error = opts.max_error * f64::from(step);
    let span = pyramid.span(key);
    let curvature = Curvature {
        centre: georef.crs.is_some().then(|| {
            let c = frame.world(
                f64::from(span.col0 + span.col1) / 2.0,
                f64::from(span.row0 + span.row1) / 2.0,
                0.0,
            );
            (c[0], c[1])
        }),
    };
    let lowered: Vec<f32> = if curvature.centre.is_some() {
        let nc = grid.cols.len();
        heights
            .iter()
            .enumerate()
            .map(|(k, &h)| {
                let p = frame.world(f64::from(grid.cols[k % nc]), f64::from(grid.rows[k / nc]), 0.0);
                (f64::from(h) - curvature.drop(p[0], p[1])) as f32
            })
            .collect()
    } else {
        Vec::new()
    };
    let tin_heights = if lowered.is_empty() { &heights } else { &lowered };
    let t = tin::build(&grid, tin_heights, node_error).map_err(|source| BakeError::Tin { key, source })?;

    // World mesh, counter-clockwise seen from +z whatever the signs of dx and dy.
    let nc = grid.cols.len();
    let mut mesh = Mesh {
        positions: t
            .vertices
            .iter()
            .map(|&[i, j]| {
                let z = f64::from(heights[j as usize * nc + i as usize]);
                frame.world(f64::from(grid.cols[i as usize]), f64::from(grid.rows[j as usize]), z)
            })
            .collect(),
        triangles: t.triangles,
    };
    if georef.dx * georef.dy < 0.0 {
        for tri in &mut mesh.triangles {
            tri.swap(1, 2);
        }
    }
    let mut bounds = Bounds::of_points(&mesh.positions);
    for (c, r) in [(span.col0, span.row0), (span.col1, span.row1)] {
        let p = frame.world(f64::from(c), f64::from(r), bounds.min[2]);
        bounds.extend(p);
    }
    // Heights are quantized on one global grid per depth — a power-of-two step, with the origin
    // a multiple of it — so a border vertex decodes to bit-identical heights in both neighbours.
    let z_step = pow2_at_most(
        (node_error / MESH_Z_STEPS_PER_ERROR).max(f64::from(f32::EPSILON) * bounds.max[2].abs().max(1.0)),
    );
    bounds.min[2] = (bounds.min[2] / z_step).floor() * z_step;
    let (adx, ady) = (georef.dx.abs(), georef.dy.abs());
    let xy_step = if (adx - ady).abs() <= 1e-12 * adx {
        // Square cells: vertices sit on the raster grid, which starts at this node's corner,
        // so every x and y is an exact multiple of the cell from `bounds.min`.
        adx
    } else {
        // Rectangular cells (degree rasters): one power-of-two step on a global grid, fine
        // enough (≤ 1/1024 cell and ≤ 1/64 m, so a vertex lands within 1.1 cm of its sample on
        // the Earth) yet within the codec's range over the node, and again identical in both
        // neighbours.
        let span = (bounds.max[0] - bounds.min[0]).max(bounds.max[1] - bounds.min[1]);
        let step = pow2_at_most((adx.min(ady) / 1024.0).min(1.0 / 64.0).max(span / f64::from(1u32 << 30)));
        for a in 0..2 {
            bounds.min[a] = (bounds.min[a] / step).floor() * step;
        }
        step
    };
    let mesh_q = Quantization { xy_step, z_step };
    mesh.positions = codec::quantize_positions(&mesh.positions, &bounds, mesh_q);
    // A vertex rounded up past the box (the top height rarely lies on the grid) stays where it
    // is — its neighbour stores the same border vertex — and the box grows to hold it.
    let bounds = codec::quantized_bounds(&bounds, &mesh.positions, mesh_q);

    // Measured against every full-resolution sample the node covers, in sample coordinates,
    // read in strips of rows (one strip up to `tin::MEASURE_STRIP_SAMPLES` samples).
    let cols: Vec<u32> = (span.col0..=span.col1).collect();
    let sample_space: Vec<[f64; 3]> = mesh
        .positions
        .iter()
        .map(|p| {
            [
                (p[0] - georef.x0) / georef.dx,
                (p[1] - georef.y0) / georef.dy,
                p[2] - curvature.drop(p[0], p[1]),
            ]
        })
        .map(|p| [p[0].round(), p[1].round(), p[2]])
        .collect();
    let mesh_errors = tin::measure_vertical_strips(
        &sample_space,
        &mesh.triangles,
        span,
        tin::MEASURE_STRIP_SAMPLES,
        |r0, r1, out| {
            let rows: Vec<u32> = (r0..=r1).collect();
            reader.read_window(&cols, &rows, out)?;
            if curvature.centre.is_some() {
                let nc = cols.len();
                for (k, v) in out.iter_mut().enumerate() {
                    let p = frame.world(f64::from(cols[k % nc]), f64::from(rows[k / nc]), 0.0);
                    *v = (f64::from(*v) - curvature.drop(p[0], p[1])) as f32;
                }
            }
            Ok(())
        },
    )
    .map_err(|e| match e {
        tin::StripError::Tin(source) => BakeError::Tin { key, source },
        tin::StripError::Read(e) => BakeError::Raster(e),
    })?;
    // A warped dataset's heights are themselves resampled: their error adds to the mesh's.
    let mut mesh_errors = mesh_errors;
    mesh_errors.max += georef.resample_error;

    Ok(NodeMesh {
        key,
        bounds,
        mesh,
        mesh_errors,
        quantization: mesh_q,
        level1_cell: frame.cell() * f64::from(step) * 2.0,
    })
}

/// Encodes a node's levels (`clouds` are the levels `plan` bakes, in order), keeps those that
/// pay — cheaper than every finer level kept ([`store::Payer`]) and, measured, under the plan's
/// reach — and writes their blobs (the others get an `unpaid` marker saying why); returns its
/// index entry. The cost rule looks at counts and bytes only, so a point level is measured only
/// once it is known to be cheaper: the blobs are those of measuring every level.
pub(super) fn write_node(
    nm: &NodeMesh,
    plan: &LevelPlan,
    clouds: Vec<PointCloud>,
    store: &Store,
) -> Result<NodeEntry, BakeError> {
    let key = nm.key;
    let codec_err = |level: u8| move |source| BakeError::Codec { key, level, source };
    let mesh_blob = codec::encode_mesh(key, 0, &nm.bounds, nm.quantization, &nm.mesh, nm.mesh_errors)
        .map_err(codec_err(0))?;
    let mesh_level = NodeLevel {
        level: 0,
        errors: nm.mesh_errors,
        count: nm.mesh.positions.len() as u32,
        triangles: nm.mesh.triangles.len() as u32,
        bytes: mesh_blob.len() as u64,
        checksum: codec::decode_header(&mesh_blob).map_err(codec_err(0))?.checksum,
    };
    let mut payer = store::Payer::default();
    payer.keep(mesh_level.count, mesh_level.bytes);
    let mut levels: Vec<LevelToWrite> = vec![(mesh_level.level, Ok((mesh_level, mesh_blob)))];
    let mut clouds = clouds.into_iter();
    for &(level, planned_skip) in &plan.levels {
        if let Some(why) = planned_skip {
            levels.push((level, Err(why)));
            continue;
        }
        let Some(pc) = clouds.next() else {
            return Err(BakeError::Plan(format!("tile {key}: no point cloud baked for level {level}")));
        };
        let (pc, q) = nm.quantize_level(level, pc);
        let count = pc.positions.len() as u32;
        let mut kept = Err(SkipReason::Costlier);
        if payer.may_pay(count) {
            let draft = codec::draft_points(key, level, &nm.bounds, q, &pc).map_err(codec_err(level))?;
            if payer.would_pay(count, draft.len() as u64) {
                let errors = nm.measure_level(level, &pc);
                if errors.geometric() < plan.reach {
                    payer.keep(count, draft.len() as u64);
                    let blob = draft.finish(errors).map_err(codec_err(level))?;
                    let info = NodeLevel {
                        level,
                        errors,
                        count,
                        triangles: 0,
                        bytes: blob.len() as u64,
                        checksum: codec::decode_header(&blob).map_err(codec_err(level))?.checksum,
                    };
                    kept = Ok((info, blob));
                } else {
                    kept = Err(SkipReason::Unreachable);
                }
            }
        }
        levels.push((level, kept));
    }
    let (levels, _) = write_levels(store, key, levels)?;
    Ok(NodeEntry { key, bounds: nm.bounds, levels })
}

/// Writes the blobs of one node's levels that pay and the `unpaid` markers of the others;
/// returns the kept levels, finest first, and the others. Shared by terrain nodes and model
/// tilesets.
pub(crate) fn write_paying(
    store: &Store,
    key: TileKey,
    blobs: Vec<(NodeLevel, Vec<u8>)>,
) -> Result<(Vec<NodeLevel>, Vec<SkippedLevel>), store::StoreError> {
    let infos: Vec<NodeLevel> = blobs.iter().map(|(l, _)| *l).collect();
    let pays = store::levels_that_pay(&infos);
    let levels = blobs.into_iter().zip(pays).map(|((info, bytes), pays)| {
        (info.level, if pays { Ok((info, bytes)) } else { Err(SkipReason::Costlier) })
    });
    write_levels(store, key, levels.collect())
}

/// One level of a node to write: its id, and its index entry and blob if it is kept, else why
/// not.
type LevelToWrite = (u8, Result<(NodeLevel, Vec<u8>), SkipReason>);

/// Writes one node's kept levels (`Ok`: their blobs) and the `unpaid` markers of the others
/// (`Err`: the reason), coarsest first and the mesh (level 0) last: a node counts as complete on
/// resume only once its mesh blob exists, and then every other level has its blob or its
/// marker. Returns the kept levels, finest first, and the skipped ones.
fn write_levels(
    store: &Store,
    key: TileKey,
    levels: Vec<LevelToWrite>,
) -> Result<(Vec<NodeLevel>, Vec<SkippedLevel>), store::StoreError> {
    let mut kept = Vec::with_capacity(levels.len());
    let mut skipped = Vec::new();
    for (level, blob) in levels.into_iter().rev() {
        match blob {
            Ok((info, bytes)) => {
                store.write_blob(key, level, &bytes)?;
                kept.push(info);
            }
            Err(why) => {
                store.write_unpaid(key, level, why)?;
                skipped.push(SkippedLevel { level, why });
            }
        }
    }
    kept.reverse();
    skipped.reverse();
    Ok((kept, skipped))
}

/// The index entry of a node whose mesh blob and every point level's blob are present, whole
/// and valid (they decode completely: exact length, payload checksum, geometry inside their
/// bounds — see [`codec::decode`]) and name that node and level — or, for a point level, whose
/// `unpaid` marker says it was left out — rebuilt from the blob headers, and holding only the
/// levels that pay (an earlier version stored them all); `None` for anything else — missing,
/// truncated, extended, flipped, or written by a version whose blobs this one refuses — which a
/// resumed bake bakes again (replacing its blobs). A store that cannot be read (an I/O error, a
/// bucket that fails or stalls past its retries) is an error, not a missing blob: re-baking
/// would only meet the same store.
pub fn node_from_blobs(store: &Store, key: TileKey, levels: u8) -> Result<Option<NodeEntry>, StoreError> {
    let mut out = Vec::new();
    let mut bounds = None;
    for level in 0..=levels {
        let Some(bytes) = store.read_blob(key, level)? else {
            if level > 0 && store.is_unpaid(key, level)? {
                continue;
            }
            return Ok(None);
        };
        let h = match codec::decode(&bytes) {
            Ok(b) => b.header,
            Err(e) => {
                tracing::warn!(tile = %key, level, "re-baking a damaged blob: {e}");
                return Ok(None);
            }
        };
        if h.key != key || h.level != level {
            return Ok(None);
        }
        bounds.get_or_insert(Bounds::new(h.bounds[0], h.bounds[1]));
        out.push(NodeLevel {
            level,
            errors: h.errors,
            count: h.vertex_count,
            triangles: h.triangle_count,
            bytes: bytes.len() as u64,
            checksum: h.checksum,
        });
    }
    let pays = store::levels_that_pay(&out);
    if pays.iter().any(|p| !p) {
        // Blobs of a bake from before levels had to pay: mark the ones that do not.
        for (l, _) in out.iter().zip(&pays).filter(|(_, p)| !**p) {
            store.write_unpaid(key, l.level, SkipReason::Costlier)?;
        }
        out = out.into_iter().zip(pays).filter(|(_, p)| *p).map(|(l, _)| l).collect();
    }
    Ok(bounds.map(|bounds| NodeEntry { key, bounds, levels: out }))
}

/// The largest power of two ≤ `v` (v > 0 and finite).
fn pow2_at_most(v: f64) -> f64 {
    2f64.powi(v.log2().floor() as i32)
}

#[cfg(test)]
mod one_node_tests {
    use super::*;

    /// `bake_node` writes the very bytes `bake_terrain` writes, and `options_record` is the record
    /// `bake` stores, so on-demand tiles and batch bakes resume each other.
    #[test]
    fn one_node_matches_full_bake() {
        let (w, h) = (65, 49);
        let raster = LoadedRaster {
            heights: crate::raster::Heightfield {
                width: w,
                height: h,
                data: crate::raster::synth::terrain(w, h, 3),
            },
            georef: Georef { dx: 10.0, dy: -10.0, ..Georef::default() },
            nodata_filled: 0,
            nodata_fallback: 0,
            format: "test".into(),
        };
        let opts = BakeOptions { tile_size: 32, max_error: 2.0, levels: 2, point_levels: PointLevels::Auto };
        let full = tempfile::tempdir().unwrap();
        let full_store = Store::new(full.path());
        super::super::bake_terrain(
            &raster,
            "t.tif",
            &opts,
            &PointBaker::Cpu,
            &full_store,
            &super::super::NoProgress,
        )
        .unwrap();
        let manifest = full_store.manifest().unwrap();
        assert_eq!(manifest.options, super::super::options_record(&raster, "t.tif", &opts));

        let one = tempfile::tempdir().unwrap();
        let one_store = Store::new(&one.path().join("ts"));
        one_store.begin_bake(&super::super::options_record(&raster, "t.tif", &opts)).unwrap();
        let key = TileKey::new(1, 1, 0);
        let entry = bake_node(&raster, key, &opts, &PointBaker::Cpu, &one_store).unwrap();
        assert_eq!(Some(&entry), full_store.node(key).unwrap().as_ref());
        for level in 0..=opts.levels {
            assert_eq!(one_store.read_blob(key, level).unwrap(), full_store.read_blob(key, level).unwrap());
        }
        assert_eq!(node_from_blobs(&one_store, key, opts.levels).unwrap(), Some(entry));
        assert!(bake_node(&raster, TileKey::new(1, 2, 0), &opts, &PointBaker::Cpu, &one_store).is_err());
    }
}

#[cfg(test)]
mod tests {
    use std::path::{Path, PathBuf};

    use super::*;
    use crate::raster::Heightfield;

    /// Every baked level measured and encoded, then the rule (cheaper than every finer level
    /// kept, and under the reach): what `write_node` does while measuring only the levels
    /// that are cheaper.
    fn write_node_measuring_every_level(
        nm: &NodeMesh,
        plan: &LevelPlan,
        clouds: Vec<PointCloud>,
        store: &Store,
    ) -> (Vec<NodeLevel>, Vec<SkippedLevel>) {
        let key = nm.key;
        let mesh_blob =
            codec::encode_mesh(key, 0, &nm.bounds, nm.quantization, &nm.mesh, nm.mesh_errors).unwrap();
        let info = |level, errors, count, triangles, blob: &Vec<u8>| NodeLevel {
            level,
            errors,
            count,
            triangles,
            bytes: blob.len() as u64,
            checksum: codec::decode_header(blob).unwrap().checksum,
        };
        let n = nm.mesh.positions.len() as u32;
        let mesh = info(0, nm.mesh_errors, n, nm.mesh.triangles.len() as u32, &mesh_blob);
        let mut payer = store::Payer::default();
        payer.keep(mesh.count, mesh.bytes);
        let mut levels: Vec<LevelToWrite> = vec![(0, Ok((mesh, mesh_blob)))];
        let mut clouds = clouds.into_iter();
        for &(level, skip) in &plan.levels {
            if let Some(why) = skip {
                levels.push((level, Err(why)));
                continue;
            }
            let (pc, errors, q) = nm.finish_level(level, clouds.next().unwrap());
            let blob = codec::encode_points(key, level, &nm.bounds, q, &pc, errors).unwrap();
            let l = info(level, errors, pc.positions.len() as u32, 0, &blob);
            let kept = if !payer.would_pay(l.count, l.bytes) {
                Err(SkipReason::Costlier)
            } else if errors.geometric() >= plan.reach {
                Err(SkipReason::Unreachable)
            } else {
                payer.keep(l.count, l.bytes);
                Ok((l, blob))
            };
            levels.push((level, kept));
        }
        write_levels(store, key, levels).unwrap()
    }

    /// Every file under `dir`, relative path and bytes, sorted.
    fn files(dir: &Path) -> Vec<(PathBuf, Vec<u8>)> {
        let mut out = Vec::new();
        let mut todo = vec![dir.to_path_buf()];
        while let Some(d) = todo.pop() {
            for e in std::fs::read_dir(&d).unwrap() {
                let p = e.unwrap().path();
                if p.is_dir() {
                    todo.push(p);
                } else {
                    out.push((p.strip_prefix(dir).unwrap().to_path_buf(), std::fs::read(&p).unwrap()));
                }
            }
        }
        out.sort();
        out
    }

    #[test]
    fn measuring_only_the_kept_levels_writes_what_measuring_every_level_writes() {
        let (mut kept_points, mut left_out) = (0, std::collections::BTreeMap::new());
        // Smooth ground (a TIN cheaper than most point levels) and rough ground with an exact
        // TIN (point levels pay), at several tile sizes.
        for (w, h, seed, roughness, max_error, tile_size) in
            [(97, 81, 3, 0.0, 1.0, 32), (65, 65, 8, 25.0, 0.0, 32), (129, 100, 5, 4.0, 0.5, 64)]
        {
            let data: Vec<f32> = crate::raster::synth::terrain(w, h, seed)
                .into_iter()
                .enumerate()
                .map(|(i, z)| {
                    z + roughness * (((i as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15) >> 40) % 7) as f32
                })
                .collect();
            let hf = Heightfield { width: w, height: h, data };
            let georef = Georef { dx: 10.0, dy: -10.0, ..Georef::default() };
            for point_levels in [PointLevels::All, PointLevels::Auto] {
                let opts = BakeOptions { tile_size, max_error, levels: 4, point_levels };
                let pyramid = Pyramid::new(w, h, tile_size).unwrap();
                let (a, b) = (tempfile::tempdir().unwrap(), tempfile::tempdir().unwrap());
                let (sa, sb) = (Store::new(a.path()), Store::new(b.path()));
                let mut parents = std::collections::HashMap::new();
                for key in pyramid.nodes() {
                    let nm = node_mesh(&pyramid, &hf, &georef, key, &opts).unwrap();
                    let parent = parent_key(key).map(|p| parents[&p]);
                    let plan = nm.plan_levels(&opts, parent);
                    let clouds = PointBaker::Cpu.bake_levels(&nm.mesh, &plan.grids(&nm)).unwrap().0;
                    let entry = write_node(&nm, &plan, clouds.clone(), &sa).unwrap();
                    let (kept, skipped) = write_node_measuring_every_level(&nm, &plan, clouds, &sb);
                    assert_eq!(entry.levels, kept, "{key}");
                    let ladder: Vec<u8> = (0..=opts.levels).collect();
                    assert_eq!(store::skipped_levels(&sa, &entry, &ladder).unwrap(), skipped, "{key}");
                    parents.insert(key, ParentInfo::of_entry(&entry));
                    kept_points += kept.iter().filter(|l| l.level > 0).count();
                    for s in &skipped {
                        *left_out.entry(s.why).or_insert(0) += 1;
                    }
                }
                assert_eq!(files(a.path()), files(b.path()));
            }
        }
        // Both measured paths of the rule were taken (the predicted one is `lod::reach`'s bound,
        // tested there against what the bake measures).
        assert!(
            kept_points > 0
                && left_out.contains_key(&SkipReason::Costlier)
                && left_out.contains_key(&SkipReason::Unreachable),
            "kept {kept_points}, left out {left_out:?}"
        );
    }
}
