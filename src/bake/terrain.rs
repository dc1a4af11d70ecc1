//! The bake pipeline: a loaded raster → per node a TIN (level 0) and point levels (1..=K) →
//! blobs and index chunks in a tileset directory, in parallel over nodes, resumable.
//!
//! Per node: read its sample grid through the `WindowReader`, build the TIN with the node's
//! error bound, convert to world coordinates and quantize exactly as the blob stores it, then
//! measure everything on the quantized geometry (the errors a client sees are the errors of the
//! bytes it receives). Point levels are baked from the quantized mesh.

use std::sync::atomic::{AtomicU64, Ordering};
use std::time::Instant;

use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use crate::codec::{self, Quantization};
use crate::geom::{Bounds, Errors, Mesh, PointCloud};
use crate::lod::{self, PointBaker};
use crate::raster::{Georef, LoadedRaster, WindowReader};
use crate::store::{
    IndexChunk, LevelSpec, LevelTotals, MANIFEST_FORMAT, MANIFEST_VERSION, Manifest, NodeEntry, NodeLevel,
    SUBTREE_LEVELS, SourceInfo, Store, chunk_root,
};
use crate::tiling::{Pyramid, TileKey};
use crate::tin;

/// Default TIN error bound for leaf tiles, in metres.
pub const DEFAULT_MAX_ERROR: f64 = 1.0;
/// Default number of point levels below the mesh.
pub const DEFAULT_LEVELS: u8 = 4;
/// Mesh heights are quantized to this fraction of the node's error bound.
pub const MESH_Z_STEPS_PER_ERROR: f64 = 64.0;
/// Point positions are quantized to this fraction of the level's cell edge.
pub const POINT_STEPS_PER_CELL: u32 = 64;
/// Most point levels a bake may ask for (cells of 2^16 leaf cells are larger than any raster).
pub const MAX_LEVELS: u8 = 16;

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct BakeOptions {
    pub tile_size: u32,
    pub max_error: f64,
    pub levels: u8,
}

impl Default for BakeOptions {
    fn default() -> Self {
        Self {
            tile_size: crate::tiling::DEFAULT_TILE_SIZE,
            max_error: DEFAULT_MAX_ERROR,
            levels: DEFAULT_LEVELS,
        }
    }
}

