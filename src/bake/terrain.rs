//! The terrain bake ([`bake_terrain`]): a loaded raster → per node a TIN (level 0) and point
//! levels (1..=K) → blobs and index chunks in a tileset directory, in parallel over nodes,
//! resumable; the manifest last.
//!
//! Per node (see `node`): read its sample grid through the `WindowReader`, build the TIN with
//! the node's error bound, convert to world coordinates and quantize exactly as the blob stores
//! it, then measure everything on the quantized geometry (the errors a client sees are the
//! errors of the bytes it receives). Point levels are baked from the quantized mesh.

use std::sync::Mutex;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Instant;

use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use crate::codec;
use crate::geom::Bounds;
#[cfg(feature = "gpu")]
use crate::geom::PointCloud;
use crate::lod::{self, PointBaker};
use crate::raster::{Georef, LoadedRaster, WindowReader};
use crate::store::{
    IndexChunk, LevelSpec, LevelTable, LevelTotals, MANIFEST_FORMAT, MANIFEST_VERSION, Manifest, NodeEntry,
    SUBTREE_LEVELS, SourceInfo, Store, chunk_root, content_version,
};
use crate::tiling::{Pyramid, TileKey};
use crate::tin;

#[cfg(feature = "gpu")]
use super::node::{LevelPlan, NodeMesh, node_mesh, write_node};
use super::node::{ParentInfo, bake_node_in, node_from_blobs, parent_info, parent_key};

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
    /// Which point levels a node stores (`--point-levels`). A plan written before the option
    /// existed stored every level that was cheaper: `all`.
    #[serde(default = "PointLevels::before_reach")]
    pub point_levels: PointLevels,
}

impl Default for BakeOptions {
    fn default() -> Self {
        Self {
            tile_size: crate::tiling::DEFAULT_TILE_SIZE,
            max_error: DEFAULT_MAX_ERROR,
            levels: DEFAULT_LEVELS,
            point_levels: PointLevels::Auto,
        }
    }
}

/// Which point levels a node stores (`--point-levels`).
#[cfg_attr(feature = "cli", derive(clap::ValueEnum))]
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum PointLevels {
    /// Those a screen-space-error selector can choose (`lod::reach`: under the parent's mesh
    /// error plus the threshold angle times the distance between their centres; the root keeps
    /// every level) and that are cheaper than every finer level kept. Levels whose spacing
    /// already bounds their error above that reach are not baked.
    #[default]
    Auto,
    /// Every level cheaper than every finer level kept (the rule before `auto`).
    All,
    /// The meshes alone.
    None,
}

impl PointLevels {
    pub(crate) fn before_reach() -> Self {
        Self::All
    }
}

#[derive(Debug, thiserror::Error)]
pub enum BakeError {
    #[error("bake: --max-error must be a finite number ≥ 0, got {0}")]
    MaxError(f64),
    #[error("bake: --levels must be at most {MAX_LEVELS}, got {0}")]
    Levels(u8),
    #[error("bake: --tile-size must be 2 to 65536 cells, got {0}")]
    TileSize(u32),
    #[error("bake: tile {0} is outside the raster's quadtree")]
    OutsidePyramid(TileKey),
    /// The GPU path's worker thread ended before it returned every round (it panicked).
    #[error("bake: the gpu worker stopped")]
    GpuWorkerStopped,
    /// A sharded bake's plan or shard results are missing, damaged or do not match.
    #[error("bake: {0}")]
    Plan(String),
    /// The final step of a sharded bake ran before every shard finished (it can run again later).
    #[error("bake: {0}")]
    ShardsUnfinished(String),
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
    /// Reading the dataset's samples failed (a file changed or became unreadable mid-bake).
    #[error("bake: {0}")]
    Raster(#[from] crate::raster::RasterError),
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

/// What `bake` prints when it is done: the summary line, the process's peak memory when known,
/// the point baker, the GPU batches (GPU path only) and the level table; no trailing newline.
pub struct BakeReport<'a> {
    pub summary: &'a BakeSummary,
    /// The tileset directory baked into.
    pub out: &'a std::path::Path,
    pub peak_rss_mib: Option<f64>,
}

impl std::fmt::Display for BakeReport<'_> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let s = self.summary;
        writeln!(
            f,
            "baked {} tiles ({} resumed) into {} in {:.2} s: {:.2} M samples/s, {} no-data samples filled",
            s.nodes,
            s.nodes_resumed,
            self.out.display(),
            s.seconds,
            s.samples_per_second() / 1e6,
            s.nodata_filled
        )?;
        if let Some(mib) = self.peak_rss_mib {
            writeln!(f, "peak memory (RSS): {mib:.0} MiB")?;
        }
        writeln!(f, "point levels baked by {}", s.point_baker)?;
        if s.gpu_batches > 0 {
            writeln!(
                f,
                "gpu: {} batches, peak {:.1} MiB per batch (budget {:.0} MiB), {} levels left to the cpu",
                s.gpu_batches,
                s.gpu_peak_batch_bytes as f64 / f64::from(1 << 20),
                s.gpu_budget_bytes as f64 / f64::from(1 << 20),
                s.gpu_cpu_fallback_levels
            )?;
        }
        write!(f, "{}", LevelTable(&s.totals))
    }
}

