//! Heights at arbitrary points, for simulators: a wheel, a landing gear, a sensor ray. A
//! [`SourceSampler`] answers from the dataset itself (`surface=source`): points in WGS 84
//! lon/lat, the dataset's CRS or its local world frame; nearest, bilinear or cubic
//! interpolation; heights on the ellipsoid, on the EGM96 geoid or as stored. Each answer carries
//! the error bound that applies and a no-data flag. Deterministic: the same points give the same
//! bits. Pure over a [`WindowReader`] (an in-memory raster or a dataset read by blocks).

use std::sync::Arc;

pub mod mesh;

pub use mesh::{BlobSource, MeshCache, MeshSampler};

use crate::crs::{Frame, Geoid};
use crate::raster::{Georef, RasterError, WindowReader};

/// The coordinates of the points asked about.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, serde::Deserialize, serde::Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Coords {
    /// WGS 84 longitude, latitude in degrees (longitudes 0…360 are taken as −180…180).
    #[default]
    Wgs84,
    /// The dataset's CRS (its units: metres or feet, or degrees for a geographic CRS).
    Crs,
    /// The tileset's world frame (what its blobs' x and y are in).
    Local,
}

/// How heights between samples are interpolated.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, serde::Deserialize, serde::Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Interp {
    /// The nearest sample.
    Nearest,
    /// Bilinear over the four samples around the point.
    #[default]
    Bilinear,
    /// Cubic convolution (Keys, a = −0.5, GDAL's `cubic`) over the 4×4 samples around it.
    Cubic,
}

/// What the answered heights are measured from.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, serde::Deserialize, serde::Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Datum {
    /// The WGS 84 ellipsoid (what GPS, Cesium and 3D Tiles use).
    #[default]
    Ellipsoid,
    /// The EGM96 geoid (mean sea level; what SRTM, JSBSim and most maps use).
    Geoid,
    /// The dataset's own heights, as stored.
    Native,
}

/// What to sample.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct Query {
    pub coords: Coords,
    pub interp: Interp,
    pub datum: Datum,
}

/// One answer.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Height {
    /// The height (metres on the asked datum); NaN where there is no data.
    pub h: f64,
    /// The bound that applies (metres): the interpolation's, assuming the ground between
    /// samples stays within the range of the samples around the point (see [`SourceSampler`]);
    /// NaN where there is no data.
    pub error: f64,
    /// The point is outside the data.
    pub nodata: bool,
}

impl Height {
    const NODATA: Self = Self { h: f64::NAN, error: f64::NAN, nodata: true };
}

/// Why points cannot be answered.
#[derive(Debug, thiserror::Error)]
pub enum HeightsError {
    #[error("point {index}: coordinate {value} is not a finite number")]
    NonFinite { index: usize, value: f64 },
    #[error("point {index}: latitude {lat} is outside −90…90")]
    Latitude { index: usize, lat: f64 },
    #[error("point {index}: longitude {lon} is outside −180…360")]
    Longitude { index: usize, lon: f64 },
    #[error("point {index}: {message}")]
    Transform { index: usize, message: String },
    #[error(
        "this dataset has no coordinate reference system: only coords=local and datum=native apply (asked coords={coords}, datum={datum})"
    )]
    NotPlaced { coords: &'static str, datum: &'static str },
    #[error(transparent)]
    Raster(#[from] RasterError),
    #[error("{0}")]
    Frame(String),
    #[error("depth {depth} is deeper than the tileset's finest nodes (depth {max})")]
    Depth { depth: u8, max: u8 },
    #[error("node {key}: {message}")]
    Blob { key: crate::tiling::TileKey, message: String },
    #[error("the height cache is unusable after a panic")]
    Poisoned,
}

impl Coords {
    #[must_use]
    pub fn name(self) -> &'static str {
        match self {
            Self::Wgs84 => "wgs84",
            Self::Crs => "crs",
            Self::Local => "local",
        }
    }
}

impl Datum {
    #[must_use]
    pub fn name(self) -> &'static str {
        match self {
            Self::Ellipsoid => "ellipsoid",
            Self::Geoid => "geoid",
            Self::Native => "native",
        }
    }
}

/// Heights from a dataset. The interpolation's error bound: nearest, the range of the 2×2
/// samples around the point (the ground may be anywhere between them); bilinear, the larger
/// distance from the answer to the least and greatest of those four; cubic, the same over the
/// 4×4 samples it weighs. A point whose samples are not all inside the data (beyond half a cell
/// from the outermost samples) has no data.
pub struct SourceSampler<'a> {
    reader: &'a dyn WindowReader,
    georef: Georef,
    frame: Option<Frame>,
    egm96: Arc<Geoid>,
    width: u32,
    height: u32,
}

