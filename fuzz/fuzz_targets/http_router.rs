//! The HTTP server in-process: requests built from the input (method, path, query, headers,
//! body) go through the service `Server::run` serves (the blob fast path in front of the axum
//! router) with `tower::ServiceExt::oneshot`, against a store holding a tiny tileset baked
//! once at start (`demo`) and a copy of it whose manifest states a large depth (`deep`: 63 by
//! default, see `setup`). Invariants: no panic, no 5xx but 503, every status one the OpenAPI
//! document lists (or 400/404/405), every error an `application/problem+json` body.
#![no_main]
use std::collections::BTreeSet;
use std::convert::Infallible;
use std::path::Path;
use std::sync::OnceLock;

use arbitrary::Arbitrary;
use axum::body::Body;
use axum::extract::Request;
use axum::response::Response;
use http_body_util::BodyExt;
use libfuzzer_sys::fuzz_target;
use terrastream::bake::{BakeOptions, NoProgress, PointLevels};
use terrastream::lod::GpuMode;
use terrastream::raster::{Georef, Heightfield, LoadedRaster};
use terrastream::server::{Config, Server};
use terrastream::store::Store;
use tower::ServiceExt;
use tower::util::BoxCloneSyncService;

type Svc = BoxCloneSyncService<Request, Response, Infallible>;

struct State {
    rt: tokio::runtime::Runtime,
    svc: Svc,
    /// Paths that exist in the store (blobs, chunks, manifests) and the fixed routes.
    known: Vec<String>,
    /// Every status the OpenAPI document lists, plus 400, 404 and 405.
    allowed: BTreeSet<u16>,
    _dir: tempfile::TempDir,
    _server: Server,
}

fn walk(dir: &Path, out: &mut Vec<std::path::PathBuf>) {
    for e in std::fs::read_dir(dir).expect("read store").flatten() {
        let p = e.path();
        if p.is_dir() { walk(&p, out) } else { out.push(p) }
    }
}

