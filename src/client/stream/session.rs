//! The live client: a [`Session`] streams one tileset from a running `terrastream serve` —
//! manifest first, then index chunks and (tile, level) blobs as the selection asks for them —
//! through the pure [`Scheduler`] and [`TileCache`], with a pool of blocking HTTP workers as the
//! transport; [`replay`] drives a session along a camera [`Flight`] in real time and gathers the
//! per-frame and total figures written to `stats.json`.
//!
//! The wall clock is the session's time (timeouts, backoff, `Retry-After` and fades are real);
//! frames are paced at `fps` and the flight advances `1/fps` per frame, so a slow frame delays
//! the flight instead of skipping poses.

use std::collections::{HashMap, HashSet};
use std::net::SocketAddr;
use std::sync::mpsc::{Receiver, Sender, channel};
use std::sync::{Arc, Mutex, PoisonError};
use std::thread::JoinHandle;
use std::time::{Duration, Instant, SystemTime};

use serde::Serialize;

use crate::client::ClientError;
use crate::client::select::{Camera, DrawItem, SelectParams, SelectStats, Selector};
use crate::client::stream::fetch::{
    self, FetchParams, Outcome, RequestId, Resource, Scheduler, TileCache, Transport, parse_retry_after,
};
use crate::client::stream::flight::{Flight, Pose};
use crate::client::stream::http::{self, BaseUrl};
use crate::client::tree::TileTree;
use crate::codec::{self, Blob};
use crate::store::{IndexChunk, Manifest};
use crate::tiling::TileKey;

/// Frames per second of a replay (`--fps`).
pub const DEFAULT_FPS: f64 = 30.0;
/// Longest time a replay holds the last pose waiting for the view to complete (`--settle`).
pub const DEFAULT_SETTLE_S: f64 = 20.0;
/// Viewport width in pixels (`--width`).
pub const DEFAULT_WIDTH: u32 = 1280;
/// Viewport height in pixels (`--height`).
pub const DEFAULT_HEIGHT: u32 = 720;

/// Settings of a session.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SessionOptions {
    pub width: u32,
    pub height: u32,
    pub fov_deg: f64,
    pub select: SelectParams,
    pub fetch: FetchParams,
    pub cache_bytes: usize,
}

impl Default for SessionOptions {
    fn default() -> Self {
        Self {
            width: DEFAULT_WIDTH,
            height: DEFAULT_HEIGHT,
            fov_deg: crate::client::select::DEFAULT_FOV_DEG,
            select: SelectParams::default(),
            fetch: FetchParams::default(),
            cache_bytes: fetch::DEFAULT_CACHE_BYTES,
        }
    }
}

/// A finished GET: id, resource, result, and when the response had been read in full.
type Reply = (RequestId, Resource, std::io::Result<http::Response>, Instant);

/// The transport: `max_in_flight` worker threads each doing one blocking GET at a time.
struct HttpTransport {
    jobs: Option<Sender<(RequestId, Resource)>>,
    replies: Receiver<Reply>,
    cancelled: Arc<Mutex<HashSet<RequestId>>>,
    workers: Vec<JoinHandle<()>>,
}

impl HttpTransport {
    fn new(addr: SocketAddr, base: &BaseUrl, tileset: &str, workers: usize, timeout: Duration) -> Self {
        let (jobs, job_rx) = channel::<(RequestId, Resource)>();
        let job_rx = Arc::new(Mutex::new(job_rx));
        let (reply_tx, replies) = channel();
        let cancelled = Arc::new(Mutex::new(HashSet::new()));
        let prefix = format!("{}/tilesets/{tileset}", base.prefix);
        let workers = (0..workers.max(1))
            .map(|_| {
                let (job_rx, reply_tx, cancelled) = (job_rx.clone(), reply_tx.clone(), cancelled.clone());
                let (host, prefix) = (base.authority.clone(), prefix.clone());
                std::thread::spawn(move || {
                    loop {
                        let job = job_rx.lock().unwrap_or_else(PoisonError::into_inner).recv();
                        let Ok((id, r)) = job else { return };
                        if cancelled.lock().unwrap_or_else(PoisonError::into_inner).remove(&id) {
                            continue;
                        }
                        let res = http::get(addr, &host, &format!("{prefix}/{}", r.path()), timeout);
                        if reply_tx.send((id, r, res, Instant::now())).is_err() {
                            return;
                        }
                    }
                })
            })
            .collect();
        Self { jobs: Some(jobs), replies, cancelled, workers }
    }
}

