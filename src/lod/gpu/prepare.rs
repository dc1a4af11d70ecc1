//! The host's share (the module doc's *Passes*): once per mesh, what the CPU reference computes
//! in f64 per triangle (validity, the smallest-index-first rotation, the quantized normal, the
//! vertices' box and projected area), ready to upload; once per job, the cell box and the grid
//! coordinates of the vertices (f64, then f32, as the reference specifies); and turning a job's read-back points,
//! already decoded and in their final order on the device, into the reference's output.

use super::{
    BakeStats, COLUMN_BYTES, COUNTER_WORDS, GpuJob, JobOutput, LIST_BYTES, LevelJob, MAX_EXTENT,
    MAX_GRID_COORD, NORMAL_FRACTION_BITS, POINT_BYTES, PointDecode, Prepared, RETRY_GROWTH, Redo, SCAN_BLOCK,
    SLOT_BYTES, Unfit,
};
use crate::geom::Mesh;
use glam::DVec3;

/// `x.floor()` for |x| < 2^31, without the libm call (x86-64's baseline has no `roundsd`):
/// exact, as truncation to an integer of that range is.
fn floor_small(x: f64) -> i32 {
    let t = x as i32;
    if f64::from(t) > x { t - 1 } else { t }
}

/// A mesh ready to upload, shared by its level jobs.
pub(super) struct MeshPrep {
    /// Vertices of the mesh.
    pub vertices: u64,
    /// 6 words per valid triangle (vertex indices in range, positions finite): the rotated
    /// indices and the quantized normal.
    pub tris: Vec<u32>,
    /// Triangles of the mesh.
    pub triangles: usize,
    /// The valid triangles' vertices' box, world coordinates.
    pub lo: [f64; 3],
    pub hi: [f64; 3],
    /// Sum over valid triangles of half their absolute normal components (world units²): the
    /// projected area of the three views, fragments ≈ area / cell².
    pub area: f64,
}

impl MeshPrep {
    /// Bytes the mesh adds to a batch that holds any of its jobs.
    pub(super) fn bytes(&self) -> u64 {
        self.tris.len() as u64 * 4
    }
}

impl Prepared {
    pub(super) fn columns(&self, fill: bool) -> u64 {
        if !fill {
            return 0;
        }
        let [x, y, z] = self.dims.map(u64::from);
        y * z + z * x + x * y
    }

    /// Rows of the job's box, one per (k, j).
    pub(super) fn rows(&self) -> u64 {
        u64::from(self.dims[1]) * u64::from(self.dims[2])
    }

    /// Bitmap words per row.
    pub(super) fn row_words(&self) -> u64 {
        u64::from(self.dims[0]).div_ceil(32)
    }

    /// Words of the scan buffer the job accounts for: its rows and, generously, its share of
    /// the upper levels.
    pub(super) fn scan_words(&self) -> u64 {
        self.rows() + self.rows() / (SCAN_BLOCK / 2) + 8
    }

    /// Bytes this job adds to a batch besides its mesh: vertices' grid coordinates, table,
    /// columns, cell list, bitmap, scan, output and its read-back, counters and descriptor.
    pub(super) fn bytes(&self, vertices: u64, fill: bool) -> u64 {
        vertices * 12
            + self.table_slots * SLOT_BYTES
            + self.columns(fill) * COLUMN_BYTES
            + self.out_cap * LIST_BYTES
            + (self.rows() * self.row_words() + self.scan_words()) * 4
            + 2 * (self.out_cap * POINT_BYTES + COUNTER_WORDS as u64 * 4)
            + std::mem::size_of::<GpuJob>() as u64
    }

    pub(super) fn grow(&mut self) {
        self.out_cap *= RETRY_GROWTH;
        self.table_slots = (2 * self.out_cap).next_power_of_two();
    }
}

/// Whether the job's result is usable, and its statistics: from its counters.
pub(super) fn check(p: &Prepared, counters: &[u32]) -> Result<BakeStats, Redo> {
    let n = u64::from(counters[0]);
    if counters[6] > 0 {
        return Err(Redo::Cpu);
    }
    if n > p.out_cap || counters[5] > 0 {
        return Err(Redo::Grow);
    }
    let filled = counters[1] as usize;
    Ok(BakeStats {
        fragments: [u64::from(counters[2]), u64::from(counters[3]), u64::from(counters[4])],
        occupied: n as usize - filled,
        filled,
        skipped_triangles: p.skipped,
    })
}

/// One job's points, decoded and ordered on the device (`shaders/bake/place.wgsl`), as `O`.
pub(super) fn convert<O: JobOutput>(
    p: &Prepared,
    job: &LevelJob<'_>,
    stats: BakeStats,
    points: &[u32],
) -> (O, BakeStats) {
    let d = PointDecode {
        base: p.base.map(|b| b as i32),
        basef: p.base.map(|b| b as f64),
        origin: job.origin,
        cell: job.cell,
    };
    (O::decode(&d, points), stats)
}

