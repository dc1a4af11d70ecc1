//! The model bake: a standalone model (OBJ, STL, PLY through [`crate::model`]) → a *model
//! tileset*, the first paper's own setting (it baked the Stanford models).
//!
//! ```text
//! DIR/tileset.json             manifest: the terrain manifest's fields (format, bounds, levels,
//!                              totals, options, …) plus `"kind": "model"` and a `model` object
//!                              (file, encoding, cleanup counts, per-level resolution, cell,
//!                              count, measured errors); written last
//! DIR/index/0/0/0.json         the one node, 0/0/0, as in a terrain tileset
//! DIR/tiles/0/0/0/0.tsb        level 0: the model's mesh, quantized
//! DIR/tiles/0/0/0/{l}.tsb      level l = 1..K: the point cloud baked at resolution T_l
//! DIR/bake-options.json        the bake's options (as `bake` writes it)
//! ```
//!
//! The layout is a terrain tileset's with a single tile, so the same store, index, `inspect`,
//! `export` and HTTP paths serve it; the manifest's `kind` tells a client which it has
//! (terrain manifests carry no `kind`).
//!
//! # Levels
//!
//! Level `l ≥ 1` is baked by the 6-direction slicing (`lod::cpu`) on cubic cells of edge
//! `cell_l = L / T_l`, `L` the longest side of the model's bounding box and `T_l` the level's
//! resolution — the paper's framebuffer size T3 across the model, and its slice count T1 along
//! the longest axis. The grid is anchored at the bounding box's minimum corner.
//!
//! The default ladder is linear, `T_l = T · (K + 1 − l) / K` ([`ladder`]): with T = 80 and
//! K = 4, 80, 60, 40, 20. Why linear: a level's point count grows with the surface area over
//! `cell²`, i.e. with `T²`, and the first paper's Table 3 counts for the bunny (12,654 / 7,092 /
//! 3,191 / 800) stand almost exactly as 4² : 3² : 2² : 1² (15.8 : 8.9 : 4.0 : 1), so its
//! resolutions stood as 4 : 3 : 2 : 1. T = 80 is the finest resolution whose bunny count
//! matches the paper's finest level (12,832 points against 12,654); the others then land
//! within 3 % of the paper's without further tuning (see `docs/lod.md`, *Models*). `--resolutions` sets
//! any strictly decreasing list instead.
//!
//! # Errors (measured, world units)
//!
//! - level 0: `max`/`rms` are the distances between the file's vertices and their quantized
//!   positions (the bytes a client receives); `gap` is 0;
//! - point levels: as `lod::cpu::measure_points`, of the quantized points against the model's
//!   own mesh (not the quantized one): the distance from the points to the surface and the
//!   largest gap.
//!
//! Nothing is written until the model has been read, baked and encoded in memory, so a bad
//! model leaves `--out` untouched.

pub use crate::store::model_manifest::{ModelInfo, ModelLevel, ModelLevelTable, ModelManifest};

use std::path::Path;
use std::time::Instant;

use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use crate::codec::{self, Quantization};
use crate::geom::{Bounds, ErrorFigures, Mesh};
use crate::lod;
use crate::lod::PointBaker;
use crate::model::{self, FileType, MeshError, Model, ModelStats};
use crate::store::{IndexChunk, NodeEntry, NodeLevel, Store, StoreError, TilesetKind};
use crate::tiling::TileKey;

/// Default number of point levels below the mesh.
pub const DEFAULT_MODEL_LEVELS: u8 = 4;
/// Default resolution T of level 1 (cells across the model's longest side); see [`ladder`].
pub const DEFAULT_RESOLUTION: u32 = 80;
/// Finest resolution accepted: T² grows the points and the bake's memory.
pub const MAX_RESOLUTION: u32 = 4096;
/// Level 0 is quantized to a power-of-two step no larger than the longest side / 2^this.
pub const MESH_QUANT_BITS: i32 = 20;
/// Point positions are quantized to this fraction of the level's cell edge (as `bake`).
pub const POINT_STEPS_PER_CELL: u32 = crate::bake::POINT_STEPS_PER_CELL;
/// The one node a model tileset has.
pub const MODEL_TILE: TileKey = TileKey::new(0, 0, 0);