impl Transport for HttpTransport {
    fn start(&mut self, id: RequestId, resource: Resource) {
        if let Some(j) = &self.jobs {
            let _ = j.send((id, resource));
        }
    }

    fn cancel(&mut self, id: RequestId) {
        // A request already running finishes; the scheduler ignores its late result.
        self.cancelled.lock().unwrap_or_else(PoisonError::into_inner).insert(id);
    }
}

impl Drop for HttpTransport {
    fn drop(&mut self) {
        self.jobs = None;
        for w in self.workers.drain(..) {
            let _ = w.join();
        }
    }
}

/// Which part of a replay a frame belongs to (`"flight"` or `"settle"` in `stats.json`).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum ReplayPhase {
    /// Following the flight's poses.
    #[default]
    Flight,
    /// Holding the last pose until the view is complete.
    Settle,
}

impl std::fmt::Display for ReplayPhase {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.pad(match self {
            Self::Flight => "flight",
            Self::Settle => "settle",
        })
    }
}

/// Figures of one frame (one line of `stats.json`'s `frames`).
#[derive(Debug, Clone, Default, PartialEq, Serialize)]
pub struct FrameStats {
    pub frame: u32,
    /// Flight time of the pose (s).
    pub t: f64,
    /// Session (wall-clock) time at the start of the frame (s).
    pub wall_s: f64,
    pub phase: ReplayPhase,
    /// The frame's selection: nodes visited, active and visible, tiles drawn per level and
    /// fading out, holes, the largest error drawn and whether every drawn tile is under the
    /// threshold (false when nothing is drawn). Its fields sit at this level in `stats.json`.
    #[serde(flatten)]
    pub selection: SelectStats,
    /// Nothing wanted is missing: every visible active node has its chosen level resident and
    /// every index chunk needed is loaded.
    pub complete: bool,
    /// Response body bytes received since the previous frame.
    pub bytes_received: u64,
    /// Requests running at the end of the frame.
    pub requests_in_flight: u32,
    /// Resources wanted and not yet resident (running, waiting or queued).
    pub pending: u32,
    pub select_ms: f64,
    /// Rendering: uploads of newly drawn tiles, the draw, waiting for the GPU, and the
    /// read-back on frames written as PNG (0 when not rendering).
    pub render_ms: f64,
    /// Whole frame: replies handled, selection, scheduling and rendering (`render_ms`).
    pub frame_ms: f64,
    /// PNG encoding and writing of this frame (not in `frame_ms`; 0 when not written).
    pub write_ms: f64,
    pub cache_bytes: u64,
}

/// A streaming client of one tileset.
pub struct Session {
    opts: SessionOptions,
    manifest: Manifest,
    tree: TileTree,
    selector: Selector,
    scheduler: Scheduler,
    cache: TileCache<Blob>,
    transport: HttpTransport,
    clock: Instant,
    draws: Vec<DrawItem>,
    camera: Option<Camera>,
    frame: u32,
    bytes_total: u64,
    decode_errors: u64,
    fetched: HashMap<Resource, u32>,
}

fn net(msg: String) -> ClientError {
    ClientError::Network(msg)
}

