//! WGS 84 geodetic coordinates and Earth-centred, Earth-fixed (ECEF, EPSG:4978) ones, and the
//! east-north-up frames between them. Longitudes and latitudes in degrees, heights in metres
//! above the WGS 84 ellipsoid.

/// WGS 84 semi-major axis, metres.
pub const A: f64 = 6_378_137.0;
/// The Earth's mean radius (metres): the sphere a bake lowers a node's heights by to keep chord
/// sag inside a TIN's measured error, and that the heights samplers undo.
pub const MEAN_RADIUS: f64 = 6_371_000.0;
/// WGS 84 flattening.
pub const F: f64 = 1.0 / 298.257_223_563;
/// First eccentricity squared.
pub const E2: f64 = F * (2.0 - F);

/// ECEF position of a geodetic point.
#[must_use]
pub fn from_geodetic(lon: f64, lat: f64, h: f64) -> [f64; 3] {
    let (phi, lam) = (lat.to_radians(), lon.to_radians());
    let n = A / (1.0 - E2 * phi.sin() * phi.sin()).sqrt();
    [(n + h) * phi.cos() * lam.cos(), (n + h) * phi.cos() * lam.sin(), (n * (1.0 - E2) + h) * phi.sin()]
}

/// Geodetic (lon, lat, h) of an ECEF position (Bowring's method refined by iteration: below a
/// micrometre anywhere from the centre of the Earth's crust to orbit); longitude in −180..180.
#[must_use]
pub fn to_geodetic(p: [f64; 3]) -> (f64, f64, f64) {
    let [x, y, z] = p;
    let lon = y.atan2(x).to_degrees();
    let r = x.hypot(y);
    let b = A * (1.0 - F);
    if r < 1e-9 {
        let lat = if z >= 0.0 { 90.0 } else { -90.0 };
        return (lon, lat, z.abs() - b);
    }
    let ep2 = (A * A - b * b) / (b * b);
    let theta = (z * A).atan2(r * b);
    let mut phi = (z + ep2 * b * theta.sin().powi(3)).atan2(r - E2 * A * theta.cos().powi(3));
    let mut h = 0.0;
    for _ in 0..4 {
        let n = A / (1.0 - E2 * phi.sin() * phi.sin()).sqrt();
        h = r / phi.cos() - n;
        if phi.cos().abs() < 1e-12 {
            h = z.abs() - b;
            break;
        }
        phi = (z / r / (1.0 - E2 * n / (n + h))).atan();
    }
    (lon, phi.to_degrees(), h)
}

/// The east-north-up frame at a geodetic point as a column-major 4×4 matrix (3D Tiles'
/// `transform` layout): local (east, north, up) metres → ECEF.
#[must_use]
pub fn enu_to_ecef(lon: f64, lat: f64, h: f64) -> [f64; 16] {
    let (phi, lam) = (lat.to_radians(), lon.to_radians());
    let east = [-lam.sin(), lam.cos(), 0.0];
    let north = [-phi.sin() * lam.cos(), -phi.sin() * lam.sin(), phi.cos()];
    let up = [phi.cos() * lam.cos(), phi.cos() * lam.sin(), phi.sin()];
    let o = from_geodetic(lon, lat, h);
    [
        east[0], east[1], east[2], 0.0, north[0], north[1], north[2], 0.0, up[0], up[1], up[2], 0.0, o[0],
        o[1], o[2], 1.0,
    ]
}

/// ECEF → local east-north-up at the frame `m` made by [`enu_to_ecef`] (its inverse: the
/// rotation is orthonormal).
#[must_use]
pub fn ecef_to_enu(m: &[f64; 16], p: [f64; 3]) -> [f64; 3] {
    let d = [p[0] - m[12], p[1] - m[13], p[2] - m[14]];
    std::array::from_fn(|k| m[4 * k] * d[0] + m[4 * k + 1] * d[1] + m[4 * k + 2] * d[2])
}

/// Local east-north-up → ECEF through the frame `m`.
#[must_use]
pub fn enu_to_ecef_point(m: &[f64; 16], e: [f64; 3]) -> [f64; 3] {
    std::array::from_fn(|k| m[k] * e[0] + m[4 + k] * e[1] + m[8 + k] * e[2] + m[12 + k])
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn geodetic_round_trips_everywhere() {
        for lat in [-90.0, -89.999, -45.0, 0.0, 12.5, 57.3, 89.9999, 90.0] {
            for lon in [-180.0, -179.999, 0.0, 10.0, 179.999] {
                for h in [-11_000.0, 0.0, 8_848.0, 400_000.0] {
                    let (lo, la, hh) = to_geodetic(from_geodetic(lon, lat, h));
                    assert!((la - lat).abs() < 1e-9, "{lon} {lat} {h}: lat {la}");
                    if lat.abs() < 90.0 {
                        let dl = (lo - lon + 540.0).rem_euclid(360.0) - 180.0;
                        assert!(dl.abs() < 1e-9, "{lon} {lat} {h}: lon {lo}");
                    }
                    assert!((hh - h).abs() < 1e-6, "{lon} {lat} {h}: h {hh}");
                }
            }
        }
    }

    #[test]
    fn known_ecef_positions() {
        let p = from_geodetic(0.0, 0.0, 0.0);
        assert!((p[0] - A).abs() < 1e-9 && p[1].abs() < 1e-9 && p[2].abs() < 1e-9);
        let p = from_geodetic(0.0, 90.0, 0.0);
        assert!((p[2] - 6_356_752.314_245).abs() < 1e-3, "{p:?}");
    }

    #[test]
    fn enu_frame_inverts() {
        let m = enu_to_ecef(138.7, 35.36, 100.0);
        let p = [123.0, -456.0, 789.0];
        let back = ecef_to_enu(&m, enu_to_ecef_point(&m, p));
        for k in 0..3 {
            assert!((back[k] - p[k]).abs() < 1e-8);
        }
    }
}
