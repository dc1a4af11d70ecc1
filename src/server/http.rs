//! Routes, the front middleware (load shedding, rate limit, read token, timeout, problem
//! bodies, metrics, access log) and the read handlers with their HTTP caching semantics:
//! strong ETags, `If-None-Match` → 304, single `Range` → 206/416, `Cache-Control` immutable
//! only for URLs naming the current content version.

use std::fmt::Write as _;
use std::sync::Arc;
use std::sync::atomic::Ordering;
use std::time::{Duration, Instant};

use axum::Router;
use axum::body::Body;
use axum::extract::{ConnectInfo, MatchedPath, Path, RawQuery, Request, State};
use axum::http::{HeaderValue, Method, StatusCode, header};
use axum::middleware::{self, Next};
use axum::response::{IntoResponse, Response};
use axum::routing::get;
use bytes::Bytes;
use tower_http::cors::{AllowOrigin, CorsLayer};

use super::auth::check_bearer;
use super::cache::Entry;
use super::conditional::{Conditional, etag_value, send};
use super::problem::{self, PROBLEM_JSON, Problem};
use super::registry::Tileset;
use super::{App, admin, valid_name};
use crate::codec;
use crate::store::SUBTREE_LEVELS;
use crate::tiling::TileKey;

/// `Cache-Control` of URLs carrying the current content version (`?v=`): they can never change.
pub const IMMUTABLE: &str = "public, max-age=31536000, immutable";
/// `Cache-Control` of blobs and index chunks without (or with a stale) content version.
pub const REVALIDATE: &str = "public, max-age=60, must-revalidate";
/// `Cache-Control` of manifests and the tileset list: short, then revalidate by ETag.
pub const SHORT: &str = "public, max-age=10, must-revalidate";
/// `Cache-Control` of documents that change as tiles bake (on-demand index chunks).
pub const NO_CACHE: &str = "no-cache";
/// Media type of blobs.
pub const BLOB_TYPE: &str = "application/vnd.terrastream.blob";
/// Seconds a client is asked to wait when the server sheds load.
pub const SHED_RETRY_AFTER_S: u32 = 1;
/// The blob route (also its label in metrics).
pub const BLOB_ROUTE: &str = "/tilesets/{name}/tiles/{z}/{x}/{y}/{level}";
/// `Access-Control-Expose-Headers` exactly as the CORS layer writes it from its list in `router`
/// (the fast path writes this copy; a test compares both paths' headers).
pub const EXPOSE_HEADERS: &str = "etag,content-range,content-length,accept-ranges,retry-after";

pub fn router(app: Arc<App>) -> Router {
    let cors = CorsLayer::new()
        .allow_origin(AllowOrigin::any())
        .allow_methods([Method::GET, Method::HEAD, Method::OPTIONS])
        .allow_headers([header::RANGE, header::IF_NONE_MATCH, header::IF_RANGE, header::AUTHORIZATION])
        .expose_headers([
            header::ETAG,
            header::CONTENT_RANGE,
            header::CONTENT_LENGTH,
            header::ACCEPT_RANGES,
            header::RETRY_AFTER,
        ])
        .max_age(Duration::from_hours(24))
        // No `Vary: origin, access-control-request-*`: every CORS header here is the same for
        // every request (`*`, fixed lists), so no response varies by them (Fetch §3.2.5), and
        // a CDN that honours Vary would otherwise keep one copy of each blob per Origin.
        // `Vary: authorization` is added in `front` when reading needs a token.
        .vary(Vec::<header::HeaderName>::new());
    Router::new()
        .route("/healthz", get(healthz))
        .route("/readyz", get(readyz))
        .route("/metrics", get(metrics))
        .route("/openapi.json", get(openapi))
        .route("/tilesets", get(list))
        .route("/tilesets/{name}", get(summary).post(admin::upload).delete(admin::delete))
        .route("/tilesets/{name}/tileset.json", get(manifest))
        .route("/tilesets/{name}/index/{z}/{x}/{file}", get(index_chunk))
        .route(BLOB_ROUTE, get(blob))
        .route("/tilesets/{name}/3dtiles/tileset.json", get(super::tiles3d::root))
        .route("/tilesets/{name}/3dtiles/index/{z}/{x}/{file}", get(super::tiles3d::subtree))
        .route("/tilesets/{name}/3dtiles/tiles/{z}/{x}/{y}/{file}", get(super::tiles3d::glb))
        .route("/viewer", get(super::tiles3d::viewer))
        .route("/jobs/{id}", get(admin::job).delete(admin::cancel))
        .fallback(fallback)
        .layer(middleware::from_fn_with_state(app.clone(), front))
        .layer(cors)
        .with_state(app)
}

