//! Tilesets: their layout, manifest and index chunks, atomic writes, resume; the files live in
//! one [`Backend`] (a local directory, a bucket prefix or a packed archive; see [`backend`]).
//!
//! ```text
//! DIR/tileset.json                  manifest, written last (its presence = a complete bake)
//! DIR/index/{z}/{x}/{y}.json        index chunk: every node of the subtree rooted at (z, x, y),
//!                                   SUBTREE_LEVELS deep; roots at z = 0, 4, 8, …
//! DIR/tiles/{z}/{x}/{y}/{level}.tsb one blob per (tile, level) the node stores
//! DIR/tiles/{z}/{x}/{y}/{level}.unpaid  empty: the level was baked and did not pay (it would
//!                                   cost as much as a finer level), so the node has no blob
//! DIR/bake-options.json             the options of the bake, written first, so an interrupted
//!                                   bake (no manifest yet) can be resumed and checked
//! ```
//!
//! Every file is written whole and atomically (in a directory: to a temporary name in the same
//! folder, renamed into place; in a bucket: one PUT), so a reader (or a resumed bake) sees either
//! the old file or the complete new one, never a torn one.

pub mod archive;
pub mod backend;
pub mod bounded;
pub mod model_manifest;

use std::io::Write;
use std::path::{Path, PathBuf};
use std::sync::Arc;

use backend::Sweep;
pub use backend::bucket::{self, Bucket};
use backend::local::io;
pub use backend::local::{LocalDir, check_out_file, write_atomic};
pub use backend::packed::Packed;
pub use backend::{Backend, Location, is_remote};

use serde::{Deserialize, Serialize};

use crate::geom::{Bounds, ErrorFigures};
use crate::raster::Georef;
use crate::tiling::TileKey;

/// Manifest format name and version.
pub const MANIFEST_FORMAT: &str = "terrastream-tileset";
pub const MANIFEST_VERSION: u32 = 1;
/// Levels of the quadtree held by one index chunk (1 + 4 + 16 + 64 = 85 nodes at most), so no
/// index file grows with the dataset.
pub const SUBTREE_LEVELS: u8 = 4;
pub const MANIFEST_FILE: &str = "tileset.json";
/// The file name ending of a packed tileset (`terrastream pack`).
pub const ARCHIVE_SUFFIX: &str = ".tsa";
/// What a tileset holds: the manifest's `kind` (`"terrain"`, also what a manifest without
/// `kind` is, or `"model"`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum TilesetKind {
    /// A heightfield tileset (`bake`).
    Terrain,
    /// A standalone model tileset (`bake-model`): one node, 0/0/0.
    Model,
}

impl TilesetKind {
    /// `"terrain"` or `"model"`, as the manifest writes it.
    #[must_use]
    pub fn as_str(self) -> &'static str {
        match self {
            Self::Terrain => "terrain",
            Self::Model => "model",
        }
    }
}

impl std::fmt::Display for TilesetKind {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.pad(self.as_str())
    }
}
const STATE_FILE: &str = "bake-options.json";

#[derive(Debug, thiserror::Error)]
pub enum StoreError {
    #[error("{path}: {source}")]
    Io { path: PathBuf, source: std::io::Error },
    /// An object-storage request failed (after its retries) or the URL cannot be opened.
    #[error("{url}: {message}")]
    Remote { url: String, message: String },
    #[error("{path}: invalid JSON: {source}")]
    Json { path: PathBuf, source: serde_json::Error },
    #[error("{path}: {message}")]
    Invalid { path: PathBuf, message: String },
    #[error(
        "{path}: holds an earlier bake with different options ({what}); choose another --out or delete the directory"
    )]
    OptionsChanged { path: PathBuf, what: String },
    #[error("{path}: directory is not empty and is not a terrastream tileset; refusing to write into it")]
    NotATileset { path: PathBuf },
    #[error("{path}: no tile {key} level {level} in this tileset")]
    NoSuchTile { path: PathBuf, key: TileKey, level: u8 },
    #[error(
        "{path}: tile {key} does not store level {level}: {why}; `terrastream inspect --tile {key}` lists the \
         levels it has"
    )]
    LevelNotStored { path: PathBuf, key: TileKey, level: u8, why: &'static str },
    /// A stored file failed a check of its own bytes (an archive's checksum, a directory entry
    /// out of range): the data is damaged, and reading it again will not help.
    #[error("{path}: {message}")]
    Corrupt { path: PathBuf, message: String },
    /// A stored file larger than any file of its kind can be (checked before it is read).
    #[error("{path}: {}", too_large(*.size, *.limit, .what))]
    TooLarge { path: PathBuf, size: Option<u64>, limit: u64, what: &'static str },
    /// A FIFO, device or socket where a stored file should be: refused without opening it.
    #[error("{path}: is {kind}, not a regular file; refused without reading it")]
    NotRegular { path: PathBuf, kind: &'static str },
}

fn too_large(size: Option<u64>, limit: u64, what: &str) -> String {
    match size {
        Some(n) => format!("is {n} bytes; a {what} is at most {limit} bytes (not read)"),
        None => format!("holds more than {limit} bytes, the most a {what} may hold (read no further)"),
    }
}

impl StoreError {
    /// Whether the error says the stored data itself is bad (damaged, too large, not a regular
    /// file), as opposed to the store being unreadable now (I/O, a remote error): a server
    /// answers the first `500` and the second `503` (retry later).
    #[must_use]
    pub fn is_damaged(&self) -> bool {
        matches!(
            self,
            Self::Corrupt { .. } | Self::TooLarge { .. } | Self::NotRegular { .. } | Self::Json { .. }
        )
    }
}

/// Largest JSON document of a tileset a reader accepts (manifest, index chunk, options and
/// placement records), checked before reading. Real bakes write far less: a manifest of a few
/// KiB, an index chunk of 85 nodes × 17 levels under 1 MiB (about 600 bytes per node level).
pub const MAX_DOCUMENT_BYTES: u64 = 4 << 20;
/// Largest blob a reader accepts: its header and the largest payload the blob format allows.
pub const MAX_BLOB_BYTES: u64 = crate::codec::PREFIX_LEN as u64 + crate::codec::MAX_PAYLOAD_LEN as u64;

/// The most bytes a reader takes of the tileset file `rel`, and what the file is (for
/// messages): a blob's limit for blobs and other binary files (quantized-mesh tiles, glTF),
/// [`MAX_DOCUMENT_BYTES`] for the tileset's JSON documents.
#[must_use]
pub fn read_limit(rel: &str) -> (u64, &'static str) {
    let ext = std::path::Path::new(rel).extension();
    if ext.is_some_and(|e| e.eq_ignore_ascii_case("json")) {
        (MAX_DOCUMENT_BYTES, "JSON document of a tileset")
    } else if ext.is_some_and(|e| e.eq_ignore_ascii_case("tsb")) {
        (MAX_BLOB_BYTES, "blob")
    } else {
        (MAX_BLOB_BYTES, "file of a tileset")
    }
}

/// What a level is and how it was made.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct LevelSpec {
    pub level: u8,
    pub kind: crate::codec::Kind,
    /// Mesh: the TIN's error bound for leaf tiles (parents scale it by their sample step).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub max_error: Option<f64>,
    /// Points: the slicing cell edge in leaf cells (parents scale it by their sample step).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub cell_leaf_cells: Option<u32>,
    /// Points: the paper's texture size T3 (framebuffer pixels per full tile side).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub texture_size: Option<u32>,
    /// Points: quantization step as a fraction of the cell edge.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub precision_per_cell: Option<u32>,
    /// Points: half-width, in cells, of the cube each point's footprint is clipped to (how the
    /// level is drawn and measured; see `lod::footprint_half`). Absent in tilesets baked before
    /// it was recorded: the kind's default then.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub footprint_half: Option<f64>,
}

/// Per-level figures of one node.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct NodeLevel {
    /// The level's id in the manifest's ladder (0 = the mesh). A node stores only the levels
    /// that pay ([`levels_that_pay`]), so ids may skip; an index written before ids were
    /// recorded lists every level in order, and reading it numbers them by position.
    #[serde(default = "unnumbered")]
    pub level: u8,
    pub errors: ErrorFigures,
    /// Vertices (mesh) or points.
    pub count: u32,
    /// Triangles (mesh only, 0 for points).
    pub triangles: u32,
    pub bytes: u64,
    /// The blob's payload checksum (from its header).
    pub checksum: u32,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(try_from = "RawNodeEntry")]