#[derive(Debug, thiserror::Error)]
pub enum BakeError {
    #[error("bake: {0}")]
    Options(String),
    #[error("bake: {0}")]
    Tiling(#[from] crate::tiling::TilingError),
    #[error("bake: tile {key}: {source}")]
    Tin { key: TileKey, source: tin::TinError },
    #[error("bake: tile {key} level {level}: {source}")]
    Codec { key: TileKey, level: u8, source: codec::CodecError },
    #[error(transparent)]
    Store(#[from] crate::store::StoreError),
    /// [`Progress::cancelled`] said stop; the reason (cancelled, deadline passed) is its text.
    #[error("bake stopped: {0}")]
    Cancelled(String),
    #[error("bake: {0}")]
    Baker(#[from] lod::BakerError),
}

/// Progress of a bake, reported as nodes complete (from any worker thread).
pub trait Progress: Sync {
    fn start(&self, total_nodes: u64, resumed_nodes: u64);
    fn node_done(&self);
    /// Whether the bake should stop: checked before every node, so a cancelled or timed-out
    /// bake ends with [`BakeError::Cancelled`] after the nodes in flight (each bounded by the
    /// input limits), leaving only whole blobs behind (a later bake resumes them).
    fn cancelled(&self) -> Option<String> {
        None
    }
}

/// A `Progress` that reports nothing.
pub struct NoProgress;
impl Progress for NoProgress {
    fn start(&self, _: u64, _: u64) {}
    fn node_done(&self) {}
}

#[derive(Debug, Clone, Serialize)]
pub struct BakeSummary {
    pub nodes: u64,
    pub nodes_resumed: u64,
    pub samples: u64,
    pub nodata_filled: u64,
    pub totals: Vec<LevelTotals>,
    pub seconds: f64,
    /// "cpu" or "gpu: <adapter>".
    pub point_baker: String,
    /// GPU batches submitted, and the largest one's buffers in bytes (0 on the CPU path).
    pub gpu_batches: u64,
    pub gpu_peak_batch_bytes: u64,
    pub gpu_budget_bytes: u64,
    /// Point levels the GPU path left to the CPU reference (too large for one batch).
    pub gpu_cpu_fallback_levels: u64,
}

impl BakeSummary {
    #[must_use]
    pub fn samples_per_second(&self) -> f64 {
        self.samples as f64 / self.seconds.max(1e-9)
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

/// Validates options before anything is written.
pub fn check_options(opts: &BakeOptions) -> Result<(), BakeError> {
    if !opts.max_error.is_finite() || opts.max_error < 0.0 {
        return Err(BakeError::Options(format!(
            "--max-error must be a finite number ≥ 0, got {}",
            opts.max_error
        )));
    }
    if opts.levels > MAX_LEVELS {
        return Err(BakeError::Options(format!(
            "--levels must be at most {MAX_LEVELS}, got {}",
            opts.levels
        )));
    }
    if opts.tile_size < 2 || opts.tile_size > 65_536 {
        return Err(BakeError::Options(format!(
            "--tile-size must be 2 to 65536 cells, got {}",
            opts.tile_size
        )));
    }
    Ok(())
}

/// The level table of a bake.
#[must_use]
pub fn level_specs(opts: &BakeOptions) -> Vec<LevelSpec> {
    let mut out = vec![LevelSpec {
        level: 0,
        kind: codec::Kind::Mesh,
        max_error: Some(opts.max_error),
        cell_leaf_cells: None,
        texture_size: None,
        precision_per_cell: None,
    }];
    for l in 1..=opts.levels {
        let cells = 1u32 << l;
        out.push(LevelSpec {
            level: l,
            kind: codec::Kind::Points,
            max_error: None,
            cell_leaf_cells: Some(cells),
            texture_size: Some(opts.tile_size.div_ceil(cells)),
            precision_per_cell: Some(POINT_STEPS_PER_CELL),
        });
    }
    out
}

/// Bakes `raster` into `store` with the CPU point baker (see [`bake_with`]).
pub fn bake(
    raster: &LoadedRaster,
    source_name: &str,
    opts: &BakeOptions,
    store: &Store,
    progress: &dyn Progress,
) -> Result<BakeSummary, BakeError> {
    bake_with(raster, source_name, opts, &PointBaker::Cpu, store, progress)
}

/// Bakes `raster` into `store`, point levels by `baker`. Resumes a bake with the same options,
/// keeping complete nodes.
pub fn bake_with(
    raster: &LoadedRaster,
    source_name: &str,
    opts: &BakeOptions,
    baker: &PointBaker,
    store: &Store,
    progress: &dyn Progress,
) -> Result<BakeSummary, BakeError> {
    check_options(opts)?;
    let t0 = Instant::now();
    let hf = &raster.heights;
    let pyramid = Pyramid::new(hf.width, hf.height, opts.tile_size)?;
    let options_json = serde_json::json!({
        "tile_size": opts.tile_size,
        "max_error": opts.max_error,
        "levels": opts.levels,
        "frame": raster.georef,
        "source": { "file": source_name, "width": hf.width, "height": hf.height, "crc32": heights_crc(&hf.data) },
        "format_version": codec::FORMAT_VERSION,
    });
    store.begin_bake(&options_json)?;

    // Larger nodes first: parents measure against more full-resolution samples, so starting them
    // early keeps both cores busy until the end.
    let nodes = pyramid.nodes();
    let resumed: Vec<Option<NodeEntry>> =
        nodes.par_iter().map(|&k| existing_node(store, k, opts.levels)).collect();
    let resumed_count = resumed.iter().filter(|r| r.is_some()).count() as u64;
    progress.start(nodes.len() as u64, resumed_count);
    // [batches, peak batch bytes, budget bytes, levels left to the CPU] of the GPU path.
    #[allow(unused_mut)]
    let mut gpu_report: Option<[u64; 4]> = None;
    let entries: Vec<NodeEntry> = match baker {
        PointBaker::Cpu => bake_nodes_cpu(&pyramid, raster, opts, &nodes, resumed, store, progress)?,
        #[cfg(feature = "gpu")]
        PointBaker::Gpu(gpu) => {
            let (entries, report) =
                bake_nodes_gpu(gpu, &pyramid, raster, opts, &nodes, resumed, store, progress)?;
            gpu_report =
                Some([report.batches, report.peak_batch_bytes, report.budget_bytes, report.cpu_jobs]);
            entries
        }
    };

    // Index chunks, then the manifest last.
    let mut chunks: std::collections::BTreeMap<TileKey, Vec<NodeEntry>> = std::collections::BTreeMap::new();
    let mut totals = vec![LevelTotals::default(); usize::from(opts.levels) + 1];
    let mut bounds = Bounds::empty();
    let mut hasher = crc32fast::Hasher::new();
    for e in &entries {
        for (t, l) in totals.iter_mut().zip(&e.levels) {
            t.add(l);
            // Every blob's checksum, in node order, names this exact content.
            hasher.update(&l.checksum.to_le_bytes());
        }
        bounds.extend(e.bounds.min);
        bounds.extend(e.bounds.max);
        chunks.entry(chunk_root(e.key)).or_default().push(e.clone());
    }
    for (root, nodes) in chunks {
        store.write_chunk(&IndexChunk { root, nodes })?;
    }
    let manifest = Manifest {
        format: MANIFEST_FORMAT.into(),
        version: MANIFEST_VERSION,
        content_version: format!("{:08x}", hasher.finalize()),
        source: SourceInfo {
            file: source_name.into(),
            format: raster.format.clone(),
            width: hf.width,
            height: hf.height,
            nodata_filled: raster.nodata_filled,
        },
        frame: raster.georef,
        tile_size: opts.tile_size,
        depth: pyramid.depth,
        subtree_levels: SUBTREE_LEVELS,
        bounds,
        levels: level_specs(opts),
        totals: totals.clone(),
        options: options_json,
        point_baker: baker.describe(),
    };
    store.finish_bake(&manifest)?;
    Ok(BakeSummary {
        nodes: nodes.len() as u64,
        nodes_resumed: resumed_count,
        samples: u64::from(hf.width) * u64::from(hf.height),
        nodata_filled: raster.nodata_filled,
        totals,
        seconds: t0.elapsed().as_secs_f64(),
        point_baker: baker.describe(),
        gpu_batches: gpu_report.map_or(0, |r| r[0]),
        gpu_peak_batch_bytes: gpu_report.map_or(0, |r| r[1]),
        gpu_budget_bytes: gpu_report.map_or(0, |r| r[2]),
        gpu_cpu_fallback_levels: gpu_report.map_or(0, |r| r[3]),
    })
}

/// The CPU path: every node on its own, in parallel.
fn bake_nodes_cpu(
    pyramid: &Pyramid,
    raster: &LoadedRaster,
    opts: &BakeOptions,
    nodes: &[TileKey],
    resumed: Vec<Option<NodeEntry>>,
    store: &Store,
    progress: &dyn Progress,
) -> Result<Vec<NodeEntry>, BakeError> {
    let hf = &raster.heights;
    let failures = AtomicU64::new(0);
    nodes
        .par_iter()
        .zip(resumed.into_par_iter())
        .map(|(&key, prev)| {
            if let Some(entry) = prev {
                return Ok(entry);
            }
            if failures.load(Ordering::Relaxed) > 0 {
                return Err(None);
            }
            if let Some(why) = progress.cancelled() {
                failures.fetch_add(1, Ordering::Relaxed);
                return Err(Some(BakeError::Cancelled(why)));
            }
            let r = bake_node(pyramid, hf, &raster.georef, key, opts, store);
            progress.node_done();
            r.map_err(|e| {
                failures.fetch_add(1, Ordering::Relaxed);
                Some(e)
            })
        })
        .collect::<Result<_, Option<BakeError>>>()
        .map_err(|e| e.unwrap_or_else(|| BakeError::Options("bake stopped after an earlier failure".into())))
}

/// Nodes per GPU round: their TINs are built (in parallel) while the GPU bakes the round
/// before, and their levels go to the GPU together, split into batches by the memory budget.
#[cfg(feature = "gpu")]
pub const GPU_ROUND_NODES: usize = 32;

/// The GPU path: rounds of nodes, each round's TINs built on the CPU while the GPU bakes the
/// previous round's point levels, which are then measured, encoded and written in parallel.
/// Each node's result is what it would be alone (a job's output does not depend on its batch).
#[cfg(feature = "gpu")]
#[allow(clippy::too_many_arguments)]
fn bake_nodes_gpu(
    gpu: &lod::gpu::GpuBaker,
    pyramid: &Pyramid,
    raster: &LoadedRaster,
    opts: &BakeOptions,
    nodes: &[TileKey],
    resumed: Vec<Option<NodeEntry>>,
    store: &Store,
    progress: &dyn Progress,
) -> Result<(Vec<NodeEntry>, lod::gpu::BatchReport), BakeError> {
    use std::sync::mpsc;
    type Round = (Vec<usize>, Vec<NodeMesh>);
    type Baked = (Vec<usize>, Vec<NodeMesh>, Vec<PointCloud>, lod::gpu::BatchReport);

    let hf = &raster.heights;
    let pending: Vec<usize> = (0..nodes.len()).filter(|&i| resumed[i].is_none()).collect();
    let mut entries = resumed;
    let mut report = lod::gpu::BatchReport { budget_bytes: gpu.budget_bytes(), ..Default::default() };
    let levels = opts.levels;
    let bake_round = |meshes: &[NodeMesh]| -> Result<(Vec<PointCloud>, lod::gpu::BatchReport), BakeError> {
        let jobs: Vec<lod::gpu::LevelJob<'_>> = meshes
            .iter()
            .flat_map(|nm| {
                (1..=levels).map(move |l| {
                    let (origin, cell) = nm.level_grid(l);
                    lod::gpu::LevelJob { mesh: &nm.mesh, origin, cell }
                })
            })
            .collect();
        let (results, rep) =
            gpu.bake_jobs(&jobs, &lod::cpu::SliceOptions::default()).map_err(lod::BakerError::from)?;
        let clouds = results.into_iter().map(|(cells, _)| lod::cells_to_cloud(&cells)).collect();
        Ok((clouds, rep))
    };
    std::thread::scope(|scope| -> Result<(), BakeError> {
        let (to_gpu, gpu_in) = mpsc::sync_channel::<Round>(1);
        let (gpu_out, from_gpu) = mpsc::channel::<Result<Baked, BakeError>>();
        scope.spawn(move || {
            for (ids, meshes) in gpu_in {
                let r = bake_round(&meshes).map(|(clouds, rep)| (ids, meshes, clouds, rep));
                if gpu_out.send(r).is_err() {
                    break;
                }
            }
        });
        let finish = |entries: &mut Vec<Option<NodeEntry>>,
                      baked: Baked|
         -> Result<lod::gpu::BatchReport, BakeError> {
            let (ids, meshes, clouds, rep) = baked;
            let mut clouds = clouds.into_iter();
            let work: Vec<(usize, NodeMesh, Vec<PointCloud>)> = ids
                .into_iter()
                .zip(meshes)
                .map(|(i, nm)| (i, nm, clouds.by_ref().take(usize::from(levels)).collect()))
                .collect();
            let done: Vec<(usize, NodeEntry)> = work
                .into_par_iter()
                .map(|(i, nm, clouds)| {
                    let (nb, quants) = finish_node(nm, clouds);
                    let e = write_node(&nb, &quants, store);
                    progress.node_done();
                    e.map(|e| (i, e))
                })
                .collect::<Result<_, _>>()?;
            for (i, e) in done {
                entries[i] = Some(e);
            }
            Ok(rep)
        };
        let mut sent = 0usize;
        let mut received = 0usize;
        for round in pending.chunks(GPU_ROUND_NODES) {
            if let Some(why) = progress.cancelled() {
                return Err(BakeError::Cancelled(why));
            }
            let meshes: Vec<NodeMesh> = round
                .par_iter()
                .map(|&i| bake_node_mesh(pyramid, hf, &raster.georef, nodes[i], opts))
                .collect::<Result<_, _>>()?;
            if to_gpu.send((round.to_vec(), meshes)).is_err() {
                break;
            }
            sent += 1;
            // Keep one round queued behind the one the GPU is baking.
            if sent - received > 1 {
                let baked =
                    from_gpu.recv().map_err(|_| BakeError::Options("gpu worker stopped".into()))??;
                received += 1;
                report.merge(&finish(&mut entries, baked)?);
            }
        }
        drop(to_gpu);
        while received < sent {
            let baked = from_gpu.recv().map_err(|_| BakeError::Options("gpu worker stopped".into()))??;
            received += 1;
            report.merge(&finish(&mut entries, baked)?);
        }
        Ok(())
    })?;
    let entries = entries
        .into_iter()
        .map(|e| e.ok_or_else(|| BakeError::Options("a node was left unbaked".into())))
        .collect::<Result<_, _>>()?;
    Ok((entries, report))
}

fn heights_crc(data: &[f32]) -> String {
    let mut h = crc32fast::Hasher::new();
    for chunk in data.chunks(4096) {
        let bytes: Vec<u8> = chunk.iter().flat_map(|v| v.to_le_bytes()).collect();
        h.update(&bytes);
    }
    format!("{:08x}", h.finalize())
}

/// A node whose every level blob is present, whole and valid (it decodes completely: exact
/// length, payload checksum, geometry inside its bounds — see [`codec::decode`]) and names that
/// node and level is complete: its index entry is rebuilt from the blob headers. Anything else —
/// missing, truncated, extended, flipped, or written by a version whose blobs this one refuses —
/// is baked again (and its blobs replaced).
fn existing_node(store: &Store, key: TileKey, levels: u8) -> Option<NodeEntry> {
    let mut out = Vec::new();
    let mut bounds = None;
    for level in 0..=levels {
        let bytes = store.read_blob(key, level).ok()??;
        let h = match codec::decode(&bytes) {
            Ok(b) => b.header,
            Err(e) => {
                tracing::warn!(tile = %key, level, "re-baking a damaged blob: {e}");
                return None;
            }
        };
        if h.key != key || h.level != level {
            return None;
        }
        bounds.get_or_insert(Bounds { min: h.bounds[0], max: h.bounds[1] });
        out.push(NodeLevel {
            errors: h.errors,
            count: h.vertex_count,
            triangles: h.triangle_count,
            bytes: bytes.len() as u64,
            checksum: h.checksum,
        });
    }
    Some(NodeEntry { key, bounds: bounds?, levels: out })
}

/// The largest power of two ≤ `v` (v > 0 and finite).
fn pow2_at_most(v: f64) -> f64 {
    2f64.powi(v.log2().floor() as i32)
}

/// Everything one node's bake produces, before it is written.
pub struct NodeBake {
    pub key: TileKey,
    pub bounds: Bounds,
    pub mesh: Mesh,
    pub mesh_errors: Errors,
    pub points: Vec<(PointCloud, Errors)>,
}

/// A node's level 0: its quantized TIN with measured errors, what its point levels are baked
/// from.
pub struct NodeMesh {
    pub key: TileKey,
    pub bounds: Bounds,
    pub mesh: Mesh,
    pub mesh_errors: Errors,
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
    pub fn finish_level(&self, level: u8, mut pc: PointCloud) -> (PointCloud, Errors, Quantization) {
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
        let errors = lod::cpu::measure_points(&self.mesh, &pc, cell);
        (pc, errors, q)
    }
}

/// Bakes one node in memory: TIN, quantization, measured errors, point levels (CPU
/// reference). Pure apart from reading the raster window.
pub fn bake_node_geometry(
    pyramid: &Pyramid,
    reader: &dyn WindowReader,
    georef: &Georef,
    key: TileKey,
    opts: &BakeOptions,
) -> Result<(NodeBake, Vec<Quantization>), BakeError> {
    let nm = bake_node_mesh(pyramid, reader, georef, key, opts)?;
    let clouds = (1..=opts.levels)
        .map(|level| {
            let (origin, cell) = nm.level_grid(level);
            lod::cpu::bake_points(&nm.mesh, origin, cell)
        })
        .collect();
    Ok(finish_node(nm, clouds))
}

/// [`bake_node_geometry`] with the point levels baked by `baker`: on the GPU all the node's
/// levels go in one submission. What a single-node (on-demand) bake calls; the result is the
/// same as in a whole-raster bake with the same baker.
pub fn bake_node_geometry_with(
    pyramid: &Pyramid,
    reader: &dyn WindowReader,
    georef: &Georef,
    key: TileKey,
    opts: &BakeOptions,
    baker: &PointBaker,
) -> Result<(NodeBake, Vec<Quantization>), BakeError> {
    let nm = bake_node_mesh(pyramid, reader, georef, key, opts)?;
    let grids: Vec<([f64; 3], f64)> = (1..=opts.levels).map(|l| nm.level_grid(l)).collect();
    let clouds = baker.bake_levels(&nm.mesh, &grids)?.0;
    Ok(finish_node(nm, clouds))
}

/// [`bake_node_geometry_with`], then encodes the node's blobs and writes them to `store`;
/// returns its index entry (the index and manifest are the caller's).
pub fn bake_node_with(
    pyramid: &Pyramid,
    reader: &dyn WindowReader,
    georef: &Georef,
    key: TileKey,
    opts: &BakeOptions,
    baker: &PointBaker,
    store: &Store,
) -> Result<NodeEntry, BakeError> {
    let (nb, quants) = bake_node_geometry_with(pyramid, reader, georef, key, opts, baker)?;
    write_node(&nb, &quants, store)
}

/// Quantizes and measures a node's baked clouds (levels 1, 2, …).
fn finish_node(nm: NodeMesh, clouds: Vec<PointCloud>) -> (NodeBake, Vec<Quantization>) {
    let mut quants = vec![nm.quantization];
    let mut points = Vec::with_capacity(clouds.len());
    for (k, pc) in clouds.into_iter().enumerate() {
        let (pc, errors, q) = nm.finish_level(k as u8 + 1, pc);
        quants.push(q);
        points.push((pc, errors));
    }
    let nb = NodeBake { key: nm.key, bounds: nm.bounds, mesh: nm.mesh, mesh_errors: nm.mesh_errors, points };
    (nb, quants)
}

/// A node's TIN, quantized as the blob stores it, with its errors measured against every
/// full-resolution sample it covers. Pure apart from reading the raster window.
pub fn bake_node_mesh(
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
    reader.read_window(&grid.cols, &grid.rows, &mut heights);
    let node_error = opts.max_error * f64::from(step);
    let t = tin::build(&grid, &heights, node_error).map_err(|source| BakeError::Tin { key, source })?;

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
    let span = pyramid.span(key);
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
        // enough (≤ 1/1024 cell) to be negligible, and again identical in both neighbours.
        let step = pow2_at_most(adx.min(ady) / 1024.0);
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

    // Measured against every full-resolution sample the node covers, in sample coordinates.
    let cols: Vec<u32> = (span.col0..=span.col1).collect();
    let rows: Vec<u32> = (span.row0..=span.row1).collect();
    let mut full = Vec::new();
    reader.read_window(&cols, &rows, &mut full);
    let sample_space: Vec<[f64; 3]> = mesh
        .positions
        .iter()
        .map(|p| [(p[0] - georef.x0) / georef.dx, (p[1] - georef.y0) / georef.dy, p[2]])
        .map(|p| [p[0].round(), p[1].round(), p[2]])
        .collect();
    let mesh_errors = tin::measure_vertical(&sample_space, &mesh.triangles, span, &full)
        .map_err(|source| BakeError::Tin { key, source })?;
    drop(full);

    Ok(NodeMesh {
        key,
        bounds,
        mesh,
        mesh_errors,
        quantization: mesh_q,
        level1_cell: frame.cell() * f64::from(step) * 2.0,
    })
}

fn bake_node(
    pyramid: &Pyramid,
    reader: &dyn WindowReader,
    georef: &Georef,
    key: TileKey,
    opts: &BakeOptions,
    store: &Store,
) -> Result<NodeEntry, BakeError> {
    let (nb, quants) = bake_node_geometry(pyramid, reader, georef, key, opts)?;
    write_node(&nb, &quants, store)
}

/// Encodes and writes one baked node's blobs; returns its index entry.
fn write_node(nb: &NodeBake, quants: &[Quantization], store: &Store) -> Result<NodeEntry, BakeError> {
    let key = nb.key;
    let codec_err = |level: u8| move |source| BakeError::Codec { key, level, source };
    let mut levels = Vec::with_capacity(nb.points.len() + 1);
    let mesh_blob =
        codec::encode_mesh(key, 0, &nb.bounds, quants[0], &nb.mesh, nb.mesh_errors).map_err(codec_err(0))?;
    let mut blobs = vec![mesh_blob];
    levels.push(NodeLevel {
        errors: nb.mesh_errors,
        count: nb.mesh.positions.len() as u32,
        triangles: nb.mesh.triangles.len() as u32,
        bytes: 0,
        checksum: 0,
    });
    for (k, (pc, errors)) in nb.points.iter().enumerate() {
        let level = k as u8 + 1;
        blobs.push(
            codec::encode_points(key, level, &nb.bounds, quants[k + 1], pc, *errors)
                .map_err(codec_err(level))?,
        );
        levels.push(NodeLevel {
            errors: *errors,
            count: pc.positions.len() as u32,
            triangles: 0,
            bytes: 0,
            checksum: 0,
        });
    }
    // Mesh last: a node counts as complete on resume only when all its levels exist, and the
    // order makes an interrupted node's missing blob the cheap one to notice.
    for (level, bytes) in blobs.iter().enumerate().rev() {
        store.write_blob(key, level as u8, bytes)?;
        levels[level].bytes = bytes.len() as u64;
        levels[level].checksum = codec::decode_header(bytes).map_err(codec_err(level as u8))?.checksum;
    }
    Ok(NodeEntry { key, bounds: nb.bounds, levels })
}

/// The options record `bake` writes to `bake-options.json` (and into the manifest) for this
/// raster and these options. The server's on-demand baker writes the same record so that a
/// later `terrastream bake` of the same source resumes the tiles it baked, and vice versa.
#[must_use]
pub fn options_record(raster: &LoadedRaster, source_name: &str, opts: &BakeOptions) -> serde_json::Value {
    let hf = &raster.heights;
    serde_json::json!({
        "tile_size": opts.tile_size,
        "max_error": opts.max_error,
        "levels": opts.levels,
        "frame": raster.georef,
        "source": { "file": source_name, "width": hf.width, "height": hf.height, "crc32": heights_crc(&hf.data) },
        "format_version": codec::FORMAT_VERSION,
    })
}

/// Bakes one node (every level) of `raster` and writes its blobs into `store`, exactly as
/// [`bake`] would (same bytes); used by the server to bake tiles on first request. The caller
/// has prepared the store with [`Store::begin_bake`] and [`options_record`].
pub fn bake_one_node(
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
        return Err(BakeError::Options(format!("tile {key} is outside the raster's quadtree")));
    }
    bake_node_with(&pyramid, hf, &raster.georef, key, opts, baker, store)
}

/// The index entry of a node whose every level is on disk (rebuilt from the blob headers), or
/// `None` when a level is missing or does not decode as that node and level.
#[must_use]
pub fn node_from_blobs(store: &Store, key: TileKey, levels: u8) -> Option<NodeEntry> {
    existing_node(store, key, levels)
}

#[cfg(test)]
mod one_node_tests {
    use super::*;

    /// `bake_one_node` writes the very bytes `bake` writes, and `options_record` is the record
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
            format: "test".into(),
        };
        let opts = BakeOptions { tile_size: 32, max_error: 2.0, levels: 2 };
        let full = tempfile::tempdir().unwrap();
        let full_store = Store::new(full.path());
        bake(&raster, "t.tif", &opts, &full_store, &NoProgress).unwrap();
        let manifest = full_store.manifest().unwrap();
        assert_eq!(manifest.options, options_record(&raster, "t.tif", &opts));

        let one = tempfile::tempdir().unwrap();
        let one_store = Store::new(&one.path().join("ts"));
        one_store.begin_bake(&options_record(&raster, "t.tif", &opts)).unwrap();
        let key = TileKey::new(1, 1, 0);
        let entry = bake_one_node(&raster, key, &opts, &PointBaker::Cpu, &one_store).unwrap();
        assert_eq!(Some(&entry), full_store.node(key).unwrap().as_ref());
        for level in 0..=opts.levels {
            assert_eq!(one_store.read_blob(key, level).unwrap(), full_store.read_blob(key, level).unwrap());
        }
        assert_eq!(node_from_blobs(&one_store, key, opts.levels), Some(entry));
        assert!(bake_one_node(&raster, TileKey::new(1, 2, 0), &opts, &PointBaker::Cpu, &one_store).is_err());
    }
}

/// D1: every blob's positions lie inside the bounds its header states, for random tiles, flat
/// tiles at random heights, plateaus with lakes, every level ladder and several cell sizes
/// (the GPU baker is held to the same in tests/gpu.rs).
#[cfg(test)]
mod bounds_tests {
    use proptest::prelude::*;

    use super::*;

    fn check_inside(store: &Store) -> Result<usize, TestCaseError> {
        let mut n = 0;
        let m = store.manifest().map_err(|e| TestCaseError::fail(e.to_string()))?;
        let pyramid = Pyramid::new(m.source.width, m.source.height, m.tile_size).unwrap();
        for key in pyramid.nodes() {
            for level in 0..m.levels.len() as u8 {
                let bytes = store.read_blob(key, level).unwrap().unwrap();
                let blob =
                    codec::decode(&bytes).map_err(|e| TestCaseError::fail(format!("{key}/{level}: {e}")))?;
                let b = blob.header.bounds();
                let ps = match &blob.geometry {
                    codec::Geometry::Mesh(m) => &m.positions,
                    codec::Geometry::Points(p) => &p.positions,
                };
                for p in ps {
                    for a in 0..3 {
                        prop_assert!(
                            b.min[a] <= p[a] && p[a] <= b.max[a],
                            "{key}/{level}: {p:?} outside {b:?}"
                        );
                    }
                }
                n += 1;
            }
        }
        Ok(n)
    }

    proptest! {
        #![proptest_config(ProptestConfig { cases: 48, ..ProptestConfig::default() })]
        #[test]
        fn quantized_positions_lie_inside_the_header_bounds(
            kind in 0u8..3,
            w in 9u32..48,
            h in 9u32..48,
            tile_size in prop::sample::select(vec![8u32, 16, 32]),
            cell in prop::sample::select(vec![0.25f64, 1.0, 30.0, 0.1]),
            base in -2000.0f32..9000.0,
            levels in 1u8..=4,
            max_error in prop::sample::select(vec![0.0f64, 0.5, 2.0]),
            seed in 0u64..1000,
        ) {
            let n = (w * h) as usize;
            let data: Vec<f32> = match kind {
                0 => vec![base; n],
                1 => (0..n).map(|i| {
                    let (c, r) = (i as u32 % w, i as u32 / w);
                    if (2..7).contains(&c) && (2..7).contains(&r) { base - 2.5 } else if c > w / 2 { base + 40.125 } else { base }
                }).collect(),
                _ => crate::raster::synth::terrain(w, h, seed).into_iter().map(|z| base + z * 0.1).collect(),
            };
            let raster = LoadedRaster {
                heights: crate::raster::Heightfield { width: w, height: h, data },
                georef: Georef { dx: cell, dy: -cell, ..Georef::default() },
                nodata_filled: 0,
                format: "test".into(),
            };
            let dir = tempfile::tempdir().unwrap();
            let store = Store::new(dir.path());
            let opts = BakeOptions { tile_size, max_error, levels };
            bake(&raster, "t.tif", &opts, &store, &NoProgress).map_err(|e| TestCaseError::fail(e.to_string()))?;
            prop_assert!(check_inside(&store)? > 0);
        }
    }
}
