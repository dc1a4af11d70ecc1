//! The handlers of the native API: probes, metrics, the OpenAPI document, the tileset list,
//! summaries, manifests, index chunks and blobs, with their HTTP caching semantics: strong
//! ETags, `If-None-Match` → 304, single `Range` → 206/416, `Cache-Control` immutable only for
//! URLs naming the current content version.

use std::fmt::Write as _;
use std::sync::Arc;
use std::sync::atomic::Ordering;

use axum::body::Body;
use axum::extract::{Path, RawQuery, State};
use axum::http::{HeaderValue, Method, header};
use axum::response::{IntoResponse, Response};
use bytes::Bytes;

use super::App;
use super::cache::Entry;
use super::conditional::{Conditional, etag_value, send};
use super::loaders::{
    NO_CACHE, SHORT, chunk_entry, load_blob, parse_key, parse_level, tileset, versioned_cache,
};
use super::problem::Problem;
use crate::store::SUBTREE_LEVELS;

/// Media type of blobs.
pub const BLOB_TYPE: &str = "application/vnd.terrastream.blob";
/// The blob route (also its label in metrics).
pub const BLOB_ROUTE: &str = "/tilesets/{name}/tiles/{z}/{x}/{y}/{level}";

pub(super) async fn healthz() -> Response {
    json_response(&serde_json::json!({"status": "ok"}), "no-store")
}

pub(super) async fn readyz(State(app): State<Arc<App>>) -> Response {
    if let Some(d) = app.scan_stuck() {
        return Problem::unavailable(
            "not-ready",
            format!(
                "a scan of the store {} has run for {} s without finishing (a file that blocks when read, a hung mount?)",
                app.registry.root().display(),
                d.as_secs()
            ),
            5,
        )
        .into_response();
    }
    // A bucket is readable when its last scan (a listing) succeeded: `ready` says so.
    // On the blocking pool: a stat on a hung mount must not hold an async worker.
    let store_ok =
        app.registry.is_remote() || tokio::fs::metadata(app.registry.root()).await.is_ok_and(|m| m.is_dir());
    let ready = app.ready.load(Ordering::Relaxed) && store_ok;
    if ready {
        let n = app.registry.all().len();
        json_response(&serde_json::json!({"status": "ready", "tilesets": n}), "no-store")
    } else {
        Problem::unavailable(
            "not-ready",
            format!("the store {} cannot be read", app.registry.root().display()),
            5,
        )
        .into_response()
    }
}

pub(super) async fn metrics(State(app): State<Arc<App>>) -> Response {
    let mut text = app.metrics.render();
    let _ = writeln!(
        text,
        "# HELP terrastream_cache_bytes Bytes of verified blobs held in memory.\n# TYPE terrastream_cache_bytes gauge\nterrastream_cache_bytes {}",
        app.cache.bytes()
    );
    let mut r = text.into_response();
    r.headers_mut().insert(header::CONTENT_TYPE, HeaderValue::from_static("text/plain; version=0.0.4"));
    r.headers_mut().insert(header::CACHE_CONTROL, HeaderValue::from_static("no-store"));
    r
}

pub(super) async fn openapi() -> Response {
    json_response(&super::openapi::document(), SHORT)
}

fn json_response(v: &serde_json::Value, cache: &'static str) -> Response {
    let body = serde_json::to_vec_pretty(v).unwrap_or_default();
    let mut r = Response::new(Body::from(body));
    r.headers_mut().insert(header::CONTENT_TYPE, HeaderValue::from_static("application/json"));
    r.headers_mut().insert(header::CACHE_CONTROL, HeaderValue::from_static(cache));
    r
}

pub(super) async fn list(State(app): State<Arc<App>>, headers: Conditional, method: Method) -> Response {
    let all: Vec<serde_json::Value> = app.registry.all().iter().map(|t| t.summary.clone()).collect();
    let body = serde_json::to_vec_pretty(&serde_json::json!({ "tilesets": all })).unwrap_or_default();
    let etag = etag_value(&super::registry::etag_of(&body));
    send(&method, &headers, &Entry { bytes: Bytes::from(body), etag }, "application/json", SHORT)
}

pub(super) async fn summary(
    State(app): State<Arc<App>>,
    path: Result<Path<String>, axum::extract::rejection::PathRejection>,
) -> Result<Response, Problem> {
    let Path(name) = path.map_err(|e| Problem::bad_request(e.body_text()))?;
    let ts = tileset(&app, &name)?;
    Ok(json_response(&ts.summary, SHORT))
}

pub(super) async fn manifest(
    State(app): State<Arc<App>>,
    path: Result<Path<String>, axum::extract::rejection::PathRejection>,
    method: Method,
    headers: Conditional,
) -> Result<Response, Problem> {
    let Path(name) = path.map_err(|e| Problem::bad_request(e.body_text()))?;
    let ts = tileset(&app, &name)?;
    let entry = Entry { bytes: ts.manifest_json.clone(), etag: etag_value(&ts.manifest_etag) };
    Ok(send(&method, &headers, &entry, "application/json", SHORT))
}

type ChunkPath = (String, String, String, String);

pub(super) async fn index_chunk(
    State(app): State<Arc<App>>,
    path: Result<Path<ChunkPath>, axum::extract::rejection::PathRejection>,
    RawQuery(query): RawQuery,
    method: Method,
    headers: Conditional,
) -> Result<Response, Problem> {
    let Path((name, z, x, file)) = path.map_err(|e| Problem::bad_request(e.body_text()))?;
    let ts = tileset(&app, &name)?;
    let y = file
        .strip_suffix(".json")
        .ok_or_else(|| Problem::bad_request(format!("index chunk {file:?} must be named Y.json")))?;
    let key = parse_key(&ts, &z, &x, y)?;
    if key.z % SUBTREE_LEVELS != 0 {
        return Err(Problem::not_found(format!(
            "index chunks are rooted at z = 0, {SUBTREE_LEVELS}, {}, …; z {} is not a chunk root",
            SUBTREE_LEVELS * 2,
            key.z
        )));
    }
    let (entry, growing) = chunk_entry(&app, &ts, key).await?;
    let cache = if growing { NO_CACHE } else { versioned_cache(&ts, query.as_deref()) };
    Ok(send(&method, &headers, &entry, "application/json", cache))
}

type BlobPath = (String, String, String, String, String);

pub(super) async fn blob(
    State(app): State<Arc<App>>,
    path: Result<Path<BlobPath>, axum::extract::rejection::PathRejection>,
    RawQuery(query): RawQuery,
    method: Method,
    headers: Conditional,
) -> Result<Response, Problem> {
    let Path((name, z, x, y, level)) = path.map_err(|e| Problem::bad_request(e.body_text()))?;
    let ts = tileset(&app, &name)?;
    let key = parse_key(&ts, &z, &x, &y)?;
    let level = parse_level(&ts, &level)?;
    let entry = load_blob(&app, &ts, key, level).await?;
    Ok(send(&method, &headers, &entry, BLOB_TYPE, versioned_cache(&ts, query.as_deref())))
}