impl<'a> SourceSampler<'a> {
    /// The heights of `reader` on `georef`'s grid.
    pub fn new(reader: &'a dyn WindowReader, georef: &Georef) -> Result<Self, HeightsError> {
        let frame = georef.frame().map_err(|e| HeightsError::Frame(e.to_string()))?;
        let egm96 = Geoid::egm96().map_err(|e| HeightsError::Frame(e.to_string()))?;
        let (width, height) = reader.size();
        Ok(Self { reader, georef: georef.clone(), frame, egm96, width, height })
    }

    /// Whether the dataset is placed on the Earth (has a CRS).
    #[must_use]
    pub fn is_placed(&self) -> bool {
        self.frame.is_some()
    }

    /// The answers for `points` (x, y in `q.coords`), in order. Bad coordinates are refused
    /// before anything is read, naming the first bad point.
    pub fn sample(&self, points: &[[f64; 2]], q: Query) -> Result<Vec<Height>, HeightsError> {
        self.sample_from(points, q, 0)
    }

    /// [`SourceSampler::sample`] of a batch whose first point is point `base` of a larger one
    /// (errors name points by their index in that).
    pub fn sample_from(
        &self,
        points: &[[f64; 2]],
        q: Query,
        base: usize,
    ) -> Result<Vec<Height>, HeightsError> {
        if self.frame.is_none() && (q.coords != Coords::Local || q.datum != Datum::Native) {
            return Err(HeightsError::NotPlaced { coords: q.coords.name(), datum: q.datum.name() });
        }
        for (index, p) in points.iter().enumerate() {
            check(base + index, *p, q.coords)?;
        }
        let mut out = Vec::with_capacity(points.len());
        let mut buf = Vec::with_capacity(16);
        for (index, &p) in points.iter().enumerate() {
            out.push(self.one(base + index, p, q, &mut buf)?);
        }
        Ok(out)
    }

    /// The fractional (column, row) of a point and its WGS 84 position (for the datum).
    fn locate(&self, index: usize, p: [f64; 2], coords: Coords) -> Result<Located, HeightsError> {
        let transform = |e: crate::crs::CrsError| HeightsError::Transform { index, message: e.to_string() };
        let Some(frame) = &self.frame else {
            let g = &self.georef;
            return Ok((((p[0] - g.x0) / g.dx, (p[1] - g.y0) / g.dy), None));
        };
        let g = &frame.grid;
        let (e, n, lonlat) = match coords {
            Coords::Wgs84 => {
                let lon = crate::crs::wrap_lon(p[0]);
                let (e, n) = g.crs.from_wgs84(lon, p[1]).map_err(transform)?;
                (e, n, Some((lon, p[1])))
            }
            Coords::Crs => (p[0], p[1], None),
            Coords::Local => {
                let (e, n) = frame.crs_xy(p[0], p[1]);
                (e, n, None)
            }
        };
        let lonlat = match lonlat {
            Some(ll) => ll,
            None => g.crs.to_wgs84(e, n).map_err(transform)?,
        };
        let (mut c, r) = ((e - g.e0) / g.de, (n - g.n0) / g.dn);
        if g.crs.is_geographic() && !self.inside(c, r) {
            // A raster in 0…360 asked in −180…180, or the other way round.
            for turn in [360.0, -360.0] {
                let c2 = (e + turn - g.e0) / g.de;
                if self.inside(c2, r) {
                    c = c2;
                    break;
                }
            }
        }
        Ok(((c, r), Some(lonlat)))
    }

    fn inside(&self, c: f64, r: f64) -> bool {
        c >= -0.5 && r >= -0.5 && c <= f64::from(self.width) - 0.5 && r <= f64::from(self.height) - 0.5
    }

