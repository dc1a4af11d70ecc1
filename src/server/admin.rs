//! The admin API (bearer token, `--admin-token`): upload a raster and bake it as a new tileset
//! (`POST /tilesets/{name}`, streamed to disk and size-limited), follow the bake job
//! (`GET /jobs/{id}`) or cancel it (`DELETE /jobs/{id}`), delete a tileset
//! (`DELETE /tilesets/{name}`). Uploads bake one at a time on their own thread into a hidden
//! staging directory that is renamed into place when complete, so readers never see a
//! half-baked tileset. A running job stops at its next node when cancelled or past
//! `--job-timeout`; ended jobs are forgotten after `--job-ttl`.

use std::collections::HashMap;
use std::panic::AssertUnwindSafe;
use std::path::{Path as FsPath, PathBuf};
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use axum::body::Body;
use axum::extract::{Path, Query, State};
use axum::http::{HeaderMap, HeaderValue, StatusCode, Uri, header};
use axum::response::{IntoResponse, Response};
use http_body_util::BodyExt;
use serde::Deserialize;
use tokio::io::AsyncWriteExt;
use tokio::sync::{Notify, Semaphore};

use super::auth::check_bearer;
use super::problem::Problem;
use super::{App, valid_name};
use crate::bake::{BakeOptions, Progress};
use crate::lod::PointBaker;
use crate::raster::{HeightEncoding, LoadOptions, Overrides};
use crate::store::Store;

/// Seconds a running job gets to stop at its next node once cancelled or past `--job-timeout`;
/// after that the job is ended anyway and the upload slot released, whatever its bake thread
/// is doing (the thread's late result is discarded and its staging directory removed).
pub const JOB_STOP_GRACE_S: u64 = 30;

const QUEUED: &str = "queued";
const RUNNING: &str = "running";
const DONE: &str = "done";
const FAILED: &str = "failed";
const CANCELLED: &str = "cancelled";

fn terminal(state: &str) -> bool {
    matches!(state, DONE | FAILED | CANCELLED)
}

struct JobState {
    state: &'static str,
    error: Option<String>,
    /// When the job reached a terminal state (for `--job-ttl`).
    finished: Option<Instant>,
    /// When a running job must stop (`--job-timeout` after it started running).
    deadline: Option<Instant>,
}

/// A bake job started by an upload.
pub struct Job {
    id: String,
    tileset: String,
    state: Mutex<JobState>,
    total: AtomicU64,
    done: AtomicU64,
    /// `DELETE /jobs/{id}` asked it to stop.
    cancel: AtomicBool,
    /// Wakes the job's supervisor when `cancel` is set.
    wake: Notify,
    timeout: Duration,
}

impl Job {
    fn json(&self) -> serde_json::Value {
        let (state, error) = self.state.lock().map_or(("unknown", None), |g| (g.state, g.error.clone()));
        serde_json::json!({
            "id": self.id,
            "tileset": self.tileset,
            "state": state,
            "nodes_total": self.total.load(Ordering::Relaxed),
            "nodes_done": self.done.load(Ordering::Relaxed),
            "cancel_requested": self.cancel.load(Ordering::Relaxed),
            "error": error,
        })
    }

    fn state(&self) -> &'static str {
        self.state.lock().map_or(FAILED, |g| g.state)
    }

    /// Starts running: the `--job-timeout` clock starts now.
    fn set_running(&self) {
        if let Ok(mut g) = self.state.lock()
            && !terminal(g.state)
        {
            g.state = RUNNING;
            g.deadline = Some(Instant::now() + self.timeout);
        }
    }

    /// Ends the job, unless it has ended already (the first end wins). Returns whether it did.
    fn finish(&self, state: &'static str, error: Option<String>) -> bool {
        let Ok(mut g) = self.state.lock() else { return false };
        if terminal(g.state) {
            return false;
        }
        *g = JobState { state, error, finished: Some(Instant::now()), deadline: g.deadline };
        true
    }

    fn timeout_message(&self) -> String {
        format!("the job ran longer than --job-timeout ({} s) and was stopped", self.timeout.as_secs())
    }

    fn past_deadline(&self) -> bool {
        self.state.lock().ok().and_then(|g| g.deadline).is_some_and(|d| Instant::now() >= d)
    }

    /// Completes once `DELETE /jobs/{id}` has asked the job to stop.
    async fn cancel_requested(&self) {
        while !self.cancel.load(Ordering::Acquire) {
            self.wake.notified().await;
        }
    }
}

