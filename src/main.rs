//! The `terrastream` command: argument parsing, logging and progress bars; the work is in the
//! library.

/// `println!` that does not panic when stdout is gone: a closed pipe (`terrastream inspect … |
/// head`) ends the process quietly, as it ends other Unix tools; any other write error is
/// reported.
macro_rules! outln {
    ($($t:tt)*) => {{
        use std::io::Write as _;
        if let Err(e) = writeln!(std::io::stdout(), $($t)*) {
            if e.kind() != std::io::ErrorKind::BrokenPipe {
                eprintln!("error: cannot write to standard output: {e}");
                std::process::exit(1);
            }
            std::process::exit(0);
        }
    }};
}

use std::path::PathBuf;
use std::time::{Duration, Instant};

use anyhow::{Context, Result, bail};
use clap::{Parser, Subcommand, ValueEnum};
use indicatif::{ProgressBar, ProgressStyle};
use terrastream::bake::model::{self as bake_model, ModelBakeOptions, ModelLevel};
use terrastream::bake::{self, BakeOptions, BakeSummary};
#[cfg(feature = "client")]
use terrastream::client;
use terrastream::model::FileType;
use terrastream::raster::{self, Encoding, Limits, LoadOptions, Overrides};
#[cfg(feature = "server")]
use terrastream::server;
use terrastream::store::export;
use terrastream::store::{LevelTotals, Store};
use terrastream::tiling;
use terrastream::tiling::TileKey;

#[derive(Parser)]
#[command(version, about = "Terrain heightfields → tiled TIN + point-cloud LOD blobs, streamed over HTTP")]
struct Cli {
    #[command(subcommand)]
    command: Command,
    /// Log filter (e.g. info, debug, terrastream=trace).
    #[arg(long, global = true, default_value = "warn", env = "TERRASTREAM_LOG")]
    log: String,
}

#[derive(Subcommand)]
enum Command {
    /// Bake a heightfield raster into a tileset directory (resumes an interrupted bake).
    Bake(BakeArgs),
    /// Bake a standalone 3D model (OBJ, STL, PLY) into a model tileset: the quantized mesh as
    /// level 0 and point-cloud levels 1..K baked by 6-direction slicing.
    BakeModel(BakeModelArgs),
    /// Summarise a tileset: per-level totals and worst errors, or one node with --tile.
    Inspect {
        /// Tileset directory.
        dir: PathBuf,
        /// Print JSON instead of a table.
        #[arg(long)]
        json: bool,
        /// One node, as Z/X/Y.
        #[arg(long, value_parser = parse_key)]
        tile: Option<TileKey>,
    },
    /// Write a deterministic synthetic terrain as a float32 GeoTIFF (for tests and benchmarks).
    Synth {
        /// Output .tif file.
        #[arg(long)]
        out: PathBuf,
        /// Width in samples.
        #[arg(long, default_value_t = 1025)]
        width: u32,
        /// Height in samples (default: the width).
        #[arg(long)]
        height: Option<u32>,
        /// Cell size in metres.
        #[arg(long, default_value_t = 10.0)]
        cell_size: f64,
        #[arg(long, default_value_t = 1)]
        seed: u64,
    },
    /// Serve a store directory of tilesets over HTTP (and bake missing tiles of --source tilesets).
    #[cfg(feature = "server")]
    Serve(Box<ServeArgs>),
    /// Generate, bake (once) and serve a sample terrain: the quick start.
    #[cfg(feature = "server")]
    Demo {
        /// Address to serve on.
        #[arg(long, default_value = server::DEFAULT_BIND)]
        bind: String,
        /// Working directory: the generated terrain and the store (out/demo-store) go here.
        #[arg(long, default_value = "out")]
        dir: PathBuf,
        /// Generate and bake only; do not serve.
        #[arg(long)]
        no_serve: bool,
        /// Where the demo's point levels are baked (as `bake --gpu`).
        #[arg(long, value_enum, default_value_t = GpuArg::Auto)]
        gpu: GpuArg,
    },
    /// Replay a camera flight against a running `terrastream serve`: select, stream and cache
    /// tiles frame by frame and write OUT/stats.json (per-frame and total figures).
    #[cfg(feature = "client")]
    Client(Box<ClientArgs>),
    /// Evaluate a tileset's LOD (the first paper, section 4.6): render the full-detail geometry
    /// and the client's LOD selection from cameras spread over distances and two sphere angles,
    /// compare coverage pixel by pixel (recall, precision, F-measure per distance and level,
    /// depth differences), time N×N model instances with and without LOD (model tilesets), and
    /// write REPORT_DIR/report.md with PNG charts. The last line printed is `F-measure: <value>`.
    #[cfg(all(feature = "client", feature = "gpu"))]
    Eval(Box<EvalArgs>),
    /// Decode one (tile, level) to PLY or OBJ in world coordinates.
    Export {
        /// Tileset directory.
        dir: PathBuf,
        #[arg(long, value_parser = parse_key)]
        tile: TileKey,
        #[arg(long)]
        level: u8,
        #[arg(long, value_enum, default_value_t = ExportFormat::Ply)]
        format: ExportFormat,
        #[arg(long)]
        out: PathBuf,
    },
}

