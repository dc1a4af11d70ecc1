//! Coordinate reference systems: what a dataset's coordinates mean on the Earth ([`Crs`]), how a
//! raster's grid maps onto them ([`CrsGrid`]), what its heights are measured from
//! ([`VerticalDatum`], [`Geoid`]), and the exact way from the world frame to WGS 84 and ECEF
//! ([`Frame`]).
//!
//! Pure Rust: `proj4rs` does the projections and datum shifts from the EPSG definitions of
//! `crs-definitions` (6,184 codes as PROJ strings), so nothing needs a system library. Datum shifts
//! are the definitions' Helmert parameters (`+towgs84`), as PROJ applies them without grids: good
//! to about a metre for NAD83, ETRS89 and NZGD2000 (all within ~1–2 m of WGS 84, taken as equal)
//! and 1–3 m for the classical datums with 3- or 7-parameter shifts (CH1903+, OSGB36, Potsdam …);
//! grid-based shifts (NTv2, `+nadgrids`) are refused rather than silently skipped. Projections
//! agree with PROJ to better than a millimetre (tested against pyproj in `tests/placement/`).

pub mod ecef;
pub mod geoid;

use std::sync::Arc;

use serde::{Deserialize, Serialize};

pub use geoid::{Geoid, GeoidError, VerticalDatum};

/// Why a CRS cannot be used. Each names what was given.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum CrsError {
    /// An EPSG code outside the table.
    #[error(
        "EPSG:{0} is not a coordinate system terrastream knows (its table holds the 6,184 EPSG codes of crs-definitions)"
    )]
    UnknownEpsg(u32),
    /// A text that is neither `EPSG:n`, a PROJ string nor WKT with an EPSG identifier.
    #[error(
        "{text:?} is not a CRS: expected EPSG:NNNN, EPSG:NNNN+VVVV (with a vertical CRS), a PROJ string (+proj=…) or WKT with an EPSG identifier"
    )]
    Syntax { text: String },
    /// proj4rs refused the definition.
    #[error("{definition}: {message}")]
    Unsupported { definition: String, message: String },
    /// A vertical CRS code that is not one of the datums terrastream converts.
    #[error("vertical CRS EPSG:{0} is not supported: expected 5773 (EGM96 height) or 3855 (EGM2008 height)")]
    UnknownVertical(u32),
    /// A point the projection cannot convert.
    #[error("({x}, {y}) in {definition}: {message}")]
    Point { definition: String, x: f64, y: f64, message: String },
}

/// A horizontal coordinate reference system.
#[derive(Clone)]
pub struct Crs {
    /// `EPSG:n` when it came from a code, else the PROJ string as given.
    definition: String,
    epsg: Option<u32>,
    proj4: String,
    proj: Arc<proj4rs::Proj>,
    wgs84: Arc<proj4rs::Proj>,
}

impl std::fmt::Debug for Crs {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "Crs({})", self.definition)
    }
}

impl PartialEq for Crs {
    fn eq(&self, other: &Self) -> bool {
        self.proj4 == other.proj4
    }
}

/// How a [`Crs`] is recorded in manifests: its definition and the PROJ string it resolved to.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct CrsRecord {
    pub definition: String,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub epsg: Option<u32>,
    pub proj4: String,
    /// "geographic" or "projected".
    pub kind: String,
    /// Metres per unit of the coordinates (1 for degrees: see `kind`).
    pub unit_metres: f64,
}

impl Serialize for Crs {
    fn serialize<S: serde::Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        self.record().serialize(s)
    }
}

impl<'de> Deserialize<'de> for Crs {
    fn deserialize<D: serde::Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        let r = CrsRecord::deserialize(d)?;
        let mut c = Self::from_proj4(&r.proj4).map_err(serde::de::Error::custom)?;
        c.definition = r.definition;
        c.epsg = r.epsg;
        Ok(c)
    }
}

const WGS84: &str = "+proj=longlat +datum=WGS84 +no_defs";

