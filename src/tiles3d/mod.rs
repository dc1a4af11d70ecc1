//! OGC 3D Tiles 1.1 from a tileset's own records, so third-party clients (CesiumJS, Cesium for
//! Unreal/Unity, the three.js 3d-tiles-renderer, deck.gl) read every tileset without a re-bake:
//! a decoded blob becomes a glTF 2.0 binary ([`glb`]) and an index chunk becomes a tileset JSON
//! ([`chunk_tileset`]) whose subtrees below the chunk are external tilesets, so no JSON grows
//! with the dataset. Pure: values in, bytes and JSON out (the server and `export` do the I/O).
//!
//! Placement ([`Placement`]): the tileset frame is east-north-up metres around a local origin
//! (the centre of the data at height 0; a model's bottom centre), and the root tile's
//! `transform` takes it to Earth-centred coordinates at the anchor (longitude, latitude,
//! ellipsoidal height). glTF is y-up, so a glTF position is (east, up, −north). Positions keep
//! the blob's integer grid: each glTF axis stores `q` (or `Q − q` where the axis is reversed)
//! and the node's `translation` and `scale` hold the grid's origin and step, so a position
//! decodes to exactly what the blob decodes to.

use serde::{Deserialize, Serialize};
use serde_json::{Value, json};

use crate::codec::{Blob, Geometry, Kind};
use crate::geom::{Bounds, Errors, Mesh, add_skirts, skirt_depth};
use crate::store::{IndexChunk, LevelSpec, Manifest, NodeEntry, NodeLevel, SUBTREE_LEVELS, TilesetKind};
use crate::tiling::{Pyramid, TileKey};

/// Media type of a glTF binary.
pub const GLB_TYPE: &str = "model/gltf-binary";
/// Written into `asset.generator` of every tileset and glTF.
pub const GENERATOR: &str = concat!("terrastream ", env!("CARGO_PKG_VERSION"));
/// Where a tileset with no anchor of its own is placed: 0° E, 0° N, height 0 (stated in the
/// tileset JSON's `asset.extras.terrastream.anchor`, `from: "default"`).
pub const DEFAULT_ANCHOR: Anchor = Anchor { lon: 0.0, lat: 0.0, height: 0.0 };
/// Largest |height| of an anchor, metres (as raster heights).
pub const MAX_ANCHOR_HEIGHT: f64 = crate::raster::MAX_HEIGHT;

/// A geographic position: WGS84 longitude and latitude in degrees, ellipsoidal height in metres.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Anchor {
    pub lon: f64,
    pub lat: f64,
    #[serde(default)]
    pub height: f64,
}

impl Anchor {
    /// Parses `LON,LAT[,H]` (degrees, degrees, metres). Errors name the value and the range.
    pub fn parse(s: &str) -> Result<Self, String> {
        let parts: Vec<&str> = s.split(',').map(str::trim).collect();
        if !(2..=3).contains(&parts.len()) {
            return Err(format!("anchor {s:?}: expected LON,LAT or LON,LAT,HEIGHT"));
        }
        let num = |t: &str, what: &str| {
            t.parse::<f64>().map_err(|_| format!("anchor {s:?}: {what} {t:?} is not a number"))
        };
        let a = Self {
            lon: num(parts[0], "longitude")?,
            lat: num(parts[1], "latitude")?,
            height: parts.get(2).map_or(Ok(0.0), |t| num(t, "height"))?,
        };
        a.check().map_err(|e| format!("anchor {s:?}: {e}"))?;
        Ok(a)
    }

    /// Checks the ranges: longitude −180..180, latitude −90..90, |height| ≤ 1e7 m.
    pub fn check(&self) -> Result<(), String> {
        if !(self.lon.is_finite() && (-180.0..=180.0).contains(&self.lon)) {
            return Err(format!("longitude {} is not within -180..180 degrees", self.lon));
        }
        if !(self.lat.is_finite() && (-90.0..=90.0).contains(&self.lat)) {
            return Err(format!("latitude {} is not within -90..90 degrees", self.lat));
        }
        if !(self.height.is_finite() && self.height.abs() <= MAX_ANCHOR_HEIGHT) {
            return Err(format!("height {} is not within ±1e7 m", self.height));
        }
        Ok(())
    }