#[cfg(all(feature = "client", feature = "gpu"))]
#[derive(clap::Args)]
struct EvalArgs {
    /// Tileset directory (a terrain `bake` or a `bake-model` output).
    dir: PathBuf,
    /// Report directory (report.md, fmeasure.png, frametime.png, frames/).
    #[arg(long, default_value = "eval-report")]
    out: PathBuf,
    /// Viewport width in pixels.
    #[arg(long, default_value_t = client::eval::DEFAULT_EVAL_WIDTH)]
    width: u32,
    /// Viewport height in pixels.
    #[arg(long, default_value_t = client::eval::DEFAULT_EVAL_HEIGHT)]
    height: u32,
    /// Horizontal field of view in degrees.
    #[arg(long, default_value_t = client::select::DEFAULT_FOV_DEG)]
    fov: f64,
    /// Screen-space error threshold in pixels (the client's selection).
    #[arg(long, default_value_t = client::select::DEFAULT_THRESHOLD_PX)]
    threshold: f64,
    /// Camera distances, in multiples of the distance at which the bounding sphere fills the
    /// view [default: 0.5,1,2,4,8].
    #[arg(long, value_delimiter = ',')]
    distances: Vec<f64>,
    /// Azimuths per distance and elevation, spread evenly over 360°.
    #[arg(long, default_value_t = client::eval::DEFAULT_AZIMUTHS)]
    azimuths: u32,
    /// Elevations in degrees [default: terrain 20,45,70 about +Z; models -45,0,45 about +Y].
    #[arg(long, value_delimiter = ',', allow_hyphen_values = true)]
    elevations: Vec<f64>,
    /// Grid sides N of the instance experiment (N×N instances of the model).
    #[arg(long, value_delimiter = ',', default_values_t = client::eval::DEFAULT_GRID_SIDES)]
    grid: Vec<u32>,
    /// Skip grid sides above this (for slow adapters such as lavapipe).
    #[arg(long, default_value_t = client::evaluate::DEFAULT_MAX_GRID)]
    max_grid: u32,
    /// Frames timed per configuration (median reported; one warm-up frame before).
    #[arg(long, default_value_t = client::evaluate::DEFAULT_FRAMES)]
    frames: u32,
    /// Print only the summary (no per-camera progress).
    #[arg(long)]
    quiet: bool,
}

#[cfg(feature = "client")]
#[derive(clap::Args)]
struct ClientArgs {
    /// Server base URL (http://HOST:PORT[/PREFIX]).
    #[arg(long)]
    url: String,
    /// Tileset name on the server.
    #[arg(long)]
    tileset: String,
    /// Flight JSON (timestamped eye/target/up keys; see docs: world or normalized frame).
    #[arg(long)]
    flight: PathBuf,
    /// Viewport width in pixels.
    #[arg(long, default_value_t = client::live::DEFAULT_WIDTH)]
    width: u32,
    /// Viewport height in pixels.
    #[arg(long, default_value_t = client::live::DEFAULT_HEIGHT)]
    height: u32,
    /// Horizontal field of view in degrees.
    #[arg(long, default_value_t = client::select::DEFAULT_FOV_DEG)]
    fov: f64,
    /// Screen-space error threshold in pixels.
    #[arg(long, default_value_t = client::select::DEFAULT_THRESHOLD_PX)]
    threshold: f64,
    /// Level cross-fade duration in seconds (0: switch at once).
    #[arg(long, default_value_t = client::select::DEFAULT_FADE_SECONDS)]
    fade: f64,
    /// Frames per second of the replay.
    #[arg(long, default_value_t = client::live::DEFAULT_FPS)]
    fps: f64,
    /// Longest time (s) to hold the last pose waiting for a complete view.
    #[arg(long, default_value_t = client::live::DEFAULT_SETTLE_S)]
    settle: f64,
    /// Requests running at once.
    #[arg(long, default_value_t = client::fetch::DEFAULT_MAX_IN_FLIGHT)]
    max_in_flight: usize,
    /// Decoded-tile cache budget in MiB.
    #[arg(long, default_value_t = client::fetch::DEFAULT_CACHE_BYTES >> 20)]
    cache_mb: usize,
    /// Render frames (wgpu, headless): auto = with any adapter (software included), replaying
    /// without rendering when there is none; on = an adapter or an error; off = never.
    #[arg(long, value_enum, default_value = "auto")]
    render: GpuArg,
    /// Write every Nth rendered frame as OUT/frames/NNNNN.png plus the settled view as
    /// OUT/frames/final.png; 0 = write none (frames are still rendered and timed).
    #[arg(long, default_value_t = client::live::DEFAULT_FRAMES_EVERY)]
    frames_every: u32,
    /// Output directory (stats.json, frames/).
    #[arg(long, default_value = "out/client")]
    out: PathBuf,
}