/// Validates options before anything is written.
pub fn check_options(opts: &BakeOptions) -> Result<(), BakeError> {
    if !opts.max_error.is_finite() || opts.max_error < 0.0 {
        return Err(BakeError::MaxError(opts.max_error));
    }
    if opts.levels > MAX_LEVELS {
        return Err(BakeError::Levels(opts.levels));
    }
    if opts.tile_size < 2 || opts.tile_size > 65_536 {
        return Err(BakeError::TileSize(opts.tile_size));
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
        footprint_half: None,
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
            footprint_half: Some(lod::TERRAIN_FOOTPRINT_HALF),
        });
    }
    out
}

/// What a terrain bake reads: the samples (through a window reader: an in-memory raster or a
/// dataset read in blocks), their frame, and what the source was.
pub struct TerrainInput<'a> {
    pub reader: &'a dyn WindowReader,
    pub georef: Georef,
    /// Short format name of the source ("geotiff", "hgt", …).
    pub format: String,
    pub nodata_filled: u64,
    /// Of the filled samples, those beyond the fill's reach (set from the fallback grid).
    pub nodata_fallback: u64,
    /// CRC-32 of every filled height, row-major, little-endian f32.
    pub crc32: String,
}

impl<'a> TerrainInput<'a> {
    /// The input of an in-memory raster (its checksum computed here).
    #[must_use]
    pub fn of(raster: &'a LoadedRaster) -> Self {
        Self {
            reader: &raster.heights,
            georef: raster.georef.clone(),
            format: raster.format.clone(),
            nodata_filled: raster.nodata_filled,
            nodata_fallback: raster.nodata_fallback,
            crc32: heights_crc(&raster.heights.data),
        }
    }

    /// The input of a dataset opened in blocks.
    #[must_use]
    pub fn of_dataset(ds: &'a crate::raster::dataset::Dataset) -> Self {
        let s = ds.summary();
        Self {
            reader: ds,
            georef: ds.georef().clone(),
            format: s.format.clone(),
            nodata_filled: s.nodata_filled,
            nodata_fallback: s.nodata_fallback,
            crc32: s.crc32.clone(),
        }
    }
}

/// Bakes `raster` into `store`, point levels by `baker`. Resumes a bake with the same options,
/// keeping complete nodes.
pub fn bake_terrain(
    raster: &LoadedRaster,
    source_name: &str,
    opts: &BakeOptions,
    baker: &PointBaker,
    store: &Store,
    progress: &dyn Progress,
) -> Result<BakeSummary, BakeError> {
    bake_input(&TerrainInput::of(raster), source_name, opts, baker, store, progress)
}

