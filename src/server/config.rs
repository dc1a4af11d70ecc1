//! Server configuration: named defaults, a partial configuration that flags, environment
//! variables and an optional TOML file each fill, and their merge (flags and environment win
//! over the file, the file over the defaults).

use std::net::SocketAddr;
use std::path::{Path, PathBuf};
use std::time::Duration;

use serde::Deserialize;

use super::ServerError;
use crate::lod::{DEFAULT_GPU_BUDGET_MIB, GpuMode};

/// Address `serve` listens on.
pub const DEFAULT_BIND: &str = "127.0.0.1:8080";
/// Most TCP connections served at once; further connections wait in the kernel's backlog.
pub const DEFAULT_MAX_CONNECTIONS: usize = 4096;
/// Most requests handled at once; more are answered `503` with `Retry-After`.
pub const DEFAULT_MAX_IN_FLIGHT: usize = 2048;
/// Per-request time limit in seconds (including an on-demand bake the request waits for).
pub const DEFAULT_REQUEST_TIMEOUT_S: u64 = 30;
/// Largest raster upload accepted by the admin API, in bytes.
pub const DEFAULT_MAX_BODY_BYTES: u64 = 512 << 20;
/// Worker threads baking tiles on demand.
pub const DEFAULT_BAKE_WORKERS: usize = 2;
/// Tile bakes that may wait for a worker; when full, requests get `503` with `Retry-After`.
pub const DEFAULT_BAKE_QUEUE: usize = 64;
/// Bytes of verified blobs kept in memory.
pub const DEFAULT_CACHE_BYTES: u64 = 256 << 20;
/// How often the store directory is re-scanned for added, changed and removed tilesets (ms).
pub const DEFAULT_POLL_MS: u64 = 2000;
/// Per-client-address request rate (requests per second, bursts of twice that); 0 = no limit.
pub const DEFAULT_RATE_LIMIT: u32 = 0;
/// How long in-flight requests may take to finish after SIGTERM/Ctrl-C (seconds).
pub const DEFAULT_SHUTDOWN_TIMEOUT_S: u64 = 10;
/// Most connections open from one client IP address (0 = no limit). A browser opens about six
/// per origin, so this leaves room for dozens of users behind one NAT, while one client can hold
/// only a sixteenth of the default `--max-connections`. Behind a reverse proxy or CDN every
/// client shares the proxy's address: raise it there, or set 0.
pub const DEFAULT_MAX_CONNECTIONS_PER_CLIENT: usize = 256;
/// Seconds a client has to send a whole request head from its first byte (slowloris defence).
/// A real client sends its head in one packet; 10 s covers very slow links.
pub const DEFAULT_HEADER_TIMEOUT_S: u64 = 10;
/// Seconds a connection may sit with no request in flight and no bytes moving before it is
/// closed (keep-alive idle timeout; also a connection that never sends a request). Long enough
/// that a viewer panning with pauses keeps its connections.
pub const DEFAULT_IDLE_TIMEOUT_S: u64 = 60;
/// Longest an admin bake job may run (seconds) before it is stopped and marked failed.
pub const DEFAULT_JOB_TIMEOUT_S: u64 = 4 * 3600;
/// How long finished, failed and cancelled admin jobs stay visible at `/jobs/{id}` (seconds).
pub const DEFAULT_JOB_TTL_S: u64 = 3600;

/// Most bytes `--config` reads: a config file is a few lines of TOML (sources included), so
/// 1 MiB is generous, and a wrong path (`/dev/zero`, a huge file) is refused at it.
pub const MAX_CONFIG_BYTES: u64 = 1 << 20;

/// How log lines are written.
#[cfg_attr(feature = "cli", derive(clap::ValueEnum))]
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum LogFormat {
    #[default]
    Human,
    Json,
}

/// Whether serving threads are pinned to CPUs (`--cpu-affinity`).
#[cfg_attr(feature = "cli", derive(clap::ValueEnum))]
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum CpuAffinity {
    /// On Linux, when there is one serving thread for each CPU the process may run on: thread
    /// `i` runs on the `i`-th of those CPUs only, and its listening socket takes the
    /// connections whose packets that CPU receives (`SO_INCOMING_CPU`). Otherwise as `off`.
    #[default]
    Auto,
    /// Threads go wherever the kernel's scheduler puts them; new connections are spread over
    /// the listening sockets by the kernel's hash.
    Off,
}

