//! The tileset JSON of one index chunk ([`chunk_tileset`]): the chunk's nodes as tiles, the
//! subtrees below the chunk as external tilesets, so no JSON grows with the dataset; and the
//! GLB of a stored (tile, level) as that JSON lists it ([`tile_glb`]).

use serde::Deserialize;
use serde_json::{Value, json};

use super::border::BorderFans;
use super::glb::{GENERATOR, glb_and_normals, mesh_skirt_depth};
use super::placement::{Anchor, Placement};
use super::{GlbCompression, Tiles3dError};
use crate::codec::{Blob, BlobHeader, Kind};
use crate::geom::{Bounds, ErrorFigures};
use crate::store::{IndexChunk, LevelSpec, Manifest, NodeEntry, NodeLevel, SUBTREE_LEVELS, TilesetKind};
use crate::tiling::{Pyramid, TileKey};

/// What the tileset JSON of any chunk needs to know about the tileset.
#[derive(Debug, Clone)]
pub struct TilesetInfo {
    pub name: String,
    pub kind: TilesetKind,
    pub manifest: Manifest,
    pub place: Placement,
    /// Terrain: the quadtree (which children a node has, and where a node lies before it is
    /// baked). None for models (one node).
    pub pyramid: Option<Pyramid>,
    /// Per level: the distance between neighbouring points at leaf resolution (models: the
    /// level's cell), for clients that size point splats.
    pub model_cells: Vec<Option<f64>>,
    /// Appended to every URI (`?v=<content version>` when served, empty when exported).
    pub query: String,
    /// An on-demand tileset not fully baked: nodes not baked yet are listed with their mesh
    /// level only and its error bound as the error (`extras.terrastream.provisional`).
    pub provisional: bool,
    /// How the GLBs are compressed ([`tile_glb`]); `none` unless asked for.
    pub glb: GlbCompression,
}

impl TilesetInfo {
    /// The info of a tileset from its manifest (and, for models, the manifest's `model.levels`
    /// cells).
    #[must_use]
    pub fn new(name: &str, kind: TilesetKind, manifest: Manifest, place: Placement, query: String) -> Self {
        let pyramid = match kind {
            TilesetKind::Terrain => {
                Pyramid::new(manifest.source.width, manifest.source.height, manifest.tile_size).ok()
            }
            TilesetKind::Model => None,
        };
        Self {
            name: name.to_owned(),
            kind,
            model_cells: Vec::new(),
            manifest,
            place,
            pyramid,
            query,
            provisional: false,
            glb: GlbCompression::None,
        }
    }

    /// The info of a tileset from its manifest as JSON (a terrain or model manifest, or an
    /// on-demand tileset's provisional one, which says `"on_demand": true`).
    pub fn from_manifest_json(
        name: &str,
        bytes: &[u8],
        anchor: Option<Anchor>,
        query: String,
    ) -> Result<Self, Tiles3dError> {
        let v: Value = serde_json::from_slice(bytes).map_err(Tiles3dError::Manifest)?;
        let kind = match v.get("kind") {
            None => TilesetKind::Terrain,
            Some(k) => TilesetKind::deserialize(k).map_err(|_| Tiles3dError::ManifestKind(k.clone()))?,
        };
        let manifest = Manifest::deserialize(&v).map_err(Tiles3dError::Manifest)?;
        let place = Placement::of(&manifest, kind, anchor)?;
        let mut info = Self::new(name, kind, manifest, place, query);
        info.provisional = v.get("on_demand") == Some(&Value::Bool(true));
        if let Some(levels) = v.pointer("/model/levels").and_then(Value::as_array) {
            info.model_cells = vec![None; info.manifest.levels.len().max(levels.len())];
            for l in levels {
                if let (Some(i), Some(c)) =
                    (l.get("level").and_then(Value::as_u64), l.get("cell").and_then(Value::as_f64))
                    && let Some(slot) = info.model_cells.get_mut(i as usize)
                {
                    *slot = Some(c);
                }
            }
        }
        Ok(info)
    }

    fn children(&self, key: TileKey) -> Vec<TileKey> {
        self.pyramid.map(|p| p.children(key)).unwrap_or_default()
    }

    /// World box of a node before it is baked: its samples' extent, the dataset's height range.
    pub(crate) fn planned_bounds(&self, key: TileKey) -> Bounds {
        let m = &self.manifest;
        let Some(p) = self.pyramid else { return m.bounds };
        let s = p.span(key);
        let f = &m.frame;
        let xs = [f.x0 + f64::from(s.col0) * f.dx, f.x0 + f64::from(s.col1) * f.dx];
        let ys = [f.y0 + f64::from(s.row0) * f.dy, f.y0 + f64::from(s.row1) * f.dy];
        Bounds::new(
            [xs[0].min(xs[1]), ys[0].min(ys[1]), m.bounds.min.z],
            [xs[0].max(xs[1]), ys[0].max(ys[1]), m.bounds.max.z],
        )
    }

