//! The tilesets being served: one per subdirectory of the store with a valid manifest, one per
//! packed archive `NAME.tsa` beside them, plus the on-demand tilesets named by `--source`. The
//! store is a local directory or a bucket prefix (`s3://BUCKET/PREFIX`, the same layout). It is
//! re-scanned by polling (every `Config::poll`): a tileset whose `tileset.json` (or archive)
//! appeared, changed (size or mtime) or vanished is loaded, reloaded or dropped. Polling rather
//! than inotify keeps it portable and works on network filesystems and buckets; the cost is one
//! `stat` per tileset per interval (in a bucket: one listing plus one HEAD per folder tileset).

use std::collections::HashMap;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, RwLock};
use std::time::SystemTime;

use bytes::Bytes;

use crate::bake::BakeOptions;
use crate::raster::LoadedRaster;
use crate::store::{Manifest, Store};
use crate::tiling::Pyramid;

use super::{ServerError, valid_name};

/// A raster that tiles of one tileset are baked from on demand.
pub struct Source {
    pub raster: LoadedRaster,
    pub opts: BakeOptions,
    pub pyramid: Pyramid,
    /// Its globe terrain's options (`/terrain/…`).
    pub terrain: crate::bake::qmesh::TerrainOptions,
    /// The raster's lowest and highest height, found once (its terrain's edge lattice).
    pub heights: Option<(f32, f32)>,
}

/// One tileset as served. Immutable: a change on disk replaces the whole value (and so starts a
/// new cache generation).
pub struct Tileset {
    pub name: String,
    pub store: Store,
    /// The manifest as served (for on-demand tilesets not fully baked: a provisional one).
    pub manifest_json: Bytes,
    pub manifest_etag: String,
    pub content_version: String,
    pub depth: u8,
    /// Levels per node (mesh + point levels).
    pub level_count: u8,
    pub summary: serde_json::Value,
    /// Distinguishes this load from earlier loads of the same name in cache keys.
    pub generation: u64,
    pub source: Option<Arc<Source>>,
    stamp: Option<(SystemTime, u64)>,
}

static GENERATION: AtomicU64 = AtomicU64::new(1);

/// The manifest's mtime and size; `Ok(None)` when it does not exist, `Err` when it cannot be
/// looked at (permissions, a path component that is not a directory, I/O).
fn stamp(path: &Path) -> std::io::Result<Option<(SystemTime, u64)>> {
    match std::fs::metadata(path) {
        Ok(md) => Ok(md.modified().ok().map(|t| (t, md.len()))),
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => Ok(None),
        Err(e) => Err(e),
    }
}

pub(super) fn etag_of(bytes: &[u8]) -> String {
    format!("\"{:08x}{:08x}\"", crc32fast::hash(bytes), bytes.len())
}

fn summary(name: &str, m: &Manifest, complete: bool) -> serde_json::Value {
    let mut s = serde_json::json!({
        "name": name,
        "complete": complete,
        "content_version": m.content_version,
        "source": m.source,
        "tile_size": m.tile_size,
        "depth": m.depth,
        "levels": m.levels.len(),
        "bounds": m.bounds,
        "totals": m.totals,
        "manifest": format!("/tilesets/{name}/tileset.json?v={}", m.content_version),
        "frame": m.frame,
    });
    s["globe"] = globe(m);
    s
}

