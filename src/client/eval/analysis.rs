//! The first paper's evaluation (section 4.6), pure parts: camera positions on spheres around a
//! tileset's bounds, per-pixel coverage comparison (TP, FP, FN → recall, precision, F-measure),
//! depth differences, aggregation by distance and level, the instance grid of the rendering
//! experiment, the Markdown report and its PNG charts (drawn with `image`, no fonts).
//!
//! No GPU and no file system here: [`crate::client::eval`] renders and writes, this module only
//! computes on values, so every rule is unit-tested.
//!
//! Camera placement: the tileset's bounding sphere (centre `c`, radius `r` = half the box
//! diagonal) is seen from `d = f · d_fit` for each distance factor `f`, where
//! `d_fit = r / sin(φ_min/2)` is the distance at which the sphere just fills the narrower field
//! of view; directions are the two sphere angles, azimuth (evenly spread over 360°) and
//! elevation (a list). Terrain is seen from above (elevations 20°, 45°, 70° about +Z); models
//! from below, level and above (−45°, 0°, 45° about +Y, the Stanford models' up axis).

use std::collections::BTreeMap;
use std::fmt::Write as _;

use crate::client::select::Camera;
use crate::geom::Bounds;
use glam::DVec3;

/// Distance factors (multiples of the fit distance) at which cameras are placed.
pub const DEFAULT_DISTANCES: [f64; 5] = [0.5, 1.0, 2.0, 4.0, 8.0];
/// Azimuths per distance and elevation, evenly spread over 360°.
pub const DEFAULT_AZIMUTHS: u32 = 6;
/// Elevations (degrees above the horizontal plane) for terrain tilesets.
pub const TERRAIN_ELEVATIONS: [f64; 3] = [20.0, 45.0, 70.0];
/// Elevations (degrees) for model tilesets.
pub const MODEL_ELEVATIONS: [f64; 3] = [-45.0, 0.0, 45.0];
/// Viewport of the coverage renders.
pub const DEFAULT_EVAL_WIDTH: u32 = 512;
pub const DEFAULT_EVAL_HEIGHT: u32 = 384;
/// Grid sides N of the rendering experiment (N² = 121 … 6,561 instances, the paper's range).
pub const DEFAULT_GRID_SIDES: [u32; 4] = [11, 21, 41, 81];
/// Instance spacing in the grid, in multiples of the model's longest side.
pub const GRID_SPACING: f64 = 1.5;
/// Elevation (degrees) of the camera that sees the whole instance grid.
pub const GRID_ELEVATION_DEG: f64 = 35.0;
/// The first paper's averages (section 4.6), as cited in DESIGN.md and issue 4.
pub const PAPER_F_AVERAGE: f64 = 0.947;
pub const PAPER_F_TERRAIN: f64 = 0.972;
pub const PAPER_F_BUNNY: f64 = 0.965;

/// What a tileset holds; it decides the sphere's polar axis and default elevations.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Subject {
    Terrain,
    Model,
}

impl Subject {
    /// Unit polar axis and two unit axes spanning the plane perpendicular to it (right-handed).
    #[must_use]
    pub fn axes(self) -> (DVec3, DVec3, DVec3) {
        match self {
            Self::Terrain => (DVec3::Z, DVec3::X, DVec3::Y),
            Self::Model => (DVec3::Y, DVec3::Z, DVec3::X),
        }
    }

    #[must_use]
    pub fn default_elevations(self) -> Vec<f64> {
        match self {
            Self::Terrain => TERRAIN_ELEVATIONS.to_vec(),
            Self::Model => MODEL_ELEVATIONS.to_vec(),
        }
    }

    #[must_use]
    pub fn name(self) -> &'static str {
        match self {
            Self::Terrain => "terrain",
            Self::Model => "model",
        }
    }
}

/// Where the evaluation cameras go and what they see.
#[derive(Debug, Clone, PartialEq)]
pub struct CameraPlan {
    pub width: u32,
    pub height: u32,
    pub fov_deg: f64,
    pub distances: Vec<f64>,
    pub azimuths: u32,
    pub elevations: Vec<f64>,
}

/// One evaluation camera and its place on the sphere.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct EvalCamera {
    pub camera: Camera,
    /// Multiple of the fit distance.
    pub distance_factor: f64,
    /// World distance from the eye to the sphere's centre.
    pub distance: f64,
    pub azimuth_deg: f64,
    pub elevation_deg: f64,
    /// Clip planes that hold the whole bounding sphere (near as close as it allows, for depth
    /// precision).
    pub near: f64,
    pub far: f64,
}

/// Centre and radius (half the box diagonal, at least 1e-9) of the bounds' sphere.
#[must_use]
pub fn bounding_sphere(b: &Bounds) -> (DVec3, f64) {
    (b.center(), (0.5 * b.size().length()).max(1e-9))
}

/// The distance at which a sphere of radius `r` just fills the narrower field of view.
#[must_use]
pub fn fit_distance(r: f64, width: u32, height: u32, fov_deg: f64) -> f64 {
    let tan_h = (fov_deg.to_radians() * 0.5).tan();
    let tan_v = tan_h * f64::from(height) / f64::from(width.max(1));
    let half = tan_h.min(tan_v).atan();
    r / half.sin()
}

/// A camera plan [`cameras`] refuses, naming the setting.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum PlanError {
    #[error("bounds {min:?}..{max:?} are empty or not finite")]
    Bounds { min: [f64; 3], max: [f64; 3] },
    #[error("viewport {width}×{height} is empty")]
    Viewport { width: u32, height: u32 },
    #[error("fov {0} is not between 0 and 180 degrees")]
    Fov(f64),
    #[error("distances {0:?} must be positive multiples of the fit distance")]
    Distances(Vec<f64>),
    #[error("azimuths must be 1 or more")]
    Azimuths,
    #[error("elevations {0:?} must lie strictly between -89 and 89 degrees")]
    Elevations(Vec<f64>),
}

