//! Heightmap tiles on the Web-Mercator XYZ grid (EPSG:3857, `y` from the north): what MapLibre
//! GL's `raster-dem` sources, deck.gl's terrain layer, AWS Terrain Tiles and Mapbox read, as PNG
//! in the Terrarium or Mapbox Terrain-RGB encoding, and as float32 for physics engines (Unreal
//! Landscape, Gazebo, grid_map). Pure: the grid's geometry, heights in, bytes out.

use std::io::Cursor;

/// Pixels per tile side.
pub const TILE_PX: u32 = 256;
/// The deepest zoom served (≈ 2.4 cm pixels at the equator).
pub const MAX_ZOOM: u8 = 22;
/// Web Mercator's latitude limit (degrees).
pub const MAX_LAT: f64 = 85.051_128_779_806_59;

/// How heights become pixels.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Encoding {
    /// Mapzen/AWS Terrarium: `h = R·256 + G + B/256 − 32768` (1/256 m steps).
    Terrarium,
    /// Mapbox Terrain-RGB: `h = −10000 + (R·65536 + G·256 + B)·0.1` (0.1 m steps).
    TerrainRgb,
}

impl Encoding {
    /// The encoding named `s` (`terrarium`, `terrain-rgb`, also MapLibre's `mapbox`).
    #[must_use]
    pub fn parse(s: &str) -> Option<Self> {
        match s {
            "terrarium" => Some(Self::Terrarium),
            "terrain-rgb" | "mapbox" => Some(Self::TerrainRgb),
            _ => None,
        }
    }

    /// MapLibre's name for it (`raster-dem` source `encoding`).
    #[must_use]
    pub fn maplibre_name(self) -> &'static str {
        match self {
            Self::Terrarium => "terrarium",
            Self::TerrainRgb => "mapbox",
        }
    }

    /// The pixel of height `h` (metres), clamped to the encoding's range.
    #[must_use]
    pub fn rgb(self, h: f64) -> [u8; 3] {
        match self {
            Self::Terrarium => {
                let v = ((h + 32768.0) * 256.0).round().clamp(0.0, f64::from(1u32 << 24) - 1.0) as u32;
                [(v >> 16) as u8, (v >> 8) as u8, v as u8]
            }
            Self::TerrainRgb => {
                let v = ((h + 10000.0) * 10.0).round().clamp(0.0, f64::from(1u32 << 24) - 1.0) as u32;
                [(v >> 16) as u8, (v >> 8) as u8, v as u8]
            }
        }
    }

    /// The height of a pixel (the inverse of [`Encoding::rgb`] on its steps).
    #[must_use]
    pub fn height(self, p: [u8; 3]) -> f64 {
        let [r, g, b] = p.map(f64::from);
        match self {
            Self::Terrarium => r * 256.0 + g + b / 256.0 - 32768.0,
            Self::TerrainRgb => -10000.0 + (r * 65536.0 + g * 256.0 + b) * 0.1,
        }
    }

    /// The height step of one code (metres): the encoding's rounding is half of it.
    #[must_use]
    pub fn step(self) -> f64 {
        match self {
            Self::Terrarium => 1.0 / 256.0,
            Self::TerrainRgb => 0.1,
        }
    }
}

/// A tile of the XYZ grid.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct Xyz {
    pub z: u8,
    pub x: u32,
    pub y: u32,
}

impl Xyz {
    /// The tile, if it is on the grid (`z ≤ MAX_ZOOM`, `x, y < 2^z`).
    #[must_use]
    pub fn new(z: u8, x: u32, y: u32) -> Option<Self> {
        (z <= MAX_ZOOM && u64::from(x) < (1u64 << z) && u64::from(y) < (1u64 << z)).then_some(Self {
            z,
            x,
            y,
        })
    }

    /// WGS 84 (lon, lat) of the centre of pixel (i, j) (`j` from the north).
    #[must_use]
    pub fn pixel_lonlat(self, i: u32, j: u32) -> (f64, f64) {
        let n = f64::from(TILE_PX) * (1u64 << self.z) as f64;
        let gx = f64::from(self.x) * f64::from(TILE_PX) + f64::from(i) + 0.5;
        let gy = f64::from(self.y) * f64::from(TILE_PX) + f64::from(j) + 0.5;
        let lon = gx / n * 360.0 - 180.0;
        let lat = (std::f64::consts::PI * (1.0 - 2.0 * gy / n)).sinh().atan().to_degrees();
        (lon, lat)
    }

