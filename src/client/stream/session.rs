//! The live client: a [`Session`] streams one tileset from a running `terrastream serve` —
//! manifest first, then index chunks and (tile, level) blobs as the selection asks for them —
//! through the pure [`Scheduler`] and [`TileCache`], with a pool of blocking HTTP workers as the
//! transport. One [`Session::frame`] takes in what arrived, selects and schedules; the replay
//! application that drives a session along a camera flight lives in
//! [`crate::client::stream::replay`].
//!
//! With a collision radius ([`SessionOptions::collision`]) each frame also names the leaves
//! within `R` of the ego ([`crate::client::collision`]) and asks for their level 0 ahead of
//! every view tile, together with the leaves the ego will reach within the look-ahead
//! ([`Session::set_ego`]); those tiles are held in the cache from the moment they are asked for
//! (never evicted while in the region), and each frame counts the required leaves not resident at level 0 when the frame is
//! drawn (misses).
//!
//! The wall clock is the session's time (timeouts, backoff, `Retry-After` and fades are real).

use std::collections::{HashMap, HashSet};
use std::net::SocketAddr;
use std::sync::mpsc::{Receiver, Sender, channel};
use std::sync::{Arc, Mutex, PoisonError};
use std::thread::JoinHandle;
use std::time::{Duration, Instant, SystemTime};

use glam::DVec3;
use serde::Serialize;

use crate::client::ClientError;
use crate::client::collision::{self, CollisionParams, Region};
use crate::client::select::{Camera, DrawItem, SelectParams, SelectStats, Selector};
use crate::client::stream::fetch::{
    self, FetchParams, Outcome, RequestId, Resource, Scheduler, TileCache, Transport, parse_retry_after,
};
use crate::client::stream::flight_path::Pose;
use crate::client::stream::http::{self, BaseUrl};
use crate::client::tree::{NodeId, TileTree};
use crate::codec::{self, Blob};
use crate::store::{IndexChunk, Manifest};
use crate::tiling::TileKey;

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
    /// The collision region (`--collision-radius`); `None`: none.
    pub collision: Option<CollisionParams>,
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
            collision: None,
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
    /// The collision region's figures (only with a collision radius).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub collision: Option<CollisionFrame>,
}

/// The collision region in one frame (`stats.json`'s `frames[i].collision`).
#[derive(Debug, Clone, Default, PartialEq, Serialize)]
pub struct CollisionFrame {
    /// The ego position used (world units).
    pub ego: [f64; 3],
    /// Nodes required: leaves within the radius, plus one per node within it whose children's
    /// index chunk has not arrived (its leaves cannot be named yet), plus one for a missing root.
    pub required: u32,
    /// Required nodes not resident at level 0 when the frame was drawn (unnamed ones included).
    pub misses: u32,
    /// Leaves asked for or held: within the radius grown by the ego's look-ahead distance.
    pub held: u32,
    /// The look-ahead distance added to the radius for fetching (world units).
    pub ahead_m: f64,
    /// Response body bytes received since the previous frame for resources the region asked
    /// for.
    pub bytes: u64,
}

/// The collision region's working state in a session.
#[derive(Debug, Default)]
struct CollisionState {
    /// Ego and look-ahead distance for the next frame ([`Session::set_ego`]).
    next: Option<(DVec3, f64)>,
    required: Region,
    held: Region,
    /// Every resource the region asked for.
    asked: HashSet<Resource>,
    bytes: u64,
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
    collision: CollisionState,
}

fn net(msg: String) -> ClientError {
    ClientError::Network(msg)
}

