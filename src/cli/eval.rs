//! `terrastream eval`: the first paper's LOD evaluation of a tileset (section 4.6).

use std::path::{Path, PathBuf};

use anyhow::{Context, Result};
use terrastream::{client, eval};

#[derive(clap::Args)]
pub struct EvalArgs {
    /// Tileset directory (a terrain `bake` or a `bake-model` output).
    pub dir: PathBuf,
    /// Report directory (report.md, fmeasure.png, frametime.png, frames/).
    #[arg(long, default_value = "eval-report")]
    pub out: PathBuf,
    /// Viewport width in pixels.
    #[arg(long, default_value_t = eval::analysis::DEFAULT_EVAL_WIDTH)]
    pub width: u32,
    /// Viewport height in pixels.
    #[arg(long, default_value_t = eval::analysis::DEFAULT_EVAL_HEIGHT)]
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
    #[arg(long, default_value_t = eval::analysis::DEFAULT_AZIMUTHS)]
    pub azimuths: u32,
    /// Elevations in degrees [default: terrain 20,45,70 about +Z; models -45,0,45 about +Y].
    #[arg(long, value_delimiter = ',', allow_hyphen_values = true)]
    pub elevations: Vec<f64>,
    /// Grid sides N of the instance experiment (N×N instances of the model).
    #[arg(long, value_delimiter = ',', default_values_t = eval::analysis::DEFAULT_GRID_SIDES)]
    pub grid: Vec<u32>,
    /// Skip grid sides above this (for slow adapters such as lavapipe).
    #[arg(long, default_value_t = eval::DEFAULT_MAX_GRID)]
    pub max_grid: u32,
    /// Frames timed per configuration (median reported; one warm-up frame before).
    #[arg(long, default_value_t = eval::DEFAULT_FRAMES)]
    pub frames: u32,
    /// Also replay this flight (JSON, as `client --flight`) over the tileset with everything
    /// resident: primitives and bytes drawn per frame and bytes streamed, written to
    /// OUT/flight.json.
    #[arg(long)]
    pub flight: Option<PathBuf>,
    /// Frames per second of the flight replay.
    #[arg(long, default_value_t = 30.0)]
    pub flight_fps: f64,
    /// Selection rule of the flight replay: `cheapest` (the client's: the cheapest level under
    /// the threshold) or `coarsest` (the rule before levels were compared by cost, for
    /// before/after comparisons).
    #[arg(long, default_value = "cheapest", value_parser = ["cheapest", "coarsest"])]
    pub flight_rule: String,
    /// Skip the large-terrain frame-time experiment on terrain tilesets.
    #[arg(long)]
    pub no_frame_times: bool,
}

pub fn run(a: &EvalArgs, quiet: bool) -> Result<()> {
    use eval::{self as evaluate, EvalOptions};
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
    let (report, samples) = evaluate::run(&a.dir, &opts, |line| {
        if !quiet {
            eprintln!("{line}");
        }
    })?;
    let path = evaluate::write_report(&report, &samples, &a.out)?;
    eprintln!("report: {}", path.display());
    let mut extra = Vec::new();
    if report.subject == evaluate::analysis::Subject::Terrain && !a.no_frame_times {
        let f = evaluate::frames::terrain_frames(&a.dir, &opts, |line| {
            if !quiet {
                eprintln!("{line}");
            }
        })?;
        write_json(&a.out, "frames.json", &f)?;
        extra.push(f.text());
    }
    if let Some(flight) = &a.flight {
        let store = terrastream::store::Store::new(&a.dir);
        let manifest = store.manifest()?;
        let tree = if store.manifest_kind()? == terrastream::store::TilesetKind::Model {
            let mut t = client::tree::TileTree::new(terrastream::tiling::Pyramid::new(2, 2, 1)?);
            t.insert_chunk(&store.chunk(terrastream::tiling::TileKey::new(0, 0, 0))?)?;
            t
        } else {
            client::tree::TileTree::load(&store)?
        };
        let f = client::stream::flight_path::Flight::load(flight)?;
        let rule = if a.flight_rule == "coarsest" {
            evaluate::flight_cost::Rule::Coarsest
        } else {
            evaluate::flight_cost::Rule::Cheapest
        };
        let cost = evaluate::flight_cost::flight_cost(
            flight,
            &tree,
            rule,
            &manifest.bounds,
            &f,
            (a.width, a.height, a.fov),
            a.threshold,
            a.flight_fps,
        )?;
        write_json(&a.out, "flight.json", &cost)?;
        extra.push(cost.summary());
    }
    // The summary's last line stays `F-measure: …` (scripts read it).
    let text = report.text();
    let (head, last) = text.rsplit_once('\n').unwrap_or(("", &text));
    outln!("{head}");
    for e in &extra {
        outln!("{e}");
    }
    outln!("{last}");
    Ok(())
}

/// Writes `v` as `OUT/NAME` (pretty JSON), through a temporary file renamed into place.
fn write_json<T: serde::Serialize>(out: &Path, name: &str, v: &T) -> Result<()> {
    let p = out.join(name);
    let tmp = out.join(format!(".{name}.tmp"));
    let mut bytes = serde_json::to_vec_pretty(v)?;
    bytes.push(b'\n');
    std::fs::write(&tmp, bytes).with_context(|| format!("writing {}", tmp.display()))?;
    std::fs::rename(&tmp, &p).with_context(|| format!("writing {}", p.display()))?;
    eprintln!("{name}: {}", p.display());
    Ok(())
}
