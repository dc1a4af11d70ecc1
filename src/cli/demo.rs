//! `terrastream demo`: generate, bake (once) and serve a sample terrain: the quick start.

use std::path::PathBuf;
use std::time::Instant;

use anyhow::Result;
use terrastream::{lod, server};

use super::progress::Bar;

#[derive(clap::Args)]
pub struct DemoArgs {
    /// Address to serve on.
    #[arg(long, default_value = server::DEFAULT_BIND)]
    pub bind: String,
    /// Working directory: the generated terrain and the store (out/demo-store) go here.
    #[arg(long, default_value = "out")]
    pub dir: PathBuf,
    /// Generate and bake only; do not serve.
    #[arg(long)]
    pub no_serve: bool,
    /// Where the demo's point levels are baked (as `bake --gpu`).
    #[arg(long, value_enum, default_value_t = lod::GpuMode::Auto)]
    pub gpu: lod::GpuMode,
}

pub fn run(a: &DemoArgs, quiet: bool) -> Result<()> {
    let DemoArgs { ref bind, ref dir, no_serve, gpu } = *a;
    let progress = Bar::stderr("baking demo terrain {bar:40} {pos}/{len} tiles  ETA {eta}", quiet, None);
    let t0 = Instant::now();
    let (baker, notice) = lod::PointBaker::open(gpu, lod::DEFAULT_GPU_BUDGET_MIB << 20)?;
    if let Some(n) = notice {
        eprintln!("{n}");
    }
    let (store, baked) = server::demo::prepare(dir, &baker, &progress)?;
    progress.finish();
    if baked {
        outln!(
            "baked the demo terrain into {} in {:.1} s (point levels: {})",
            store.display(),
            t0.elapsed().as_secs_f64(),
            baker.describe()
        );
    } else {
        outln!("using the demo tileset already baked in {}", store.display());
    }
    if no_serve {
        return Ok(());
    }
    let config = server::PartialConfig { store: Some(store), bind: Some(bind.clone()), ..Default::default() }
        .resolve()?;
    server::serve_blocking(config, |addr, app| {
        super::serve::print_urls(addr, &app.tileset_names());
        outln!("try:  curl -sI http://{addr}/tilesets/demo/tiles/1/0/1/0");
    })?;
    Ok(())
}
