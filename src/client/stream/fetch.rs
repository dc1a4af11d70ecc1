//! Streaming: the request scheduler and the decoded-tile cache, as pure logic. The network sits
//! behind [`Transport`] (start and cancel requests by id; results come back through
//! [`Scheduler::complete`]) and time is passed in as seconds, so any async runtime — or a test —
//! can drive it.
//!
//! Rules:
//! - each frame the selection's wants replace the wanted set ([`Scheduler::update`]); requests
//!   start in priority order (the collision region's first, then visible, then largest
//!   screen-space error) while fewer than `max_in_flight` are running;
//! - a request no longer wanted for `cancel_grace_s` is cancelled (the grace keeps a camera that
//!   jitters across a threshold from cancelling and restarting the same tile);
//! - timeouts, connection failures, `408`, `429` and `5xx` are retried with exponential backoff
//!   (`backoff_base_s · 2^(attempt−1)`, capped at `backoff_max_s`, with deterministic jitter in
//!   its upper half); a `Retry-After` on `429`/`503` replaces the backoff for that request and
//!   pauses every new request until it has passed (the server asked the client, not the tile);
//!   other `4xx` fail the request for good;
//! - [`TileCache`] holds decoded tiles under a byte budget, evicting the least recently used
//!   tile that is not being drawn; tiles being drawn are pinned and never evicted (the cache may
//!   exceed its budget rather than open a hole), and so are held tiles (the collision region's),
//!   which are pinned before they arrive so a later arrival cannot evict them.

use std::collections::{BTreeMap, HashMap, HashSet};
use std::time::{Duration, SystemTime};

use crate::client::select::{Residency, Want};
use crate::tiling::TileKey;

/// Requests running at once.
pub const DEFAULT_MAX_IN_FLIGHT: usize = 8;
/// Seconds before a running request is abandoned as timed out.
pub const DEFAULT_TIMEOUT_S: f64 = 10.0;
/// First retry delay in seconds.
pub const DEFAULT_BACKOFF_BASE_S: f64 = 0.25;
/// Longest retry delay in seconds (also how soon a client notices a server that came back).
pub const DEFAULT_BACKOFF_MAX_S: f64 = 8.0;
/// Seconds a request may stay unwanted before it is cancelled.
pub const DEFAULT_CANCEL_GRACE_S: f64 = 0.5;
/// Longest `Retry-After` honoured, in seconds (a larger value is clamped to it).
pub const MAX_RETRY_AFTER_S: f64 = 300.0;
/// Decoded-tile cache budget in bytes (`--cache-mb`).
pub const DEFAULT_CACHE_BYTES: usize = 512 << 20;

/// Something the client fetches.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum Resource {
    /// One (tile, level) blob.
    Tile { key: TileKey, level: u8 },
    /// One index chunk, by its root key.
    Chunk { root: TileKey },
}

impl Resource {
    /// The resource's path inside a tileset (the store layout: `tiles/z/x/y/level.tsb`,
    /// `index/z/x/y.json`); transports put their own prefix in front.
    #[must_use]
    pub fn path(&self) -> String {
        match self {
            Self::Tile { key, level } => format!("tiles/{}/{}/{}/{level}.tsb", key.z, key.x, key.y),
            Self::Chunk { root } => format!("index/{}/{}/{}.json", root.z, root.x, root.y),
        }
    }
}

/// Fetch order: the collision region's wants before the view's, visible before invisible, then
/// larger screen-space error first.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct Priority {
    /// Wanted by the collision region ([`crate::client::collision`]): ahead of any view tile.
    pub collision: bool,
    pub visible: bool,
    /// Screen-space error in pixels of what stands in for the resource now (infinite: a hole).
    pub error_px: f64,
}

impl Priority {
    fn rank(&self) -> (bool, bool, f64) {
        (self.collision, self.visible, if self.error_px.is_nan() { 0.0 } else { self.error_px })
    }
}

/// The wants of one selection as scheduler input; index chunks come first (a missing chunk
/// stops refinement of its whole subtree).
#[must_use]
pub fn wants_of(wants: &[Want], missing_chunks: &[TileKey]) -> Vec<(Resource, Priority)> {
    missing_chunks
        .iter()
        .map(|&root| {
            (
                Resource::Chunk { root },
                Priority { visible: true, error_px: f64::INFINITY, ..Priority::default() },
            )
        })
        .chain(wants.iter().map(|w| {
            (
                Resource::Tile { key: w.key, level: w.level },
                Priority { visible: true, error_px: w.priority_px, ..Priority::default() },
            )
        }))
        .collect()
}

