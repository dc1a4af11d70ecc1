//! The HTTP server (axum on tokio): serves a store directory of tilesets — manifests, index
//! chunks and blobs with strong ETags, conditional and range requests, content-versioned
//! immutable caching, CORS — bakes missing tiles on demand from `--source` rasters, sheds load
//! with `429`/`503` + `Retry-After`, exposes health, readiness, Prometheus metrics and an
//! OpenAPI document, and an admin API (bearer token) to upload rasters, follow bake jobs and
//! delete tilesets. See `docs/http-api.md` for the API and its caching semantics.
//!
//! Every error is `application/problem+json`; a client mistake is a 4xx, never a 500, and no
//! path or header makes a handler panic (the router is property-tested with random paths).

mod admin;
mod affinity;
mod auth;
mod bakery;
mod cache;
mod conditional;
mod config;
pub mod demo;
mod fast;
mod heightmap;
pub(crate) mod heights;
mod http;
mod listener;
mod loaders;
mod metrics;
mod native;
mod openapi;
mod problem;
mod rate_limit;
mod registry;
mod terrain;
mod tiles3d;

use std::collections::HashMap;
use std::future::Future;
use std::net::SocketAddr;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};

pub use bakery::{BakeFailure, FAILED_BAKE_RETRY_S};
pub use config::{
    Config, DEFAULT_BAKE_QUEUE, DEFAULT_BAKE_WORKERS, DEFAULT_BIND, DEFAULT_CACHE_BYTES,
    DEFAULT_HEADER_TIMEOUT_S, DEFAULT_IDLE_TIMEOUT_S, DEFAULT_JOB_TIMEOUT_S, DEFAULT_JOB_TTL_S,
    DEFAULT_MAX_BODY_BYTES, DEFAULT_MAX_CONNECTIONS, DEFAULT_MAX_CONNECTIONS_PER_CLIENT,
    DEFAULT_MAX_IN_FLIGHT, DEFAULT_POLL_MS, DEFAULT_RATE_LIMIT, DEFAULT_REQUEST_TIMEOUT_S,
    DEFAULT_SHUTDOWN_TIMEOUT_S, LogFormat, PartialConfig, SourceSpec, SourceSpecError,
};
pub use metrics::Metrics;

use crate::bake::BakeOptions;
use crate::lod::PointBaker;
use crate::raster::{HeightEncoding, LoadOptions, Overrides};
use crate::store::Store;
use crate::tiling::Pyramid;

