//! Sharded terrain bakes: one bake split over many processes or machines (the indexes of a
//! Kubernetes Indexed Job, an AWS Batch or Slurm array), writing into one tileset.
//!
//! Every node of the pyramid is baked on its own (its blobs depend only on the samples it
//! covers), so a shard is a set of whole subtrees: the nodes at the *shard depth* `d` (the
//! shallowest depth with at least as many nodes as shards), in Morton order so a shard's
//! subtrees lie side by side, cut into contiguous runs of about equal samples. Three steps:
//!
//! 1. [`write_plan`] (`terrastream plan`): begins the tileset ([`Store::begin_bake`]) and writes
//!    `shards/plan.json` ([`Plan`]) — the options record, the bake options, how the inputs are
//!    reopened ([`PlanInputs`]: files, read options, the scan's record, with its fallback grid
//!    in [`FALLBACK_FILE`]), the shards' roots;
//! 2. [`bake_shard`] (`terrastream bake --plan … --shard I`), any number at once, in any order,
//!    each re-runnable alone: bakes the subtrees of shard I (resuming whole nodes) and then
//!    writes `shards/shard-I.json`, the index entries of its nodes;
//! 3. [`finish_plan`] (`terrastream bake --plan … --finish`): bakes the nodes above depth `d`,
//!    joins them with every shard's entries in the one-machine order, writes the index chunks,
//!    the manifest last, and removes `shards/`. The tileset is byte for byte the one a
//!    one-machine bake of the same inputs writes.

use std::collections::HashMap;
use std::path::PathBuf;
use std::time::Instant;

use serde::{Deserialize, Serialize};

use crate::raster::dataset::{DatasetOptions, ScanRecord};
use crate::raster::{HeightEncoding, Limits, LoadOptions, Overrides};
use crate::store::{NodeEntry, Store, StoreError};
use crate::tiling::{Pyramid, TileKey, morton};

use super::terrain::{NodesBaked, bake_nodes, options_record_of, publish};
use super::{BakeError, BakeOptions, BakeSummary, Progress, TerrainInput, check_options};
use crate::lod::PointBaker;

pub const PLAN_FORMAT: &str = "terrastream-plan";
pub const PLAN_VERSION: u32 = 1;
/// The folder of a tileset that holds the plan and the shards' results until the final step.
pub const PLAN_DIR: &str = "shards";
pub const PLAN_FILE: &str = "shards/plan.json";
/// The fallback grid of a plan's scan (little-endian f32), beside [`PLAN_FILE`].
pub const FALLBACK_FILE: &str = "shards/fallback.f32";
/// Largest plan or shard result a step reads (checked before reading): far above what a plan
/// of [`MAX_SHARDS`] shards over a million input files, or a shard's node list, holds.
pub const MAX_STEP_FILE_BYTES: u64 = 1 << 30;
/// Most shards a plan may have (an Indexed Job allows 100,000 completions).
pub const MAX_SHARDS: u32 = 100_000;

/// One shard: the roots of its subtrees (all at the plan's shard depth).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ShardSpec {
    pub roots: Vec<TileKey>,
    /// Nodes of its subtrees.
    pub nodes: u64,
    /// Full-resolution samples its roots cover (each depth below covers them again).
    pub samples: u64,
}

/// What a plan records of its inputs (`inputs` in `shards/plan.json`): the files (expanded,
/// absolute) and how they are read, so that every step opens them alike.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct PlanInputs {
    pub files: Vec<PathBuf>,
    pub read: InputOptions,
    /// What the plan's scan of the inputs found (the shards open them without scanning while
    /// it stands; plans without it scan in every step). Its fallback grid, when the dataset has
    /// no-data, is the plan's file [`FALLBACK_FILE`] ([`Plan::read_fallback`]).
    #[serde(default)]
    pub scan: Option<ScanRecord>,
}

