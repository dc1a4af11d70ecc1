//! Hole filling, the paper's median filter (the module doc's *Hole filling*), and turning a
//! cell's sums into its point.

use super::{
    Acc, BakedCell, CellKey, FILL_MIN_NEIGHBOURS, FastMap, NORMAL_ONE, POS_HALF, POS_MASK, POS_ONE,
    POSITION_FRACTION_BITS,
};

/// Turns a cell's sums into its output point.
pub(super) fn finish(key: CellKey, a: &Acc, origin: [f64; 3], cell: f64, filled: bool) -> BakedCell {
    let index = key.index();
    let denom = a.count.max(1) as f64 * POS_ONE;
    let coord = |d: usize| origin[d] + (f64::from(index[d]) + a.pos[d] as f64 / denom) * cell;
    let position = [coord(0), coord(1), coord(2)];
    let n = [a.normal[0] as f64, a.normal[1] as f64, a.normal[2] as f64];
    let len = (n[0] * n[0] + n[1] * n[1] + n[2] * n[2]).sqrt();
    let normal = if len > 0.0 {
        [(n[0] / len) as f32, (n[1] / len) as f32, (n[2] / len) as f32]
    } else {
        [0.0, 0.0, 1.0]
    };
    BakedCell { index, position, normal, samples: a.count, filled }
}

/// Per-column summary of the occupancy along one axis.
#[derive(Clone, Copy)]
pub(super) struct Column {
    /// Column index on (u, v).
    uv: [i32; 2],
    /// Positions in the sorted cell list of the lowest and highest occupied cell along the axis.
    front: usize,
    back: usize,
    /// Their slices.
    front_s: i32,
    back_s: i32,
}

/// Finds a column by its (u, v) index: a dense table over the columns' bounding rectangle when
/// that is not much larger than the column count (the usual case: a tile's projections are
/// compact), a hash map otherwise (sparse models in large empty volumes).
enum ColumnLookup {
    Dense { min: [i64; 2], width: i64, height: i64, slots: Vec<u32> },
    Sparse(FastMap<[i32; 2], u32>),
}

impl ColumnLookup {
    fn new(min: [i64; 2], max: [i64; 2], cells: usize) -> Self {
        // One ring of margin so neighbour lookups of edge columns stay in the table.
        let width = max[0] - min[0] + 3;
        let height = max[1] - min[1] + 3;
        let area = width as f64 * height as f64;
        if area <= (8.0 * cells as f64).max(65_536.0) {
            Self::Dense {
                min: [min[0] - 1, min[1] - 1],
                width,
                height,
                slots: vec![u32::MAX; (width * height) as usize],
            }
        } else {
            Self::Sparse(FastMap::default())
        }
    }

    #[inline]
    fn get(&self, uv: [i32; 2]) -> Option<u32> {
        match self {
            Self::Dense { min, width, height, slots } => {
                let x = i64::from(uv[0]) - min[0];
                let y = i64::from(uv[1]) - min[1];
                if x < 0 || y < 0 || x >= *width || y >= *height {
                    return None;
                }
                let s = slots[(y * width + x) as usize];
                (s != u32::MAX).then_some(s)
            }
            Self::Sparse(map) => map.get(&uv).copied(),
        }
    }

    #[inline]
    fn insert(&mut self, uv: [i32; 2], id: u32) {
        match self {
            Self::Dense { min, width, slots, .. } => {
                let x = i64::from(uv[0]) - min[0];
                let y = i64::from(uv[1]) - min[1];
                slots[(y * *width + x) as usize] = id;
            }
            Self::Sparse(map) => {
                map.insert(uv, id);
            }
        }
    }
}

/// The median filter over the pre-filter occupancy `cells` (sorted), all three axes.
pub(super) fn fill_holes(cells: &[(CellKey, Acc)]) -> Vec<(CellKey, Acc)> {
    let mut fills: FastMap<CellKey, Acc> = FastMap::default();
    if cells.is_empty() {
        return Vec::new();
    }
    for axis in 0..3 {
        fill_axis(cells, axis, &mut fills);
    }
    let mut out: Vec<(CellKey, Acc)> = fills.into_iter().collect();
    out.sort_unstable_by_key(|c| c.0);
    out
}