    /// Earth-centred, Earth-fixed (WGS84) position of the anchor, metres.
    #[must_use]
    pub fn ecef(&self) -> [f64; 3] {
        const A: f64 = 6_378_137.0;
        const F: f64 = 1.0 / 298.257_223_563;
        let e2 = F * (2.0 - F);
        let (phi, lam) = (self.lat.to_radians(), self.lon.to_radians());
        let n = A / (1.0 - e2 * phi.sin() * phi.sin()).sqrt();
        [
            (n + self.height) * phi.cos() * lam.cos(),
            (n + self.height) * phi.cos() * lam.sin(),
            (n * (1.0 - e2) + self.height) * phi.sin(),
        ]
    }

    /// The east-north-up frame at the anchor as a column-major 4×4 matrix (3D Tiles'
    /// `transform`): local (east, north, up) metres → Earth-centred coordinates.
    #[must_use]
    pub fn enu_to_ecef(&self) -> [f64; 16] {
        let (phi, lam) = (self.lat.to_radians(), self.lon.to_radians());
        let east = [-lam.sin(), lam.cos(), 0.0];
        let north = [-phi.sin() * lam.cos(), -phi.sin() * lam.sin(), phi.cos()];
        let up = [phi.cos() * lam.cos(), phi.cos() * lam.sin(), phi.sin()];
        let o = self.ecef();
        [
            east[0], east[1], east[2], 0.0, north[0], north[1], north[2], 0.0, up[0], up[1], up[2], 0.0,
            o[0], o[1], o[2], 1.0,
        ]
    }
}

/// Where a tileset's anchor came from.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum AnchorFrom {
    /// A geographic source: the centre of its data.
    Source,
    /// `--anchor` (at bake, or at export).
    Option,
    /// Neither: [`DEFAULT_ANCHOR`].
    Default,
}

/// How world coordinates turn into east-north-up ones.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Axes {
    /// Terrain whose `y` grows northwards (georeferenced rasters: projected northings, or the
    /// metric frame of a geographic raster).
    NorthUp,
    /// Terrain without georeference, whose `y` grows with the row: images are north-up, so row 0
    /// is the north edge and north is −y (a mirror image of the world frame, so triangles turn).
    RowsSouth,
    /// A model: its own coordinates are y-up (as OBJ and PLY are by convention), like glTF's.
    ModelYUp,
}

/// A tileset's place on the globe: the anchor, the world point placed there and the axes.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Placement {
    pub anchor: Anchor,
    pub from: AnchorFrom,
    /// The world point at the anchor.
    pub origin: [f64; 3],
    pub axes: Axes,
}

impl Placement {
    /// The placement of a tileset: `anchor` (from `--anchor`) wins; a geographic terrain source
    /// is anchored at the centre of its data; anything else at [`DEFAULT_ANCHOR`].
    #[must_use]
    pub fn of(m: &Manifest, kind: TilesetKind, anchor: Option<Anchor>) -> Self {
        let b = &m.bounds;
        let c = b.center();
        let (origin, axes) = match kind {
            TilesetKind::Terrain => {
                let axes = if m.frame.geographic.is_some() || m.frame.dy < 0.0 {
                    Axes::NorthUp
                } else {
                    Axes::RowsSouth
                };
                ([c.x, c.y, 0.0], axes)
            }
            TilesetKind::Model => ([c.x, b.min.y, c.z], Axes::ModelYUp),
        };
        let source = match (kind, m.frame.geographic) {
            (TilesetKind::Terrain, Some(g)) if m.frame.dx != 0.0 && m.frame.dy != 0.0 => {
                let col = (origin[0] - m.frame.x0) / m.frame.dx;
                let row = (origin[1] - m.frame.y0) / m.frame.dy;
                let a = Anchor { lon: g.lon0 + col * g.dlon, lat: g.lat0 + row * g.dlat, height: 0.0 };
                a.check().is_ok().then_some(a)
            }
            _ => None,
        };
        let (anchor, from) = match (anchor, source) {
            (Some(a), _) => (a, AnchorFrom::Option),
            (None, Some(a)) => (a, AnchorFrom::Source),
            (None, None) => (DEFAULT_ANCHOR, AnchorFrom::Default),
        };
        Self { anchor, from, origin, axes }
    }

