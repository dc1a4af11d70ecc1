//! The quantized-mesh terrain as 3D Tiles 1.1, what CesiumJS's `Cesium3DTilesTerrainProvider`
//! (1.135+) reads: a `tileset.json` whose root has two children, the western and eastern
//! hemispheres (the two root tiles of the geodetic grid), each an implicit quadtree
//! (`implicitTiling`, `region` volumes) with subtree files and one GLB per tile. Pure: decoded
//! tiles and availability in, bytes and JSON out; the server and `bake::terrain3d` do the I/O.
//!
//! - **Coordinates.** Tile `(z, x, y)` of the grid is tile `(z, x mod 2^z, y)` of root
//!   `x / 2^z`'s implicit quadtree (`y` from the south in both, as CesiumJS maps them).
//! - **GLB** ([`glb`]): the very vertices of the quantized-mesh tile — each `(u, v, height)`
//!   decoded to longitude, latitude and height exactly as a quantized-mesh client does, placed on
//!   the WGS 84 ellipsoid, stored as `FLOAT` offsets from the tile's header centre (the node's
//!   `matrix`; glTF y-up, so an ECEF offset `(x, y, z)` is stored as `(x, z, −y)`). Both forms of
//!   a tile are one surface (to the `f32` rounding of an offset: 2⁻²⁴ of the tile's size, a
//!   millimetre at zoom 10), and neighbours stay crack-free as their quantized-mesh tiles do.
//!   Same triangles (counter-clockwise seen from above), `FLOAT` normals from the tile's
//!   oct-encoded ones (CesiumJS reads `NORMAL` as `f32` only), and the four edge lists in
//!   `CESIUM_tile_edges` (`left`, `bottom`, `right`, `top`: west, south, east, north) for skirts,
//!   in the order CesiumJS joins skirt vertices in ([`tile_edges`]: a list out of order draws
//!   skirt walls across the tile).
//! - **Subtrees** ([`subtree`]): tile and content availability from the layer's availability,
//!   child-subtree availability, and per tile the metadata CesiumJS culls and places the tile by:
//!   `TILE_MINIMUM_HEIGHT`/`TILE_MAXIMUM_HEIGHT` (its bounding box with the tile's rectangle),
//!   `TILE_BOUNDING_SPHERE`, `TILE_HORIZON_OCCLUSION_POINT`. These are the tile's own
//!   quantized-mesh header values, so the rule is: **a subtree is made from its tiles** (each
//!   built or read first), never from guesses — too low a maximum height or too small a sphere
//!   culls a tile that is in view, and a conservative ±10 km box would make CesiumJS's distance
//!   to every tile too short, so it would refine far more than the quantized-mesh provider does.
//!   With [`SUBTREE_LEVELS`] = 2 a subtree holds at most 5 tiles: a tile and its 4 children.

use serde_json::{Value, json};

use super::codec::{Header, QmTile, oct_decode};
use super::grid::{MAX_ZOOM, TileId, tiles_at};
use super::layer::{Coverage, Range};
use crate::crs::ecef;
use crate::formats::tiles3d::GENERATOR;
use crate::formats::tiles3d::glb::{
    ARRAY_BUFFER, ELEMENT_ARRAY_BUFFER, GLTF_FLOAT, GLTF_U16, GLTF_U32, Gltf, MAX_U16_VERTICES,
};

/// Levels per subtree file: a tile and its children. Small, because a subtree needs the
/// headers of all its tiles, and on demand each is built first.
pub const SUBTREE_LEVELS: u8 = 2;
/// Heights (metres above the ellipsoid) of the tileset's root regions: every ellipsoidal height
/// on the Earth (the Mariana trench's −11 km below a geoid at most 106 m down; Everest's 8.85 km
/// above one at most 85 m up). CesiumJS's terrain provider does not read them; generic 3D Tiles
/// clients that open the tileset do.
pub const REGION_HEIGHTS: (f64, f64) = (-12_000.0, 9_000.0);
/// Media type of a subtree file.
pub const SUBTREE_TYPE: &str = "application/octet-stream";
/// Names of the metadata class and its properties in the tileset's schema.
const CLASS: &str = "tile";