/// How a terrain bake reads its inputs and bakes them (the flags `bake` and `plan` share), as a
/// plan records them (`inputs.read`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct InputOptions {
    /// Leaf tile size in raster cells.
    pub tile_size: u32,
    /// TIN error bound for leaf tiles (world units).
    pub max_error: f64,
    /// Point-cloud levels below the mesh.
    pub levels: u8,
    /// `--point-levels` (a plan written before it existed: `all`).
    #[serde(default = "super::PointLevels::before_reach")]
    pub point_levels: super::PointLevels,
    /// How a PNG encodes heights.
    pub encoding: Option<HeightEncoding>,
    /// OpenEXR channel to read.
    pub channel: Option<String>,
    /// Horizontal cell size (overrides the file's georeference).
    pub cell_size: Option<f64>,
    /// World position of sample (0, 0) (overrides the file's georeference).
    pub origin: Option<(f64, f64)>,
    /// Multiplies raw sample values.
    pub z_scale: Option<f64>,
    /// Added to heights after scaling.
    pub z_offset: Option<f64>,
    /// Memory for the block caches, in MiB.
    pub cache_mib: u64,
    /// Directory for scratch files.
    pub scratch_dir: Option<PathBuf>,
    /// `--crs`: the inputs' horizontal CRS (instead of what they state).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub crs: Option<crate::crs::Crs>,
    /// `--vertical-datum`: what the inputs' heights are measured from.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub vertical_datum: Option<crate::crs::VerticalDatum>,
    /// `--geoid-grid`: the geoid of the vertical datum, a GTX file.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub geoid_grid: Option<PathBuf>,
    /// `--target-crs`: the CRS inputs are warped onto.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub target_crs: Option<crate::crs::Crs>,
    /// Largest side of a file decoded whole, in samples.
    pub max_side: u32,
    /// Largest heights of a file decoded whole, in bytes.
    pub max_bytes: u64,
    /// `--allow-sparse`: accept a VRT mostly of no-data.
    #[serde(default, skip_serializing_if = "std::ops::Not::not")]
    pub allow_sparse: bool,
}

impl InputOptions {
    #[must_use]
    pub fn bake_options(&self) -> BakeOptions {
        BakeOptions {
            tile_size: self.tile_size,
            max_error: self.max_error,
            levels: self.levels,
            point_levels: self.point_levels,
        }
    }

    #[must_use]
    pub fn dataset_options(&self) -> DatasetOptions {
        let load = LoadOptions {
            encoding: self.encoding,
            channel: self.channel.clone(),
            limits: Limits { max_side: self.max_side, max_bytes: self.max_bytes },
            overrides: Overrides {
                cell_size: self.cell_size,
                origin: self.origin,
                z_scale: self.z_scale,
                z_offset: self.z_offset,
                crs: self.crs.clone(),
                vertical: self.vertical_datum,
                geoid_grid: self.geoid_grid.clone(),
                target_crs: self.target_crs.clone(),
            },
        };
        DatasetOptions {
            load,
            cache_bytes: self.cache_mib.saturating_mul(1 << 20),
            scratch: self.scratch_dir.clone(),
            allow_sparse: self.allow_sparse,
        }
    }
}

/// Writes `v` as a `serde_json::Value`, whose objects sort their keys: the bytes plans have
/// always been written with (their `inputs` used to be an untyped value).
fn sorted_json<T: Serialize, S: serde::Serializer>(v: &T, s: S) -> Result<S::Ok, S::Error> {
    serde_json::to_value(v).map_err(serde::ser::Error::custom)?.serialize(s)
}

/// `shards/plan.json`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Plan {
    pub format: String,
    pub version: u32,
    /// The bake's options record (`bake-options.json`): a shard whose inputs read differently
    /// (other files, other bytes, other flags) refuses to write.
    pub options: serde_json::Value,
    pub bake: BakeOptions,
    /// The source name the manifest records.
    pub source_name: String,
    /// How every step reopens the inputs: files, read options, the scan's record.
    #[serde(serialize_with = "sorted_json")]
    pub inputs: PlanInputs,
    /// Depth of the shards' subtree roots; the final step bakes the nodes above it.
    pub shard_depth: u8,
    pub shards: Vec<ShardSpec>,
    /// Nodes the final step bakes (above the shard depth).
    pub top_nodes: u64,
}

