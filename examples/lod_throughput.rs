//! Point-level bake throughput, `lod::cpu` (all cores) against `lod::gpu` (one adapter), on
//! the same level jobs in the same run: every node of a raster's quadtree, levels `1..=K`, as
//! `bake` builds them. The TINs are built first and not timed: this isolates the stage the GPU
//! takes over. `bench/gpu_vs_cpu.sh` runs it next to the end-to-end `bake --gpu off|on`.
//!
//! `lod_throughput RASTER [--tile-size N] [--levels K] [--max-error E] [--gpu-budget-mib M]`
//! prints one line per path and one JSON line with all the figures (`*_cpu_s`: CPU seconds the
//! process spent in each path, all threads, lavapipe's included: steadier than wall time when
//! other work shares the machine).
use std::time::Instant;

use anyhow::{Context, bail};
use rayon::prelude::*;
use terrastream::bake::{self, BakeOptions, NodeMesh};
use terrastream::lod::gpu::{GpuBaker, LevelJob};
use terrastream::lod::{self, cpu};
use terrastream::raster::{self, LoadOptions};
use terrastream::tiling::Pyramid;

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

fn main() -> anyhow::Result<()> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let path = args.first().context("usage: lod_throughput RASTER [--tile-size N] [--levels K] …")?;
    let mut opts = BakeOptions::default();
    let mut budget_mib = lod::DEFAULT_GPU_BUDGET_MIB;
    let mut it = args[1..].iter();
    while let Some(flag) = it.next() {
        let value = it.next().with_context(|| format!("{flag} needs a value"))?;
        match flag.as_str() {
            "--tile-size" => opts.tile_size = value.parse()?,
            "--levels" => opts.levels = value.parse()?,
            "--max-error" => opts.max_error = value.parse()?,
            "--gpu-budget-mib" => budget_mib = value.parse()?,
            _ => bail!("unknown flag {flag}"),
        }
    }
    let r = raster::load(path.as_ref(), &LoadOptions::default())?;
    let pyramid = Pyramid::new(r.heights.width, r.heights.height, opts.tile_size)?;
    let t = Instant::now();
    let meshes: Vec<NodeMesh> = pyramid
        .nodes()
        .into_par_iter()
        .map(|k| bake::node_mesh(&pyramid, &r.heights, &r.georef, k, &opts))
        .collect::<Result<_, _>>()?;
    let triangles: usize = meshes.iter().map(|m| m.mesh.triangles.len()).sum();
    eprintln!(
        "{} nodes, {triangles} TIN triangles built in {:.1} s (not timed below)",
        meshes.len(),
        t.elapsed().as_secs_f64()
    );
    let jobs: Vec<LevelJob<'_>> = meshes
        .iter()
        .flat_map(|nm| {
            (1..=opts.levels).map(move |l| {
                let (origin, cell) = nm.level_grid(l);
                LevelJob { mesh: &nm.mesh, origin, cell }
            })
        })
        .collect();
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
    let t = Instant::now();
    let c = process_cpu_s();
    let (gpu_out, report) = gpu.bake_jobs(&jobs, &lod)?;
    let gpu_s = t.elapsed().as_secs_f64();
    let gpu_cpu_s = process_cpu_s() - c;
    let gpu_points: usize = gpu_out.iter().map(|(c, _)| c.len()).sum();

    let nodes = meshes.len() as f64;
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
        report.batches,
        report.peak_batch_bytes as f64 / f64::from(1 << 20),
        budget_mib,
        report.retried_jobs,
        report.cpu_jobs,
        report.reused_buffers
    );
    println!(
        "{{\"nodes\":{},\"level_jobs\":{},\"cpu_threads\":{threads},\"cpu_points\":{cpu_points},\"cpu_s\":{cpu_s:.4},\"cpu_cpu_s\":{cpu_cpu_s:.2},\"gpu_adapter\":{:?},\"gpu_points\":{gpu_points},\"gpu_s\":{gpu_s:.4},\"gpu_cpu_s\":{gpu_cpu_s:.2},\"gpu_batches\":{},\"gpu_peak_batch_bytes\":{},\"gpu_budget_bytes\":{},\"gpu_reused_buffers\":{}}}",
        meshes.len(),
        jobs.len(),
        gpu.adapter(),
        report.batches,
        report.peak_batch_bytes,
        report.budget_bytes,
        report.reused_buffers
    );
    Ok(())
}