pub struct NodeEntry {
    pub key: TileKey,
    pub bounds: Bounds,
    /// The levels this node stores, finest first: level 0 (the mesh) always, then the point
    /// levels that pay, by increasing id.
    pub levels: Vec<NodeLevel>,
}

/// A point level a node does not store, and why (its `unpaid` marker says so: the index, which
/// clients stream, does not).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct SkippedLevel {
    pub level: u8,
    pub why: SkipReason,
}

/// Why a node does not store one of its point levels.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum SkipReason {
    /// Baked, and not cheaper (primitives and bytes) than a finer level the node keeps
    /// ([`levels_that_pay`]); also every marker written before reasons were kept.
    Costlier,
    /// Baked and measured: its error is not under what the parent's finest level leaves to
    /// reach (`lod::reach`), so no screen-space selector would choose it.
    Unreachable,
    /// Not baked: its error is bounded below by its point spacing (`lod::reach::gap_lower_bound`)
    /// at or above that reach.
    PredictedUnreachable,
    /// Not baked: `--point-levels none`.
    Policy,
}

impl SkipReason {
    /// The marker's text (`tiles/{z}/{x}/{y}/{level}.unpaid`): empty for `Costlier`, as every
    /// marker was before reasons were kept (so `--point-levels all` writes what it always wrote).
    #[must_use]
    pub fn as_str(self) -> &'static str {
        match self {
            Self::Costlier => "",
            Self::Unreachable => "unreachable",
            Self::PredictedUnreachable => "predicted-unreachable",
            Self::Policy => "policy",
        }
    }

    /// The reason a marker's bytes name; an empty marker or unknown text is `Costlier`.
    #[must_use]
    pub fn from_marker(bytes: &[u8]) -> Self {
        [Self::Unreachable, Self::PredictedUnreachable, Self::Policy]
            .into_iter()
            .find(|r| r.as_str().as_bytes() == bytes.trim_ascii())
            .unwrap_or(Self::Costlier)
    }

    /// One line for people.
    #[must_use]
    pub fn describe(self) -> &'static str {
        match self {
            Self::Costlier => "not cheaper than a finer level kept",
            Self::Unreachable => "error too large to be chosen below the parent (measured)",
            Self::PredictedUnreachable => {
                "error too large to be chosen below the parent (predicted from spacing, not baked)"
            }
            Self::Policy => "--point-levels none",
        }
    }
}

impl NodeEntry {
    /// The node's figures for level `level`, if it stores that level.
    #[must_use]
    pub fn level(&self, level: u8) -> Option<&NodeLevel> {
        self.levels.iter().find(|l| l.level == level)
    }

    /// Bit `l` set for each level `l` the node stores.
    #[must_use]
    pub fn level_mask(&self) -> u64 {
        self.levels.iter().fold(0, |m, l| m | (1u64 << (l.level & 63)))
    }
}

/// `NodeLevel::level` of an index entry written before level ids were recorded.
const UNNUMBERED: u8 = u8::MAX;
fn unnumbered() -> u8 {
    UNNUMBERED
}

/// A node entry as read, before its level ids are checked (or numbered by position).
#[derive(Deserialize)]
struct RawNodeEntry {
    key: TileKey,
    bounds: Bounds,
    levels: Vec<NodeLevel>,
}

/// Why an index entry's levels are not a node's: the JSON reader reports it with its position.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum NodeEntryError {
    /// An entry without level ids lists more levels than ids exist.
    #[error("node {key}: {count} levels")]
    TooManyLevels { key: TileKey, count: usize },
    #[error("node {key}: some levels have a `level` id and some do not")]
    MixedIds { key: TileKey },
    #[error("node {key}: the first level must be level 0 (the mesh)")]
    FirstNotMesh { key: TileKey },
    #[error("node {key}: level ids must increase (level {level} after {after})")]
    IdsNotIncreasing { key: TileKey, level: u8, after: u8 },
}

impl TryFrom<RawNodeEntry> for NodeEntry {
    type Error = NodeEntryError;
    fn try_from(raw: RawNodeEntry) -> Result<Self, NodeEntryError> {
        let RawNodeEntry { key, bounds, mut levels } = raw;
        let unnumbered = levels.iter().filter(|l| l.level == UNNUMBERED).count();
        if unnumbered == levels.len() {
            if levels.len() > usize::from(UNNUMBERED) {
                return Err(NodeEntryError::TooManyLevels { key, count: levels.len() });
            }
            for (i, l) in levels.iter_mut().enumerate() {
                l.level = i as u8;
            }
        } else if unnumbered > 0 {
            return Err(NodeEntryError::MixedIds { key });
        }
        if levels.first().map(|l| l.level) != Some(0) {
            return Err(NodeEntryError::FirstNotMesh { key });
        }
        if let Some(w) = levels.windows(2).find(|w| w[1].level <= w[0].level) {
            return Err(NodeEntryError::IdsNotIncreasing { key, level: w[1].level, after: w[0].level });
        }
        Ok(Self { key, bounds, levels })
    }
}