/// Cameras for every (distance, elevation, azimuth), all looking at the sphere's centre with the
/// polar axis up. Errors name the bad setting.
pub fn cameras(bounds: &Bounds, subject: Subject, plan: &CameraPlan) -> Result<Vec<EvalCamera>, PlanError> {
    if !bounds.is_valid() {
        return Err(PlanError::Bounds { min: bounds.min.to_array(), max: bounds.max.to_array() });
    }
    if plan.width == 0 || plan.height == 0 {
        return Err(PlanError::Viewport { width: plan.width, height: plan.height });
    }
    if !(plan.fov_deg > 0.0 && plan.fov_deg < 180.0) {
        return Err(PlanError::Fov(plan.fov_deg));
    }
    if plan.distances.is_empty() || plan.distances.iter().any(|d| !(d.is_finite() && *d > 0.0)) {
        return Err(PlanError::Distances(plan.distances.clone()));
    }
    if plan.azimuths == 0 {
        return Err(PlanError::Azimuths);
    }
    if plan.elevations.is_empty() || plan.elevations.iter().any(|e| e.is_nan() || e.abs() >= 89.0) {
        return Err(PlanError::Elevations(plan.elevations.clone()));
    }
    let (c, r) = bounding_sphere(bounds);
    let fit = fit_distance(r, plan.width, plan.height, plan.fov_deg);
    let (pole, u1, u2) = subject.axes();
    let mut out = Vec::new();
    for &f in &plan.distances {
        let d = f * fit;
        for &el in &plan.elevations {
            for i in 0..plan.azimuths {
                let az = 360.0 * f64::from(i) / f64::from(plan.azimuths);
                let (sa, ca) = az.to_radians().sin_cos();
                let (se, ce) = el.to_radians().sin_cos();
                let dir = ((u1 * (ce * ca)) + (u2 * (ce * sa))) + (pole * se);
                let eye = c + (dir * d);
                out.push(EvalCamera {
                    camera: Camera {
                        eye,
                        target: c,
                        up: pole,
                        width: plan.width,
                        height: plan.height,
                        fov_deg: plan.fov_deg,
                    },
                    distance_factor: f,
                    distance: d,
                    azimuth_deg: az,
                    elevation_deg: el,
                    near: (d - 1.05 * r).max(d * 1e-3),
                    far: d + 1.05 * r,
                });
            }
        }
    }
    Ok(out)
}

/// Pixel counts of a coverage comparison: TP covered in both frames, FP only in the LOD frame,
/// FN only in the full-detail frame.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct Confusion {
    pub tp: u64,
    pub fp: u64,
    pub fn_: u64,
}

impl Confusion {
    /// Compares two coverage masks of the same size (the shorter length is used).
    #[must_use]
    pub fn of_masks(reference: &[bool], lod: &[bool]) -> Self {
        let mut c = Self::default();
        for (&a, &b) in reference.iter().zip(lod) {
            match (a, b) {
                (true, true) => c.tp += 1,
                (false, true) => c.fp += 1,
                (true, false) => c.fn_ += 1,
                (false, false) => {}
            }
        }
        c
    }

    pub fn add(&mut self, o: &Self) {
        self.tp += o.tp;
        self.fp += o.fp;
        self.fn_ += o.fn_;
    }

    /// TP / (TP + FN); 1 when the reference covers nothing (nothing could be missed).
    #[must_use]
    pub fn recall(&self) -> f64 {
        ratio(self.tp, self.tp + self.fn_)
    }

    /// TP / (TP + FP); 1 when the LOD frame covers nothing (nothing drawn wrongly).
    #[must_use]
    pub fn precision(&self) -> f64 {
        ratio(self.tp, self.tp + self.fp)
    }

    /// Harmonic mean of precision and recall (0 when both are 0).
    #[must_use]
    pub fn f_measure(&self) -> f64 {
        let (p, r) = (self.precision(), self.recall());
        if p + r > 0.0 { 2.0 * p * r / (p + r) } else { 0.0 }
    }
}

fn ratio(a: u64, b: u64) -> f64 {
    if b == 0 { 1.0 } else { a as f64 / b as f64 }
}

/// Linear view depth from a `[0, 1]` depth-buffer value of the renderer's projection
/// (`depth = f·(D − n) / ((f − n)·D)`), or `None` for the cleared far value.
#[must_use]
pub fn linear_depth(depth: f32, near: f64, far: f64) -> Option<f64> {
    let z = f64::from(depth);
    if !(0.0..1.0).contains(&z) {
        return None;
    }
    Some(far * near / (far - z * (far - near)))
}

/// Sum and count of absolute depth differences over pixels covered in both frames.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct DepthDiff {
    pub sum: f64,
    pub count: u64,
}

impl DepthDiff {
    /// Compares two linear-depth frames (NaN where nothing was drawn).
    #[must_use]
    pub fn of(reference: &[f64], lod: &[f64]) -> Self {
        let mut d = Self::default();
        for (&a, &b) in reference.iter().zip(lod) {
            if a.is_finite() && b.is_finite() {
                d.sum += (a - b).abs();
                d.count += 1;
            }
        }
        d
    }

    pub fn add(&mut self, o: &Self) {
        self.sum += o.sum;
        self.count += o.count;
    }

    /// Mean absolute difference (world units), `None` with no pixel in common.
    #[must_use]
    pub fn mean(&self) -> Option<f64> {
        (self.count > 0).then(|| self.sum / self.count as f64)
    }
}

/// The result of one evaluation camera.
#[derive(Debug, Clone, PartialEq)]
pub struct CameraResult {
    pub distance_factor: f64,
    pub distance: f64,
    pub azimuth_deg: f64,
    pub elevation_deg: f64,
    /// The LOD selection against the full detail.
    pub lod: Confusion,
    pub depth: DepthDiff,
    /// Draw items per level in the selection.
    pub drawn_per_level: Vec<u32>,
    pub points_drawn: u64,
    pub triangles_drawn: u64,
    /// Level `l` forced on the nodes the selection draws, against the full detail.
    pub per_level: Vec<Confusion>,
}

/// Aggregates of one group of cameras (all, or one distance).
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Summary {
    pub cameras: u32,
    /// Pixel counts summed over the cameras (pooled; close views weigh most).
    pub lod: Confusion,
    /// Means over the cameras of the per-camera recall, precision and F-measure: every view
    /// weighs the same, as the paper averages over camera positions. The headline figures.
    pub mean_recall: f64,
    pub mean_precision: f64,
    pub mean_f: f64,
    /// Per level forced: mean over the cameras of the per-camera F-measure.
    pub per_level_mean_f: Vec<f64>,
    pub depth: DepthDiff,
    pub drawn_per_level: Vec<u64>,
    pub points_drawn: u64,
    pub triangles_drawn: u64,
    pub per_level: Vec<Confusion>,
}

