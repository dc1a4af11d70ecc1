//! The `terrastream` command line: one file per command, each with its clap `Args` and a
//! `run` that calls the library and prints what it returns; the work is in the library.

pub mod bake;
pub mod bake_model;
#[cfg(feature = "client")]
pub mod client;
#[cfg(feature = "server")]
pub mod demo;
#[cfg(all(feature = "client", feature = "gpu"))]
pub mod eval;
pub mod export;
pub mod inspect;
pub mod pack;
pub mod plan;
mod progress;
#[cfg(feature = "server")]
pub mod serve;
pub mod synth;

use anyhow::{Context, Result};
use clap::{Parser, Subcommand};
use terrastream::lod;
use terrastream::tiling::TileKey;

#[derive(Parser)]
#[command(version, about = "Terrain heightfields → tiled TIN + point-cloud LOD blobs, streamed over HTTP")]
pub struct Cli {
    #[command(subcommand)]
    pub command: Command,
    /// Log filter (e.g. info, debug, terrastream=trace).
    #[arg(long, global = true, default_value = "warn", env = "TERRASTREAM_LOG")]
    pub log: String,
    /// No progress output on stderr (bars, per-frame and per-camera lines, the dataset's
    /// description); what a command prints on stdout, its summary or result, is unchanged.
    /// Accepted by every command.
    #[arg(long, short, global = true)]
    pub quiet: bool,
}

#[derive(Subcommand)]
pub enum Command {
    /// Bake a heightfield raster into a tileset directory (resumes an interrupted bake), or one
    /// step of a sharded bake (--plan).
    Bake(bake::BakeArgs),
    /// Plan a sharded bake: split a dataset into shards (subtrees of the quadtree) baked by
    /// `bake --plan OUT --shard I` on any number of workers, then `bake --plan OUT --finish`.
    Plan(plan::PlanArgs),
    /// Bake a standalone 3D model (OBJ, STL, PLY) into a model tileset: the quantized mesh as
    /// level 0 and point-cloud levels 1..K baked by 6-direction slicing.
    BakeModel(bake_model::BakeModelArgs),
    /// Summarise a tileset: per-level totals and worst errors, or one node with --tile.
    Inspect(inspect::InspectArgs),
    /// Write a deterministic synthetic terrain as a float32 GeoTIFF (for tests and benchmarks).
    Synth(synth::SynthArgs),
    /// Serve a store directory of tilesets over HTTP (and bake missing tiles of --source tilesets).
    #[cfg(feature = "server")]
    Serve(Box<serve::ServeArgs>),
    /// Generate, bake (once) and serve a sample terrain: the quick start.
    #[cfg(feature = "server")]
    Demo(demo::DemoArgs),
    /// Replay a camera flight against a running `terrastream serve`: select, stream and cache
    /// tiles frame by frame and write OUT/stats.json (per-frame and total figures).
    #[cfg(feature = "client")]
    Client(Box<client::ClientArgs>),
    /// Evaluate a tileset's LOD (the first paper, section 4.6): render the full-detail geometry
    /// and the client's LOD selection from cameras spread over distances and two sphere angles,
    /// compare coverage pixel by pixel (recall, precision, F-measure per distance and level,
    /// depth differences), time N×N model instances with and without LOD (model tilesets), and
    /// write REPORT_DIR/report.md with PNG charts. The last line printed is `F-measure: <value>`.
    #[cfg(all(feature = "client", feature = "gpu"))]
    Eval(Box<eval::EvalArgs>),
    /// Export a tileset: one (tile, level) decoded to PLY or OBJ in world coordinates, or the
    /// whole tileset as static 3D Tiles 1.1 (--format 3dtiles).
    Export(export::ExportArgs),
    /// Pack a finished tileset into one archive file (.tsa; local or s3://), which `serve`,
    /// `inspect` and `export` read like the tileset and any HTTP host can serve by ranges.
    Pack(pack::PackArgs),
}

/// The worker and point-baker flags `bake` and `bake-model` share.
#[derive(clap::Args)]
pub struct BakerArgs {
    /// Worker threads (default: all cores).
    #[arg(long)]
    pub threads: Option<usize>,
    /// Where point levels are baked: auto (a hardware GPU adapter, else the CPU with a notice;
    /// a software adapter such as lavapipe is slower than the CPU), on (any GPU adapter,
    /// software ones included, or an error), off (CPU).
    #[arg(long, value_enum, default_value_t = lod::GpuMode::Auto)]
    pub gpu: lod::GpuMode,
    /// GPU memory budget of one batch of point levels, in MiB.
    #[arg(long, default_value_t = lod::DEFAULT_GPU_BUDGET_MIB)]
    pub gpu_budget_mib: u64,
}

impl BakerArgs {
    /// Sizes the global worker pool (`--threads`); call before any parallel work.
    pub fn set_threads(&self) -> Result<()> {
        if let Some(n) = self.threads {
            rayon::ThreadPoolBuilder::new().num_threads(n).build_global().context("--threads")?;
        }
        Ok(())
    }

    /// Opens the point baker `--gpu` asks for, printing its notice (if any) on stderr.
    pub fn open(&self) -> Result<lod::PointBaker> {
        let (baker, notice) = lod::PointBaker::open(self.gpu, self.gpu_budget_mib.saturating_mul(1 << 20))?;
        if let Some(n) = notice {
            eprintln!("{n}");
        }
        Ok(baker)
    }
}

