//! Warping: a dataset whose files are in different coordinate systems (or given `--target-crs`)
//! is resampled, block by block and out of core, onto one target grid.
//!
//! The target CRS is `--target-crs`, else the first file's; its cells are the first file's cell
//! carried to the target CRS at that file's centre (its own cells when the CRS is the same), and
//! the grid is aligned to the first file's when the CRS is the same, so that file's samples are
//! taken as they are. Each target sample is carried to every file's CRS in input order; the
//! first file that covers it gives its value, bilinearly from its four samples around it — with
//! no-data samples left out and the weights of the others renormalised, no-data only where no
//! valid sample has weight. The resampling's own error is measured: at every interpolated sample,
//! the twist of its cell (`|a − b − c + d| / 4`, how far a bilinear surface leaves any plane
//! through its corners; 0 on planes and on grid-aligned samples). The largest over the dataset
//! goes into every tile's error ([`WarpStats::max_twist`]).

use std::collections::HashMap;
use std::path::Path;
use std::sync::{Arc, Mutex, PoisonError};

use super::parts::{BlockSource, MAX_DATASET_SIDE, Part, whole_part};
use super::{FileCrs, FileGeoref, RasterError};
use crate::crs::Crs;

/// Side of a warped block, in target samples.
const BLOCK: u32 = 256;
/// File blocks each file keeps decoded.
const CACHED_BLOCKS: usize = 64;
/// Points per edge when a file's extent is carried to the target CRS.
const EDGE_POINTS: u32 = 33;

/// One file of a warped dataset.
struct Input {
    part: Part,
    crs: Crs,
    /// The file's sample (0, 0) centre and steps, in its CRS's units.
    x0: f64,
    y0: f64,
    dx: f64,
    dy: f64,
    /// Its sample-centre extent in the target CRS, widened by two target cells: target samples
    /// outside it are not carried to this file's CRS at all.
    reach: [f64; 4],
    blocks: Mutex<BlockMap>,
}

/// Decoded file blocks by (block column, block row).
type BlockMap = HashMap<(u32, u32), Arc<Vec<f32>>>;

impl Input {
    /// Sample (c, r) of the file's window: `None` for no-data.
    fn sample(&self, c: u32, r: u32) -> Result<Option<f32>, RasterError> {
        let p = &self.part;
        let (bw, bh) = p.source.block_size();
        let (fc, fr) = (p.win_col + c, p.win_row + r);
        let (bx, by) = (fc / bw.max(1), fr / bh.max(1));
        let block = {
            let cached = self.blocks.lock().unwrap_or_else(PoisonError::into_inner).get(&(bx, by)).cloned();
            if let Some(b) = cached {
                b
            } else {
                let mut out = Vec::new();
                p.source.read_block(&p.path, bx, by, &mut out)?;
                let b = Arc::new(out);
                let mut map = self.blocks.lock().unwrap_or_else(PoisonError::into_inner);
                if map.len() >= CACHED_BLOCKS {
                    // Any block goes: reads move in rows of target blocks, so the cache holds
                    // what the current rows touch.
                    if let Some(k) = map.keys().next().copied() {
                        map.remove(&k);
                    }
                }
                map.insert((bx, by), b.clone());
                b
            }
        };
        let w = bw.min(p.file_width - bx * bw);
        let i = ((fr - by * bh) * w + (fc - bx * bw)) as usize;
        let v = block.get(i).copied().ok_or_else(|| {
            RasterError::corrupt(&p.path, "raster", format!("block ({bx}, {by}) is shorter than its size"))
        })?;
        Ok((!(v.is_nan() || p.nodata.contains(&v))).then_some(v))
    }