/// [`bake_terrain`] for any [`TerrainInput`]: the same bytes for the same heights, whether they
/// are held in memory or read in blocks.
pub fn bake_input(
    input: &TerrainInput<'_>,
    source_name: &str,
    opts: &BakeOptions,
    baker: &PointBaker,
    store: &Store,
    progress: &dyn Progress,
) -> Result<BakeSummary, BakeError> {
    check_options(opts)?;
    let t0 = Instant::now();
    let (width, height) = input.reader.size();
    let pyramid = Pyramid::new(width, height, opts.tile_size)?;
    let options_json = options_record_of(input, source_name, opts);
    store.begin_bake(&options_json)?;
    let nodes = pyramid.nodes();
    let baked = bake_nodes(input, opts, baker, &pyramid, &nodes, store, progress)?;
    let totals = publish(input, source_name, opts, &baker.describe(), &baked.entries, options_json, store)?;
    Ok(baked.summary(input, totals, t0, baker.describe()))
}

/// What [`bake_nodes`] returns: the nodes' index entries (in the order asked), how many were
/// resumed from blobs, and the GPU path's figures.
pub(crate) struct NodesBaked {
    pub entries: Vec<NodeEntry>,
    pub resumed: u64,
    /// [batches, peak batch bytes, budget bytes, levels left to the CPU] of the GPU path.
    pub gpu_report: Option<[u64; 4]>,
}

impl NodesBaked {
    pub(crate) fn summary(
        &self,
        input: &TerrainInput<'_>,
        totals: Vec<LevelTotals>,
        t0: Instant,
        point_baker: String,
    ) -> BakeSummary {
        let (width, height) = input.reader.size();
        let g = self.gpu_report;
        BakeSummary {
            nodes: self.entries.len() as u64,
            nodes_resumed: self.resumed,
            samples: u64::from(width) * u64::from(height),
            nodata_filled: input.nodata_filled,
            totals,
            seconds: t0.elapsed().as_secs_f64(),
            point_baker,
            gpu_batches: g.map_or(0, |r| r[0]),
            gpu_peak_batch_bytes: g.map_or(0, |r| r[1]),
            gpu_budget_bytes: g.map_or(0, |r| r[2]),
            gpu_cpu_fallback_levels: g.map_or(0, |r| r[3]),
        }
    }
}

/// Bakes `nodes` (of `pyramid`) into `store`, resuming those whose blobs are whole; the store
/// was prepared by [`Store::begin_bake`] with this input's options record. Entries come back in
/// the order of `nodes`.
pub(crate) fn bake_nodes(
    input: &TerrainInput<'_>,
    opts: &BakeOptions,
    baker: &PointBaker,
    pyramid: &Pyramid,
    nodes: &[TileKey],
    store: &Store,
    progress: &dyn Progress,
) -> Result<NodesBaked, BakeError> {
    let resumed: Vec<Option<NodeEntry>> =
        nodes.par_iter().map(|&k| node_from_blobs(store, k, opts.levels)).collect::<Result<_, _>>()?;
    let resumed_count = resumed.iter().filter(|r| r.is_some()).count() as u64;
    progress.start(nodes.len() as u64, resumed_count);
    let mut parents = Parents::new(input, opts, pyramid, nodes, &resumed, store)?;
    let mut entries = resumed;
    #[cfg(feature = "gpu")]
    let mut gpu_report: Option<lod::gpu::BatchReport> = None;
    // With `--point-levels auto`, depth by depth, root first: a node's levels depend on its
    // parent's mesh, which is then done. Other policies need no parent: one group, so the
    // nodes of every depth share the threads (and the GPU's batches).
    for depth in depth_groups(nodes, &entries, parents.auto) {
        match baker {
            PointBaker::Cpu => {
                bake_nodes_cpu(pyramid, input, opts, nodes, &depth, &parents, &mut entries, store, progress)?;
            }
            #[cfg(feature = "gpu")]
            PointBaker::Gpu(gpu) => {
                let report = bake_nodes_gpu(
                    gpu,
                    pyramid,
                    input,
                    opts,
                    nodes,
                    &depth,
                    &parents,
                    &mut entries,
                    store,
                    progress,
                )?;
                gpu_report
                    .get_or_insert_with(|| lod::gpu::BatchReport {
                        budget_bytes: gpu.budget_bytes(),
                        ..Default::default()
                    })
                    .merge(&report);
            }
        }
        parents.add(depth.iter().filter_map(|&i| entries[i].as_ref()));
    }
    let entries = entries
        .into_iter()
        // Every depth was baked above, so every node has its entry.
        .map(|e| e.ok_or(BakeError::GpuWorkerStopped))
        .collect::<Result<Vec<_>, _>>()?;
    #[cfg(feature = "gpu")]
    let gpu_report = gpu_report.map(|r| [r.batches, r.peak_batch_bytes, r.budget_bytes, r.cpu_jobs]);
    #[cfg(not(feature = "gpu"))]
    let gpu_report: Option<[u64; 4]> = None;
    Ok(NodesBaked { entries, resumed: resumed_count, gpu_report })
}

