//! The first paper's published figures (`../shared/papers/tables.md`), as data, and the lookups
//! a report needs to print them beside ours: which of the paper's five models a tileset is (from
//! its source file name), Table 3 (vertices per level), Tables 4–7 (FPS of N instances without
//! and with LOD on two GPUs, as with/without ratios that know about the display's 120 FPS cap),
//! Table 12 (coverage recall, precision, F-measure) and the large-terrain F-measure.
//!
//! The paper's hardware and settings are not ours, so only ratios are compared (FPS with LOD /
//! without, the paper's speed-up, against our frame time without / with); absolute frame rates
//! are not. Rows and columns keep the paper's order: Happy Buddha, Dragon, Stanford Bunny,
//! Stanford Lucy, Armadillo.

use std::fmt::Write as _;

/// One of the five models of the paper's tables, in the tables' column order.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum PaperModel {
    HappyBuddha,
    Dragon,
    StanfordBunny,
    StanfordLucy,
    Armadillo,
}

/// The paper's models in its tables' order (the index into every table below).
pub const PAPER_MODELS: [PaperModel; 5] = [
    PaperModel::HappyBuddha,
    PaperModel::Dragon,
    PaperModel::StanfordBunny,
    PaperModel::StanfordLucy,
    PaperModel::Armadillo,
];

impl PaperModel {
    /// The model's name in Tables 3 and 12.
    #[must_use]
    pub fn name(self) -> &'static str {
        match self {
            Self::HappyBuddha => "Happy Buddha",
            Self::Dragon => "Dragon",
            Self::StanfordBunny => "Stanford Bunny",
            Self::StanfordLucy => "Stanford Lucy",
            Self::Armadillo => "Armadillo",
        }
    }

    /// The model's column heading in Tables 4–7.
    #[must_use]
    pub fn short_name(self) -> &'static str {
        match self {
            Self::HappyBuddha => "Buddha",
            Self::Dragon => "Dragon",
            Self::StanfordBunny => "Bunny",
            Self::StanfordLucy => "Lucy",
            Self::Armadillo => "Armadillo",
        }
    }

    /// Row of Tables 3 and 12, column of Tables 4–7.
    #[must_use]
    pub fn index(self) -> usize {
        self as usize
    }

    /// The paper model a source file is, from its name (directories and case ignored): the
    /// letter runs of the name are matched as words, so `bunny.ply`, `stanford-bunny.obj`,
    /// `bun_zipper.ply`, `bun000.ply` are the Stanford Bunny, `happy_vrip.ply`,
    /// `happy-buddha.obj` and `buddha.ply` the Happy Buddha, `dragon_vrip.ply` the Dragon,
    /// `lucy.ply` Lucy and `Armadillo.ply` the Armadillo. A name with no such word, or words of
    /// two different models, is none of them.
    #[must_use]
    pub fn from_source_name(name: &str) -> Option<Self> {
        let file = name.rsplit(['/', '\\']).next().unwrap_or(name).to_ascii_lowercase();
        let words: Vec<&str> =
            file.split(|c: char| !c.is_ascii_alphabetic()).filter(|w| !w.is_empty()).collect();
        let has = |w: &str| words.contains(&w);
        let found: Vec<Self> = PAPER_MODELS
            .into_iter()
            .filter(|m| match m {
                Self::HappyBuddha => has("buddha") || has("happybuddha") || (has("happy") && has("vrip")),
                Self::Dragon => has("dragon"),
                Self::StanfordBunny => has("bunny") || has("bun"),
                Self::StanfordLucy => has("lucy"),
                Self::Armadillo => has("armadillo"),
            })
            .collect();
        match found[..] {
            [m] => Some(m),
            _ => None,
        }
    }

    /// Table 3: vertices of LOD 0 (the original) to LOD 4.
    #[must_use]
    pub fn table_3(self) -> [u64; 5] {
        TABLE_3_VERTICES[self.index()]
    }

    /// Table 12: the model's coverage figures.
    #[must_use]
    pub fn table_12(self) -> Coverage {
        TABLE_12[self.index()]
    }
}