    /// The bilinear value at fractional sample (fc, fr) of the window, no-data aware, and the
    /// cell's twist; `None` outside the window or where no sample with weight is valid.
    fn bilinear(&self, fc: f64, fr: f64) -> Result<Option<(f32, f64)>, RasterError> {
        let (w, h) = (f64::from(self.part.width), f64::from(self.part.height));
        let eps = 1e-9;
        if !(fc >= -eps && fr >= -eps && fc <= w - 1.0 + eps && fr <= h - 1.0 + eps) {
            return Ok(None);
        }
        let fc = fc.clamp(0.0, w - 1.0);
        let fr = fr.clamp(0.0, h - 1.0);
        let (c0, r0) = (fc.floor() as u32, fr.floor() as u32);
        let (c1, r1) = ((c0 + 1).min(self.part.width - 1), (r0 + 1).min(self.part.height - 1));
        let (tc, tr) = (fc - f64::from(c0), fr - f64::from(r0));
        let corners = [
            (c0, r0, (1.0 - tc) * (1.0 - tr)),
            (c1, r0, tc * (1.0 - tr)),
            (c0, r1, (1.0 - tc) * tr),
            (c1, r1, tc * tr),
        ];
        let (mut sum, mut weight) = (0.0, 0.0);
        let mut values = [None; 4];
        for (k, &(c, r, wgt)) in corners.iter().enumerate() {
            if wgt <= 1e-12 {
                continue;
            }
            if let Some(v) = self.sample(c, r)? {
                values[k] = Some(f64::from(v));
                sum += wgt * f64::from(v);
                weight += wgt;
            }
        }
        if weight <= 1e-12 {
            return Ok(None);
        }
        let twist = match values {
            [Some(a), Some(b), Some(c), Some(d)] => (a - b - c + d).abs() / 4.0,
            _ => 0.0,
        };
        Ok(Some(((sum / weight) as f32, twist)))
    }
}

/// What warping measured, for the summary, the manifest and the tile errors.
#[derive(Debug, Clone, Copy, Default, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct WarpStats {
    /// The largest twist of a cell a target sample was interpolated in (metres): added to every
    /// tile's error.
    pub max_twist: f64,
    /// Target samples interpolated (not on a file's grid) and taken as they are.
    pub interpolated: u64,
    pub exact: u64,
}

/// The warped grid as one block source.
struct WarpSource {
    inputs: Vec<Input>,
    target: Crs,
    x0: f64,
    y0: f64,
    dx: f64,
    dy: f64,
    width: u32,
    height: u32,
    stats: Arc<Mutex<WarpStats>>,
}

impl BlockSource for WarpSource {
    fn block_size(&self) -> (u32, u32) {
        (BLOCK, BLOCK)
    }

    fn read_block(&self, _path: &Path, bx: u32, by: u32, out: &mut Vec<f32>) -> Result<(), RasterError> {
        let (c0, r0) = (bx * BLOCK, by * BLOCK);
        let (w, h) = (BLOCK.min(self.width - c0), BLOCK.min(self.height - r0));
        out.reserve((w * h) as usize);
        let mut local = WarpStats::default();
        for r in r0..r0 + h {
            for c in c0..c0 + w {
                let (x, y) = (self.x0 + f64::from(c) * self.dx, self.y0 + f64::from(r) * self.dy);
                let mut value = f32::NAN;
                for input in &self.inputs {
                    let r = &input.reach;
                    let tx = if self.target.is_geographic() {
                        unwrap_near(x, f64::midpoint(r[0], r[1]), 0.0, 1)
                    } else {
                        x
                    };
                    if !(r[0]..=r[1]).contains(&tx) || !(r[2]..=r[3]).contains(&y) {
                        continue;
                    }
                    let Ok((sx, sy)) = self.target.transform_to(&input.crs, x, y) else { continue };
                    let sx = if input.crs.is_geographic() {
                        unwrap_near(sx, input.x0, input.dx, input.part.width)
                    } else {
                        sx
                    };
                    let (fc, fr) = ((sx - input.x0) / input.dx, (sy - input.y0) / input.dy);
                    if let Some((v, twist)) = input.bilinear(fc, fr)? {
                        let on_grid = (fc - fc.round()).abs() < 1e-6 && (fr - fr.round()).abs() < 1e-6;
                        if on_grid {
                            local.exact += 1;
                        } else {
                            local.interpolated += 1;
                            local.max_twist = local.max_twist.max(twist);
                        }
                        value = v;
                        break;
                    }
                }
                out.push(value);
            }
        }
        let mut s = self.stats.lock().unwrap_or_else(PoisonError::into_inner);
        s.max_twist = s.max_twist.max(local.max_twist);
        s.interpolated += local.interpolated;
        s.exact += local.exact;
        Ok(())
    }
}

