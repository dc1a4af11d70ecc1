//! On-demand baking: a bounded pool of worker threads with a bounded queue, and single flight —
//! every request for a node that is being baked waits for that one bake (a node bakes all its
//! levels at once, so requests for different levels of one node share it too). When the queue
//! is full the request is refused (`503` + `Retry-After`) rather than queued without limit.
//! A bake that fails is not retried for `FAILED_BAKE_RETRY_S`: requests for that node meanwhile
//! get the same error at once instead of each running the failing bake again.

use std::collections::HashMap;
use std::panic::AssertUnwindSafe;
use std::sync::atomic::Ordering;
use std::sync::mpsc::{Receiver, SyncSender, TrySendError};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use tokio::sync::watch;

use super::metrics::Metrics;
use super::problem::Problem;
use super::registry::Tileset;
use crate::lod::PointBaker;
use crate::tiling::TileKey;

/// `None` while baking; then the bake's outcome.
pub type Outcome = Option<Result<(), BakeFailure>>;

/// Why an on-demand bake of a node gave no blobs. Cloned to every request waiting for the bake
/// (so the bake's own error is shared behind an `Arc`).
#[derive(Debug, Clone, thiserror::Error)]
pub enum BakeFailure {
    #[error(transparent)]
    Bake(Arc<crate::bake::BakeError>),
    #[error("the bake panicked")]
    Panicked,
    #[error("tileset has no source raster")]
    NoSource,
    /// The node's bake failed less than [`FAILED_BAKE_RETRY_S`] ago; it is not tried again yet.
    #[error("{0} (not retried until {FAILED_BAKE_RETRY_S} s after the failure)")]
    Recent(#[source] Box<BakeFailure>),
}

/// Seconds a client is asked to wait when the queue is full.
pub const QUEUE_FULL_RETRY_AFTER_S: u32 = 2;
/// Seconds a failed on-demand bake of a node is remembered: its error is answered for that
/// node meanwhile, and the bake is tried again only after. Long enough that a client retrying
/// in a loop cannot keep a worker busy on a bake that fails; short enough that a transient
/// cause (a full disk freed, a permission fixed) clears by itself.
pub const FAILED_BAKE_RETRY_S: u64 = 30;
/// Failures remembered at most (the oldest are forgotten first): bounded memory.
const MAX_FAILURES: usize = 10_000;

struct Job {
    ts: Arc<Tileset>,
    key: TileKey,
    done: watch::Sender<Outcome>,
}

type Flights = Mutex<HashMap<(String, TileKey), watch::Receiver<Outcome>>>;
/// Recent failed bakes by node: when, and the error.
type Failures = Mutex<HashMap<(String, TileKey), (Instant, BakeFailure)>>;

pub struct Bakery {
    tx: Mutex<Option<SyncSender<Job>>>,
    flights: Arc<Flights>,
    failures: Arc<Failures>,
    metrics: Arc<Metrics>,
}

impl Bakery {
    /// Starts `workers` threads fed by a queue of `queue` jobs.
    pub fn start(workers: usize, queue: usize, metrics: Arc<Metrics>, baker: &Arc<PointBaker>) -> Self {
        let (tx, rx) = std::sync::mpsc::sync_channel::<Job>(queue);
        let rx = Arc::new(Mutex::new(rx));
        let flights: Arc<Flights> = Arc::default();
        let failures: Arc<Failures> = Arc::default();
        for i in 0..workers {
            let (rx, flights, metrics, baker) = (rx.clone(), flights.clone(), metrics.clone(), baker.clone());
            let failures = failures.clone();
            let spawned = std::thread::Builder::new()
                .name(format!("bake-{i}"))
                .spawn(move || worker(&rx, &flights, &failures, &metrics, &baker));
            if let Err(e) = spawned {
                tracing::error!(error = %e, "cannot start a bake worker");
            }
        }
        Self { tx: Mutex::new(Some(tx)), flights, failures, metrics }
    }

    /// Stops taking jobs; workers finish the jobs already queued and exit.
    pub fn close(&self) {
        if let Ok(mut tx) = self.tx.lock() {
            tx.take();
        }
    }

