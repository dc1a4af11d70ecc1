//! Where a 3D Tiles tileset lies on the globe ([`Placement`]): the tileset frame is
//! east-north-up metres around a local origin (the centre of the data at height 0; a model's
//! bottom centre), and the root tile's `transform` takes it to Earth-centred coordinates at the
//! anchor ([`Anchor`]: longitude, latitude, ellipsoidal height). glTF is y-up, so a glTF
//! position is (east, up, −north).

use serde::{Deserialize, Serialize};
use serde_json::{Value, json};

use std::sync::Arc;

use super::earth::EarthFrame;
use crate::crs::PlaceError;
use crate::geom::Bounds;
use crate::raster::FrameError;
use crate::store::{Manifest, TilesetKind};

/// Where a tileset with no anchor of its own is placed: 0° E, 0° N, height 0 (stated in the
/// tileset JSON's `asset.extras.terrastream.anchor`, `from: "default"`).
pub const DEFAULT_ANCHOR: Anchor = Anchor { lon: 0.0, lat: 0.0, height: 0.0 };
/// Largest |height| of an anchor, metres (as raster heights).
pub const MAX_ANCHOR_HEIGHT: f64 = crate::raster::MAX_HEIGHT;

/// An anchor coordinate out of range ([`Anchor::check`]).
#[derive(Debug, Clone, Copy, PartialEq, thiserror::Error)]
pub enum AnchorRangeError {
    #[error("longitude {0} is not within -180..180 degrees")]
    Longitude(f64),
    #[error("latitude {0} is not within -90..90 degrees")]
    Latitude(f64),
    #[error("height {0} is not within ±1e7 m")]
    Height(f64),
}

