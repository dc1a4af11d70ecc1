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
//!
//! In front of hyper, [`FastPath::wire_step`] answers the same requests — and a `GET`/`HEAD`
//! of a 3D Tiles GLB whose answer (in the `glb=` form and the coding `Accept-Encoding`
//! negotiates) the router has already made and cached (`tiles3d::cached_glb`) — straight from a
//! connection's bytes (see `listener::wire`): it parses the request head with `httparse` and
//! writes the status line, headers and body itself, into a buffer the connection reuses, so a
//! hit costs no allocation and one `writev`. It answers only a plain `GET` or `HEAD` of an
//! in-memory blob or GLB over HTTP/1.1 — with `If-None-Match` (`304`) and `Connection: close` — and
//! hands the connection to hyper, from the first byte of the first request it does not answer,
//! for anything else: another route, a body (`Content-Length`, `Transfer-Encoding`), `Range`,
//! `If-Range`, `Expect`, `Upgrade`, HTTP/1.0, a missing, repeated or unusual `Host`, a repeated
//! `Accept-Encoding`, any byte
//! outside a conservative set in the request target, an unparsable or oversized head. Its
//! answers are byte for byte the router's but the date (tests compare both).

use std::convert::Infallible;
use std::future::Future;
use std::io::Write as _;
use std::pin::Pin;
use std::sync::Arc;
use std::sync::atomic::Ordering;
use std::task::{Context, Poll};
use std::time::Instant;

use axum::Router;
use axum::extract::Request;
use axum::http::{HeaderValue, Method, Version, header};
use axum::response::{IntoResponse, Response};
use bytes::Bytes;
use tower::Service;

use super::App;
use super::cache::Entry;
use super::conditional::{self, Conditional};
use super::http;
use super::loaders;
use super::native::{self, BLOB_ROUTE};
use super::problem::Problem;
use super::tiles3d;
use crate::formats::tiles3d::GLB_TYPE;

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

    pub(super) fn metrics(&self) -> &Arc<super::Metrics> {
        &self.app.metrics
    }

    /// Can the wire-level fast path answer anything on this server? Not with a read token or a
    /// rate limit: those requests take the router's way.
    pub(super) fn wire_enabled(&self) -> bool {
        self.app.config.read_token.is_none() && !self.app.rate.enabled()
    }

    /// What to do with the request at the start of `buf` (a connection's unanswered bytes):
    /// wait for more bytes, hand the connection to hyper, or send the response written into
    /// `out` (head) followed by the body, after consuming the request's bytes.
    pub(super) fn wire_step(&self, buf: &[u8], out: &mut Vec<u8>) -> Step {
        wire_step(&self.app, buf, out)
    }
}

/// Most bytes of a request head the wire-level fast path reads; a longer head is hyper's (which
/// answers `431` past its own, larger, limit).
pub(super) const WIRE_MAX_HEAD: usize = 8 * 1024;
/// Most header fields of a request the wire-level fast path parses; more go to hyper.
const WIRE_MAX_HEADERS: usize = 32;

/// The wire-level fast path's decision on the request at the start of a connection's buffer.
#[derive(Debug)]
pub(super) enum Step {
    /// The head is not complete yet (and within [`WIRE_MAX_HEAD`]).
    NeedMore,
    /// Not one the fast path answers: hyper takes the connection, from the request's first byte.
    Handoff,
    /// The response head is in `out`; send it, then `body`, and drop `consumed` bytes of the
    /// buffer (the request). With `close`, close the connection after it.
    Answer { consumed: usize, body: Bytes, close: bool },
}

