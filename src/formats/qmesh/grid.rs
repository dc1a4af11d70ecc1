//! The global geodetic tiling of quantized-mesh terrain (EPSG:4326, TMS): two root tiles at
//! zoom 0, `2^(z+1) × 2^z` tiles at zoom `z`, `y` counted from the south. Each tile carries a
//! grid of `CELLS + 1` × `CELLS + 1` sample points; a sample's position is computed from its
//! global index at that zoom, never from tile-local arithmetic, so two tiles that share an edge
//! compute the very same coordinates (and so the same heights and normals) for it.

/// Cells per tile side: 65 × 65 samples, the size CesiumJS assumes for its level-0 geometric
/// error estimate of quantized-mesh terrain.
pub const CELLS: u32 = 64;
/// Samples per tile side.
pub const SAMPLES: u32 = CELLS + 1;
/// The deepest zoom made (a cell is then 1.7·10⁻⁷ degrees, about 2 cm).
pub const MAX_ZOOM: u8 = 24;
/// CesiumJS's level-0 geometric error for quantized-mesh terrain on this tiling, in metres:
/// `TerrainProvider.getEstimatedLevelZeroGeometricErrorForAHeightmap(WGS84, 65, 2)` — the
/// ellipsoid's maximum radius × 2π × 0.25 / (65 × 2). A client refines a tile at zoom `z` as if
/// its error were this / 2^z.
pub const LEVEL0_ERROR: f64 = 6_378_137.0 * 2.0 * std::f64::consts::PI * 0.25 / (65.0 * 2.0);

/// One tile of the geodetic tiling.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub struct TileId {
    pub z: u8,
    pub x: u32,
    pub y: u32,
}

/// Why a tile address is not a tile of the tiling.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum TileIdError {
    #[error("zoom {0} is beyond the deepest zoom {MAX_ZOOM}")]
    Zoom(u8),
    #[error("tile {z}/{x}/{y} is outside zoom {z}'s {cols} × {rows} tiles")]
    Outside { z: u8, x: u32, y: u32, cols: u32, rows: u32 },
}

/// A rectangle in degrees (west, south, east, north), west < east (no wrap).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Rect {
    pub west: f64,
    pub south: f64,
    pub east: f64,
    pub north: f64,
}

impl TileId {
    /// A tile, checked against its zoom's extent.
    pub fn new(z: u8, x: u32, y: u32) -> Result<Self, TileIdError> {
        if z > MAX_ZOOM {
            return Err(TileIdError::Zoom(z));
        }
        let (cols, rows) = tiles_at(z);
        if x >= cols || y >= rows {
            return Err(TileIdError::Outside { z, x, y, cols, rows });
        }
        Ok(Self { z, x, y })
    }

    /// The tile's rectangle.
    #[must_use]
    pub fn rect(self) -> Rect {
        let (w, s) = sample_lonlat(self.z, self.x * CELLS, self.y * CELLS);
        let (e, n) = sample_lonlat(self.z, (self.x + 1) * CELLS, (self.y + 1) * CELLS);
        Rect { west: w, south: s, east: e, north: n }
    }

    /// The tile's parent (`None` at zoom 0).
    #[must_use]
    pub fn parent(self) -> Option<Self> {
        (self.z > 0).then(|| Self { z: self.z - 1, x: self.x / 2, y: self.y / 2 })
    }

    /// Longitude and latitude of the tile's sample `(i, j)` (`i` east, `j` north, may lie one
    /// sample outside the tile: the border that normals read).
    #[must_use]
    pub fn sample(self, i: i64, j: i64) -> (f64, f64) {
        let gi = i64::from(self.x) * i64::from(CELLS) + i;
        let gj = i64::from(self.y) * i64::from(CELLS) + j;
        sample_lonlat_signed(self.z, gi, gj)
    }
}

impl std::fmt::Display for TileId {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "{}/{}/{}", self.z, self.x, self.y)
    }
}

/// A longitude in −180…180 (180 excluded): the antimeridian is −180 seen from both sides, so
/// the tiles on either side of it sample the very same heights there.
#[must_use]
pub fn canonical_lon(lon: f64) -> f64 {
    if (-180.0..180.0).contains(&lon) { lon } else { (lon + 180.0).rem_euclid(360.0) - 180.0 }
}

/// Tiles across and up at zoom `z`.
#[must_use]
pub fn tiles_at(z: u8) -> (u32, u32) {
    (2u32 << z, 1u32 << z)
}

/// Degrees per sample step at zoom `z`.
#[must_use]
pub fn cell_degrees(z: u8) -> f64 {
    180.0 / (f64::from(CELLS) * f64::from(1u32 << z))
}