    /// A node not baked yet: its mesh level, with the TIN's error bound at its depth.
    fn planned_node(&self, key: TileKey) -> Option<NodeEntry> {
        let p = self.pyramid?;
        if !p.contains(key) {
            return None;
        }
        let bound =
            self.manifest.levels.first().and_then(|l| l.max_error).unwrap_or(0.0) * f64::from(p.step(key.z));
        Some(NodeEntry {
            key,
            bounds: self.planned_bounds(key),
            levels: vec![NodeLevel {
                level: 0,
                errors: ErrorFigures { max: bound, rms: 0.0, gap: 0.0 },
                count: 0,
                triangles: 0,
                bytes: 0,
                checksum: 0,
            }],
        })
    }

    /// Distance between neighbouring points of `level` at node depth `z`.
    fn spacing(&self, level: u8, z: u8) -> Option<f64> {
        if let Some(Some(c)) = self.model_cells.get(usize::from(level)) {
            return Some(*c);
        }
        let spec: &LevelSpec = self.manifest.levels.get(usize::from(level))?;
        let cells = f64::from(spec.cell_leaf_cells?);
        let cell = self.manifest.frame.dx.abs().max(self.manifest.frame.dy.abs());
        Some(cells * cell * f64::from(self.pyramid.map_or(1, |p| p.step(z))))
    }
}

/// Where a JSON document lies relative to the tileset's `3dtiles/` folder: the root
/// `tileset.json`, or an external chunk tileset `index/{z}/{x}/{y}.json` (three folders down).
fn prefix(root: bool) -> &'static str {
    if root { "" } else { "../../../" }
}

/// The tileset JSON of one index chunk: the chunk's nodes as tiles (each node a chain of its
/// stored levels, coarsest first, `REPLACE` down to level 0 and then to the children), nodes
/// below the chunk as external tilesets. `root` gives the tileset's root document (with the
/// `transform` and the tileset-wide extras); otherwise the external tileset of that chunk.
///
/// The tree's geometric errors never grow downwards (3D Tiles: a child's error is at most its
/// parent's): a point level is listed in its node's chain only when its error is at most what
/// the tile above allows and at least its mesh's (a level finer than its own mesh would have to
/// hang below it, above the children, which are finer still); a mesh whose measured error is
/// above its parent's is listed with its parent's (rare: a child is measured against the same
/// samples with half the bound): a mesh is listed with the least mesh error on its path from
/// the root. `cap` is that of the chunk root's parent ([`path_cap`]; infinite for the root
/// chunk).
pub fn chunk_tileset(
    info: &TilesetInfo,
    chunk: &IndexChunk,
    root: bool,
    cap: f64,
) -> Result<Value, Tiles3dError> {
    let nodes: std::collections::HashMap<TileKey, &NodeEntry> =
        chunk.nodes.iter().map(|n| (n.key, n)).collect();
    let pre = prefix(root);
    let mut tile = match node_tiles(info, &nodes, chunk.root, chunk.root, pre, cap)? {
        Some(t) => t,
        None => {
            json!({ "boundingVolume": info.place.bounding_volume(&info.manifest.bounds)?, "geometricError": 0.0 })
        }
    };
    let head_error = tile["geometricError"].as_f64().unwrap_or(0.0);
    let mut asset =
        json!({ "version": "1.1", "generator": GENERATOR, "tilesetVersion": info.manifest.content_version });
    let geometric_error = if root {
        // With a coordinate system every GLB carries its own frame and the regions are absolute.
        if info.place.earth.is_none() {
            tile["transform"] = json!(info.place.anchor.enu_to_ecef());
        }
        let mut extras = info.place.describe();
        extras["tileset"] = json!(info.name);
        extras["kind"] = json!(info.kind);
        extras["content_version"] = json!(info.manifest.content_version);
        extras["levels"] = json!(
            info.manifest
                .levels
                .iter()
                .map(|l| json!({"level": l.level, "kind": l.kind}))
                .collect::<Vec<_>>()
        );
        if info.provisional {
            extras["on_demand"] = json!(true);
        }
        asset["extras"] = json!({ "terrastream": extras });
        // Nothing drawn at all is worse than the root's coarsest level: the data's diagonal.
        head_error.max(info.manifest.bounds.size().length())
    } else {
        head_error
    };
    Ok(json!({ "asset": asset, "geometricError": geometric_error, "root": tile }))
}

