//! `lod::gpu` against the CPU reference `lod::cpu` on real tiles (fuji.png), the Stanford bunny
//! and generated terrain; determinism, batching under the memory budget, and the `--gpu`
//! choice of the binary.
//!
//! Tests that need an adapter skip (with the reason printed) when none is found, unless
//! `TERRASTREAM_REQUIRE_GPU=1` (CI sets it, with Mesa's lavapipe installed): then they fail.
//! The shader validation test needs no adapter.
#![cfg(feature = "gpu")]
// Test helpers outside `#[test]` functions unwrap and panic as the tests themselves may.
#![allow(clippy::unwrap_used, clippy::panic)]

mod common;
use common::{bin, bunny_or_generated, fuji_or_generated, gpu_or_skip, require_gpu, shared, tree};

use std::collections::HashMap;
use std::path::Path;
use std::sync::OnceLock;

use terrastream::bake::{self, BakeOptions, NodeMesh};
use terrastream::geom::{Mesh, PointCloud};
use terrastream::lod;
use terrastream::lod::cpu::{self, BakedCell};
use terrastream::lod::gpu::{self, GpuBaker, LevelJob};
use terrastream::raster::{self, Georef, HeightEncoding, Heightfield, LoadOptions, Overrides};
use terrastream::tiling::Pyramid;

/// Every pipeline's WGSL parses and validates with naga: runs without any adapter.
#[test]
fn shaders_validate_with_naga() {
    for (name, source) in gpu::SHADERS {
        let module = naga::front::wgsl::parse_str(source)
            .unwrap_or_else(|e| panic!("shader {name}: {}", e.emit_to_string(source)));
        naga::valid::Validator::new(naga::valid::ValidationFlags::all(), naga::valid::Capabilities::empty())
            .validate(&module)
            .unwrap_or_else(|e| panic!("shader {name}: {}", e.emit_to_string(source)));
        assert!(
            module.entry_points.iter().any(|e| e.name == "main" && e.stage == naga::ShaderStage::Compute),
            "shader {name} has no compute entry point `main`"
        );
    }
}

/// The shared baker, or `None` (test skipped) when no adapter is found and none is required.
fn baker() -> Option<&'static GpuBaker> {
    static BAKER: OnceLock<Result<GpuBaker, String>> = OnceLock::new();
    match BAKER.get_or_init(|| GpuBaker::open_default(64 << 20).map_err(|e| e.to_string())) {
        Ok(b) => Some(b),
        Err(e) if require_gpu() => panic!("TERRASTREAM_REQUIRE_GPU=1 but no GPU baker: {e}"),
        Err(e) => {
            eprintln!("skipping GPU test: {e} (set TERRASTREAM_REQUIRE_GPU=1 to fail instead)");
            None
        }
    }
}

/// Cell-by-cell comparison of a GPU bake with the reference.
#[derive(Debug, Default)]
struct Agreement {
    union: usize,
    agree: usize,
    /// Largest position difference of agreeing cells, in cells.
    max_pos: f64,
    /// Largest normal component difference of agreeing cells (reported, not bounded: a pixel
    /// centre on an edge shared by two triangles may go to the other one in f32, which keeps the
    /// count and, the surface being continuous, the position, but not the normal).
    max_normal: f32,
}

impl Agreement {
    fn fraction(&self) -> f64 {
        if self.union == 0 { 1.0 } else { self.agree as f64 / self.union as f64 }
    }

    fn add(&mut self, o: &Self) {
        self.union += o.union;
        self.agree += o.agree;
        self.max_pos = self.max_pos.max(o.max_pos);
        self.max_normal = self.max_normal.max(o.max_normal);
    }
}

/// Cells agree when both bakes have them, from the same number of samples, both filled or
/// both not.
fn compare(cpu: &[BakedCell], gpu: &[BakedCell], cell: f64) -> Agreement {
    let by_index: HashMap<[i32; 3], &BakedCell> = cpu.iter().map(|c| (c.index, c)).collect();
    let mut a = Agreement { union: cpu.len(), ..Agreement::default() };
    for g in gpu {
        match by_index.get(&g.index) {
            Some(c) if c.samples == g.samples && c.filled == g.filled => {
                a.agree += 1;
                for d in 0..3 {
                    a.max_pos = a.max_pos.max((c.position[d] - g.position[d]).abs() / cell);
                    a.max_normal = a.max_normal.max((c.normal[d] - g.normal[d]).abs());
                }
            }
            Some(_) => {}
            None => a.union += 1,
        }
    }
    a
}