impl Plan {
    /// The plan of a tileset (`Ok(None)` when it has none).
    pub fn read(store: &Store) -> Result<Option<Self>, BakeError> {
        let Some(bytes) = read_step_file(store, PLAN_FILE)? else {
            return Ok(None);
        };
        let plan: Plan = serde_json::from_slice(&bytes)
            .map_err(|e| BakeError::Plan(format!("{}: invalid plan: {e}", store.describe(PLAN_FILE))))?;
        if plan.format != PLAN_FORMAT || plan.version != PLAN_VERSION {
            return Err(BakeError::Plan(format!(
                "{}: not a {PLAN_FORMAT} v{PLAN_VERSION} file (format {:?}, version {})",
                store.describe(PLAN_FILE),
                plan.format,
                plan.version
            )));
        }
        check_options(&plan.bake).map_err(|e| {
            BakeError::Plan(format!(
                "{}: field `bake`: {}",
                store.describe(PLAN_FILE),
                e.to_string().trim_start_matches("bake: ")
            ))
        })?;
        plan.check_shape().map_err(|m| BakeError::Plan(format!("{}: {m}", store.describe(PLAN_FILE))))?;
        Ok(Some(plan))
    }

    /// What a plan must hold whatever its dataset: 1 to [`MAX_SHARDS`] shards, each with at least
    /// one root, every root at the shard depth, the same bake options in `bake` and
    /// `inputs.read`. (That the roots lie in the dataset's quadtree and cover its shard depth
    /// once is checked against the dataset: [`Plan::check_roots`].)
    fn check_shape(&self) -> Result<(), String> {
        if self.shards.is_empty() || self.shards.len() > MAX_SHARDS as usize {
            return Err(format!(
                "field `shards` holds {} shards; a plan has 1 to {MAX_SHARDS}",
                self.shards.len()
            ));
        }
        for (i, s) in self.shards.iter().enumerate() {
            if s.roots.is_empty() {
                return Err(format!("shard {i} has no roots"));
            }
            if let Some(r) = s.roots.iter().find(|r| r.z != self.shard_depth) {
                return Err(format!(
                    "shard {i} has the root {r}, not at the plan's shard depth {}",
                    self.shard_depth
                ));
            }
        }
        let read = self.inputs.read.bake_options();
        if read != self.bake {
            return Err(format!(
                "fields `bake` ({:?}) and `inputs.read` ({:?}) give different bake options",
                self.bake, read
            ));
        }
        Ok(())
    }

    /// Checks the shards' roots against the dataset's quadtree: the shard depth is in it, every
    /// root is a node of it, and the roots are every node at that depth, each once (so the
    /// shards and the final step bake every node once, and none outside the tree).
    fn check_roots(&self, pyramid: &Pyramid, store: &Store) -> Result<(), BakeError> {
        let refuse = |m: String| BakeError::Plan(format!("{}: {m}; plan again", store.describe(PLAN_FILE)));
        if self.shard_depth > pyramid.depth {
            return Err(refuse(format!(
                "field `shard_depth` is {}, below the dataset's leaves (depth {})",
                self.shard_depth, pyramid.depth
            )));
        }
        let mut seen = std::collections::HashSet::new();
        for (i, s) in self.shards.iter().enumerate() {
            for &r in &s.roots {
                if !pyramid.contains(r) {
                    let (nx, ny) = pyramid.nodes_at(r.z);
                    return Err(refuse(format!(
                        "shard {i} has the root {r}, outside the dataset's quadtree ({nx}×{ny} nodes at depth {})",
                        r.z
                    )));
                }
                if !seen.insert(r) {
                    return Err(refuse(format!(
                        "shard {i} has the root {r}, which an earlier shard has too"
                    )));
                }
            }
        }
        let (nx, ny) = pyramid.nodes_at(self.shard_depth);
        let all = u64::from(nx) * u64::from(ny);
        if seen.len() as u64 != all {
            return Err(refuse(format!(
                "the shards have {} roots, but depth {} of the dataset's quadtree has {all} nodes",
                seen.len(),
                self.shard_depth
            )));
        }
        Ok(())
    }

    #[must_use]
    pub fn shard_count(&self) -> u32 {
        self.shards.len() as u32
    }