#[derive(Debug, thiserror::Error)]
pub enum ModelBakeError {
    #[error(
        "bake-model: --resolution {first} is too small for {levels} distinct levels (--levels); raise \
         --resolution to at least {levels} or lower --levels"
    )]
    Ladder { first: u32, levels: u8 },
    #[error("bake-model: at most {max} point levels, got {got}", max = crate::bake::MAX_LEVELS)]
    TooManyLevels { got: usize },
    #[error("bake-model: resolution {0} is outside 1..={MAX_RESOLUTION}")]
    Resolution(u32),
    #[error(
        "bake-model: resolutions must decrease level by level (each level coarser than the one before), got \
         {0:?}"
    )]
    NotDecreasing(Vec<u32>),
    #[error("bake-model: {file}: the model has no valid bounds")]
    NoBounds { file: String },
    #[error(
        "bake-model: {file}: coordinates reach {reach:e} (box {min:?}..{max:?}), beyond the supported \
         ±{MAX_MODEL_COORDINATE:e}"
    )]
    TooLarge { file: String, reach: f64, min: [f64; 3], max: [f64; 3] },
    #[error("bake-model: {file}: the model has zero extent")]
    ZeroExtent { file: String },
    #[error(
        "bake-model: {file}: the model is {longest:e} wide but lies {reach:e} from the origin (more than 1e9 \
         times its size); move it nearer the origin"
    )]
    FarFromOrigin { file: String, longest: f64, reach: f64 },
    #[error(transparent)]
    Mesh(#[from] MeshError),
    #[error("bake-model: {file}: level {level}: {source}")]
    Codec { file: String, level: u8, source: codec::CodecError },
    #[error(transparent)]
    Store(#[from] StoreError),
    // "bake: " as when this error came through the terrain bake's error type.
    #[error("bake-model: {file}: bake: {source}")]
    Points { file: String, source: crate::lod::BakerError },
}

/// Options of a model bake: the resolution T of each point level, finest first.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct ModelBakeOptions {
    pub resolutions: Vec<u32>,
    /// Read the file as this type instead of going by its extension or content.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub file_type: Option<FileType>,
}

impl Default for ModelBakeOptions {
    fn default() -> Self {
        Self {
            resolutions: ladder(DEFAULT_RESOLUTION, DEFAULT_MODEL_LEVELS).unwrap_or_default(),
            file_type: None,
        }
    }
}

/// The default ladder of `levels` resolutions from `first` down: level `l` of `K` gets
/// `T_l = round(first · (K + 1 − l) / K)`, so `first` = 64 and K = 4 give 64, 48, 32, 16 (see
/// the module doc for why). Errors when two levels would get the same resolution.
pub fn ladder(first: u32, levels: u8) -> Result<Vec<u32>, ModelBakeError> {
    let k = u64::from(levels);
    let out: Vec<u32> =
        (1..=k).map(|l| ((u64::from(first) * (k + 1 - l) + k / 2) / k.max(1)) as u32).collect();
    if out.windows(2).any(|w| w[1] >= w[0]) || out.contains(&0) {
        return Err(ModelBakeError::Ladder { first, levels });
    }
    Ok(out)
}

/// Validates options before anything is read or written.
pub fn check_options(opts: &ModelBakeOptions) -> Result<(), ModelBakeError> {
    let r = &opts.resolutions;
    if r.len() > usize::from(crate::bake::MAX_LEVELS) {
        return Err(ModelBakeError::TooManyLevels { got: r.len() });
    }
    if let Some(t) = r.iter().find(|&&t| t == 0 || t > MAX_RESOLUTION) {
        return Err(ModelBakeError::Resolution(*t));
    }
    if r.windows(2).any(|w| w[1] >= w[0]) {
        return Err(ModelBakeError::NotDecreasing(r.clone()));
    }
    Ok(())
}

