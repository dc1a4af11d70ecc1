//! Size and speed figures of the blob codec, on the codec tests' own inputs
//! (`src/codec/testdata.rs`): the Stanford Bunny, the real Fuji tile and a synthetic one, next
//! to Cesium quantized-mesh-1.0 + gzip; zstd levels per stream; normal predictors.
//!
//! `cargo run --release --example codec_figures [sizes] [zstd] [normals]` (all three when none
//! is named). The real data comes from `TERRASTREAM_DATA` (default `../shared/data`); what is
//! missing is skipped with a line saying so. With `TERRASTREAM_DUMP_POINTS=DIR`, `sizes` also
//! writes each point level's quantized points (decoded order) for a LAZ comparison.

// A failed step is the figure failing: unwrap says where.
#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]

use std::collections::HashMap;
use std::fmt::Write as _;
use std::time::Instant;

// `testdata.rs` names its imports `crate::…` (it is a module of the library's tests).
use terrastream::{geom, raster, tiling, tin};

#[path = "../src/codec/testdata.rs"]
mod testdata;

use terrastream::codec::{
    Geometry, PREFIX_LEN, Quantization, decode, decode_header, encode_mesh, encode_points, oct_encode,
};
use terrastream::geom::{Bounds, ErrorFigures};
use terrastream::tiling::TileKey;
use testdata::{bunny, fuji, greedy_tin, quantized_mesh_gzip, synthetic, tin_surface, voxel_points};

const KEY: TileKey = TileKey::new(3, 5, 6);
const ERRORS: ErrorFigures = ErrorFigures { max: 1.5, rms: 0.25, gap: 0.0 };

fn main() {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let want = |name: &str| args.is_empty() || args.iter().any(|a| a == name);
    if let Some(bad) = args.iter().find(|a| !["sizes", "zstd", "normals"].contains(&a.as_str())) {
        eprintln!("codec_figures: unknown figure {bad:?} (sizes, zstd, normals)");
        std::process::exit(2);
    }
    if want("sizes") {
        sizes();
    }
    if want("zstd") {
        zstd_levels();
    }
    if want("normals") {
        normal_predictors();
    }
}

/// One stored stream: method (0 stored, 1 zstd), raw length, stored bytes.
type Stream<'a> = (u8, usize, &'a [u8]);

/// The stream table of a blob's payload: `mode u8 | count u8 | (method u8, raw_len u32,
/// stored_len u32) × count | stored bytes…` (docs/formats.md), as (method, raw, stored bytes).
fn streams(blob: &[u8]) -> (u8, Vec<Stream<'_>>) {
    let p = &blob[PREFIX_LEN..];
    let count = usize::from(p[1]);
    let mut data = &p[2 + 9 * count..];
    let mut out = Vec::new();
    for i in 0..count {
        let e = &p[2 + 9 * i..11 + 9 * i];
        let raw = u32::from_le_bytes(e[1..5].try_into().unwrap()) as usize;
        let stored = u32::from_le_bytes(e[5..9].try_into().unwrap()) as usize;
        let (bytes, rest) = data.split_at(stored);
        out.push((e[0], raw, bytes));
        data = rest;
    }
    (p[0], out)
}

/// Per-stream sizes of a blob's payload (raw -> stored), for tuning.
fn stream_report(blob: &[u8]) -> String {
    let (mode, streams) = streams(blob);
    let mut out = format!("mode {mode}:");
    for (_, raw, stored) in streams {
        write!(out, " [{raw} -> {}]", stored.len()).unwrap();
    }
    out
}

fn ms(t: Instant) -> f64 {
    t.elapsed().as_secs_f64() * 1e3
}

