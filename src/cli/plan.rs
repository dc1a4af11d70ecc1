//! `terrastream plan` and the steps of a sharded bake (`bake --plan … --shard I`, `bake --plan …
//! --finish`): one bake split over the workers of an engine that runs array jobs (Kubernetes
//! Indexed Jobs, AWS Batch, Slurm). The work is in `terrastream::bake::shard`.

use std::path::{Path, PathBuf};

use anyhow::{Context, Result};
use terrastream::bake::shard::{self, PLAN_FILE, Plan, PlanInputs};
use terrastream::raster;
use terrastream::store::Store;

use super::bake::{BakeArgs, InputArgs, open_with, print_summary, tiles_bar};

#[derive(clap::Args)]
pub struct PlanArgs {
    /// Input rasters forming one dataset (as for `bake`). Every shard reads them at the same
    /// paths: on a cluster, a volume mounted alike in every pod.
    #[arg(required = true, num_args = 1..)]
    pub inputs: Vec<PathBuf>,
    /// The tileset to bake into (created; must be empty or an earlier bake of the same input).
    #[arg(long)]
    pub out: PathBuf,
    /// Number of shards. Default: as many as keep each shard's region of the raster within
    /// --shard-mib of float heights.
    #[arg(long, value_parser = clap::value_parser!(u32).range(1..=i64::from(shard::MAX_SHARDS)))]
    pub shards: Option<u32>,
    /// Largest region of the raster one shard covers, in MiB of 4-byte heights (when --shards is
    /// not given).
    #[arg(long, default_value_t = 4096)]
    pub shard_mib: u64,
    #[command(flatten)]
    pub input: InputArgs,
}

/// Marks an error as the input's or the plan's fault (a retry cannot succeed): the process exits
/// with [`INPUT_REFUSED_EXIT`], which a Kubernetes `podFailurePolicy` turns into a failed index
/// at once. Its text is empty: the error it wraps says what is wrong.
#[derive(Debug)]
pub struct InputRefused;

impl std::fmt::Display for InputRefused {
    fn fmt(&self, _: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        Ok(())
    }
}

impl std::error::Error for InputRefused {}

/// Exit status of a step refused for its input or plan (2 is a usage error, from clap).
pub const INPUT_REFUSED_EXIT: u8 = 3;

/// Array-index variables of the engines that run array jobs, in the order they are read.
pub const INDEX_VARS: [&str; 3] =
    ["JOB_COMPLETION_INDEX", "AWS_BATCH_JOB_ARRAY_INDEX", "SLURM_ARRAY_TASK_ID"];

pub fn run(a: &PlanArgs, quiet: bool) -> Result<()> {
    Store::at(&a.out)?.check_out()?;
    // The input refused exits as a step's does (3): a retry cannot help.
    let files = raster::dataset::expand_inputs(&a.inputs).context(InputRefused)?;
    let files: Vec<PathBuf> = files
        .into_iter()
        .map(|f| std::path::absolute(&f).with_context(|| format!("{}", f.display())))
        .collect::<Result<_>>()?;
    let opened = a.input.open(files, quiet).context(InputRefused)?;
    let (w, h) = {
        let g = opened.dataset.summary();
        (g.width, g.height)
    };
    let samples = u64::from(w) * u64::from(h);
    let per = a.shard_mib.max(1).saturating_mul(1 << 20) / 4;
    let shards = a.shards.unwrap_or_else(|| u32::try_from(samples.div_ceil(per).max(1)).unwrap_or(u32::MAX));
    let input = terrastream::bake::TerrainInput::of_dataset(&opened.dataset);
    // The scan's results go into the plan, so that the shards open the inputs without reading
    // every sample again (each reads only its own region).
    let (scan, fallback) = opened.dataset.scan_record()?;
    let inputs = PlanInputs { files: opened.files.clone(), read: a.input.options(), scan: Some(scan) };
    let store = Store::at(&a.out)?;
    let plan = shard::write_plan(
        &input,
        &opened.name,
        &a.input.bake_options(),
        inputs,
        shards,
        fallback.as_deref(),
        &store,
    )
    .map_err(refused_unless_io)?;
    let biggest = plan.shards.iter().map(|s| s.samples).max().unwrap_or(0);
    outln!(
        "plan: {} shards of the subtrees at depth {} ({} tiles each at most, ≤ {:.1} MiB of heights), then a final step for the {} tiles above\n\
         written to {}\n\
         run: terrastream bake --plan {} --shard I   for I in 0..{} (or as an array job: {}),\n\
         \x20    terrastream bake --plan {} --finish    once they have all finished",
        plan.shard_count(),
        plan.shard_depth,
        plan.shards.iter().map(|s| s.nodes).max().unwrap_or(0),
        biggest as f64 * 4.0 / f64::from(1 << 20),
        plan.top_nodes,
        store.describe(PLAN_FILE),
        a.out.display(),
        plan.shard_count(),
        INDEX_VARS.join(", "),
        a.out.display(),
    );
    Ok(())
}