fn setup() -> State {
    let dir = tempfile::tempdir().expect("tempdir");
    let (w, h) = (65, 49);
    let raster = LoadedRaster {
        heights: Heightfield { width: w, height: h, data: terrastream::raster::synth::terrain(w, h, 7) },
        georef: Georef { dx: 10.0, dy: -10.0, ..Georef::default() },
        nodata_filled: 0,
        nodata_fallback: 0,
        format: "synthetic".into(),
    };
    let opts = BakeOptions { tile_size: 32, max_error: 2.0, levels: 2, point_levels: PointLevels::All };
    let demo = dir.path().join("demo");
    terrastream::bake::bake_terrain(
        &raster,
        "synthetic",
        &opts,
        &terrastream::lod::PointBaker::Cpu,
        &Store::new(&demo),
        &NoProgress,
    )
    .expect("bake");
    // `deep`: the same tiles under a manifest stating depth 255.
    let mut files = Vec::new();
    walk(&demo, &mut files);
    let deep = dir.path().join("deep");
    for f in &files {
        let rel = f.strip_prefix(&demo).expect("prefix");
        let to = deep.join(rel);
        std::fs::create_dir_all(to.parent().expect("parent")).expect("mkdir");
        std::fs::copy(f, &to).expect("copy");
    }
    let mpath = deep.join("tileset.json");
    let mut m: serde_json::Value =
        serde_json::from_slice(&std::fs::read(&mpath).expect("manifest")).expect("json");
    // 255, the largest a manifest can state: this target found `server::http::parse_key`
    // overflowing `1u64 << z` for z ≥ 64 (fixed; tests/fuzz_regressions.rs).
    // TS_FUZZ_DEEP_DEPTH sets another depth.
    let depth: u8 = std::env::var("TS_FUZZ_DEEP_DEPTH").ok().and_then(|v| v.parse().ok()).unwrap_or(255);
    m["depth"] = depth.into();
    std::fs::write(&mpath, serde_json::to_vec(&m).expect("json")).expect("write");

    let mut known: Vec<String> = [
        "/healthz",
        "/readyz",
        "/metrics",
        "/openapi.json",
        "/tilesets",
        "/jobs/1",
        "/tilesets/demo",
        "/tilesets/deep",
    ]
    .map(str::to_owned)
    .into();
    for f in files {
        let rel = f.strip_prefix(&demo).expect("prefix").to_string_lossy().into_owned();
        let url = if let Some(b) = rel.strip_prefix("tiles/").and_then(|r| r.strip_suffix(".tsb")) {
            format!("tiles/{b}")
        } else if rel.starts_with("index/") || rel == "tileset.json" {
            rel
        } else {
            continue;
        };
        known.push(format!("/tilesets/demo/{url}"));
        known.push(format!("/tilesets/deep/{url}"));
    }
    known.sort();

    let mut config = Config::for_store(dir.path()).expect("config");
    config.bind = "127.0.0.1:0".parse().expect("addr");
    config.gpu = GpuMode::Off;
    config.poll = std::time::Duration::from_secs(3600);
    let rt = tokio::runtime::Builder::new_current_thread().enable_all().build().expect("runtime");
    let server = rt.block_on(Server::bind(config)).expect("bind");
    let svc = Svc::new(server.service());
    let doc = rt.block_on(async {
        let req =
            Request::get("/openapi.json").header("host", "127.0.0.1").body(Body::empty()).expect("request");
        let resp = svc.clone().oneshot(req).await.expect("infallible");
        resp.into_body().collect().await.expect("body").to_bytes()
    });
    let doc: serde_json::Value = serde_json::from_slice(&doc).expect("openapi json");
    let mut allowed: BTreeSet<u16> = [400, 404, 405].into();
    for ops in doc["paths"].as_object().expect("paths").values() {
        for op in ops.as_object().expect("ops").values() {
            if let Some(r) = op.get("responses").and_then(|r| r.as_object()) {
                allowed.extend(r.keys().filter_map(|k| k.parse::<u16>().ok()));
            }
        }
    }
    State { rt, svc, known, allowed, _dir: dir, _server: server }
}

static STATE: OnceLock<State> = OnceLock::new();

#[derive(Debug, Arbitrary)]
enum Method {
    Get,
    Head,
    Options,
    Post,
    Delete,
    Put,
    Other(String),
}

#[derive(Debug, Arbitrary)]
enum Seg {
    Word(u8),
    Num(u32),
    Raw(String),
}

const WORDS: &[&str] = &[
    "tilesets",
    "demo",
    "deep",
    "tiles",
    "index",
    "tileset.json",
    "0.json",
    "jobs",
    "0",
    "1",
    "2",
    "3",
    "64",
    "255",
    "",
    "..",
    ".",
    "%2e%2e",
    "%2F",
    "%00",
    "-1",
    "+1",
    "01",
    "4294967296",
    "healthz",
    "metrics",
];

#[derive(Debug, Arbitrary)]
enum Path_ {
    /// A known path, with segment `at` (if any) replaced.
    Known(u16, Option<(u8, Seg)>),
    Built(Vec<Seg>),
}

#[derive(Debug, Arbitrary)]
enum Hdr {
    Range,
    IfNoneMatch,
    IfRange,
    Authorization,
    Origin,
    AccessControlRequestMethod,
    AccessControlRequestHeaders,
    AcceptEncoding,
    ContentType,
    ContentLength,
    Raw(String),
}

#[derive(Debug, Arbitrary)]
struct Input {
    method: Method,
    path: Path_,
    query: Option<String>,
    headers: Vec<(Hdr, Vec<u8>)>,
    body: Vec<u8>,
}

fn seg(s: &Seg) -> String {
    match s {
        Seg::Word(i) => WORDS[*i as usize % WORDS.len()].to_owned(),
        Seg::Num(n) => n.to_string(),
        Seg::Raw(r) => r.clone(),
    }
}