/// Which of a node's levels pay for themselves: level 0 (the mesh) always; a coarser level
/// only if it is cheaper — fewer primitives (vertices of the mesh, points of a point level: what
/// the GPU transforms) *and* fewer bytes — than every finer level that is kept. A level that
/// costs as much as a finer one is worse in every respect (slower to draw and to stream, less
/// exact), so the node simply goes without it. `levels` is finest first; the result is
/// parallel to it.
#[must_use]
pub fn levels_that_pay(levels: &[NodeLevel]) -> Vec<bool> {
    let mut pay = Payer::default();
    levels.iter().map(|l| pay.keep(l.count, l.bytes)).collect()
}

/// [`levels_that_pay`] one level at a time, finest first, for a baker that decides before it
/// has finished a level: the rule looks at primitives and bytes only, so [`Payer::may_pay`]
/// tells from the count alone whether encoding can help, and the measured errors are needed
/// only for the levels kept.
#[derive(Debug, Clone, Copy, Default)]
pub struct Payer {
    /// Cheapest kept so far: every finer kept level costs at least this much in both measures.
    cheapest: Option<(u32, u64)>,
}

impl Payer {
    /// False when a level of `count` primitives cannot pay whatever its bytes.
    #[must_use]
    pub fn may_pay(&self, count: u32) -> bool {
        self.cheapest.is_none_or(|(c, _)| count < c)
    }

    /// Whether a level of `count` primitives and `bytes` bytes would pay ([`Payer::keep`]
    /// without keeping it).
    #[must_use]
    pub fn would_pay(&self, count: u32, bytes: u64) -> bool {
        self.cheapest.is_none_or(|(c, b)| count < c && bytes < b)
    }

    /// Whether the next level (finer ones already seen) pays; if so it is kept.
    pub fn keep(&mut self, count: u32, bytes: u64) -> bool {
        let pays = self.cheapest.is_none_or(|(c, b)| count < c && bytes < b);
        if pays {
            self.cheapest = Some((count, bytes));
        }
        pays
    }
}

/// One index chunk: the nodes of the subtree rooted at `root`, `SUBTREE_LEVELS` deep.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct IndexChunk {
    pub root: TileKey,
    pub nodes: Vec<NodeEntry>,
}

/// Where the heights came from.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct SourceInfo {
    pub file: String,
    pub format: String,
    pub width: u32,
    pub height: u32,
    pub nodata_filled: u64,
}

/// Per-level totals over the whole tileset.
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize, Deserialize)]
pub struct LevelTotals {
    pub tiles: u64,
    pub count: u64,
    pub triangles: u64,
    pub bytes: u64,
    pub worst: ErrorFigures,
}

/// The per-level table `bake` and `inspect` print: one header line and one line per level
/// (level 0 the mesh), without a trailing newline.
pub struct LevelTable<'a>(pub &'a [LevelTotals]);

impl std::fmt::Display for LevelTable<'_> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "{:>5}  {:>6}  {:>7}  {:>11}  {:>10}  {:>12}  {:>7}  {:>10}  {:>10}  {:>10}",
            "level",
            "kind",
            "tiles",
            "vertices/pts",
            "triangles",
            "bytes",
            "B/item",
            "max err",
            "worst rms",
            "worst gap"
        )?;
        for (l, t) in self.0.iter().enumerate() {
            if l > 0 && t.tiles == 0 {
                write!(f, "\n{l:>5}  {:>6}  {:>7}  (not stored)", "points", 0)?;
                continue;
            }
            write!(
                f,
                "\n{:>5}  {:>6}  {:>7}  {:>11}  {:>10}  {:>12}  {:>7.2}  {:>10.3}  {:>10.3}  {:>10.3}",
                l,
                if l == 0 { "mesh" } else { "points" },
                t.tiles,
                t.count,
                t.triangles,
                t.bytes,
                t.bytes as f64 / t.count.max(1) as f64,
                t.worst.max,
                t.worst.rms,
                t.worst.gap
            )?;
        }
        Ok(())
    }
}

/// How many nodes store each set of levels (`inspect`'s "levels per node"), most common first.
#[must_use]
pub fn level_sets<'a>(nodes: impl IntoIterator<Item = &'a NodeEntry>) -> Vec<(Vec<u8>, u64)> {
    let mut sets: std::collections::BTreeMap<Vec<u8>, u64> = std::collections::BTreeMap::new();
    for n in nodes {
        *sets.entry(n.levels.iter().map(|l| l.level).collect()).or_default() += 1;
    }
    let mut out: Vec<(Vec<u8>, u64)> = sets.into_iter().collect();
    out.sort_by(|a, b| b.1.cmp(&a.1).then_with(|| a.0.cmp(&b.0)));
    out
}

/// The point levels of `ladder` (level ids) that `node` does not store, and why (from their
/// `unpaid` markers; a level with neither blob nor marker is not listed).
pub fn skipped_levels(
    store: &Store,
    node: &NodeEntry,
    ladder: &[u8],
) -> Result<Vec<SkippedLevel>, StoreError> {
    let mut out = Vec::new();
    for &level in ladder.iter().filter(|&&l| l > 0 && node.level(l).is_none()) {
        if let Some(why) = store.unpaid_reason(node.key, level)? {
            out.push(SkippedLevel { level, why });
        }
    }
    Ok(out)
}

/// How many nodes left out each level, by reason ([`skipped_levels`]).
pub fn skipped_counts<'a>(
    store: &Store,
    nodes: impl IntoIterator<Item = &'a NodeEntry>,
    ladder: &[u8],
) -> Result<std::collections::BTreeMap<(u8, SkipReason), u64>, StoreError> {
    let mut out = std::collections::BTreeMap::new();
    for n in nodes {
        for s in skipped_levels(store, n, ladder)? {
            *out.entry((s.level, s.why)).or_default() += 1;
        }
    }
    Ok(out)
}