impl Session {
    /// Fetches the tileset's manifest from `url` (`http://host:port[/prefix]`) and starts the
    /// workers; index chunks and blobs follow frame by frame.
    pub fn connect(url: &str, tileset: &str, opts: SessionOptions) -> Result<Self, ClientError> {
        let base = BaseUrl::parse(url).map_err(net)?;
        let addr = base.resolve().map_err(net)?;
        let timeout = Duration::from_secs_f64(opts.fetch.timeout_s.clamp(0.001, 3600.0));
        let path = format!("{}/tilesets/{tileset}/tileset.json", base.prefix);
        let resp =
            http::get(addr, &base.authority, &path, timeout).map_err(|e| net(format!("GET {path}: {e}")))?;
        if resp.status != 200 {
            return Err(net(format!(
                "GET {path}: HTTP {}: {}",
                resp.status,
                String::from_utf8_lossy(&resp.body).chars().take(300).collect::<String>()
            )));
        }
        let manifest: Manifest = serde_json::from_slice(&resp.body)
            .map_err(|e| net(format!("GET {path}: not a tileset manifest: {e}")))?;
        let tree = TileTree::for_manifest(&manifest)?;
        let transport = HttpTransport::new(addr, &base, tileset, opts.fetch.max_in_flight, timeout);
        Ok(Self {
            opts,
            tree,
            selector: Selector::new(opts.select)?,
            scheduler: Scheduler::new(opts.fetch),
            cache: TileCache::new(opts.cache_bytes),
            transport,
            clock: Instant::now(),
            draws: Vec::new(),
            camera: None,
            frame: 0,
            bytes_total: resp.body.len() as u64,
            decode_errors: 0,
            fetched: HashMap::new(),
            manifest,
        })
    }

    #[must_use]
    pub fn manifest(&self) -> &Manifest {
        &self.manifest
    }

    #[must_use]
    pub fn tree(&self) -> &TileTree {
        &self.tree
    }

    #[must_use]
    pub fn cache(&self) -> &TileCache<Blob> {
        &self.cache
    }

    #[must_use]
    pub fn scheduler(&self) -> &Scheduler {
        &self.scheduler
    }

    /// What the last frame drew (fading-out tiles included, flagged `retiring`).
    #[must_use]
    pub fn draws(&self) -> &[DrawItem] {
        &self.draws
    }

    /// The camera of the last frame (`None` before the first).
    #[must_use]
    pub fn camera(&self) -> Option<&Camera> {
        self.camera.as_ref()
    }

    /// Response body bytes received so far (manifest included).
    #[must_use]
    pub fn bytes_received(&self) -> u64 {
        self.bytes_total
    }

    /// Blobs or chunks that arrived but did not decode (each is asked for again).
    #[must_use]
    pub fn decode_errors(&self) -> u64 {
        self.decode_errors
    }

    /// How many times each resource was received complete (more than once means it was
    /// evicted or failed to decode and had to be fetched again).
    #[must_use]
    pub fn fetch_counts(&self) -> &HashMap<Resource, u32> {
        &self.fetched
    }

    /// Seconds since the session started.
    #[must_use]
    pub fn now(&self) -> f64 {
        self.clock.elapsed().as_secs_f64()
    }

    /// One frame at `pose` (world units): takes in what arrived, selects, schedules requests.
    pub fn frame(&mut self, pose: &Pose, t: f64, phase: ReplayPhase) -> Result<FrameStats, ClientError> {
        let start = Instant::now();
        let now = self.now();
        let before = self.bytes_total;
        self.take_replies(now)?;
        let camera = Camera::new(pose, self.opts.width, self.opts.height, self.opts.fov_deg);
        let sel_start = Instant::now();
        let sel = self.selector.select(&self.tree, &camera, &self.cache, now)?;
        let select_ms = sel_start.elapsed().as_secs_f64() * 1e3;
        let mut wants = fetch::wants_of(&sel.wants, &sel.missing_chunks);
        let root = TileKey::new(0, 0, 0);
        if self.tree.root().is_none() && self.scheduler.failure(&Resource::Chunk { root }).is_none() {
            wants
                .push((Resource::Chunk { root }, fetch::Priority { visible: true, error_px: f64::INFINITY }));
        }
        let s = &sel.stats;
        let mut stats = FrameStats {
            frame: self.frame,
            t,
            wall_s: now,
            phase,
            selection: SelectStats {
                under_threshold: s.under_threshold && !sel.draws.is_empty(),
                ..s.clone()
            },
            complete: wants.is_empty() && self.tree.root().is_some(),
            select_ms,
            ..FrameStats::default()
        };
        self.draws.clear();
        self.draws.extend_from_slice(&sel.draws);
        self.camera = Some(camera);
        self.cache.set_drawn(self.draws.iter().map(|d| (d.key, d.level)));
        self.scheduler.update(&wants, now);
        self.scheduler.pump(now, &mut self.transport);
        self.frame += 1;
        stats.bytes_received = self.bytes_total - before;
        stats.requests_in_flight = u32::try_from(self.scheduler.in_flight()).unwrap_or(u32::MAX);
        stats.pending = u32::try_from(self.scheduler.pending()).unwrap_or(u32::MAX);
        stats.cache_bytes = self.cache.used_bytes() as u64;
        stats.frame_ms = start.elapsed().as_secs_f64() * 1e3;
        Ok(stats)
    }

