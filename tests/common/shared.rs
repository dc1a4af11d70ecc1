//! The shared real test data (`../shared/data`, or `$TERRASTREAM_DATA`) or a printed skip, and
//! the generated stand-ins with which the default suite covers the same code paths on a clone
//! without that data. One rule for all of it, the library's
//! [`terrastream::raster::shared_test_data`]: a test that needs a real file skips with the
//! reason on stderr, unless `TERRASTREAM_REQUIRE_DATA=1` (CI sets it), where it fails.

use std::fmt::Write as _;
use std::io::Write as _;
use std::path::{Path, PathBuf};

/// `name` in the shared data, or `None` after printing that `what` is skipped (a failure
/// instead under `TERRASTREAM_REQUIRE_DATA=1`).
pub fn shared(name: &str, what: &str) -> Option<PathBuf> {
    terrastream::raster::shared_test_data(name, what)
}

/// `name` in the shared data when it is there (or required: then its absence fails); else the
/// file `make` writes into `dir`, after printing that `what` runs on that stand-in.
fn real_or(name: &str, what: &str, dir: &Path, make: impl FnOnce(&Path) -> PathBuf) -> PathBuf {
    let real = terrastream::raster::test_data_dir().join(name);
    if real.exists() || std::env::var("TERRASTREAM_REQUIRE_DATA").is_ok_and(|v| v == "1") {
        return shared(name, what).unwrap_or(real);
    }
    let p = make(dir);
    let _ = writeln!(
        std::io::stderr(),
        "{what}: {} not found, running on the generated {} instead",
        real.display(),
        p.display()
    );
    p
}

/// `fuji.png` (512×512 terrain-RGB, about 13 to 3751 m) from the shared data, or else
/// [`write_terrain_rgb_png`]'s stand-in of the same size and height range in `dir`.
pub fn fuji_or_generated(dir: &Path, what: &str) -> PathBuf {
    real_or("fuji.png", what, dir, |d| {
        let p = d.join("generated-fuji.png");
        write_terrain_rgb_png(&p, 512, 512, 7);
        p
    })
}

/// `stanford-bunny.obj` from the shared data, or else [`write_model_obj`]'s stand-in in `dir`.
pub fn bunny_or_generated(dir: &Path, what: &str) -> PathBuf {
    real_or("stanford-bunny.obj", what, dir, |d| {
        let p = d.join("generated-model.obj");
        write_model_obj(&p);
        p
    })
}

/// A Mapbox terrain-RGB PNG of generated terrain (`raster::synth`, scaled to about 13 to
/// 3760 m like fuji.png), in 0.1 m steps as the encoding stores them.
pub fn write_terrain_rgb_png(path: &Path, width: u32, height: u32, seed: u64) {
    let heights = terrastream::raster::synth::terrain(width, height, seed);
    let mut rgb = Vec::with_capacity(heights.len() * 3);
    for z in heights {
        let z = 13.0 + 1.5 * f64::from(z);
        let v = ((z + 10_000.0) * 10.0).round() as u32;
        rgb.extend_from_slice(&[(v >> 16) as u8, (v >> 8) as u8, v as u8]);
    }
    image::RgbImage::from_raw(width, height, rgb).unwrap().save(path).unwrap();
}

/// A closed, bumpy sphere as an OBJ (about 20,000 vertices, 40,000 triangles, some 0.15 units
/// across like the bunny): a model with detail at every scale the default point levels use.
pub fn write_model_obj(path: &Path) {
    let (rings, segments) = (100_u32, 200_u32);
    let mut s = String::from("# generated test model: a bumpy sphere\n");
    let radius = |theta: f64, phi: f64| 0.075 * (1.0 + 0.08 * (5.0 * theta).sin() * (7.0 * phi).cos());
    // Poles, then the rings between them.
    writeln!(s, "v 0 0 {}", radius(0.0, 0.0)).unwrap();
    writeln!(s, "v 0 0 {}", -radius(std::f64::consts::PI, 0.0)).unwrap();
    for i in 1..rings {
        let theta = std::f64::consts::PI * f64::from(i) / f64::from(rings);
        for j in 0..segments {
            let phi = std::f64::consts::TAU * f64::from(j) / f64::from(segments);
            let r = radius(theta, phi);
            writeln!(
                s,
                "v {} {} {}",
                r * theta.sin() * phi.cos(),
                r * theta.sin() * phi.sin(),
                r * theta.cos()
            )
            .unwrap();
        }
    }
    // 1-based OBJ indices: 1 north pole, 2 south pole, ring i (1..rings) segment j.
    let at = |i: u32, j: u32| 3 + (i - 1) * segments + j % segments;
    for j in 0..segments {
        writeln!(s, "f 1 {} {}", at(1, j), at(1, j + 1)).unwrap();
        writeln!(s, "f 2 {} {}", at(rings - 1, j + 1), at(rings - 1, j)).unwrap();
    }
    for i in 1..rings - 1 {
        for j in 0..segments {
            let (a, b, c, d) = (at(i, j), at(i, j + 1), at(i + 1, j + 1), at(i + 1, j));
            writeln!(s, "f {a} {d} {c}").unwrap();
            writeln!(s, "f {a} {c} {b}").unwrap();
        }
    }
    std::fs::write(path, s).unwrap();
}