impl LevelTotals {
    pub fn add(&mut self, l: &NodeLevel) {
        self.tiles += 1;
        self.count += u64::from(l.count);
        self.triangles += u64::from(l.triangles);
        self.bytes += l.bytes;
        self.worst.max = self.worst.max.max(l.errors.max);
        self.worst.rms = self.worst.rms.max(l.errors.rms);
        self.worst.gap = self.worst.gap.max(l.errors.gap);
    }
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Manifest {
    pub format: String,
    pub version: u32,
    /// Changes whenever any blob's content changes (a hash of every blob's checksum), so clients
    /// may put it in URLs and cache those forever.
    pub content_version: String,
    pub source: SourceInfo,
    pub frame: Georef,
    pub tile_size: u32,
    pub depth: u8,
    pub subtree_levels: u8,
    pub bounds: Bounds,
    pub levels: Vec<LevelSpec>,
    pub totals: Vec<LevelTotals>,
    /// The options the tileset was baked with (what a resumed bake must match).
    pub options: serde_json::Value,
    /// What baked the point levels in the run that finished the tileset: "cpu" or
    /// "gpu: <adapter name> (<backend>, <device type>)".
    #[serde(default)]
    pub point_baker: String,
}

/// A tileset's content version: the 64-bit XXH3 of every stored level's record — level id,
/// payload CRC-32, stored bytes, vertex/point and triangle counts, measured errors — in node order
/// and level order within a node, as 16 hex digits. Clients cache `?v=` URLs for a year, so the
/// version is 64 bits wide (a 32-bit one has even odds of two versions colliding by ~77,000);
/// a blob whose bytes change changes its checksum, length or figures, and so the version.
#[must_use]
pub fn content_version<'a>(levels: impl IntoIterator<Item = &'a NodeLevel>) -> String {
    let mut hasher = xxhash_rust::xxh3::Xxh3Default::new();
    for l in levels {
        hasher.update(&[l.level]);
        hasher.update(&l.checksum.to_le_bytes());
        hasher.update(&l.bytes.to_le_bytes());
        hasher.update(&l.count.to_le_bytes());
        hasher.update(&l.triangles.to_le_bytes());
        for e in [l.errors.max, l.errors.rms, l.errors.gap] {
            hasher.update(&e.to_bits().to_le_bytes());
        }
    }
    format!("{:016x}", hasher.digest())
}

/// The index chunk root holding `key`.
#[must_use]
pub fn chunk_root(key: TileKey) -> TileKey {
    let dz = key.z % SUBTREE_LEVELS;
    TileKey::new(key.z - dz, key.x >> dz, key.y >> dz)
}

/// A tileset, in one [`Backend`]: a local directory (the default and the fast path), a prefix
/// in object storage ([`Store::at`] with an `s3://` URL) or a packed archive (read-only).
#[derive(Debug, Clone)]
pub struct Store {
    backend: Arc<dyn Backend>,
}

/// The blob of a node's level, relative to the tileset.
#[must_use]
pub fn blob_rel(key: TileKey, level: u8) -> String {
    format!("tiles/{}/{}/{}/{level}.tsb", key.z, key.x, key.y)
}

/// The `unpaid` marker of a node's level, relative to the tileset.
#[must_use]
pub fn unpaid_rel(key: TileKey, level: u8) -> String {
    format!("tiles/{}/{}/{}/{level}.unpaid", key.z, key.x, key.y)
}

/// The index chunk rooted at `root`, relative to the tileset.
#[must_use]
pub fn chunk_rel(root: TileKey) -> String {
    format!("index/{}/{}/{}.json", root.z, root.x, root.y)
}

/// The folder of a node's blobs and markers, relative to the tileset.
fn node_rel(key: TileKey) -> String {
    format!("tiles/{}/{}/{}", key.z, key.x, key.y)
}

/// Top folders of the tileset that hold files a bake writes, and how deep below the top their
/// files lie at most (`tiles/{z}/{x}/{y}/`, one more for what may sit beside a blob).
const WRITTEN_FOLDERS: [&str; 2] = ["tiles", "index"];
const WRITTEN_DEPTH: u32 = 5;

impl Store {
    /// Opens an existing or new tileset directory (nothing is created until the first write).
    #[must_use]
    pub fn new(dir: &Path) -> Self {
        Self::with(LocalDir::new(dir))
    }

    /// The tileset in `backend`.
    #[must_use]
    pub fn with(backend: impl Backend) -> Self {
        Self { backend: Arc::new(backend) }
    }

    /// Opens a tileset by location: a path, a `file://` URL, or object storage (`s3://BUCKET/PREFIX`,
    /// configured from the environment; see [`bucket`]); a name ending in `.tsa` is a packed
    /// tileset ([`Store::archive_at`]). Nothing is requested until the first read or write.
    pub fn at(location: &Path) -> Result<Self, StoreError> {
        let text = location.to_string_lossy();
        if let Some(path) = text.strip_prefix("file://") {
            return Ok(Self::new(Path::new(path)));
        }
        if text.ends_with(ARCHIVE_SUFFIX) {
            return Self::archive_at(&text);
        }
        if is_remote(&text) {
            return Ok(Self::from_bucket(Bucket::open(&text)?));
        }
        Ok(Self::new(location))
    }

    /// The tileset's name: its folder's (or prefix's) last component, an archive's file name
    /// without `.tsa` (as `serve` names it).
    #[must_use]
    pub fn name(&self) -> Option<String> {
        let n = self.dir().file_name()?.to_string_lossy().into_owned();
        Some(if self.archive().is_some() {
            n.strip_suffix(ARCHIVE_SUFFIX).map_or(n.clone(), str::to_owned)
        } else {
            n
        })
    }

    /// The tileset at an opened bucket prefix.
    #[must_use]
    pub fn from_bucket(r: Bucket) -> Self {
        Self::with(r)
    }

    /// A packed tileset: a local `.tsa` file or one in a bucket, opened for reading (its footer
    /// and directory root are read and checked now).
    pub fn archive_at(location: &str) -> Result<Self, StoreError> {
        Ok(Self::with(Packed::open(location)?))
    }

    /// The backend the tileset is in.
    #[must_use]
    pub fn backend(&self) -> &dyn Backend {
        self.backend.as_ref()
    }

    /// Where the tileset is.
    #[must_use]
    pub fn location(&self) -> &Location {
        self.backend.location()
    }

    /// The archive, when the tileset is a packed one.
    #[must_use]
    pub fn archive(&self) -> Option<&archive::Archive> {
        let any: &dyn std::any::Any = self.backend.as_ref();
        any.downcast_ref::<Packed>().map(Packed::archive)
    }

    /// The object-storage location, when the tileset is a bucket prefix.
    #[must_use]
    pub fn bucket(&self) -> Option<&Bucket> {
        let any: &dyn std::any::Any = self.backend.as_ref();
        any.downcast_ref::<Bucket>()
    }

    /// The directory (for a tileset in a bucket or an archive, its location as a path: for
    /// messages only).
    #[must_use]
    pub fn dir(&self) -> &Path {
        self.location().as_path()
    }

