//! The 3D Tiles 1.1 view of every tileset of the store, made on the fly from the stored index
//! chunks and blobs (no re-bake): `/tilesets/{name}/3dtiles/tileset.json` (the root, placed on
//! the globe), `…/3dtiles/index/{z}/{x}/{y}.json` (one external tileset per index chunk) and
//! `…/3dtiles/tiles/{z}/{x}/{y}/{level}.glb`, with the caching rules of blobs (strong ETags,
//! immutable `?v=` URLs, conditional and range requests); and the viewer page (`/viewer`).
//!
//! GLBs and tileset JSON are sent compressed where the request's `Accept-Encoding` allows
//! ([`Coding`]: `gzip`, or `zstd` where preferred, else none), with `Vary: Accept-Encoding` and one strong ETag
//! per coding (the tag of the bytes sent); a compressed GLB or chunk JSON is cached beside its
//! plain form, so warm requests never recompress.
//!
//! `?glb=meshopt` on any of these routes gives GLBs with `EXT_meshopt_compression` (the bytes of
//! `export --glb-compression meshopt`), `?glb=draco` mesh GLBs with `KHR_draco_mesh_compression`
//! (and point GLBs with meshopt; `export --glb-compression draco`), and the tileset JSON lists its content and external
//! tilesets with the option carried on; each form is cached apart.

use std::sync::Arc;

use axum::extract::{Path, RawQuery, State};
use axum::http::{HeaderMap, HeaderValue, Method, StatusCode, header};
use axum::response::Response;
use bytes::Bytes;

use super::App;
use super::cache::{CacheKey, Entry, GLB, TILES3D_CHUNK};
use super::conditional::{Conditional, etag_value, send};
use super::loaders::{
    NO_CACHE, SHORT, chunk_entry, load_blob, parse_key, parse_level, tileset, versioned_cache_with,
};
use super::problem::Problem;
use super::registry::{Tileset, etag_of};
use crate::bake::export;
use crate::formats::tiles3d::{
    BorderFans, GLB_REVISION, GLB_TYPE, GlbCompression, TilesetInfo, around, chunk_tileset, path_cap,
    planned_entry, takes_neighbours, tile_fans, tile_glb,
};
use crate::store::{IndexChunk, SUBTREE_LEVELS, chunk_root};
use crate::tiling::TileKey;

/// The viewer page (`GET /viewer`): a small WebGL 2 client of the 3D Tiles routes, no
/// third-party code, no network beyond this server.
const VIEWER_HTML: &str = include_str!("viewer.html");

type Rejection = axum::extract::rejection::PathRejection;

/// The cache document of a tile level's GLB compressed with gzip (this plus the level; `GLB` is
/// the plain one, 0x200 and 0x300 are quantized-mesh and heightmap tiles).
const GLB_GZIP: u16 = 0x400;
/// The same for zstd.
const GLB_ZSTD: u16 = 0x500;
/// The cache documents of a chunk's tileset JSON compressed ([`TILES3D_CHUNK`] is the plain one).
const TILES3D_CHUNK_GZIP: u16 = u16::MAX - 2;
const TILES3D_CHUNK_ZSTD: u16 = u16::MAX - 3;
/// The same three for `?glb=meshopt` (its URIs carry the option).
const TILES3D_CHUNK_MESHOPT: [u16; 3] = [u16::MAX - 4, u16::MAX - 5, u16::MAX - 6];
/// The cache documents of a GLB with `EXT_meshopt_compression`: plain, gzip, zstd (plus the level).
const GLB_MESHOPT: [u16; 3] = [0x600, 0x700, 0x800];
/// The same three for `?glb=draco`.
const TILES3D_CHUNK_DRACO: [u16; 3] = [u16::MAX - 7, u16::MAX - 8, u16::MAX - 9];
/// The cache documents of a GLB with `KHR_draco_mesh_compression` (meshes) or
/// `EXT_meshopt_compression` (points): plain, gzip, zstd (plus the level).
const GLB_DRACO: [u16; 3] = [0x900, 0xa00, 0xb00];
/// gzip level: 6 gives the bytes of 9 on GLBs (within 0.1 %) in a fifth of the time.
const GZIP_LEVEL: u32 = 6;
/// zstd level: on GLBs only 19 beats gzip (by about a tenth); lower levels come out larger.
const ZSTD_LEVEL: i32 = 19;
/// Longest `Accept-Encoding` header read; a longer one is treated as absent (no coding).
const MAX_ACCEPT_ENCODING: usize = 1024;

