//! The admin API (bearer token, `--admin-token`): upload a raster and bake it as a new tileset
//! (`POST /tilesets/{name}`, streamed to disk and size-limited), follow the bake job
//! (`GET /jobs/{id}`), delete a tileset (`DELETE /tilesets/{name}`). Uploads bake one at a time
//! on their own thread into a hidden staging directory that is renamed into place when complete,
//! so readers never see a half-baked tileset.

use std::collections::HashMap;
use std::path::{Path as FsPath, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Mutex};

use axum::body::Body;
use axum::extract::{Path, Query, State};
use axum::http::{HeaderMap, HeaderValue, StatusCode, Uri, header};
use axum::response::{IntoResponse, Response};
use http_body_util::BodyExt;
use serde::Deserialize;
use tokio::io::AsyncWriteExt;

use super::http::check_bearer;
use super::problem::Problem;
use super::{App, valid_name};
use crate::bake::{BakeOptions, PointBaker, Progress};
use crate::raster::{Encoding, LoadOptions, Overrides};
use crate::store::Store;

/// A bake job started by an upload.
pub struct Job {
    id: String,
    tileset: String,
    state: Mutex<(&'static str, Option<String>)>,
    total: AtomicU64,
    done: AtomicU64,
}

impl Job {
    fn json(&self) -> serde_json::Value {
        let (state, error) = self.state.lock().map_or(("unknown", None), |g| g.clone());
        serde_json::json!({
            "id": self.id,
            "tileset": self.tileset,
            "state": state,
            "nodes_total": self.total.load(Ordering::Relaxed),
            "nodes_done": self.done.load(Ordering::Relaxed),
            "error": error,
        })
    }
    fn set(&self, state: &'static str, error: Option<String>) {
        if let Ok(mut g) = self.state.lock() {
            *g = (state, error);
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
}

#[derive(Default)]
pub struct Jobs {
    map: Mutex<HashMap<String, Arc<Job>>>,
    next: AtomicU64,
    /// Uploaded bakes run one at a time: each already uses every core.
    bake_lock: Arc<Mutex<()>>,
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
        Some("gray16") => Some(Encoding::Gray16),
        Some("terrain-rgb") => Some(Encoding::TerrainRgb),
        Some("terrarium") => Some(Encoding::Terrarium),
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
    };
    crate::bake::check_options(&opts).map_err(|e| Problem::bad_request(e.to_string()))?;
    let root = app.registry.root().to_owned();
    if app.registry.get(&name).is_some() || root.join(&name).exists() {
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
    let job = Arc::new(Job {
        id: id.clone(),
        tileset: name.clone(),
        state: Mutex::new(("queued", None)),
        total: AtomicU64::new(0),
        done: AtomicU64::new(0),
    });
    if let Ok(mut m) = app.jobs.map.lock() {
        m.insert(id.clone(), job.clone());
    }
    let reply = job.json();
    let location = format!("/jobs/{id}");
    let app2 = app.clone();
    let lock = app.jobs.bake_lock.clone();
    let spawned = std::thread::Builder::new().name(format!("job-{id}")).spawn(move || {
        let _one_at_a_time = lock.lock();
        job.set("running", None);
        let src = JobSource { upload: &upload, encoding, cell_size: params.cell_size };
        let r = run_job(&root, &src, &name, &id, &opts, &app2.baker, &job);
        let _ = std::fs::remove_file(&upload);
        match r {
            Ok(()) => {
                job.set("done", None);
                app2.rescan();
            }
            Err(e) => {
                tracing::error!(job = %id, error = %e, "bake job failed");
                job.set("failed", Some(e));
            }
        }
    });
    if spawned.is_err() {
        return Err(Problem::unavailable("jobs", "cannot start the bake job", 5));
    }
    let mut r = (StatusCode::ACCEPTED, axum::Json(reply)).into_response();
    if let Ok(v) = HeaderValue::from_str(&location) {
        r.headers_mut().insert(header::LOCATION, v);
    }
    Ok(r)
}

/// Streams the body to `path`; `Err(None)` when it exceeds `limit`.
async fn stream_to(path: &FsPath, body: Body, limit: u64) -> Result<(), Option<Problem>> {
    let io = |e: std::io::Error| {
        tracing::error!(path = %path.display(), error = %e, "cannot store upload");
        Some(Problem::internal("store-io", "the upload could not be stored"))
    };
    let mut file = tokio::fs::File::create(path).await.map_err(io)?;
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

#[allow(clippy::too_many_arguments)]
/// The uploaded raster of a job and how to read it.
struct JobSource<'a> {
    upload: &'a FsPath,
    encoding: Option<Encoding>,
    cell_size: Option<f64>,
}

fn run_job(
    root: &FsPath,
    src: &JobSource<'_>,
    name: &str,
    id: &str,
    opts: &BakeOptions,
    baker: &PointBaker,
    job: &Job,
) -> Result<(), String> {
    let load = LoadOptions {
        encoding: src.encoding,
        overrides: Overrides { cell_size: src.cell_size, ..Overrides::default() },
        ..LoadOptions::default()
    };
    let raster = crate::raster::load(src.upload, &load).map_err(|e| e.to_string())?;
    let staging: PathBuf = root.join(format!(".job-{id}"));
    let r = crate::bake::bake_with(&raster, name, opts, baker, &Store::new(&staging), job)
        .map(|_| ())
        .map_err(|e| e.to_string());
    if let Err(e) = r {
        let _ = std::fs::remove_dir_all(&staging);
        return Err(e);
    }
    let target = root.join(name);
    if target.exists() {
        let _ = std::fs::remove_dir_all(&staging);
        return Err(format!("tileset {name:?} appeared while baking; upload discarded"));
    }
    std::fs::rename(&staging, &target).map_err(|e| format!("{}: {e}", target.display()))
}

pub async fn job(
    State(app): State<Arc<App>>,
    path: Result<Path<String>, axum::extract::rejection::PathRejection>,
    headers: HeaderMap,
) -> Result<Response, Problem> {
    admin(&app, &headers)?;
    let Path(id) = path.map_err(|e| problem_of(&e))?;
    let job = app.jobs.map.lock().ok().and_then(|m| m.get(&id).cloned());
    let job = job.ok_or_else(|| Problem::not_found(format!("no job {id:?}")))?;
    let mut r = axum::Json(job.json()).into_response();
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
    let dir = root.join(&name);
    if !dir.is_dir() {
        return Err(Problem::not_found(format!("no tileset named {name:?}")));
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
    tokio::task::spawn_blocking(move || std::fs::remove_dir_all(gone));
    tracing::info!(tileset = %name, "tileset deleted");
    Ok(StatusCode::NO_CONTENT.into_response())
}