/// Table 3: vertices per LOD level (LOD 0, the original, to LOD 4), one row per model.
pub const TABLE_3_VERTICES: [[u64; 5]; 5] = [
    [300_000, 138_967, 89_022, 35_492, 22_301],
    [300_000, 109_486, 69_952, 27_251, 17_478],
    [14_904, 12_654, 7_092, 3_191, 800],
    [1_346_640, 81_566, 52_162, 39_897, 20_354],
    [1_037_832, 64_200, 41_211, 31_621, 16_102],
];

/// The GPUs of Tables 4–7.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Gpu {
    Gtx750,
    Gtx1080Ti,
}

/// Both GPUs, the slower first.
pub const GPUS: [Gpu; 2] = [Gpu::Gtx750, Gpu::Gtx1080Ti];

impl Gpu {
    #[must_use]
    pub fn name(self) -> &'static str {
        match self {
            Self::Gtx750 => "GTX 750",
            Self::Gtx1080Ti => "GTX 1080 Ti",
        }
    }

    /// The table of FPS without LOD (`with_lod` false: Tables 4 and 6) or with (Tables 5, 7).
    #[must_use]
    pub fn fps_table(self, with_lod: bool) -> &'static [[u32; 5]; 6] {
        match (self, with_lod) {
            (Self::Gtx750, false) => &TABLE_4_GTX750_WITHOUT_LOD,
            (Self::Gtx750, true) => &TABLE_5_GTX750_WITH_LOD,
            (Self::Gtx1080Ti, false) => &TABLE_6_GTX1080TI_WITHOUT_LOD,
            (Self::Gtx1080Ti, true) => &TABLE_7_GTX1080TI_WITH_LOD,
        }
    }
}

/// The display's frame-rate cap in Tables 4–7: a cell at it only says "at least this fast".
pub const FPS_CAP: u32 = 120;
/// Instance counts N² of the rows of Tables 4–7.
pub const INSTANCE_COUNTS: [u32; 6] = [121, 441, 961, 1_681, 5_041, 6_561];

/// Table 4: FPS on a GTX 750 without LOD; rows [`INSTANCE_COUNTS`], columns [`PAPER_MODELS`].
pub const TABLE_4_GTX750_WITHOUT_LOD: [[u32; 5]; 6] = [
    [44, 44, 120, 10, 14],
    [14, 14, 120, 4, 4],
    [6, 6, 120, 2, 2],
    [4, 4, 74, 2, 2],
    [2, 2, 26, 2, 2],
    [2, 2, 20, 2, 2],
];
/// Table 5: FPS on a GTX 750 with LOD.
pub const TABLE_5_GTX750_WITH_LOD: [[u32; 5]; 6] = [
    [56, 66, 120, 24, 32],
    [26, 32, 120, 20, 24],
    [18, 22, 120, 16, 20],
    [14, 18, 120, 14, 18],
    [8, 12, 120, 10, 12],
    [6, 8, 100, 8, 10],
];
/// Table 6: FPS on a GTX 1080 Ti without LOD.
pub const TABLE_6_GTX1080TI_WITHOUT_LOD: [[u32; 5]; 6] = [
    [120, 120, 120, 78, 100],
    [104, 104, 120, 22, 30],
    [48, 48, 120, 10, 14],
    [26, 26, 120, 6, 8],
    [10, 10, 120, 2, 2],
    [8, 8, 115, 2, 2],
];
/// Table 7: FPS on a GTX 1080 Ti with LOD.
pub const TABLE_7_GTX1080TI_WITH_LOD: [[u32; 5]; 6] = [
    [120, 120, 120, 120, 120],
    [105, 110, 120, 120, 120],
    [50, 62, 120, 106, 112],
    [44, 50, 120, 74, 80],
    [22, 32, 120, 38, 46],
    [18, 22, 120, 19, 28],
];

