//! The hot path of a tile server: a `GET` of a blob that is already verified and held in memory.
//! Such a request is answered here, in front of the router, with exactly the response the
//! router's blob handler and the front middleware would give (same headers, metrics, CORS), but
//! without the router's per-request work (service clones, boxed middleware, five path
//! parameters percent-decoded into extensions and deserialized into strings), which profiling
//! under `bench/server_vs_nginx.sh` showed to be most of the server's user-space time per
//! request. Anything else — another route or method, a percent-encoded or malformed path, a key
//! or level that is not valid, a blob not in memory, a server with `--read-token` or
//! `--rate-limit`, or one at its in-flight limit — goes to the router unchanged, which owns
//! every error answer, disk read and bake.

use std::convert::Infallible;
use std::future::Future;
use std::pin::Pin;
use std::sync::Arc;
use std::sync::atomic::Ordering;
use std::task::{Context, Poll};
use std::time::Instant;

use axum::Router;
use axum::extract::Request;
use axum::http::{HeaderValue, Method, Version, header};
use axum::response::{IntoResponse, Response};
use tower::Service;

use super::App;
use super::conditional::{self, Conditional};
use super::http;
use super::loaders;
use super::native::{self, BLOB_ROUTE};
use super::problem::Problem;

/// The router behind the in-memory blob fast path.
#[derive(Clone)]
pub struct FastPath {
    app: Arc<App>,
    router: Router,
}

impl FastPath {
    pub fn new(app: Arc<App>) -> Self {
        Self { router: http::router(app.clone()), app }
    }
}

impl Service<Request> for FastPath {
    type Response = Response;
    type Error = Infallible;
    type Future = Pin<Box<dyn Future<Output = Result<Response, Infallible>> + Send>>;

    fn poll_ready(&mut self, _cx: &mut Context<'_>) -> Poll<Result<(), Infallible>> {
        // The router is always ready.
        Poll::Ready(Ok(()))
    }

    fn call(&mut self, req: Request) -> Self::Future {
        if let Some(resp) = bad_host(&self.app, &req).or_else(|| cached_blob(&self.app, &req)) {
            return Box::pin(std::future::ready(Ok(resp)));
        }
        Box::pin(self.router.call(req))
    }
}

/// `400` for a request without the one valid `Host` header RFC 9112 §3.2 requires: an HTTP/1.1
/// request without `Host`, any request with more than one, or one whose value is not a
/// `host[:port]` (an empty value is allowed). HTTP/1.0 requests need not send `Host`.
fn bad_host(app: &App, req: &Request) -> Option<Response> {
    let start = Instant::now();
    let mut hosts = req.headers().get_all(header::HOST).iter();
    let detail = match (hosts.next(), hosts.next()) {
        (None, _) if req.version() == Version::HTTP_11 => "an HTTP/1.1 request must have a Host header",
        (None, _) => return None,
        (Some(_), Some(_)) => "a request must not have more than one Host header",
        (Some(h), None) => {
            let ok = h.is_empty()
                || (!h.as_bytes().contains(&b'@')
                    && axum::http::uri::Authority::try_from(h.as_bytes()).is_ok());
            if ok {
                return None;
            }
            "the Host header is not a valid host[:port]"
        }
    };
    let resp = Problem::bad_request(detail).into_response();
    http::observe(app, "unmatched", req.method(), req.uri().path(), &resp, start);
    Some(resp)
}

/// The response to `req` when it is a plain `GET` of a blob held in memory, else `None`.
fn cached_blob(app: &App, req: &Request) -> Option<Response> {
    let start = Instant::now();
    if req.method() != Method::GET
        || app.config.read_token.is_some()
        || app.rate.enabled()
        || app.in_flight.load(Ordering::Relaxed) >= app.config.max_in_flight
    {
        return None;
    }
    let path = req.uri().path();
    // Percent-encoded paths take the router's way (it decodes them).
    if path.contains('%') {
        return None;
    }
    let mut parts = path.strip_prefix("/tilesets/")?.split('/');
    let (name, tiles, z, x, y, level) =
        (parts.next()?, parts.next()?, parts.next()?, parts.next()?, parts.next()?, parts.next()?);
    if tiles != "tiles" || parts.next().is_some() {
        return None;
    }
    let ts = loaders::tileset(app, name).ok()?;
    let key = loaders::parse_key(&ts, z, x, y).ok()?;
    let level = loaders::parse_level(&ts, level).ok()?;
    let entry = app.cache.get(&(ts.generation, key, u16::from(level)))?;
    app.metrics.cache_hits.fetch_add(1, Ordering::Relaxed);
    let cond = Conditional::from_headers(req.headers());
    let mut resp = conditional::send(
        req.method(),
        &cond,
        &entry,
        native::BLOB_TYPE,
        loaders::versioned_cache(&ts, req.uri().query()),
    );
    // What the CORS layer adds to every response.
    let h = resp.headers_mut();
    h.insert(header::ACCESS_CONTROL_EXPOSE_HEADERS, HeaderValue::from_static(http::EXPOSE_HEADERS));
    h.insert(header::ACCESS_CONTROL_ALLOW_ORIGIN, HeaderValue::from_static("*"));
    http::observe(app, BLOB_ROUTE, req.method(), path, &resp, start);
    Some(resp)
}
