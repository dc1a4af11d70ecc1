//! The coordinate system a `GeoKeyDirectory` states (GeoTIFF 1.1, OGC 19-008r4), read in full:
//! keys stored in the directory itself, in `GeoDoubleParamsTag` (34736) and in
//! `GeoAsciiParamsTag` (34737). Used for GeoTIFF files and for the GeoKey VLRs of LAS/LAZ.
//!
//! **Horizontal.** `ProjectedCSTypeGeoKey` (3072) and `GeographicTypeGeoKey` (2048) as EPSG codes
//! (the table of `crs-definitions`); user-defined (32767) CRSs from their parts, turned into a
//! PROJ string for proj4rs:
//! - the projection: `ProjectionGeoKey` (3074) as a UTM zone (16001–16060 north, 16101–16160
//!   south), or `ProjCoordTransGeoKey` (3075) with its parameters (3078–3095): Transverse
//!   Mercator (1) and its south-oriented form (27), Mercator (7: `ProjStdParallel1GeoKey` makes it
//!   the 2SP form), Lambert Conformal Conic 2SP (8) and 1SP (9), Lambert Azimuthal Equal Area (10),
//!   Albers (11), Azimuthal Equidistant (12), Equidistant Conic (13), Stereographic (14), Polar
//!   Stereographic (15), Oblique Stereographic (16), Equirectangular (17), Cassini-Soldner (18),
//!   Gnomonic (19), Orthographic (21), Polyconic (22), Sinusoidal (24), Cylindrical Equal Area
//!   (28). A parameter may sit in any of the keys GeoTIFF writers use for it (natural origin,
//!   false origin or centre, as libgeotiff reads them); two of them that disagree are refused.
//!   The longitude of origin (and both standard parallels of a two-parallel conic, the latitude
//!   of true scale of a polar stereographic) must be given; a missing latitude of origin, false
//!   easting or northing is 0 and a missing scale 1, as in libgeotiff.
//! - the geographic CRS: a `GeographicTypeGeoKey` code, or a datum (`GeogGeodeticDatumGeoKey`
//!   2050: an EPSG datum, through the geographic CRS of the table on that datum) or an ellipsoid
//!   (`GeogEllipsoidGeoKey` 2056, or the axes 2057–2059 in `GeogLinearUnitsGeoKey` 2052) with
//!   `GeogTOWGS84GeoKey` (2062; 3 or 7 Helmert parameters, position-vector convention as PROJ's
//!   `+towgs84`), and the prime meridian (2051 / 2061). A user-defined datum without
//!   `GeogTOWGS84GeoKey` is refused: its shift to WGS 84 is unknown.
//! - units: `ProjLinearUnitsGeoKey` (3076, or a size in metres in 3077) for the coordinates,
//!   the false eastings and northings; `GeogAngularUnitsGeoKey` (2054, or a size in radians in
//!   2055) for angles, a geographic model's coordinates included (converted to degrees);
//!   `GeogAzimuthUnitsGeoKey` (2060) for the azimuth. The DMS representations 9107 and 9108 are
//!   read as decimal degrees, as libgeotiff does; packed DDD.MMSS (9110) is refused.
//!
//! **Vertical.** `VerticalCSTypeGeoKey` (4096) 5773 (EGM96 height) or 3855 (EGM2008 height), or
//! a user-defined vertical CRS whose `VerticalDatumGeoKey` (4098) is 5171 (EGM96 geoid) or 1027
//! (EGM2008 geoid). Heights must be in metres: `VerticalUnitsGeoKey` (4099) other than 9001 is
//! refused, because the height scale is not carried from here to the frame (convert the heights
//! to metres first).
//!
//! Anything else — a geocentric model, an unknown code, a projection proj4rs lacks — is refused
//! with a message naming the key and its value; nothing is guessed.

use crate::crs::{Crs, VerticalDatum};

use super::super::FileCrs;

pub(crate) const GEO_DOUBLE_PARAMS: u16 = 34736;
pub(crate) const GEO_ASCII_PARAMS: u16 = 34737;
const GEO_KEY_DIRECTORY: u16 = 34735;
const USER_DEFINED: u16 = 32767;

pub(crate) const MODEL_PROJECTED: u16 = 1;
pub(crate) const MODEL_GEOGRAPHIC: u16 = 2;
const MODEL_GEOCENTRIC: u16 = 3;

// GeoKey ids.
const GT_MODEL_TYPE: u16 = 1024;
const GT_RASTER_TYPE: u16 = 1025;
const GT_CITATION: u16 = 1026;
const GEOGRAPHIC_TYPE: u16 = 2048;
const GEOG_CITATION: u16 = 2049;
const GEOG_DATUM: u16 = 2050;
const GEOG_PRIME_MERIDIAN: u16 = 2051;
const GEOG_LINEAR_UNITS: u16 = 2052;
const GEOG_LINEAR_UNIT_SIZE: u16 = 2053;
const GEOG_ANGULAR_UNITS: u16 = 2054;
const GEOG_ANGULAR_UNIT_SIZE: u16 = 2055;
const GEOG_ELLIPSOID: u16 = 2056;
const GEOG_SEMI_MAJOR: u16 = 2057;
const GEOG_SEMI_MINOR: u16 = 2058;
const GEOG_INV_FLATTENING: u16 = 2059;
const GEOG_AZIMUTH_UNITS: u16 = 2060;
const GEOG_PRIME_MERIDIAN_LONG: u16 = 2061;
const GEOG_TOWGS84: u16 = 2062;
const PROJECTED_TYPE: u16 = 3072;
const PCS_CITATION: u16 = 3073;
const PROJECTION: u16 = 3074;
const PROJ_COORD_TRANS: u16 = 3075;
const PROJ_LINEAR_UNITS: u16 = 3076;
const PROJ_LINEAR_UNIT_SIZE: u16 = 3077;
const PROJ_STD_PARALLEL1: u16 = 3078;
const PROJ_STD_PARALLEL2: u16 = 3079;
const PROJ_NAT_ORIGIN_LONG: u16 = 3080;
const PROJ_NAT_ORIGIN_LAT: u16 = 3081;
const PROJ_FALSE_EASTING: u16 = 3082;
const PROJ_FALSE_NORTHING: u16 = 3083;
const PROJ_FALSE_ORIGIN_LONG: u16 = 3084;
const PROJ_FALSE_ORIGIN_LAT: u16 = 3085;
const PROJ_FALSE_ORIGIN_EASTING: u16 = 3086;
const PROJ_FALSE_ORIGIN_NORTHING: u16 = 3087;
const PROJ_CENTER_LONG: u16 = 3088;
const PROJ_CENTER_LAT: u16 = 3089;
const PROJ_CENTER_EASTING: u16 = 3090;
const PROJ_CENTER_NORTHING: u16 = 3091;
const PROJ_SCALE_AT_NAT_ORIGIN: u16 = 3092;
const PROJ_SCALE_AT_CENTER: u16 = 3093;
const PROJ_AZIMUTH_ANGLE: u16 = 3094;
const PROJ_STRAIGHT_VERT_POLE_LONG: u16 = 3095;
const VERTICAL_TYPE: u16 = 4096;
const VERTICAL_DATUM: u16 = 4098;
const VERTICAL_UNITS: u16 = 4099;