/// One on-demand source: tiles of tileset `name` missing from the store are baked from `raster`
/// with these options (the `bake` command's defaults where unset).
#[derive(Debug, Clone, PartialEq, Default, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SourceSpec {
    pub name: String,
    pub raster: PathBuf,
    /// PNG height encoding: gray16, terrain-rgb or terrarium.
    pub encoding: Option<String>,
    pub cell_size: Option<f64>,
    pub tile_size: Option<u32>,
    pub max_error: Option<f64>,
    pub levels: Option<u8>,
    /// Which point levels a node stores (`bake --point-levels`): auto, all or none.
    pub point_levels: Option<crate::bake::PointLevels>,
    /// Globe terrain (quantized-mesh): the error scale and deepest zoom of `bake --terrain`.
    pub terrain_error_scale: Option<f64>,
    pub terrain_max_zoom: Option<u8>,
    /// The raster's CRS instead of what it states (`bake --crs`): `EPSG:NNNN` or
    /// `EPSG:NNNN+VVVV` (5773 EGM96, 3855 EGM2008 heights).
    pub crs: Option<String>,
    /// What its heights are measured from (`bake --vertical-datum`): ellipsoid, egm96, egm2008.
    pub vertical_datum: Option<String>,
}

/// Why a `--source` value cannot be read; each names the value (`spec`) as given.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum SourceSpecError {
    #[error("expected NAME=RASTER, got {spec:?}")]
    NoName { spec: String },
    #[error("tileset name {name:?} must match [a-z0-9_-]{{1,64}}")]
    BadName { name: String },
    #[error("no raster path in {spec:?}")]
    NoRaster { spec: String },
    #[error("expected key=value, got {option:?} in {spec:?}")]
    NotKeyValue { option: String, spec: String },
    /// `what` is "number" or "integer".
    #[error("{key}={value:?} in {spec:?} is not a valid {what}")]
    BadValue { key: String, value: String, spec: String, what: &'static str },
    #[error(
        "unknown source option {key:?} in {spec:?} (encoding, cell_size, tile_size, max_error, levels, point_levels, terrain_error_scale, terrain_max_zoom, crs, vertical_datum)"
    )]
    UnknownOption { key: String, spec: String },
}

impl std::str::FromStr for SourceSpec {
    type Err = SourceSpecError;
    /// `NAME=RASTER[,key=value…]` with keys encoding, cell_size, tile_size, max_error, levels,
    /// point_levels, terrain_error_scale, terrain_max_zoom, crs, vertical_datum.
    fn from_str(s: &str) -> Result<Self, SourceSpecError> {
        let (name, rest) = s.split_once('=').ok_or_else(|| SourceSpecError::NoName { spec: s.to_owned() })?;
        if !super::valid_name(name) {
            return Err(SourceSpecError::BadName { name: name.to_owned() });
        }
        let mut parts = rest.split(',');
        let raster = parts.next().unwrap_or_default();
        if raster.is_empty() {
            return Err(SourceSpecError::NoRaster { spec: s.to_owned() });
        }
        let mut spec = Self { name: name.to_owned(), raster: PathBuf::from(raster), ..Self::default() };
        for kv in parts {
            let (k, v) = kv
                .split_once('=')
                .ok_or_else(|| SourceSpecError::NotKeyValue { option: kv.to_owned(), spec: s.to_owned() })?;
            let num = |what: &'static str| SourceSpecError::BadValue {
                key: k.to_owned(),
                value: v.to_owned(),
                spec: s.to_owned(),
                what,
            };
            match k {
                "encoding" => spec.encoding = Some(v.to_owned()),
                "cell_size" => spec.cell_size = Some(v.parse().map_err(|_| num("number"))?),
                "tile_size" => spec.tile_size = Some(v.parse().map_err(|_| num("integer"))?),
                "max_error" => spec.max_error = Some(v.parse().map_err(|_| num("number"))?),
                "levels" => spec.levels = Some(v.parse().map_err(|_| num("integer"))?),
                "point_levels" => {
                    spec.point_levels = Some(match v {
                        "auto" => crate::bake::PointLevels::Auto,
                        "all" => crate::bake::PointLevels::All,
                        "none" => crate::bake::PointLevels::None,
                        _ => return Err(num("point level rule (auto, all or none)")),
                    });
                }
                "terrain_error_scale" => {
                    let f: f64 = v.parse().map_err(|_| num("number"))?;
                    if !(f.is_finite() && f > 0.0 && f <= 1e6) {
                        return Err(num("number (> 0, at most 1e6)"));
                    }
                    spec.terrain_error_scale = Some(f);
                }
                "crs" => {
                    crate::crs::Crs::parse(v).map_err(|_| num("CRS (EPSG:NNNN or EPSG:NNNN+VVVV)"))?;
                    spec.crs = Some(v.to_owned());
                }
                "vertical_datum" => {
                    if !matches!(v, "ellipsoid" | "egm96" | "egm2008") {
                        return Err(num("vertical datum (ellipsoid, egm96 or egm2008)"));
                    }
                    spec.vertical_datum = Some(v.to_owned());
                }
                "terrain_max_zoom" => {
                    let z: u8 = v.parse().map_err(|_| num("integer"))?;
                    if z > crate::formats::qmesh::grid::MAX_ZOOM {
                        return Err(num("zoom (0 to 24)"));
                    }
                    spec.terrain_max_zoom = Some(z);
                }
                _ => return Err(SourceSpecError::UnknownOption { key: k.to_owned(), spec: s.to_owned() }),
            }
        }
        Ok(spec)
    }
}

