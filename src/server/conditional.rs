//! Conditional and range requests (RFC 9110): strong ETags, `If-None-Match` → 304, a single
//! `Range` → 206/416 (honoured only when `If-Range`, if any, names the ETag).

use axum::body::Body;
use axum::http::{HeaderMap, HeaderValue, Method, StatusCode, header};
use axum::response::{IntoResponse, Response};

use super::cache::Entry;
use super::problem::Problem;

/// The request headers the read handlers look at. Extracting these three values (shared bytes)
/// instead of a `HeaderMap` saves copying every request's header map on the serving path.
pub(super) struct Conditional {
    if_none_match: Option<HeaderValue>,
    range: Option<HeaderValue>,
    if_range: Option<HeaderValue>,
}

impl Conditional {
    pub(super) fn from_headers(h: &HeaderMap) -> Self {
        Self {
            if_none_match: h.get(header::IF_NONE_MATCH).cloned(),
            range: h.get(header::RANGE).cloned(),
            if_range: h.get(header::IF_RANGE).cloned(),
        }
    }
}

impl<S: Send + Sync> axum::extract::FromRequestParts<S> for Conditional {
    type Rejection = std::convert::Infallible;

    async fn from_request_parts(
        parts: &mut axum::http::request::Parts,
        _: &S,
    ) -> Result<Self, Self::Rejection> {
        Ok(Self::from_headers(&parts.headers))
    }
}

pub(super) fn etag_value(s: &str) -> HeaderValue {
    HeaderValue::from_str(s).unwrap_or_else(|_| HeaderValue::from_static("\"0\""))
}

/// Does `If-None-Match` match `etag`? (weak comparison, as RFC 9110 specifies for it)
fn none_match(if_none_match: Option<&HeaderValue>, etag: &HeaderValue) -> bool {
    if_none_match.is_some_and(|v| none_match_bytes(v.as_bytes(), etag.as_bytes()))
}

/// [`none_match`] on the raw bytes of an `If-None-Match` value (the wire-level fast path's):
/// a value that is not visible ASCII matches nothing, as `HeaderValue::to_str` fails on it.
pub(super) fn none_match_bytes(if_none_match: &[u8], etag: &[u8]) -> bool {
    let Ok(inm) = std::str::from_utf8(if_none_match) else { return false };
    if !inm.bytes().all(|b| b == b'\t' || (32..127).contains(&b)) {
        return false;
    }
    inm.split(',').map(str::trim).any(|t| t == "*" || t.trim_start_matches("W/").as_bytes() == etag)
}

enum RangeReq {
    Full,
    Part(u64, u64),
    Unsatisfiable,
}

/// One `bytes=` range; several ranges or a malformed header are ignored (the full body is sent,
/// as RFC 9110 allows).
fn parse_range(h: &str, len: u64) -> RangeReq {
    let Some(spec) = h.trim().strip_prefix("bytes=") else { return RangeReq::Full };
    if spec.contains(',') {
        return RangeReq::Full;
    }
    let Some((a, b)) = spec.trim().split_once('-') else { return RangeReq::Full };
    let num = |s: &str| -> Option<u64> {
        (!s.is_empty() && s.len() <= 19 && s.bytes().all(|c| c.is_ascii_digit()))
            .then(|| s.parse().ok())
            .flatten()
    };
    match (num(a), num(b), b.is_empty()) {
        (Some(start), None, true) => {
            if start >= len {
                RangeReq::Unsatisfiable
            } else {
                RangeReq::Part(start, len - 1)
            }
        }
        (Some(start), Some(end), _) if start <= end => {
            if start >= len {
                RangeReq::Unsatisfiable
            } else {
                RangeReq::Part(start, end.min(len - 1))
            }
        }
        (None, Some(n), _) if a.is_empty() => {
            if n == 0 || len == 0 {
                RangeReq::Unsatisfiable
            } else {
                RangeReq::Part(len.saturating_sub(n), len - 1)
            }
        }
        _ => RangeReq::Full,
    }
}