impl Progress for Job {
    fn start(&self, total: u64, resumed: u64) {
        self.total.store(total, Ordering::Relaxed);
        self.done.store(resumed, Ordering::Relaxed);
    }
    fn node_done(&self) {
        self.done.fetch_add(1, Ordering::Relaxed);
    }
    /// Checked by the bake before every node: stops it when cancelled or past its deadline.
    fn cancelled(&self) -> Option<String> {
        if self.cancel.load(Ordering::Acquire) {
            return Some(format!("job {} was cancelled", self.id));
        }
        self.past_deadline().then(|| self.timeout_message())
    }
}

pub struct Jobs {
    map: Mutex<HashMap<String, Arc<Job>>>,
    next: AtomicU64,
    /// Uploaded bakes run one at a time (each already uses every core): the one permit is held
    /// by the job's supervisor task — never by the bake thread — so it is given back when the
    /// job ends, is cancelled or times out, whatever the bake thread does.
    slot: Arc<Semaphore>,
}

impl Jobs {
    pub fn new() -> Self {
        Self { map: Mutex::new(HashMap::new()), next: AtomicU64::new(0), slot: Arc::new(Semaphore::new(1)) }
    }

    /// Forgets jobs that ended more than `ttl` ago.
    fn expire(&self, ttl: Duration) {
        if let Ok(mut m) = self.map.lock() {
            m.retain(|_, j| j.state.lock().map_or(true, |g| g.finished.is_none_or(|t| t.elapsed() < ttl)));
        }
    }

    fn get(&self, id: &str, ttl: Duration) -> Option<Arc<Job>> {
        self.expire(ttl);
        self.map.lock().ok().and_then(|m| m.get(id).cloned())
    }
}

fn admin(app: &App, headers: &HeaderMap) -> Result<(), Problem> {
    match &app.config.admin_token {
        Some(t) => check_bearer(headers, t, "the admin API"),
        None => Err(Problem::new(
            StatusCode::FORBIDDEN,
            "admin-disabled",
            "the admin API is disabled: start the server with --admin-token",
        )),
    }
}

/// Bake options of an upload, from the query string.
#[derive(Debug, Default, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct UploadParams {
    encoding: Option<String>,
    cell_size: Option<f64>,
    tile_size: Option<u32>,
    max_error: Option<f64>,
    levels: Option<u8>,
}

fn problem_of(e: &axum::extract::rejection::PathRejection) -> Problem {
    Problem::bad_request(e.body_text())
}