/// The 8 neighbour columns, as (u, v) offsets.
const NEIGHBOURS: [[i32; 2]; 8] = [[-1, -1], [0, -1], [1, -1], [-1, 0], [1, 0], [-1, 1], [0, 1], [1, 1]];

pub(super) fn fill_axis(cells: &[(CellKey, Acc)], axis: usize, fills: &mut FastMap<CellKey, Acc>) {
    let (ua, va) = ((axis + 1) % 3, (axis + 2) % 3);
    let uv_of = |k: CellKey| {
        let idx = k.index();
        [idx[ua], idx[va]]
    };
    let mut min = [i64::MAX; 2];
    let mut max = [i64::MIN; 2];
    for (k, _) in cells {
        let uv = uv_of(*k);
        for d in 0..2 {
            min[d] = min[d].min(i64::from(uv[d]));
            max[d] = max[d].max(i64::from(uv[d]));
        }
    }
    let mut lookup = ColumnLookup::new(min, max, cells.len());
    let mut columns: Vec<Column> = Vec::new();
    for (n, (k, _)) in cells.iter().enumerate() {
        let uv = uv_of(*k);
        let s = k.index()[axis];
        if let Some(id) = lookup.get(uv) {
            let c = &mut columns[id as usize];
            if s < c.front_s {
                (c.front, c.front_s) = (n, s);
            }
            if s > c.back_s {
                (c.back, c.back_s) = (n, s);
            }
        } else {
            lookup.insert(uv, columns.len() as u32);
            columns.push(Column { uv, front: n, back: n, front_s: s, back_s: s });
        }
    }

    // A hole has all four edge neighbours occupied, so it is an edge neighbour of some column.
    let mut holes: Vec<[i32; 2]> = Vec::new();
    for c in &columns {
        for o in [[0, -1], [-1, 0], [1, 0], [0, 1]] {
            let uv = [c.uv[0] + o[0], c.uv[1] + o[1]];
            if lookup.get(uv).is_none() {
                holes.push(uv);
            }
        }
    }
    holes.sort_unstable();
    holes.dedup();

    let key_of = |cell: usize| {
        let (k, a) = &cells[cell];
        (i64::from(k.index()[axis]) << POSITION_FRACTION_BITS) + a.mean_offset(axis) as i64
    };
    for uv in holes {
        let mut around = [0usize; 8];
        let mut n = 0;
        let mut edge_neighbours = 0;
        for o in NEIGHBOURS {
            if let Some(id) = lookup.get([uv[0] + o[0], uv[1] + o[1]]) {
                around[n] = id as usize;
                n += 1;
                if o[0] == 0 || o[1] == 0 {
                    edge_neighbours += 1;
                }
            }
        }
        if n < FILL_MIN_NEIGHBOURS || edge_neighbours < 4 {
            continue;
        }
        for back in [false, true] {
            let mut offered = [(0i64, 0usize); 8];
            let mut normal = [0i64; 3];
            for (slot, &id) in offered.iter_mut().zip(&around[..n]) {
                let col = &columns[id];
                let cell = if back { col.back } else { col.front };
                *slot = (key_of(cell), cell);
                for (sum, c) in normal.iter_mut().zip(cells[cell].1.normal) {
                    *sum += c;
                }
            }
            let offered = &mut offered[..n];
            offered.sort_unstable();
            let key = offered[if back { n / 2 } else { (n - 1) / 2 }].0;
            let mut idx = [0i32; 3];
            idx[axis] = (key >> POSITION_FRACTION_BITS) as i32;
            idx[ua] = uv[0];
            idx[va] = uv[1];
            let mut offset = [POS_HALF; 3];
            offset[axis] = (key & POS_MASK) as u64;
            let m = normal.map(|c| c as f64);
            let len = (m[0] * m[0] + m[1] * m[1] + m[2] * m[2]).sqrt();
            let nq = if len > 0.0 { m.map(|c| (c / len * NORMAL_ONE + 0.5).floor() as i64) } else { [0; 3] };
            let a = fills.entry(CellKey::from_index(idx)).or_default();
            for d in 0..3 {
                a.pos[d] += offset[d];
                a.normal[d] += nq[d];
            }
            a.count += 1;
        }
    }
}