/// A content coding of the 3D Tiles routes' bodies (RFC 9110 §8.4), chosen per request from
/// `Accept-Encoding` ([`Coding::negotiate`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(super) enum Coding {
    Zstd,
    Gzip,
    Identity,
}

impl Coding {
    /// The coding to send for an `Accept-Encoding` value: of `gzip` (or `x-gzip`) and `zstd` the
    /// one of highest weight above 0, listed by name or through `*`; gzip when they tie (what
    /// browsers send): zstd is smaller only at level 19, which costs about 1.5 s of CPU a
    /// megabyte on a tile's first request, gzip a tenth of that; otherwise none (`identity` is always acceptable to us: a client that refuses
    /// it and everything else gets the plain body, as RFC 9110 allows). No header, or one
    /// longer than [`MAX_ACCEPT_ENCODING`], means no coding.
    pub(super) fn negotiate(accept: Option<&HeaderValue>) -> Self {
        accept.map_or(Self::Identity, |v| Self::negotiate_bytes(v.as_bytes()))
    }

    /// [`Coding::negotiate`] on a header value's bytes, without an allocation (the wire-level
    /// fast path's): a value that is not visible ASCII means no coding, as
    /// `HeaderValue::to_str` fails on it.
    pub(super) fn negotiate_bytes(accept: &[u8]) -> Self {
        if accept.len() > MAX_ACCEPT_ENCODING || !accept.iter().all(|&b| b == b'\t' || (32..127).contains(&b))
        {
            return Self::Identity;
        }
        let Ok(text) = std::str::from_utf8(accept) else { return Self::Identity };
        let (mut zstd, mut gzip, mut star) = (None, None, None);
        for item in text.split(',') {
            let mut parts = item.split(';');
            let name = parts.next().unwrap_or("").trim();
            let mut q = Some(1.0);
            for param in parts {
                if let Some((k, v)) = param.split_once('=')
                    && k.trim().eq_ignore_ascii_case("q")
                {
                    q = v.trim().parse::<f64>().ok().filter(|q| (0.0..=1.0).contains(q));
                }
            }
            // A malformed weight makes the element count as refused.
            let q = q.unwrap_or(0.0);
            if name.eq_ignore_ascii_case("zstd") {
                zstd = Some(q);
            } else if name.eq_ignore_ascii_case("gzip") || name.eq_ignore_ascii_case("x-gzip") {
                gzip = Some(gzip.map_or(q, |g: f64| g.max(q)));
            } else if name == "*" {
                star = Some(q);
            }
        }
        let zstd = zstd.or(star).unwrap_or(0.0);
        let gzip = gzip.or(star).unwrap_or(0.0);
        if gzip > 0.0 && gzip >= zstd {
            Self::Gzip
        } else if zstd > 0.0 {
            Self::Zstd
        } else {
            Self::Identity
        }
    }

    /// The `Content-Encoding` token.
    fn token(self) -> Option<&'static str> {
        match self {
            Self::Zstd => Some("zstd"),
            Self::Gzip => Some("gzip"),
            Self::Identity => None,
        }
    }

    /// `bytes` in this coding (`None` for identity).
    pub(super) fn encode(self, bytes: &[u8]) -> std::io::Result<Option<Vec<u8>>> {
        use std::io::Write as _;
        match self {
            Self::Identity => Ok(None),
            Self::Gzip => {
                let mut e = flate2::write::GzEncoder::new(
                    Vec::with_capacity(bytes.len() / 2),
                    flate2::Compression::new(GZIP_LEVEL),
                );
                e.write_all(bytes)?;
                e.finish().map(Some)
            }
            Self::Zstd => zstd::bulk::compress(bytes, ZSTD_LEVEL).map(Some),
        }
    }
}

/// The request's `Accept-Encoding`, as [`Coding::negotiate`] reads it.
pub(super) struct AcceptEncoding(pub(super) Coding);

