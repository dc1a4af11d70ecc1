//! The host's share of a job (the module doc's *Rasterization in compute*): grid coordinates and
//! the cell box in f64 as the CPU reference computes them, ready to upload; and decoding a job's
//! read-back counters and points into the reference's output.

use super::{
    BakeStats, BakedCell, COLUMN_BYTES, COUNT_BITS, COUNT_FIELD, COUNTER_WORDS, Decoded, FILL_BIT, GpuJob,
    LevelJob, MAX_EXTENT, MAX_GRID_COORD, NORMAL_FRACTION_BITS, POINT_BYTES, POS_HALF, POS_ONE, Prepared,
    RETRY_GROWTH, Redo, SLOT_BYTES, Unfit, triangle_normal,
};

impl Prepared {
    pub(super) fn columns(&self, fill: bool) -> u64 {
        if !fill {
            return 0;
        }
        let [x, y, z] = self.dims.map(u64::from);
        y * z + z * x + x * y
    }

    /// Bytes this job adds to a batch: inputs, table, columns, output and its staging copy,
    /// counters and descriptor.
    pub(super) fn bytes(&self, fill: bool) -> u64 {
        self.verts.len() as u64 * 4
            + self.tris.len() as u64 * 4
            + self.table_slots * SLOT_BYTES
            + self.columns(fill) * COLUMN_BYTES
            + 2 * (self.out_cap * POINT_BYTES + COUNTER_WORDS as u64 * 4)
            + std::mem::size_of::<GpuJob>() as u64
    }

    pub(super) fn grow(&mut self) {
        self.out_cap *= RETRY_GROWTH;
        self.table_slots = (2 * self.out_cap).next_power_of_two();
    }
}

/// Turns one job's counters and points into the reference's output.
pub(super) fn decode(p: &Prepared, job: &LevelJob<'_>, counters: &[u32], points: &[u32]) -> Decoded {
    let n = u64::from(counters[0]);
    if counters[6] > 0 {
        return Err(Redo::Cpu);
    }
    if n > p.out_cap || counters[5] > 0 {
        return Err(Redo::Grow);
    }
    let recs = &points[..n as usize * 8];
    let filled = recs.chunks_exact(8).filter(|r| r[1] & FILL_BIT != 0).count();
    let stats = BakeStats {
        fragments: [u64::from(counters[2]), u64::from(counters[3]), u64::from(counters[4])],
        occupied: n as usize - filled,
        filled,
        skipped_triangles: p.skipped,
    };
    let mut recs: Vec<&[u32]> = recs.chunks_exact(8).collect();
    recs.sort_unstable_by_key(|r| r[0]);
    let [nx, ny, _] = p.dims;
    let cells = recs
        .iter()
        .map(|r| {
            let key = r[0];
            let local = [key % nx, (key / nx) % ny, key / nx / ny];
            let index = [0, 1, 2].map(|d| (p.base[d] + i64::from(local[d])) as i32);
            // Per-axis counts and depth sums → the three position sums (`shaders/bake/common.wgsl`).
            let counts = [0, 1, 2].map(|d: u32| u64::from((r[1] >> (d * COUNT_BITS)) & COUNT_FIELD));
            let count = counts.iter().sum::<u64>();
            let denom = count.max(1) as f64 * POS_ONE;
            let position = [0, 1, 2].map(|d| {
                let sum = u64::from(r[2 + d]) + POS_HALF * (count - counts[d]);
                job.origin[d] + (f64::from(index[d]) + sum as f64 / denom) * job.cell
            });
            let n = [0, 1, 2].map(|d| f64::from(r[5 + d].cast_signed()));
            let len = (n[0] * n[0] + n[1] * n[1] + n[2] * n[2]).sqrt();
            let normal = if len > 0.0 {
                [(n[0] / len) as f32, (n[1] / len) as f32, (n[2] / len) as f32]
            } else {
                [0.0, 0.0, 1.0]
            };
            BakedCell { index, position, normal, samples: count, filled: r[1] & FILL_BIT != 0 }
        })
        .collect();
    Ok((cells, stats))
}