/// Why a text is not an anchor ([`Anchor::parse`]); each names the text as given.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum AnchorError {
    #[error("anchor {text:?}: expected LON,LAT or LON,LAT,HEIGHT")]
    Syntax { text: String },
    /// `what` is "longitude", "latitude" or "height".
    #[error("anchor {text:?}: {what} {value:?} is not a number")]
    NotANumber { text: String, what: &'static str, value: String },
    #[error("anchor {text:?}: {source}")]
    OutOfRange { text: String, source: AnchorRangeError },
}

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
    pub fn parse(s: &str) -> Result<Self, AnchorError> {
        let parts: Vec<&str> = s.split(',').map(str::trim).collect();
        if !(2..=3).contains(&parts.len()) {
            return Err(AnchorError::Syntax { text: s.to_owned() });
        }
        let num = |t: &str, what: &'static str| {
            t.parse::<f64>().map_err(|_| AnchorError::NotANumber {
                text: s.to_owned(),
                what,
                value: t.to_owned(),
            })
        };
        let a = Self {
            lon: num(parts[0], "longitude")?,
            lat: num(parts[1], "latitude")?,
            height: parts.get(2).map_or(Ok(0.0), |t| num(t, "height"))?,
        };
        a.check().map_err(|source| AnchorError::OutOfRange { text: s.to_owned(), source })?;
        Ok(a)
    }

    /// Checks the ranges: longitude −180..180, latitude −90..90, |height| ≤ 1e7 m.
    pub fn check(&self) -> Result<(), AnchorRangeError> {
        if !(self.lon.is_finite() && (-180.0..=180.0).contains(&self.lon)) {
            return Err(AnchorRangeError::Longitude(self.lon));
        }
        if !(self.lat.is_finite() && (-90.0..=90.0).contains(&self.lat)) {
            return Err(AnchorRangeError::Latitude(self.lat));
        }
        if !(self.height.is_finite() && self.height.abs() <= MAX_ANCHOR_HEIGHT) {
            return Err(AnchorRangeError::Height(self.height));
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

/// A tileset's place on the globe. With a coordinate system (`earth`), every vertex is placed
/// exactly ([`super::earth`]) and the anchor only names the data's centre; without one (a local
/// frame, a model), the anchor, the world point placed there and the axes.
#[derive(Debug, Clone)]
pub struct Placement {
    pub anchor: Anchor,
    pub from: AnchorFrom,
    /// The world point at the anchor.
    pub origin: [f64; 3],
    pub axes: Axes,
    /// The exact frame of a tileset with a coordinate system.
    pub earth: Option<EarthFrame>,
    /// The dataset's sample grid: sample (col, row) lies at world x = `x0 + col·dx`,
    /// y = `y0 + row·dy` (`[x0, y0, dx, dy]`), which names the samples tiles share.
    pub samples: [f64; 4],
    /// A geographic grid whose columns go once around the Earth, its last column on the
    /// meridian of its first (ETOPO, GEBCO): that column count, by which column `n` is column 0
    /// (the antimeridian is a border like any other).
    pub wrap_cols: Option<i64>,
}

impl Placement {
    /// The placement of a tileset: `anchor` (from `--anchor`) wins; a geographic terrain source
    /// is anchored at the centre of its data; anything else at [`DEFAULT_ANCHOR`].
    ///
    /// A terrain tileset with a coordinate system is placed by it, exactly, whatever `anchor`
    /// says; its frame fails only when its geoid grid cannot be read.
    pub fn of(m: &Manifest, kind: TilesetKind, anchor: Option<Anchor>) -> Result<Self, FrameError> {
        let b = &m.bounds;
        let c = b.center();
        let (origin, axes) = match kind {
            TilesetKind::Terrain => {
                let axes =
                    if m.frame.crs.is_some() || m.frame.dy < 0.0 { Axes::NorthUp } else { Axes::RowsSouth };
                ([c.x, c.y, 0.0], axes)
            }
            TilesetKind::Model => ([c.x, b.min.y, c.z], Axes::ModelYUp),
        };
        let earth = match kind {
            TilesetKind::Terrain => m.frame.frame()?.map(Arc::new),
            TilesetKind::Model => None,
        };
        let source = earth.as_ref().and_then(|f| {
            f.to_geodetic(origin).ok().and_then(|(lon, lat, height)| {
                let a = Anchor { lon, lat, height };
                a.check().is_ok().then_some(a)
            })
        });
        let (anchor, from) = match (source, anchor) {
            (Some(a), _) => (a, AnchorFrom::Source),
            (None, Some(a)) => (a, AnchorFrom::Option),
            (None, None) => (DEFAULT_ANCHOR, AnchorFrom::Default),
        };
        let cols = i64::from(m.source.width) - 1;
        let wrap_cols = earth
            .as_ref()
            .filter(|f| f.grid.crs.is_geographic() && cols >= 2)
            .filter(|f| (cols as f64 * f.grid.de.abs() - 360.0).abs() <= 1e-6)
            .map(|_| cols);
        let f = &m.frame;
        Ok(Self { anchor, from, origin, axes, earth, samples: [f.x0, f.y0, f.dx, f.dy], wrap_cols })
    }

    /// How far a GLB's positions may lie from where they belong, metres: on the Earth, the f32
    /// rounding of positions relative to the node's centre (half an ulp per axis of the
    /// farthest, the box's half-diagonal plus the Earth's drop there); 0 in a local frame, whose
    /// positions are the blob's integers.
    #[must_use]
    pub fn position_error(&self, b: &Bounds) -> f64 {
        if self.earth.is_none() {
            return 0.0;
        }
        let half = b.size().length() / 2.0;
        let reach = half + half * half / (2.0 * 6_371_000.0);
        reach * f64::from(f32::EPSILON) * 3f64.sqrt() / 2.0
    }

    /// A tile's `boundingVolume` for a world box: a `region` on the Earth, a `box` in the
    /// tileset frame otherwise.
    pub fn bounding_volume(&self, b: &Bounds) -> Result<Value, PlaceError> {
        match &self.earth {
            Some(f) => Ok(json!({ "region": super::earth::region(f, b)? })),
            None => Ok(json!({ "box": self.enu_box(b) })),
        }
    }

    /// Per glTF axis: the world axis it reads and its sign (glTF = east, up, −north).
    pub(super) fn axis_map(&self) -> [(usize, f64); 3] {
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
    pub(super) fn describe(&self) -> Value {
        if let Some(f) = &self.earth {
            return json!({
                "placement": "exact",
                "centre": { "lon": self.anchor.lon, "lat": self.anchor.lat, "height": self.anchor.height },
                "frame": {
                    "crs": f.grid.crs.record(),
                    "vertical_datum": f.vertical,
                    "geoid": f.geoid.as_ref().map(|g| g.name.clone()),
                },
                "note": "every vertex placed from its sample's longitude, latitude and ellipsoidal height; each GLB's node matrix is the east-north-up frame at its node's centre",
            });
        }
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