impl<S: Send + Sync> axum::extract::FromRequestParts<S> for AcceptEncoding {
    type Rejection = std::convert::Infallible;

    async fn from_request_parts(
        parts: &mut axum::http::request::Parts,
        _: &S,
    ) -> Result<Self, Self::Rejection> {
        Ok(Self(Coding::negotiate(parts.headers.get(header::ACCEPT_ENCODING))))
    }
}

/// `plain` in `coding` with its own strong ETag, from the cache under `key` when it is there
/// (compressed off the async threads, then cached when `cache` is set); `plain` itself for
/// identity or if compressing fails (logged: the plain body is still a right answer).
async fn coded(app: &App, plain: &Entry, coding: Coding, key: Option<CacheKey>) -> (Entry, Coding) {
    if coding == Coding::Identity {
        return (plain.clone(), coding);
    }
    if let Some(k) = &key
        && let Some(e) = app.cache.get(k)
    {
        return (e, coding);
    }
    let bytes = plain.bytes.clone();
    let made = tokio::task::spawn_blocking(move || coding.encode(&bytes)).await;
    match made {
        Ok(Ok(Some(b))) => {
            let e = Entry { etag: etag_value(&etag_of(&b)), bytes: Bytes::from(b) };
            if let Some(k) = key {
                app.cache.insert(k, e.clone());
            }
            (e, coding)
        }
        Ok(Err(e)) => {
            tracing::error!(error = %e, ?coding, "compressing a 3D Tiles body failed; sending it plain");
            (plain.clone(), Coding::Identity)
        }
        // No coding (not reached: identity returned above), or the task was lost.
        Ok(Ok(None)) | Err(_) => (plain.clone(), Coding::Identity),
    }
}

/// [`send`] with the coding's `Content-Encoding` and `Vary: Accept-Encoding` (every response of
/// these routes varies with it, the plain ones too, so caches keep the forms apart).
fn send_coded(
    method: &Method,
    headers: &Conditional,
    e: &Entry,
    coding: Coding,
    content_type: &'static str,
    cache: &'static str,
) -> Response {
    let mut r = send(method, headers, e, content_type, cache);
    let h: &mut HeaderMap = r.headers_mut();
    if let Some(t) = coding.token() {
        h.insert(header::CONTENT_ENCODING, HeaderValue::from_static(t));
    }
    h.append(header::VARY, HeaderValue::from_static("accept-encoding"));
    r
}

/// The cache document of `plain`'s compressed form.
fn coded_doc(coding: Coding, gzip: u16, zstd: u16) -> Option<u16> {
    match coding {
        Coding::Gzip => Some(gzip),
        Coding::Zstd => Some(zstd),
        Coding::Identity => None,
    }
}

/// The `glb=` parameter of a 3D Tiles request (`none` when absent): how its GLBs are compressed.
fn glb_option(query: Option<&str>) -> Result<GlbCompression, Problem> {
    let v = query.into_iter().flat_map(|q| q.split('&')).find_map(|kv| kv.strip_prefix("glb="));
    match v {
        None => Ok(GlbCompression::None),
        Some(v) => GlbCompression::parse(v).ok_or_else(|| {
            Problem::bad_request(format!("glb={v:?}: give glb=meshopt, glb=draco or glb=none"))
        }),
    }
}

/// The tileset's 3D Tiles view as this server gives it: URIs carry `?v=<content version>` (and
/// `&glb=meshopt` when asked for, so every document and GLB below keeps the option).
async fn info(ts: &Arc<Tileset>, with_anchor: bool, glb: GlbCompression) -> Result<TilesetInfo, Problem> {
    let anchor = if with_anchor {
        let store = ts.store.clone();
        tokio::task::spawn_blocking(move || export::read_anchor(&store))
            .await
            .map_err(|_| Problem::internal("placement", "reading the placement failed"))?
            .map_err(|e| {
                tracing::error!(tileset = %ts.name, error = %e, "cannot read the tileset's placement");
                Problem::internal(
                    "placement",
                    format!("the placement of tileset {:?} cannot be read", ts.name),
                )
            })?
    } else {
        None
    };
    let query = match glb {
        GlbCompression::None => format!("?v={}{GLB_REVISION}", ts.content_version),
        GlbCompression::Meshopt | GlbCompression::Draco => {
            format!("?v={}{GLB_REVISION}&glb={}", ts.content_version, glb.name())
        }
    };
    let mut info =
        TilesetInfo::from_manifest_json(&ts.name, &ts.manifest_json, anchor, query).map_err(|e| {
            tracing::error!(tileset = %ts.name, error = %e, "cannot read the manifest for 3D Tiles");
            Problem::internal(
                "manifest",
                format!("the manifest of tileset {:?} cannot be read: {e}", ts.name),
            )
        })?;
    info.glb = glb;
    Ok(info)
}