/// Sums a group of camera results.
#[must_use]
pub fn summarize<'a>(results: impl IntoIterator<Item = &'a CameraResult>) -> Summary {
    let mut s = Summary::default();
    let (mut r_sum, mut p_sum, mut f_sum) = (0.0, 0.0, 0.0);
    for r in results {
        s.cameras += 1;
        s.lod.add(&r.lod);
        r_sum += r.lod.recall();
        p_sum += r.lod.precision();
        f_sum += r.lod.f_measure();
        s.depth.add(&r.depth);
        grow_add(&mut s.drawn_per_level, r.drawn_per_level.iter().map(|&c| u64::from(c)));
        s.points_drawn += r.points_drawn;
        s.triangles_drawn += r.triangles_drawn;
        if s.per_level.len() < r.per_level.len() {
            s.per_level.resize(r.per_level.len(), Confusion::default());
        }
        if s.per_level_mean_f.len() < r.per_level.len() {
            s.per_level_mean_f.resize(r.per_level.len(), 0.0);
        }
        for (a, b) in s.per_level.iter_mut().zip(&r.per_level) {
            a.add(b);
        }
        for (a, b) in s.per_level_mean_f.iter_mut().zip(&r.per_level) {
            *a += b.f_measure();
        }
    }
    if s.cameras > 0 {
        let n = f64::from(s.cameras);
        s.mean_recall = r_sum / n;
        s.mean_precision = p_sum / n;
        s.mean_f = f_sum / n;
        for f in &mut s.per_level_mean_f {
            *f /= n;
        }
    }
    s
}

fn grow_add(acc: &mut Vec<u64>, items: impl Iterator<Item = u64>) {
    for (i, v) in items.enumerate() {
        if acc.len() <= i {
            acc.resize(i + 1, 0);
        }
        acc[i] += v;
    }
}

/// Results grouped by distance factor, nearest first.
#[must_use]
pub fn by_distance(results: &[CameraResult]) -> Vec<(f64, Summary)> {
    let mut groups: BTreeMap<u64, Vec<&CameraResult>> = BTreeMap::new();
    for r in results {
        // Distance factors are positive, so their bit patterns sort like the values.
        groups.entry(r.distance_factor.to_bits()).or_default().push(r);
    }
    groups.into_iter().map(|(k, g)| (f64::from_bits(k), summarize(g))).collect()
}

/// Chooses a level for an object at `dist` whose levels have the geometric errors `errors`
/// (finest first): the coarsest with `e · k / dist ≤ threshold`, else level 0 (the selection's
/// rule for one node).
#[must_use]
pub fn level_for(errors: &[f64], k: f64, dist: f64, threshold_px: f64) -> usize {
    let allowed = threshold_px * dist.max(1e-6) / k;
    (0..errors.len()).rev().find(|&l| errors[l] <= allowed).unwrap_or(0)
}

/// Instance offsets of an `n × n` grid centred on the origin in the plane perpendicular to the
/// subject's polar axis, `spacing` apart.
#[must_use]
pub fn grid_offsets(n: u32, spacing: f64, subject: Subject) -> Vec<[f64; 3]> {
    let (_, u1, u2) = subject.axes();
    let half = f64::from(n.saturating_sub(1)) * 0.5;
    let mut out = Vec::with_capacity((n as usize) * (n as usize));
    for j in 0..n {
        for i in 0..n {
            let a = (f64::from(i) - half) * spacing;
            let b = (f64::from(j) - half) * spacing;
            out.push((u1 * a + u2 * b).to_array());
        }
    }
    out
}

/// The camera that sees a whole `n × n` grid of objects with bounding sphere `(c, r)`, from
/// the fit distance of the grid's sphere at [`GRID_ELEVATION_DEG`].
#[must_use]
// The camera needs the grid (n, spacing, subject), the object's sphere and the viewport.
#[allow(clippy::too_many_arguments)]
pub fn grid_camera(
    c: DVec3,
    r: f64,
    n: u32,
    spacing: f64,
    subject: Subject,
    w: u32,
    h: u32,
    fov: f64,
) -> EvalCamera {
    let half_extent = f64::from(n.saturating_sub(1)) * 0.5 * spacing;
    let grid_r = (2.0f64.sqrt() * half_extent + r).max(r);
    let d = fit_distance(grid_r, w, h, fov);
    let (pole, u1, _) = subject.axes();
    let (se, ce) = GRID_ELEVATION_DEG.to_radians().sin_cos();
    let eye = c + ((u1 * (-ce * d)) + (pole * (se * d)));
    EvalCamera {
        camera: Camera { eye, target: c, up: pole, width: w, height: h, fov_deg: fov },
        distance_factor: 1.0,
        distance: d,
        azimuth_deg: 180.0,
        elevation_deg: GRID_ELEVATION_DEG,
        near: (d - 1.05 * grid_r).max(d * 1e-3),
        far: d + 1.05 * grid_r,
    }
}

/// One row of the rendering experiment.
#[derive(Debug, Clone, PartialEq)]
pub struct InstanceRow {
    pub n: u32,
    /// Median frame time in milliseconds without LOD (every instance draws the full mesh).
    pub ms_full: f64,
    /// Median frame time in milliseconds with LOD (each instance at its selected level).
    pub ms_lod: f64,
    /// Instances per level with LOD.
    pub per_level: Vec<u32>,
    pub triangles_full: u64,
    pub triangles_lod: u64,
    pub points_lod: u64,
}

impl InstanceRow {
    /// Speed-up of LOD: frame time without / with.
    #[must_use]
    pub fn ratio(&self) -> f64 {
        if self.ms_lod > 0.0 { self.ms_full / self.ms_lod } else { f64::NAN }
    }
}

/// The median of a non-empty list (NaN when empty).
#[must_use]
pub fn median(v: &[f64]) -> f64 {
    if v.is_empty() {
        return f64::NAN;
    }
    let mut s = v.to_vec();
    s.sort_by(f64::total_cmp);
    let m = s.len() / 2;
    if s.len() % 2 == 1 { s[m] } else { 0.5 * (s[m - 1] + s[m]) }
}