    /// The tile's bounds: (west, south, east, north) in degrees.
    #[must_use]
    pub fn bounds(self) -> (f64, f64, f64, f64) {
        let n = (1u64 << self.z) as f64;
        let lon = |x: f64| x / n * 360.0 - 180.0;
        let lat = |y: f64| (std::f64::consts::PI * (1.0 - 2.0 * y / n)).sinh().atan().to_degrees();
        (
            lon(f64::from(self.x)),
            lat(f64::from(self.y) + 1.0),
            lon(f64::from(self.x) + 1.0),
            lat(f64::from(self.y)),
        )
    }

    /// Every pixel centre, row by row from the north-west.
    #[must_use]
    pub fn pixel_centres(self) -> Vec<[f64; 2]> {
        let mut out = Vec::with_capacity((TILE_PX * TILE_PX) as usize);
        for j in 0..TILE_PX {
            for i in 0..TILE_PX {
                let (lon, lat) = self.pixel_lonlat(i, j);
                out.push([lon, lat]);
            }
        }
        out
    }
}

/// The depth of the quadtree nodes whose TIN a heightmap tile at `t` samples: the coarsest whose
/// cells (`cell_metres` at the finest depth `finest`, doubling per level up) are no larger than
/// the tile's pixels at its centre: what a client draws at that scale, and not every leaf under a
/// continent-sized tile.
#[must_use]
pub fn mesh_depth(t: Xyz, cell_metres: f64, finest: u8) -> u8 {
    let (_, s, _, n) = t.bounds();
    let lat = f64::midpoint(s, n).clamp(-MAX_LAT, MAX_LAT);
    let px = 2.0 * std::f64::consts::PI * crate::crs::ecef::A * lat.to_radians().cos()
        / (f64::from(TILE_PX) * (1u64 << t.z) as f64);
    let coarser = (px / cell_metres.max(f64::MIN_POSITIVE)).log2().floor().clamp(0.0, 255.0);
    finest.saturating_sub(coarser as u8)
}

/// The zoom whose pixels are no larger than `cell_metres` at latitude `lat` (at most
/// [`MAX_ZOOM`]): where a heightmap stops gaining detail from a source of that resolution.
#[must_use]
pub fn zoom_for_cell(cell_metres: f64, lat: f64) -> u8 {
    let circumference = 2.0 * std::f64::consts::PI * crate::crs::ecef::A;
    let metres_per_px0 = circumference * lat.to_radians().cos().abs().max(1e-6) / f64::from(TILE_PX);
    let mut z = 0u8;
    while z < MAX_ZOOM && metres_per_px0 / (1u64 << z) as f64 > cell_metres {
        z += 1;
    }
    z
}

/// The tiles of zoom `z` that meet the box (west, south, east, north) in degrees, as inclusive
/// (x0, x1, y0, y1) ranges; `None` when the box is empty or off the grid's latitudes.
#[must_use]
pub fn tile_range(z: u8, west: f64, south: f64, east: f64, north: f64) -> Option<(u32, u32, u32, u32)> {
    let n = (1u64 << z) as f64;
    let south = south.max(-MAX_LAT);
    let north = north.min(MAX_LAT);
    if !(west <= east && south <= north) {
        return None;
    }
    let fx = |lon: f64| ((lon + 180.0) / 360.0 * n).floor().clamp(0.0, n - 1.0) as u32;
    let fy = |lat: f64| {
        let r = lat.to_radians();
        ((1.0 - (r.tan() + 1.0 / r.cos()).ln() / std::f64::consts::PI) / 2.0 * n).floor().clamp(0.0, n - 1.0)
            as u32
    };
    Some((fx(west), fx(east), fy(north), fy(south)))
}

