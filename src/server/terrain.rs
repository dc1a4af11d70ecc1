//! Cesium quantized-mesh globe terrain of every tileset: `/tilesets/{name}/terrain/layer.json`
//! and `…/terrain/{z}/{x}/{y}.terrain`. A tileset baked with `--terrain` serves its stored
//! tiles; an on-demand tileset (`--source`) builds each tile when first asked (single flight,
//! at most `--bake-workers` at once and `--bake-queue` waiting, then `503` + `Retry-After`),
//! with the very function the bake uses, so both give the same bytes. A tile is stored or built
//! once with every extension; each request gets the extensions its `Accept` header names
//! (`application/vnd.quantized-mesh;extensions=octvertexnormals-watermask-metadata`), gzipped
//! when `Accept-Encoding` allows, with strong ETags, `Vary`, and immutable `?v=` URLs.
//!
//! The same terrain as 3D Tiles for CesiumJS's `Cesium3DTilesTerrainProvider`, under
//! `…/terrain/3dtiles/` (tileset JSON, subtrees, one GLB per tile), made from those tiles with
//! the same caching, gzip and errors (`formats::qmesh::tiles3d` says how).

use std::collections::HashMap;
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::{Arc, Mutex};

use axum::extract::{Path, RawQuery, State};
use axum::http::{HeaderMap, HeaderValue, Method, StatusCode, header};
use axum::response::Response;
use bytes::Bytes;
use tokio::sync::{OnceCell, Semaphore};

use super::App;
use super::cache::Entry;
use super::conditional::{Conditional, etag_value, send};
use super::loaders::{SHORT, parse_num, stored_file_problem, tileset, versioned_cache};
use super::problem::Problem;
use super::registry::{Tileset, etag_of};
use crate::bake::qmesh::{TERRAIN_DIR, TerrainSource, tile_rel};
use crate::formats::qmesh::grid::zoom_error;
use crate::formats::qmesh::tiles3d::{self, Availability, Implicit};
use crate::formats::qmesh::{Extensions, QM_TYPE, TileId, decode, filter_extensions};
use crate::formats::tiles3d::GLB_TYPE;
use crate::tiling::TileKey;

/// Cache documents: `QM + variant` (extension bits, gzip bit) of a tile; `QM_FULL` the tile with
/// every extension as stored or built; `QM_LAYER` the layer document.
const QM: u16 = 0x200;
const QM_FULL: u16 = 0x210;
const QM_LAYER: u16 = 0x211;
/// 3D Tiles terrain documents: `T3_GLB + gzip bit` a tile's GLB, `T3_SUBTREE + gzip bit` a
/// subtree (keyed by its root tile), `T3_TILESET` the tileset JSON (keyed by tile 0/0/0).
const T3_GLB: u16 = 0x230;
const T3_SUBTREE: u16 = 0x232;
const T3_TILESET: u16 = 0x234;
/// A stored tile or layer document larger than this is refused as damaged (a tile with every
/// extension is at most ~100 KB: 4,225 vertices, a 64 KiB water mask).
const MAX_STORED_BYTES: u64 = 4 << 20;

type Flight = Arc<OnceCell<Result<Bytes, Problem>>>;

/// On-demand tile builds: single flight per tile, bounded concurrency and queue.
pub struct Builds {
    flights: Mutex<HashMap<(u64, TileId), Flight>>,
    permits: Semaphore,
    /// Builds running or waiting for a worker.
    waiting: AtomicUsize,
    /// At most this many running or waiting (`--bake-workers` + `--bake-queue`).
    limit: usize,
}

impl Builds {
    pub fn new(workers: usize, queue: usize) -> Self {
        Self {
            flights: Mutex::default(),
            permits: Semaphore::new(workers.max(1)),
            waiting: AtomicUsize::new(0),
            limit: workers.max(1) + queue,
        }
    }
}

type Rejection = axum::extract::rejection::PathRejection;
type TilePath = (String, String, String, String);

/// Whether the tileset's store holds baked terrain (its `terrain/layer.json`).
async fn baked(app: &App, ts: &Arc<Tileset>) -> Result<Option<Vec<u8>>, Problem> {
    let store = ts.store.clone();
    let rel = format!("{TERRAIN_DIR}/layer.json");
    let rel2 = rel.clone();
    tokio::task::spawn_blocking(move || store.read_file_within(&rel2, 2..=MAX_STORED_BYTES))
        .await
        .map_err(|_| Problem::internal("terrain", "reading the terrain failed"))?
        .map_err(|e| stored_file_problem(app, ts, &rel, "terrain layer", &e))
}