impl Crs {
    /// The WGS 84 geographic CRS (EPSG:4326).
    #[must_use]
    pub fn wgs84() -> Self {
        Self::from_epsg(4326).unwrap_or_else(|_| unreachable!("EPSG:4326 is in the table"))
    }

    /// A CRS by its EPSG code.
    pub fn from_epsg(code: u32) -> Result<Self, CrsError> {
        let def = u16::try_from(code)
            .ok()
            .and_then(crs_definitions::from_code)
            .ok_or(CrsError::UnknownEpsg(code))?;
        let mut c = Self::from_proj4(def.proj4)?;
        c.definition = format!("EPSG:{code}");
        c.epsg = Some(code);
        Ok(c)
    }

    /// A CRS from a PROJ string.
    pub fn from_proj4(proj4: &str) -> Result<Self, CrsError> {
        let unsupported = |message: String| CrsError::Unsupported { definition: proj4.to_owned(), message };
        if proj4.contains("+nadgrids=") && !proj4.contains("+nadgrids=@null") {
            return Err(unsupported(
                "datum shifts by grid (+nadgrids) are not supported; give a definition with +towgs84 parameters"
                    .into(),
            ));
        }
        // A datum other than WGS 84's ellipsoid with no shift to it would be taken as WGS 84:
        // hundreds of metres off for the classical datums. Refused, not guessed.
        let has_shift = ["+towgs84=", "+datum=", "+nadgrids=@null"].iter().any(|k| proj4.contains(k));
        let wgs84_like =
            ["+ellps=WGS84", "+ellps=GRS80", "+a=6378137 +b=6378137"].iter().any(|k| proj4.contains(k))
                || !(proj4.contains("+ellps=") || proj4.contains("+a=") || proj4.contains("+R="));
        if !has_shift && !wgs84_like {
            return Err(unsupported(
                "the definition states no datum shift to WGS 84 (+towgs84) for its ellipsoid; give the CRS with \
                 --crs as a PROJ string with +towgs84 parameters"
                    .into(),
            ));
        }
        if proj4.contains("+geoidgrids=") {
            return Err(unsupported(
                "+geoidgrids: give the vertical datum with --vertical-datum instead".into(),
            ));
        }
        let proj = proj4rs::Proj::from_proj_string(proj4).map_err(|e| unsupported(e.to_string()))?;
        if proj.is_geocent() {
            return Err(unsupported("a geocentric CRS is not a raster's horizontal CRS".into()));
        }
        if !proj.has_inverse() {
            return Err(unsupported(format!("the projection {} has no inverse", proj.projname())));
        }
        let wgs84 = proj4rs::Proj::from_proj_string(WGS84).map_err(|e| unsupported(e.to_string()))?;
        Ok(Self {
            definition: proj4.trim().to_owned(),
            epsg: None,
            proj4: proj4.trim().to_owned(),
            proj: Arc::new(proj),
            wgs84: Arc::new(wgs84),
        })
    }

    /// A CRS from a PROJ string under another name: what a file's own description of it says
    /// (e.g. a GeoTIFF's user-defined keys). The PROJ string still defines it, and manifests
    /// record both.
    pub fn from_proj4_named(proj4: &str, definition: &str) -> Result<Self, CrsError> {
        let mut c = Self::from_proj4(proj4)?;
        definition.trim().clone_into(&mut c.definition);
        Ok(c)
    }

