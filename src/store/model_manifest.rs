//! A model tileset's manifest (`bake-model`): every field of a terrain [`Manifest`] plus
//! `kind` = `"model"` and a `model` object (the file, its cleanup counts and the levels as
//! baked), and the per-level table `bake-model` and `inspect` print.

use serde::{Deserialize, Serialize};

use super::{
    LevelSpec, LevelTotals, MANIFEST_FORMAT, MANIFEST_VERSION, Manifest, NodeLevel, SUBTREE_LEVELS,
    SourceInfo, Store, StoreError, TilesetKind, content_version,
};
use crate::geom::{Bounds, ErrorFigures};
use crate::raster::Georef;

/// One level of a model bake, as reported and stored in the manifest.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ModelLevel {
    pub level: u8,
    pub kind: crate::codec::Kind,
    /// Points: the resolution T (cells across the longest side).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub resolution: Option<u32>,
    /// Points: the cell edge, world units.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub cell: Option<f64>,
    /// Quantization step of the stored positions, world units.
    pub quant_step: f64,
    /// Vertices (mesh) or points.
    pub count: u32,
    /// Triangles (mesh), 0 for points.
    pub triangles: u32,
    /// Points: cells hit by fragments, and cells added by hole filling (count = their sum).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub occupied: Option<u64>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub filled: Option<u64>,
    pub errors: ErrorFigures,
    pub bytes: u64,
    /// False for a level that was baked and did not pay (`store::levels_that_pay`): it has no
    /// blob and the index does not list it. Absent in manifests from before levels had to pay.
    #[serde(default = "stored_default")]
    pub stored: bool,
}

fn stored_default() -> bool {
    true
}

/// The per-level table `bake-model` and `inspect` print for a model tileset: one header line
/// and one line per level, without a trailing newline.
pub struct ModelLevelTable<'a>(pub &'a [ModelLevel]);

impl std::fmt::Display for ModelLevelTable<'_> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "{:>5}  {:>6}  {:>5}  {:>10}  {:>9}  {:>9}  {:>9}  {:>10}  {:>10}  {:>10}  {:>6}",
            "level", "kind", "T", "cell", "count", "triangles", "bytes", "max err", "rms", "gap", "stored"
        )?;
        for l in self.0 {
            write!(
                f,
                "\n{:>5}  {:>6}  {:>5}  {:>10}  {:>9}  {:>9}  {:>9}  {:>10.3e}  {:>10.3e}  {:>10.3e}  {:>6}",
                l.level,
                l.kind,
                l.resolution.map_or_else(|| "-".to_owned(), |t| t.to_string()),
                l.cell.map_or_else(|| "-".to_owned(), |c| format!("{c:.3e}")),
                l.count,
                l.triangles,
                l.bytes,
                l.errors.max,
                l.errors.rms,
                l.errors.gap,
                if l.stored { "yes" } else { "no" }
            )?;
        }
        if self.0.iter().any(|l| !l.stored) {
            write!(f, "\n(a level not stored would cost as many points or bytes as a finer one)")?;
        }
        Ok(())
    }
}

/// The `model` object of a model tileset's manifest.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ModelInfo {
    pub file: String,
    pub encoding: String,
    /// Size and CRC-32 of the model file.
    pub file_bytes: u64,
    pub file_crc32: String,
    pub vertices: u32,
    pub triangles: u32,
    pub faces_read: u64,
    pub triangles_read: u64,
    pub degenerate_skipped: u64,
    pub vertices_read: u64,
    pub unreferenced_dropped: u64,
    pub normals_from_file: u64,
    pub levels: Vec<ModelLevel>,
}

/// A model tileset's manifest: every field of a terrain [`Manifest`] (so generic readers work)
/// plus `kind` = [`TilesetKind::Model`] and `model`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ModelManifest {
    pub kind: TilesetKind,
    #[serde(flatten)]
    pub tileset: Manifest,
    pub model: ModelInfo,
}

impl ModelManifest {
    /// The manifest of a model tileset with one node whose levels are `node_levels` (as its
    /// index entry holds them, level 0 first) and `model.levels`: totals, level table and
    /// content version follow from them; the frame is the identity (model coordinates are world
    /// coordinates) and the raster fields are 0. Point levels are quantized to
    /// `1 / precision_per_cell` of their cell.
    #[must_use]
    pub fn new(
        model: ModelInfo,
        bounds: Bounds,
        node_levels: &[NodeLevel],
        precision_per_cell: u32,
        options: serde_json::Value,
        point_baker: String,
    ) -> Self {
        // One row per level of the ladder, empty for a level the node does not store.
        let totals = model
            .levels
            .iter()
            .map(|ml| {
                let mut t = LevelTotals::default();
                if let Some(l) = node_levels.iter().find(|l| l.level == ml.level) {
                    t.add(l);
                }
                t
            })
            .collect();
        let levels = model
            .levels
            .iter()
            .map(|l| LevelSpec {
                level: l.level,
                kind: l.kind,
                max_error: None,
                cell_leaf_cells: None,
                texture_size: l.resolution,
                precision_per_cell: l.resolution.map(|_| precision_per_cell),
                footprint_half: l.resolution.map(|_| crate::lod::MODEL_FOOTPRINT_HALF),
            })
            .collect();
        Self {
            kind: TilesetKind::Model,
            tileset: Manifest {
                format: MANIFEST_FORMAT.into(),
                version: MANIFEST_VERSION,
                content_version: content_version(node_levels),
                source: SourceInfo {
                    file: model.file.clone(),
                    format: model.encoding.clone(),
                    width: 0,
                    height: 0,
                    nodata_filled: 0,
                },
                frame: Georef::default(),
                tile_size: 0,
                depth: 0,
                subtree_levels: SUBTREE_LEVELS,
                bounds,
                levels,
                totals,
                options,
                point_baker,
            },
            model,
        }
    }
}

impl Store {
    /// Reads a model tileset's manifest; errors when the directory holds another kind.
    pub fn model_manifest(&self) -> Result<ModelManifest, StoreError> {
        let kind = self.manifest_kind()?;
        if kind != TilesetKind::Model {
            return Err(StoreError::Invalid {
                path: self.manifest_path(),
                message: format!("holds a {kind} tileset, not a model tileset"),
            });
        }
        self.manifest()?;
        self.manifest_as()
    }
}