async fn fallback() -> Problem {
    Problem::not_found("no such resource; see /openapi.json for the API")
}

struct InFlight<'a>(&'a App);
impl Drop for InFlight<'_> {
    fn drop(&mut self) {
        self.0.in_flight.fetch_sub(1, Ordering::Relaxed);
    }
}

async fn front(State(app): State<Arc<App>>, req: Request, next: Next) -> Response {
    let start = Instant::now();
    // Clones of the matched route (an `Arc<str>`) and the URI (shared bytes): no allocation
    // per request on the serving path.
    let matched = req.extensions().get::<MatchedPath>().cloned();
    let route = matched.as_ref().map_or("unmatched", MatchedPath::as_str);
    let method = req.method().clone();
    let uri = req.uri().clone();
    let probe = matches!(route, "/healthz" | "/readyz");
    let ip = req.extensions().get::<ConnectInfo<super::listener::Peer>>().map(|c| c.0.0.ip());
    let admin_route = matches!(method, Method::POST | Method::DELETE) || route == "/jobs/{id}";

    let n = app.in_flight.fetch_add(1, Ordering::Relaxed);
    let guard = InFlight(&app);
    let resp = if !probe && n >= app.config.max_in_flight {
        app.metrics.shed.fetch_add(1, Ordering::Relaxed);
        Problem::unavailable(
            "overloaded",
            "the server is at its in-flight request limit; retry later",
            SHED_RETRY_AFTER_S,
        )
        .into_response()
    } else if let Some(wait) = ip.filter(|_| !probe).and_then(|ip| app.rate.check(ip)) {
        app.metrics.shed.fetch_add(1, Ordering::Relaxed);
        Problem {
            retry_after: Some(wait),
            ..Problem::new(
                StatusCode::TOO_MANY_REQUESTS,
                "rate-limited",
                "too many requests from this client",
            )
        }
        .into_response()
    } else if let (Some(tok), false, false) = (&app.config.read_token, probe, admin_route)
        && let Err(p) = check_bearer(req.headers(), tok, "reading")
    {
        p.into_response()
    } else if admin_route {
        // Uploads stream large bodies: bounded by size, not by the request timeout.
        next.run(req).await
    } else {
        match tokio::time::timeout(app.config.request_timeout, next.run(req)).await {
            Ok(r) => r,
            Err(_) => Problem::unavailable(
                "timeout",
                format!("the request took longer than {} s", app.config.request_timeout.as_secs()),
                SHED_RETRY_AFTER_S,
            )
            .into_response(),
        }
    };
    drop(guard);
    let mut resp = problem_body(resp);
    if app.config.read_token.is_some() {
        resp.headers_mut().append(header::VARY, HeaderValue::from_static("authorization"));
    }
    observe(&app, route, &method, uri.path(), &resp, start);
    resp
}

/// What every answered request records, whichever path answered it (the router through
/// `front`, or the fast path in front of it): the bytes of the body sent (none for `HEAD`), the
/// request in the metrics by route and status, and its log line (a warning for a 5xx).
pub(super) fn observe(app: &App, route: &str, method: &Method, path: &str, resp: &Response, start: Instant) {
    if method != Method::HEAD
        && let Some(len) =
            resp.headers().get(header::CONTENT_LENGTH).and_then(|v| v.to_str().ok()?.parse::<u64>().ok())
    {
        app.metrics.bytes_sent.fetch_add(len, Ordering::Relaxed);
    }
    let status = resp.status();
    app.metrics.record(route, status.as_u16(), start.elapsed());
    let ms = start.elapsed().as_secs_f64() * 1e3;
    if status.is_server_error() {
        tracing::warn!(%method, %path, status = status.as_u16(), ms, "request");
    } else {
        tracing::debug!(%method, %path, status = status.as_u16(), ms, "request");
    }
}

/// Gives error responses made outside our handlers (405 from the method router, extractor
/// rejections) a problem+json body, keeping their headers (`Allow`).
fn problem_body(resp: Response) -> Response {
    let status = resp.status();
    let is_problem =
        resp.headers().get(header::CONTENT_TYPE).is_some_and(|v| v.as_bytes() == PROBLEM_JSON.as_bytes());
    if status.as_u16() < 400 || is_problem {
        return resp;
    }
    let (mut parts, _) = resp.into_parts();
    let (slug, detail) = problem::generic(status);
    let body = problem::body(status, slug, detail);
    parts.headers.insert(header::CONTENT_TYPE, HeaderValue::from_static(PROBLEM_JSON));
    parts.headers.insert(header::CACHE_CONTROL, HeaderValue::from_static("no-store"));
    parts.headers.insert(header::CONTENT_LENGTH, HeaderValue::from(body.len()));
    Response::from_parts(parts, Body::from(body))
}