    /// Per glTF axis: the world axis it reads and its sign (glTF = east, up, −north).
    fn axis_map(&self) -> [(usize, f64); 3] {
        match self.axes {
            Axes::NorthUp => [(0, 1.0), (2, 1.0), (1, -1.0)],
            Axes::RowsSouth => [(0, 1.0), (2, 1.0), (1, 1.0)],
            Axes::ModelYUp => [(0, 1.0), (1, 1.0), (2, 1.0)],
        }
    }

    /// True when world → east-north-up is a mirror image (triangle winding must turn).
    #[must_use]
    pub fn mirrored(&self) -> bool {
        self.axes == Axes::RowsSouth
    }

    /// A world point in glTF coordinates (y-up, relative to the origin).
    #[must_use]
    pub fn gltf_of(&self, p: [f64; 3]) -> [f64; 3] {
        self.axis_map().map(|(a, s)| s * (p[a] - self.origin[a]))
    }

    /// A world point in the tileset frame (east, north, up relative to the origin).
    #[must_use]
    pub fn enu_of(&self, p: [f64; 3]) -> [f64; 3] {
        let g = self.gltf_of(p);
        [g[0], -g[2], g[1]]
    }

    /// A world box as a 3D Tiles `box` in the tileset frame (centre, then three half-axes).
    #[must_use]
    pub fn enu_box(&self, b: &Bounds) -> [f64; 12] {
        let (p, q) = (self.enu_of(b.min.to_array()), self.enu_of(b.max.to_array()));
        // Half-axes of zero are legal but some clients cull such boxes by their volume: a
        // millimetre keeps a flat tile a box.
        let h: [f64; 3] = std::array::from_fn(|a| ((p[a] - q[a]).abs() / 2.0).max(1e-3));
        let c: [f64; 3] = std::array::from_fn(|a| f64::midpoint(p[a], q[a]));
        [c[0], c[1], c[2], h[0], 0.0, 0.0, 0.0, h[1], 0.0, 0.0, 0.0, h[2]]
    }

    /// The `asset.extras.terrastream` fields that say where the tileset is and why.
    fn describe(&self) -> Value {
        let north = match self.axes {
            Axes::NorthUp => "+y",
            Axes::RowsSouth => "-y",
            Axes::ModelYUp => "-z",
        };
        let mut anchor = json!({
            "lon": self.anchor.lon, "lat": self.anchor.lat, "height": self.anchor.height,
            "from": self.from,
        });
        if self.from == AnchorFrom::Default {
            anchor["note"] = json!(
                "the source has no geographic reference the project can resolve: placed at the default \
                 anchor; bake or export with --anchor LON,LAT[,H] to place it"
            );
        }
        json!({
            "anchor": anchor,
            "local_frame": {
                "origin": self.origin,
                "north": north,
                "up": if self.axes == Axes::ModelYUp { "+y" } else { "+z" },
            },
        })
    }
}

// ---------------------------------------------------------------------------------------------
// glTF binary

const GLTF_FLOAT: u32 = 5126;
const GLTF_U16: u32 = 5123;
const GLTF_U32: u32 = 5125;
const GLTF_I8: u32 = 5120;
const ARRAY_BUFFER: u32 = 34962;
const ELEMENT_ARRAY_BUFFER: u32 = 34963;
/// Largest vertex count drawn with 16-bit indices: 65535 is WebGL 2's primitive-restart index.
const MAX_U16_VERTICES: usize = 65_535;