/// The GeoKey's name, for messages.
fn key_name(id: u16) -> String {
    let name = match id {
        GT_MODEL_TYPE => "GTModelTypeGeoKey",
        GT_RASTER_TYPE => "GTRasterTypeGeoKey",
        GT_CITATION => "GTCitationGeoKey",
        GEOGRAPHIC_TYPE => "GeographicTypeGeoKey",
        GEOG_CITATION => "GeogCitationGeoKey",
        GEOG_DATUM => "GeogGeodeticDatumGeoKey",
        GEOG_PRIME_MERIDIAN => "GeogPrimeMeridianGeoKey",
        GEOG_LINEAR_UNITS => "GeogLinearUnitsGeoKey",
        GEOG_LINEAR_UNIT_SIZE => "GeogLinearUnitSizeGeoKey",
        GEOG_ANGULAR_UNITS => "GeogAngularUnitsGeoKey",
        GEOG_ANGULAR_UNIT_SIZE => "GeogAngularUnitSizeGeoKey",
        GEOG_ELLIPSOID => "GeogEllipsoidGeoKey",
        GEOG_SEMI_MAJOR => "GeogSemiMajorAxisGeoKey",
        GEOG_SEMI_MINOR => "GeogSemiMinorAxisGeoKey",
        GEOG_INV_FLATTENING => "GeogInvFlatteningGeoKey",
        GEOG_AZIMUTH_UNITS => "GeogAzimuthUnitsGeoKey",
        GEOG_PRIME_MERIDIAN_LONG => "GeogPrimeMeridianLongGeoKey",
        GEOG_TOWGS84 => "GeogTOWGS84GeoKey",
        PROJECTED_TYPE => "ProjectedCSTypeGeoKey",
        PCS_CITATION => "PCSCitationGeoKey",
        PROJECTION => "ProjectionGeoKey",
        PROJ_COORD_TRANS => "ProjCoordTransGeoKey",
        PROJ_LINEAR_UNITS => "ProjLinearUnitsGeoKey",
        PROJ_LINEAR_UNIT_SIZE => "ProjLinearUnitSizeGeoKey",
        PROJ_STD_PARALLEL1 => "ProjStdParallel1GeoKey",
        PROJ_STD_PARALLEL2 => "ProjStdParallel2GeoKey",
        PROJ_NAT_ORIGIN_LONG => "ProjNatOriginLongGeoKey",
        PROJ_NAT_ORIGIN_LAT => "ProjNatOriginLatGeoKey",
        PROJ_FALSE_EASTING => "ProjFalseEastingGeoKey",
        PROJ_FALSE_NORTHING => "ProjFalseNorthingGeoKey",
        PROJ_FALSE_ORIGIN_LONG => "ProjFalseOriginLongGeoKey",
        PROJ_FALSE_ORIGIN_LAT => "ProjFalseOriginLatGeoKey",
        PROJ_FALSE_ORIGIN_EASTING => "ProjFalseOriginEastingGeoKey",
        PROJ_FALSE_ORIGIN_NORTHING => "ProjFalseOriginNorthingGeoKey",
        PROJ_CENTER_LONG => "ProjCenterLongGeoKey",
        PROJ_CENTER_LAT => "ProjCenterLatGeoKey",
        PROJ_CENTER_EASTING => "ProjCenterEastingGeoKey",
        PROJ_CENTER_NORTHING => "ProjCenterNorthingGeoKey",
        PROJ_SCALE_AT_NAT_ORIGIN => "ProjScaleAtNatOriginGeoKey",
        PROJ_SCALE_AT_CENTER => "ProjScaleAtCenterGeoKey",
        PROJ_AZIMUTH_ANGLE => "ProjAzimuthAngleGeoKey",
        PROJ_STRAIGHT_VERT_POLE_LONG => "ProjStraightVertPoleLongGeoKey",
        VERTICAL_TYPE => "VerticalCSTypeGeoKey",
        VERTICAL_DATUM => "VerticalDatumGeoKey",
        VERTICAL_UNITS => "VerticalUnitsGeoKey",
        _ => return format!("GeoKey {id}"),
    };
    name.to_owned()
}

/// A `GeoKeyDirectory` with the value arrays its keys may point into.
#[derive(Debug, Clone, Copy, Default)]
pub(crate) struct GeoKeys<'a> {
    /// `GeoKeyDirectoryTag`: a header of 4 shorts (version 1, revision, minor revision, key
    /// count), then 4 shorts per key (id, location, count, value or offset).
    pub dir: &'a [u16],
    /// `GeoDoubleParamsTag`.
    pub doubles: &'a [f64],
    /// `GeoAsciiParamsTag` (strings end with `|`).
    pub ascii: &'a str,
}

/// What a directory says about the raster and its coordinate system.
#[derive(Debug, Clone, PartialEq)]
pub(crate) struct KeysCrs {
    /// `GTModelTypeGeoKey`: 1 projected, 2 geographic (3, geocentric, is refused).
    pub model: Option<u16>,
    /// `GTRasterTypeGeoKey`: 1 PixelIsArea, 2 PixelIsPoint.
    pub raster: Option<u16>,
    pub crs: FileCrs,
    /// Degrees per unit of a geographic model's coordinates (`GeogAngularUnitsGeoKey`; 1 for
    /// degrees).
    pub degrees_per_unit: f64,
}

impl Default for KeysCrs {
    fn default() -> Self {
        Self { model: None, raster: None, crs: FileCrs::default(), degrees_per_unit: 1.0 }
    }
}

type Res<T> = Result<T, String>;

fn refuse<T>(id: u16, value: impl std::fmt::Display, why: impl std::fmt::Display) -> Res<T> {
    Err(format!("{} {value}: {why}", key_name(id)))
}