/// The index chunk rooted at `key`, parsed, and whether it still grows.
async fn chunk(app: &App, ts: &Arc<Tileset>, key: TileKey) -> Result<(IndexChunk, bool), Problem> {
    let (entry, growing) = chunk_entry(app, ts, key).await?;
    let chunk = serde_json::from_slice(&entry.bytes).map_err(|e| {
        tracing::error!(tileset = %ts.name, chunk = %key, error = %e, "cannot parse index chunk");
        Problem::internal("index", format!("index chunk {key} of tileset {:?} cannot be read", ts.name))
    })?;
    Ok((chunk, growing))
}

/// The cap of the external tileset rooted at `key` ([`path_cap`]: the least mesh error from the
/// root to `key`'s parent), from the index chunks above it; and whether one of them is still
/// growing (an on-demand tileset baking).
async fn cap_above(
    app: &App,
    ts: &Arc<Tileset>,
    info: &TilesetInfo,
    key: TileKey,
) -> Result<(f64, bool), Problem> {
    let mut path = Vec::with_capacity(usize::from(key.z));
    let mut growing = false;
    for z in 0..key.z {
        let shift = key.z - z;
        let a = TileKey::new(z, key.x >> shift, key.y >> shift);
        let (c, g) = chunk(app, ts, chunk_root(a)).await?;
        growing |= g;
        if let Some(n) = c.nodes.into_iter().find(|n| n.key == a).or_else(|| planned_entry(info, a)) {
            path.push(n);
        }
    }
    Ok((path_cap(info, &path), growing))
}

fn json_entry(v: &serde_json::Value) -> Entry {
    let body = serde_json::to_vec(v).unwrap_or_default();
    Entry { etag: etag_value(&etag_of(&body)), bytes: Bytes::from(body) }
}

/// `GET /tilesets/{name}/3dtiles/tileset.json`: the root tileset (index chunk 0/0/0, the
/// root `transform` at the anchor). Short-lived like the manifest: it names the content version
/// (`no-cache` while an on-demand tileset is baking: it changes as nodes bake).
pub(super) async fn root(
    State(app): State<Arc<App>>,
    path: Result<Path<String>, Rejection>,
    RawQuery(query): RawQuery,
    method: Method,
    headers: Conditional,
    AcceptEncoding(coding): AcceptEncoding,
) -> Result<Response, Problem> {
    let Path(name) = path.map_err(|e| Problem::bad_request(e.body_text()))?;
    let glb = glb_option(query.as_deref())?;
    let ts = tileset(&app, &name)?;
    let info = info(&ts, true, glb).await?;
    let (c, growing) = chunk(&app, &ts, TileKey::new(0, 0, 0)).await?;
    let entry = json_entry(
        &chunk_tileset(&info, &c, true, f64::INFINITY).map_err(|e| placement_problem(&ts.name, &e))?,
    );
    // Not cached (it names the content version): compressed per request, it is small.
    let (entry, coding) = coded(&app, &entry, coding, None).await;
    Ok(send_coded(
        &method,
        &headers,
        &entry,
        coding,
        "application/json",
        if growing { NO_CACHE } else { SHORT },
    ))
}

type ChunkPath = (String, String, String, String);

