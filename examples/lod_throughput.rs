//! Point-level bake throughput, `lod::cpu` (all cores) against `lod::gpu` (one adapter), on
//! the same level jobs in the same run. Inputs:
//! - a raster: every node of its quadtree, levels `1..=K`, as `bake` builds them (the TINs are
//!   built first and not timed: this isolates the stage the GPU takes over);
//! - `--model PATH` (OBJ/PLY, e.g. the Stanford bunny): the model on grids of 512, 256, 128 and
//!   64 cells across its largest extent;
//! - `--sphere N`: a generated noisy sphere of about N triangles (a latitude–longitude grid with
//!   deterministic bumps), on the same four grids: the dense-mesh case.
//!
//! `bench/gpu_vs_cpu.sh` runs it next to the end-to-end `bake --gpu off|on`.
//!
//! `lod_throughput [RASTER | --model PATH | --sphere N] [--tile-size N] [--levels K]
//! [--max-error E] [--gpu-budget-mib M] [--repeat R]` (R GPU bakes of the same jobs, figures
//! averaged; each GPU bake returns point clouds, as `bake` and the model bake take them,
//! `GpuBaker::bake_clouds`) prints one line per path, the GPU path's host work
//! (`BatchReport`: host seconds per million points by phase, bytes up and down per point,
//! submissions and dispatches per batch), the CPU time of the host threads (this one and
//! rayon's, from `/proc`: what the host spent, lavapipe's threads left out) and one JSON line with all the figures (`*_cpu_s`:
//! CPU seconds the process spent in each path, all threads, lavapipe's included: steadier than
//! wall time when other work shares the machine).
use std::time::Instant;

use anyhow::{Context, bail};
use rayon::prelude::*;
use terrastream::bake::{self, BakeOptions, NodeMesh};
use terrastream::geom::Mesh;
use terrastream::lod::gpu::{BatchReport, GpuBaker, LevelJob};
use terrastream::lod::{self, cpu};
use terrastream::raster::{self, LoadOptions};
use terrastream::tiling::Pyramid;

/// Cells across a model's largest extent, one level each.
const MODEL_GRIDS: [f64; 4] = [512.0, 256.0, 128.0, 64.0];

/// CPU seconds (user + system, all threads) this process has used, from `/proc/self/stat`
/// (Linux; 0 elsewhere): unlike wall time it hardly moves when other processes share the
/// cores, so it compares builds on a busy machine. lavapipe runs on the CPU, so it counts there.
fn process_cpu_s() -> f64 {
    let Ok(stat) = std::fs::read_to_string("/proc/self/stat") else { return 0.0 };
    // Fields after the parenthesised command name; utime and stime are the 12th and 13th.
    let rest = stat.rsplit_once(')').map_or("", |(_, r)| r);
    let f: Vec<f64> = rest.split_whitespace().skip(11).take(2).filter_map(|v| v.parse().ok()).collect();
    // Clock ticks: 100 per second on Linux.
    f.iter().sum::<f64>() / 100.0
}

/// This thread's id, from the `/proc/thread-self` link (`PID/task/TID`; Linux).
fn thread_id() -> Option<String> {
    let link = std::fs::read_link("/proc/thread-self").ok()?;
    Some(link.file_name()?.to_string_lossy().into_owned())
}

/// The host threads: this one and rayon's workers (lavapipe's threads are not among them).
fn host_threads() -> Vec<String> {
    let mut ids: Vec<String> = rayon::broadcast(|_| thread_id()).into_iter().flatten().collect();
    ids.extend(thread_id());
    ids.sort();
    ids.dedup();
    ids
}

/// CPU seconds (user + system) the given threads of this process have used, from
/// `/proc/self/task/TID/stat` (clock ticks of 10 ms: sum long runs).
fn threads_cpu_s(ids: &[String]) -> f64 {
    ids.iter()
        .filter_map(|id| std::fs::read_to_string(format!("/proc/self/task/{id}/stat")).ok())
        .map(|stat| {
            let rest = stat.rsplit_once(')').map_or("", |(_, r)| r).to_string();
            rest.split_whitespace().skip(11).take(2).filter_map(|v| v.parse::<f64>().ok()).sum::<f64>()
                / 100.0
        })
        .sum()
}