fn cloud(cells: &[BakedCell]) -> PointCloud {
    PointCloud {
        positions: cells.iter().map(|c| c.position).collect(),
        normals: cells.iter().map(|c| c.normal).collect(),
    }
}

fn close(a: f64, b: f64) -> bool {
    (a - b).abs() <= 0.01 * a.abs().max(b.abs())
}

/// Bakes every job on the GPU (one batched call) and on the CPU; checks the bars:
/// ≥ 99.5 % of occupied cells agree, agreeing points within 1/1000 cell, measured errors within
/// 1 %, and the same statistics where they are exact.
fn check_jobs(name: &str, gpu: &GpuBaker, jobs: &[LevelJob<'_>]) -> Agreement {
    let opts = cpu::SliceOptions::default();
    let (gpu_out, report) = gpu.bake_jobs(jobs, &opts).unwrap();
    assert_eq!(report.cpu_jobs, 0, "{name}: every job should fit the GPU: {report:?}");
    let mut total = Agreement::default();
    for (n, (job, (g, gs))) in jobs.iter().zip(&gpu_out).enumerate() {
        let (c, cs) = cpu::bake_cells(job.mesh, job.origin, job.cell, &opts);
        assert_eq!(gs.skipped_triangles, cs.skipped_triangles, "{name} job {n}");
        let a = compare(&c, g, job.cell);
        assert!(a.fraction() >= 0.995, "{name} job {n}: {a:?} ({:.4})", a.fraction());
        assert!(a.max_pos <= 1e-3, "{name} job {n}: {a:?}");
        let ec =
            cpu::measure_points(job.mesh, &cloud(&c), job.cell, terrastream::lod::TERRAIN_FOOTPRINT_HALF);
        let eg = cpu::measure_points(job.mesh, &cloud(g), job.cell, terrastream::lod::TERRAIN_FOOTPRINT_HALF);
        assert!(
            close(ec.max, eg.max) && close(ec.rms, eg.rms) && close(ec.gap, eg.gap),
            "{name} job {n}: errors cpu {ec:?} gpu {eg:?}"
        );
        total.add(&a);
    }
    eprintln!(
        "{name}: {} jobs, {} cells, {:.4}% agree, max position difference {:.2e} cells, max normal difference {:.3}, {report:?}",
        jobs.len(),
        total.union,
        100.0 * total.fraction(),
        total.max_pos,
        total.max_normal
    );
    total
}

/// Node meshes of a raster, as the bake builds them (quantized TIN, level grids).
fn node_meshes(hf: &Heightfield, georef: &Georef, tile: u32, max_error: f64) -> Vec<NodeMesh> {
    let opts = BakeOptions { tile_size: tile, max_error, levels: 3, point_levels: bake::PointLevels::All };
    let pyramid = Pyramid::new(hf.width, hf.height, tile).unwrap();
    pyramid.nodes().into_iter().map(|k| bake::node_mesh(&pyramid, hf, georef, k, &opts).unwrap()).collect()
}

fn level_jobs(meshes: &[NodeMesh], levels: u8) -> Vec<LevelJob<'_>> {
    meshes
        .iter()
        .flat_map(|nm| {
            (1..=levels).map(move |l| {
                let (origin, cell) = nm.level_grid(l);
                LevelJob { mesh: &nm.mesh, origin, cell }
            })
        })
        .collect()
}

#[test]
fn agrees_with_cpu_on_fuji_tiles() {
    let Some(gpu) = baker() else { return };
    let opts = LoadOptions {
        encoding: Some(HeightEncoding::TerrainRgb),
        overrides: Overrides { cell_size: Some(30.0), ..Overrides::default() },
        ..LoadOptions::default()
    };
    let Some(fuji) = shared("fuji.png", "gpu::agrees_with_cpu_on_fuji_tiles") else { return };
    let r = raster::load(&fuji, &opts).unwrap();
    let meshes = node_meshes(&r.heights, &r.georef, 128, 2.0);
    check_jobs("fuji", gpu, &level_jobs(&meshes, 3));
}

#[test]
fn agrees_with_cpu_on_generated_terrain() {
    let Some(gpu) = baker() else { return };
    let hf = Heightfield { width: 257, height: 257, data: terrastream::raster::synth::terrain(257, 257, 7) };
    let georef = Georef { dx: 30.0, dy: -30.0, y0: 257.0 * 30.0, ..Georef::default() };
    let meshes = node_meshes(&hf, &georef, 128, 1.0);
    check_jobs("synth", gpu, &level_jobs(&meshes, 3));
}