/// What the 120 FPS cap does to a with/without ratio.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Cap {
    /// Neither value at the cap: the ratio is the paper's.
    Exact,
    /// Only the with-LOD value at the cap: the true ratio is at least the one shown.
    LowerBound,
    /// Only the without-LOD value at the cap: the true ratio is at most the one shown.
    UpperBound,
    /// Both at the cap: the ratio says nothing.
    BothCapped,
}

/// One cell pair of Tables 4–7: a model's FPS without and with LOD for one instance count.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct FpsRatio {
    pub model: PaperModel,
    pub gpu: Gpu,
    pub instances: u32,
    pub fps_without: u32,
    pub fps_with: u32,
}

impl FpsRatio {
    /// FPS with LOD / without: the paper's speed-up (as shown, whatever the cap).
    #[must_use]
    pub fn ratio(&self) -> f64 {
        f64::from(self.fps_with) / f64::from(self.fps_without)
    }

    #[must_use]
    pub fn cap(&self) -> Cap {
        match (self.fps_without >= FPS_CAP, self.fps_with >= FPS_CAP) {
            (false, false) => Cap::Exact,
            (false, true) => Cap::LowerBound,
            (true, false) => Cap::UpperBound,
            (true, true) => Cap::BothCapped,
        }
    }

    /// The ratio with its cap marker: `1.27`, `≥1.62` (lower bound), `≤0.95` (upper bound) or
    /// `capped` (both at the cap).
    #[must_use]
    pub fn label(&self) -> String {
        let r = self.ratio();
        match self.cap() {
            Cap::Exact => format!("{r:.2}"),
            Cap::LowerBound => format!("≥{r:.2}"),
            Cap::UpperBound => format!("≤{r:.2}"),
            Cap::BothCapped => "capped".into(),
        }
    }

    /// [`Self::label`] and the two FPS values, with LOD first: `≥1.62 (120/74 FPS)`.
    #[must_use]
    pub fn detail(&self) -> String {
        format!("{} ({}/{} FPS)", self.label(), self.fps_with, self.fps_without)
    }
}

/// The paper's FPS cells for `model` on `gpu` with `instances` instances; none when Tables 4–7
/// have no such row.
#[must_use]
pub fn fps_ratio(model: PaperModel, gpu: Gpu, instances: u32) -> Option<FpsRatio> {
    let row = INSTANCE_COUNTS.iter().position(|&n| n == instances)?;
    Some(FpsRatio {
        model,
        gpu,
        instances,
        fps_without: gpu.fps_table(false)[row][model.index()],
        fps_with: gpu.fps_table(true)[row][model.index()],
    })
}

/// The spread of the five models' ratios on one GPU and instance count.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct RatioRange {
    /// The smallest and largest ratio among the cells not both at the cap; none when every
    /// model's cells are.
    pub lowest: Option<FpsRatio>,
    pub highest: Option<FpsRatio>,
    /// Models left out: both cells at the cap.
    pub both_capped: Vec<PaperModel>,
}

impl RatioRange {
    /// `1.27–2.40 (Bunny capped)`: the two ends with their cap markers, then the models left out.
    #[must_use]
    pub fn label(&self) -> String {
        let mut s = match (&self.lowest, &self.highest) {
            (Some(lo), Some(hi)) if lo == hi => lo.label(),
            (Some(lo), Some(hi)) => format!("{}–{}", lo.label(), hi.label()),
            _ => return "all capped".into(),
        };
        if !self.both_capped.is_empty() {
            let names: Vec<&str> = self.both_capped.iter().map(|m| m.short_name()).collect();
            let _ = write!(s, " ({} capped)", names.join(", "));
        }
        s
    }
}