    /// The fallback grid of the plan's scan ([`FALLBACK_FILE`]), when the scan recorded one:
    /// its size is checked against the record before it is read. A record that does not fit
    /// its dataset, or a file of another size, is a damaged plan ([`BakeError::Plan`]).
    pub fn read_fallback(&self, store: &Store) -> Result<Option<Vec<u8>>, BakeError> {
        let Some(scan) = self.inputs.scan.as_ref().filter(|s| s.fallback.is_some()) else {
            return Ok(None);
        };
        let Some(len) = scan.fallback_len() else {
            return Err(BakeError::Plan(format!(
                "{}: field `inputs.scan.fallback` does not fit the recorded {}x{} samples",
                store.describe(PLAN_FILE),
                scan.width,
                scan.height
            )));
        };
        store.read_file_within(FALLBACK_FILE, len..=len).map_err(|e| match e {
            e if e.is_damaged() || matches!(e, StoreError::Invalid { .. }) => BakeError::Plan(e.to_string()),
            e => e.into(),
        })
    }
}

/// A finished shard's result, `shards/shard-I.json`.
#[derive(Debug, Clone, Serialize, Deserialize)]
struct Fragment {
    shard: u32,
    shards: u32,
    options: serde_json::Value,
    point_baker: String,
    nodes: Vec<NodeEntry>,
}

/// A plan or shard result, refused as a damaged plan ([`BakeError::Plan`]) when it is larger
/// than [`MAX_STEP_FILE_BYTES`] (checked before reading).
fn read_step_file(store: &Store, rel: &str) -> Result<Option<Vec<u8>>, BakeError> {
    store.read_file_within(rel, 0..=MAX_STEP_FILE_BYTES).map_err(|e| match e {
        // Damaged, too large, or a FIFO or device (`plan.json -> /dev/zero`), refused unread.
        e if e.is_damaged() || matches!(e, StoreError::Invalid { .. }) => BakeError::Plan(e.to_string()),
        e => e.into(),
    })
}

fn fragment_file(index: u32) -> String {
    format!("{PLAN_DIR}/shard-{index}.json")
}

/// Every node of the subtree under `root`, root first.
fn subtree(pyramid: &Pyramid, root: TileKey) -> Vec<TileKey> {
    let mut out = vec![root];
    let mut i = 0;
    while let Some(&k) = out.get(i) {
        out.extend(pyramid.children(k));
        i += 1;
    }
    out
}

/// Splits `pyramid` into `shards` shards: the shard depth and each shard's subtree roots,
/// contiguous in Morton order with about equal samples each (every shard has at least one).
pub fn plan_shards(pyramid: &Pyramid, shards: u32) -> Result<(u8, Vec<ShardSpec>), BakeError> {
    if shards == 0 || shards > MAX_SHARDS {
        return Err(BakeError::Plan(format!("--shards must be 1 to {MAX_SHARDS}, got {shards}")));
    }
    let depth = (0..=pyramid.depth).find(|&z| {
        let (nx, ny) = pyramid.nodes_at(z);
        u64::from(nx) * u64::from(ny) >= u64::from(shards)
    });
    let Some(depth) = depth else {
        let (nx, ny) = pyramid.nodes_at(pyramid.depth);
        return Err(BakeError::Plan(format!(
            "--shards {shards}: the dataset has only {} leaf tiles; ask for at most that many shards, or a smaller --tile-size",
            u64::from(nx) * u64::from(ny)
        )));
    };
    let (nx, ny) = pyramid.nodes_at(depth);
    let mut roots: Vec<TileKey> =
        (0..ny).flat_map(|y| (0..nx).map(move |x| TileKey::new(depth, x, y))).collect();
    roots.sort_by_key(|k| morton(k.x, k.y));
    let weight = |k: &TileKey| {
        let s = pyramid.span(*k);
        u64::from(s.cols()) * u64::from(s.rows())
    };
    let total: u64 = roots.iter().map(weight).sum();
    let n = shards as usize;
    let mut out: Vec<ShardSpec> = Vec::with_capacity(n);
    let mut cum = 0u64;
    let mut start = 0usize;
    for i in 0..n {
        // Shard i ends where the running sum first reaches (i+1)/n of the total, leaving at
        // least one root for every shard after it.
        let left_for_others = n - i - 1;
        let target = (u128::from(total) * (i as u128 + 1) / n as u128) as u64;
        let mut end = start + 1;
        cum += weight(&roots[start]);
        while end < roots.len() - left_for_others && cum < target {
            cum += weight(&roots[end]);
            end += 1;
        }
        if i == n - 1 {
            for r in &roots[end..] {
                cum += weight(r);
            }
            end = roots.len();
        }
        let rs = roots[start..end].to_vec();
        let nodes = rs.iter().map(|&r| subtree(pyramid, r).len() as u64).sum();
        let samples = rs.iter().map(weight).sum();
        out.push(ShardSpec { roots: rs, nodes, samples });
        start = end;
    }
    Ok((depth, out))
}