#[derive(Debug, thiserror::Error)]
pub enum ServerError {
    #[error("serve: {0}")]
    Config(String),
    #[error("serve: cannot listen on {addr}: {source}")]
    Bind { addr: SocketAddr, source: std::io::Error },
    #[error("serve: {0}")]
    Io(#[from] std::io::Error),
    #[error(transparent)]
    Store(#[from] crate::store::StoreError),
    #[error("serve: --source {name}: {source}")]
    Source { name: String, source: SourceError },
}

/// Why an on-demand source or the demo tileset could not be prepared: the stage that failed.
#[derive(Debug, thiserror::Error)]
pub enum SourceError {
    #[error(transparent)]
    Raster(#[from] crate::raster::RasterError),
    #[error(transparent)]
    Bake(#[from] crate::bake::BakeError),
    #[error(transparent)]
    Store(#[from] crate::store::StoreError),
}

/// Tileset names: `[a-z0-9_-]{1,64}`. Nothing else can name a directory in the store, so no
/// request can reach outside it (no `.`, no separator, no encoded separator survives this).
#[must_use]
pub fn valid_name(name: &str) -> bool {
    (1..=64).contains(&name.len())
        && name.bytes().all(|b| b.is_ascii_lowercase() || b.is_ascii_digit() || b == b'_' || b == b'-')
}

/// Shared state of a running server.
pub struct App {
    pub config: Config,
    pub metrics: Arc<Metrics>,
    registry: registry::Registry,
    cache: cache::BlobCache,
    bakery: bakery::Bakery,
    /// On-demand quantized-mesh builds.
    terrain: terrain::Builds,
    /// Decoded TINs of height queries (`surface=mesh`), shared by requests.
    meshes: Arc<crate::heights::MeshCache>,
    /// Border fans of terrain blobs (generation, tile, level) for their neighbours' GLBs.
    fans: Arc<crate::formats::tiles3d::border::FanCache<(u64, crate::tiling::TileKey, u8)>>,
    jobs: admin::Jobs,
    in_flight: AtomicUsize,
    rate: rate_limit::RateLimiter,
    ready: AtomicBool,
    /// When the store scan running now began (`None`: none runs). One scan runs at a time; a
    /// scan stuck on a file (a FIFO swapped in after its type was checked, a hung mount) makes
    /// the server not ready once it has run past [`App::scan_deadline`], and holds up nothing
    /// else: requests, polling's timer and shutdown do not wait for it.
    scan_since: std::sync::Mutex<Option<std::time::Instant>>,
    /// Computes point levels for on-demand and admin bakes (opened once at startup).
    baker: Arc<PointBaker>,
}

impl App {
    /// Re-scans the store for added, changed and removed tilesets now (blocking: call it off
    /// the async workers). Does nothing while another scan still runs.
    pub fn rescan(&self) {
        struct Running<'a>(&'a std::sync::Mutex<Option<std::time::Instant>>);
        impl Drop for Running<'_> {
            fn drop(&mut self) {
                if let Ok(mut s) = self.0.lock() {
                    *s = None;
                }
            }
        }
        {
            let Ok(mut since) = self.scan_since.lock() else { return };
            if since.is_some() {
                return;
            }
            *since = Some(std::time::Instant::now());
        }
        let _running = Running(&self.scan_since);
        match self.registry.scan() {
            Ok(()) => self.ready.store(true, Ordering::Relaxed),
            Err(e) => {
                self.ready.store(false, Ordering::Relaxed);
                tracing::error!(error = %e, "store scan failed");
            }
        }
    }

    /// How long a store scan may run before the server says it is not ready: ten poll
    /// intervals, and at least [`SCAN_DEADLINE_MIN`].
    #[must_use]
    pub fn scan_deadline(&self) -> std::time::Duration {
        (self.config.poll * 10).max(SCAN_DEADLINE_MIN)
    }

    /// How long the scan running now has run, when that is past [`App::scan_deadline`].
    #[must_use]
    pub fn scan_stuck(&self) -> Option<std::time::Duration> {
        let since = (*self.scan_since.lock().ok()?)?;
        Some(since.elapsed()).filter(|d| *d > self.scan_deadline())
    }

    /// What bakes point levels in this server: "cpu" or "gpu: <adapter>".
    #[must_use]
    pub fn point_baker(&self) -> String {
        self.baker.describe()
    }

    /// Names of the tilesets being served.
    #[must_use]
    pub fn tileset_names(&self) -> Vec<String> {
        self.registry.all().iter().map(|t| t.name.clone()).collect()
    }
}

/// Refuses a raster too small to be tiled (under 2×2 samples) with the message `bake` gives,
/// naming `path`. Checked where the server loads a raster whole (`--source`, admin uploads),
/// not in the loader: tiny rasters are legitimate inputs to other uses of it.
pub(crate) fn tileable(
    path: &std::path::Path,
    raster: &crate::raster::LoadedRaster,
) -> Result<(), crate::raster::RasterError> {
    let (w, h) = (raster.heights.width, raster.heights.height);
    if w < 2 || h < 2 {
        return Err(crate::raster::RasterError::Dataset {
            path: path.to_owned(),
            message: format!("is {w}×{h} samples; a heightfield needs at least 2×2 to be tiled"),
        });
    }
    Ok(())
}

/// Loads an on-demand source and prepares its directory (as `bake` would, so either resumes the
/// other's work).
fn open_source(root: &std::path::Path, spec: &SourceSpec) -> Result<registry::OnDemand, ServerError> {
    let err = |e: SourceError| ServerError::Source { name: spec.name.clone(), source: e };
    let encoding = match spec.encoding.as_deref() {
        None => None,
        Some("gray16") => Some(HeightEncoding::Gray16),
        Some("terrain-rgb") => Some(HeightEncoding::TerrainRgb),
        Some("terrarium") => Some(HeightEncoding::Terrarium),
        Some(other) => {
            return Err(ServerError::Config(format!(
                "--source {}: encoding {other:?} is not gray16, terrain-rgb or terrarium",
                spec.name
            )));
        }
    };
    let crs = match &spec.crs {
        Some(c) => Some(
            crate::crs::Crs::parse(c)
                .map_err(|e| ServerError::Config(format!("--source {}: crs {c:?}: {e}", spec.name)))?,
        ),
        None => None,
    };
    let vertical = match spec.vertical_datum.as_deref() {
        Some("egm96") => Some(crate::crs::VerticalDatum::Egm96),
        Some("egm2008") => Some(crate::crs::VerticalDatum::Egm2008),
        Some(_) => Some(crate::crs::VerticalDatum::Ellipsoid),
        None => crs.as_ref().and_then(|c| c.1),
    };
    let load = LoadOptions {
        encoding,
        overrides: Overrides {
            cell_size: spec.cell_size,
            crs: crs.map(|c| c.0),
            vertical,
            ..Overrides::default()
        },
        ..LoadOptions::default()
    };
    let raster = crate::raster::load(&spec.raster, &load).map_err(|e| err(e.into()))?;
    tileable(&spec.raster, &raster).map_err(|e| err(e.into()))?;
    let d = BakeOptions::default();
    let opts = BakeOptions {
        tile_size: spec.tile_size.unwrap_or(d.tile_size),
        max_error: spec.max_error.unwrap_or(d.max_error),
        levels: spec.levels.unwrap_or(d.levels),
        point_levels: spec.point_levels.unwrap_or(d.point_levels),
    };
    crate::bake::check_options(&opts).map_err(|e| err(e.into()))?;
    let pyramid = Pyramid::new(raster.heights.width, raster.heights.height, opts.tile_size)
        .map_err(|e| err(crate::bake::BakeError::from(e).into()))?;
    let file = spec
        .raster
        .file_name()
        .map_or_else(|| spec.raster.display().to_string(), |n| n.to_string_lossy().into_owned());
    let options = crate::bake::options_record(&raster, &file, &opts);
    Store::new(&root.join(&spec.name)).begin_bake(&options).map_err(|e| err(e.into()))?;
    let terrain = crate::bake::qmesh::TerrainOptions {
        error_scale: spec.terrain_error_scale.unwrap_or(1.0),
        max_zoom: spec.terrain_max_zoom,
    };
    let heights = crate::raster::WindowReader::height_range(&raster.heights);
    Ok(registry::OnDemand {
        source: Arc::new(registry::Source { raster, opts, pyramid, terrain, heights }),
        options,
    })
}

/// Is `name` a staging entry the admin API creates in the store (`.upload-jN`, `.job-jN`) or a
/// deleted tileset being removed (`.deleted-NAME-NANOS`)? Only these exact shapes.
fn is_staging_name(name: &str) -> bool {
    let digits = |s: &str| !s.is_empty() && s.bytes().all(|b| b.is_ascii_digit());
    if let Some(n) = name.strip_prefix(".upload-j").or_else(|| name.strip_prefix(".job-j")) {
        return digits(n);
    }
    name.strip_prefix(".deleted-")
        .and_then(|r| r.rsplit_once('-'))
        .is_some_and(|(tileset, nanos)| valid_name(tileset) && digits(nanos))
}

/// Removes what an earlier server left in the store mid-upload, mid-bake or mid-delete (it was
/// killed, or the machine went down): job ids restart at 1, so a leftover `.job-j1` would
/// otherwise be resumed into a different upload. Each removal is logged.
fn remove_staging_leftovers(root: &std::path::Path) {
    let Ok(entries) = std::fs::read_dir(root) else { return };
    for entry in entries.flatten() {
        if !entry.file_name().to_str().is_some_and(is_staging_name) {
            continue;
        }
        let path = entry.path();
        let is_dir = entry.file_type().is_ok_and(|t| t.is_dir());
        let r = if is_dir { std::fs::remove_dir_all(&path) } else { std::fs::remove_file(&path) };
        match r {
            Ok(()) => tracing::info!(path = %path.display(), "removed a staging leftover of an earlier run"),
            Err(e) => tracing::warn!(path = %path.display(), error = %e, "cannot remove a staging leftover"),
        }
    }
}

/// The shortest time a store scan may run before the server reports not ready
/// ([`App::scan_deadline`]): a scan of a large store or a bucket takes seconds.
pub const SCAN_DEADLINE_MIN: std::time::Duration = std::time::Duration::from_secs(30);

/// How long stopping the server waits for blocking work still running (a store read stuck on
/// a file, a tileset being deleted): the process then exits without it. Every write is atomic,
/// so nothing is left half-written.
const BLOCKING_SHUTDOWN_WAIT: std::time::Duration = std::time::Duration::from_secs(2);

/// Connections the kernel queues for `accept` (capped by `net.core.somaxconn`): room for a
/// burst of clients while the server is at `--max-connections` or accepting a flood; the
/// 1024 of a plain `bind` drops SYNs of a burst, which then wait seconds to be retried.
const LISTEN_BACKLOG: u32 = 4096;

/// `n` listening sockets on `addr`, one per serving thread. With more than one, each has
/// `SO_REUSEPORT` (the kernel spreads new connections over them; port 0 picks one port for
/// all). Such a bind would also join another process's `SO_REUSEPORT` sockets on the port, so
/// a plain socket is bound to it first: if anything listens there, that fails as a plain bind
/// does.
///
/// With `cpus` (one per socket, `affinity::plan`), socket `i` asks for the connections CPU
/// `cpus[i]` receives; a refusal is logged and leaves the kernel's hash to spread them.
fn listen(addr: SocketAddr, n: usize, cpus: Option<&[usize]>) -> std::io::Result<Vec<std::net::TcpListener>> {
    let socket = |a: SocketAddr| {
        let s = if a.is_ipv4() { tokio::net::TcpSocket::new_v4()? } else { tokio::net::TcpSocket::new_v6()? };
        s.set_reuseaddr(true)?;
        std::io::Result::Ok(s)
    };
    let probe = socket(addr)?;
    probe.bind(addr)?;
    if n <= 1 {
        return Ok(vec![probe.listen(LISTEN_BACKLOG)?.into_std()?]);
    }
    let addr = probe.local_addr()?;
    drop(probe);
    let mut listeners = Vec::with_capacity(n);
    for i in 0..n {
        let s = socket(addr)?;
        #[cfg(unix)]
        s.set_reuseport(true)?;
        if let Some(&cpu) = cpus.and_then(|c| c.get(i))
            && let Err(e) = affinity::steer(&s, cpu)
        {
            tracing::warn!(cpu, error = %e, "cannot steer connections to the serving thread of their CPU (SO_INCOMING_CPU)");
        }
        s.bind(addr)?;
        listeners.push(s.listen(LISTEN_BACKLOG)?.into_std()?);
    }
    Ok(listeners)
}

/// A bound, not yet running server.
pub struct Server {
    /// One per serving thread (`Config::threads`).
    listeners: Vec<std::net::TcpListener>,
    /// The CPU each serving thread is pinned to (`--cpu-affinity`), or none.
    cpus: Option<Vec<usize>>,
    app: Arc<App>,
}

impl Server {
    /// Loads the on-demand sources, scans the store, starts the bake workers and binds.
    pub async fn bind(config: Config) -> Result<Self, ServerError> {
        let remote = crate::store::is_remote(&config.store.to_string_lossy());
        if remote {
            // The server only reads a bucket: what writes into the store needs a directory.
            if !config.sources.is_empty() || config.admin_token.is_some() {
                return Err(ServerError::Config(format!(
                    "--store {}: a store in object storage is served read-only; --source and the admin API \
                     (--admin-token) bake into the store and need a local directory",
                    config.store.display()
                )));
            }
        } else if !config.store.is_dir() {
            return Err(ServerError::Config(format!(
                "--store {}: not a directory (create it, or bake into DIR/NAME first)",
                config.store.display()
            )));
        } else {
            let root = config.store.clone();
            tokio::task::spawn_blocking(move || remove_staging_leftovers(&root))
                .await
                .map_err(|e| ServerError::Config(format!("--store: {e}")))?;
        }
        let mut on_demand = HashMap::new();
        for spec in &config.sources {
            let root = config.store.clone();
            let spec2 = spec.clone();
            let od = tokio::task::spawn_blocking(move || open_source(&root, &spec2))
                .await
                .map_err(|e| ServerError::Config(format!("--source {}: {e}", spec.name)))??;
            on_demand.insert(spec.name.clone(), od);
        }
        let (mode, budget) = (config.gpu, config.gpu_budget_mib.saturating_mul(1 << 20));
        // A server with no source and no admin API never bakes: no adapter is opened for it.
        let bakes = !config.sources.is_empty() || config.admin_token.is_some();
        let mode = if bakes { mode } else { crate::lod::GpuMode::Off };
        let (baker, notice) = tokio::task::spawn_blocking(move || PointBaker::open(mode, budget))
            .await
            .map_err(|e| ServerError::Config(format!("--gpu: {e}")))?
            .map_err(|e| ServerError::Config(format!("--gpu: {e}")))?;
        if let Some(n) = notice {
            tracing::warn!("{n}; baking point levels on the CPU");
        }
        tracing::info!(point_baker = %baker.describe(), "point levels will be baked here");
        let baker = Arc::new(baker);
        let metrics = Arc::new(Metrics::default());
        let registry = registry::Registry::new(&config.store, on_demand)?;
        let app = Arc::new(App {
            registry,
            cache: cache::BlobCache::new(config.cache_bytes),
            bakery: bakery::Bakery::start(config.bake_workers, config.bake_queue, metrics.clone(), &baker),
            terrain: terrain::Builds::new(config.bake_workers, config.bake_queue),
            meshes: Arc::new(crate::heights::MeshCache::new(heights::MESH_CACHE_BYTES)),
            fans: Arc::new(crate::formats::tiles3d::border::FanCache::new(tiles3d::FAN_MEMO_BYTES)),
            baker,
            jobs: admin::Jobs::new(),
            in_flight: AtomicUsize::new(0),
            rate: rate_limit::RateLimiter::new(config.rate_limit),
            ready: AtomicBool::new(false),
            scan_since: std::sync::Mutex::new(None),
            metrics,
            config,
        });
        {
            // The first scan, before listening; one stuck past its deadline is left running
            // (the server listens, not ready, and polling takes over once it ends).
            let a = app.clone();
            let first = tokio::task::spawn_blocking(move || a.rescan());
            if let Ok(r) = tokio::time::timeout(app.scan_deadline(), first).await {
                r.map_err(|e| ServerError::Config(format!("--store: {e}")))?;
            } else {
                tracing::error!(
                    store = %app.config.store.display(),
                    "the first store scan has not finished; listening, not ready until a scan completes"
                );
            }
        }
        let cpus = affinity::plan(app.config.cpu_affinity, app.config.threads, &affinity::allowed_cpus());
        let listeners = listen(app.config.bind, app.config.threads, cpus.as_deref())
            .map_err(|source| ServerError::Bind { addr: app.config.bind, source })?;
        if let Some(c) = &cpus {
            tracing::info!(cpus = ?c, "serving threads pinned one to a CPU; connections go to the thread on the CPU that receives them");
        }
        Ok(Self { listeners, cpus, app })
    }

    pub fn local_addr(&self) -> Result<SocketAddr, ServerError> {
        match self.listeners.first() {
            Some(l) => Ok(l.local_addr()?),
            None => Err(ServerError::Config("no listening socket".into())),
        }
    }

    #[must_use]
    pub fn app(&self) -> Arc<App> {
        self.app.clone()
    }

    /// The request service `run` serves (the blob fast path in front of the router), for
    /// driving requests in-process without a connection (fuzzing).
    #[doc(hidden)]
    #[must_use]
    pub fn service(&self) -> fast::FastPath {
        fast::FastPath::new(self.app.clone())
    }

    /// Serves until `shutdown` completes, then stops accepting, lets in-flight requests finish
    /// within `Config::shutdown_timeout`, and returns. Blobs are only ever renamed into place
    /// complete, so a bake cut short leaves no half-written blob.
    pub async fn run(self, shutdown: impl Future<Output = ()> + Send + 'static) -> Result<(), ServerError> {
        let app = self.app;
        let poller = {
            let app = app.clone();
            tokio::spawn(async move {
                let mut tick = tokio::time::interval(app.config.poll);
                tick.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Delay);
                let mut stuck_logged = false;
                loop {
                    tick.tick().await;
                    // Not awaited: a scan stuck on a file must not stop the timer (the next
                    // tick's scan returns at once while it runs) nor hold up shutdown.
                    let a = app.clone();
                    drop(tokio::task::spawn_blocking(move || a.rescan()));
                    match app.scan_stuck() {
                        Some(d) if !stuck_logged => {
                            stuck_logged = true;
                            tracing::error!(
                                seconds = d.as_secs(),
                                "a store scan has not finished (a file that blocks on open, a hung mount?); not ready until it does"
                            );
                        }
                        None => stuck_logged = false,
                        Some(_) => {}
                    }
                }
            })
        };
        let (stop_tx, stop_rx) = tokio::sync::watch::channel(false);
        let (abort_tx, abort_rx) = tokio::sync::watch::channel(false);
        let limits = listener::Limits {
            max_connections: app.config.max_connections,
            per_client: app.config.max_connections_per_client,
            header_timeout: app.config.header_timeout,
            idle_timeout: app.config.idle_timeout,
        };
        // Sockets steered by CPU take all of one CPU's connections: threads then even out
        // their counts (`Shared::balanced`); the kernel's hash needs no help.
        let (shared, inboxes) = match &self.cpus {
            Some(_) => listener::Shared::balanced(&limits, self.listeners.len()),
            None => (listener::Shared::new(&limits), Vec::new()),
        };
        let shared = Arc::new(shared);
        let mut inboxes = inboxes.into_iter().map(Some).collect::<Vec<_>>();
        // One single-threaded runtime per serving thread, each with its own listening socket:
        // a connection stays on the thread that accepted it, with no work stealing and no
        // wake-ups across threads (nginx's worker model).
        let mut done = Vec::with_capacity(self.listeners.len());
        let mut result = Ok(());
        for (i, l) in self.listeners.into_iter().enumerate() {
            let rt = match tokio::runtime::Builder::new_current_thread().enable_all().build() {
                Ok(rt) => rt,
                Err(e) => {
                    result = Err(ServerError::Io(e));
                    break;
                }
            };
            let (tx, rx) = tokio::sync::oneshot::channel::<()>();
            let (app, shared, stop, mut abort) =
                (app.clone(), shared.clone(), stop_rx.clone(), abort_rx.clone());
            let cpu = self.cpus.as_ref().and_then(|c| c.get(i).copied());
            let inbox = inboxes.get_mut(i).and_then(Option::take);
            let spawned =
                std::thread::Builder::new().name(format!("terrastream-serve-{i}")).spawn(move || {
                    if let Some(cpu) = cpu
                        && let Err(e) = affinity::pin_current_thread(cpu)
                    {
                        tracing::warn!(cpu, error = %e, "cannot pin a serving thread to its CPU; it runs unpinned");
                    }
                    rt.block_on(async move {
                        let serve = async {
                            match tokio::net::TcpListener::from_std(l) {
                                Ok(l) => {
                                    listener::serve(l, fast::FastPath::new(app), limits, &shared, i, inbox, stop)
                                        .await;
                                }
                                Err(e) => tracing::error!(error = %e, "cannot serve on a listening socket"),
                            }
                        };
                        tokio::select! {
                            () = serve => {}
                            _ = abort.wait_for(|v| *v) => {}
                        }
                    });
                    // Connections still open (past the shutdown timeout) are dropped here; blocking
                    // work still running is left behind after a short wait.
                    rt.shutdown_timeout(BLOCKING_SHUTDOWN_WAIT);
                    drop(tx);
                });
            match spawned {
                Ok(_) => done.push(rx),
                Err(e) => {
                    result = Err(ServerError::Io(e));
                    break;
                }
            }
        }
        let serve = async {
            for rx in &mut done {
                let _ = rx.await;
            }
        };
        let mut serve = std::pin::pin!(serve);
        let mut finished = false;
        if result.is_ok() {
            tokio::select! {
                () = serve.as_mut() => finished = true,
                () = shutdown => {
                    tracing::info!("shutting down: no new connections; finishing in-flight requests");
                    let _ = stop_tx.send(true);
                    if tokio::time::timeout(app.config.shutdown_timeout, serve.as_mut()).await.is_ok() {
                        finished = true;
                    } else {
                        tracing::warn!(
                            in_flight = app.in_flight.load(Ordering::Relaxed),
                            "shutdown timeout reached; dropping the requests still in flight"
                        );
                    }
                }
            }
        }
        if !finished {
            // Whatever still runs (past the timeout, or after a failed start) stops now.
            let _ = stop_tx.send(true);
            let _ = abort_tx.send(true);
            serve.await;
        }
        poller.abort();
        app.bakery.close();
        result
    }
}

/// Completes on Ctrl-C or SIGTERM.
pub async fn shutdown_signal() {
    let ctrl_c = async {
        if tokio::signal::ctrl_c().await.is_err() {
            std::future::pending::<()>().await;
        }
    };
    #[cfg(unix)]
    let term = async {
        match tokio::signal::unix::signal(tokio::signal::unix::SignalKind::terminate()) {
            Ok(mut s) => {
                s.recv().await;
            }
            Err(_) => std::future::pending::<()>().await,
        }
    };
    #[cfg(not(unix))]
    let term = std::future::pending::<()>();
    tokio::select! {
        () = ctrl_c => {},
        () = term => {},
    }
}

/// Runs a server until Ctrl-C or SIGTERM; `on_ready` gets the bound address (print URLs there).
/// Connections are served on `Config::threads` threads of their own (`Server::run`); this
/// thread's runtime only waits for signals and re-scans the store.
pub fn serve_blocking(config: Config, on_ready: impl FnOnce(SocketAddr, &App)) -> Result<(), ServerError> {
    let rt = tokio::runtime::Builder::new_current_thread().enable_all().build()?;
    let r = rt.block_on(async move {
        let server = Server::bind(config).await?;
        on_ready(server.local_addr()?, &server.app);
        server.run(shutdown_signal()).await
    });
    // Dropping the runtime would wait for every blocking task, a read stuck on a file too.
    rt.shutdown_timeout(BLOCKING_SHUTDOWN_WAIT);
    r
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn staging_names_are_matched_exactly() {
        for n in [".upload-j1", ".job-j12", ".deleted-t-1700000000000000000", ".deleted-a-b-1"] {
            assert!(is_staging_name(n), "{n}");
        }
        for n in [
            ".upload-j",
            ".upload-jx",
            ".job-1",
            "job-j1",
            ".job-j1.bak",
            ".upload-j1/",
            ".deleted-t-",
            ".deleted-T-1",
            ".deleted-1",
            "t",
            ".hidden",
        ] {
            assert!(!is_staging_name(n), "{n}");
        }
    }
}
