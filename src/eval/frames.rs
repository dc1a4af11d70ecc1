//! The first paper's large-terrain experiment on a terrain tileset (`eval` on terrain): from the
//! evaluation's cameras, the frame time of full detail (every leaf tile's full-resolution TIN)
//! and of the LOD selection on this machine's adapter, with the primitives and bytes each
//! draws. The paper drew 1,681 tiles (41 × 41) with 5 levels at 40 FPS on a GTX 1080 Ti
//! (F 0.972); the F-measure of the same cameras is the evaluation's own.

use std::path::Path;
use std::time::Instant;

use serde::Serialize;

use super::EvalError;
use super::analysis::{self, Subject};
use super::run::{EvalOptions, Tileset, item};
use crate::client::render::Renderer;
use crate::client::select::{AllResident, DrawItem, SelectParams, Selector};

/// The paper's large-terrain figures (`../shared/papers/tables.md`, *Large terrain*).
pub const PAPER_TILES: u32 = 1_681;
pub const PAPER_LEVELS: u32 = 5;
pub const PAPER_FPS: f64 = 40.0;

/// One camera of the experiment.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct FrameRow {
    pub distance_factor: f64,
    pub azimuth_deg: f64,
    pub elevation_deg: f64,
    /// Median frame time (ms) of full detail and of the LOD selection.
    pub ms_full: f64,
    pub ms_lod: f64,
    pub draws_lod: u32,
    /// Mesh triangles plus points drawn, and the bytes of the blobs drawn.
    pub primitives_full: u64,
    pub primitives_lod: u64,
    pub bytes_full: u64,
    pub bytes_lod: u64,
}

/// The experiment's result.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct TerrainFrames {
    pub adapter: String,
    pub leaf_tiles: u32,
    /// Levels per node in the ladder (mesh + point levels).
    pub levels: u32,
    pub frames_per_camera: u32,
    pub rows: Vec<FrameRow>,
}

impl TerrainFrames {
    /// Terminal lines: per distance the medians, then the paper's figures.
    #[must_use]
    pub fn text(&self) -> String {
        use std::fmt::Write as _;
        let mut s = format!(
            "large-terrain experiment: {} leaf tiles, {} levels, adapter {}, median of {} frames per camera\n\
             distance  full ms  LOD ms  speed-up  FPS full  FPS LOD  primitives full → LOD  bytes full → LOD\n",
            self.leaf_tiles, self.levels, self.adapter, self.frames_per_camera
        );
        let mut factors: Vec<f64> = self.rows.iter().map(|r| r.distance_factor).collect();
        factors.sort_by(f64::total_cmp);
        factors.dedup();
        for f in factors {
            let rows: Vec<&FrameRow> =
                self.rows.iter().filter(|r| r.distance_factor.total_cmp(&f).is_eq()).collect();
            let med = |g: &dyn Fn(&FrameRow) -> f64| {
                analysis::median(&rows.iter().map(|r| g(r)).collect::<Vec<_>>())
            };
            let (full, lod) = (med(&|r| r.ms_full), med(&|r| r.ms_lod));
            let _ = writeln!(
                s,
                "{f:>7.2}×  {full:>7.2}  {lod:>6.2}  {:>8.2}  {:>8.1}  {:>7.1}  {:>10.0} → {:<10.0}  {:.0} → {:.0}",
                full / lod.max(1e-9),
                1e3 / full.max(1e-9),
                1e3 / lod.max(1e-9),
                med(&|r| r.primitives_full as f64),
                med(&|r| r.primitives_lod as f64),
                med(&|r| r.bytes_full as f64),
                med(&|r| r.bytes_lod as f64),
            );
        }
        let _ = write!(
            s,
            "paper (GTX 1080 Ti): {PAPER_TILES} terrain tiles of 5,000,000 vertices, {PAPER_LEVELS} levels, {PAPER_FPS} FPS, F 0.972"
        );
        s
    }
}

