//! The report's PNG charts, drawn with `image` (lines, dots, no fonts).

use super::{EvalReport, InstanceRow, by_distance};

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
