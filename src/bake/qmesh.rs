//! Quantized-mesh globe terrain from a placed dataset: each tile's samples read from the
//! source (any CRS, through its block cache: out of core), converted to ellipsoidal heights,
//! built by [`crate::formats::qmesh`]; and the bake of every tile into a store (`terrain/`). The
//! server's on-demand tiles call [`TerrainSource::tile`], which is the same function: on-demand
//! and baked tiles are byte-identical.

use std::sync::Arc;
use std::sync::atomic::{AtomicU64, Ordering};
use std::time::Instant;

use rayon::prelude::*;

use crate::crs::{Frame, Geoid};
use crate::formats::qmesh::grid::{CELLS, MAX_ZOOM, Rect, TileId, canonical_lon, zoom_for_cell};
use crate::formats::qmesh::layer::{Coverage, layer_json};
use crate::formats::qmesh::{BuiltTile, Extensions, SIDE, TileSamples, build_tile, filter_extensions};
use crate::raster::{Georef, RasterError, WindowReader};

/// Folder of a store that holds the terrain.
pub const TERRAIN_DIR: &str = "terrain";

/// Why terrain cannot be made.
#[derive(Debug, thiserror::Error)]
pub enum TerrainError {
    #[error(
        "globe terrain needs a dataset placed on the Earth; this one has no coordinate reference system (give --crs)"
    )]
    NotPlaced,
    #[error("{0}")]
    Frame(String),
    #[error(transparent)]
    Raster(#[from] RasterError),
    #[error(transparent)]
    Build(#[from] crate::formats::qmesh::BuildError),
    #[error(transparent)]
    Store(#[from] crate::store::StoreError),
    #[error(transparent)]
    Codec(#[from] crate::formats::qmesh::QmError),
    #[error("--terrain-error-scale must be finite and > 0, got {0}")]
    Scale(f64),
    #[error(
        "globe terrain holds ellipsoidal heights within ±32,000 m; the dataset's heights reach {lo:.1} … {hi:.1} m: \
         are they in decimetres or centimetres (--z-scale 0.1 or 0.01), or is an undeclared no-data \
         value among them?"
    )]
    Heights { lo: f32, hi: f32 },
}

/// The terrain options a user sets.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TerrainOptions {
    /// Scales every zoom's error bound (1: CesiumJS's own estimate for the zoom).
    pub error_scale: f64,
    /// The deepest zoom; `None`: where a tile's cells match the source's.
    pub max_zoom: Option<u8>,
}

impl Default for TerrainOptions {
    fn default() -> Self {
        Self { error_scale: 1.0, max_zoom: None }
    }
}

/// A dataset as a source of terrain tiles.
pub struct TerrainSource<'a> {
    reader: &'a dyn WindowReader,
    frame: Frame,
    width: u32,
    height: u32,
    sea: Arc<Geoid>,
    pub coverage: Coverage,
    /// The most relief a tile can have ([`TileSamples::relief`]), from the dataset's heights.
    relief: Option<f64>,
    /// Where a WGS 84 point can fall on the source at all (the coverage, widened by a margin),
    /// for a projected source: outside it a sample is no data without being transformed.
    /// `None` where the test would not be safe (a geographic source, the antimeridian, a pole).
    near: Option<Vec<Rect>>,
    pub options: TerrainOptions,
}

/// A pixel position's four neighbours (first and second column, first and second row) and its
/// bilinear weights.
type Corners = (u32, u32, u32, u32, f64, f64);

/// The smallest cell (samples a side) or line segment over which sample positions in the source
/// CRS are interpolated rather than transformed one by one (see `TerrainSource::pixels`).
const LATTICE: i64 = 8;
/// The largest error (source pixels) an interpolated CRS position may have where it is checked;
/// a cell or segment over it is halved, and below [`LATTICE`] transformed exactly.
const LATTICE_TOLERANCE_PX: f64 = 0.01;

