//! What the native and the 3D Tiles handlers share: the tileset and key of a path, the
//! `Cache-Control` of a response, and the loaders of verified index chunks and blobs (from
//! memory, from the store, or baked on demand).

use std::sync::Arc;
use std::sync::atomic::Ordering;

use bytes::Bytes;

use super::App;
use super::cache::Entry;
use super::conditional::etag_value;
use super::problem::Problem;
use super::registry::Tileset;
use super::valid_name;
use crate::codec;
use crate::store::SUBTREE_LEVELS;
use crate::tiling::TileKey;

/// `Cache-Control` of URLs carrying the current content version (`?v=`): they can never change.
pub const IMMUTABLE: &str = "public, max-age=31536000, immutable";
/// `Cache-Control` of blobs and index chunks without (or with a stale) content version.
pub const REVALIDATE: &str = "public, max-age=60, must-revalidate";
/// `Cache-Control` of manifests and the tileset list: short, then revalidate by ETag.
pub const SHORT: &str = "public, max-age=10, must-revalidate";
/// `Cache-Control` of documents that change as tiles bake (on-demand index chunks).
pub const NO_CACHE: &str = "no-cache";

/// The tileset named in a path, or 400 (invalid name) / 404 (unknown).
pub(super) fn tileset(app: &App, name: &str) -> Result<Arc<Tileset>, Problem> {
    if !valid_name(name) {
        return Err(Problem::bad_request(format!(
            "tileset name {name:?} is invalid: names are 1 to 64 of a-z, 0-9, _ and -"
        )));
    }
    app.registry.get(name).ok_or_else(|| Problem::not_found(format!("no tileset named {name:?}")))
}

/// A decimal path component: digits only (no sign, no spaces), at most `u32`.
pub(super) fn parse_num(s: &str, what: &str) -> Result<u32, Problem> {
    if s.is_empty() || s.len() > 10 || !s.bytes().all(|b| b.is_ascii_digit()) {
        return Err(Problem::bad_request(format!("{what} {s:?} is not a non-negative integer")));
    }
    s.parse().map_err(|_| Problem::bad_request(format!("{what} {s:?} is too large")))
}

/// Checks a key against the tileset's quadtree: `400` when it cannot exist at all.
pub(super) fn parse_key(ts: &Tileset, z: &str, x: &str, y: &str) -> Result<TileKey, Problem> {
    // Well-formed keys outside the tileset name no resource: 404, not 400 (RFC 9110 §15.5.5).
    let zn = parse_num(z, "z")?;
    let (xn, yn) = (parse_num(x, "x")?, parse_num(y, "y")?);
    if zn > u32::from(ts.depth) {
        return Err(Problem::not_found(format!(
            "no tile at z {zn}: tileset {:?} has z 0 to {}",
            ts.name, ts.depth
        )));
    }
    // x and y are u32, so every one fits from z 32 on (and a manifest's depth may be anything
    // up to 255: no shift may overflow).
    let side = 1u64.checked_shl(zn).unwrap_or(u64::MAX);
    if u64::from(xn) >= side || u64::from(yn) >= side {
        return Err(Problem::not_found(format!(
            "no tile x {xn} / y {yn} at z {zn}: x and y run 0 to {}",
            side - 1
        )));
    }
    let Ok(z8) = u8::try_from(zn) else {
        return Err(Problem::not_found(format!("no tile at z {zn}")));
    };
    Ok(TileKey::new(z8, xn, yn))
}

/// `Cache-Control` of a content-addressed document: immutable only when the request names the
/// tileset's current content version.
pub(super) fn versioned_cache(ts: &Tileset, query: Option<&str>) -> &'static str {
    versioned_cache_with(ts, query, "")
}

