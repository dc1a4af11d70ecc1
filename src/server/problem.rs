//! RFC 9457 problem details: every error the server answers is `application/problem+json` with
//! a stable `type`, a `title` and a `detail` naming what was wrong with the request. Errors are
//! never cached (`Cache-Control: no-store`), so a CDN does not keep a transient failure.

use axum::http::{HeaderValue, StatusCode, header};
use axum::response::{IntoResponse, Response};

pub const PROBLEM_JSON: &str = "application/problem+json";

#[derive(Debug, Clone)]
pub struct Problem {
    pub status: StatusCode,
    /// Short machine-readable slug (the `type` is `urn:terrastream:problem:<slug>`).
    pub slug: &'static str,
    pub detail: String,
    pub retry_after: Option<u32>,
    /// `WWW-Authenticate` challenge for 401.
    pub challenge: bool,
}

impl Problem {
    pub fn new(status: StatusCode, slug: &'static str, detail: impl Into<String>) -> Self {
        Self { status, slug, detail: detail.into(), retry_after: None, challenge: false }
    }
    pub fn bad_request(detail: impl Into<String>) -> Self {
        Self::new(StatusCode::BAD_REQUEST, "bad-request", detail)
    }
    pub fn not_found(detail: impl Into<String>) -> Self {
        Self::new(StatusCode::NOT_FOUND, "not-found", detail)
    }
    pub fn unavailable(slug: &'static str, detail: impl Into<String>, retry_after: u32) -> Self {
        Self { retry_after: Some(retry_after), ..Self::new(StatusCode::SERVICE_UNAVAILABLE, slug, detail) }
    }
    pub fn internal(slug: &'static str, detail: impl Into<String>) -> Self {
        Self::new(StatusCode::INTERNAL_SERVER_ERROR, slug, detail)
    }
}

/// The problem document for `status` with `detail`, as bytes.
#[must_use]
pub fn body(status: StatusCode, slug: &str, detail: &str) -> String {
    serde_json::json!({
        "type": format!("urn:terrastream:problem:{slug}"),
        "title": status.canonical_reason().unwrap_or("Error"),
        "status": status.as_u16(),
        "detail": detail,
    })
    .to_string()
}

impl IntoResponse for Problem {
    fn into_response(self) -> Response {
        let mut r = (self.status, body(self.status, self.slug, &self.detail)).into_response();
        let h = r.headers_mut();
        h.insert(header::CONTENT_TYPE, HeaderValue::from_static(PROBLEM_JSON));
        h.insert(header::CACHE_CONTROL, HeaderValue::from_static("no-store"));
        if let Some(s) = self.retry_after {
            h.insert(header::RETRY_AFTER, HeaderValue::from(s));
        }
        if self.challenge {
            h.insert(header::WWW_AUTHENTICATE, HeaderValue::from_static("Bearer realm=\"terrastream\""));
        }
        r
    }
}

/// A generic slug and detail for error statuses produced outside our handlers (the router's
/// 404/405, the timeout layer's 408, body-limit 413s, rejections).
#[must_use]
pub fn generic(status: StatusCode) -> (&'static str, &'static str) {
    match status.as_u16() {
        400 => ("bad-request", "the request is malformed"),
        404 => ("not-found", "no such resource; see /openapi.json for the API"),
        405 => ("method-not-allowed", "this method is not allowed here; see the Allow header"),
        408 => ("timeout", "the request took longer than the server's request timeout"),
        413 => ("too-large", "the request body is larger than the server accepts"),
        415 => ("unsupported-media-type", "unsupported request content type"),
        422 => ("unprocessable", "the request could not be processed"),
        _ => ("error", "the request failed"),
    }
}
