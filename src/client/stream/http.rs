//! A minimal blocking HTTP/1.1 GET client over `std::net::TcpStream` for the reference client:
//! one connection per request (`Connection: close`), `Content-Length` or chunked bodies, a
//! deadline on connect and on every read. Plain `http://` only — the client talks to
//! `terrastream serve`, which a TLS-terminating proxy fronts in production.
//!
//! Kept dependency-free on purpose: the client's request logic lives in the pure scheduler
//! ([`crate::client::stream::fetch`]); this only moves bytes, so it needs no async runtime.

use std::io::{Read, Write};
use std::net::{SocketAddr, TcpStream, ToSocketAddrs};
use std::time::{Duration, Instant};

/// Largest response body accepted (a blob or index chunk is far smaller).
pub const MAX_BODY_BYTES: usize = 256 << 20;
/// Largest response head accepted.
const MAX_HEAD_BYTES: usize = 64 << 10;

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
    pub fn parse(url: &str) -> Result<Self, String> {
        let rest = url
            .strip_prefix("http://")
            .ok_or_else(|| format!("--url {url:?}: only http:// URLs are supported"))?;
        let (authority, path) = rest.find('/').map_or((rest, ""), |i| (&rest[..i], &rest[i..]));
        if authority.is_empty() {
            return Err(format!("--url {url:?}: no host"));
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
    pub fn resolve(&self) -> Result<SocketAddr, String> {
        self.authority
            .to_socket_addrs()
            .map_err(|e| format!("{}: {e}", self.authority))?
            .next()
            .ok_or_else(|| format!("{}: resolves to no address", self.authority))
    }
}

/// A response: status, the headers we use, body.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Response {
    pub status: u16,
    /// Raw `Retry-After` header value, if any.
    pub retry_after: Option<String>,
    pub body: Vec<u8>,
}

/// GETs `path` (absolute, starting with `/`) from `addr`, giving up after `timeout` in total.
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
    let head_end = loop {
        s.set_read_timeout(Some(left()?))?;
        let n = s.read(&mut chunk)?;
        if n == 0 {
            return Err(bad("connection closed before the response head"));
        }
        buf.extend_from_slice(&chunk[..n]);
        if let Some(i) = find(&buf, b"\r\n\r\n") {
            break i;
        }
        if buf.len() > MAX_HEAD_BYTES {
            return Err(bad("response head too large"));
        }
    };
    let head = std::str::from_utf8(&buf[..head_end]).map_err(|_| bad("response head is not UTF-8"))?;
    let mut lines = head.split("\r\n");
    let status_line = lines.next().unwrap_or_default();
    let status: u16 = status_line
        .split(' ')
        .nth(1)
        .and_then(|c| c.parse().ok())
        .ok_or_else(|| bad(&format!("bad status line {status_line:?}")))?;
    let (mut length, mut chunked, mut retry_after) = (None, false, None);
    for line in lines {
        let Some((name, value)) = line.split_once(':') else { continue };
        let value = value.trim();
        if name.eq_ignore_ascii_case("content-length") {
            length = Some(value.parse::<usize>().map_err(|_| bad("bad Content-Length"))?);
        } else if name.eq_ignore_ascii_case("transfer-encoding") {
            chunked = value.to_ascii_lowercase().contains("chunked");
        } else if name.eq_ignore_ascii_case("retry-after") {
            retry_after = Some(value.to_owned());
        }
    }
    if length.is_some_and(|l| l > MAX_BODY_BYTES) {
        return Err(bad("response body too large"));
    }
    let mut body = buf.split_off(head_end + 4);
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
    Ok(Response { status, retry_after, body })
}

fn bad(msg: &str) -> std::io::Error {
    std::io::Error::new(std::io::ErrorKind::InvalidData, msg.to_owned())
}

fn find(hay: &[u8], needle: &[u8]) -> Option<usize> {
    hay.windows(needle.len()).position(|w| w == needle)
}

/// Decodes a chunked transfer-encoded body; `None` when it is malformed or incomplete.
fn dechunk(mut b: &[u8]) -> Option<Vec<u8>> {
    let mut out = Vec::new();
    loop {
        let eol = find(b, b"\r\n")?;
        let size_s = std::str::from_utf8(&b[..eol]).ok()?;
        let size = usize::from_str_radix(size_s.split(';').next()?.trim(), 16).ok()?;
        b = &b[eol + 2..];
        if size == 0 {
            return Some(out);
        }
        if b.len() < size + 2 || out.len() + size > MAX_BODY_BYTES {
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
        assert!(BaseUrl::parse("https://x").unwrap_err().contains("only http://"));
        assert!(BaseUrl::parse("http:///x").unwrap_err().contains("no host"));
    }

    #[test]
    fn chunked_bodies() {
        assert_eq!(dechunk(b"3\r\nabc\r\n2;x=1\r\nde\r\n0\r\n\r\n").unwrap(), b"abcde");
        assert!(dechunk(b"5\r\nab").is_none());
        assert!(dechunk(b"zz\r\n").is_none());
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
        let r = get(addr, "h", "/a", Duration::from_secs(5)).unwrap();
        assert_eq!((r.status, r.retry_after.as_deref()), (503, Some("2")));
        t.join().unwrap();
        // Nobody listening any more: a connection error, not a panic.
        assert!(get(addr, "h", "/a", Duration::from_millis(500)).is_err());
    }
}