pub async fn upload(
    State(app): State<Arc<App>>,
    path: Result<Path<String>, axum::extract::rejection::PathRejection>,
    uri: Uri,
    headers: HeaderMap,
    body: Body,
) -> Result<Response, Problem> {
    admin(&app, &headers)?;
    let Path(name) = path.map_err(|e| problem_of(&e))?;
    if !valid_name(&name) {
        return Err(Problem::bad_request(format!(
            "tileset name {name:?} is invalid: 1 to 64 of a-z, 0-9, _ and -"
        )));
    }
    let Query(params) =
        Query::<UploadParams>::try_from_uri(&uri).map_err(|e| Problem::bad_request(e.body_text()))?;
    let encoding = match params.encoding.as_deref() {
        None => None,
        Some("gray16") => Some(HeightEncoding::Gray16),
        Some("terrain-rgb") => Some(HeightEncoding::TerrainRgb),
        Some("terrarium") => Some(HeightEncoding::Terrarium),
        Some(o) => {
            return Err(Problem::bad_request(format!(
                "encoding {o:?} is not gray16, terrain-rgb or terrarium"
            )));
        }
    };
    let d = BakeOptions::default();
    let opts = BakeOptions {
        tile_size: params.tile_size.unwrap_or(d.tile_size),
        max_error: params.max_error.unwrap_or(d.max_error),
        levels: params.levels.unwrap_or(d.levels),
        point_levels: d.point_levels,
    };
    crate::bake::check_options(&opts).map_err(|e| Problem::bad_request(e.to_string()))?;
    // Checked before anything is stored (the raster's own frame is checked when it is read).
    if let Some(c) = params.cell_size
        && !(crate::raster::MIN_CELL_SIZE..=crate::raster::MAX_CELL_SIZE).contains(&c)
    {
        return Err(Problem::bad_request(format!(
            "cell_size {c:?} is outside {:e}..{:e} world units",
            crate::raster::MIN_CELL_SIZE,
            crate::raster::MAX_CELL_SIZE
        )));
    }
    let root = app.registry.root().to_owned();
    if app.registry.get(&name).is_some() || tokio::fs::try_exists(root.join(&name)).await.unwrap_or(false) {
        return Err(Problem::new(
            StatusCode::CONFLICT,
            "exists",
            format!("tileset {name:?} already exists; DELETE it first"),
        ));
    }
    let limit = app.config.max_body_bytes;
    let declared = headers.get(header::CONTENT_LENGTH).and_then(|v| v.to_str().ok()?.parse::<u64>().ok());
    let too_large = || {
        Problem::new(
            StatusCode::PAYLOAD_TOO_LARGE,
            "too-large",
            format!("the upload is larger than {limit} bytes"),
        )
    };
    if declared.is_some_and(|n| n > limit) {
        return Err(too_large());
    }
    let id = format!("j{}", app.jobs.next.fetch_add(1, Ordering::Relaxed) + 1);
    let upload = root.join(format!(".upload-{id}"));
    if let Err(p) = stream_to(&upload, body, limit).await {
        let _ = tokio::fs::remove_file(&upload).await;
        return Err(p.unwrap_or_else(too_large));
    }
    app.jobs.expire(app.config.job_ttl);
    let job = Arc::new(Job {
        id: id.clone(),
        tileset: name.clone(),
        state: Mutex::new(JobState { state: QUEUED, error: None, finished: None, deadline: None }),
        total: AtomicU64::new(0),
        done: AtomicU64::new(0),
        cancel: AtomicBool::new(false),
        wake: Notify::new(),
        timeout: app.config.job_timeout,
    });
    if let Ok(mut m) = app.jobs.map.lock() {
        m.insert(id.clone(), job.clone());
    }
    let reply = job.json();
    let location = format!("/jobs/{id}");
    let work = Work { root, upload, name, encoding, cell_size: params.cell_size, opts };
    tokio::spawn(supervise(app.clone(), job, work));
    let mut r = (StatusCode::ACCEPTED, axum::Json(reply)).into_response();
    if let Ok(v) = HeaderValue::from_str(&location) {
        r.headers_mut().insert(header::LOCATION, v);
    }
    Ok(r)
}