/// Most serving threads (`--threads`): each holds a runtime and a listening socket.
pub const MAX_THREADS: usize = 256;

/// Every setting optional: what one layer (flags + environment, or the TOML file) sets.
/// With the `cli` feature this is also `serve`'s flags (each with its environment variable):
/// the command line and the TOML file fill the same struct.
#[derive(Debug, Clone, Default, Deserialize)]
#[cfg_attr(feature = "cli", derive(clap::Args))]
#[serde(deny_unknown_fields)]
pub struct PartialConfig {
    #[cfg_attr(
        feature = "cli",
        arg(
            long,
            env = "TERRASTREAM_STORE",
            help = "The store: a directory or s3://BUCKET/PREFIX; each folder NAME/ in it is a tileset, and so is each archive NAME.tsa (terrastream pack). A bucket is served read-only"
        )
    )]
    pub store: Option<PathBuf>,
    #[cfg_attr(feature = "cli", arg(long, env = "TERRASTREAM_BIND", help = format!("Address to listen on [default: {}]", DEFAULT_BIND)))]
    pub bind: Option<String>,
    #[serde(default)]
    #[cfg_attr(
        feature = "cli",
        arg(
            long = "source",
            value_name = "NAME=RASTER[,key=value…]",
            help = "Bake tiles of tileset NAME missing from the store from RASTER on first request; keys: encoding, cell_size, tile_size, max_error, levels, terrain_error_scale, terrain_max_zoom (repeatable)"
        )
    )]
    pub sources: Vec<SourceSpec>,
    #[cfg_attr(feature = "cli", arg(long, env = "TERRASTREAM_MAX_CONNECTIONS", help = format!("Most open connections [default: {}]", DEFAULT_MAX_CONNECTIONS)))]
    pub max_connections: Option<usize>,
    #[cfg_attr(feature = "cli", arg(long, env = "TERRASTREAM_MAX_IN_FLIGHT", help = format!("Most requests in progress; more get 503 + Retry-After [default: {}]", DEFAULT_MAX_IN_FLIGHT)))]
    pub max_in_flight: Option<usize>,
    #[cfg_attr(feature = "cli", arg(long = "request-timeout", env = "TERRASTREAM_REQUEST_TIMEOUT", value_name = "SECONDS", help = format!("Per-request time limit [default: {}]", DEFAULT_REQUEST_TIMEOUT_S)))]
    pub request_timeout_s: Option<u64>,
    #[cfg_attr(feature = "cli", arg(long, env = "TERRASTREAM_MAX_BODY_BYTES", help = format!("Largest admin upload [default: {}]", DEFAULT_MAX_BODY_BYTES)))]
    pub max_body_bytes: Option<u64>,
    #[cfg_attr(
        feature = "cli",
        arg(
            long,
            env = "TERRASTREAM_THREADS",
            help = "Threads serving connections, each with its own listening socket [default: the number of cores]"
        )
    )]
    pub threads: Option<usize>,
    #[cfg_attr(
        feature = "cli",
        arg(
            long,
            env = "TERRASTREAM_CPU_AFFINITY",
            value_enum,
            help = "Pin each serving thread to a CPU and steer connections to the thread on the CPU that receives them (auto: on Linux, when --threads equals the CPUs this process may use) [default: auto]"
        )
    )]
    pub cpu_affinity: Option<CpuAffinity>,
    #[cfg_attr(feature = "cli", arg(long, env = "TERRASTREAM_BAKE_WORKERS", help = format!("On-demand bake threads [default: {}]", DEFAULT_BAKE_WORKERS)))]
    pub bake_workers: Option<usize>,
    #[cfg_attr(feature = "cli", arg(long, env = "TERRASTREAM_BAKE_QUEUE", help = format!("On-demand bakes that may wait; more get 503 + Retry-After [default: {}]", DEFAULT_BAKE_QUEUE)))]
    pub bake_queue: Option<usize>,
    #[cfg_attr(feature = "cli", arg(long, env = "TERRASTREAM_CACHE_BYTES", help = format!("Memory for verified blobs [default: {}]", DEFAULT_CACHE_BYTES)))]
    pub cache_bytes: Option<u64>,
    #[cfg_attr(feature = "cli", arg(long, env = "TERRASTREAM_POLL_MS", help = format!("Store re-scan interval in ms [default: {}]", DEFAULT_POLL_MS)))]
    pub poll_ms: Option<u64>,
    #[cfg_attr(feature = "cli", arg(long, env = "TERRASTREAM_RATE_LIMIT", help = format!("Requests per second per client address, 0 = off [default: {}]", DEFAULT_RATE_LIMIT)))]
    pub rate_limit: Option<u32>,
    #[cfg_attr(feature = "cli", arg(long = "shutdown-timeout", env = "TERRASTREAM_SHUTDOWN_TIMEOUT", value_name = "SECONDS", help = format!("Time in-flight requests get after SIGTERM [default: {}]", DEFAULT_SHUTDOWN_TIMEOUT_S)))]
    pub shutdown_timeout_s: Option<u64>,
    #[cfg_attr(feature = "cli", arg(long, env = "TERRASTREAM_MAX_CONNECTIONS_PER_CLIENT", help = format!("Most open connections from one client IP; more get 503 and are closed; 0 = no limit [default: {}]", DEFAULT_MAX_CONNECTIONS_PER_CLIENT)))]
    pub max_connections_per_client: Option<usize>,
    #[cfg_attr(feature = "cli", arg(long = "header-timeout", env = "TERRASTREAM_HEADER_TIMEOUT", value_name = "SECONDS", help = format!("Time a client has to send a request head from its first byte [default: {}]", DEFAULT_HEADER_TIMEOUT_S)))]
    pub header_timeout_s: Option<u64>,
    #[cfg_attr(feature = "cli", arg(long = "idle-timeout", env = "TERRASTREAM_IDLE_TIMEOUT", value_name = "SECONDS", help = format!("A connection with no request in flight is closed after this long idle [default: {}]", DEFAULT_IDLE_TIMEOUT_S)))]
    pub idle_timeout_s: Option<u64>,
    #[cfg_attr(feature = "cli", arg(long = "job-timeout", env = "TERRASTREAM_JOB_TIMEOUT", value_name = "SECONDS", help = format!("Longest an admin bake job may run before it is stopped (failed) [default: {}]", DEFAULT_JOB_TIMEOUT_S)))]
    pub job_timeout_s: Option<u64>,
    #[cfg_attr(feature = "cli", arg(long = "job-ttl", env = "TERRASTREAM_JOB_TTL", value_name = "SECONDS", help = format!("How long ended admin jobs stay at /jobs/ID [default: {}]", DEFAULT_JOB_TTL_S)))]
    pub job_ttl_s: Option<u64>,
    #[cfg_attr(
        feature = "cli",
        arg(
            long,
            env = "TERRASTREAM_ADMIN_TOKEN",
            hide_env_values = true,
            help = "Bearer token of the admin API (disabled without)"
        )
    )]
    pub admin_token: Option<String>,
    #[cfg_attr(
        feature = "cli",
        arg(
            long,
            env = "TERRASTREAM_READ_TOKEN",
            hide_env_values = true,
            help = "Bearer token required for reading (public without)"
        )
    )]
    pub read_token: Option<String>,
    #[cfg_attr(
        feature = "cli",
        arg(long, env = "TERRASTREAM_LOG_FORMAT", value_enum, help = "Log format [default: human]")
    )]
    pub log_format: Option<LogFormat>,
    /// Where on-demand and admin bakes compute point levels: auto, on or off.
    #[cfg_attr(
        feature = "cli",
        arg(
            long,
            env = "TERRASTREAM_GPU",
            value_enum,
            help = "Where on-demand and admin bakes compute point levels: auto (a hardware adapter, else the CPU), on (any adapter), off [default: auto]"
        )
    )]
    pub gpu: Option<GpuMode>,
    /// GPU memory budget of one batch of point levels, MiB.
    #[cfg_attr(feature = "cli", arg(long, env = "TERRASTREAM_GPU_BUDGET_MIB", help = format!("GPU memory budget of one batch of point levels, MiB [default: {}]", DEFAULT_GPU_BUDGET_MIB)))]
    pub gpu_budget_mib: Option<u64>,
}