/// Request id, unique per scheduler.
pub type RequestId = u64;

/// How a request ended, as the transport saw it.
#[derive(Debug, Clone, PartialEq)]
pub enum Outcome {
    /// Success with this many body bytes.
    Ok { bytes: u64 },
    /// An HTTP status other than success, with the `Retry-After` in seconds if the response had
    /// one (see [`parse_retry_after`]).
    Status { code: u16, retry_after_s: Option<f64> },
    /// The transport's own timeout.
    Timeout,
    /// Connection refused, reset, DNS failure…
    Network(String),
}

/// What the scheduler asks of the network.
pub trait Transport {
    /// Starts fetching `resource`; report the result with [`Scheduler::complete`] and `id`.
    fn start(&mut self, id: RequestId, resource: Resource);
    /// Abandons a request; a late result for it is ignored.
    fn cancel(&mut self, id: RequestId);
}

/// Scheduler settings.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FetchParams {
    pub max_in_flight: usize,
    pub timeout_s: f64,
    pub backoff_base_s: f64,
    pub backoff_max_s: f64,
    pub cancel_grace_s: f64,
}

impl Default for FetchParams {
    fn default() -> Self {
        Self {
            max_in_flight: DEFAULT_MAX_IN_FLIGHT,
            timeout_s: DEFAULT_TIMEOUT_S,
            backoff_base_s: DEFAULT_BACKOFF_BASE_S,
            backoff_max_s: DEFAULT_BACKOFF_MAX_S,
            cancel_grace_s: DEFAULT_CANCEL_GRACE_S,
        }
    }
}

#[derive(Debug, Clone, Copy, PartialEq)]
enum State {
    Idle,
    InFlight { id: RequestId, started: f64 },
    Backoff { until: f64 },
    Failed { code: u16 },
}

#[derive(Debug, Clone, Copy)]
struct Entry {
    priority: Priority,
    wanted_at: f64,
    state: State,
    /// Failed attempts so far.
    failures: u32,
}

/// Counters over the scheduler's life.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct FetchStats {
    pub started: u64,
    pub succeeded: u64,
    pub bytes: u64,
    pub retries: u64,
    pub timeouts: u64,
    pub cancelled: u64,
    /// Requests failed for good (4xx other than 408/429).
    pub failed: u64,
    /// Seconds from start to success, per successful request.
    pub latencies_s: Vec<f64>,
}

/// A finished request, for the caller to act on (decode and insert a tile, add a chunk).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Finished {
    pub resource: Resource,
    /// True on success; false for a permanent failure (retries are not reported).
    pub ok: bool,
}

/// The request scheduler.
#[derive(Debug, Clone)]
pub struct Scheduler {
    params: FetchParams,
    entries: HashMap<Resource, Entry>,
    in_flight: HashMap<RequestId, Resource>,
    next_id: RequestId,
    pause_until: f64,
    stats: FetchStats,
}

impl Scheduler {
    #[must_use]
    pub fn new(params: FetchParams) -> Self {
        let params = FetchParams { max_in_flight: params.max_in_flight.max(1), ..params };
        Self {
            params,
            entries: HashMap::new(),
            in_flight: HashMap::new(),
            next_id: 1,
            pause_until: f64::NEG_INFINITY,
            stats: FetchStats::default(),
        }
    }

    #[must_use]
    pub fn stats(&self) -> &FetchStats {
        &self.stats
    }

    /// Requests running now.
    #[must_use]
    pub fn in_flight(&self) -> usize {
        self.in_flight.len()
    }

    /// Resources wanted and not yet fetched (idle, running or waiting to retry).
    #[must_use]
    pub fn pending(&self) -> usize {
        self.entries.values().filter(|e| !matches!(e.state, State::Failed { .. })).count()
    }

    /// True while a `Retry-After` holds back new requests.
    #[must_use]
    pub fn paused(&self, now: f64) -> bool {
        now < self.pause_until
    }

