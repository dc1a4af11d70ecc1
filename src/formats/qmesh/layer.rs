//! What tiles a terrain has and the `layer.json` that tells clients: availability per zoom from
//! the data's geographic extent, the `metadata` extension's child availability, and the layer
//! document itself (TileJSON 2.1 fields CesiumJS, Cesium for Unreal/Unity and osgEarth read).

use serde_json::json;

use super::grid::{Rect, TileId, tiles_at, tiles_covering};

/// Zooms whose tiles carry their descendants' availability (`metadataAvailability`): tiles at
/// zooms 0, 10, 20 name which tiles exist in the next 10 zooms below them.
pub const METADATA_AVAILABILITY: u8 = 10;

/// A terrain's extent: the data's geographic bounding rectangles (two when it crosses the
/// antimeridian) and its deepest zoom.
#[derive(Debug, Clone, PartialEq)]
pub struct Coverage {
    pub rects: Vec<Rect>,
    pub max_zoom: u8,
}

/// An inclusive range of tiles at one zoom.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Range {
    pub x0: u32,
    pub y0: u32,
    pub x1: u32,
    pub y1: u32,
}

impl Range {
    fn contains(&self, x: u32, y: u32) -> bool {
        (self.x0..=self.x1).contains(&x) && (self.y0..=self.y1).contains(&y)
    }
    fn json(&self) -> serde_json::Value {
        json!({"startX": self.x0, "startY": self.y0, "endX": self.x1, "endY": self.y1})
    }
    fn len(&self) -> u64 {
        u64::from(self.x1 - self.x0 + 1) * u64::from(self.y1 - self.y0 + 1)
    }
}

impl Coverage {
    /// The tile ranges available at zoom `z`: both root tiles at zoom 0 (a client needs them
    /// to start), then the tiles that intersect the data; none beyond the deepest zoom.
    #[must_use]
    pub fn available(&self, z: u8) -> Vec<Range> {
        if z > self.max_zoom {
            return Vec::new();
        }
        if z == 0 {
            return vec![Range { x0: 0, y0: 0, x1: 1, y1: 0 }];
        }
        let mut out: Vec<Range> = Vec::new();
        for r in &self.rects {
            let (x0, y0, x1, y1) = tiles_covering(z, *r);
            let range = Range { x0, y0, x1, y1 };
            if !out.contains(&range) {
                out.push(range);
            }
        }
        out
    }

    /// Whether tile `id` exists.
    #[must_use]
    pub fn has(&self, id: TileId) -> bool {
        self.available(id.z).iter().any(|r| r.contains(id.x, id.y))
    }

    /// Every tile, zoom by zoom (each once).
    pub fn tiles(&self) -> impl Iterator<Item = TileId> + '_ {
        (0..=self.max_zoom).flat_map(move |z| {
            let ranges = self.available(z);
            let mut ids: Vec<TileId> = Vec::new();
            for (k, r) in ranges.iter().enumerate() {
                for y in r.y0..=r.y1 {
                    for x in r.x0..=r.x1 {
                        // A tile in an earlier range too is listed there.
                        if !ranges[..k].iter().any(|p| p.contains(x, y)) {
                            ids.push(TileId { z, x, y });
                        }
                    }
                }
            }
            ids
        })
    }

    /// Tiles in all.
    #[must_use]
    pub fn tile_count(&self) -> u64 {
        // Ranges at one zoom overlap only where two rectangles share tiles (rare and small):
        // counted by enumeration there.
        (0..=self.max_zoom)
            .map(|z| {
                let r = self.available(z);
                if r.len() == 1 { r[0].len() } else { self.tiles().filter(|t| t.z == z).count() as u64 }
            })
            .sum()
    }

    /// The `metadata` extension's JSON for tile `id`: at zooms that are multiples of
    /// [`METADATA_AVAILABILITY`], the available tiles below it for that many zooms (clipped to
    /// its own descendants); `None` at other zooms.
    #[must_use]
    pub fn metadata(&self, id: TileId) -> Option<String> {
        if !id.z.is_multiple_of(METADATA_AVAILABILITY) {
            return None;
        }
        let mut levels = Vec::new();
        for dz in 1..=METADATA_AVAILABILITY {
            let z = id.z.saturating_add(dz);
            if z > self.max_zoom {
                break;
            }
            let k = 1u32 << dz;
            let mine = Range { x0: id.x * k, y0: id.y * k, x1: id.x * k + k - 1, y1: id.y * k + k - 1 };
            let clipped: Vec<serde_json::Value> = self
                .available(z)
                .iter()
                .filter_map(|r| {
                    let c = Range {
                        x0: r.x0.max(mine.x0),
                        y0: r.y0.max(mine.y0),
                        x1: r.x1.min(mine.x1),
                        y1: r.y1.min(mine.y1),
                    };
                    (c.x0 <= c.x1 && c.y0 <= c.y1).then(|| c.json())
                })
                .collect();
            levels.push(serde_json::Value::Array(clipped));
        }
        Some(json!({ "available": levels }).to_string())
    }

    /// The data's bounds in degrees (west, south, east, north); the whole longitude range when
    /// it crosses the antimeridian.
    #[must_use]
    pub fn bounds(&self) -> [f64; 4] {
        let s = self.rects.iter().map(|r| r.south).fold(90.0, f64::min);
        let n = self.rects.iter().map(|r| r.north).fold(-90.0, f64::max);
        if self.rects.len() == 1 {
            let r = self.rects[0];
            [r.west, s, r.east, n]
        } else {
            [-180.0, s, 180.0, n]
        }
    }
}