/// Blob sizes and encode/decode times of meshes and point levels.
fn sizes() {
    if let Some(m) = bunny() {
        // A closed 3D model: the general coder. 0.1 mm steps on a model about 15 cm across.
        let b = Bounds::of_points(&m.positions);
        let q = Quantization { xy_step: 1e-4, z_step: 1e-4 };
        let t0 = Instant::now();
        let blob = encode_mesh(KEY, 0, &b, q, &m, ERRORS).unwrap();
        let enc = ms(t0);
        let t0 = Instant::now();
        decode(&blob).unwrap();
        let dec = ms(t0);
        let raw = m.positions.len() * 12 + m.triangles.len() * 12;
        println!(
            "bunny (general mode): {} vertices, {} triangles; blob {} B = {:.2} B/vertex (f32 + u32 arrays: {:.0} B/vertex); encode {enc:.1} ms, decode {dec:.1} ms",
            m.positions.len(),
            m.triangles.len(),
            blob.len(),
            blob.len() as f64 / m.positions.len() as f64,
            raw as f64 / m.positions.len() as f64,
        );
        println!("  {}", stream_report(&blob));
    } else {
        println!("bunny: stanford-bunny.obj not found, skipped");
    }
    let fields = [("fuji 512x512 @30m", fuji()), ("synthetic 513x513 @30m", Some(synthetic(513, 513, 30.0)))];
    for (name, hf) in fields {
        let Some(hf) = hf else {
            println!("{name}: data not found, skipped");
            continue;
        };
        let extent = (hf.w - 1) as f64 * hf.cell;
        for max_error in [1.0, 2.0, 5.0] {
            let m = greedy_tin(&hf, max_error);
            let b = Bounds::of_points(&m.positions);
            let b = Bounds::new([0.0, 0.0, b.min[2]], [extent, extent, b.max[2]]);
            for z_step in [0.1, 0.5] {
                let q = Quantization { xy_step: hf.cell, z_step };
                let t0 = Instant::now();
                let blob = encode_mesh(KEY, 0, &b, q, &m, ERRORS).unwrap();
                let enc = ms(t0);
                let t0 = Instant::now();
                let back = decode(&blob).unwrap();
                let dec = ms(t0);
                assert!(matches!(back.geometry, Geometry::Mesh(_)));
                println!("  {}", stream_report(&blob));
                let qm = quantized_mesh_gzip(&m, extent);
                let nv = m.positions.len() as f64;
                println!(
                    "{name} tin max_err {max_error} m, z_step {z_step}: {} vertices, {} triangles; blob {} B = {:.2} B/vertex; QM+gzip {qm} B = {:.2} B/vertex; ratio {:.3}; encode {enc:.1} ms, decode {dec:.1} ms",
                    m.positions.len(),
                    m.triangles.len(),
                    blob.len(),
                    blob.len() as f64 / nv,
                    qm as f64 / nv,
                    blob.len() as f64 / qm as f64,
                );
            }
        }
        let tin = greedy_tin(&hf, 2.0);
        let (surface, normals) = tin_surface(&hf, &tin);
        for cell in [60.0, 120.0] {
            for centres in [true, false] {
                let pc = voxel_points(&surface, Some(&normals), cell, centres);
                let b = Bounds::of_points(&pc.positions);
                let b = Bounds::new([0.0, 0.0, b.min[2]], [extent + cell, extent + cell, b.max[2]]);
                let q = Quantization { xy_step: cell / 64.0, z_step: cell / 64.0 };
                let t0 = Instant::now();
                let blob = encode_points(KEY, 1, &b, q, &pc, ERRORS).unwrap();
                let enc = ms(t0);
                let t0 = Instant::now();
                let back = decode(&blob).unwrap();
                let dec = ms(t0);
                if let (Some(dir), Geometry::Points(pts)) =
                    (std::env::var_os("TERRASTREAM_DUMP_POINTS"), &back.geometry)
                {
                    let mut text = String::new();
                    for (p, n) in pts.positions.iter().zip(&pts.normals) {
                        let qi: Vec<i64> =
                            (0..3).map(|a| ((p[a] - b.min[a]) / (cell / 64.0)).round() as i64).collect();
                        let o = oct_encode(*n).unwrap();
                        writeln!(text, "{} {} {} {} {}", qi[0], qi[1], qi[2], o[0], o[1]).unwrap();
                    }
                    let file = format!("{}-{cell}-{centres}.txt", name.split(' ').next().unwrap());
                    std::fs::write(std::path::Path::new(&dir).join(file), text).unwrap();
                }
                println!("  {}", stream_report(&blob));
                println!(
                    "{name} points of the 2 m TIN, cell {cell} m ({}): {} points; blob {} B = {:.3} B/point; encode {enc:.1} ms, decode {dec:.1} ms",
                    if centres { "voxel centres" } else { "sample means" },
                    pc.positions.len(),
                    blob.len(),
                    blob.len() as f64 / pc.positions.len() as f64,
                );
            }
        }
    }
}

/// Total stored size and compression time of real blobs' streams at several zstd levels.
fn zstd_levels() {
    let Some(hf) = fuji() else {
        println!("zstd: fuji.png not found, skipped");
        return;
    };
    let extent = 511.0 * 30.0;
    let m = greedy_tin(&hf, 2.0);
    let b = Bounds::of_points(&m.positions);
    let b = Bounds::new([0.0, 0.0, b.min[2]], [extent, extent, b.max[2]]);
    let mesh_blob = encode_mesh(KEY, 0, &b, Quantization { xy_step: 30.0, z_step: 0.1 }, &m, ERRORS).unwrap();
    let (surface, normals) = tin_surface(&hf, &m);
    let pc = voxel_points(&surface, Some(&normals), 60.0, true);
    let b = Bounds::of_points(&pc.positions);
    let q = Quantization { xy_step: 60.0 / 64.0, z_step: 60.0 / 64.0 };
    let points_blob = encode_points(KEY, 1, &b, q, &pc, ERRORS).unwrap();
    for (name, blob) in [("mesh", &mesh_blob), ("points", &points_blob)] {
        decode_header(blob).unwrap();
        let raw: Vec<Vec<u8>> = streams(blob)
            .1
            .into_iter()
            .map(
                |(method, raw, stored)| {
                    if method == 1 { zstd::bulk::decompress(stored, raw).unwrap() } else { stored.to_vec() }
                },
            )
            .collect();
        for level in [3, 9, 12, 15, 17, 19, 22] {
            let t0 = Instant::now();
            let total: usize =
                raw.iter().map(|r| zstd::bulk::compress(r, level).unwrap().len().min(r.len())).sum();
            println!("{name} level {level}: {total} B, {:.1} ms", ms(t0));
        }
    }
}