/// `GET /tilesets/{name}/3dtiles/index/{z}/{x}/{y}.json`: the external tileset of one index
/// chunk below the root.
pub(super) async fn subtree(
    State(app): State<Arc<App>>,
    path: Result<Path<ChunkPath>, Rejection>,
    RawQuery(query): RawQuery,
    method: Method,
    headers: Conditional,
    AcceptEncoding(coding): AcceptEncoding,
) -> Result<Response, Problem> {
    let Path((name, z, x, file)) = path.map_err(|e| Problem::bad_request(e.body_text()))?;
    let ts = tileset(&app, &name)?;
    let y = file
        .strip_suffix(".json")
        .ok_or_else(|| Problem::bad_request(format!("tileset {file:?} must be named Y.json")))?;
    let key = parse_key(&ts, &z, &x, y)?;
    if key.z % SUBTREE_LEVELS != 0 || key.z == 0 {
        return Err(Problem::not_found(format!(
            "external tilesets are rooted at z = {SUBTREE_LEVELS}, {}, …; z {} is not one (z 0 is 3dtiles/tileset.json)",
            SUBTREE_LEVELS * 2,
            key.z
        )));
    }
    let glb = glb_option(query.as_deref())?;
    let docs = match glb {
        GlbCompression::None => [TILES3D_CHUNK, TILES3D_CHUNK_GZIP, TILES3D_CHUNK_ZSTD],
        GlbCompression::Meshopt => TILES3D_CHUNK_MESHOPT,
        GlbCompression::Draco => TILES3D_CHUNK_DRACO,
    };
    let ck = (ts.generation, key, docs[0]);
    let coded_key = coded_doc(coding, docs[1], docs[2]).map(|d| (ts.generation, key, d));
    let cache = versioned_cache_with(&ts, query.as_deref(), GLB_REVISION);
    if let Some(e) = coded_key.and_then(|k| app.cache.get(&k)) {
        return Ok(send_coded(&method, &headers, &e, coding, "application/json", cache));
    }
    if let Some(e) = app.cache.get(&ck) {
        let (e, coding) = coded(&app, &e, coding, coded_key).await;
        return Ok(send_coded(&method, &headers, &e, coding, "application/json", cache));
    }
    let info = info(&ts, false, glb).await?;
    let (c, growing) = chunk(&app, &ts, key).await?;
    let (cap, above_growing) = cap_above(&app, &ts, &info, key).await?;
    let growing = growing || above_growing;
    let entry =
        json_entry(&chunk_tileset(&info, &c, false, cap).map_err(|e| placement_problem(&ts.name, &e))?);
    if growing {
        let (entry, coding) = coded(&app, &entry, coding, None).await;
        return Ok(send_coded(&method, &headers, &entry, coding, "application/json", NO_CACHE));
    }
    app.cache.insert(ck, entry.clone());
    let (entry, coding) = coded(&app, &entry, coding, coded_key).await;
    Ok(send_coded(&method, &headers, &entry, coding, "application/json", cache))
}

type TilePath = (String, String, String, String, String);

