//! Reference values from PROJ 9.5 (pyproj 3.7, `Transformer.from_crs(code, 4979, always_xy=True)`),
//! an implementation independent of proj4rs.
#![allow(clippy::float_cmp)]

use super::*;

#[test]
fn projections_agree_with_proj() {
    // (code, x, y, lon, lat) — PROJ's answers.
    let cases = [
        (32632, 650_000.0, 5_170_000.0, 10.960_883_456_9, 46.666_752_668_9),
        (26918, 500_000.0, 4_500_000.0, -75.0, 40.650_856_516_6),
        (2056, 2_600_000.0, 1_200_000.0, 7.438_632_420_9, 46.951_082_771_9),
        (2276, 2_400_000.0, 7_000_000.0, -97.094_594_351_0, 32.863_572_243_9),
        (3857, 1_000_000.0, 7_800_000.0, 8.983_152_841_2, 57.194_611_313_8),
        (2193, 1_600_000.0, 5_400_000.0, 173.0, -41.551_664_523_5),
        (32717, 500_000.0, 9_000_000.0, -81.0, -9.046_562_463_8),
        (3413, 0.0, -1_000_000.0, -45.0, 80.787_812_971_1),
    ];
    for (code, x, y, lon, lat) in cases {
        let c = Crs::from_epsg(code).unwrap();
        let (a, b) = c.to_wgs84(x, y).unwrap();
        // 1e-9° is 0.1 mm.
        assert!((a - lon).abs() < 1e-9 && (b - lat).abs() < 1e-9, "EPSG:{code}: {a} {b} vs {lon} {lat}");
        let (bx, by) = c.from_wgs84(a, b).unwrap();
        assert!((bx - x).abs() < 1e-4 && (by - y).abs() < 1e-4, "EPSG:{code} back: {bx} {by}");
    }
}

#[test]
fn units_and_scale() {
    let feet = Crs::from_epsg(2276).unwrap();
    assert!((feet.unit_metres() - 1200.0 / 3937.0).abs() < 1e-12);
    let (kx, ky) = feet.ground_scale(2_400_000.0, 7_000_000.0).unwrap();
    // A US survey foot on the ground, times the Lambert scale there (within 0.1 %).
    assert!((kx / 0.304_800_6 - 1.0).abs() < 1e-3 && (kx / ky - 1.0).abs() < 1e-6, "{kx} {ky}");
    let merc = Crs::from_epsg(3857).unwrap();
    let (kx, _) = merc.ground_scale(1_000_000.0, 7_800_000.0).unwrap();
    // Web Mercator metres at 57.19° N are cos(57.19°) ground metres (within the ellipsoid's 0.5 %).
    assert!((kx / 57.194_611_f64.to_radians().cos() - 1.0).abs() < 5e-3, "{kx}");
    let geo = Crs::wgs84();
    assert!(geo.is_geographic() && geo.unit_metres() == 1.0);
}

#[test]
fn longitudes_wrap_and_latitudes_are_checked() {
    let geo = Crs::wgs84();
    let (lon, lat) = geo.to_wgs84(190.0, 10.0).unwrap();
    assert!((lon + 170.0).abs() < 1e-12 && (lat - 10.0).abs() < 1e-12);
    assert_eq!(geo.to_wgs84(0.0, 90.0).unwrap().1, 90.0);
    assert_eq!(geo.to_wgs84(0.0, 90.5).unwrap().1, 90.0, "past the pole is the pole");
    assert!(matches!(geo.to_wgs84(f64::NAN, 0.0), Err(CrsError::Point { .. })));
}