/// The coverage of a projected source widened by a tenth of its larger side (at least 0.01°,
/// about 1 km), far more than the outline's sampling can miss between its points; `None` for a
/// geographic source (its transform is cheap, and 0…360° rasters wrap) or where a widened
/// rectangle would cross the antimeridian or come within a degree of a pole.
fn near_rects(rects: &[Rect], geographic: bool) -> Option<Vec<Rect>> {
    if geographic || rects.is_empty() {
        return None;
    }
    rects
        .iter()
        .map(|r| {
            let m = ((r.east - r.west).max(r.north - r.south) * 0.1).max(0.01);
            let w = Rect { west: r.west - m, south: r.south - m, east: r.east + m, north: r.north + m };
            (w.west > -180.0 && w.east < 180.0 && w.south > -89.0 && w.north < 89.0).then_some(w)
        })
        .collect()
}

/// Whether an interpolated pixel position `q` is within [`LATTICE_TOLERANCE_PX`] of the exact `p`.
fn close(p: (f64, f64), q: (f64, f64)) -> bool {
    (p.0 - q.0).abs().max((p.1 - q.1).abs()) <= LATTICE_TOLERANCE_PX
}

impl<'a> TerrainSource<'a> {
    /// The terrain of `reader`'s heights on `georef`'s frame.
    pub fn new(
        reader: &'a dyn WindowReader,
        georef: &Georef,
        options: TerrainOptions,
    ) -> Result<Self, TerrainError> {
        Self::with_heights(reader, georef, options, reader.height_range())
    }

    /// [`Self::new`] with the reader's height range given (`None`: not known), for a caller
    /// that keeps it rather than have the reader find it again.
    pub fn with_heights(
        reader: &'a dyn WindowReader,
        georef: &Georef,
        options: TerrainOptions,
        heights: Option<(f32, f32)>,
    ) -> Result<Self, TerrainError> {
        if !(options.error_scale.is_finite() && options.error_scale > 0.0) {
            return Err(TerrainError::Scale(options.error_scale));
        }
        // Ellipsoidal heights: the geoid's undulation (within −107…+86 m everywhere, EGM96 and
        // EGM2008 alike) added to orthometric ones, and the sea-level fill outside the data.
        let relief = match heights {
            Some((lo, hi)) => {
                let (low, high) = (f64::from(lo).min(0.0) - 110.0, f64::from(hi).max(0.0) + 90.0);
                if low < -32_000.0 || high > 32_000.0 {
                    return Err(TerrainError::Heights { lo, hi });
                }
                Some(high - low)
            }
            None => None,
        };
        let frame =
            georef.frame().map_err(|e| TerrainError::Frame(e.to_string()))?.ok_or(TerrainError::NotPlaced)?;
        let sea = Geoid::egm96().map_err(|e| TerrainError::Frame(e.to_string()))?;
        let (width, height) = reader.size();
        let mut s = Self {
            reader,
            frame,
            width,
            height,
            sea,
            coverage: Coverage { rects: Vec::new(), max_zoom: 0 },
            relief,
            near: None,
            options,
        };
        s.coverage = s.find_coverage()?;
        s.near = near_rects(&s.coverage.rects, s.frame.grid.crs.is_geographic());
        Ok(s)
    }