fn sample_lonlat(z: u8, gi: u32, gj: u32) -> (f64, f64) {
    sample_lonlat_signed(z, i64::from(gi), i64::from(gj))
}

/// The one formula for a sample's position: global sample index × step, from (−180°, −90°).
/// Latitudes beyond the poles (a border sample) are clamped.
fn sample_lonlat_signed(z: u8, gi: i64, gj: i64) -> (f64, f64) {
    let step = cell_degrees(z);
    #[allow(clippy::cast_precision_loss)]
    let (lon, lat) = (-180.0 + gi as f64 * step, -90.0 + gj as f64 * step);
    (lon, lat.clamp(-90.0, 90.0))
}

/// The error bound of a tile at zoom `z`: `scale` × CesiumJS's own estimate for that zoom
/// ([`LEVEL0_ERROR`] / 2^z), so a client's screen-space error for the tile is the true one.
#[must_use]
pub fn zoom_error(z: u8, scale: f64) -> f64 {
    scale * LEVEL0_ERROR / f64::from(1u32 << z)
}

/// The height lattice of tile edges at zoom `z` (metres, a power of two): every edge sample's
/// height is rounded to it, and every tile's height step divides it, so both tiles of an edge
/// decode the very same heights there. Fine against the zoom's error (≤ 1/16 of it), coarse
/// enough that a tile's 15-bit height range spans it (1 m covers 32 km of relief).
#[must_use]
pub fn edge_lattice(z: u8) -> f64 {
    let e = zoom_error(z, 1.0) / 16.0;
    2f64.powi(e.log2().floor() as i32).clamp(MIN_STEP, 1.0)
}

/// The edge lattice of zoom `z` for a dataset whose tiles' heights all lie within `relief` metres
/// of each other (ellipsoidal, the sea-level fill included; `None`: not known): [`edge_lattice`],
/// or coarser where a tile with that much relief would need a coarser height step than the
/// lattice — the smallest power of two that holds `relief` in a tile's 15-bit range with room
/// for the edges' rounding. Every tile of the dataset then has a step that divides its lattice,
/// so both tiles of every edge decode the very same heights; only fine zooms of datasets with
/// kilometres of relief are coarsened (e.g. 2.8 km: zoom 16 and deeper). Where that lattice
/// would exceed the zoom's error itself (e.g. 2.8 km of relief at zoom 20, a 10 cm DEM), a
/// tile's 15 bits cannot hold both the relief and the bound: the zoom's own lattice is kept, so
/// every tile of ordinary relief keeps its bound and only tiles of more relief than it holds
/// miss it (counted, and warned about, by the bake).
#[must_use]
pub fn edge_lattice_for(z: u8, relief: Option<f64>) -> f64 {
    let fine = edge_lattice(z);
    match relief {
        Some(r) if r.is_finite() && r > 0.0 => {
            let floor = 2f64.powi((r / 32_000.0).log2().ceil() as i32);
            if floor <= zoom_error(z, 1.0) { fine.max(floor) } else { fine }
        }
        _ => fine,
    }
}

/// The finest height step of a tile (2⁻⁹ m): every multiple of it below 32 km is exact in the
/// header's `f32` heights.
pub const MIN_STEP: f64 = 1.0 / 512.0;

/// The deepest zoom needed for a source whose cells are `cell_degrees` apart: the first zoom
/// whose cells are no larger.
#[must_use]
pub fn zoom_for_cell(cell_deg: f64) -> u8 {
    (0..=MAX_ZOOM).find(|&z| cell_degrees(z) <= cell_deg).unwrap_or(MAX_ZOOM)
}