/// Whether the tileset's store holds baked terrain, without reading its layer.
async fn has_baked(app: &App, ts: &Arc<Tileset>) -> Result<bool, Problem> {
    let store = ts.store.clone();
    let rel = format!("{TERRAIN_DIR}/layer.json");
    let rel2 = rel.clone();
    tokio::task::spawn_blocking(move || store.has_file(&rel2))
        .await
        .map_err(|_| Problem::internal("terrain", "reading the terrain failed"))?
        .map_err(|e| stored_file_problem(app, ts, &rel, "terrain layer", &e))
}

fn no_terrain(name: &str) -> Problem {
    Problem::not_found(format!(
        "tileset {name:?} has no globe terrain: bake it with --terrain, or serve its source on demand (--source)"
    ))
}

fn terrain_problem(name: &str, e: &crate::bake::qmesh::TerrainError) -> Problem {
    tracing::error!(tileset = %name, error = %e, "cannot make globe terrain");
    match e {
        crate::bake::qmesh::TerrainError::NotPlaced => Problem::not_found(format!("tileset {name:?}: {e}")),
        _ => Problem::internal("terrain", format!("the terrain of tileset {name:?} cannot be made: {e}")),
    }
}

/// `GET /tilesets/{name}/terrain/layer.json`.
pub(super) async fn layer(
    State(app): State<Arc<App>>,
    path: Result<Path<String>, Rejection>,
    method: Method,
    headers: Conditional,
) -> Result<Response, Problem> {
    let Path(name) = path.map_err(|e| Problem::bad_request(e.body_text()))?;
    let ts = tileset(&app, &name)?;
    let entry = layer_entry(&app, &ts).await?;
    Ok(send(&method, &headers, &entry, "application/json", SHORT))
}

/// The layer document: from the cache, the store (baked terrain), or made from the source.
async fn layer_entry(app: &Arc<App>, ts: &Arc<Tileset>) -> Result<Entry, Problem> {
    let ck = (ts.generation, TileKey::new(0, 0, 0), QM_LAYER);
    if let Some(e) = app.cache.get(&ck) {
        return Ok(e);
    }
    let body = if let Some(b) = baked(app, ts).await? {
        b
    } else if let Some(src) = ts.source.clone() {
        let (name2, version) = (ts.name.clone(), ts.content_version.clone());
        tokio::task::spawn_blocking(move || {
            TerrainSource::with_heights(&src.raster.heights, &src.raster.georef, src.terrain, src.heights)
                .map(|t| serde_json::to_vec_pretty(&t.layer(&name2, "", &version)).unwrap_or_default())
        })
        .await
        .map_err(|_| Problem::internal("terrain", "making the layer failed"))?
        .map_err(|e| terrain_problem(&ts.name, &e))?
    } else {
        return Err(no_terrain(&ts.name));
    };
    let entry = Entry { etag: etag_value(&etag_of(&body)), bytes: Bytes::from(body) };
    app.cache.insert(ck, entry.clone());
    Ok(entry)
}

/// Whether `Accept-Encoding` allows gzip (`gzip` or `*`, not at q=0).
fn accepts_gzip(h: &HeaderMap) -> bool {
    h.get_all(header::ACCEPT_ENCODING).iter().filter_map(|v| v.to_str().ok()).flat_map(|v| v.split(',')).any(
        |c| {
            let mut p = c.split(';').map(str::trim);
            let coding = p.next().unwrap_or_default();
            let q0 = p.any(|x| {
                x.strip_prefix("q=").is_some_and(|q| q.trim().parse::<f64>().is_ok_and(|q| q == 0.0))
            });
            (coding.eq_ignore_ascii_case("gzip") || coding == "*") && !q0
        },
    )
}