/// A longitude moved by whole turns to lie nearest the file's columns.
fn unwrap_near(lon: f64, x0: f64, dx: f64, width: u32) -> f64 {
    let centre = x0 + dx * f64::from(width.saturating_sub(1)) / 2.0;
    lon + 360.0 * ((centre - lon) / 360.0).round()
}

fn bad(path: &Path, message: String) -> RasterError {
    RasterError::Dataset { path: path.to_owned(), message }
}

/// Warps `parts` (each with its file georeference and CRS) onto one grid in `target` (or the
/// first file's CRS): the dataset's single part, its georeference in the target CRS, the target
/// CRS, and where warping's figures will be gathered.
#[allow(clippy::type_complexity)]
pub(super) fn warp(
    parts: Vec<Part>,
    georefs: &[FileGeoref],
    crss: &[(std::path::PathBuf, FileCrs)],
    target: Option<Crs>,
) -> Result<(Part, FileGeoref, FileCrs, Arc<Mutex<WarpStats>>), RasterError> {
    let first = crss.first().map(|c| c.0.clone()).unwrap_or_default();
    let with_crs = crss.iter().find_map(|(p, c)| c.horizontal.as_ref().map(|h| (p, h.definition())));
    let mut inputs = Vec::with_capacity(parts.len());
    for ((part, g), (path, fc)) in parts.into_iter().zip(georefs).zip(crss) {
        let Some(crs) = fc.horizontal.clone() else {
            let (other, def) = with_crs.unwrap_or((path, "another CRS"));
            return Err(bad(
                path,
                format!(
                    "names no coordinate system but {} is in {def}; the files of a mosaic in several coordinate \
                     systems must each name theirs (or give --crs for all)",
                    other.display()
                ),
            ));
        };
        if fc.vertical != crss[0].1.vertical {
            return Err(bad(path, "measures heights from another vertical datum than the first file".into()));
        }
        let (x0, y0, dx, dy) = match *g {
            FileGeoref::Projected { x0, y0, dx, dy } => (x0, y0, dx, dy),
            FileGeoref::Geographic { lon0, lat0, dlon, dlat } => (lon0, lat0, dlon, dlat),
            FileGeoref::None => return Err(bad(path, "has no georeference".into())),
        };
        inputs.push(Input { part, crs, x0, y0, dx, dy, reach: [0.0; 4], blocks: Mutex::new(HashMap::new()) });
    }
    let Some(f) = inputs.first() else { return Err(bad(&first, "no input to warp".into())) };
    let target = target.unwrap_or_else(|| f.crs.clone());
    let same = target == f.crs;
    // The target's cell: the first file's, carried to the target CRS at its centre.
    let (fw, fh) = (f64::from(f.part.width), f64::from(f.part.height));
    let (cx, cy) = (f.x0 + f.dx * (fw - 1.0) / 2.0, f.y0 + f.dy * (fh - 1.0) / 2.0);
    let (dx, dy) = if same {
        (f.dx, f.dy)
    } else {
        let to =
            |x: f64, y: f64| f.crs.transform_to(&target, x, y).map_err(|e| bad(&f.part.path, e.to_string()));
        let (a, b, c) = (to(cx, cy)?, to(cx + f.dx, cy)?, to(cx, cy + f.dy)?);
        let side = ((b.0 - a.0).hypot(b.1 - a.1) * (c.0 - a.0).hypot(c.1 - a.1)).sqrt();
        (side, -side)
    };
    // The union of the files' sample-centre extents in the target CRS.
    let (fx0, fy0, fdx, fdy) = (f.x0, f.y0, f.dx, f.dy);
    let (mut xmin, mut xmax, mut ymin, mut ymax) =
        (f64::INFINITY, f64::NEG_INFINITY, f64::INFINITY, f64::NEG_INFINITY);
    let mut ref_lon = None;
    for i in &mut inputs {
        let mut reach = [f64::INFINITY, f64::NEG_INFINITY, f64::INFINITY, f64::NEG_INFINITY];
        let (w, h) = (f64::from(i.part.width - 1), f64::from(i.part.height - 1));
        for k in 0..EDGE_POINTS {
            let t = f64::from(k) / f64::from(EDGE_POINTS - 1);
            for (u, v) in [(t, 0.0), (t, 1.0), (0.0, t), (1.0, t)] {
                let (x, y) = (i.x0 + i.dx * u * w, i.y0 + i.dy * v * h);
                let (mut tx, ty) =
                    i.crs.transform_to(&target, x, y).map_err(|e| bad(&i.part.path, e.to_string()))?;
                if target.is_geographic() {
                    let r = *ref_lon.get_or_insert(tx);
                    tx += 360.0 * ((r - tx) / 360.0).round();
                }
                reach = [reach[0].min(tx), reach[1].max(tx), reach[2].min(ty), reach[3].max(ty)];
            }
        }
        xmin = xmin.min(reach[0]);
        xmax = xmax.max(reach[1]);
        ymin = ymin.min(reach[2]);
        ymax = ymax.max(reach[3]);
        i.reach = reach;
    }
    // Widened by two target cells (the files' edges curve between the sampled points).
    for i in &mut inputs {
        let (mx, my) = (2.0 * dx.abs(), 2.0 * dy.abs());
        i.reach = [i.reach[0] - mx, i.reach[1] + mx, i.reach[2] - my, i.reach[3] + my];
    }
    // Aligned to the first file's grid in its own CRS; north-up, west to east otherwise.
    let (ox, oy) = if same {
        let snap = |o: f64, v: f64, d: f64| o + ((v - o) / d).floor() * d;
        (
            snap(fx0, if fdx > 0.0 { xmin } else { xmax }, fdx),
            snap(fy0, if fdy < 0.0 { ymax } else { ymin }, fdy),
        )
    } else {
        (xmin, ymax)
    };
    let cols = ((if dx > 0.0 { xmax - ox } else { ox - xmin }) / dx.abs()).floor() + 1.0;
    let rows = ((if dy < 0.0 { oy - ymin } else { ymax - oy }) / dy.abs()).floor() + 1.0;
    if !(cols.is_finite() && rows.is_finite())
        || cols > f64::from(MAX_DATASET_SIDE)
        || rows > f64::from(MAX_DATASET_SIDE)
    {
        return Err(bad(
            &first,
            format!(
                "warped onto {} the mosaic would be {cols}×{rows} samples, beyond {MAX_DATASET_SIDE} a side",
                target.definition()
            ),
        ));
    }
    let (width, height) = (cols as u32, rows as u32);
    let georef = if target.is_geographic() {
        FileGeoref::Geographic { lon0: ox, lat0: oy, dlon: dx, dlat: dy }
    } else {
        FileGeoref::Projected { x0: ox, y0: oy, dx, dy }
    };
    let vertical = crss[0].1.vertical;
    let stats = Arc::new(Mutex::new(WarpStats::default()));
    let source = WarpSource {
        inputs,
        target: target.clone(),
        x0: ox,
        y0: oy,
        dx,
        dy,
        width,
        height,
        stats: stats.clone(),
    };
    let part = whole_part(&first, Box::new(source), "warped", width, height);
    Ok((part, georef, FileCrs { horizontal: Some(target), vertical }, stats))
}
