//! The HTTP server end to end on `127.0.0.1:0`: caching semantics (ETag/304, Range, HEAD, CORS),
//! every error status as problem+json, auth, path traversal, random paths and headers, on-demand
//! single flight, the bounded bake queue, store polling, the admin API, graceful shutdown, and a
//! blob corrupted on disk. Requests are written by hand over TCP so that paths reach the server
//! exactly as given (no client-side normalisation of `..` or `%2F`).

// Helpers outside `#[test]` functions unwrap too: a failure there is a test failure.
#![allow(clippy::unwrap_used, clippy::expect_used, clippy::float_cmp, clippy::panic)]
#![allow(clippy::large_futures, clippy::duration_suboptimal_units, clippy::format_push_string)]

mod common;

use std::net::{IpAddr, SocketAddr};
use std::path::{Path, PathBuf};
use std::time::Duration;

use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::net::TcpStream;

use common::Running;

use terrastream::bake::BakeOptions;
use terrastream::bake::PointLevels;
use terrastream::server::PartialConfig;
use terrastream::store::Store;

/// The small test raster: 4×3 leaves of 64 cells (depth 2), so row 3 at z = 2 is in the
/// quadtree but outside the data.
const WIDTH: u32 = 257;
const HEIGHT: u32 = 193;
/// An exact TIN (`max_error` 0) over the smooth test raster keeps enough vertices that both
/// point levels pay in every node (checked by `point_levels_that_do_not_pay_are_404`), so the
/// tests below may request any level.
const OPTS: BakeOptions =
    BakeOptions { tile_size: 64, max_error: 0.0, levels: 2, point_levels: PointLevels::All };

#[derive(Debug)]
struct Resp {
    status: u16,
    headers: Vec<(String, String)>,
    body: Vec<u8>,
}

impl Resp {
    fn header(&self, name: &str) -> Option<&str> {
        self.headers.iter().find(|(k, _)| k == name).map(|(_, v)| v.as_str())
    }
    fn json(&self) -> serde_json::Value {
        serde_json::from_slice(&self.body).unwrap_or_else(|e| panic!("not JSON ({e}): {self:?}"))
    }
    /// An error answer must be problem+json naming its status.
    fn assert_problem(&self, status: u16) {
        assert_eq!(self.status, status, "{self:?} body {}", String::from_utf8_lossy(&self.body));
        assert_eq!(self.header("content-type"), Some("application/problem+json"), "{self:?}");
        let j = self.json();
        assert_eq!(j["status"], status, "{j}");
        assert!(j["detail"].as_str().is_some_and(|d| !d.is_empty()), "{j}");
    }
}

fn dechunk(mut b: &[u8]) -> Vec<u8> {
    let mut out = Vec::new();
    loop {
        let Some(eol) = b.windows(2).position(|w| w == b"\r\n") else { return out };
        let size = usize::from_str_radix(std::str::from_utf8(&b[..eol]).unwrap().trim(), 16).unwrap();
        if size == 0 {
            return out;
        }
        out.extend_from_slice(&b[eol + 2..eol + 2 + size]);
        b = &b[eol + 2 + size + 2..];
    }
}

/// One request on its own connection (`Connection: close`), answered within 60 s.
async fn request(addr: SocketAddr, method: &str, path: &str, headers: &[(&str, &str)], body: &[u8]) -> Resp {
    request_from(None, addr, method, path, headers, body).await
}

/// A connection from source address `from` (any of 127/8 on Linux: a different "client").
async fn connect_from(from: Option<IpAddr>, addr: SocketAddr) -> TcpStream {
    match from {
        None => TcpStream::connect(addr).await.unwrap(),
        Some(ip) => {
            let sock = tokio::net::TcpSocket::new_v4().unwrap();
            sock.bind(SocketAddr::new(ip, 0)).unwrap();
            sock.connect(addr).await.unwrap()
        }
    }
}

/// `request` from source address `from`.
async fn request_from(
    from: Option<IpAddr>,
    addr: SocketAddr,
    method: &str,
    path: &str,
    headers: &[(&str, &str)],
    body: &[u8],
) -> Resp {
    tokio::time::timeout(Duration::from_secs(60), async {
        let mut s = connect_from(from, addr).await;
        let mut req = format!("{method} {path} HTTP/1.1\r\nHost: test\r\nConnection: close\r\n");
        for (k, v) in headers {
            req.push_str(&format!("{k}: {v}\r\n"));
        }
        if !body.is_empty() && !headers.iter().any(|(k, _)| k.eq_ignore_ascii_case("transfer-encoding")) {
            req.push_str(&format!("Content-Length: {}\r\n", body.len()));
        }
        req.push_str("\r\n");
        s.write_all(req.as_bytes()).await.unwrap();
        // The server may answer (413, 409) and close before reading a body: keep what it said.
        let _ = s.write_all(body).await;
        let mut raw = Vec::new();
        let mut buf = vec![0u8; 65536];
        loop {
            match s.read(&mut buf).await {
                Ok(0) | Err(_) => break,
                Ok(n) => raw.extend_from_slice(&buf[..n]),
            }
        }
        let split =
            raw.windows(4).position(|w| w == b"\r\n\r\n").unwrap_or_else(|| panic!("no response to {path}"));
        let head = String::from_utf8_lossy(&raw[..split]).into_owned();
        let mut lines = head.split("\r\n");
        let status = lines.next().unwrap().split(' ').nth(1).unwrap().parse().unwrap();
        let headers: Vec<(String, String)> = lines
            .filter_map(|l| l.split_once(':'))
            .map(|(k, v)| (k.trim().to_ascii_lowercase(), v.trim().to_owned()))
            .collect();
        let rest = &raw[split + 4..];
        let chunked = headers.iter().any(|(k, v)| k == "transfer-encoding" && v.contains("chunked"));
        let body = if chunked { dechunk(rest) } else { rest.to_vec() };
        Resp { status, headers, body }
    })
    .await
    .unwrap_or_else(|_| panic!("{method} {path}: no answer within 60 s"))
}

async fn get(addr: SocketAddr, path: &str) -> Resp {
    request(addr, "GET", path, &[], &[]).await
}

/// A store with one baked tileset `t`; also returns the raster's path (for `--source`).
fn baked_store() -> (tempfile::TempDir, PathBuf, PathBuf) {
    let tmp = tempfile::tempdir().unwrap();
    let store = tmp.path().join("store");
    std::fs::create_dir_all(&store).unwrap();
    let tif = tmp.path().join("t.tif");
    common::write_synth_geotiff(&tif, (WIDTH, HEIGHT), 7, (0.0, 0.0));
    common::bake_file(&tif, &OPTS, &store.join("t"));
    (tmp, store, tif)
}

fn store_config(store: &Path) -> PartialConfig {
    PartialConfig { store: Some(store.to_owned()), poll_ms: Some(100), ..PartialConfig::default() }
}

fn metric(text: &str, name: &str) -> f64 {
    text.lines()
        .find_map(|l| l.strip_prefix(name).and_then(|r| r.strip_prefix(' ')))
        .unwrap_or_else(|| panic!("no metric {name} in\n{text}"))
        .parse()
        .unwrap()
}