/// Plans a sharded bake of `input` into `store`: begins the tileset and writes its plan.
/// Planning again with the same inputs and shard count rewrites the same plan; with another
/// shard count while shards have finished, it refuses (their results would not match).
/// `fallback` is the scan's fallback grid ([`FALLBACK_FILE`]), when `inputs.scan` has one.
pub fn write_plan(
    input: &TerrainInput<'_>,
    source_name: &str,
    opts: &BakeOptions,
    inputs: PlanInputs,
    shards: u32,
    fallback: Option<&[u8]>,
    store: &Store,
) -> Result<Plan, BakeError> {
    check_options(opts)?;
    let (width, height) = input.reader.size();
    let pyramid = Pyramid::new(width, height, opts.tile_size)?;
    let (shard_depth, specs) = plan_shards(&pyramid, shards)?;
    let options = options_record_of(input, source_name, opts);
    let top_nodes = pyramid.nodes().iter().filter(|k| k.z < shard_depth).count() as u64;
    let plan = Plan {
        format: PLAN_FORMAT.into(),
        version: PLAN_VERSION,
        options: options.clone(),
        bake: opts.clone(),
        source_name: source_name.into(),
        inputs,
        shard_depth,
        shards: specs,
        top_nodes,
    };
    if let Some(prev) = Plan::read(store)?
        && prev.shards != plan.shards
    {
        let mut done = Vec::new();
        for i in 0..prev.shard_count() {
            if store.has_file(&fragment_file(i))? {
                done.push(i);
            }
        }
        if !done.is_empty() {
            return Err(BakeError::Plan(format!(
                "{}: an earlier plan of {} shards has finished shards {done:?}; finish it, or delete the tileset to plan again",
                store.describe(PLAN_FILE),
                prev.shard_count()
            )));
        }
    }
    store.begin_bake(&options)?;
    if let Some(bytes) = fallback {
        store.write_file(FALLBACK_FILE, bytes)?;
    }
    let bytes = serde_json::to_vec_pretty(&plan).map_err(|e| BakeError::Plan(e.to_string()))?;
    store.write_file(PLAN_FILE, &bytes)?;
    Ok(plan)
}

/// Checks that `input` is what `plan` was made from, and that `store` holds that plan's bake.
fn check_input(plan: &Plan, input: &TerrainInput<'_>, store: &Store) -> Result<Pyramid, BakeError> {
    let options = options_record_of(input, &plan.source_name, &plan.bake);
    if options != plan.options {
        return Err(BakeError::Plan(format!(
            "{}: the inputs no longer read as when the plan was made ({}); plan again",
            store.describe(PLAN_FILE),
            crate::store::diff_keys(&plan.options, &options)
        )));
    }
    store.check_bake(&options).map_err(|e| match e {
        // The tileset holds another bake than the plan's: a plan edited or for another tileset.
        e @ StoreError::OptionsChanged { .. } => {
            BakeError::Plan(format!("{e} (the plan {} is not this tileset's)", store.describe(PLAN_FILE)))
        }
        e => e.into(),
    })?;
    let (w, h) = input.reader.size();
    let pyramid = Pyramid::new(w, h, plan.bake.tile_size)
        .map_err(|e| BakeError::Plan(format!("{}: {e}", store.describe(PLAN_FILE))))?;
    plan.check_roots(&pyramid, store)?;
    Ok(pyramid)
}