/// Runs the parsed command.
pub fn run(cli: Cli) -> Result<()> {
    let quiet = cli.quiet;
    match cli.command {
        Command::Bake(a) => match &a.plan {
            Some(plan_at) => plan::run_step(&a, plan_at, quiet),
            None => bake::run(&a, quiet),
        },
        Command::Plan(a) => plan::run(&a, quiet),
        Command::BakeModel(a) => bake_model::run(&a),
        Command::Inspect(a) => inspect::run(&a),
        Command::Synth(a) => synth::run(&a),
        #[cfg(feature = "server")]
        Command::Serve(a) => serve::run(&a),
        #[cfg(feature = "server")]
        Command::Demo(a) => demo::run(&a, quiet),
        #[cfg(feature = "client")]
        Command::Client(a) => client::run(&a, quiet),
        #[cfg(all(feature = "client", feature = "gpu"))]
        Command::Eval(a) => eval::run(&a, quiet),
        Command::Export(mut a) => {
            a.quiet |= quiet;
            export::run(&a)
        }
        Command::Pack(a) => pack::run(&a, quiet),
    }
}

/// Whether the logs are JSON lines (`serve --log-format json`, from flags, environment or file).
#[must_use]
pub fn json_logs(cli: &Cli) -> bool {
    match &cli.command {
        #[cfg(feature = "server")]
        Command::Serve(a) => a.config().is_ok_and(|c| c.log_format == terrastream::server::LogFormat::Json),
        _ => false,
    }
}

pub(crate) fn parse_key(s: &str) -> Result<TileKey, String> {
    let parts: Vec<&str> = s.split('/').collect();
    let [z, x, y] = parts.as_slice() else {
        return Err(format!("expected Z/X/Y, got {s:?}"));
    };
    let num = |v: &str, name: &str| v.parse::<u32>().map_err(|_| format!("{name} in {s:?} is not a number"));
    let z = num(z, "Z")?;
    Ok(TileKey::new(
        u8::try_from(z).map_err(|_| format!("Z in {s:?} is too large"))?,
        num(x, "X")?,
        num(y, "Y")?,
    ))
}

pub(crate) fn parse_pair(s: &str) -> Result<(f64, f64), String> {
    let (a, b) = s.split_once(',').ok_or_else(|| format!("expected X,Y, got {s:?}"))?;
    let f = |v: &str| v.trim().parse::<f64>().map_err(|_| format!("{v:?} is not a number"));
    Ok((f(a)?, f(b)?))
}

/// Raises the soft limit on open files (`RLIMIT_NOFILE`) to the hard one, as far as the system
/// allows: a bake of a mosaic of thousands of files, or a server with many clients and
/// archives, should not stop at a shell's default of 1,024 when the hard limit is higher. The
/// input files' pool (`raster::open_files`) sizes itself from the soft limit it then finds.
/// Failures leave the limit as it was.
pub fn raise_open_file_limit() {
    #[cfg(unix)]
    {
        use rustix::process::{Resource, Rlimit, getrlimit, setrlimit};
        let Rlimit { current, maximum } = getrlimit(Resource::Nofile);
        // macOS refuses more than OPEN_MAX (10,240) whatever the hard limit says.
        let target = if cfg!(target_os = "macos") {
            maximum.map_or(10_240, |m| m.min(10_240))
        } else {
            match maximum {
                Some(m) => m,
                None => return,
            }
        };
        if current.is_some_and(|c| c < target) {
            let _ = setrlimit(Resource::Nofile, Rlimit { current: Some(target), maximum });
        }
    }
}

/// Without a usable `XDG_RUNTIME_DIR` (containers, CI, ssh sessions), Mesa's implicit
/// device-select Vulkan layer asks libwayland for a display while wgpu opens the adapter, and
/// libwayland prints "error: XDG_RUNTIME_DIR is invalid or not set in the environment." — a
/// line that means nothing for a headless bake. Without a Wayland session there is nothing for
/// that layer to select by, so the process re-executes itself once with the layer disabled
/// (`NODEVICE_SELECT=1`, Mesa's documented switch; same pid, arguments and streams). A user who
/// sets `NODEVICE_SELECT` themselves is left alone.
pub fn quiet_mesa_device_select() {
    #[cfg(target_os = "linux")]
    {
        use std::os::unix::process::CommandExt;
        let runtime_ok =
            std::env::var_os("XDG_RUNTIME_DIR").is_some_and(|d| std::path::Path::new(&d).is_dir());
        if runtime_ok || std::env::var_os("NODEVICE_SELECT").is_some() {
            return;
        }
        let Ok(exe) = std::env::current_exe() else { return };
        let mut args = std::env::args_os();
        let arg0 = args.next().unwrap_or_else(|| exe.clone().into_os_string());
        // `exec` returns only if it failed; then run on as we are.
        let _ = std::process::Command::new(exe).arg0(arg0).args(args).env("NODEVICE_SELECT", "1").exec();
    }
}

/// The error and its causes joined by ": ", each cause once: library messages often embed
/// their source's text already, so a cause whose text is printed is not printed again.
pub fn error_chain(e: &anyhow::Error) -> String {
    let mut out = String::new();
    for cause in e.chain() {
        let text = cause.to_string();
        if text.is_empty() || out.contains(&text) {
            continue;
        }
        if !out.is_empty() {
            out.push_str(": ");
        }
        out.push_str(&text);
    }
    out
}