impl Session {
    /// Fetches the tileset's manifest from `url` (`http://host:port[/prefix]`) and starts the
    /// workers; index chunks and blobs follow frame by frame.
    pub fn connect(url: &str, tileset: &str, opts: SessionOptions) -> Result<Self, ClientError> {
        if let Some(c) = opts.collision {
            CollisionParams::new(c.radius_m, c.lookahead_s)?;
        }
        let base = BaseUrl::parse(url)?;
        let addr = base.resolve()?;
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
            collision: CollisionState::default(),
            manifest,
        })
    }

    #[must_use]
    pub fn options(&self) -> &SessionOptions {
        &self.opts
    }

    /// Sets the ego position (world units) and how far (horizontally) it will move within the
    /// look-ahead, for the next frame only. A frame without one uses the camera's eye and no
    /// look-ahead.
    ///
    /// # Errors
    /// A position that is not finite or a distance that is not a finite number ≥ 0.
    pub fn set_ego(&mut self, ego: DVec3, ahead_m: f64) -> Result<(), ClientError> {
        if !(ego.is_finite() && ahead_m.is_finite() && ahead_m >= 0.0) {
            return Err(ClientError::Collision(format!(
                "ego {:?} with look-ahead distance {ahead_m} is not a finite position and distance ≥ 0",
                ego.to_array()
            )));
        }
        self.collision.next = Some((ego, ahead_m));
        Ok(())
    }

    /// Every resource the collision region has asked for.
    #[must_use]
    pub fn collision_asked(&self) -> &HashSet<Resource> {
        &self.collision.asked
    }

    /// Response body bytes received for resources the collision region asked for.
    #[must_use]
    pub fn collision_bytes(&self) -> u64 {
        self.collision.bytes
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
        let region_before = self.collision.bytes;
        self.take_replies(now)?;
        let camera = Camera::new(pose, self.opts.width, self.opts.height, self.opts.fov_deg);
        let sel_start = Instant::now();
        let sel = self.selector.select(&self.tree, &camera, &self.cache, now)?;
        let select_ms = sel_start.elapsed().as_secs_f64() * 1e3;
        let mut wants = fetch::wants_of(&sel.wants, &sel.missing_chunks);
        let root = TileKey::new(0, 0, 0);
        if self.tree.root().is_none() && self.scheduler.failure(&Resource::Chunk { root }).is_none() {
            wants.push((
                Resource::Chunk { root },
                fetch::Priority { visible: true, error_px: f64::INFINITY, ..fetch::Priority::default() },
            ));
        }
        let view_complete = wants.is_empty() && self.tree.root().is_some();
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
            complete: view_complete,
            select_ms,
            ..FrameStats::default()
        };
        self.draws.clear();
        self.draws.extend_from_slice(&sel.draws);
        let ego = self.collision.next.take().unwrap_or((pose.eye, 0.0));
        let collision = self.opts.collision.map(|c| self.collision_wants(&c, ego, &mut wants));
        self.camera = Some(camera);
        // The region's leaves are held (pinned, arrived or not): never evicted while in it.
        if self.opts.collision.is_some() {
            let tree = &self.tree;
            self.cache.set_held(self.collision.held.leaves.iter().map(|&n| (tree.node(n).key, 0)));
        }
        self.cache.set_drawn(self.draws.iter().map(|d| (d.key, d.level)));
        self.scheduler.update(&wants, now);
        self.scheduler.pump(now, &mut self.transport);
        self.frame += 1;
        stats.bytes_received = self.bytes_total - before;
        stats.requests_in_flight = u32::try_from(self.scheduler.in_flight()).unwrap_or(u32::MAX);
        stats.pending = u32::try_from(self.scheduler.pending()).unwrap_or(u32::MAX);
        stats.cache_bytes = self.cache.used_bytes() as u64;
        stats.collision =
            collision.map(|c| CollisionFrame { bytes: self.collision.bytes - region_before, ..c });
        stats.frame_ms = start.elapsed().as_secs_f64() * 1e3;
        Ok(stats)
    }

    /// The collision region at `ego` (with look-ahead distance): counts misses against what is
    /// resident now and appends its wants, ahead of the view's, to `wants`.
    fn collision_wants(
        &mut self,
        c: &CollisionParams,
        (ego, ahead_m): (DVec3, f64),
        wants: &mut Vec<(Resource, fetch::Priority)>,
    ) -> CollisionFrame {
        let st = &mut self.collision;
        collision::region_into(&self.tree, ego, c.radius_m, &mut st.required);
        let reach = c.radius_m + ahead_m;
        collision::region_into(&self.tree, ego, reach, &mut st.held);
        let resident = |n: NodeId| self.cache.contains(self.tree.node(n).key, 0);
        let missing_leaves = st.required.leaves.iter().filter(|&&n| !resident(n)).count();
        let misses = missing_leaves + st.required.unresolved.len() + usize::from(st.required.root_missing);
        for &root in &st.held.missing_chunks {
            let r = Resource::Chunk { root };
            st.asked.insert(r);
            wants.push((r, fetch::Priority { collision: true, visible: true, error_px: f64::INFINITY }));
        }
        let p = ego.truncate();
        for &n in &st.held.leaves {
            let node = self.tree.node(n);
            if self.cache.contains(node.key, 0) {
                continue;
            }
            let r = Resource::Tile { key: node.key, level: 0 };
            st.asked.insert(r);
            // Nearer the ego first: every leaf within the radius goes before the look-ahead's.
            let error_px = reach - collision::horizontal_distance(&node.cull, p);
            wants.push((r, fetch::Priority { collision: true, visible: true, error_px }));
        }
        CollisionFrame {
            ego: ego.to_array(),
            required: u32::try_from(st.required.required()).unwrap_or(u32::MAX),
            misses: u32::try_from(misses).unwrap_or(u32::MAX),
            held: u32::try_from(st.held.leaves.len()).unwrap_or(u32::MAX),
            ahead_m,
            bytes: 0,
        }
    }

    fn take_replies(&mut self, now: f64) -> Result<(), ClientError> {
        while let Ok((id, r, res, done)) = self.transport.replies.try_recv() {
            // Latency ends when the response was read, not at the frame that takes it in.
            let at = done.saturating_duration_since(self.clock).as_secs_f64().min(now);
            let (outcome, body) = match res {
                Ok(resp) => {
                    self.bytes_total += resp.body.len() as u64;
                    if self.collision.asked.contains(&r) {
                        self.collision.bytes += resp.body.len() as u64;
                    }
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

#[cfg(test)]
mod tests {
    use super::*;

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