/// What a model bake did.
#[derive(Debug, Clone, Serialize)]
pub struct ModelBakeSummary {
    pub file: String,
    pub encoding: String,
    pub stats: ModelStats,
    pub bounds: Bounds,
    pub levels: Vec<ModelLevel>,
    /// Reading and cleaning the model.
    pub read_seconds: f64,
    /// Baking, measuring and encoding every level.
    pub bake_seconds: f64,
    /// Everything, writing included.
    pub seconds: f64,
    pub resumed: bool,
    /// What baked the point levels: "cpu" or "gpu: <adapter>".
    pub point_baker: String,
}

/// What `bake-model` prints when it is done: what was read and cleaned, what was baked where,
/// the point baker and the level table; no trailing newline.
pub struct ModelBakeReport<'a> {
    pub summary: &'a ModelBakeSummary,
    /// The tileset directory baked into.
    pub out: &'a Path,
}

impl std::fmt::Display for ModelBakeReport<'_> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let s = self.summary;
        let st = &s.stats;
        writeln!(
            f,
            "{} ({}): {} faces → {} triangles read, {} degenerate skipped; {} vertices read, {} unreferenced \
             dropped, {} normals from the file",
            s.file,
            s.encoding,
            st.faces,
            st.triangles_read,
            st.degenerate,
            st.vertices_read,
            st.unreferenced,
            st.normals_from_file
        )?;
        writeln!(
            f,
            "baked {} levels into {}{} in {:.3} s (read {:.3} s, bake {:.3} s); bounds {:?} – {:?}",
            s.levels.len(),
            self.out.display(),
            if s.resumed { " (same options: rewritten)" } else { "" },
            s.seconds,
            s.read_seconds,
            s.bake_seconds,
            s.bounds.min.to_array(),
            s.bounds.max.to_array()
        )?;
        writeln!(f, "point levels baked by {}", s.point_baker)?;
        write!(f, "{}", ModelLevelTable(&s.levels))
    }
}

/// A baked level in memory, encoded.
struct BakedLevel {
    info: ModelLevel,
    blob: Vec<u8>,
    checksum: u32,
}

/// A model file read and cleaned, ready for [`bake_model`].
#[derive(Debug, Clone)]
pub struct ModelFile {
    pub model: Model,
    pub source: SourceFile,
    /// Reading and cleaning the model.
    pub read_seconds: f64,
}

/// Reads and cleans the model at `path` (its type from `file_type`, else the extension, else
/// sniffed). Separate from baking so a caller can refuse a bad file before it opens a GPU.
pub fn read_model_file(path: &Path, file_type: Option<FileType>) -> Result<ModelFile, ModelBakeError> {
    let t0 = Instant::now();
    let bytes = crate::model::read_file(path, crate::model::MAX_MODEL_FILE_BYTES)?;
    let shown = path.display().to_string();
    let ty = file_type.or_else(|| {
        match path.extension().map(|e| e.to_string_lossy().to_ascii_lowercase()).as_deref() {
            Some("obj") => Some(FileType::Obj),
            Some("stl") => Some(FileType::Stl),
            Some("ply") => Some(FileType::Ply),
            _ => None,
        }
    });
    let model = model::parse(&bytes, &shown, ty)?;
    let name = path.file_name().map_or_else(|| shown.clone(), |n| n.to_string_lossy().into_owned());
    let source =
        SourceFile { name, bytes: bytes.len() as u64, crc32: format!("{:08x}", crc32fast::hash(&bytes)) };
    Ok(ModelFile { model, source, read_seconds: t0.elapsed().as_secs_f64() })
}