    /// Joins the bake of `key` in progress, or queues one. `level_path` is the blob the caller
    /// missed: checked again under the lock, so a bake that finished since the caller looked is
    /// not repeated.
    pub fn request(
        &self,
        ts: &Arc<Tileset>,
        key: TileKey,
        level_path: &std::path::Path,
    ) -> Result<watch::Receiver<Outcome>, Problem> {
        let mut flights = self
            .flights
            .lock()
            .map_err(|_| Problem::internal("bake-pool", "the bake pool is unavailable"))?;
        if let Some(rx) = flights.get(&(ts.name.clone(), key)) {
            return Ok(rx.clone());
        }
        if level_path.exists() {
            return Ok(watch::channel(Some(Ok(()))).1);
        }
        if let Some(e) = self.recent_failure(&ts.name, key) {
            return Ok(watch::channel(Some(Err(e))).1);
        }
        let (done, rx) = watch::channel(None);
        let tx =
            self.tx.lock().map_err(|_| Problem::internal("bake-pool", "the bake pool is unavailable"))?;
        let Some(tx) = tx.as_ref() else {
            return Err(Problem::unavailable("shutting-down", "the server is shutting down", 5));
        };
        match tx.try_send(Job { ts: ts.clone(), key, done }) {
            Ok(()) => {
                self.metrics.bake_queue_depth.fetch_add(1, Ordering::Relaxed);
                flights.insert((ts.name.clone(), key), rx.clone());
                Ok(rx)
            }
            Err(TrySendError::Full(_)) => {
                self.metrics.shed.fetch_add(1, Ordering::Relaxed);
                Err(Problem::unavailable(
                    "bake-queue-full",
                    format!(
                        "tile {key} of {:?} is not baked yet and the bake queue is full; retry later",
                        ts.name
                    ),
                    QUEUE_FULL_RETRY_AFTER_S,
                ))
            }
            Err(TrySendError::Disconnected(_)) => {
                Err(Problem::unavailable("shutting-down", "the server is shutting down", 5))
            }
        }
    }
}

impl Bakery {
    /// The error of a bake of `key` that failed less than `FAILED_BAKE_RETRY_S` ago.
    fn recent_failure(&self, tileset: &str, key: TileKey) -> Option<BakeFailure> {
        let mut f = self.failures.lock().ok()?;
        let k = (tileset.to_owned(), key);
        let (at, e) = f.get(&k)?;
        if at.elapsed() < Duration::from_secs(FAILED_BAKE_RETRY_S) {
            return Some(BakeFailure::Recent(Box::new(e.clone())));
        }
        f.remove(&k);
        None
    }
}

fn remember_failure(failures: &Failures, tileset: &str, key: TileKey, error: &BakeFailure) {
    let Ok(mut f) = failures.lock() else { return };
    if f.len() >= MAX_FAILURES {
        let horizon = Duration::from_secs(FAILED_BAKE_RETRY_S);
        f.retain(|_, (at, _)| at.elapsed() < horizon);
        if f.len() >= MAX_FAILURES
            && let Some(oldest) = f.iter().min_by_key(|(_, (at, _))| *at).map(|(k, _)| k.clone())
        {
            f.remove(&oldest);
        }
    }
    f.insert((tileset.to_owned(), key), (Instant::now(), error.clone()));
}

fn worker(
    rx: &Mutex<Receiver<Job>>,
    flights: &Flights,
    failures: &Failures,
    metrics: &Metrics,
    baker: &PointBaker,
) {
    loop {
        let job = {
            let Ok(rx) = rx.lock() else { return };
            match rx.recv() {
                Ok(j) => j,
                Err(_) => return,
            }
        };
        metrics.bake_queue_depth.fetch_sub(1, Ordering::Relaxed);
        metrics.bakes_running.fetch_add(1, Ordering::Relaxed);
        let Job { ts, key, done } = job;
        let result = match &ts.source {
            Some(src) => std::panic::catch_unwind(AssertUnwindSafe(|| {
                crate::bake::bake_node(&src.raster, key, &src.opts, baker, &ts.store)
            }))
            .map_err(|_| BakeFailure::Panicked)
            .and_then(|r| r.map(|_| ()).map_err(|e| BakeFailure::Bake(Arc::new(e)))),
            None => Err(BakeFailure::NoSource),
        };
        metrics.bakes_running.fetch_sub(1, Ordering::Relaxed);
        match &result {
            Ok(()) => {
                metrics.bakes_done.fetch_add(1, Ordering::Relaxed);
                tracing::info!(tileset = %ts.name, tile = %key, "baked on demand");
            }
            Err(e) => {
                metrics.bakes_failed.fetch_add(1, Ordering::Relaxed);
                tracing::error!(
                    tileset = %ts.name, tile = %key, error = %e, retry_after_s = FAILED_BAKE_RETRY_S,
                    "on-demand bake failed"
                );
                // Before the flight is removed: a request arriving in between finds either.
                remember_failure(failures, &ts.name, key, e);
            }
        }
        if let Ok(mut f) = flights.lock() {
            f.remove(&(ts.name.clone(), key));
        }
        // No receiver left (every waiter timed out) is fine: the blobs are on disk for the next.
        let _ = done.send(Some(result));
    }
}