/// The indices of `nodes` still to bake: grouped by depth, shallowest first, when `by_depth`,
/// else one group in the order of `nodes`.
fn depth_groups(nodes: &[TileKey], entries: &[Option<NodeEntry>], by_depth: bool) -> Vec<Vec<usize>> {
    let mut groups: std::collections::BTreeMap<u8, Vec<usize>> = std::collections::BTreeMap::new();
    for (i, k) in nodes.iter().enumerate() {
        if entries[i].is_none() {
            groups.entry(if by_depth { k.z } else { 0 }).or_default().push(i);
        }
    }
    groups.into_values().collect()
}

/// The [`ParentInfo`] of every node whose children a bake may need: those baked or resumed so
/// far, and the parents outside the nodes asked for (a shard's roots), built up front.
struct Parents {
    auto: bool,
    known: std::collections::HashMap<TileKey, ParentInfo>,
}

impl Parents {
    fn new(
        input: &TerrainInput<'_>,
        opts: &BakeOptions,
        pyramid: &Pyramid,
        nodes: &[TileKey],
        resumed: &[Option<NodeEntry>],
        store: &Store,
    ) -> Result<Self, BakeError> {
        let auto = opts.point_levels == PointLevels::Auto;
        let mut p = Self { auto, known: std::collections::HashMap::new() };
        if !auto {
            return Ok(p);
        }
        p.add(resumed.iter().flatten());
        let asked: std::collections::HashSet<TileKey> = nodes.iter().copied().collect();
        let mut outside: Vec<TileKey> = nodes
            .iter()
            .zip(resumed)
            .filter(|(_, r)| r.is_none())
            .filter_map(|(&k, _)| parent_key(k))
            .filter(|pk| !asked.contains(pk))
            .collect();
        outside.sort_unstable();
        outside.dedup();
        let infos: Vec<(TileKey, ParentInfo)> = outside
            .par_iter()
            .map(|&pk| {
                parent_info(pyramid, input.reader, &input.georef, pk, opts, Some(store)).map(|i| (pk, i))
            })
            .collect::<Result<_, _>>()?;
        p.known.extend(infos);
        Ok(p)
    }

    fn add<'a>(&mut self, entries: impl Iterator<Item = &'a NodeEntry>) {
        if self.auto {
            self.known.extend(entries.map(|e| (e.key, ParentInfo::of_entry(e))));
        }
    }

    /// What `key`'s parent leaves it; `None` for a root or a rule that does not ask.
    fn of(&self, key: TileKey) -> Result<Option<ParentInfo>, BakeError> {
        if !self.auto {
            return Ok(None);
        }
        match parent_key(key) {
            None => Ok(None),
            Some(pk) => {
                self.known.get(&pk).copied().map(Some).ok_or_else(|| {
                    BakeError::Plan(format!("tile {key}: its parent {pk} was not baked first"))
                })
            }
        }
    }
}