/// A PNG of `TILE_PX²` heights (row-major from the north-west) in `enc`; `None` heights (no
/// data) are written as 0 m, what the encodings' readers take for sea level.
#[must_use]
pub fn png(heights: &[Option<f64>], enc: Encoding) -> Vec<u8> {
    let mut rgb = Vec::with_capacity(heights.len() * 3);
    for h in heights {
        rgb.extend_from_slice(&enc.rgb(h.unwrap_or(0.0)));
    }
    let mut out = Vec::new();
    let side = (heights.len() as f64).sqrt() as u32;
    let enc_png = image::codecs::png::PngEncoder::new_with_quality(
        Cursor::new(&mut out),
        image::codecs::png::CompressionType::Fast,
        image::codecs::png::FilterType::Paeth,
    );
    // A buffer of the right size cannot fail to encode into memory.
    let _ = image::ImageEncoder::write_image(enc_png, &rgb, side, side, image::ExtendedColorType::Rgb8);
    out
}

/// The float32 form: `TILE_PX²` little-endian f32 heights, rows from the north, NaN where there
/// is no data.
#[must_use]
pub fn f32_tile(heights: &[Option<f64>]) -> Vec<u8> {
    heights.iter().flat_map(|h| (h.map_or(f32::NAN, |v| v as f32)).to_le_bytes()).collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn encodings_round_trip_within_half_a_step() {
        for enc in [Encoding::Terrarium, Encoding::TerrainRgb] {
            for h in [-420.7, 0.0, 0.05, 1234.567, 8848.86, -10.0] {
                let back = enc.height(enc.rgb(h));
                assert!((back - h).abs() <= enc.step() / 2.0 + 1e-9, "{enc:?}: {h} → {back}");
            }
        }
        // Published examples: Terrarium (128, 0, 0) is 0 m; Terrain-RGB (1, 134, 160) is 0 m.
        assert_eq!(Encoding::Terrarium.rgb(0.0), [128, 0, 0]);
        assert_eq!(Encoding::TerrainRgb.rgb(0.0), [1, 134, 160]);
    }

    #[test]
    fn the_grid_matches_web_mercator() {
        let t = Xyz::new(0, 0, 0).unwrap();
        let (w, s, e, n) = t.bounds();
        assert!((w + 180.0).abs() < 1e-12 && (e - 180.0).abs() < 1e-12);
        assert!((n - MAX_LAT).abs() < 1e-9 && (s + MAX_LAT).abs() < 1e-9);
        // Zoom 1, tile (1, 0) is the north-east quarter.
        let (w, s, e, n) = Xyz::new(1, 1, 0).unwrap().bounds();
        assert!(
            w.abs() < 1e-12 && s.abs() < 1e-12 && (e - 180.0).abs() < 1e-12 && (n - MAX_LAT).abs() < 1e-9
        );
        assert!(Xyz::new(1, 2, 0).is_none() && Xyz::new(23, 0, 0).is_none());
        // The pixel centres of a tile lie inside it, the first in the north-west.
        let t = Xyz::new(12, 2183, 1464).unwrap();
        let (w, s, e, n) = t.bounds();
        let (lon, lat) = t.pixel_lonlat(0, 0);
        assert!(lon > w && lon < e && lat < n && lat > s && n - lat < (n - s) / 256.0);
        assert_eq!(tile_range(12, lon, lat, lon, lat), Some((2183, 2183, 1464, 1464)));
        // 30 m cells at 46° N: zoom 12 pixels are ≈ 26.5 m there, zoom 11 ≈ 53 m.
        assert_eq!(zoom_for_cell(30.0, 46.0), 12);
    }

    #[test]
    fn png_decodes_to_the_heights() {
        let hs: Vec<Option<f64>> =
            (0..TILE_PX * TILE_PX).map(|k| (k % 7 != 0).then(|| f64::from(k % 5000) * 0.37 - 50.0)).collect();
        for enc in [Encoding::Terrarium, Encoding::TerrainRgb] {
            let bytes = png(&hs, enc);
            let img = image::load_from_memory(&bytes).unwrap().to_rgb8();
            assert_eq!(img.dimensions(), (TILE_PX, TILE_PX));
            for (k, p) in img.pixels().enumerate() {
                let want = hs[k].unwrap_or(0.0);
                assert!((enc.height(p.0) - want).abs() <= enc.step() / 2.0 + 1e-9, "{enc:?} pixel {k}");
            }
        }
        let f = f32_tile(&hs);
        assert_eq!(f.len(), hs.len() * 4);
        assert!(f32::from_le_bytes(f[..4].try_into().unwrap()).is_nan());
    }
}