    fn take_replies(&mut self, now: f64) -> Result<(), ClientError> {
        while let Ok((id, r, res, done)) = self.transport.replies.try_recv() {
            // Latency ends when the response was read, not at the frame that takes it in.
            let at = done.saturating_duration_since(self.clock).as_secs_f64().min(now);
            let (outcome, body) = match res {
                Ok(resp) => {
                    self.bytes_total += resp.body.len() as u64;
                    if resp.status == 200 {
                        (Outcome::Ok { bytes: resp.body.len() as u64 }, Some(resp.body))
                    } else {
                        let retry_after_s =
                            resp.retry_after.as_deref().and_then(|v| parse_retry_after(v, SystemTime::now()));
                        (Outcome::Status { code: resp.status, retry_after_s }, None)
                    }
                }
                Err(e)
                    if matches!(e.kind(), std::io::ErrorKind::TimedOut | std::io::ErrorKind::WouldBlock) =>
                {
                    (Outcome::Timeout, None)
                }
                Err(e) => (Outcome::Network(e.to_string()), None),
            };
            let Some(done) = self.scheduler.complete(id, &outcome, at) else { continue };
            let (true, Some(body)) = (done.ok, body) else { continue };
            *self.fetched.entry(r).or_insert(0) += 1;
            match r {
                Resource::Tile { key, level } => match codec::decode(&body) {
                    Ok(blob) if blob.header.key == key && blob.header.level == level => {
                        let bytes = fetch::decoded_bytes(&blob);
                        self.cache.insert(key, level, blob, bytes);
                    }
                    Ok(_) | Err(_) => self.decode_errors += 1,
                },
                Resource::Chunk { .. } => match serde_json::from_slice::<IndexChunk>(&body) {
                    Ok(chunk) => self.tree.insert_chunk(&chunk)?,
                    Err(_) => self.decode_errors += 1,
                },
            }
        }
        Ok(())
    }
}

/// Settings of a replay.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ReplayOptions {
    pub fps: f64,
    /// Longest time to hold the last pose waiting for a complete view.
    pub settle_s: f64,
    /// Flight seconds per wall-clock second (tests fly faster than real time).
    pub speed: f64,
}

impl Default for ReplayOptions {
    fn default() -> Self {
        Self { fps: DEFAULT_FPS, settle_s: DEFAULT_SETTLE_S, speed: 1.0 }
    }
}

