//! Test inputs for the codec: synthetic and real heightfields, their TIN from the `tin` stage
//! (realistic vertex layouts), voxel-walk point clouds (a stand-in for `lod`), and a Cesium
//! quantized-mesh-1.0 writer for size comparisons.
//!
//! `examples/codec_figures.rs` includes this file too (by path), so the figures it prints are
//! of the same inputs the tests use; each side uses only some of the helpers.

// Exact float equality is the point of these tests: decoding must be bit-exact.
#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic, clippy::float_cmp)]
#![allow(dead_code)]

use std::io::Write;

use crate::geom::{Mesh, PointCloud};

/// A row-major heightfield in metres with square cells of `cell` metres.
pub struct Heights {
    pub w: usize,
    pub h: usize,
    pub cell: f64,
    pub z: Vec<f64>,
}

impl Heights {
    pub fn at(&self, c: usize, r: usize) -> f64 {
        self.z[r * self.w + c]
    }

    /// Unit surface normal at a grid sample, by central differences.
    pub fn normal(&self, c: usize, r: usize) -> [f32; 3] {
        let (c0, c1) = (c.saturating_sub(1), (c + 1).min(self.w - 1));
        let (r0, r1) = (r.saturating_sub(1), (r + 1).min(self.h - 1));
        let dzdx = (self.at(c1, r) - self.at(c0, r)) / ((c1 - c0).max(1) as f64 * self.cell);
        let dzdy = (self.at(c, r1) - self.at(c, r0)) / ((r1 - r0).max(1) as f64 * self.cell);
        let n = [-dzdx, -dzdy, 1.0];
        let l = (n[0] * n[0] + n[1] * n[1] + 1.0).sqrt();
        [(n[0] / l) as f32, (n[1] / l) as f32, (n[2] / l) as f32]
    }
}

/// Smooth hills with ridges, heights quantized to 0.1 m like a terrain-RGB tile.
pub fn synthetic(w: usize, h: usize, cell: f64) -> Heights {
    let mut z = Vec::with_capacity(w * h);
    for r in 0..h {
        for c in 0..w {
            let (x, y) = (c as f64 * cell, r as f64 * cell);
            let v = 400.0 * (x / 2500.0).sin() * (y / 3100.0).cos()
                + 150.0 * ((x + 2.0 * y) / 900.0).sin().abs()
                + 40.0 * ((x * 0.7 - y) / 210.0).cos()
                + 900.0;
            z.push((v * 10.0).round() / 10.0);
        }
    }
    Heights { w, h, cell, z }
}

/// `name` in the shared test data, or `None` after printing the skip (the tests' one "shared data
/// or skip" rule, [`crate::raster::shared_test_data`]: fails under `TERRASTREAM_REQUIRE_DATA=1`).
pub fn data_file(name: &str) -> Option<std::path::PathBuf> {
    crate::raster::shared_test_data(name, "a codec figure on the shared data")
}

/// The Mt. Fuji terrain-RGB tile at 30 m cells, if present.
pub fn fuji() -> Option<Heights> {
    let img = image::open(data_file("fuji.png")?).ok()?.to_rgb8();
    let (w, h) = (img.width() as usize, img.height() as usize);
    let z = img
        .pixels()
        .map(|p| {
            let v = f64::from(p[0]) * 65536.0 + f64::from(p[1]) * 256.0 + f64::from(p[2]);
            ((-10000.0 + v * 0.1) * 10.0).round() / 10.0
        })
        .collect();
    Some(Heights { w, h, cell: 30.0, z })
}

/// The Stanford Bunny (a closed 3D mesh, not a TIN), if present.
pub fn bunny() -> Option<Mesh> {
    let text = std::fs::read_to_string(data_file("stanford-bunny.obj")?).ok()?;
    let mut m = Mesh::default();
    for line in text.lines() {
        let mut it = line.split_whitespace();
        match it.next() {
            Some("v") => {
                let v: Vec<f64> = it.take(3).map(|t| t.parse().unwrap()).collect();
                m.positions.push([v[0], v[1], v[2]]);
            }
            Some("f") => {
                let idx: Vec<u32> =
                    it.map(|t| t.split('/').next().unwrap().parse::<u32>().unwrap() - 1).collect();
                for i in 1..idx.len() - 1 {
                    m.triangles.push([idx[0], idx[i], idx[i + 1]]);
                }
            }
            _ => {}
        }
    }
    Some(m)
}

/// The `tin` stage's mesh of the whole heightfield (every sample within `max_error` of it);
/// positions in world units (x = col·cell, y = row·cell, z the sample's own height).
pub fn greedy_tin(hf: &Heights, max_error: f64) -> Mesh {
    let grid = crate::tiling::NodeGrid { cols: (0..hf.w as u32).collect(), rows: (0..hf.h as u32).collect() };
    let heights: Vec<f32> = hf.z.iter().map(|&z| z as f32).collect();
    let tin = crate::tin::build(&grid, &heights, max_error).unwrap();
    let positions = tin
        .vertices
        .iter()
        .map(|&[c, r]| [f64::from(c) * hf.cell, f64::from(r) * hf.cell, hf.at(c as usize, r as usize)])
        .collect();
    Mesh { positions, triangles: tin.triangles }
}

