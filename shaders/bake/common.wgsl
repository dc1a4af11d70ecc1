// Shared head of every `lod::gpu` pipeline: prepended to each pipeline's own file. Binding
// numbers are the same in all pipelines, but each pipeline declares (and its bind group layout
// holds) only the buffers it uses, read-only where it only reads them: on llvmpipe every
// atomic access is scalarised per lane, a plain read of a read-only binding is not.
//
// Bindings (group 0):
//   0  params    uniform        `Params`: job count and the item count of each pass
//   1  jobs      storage, read  `Job` per (mesh, level) of the batch (see `lod::gpu::GpuJob`)
//   2  counters  storage        8 words per job: 0 cells inserted (the job's cell list
//                               length), 1 cells inserted by `fill`, 2..4 fragments per view
//                               axis, 5 overflow (table full), 6 count overflow (a cell's
//                               per-axis count full)
//   3  table     storage        the cell hash table, `SLOT_WORDS` words per slot: 0 packed
//                               local cell key + 1 (0 = empty), 1 per-view-axis counts
//                               (`COUNT_BITS` each from bit 0, axis after axis; FILL_BIT set
//                               on a filled cell), 2..4 per-view-axis sums of the depth
//                               offsets (units cell/2^16), 5..7 normal sums (i32 bits, units
//                               2^-15). A fragment of view `axis` lies at the pixel centre on
//                               the other two axes, so the position sum on axis d is sum d plus
//                               POS_HALF per fragment of the other views: `place` rebuilds
//                               the three position sums exactly, with two atomics per
//                               fragment instead of four.
//   4  columns   storage        per-view column occupancy (`columns.wgsl`)
//   5  verts     storage, read  f32 × 3 per vertex of each job: grid coordinates relative to
//                               the job's base cell (`rasterize.wgsl`)
//   6  tris      storage, read  u32 × 6 per triangle of each mesh (uploaded once per mesh and
//                               batch, shared by the mesh's levels): vertex indices relative
//                               to the mesh's first vertex, smallest first, then the quantized
//                               normal (i32 bits)
//   7  list      storage        the cell list: one table slot per inserted cell, job after job
//                               (room `job.out_cap` from `job.out_start`), appended on insertion
//                               by `raster` and `fill`
//   8  bitmap    storage        one bit per cell of each job's box, row after row (a row is one
//                               (k, j), `job.row_words` words of i), set on insertion
//   9  scan      storage        per row of every job, the number of cells before it in the
//                               batch (cell order (k, j, i), job after job), and the block sums
//                               of the scan (`scan.wgsl`)
//  10  out       storage        the batch's points, in their final order, 8 words each
//                               (`place.wgsl`)
//  11  level     uniform        one scan level (`scan.wgsl`), at a dynamic offset
// `insert.wgsl` declares 2, 3, 7 and 8 read-write with atomics for the passes that insert cells
// (`raster`, `fill`); the others declare what they read as plain read-only arrays.
//
// Work is a flat list of items per pass (triangle × axis, column, cell-list entry or
// row), laid out job after job; an invocation finds its job by binary search over the jobs'
// item starts.

struct Params {
    n_jobs: u32,
    raster_items: u32,
    slots: u32,
    col_items: u32,
    out_items: u32,
    rows: u32,
    pad0: u32,
    pad1: u32,
}

struct Job {
    tri_start: u32,
    tri_count: u32,
    vert_start: u32,
    raster_start: u32,
    nx: u32,
    ny: u32,
    nz: u32,
    slot_start: u32,
    table_mask: u32,
    out_start: u32,
    out_cap: u32,
    col_start: u32,
    fill: u32,
    row_start: u32,
    bit_start: u32,
    row_words: u32,
}

@group(0) @binding(0) var<uniform> params: Params;
@group(0) @binding(1) var<storage, read> jobs: array<Job>;

