//! `terrastream eval`: renders a tileset's full-detail geometry and the client's LOD selection
//! (blobs read from the tileset directory, no server) from the cameras of [`crate::eval::analysis`],
//! compares them pixel by pixel, runs the instance experiment on model tilesets
//! ([`crate::eval::instances`]) and writes the report (Markdown, PNG charts, sample frames).
//!
//! - Full detail, terrain: every leaf tile's level 0 (the full-resolution TIN; leaves share
//!   their border vertices, so no skirts). Model: its level 0 (the quantized mesh).
//! - LOD: a fresh [`Selector`] (no fades) per camera at the threshold, everything resident;
//!   meshes get skirts as deep as their error plus the largest error drawn in the frame (the
//!   crack bound of [`skirt_depth`]), none on the dataset's outer border; models get none.
//! - Per level: level `l` forced on the nodes the selection draws.

use glam::DVec3;
use std::collections::HashMap;
use std::path::{Path, PathBuf};
use std::time::Instant;

use crate::bake::model_tileset as bake_model;
use crate::client::ClientError;
use crate::client::render::{Renderer, covered, footprint_half};
use crate::client::select::{AllResident, DrawItem, SelectParams, Selector, skirt_depth};
use crate::client::tree::TileTree;
use crate::codec::{self, Blob, Geometry};
use crate::eval::EvalError;
use crate::eval::analysis::{
    self, CameraPlan, CameraResult, Confusion, DepthDiff, EvalReport, InstanceRow, Subject, linear_depth,
};
use crate::eval::instances::InstanceBench;
use crate::geom::Bounds;
use crate::store::{Store, TilesetKind};
use crate::tiling::TileKey;

/// Frames timed per configuration of the instance experiment (after one warm-up frame).
pub const DEFAULT_FRAMES: u32 = 5;
/// Largest grid side N run by default (81: 6,561 instances, the paper's largest).
pub const DEFAULT_MAX_GRID: u32 = 81;

/// Settings of one evaluation.
#[derive(Debug, Clone, PartialEq)]
pub struct EvalOptions {
    pub width: u32,
    pub height: u32,
    pub fov_deg: f64,
    pub threshold_px: f64,
    /// Distance factors; empty: [`analysis::DEFAULT_DISTANCES`].
    pub distances: Vec<f64>,
    pub azimuths: u32,
    /// Elevations in degrees; empty: the subject's defaults.
    pub elevations: Vec<f64>,
    /// Grid sides N of the instance experiment.
    pub grid_sides: Vec<u32>,
    /// Sides above this are not run (slow adapters).
    pub max_grid: u32,
    pub frames: u32,
}

impl Default for EvalOptions {
    fn default() -> Self {
        Self {
            width: analysis::DEFAULT_EVAL_WIDTH,
            height: analysis::DEFAULT_EVAL_HEIGHT,
            fov_deg: crate::client::select::DEFAULT_FOV_DEG,
            threshold_px: crate::client::select::DEFAULT_THRESHOLD_PX,
            distances: Vec::new(),
            azimuths: analysis::DEFAULT_AZIMUTHS,
            elevations: Vec::new(),
            grid_sides: analysis::DEFAULT_GRID_SIDES.to_vec(),
            max_grid: DEFAULT_MAX_GRID,
            frames: DEFAULT_FRAMES,
        }
    }
}

impl EvalOptions {
    /// The camera plan of these options for `subject` (empty lists: the defaults).
    #[must_use]
    pub fn plan(&self, subject: Subject) -> CameraPlan {
        CameraPlan {
            width: self.width,
            height: self.height,
            fov_deg: self.fov_deg,
            distances: if self.distances.is_empty() {
                analysis::DEFAULT_DISTANCES.to_vec()
            } else {
                self.distances.clone()
            },
            azimuths: self.azimuths,
            elevations: if self.elevations.is_empty() {
                subject.default_elevations()
            } else {
                self.elevations.clone()
            },
        }
    }
}

