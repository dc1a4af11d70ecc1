//! GPU bake of point levels with `wgpu`: the same 6-direction orthographic slicing as
//! [`super::cpu`], whose module doc is the specification, cell for cell, run as compute passes
//! over many (mesh, level) jobs per submission.
//!
//! # Rasterization in compute, all slices at once
//!
//! The paper renders every slice of every direction into a framebuffer. Here each view axis is
//! rasterized once, with no depth test and no culling, and every fragment is binned into its
//! slice by its own depth: the same sampling as one pass per slice, with one pass per axis
//! (and ±axis views coincide without depth test, see `lod::cpu`). The rasterization runs in a
//! compute shader (`../../shaders/bake/rasterize.wgsl`, one invocation per triangle and axis) rather than in
//! the hardware rasterizer, because:
//! - the CPU reference's coverage rule (canonical edge functions, the top-left tie rule at
//!   pixel centres) is evaluated on the job's own grid coordinates, with no sub-pixel snapping
//!   of vertices as rasterizers do (8 bits on most hardware, lavapipe included), so GPU and CPU
//!   disagree only where f32 and f64 rounding differ on a near-tie;
//! - the framebuffer of a view would be the tile's extent in cells, one render target per job
//!   and axis, while a compute dispatch covers every job of a batch at once;
//! - WebGPU has no point size and no conservative rasterization; compute needs neither.
//!
//! # Passes (one submission per batch)
//!
//! 1. `raster`: fragments → a per-job open-addressing hash table of cells keyed by the packed
//!    cell index, summing in fixed point with atomics (per-axis counts, depth offsets in
//!    cell/2^16, quantized normals in 2^-15): integer sums, so the result does not depend on the order in
//!    which fragments arrive. The invocation that inserts a cell appends its slot to the job's
//!    cell list (in the job's output range), so no later pass scans the whole table.
//! 2. `columns`: per view, each column's front and back slice (before fills), one invocation
//!    per cell-list entry.
//! 3. `fill`: the median hole filler, one invocation per column, looking up its neighbours'
//!    front and back cells in the table by key and adding fills to the table (and to the
//!    cell list).
//! 4. `compact`: every cell-list entry → its point record (cell, count, position and normal
//!    sums), in place.
//! 5. One copy of the counters and all points into one staging buffer, one map (read-back).
//!
//! Each pipeline binds only the buffers it uses, read-only where it only reads: on lavapipe
//! every atomic access is scalarised per lane, plain loads are not.
//!
//! Slots in the table and the append order depend on scheduling; the host sorts each job's
//! points by cell `(k, j, i)` as the CPU does, so two bakes are identical. The host prepares
//! what the CPU reference computes in f64 per vertex or triangle: grid coordinates (relative
//! to the job's base cell, then f32), the smallest-index-first rotation and the quantized
//! triangle normal; validity checks and skip counts are the reference's.
//!
//! # Batching and memory
//!
//! Jobs are packed into batches whose buffers (device buffers and the read-back staging
//! buffer, counted exactly as allocated) stay within the batch budget
//! ([`DEFAULT_BATCH_BUDGET_MIB`], `--gpu-budget-mib`) and the adapter's binding limits. The
//! table and output sizes of a job come from its projected area (fragments ≈ area): a job whose
//! table or output overflows is re-run in a later batch with four times the room, so sizes are
//! an estimate but results never depend on them. A job that alone exceeds the budget, or whose
//! cell box does not fit the 32-bit keys (an extent over 2^16 − 1 cells, or over 2^32 − 2 cells
//! in all), or in which one cell gets over 1023 fragments of one view (the per-axis count
//! fields of the table, see `../../shaders/bake/common.wgsl`), is baked by the CPU reference instead and
//! counted in [`BatchReport::cpu_jobs`].
//! While the GPU runs one batch the host prepares and submits the next and decodes the
//! previous, so at most two batches are in flight: the device memory peak is at most twice the
//! batch budget. The buffers of a read batch are kept (two sets at most, between calls too) and
//! reused by later batches when large enough and at most twice what they need, within the
//! budget; only the accumulating ranges are cleared ([`BatchReport::reused_buffers`]).

use std::sync::mpsc;

use bytemuck::{Pod, Zeroable};
use rayon::prelude::*;
use wgpu::util::DeviceExt;