/// Bakes shard `index` of `plan` into `store`: every node of its subtrees (resuming whole ones),
/// then its result file. Idempotent: a shard run again resumes its nodes and writes the same
/// result.
pub fn bake_shard(
    input: &TerrainInput<'_>,
    plan: &Plan,
    index: u32,
    baker: &PointBaker,
    store: &Store,
    progress: &dyn Progress,
) -> Result<BakeSummary, BakeError> {
    let t0 = Instant::now();
    let spec = plan.shards.get(index as usize).ok_or_else(|| {
        BakeError::Plan(format!(
            "shard {index} does not exist: the plan {} has shards 0 to {}",
            store.describe(PLAN_FILE),
            plan.shard_count().saturating_sub(1)
        ))
    })?;
    let pyramid = check_input(plan, input, store)?;
    let mut nodes: Vec<TileKey> = spec.roots.iter().flat_map(|&r| subtree(&pyramid, r)).collect();
    // The one-machine order (root first, depth by depth): larger nodes start first.
    let order: HashMap<TileKey, usize> =
        pyramid.nodes().into_iter().enumerate().map(|(i, k)| (k, i)).collect();
    nodes.sort_by_key(|k| order.get(k).copied().unwrap_or(usize::MAX));
    store.remove_stale_temps_of(&nodes)?;
    let baked = bake_nodes(input, &plan.bake, baker, &pyramid, &nodes, store, progress)?;
    let fragment = Fragment {
        shard: index,
        shards: plan.shard_count(),
        options: plan.options.clone(),
        point_baker: baker.describe(),
        nodes: baked.entries.clone(),
    };
    let bytes = serde_json::to_vec(&fragment).map_err(|e| BakeError::Plan(e.to_string()))?;
    store.write_file(&fragment_file(index), &bytes)?;
    Ok(summary_of(&baked, input, &plan.bake, t0, baker.describe()))
}

fn summary_of(
    baked: &NodesBaked,
    input: &TerrainInput<'_>,
    opts: &BakeOptions,
    t0: Instant,
    point_baker: String,
) -> BakeSummary {
    let mut totals = vec![crate::store::LevelTotals::default(); usize::from(opts.levels) + 1];
    for l in baked.entries.iter().flat_map(|e| &e.levels) {
        if let Some(t) = totals.get_mut(usize::from(l.level)) {
            t.add(l);
        }
    }
    baked.summary(input, totals, t0, point_baker)
}

/// The final step of `plan`: checks that every shard finished, bakes the nodes above the shard
/// depth, writes the index chunks and the manifest (last) and removes `shards/`. Refuses, naming
/// them, while shards are missing.
pub fn finish_plan(
    input: &TerrainInput<'_>,
    plan: &Plan,
    baker: &PointBaker,
    store: &Store,
    progress: &dyn Progress,
) -> Result<BakeSummary, BakeError> {
    let t0 = Instant::now();
    let pyramid = check_input(plan, input, store)?;
    let mut fragments = Vec::with_capacity(plan.shards.len());
    let mut missing = Vec::new();
    // Results that cannot be used (damaged, not a file, too large, another plan's): the shard
    // is sent back as for a damaged blob — running it again rewrites its result.
    let mut unusable: Vec<(u32, String)> = Vec::new();
    for i in 0..plan.shard_count() {
        let file = fragment_file(i);
        let bytes = match read_step_file(store, &file) {
            Ok(None) => {
                missing.push(i);
                continue;
            }
            Ok(Some(bytes)) => bytes,
            Err(BakeError::Plan(why)) => {
                unusable.push((i, why));
                continue;
            }
            Err(e) => return Err(e),
        };
        match serde_json::from_slice::<Fragment>(&bytes) {
            Err(e) => unusable.push((i, format!("{}: invalid shard result: {e}", store.describe(&file)))),
            Ok(f) if f.shard != i || f.shards != plan.shard_count() || f.options != plan.options => {
                unusable.push((
                    i,
                    format!(
                        "{}: written for another plan (shard {} of {})",
                        store.describe(&file),
                        f.shard,
                        f.shards
                    ),
                ));
            }
            Ok(f) => fragments.push(f),
        }
    }
    if !unusable.is_empty() {
        send_back(plan, store, &unusable, "hold results that cannot be used")?;
    }
    if !missing.is_empty() {
        let shown: Vec<String> = missing.iter().take(20).map(ToString::to_string).collect();
        return Err(BakeError::ShardsUnfinished(format!(
            "{} of {} shards have not finished (shards {}{}); run them (bake --plan … --shard I), then finish",
            missing.len(),
            plan.shard_count(),
            shown.join(", "),
            if missing.len() > 20 { ", …" } else { "" }
        )));
    }
    verify_fragments(plan, &pyramid, &fragments, store)?;
    let all = pyramid.nodes();
    // Every shard has finished: any temporary file left in the tileset is a killed writer's.
    store.remove_temps(true)?;
    let top: Vec<TileKey> = all.iter().copied().filter(|k| k.z < plan.shard_depth).collect();
    let baked = bake_nodes(input, &plan.bake, baker, &pyramid, &top, store, progress)?;
    let mut by_key: HashMap<TileKey, NodeEntry> = baked.entries.iter().map(|e| (e.key, e.clone())).collect();
    let mut bakers: Vec<String> = vec![baker.describe()];
    for f in fragments {
        if !bakers.contains(&f.point_baker) {
            bakers.push(f.point_baker);
        }
        for e in f.nodes {
            by_key.insert(e.key, e);
        }
    }
    let mut entries = Vec::with_capacity(all.len());
    for k in &all {
        let e = by_key.remove(k).ok_or_else(|| {
            BakeError::Plan(format!("tile {k} is in no shard's result; run its shard again, then finish"))
        })?;
        entries.push(e);
    }
    let point_baker = bakers.join(" + ");
    let totals =
        publish(input, &plan.source_name, &plan.bake, &point_baker, &entries, plan.options.clone(), store)?;
    store.remove_folder(PLAN_DIR)?;
    // The summary counts the tiles this step baked (the shards reported theirs).
    Ok(baked.summary(input, totals, t0, point_baker))
}