/// `GET /tilesets/{name}/terrain/{z}/{x}/{y}.terrain`.
pub(super) async fn tile(
    State(app): State<Arc<App>>,
    path: Result<Path<TilePath>, Rejection>,
    RawQuery(query): RawQuery,
    method: Method,
    conditional: Conditional,
    headers: HeaderMap,
) -> Result<Response, Problem> {
    let Path((name, z, x, file)) = path.map_err(|e| Problem::bad_request(e.body_text()))?;
    let ts = tileset(&app, &name)?;
    let y = file
        .strip_suffix(".terrain")
        .ok_or_else(|| Problem::bad_request(format!("terrain tile {file:?} must be named Y.terrain")))?;
    let (z, x, y) = (parse_num(&z, "zoom")?, parse_num(&x, "x")?, parse_num(y, "y")?);
    let id = u8::try_from(z)
        .ok()
        .and_then(|z| TileId::new(z, x, y).ok())
        .ok_or_else(|| Problem::not_found(format!("{z}/{x}/{y} is not a tile of the geodetic grid")))?;
    let accept = headers.get(header::ACCEPT).and_then(|v| v.to_str().ok());
    let (ext, acceptable) = Extensions::from_accept(accept);
    if !acceptable {
        return Err(Problem::new(
            StatusCode::NOT_ACCEPTABLE,
            "not-acceptable",
            format!(
                "terrain tiles are {QM_TYPE} (with extensions=octvertexnormals-watermask-metadata); Accept names none of it"
            ),
        ));
    }
    let gz = accepts_gzip(&headers);
    let variant = QM
        + u16::from(ext.normals)
        + 2 * u16::from(ext.watermask)
        + 4 * u16::from(ext.metadata)
        + 8 * u16::from(gz);
    let key = TileKey::new(id.z, id.x, id.y);
    let cache = versioned_cache(&ts, query.as_deref());
    let ck = (ts.generation, key, variant);
    let entry = if let Some(e) = app.cache.get(&ck) {
        e
    } else {
        let full = full_tile(&app, &ts, id).await?;
        let body = filter_extensions(&full, ext).map_err(|e| {
            tracing::error!(tileset = %ts.name, tile = %id, error = %e, "a terrain tile does not decode");
            app.metrics.corrupt_blobs.fetch_add(1, Ordering::Relaxed);
            Problem::internal("corrupt-blob", format!("terrain tile {id} of {:?} does not decode", ts.name))
        })?;
        let body = if gz { crate::formats::qmesh::codec::gzip(&body) } else { body };
        let e = Entry { etag: etag_value(&etag_of(&body)), bytes: Bytes::from(body) };
        app.cache.insert(ck, e.clone());
        e
    };
    let mut r = send(&method, &conditional, &entry, QM_TYPE, cache);
    let h = r.headers_mut();
    h.insert(header::VARY, HeaderValue::from_static("accept, accept-encoding"));
    if gz {
        h.insert(header::CONTENT_ENCODING, HeaderValue::from_static("gzip"));
    }
    if h.contains_key(header::CONTENT_TYPE) {
        let names: Vec<&str> =
            [(ext.normals, "octvertexnormals"), (ext.watermask, "watermask"), (ext.metadata, "metadata")]
                .into_iter()
                .filter_map(|(on, n)| on.then_some(n))
                .collect();
        if !names.is_empty()
            && let Ok(v) = HeaderValue::from_str(&format!("{QM_TYPE};extensions={}", names.join("-")))
        {
            h.insert(header::CONTENT_TYPE, v);
        }
    }
    Ok(r)
}

/// The tile with every extension: from the cache, the store (baked terrain), or built.
async fn full_tile(app: &Arc<App>, ts: &Arc<Tileset>, id: TileId) -> Result<Bytes, Problem> {
    let ck = (ts.generation, TileKey::new(id.z, id.x, id.y), QM_FULL);
    if let Some(e) = app.cache.get(&ck) {
        return Ok(e.bytes);
    }
    let bytes = if has_baked(app, ts).await? {
        let store = ts.store.clone();
        let rel = tile_rel(id);
        let got = tokio::task::spawn_blocking(move || store.read_file_within(&rel, 88..=MAX_STORED_BYTES))
            .await
            .map_err(|_| Problem::internal("terrain", "reading the tile failed"))?;
        match got {
            Ok(Some(b)) => Bytes::from(b),
            Ok(None) => {
                return Err(Problem::not_found(format!("tileset {:?} has no terrain tile {id}", ts.name)));
            }
            // A tile of the wrong size is damage; a failed read may pass (503).
            Err(e @ crate::store::StoreError::Invalid { .. }) => {
                tracing::error!(tileset = %ts.name, tile = %id, error = %e, "cannot read a terrain tile");
                app.metrics.corrupt_blobs.fetch_add(1, Ordering::Relaxed);
                return Err(Problem::internal(
                    "corrupt-blob",
                    format!("terrain tile {id} of {:?} cannot be read", ts.name),
                ));
            }
            Err(e) => {
                return Err(stored_file_problem(app, ts, &tile_rel(id), &format!("terrain tile {id}"), &e));
            }
        }
    } else if ts.source.is_some() {
        build_once(app, ts, id).await?
    } else {
        return Err(no_terrain(&ts.name));
    };
    app.cache.insert(ck, Entry { etag: etag_value(&etag_of(&bytes)), bytes: bytes.clone() });
    Ok(bytes)
}