/// Why a tile or subtree cannot be made into 3D Tiles.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum Terrain3dError {
    #[error("3D Tiles terrain: tile {tile}: {reason}")]
    Tile { tile: TileId, reason: String },
    #[error("3D Tiles terrain: subtree {root}/{level}/{x}/{y}: {reason}")]
    Subtree { root: u32, level: u8, x: u32, y: u32, reason: String },
    #[error("3D Tiles terrain: layer.json: {0}")]
    Layer(String),
}

/// A tile's place in its root's implicit quadtree.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub struct Implicit {
    /// 0: the western hemisphere, 1: the eastern.
    pub root: u32,
    pub level: u8,
    pub x: u32,
    pub y: u32,
}

impl Implicit {
    /// The implicit coordinates of grid tile `id`.
    #[must_use]
    pub fn of(id: TileId) -> Self {
        let side = 1u32 << id.z;
        Self { root: id.x / side, level: id.z, x: id.x % side, y: id.y }
    }

    /// The grid tile at these coordinates, checked (root 0 or 1, inside its level).
    pub fn tile(self) -> Result<TileId, Terrain3dError> {
        let bad = |reason: &str| Terrain3dError::Subtree {
            root: self.root,
            level: self.level,
            x: self.x,
            y: self.y,
            reason: reason.to_string(),
        };
        if self.level > MAX_ZOOM {
            return Err(bad("beyond the deepest zoom of the grid"));
        }
        let side = 1u32 << self.level;
        if self.root > 1 || self.x >= side || self.y >= side {
            return Err(bad("not a tile of the two roots' quadtrees"));
        }
        Ok(TileId { z: self.level, x: self.root * side + self.x, y: self.y })
    }

    /// Whether these coordinates are a subtree's root (levels 0, [`SUBTREE_LEVELS`], …).
    #[must_use]
    pub fn is_subtree_root(self) -> bool {
        self.level.is_multiple_of(SUBTREE_LEVELS)
    }
}

/// Path of a tile's GLB, relative to the tileset JSON (`tiles/{root}/{level}/{x}/{y}.glb`).
#[must_use]
pub fn glb_rel(id: TileId) -> String {
    let i = Implicit::of(id);
    format!("tiles/{}/{}/{}/{}.glb", i.root, i.level, i.x, i.y)
}

/// Path of a subtree file, relative to the tileset JSON.
#[must_use]
pub fn subtree_rel(s: Implicit) -> String {
    format!("subtrees/{}/{}/{}/{}.subtree", s.root, s.level, s.x, s.y)
}

/// Which tiles exist: per zoom, the ranges of `layer.json`'s `available` (from a [`Coverage`], or
/// read back from a stored `layer.json`).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Availability {
    pub max_zoom: u8,
    /// `ranges[z]`: the available tiles of zoom `z`.
    pub ranges: Vec<Vec<Range>>,
}

impl Availability {
    #[must_use]
    pub fn of(c: &Coverage) -> Self {
        Self { max_zoom: c.max_zoom, ranges: (0..=c.max_zoom).map(|z| c.available(z)).collect() }
    }