    /// Replaces the wanted set with this frame's wants. Resources not wanted any more are
    /// forgotten unless running (those are cancelled in [`Scheduler::pump`] after the grace).
    pub fn update(&mut self, wants: &[(Resource, Priority)], now: f64) {
        for &(r, priority) in wants {
            let e = self.entries.entry(r).or_insert(Entry {
                priority,
                wanted_at: now,
                state: State::Idle,
                failures: 0,
            });
            e.priority = priority;
            e.wanted_at = now;
        }
        self.entries.retain(|_, e| {
            e.wanted_at >= now || matches!(e.state, State::InFlight { .. } | State::Failed { .. })
        });
    }

    /// Times out, cancels and starts requests. Call once per frame (and when
    /// [`Scheduler::next_deadline`] passes).
    pub fn pump<T: Transport + ?Sized>(&mut self, now: f64, transport: &mut T) {
        // Timeouts and cancellations.
        let mut ended: Vec<(RequestId, Resource, bool)> = Vec::new();
        for (&id, &r) in &self.in_flight {
            if let Some(e) = self.entries.get(&r)
                && let State::InFlight { started, .. } = e.state
            {
                if now - started >= self.params.timeout_s {
                    ended.push((id, r, true));
                } else if now - e.wanted_at > self.params.cancel_grace_s {
                    ended.push((id, r, false));
                }
            }
        }
        ended.sort_by_key(|&(id, _, _)| id);
        for (id, r, timed_out) in ended {
            transport.cancel(id);
            if timed_out {
                self.complete(id, &Outcome::Timeout, now);
            } else {
                self.in_flight.remove(&id);
                self.entries.remove(&r);
                self.stats.cancelled += 1;
            }
        }
        for e in self.entries.values_mut() {
            if let State::Backoff { until } = e.state
                && until <= now
            {
                e.state = State::Idle;
            }
        }
        if now < self.pause_until {
            return;
        }
        let free = self.params.max_in_flight.saturating_sub(self.in_flight.len());
        if free == 0 {
            return;
        }
        let mut ready: Vec<(Resource, Priority)> = self
            .entries
            .iter()
            .filter(|(_, e)| e.state == State::Idle && e.wanted_at >= now - self.params.cancel_grace_s)
            .map(|(r, e)| (*r, e.priority))
            .collect();
        ready.sort_by(|a, b| {
            let (ca, va, ea) = a.1.rank();
            let (cb, vb, eb) = b.1.rank();
            cb.cmp(&ca).then(vb.cmp(&va)).then(eb.total_cmp(&ea)).then(a.0.cmp(&b.0))
        });
        for (r, _) in ready.into_iter().take(free) {
            let id = self.next_id;
            self.next_id += 1;
            if let Some(e) = self.entries.get_mut(&r) {
                e.state = State::InFlight { id, started: now };
            }
            self.in_flight.insert(id, r);
            self.stats.started += 1;
            transport.start(id, r);
        }
    }

    /// Records a request's outcome. Returns the resource when it is done for good (success or
    /// permanent failure); `None` for an unknown or cancelled id and for a retry.
    pub fn complete(&mut self, id: RequestId, outcome: &Outcome, now: f64) -> Option<Finished> {
        let r = self.in_flight.remove(&id)?;
        let e = self.entries.get_mut(&r)?;
        let started = match e.state {
            State::InFlight { id: cur, started } if cur == id => started,
            _ => return None,
        };
        let retry_after = match outcome {
            Outcome::Ok { bytes } => {
                self.stats.succeeded += 1;
                self.stats.bytes += bytes;
                self.stats.latencies_s.push(now - started);
                self.entries.remove(&r);
                return Some(Finished { resource: r, ok: true });
            }
            Outcome::Status { code, retry_after_s } if retryable(*code) => *retry_after_s,
            Outcome::Status { code, .. } => {
                self.stats.failed += 1;
                e.state = State::Failed { code: *code };
                return Some(Finished { resource: r, ok: false });
            }
            Outcome::Timeout => {
                self.stats.timeouts += 1;
                None
            }
            Outcome::Network(_) => None,
        };
        e.failures += 1;
        self.stats.retries += 1;
        let delay = match retry_after {
            Some(s) if s.is_finite() && s >= 0.0 => {
                let s = s.min(MAX_RETRY_AFTER_S);
                self.pause_until = self.pause_until.max(now + s);
                s
            }
            _ => backoff_delay(&self.params, &r, e.failures),
        };
        e.state = State::Backoff { until: now + delay };
        None
    }