#[test]
fn agrees_with_cpu_on_the_bunny() {
    let Some(gpu) = baker() else { return };
    // The agreement bounds are the bunny's (generated terrain has its own test above).
    let Some(bunny) = shared("stanford-bunny.obj", "gpu::agrees_with_cpu_on_the_bunny") else { return };
    let mesh = terrastream::model::load(&bunny).unwrap().mesh;
    assert!(mesh.triangles.len() > 10_000);
    let b = terrastream::geom::Bounds::of_points(&mesh.positions);
    let size = b.size().max_element();
    // Framebuffers of 256, 128, 64 and 32 cells across the bunny's largest extent.
    let jobs: Vec<LevelJob<'_>> = [256.0, 128.0, 64.0, 32.0]
        .into_iter()
        .map(|n| LevelJob { mesh: &mesh, origin: b.min.to_array(), cell: size / n })
        .collect();
    check_jobs("bunny", gpu, &jobs);
}

/// Two GPU bakes are bit-identical, and so are bakes split into many small batches: a job's
/// result does not depend on its batch. The small budget is respected.
#[test]
fn bakes_are_deterministic_and_independent_of_batching() {
    let Some(gpu) = baker() else { return };
    let hf = Heightfield { width: 257, height: 257, data: terrastream::raster::synth::terrain(257, 257, 3) };
    let georef = Georef { dx: 10.0, dy: 10.0, ..Georef::default() };
    let meshes = node_meshes(&hf, &georef, 64, 1.0);
    let jobs = level_jobs(&meshes, 3);
    let opts = cpu::SliceOptions::default();
    let bits = |r: &[(Vec<BakedCell>, cpu::BakeStats)]| -> Vec<(Vec<u64>, Vec<u32>, cpu::BakeStats)> {
        r.iter()
            .map(|(cells, s)| {
                (
                    cells.iter().flat_map(|c| c.position.map(f64::to_bits)).collect(),
                    cells.iter().flat_map(|c| c.normal.map(f32::to_bits)).collect(),
                    *s,
                )
            })
            .collect()
    };
    let same = |x: &[(Vec<BakedCell>, cpu::BakeStats)], y: &[(Vec<BakedCell>, cpu::BakeStats)]| {
        let (x, y) = (bits(x), bits(y));
        let first = x.iter().zip(&y).position(|(p, q)| p != q);
        assert!(first.is_none() && x.len() == y.len(), "results differ from job {first:?} on");
    };
    let (a, ra) = gpu.bake_jobs(&jobs, &opts).unwrap();
    let (b, _) = gpu.bake_jobs(&jobs, &opts).unwrap();
    same(&a, &b);
    assert_eq!(ra.batches, 1, "{ra:?}");

    let ctx = terrastream::gpu::open().unwrap();
    let budget = 2 << 20;
    let small = GpuBaker::new(ctx.device, ctx.queue, ctx.adapter, budget).unwrap();
    let (c, rc) = small.bake_jobs(&jobs, &opts).unwrap();
    same(&a, &c);
    assert!(rc.batches > 3 && rc.cpu_jobs == 0, "{rc:?}");
    // From the third batch on (two are in flight at once) buffers come back from the pool.
    assert!(rc.reused_buffers > 0, "{rc:?}");
    assert!(rc.peak_batch_bytes <= rc.budget_bytes && rc.budget_bytes == budget, "{rc:?}");
    assert!(ra.peak_batch_bytes <= 64 << 20, "{ra:?}");
    eprintln!("budget 64 MiB: {ra:?}\nbudget 2 MiB: {rc:?}");
}

/// Degenerate input gives what the reference gives.
#[test]
fn degenerate_input_matches_the_reference() {
    let Some(gpu) = baker() else { return };
    let mut m = Mesh {
        positions: vec![[0.0, 0.0, 0.0], [4.0, 0.0, 1.0], [0.0, 4.0, 2.0], [f64::NAN, 0.0, 0.0]],
        triangles: vec![[0, 1, 2], [0, 1, 3], [0, 1, 9], [0, 0, 1]],
    };
    let opts = cpu::SliceOptions::default();
    for cell in [0.5, 0.0, f64::NAN] {
        let (g, gs) = gpu.bake_cells(&m, [0.0; 3], cell, &opts).unwrap();
        let (c, cs) = cpu::bake_cells(&m, [0.0; 3], cell, &opts);
        assert_eq!(gs.skipped_triangles, cs.skipped_triangles, "cell {cell}");
        assert_eq!(g.len(), c.len(), "cell {cell}");
    }
    m.triangles.clear();
    assert!(gpu.bake_cells(&m, [0.0; 3], 1.0, &opts).unwrap().0.is_empty());
}