    /// From a `layer.json`'s `available` (`maxzoom`: its length − 1).
    pub fn from_layer(layer: &Value) -> Result<Self, Terrain3dError> {
        let bad = |m: String| Terrain3dError::Layer(m);
        let levels = layer["available"].as_array().ok_or_else(|| bad("no `available` array".into()))?;
        if levels.is_empty() || levels.len() > usize::from(MAX_ZOOM) + 1 {
            return Err(bad(format!("`available` has {} zooms, not 1 to {}", levels.len(), MAX_ZOOM + 1)));
        }
        let mut ranges = Vec::with_capacity(levels.len());
        for (z, level) in levels.iter().enumerate() {
            let list = level.as_array().ok_or_else(|| bad(format!("available[{z}] is not an array")))?;
            let (cols, rows) = tiles_at(z as u8);
            let mut out = Vec::with_capacity(list.len());
            for r in list {
                let n = |k: &str| {
                    r[k].as_u64()
                        .and_then(|v| u32::try_from(v).ok())
                        .ok_or_else(|| bad(format!("available[{z}]: `{k}` is not a tile index")))
                };
                let range = Range { x0: n("startX")?, y0: n("startY")?, x1: n("endX")?, y1: n("endY")? };
                if range.x0 > range.x1 || range.y0 > range.y1 || range.x1 >= cols || range.y1 >= rows {
                    return Err(bad(format!("available[{z}]: {range:?} is not a range of zoom {z}'s tiles")));
                }
                out.push(range);
            }
            ranges.push(out);
        }
        Ok(Self { max_zoom: (ranges.len() - 1) as u8, ranges })
    }

    /// Whether tile `id` exists.
    #[must_use]
    pub fn has(&self, id: TileId) -> bool {
        self.ranges.get(usize::from(id.z)).is_some_and(|rs| {
            rs.iter().any(|r| (r.x0..=r.x1).contains(&id.x) && (r.y0..=r.y1).contains(&id.y))
        })
    }
}

/// The subtree rooted at `root` (a subtree root, see [`Implicit::is_subtree_root`]): its
/// available tiles in the order of its availability bitstream (level by level, Morton order
/// within a level), which is also the order of its metadata; empty when its root tile is not
/// available.
pub fn subtree_tiles(avail: &Availability, root: Implicit) -> Result<Vec<TileId>, Terrain3dError> {
    check_subtree_root(root)?;
    let mut out = Vec::new();
    for l in 0..SUBTREE_LEVELS {
        for (lx, ly) in level_order(l) {
            let t = Implicit {
                root: root.root,
                level: root.level + l,
                x: (root.x << l) + lx,
                y: (root.y << l) + ly,
            };
            if t.level > avail.max_zoom {
                break;
            }
            if let Ok(id) = t.tile()
                && avail.has(id)
            {
                out.push(id);
            }
        }
    }
    Ok(out)
}

fn check_subtree_root(root: Implicit) -> Result<(), Terrain3dError> {
    root.tile()?;
    if root.is_subtree_root() {
        Ok(())
    } else {
        Err(Terrain3dError::Subtree {
            root: root.root,
            level: root.level,
            x: root.x,
            y: root.y,
            reason: format!("subtrees start at levels that are multiples of {SUBTREE_LEVELS}"),
        })
    }
}

/// The local (x, y) of a level's `4^l` tiles in Morton order (x in the low bit).
fn level_order(l: u8) -> impl Iterator<Item = (u32, u32)> {
    (0..(1u64 << (2 * l))).map(move |m| {
        let (mut x, mut y) = (0u32, 0u32);
        for b in 0..l {
            x |= (((m >> (2 * b)) & 1) as u32) << b;
            y |= (((m >> (2 * b + 1)) & 1) as u32) << b;
        }
        (x, y)
    })
}