/// A unit sphere of radius 1000 on a `rows` × `2·rows` latitude–longitude grid (about
/// `4·rows²` triangles), its radius bumped by a few percent with a deterministic pattern so
/// that cells see varied normals.
fn noisy_sphere(triangles: usize) -> Mesh {
    let rows = ((triangles as f64 / 4.0).sqrt().ceil() as usize).max(4);
    let cols = 2 * rows;
    let mut positions = Vec::with_capacity((rows + 1) * cols);
    for r in 0..=rows {
        let theta = std::f64::consts::PI * r as f64 / rows as f64;
        for c in 0..cols {
            let phi = std::f64::consts::TAU * c as f64 / cols as f64;
            let bump = 1.0
                + 0.02 * (7.0 * theta).sin() * (11.0 * phi).cos()
                + 0.01 * (23.0 * theta + 1.0).cos() * (17.0 * phi).sin();
            let radius = 1000.0 * bump;
            positions.push([
                radius * theta.sin() * phi.cos(),
                radius * theta.sin() * phi.sin(),
                radius * theta.cos(),
            ]);
        }
    }
    let id = |r: usize, c: usize| (r * cols + c % cols) as u32;
    let mut tris = Vec::with_capacity(2 * rows * cols);
    for r in 0..rows {
        for c in 0..cols {
            tris.push([id(r, c), id(r + 1, c), id(r + 1, c + 1)]);
            tris.push([id(r, c), id(r + 1, c + 1), id(r, c + 1)]);
        }
    }
    Mesh { positions, triangles: tris }
}

/// Jobs of one mesh on the model grids.
fn model_jobs(mesh: &Mesh) -> Vec<LevelJob<'_>> {
    let b = terrastream::geom::Bounds::of_points(&mesh.positions);
    let size = b.size().max_element();
    MODEL_GRIDS.iter().map(|n| LevelJob { mesh, origin: b.min.to_array(), cell: size / n }).collect()
}