/// The model file as the manifest and the resume check name it.
#[derive(Debug, Clone)]
pub struct SourceFile {
    pub name: String,
    pub bytes: u64,
    pub crc32: String,
}

/// Largest |coordinate| of a model accepted by [`bake_model`] (model units).
pub const MAX_MODEL_COORDINATE: f64 = 1e12;

/// Bakes a model read by [`read_model_file`] into `store`: every level in memory first, then
/// blobs, index and manifest (last), so a model that cannot be baked leaves `store` untouched.
/// An earlier bake of the same file with the same options is overwritten with identical bytes;
/// one with other options, or a foreign directory, is refused. The summary's times include the
/// read.
#[expect(clippy::too_many_lines, reason = "one bake, step by step; the manifest is built in `store`")]
pub fn bake_model(
    file: &ModelFile,
    opts: &ModelBakeOptions,
    baker: &PointBaker,
    store: &Store,
) -> Result<ModelBakeSummary, ModelBakeError> {
    check_options(opts)?;
    let t0 = Instant::now();
    let (model, source) = (&file.model, &file.source);
    let mesh = &model.mesh;
    let raw = Bounds::of_points(&mesh.positions);
    if !raw.is_valid() {
        return Err(ModelBakeError::NoBounds { file: source.name.clone() });
    }
    let reach = raw.min.abs().max(raw.max.abs()).max_element();
    if reach.is_nan() || reach > MAX_MODEL_COORDINATE {
        return Err(ModelBakeError::TooLarge {
            file: source.name.clone(),
            reach,
            min: raw.min.to_array(),
            max: raw.max.to_array(),
        });
    }
    let longest = raw.size().max_element();
    if !(longest > 0.0 && longest.is_finite()) {
        return Err(ModelBakeError::ZeroExtent { file: source.name.clone() });
    }
    // Relative to its own size a model may sit far from the origin, but not so far that the
    // quantization grid (2^-MESH_QUANT_BITS of the extent) loses its steps in f64.
    if reach / longest > 1e9 {
        return Err(ModelBakeError::FarFromOrigin { file: source.name.clone(), longest, reach });
    }
    let codec_err = |level: u8| {
        let file = source.name.clone();
        move |source| ModelBakeError::Codec { file, level, source }
    };

    // Level 0: positions on a power-of-two grid, the box's minimum snapped to it.
    let step = 2f64.powi((longest.log2().floor() as i32) - MESH_QUANT_BITS);
    let mut bounds = raw;
    for a in 0..3 {
        bounds.min[a] = (raw.min[a] / step).floor() * step;
    }
    let q0 = Quantization { xy_step: step, z_step: step };
    let quantized = Mesh {
        positions: codec::quantize_positions(&mesh.positions, &bounds, q0),
        triangles: mesh.triangles.clone(),
    };
    let bounds = codec::quantized_bounds(&bounds, &quantized.positions, q0);
    let mesh_errors = displacement(&mesh.positions, &quantized.positions);
    let blob0 =
        codec::encode_mesh(MODEL_TILE, 0, &bounds, q0, &quantized, mesh_errors).map_err(codec_err(0))?;
    drop(quantized);
    let level0 = BakedLevel {
        checksum: codec::decode_header(&blob0).map_err(codec_err(0))?.checksum,
        info: ModelLevel {
            level: 0,
            kind: crate::codec::Kind::Mesh,
            resolution: None,
            cell: None,
            quant_step: step,
            count: mesh.positions.len() as u32,
            triangles: mesh.triangles.len() as u32,
            occupied: None,
            filled: None,
            errors: mesh_errors,
            bytes: blob0.len() as u64,
            stored: true,
        },
        blob: blob0,
    };

    // Point levels: all baked by `baker` at once, then measured and encoded in parallel; each is
    // deterministic on its own.
    let origin = raw.min.to_array();
    let grids: Vec<([f64; 3], f64)> =
        opts.resolutions.iter().map(|&t| (origin, longest / f64::from(t))).collect();
    let clouds = baker
        .bake_grids(mesh, &grids)
        .map_err(|e| ModelBakeError::Points { file: source.name.clone(), source: e })?;
    let points: Vec<BakedLevel> = clouds
        .into_par_iter()
        .zip(opts.resolutions.par_iter())
        .enumerate()
        .map(|(i, ((mut pc, stats), &t))| {
            let level = i as u8 + 1;
            let cell = longest / f64::from(t);
            let (occupied, filled) = (stats.occupied as u64, stats.filled as u64);
            let step = cell / f64::from(POINT_STEPS_PER_CELL);
            let q = Quantization { xy_step: step, z_step: step };
            // Onto the grid and into the box the header states (see `codec::snap_positions`).
            pc.positions = codec::snap_positions(&pc.positions, &bounds, q).map_err(codec_err(level))?;
            let errors = lod::cpu::measure_points(mesh, &pc, cell, lod::MODEL_FOOTPRINT_HALF);
            let blob =
                codec::encode_points(MODEL_TILE, level, &bounds, q, &pc, errors).map_err(codec_err(level))?;
            Ok(BakedLevel {
                checksum: codec::decode_header(&blob).map_err(codec_err(level))?.checksum,
                info: ModelLevel {
                    level,
                    kind: crate::codec::Kind::Points,
                    resolution: Some(t),
                    cell: Some(cell),
                    quant_step: step,
                    count: pc.positions.len() as u32,
                    triangles: 0,
                    occupied: Some(occupied),
                    filled: Some(filled),
                    errors,
                    bytes: blob.len() as u64,
                    stored: true,
                },
                blob,
            })
        })
        .collect::<Result<_, ModelBakeError>>()?;
    let bake_seconds = t0.elapsed().as_secs_f64();

    let mut levels: Vec<BakedLevel> = std::iter::once(level0).chain(points).collect();
    let options_json = serde_json::json!({
        "kind": TilesetKind::Model,
        "resolutions": opts.resolutions,
        "source": { "file": source.name, "bytes": source.bytes, "crc32": source.crc32 },
        "format_version": codec::FORMAT_VERSION,
    });
    let resumed = store.begin_bake(&options_json)?;
    // Only the levels that pay are stored; points first, the mesh last, as `bake` does.
    let blobs = levels
        .iter()
        .map(|l| {
            let nl = NodeLevel {
                level: l.info.level,
                errors: l.info.errors,
                count: l.info.count,
                triangles: l.info.triangles,
                bytes: l.info.bytes,
                checksum: l.checksum,
            };
            (nl, l.blob.clone())
        })
        .collect();
    let (node_levels, _) = super::node::write_paying(store, MODEL_TILE, blobs)?;
    for l in &mut levels {
        l.info.stored = node_levels.iter().any(|n| n.level == l.info.level);
    }
    store.write_chunk(&IndexChunk {
        root: MODEL_TILE,
        nodes: vec![NodeEntry { key: MODEL_TILE, bounds, levels: node_levels.clone() }],
    })?;
    let infos: Vec<ModelLevel> = levels.into_iter().map(|l| l.info).collect();
    let s = model.stats;
    let info = ModelInfo {
        file: source.name.clone(),
        encoding: model.encoding.name().into(),
        file_bytes: source.bytes,
        file_crc32: source.crc32.clone(),
        vertices: mesh.positions.len() as u32,
        triangles: mesh.triangles.len() as u32,
        faces_read: s.faces as u64,
        triangles_read: s.triangles_read as u64,
        degenerate_skipped: s.degenerate as u64,
        vertices_read: s.vertices_read as u64,
        unreferenced_dropped: s.unreferenced as u64,
        normals_from_file: s.normals_from_file as u64,
        levels: infos.clone(),
    };
    let manifest =
        ModelManifest::new(info, bounds, &node_levels, POINT_STEPS_PER_CELL, options_json, baker.describe());
    store.finish_bake_as(&manifest)?;
    Ok(ModelBakeSummary {
        file: source.name.clone(),
        encoding: model.encoding.name().into(),
        stats: s,
        bounds,
        levels: infos,
        read_seconds: file.read_seconds,
        bake_seconds,
        seconds: t0.elapsed().as_secs_f64() + file.read_seconds,
        resumed,
        point_baker: baker.describe(),
    })
}

