#![allow(clippy::float_cmp)] // exact values on exact grids: equality is the check

use super::*;
use crate::crs::{Crs, CrsGrid, VerticalDatum};
use crate::raster::Heightfield;

/// A `w × h` raster whose sample (c, r) is `f(c, r)`.
fn raster(w: u32, h: u32, f: impl Fn(f64, f64) -> f64) -> Heightfield {
    let mut data = Vec::with_capacity((w * h) as usize);
    for r in 0..h {
        for c in 0..w {
            data.push(f(f64::from(c), f64::from(r)) as f32);
        }
    }
    Heightfield { width: w, height: h, data }
}

fn local(dx: f64) -> Georef {
    Georef { x0: 100.0, y0: 200.0, dx, dy: dx, ..Georef::default() }
}

fn q(coords: Coords, interp: Interp, datum: Datum) -> Query {
    Query { coords, interp, datum }
}

#[test]
fn local_frame_interpolates_a_plane_exactly() {
    // z = 3 + 0.5·c − 0.25·r: bilinear and cubic reproduce a plane inside the grid.
    let hf = raster(20, 10, |c, r| 3.0 + 0.5 * c - 0.25 * r);
    let s = SourceSampler::new(&hf, &local(2.0)).unwrap();
    let pts = [[100.0 + 2.0 * 7.3, 200.0 + 2.0 * 4.6], [100.0 + 2.0 * 12.5, 200.0 + 2.0 * 2.25]];
    for interp in [Interp::Bilinear, Interp::Cubic] {
        let a = s.sample(&pts, q(Coords::Local, interp, Datum::Native)).unwrap();
        for (p, h) in pts.iter().zip(&a) {
            let (c, r) = ((p[0] - 100.0) / 2.0, (p[1] - 200.0) / 2.0);
            let want = 3.0 + 0.5 * c - 0.25 * r;
            assert!((h.h - want).abs() < 1e-5, "{interp:?} at {p:?}: {} vs {want}", h.h);
            assert!(!h.nodata);
            // The bound covers the plane's rise across the samples weighed.
            assert!(h.error > 0.0 && h.error < 2.0, "{interp:?}: {}", h.error);
        }
    }
    let n = s.sample(&pts, q(Coords::Local, Interp::Nearest, Datum::Native)).unwrap();
    // (7.3, 4.6) → sample (7, 5); (12.5, 2.25) → (13, 2): halves round up.
    assert_eq!(n[0].h, 3.0 + 0.5 * 7.0 - 0.25 * 5.0);
    assert_eq!(n[1].h, 3.0 + 0.5 * 13.0 - 0.25 * 2.0);
}

#[test]
fn cubic_differs_from_bilinear_on_a_curve_and_is_closer() {
    // z = c²: cubic convolution is exact for quadratics away from the edge; bilinear is not.
    let hf = raster(16, 4, |c, _| c * c);
    let s = SourceSampler::new(&hf, &local(1.0)).unwrap();
    let p = [[100.0 + 6.5, 200.0 + 1.0]];
    let cubic = s.sample(&p, q(Coords::Local, Interp::Cubic, Datum::Native)).unwrap()[0];
    let lin = s.sample(&p, q(Coords::Local, Interp::Bilinear, Datum::Native)).unwrap()[0];
    assert!((cubic.h - 42.25).abs() < 1e-4, "{}", cubic.h);
    assert!((lin.h - 42.5).abs() < 1e-4, "{}", lin.h);
}

#[test]
fn outside_the_data_is_no_data_and_edges_are_inside() {
    let hf = raster(4, 4, |c, r| c + r);
    let s = SourceSampler::new(&hf, &local(1.0)).unwrap();
    let pts = [[100.0 - 0.5, 200.0], [100.0 - 0.51, 200.0], [100.0 + 3.5, 200.0 + 3.5], [100.0 + 3.6, 200.0]];
    let a = s.sample(&pts, q(Coords::Local, Interp::Bilinear, Datum::Native)).unwrap();
    assert_eq!(a.iter().map(|h| h.nodata).collect::<Vec<_>>(), [false, true, false, true]);
    assert!(a[1].h.is_nan() && a[1].error.is_nan());
    assert_eq!(a[2].h, 6.0);
}

#[test]
fn an_unplaced_dataset_answers_local_native_only() {
    let hf = raster(4, 4, |_, _| 1.0);
    let s = SourceSampler::new(&hf, &local(1.0)).unwrap();
    let e = s.sample(&[[0.0, 0.0]], q(Coords::Wgs84, Interp::Bilinear, Datum::Ellipsoid)).unwrap_err();
    assert!(e.to_string().contains("no coordinate reference system"), "{e}");
    let e = s.sample(&[[100.0, 200.0]], q(Coords::Local, Interp::Bilinear, Datum::Geoid)).unwrap_err();
    assert!(e.to_string().contains("datum=geoid"), "{e}");
}