/// [`versioned_cache`] for a view whose URIs carry `suffix` after the content version (the 3D
/// Tiles view's GLB revision, [`crate::formats::tiles3d::GLB_REVISION`]).
pub(super) fn versioned_cache_with(ts: &Tileset, query: Option<&str>, suffix: &str) -> &'static str {
    let v = query.into_iter().flat_map(|q| q.split('&')).find_map(|kv| kv.strip_prefix("v="));
    match v.and_then(|v| v.strip_prefix(ts.content_version.as_str())) {
        Some(rest) if rest == suffix => IMMUTABLE,
        _ => REVALIDATE,
    }
}

/// A level path component (`N` or `N.tsb`) checked against the tileset's levels.
pub(super) fn parse_level(ts: &Tileset, level: &str) -> Result<u8, Problem> {
    let level_s = level.strip_suffix(".tsb").unwrap_or(level);
    let level = parse_num(level_s, "level")?;
    if level >= u32::from(ts.level_count) {
        return Err(Problem::not_found(format!(
            "no level {level}: tileset {:?} has levels 0 to {}",
            ts.name,
            ts.level_count.saturating_sub(1)
        )));
    }
    Ok(level as u8)
}

/// The index chunk rooted at `key` (checked to be a chunk root of the tileset) and whether it
/// still grows: an on-demand tileset not fully baked lists the nodes baked so far, rebuilt
/// from their blobs.
pub(super) async fn chunk_entry(
    app: &App,
    ts: &Arc<Tileset>,
    key: TileKey,
) -> Result<(Entry, bool), Problem> {
    let name = &ts.name;
    let baking =
        ts.source.is_some() && !tokio::fs::try_exists(ts.store.manifest_path()).await.unwrap_or(false);
    if let Some(src) = ts.source.clone().filter(|_| baking) {
        // On-demand and not fully baked: the nodes baked so far, rebuilt from their blobs.
        if !src.pyramid.contains(key) {
            return Err(Problem::not_found(format!("tile {key} lies outside the data of {name:?}")));
        }
        let ts2 = ts.clone();
        let chunk = tokio::task::spawn_blocking(move || {
            let mut nodes = Vec::new();
            let mut frontier = vec![key];
            for _ in 0..SUBTREE_LEVELS {
                let mut next = Vec::new();
                for k in frontier {
                    if let Some(n) = crate::bake::node_from_blobs(&ts2.store, k, src.opts.levels)? {
                        nodes.push(n);
                    }
                    next.extend(src.pyramid.children(k));
                }
                frontier = next;
            }
            Ok::<_, crate::store::StoreError>(crate::store::IndexChunk { root: key, nodes })
        })
        .await
        .map_err(|_| Problem::internal("index", "building the index chunk failed"))?
        .map_err(|e| Problem::internal("index", format!("reading the blobs baked so far: {e}")))?;
        let body = serde_json::to_vec_pretty(&chunk).unwrap_or_default();
        let etag = etag_value(&super::registry::etag_of(&body));
        return Ok((Entry { bytes: Bytes::from(body), etag }, true));
    }
    let ck = (ts.generation, key, super::cache::INDEX_CHUNK);
    let entry = if let Some(e) = app.cache.get(&ck) {
        e
    } else {
        let rel = crate::store::chunk_rel(key);
        let bytes = match ts.store.get_async(&rel).await {
            Ok(Some(b)) => b,
            Ok(None) => {
                return Err(Problem::not_found(format!("no index chunk {key} in tileset {name:?}")));
            }
            Err(e) => return Err(stored_file_problem(app, ts, &rel, &format!("index chunk {key}"), &e)),
        };
        // A folder keeps no checksum of its chunks: a chunk that is not the chunk rooted at
        // `key` (truncated, edited, another chunk's) is damage, answered as an archive's CRC
        // mismatch is, never sent.
        match serde_json::from_slice::<crate::store::IndexChunk>(&bytes) {
            Ok(c) if c.root == key => {}
            other => {
                let why = other.map_or_else(|e| e.to_string(), |c| format!("its root is {}", c.root));
                app.metrics.corrupt_blobs.fetch_add(1, Ordering::Relaxed);
                tracing::error!(
                    tileset = %name, path = %ts.store.describe(&rel), error = %why,
                    "corrupt index chunk detected; not sent"
                );
                return Err(Problem::internal(
                    "corrupt-blob",
                    format!("the stored index chunk {key} failed verification and was not sent"),
                ));
            }
        }
        let e = Entry { etag: etag_value(&super::registry::etag_of(&bytes)), bytes };
        app.cache.insert(ck, e.clone());
        e
    };
    Ok((entry, false))
}