/// Reads a model tileset's manifest; errors when the directory holds no model tileset.
pub fn read_manifest(store: &Store) -> Result<ModelManifest, ModelBakeError> {
    Ok(store.model_manifest()?)
}

/// Max and RMS distance between corresponding positions; gap 0.
fn displacement(a: &[[f64; 3]], b: &[[f64; 3]]) -> ErrorFigures {
    let mut max = 0.0f64;
    let mut sum = 0.0;
    for (p, q) in a.iter().zip(b) {
        let d2 = (0..3).map(|i| (p[i] - q[i]) * (p[i] - q[i])).sum::<f64>();
        max = max.max(d2);
        sum += d2;
    }
    ErrorFigures { max: max.sqrt(), rms: (sum / a.len().max(1) as f64).sqrt(), gap: 0.0 }
}

#[cfg(test)]
#[allow(clippy::float_cmp)]
mod tests {
    use super::*;

    const TET: &str = "v 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 1\nf 1 3 2\nf 1 2 4\nf 1 4 3\nf 2 3 4\n";

    #[test]
    fn options() {
        assert_eq!(ladder(64, 4).unwrap(), vec![64, 48, 32, 16]);
        assert_eq!(ladder(100, 3).unwrap(), vec![100, 67, 33]);
        assert_eq!(ladder(4, 4).unwrap(), vec![4, 3, 2, 1]);
        assert_eq!(ladder(64, 1).unwrap(), vec![64]);
        assert!(ladder(64, 0).unwrap().is_empty());
        assert!(ladder(3, 4).unwrap_err().to_string().contains("too small for 4 distinct levels"));
        assert_eq!(ModelBakeOptions::default().resolutions, vec![80, 60, 40, 20]);
        let bad = |r: Vec<u32>| check_options(&ModelBakeOptions { resolutions: r, file_type: None }).is_err();
        assert!(bad(vec![32, 64]));
        assert!(bad(vec![32, 32]));
        assert!(bad(vec![0]));
        assert!(bad(vec![MAX_RESOLUTION + 1]));
        assert!(!bad(vec![64, 45, 32, 16]));
        assert!(!bad(vec![]));
    }