/// The subtree file (binary `subt`, version 1) of `root`: `headers` are the quantized-mesh
/// headers of [`subtree_tiles`]`(avail, root)`, in that order.
pub fn subtree(avail: &Availability, root: Implicit, headers: &[Header]) -> Result<Vec<u8>, Terrain3dError> {
    let tiles = subtree_tiles(avail, root)?;
    let bad = |reason: String| Terrain3dError::Subtree {
        root: root.root,
        level: root.level,
        x: root.x,
        y: root.y,
        reason,
    };
    if tiles.is_empty() {
        return Err(bad("its root tile is not available".into()));
    }
    if headers.len() != tiles.len() {
        return Err(bad(format!("{} tiles available but {} headers given", tiles.len(), headers.len())));
    }
    let levels = u32::from(SUBTREE_LEVELS);
    let tile_bits = ((1usize << (2 * levels)) - 1) / 3;
    let mut tile_avail = vec![false; tile_bits];
    for id in &tiles {
        let i = Implicit::of(*id);
        let l = i.level - root.level;
        let (lx, ly) = (i.x - (root.x << l), i.y - (root.y << l));
        let first = ((1usize << (2 * l)) - 1) / 3;
        tile_avail[first + crate::tiling::morton(lx, ly) as usize] = true;
    }
    let child_level = root.level + SUBTREE_LEVELS;
    let mut child_avail = vec![false; 1usize << (2 * levels)];
    if child_level <= avail.max_zoom {
        for (m, (lx, ly)) in level_order(SUBTREE_LEVELS).enumerate() {
            let c = Implicit {
                root: root.root,
                level: child_level,
                x: (root.x << levels) + lx,
                y: (root.y << levels) + ly,
            };
            child_avail[m] = c.tile().is_ok_and(|id| avail.has(id));
        }
    }
    let mut bin = Vec::new();
    let mut views = Vec::new();
    let mut add = |bytes: &[u8]| {
        while !bin.len().is_multiple_of(8) {
            bin.push(0);
        }
        views.push(json!({ "buffer": 0, "byteOffset": bin.len(), "byteLength": bytes.len() }));
        bin.extend_from_slice(bytes);
        views.len() - 1
    };
    let tile_view = add(&bitstream(&tile_avail));
    let children = child_avail.iter().filter(|&&b| b).count();
    let child = if children == 0 {
        json!({ "constant": 0 })
    } else {
        json!({ "bitstream": add(&bitstream(&child_avail)), "availableCount": children })
    };
    let f64s = |vals: &mut dyn Iterator<Item = f64>| -> Vec<u8> { vals.flat_map(f64::to_le_bytes).collect() };
    let min = add(&f64s(&mut headers.iter().map(|h| f64::from(h.min_height))));
    let max = add(&f64s(&mut headers.iter().map(|h| f64::from(h.max_height))));
    let sphere = add(&f64s(
        &mut headers
            .iter()
            .flat_map(|h| [h.sphere_center[0], h.sphere_center[1], h.sphere_center[2], h.sphere_radius]),
    ));
    let horizon = add(&f64s(&mut headers.iter().flat_map(|h| h.horizon)));
    while !bin.len().is_multiple_of(8) {
        bin.push(0);
    }
    let n = tiles.len();
    let doc = json!({
        "buffers": [{ "byteLength": bin.len() }],
        "bufferViews": views,
        "tileAvailability": { "bitstream": tile_view, "availableCount": n },
        "contentAvailability": [{ "bitstream": tile_view, "availableCount": n }],
        "childSubtreeAvailability": child,
        "propertyTables": [{
            "class": CLASS,
            "count": n,
            "properties": {
                "minimumHeight": { "values": min },
                "maximumHeight": { "values": max },
                "boundingSphere": { "values": sphere },
                "horizonOcclusionPoint": { "values": horizon },
            },
        }],
        "tileMetadata": 0,
    });
    let mut text = serde_json::to_vec(&doc).map_err(|e| bad(e.to_string()))?;
    while !text.len().is_multiple_of(8) {
        text.push(b' ');
    }
    let mut out = Vec::with_capacity(24 + text.len() + bin.len());
    out.extend_from_slice(b"subt");
    out.extend_from_slice(&1u32.to_le_bytes());
    out.extend_from_slice(&(text.len() as u64).to_le_bytes());
    out.extend_from_slice(&(bin.len() as u64).to_le_bytes());
    out.extend_from_slice(&text);
    out.extend_from_slice(&bin);
    Ok(out)
}