impl GeoKeys<'_> {
    /// The key entries (id, location, count, value or offset); a directory shorter than its
    /// count says yields the entries it holds.
    fn entries(&self) -> impl Iterator<Item = &[u16]> {
        let count = self.dir.get(3).map_or(0, |&n| usize::from(n));
        self.dir.get(4..).unwrap_or(&[]).chunks_exact(4).take(count)
    }

    fn entry(&self, id: u16) -> Option<&[u16]> {
        self.entries().find(|k| k[0] == id)
    }

    fn has(&self, id: u16) -> bool {
        self.entry(id).is_some()
    }

    /// A SHORT key: stored in the entry itself, or (one value) in the directory array.
    fn short(&self, id: u16) -> Res<Option<u16>> {
        let Some(k) = self.entry(id) else { return Ok(None) };
        match k[1] {
            0 => Ok(Some(k[3])),
            GEO_KEY_DIRECTORY if k[2] == 1 => match self.dir.get(usize::from(k[3])) {
                Some(&v) => Ok(Some(v)),
                None => Err(format!("{}: its value lies past the end of the directory", key_name(id))),
            },
            loc => Err(format!("{}: expected a SHORT value, found one stored in tag {loc}", key_name(id))),
        }
    }

    /// A DOUBLE key's values, all finite.
    fn doubles(&self, id: u16) -> Res<Option<&[f64]>> {
        let Some(k) = self.entry(id) else { return Ok(None) };
        if k[1] != GEO_DOUBLE_PARAMS {
            return Err(format!(
                "{}: expected DOUBLE values (GeoDoubleParamsTag), found them stored in tag {}",
                key_name(id),
                k[1]
            ));
        }
        let (at, n) = (usize::from(k[3]), usize::from(k[2]));
        let Some(v) = self.doubles.get(at..at + n) else {
            return Err(format!(
                "{}: values {at}..{} lie past the {} values of GeoDoubleParamsTag",
                key_name(id),
                at + n,
                self.doubles.len()
            ));
        };
        if let Some(bad) = v.iter().find(|x| !x.is_finite()) {
            return refuse(id, bad, "not a finite number");
        }
        Ok(Some(v))
    }

    fn double(&self, id: u16) -> Res<Option<f64>> {
        match self.doubles(id)? {
            None => Ok(None),
            Some(&[v]) => Ok(Some(v)),
            Some(v) => Err(format!("{}: expected one value, found {}", key_name(id), v.len())),
        }
    }

    /// An ASCII key's text, without the `|` that ends it.
    fn ascii(&self, id: u16) -> Option<&str> {
        let k = self.entry(id)?;
        if k[1] != GEO_ASCII_PARAMS {
            return None;
        }
        let (at, n) = (usize::from(k[3]), usize::from(k[2]));
        let s = self.ascii.get(at..(at + n).min(self.ascii.len()))?;
        let s = s.trim_end_matches(['|', '\0']).trim();
        (!s.is_empty()).then_some(s)
    }

    /// The first of `ids` present, times `factor`; keys of `ids` that disagree are refused.
    fn param(&self, ids: &[u16], factor: f64) -> Res<Option<f64>> {
        let mut found: Option<(u16, f64)> = None;
        for &id in ids {
            if let Some(v) = self.double(id)? {
                match found {
                    None => found = Some((id, v)),
                    Some((first, w)) if (v - w).abs() > 1e-12 * w.abs().max(1.0) => {
                        return Err(format!(
                            "{} {w} and {} {v} disagree: which one the projection uses is not stated",
                            key_name(first),
                            key_name(id)
                        ));
                    }
                    Some(_) => {}
                }
            }
        }
        Ok(found.map(|(_, v)| v * factor))
    }

    /// A parameter that must be present.
    fn required(&self, ids: &[u16], factor: f64, method: &str) -> Res<f64> {
        self.param(ids, factor)?.ok_or_else(|| {
            let names: Vec<String> = ids.iter().map(|&i| key_name(i)).collect();
            format!("{method} needs {} and the file has none of them", names.join(" or "))
        })
    }
}

/// Reads the coordinate system of a directory. Errors name the key and its value.
pub(crate) fn read(keys: &GeoKeys) -> Res<KeysCrs> {
    if keys.dir.is_empty() {
        return Ok(KeysCrs::default());
    }
    if keys.dir[0] != 1 {
        return Err(format!("GeoKeyDirectoryTag version {}: expected 1", keys.dir[0]));
    }
    let model = keys.short(GT_MODEL_TYPE)?;
    let raster = keys.short(GT_RASTER_TYPE)?;
    match model {
        None | Some(MODEL_PROJECTED | MODEL_GEOGRAPHIC) => {}
        Some(MODEL_GEOCENTRIC) => {
            return refuse(
                GT_MODEL_TYPE,
                MODEL_GEOCENTRIC,
                "a geocentric model (X, Y, Z in ECEF) is not a heightfield grid",
            );
        }
        Some(32767) => {
            return refuse(
                GT_MODEL_TYPE,
                32767,
                "user-defined: a coordinate system this reader cannot take from GeoKeys; reproject the file to an \
                 EPSG CRS first (gdalwarp -t_srs EPSG:…)",
            );
        }
        Some(other) => return refuse(GT_MODEL_TYPE, other, "expected 1 (projected) or 2 (geographic)"),
    }
    match raster {
        None | Some(1 | 2) => {}
        Some(other) => return refuse(GT_RASTER_TYPE, other, "expected 1 (PixelIsArea) or 2 (PixelIsPoint)"),
    }
    let angular = angular_unit(keys, GEOG_ANGULAR_UNITS, GEOG_ANGULAR_UNIT_SIZE)?;
    let pcs = keys.short(PROJECTED_TYPE)?;
    let states_projection = keys.has(PROJECTION) || keys.has(PROJ_COORD_TRANS);
    let horizontal = match model {
        Some(MODEL_PROJECTED) | None if pcs.is_some() || states_projection => {
            Some(projected(keys, pcs, angular.0)?)
        }
        Some(MODEL_GEOGRAPHIC) => geodetic(keys, angular.0)?.map(Geodetic::geographic).transpose()?,
        _ => None,
    };
    if let (Some(c), Some(m)) = (&horizontal, model)
        && c.is_geographic() != (m == MODEL_GEOGRAPHIC)
    {
        return refuse(
            GT_MODEL_TYPE,
            m,
            format!(
                "does not fit {} ({})",
                c.definition(),
                if c.is_geographic() { "geographic" } else { "projected" }
            ),
        );
    }
    Ok(KeysCrs {
        model,
        raster,
        crs: FileCrs { horizontal, vertical: vertical(keys)? },
        degrees_per_unit: if model == Some(MODEL_GEOGRAPHIC) { angular.0 } else { 1.0 },
    })
}

/// (degrees per unit, name) of an angular-units key; degrees when absent.
fn angular_unit(keys: &GeoKeys, id: u16, size_id: u16) -> Res<(f64, &'static str)> {
    const DEG: f64 = 1.0;
    let code = keys.short(id)?;
    Ok(match code {
        // 9107 and 9108 are DMS representations of the EPSG table; GeoTIFF stores the values as
        // decimal degrees (as libgeotiff reads them).
        None | Some(9102 | 9122 | 9107 | 9108) => (DEG, "degree"),
        Some(9101) => (180.0 / std::f64::consts::PI, "radian"),
        Some(9103) => (1.0 / 60.0, "arc-minute"),
        Some(9104) => (1.0 / 3600.0, "arc-second"),
        Some(9105 | 9106) => (0.9, "grad"),
        Some(9109) => (1e-6 * 180.0 / std::f64::consts::PI, "microradian"),
        Some(9112) => (0.009, "centesimal minute"),
        Some(9113) => (0.000_09, "centesimal second"),
        Some(USER_DEFINED) => match keys.double(size_id)? {
            Some(r) if r > 0.0 => (r.to_degrees(), "user-defined angular unit"),
            Some(r) => return refuse(size_id, r, "not a positive size in radians"),
            None => {
                return refuse(
                    id,
                    USER_DEFINED,
                    format!("a user-defined unit without {}", key_name(size_id)),
                );
            }
        },
        Some(9110) => {
            return refuse(id, 9110, "packed sexagesimal DDD.MMSSsss values are not supported");
        }
        Some(other) => return refuse(id, other, "not an angular unit terrastream knows"),
    })
}

