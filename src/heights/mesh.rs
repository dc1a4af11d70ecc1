//! `surface=mesh`: heights on the TIN a client draws, read from the tileset's blobs. A point
//! lies in one node of the chosen depth (the finest by default: exactly what a client draws at
//! full detail); its level-0 blob (the node's TIN) is decoded once, its triangles bucketed in a
//! grid, and kept in a bounded cache; the answer is the height of the triangle under the point
//! and the level's measured maximum error. The blobs come from any [`BlobSource`] (a directory,
//! a bucket, an archive, or built on demand): the same bytes give the same heights.

use std::collections::{HashMap, VecDeque};
use std::sync::{Arc, Mutex};

use super::{Coords, Datum, Height, HeightsError, Query, check};
use crate::codec::{Geometry, decode};
use crate::crs::{Frame, Geoid};
use crate::raster::Georef;
use crate::tiling::{Pyramid, TileKey};

/// Where a [`MeshSampler`] gets a node's level-0 blob: `Ok(None)` when the node has none.
pub trait BlobSource: Sync {
    fn blob(&self, key: TileKey) -> Result<Option<Vec<u8>>, String>;
}

/// A node's TIN ready for point queries, as the bake measured it: vertices on the raster's
/// sample grid (column, row), triangles bucketed in a `cells × cells` grid over the node's box.
/// On a placed tileset the client draws each triangle as a chord of the curved Earth, and the
/// bake measured the TIN on heights lowered by the Earth's drop below the plane tangent at the
/// node's centre (`d²/2R`, [`crate::crs::ecef::MEAN_RADIUS`], the bake's): so here too a point's height is the
/// planar interpolation (in sample space) of the lowered corner heights plus its own drop, the
/// drawn surface's height to second order and what the stored error bounds.
struct NodeMesh {
    /// Column, row and the (lowered) height of each vertex.
    positions: Vec<[f64; 3]>,
    /// The node's centre (world) for the drop; `None` in a local (flat) frame.
    centre: Option<[f64; 2]>,
    triangles: Vec<[u32; 3]>,
    lo: [f64; 2],
    size: [f64; 2],
    cells: usize,
    /// Per cell, the triangles whose bounding box meets it (CSR: `start[c]..start[c + 1]`).
    start: Vec<u32>,
    items: Vec<u32>,
    error: f64,
    bytes: usize,
}

/// Barycentric slack: a point this close outside a triangle (in units of its coordinates) is on it.
const TOL: f64 = -1e-9;

impl NodeMesh {
    fn new(positions: Vec<[f64; 3]>, triangles: Vec<[u32; 3]>, error: f64, centre: Option<[f64; 2]>) -> Self {
        let (mut lo, mut hi) = ([f64::INFINITY; 2], [f64::NEG_INFINITY; 2]);
        for p in &positions {
            for k in 0..2 {
                lo[k] = lo[k].min(p[k]);
                hi[k] = hi[k].max(p[k]);
            }
        }
        let size = [(hi[0] - lo[0]).max(f64::MIN_POSITIVE), (hi[1] - lo[1]).max(f64::MIN_POSITIVE)];
        let cells = ((triangles.len() as f64).sqrt() as usize).clamp(1, 256);
        let cell_of = |v: f64, k: usize| (((v - lo[k]) / size[k] * cells as f64) as usize).min(cells - 1);
        let bbox = |t: &[u32; 3]| {
            let p = t.map(|v| positions[v as usize]);
            let (x0, x1) = (p[0][0].min(p[1][0]).min(p[2][0]), p[0][0].max(p[1][0]).max(p[2][0]));
            let (y0, y1) = (p[0][1].min(p[1][1]).min(p[2][1]), p[0][1].max(p[1][1]).max(p[2][1]));
            (cell_of(x0, 0), cell_of(x1, 0), cell_of(y0, 1), cell_of(y1, 1))
        };
        let mut count = vec![0u32; cells * cells + 1];
        for t in &triangles {
            let (i0, i1, j0, j1) = bbox(t);
            for j in j0..=j1 {
                for i in i0..=i1 {
                    count[j * cells + i + 1] += 1;
                }
            }
        }
        for c in 1..count.len() {
            count[c] += count[c - 1];
        }
        let mut fill = count.clone();
        let mut items = vec![0u32; count[cells * cells] as usize];
        for (k, t) in triangles.iter().enumerate() {
            let (i0, i1, j0, j1) = bbox(t);
            for j in j0..=j1 {
                for i in i0..=i1 {
                    let c = j * cells + i;
                    items[fill[c] as usize] = k as u32;
                    fill[c] += 1;
                }
            }
        }
        let bytes = positions.len() * 24 + triangles.len() * 12 + items.len() * 4 + count.len() * 4;
        Self { positions, centre, triangles, lo, size, cells, start: count, items, error, bytes }
    }