/// Where a tileset lies on the Earth, for clients that show it (null for a local frame): the
/// centre of its data (WGS 84 longitude, latitude, ellipsoidal height), its CRS and vertical
/// datum, and its region in degrees with the ellipsoidal height range. The exact transform is
/// `frame` (see docs/frames.md).
fn globe(m: &Manifest) -> serde_json::Value {
    let Ok(Some(f)) = m.frame.frame() else { return serde_json::Value::Null };
    let c = m.bounds.center();
    let centre = f.to_geodetic([c.x, c.y, c.z]);
    let region = crate::formats::tiles3d::earth::region(&f, &m.bounds);
    match (centre, region) {
        (Ok((lon, lat, height)), Ok(r)) => serde_json::json!({
            "centre": { "lon": lon, "lat": lat, "height": height },
            "crs": f.grid.crs.definition(),
            "vertical_datum": f.vertical,
            "geoid": f.geoid.as_ref().map(|g| g.name.clone()),
            "region": [r[0].to_degrees(), r[1].to_degrees(), r[2].to_degrees(), r[3].to_degrees(), r[4], r[5]],
        }),
        _ => serde_json::Value::Null,
    }
}

/// Loads a complete (manifest present) tileset: a directory, a bucket prefix or an archive.
fn load_complete(
    name: &str,
    store: Store,
    st: Option<(SystemTime, u64)>,
    source: Option<Arc<Source>>,
) -> Result<Tileset, ServerError> {
    let manifest = store.manifest()?;
    let bytes = store.read_file(crate::store::MANIFEST_FILE)?.ok_or_else(|| {
        ServerError::Config(format!(
            "{}: vanished while loading",
            store.describe(crate::store::MANIFEST_FILE)
        ))
    })?;
    Ok(Tileset {
        name: name.to_owned(),
        manifest_etag: etag_of(&bytes),
        manifest_json: Bytes::from(bytes),
        content_version: manifest.content_version.clone(),
        depth: manifest.depth,
        level_count: u8::try_from(manifest.levels.len()).unwrap_or(u8::MAX),
        summary: summary(name, &manifest, true),
        generation: GENERATION.fetch_add(1, Ordering::Relaxed),
        source,
        store,
        stamp: st,
    })
}

/// An on-demand tileset whose bake is not complete: a provisional manifest describing what the
/// tiles will be (no totals yet). Its content version is a hash of the bake options record,
/// which names the source heights and every option: baking is deterministic, so the blobs under
/// that version can never differ.
fn load_provisional(name: &str, dir: &Path, source: Arc<Source>, options: &serde_json::Value) -> Tileset {
    let raster = &source.raster;
    let hf = &raster.heights;
    let (lo, hi) = hf.data.iter().fold((f32::MAX, f32::MIN), |(l, h), &v| (l.min(v), h.max(v)));
    let g = &raster.georef;
    let (w, h) = (f64::from(hf.width - 1), f64::from(hf.height - 1));
    let xs = [g.x0, g.x0 + w * g.dx];
    let ys = [g.y0, g.y0 + h * g.dy];
    let bounds = crate::geom::Bounds::new(
        [xs[0].min(xs[1]), ys[0].min(ys[1]), f64::from(lo)],
        [xs[0].max(xs[1]), ys[0].max(ys[1]), f64::from(hi)],
    );
    let options_text = serde_json::to_vec(options).unwrap_or_default();
    let manifest = Manifest {
        format: crate::store::MANIFEST_FORMAT.into(),
        version: crate::store::MANIFEST_VERSION,
        content_version: format!("s{:016x}", xxhash_rust::xxh3::xxh3_64(&options_text)),
        source: crate::store::SourceInfo {
            file: options["source"]["file"].as_str().unwrap_or_default().to_owned(),
            format: raster.format.clone(),
            width: hf.width,
            height: hf.height,
            nodata_filled: raster.nodata_filled,
        },
        frame: raster.georef.clone(),
        tile_size: source.opts.tile_size,
        depth: source.pyramid.depth,
        subtree_levels: crate::store::SUBTREE_LEVELS,
        bounds,
        levels: crate::bake::level_specs(&source.opts),
        totals: Vec::new(),
        options: options.clone(),
        // Filled in by the bake that completes the tileset.
        point_baker: String::new(),
    };
    let mut value = serde_json::to_value(&manifest).unwrap_or_default();
    if let Some(o) = value.as_object_mut() {
        // Not part of a baked manifest: tells clients the index lists only baked nodes so far.
        o.insert("on_demand".into(), serde_json::Value::Bool(true));
    }
    let mut bytes = serde_json::to_vec_pretty(&value).unwrap_or_default();
    bytes.push(b'\n');
    Tileset {
        name: name.to_owned(),
        store: Store::new(dir),
        manifest_etag: etag_of(&bytes),
        manifest_json: Bytes::from(bytes),
        content_version: manifest.content_version.clone(),
        depth: manifest.depth,
        level_count: u8::try_from(manifest.levels.len()).unwrap_or(u8::MAX),
        summary: summary(name, &manifest, false),
        generation: GENERATION.fetch_add(1, Ordering::Relaxed),
        source: Some(source),
        stamp: None,
    }
}