/// Everything the report shows.
#[derive(Debug, Clone, PartialEq)]
pub struct EvalReport {
    pub tileset: String,
    pub subject: Subject,
    pub adapter: String,
    pub plan: CameraPlan,
    pub threshold_px: f64,
    /// Per level: kind ("mesh"/"points") and the level's total count and triangles.
    pub levels: Vec<String>,
    pub reference_points: u64,
    pub reference_triangles: u64,
    pub results: Vec<CameraResult>,
    pub instances: Vec<InstanceRow>,
    /// Why the rendering experiment did not run or was cut short, if it was.
    pub instances_note: Option<String>,
    /// Grid sides that were asked for but not run (`--max-grid`).
    pub grid_skipped: Vec<u32>,
}

impl EvalReport {
    #[must_use]
    pub fn overall(&self) -> Summary {
        summarize(&self.results)
    }

    /// The paper's F-measure for this kind of subject.
    #[must_use]
    pub fn paper_f(&self) -> (f64, &'static str) {
        match self.subject {
            Subject::Terrain => (PAPER_F_TERRAIN, "terrain"),
            Subject::Model => (PAPER_F_BUNNY, "bunny"),
        }
    }

    /// The terminal summary; its last line is `F-measure: <value>`.
    #[must_use]
    pub fn text(&self) -> String {
        let o = self.overall();
        let mut s = String::new();
        let _ = writeln!(
            s,
            "{} tileset {}: {} cameras ({}×{} px, fov {}°), threshold {} px, adapter {}",
            self.subject.name(),
            self.tileset,
            o.cameras,
            self.plan.width,
            self.plan.height,
            self.plan.fov_deg,
            self.threshold_px,
            self.adapter
        );
        let _ = writeln!(s, "distance  cameras  recall  precision  F-measure  mean|Δdepth|  levels drawn");
        for (f, g) in by_distance(&self.results) {
            let _ = writeln!(
                s,
                "{f:>7.2}×  {:>7}  {:>6.4}  {:>9.4}  {:>9.4}  {:>12}  {:?}",
                g.cameras,
                g.mean_recall,
                g.mean_precision,
                g.mean_f,
                fmt_opt(g.depth.mean()),
                g.drawn_per_level
            );
        }
        for (l, (c, f)) in o.per_level.iter().zip(&o.per_level_mean_f).enumerate() {
            let _ = writeln!(
                s,
                "level {l} forced: F-measure {f:.4} (pooled pixels: recall {:.4}, precision {:.4}, F {:.4})",
                c.recall(),
                c.precision(),
                c.f_measure()
            );
        }
        let (pf, what) = self.paper_f();
        let _ = writeln!(
            s,
            "LOD selection: recall {:.4}, precision {:.4} (pooled pixels: {:.4}, {:.4}, F {:.4}); mean |Δdepth| {}; paper: F {pf} ({what}), {PAPER_F_AVERAGE} (average)",
            o.mean_recall,
            o.mean_precision,
            o.lod.recall(),
            o.lod.precision(),
            o.lod.f_measure(),
            fmt_opt(o.depth.mean())
        );
        for row in &self.instances {
            let _ = writeln!(
                s,
                "instances {:>5} ({}×{}): without LOD {:.2} ms, with LOD {:.2} ms, ratio {:.2} (paper: not available, see docs/evaluation.md)",
                row.n * row.n,
                row.n,
                row.n,
                row.ms_full,
                row.ms_lod,
                row.ratio()
            );
        }
        if let Some(n) = &self.instances_note {
            let _ = writeln!(s, "instances: {n}");
        }
        let _ = write!(s, "F-measure: {:.4}", o.mean_f);
        s
    }

