//! Writes the inputs of `bench/hgt_mosaic.sh`: 16 SRTM `.hgt` tiles (3 arc-seconds, 1201²,
//! N35..N38 × E136..E139, sharing their edge rows and columns) into DIR, and the same 4° × 4°
//! (4801² samples) as one geographic float32 GeoTIFF at FILE.
//!
//! Usage: `cargo run --release --example hgt_mosaic -- DIR FILE`

use std::io::BufWriter;

use terrastream::raster::geotiff::{Model, write_tiled_f32};

fn main() -> std::io::Result<()> {
    let args: Vec<String> = std::env::args().collect();
    let [_, dir, file] = args.as_slice() else {
        eprintln!("usage: hgt_mosaic DIR FILE");
        std::process::exit(2);
    };
    let n = 4801u32;
    let height = |c: u32, r: u32| (terrastream::raster::synth::height_at(n, n, 5, c, r) * 0.8).round();
    std::fs::create_dir_all(dir)?;
    for ty in 0..4u32 {
        for tx in 0..4u32 {
            let (lat, lon) = (38 - ty, 136 + tx);
            let mut bytes = Vec::with_capacity(1201 * 1201 * 2);
            for r in 0..1201 {
                for c in 0..1201 {
                    bytes.extend_from_slice(&(height(tx * 1200 + c, ty * 1200 + r) as i16).to_be_bytes());
                }
            }
            std::fs::write(format!("{dir}/N{lat:02}E{lon:03}.hgt"), bytes)?;
        }
    }
    let mut out = BufWriter::new(std::fs::File::create(file)?);
    let step = 1.0 / 1200.0;
    write_tiled_f32(
        &mut out,
        (n, n),
        256,
        Model::Geographic,
        (136.0, 39.0),
        (step, -step),
        None,
        false,
        height,
    )?;
    println!("wrote 16 tiles into {dir} and {file} ({n}² samples)");
    Ok(())
}
