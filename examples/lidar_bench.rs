//! The LAS/LAZ gridding benchmark's two halves (run by `bench/lidar.sh`):
//!
//! - `lidar_bench write N W H OUT.las|OUT.laz` writes N points spread uniformly over W × H metres
//!   of generated terrain (70 % ground, class 2; 30 % vegetation 2–20 m above it, class 5),
//!   LAS 1.2 point format 1, millimetre scale; LAZ by the extension.
//! - `lidar_bench grid FILE CELL` opens FILE as a dataset gridded at CELL (reading, bucketing,
//!   reducing and the opening scan) and prints the time, points per second and the process's peak
//!   RSS.

// A benchmark driver: a failure is a crash with the message.
#![allow(clippy::unwrap_used, clippy::expect_used)]

use std::path::PathBuf;
use std::time::Instant;

use las::point::Classification;
use terrastream::raster::dataset::{Dataset, DatasetOptions};
use terrastream::raster::{LoadOptions, Overrides, synth};

fn peak_rss_mib() -> f64 {
    let status = std::fs::read_to_string("/proc/self/status").unwrap_or_default();
    status
        .lines()
        .find(|l| l.starts_with("VmHWM:"))
        .and_then(|l| l.split_whitespace().nth(1)?.parse::<f64>().ok())
        .map_or(f64::NAN, |kib| kib / 1024.0)
}

fn main() {
    let args: Vec<String> = std::env::args().collect();
    match args.get(1).map(String::as_str) {
        Some("write") if args.len() == 6 => {
            let n: u64 = args[2].parse().expect("N");
            let (w, h): (u32, u32) = (args[3].parse().expect("W"), args[4].parse().expect("H"));
            let out = PathBuf::from(&args[5]);
            let t = Instant::now();
            let mut b = las::Builder::from((1, 2));
            b.point_format = las::point::Format::new(1).unwrap();
            let tr = las::Transform { scale: 0.001, offset: 0.0 };
            b.transforms = las::Vector { x: tr, y: tr, z: tr };
            let mut wr = las::Writer::from_path(&out, b.into_header().unwrap()).unwrap();
            let mut seed = 0x9E37_79B9_7F4A_7C15u64;
            let mut rnd = || {
                seed = seed.wrapping_mul(6_364_136_223_846_793_005).wrapping_add(1_442_695_040_888_963_407);
                (seed >> 11) as f64 / (1u64 << 53) as f64
            };
            for _ in 0..n {
                let (x, y) = (rnd() * f64::from(w), rnd() * f64::from(h));
                let ground = f64::from(synth::height_at(w, h, 11, x as u32, y as u32)) * 0.2;
                let veg = rnd() < 0.3;
                let (z, classification) = if veg {
                    (ground + 2.0 + 18.0 * rnd(), Classification::MediumVegetation)
                } else {
                    (ground, Classification::Ground)
                };
                wr.write_point(las::Point {
                    x,
                    y,
                    z,
                    classification,
                    gps_time: Some(0.0),
                    ..las::Point::default()
                })
                .unwrap();
            }
            wr.close().unwrap();
            let bytes = std::fs::metadata(&out).map_or(0, |m| m.len());
            println!(
                "wrote {} ({n} points, {:.1} MB) in {:.1} s",
                out.display(),
                bytes as f64 / 1e6,
                t.elapsed().as_secs_f64()
            );
        }
        Some("grid") if args.len() == 4 => {
            let path = PathBuf::from(&args[2]);
            let cell: f64 = args[3].parse().expect("CELL");
            let load = LoadOptions {
                overrides: Overrides { cell_size: Some(cell), ..Overrides::default() },
                ..LoadOptions::default()
            };
            let t = Instant::now();
            let ds = Dataset::open(
                std::slice::from_ref(&path),
                &DatasetOptions { load, ..DatasetOptions::default() },
                &|_, _, _| {},
            )
            .unwrap_or_else(|e| {
                eprintln!("{e}");
                std::process::exit(1)
            });
            let secs = t.elapsed().as_secs_f64();
            let s = ds.summary();
            let p = s.points.clone().unwrap_or_default();
            println!(
                "gridded {}: {} points ({} used) into {}×{} cells ({} with points) in {secs:.2} s: {:.2} M points/s, \
                 peak RSS {:.0} MiB",
                path.display(),
                p.points,
                p.used,
                s.width,
                s.height,
                p.cells_with_points,
                p.points as f64 / secs / 1e6,
                peak_rss_mib()
            );
        }
        _ => {
            eprintln!("usage: lidar_bench write N W H OUT.las|OUT.laz | lidar_bench grid FILE CELL");
            std::process::exit(2);
        }
    }
}
