//! Quantized-mesh build stages: opens a placed DEM, then for every terrain tile (serially) times
//! the sampling (`TerrainSource::samples`: CRS positions, source reads, bilinear + geoid) and the
//! build (`build_tile`: quantization, TIN, measure, normals, encode) separately, `--repeat N`
//! times over all tiles (the best pass counts, warm caches), and prints one JSON line.
//! `bench/qmesh_vs_python.sh` reports the whole; this is where the time goes.
//!
//! `qmesh_stages DEM [--repeat N] [--max-zoom Z]`
use std::time::Instant;

use anyhow::Context;
use terrastream::bake::qmesh::{TerrainOptions, TerrainSource};
use terrastream::formats::qmesh::build_tile;
use terrastream::raster::dataset::{Dataset, DatasetOptions};

fn main() -> anyhow::Result<()> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let path = args.first().context("usage: qmesh_stages DEM [--repeat N] [--max-zoom Z]")?;
    let flag = |name: &str| args.iter().position(|a| a == name).and_then(|k| args.get(k + 1));
    let repeat: usize = flag("--repeat").map_or(Ok(3), |v| v.parse()).context("--repeat")?;
    let max_zoom: Option<u8> = flag("--max-zoom").map(|v| v.parse()).transpose().context("--max-zoom")?;
    let ds = Dataset::open(&[path.into()], &DatasetOptions::default(), &|_, _, _| {})?;
    let opts = TerrainOptions { max_zoom, ..TerrainOptions::default() };
    let src = TerrainSource::new(&ds, ds.georef(), opts)?;
    let ids: Vec<_> = src.coverage.tiles().collect();
    let (mut best_s, mut best_b) = (f64::INFINITY, f64::INFINITY);
    let mut vertices = 0usize;
    let mut digest = 0u64;
    for _ in 0..repeat.max(1) {
        let (mut ts, mut tb) = (0.0, 0.0);
        vertices = 0;
        digest = 0xcbf2_9ce4_8422_2325;
        for &id in &ids {
            let t0 = Instant::now();
            let s = src.samples(id)?;
            let t1 = Instant::now();
            let b = build_tile(&s, opts.error_scale, src.coverage.metadata(id))?;
            ts += (t1 - t0).as_secs_f64();
            tb += t1.elapsed().as_secs_f64();
            vertices += b.vertices;
            // FNV-1a of every tile's bytes: the same digest, the same tiles.
            for &x in &b.bytes {
                digest = (digest ^ u64::from(x)).wrapping_mul(0x100_0000_01b3);
            }
        }
        best_s = best_s.min(ts);
        best_b = best_b.min(tb);
    }
    let n = ids.len() as f64;
    println!(
        "{}",
        serde_json::json!({
            "dem": path, "tiles": ids.len(), "mean_vertices": vertices as f64 / n,
            "ms_samples": best_s * 1e3 / n, "ms_build": best_b * 1e3 / n,
            "digest": format!("{digest:016x}"), "ms_total": (best_s + best_b) * 1e3 / n,
        })
    );
    Ok(())
}