const WORKGROUP: u32 = 64u;
const SLOT_WORDS: u32 = 8u;
const COUNTER_WORDS: u32 = 8u;
const POINT_WORDS: u32 = 8u;
const C_OUT: u32 = 0u;
const C_FILLED: u32 = 1u;
const C_FRAGS: u32 = 2u;
const C_OVERFLOW: u32 = 5u;
const C_COUNT_OVERFLOW: u32 = 6u;
// Per-axis counts: fragments of one view in one cell all lie on the same pixel centre, one per
// triangle, so a field rarely gets near 2^COUNT_BITS; one that fills up is reported
// (C_COUNT_OVERFLOW) and the host bakes that job with the CPU reference instead.
const COUNT_BITS: u32 = 10u;
const COUNT_FIELD: u32 = 1023u;
// A filled cell never holds fragments; its counts are its fill contributions.
const FILL_BIT: u32 = 2147483648u;
// Position offsets: 2^16 units per cell, the pixel centre at 2^15.
const POS_ONE: f32 = 65536.0;
const POS_HALF: u32 = 32768u;
// Column occupancy: front stored as FRONT_BASE - slice (so atomicMax keeps the lowest slice),
// back as slice + 1; 0 means empty either way.
const FRONT_BASE: u32 = 1073741824u;
const COLUMN_WORDS: u32 = 2u;

// The invocation's flat item index over a 2D dispatch (one dimension caps at 65535 groups).
fn flat_id(gid: vec3<u32>, nwg: vec3<u32>) -> u32 {
    return gid.x + gid.y * nwg.x * WORKGROUP;
}

fn item_start(j: u32, which: u32) -> u32 {
    switch which {
        case 0u: { return jobs[j].raster_start; }
        case 1u: { return jobs[j].out_start; }
        case 2u: { return jobs[j].col_start; }
        default: { return jobs[j].row_start; }
    }
}

// The last job whose start is ≤ item (jobs with no items share the next one's start).
fn find_job(item: u32, which: u32) -> u32 {
    var lo = 0u;
    var hi = params.n_jobs - 1u;
    while lo < hi {
        let mid = (lo + hi + 1u) / 2u;
        if item_start(mid, which) <= item {
            lo = mid;
        } else {
            hi = mid - 1u;
        }
    }
    return lo;
}

fn hash32(k: u32) -> u32 {
    var x = k;
    x = x ^ (x >> 16u);
    x = x * 0x7feb352du;
    x = x ^ (x >> 15u);
    x = x * 0x846ca68bu;
    x = x ^ (x >> 16u);
    return x;
}

fn job_dims(job: Job) -> vec3<u32> {
    return vec3<u32>(job.nx, job.ny, job.nz);
}

fn pack_key(job: Job, c: vec3<u32>) -> u32 {
    return (c.z * job.ny + c.y) * job.nx + c.x;
}

fn unpack_key(job: Job, key: u32) -> vec3<u32> {
    let i = key % job.nx;
    let r = key / job.nx;
    return vec3<u32>(i, r % job.ny, r / job.ny);
}

// Column of the view along `axis` through cell `c`: views project onto
// (u, v) = ((axis + 1) mod 3, (axis + 2) mod 3); the job's columns are laid out axis by axis.
fn column_index(job: Job, axis: u32, u: u32, v: u32) -> u32 {
    let n = job_dims(job);
    var off = 0u;
    if axis >= 1u {
        off += n.y * n.z;
    }
    if axis >= 2u {
        off += n.z * n.x;
    }
    let nu = n[(axis + 1u) % 3u];
    return job.col_start + off + v * nu + u;
}

// The buffers' word indices, written once: counter `c` of job `j`, the first word of table
// slot `s`, the first word of point record `n` (batch-wide).
fn counter_word(j: u32, c: u32) -> u32 {
    return j * COUNTER_WORDS + c;
}

fn slot_word(s: u32) -> u32 {
    return s * SLOT_WORDS;
}


fn point_word(n: u32) -> u32 {
    return n * POINT_WORDS;
}
