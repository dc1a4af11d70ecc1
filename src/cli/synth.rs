//! `terrastream synth`: a deterministic synthetic terrain as a float32 GeoTIFF.

use std::path::PathBuf;

use anyhow::{Context, Result, bail};
use terrastream::raster;

#[derive(clap::Args)]
pub struct SynthArgs {
    /// Output .tif file.
    #[arg(long)]
    pub out: PathBuf,
    /// Width in samples.
    #[arg(long, default_value_t = 1025)]
    pub width: u32,
    /// Height in samples (default: the width).
    #[arg(long)]
    pub height: Option<u32>,
    /// Cell size in metres.
    #[arg(long, default_value_t = 10.0)]
    pub cell_size: f64,
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Write tiles of this side (a multiple of 16) instead of strips, generated tile row by tile
    /// row so any size fits in memory; BigTIFF past 4 GiB.
    #[arg(long)]
    pub tiled: Option<u32>,
}

pub fn run(a: &SynthArgs) -> Result<()> {
    let SynthArgs { ref out, width, height, cell_size, seed, tiled } = *a;
    let height = height.unwrap_or(width);
    if let Some(tile) = tiled {
        return write_tiled(out, width, height, cell_size, seed, tile);
    }
    if width < 2 || height < 2 || u64::from(width) * u64::from(height) > 1 << 30 {
        bail!("--width/--height must be 2 or more and at most 2^30 samples together");
    }
    if !(cell_size.is_finite() && cell_size > 0.0) {
        bail!("--cell-size must be a positive number");
    }
    let heights = terrastream::raster::synth::terrain(width, height, seed);
    let bytes = raster::geotiff::encode_f32(width, height, &heights, (0.0, 0.0), (cell_size, -cell_size))
        .with_context(|| format!("{}: encoding GeoTIFF", out.display()))?;
    terrastream::store::write_atomic(out, &bytes)?;
    outln!("wrote {} ({width}×{height} samples, {cell_size} m cells, seed {seed})", out.display());
    Ok(())
}

/// `synth --tiled`: a tiled (Big)TIFF written through a temporary file, renamed when complete.
fn write_tiled(
    out: &std::path::Path,
    width: u32,
    height: u32,
    cell_size: f64,
    seed: u64,
    tile: u32,
) -> Result<()> {
    use rayon::prelude::*;
    if width < 2 || height < 2 || width > 1 << 20 || height > 1 << 20 {
        bail!("--width/--height must be 2 to 2^20 samples");
    }
    if !(cell_size.is_finite() && cell_size > 0.0) {
        bail!("--cell-size must be a positive number");
    }
    if tile == 0 || !tile.is_multiple_of(16) || tile > 4096 {
        bail!("--tiled must be a multiple of 16, at most 4096");
    }
    let big = u64::from(width) * u64::from(height) * 4 > 3 << 30;
    let tmp = out.with_extension("tif.partial");
    let file = std::fs::File::create(&tmp).with_context(|| format!("{}: cannot create", tmp.display()))?;
    let mut w = std::io::BufWriter::with_capacity(8 << 20, file);
    // One band of `tile` rows generated in parallel at a time.
    let mut band: (u32, Vec<f32>) = (u32::MAX, Vec::new());
    let r = raster::geotiff::write_tiled_f32(
        &mut w,
        (width, height),
        tile,
        raster::geotiff::Model::Projected,
        (0.0, 0.0),
        (cell_size, -cell_size),
        None,
        big,
        |c, r| {
            let b = r / tile;
            if band.0 != b {
                let rows: Vec<u32> = (b * tile..((b + 1) * tile).min(height)).collect();
                band = (
                    b,
                    rows.par_iter()
                        .flat_map_iter(|&r| {
                            (0..width).map(move |c| raster::synth::height_at(width, height, seed, c, r))
                        })
                        .collect(),
                );
            }
            band.1[((r - b * tile) * width + c) as usize]
        },
    );
    let done = r
        .and_then(|()| w.into_inner().map_err(std::io::IntoInnerError::into_error))
        .and_then(|f| f.sync_all());
    if let Err(e) = done {
        let _ = std::fs::remove_file(&tmp);
        bail!("{}: writing the tiled GeoTIFF: {e}", out.display());
    }
    std::fs::rename(&tmp, out).with_context(|| format!("{}: cannot rename into place", out.display()))?;
    outln!(
        "wrote {} ({width}×{height} samples in {tile}² tiles{}, {cell_size} m cells, seed {seed})",
        out.display(),
        if big { ", BigTIFF" } else { "" }
    );
    Ok(())
}