fn main() -> anyhow::Result<()> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let usage = "usage: lod_throughput [RASTER | --model PATH | --sphere N] [--tile-size N] [--levels K] …";
    let mut opts = BakeOptions::default();
    let mut budget_mib = lod::DEFAULT_GPU_BUDGET_MIB;
    let (mut raster_path, mut model_path, mut sphere) = (None, None, None);
    let mut repeat = 1usize;
    let mut it = args.iter();
    while let Some(flag) = it.next() {
        if !flag.starts_with("--") {
            raster_path = Some(flag.clone());
            continue;
        }
        let value = it.next().with_context(|| format!("{flag} needs a value"))?;
        match flag.as_str() {
            "--tile-size" => opts.tile_size = value.parse()?,
            "--levels" => opts.levels = value.parse()?,
            "--max-error" => opts.max_error = value.parse()?,
            "--gpu-budget-mib" => budget_mib = value.parse()?,
            "--model" => model_path = Some(value.clone()),
            "--sphere" => sphere = Some(value.parse::<usize>()?),
            "--repeat" => repeat = value.parse::<usize>()?.max(1),
            _ => bail!("unknown flag {flag}"),
        }
    }
    let t = Instant::now();
    let mut meshes: Vec<NodeMesh> = Vec::new();
    let model: Option<Mesh> = if let Some(p) = &model_path {
        Some(terrastream::model::load(p.as_ref())?.mesh)
    } else if let Some(n) = sphere {
        Some(noisy_sphere(n))
    } else {
        let path = raster_path.context(usage)?;
        let r = raster::load(path.as_ref(), &LoadOptions::default())?;
        let pyramid = Pyramid::new(r.heights.width, r.heights.height, opts.tile_size)?;
        meshes = pyramid
            .nodes()
            .into_par_iter()
            .map(|k| bake::node_mesh(&pyramid, &r.heights, &r.georef, k, &opts))
            .collect::<Result<_, _>>()?;
        None
    };
    let jobs: Vec<LevelJob<'_>> = match &model {
        Some(m) => model_jobs(m),
        None => meshes
            .iter()
            .flat_map(|nm| {
                (1..=opts.levels).map(move |l| {
                    let (origin, cell) = nm.level_grid(l);
                    LevelJob { mesh: &nm.mesh, origin, cell }
                })
            })
            .collect(),
    };
    let (nodes, triangles) = match &model {
        Some(m) => (1, m.triangles.len()),
        None => (meshes.len(), meshes.iter().map(|m| m.mesh.triangles.len()).sum()),
    };
    eprintln!(
        "{nodes} meshes, {triangles} triangles built in {:.1} s (not timed below), {} level jobs",
        t.elapsed().as_secs_f64(),
        jobs.len()
    );
    let lod = cpu::SliceOptions::default();

    let t = Instant::now();
    let c = process_cpu_s();
    let cpu_out: Vec<_> = jobs.par_iter().map(|j| cpu::bake_cells(j.mesh, j.origin, j.cell, &lod)).collect();
    let cpu_s = t.elapsed().as_secs_f64();
    let cpu_cpu_s = process_cpu_s() - c;
    let cpu_points: usize = cpu_out.iter().map(|(c, _)| c.len()).sum();
    drop(cpu_out);

    let t = Instant::now();
    let gpu = GpuBaker::open_default(budget_mib << 20)?;
    let open_s = t.elapsed().as_secs_f64();
    let ids = host_threads();
    let t = Instant::now();
    let c = process_cpu_s();
    let h = threads_cpu_s(&ids);
    let mut report = BatchReport::default();
    let mut gpu_out = Vec::new();
    for _ in 0..repeat {
        let (out, r) = gpu.bake_clouds(&jobs, &lod)?;
        report.merge(&r);
        gpu_out = out;
    }
    let runs = repeat as f64;
    let gpu_s = t.elapsed().as_secs_f64() / runs;
    let gpu_cpu_s = (process_cpu_s() - c) / runs;
    let host_cpu_s = (threads_cpu_s(&ids) - h) / runs;
    let gpu_points: usize = gpu_out.iter().map(|(c, _)| c.positions.len()).sum();

    let nodes = nodes as f64;
    let threads = rayon::current_num_threads();
    println!(
        "lod::cpu ({threads} threads): {cpu_points} points, {} level jobs in {cpu_s:.2} s: {:.2} M points/s, {:.1} tiles/s",
        jobs.len(),
        cpu_points as f64 / cpu_s / 1e6,
        nodes / cpu_s
    );
    println!(
        "lod::gpu ({}): {gpu_points} points in {gpu_s:.2} s (+{open_s:.2} s adapter and pipelines): {:.2} M points/s, {:.1} tiles/s; {} batches, peak {:.1} MiB per batch (budget {} MiB), {} jobs retried, {} left to the cpu, {} buffers reused",
        gpu.adapter(),
        gpu_points as f64 / gpu_s / 1e6,
        nodes / gpu_s,
        report.batches / repeat as u64,
        report.peak_batch_bytes as f64 / f64::from(1 << 20),
        budget_mib,
        report.retried_jobs / repeat as u64,
        report.cpu_jobs / repeat as u64,
        report.reused_buffers / repeat as u64
    );
    let mp = report.points.max(1) as f64 / 1e6;
    let per_batch = |n: u64| n as f64 / report.batches.max(1) as f64;
    println!(
        "lod::gpu host s per M points: prepare {:.4}, upload/encode {:.4}, submit {:.4}, map {:.4}, convert {:.4} = host {:.4} (wait {:.4}); bytes per point up {:.1}, down {:.1}; per batch {:.1} submissions, {:.1} dispatches",
        report.prepare_s / mp,
        report.upload_s / mp,
        report.submit_s / mp,
        report.map_s / mp,
        report.convert_s / mp,
        report.host_s() / mp,
        report.wait_s / mp,
        report.bytes_uploaded as f64 / (mp * 1e6),
        report.bytes_read_back as f64 / (mp * 1e6),
        per_batch(report.submissions),
        per_batch(report.dispatches)
    );
    let gmp = gpu_points as f64 / 1e6;
    println!(
        "lod::gpu CPU s per M points, from /proc (mean of {repeat} bakes): host threads (this one and rayon's) {:.4}, whole process (lavapipe's threads included) {:.4}",
        host_cpu_s / gmp,
        gpu_cpu_s / gmp
    );
    println!(
        "{{\"nodes\":{},\"level_jobs\":{},\"cpu_threads\":{threads},\"cpu_points\":{cpu_points},\"cpu_s\":{cpu_s:.4},\"cpu_cpu_s\":{cpu_cpu_s:.2},\"gpu_adapter\":{:?},\"gpu_points\":{gpu_points},\"gpu_s\":{gpu_s:.4},\"gpu_cpu_s\":{gpu_cpu_s:.2},\"gpu_host_threads_cpu_s\":{host_cpu_s:.3},\"gpu_batches\":{},\"gpu_peak_batch_bytes\":{},\"gpu_budget_bytes\":{},\"gpu_reused_buffers\":{},\"gpu_host_s\":{:.4},\"gpu_prepare_s\":{:.4},\"gpu_upload_s\":{:.4},\"gpu_submit_s\":{:.4},\"gpu_wait_s\":{:.4},\"gpu_map_s\":{:.4},\"gpu_convert_s\":{:.4},\"gpu_bytes_uploaded\":{},\"gpu_bytes_read_back\":{},\"gpu_submissions\":{},\"gpu_dispatches\":{}}}",
        nodes,
        jobs.len(),
        gpu.adapter(),
        report.batches,
        report.peak_batch_bytes,
        report.budget_bytes,
        report.reused_buffers,
        report.host_s(),
        report.prepare_s,
        report.upload_s,
        report.submit_s,
        report.wait_s,
        report.map_s,
        report.convert_s,
        report.bytes_uploaded,
        report.bytes_read_back,
        report.submissions,
        report.dispatches
    );
    Ok(())
}