/// Writes the index chunks of `entries` (every node of the pyramid, in [`Pyramid::nodes`]
/// order), then the manifest, last. Returns the per-level totals.
pub(crate) fn publish(
    input: &TerrainInput<'_>,
    source_name: &str,
    opts: &BakeOptions,
    point_baker: &str,
    entries: &[NodeEntry],
    options_json: serde_json::Value,
    store: &Store,
) -> Result<Vec<LevelTotals>, BakeError> {
    let (width, height) = input.reader.size();
    let pyramid = Pyramid::new(width, height, opts.tile_size)?;
    let mut chunks: std::collections::BTreeMap<TileKey, Vec<NodeEntry>> = std::collections::BTreeMap::new();
    let mut totals = vec![LevelTotals::default(); usize::from(opts.levels) + 1];
    let mut bounds = Bounds::empty();
    for e in entries {
        for l in &e.levels {
            if let Some(t) = totals.get_mut(usize::from(l.level)) {
                t.add(l);
            }
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
        content_version: content_version(entries.iter().flat_map(|e| &e.levels)),
        source: SourceInfo {
            file: source_name.into(),
            format: input.format.clone(),
            width,
            height,
            nodata_filled: input.nodata_filled,
        },
        frame: input.georef.clone(),
        tile_size: opts.tile_size,
        depth: pyramid.depth,
        subtree_levels: SUBTREE_LEVELS,
        bounds,
        levels: level_specs(opts),
        totals: totals.clone(),
        options: options_json,
        point_baker: point_baker.to_owned(),
    };
    store.finish_bake(&manifest)?;
    Ok(totals)
}

/// The CPU path: the nodes `todo` (indices into `nodes`, one depth) each on its own, in
/// parallel; their entries go into `entries`.
#[allow(clippy::too_many_arguments)]
fn bake_nodes_cpu(
    pyramid: &Pyramid,
    input: &TerrainInput<'_>,
    opts: &BakeOptions,
    nodes: &[TileKey],
    todo: &[usize],
    parents: &Parents,
    entries: &mut [Option<NodeEntry>],
    store: &Store,
    progress: &dyn Progress,
) -> Result<(), BakeError> {
    // The first failure stops the others (nodes already in flight finish) and is what the bake
    // reports.
    let first_error: Mutex<Option<BakeError>> = Mutex::new(None);
    let failed = AtomicBool::new(false);
    let fail = |e: BakeError| {
        failed.store(true, Ordering::Relaxed);
        first_error.lock().unwrap_or_else(std::sync::PoisonError::into_inner).get_or_insert(e);
    };
    let baked: Vec<(usize, NodeEntry)> = todo
        .par_iter()
        .filter_map(|&i| {
            let key = nodes[i];
            if failed.load(Ordering::Relaxed) {
                return None;
            }
            if let Some(why) = progress.cancelled() {
                fail(BakeError::Cancelled(why));
                return None;
            }
            let r = parents.of(key).and_then(|parent| {
                bake_node_in(pyramid, input.reader, &input.georef, key, opts, &PointBaker::Cpu, store, parent)
            });
            progress.node_done();
            r.map_err(fail).ok().map(|e| (i, e))
        })
        .collect();
    if let Some(e) = first_error.into_inner().unwrap_or_else(std::sync::PoisonError::into_inner) {
        return Err(e);
    }
    for (i, e) in baked {
        entries[i] = Some(e);
    }
    Ok(())
}

/// Nodes per GPU round: their TINs are built (in parallel) while the GPU bakes the round
/// before, and their levels go to the GPU together, split into batches by the memory budget.
#[cfg(feature = "gpu")]
pub const GPU_ROUND_NODES: usize = 32;

/// The GPU path: the nodes `todo` (one depth) in rounds, each round's TINs built on the CPU
/// while the GPU bakes the previous round's point levels, which are then measured, encoded and
/// written in parallel. Each node's result is what it would be alone (a job's output does not
/// depend on its batch).
#[cfg(feature = "gpu")]
#[allow(clippy::too_many_arguments)]
fn bake_nodes_gpu(
    gpu: &lod::gpu::GpuBaker,
    pyramid: &Pyramid,
    input: &TerrainInput<'_>,
    opts: &BakeOptions,
    nodes: &[TileKey],
    todo: &[usize],
    parents: &Parents,
    entries: &mut [Option<NodeEntry>],
    store: &Store,
    progress: &dyn Progress,
) -> Result<lod::gpu::BatchReport, BakeError> {
    use std::sync::mpsc;
    type Planned = (NodeMesh, LevelPlan);
    type Round = (Vec<usize>, Vec<Planned>);
    type Baked = (Vec<usize>, Vec<Planned>, Vec<PointCloud>, lod::gpu::BatchReport);

    let mut report = lod::gpu::BatchReport { budget_bytes: gpu.budget_bytes(), ..Default::default() };
    let bake_round = |planned: &[Planned]| -> Result<(Vec<PointCloud>, lod::gpu::BatchReport), BakeError> {
        let jobs: Vec<lod::gpu::LevelJob<'_>> = planned
            .iter()
            .flat_map(|(nm, plan)| {
                plan.grids(nm).into_iter().map(move |(origin, cell)| lod::gpu::LevelJob {
                    mesh: &nm.mesh,
                    origin,
                    cell,
                })
            })
            .collect();
        let (results, rep) =
            gpu.bake_clouds(&jobs, &lod::cpu::SliceOptions::default()).map_err(lod::BakerError::from)?;
        let clouds = results.into_iter().map(|(cloud, _)| cloud).collect();
        Ok((clouds, rep))
    };
    std::thread::scope(|scope| -> Result<(), BakeError> {
        let (to_gpu, gpu_in) = mpsc::sync_channel::<Round>(1);
        let (gpu_out, from_gpu) = mpsc::channel::<Result<Baked, BakeError>>();
        scope.spawn(move || {
            for (ids, planned) in gpu_in {
                let r = bake_round(&planned).map(|(clouds, rep)| (ids, planned, clouds, rep));
                if gpu_out.send(r).is_err() {
                    break;
                }
            }
        });
        let finish =
            |entries: &mut [Option<NodeEntry>], baked: Baked| -> Result<lod::gpu::BatchReport, BakeError> {
                let (ids, planned, clouds, rep) = baked;
                let mut clouds = clouds.into_iter();
                let work: Vec<(usize, Planned, Vec<PointCloud>)> = ids
                    .into_iter()
                    .zip(planned)
                    .map(|(i, (nm, plan))| {
                        let n = plan.to_bake().count();
                        (i, (nm, plan), clouds.by_ref().take(n).collect())
                    })
                    .collect();
                let done: Vec<(usize, NodeEntry)> = work
                    .into_par_iter()
                    .map(|(i, (nm, plan), clouds)| {
                        let e = write_node(&nm, &plan, clouds, store);
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
        for round in todo.chunks(GPU_ROUND_NODES) {
            if let Some(why) = progress.cancelled() {
                return Err(BakeError::Cancelled(why));
            }
            let planned: Vec<Planned> = round
                .par_iter()
                .map(|&i| {
                    let nm = node_mesh(pyramid, input.reader, &input.georef, nodes[i], opts)?;
                    let plan = nm.plan_levels(opts, parents.of(nodes[i])?);
                    Ok((nm, plan))
                })
                .collect::<Result<_, BakeError>>()?;
            if to_gpu.send((round.to_vec(), planned)).is_err() {
                return Err(BakeError::GpuWorkerStopped);
            }
            sent += 1;
            // Keep one round queued behind the one the GPU is baking.
            if sent - received > 1 {
                let baked = from_gpu.recv().map_err(|_| BakeError::GpuWorkerStopped)??;
                received += 1;
                report.merge(&finish(entries, baked)?);
            }
        }
        drop(to_gpu);
        while received < sent {
            let baked = from_gpu.recv().map_err(|_| BakeError::GpuWorkerStopped)??;
            received += 1;
            report.merge(&finish(entries, baked)?);
        }
        Ok(())
    })?;
    Ok(report)
}

fn heights_crc(data: &[f32]) -> String {
    let mut h = crc32fast::Hasher::new();
    for chunk in data.chunks(4096) {
        let bytes: Vec<u8> = chunk.iter().flat_map(|v| v.to_le_bytes()).collect();
        h.update(&bytes);
    }
    format!("{:08x}", h.finalize())
}

/// The options record `bake` writes to `bake-options.json` (and into the manifest) for this
/// raster and these options. The server's on-demand baker writes the same record so that a
/// later `terrastream bake` of the same source resumes the tiles it baked, and vice versa.
#[must_use]
pub fn options_record(raster: &LoadedRaster, source_name: &str, opts: &BakeOptions) -> serde_json::Value {
    options_record_of(&TerrainInput::of(raster), source_name, opts)
}

/// [`options_record`] of any input. Two rules newer than the record's first form are written
/// only where they change the result, so every earlier tileset they do not affect keeps its
/// record (and resumes): `fill` when samples lie beyond the no-data fill's reach (the fallback
/// grid set them), `measure_strip_samples` when the raster is larger than one measuring strip
/// (the rms of the widest nodes is summed per strip).
#[must_use]
pub fn options_record_of(
    input: &TerrainInput<'_>,
    source_name: &str,
    opts: &BakeOptions,
) -> serde_json::Value {
    let (width, height) = input.reader.size();
    let mut record = serde_json::json!({
        "tile_size": opts.tile_size,
        "max_error": opts.max_error,
        "levels": opts.levels,
        "frame": input.georef,
        "source": { "file": source_name, "width": width, "height": height, "crc32": input.crc32 },
        "format_version": codec::FORMAT_VERSION,
    });
    if input.nodata_fallback > 0 {
        record["fill"] = serde_json::json!({
            "reach": crate::raster::dataset::FILL_REACH,
            "fallback_block": crate::raster::dataset::BLOCK,
        });
    }
    if u64::from(width) * u64::from(height) > tin::MEASURE_STRIP_SAMPLES as u64 {
        record["measure_strip_samples"] = serde_json::json!(tin::MEASURE_STRIP_SAMPLES);
    }
    if opts.point_levels != PointLevels::All {
        // `auto` (with its threshold angle, the rule's one constant) and `none` store other
        // levels than `all`, the rule of every earlier record.
        record["point_levels"] = serde_json::json!(opts.point_levels);
        if opts.point_levels == PointLevels::Auto {
            record["reach_angle"] = serde_json::json!(lod::reach::REACH_ANGLE);
        }
    }
    record
}

/// D1: every blob's positions lie inside the bounds its header states, for random tiles, flat
/// tiles at random heights, plateaus with lakes, every level ladder and several cell sizes
/// (the GPU baker is held to the same in tests/gpu.rs).
#[cfg(test)]
mod bounds_tests {
    use proptest::prelude::*;

    use super::*;
    use crate::raster::Georef;

    fn check_inside(store: &Store) -> Result<usize, TestCaseError> {
        let mut n = 0;
        let m = store.manifest().map_err(|e| TestCaseError::fail(e.to_string()))?;
        let pyramid = Pyramid::new(m.source.width, m.source.height, m.tile_size).unwrap();
        for key in pyramid.nodes() {
            for level in 0..m.levels.len() as u8 {
                let Some(bytes) = store.read_blob(key, level).unwrap() else {
                    prop_assert!(
                        store.is_unpaid(key, level).unwrap() && level > 0,
                        "{key}/{level}: no blob, no marker"
                    );
                    continue;
                };
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
                nodata_fallback: 0,
                format: "test".into(),
            };
            let dir = tempfile::tempdir().unwrap();
            let store = Store::new(dir.path());
            let opts = BakeOptions { tile_size, max_error, levels, point_levels: PointLevels::All };
            bake_terrain(&raster, "t.tif", &opts, &PointBaker::Cpu, &store, &NoProgress).map_err(|e| TestCaseError::fail(e.to_string()))?;
            prop_assert!(check_inside(&store)? > 0);
        }
    }
}
