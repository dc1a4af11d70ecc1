//! The 3D Tiles 1.1 view of every tileset of the store, made on the fly from the stored index
//! chunks and blobs (no re-bake): `/tilesets/{name}/3dtiles/tileset.json` (the root, placed on
//! the globe), `…/3dtiles/index/{z}/{x}/{y}.json` (one external tileset per index chunk) and
//! `…/3dtiles/tiles/{z}/{x}/{y}/{level}.glb`, with the caching rules of blobs (strong ETags,
//! immutable `?v=` URLs, conditional and range requests); and the viewer page (`/viewer`).

use std::sync::Arc;

use axum::extract::{Path, RawQuery, State};
use axum::http::{HeaderValue, Method, header};
use axum::response::Response;
use bytes::Bytes;

use super::App;
use super::cache::{Entry, GLB, TILES3D_CHUNK};
use super::conditional::{Conditional, etag_value, send};
use super::loaders::{
    NO_CACHE, SHORT, chunk_entry, load_blob, parse_key, parse_level, tileset, versioned_cache,
};
use super::problem::Problem;
use super::registry::{Tileset, etag_of};
use crate::bake::export;
use crate::formats::tiles3d::{GLB_TYPE, TilesetInfo, chunk_tileset, path_cap, planned_entry, tile_glb};
use crate::store::{IndexChunk, SUBTREE_LEVELS, chunk_root};
use crate::tiling::TileKey;

/// The viewer page (`GET /viewer`): a small WebGL 2 client of the 3D Tiles routes, no
/// third-party code, no network beyond this server.
const VIEWER_HTML: &str = include_str!("viewer.html");

type Rejection = axum::extract::rejection::PathRejection;

/// The tileset's 3D Tiles view as this server gives it: URIs carry `?v=<content version>`.
async fn info(ts: &Arc<Tileset>, with_anchor: bool) -> Result<TilesetInfo, Problem> {
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
    TilesetInfo::from_manifest_json(&ts.name, &ts.manifest_json, anchor, format!("?v={}", ts.content_version))
        .map_err(|e| {
            tracing::error!(tileset = %ts.name, error = %e, "cannot read the manifest for 3D Tiles");
            Problem::internal(
                "manifest",
                format!("the manifest of tileset {:?} cannot be read: {e}", ts.name),
            )
        })
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
    method: Method,
    headers: Conditional,
) -> Result<Response, Problem> {
    let Path(name) = path.map_err(|e| Problem::bad_request(e.body_text()))?;
    let ts = tileset(&app, &name)?;
    let info = info(&ts, true).await?;
    let (c, growing) = chunk(&app, &ts, TileKey::new(0, 0, 0)).await?;
    let entry = json_entry(
        &chunk_tileset(&info, &c, true, f64::INFINITY).map_err(|e| placement_problem(&ts.name, &e))?,
    );
    Ok(send(&method, &headers, &entry, "application/json", if growing { NO_CACHE } else { SHORT }))
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
    let ck = (ts.generation, key, TILES3D_CHUNK);
    if let Some(e) = app.cache.get(&ck) {
        return Ok(send(&method, &headers, &e, "application/json", versioned_cache(&ts, query.as_deref())));
    }
    let info = info(&ts, false).await?;
    let (c, growing) = chunk(&app, &ts, key).await?;
    let (cap, above_growing) = cap_above(&app, &ts, &info, key).await?;
    let growing = growing || above_growing;
    let entry =
        json_entry(&chunk_tileset(&info, &c, false, cap).map_err(|e| placement_problem(&ts.name, &e))?);
    if growing {
        return Ok(send(&method, &headers, &entry, "application/json", NO_CACHE));
    }
    app.cache.insert(ck, entry.clone());
    Ok(send(&method, &headers, &entry, "application/json", versioned_cache(&ts, query.as_deref())))
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
) -> Result<Response, Problem> {
    let Path((name, z, x, y, file)) = path.map_err(|e| Problem::bad_request(e.body_text()))?;
    let ts = tileset(&app, &name)?;
    let key = parse_key(&ts, &z, &x, &y)?;
    let level = file
        .strip_suffix(".glb")
        .ok_or_else(|| Problem::bad_request(format!("tile {file:?} must be named LEVEL.glb")))?;
    let level = parse_level(&ts, level)?;
    let ck = (ts.generation, key, GLB + u16::from(level));
    let cache = versioned_cache(&ts, query.as_deref());
    if let Some(e) = app.cache.get(&ck) {
        return Ok(send(&method, &headers, &e, GLB_TYPE, cache));
    }
    let blob = load_blob(&app, &ts, key, level).await?;
    let info = info(&ts, false).await?;
    let glb = tokio::task::spawn_blocking(move || {
        crate::codec::decode(&blob.bytes).map(|b| tile_glb(&info, &b))
    })
    .await
    .map_err(|_| Problem::internal("glb", format!("making the GLB of tile {key} level {level} failed")))?
    .map_err(|e| {
        tracing::error!(tileset = %ts.name, tile = %key, level, error = %e, "a verified blob does not decode");
        Problem::internal("corrupt-blob", format!("tile {key} level {level} does not decode"))
    })?
    .map_err(|e| placement_problem(&ts.name, &e))?;
    let entry = Entry { etag: etag_value(&etag_of(&glb)), bytes: Bytes::from(glb) };
    app.cache.insert(ck, entry.clone());
    Ok(send(&method, &headers, &entry, GLB_TYPE, cache))
}

/// A tileset that cannot be placed on the Earth (its geoid grid unreadable, a point outside
/// its CRS's domain): a server-side fault, logged and named.
fn placement_problem(name: &str, e: &crate::formats::tiles3d::Tiles3dError) -> Problem {
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