#[tokio::test(flavor = "multi_thread", worker_threads = 4)]
async fn caching_semantics() {
    let (_tmp, store, _) = baked_store();
    let srv = Running::start(store_config(&store)).await;
    let a = srv.addr;

    let list = get(a, "/tilesets").await;
    assert_eq!(list.status, 200);
    let ts = &list.json()["tilesets"][0];
    assert_eq!(ts["name"], "t");
    let version = ts["content_version"].as_str().unwrap().to_owned();

    // Manifest: short max-age, revalidated by ETag.
    let m = get(a, "/tilesets/t/tileset.json").await;
    assert_eq!(m.status, 200);
    assert!(m.header("cache-control").unwrap().contains("max-age=10"), "{m:?}");
    assert_eq!(m.json()["content_version"], version.as_str());
    let etag = m.header("etag").unwrap().to_owned();
    let m304 = request(a, "GET", "/tilesets/t/tileset.json", &[("If-None-Match", &etag)], &[]).await;
    assert_eq!(m304.status, 304);
    assert!(m304.body.is_empty());

    // Index chunk.
    let idx = get(a, &format!("/tilesets/t/index/0/0/0.json?v={version}")).await;
    assert_eq!(idx.status, 200);
    assert!(!idx.json()["nodes"].as_array().unwrap().is_empty());

    // Blob: the stored bytes, strong content ETag, revalidated without the version …
    let on_disk =
        std::fs::read(Store::new(&store.join("t")).blob_path(terrastream::tiling::TileKey::new(1, 1, 0), 1))
            .unwrap();
    let b = get(a, "/tilesets/t/tiles/1/1/0/1").await;
    assert_eq!(b.status, 200);
    assert_eq!(b.body, on_disk);
    assert_eq!(b.header("content-length").unwrap(), on_disk.len().to_string());
    assert_eq!(b.header("accept-ranges"), Some("bytes"));
    let etag = b.header("etag").unwrap().to_owned();
    assert!(etag.starts_with('"') && !etag.starts_with("W/"), "strong ETag: {etag}");
    // The first request read the blob from disk through the router; now that it is in memory
    // the fast path answers: the very same bytes and headers (but the date).
    let hit = get(a, "/tilesets/t/tiles/1/1/0/1").await;
    let without_date = |r: &Resp| r.headers.iter().filter(|(k, _)| k != "date").cloned().collect::<Vec<_>>();
    assert_eq!((hit.status, &hit.body), (200, &on_disk));
    assert_eq!(without_date(&hit), without_date(&b));
    for (k, v) in
        [("access-control-allow-origin", "*"), ("cache-control", "public, max-age=60, must-revalidate")]
    {
        assert_eq!(hit.header(k), Some(v), "{hit:?}");
    }
    assert!(b.header("cache-control").unwrap().contains("must-revalidate"));
    // … immutable with the current content version, revalidated with a stale one.
    let bv = get(a, &format!("/tilesets/t/tiles/1/1/0/1?v={version}")).await;
    assert_eq!(bv.header("cache-control"), Some("public, max-age=31536000, immutable"));
    assert_eq!(bv.header("etag"), Some(etag.as_str()));
    let stale = get(a, "/tilesets/t/tiles/1/1/0/1?v=00000000").await;
    assert!(stale.header("cache-control").unwrap().contains("must-revalidate"));
    // The ETag derives from the content: another blob has another one.
    let other = get(a, "/tilesets/t/tiles/1/0/0/1").await;
    assert_ne!(other.header("etag"), Some(etag.as_str()));

    // If-None-Match → 304 (also in a list, and weak-compared).
    for inm in [etag.clone(), format!("\"nope\", {etag}"), format!("W/{etag}"), "*".into()] {
        let r = request(a, "GET", "/tilesets/t/tiles/1/1/0/1", &[("If-None-Match", &inm)], &[]).await;
        assert_eq!(r.status, 304, "{inm}");
        assert_eq!(r.header("etag"), Some(etag.as_str()));
        assert!(r.body.is_empty());
    }
    let r = request(a, "GET", "/tilesets/t/tiles/1/1/0/1", &[("If-None-Match", "\"other\"")], &[]).await;
    assert_eq!(r.status, 200);

    // Range: 206 with Content-Range, suffix ranges, 416 beyond the end, If-Range.
    let len = on_disk.len();
    let r = request(a, "GET", "/tilesets/t/tiles/1/1/0/1", &[("Range", "bytes=0-9")], &[]).await;
    assert_eq!(r.status, 206);
    assert_eq!(r.body, &on_disk[..10]);
    assert_eq!(r.header("content-range").unwrap(), format!("bytes 0-9/{len}"));
    assert_eq!(r.header("content-length"), Some("10"));
    let r = request(a, "GET", "/tilesets/t/tiles/1/1/0/1", &[("Range", "bytes=-5")], &[]).await;
    assert_eq!(r.status, 206);
    assert_eq!(r.body, &on_disk[len - 5..]);
    let r = request(a, "GET", "/tilesets/t/tiles/1/1/0/1", &[("Range", &format!("bytes={len}-"))], &[]).await;
    r.assert_problem(416);
    assert_eq!(r.header("content-range").unwrap(), format!("bytes */{len}"));
    let r = request(
        a,
        "GET",
        "/tilesets/t/tiles/1/1/0/1",
        &[("Range", "bytes=0-9"), ("If-Range", "\"old\"")],
        &[],
    )
    .await;
    assert_eq!(r.status, 200, "a stale If-Range gets the whole body");
    assert_eq!(r.body.len(), len);

    // HEAD: same headers, no body.
    let h = request(a, "HEAD", "/tilesets/t/tiles/1/1/0/1", &[], &[]).await;
    assert_eq!(h.status, 200);
    assert_eq!(h.header("content-length").unwrap(), len.to_string());
    assert_eq!(h.header("etag"), Some(etag.as_str()));
    assert!(h.body.is_empty());

    // CORS: simple requests and the preflight.
    let c =
        request(a, "GET", "/tilesets/t/tiles/1/1/0/1", &[("Origin", "https://viewer.example")], &[]).await;
    assert_eq!(c.header("access-control-allow-origin"), Some("*"));
    assert!(c.header("access-control-expose-headers").unwrap().to_ascii_lowercase().contains("etag"));
    let p = request(
        a,
        "OPTIONS",
        "/tilesets/t/tiles/1/1/0/1",
        &[
            ("Origin", "https://viewer.example"),
            ("Access-Control-Request-Method", "GET"),
            ("Access-Control-Request-Headers", "range, if-none-match"),
        ],
        &[],
    )
    .await;
    assert!(p.status == 200 || p.status == 204, "{p:?}");
    assert_eq!(p.header("access-control-allow-origin"), Some("*"));
    assert!(p.header("access-control-allow-methods").unwrap().contains("GET"));
    assert!(p.header("access-control-allow-headers").unwrap().to_ascii_lowercase().contains("range"));
    // No Vary: the CORS headers are the same for every origin (`*`), so no response varies by
    // Origin (a CDN honouring Vary would otherwise keep a copy of each blob per origin).
    assert_eq!(c.header("vary"), None, "{c:?}");
    assert_eq!(p.header("vary"), None, "{p:?}");

    // Probes, metrics, OpenAPI.
    assert_eq!(get(a, "/healthz").await.status, 200);
    let ready = get(a, "/readyz").await;
    assert_eq!((ready.status, ready.json()["tilesets"].as_u64()), (200, Some(1)));
    let api = get(a, "/openapi.json").await.json();
    assert!(api["openapi"].as_str().unwrap().starts_with("3."));
    assert!(api["paths"]["/tilesets/{name}/tiles/{z}/{x}/{y}/{level}"].is_object());
    // The document matches the router: every operation it lists is routed (neither 405 nor the
    // fallback's 404), every other method on its paths is 405 (HEAD rides along with GET).
    let paths = api["paths"].as_object().unwrap();
    assert_eq!(paths.len(), 23, "{:?}", paths.keys());
    for (path, item) in paths {
        let url = path
            .replace("{name}", "t")
            .replace("{z}", "0")
            .replace("{x}", "0")
            .replace("{y}", "0")
            .replace("{level}", "0")
            .replace("{id}", "j1");
        for method in ["GET", "HEAD", "POST", "DELETE", "PUT", "PATCH"] {
            let documented = item.get(method.to_ascii_lowercase()).is_some();
            let r = request(a, method, &url, &[], &[]).await;
            let fallback = String::from_utf8_lossy(&r.body).contains("see /openapi.json");
            if documented {
                assert!(r.status != 405 && !fallback, "{method} {url} is documented but not routed: {r:?}");
                for status in item[method.to_ascii_lowercase()]["responses"].as_object().unwrap().keys() {
                    assert!(status.len() == 3 && status.parse::<u16>().is_ok(), "{method} {path}: {status}");
                }
            } else if method != "HEAD" {
                assert_eq!(r.status, 405, "{method} {url} is routed but not documented: {r:?}");
            }
        }
    }
    let text = String::from_utf8(get(a, "/metrics").await.body).unwrap();
    // Every series the issue names: requests by route and status, latency histograms, bytes
    // sent, cache hits, bake queue depth, bakes done and failed.
    for series in [
        "terrastream_http_requests_total{",
        "terrastream_http_request_duration_seconds_bucket{",
        "terrastream_http_request_duration_seconds_sum{",
        "terrastream_http_request_duration_seconds_count{",
        "terrastream_http_response_bytes_total ",
        "terrastream_cache_hits_total ",
        "terrastream_bake_queue_depth ",
        "terrastream_bakes_done_total ",
        "terrastream_bakes_failed_total ",
    ] {
        assert!(text.lines().any(|l| l.starts_with(series)), "no {series} in\n{text}");
        let name = series.trim_end_matches(['{', ' ']);
        assert!(
            text.contains(&format!(
                "# TYPE {}",
                name.trim_end_matches("_bucket").trim_end_matches("_sum").trim_end_matches("_count")
            )),
            "{name}"
        );
    }
    assert!(text.contains("terrastream_http_requests_total{route=\"/tilesets/{name}/tiles/{z}/{x}/{y}/{level}\",status=\"304\"} 4"), "{text}");
    // `/tilesets` was requested once above and once per method by the OpenAPI check.
    assert!(
        metric(&text, "terrastream_http_request_duration_seconds_bucket{route=\"/tilesets\",le=\"+Inf\"}")
            >= 3.0
    );
    assert!(metric(&text, "terrastream_cache_hits_total") >= 10.0);
    assert!(metric(&text, "terrastream_http_response_bytes_total") > len as f64);
    srv.stop().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 4)]
