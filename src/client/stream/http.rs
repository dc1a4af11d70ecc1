//! The one HTTP client of the crate and its tests: a blocking HTTP/1.1 GET over
//! `std::net::TcpStream`, one connection per request (`Connection: close`), `Content-Length`,
//! chunked or close-delimited bodies, a deadline on connect and on every read. Plain `http://`
//! only — the client talks to `terrastream serve`, which a TLS-terminating proxy fronts in
//! production. The integration tests call [`get`] too (`tests/common`), so what they check is
//! what the client sends and reads.
//!
//! The response head and chunk sizes are parsed by `httparse` (hyper's parser, no dependencies
//! of its own); the rest is moving bytes. A full client crate was weighed and left out:
//! `reqwest`'s blocking client (in the lock file through `object_store`) or `hyper`'s would
//! bring a tokio runtime and, for reqwest, a TLS stack into the `client` feature, which the
//! pure scheduler ([`crate::client::stream::fetch`]) does not need for one GET per connection
//! on its worker threads.

use std::io::{Read, Write};
use std::net::{SocketAddr, TcpStream, ToSocketAddrs};
use std::time::{Duration, Instant};

/// Largest response body accepted (a blob or index chunk is far smaller).
pub const MAX_BODY_BYTES: usize = 256 << 20;
/// Largest response head accepted.
const MAX_HEAD_BYTES: usize = 64 << 10;

/// What is wrong with a `--url`, or why its host has no address.
#[derive(Debug, thiserror::Error)]
pub enum UrlError {
    #[error("--url {url:?}: only http:// URLs are supported")]
    NotHttp { url: String },
    #[error("--url {url:?}: no host")]
    NoHost { url: String },
    #[error("{authority}: {source}")]
    Resolve { authority: String, source: std::io::Error },
    #[error("{authority}: resolves to no address")]
    NoAddress { authority: String },
}

/// A parsed `http://host:port/prefix` base URL.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct BaseUrl {
    /// `host:port` as written (sent as the `Host` header).
    pub authority: String,
    /// Path prefix without a trailing slash (`""` for the root).
    pub prefix: String,
}

impl BaseUrl {
    /// Parses `http://HOST[:PORT][/PREFIX]`; the error says what is wrong with the URL.
    pub fn parse(url: &str) -> Result<Self, UrlError> {
        let rest = url.strip_prefix("http://").ok_or_else(|| UrlError::NotHttp { url: url.to_owned() })?;
        let (authority, path) = rest.find('/').map_or((rest, ""), |i| (&rest[..i], &rest[i..]));
        if authority.is_empty() {
            return Err(UrlError::NoHost { url: url.to_owned() });
        }
        let authority =
            if authority.rsplit_once(':').is_some_and(|(_, p)| p.bytes().all(|b| b.is_ascii_digit()))
                && !authority.ends_with(']')
            {
                authority.to_owned()
            } else {
                format!("{authority}:80")
            };
        Ok(Self { authority, prefix: path.trim_end_matches('/').to_owned() })
    }

    /// Resolves the host (first address).
    pub fn resolve(&self) -> Result<SocketAddr, UrlError> {
        self.authority
            .to_socket_addrs()
            .map_err(|source| UrlError::Resolve { authority: self.authority.clone(), source })?
            .next()
            .ok_or_else(|| UrlError::NoAddress { authority: self.authority.clone() })
    }
}

/// Most header lines a response may have.
const MAX_HEADERS: usize = 64;

/// A response: status, headers, body.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Response {
    pub status: u16,
    /// Raw `Retry-After` header value, if any.
    pub retry_after: Option<String>,
    /// Every header line in order: (lower-case name, value without surrounding blanks).
    pub headers: Vec<(String, String)>,
    pub body: Vec<u8>,
}

impl Response {
    /// The first value of header `name` (any case).
    #[must_use]
    pub fn header(&self, name: &str) -> Option<&str> {
        self.headers.iter().find(|(n, _)| n.eq_ignore_ascii_case(name)).map(|(_, v)| v.as_str())
    }
}