/// An on-demand tileset as configured: its source and its options record.
pub struct OnDemand {
    pub source: Arc<Source>,
    pub options: serde_json::Value,
}

/// Where a tileset of the store is, as the scan found it.
enum Found {
    Dir(PathBuf),
    Prefix(String),
    Archive(String, Option<(SystemTime, u64)>),
}

/// All tilesets, by name.
pub struct Registry {
    root: PathBuf,
    /// The bucket prefix, when the store is in object storage.
    remote: Option<crate::store::Bucket>,
    on_demand: HashMap<String, OnDemand>,
    map: RwLock<HashMap<String, Arc<Tileset>>>,
    /// Tilesets whose manifest (or archive) failed to load, with the stamp (mtime, size) it
    /// had then: a damaged one is not read again, nor logged again, until the stamp changes, so
    /// a broken file costs one `stat` per poll and one log line per change.
    failed: std::sync::Mutex<HashMap<String, Broken>>,
    /// Loaded tilesets that cannot be read now (kept listed), with the error last logged and
    /// the scan that last saw it: logged once per change of the error, not every poll.
    unreadable: std::sync::Mutex<HashMap<String, (String, u64)>>,
    scans: AtomicU64,
}

/// A tileset that failed to load, as [`Registry::load_failed`] recorded it.
#[derive(PartialEq)]
struct Broken {
    stamp: Option<(SystemTime, u64)>,
    message: String,
    transient: bool,
}

impl Registry {
    /// The registry of the store at `root` (a directory, or a bucket URL opened here).
    pub fn new(root: &Path, on_demand: HashMap<String, OnDemand>) -> Result<Self, ServerError> {
        let text = root.to_string_lossy();
        let remote =
            if crate::store::is_remote(&text) { Some(crate::store::Bucket::open(&text)?) } else { None };
        Ok(Self {
            root: root.to_owned(),
            remote,
            on_demand,
            map: RwLock::new(HashMap::new()),
            failed: std::sync::Mutex::new(HashMap::new()),
            unreadable: std::sync::Mutex::new(HashMap::new()),
            scans: AtomicU64::new(0),
        })
    }

    /// Logs that the loaded tileset `name` cannot be read now (`path`: what failed), once per
    /// change of the error.
    fn note_unreadable(&self, name: &str, path: &str, e: &dyn std::fmt::Display) {
        let scan = self.scans.load(Ordering::Relaxed);
        let message = format!("{path}: {e}");
        let Ok(mut u) = self.unreadable.lock() else { return };
        if u.get(name).is_none_or(|(m, _)| *m != message) {
            tracing::error!(
                tileset = %name, path = %path, error = %e,
                "tileset cannot be read; still listed, its reads fail (logged again when the error changes)"
            );
        }
        u.insert(name.to_owned(), (message, scan));
    }

    /// Starts a scan: tilesets not noted unreadable by it are readable again.
    fn begin_scan(&self) {
        self.scans.fetch_add(1, Ordering::Relaxed);
    }