    /// The earliest time after `now` something changes without new input (a backoff or pause
    /// ends, a request times out), for drivers that sleep between frames.
    #[must_use]
    pub fn next_deadline(&self, now: f64) -> Option<f64> {
        let mut t = f64::INFINITY;
        for e in self.entries.values() {
            match e.state {
                State::Backoff { until } => t = t.min(until),
                State::InFlight { started, .. } => t = t.min(started + self.params.timeout_s),
                _ => {}
            }
        }
        if self.pause_until > now {
            t = t.min(self.pause_until);
        }
        t.is_finite().then_some(t)
    }

    /// The status code of a resource that failed for good, if it did.
    #[must_use]
    pub fn failure(&self, r: &Resource) -> Option<u16> {
        match self.entries.get(r)?.state {
            State::Failed { code } => Some(code),
            _ => None,
        }
    }
}

/// Statuses worth retrying: request timeout, too many requests, and server errors.
#[must_use]
pub fn retryable(code: u16) -> bool {
    code == 408 || code == 429 || (500..600).contains(&code)
}

/// The delay before retry number `failures` (1-based): `base·2^(failures−1)` capped at the
/// maximum, then scaled into its upper half by a jitter derived from the resource and attempt,
/// so many clients (and many tiles) do not retry in lockstep yet runs stay reproducible.
#[must_use]
pub fn backoff_delay(p: &FetchParams, r: &Resource, failures: u32) -> f64 {
    let exp = failures.saturating_sub(1).min(60);
    let full = (p.backoff_base_s * 2f64.powi(exp as i32)).min(p.backoff_max_s);
    let mut h = std::hash::DefaultHasher::new();
    std::hash::Hash::hash(&(r, failures), &mut h);
    let u = (std::hash::Hasher::finish(&h) >> 11) as f64 / (1u64 << 53) as f64;
    full * (0.5 + 0.5 * u)
}

/// Parses a `Retry-After` header value: delay-seconds or an HTTP date (RFC 9110 §5.6.7, through
/// `httpdate`: the IMF-fixdate `Sun, 06 Nov 1994 08:49:37 GMT`, or the obsolete RFC 850 and
/// asctime forms every recipient must accept), relative to `now`. `None` when it is neither, or
/// names a date that does not exist (30 Feb, a wrong weekday).
#[must_use]
pub fn parse_retry_after(value: &str, now: SystemTime) -> Option<f64> {
    let v = value.trim();
    if !v.is_empty() && v.bytes().all(|b| b.is_ascii_digit()) {
        return v.parse::<u64>().ok().map(|s| s as f64);
    }
    let date = httpdate::parse_http_date(v).ok()?;
    Some(date.duration_since(now).unwrap_or(Duration::ZERO).as_secs_f64())
}

/// Decoded tiles under a byte budget, least recently used evicted first, drawn tiles pinned.
#[derive(Debug, Clone)]
pub struct TileCache<V> {
    budget: usize,
    used: usize,
    tick: u64,
    map: HashMap<(TileKey, u8), (V, usize, u64)>,
    order: BTreeMap<u64, (TileKey, u8)>,
    levels: HashMap<TileKey, u32>,
    pinned: HashSet<(TileKey, u8)>,
    /// Pinned whether resident or not ([`TileCache::set_held`]).
    held: HashSet<(TileKey, u8)>,
    evictions: u64,
}

impl<V> TileCache<V> {
    #[must_use]
    pub fn new(budget_bytes: usize) -> Self {
        Self {
            budget: budget_bytes,
            used: 0,
            tick: 0,
            map: HashMap::new(),
            order: BTreeMap::new(),
            levels: HashMap::new(),
            pinned: HashSet::new(),
            held: HashSet::new(),
            evictions: 0,
        }
    }

    #[must_use]
    pub fn used_bytes(&self) -> usize {
        self.used
    }

    #[must_use]
    pub fn budget_bytes(&self) -> usize {
        self.budget
    }

    #[must_use]
    pub fn len(&self) -> usize {
        self.map.len()
    }

    #[must_use]
    pub fn is_empty(&self) -> bool {
        self.map.is_empty()
    }

    #[must_use]
    pub fn evictions(&self) -> u64 {
        self.evictions
    }

    #[must_use]
    pub fn contains(&self, key: TileKey, level: u8) -> bool {
        self.map.contains_key(&(key, level))
    }