/// Totals of a replay (`stats.json`'s `totals`).
#[derive(Debug, Clone, Default, PartialEq, Serialize)]
pub struct Totals {
    pub frames: u32,
    pub flight_frames: u32,
    /// Response body bytes received, manifest included.
    pub bytes: u64,
    /// Requests started (retries count again), and how they ended.
    pub requests: u64,
    pub succeeded: u64,
    pub retries: u64,
    pub timeouts: u64,
    pub cancelled: u64,
    pub failed: u64,
    pub decode_errors: u64,
    /// Request latency (start to complete response) percentiles over successful requests (ms).
    pub latency_p50_ms: f64,
    pub latency_p99_ms: f64,
    /// Session time of the first frame whose view was complete (s); `null` if none was.
    pub first_complete_s: Option<f64>,
    /// Share of frames with tiles drawn and every drawn tile under the threshold.
    pub share_under_threshold: f64,
    /// The last frame was complete.
    pub settled: bool,
    pub select_ms_mean: f64,
    pub select_ms_max: f64,
    pub frame_ms_mean: f64,
    pub frame_ms_max: f64,
    pub render_ms_mean: f64,
    pub render_ms_max: f64,
}

/// `stats.json`.
#[derive(Debug, Clone, Serialize)]
pub struct ReplayReport {
    pub tileset: String,
    pub url: String,
    pub flight: Option<String>,
    pub width: u32,
    pub height: u32,
    pub fov_deg: f64,
    pub threshold_px: f64,
    pub fps: f64,
    /// The adapter frames were rendered on, or `off: <why>`.
    pub rendering: String,
    pub totals: Totals,
    pub frames: Vec<FrameStats>,
}

/// Percentile `p` (0..=1) of `v` by nearest rank; 0 for an empty slice.
#[must_use]
pub fn percentile(v: &[f64], p: f64) -> f64 {
    if v.is_empty() {
        return 0.0;
    }
    let mut s = v.to_vec();
    s.sort_by(f64::total_cmp);
    let rank = (p.clamp(0.0, 1.0) * s.len() as f64).ceil().max(1.0) as usize;
    s[rank.min(s.len()) - 1]
}

/// Flies `flight` (any frame; normalised keys are mapped onto the tileset's bounds) through a
/// session in real time, then holds the last pose until the view is complete or `settle_s` has
/// passed. `on_frame` sees the session after each frame (rendering hooks in there, adding its
/// time to the frame's `render_ms` and `frame_ms`).
pub fn replay(
    session: &mut Session,
    flight: &Flight,
    opts: &ReplayOptions,
    mut on_frame: impl FnMut(&Session, &mut FrameStats) -> Result<(), ClientError>,
) -> Result<(Vec<FrameStats>, Totals), ClientError> {
    if !(opts.fps.is_finite() && opts.fps > 0.0) {
        return Err(ClientError::Camera(format!("fps {} must be positive", opts.fps)));
    }
    if !(opts.speed.is_finite() && opts.speed > 0.0) {
        return Err(ClientError::Camera(format!("speed {} must be positive", opts.speed)));
    }
    let world = flight.to_world(&session.manifest.bounds).map_err(ClientError::Camera)?;
    let t0 = session.now();
    let mut frames = Vec::new();
    let mut settle_start = None;
    let mut i: u32 = 0;
    loop {
        let t = world.start() + f64::from(i) * opts.speed / opts.fps;
        let phase = if t <= world.end() { ReplayPhase::Flight } else { ReplayPhase::Settle };
        if phase == ReplayPhase::Settle {
            let since = *settle_start.get_or_insert(session.now());
            let last_complete =
                frames.last().is_some_and(|f: &FrameStats| f.complete && f.selection.retiring == 0);
            if last_complete || session.now() - since > opts.settle_s {
                break;
            }
        }
        let pose = world.pose_at(t);
        let mut f = session.frame(&pose, t.min(world.end()), phase)?;
        on_frame(session, &mut f)?;
        frames.push(f);
        i += 1;
        let due = t0 + f64::from(i) / opts.fps;
        let wait = due - session.now();
        if wait > 0.0 {
            std::thread::sleep(Duration::from_secs_f64(wait));
        }
    }
    Ok((frames.clone(), totals(session, &frames)))
}

