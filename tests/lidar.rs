//! LAS/LAZ point clouds gridded into heightfields (issue 14): the rule against a hand-computed
//! grid, LAS and LAZ giving the same bake, and bad files refused naming them with nothing
//! written.

// Helpers outside `#[test]` functions unwrap too: a failure there is a test failure.
#![allow(clippy::unwrap_used, clippy::float_cmp, clippy::cast_lossless)]

mod common;
use common::{bin, blobs_and_index, fails, ok};

use std::path::{Path, PathBuf};

use las::point::Classification;
use terrastream::raster::dataset::{Dataset, DatasetOptions};
use terrastream::raster::{self, LoadOptions, Overrides, WindowReader};

/// Writes `points` (x, y, z, class) as LAS 1.2 (or LAZ by the extension), scale 0.001.
fn write_cloud(path: &Path, points: &[(f64, f64, f64, Classification)]) {
    let mut b = las::Builder::from((1, 2));
    b.point_format = las::point::Format::new(1).unwrap();
    let t = las::Transform { scale: 0.001, offset: 0.0 };
    b.transforms = las::Vector { x: t, y: t, z: t };
    let mut w = las::Writer::from_path(path, b.into_header().unwrap()).unwrap();
    for &(x, y, z, classification) in points {
        w.write_point(las::Point { x, y, z, classification, gps_time: Some(0.0), ..las::Point::default() })
            .unwrap();
    }
    w.close().unwrap();
}

fn open(paths: &[PathBuf], cell: f64) -> Result<Dataset, raster::RasterError> {
    let load = LoadOptions {
        overrides: Overrides { cell_size: Some(cell), ..Overrides::default() },
        ..LoadOptions::default()
    };
    Dataset::open(paths, &DatasetOptions { load, ..DatasetOptions::default() }, &|_, _, _| {})
}

/// Every sample of a dataset, row-major.
fn all(ds: &Dataset) -> Vec<f32> {
    let (w, h) = ds.size();
    let mut v = Vec::new();
    ds.read_window(&(0..w).collect::<Vec<_>>(), &(0..h).collect::<Vec<_>>(), &mut v).unwrap();
    v
}

#[test]
fn gridding_follows_the_documented_rule() {
    use Classification::{Building, CreatedNeverClassified as Never, Ground, HighVegetation, Unclassified};
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    // Classified: the mean of the ground points; other classes do not count.
    let a = d.join("a.las");
    write_cloud(
        &a,
        &[
            (10.2, 20.1, 5.0, Ground),
            (9.8, 19.7, 7.0, Ground),
            (10.0, 20.0, 100.0, HighVegetation),
            (12.0, 20.0, 50.0, Building),
            (11.0, 21.0, 3.0, Ground),
        ],
    );
    // Unclassified: the lowest point of each cell.
    let b = d.join("b.laz");
    write_cloud(
        &b,
        &[
            (13.0, 22.0, 8.0, Never),
            (13.2, 21.9, 4.0, Unclassified),
            (12.9, 22.3, 6.0, Never),
            (10.0, 22.0, 2.5, Never),
        ],
    );
    let ds = open(&[a.clone(), b.clone()], 1.0).unwrap();
    let s = ds.summary();
    // Columns x = 10..=13, rows y = 22 (top) ..= 20.
    assert_eq!((s.width, s.height, s.crs.as_str()), (4, 3, "local"));
    assert_eq!(s.extent, [10.0, 20.0, 13.0, 22.0]);
    assert_eq!(s.format, "las+laz");
    let p = s.points.clone().unwrap();
    assert_eq!((p.points, p.used, p.classified_files, p.cells_with_points), (9, 7, 1, 4));
    assert_eq!(s.nodata_filled, 12 - 4);
    let v = all(&ds);
    let at = |c: usize, r: usize| v[r * 4 + c];
    assert_eq!(at(0, 2), 6.0); // (10, 20): mean of 5 and 7; the vegetation point is left out
    assert_eq!(at(1, 1), 3.0); // (11, 21)
    assert_eq!(at(3, 0), 4.0); // (13, 22): lowest of 8, 4, 6
    assert_eq!(at(0, 0), 2.5); // (10, 22)
    // (12, 20) holds only a building point of a classified file: no-data, filled from neighbours.
    assert!(at(2, 2).is_finite() && at(2, 2) != 50.0);
    assert!(v.iter().all(|x| x.is_finite()));

    // The same cloud as one LAZ and as one LAS grid the same.
    let (l1, l2) = (d.join("c.las"), d.join("c.laz"));
    let cloud: Vec<_> = (0..500)
        .map(|i| (f64::from(i % 25) * 0.7, f64::from(i / 25) * 0.9, f64::from(i % 7), Never))
        .collect();
    write_cloud(&l1, &cloud);
    write_cloud(&l2, &cloud);
    let (g1, g2) = (open(&[l1], 0.5).unwrap(), open(&[l2], 0.5).unwrap());
    assert_eq!((g1.summary().format.as_str(), g2.summary().format.as_str()), ("las", "laz"));
    assert_eq!(all(&g1), all(&g2));
}

