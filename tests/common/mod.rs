//! Helpers shared by the integration tests: the binary runner (with a time limit, so a hang is
//! a failure rather than a stuck run), the GPU-or-skip rule, the shared test data and tileset
//! tree comparison.

// Each test binary uses what it needs of this module; a failed unwrap is the test failing.
#![allow(dead_code, clippy::unwrap_used, clippy::panic)]

mod shared;
#[allow(unused_imports)] // each test binary uses what it needs
pub use shared::*;

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::process::{Command, Output, Stdio};
use std::time::{Duration, Instant};

/// The `terrastream` binary of this build, with stdin closed.
pub fn bin() -> Command {
    let mut c = Command::new(env!("CARGO_BIN_EXE_terrastream"));
    c.stdin(Stdio::null());
    c
}

/// `cmd` set up as one shard of a sharded bake: `bake --plan PLAN --shard I`, quiet, on the CPU,
/// one thread (shards run side by side).
pub fn shard_step(mut cmd: Command, plan: impl AsRef<std::ffi::OsStr>, i: u32) -> Command {
    cmd.arg("bake").arg("--plan").arg(plan).args(["--shard", &i.to_string(), "-q", "--gpu", "off"]);
    cmd.args(["--threads", "1"]);
    cmd
}

/// Runs `cmd`, killing it after `limit` (a hang is a failure, not a stuck test run).
pub fn run_within(cmd: &mut Command, limit: Duration) -> Output {
    let mut child = cmd.stdout(Stdio::piped()).stderr(Stdio::piped()).spawn().unwrap();
    let t0 = Instant::now();
    while child.try_wait().unwrap().is_none() {
        if t0.elapsed() > limit {
            child.kill().unwrap();
            let out = child.wait_with_output().unwrap();
            panic!("{cmd:?} still running after {limit:?}\n{}", String::from_utf8_lossy(&out.stderr));
        }
        std::thread::sleep(Duration::from_millis(20));
    }
    child.wait_with_output().unwrap()
}

/// Runs `cmd` (at most 5 minutes), asserts it succeeded and returns its stdout.
pub fn ok(cmd: &mut Command) -> String {
    let out = run_within(cmd, Duration::from_mins(5));
    assert!(out.status.success(), "{cmd:?} failed\n{}", String::from_utf8_lossy(&out.stderr));
    String::from_utf8_lossy(&out.stdout).into_owned()
}

/// Runs `cmd` (at most a minute), asserts it failed and returns its stderr.
pub fn fails(cmd: &mut Command) -> String {
    let out = run_within(cmd, Duration::from_mins(1));
    assert!(!out.status.success(), "{cmd:?} should fail");
    String::from_utf8_lossy(&out.stderr).into_owned()
}

/// GPU tests skip with a printed reason when no adapter is found, unless
/// `TERRASTREAM_REQUIRE_GPU=1` (CI sets it, with Mesa's lavapipe installed): then they fail.
pub fn require_gpu() -> bool {
    std::env::var("TERRASTREAM_REQUIRE_GPU").is_ok_and(|v| v == "1")
}

/// An adapter for a GPU test, or `None` after printing why `what` is skipped; panics instead
/// under `TERRASTREAM_REQUIRE_GPU=1` (see [`require_gpu`]).
#[cfg(feature = "gpu")]
pub fn gpu_or_skip(what: &str) -> Option<terrastream::gpu::GpuContext> {
    match terrastream::gpu::open() {
        Ok(ctx) => Some(ctx),
        Err(e) if require_gpu() => panic!("TERRASTREAM_REQUIRE_GPU=1 but no adapter: {e}"),
        Err(e) => {
            eprintln!("skipping {what}: {e} (set TERRASTREAM_REQUIRE_GPU=1 to fail instead)");
            None
        }
    }
}

/// A file of the shared test data (`$TERRASTREAM_DATA`, default `../shared/data`), whether it
/// exists or not: tests that need it take [`shared`] (or a `*_or_generated` stand-in) instead.
pub fn data(name: &str) -> PathBuf {
    terrastream::raster::test_data_dir().join(name)
}

/// Every file under `dir` (hidden ones included) with its bytes, by relative path.
pub fn tree(dir: &Path) -> BTreeMap<String, Vec<u8>> {
    fn walk(root: &Path, dir: &Path, out: &mut BTreeMap<String, Vec<u8>>) {
        for e in std::fs::read_dir(dir).unwrap() {
            let p = e.unwrap().path();
            if p.is_dir() {
                walk(root, &p, out);
            } else {
                out.insert(p.strip_prefix(root).unwrap().display().to_string(), std::fs::read(&p).unwrap());
            }
        }
    }
    let mut out = BTreeMap::new();
    walk(dir, dir, &mut out);
    out
}