/// The range of the five models' ratios on `gpu` for `instances`; none without such a row.
#[must_use]
pub fn ratio_range(gpu: Gpu, instances: u32) -> Option<RatioRange> {
    let cells: Vec<FpsRatio> =
        PAPER_MODELS.iter().map(|&m| fps_ratio(m, gpu, instances)).collect::<Option<_>>()?;
    let (capped, meaningful): (Vec<FpsRatio>, Vec<FpsRatio>) =
        cells.into_iter().partition(|c| c.cap() == Cap::BothCapped);
    let by_ratio = |a: &&FpsRatio, b: &&FpsRatio| a.ratio().total_cmp(&b.ratio());
    Some(RatioRange {
        lowest: meaningful.iter().min_by(by_ratio).copied(),
        highest: meaningful.iter().max_by(by_ratio).copied(),
        both_capped: capped.iter().map(|c| c.model).collect(),
    })
}

/// The paper's ratio for `instances` on `gpu` as a report cell: the model's cell with its FPS
/// values when the tileset is one of the paper's models, else the five models' range; none
/// when Tables 4–7 have no such row.
#[must_use]
pub fn ratio_cell(model: Option<PaperModel>, gpu: Gpu, instances: u32) -> Option<String> {
    match model {
        Some(m) => fps_ratio(m, gpu, instances).map(|r| r.detail()),
        None => ratio_range(gpu, instances).map(|r| r.label()),
    }
}

/// Recall, precision and F-measure of the paper's coverage comparison.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Coverage {
    pub recall: f64,
    pub precision: f64,
    pub f_measure: f64,
}

/// Table 12: coverage, LOD against the original, 1,331 cameras on a sphere; one row per model.
pub const TABLE_12: [Coverage; 5] = [
    Coverage { recall: 0.949, precision: 0.969, f_measure: 0.959 },
    Coverage { recall: 0.938, precision: 0.951, f_measure: 0.944 },
    Coverage { recall: 0.950, precision: 0.981, f_measure: 0.965 },
    Coverage { recall: 0.949, precision: 0.889, f_measure: 0.918 },
    Coverage { recall: 0.971, precision: 0.890, f_measure: 0.928 },
];
/// Table 12's average row, as published. Its recall is the five rows' mean; its precision and
/// F-measure are not (the rows' means are 0.936 and 0.943), so it is printed as the paper's
/// figure, not recomputed.
pub const TABLE_12_AVERAGE: Coverage = Coverage { recall: 0.952, precision: 0.944, f_measure: 0.947 };
/// The large-terrain experiment (1,681 tiles of 5,000,000 vertices, 5 levels, GTX 1080 Ti).
pub const LARGE_TERRAIN_F: f64 = 0.972;

/// Table 12's row for `model`, or its average row for none.
#[must_use]
pub fn table_12(model: Option<PaperModel>) -> Coverage {
    model.map_or(TABLE_12_AVERAGE, PaperModel::table_12)
}

/// Our per-level counts beside Table 3 when `source_name` names one of the paper's models:
/// a heading, a header line and one line per level (level, ours, the paper's, ours / paper),
/// without a trailing newline. `levels` holds (level id, vertices or points) of the levels
/// stored, in any order and possibly with gaps: a Table-3 level whose id is absent is "not
/// stored", and our levels past Table 3's are listed with no paper figure.
#[must_use]
pub fn table_3_comparison(source_name: &str, levels: &[(u8, u64)]) -> Option<String> {
    let model = PaperModel::from_source_name(source_name)?;
    let paper = model.table_3();
    let mut s = format!(
        "the paper's Table 3, {} (level 0: mesh vertices; other levels: points):\n{:>5}  {:>10}  {:>10}  {:>10}",
        model.name(),
        "level",
        "ours",
        "paper",
        "ours/paper"
    );
    let last = levels.iter().map(|l| l.0).max().unwrap_or(0).max((paper.len() - 1) as u8);
    for id in 0..=last {
        let ours = levels.iter().find(|l| l.0 == id).map(|l| l.1);
        let theirs = paper.get(usize::from(id)).copied();
        if ours.is_none() && theirs.is_none() {
            continue;
        }
        let ratio = match (ours, theirs) {
            (Some(o), Some(p)) if p > 0 => format!("{:.2}", o as f64 / p as f64),
            _ => "-".into(),
        };
        let _ = write!(
            s,
            "\n{id:>5}  {:>10}  {:>10}  {ratio:>10}",
            ours.map_or_else(|| "not stored".into(), |o| o.to_string()),
            theirs.map_or_else(|| "-".into(), |p| p.to_string())
        );
    }
    Some(s)
}