/// The geometric error a node's mesh tile is listed with before the cap of its path: its
/// measured error plus what placing it on the Earth adds.
fn mesh_error(info: &TilesetInfo, node: &NodeEntry) -> f64 {
    node.levels.first().map_or(0.0, |l| l.errors.geometric()) + info.place.position_error(&node.bounds)
}

/// The error the mesh tile of the last of `path` (nodes from the root down, each the parent of
/// the next) is listed with: the least mesh error on the path. An external tileset rooted at a
/// child of that node passes it to [`chunk_tileset`]. Nodes of the path that are not baked yet
/// (an on-demand tileset) stand in with their planned entries.
#[must_use]
pub fn path_cap(info: &TilesetInfo, path: &[NodeEntry]) -> f64 {
    path.iter().map(|n| mesh_error(info, n)).fold(f64::INFINITY, f64::min)
}

/// The entry an on-demand tileset lists for a node it has not baked yet.
#[must_use]
pub fn planned_entry(info: &TilesetInfo, key: TileKey) -> Option<NodeEntry> {
    info.planned_node(key)
}

/// The chain of tiles of node `key` (coarsest level first), with its children below level 0;
/// no tile's geometric error above `cap` (the tile above it).
fn node_tiles(
    info: &TilesetInfo,
    nodes: &std::collections::HashMap<TileKey, &NodeEntry>,
    chunk: TileKey,
    key: TileKey,
    pre: &str,
    cap: f64,
) -> Result<Option<Value>, Tiles3dError> {
    let planned;
    let (node, provisional) = match nodes.get(&key) {
        Some(n) => (*n, false),
        None if info.provisional => {
            let Some(p) = info.planned_node(key) else { return Ok(None) };
            planned = p;
            (&planned, true)
        }
        None => return Ok(None),
    };
    // The chain from the top: coarse point levels whose errors fall from `cap` to the mesh's,
    // then the mesh. A point level without points (a node whose surface no slice hit) has no
    // content a client could draw: an empty glTF is not valid glTF, so the chain skips it.
    let Some(mesh) = node.levels.first() else { return Ok(None) };
    let error_of = |l: &NodeLevel| l.errors.geometric() + info.place.position_error(&node.bounds);
    let mesh_error = mesh_error(info, node);
    let mut chain: Vec<(&NodeLevel, f64)> = Vec::new();
    let mut above = cap;
    for l in node.levels.iter().skip(1).rev().filter(|l| l.count > 0) {
        let e = error_of(l);
        if e <= above && e >= mesh_error {
            chain.push((l, e));
            above = e;
        }
    }
    let mesh_listed = mesh_error.min(above);
    chain.push((mesh, mesh_listed));

    let last = key.z >= chunk.z.saturating_add(SUBTREE_LEVELS - 1);
    let mut children = Vec::new();
    for c in info.children(key) {
        if last {
            children.push(reference_tile(info, node, c, pre, mesh_listed)?);
        } else if let Some(t) = node_tiles(info, nodes, chunk, c, pre, mesh_listed)? {
            children.push(t);
        }
    }
    let mut below = children;
    let mut head = None;
    for &(l, e) in chain.iter().rev() {
        let t = level_tile(info, node, l, e, std::mem::take(&mut below), pre, provisional)?;
        below = vec![t.clone()];
        head = Some(t);
    }
    Ok(head)
}

#[allow(clippy::too_many_arguments)]
fn level_tile(
    info: &TilesetInfo,
    node: &NodeEntry,
    l: &NodeLevel,
    geometric_error: f64,
    children: Vec<Value>,
    pre: &str,
    provisional: bool,
) -> Result<Value, Tiles3dError> {
    let key = node.key;
    let kind = info
        .manifest
        .levels
        .get(usize::from(l.level))
        .map_or(if l.level == 0 { Kind::Mesh } else { Kind::Points }, |s| s.kind);
    let mut b = node.bounds;
    let skirt = info.kind == TilesetKind::Terrain && kind == Kind::Mesh;
    if kind == Kind::Points {
        // Points lie within their measured distance of the surface.
        let m = l.errors.max;
        b = Bounds::new(b.min - glam::DVec3::splat(m), b.max + glam::DVec3::splat(m));
    } else if skirt {
        b.min.z -= mesh_skirt_depth(l.errors.max);
    }
    let mut extras = json!({
        "key": key.to_string(), "level": l.level, "kind": kind, "count": l.count, "triangles": l.triangles,
        "bytes": l.bytes, "errors": l.errors,
    });
    if kind == Kind::Points
        && let Some(s) = info.spacing(l.level, key.z)
    {
        extras["spacing"] = json!(s);
    }
    if provisional {
        extras["provisional"] = json!(true);
    }
    let mut t = json!({
        "boundingVolume": info.place.bounding_volume(&b)?,
        "geometricError": geometric_error,
        "refine": "REPLACE",
        "content": { "uri": format!("{pre}tiles/{}/{}/{}/{}.glb{}", key.z, key.x, key.y, l.level, info.query) },
        "extras": { "terrastream": extras },
    });
    if !children.is_empty() {
        t["children"] = Value::Array(children);
    }
    Ok(t)
}