/// A UTM 32N raster with orthometric (EGM96) heights `h = 0.01·(E − 600000) + 0.02·(N − 5199000)`,
/// 30 m cells from (600000, 5200000) southwards.
fn utm() -> (Heightfield, Georef) {
    let (e0, n0, d) = (600_000.0, 5_200_000.0, 30.0);
    let hf = raster(40, 40, |c, r| 0.01 * (c * d) + 0.02 * (n0 - r * d - 5_199_000.0));
    let g = Georef::projected_egm96(32632, e0, n0, d);
    (hf, g)
}

#[test]
fn utm_heights_at_lon_lat_match_an_independent_transform_and_geoid() {
    let (hf, g) = utm();
    let s = SourceSampler::new(&hf, &g).unwrap();
    // (600300, 5199400) in EPSG:32632 is 10.317839413745°, 46.940545136845° (pyproj 3.7, PROJ
    // 9); EGM96 there is 49.644 m (bilinear in PROJ's egm96_15.gtx).
    let want = 0.01 * 300.0 + 0.02 * 400.0;
    let p = [[10.317_839_413_745, 46.940_545_136_845]];
    for interp in [Interp::Nearest, Interp::Bilinear, Interp::Cubic] {
        let native = s.sample(&p, q(Coords::Wgs84, interp, Datum::Native)).unwrap()[0];
        assert!((native.h - want).abs() < 1e-3, "{interp:?}: {} vs {want}", native.h);
        let geoid = s.sample(&p, q(Coords::Wgs84, interp, Datum::Geoid)).unwrap()[0];
        assert!((geoid.h - want).abs() < 1e-3, "{interp:?}: orthometric source: {}", geoid.h);
        let ell = s.sample(&p, q(Coords::Wgs84, interp, Datum::Ellipsoid)).unwrap()[0];
        assert!((ell.h - want - 49.644).abs() < 0.01, "{interp:?}: {} vs {}", ell.h, want + 49.644);
    }
    // The same place in the CRS and in the world frame.
    let crs = s.sample(&[[600_300.0, 5_199_400.0]], q(Coords::Crs, Interp::Bilinear, Datum::Native)).unwrap();
    let world =
        s.sample(&[[600_300.0, 5_199_400.0]], q(Coords::Local, Interp::Bilinear, Datum::Native)).unwrap();
    assert!((crs[0].h - want).abs() < 1e-4 && (world[0].h - want).abs() < 1e-4);
}

#[test]
fn longitudes_wrap_and_bad_points_are_refused_by_index() {
    // A geographic raster across the antimeridian's east side: −170…−160°, 0…10° N.
    let hf = raster(11, 11, |c, r| 100.0 + c + 10.0 * r);
    let grid = CrsGrid { crs: Crs::wgs84(), e0: -170.0, n0: 10.0, de: 1.0, dn: -1.0 };
    let g = Georef {
        crs: Some(grid),
        vertical: VerticalDatum::Ellipsoid,
        dx: 1.0,
        dy: -1.0,
        ..Georef::default()
    };
    let s = SourceSampler::new(&hf, &g).unwrap();
    let a = s
        .sample(&[[-165.0, 5.0], [195.0, 5.0]], q(Coords::Wgs84, Interp::Bilinear, Datum::Ellipsoid))
        .unwrap();
    assert_eq!(a[0].h, 100.0 + 5.0 + 50.0);
    assert_eq!(a[0].h.to_bits(), a[1].h.to_bits(), "195° is −165°");
    // Ellipsoidal source, geoid datum: minus EGM96 (11.679 m at −170°, 10° N).
    let geo = s.sample(&[[-170.0, 10.0]], q(Coords::Wgs84, Interp::Bilinear, Datum::Geoid)).unwrap();
    assert!((geo[0].h - (100.0 - 11.679)).abs() < 0.01, "{}", geo[0].h);
    let all = q(Coords::Wgs84, Interp::Bilinear, Datum::Ellipsoid);
    for (pts, what) in [
        (vec![[0.0, 0.0], [f64::NAN, 1.0]], "point 1: coordinate NaN"),
        (vec![[0.0, 91.0]], "point 0: latitude 91"),
        (vec![[0.0, 0.0], [0.0, 0.0], [361.0, 0.0]], "point 2: longitude 361"),
        (vec![[f64::INFINITY, 0.0]], "point 0: coordinate inf"),
    ] {
        let e = s.sample(&pts, all).unwrap_err().to_string();
        assert!(e.starts_with(what), "{e}");
    }
}

#[test]
fn answers_are_deterministic_and_ordered() {
    let (hf, g) = utm();
    let s = SourceSampler::new(&hf, &g).unwrap();
    let pts: Vec<[f64; 2]> =
        (0..50).map(|k| [600_000.0 + 23.7 * f64::from(k), 5_199_000.0 + 11.3 * f64::from(k)]).collect();
    let one = s.sample(&pts, q(Coords::Crs, Interp::Cubic, Datum::Ellipsoid)).unwrap();
    let rev: Vec<[f64; 2]> = pts.iter().rev().copied().collect();
    let two = s.sample(&rev, q(Coords::Crs, Interp::Cubic, Datum::Ellipsoid)).unwrap();
    for (a, b) in one.iter().zip(two.iter().rev()) {
        assert_eq!(a.h.to_bits(), b.h.to_bits());
    }
}