fn totals(session: &Session, frames: &[FrameStats]) -> Totals {
    let st = session.scheduler.stats();
    let n = frames.len().max(1) as f64;
    Totals {
        frames: frames.len() as u32,
        flight_frames: frames.iter().filter(|f| f.phase == ReplayPhase::Flight).count() as u32,
        bytes: session.bytes_total,
        requests: st.started,
        succeeded: st.succeeded,
        retries: st.retries,
        timeouts: st.timeouts,
        cancelled: st.cancelled,
        failed: st.failed,
        decode_errors: session.decode_errors,
        latency_p50_ms: percentile(&st.latencies_s, 0.5) * 1e3,
        latency_p99_ms: percentile(&st.latencies_s, 0.99) * 1e3,
        first_complete_s: frames.iter().find(|f| f.complete).map(|f| f.wall_s),
        share_under_threshold: frames.iter().filter(|f| f.selection.under_threshold).count() as f64 / n,
        settled: frames.last().is_some_and(|f| f.complete),
        select_ms_mean: frames.iter().map(|f| f.select_ms).sum::<f64>() / n,
        select_ms_max: frames.iter().map(|f| f.select_ms).fold(0.0, f64::max),
        frame_ms_mean: frames.iter().map(|f| f.frame_ms).sum::<f64>() / n,
        frame_ms_max: frames.iter().map(|f| f.frame_ms).fold(0.0, f64::max),
        render_ms_mean: frames.iter().map(|f| f.render_ms).sum::<f64>() / n,
        render_ms_max: frames.iter().map(|f| f.render_ms).fold(0.0, f64::max),
    }
}

/// Name of the statistics file a replay writes into its output directory.
pub const STATS_FILE: &str = "stats.json";

/// The settled view's PNG, in the frames folder.
pub const FINAL_FRAME: &str = "final.png";
/// Folder under `--out` that PNG frames are written to.
pub const FRAMES_DIR: &str = "frames";
/// Every how many frames one is written as PNG (`--frames-every`; 0 = none). At 30 frames per
/// second this is three pictures per flight second, plus the settled view (`final.png`).
pub const DEFAULT_FRAMES_EVERY: u32 = 10;

/// Whether `terrastream client` renders (`--render`).
#[cfg_attr(feature = "cli", derive(clap::ValueEnum))]
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum RenderMode {
    /// With any adapter (software ones such as Mesa lavapipe included); without one, replays
    /// without rendering and says so.
    #[default]
    Auto,
    /// An adapter or a clear error.
    On,
    /// Selection and streaming only.
    Off,
}

/// Everything `terrastream client` needs.
#[derive(Debug, Clone)]
pub struct ClientRun {
    pub url: String,
    pub tileset: String,
    pub flight: std::path::PathBuf,
    pub out: std::path::PathBuf,
    pub session: SessionOptions,
    pub replay: ReplayOptions,
    pub render: RenderMode,
    /// Write every Nth frame as `OUT/frames/NNNNN.png` (0: none), and the settled view as
    /// `OUT/frames/final.png` (unless 0).
    pub frames_every: u32,
}

/// The renderer of a run, or why there is none.
#[cfg(feature = "gpu")]
fn open_view(
    mode: RenderMode,
    session: &Session,
    opts: &SessionOptions,
) -> Result<(Option<crate::client::stream::view::SessionView>, String), ClientError> {
    if mode == RenderMode::Off {
        return Ok((None, "off (--render off)".into()));
    }
    match crate::gpu::open() {
        Ok(ctx) => {
            let adapter = ctx.adapter.clone();
            let view = crate::client::stream::view::SessionView::new(ctx, session, opts.width, opts.height)?;
            Ok((Some(view), adapter))
        }
        Err(e) if mode == RenderMode::On => Err(e.into()),
        Err(e) => {
            tracing::warn!("not rendering: {e}");
            Ok((None, format!("off: {e}")))
        }
    }
}