use super::cpu::{BakeStats, BakedCell, MAX_GRID_COORD, NORMAL_FRACTION_BITS, SliceOptions};
use crate::geom::{Mesh, triangle_normal};
use crate::gpu::{GpuError, open};

/// Default GPU memory budget of one batch, in MiB.
pub const DEFAULT_BATCH_BUDGET_MIB: u64 = 256;

/// WGSL sources, one per pipeline, each prefixed by the shared head (and, for the passes that
/// insert cells, by `insert.wgsl`). Public so the CPU-only validation test can parse and
/// validate them with naga.
pub const SHADERS: [(&str, &str); 4] = [
    (
        "raster",
        concat!(
            include_str!("../../shaders/bake/common.wgsl"),
            include_str!("../../shaders/bake/insert.wgsl"),
            include_str!("../../shaders/bake/rasterize.wgsl")
        ),
    ),
    (
        "columns",
        concat!(
            include_str!("../../shaders/bake/common.wgsl"),
            include_str!("../../shaders/bake/columns.wgsl")
        ),
    ),
    (
        "fill",
        concat!(
            include_str!("../../shaders/bake/common.wgsl"),
            include_str!("../../shaders/bake/insert.wgsl"),
            include_str!("../../shaders/bake/fill_holes.wgsl")
        ),
    ),
    (
        "compact",
        concat!(
            include_str!("../../shaders/bake/common.wgsl"),
            include_str!("../../shaders/bake/compact.wgsl")
        ),
    ),
];

/// How a pipeline binds a buffer.
#[derive(Clone, Copy)]
enum Access {
    Uniform,
    Read,
    ReadWrite,
}

/// The bindings of each pipeline of [`SHADERS`], in order: only what its WGSL declares, read-only
/// where it only reads (plain loads rather than atomics; see `../../shaders/bake/common.wgsl`).
const BINDINGS: [&[(u32, Access)]; 4] = {
    use Access::{Read as R, ReadWrite as W, Uniform as U};
    [
        &[(0, U), (1, R), (2, W), (3, W), (5, R), (6, R), (7, W)],
        &[(0, U), (1, R), (2, R), (3, R), (4, W), (7, R)],
        &[(0, U), (1, R), (2, W), (3, W), (4, R), (7, W)],
        &[(0, U), (1, R), (2, R), (3, R), (7, W)],
    ]
};
/// Storage buffers of the pipeline with the most.
const MAX_STORAGE_BINDINGS: u32 = 6;

const WORKGROUP: u32 = 64;
const MAX_GROUPS_X: u32 = 65_535;
const SLOT_BYTES: u64 = 32;
const POINT_BYTES: u64 = 32;
const COLUMN_BYTES: u64 = 8;
const COUNTER_WORDS: usize = 8;
/// Count word of a slot (`../../shaders/bake/common.wgsl`): per-view-axis counts of `COUNT_BITS` each,
/// `FILL_BIT` on a filled cell.
const COUNT_BITS: u32 = 10;
const COUNT_FIELD: u32 = (1 << COUNT_BITS) - 1;
const FILL_BIT: u32 = 1 << 31;
/// Position offset of a pixel centre, in cell/2^16.
const POS_HALF: u64 = 1 << (super::cpu::POSITION_FRACTION_BITS - 1);
/// Largest job extent on any axis: slices must fit 16 bits in the fill keys.
const MAX_EXTENT: i64 = 65_535;
/// Room multiplier for a job re-run after its table or output overflowed.
const RETRY_GROWTH: u64 = 4;
const POS_ONE: f64 = (1u64 << super::cpu::POSITION_FRACTION_BITS) as f64;

/// One point level to bake: `mesh` on the cubic grid of edge `cell` anchored at `origin`
/// (the arguments of [`super::cpu::bake_cells`]).
#[derive(Debug, Clone, Copy)]
pub struct LevelJob<'a> {
    pub mesh: &'a Mesh,
    pub origin: [f64; 3],
    pub cell: f64,
}

/// What a set of jobs cost.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct BatchReport {
    /// Submissions.
    pub batches: u64,
    /// Jobs baked on the GPU (re-runs not counted twice).
    pub gpu_jobs: u64,
    /// Jobs baked by the CPU reference (alone over the budget, or cell box too large).
    pub cpu_jobs: u64,
    /// Jobs re-run with more room after their table or output overflowed.
    pub retried_jobs: u64,
    /// Largest sum of buffer sizes of one batch, staging buffer included, in bytes.
    pub peak_batch_bytes: u64,
    /// The budget it was held to, in bytes.
    pub budget_bytes: u64,
    /// Batch buffers reused from an earlier batch rather than allocated (seven per batch).
    pub reused_buffers: u64,
}