/// Why a blob of a shard's result cannot be published: missing, damaged, or not the blob the
/// shard recorded (length, checksum, tile or level).
fn check_recorded_blob(
    store: &Store,
    key: TileKey,
    l: &crate::store::NodeLevel,
) -> Result<Option<String>, BakeError> {
    let Some(bytes) = store.read_blob(key, l.level)? else {
        return Ok(Some("is missing".into()));
    };
    if bytes.len() as u64 != l.bytes {
        return Ok(Some(format!("is {} bytes; the shard recorded {}", bytes.len(), l.bytes)));
    }
    match crate::codec::verify(&bytes) {
        Err(e) => Ok(Some(format!("is damaged: {e}"))),
        Ok(h) if h.checksum != l.checksum => {
            Ok(Some(format!("has the checksum {:08x}; the shard recorded {:08x}", h.checksum, l.checksum)))
        }
        Ok(h) if h.key != key || h.level != l.level => {
            Ok(Some(format!("holds tile {} level {}", h.key, h.level)))
        }
        Ok(_) => Ok(None),
    }
}

/// Checks that each shard's result lists exactly its subtrees' nodes, and every blob the results
/// record (as a resumed bake checks what it keeps: the length, the blob's own checksums, and the
/// checksum recorded): the final step publishes
/// nothing it has not verified. A shard with a blob that fails is sent back: its result file is
/// removed, so that running the shard again re-bakes what is damaged (it resumes the rest), and
/// the step fails naming the shards, the first bad blob of each, and what to run
/// ([`BakeError::ShardsUnfinished`]: a retry after the shards run again succeeds).
fn verify_fragments(
    plan: &Plan,
    pyramid: &Pyramid,
    fragments: &[Fragment],
    store: &Store,
) -> Result<(), BakeError> {
    use rayon::prelude::*;
    let mut bad: Vec<(u32, String)> = Vec::new();
    for f in fragments {
        // The result lists exactly the nodes of the shard's subtrees, each once.
        let mut want: std::collections::HashSet<TileKey> =
            plan.shards[f.shard as usize].roots.iter().flat_map(|&r| subtree(pyramid, r)).collect();
        let stray = f.nodes.iter().find(|e| !want.remove(&e.key));
        if let Some(e) = stray {
            bad.push((
                f.shard,
                format!("its result lists tile {}, which is not its to bake or is listed twice", e.key),
            ));
            continue;
        }
        if let Some(k) = want.iter().min_by_key(|k| (k.z, k.y, k.x)) {
            bad.push((f.shard, format!("its result lacks tile {k} ({} of its tiles)", want.len())));
            continue;
        }
        let levels: Vec<(TileKey, &crate::store::NodeLevel)> =
            f.nodes.iter().flat_map(|e| e.levels.iter().map(move |l| (e.key, l))).collect();
        let first = levels
            .par_iter()
            .map(|&(k, l)| {
                Ok(check_recorded_blob(store, k, l)?.map(|why| format!("tile {k} level {} {why}", l.level)))
            })
            .collect::<Result<Vec<Option<String>>, BakeError>>()?
            .into_iter()
            .flatten()
            .next();
        if let Some(why) = first {
            bad.push((f.shard, why));
        }
    }
    if bad.is_empty() {
        return Ok(());
    }
    send_back(plan, store, &bad, "hold results or blobs that do not match")
}

