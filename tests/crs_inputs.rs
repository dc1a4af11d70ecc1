//! The coordinate system of every input (issue 36, item 1): GeoTIFFs whose GeoKeys are built by
//! hand (user-defined projections and datums, keys in the double and ASCII tags, units, vertical
//! keys) and LAS files with a WKT or GeoKey VLR, read through the loader and the dataset, placed
//! on the Earth and compared with PROJ; what cannot be read is refused naming the key and value.
//!
//! Reference positions: PROJ 9.5 through pyproj 3.7,
//! `Transformer.from_crs(src, "EPSG:4326", always_xy=True).transform(x, y)`, `src` the EPSG code
//! (WGS 84, NAD83: no datum shift) or, for a Helmert datum, the PROJ string with the same
//! `+towgs84` as the keys (so PROJ applies that shift, not a grid).

// Helpers outside `#[test]` functions unwrap too: a failure there is a test failure.
#![allow(clippy::unwrap_used, clippy::float_cmp, clippy::cast_lossless)]

use std::io::Cursor;
use std::path::{Path, PathBuf};

use terrastream::crs::{Crs, VerticalDatum, metres_per_degree};
use terrastream::raster::dataset::{Dataset, DatasetOptions};
use terrastream::raster::{self, Georef, LoadOptions, Overrides, RasterError, WindowReader};
use tiff::encoder::{TiffEncoder, colortype};
use tiff::tags::Tag;