    /// Checks, before any input is read, that a bake can write the tileset here: a path that
    /// cannot become a folder (a file, a path under a file, a dangling symbolic link) or a
    /// packed tileset is refused with the error [`Store::begin_bake`] would give after the work.
    pub fn check_out(&self) -> Result<(), StoreError> {
        self.backend.check_writable()
    }

    /// A file of the tileset (relative path); `Ok(None)` when it does not exist.
    /// Its size is checked against [`read_limit`] before (and while) it is read.
    fn get(&self, rel: &str) -> Result<Option<Vec<u8>>, StoreError> {
        self.backend.read(rel, read_limit(rel).0)
    }

    /// Writes a file of the tileset whole: a temporary file renamed into place, or one PUT.
    fn put(&self, rel: &str, bytes: &[u8]) -> Result<(), StoreError> {
        self.backend.write(rel, bytes)
    }

    /// A file of the tileset by its relative path, for the server: `Ok(None)` when it does not
    /// exist. Local files are read on tokio's blocking pool, objects through the async client,
    /// archive ranges on the blocking pool. Its size is checked against [`read_limit`] before
    /// (and while) it is read.
    #[cfg(feature = "server")]
    pub async fn get_async(&self, rel: &str) -> Result<Option<bytes::Bytes>, StoreError> {
        self.backend.read_async(rel, read_limit(rel).0).await
    }

    /// Whether a file of the tileset exists, for the server.
    #[cfg(feature = "server")]
    pub async fn exists_async(&self, rel: &str) -> Result<bool, StoreError> {
        self.backend.exists_async(rel).await
    }

    fn exists(&self, rel: &str) -> Result<bool, StoreError> {
        self.backend.exists(rel)
    }

    fn get_json<T: for<'de> Deserialize<'de>>(&self, rel: &str) -> Result<T, StoreError> {
        let path = self.location().join(rel);
        let bytes = self.get(rel)?.ok_or_else(|| {
            io(&path)(std::io::Error::new(
                std::io::ErrorKind::NotFound,
                "No such file or directory (os error 2)",
            ))
        })?;
        serde_json::from_slice(&bytes).map_err(|source| StoreError::Json { path, source })
    }

    #[must_use]
    pub fn blob_path(&self, key: TileKey, level: u8) -> PathBuf {
        self.location().join(&blob_rel(key, level))
    }

    #[must_use]
    pub fn chunk_path(&self, root: TileKey) -> PathBuf {
        self.location().join(&chunk_rel(root))
    }

    /// Every file of the tileset a reader needs, as relative paths with their sizes, in path
    /// order: temporary files (names beginning with a dot), a sharded bake's `shards/` folder
    /// and blobs moved aside as `.corrupt` are left out. A directory tree deeper than 16 levels
    /// is refused (a tileset is 6 deep).
    pub fn files(&self) -> Result<Vec<(String, u64)>, StoreError> {
        let mut out = self.backend.list()?;
        out.retain(|(rel, _)| {
            !rel.starts_with("shards/")
                && !rel.split('/').any(|c| c.starts_with('.'))
                && !rel.ends_with(".corrupt")
        });
        out.sort();
        Ok(out)
    }

    /// Packs the finished tileset into one archive ([`archive`]) written to `out`; returns the
    /// files packed and the archive's length. Refuses a tileset without its manifest.
    pub fn pack_into<W: Write>(
        &self,
        out: W,
        mut progress: impl FnMut(u64),
    ) -> Result<(W, u64, u64), StoreError> {
        if !self.has_manifest()? {
            return Err(StoreError::Invalid {
                path: self.manifest_path(),
                message:
                    "no manifest: only a finished tileset can be packed (finish or resume its bake first)"
                        .into(),
            });
        }
        let files = self.files()?;
        let werr = |e: archive::ArchiveError| StoreError::Invalid {
            path: self.dir().to_owned(),
            message: format!("packing: {e}"),
        };
        let mut w = archive::ArchiveWriter::new(out).map_err(werr)?;
        for (rel, _) in &files {
            let bytes = self.get(rel)?.ok_or_else(|| StoreError::Invalid {
                path: self.location().join(rel),
                message: "vanished while packing (is a bake still writing here?)".into(),
            })?;
            w.add(rel, &bytes).map_err(werr)?;
            progress(bytes.len() as u64);
        }
        let (out, len) = w.finish().map_err(werr)?;
        Ok((out, files.len() as u64, len))
    }

    /// Whether the manifest exists (the bake is complete).
    pub fn has_manifest(&self) -> Result<bool, StoreError> {
        self.exists(MANIFEST_FILE)
    }

    #[must_use]
    pub fn manifest_path(&self) -> PathBuf {
        self.location().join(MANIFEST_FILE)
    }

    /// Prepares the directory for a bake with `options`, resuming an interrupted or complete
    /// bake with the same options. Refuses a non-empty foreign directory and a tileset baked
    /// with other options. Returns true when an earlier bake is being resumed.
    pub fn begin_bake(&self, options: &serde_json::Value) -> Result<bool, StoreError> {
        // Before anything is read under it: a path that cannot be a tileset folder is named as
        // such, not as a failed read of a file inside it.
        self.backend.check_writable()?;
        let earlier = if let Some(bytes) = self.get(STATE_FILE)? {
            let path = self.location().join(STATE_FILE);
            Some(
                serde_json::from_slice::<serde_json::Value>(&bytes)
                    .map_err(|source| StoreError::Json { path, source })?,
            )
        } else if self.exists(MANIFEST_FILE)? {
            Some(self.manifest()?.options)
        } else {
            None
        };
        match earlier {
            Some(prev) if &prev == options => {
                // A bake killed mid-write leaves its temporary files; a resumed bake's tree
                // must be the same as an uninterrupted one's.
                self.remove_stale_temps()?;
                Ok(true)
            }
            Some(prev) => Err(StoreError::OptionsChanged {
                path: self.dir().to_owned(),
                what: diff_keys(&prev, options),
            }),
            None => {
                let state = self.location().join(STATE_FILE);
                if self.backend.create_first(STATE_FILE, &to_json(options, &state)?)? {
                    Ok(false)
                } else {
                    // Another bake began here between the check and the write: check it as a
                    // resume.
                    self.begin_bake(options)
                }
            }
        }
    }

    /// A file of the tileset by its path relative to the tileset (`shards/plan.json`), written
    /// atomically.
    pub fn write_file(&self, rel: &str, bytes: &[u8]) -> Result<(), StoreError> {
        self.put(rel, bytes)
    }