fn build(st: &State, inp: Input) -> Option<Request> {
    let mut path = match &inp.path {
        Path_::Known(i, repl) => {
            let p = &st.known[*i as usize % st.known.len()];
            match repl {
                None => p.clone(),
                Some((at, s)) => {
                    let mut parts: Vec<String> = p.split('/').map(str::to_owned).collect();
                    let k = 1 + *at as usize % (parts.len() - 1);
                    parts[k] = seg(s);
                    parts.join("/")
                }
            }
        }
        Path_::Built(segs) => segs.iter().fold(String::new(), |acc, s| acc + "/" + &seg(s)),
    };
    if path.is_empty() {
        path.push('/');
    }
    if let Some(q) = &inp.query {
        path = format!("{path}?{q}");
    }
    let method = match &inp.method {
        Method::Get => axum::http::Method::GET,
        Method::Head => axum::http::Method::HEAD,
        Method::Options => axum::http::Method::OPTIONS,
        Method::Post => axum::http::Method::POST,
        Method::Delete => axum::http::Method::DELETE,
        Method::Put => axum::http::Method::PUT,
        Method::Other(m) => axum::http::Method::from_bytes(m.as_bytes()).ok()?,
    };
    // HTTP/1.1 requires one Host (the server answers 400 without it); a fuzzed Raw "host"
    // header adds a second one, which is the 400 case.
    let mut b = Request::builder().method(method).uri(path).header("host", "127.0.0.1");
    for (h, v) in &inp.headers {
        use axum::http::header;
        let name = match h {
            Hdr::Range => header::RANGE,
            Hdr::IfNoneMatch => header::IF_NONE_MATCH,
            Hdr::IfRange => header::IF_RANGE,
            Hdr::Authorization => header::AUTHORIZATION,
            Hdr::Origin => header::ORIGIN,
            Hdr::AccessControlRequestMethod => header::ACCESS_CONTROL_REQUEST_METHOD,
            Hdr::AccessControlRequestHeaders => header::ACCESS_CONTROL_REQUEST_HEADERS,
            Hdr::AcceptEncoding => header::ACCEPT_ENCODING,
            Hdr::ContentType => header::CONTENT_TYPE,
            Hdr::ContentLength => header::CONTENT_LENGTH,
            Hdr::Raw(n) => match header::HeaderName::from_bytes(n.as_bytes()) {
                Ok(n) => n,
                Err(_) => continue,
            },
        };
        let Ok(value) = header::HeaderValue::from_bytes(v) else { continue };
        b = b.header(name, value);
    }
    b.body(Body::from(inp.body)).ok()
}

// The tileset is baked and the server started before the first input, so that set-up (about
// 0.2 s, more on a loaded machine) is not charged to an input as a timeout.
fuzz_target!(init: { STATE.get_or_init(setup); }, |inp: Input| {
    let st = STATE.get_or_init(setup);
    let Some(req) = build(st, inp) else { return };
    let what = format!("{} {}", req.method(), req.uri());
    let (status, content_type, body) = st.rt.block_on(async {
        let resp = st.svc.clone().oneshot(req).await.expect("infallible");
        let status = resp.status().as_u16();
        let ct = resp.headers().get("content-type").map(|v| v.as_bytes().to_vec());
        let body = resp.into_body().collect().await.map(|b| b.to_bytes());
        (status, ct, body)
    });
    let body = body.unwrap_or_else(|e| panic!("{what}: response body failed: {e}"));
    assert!(
        !(500..600).contains(&status) || status == 503,
        "{what}: status {status}: {}",
        String::from_utf8_lossy(&body)
    );
    assert!(st.allowed.contains(&status), "{what}: status {status} is not in the OpenAPI document");
    if status >= 400 {
        let ct = content_type.unwrap_or_default();
        assert!(
            ct.starts_with(b"application/problem+json"),
            "{what}: status {status} with content-type {:?}",
            String::from_utf8_lossy(&ct)
        );
    }
});