    /// The Markdown report; `fmeasure_png` and `frametime_png` are the charts' file names and
    /// `extra` is Markdown placed before the final `F-measure:` line.
    #[must_use]
    pub fn markdown(&self, fmeasure_png: &str, frametime_png: Option<&str>, extra: &str) -> String {
        let o = self.overall();
        let (pf, what) = self.paper_f();
        let mut s = String::new();
        let _ = writeln!(s, "# LOD evaluation: {}\n", self.tileset);
        let _ = writeln!(
            s,
            "A {} tileset, rendered headless on **{}**. The full-detail geometry and the client's LOD \
             selection (threshold {} px, fov {}°, {}×{} px) are rendered from {} cameras and their \
             coverage masks compared pixel by pixel (the first paper, section 4.6).\n",
            self.subject.name(),
            self.adapter,
            self.threshold_px,
            self.plan.fov_deg,
            self.plan.width,
            self.plan.height,
            o.cameras
        );
        let _ = writeln!(s, "## Result\n");
        let _ = writeln!(s, "| | recall | precision | F-measure |\n|---|---|---|---|");
        let _ = writeln!(
            s,
            "| LOD selection, mean over the cameras | {:.4} | {:.4} | **{:.4}** |",
            o.mean_recall, o.mean_precision, o.mean_f
        );
        let _ = writeln!(
            s,
            "| LOD selection, pixel counts pooled over the cameras | {:.4} | {:.4} | {:.4} |",
            o.lod.recall(),
            o.lod.precision(),
            o.lod.f_measure()
        );
        let _ = writeln!(s, "| the paper, {what} | | | {pf} |");
        let _ = writeln!(s, "| the paper, average | 0.952 | 0.944 | {PAPER_F_AVERAGE} |\n");
        let _ = writeln!(
            s,
            "Mean absolute depth difference on pixels covered in both frames: {} world units \
             (over {} pixels).\n",
            fmt_opt(o.depth.mean()),
            o.depth.count
        );
        let _ = writeln!(
            s,
            "Full detail drawn per camera: {} points, {} triangles. LOD selection, summed over \
             all cameras: {} points, {} triangles; draws per level {:?}.\n",
            self.reference_points,
            self.reference_triangles,
            o.points_drawn,
            o.triangles_drawn,
            o.drawn_per_level
        );
        let _ = writeln!(s, "Levels: {}\n", self.levels.join("; "));
        let _ = writeln!(s, "## F-measure by distance\n");
        let _ = writeln!(
            s,
            "![F-measure by distance]({fmeasure_png})\n\nx: distance in multiples of the fit \
             distance (the bounding sphere just fills the view; ticks at the distances of the \
             table below), log scale; y: mean F-measure from 0.80 \
             (bottom) to 1.00 (top), grid lines every 0.02. Black: the LOD selection; colours: each \
             level forced on the nodes the selection draws (level 0 red, 1 orange, 2 green, 3 blue, \
             4 purple, 5 grey); values under 0.80 are drawn at 0.80. Dashed: 0.98 (the target).\n"
        );
        let _ = writeln!(
            s,
            "| distance | cameras | recall | precision | F-measure | mean \\|Δdepth\\| | draws per level | points | triangles |"
        );
        let _ = writeln!(s, "|---|---|---|---|---|---|---|---|---|");
        for (f, g) in by_distance(&self.results) {
            let _ = writeln!(
                s,
                "| {f}× | {} | {:.4} | {:.4} | {:.4} | {} | {:?} | {} | {} |",
                g.cameras,
                g.mean_recall,
                g.mean_precision,
                g.mean_f,
                fmt_opt(g.depth.mean()),
                g.drawn_per_level,
                g.points_drawn,
                g.triangles_drawn
            );
        }
        let _ = writeln!(s, "\n### Each level forced\n");
        let mut head = String::from("| distance |");
        let mut rule = String::from("|---|");
        for l in 0..o.per_level.len() {
            let _ = write!(head, " level {l} |");
            rule.push_str("---|");
        }
        let _ = writeln!(s, "{head}\n{rule}");
        for (f, g) in by_distance(&self.results) {
            let mut row = format!("| {f}× |");
            for f in &g.per_level_mean_f {
                let _ = write!(row, " {f:.4} |");
            }
            let _ = writeln!(s, "{row}");
        }
        let mut row = String::from("| all |");
        for f in &o.per_level_mean_f {
            let _ = write!(row, " {f:.4} |");
        }
        let _ = writeln!(s, "{row}\n");
        let _ = writeln!(s, "## Rendering experiment: N×N instances with and without LOD\n");
        if let (Some(png), Some(ch)) = (frametime_png, frametime_chart(&self.instances)) {
            let _ = writeln!(
                s,
                "![frame time by instance count]({png})\n\nx: instances N² (ticks at {:?}), log \
                 scale; y: median frame time from {} ms (bottom) to {} ms (top), log scale, grid \
                 lines at powers of ten. Red: without LOD (every instance draws the full mesh); blue: \
                 with LOD (each instance at the coarsest level under the threshold).\n",
                self.instances.iter().map(|r| r.n * r.n).collect::<Vec<_>>(),
                ch.y_range.0,
                ch.y_range.1
            );
        }
        if !self.instances.is_empty() {
            let _ = writeln!(
                s,
                "| N² | without LOD (ms) | with LOD (ms) | ratio | paper's ratio | triangles without | triangles with | points with | instances per level |"
            );
            let _ = writeln!(s, "|---|---|---|---|---|---|---|---|---|");
            for r in &self.instances {
                let _ = writeln!(
                    s,
                    "| {} | {:.2} | {:.2} | {:.2} | n/a | {} | {} | {} | {:?} |",
                    r.n * r.n,
                    r.ms_full,
                    r.ms_lod,
                    r.ratio(),
                    r.triangles_full,
                    r.triangles_lod,
                    r.points_lod,
                    r.per_level
                );
            }
            let _ = writeln!(
                s,
                "\nThe paper's Tables 4–7 ratios are not reproduced here: they are not listed in \
                 the project's design notes or the issue (see docs/evaluation.md in the repository).\n"
            );
        }
        if !self.grid_skipped.is_empty() {
            let _ = writeln!(s, "Not run (over `--max-grid`): N = {:?}.\n", self.grid_skipped);
        }
        if let Some(n) = &self.instances_note {
            let _ = writeln!(s, "{n}\n");
        }
        s.push_str(extra);
        let _ = writeln!(s, "F-measure: {:.4}", o.mean_f);
        s
    }
}

/// Four significant digits whatever the tileset's units (metres of terrain, a bunny 0.15 wide).
pub(crate) fn fmt_opt(v: Option<f64>) -> String {
    v.map_or_else(
        || "n/a".into(),
        |v| if v == 0.0 || v.abs() >= 0.1 { format!("{v:.4}") } else { format!("{v:.3e}") },
    )
}

/// Chart colours (RGBA): level 0.. then black for the LOD selection.
pub const PALETTE: [[u8; 4]; 6] = [
    [214, 39, 40, 255],
    [255, 127, 14, 255],
    [44, 160, 44, 255],
    [31, 119, 180, 255],
    [148, 103, 189, 255],
    [127, 127, 127, 255],
];
const BLACK: [u8; 4] = [0, 0, 0, 255];

/// A line series: colour and (x, y) points in data units.
#[derive(Debug, Clone, PartialEq)]
pub struct Series {
    pub color: [u8; 4],
    pub thick: bool,
    pub points: Vec<(f64, f64)>,
}

/// A line chart without text: white background, axes, grid lines at `y_grid` (and dashed at
/// `y_mark`), one polyline with dots per series. `log_x`/`log_y` plot log10 of the values.
#[derive(Debug, Clone, PartialEq)]
pub struct Chart {
    pub width: u32,
    pub height: u32,
    pub x_range: (f64, f64),
    pub y_range: (f64, f64),
    pub log_x: bool,
    pub log_y: bool,
    pub y_grid: Vec<f64>,
    pub y_mark: Option<f64>,
    pub series: Vec<Series>,
}

const MARGIN: u32 = 24;

impl Chart {
    fn map(&self, x: f64, y: f64) -> Option<(f64, f64)> {
        let t = |v: f64, log: bool| if log { (v > 0.0).then(|| v.log10()) } else { Some(v) };
        let (x, y) = (t(x, self.log_x)?, t(y, self.log_y)?);
        let (x0, x1) = (t(self.x_range.0, self.log_x)?, t(self.x_range.1, self.log_x)?);
        let (y0, y1) = (t(self.y_range.0, self.log_y)?, t(self.y_range.1, self.log_y)?);
        if !(x.is_finite() && y.is_finite()) || x1 <= x0 || y1 <= y0 {
            return None;
        }
        let w = f64::from(self.width - 2 * MARGIN);
        let h = f64::from(self.height - 2 * MARGIN);
        let px = f64::from(MARGIN) + (x - x0) / (x1 - x0) * w;
        let py = f64::from(self.height - MARGIN) - (y - y0) / (y1 - y0) * h;
        Some((px, py))
    }