async fn every_error_status_is_a_problem() {
    let (_tmp, store, _) = baked_store();
    let cfg = PartialConfig {
        admin_token: Some("admin-secret-1".into()),
        max_body_bytes: Some(1000),
        ..store_config(&store)
    };
    let srv = Running::start(cfg).await;
    let a = srv.addr;
    for path in [
        "/tilesets/t/tiles/x/0/0/0",           // not a number
        "/tilesets/t/tiles/-1/0/0/0",          // signed
        "/tilesets/t/tiles/1/0/0/99999999999", // level overflow
        "/tilesets/T/tiles/0/0/0/0",           // invalid name
        "/tilesets/t/index/0/0/0.txt",         // not Y.json
    ] {
        get(a, path).await.assert_problem(400);
    }
    // Well-formed keys that name no tile are 404 (schemathesis: a schema-valid request must
    // not be 400), including depths whose shift would overflow.
    for path in [
        "/tilesets/t/tiles/3/0/0/0",    // z beyond the depth (2)
        "/tilesets/t/tiles/1/2/0/0",    // x beyond 2^z
        "/tilesets/t/tiles/1/0/0/3",    // level beyond 0..=2
        "/tilesets/t/tiles/64/0/0/0",   // z past any shift
        "/tilesets/t/index/1/0/0.json", // not a chunk root
    ] {
        get(a, path).await.assert_problem(404);
    }
    let long = format!("/tilesets/{}/tileset.json", "a".repeat(65));
    get(a, &long).await.assert_problem(400);
    for path in [
        "/tilesets/nope/tileset.json",
        "/tilesets/nope/tiles/0/0/0/0",
        "/nothing/here",
        "/tilesets/t/tiles/0/0/0",
        "/tilesets/t/tiles/2/0/3/0",
    ] {
        get(a, path).await.assert_problem(404);
    }
    // 405 with Allow.
    let r = request(a, "PUT", "/tilesets/t/tiles/0/0/0/0", &[], &[]).await;
    r.assert_problem(405);
    assert!(r.header("allow").unwrap().contains("GET"));
    // 413: an upload over --max-body-bytes, declared or streamed.
    let auth = [("Authorization", "Bearer admin-secret-1")];
    request(a, "POST", "/tilesets/big", &auth, &[0u8; 2000]).await.assert_problem(413);
    let mut chunked = b"7d0\r\n".to_vec();
    chunked.extend_from_slice(&[0u8; 2000]);
    chunked.extend_from_slice(b"\r\n0\r\n\r\n");
    let r = request(a, "POST", "/tilesets/big", &[auth[0], ("Transfer-Encoding", "chunked")], &chunked).await;
    assert!(r.status == 413 || r.status == 400, "{r:?}");
    assert!(!store.join("big").exists());
    srv.stop().await;

    // 429 from the per-client rate limit, with Retry-After.
    let srv = Running::start(PartialConfig { rate_limit: Some(5), ..store_config(&store) }).await;
    let mut statuses = Vec::new();
    for _ in 0..30 {
        statuses.push(get(srv.addr, "/tilesets/t/tiles/0/0/0/0").await);
    }
    let limited = statuses.iter().find(|r| r.status == 429).expect("some request is rate-limited");
    limited.assert_problem(429);
    assert!(limited.header("retry-after").unwrap().parse::<u32>().unwrap() >= 1);
    assert_eq!(get(srv.addr, "/healthz").await.status, 200, "probes are never limited");
    srv.stop().await;

    // 503 from the in-flight limit, with Retry-After: one slow on-demand bake holds the only slot.
    let tmp = tempfile::tempdir().unwrap();
    let tif = tmp.path().join("big.tif");
    common::write_synth_geotiff(&tif, (1025, 1025), 3, (0.0, 0.0));
    let store2 = tmp.path().join("store");
    std::fs::create_dir_all(&store2).unwrap();
    let src = format!("big={},tile_size=256,levels=1", tif.display());
    let cfg = PartialConfig {
        sources: vec![src.parse().unwrap()],
        max_in_flight: Some(1),
        ..store_config(&store2)
    };
    let srv = Running::start(cfg).await;
    // The tile request and the first poll race for the one slot (on two serving threads they
    // are answered at the same time): when the tile request is the one refused, nothing was
    // baked, and it is sent again.
    for attempt in 1.. {
        let slow = tokio::spawn(get(srv.addr, "/tilesets/big/tiles/0/0/0/0"));
        // Asked again and again while the bake holds the slot (how long it takes depends on
        // the machine): some answer is a 503 before the bake ends.
        let mut r = get(srv.addr, "/tilesets/big/tileset.json").await;
        while r.status != 503 && !slow.is_finished() {
            tokio::time::sleep(Duration::from_millis(2)).await;
            r = get(srv.addr, "/tilesets/big/tileset.json").await;
        }
        let slow = slow.await.unwrap();
        if slow.status == 503 && attempt < 20 {
            continue;
        }
        r.assert_problem(503);
        assert!(r.header("retry-after").is_some());
        assert_eq!(slow.status, 200, "{slow:?}");
        break;
    }
    srv.stop().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 4)]
async fn auth_admin_and_read_tokens() {
    let (_tmp, store, tif) = baked_store();
    let cfg = PartialConfig {
        admin_token: Some("admin-secret-1".into()),
        read_token: Some("read-secret-1".into()),
        ..store_config(&store)
    };
    let srv = Running::start(cfg).await;
    let a = srv.addr;
    let read = [("Authorization", "Bearer read-secret-1")];
    let admin = [("Authorization", "Bearer admin-secret-1")];

    // Reading needs the read token: 401 without (with a challenge), 403 wrong.
    let r = get(a, "/tilesets/t/tileset.json").await;
    r.assert_problem(401);
    assert!(r.header("www-authenticate").unwrap().starts_with("Bearer"));
    request(a, "GET", "/tilesets/t/tileset.json", &[("Authorization", "Bearer nope-nope-nope")], &[])
        .await
        .assert_problem(403);
    let ok = request(a, "GET", "/tilesets/t/tileset.json", &read, &[]).await;
    assert_eq!(ok.status, 200);
    assert!(ok.header("vary").unwrap().to_ascii_lowercase().contains("authorization"));
    assert_eq!(get(a, "/healthz").await.status, 200, "probes stay public");

    // Admin: 401 without, 403 with the read token, then upload → job → tileset → delete.
    request(a, "DELETE", "/tilesets/t", &[], &[]).await.assert_problem(401);
    request(a, "DELETE", "/tilesets/t", &read, &[]).await.assert_problem(403);
    request(a, "GET", "/jobs/j1", &[], &[]).await.assert_problem(401);
    let body = std::fs::read(&tif).unwrap();
    let up = request(a, "POST", "/tilesets/up?tile_size=128&levels=1", &admin, &body).await;
    assert_eq!(up.status, 202, "{}", String::from_utf8_lossy(&up.body));
    let location = up.header("location").unwrap().to_owned();
    let mut state = String::new();
    for _ in 0..600 {
        let j = request(a, "GET", &location, &admin, &[]).await.json();
        state = j["state"].as_str().unwrap().to_owned();
        if state == "done" || state == "failed" {
            assert_eq!(j["nodes_done"], j["nodes_total"], "{j}");
            break;
        }
        tokio::time::sleep(Duration::from_millis(100)).await;
    }
    assert_eq!(state, "done");
    let m = request(a, "GET", "/tilesets/up/tileset.json", &read, &[]).await;
    assert_eq!(m.status, 200);
    assert_eq!(m.json()["tile_size"], 128);
    // Uploading over an existing tileset is a conflict; a bad raster fails its job, not the server.
    request(a, "POST", "/tilesets/up", &admin, b"small").await.assert_problem(409);
    let bad = request(a, "POST", "/tilesets/junk", &admin, b"not a raster at all").await;
    assert_eq!(bad.status, 202);
    let loc = bad.header("location").unwrap().to_owned();
    let mut j = serde_json::Value::Null;
    for _ in 0..100 {
        j = request(a, "GET", &loc, &admin, &[]).await.json();
        if j["state"] == "failed" {
            break;
        }
        tokio::time::sleep(Duration::from_millis(50)).await;
    }
    assert_eq!(j["state"], "failed", "{j}");
    assert!(!store.join("junk").exists());
    request(a, "POST", "/tilesets/x?colour=red", &admin, &body).await.assert_problem(400);
    // Delete.
    assert_eq!(request(a, "DELETE", "/tilesets/up", &admin, &[]).await.status, 204);
    request(a, "GET", "/tilesets/up/tileset.json", &read, &[]).await.assert_problem(404);
    request(a, "DELETE", "/tilesets/up", &admin, &[]).await.assert_problem(404);
    assert!(!store.join("up").exists());
    srv.stop().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 4)]