    #[test]
    fn tetrahedron_bakes_with_measured_errors_and_a_self_describing_manifest() {
        let dir = tempfile::tempdir().unwrap();
        let store = Store::new(&dir.path().join("ts"));
        let model = model::parse(TET.as_bytes(), "tet.obj", None).unwrap();
        let source = SourceFile { name: "tet.obj".into(), bytes: TET.len() as u64, crc32: "0".into() };
        let file = ModelFile { model, source, read_seconds: 0.0 };
        let opts = ModelBakeOptions { resolutions: vec![32, 16, 8], file_type: None };
        let s = bake_model(&file, &opts, &PointBaker::Cpu, &store).unwrap();
        assert_eq!(s.levels.len(), 4);
        assert_eq!((s.levels[0].count, s.levels[0].triangles), (4, 4));
        // Unit coordinates sit on the quantization grid exactly.
        assert_eq!(s.levels[0].errors, ErrorFigures::default());
        for w in s.levels[1..].windows(2) {
            assert!(w[1].count < w[0].count, "{:?}", s.levels);
        }
        for l in &s.levels[1..] {
            let cell = l.cell.unwrap();
            // Points lie within a cell of the surface and leave no gap wider than a few cells.
            assert!(l.errors.max > 0.0 && l.errors.max <= cell * 0.9, "{l:?}");
            assert!(l.errors.gap > 0.0 && l.errors.gap <= cell * 2.0, "{l:?}");
        }
        assert_eq!(store.manifest_kind().unwrap(), TilesetKind::Model);
        let m = read_manifest(&store).unwrap();
        assert_eq!(m.model.levels, s.levels);
        assert_eq!(m.tileset.depth, 0);
        // The generic reader and the index see the one node.
        assert_eq!(store.manifest().unwrap().totals.len(), 4);
        // Every point level has more points than the tetrahedron's 4 vertices: none pays, so
        // the node stores its mesh alone and each point level has its `unpaid` marker.
        let node = store.node(MODEL_TILE).unwrap().unwrap();
        assert_eq!(node.levels.iter().map(|l| l.level).collect::<Vec<_>>(), vec![0]);
        assert!(s.levels[0].stored && s.levels[1..].iter().all(|l| !l.stored && l.count > 4));
        for info in &s.levels {
            match store.read_blob(MODEL_TILE, info.level).unwrap() {
                Some(bytes) => {
                    let blob = codec::decode(&bytes).unwrap();
                    assert_eq!(blob.header.vertex_count, info.count);
                    assert_eq!(blob.header.errors, info.errors);
                }
                None => assert!(!info.stored && store.is_unpaid(MODEL_TILE, info.level).unwrap(), "{info:?}"),
            }
        }
        assert_eq!(store.manifest().unwrap().totals[1].tiles, 0);
    }

