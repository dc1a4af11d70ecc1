//! GPU bake of point levels with `wgpu`: the same 6-direction orthographic slicing as
//! [`super::cpu`], whose module doc is the specification, cell for cell, run as compute passes
//! over many (mesh, level) jobs per submission, with the points sorted and decoded on the device.
//!
//! # Rasterization in compute, all slices at once
//!
//! The paper renders every slice of every direction into a framebuffer. Here each view axis is
//! rasterized once, with no depth test and no culling, and every fragment is binned into its
//! slice by its own depth: the same sampling as one pass per slice, with one pass per axis
//! (and ±axis views coincide without depth test, see `lod::cpu`). The rasterization runs in a
//! compute shader (`shaders/bake/rasterize.wgsl`, one invocation per triangle and axis) rather than in
//! the hardware rasterizer, because:
//! - the CPU reference's coverage rule (canonical edge functions, the top-left tie rule at
//!   pixel centres) is evaluated on the job's own grid coordinates, with no sub-pixel snapping
//!   of vertices as rasterizers do (8 bits on most hardware, lavapipe included), so GPU and CPU
//!   disagree only where f32 and f64 rounding differ on a near-tie;
//! - the framebuffer of a view would be the tile's extent in cells, one render target per job
//!   and axis, while a compute dispatch covers every job of a batch at once;
//! - WebGPU has no point size and no conservative rasterization; compute needs neither.
//!
//! # Passes (two submissions per batch; the host works per mesh, job and batch, not per point)
//!
//! The host prepares each distinct mesh of a call once (`prepare.rs`): what the CPU reference
//! computes in f64 per triangle (validity, the smallest-index-first rotation, the quantized
//! normal, and the vertices' box and projected area). Per job it computes only the cell box
//! (from the mesh's box: the grid map is monotonic) and the vertices' grid coordinates (f64,
//! relative to the job's base cell, then f32, as the reference specifies; computing them on
//! the device from f32 positions changed near-tie coverage enough to move measured errors).
//! A mesh's triangles are uploaded once per batch and shared by its levels; jobs of one mesh
//! are adjacent in the queue, so its levels mostly share a batch. One submission records:
//!
//! 1. `raster`: fragments → a per-job open-addressing hash table of cells keyed by the packed
//!    cell index, summing in fixed point with atomics (per-axis counts, depth offsets in
//!    cell/2^16, quantized normals in 2^-15): integer sums, so the result does not depend on
//!    the order in which fragments arrive. The invocation that inserts a cell appends its slot
//!    to the job's cell list and sets the cell's bit in the job's bitmap (one bit per cell of
//!    the job's box, rows of `i` per `(k, j)`), so no later pass scans the whole table.
//! 2. `columns`: per view, each column's front and back slice (before fills), one invocation
//!    per cell-list entry.
//! 3. `fill`: the median hole filler, one invocation per column, looking up its neighbours'
//!    front and back cells in the table by key and adding fills to the table (and to the
//!    cell list and bitmap).
//! 4. `scan_rows`, `scan`, `scan_add`: a batch-wide exclusive prefix sum of the cells per row
//!    (a row's count is the popcount of its bitmap words; rows job after job), in blocks of 256
//!    per workgroup, level after level (two or three levels for any batch within the budget).
//! 5. `place`: every cell-list entry → its point, decoded (local cell, samples, fill flag,
//!    position in fixed point cell/2^16 from the job's base corner, rounded to nearest in
//!    integer arithmetic, and the f32 unit normal), written at its rank: its row's prefix plus
//!    the bits before it in its row. Ranks follow `(job, k, j, i)`, the reference's order, and
//!    do not depend on scheduling: the batch's points come out packed, job after job, sorted.
//! 6. A copy of the counters into the read-back buffer.
//!
//! The host maps the counters (each job's list length, overflows, fragment and fill counts),
//! checks each job, then submits one copy of exactly the batch's points and maps them: no
//! room, no table, nothing per cell but the points themselves (32 bytes each). Turning a
//! point into the caller's [`PointCloud`] (or, for parity checks, [`BakedCell`]) is an integer
//! add and a multiply-add per axis (the f64 grid of the job): no sort, no division, no square
//! root on the host, and no intermediate copy. Positions differ
//! from the reference's by at most 2^-17 cell (the fixed-point rounding), normals by the f32
//! normalisation; the bars are ≥ 99.5 % of cells agreeing and 1/1000 cell.
//!
//! Each pipeline binds only the buffers it uses, read-only where it only reads: on lavapipe
//! every atomic access is scalarised per lane, plain loads are not.
//!
//! [`BatchReport`] counts what the host did: seconds by phase (prepare, upload and encoding,
//! submission, wait, mapping, conversion), bytes uploaded and read back, submissions,
//! dispatches and points; `examples/lod_throughput.rs` prints them per million points.
//!
//! # Batching and memory
//!
//! Jobs are packed into batches whose buffers (device buffers and the read-back staging
//! buffer, counted exactly as allocated) stay within the batch budget
//! ([`DEFAULT_BATCH_BUDGET_MIB`], `--gpu-budget-mib`) and the adapter's binding limits, except
//! the triangles: a batch's triangles (24 bytes each) need only fit the adapter's largest
//! buffer, and when they exceed its largest storage binding (128 MiB on lavapipe, and WebGPU's
//! default: 5.6 M triangles) the raster pass runs once per window of triangles that fits, each
//! dispatch binding its window (the other items return at once), so a dense model of tens of
//! millions of triangles stays on the GPU. The table and output sizes of a job come from its projected area (fragments ≈ area): a job whose
//! table or output overflows is re-run in a later batch with four times the room, so sizes are
//! an estimate but results never depend on them. A job that alone exceeds the budget, or whose
//! cell box does not fit the 32-bit keys (an extent over 2^16 − 1 cells, or over 2^32 − 2 cells
//! in all), or in which one cell gets over 1023 fragments of one view (the per-axis count
//! fields of the table, see `shaders/bake/common.wgsl`), or whose mesh's box reaches past the
//! reference's grid range ([`super::cpu::MAX_GRID_COORD`]) at that level (the reference then
//! decides which triangles to skip), is baked by the CPU reference instead and counted in
//! [`BatchReport::cpu_jobs`].
//! While the GPU runs one batch the host submits the next and reads back the previous, so at
//! most two batches are in flight: the device memory peak is at most twice the
//! batch budget. The buffers of a read batch are kept (two sets at most, between calls too) and
//! reused by later batches when large enough and at most twice what they need, within the
//! budget; only the accumulating ranges (counters, table, columns, bitmap) are cleared
//! ([`BatchReport::reused_buffers`]). A job's device memory includes its bitmap, one bit per
//! cell of its box: a job whose box is large and sparse can exceed the budget alone and then
//! goes to the CPU reference.