    /// A file of the tileset by its relative path; `Ok(None)` when it does not exist.
    pub fn read_file(&self, rel: &str) -> Result<Option<Vec<u8>>, StoreError> {
        self.get(rel)
    }

    /// [`Store::read_file`] of a file whose length must lie in `lens` (one length when it is
    /// known in advance, or a limit): the stored size is checked before anything is read, so a
    /// damaged or hostile file is not loaded whole, and a file of another size is
    /// [`StoreError::Invalid`], naming its size and the expected one.
    pub fn read_file_within(
        &self,
        rel: &str,
        lens: std::ops::RangeInclusive<u64>,
    ) -> Result<Option<Vec<u8>>, StoreError> {
        let size = self.backend.size(rel)?;
        let wrong = |size: u64| {
            let expected = if lens.start() == lens.end() {
                format!("{} bytes were expected", lens.start())
            } else {
                format!("{} to {} bytes were expected", lens.start(), lens.end())
            };
            StoreError::Invalid {
                path: self.location().join(rel),
                message: format!("is {size} bytes; {expected}"),
            }
        };
        match size {
            None => Ok(None),
            Some(size) if !lens.contains(&size) => Err(wrong(size)),
            Some(_) => match self.backend.read(rel, *lens.end())? {
                // Replaced between the two requests.
                Some(b) if !lens.contains(&(b.len() as u64)) => Err(wrong(b.len() as u64)),
                other => Ok(other),
            },
        }
    }

    /// Whether a file of the tileset (relative path) exists.
    pub fn has_file(&self, rel: &str) -> Result<bool, StoreError> {
        self.exists(rel)
    }

    /// Removes a folder of the tileset (relative path) and everything in it; nothing when absent.
    pub fn remove_folder(&self, rel: &str) -> Result<(), StoreError> {
        self.backend.remove_folder(rel)
    }

    /// Where a relative path of the tileset is, for messages.
    #[must_use]
    pub fn describe(&self, rel: &str) -> String {
        self.location().join(rel).display().to_string()
    }

    /// [`Store::remove_stale_temps`] in the folders of `keys`' blobs only: what a shard of a
    /// sharded bake cleans on resume (the tileset's other folders belong to other shards, whose
    /// writers may run on other machines where this one's process table says nothing).
    pub fn remove_stale_temps_of(&self, keys: &[TileKey]) -> Result<u64, StoreError> {
        let folders: Vec<String> = keys.iter().map(|&k| node_rel(k)).collect();
        self.backend.remove_temps(Sweep::Folders(&folders), false)
    }

    /// Checks that the tileset was begun ([`Store::begin_bake`]) with `options`, without
    /// touching it: what a shard checks before it writes.
    pub fn check_bake(&self, options: &serde_json::Value) -> Result<(), StoreError> {
        let prev: serde_json::Value = self.get_json(STATE_FILE)?;
        if &prev == options {
            Ok(())
        } else {
            Err(StoreError::OptionsChanged { path: self.dir().to_owned(), what: diff_keys(&prev, options) })
        }
    }

    /// Removes the temporary files of an atomic write (`.NAME.PID.N.tmp`) that a process which
    /// no longer runs left in the tileset (killed mid-write). Files of a live process other than
    /// this one are kept (where `/proc` tells; elsewhere all are removed). Walks only the
    /// tileset's own layout (root, `tiles/` and `index/` down to their blob depth). Returns how
    /// many were removed.
    pub fn remove_stale_temps(&self) -> Result<u64, StoreError> {
        self.remove_temps(false)
    }

    /// [`Store::remove_stale_temps`], or with `every` all temporary files whoever wrote them:
    /// what the final step of a sharded bake does once every shard has finished (a shard killed
    /// on another machine left them; this machine's process table cannot tell). Object stores
    /// have no temporary names (a PUT is atomic) and archives are read-only: nothing to remove.
    pub fn remove_temps(&self, every: bool) -> Result<u64, StoreError> {
        self.backend.remove_temps(Sweep::Tree { folders: &WRITTEN_FOLDERS, depth: WRITTEN_DEPTH }, every)
    }

    /// Marks the bake complete by writing the manifest, last.
    pub fn finish_bake(&self, manifest: &Manifest) -> Result<(), StoreError> {
        self.finish_bake_as(manifest)
    }

    /// [`Store::finish_bake`] for a manifest of another shape (a model tileset's, which adds
    /// fields to [`Manifest`]'s).
    pub fn finish_bake_as<T: Serialize>(&self, manifest: &T) -> Result<(), StoreError> {
        let path = self.manifest_path();
        self.put(MANIFEST_FILE, &to_json(manifest, &path)?)
    }

    /// The manifest read as `T` (for manifests that extend [`Manifest`]); no format check.
    pub fn manifest_as<T: for<'de> Deserialize<'de>>(&self) -> Result<T, StoreError> {
        self.get_json(MANIFEST_FILE)
    }

    /// What the tileset holds: the manifest's `kind` field, terrain when it has none (terrain
    /// manifests predate the field).
    pub fn manifest_kind(&self) -> Result<TilesetKind, StoreError> {
        let path = self.manifest_path();
        let v: serde_json::Value = self.get_json(MANIFEST_FILE)?;
        match v.get("kind") {
            None => Ok(TilesetKind::Terrain),
            Some(k) => TilesetKind::deserialize(k).map_err(|_| StoreError::Invalid {
                path,
                message: format!("manifest field `kind` is {k}, not \"terrain\" or \"model\""),
            }),
        }
    }

    pub fn write_blob(&self, key: TileKey, level: u8, bytes: &[u8]) -> Result<(), StoreError> {
        self.put(&blob_rel(key, level), bytes)?;
        // A fresh bake has no markers: remove one only when resuming finds it (in a bucket, a
        // HEAD rather than a DELETE, which is a write).
        let marker = unpaid_rel(key, level);
        if self.exists(&marker)? {
            self.backend.remove(&marker)?;
        }
        Ok(())
    }

    /// The empty marker saying a node's level was baked and did not pay
    /// ([`levels_that_pay`]): `tiles/{z}/{x}/{y}/{level}.unpaid`. A resumed bake tells a level
    /// left out on purpose from a blob lost since (which it bakes again) by it.
    #[must_use]
    pub fn unpaid_path(&self, key: TileKey, level: u8) -> PathBuf {
        self.location().join(&unpaid_rel(key, level))
    }

    /// Records that `level` of `key` is not stored and why: writes the marker (its text is the
    /// reason) and removes any blob an earlier bake left for it.
    pub fn write_unpaid(&self, key: TileKey, level: u8, why: SkipReason) -> Result<(), StoreError> {
        self.put(&unpaid_rel(key, level), why.as_str().as_bytes())?;
        self.backend.remove(&blob_rel(key, level))
    }