    /// Which levels pay: each kept level is cheaper in both primitives and bytes than every
    /// finer kept one; a level as dear as a finer one in either measure is left out, and a
    /// cheaper level after one left out is judged against the kept ones only.
    #[test]
    fn levels_pay_only_when_cheaper_in_primitives_and_bytes() {
        let l = |count: u32, bytes: u64| NodeLevel {
            level: 0,
            errors: ErrorFigures::default(),
            count,
            triangles: 0,
            bytes,
            checksum: 0,
        };
        let pays = crate::store::levels_that_pay;
        assert_eq!(pays(&[l(100, 1000)]), vec![true]);
        assert_eq!(pays(&[l(100, 1000), l(50, 500), l(20, 200)]), vec![true; 3]);
        // More points than the mesh has vertices; fewer points but more bytes; equal cost.
        assert_eq!(
            pays(&[l(100, 1000), l(150, 900), l(90, 1100), l(100, 1000)]),
            vec![true, false, false, false]
        );
        // Judged against the kept levels: 60 < 100 although the left-out 150 is dearer still.
        assert_eq!(
            pays(&[l(100, 1000), l(150, 1500), l(60, 600), l(70, 500)]),
            vec![true, false, true, false]
        );
        assert!(pays(&[]).is_empty());
    }

    #[test]
    fn quantized_level0_error_is_measured() {
        let text = "v 0.1 0.2 0.3\nv 1.7 0.01 0\nv 0 1.3 0\nf 1 2 3\n";
        let model = model::parse(text.as_bytes(), "tri.obj", None).unwrap();
        let dir = tempfile::tempdir().unwrap();
        let store = Store::new(dir.path());
        let source = SourceFile { name: "tri.obj".into(), bytes: 0, crc32: "0".into() };
        let s = bake_model(
            &ModelFile { model, source, read_seconds: 0.0 },
            &ModelBakeOptions { resolutions: vec![8], file_type: None },
            &PointBaker::Cpu,
            &store,
        )
        .unwrap();
        let e = s.levels[0].errors;
        let step = s.levels[0].quant_step;
        assert!(e.max > 0.0 && e.max <= step * 3f64.sqrt() / 2.0, "{e:?} step {step}");
        assert!(e.rms <= e.max);
    }
}
