//! The globe terrain's 3D Tiles form as static files (`DIR/terrain/3dtiles/`), so a CDN can host
//! what the server sends under `/tilesets/{name}/terrain/3dtiles/`: made from the baked
//! quantized-mesh tiles (`terrain/{z}/{x}/{y}.terrain`, `layer.json`, `stats.json`) by the very
//! functions the server uses, so the files are the served bytes. Runs after the quantized-mesh
//! stage; `tileset.json` is written last, so a store with it holds every GLB and subtree.

use std::collections::HashMap;
use std::sync::atomic::{AtomicU64, Ordering};

use rayon::prelude::*;

use super::qmesh::{TERRAIN_DIR, tile_rel};
use crate::formats::qmesh::codec::{Header, QmError, decode};
use crate::formats::qmesh::grid::{TileId, zoom_error};
use crate::formats::qmesh::tiles3d::{self, Availability, Implicit, Terrain3dError};
use crate::store::{Store, StoreError};

/// Where the 3D Tiles form goes, under the store.
pub const TILES3D_DIR: &str = "terrain/3dtiles";
/// A baked tile or document larger than this is refused as damaged (as the server does).
const MAX_STORED_BYTES: u64 = 4 << 20;

/// Why the 3D Tiles form cannot be written.
#[derive(Debug, thiserror::Error)]
pub enum Terrain3dBakeError {
    #[error(
        "3D Tiles terrain: the store has no baked terrain ({TERRAIN_DIR}/layer.json): bake with --terrain first"
    )]
    NoTerrain,
    #[error("3D Tiles terrain: {TERRAIN_DIR}/layer.json is not JSON: {0}")]
    Layer(#[source] serde_json::Error),
    #[error("3D Tiles terrain: tile {tile} is missing from the store")]
    Missing { tile: TileId },
    #[error("3D Tiles terrain: tile {tile}: {source}")]
    Tile { tile: TileId, source: QmError },
    #[error(transparent)]
    Convert(#[from] Terrain3dError),
    #[error(transparent)]
    Store(#[from] StoreError),
}

/// What [`write_terrain_3dtiles`] wrote.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct Written {
    pub glbs: u64,
    pub subtrees: u64,
    pub bytes: u64,
}

/// Zoom 0's error bound of the store's terrain (its `stats.json`; CesiumJS's default when the
/// figures cannot be read).
pub fn level0_error(store: &Store) -> f64 {
    store
        .read_file_within(&format!("{TERRAIN_DIR}/stats.json"), 2..=MAX_STORED_BYTES)
        .ok()
        .flatten()
        .and_then(|b| serde_json::from_slice::<serde_json::Value>(&b).ok())
        .as_ref()
        .and_then(tiles3d::level0_error_of_stats)
        .unwrap_or_else(|| zoom_error(0, 1.0))
}

/// Writes the 3D Tiles form of the store's baked terrain: a GLB per tile, a subtree per subtree
/// root, then `tileset.json`.
pub fn write_terrain_3dtiles(store: &Store) -> Result<Written, Terrain3dBakeError> {
    let layer = store
        .read_file_within(&format!("{TERRAIN_DIR}/layer.json"), 2..=MAX_STORED_BYTES)?
        .ok_or(Terrain3dBakeError::NoTerrain)?;
    let layer: serde_json::Value = serde_json::from_slice(&layer).map_err(Terrain3dBakeError::Layer)?;
    let avail = Availability::from_layer(&layer)?;
    let mut ids: Vec<TileId> = Vec::new();
    for (z, ranges) in avail.ranges.iter().enumerate() {
        for r in ranges {
            for y in r.y0..=r.y1 {
                for x in r.x0..=r.x1 {
                    ids.push(TileId { z: z as u8, x, y });
                }
            }
        }
    }
    ids.sort_unstable();
    ids.dedup();
    let bytes = AtomicU64::new(0);
    let headers: HashMap<TileId, Header> = ids
        .par_iter()
        .map(|&id| {
            let b = store.read_file_within(&tile_rel(id), 88..=MAX_STORED_BYTES)?;
            let b = b.ok_or(Terrain3dBakeError::Missing { tile: id })?;
            let t = decode(&b).map_err(|source| Terrain3dBakeError::Tile { tile: id, source })?;
            let glb = tiles3d::glb(&t, id)?;
            store.write_file(&format!("{TILES3D_DIR}/{}", tiles3d::glb_rel(id)), &glb)?;
            bytes.fetch_add(glb.len() as u64, Ordering::Relaxed);
            Ok((id, t.header))
        })
        .collect::<Result<_, Terrain3dBakeError>>()?;
    let roots: Vec<Implicit> =
        ids.iter().map(|&id| Implicit::of(id)).filter(|i| i.is_subtree_root()).collect();
    roots.par_iter().try_for_each(|&root| -> Result<(), Terrain3dBakeError> {
        let tiles = tiles3d::subtree_tiles(&avail, root)?;
        let heads: Vec<Header> = tiles
            .iter()
            .map(|t| headers.get(t).copied().ok_or(Terrain3dBakeError::Missing { tile: *t }))
            .collect::<Result<_, _>>()?;
        let sub = tiles3d::subtree(&avail, root, &heads)?;
        store.write_file(&format!("{TILES3D_DIR}/{}", tiles3d::subtree_rel(root)), &sub)?;
        bytes.fetch_add(sub.len() as u64, Ordering::Relaxed);
        Ok(())
    })?;
    let tileset = tiles3d::tileset_from_layer(&layer, level0_error(store))?;
    store.write_file(&format!("{TILES3D_DIR}/tileset.json"), &tileset)?;
    Ok(Written {
        glbs: ids.len() as u64,
        subtrees: roots.len() as u64,
        bytes: bytes.load(Ordering::Relaxed) + tileset.len() as u64,
    })
}
