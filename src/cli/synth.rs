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
}

pub fn run(a: &SynthArgs) -> Result<()> {
    let SynthArgs { ref out, width, height, cell_size, seed } = *a;
    let height = height.unwrap_or(width);
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