#[test]
fn parse_codes_proj_strings_and_wkt() {
    assert_eq!(Crs::parse("EPSG:32632").unwrap().0.epsg(), Some(32632));
    assert_eq!(Crs::parse("epsg:4326+5773").unwrap().1, Some(VerticalDatum::Egm96));
    assert_eq!(Crs::parse("EPSG:4326+3855").unwrap().1, Some(VerticalDatum::Egm2008));
    assert_eq!(Crs::parse("EPSG:4326+5703").unwrap_err(), CrsError::UnknownVertical(5703));
    assert_eq!(Crs::parse("EPSG:99999").unwrap_err(), CrsError::UnknownEpsg(99999));
    assert!(matches!(Crs::parse("utm 32"), Err(CrsError::Syntax { .. })));
    let p = Crs::parse("+proj=utm +zone=33 +datum=WGS84 +units=m +no_defs").unwrap().0;
    assert!(!p.is_geographic());
    // Anguilla 1957: Clarke 1880 with no shift to WGS 84 in its definition.
    let e = Crs::parse("EPSG:2000").unwrap_err().to_string();
    assert!(e.contains("towgs84"), "{e}");
    let e = Crs::parse("+proj=tmerc +nadgrids=ntv2_0.gsb +ellps=clrk66").unwrap_err().to_string();
    assert!(e.contains("nadgrids"), "{e}");
    let wkt1 = r#"PROJCS["WGS 84 / UTM zone 32N",GEOGCS["WGS 84",DATUM["WGS_1984",SPHEROID["WGS 84",6378137,298.257223563,AUTHORITY["EPSG","7030"]],AUTHORITY["EPSG","6326"]],PRIMEM["Greenwich",0],UNIT["degree",0.0174532925199433],AUTHORITY["EPSG","4326"]],PROJECTION["Transverse_Mercator"],UNIT["metre",1],AUTHORITY["EPSG","32632"]]"#;
    assert_eq!(Crs::parse(wkt1).unwrap().0.epsg(), Some(32632));
    let wkt2 = r#"PROJCRS["NAD83 / UTM zone 18N",BASEGEOGCRS["NAD83",DATUM["North American Datum 1983",ELLIPSOID["GRS 1980",6378137,298.257222101]],ID["EPSG",4269]],CONVERSION["UTM zone 18N",METHOD["Transverse Mercator"]],CS[Cartesian,2],ID["EPSG",26918]]"#;
    assert_eq!(Crs::parse(wkt2).unwrap().0.epsg(), Some(26918));
    let compound = r#"COMPD_CS["WGS 84 + EGM96 height",GEOGCS["WGS 84",DATUM["WGS_1984",SPHEROID["WGS 84",6378137,298.257223563]],AUTHORITY["EPSG","4326"]],VERT_CS["EGM96 height",VERT_DATUM["EGM96 geoid",2005],AUTHORITY["EPSG","5773"]]]"#;
    let (c, v) = Crs::parse(compound).unwrap();
    assert_eq!((c.epsg(), v), (Some(4326), Some(VerticalDatum::Egm96)));
    // WKT without an EPSG identifier is not guessed at.
    assert!(matches!(Crs::parse(r#"PROJCS["custom",GEOGCS["x"]]"#), Err(CrsError::Syntax { .. })));
}

#[test]
fn records_round_trip() {
    let c = Crs::from_epsg(2056).unwrap();
    let json = serde_json::to_string(&c).unwrap();
    let back: Crs = serde_json::from_str(&json).unwrap();
    assert_eq!(back, c);
    assert_eq!(back.definition(), "EPSG:2056");
    assert!(json.contains("towgs84"), "{json}");
}

#[test]
fn frame_places_and_inverts() {
    let grid =
        CrsGrid { crs: Crs::from_epsg(32632).unwrap(), e0: 600_000.0, n0: 5_200_000.0, de: 30.0, dn: -30.0 };
    let f = Frame {
        x0: 600_000.0,
        y0: 5_200_000.0,
        dx: 29.99,
        dy: -29.99,
        grid,
        vertical: VerticalDatum::Egm96,
        geoid: Some(Geoid::egm96().unwrap()),
    };
    let p = [600_000.0 + 10.0 * 29.99, 5_200_000.0 - 20.0 * 29.99, 1234.5];
    let (e, n) = f.crs_xy(p[0], p[1]);
    assert!((e - 600_300.0).abs() < 1e-6 && (n - 5_199_400.0).abs() < 1e-6);
    let (lon, lat, h) = f.to_geodetic(p).unwrap();
    let undulation = f.undulation(lon, lat).unwrap();
    assert!((h - 1234.5 - undulation).abs() < 1e-9 && undulation > 40.0 && undulation < 55.0, "{undulation}");
    let back = f.from_ecef(f.to_ecef(p).unwrap()).unwrap();
    for k in 0..3 {
        assert!((back[k] - p[k]).abs() < 1e-6, "{back:?} {p:?}");
    }
}