/// Skirt depth of a tile mesh with error `own`: deep enough for a neighbour drawn one level
/// coarser (about twice the error), see [`skirt_depth`].
#[must_use]
pub fn mesh_skirt_depth(own: f64) -> f64 {
    skirt_depth(own, 2.0 * own)
}

/// The glTF binary of a decoded blob: a mesh as indexed triangles (with skirts `skirt` deep
/// below its borders, none on the dataset's outer border `outer`, when `skirt` is given), points
/// as `POINTS` with normals. Positions are the blob's integer grid: `UNSIGNED_SHORT` with
/// `KHR_mesh_quantization` when every axis fits 16 bits, else the same integers as `FLOAT`
/// (exact below 2²⁴); normals are `BYTE` normalized.
#[must_use]
pub fn glb(blob: &Blob, place: &Placement, skirt: Option<(f64, Option<&Bounds>)>) -> Vec<u8> {
    let h = &blob.header;
    let step = [h.quant.xy_step, h.quant.xy_step, h.quant.z_step];
    let min = h.bounds[0];
    match &blob.geometry {
        Geometry::Mesh(mesh) => {
            // Top triangles must face up (a terrain) or keep their winding (a model, unless the
            // placement mirrors it); skirt walls are built facing outward in the world frame, so
            // they turn only where the placement mirrors.
            let flip_top = turns(mesh, place);
            let skirted = match skirt {
                Some((depth, outer)) if !mesh.triangles.is_empty() => {
                    // A whole number of z steps, so skirt vertices stay on the grid.
                    let depth = (depth / step[2]).ceil().max(1.0) * step[2];
                    Some(add_skirts(mesh, depth, outer))
                }
                _ => None,
            };
            let (all, tops, first_wall): (&Mesh, &[u32], usize) = match &skirted {
                Some(s) => (&s.mesh, &s.skirt_tops, s.first_skirt_triangle),
                None => (mesh, &[], mesh.triangles.len()),
            };
            let mut tris = all.triangles.clone();
            for (i, t) in tris.iter_mut().enumerate() {
                let flip = if i < first_wall { flip_top } else { place.mirrored() };
                if flip {
                    t.swap(1, 2);
                }
            }
            let pos = Positions::new(&all.positions, min, step, place);
            let normals = mesh_normals(all, &tris[..first_wall], tops, place);
            Gltf::mesh(&pos, &tris, &normals, h.key, h.level).finish()
        }
        Geometry::Points(points) => {
            let pos = Positions::new(&points.positions, min, step, place);
            let map = place.axis_map();
            let normals: Vec<[i8; 3]> =
                points.normals.iter().map(|n| oct_free_i8(map.map(|(a, s)| s * f64::from(n[a])))).collect();
            Gltf::points(&pos, &normals, h.key, h.level).finish()
        }
    }
}

/// Whether a mesh's triangles must turn to face the way glTF expects (counter-clockwise seen from
/// outside). A model keeps its own winding unless the placement mirrors it; a terrain mesh is a
/// height field, so its triangles must face up: the sign of their summed area seen from above
/// in the tileset frame says which way they face (the TIN's winding follows the raster's rows,
/// whose direction in the world frame depends on the georeference).
fn turns(mesh: &Mesh, place: &Placement) -> bool {
    if place.axes == Axes::ModelYUp {
        return place.mirrored();
    }
    let area: f64 = mesh
        .triangles
        .iter()
        .map(|t| {
            let [a, b, c] = t.map(|i| place.enu_of(mesh.positions[i as usize]));
            (b[0] - a[0]) * (c[1] - a[1]) - (b[1] - a[1]) * (c[0] - a[0])
        })
        .sum();
    area < 0.0
}