    /// The height of the surface at (x, y): the first triangle (in stored order) that holds the
    /// point; else, for a point just outside the mesh (rounding of its position or of the
    /// stored vertices), the triangle it is least outside of, if within [`EDGE_SLACK`] of it;
    /// else `None`.
    fn height(&self, x: f64, y: f64) -> Option<f64> {
        let cell = |v: f64, k: usize| {
            let t = (v - self.lo[k]) / self.size[k];
            (-EDGE_SLACK..=1.0 + EDGE_SLACK)
                .contains(&t)
                .then(|| ((t.max(0.0) * self.cells as f64) as usize).min(self.cells - 1))
        };
        let c = cell(y, 1)? * self.cells + cell(x, 0)?;
        let mut best: Option<(f64, f64)> = None;
        for &k in &self.items[self.start[c] as usize..self.start[c + 1] as usize] {
            let [a, b, d] = self.triangles[k as usize].map(|v| self.positions[v as usize]);
            let det = (b[0] - a[0]) * (d[1] - a[1]) - (d[0] - a[0]) * (b[1] - a[1]);
            if det == 0.0 {
                continue;
            }
            let l1 = ((x - a[0]) * (d[1] - a[1]) - (d[0] - a[0]) * (y - a[1])) / det;
            let l2 = ((b[0] - a[0]) * (y - a[1]) - (x - a[0]) * (b[1] - a[1])) / det;
            let l0 = 1.0 - l1 - l2;
            let inside = l0.min(l1).min(l2);
            let h = l0 * a[2] + l1 * b[2] + l2 * d[2];
            if inside >= TOL {
                return Some(h);
            }
            if inside >= -EDGE_SLACK && best.is_none_or(|(w, _)| inside > w) {
                best = Some((inside, h));
            }
        }
        best.map(|(_, h)| h)
    }
}

/// How far (as a fraction of a triangle, or of the node's box) a point may lie outside and still
/// be answered by the nearest triangle: far above the rounding of positions, far below a cell.
const EDGE_SLACK: f64 = 1e-6;

/// The drop of the Earth's surface at world (x, y) below the plane tangent at `c`.
fn drop(c: [f64; 2], x: f64, y: f64) -> f64 {
    ((x - c[0]).powi(2) + (y - c[1]).powi(2)) / (2.0 * crate::crs::ecef::MEAN_RADIUS)
}

/// Decoded nodes kept up to a byte budget, oldest out first; shared by samplers (and so by
/// requests) through an `Arc`. Keys carry a tag (e.g. a tileset's load generation), so one
/// cache serves several tilesets.
pub struct MeshCache {
    inner: Mutex<CacheInner>,
    budget: usize,
}

struct CacheInner {
    nodes: HashMap<(u64, TileKey), Arc<NodeMesh>>,
    order: VecDeque<(u64, TileKey)>,
    bytes: usize,
}

impl MeshCache {
    /// A cache of up to `budget` bytes of decoded nodes.
    #[must_use]
    pub fn new(budget: usize) -> Self {
        Self {
            inner: Mutex::new(CacheInner { nodes: HashMap::new(), order: VecDeque::new(), bytes: 0 }),
            budget,
        }
    }

    /// Whether node `key` of tag `tag` is held.
    #[must_use]
    pub fn contains(&self, tag: u64, key: TileKey) -> bool {
        self.inner.lock().is_ok_and(|c| c.nodes.contains_key(&(tag, key)))
    }

