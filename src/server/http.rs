//! The router and the front middleware every request passes (load shedding, rate limit, read
//! token, timeout, problem bodies, metrics, access log). The handlers live beside it:
//! [`super::native`] (tileset list, manifests, index chunks, blobs), [`super::tiles3d`] (the 3D
//! Tiles view), [`super::admin`] (uploads, jobs); what they share is in [`super::loaders`].

use std::sync::Arc;
use std::sync::atomic::Ordering;
use std::time::{Duration, Instant};

use axum::Router;
use axum::body::Body;
use axum::extract::{ConnectInfo, MatchedPath, Request, State};
use axum::http::{HeaderValue, Method, StatusCode, header};
use axum::middleware::{self, Next};
use axum::response::{IntoResponse, Response};
use axum::routing::get;
use tower_http::cors::{AllowOrigin, CorsLayer};

use super::auth::check_bearer;
use super::native::{self, BLOB_ROUTE};
use super::problem::{self, PROBLEM_JSON, Problem};
use super::{App, admin, heightmap, heights, terrain, tiles3d};

/// The peer address of a connection, as `ConnectInfo` in every request's extensions (the
/// listener puts it there; the middleware reads it for the per-client limits and logs).
#[derive(Clone, Copy, Debug)]
pub struct Peer(pub std::net::SocketAddr);

/// Seconds a client is asked to wait when the server sheds load.
pub const SHED_RETRY_AFTER_S: u32 = 1;
/// `Access-Control-Expose-Headers` exactly as the CORS layer writes it from its list in `router`
/// (the fast path writes this copy; a test compares both paths' headers).
pub const EXPOSE_HEADERS: &str = "etag,content-range,content-length,accept-ranges,retry-after";

pub fn router(app: Arc<App>) -> Router {
    let cors = CorsLayer::new()
        .allow_origin(AllowOrigin::any())
        .allow_methods([Method::GET, Method::HEAD, Method::POST, Method::OPTIONS])
        .allow_headers([
            header::RANGE,
            header::IF_NONE_MATCH,
            header::IF_RANGE,
            header::AUTHORIZATION,
            header::CONTENT_TYPE,
        ])
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
        .route("/healthz", get(native::healthz))
        .route("/readyz", get(native::readyz))
        .route("/metrics", get(native::metrics))
        .route("/openapi.json", get(native::openapi))
        .route("/tilesets", get(native::list))
        .route("/tilesets/{name}", get(native::summary).post(admin::upload).delete(admin::delete))
        .route("/tilesets/{name}/tileset.json", get(native::manifest))
        .route("/tilesets/{name}/index/{z}/{x}/{file}", get(native::index_chunk))
        .route(BLOB_ROUTE, get(native::blob))
        .route("/tilesets/{name}/3dtiles/tileset.json", get(tiles3d::root))
        .route("/tilesets/{name}/3dtiles/index/{z}/{x}/{file}", get(tiles3d::subtree))
        .route(tiles3d::GLB_ROUTE, get(tiles3d::glb))
        .route("/tilesets/{name}/heights", get(heights::get).post(heights::post))
        .route("/tilesets/{name}/heightmap/tiles.json", get(heightmap::tilejson))
        .route("/tilesets/{name}/heightmap/{z}/{x}/{file}", get(heightmap::tile))
        .route("/tilesets/{name}/terrain/layer.json", get(terrain::layer))
        .route("/tilesets/{name}/terrain/{z}/{x}/{file}", get(terrain::tile))
        .route("/tilesets/{name}/terrain/3dtiles/tileset.json", get(terrain::tileset3d))
        .route("/tilesets/{name}/terrain/3dtiles/tiles/{root}/{level}/{x}/{file}", get(terrain::glb3d))
        .route("/tilesets/{name}/terrain/3dtiles/subtrees/{root}/{level}/{x}/{file}", get(terrain::subtree3d))
        .route("/viewer", get(tiles3d::viewer))
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
    let ip = req.extensions().get::<ConnectInfo<Peer>>().map(|c| c.0.0.ip());
    // Height queries are reads that happen to carry a body.
    let admin_route = (matches!(method, Method::POST | Method::DELETE)
        && route != "/tilesets/{name}/heights")
        || route == "/jobs/{id}";

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
    let sent = if method == Method::HEAD {
        None
    } else {
        resp.headers().get(header::CONTENT_LENGTH).and_then(|v| v.to_str().ok()?.parse::<u64>().ok())
    };
    observe_status(app, route, method, path, resp.status().as_u16(), sent, start);
}

/// [`observe`] from a response's status and the bytes of its body sent (the wire-level fast
/// path's, which writes its responses itself).
pub(super) fn observe_status(
    app: &App,
    route: &str,
    method: &Method,
    path: &str,
    status: u16,
    sent: Option<u64>,
    start: Instant,
) {
    if let Some(len) = sent {
        app.metrics.bytes_sent.fetch_add(len, Ordering::Relaxed);
    }
    let elapsed = start.elapsed();
    app.metrics.record(route, status, elapsed);
    let ms = elapsed.as_secs_f64() * 1e3;
    if status >= 500 {
        tracing::warn!(%method, %path, status, ms, "request");
    } else {
        tracing::debug!(%method, %path, status, ms, "request");
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