/// A GeoKey's value.
#[derive(Clone)]
enum V {
    S(u16),
    D(Vec<f64>),
    A(&'static str),
}

fn d(v: f64) -> V {
    V::D(vec![v])
}

/// `GeoKeyDirectoryTag`, `GeoDoubleParamsTag`, `GeoAsciiParamsTag` of `keys`.
fn arrays(keys: &[(u16, V)]) -> (Vec<u16>, Vec<f64>, String) {
    let mut keys = keys.to_vec();
    keys.sort_by_key(|k| k.0);
    let mut dir = vec![1, 1, 1, keys.len() as u16];
    let (mut doubles, mut ascii) = (Vec::new(), String::new());
    for (id, v) in keys {
        match v {
            V::S(s) => dir.extend([id, 0, 1, s]),
            V::D(x) => {
                dir.extend([id, 34736, x.len() as u16, doubles.len() as u16]);
                doubles.extend(x);
            }
            V::A(t) => {
                dir.extend([id, 34737, t.len() as u16 + 1, ascii.len() as u16]);
                ascii.push_str(t);
                ascii.push('|');
            }
        }
    }
    (dir, doubles, ascii)
}

/// A 4 × 3 float32 GeoTIFF (heights 100 + index) whose sample (0, 0) is centred at `origin`,
/// cells of `cell` (PixelIsArea: the tiepoint is half a cell up and left), with `keys`.
fn geotiff(dir: &Path, name: &str, origin: (f64, f64), cell: f64, keys: &[(u16, V)]) -> PathBuf {
    let (k, doubles, ascii) = arrays(keys);
    let data: Vec<f32> = (0..12).map(|i| 100.0 + i as f32).collect();
    let mut buf = Cursor::new(Vec::new());
    let mut enc = TiffEncoder::new(&mut buf).unwrap();
    let mut img = enc.new_image::<colortype::Gray32Float>(4, 3).unwrap();
    let e = img.encoder();
    e.write_tag(Tag::ModelPixelScaleTag, &[cell, cell, 0.0][..]).unwrap();
    let tie = [0.0, 0.0, 0.0, origin.0 - cell / 2.0, origin.1 + cell / 2.0, 0.0];
    e.write_tag(Tag::ModelTiepointTag, &tie[..]).unwrap();
    e.write_tag(Tag::GeoKeyDirectoryTag, &k[..]).unwrap();
    if !doubles.is_empty() {
        e.write_tag(Tag::GeoDoubleParamsTag, &doubles[..]).unwrap();
    }
    if !ascii.is_empty() {
        e.write_tag(Tag::GeoAsciiParamsTag, ascii.as_str()).unwrap();
    }
    img.write_data(&data).unwrap();
    let p = dir.join(name);
    std::fs::write(&p, buf.into_inner()).unwrap();
    p
}

fn load(p: &Path) -> Result<Georef, RasterError> {
    raster::load(p, &LoadOptions::default()).map(|r| r.georef)
}

/// WGS 84 longitude and latitude of sample (col, row) of a loaded frame.
fn lonlat(g: &Georef, col: f64, row: f64) -> (f64, f64) {
    let f = g.frame().unwrap().unwrap();
    let (lon, lat, _) = f.to_geodetic([g.x0 + col * g.dx, g.y0 + row * g.dy, 0.0]).unwrap();
    (lon, lat)
}

/// Metres between two lon/lat points (degrees), locally flat: fine at millimetres.
fn metres(a: (f64, f64), b: (f64, f64)) -> f64 {
    let (m_lon, m_lat) = metres_per_degree(b.1);
    ((a.0 - b.0) * m_lon).hypot((a.1 - b.1) * m_lat)
}

fn assert_within(what: &str, got: (f64, f64), expect: (f64, f64), tol_m: f64) {
    let off = metres(got, expect);
    assert!(off < tol_m, "{what}: {got:?}, expected {expect:?}: {off} m off");
}

const PROJECTED: (u16, V) = (1024, V::S(1));
const GEOGRAPHIC: (u16, V) = (1024, V::S(2));
const USER_PCS: (u16, V) = (3072, V::S(32767));
const WGS84: (u16, V) = (2048, V::S(4326));

#[test]
fn user_defined_utm_by_projection_key() {
    let dir = tempfile::tempdir().unwrap();
    let keys = [PROJECTED, USER_PCS, (3074, V::S(16032)), WGS84];
    let p = geotiff(dir.path(), "utm.tif", (650_000.0, 5_170_000.0), 30.0, &keys);
    let g = load(&p).unwrap();
    let c = &g.crs.as_ref().unwrap().crs;
    assert!(c.definition().contains("UTM zone 32N"), "{c:?}");
    // PROJ: EPSG:32632 (650000, 5170000) → 10.9608834569, 46.6667526689.
    assert_within("sample (0, 0)", lonlat(&g, 0.0, 0.0), (10.960_883_456_9, 46.666_752_668_9), 1e-3);
    // The same frame as the file that names EPSG:32632, sample for sample.
    let q =
        geotiff(dir.path(), "code.tif", (650_000.0, 5_170_000.0), 30.0, &[PROJECTED, (3072, V::S(32632))]);
    let h = load(&q).unwrap();
    for (c, r) in [(0.0, 0.0), (3.0, 0.0), (0.0, 2.0), (3.0, 2.0)] {
        assert_within("corner", lonlat(&g, c, r), lonlat(&h, c, r), 1e-3);
    }
    // The dataset (windowed) path reads the same keys.
    let ds = Dataset::open(std::slice::from_ref(&p), &DatasetOptions::default(), &|_, _, _| {}).unwrap();
    assert_eq!(ds.georef().crs, g.crs);
}

#[test]
fn user_defined_lambert_in_us_survey_feet_is_epsg_2276() {
    let dir = tempfile::tempdir().unwrap();
    // EPSG:2276's parameters (NAD83 / Texas North Central (ftUS)), as user-defined keys.
    let keys = [
        PROJECTED,
        USER_PCS,
        (3075, V::S(8)),
        (3078, d(33.0 + 58.0 / 60.0)),
        (3079, d(32.0 + 8.0 / 60.0)),
        (3085, d(31.0 + 40.0 / 60.0)),
        (3084, d(-98.5)),
        (3082, d(1_968_500.0)),
        (3083, d(6_561_666.667)),
        (3076, V::S(9003)),
        (2048, V::S(4269)),
        (3073, V::A("NAD83 / Texas North Central (ftUS)")),
    ];
    let origin = (2_400_000.0, 7_000_000.0);
    let p = geotiff(dir.path(), "lcc.tif", origin, 100.0, &keys);
    let q = geotiff(dir.path(), "2276.tif", origin, 100.0, &[PROJECTED, (3072, V::S(2276))]);
    let (g, h) = (load(&p).unwrap(), load(&q).unwrap());
    let c = &g.crs.as_ref().unwrap().crs;
    assert!(c.definition().contains("Texas North Central") && (c.unit_metres() - 0.304_800_6).abs() < 1e-7);
    // 100 ftUS cells are about 30.5 ground metres, not 100.
    assert!((g.dx / 30.48 - 1.0).abs() < 2e-3, "{}", g.dx);
    // PROJ: EPSG:2276 (2400000, 7000000) → -97.0945943510, 32.8635722439.
    assert_within("sample (0, 0)", lonlat(&g, 0.0, 0.0), (-97.094_594_351_0, 32.863_572_243_9), 1e-3);
    for (col, row) in [(0.0, 0.0), (3.0, 0.0), (0.0, 2.0), (3.0, 2.0)] {
        assert_within("same as EPSG:2276", lonlat(&g, col, row), lonlat(&h, col, row), 1e-3);
    }
}

#[test]
fn user_defined_transverse_mercator_with_towgs84() {
    let dir = tempfile::tempdir().unwrap();
    // DHDN / 3-degree Gauss-Krüger zone 3: Bessel 1841, the 7-parameter shift of EPSG:31467.
    let keys = [
        PROJECTED,
        USER_PCS,
        (3075, V::S(1)),
        (3081, d(0.0)),
        (3080, d(9.0)),
        (3092, d(1.0)),
        (3082, d(3_500_000.0)),
        (3083, d(0.0)),
        (2048, V::S(32767)),
        (2050, V::S(32767)),
        (2056, V::S(7004)),
        (2062, V::D(vec![598.1, 73.7, 418.2, 0.202, 0.045, -2.455, 6.7])),
    ];
    let p = geotiff(dir.path(), "gk.tif", (3_512_345.0, 5_400_000.0), 25.0, &keys);
    let g = load(&p).unwrap();
    // PROJ: +proj=tmerc +lat_0=0 +lon_0=9 +k=1 +x_0=3500000 +y_0=0 +ellps=bessel
    // +towgs84=598.1,73.7,418.2,0.202,0.045,-2.455,6.7 (3512345, 5400000) → 9.1668026855, 48.7374176158.
    assert_within("sample (0, 0)", lonlat(&g, 0.0, 0.0), (9.166_802_685_5, 48.737_417_615_8), 1e-3);
    // Without the shift the datum is not guessed.
    let e = load(&geotiff(dir.path(), "noshift.tif", (0.0, 0.0), 25.0, &keys[..keys.len() - 1])).unwrap_err();
    assert!(matches!(e, RasterError::Crs { .. }) && e.to_string().contains("GeogTOWGS84GeoKey"), "{e}");
}

#[test]
fn geographic_model_in_radians() {
    let dir = tempfile::tempdir().unwrap();
    let (lon, lat, step) = (10.5_f64, 46.25_f64, 1.0_f64 / 3600.0);
    let keys = [GEOGRAPHIC, WGS84, (2054, V::S(9101))];
    let p = geotiff(dir.path(), "rad.tif", (lon.to_radians(), lat.to_radians()), step.to_radians(), &keys);
    let g = load(&p).unwrap();
    let grid = g.crs.clone().unwrap();
    assert!((grid.e0 - lon).abs() < 1e-12 && (grid.n0 - lat).abs() < 1e-12, "{grid:?}");
    assert!((grid.de - step).abs() < 1e-15 && (grid.dn + step).abs() < 1e-15, "{grid:?}");
    assert_within("sample (3, 2)", lonlat(&g, 3.0, 2.0), (lon + 3.0 * step, lat - 2.0 * step), 1e-3);
}

/// A file name, its keys and what the refusal must say.
type Refusal = (&'static str, Vec<(u16, V)>, &'static str);

/// Refusals name the file, the key and its value.
#[test]
fn unsupported_keys_are_refused() {
    let dir = tempfile::tempdir().unwrap();
    let cases: Vec<Refusal> = vec![
        (
            "hotine.tif",
            vec![PROJECTED, USER_PCS, (3075, V::S(3)), (3088, d(10.0)), WGS84],
            "ProjCoordTransGeoKey 3",
        ),
        (
            "nzmg.tif",
            vec![PROJECTED, USER_PCS, (3075, V::S(26)), (3080, d(173.0)), WGS84],
            "ProjCoordTransGeoKey 26",
        ),
        ("unknown.tif", vec![PROJECTED, (3072, V::S(65000))], "ProjectedCSTypeGeoKey 65000"),
        ("geocentric.tif", vec![(1024, V::S(3))], "GTModelTypeGeoKey 3"),
        ("navd88.tif", vec![PROJECTED, (3072, V::S(32632)), (4096, V::S(5703))], "VerticalCSTypeGeoKey 5703"),
        ("feet.tif", vec![PROJECTED, (3072, V::S(2276)), (4099, V::S(9003))], "VerticalUnitsGeoKey 9003"),
        (
            "feet2.tif",
            vec![PROJECTED, (3072, V::S(32632)), (4096, V::S(5773)), (4099, V::S(9002))],
            "VerticalUnitsGeoKey 9002",
        ),
    ];
    for (name, keys, expect) in cases {
        let p = geotiff(dir.path(), name, (500_000.0, 5_000_000.0), 30.0, &keys);
        let e = load(&p).unwrap_err();
        let msg = e.to_string();
        assert!(matches!(e, RasterError::Crs { .. }), "{name}: {msg}");
        assert!(msg.contains(expect) && msg.contains(name), "{name}: {msg}");
        // The dataset path refuses the same way.
        let e = Dataset::open(&[p], &DatasetOptions::default(), &|_, _, _| {}).err().unwrap();
        assert!(e.to_string().contains(expect), "{name}: {e}");
    }
}

#[test]
fn vertical_keys() {
    let dir = tempfile::tempdir().unwrap();
    for (code, datum) in [(5773, VerticalDatum::Egm96), (3855, VerticalDatum::Egm2008)] {
        let keys = [PROJECTED, (3072, V::S(32632)), (4096, V::S(code)), (4099, V::S(9001))];
        let p = geotiff(dir.path(), "v.tif", (650_000.0, 5_170_000.0), 30.0, &keys);
        assert_eq!(load(&p).unwrap().vertical, datum, "VerticalCSTypeGeoKey {code}");
    }
    let p =
        geotiff(dir.path(), "none.tif", (650_000.0, 5_170_000.0), 30.0, &[PROJECTED, (3072, V::S(32632))]);
    assert_eq!(load(&p).unwrap().vertical, VerticalDatum::Ellipsoid);
}

// ---- LAS ----

/// A LAS file of a 3 × 3 grid of ground points, 10 units apart from `origin`, with `vlrs` and
/// the WKT bit of LAS 1.4 when `wkt`.
fn cloud(path: &Path, origin: (f64, f64), vlrs: Vec<las::Vlr>, wkt: bool) {
    let mut b = las::Builder::from((1, if wkt { 4 } else { 2 }));
    b.point_format = las::point::Format::new(1).unwrap();
    let t = |offset| las::Transform { scale: 0.001, offset };
    b.transforms = las::Vector { x: t(origin.0), y: t(origin.1), z: t(0.0) };
    b.vlrs = vlrs;
    b.has_wkt_crs = wkt;
    let mut w = las::Writer::from_path(path, b.into_header().unwrap()).unwrap();
    for i in 0..9 {
        let (x, y) = (origin.0 + f64::from(i % 3) * 10.0, origin.1 + f64::from(i / 3) * 10.0);
        let classification = las::point::Classification::Ground;
        w.write_point(las::Point {
            x,
            y,
            z: 200.0 + f64::from(i),
            classification,
            gps_time: Some(0.0),
            ..Default::default()
        })
        .unwrap();
    }
    w.close().unwrap();
}

fn vlr(record_id: u16, data: Vec<u8>) -> las::Vlr {
    las::Vlr { user_id: "LASF_Projection".into(), record_id, description: String::new(), data }
}

fn key_vlrs(keys: &[(u16, V)]) -> Vec<las::Vlr> {
    let (dir, doubles, ascii) = arrays(keys);
    let mut v = vec![vlr(34735, dir.iter().flat_map(|x| x.to_le_bytes()).collect())];
    if !doubles.is_empty() {
        v.push(vlr(34736, doubles.iter().flat_map(|x| x.to_le_bytes()).collect()));
    }
    if !ascii.is_empty() {
        v.push(vlr(34737, ascii.into_bytes()));
    }
    v
}

fn open_clouds(paths: &[PathBuf], crs: Option<Crs>) -> Result<Dataset, RasterError> {
    let overrides = Overrides { cell_size: Some(10.0), crs, ..Overrides::default() };
    let load = LoadOptions { overrides, ..LoadOptions::default() };
    Dataset::open(paths, &DatasetOptions { load, ..DatasetOptions::default() }, &|_, _, _| {})
}

#[test]
fn las_with_a_wkt_vlr() {
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("wkt.las");
    let mut wkt = crs_definitions::EPSG_32632.wkt.as_bytes().to_vec();
    wkt.push(0);
    cloud(&p, (650_000.0, 5_170_000.0), vec![vlr(2112, wkt)], true);
    let ds = open_clouds(std::slice::from_ref(&p), None).unwrap();
    let g = ds.georef();
    assert_eq!(g.crs.as_ref().unwrap().crs.epsg(), Some(32632));
    // The cell of the point at (650000, 5170000): the grid's bottom-left sample (rows go south).
    let (_, h) = ds.size();
    // PROJ: EPSG:32632 (650000, 5170000) → 10.9608834569, 46.6667526689.
    assert_within(
        "bottom-left cell",
        lonlat(g, 0.0, f64::from(h - 1)),
        (10.960_883_456_9, 46.666_752_668_9),
        1e-3,
    );
    // --crs replaces it.
    let ds = open_clouds(&[p], Some(Crs::from_epsg(32633).unwrap())).unwrap();
    assert_eq!(ds.georef().crs.as_ref().unwrap().crs.epsg(), Some(32633));
}

#[test]
fn las_with_geokey_vlrs() {
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("keys.las");
    let keys = [PROJECTED, USER_PCS, (3074, V::S(16032)), WGS84, (4096, V::S(5773)), (3073, V::A("UTM 32N"))];
    cloud(&p, (650_000.0, 5_170_000.0), key_vlrs(&keys), false);
    let ds = open_clouds(std::slice::from_ref(&p), None).unwrap();
    let g = ds.georef();
    assert!(g.crs.as_ref().unwrap().crs.definition().contains("UTM zone 32N"), "{:?}", g.crs);
    assert_eq!(g.vertical, VerticalDatum::Egm96);
    let (_, h) = ds.size();
    assert_within(
        "bottom-left cell",
        lonlat(g, 0.0, f64::from(h - 1)),
        (10.960_883_456_9, 46.666_752_668_9),
        1e-3,
    );
    // A second file in another CRS is refused, naming it.
    let q = dir.path().join("other.las");
    cloud(&q, (650_020.0, 5_170_000.0), key_vlrs(&[PROJECTED, (3072, V::S(32633))]), false);
    let e = open_clouds(&[p.clone(), q.clone()], None).err().unwrap().to_string();
    assert!(e.contains("other.las") && e.contains("EPSG:32633"), "{e}");
    // Unsupported keys are refused naming the key.
    let r = dir.path().join("bad.las");
    cloud(&r, (0.0, 0.0), key_vlrs(&[PROJECTED, USER_PCS, (3075, V::S(3)), WGS84]), false);
    let e = open_clouds(&[r], None).err().unwrap().to_string();
    assert!(e.contains("bad.las") && e.contains("ProjCoordTransGeoKey 3"), "{e}");
    // Without any CRS record: a local frame, as before.
    let s = dir.path().join("plain.las");
    cloud(&s, (0.0, 0.0), Vec::new(), false);
    assert_eq!(open_clouds(&[s], None).unwrap().georef().crs, None);
}