    fn get(&self, tag: u64, key: TileKey) -> Result<Option<Arc<NodeMesh>>, HeightsError> {
        Ok(self.inner.lock().map_err(|_| HeightsError::Poisoned)?.nodes.get(&(tag, key)).cloned())
    }

    fn put(&self, tag: u64, key: TileKey, mesh: Arc<NodeMesh>) -> Result<(), HeightsError> {
        let mut c = self.inner.lock().map_err(|_| HeightsError::Poisoned)?;
        let bytes = mesh.bytes;
        if let Some(old) = c.nodes.insert((tag, key), mesh) {
            c.bytes -= old.bytes;
        } else {
            c.order.push_back((tag, key));
        }
        c.bytes += bytes;
        while c.bytes > self.budget && c.order.len() > 1 {
            let Some(old) = c.order.pop_front() else { break };
            if let Some(n) = c.nodes.remove(&old) {
                c.bytes -= n.bytes;
            }
        }
        Ok(())
    }
}

/// Heights on a tileset's TINs. Batched (each node of a batch is read and decoded once) and
/// cached (decoded nodes in a [`MeshCache`], which may outlive the sampler).
pub struct MeshSampler<S: BlobSource> {
    source: S,
    pyramid: Pyramid,
    georef: Georef,
    frame: Option<Frame>,
    egm96: Arc<Geoid>,
    cache: Arc<MeshCache>,
    tag: u64,
}

impl<S: BlobSource> MeshSampler<S> {
    /// The TINs of a tileset whose samples lie on `georef`'s grid in `pyramid`, read from
    /// `source`, keeping up to `cache_bytes` of decoded nodes.
    pub fn new(
        source: S,
        pyramid: Pyramid,
        georef: &Georef,
        cache_bytes: usize,
    ) -> Result<Self, HeightsError> {
        Self::with_cache(source, pyramid, georef, Arc::new(MeshCache::new(cache_bytes)), 0)
    }

    /// [`MeshSampler::new`] keeping decoded nodes in `cache` under `tag`.
    pub fn with_cache(
        source: S,
        pyramid: Pyramid,
        georef: &Georef,
        cache: Arc<MeshCache>,
        tag: u64,
    ) -> Result<Self, HeightsError> {
        let frame = georef.frame().map_err(|e| HeightsError::Frame(e.to_string()))?;
        let egm96 = Geoid::egm96().map_err(|e| HeightsError::Frame(e.to_string()))?;
        Ok(Self { source, pyramid, georef: georef.clone(), frame, egm96, cache, tag })
    }

    /// The depth of the finest nodes (the default `depth` of [`MeshSampler::sample`]).
    #[must_use]
    pub fn depth(&self) -> u8 {
        self.pyramid.depth
    }

    /// The answers for `points` on the TINs of the nodes at `depth` (`q.interp` does not apply).
    pub fn sample(&self, points: &[[f64; 2]], q: Query, depth: u8) -> Result<Vec<Height>, HeightsError> {
        self.sample_from(points, q, depth, 0)
    }

    /// [`MeshSampler::sample`] of a batch whose first point is point `base` of a larger one
    /// (errors name points by their index in that).
    pub fn sample_from(
        &self,
        points: &[[f64; 2]],
        q: Query,
        depth: u8,
        base: usize,
    ) -> Result<Vec<Height>, HeightsError> {
        let at = Placement { frame: self.frame.as_ref(), georef: &self.georef, pyramid: self.pyramid };
        let located = at.locate_all(points, q, depth, base)?;
        let mut order: Vec<usize> = (0..points.len()).collect();
        order.sort_by_key(|&k| located[k].2.map(|key| (key.y, key.x)));
        let mut out = vec![Height::NODATA; points.len()];
        let mut current: Option<(TileKey, Option<Arc<NodeMesh>>)> = None;
        for k in order {
            let ([x, y], lonlat, key) = located[k];
            let Some(key) = key else { continue };
            if current.as_ref().is_none_or(|c| c.0 != key) {
                current = Some((key, self.node(key)?));
            }
            let Some(Some(mesh)) = current.as_ref().map(|c| c.1.as_ref()) else { continue };
            let g = &self.georef;
            let Some(h) = mesh.height((x - g.x0) / g.dx, (y - g.y0) / g.dy) else { continue };
            let h = h + mesh.centre.map_or(0.0, |c| drop(c, x, y));
            let h = super::to_datum(h, q.datum, self.frame.as_ref(), lonlat, &self.egm96, base + k)?;
            out[k] = Height { h, error: mesh.error, nodata: false };
        }
        Ok(out)
    }