/// GETs `path` (absolute, starting with `/`) from `addr`, sending `host` as the `Host` header,
/// giving up after `timeout` in total. Errors: connecting, a timeout (`TimedOut`), a malformed
/// or oversized head or body (`InvalidData`, the message says which).
pub fn get(addr: SocketAddr, host: &str, path: &str, timeout: Duration) -> std::io::Result<Response> {
    let deadline = Instant::now() + timeout;
    let left = || {
        deadline
            .checked_duration_since(Instant::now())
            .filter(|d| !d.is_zero())
            .ok_or_else(|| std::io::Error::new(std::io::ErrorKind::TimedOut, "request timed out"))
    };
    let mut s = TcpStream::connect_timeout(&addr, left()?)?;
    s.set_nodelay(true)?;
    s.set_write_timeout(Some(left()?))?;
    write!(
        s,
        "GET {path} HTTP/1.1\r\nHost: {host}\r\nAccept-Encoding: identity\r\nConnection: close\r\n\r\n"
    )?;
    let mut buf = Vec::new();
    let mut chunk = vec![0u8; 64 << 10];
    let (head_len, status, headers) = loop {
        s.set_read_timeout(Some(left()?))?;
        let n = s.read(&mut chunk)?;
        if n == 0 {
            return Err(bad("connection closed before the response head"));
        }
        buf.extend_from_slice(&chunk[..n]);
        let mut slots = [httparse::EMPTY_HEADER; MAX_HEADERS];
        let mut head = httparse::Response::new(&mut slots);
        match head.parse(&buf) {
            Ok(httparse::Status::Complete(len)) => {
                let status = head.code.ok_or_else(|| bad("response without a status code"))?;
                let headers: Vec<(String, String)> = head
                    .headers
                    .iter()
                    .map(|h| {
                        (h.name.to_ascii_lowercase(), String::from_utf8_lossy(h.value).trim().to_owned())
                    })
                    .collect();
                break (len, status, headers);
            }
            Ok(httparse::Status::Partial) if buf.len() <= MAX_HEAD_BYTES => {}
            Ok(httparse::Status::Partial) | Err(httparse::Error::TooManyHeaders) => {
                return Err(bad("response head too large"));
            }
            Err(e) => return Err(bad(&format!("malformed response head: {e}"))),
        }
    };
    let (mut length, mut chunked, mut retry_after) = (None, false, None);
    for (name, value) in &headers {
        match name.as_str() {
            "content-length" => {
                length = Some(value.parse::<usize>().map_err(|_| bad("bad Content-Length"))?);
            }
            "transfer-encoding" => chunked = value.to_ascii_lowercase().contains("chunked"),
            "retry-after" => retry_after = Some(value.clone()),
            _ => {}
        }
    }
    if length.is_some_and(|l| l > MAX_BODY_BYTES) {
        return Err(bad("response body too large"));
    }
    let mut body = buf.split_off(head_len);
    loop {
        if length.is_some_and(|l| body.len() >= l) {
            break;
        }
        s.set_read_timeout(Some(left()?))?;
        let n = s.read(&mut chunk)?;
        if n == 0 {
            break;
        }
        body.extend_from_slice(&chunk[..n]);
        if body.len() > MAX_BODY_BYTES + MAX_HEAD_BYTES {
            return Err(bad("response body too large"));
        }
    }
    if let Some(l) = length {
        if body.len() < l {
            return Err(bad(&format!("body cut short: {} of {l} bytes", body.len())));
        }
        body.truncate(l);
    } else if chunked {
        body = dechunk(&body).ok_or_else(|| bad("malformed chunked body"))?;
    }
    Ok(Response { status, retry_after, headers, body })
}

fn bad(msg: &str) -> std::io::Error {
    std::io::Error::new(std::io::ErrorKind::InvalidData, msg.to_owned())
}

/// Decodes a chunked transfer-encoded body; `None` when it is malformed or incomplete.
fn dechunk(mut b: &[u8]) -> Option<Vec<u8>> {
    let mut out = Vec::new();
    loop {
        let httparse::Status::Complete((used, size)) = httparse::parse_chunk_size(b).ok()? else {
            return None;
        };
        let size = usize::try_from(size).ok()?;
        b = &b[used..];
        if size == 0 {
            return Some(out);
        }
        if b.len() < size.checked_add(2)?
            || out.len() + size > MAX_BODY_BYTES
            || &b[size..size + 2] != b"\r\n"
        {
            return None;
        }
        out.extend_from_slice(&b[..size]);
        b = &b[size + 2..];
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn urls() {
        let u = BaseUrl::parse("http://127.0.0.1:8080/").unwrap();
        assert_eq!((u.authority.as_str(), u.prefix.as_str()), ("127.0.0.1:8080", ""));
        let u = BaseUrl::parse("http://example.org/terrain/v1").unwrap();
        assert_eq!((u.authority.as_str(), u.prefix.as_str()), ("example.org:80", "/terrain/v1"));
        assert!(BaseUrl::parse("https://x").unwrap_err().to_string().contains("only http://"));
        assert!(BaseUrl::parse("http:///x").unwrap_err().to_string().contains("no host"));
    }

    #[test]
    fn chunked_bodies() {
        assert_eq!(dechunk(b"3\r\nabc\r\n2;x=1\r\nde\r\n0\r\n\r\n").unwrap(), b"abcde");
        assert!(dechunk(b"5\r\nab").is_none());
        assert!(dechunk(b"zz\r\n").is_none());
        assert!(dechunk(b"3\r\nabcXY0\r\n\r\n").is_none(), "chunk not closed by CRLF");
    }

    #[test]
    fn talks_to_a_socket() {
        let l = std::net::TcpListener::bind("127.0.0.1:0").unwrap();
        let addr = l.local_addr().unwrap();
        let t = std::thread::spawn(move || {
            for body in [
                "HTTP/1.1 200 OK\r\nContent-Length: 5\r\n\r\nhello",
                "HTTP/1.1 503 Busy\r\nRetry-After: 2\r\nContent-Length: 0\r\n\r\n",
            ] {
                let (mut c, _) = l.accept().unwrap();
                // The request may arrive in several reads: read up to the end of the head.
                let mut req = Vec::new();
                let mut buf = [0u8; 1024];
                while !req.windows(4).any(|w| w == b"\r\n\r\n") {
                    let n = c.read(&mut buf).unwrap();
                    assert!(n > 0, "connection closed mid-request: {req:?}");
                    req.extend_from_slice(&buf[..n]);
                }
                assert!(req.starts_with(b"GET /a HTTP/1.1\r\n"), "{:?}", String::from_utf8_lossy(&req));
                c.write_all(body.as_bytes()).unwrap();
            }
        });
        let r = get(addr, "h", "/a", Duration::from_secs(5)).unwrap();
        assert_eq!((r.status, r.body.as_slice()), (200, b"hello".as_slice()));
        assert_eq!((r.header("CONTENT-length"), r.headers.len()), (Some("5"), 1));
        let r = get(addr, "h", "/a", Duration::from_secs(5)).unwrap();
        assert_eq!((r.status, r.retry_after.as_deref()), (503, Some("2")));
        t.join().unwrap();
        // Nobody listening any more: a connection error, not a panic.
        assert!(get(addr, "h", "/a", Duration::from_millis(500)).is_err());
    }
}