/// Linear units of the EPSG dataset: (code, name, metres per unit). From PROJ 9.5's EPSG
/// database (`pyproj.database.get_units_map(auth_name="EPSG", category="linear")`); the US
/// survey units are written as their defining ratios.
const LINEAR_UNITS: [(u16, &str, f64); 47] = [
    (1025, "millimetre", 0.001),
    (1033, "centimetre", 0.01),
    (9001, "metre", 1.0),
    (9002, "foot", 0.3048),
    (9003, "US survey foot", 1200.0 / 3937.0),
    (9005, "Clarke's foot", 0.304_797_265_4),
    (9014, "fathom", 1.8288),
    (9030, "nautical mile", 1852.0),
    (9031, "German legal metre", 1.000_013_596_5),
    (9033, "US survey chain", 66.0 * 1200.0 / 3937.0),
    (9034, "US survey link", 0.66 * 1200.0 / 3937.0),
    (9035, "US survey mile", 5280.0 * 1200.0 / 3937.0),
    (9036, "kilometre", 1000.0),
    (9037, "Clarke's yard", 0.914_391_796_2),
    (9038, "Clarke's chain", 20.116_619_516_4),
    (9039, "Clarke's link", 0.201_166_195_164),
    (9040, "British yard (Sears 1922)", 0.914_398_414_616_029),
    (9041, "British foot (Sears 1922)", 0.304_799_471_538_676),
    (9042, "British chain (Sears 1922)", 20.116_765_121_552_6),
    (9043, "British link (Sears 1922)", 0.201_167_651_215_526),
    (9050, "British yard (Benoit 1895 A)", 0.914_399_2),
    (9051, "British foot (Benoit 1895 A)", 0.304_799_733_333_333),
    (9052, "British chain (Benoit 1895 A)", 20.116_782_4),
    (9053, "British link (Benoit 1895 A)", 0.201_167_824),
    (9060, "British yard (Benoit 1895 B)", 0.914_399_204_289_812),
    (9061, "British foot (Benoit 1895 B)", 0.304_799_734_763_271),
    (9062, "British chain (Benoit 1895 B)", 20.116_782_494_375_9),
    (9063, "British link (Benoit 1895 B)", 0.201_167_824_943_759),
    (9070, "British foot (1865)", 0.304_800_833_333_333),
    (9080, "Indian foot", 0.304_799_510_248_147),
    (9081, "Indian foot (1937)", 0.304_798_41),
    (9082, "Indian foot (1962)", 0.304_799_6),
    (9083, "Indian foot (1975)", 0.304_799_5),
    (9084, "Indian yard", 0.914_398_530_744_441),
    (9085, "Indian yard (1937)", 0.914_395_23),
    (9086, "Indian yard (1962)", 0.914_398_8),
    (9087, "Indian yard (1975)", 0.914_398_5),
    (9093, "Statute mile", 1609.344),
    (9094, "Gold Coast foot", 0.304_799_710_181_509),
    (9095, "British foot (1936)", 0.304_800_749_1),
    (9096, "yard", 0.9144),
    (9097, "chain", 20.1168),
    (9098, "link", 0.201_168),
    (9099, "British yard (Sears 1922 truncated)", 0.914_398),
    (9300, "British foot (Sears 1922 truncated)", 0.304_799_333_333_333),
    (9301, "British chain (Sears 1922 truncated)", 20.116_756),
    (9302, "British link (Sears 1922 truncated)", 0.201_167_56),
];

/// The EPSG linear unit of `code`: (metres per unit, name).
pub(crate) fn linear_unit_of(code: u16) -> Option<(f64, &'static str)> {
    LINEAR_UNITS.iter().find(|u| u.0 == code).map(|u| (u.2, u.1))
}

/// (metres per unit, name) of a linear-units key; metres when absent.
fn linear_unit(keys: &GeoKeys, id: u16, size_id: u16) -> Res<(f64, String)> {
    match keys.short(id)? {
        None => Ok((1.0, "metre".into())),
        Some(USER_DEFINED) => match keys.double(size_id)? {
            Some(m) if m > 0.0 => Ok((m, format!("unit of {m} m"))),
            Some(m) => refuse(size_id, m, "not a positive size in metres"),
            None => refuse(id, USER_DEFINED, format!("a user-defined unit without {}", key_name(size_id))),
        },
        Some(code) => match linear_unit_of(code) {
            Some((m, name)) => Ok((m, name.to_owned())),
            None => refuse(id, code, "not a linear unit of the EPSG dataset"),
        },
    }
}

/// How an ellipsoid is defined: the inverse flattening, or (for ellipsoids the EPSG dataset
/// defines by both axes) the semi-minor axis.
#[derive(Clone, Copy)]
enum Second {
    InvFlattening(f64),
    SemiMinor(f64),
}

