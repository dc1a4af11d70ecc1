// Shared head of every `lod::gpu` pipeline: prepended to each pipeline's own file, so the
// bindings below are the same in all of them.
//
// Bindings (group 0):
//   0  params    uniform        `Params`: job count and the item count of each pass
//   1  jobs      storage, read  `Job` per (mesh, level) of the batch (see `lod::gpu::GpuJob`)
//   2  counters  storage, rw    8 atomic words per job: 0 points out, 1 filled cells,
//                               2..4 fragments per view axis, 5 overflow (table or output full)
//   3  table     storage, rw    the cell hash table, `SLOT_WORDS` atomic words per slot:
//                               0 packed local cell key + 1 (0 = empty), 1 count (+ FILL_FLAG per
//                               fill contribution), 2..4 position offset sums (units cell/2^16),
//                               5..7 normal sums (i32 bits, units 2^-15)
// Pipelines add their own from 4 on, numbered apart so that one bind group layout serves all
// five: 4 columns (rw), 5 verts (read), 6 tris (read), 7 points (rw).
//
// Work is a flat list of items per pass (triangle × axis, table slot, or column), laid out job
// after job; an invocation finds its job by binary search over the jobs' item starts.

struct Params {
    n_jobs: u32,
    raster_items: u32,
    slots: u32,
    col_items: u32,
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
    pad0: u32,
    pad1: u32,
    pad2: u32,
}

@group(0) @binding(0) var<uniform> params: Params;
@group(0) @binding(1) var<storage, read> jobs: array<Job>;
@group(0) @binding(2) var<storage, read_write> counters: array<atomic<u32>>;
@group(0) @binding(3) var<storage, read_write> table: array<atomic<u32>>;

const WORKGROUP: u32 = 64u;
const SLOT_WORDS: u32 = 8u;
const COUNTER_WORDS: u32 = 8u;
const C_OUT: u32 = 0u;
const C_FILLED: u32 = 1u;
const C_FRAGS: u32 = 2u;
const C_OVERFLOW: u32 = 5u;
// Fill contributions are counted in the high bits of the count word: a filled cell never holds
// fragments, and a cell gets far fewer than 2^20 fragments.
const FILL_FLAG: u32 = 1048576u;
const COUNT_MASK: u32 = 1048575u;
// Position offsets: 2^16 units per cell, the pixel centre at 2^15.
const POS_ONE: f32 = 65536.0;
const POS_HALF: u32 = 32768u;
// Column occupancy: front stored as FRONT_BASE - slice (so atomicMax keeps the lowest slice),
// back as slice + 1; 0 means empty either way.
const FRONT_BASE: u32 = 1073741824u;
const COLUMN_WORDS: u32 = 4u;

// The invocation's flat item index over a 2D dispatch (one dimension caps at 65535 groups).
fn flat_id(gid: vec3<u32>, nwg: vec3<u32>) -> u32 {
    return gid.x + gid.y * nwg.x * WORKGROUP;
}

fn item_start(j: u32, which: u32) -> u32 {
    switch which {
        case 0u: { return jobs[j].raster_start; }
        case 1u: { return jobs[j].slot_start; }
        default: { return jobs[j].col_start; }
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

// The global slot of cell `key` (packed local index) in the job's table, inserting it when
// missing (linear probing); -1 when the table is full. Slots depend on insertion order, the
// sums in them do not; the output is sorted by cell on the host.
fn find_or_insert(job: Job, key: u32) -> i32 {
    let key1 = key + 1u;
    var h = hash32(key) & job.table_mask;
    for (var probe = 0u; probe <= job.table_mask; probe++) {
        let s = job.slot_start + h;
        let w = s * SLOT_WORDS;
        loop {
            let cur = atomicLoad(&table[w]);
            if cur == key1 {
                return i32(s);
            }
            if cur != 0u {
                break;
            }
            let r = atomicCompareExchangeWeak(&table[w], 0u, key1);
            if r.exchanged || r.old_value == key1 {
                return i32(s);
            }
            if r.old_value != 0u {
                break;
            }
        }
        h = (h + 1u) & job.table_mask;
    }
    return -1;
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