/// The per-mesh share (see the module doc).
pub(super) fn prepare_mesh(mesh: &Mesh) -> MeshPrep {
    let finite: Vec<bool> =
        mesh.positions.iter().map(|p| p[0].is_finite() && p[1].is_finite() && p[2].is_finite()).collect();
    let ok = |id: u32| finite.get(id as usize).copied().unwrap_or(false);
    let mut lo = DVec3::INFINITY;
    let mut hi = DVec3::NEG_INFINITY;
    let mut area = 0.0;
    let normal_one = f64::from(1u32 << NORMAL_FRACTION_BITS);
    let limit = f64::from((1u32 << NORMAL_FRACTION_BITS) - 1);
    let mut tris = Vec::with_capacity(mesh.triangles.len() * 6);
    for tri in &mesh.triangles {
        if !(ok(tri[0]) && ok(tri[1]) && ok(tri[2])) {
            continue;
        }
        let lead = if tri[0] <= tri[1] && tri[0] <= tri[2] {
            0
        } else if tri[1] <= tri[2] {
            1
        } else {
            2
        };
        let ids = [tri[lead], tri[(lead + 1) % 3], tri[(lead + 2) % 3]];
        let [a, b, c] = ids.map(|i| DVec3::from_array(mesh.positions[i as usize]));
        lo = lo.min(a).min(b).min(c);
        hi = hi.max(a).max(b).max(c);
        // `triangle_normal`'s cross product, once for the normal and the projected areas.
        let n = (b - a).cross(c - a);
        area += 0.5 * (n.x.abs() + n.y.abs() + n.z.abs());
        let len = n.length();
        let unit = if len > 0.0 { n / len } else { DVec3::ZERO };
        let q = |c: f64| {
            floor_small((c * normal_one + 0.5).clamp(-limit, limit + 1.0)).min(limit as i32).cast_unsigned()
        };
        tris.extend_from_slice(&[ids[0], ids[1], ids[2], q(unit.x), q(unit.y), q(unit.z)]);
    }
    let (lo, hi) = (lo.to_array(), hi.to_array());
    MeshPrep { vertices: mesh.positions.len() as u64, tris, triangles: mesh.triangles.len(), lo, hi, area }
}

/// The per-job share (see the module doc): the reference's cell box, from the mesh's box (the
/// grid map is monotonic, so the box of the grid coordinates is the map of the box), and the
/// vertices' grid coordinates. A job whose box leaves the reference's grid range would skip triangles the
/// mesh's preparation kept: the reference bakes it (`TooLarge`).
pub(super) fn prepare_job(
    n: usize,
    job: &LevelJob<'_>,
    mesh: usize,
    m: &MeshPrep,
) -> Result<Prepared, Unfit> {
    let (origin, cell) = (job.origin, job.cell);
    let all_skipped = BakeStats { skipped_triangles: m.triangles, ..BakeStats::default() };
    if !(cell.is_finite() && cell > 0.0) || origin.iter().any(|c| !c.is_finite()) || m.tris.is_empty() {
        return Err(Unfit::Empty(all_skipped));
    }
    let glo = [0, 1, 2].map(|d| (m.lo[d] - origin[d]) / cell);
    let ghi = [0, 1, 2].map(|d| (m.hi[d] - origin[d]) / cell);
    if glo.iter().chain(&ghi).any(|g| !(g.is_finite() && g.abs() <= MAX_GRID_COORD)) {
        return Err(Unfit::TooLarge);
    }
    // One cell of margin below and above the vertices' floor box, as the reference.
    let base = [0, 1, 2].map(|d| glo[d].floor() as i64 - 1);
    let top = [0, 1, 2].map(|d| ghi[d].floor() as i64 + 1);
    let ext = [0, 1, 2].map(|d| top[d] - base[d] + 1);
    if ext.iter().any(|&e| e > MAX_EXTENT) || ext.iter().product::<i64>() >= i64::from(u32::MAX) - 1 {
        return Err(Unfit::TooLarge);
    }
    // Fragments ≈ the projected area; occupied cells ≤ fragments. Overflow re-runs the job.
    let out_cap = (m.area / (cell * cell) * 1.25) as u64 + 256;
    let mut verts = Vec::with_capacity(job.mesh.positions.len() * 3);
    let basef = base.map(|b| b as f64);
    for p in &job.mesh.positions {
        let g = [(p[0] - origin[0]) / cell, (p[1] - origin[1]) / cell, (p[2] - origin[2]) / cell];
        let ok = |c: f64| c.is_finite() && c.abs() <= MAX_GRID_COORD;
        if ok(g[0]) && ok(g[1]) && ok(g[2]) {
            verts.extend_from_slice(&[
                (g[0] - basef[0]) as f32,
                (g[1] - basef[1]) as f32,
                (g[2] - basef[2]) as f32,
            ]);
        } else {
            verts.extend_from_slice(&[0.0; 3]);
        }
    }
    Ok(Prepared {
        job: n,
        mesh,
        base,
        dims: ext.map(|e| e as u32),
        verts,
        skipped: m.triangles - m.tris.len() / 6,
        out_cap,
        table_slots: (2 * out_cap).next_power_of_two(),
    })
}