/// Smooth vertex normals in glTF axes, as `BYTE` vectors: area-weighted sums over the top
/// triangles (`top`, already facing the right way); a skirt vertex takes the normal of the
/// border vertex it hangs below (`tops`, in order from the first skirt vertex), so a wall
/// shades like the surface above it, as Cesium's quantized-mesh skirts do.
fn mesh_normals(mesh: &Mesh, top: &[[u32; 3]], tops: &[u32], place: &Placement) -> Vec<[i8; 3]> {
    let g: Vec<glam::DVec3> =
        mesh.positions.iter().map(|p| glam::DVec3::from_array(place.gltf_of(*p))).collect();
    let mut sums = vec![glam::DVec3::ZERO; g.len()];
    for t in top {
        let [a, b, c] = t.map(|i| g[i as usize]);
        let n = (b - a).cross(c - a);
        for &i in t {
            sums[i as usize] += n;
        }
    }
    let first_skirt = g.len() - tops.len();
    for (k, &top) in tops.iter().enumerate() {
        sums[first_skirt + k] = sums[top as usize];
    }
    // A vertex of no triangle (there are none in a decoded mesh) points up.
    sums.iter().map(|s| oct_free_i8(if s.length() > 0.0 { s.to_array() } else { [0.0, 1.0, 0.0] })).collect()
}

/// Positions on the blob's grid, per glTF axis: the stored integers, the node's translation
/// (relative to the placement origin) and scale (the grid step).
struct Positions {
    ints: Vec<[u32; 3]>,
    translation: [f64; 3],
    scale: [f64; 3],
    max: [u32; 3],
}

impl Positions {
    fn new(world: &[[f64; 3]], min: [f64; 3], step: [f64; 3], place: &Placement) -> Self {
        let q: Vec<[i64; 3]> = world
            .iter()
            .map(|p| std::array::from_fn(|a| ((p[a] - min[a]) / step[a]).round() as i64))
            .collect();
        let (mut lo, mut hi) = ([i64::MAX; 3], [i64::MIN; 3]);
        for p in &q {
            for a in 0..3 {
                lo[a] = lo[a].min(p[a]);
                hi[a] = hi[a].max(p[a]);
            }
        }
        if q.is_empty() {
            (lo, hi) = ([0; 3], [0; 3]);
        }
        let map = place.axis_map();
        let ints = q
            .iter()
            .map(|p| map.map(|(a, s)| if s > 0.0 { p[a] - lo[a] } else { hi[a] - p[a] } as u32))
            .collect();
        let translation = map.map(|(a, s)| {
            let base = if s > 0.0 { lo[a] } else { hi[a] };
            s * (min[a] + base as f64 * step[a] - place.origin[a])
        });
        let scale = map.map(|(a, _)| step[a]);
        let max = map.map(|(a, _)| (hi[a] - lo[a]) as u32);
        Self { ints, translation, scale, max }
    }

    fn fits_u16(&self) -> bool {
        self.max.iter().all(|&m| u16::try_from(m).is_ok())
    }
}

/// The `BYTE`-normalized unit vector nearest in direction to `n` whose length passes glTF
/// validators (|len − 1| small): rounding each component alone can miss by 0.7 %.
fn oct_free_i8(n: [f64; 3]) -> [i8; 3] {
    let len = (n[0] * n[0] + n[1] * n[1] + n[2] * n[2]).sqrt();
    let u = if len > 0.0 && len.is_finite() { n.map(|c| c / len) } else { [0.0, 0.0, 1.0] };
    let base = u.map(|c| (c * 127.0).round());
    let mut best = (f64::INFINITY, [0i8; 3]);
    for d in 0..27 {
        let c: [f64; 3] = std::array::from_fn(|a| {
            (base[a] + f64::from((d / 3_i32.pow(a as u32)) % 3 - 1)).clamp(-127.0, 127.0)
        });
        let l = (c[0] * c[0] + c[1] * c[1] + c[2] * c[2]).sqrt() / 127.0;
        if l == 0.0 {
            continue;
        }
        let cos = (c[0] * u[0] + c[1] * u[1] + c[2] * u[2]) / (l * 127.0);
        let score = (1.0 - cos) + (l - 1.0).abs() * 4.0;
        if score < best.0 {
            best = (score, c.map(|v| v as i8));
        }
    }
    best.1
}

/// A glTF document being put together: its JSON and its one binary buffer.
struct Gltf {
    json: Value,
    bin: Vec<u8>,
}