/// Runs the experiment on the terrain tileset in `dir` from the evaluation's cameras
/// (`opts.frames` timed frames per configuration after one warm-up).
pub fn terrain_frames(
    dir: &Path,
    opts: &EvalOptions,
    mut log: impl FnMut(&str),
) -> Result<TerrainFrames, EvalError> {
    if !(opts.threshold_px.is_finite() && opts.threshold_px > 0.0) {
        return Err(EvalError::Threshold(opts.threshold_px));
    }
    let mut ts = Tileset::open(dir)?;
    if ts.subject != Subject::Terrain {
        return Err(EvalError::NotTerrain(dir.to_owned()));
    }
    let plan = opts.plan(ts.subject);
    let cams = analysis::cameras(&ts.bounds, ts.subject, &plan)?;
    let gpu = crate::gpu::open()?;
    let origin = ts.bounds.min;
    let mut full = Renderer::new(gpu.device.clone(), gpu.queue.clone(), opts.width, opts.height, origin)?;
    let mut lod = Renderer::new(gpu.device.clone(), gpu.queue.clone(), opts.width, opts.height, origin)?;
    let tree = ts.tree.clone();
    let leaves: Vec<DrawItem> = tree
        .nodes()
        .iter()
        .enumerate()
        .filter(|(_, n)| n.is_leaf())
        .map(|(i, _)| item(&tree, i as u32, 0))
        .collect();
    let bytes_of = |draws: &[DrawItem]| -> u64 {
        draws.iter().map(|d| tree.level_costs(d.node)[usize::from(d.level)].bytes).sum()
    };
    let (p, t) = ts.upload(&mut full, &leaves)?;
    let (primitives_full, bytes_full) = (p + t, bytes_of(&leaves));
    let levels = tree.nodes().iter().map(|n| n.level_count() as u32).max().unwrap_or(1);
    let frames = opts.frames.max(1);
    let time = |r: &Renderer, c: &analysis::EvalCamera, draws: &[DrawItem]| -> Result<f64, EvalError> {
        let mut ms = Vec::with_capacity(frames as usize);
        for f in 0..=frames {
            let t0 = Instant::now();
            r.draw(&c.camera, draws, c.far)?;
            if f > 0 {
                ms.push(t0.elapsed().as_secs_f64() * 1e3);
            }
        }
        Ok(analysis::median(&ms))
    };
    let mut selector = Selector::new(SelectParams {
        threshold_px: opts.threshold_px,
        fade_seconds: 0.0,
        ..SelectParams::default()
    })?;
    let mut rows = Vec::with_capacity(cams.len());
    for (ci, c) in cams.iter().enumerate() {
        selector.reset();
        let draws: Vec<DrawItem> = selector
            .select(&tree, &c.camera, &AllResident, 0.0)?
            .draws
            .iter()
            .filter(|d| !d.retiring)
            .copied()
            .collect();
        let (p, t) = ts.upload(&mut lod, &draws)?;
        let ms_full = time(&full, c, &leaves)?;
        let ms_lod = time(&lod, c, &draws)?;
        for d in &draws {
            lod.evict(d.key, d.level);
        }
        let row = FrameRow {
            distance_factor: c.distance_factor,
            azimuth_deg: c.azimuth_deg,
            elevation_deg: c.elevation_deg,
            ms_full,
            ms_lod,
            draws_lod: draws.len() as u32,
            primitives_full,
            primitives_lod: p + t,
            bytes_full,
            bytes_lod: bytes_of(&draws),
        };
        log(&format!(
            "frame timing {}/{}: distance {}×: full {:.2} ms, LOD {:.2} ms ({} draws)",
            ci + 1,
            cams.len(),
            c.distance_factor,
            ms_full,
            ms_lod,
            row.draws_lod
        ));
        rows.push(row);
    }
    Ok(TerrainFrames {
        adapter: gpu.adapter.clone(),
        leaf_tiles: leaves.len() as u32,
        levels,
        frames_per_camera: frames,
        rows,
    })
}