    fn end_scan(&self) {
        let scan = self.scans.load(Ordering::Relaxed);
        if let Ok(mut u) = self.unreadable.lock() {
            u.retain(|name, (_, seen)| {
                if *seen != scan {
                    tracing::info!(tileset = %name, "tileset readable again");
                }
                *seen == scan
            });
        }
    }

    /// Whether the tileset `name` failed to load with the same stamp `st` already, for a reason
    /// in its files (damaged, too large, not a regular file, invalid): not worth reading again.
    fn known_broken(&self, name: &str, st: Option<(SystemTime, u64)>) -> bool {
        self.failed.lock().is_ok_and(|f| f.get(name).is_some_and(|b| b.stamp == st && !b.transient))
    }

    /// Records a load of `name` (stamp `st`) that failed with `e`; logged once per change of
    /// the stamp or the error. A failed read (I/O, a remote request) is tried again at the next
    /// scan; anything else waits for the files to change.
    fn load_failed(&self, name: &str, st: Option<(SystemTime, u64)>, e: &ServerError) {
        use crate::store::StoreError;
        let transient = matches!(
            e,
            ServerError::Io(_) | ServerError::Store(StoreError::Io { .. } | StoreError::Remote { .. })
        );
        let broken = Broken { stamp: st, message: e.to_string(), transient };
        let Ok(mut f) = self.failed.lock() else { return };
        if f.get(name) != Some(&broken) {
            tracing::warn!(
                tileset = %name, error = %e,
                "tileset skipped (logged again only when its files or the error change)"
            );
            f.insert(name.to_owned(), broken);
        }
    }

    /// Forgets the failures of tilesets loaded now, or no longer in the store.
    fn prune_failed(&self, present: &dyn Fn(&str) -> bool, next: &HashMap<String, Arc<Tileset>>) {
        if let Ok(mut f) = self.failed.lock() {
            f.retain(|name, _| present(name) && !next.contains_key(name));
        }
    }

    #[must_use]
    pub fn root(&self) -> &Path {
        &self.root
    }

    /// Whether the store is a bucket prefix (read-only for this server).
    #[must_use]
    pub fn is_remote(&self) -> bool {
        self.remote.is_some()
    }

    #[must_use]
    pub fn get(&self, name: &str) -> Option<Arc<Tileset>> {
        self.map.read().ok()?.get(name).cloned()
    }

    #[must_use]
    pub fn all(&self) -> Vec<Arc<Tileset>> {
        let mut v: Vec<_> = self.map.read().map(|m| m.values().cloned().collect()).unwrap_or_default();
        v.sort_by(|a, b| a.name.cmp(&b.name));
        v
    }

    #[must_use]
    pub fn is_on_demand(&self, name: &str) -> bool {
        self.on_demand.contains_key(name)
    }

    /// Forgets a tileset at once (its directory is being deleted).
    pub fn remove(&self, name: &str) {
        if let Ok(mut m) = self.map.write() {
            m.remove(name);
        }
    }