/// Ellipsoids of the EPSG dataset: (code, name, semi-major axis in metres, second parameter).
/// From PROJ 9.5's EPSG database (`pyproj.crs.Ellipsoid.from_epsg`).
const ELLIPSOIDS: [(u16, &str, f64, Second); 53] = {
    use Second::{InvFlattening as F, SemiMinor as B};
    [
        (1024, "CGCS2000", 6_378_137.0, F(298.257_222_101)),
        (1025, "GSK-2011", 6_378_136.5, F(298.256_415_1)),
        (1026, "Zach 1812", 6_376_045.0, F(310.0)),
        (7001, "Airy 1830", 6_377_563.396, F(299.324_964_6)),
        (7002, "Airy Modified 1849", 6_377_340.189, F(299.324_964_6)),
        (7003, "Australian National Spheroid", 6_378_160.0, F(298.25)),
        (7004, "Bessel 1841", 6_377_397.155, F(299.152_812_8)),
        (7005, "Bessel Modified", 6_377_492.018, F(299.152_812_8)),
        (7007, "Clarke 1858", 6_378_293.645_208_759, B(6_356_617.987_679_838)),
        (7008, "Clarke 1866", 6_378_206.4, B(6_356_583.8)),
        (7010, "Clarke 1880 (Benoit)", 6_378_300.789, B(6_356_566.435)),
        (7011, "Clarke 1880 (IGN)", 6_378_249.2, B(6_356_515.0)),
        (7012, "Clarke 1880 (RGS)", 6_378_249.145, F(293.465)),
        (7013, "Clarke 1880 (Arc)", 6_378_249.145, F(293.466_307_7)),
        (7014, "Clarke 1880 (SGA 1922)", 6_378_249.2, F(293.465_98)),
        (7015, "Everest 1830 (1937 Adjustment)", 6_377_276.345, F(300.8017)),
        (7016, "Everest 1830 (1967 Definition)", 6_377_298.556, F(300.8017)),
        (7018, "Everest 1830 Modified", 6_377_304.063, F(300.8017)),
        (7019, "GRS 1980", 6_378_137.0, F(298.257_222_101)),
        (7020, "Helmert 1906", 6_378_200.0, F(298.3)),
        (7021, "Indonesian National Spheroid", 6_378_160.0, F(298.247)),
        (7022, "International 1924", 6_378_388.0, F(297.0)),
        (7024, "Krassowsky 1940", 6_378_245.0, F(298.3)),
        (7025, "NWL 9D", 6_378_145.0, F(298.25)),
        (7027, "Plessis 1817", 6_376_523.0, F(308.64)),
        (7028, "Struve 1860", 6_378_298.3, F(294.73)),
        (7029, "War Office", 6_378_300.0, F(296.0)),
        (7030, "WGS 84", 6_378_137.0, F(298.257_223_563)),
        (7031, "GEM 10C", 6_378_137.0, F(298.257_223_563)),
        (7032, "OSU86F", 6_378_136.2, F(298.257_223_563)),
        (7033, "OSU91A", 6_378_136.3, F(298.257_223_563)),
        (7034, "Clarke 1880", 6_378_249.144_808_011, F(293.466_307_655_636_46)),
        (7036, "GRS 1967", 6_378_160.0, F(298.247_167_427)),
        (7041, "Average Terrestrial System 1977", 6_378_135.0, F(298.257)),
        (7042, "Everest (1830 Definition)", 6_377_299.365_595_38, B(6_356_098.359_005_156)),
        (7043, "WGS 72", 6_378_135.0, F(298.26)),
        (7044, "Everest 1830 (1962 Definition)", 6_377_301.243, F(300.801_725_5)),
        (7045, "Everest 1830 (1975 Definition)", 6_377_299.151, F(300.801_725_5)),
        (7046, "Bessel Namibia (GLM)", 6_377_483.865_280_419, F(299.152_812_8)),
        (7048, "GRS 1980 Authalic Sphere", 6_371_007.0, B(6_371_007.0)),
        (7049, "IAG 1975", 6_378_140.0, F(298.257)),
        (7050, "GRS 1967 Modified", 6_378_160.0, F(298.25)),
        (7051, "Danish 1876", 6_377_019.27, F(300.0)),
        (7052, "Clarke 1866 Authalic Sphere", 6_370_997.0, B(6_370_997.0)),
        (7053, "Hough 1960", 6_378_270.0, F(297.0)),
        (7054, "PZ-90", 6_378_136.0, F(298.257_839_303)),
        (7055, "Clarke 1880 (international foot)", 6_378_306.369_6, B(6_356_571.996)),
        (7056, "Everest 1830 (RSO 1969)", 6_377_295.664, F(300.8017)),
        (7057, "International 1924 Authalic Sphere", 6_371_228.0, B(6_371_228.0)),
        (7058, "Hughes 1980", 6_378_273.0, B(6_356_889.449)),
        // Deprecated codes still in the database (GeoTIFF 1.0 lists the first two).
        (7035, "Sphere", 6_371_000.0, B(6_371_000.0)),
        (7047, "GRS 1980 Authalic Sphere", 6_370_997.0, B(6_370_997.0)),
        (7059, "Popular Visualisation Sphere", 6_378_137.0, B(6_378_137.0)),
    ]
};

/// Prime meridians of the EPSG dataset: (code, name, degrees east of Greenwich). From PROJ 9.5's
/// EPSG database (`pyproj.crs.PrimeMeridian.from_epsg`; Paris's 2.5969213 grad in degrees).
const PRIME_MERIDIANS: [(u16, &str, f64); 15] = [
    (1026, "Copenhagen", 12.57775),
    (8901, "Greenwich", 0.0),
    (8902, "Lisbon", -9.131_906_111_111_112),
    (8903, "Paris", 2.596_921_3 * 0.9),
    (8904, "Bogota", -74.080_916_666_666_67),
    (8905, "Madrid", -3.687_375),
    (8906, "Rome", 12.452_333_333_333_332),
    (8907, "Bern", 7.439_583_333_333_333),
    (8908, "Jakarta", 106.807_719_444_444_44),
    (8909, "Ferro", -17.666_666_666_666_668),
    (8910, "Brussels", 4.367_975),
    (8911, "Stockholm", 18.058_277_777_777_78),
    (8912, "Athens", 23.716_337_5),
    (8913, "Oslo", 10.722_916_666_666_666),
    (8914, "Paris RGS", 2.337_208_333_333_333),
];

/// A geodetic datum as PROJ parameters (`+datum`/`+ellps`/`+a`…, `+towgs84`, `+pm`) and a name.
struct Geodetic {
    params: Vec<String>,
    name: String,
    /// The EPSG code of the geographic CRS, when the keys gave one.
    epsg: Option<u16>,
}

impl Geodetic {
    /// The geographic CRS on this datum (longitude, latitude in degrees).
    fn geographic(self) -> Res<Crs> {
        if let Some(code) = self.epsg {
            return Crs::from_epsg(u32::from(code))
                .map_err(|e| format!("{} {code}: {e}", key_name(GEOGRAPHIC_TYPE)));
        }
        let proj4 = format!("+proj=longlat {} +no_defs", self.params.join(" "));
        Crs::from_proj4_named(&proj4, &format!("GeoTIFF keys: geographic, {}", self.name))
            .map_err(|e| format!("the geographic CRS of the keys ({}): {e}", self.name))
    }
}

/// The datum parameters of a PROJ string of the table (everything but the projection and units).
fn datum_params(proj4: &str) -> Vec<String> {
    const KEEP: [&str; 10] = ["datum", "ellps", "a", "b", "rf", "f", "R", "towgs84", "nadgrids", "pm"];
    proj4
        .split_whitespace()
        .filter(|t| {
            let key = t.trim_start_matches('+').split('=').next().unwrap_or("");
            t.starts_with('+') && KEEP.contains(&key)
        })
        .map(str::to_owned)
        .collect()
}

/// The geographic CRS of the table whose datum is EPSG `datum` and whose prime meridian is
/// Greenwich: by the usual numbering (datum 6xxx, CRS 4xxx) when that fits, else the first in
/// the table.
fn geographic_of_datum(datum: u16) -> Option<crs_definitions::Def> {
    let marker = format!("AUTHORITY[\"EPSG\",\"{datum}\"]],PRIMEM[\"Greenwich\",0,");
    let fits = |d: &crs_definitions::Def| d.wkt.starts_with("GEOGCS[") && d.wkt.contains(&marker);
    let usual = datum.checked_sub(2000).and_then(crs_definitions::from_code).filter(fits);
    usual.or_else(|| (0..=u16::MAX).filter_map(crs_definitions::from_code).find(fits))
}