/// Why a bake job's thread gave no tileset; its text is the job's `error`.
#[derive(Debug, thiserror::Error)]
enum JobError {
    /// Cancelled or past `--job-timeout` before the bake began: the reason.
    #[error("{0}")]
    Stopped(String),
    #[error(transparent)]
    Load(#[from] crate::raster::RasterError),
    #[error(transparent)]
    Bake(#[from] crate::bake::BakeError),
    #[error("the bake panicked")]
    Panicked,
    #[error("the bake thread ended without a result")]
    ThreadLost,
}

/// What a job bakes.
struct Work {
    root: PathBuf,
    upload: PathBuf,
    name: String,
    encoding: Option<HeightEncoding>,
    cell_size: Option<f64>,
    opts: BakeOptions,
}

/// Runs one job: waits for the upload slot (or a cancel), bakes on its own thread, stops it at
/// the next node when cancelled or past `--job-timeout`, publishes the tileset only if the job
/// is still running when the bake completes, and gives the slot back in every case.
async fn supervise(app: Arc<App>, job: Arc<Job>, work: Work) {
    let permit = tokio::select! {
        p = app.jobs.slot.clone().acquire_owned() => p.ok(),
        () = job.cancel_requested() => None,
    };
    let Some(permit) = permit.filter(|_| !job.cancel.load(Ordering::Acquire)) else {
        job.finish(CANCELLED, Some(format!("job {} was cancelled before it started", job.id)));
        let _ = tokio::fs::remove_file(&work.upload).await;
        tracing::info!(job = %job.id, "queued bake job cancelled");
        return;
    };
    job.set_running();
    let (tx, rx) = tokio::sync::oneshot::channel::<Result<PathBuf, JobError>>();
    let (job2, baker, upload) = (job.clone(), app.baker.clone(), work.upload.clone());
    let spawned = std::thread::Builder::new().name(format!("job-{}", job.id)).spawn(move || {
        let r =
            std::panic::catch_unwind(AssertUnwindSafe(|| bake_to_staging(&work, &job2.id, &baker, &job2)))
                .unwrap_or(Err(JobError::Panicked));
        let _ = std::fs::remove_file(&work.upload);
        // Nobody listening (the job was ended without us): discard what was baked.
        if let Err(Ok(staging)) = tx.send(r) {
            let _ = std::fs::remove_dir_all(staging);
        }
    });
    if spawned.is_err() {
        job.finish(FAILED, Some("cannot start the bake thread".to_owned()));
        let _ = tokio::fs::remove_file(&upload).await;
        return;
    }
    let deadline = job.state.lock().ok().and_then(|g| g.deadline).unwrap_or_else(Instant::now);
    let grace = Duration::from_secs(JOB_STOP_GRACE_S);
    let stopped_late = async {
        tokio::select! {
            () = tokio::time::sleep_until((deadline + grace).into()) => FAILED,
            () = async { job.cancel_requested().await; tokio::time::sleep(grace).await; } => CANCELLED,
        }
    };
    let outcome = tokio::select! {
        r = rx => Some(r.unwrap_or(Err(JobError::ThreadLost))),
        state = stopped_late => {
            let why = if state == FAILED { job.timeout_message() } else { format!("job {} was cancelled", job.id) };
            tracing::error!(job = %job.id, "bake job did not stop within {JOB_STOP_GRACE_S} s; ended without it");
            job.finish(state, Some(format!("{why}; its bake did not stop within {JOB_STOP_GRACE_S} s and was abandoned")));
            let _ = tokio::fs::remove_file(&upload).await;
            None
        }
    };
    if let Some(r) = outcome {
        // Off the async workers: it renames or removes the staged tileset and rescans the store.
        let (a, j) = (app.clone(), job.clone());
        if tokio::task::spawn_blocking(move || conclude(&a, &j, r)).await.is_err() {
            job.finish(FAILED, Some("publishing the baked tileset failed".to_owned()));
        }
    }
    drop(permit);
}

/// The end of a job whose bake thread returned: publish the staged tileset if the job still
/// may (not cancelled, not past its deadline), else discard it.
fn conclude(app: &App, job: &Job, r: Result<PathBuf, JobError>) {
    let stop = job.cancelled();
    match r {
        Ok(staging) => {
            if let Some(why) = stop {
                let _ = std::fs::remove_dir_all(&staging);
                let state = if job.cancel.load(Ordering::Acquire) { CANCELLED } else { FAILED };
                job.finish(state, Some(why));
                return;
            }
            let target = app.registry.root().join(&job.tileset);
            // Under the job's lock, so no cancel slips between the check and the rename.
            let Ok(mut g) = job.state.lock() else { return };
            if terminal(g.state) {
                let _ = std::fs::remove_dir_all(&staging);
                return;
            }
            let published = if target.exists() {
                let _ = std::fs::remove_dir_all(&staging);
                Err(format!("tileset {:?} appeared while baking; upload discarded", job.tileset))
            } else {
                std::fs::rename(&staging, &target).map_err(|e| {
                    let _ = std::fs::remove_dir_all(&staging);
                    format!("{}: {e}", target.display())
                })
            };
            let (state, error) = match published {
                Ok(()) => (DONE, None),
                Err(e) => (FAILED, Some(e)),
            };
            *g = JobState {
                state,
                error: error.clone(),
                finished: Some(Instant::now()),
                deadline: g.deadline,
            };
            drop(g);
            match error {
                None => {
                    tracing::info!(job = %job.id, tileset = %job.tileset, "bake job done");
                    app.rescan();
                }
                Some(e) => tracing::error!(job = %job.id, error = %e, "bake job failed"),
            }
        }
        Err(e) => {
            let state = match stop {
                Some(_) if job.cancel.load(Ordering::Acquire) => CANCELLED,
                Some(why) => {
                    tracing::error!(job = %job.id, "{why}");
                    job.finish(FAILED, Some(why));
                    return;
                }
                None => FAILED,
            };
            if state == FAILED {
                tracing::error!(job = %job.id, error = %e, "bake job failed");
            } else {
                tracing::info!(job = %job.id, "running bake job cancelled");
            }
            job.finish(state, Some(e.to_string()));
        }
    }
}

/// Streams the body to `path`; `Err(None)` when it exceeds `limit`.
async fn stream_to(path: &FsPath, body: Body, limit: u64) -> Result<(), Option<Problem>> {
    let io = |e: std::io::Error| {
        tracing::error!(path = %path.display(), error = %e, "cannot store upload");
        Some(Problem::internal("store-io", "the upload could not be stored"))
    };
    // A new file, never one already there: job ids restart at 1, and a `.upload-jN` planted in
    // the store (a link to a file elsewhere, a FIFO) must not be written through or waited on.
    let mut file = tokio::fs::OpenOptions::new().write(true).create_new(true).open(path).await.map_err(io)?;
    let mut body = body;
    let mut n = 0u64;
    while let Some(frame) = body.frame().await {
        let frame = frame.map_err(|e| Some(Problem::bad_request(format!("upload interrupted: {e}"))))?;
        if let Ok(data) = frame.into_data() {
            n += data.len() as u64;
            if n > limit {
                return Err(None);
            }
            file.write_all(&data).await.map_err(io)?;
        }
    }
    file.sync_all().await.map_err(io)?;
    Ok(())
}

/// Loads the upload and bakes it into the job's staging directory `.job-{id}`; returns that
/// directory, complete. A failed or stopped bake removes it.
fn bake_to_staging(work: &Work, id: &str, baker: &PointBaker, job: &Job) -> Result<PathBuf, JobError> {
    let load = LoadOptions {
        encoding: work.encoding,
        overrides: Overrides { cell_size: work.cell_size, ..Overrides::default() },
        ..LoadOptions::default()
    };
    if let Some(why) = job.cancelled() {
        return Err(JobError::Stopped(why));
    }
    let raster = crate::raster::load(&work.upload, &load)?;
    super::tileable(&work.upload, &raster)?;
    let staging: PathBuf = work.root.join(format!(".job-{id}"));
    let r = crate::bake::bake_terrain(&raster, &work.name, &work.opts, baker, &Store::new(&staging), job);
    if let Err(e) = r {
        let _ = std::fs::remove_dir_all(&staging);
        return Err(e.into());
    }
    Ok(staging)
}

pub async fn job(
    State(app): State<Arc<App>>,
    path: Result<Path<String>, axum::extract::rejection::PathRejection>,
    headers: HeaderMap,
) -> Result<Response, Problem> {
    admin(&app, &headers)?;
    let Path(id) = path.map_err(|e| problem_of(&e))?;
    let job = app.jobs.get(&id, app.config.job_ttl);
    let job = job.ok_or_else(|| {
        Problem::not_found(format!(
            "no job {id:?} (jobs are forgotten {} s after they end)",
            app.config.job_ttl.as_secs()
        ))
    })?;
    let mut r = axum::Json(job.json()).into_response();
    r.headers_mut().insert(header::CACHE_CONTROL, HeaderValue::from_static("no-store"));
    Ok(r)
}

/// `DELETE /jobs/{id}`: a queued job is cancelled at once (`204`); a running one is asked to
/// stop at its next node (`202`, the job as it is; its state becomes `cancelled` when it has
/// stopped); a job already cancelled answers `204` again; a finished or failed one `409`.
pub async fn cancel(
    State(app): State<Arc<App>>,
    path: Result<Path<String>, axum::extract::rejection::PathRejection>,
    headers: HeaderMap,
) -> Result<Response, Problem> {
    admin(&app, &headers)?;
    let Path(id) = path.map_err(|e| problem_of(&e))?;
    let job = app.jobs.get(&id, app.config.job_ttl);
    let job = job.ok_or_else(|| Problem::not_found(format!("no job {id:?}")))?;
    match job.state() {
        CANCELLED => return Ok(StatusCode::NO_CONTENT.into_response()),
        s @ (DONE | FAILED) => {
            return Err(Problem::new(
                StatusCode::CONFLICT,
                "job-ended",
                format!("job {id:?} has already ended ({s})"),
            ));
        }
        _ => {}
    }
    job.cancel.store(true, Ordering::Release);
    job.wake.notify_one();
    if job.state() == QUEUED
        && job.finish(CANCELLED, Some(format!("job {id} was cancelled before it started")))
    {
        tracing::info!(job = %id, "queued bake job cancelled");
        return Ok(StatusCode::NO_CONTENT.into_response());
    }
    if job.state() == CANCELLED {
        return Ok(StatusCode::NO_CONTENT.into_response());
    }
    tracing::info!(job = %id, "cancelling running bake job");
    let mut r = (StatusCode::ACCEPTED, axum::Json(job.json())).into_response();
    r.headers_mut().insert(header::CACHE_CONTROL, HeaderValue::from_static("no-store"));
    Ok(r)
}

pub async fn delete(
    State(app): State<Arc<App>>,
    path: Result<Path<String>, axum::extract::rejection::PathRejection>,
    headers: HeaderMap,
) -> Result<Response, Problem> {
    admin(&app, &headers)?;
    let Path(name) = path.map_err(|e| problem_of(&e))?;
    if !valid_name(&name) {
        return Err(Problem::bad_request(format!("tileset name {name:?} is invalid")));
    }
    if app.registry.is_on_demand(&name) {
        return Err(Problem::new(
            StatusCode::CONFLICT,
            "on-demand",
            format!(
                "tileset {name:?} is baked on demand from --source; remove the flag and restart to delete it"
            ),
        ));
    }
    let root = app.registry.root().to_owned();
    // The folder, else the archive `NAME.tsa` (a folder of the same name is the one served).
    let mut dir = root.join(&name);
    let is_dir = tokio::fs::metadata(&dir).await.is_ok_and(|m| m.is_dir());
    if !is_dir {
        dir = root.join(format!("{name}{}", crate::store::ARCHIVE_SUFFIX));
        if !tokio::fs::metadata(&dir).await.is_ok_and(|m| m.is_file()) {
            return Err(Problem::not_found(format!("no tileset named {name:?}")));
        }
    }
    // Renamed out of the namespace first (atomic), then removed in the background.
    let nanos =
        std::time::SystemTime::now().duration_since(std::time::UNIX_EPOCH).map_or(0, |d| d.as_nanos());
    let gone = root.join(format!(".deleted-{name}-{nanos}"));
    tokio::fs::rename(&dir, &gone).await.map_err(|e| {
        tracing::error!(error = %e, "cannot delete tileset");
        Problem::internal("store-io", format!("tileset {name:?} could not be deleted"))
    })?;
    app.registry.remove(&name);
    tokio::task::spawn_blocking(move || {
        if is_dir { std::fs::remove_dir_all(gone) } else { std::fs::remove_file(gone) }
    });
    tracing::info!(tileset = %name, "tileset deleted");
    Ok(StatusCode::NO_CONTENT.into_response())
}