/// Every serve setting is optional here: unset ones come from the TOML file (--config), then
/// the defaults. Environment variables count as flags.
#[cfg(feature = "server")]
#[derive(clap::Args)]
struct ServeArgs {
    #[arg(
        long,
        env = "TERRASTREAM_STORE",
        help = "Store directory: each subdirectory DIR/NAME is a tileset"
    )]
    store: Option<PathBuf>,
    #[arg(long, env = "TERRASTREAM_BIND", help = format!("Address to listen on [default: {}]", server::DEFAULT_BIND))]
    bind: Option<String>,
    #[arg(
        long = "source",
        value_name = "NAME=RASTER[,key=value…]",
        help = "Bake tiles of tileset NAME missing from the store from RASTER on first request; keys: encoding, cell_size, tile_size, max_error, levels (repeatable)"
    )]
    sources: Vec<server::SourceSpec>,
    #[arg(
        long,
        env = "TERRASTREAM_CONFIG",
        help = "TOML file with the same settings (snake_case keys); flags and environment win"
    )]
    config: Option<PathBuf>,
    #[arg(long, env = "TERRASTREAM_MAX_CONNECTIONS", help = format!("Most open connections [default: {}]", server::DEFAULT_MAX_CONNECTIONS))]
    max_connections: Option<usize>,
    #[arg(long, env = "TERRASTREAM_MAX_IN_FLIGHT", help = format!("Most requests in progress; more get 503 + Retry-After [default: {}]", server::DEFAULT_MAX_IN_FLIGHT))]
    max_in_flight: Option<usize>,
    #[arg(long, env = "TERRASTREAM_REQUEST_TIMEOUT", value_name = "SECONDS", help = format!("Per-request time limit [default: {}]", server::DEFAULT_REQUEST_TIMEOUT_S))]
    request_timeout: Option<u64>,
    #[arg(long, env = "TERRASTREAM_MAX_BODY_BYTES", help = format!("Largest admin upload [default: {}]", server::DEFAULT_MAX_BODY_BYTES))]
    max_body_bytes: Option<u64>,
    #[arg(long, env = "TERRASTREAM_BAKE_WORKERS", help = format!("On-demand bake threads [default: {}]", server::DEFAULT_BAKE_WORKERS))]
    bake_workers: Option<usize>,
    #[arg(long, env = "TERRASTREAM_BAKE_QUEUE", help = format!("On-demand bakes that may wait; more get 503 + Retry-After [default: {}]", server::DEFAULT_BAKE_QUEUE))]
    bake_queue: Option<usize>,
    #[arg(long, env = "TERRASTREAM_CACHE_BYTES", help = format!("Memory for verified blobs [default: {}]", server::DEFAULT_CACHE_BYTES))]
    cache_bytes: Option<u64>,
    #[arg(long, env = "TERRASTREAM_POLL_MS", help = format!("Store re-scan interval in ms [default: {}]", server::DEFAULT_POLL_MS))]
    poll_ms: Option<u64>,
    #[arg(long, env = "TERRASTREAM_RATE_LIMIT", help = format!("Requests per second per client address, 0 = off [default: {}]", server::DEFAULT_RATE_LIMIT))]
    rate_limit: Option<u32>,
    #[arg(long, env = "TERRASTREAM_SHUTDOWN_TIMEOUT", value_name = "SECONDS", help = format!("Time in-flight requests get after SIGTERM [default: {}]", server::DEFAULT_SHUTDOWN_TIMEOUT_S))]
    shutdown_timeout: Option<u64>,
    #[arg(long, env = "TERRASTREAM_MAX_CONNECTIONS_PER_CLIENT", help = format!("Most open connections from one client IP; more get 503 and are closed; 0 = no limit [default: {}]", server::DEFAULT_MAX_CONNECTIONS_PER_CLIENT))]
    max_connections_per_client: Option<usize>,
    #[arg(long, env = "TERRASTREAM_HEADER_TIMEOUT", value_name = "SECONDS", help = format!("Time a client has to send a request head from its first byte [default: {}]", server::DEFAULT_HEADER_TIMEOUT_S))]
    header_timeout: Option<u64>,
    #[arg(long, env = "TERRASTREAM_IDLE_TIMEOUT", value_name = "SECONDS", help = format!("A connection with no request in flight is closed after this long idle [default: {}]", server::DEFAULT_IDLE_TIMEOUT_S))]
    idle_timeout: Option<u64>,
    #[arg(long, env = "TERRASTREAM_JOB_TIMEOUT", value_name = "SECONDS", help = format!("Longest an admin bake job may run before it is stopped (failed) [default: {}]", server::DEFAULT_JOB_TIMEOUT_S))]
    job_timeout: Option<u64>,
    #[arg(long, env = "TERRASTREAM_JOB_TTL", value_name = "SECONDS", help = format!("How long ended admin jobs stay at /jobs/ID [default: {}]", server::DEFAULT_JOB_TTL_S))]
    job_ttl: Option<u64>,
    #[arg(
        long,
        env = "TERRASTREAM_ADMIN_TOKEN",
        hide_env_values = true,
        help = "Bearer token of the admin API (disabled without)"
    )]
    admin_token: Option<String>,
    #[arg(
        long,
        env = "TERRASTREAM_READ_TOKEN",
        hide_env_values = true,
        help = "Bearer token required for reading (public without)"
    )]
    read_token: Option<String>,
    #[arg(long, env = "TERRASTREAM_LOG_FORMAT", value_enum, help = "Log format [default: human]")]
    log_format: Option<LogFormatArg>,
    #[arg(
        long,
        env = "TERRASTREAM_GPU",
        value_enum,
        help = "Where on-demand and admin bakes compute point levels: auto (any adapter, else the CPU), on, off [default: auto]"
    )]
    gpu: Option<GpuArg>,
    #[arg(long, env = "TERRASTREAM_GPU_BUDGET_MIB", help = format!("GPU memory budget of one batch of point levels, MiB [default: {}]", bake::DEFAULT_GPU_BUDGET_MIB))]
    gpu_budget_mib: Option<u64>,
}

#[cfg(feature = "server")]
#[derive(Clone, Copy, ValueEnum)]
enum LogFormatArg {
    Human,
    Json,
}