async fn no_path_reaches_outside_the_store() {
    let (tmp, store, _) = baked_store();
    // A secret next to the store, and one inside a tileset-shaped directory outside it.
    std::fs::write(tmp.path().join("secret.txt"), "TOP-SECRET").unwrap();
    std::fs::write(store.join("t").join("secret.txt"), "TOP-SECRET").unwrap();
    let srv = Running::start(store_config(&store)).await;
    let a = srv.addr;
    for path in [
        "/tilesets/../secret.txt",
        "/tilesets/%2e%2e/secret.txt",
        "/tilesets/%2E%2E/tileset.json",
        "/tilesets/..%2Fsecret.txt/tileset.json",
        "/tilesets/..%2fstore%2ft/tileset.json",
        "/tilesets/t/..%2F..%2Fsecret.txt",
        "/tilesets/t/tiles/..%2F..%2F..%2Fsecret.txt/0/0/0",
        "/tilesets/t/tiles/0/0/0/..%2F..%2F..%2F..%2Fsecret.txt",
        "/tilesets/t/tiles/0/0/0/%2e%2e%2f%2e%2e%2fsecret.txt",
        "/tilesets/t/index/0/0/..%2F..%2F..%2Fsecret.txt",
        "/tilesets//t/tileset.json",
        "/tilesets/t//tiles/0/0/0/0",
        "/tilesets/%252e%252e/tileset.json",
        "/tilesets/t/tiles/0/0/0/0%00",
        "/tilesets/t%2F..%2F..%2Fsecret.txt",
        "//etc/passwd",
        "/tilesets/t/secret.txt",
        "/tilesets/t/../t/secret.txt",
        "/tilesets/.%2E/secret.txt",
    ] {
        let r = get(a, path).await;
        assert!(
            (400..500).contains(&r.status),
            "{path}: status {} body {}",
            r.status,
            String::from_utf8_lossy(&r.body)
        );
        assert!(!String::from_utf8_lossy(&r.body).contains("TOP-SECRET"), "{path}");
    }
    srv.stop().await;
}

/// Random paths and header values never make the server answer 5xx or stop answering.
#[test]
fn random_paths_and_headers_never_fail_the_server() {
    use proptest::prelude::*;
    use proptest::test_runner::{Config, TestRunner};
    let rt = tokio::runtime::Builder::new_multi_thread().worker_threads(2).enable_all().build().unwrap();
    let (_tmp, store, _) = baked_store();
    let srv = rt.block_on(Running::start(store_config(&store)));
    let a = srv.addr;
    let segment = prop_oneof![
        Just("tilesets".to_owned()),
        Just("t".to_owned()),
        Just("tiles".to_owned()),
        Just("index".to_owned()),
        Just("tileset.json".to_owned()),
        Just("..".to_owned()),
        Just("%2e%2e".to_owned()),
        Just("%2F".to_owned()),
        "[0-9]{1,25}",
        "-?[0-9]{1,3}",
        "[a-zA-Z0-9%._~!$&'()*+,;=:@-]{0,16}",
    ];
    let path = proptest::collection::vec(segment, 0..8).prop_map(|s| format!("/{}", s.join("/")));
    let query = proptest::option::of("[a-zA-Z0-9=&%.-]{0,20}");
    let header = proptest::option::of(prop_oneof![
        "bytes=[0-9-]{0,12}(,[0-9-]{0,6})?",
        "\"[0-9a-f]{0,16}\"",
        "[ -~]{0,30}",
    ]);
    let method =
        prop_oneof![Just("GET"), Just("HEAD"), Just("OPTIONS"), Just("DELETE"), Just("POST"), Just("PATCH")];
    let mut runner = TestRunner::new(Config { cases: 300, ..Config::default() });
    runner
        .run(&(path, query, header.clone(), header, method), |(p, q, range, inm, method)| {
            let target = match &q {
                Some(q) => format!("{p}?{q}"),
                None => p.clone(),
            };
            let mut hs: Vec<(&str, &str)> = Vec::new();
            if let Some(r) = &range {
                hs.push(("Range", r.trim()));
            }
            if let Some(v) = &inm {
                hs.push(("If-None-Match", v.trim()));
            }
            let r = rt.block_on(request(a, method, &target, &hs, &[]));
            prop_assert!(
                r.status < 500,
                "{method} {target} {hs:?} → {} {}",
                r.status,
                String::from_utf8_lossy(&r.body)
            );
            Ok(())
        })
        .unwrap();
    let r = rt.block_on(get(a, "/tilesets/t/tiles/0/0/0/0"));
    assert_eq!(r.status, 200, "still serving");
    rt.block_on(srv.stop());
}

/// An on-demand store: `src/NAME` baked from a 1025² raster in 256-cell tiles on first request.
fn on_demand_store(side: u32) -> (tempfile::TempDir, PathBuf, String) {
    let tmp = tempfile::tempdir().unwrap();
    let tif = tmp.path().join("src.tif");
    common::write_synth_geotiff(&tif, (side, side), 11, (0.0, 0.0));
    let store = tmp.path().join("store");
    std::fs::create_dir_all(&store).unwrap();
    let spec = format!("od={},tile_size=256,max_error=0,levels=2,point_levels=all", tif.display());
    (tmp, store, spec)
}

#[tokio::test(flavor = "multi_thread", worker_threads = 4)]
async fn concurrent_requests_for_one_missing_tile_bake_it_once() {
    let (_tmp, store, spec) = on_demand_store(1025);
    let cfg = PartialConfig { sources: vec![spec.parse().unwrap()], ..store_config(&store) };
    let srv = Running::start(cfg).await;
    let a = srv.addr;
    let m = get(a, "/tilesets/od/tileset.json").await.json();
    assert_eq!(m["on_demand"], true);
    assert!(!store.join("od/tiles/1/1/1").exists());
    let mut tasks = Vec::new();
    for i in 0..100 {
        // Every level of the node: one bake serves them all.
        tasks.push(tokio::spawn(get(a, ["/tilesets/od/tiles/1/1/1/0", "/tilesets/od/tiles/1/1/1/2"][i % 2])));
    }
    let mut bodies = [None, None];
    for (i, t) in tasks.into_iter().enumerate() {
        let r = t.await.unwrap();
        assert_eq!(r.status, 200, "{}", String::from_utf8_lossy(&r.body));
        let b = bodies[i % 2].get_or_insert_with(|| r.body.clone());
        assert_eq!(b, &r.body);
    }
    let text = String::from_utf8(get(a, "/metrics").await.body).unwrap();
    assert_eq!(metric(&text, "terrastream_bakes_done_total"), 1.0, "{text}");
    assert_eq!(metric(&text, "terrastream_bakes_failed_total"), 0.0);
    assert_eq!(metric(&text, "terrastream_bake_queue_depth"), 0.0);
    // The blob on disk is what `bake` writes; the index now lists the node.
    let on_disk = std::fs::read(store.join("od/tiles/1/1/1/0.tsb")).unwrap();
    assert_eq!(bodies[0].as_ref().unwrap(), &on_disk);
    let idx = get(a, "/tilesets/od/index/0/0/0.json").await;
    assert_eq!(idx.header("cache-control"), Some("no-cache"));
    let nodes = idx.json()["nodes"].as_array().unwrap().clone();
    assert_eq!(nodes.len(), 1);
    assert_eq!(nodes[0]["key"], serde_json::json!({"z": 1, "x": 1, "y": 1}));
    // Another level of the baked node does not bake again.
    assert_eq!(get(a, "/tilesets/od/tiles/1/1/1/1").await.status, 200);
    let text = String::from_utf8(get(a, "/metrics").await.body).unwrap();
    assert_eq!(metric(&text, "terrastream_bakes_done_total"), 1.0);
    srv.stop().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 4)]