    /// A CRS from what a user or a file gives: `EPSG:n` (or `epsg:n`), a PROJ string, or WKT
    /// (1 or 2) whose outermost CRS carries an EPSG identifier. A vertical part
    /// (`EPSG:32632+5773`, or a compound WKT) is returned separately.
    pub fn parse(text: &str) -> Result<(Self, Option<VerticalDatum>), CrsError> {
        let t = text.trim();
        let syntax = || CrsError::Syntax { text: text.to_owned() };
        if t.starts_with('+') {
            return Ok((Self::from_proj4(t)?, None));
        }
        let upper = t.to_ascii_uppercase();
        if let Some(rest) = upper.strip_prefix("EPSG:") {
            let (h, v) = match rest.split_once('+') {
                Some((h, v)) => (h, Some(v)),
                None => (rest, None),
            };
            let code = |s: &str| s.trim().parse::<u32>().map_err(|_| syntax());
            let vertical = match v {
                Some(v) => {
                    let c = code(v)?;
                    Some(VerticalDatum::from_epsg(c).ok_or(CrsError::UnknownVertical(c))?)
                }
                None => None,
            };
            return Ok((Self::from_epsg(code(h)?)?, vertical));
        }
        if let Some(code) = wkt_epsg(t) {
            let vertical = wkt_vertical(t)?;
            return Ok((Self::from_epsg(code)?, vertical));
        }
        Err(syntax())
    }

    /// `EPSG:n` or the PROJ string.
    #[must_use]
    pub fn definition(&self) -> &str {
        &self.definition
    }

    #[must_use]
    pub fn epsg(&self) -> Option<u32> {
        self.epsg
    }

    /// True for longitude/latitude CRSs (coordinates in degrees).
    #[must_use]
    pub fn is_geographic(&self) -> bool {
        self.proj.is_latlong()
    }

    /// Metres per coordinate unit of a projected CRS (0.3048006 for US survey feet); 1 for a
    /// geographic one (whose unit is the degree).
    #[must_use]
    pub fn unit_metres(&self) -> f64 {
        if self.is_geographic() { 1.0 } else { self.proj.to_meter() }
    }

    /// How manifests record it.
    #[must_use]
    pub fn record(&self) -> CrsRecord {
        CrsRecord {
            definition: self.definition.clone(),
            epsg: self.epsg,
            proj4: self.proj4.clone(),
            kind: if self.is_geographic() { "geographic" } else { "projected" }.into(),
            unit_metres: self.unit_metres(),
        }
    }

    /// WGS 84 longitude (−180..180) and latitude, degrees, of a point in this CRS's coordinates
    /// (degrees for a geographic CRS: any longitude, 0–360 included).
    pub fn to_wgs84(&self, x: f64, y: f64) -> Result<(f64, f64), CrsError> {
        let (lon, lat, _) = self.to_wgs84_3d(x, y, 0.0)?;
        Ok((lon, lat))
    }

    /// As [`Crs::to_wgs84`], with an ellipsoidal height on this CRS's datum turned into one on
    /// WGS 84 (the datum shift moves heights too: up to ~100 m between Bessel and WGS 84).
    pub fn to_wgs84_3d(&self, x: f64, y: f64, h: f64) -> Result<(f64, f64, f64), CrsError> {
        let bad = |message: String| CrsError::Point { definition: self.definition.clone(), x, y, message };
        if !(x.is_finite() && y.is_finite() && h.is_finite()) {
            return Err(bad("not a finite coordinate".into()));
        }
        let mut p = if self.is_geographic() {
            // A latitude past a pole (a bounding box or a point level reaching over the edge of
            // a polar raster) is the pole.
            (wrap_lon(x).to_radians(), y.clamp(-90.0, 90.0).to_radians(), h)
        } else {
            (x, y, h)
        };
        proj4rs::transform::transform(&self.proj, &self.wgs84, &mut p).map_err(|e| bad(e.to_string()))?;
        let (lon, lat) = (wrap_lon(p.0.to_degrees()), p.1.to_degrees());
        if !(lon.is_finite() && lat.is_finite() && lat.abs() <= 90.0 + 1e-9) {
            return Err(bad(format!("converts to ({lon}, {lat})")));
        }
        Ok((lon, lat.clamp(-90.0, 90.0), p.2))
    }

