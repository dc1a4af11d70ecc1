//! The export driver: reads a tileset (directory, bucket or archive) and writes the files of
//! an output format of [`crate::formats`]: one (tile, level) as PLY or OBJ ([`export_tile`]),
//! or the whole tileset as static 3D Tiles ([`export_3dtiles`]); and the tileset's placement
//! record ([`PLACEMENT_FILE`]), which the server's 3D Tiles view reads too. Orchestration like
//! the bakes beside it: the formats make bytes, this module does the I/O (atomic files, a
//! staging folder renamed into place).

use std::io;

use crate::codec::Blob;
use crate::formats::interchange::{self, Format};
use crate::formats::tiles3d::border::FanCache;
use crate::formats::tiles3d::{
    Anchor, AnchorRangeError, BorderFans, GlbCompression, Tiles3dError, TilesetInfo, around, chunk_tileset,
    path_cap, takes_neighbours, tile_fans, tile_glb,
};

/// Memory an export's memo of border fans may hold (about 80 bytes a border vertex).
const FAN_MEMO_BYTES: usize = 256 << 20;

/// Errors of the export driver.
#[derive(Debug, thiserror::Error)]
pub enum ExportError {
    #[error(transparent)]
    Store(#[from] crate::store::StoreError),
    #[error("{path}: {source}")]
    Codec { path: std::path::PathBuf, source: crate::codec::CodecError },
    #[error("{path}: {source}")]
    Io { path: std::path::PathBuf, source: io::Error },
    /// The output file of a single-tile export exists and overwriting was not asked for.
    #[error("{path}: exists; choose another --out or pass --force to overwrite it")]
    Exists { path: std::path::PathBuf },
    /// The placement record holds an anchor out of range.
    #[error("{path}: anchor: {source}")]
    Anchor { path: std::path::PathBuf, source: AnchorRangeError },
    /// The manifest cannot be read as the 3D Tiles view needs it.
    #[error("{path}: {source}")]
    Tiles3d { path: std::path::PathBuf, source: Tiles3dError },
}

/// Decodes one (tile, level) of a tileset and writes it to `out` (atomically) in `format`. An
/// existing `out` is refused unless `overwrite`. Returns the number of vertices or points
/// written.
pub fn export_tile(
    store: &crate::store::Store,
    key: crate::tiling::TileKey,
    level: u8,
    format: Format,
    out: &std::path::Path,
    overwrite: bool,
) -> Result<usize, ExportError> {
    use crate::codec::{Geometry, decode};
    let path = store.blob_path(key, level);
    let Some(bytes) = store.read_blob(key, level)? else {
        return Err(if let Some(why) = store.unpaid_reason(key, level)? {
            crate::store::StoreError::LevelNotStored {
                path: store.dir().to_owned(),
                key,
                level,
                why: why.describe(),
            }
        } else {
            crate::store::StoreError::NoSuchTile { path: store.dir().to_owned(), key, level }
        }
        .into());
    };
    let blob = decode(&bytes).map_err(|source| ExportError::Codec { path: path.clone(), source })?;
    let (buf, count) = match &blob.geometry {
        Geometry::Mesh(m) => (interchange::mesh_bytes(m, format), m.positions.len()),
        Geometry::Points(p) => (interchange::points_bytes(p, format), p.positions.len()),
    };
    // Checked once the tile is known to exist, so a wrong tile is reported as such.
    // `symlink_metadata`: a dangling link or a special file is there too.
    if !overwrite && std::fs::symlink_metadata(out).is_ok() {
        return Err(ExportError::Exists { path: out.to_owned() });
    }
    crate::store::write_atomic(out, &buf)?;
    Ok(count)
}

/// The file beside a tileset's manifest that places it on the globe (`--anchor` of `bake` and
/// `bake-model`): `{"anchor": {"lon": …, "lat": …, "height": …}}`. Not part of the baked content
/// (no blob depends on it), so it can be set or changed without a re-bake.
pub const PLACEMENT_FILE: &str = "placement.json";

#[derive(serde::Serialize, serde::Deserialize)]
struct PlacementRecord {
    anchor: Anchor,
}

/// Records the tileset's anchor ([`PLACEMENT_FILE`]), atomically.
pub fn write_anchor(store: &crate::store::Store, anchor: Anchor) -> Result<(), crate::store::StoreError> {
    let path = store.dir().join(PLACEMENT_FILE);
    let mut bytes = serde_json::to_vec_pretty(&PlacementRecord { anchor })
        .map_err(|source| crate::store::StoreError::Json { path: path.clone(), source })?;
    bytes.push(b'\n');
    store.write_file(PLACEMENT_FILE, &bytes)
}

/// The tileset's recorded anchor; `Ok(None)` when it has none. A record that cannot be read or
/// holds an anchor out of range is an error naming the file.
pub fn read_anchor(store: &crate::store::Store) -> Result<Option<Anchor>, ExportError> {
    let path = store.dir().join(PLACEMENT_FILE);
    let Some(bytes) = store.read_file(PLACEMENT_FILE)? else { return Ok(None) };
    let r: PlacementRecord = serde_json::from_slice(&bytes)
        .map_err(|source| crate::store::StoreError::Json { path: path.clone(), source })?;
    r.anchor.check().map_err(|source| ExportError::Anchor { path, source })?;
    Ok(Some(r.anchor))
}

/// The 3D Tiles view of a tileset directory: its manifest, kind and placement, as the server
/// and `export --format 3dtiles` build it.
pub fn tiles3d_info(
    store: &crate::store::Store,
    name: &str,
    anchor: Option<Anchor>,
    query: String,
) -> Result<TilesetInfo, ExportError> {
    // Checks the format and version; the kind and a model's levels come from the raw JSON.
    store.manifest()?;
    let path = store.manifest_path();
    let bytes = store.read_file(crate::store::MANIFEST_FILE)?.ok_or_else(|| {
        crate::store::StoreError::Invalid { path: path.clone(), message: "no manifest".into() }
    })?;
    let anchor = match anchor {
        Some(a) => Some(a),
        None => read_anchor(store)?,
    };
    TilesetInfo::from_manifest_json(name, &bytes, anchor, query)
        .map_err(|source| ExportError::Tiles3d { path, source })
}

/// What `export --format 3dtiles` wrote.
#[derive(Debug, Clone, Copy, Default)]
pub struct Tiles3dExport {
    /// Tileset JSON files (the root and one per index chunk below it).
    pub documents: u64,
    pub glbs: u64,
    pub glb_bytes: u64,
    /// The blobs the GLBs were made from.
    pub blob_bytes: u64,
}

/// Writes a complete tileset as static 3D Tiles 1.1 into `out` (`tileset.json`,
/// `index/{z}/{x}/{y}.json`, `tiles/{z}/{x}/{y}/{level}.glb`), the same documents the server
/// gives at `/tilesets/{name}/3dtiles/` without the `?v=` queries. Everything is written into a
/// staging directory beside `out` and renamed into place when complete, so `out` is never
/// half-written; `out` must not exist or be empty. Every blob is verified first.
/// `progress(done, total)` counts GLBs.
pub fn export_3dtiles(
    store: &crate::store::Store,
    out: &std::path::Path,
    anchor: Option<Anchor>,
    progress: &(dyn Fn(u64, u64) + Sync),
) -> Result<Tiles3dExport, ExportError> {
    export_3dtiles_with(store, out, anchor, GlbCompression::None, progress)
}

/// [`export_3dtiles`] with the GLBs compressed as `glb` says (`EXT_meshopt_compression` for
/// [`GlbCompression::Meshopt`]: the bytes the server gives at `…/tileset.json?glb=meshopt`).
pub fn export_3dtiles_with(
    store: &crate::store::Store,
    out: &std::path::Path,
    anchor: Option<Anchor>,
    glb: GlbCompression,
    progress: &(dyn Fn(u64, u64) + Sync),
) -> Result<Tiles3dExport, ExportError> {
    use rayon::prelude::*;
    use std::sync::atomic::{AtomicU64, Ordering};

    use crate::store::{StoreError, TilesetKind, chunk_root};

    let io_err = |path: &std::path::Path| {
        let path = path.to_owned();
        move |source| ExportError::Io { path, source }
    };
    if !store.has_manifest()? {
        return Err(StoreError::Invalid {
            path: store.dir().to_owned(),
            message: "no tileset.json: not a complete tileset (finish or resume its bake first)".into(),
        }
        .into());
    }
    check_out_free(out)?;
    let name = store.name().unwrap_or_else(|| "tileset".to_owned());
    let mut info = tiles3d_info(store, &name, anchor, String::new())?;
    info.glb = glb;
    // The chunks, from the root down (each read once; bounded by the pyramid).
    let mut chunks = Vec::new();
    let mut roots = vec![crate::tiling::TileKey::new(0, 0, 0)];
    while let Some(root) = roots.pop() {
        let chunk = store.chunk(root)?;
        if info.kind == TilesetKind::Terrain
            && let Some(p) = info.pyramid
        {
            let last = root.z.saturating_add(crate::store::SUBTREE_LEVELS - 1);
            for n in &chunk.nodes {
                if n.key.z == last && chunk_root(n.key) == root {
                    roots.extend(p.children(n.key).into_iter().filter(|c| p.contains(*c)));
                }
            }
        }
        chunks.push(chunk);
    }
    let stage = stage_dir(out)?;
    let result = (|| {
        if stage.exists() {
            std::fs::remove_dir_all(&stage).map_err(io_err(&stage))?;
        }
        let mut docs = 0u64;
        let entries: std::collections::HashMap<crate::tiling::TileKey, &crate::store::NodeEntry> =
            chunks.iter().flat_map(|c| &c.nodes).map(|n| (n.key, n)).collect();
        for c in &chunks {
            let root = c.root.z == 0;
            let path = if root {
                stage.join("tileset.json")
            } else {
                stage.join(format!("index/{}/{}/{}.json", c.root.z, c.root.x, c.root.y))
            };
            let cap = if root {
                f64::INFINITY
            } else {
                let k = c.root;
                let path: Vec<crate::store::NodeEntry> = (0..k.z)
                    .filter_map(|z| {
                        let shift = k.z - z;
                        let a = crate::tiling::TileKey::new(z, k.x >> shift, k.y >> shift);
                        entries.get(&a).map(|n| (*n).clone())
                    })
                    .collect();
                path_cap(&info, &path)
            };
            let doc = chunk_tileset(&info, c, root, cap)
                .map_err(|source| ExportError::Tiles3d { path: store.dir().to_owned(), source })?;
            let mut bytes = serde_json::to_vec(&doc).unwrap_or_default();
            bytes.push(b'\n');
            write_file(&path, &bytes).map_err(io_err(&path))?;
            docs += 1;
        }
        let work: Vec<(crate::tiling::TileKey, u8)> = chunks
            .iter()
            .flat_map(|c| &c.nodes)
            .flat_map(|n| n.levels.iter().map(move |l| (n.key, l.level)))
            .collect();
        let total = work.len() as u64;
        let done = AtomicU64::new(0);
        let glb_bytes = AtomicU64::new(0);
        let blob_bytes = AtomicU64::new(0);
        let load = |key: crate::tiling::TileKey, level: u8| -> Result<(Vec<u8>, Blob), ExportError> {
            let path = store.blob_path(key, level);
            let bytes = store.read_blob(key, level)?.ok_or_else(|| StoreError::NoSuchTile {
                path: store.dir().to_owned(),
                key,
                level,
            })?;
            let blob = crate::codec::decode(&bytes)
                .map_err(|source| ExportError::Codec { path: path.clone(), source })?;
            if blob.header.key != key || blob.header.level != level {
                return Err(StoreError::Invalid {
                    path,
                    message: format!(
                        "the blob's header names tile {} level {}",
                        blob.header.key, blob.header.level
                    ),
                }
                .into());
            }
            Ok((bytes, blob))
        };
        // Neighbours' border fans (one normal per shared border vertex), each made once while
        // the bounded memo holds it: the work runs in index order, so neighbours come close.
        let present: std::collections::HashSet<(crate::tiling::TileKey, u8)> = work.iter().copied().collect();
        let fans = FanCache::new(FAN_MEMO_BYTES);
        work.par_iter().try_for_each(|&(key, level)| -> Result<(), ExportError> {
            let path = store.blob_path(key, level);
            let (bytes, blob) = load(key, level)?;
            let around_fans = if takes_neighbours(&info, &blob.header) {
                // Its own fans too (from the memo when a neighbour made them first).
                let own = fans.get_or_make((key, level), || {
                    tile_fans(&info, &blob)
                        .map_err(|source| ExportError::Tiles3d { path: path.clone(), source })
                })?;
                let mut all = vec![own];
                for k in around(&info, key).into_iter().filter(|k| present.contains(&(*k, level))) {
                    all.push(fans.get_or_make((k, level), || {
                        let (_, b) = load(k, level)?;
                        tile_fans(&info, &b).map_err(|source| ExportError::Tiles3d {
                            path: store.blob_path(k, level),
                            source,
                        })
                    })?);
                }
                all
            } else {
                Vec::new()
            };
            let neighbours: Vec<&BorderFans> =
                around_fans.iter().filter_map(|f| f.as_ref().as_ref()).collect();
            let glb = tile_glb(&info, &blob, &neighbours)
                .map_err(|source| ExportError::Tiles3d { path: path.clone(), source })?;
            let dest = stage.join(format!("tiles/{}/{}/{}/{level}.glb", key.z, key.x, key.y));
            write_file(&dest, &glb).map_err(io_err(&dest))?;
            glb_bytes.fetch_add(glb.len() as u64, Ordering::Relaxed);
            blob_bytes.fetch_add(bytes.len() as u64, Ordering::Relaxed);
            progress(done.fetch_add(1, Ordering::Relaxed) + 1, total);
            Ok(())
        })?;
        if out.exists() {
            std::fs::remove_dir(out).map_err(io_err(out))?;
        }
        std::fs::rename(&stage, out).map_err(io_err(out))?;
        Ok(Tiles3dExport {
            documents: docs,
            glbs: total,
            glb_bytes: glb_bytes.into_inner(),
            blob_bytes: blob_bytes.into_inner(),
        })
    })();
    if result.is_err() {
        let _ = std::fs::remove_dir_all(&stage);
    }
    result
}

/// Writes a file of the staging directory (its folders created); the directory as a whole is
/// what is published atomically.
fn write_file(path: &std::path::Path, bytes: &[u8]) -> io::Result<()> {
    if let Some(d) = path.parent() {
        std::fs::create_dir_all(d)?;
    }
    std::fs::write(path, bytes)
}

/// What [`export_heightmap`] wrote.
#[derive(Debug, Clone, Copy)]
pub struct HeightmapExport {
    pub tiles: u64,
    pub bytes: u64,
    pub zooms: (u8, u8),
}

/// A store's blobs as the heights samplers read them (level 0 of a node).
struct StoreBlobs<'a>(&'a crate::store::Store);