use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::mpsc;
use std::time::Instant;

use bytemuck::{Pod, Zeroable};
use rayon::prelude::*;

mod batch;
mod prepare;

use prepare::{MeshPrep, prepare_job, prepare_mesh};

use super::cpu::{BakeStats, BakedCell, MAX_GRID_COORD, NORMAL_FRACTION_BITS, SliceOptions};
use crate::geom::{Mesh, PointCloud};
use crate::gpu::{GpuError, open};

/// Default GPU memory budget of one batch, in MiB.
pub const DEFAULT_BATCH_BUDGET_MIB: u64 = 256;

/// WGSL sources, one per pipeline, prefixed by the shared head where they use jobs (and, for
/// the passes that insert cells, by `insert.wgsl`; for the block scans, by `scan_block.wgsl`). Public so the CPU-only validation test can parse and
/// validate them with naga.
pub const SHADERS: [(&str, &str); 7] = [
    (
        "raster",
        concat!(
            include_str!("../../../shaders/bake/common.wgsl"),
            include_str!("../../../shaders/bake/insert.wgsl"),
            include_str!("../../../shaders/bake/rasterize.wgsl")
        ),
    ),
    (
        "columns",
        concat!(
            include_str!("../../../shaders/bake/common.wgsl"),
            include_str!("../../../shaders/bake/columns.wgsl")
        ),
    ),
    (
        "fill",
        concat!(
            include_str!("../../../shaders/bake/common.wgsl"),
            include_str!("../../../shaders/bake/insert.wgsl"),
            include_str!("../../../shaders/bake/fill_holes.wgsl")
        ),
    ),
    (
        "scan_rows",
        concat!(
            include_str!("../../../shaders/bake/common.wgsl"),
            include_str!("../../../shaders/bake/scan_block.wgsl"),
            include_str!("../../../shaders/bake/scan_rows.wgsl")
        ),
    ),
    (
        "scan",
        concat!(
            include_str!("../../../shaders/bake/scan_block.wgsl"),
            include_str!("../../../shaders/bake/scan.wgsl")
        ),
    ),
    ("scan_add", include_str!("../../../shaders/bake/scan_add.wgsl")),
    (
        "place",
        concat!(
            include_str!("../../../shaders/bake/common.wgsl"),
            include_str!("../../../shaders/bake/place.wgsl")
        ),
    ),
];
/// Indices of the pipelines in [`SHADERS`].
const RASTER: usize = 0;
const COLUMNS: usize = 1;
const FILL: usize = 2;
const SCAN_ROWS: usize = 3;
const SCAN: usize = 4;
const SCAN_ADD: usize = 5;
const PLACE: usize = 6;