#[cfg(feature = "server")]
impl ServeArgs {
    /// Flags and environment over the TOML file over the defaults.
    fn config(&self) -> Result<server::Config> {
        let flags = server::PartialConfig {
            store: self.store.clone(),
            bind: self.bind.clone(),
            sources: self.sources.clone(),
            max_connections: self.max_connections,
            max_in_flight: self.max_in_flight,
            request_timeout_s: self.request_timeout,
            max_body_bytes: self.max_body_bytes,
            bake_workers: self.bake_workers,
            bake_queue: self.bake_queue,
            cache_bytes: self.cache_bytes,
            poll_ms: self.poll_ms,
            rate_limit: self.rate_limit,
            shutdown_timeout_s: self.shutdown_timeout,
            max_connections_per_client: self.max_connections_per_client,
            header_timeout_s: self.header_timeout,
            idle_timeout_s: self.idle_timeout,
            job_timeout_s: self.job_timeout,
            job_ttl_s: self.job_ttl,
            admin_token: self.admin_token.clone(),
            read_token: self.read_token.clone(),
            log_format: self.log_format.map(|f| match f {
                LogFormatArg::Human => server::LogFormat::Human,
                LogFormatArg::Json => server::LogFormat::Json,
            }),
            gpu: self.gpu.map(gpu_mode),
            gpu_budget_mib: self.gpu_budget_mib,
        };
        let file = match &self.config {
            Some(p) => server::PartialConfig::from_toml_file(p)?,
            None => server::PartialConfig::default(),
        };
        Ok(flags.over(file).resolve()?)
    }
}

#[derive(clap::Args)]
struct BakeArgs {
    /// Input raster: OpenEXR, 16-bit PNG, terrain-RGB/Terrarium PNG, GeoTIFF or SRTM .hgt.
    input: PathBuf,
    /// Output tileset directory (created; must be empty or an earlier bake of the same input).
    #[arg(long)]
    out: PathBuf,
    /// Leaf tile size in raster cells.
    #[arg(long, default_value_t = tiling::DEFAULT_TILE_SIZE)]
    tile_size: u32,
    /// TIN error bound for leaf tiles, in metres (parents scale it with their cell size).
    #[arg(long, default_value_t = bake::DEFAULT_MAX_ERROR)]
    max_error: f64,
    /// Point-cloud levels below the mesh (cells of 2, 4, 8, … leaf cells).
    #[arg(long, default_value_t = bake::DEFAULT_LEVELS)]
    levels: u8,
    /// How a PNG encodes heights.
    #[arg(long, value_enum)]
    encoding: Option<EncodingArg>,
    /// OpenEXR channel to read (default: the first float channel).
    #[arg(long)]
    channel: Option<String>,
    /// Horizontal cell size in metres (overrides the file's georeference).
    #[arg(long)]
    cell_size: Option<f64>,
    /// World position of sample (0, 0) as X,Y (overrides the file's georeference).
    #[arg(long, value_parser = parse_pair, allow_hyphen_values = true)]
    origin: Option<(f64, f64)>,
    /// Multiply raw sample values by this.
    #[arg(long, allow_hyphen_values = true)]
    z_scale: Option<f64>,
    /// Add this to heights after scaling.
    #[arg(long, allow_hyphen_values = true)]
    z_offset: Option<f64>,
    /// Refuse rasters with a side longer than this many samples.
    #[arg(long, default_value_t = raster::DEFAULT_MAX_SIDE)]
    max_side: u32,
    /// Refuse rasters whose decoded heights exceed this many bytes.
    #[arg(long, default_value_t = raster::DEFAULT_MAX_BYTES)]
    max_bytes: u64,
    /// Worker threads (default: all cores).
    #[arg(long)]
    threads: Option<usize>,
    /// Where point levels are baked: auto (any GPU adapter, software ones included, else the
    /// CPU with a notice), on (a GPU adapter or an error), off (CPU).
    #[arg(long, value_enum, default_value_t = GpuArg::Auto)]
    gpu: GpuArg,
    /// GPU memory budget of one batch of point levels, in MiB.
    #[arg(long, default_value_t = bake::DEFAULT_GPU_BUDGET_MIB)]
    gpu_budget_mib: u64,
    /// Stop the bake after this many seconds (between tiles; what is baked is kept and a re-run
    /// resumes it). Default: no limit.
    #[arg(long, value_name = "SECONDS", value_parser = parse_time_limit)]
    time_limit: Option<f64>,
    /// No progress bar.
    #[arg(long, short)]
    quiet: bool,
}

fn parse_time_limit(s: &str) -> Result<f64, String> {
    let v: f64 = s.parse().map_err(|_| format!("{s:?} is not a number of seconds"))?;
    if v.is_finite() && v > 0.0 && v <= 1e9 {
        Ok(v)
    } else {
        Err(format!("{s} must be > 0 and at most 1e9 seconds"))
    }
}