#[cfg(test)]
#[allow(clippy::float_cmp)]
mod tests {
    use super::*;

    #[test]
    fn source_names_find_the_paper_models() {
        use PaperModel::*;
        for (name, want) in [
            ("bunny.ply", Some(StanfordBunny)),
            ("stanford-bunny.obj", Some(StanfordBunny)),
            ("bun_zipper.ply", Some(StanfordBunny)),
            ("BUN_ZIPPER_RES2.PLY", Some(StanfordBunny)),
            ("data/scans/bun000.ply", Some(StanfordBunny)),
            ("dragon.obj", Some(Dragon)),
            ("dragon_vrip_res2.ply", Some(Dragon)),
            ("xyzrgb_dragon.ply", Some(Dragon)),
            ("happy_vrip.ply", Some(HappyBuddha)),
            ("Happy-Buddha.stl", Some(HappyBuddha)),
            ("HappyBuddha.obj", Some(HappyBuddha)),
            ("buddha.ply", Some(HappyBuddha)),
            ("lucy.ply", Some(StanfordLucy)),
            ("C:\\models\\Stanford_Lucy.ply", Some(StanfordLucy)),
            ("Armadillo.ply", Some(Armadillo)),
            ("spot.obj", None),
            ("rocker-arm.obj", None),
            ("bundle.obj", None),
            ("happy.obj", None),
            ("fuji.png", None),
            ("bunny-and-dragon.obj", None),
            ("", None),
        ] {
            assert_eq!(PaperModel::from_source_name(name), want, "{name}");
        }
        assert!(PAPER_MODELS.iter().enumerate().all(|(i, m)| m.index() == i));
    }

    #[test]
    fn fps_ratios_know_the_cap() {
        let r = fps_ratio(PaperModel::StanfordBunny, Gpu::Gtx750, 1_681).unwrap();
        assert_eq!((r.fps_with, r.fps_without), (120, 74));
        assert!((r.ratio() - 120.0 / 74.0).abs() < 1e-12);
        assert_eq!(r.cap(), Cap::LowerBound);
        assert_eq!(r.label(), "≥1.62");
        assert_eq!(r.detail(), "≥1.62 (120/74 FPS)");

        let r = fps_ratio(PaperModel::HappyBuddha, Gpu::Gtx750, 121).unwrap();
        assert_eq!((r.fps_with, r.fps_without), (56, 44));
        assert_eq!(r.cap(), Cap::Exact);
        assert_eq!(r.detail(), "1.27 (56/44 FPS)");

        let r = fps_ratio(PaperModel::StanfordBunny, Gpu::Gtx1080Ti, 121).unwrap();
        assert_eq!(r.cap(), Cap::BothCapped);
        assert_eq!(r.label(), "capped");
        let r = fps_ratio(PaperModel::StanfordBunny, Gpu::Gtx1080Ti, 6_561).unwrap();
        assert_eq!((r.fps_with, r.fps_without, r.cap()), (120, 115, Cap::LowerBound));
        let r = fps_ratio(PaperModel::StanfordLucy, Gpu::Gtx1080Ti, 6_561).unwrap();
        assert_eq!((r.fps_with, r.fps_without, r.cap()), (19, 2, Cap::Exact));
        assert_eq!(r.label(), "9.50");
        let r = fps_ratio(PaperModel::Armadillo, Gpu::Gtx750, 5_041).unwrap();
        assert_eq!((r.fps_with, r.fps_without), (12, 2));

        let up = FpsRatio { fps_without: 120, fps_with: 100, ..r };
        assert_eq!((up.cap(), up.label()), (Cap::UpperBound, "≤0.83".to_owned()));
        assert!(fps_ratio(PaperModel::Dragon, Gpu::Gtx750, 225).is_none());
        assert!(ratio_cell(None, Gpu::Gtx750, 9).is_none());
    }