    /// Why `level` of `key` is not stored, when its marker says so ([`Store::write_unpaid`]).
    pub fn unpaid_reason(&self, key: TileKey, level: u8) -> Result<Option<SkipReason>, StoreError> {
        let rel = unpaid_rel(key, level);
        match self.backend.size(&rel)? {
            None => Ok(None),
            // A marker is a word: an empty one (the cheaper-only rule's) or a larger file is not
            // read.
            Some(n) if n == 0 || n > 64 => Ok(Some(SkipReason::Costlier)),
            Some(_) => Ok(self.get(&rel)?.map(|b| SkipReason::from_marker(&b))),
        }
    }

    /// True when [`Store::write_unpaid`] marked `level` of `key` as not stored.
    pub fn is_unpaid(&self, key: TileKey, level: u8) -> Result<bool, StoreError> {
        self.exists(&unpaid_rel(key, level))
    }

    /// The blob's bytes; `Ok(None)` when it does not exist.
    pub fn read_blob(&self, key: TileKey, level: u8) -> Result<Option<Vec<u8>>, StoreError> {
        self.get(&blob_rel(key, level))
    }

    pub fn write_chunk(&self, chunk: &IndexChunk) -> Result<(), StoreError> {
        let path = self.chunk_path(chunk.root);
        self.put(&chunk_rel(chunk.root), &to_json(chunk, &path)?)
    }

    pub fn chunk(&self, root: TileKey) -> Result<IndexChunk, StoreError> {
        self.get_json(&chunk_rel(root))
    }

    pub fn manifest(&self) -> Result<Manifest, StoreError> {
        let path = self.manifest_path();
        let m: Manifest = self.get_json(MANIFEST_FILE)?;
        if m.format != MANIFEST_FORMAT || m.version != MANIFEST_VERSION {
            return Err(StoreError::Invalid {
                path,
                message: format!(
                    "not a {MANIFEST_FORMAT} v{MANIFEST_VERSION} manifest (format {:?}, version {})",
                    m.format, m.version
                ),
            });
        }
        Ok(m)
    }

    /// Every node of the index, chunk by chunk from the root (`pyramid` gives the keys of the
    /// chunks below a chunk's deepest nodes). Bounded by the pyramid: each chunk is read once.
    pub fn all_nodes(&self, pyramid: &crate::tiling::Pyramid) -> Result<Vec<NodeEntry>, StoreError> {
        let mut out = Vec::new();
        let mut roots = vec![TileKey::new(0, 0, 0)];
        while let Some(root) = roots.pop() {
            if !pyramid.contains(root) {
                continue;
            }
            let chunk = self.chunk(root)?;
            let last = root.z.saturating_add(SUBTREE_LEVELS - 1);
            for n in &chunk.nodes {
                if n.key.z == last && chunk_root(n.key) == root {
                    roots.extend(pyramid.children(n.key));
                }
            }
            out.extend(chunk.nodes);
        }
        Ok(out)
    }

    /// The index entry of one node.
    pub fn node(&self, key: TileKey) -> Result<Option<NodeEntry>, StoreError> {
        let chunk = self.chunk(chunk_root(key))?;
        Ok(chunk.nodes.into_iter().find(|n| n.key == key))
    }
}

fn to_json<T: Serialize>(v: &T, path: &Path) -> Result<Vec<u8>, StoreError> {
    let mut out =
        serde_json::to_vec_pretty(v).map_err(|source| StoreError::Json { path: path.to_owned(), source })?;
    out.push(b'\n');
    Ok(out)
}

/// The top-level keys whose values differ, for a readable error.
#[must_use]
pub fn diff_keys(a: &serde_json::Value, b: &serde_json::Value) -> String {
    match (a.as_object(), b.as_object()) {
        (Some(a), Some(b)) => {
            let mut keys: Vec<&String> = a.keys().chain(b.keys()).collect();
            keys.sort();
            keys.dedup();
            let diff: Vec<String> = keys
                .into_iter()
                .filter(|k| a.get(*k) != b.get(*k))
                .map(|k| {
                    let show = |v: Option<&serde_json::Value>| v.map_or("none".into(), ToString::to_string);
                    format!("{k}: {} → {}", show(a.get(k)), show(b.get(k)))
                })
                .collect();
            diff.join(", ")
        }
        _ => "options".into(),
    }
}

#[cfg(test)]
mod tests {
    use std::fs;

    use super::*;

    /// The content version is 64 bits (16 hex digits) and moves with every figure of every
    /// level it covers, and with their order.
    #[test]
    fn content_version_is_64_bits_and_covers_every_level_figure() {
        let base = NodeLevel {
            level: 1,
            errors: crate::geom::ErrorFigures { max: 1.0, rms: 0.5, gap: 0.25 },
            count: 100,
            triangles: 0,
            bytes: 400,
            checksum: 0xdead_beef,
        };
        let other = NodeLevel { level: 0, count: 7, ..base };
        let v = content_version([&base, &other]);
        assert_eq!(v.len(), 16);
        assert!(v.bytes().all(|b| b.is_ascii_hexdigit()));
        assert_eq!(v, content_version([&base, &other]), "deterministic");
        assert_ne!(v, content_version([&other, &base]), "order");
        let changed: [fn(&mut NodeLevel); 7] = [
            |l| l.level = 2,
            |l| l.errors.max = 1.5,
            |l| l.errors.rms = 0.75,
            |l| l.errors.gap = 0.5,
            |l| l.count = 101,
            |l| l.bytes = 401,
            |l| l.checksum ^= 1,
        ];
        for (i, change) in changed.iter().enumerate() {
            let mut l = base;
            change(&mut l);
            assert_ne!(v, content_version([&l, &other]), "figure {i} left the version unchanged");
        }
        let mut l = base;
        l.triangles = 3;
        assert_ne!(v, content_version([&l, &other]));
    }