/// The response for a verified body: 304 when `If-None-Match` matches, 206/416 for a range
/// (honoured only when `If-Range`, if any, names this ETag), else 200. HEAD gets the same
/// headers (axum drops the body).
pub(super) fn send(
    method: &Method,
    headers: &Conditional,
    e: &Entry,
    content_type: &'static str,
    cache: &'static str,
) -> Response {
    // Sized once for what it will hold (ours, CORS's two, `Vary`) instead of growing per insert.
    let mut h = HeaderMap::with_capacity(12);
    h.insert(header::ETAG, e.etag.clone());
    h.insert(header::CACHE_CONTROL, HeaderValue::from_static(cache));
    h.insert(header::ACCEPT_RANGES, HeaderValue::from_static("bytes"));
    let respond = |status: StatusCode, headers: HeaderMap, body: Body| {
        let mut r = Response::new(body);
        *r.status_mut() = status;
        *r.headers_mut() = headers;
        r
    };
    if none_match(headers.if_none_match.as_ref(), &e.etag) {
        return respond(StatusCode::NOT_MODIFIED, h, Body::empty());
    }
    h.insert(header::CONTENT_TYPE, HeaderValue::from_static(content_type));
    let len = e.bytes.len() as u64;
    let range_ok = headers.if_range.as_ref().is_none_or(|v| v.as_bytes() == e.etag.as_bytes());
    let range = match headers.range.as_ref().and_then(|v| v.to_str().ok()) {
        Some(r) if range_ok && (method == Method::GET || method == Method::HEAD) => parse_range(r, len),
        _ => RangeReq::Full,
    };
    match range {
        RangeReq::Full => {
            h.insert(header::CONTENT_LENGTH, HeaderValue::from(len));
            respond(StatusCode::OK, h, Body::from(e.bytes.clone()))
        }
        RangeReq::Part(start, end) => {
            let body = e.bytes.slice(start as usize..=end as usize);
            if let Ok(v) = HeaderValue::from_str(&format!("bytes {start}-{end}/{len}")) {
                h.insert(header::CONTENT_RANGE, v);
            }
            h.insert(header::CONTENT_LENGTH, HeaderValue::from(body.len()));
            respond(StatusCode::PARTIAL_CONTENT, h, Body::from(body))
        }
        RangeReq::Unsatisfiable => {
            let mut r = Problem::new(
                StatusCode::RANGE_NOT_SATISFIABLE,
                "range-not-satisfiable",
                format!("the range lies outside the {len} bytes of this resource"),
            )
            .into_response();
            if let Ok(v) = HeaderValue::from_str(&format!("bytes */{len}")) {
                r.headers_mut().insert(header::CONTENT_RANGE, v);
            }
            r
        }
    }
}

#[cfg(test)]
#[allow(clippy::unwrap_used)]
mod tests {
    use super::*;

    #[test]
    fn ranges() {
        let p = |h: &str| match parse_range(h, 100) {
            RangeReq::Full => "full".to_owned(),
            RangeReq::Part(a, b) => format!("{a}-{b}"),
            RangeReq::Unsatisfiable => "416".to_owned(),
        };
        assert_eq!(p("bytes=0-9"), "0-9");
        assert_eq!(p("bytes=90-"), "90-99");
        assert_eq!(p("bytes=-10"), "90-99");
        assert_eq!(p("bytes=-1000"), "0-99");
        assert_eq!(p("bytes=50-1000"), "50-99");
        assert_eq!(p("bytes=100-"), "416");
        assert_eq!(p("bytes=100-200"), "416");
        assert_eq!(p("bytes=-0"), "416");
        assert_eq!(p("bytes=9-1"), "full");
        assert_eq!(p("bytes=0-1,5-6"), "full");
        assert_eq!(p("items=0-1"), "full");
        assert_eq!(p("bytes=a-b"), "full");
        assert_eq!(p("bytes=-"), "full");
    }
}