fn bake_fuji(out: &Path, gpu: &str) -> String {
    let src = tempfile::tempdir().unwrap();
    let fuji = fuji_or_generated(src.path(), "gpu: a fuji.png bake");
    let o = bin()
        .args(["bake", "--quiet", "--encoding", "terrain-rgb", "--cell-size", "30", "--tile-size", "128"])
        .args(["--max-error", "2", "--levels", "3", "--gpu", gpu, "--out"])
        .arg(out)
        .arg(&fuji)
        .output()
        .unwrap();
    assert!(o.status.success(), "bake --gpu {gpu} failed: {}", String::from_utf8_lossy(&o.stderr));
    String::from_utf8(o.stdout).unwrap()
}

/// `bake --gpu on` twice gives byte-identical tilesets naming the adapter; `--gpu off` names
/// the CPU.
#[test]
fn cli_gpu_bakes_are_byte_identical_and_name_the_adapter() {
    if baker().is_none() {
        return;
    }
    let tmp = tempfile::tempdir().unwrap();
    let (a, b, c) = (tmp.path().join("a"), tmp.path().join("b"), tmp.path().join("c"));
    let summary = bake_fuji(&a, "on");
    bake_fuji(&b, "on");
    assert_eq!(tree(&a), tree(&b));
    assert!(summary.contains("point levels baked by gpu: "), "{summary}");
    let manifest = terrastream::store::Store::new(&a).manifest().unwrap();
    assert!(manifest.point_baker.starts_with("gpu: "), "{}", manifest.point_baker);
    bake_fuji(&c, "off");
    assert_eq!(terrastream::store::Store::new(&c).manifest().unwrap().point_baker, "cpu");
}

/// The baker is shared by threads (the bake's workers, the server's on-demand bakes).
#[test]
fn point_baker_is_send_and_sync() {
    fn check<T: Send + Sync>() {}
    check::<lod::PointBaker>();
    check::<GpuBaker>();
}

fn bake_bunny(out: &Path, gpu: &str) -> String {
    let src = tempfile::tempdir().unwrap();
    let bunny = bunny_or_generated(src.path(), "gpu: a stanford-bunny.obj bake");
    let o = bin().args(["bake-model", "--gpu", gpu, "--out"]).arg(out).arg(&bunny).output().unwrap();
    assert!(o.status.success(), "bake-model --gpu {gpu} failed: {}", String::from_utf8_lossy(&o.stderr));
    String::from_utf8(o.stdout).unwrap()
}

/// `bake-model --gpu on` bakes the bunny's point levels on the adapter: twice byte-identical,
/// the adapter named in the summary and manifest, and each level's count and measured errors
/// within the agreement bounds of the CPU bake (`--gpu off`).
#[test]
fn bake_model_on_the_gpu_matches_the_cpu() {
    if baker().is_none() {
        return;
    }
    let tmp = tempfile::tempdir().unwrap();
    let (a, b, c) = (tmp.path().join("a"), tmp.path().join("b"), tmp.path().join("c"));
    let summary = bake_bunny(&a, "on");
    bake_bunny(&b, "on");
    assert_eq!(tree(&a), tree(&b));
    assert!(summary.contains("point levels baked by gpu: "), "{summary}");
    bake_bunny(&c, "off");
    let g = terrastream::bake::model_tileset::read_manifest(&terrastream::store::Store::new(&a)).unwrap();
    let cpu = terrastream::bake::model_tileset::read_manifest(&terrastream::store::Store::new(&c)).unwrap();
    assert!(g.tileset.point_baker.starts_with("gpu: "), "{}", g.tileset.point_baker);
    assert_eq!(cpu.tileset.point_baker, "cpu");
    assert_eq!(g.model.levels.len(), cpu.model.levels.len());
    for (lg, lc) in g.model.levels.iter().zip(&cpu.model.levels).skip(1) {
        let (ng, nc) = (f64::from(lg.count), f64::from(lc.count));
        assert!((ng - nc).abs() <= 0.005 * nc, "level {}: {ng} points on the GPU, {nc} on the CPU", lg.level);
        assert!(
            close(lg.errors.max, lc.errors.max),
            "level {}: {:?} vs {:?}",
            lg.level,
            lg.errors,
            lc.errors
        );
        assert!(
            close(lg.errors.rms, lc.errors.rms),
            "level {}: {:?} vs {:?}",
            lg.level,
            lg.errors,
            lc.errors
        );
    }
}