    /// Draws the chart.
    #[must_use]
    pub fn draw(&self) -> image::RgbaImage {
        let (w, h) = (self.width.max(2 * MARGIN + 2), self.height.max(2 * MARGIN + 2));
        let chart = Self { width: w, height: h, ..self.clone() };
        let mut img = image::RgbaImage::from_pixel(w, h, image::Rgba([255, 255, 255, 255]));
        let grey = [200, 200, 200, 255];
        for &g in &chart.y_grid {
            if let Some((_, y)) = chart.map(chart.x_range.0, g) {
                line(&mut img, f64::from(MARGIN), y, f64::from(w - MARGIN), y, grey, false, false);
            }
        }
        if let Some(m) = chart.y_mark
            && let Some((_, y)) = chart.map(chart.x_range.0, m)
        {
            line(&mut img, f64::from(MARGIN), y, f64::from(w - MARGIN), y, [90, 90, 90, 255], false, true);
        }
        // Axes: left and bottom.
        let (l, b) = (f64::from(MARGIN), f64::from(h - MARGIN));
        line(&mut img, l, f64::from(MARGIN), l, b, BLACK, false, false);
        line(&mut img, l, b, f64::from(w - MARGIN), b, BLACK, false, false);
        for s in &chart.series {
            let pts: Vec<(f64, f64)> = s.points.iter().filter_map(|&(x, y)| chart.map(x, y)).collect();
            // Ticks on the x axis at every data point.
            for &(x, _) in &pts {
                line(&mut img, x, b, x, b + 5.0, BLACK, false, false);
            }
            for p in pts.windows(2) {
                line(&mut img, p[0].0, p[0].1, p[1].0, p[1].1, s.color, s.thick, false);
            }
            for &(x, y) in &pts {
                dot(&mut img, x, y, s.color);
            }
        }
        img
    }
}

fn put(img: &mut image::RgbaImage, x: i64, y: i64, c: [u8; 4]) {
    if x >= 0 && y >= 0 && x < i64::from(img.width()) && y < i64::from(img.height()) {
        img.put_pixel(x as u32, y as u32, image::Rgba(c));
    }
}

#[allow(clippy::too_many_arguments, clippy::fn_params_excessive_bools)]
fn line(
    img: &mut image::RgbaImage,
    x0: f64,
    y0: f64,
    x1: f64,
    y1: f64,
    c: [u8; 4],
    thick: bool,
    dashed: bool,
) {
    let steps = (x1 - x0).abs().max((y1 - y0).abs()).ceil().max(1.0) as i64;
    for i in 0..=steps {
        if dashed && (i / 6) % 2 == 1 {
            continue;
        }
        let t = i as f64 / steps as f64;
        let x = (x0 + (x1 - x0) * t).round() as i64;
        let y = (y0 + (y1 - y0) * t).round() as i64;
        put(img, x, y, c);
        if thick {
            put(img, x + 1, y, c);
            put(img, x, y + 1, c);
            put(img, x + 1, y + 1, c);
        }
    }
}

fn dot(img: &mut image::RgbaImage, x: f64, y: f64, c: [u8; 4]) {
    let (cx, cy) = (x.round() as i64, y.round() as i64);
    for dy in -3..=3 {
        for dx in -3..=3 {
            if dx * dx + dy * dy <= 9 {
                put(img, cx + dx, cy + dy, c);
            }
        }
    }
}

/// The F-measure-by-distance chart of a report.
#[must_use]
pub fn fmeasure_chart(report: &EvalReport) -> Chart {
    let groups = by_distance(&report.results);
    let xs: Vec<f64> = groups.iter().map(|g| g.0).collect();
    let lo = xs.first().copied().unwrap_or(1.0);
    let hi = xs.last().copied().unwrap_or(1.0);
    let levels = groups.iter().map(|g| g.1.per_level.len()).max().unwrap_or(0);
    let mut series: Vec<Series> = (0..levels)
        .map(|l| Series {
            color: PALETTE[l.min(PALETTE.len() - 1)],
            thick: false,
            points: groups
                .iter()
                .filter_map(|(f, g)| g.per_level_mean_f.get(l).map(|v| (*f, v.max(0.8))))
                .collect(),
        })
        .collect();
    series.push(Series {
        color: BLACK,
        thick: true,
        points: groups.iter().map(|(f, g)| (*f, g.mean_f.max(0.8))).collect(),
    });
    Chart {
        width: 640,
        height: 400,
        x_range: (lo / 1.3, hi * 1.3),
        y_range: (0.8, 1.0),
        log_x: true,
        log_y: false,
        y_grid: (0..=10).map(|i| 0.8 + 0.02 * f64::from(i)).collect(),
        y_mark: Some(0.98),
        series,
    }
}

/// The frame-time-by-instance-count chart (`None` without rows).
#[must_use]
pub fn frametime_chart(rows: &[InstanceRow]) -> Option<Chart> {
    if rows.is_empty() {
        return None;
    }
    let ms: Vec<f64> = rows.iter().flat_map(|r| [r.ms_full, r.ms_lod]).filter(|v| *v > 0.0).collect();
    let lo = ms.iter().copied().fold(f64::INFINITY, f64::min);
    let hi = ms.iter().copied().fold(0.0, f64::max);
    if !(lo.is_finite() && hi > 0.0) {
        return None;
    }
    let (y0, y1) =
        (10f64.powf(lo.log10().floor()), 10f64.powf(hi.log10().ceil().max(lo.log10().floor() + 1.0)));
    let n2 = |r: &InstanceRow| f64::from(r.n * r.n);
    let (x0, x1) =
        (rows.iter().map(n2).fold(f64::INFINITY, f64::min), rows.iter().map(n2).fold(0.0, f64::max));
    let mut grid = Vec::new();
    let mut g = y0;
    while g <= y1 * 1.0001 {
        grid.push(g);
        g *= 10.0;
    }
    Some(Chart {
        width: 640,
        height: 400,
        x_range: (x0 / 1.5, x1 * 1.5),
        y_range: (y0, y1),
        log_x: true,
        log_y: true,
        y_grid: grid,
        y_mark: None,
        series: vec![
            Series {
                color: PALETTE[0],
                thick: true,
                points: rows.iter().map(|r| (n2(r), r.ms_full)).collect(),
            },
            Series {
                color: PALETTE[3],
                thick: true,
                points: rows.iter().map(|r| (n2(r), r.ms_lod)).collect(),
            },
        ],
    })
}