impl Gltf {
    fn new(key: TileKey, level: u8) -> Self {
        Self {
            json: json!({
                "asset": { "version": "2.0", "generator": GENERATOR },
                "scene": 0,
                "scenes": [{ "nodes": [0] }],
                "bufferViews": [],
                "accessors": [],
                "extras": { "terrastream": { "key": key.to_string(), "level": level } },
            }),
            bin: Vec::new(),
        }
    }

    /// Appends a buffer view (4-byte aligned) and returns its index.
    fn view(&mut self, bytes: &[u8], stride: Option<usize>, target: u32) -> usize {
        while !self.bin.len().is_multiple_of(4) {
            self.bin.push(0);
        }
        let mut v =
            json!({ "buffer": 0, "byteOffset": self.bin.len(), "byteLength": bytes.len(), "target": target });
        if let Some(s) = stride {
            v["byteStride"] = json!(s);
        }
        self.bin.extend_from_slice(bytes);
        push(&mut self.json, "bufferViews", v)
    }

    fn accessor(&mut self, a: Value) -> usize {
        push(&mut self.json, "accessors", a)
    }

    fn positions(&mut self, p: &Positions) -> usize {
        let count = p.ints.len();
        let (view, component) = if p.fits_u16() {
            let mut b = Vec::with_capacity(count * 8);
            for v in &p.ints {
                for c in v {
                    b.extend_from_slice(&(*c as u16).to_le_bytes());
                }
                b.extend_from_slice(&[0, 0]);
            }
            (self.view(&b, Some(8), ARRAY_BUFFER), GLTF_U16)
        } else {
            let mut b = Vec::with_capacity(count * 12);
            for v in &p.ints {
                for c in v {
                    b.extend_from_slice(&(*c as f32).to_le_bytes());
                }
            }
            (self.view(&b, Some(12), ARRAY_BUFFER), GLTF_FLOAT)
        };
        let (mut lo, mut hi) = ([u32::MAX; 3], [0u32; 3]);
        for v in &p.ints {
            for a in 0..3 {
                lo[a] = lo[a].min(v[a]);
                hi[a] = hi[a].max(v[a]);
            }
        }
        if p.ints.is_empty() {
            lo = [0; 3];
        }
        let acc = self.accessor(json!({
            "bufferView": view, "componentType": component, "count": count, "type": "VEC3",
            "min": lo, "max": hi,
        }));
        if component == GLTF_U16 {
            self.json["extensionsUsed"] = json!(["KHR_mesh_quantization"]);
            self.json["extensionsRequired"] = json!(["KHR_mesh_quantization"]);
        }
        self.json["nodes"] = json!([{ "mesh": 0, "translation": p.translation, "scale": p.scale }]);
        acc
    }

    /// Unit normals as `BYTE` normalized (`KHR_mesh_quantization`), padded to 4 bytes each.
    fn normals(&mut self, normals: &[[i8; 3]]) -> usize {
        let b: Vec<u8> = normals.iter().flat_map(|n| [n[0] as u8, n[1] as u8, n[2] as u8, 0]).collect();
        let view = self.view(&b, Some(4), ARRAY_BUFFER);
        self.json["extensionsUsed"] = json!(["KHR_mesh_quantization"]);
        self.json["extensionsRequired"] = json!(["KHR_mesh_quantization"]);
        self.accessor(json!({
            "bufferView": view, "componentType": GLTF_I8, "normalized": true, "count": normals.len(), "type": "VEC3",
        }))
    }

    fn material(&mut self, rgb: [f64; 3], points: bool) {
        self.json["materials"] = json!([{
            "name": if points { "points" } else { "terrain" },
            "pbrMetallicRoughness": {
                "baseColorFactor": [rgb[0], rgb[1], rgb[2], 1.0],
                "metallicFactor": 0.0,
                "roughnessFactor": 1.0,
            },
        }]);
    }