impl BatchReport {
    /// Adds `other` (peaks take the maximum).
    pub fn merge(&mut self, other: &Self) {
        self.batches += other.batches;
        self.gpu_jobs += other.gpu_jobs;
        self.cpu_jobs += other.cpu_jobs;
        self.retried_jobs += other.retried_jobs;
        self.peak_batch_bytes = self.peak_batch_bytes.max(other.peak_batch_bytes);
        self.budget_bytes = self.budget_bytes.max(other.budget_bytes);
        self.reused_buffers += other.reused_buffers;
    }
}

/// Job descriptor shared with the shaders (`Job` in `../../shaders/bake/common.wgsl`).
#[repr(C)]
#[derive(Debug, Clone, Copy, Default, Pod, Zeroable)]
pub struct GpuJob {
    pub tri_start: u32,
    pub tri_count: u32,
    pub vert_start: u32,
    pub raster_start: u32,
    pub nx: u32,
    pub ny: u32,
    pub nz: u32,
    pub slot_start: u32,
    pub table_mask: u32,
    pub out_start: u32,
    pub out_cap: u32,
    pub col_start: u32,
    pub fill: u32,
    pub pad: [u32; 3],
}

/// Pass sizes shared with the shaders (`Params` in `../../shaders/bake/common.wgsl`).
#[repr(C)]
#[derive(Debug, Clone, Copy, Default, Pod, Zeroable)]
pub struct GpuParams {
    pub n_jobs: u32,
    pub raster_items: u32,
    pub slots: u32,
    pub col_items: u32,
    pub out_items: u32,
    pub pad: [u32; 3],
}

/// The host's part of a job: what the CPU reference computes in f64, ready to upload.
struct Prepared {
    /// Index into the caller's job list.
    job: usize,
    base: [i64; 3],
    dims: [u32; 3],
    /// Local grid coordinates, 3 per mesh vertex.
    verts: Vec<f32>,
    /// 6 words per valid triangle.
    tris: Vec<u32>,
    skipped: usize,
    /// Output room, points.
    out_cap: u64,
    /// Table slots (a power of two).
    table_slots: u64,
}

impl Prepared {
    fn columns(&self, fill: bool) -> u64 {
        if !fill {
            return 0;
        }
        let [x, y, z] = self.dims.map(u64::from);
        y * z + z * x + x * y
    }

    /// Bytes this job adds to a batch: inputs, table, columns, output and its staging copy,
    /// counters and descriptor.
    fn bytes(&self, fill: bool) -> u64 {
        self.verts.len() as u64 * 4
            + self.tris.len() as u64 * 4
            + self.table_slots * SLOT_BYTES
            + self.columns(fill) * COLUMN_BYTES
            + 2 * (self.out_cap * POINT_BYTES + COUNTER_WORDS as u64 * 4)
            + std::mem::size_of::<GpuJob>() as u64
    }

    fn grow(&mut self) {
        self.out_cap *= RETRY_GROWTH;
        self.table_slots = (2 * self.out_cap).next_power_of_two();
    }
}

/// One job's output: what [`super::cpu::bake_cells`] returns.
pub type JobResult = (Vec<BakedCell>, BakeStats);

/// Why a job cannot go to the GPU.
enum Unfit {
    /// No valid triangle: the result is empty.
    Empty(BakeStats),
    /// Cell box too large for the 32-bit keys.
    TooLarge,
}