    /// Re-scans a store in a bucket: one delimited listing, then a HEAD of each folder's
    /// manifest (archives' sizes and times come with the listing). A tileset whose manifest
    /// cannot be looked at now stays loaded (its reads fail as `503`).
    // Without `s3` a `Bucket` cannot exist, so the code after `r.child` is unreachable there.
    #[cfg_attr(not(feature = "s3"), allow(unreachable_code, unused_variables))]
    fn scan_remote(&self, r: &crate::store::Bucket) -> Result<(), ServerError> {
        let (folders, objects) = r.list_top()?;
        let current: HashMap<String, Arc<Tileset>> = self.map.read().map(|m| m.clone()).unwrap_or_default();
        let mut found: Vec<(String, Found)> = Vec::new();
        for (file, size, modified_ms) in objects {
            if let Some(name) = file.strip_suffix(crate::store::ARCHIVE_SUFFIX).filter(|n| valid_name(n)) {
                let t = SystemTime::UNIX_EPOCH + std::time::Duration::from_millis(modified_ms.max(0) as u64);
                found.push((name.to_owned(), Found::Archive(file.clone(), Some((t, size)))));
            }
        }
        for name in folders.into_iter().filter(|n| valid_name(n)) {
            if !found.iter().any(|(n, _)| *n == name) {
                found.push((name.clone(), Found::Prefix(name)));
            }
        }
        let found_names = found.iter().map(|(n, _)| n.clone()).collect();
        let mut next = HashMap::with_capacity(found.len());
        for (name, f) in found {
            // Ok: an archive object's name; Err: a folder tileset's prefix.
            let (st, store): (_, Result<String, crate::store::Bucket>) = match &f {
                Found::Archive(file, st) => (*st, Ok(file.clone())),
                Found::Prefix(p) => {
                    let child = r.child(p);
                    match child.stamp(crate::store::MANIFEST_FILE) {
                        Ok(Some((size, ms))) => (
                            Some((
                                SystemTime::UNIX_EPOCH + std::time::Duration::from_millis(ms.max(0) as u64),
                                size,
                            )),
                            Err(child),
                        ),
                        Ok(None) => continue,
                        Err(e) => {
                            if let Some(old) = current.get(&name) {
                                self.note_unreadable(&name, &format!("{}/{p}", r.url()), &e);
                                next.insert(name, Arc::clone(old));
                            }
                            continue;
                        }
                    }
                }
                Found::Dir(_) => continue,
            };
            if let Some(old) = current.get(&name)
                && old.stamp == st
            {
                next.insert(name, old.clone());
                continue;
            }
            if self.known_broken(&name, st) {
                continue;
            }
            let opened = match store {
                Ok(file) => Store::archive_at(&format!("{}/{file}", r.url())),
                Err(child) => Ok(Store::from_bucket(child)),
            };
            match opened.map_err(ServerError::from).and_then(|s| load_complete(&name, s, st, None)) {
                Ok(ts) => {
                    tracing::info!(tileset = %name, content_version = %ts.content_version, "tileset loaded");
                    next.insert(name, Arc::new(ts));
                }
                Err(e) => self.load_failed(&name, st, &e),
            }
        }
        let names: std::collections::HashSet<String> = found_names;
        self.prune_failed(&|n| names.contains(n), &next);
        self.publish(&current, next);
        Ok(())
    }

    fn publish(&self, current: &HashMap<String, Arc<Tileset>>, next: HashMap<String, Arc<Tileset>>) {
        for name in current.keys() {
            if !next.contains_key(name) {
                tracing::info!(tileset = %name, "tileset removed");
            }
        }
        if let Ok(mut m) = self.map.write() {
            *m = next;
        }
    }

    /// Re-scans the store; returns an error only when the store itself cannot be read.
    pub fn scan(&self) -> Result<(), ServerError> {
        self.begin_scan();
        let r = self.scan_store();
        if r.is_ok() {
            self.end_scan();
        }
        r
    }