/// Counts a build out of `waiting` when it ends, however it ends (a cancelled request too).
struct Leave<'a>(&'a AtomicUsize);

impl Drop for Leave<'_> {
    fn drop(&mut self) {
        self.0.fetch_sub(1, Ordering::AcqRel);
    }
}

/// Builds an on-demand tile once however many ask at the same time.
async fn build_once(app: &Arc<App>, ts: &Arc<Tileset>, id: TileId) -> Result<Bytes, Problem> {
    let key = (ts.generation, id);
    let flight = {
        let mut f = app
            .terrain
            .flights
            .lock()
            .map_err(|_| Problem::internal("terrain", "the build pool is unavailable"))?;
        f.entry(key).or_default().clone()
    };
    let result = flight
        .get_or_init(|| async {
            let b = &app.terrain;
            if b.waiting.fetch_add(1, Ordering::AcqRel) >= b.limit {
                b.waiting.fetch_sub(1, Ordering::AcqRel);
                app.metrics.shed.fetch_add(1, Ordering::Relaxed);
                return Err(Problem::unavailable(
                    "bake-queue-full",
                    format!(
                        "terrain tile {id} of {:?} is not built yet and the build queue is full; retry later",
                        ts.name
                    ),
                    super::bakery::QUEUE_FULL_RETRY_AFTER_S,
                ));
            }
            let _left = Leave(&b.waiting);
            let permit = b.permits.acquire().await;
            let _permit = permit
                .map_err(|_| Problem::unavailable("shutting-down", "the server is shutting down", 5))?;
            let Some(src) = ts.source.clone() else { return Err(no_terrain(&ts.name)) };
            let name = ts.name.clone();
            let built = tokio::task::spawn_blocking(move || {
                let t = TerrainSource::with_heights(
                    &src.raster.heights,
                    &src.raster.georef,
                    src.terrain,
                    src.heights,
                )?;
                if !t.coverage.has(id) {
                    return Ok(None);
                }
                t.tile(id).map(|t| Some(t.bytes))
            })
            .await
            .map_err(|_| Problem::internal("terrain", format!("building terrain tile {id} failed")))?;
            match built {
                Ok(Some(b)) => Ok(Bytes::from(b)),
                Ok(None) => Err(Problem::not_found(format!(
                    "tileset {name:?} has no terrain tile {id}: outside its data (see layer.json's available)"
                ))),
                Err(e) => Err(terrain_problem(&name, &e)),
            }
        })
        .await
        .clone();
    if let Ok(mut f) = app.terrain.flights.lock() {
        f.remove(&key);
    }
    result
}

// ---- The same terrain as 3D Tiles (`Cesium3DTilesTerrainProvider`) -------------------------
//
// `…/terrain/3dtiles/tileset.json`, `…/3dtiles/subtrees/{root}/{level}/{x}/{y}.subtree` and
// `…/3dtiles/tiles/{root}/{level}/{x}/{y}.glb` (implicit coordinates of the two hemispheres'
// quadtrees, see `formats::qmesh::tiles3d`): each made from the quantized-mesh tiles above —
// stored, or built on demand through the same single flight — so both forms are one surface.

type ImplicitPath = (String, String, String, String, String);

/// The layer document as JSON.
async fn layer_value(app: &Arc<App>, ts: &Arc<Tileset>) -> Result<serde_json::Value, Problem> {
    let e = layer_entry(app, ts).await?;
    serde_json::from_slice(&e.bytes).map_err(|e| {
        tracing::error!(tileset = %ts.name, error = %e, "the terrain's layer.json is not JSON");
        Problem::internal(
            "corrupt-blob",
            format!("the terrain layer of tileset {:?} cannot be read", ts.name),
        )
    })
}