/// The batch buffers that are kept from batch to batch, in this order: vertices, triangles,
/// counters, table, columns, points, read-back staging (name and usage of each).
const POOLED: [(&str, wgpu::BufferUsages); 7] = {
    use wgpu::BufferUsages as U;
    [
        ("verts", U::STORAGE.union(U::COPY_DST)),
        ("tris", U::STORAGE.union(U::COPY_DST)),
        ("counters", U::STORAGE.union(U::COPY_SRC).union(U::COPY_DST)),
        ("table", U::STORAGE.union(U::COPY_DST)),
        ("columns", U::STORAGE.union(U::COPY_DST)),
        ("points", U::STORAGE.union(U::COPY_SRC).union(U::COPY_DST)),
        ("read-back", U::MAP_READ.union(U::COPY_DST)),
    ]
};
const P_VERTS: usize = 0;
const P_TRIS: usize = 1;
const P_COUNTERS: usize = 2;
const P_TABLE: usize = 3;
const P_COLUMNS: usize = 4;
const P_POINTS: usize = 5;
const P_STAGING: usize = 6;
/// Batches in flight at once (double buffering), and so the buffer sets the pool keeps.
const POOL_SETS: usize = 2;

/// Buffers of one submitted batch, waiting for its read-back.
struct InFlight {
    jobs: Vec<Prepared>,
    /// The pooled buffers (`POOLED` order), back to the pool once read.
    buffers: [wgpu::Buffer; 7],
    /// Bytes of the staging buffer that the batch uses (counters, then points).
    staging_bytes: u64,
    /// How many of `buffers` were reused from the pool.
    reused: u64,
    counters_bytes: u64,
    out_offsets: Vec<u64>,
    mapped: mpsc::Receiver<Result<(), wgpu::BufferAsyncError>>,
    bytes: u64,
}

/// The point-level baker: pipelines on a device and queue passed in.
pub struct GpuBaker {
    device: wgpu::Device,
    queue: wgpu::Queue,
    adapter: String,
    layouts: [wgpu::BindGroupLayout; 4],
    pipelines: [wgpu::ComputePipeline; 4],
    budget: u64,
    max_binding: u64,
    /// Buffer sets of finished batches (at most `POOL_SETS`, kept between calls), reused by
    /// the next ones: a fresh buffer costs a page fault and a zero fill per page on every
    /// batch (on lavapipe about a tenth of the point stage's time), a reused one only the
    /// clear of the range the batch uses.
    pool: std::sync::Mutex<Vec<[wgpu::Buffer; 7]>>,
}