    fn scan_store(&self) -> Result<(), ServerError> {
        if let Some(r) = &self.remote {
            return self.scan_remote(r);
        }
        let entries = std::fs::read_dir(&self.root).map_err(|e| {
            ServerError::Config(format!("{}: cannot read the store: {e}", self.root.display()))
        })?;
        let current: HashMap<String, Arc<Tileset>> = self.map.read().map(|m| m.clone()).unwrap_or_default();
        let mut next = HashMap::with_capacity(current.len());
        // A loaded tileset whose directory or manifest cannot be read now (permissions, its
        // directory replaced by a file, a failing mount) stays loaded: its reads then fail as
        // `503` (store-io), instead of the tileset vanishing as `404`. Only a directory or
        // manifest that is not there any more (NotFound) drops it.
        let keep_unreadable = |name: &str, path: &Path, e: &std::io::Error, next: &mut HashMap<_, _>| {
            if let Some(old) = current.get(name) {
                self.note_unreadable(name, &path.display().to_string(), e);
                next.insert(name.to_owned(), Arc::clone(old));
            }
        };
        let mut seen: HashMap<String, Found> = HashMap::new();
        for entry in entries.flatten() {
            let Some(file) = entry.file_name().to_str().map(str::to_owned) else { continue };
            let path = entry.path();
            if let Some(name) = file.strip_suffix(crate::store::ARCHIVE_SUFFIX).filter(|n| valid_name(n)) {
                // A packed tileset; a folder of the same name wins.
                match stamp(&path) {
                    Ok(Some(st)) => {
                        seen.entry(name.to_owned())
                            .or_insert_with(|| Found::Archive(path.to_string_lossy().into_owned(), Some(st)));
                    }
                    Ok(None) => {}
                    Err(e) => keep_unreadable(name, &path, &e, &mut next),
                }
                continue;
            }
            let name = file;
            if !valid_name(&name) {
                continue;
            }
            match std::fs::metadata(&path) {
                Ok(md) if md.is_dir() => {
                    seen.insert(name, Found::Dir(path));
                }
                Ok(_) => keep_unreadable(
                    &name,
                    &path,
                    &std::io::Error::from(std::io::ErrorKind::NotADirectory),
                    &mut next,
                ),
                Err(e) if e.kind() == std::io::ErrorKind::NotFound => {}
                Err(e) => keep_unreadable(&name, &path, &e, &mut next),
            }
        }
        for name in self.on_demand.keys() {
            if !next.contains_key(name) {
                seen.insert(name.clone(), Found::Dir(self.root.join(name)));
            }
        }
        let found_names: std::collections::HashSet<String> = seen.keys().cloned().collect();
        for (name, found) in seen {
            let dir = match found {
                Found::Dir(dir) => dir,
                Found::Archive(file, st) => {
                    if let Some(old) = current.get(&name)
                        && old.stamp == st
                    {
                        next.insert(name, old.clone());
                        continue;
                    }
                    if self.known_broken(&name, st) {
                        continue;
                    }
                    // A FIFO or device named NAME.tsa is refused by its type, never opened.
                    match Store::archive_at(&file)
                        .map_err(ServerError::from)
                        .and_then(|s| load_complete(&name, s, st, None))
                    {
                        Ok(ts) => {
                            tracing::info!(tileset = %name, content_version = %ts.content_version, "tileset loaded (archive)");
                            next.insert(name, Arc::new(ts));
                        }
                        Err(e) => self.load_failed(&name, st, &e),
                    }
                    continue;
                }
                Found::Prefix(_) => continue,
            };
            let od = self.on_demand.get(&name);
            let manifest_path = dir.join(crate::store::MANIFEST_FILE);
            let st = match stamp(&manifest_path) {
                Ok(st) => st,
                Err(e) => {
                    keep_unreadable(&name, &manifest_path, &e, &mut next);
                    continue;
                }
            };
            if let Some(old) = current.get(&name)
                && old.stamp == st
            {
                next.insert(name, old.clone());
                continue;
            }
            if st.is_some() && self.known_broken(&name, st) {
                continue;
            }
            let loaded = match (st, od) {
                (Some(_), _) => load_complete(&name, Store::new(&dir), st, od.map(|o| o.source.clone())),
                (None, Some(o)) => Ok(load_provisional(&name, &dir, o.source.clone(), &o.options)),
                (None, None) => continue,
            };
            match loaded {
                Ok(ts) => {
                    tracing::info!(tileset = %name, content_version = %ts.content_version, "tileset loaded");
                    next.insert(name, Arc::new(ts));
                }
                // A half-copied or foreign directory, a manifest that is a FIFO or too large:
                // skipped, and read again only once its manifest changes.
                Err(e) => self.load_failed(&name, st, &e),
            }
        }
        self.prune_failed(&|n| found_names.contains(n), &next);
        self.publish(&current, next);
        Ok(())
    }
}
