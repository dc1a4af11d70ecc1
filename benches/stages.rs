//! Criterion benchmarks of the pure stages, one group each, on fixed synthetic inputs:
//!
//! - `tin`: the TIN of one 257×257 leaf tile of `raster::synth::terrain` at 1 m error;
//! - `codec`: encoding and decoding that tile's quantized mesh, and a point level of it;
//! - `slicing`: the CPU reference of the 6-direction slicing (`lod::cpu`) for point levels 1
//!   and 3 of that tile, and measuring level 1 against the mesh; and the bake and measure of
//!   `lod::cpu`'s own test terrain (a jittered 102×102-quad grid over 256 units, cell 2), the
//!   figure its tests used to print;
//! - `selection`: one frame of `client::select::Selector::select` on a 100,000-node synthetic
//!   tree, 300 m over the relief looking 20 km ahead, at a 0.02 px threshold with the nearest-
//!   point distance (the stress setting of `examples/select_bench`), everything resident, once
//!   the cut has settled (its size is in the benchmark's name).
//!
//! These track each stage's own cost from change to change (`cargo bench --bench stages`;
//! criterion keeps the previous run under `target/criterion` and prints the change). The
//! comparisons with the papers' figures and other tools are the anchor scripts in `bench/`.

// A failed setup step is the benchmark failing: `expect` says which.
#![allow(clippy::expect_used)]

use std::hint::black_box;

use criterion::{Criterion, criterion_group, criterion_main};
use glam::DVec3;
use terrastream::bake::PointLevels;
use terrastream::bake::{self, BakeOptions, NodeMesh};
use terrastream::client::camera::Camera;
use terrastream::client::select::{AllResident, DEFAULT_FOV_DEG, DistanceRule, SelectParams, Selector};
use terrastream::client::stream::flight_path::Pose;
use terrastream::client::tree::{Synthetic, TileTree};
use terrastream::codec;
use terrastream::geom::ErrorFigures;
use terrastream::lod::cpu;
use terrastream::raster::{Georef, synth};
use terrastream::tiling::{Pyramid, TileKey};
use terrastream::tin;

/// Samples per side of the benchmark tile (one leaf of 256 cells).
const SIDE: u32 = 257;

fn tile() -> (Pyramid, Vec<f32>, Georef, BakeOptions) {
    let heights = synth::terrain(SIDE, SIDE, 7);
    let pyramid = Pyramid::new(SIDE, SIDE, SIDE - 1).expect("one-tile pyramid");
    let georef = Georef { dx: 10.0, dy: -10.0, ..Georef::default() };
    (
        pyramid,
        heights,
        georef,
        BakeOptions { tile_size: SIDE - 1, max_error: 1.0, levels: 3, point_levels: PointLevels::All },
    )
}

fn node_mesh() -> NodeMesh {
    let (pyramid, heights, georef, opts) = tile();
    let hf = terrastream::raster::Heightfield { width: SIDE, height: SIDE, data: heights };
    bake::node_mesh(&pyramid, &hf, &georef, TileKey::new(0, 0, 0), &opts).expect("node mesh")
}

fn tin_build(c: &mut Criterion) {
    let (pyramid, heights, _, opts) = tile();
    let grid = pyramid.grid(TileKey::new(0, 0, 0));
    c.bench_function("tin/build 257x257 at 1 m", |b| {
        b.iter(|| tin::build(black_box(&grid), black_box(&heights), opts.max_error).expect("tin"));
    });
}

fn codec(c: &mut Criterion) {
    let nm = node_mesh();
    let key = nm.key;
    let mesh_blob =
        codec::encode_mesh(key, 0, &nm.bounds, nm.quantization, &nm.mesh, nm.mesh_errors).expect("mesh");
    let (origin, cell) = nm.level_grid(1);
    let (pc, errors, q) = nm.finish_level(1, cpu::bake_points(&nm.mesh, origin, cell));
    let points_blob = codec::encode_points(key, 1, &nm.bounds, q, &pc, errors).expect("points");
    let mut g = c.benchmark_group("codec");
    g.bench_function(format!("encode mesh ({} vertices)", nm.mesh.positions.len()), |b| {
        b.iter(|| {
            codec::encode_mesh(
                key,
                0,
                &nm.bounds,
                nm.quantization,
                black_box(&nm.mesh),
                ErrorFigures::default(),
            )
            .expect("mesh")
        });
    });
    g.bench_function(format!("decode mesh ({} bytes)", mesh_blob.len()), |b| {
        b.iter(|| codec::decode(black_box(&mesh_blob)).expect("decode"));
    });
    g.bench_function(format!("encode points ({} points)", pc.positions.len()), |b| {
        b.iter(|| codec::encode_points(key, 1, &nm.bounds, q, black_box(&pc), errors).expect("points"));
    });
    g.bench_function(format!("decode points ({} bytes)", points_blob.len()), |b| {
        b.iter(|| codec::decode(black_box(&points_blob)).expect("decode"));
    });
    g.finish();
}