    /// This CRS's coordinates of a WGS 84 longitude and latitude (degrees).
    pub fn from_wgs84(&self, lon: f64, lat: f64) -> Result<(f64, f64), CrsError> {
        let bad =
            |message: String| CrsError::Point { definition: "EPSG:4326".into(), x: lon, y: lat, message };
        if !(lon.is_finite() && lat.is_finite() && lat.abs() <= 90.0) {
            return Err(bad("not a longitude and latitude".into()));
        }
        // Horizontal coordinates of a datum shift depend slightly on the height: solve for the
        // point whose height is 0 on this CRS's datum, as [`Crs::to_wgs84`] reads it (the
        // second pass starts from the WGS 84 height of the first answer's datum height 0).
        let mut p = (wrap_lon(lon).to_radians(), lat.to_radians(), 0.0);
        proj4rs::transform::transform(&self.wgs84, &self.proj, &mut p).map_err(|e| bad(e.to_string()))?;
        if p.2 != 0.0 {
            let h = -p.2;
            p = (wrap_lon(lon).to_radians(), lat.to_radians(), h);
            proj4rs::transform::transform(&self.wgs84, &self.proj, &mut p).map_err(|e| bad(e.to_string()))?;
        }
        if self.is_geographic() {
            return Ok((p.0.to_degrees(), p.1.to_degrees()));
        }
        Ok((p.0, p.1))
    }

    /// A point of this CRS in `to`'s coordinates (degrees for geographic CRSs; the datum shift
    /// between them at height 0).
    pub fn transform_to(&self, to: &Self, x: f64, y: f64) -> Result<(f64, f64), CrsError> {
        let bad = |message: String| CrsError::Point { definition: self.definition.clone(), x, y, message };
        if !(x.is_finite() && y.is_finite()) {
            return Err(bad("not a finite coordinate".into()));
        }
        let mut p = if self.is_geographic() {
            (wrap_lon(x).to_radians(), y.clamp(-90.0, 90.0).to_radians(), 0.0)
        } else {
            (x, y, 0.0)
        };
        proj4rs::transform::transform(&self.proj, &to.proj, &mut p).map_err(|e| bad(e.to_string()))?;
        let out = if to.is_geographic() { (p.0.to_degrees(), p.1.to_degrees()) } else { (p.0, p.1) };
        if out.0.is_finite() && out.1.is_finite() {
            Ok(out)
        } else {
            Err(bad(format!("converts to {out:?}")))
        }
    }

    /// Ground metres per coordinate unit along x and along y at a point (the projection's point
    /// scale, times the unit): metres per degree of longitude and latitude for a geographic CRS.
    pub fn ground_scale(&self, x: f64, y: f64) -> Result<(f64, f64), CrsError> {
        if self.is_geographic() {
            let (m_lon, m_lat) = metres_per_degree(y);
            return Ok((m_lon, m_lat));
        }
        // A step of about a metre, in the CRS's units.
        let s = 1.0 / self.unit_metres();
        let dist = |a: (f64, f64), b: (f64, f64)| {
            let phi = f64::midpoint(a.1, b.1).to_radians();
            let w = (1.0 - ecef::E2 * phi.sin() * phi.sin()).sqrt();
            let n = ecef::A / w;
            let m = ecef::A * (1.0 - ecef::E2) / (w * w * w);
            let dlon = (wrap_lon(b.0 - a.0)).to_radians();
            let dlat = (b.1 - a.1).to_radians();
            (m * dlat).hypot(n * phi.cos() * dlon)
        };
        let p = self.to_wgs84(x, y)?;
        let px = self.to_wgs84(x + s, y)?;
        let py = self.to_wgs84(x, y + s)?;
        Ok((dist(p, px) / s, dist(p, py) / s))
    }
}

/// Metres per degree of (longitude, latitude) at latitude `lat_deg` on the WGS84 ellipsoid
/// (exact for the ellipsoid: the radii of curvature).
#[must_use]
pub fn metres_per_degree(lat_deg: f64) -> (f64, f64) {
    let phi = lat_deg.to_radians();
    let w = (1.0 - ecef::E2 * phi.sin() * phi.sin()).sqrt();
    let n = ecef::A / w;
    let m = ecef::A * (1.0 - ecef::E2) / (w * w * w);
    let k = std::f64::consts::PI / 180.0;
    (n * phi.cos() * k, m * k)
}