/// The blobs and index of a tileset: [`tree`] without the files that name the sources (the
/// manifest), for comparing bakes of the same heights from different inputs.
pub fn blobs_and_index(dir: &Path) -> BTreeMap<String, Vec<u8>> {
    tree(dir).into_iter().filter(|(k, _)| k.starts_with("tiles/") || k.starts_with("index/")).collect()
}

/// Asserts that every node of the tileset in `dir` stores only levels that pay: level 0 always,
/// each further level with fewer primitives *and* fewer bytes than every finer level the node
/// stores; the index's figures match the blobs; and every level of the ladder a node does not
/// store has its `unpaid` marker and no blob. Returns (nodes, levels stored, levels left out).
pub fn assert_levels_pay(dir: &Path) -> (usize, usize, usize) {
    use terrastream::store::{Store, TilesetKind};
    let store = Store::new(dir);
    let m = store.manifest().unwrap();
    let nodes = if store.manifest_kind().unwrap() == TilesetKind::Model {
        vec![store.node(terrastream::tiling::TileKey::new(0, 0, 0)).unwrap().unwrap()]
    } else {
        let pyramid =
            terrastream::tiling::Pyramid::new(m.source.width, m.source.height, m.tile_size).unwrap();
        let all = store.all_nodes(&pyramid).unwrap();
        assert_eq!(all.len(), pyramid.nodes().len(), "{}: index misses nodes", dir.display());
        all
    };
    let (mut stored, mut left_out) = (0, 0);
    for n in &nodes {
        assert_eq!(n.levels.first().map(|l| l.level), Some(0), "{}: no mesh", n.key);
        for (i, l) in n.levels.iter().enumerate() {
            let bytes = store
                .read_blob(n.key, l.level)
                .unwrap()
                .unwrap_or_else(|| panic!("{} level {}: listed in the index, no blob", n.key, l.level));
            let h = terrastream::codec::decode(&bytes).unwrap().header;
            assert_eq!(
                (h.level, h.vertex_count, bytes.len() as u64),
                (l.level, l.count, l.bytes),
                "{}",
                n.key
            );
            for finer in &n.levels[..i] {
                assert!(
                    l.count < finer.count && l.bytes < finer.bytes,
                    "{} level {} ({} primitives, {} B) does not pay against level {} ({} primitives, {} B)",
                    n.key,
                    l.level,
                    l.count,
                    l.bytes,
                    finer.level,
                    finer.count,
                    finer.bytes
                );
            }
            stored += 1;
        }
        for spec in &m.levels {
            if n.level(spec.level).is_none() {
                assert!(
                    store.is_unpaid(n.key, spec.level).unwrap(),
                    "{} level {}: neither blob nor marker",
                    n.key,
                    spec.level
                );
                assert!(store.read_blob(n.key, spec.level).unwrap().is_none());
                left_out += 1;
            }
        }
    }
    // `--point-levels auto`: no stored level of a node below the root is out of the selector's
    // reach (`lod::reach`), and every level left out says why.
    if m.options.get("point_levels").and_then(|v| v.as_str()) == Some("auto") {
        let by_key: std::collections::HashMap<_, _> = nodes.iter().map(|n| (n.key, n)).collect();
        for n in &nodes {
            // Every level left out has a readable reason (`unpaid_reason`), the stored ones none.
            let ladder: Vec<u8> = m.levels.iter().map(|l| l.level).collect();
            let skipped = terrastream::store::skipped_levels(&store, n, &ladder).unwrap();
            assert_eq!(skipped.len() + n.levels.len(), ladder.len(), "{}", n.key);
            if n.key.z == 0 {
                continue;
            }
            let p = by_key[&terrastream::tiling::TileKey::new(n.key.z - 1, n.key.x / 2, n.key.y / 2)];
            let reach = terrastream::lod::reach::reach(
                p.levels[0].errors.geometric(),
                terrastream::lod::reach::farthest_corner(n.bounds.center(), &p.bounds),
            );
            for l in n.levels.iter().skip(1) {
                assert!(
                    l.errors.geometric() < reach,
                    "{} level {}: error {} is out of reach ({reach}) below its parent",
                    n.key,
                    l.level,
                    l.errors.geometric()
                );
            }
        }
    }
    assert_tiles3d_monotone(dir);
    (nodes.len(), stored, left_out)
}