    /// Node `key`'s TIN, from the cache or read, decoded and kept.
    fn node(&self, key: TileKey) -> Result<Option<Arc<NodeMesh>>, HeightsError> {
        if let Some(n) = self.cache.get(self.tag, key)? {
            return Ok(Some(n));
        }
        let Some(bytes) = self.source.blob(key).map_err(|message| HeightsError::Blob { key, message })?
        else {
            return Ok(None);
        };
        let blob = decode(&bytes).map_err(|e| HeightsError::Blob { key, message: e.to_string() })?;
        let Geometry::Mesh(m) = blob.geometry else {
            return Err(HeightsError::Blob { key, message: "level 0 is not a mesh".into() });
        };
        let centre = self.frame.as_ref().map(|_| {
            let s = self.pyramid.span(key);
            let g = &self.georef;
            let (c, r) = (f64::from(s.col0 + s.col1) / 2.0, f64::from(s.row0 + s.row1) / 2.0);
            [g.x0 + c * g.dx, g.y0 + r * g.dy]
        });
        // On the sample grid (the bake's vertices are samples; the blob's positions are rounded
        // to its quantization), the heights lowered by the drop of their stored position.
        let g = &self.georef;
        let positions = m
            .positions
            .iter()
            .map(|p| {
                let lowered = p[2] - centre.map_or(0.0, |c| drop(c, p[0], p[1]));
                [((p[0] - g.x0) / g.dx).round(), ((p[1] - g.y0) / g.dy).round(), lowered]
            })
            .collect();
        let mesh = Arc::new(NodeMesh::new(positions, m.triangles, blob.header.errors.max, centre));
        self.cache.put(self.tag, key, mesh.clone())?;
        Ok(Some(mesh))
    }
}

/// Where points fall in a tileset: its frame, grid and pyramid.
struct Placement<'a> {
    frame: Option<&'a Frame>,
    georef: &'a Georef,
    pyramid: Pyramid,
}