/// The tileset as the evaluation reads it.
pub(super) struct Tileset {
    store: Store,
    pub(super) subject: Subject,
    pub(super) tree: TileTree,
    pub(super) bounds: Bounds,
    /// Point spacing (world units) of level `l` at depth `z`: `spacing[l] * step(z)`.
    spacing: Vec<f64>,
    /// Footprint half-width (cells) of each point level.
    half: Vec<f64>,
    levels: Vec<String>,
    /// The manifest's source file name (for the report's paper figures).
    source_file: String,
    blobs: HashMap<(TileKey, u8), Blob>,
}

impl Tileset {
    pub(super) fn open(dir: &Path) -> Result<Self, EvalError> {
        let store = Store::new(dir);
        let kind = store.manifest_kind()?;
        let manifest = store.manifest()?;
        let tree = if kind == TilesetKind::Model {
            // A model tileset has one node and no raster (its manifest's raster size is 0): a
            // one-node quadtree holds it.
            let pyramid = crate::tiling::Pyramid::new(2, 2, 1)?;
            let mut tree = TileTree::new(pyramid);
            tree.insert_chunk(&store.chunk(bake_model::MODEL_TILE)?)?;
            tree
        } else {
            TileTree::load(&store)?
        };
        let (subject, spacing) = match kind {
            TilesetKind::Terrain => {
                let cell = manifest.frame.dx.abs().max(manifest.frame.dy.abs());
                let s = manifest
                    .levels
                    .iter()
                    .map(|l| l.cell_leaf_cells.map_or(0.0, |c| f64::from(c) * cell))
                    .collect::<Vec<_>>();
                (Subject::Terrain, s)
            }
            TilesetKind::Model => {
                let m = store.model_manifest()?;
                (Subject::Model, m.model.levels.iter().map(|l| l.cell.unwrap_or(0.0)).collect())
            }
        };
        let levels = manifest
            .levels
            .iter()
            .zip(&manifest.totals)
            .map(|(l, t)| {
                if l.kind == crate::codec::Kind::Mesh {
                    format!("{} mesh ({} vertices, {} triangles)", l.level, t.count, t.triangles)
                } else {
                    format!(
                        "{} points ({} points, worst error {})",
                        l.level,
                        t.count,
                        analysis::fmt_opt(Some(t.worst.geometric()))
                    )
                }
            })
            .collect();
        if tree.is_empty() {
            return Err(EvalError::EmptyIndex(dir.to_owned()));
        }
        let half = (0..manifest.levels.len()).map(|l| footprint_half(&manifest, l as u8)).collect();
        Ok(Self {
            store,
            subject,
            tree,
            bounds: manifest.bounds,
            spacing,
            half,
            levels,
            source_file: manifest.source.file.clone(),
            blobs: HashMap::new(),
        })
    }

    fn blob(&mut self, key: TileKey, level: u8) -> Result<&Blob, EvalError> {
        if !self.blobs.contains_key(&(key, level)) {
            let path = || self.store.blob_path(key, level);
            let bytes = self.store.read_blob(key, level)?.ok_or_else(|| EvalError::BlobMissing(path()))?;
            let blob = codec::decode(&bytes).map_err(|source| EvalError::Blob { path: path(), source })?;
            self.blobs.insert((key, level), blob);
        }
        Ok(&self.blobs[&(key, level)])
    }

    fn point_spacing(&self, key: TileKey, level: u8) -> f64 {
        let s = self.spacing.get(usize::from(level)).copied().unwrap_or(0.0);
        match self.subject {
            Subject::Terrain => s * f64::from(self.tree.pyramid().step(key.z)),
            Subject::Model => s,
        }
    }

    fn outer(&self) -> Option<Bounds> {
        (self.subject == Subject::Terrain).then_some(self.bounds)
    }

