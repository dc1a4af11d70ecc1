//! Bearer tokens: the read token (`--read-token`) and the admin API's (`--admin-token`).

use axum::http::{HeaderMap, StatusCode, header};

use super::problem::Problem;

/// Constant-time comparison (no early exit on the first differing byte).
fn ct_eq(a: &[u8], b: &[u8]) -> bool {
    let mut diff = a.len() ^ b.len();
    for i in 0..a.len().max(b.len()) {
        diff |= usize::from(a.get(i).copied().unwrap_or(0) ^ b.get(i).copied().unwrap_or(0));
    }
    diff == 0
}

/// `401` without a bearer token, `403` with a wrong one.
pub fn check_bearer(headers: &HeaderMap, expected: &str, what: &str) -> Result<(), Problem> {
    // The scheme is case-insensitive (RFC 9110 §11.1): `Bearer`, `bearer`, `BEARER`, …
    let given = headers
        .get(header::AUTHORIZATION)
        .and_then(|v| v.to_str().ok())
        .and_then(|v| v.trim_start().split_once(' '))
        .and_then(|(scheme, token)| scheme.eq_ignore_ascii_case("bearer").then_some(token));
    match given {
        None => Err(Problem {
            challenge: true,
            ..Problem::new(
                StatusCode::UNAUTHORIZED,
                "unauthorized",
                format!("{what} needs an `Authorization: Bearer <token>` header"),
            )
        }),
        Some(t) if ct_eq(t.trim().as_bytes(), expected.as_bytes()) => Ok(()),
        Some(_) => Err(Problem::new(StatusCode::FORBIDDEN, "forbidden", format!("wrong token for {what}"))),
    }
}

#[cfg(test)]
#[allow(clippy::unwrap_used)]
mod tests {
    use axum::http::HeaderValue;

    use super::*;

    #[test]
    fn bearer_scheme_is_case_insensitive() {
        let h = |v: &str| {
            let mut m = HeaderMap::new();
            m.insert(header::AUTHORIZATION, HeaderValue::from_str(v).unwrap());
            m
        };
        for v in
            ["Bearer secret-token", "bearer secret-token", "BEARER secret-token", "bEaReR  secret-token "]
        {
            assert!(check_bearer(&h(v), "secret-token", "x").is_ok(), "{v}");
        }
        assert_eq!(check_bearer(&h("Basic secret-token"), "secret-token", "x").unwrap_err().status, 401);
        assert_eq!(check_bearer(&h("Bearersecret-token"), "secret-token", "x").unwrap_err().status, 401);
        assert_eq!(check_bearer(&h("BEARER wrong-token"), "secret-token", "x").unwrap_err().status, 403);
        assert_eq!(check_bearer(&HeaderMap::new(), "secret-token", "x").unwrap_err().status, 401);
    }

    #[test]
    fn constant_time_eq() {
        assert!(ct_eq(b"secret-token", b"secret-token"));
        assert!(!ct_eq(b"secret-token", b"secret-tokeN"));
        assert!(!ct_eq(b"secret-token", b"secret-token-longer"));
        assert!(!ct_eq(b"", b"x"));
    }
}