/// The range of tiles at zoom `z` that intersect `r` (inclusive `x0..=x1`, `y0..=y1`); `r` is
/// clamped to the globe. Tiles that only touch `r` along an edge are not counted.
#[must_use]
pub fn tiles_covering(z: u8, r: Rect) -> (u32, u32, u32, u32) {
    let (cols, rows) = tiles_at(z);
    let size = 180.0 / f64::from(1u32 << z);
    let idx = |v: f64, origin: f64, n: u32, upper: bool| -> u32 {
        let t = (v - origin) / size;
        // An edge exactly on a tile boundary belongs to the tile before it when it is the upper
        // end of the range.
        let k = if upper { t.ceil() - 1.0 } else { t.floor() };
        #[allow(clippy::cast_possible_truncation, clippy::cast_sign_loss)]
        let k = k.clamp(0.0, f64::from(n - 1)) as u32;
        k
    };
    let w = r.west.clamp(-180.0, 180.0);
    let e = r.east.clamp(-180.0, 180.0);
    let s = r.south.clamp(-90.0, 90.0);
    let n = r.north.clamp(-90.0, 90.0);
    (
        idx(w, -180.0, cols, false),
        idx(s, -90.0, rows, false),
        idx(e, -180.0, cols, true).max(idx(w, -180.0, cols, false)),
        idx(n, -90.0, rows, true).max(idx(s, -90.0, rows, false)),
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn roots_and_children() {
        assert_eq!(tiles_at(0), (2, 1));
        let r = TileId::new(0, 1, 0).unwrap().rect();
        assert_eq!((r.west, r.south, r.east, r.north), (0.0, -90.0, 180.0, 90.0));
        let r = TileId::new(1, 0, 1).unwrap().rect();
        assert_eq!((r.west, r.south, r.east, r.north), (-180.0, 0.0, -90.0, 90.0));
        assert!(TileId::new(0, 2, 0).is_err());
        assert!(TileId::new(25, 0, 0).is_err());
        assert_eq!(TileId::new(3, 5, 2).unwrap().parent(), Some(TileId { z: 2, x: 2, y: 1 }));
    }

    #[test]
    fn shared_edges_have_the_same_coordinates() {
        let a = TileId::new(14, 17_000, 12_000).unwrap();
        let b = TileId::new(14, 17_001, 12_000).unwrap();
        for j in 0..=i64::from(CELLS) {
            assert_eq!(a.sample(i64::from(CELLS), j), b.sample(0, j));
        }
        let c = TileId::new(14, 17_000, 12_001).unwrap();
        for i in -1..=i64::from(CELLS) + 1 {
            assert_eq!(a.sample(i, i64::from(CELLS)), c.sample(i, 0));
        }
    }

    #[test]
    fn zoom_for_cells() {
        // SRTM 1″ (1/3600°): zoom 14 has 1/5825° cells, zoom 13 1/2912°.
        assert_eq!(zoom_for_cell(1.0 / 3600.0), 14);
        assert_eq!(zoom_for_cell(1.0), 2);
        assert_eq!(zoom_for_cell(100.0), 0);
    }

    #[test]
    fn covering() {
        let r = Rect { west: 10.0, south: 46.0, east: 11.0, north: 47.0 };
        let (x0, y0, x1, y1) = tiles_covering(2, r);
        // Zoom 2: 45° tiles; 10–11° E lies in x 4, 46–47° N in y 3.
        assert_eq!((x0, y0, x1, y1), (4, 3, 4, 3));
        // A rectangle ending on a boundary does not take the next tile.
        let r = Rect { west: 0.0, south: 0.0, east: 45.0, north: 45.0 };
        assert_eq!(tiles_covering(2, r), (4, 2, 4, 2));
        let all = Rect { west: -180.0, south: -90.0, east: 180.0, north: 90.0 };
        assert_eq!(tiles_covering(0, all), (0, 0, 1, 0));
    }

    #[test]
    #[allow(clippy::float_cmp)] // powers of two, exact
    fn lattice_and_errors() {
        assert!((LEVEL0_ERROR - 77_067.34).abs() < 0.01);
        for z in 0..=MAX_ZOOM {
            let s = edge_lattice(z);
            assert!((MIN_STEP..=1.0).contains(&s) && s.log2().fract() == 0.0);
            assert!(s <= zoom_error(z, 1.0) / 16.0 || s == MIN_STEP);
            // Relief coarsens the lattice to hold it in 15 bits, never past the zoom's error.
            for relief in [None, Some(0.0), Some(500.0), Some(2_800.0), Some(20_000.0), Some(f64::NAN)] {
                let l = edge_lattice_for(z, relief);
                assert!(l >= s && l.log2().fract() == 0.0, "zoom {z}, {relief:?}: {l}");
                if l > s {
                    assert!(
                        l <= zoom_error(z, 1.0) && relief.unwrap() <= 32_766.0 * l,
                        "zoom {z}, {relief:?}: {l}"
                    );
                }
            }
        }
        // 2.8 km of relief: the lattice is coarsened at zoom 16 (its own 1/16 m holds 2,048 m), not at
        // zoom 12, and not past zoom 19 (1/8 m against e(20) = 7.3 cm).
        assert_eq!(edge_lattice_for(12, Some(2_800.0)), edge_lattice(12));
        assert_eq!(edge_lattice_for(16, Some(2_800.0)), 0.125);
        assert_eq!(edge_lattice_for(19, Some(2_800.0)), 0.125);
        assert_eq!(edge_lattice_for(20, Some(2_800.0)), edge_lattice(20));
    }
}