    /// Uploads the draws (skirts as deep as the crack bound of this set of draws).
    pub(super) fn upload(&mut self, r: &mut Renderer, draws: &[DrawItem]) -> Result<(u64, u64), EvalError> {
        let max_e = draws.iter().map(|d| d.error_world).fold(0.0, f64::max);
        let outer = self.outer();
        let (mut points, mut triangles) = (0, 0);
        for d in draws {
            let depth = match self.subject {
                Subject::Terrain => skirt_depth(d.error_world, max_e),
                Subject::Model => 0.0,
            };
            let spacing = self.point_spacing(d.key, d.level);
            let half = self.half.get(usize::from(d.level)).copied().unwrap_or(0.0);
            let blob = self.blob(d.key, d.level)?;
            match &blob.geometry {
                Geometry::Mesh(m) => triangles += m.triangles.len() as u64,
                Geometry::Points(p) => points += p.positions.len() as u64,
            }
            r.upload(blob, depth, outer.as_ref(), spacing, half);
        }
        Ok((points, triangles))
    }
}

pub(super) fn item(tree: &TileTree, node: u32, level: u8) -> DrawItem {
    let e = tree.level_errors(node).get(usize::from(level)).copied().unwrap_or(0.0);
    DrawItem {
        node,
        key: tree.node(node).key,
        level,
        alpha: 1.0,
        retiring: false,
        error_px: 0.0,
        error_world: e,
    }
}

/// A rendered frame: coverage and linear depth (NaN where empty).
struct RenderedFrame {
    image: image::RgbaImage,
    mask: Vec<bool>,
    depth: Vec<f64>,
}

fn frame(r: &Renderer, c: &analysis::EvalCamera, draws: &[DrawItem]) -> Result<RenderedFrame, EvalError> {
    let (near, far) = (c.near, c.far);
    let (image, raw) = r.render_with_depth(&c.camera, draws, near, far)?;
    let mask = covered(&image);
    let depth = raw
        .iter()
        .zip(&mask)
        .map(|(&z, &c)| if c { linear_depth(z, near, far).unwrap_or(f64::NAN) } else { f64::NAN })
        .collect();
    Ok(RenderedFrame { image, mask, depth })
}