    #[test]
    fn ranges_leave_out_cells_capped_at_both() {
        // GTX 750, 121: Buddha 56/44, Dragon 66/44, Bunny 120/120, Lucy 24/10, Armadillo 32/14.
        let r = ratio_range(Gpu::Gtx750, 121).unwrap();
        assert_eq!(r.lowest.unwrap().model, PaperModel::HappyBuddha);
        assert_eq!(r.highest.unwrap().model, PaperModel::StanfordLucy);
        assert_eq!(r.both_capped, vec![PaperModel::StanfordBunny]);
        assert_eq!(r.label(), "1.27–2.40 (Bunny capped)");
        // GTX 1080 Ti, 121: only Lucy (120/78) and Armadillo (120/100) say anything, as bounds.
        let r = ratio_range(Gpu::Gtx1080Ti, 121).unwrap();
        assert_eq!(r.label(), "≥1.20–≥1.54 (Buddha, Dragon, Bunny capped)");
        // GTX 750, 6,561: every cell below the cap; Bunny 100/20 is the largest.
        let r = ratio_range(Gpu::Gtx750, 6_561).unwrap();
        assert_eq!(r.label(), "3.00–5.00");
        assert_eq!(
            ratio_cell(Some(PaperModel::StanfordBunny), Gpu::Gtx750, 6_561).unwrap(),
            "5.00 (100/20 FPS)"
        );
        let none = RatioRange { lowest: None, highest: None, both_capped: PAPER_MODELS.to_vec() };
        assert_eq!(none.label(), "all capped");
    }

    #[test]
    fn tables_3_and_12_by_model() {
        assert_eq!(PaperModel::StanfordBunny.table_3(), [14_904, 12_654, 7_092, 3_191, 800]);
        assert_eq!(PaperModel::StanfordLucy.table_3()[0], 1_346_640);
        assert_eq!(table_12(Some(PaperModel::StanfordBunny)).f_measure, 0.965);
        assert_eq!(table_12(Some(PaperModel::Armadillo)).precision, 0.890);
        assert_eq!(table_12(None), TABLE_12_AVERAGE);
        // As published: the average's recall is the rows' mean, its precision and F are not.
        let mean = |f: fn(&Coverage) -> f64| TABLE_12.iter().map(f).sum::<f64>() / 5.0;
        assert!((mean(|c| c.recall) - TABLE_12_AVERAGE.recall).abs() < 0.001);
        assert!((mean(|c| c.precision) - 0.936).abs() < 0.001);
        assert!((mean(|c| c.f_measure) - 0.943).abs() < 0.001);
    }

    /// The header and body rows (cells trimmed, thousands separators removed) of the Markdown
    /// table after the first line of `md` that starts with `title`.
    fn md_table(md: &str, title: &str) -> (Vec<String>, Vec<Vec<String>>) {
        let cells =
            |l: &str| l.trim().trim_matches('|').split('|').map(|c| c.trim().replace(',', "")).collect();
        let mut rows = md
            .lines()
            .skip_while(|l| !l.starts_with(title))
            .skip(1)
            .skip_while(|l| !l.starts_with('|'))
            .take_while(|l| l.starts_with('|'));
        let header = rows.next().map(cells).unwrap_or_default();
        (header, rows.skip(1).map(cells).collect())
    }