async fn a_full_bake_queue_answers_503_with_retry_after() {
    let (_tmp, store, spec) = on_demand_store(1025);
    let cfg = PartialConfig {
        sources: vec![spec.parse().unwrap()],
        bake_workers: Some(1),
        bake_queue: Some(1),
        ..store_config(&store)
    };
    let srv = Running::start(cfg).await;
    let a = srv.addr;
    // Sixteen different leaves at once: one bakes, one waits, the rest are refused.
    let mut tasks = Vec::new();
    for y in 0..4 {
        for x in 0..4 {
            let p = format!("/tilesets/od/tiles/2/{x}/{y}/0");
            tasks.push(tokio::spawn(async move { get(a, &p).await }));
        }
    }
    let mut ok = 0;
    let mut refused = 0;
    for t in tasks {
        let r = t.await.unwrap();
        match r.status {
            200 => ok += 1,
            503 => {
                r.assert_problem(503);
                assert!(r.header("retry-after").unwrap().parse::<u32>().unwrap() >= 1);
                refused += 1;
            }
            s => panic!("unexpected {s}: {}", String::from_utf8_lossy(&r.body)),
        }
    }
    assert!(ok >= 1 && refused >= 1, "ok {ok}, refused {refused}");
    assert_eq!(ok + refused, 16);
    let text = String::from_utf8(get(a, "/metrics").await.body).unwrap();
    assert_eq!(metric(&text, "terrastream_bakes_done_total"), f64::from(ok), "{text}");
    // Retried later, a refused tile bakes.
    for y in 0..4 {
        for x in 0..4 {
            assert_eq!(get(a, &format!("/tilesets/od/tiles/2/{x}/{y}/0")).await.status, 200);
        }
    }
    srv.stop().await;
}

fn walk(dir: &Path, out: &mut Vec<PathBuf>) {
    for e in std::fs::read_dir(dir).unwrap() {
        let p = e.unwrap().path();
        if p.is_dir() { walk(&p, out) } else { out.push(p) }
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 4)]
async fn graceful_shutdown_finishes_requests_in_flight() {
    let (_tmp, store, spec) = on_demand_store(1025);
    let cfg = PartialConfig {
        sources: vec![spec.parse().unwrap()],
        bake_workers: Some(1),
        shutdown_timeout_s: Some(60),
        ..store_config(&store)
    };
    let mut srv = Running::start(cfg).await;
    let a = srv.addr;
    let mut tasks = Vec::new();
    for (x, y) in [(0, 0), (1, 0), (0, 1), (1, 1)] {
        let p = format!("/tilesets/od/tiles/1/{x}/{y}/2");
        tasks.push(tokio::spawn(async move { get(a, &p).await }));
    }
    tokio::time::sleep(Duration::from_millis(150)).await;
    // The test means something only if some of them are still waiting for their bake.
    assert!(tasks.iter().any(|t| !t.is_finished()), "every request finished before shutdown began");
    srv.begin_stop();
    tokio::time::sleep(Duration::from_millis(150)).await;
    // No new connections once shutting down.
    let refused = tokio::time::timeout(Duration::from_secs(5), TcpStream::connect(a)).await;
    assert!(!matches!(refused, Ok(Ok(_))), "a new connection was accepted during shutdown");
    for t in tasks {
        let r = t.await.unwrap();
        assert_eq!(r.status, 200, "{}", String::from_utf8_lossy(&r.body));
        assert!(r.body.starts_with(b"TSB1"));
    }
    srv.stop_within(Duration::from_secs(60)).await;
    // Nothing half-written: no temporary files, and every blob verifies.
    let mut files = Vec::new();
    walk(&store.join("od"), &mut files);
    for f in &files {
        let name = f.file_name().unwrap().to_string_lossy();
        assert!(!name.ends_with(".tmp"), "left behind: {}", f.display());
        if name.ends_with(".tsb") {
            terrastream::codec::decode(&std::fs::read(f).unwrap()).unwrap();
        }
    }
    assert!(files.iter().filter(|f| f.extension().is_some_and(|e| e == "tsb")).count() >= 12);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 4)]
async fn a_corrupt_blob_is_never_sent() {
    let (_tmp, store, _) = baked_store();
    let srv = Running::start(store_config(&store)).await;
    let a = srv.addr;
    let path = Store::new(&store.join("t")).blob_path(terrastream::tiling::TileKey::new(2, 1, 1), 0);
    let mut bytes = std::fs::read(&path).unwrap();
    let last = bytes.len() - 1;
    bytes[last] ^= 0x55;
    std::fs::write(&path, &bytes).unwrap();
    let r = get(a, "/tilesets/t/tiles/2/1/1/0").await;
    r.assert_problem(500);
    assert!(r.json()["detail"].as_str().unwrap().contains("verification"));
    assert!(!r.body.windows(4).any(|w| w == b"TSB1"));
    // Truncated too.
    std::fs::write(&path, &bytes[..100]).unwrap();
    get(a, "/tilesets/t/tiles/2/1/1/0").await.assert_problem(500);
    let text = String::from_utf8(get(a, "/metrics").await.body).unwrap();
    assert_eq!(metric(&text, "terrastream_corrupt_blobs_total"), 2.0);
    // Other blobs are unaffected.
    assert_eq!(get(a, "/tilesets/t/tiles/2/1/1/1").await.status, 200);
    srv.stop().await;

    // On demand, a corrupt blob is set aside and baked again.
    let (_tmp, store, spec) = on_demand_store(513);
    let cfg = PartialConfig { sources: vec![spec.parse().unwrap()], ..store_config(&store) };
    let srv = Running::start(cfg).await;
    let good = get(srv.addr, "/tilesets/od/tiles/1/0/0/1").await;
    assert_eq!(good.status, 200);
    srv.stop().await;
    let path = store.join("od/tiles/1/0/0/1.tsb");
    let mut bytes = std::fs::read(&path).unwrap();
    bytes[200] ^= 0xff;
    std::fs::write(&path, &bytes).unwrap();
    let cfg = PartialConfig { sources: vec![spec.parse().unwrap()], ..store_config(&store) };
    let srv = Running::start(cfg).await;
    let again = get(srv.addr, "/tilesets/od/tiles/1/0/0/1").await;
    assert_eq!(again.status, 200);
    assert_eq!(again.body, good.body);
    assert!(path.with_extension("tsb.corrupt").exists());
    srv.stop().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 4)]