/// Voxel walk: one point per voxel of edge `cell_m` that the surface passes through. With
/// `centres` the point is the voxel centre (a lattice); otherwise the mean of the raster samples
/// in the voxel (continuous positions). Normals are the surface normals at a nearby sample.
pub fn voxel_points(hf: &Heights, normals: Option<&[[f32; 3]]>, cell_m: f64, centres: bool) -> PointCloud {
    let k = (cell_m / hf.cell).round().max(1.0) as usize;
    let mut pc = PointCloud::default();
    for j in 0..hf.h.div_ceil(k) {
        for i in 0..hf.w.div_ceil(k) {
            // Samples of the column, bucketed by voxel layer.
            let mut layers: std::collections::BTreeMap<i64, (f64, f64, f64, usize)> =
                std::collections::BTreeMap::default();
            for r in j * k..((j + 1) * k + 1).min(hf.h) {
                for c in i * k..((i + 1) * k + 1).min(hf.w) {
                    let z = hf.at(c, r);
                    let e = layers.entry((z / cell_m).floor() as i64).or_default();
                    e.0 += c as f64 * hf.cell;
                    e.1 += r as f64 * hf.cell;
                    e.2 += z;
                    e.3 += 1;
                }
            }
            // Fill layers between the lowest and highest so steep columns are closed.
            let (lo, hi) = (*layers.keys().next().unwrap(), *layers.keys().last().unwrap());
            for layer in lo..=hi {
                let centre =
                    [(i as f64 + 0.5) * cell_m, (j as f64 + 0.5) * cell_m, (layer as f64 + 0.5) * cell_m];
                let p = match (centres, layers.get(&layer)) {
                    (false, Some(&(x, y, z, n))) => [x / n as f64, y / n as f64, z / n as f64],
                    _ => centre,
                };
                let (c, r) = (
                    ((p[0] / hf.cell).round() as usize).min(hf.w - 1),
                    ((p[1] / hf.cell).round() as usize).min(hf.h - 1),
                );
                pc.positions.push(p);
                pc.normals.push(normals.map_or_else(|| hf.normal(c, r), |n| n[r * hf.w + c]));
            }
        }
    }
    pc
}

/// A TIN's surface sampled on the raster grid: heights, and per sample the normal of the
/// triangle over it (what a point level baked from the TIN sees).
pub fn tin_surface(hf: &Heights, mesh: &Mesh) -> (Heights, Vec<[f32; 3]>) {
    let mut z = hf.z.clone();
    let mut normals = vec![[0.0f32, 0.0, 1.0]; hf.w * hf.h];
    for t in &mesh.triangles {
        let p = t.map(|i| mesh.positions[i as usize]);
        let g = p.map(|v| [v[0] / hf.cell, v[1] / hf.cell, v[2]]);
        let n = crate::geom::triangle_normal(p[0], p[1], p[2]).map(|v| v as f32);
        let d = (g[1][0] - g[0][0]) * (g[2][1] - g[0][1]) - (g[1][1] - g[0][1]) * (g[2][0] - g[0][0]);
        if d == 0.0 {
            continue;
        }
        let x0 = g.iter().map(|v| v[0]).fold(f64::MAX, f64::min) as usize;
        let x1 = g.iter().map(|v| v[0]).fold(f64::MIN, f64::max) as usize;
        let y0 = g.iter().map(|v| v[1]).fold(f64::MAX, f64::min) as usize;
        let y1 = g.iter().map(|v| v[1]).fold(f64::MIN, f64::max) as usize;
        for r in y0..=y1 {
            for c in x0..=x1 {
                let (x, y) = (c as f64, r as f64);
                let b1 = ((x - g[0][0]) * (g[2][1] - g[0][1]) - (y - g[0][1]) * (g[2][0] - g[0][0])) / d;
                let b2 = ((g[1][0] - g[0][0]) * (y - g[0][1]) - (g[1][1] - g[0][1]) * (x - g[0][0])) / d;
                let b0 = 1.0 - b1 - b2;
                if b0 < -1e-9 || b1 < -1e-9 || b2 < -1e-9 {
                    continue;
                }
                z[r * hf.w + c] = b0 * g[0][2] + b1 * g[1][2] + b2 * g[2][2];
                normals[r * hf.w + c] = n;
            }
        }
    }
    (Heights { w: hf.w, h: hf.h, cell: hf.cell, z }, normals)
}

/// Cesium quantized-mesh-1.0 (no extensions) of a tile mesh with x, y in `0..=extent` metres,
/// gzipped at the default level, as servers ship it.
pub fn quantized_mesh_gzip(mesh: &Mesh, extent: f64) -> usize {
    quantized_mesh_gzip_ordered(mesh, extent).min(quantized_mesh_gzip_ordered(&reorder(mesh), extent))
}