#[derive(clap::Args)]
struct BakeModelArgs {
    /// Model file: Wavefront .obj, .stl (binary or ASCII) or .ply (ASCII or binary).
    model: PathBuf,
    /// Output tileset directory (created; must be empty or an earlier bake of the same model).
    #[arg(long)]
    out: PathBuf,
    /// Point-cloud levels below the mesh.
    #[arg(long, default_value_t = bake_model::DEFAULT_MODEL_LEVELS)]
    levels: u8,
    /// Resolution T of level 1: grid cells across the model's longest side (the paper's
    /// framebuffer size T3); level l of K gets T·(K+1−l)/K.
    #[arg(long, default_value_t = bake_model::DEFAULT_RESOLUTION)]
    resolution: u32,
    /// Explicit resolutions, finest first, comma-separated (overrides --levels/--resolution).
    #[arg(long, value_delimiter = ',')]
    resolutions: Option<Vec<u32>>,
    /// Read the file as this format instead of going by its extension or content.
    #[arg(long = "format", value_enum)]
    file_type: Option<ModelFormatArg>,
    /// Worker threads (default: all cores).
    #[arg(long)]
    threads: Option<usize>,
    /// Where point levels are baked: auto (any GPU adapter, software ones included, else the
    /// CPU with a notice), on (a GPU adapter or an error), off (CPU).
    #[arg(long, value_enum, default_value_t = GpuArg::Auto)]
    gpu: GpuArg,
    /// GPU memory budget of one batch of point levels, in MiB.
    #[arg(long, default_value_t = bake::DEFAULT_GPU_BUDGET_MIB)]
    gpu_budget_mib: u64,
}

#[derive(Clone, Copy, ValueEnum)]
enum ModelFormatArg {
    Obj,
    Stl,
    Ply,
}

#[derive(Clone, Copy, ValueEnum)]
enum GpuArg {
    Auto,
    On,
    Off,
}

#[derive(Clone, Copy, ValueEnum)]
enum EncodingArg {
    Gray16,
    TerrainRgb,
    Terrarium,
}

#[derive(Clone, Copy, ValueEnum)]
enum ExportFormat {
    Ply,
    Obj,
}