/// [`assert_tiles3d_monotone`]'s walk: `tile` and below, under a parent of error `cap`.
fn walk_monotone(base: &Path, tile: &serde_json::Value, cap: f64, where_: &str, n: &mut usize) {
    let e = tile["geometricError"].as_f64().unwrap();
    assert!(
        e <= cap * (1.0 + 1e-12) + 1e-12,
        "{where_}: tile {} has geometricError {e} under a parent of {cap}",
        tile["extras"]["terrastream"]
    );
    *n += 1;
    if let Some(uri) =
        tile["content"]["uri"].as_str().filter(|u| Path::new(u).extension().is_some_and(|x| x == "json"))
    {
        let doc: serde_json::Value = serde_json::from_slice(&std::fs::read(base.join(uri)).unwrap()).unwrap();
        assert!(doc["geometricError"].as_f64().unwrap() <= e * (1.0 + 1e-12) + 1e-12, "{uri}");
        walk_monotone(base, &doc["root"], e, uri, n);
    }
    for c in tile["children"].as_array().into_iter().flatten() {
        walk_monotone(base, c, e, where_, n);
    }
}

/// Exports the tileset in `dir` as 3D Tiles (the library's `export_3dtiles`, the documents the
/// server sends) and asserts its error chain is monotone: on every path from the root, across
/// external tilesets too, no tile's `geometricError` is above its parent's. Returns the tiles
/// checked.
pub fn assert_tiles3d_monotone(dir: &Path) -> usize {
    let store = terrastream::store::Store::new(dir);
    let out = tempfile::tempdir().unwrap();
    let out = out.path().join("3dtiles");
    terrastream::bake::export::export_3dtiles(&store, &out, None, &|_, _| {}).unwrap();
    let root: serde_json::Value =
        serde_json::from_slice(&std::fs::read(out.join("tileset.json")).unwrap()).unwrap();
    let mut n = 0;
    walk_monotone(&out, &root["root"], root["geometricError"].as_f64().unwrap(), "tileset.json", &mut n);
    n
}

/// A `terrastream serve` process on a free 127.0.0.1 port, killed when dropped.
pub struct Served {
    pub child: std::process::Child,
    pub addr: std::net::SocketAddr,
}

impl Drop for Served {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

/// Starts `cmd` (a `bin()` with `serve --store …` arguments) with `--bind` on a free port and
/// waits until `/readyz` answers 200 (at most 60 s).
pub fn serve(mut cmd: Command) -> Served {
    let port = std::net::TcpListener::bind("127.0.0.1:0").unwrap().local_addr().unwrap().port();
    let addr: std::net::SocketAddr = format!("127.0.0.1:{port}").parse().unwrap();
    let child = cmd
        .arg("--bind")
        .arg(addr.to_string())
        .stdout(Stdio::null())
        .stderr(Stdio::inherit())
        .spawn()
        .unwrap();
    let s = Served { child, addr };
    let t0 = Instant::now();
    while http_get(addr, "/readyz").map(|r| r.0) != Some(200) {
        assert!(t0.elapsed() < Duration::from_mins(1), "the server on {addr} did not become ready");
        std::thread::sleep(Duration::from_millis(50));
    }
    s
}

/// A response: status, headers (lower-case names), body.
pub type Got = (u16, Vec<(String, String)>, Vec<u8>);

/// One GET on its own connection, through the library's HTTP client (the one the reference
/// client streams with): status, headers (lower-case names) and body; `None` when the connection
/// or the response fails.
pub fn http_get(addr: std::net::SocketAddr, path: &str) -> Option<Got> {
    let r =
        terrastream::client::stream::http::get(addr, &addr.to_string(), path, Duration::from_mins(1)).ok()?;
    Some((r.status, r.headers, r.body))
}

/// The URLs of every resource of tileset `name` whose files are `files` (paths relative to the
/// tileset): the manifest, each index chunk, each blob, the 3D Tiles root, and the GLB and
/// subtree of every 5th blob.
pub fn tileset_urls<'a>(name: &str, files: impl IntoIterator<Item = &'a String>) -> Vec<String> {
    let mut urls = vec![
        format!("/tilesets/{name}/tileset.json"),
        format!("/tilesets/{name}"),
        format!("/tilesets/{name}/3dtiles/tileset.json"),
    ];
    for (i, f) in files.into_iter().enumerate() {
        if let Some(rest) = f.strip_prefix("tiles/").and_then(|r| r.strip_suffix(".tsb")) {
            urls.push(format!("/tilesets/{name}/tiles/{rest}"));
            if i % 5 == 0 {
                urls.push(format!("/tilesets/{name}/3dtiles/tiles/{rest}.glb"));
            }
        } else if let Some(rest) = f.strip_prefix("index/") {
            urls.push(format!("/tilesets/{name}/index/{rest}"));
            if !rest.starts_with("0/") {
                urls.push(format!("/tilesets/{name}/3dtiles/index/{rest}"));
            }
        }
    }
    urls
}