    /// Every figure above against the published tables as transcribed in the shared
    /// `papers/tables.md` (skipped without the shared data, unless `TERRASTREAM_REQUIRE_DATA=1`).
    #[test]
    fn constants_match_the_published_tables() {
        let what = "paper::tests::constants_match_the_published_tables";
        let Some(path) = crate::raster::shared_test_data("../papers/tables.md", what) else { return };
        let md = std::fs::read_to_string(path).unwrap();
        let (_, t3) = md_table(&md, "### Table 3 ");
        assert_eq!(t3.len(), PAPER_MODELS.len());
        for (row, m) in t3.iter().zip(PAPER_MODELS) {
            assert_eq!(row[0], m.name());
            let v: Vec<u64> = row[1..].iter().map(|c| c.parse().unwrap()).collect();
            assert_eq!(v, m.table_3(), "Table 3, {}", m.name());
        }
        for (title, gpu, with_lod) in [
            ("Table 4 — ", Gpu::Gtx750, false),
            ("Table 5 — ", Gpu::Gtx750, true),
            ("Table 6 — ", Gpu::Gtx1080Ti, false),
            ("Table 7 — ", Gpu::Gtx1080Ti, true),
        ] {
            let (header, rows) = md_table(&md, title);
            assert_eq!(header[1..], PAPER_MODELS.map(PaperModel::short_name), "{title}");
            assert!(md.lines().any(|l| l.starts_with(title) && l.contains(gpu.name())), "{title}");
            assert_eq!(rows.len(), INSTANCE_COUNTS.len(), "{title}");
            for ((row, n), want) in rows.iter().zip(INSTANCE_COUNTS).zip(gpu.fps_table(with_lod)) {
                assert_eq!(row[0].parse::<u32>().unwrap(), n, "{title}");
                let v: Vec<u32> = row[1..].iter().map(|c| c.parse().unwrap()).collect();
                assert_eq!(&v[..], want, "{title}N = {n}");
            }
        }
        assert!(md.contains(&format!("capped at {FPS_CAP} FPS")));
        let (_, t12) = md_table(&md, "### Table 12 ");
        let want =
            PAPER_MODELS.map(|m| (m.name(), m.table_12())).into_iter().chain([("average", TABLE_12_AVERAGE)]);
        assert_eq!(t12.len(), PAPER_MODELS.len() + 1);
        for (row, (name, c)) in t12.iter().zip(want) {
            assert_eq!(row[0], name);
            let v: Vec<f64> = row[1..].iter().map(|c| c.parse().unwrap()).collect();
            assert_eq!(v, [c.recall, c.precision, c.f_measure], "Table 12, {name}");
        }
        // The large-terrain bullet (it wraps over lines).
        let terrain = &md[md.find("1,681 terrain tiles").unwrap()..];
        let terrain = &terrain[..terrain.find("\n- ").unwrap_or(terrain.len())];
        assert!(terrain.contains(&format!("F-measure {LARGE_TERRAIN_F}")), "{terrain}");
    }

    #[test]
    fn table_3_comparison_marks_levels_not_stored() {
        assert!(table_3_comparison("spot.obj", &[(0, 10)]).is_none());
        let t = table_3_comparison("stanford-bunny.obj", &[(0, 35_947), (1, 12_832), (3, 3_300), (5, 100)])
            .unwrap();
        let lines: Vec<&str> = t.lines().collect();
        assert_eq!(lines.len(), 2 + 6, "{t}");
        assert!(lines[0].contains("Stanford Bunny"), "{t}");
        let cols = |l: &str| l.split_whitespace().map(str::to_owned).collect::<Vec<_>>();
        assert_eq!(cols(lines[1]), ["level", "ours", "paper", "ours/paper"]);
        assert_eq!(cols(lines[2]), ["0", "35947", "14904", "2.41"]);
        assert_eq!(cols(lines[3]), ["1", "12832", "12654", "1.01"]);
        assert_eq!(cols(lines[4]), ["2", "not", "stored", "7092", "-"]);
        assert_eq!(cols(lines[5]), ["3", "3300", "3191", "1.03"]);
        assert_eq!(cols(lines[6]), ["4", "not", "stored", "800", "-"]);
        assert_eq!(cols(lines[7]), ["5", "100", "-", "-"]);
        assert!(!t.ends_with('\n'));
        // Order of the input does not matter.
        let u = table_3_comparison("bunny.ply", &[(5, 100), (3, 3_300), (1, 12_832), (0, 35_947)]).unwrap();
        assert_eq!(u.lines().skip(1).collect::<Vec<_>>(), lines[1..]);
    }
}