/// Connects, replays the flight (rendering each frame unless `--render off` or no adapter under
/// `auto`), writes PNG frames and `OUT/stats.json`; `on_frame` sees every frame's figures
/// (progress output). Returns the report that was written.
pub fn run_client(
    run: &ClientRun,
    mut on_frame: impl FnMut(&FrameStats),
) -> Result<ReplayReport, ClientError> {
    let flight = Flight::load(&run.flight)?;
    let mut session = Session::connect(&run.url, &run.tileset, run.session)?;
    let io = |path: &std::path::Path| {
        let path = path.to_owned();
        move |source| ClientError::Io { path, source }
    };
    std::fs::create_dir_all(&run.out).map_err(io(&run.out))?;
    let frames_dir = run.out.join(FRAMES_DIR);
    #[cfg(feature = "gpu")]
    let (mut view, rendering) = open_view(run.render, &session, &run.session)?;
    #[cfg(not(feature = "gpu"))]
    let rendering = match run.render {
        RenderMode::On => {
            return Err(ClientError::NoGpuFeature);
        }
        _ => "off: built without the `gpu` feature".to_owned(),
    };
    #[cfg(feature = "gpu")]
    if view.is_some() && run.frames_every > 0 {
        std::fs::create_dir_all(&frames_dir).map_err(io(&frames_dir))?;
    }
    let (frames, totals) = replay(&mut session, &flight, &run.replay, |s, f| {
        #[cfg(feature = "gpu")]
        if let Some(v) = view.as_mut() {
            let write = run.frames_every > 0 && f.frame % run.frames_every == 0;
            let start = Instant::now();
            let img = v.draw(s, write)?;
            f.render_ms = start.elapsed().as_secs_f64() * 1e3;
            f.frame_ms += f.render_ms;
            if let Some(img) = img {
                let start = Instant::now();
                let path = frames_dir.join(format!("{:05}.png", f.frame));
                crate::client::render::Renderer::save_png(&img, &path)?;
                f.write_ms = start.elapsed().as_secs_f64() * 1e3;
            }
        }
        #[cfg(not(feature = "gpu"))]
        let _ = (s, &frames_dir);
        on_frame(f);
        Ok(())
    })?;
    #[cfg(feature = "gpu")]
    if let (Some(v), true) = (view.as_mut(), run.frames_every > 0)
        && let Some(img) = v.draw(&session, true)?
    {
        crate::client::render::Renderer::save_png(&img, &frames_dir.join(FINAL_FRAME))?;
    }
    let report = ReplayReport {
        tileset: run.tileset.clone(),
        url: run.url.clone(),
        flight: flight.name.clone(),
        width: run.session.width,
        height: run.session.height,
        fov_deg: run.session.fov_deg,
        threshold_px: run.session.select.threshold_px,
        fps: run.replay.fps,
        rendering,
        totals,
        frames,
    };
    let path = run.out.join(STATS_FILE);
    let json = serde_json::to_vec_pretty(&report)
        .map_err(|e| ClientError::Io { path: path.clone(), source: std::io::Error::other(e) })?;
    crate::store::write_atomic(&path, &json)
        .map_err(|e| ClientError::Io { path: path.clone(), source: std::io::Error::other(e.to_string()) })?;
    Ok(report)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn percentiles_by_nearest_rank() {
        let v: Vec<f64> = (1..=100).map(f64::from).collect();
        assert!((percentile(&v, 0.5) - 50.0).abs() < 1e-12);
        assert!((percentile(&v, 0.99) - 99.0).abs() < 1e-12);
        assert!((percentile(&[3.0], 0.99) - 3.0).abs() < 1e-12);
        assert!(percentile(&[], 0.5).abs() < 1e-12);
    }

    #[test]
    fn connect_names_the_problem() {
        let e = Session::connect("ftp://x", "t", SessionOptions::default()).err().unwrap().to_string();
        assert!(e.contains("only http://"), "{e}");
        // A port nobody listens on.
        let port = std::net::TcpListener::bind("127.0.0.1:0").unwrap().local_addr().unwrap().port();
        let e = Session::connect(&format!("http://127.0.0.1:{port}"), "t", SessionOptions::default())
            .err()
            .unwrap()
            .to_string();
        assert!(e.contains("tileset.json"), "{e}");
    }
}