/// Asserts that every URL gets the same status, body, ETag and content type from each server.
pub fn assert_same_responses(servers: &[(&str, std::net::SocketAddr)], urls: &[String]) {
    let pick = |h: &[(String, String)], k: &str| h.iter().find(|(n, _)| n == k).map(|(_, v)| v.clone());
    for url in urls {
        let (first_name, first_addr) = servers[0];
        let (s0, h0, b0) = http_get(first_addr, url).unwrap();
        assert!(s0 == 200 || s0 == 404, "{first_name} {url}: {s0} {}", String::from_utf8_lossy(&b0));
        for &(name, addr) in &servers[1..] {
            let (s, h, b) = http_get(addr, url).unwrap();
            assert_eq!(s, s0, "{url}: {name} vs {first_name}");
            assert!(b == b0, "{url}: {name} body differs from {first_name}'s");
            for k in ["etag", "content-type", "cache-control"] {
                assert_eq!(pick(&h, k), pick(&h0, k), "{url}: {name} {k} vs {first_name}");
            }
        }
    }
}

/// An answer read off a socket: status, headers (lower-case names), body.
pub type Answer = (u16, BTreeMap<String, String>, Vec<u8>);

/// The bytes of a one-shot request: `Connection: close`, the given headers, and a
/// `Content-Length` where there is a body (or the method is POST).
fn request_head(method: &str, path: &str, headers: &[(&str, &str)], body: &[u8]) -> String {
    let mut req = format!("{method} {path} HTTP/1.1\r\nHost: t\r\nConnection: close\r\n");
    for (k, v) in headers {
        req.extend([*k, ": ", *v, "\r\n"]);
    }
    if method == "POST" || !body.is_empty() {
        req.extend(["Content-Length: ", &body.len().to_string(), "\r\n"]);
    }
    req.push_str("\r\n");
    req
}

/// A whole response as read until the server closed: status, headers, and the body with any
/// chunked transfer coding taken off (content codings stay: the bytes are as sent).
fn parse_answer(buf: &[u8]) -> Answer {
    let end = buf.windows(4).position(|w| w == b"\r\n\r\n").unwrap();
    let head = String::from_utf8_lossy(&buf[..end]).into_owned();
    let mut lines = head.lines();
    let status = lines.next().unwrap().split(' ').nth(1).unwrap().parse().unwrap();
    let h: BTreeMap<String, String> = lines
        .filter_map(|l| l.split_once(':'))
        .map(|(k, v)| (k.trim().to_ascii_lowercase(), v.trim().to_owned()))
        .collect();
    let mut body = buf[end + 4..].to_vec();
    if h.get("transfer-encoding").is_some_and(|v| v.contains("chunked")) {
        let mut out = Vec::new();
        let mut rest = &body[..];
        loop {
            let eol = rest.windows(2).position(|w| w == b"\r\n").unwrap();
            let n = usize::from_str_radix(std::str::from_utf8(&rest[..eol]).unwrap().trim(), 16).unwrap();
            if n == 0 {
                break;
            }
            out.extend_from_slice(&rest[eol + 2..eol + 2 + n]);
            rest = &rest[eol + 2 + n + 2..];
        }
        body = out;
    }
    (status, h, body)
}

/// One request on its own connection over a plain socket (paths reach the server as given):
/// [`Answer`], a chunked body decoded, a compressed one not. A server that sends nothing for a
/// minute fails the test.
pub fn request(
    addr: std::net::SocketAddr,
    method: &str,
    path: &str,
    headers: &[(&str, &str)],
    body: &[u8],
) -> Answer {
    use std::io::{Read, Write};
    let mut s = std::net::TcpStream::connect(addr).unwrap();
    s.set_read_timeout(Some(Duration::from_mins(1))).unwrap();
    s.write_all(request_head(method, path, headers, body).as_bytes()).unwrap();
    s.write_all(body).unwrap();
    let mut buf = Vec::new();
    s.read_to_end(&mut buf).unwrap();
    parse_answer(&buf)
}

/// One GET with request headers ([`request`]).
pub fn get_with(addr: std::net::SocketAddr, path: &str, headers: &[(&str, &str)]) -> Answer {
    request(addr, "GET", path, headers, &[])
}