/// Bits, least significant first in each byte (3D Tiles availability bitstreams).
fn bitstream(bits: &[bool]) -> Vec<u8> {
    let mut out = vec![0u8; bits.len().div_ceil(8)];
    for (i, _) in bits.iter().enumerate().filter(|(_, b)| **b) {
        out[i / 8] |= 1 << (i % 8);
    }
    out
}

/// The metadata schema of the subtrees: one class whose properties carry the semantics
/// CesiumJS's terrain provider reads.
fn schema() -> Value {
    let f64_prop =
        |semantic: &str| json!({ "type": "SCALAR", "componentType": "FLOAT64", "semantic": semantic });
    json!({
        "id": "terrastream_terrain",
        "classes": { CLASS: { "properties": {
            "minimumHeight": f64_prop("TILE_MINIMUM_HEIGHT"),
            "maximumHeight": f64_prop("TILE_MAXIMUM_HEIGHT"),
            "boundingSphere": { "type": "SCALAR", "componentType": "FLOAT64", "array": true, "count": 4,
                "semantic": "TILE_BOUNDING_SPHERE" },
            "horizonOcclusionPoint": { "type": "VEC3", "componentType": "FLOAT64",
                "semantic": "TILE_HORIZON_OCCLUSION_POINT" },
        } } },
    })
}

/// The tileset JSON: a root without content over the globe, whose two children are the
/// hemispheres' implicit quadtrees (the layout `Cesium3DTilesTerrainProvider` reads:
/// `root.children[0]` west, `[1]` east). `level0_error` is the error bound of zoom 0 (halved per
/// level by implicit tiling, as the tiles are built); `version` goes into every URI (`?v=`), so
/// tiles and subtrees are immutable per content version.
#[must_use]
pub fn tileset_json(avail: &Availability, level0_error: f64, version: &str) -> Value {
    use std::f64::consts::{FRAC_PI_2, PI};
    let q = if version.is_empty() { String::new() } else { format!("?v={version}") };
    let (lo, hi) = REGION_HEIGHTS;
    let hemisphere = |r: u32| {
        let west = -PI + f64::from(r) * PI;
        json!({
            "boundingVolume": { "region": [west, -FRAC_PI_2, west + PI, FRAC_PI_2, lo, hi] },
            "geometricError": level0_error,
            "refine": "REPLACE",
            "content": { "uri": format!("tiles/{r}/{{level}}/{{x}}/{{y}}.glb{q}") },
            "implicitTiling": {
                "subdivisionScheme": "QUADTREE",
                "subtreeLevels": SUBTREE_LEVELS,
                "availableLevels": u32::from(avail.max_zoom) + 1,
                "subtrees": { "uri": format!("subtrees/{r}/{{level}}/{{x}}/{{y}}.subtree{q}") },
            },
        })
    };
    json!({
        "asset": { "version": "1.1", "generator": GENERATOR, "tilesetVersion": version },
        "schema": schema(),
        "geometricError": 2.0 * level0_error,
        "root": {
            "boundingVolume": { "region": [-PI, -FRAC_PI_2, PI, FRAC_PI_2, lo, hi] },
            "geometricError": 2.0 * level0_error,
            "refine": "REPLACE",
            "children": [hemisphere(0), hemisphere(1)],
        },
    })
}

/// The content version in a `layer.json`'s tile template (`…?v=VERSION`; empty without one):
/// the 3D Tiles URIs carry the same, so both forms of the terrain change version together.
#[must_use]
pub fn layer_version(layer: &Value) -> &str {
    layer["tiles"][0].as_str().and_then(|t| t.split_once("?v=")).map_or("", |(_, v)| v)
}

/// Zoom 0's error bound from a terrain bake's `stats.json` (`per_zoom["0"].bound`).
#[must_use]
pub fn level0_error_of_stats(stats: &Value) -> Option<f64> {
    stats["per_zoom"]["0"]["bound"].as_f64().filter(|e| e.is_finite() && *e > 0.0)
}

