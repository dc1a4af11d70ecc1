//! `terrastream eval`: the first paper's LOD evaluation of a tileset (section 4.6).

use std::path::PathBuf;

use anyhow::Result;
use terrastream::client;

#[derive(clap::Args)]
pub struct EvalArgs {
    /// Tileset directory (a terrain `bake` or a `bake-model` output).
    pub dir: PathBuf,
    /// Report directory (report.md, fmeasure.png, frametime.png, frames/).
    #[arg(long, default_value = "eval-report")]
    pub out: PathBuf,
    /// Viewport width in pixels.
    #[arg(long, default_value_t = client::eval::analysis::DEFAULT_EVAL_WIDTH)]
    pub width: u32,
    /// Viewport height in pixels.
    #[arg(long, default_value_t = client::eval::analysis::DEFAULT_EVAL_HEIGHT)]
    pub height: u32,
    /// Horizontal field of view in degrees.
    #[arg(long, default_value_t = client::select::DEFAULT_FOV_DEG)]
    pub fov: f64,
    /// Screen-space error threshold in pixels (the client's selection).
    #[arg(long, default_value_t = client::select::DEFAULT_THRESHOLD_PX)]
    pub threshold: f64,
    /// Camera distances, in multiples of the distance at which the bounding sphere fills the
    /// view [default: 0.5,1,2,4,8].
    #[arg(long, value_delimiter = ',')]
    pub distances: Vec<f64>,
    /// Azimuths per distance and elevation, spread evenly over 360°.
    #[arg(long, default_value_t = client::eval::analysis::DEFAULT_AZIMUTHS)]
    pub azimuths: u32,
    /// Elevations in degrees [default: terrain 20,45,70 about +Z; models -45,0,45 about +Y].
    #[arg(long, value_delimiter = ',', allow_hyphen_values = true)]
    pub elevations: Vec<f64>,
    /// Grid sides N of the instance experiment (N×N instances of the model).
    #[arg(long, value_delimiter = ',', default_values_t = client::eval::analysis::DEFAULT_GRID_SIDES)]
    pub grid: Vec<u32>,
    /// Skip grid sides above this (for slow adapters such as lavapipe).
    #[arg(long, default_value_t = client::eval::DEFAULT_MAX_GRID)]
    pub max_grid: u32,
    /// Frames timed per configuration (median reported; one warm-up frame before).
    #[arg(long, default_value_t = client::eval::DEFAULT_FRAMES)]
    pub frames: u32,
    /// Print only the summary (no per-camera progress).
    #[arg(long)]
    pub quiet: bool,
}

pub fn run(a: &EvalArgs) -> Result<()> {
    use client::eval::{self as evaluate, EvalOptions};
    let opts = EvalOptions {
        width: a.width,
        height: a.height,
        fov_deg: a.fov,
        threshold_px: a.threshold,
        distances: a.distances.clone(),
        azimuths: a.azimuths,
        elevations: a.elevations.clone(),
        grid_sides: a.grid.clone(),
        max_grid: a.max_grid,
        frames: a.frames,
    };
    let quiet = a.quiet;
    let (report, samples) = evaluate::run(&a.dir, &opts, |line| {
        if !quiet {
            eprintln!("{line}");
        }
    })?;
    let path = evaluate::write_report(&report, &samples, &a.out)?;
    eprintln!("report: {}", path.display());
    outln!("{}", report.text());
    Ok(())
}