    /// Index entries: level ids as written, numbered by position when an older index has none,
    /// and refused (naming the node) when mixed, out of order or without the mesh.
    #[test]
    fn node_entries_read_level_ids_or_number_them() {
        let level = |id: Option<u8>| {
            let mut v = serde_json::json!({
                "errors": {"max": 1.0, "rms": 0.5, "gap": 0.0}, "count": 3, "triangles": 1, "bytes": 10, "checksum": 7
            });
            if let Some(id) = id {
                v["level"] = id.into();
            }
            v
        };
        let entry = |levels: Vec<serde_json::Value>| {
            serde_json::json!({
                "key": {"z": 1, "x": 0, "y": 1},
                "bounds": {"min": [0.0, 0.0, 0.0], "max": [1.0, 1.0, 1.0]},
                "levels": levels,
            })
        };
        let parse = |v: serde_json::Value| serde_json::from_value::<NodeEntry>(v);
        let ids = |e: &NodeEntry| e.levels.iter().map(|l| l.level).collect::<Vec<_>>();
        let e = parse(entry(vec![level(Some(0)), level(Some(3)), level(Some(4))])).unwrap();
        assert_eq!(ids(&e), vec![0, 3, 4]);
        assert!(e.level(3).is_some() && e.level(1).is_none());
        assert_eq!(e.level_mask(), 0b11001);
        let old = parse(entry(vec![level(None), level(None), level(None)])).unwrap();
        assert_eq!(ids(&old), vec![0, 1, 2]);
        for (bad, why) in [
            (entry(vec![level(Some(0)), level(None)]), "some levels have"),
            (entry(vec![level(Some(0)), level(Some(2)), level(Some(2))]), "must increase"),
            (entry(vec![level(Some(1))]), "must be level 0"),
            (entry(vec![]), "must be level 0"),
        ] {
            let err = parse(bad).unwrap_err().to_string();
            assert!(err.contains(why) && err.contains("1/0/1"), "{err}");
        }
        assert_eq!(
            parse(entry(vec![level(Some(0)), level(Some(2)), level(Some(2))])).unwrap_err().to_string(),
            "node 1/0/1: level ids must increase (level 2 after 2)"
        );
        // Written and read back, an entry is unchanged (what the store_json fuzz target holds).
        let text = serde_json::to_string(&e).unwrap();
        assert_eq!(serde_json::from_str::<NodeEntry>(&text).unwrap(), e);
    }

    #[test]
    fn chunk_roots() {
        assert_eq!(chunk_root(TileKey::new(0, 0, 0)), TileKey::new(0, 0, 0));
        assert_eq!(chunk_root(TileKey::new(3, 7, 5)), TileKey::new(0, 0, 0));
        assert_eq!(chunk_root(TileKey::new(4, 9, 3)), TileKey::new(4, 9, 3));
        assert_eq!(chunk_root(TileKey::new(6, 9, 3)), TileKey::new(4, 2, 0));
    }

    #[test]
    fn out_dirs_that_cannot_be_made_say_why() {
        let dir = tempfile::tempdir().unwrap();
        let opts = serde_json::json!({"a": 1});
        let link = dir.path().join("link");
        std::os::unix::fs::symlink(dir.path().join("missing"), &link).unwrap();
        let e = Store::new(&link).begin_bake(&opts).unwrap_err().to_string();
        assert!(
            e.contains("symbolic link") && e.contains("does not exist") && !e.contains("File exists"),
            "{e}"
        );
        let file = dir.path().join("file");
        fs::write(&file, b"x").unwrap();
        let e = Store::new(&file).begin_bake(&opts).unwrap_err().to_string();
        assert!(e.contains("not a directory"), "{e}");
        let e = Store::new(&file.join("sub")).begin_bake(&opts).unwrap_err().to_string();
        assert!(e.contains("file: ") || e.contains("is not a directory"), "{e}");
        assert!(!e.contains("os error"), "{e}");
    }

    #[test]
    fn resume_removes_temps_of_dead_writers_only() {
        let dir = tempfile::tempdir().unwrap();
        let store = Store::new(dir.path());
        let opts = serde_json::json!({"a": 1});
        assert!(!store.begin_bake(&opts).unwrap());
        let blob_dir = dir.path().join("tiles/0/0/0");
        fs::create_dir_all(&blob_dir).unwrap();
        // pid 0 is never a user process; u32::MAX - 1 is above any pid_max.
        let dead = blob_dir.join(format!(".1.tsb.{}.0.tmp", u32::MAX - 1));
        let mine = dir.path().join(format!(".tileset.json.{}.0.tmp", std::process::id()));
        let live = blob_dir.join(".0.tsb.1.0.tmp"); // pid 1 (init) is alive wherever /proc exists
        let other = blob_dir.join("notes.tmp");
        for p in [&dead, &mine, &live, &other] {
            fs::write(p, b"x").unwrap();
        }
        assert!(store.begin_bake(&opts).unwrap());
        assert!(!dead.exists() && !mine.exists());
        assert!(other.exists());
        assert_eq!(live.exists(), Path::new("/proc/1").exists());
    }

    /// A bake killed before its options record was first written leaves only that record's
    /// temporary file (found by `tests/hardening.rs`'s kill at once): the next bake starts
    /// there and removes it; a live writer's temporary file, or any other file, still makes the
    /// directory foreign.
    #[test]
    fn a_bake_killed_before_its_first_write_can_start_again() {
        let dir = tempfile::tempdir().unwrap();
        let out = dir.path().join("ts");
        fs::create_dir_all(&out).unwrap();
        let dead = out.join(format!(".{STATE_FILE}.{}.0.tmp", u32::MAX - 1));
        fs::write(&dead, b"{\"tile_").unwrap();
        let opts = serde_json::json!({"a": 1});
        assert!(!Store::new(&out).begin_bake(&opts).unwrap());
        assert!(!dead.exists());
        assert!(Store::new(&out).begin_bake(&opts).unwrap());

        let other = dir.path().join("other");
        fs::create_dir_all(&other).unwrap();
        fs::write(other.join(format!(".{STATE_FILE}.1.0.tmp")), b"x").unwrap(); // pid 1 is alive
        fs::write(other.join("notes.txt"), b"x").unwrap();
        assert!(matches!(Store::new(&other).begin_bake(&opts), Err(StoreError::NotATileset { .. })));
    }

    #[test]
    fn begin_bake_refuses_foreign_dirs_and_changed_options() {
        let dir = tempfile::tempdir().unwrap();
        fs::write(dir.path().join("notes.txt"), "mine").unwrap();
        let s = Store::new(dir.path());
        assert!(matches!(s.begin_bake(&serde_json::json!({})), Err(StoreError::NotATileset { .. })));

        let out = dir.path().join("ts");
        let s = Store::new(&out);
        let a = serde_json::json!({"max_error": 1.0, "levels": 4});
        assert!(!s.begin_bake(&a).unwrap());
        assert!(s.begin_bake(&a).unwrap());
        let b = serde_json::json!({"max_error": 2.0, "levels": 4});
        let err = s.begin_bake(&b).unwrap_err().to_string();
        assert!(err.contains("max_error: 1.0 → 2.0"), "{err}");
    }
}