/// Runs the evaluation of the tileset in `dir`; `log` receives progress lines. Frames of the
/// middle elevation's first azimuth are kept for the report (`(name, image)`).
pub fn run(
    dir: &Path,
    opts: &EvalOptions,
    mut log: impl FnMut(&str),
) -> Result<(EvalReport, Vec<(String, image::RgbaImage)>), EvalError> {
    if !(opts.threshold_px.is_finite() && opts.threshold_px > 0.0) {
        return Err(EvalError::Threshold(opts.threshold_px));
    }
    let mut ts = Tileset::open(dir)?;
    let plan = opts.plan(ts.subject);
    let cams = analysis::cameras(&ts.bounds, ts.subject, &plan)?;
    let gpu = crate::gpu::open()?;
    let adapter = gpu.adapter.clone();
    log(&format!("adapter: {adapter}; {} cameras", cams.len()));
    let origin = ts.bounds.min;
    let mut reference =
        Renderer::new(gpu.device.clone(), gpu.queue.clone(), opts.width, opts.height, origin)?;
    let mut lod = Renderer::new(gpu.device.clone(), gpu.queue.clone(), opts.width, opts.height, origin)?;
    let tree = ts.tree.clone();
    let leaves: Vec<DrawItem> = tree
        .nodes()
        .iter()
        .enumerate()
        .filter(|(_, n)| n.is_leaf() && n.level_count() > 0)
        .map(|(i, _)| DrawItem { error_world: 0.0, ..item(&tree, i as u32, 0) })
        .collect();
    let (mut ref_points, mut ref_triangles) = (0u64, 0u64);
    for d in &leaves {
        let blob = ts.blob(d.key, 0)?;
        match &blob.geometry {
            Geometry::Mesh(m) => ref_triangles += m.triangles.len() as u64,
            Geometry::Points(p) => ref_points += p.positions.len() as u64,
        }
        let outer = ts.outer();
        let spacing = ts.point_spacing(d.key, 0);
        let blob = ts.blob(d.key, 0)?;
        reference.upload(blob, 0.0, outer.as_ref(), spacing, 0.0);
    }
    let level_count = tree.nodes().iter().map(crate::client::tree::TreeNode::level_count).max().unwrap_or(1);
    let mut selector = Selector::new(SelectParams {
        threshold_px: opts.threshold_px,
        fade_seconds: 0.0,
        ..SelectParams::default()
    })?;
    let keep_el = plan.elevations[plan.elevations.len() / 2];
    let mut samples = Vec::new();
    let mut results = Vec::with_capacity(cams.len());
    let t0 = Instant::now();
    for (ci, c) in cams.iter().enumerate() {
        let full = frame(&reference, c, &leaves)?;
        selector.reset();
        let draws: Vec<DrawItem> = selector
            .select(&tree, &c.camera, &AllResident, 0.0)?
            .draws
            .iter()
            .filter(|d| !d.retiring)
            .copied()
            .collect();
        let mut drawn_per_level = vec![0u32; level_count];
        for d in &draws {
            if let Some(n) = drawn_per_level.get_mut(usize::from(d.level)) {
                *n += 1;
            }
        }
        for d in &draws {
            lod.evict(d.key, d.level);
        }
        let (points, triangles) = ts.upload(&mut lod, &draws)?;
        let sel = frame(&lod, c, &draws)?;
        for d in &draws {
            lod.evict(d.key, d.level);
        }
        let conf = Confusion::of_masks(&full.mask, &sel.mask);
        let depth = DepthDiff::of(&full.depth, &sel.depth);
        let mut per_level = Vec::with_capacity(level_count);
        for l in 0..level_count {
            // Every selected node at level l, or where it does not store l (the level did not
            // pay) at its coarsest stored level finer than l, which is cheaper anyway.
            let forced: Vec<DrawItem> = draws
                .iter()
                .map(|d| {
                    let n = tree.node(d.node);
                    let stored = (0..=l.min(n.level_count().saturating_sub(1)) as u8)
                        .rev()
                        .find(|&s| n.has_level(s))
                        .unwrap_or(0);
                    item(&tree, d.node, stored)
                })
                .collect();
            ts.upload(&mut lod, &forced)?;
            let f = frame(&lod, c, &forced)?;
            for d in &forced {
                lod.evict(d.key, d.level);
            }
            per_level.push(Confusion::of_masks(&full.mask, &f.mask));
        }
        if (c.elevation_deg - keep_el).abs() < 1e-9 && c.azimuth_deg.abs() < 1e-9 {
            let tag = format!("d{}", c.distance_factor);
            samples.push((format!("full-{tag}.png"), full.image));
            samples.push((format!("lod-{tag}.png"), sel.image));
        }
        log(&format!(
            "camera {}/{}: distance {}× az {}° el {}°: F {:.4} (levels drawn {:?})",
            ci + 1,
            cams.len(),
            c.distance_factor,
            c.azimuth_deg,
            c.elevation_deg,
            conf.f_measure(),
            drawn_per_level
        ));
        results.push(CameraResult {
            distance_factor: c.distance_factor,
            distance: c.distance,
            azimuth_deg: c.azimuth_deg,
            elevation_deg: c.elevation_deg,
            lod: conf,
            depth,
            drawn_per_level,
            points_drawn: points,
            triangles_drawn: triangles,
            per_level,
        });
    }
    log(&format!("coverage: {} cameras in {:.1} s", cams.len(), t0.elapsed().as_secs_f64()));
    drop((reference, lod));
    let mut report = EvalReport {
        tileset: dir.display().to_string(),
        source_file: ts.source_file.clone(),
        subject: ts.subject,
        adapter,
        plan,
        threshold_px: opts.threshold_px,
        levels: ts.levels.clone(),
        reference_points: ref_points,
        reference_triangles: ref_triangles,
        results,
        instances: Vec::new(),
        instances_note: None,
        grid_skipped: Vec::new(),
    };
    if ts.subject == Subject::Model {
        instances(&mut ts, &tree, gpu, opts, &mut report, &mut log)?;
    } else {
        report.instances_note = Some(
            "The N×N instance experiment needs a model tileset (bake-model); not run on terrain.".into(),
        );
    }
    Ok((report, samples))
}