/// How a pipeline binds a buffer.
#[derive(Clone, Copy)]
enum Access {
    Uniform,
    /// A uniform at a dynamic offset (the scan level, the raster's triangle window).
    Level,
    Read,
    ReadWrite,
}

/// The bindings of each pipeline of [`SHADERS`], in order: only what its WGSL declares, read-only
/// where it only reads (plain loads rather than atomics; see `shaders/bake/common.wgsl`).
const BINDINGS: [&[(u32, Access)]; 7] = {
    use Access::{Level as L, Read as R, ReadWrite as W, Uniform as U};
    [
        &[(0, U), (1, R), (2, W), (3, W), (5, R), (6, R), (7, W), (8, W), (11, L)],
        &[(0, U), (1, R), (2, R), (3, R), (4, W), (7, R)],
        &[(0, U), (1, R), (2, W), (3, W), (4, R), (7, W), (8, W)],
        &[(0, U), (1, R), (8, R), (9, W), (11, L)],
        &[(9, W), (11, L)],
        &[(9, W), (11, L)],
        &[(0, U), (1, R), (2, R), (3, R), (7, R), (8, R), (9, R), (10, W)],
    ]
};
/// Storage buffers of the pipeline with the most.
const MAX_STORAGE_BINDINGS: u32 = 7;

const WORKGROUP: u32 = 64;
/// Workgroup size and block of the scan pipelines (`shaders/bake/scan_block.wgsl`).
const SCAN_BLOCK: u64 = 256;
/// Stride of the scan levels in their uniform buffer (the largest offset alignment WebGPU allows).
const LEVEL_STRIDE: u64 = 256;
const MAX_GROUPS_X: u32 = 65_535;
const SLOT_BYTES: u64 = 32;
/// An output point (`shaders/bake/place.wgsl`), on the device and read back.
const POINT_BYTES: u64 = 32;
/// A cell-list entry (a table slot).
const LIST_BYTES: u64 = 4;
const COLUMN_BYTES: u64 = 8;
const COUNTER_WORDS: usize = 8;
/// Bytes of a batch outside its jobs: parameters and scan levels.
const BATCH_OVERHEAD: u64 = 4096;
/// Flag of a filled cell in a slot's count word and an output point's second word
/// (`shaders/bake/common.wgsl`, `place.wgsl`).
const FILL_BIT: u32 = 1 << 31;
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
    /// Batch buffers reused from an earlier batch rather than allocated (ten per batch).
    pub reused_buffers: u64,
    /// Host seconds by phase, summed over the threads that ran it (wall time inside the phase,
    /// so on a busy machine it includes time the thread waited for a core). `prepare`: meshes
    /// (once per mesh and call) and jobs; `upload`: job tables, buffer writes, bind groups and
    /// command encoding; `submit`: `queue.submit` and the map requests; `wait`: blocked on the
    /// device; `map`: mapping and unmapping the read-back; `convert`: read-back points to the
    /// caller's cells (an affine map per point: no sort, no division).
    pub prepare_s: f64,
    pub upload_s: f64,
    pub submit_s: f64,
    pub wait_s: f64,
    pub map_s: f64,
    pub convert_s: f64,
    /// Bytes written to the device (buffer writes and initialised buffers).
    pub bytes_uploaded: u64,
    /// Bytes mapped and read back.
    pub bytes_read_back: u64,
    /// Queue submissions (two per batch: the passes, then the copy of exactly the points).
    pub submissions: u64,
    /// Compute dispatches.
    pub dispatches: u64,
    /// Points read back from the GPU.
    pub points: u64,
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
        self.prepare_s += other.prepare_s;
        self.upload_s += other.upload_s;
        self.submit_s += other.submit_s;
        self.wait_s += other.wait_s;
        self.map_s += other.map_s;
        self.convert_s += other.convert_s;
        self.bytes_uploaded += other.bytes_uploaded;
        self.bytes_read_back += other.bytes_read_back;
        self.submissions += other.submissions;
        self.dispatches += other.dispatches;
        self.points += other.points;
    }

    /// Host seconds outside the wait, all phases.
    #[must_use]
    pub fn host_s(&self) -> f64 {
        self.prepare_s + self.upload_s + self.submit_s + self.map_s + self.convert_s
    }
}