/// The geodetic datum the keys state; `None` when they state none.
fn geodetic(keys: &GeoKeys, deg_per_unit: f64) -> Res<Option<Geodetic>> {
    let towgs84 = match keys.doubles(GEOG_TOWGS84)? {
        None => None,
        Some(v) if v.len() == 3 || v.len() == 7 => {
            Some(format!("+towgs84={}", v.iter().map(f64::to_string).collect::<Vec<_>>().join(",")))
        }
        Some(v) => return refuse(GEOG_TOWGS84, format!("{v:?}"), "expected 3 or 7 values"),
    };
    let with_towgs84 = |mut params: Vec<String>| {
        if let Some(t) = &towgs84 {
            params.retain(|p| !p.starts_with("+towgs84=") && !p.starts_with("+nadgrids="));
            params.push(t.clone());
        }
        params
    };
    match keys.short(GEOGRAPHIC_TYPE)? {
        Some(USER_DEFINED) | None => {}
        Some(code) => {
            let Some(def) = crs_definitions::from_code(code) else {
                return refuse(
                    GEOGRAPHIC_TYPE,
                    code,
                    format!("{}", crate::crs::CrsError::UnknownEpsg(u32::from(code))),
                );
            };
            if !def.wkt.starts_with("GEOGCS[") {
                return refuse(GEOGRAPHIC_TYPE, code, format!("EPSG:{code} is not a geographic CRS"));
            }
            // A code with its own shift replaced: the keys' TOWGS84 wins, as in GDAL.
            return Ok(Some(match towgs84 {
                None => Geodetic {
                    params: datum_params(def.proj4),
                    name: format!("EPSG:{code}"),
                    epsg: Some(code),
                },
                Some(_) => Geodetic {
                    params: with_towgs84(datum_params(def.proj4)),
                    name: format!("EPSG:{code} with GeogTOWGS84GeoKey"),
                    epsg: None,
                },
            }));
        }
    }
    let datum = keys.short(GEOG_DATUM)?;
    let any_part = datum.is_some() || keys.has(GEOG_ELLIPSOID) || keys.has(GEOG_SEMI_MAJOR);
    if !any_part {
        return match keys.short(GEOGRAPHIC_TYPE)? {
            Some(USER_DEFINED) => refuse(
                GEOGRAPHIC_TYPE,
                USER_DEFINED,
                "a user-defined geographic CRS without GeogGeodeticDatumGeoKey or GeogEllipsoidGeoKey",
            ),
            _ => Ok(None),
        };
    }
    let (mut params, mut name) = match datum {
        Some(code) if code != USER_DEFINED => {
            let Some(def) = geographic_of_datum(code) else {
                return refuse(GEOG_DATUM, code, "not a datum of a geographic CRS in the EPSG table");
            };
            let name = match &towgs84 {
                None => format!("datum EPSG:{code}"),
                Some(_) => format!("datum EPSG:{code} with GeogTOWGS84GeoKey"),
            };
            (
                with_towgs84(datum_params(def.proj4))
                    .into_iter()
                    .filter(|p| !p.starts_with("+pm="))
                    .collect(),
                name,
            )
        }
        _ => {
            let (ellps, ellps_name) = ellipsoid(keys)?;
            let Some(t) = &towgs84 else {
                return refuse(
                    GEOG_DATUM,
                    datum.map_or_else(|| "(absent)".to_owned(), |d| d.to_string()),
                    format!(
                        "a user-defined datum on ellipsoid {ellps_name} without GeogTOWGS84GeoKey: its shift to \
                         WGS 84 is not stated"
                    ),
                );
            };
            let mut p = ellps;
            p.push(t.clone());
            (p, format!("user-defined datum on ellipsoid {ellps_name} with GeogTOWGS84GeoKey"))
        }
    };
    if let Some((pm, pm_name)) = prime_meridian(keys, deg_per_unit)? {
        params.push(format!("+pm={pm}"));
        name = format!("{name}, prime meridian {pm_name}");
    }
    Ok(Some(Geodetic { params, name, epsg: None }))
}

/// The ellipsoid of a user-defined datum: PROJ parameters and a name.
fn ellipsoid(keys: &GeoKeys) -> Res<(Vec<String>, String)> {
    let code = keys.short(GEOG_ELLIPSOID)?;
    if let Some(c) = code.filter(|&c| c != USER_DEFINED) {
        let Some(&(_, name, a, second)) = ELLIPSOIDS.iter().find(|e| e.0 == c) else {
            return refuse(GEOG_ELLIPSOID, c, "not an ellipsoid of the EPSG dataset");
        };
        let second = match second {
            Second::InvFlattening(rf) => format!("+rf={rf}"),
            Second::SemiMinor(b) => format!("+b={b}"),
        };
        return Ok((vec![format!("+a={a}"), second], format!("{name} (EPSG:{c})")));
    }
    let (unit, _) = linear_unit(keys, GEOG_LINEAR_UNITS, GEOG_LINEAR_UNIT_SIZE)?;
    let Some(a) = keys.double(GEOG_SEMI_MAJOR)? else {
        return refuse(
            GEOG_ELLIPSOID,
            code.map_or_else(|| "(absent)".to_owned(), |c| c.to_string()),
            "a user-defined ellipsoid without GeogSemiMajorAxisGeoKey",
        );
    };
    if a <= 0.0 {
        return refuse(GEOG_SEMI_MAJOR, a, "not a positive length");
    }
    let a = a * unit;
    let second = match (keys.double(GEOG_INV_FLATTENING)?, keys.double(GEOG_SEMI_MINOR)?) {
        (Some(0.0), _) => format!("+b={a}"),
        (Some(rf), _) if rf > 1.0 => format!("+rf={rf}"),
        (Some(rf), _) => {
            return refuse(GEOG_INV_FLATTENING, rf, "not an inverse flattening (0 for a sphere, else > 1)");
        }
        (None, Some(b)) if b > 0.0 && b * unit <= a => format!("+b={}", b * unit),
        (None, Some(b)) => {
            return refuse(GEOG_SEMI_MINOR, b, "not a positive length up to the semi-major axis");
        }
        (None, None) => {
            return refuse(
                GEOG_SEMI_MAJOR,
                a,
                "a user-defined ellipsoid needs GeogInvFlatteningGeoKey or GeogSemiMinorAxisGeoKey too",
            );
        }
    };
    let name = format!("a = {a} m, {}", second[1..].replace('=', " = "));
    Ok((vec![format!("+a={a}"), second], name))
}

/// The prime meridian in degrees east of Greenwich and its name; `None` for Greenwich or when
/// not stated.
fn prime_meridian(keys: &GeoKeys, deg_per_unit: f64) -> Res<Option<(f64, String)>> {
    let by_longitude = || -> Res<Option<(f64, String)>> {
        Ok(keys
            .double(GEOG_PRIME_MERIDIAN_LONG)?
            .filter(|&l| l != 0.0)
            .map(|l| (l * deg_per_unit, format!("{}°", l * deg_per_unit))))
    };
    match keys.short(GEOG_PRIME_MERIDIAN)? {
        // GDAL writes the longitude alone.
        None => by_longitude(),
        Some(8901) => Ok(None),
        Some(USER_DEFINED) if keys.has(GEOG_PRIME_MERIDIAN_LONG) => by_longitude(),
        Some(USER_DEFINED) => {
            refuse(GEOG_PRIME_MERIDIAN, USER_DEFINED, "user-defined without GeogPrimeMeridianLongGeoKey")
        }
        Some(code) => match PRIME_MERIDIANS.iter().find(|p| p.0 == code) {
            Some(&(_, name, deg)) => Ok(Some((deg, name.to_owned()))),
            None => refuse(GEOG_PRIME_MERIDIAN, code, "not a prime meridian of the EPSG dataset"),
        },
    }
}