async fn tilesets_added_and_removed_while_serving_are_picked_up() {
    let (tmp, store, tif) = baked_store();
    let srv = Running::start(store_config(&store)).await;
    let a = srv.addr;
    get(a, "/tilesets/late/tileset.json").await.assert_problem(404);
    // Baked elsewhere, moved in (as a deploy would).
    let staging = tmp.path().join("staging");
    std::fs::create_dir_all(&staging).unwrap();
    common::bake_file(&tif, &OPTS, &staging.join("late"));
    std::fs::rename(staging.join("late"), store.join("late")).unwrap();
    let mut found = false;
    for _ in 0..50 {
        if get(a, "/tilesets/late/tileset.json").await.status == 200 {
            found = true;
            break;
        }
        tokio::time::sleep(Duration::from_millis(100)).await;
    }
    assert!(found, "the new tileset was not picked up");
    assert_eq!(get(a, "/tilesets").await.json()["tilesets"].as_array().unwrap().len(), 2);
    std::fs::remove_dir_all(store.join("late")).unwrap();
    let mut gone = false;
    for _ in 0..50 {
        if get(a, "/tilesets/late/tileset.json").await.status == 404 {
            gone = true;
            break;
        }
        tokio::time::sleep(Duration::from_millis(100)).await;
    }
    assert!(gone, "the removed tileset is still served");
    srv.stop().await;
}

/// Reads until the server closes the connection (EOF or reset); `None` when it stays open for
/// `within`.
async fn closed_within(s: &mut TcpStream, within: Duration) -> Option<Vec<u8>> {
    let mut got = Vec::new();
    let mut buf = vec![0u8; 65536];
    tokio::time::timeout(within, async {
        loop {
            match s.read(&mut buf).await {
                Ok(0) | Err(_) => return,
                Ok(n) => got.extend_from_slice(&buf[..n]),
            }
        }
    })
    .await
    .ok()
    .map(|()| got)
}

/// D3: idle connections, slowloris heads and one client opening more than its share are all
/// closed by the server (idle timeout, header timeout, per-client cap), and a normal client is
/// served throughout.
#[tokio::test(flavor = "multi_thread", worker_threads = 4)]
async fn idle_slowloris_and_greedy_connections_are_closed_and_others_still_served() {
    let (_tmp, store, _) = baked_store();
    let cfg = PartialConfig {
        max_connections: Some(32),
        max_connections_per_client: Some(8),
        header_timeout_s: Some(1),
        idle_timeout_s: Some(3),
        ..store_config(&store)
    };
    let srv = Running::start(cfg).await;
    let a = srv.addr;
    let greedy: IpAddr = "127.0.0.3".parse().unwrap();
    let slow: IpAddr = "127.0.0.4".parse().unwrap();
    let normal: Option<IpAddr> = Some("127.0.0.2".parse().unwrap());

    // One client opens 12 idle connections: 8 are held, the 4 past its cap are refused at once.
    let mut idle = Vec::new();
    let mut last_idle_opened = std::time::Instant::now();
    for i in 0..12 {
        if i < 8 {
            last_idle_opened = std::time::Instant::now();
        }
        idle.push(connect_from(Some(greedy), a).await);
        tokio::time::sleep(Duration::from_millis(20)).await;
    }
    // The window is generous (a loaded machine is slow, not wrong); that these were refused, not
    // closed idle, the refused-connections metric says below.
    let mut refused = 0;
    for s in &mut idle[8..] {
        let got =
            closed_within(s, Duration::from_secs(30)).await.expect("a connection past the cap stayed open");
        assert!(got.is_empty() || got.starts_with(b"HTTP/1.1 503"), "{}", String::from_utf8_lossy(&got));
        refused += 1;
    }
    assert_eq!(refused, 4);
    idle.truncate(8);

    // Slowloris: 5 connections trickling a request head, one byte every 200 ms.
    let mut slow_tasks = Vec::new();
    for _ in 0..5 {
        let start = std::time::Instant::now();
        let mut s = connect_from(Some(slow), a).await;
        slow_tasks.push(tokio::spawn(async move {
            let head = b"GET /healthz HTTP/1.1\r\nHost: x\r\nX-Padding: aaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaa\r\n";
            for b in head {
                if s.write_all(&[*b]).await.is_err() {
                    return start.elapsed();
                }
                tokio::time::sleep(Duration::from_millis(200)).await;
            }
            panic!("the server read a slowloris head for {:?}", start.elapsed());
        }));
    }

    // During the abuse, another client is served: health and a blob (from disk, then memory).
    tokio::time::sleep(Duration::from_millis(300)).await;
    assert_eq!(request_from(normal, a, "GET", "/healthz", &[], &[]).await.status, 200);
    for _ in 0..2 {
        let r = request_from(normal, a, "GET", "/tilesets/t/tiles/1/0/0/0", &[], &[]).await;
        assert_eq!(r.status, 200);
        assert!(r.body.starts_with(b"TSB1"));
    }

    // Slowloris heads are cut after the header timeout (1 s), though bytes keep arriving. No
    // timing window that a slow machine could miss: not before the timeout (the clock started
    // before the connection did), and long before the head is complete (93 bytes at 200 ms a
    // byte take 18.6 s; without a cut the task panics when all are sent).
    for t in slow_tasks {
        let took = t.await.unwrap();
        assert!(
            (Duration::from_secs(1)..Duration::from_secs(9)).contains(&took),
            "a slowloris connection was cut after {took:?}"
        );
    }
    // Idle connections close after the idle timeout (3 s), not the header timeout: not before
    // 3 s after the last one opened (a lower bound only; the upper one is "closed at all").
    for s in &mut idle {
        let got = closed_within(s, Duration::from_secs(60)).await.expect("an idle connection stayed open");
        assert!(got.is_empty());
    }
    let idle_for = last_idle_opened.elapsed();
    assert!(idle_for >= Duration::from_secs(3), "idle connections closed after {idle_for:?}");

    // The greedy client's slots are free again.
    let r = request_from(Some(greedy), a, "GET", "/healthz", &[], &[]).await;
    assert_eq!(r.status, 200);
    let text = String::from_utf8(get(a, "/metrics").await.body).unwrap();
    assert_eq!(metric(&text, "terrastream_connections_refused_total"), 4.0, "{text}");
    assert!(metric(&text, "terrastream_connections_header_timeouts_total") >= 5.0, "{text}");
    assert!(metric(&text, "terrastream_connections_idle_closed_total") >= 8.0, "{text}");
    srv.stop().await;
}

/// D3: with the per-client cap off, one client can fill `--max-connections`; the idle timeout
/// still gives the slots back, so a new client gets in after it.
#[tokio::test(flavor = "multi_thread", worker_threads = 4)]
async fn idle_connections_filling_the_server_are_closed_and_it_serves_again() {
    let (_tmp, store, _) = baked_store();
    let cfg = PartialConfig {
        max_connections: Some(16),
        max_connections_per_client: Some(0),
        idle_timeout_s: Some(1),
        ..store_config(&store)
    };
    let srv = Running::start(cfg).await;
    let a = srv.addr;
    let mut idle = Vec::new();
    for _ in 0..16 {
        idle.push(connect_from(Some("127.0.0.5".parse().unwrap()), a).await);
    }
    let start = std::time::Instant::now();
    let r = request_from(Some("127.0.0.6".parse().unwrap()), a, "GET", "/healthz", &[], &[]).await;
    assert_eq!(r.status, 200);
    // Served once the 1 s idle timeout freed a slot: generous bounds (a slow machine is slow,
    // not wrong); without the timeout the slots would never free.
    assert!(start.elapsed() < Duration::from_secs(30), "served after {:?}", start.elapsed());
    for s in &mut idle {
        closed_within(s, Duration::from_secs(30)).await.expect("an idle connection stayed open");
    }
    srv.stop().await;
}

/// Every pipelined request is answered when the client half-closes after sending them.
#[tokio::test(flavor = "multi_thread", worker_threads = 4)]
async fn pipelined_requests_then_half_close_are_all_answered() {
    let (_tmp, store, _) = baked_store();
    let srv = Running::start(store_config(&store)).await;
    let n = 2000;
    let mut reqs = String::new();
    for i in 0..n {
        let path = match i % 3 {
            0 => "/healthz",
            1 => "/tilesets/t/tiles/1/1/0/1",
            _ => "/tilesets/nope/tileset.json",
        };
        reqs.push_str(&format!("GET {path} HTTP/1.1\r\nHost: t\r\n\r\n"));
    }
    let s = TcpStream::connect(srv.addr).await.unwrap();
    let (mut rd, mut wr) = s.into_split();
    let reader = tokio::spawn(async move {
        let mut got = Vec::new();
        rd.read_to_end(&mut got).await.unwrap();
        got
    });
    wr.write_all(reqs.as_bytes()).await.unwrap();
    wr.shutdown().await.unwrap();
    let got = tokio::time::timeout(Duration::from_secs(60), reader).await.unwrap().unwrap();
    let count = |needle: &[u8]| got.windows(needle.len()).filter(|w| *w == needle).count();
    assert_eq!(count(b"HTTP/1.1 "), n, "responses to {n} pipelined requests");
    assert_eq!(count(b"HTTP/1.1 200 "), n - n / 3);
    assert_eq!(count(b"HTTP/1.1 404 "), n / 3);
    drop(wr);
    srv.stop().await;
}

