//! TIN benchmark driver: times `tin::build` on a terrain-RGB PNG (fuji.png by default) at the
//! max errors given, verifies each mesh's max error against every sample, and prints JSON lines.
//! `bench/tin_vs_pydelatin.py` runs it next to pydelatin in the same run.
//!
//! `tin_fuji DEM E1 E2 …` times our TIN; `tin_fuji DEM --measure MESH.bin` measures a foreign
//! mesh (u32 nv, u32 nt, nv × (f64 col, f64 row), nt × 3 u32, little-endian) on the same heights;
//! `tin_fuji DEM --dump HEIGHTS.f32` writes the heights the TIN sees (row-major little-endian
//! f32, no-data filled as a bake fills it) and prints `{"width": W, "height": H}`, so an anchor
//! triangulates exactly the same samples. DEM: a terrain-RGB PNG (`.png`) or any raster
//! `bake` reads (GeoTIFF, HGT, …).
use std::time::Instant;

use anyhow::{Context, bail};
use terrastream::raster::{self, HeightEncoding, LoadOptions};
use terrastream::tiling::{NodeGrid, Span};
use terrastream::tin;

fn main() -> anyhow::Result<()> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let path =
        args.first().context("usage: tin_fuji DEM [E…] | DEM --measure MESH.bin | DEM --dump OUT.f32")?;
    let png = std::path::Path::new(path).extension().is_some_and(|e| e.eq_ignore_ascii_case("png"));
    let encoding = png.then_some(HeightEncoding::TerrainRgb);
    let opts = LoadOptions { encoding, ..LoadOptions::default() };
    let r = raster::load(path.as_ref(), &opts)?;
    let (w, h) = (r.heights.width, r.heights.height);
    let hs = &r.heights.data;
    let span = Span { col0: 0, col1: w - 1, row0: 0, row1: h - 1 };
    let z = |c: f64, row: f64| f64::from(hs[row as usize * w as usize + c as usize]);

    if args.get(1).map(String::as_str) == Some("--dump") {
        let out = args.get(2).context("--dump needs a file")?;
        let bytes: Vec<u8> = hs.iter().flat_map(|v| v.to_le_bytes()).collect();
        std::fs::write(out, bytes).with_context(|| format!("writing {out}"))?;
        println!("{{\"width\": {w}, \"height\": {h}}}");
        return Ok(());
    }
    if args.get(1).map(String::as_str) == Some("--measure") {
        let bytes = std::fs::read(args.get(2).context("--measure needs a file")?)?;
        let u32_at = |o: usize| -> anyhow::Result<u32> {
            Ok(u32::from_le_bytes(bytes.get(o..o + 4).context("truncated mesh file")?.try_into()?))
        };
        let (nv, nt) = (u32_at(0)? as usize, u32_at(4)? as usize);
        if bytes.len() != 8 + nv * 16 + nt * 12 {
            bail!("mesh file size does not match its counts");
        }
        let f64_at = |o: usize| f64::from_le_bytes(bytes[o..o + 8].try_into().unwrap_or_default());
        let pos: Vec<[f64; 3]> = (0..nv)
            .map(|k| {
                let (c, row) = (f64_at(8 + k * 16), f64_at(16 + k * 16));
                [c, row, z(c, row)]
            })
            .collect();
        let tris: Vec<[u32; 3]> = (0..nt)
            .map(|k| std::array::from_fn(|a| u32_at(8 + nv * 16 + k * 12 + a * 4).unwrap_or(0)))
            .collect();
        let e = tin::measure_vertical(&pos, &tris, span, hs)?;
        println!("{{\"measured_max_error\": {}, \"rms\": {}}}", e.max, e.rms);
        return Ok(());
    }

    let grid = NodeGrid { cols: (0..w).collect(), rows: (0..h).collect() };
    let errors: Vec<f64> = args[1..].iter().map(|a| a.parse()).collect::<Result<_, _>>()?;
    for e in if errors.is_empty() { vec![1.0, 10.0, 30.0] } else { errors } {
        let mut best = f64::INFINITY;
        let mut t = tin::Tin::default();
        for _ in 0..5 {
            let start = Instant::now();
            t = tin::build(&grid, hs, e)?;
            best = best.min(start.elapsed().as_secs_f64());
        }
        let pos: Vec<[f64; 3]> = t
            .vertices
            .iter()
            .map(|&[i, j]| [f64::from(i), f64::from(j), z(f64::from(i), f64::from(j))])
            .collect();
        let m = tin::measure_vertical(&pos, &t.triangles, span, hs)?;
        println!(
            "{{\"max_error\": {e}, \"vertices\": {}, \"triangles\": {}, \"seconds\": {best:.4}, \"measured_max_error\": {:.4}}}",
            t.vertices.len(),
            t.triangles.len(),
            m.max
        );
    }
    Ok(())
}