fn parse_key(s: &str) -> Result<TileKey, String> {
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

fn parse_pair(s: &str) -> Result<(f64, f64), String> {
    let (a, b) = s.split_once(',').ok_or_else(|| format!("expected X,Y, got {s:?}"))?;
    let f = |v: &str| v.trim().parse::<f64>().map_err(|_| format!("{v:?} is not a number"));
    Ok((f(a)?, f(b)?))
}

fn main() -> std::process::ExitCode {
    quiet_mesa_device_select();
    let cli = Cli::parse();
    let json_logs = match &cli.command {
        #[cfg(feature = "server")]
        Command::Serve(a) => a.config().is_ok_and(|c| c.log_format == server::LogFormat::Json),
        _ => false,
    };
    let filter = tracing_subscriber::EnvFilter::try_new(&cli.log).unwrap_or_default();
    // Colour only on a terminal: a redirected log holds plain text.
    let ansi = std::io::IsTerminal::is_terminal(&std::io::stderr());
    if json_logs {
        tracing_subscriber::fmt().json().with_env_filter(filter).with_writer(std::io::stderr).init();
    } else {
        tracing_subscriber::fmt().with_ansi(ansi).with_env_filter(filter).with_writer(std::io::stderr).init();
    }
    match run(cli) {
        Ok(()) => std::process::ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {}", error_chain(&e));
            std::process::ExitCode::FAILURE
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
fn quiet_mesa_device_select() {
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
fn error_chain(e: &anyhow::Error) -> String {
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

fn run(cli: Cli) -> Result<()> {
    match cli.command {
        Command::Bake(args) => run_bake(&args),
        Command::BakeModel(args) => run_bake_model(&args),
        Command::Inspect { dir, json, tile } => run_inspect(&dir, json, tile),
        Command::Synth { out, width, height, cell_size, seed } => {
            let height = height.unwrap_or(width);
            if width < 2 || height < 2 || u64::from(width) * u64::from(height) > 1 << 30 {
                bail!("--width/--height must be 2 or more and at most 2^30 samples together");
            }
            if !(cell_size.is_finite() && cell_size > 0.0) {
                bail!("--cell-size must be a positive number");
            }
            let heights = terrastream::raster::synth::terrain(width, height, seed);
            let bytes =
                raster::geotiff::encode_f32(width, height, &heights, (0.0, 0.0), (cell_size, -cell_size))
                    .with_context(|| format!("{}: encoding GeoTIFF", out.display()))?;
            terrastream::store::write_atomic(&out, &bytes)?;
            outln!("wrote {} ({width}×{height} samples, {cell_size} m cells, seed {seed})", out.display());
            Ok(())
        }
        #[cfg(feature = "server")]
        Command::Serve(args) => {
            let config = args.config()?;
            server::serve_blocking(config, |addr, app| print_urls(addr, &app.tileset_names()))?;
            Ok(())
        }
        #[cfg(feature = "server")]
        Command::Demo { bind, dir, no_serve, gpu } => run_demo(&bind, &dir, no_serve, gpu),
        #[cfg(feature = "client")]
        Command::Client(a) => run_client(&a),
        #[cfg(all(feature = "client", feature = "gpu"))]
        Command::Eval(a) => run_eval(&a),
        Command::Export { dir, tile, level, format, out } => {
            let format = match format {
                ExportFormat::Ply => export::Format::Ply,
                ExportFormat::Obj => export::Format::Obj,
            };
            let n = export::export_tile(&Store::new(&dir), tile, level, format, &out)?;
            outln!("wrote {} ({n} {})", out.display(), if level == 0 { "vertices" } else { "points" });
            Ok(())
        }
    }
}

#[cfg(all(feature = "client", feature = "gpu"))]
fn run_eval(a: &EvalArgs) -> Result<()> {
    use client::evaluate::{self, EvalOptions};
    let opts = EvalOptions {
        width: a.width,
        height: a.height,
        fov_deg: a.fov,
        threshold_px: a.threshold,
        distances: a.distances.clone(),
        azimuths: a.azimuths,
        elevations: a.elevations.clone(),
        grid_sides: a.grid.clone(),
        max_grid: a.max_grid,
        frames: a.frames,
    };
    let quiet = a.quiet;
    let (report, samples) = evaluate::run(&a.dir, &opts, |line| {
        if !quiet {
            eprintln!("{line}");
        }
    })?;
    let path = evaluate::write_report(&report, &samples, &a.out)?;
    eprintln!("report: {}", path.display());
    outln!("{}", report.text());
    Ok(())
}

#[cfg(feature = "client")]
fn run_client(a: &ClientArgs) -> Result<()> {
    use client::live::{ClientRun, ReplayOptions, SessionOptions};
    let defaults = SessionOptions::default();
    let run = ClientRun {
        url: a.url.clone(),
        tileset: a.tileset.clone(),
        flight: a.flight.clone(),
        out: a.out.clone(),
        session: SessionOptions {
            width: a.width,
            height: a.height,
            fov_deg: a.fov,
            select: client::select::SelectParams {
                threshold_px: a.threshold,
                fade_seconds: a.fade,
                ..defaults.select
            },
            fetch: client::fetch::FetchParams { max_in_flight: a.max_in_flight, ..defaults.fetch },
            cache_bytes: a.cache_mb.saturating_mul(1 << 20),
        },
        replay: ReplayOptions { fps: a.fps, settle_s: a.settle, speed: 1.0 },
        render: match a.render {
            GpuArg::Auto => client::live::RenderMode::Auto,
            GpuArg::On => client::live::RenderMode::On,
            GpuArg::Off => client::live::RenderMode::Off,
        },
        frames_every: a.frames_every,
    };
    let report = client::live::run_client(&run, |f| {
        if f.frame % 30 == 0 {
            eprintln!(
                "frame {:>5} t {:>6.2}s {:<6} drawn {:?} in flight {:>2} select {:.3} ms frame {:.1} ms",
                f.frame, f.t, f.phase, f.drawn_per_level, f.requests_in_flight, f.select_ms, f.frame_ms
            );
        }
    })?;
    let t = &report.totals;
    outln!(
        "{} frames ({} in flight), {} bytes in {} requests ({} retries, {} failed), latency p50 {:.1} ms p99 {:.1} ms",
        t.frames,
        t.flight_frames,
        t.bytes,
        t.requests,
        t.retries,
        t.failed,
        t.latency_p50_ms,
        t.latency_p99_ms
    );
    outln!(
        "first complete view {}, frames under {} px: {:.1} %, settled: {}, selection mean {:.3} ms max {:.3} ms",
        t.first_complete_s.map_or_else(|| "never".to_owned(), |s| format!("at {s:.2} s")),
        report.threshold_px,
        100.0 * t.share_under_threshold,
        t.settled,
        t.select_ms_mean,
        t.select_ms_max
    );
    outln!(
        "rendering: {}{}",
        report.rendering,
        if t.render_ms_mean > 0.0 {
            format!(" — render mean {:.2} ms max {:.2} ms per frame", t.render_ms_mean, t.render_ms_max)
        } else {
            String::new()
        }
    );
    let frames = a.out.join(client::live::FRAMES_DIR);
    if frames.is_dir() {
        outln!("wrote frames to {}", frames.display());
    }
    outln!("wrote {}", a.out.join(client::live::STATS_FILE).display());
    Ok(())
}

#[cfg(feature = "server")]
fn print_urls(addr: std::net::SocketAddr, names: &[String]) {
    outln!("serving {} tileset(s) on http://{addr}  (Ctrl-C to stop)", names.len());
    outln!("  http://{addr}/tilesets");
    for n in names.iter().take(3) {
        outln!("  http://{addr}/tilesets/{n}/tileset.json");
        outln!("  http://{addr}/tilesets/{n}/index/0/0/0.json");
        outln!("  http://{addr}/tilesets/{n}/tiles/0/0/0/0");
    }
    outln!("  http://{addr}/openapi.json   http://{addr}/metrics   http://{addr}/readyz");
}

#[cfg(feature = "server")]
fn run_demo(bind: &str, dir: &std::path::Path, no_serve: bool, gpu: GpuArg) -> Result<()> {
    let bar = ProgressBar::new(0);
    bar.set_style(
        ProgressStyle::with_template("baking demo terrain {bar:40} {pos}/{len} tiles  ETA {eta}")
            .unwrap_or_else(|_| ProgressStyle::default_bar()),
    );
    let progress = Bar(bar, None);
    let t0 = Instant::now();
    let (baker, notice) = bake::PointBaker::open(gpu_mode(gpu), bake::DEFAULT_GPU_BUDGET_MIB << 20)?;
    if let Some(n) = notice {
        progress.0.println(n);
    }
    let (store, baked) = server::demo::prepare(dir, &baker, &progress)?;
    progress.0.finish_and_clear();
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
    let config =
        server::PartialConfig { store: Some(store), bind: Some(bind.to_owned()), ..Default::default() }
            .resolve()?;
    server::serve_blocking(config, |addr, app| {
        print_urls(addr, &app.tileset_names());
        outln!("try:  curl -sI http://{addr}/tilesets/demo/tiles/1/0/1/0");
    })?;
    Ok(())
}

fn gpu_mode(a: GpuArg) -> bake::GpuMode {
    match a {
        GpuArg::Auto => bake::GpuMode::Auto,
        GpuArg::On => bake::GpuMode::On,
        GpuArg::Off => bake::GpuMode::Off,
    }
}

struct Bar(ProgressBar, Option<(Instant, Duration)>);

impl bake::Progress for Bar {
    fn start(&self, total: u64, resumed: u64) {
        self.0.set_length(total);
        self.0.set_position(resumed);
        self.0.reset_eta();
        if resumed > 0 {
            self.0.println(format!("resuming: {resumed} of {total} tiles already baked"));
        }
    }
    fn node_done(&self) {
        self.0.inc(1);
    }
    fn cancelled(&self) -> Option<String> {
        let (t0, limit) = self.1?;
        (t0.elapsed() > limit).then(|| {
            format!(
                "--time-limit of {} s passed; the tiles baked so far are kept, run again to resume",
                limit.as_secs_f64()
            )
        })
    }
}

fn run_bake(a: &BakeArgs) -> Result<()> {
    if let Some(n) = a.threads {
        rayon::ThreadPoolBuilder::new().num_threads(n).build_global().context("--threads")?;
    }
    let opts = BakeOptions { tile_size: a.tile_size, max_error: a.max_error, levels: a.levels };
    bake::check_options(&opts)?;
    let load = LoadOptions {
        encoding: a.encoding.map(|e| match e {
            EncodingArg::Gray16 => Encoding::Gray16,
            EncodingArg::TerrainRgb => Encoding::TerrainRgb,
            EncodingArg::Terrarium => Encoding::Terrarium,
        }),
        channel: a.channel.clone(),
        limits: Limits { max_side: a.max_side, max_bytes: a.max_bytes },
        overrides: Overrides {
            cell_size: a.cell_size,
            origin: a.origin,
            z_scale: a.z_scale,
            z_offset: a.z_offset,
        },
    };
    let raster = raster::load(&a.input, &load)?;
    let name =
        a.input.file_name().map_or_else(|| a.input.display().to_string(), |n| n.to_string_lossy().into());
    if !a.quiet {
        eprintln!(
            "{name}: {}×{} {} samples, cell {:.3} × {:.3}, {} no-data filled",
            raster.heights.width,
            raster.heights.height,
            raster.format,
            raster.georef.dx.abs(),
            raster.georef.dy.abs(),
            raster.nodata_filled
        );
    }
    let bar = if a.quiet { ProgressBar::hidden() } else { ProgressBar::new(0) };
    bar.set_style(
        ProgressStyle::with_template("{bar:40} {pos}/{len} tiles  {per_sec}  ETA {eta}  {elapsed}")
            .unwrap_or_else(|_| ProgressStyle::default_bar()),
    );
    bar.enable_steady_tick(Duration::from_millis(200));
    let progress = Bar(bar, a.time_limit.map(|s| (Instant::now(), Duration::from_secs_f64(s))));
    let (baker, notice) = bake::PointBaker::open(gpu_mode(a.gpu), a.gpu_budget_mib.saturating_mul(1 << 20))?;
    if let Some(n) = notice {
        eprintln!("{n}");
    }
    let summary = bake::bake_with(&raster, &name, &opts, &baker, &Store::new(&a.out), &progress);
    let summary = summary.inspect_err(|_| progress.0.finish_and_clear())?;
    progress.0.finish_and_clear();
    print_summary(&summary, &a.out);
    Ok(())
}

fn run_bake_model(a: &BakeModelArgs) -> Result<()> {
    if let Some(n) = a.threads {
        rayon::ThreadPoolBuilder::new().num_threads(n).build_global().context("--threads")?;
    }
    let resolutions = match &a.resolutions {
        Some(r) => r.clone(),
        None => bake_model::ladder(a.resolution, a.levels)?,
    };
    let opts = ModelBakeOptions {
        resolutions,
        file_type: a.file_type.map(|t| match t {
            ModelFormatArg::Obj => FileType::Obj,
            ModelFormatArg::Stl => FileType::Stl,
            ModelFormatArg::Ply => FileType::Ply,
        }),
    };
    // Options and the file are checked before a GPU is opened, so a bad input is refused
    // quickly and with nothing but its own error on stderr.
    bake_model::check_options(&opts)?;
    let file = bake_model::read_model_file(&a.model, opts.file_type)?;
    let (baker, notice) = bake::PointBaker::open(gpu_mode(a.gpu), a.gpu_budget_mib.saturating_mul(1 << 20))?;
    if let Some(n) = notice {
        eprintln!("{n}");
    }
    let s = bake_model::bake_read_model(&file, &opts, &baker, &Store::new(&a.out))?;
    let st = &s.stats;
    outln!(
        "{} ({}): {} faces → {} triangles read, {} degenerate skipped; {} vertices read, {} unreferenced \
         dropped, {} normals from the file",
        s.file,
        s.encoding,
        st.faces,
        st.triangles_read,
        st.degenerate,
        st.vertices_read,
        st.unreferenced,
        st.normals_from_file
    );
    outln!(
        "baked {} levels into {}{} in {:.3} s (read {:.3} s, bake {:.3} s); bounds {:?} – {:?}",
        s.levels.len(),
        a.out.display(),
        if s.resumed { " (same options: rewritten)" } else { "" },
        s.seconds,
        s.read_seconds,
        s.bake_seconds,
        s.bounds.min,
        s.bounds.max
    );
    outln!("point levels baked by {}", s.point_baker);
    print_model_levels(&s.levels);
    Ok(())
}

fn print_model_levels(levels: &[ModelLevel]) {
    outln!(
        "{:>5}  {:>6}  {:>5}  {:>10}  {:>9}  {:>9}  {:>9}  {:>10}  {:>10}  {:>10}",
        "level",
        "kind",
        "T",
        "cell",
        "count",
        "triangles",
        "bytes",
        "max err",
        "rms",
        "gap"
    );
    for l in levels {
        outln!(
            "{:>5}  {:>6}  {:>5}  {:>10}  {:>9}  {:>9}  {:>9}  {:>10.3e}  {:>10.3e}  {:>10.3e}",
            l.level,
            l.kind,
            l.resolution.map_or_else(|| "-".to_owned(), |t| t.to_string()),
            l.cell.map_or_else(|| "-".to_owned(), |c| format!("{c:.3e}")),
            l.count,
            l.triangles,
            l.bytes,
            l.errors.max,
            l.errors.rms,
            l.errors.gap
        );
    }
}

fn print_summary(s: &BakeSummary, out: &std::path::Path) {
    outln!(
        "baked {} tiles ({} resumed) into {} in {:.2} s: {:.2} M samples/s, {} no-data samples filled",
        s.nodes,
        s.nodes_resumed,
        out.display(),
        s.seconds,
        s.samples_per_second() / 1e6,
        s.nodata_filled
    );
    if let Some(mib) = peak_rss_mib() {
        outln!("peak memory (RSS): {mib:.0} MiB");
    }
    outln!("point levels baked by {}", s.point_baker);
    if s.gpu_batches > 0 {
        outln!(
            "gpu: {} batches, peak {:.1} MiB per batch (budget {:.0} MiB), {} levels left to the cpu",
            s.gpu_batches,
            s.gpu_peak_batch_bytes as f64 / f64::from(1 << 20),
            s.gpu_budget_bytes as f64 / f64::from(1 << 20),
            s.gpu_cpu_fallback_levels
        );
    }
    print_levels(&s.totals);
}

/// The process's peak resident memory, where the OS reports it (Linux).
fn peak_rss_mib() -> Option<f64> {
    let status = std::fs::read_to_string("/proc/self/status").ok()?;
    let line = status.lines().find(|l| l.starts_with("VmHWM:"))?;
    let kib: f64 = line.split_whitespace().nth(1)?.parse().ok()?;
    Some(kib / 1024.0)
}

fn print_levels(totals: &[LevelTotals]) {
    outln!(
        "{:>5}  {:>6}  {:>7}  {:>11}  {:>10}  {:>12}  {:>7}  {:>10}  {:>10}  {:>10}",
        "level",
        "kind",
        "tiles",
        "vertices/pts",
        "triangles",
        "bytes",
        "B/item",
        "max err",
        "worst rms",
        "worst gap"
    );
    for (l, t) in totals.iter().enumerate() {
        outln!(
            "{:>5}  {:>6}  {:>7}  {:>11}  {:>10}  {:>12}  {:>7.2}  {:>10.3}  {:>10.3}  {:>10.3}",
            l,
            if l == 0 { "mesh" } else { "points" },
            t.tiles,
            t.count,
            t.triangles,
            t.bytes,
            t.bytes as f64 / t.count.max(1) as f64,
            t.worst.max,
            t.worst.rms,
            t.worst.gap
        );
    }
}

fn run_inspect(dir: &std::path::Path, json: bool, tile: Option<TileKey>) -> Result<()> {
    let store = Store::new(dir);
    let manifest = store.manifest()?;
    if tile.is_none() && store.manifest_kind()? == terrastream::store::KIND_MODEL {
        let m = bake_model::read_manifest(&store)?;
        if json {
            outln!("{}", serde_json::to_string_pretty(&m)?);
            return Ok(());
        }
        outln!(
            "{}: model {} ({}, {} vertices, {} triangles; {} degenerate skipped), bounds {:?} – {:?}, \
             content version {}",
            dir.display(),
            m.model.file,
            m.model.encoding,
            m.model.vertices,
            m.model.triangles,
            m.model.degenerate_skipped,
            m.tileset.bounds.min,
            m.tileset.bounds.max,
            m.tileset.content_version
        );
        print_model_levels(&m.model.levels);
        return Ok(());
    }
    if let Some(key) = tile {
        let Some(node) = store.node(key)? else {
            bail!("{}: no tile {key} in this tileset (depth {})", dir.display(), manifest.depth);
        };
        if json {
            outln!("{}", serde_json::to_string_pretty(&node)?);
        } else {
            outln!("tile {key}: bounds {:?} – {:?}", node.bounds.min, node.bounds.max);
            let totals: Vec<LevelTotals> = node
                .levels
                .iter()
                .map(|l| {
                    let mut t = LevelTotals::default();
                    t.add(l);
                    t
                })
                .collect();
            print_levels(&totals);
        }
        return Ok(());
    }
    if json {
        outln!("{}", serde_json::to_string_pretty(&manifest)?);
    } else {
        outln!(
            "{}: {} ({}×{} samples, {}), tile size {}, depth {}, content version {}",
            dir.display(),
            manifest.source.file,
            manifest.source.width,
            manifest.source.height,
            manifest.source.format,
            manifest.tile_size,
            manifest.depth,
            manifest.content_version
        );
        print_levels(&manifest.totals);
    }
    Ok(())
}