/// A longitude in −180..180.
#[must_use]
pub fn wrap_lon(lon: f64) -> f64 {
    if (-180.0..=180.0).contains(&lon) { lon } else { (lon + 180.0).rem_euclid(360.0) - 180.0 }
}

/// The EPSG code of a WKT's outermost CRS: its last `AUTHORITY["EPSG","n"]` (WKT 1) or
/// `ID["EPSG",n]` (WKT 2) when that closes the outermost node; of a compound CRS, its
/// horizontal part's.
fn wkt_epsg(wkt: &str) -> Option<u32> {
    let t = wkt.trim();
    let head = t.split('[').next()?.trim().to_ascii_uppercase();
    let nodes = ["PROJCS", "GEOGCS", "PROJCRS", "GEOGCRS", "GEODCRS", "COMPD_CS", "COMPOUNDCRS", "BOUNDCRS"];
    if !nodes.contains(&head.as_str()) {
        return None;
    }
    if head == "COMPD_CS" || head == "COMPOUNDCRS" {
        // The first sub-CRS is the horizontal one.
        let up = t.to_ascii_uppercase();
        let start = ["PROJCS[", "GEOGCS[", "PROJCRS[", "GEOGCRS[", "GEODCRS["]
            .iter()
            .filter_map(|k| up.find(k))
            .min()?;
        return wkt_epsg(top_node(&t[start..])?);
    }
    let node = top_node(t)?;
    // The identifier of the outermost node is the last one at depth 1.
    let mut depth = 0;
    let mut last = None;
    let bytes = node.as_bytes();
    let mut i = 0;
    while i < bytes.len() {
        match bytes[i] {
            b'[' | b'(' => depth += 1,
            b']' | b')' => depth -= 1,
            b'"' => {
                i += 1;
                while i < bytes.len() && bytes[i] != b'"' {
                    i += 1;
                }
            }
            _ if depth == 1 => {
                let rest = &node[i..];
                let up = rest.get(..10).unwrap_or(rest).to_ascii_uppercase();
                if up.starts_with("AUTHORITY[") || up.starts_with("ID[") {
                    last = Some(i);
                }
            }
            _ => {}
        }
        i += 1;
    }
    let rest = &node[last?..];
    let open = rest.find('[')?;
    let close = rest.find(']')?;
    let parts: Vec<&str> = rest[open + 1..close].split(',').map(|s| s.trim().trim_matches('"')).collect();
    if parts.first()?.eq_ignore_ascii_case("EPSG") { parts.get(1)?.parse().ok() } else { None }
}

/// The vertical datum of a compound WKT's vertical part, when it has one.
fn wkt_vertical(wkt: &str) -> Result<Option<VerticalDatum>, CrsError> {
    let up = wkt.to_ascii_uppercase();
    for key in ["VERT_CS[", "VERTCRS[", "VERTICALCRS["] {
        if let Some(at) = up.find(key) {
            let sub = top_node(&wkt[at..]).unwrap_or(&wkt[at..]);
            let code = wkt_last_epsg(sub);
            return match code {
                Some(c) => VerticalDatum::from_epsg(c).map(Some).ok_or(CrsError::UnknownVertical(c)),
                None => Ok(None),
            };
        }
    }
    Ok(None)
}

fn wkt_last_epsg(node: &str) -> Option<u32> {
    let up = node.to_ascii_uppercase();
    let at = up.rfind("\"EPSG\"")?;
    let rest = &node[at + 6..];
    let digits: String =
        rest.trim_start_matches([',', ' ', '"']).chars().take_while(char::is_ascii_digit).collect();
    digits.parse().ok()
}

/// The first bracketed node of a WKT text (up to its matching bracket), quotes respected.
fn top_node(t: &str) -> Option<&str> {
    let mut depth = 0;
    let mut in_quote = false;
    for (i, c) in t.char_indices() {
        match c {
            '"' => in_quote = !in_quote,
            '[' | '(' if !in_quote => depth += 1,
            ']' | ')' if !in_quote => {
                depth -= 1;
                if depth == 0 {
                    return Some(&t[..=i]);
                }
            }
            _ => {}
        }
    }
    None
}