async fn healthz() -> Response {
    json_response(&serde_json::json!({"status": "ok"}), "no-store")
}

async fn readyz(State(app): State<Arc<App>>) -> Response {
    // A bucket is readable when its last scan (a listing) succeeded: `ready` says so.
    let store_ok = app.registry.is_remote() || app.registry.root().is_dir();
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

async fn metrics(State(app): State<Arc<App>>) -> Response {
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

async fn openapi() -> Response {
    json_response(&super::openapi::document(), SHORT)
}

fn json_response(v: &serde_json::Value, cache: &'static str) -> Response {
    let body = serde_json::to_vec_pretty(v).unwrap_or_default();
    let mut r = Response::new(Body::from(body));
    r.headers_mut().insert(header::CONTENT_TYPE, HeaderValue::from_static("application/json"));
    r.headers_mut().insert(header::CACHE_CONTROL, HeaderValue::from_static(cache));
    r
}

async fn list(State(app): State<Arc<App>>, headers: Conditional, method: Method) -> Response {
    let all: Vec<serde_json::Value> = app.registry.all().iter().map(|t| t.summary.clone()).collect();
    let body = serde_json::to_vec_pretty(&serde_json::json!({ "tilesets": all })).unwrap_or_default();
    let etag = etag_value(&super::registry::etag_of(&body));
    send(&method, &headers, &Entry { bytes: Bytes::from(body), etag }, "application/json", SHORT)
}

/// The tileset named in a path, or 400 (invalid name) / 404 (unknown).
pub(super) fn tileset(app: &App, name: &str) -> Result<Arc<Tileset>, Problem> {
    if !valid_name(name) {
        return Err(Problem::bad_request(format!(
            "tileset name {name:?} is invalid: names are 1 to 64 of a-z, 0-9, _ and -"
        )));
    }
    app.registry.get(name).ok_or_else(|| Problem::not_found(format!("no tileset named {name:?}")))
}

async fn summary(
    State(app): State<Arc<App>>,
    path: Result<Path<String>, axum::extract::rejection::PathRejection>,
) -> Result<Response, Problem> {
    let Path(name) = path.map_err(|e| Problem::bad_request(e.body_text()))?;
    let ts = tileset(&app, &name)?;
    Ok(json_response(&ts.summary, SHORT))
}

async fn manifest(
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

/// A decimal path component: digits only (no sign, no spaces), at most `u32`.
fn parse_num(s: &str, what: &str) -> Result<u32, Problem> {
    if s.is_empty() || s.len() > 10 || !s.bytes().all(|b| b.is_ascii_digit()) {
        return Err(Problem::bad_request(format!("{what} {s:?} is not a non-negative integer")));
    }
    s.parse().map_err(|_| Problem::bad_request(format!("{what} {s:?} is too large")))
}

/// Checks a key against the tileset's quadtree: `400` when it cannot exist at all.
pub(super) fn parse_key(ts: &Tileset, z: &str, x: &str, y: &str) -> Result<TileKey, Problem> {
    // Well-formed keys outside the tileset name no resource: 404, not 400 (RFC 9110 §15.5.5).
    let zn = parse_num(z, "z")?;
    let (xn, yn) = (parse_num(x, "x")?, parse_num(y, "y")?);
    if zn > u32::from(ts.depth) {
        return Err(Problem::not_found(format!(
            "no tile at z {zn}: tileset {:?} has z 0 to {}",
            ts.name, ts.depth
        )));
    }
    // x and y are u32, so every one fits from z 32 on (and a manifest's depth may be anything
    // up to 255: no shift may overflow).
    let side = 1u64.checked_shl(zn).unwrap_or(u64::MAX);
    if u64::from(xn) >= side || u64::from(yn) >= side {
        return Err(Problem::not_found(format!(
            "no tile x {xn} / y {yn} at z {zn}: x and y run 0 to {}",
            side - 1
        )));
    }
    let Ok(z8) = u8::try_from(zn) else {
        return Err(Problem::not_found(format!("no tile at z {zn}")));
    };
    Ok(TileKey::new(z8, xn, yn))
}

/// `Cache-Control` of a content-addressed document: immutable only when the request names the
/// tileset's current content version.
pub(super) fn versioned_cache(ts: &Tileset, query: Option<&str>) -> &'static str {
    let v = query.into_iter().flat_map(|q| q.split('&')).find_map(|kv| kv.strip_prefix("v="));
    match v {
        Some(v) if v == ts.content_version => IMMUTABLE,
        _ => REVALIDATE,
    }
}

type ChunkPath = (String, String, String, String);

async fn index_chunk(
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

/// The index chunk rooted at `key` (checked to be a chunk root of the tileset) and whether it
/// still grows: an on-demand tileset not fully baked lists the nodes baked so far, rebuilt
/// from their blobs.
pub(super) async fn chunk_entry(
    app: &App,
    ts: &Arc<Tileset>,
    key: TileKey,
) -> Result<(Entry, bool), Problem> {
    let name = &ts.name;
    if let Some(src) = ts.source.clone().filter(|_| !ts.store.manifest_path().exists()) {
        // On-demand and not fully baked: the nodes baked so far, rebuilt from their blobs.
        if !src.pyramid.contains(key) {
            return Err(Problem::not_found(format!("tile {key} lies outside the data of {name:?}")));
        }
        let ts2 = ts.clone();
        let chunk = tokio::task::spawn_blocking(move || {
            let mut nodes = Vec::new();
            let mut frontier = vec![key];
            for _ in 0..SUBTREE_LEVELS {
                let mut next = Vec::new();
                for k in frontier {
                    if let Some(n) = crate::bake::node_from_blobs(&ts2.store, k, src.opts.levels)? {
                        nodes.push(n);
                    }
                    next.extend(src.pyramid.children(k));
                }
                frontier = next;
            }
            Ok::<_, crate::store::StoreError>(crate::store::IndexChunk { root: key, nodes })
        })
        .await
        .map_err(|_| Problem::internal("index", "building the index chunk failed"))?
        .map_err(|e| Problem::internal("index", format!("reading the blobs baked so far: {e}")))?;
        let body = serde_json::to_vec_pretty(&chunk).unwrap_or_default();
        let etag = etag_value(&super::registry::etag_of(&body));
        return Ok((Entry { bytes: Bytes::from(body), etag }, true));
    }
    let ck = (ts.generation, key, super::cache::INDEX_CHUNK);
    let entry = if let Some(e) = app.cache.get(&ck) {
        e
    } else {
        let rel = crate::store::chunk_rel(key);
        let bytes = match ts.store.get_async(&rel).await {
            Ok(Some(b)) => b,
            Ok(None) => {
                return Err(Problem::not_found(format!("no index chunk {key} in tileset {name:?}")));
            }
            Err(e) => {
                tracing::error!(path = %ts.store.describe(&rel), error = %e, "cannot read index chunk");
                return Err(store_unavailable("the index chunk could not be read from the store".into()));
            }
        };
        let e = Entry { etag: etag_value(&super::registry::etag_of(&bytes)), bytes };
        app.cache.insert(ck, e.clone());
        e
    };
    Ok((entry, false))
}

type BlobPath = (String, String, String, String, String);

async fn blob(
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

/// A level path component (`N` or `N.tsb`) checked against the tileset's levels.
pub(super) fn parse_level(ts: &Tileset, level: &str) -> Result<u8, Problem> {
    let level_s = level.strip_suffix(".tsb").unwrap_or(level);
    let level = parse_num(level_s, "level")?;
    if level >= u32::from(ts.level_count) {
        return Err(Problem::not_found(format!(
            "no level {level}: tileset {:?} has levels 0 to {}",
            ts.name,
            ts.level_count.saturating_sub(1)
        )));
    }
    Ok(level as u8)
}

/// Seconds a client is asked to wait when the store cannot be read.
pub const STORE_IO_RETRY_AFTER_S: u32 = 5;

/// The answer when reading the store fails other than by a missing file (permissions, a
/// directory replaced by a file, a failing disk or mount): `503` + `Retry-After`, not `404` —
/// the resource may well exist, the server cannot tell — and not cached (`no-store`), so a CDN
/// does not keep the failure once the store is readable again.
fn store_unavailable(detail: String) -> Problem {
    Problem::unavailable("store-io", detail, STORE_IO_RETRY_AFTER_S)
}

/// What reading a blob from disk found.
enum Read {
    Ok(Entry),
    Missing,
    Corrupt(String),
}

fn verify(bytes: Bytes, key: TileKey, level: u8) -> Read {
    let h = match codec::decode_header(&bytes) {
        Ok(h) => h,
        Err(e) => return Read::Corrupt(e.to_string()),
    };
    if h.key != key || h.level != level {
        return Read::Corrupt(format!("header names tile {} level {}", h.key, h.level));
    }
    if bytes.len() != h.blob_len() {
        return Read::Corrupt(format!("{} bytes, header says {}", bytes.len(), h.blob_len()));
    }
    let computed = crc32fast::hash(&bytes[codec::PREFIX_LEN..]);
    if computed != h.checksum {
        return Read::Corrupt(format!("payload checksum {computed:08x}, header says {:08x}", h.checksum));
    }
    // Content-derived: the payload's CRC and the header's CRC (which covers the payload CRC,
    // its length, the key and level), 64 bits in all.
    let etag = etag_value(&format!("\"{:08x}{:08x}\"", h.checksum, h.header_checksum));
    Read::Ok(Entry { bytes, etag })
}

async fn read_verified(store: &crate::store::Store, key: TileKey, level: u8) -> Result<Read, Problem> {
    let rel = crate::store::blob_rel(key, level);
    match store.get_async(&rel).await {
        Ok(Some(b)) => Ok(verify(b, key, level)),
        Ok(None) => Ok(Read::Missing),
        Err(e) => {
            tracing::error!(path = %store.describe(&rel), error = %e, "cannot read blob");
            Err(store_unavailable(format!("tile {key} level {level} could not be read from the store")))
        }
    }
}

/// A verified blob: from memory, from disk, or baked on demand. A blob failing verification is
/// never sent: it is logged and answered `500` (the stored data is bad — the server's fault,
/// not the client's, and retrying will not help until it is re-baked); for an on-demand
/// tileset it is moved aside and baked again.
pub(super) async fn load_blob(
    app: &App,
    ts: &Arc<Tileset>,
    key: TileKey,
    level: u8,
) -> Result<Entry, Problem> {
    let ck = (ts.generation, key, u16::from(level));
    if let Some(e) = app.cache.get(&ck) {
        app.metrics.cache_hits.fetch_add(1, Ordering::Relaxed);
        return Ok(e);
    }
    app.metrics.cache_misses.fetch_add(1, Ordering::Relaxed);
    let path = ts.store.blob_path(key, level);
    let mut baked = false;
    loop {
        match read_verified(&ts.store, key, level).await? {
            Read::Ok(e) => {
                app.cache.insert(ck, e.clone());
                return Ok(e);
            }
            Read::Corrupt(why) => {
                app.metrics.corrupt_blobs.fetch_add(1, Ordering::Relaxed);
                tracing::error!(
                    tileset = %ts.name, tile = %key, level, path = %path.display(), error = %why,
                    "corrupt blob detected; not sent"
                );
                if ts.source.is_none() || baked {
                    return Err(Problem::internal(
                        "corrupt-blob",
                        format!(
                            "the stored blob of tile {key} level {level} failed verification and was not sent"
                        ),
                    ));
                }
                let aside = path.with_extension("tsb.corrupt");
                if let Err(e) = tokio::fs::rename(&path, &aside).await {
                    tracing::error!(error = %e, "cannot move the corrupt blob aside");
                    return Err(Problem::internal(
                        "corrupt-blob",
                        format!("tile {key} level {level} is corrupt"),
                    ));
                }
            }
            Read::Missing => {
                let unpaid =
                    ts.store.exists_async(&crate::store::unpaid_rel(key, level)).await.map_err(|e| {
                        tracing::error!(error = %e, "cannot look up an unpaid marker");
                        store_unavailable(format!(
                            "tile {key} level {level} could not be read from the store"
                        ))
                    })?;
                if unpaid {
                    return Err(Problem::not_found(format!(
                        "tile {key} has no level {level} in tileset {:?}: that level did not pay (it would \
                         cost as many primitives or bytes as a finer level of the tile); its index entry \
                         lists the levels it has",
                        ts.name
                    )));
                }
                let Some(src) = &ts.source else {
                    return Err(Problem::not_found(format!(
                        "no tile {key} level {level} in tileset {:?}",
                        ts.name
                    )));
                };
                if !src.pyramid.contains(key) {
                    return Err(Problem::not_found(format!(
                        "tile {key} lies outside the data of {:?}",
                        ts.name
                    )));
                }
                if baked {
                    return Err(Problem::internal(
                        "bake",
                        format!("tile {key} was baked but level {level} is missing"),
                    ));
                }
            }
        }
        let mut rx = app.bakery.request(ts, key, &path)?;
        let outcome = rx
            .wait_for(Option::is_some)
            .await
            .map_err(|_| Problem::internal("bake", format!("the bake of tile {key} was abandoned")))?
            .clone();
        if let Some(Err(e)) = outcome {
            return Err(Problem::internal("bake", format!("baking tile {key} failed: {e}")));
        }
        baked = true;
    }
}