/// A terrain-like cloud: about 2 points per cell over `w × h` metres, ground and vegetation.
fn terrain_cloud(w: u32, h: u32) -> Vec<(f64, f64, f64, Classification)> {
    let mut pts = Vec::new();
    let mut seed = 12345u64;
    let mut rnd = || {
        seed = seed.wrapping_mul(6_364_136_223_846_793_005).wrapping_add(1_442_695_040_888_963_407);
        (seed >> 11) as f64 / (1u64 << 53) as f64
    };
    for _ in 0..(w * h * 2) {
        let (x, y) = (rnd() * f64::from(w), rnd() * f64::from(h));
        let ground = f64::from(raster::synth::height_at(w, h, 5, x as u32, y as u32)) * 0.05;
        let veg = rnd() < 0.3;
        let class = if veg { Classification::HighVegetation } else { Classification::Ground };
        pts.push((x, y, ground + if veg { 12.0 } else { 0.0 }, class));
    }
    pts
}

#[test]
fn las_and_laz_bake_the_same_tileset() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let cloud = terrain_cloud(160, 120);
    let (las_path, laz_path) = (d.join("survey.las"), d.join("survey.laz"));
    write_cloud(&las_path, &cloud);
    write_cloud(&laz_path, &cloud);
    let args = [
        "bake",
        "--quiet",
        "--tile-size",
        "64",
        "--max-error",
        "0.5",
        "--levels",
        "2",
        "--cell-size",
        "1",
        "--out",
    ];
    let (a, b) = (d.join("a"), d.join("b"));
    ok(bin().args(args).arg(&a).arg(&las_path));
    ok(bin().args(args).arg(&b).arg(&laz_path));
    let (ta, tb) = (blobs_and_index(&a), blobs_and_index(&b));
    assert!(ta.len() > 5);
    assert!(ta == tb, "LAS and LAZ bakes differ");
}

#[test]
fn bad_point_clouds_are_refused_naming_the_file_and_nothing_is_written() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let cloud = terrain_cloud(40, 30);
    let good_las = d.join("good.las");
    let good_laz = d.join("good.laz");
    write_cloud(&good_las, &cloud);
    write_cloud(&good_laz, &cloud);
    let las = std::fs::read(&good_las).unwrap();
    let laz = std::fs::read(&good_laz).unwrap();
    let patch = |bytes: &[u8], at: usize, with: &[u8]| {
        let mut b = bytes.to_vec();
        b[at..at + with.len()].copy_from_slice(with);
        b
    };
    let count = u32::try_from(cloud.len()).unwrap();
    // LAS 1.2 header: point count at 107, x scale at 131, max x at 179.
    let cases: Vec<(&str, Vec<u8>, &str)> = vec![
        ("truncated.las", las[..las.len() - 100].to_vec(), "truncated"),
        ("count.las", patch(&las, 107, &(count + 10).to_le_bytes()), "point count"),
        ("scale.las", patch(&las, 131, &0.0f64.to_le_bytes()), "x scale factor"),
        ("huge-scale.las", patch(&las, 131, &1e300f64.to_le_bytes()), "x scale factor"),
        ("bounds.las", patch(&las, 179, &5.0f64.to_le_bytes()), "outside the header's bounds"),
        ("nan-bounds.las", patch(&las, 179, &f64::NAN.to_le_bytes()), "x bounds"),
        ("zero.las", patch(&las, 107, &0u32.to_le_bytes()), "zero points"),
        ("header.las", las[..50].to_vec(), "header"),
        ("truncated.laz", laz[..laz.len() / 2].to_vec(), "LAZ"),
        ("count.laz", patch(&laz, 107, &(count + 10).to_le_bytes()), "LAZ"),
    ];
    for (name, bytes, needle) in cases {
        let p = d.join(name);
        std::fs::write(&p, bytes).unwrap();
        let out = d.join(format!("out-{name}"));
        let msg = fails(bin().args(["bake", "--quiet", "--cell-size", "1", "--out"]).arg(&out).arg(&p));
        eprintln!("{name}: {}", msg.trim());
        assert!(msg.contains(name) && msg.contains(needle), "{name}: {msg}");
        assert!(!out.exists(), "{name}: something was written");
    }
    // No cell size; a point cloud mixed with a raster.
    let out = d.join("out-nocell");
    let msg = fails(bin().args(["bake", "--quiet", "--out"]).arg(&out).arg(&good_las));
    assert!(msg.contains("--cell-size") && msg.contains("good.las"), "{msg}");
    let png = common::fuji_or_generated(d, "lidar: a point cloud mixed with a raster");
    let msg = fails(
        bin().args(["bake", "--quiet", "--cell-size", "1", "--out"]).arg(&out).arg(&good_las).arg(&png),
    );
    assert!(msg.contains("fuji.png") && msg.contains("point cloud"), "{msg}");
    assert!(!out.exists());
}