/// A tile standing for the subtree of `child` (a chunk root below this chunk): its content is
/// that chunk's external tileset. Its box is the child's extent at the dataset's height range
/// and its error the parent's mesh tile's, `error` (the chunk file says the rest).
fn reference_tile(
    info: &TilesetInfo,
    parent: &NodeEntry,
    child: TileKey,
    pre: &str,
    error: f64,
) -> Result<Value, Tiles3dError> {
    let mut b = info.planned_bounds(child);
    let parent_error = parent.levels.first().map_or(0.0, |l| l.errors.max);
    b.min.z = b.min.z.min(parent.bounds.min.z) - mesh_skirt_depth(parent_error);
    b.max.z = b.max.z.max(parent.bounds.max.z);
    Ok(json!({
        "boundingVolume": info.place.bounding_volume(&b)?,
        "geometricError": error,
        "refine": "REPLACE",
        "content": { "uri": format!("{pre}index/{}/{}/{}.json{}", child.z, child.x, child.y, info.query) },
        "extras": { "terrastream": { "key": child.to_string(), "subtree": true } },
    }))
}

/// The GLB of one stored (tile, level), from its verified blob: a terrain mesh gets skirts below
/// its inner borders (none on the dataset's outer border), as the tileset JSON's boxes allow for,
/// and the vertices it shares with `neighbours` (the [`tile_fans`] of the same level's blobs of
/// the tiles [`around`] it that exist) one normal with them.
pub fn tile_glb(
    info: &TilesetInfo,
    blob: &Blob,
    neighbours: &[&BorderFans],
) -> Result<Vec<u8>, Tiles3dError> {
    let skirt = takes_neighbours(info, &blob.header)
        .then(|| (mesh_skirt_depth(blob.header.errors.max), Some(&info.manifest.bounds)));
    let (glb, normals) = glb_and_normals(blob, &info.place, skirt, neighbours)?;
    info.glb.apply_with(glb, normals.as_ref())
}

/// Whether the GLB of `header`'s blob takes its neighbours' [`tile_fans`] (and skirts): terrain
/// meshes.
#[must_use]
pub fn takes_neighbours(info: &TilesetInfo, header: &BlobHeader) -> bool {
    info.kind == TilesetKind::Terrain && header.kind == Kind::Mesh
}

/// What the GLB of a neighbouring tile needs of this blob ([`BorderFans`]); `None` where
/// [`takes_neighbours`] says no, or the mesh has no vertex on its box's edge.
pub fn tile_fans(info: &TilesetInfo, blob: &Blob) -> Result<Option<BorderFans>, Tiles3dError> {
    if !takes_neighbours(info, &blob.header) {
        return Ok(None);
    }
    Ok(BorderFans::of(blob, &info.place)?)
}

/// The up to eight tiles of `key`'s depth around it (edges and corners) that the quadtree has;
/// across the antimeridian too when the grid goes around the Earth.
#[must_use]
pub fn around(info: &TilesetInfo, key: TileKey) -> Vec<TileKey> {
    let side = 1i64.checked_shl(u32::from(key.z)).unwrap_or(i64::MAX);
    // Around the Earth ([`Placement::wrap_cols`]) the first column of tiles neighbours the last.
    let wrap =
        info.place.wrap_cols.and(info.pyramid).map(|p| i64::from(p.nodes_at(key.z).0)).filter(|&n| n >= 3);
    let mut out = Vec::with_capacity(8);
    for dy in -1i64..=1 {
        for dx in -1i64..=1 {
            let (mut x, y) = (i64::from(key.x) + dx, i64::from(key.y) + dy);
            if let Some(n) = wrap
                && i64::from(key.x) < n
            {
                x = x.rem_euclid(n);
            }
            if (dx, dy) != (0, 0) && (0..side).contains(&x) && (0..side).contains(&y) {
                out.push(TileKey::new(key.z, x as u32, y as u32));
            }
        }
    }
    out
}