#[cfg(test)]
#[allow(clippy::float_cmp)]
mod tests {
    use super::*;

    fn plan() -> CameraPlan {
        CameraPlan {
            width: 400,
            height: 300,
            fov_deg: 60.0,
            distances: vec![1.0, 2.0],
            azimuths: 4,
            elevations: vec![30.0, 60.0],
        }
    }

    fn cube() -> Bounds {
        Bounds::new([10.0, 20.0, 0.0], [30.0, 40.0, 20.0])
    }

    #[test]
    fn confusion_counts_and_metrics() {
        let r = [true, true, true, false, false, true];
        let l = [true, false, true, true, false, true];
        let c = Confusion::of_masks(&r, &l);
        assert_eq!(c, Confusion { tp: 3, fp: 1, fn_: 1 });
        assert!((c.recall() - 0.75).abs() < 1e-12);
        assert!((c.precision() - 0.75).abs() < 1e-12);
        assert!((c.f_measure() - 0.75).abs() < 1e-12);
        let c = Confusion { tp: 8, fp: 2, fn_: 0 };
        let (p, r) = (0.8, 1.0);
        assert!((c.f_measure() - 2.0 * p * r / (p + r)).abs() < 1e-12);
    }

    #[test]
    fn confusion_edge_cases() {
        let none = Confusion::default();
        assert_eq!((none.recall(), none.precision(), none.f_measure()), (1.0, 1.0, 1.0));
        let only_fp = Confusion { tp: 0, fp: 5, fn_: 0 };
        assert_eq!(only_fp.precision(), 0.0);
        assert_eq!(only_fp.f_measure(), 0.0);
        let only_fn = Confusion { tp: 0, fp: 0, fn_: 5 };
        assert_eq!(only_fn.recall(), 0.0);
        assert_eq!(only_fn.f_measure(), 0.0);
        let mut a = Confusion { tp: 1, fp: 2, fn_: 3 };
        a.add(&Confusion { tp: 10, fp: 20, fn_: 30 });
        assert_eq!(a, Confusion { tp: 11, fp: 22, fn_: 33 });
    }

    #[test]
    fn depth_round_trips_and_differences() {
        let (n, f) = (0.5, 1000.0);
        for d in [0.5, 1.0, 10.0, 123.0, 999.0] {
            let z = f * (d - n) / ((f - n) * d);
            let back = linear_depth(z as f32, n, f).unwrap();
            assert!((back - d).abs() / d < 1e-4, "{d} → {back}");
        }
        assert_eq!(linear_depth(1.0, n, f), None);
        let a = [1.0, 2.0, f64::NAN, 4.0];
        let b = [1.5, f64::NAN, 3.0, 3.0];
        let dd = DepthDiff::of(&a, &b);
        assert_eq!(dd.count, 2);
        assert!((dd.mean().unwrap() - 0.75).abs() < 1e-12);
        assert_eq!(DepthDiff::default().mean(), None);
    }

    #[test]
    fn cameras_spread_on_spheres_and_see_the_whole_box_at_fit_distance() {
        let b = cube();
        let p = plan();
        let cams = cameras(&b, Subject::Terrain, &p).unwrap();
        assert_eq!(cams.len(), 2 * 4 * 2);
        let (c, r) = bounding_sphere(&b);
        let fit = fit_distance(r, p.width, p.height, p.fov_deg);
        for e in &cams {
            let d = (e.camera.eye - c).length();
            assert!((d - e.distance_factor * fit).abs() < 1e-9 * fit);
            assert!((d - e.distance).abs() < 1e-9);
            assert_eq!(e.camera.target, c);
            // Elevation above the horizontal plane matches.
            let el = ((e.camera.eye[2] - c[2]) / d).asin().to_degrees();
            assert!((el - e.elevation_deg).abs() < 1e-9);
            assert!(e.far > d + r && e.near > 0.0 && e.near < d - r);
            let view = e.camera.view().unwrap();
            // At the fit distance every corner of the box is inside the frustum.
            if e.distance_factor == 1.0 {
                for i in 0..8 {
                    let corner = [
                        if i & 1 == 0 { b.min[0] } else { b.max[0] },
                        if i & 2 == 0 { b.min[1] } else { b.max[1] },
                        if i & 4 == 0 { b.min[2] } else { b.max[2] },
                    ];
                    let q = DVec3::from_array(corner) - view.eye;
                    let z = q.dot(view.forward);
                    assert!(z > 0.0);
                    assert!(q.dot(view.right).abs() <= z * view.tan_h + 1e-9);
                    assert!(q.dot(view.up).abs() <= z * view.tan_v + 1e-9);
                }
            }
        }
        // Azimuths are distinct and evenly spread.
        let az: Vec<f64> = cams.iter().take(4).map(|e| e.azimuth_deg).collect();
        assert_eq!(az, vec![0.0, 90.0, 180.0, 270.0]);
    }

    #[test]
    fn model_cameras_use_the_y_axis_as_pole() {
        let mut p = plan();
        p.elevations = vec![-45.0, 45.0];
        let cams = cameras(&cube(), Subject::Model, &p).unwrap();
        let (c, _) = bounding_sphere(&cube());
        for e in &cams {
            let d = e.distance;
            let el = ((e.camera.eye[1] - c[1]) / d).asin().to_degrees();
            assert!((el - e.elevation_deg).abs() < 1e-9);
            assert_eq!(e.camera.up, DVec3::Y);
        }
    }

    #[test]
    fn bad_plans_are_refused_with_the_field_named() {
        let b = cube();
        let mut p = plan();
        p.elevations = vec![90.0];
        assert!(cameras(&b, Subject::Terrain, &p).unwrap_err().to_string().contains("elevations"));
        let mut p = plan();
        p.distances = vec![0.0];
        assert!(cameras(&b, Subject::Terrain, &p).unwrap_err().to_string().contains("distances"));
        let mut p = plan();
        p.azimuths = 0;
        assert!(cameras(&b, Subject::Terrain, &p).unwrap_err().to_string().contains("azimuths"));
        assert!(
            cameras(&Bounds::empty(), Subject::Terrain, &plan()).unwrap_err().to_string().contains("bounds")
        );
    }