    fn mesh(p: &Positions, tris: &[[u32; 3]], normals: &[[i8; 3]], key: TileKey, level: u8) -> Self {
        let mut g = Self::new(key, level);
        let pos = g.positions(p);
        let nrm = g.normals(normals);
        let (view, component) = if p.ints.len() <= MAX_U16_VERTICES {
            let b: Vec<u8> = tris.iter().flatten().flat_map(|&i| (i as u16).to_le_bytes()).collect();
            (g.view(&b, None, ELEMENT_ARRAY_BUFFER), GLTF_U16)
        } else {
            let b: Vec<u8> = tris.iter().flatten().flat_map(|&i| i.to_le_bytes()).collect();
            (g.view(&b, None, ELEMENT_ARRAY_BUFFER), GLTF_U32)
        };
        let idx =
            g.accessor(json!({ "bufferView": view, "componentType": component, "count": tris.len() * 3, "type": "SCALAR" }));
        g.material([0.64, 0.60, 0.50], false);
        g.json["meshes"] = json!([{ "primitives": [{ "attributes": { "POSITION": pos, "NORMAL": nrm }, "indices": idx, "mode": 4, "material": 0 }] }]);
        g
    }

    fn points(p: &Positions, normals: &[[i8; 3]], key: TileKey, level: u8) -> Self {
        let mut g = Self::new(key, level);
        let pos = g.positions(p);
        let nrm = g.normals(normals);
        g.material([0.78, 0.70, 0.52], true);
        g.json["meshes"] = json!([{
            "primitives": [{ "attributes": { "POSITION": pos, "NORMAL": nrm }, "mode": 0, "material": 0 }]
        }]);
        g
    }

    /// The GLB container: header, JSON chunk (space-padded), BIN chunk (zero-padded).
    fn finish(mut self) -> Vec<u8> {
        while !self.bin.len().is_multiple_of(4) {
            self.bin.push(0);
        }
        self.json["buffers"] = json!([{ "byteLength": self.bin.len() }]);
        let mut text = serde_json::to_vec(&self.json).unwrap_or_default();
        while !text.len().is_multiple_of(4) {
            text.push(b' ');
        }
        let total = 12 + 8 + text.len() + 8 + self.bin.len();
        let mut out = Vec::with_capacity(total);
        out.extend_from_slice(b"glTF");
        out.extend_from_slice(&2u32.to_le_bytes());
        out.extend_from_slice(&(total as u32).to_le_bytes());
        out.extend_from_slice(&(text.len() as u32).to_le_bytes());
        out.extend_from_slice(&0x4E4F_534Au32.to_le_bytes());
        out.extend_from_slice(&text);
        out.extend_from_slice(&(self.bin.len() as u32).to_le_bytes());
        out.extend_from_slice(&0x004E_4942u32.to_le_bytes());
        out.extend_from_slice(&self.bin);
        out
    }
}

fn push(doc: &mut Value, array: &str, v: Value) -> usize {
    if let Some(a) = doc.get_mut(array).and_then(Value::as_array_mut) {
        a.push(v);
        a.len() - 1
    } else {
        doc[array] = json!([v]);
        0
    }
}