/// `GET /tilesets/{name}/3dtiles/tiles/{z}/{x}/{y}/{level}.glb`: one stored (tile, level) as
/// glTF binary, made from its verified blob (baked first for an on-demand tileset).
pub(super) async fn glb(
    State(app): State<Arc<App>>,
    path: Result<Path<TilePath>, Rejection>,
    RawQuery(query): RawQuery,
    method: Method,
    headers: Conditional,
    AcceptEncoding(coding): AcceptEncoding,
) -> Result<Response, Problem> {
    let Path((name, z, x, y, file)) = path.map_err(|e| Problem::bad_request(e.body_text()))?;
    let ts = tileset(&app, &name)?;
    let key = parse_key(&ts, &z, &x, &y)?;
    let level = file
        .strip_suffix(".glb")
        .ok_or_else(|| Problem::bad_request(format!("tile {file:?} must be named LEVEL.glb")))?;
    let level = parse_level(&ts, level)?;
    let glb = glb_option(query.as_deref())?;
    let docs = glb_docs(glb);
    let ck = (ts.generation, key, docs[0] + u16::from(level));
    let coded_key = coded_doc(coding, docs[1], docs[2]).map(|d| (ts.generation, key, d + u16::from(level)));
    let cache = versioned_cache_with(&ts, query.as_deref(), GLB_REVISION);
    if let Some(e) = coded_key.and_then(|k| app.cache.get(&k)) {
        return Ok(send_coded(&method, &headers, &e, coding, GLB_TYPE, cache));
    }
    if let Some(e) = app.cache.get(&ck) {
        let (e, coding) = coded(&app, &e, coding, coded_key).await;
        return Ok(send_coded(&method, &headers, &e, coding, GLB_TYPE, cache));
    }
    let blob = load_blob(&app, &ts, key, level).await?;
    let info = info(&ts, false, glb).await?;
    let failed = || Problem::internal("glb", format!("making the GLB of tile {key} level {level} failed"));
    let corrupt = |k: TileKey, e: &dyn std::fmt::Display| {
        tracing::error!(tileset = %ts.name, tile = %k, level, error = %e, "a verified blob does not decode");
        Problem::internal("corrupt-blob", format!("tile {k} level {level} does not decode"))
    };
    let decoded = tokio::task::spawn_blocking(move || crate::codec::decode(&blob.bytes))
        .await
        .map_err(|_| failed())?
        .map_err(|e| corrupt(key, &e))?;
    // A terrain mesh's border normals take its neighbours' fans: their blobs (baked first on
    // demand, so the bytes never depend on what else was asked for); a tile the tileset does
    // not have is no neighbour.
    let mut around_blobs = Vec::new();
    if takes_neighbours(&info, &decoded.header) {
        let keys = around(&info, key);
        let loads =
            futures_util::future::join_all(keys.iter().map(|&k| load_blob(&app, &ts, k, level))).await;
        for (k, got) in keys.into_iter().zip(loads) {
            match got {
                Ok(e) => around_blobs.push((k, e)),
                Err(p) if p.status == StatusCode::NOT_FOUND => {}
                Err(p) => return Err(p),
            }
        }
    }
    let fans = app.fans.clone();
    let generation = ts.generation;
    let made = tokio::task::spawn_blocking(move || -> Result<Vec<u8>, GlbFailure> {
        // Its own fans (from the memo when a neighbour's GLB made them first), then theirs.
        let mut around_fans = Vec::with_capacity(around_blobs.len() + 1);
        if !around_blobs.is_empty() {
            around_fans.push(fans.get_or_make((generation, key, level), || tile_fans(&info, &decoded))?);
        }
        for (k, e) in around_blobs {
            around_fans.push(fans.get_or_make((generation, k, level), || {
                let b =
                    crate::codec::decode(&e.bytes).map_err(|err| GlbFailure::Corrupt(k, err.to_string()))?;
                Ok::<_, GlbFailure>(tile_fans(&info, &b)?)
            })?);
        }
        let neighbours: Vec<&BorderFans> = around_fans.iter().filter_map(|f| f.as_ref().as_ref()).collect();
        Ok(tile_glb(&info, &decoded, &neighbours)?)
    })
    .await
    .map_err(|_| failed())?;
    let glb = match made {
        Ok(glb) => glb,
        Err(GlbFailure::Corrupt(k, e)) => return Err(corrupt(k, &e)),
        Err(GlbFailure::Tiles3d(e)) => return Err(placement_problem(&ts.name, &e)),
    };
    let entry = Entry { etag: etag_value(&etag_of(&glb)), bytes: Bytes::from(glb) };
    app.cache.insert(ck, entry.clone());
    let (entry, coding) = coded(&app, &entry, coding, coded_key).await;
    Ok(send_coded(&method, &headers, &entry, coding, GLB_TYPE, cache))
}

/// Why a GLB could not be made: a blob (its own or a neighbour's) that does not decode, or the
/// 3D Tiles view's own failure (placement, compression).
enum GlbFailure {
    Corrupt(TileKey, String),
    Tiles3d(crate::formats::tiles3d::Tiles3dError),
}

impl From<crate::formats::tiles3d::Tiles3dError> for GlbFailure {
    fn from(e: crate::formats::tiles3d::Tiles3dError) -> Self {
        Self::Tiles3d(e)
    }
}

/// Memory the server's memo of border fans may hold (see [`crate::formats::tiles3d::border`]).
pub(super) const FAN_MEMO_BYTES: usize = 64 << 20;