fn wire_step(app: &App, buf: &[u8], out: &mut Vec<u8>) -> Step {
    let start = Instant::now();
    let mut headers = [httparse::EMPTY_HEADER; WIRE_MAX_HEADERS];
    let mut req = httparse::Request::new(&mut headers);
    let consumed = match req.parse(buf) {
        Ok(httparse::Status::Complete(n)) => n,
        Ok(httparse::Status::Partial) if buf.len() < WIRE_MAX_HEAD => return Step::NeedMore,
        // Too long, too many fields, or malformed: hyper's limits and error answers.
        Ok(httparse::Status::Partial) | Err(_) => return Step::Handoff,
    };
    let method = match req.method {
        Some("GET") => Method::GET,
        Some("HEAD") => Method::HEAD,
        _ => return Step::Handoff,
    };
    let (Some(1), Some(target)) = (req.version, req.path) else { return Step::Handoff };
    if !target.starts_with('/') || !target.bytes().all(plain_target_byte) {
        return Step::Handoff;
    }
    let mut host = 0;
    let mut close = false;
    let mut if_none_match = None;
    let mut accept_encoding = None;
    for h in req.headers.iter() {
        let name = h.name;
        if name.eq_ignore_ascii_case("host") {
            host += 1;
            if !plain_host(h.value) {
                return Step::Handoff;
            }
        } else if name.eq_ignore_ascii_case("connection") {
            for token in h.value.split(|&b| b == b',') {
                let token = token.trim_ascii();
                if token.eq_ignore_ascii_case(b"close") {
                    close = true;
                } else if !token.eq_ignore_ascii_case(b"keep-alive") {
                    return Step::Handoff;
                }
            }
        } else if name.eq_ignore_ascii_case("if-none-match") {
            if if_none_match.is_some() {
                return Step::Handoff;
            }
            if_none_match = Some(h.value);
        } else if name.eq_ignore_ascii_case("accept-encoding") {
            // The router reads the first of several; the fast path takes only one.
            if accept_encoding.is_some() {
                return Step::Handoff;
            }
            accept_encoding = Some(h.value);
        } else if ["content-length", "transfer-encoding", "expect", "upgrade", "range", "if-range"]
            .iter()
            .any(|n| name.eq_ignore_ascii_case(n))
        {
            return Step::Handoff;
        }
    }
    if host != 1 || app.in_flight.load(Ordering::Relaxed) >= app.config.max_in_flight {
        return Step::Handoff;
    }
    let (path, query) = match target.split_once('?') {
        Some((p, q)) => (p, Some(q)),
        None => (target, None),
    };
    // A blob (counted as a cache hit, as the router's blob handler counts it), or a GLB in the
    // negotiated coding (`Some(Content-Encoding)`).
    let (entry, cache, glb) = if let Some((entry, cache)) = lookup(app, path, query) {
        app.metrics.cache_hits.fetch_add(1, Ordering::Relaxed);
        (entry, cache, None)
    } else if let Some((entry, cache, coding)) = tiles3d::cached_glb(app, path, query, accept_encoding) {
        (entry, cache, Some(coding))
    } else {
        return Step::Handoff;
    };
    let not_modified = if_none_match.is_some_and(|v| conditional::none_match_bytes(v, entry.etag.as_bytes()));
    // The headers in the order hyper writes the router's response (a test compares them).
    out.clear();
    out.extend_from_slice(if not_modified {
        b"HTTP/1.1 304 Not Modified\r\n"
    } else {
        b"HTTP/1.1 200 OK\r\n"
    });
    for (name, value) in [
        (&b"etag: "[..], entry.etag.as_bytes()),
        (b"cache-control: ", cache.as_bytes()),
        (b"accept-ranges: ", b"bytes"),
    ] {
        push_header(out, name, value);
    }
    let len = entry.bytes.len();
    if !not_modified {
        let kind = if glb.is_some() { GLB_TYPE } else { native::BLOB_TYPE };
        push_header(out, b"content-type: ", kind.as_bytes());
        out.extend_from_slice(b"content-length: ");
        // Writing into a Vec cannot fail.
        let _ = write!(out, "{len}\r\n");
    }
    if let Some(coding) = glb {
        if let Some(token) = coding {
            push_header(out, b"content-encoding: ", token.as_bytes());
        }
        push_header(out, b"vary: ", b"accept-encoding");
    }
    push_header(out, b"access-control-expose-headers: ", http::EXPOSE_HEADERS.as_bytes());
    push_header(out, b"access-control-allow-origin: ", b"*");
    if not_modified && method == Method::HEAD {
        // The router's answer to a HEAD carries its empty body's length, even on a 304.
        push_header(out, b"content-length: ", b"0");
    }
    if close {
        push_header(out, b"connection: ", b"close");
    }
    out.extend_from_slice(b"date: ");
    push_date(out);
    out.extend_from_slice(b"\r\n\r\n");
    let status = if not_modified { 304 } else { 200 };
    let sent = (!not_modified && method == Method::GET).then_some(len as u64);
    let route = if glb.is_some() { tiles3d::GLB_ROUTE } else { BLOB_ROUTE };
    http::observe_status(app, route, &method, path, status, sent, start);
    app.metrics.wire_answers.fetch_add(1, Ordering::Relaxed);
    let body = if sent.is_some() { entry.bytes } else { Bytes::new() };
    Step::Answer { consumed, body, close }
}

fn push_header(out: &mut Vec<u8>, name: &[u8], value: &[u8]) {
    out.extend_from_slice(name);
    out.extend_from_slice(value);
    out.extend_from_slice(b"\r\n");
}

/// The `Date` value (IMF-fixdate) of this second, formatted once a second per thread.
fn push_date(out: &mut Vec<u8>) {
    use std::cell::RefCell;
    use std::time::{SystemTime, UNIX_EPOCH};
    thread_local! {
        static DATE: RefCell<(u64, String)> = const { RefCell::new((u64::MAX, String::new())) };
    }
    let now = SystemTime::now();
    let second = now.duration_since(UNIX_EPOCH).map_or(0, |d| d.as_secs());
    DATE.with_borrow_mut(|(at, text)| {
        if *at != second {
            *at = second;
            *text = httpdate::fmt_http_date(now);
        }
        out.extend_from_slice(text.as_bytes());
    });
}