/// The tileset JSON's bytes for a terrain described by `layer` (its availability and version)
/// whose zoom 0 was built to `level0_error`: what the server sends and the bake writes.
pub fn tileset_from_layer(layer: &Value, level0_error: f64) -> Result<Vec<u8>, Terrain3dError> {
    let avail = Availability::from_layer(layer)?;
    serde_json::to_vec_pretty(&tileset_json(&avail, level0_error, layer_version(layer)))
        .map_err(|e| Terrain3dError::Layer(e.to_string()))
}

/// The geodetic (longitude, latitude in degrees, height) of each vertex of tile `id`, decoded
/// as quantized-mesh clients decode it.
#[must_use]
pub fn vertex_geodetic(t: &QmTile, id: TileId) -> Vec<(f64, f64, f64)> {
    let r = id.rect();
    let q = f64::from(super::codec::QMAX);
    let (h0, h1) = (f64::from(t.header.min_height), f64::from(t.header.max_height));
    let lerp = |a: f64, b: f64, s: f64| a + (b - a) * s;
    t.u.iter()
        .zip(&t.v)
        .zip(&t.h)
        .map(|((&u, &v), &h)| {
            (
                lerp(r.west, r.east, f64::from(u) / q),
                lerp(r.south, r.north, f64::from(v) / q),
                lerp(h0, h1, f64::from(h) / q),
            )
        })
        .collect()
}