/// Job descriptor shared with the shaders (`Job` in `shaders/bake/common.wgsl`).
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
    pub row_start: u32,
    pub bit_start: u32,
    pub row_words: u32,
}

/// Pass sizes shared with the shaders (`Params` in `shaders/bake/common.wgsl`).
#[repr(C)]
#[derive(Debug, Clone, Copy, Default, Pod, Zeroable)]
pub struct GpuParams {
    pub n_jobs: u32,
    pub raster_items: u32,
    pub slots: u32,
    pub col_items: u32,
    pub out_items: u32,
    pub rows: u32,
    pub pad: [u32; 2],
}

/// One level of the prefix sum (`Level` in `shaders/bake/scan.wgsl`).
#[repr(C)]
#[derive(Debug, Clone, Copy, Default, Pod, Zeroable)]
pub struct GpuLevel {
    pub src: u32,
    pub count: u32,
    pub dst: u32,
    pub pad: u32,
}

/// One job's output in the reference's form: what [`super::cpu::bake_cells`] returns.
pub type JobResult = (Vec<BakedCell>, BakeStats);

/// What a job's points are returned as: the reference's cells ([`BakedCell`], in the order
/// and form [`super::cpu::bake_cells`] gives them, which parity tests compare) or a
/// [`PointCloud`], the bake's own output, written straight from the read-back (36 bytes a
/// point, no 64-byte cell between).
pub trait JobOutput: Sized + Send + sealed::Sealed {
    /// A job's read-back points (8 words each, see `shaders/bake/place.wgsl`).
    #[doc(hidden)]
    fn decode(d: &PointDecode, points: &[u32]) -> Self;
    /// A job baked by the CPU reference.
    #[doc(hidden)]
    fn from_cells(cells: Vec<BakedCell>) -> Self;
}

mod sealed {
    pub trait Sealed {}
    impl Sealed for Vec<super::BakedCell> {}
    impl Sealed for crate::geom::PointCloud {}
}

/// A job's grid, to turn its read-back points into world positions: the local cell and the
/// fixed-point position move to the job's grid (an integer add and a multiply-add per axis).
#[doc(hidden)]
pub struct PointDecode {
    base: [i32; 3],
    basef: [f64; 3],
    origin: [f64; 3],
    cell: f64,
}

impl PointDecode {
    #[inline]
    fn position(&self, r: &[u32]) -> [f64; 3] {
        let scale = 1.0 / POS_ONE;
        let (o, b, cell) = (self.origin, self.basef, self.cell);
        [
            o[0] + (b[0] + f64::from(r[2]) * scale) * cell,
            o[1] + (b[1] + f64::from(r[3]) * scale) * cell,
            o[2] + (b[2] + f64::from(r[4]) * scale) * cell,
        ]
    }
}

#[inline]
fn point_normal(r: &[u32]) -> [f32; 3] {
    [f32::from_bits(r[5]), f32::from_bits(r[6]), f32::from_bits(r[7])]
}