/// A request-target byte the fast path takes as is: RFC 3986's unreserved, sub-delims, `:`,
/// `@`, `/`, `?` and `%` (all of which hyper's URI parser accepts too).
fn plain_target_byte(b: u8) -> bool {
    b.is_ascii_alphanumeric() || b"-._~!$&'()*+,;=:@/?%".contains(&b)
}

/// A `Host` value the fast path takes as valid without parsing it as an authority: empty, or a
/// name or IPv4 address of letters, digits, `.` and `-`, with an optional port of 1 to 5
/// digits. Anything else (IPv6 literals included) takes hyper's way, where `bad_host` decides.
fn plain_host(v: &[u8]) -> bool {
    let (name, port) = match v.iter().position(|&b| b == b':') {
        Some(i) => (&v[..i], Some(&v[i + 1..])),
        None => (v, None),
    };
    let name_ok = name.iter().all(|&b| b.is_ascii_alphanumeric() || b == b'.' || b == b'-');
    let port_ok = port.is_none_or(|p| (1..=5).contains(&p.len()) && p.iter().all(u8::is_ascii_digit));
    (v.is_empty() || !name.is_empty()) && name_ok && port_ok
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
    let (entry, cache) = lookup(app, path, req.uri().query())?;
    app.metrics.cache_hits.fetch_add(1, Ordering::Relaxed);
    let cond = Conditional::from_headers(req.headers());
    let mut resp = conditional::send(req.method(), &cond, &entry, native::BLOB_TYPE, cache);
    // What the CORS layer adds to every response.
    let h = resp.headers_mut();
    h.insert(header::ACCESS_CONTROL_EXPOSE_HEADERS, HeaderValue::from_static(http::EXPOSE_HEADERS));
    h.insert(header::ACCESS_CONTROL_ALLOW_ORIGIN, HeaderValue::from_static("*"));
    http::observe(app, BLOB_ROUTE, req.method(), path, &resp, start);
    Some(resp)
}

/// The in-memory blob `path` names and its `Cache-Control` for `query`, when `path` is a blob's
/// (not percent-encoded: the router decodes those) and the blob is in memory.
fn lookup(app: &App, path: &str, query: Option<&str>) -> Option<(Entry, &'static str)> {
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
    Some((entry, loaders::versioned_cache(&ts, query)))
}

#[cfg(test)]
#[allow(clippy::unwrap_used)]
mod tests {
    use super::*;

    #[test]
    fn plain_hosts_are_valid_authorities() {
        let ok = ["", "localhost", "localhost:8080", "a.b-c.example", "127.0.0.1:1", "x:65535", "x:99999"];
        for h in ok {
            assert!(plain_host(h.as_bytes()), "{h}");
            assert!(h.is_empty() || axum::http::uri::Authority::try_from(h.as_bytes()).is_ok(), "{h}");
        }
        // Not plain (hyper's way decides): IPv6 literals, userinfo, spaces, empty names or ports.
        for h in ["[::1]:80", "a@b", "a b", ":80", "a:", "a:123456", "a:8a", "a:1:2", "a/b", "a\tb", "ä"] {
            assert!(!plain_host(h.as_bytes()), "{h}");
        }
    }

    #[test]
    fn plain_targets_are_valid_uris() {
        let all: String = (0u8..=255).filter(|&b| plain_target_byte(b)).map(char::from).collect();
        assert!(all.is_ascii() && !all.contains(['#', ' ', '"', '<', '>', '\\', '^', '`', '{', '|', '}']));
        let target = format!("/{}", all.replace('%', "%25"));
        assert!(target.parse::<axum::http::Uri>().is_ok(), "{target}");
    }

    #[test]
    fn none_match_on_bytes_is_none_match() {
        let etag = HeaderValue::from_static("\"abc\"");
        for v in ["\"abc\"", "W/\"abc\"", "\"x\", \"abc\"", "*", "\"x\"", "", "abc", "\"abc\" ,\t\"y\""] {
            let h = HeaderValue::from_str(v).unwrap();
            let hv = h.to_str().is_ok_and(|s| {
                s.split(',').map(str::trim).any(|t| t == "*" || t.trim_start_matches("W/") == "\"abc\"")
            });
            assert_eq!(conditional::none_match_bytes(v.as_bytes(), etag.as_bytes()), hv, "{v}");
        }
        assert!(!conditional::none_match_bytes(b"\"abc\", \xff", etag.as_bytes()));
    }
}