/// The mesh with triangles sorted by their lowest vertex in (y, x) order and vertices numbered
/// by first use: the locality a good quantized-mesh writer gives its index deltas.
fn reorder(mesh: &Mesh) -> Mesh {
    let key = |i: u32| {
        let p = mesh.positions[i as usize];
        (p[1].to_bits(), p[0].to_bits())
    };
    let mut tris = mesh.triangles.clone();
    tris.sort_by_key(|t| t.iter().map(|&i| key(i)).min());
    let mut ids = vec![u32::MAX; mesh.positions.len()];
    let mut positions = Vec::with_capacity(mesh.positions.len());
    for t in &mut tris {
        for i in t.iter_mut() {
            if ids[*i as usize] == u32::MAX {
                ids[*i as usize] = positions.len() as u32;
                positions.push(mesh.positions[*i as usize]);
            }
            *i = ids[*i as usize];
        }
    }
    Mesh { positions, triangles: tris }
}

fn quantized_mesh_gzip_ordered(mesh: &Mesh, extent: f64) -> usize {
    let n = mesh.positions.len();
    let (zmin, zmax) =
        mesh.positions.iter().fold((f64::MAX, f64::MIN), |(a, b), p| (a.min(p[2]), b.max(p[2])));
    let mut out = vec![0u8; 88];
    out.extend_from_slice(&(n as u32).to_le_bytes());
    let quant =
        |v: f64, lo: f64, hi: f64| if hi > lo { ((v - lo) / (hi - lo) * 32767.0).round() as i32 } else { 0 };
    let zz = |v: i32| ((v << 1) ^ (v >> 31)) as u16;
    for axis in 0..3 {
        let mut prev = 0i32;
        for p in &mesh.positions {
            let q = if axis < 2 { quant(p[axis], 0.0, extent) } else { quant(p[2], zmin, zmax) };
            out.extend_from_slice(&zz(q - prev).to_le_bytes());
            prev = q;
        }
    }
    let wide = n > 65536;
    if wide {
        while !out.len().is_multiple_of(4) {
            out.push(0);
        }
    } else if !out.len().is_multiple_of(2) {
        out.push(0);
    }
    let put = |out: &mut Vec<u8>, v: u32| {
        if wide {
            out.extend_from_slice(&v.to_le_bytes());
        } else {
            out.extend_from_slice(&(v as u16).to_le_bytes());
        }
    };
    out.extend_from_slice(&(mesh.triangles.len() as u32).to_le_bytes());
    let mut highest = 0u32;
    for t in &mesh.triangles {
        for &i in t {
            put(&mut out, highest - i.min(highest));
            if i == highest {
                highest += 1;
            }
        }
    }
    for side in 0..4 {
        let on: Vec<u32> = (0..n as u32)
            .filter(|&i| {
                let p = mesh.positions[i as usize];
                match side {
                    0 => p[0] <= 0.0,
                    1 => p[1] <= 0.0,
                    2 => p[0] >= extent,
                    _ => p[1] >= extent,
                }
            })
            .collect();
        out.extend_from_slice(&(on.len() as u32).to_le_bytes());
        for i in on {
            put(&mut out, i);
        }
    }
    let mut gz = flate2::write::GzEncoder::new(Vec::new(), flate2::Compression::default());
    gz.write_all(&out).unwrap();
    gz.finish().unwrap().len()
}

/// A small deterministic generator (splitmix64) so tests need no RNG crate.
pub struct Rng(pub u64);

impl Rng {
    pub fn next(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9e37_79b9_7f4a_7c15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
        z ^ (z >> 31)
    }

    pub fn below(&mut self, n: u64) -> u64 {
        self.next() % n.max(1)
    }

    pub fn unit(&mut self) -> f64 {
        (self.next() >> 11) as f64 / (1u64 << 53) as f64
    }
}

/// A mesh as a sorted list of triangles of positions, each rotated to start at its smallest
/// corner (winding kept): equal for meshes with the same triangles in any order.
pub fn canonical_triangles(m: &Mesh) -> Vec<[[u64; 3]; 3]> {
    let bits = |i: u32| m.positions[i as usize].map(f64::to_bits);
    let mut out: Vec<[[u64; 3]; 3]> = m
        .triangles
        .iter()
        .map(|t| {
            let c = t.map(bits);
            // The smallest rotation as a whole, so repeated corners are handled too.
            (0..3).map(|r| [c[r], c[(r + 1) % 3], c[(r + 2) % 3]]).min().unwrap()
        })
        .collect();
    out.sort_unstable();
    out
}

/// Sorted position bits: equal for the same multiset of positions.
pub fn canonical_positions(p: &[[f64; 3]]) -> Vec<[u64; 3]> {
    let mut out: Vec<[u64; 3]> = p.iter().map(|v| v.map(f64::to_bits)).collect();
    out.sort_unstable();
    out
}
