//! On-demand baking: a bounded pool of worker threads with a bounded queue, and single flight —
//! every request for a node that is being baked waits for that one bake (a node bakes all its
//! levels at once, so requests for different levels of one node share it too). When the queue
//! is full the request is refused (`503` + `Retry-After`) rather than queued without limit.

use std::collections::HashMap;
use std::panic::AssertUnwindSafe;
use std::sync::atomic::Ordering;
use std::sync::mpsc::{Receiver, SyncSender, TrySendError};
use std::sync::{Arc, Mutex};

use tokio::sync::watch;

use super::metrics::Metrics;
use super::problem::Problem;
use super::registry::Tileset;
use crate::bake::PointBaker;
use crate::tiling::TileKey;

/// `None` while baking; then the bake's outcome.
pub type Outcome = Option<Result<(), String>>;

/// Seconds a client is asked to wait when the queue is full.
pub const QUEUE_FULL_RETRY_AFTER_S: u32 = 2;

struct Job {
    ts: Arc<Tileset>,
    key: TileKey,
    done: watch::Sender<Outcome>,
}

type Flights = Mutex<HashMap<(String, TileKey), watch::Receiver<Outcome>>>;

pub struct Bakery {
    tx: Mutex<Option<SyncSender<Job>>>,
    flights: Arc<Flights>,
    metrics: Arc<Metrics>,
}

impl Bakery {
    /// Starts `workers` threads fed by a queue of `queue` jobs.
    pub fn start(workers: usize, queue: usize, metrics: Arc<Metrics>, baker: &Arc<PointBaker>) -> Self {
        let (tx, rx) = std::sync::mpsc::sync_channel::<Job>(queue);
        let rx = Arc::new(Mutex::new(rx));
        let flights: Arc<Flights> = Arc::default();
        for i in 0..workers {
            let (rx, flights, metrics, baker) = (rx.clone(), flights.clone(), metrics.clone(), baker.clone());
            let spawned = std::thread::Builder::new()
                .name(format!("bake-{i}"))
                .spawn(move || worker(&rx, &flights, &metrics, &baker));
            if let Err(e) = spawned {
                tracing::error!(error = %e, "cannot start a bake worker");
            }
        }
        Self { tx: Mutex::new(Some(tx)), flights, metrics }
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

fn worker(rx: &Mutex<Receiver<Job>>, flights: &Flights, metrics: &Metrics, baker: &PointBaker) {
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
                crate::bake::bake_one_node(&src.raster, key, &src.opts, baker, &ts.store)
            }))
            .map_err(|_| "the bake panicked".to_owned())
            .and_then(|r| r.map(|_| ()).map_err(|e| e.to_string())),
            None => Err("tileset has no source raster".to_owned()),
        };
        metrics.bakes_running.fetch_sub(1, Ordering::Relaxed);
        match &result {
            Ok(()) => {
                metrics.bakes_done.fetch_add(1, Ordering::Relaxed);
                tracing::info!(tileset = %ts.name, tile = %key, "baked on demand");
            }
            Err(e) => {
                metrics.bakes_failed.fetch_add(1, Ordering::Relaxed);
                tracing::error!(tileset = %ts.name, tile = %key, error = %e, "on-demand bake failed");
            }
        }
        if let Ok(mut f) = flights.lock() {
            f.remove(&(ts.name.clone(), key));
        }
        // No receiver left (every waiter timed out) is fine: the blobs are on disk for the next.
        let _ = done.send(Some(result));
    }
}