    fn one(&self, index: usize, p: [f64; 2], q: Query, buf: &mut Vec<f32>) -> Result<Height, HeightsError> {
        // A point with no place in the dataset's CRS (beyond a projection's domain) has no data.
        let ((c, r), lonlat) = match self.locate(index, p, q.coords) {
            Ok(l) => l,
            Err(HeightsError::Transform { .. }) => return Ok(Height::NODATA),
            Err(e) => return Err(e),
        };
        if !self.inside(c, r) {
            return Ok(Height::NODATA);
        }
        let (w, h) = (i64::from(self.width), i64::from(self.height));
        // The samples weighed: 2×2 around the point (4×4 for cubic), clamped at the edge.
        let (c0, r0) = (c.floor() as i64, r.floor() as i64);
        let (fx, fy) = (c - c0 as f64, r - r0 as f64);
        let reach = i64::from(q.interp == Interp::Cubic);
        let cols: Vec<u32> = (c0 - reach..=c0 + 1 + reach).map(|k| k.clamp(0, w - 1) as u32).collect();
        let rows: Vec<u32> = (r0 - reach..=r0 + 1 + reach).map(|k| k.clamp(0, h - 1) as u32).collect();
        self.reader.read_window(&cols, &rows, buf)?;
        let n = cols.len();
        let at = |i: usize, j: usize| f64::from(buf[j * n + i]);
        let (lo, hi) = buf.iter().fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), &v| {
            (a.min(f64::from(v)), b.max(f64::from(v)))
        });
        let (value, error) = match q.interp {
            Interp::Nearest => {
                let (i, j) = (usize::from(fx >= 0.5), usize::from(fy >= 0.5));
                (at(i, j), hi - lo)
            }
            Interp::Bilinear => {
                let v = (at(0, 0) * (1.0 - fx) + at(1, 0) * fx) * (1.0 - fy)
                    + (at(0, 1) * (1.0 - fx) + at(1, 1) * fx) * fy;
                (v, (v - lo).max(hi - v))
            }
            Interp::Cubic => {
                let (wx, wy) = (keys(fx), keys(fy));
                let mut v = 0.0;
                for (j, wj) in wy.iter().enumerate() {
                    let row: f64 = wx.iter().enumerate().map(|(i, wi)| wi * at(i, j)).sum();
                    v += wj * row;
                }
                (v, (v - lo).max(hi - v))
            }
        };
        let h = to_datum(value, q.datum, self.frame.as_ref(), lonlat, &self.egm96, index)?;
        Ok(Height { h, error, nodata: false })
    }
}

/// A height as stored (on `frame`'s vertical datum) on `datum`, at `lonlat` (point `index`).
fn to_datum(
    value: f64,
    datum: Datum,
    frame: Option<&Frame>,
    lonlat: Option<(f64, f64)>,
    egm96: &Geoid,
    index: usize,
) -> Result<f64, HeightsError> {
    let (Some(frame), Some((lon, lat))) = (frame, lonlat) else { return Ok(value) };
    if datum == Datum::Native {
        return Ok(value);
    }
    let place = |e: crate::crs::PlaceError| HeightsError::Transform { index, message: e.to_string() };
    let ellipsoidal = value + frame.undulation(lon, lat).map_err(place)?;
    if datum == Datum::Ellipsoid {
        return Ok(ellipsoidal);
    }
    let n = egm96.undulation(lon, lat).ok_or_else(|| HeightsError::Transform {
        index,
        message: format!("no EGM96 undulation at {lon}°, {lat}°"),
    })?;
    Ok(ellipsoidal - n)
}

/// A point's fractional (column, row) in the source and, for a placed dataset, its WGS 84
/// longitude and latitude.
type Located = ((f64, f64), Option<(f64, f64)>);

/// Keys' cubic convolution weights (a = −0.5) of the four samples around fraction `t`.
fn keys(t: f64) -> [f64; 4] {
    let a = -0.5;
    let w = |x: f64| {
        let x = x.abs();
        if x <= 1.0 {
            ((a + 2.0) * x - (a + 3.0)) * x * x + 1.0
        } else if x < 2.0 {
            ((a * x - 5.0 * a) * x + 8.0 * a) * x - 4.0 * a
        } else {
            0.0
        }
    };
    [w(1.0 + t), w(t), w(1.0 - t), w(2.0 - t)]
}

/// Refuses a point whose coordinates cannot be a place.
pub fn check(index: usize, p: [f64; 2], coords: Coords) -> Result<(), HeightsError> {
    for value in p {
        if !value.is_finite() {
            return Err(HeightsError::NonFinite { index, value });
        }
    }
    if coords == Coords::Wgs84 {
        if !(-90.0..=90.0).contains(&p[1]) {
            return Err(HeightsError::Latitude { index, lat: p[1] });
        }
        if !(-180.0..=360.0).contains(&p[0]) {
            return Err(HeightsError::Longitude { index, lon: p[0] });
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests;