/// The GLB route as the metrics name it (the router's matched path).
pub(super) const GLB_ROUTE: &str = "/tilesets/{name}/3dtiles/tiles/{z}/{x}/{y}/{file}";

/// The cache documents of a GLB in `glb` compression: plain, gzip, zstd (plus the level).
fn glb_docs(glb: GlbCompression) -> [u16; 3] {
    match glb {
        GlbCompression::None => [GLB, GLB_GZIP, GLB_ZSTD],
        GlbCompression::Meshopt => GLB_MESHOPT,
        GlbCompression::Draco => GLB_DRACO,
    }
}

/// What [`glb`] answers for a `GET` of `path` (`/tilesets/{name}/3dtiles/tiles/{z}/{x}/{y}/{level}.glb`,
/// not percent-encoded) with `query` and the request's one `Accept-Encoding` value (if any),
/// when that answer is already in memory: the entry in the negotiated coding, its
/// `Cache-Control` and its `Content-Encoding` token. `None` for anything else (another path, a
/// bad key, level or `glb=`, a GLB or coded form not made yet): the router's way, which owns
/// every error answer and every GLB it makes. For the wire-level fast path (`server::fast`).
pub(super) fn cached_glb(
    app: &App,
    path: &str,
    query: Option<&str>,
    accept: Option<&[u8]>,
) -> Option<(Entry, &'static str, Option<&'static str>)> {
    if path.contains('%') {
        return None;
    }
    let mut parts = path.strip_prefix("/tilesets/")?.split('/');
    let name = parts.next()?;
    let (t3, tiles) = (parts.next()?, parts.next()?);
    let (z, x, y, file) = (parts.next()?, parts.next()?, parts.next()?, parts.next()?);
    if t3 != "3dtiles" || tiles != "tiles" || parts.next().is_some() {
        return None;
    }
    let level = file.strip_suffix(".glb")?;
    let ts = tileset(app, name).ok()?;
    let key = parse_key(&ts, z, x, y).ok()?;
    let level = parse_level(&ts, level).ok()?;
    let docs = glb_docs(glb_option(query).ok()?);
    let coding = accept.map_or(Coding::Identity, Coding::negotiate_bytes);
    let doc = coded_doc(coding, docs[1], docs[2]).unwrap_or(docs[0]);
    let entry = app.cache.get(&(ts.generation, key, doc + u16::from(level)))?;
    Some((entry, versioned_cache_with(&ts, query, GLB_REVISION), coding.token()))
}

/// A tileset that cannot be placed on the Earth (its geoid grid unreadable, a point outside
/// its CRS's domain), or a GLB the meshopt or Draco encoder refuses: a server-side fault,
/// logged and named.
fn placement_problem(name: &str, e: &crate::formats::tiles3d::Tiles3dError) -> Problem {
    use crate::formats::tiles3d::Tiles3dError;
    if matches!(e, Tiles3dError::Meshopt(_) | Tiles3dError::Draco(_)) {
        tracing::error!(tileset = %name, error = %e, "cannot compress a GLB");
        return Problem::internal("glb", format!("a GLB of tileset {name:?} cannot be compressed: {e}"));
    }
    tracing::error!(tileset = %name, error = %e, "cannot place the tileset on the Earth");
    Problem::internal("placement", format!("tileset {name:?} cannot be placed on the Earth: {e}"))
}

/// `GET /viewer`: the viewer page (it reads `?tileset=NAME` itself).
pub(super) async fn viewer(method: Method, headers: Conditional) -> Response {
    let entry = Entry {
        etag: etag_value(&etag_of(VIEWER_HTML.as_bytes())),
        bytes: Bytes::from_static(VIEWER_HTML.as_bytes()),
    };
    let mut r = send(&method, &headers, &entry, "text/html; charset=utf-8", SHORT);
    // The page runs only its own inline script and talks only to this server.
    r.headers_mut().insert(
        header::CONTENT_SECURITY_POLICY,
        HeaderValue::from_static(
            "default-src 'self'; script-src 'unsafe-inline' 'self'; style-src 'unsafe-inline' 'self'; img-src 'self' data:",
        ),
    );
    r
}