impl JobOutput for Vec<BakedCell> {
    fn decode(d: &PointDecode, points: &[u32]) -> Self {
        let base = d.base;
        points
            .chunks_exact(8)
            .map(|r| BakedCell {
                index: [
                    base[0] + (r[0] & 0xffff) as i32,
                    base[1] + (r[0] >> 16) as i32,
                    base[2] + (r[1] & 0xffff) as i32,
                ],
                position: d.position(r),
                normal: point_normal(r),
                samples: u64::from((r[1] & !FILL_BIT) >> 16),
                filled: r[1] & FILL_BIT != 0,
            })
            .collect()
    }

    fn from_cells(cells: Vec<BakedCell>) -> Self {
        cells
    }
}

impl JobOutput for PointCloud {
    fn decode(d: &PointDecode, points: &[u32]) -> Self {
        let n = points.len() / 8;
        let mut positions = Vec::with_capacity(n);
        let mut normals = Vec::with_capacity(n);
        for r in points.chunks_exact(8) {
            positions.push(d.position(r));
            normals.push(point_normal(r));
        }
        Self { positions, normals }
    }

    fn from_cells(cells: Vec<BakedCell>) -> Self {
        Self {
            positions: cells.iter().map(|c| c.position).collect(),
            normals: cells.iter().map(|c| c.normal).collect(),
        }
    }
}

/// Why a job cannot go to the GPU.
enum Unfit {
    /// No valid triangle: the result is empty.
    Empty(BakeStats),
    /// Cell box too large for the 32-bit keys, or a vertex beyond the reference's grid range.
    TooLarge,
}

/// The batch buffers that are kept from batch to batch, in this order (name and usage of each).
const POOLED: [(&str, wgpu::BufferUsages); 10] = {
    use wgpu::BufferUsages as U;
    [
        ("tris", U::STORAGE.union(U::COPY_DST)),
        ("verts", U::STORAGE.union(U::COPY_DST)),
        ("counters", U::STORAGE.union(U::COPY_SRC).union(U::COPY_DST)),
        ("table", U::STORAGE.union(U::COPY_DST)),
        ("columns", U::STORAGE.union(U::COPY_DST)),
        ("list", U::STORAGE),
        ("bitmap", U::STORAGE.union(U::COPY_DST)),
        ("scan", U::STORAGE),
        ("out", U::STORAGE.union(U::COPY_SRC)),
        ("read-back", U::MAP_READ.union(U::COPY_DST)),
    ]
};
const N_POOLED: usize = POOLED.len();
const P_TRIS: usize = 0;
const P_VERTS: usize = 1;
const P_COUNTERS: usize = 2;
const P_TABLE: usize = 3;
const P_COLUMNS: usize = 4;
const P_LIST: usize = 5;
const P_BITMAP: usize = 6;
const P_SCAN: usize = 7;
const P_OUT: usize = 8;
const P_STAGING: usize = 9;
/// Batches in flight at once (double buffering), and so the buffer sets the pool keeps.
const POOL_SETS: usize = 2;

/// Buffers of one submitted batch, waiting for its read-back.
struct InFlight {
    jobs: Vec<Prepared>,
    /// The pooled buffers (`POOLED` order), back to the pool once read.
    buffers: [wgpu::Buffer; N_POOLED],
    /// How many of `buffers` were reused from the pool.
    reused: u64,
    counters_bytes: u64,
    /// The counters' read-back (mapped at the start of the staging buffer).
    mapped: mpsc::Receiver<Result<(), wgpu::BufferAsyncError>>,
    bytes: u64,
}

/// The point-level baker: pipelines on a device and queue passed in.
pub struct GpuBaker {
    device: wgpu::Device,
    queue: wgpu::Queue,
    adapter: String,
    layouts: [wgpu::BindGroupLayout; 7],
    pipelines: [wgpu::ComputePipeline; 7],
    budget: u64,
    max_binding: u64,
    /// The adapter's largest buffer: a batch's triangles may exceed `max_binding` (they are
    /// then bound in windows), not this.
    max_buffer: u64,
    /// Bytes of the raster's triangle windows: `max_binding` unless a test sets it lower.
    tri_window_bytes: u64,
    /// Buffer sets of finished batches (at most `POOL_SETS`, kept between calls), reused by
    /// the next ones: a fresh buffer costs a page fault and a zero fill per page on every
    /// batch (on lavapipe about a tenth of the point stage's time), a reused one only the
    /// clear of the range the batch uses.
    pool: std::sync::Mutex<Vec<[wgpu::Buffer; N_POOLED]>>,
}