impl PartialConfig {
    /// Reads a TOML file with the same keys as the flags (snake_case).
    /// At most [`MAX_CONFIG_BYTES`] are read, whatever the file is: a pipe (`--config <(…)`)
    /// is read as a file is, and a device such as `/dev/zero` is refused past the limit.
    pub fn from_toml_file(path: &Path) -> Result<Self, ServerError> {
        use std::io::Read;
        let bad = |m: String| ServerError::Config(format!("{}: {m}", path.display()));
        let file = std::fs::File::open(path).map_err(|e| bad(e.to_string()))?;
        let mut text = String::new();
        file.take(MAX_CONFIG_BYTES + 1).read_to_string(&mut text).map_err(|e| bad(e.to_string()))?;
        if text.len() as u64 > MAX_CONFIG_BYTES {
            return Err(bad(format!(
                "more than {MAX_CONFIG_BYTES} bytes; a config file is a few lines of TOML (is it the right file?)"
            )));
        }
        toml::from_str(&text).map_err(|e| bad(e.to_string()))
    }

    /// `self` where set, else `lower`.
    #[must_use]
    pub fn over(self, lower: Self) -> Self {
        Self {
            store: self.store.or(lower.store),
            bind: self.bind.or(lower.bind),
            sources: if self.sources.is_empty() { lower.sources } else { self.sources },
            max_connections: self.max_connections.or(lower.max_connections),
            max_in_flight: self.max_in_flight.or(lower.max_in_flight),
            request_timeout_s: self.request_timeout_s.or(lower.request_timeout_s),
            max_body_bytes: self.max_body_bytes.or(lower.max_body_bytes),
            threads: self.threads.or(lower.threads),
            cpu_affinity: self.cpu_affinity.or(lower.cpu_affinity),
            bake_workers: self.bake_workers.or(lower.bake_workers),
            bake_queue: self.bake_queue.or(lower.bake_queue),
            cache_bytes: self.cache_bytes.or(lower.cache_bytes),
            poll_ms: self.poll_ms.or(lower.poll_ms),
            rate_limit: self.rate_limit.or(lower.rate_limit),
            shutdown_timeout_s: self.shutdown_timeout_s.or(lower.shutdown_timeout_s),
            max_connections_per_client: self.max_connections_per_client.or(lower.max_connections_per_client),
            header_timeout_s: self.header_timeout_s.or(lower.header_timeout_s),
            idle_timeout_s: self.idle_timeout_s.or(lower.idle_timeout_s),
            job_timeout_s: self.job_timeout_s.or(lower.job_timeout_s),
            job_ttl_s: self.job_ttl_s.or(lower.job_ttl_s),
            admin_token: self.admin_token.or(lower.admin_token),
            read_token: self.read_token.or(lower.read_token),
            log_format: self.log_format.or(lower.log_format),
            gpu: self.gpu.or(lower.gpu),
            gpu_budget_mib: self.gpu_budget_mib.or(lower.gpu_budget_mib),
        }
    }