impl Placement<'_> {
    /// Every point located (checked first: a bad point is refused before any is answered).
    fn locate_all(
        &self,
        points: &[[f64; 2]],
        q: Query,
        depth: u8,
        base: usize,
    ) -> Result<Vec<Located>, HeightsError> {
        if depth > self.pyramid.depth {
            return Err(HeightsError::Depth { depth, max: self.pyramid.depth });
        }
        if self.frame.is_none() && (q.coords != Coords::Local || q.datum != Datum::Native) {
            return Err(HeightsError::NotPlaced { coords: q.coords.name(), datum: q.datum.name() });
        }
        for (index, p) in points.iter().enumerate() {
            check(base + index, *p, q.coords)?;
        }
        Ok(points.iter().map(|&p| self.locate(p, q.coords, depth)).collect())
    }

    /// A point's world (x, y), its WGS 84 position (placed tilesets) and the node at `depth`
    /// that holds it (`None` outside the raster, or where the point has no place in the
    /// tileset's CRS: a projection's domain ends short of the globe).
    fn locate(&self, p: [f64; 2], coords: Coords, depth: u8) -> Located {
        const NOWHERE: Located = ([f64::NAN; 2], None, None);
        let g = self.georef;
        let (world, lonlat) = match (self.frame, coords) {
            (None, _) => (p, None),
            (Some(f), Coords::Local) => {
                let (e, n) = f.crs_xy(p[0], p[1]);
                let Ok(ll) = f.grid.crs.to_wgs84(e, n) else { return NOWHERE };
                (p, Some(ll))
            }
            (Some(f), Coords::Crs) => {
                let (x, y) = f.world_xy(p[0], p[1]);
                let Ok(ll) = f.grid.crs.to_wgs84(p[0], p[1]) else { return NOWHERE };
                ([x, y], Some(ll))
            }
            (Some(f), Coords::Wgs84) => {
                let lon = crate::crs::wrap_lon(p[0]);
                let Ok((mut e, n)) = f.grid.crs.from_wgs84(lon, p[1]) else { return NOWHERE };
                if !(e.is_finite() && n.is_finite()) {
                    return NOWHERE;
                }
                if f.grid.crs.is_geographic() {
                    // A grid in 0…360 asked in −180…180, or the other way round.
                    let inside = |e: f64| {
                        let c = (e - f.grid.e0) / f.grid.de;
                        c >= -EDGE_SLACK && c <= f64::from(self.pyramid.width - 1) + EDGE_SLACK
                    };
                    if !inside(e) {
                        e = [e + 360.0, e - 360.0].into_iter().find(|&v| inside(v)).unwrap_or(e);
                    }
                }
                let (x, y) = f.world_xy(e, n);
                ([x, y], Some((lon, p[1])))
            }
        };
        let (c, r) = ((world[0] - g.x0) / g.dx, (world[1] - g.y0) / g.dy);
        let (w, h) = (f64::from(self.pyramid.width - 1), f64::from(self.pyramid.height - 1));
        // Points a rounding outside the outermost samples are on them.
        let near = |v: f64, hi: f64| (-EDGE_SLACK..=hi + EDGE_SLACK).contains(&v);
        let key = (near(c, w) && near(r, h)).then(|| {
            let cells = f64::from(self.pyramid.tile_size) * f64::from(self.pyramid.step(depth));
            let (nx, ny) = self.pyramid.nodes_at(depth);
            let x = ((c.max(0.0) / cells) as u32).min(nx - 1);
            let y = ((r.max(0.0) / cells) as u32).min(ny - 1);
            TileKey::new(depth, x, y)
        });
        (world, lonlat, key)
    }
}

/// The nodes at `depth` that `points` (in `coords`) fall in, each once, in (y, x) order: what a
/// [`MeshSampler`] of those points reads.
pub fn nodes_of(
    points: &[[f64; 2]],
    coords: Coords,
    pyramid: Pyramid,
    georef: &Georef,
    depth: u8,
) -> Result<Vec<TileKey>, HeightsError> {
    let frame = georef.frame().map_err(|e| HeightsError::Frame(e.to_string()))?;
    let at = Placement { frame: frame.as_ref(), georef, pyramid };
    let q = Query {
        coords,
        datum: if frame.is_some() { Datum::Ellipsoid } else { Datum::Native },
        ..Query::default()
    };
    let mut keys: Vec<TileKey> =
        at.locate_all(points, q, depth, 0)?.into_iter().filter_map(|l| l.2).collect();
    keys.sort_by_key(|k| (k.y, k.x));
    keys.dedup();
    Ok(keys)
}

/// A point's world (x, y), WGS 84 (lon, lat) and node.
type Located = ([f64; 2], Option<(f64, f64)>, Option<TileKey>);

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_point_gets_the_height_of_the_triangle_under_it() {
        // Two triangles over the unit square, z = x + 2y on both.
        let p = vec![[0.0, 0.0, 0.0], [1.0, 0.0, 1.0], [1.0, 1.0, 3.0], [0.0, 1.0, 2.0]];
        let m = NodeMesh::new(p, vec![[0, 1, 2], [0, 2, 3]], 0.5, None);
        for (x, y) in [(0.25, 0.1), (0.1, 0.9), (0.5, 0.5), (1.0, 1.0), (0.0, 0.0), (1.0, 0.3)] {
            let h = m.height(x, y).unwrap();
            assert!((h - (x + 2.0 * y)).abs() < 1e-12, "({x}, {y}): {h}");
        }
        assert_eq!(m.height(1.01, 0.5), None);
        // A rounding outside the edge is on it.
        assert!((m.height(1.0 + 1e-9, 0.5).unwrap() - 2.0).abs() < 1e-6);
        assert_eq!(m.height(-0.01, 0.5), None);
    }
}