    /// The data's geographic extent (its outline walked in WGS 84, longitudes unwrapped, so an
    /// extent across the antimeridian is two rectangles and one around a pole reaches it) and
    /// the zoom whose cells match the source's.
    fn find_coverage(&self) -> Result<Coverage, TerrainError> {
        let g = &self.frame.grid;
        let (w, h) = (f64::from(self.width), f64::from(self.height));
        let steps = 64;
        let mut outline = Vec::with_capacity(4 * steps);
        for k in 0..steps {
            let t = k as f64 / steps as f64;
            outline.push((-0.5 + t * w, -0.5));
        }
        for k in 0..steps {
            let t = k as f64 / steps as f64;
            outline.push((w - 0.5, -0.5 + t * h));
        }
        for k in 0..steps {
            let t = k as f64 / steps as f64;
            outline.push((w - 0.5 - t * w, h - 0.5));
        }
        for k in 0..steps {
            let t = k as f64 / steps as f64;
            outline.push((-0.5, h - 0.5 - t * h));
        }
        let mut pts = Vec::with_capacity(outline.len());
        for (c, r) in outline {
            let (lon, lat) = g
                .crs
                .to_wgs84(g.e0 + c * g.de, g.n0 + r * g.dn)
                .map_err(|e| TerrainError::Frame(e.to_string()))?;
            pts.push((lon, lat));
        }
        // Unwrap longitudes along the outline.
        let mut lons = Vec::with_capacity(pts.len());
        let mut prev = pts[0].0;
        let mut acc = prev;
        for &(lon, _) in &pts {
            let mut d = lon - prev;
            if d > 180.0 {
                d -= 360.0;
            } else if d < -180.0 {
                d += 360.0;
            }
            acc += d;
            lons.push(acc);
            prev = lon;
        }
        let close = {
            let mut d = pts[0].0 - prev;
            if d > 180.0 {
                d -= 360.0;
            } else if d < -180.0 {
                d += 360.0;
            }
            acc + d - lons[0]
        };
        let (mut south, mut north) = (90.0f64, -90.0f64);
        for &(_, lat) in &pts {
            south = south.min(lat);
            north = north.max(lat);
        }
        let (mut west, mut east) =
            lons.iter().fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), &v| (a.min(v), b.max(v)));
        if close.abs() > 180.0 {
            // The outline goes around a pole: the data holds it.
            (west, east) = (-180.0, 180.0);
            if south + north > 0.0 {
                north = 90.0;
            } else {
                south = -90.0;
            }
        }
        if east - west >= 360.0 {
            (west, east) = (-180.0, 180.0);
        }
        // Shift into −180…180 by whole turns, then split at the antimeridian.
        let shift = ((west + 180.0) / 360.0).floor() * 360.0;
        let (west, east) = (west - shift, east - shift);
        let rects = if east > 180.0 {
            vec![
                Rect { west, south, east: 180.0, north },
                Rect { west: -180.0, south, east: east - 360.0, north },
            ]
        } else {
            vec![Rect { west, south, east, north }]
        };
        let cell_deg = if g.crs.is_geographic() {
            g.de.abs().min(g.dn.abs())
        } else {
            g.de.abs().min(g.dn.abs()) * g.crs.unit_metres() / 111_320.0
        };
        let max_zoom = self.options.max_zoom.unwrap_or_else(|| zoom_for_cell(cell_deg)).min(MAX_ZOOM);
        Ok(Coverage { rects, max_zoom })
    }

    /// The CRS position of a WGS 84 point, as fractional source (column, row); `None` where it
    /// has none, or is certainly off the source (see `near`).
    fn pixel(&self, lon: f64, lat: f64) -> Option<(f64, f64)> {
        if let Some(near) = &self.near
            && !near.iter().any(|r| (r.west..=r.east).contains(&lon) && (r.south..=r.north).contains(&lat))
        {
            return None;
        }
        self.pixel_exact(lon, lat)
    }

    /// [`Self::pixel`] without the `near` test.
    fn pixel_exact(&self, lon: f64, lat: f64) -> Option<(f64, f64)> {
        let g = &self.frame.grid;
        let (e, n) = g.crs.from_wgs84(lon, lat).ok()?;
        let (c, r) = ((e - g.e0) / g.de, (n - g.n0) / g.dn);
        if g.crs.is_geographic() && !self.inside(c, r) {
            // Longitudes on the other side of a turn (a 0…360 raster).
            for turn in [360.0, -360.0] {
                let c2 = (e + turn - g.e0) / g.de;
                if self.inside(c2, r) {
                    return Some((c2, r));
                }
            }
        }
        Some((c, r))
    }

    fn inside(&self, c: f64, r: f64) -> bool {
        c >= -0.5 && r >= -0.5 && c <= f64::from(self.width) - 0.5 && r <= f64::from(self.height) - 0.5
    }

    /// The source pixel of every sample of tile `id` (with its border), `SIDE²` row-major.
    ///
    /// Positions are interpolated between exactly transformed ones wherever that is within
    /// [`LATTICE_TOLERANCE_PX`] of exact, checked where interpolation errs most, and cells or
    /// segments that fail are halved down to [`LATTICE`] samples, below which every position is
    /// exact. Inside (more than one sample from an edge): a quadtree of cells over the tile,
    /// bilinear from each cell's corners, checked at its centre and its edges' midpoints. The
    /// three rows and columns at each edge are samples a neighbour has too (its edge, and the
    /// samples beyond it that its normals see): they are interpolated along their line, linearly
    /// over segments of the *global* sample grid (aligned to tile edges, halved the same way
    /// wherever they fail their checks at ¼, ½ and ¾), so both tiles compute every such
    /// position from the same exact points, bit for bit (rows first: a sample on an edge row and
    /// an edge column is a row sample in every tile that has it).
    fn pixels(&self, id: TileId) -> Vec<Option<(f64, f64)>> {
        type Px = Option<(f64, f64)>;
        let n = i64::from(CELLS);
        // About 90 exact points a tile, each asked for several times: FxHash, not SipHash.
        let memo = std::cell::RefCell::new(rustc_hash::FxHashMap::<(i64, i64), Px>::default());
        let exact = |i: i64, j: i64| -> Px {
            if let Some(&p) = memo.borrow().get(&(i, j)) {
                return p;
            }
            let (lon, lat) = id.sample(i, j);
            let p = self.pixel(canonical_lon(lon), lat);
            memo.borrow_mut().insert((i, j), p);
            p
        };
        let lerp = |p: (f64, f64), q: (f64, f64), f: f64| (p.0 + (q.0 - p.0) * f, p.1 + (q.1 - p.1) * f);
        let idx = |i: i64, j: i64| ((j + 1) as usize) * SIDE + (i + 1) as usize;
        let mut out: Vec<Px> = vec![None; SIDE * SIDE];

        // Inside: cells [i0, i0 + s] × [j0, j0 + s], filling samples 2..=n−2 of both axes.
        let mut cells = vec![(0, 0, n)];
        while let Some((i0, j0, s)) = cells.pop() {
            let c = [exact(i0, j0), exact(i0 + s, j0), exact(i0, j0 + s), exact(i0 + s, j0 + s)];
            let bilinear = |i: i64, j: i64| -> Px {
                let (fx, fy) = ((i - i0) as f64 / s as f64, (j - j0) as f64 / s as f64);
                let (a, b) = (lerp(c[0]?, c[1]?, fx), lerp(c[2]?, c[3]?, fx));
                Some(lerp(a, b, fy))
            };
            let h = s / 2;
            let ok = s > 1
                && [(h, h), (h, 0), (0, h), (s, h), (h, s)].into_iter().all(|(di, dj)| {
                    matches!((exact(i0 + di, j0 + dj), bilinear(i0 + di, j0 + dj)),
                        (Some(p), Some(q)) if close(p, q))
                });
            if !ok && s > LATTICE {
                cells.extend([(i0, j0, h), (i0 + h, j0, h), (i0, j0 + h, h), (i0 + h, j0 + h, h)]);
                continue;
            }
            for j in j0.max(2)..=(j0 + s).min(n - 2) {
                for i in i0.max(2)..=(i0 + s).min(n - 2) {
                    out[idx(i, j)] = if ok { bilinear(i, j) } else { exact(i, j) };
                }
            }
        }

        // The edge lines: samples `t0..=t1` of row (or column) `k`, from segments aligned to
        // the tile's edges (so to every tile's: tiles are `n` samples wide).
        let mut line = |k: i64, row: bool, t0: i64, t1: i64| {
            let at = |t: i64| if row { exact(t, k) } else { exact(k, t) };
            let mut segs: Vec<(i64, i64)> =
                (t0.div_euclid(n)..=t1.div_euclid(n)).map(|q| (q * n, n)).collect();
            while let Some((a, s)) = segs.pop() {
                let (pa, pb) = (at(a), at(a + s));
                let ok = s > 1
                    && [1, 2, 3].into_iter().all(|q| {
                        let f = f64::from(q) / 4.0;
                        matches!((at(a + s * i64::from(q) / 4), pa.zip(pb)),
                            (Some(e), Some((p, r))) if close(e, lerp(p, r, f)))
                    });
                if !ok && s > LATTICE {
                    let h = s / 2;
                    segs.extend([(a, h), (a + h, h)].into_iter().filter(|&(b, hs)| b <= t1 && b + hs >= t0));
                    continue;
                }
                for t in a.max(t0)..=(a + s).min(t1) {
                    let v = match (ok, pa.zip(pb)) {
                        (true, Some((p, r))) if t != a && t != a + s => {
                            Some(lerp(p, r, (t - a) as f64 / s as f64))
                        }
                        _ => at(t),
                    };
                    let (i, j) = if row { (t, k) } else { (k, t) };
                    out[idx(i, j)] = v;
                }
            }
        };
        for k in [-1, 0, 1, n - 1, n, n + 1] {
            line(k, true, -1, n + 1);
            line(k, false, 2, n - 2);
        }
        out
    }

    /// The samples of tile `id`: bilinear heights from the source where it has data, as
    /// ellipsoidal heights; elsewhere sea level (EGM96's undulation), flagged as no data.
    pub fn samples(&self, id: TileId) -> Result<TileSamples, TerrainError> {
        let px = self.pixels(id);
        let (w, h) = (self.width, self.height);
        // A pixel position's four neighbours (clamped at the raster's edge) and weights.
        let corners = |c: f64, r: f64| {
            let c = c.clamp(0.0, f64::from(w - 1));
            let r = r.clamp(0.0, f64::from(h - 1));
            // Clamped to ≥ 0, so truncation is the floor (and needs no libm call).
            let (c0, r0) = (c as u32, r as u32);
            (c0, (c0 + 1).min(w - 1), r0, (r0 + 1).min(h - 1), c - f64::from(c0), r - f64::from(r0))
        };
        // The columns and rows the bilinear reads need, once each: marked in a window over their
        // range (at most the raster's width and height).
        let mut span = (u32::MAX, 0u32, u32::MAX, 0u32);
        let mut pixels = Vec::with_capacity(px.len());
        for p in &px {
            let q = p.filter(|&(c, r)| self.inside(c, r)).map(|(c, r)| corners(c, r));
            if let Some((c0, c1, r0, r1, _, _)) = q {
                span = (span.0.min(c0), span.1.max(c1), span.2.min(r0), span.3.max(r1));
            }
            pixels.push(q);
        }
        let mut values = Vec::new();
        let (mut col_at, mut row_at) = (Vec::new(), Vec::new());
        let mut nc = 0;
        if span.0 <= span.1 {
            let mark = |lo: u32, hi: u32, pick: &dyn Fn(&Corners) -> [u32; 2]| {
                let mut used = vec![false; (hi - lo + 1) as usize];
                for q in pixels.iter().flatten() {
                    for v in pick(q) {
                        used[(v - lo) as usize] = true;
                    }
                }
                let list: Vec<u32> = (lo..=hi).filter(|&v| used[(v - lo) as usize]).collect();
                let mut at = vec![0u32; used.len()];
                for (k, &v) in list.iter().enumerate() {
                    at[(v - lo) as usize] = k as u32;
                }
                (list, at)
            };
            let (cols, ca) = mark(span.0, span.1, &|q| [q.0, q.1]);
            let (rows, ra) = mark(span.2, span.3, &|q| [q.2, q.3]);
            self.reader.read_window(&cols, &rows, &mut values)?;
            (col_at, row_at, nc) = (ca, ra, cols.len());
        }
        let value = |c: u32, r: u32| {
            let ci = col_at[(c - span.0) as usize] as usize;
            let ri = row_at[(r - span.2) as usize] as usize;
            f64::from(values[ri * nc + ci])
        };
        let n = i64::from(CELLS);
        let mut heights = Vec::with_capacity(SIDE * SIDE);
        let mut nodata = Vec::with_capacity(((n + 1) * (n + 1)) as usize);
        for j in -1..=n + 1 {
            for i in -1..=n + 1 {
                let (lon, lat) = id.sample(i, j);
                let lon = canonical_lon(lon);
                let hgt = match pixels[((j + 1) as usize) * SIDE + (i + 1) as usize] {
                    Some((c0, c1, r0, r1, fx, fy)) => {
                        let z = (value(c0, r0) * (1.0 - fx) + value(c1, r0) * fx) * (1.0 - fy)
                            + (value(c0, r1) * (1.0 - fx) + value(c1, r1) * fx) * fy;
                        self.frame.undulation(lon, lat).ok().map(|u| z + u)
                    }
                    None => None,
                };
                if (0..=n).contains(&i) && (0..=n).contains(&j) {
                    nodata.push(hgt.is_none());
                }
                heights.push(hgt.unwrap_or_else(|| self.sea.undulation(lon, lat).unwrap_or(0.0)));
            }
        }
        Ok(TileSamples { id, heights, nodata, relief: self.relief })
    }

    /// Tile `id`, built (every extension; the metadata one at its zooms).
    pub fn tile(&self, id: TileId) -> Result<BuiltTile, TerrainError> {
        let s = self.samples(id)?;
        Ok(build_tile(&s, self.options.error_scale, self.coverage.metadata(id))?)
    }

    /// The `layer.json` of this terrain.
    #[must_use]
    pub fn layer(&self, name: &str, attribution: &str, version: &str) -> serde_json::Value {
        layer_json(name, &self.coverage, attribution, version)
    }
}