fn slicing(c: &mut Criterion) {
    let nm = node_mesh();
    let mut g = c.benchmark_group("slicing");
    for level in [1u8, 3] {
        let (origin, cell) = nm.level_grid(level);
        g.bench_function(format!("cpu bake level {level} (cell {cell} m)"), |b| {
            b.iter(|| cpu::bake_points(black_box(&nm.mesh), origin, cell));
        });
    }
    let (origin, cell) = nm.level_grid(1);
    let pc = cpu::bake_points(&nm.mesh, origin, cell);
    g.bench_function("measure level 1", |b| {
        b.iter(|| {
            black_box(cpu::measure_points(
                black_box(&nm.mesh),
                &pc,
                cell,
                terrastream::lod::TERRAIN_FOOTPRINT_HALF,
            ));
        });
    });
    let m = jittered_terrain(102, 256.0 / 102.0, 5);
    let (origin, cell) = ([0.0, 0.0, -50.0], 2.0);
    g.bench_function(format!("cpu bake jittered grid ({} triangles, cell {cell})", m.triangles.len()), |b| {
        b.iter(|| cpu::bake_points(black_box(&m), origin, cell));
    });
    let pc = cpu::bake_points(&m, origin, cell);
    g.bench_function("measure jittered grid", |b| {
        b.iter(|| black_box(cpu::measure_points(black_box(&m), &pc, cell, 0.6)));
    });
    g.finish();
}

/// `lod::cpu`'s test terrain: an `n`×`n`-quad grid of spacing `step`, smooth hills and a ridge,
/// inner vertices moved by up to 0.15 `step` (xorshift from `seed`).
fn jittered_terrain(n: u32, step: f64, seed: u64) -> terrastream::geom::Mesh {
    let mut rng = seed;
    let mut next = || {
        rng ^= rng << 13;
        rng ^= rng >> 7;
        rng ^= rng << 17;
        (rng >> 11) as f64 / (1u64 << 53) as f64
    };
    let height = |x: f64, y: f64| {
        20.0 * (x * 0.03).sin() * (y * 0.025).cos()
            + 8.0 * (x * 0.11 + y * 0.07).sin()
            + 30.0 / (1.0 + (-(x - 0.6 * y - 40.0) * 0.5).exp())
    };
    let mut m = terrastream::geom::Mesh::default();
    let edge = f64::from(n) * step;
    for y in 0..=n {
        for x in 0..=n {
            let (mut px, mut py) = (f64::from(x) * step, f64::from(y) * step);
            let z = height(px, py);
            if px > 0.0 && px < edge && py > 0.0 && py < edge {
                px += (next() - 0.5) * 0.3 * step;
                py += (next() - 0.5) * 0.3 * step;
            }
            m.positions.push([px, py, z]);
        }
    }
    let id = |x: u32, y: u32| y * (n + 1) + x;
    for y in 0..n {
        for x in 0..n {
            m.triangles.push([id(x, y), id(x + 1, y), id(x + 1, y + 1)]);
            m.triangles.push([id(x, y), id(x + 1, y + 1), id(x, y + 1)]);
        }
    }
    m
}

fn selection(c: &mut Criterion) {
    let spec = Synthetic::with_nodes(100_000);
    let tree = TileTree::synthetic(&spec).expect("synthetic tree");
    let extent = f64::from(spec.width - 1) * spec.cell_size;
    // Low over the middle, looking 20 km ahead and down (as examples/select_bench's low pass).
    let eye = DVec3::new(0.5 * extent, 0.5 * extent, spec.relief + 300.0);
    let pose =
        Pose { eye, target: eye + DVec3::new(14_142.0, 14_142.0, -300.0 - 0.5 * spec.relief), up: DVec3::Z };
    let camera = Camera::new(&pose, 1920, 1080, DEFAULT_FOV_DEG);
    let params =
        SelectParams { distance: DistanceRule::Nearest, threshold_px: 0.02, ..SelectParams::default() };
    let mut sel = Selector::new(params).expect("selector");
    // Warm: the first frame starts from the root and each frame refines the previous cut, so
    // fly until the cut stops changing (at most 10 s of frames) and measure the steady state.
    let mut t = 0.0;
    let mut drawn = usize::MAX;
    for _ in 0..600 {
        t += 1.0 / 60.0;
        let n = sel.select(&tree, &camera, &AllResident, t).expect("select").draws.len();
        if n == drawn {
            break;
        }
        drawn = n;
    }
    c.bench_function(&format!("selection/frame on {} nodes ({drawn} drawn)", tree.len()), |b| {
        b.iter(|| {
            t += 1.0 / 60.0;
            sel.select(black_box(&tree), &camera, &AllResident, t).expect("select").draws.len()
        });
    });
}

criterion_group!(benches, tin_build, codec, slicing, selection);
criterion_main!(benches);