/// The host's share of a job (see the module doc).
pub(super) fn prepare(n: usize, job: &LevelJob<'_>) -> Result<Prepared, Unfit> {
    let mesh = job.mesh;
    let (origin, cell) = (job.origin, job.cell);
    let all_skipped = BakeStats { skipped_triangles: mesh.triangles.len(), ..BakeStats::default() };
    if !(cell.is_finite() && cell > 0.0) || origin.iter().any(|c| !c.is_finite()) {
        return Err(Unfit::Empty(all_skipped));
    }
    let grid: Vec<Option<[f64; 3]>> = mesh
        .positions
        .iter()
        .map(|p| {
            let g = [0, 1, 2].map(|d| (p[d] - origin[d]) / cell);
            g.iter().all(|c| c.is_finite() && c.abs() <= MAX_GRID_COORD).then_some(g)
        })
        .collect();
    let mut lo = [f64::INFINITY; 3];
    let mut hi = [f64::NEG_INFINITY; 3];
    let mut valid: Vec<([u32; 3], [[f64; 3]; 3])> = Vec::with_capacity(mesh.triangles.len());
    let mut area = 0.0;
    for tri in &mesh.triangles {
        let lead = if tri[0] <= tri[1] && tri[0] <= tri[2] {
            0
        } else if tri[1] <= tri[2] {
            1
        } else {
            2
        };
        let ids = [tri[lead], tri[(lead + 1) % 3], tri[(lead + 2) % 3]];
        let g = |id: u32| grid.get(id as usize).copied().flatten();
        let (Some(a), Some(b), Some(c)) = (g(ids[0]), g(ids[1]), g(ids[2])) else {
            continue;
        };
        for v in [a, b, c] {
            for d in 0..3 {
                lo[d] = lo[d].min(v[d]);
                hi[d] = hi[d].max(v[d]);
            }
        }
        let u = [b[0] - a[0], b[1] - a[1], b[2] - a[2]];
        let v = [c[0] - a[0], c[1] - a[1], c[2] - a[2]];
        area += 0.5
            * ((u[1] * v[2] - u[2] * v[1]).abs()
                + (u[2] * v[0] - u[0] * v[2]).abs()
                + (u[0] * v[1] - u[1] * v[0]).abs());
        valid.push((ids, [a, b, c]));
    }
    let skipped = mesh.triangles.len() - valid.len();
    if valid.is_empty() {
        return Err(Unfit::Empty(all_skipped));
    }
    // One cell of margin below and above the vertices' floor box, as the reference.
    let base = [0, 1, 2].map(|d| lo[d].floor() as i64 - 1);
    let top = [0, 1, 2].map(|d| hi[d].floor() as i64 + 1);
    let ext = [0, 1, 2].map(|d| top[d] - base[d] + 1);
    if ext.iter().any(|&e| e > MAX_EXTENT) || ext.iter().product::<i64>() >= i64::from(u32::MAX) - 1 {
        return Err(Unfit::TooLarge);
    }
    let mut verts = vec![0f32; mesh.positions.len() * 3];
    for (k, g) in grid.iter().enumerate() {
        if let Some(g) = g {
            for d in 0..3 {
                verts[k * 3 + d] = (g[d] - base[d] as f64) as f32;
            }
        }
    }
    let normal_one = f64::from(1u32 << NORMAL_FRACTION_BITS);
    let limit = f64::from((1u32 << NORMAL_FRACTION_BITS) - 1);
    let mut tris = Vec::with_capacity(valid.len() * 6);
    for (ids, _) in &valid {
        let w = ids.map(|i| mesh.positions[i as usize]);
        let nrm = triangle_normal(w[0], w[1], w[2]);
        tris.extend_from_slice(ids);
        for c in nrm {
            tris.push(((c * normal_one + 0.5).floor().clamp(-limit, limit) as i32).cast_unsigned());
        }
    }
    // Fragments ≈ the projected area; occupied cells ≤ fragments. Overflow re-runs the job.
    let out_cap = (area * 1.25) as u64 + 256;
    Ok(Prepared {
        job: n,
        base,
        dims: ext.map(|e| e as u32),
        verts,
        tris,
        skipped,
        out_cap,
        table_slots: (2 * out_cap).next_power_of_two(),
    })
}