/// Seconds a client is asked to wait when the store cannot be read.
pub const STORE_IO_RETRY_AFTER_S: u32 = 5;

/// The answer when reading the store fails other than by a missing file (permissions, a
/// directory replaced by a file, a failing disk or mount): `503` + `Retry-After`, not `404` —
/// the resource may well exist, the server cannot tell — and not cached (`no-store`), so a CDN
/// does not keep the failure once the store is readable again.
fn store_unavailable(detail: String) -> Problem {
    Problem::unavailable("store-io", detail, STORE_IO_RETRY_AFTER_S)
}

/// The answer when reading the stored file `what` (named for the client, without paths) of
/// tileset `ts` failed with `e`: damage found in the stored bytes (an archive's checksum or
/// directory, a file over its kind's limit, a FIFO or device where a file should be) is `500`
/// (`corrupt-blob`), logged at `error` as corruption naming the file and counted in
/// `terrastream_corrupt_blobs_total`, the same as a blob failing verification in a folder; only
/// a failed read (I/O, a remote request) is `503` + `Retry-After` (`store-io`).
pub(super) fn stored_file_problem(
    app: &App,
    ts: &Tileset,
    rel: &str,
    what: &str,
    e: &crate::store::StoreError,
) -> Problem {
    let path = ts.store.describe(rel);
    if e.is_damaged() {
        app.metrics.corrupt_blobs.fetch_add(1, Ordering::Relaxed);
        tracing::error!(tileset = %ts.name, path = %path, error = %e, "corrupt stored file detected; not sent");
        Problem::internal("corrupt-blob", format!("the stored {what} failed verification and was not sent"))
    } else {
        tracing::error!(tileset = %ts.name, path = %path, error = %e, "cannot read the store");
        store_unavailable(format!("the {what} could not be read from the store"))
    }
}

/// What reading a blob from disk found.
enum Read {
    Ok(Entry),
    Missing,
    Corrupt(String),
}

fn verify(bytes: Bytes, key: TileKey, level: u8) -> Read {
    let h = match codec::decode_header(&bytes) {
        Ok(h) => h,
        Err(e) => return Read::Corrupt(e.to_string()),
    };
    if h.key != key || h.level != level {
        return Read::Corrupt(format!("header names tile {} level {}", h.key, h.level));
    }
    if bytes.len() != h.blob_len() {
        return Read::Corrupt(format!("{} bytes, header says {}", bytes.len(), h.blob_len()));
    }
    let computed = crc32fast::hash(&bytes[codec::PREFIX_LEN..]);
    if computed != h.checksum {
        return Read::Corrupt(format!("payload checksum {computed:08x}, header says {:08x}", h.checksum));
    }
    // Content-derived: the payload's CRC and the header's CRC (which covers the payload CRC,
    // its length, the key and level), 64 bits in all.
    let etag = etag_value(&format!("\"{:08x}{:08x}\"", h.checksum, h.header_checksum));
    Read::Ok(Entry { bytes, etag })
}