/// [`get_with`] from async tests (a server in the same process): the same bytes on a tokio
/// socket, the whole exchange within a minute.
pub async fn get_async(addr: std::net::SocketAddr, path: &str, headers: &[(&str, &str)]) -> Answer {
    use tokio::io::{AsyncReadExt, AsyncWriteExt};
    let exchange = async {
        let mut s = tokio::net::TcpStream::connect(addr).await.unwrap();
        s.write_all(request_head("GET", path, headers, &[]).as_bytes()).await.unwrap();
        let mut buf = Vec::new();
        s.read_to_end(&mut buf).await.unwrap();
        buf
    };
    let buf = tokio::time::timeout(Duration::from_mins(1), exchange)
        .await
        .unwrap_or_else(|_| panic!("GET {path}: no answer within a minute"));
    parse_answer(&buf)
}

/// [`serve`] of `terrastream serve --store STORE`, with a `--source` for each of `sources`.
pub fn serve_store(store: &Path, sources: &[String]) -> Served {
    let mut c = bin();
    c.args(["serve", "--store"]).arg(store);
    for s in sources {
        c.arg("--source").arg(s);
    }
    serve(c)
}

/// A server of the library's own (`Server::bind` + `run`) in the test's process, on a free
/// 127.0.0.1 port, until [`Running::stop`].
#[cfg(feature = "server")]
pub struct Running {
    pub addr: std::net::SocketAddr,
    stop: Option<tokio::sync::oneshot::Sender<()>>,
    task: tokio::task::JoinHandle<Result<(), terrastream::server::ServerError>>,
}

#[cfg(feature = "server")]
impl Running {
    /// Binds `config` on 127.0.0.1:0 (whatever `bind` it names) and runs it on the current
    /// tokio runtime.
    pub async fn start(config: terrastream::server::PartialConfig) -> Self {
        let config = terrastream::server::PartialConfig { bind: Some("127.0.0.1:0".into()), ..config };
        let server = terrastream::server::Server::bind(config.resolve().unwrap()).await.unwrap();
        let addr = server.local_addr().unwrap();
        let (tx, rx) = tokio::sync::oneshot::channel::<()>();
        let task = tokio::spawn(server.run(async move {
            let _ = rx.await;
        }));
        Self { addr, stop: Some(tx), task }
    }

    /// Starts the graceful shutdown without waiting for it.
    pub fn begin_stop(&mut self) {
        if let Some(tx) = self.stop.take() {
            let _ = tx.send(());
        }
    }

    /// Shuts down and asserts the server ended cleanly within `limit`.
    pub async fn stop_within(mut self, limit: Duration) {
        self.begin_stop();
        tokio::time::timeout(limit, self.task).await.unwrap().unwrap().unwrap();
    }

    /// [`Running::stop_within`] 30 s.
    pub async fn stop(self) {
        self.stop_within(Duration::from_secs(30)).await;
    }
}

/// `raster::synth::terrain(w, h, seed)` as a float GeoTIFF at `path`: 10 m cells, sample (0, 0)
/// at `origin`, rows going south.
pub fn write_synth_geotiff(path: &Path, (w, h): (u32, u32), seed: u64, origin: (f64, f64)) {
    let heights = terrastream::raster::synth::terrain(w, h, seed);
    let bytes = terrastream::raster::geotiff::encode_f32(w, h, &heights, origin, (10.0, -10.0)).unwrap();
    std::fs::write(path, bytes).unwrap();
}

/// Bakes `raster` (read from a file named `source`) into the tileset folder `out`: the CPU
/// point baker, no progress output.
pub fn bake_cpu(
    raster: &terrastream::raster::LoadedRaster,
    source: &str,
    opts: &terrastream::bake::BakeOptions,
    out: &Path,
) {
    let store = terrastream::store::Store::new(out);
    let cpu = terrastream::lod::PointBaker::Cpu;
    terrastream::bake::bake_terrain(raster, source, opts, &cpu, &store, &terrastream::bake::NoProgress)
        .unwrap();
}

/// Loads the raster file `src` with the default options and bakes it ([`bake_cpu`]) into `out`,
/// its file name as the source's name.
pub fn bake_file(src: &Path, opts: &terrastream::bake::BakeOptions, out: &Path) {
    let r = terrastream::raster::load(src, &terrastream::raster::LoadOptions::default()).unwrap();
    bake_cpu(&r, &src.file_name().unwrap().to_string_lossy(), opts, out);
}

/// A xorshift64 generator from `seed` (not 0): deterministic noise for hostile-input tests.
pub fn xorshift(mut seed: u64) -> impl FnMut() -> u64 {
    move || {
        seed ^= seed << 13;
        seed ^= seed >> 7;
        seed ^= seed << 17;
        seed
    }
}