impl GpuBaker {
    /// Builds the pipelines. `budget_bytes` caps the buffers of one batch; `adapter`
    /// names the adapter in reports.
    pub fn new(
        device: wgpu::Device,
        queue: wgpu::Queue,
        adapter: String,
        budget_bytes: u64,
    ) -> Result<Self, GpuError> {
        let limits = device.limits();
        if limits.max_storage_buffers_per_shader_stage < MAX_STORAGE_BINDINGS {
            return Err(GpuError::StorageBindings {
                adapter,
                got: limits.max_storage_buffers_per_shader_stage,
                needed: MAX_STORAGE_BINDINGS,
            });
        }
        let layouts = BINDINGS.map(|bindings| {
            let entries: Vec<wgpu::BindGroupLayoutEntry> = bindings
                .iter()
                .map(|&(binding, access)| wgpu::BindGroupLayoutEntry {
                    binding,
                    visibility: wgpu::ShaderStages::COMPUTE,
                    ty: wgpu::BindingType::Buffer {
                        ty: match access {
                            Access::Uniform | Access::Level => wgpu::BufferBindingType::Uniform,
                            Access::Read => wgpu::BufferBindingType::Storage { read_only: true },
                            Access::ReadWrite => wgpu::BufferBindingType::Storage { read_only: false },
                        },
                        has_dynamic_offset: matches!(access, Access::Level),
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
            return Err(GpuError::Wgpu {
                during: format!("pipeline creation on {adapter}"),
                message: e.to_string(),
            });
        }
        let max_binding = limits.max_storage_buffer_binding_size.min(limits.max_buffer_size);
        let max_buffer = limits.max_buffer_size;
        Ok(Self {
            device,
            queue,
            adapter,
            layouts,
            pipelines,
            budget: budget_bytes.max(1 << 20),
            max_binding,
            max_buffer,
            tri_window_bytes: max_binding,
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

    /// Binds a batch's triangles to the raster pass in windows of at most `bytes` (at least
    /// 32 triangles), as on an adapter whose largest storage binding is that small: a test
    /// of the windowed raster on any adapter. Results do not depend on it.
    #[doc(hidden)]
    pub fn set_triangle_window_bytes(&mut self, bytes: u64) {
        self.tri_window_bytes = bytes.min(self.max_binding);
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
        out.pop().ok_or(GpuError::Internal("no result for the job"))
    }

    /// Bakes every job, batched under the memory budget; results in job order, each as
    /// [`super::cpu::bake_cells`] returns it. Jobs on the same mesh (the same `&Mesh`) share
    /// its preparation and, within a batch, its upload.
    pub fn bake_jobs(
        &self,
        jobs: &[LevelJob<'_>],
        options: &SliceOptions,
    ) -> Result<(Vec<JobResult>, BatchReport), GpuError> {
        self.bake_jobs_as(jobs, options)
    }

    /// [`Self::bake_jobs`] with each job's points as a [`PointCloud`] (positions and normals,
    /// the same values and order as the cells'): the bake's path.
    pub fn bake_clouds(
        &self,
        jobs: &[LevelJob<'_>],
        options: &SliceOptions,
    ) -> Result<(Vec<(PointCloud, BakeStats)>, BatchReport), GpuError> {
        self.bake_jobs_as(jobs, options)
    }

    /// [`Self::bake_jobs`] with the points as `O`.
    pub fn bake_jobs_as<O: JobOutput>(
        &self,
        jobs: &[LevelJob<'_>],
        options: &SliceOptions,
    ) -> Result<(Vec<(O, BakeStats)>, BatchReport), GpuError> {
        let fill = options.fill_holes;
        let mut report = BatchReport { budget_bytes: self.budget, ..BatchReport::default() };
        let mut results: Vec<Option<(O, BakeStats)>> = (0..jobs.len()).map(|_| None).collect();

        let t = Instant::now();
        // Busy time of the parallel parts, summed over items (so over threads).
        let busy = AtomicU64::new(0);
        // Distinct meshes, in order of first use.
        let mut mesh_of: std::collections::HashMap<*const Mesh, usize> = std::collections::HashMap::new();
        let mut distinct: Vec<&Mesh> = Vec::new();
        let job_mesh: Vec<usize> = jobs
            .iter()
            .map(|j| {
                *mesh_of.entry(std::ptr::from_ref(j.mesh)).or_insert_with(|| {
                    distinct.push(j.mesh);
                    distinct.len() - 1
                })
            })
            .collect();
        let seq = t.elapsed();
        let meshes: Vec<MeshPrep> = distinct.par_iter().map(|m| timed(&busy, || prepare_mesh(m))).collect();
        let prepared: Vec<Result<Prepared, Unfit>> = jobs
            .par_iter()
            .enumerate()
            .map(|(n, j)| timed(&busy, || prepare_job(n, j, job_mesh[n], &meshes[job_mesh[n]])))
            .collect();
        let t = Instant::now();
        let mut queue: std::collections::VecDeque<Prepared> = std::collections::VecDeque::new();
        let mut cpu: Vec<usize> = Vec::new();
        for (n, p) in prepared.into_iter().enumerate() {
            match p {
                Ok(p) if self.fits_alone(&p, &meshes, fill) => queue.push_back(p),
                Ok(_) | Err(Unfit::TooLarge) => cpu.push(n),
                Err(Unfit::Empty(stats)) => results[n] = Some((O::from_cells(Vec::new()), stats)),
            }
        }
        report.prepare_s += (seq + t.elapsed()).as_secs_f64() + busy_s(&busy);
        report.gpu_jobs = queue.len() as u64;
        report.cpu_jobs = cpu.len() as u64;

        // Double buffering: submit the next batch before reading back the previous one.
        let mut in_flight: Option<InFlight> = None;
        loop {
            let batch = self.take_batch(&mut queue, &meshes, fill);
            let submitted =
                if batch.is_empty() { None } else { Some(self.submit(batch, &meshes, fill, &mut report)?) };
            if let Some(f) = in_flight.take() {
                report.batches += 1;
                report.peak_batch_bytes = report.peak_batch_bytes.max(f.bytes);
                report.reused_buffers += f.reused;
                for (p, r) in self.finish(f, jobs, &mut report)? {
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
                            if self.fits_alone(&p, &meshes, fill) {
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
        let cpu_results: Vec<(usize, (O, BakeStats))> = cpu
            .par_iter()
            .map(|&n| {
                let (cells, stats) =
                    super::cpu::bake_cells(jobs[n].mesh, jobs[n].origin, jobs[n].cell, options);
                (n, (O::from_cells(cells), stats))
            })
            .collect();
        for (n, r) in cpu_results {
            results[n] = Some(r);
        }
        let results = results
            .into_iter()
            .map(|r| r.ok_or(GpuError::Internal("a job was left without a result")))
            .collect::<Result<_, _>>()?;
        Ok((results, report))
    }
}

/// Runs `f`, adding its wall time to `acc` (ns): busy time of a parallel phase, summed over the
/// items, so over the threads that ran them.
fn timed<T>(acc: &AtomicU64, f: impl FnOnce() -> T) -> T {
    let t = Instant::now();
    let r = f();
    acc.fetch_add(u64::try_from(t.elapsed().as_nanos()).unwrap_or(u64::MAX), Ordering::Relaxed);
    r
}

fn busy_s(acc: &AtomicU64) -> f64 {
    acc.load(Ordering::Relaxed) as f64 * 1e-9
}

/// The host's part of a job: its cell box and grid transform, its room on the device.
struct Prepared {
    /// Index into the caller's job list.
    job: usize,
    /// Index into the call's distinct meshes.
    mesh: usize,
    base: [i64; 3],
    dims: [u32; 3],
    /// Grid coordinates relative to `base`, 3 per mesh vertex (the reference's, in f64, then
    /// f32).
    verts: Vec<f32>,
    skipped: usize,
    /// Output room, points.
    out_cap: u64,
    /// Table slots (a power of two).
    table_slots: u64,
}

/// Why a job's GPU result was not used.
enum Redo {
    /// Its table or output overflowed: re-run with more room.
    Grow,
    /// A cell's per-axis count filled up: bake it with the CPU reference.
    Cpu,
}

/// A job's GPU result, or why it is not used.
type Decoded<O> = Result<(O, BakeStats), Redo>;