/// The shard index: `--shard`, else the first array-index variable set.
fn shard_index(given: Option<u32>) -> Result<u32> {
    if let Some(i) = given {
        return Ok(i);
    }
    for var in INDEX_VARS {
        if let Ok(v) = std::env::var(var) {
            return v
                .trim()
                .parse::<u32>()
                .map_err(|_| anyhow::anyhow!("{var}={v:?} is not a shard index (0, 1, 2, …)"))
                .context(InputRefused);
        }
    }
    Err(anyhow::anyhow!(
        "bake --plan: give --shard I, --finish, or run as an array job that sets {}",
        INDEX_VARS.join(", ")
    ))
    .context(InputRefused)
}

/// A plan's error as the process reports it: one that cannot be read (an I/O error, a bucket
/// failing past its retries) may be read on a retry; one that is damaged or of another version
/// may not ([`InputRefused`]).
fn refused_unless_io(e: terrastream::bake::BakeError) -> anyhow::Error {
    use terrastream::bake::BakeError;
    use terrastream::store::StoreError;
    // A plan that is a directory (or another file that is no plan) is the plan's fault too.
    let not_a_file = |e: &std::io::Error| {
        matches!(e.kind(), std::io::ErrorKind::IsADirectory | std::io::ErrorKind::NotADirectory)
    };
    let refused = match &e {
        BakeError::Store(StoreError::Io { source, .. }) => not_a_file(source),
        BakeError::Store(_) => false,
        _ => true,
    };
    let e = anyhow::Error::from(e);
    if refused { e.context(InputRefused) } else { e }
}

/// `bake --plan TILESET (--shard I | --finish)`.
pub fn run_step(a: &BakeArgs, plan_at: &Path, quiet: bool) -> Result<()> {
    a.baker.set_threads()?;
    let dir = if plan_at.ends_with(PLAN_FILE) {
        plan_at.parent().and_then(Path::parent).unwrap_or(Path::new("."))
    } else {
        plan_at
    };
    let store = Store::at(dir).context(InputRefused)?;
    let plan = match Plan::read(&store).map_err(refused_unless_io)? {
        Some(p) => p,
        None if store.has_manifest()? => {
            // Every step is idempotent: a step run again after the final one has nothing to do.
            eprintln!(
                "{}: the sharded bake has finished (the tileset is complete); nothing to do",
                dir.display()
            );
            return Ok(());
        }
        None => {
            return Err(anyhow::anyhow!(
                "{}: no plan; write one with `terrastream plan INPUTS --out {}`",
                store.describe(PLAN_FILE),
                dir.display()
            ))
            .context(InputRefused);
        }
    };
    let step = if a.finish { None } else { Some(shard_index(a.shard)?) };
    if step.is_some() && a.anchor.is_some() {
        // Not silently ignored: the placement is written by the final step.
        clap::Error::raw(
            clap::error::ErrorKind::ArgumentConflict,
            "--anchor places the finished tileset: give it to `bake --plan … --finish`, not to a shard\n",
        )
        .exit();
    }
    if let Some(i) = step
        && i >= plan.shard_count()
    {
        // Before the inputs are opened: a wrong index fails at once.
        return Err(anyhow::anyhow!(
            "shard {i} does not exist: the plan {} has shards 0 to {}",
            store.describe(PLAN_FILE),
            plan.shard_count().saturating_sub(1)
        ))
        .context(InputRefused);
    }
    let fallback = plan.read_fallback(&store).map_err(refused_unless_io)?;
    let inputs = &plan.inputs;
    let scanned = inputs.scan.as_ref().map(|s| (s, fallback.as_deref()));
    // The block cache and the scratch folder are this process's (the bytes baked do not depend
    // on them); every other input flag is the plan's (given here, clap refuses it).
    let mut read = inputs.read.clone();
    if let Some(mib) = a.input.cache_mib {
        read.cache_mib = mib;
    }
    if let Some(dir) = &a.input.scratch_dir {
        read.scratch_dir = Some(dir.clone());
    }
    let opened = open_with(&read, inputs.files.clone(), scanned, quiet).context(InputRefused)?;
    let input = terrastream::bake::TerrainInput::of_dataset(&opened.dataset);
    let baker = a.baker.open()?;
    let progress = tiles_bar(quiet, a.time_limit);
    let r = match step {
        Some(i) => shard::bake_shard(&input, &plan, i, &baker, &store, &progress),
        None => shard::finish_plan(&input, &plan, &baker, &store, &progress),
    };
    progress.finish();
    let summary = r.map_err(|e| {
        let refused = matches!(e, terrastream::bake::BakeError::Plan(_));
        let e = anyhow::Error::from(e);
        if refused { e.context(InputRefused) } else { e }
    })?;
    if let Some(i) = step {
        outln!("shard {i} of {}:", plan.shard_count());
    } else {
        if let Some(anchor) = a.anchor {
            terrastream::bake::export::write_anchor(&store, anchor)?;
        }
        outln!("final step of {} shards:", plan.shard_count());
    }
    print_summary(&summary, dir);
    Ok(())
}