    /// Fills the defaults and checks every value.
    pub fn resolve(self) -> Result<Config, ServerError> {
        let bad = |m: String| Err(ServerError::Config(m));
        let Some(store) = self.store else {
            return bad("no store directory: pass --store DIR (or TERRASTREAM_STORE, or store = … in the config file)".into());
        };
        let bind_s = self.bind.unwrap_or_else(|| DEFAULT_BIND.to_owned());
        let Ok(bind) = bind_s.parse::<SocketAddr>() else {
            return bad(format!("--bind {bind_s:?} is not an address like 127.0.0.1:8080"));
        };
        let positive = |v: Option<usize>, d: usize, flag: &str| -> Result<usize, ServerError> {
            match v.unwrap_or(d) {
                0 => Err(ServerError::Config(format!("{flag} must be at least 1"))),
                n => Ok(n),
            }
        };
        // `--source` flags are checked when parsed; a config file's sources only here. The name
        // becomes a directory under the store, so nothing else may pass (`../x` would bake
        // outside it).
        if let Some(s) = self.sources.iter().find(|s| !super::valid_name(&s.name)) {
            return bad(format!("source name {:?} must match [a-z0-9_-]{{1,64}}", s.name));
        }
        let mut names: Vec<&str> = self.sources.iter().map(|s| s.name.as_str()).collect();
        names.sort_unstable();
        if let Some([w, ..]) = names.windows(2).find(|w| w[0] == w[1]) {
            return bad(format!("--source {w} is given twice"));
        }
        for t in [&self.admin_token, &self.read_token].into_iter().flatten() {
            if t.len() < 8 || !t.bytes().all(|b| b.is_ascii_graphic()) {
                return bad("tokens must be at least 8 printable ASCII characters".into());
            }
        }
        let request_timeout_s = self.request_timeout_s.unwrap_or(DEFAULT_REQUEST_TIMEOUT_S);
        if request_timeout_s == 0 {
            return bad("--request-timeout must be at least 1 second".into());
        }
        let seconds = |v: Option<u64>, d: u64, flag: &str| -> Result<Duration, ServerError> {
            match v.unwrap_or(d) {
                0 => Err(ServerError::Config(format!("{flag} must be at least 1 second"))),
                n => Ok(Duration::from_secs(n)),
            }
        };
        Ok(Config {
            store,
            bind,
            sources: self.sources,
            max_connections: positive(self.max_connections, DEFAULT_MAX_CONNECTIONS, "--max-connections")?,
            max_in_flight: positive(self.max_in_flight, DEFAULT_MAX_IN_FLIGHT, "--max-in-flight")?,
            request_timeout: Duration::from_secs(request_timeout_s),
            max_body_bytes: self.max_body_bytes.unwrap_or(DEFAULT_MAX_BODY_BYTES),
            threads: match positive(
                self.threads,
                std::thread::available_parallelism().map_or(1, std::num::NonZeroUsize::get).min(MAX_THREADS),
                "--threads",
            )? {
                n if n > MAX_THREADS => return bad(format!("--threads {n}: at most {MAX_THREADS}")),
                n => n,
            },
            cpu_affinity: self.cpu_affinity.unwrap_or_default(),
            bake_workers: positive(self.bake_workers, DEFAULT_BAKE_WORKERS, "--bake-workers")?,
            bake_queue: self.bake_queue.unwrap_or(DEFAULT_BAKE_QUEUE),
            cache_bytes: self.cache_bytes.unwrap_or(DEFAULT_CACHE_BYTES),
            poll: Duration::from_millis(self.poll_ms.unwrap_or(DEFAULT_POLL_MS).max(50)),
            rate_limit: self.rate_limit.unwrap_or(DEFAULT_RATE_LIMIT),
            shutdown_timeout: Duration::from_secs(
                self.shutdown_timeout_s.unwrap_or(DEFAULT_SHUTDOWN_TIMEOUT_S),
            ),
            max_connections_per_client: self
                .max_connections_per_client
                .unwrap_or(DEFAULT_MAX_CONNECTIONS_PER_CLIENT),
            header_timeout: seconds(self.header_timeout_s, DEFAULT_HEADER_TIMEOUT_S, "--header-timeout")?,
            idle_timeout: seconds(self.idle_timeout_s, DEFAULT_IDLE_TIMEOUT_S, "--idle-timeout")?,
            job_timeout: seconds(self.job_timeout_s, DEFAULT_JOB_TIMEOUT_S, "--job-timeout")?,
            job_ttl: seconds(self.job_ttl_s, DEFAULT_JOB_TTL_S, "--job-ttl")?,
            admin_token: self.admin_token,
            read_token: self.read_token,
            log_format: self.log_format.unwrap_or_default(),
            gpu: self.gpu.unwrap_or_default(),
            gpu_budget_mib: match self.gpu_budget_mib.unwrap_or(DEFAULT_GPU_BUDGET_MIB) {
                0 => return bad("--gpu-budget-mib must be at least 1".into()),
                n => n,
            },
        })
    }
}