/// How a raster's grid lies in its CRS: sample (col, row) has its centre at
/// (`e0 + col·de`, `n0 + row·dn`) in the CRS's units (degrees for a geographic CRS).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct CrsGrid {
    pub crs: Crs,
    pub e0: f64,
    pub n0: f64,
    pub de: f64,
    pub dn: f64,
}

/// A tileset's world frame on the Earth: world `x = x0 + col·dx`, `y = y0 + row·dy`, `z` a height
/// on `vertical`, with the grid in its CRS ([`CrsGrid`]). Converts world points to WGS 84 and
/// ECEF and back, exactly (through the CRS, never a tangent plane): what 3D Tiles, heights in
/// lon/lat and a simulator's own origin use.
#[derive(Debug, Clone)]
pub struct Frame {
    pub x0: f64,
    pub y0: f64,
    pub dx: f64,
    pub dy: f64,
    pub grid: CrsGrid,
    pub vertical: VerticalDatum,
    /// The geoid of `vertical` (none for ellipsoidal heights).
    pub geoid: Option<Arc<Geoid>>,
}

/// Why a world point cannot be placed.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum PlaceError {
    #[error(transparent)]
    Crs(#[from] CrsError),
    #[error("no geoid undulation at {lon}°, {lat}° in the {grid} grid")]
    Geoid { lon: f64, lat: f64, grid: String },
}

impl Frame {
    /// The CRS coordinates of a world point.
    #[must_use]
    pub fn crs_xy(&self, x: f64, y: f64) -> (f64, f64) {
        let col = (x - self.x0) / self.dx;
        let row = (y - self.y0) / self.dy;
        (self.grid.e0 + col * self.grid.de, self.grid.n0 + row * self.grid.dn)
    }

    /// The world point of CRS coordinates.
    #[must_use]
    pub fn world_xy(&self, e: f64, n: f64) -> (f64, f64) {
        let col = (e - self.grid.e0) / self.grid.de;
        let row = (n - self.grid.n0) / self.grid.dn;
        (self.x0 + col * self.dx, self.y0 + row * self.dy)
    }

    /// WGS 84 longitude, latitude and ellipsoidal height of a world point.
    pub fn to_geodetic(&self, p: [f64; 3]) -> Result<(f64, f64, f64), PlaceError> {
        let (e, n) = self.crs_xy(p[0], p[1]);
        let (lon, lat) = self.grid.crs.to_wgs84(e, n)?;
        Ok((lon, lat, p[2] + self.undulation(lon, lat)?))
    }

    /// The geoid undulation at a WGS 84 point (0 for ellipsoidal heights).
    pub fn undulation(&self, lon: f64, lat: f64) -> Result<f64, PlaceError> {
        match &self.geoid {
            None => Ok(0.0),
            Some(g) => {
                g.undulation(lon, lat).ok_or_else(|| PlaceError::Geoid { lon, lat, grid: g.name.clone() })
            }
        }
    }

    /// ECEF position of a world point.
    pub fn to_ecef(&self, p: [f64; 3]) -> Result<[f64; 3], PlaceError> {
        let (lon, lat, h) = self.to_geodetic(p)?;
        Ok(ecef::from_geodetic(lon, lat, h))
    }

    /// The world point of a WGS 84 longitude, latitude and ellipsoidal height.
    pub fn from_geodetic(&self, lon: f64, lat: f64, h: f64) -> Result<[f64; 3], PlaceError> {
        let (e, n) = self.grid.crs.from_wgs84(lon, lat)?;
        let (x, y) = self.world_xy(e, n);
        Ok([x, y, h - self.undulation(lon, lat)?])
    }

    /// The world point of an ECEF position.
    pub fn from_ecef(&self, p: [f64; 3]) -> Result<[f64; 3], PlaceError> {
        let (lon, lat, h) = ecef::to_geodetic(p);
        self.from_geodetic(lon, lat, h)
    }
}

#[cfg(test)]
mod tests;