/// Store path of a tile.
#[must_use]
pub fn tile_rel(id: TileId) -> String {
    format!("{TERRAIN_DIR}/{}/{}/{}.terrain", id.z, id.x, id.y)
}

/// What a terrain bake made, per zoom and in all (`terrain/stats.json`). Bytes are of tiles as
/// sent without extensions (`bytes_raw`, `bytes_gzip`: what compares with other encoders) and
/// with every extension (`bytes_raw_all`, `bytes_gzip_all`).
#[derive(Debug, Clone, Default, serde::Serialize)]
pub struct TerrainStats {
    pub tiles: u64,
    /// Wall time of the whole stage (building, gzip figures, writing each tile durably).
    pub seconds: f64,
    /// Time spent building tiles (reading and sampling the source, the TIN, encoding), summed
    /// over tiles: per tile, what an on-demand request costs the server.
    pub build_seconds: f64,
    /// Build time per tile, median and 99th percentile (milliseconds).
    pub ms_p50: f64,
    pub ms_p99: f64,
    pub bytes_raw: u64,
    pub bytes_gzip: u64,
    pub bytes_raw_all: u64,
    pub bytes_gzip_all: u64,
    pub max_zoom: u8,
    pub per_zoom: std::collections::BTreeMap<u8, ZoomStats>,
    /// Tiles whose relief exceeds their zoom's edge lattice (edges within a height step of the
    /// neighbour's rather than exact): 0 on real terrain.
    pub lattice_misses: u64,
}