impl crate::heights::BlobSource for StoreBlobs<'_> {
    fn blob(&self, key: crate::tiling::TileKey) -> Result<Option<Vec<u8>>, String> {
        self.0.read_blob(key, 0).map_err(|e| e.to_string())
    }
}

/// Writes a placed tileset's heightmap tiles (the server's `/heightmap/` tiles: the TIN at each
/// tile's scale, heights above the EGM96 geoid) for zooms `zooms` into `out`:
/// `{z}/{x}/{y}.png` in `encoding` (or `.f32` float32 when `encoding` is `None`) and
/// `tiles.json` (TileJSON with a relative tile template). Staged beside `out` and renamed into
/// place when complete; `out` must not exist or be empty. `progress(done, total)` counts tiles.
pub fn export_heightmap(
    store: &crate::store::Store,
    out: &std::path::Path,
    zooms: Option<(u8, u8)>,
    encoding: Option<crate::formats::heightmap::Encoding>,
    progress: &(dyn Fn(u64, u64) + Sync),
) -> Result<HeightmapExport, ExportError> {
    use rayon::prelude::*;
    use std::sync::atomic::{AtomicU64, Ordering};

    use crate::formats::heightmap::{self as hm, Xyz};
    use crate::heights::{Coords, Datum, MeshCache, MeshSampler, Query};

    let io_err = |path: &std::path::Path| {
        let path = path.to_owned();
        move |source| ExportError::Io { path, source }
    };
    let invalid =
        |message: String| crate::store::StoreError::Invalid { path: store.dir().to_owned(), message };
    let m = store.manifest()?;
    let frame = m.frame.frame().map_err(|e| invalid(format!("its frame: {e}")))?.ok_or_else(|| {
        invalid(
            "the tileset is not placed on the Earth (no CRS): heightmap tiles need a georeferenced dataset"
                .into(),
        )
    })?;
    let r = crate::formats::tiles3d::earth::region(&frame, &m.bounds).map_err(|e| invalid(e.to_string()))?;
    let (west, south, east, north) =
        (r[0].to_degrees(), r[1].to_degrees(), r[2].to_degrees(), r[3].to_degrees());
    let cell_m = m.frame.dx.abs().min(m.frame.dy.abs());
    let max_zoom = hm::zoom_for_cell(cell_m, f64::midpoint(south, north));
    let (z0, z1) = zooms.unwrap_or((0, max_zoom));
    if z0 > z1 || z1 > hm::MAX_ZOOM {
        return Err(invalid(format!("zooms {z0}:{z1}: give A:B with A ≤ B ≤ {}", hm::MAX_ZOOM)).into());
    }
    let pyramid = crate::tiling::Pyramid::new(m.source.width, m.source.height, m.tile_size)
        .map_err(|e| invalid(e.to_string()))?;
    // Every tile of the zooms that meets the data (two ranges across the antimeridian).
    let mut tiles = Vec::new();
    let lon_ranges = if west <= east { vec![(west, east)] } else { vec![(west, 180.0), (-180.0, east)] };
    for z in z0..=z1 {
        for &(w, e) in &lon_ranges {
            if let Some((x0, x1, y0, y1)) = hm::tile_range(z, w, south, e, north) {
                let n = u64::from(x1 - x0 + 1) * u64::from(y1 - y0 + 1);
                if tiles.len() as u64 + n > 10_000_000 {
                    return Err(invalid(format!(
                        "zooms {z0}:{z1} make more than 10,000,000 tiles; export fewer zooms (--zooms A:B)"
                    ))
                    .into());
                }
                for y in y0..=y1 {
                    for x in x0..=x1 {
                        tiles.extend(Xyz::new(z, x, y));
                    }
                }
            }
        }
    }
    check_out_free(out)?;
    let stage = stage_dir(out)?;
    let cache = std::sync::Arc::new(MeshCache::new(512 << 20));
    let sampler = MeshSampler::with_cache(StoreBlobs(store), pyramid, &m.frame, cache, 0)
        .map_err(|e| invalid(e.to_string()))?;
    let q = Query { coords: Coords::Wgs84, datum: Datum::Geoid, ..Query::default() };
    let ext = if encoding.is_some() { "png" } else { "f32" };
    let result = (|| {
        if stage.exists() {
            std::fs::remove_dir_all(&stage).map_err(io_err(&stage))?;
        }
        let total = tiles.len() as u64;
        let (done, bytes) = (AtomicU64::new(0), AtomicU64::new(0));
        tiles.par_iter().try_for_each(|&t| -> Result<(), ExportError> {
            let depth = hm::mesh_depth(t, cell_m, m.depth);
            let hs = sampler
                .sample(&t.pixel_centres(), q, depth)
                .map_err(|e| invalid(format!("heightmap tile {}/{}/{}: {e}", t.z, t.x, t.y)))?;
            let hs: Vec<Option<f64>> =
                hs.iter().map(|h| (!h.nodata && h.h.is_finite()).then_some(h.h)).collect();
            let body = match encoding {
                Some(enc) => hm::png(&hs, enc),
                None => hm::f32_tile(&hs),
            };
            let dest = stage.join(format!("{}/{}/{}.{ext}", t.z, t.x, t.y));
            write_file(&dest, &body).map_err(io_err(&dest))?;
            bytes.fetch_add(body.len() as u64, Ordering::Relaxed);
            progress(done.fetch_add(1, Ordering::Relaxed) + 1, total);
            Ok(())
        })?;
        let tj = serde_json::json!({
            "tilejson": "3.0.0",
            "name": store.name().unwrap_or_else(|| "tileset".to_owned()),
            "scheme": "xyz",
            "tiles": [format!("{{z}}/{{x}}/{{y}}.{ext}")],
            "minzoom": z0,
            "maxzoom": z1,
            "bounds": [west, south.max(-hm::MAX_LAT), east, north.min(hm::MAX_LAT)],
            "tileSize": hm::TILE_PX,
            "encoding": encoding.map_or("float32", hm::Encoding::maplibre_name),
        });
        let path = stage.join("tiles.json");
        write_file(&path, &serde_json::to_vec_pretty(&tj).unwrap_or_default()).map_err(io_err(&path))?;
        if out.exists() {
            std::fs::remove_dir(out).map_err(io_err(out))?;
        }
        std::fs::rename(&stage, out).map_err(io_err(out))?;
        Ok(HeightmapExport { tiles: total, bytes: bytes.into_inner(), zooms: (z0, z1) })
    })();
    if result.is_err() {
        let _ = std::fs::remove_dir_all(&stage);
    }
    result
}

/// Refuses an export folder that exists and is not an empty directory.
fn check_out_free(out: &std::path::Path) -> Result<(), ExportError> {
    if out.exists() {
        let io_err = |source| ExportError::Io { path: out.to_owned(), source };
        let empty = out.is_dir() && std::fs::read_dir(out).map_err(io_err)?.next().is_none();
        if !empty {
            return Err(io_err(io::Error::new(
                io::ErrorKind::AlreadyExists,
                "exists and is not an empty directory; choose another --out",
            )));
        }
    }
    Ok(())
}

/// The staging folder beside `out` (its parent created) that an export fills and renames into
/// place when complete.
fn stage_dir(out: &std::path::Path) -> Result<std::path::PathBuf, ExportError> {
    let parent = out.parent().filter(|p| !p.as_os_str().is_empty()).unwrap_or(std::path::Path::new("."));
    std::fs::create_dir_all(parent).map_err(|source| ExportError::Io { path: parent.to_owned(), source })?;
    Ok(parent.join(format!(
        ".{}.partial-{}",
        out.file_name().map_or_else(|| "export".into(), |n| n.to_string_lossy().into_owned()),
        std::process::id()
    )))
}
