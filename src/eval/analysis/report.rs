//! The evaluation report: per-camera results, instance rows and the Markdown text.

use super::paper::{self, GPUS, PaperModel};
use super::*;

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
    /// The tileset's source file name (the manifest's `source.file`): it says whether a model
    /// is one of the paper's, whose own figures are then printed beside ours.
    pub source_file: String,
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

    /// The paper's model this tileset is, from its source file name (model tilesets only).
    #[must_use]
    pub fn paper_model(&self) -> Option<PaperModel> {
        match self.subject {
            Subject::Model => PaperModel::from_source_name(&self.source_file),
            Subject::Terrain => None,
        }
    }

    /// The paper's coverage figures beside our LOD selection's, for the terminal: Table 12's
    /// row for the paper's model, else its average; terrain: the large-terrain F-measure too.
    fn paper_coverage_text(&self) -> String {
        let c = paper::table_12(self.paper_model());
        let figures = format!("recall {:.3}, precision {:.3}, F {:.3}", c.recall, c.precision, c.f_measure);
        match (self.subject, self.paper_model()) {
            (Subject::Terrain, _) => {
                format!("paper: F {} (large terrain), Table 12 average: {figures}", paper::LARGE_TERRAIN_F)
            }
            (Subject::Model, Some(m)) => format!("paper (Table 12, {}): {figures}", m.name()),
            (Subject::Model, None) => format!("paper (Table 12, average; not one of its models): {figures}"),
        }
    }

    /// The paper's ratio for `instances` on each GPU (see [`paper::ratio_cell`]); none when
    /// Tables 4–7 have no such row.
    fn paper_ratios(&self, instances: u32) -> Option<Vec<String>> {
        GPUS.iter().map(|&g| paper::ratio_cell(self.paper_model(), g, instances)).collect()
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
        let _ = writeln!(
            s,
            "LOD selection: recall {:.4}, precision {:.4} (pooled pixels: {:.4}, {:.4}, F {:.4}); mean |Δdepth| {}; {}",
            o.mean_recall,
            o.mean_precision,
            o.lod.recall(),
            o.lod.precision(),
            o.lod.f_measure(),
            fmt_opt(o.depth.mean()),
            self.paper_coverage_text()
        );
        let source = self.paper_model().map_or("range over its 5 models", PaperModel::name);
        for row in &self.instances {
            let n2 = row.n * row.n;
            let theirs = match self.paper_ratios(n2) {
                Some(cells) => {
                    let cells: Vec<String> =
                        GPUS.iter().zip(cells).map(|(g, c)| format!("{} {c}", g.name())).collect();
                    format!("paper ({source}): {}", cells.join(", "))
                }
                None => {
                    format!("paper: no row for {n2} instances (Tables 4–7: {:?})", paper::INSTANCE_COUNTS)
                }
            };
            let _ = writeln!(
                s,
                "instances {n2:>5} ({}×{}): without LOD {:.2} ms, with LOD {:.2} ms, ratio {:.2}; {theirs}",
                row.n,
                row.n,
                row.ms_full,
                row.ms_lod,
                row.ratio()
            );
        }
        if !self.instances.is_empty() {
            let _ = writeln!(
                s,
                "paper's ratio: FPS with / without LOD (Tables 4–7, display capped at {} FPS); ≥: with LOD at \
                 the cap (a lower bound), ≤: without LOD at the cap (an upper bound), capped: both (no ratio)",
                paper::FPS_CAP
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
        let model = self.paper_model();
        let mut s = String::new();
        let _ = writeln!(s, "# LOD evaluation: {}\n", self.tileset);
        let _ = writeln!(
            s,
            "A {} tileset (source `{}`{}), rendered headless on **{}**. The full-detail geometry and the client's LOD \
             selection (threshold {} px, fov {}°, {}×{} px) are rendered from {} cameras and their \
             coverage masks compared pixel by pixel (the first paper, section 4.6).\n",
            self.subject.name(),
            self.source_file,
            model.map_or_else(String::new, |m| format!(", the paper's {}", m.name())),
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
        let paper_row = |s: &mut String, what: &str, c: paper::Coverage| {
            let _ = writeln!(
                s,
                "| the paper, {what} | {:.3} | {:.3} | {:.3} |",
                c.recall, c.precision, c.f_measure
            );
        };
        match (self.subject, model) {
            (Subject::Terrain, _) => {
                let _ = writeln!(
                    s,
                    "| the paper, large terrain (1,681 tiles, 5 levels) | | | {} |",
                    paper::LARGE_TERRAIN_F
                );
            }
            (Subject::Model, Some(m)) => paper_row(&mut s, &format!("Table 12, {}", m.name()), m.table_12()),
            (Subject::Model, None) => {}
        }
        paper_row(&mut s, "Table 12, average of its 5 models", paper::TABLE_12_AVERAGE);
        s.push('\n');
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
                "| N² | without LOD (ms) | with LOD (ms) | ratio | paper, {} | paper, {} | triangles without | triangles with | points with | instances per level |",
                GPUS[0].name(),
                GPUS[1].name()
            );
            let _ = writeln!(s, "|---|---|---|---|---|---|---|---|---|---|");
            for r in &self.instances {
                let theirs =
                    self.paper_ratios(r.n * r.n).map_or_else(|| "no row | no row".into(), |c| c.join(" | "));
                let _ = writeln!(
                    s,
                    "| {} | {:.2} | {:.2} | {:.2} | {theirs} | {} | {} | {} | {:?} |",
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
            let whose = model.map_or_else(
                || {
                    format!(
                        "the range (lowest–highest) over its five models, `{}` being none of them; models \
                         whose two cells are both at the cap are left out and named in brackets",
                        self.source_file
                    )
                },
                |m| format!("the {}'s, with its FPS with / without LOD in brackets", m.name()),
            );
            let _ = writeln!(
                s,
                "\nThe paper's ratios are its Tables 4–7, FPS with LOD / FPS without on its hardware: \
                 {whose}. Ours is frame time without LOD / with, the same speed-up; compare ratios, not \
                 frame rates. The paper's display was capped at {cap} FPS: ≥ marks a ratio whose with-LOD \
                 FPS sat at the cap (the true ratio is at least that), ≤ one whose without-LOD FPS did (at \
                 most that), and *capped* a pair both at the cap (no ratio). The tables have rows for {:?} \
                 instances only.\n",
                paper::INSTANCE_COUNTS,
                cap = paper::FPS_CAP
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