/// Order-0 entropy in bits of a sequence of values.
fn entropy<T: std::hash::Hash + Eq>(vals: impl Iterator<Item = T>) -> f64 {
    let mut m = HashMap::new();
    let mut n = 0usize;
    for v in vals {
        *m.entry(v).or_insert(0usize) += 1;
        n += 1;
    }
    let n = n as f64;
    m.values().map(|&c| -(c as f64 / n) * (c as f64 / n).log2()).sum::<f64>()
}

/// Median of three (the points coder's edge detector).
fn med(a: i64, b: i64, c: i64) -> i64 {
    if c >= a.max(b) {
        a.min(b)
    } else if c <= a.min(b) {
        a.max(b)
    } else {
        a + b - c
    }
}

/// Compares normal predictors (order-0 entropy, bits per point for u + v, and joint) on the
/// Fuji tile's point level at 60 m cells, in the order the points coder stores them.
fn normal_predictors() {
    let Some(hf) = fuji() else {
        println!("normals: fuji.png not found, skipped");
        return;
    };
    let tin = greedy_tin(&hf, 2.0);
    let (surface, normals) = tin_surface(&hf, &tin);
    let step = 60.0 / 64.0;
    for centres in [true, false] {
        let pc = voxel_points(&surface, Some(&normals), 60.0, centres);
        let q = Quantization { xy_step: step, z_step: step };
        let blob = encode_points(KEY, 1, &Bounds::of_points(&pc.positions), q, &pc, ERRORS).unwrap();
        let back = decode(&blob).unwrap();
        let Geometry::Points(back_pc) = back.geometry else { panic!("a points blob decoded as a mesh") };
        let min = back.header.bounds().min;
        let oct: Vec<[u8; 2]> = back_pc.normals.iter().map(|&n| oct_encode(n).unwrap()).collect();
        // Lattice coordinates in decoded order, and cells of 2^6 steps.
        let lattice: Vec<[i64; 2]> = back_pc
            .positions
            .iter()
            .map(|p| [((p[0] - min[0]) / step).round() as i64, ((p[1] - min[1]) / step).round() as i64])
            .collect();
        let shift = 6;
        let key = |i: usize| (lattice[i][1] >> shift, lattice[i][0] >> shift);
        let mut first: HashMap<(i64, i64), usize> = HashMap::default();
        for i in 0..lattice.len() {
            first.entry(key(i)).or_insert(i);
        }
        let mut res: Vec<Vec<(i16, i16)>> = vec![Vec::new(); 5];
        for i in 0..lattice.len() {
            let (cy, cx) = key(i);
            let prev = if i > 0 { oct[i - 1] } else { [127, 127] };
            let left = first.get(&(cy, cx - 1)).map(|&j| oct[j]);
            let up = first.get(&(cy - 1, cx)).map(|&j| oct[j]);
            let ul = first.get(&(cy - 1, cx - 1)).map(|&j| oct[j]);
            let o = oct[i];
            let r = |p: [u8; 2]| (i16::from(o[0]) - i16::from(p[0]), i16::from(o[1]) - i16::from(p[1]));
            res[0].push(r(prev));
            res[1].push(r(left.unwrap_or(prev)));
            res[2].push(r(up.unwrap_or(prev)));
            let avg = match (left, up) {
                (Some(a), Some(b)) => [u8::midpoint(a[0], b[0]), u8::midpoint(a[1], b[1])],
                _ => left.or(up).unwrap_or(prev),
            };
            res[3].push(r(avg));
            let medp = match (left, up, ul) {
                (Some(a), Some(b), Some(c)) => {
                    [0, 1].map(|k| med(i64::from(a[k]), i64::from(b[k]), i64::from(c[k])).clamp(0, 255) as u8)
                }
                _ => avg,
            };
            res[4].push(r(medp));
        }
        for (name, r) in ["prev", "left", "up", "avg", "med"].iter().zip(&res) {
            let hu = entropy(r.iter().map(|x| x.0));
            let hv = entropy(r.iter().map(|x| x.1));
            let hj = entropy(r.iter().copied());
            println!("centres {centres} {name}: H(u) + H(v) = {:.2}, H(u, v) = {hj:.2} bits", hu + hv);
        }
    }
}