/// `layer.json`: what CesiumJS's `CesiumTerrainProvider`, Cesium for Unreal/Unity and osgEarth
/// read. `version` goes into every tile URL (`?v=`), so tiles are immutable per content version.
#[must_use]
pub fn layer_json(name: &str, coverage: &Coverage, attribution: &str, version: &str) -> serde_json::Value {
    let (cols, _) = tiles_at(0);
    debug_assert_eq!(cols, 2);
    let available: Vec<serde_json::Value> = (0..=coverage.max_zoom)
        .map(|z| serde_json::Value::Array(coverage.available(z).iter().map(Range::json).collect()))
        .collect();
    json!({
        "tilejson": "2.1.0",
        "name": name,
        "description": format!("{name}: quantized-mesh terrain by terrastream"),
        "version": "1.2.0",
        "format": "quantized-mesh-1.0",
        "attribution": attribution,
        "scheme": "tms",
        "tiles": [format!("{{z}}/{{x}}/{{y}}.terrain?v={version}")],
        "projection": "EPSG:4326",
        "bounds": coverage.bounds(),
        "minzoom": 0,
        "maxzoom": coverage.max_zoom,
        "available": available,
        "extensions": ["octvertexnormals", "watermask", "metadata"],
        "metadataAvailability": METADATA_AVAILABILITY,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn alps() -> Coverage {
        Coverage { rects: vec![Rect { west: 10.5, south: 46.5, east: 10.9, north: 46.8 }], max_zoom: 14 }
    }

    #[test]
    fn availability_follows_the_data() {
        let c = alps();
        assert_eq!(c.available(0), vec![Range { x0: 0, y0: 0, x1: 1, y1: 0 }]);
        assert!(c.available(15).is_empty());
        for z in 1..=14 {
            let r = c.available(z);
            assert_eq!(r.len(), 1);
            let step = 180.0 / f64::from(1u32 << z);
            // The range's tiles cover the rectangle and no tile more.
            assert!(
                -180.0 + f64::from(r[0].x0) * step <= 10.5 && -180.0 + f64::from(r[0].x1 + 1) * step >= 10.9
            );
            assert!(-180.0 + f64::from(r[0].x0 + 1) * step > 10.5);
            assert!(-90.0 + f64::from(r[0].y1) * step < 46.8);
        }
        let n = c.tiles().count() as u64;
        assert_eq!(n, c.tile_count());
        assert!(c.has(TileId { z: 0, x: 0, y: 0 }));
        assert!(!c.has(TileId { z: 3, x: 0, y: 0 }));
    }

    #[test]
    fn metadata_names_descendants_only() {
        let c = alps();
        assert!(c.metadata(TileId { z: 3, x: 8, y: 5 }).is_none());
        let m: serde_json::Value =
            serde_json::from_str(&c.metadata(TileId { z: 0, x: 1, y: 0 }).unwrap()).unwrap();
        let levels = m["available"].as_array().unwrap();
        assert_eq!(levels.len(), 10);
        assert_eq!(levels[0][0], json!({"startX": 2, "startY": 1, "endX": 2, "endY": 1}));
        // The western root has none of the data below it.
        let w: serde_json::Value =
            serde_json::from_str(&c.metadata(TileId { z: 0, x: 0, y: 0 }).unwrap()).unwrap();
        assert!(w["available"].as_array().unwrap().iter().all(|l| l.as_array().unwrap().is_empty()));
        // Zoom 10 carries zooms 11..=14 only.
        let id = c.tiles().find(|t| t.z == 10).unwrap();
        let m: serde_json::Value = serde_json::from_str(&c.metadata(id).unwrap()).unwrap();
        assert_eq!(m["available"].as_array().unwrap().len(), 4);
    }

    #[test]
    fn layer_offers_metadata_with_its_availability() {
        let l = layer_json("t", &alps(), "", "abc");
        assert_eq!(l["metadataAvailability"], 10);
        assert!(l["extensions"].as_array().unwrap().contains(&json!("metadata")));
        assert_eq!(l["available"].as_array().unwrap().len(), 15);
        assert_eq!(l["tiles"][0], "{z}/{x}/{y}.terrain?v=abc");
    }

    #[test]
    fn antimeridian_tiles_are_listed_once() {
        let c = Coverage {
            rects: vec![
                Rect { west: 179.0, south: -17.0, east: 180.0, north: -16.0 },
                Rect { west: -180.0, south: -17.0, east: -179.0, north: -16.0 },
            ],
            max_zoom: 6,
        };
        let all: Vec<TileId> = c.tiles().collect();
        let mut dedup = all.clone();
        dedup.sort();
        dedup.dedup();
        assert_eq!(all.len(), dedup.len());
        assert!(c.bounds().iter().zip([-180.0, -17.0, 180.0, -16.0]).all(|(a, b)| (a - b).abs() < 1e-12));
        assert_eq!(c.available(1).len(), 2);
    }
}