async fn read_verified(store: &crate::store::Store, key: TileKey, level: u8) -> Result<Read, Problem> {
    let rel = crate::store::blob_rel(key, level);
    match store.get_async(&rel).await {
        Ok(Some(b)) => Ok(verify(b, key, level)),
        Ok(None) => Ok(Read::Missing),
        // Damage found by the store (an archive's checksum or directory, a file over the blob
        // limit, a FIFO): the same failed verification as a bad blob in a folder.
        Err(e) if e.is_damaged() => Ok(Read::Corrupt(e.to_string())),
        Err(e) => {
            tracing::error!(path = %store.describe(&rel), error = %e, "cannot read blob");
            Err(store_unavailable(format!("tile {key} level {level} could not be read from the store")))
        }
    }
}

/// A verified blob: from memory, from disk, or baked on demand. A blob failing verification is
/// never sent: it is logged and answered `500` (the stored data is bad — the server's fault,
/// not the client's, and retrying will not help until it is re-baked); for an on-demand
/// tileset it is moved aside and baked again.
pub(super) async fn load_blob(
    app: &App,
    ts: &Arc<Tileset>,
    key: TileKey,
    level: u8,
) -> Result<Entry, Problem> {
    let ck = (ts.generation, key, u16::from(level));
    if let Some(e) = app.cache.get(&ck) {
        app.metrics.cache_hits.fetch_add(1, Ordering::Relaxed);
        return Ok(e);
    }
    app.metrics.cache_misses.fetch_add(1, Ordering::Relaxed);
    let path = ts.store.blob_path(key, level);
    let mut baked = false;
    loop {
        match read_verified(&ts.store, key, level).await? {
            Read::Ok(e) => {
                app.cache.insert(ck, e.clone());
                return Ok(e);
            }
            Read::Corrupt(why) => {
                app.metrics.corrupt_blobs.fetch_add(1, Ordering::Relaxed);
                tracing::error!(
                    tileset = %ts.name, tile = %key, level, path = %path.display(), error = %why,
                    "corrupt blob detected; not sent"
                );
                if ts.source.is_none() || baked {
                    return Err(Problem::internal(
                        "corrupt-blob",
                        format!(
                            "the stored blob of tile {key} level {level} failed verification and was not sent"
                        ),
                    ));
                }
                let aside = path.with_extension("tsb.corrupt");
                if let Err(e) = tokio::fs::rename(&path, &aside).await {
                    tracing::error!(error = %e, "cannot move the corrupt blob aside");
                    return Err(Problem::internal(
                        "corrupt-blob",
                        format!("tile {key} level {level} is corrupt"),
                    ));
                }
            }
            Read::Missing => {
                let marker = crate::store::unpaid_rel(key, level);
                let unpaid = ts.store.exists_async(&marker).await.map_err(|e| {
                    stored_file_problem(app, ts, &marker, &format!("tile {key} level {level}"), &e)
                })?;
                if unpaid {
                    return Err(Problem::not_found(format!(
                        "tile {key} has no level {level} in tileset {:?}: that level is not stored (not \
                         cheaper than a finer level of the tile, or too coarse for any screen-space selector \
                         to choose below its parent); its index entry lists the levels it has and why the \
                         others are left out",
                        ts.name
                    )));
                }
                let Some(src) = &ts.source else {
                    return Err(Problem::not_found(format!(
                        "no tile {key} level {level} in tileset {:?}",
                        ts.name
                    )));
                };
                if !src.pyramid.contains(key) {
                    return Err(Problem::not_found(format!(
                        "tile {key} lies outside the data of {:?}",
                        ts.name
                    )));
                }
                if baked {
                    return Err(Problem::internal(
                        "bake",
                        format!("tile {key} was baked but level {level} is missing"),
                    ));
                }
            }
        }
        let mut rx = app.bakery.request(ts, key, &path)?;
        let outcome = rx
            .wait_for(Option::is_some)
            .await
            .map_err(|_| Problem::internal("bake", format!("the bake of tile {key} was abandoned")))?
            .clone();
        if let Some(Err(e)) = outcome {
            return Err(Problem::internal("bake", format!("baking tile {key} failed: {e}")));
        }
        baked = true;
    }
}