/// Zoom 0's error bound: the bake's (`terrain/stats.json`), or the on-demand source's.
async fn level0_error(app: &App, ts: &Arc<Tileset>) -> Result<f64, Problem> {
    if has_baked(app, ts).await? {
        let store = ts.store.clone();
        tokio::task::spawn_blocking(move || crate::bake::terrain3d::level0_error(&store))
            .await
            .map_err(|_| Problem::internal("terrain", "reading the terrain failed"))
    } else if let Some(src) = &ts.source {
        Ok(zoom_error(0, src.terrain.error_scale))
    } else {
        Err(no_terrain(&ts.name))
    }
}

fn corrupt_tile(app: &App, ts: &Tileset, id: TileId, e: &dyn std::fmt::Display) -> Problem {
    tracing::error!(tileset = %ts.name, tile = %id, error = %e, "a terrain tile cannot be made into 3D Tiles");
    app.metrics.corrupt_blobs.fetch_add(1, Ordering::Relaxed);
    Problem::internal("corrupt-blob", format!("terrain tile {id} of {:?} cannot be read: {e}", ts.name))
}

/// The grid tile of an implicit path `{root}/{level}/{x}/{file}` (`file` = `{y}{ext}`).
fn implicit_tile(root: &str, level: &str, x: &str, file: &str, ext: &str) -> Result<TileId, Problem> {
    let y = file
        .strip_suffix(ext)
        .ok_or_else(|| Problem::bad_request(format!("{file:?} must be named Y{ext}")))?;
    let (root, level, x, y) =
        (parse_num(root, "root")?, parse_num(level, "level")?, parse_num(x, "x")?, parse_num(y, "y")?);
    let implicit = u8::try_from(level).ok().map(|level| Implicit { root, level, x, y });
    implicit.and_then(|i| i.tile().ok()).ok_or_else(|| {
        Problem::not_found(format!(
            "{root}/{level}/{x}/{y} is not a tile of the two hemispheres' quadtrees (root 0 or 1, x and y below 2^level)"
        ))
    })
}

/// Sends a 3D Tiles terrain document made once per variant (`gzip` or not).
fn send_t3(
    method: &Method,
    conditional: &Conditional,
    e: &Entry,
    ty: &'static str,
    cache: &'static str,
    gz: bool,
) -> Response {
    let mut r = send(method, conditional, e, ty, cache);
    let h = r.headers_mut();
    h.insert(header::VARY, HeaderValue::from_static("accept-encoding"));
    if gz {
        h.insert(header::CONTENT_ENCODING, HeaderValue::from_static("gzip"));
    }
    r
}

/// A 3D Tiles terrain document of tile `id`: from the cache (document `doc`, its gzip variant
/// `doc + 1`), or made by `make`, gzipped when `gz`, and kept.
async fn cached_t3(
    app: &App,
    ts: &Tileset,
    id: TileId,
    doc: u16,
    gz: bool,
    make: impl Future<Output = Result<Vec<u8>, Problem>>,
) -> Result<Entry, Problem> {
    let ck = (ts.generation, TileKey::new(id.z, id.x, id.y), doc + u16::from(gz));
    if let Some(e) = app.cache.get(&ck) {
        return Ok(e);
    }
    let body = make.await?;
    let body = if gz { crate::formats::qmesh::codec::gzip(&body) } else { body };
    let e = Entry { etag: etag_value(&etag_of(&body)), bytes: Bytes::from(body) };
    app.cache.insert(ck, e.clone());
    Ok(e)
}

/// `GET /tilesets/{name}/terrain/3dtiles/tileset.json`.
pub(super) async fn tileset3d(
    State(app): State<Arc<App>>,
    path: Result<Path<String>, Rejection>,
    method: Method,
    headers: Conditional,
) -> Result<Response, Problem> {
    let Path(name) = path.map_err(|e| Problem::bad_request(e.body_text()))?;
    let ts = tileset(&app, &name)?;
    let root = TileId { z: 0, x: 0, y: 0 };
    let entry = cached_t3(&app, &ts, root, T3_TILESET, false, async {
        let layer = layer_value(&app, &ts).await?;
        let e0 = level0_error(&app, &ts).await?;
        tiles3d::tileset_from_layer(&layer, e0).map_err(|e| {
            tracing::error!(tileset = %ts.name, error = %e, "the terrain's layer.json cannot be made a tileset");
            Problem::internal("corrupt-blob", format!("the terrain of tileset {:?}: {e}", ts.name))
        })
    })
    .await?;
    Ok(send(&method, &headers, &entry, "application/json", SHORT))
}