    /// Adds (or replaces) a decoded tile of `bytes` bytes and evicts other unpinned tiles to fit
    /// the budget; returns the evicted (tile, level) pairs. The new tile itself is kept even if
    /// it alone exceeds the budget, so it can be drawn this frame.
    pub fn insert(&mut self, key: TileKey, level: u8, value: V, bytes: usize) -> Vec<(TileKey, u8)> {
        self.remove(key, level);
        self.tick += 1;
        self.map.insert((key, level), (value, bytes, self.tick));
        self.order.insert(self.tick, (key, level));
        *self.levels.entry(key).or_insert(0) |= 1 << (level & 31);
        self.used += bytes;
        self.evict(Some((key, level)))
    }

    /// The tile, marking it recently used.
    pub fn get(&mut self, key: TileKey, level: u8) -> Option<&V> {
        let (_, _, t) = self.map.get_mut(&(key, level))?;
        self.order.remove(t);
        self.tick += 1;
        *t = self.tick;
        self.order.insert(self.tick, (key, level));
        self.map.get(&(key, level)).map(|(v, _, _)| v)
    }

    /// The tile without touching its recency.
    #[must_use]
    pub fn peek(&self, key: TileKey, level: u8) -> Option<&V> {
        self.map.get(&(key, level)).map(|(v, _, _)| v)
    }

    /// Replaces the pinned set with the tiles drawn this frame (fading ones included), marks them
    /// recently used and evicts down to the budget; returns the evicted pairs.
    pub fn set_drawn(&mut self, drawn: impl IntoIterator<Item = (TileKey, u8)>) -> Vec<(TileKey, u8)> {
        self.pinned.clear();
        for (k, l) in drawn {
            if self.map.contains_key(&(k, l)) {
                self.pinned.insert((k, l));
                let _ = self.get(k, l);
            }
        }
        self.evict(None)
    }

    /// Replaces the held set: these (tile, level) pairs are never evicted, including ones that
    /// arrive later (unlike [`TileCache::set_drawn`], which pins only what is resident). Evicts
    /// down to the budget what is no longer held; returns the evicted pairs.
    pub fn set_held(&mut self, held: impl IntoIterator<Item = (TileKey, u8)>) -> Vec<(TileKey, u8)> {
        self.held.clear();
        self.held.extend(held);
        self.evict(None)
    }

    fn remove(&mut self, key: TileKey, level: u8) -> Option<V> {
        let (v, bytes, t) = self.map.remove(&(key, level))?;
        self.order.remove(&t);
        self.used -= bytes;
        if let Some(m) = self.levels.get_mut(&key) {
            *m &= !(1 << (level & 31));
            if *m == 0 {
                self.levels.remove(&key);
            }
        }
        Some(v)
    }

    fn evict(&mut self, keep: Option<(TileKey, u8)>) -> Vec<(TileKey, u8)> {
        let mut out = Vec::new();
        if self.used <= self.budget {
            return out;
        }
        let victims: Vec<(TileKey, u8)> = {
            let mut need = self.used - self.budget;
            let mut v = Vec::new();
            for &k in self.order.values() {
                if need == 0 {
                    break;
                }
                if self.pinned.contains(&k) || self.held.contains(&k) || Some(k) == keep {
                    continue;
                }
                let bytes = self.map.get(&k).map_or(0, |e| e.1);
                need = need.saturating_sub(bytes.max(1));
                v.push(k);
            }
            v
        };
        for (k, l) in victims {
            if self.remove(k, l).is_some() {
                self.evictions += 1;
                out.push((k, l));
            }
        }
        out
    }
}

impl<V> Residency for TileCache<V> {
    fn levels(&self, key: TileKey) -> u32 {
        self.levels.get(&key).copied().unwrap_or(0)
    }
}

/// Memory a decoded blob holds (positions, normals, indices), for the cache's byte budget.
#[must_use]
pub fn decoded_bytes(blob: &crate::codec::Blob) -> usize {
    use crate::codec::Geometry;
    match &blob.geometry {
        Geometry::Mesh(m) => m.positions.len() * 24 + m.triangles.len() * 12,
        Geometry::Points(p) => p.positions.len() * 24 + p.normals.len() * 12,
    }
}

#[cfg(test)]
#[path = "fetch_tests.rs"]
mod tests;