/// The projected CRS the keys state: an EPSG code, or user-defined.
fn projected(keys: &GeoKeys, pcs: Option<u16>, deg_per_unit: f64) -> Res<Crs> {
    if let Some(code) = pcs.filter(|&c| c != USER_DEFINED) {
        let crs = Crs::from_epsg(u32::from(code))
            .map_err(|e| format!("{} {code}: {e}", key_name(PROJECTED_TYPE)))?;
        // The code's unit rules; a units key that says otherwise is a contradiction, not a choice.
        if keys.has(PROJ_LINEAR_UNITS) {
            let (m, name) = linear_unit(keys, PROJ_LINEAR_UNITS, PROJ_LINEAR_UNIT_SIZE)?;
            if !crs.is_geographic() && (m / crs.unit_metres() - 1.0).abs() > 1e-9 {
                return refuse(
                    PROJ_LINEAR_UNITS,
                    keys.short(PROJ_LINEAR_UNITS)?.unwrap_or(0),
                    format!("{name} ({m} m) contradicts EPSG:{code}, whose unit is {} m", crs.unit_metres()),
                );
            }
        }
        return Ok(crs);
    }
    let Some(geodetic) = geodetic(keys, deg_per_unit)? else {
        return refuse(
            PROJECTED_TYPE,
            pcs.map_or_else(|| "(absent)".to_owned(), |c| c.to_string()),
            "a user-defined projection whose geographic CRS is not stated (no GeographicTypeGeoKey, \
             GeogGeodeticDatumGeoKey or GeogEllipsoidGeoKey)",
        );
    };
    let (unit, unit_name) = linear_unit(keys, PROJ_LINEAR_UNITS, PROJ_LINEAR_UNIT_SIZE)?;
    let (method, name) = projection(keys, deg_per_unit, unit)?;
    let units =
        if (unit - 1.0).abs() < f64::EPSILON { "+units=m".to_owned() } else { format!("+to_meter={unit}") };
    let proj4 = format!("{method} {} {units} +no_defs", geodetic.params.join(" "));
    let mut definition = format!("GeoTIFF keys: {name}, {}, {unit_name}", geodetic.name);
    // GDAL writes "unknown" (or notes such as "LUnits = …") for CRSs without a name.
    let named = |c: &&str| !c.eq_ignore_ascii_case("unknown") && !c.contains(" = ");
    if let Some(c) = keys.ascii(PCS_CITATION).filter(named).or_else(|| keys.ascii(GT_CITATION).filter(named))
    {
        definition = format!("{definition} (\"{c}\")");
    }
    Crs::from_proj4_named(&proj4, &definition)
        .map_err(|e| format!("the projection of the keys ({definition}): {e}"))
}

/// The PROJ projection (`+proj=… +lat_0=…`, false easting and northing in metres) and its name.
fn projection(keys: &GeoKeys, deg: f64, unit: f64) -> Res<(String, String)> {
    // The keys a parameter may sit in (libgeotiff reads each from any of them).
    const LAT: [u16; 3] = [PROJ_NAT_ORIGIN_LAT, PROJ_FALSE_ORIGIN_LAT, PROJ_CENTER_LAT];
    const LON: [u16; 3] = [PROJ_NAT_ORIGIN_LONG, PROJ_FALSE_ORIGIN_LONG, PROJ_CENTER_LONG];
    const POLE_LON: [u16; 4] =
        [PROJ_STRAIGHT_VERT_POLE_LONG, PROJ_NAT_ORIGIN_LONG, PROJ_FALSE_ORIGIN_LONG, PROJ_CENTER_LONG];
    const EAST: [u16; 3] = [PROJ_FALSE_EASTING, PROJ_FALSE_ORIGIN_EASTING, PROJ_CENTER_EASTING];
    const NORTH: [u16; 3] = [PROJ_FALSE_NORTHING, PROJ_FALSE_ORIGIN_NORTHING, PROJ_CENTER_NORTHING];
    const SCALE: [u16; 2] = [PROJ_SCALE_AT_NAT_ORIGIN, PROJ_SCALE_AT_CENTER];
    if let Some(code) = keys.short(PROJECTION)?.filter(|&c| c != USER_DEFINED) {
        return match code {
            16001..=16060 => {
                Ok((format!("+proj=utm +zone={}", code - 16000), format!("UTM zone {}N", code - 16000)))
            }
            16101..=16160 => Ok((
                format!("+proj=utm +zone={} +south", code - 16100),
                format!("UTM zone {}S", code - 16100),
            )),
            _ => refuse(
                PROJECTION,
                code,
                "only UTM zones are known by code (16001–16060 north, 16101–16160 south); give \
                 ProjCoordTransGeoKey and its parameters, or the CRS's EPSG code in ProjectedCSTypeGeoKey",
            ),
        };
    }
    let Some(ct) = keys.short(PROJ_COORD_TRANS)? else {
        return refuse(
            PROJECTED_TYPE,
            USER_DEFINED,
            "a user-defined projection without ProjectionGeoKey or ProjCoordTransGeoKey",
        );
    };
    let name = ct_name(ct);
    let lat = || Ok::<f64, String>(keys.param(&LAT, deg)?.unwrap_or(0.0));
    let lon = || keys.required(&LON, deg, name.unwrap_or(""));
    let k = || Ok::<f64, String>(keys.param(&SCALE, 1.0)?.unwrap_or(1.0));
    let sp = |id: u16| keys.required(&[id], deg, name.unwrap_or(""));
    let xy = || {
        let e = keys.param(&EAST, unit)?.unwrap_or(0.0);
        let n = keys.param(&NORTH, unit)?.unwrap_or(0.0);
        Ok::<String, String>(format!("+x_0={e} +y_0={n}"))
    };
    let method = match ct {
        1 => format!("+proj=tmerc +lat_0={} +lon_0={} +k_0={} {}", lat()?, lon()?, k()?, xy()?),
        27 => format!("+proj=tmerc +axis=wsu +lat_0={} +lon_0={} +k_0={} {}", lat()?, lon()?, k()?, xy()?),
        7 => {
            let origin = lat()?;
            if origin != 0.0 {
                return refuse(
                    PROJ_NAT_ORIGIN_LAT,
                    origin / deg,
                    "a Mercator projection's origin is on the equator",
                );
            }
            match keys.param(&[PROJ_STD_PARALLEL1], deg)? {
                Some(ts) => format!("+proj=merc +lat_ts={ts} +lon_0={} {}", lon()?, xy()?),
                None => format!("+proj=merc +lon_0={} +k_0={} {}", lon()?, k()?, xy()?),
            }
        }
        8 => format!(
            "+proj=lcc +lat_1={} +lat_2={} +lat_0={} +lon_0={} {}",
            sp(PROJ_STD_PARALLEL1)?,
            sp(PROJ_STD_PARALLEL2)?,
            lat()?,
            lon()?,
            xy()?
        ),
        9 => {
            let l = lat()?;
            format!("+proj=lcc +lat_1={l} +lat_0={l} +lon_0={} +k_0={} {}", lon()?, k()?, xy()?)
        }
        10 => format!("+proj=laea +lat_0={} +lon_0={} {}", lat()?, lon()?, xy()?),
        11 => format!(
            "+proj=aea +lat_1={} +lat_2={} +lat_0={} +lon_0={} {}",
            sp(PROJ_STD_PARALLEL1)?,
            sp(PROJ_STD_PARALLEL2)?,
            lat()?,
            lon()?,
            xy()?
        ),
        12 => format!("+proj=aeqd +lat_0={} +lon_0={} {}", lat()?, lon()?, xy()?),
        13 => format!(
            "+proj=eqdc +lat_1={} +lat_2={} +lat_0={} +lon_0={} {}",
            sp(PROJ_STD_PARALLEL1)?,
            sp(PROJ_STD_PARALLEL2)?,
            lat()?,
            lon()?,
            xy()?
        ),
        14 => format!("+proj=stere +lat_0={} +lon_0={} +k_0={} {}", lat()?, lon()?, k()?, xy()?),
        15 => {
            let ts = keys.required(&LAT, deg, "Polar Stereographic")?;
            if ts == 0.0 || ts.abs() > 90.0 {
                return refuse(
                    PROJ_NAT_ORIGIN_LAT,
                    ts / deg,
                    "a polar stereographic's latitude of true scale is a latitude off the equator",
                );
            }
            let pole = if ts > 0.0 { 90.0 } else { -90.0 };
            let lon = keys.required(&POLE_LON, deg, "Polar Stereographic")?;
            format!("+proj=stere +lat_0={pole} +lat_ts={ts} +lon_0={lon} +k_0={} {}", k()?, xy()?)
        }
        16 => format!("+proj=sterea +lat_0={} +lon_0={} +k_0={} {}", lat()?, lon()?, k()?, xy()?),
        17 => {
            let ts = keys.param(&[PROJ_STD_PARALLEL1], deg)?.unwrap_or(0.0);
            format!("+proj=eqc +lat_ts={ts} +lat_0={} +lon_0={} {}", lat()?, lon()?, xy()?)
        }
        18 => format!("+proj=cass +lat_0={} +lon_0={} {}", lat()?, lon()?, xy()?),
        19 => format!("+proj=gnom +lat_0={} +lon_0={} {}", lat()?, lon()?, xy()?),
        21 => format!("+proj=ortho +lat_0={} +lon_0={} {}", lat()?, lon()?, xy()?),
        22 => format!("+proj=poly +lat_0={} +lon_0={} {}", lat()?, lon()?, xy()?),
        24 => format!("+proj=sinu +lon_0={} {}", lon()?, xy()?),
        28 => {
            let ts = keys.param(&[PROJ_STD_PARALLEL1], deg)?.unwrap_or(0.0);
            format!("+proj=cea +lat_ts={ts} +lon_0={} {}", lon()?, xy()?)
        }
        other => {
            let what = ct_name(other).map_or_else(
                || "not a coordinate transformation of GeoTIFF 1.1".to_owned(),
                |n| format!("{n} is not supported"),
            );
            return refuse(PROJ_COORD_TRANS, other, what);
        }
    };
    Ok((method, name.unwrap_or("").to_owned()))
}