fn instances(
    ts: &mut Tileset,
    tree: &TileTree,
    gpu: crate::gpu::GpuContext,
    opts: &EvalOptions,
    report: &mut EvalReport,
    log: &mut impl FnMut(&str),
) -> Result<(), EvalError> {
    let root = tree.root().ok_or(EvalError::NoRoot)?;
    let node = tree.node(root);
    let key = node.key;
    // The levels the model stores (ids may skip a level that did not pay); the bench numbers
    // them 0.. in this order.
    let ids: Vec<u8> = (0..node.level_count() as u8).filter(|&l| node.has_level(l)).collect();
    let mut levels = Vec::with_capacity(ids.len());
    for &l in &ids {
        let spacing = ts.point_spacing(key, l);
        levels.push((ts.blob(key, l)?.clone(), spacing, ts.half.get(usize::from(l)).copied().unwrap_or(0.0)));
    }
    let position = |id: usize| ids.iter().position(|&l| usize::from(l) == id).unwrap_or(0);
    let errors = tree.level_errors(root).to_vec();
    let costs = tree.level_costs(root).to_vec();
    let (c, r) = analysis::bounding_sphere(&ts.bounds);
    let size = ts.bounds.size();
    let spacing = analysis::GRID_SPACING * size[0].max(size[1]).max(size[2]);
    let bench = InstanceBench::new(gpu.device, gpu.queue, opts.width, opts.height, ts.bounds.min, &levels)?;
    let frames = opts.frames.max(1);
    for &n in &opts.grid_sides {
        if n > opts.max_grid {
            report.grid_skipped.push(n);
            continue;
        }
        let offsets = analysis::grid_offsets(n, spacing, ts.subject);
        let cam = analysis::grid_camera(c, r, n, spacing, ts.subject, opts.width, opts.height, opts.fov_deg);
        let view = cam.camera.view()?;
        let chosen: Vec<usize> = offsets
            .iter()
            .map(|o| {
                let centre = c + DVec3::from_array(*o);
                let d = (centre - view.eye).length();
                position(analysis::level_for(&errors, &costs, view.k, d, opts.threshold_px))
            })
            .collect();
        let full = vec![0usize; offsets.len()];
        let (t_full, c_full) = bench.time_frames(&cam.camera, cam.far, &offsets, &full, frames)?;
        let (t_lod, c_lod) = bench.time_frames(&cam.camera, cam.far, &offsets, &chosen, frames)?;
        // Instances per level id (0 for a level not stored).
        let mut per_level = vec![0; node.level_count()];
        for (&id, &c) in ids.iter().zip(&c_lod.per_level) {
            per_level[usize::from(id)] = c;
        }
        let row = InstanceRow {
            n,
            ms_full: analysis::median(&t_full),
            ms_lod: analysis::median(&t_lod),
            per_level,
            triangles_full: c_full.triangles,
            triangles_lod: c_lod.triangles,
            points_lod: c_lod.points,
        };
        log(&format!(
            "instances {} ({n}×{n}): without LOD {:.2} ms, with LOD {:.2} ms, ratio {:.2}; per level {:?}",
            n * n,
            row.ms_full,
            row.ms_lod,
            row.ratio(),
            row.per_level
        ));
        report.instances.push(row);
    }
    if !report.grid_skipped.is_empty() {
        report.instances_note = Some(format!(
            "Grid sides {:?} were not run: over --max-grid {} (set for slow adapters).",
            report.grid_skipped, opts.max_grid
        ));
    }
    Ok(())
}