impl GpuBaker {
    /// Builds the four pipelines. `budget_bytes` caps the buffers of one batch; `adapter`
    /// names the adapter in reports.
    pub fn new(
        device: wgpu::Device,
        queue: wgpu::Queue,
        adapter: String,
        budget_bytes: u64,
    ) -> Result<Self, GpuError> {
        let limits = device.limits();
        if limits.max_storage_buffers_per_shader_stage < MAX_STORAGE_BINDINGS {
            return Err(GpuError::Failed(format!(
                "adapter {adapter} allows {} storage buffers per shader stage, the bake needs {MAX_STORAGE_BINDINGS}",
                limits.max_storage_buffers_per_shader_stage
            )));
        }
        let layouts = BINDINGS.map(|bindings| {
            let entries: Vec<wgpu::BindGroupLayoutEntry> = bindings
                .iter()
                .map(|&(binding, access)| wgpu::BindGroupLayoutEntry {
                    binding,
                    visibility: wgpu::ShaderStages::COMPUTE,
                    ty: wgpu::BindingType::Buffer {
                        ty: match access {
                            Access::Uniform => wgpu::BufferBindingType::Uniform,
                            Access::Read => wgpu::BufferBindingType::Storage { read_only: true },
                            Access::ReadWrite => wgpu::BufferBindingType::Storage { read_only: false },
                        },
                        has_dynamic_offset: false,
                        min_binding_size: None,
                    },
                    count: None,
                })
                .collect();
            device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
                label: Some("lod::gpu"),
                entries: &entries,
            })
        });
        let scope = device.push_error_scope(wgpu::ErrorFilter::Validation);
        let mut n = 0;
        let pipelines = SHADERS.map(|(name, source)| {
            let layout = &layouts[n];
            n += 1;
            let pipeline_layout = device.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
                label: Some(name),
                bind_group_layouts: &[Some(layout)],
                immediate_size: 0,
            });
            let module = crate::gpu::shader_module(&device, name, source);
            device.create_compute_pipeline(&wgpu::ComputePipelineDescriptor {
                label: Some(name),
                layout: Some(&pipeline_layout),
                module: &module,
                entry_point: Some("main"),
                compilation_options: wgpu::PipelineCompilationOptions::default(),
                cache: None,
            })
        });
        if let Some(e) = pollster::block_on(scope.pop()) {
            return Err(GpuError::Failed(format!("pipeline creation on {adapter}: {e}")));
        }
        let max_binding = limits.max_storage_buffer_binding_size.min(limits.max_buffer_size);
        Ok(Self {
            device,
            queue,
            adapter,
            layouts,
            pipelines,
            budget: budget_bytes.max(1 << 20),
            max_binding,
            pool: std::sync::Mutex::new(Vec::new()),
        })
    }

    /// Opens the default adapter ([`open`]) and builds a baker on it.
    pub fn open_default(budget_bytes: u64) -> Result<Self, GpuError> {
        let ctx = open()?;
        Self::new(ctx.device, ctx.queue, ctx.adapter, budget_bytes)
    }

    /// The adapter's name, backend and type.
    #[must_use]
    pub fn adapter(&self) -> &str {
        &self.adapter
    }

    /// The batch budget in bytes.
    #[must_use]
    pub fn budget_bytes(&self) -> u64 {
        self.budget
    }

    /// [`super::cpu::bake_cells`] on the GPU: one job, one batch.
    pub fn bake_cells(
        &self,
        mesh: &Mesh,
        origin: [f64; 3],
        cell: f64,
        options: &SliceOptions,
    ) -> Result<(Vec<BakedCell>, BakeStats), GpuError> {
        let (mut out, _) = self.bake_jobs(&[LevelJob { mesh, origin, cell }], options)?;
        out.pop().ok_or_else(|| GpuError::Failed("no result for the job".into()))
    }

    /// Bakes every job, batched under the memory budget; results in job order, each as
    /// [`super::cpu::bake_cells`] returns it.
    pub fn bake_jobs(
        &self,
        jobs: &[LevelJob<'_>],
        options: &SliceOptions,
    ) -> Result<(Vec<JobResult>, BatchReport), GpuError> {
        let fill = options.fill_holes;
        let mut report = BatchReport { budget_bytes: self.budget, ..BatchReport::default() };
        let mut results: Vec<Option<JobResult>> = vec![None; jobs.len()];
        let prepared: Vec<Result<Prepared, Unfit>> =
            jobs.par_iter().enumerate().map(|(n, j)| prepare(n, j)).collect();
        let mut queue: std::collections::VecDeque<Prepared> = std::collections::VecDeque::new();
        let mut cpu: Vec<usize> = Vec::new();
        for (n, p) in prepared.into_iter().enumerate() {
            match p {
                Ok(p) if p.bytes(fill) <= self.budget && self.fits_bindings(&p, fill) => queue.push_back(p),
                Ok(_) | Err(Unfit::TooLarge) => cpu.push(n),
                Err(Unfit::Empty(stats)) => results[n] = Some((Vec::new(), stats)),
            }
        }
        report.gpu_jobs = queue.len() as u64;
        report.cpu_jobs = cpu.len() as u64;

        // Double buffering: submit the next batch before reading back the previous one.
        let mut in_flight: Option<InFlight> = None;
        loop {
            let batch = self.take_batch(&mut queue, fill);
            let submitted = if batch.is_empty() { None } else { Some(self.submit(batch, jobs, fill)?) };
            if let Some(f) = in_flight.take() {
                report.batches += 1;
                report.peak_batch_bytes = report.peak_batch_bytes.max(f.bytes);
                report.reused_buffers += f.reused;
                for (p, r) in self.finish(f, jobs)? {
                    match r {
                        Ok(r) => results[p.job] = Some(r),
                        Err(Redo::Cpu) => {
                            report.cpu_jobs += 1;
                            report.gpu_jobs -= 1;
                            cpu.push(p.job);
                        }
                        Err(Redo::Grow) => {
                            let mut p = p;
                            p.grow();
                            report.retried_jobs += 1;
                            if p.bytes(fill) <= self.budget && self.fits_bindings(&p, fill) {
                                queue.push_back(p);
                            } else {
                                report.cpu_jobs += 1;
                                report.gpu_jobs -= 1;
                                cpu.push(p.job);
                            }
                        }
                    }
                }
            }
            in_flight = submitted;
            if in_flight.is_none() && queue.is_empty() {
                break;
            }
        }
        let cpu_results: Vec<(usize, JobResult)> = cpu
            .par_iter()
            .map(|&n| (n, super::cpu::bake_cells(jobs[n].mesh, jobs[n].origin, jobs[n].cell, options)))
            .collect();
        for (n, r) in cpu_results {
            results[n] = Some(r);
        }
        let results = results
            .into_iter()
            .map(|r| r.ok_or_else(|| GpuError::Failed("a job was left without a result".into())))
            .collect::<Result<_, _>>()?;
        Ok((results, report))
    }

    fn fits_bindings(&self, p: &Prepared, fill: bool) -> bool {
        let m = self.max_binding;
        p.table_slots * SLOT_BYTES <= m
            && p.out_cap * POINT_BYTES <= m
            && p.columns(fill) * COLUMN_BYTES <= m
            && p.verts.len() as u64 * 4 <= m
            && p.tris.len() as u64 * 4 <= m
    }

    /// Takes jobs from the front of `queue` while the batch stays within the budget, the
    /// binding limits and 32-bit item counts.
    fn take_batch(&self, queue: &mut std::collections::VecDeque<Prepared>, fill: bool) -> Vec<Prepared> {
        let mut batch = Vec::new();
        let (mut bytes, mut slots, mut out, mut cols, mut verts, mut tris) =
            (0u64, 0u64, 0u64, 0u64, 0u64, 0u64);
        let limit_items = u64::from(u32::MAX / 2);
        while let Some(p) = queue.front() {
            let nb = bytes + p.bytes(fill);
            let ns = slots + p.table_slots;
            let no = out + p.out_cap;
            let nc = cols + p.columns(fill);
            let nv = verts + p.verts.len() as u64;
            let nt = tris + p.tris.len() as u64;
            let fits = nb <= self.budget
                && ns * SLOT_BYTES <= self.max_binding
                && no * POINT_BYTES <= self.max_binding
                && nc * COLUMN_BYTES <= self.max_binding
                && nv * 4 <= self.max_binding
                && nt * 4 <= self.max_binding
                && ns.max(nc).max(nt / 2) <= limit_items;
            if !fits && !batch.is_empty() {
                break;
            }
            (bytes, slots, out, cols, verts, tris) = (nb, ns, no, nc, nv, nt);
            if let Some(p) = queue.pop_front() {
                batch.push(p);
            }
        }
        batch
    }

    /// Uploads a batch, records the passes and the read-back copy, and submits.
    fn submit(&self, batch: Vec<Prepared>, jobs: &[LevelJob<'_>], fill: bool) -> Result<InFlight, GpuError> {
        let _ = jobs;
        let mut gjobs = Vec::with_capacity(batch.len());
        let mut verts: Vec<f32> = Vec::new();
        let mut tris: Vec<u32> = Vec::new();
        let (mut raster, mut slots, mut out, mut cols) = (0u64, 0u64, 0u64, 0u64);
        let mut out_offsets = Vec::with_capacity(batch.len());
        for p in &batch {
            let tri_count = (p.tris.len() / 6) as u64;
            gjobs.push(GpuJob {
                tri_start: (tris.len() / 6) as u32,
                tri_count: tri_count as u32,
                vert_start: (verts.len() / 3) as u32,
                raster_start: raster as u32,
                nx: p.dims[0],
                ny: p.dims[1],
                nz: p.dims[2],
                slot_start: slots as u32,
                table_mask: (p.table_slots - 1) as u32,
                out_start: out as u32,
                out_cap: p.out_cap as u32,
                col_start: cols as u32,
                fill: u32::from(fill),
                pad: [0; 3],
            });
            out_offsets.push(out);
            verts.extend_from_slice(&p.verts);
            tris.extend_from_slice(&p.tris);
            raster += tri_count * 3;
            slots += p.table_slots;
            out += p.out_cap;
            cols += p.columns(fill);
        }
        let params = GpuParams {
            n_jobs: gjobs.len() as u32,
            raster_items: raster as u32,
            slots: slots as u32,
            col_items: cols as u32,
            out_items: out as u32,
            pad: [0; 3],
        };
        let d = &self.device;
        let scope = d.push_error_scope(wgpu::ErrorFilter::Validation);
        let init = |label: &str, bytes: &[u8], usage: wgpu::BufferUsages| {
            // Bindings may not be empty.
            let padded;
            let contents = if bytes.is_empty() {
                padded = [0u8; 16];
                &padded[..]
            } else {
                bytes
            };
            d.create_buffer_init(&wgpu::util::BufferInitDescriptor { label: Some(label), contents, usage })
        };
        let storage = wgpu::BufferUsages::STORAGE;
        let counters_bytes = (gjobs.len() * COUNTER_WORDS * 4) as u64;
        let out_bytes = out * POINT_BYTES;
        let b_params = init("params", bytemuck::bytes_of(&params), wgpu::BufferUsages::UNIFORM);
        let b_jobs = init("jobs", bytemuck::cast_slice(&gjobs), storage);
        // Sizes the batch uses in each pooled buffer (bindings may not be empty).
        let used = [
            verts.len() as u64 * 4,
            tris.len() as u64 * 4,
            counters_bytes,
            slots * SLOT_BYTES,
            cols * COLUMN_BYTES,
            out_bytes,
            counters_bytes + out_bytes,
        ]
        .map(|b| b.max(16));
        let (pooled, reused) = self.take_buffers(used, b_params.size() + b_jobs.size());
        if !verts.is_empty() {
            self.queue.write_buffer(&pooled[P_VERTS], 0, bytemuck::cast_slice(&verts));
        }
        if !tris.is_empty() {
            self.queue.write_buffer(&pooled[P_TRIS], 0, bytemuck::cast_slice(&tris));
        }
        let bytes = b_params.size() + b_jobs.size() + pooled.iter().map(wgpu::Buffer::size).sum::<u64>();
        let part = |n: usize| {
            wgpu::BindingResource::Buffer(wgpu::BufferBinding {
                buffer: &pooled[n],
                offset: 0,
                size: std::num::NonZeroU64::new(used[n]),
            })
        };
        // Binding order (`common.wgsl`): params, jobs, counters, table, columns, verts, tris,
        // points.
        let resources = [
            b_params.as_entire_binding(),
            b_jobs.as_entire_binding(),
            part(P_COUNTERS),
            part(P_TABLE),
            part(P_COLUMNS),
            part(P_VERTS),
            part(P_TRIS),
            part(P_POINTS),
        ];
        let groups: Vec<wgpu::BindGroup> = BINDINGS
            .iter()
            .zip(&self.layouts)
            .map(|(bindings, layout)| {
                let entries: Vec<wgpu::BindGroupEntry<'_>> = bindings
                    .iter()
                    .map(|&(binding, _)| wgpu::BindGroupEntry {
                        binding,
                        resource: resources[binding as usize].clone(),
                    })
                    .collect();
                d.create_bind_group(&wgpu::BindGroupDescriptor {
                    label: Some("lod::gpu batch"),
                    layout,
                    entries: &entries,
                })
            })
            .collect();
        let mut enc =
            d.create_command_encoder(&wgpu::CommandEncoderDescriptor { label: Some("lod::gpu batch") });
        // What the passes accumulate into starts at zero; the inputs are overwritten above and
        // the points are written before they are read (`compact` fills every listed record).
        for n in [P_COUNTERS, P_TABLE, P_COLUMNS] {
            enc.clear_buffer(&pooled[n], 0, Some(used[n]));
        }
        {
            let mut pass = enc.begin_compute_pass(&wgpu::ComputePassDescriptor {
                label: Some("bake"),
                timestamp_writes: None,
            });
            let mut run = |n: usize, items: u64| {
                if items == 0 {
                    return;
                }
                let wgs = items.div_ceil(u64::from(WORKGROUP));
                let x = wgs.min(u64::from(MAX_GROUPS_X));
                let y = wgs.div_ceil(x);
                pass.set_pipeline(&self.pipelines[n]);
                pass.set_bind_group(0, &groups[n], &[]);
                pass.dispatch_workgroups(x as u32, y as u32, 1);
            };
            // Pipelines in `SHADERS` order: raster, columns, fill, compact. The passes after
            // `raster` run over the cell lists (room `out` in all), not the tables.
            run(0, raster);
            if fill {
                run(1, out);
                run(2, cols);
            }
            run(3, out);
        }
        let staging = &pooled[P_STAGING];
        enc.copy_buffer_to_buffer(&pooled[P_COUNTERS], 0, staging, 0, counters_bytes);
        if out_bytes > 0 {
            enc.copy_buffer_to_buffer(&pooled[P_POINTS], 0, staging, counters_bytes, out_bytes);
        }
        self.queue.submit([enc.finish()]);
        if let Some(e) = pollster::block_on(scope.pop()) {
            return Err(GpuError::Failed(format!("batch submission on {}: {e}", self.adapter)));
        }
        let (tx, rx) = mpsc::channel();
        let staging_bytes = counters_bytes + out_bytes;
        staging.slice(..staging_bytes).map_async(wgpu::MapMode::Read, move |r| {
            let _ = tx.send(r);
        });
        Ok(InFlight {
            jobs: batch,
            buffers: pooled,
            staging_bytes,
            reused,
            counters_bytes,
            out_offsets,
            mapped: rx,
            bytes,
        })
    }

    /// Waits for a batch's read-back and decodes each job.
    fn finish(&self, f: InFlight, jobs: &[LevelJob<'_>]) -> Result<Vec<(Prepared, Decoded)>, GpuError> {
        self.device
            .poll(wgpu::PollType::wait_indefinitely())
            .map_err(|e| GpuError::Failed(format!("waiting for the device: {e}")))?;
        f.mapped
            .recv()
            .map_err(|_| GpuError::Failed("read-back callback dropped".into()))?
            .map_err(|e| GpuError::Failed(format!("read-back: {e}")))?;
        let out = {
            let view = f.buffers[P_STAGING]
                .slice(..f.staging_bytes)
                .get_mapped_range()
                .map_err(|e| GpuError::Failed(format!("read-back mapping: {e}")))?;
            let words: &[u32] = bytemuck::cast_slice(&view);
            let counters = &words[..f.counters_bytes as usize / 4];
            let points = &words[f.counters_bytes as usize / 4..];
            f.jobs
                .into_par_iter()
                .zip(f.out_offsets.par_iter())
                .enumerate()
                .map(|(n, (p, &off))| {
                    let c = &counters[n * COUNTER_WORDS..(n + 1) * COUNTER_WORDS];
                    let r = decode(&p, &jobs[p.job], c, &points[off as usize * 8..]);
                    (p, r)
                })
                .collect()
        };
        f.buffers[P_STAGING].unmap();
        if let Ok(mut pool) = self.pool.lock()
            && pool.len() < POOL_SETS
        {
            pool.push(f.buffers);
        }
        Ok(out)
    }

    /// The pooled buffers for a batch that uses `used` bytes of each (`POOLED` order) and
    /// `other` bytes elsewhere: a kept buffer is reused when it is large enough, at most twice
    /// the size used (so a small batch does not pin a large one) and the batch's total stays
    /// within the budget (or within what the batch needs, for a single job over it); any other
    /// is allocated at the size used. Returns the buffers and how many were reused.
    fn take_buffers(&self, used: [u64; 7], other: u64) -> ([wgpu::Buffer; 7], u64) {
        let kept = self.pool.lock().ok().and_then(|mut p| p.pop());
        let mut kept: [Option<wgpu::Buffer>; 7] = match kept {
            Some(set) => set.map(Some),
            None => Default::default(),
        };
        let needed = other + used.iter().sum::<u64>();
        let limit = self.budget.max(needed);
        let mut total = needed;
        let mut reused = 0;
        let set = std::array::from_fn(|n| {
            if let Some(b) = kept[n].take() {
                let size = b.size();
                if size >= used[n] && size <= 2 * used[n] && total - used[n] + size <= limit {
                    total = total - used[n] + size;
                    reused += 1;
                    return b;
                }
            }
            self.device.create_buffer(&wgpu::BufferDescriptor {
                label: Some(POOLED[n].0),
                size: used[n].next_multiple_of(wgpu::COPY_BUFFER_ALIGNMENT),
                usage: POOLED[n].1,
                mapped_at_creation: false,
            })
        });
        (set, reused)
    }
}

/// Why a job's GPU result was not used.
enum Redo {
    /// Its table or output overflowed: re-run with more room.
    Grow,
    /// A cell's per-axis count filled up: bake it with the CPU reference.
    Cpu,
}

/// A job's GPU result, or why it is not used.
type Decoded = Result<JobResult, Redo>;

/// Turns one job's counters and points into the reference's output.
fn decode(p: &Prepared, job: &LevelJob<'_>, counters: &[u32], points: &[u32]) -> Decoded {
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
            // Per-axis counts and depth sums → the three position sums (`../../shaders/bake/common.wgsl`).
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
fn prepare(n: usize, job: &LevelJob<'_>) -> Result<Prepared, Unfit> {
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