/// The coordinate transformation's name (GeoTIFF 1.1, table of ProjCoordTransGeoKey values).
fn ct_name(ct: u16) -> Option<&'static str> {
    Some(match ct {
        1 => "Transverse Mercator",
        2 => "Transverse Mercator (modified Alaska)",
        3 => "Oblique Mercator",
        4 => "Oblique Mercator (Laborde)",
        5 => "Oblique Mercator (Rosenmund)",
        6 => "Oblique Mercator (spherical)",
        7 => "Mercator",
        8 => "Lambert Conformal Conic (2SP)",
        9 => "Lambert Conformal Conic (1SP)",
        10 => "Lambert Azimuthal Equal Area",
        11 => "Albers Equal Area",
        12 => "Azimuthal Equidistant",
        13 => "Equidistant Conic",
        14 => "Stereographic",
        15 => "Polar Stereographic",
        16 => "Oblique Stereographic",
        17 => "Equirectangular",
        18 => "Cassini-Soldner",
        19 => "Gnomonic",
        20 => "Miller Cylindrical",
        21 => "Orthographic",
        22 => "Polyconic",
        23 => "Robinson",
        24 => "Sinusoidal",
        25 => "Van der Grinten",
        26 => "New Zealand Map Grid",
        27 => "Transverse Mercator (south oriented)",
        28 => "Cylindrical Equal Area",
        _ => return None,
    })
}

/// The vertical datum the keys state; heights must be in metres.
fn vertical(keys: &GeoKeys) -> Res<Option<VerticalDatum>> {
    if let Some(u) = keys.short(VERTICAL_UNITS)?.filter(|&u| u != 9001) {
        let what = linear_unit_of(u).map_or_else(|| "a unit".to_owned(), |(m, n)| format!("{n} ({m} m)"));
        return refuse(
            VERTICAL_UNITS,
            u,
            format!(
                "heights in {what} are not converted to metres; convert them first (e.g. gdal_calc.py with \
                 --calc=\"A*{}\") and drop the key",
                linear_unit_of(u).map_or(1.0, |x| x.0)
            ),
        );
    }
    let by_datum = |keys: &GeoKeys| -> Res<Option<VerticalDatum>> {
        match keys.short(VERTICAL_DATUM)? {
            None => Ok(None),
            Some(5171) => Ok(Some(VerticalDatum::Egm96)),
            Some(1027) => Ok(Some(VerticalDatum::Egm2008)),
            Some(d) => refuse(VERTICAL_DATUM, d, "expected 5171 (EGM96 geoid) or 1027 (EGM2008 geoid)"),
        }
    };
    match keys.short(VERTICAL_TYPE)? {
        None => by_datum(keys),
        Some(USER_DEFINED) => match by_datum(keys)? {
            Some(v) => Ok(Some(v)),
            None => {
                refuse(VERTICAL_TYPE, USER_DEFINED, "a user-defined vertical CRS without VerticalDatumGeoKey")
            }
        },
        Some(code) => VerticalDatum::from_epsg(u32::from(code)).map(Some).ok_or_else(|| {
            format!(
                "{} {code}: expected 5773 (EGM96 height) or 3855 (EGM2008 height)",
                key_name(VERTICAL_TYPE)
            )
        }),
    }
}

#[cfg(test)]
#[path = "geokeys_tests.rs"]
mod tests;