#[derive(Debug, Clone, Default, serde::Serialize)]
pub struct ZoomStats {
    pub tiles: u64,
    /// Build time of the zoom's tiles, summed.
    pub seconds: f64,
    pub mean_vertices: f64,
    pub max_error: f64,
    pub bound: f64,
    pub bytes_raw: u64,
    pub bytes_gzip: u64,
    pub bytes_raw_all: u64,
    pub bytes_gzip_all: u64,
}

fn gzip_len(b: &[u8]) -> u64 {
    crate::formats::qmesh::codec::gzip(b).len() as u64
}

/// One baked tile's figures.
struct Made {
    id: TileId,
    seconds: f64,
    vertices: usize,
    max_error: f64,
    bound: f64,
    /// (raw, gzip) without extensions, then with all.
    plain: (u64, u64),
    all: (u64, u64),
    exact: bool,
}

/// Bakes every tile of `src` into `store` under [`TERRAIN_DIR`], then `layer.json` and
/// `stats.json`. `progress(done, total)` after each tile.
pub fn bake_terrain_tiles(
    src: &TerrainSource,
    store: &crate::store::Store,
    name: &str,
    version: &str,
    progress: &(dyn Fn(u64, u64) + Sync),
) -> Result<TerrainStats, TerrainError> {
    let start = Instant::now();
    let ids: Vec<TileId> = src.coverage.tiles().collect();
    let total = ids.len() as u64;
    let done = AtomicU64::new(0);
    let made: Vec<Made> = ids
        .par_iter()
        .map(|&id| {
            let t0 = Instant::now();
            let t = src.tile(id)?;
            let seconds = t0.elapsed().as_secs_f64();
            store.write_file(&tile_rel(id), &t.bytes)?;
            let plain = filter_extensions(&t.bytes, Extensions::default())?;
            progress(done.fetch_add(1, Ordering::Relaxed) + 1, total);
            Ok(Made {
                id,
                seconds,
                vertices: t.vertices,
                max_error: t.max_error,
                bound: t.bound,
                plain: (plain.len() as u64, gzip_len(&plain)),
                all: (t.bytes.len() as u64, gzip_len(&t.bytes)),
                exact: t.lattice_exact,
            })
        })
        .collect::<Result<_, TerrainError>>()?;
    let mut stats = TerrainStats { max_zoom: src.coverage.max_zoom, ..TerrainStats::default() };
    let mut ms: Vec<f64> = made.iter().map(|m| m.seconds * 1e3).collect();
    ms.sort_by(f64::total_cmp);
    let pick = |q: f64| ms.get(((ms.len() as f64 - 1.0) * q).round() as usize).copied().unwrap_or(0.0);
    (stats.ms_p50, stats.ms_p99) = (pick(0.5), pick(0.99));
    for m in made {
        let z = stats.per_zoom.entry(m.id.z).or_default();
        z.tiles += 1;
        z.seconds += m.seconds;
        z.mean_vertices += m.vertices as f64;
        z.max_error = z.max_error.max(m.max_error);
        z.bound = m.bound;
        (z.bytes_raw, z.bytes_gzip) = (z.bytes_raw + m.plain.0, z.bytes_gzip + m.plain.1);
        (z.bytes_raw_all, z.bytes_gzip_all) = (z.bytes_raw_all + m.all.0, z.bytes_gzip_all + m.all.1);
        stats.tiles += 1;
        stats.build_seconds += m.seconds;
        (stats.bytes_raw, stats.bytes_gzip) = (stats.bytes_raw + m.plain.0, stats.bytes_gzip + m.plain.1);
        (stats.bytes_raw_all, stats.bytes_gzip_all) =
            (stats.bytes_raw_all + m.all.0, stats.bytes_gzip_all + m.all.1);
        stats.lattice_misses += u64::from(!m.exact);
    }
    for z in stats.per_zoom.values_mut() {
        z.mean_vertices /= z.tiles.max(1) as f64;
    }
    let layer = src.layer(name, "", version);
    store.write_file(
        &format!("{TERRAIN_DIR}/layer.json"),
        &serde_json::to_vec_pretty(&layer).unwrap_or_default(),
    )?;
    stats.seconds = start.elapsed().as_secs_f64();
    store.write_file(
        &format!("{TERRAIN_DIR}/stats.json"),
        &serde_json::to_vec_pretty(&stats).unwrap_or_default(),
    )?;
    Ok(stats)
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used, clippy::expect_used)]
    use super::*;
    use crate::formats::qmesh::grid::cell_degrees;
    use crate::raster::Heightfield;

    /// A UTM 32N raster far off the zone's central meridian (where the projection bends most),
    /// 30 m cells.
    fn source() -> (Heightfield, Georef) {
        let (w, h, d) = (700u32, 500u32, 30.0);
        let data = (0..w * h).map(|k| (k % w) as f32 * 0.5 + (k / w) as f32 * 0.25).collect();
        let g = Georef::projected_egm96(32632, 780_000.0, 5_300_000.0, d);
        (Heightfield { width: w, height: h, data }, g)
    }

    fn tiles_near_centre(src: &TerrainSource, z: u8) -> Vec<TileId> {
        let r = &src.coverage.rects[0];
        let (lon, lat) = (f64::midpoint(r.west, r.east), f64::midpoint(r.south, r.north));
        let d = cell_degrees(z) * f64::from(CELLS);
        let (x, y) = (((lon + 180.0) / d) as u32, ((lat + 90.0) / d) as u32);
        let mut out = Vec::new();
        for dy in 0..3 {
            for dx in 0..3 {
                out.push(TileId::new(z, x + dx - 1, y + dy - 1).unwrap());
            }
        }
        out
    }

    #[test]
    fn interpolated_positions_stay_near_exact_and_neighbours_share_their_edge_lines_bit_for_bit() {
        let (hf, g) = source();
        let src = TerrainSource::new(&hf, &g, TerrainOptions::default()).unwrap();
        let n = i64::from(CELLS);
        let idx = |i: i64, j: i64| ((j + 1) as usize) * SIDE + (i + 1) as usize;
        let mut worst = 0.0f64;
        for z in [src.coverage.max_zoom, src.coverage.max_zoom - 2, 6] {
            let ids = tiles_near_centre(&src, z);
            let px: Vec<_> = ids.iter().map(|&id| src.pixels(id)).collect();
            for (id, p) in ids.iter().zip(&px) {
                for j in -1..=n + 1 {
                    for i in -1..=n + 1 {
                        let (lon, lat) = id.sample(i, j);
                        let exact = src.pixel_exact(canonical_lon(lon), lat);
                        match (p[idx(i, j)], exact) {
                            (Some(a), Some(b)) => worst = worst.max((a.0 - b.0).abs().max((a.1 - b.1).abs())),
                            // Only far off the source may a sample have no position.
                            (None, Some(b)) => assert!(!src.inside(b.0, b.1), "{id} ({i}, {j}) {b:?}"),
                            (a, b) => assert_eq!(a.is_some(), b.is_some(), "{id} ({i}, {j})"),
                        }
                    }
                }
            }
            // Tiles 3 wide, row-major from the south-west: (k, k + 1) and (k, k + 3) neighbour.
            for k in 0..9 {
                for (other, east) in [(k + 1, true), (k + 3, false)] {
                    if other >= 9 || (east && k % 3 == 2) {
                        continue;
                    }
                    for t in -1..=n + 1 {
                        for o in -1..=1 {
                            let (a, b) =
                                if east { (idx(n + o, t), idx(o, t)) } else { (idx(t, n + o), idx(t, o)) };
                            let bits = |p: Option<(f64, f64)>| p.map(|(x, y)| (x.to_bits(), y.to_bits()));
                            assert_eq!(
                                bits(px[k][a]),
                                bits(px[other][b]),
                                "z{z} tiles {k}/{other} t {t} o {o}"
                            );
                        }
                    }
                }
            }
        }
        assert!(worst <= 2.0 * LATTICE_TOLERANCE_PX, "interpolated positions off by {worst} px");
        eprintln!("largest interpolation error {worst:.5} px");
    }

    #[test]
    fn near_rects_skip_only_what_is_off_the_source() {
        let r = Rect { west: 10.0, south: 45.0, east: 11.0, north: 45.5 };
        let near = near_rects(&[r], false).unwrap();
        assert!((near[0].west - 9.9).abs() < 1e-12 && (near[0].north - 45.6).abs() < 1e-12);
        assert!(near_rects(&[r], true).is_none(), "geographic sources are never skipped");
        let edge = Rect { west: 179.5, south: 0.0, east: 180.0, north: 1.0 };
        assert!(near_rects(&[edge], false).is_none(), "across the antimeridian");
        let pole = Rect { west: 0.0, south: 88.5, east: 10.0, north: 89.5 };
        assert!(near_rects(&[pole], false).is_none(), "near a pole");
    }
}