/// Sends the shards `bad` (index, why) back: removes each one's result file, so that running
/// it again re-bakes what is damaged (it resumes the rest), and fails naming them
/// ([`BakeError::ShardsUnfinished`]: a retry after the shards run again succeeds).
fn send_back(plan: &Plan, store: &Store, bad: &[(u32, String)], what: &str) -> Result<(), BakeError> {
    for (i, why) in bad {
        tracing::warn!(shard = i, "shard {i} sent back: {why}");
        store.backend().remove(&fragment_file(*i))?;
    }
    let shown: Vec<String> = bad.iter().take(20).map(|(i, why)| format!("shard {i}: {why}")).collect();
    Err(BakeError::ShardsUnfinished(format!(
        "{} of {} shards {what}, so nothing was published ({}{}); \
         those shards were marked unfinished: run them again (bake --plan … --shard I re-bakes what is damaged), then finish",
        bad.len(),
        plan.shard_count(),
        shown.join("; "),
        if bad.len() > 20 { "; …" } else { "" }
    )))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Every node below the shard depth is in exactly one shard; shards are never empty and
    /// their samples are about equal.
    #[test]
    fn shards_cover_the_pyramid_once() {
        for (w, h, ts) in [(257, 257, 32), (1000, 300, 16), (33, 33, 8), (4097, 4097, 256)] {
            let p = Pyramid::new(w, h, ts).unwrap();
            for n in [1u32, 2, 3, 4, 7, 16] {
                let Ok((d, shards)) = plan_shards(&p, n) else {
                    continue;
                };
                assert_eq!(shards.len(), n as usize);
                let mut seen = std::collections::HashSet::new();
                for s in &shards {
                    assert!(!s.roots.is_empty());
                    for &r in &s.roots {
                        assert_eq!(r.z, d);
                        for k in subtree(&p, r) {
                            assert!(seen.insert(k), "{k} twice");
                        }
                    }
                }
                let below: Vec<TileKey> = p.nodes().into_iter().filter(|k| k.z >= d).collect();
                assert_eq!(seen.len(), below.len(), "{w}x{h}/{ts} n={n}");
                if d == 0 {
                    assert_eq!(n, 1);
                }
            }
        }
        let p = Pyramid::new(257, 257, 32).unwrap();
        let (_, s) = plan_shards(&p, 4).unwrap();
        assert!(s.iter().all(|s| s.samples == s.samples.max(1)), "{s:?}");
        let max = s.iter().map(|s| s.samples).max().unwrap();
        let min = s.iter().map(|s| s.samples).min().unwrap();
        assert!(max - min <= max / 4, "{s:?}");
        assert!(plan_shards(&p, 0).is_err());
        let e = plan_shards(&p, 1000).unwrap_err().to_string();
        assert!(e.contains("only 64 leaf tiles"), "{e}");
    }

    #[test]
    fn morton_interleaves() {
        assert_eq!(morton(0, 0), 0);
        assert_eq!(morton(1, 0), 1);
        assert_eq!(morton(0, 1), 2);
        assert_eq!(morton(3, 3), 15);
        assert_eq!(morton(u32::MAX, 0), 0x5555_5555_5555_5555);
    }
}