/// `GET /tilesets/{name}/terrain/3dtiles/tiles/{root}/{level}/{x}/{y}.glb`.
pub(super) async fn glb3d(
    State(app): State<Arc<App>>,
    path: Result<Path<ImplicitPath>, Rejection>,
    RawQuery(query): RawQuery,
    method: Method,
    conditional: Conditional,
    headers: HeaderMap,
) -> Result<Response, Problem> {
    let Path((name, root, level, x, file)) = path.map_err(|e| Problem::bad_request(e.body_text()))?;
    let ts = tileset(&app, &name)?;
    let id = implicit_tile(&root, &level, &x, &file, ".glb")?;
    let gz = accepts_gzip(&headers);
    let entry = cached_t3(&app, &ts, id, T3_GLB, gz, async {
        let full = full_tile(&app, &ts, id).await?;
        let t = decode(&full).map_err(|e| corrupt_tile(&app, &ts, id, &e))?;
        tiles3d::glb(&t, id).map_err(|e| corrupt_tile(&app, &ts, id, &e))
    })
    .await?;
    Ok(send_t3(&method, &conditional, &entry, GLB_TYPE, versioned_cache(&ts, query.as_deref()), gz))
}

/// `GET /tilesets/{name}/terrain/3dtiles/subtrees/{root}/{level}/{x}/{y}.subtree`: made from the
/// headers of the subtree's tiles (each read, or built on demand, first).
pub(super) async fn subtree3d(
    State(app): State<Arc<App>>,
    path: Result<Path<ImplicitPath>, Rejection>,
    RawQuery(query): RawQuery,
    method: Method,
    conditional: Conditional,
    headers: HeaderMap,
) -> Result<Response, Problem> {
    let Path((name, root, level, x, file)) = path.map_err(|e| Problem::bad_request(e.body_text()))?;
    let ts = tileset(&app, &name)?;
    let id = implicit_tile(&root, &level, &x, &file, ".subtree")?;
    let sub = Implicit::of(id);
    if !sub.is_subtree_root() {
        return Err(Problem::not_found(format!(
            "no subtree at level {}: subtrees start at levels that are multiples of {}",
            id.z,
            tiles3d::SUBTREE_LEVELS
        )));
    }
    let gz = accepts_gzip(&headers);
    let entry = cached_t3(&app, &ts, id, T3_SUBTREE, gz, subtree_bytes(&app, &ts, sub)).await?;
    Ok(send_t3(
        &method,
        &conditional,
        &entry,
        tiles3d::SUBTREE_TYPE,
        versioned_cache(&ts, query.as_deref()),
        gz,
    ))
}

/// The subtree file rooted at `sub`, from its tiles' headers (their tiles fetched at once).
async fn subtree_bytes(app: &Arc<App>, ts: &Arc<Tileset>, sub: Implicit) -> Result<Vec<u8>, Problem> {
    let layer = layer_value(app, ts).await?;
    let avail = Availability::from_layer(&layer).map_err(|e| {
        Problem::internal("corrupt-blob", format!("the terrain of tileset {:?}: {e}", ts.name))
    })?;
    let tiles = tiles3d::subtree_tiles(&avail, sub).map_err(|e| Problem::not_found(e.to_string()))?;
    if tiles.is_empty() {
        return Err(Problem::not_found(format!(
            "tileset {:?} has no terrain tile {}, so no subtree there (see layer.json's available)",
            ts.name,
            TileId { z: sub.level, x: (sub.root << sub.level) + sub.x, y: sub.y }
        )));
    }
    let mut set = tokio::task::JoinSet::new();
    for (k, &t) in tiles.iter().enumerate() {
        let (app, ts) = (app.clone(), ts.clone());
        set.spawn(async move { (k, full_tile(&app, &ts, t).await) });
    }
    let mut got: Vec<Option<Bytes>> = vec![None; tiles.len()];
    while let Some(done) = set.join_next().await {
        let (k, bytes) =
            done.map_err(|_| Problem::internal("terrain", "reading a subtree's tiles failed"))?;
        got[k] = Some(bytes?);
    }
    let mut heads = Vec::with_capacity(tiles.len());
    for (t, b) in tiles.iter().zip(got) {
        let b = b.ok_or_else(|| Problem::internal("terrain", "reading a subtree's tiles failed"))?;
        heads.push(decode(&b).map_err(|e| corrupt_tile(app, ts, *t, &e))?.header);
    }
    tiles3d::subtree(&avail, sub, &heads).map_err(|e| Problem::internal("terrain", e.to_string()))
}
