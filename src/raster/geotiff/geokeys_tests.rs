//! GeoKey directories built by hand, read and compared with PROJ.
//!
//! Reference positions: PROJ 9.5 through pyproj 3.7, `Transformer.from_crs(src, "EPSG:4326",
//! always_xy=True)`, where `src` is the EPSG code when the CRS has one whose datum needs no shift
//! (WGS 84, NAD83, ETRS89), else the PROJ string with the same `+towgs84` the keys give (so that
//! PROJ applies the same Helmert shift rather than a grid). An implementation independent of
//! proj4rs and of this module.

// A failed unwrap is the test failing.
#![allow(clippy::unwrap_used)]

use super::*;

/// A key's value as a test writes it.
#[derive(Clone)]
enum V {
    S(u16),
    D(Vec<f64>),
    A(&'static str),
}

fn d(v: f64) -> V {
    V::D(vec![v])
}

/// The directory, double and ASCII arrays of `keys` (sorted by id, as GeoTIFF requires).
fn arrays(keys: &[(u16, V)]) -> (Vec<u16>, Vec<f64>, String) {
    let mut keys = keys.to_vec();
    keys.sort_by_key(|k| k.0);
    let mut dir = vec![1, 1, 1, keys.len() as u16];
    let (mut doubles, mut ascii) = (Vec::new(), String::new());
    for (id, v) in keys {
        match v {
            V::S(s) => dir.extend([id, 0, 1, s]),
            V::D(x) => {
                dir.extend([id, GEO_DOUBLE_PARAMS, x.len() as u16, doubles.len() as u16]);
                doubles.extend(x);
            }
            V::A(t) => {
                dir.extend([id, GEO_ASCII_PARAMS, t.len() as u16 + 1, ascii.len() as u16]);
                ascii.push_str(t);
                ascii.push('|');
            }
        }
    }
    (dir, doubles, ascii)
}

fn read_keys(keys: &[(u16, V)]) -> Res<KeysCrs> {
    let (dir, doubles, ascii) = arrays(keys);
    read(&GeoKeys { dir: &dir, doubles: &doubles, ascii: &ascii })
}

fn crs_of(keys: &[(u16, V)]) -> Crs {
    let k = read_keys(keys).unwrap_or_else(|e| panic!("refused: {e}"));
    k.crs.horizontal.unwrap()
}

fn refusal(keys: &[(u16, V)]) -> String {
    match read_keys(keys) {
        Ok(k) => panic!("accepted: {:?}", k.crs.horizontal),
        Err(e) => e,
    }
}

/// Metres between two lon/lat points (degrees), locally flat: fine at millimetres.
fn metres(a: (f64, f64), b: (f64, f64)) -> f64 {
    let (m_lon, m_lat) = crate::crs::metres_per_degree(b.1);
    ((a.0 - b.0) * m_lon).hypot((a.1 - b.1) * m_lat)
}

fn assert_near(c: &Crs, (x, y): (f64, f64), expect: (f64, f64), tol_m: f64) {
    let got = c.to_wgs84(x, y).unwrap();
    let off = metres(got, expect);
    assert!(off < tol_m, "{} at ({x}, {y}): {got:?}, PROJ says {expect:?}: {off} m off", c.definition());
}

const PROJECTED: (u16, V) = (GT_MODEL_TYPE, V::S(MODEL_PROJECTED));
const USER: (u16, V) = (PROJECTED_TYPE, V::S(USER_DEFINED));

#[test]
fn utm_by_projection_code() {
    let north = crs_of(&[PROJECTED, USER, (PROJECTION, V::S(16032)), (GEOGRAPHIC_TYPE, V::S(4326))]);
    assert!(north.definition().contains("UTM zone 32N") && north.definition().contains("EPSG:4326"));
    assert_near(&north, (650_000.0, 5_170_000.0), (10.960_883_456_9, 46.666_752_668_9), 1e-3);
    assert_near(&north, (300_000.0, 4_000_000.0), (6.777_608_614_6, 36.124_095_832_1), 1e-3);
    let south = crs_of(&[PROJECTED, USER, (PROJECTION, V::S(16117)), (GEOGRAPHIC_TYPE, V::S(4326))]);
    assert_near(&south, (500_000.0, 9_000_000.0), (-81.0, -9.046_562_463_8), 1e-3);
    let e = refusal(&[PROJECTED, USER, (PROJECTION, V::S(10101)), (GEOGRAPHIC_TYPE, V::S(4267))]);
    assert!(e.starts_with("ProjectionGeoKey 10101:"), "{e}");
}

/// EPSG:2276, NAD83 / Texas North Central (ftUS), spelled out: Lambert 2SP with its false origin
/// in US survey feet (EPSG's own parameters: 33°58′, 32°08′, origin 31°40′ N 98°30′ W, false
/// easting 1 968 500 ftUS, false northing 6 561 666.667 ftUS).
fn texas_keys() -> Vec<(u16, V)> {
    vec![
        PROJECTED,
        USER,
        (PROJ_COORD_TRANS, V::S(8)),
        (PROJ_STD_PARALLEL1, d(33.0 + 58.0 / 60.0)),
        (PROJ_STD_PARALLEL2, d(32.0 + 8.0 / 60.0)),
        (PROJ_FALSE_ORIGIN_LAT, d(31.0 + 40.0 / 60.0)),
        (PROJ_FALSE_ORIGIN_LONG, d(-98.5)),
        (PROJ_FALSE_ORIGIN_EASTING, d(1_968_500.0)),
        (PROJ_FALSE_ORIGIN_NORTHING, d(6_561_666.667)),
        (PROJ_LINEAR_UNITS, V::S(9003)),
        (GEOGRAPHIC_TYPE, V::S(4269)),
        (PCS_CITATION, V::A("NAD83 / Texas North Central (ftUS)")),
    ]
}

#[test]
fn lcc_2sp_in_us_survey_feet_is_epsg_2276() {
    let c = crs_of(&texas_keys());
    let code = Crs::from_epsg(2276).unwrap();
    assert!((c.unit_metres() - 1200.0 / 3937.0).abs() < 1e-15);
    assert!(
        c.definition().contains("Texas North Central") && c.definition().contains("US survey foot"),
        "{c:?}"
    );
    let refs = [
        ((2_400_000.0, 7_000_000.0), (-97.094_594_351_0, 32.863_572_243_9)),
        ((1_900_000.0, 6_900_000.0), (-98.722_429_441_0, 32.596_432_661_0)),
        ((2_600_000.0, 7_200_000.0), (-96.430_499_956_9, 33.404_127_550_9)),
    ];
    for (p, expect) in refs {
        assert_near(&c, p, expect, 1e-3);
        // The same lon/lat as the EPSG definition, within a millimetre.
        let (a, b) = (c.to_wgs84(p.0, p.1).unwrap(), code.to_wgs84(p.0, p.1).unwrap());
        assert!(metres(a, b) < 1e-3, "{a:?} {b:?}");
    }
    // GDAL writes the false origin in the natural-origin keys; both are read.
    let mut gdal = texas_keys();
    for (id, _) in &mut gdal {
        *id = match *id {
            PROJ_FALSE_ORIGIN_EASTING => PROJ_FALSE_EASTING,
            PROJ_FALSE_ORIGIN_NORTHING => PROJ_FALSE_NORTHING,
            other => other,
        };
    }
    assert_eq!(crs_of(&gdal), c);
    // Two keys for one parameter that disagree are refused.
    let mut both = texas_keys();
    both.push((PROJ_FALSE_EASTING, d(0.0)));
    let e = refusal(&both);
    assert!(e.contains("ProjFalseEastingGeoKey 0") && e.contains("ProjFalseOriginEastingGeoKey"), "{e}");
}

/// DHDN / 3-degree Gauss-Krüger zone 3 (EPSG:31467) as user-defined keys: Bessel 1841 by code, a
/// user-defined datum with its 7-parameter shift.
#[test]
fn transverse_mercator_with_towgs84() {
    let keys = [
        PROJECTED,
        USER,
        (PROJ_COORD_TRANS, V::S(1)),
        (PROJ_NAT_ORIGIN_LAT, d(0.0)),
        (PROJ_NAT_ORIGIN_LONG, d(9.0)),
        (PROJ_SCALE_AT_NAT_ORIGIN, d(1.0)),
        (PROJ_FALSE_EASTING, d(3_500_000.0)),
        (PROJ_FALSE_NORTHING, d(0.0)),
        (GEOGRAPHIC_TYPE, V::S(USER_DEFINED)),
        (GEOG_DATUM, V::S(USER_DEFINED)),
        (GEOG_ELLIPSOID, V::S(7004)),
        (GEOG_TOWGS84, V::D(vec![598.1, 73.7, 418.2, 0.202, 0.045, -2.455, 6.7])),
    ];
    let c = crs_of(&keys);
    // PROJ: +proj=tmerc +lon_0=9 +k=1 +x_0=3500000 +ellps=bessel +towgs84=598.1,73.7,418.2,0.202,0.045,-2.455,6.7
    assert_near(&c, (3_512_345.0, 5_400_000.0), (9.166_802_685_5, 48.737_417_615_8), 1e-3);
    // Without the shift the datum is unknown: refused, not taken as WGS 84.
    let e = refusal(&keys[..keys.len() - 1]);
    assert!(e.starts_with("GeogGeodeticDatumGeoKey 32767:") && e.contains("GeogTOWGS84GeoKey"), "{e}");
    // The same ellipsoid by its axes (in metres by default).
    let mut axes = keys.to_vec();
    axes.retain(|k| k.0 != GEOG_ELLIPSOID);
    axes.push((GEOG_SEMI_MAJOR, d(6_377_397.155)));
    axes.push((GEOG_INV_FLATTENING, d(299.152_812_8)));
    assert_near(&crs_of(&axes), (3_512_345.0, 5_400_000.0), (9.166_802_685_5, 48.737_417_615_8), 1e-3);
}

/// What a key set spells out, its keys, a point and PROJ's longitude and latitude of it.
type Case = (&'static str, Vec<(u16, V)>, (f64, f64), (f64, f64));

/// One key set per supported method, against the EPSG CRS it spells out (or the PROJ string with
/// the same `+towgs84`, see the module comment).
#[test]
fn methods_agree_with_proj() {
    let wgs84 = (GEOGRAPHIC_TYPE, V::S(4326));
    let ct = |c: u16| (PROJ_COORD_TRANS, V::S(c));
    let cases: Vec<Case> = vec![
        (
            "EPSG:3413 polar stereographic",
            vec![
                ct(15),
                (PROJ_NAT_ORIGIN_LAT, d(70.0)),
                (PROJ_STRAIGHT_VERT_POLE_LONG, d(-45.0)),
                (PROJ_SCALE_AT_NAT_ORIGIN, d(1.0)),
                wgs84.clone(),
            ],
            (500_000.0, -1_500_000.0),
            (-26.565_051_177_1, 75.479_145_894_4),
        ),
        (
            "EPSG:3035 Lambert azimuthal equal area",
            vec![
                ct(10),
                (PROJ_CENTER_LAT, d(52.0)),
                (PROJ_CENTER_LONG, d(10.0)),
                (PROJ_FALSE_EASTING, d(4_321_000.0)),
                (PROJ_FALSE_NORTHING, d(3_210_000.0)),
                (GEOGRAPHIC_TYPE, V::S(4258)),
            ],
            (4_421_000.0, 3_410_000.0),
            (11.517_143_545_7, 53.787_893_407_6),
        ),
        (
            "EPSG:5070 Albers",
            vec![
                ct(11),
                (PROJ_STD_PARALLEL1, d(29.5)),
                (PROJ_STD_PARALLEL2, d(45.5)),
                (PROJ_NAT_ORIGIN_LAT, d(23.0)),
                (PROJ_NAT_ORIGIN_LONG, d(-96.0)),
                (GEOGRAPHIC_TYPE, V::S(4269)),
            ],
            (100_000.0, 1_500_000.0),
            (-94.872_589_251_1, 36.541_672_730_1),
        ),
        (
            "RD New oblique stereographic (+towgs84=565.417,…)",
            vec![
                ct(16),
                (PROJ_NAT_ORIGIN_LAT, d(52.156_160_555_555_55)),
                (PROJ_NAT_ORIGIN_LONG, d(5.387_638_888_888_89)),
                (PROJ_SCALE_AT_NAT_ORIGIN, d(0.999_907_9)),
                (PROJ_FALSE_EASTING, d(155_000.0)),
                (PROJ_FALSE_NORTHING, d(463_000.0)),
                (GEOG_DATUM, V::S(USER_DEFINED)),
                (GEOG_ELLIPSOID, V::S(7004)),
                (GEOG_TOWGS84, V::D(vec![565.417, 50.3319, 465.552, -0.398_957, 0.343_988, -1.8774, 4.0725])),
            ],
            (156_000.0, 465_000.0),
            (5.401_822_044_0, 52.173_147_200_9),
        ),
        (
            "EPSG:3395 Mercator (1SP)",
            vec![ct(7), (PROJ_NAT_ORIGIN_LONG, d(0.0)), (PROJ_SCALE_AT_NAT_ORIGIN, d(1.0)), wgs84.clone()],
            (1_000_000.0, 7_000_000.0),
            (8.983_152_841_2, 53.276_311_903_4),
        ),
        (
            "WGS 84 / Mercator 41 (2SP)",
            vec![ct(7), (PROJ_STD_PARALLEL1, d(-41.0)), (PROJ_NAT_ORIGIN_LONG, d(100.0)), wgs84.clone()],
            (1_000_000.0, -5_000_000.0),
            (111.885_633_800_5, -51.155_317_314_3),
        ),
        (
            "EPSG:2046 south-oriented Transverse Mercator",
            vec![ct(27), (PROJ_NAT_ORIGIN_LONG, d(15.0)), (PROJ_SCALE_AT_NAT_ORIGIN, d(1.0)), wgs84.clone()],
            (50_000.0, 3_700_000.0),
            (14.462_384_469_4, -33.424_880_388_2),
        ),
        (
            "EPSG:4087 equirectangular",
            vec![ct(17), (PROJ_CENTER_LONG, d(0.0)), (PROJ_STD_PARALLEL1, d(0.0)), wgs84.clone()],
            (1_000_000.0, 5_000_000.0),
            (8.983_152_841_2, 44.915_764_206_0),
        ),
    ];
    for (what, mut keys, p, expect) in cases {
        keys.extend([PROJECTED, USER]);
        let c = crs_of(&keys);
        assert!(!c.is_geographic(), "{what}");
        assert_near(&c, p, expect, 1e-3);
    }
}

/// EPSG:27572, NTF (Paris) / Lambert zone II, as its keys would be: angles in grads, the Paris
/// meridian, Clarke 1880 (IGN) by code, its 3-parameter shift.
#[test]
fn grads_and_the_paris_meridian() {
    let keys = [
        PROJECTED,
        USER,
        (PROJ_COORD_TRANS, V::S(9)),
        (PROJ_NAT_ORIGIN_LAT, d(52.0)),
        (PROJ_NAT_ORIGIN_LONG, d(0.0)),
        (PROJ_SCALE_AT_NAT_ORIGIN, d(0.999_877_42)),
        (PROJ_FALSE_EASTING, d(600_000.0)),
        (PROJ_FALSE_NORTHING, d(2_200_000.0)),
        (GEOG_ANGULAR_UNITS, V::S(9105)),
        (GEOG_DATUM, V::S(USER_DEFINED)),
        (GEOG_ELLIPSOID, V::S(7011)),
        (GEOG_PRIME_MERIDIAN, V::S(8903)),
        (GEOG_TOWGS84, V::D(vec![-168.0, -60.0, 320.0])),
    ];
    let c = crs_of(&keys);
    assert!(c.definition().contains("Paris"), "{c:?}");
    // PROJ, EPSG:27572 (whose datum shift is these three parameters).
    assert_near(&c, (610_000.0, 2_210_000.0), (2.467_760_163_4, 46.889_838_947_9), 1e-3);
}

/// The keys GDAL 3 writes for `+proj=longlat +ellps=clrk80ign +pm=paris +towgs84=-168,-60,320`
/// (read back from its file): the prime meridian by its longitude alone.
#[test]
fn gdal_style_paris_geographic() {
    let keys = [
        (GT_MODEL_TYPE, V::S(MODEL_GEOGRAPHIC)),
        (GT_RASTER_TYPE, V::S(1)),
        (GEOGRAPHIC_TYPE, V::S(USER_DEFINED)),
        (GEOG_CITATION, V::A("GCS Name = unknown|Datum = Unknown based on Clarke 1880 (IGN).")),
        (GEOG_DATUM, V::S(USER_DEFINED)),
        (GEOG_ANGULAR_UNITS, V::S(9102)),
        (GEOG_ELLIPSOID, V::S(USER_DEFINED)),
        (GEOG_SEMI_MAJOR, d(6_378_249.2)),
        (GEOG_INV_FLATTENING, d(293.466_021_293_627)),
        (GEOG_PRIME_MERIDIAN_LONG, d(2.337_229_17)),
        (GEOG_TOWGS84, V::D(vec![-168.0, -60.0, 320.0])),
    ];
    let c = crs_of(&keys);
    assert!(c.is_geographic() && c.definition().contains("prime meridian 2.33722917°"), "{c:?}");
    // PROJ: +proj=longlat +a=6378249.2 +rf=293.466021293627 +pm=paris +towgs84=-168,-60,320 (0.1, 49.1).
    assert_near(&c, (0.1, 49.1), (2.436_506_113_2, 49.099_929_929_3), 1e-3);
}

#[test]
fn geographic_keys() {
    let geo = (GT_MODEL_TYPE, V::S(MODEL_GEOGRAPHIC));
    let k = read_keys(&[geo.clone(), (GEOGRAPHIC_TYPE, V::S(4326))]).unwrap();
    assert_eq!((k.crs.horizontal.unwrap().epsg(), k.degrees_per_unit), (Some(4326), 1.0));
    // Radians: the coordinates convert to degrees.
    let k =
        read_keys(&[geo.clone(), (GEOGRAPHIC_TYPE, V::S(4326)), (GEOG_ANGULAR_UNITS, V::S(9101))]).unwrap();
    assert!((k.degrees_per_unit - 57.295_779_513_082_32).abs() < 1e-12);
    // A datum by its EPSG code: NAD83's geographic CRS.
    let c = read_keys(&[geo.clone(), (GEOGRAPHIC_TYPE, V::S(USER_DEFINED)), (GEOG_DATUM, V::S(6269))])
        .unwrap()
        .crs
        .horizontal
        .unwrap();
    assert!(c.is_geographic() && c.record().proj4.contains("+datum=NAD83"), "{:?}", c.record());
    assert!(c.definition().contains("datum EPSG:6269"));
    // A projected CRS code in a geographic model, and a geographic one with the wrong model.
    let e = refusal(&[geo.clone(), (GEOGRAPHIC_TYPE, V::S(32632))]);
    assert!(e.starts_with("GeographicTypeGeoKey 32632:"), "{e}");
    let e = refusal(&[PROJECTED, (PROJECTED_TYPE, V::S(4326))]);
    assert!(e.starts_with("GTModelTypeGeoKey 1:"), "{e}");
    let e = refusal(&[geo, (GEOGRAPHIC_TYPE, V::S(4326)), (GEOG_ANGULAR_UNITS, V::S(9110))]);
    assert!(e.starts_with("GeogAngularUnitsGeoKey 9110:"), "{e}");
}

#[test]
fn unsupported_keys_are_refused_by_name_and_value() {
    let wgs84 = (GEOGRAPHIC_TYPE, V::S(4326));
    let hotine = [PROJECTED, USER, (PROJ_COORD_TRANS, V::S(3)), (PROJ_CENTER_LONG, d(10.0)), wgs84.clone()];
    let e = refusal(&hotine);
    assert!(e.starts_with("ProjCoordTransGeoKey 3:") && e.contains("Oblique Mercator"), "{e}");
    let e = refusal(&[PROJECTED, USER, (PROJ_COORD_TRANS, V::S(99)), wgs84.clone()]);
    assert!(e.starts_with("ProjCoordTransGeoKey 99:"), "{e}");
    let e = refusal(&[PROJECTED, (PROJECTED_TYPE, V::S(65000))]);
    assert!(e.starts_with("ProjectedCSTypeGeoKey 65000:") && e.contains("EPSG:65000"), "{e}");
    let e = refusal(&[(GT_MODEL_TYPE, V::S(MODEL_GEOGRAPHIC)), (GEOGRAPHIC_TYPE, V::S(9999))]);
    assert!(e.starts_with("GeographicTypeGeoKey 9999:"), "{e}");
    let e = refusal(&[(GT_MODEL_TYPE, V::S(3))]);
    assert!(e.starts_with("GTModelTypeGeoKey 3:") && e.contains("geocentric"), "{e}");
    // The central meridian is never taken as 0.
    let e = refusal(&[PROJECTED, USER, (PROJ_COORD_TRANS, V::S(1)), wgs84.clone()]);
    assert!(e.contains("Transverse Mercator needs ProjNatOriginLongGeoKey"), "{e}");
    let e = refusal(&[PROJECTED, USER, (PROJECTION, V::S(16032))]);
    assert!(
        e.starts_with("ProjectedCSTypeGeoKey 32767:") && e.contains("geographic CRS is not stated"),
        "{e}"
    );
    // A units key that contradicts the code's unit.
    let e = refusal(&[PROJECTED, (PROJECTED_TYPE, V::S(32632)), (PROJ_LINEAR_UNITS, V::S(9002))]);
    assert!(e.starts_with("ProjLinearUnitsGeoKey 9002:") && e.contains("EPSG:32632"), "{e}");
    let e = refusal(&[PROJECTED, USER, (PROJECTION, V::S(16032)), wgs84, (PROJ_LINEAR_UNITS, V::S(9999))]);
    assert!(e.starts_with("ProjLinearUnitsGeoKey 9999:"), "{e}");
}

#[test]
fn vertical_keys() {
    let v = |keys: &[(u16, V)]| read_keys(keys).map(|k| k.crs.vertical);
    assert_eq!(v(&[(VERTICAL_TYPE, V::S(5773))]), Ok(Some(VerticalDatum::Egm96)));
    assert_eq!(v(&[(VERTICAL_TYPE, V::S(3855))]), Ok(Some(VerticalDatum::Egm2008)));
    assert_eq!(
        v(&[(VERTICAL_TYPE, V::S(USER_DEFINED)), (VERTICAL_DATUM, V::S(5171))]),
        Ok(Some(VerticalDatum::Egm96))
    );
    assert_eq!(
        v(&[(VERTICAL_TYPE, V::S(5773)), (VERTICAL_UNITS, V::S(9001))]),
        Ok(Some(VerticalDatum::Egm96))
    );
    assert_eq!(v(&[PROJECTED]), Ok(None));
    let e = v(&[(VERTICAL_TYPE, V::S(5703))]).unwrap_err();
    assert!(e.starts_with("VerticalCSTypeGeoKey 5703:") && e.contains("5773"), "{e}");
    let e = v(&[(VERTICAL_TYPE, V::S(USER_DEFINED)), (VERTICAL_DATUM, V::S(5103))]).unwrap_err();
    assert!(e.starts_with("VerticalDatumGeoKey 5103:"), "{e}");
    // Heights in feet are refused: they would be read as metres.
    for (u, name) in [(9002, "foot"), (9003, "US survey foot")] {
        let e = v(&[(VERTICAL_TYPE, V::S(5773)), (VERTICAL_UNITS, V::S(u))]).unwrap_err();
        assert!(e.starts_with(&format!("VerticalUnitsGeoKey {u}:")) && e.contains(name), "{e}");
    }
}

#[test]
fn values_in_every_location() {
    // A SHORT stored in the directory array (location 34735, offset 20: after the 4 entries).
    let dir = [1, 1, 1, 4, 1024, 0, 1, 1, 2048, 0, 1, 4326, 3072, 34735, 1, 20, 3074, 0, 1, 16032, 32767];
    let k = read(&GeoKeys { dir: &dir, ..GeoKeys::default() }).unwrap();
    assert!(k.crs.horizontal.unwrap().definition().contains("UTM zone 32N"));
    // A citation in the ASCII tag, after another string.
    let mut keys = texas_keys();
    keys.retain(|k| k.0 != PCS_CITATION);
    keys.push((GT_CITATION, V::A("from GTCitationGeoKey")));
    assert!(crs_of(&keys).definition().ends_with("(\"from GTCitationGeoKey\")"));
    // A key pointing past the doubles.
    let tm = [
        PROJECTED,
        USER,
        (PROJ_COORD_TRANS, V::S(1)),
        (PROJ_NAT_ORIGIN_LONG, d(9.0)),
        (GEOGRAPHIC_TYPE, V::S(4326)),
    ];
    let (dir, _, _) = arrays(&tm);
    let e = read(&GeoKeys { dir: &dir, doubles: &[], ascii: "" }).unwrap_err();
    assert!(e.starts_with("ProjNatOriginLongGeoKey:") && e.contains("past"), "{e}");
    // A double where a SHORT belongs, and a directory of another version.
    let e = read_keys(&[(PROJECTED_TYPE, d(32632.0))]).unwrap_err();
    assert!(e.starts_with("ProjectedCSTypeGeoKey:"), "{e}");
    let e = read(&GeoKeys { dir: &[2, 1, 0, 0], ..GeoKeys::default() }).unwrap_err();
    assert!(e.contains("version 2"), "{e}");
}

/// Every table row is the EPSG dataset's: spot checks of values PROJ prints for these codes.
#[test]
fn tables() {
    assert_eq!(linear_unit_of(9002), Some((0.3048, "foot")));
    assert_eq!(linear_unit_of(9030), Some((1852.0, "nautical mile")));
    let codes: Vec<u16> = LINEAR_UNITS.iter().map(|u| u.0).collect();
    assert!(codes.windows(2).all(|w| w[0] < w[1]));
    assert!(ELLIPSOIDS.iter().all(|e| e.2 > 6.3e6 && e.2 < 6.4e6));
    assert!(PRIME_MERIDIANS.iter().any(|p| p.0 == 8903 && (p.2 - 2.337_229_17).abs() < 1e-8));
}

#[test]
fn a_user_defined_model_says_to_reproject() {
    // GDAL writes model type 32767 for projections GeoTIFF cannot name (Mollweide, ESRI:54009).
    let dir = [1, 1, 1, 1, 1024, 0, 1, 32767];
    let e = read(&GeoKeys { dir: &dir, ..GeoKeys::default() }).err().unwrap();
    assert!(e.starts_with("GTModelTypeGeoKey 32767:") && e.contains("gdalwarp -t_srs"), "{e}");
}
