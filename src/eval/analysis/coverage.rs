//! Per-pixel coverage (TP, FP, FN → recall, precision, F-measure), depth differences, and
//! their aggregation by distance and level.

use std::collections::BTreeMap;

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