/// The tile's edge lists as `CESIUM_tile_edges` names and orders them: CesiumJS hangs its skirts
/// from them as they come, taking `left` south to north, `bottom` east to west, `right` north to
/// south and `top` west to east (`TerrainMesh`'s `westIndicesSouthToNorth`, …), where
/// quantized-mesh lists have no order (clients sort them).
#[must_use]
pub fn tile_edges(t: &QmTile) -> [(&'static str, Vec<u32>); 4] {
    let sorted = |list: &[u32], key: &dyn Fn(u32) -> i32| {
        let mut l = list.to_vec();
        l.sort_by_key(|&i| (key(i), i));
        l
    };
    let (u, v) = (|i: u32| i32::from(t.u[i as usize]), |i: u32| i32::from(t.v[i as usize]));
    [
        ("left", sorted(&t.west, &v)),
        ("bottom", sorted(&t.south, &|i| -u(i))),
        ("right", sorted(&t.east, &|i| -v(i))),
        ("top", sorted(&t.north, &u)),
    ]
}

/// Index lists as the bytes of one glTF component type.
type IndexBytes = fn(&[u32]) -> Vec<u8>;

/// ECEF `(x, y, z)` in glTF's y-up axes.
fn y_up(p: [f64; 3]) -> [f64; 3] {
    [p[0], p[2], -p[1]]
}

/// The GLB of quantized-mesh tile `t` (decoded, of grid tile `id`): see the module doc.
pub fn glb(t: &QmTile, id: TileId) -> Result<Vec<u8>, Terrain3dError> {
    let bad = |reason: String| Terrain3dError::Tile { tile: id, reason };
    let n = t.u.len();
    if n == 0 || t.triangles.is_empty() {
        return Err(bad("the tile has no triangles".into()));
    }
    if t.v.len() != n || t.h.len() != n {
        return Err(bad("u, v and height arrays differ in length".into()));
    }
    if t.triangles.iter().flatten().any(|&i| i as usize >= n) {
        return Err(bad(format!("a triangle names a vertex beyond its {n}")));
    }
    for (name, list) in [("west", &t.west), ("south", &t.south), ("east", &t.east), ("north", &t.north)] {
        if list.is_empty() {
            return Err(bad(format!("its {name} edge list is empty")));
        }
        if list.iter().any(|&i| i as usize >= n) {
            return Err(bad(format!("its {name} edge list names a vertex beyond its {n}")));
        }
    }
    if t.normals.as_ref().is_some_and(|v| v.len() != n) {
        return Err(bad("not one normal per vertex".into()));
    }
    let center = t.header.center;
    let origin = y_up(center);
    let mut pos = Vec::with_capacity(n * 12);
    let (mut lo, mut hi) = ([f32::INFINITY; 3], [f32::NEG_INFINITY; 3]);
    for (lon, lat, h) in vertex_geodetic(t, id) {
        let p = ecef::from_geodetic(lon, lat, h);
        let g = y_up([p[0] - center[0], p[1] - center[1], p[2] - center[2]]);
        for a in 0..3 {
            let v = g[a] as f32;
            lo[a] = lo[a].min(v);
            hi[a] = hi[a].max(v);
            pos.extend_from_slice(&v.to_le_bytes());
        }
    }
    let mut g = Gltf {
        json: json!({
            "asset": { "version": "2.0", "generator": GENERATOR },
            "scene": 0,
            "scenes": [{ "nodes": [0] }],
            "nodes": [{ "mesh": 0, "matrix": [
                1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0, origin[0], origin[1], origin[2], 1.0,
            ] }],
            "bufferViews": [],
            "accessors": [],
            "extensionsUsed": ["CESIUM_tile_edges"],
            "extras": { "terrastream": { "terrain": id.to_string() } },
        }),
        bin: Vec::new(),
    };
    let view = g.view(&pos, Some(12), ARRAY_BUFFER);
    let position = g.accessor(json!({
        "bufferView": view, "componentType": GLTF_FLOAT, "count": n, "type": "VEC3", "min": lo, "max": hi,
    }));
    let mut attributes = json!({ "POSITION": position });
    if let Some(normals) = &t.normals {
        let b: Vec<u8> = normals
            .iter()
            .flat_map(|o| {
                let d = oct_decode(*o);
                let len = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt();
                let u = if len > 0.0 { d.map(|c| c / len) } else { [0.0, 0.0, 1.0] };
                y_up(u).into_iter().flat_map(|c| (c as f32).to_le_bytes())
            })
            .collect();
        let view = g.view(&b, Some(12), ARRAY_BUFFER);
        attributes["NORMAL"] = json!(g.accessor(json!({
            "bufferView": view, "componentType": GLTF_FLOAT, "count": n, "type": "VEC3",
        })));
    }
    let wide = n > MAX_U16_VERTICES;
    let (component, ints): (u32, IndexBytes) = if wide {
        (GLTF_U32, |l| l.iter().flat_map(|i| i.to_le_bytes()).collect())
    } else {
        (GLTF_U16, |l| l.iter().flat_map(|&i| (i as u16).to_le_bytes()).collect())
    };
    let flat: Vec<u32> = t.triangles.iter().flatten().copied().collect();
    let view = g.view(&ints(&flat), None, ELEMENT_ARRAY_BUFFER);
    let indices = g.accessor(
        json!({ "bufferView": view, "componentType": component, "count": flat.len(), "type": "SCALAR" }),
    );
    let mut edges = serde_json::Map::new();
    for (name, list) in tile_edges(t) {
        let view = g.view(&ints(&list), None, 0);
        // Edge lists are read by the extension, not drawn: their views have no target.
        if let Some(v) = g.json["bufferViews"][view].as_object_mut() {
            v.remove("target");
        }
        let acc = g.accessor(
            json!({ "bufferView": view, "componentType": component, "count": list.len(), "type": "SCALAR" }),
        );
        edges.insert(name.to_string(), json!(acc));
    }
    g.json["meshes"] = json!([{ "primitives": [{
        "attributes": attributes, "indices": indices, "mode": 4,
        "extensions": { "CESIUM_tile_edges": edges },
    }] }]);
    Ok(g.finish())
}

#[cfg(test)]
mod tests;