// ---------------------------------------------------------------------------------------------
// Tileset JSON

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
        }
    }

    /// The info of a tileset from its manifest as JSON (a terrain or model manifest, or an
    /// on-demand tileset's provisional one, which says `"on_demand": true`).
    pub fn from_manifest_json(
        name: &str,
        bytes: &[u8],
        anchor: Option<Anchor>,
        query: String,
    ) -> Result<Self, String> {
        let v: Value = serde_json::from_slice(bytes).map_err(|e| format!("manifest: {e}"))?;
        let kind = match v.get("kind") {
            None => TilesetKind::Terrain,
            Some(k) => TilesetKind::deserialize(k)
                .map_err(|_| format!("manifest: `kind` is {k}, not terrain or model"))?,
        };
        let manifest = Manifest::deserialize(&v).map_err(|e| format!("manifest: {e}"))?;
        let place = Placement::of(&manifest, kind, anchor);
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
    fn planned_bounds(&self, key: TileKey) -> Bounds {
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
                errors: Errors { max: bound, rms: 0.0, gap: 0.0 },
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
#[must_use]
pub fn chunk_tileset(info: &TilesetInfo, chunk: &IndexChunk, root: bool) -> Value {
    let nodes: std::collections::HashMap<TileKey, &NodeEntry> =
        chunk.nodes.iter().map(|n| (n.key, n)).collect();
    let pre = prefix(root);
    let mut tile = node_tiles(info, &nodes, chunk.root, chunk.root, pre)
        .unwrap_or_else(|| json!({ "boundingVolume": { "box": info.place.enu_box(&info.manifest.bounds) }, "geometricError": 0.0 }));
    let head_error = tile["geometricError"].as_f64().unwrap_or(0.0);
    let mut asset =
        json!({ "version": "1.1", "generator": GENERATOR, "tilesetVersion": info.manifest.content_version });
    let geometric_error = if root {
        tile["transform"] = json!(info.place.anchor.enu_to_ecef());
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
    json!({ "asset": asset, "geometricError": geometric_error, "root": tile })
}

/// The chain of tiles of node `key` (coarsest level first), with its children below level 0.
fn node_tiles(
    info: &TilesetInfo,
    nodes: &std::collections::HashMap<TileKey, &NodeEntry>,
    chunk: TileKey,
    key: TileKey,
    pre: &str,
) -> Option<Value> {
    let planned;
    let (node, provisional) = match nodes.get(&key) {
        Some(n) => (*n, false),
        None if info.provisional => {
            planned = info.planned_node(key)?;
            (&planned, true)
        }
        None => return None,
    };
    let last = key.z >= chunk.z.saturating_add(SUBTREE_LEVELS - 1);
    let children: Vec<Value> = info
        .children(key)
        .into_iter()
        .filter_map(|c| {
            if last {
                Some(reference_tile(info, node, c, pre))
            } else {
                node_tiles(info, nodes, chunk, c, pre)
            }
        })
        .collect();
    let mut below = children;
    let mut head = None;
    for l in &node.levels {
        let t = level_tile(info, node, l, std::mem::take(&mut below), pre, provisional);
        below = vec![t.clone()];
        head = Some(t);
    }
    head
}

fn level_tile(
    info: &TilesetInfo,
    node: &NodeEntry,
    l: &NodeLevel,
    children: Vec<Value>,
    pre: &str,
    provisional: bool,
) -> Value {
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
        "boundingVolume": { "box": info.place.enu_box(&b) },
        "geometricError": l.errors.geometric(),
        "refine": "REPLACE",
        "content": { "uri": format!("{pre}tiles/{}/{}/{}/{}.glb{}", key.z, key.x, key.y, l.level, info.query) },
        "extras": { "terrastream": extras },
    });
    if !children.is_empty() {
        t["children"] = Value::Array(children);
    }
    t
}

/// A tile standing for the subtree of `child` (a chunk root below this chunk): its content is
/// that chunk's external tileset. Its box is the child's extent at the dataset's height range
/// and its error the parent's mesh error (the chunk file says the rest).
fn reference_tile(info: &TilesetInfo, parent: &NodeEntry, child: TileKey, pre: &str) -> Value {
    let mut b = info.planned_bounds(child);
    let parent_error = parent.levels.first().map_or(0.0, |l| l.errors.max);
    b.min.z = b.min.z.min(parent.bounds.min.z) - mesh_skirt_depth(parent_error);
    b.max.z = b.max.z.max(parent.bounds.max.z);
    json!({
        "boundingVolume": { "box": info.place.enu_box(&b) },
        "geometricError": parent.levels.first().map_or(0.0, |l| l.errors.geometric()),
        "refine": "REPLACE",
        "content": { "uri": format!("{pre}index/{}/{}/{}.json{}", child.z, child.x, child.y, info.query) },
        "extras": { "terrastream": { "key": child.to_string(), "subtree": true } },
    })
}

#[cfg(test)]
mod tests;