/// D1 on the GPU baker: the reported fuji bake (64-cell tiles), a flat raster and a plateau
/// with a lake bake with every position inside the bounds its blob header states.
#[test]
fn gpu_bakes_keep_positions_inside_the_bounds() {
    if baker().is_none() {
        return;
    }
    let tmp = tempfile::tempdir().unwrap();
    let check = |dir: &Path| {
        let mut n = 0;
        for (name, bytes) in tree(dir) {
            if std::path::Path::new(&name).extension().is_none_or(|e| e != "tsb") {
                continue;
            }
            let blob = terrastream::codec::decode(&bytes).unwrap();
            let b = blob.header.bounds();
            let ps = match &blob.geometry {
                terrastream::codec::Geometry::Mesh(m) => m.positions.clone(),
                terrastream::codec::Geometry::Points(p) => p.positions.clone(),
            };
            for p in ps {
                assert!(
                    (0..3).all(|a| b.min[a] <= p[a] && p[a] <= b.max[a]),
                    "{name:?}: {p:?} outside {b:?}"
                );
            }
            n += 1;
        }
        assert!(n > 0);
    };
    // D8 too: without XDG_RUNTIME_DIR (CI, containers) Mesa's device-select layer made
    // libwayland print "error: XDG_RUNTIME_DIR is invalid…" in every GPU run.
    let run = |args: &[&str], out: &Path, input: &Path| {
        let o = bin()
            .env_remove("XDG_RUNTIME_DIR")
            .env_remove("NODEVICE_SELECT")
            .args(["bake", "--quiet", "--gpu", "on"])
            .args(args)
            .arg("--out")
            .arg(out)
            .arg(input)
            .output()
            .unwrap();
        let stderr = String::from_utf8_lossy(&o.stderr);
        assert!(o.status.success(), "{stderr}");
        assert!(!stderr.contains("error"), "alarming lines in a normal GPU run: {stderr}");
    };
    let out = tmp.path().join("fuji64");
    run(
        &["--encoding", "terrain-rgb", "--cell-size", "30", "--tile-size", "64", "--max-error", "2"],
        &out,
        &fuji_or_generated(tmp.path(), "gpu::gpu_bakes_keep_positions_inside_the_bounds"),
    );
    check(&out);
    for (i, plateau) in [false, true].into_iter().enumerate() {
        let (w, h) = (33u32, 33u32);
        let data: Vec<f32> = (0..w * h)
            .map(|i| {
                let (c, r) = (i % w, i / w);
                if !plateau {
                    175.187_38
                } else if (2..8).contains(&c) && (2..8).contains(&r) {
                    171.5
                } else if c > 16 {
                    212.3
                } else {
                    175.187_38
                }
            })
            .collect();
        let tif = tmp.path().join(format!("f{i}.tif"));
        std::fs::write(&tif, raster::geotiff::encode_f32(w, h, &data, (0.0, 0.0), (1.0, -1.0)).unwrap())
            .unwrap();
        let out = tmp.path().join(format!("flat{i}"));
        run(&["--tile-size", "32", "--levels", "4"], &out, &tif);
        check(&out);
    }
}

/// `--gpu auto` bakes on a hardware adapter and leaves a software one (Mesa lavapipe, several
/// times slower than the CPU reference for baking) to `--gpu on`; `on` takes either.
#[test]
fn gpu_auto_takes_hardware_adapters_only() {
    let Some(ctx) = gpu_or_skip("GPU test") else { return };
    let (auto, notice) = lod::PointBaker::open(lod::GpuMode::Auto, 64 << 20).unwrap();
    if ctx.software {
        assert_eq!(auto.describe(), "cpu", "auto took the software adapter {}", ctx.adapter);
        let notice = notice.expect("auto on a software adapter says why it bakes on the CPU");
        assert!(notice.contains("software adapter") && notice.contains("--gpu on"), "{notice}");
    } else {
        assert!(auto.describe().starts_with("gpu: "), "auto left the hardware adapter {}", ctx.adapter);
    }
    let (on, _) = lod::PointBaker::open(lod::GpuMode::On, 64 << 20).unwrap();
    assert!(on.describe().starts_with("gpu: "), "{}", on.describe());
}