/// RFC 9112 §3.2: an HTTP/1.1 request needs exactly one valid Host; HTTP/1.0 needs none.
#[tokio::test(flavor = "multi_thread", worker_threads = 4)]
async fn a_request_without_one_valid_host_is_400() {
    let (_tmp, store, _) = baked_store();
    let srv = Running::start(store_config(&store)).await;
    let raw = |head: &'static str| async move {
        let mut s = TcpStream::connect(srv.addr).await.unwrap();
        s.write_all(head.as_bytes()).await.unwrap();
        let got = closed_within(&mut s, Duration::from_secs(30)).await.unwrap();
        String::from_utf8_lossy(&got).into_owned()
    };
    for (head, status) in [
        ("GET /healthz HTTP/1.1\r\nConnection: close\r\n\r\n", "400"),
        ("GET /tilesets/t/tiles/1/1/0/1 HTTP/1.1\r\nConnection: close\r\n\r\n", "400"),
        ("GET /healthz HTTP/1.1\r\nHost: a\r\nHost: b\r\nConnection: close\r\n\r\n", "400"),
        ("GET /healthz HTTP/1.1\r\nHost: a b\r\nConnection: close\r\n\r\n", "400"),
        ("GET /healthz HTTP/1.0\r\n\r\n", "200"),
        ("GET /healthz HTTP/1.1\r\nHost: example.org:8080\r\nConnection: close\r\n\r\n", "200"),
        ("GET /healthz HTTP/1.1\r\nHost:\r\nConnection: close\r\n\r\n", "200"),
    ] {
        let got = raw(head).await;
        assert!(
            got.starts_with(&format!("HTTP/1.1 {status} "))
                || got.starts_with(&format!("HTTP/1.0 {status} ")),
            "{head:?} → {got}"
        );
        if status == "400" {
            assert!(got.to_ascii_lowercase().contains("content-type: application/problem+json"), "{got}");
            assert!(got.contains("Host"), "{got}");
        }
    }
    srv.stop().await;
}

/// A failing on-demand bake runs once; requests meanwhile get its error without a new bake.
#[tokio::test(flavor = "multi_thread", worker_threads = 4)]
async fn a_failed_on_demand_bake_is_remembered_not_rerun() {
    let (_tmp, store, spec) = on_demand_store(513);
    let cfg = PartialConfig { sources: vec![spec.parse().unwrap()], ..store_config(&store) };
    let srv = Running::start(cfg).await;
    let a = srv.addr;
    // Level 2 of node 1/1/1 cannot be written (a non-empty directory sits at its path; the
    // bake writes it first), so the node's bake fails; level 1 is what is requested (missing,
    // so it bakes).
    std::fs::create_dir_all(store.join("od/tiles/1/1/1/2.tsb/x")).unwrap();
    let first = get(a, "/tilesets/od/tiles/1/1/1/1").await;
    first.assert_problem(500);
    let second = get(a, "/tilesets/od/tiles/1/1/1/1").await;
    second.assert_problem(500);
    assert!(second.json()["detail"].as_str().unwrap().contains("not retried"), "{:?}", second.json());
    let text = String::from_utf8(get(a, "/metrics").await.body).unwrap();
    assert_eq!(metric(&text, "terrastream_bakes_failed_total"), 1.0, "{text}");
    assert_eq!(metric(&text, "terrastream_bakes_done_total"), 0.0, "{text}");
    // Another node bakes normally.
    assert_eq!(get(a, "/tilesets/od/tiles/1/0/0/1").await.status, 200);
    srv.stop().await;
}

/// A store that cannot be read (here: a tileset's tiles directory replaced by a file, so every
/// blob path fails with ENOTDIR) is a 503 with Retry-After, not a 404.
#[tokio::test(flavor = "multi_thread", worker_threads = 4)]
async fn an_unreadable_store_is_503_not_404() {
    let (_tmp, store, _) = baked_store();
    let srv = Running::start(store_config(&store)).await;
    let a = srv.addr;
    let tiles = store.join("t/tiles");
    std::fs::rename(&tiles, store.join("t/tiles.away")).unwrap();
    std::fs::write(&tiles, b"not a directory").unwrap();
    let index = store.join("t/index");
    std::fs::rename(&index, store.join("t/index.away")).unwrap();
    std::fs::write(&index, b"not a directory").unwrap();
    let r = get(a, "/tilesets/t/tiles/1/0/0/0").await;
    r.assert_problem(503);
    assert!(r.header("retry-after").is_some(), "{r:?}");
    let r = get(a, "/tilesets/t/index/0/0/0.json").await;
    r.assert_problem(503);
    assert!(r.header("retry-after").is_some(), "{r:?}");
    // The whole tileset directory replaced by a file: still listed (store scans keep it), its
    // blobs 503, not 404; once the directory is back, served again.
    std::fs::remove_file(&index).unwrap();
    std::fs::rename(store.join("t/index.away"), &index).unwrap();
    std::fs::remove_file(&tiles).unwrap();
    std::fs::rename(store.join("t/tiles.away"), &tiles).unwrap();
    std::fs::rename(store.join("t"), store.join("t.away")).unwrap();
    std::fs::write(store.join("t"), b"not a directory").unwrap();
    tokio::time::sleep(Duration::from_millis(500)).await; // several re-scans (poll 100 ms)
    let r = get(a, "/tilesets/t/tiles/1/0/0/0").await;
    r.assert_problem(503);
    assert!(r.header("retry-after").is_some(), "{r:?}");
    assert_eq!(get(a, "/tilesets/t").await.status, 200);
    std::fs::remove_file(store.join("t")).unwrap();
    std::fs::rename(store.join("t.away"), store.join("t")).unwrap();
    // A blob that is simply missing is still a 404.
    std::fs::remove_file(store.join("t/tiles/1/0/0/0.tsb")).unwrap();
    get(a, "/tilesets/t/tiles/1/0/0/0").await.assert_problem(404);
    assert_eq!(get(a, "/tilesets/t/tiles/1/0/0/1").await.status, 200);
    srv.stop().await;
}

/// Polls a job until `done(state)`, at most 60 s; returns its last JSON.
async fn wait_job(
    a: SocketAddr,
    loc: &str,
    admin: &[(&str, &str)],
    done: impl Fn(&str) -> bool,
) -> serde_json::Value {
    let mut j = serde_json::Value::Null;
    for _ in 0..1200 {
        j = request(a, "GET", loc, admin, &[]).await.json();
        if done(j["state"].as_str().unwrap_or_default()) {
            return j;
        }
        tokio::time::sleep(Duration::from_millis(50)).await;
    }
    panic!("job {loc} never reached the state wanted: {j}");
}

fn no_staging(store: &Path) {
    for e in std::fs::read_dir(store).unwrap() {
        let n = e.unwrap().file_name().to_string_lossy().into_owned();
        assert!(!n.starts_with(".job-") && !n.starts_with(".upload-"), "left behind: {n}");
    }
}