    fn result(f: f64, lod: Confusion) -> CameraResult {
        CameraResult {
            distance_factor: f,
            distance: f,
            azimuth_deg: 0.0,
            elevation_deg: 0.0,
            lod,
            depth: DepthDiff { sum: 2.0, count: 4 },
            drawn_per_level: vec![1, 2],
            points_drawn: 10,
            triangles_drawn: 20,
            per_level: vec![lod, Confusion { tp: 1, fp: 0, fn_: 1 }],
        }
    }

    #[test]
    fn summaries_sum_pixels_and_group_by_distance() {
        let rs = vec![
            result(2.0, Confusion { tp: 90, fp: 10, fn_: 0 }),
            result(1.0, Confusion { tp: 50, fp: 0, fn_: 50 }),
            result(2.0, Confusion { tp: 100, fp: 0, fn_: 0 }),
        ];
        let s = summarize(&rs);
        assert_eq!(s.cameras, 3);
        assert_eq!(s.lod, Confusion { tp: 240, fp: 10, fn_: 50 });
        assert_eq!(s.drawn_per_level, vec![3, 6]);
        assert_eq!(s.per_level[1], Confusion { tp: 3, fp: 0, fn_: 3 });
        assert!((s.depth.mean().unwrap() - 0.5).abs() < 1e-12);
        let f: Vec<f64> = rs.iter().map(|r| r.lod.f_measure()).collect();
        assert!((s.mean_f - f.iter().sum::<f64>() / 3.0).abs() < 1e-12);
        assert!((s.per_level_mean_f[1] - 2.0 / 3.0).abs() < 1e-12);
        let rec: Vec<f64> = rs.iter().map(|r| r.lod.recall()).collect();
        assert!((s.mean_recall - rec.iter().sum::<f64>() / 3.0).abs() < 1e-12);
        let g = by_distance(&rs);
        assert_eq!(g.len(), 2);
        assert_eq!(g[0].0, 1.0);
        assert_eq!(g[1].1.cameras, 2);
        assert_eq!(g[1].1.lod, Confusion { tp: 190, fp: 10, fn_: 0 });
    }

    #[test]
    fn level_choice_follows_the_screen_space_error() {
        let errs = [0.1, 1.0, 10.0];
        let k = 500.0;
        // e·k/d ≤ 2 ⇔ d ≥ e·k/2: level 2 from 2500, level 1 from 250, else 0.
        assert_eq!(level_for(&errs, k, 3000.0, 2.0), 2);
        assert_eq!(level_for(&errs, k, 2499.0, 2.0), 1);
        assert_eq!(level_for(&errs, k, 250.0, 2.0), 1);
        assert_eq!(level_for(&errs, k, 10.0, 2.0), 0);
    }

    #[test]
    fn grid_is_centred_and_its_camera_sees_every_instance() {
        let o = grid_offsets(3, 2.0, Subject::Model);
        assert_eq!(o.len(), 9);
        assert_eq!(o[4], [0.0, 0.0, 0.0]);
        assert!(o.iter().all(|p| p[1] == 0.0));
        let c = DVec3::new(0.0, 0.5, 0.0);
        let cam = grid_camera(c, 0.7, 3, 2.0, Subject::Model, 400, 300, 60.0);
        let view = cam.camera.view().unwrap();
        for p in &o {
            let p = DVec3::from_array(*p);
            assert!(view.intersects(&Bounds::new((p - 0.7).to_array(), (p + 0.7).to_array())));
        }
        assert!((median(&[3.0, 1.0, 2.0]) - 2.0).abs() < 1e-12);
        assert!((median(&[4.0, 1.0, 2.0, 3.0]) - 2.5).abs() < 1e-12);
        assert!(median(&[]).is_nan());
    }

    #[test]
    fn report_ends_with_the_f_measure_line() {
        let rep = EvalReport {
            tileset: "t".into(),
            subject: Subject::Model,
            adapter: "a".into(),
            plan: plan(),
            threshold_px: 2.0,
            levels: vec![],
            reference_points: 1,
            reference_triangles: 1,
            results: vec![result(1.0, Confusion { tp: 98, fp: 2, fn_: 2 })],
            instances: vec![InstanceRow {
                n: 11,
                ms_full: 10.0,
                ms_lod: 2.5,
                per_level: vec![0, 121],
                triangles_full: 1,
                triangles_lod: 0,
                points_lod: 5,
            }],
            instances_note: None,
            grid_skipped: vec![81],
        };
        let t = rep.text();
        assert_eq!(t.lines().last().unwrap(), "F-measure: 0.9800");
        assert!(t.contains("ratio 4.00"));
        let md = rep.markdown("f.png", Some("t.png"), "EXTRA\n");
        assert!(md.contains("EXTRA\nF-measure"));
        assert!(md.contains("![F-measure by distance](f.png)"));
        assert!(md.contains("| 121 | 10.00 | 2.50 | 4.00 |"));
        assert!(md.contains("N = [81]"));
        assert!(md.trim_end().ends_with("F-measure: 0.9800"));
    }

    #[test]
    fn charts_draw_lines_in_their_colours() {
        let rep_rows = vec![
            InstanceRow {
                n: 11,
                ms_full: 10.0,
                ms_lod: 2.0,
                per_level: vec![],
                triangles_full: 0,
                triangles_lod: 0,
                points_lod: 0,
            },
            InstanceRow {
                n: 21,
                ms_full: 40.0,
                ms_lod: 5.0,
                per_level: vec![],
                triangles_full: 0,
                triangles_lod: 0,
                points_lod: 0,
            },
        ];
        let img = frametime_chart(&rep_rows).unwrap().draw();
        assert_eq!(img.dimensions(), (640, 400));
        let count = |c: [u8; 4]| img.pixels().filter(|p| p.0 == c).count();
        assert!(count(PALETTE[0]) > 50 && count(PALETTE[3]) > 50);
        assert!(count([0, 0, 0, 255]) > 500, "axes");
        assert!(frametime_chart(&[]).is_none());
        // A point outside a log axis (0) is skipped, not drawn at infinity.
        let ch = Chart {
            width: 100,
            height: 80,
            x_range: (1.0, 10.0),
            y_range: (1.0, 10.0),
            log_x: true,
            log_y: true,
            y_grid: vec![],
            y_mark: None,
            series: vec![Series { color: PALETTE[1], thick: false, points: vec![(0.0, 1.0), (2.0, 2.0)] }],
        };
        let img = ch.draw();
        assert!(img.pixels().filter(|p| p.0 == PALETTE[1]).count() > 10);
    }
}