/// A complete, checked configuration.
#[derive(Debug, Clone)]
pub struct Config {
    pub store: PathBuf,
    pub bind: SocketAddr,
    pub sources: Vec<SourceSpec>,
    pub max_connections: usize,
    pub max_in_flight: usize,
    pub request_timeout: Duration,
    pub max_body_bytes: u64,
    /// Threads serving connections (one runtime and one listening socket each).
    pub threads: usize,
    pub cpu_affinity: CpuAffinity,
    pub bake_workers: usize,
    pub bake_queue: usize,
    pub cache_bytes: u64,
    pub poll: Duration,
    pub rate_limit: u32,
    pub shutdown_timeout: Duration,
    /// 0 = no per-client limit.
    pub max_connections_per_client: usize,
    pub header_timeout: Duration,
    pub idle_timeout: Duration,
    pub job_timeout: Duration,
    pub job_ttl: Duration,
    pub admin_token: Option<String>,
    pub read_token: Option<String>,
    pub log_format: LogFormat,
    pub gpu: GpuMode,
    pub gpu_budget_mib: u64,
}

impl Config {
    /// Defaults for a store directory (tests and the demo).
    pub fn for_store(store: &Path) -> Result<Self, ServerError> {
        PartialConfig { store: Some(store.to_owned()), ..PartialConfig::default() }.resolve()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn flags_win_over_file_and_defaults_fill() {
        let file: PartialConfig = toml::from_str(
            "store = \"/srv\"\nbind = \"0.0.0.0:9000\"\nbake_workers = 3\nlog_format = \"json\"",
        )
        .unwrap();
        let flags = PartialConfig { bind: Some("127.0.0.1:1".into()), ..PartialConfig::default() };
        let c = flags.over(file).resolve().unwrap();
        assert_eq!(c.bind, "127.0.0.1:1".parse().unwrap());
        assert_eq!(c.store, PathBuf::from("/srv"));
        assert_eq!(c.bake_workers, 3);
        assert_eq!(c.log_format, LogFormat::Json);
        assert_eq!(c.bake_queue, DEFAULT_BAKE_QUEUE);
        assert_eq!(c.gpu, GpuMode::Auto);
        let g: PartialConfig = toml::from_str("gpu = \"off\"\ngpu_budget_mib = 64").unwrap();
        assert_eq!((g.gpu, g.gpu_budget_mib), (Some(GpuMode::Off), Some(64)));
        assert!(toml::from_str::<PartialConfig>("gpu = \"maybe\"").is_err());
        assert!(toml::from_str::<PartialConfig>("nope = 1").is_err());
        assert_eq!(c.max_connections_per_client, DEFAULT_MAX_CONNECTIONS_PER_CLIENT);
        assert_eq!(c.header_timeout, Duration::from_secs(DEFAULT_HEADER_TIMEOUT_S));
        let t: PartialConfig = toml::from_str(
            "store = \"/s\"\nheader_timeout_s = 2\nidle_timeout_s = 3\nmax_connections_per_client = 0\njob_timeout_s = 5\njob_ttl_s = 6",
        )
        .unwrap();
        let c = t.resolve().unwrap();
        assert_eq!(
            (c.header_timeout, c.idle_timeout, c.max_connections_per_client, c.job_timeout, c.job_ttl),
            (
                Duration::from_secs(2),
                Duration::from_secs(3),
                0,
                Duration::from_secs(5),
                Duration::from_secs(6)
            )
        );
        let e =
            PartialConfig { store: Some("s".into()), idle_timeout_s: Some(0), ..PartialConfig::default() }
                .resolve()
                .unwrap_err()
                .to_string();
        assert!(e.contains("--idle-timeout"), "{e}");
    }

    #[test]
    fn source_spec_errors_say_what_is_wrong() {
        let e = |s: &str| s.parse::<SourceSpec>().unwrap_err().to_string();
        assert_eq!(e("x"), r#"expected NAME=RASTER, got "x""#);
        assert_eq!(e("Bad=x"), r#"tileset name "Bad" must match [a-z0-9_-]{1,64}"#);
        assert_eq!(e("a="), r#"no raster path in "a=""#);
        assert_eq!(e("a=/r,foo"), r#"expected key=value, got "foo" in "a=/r,foo""#);
        assert_eq!(e("a=/r,levels=x"), r#"levels="x" in "a=/r,levels=x" is not a valid integer"#);
        assert_eq!(e("a=/r,cell_size=x"), r#"cell_size="x" in "a=/r,cell_size=x" is not a valid number"#);
        assert_eq!(
            e("a=/r,colour=red"),
            r#"unknown source option "colour" in "a=/r,colour=red" (encoding, cell_size, tile_size, max_error, levels, point_levels, terrain_error_scale, terrain_max_zoom, crs, vertical_datum)"#
        );
        assert_eq!(
            e("a=/r,point_levels=some"),
            r#"point_levels="some" in "a=/r,point_levels=some" is not a valid point level rule (auto, all or none)"#
        );
        assert_eq!(
            e("a=/r,vertical_datum=msl"),
            r#"vertical_datum="msl" in "a=/r,vertical_datum=msl" is not a valid vertical datum (ellipsoid, egm96 or egm2008)"#
        );
        assert!(e("a=/r,crs=EPSG:99999999").contains("is not a valid CRS"));
        let ok: SourceSpec = "a=/r,crs=EPSG:4326+5773,vertical_datum=egm96".parse().unwrap();
        assert_eq!(
            (ok.crs.as_deref(), ok.vertical_datum.as_deref()),
            (Some("EPSG:4326+5773"), Some("egm96"))
        );
        assert_eq!(
            e("a=/r,terrain_error_scale=0"),
            r#"terrain_error_scale="0" in "a=/r,terrain_error_scale=0" is not a valid number (> 0, at most 1e6)"#
        );
        assert_eq!(
            e("a=/r,terrain_max_zoom=25"),
            r#"terrain_max_zoom="25" in "a=/r,terrain_max_zoom=25" is not a valid zoom (0 to 24)"#
        );
        let s: SourceSpec = "t=/t.tif,terrain_error_scale=0.5,terrain_max_zoom=12".parse().unwrap();
        assert_eq!((s.terrain_error_scale, s.terrain_max_zoom), (Some(0.5), Some(12)));
    }

    #[test]
    fn bad_values_are_named() {
        let e = PartialConfig { store: Some("s".into()), bind: Some("x".into()), ..PartialConfig::default() }
            .resolve()
            .unwrap_err()
            .to_string();
        assert!(e.contains("--bind"), "{e}");
        let e = PartialConfig { store: Some("s".into()), bake_workers: Some(0), ..PartialConfig::default() }
            .resolve()
            .unwrap_err()
            .to_string();
        assert!(e.contains("--bake-workers"), "{e}");
        assert!("Bad=x".parse::<SourceSpec>().is_err());
        assert_eq!("a-1=/x.tif".parse::<SourceSpec>().unwrap().raster, PathBuf::from("/x.tif"));
        let s: SourceSpec = "f=/f.png,encoding=terrain-rgb,cell_size=30,levels=2".parse().unwrap();
        assert_eq!(
            (s.encoding.as_deref(), s.cell_size, s.levels),
            (Some("terrain-rgb"), Some(30.0), Some(2))
        );
        assert!("f=/f.png,colour=red".parse::<SourceSpec>().is_err());
    }

    /// Found by the `config_toml` fuzz target: a config file's source names were not checked,
    /// so `name = "../x"` would have baked outside the store.
    #[test]
    fn file_source_names_are_checked() {
        for name in ["../up", "", "A", "a/b", "."] {
            let text = format!("store = \"s\"\n[[sources]]\nname = {name:?}\nraster = \"r.tif\"\n");
            let e = toml::from_str::<PartialConfig>(&text).unwrap().resolve().unwrap_err().to_string();
            assert!(e.contains("source name"), "{name:?}: {e}");
        }
        let ok = "store = \"s\"\n[[sources]]\nname = \"fuji_1-a\"\nraster = \"r.tif\"\n";
        assert_eq!(
            toml::from_str::<PartialConfig>(ok).unwrap().resolve().unwrap().sources[0].name,
            "fuji_1-a"
        );
    }
}
