//! The GPU bake's host work (issue 39): a mesh's triangles go up once per batch whatever its
//! level count, the read-back is exactly the points (in the reference's order) and the
//! counters, and the report counts submissions and dispatches. Needs an adapter: skips without
//! one unless `TERRASTREAM_REQUIRE_GPU=1`.
#![cfg(feature = "gpu")]
#![allow(clippy::unwrap_used, clippy::panic)]

mod common;
use common::require_gpu;

use terrastream::geom::Mesh;
use terrastream::lod::cpu::{self, SliceOptions};
use terrastream::lod::gpu::{GpuBaker, LevelJob};

fn baker() -> Option<GpuBaker> {
    match GpuBaker::open_default(64 << 20) {
        Ok(b) => Some(b),
        Err(e) if require_gpu() => panic!("TERRASTREAM_REQUIRE_GPU=1 but no GPU baker: {e}"),
        Err(e) => {
            eprintln!("skipping GPU test: {e} (set TERRASTREAM_REQUIRE_GPU=1 to fail instead)");
            None
        }
    }
}

/// A bumpy heightfield mesh of `n` × `n` quads.
fn terrain(n: u32) -> Mesh {
    let mut positions = Vec::new();
    for y in 0..=n {
        for x in 0..=n {
            let (fx, fy) = (f64::from(x), f64::from(y));
            positions.push([
                fx * 10.0,
                fy * 10.0,
                40.0 * (fx * 0.21).sin() * (fy * 0.17).cos() + 3.0 * fx.sqrt(),
            ]);
        }
    }
    let id = |x: u32, y: u32| y * (n + 1) + x;
    let mut triangles = Vec::new();
    for y in 0..n {
        for x in 0..n {
            triangles.push([id(x, y), id(x + 1, y), id(x + 1, y + 1)]);
            triangles.push([id(x, y), id(x + 1, y + 1), id(x, y + 1)]);
        }
    }
    Mesh { positions, triangles }
}

#[test]
fn mesh_goes_up_once_and_only_the_points_come_back() {
    let Some(gpu) = baker() else { return };
    let meshes = [terrain(60), terrain(40)];
    let cells = [8.0, 16.0, 32.0, 64.0];
    let jobs: Vec<LevelJob<'_>> = meshes
        .iter()
        .flat_map(|m| cells.iter().map(move |&cell| LevelJob { mesh: m, origin: [-5.0, -5.0, -100.0], cell }))
        .collect();
    let opts = SliceOptions::default();
    let (out, r) = gpu.bake_jobs(&jobs, &opts).unwrap();
    assert_eq!((r.batches, r.gpu_jobs, r.retried_jobs, r.cpu_jobs), (1, 8, 0, 0), "{r:?}");
    let points: usize = out.iter().map(|(c, _)| c.len()).sum();
    assert_eq!(r.points, points as u64, "{r:?}");
    // Counters (8 words per job), then 32 bytes per point: nothing else is read back.
    assert_eq!(r.bytes_read_back, 32 * r.points + 32 * jobs.len() as u64, "{r:?}");
    assert_eq!(r.submissions, 2, "{r:?}");
    assert!(r.dispatches >= 6 && r.dispatches <= 12, "{r:?}");
    // Triangles (24 bytes) once per mesh; grid coordinates (12 bytes) per vertex and level;
    // parameters, jobs and scan levels besides.
    let tris: u64 = meshes.iter().map(|m| m.triangles.len() as u64).sum();
    let verts: u64 = meshes.iter().map(|m| m.positions.len() as u64).sum();
    let expected = 24 * tris + 12 * verts * cells.len() as u64;
    assert!(r.bytes_uploaded >= expected && r.bytes_uploaded <= expected + 8192, "{r:?} vs {expected}");
    assert!(r.host_s() > 0.0 && r.wait_s > 0.0, "{r:?}");
    // The points come back in the reference's order and cells.
    for (job, (g, _)) in jobs.iter().zip(&out) {
        let (c, _) = cpu::bake_cells(job.mesh, job.origin, job.cell, &opts);
        let order = |i: [i32; 3]| (i[2], i[1], i[0]);
        assert!(g.windows(2).all(|w| order(w[0].index) < order(w[1].index)), "not sorted");
        assert!(g.len().abs_diff(c.len()) <= 1 + c.len() / 200, "{} vs {}", g.len(), c.len());
    }
}

/// The bake's form (`bake_clouds`, written straight from the read-back) holds exactly the
/// cells' positions and normals, in their order, with the same statistics and the same
/// transfers.
#[test]
fn clouds_are_the_cells_positions_and_normals() {
    let Some(gpu) = baker() else { return };
    let meshes = [terrain(50), terrain(33)];
    let jobs: Vec<LevelJob<'_>> = meshes
        .iter()
        .flat_map(|m| {
            [6.0, 12.0, 40.0].map(move |cell| LevelJob { mesh: m, origin: [-7.0, -3.0, -80.0], cell })
        })
        .collect();
    let opts = SliceOptions::default();
    let (cells, rc) = gpu.bake_jobs(&jobs, &opts).unwrap();
    let (clouds, rp) = gpu.bake_clouds(&jobs, &opts).unwrap();
    assert_eq!((rc.points, rc.batches, rc.bytes_read_back), (rp.points, rp.batches, rp.bytes_read_back));
    assert_eq!(cells.len(), clouds.len());
    let mut total = 0;
    for ((c, cs), (p, ps)) in cells.iter().zip(&clouds) {
        assert_eq!(cs, ps);
        assert_eq!(p.positions, c.iter().map(|x| x.position).collect::<Vec<_>>());
        assert_eq!(p.normals, c.iter().map(|x| x.normal).collect::<Vec<_>>());
        total += p.positions.len();
    }
    assert!(total > 1000, "{total} points");
}

/// A batch whose triangles exceed the adapter's largest storage binding (lavapipe's is
/// 128 MiB: 5.6 M triangles) is rasterized in windows of triangles, one dispatch each: the
/// points are exactly those of one window, and no job leaves the GPU.
#[test]
fn triangles_beyond_one_binding_are_rasterized_in_windows() {
    let Some(gpu) = baker() else { return };
    let Some(mut windowed) = baker() else { return };
    // 768 bytes: 32 triangles a window, so the 2 × 40² + 2 × 25² triangles take 116 windows
    // (jobs of one mesh straddle window ends).
    windowed.set_triangle_window_bytes(768);
    let meshes = [terrain(40), terrain(25)];
    let jobs: Vec<LevelJob<'_>> = meshes
        .iter()
        .flat_map(|m| {
            [5.0, 11.0, 30.0].map(move |cell| LevelJob { mesh: m, origin: [-2.0, -9.0, -60.0], cell })
        })
        .collect();
    let opts = SliceOptions::default();
    let (one, r1) = gpu.bake_jobs(&jobs, &opts).unwrap();
    let (many, rw) = windowed.bake_jobs(&jobs, &opts).unwrap();
    assert_eq!((rw.cpu_jobs, rw.retried_jobs, rw.batches), (0, 0, 1), "{rw:?}");
    let tris: u64 = meshes.iter().map(|m| m.triangles.len() as u64).sum();
    assert_eq!(rw.dispatches, r1.dispatches + tris.div_ceil(32) - 1, "{r1:?} {rw:?}");
    assert_eq!(one, many);
    assert!(one.iter().map(|(c, _)| c.len()).sum::<usize>() > 1000);
}