/// D2: a queued job is cancelled at once, a running bake stops at its next node and its job
/// ends `cancelled` with nothing published; the upload slot is free again afterwards; ended
/// jobs are forgotten after the TTL.
#[tokio::test(flavor = "multi_thread", worker_threads = 4)]
async fn admin_jobs_can_be_cancelled_and_expire() {
    let (tmp, store, tif) = baked_store();
    let big = tmp.path().join("big.tif");
    common::write_synth_geotiff(&big, (1025, 1025), 5, (0.0, 0.0));
    let cfg = PartialConfig {
        admin_token: Some("admin-secret-1".into()),
        job_ttl_s: Some(2),
        gpu: Some(terrastream::lod::GpuMode::Off),
        ..store_config(&store)
    };
    let srv = Running::start(cfg).await;
    let a = srv.addr;
    // The scheme is case-insensitive.
    let admin = [("Authorization", "BEARER admin-secret-1")];
    let body = std::fs::read(&big).unwrap();
    let up = request(a, "POST", "/tilesets/big?tile_size=64&levels=2", &admin, &body).await;
    assert_eq!(up.status, 202, "{}", String::from_utf8_lossy(&up.body));
    let running = up.header("location").unwrap().to_owned();
    // A second upload waits for the slot; cancelling it ends it at once.
    let small = std::fs::read(&tif).unwrap();
    let q = request(a, "POST", "/tilesets/queued?tile_size=128&levels=1", &admin, &small).await;
    assert_eq!(q.status, 202);
    let queued = q.header("location").unwrap().to_owned();
    let j = wait_job(a, &running, &admin, |s| s != "queued").await;
    assert_eq!(j["state"], "running", "{j}");
    assert_eq!(request(a, "GET", &queued, &admin, &[]).await.json()["state"], "queued");
    assert_eq!(request(a, "DELETE", &queued, &admin, &[]).await.status, 204);
    assert_eq!(request(a, "GET", &queued, &admin, &[]).await.json()["state"], "cancelled");
    assert_eq!(request(a, "DELETE", &queued, &admin, &[]).await.status, 204, "idempotent");
    // Cancel the running bake once it has done some nodes.
    wait_job(a, &running, &admin, |_| true).await;
    let c = request(a, "DELETE", &running, &admin, &[]).await;
    assert_eq!(c.status, 202, "{}", String::from_utf8_lossy(&c.body));
    let j = wait_job(a, &running, &admin, |s| s != "running").await;
    assert_eq!(j["state"], "cancelled", "{j}");
    assert!(j["nodes_done"].as_u64().unwrap() < j["nodes_total"].as_u64().unwrap(), "{j}");
    assert!(!store.join("big").exists() && !store.join("queued").exists());
    no_staging(&store);
    request(a, "GET", "/tilesets/big/tileset.json", &[], &[]).await.assert_problem(404);
    // The slot is free: a new upload bakes.
    let up = request(a, "POST", "/tilesets/after?tile_size=128&levels=1", &admin, &small).await;
    let after = up.header("location").unwrap().to_owned();
    let j = wait_job(a, &after, &admin, |s| s == "done" || s == "failed").await;
    assert_eq!(j["state"], "done", "{j}");
    request(a, "DELETE", &after, &admin, &[]).await.assert_problem(409);
    request(a, "DELETE", "/jobs/j999", &admin, &[]).await.assert_problem(404);
    request(a, "DELETE", &after, &[], &[]).await.assert_problem(401);
    // Ended jobs are forgotten after --job-ttl (2 s).
    tokio::time::sleep(Duration::from_millis(2500)).await;
    request(a, "GET", &after, &admin, &[]).await.assert_problem(404);
    request(a, "GET", &running, &admin, &[]).await.assert_problem(404);
    srv.stop().await;
}

/// D2: a job running past --job-timeout is stopped at its next node and fails, naming the
/// timeout; the slot is released.
#[tokio::test(flavor = "multi_thread", worker_threads = 4)]
async fn a_job_past_its_timeout_is_stopped_and_failed() {
    let (tmp, store, tif) = baked_store();
    let big = tmp.path().join("big.tif");
    common::write_synth_geotiff(&big, (1025, 1025), 5, (0.0, 0.0));
    let cfg = PartialConfig {
        admin_token: Some("admin-secret-1".into()),
        job_timeout_s: Some(1),
        gpu: Some(terrastream::lod::GpuMode::Off),
        ..store_config(&store)
    };
    let srv = Running::start(cfg).await;
    let a = srv.addr;
    let admin = [("Authorization", "Bearer admin-secret-1")];
    let up = request(a, "POST", "/tilesets/big?tile_size=64&levels=2", &admin, &std::fs::read(&big).unwrap())
        .await;
    let loc = up.header("location").unwrap().to_owned();
    let start = std::time::Instant::now();
    let j = wait_job(a, &loc, &admin, |s| s == "done" || s == "failed" || s == "cancelled").await;
    assert_eq!(j["state"], "failed", "{j}");
    assert!(j["error"].as_str().unwrap().contains("--job-timeout"), "{j}");
    assert!(start.elapsed() < Duration::from_secs(20), "{:?}", start.elapsed());
    assert!(!store.join("big").exists());
    no_staging(&store);
    // A small job still fits in the timeout: the slot was released.
    let up =
        request(a, "POST", "/tilesets/small?tile_size=128&levels=1", &admin, &std::fs::read(&tif).unwrap())
            .await;
    let loc = up.header("location").unwrap().to_owned();
    let j = wait_job(a, &loc, &admin, |s| s == "done" || s == "failed").await;
    assert!(j["state"] == "done" || j["error"].as_str().unwrap().contains("--job-timeout"), "{j}");
    srv.stop().await;
}

/// D6: staging leftovers of an earlier run (exactly `.upload-jN`, `.job-jN`, `.deleted-NAME-N`)
/// are removed at startup; nothing else is touched.
#[tokio::test(flavor = "multi_thread", worker_threads = 4)]
async fn staging_leftovers_are_removed_at_startup() {
    let (_tmp, store, _) = baked_store();
    std::fs::write(store.join(".upload-j1"), b"half an upload").unwrap();
    std::fs::create_dir_all(store.join(".job-j1/tiles/0/0/0")).unwrap();
    std::fs::write(store.join(".job-j1/tiles/0/0/0/0.tsb"), b"x").unwrap();
    std::fs::create_dir_all(store.join(".deleted-old-1700000000")).unwrap();
    let keep = [".upload-jx", ".job-j1.keep", "notes.txt", ".hidden"];
    for k in keep {
        std::fs::write(store.join(k), b"mine").unwrap();
    }
    let srv = Running::start(store_config(&store)).await;
    for gone in [".upload-j1", ".job-j1", ".deleted-old-1700000000"] {
        assert!(!store.join(gone).exists(), "{gone} left");
    }
    for k in keep {
        assert!(store.join(k).exists(), "{k} removed");
    }
    assert_eq!(get(srv.addr, "/tilesets/t/tiles/0/0/0/0").await.status, 200);
    srv.stop().await;
}

/// Issue 13: every node of the fixture stores every level (what the tests above rely on); and a
/// level that did not pay is `404` with the reason, while the node's index entry lists what it
/// has, and levels that are stored are served.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn point_levels_that_do_not_pay_are_404() {
    let (_tmp, store, _tif) = baked_store();
    let fixture = store.join("t");
    let (nodes, stored, left_out) = common::assert_levels_pay(&fixture);
    assert_eq!((stored, left_out), (nodes * 3, 0), "the fixture must store every level");

    // The same raster with a 2 m TIN: level 1 costs more than the mesh nearly everywhere.
    let tmp = tempfile::tempdir().unwrap();
    let tif = tmp.path().join("t.tif");
    common::write_synth_geotiff(&tif, (WIDTH, HEIGHT), 7, (0.0, 0.0));
    let s2 = tmp.path().join("store");
    common::bake_file(&tif, &BakeOptions { max_error: 2.0, ..OPTS }, &s2.join("t"));
    let (_, _, left_out) = common::assert_levels_pay(&s2.join("t"));
    assert!(left_out > 0);
    let srv = Running::start(store_config(&s2)).await;
    let st = Store::new(&s2.join("t"));
    let m = st.manifest().unwrap();
    let pyramid = terrastream::tiling::Pyramid::new(m.source.width, m.source.height, m.tile_size).unwrap();
    let (mut missing, mut served) = (0, 0);
    for key in pyramid.nodes() {
        let node = st.node(key).unwrap().unwrap();
        for level in 0..=2u8 {
            let r = get(srv.addr, &format!("/tilesets/t/tiles/{}/{}/{}/{level}", key.z, key.x, key.y)).await;
            if node.level(level).is_some() {
                assert_eq!(r.status, 200, "{key}/{level}");
                served += 1;
            } else {
                r.assert_problem(404);
                let body = String::from_utf8_lossy(&r.body).into_owned();
                assert!(body.contains("is not stored") && body.contains(&key.to_string()), "{body}");
                missing += 1;
            }
        }
    }
    assert!(missing > 0 && served > 0, "{missing} missing, {served} served");
    srv.stop().await;
}