/// The per-camera and per-grid figures as JSON (for scripts; the Markdown is for people).
#[must_use]
pub fn results_json(report: &EvalReport) -> serde_json::Value {
    let conf = |c: &Confusion| {
        serde_json::json!({
            "tp": c.tp, "fp": c.fp, "fn": c.fn_,
            "recall": c.recall(), "precision": c.precision(), "f_measure": c.f_measure(),
        })
    };
    let o = report.overall();
    serde_json::json!({
        "tileset": report.tileset,
        "kind": report.subject.name(),
        "adapter": report.adapter,
        "threshold_px": report.threshold_px,
        "viewport": [report.plan.width, report.plan.height],
        "fov_deg": report.plan.fov_deg,
        "f_measure": o.mean_f,
        "recall": o.mean_recall,
        "precision": o.mean_precision,
        "pooled": conf(&o.lod),
        "mean_abs_depth_diff": o.depth.mean(),
        "per_level_f_measure": o.per_level_mean_f,
        "cameras": report.results.iter().map(|r| serde_json::json!({
            "distance_factor": r.distance_factor,
            "distance": r.distance,
            "azimuth_deg": r.azimuth_deg,
            "elevation_deg": r.elevation_deg,
            "lod": conf(&r.lod),
            "mean_abs_depth_diff": r.depth.mean(),
            "drawn_per_level": r.drawn_per_level,
            "points_drawn": r.points_drawn,
            "triangles_drawn": r.triangles_drawn,
            "per_level": r.per_level.iter().map(conf).collect::<Vec<_>>(),
        })).collect::<Vec<_>>(),
        "instances": report.instances.iter().map(|r| serde_json::json!({
            "n": r.n, "instances": r.n * r.n,
            "ms_without_lod": r.ms_full, "ms_with_lod": r.ms_lod, "ratio": r.ratio(),
            "instances_per_level": r.per_level,
            "triangles_without_lod": r.triangles_full,
            "triangles_with_lod": r.triangles_lod, "points_with_lod": r.points_lod,
        })).collect::<Vec<_>>(),
        "grid_skipped": report.grid_skipped,
    })
}

/// Writes `out/report.md`, `out/results.json`, `out/fmeasure.png`, `out/frametime.png` (when
/// the instance experiment ran) and the sample frames under `out/frames/`; returns the report's
/// path.
pub fn write_report(
    report: &EvalReport,
    samples: &[(String, image::RgbaImage)],
    out: &Path,
) -> Result<PathBuf, EvalError> {
    let io = |p: &Path| {
        let p = p.to_owned();
        move |e: std::io::Error| EvalError::from(ClientError::Io { path: p, source: e })
    };
    std::fs::create_dir_all(out.join("frames")).map_err(io(out))?;
    let save = |img: &image::RgbaImage, p: &Path| -> Result<(), EvalError> {
        Renderer::save_png(img, p)?;
        Ok(())
    };
    save(&analysis::fmeasure_chart(report).draw(), &out.join("fmeasure.png"))?;
    let ft = match analysis::frametime_chart(&report.instances) {
        Some(ch) => {
            save(&ch.draw(), &out.join("frametime.png"))?;
            Some("frametime.png")
        }
        None => None,
    };
    let mut md = String::new();
    if !samples.is_empty() {
        md.push_str("## Sample frames (full detail | LOD)\n\n");
        for pair in samples.chunks(2) {
            for (name, img) in pair {
                save(img, &out.join("frames").join(name))?;
            }
            let names: Vec<String> = pair.iter().map(|(n, _)| format!("![{n}](frames/{n})")).collect();
            md.push_str(&names.join(" "));
            md.push_str("\n\n");
        }
    }
    let json = serde_json::to_vec_pretty(&results_json(report))?;
    crate::store::write_atomic(&out.join("results.json"), &json)?;
    md.push_str("Per-camera figures: [results.json](results.json).\n\n");
    let md = report.markdown("fmeasure.png", ft, &md);
    let path = out.join("report.md");
    crate::store::write_atomic(&path, md.as_bytes())?;
    Ok(path)
}
