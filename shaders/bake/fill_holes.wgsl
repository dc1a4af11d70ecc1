// Pipeline `fill`: the hole-filling median filter (`lod::cpu` module doc, "Hole filling").
// One invocation per column of each view: an empty column whose 4 edge neighbours and at least
// FILL_MIN_NEIGHBOURS of its 8 neighbours are occupied gets a front fill (lower median of the
// neighbours' front-cell keys) and a back fill (upper median of their back-cell keys), added
// to the cell table like fragments. It reads only the pre-fill column data, so the result does
// not depend on the order in which invocations run.
//
// Bindings (after common.wgsl's 0..1, and insert.wgsl's 2, 3, 7, 8 read-write):
//   4  columns  storage, read  as in `columns.wgsl`
//
// Items: every column of the three views of every job.

@group(0) @binding(4) var<storage, read> columns: array<u32>;

const FILL_MIN_NEIGHBOURS: u32 = 5u;
const NORMAL_ONE: f32 = 32768.0;

fn occupied(job: Job, axis: u32, u: i32, v: i32, nu: i32, nv: i32) -> u32 {
    if u < 0 || v < 0 || u >= nu || v >= nv {
        return 0u;
    }
    let col = column_index(job, axis, u32(u), u32(v)) * COLUMN_WORDS;
    if columns[col] == 0u {
        return 0u;
    }
    return col + 1u;
}

@compute @workgroup_size(64)
fn main(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let item = flat_id(gid, nwg);
    if item >= params.col_items {
        return;
    }
    let j = find_job(item, 2u);
    let job = jobs[j];
    if job.fill == 0u {
        return;
    }
    let dims = job_dims(job);
    var local = item - job.col_start;
    var axis = 0u;
    if local >= dims.y * dims.z {
        local -= dims.y * dims.z;
        axis = 1u;
        if local >= dims.z * dims.x {
            local -= dims.z * dims.x;
            axis = 2u;
        }
    }
    let ua = (axis + 1u) % 3u;
    let va = (axis + 2u) % 3u;
    let nu = i32(dims[ua]);
    let nv = i32(dims[va]);
    let u = i32(local % dims[ua]);
    let v = i32(local / dims[ua]);
    if occupied(job, axis, u, v, nu, nv) != 0u {
        return;
    }
    let offsets = array<vec2<i32>, 8>(
        vec2<i32>(-1, -1), vec2<i32>(0, -1), vec2<i32>(1, -1), vec2<i32>(-1, 0),
        vec2<i32>(1, 0), vec2<i32>(-1, 1), vec2<i32>(0, 1), vec2<i32>(1, 1),
    );
    var around = array<u32, 8>();
    var dirs = array<u32, 8>();
    var n = 0u;
    var edge = 0u;
    for (var k = 0u; k < 8u; k++) {
        let o = offsets[k];
        let col = occupied(job, axis, u + o.x, v + o.y, nu, nv);
        if col != 0u {
            around[n] = col - 1u;
            dirs[n] = k;
            n += 1u;
            if o.x == 0 || o.y == 0 {
                edge += 1u;
            }
        }
    }
    if n < FILL_MIN_NEIGHBOURS || edge < 4u {
        return;
    }
    for (var back = 0u; back < 2u; back++) {
        var keys = array<u32, 8>();
        var normal = vec3<i32>(0, 0, 0);
        for (var k = 0u; k < n; k++) {
            // The neighbour's front (back) cell: its slice from the column, its slot from the
            // table. Its probe chain was filled before this pass, so fills inserted meanwhile
            // do not change what the lookup finds.
            let col = around[k];
            var slice = FRONT_BASE - columns[col];
            if back == 1u {
                slice = columns[col + 1u] - 1u;
            }
            let o = offsets[dirs[k]];
            var c = vec3<u32>(0u, 0u, 0u);
            c[axis] = slice;
            c[ua] = u32(u + o.x);
            c[va] = u32(v + o.y);
            let slot = find(job, pack_key(job, c));
            if slot < 0 {
                atomicAdd(&counters[counter_word(j, C_OVERFLOW)], 1u);
                return;
            }
            let w = slot_word(u32(slot));
            // The mean offset on `axis` (see the table layout in common.wgsl); a neighbour
            // holds fragments only (no fills yet), at most 3 × COUNT_FIELD of them.
            let counts = atomicLoad(&table[w + 1u]);
            let own = (counts >> (axis * COUNT_BITS)) & COUNT_FIELD;
            let count = (counts & COUNT_FIELD) + ((counts >> COUNT_BITS) & COUNT_FIELD)
                + ((counts >> (2u * COUNT_BITS)) & COUNT_FIELD);
            let sum = atomicLoad(&table[w + 2u + axis]) + POS_HALF * (count - own);
            let mean = (sum + count / 2u) / max(count, 1u);
            // Slices stay below 2^16 (the host checks the job's extents), so one word holds
            // slice and offset in key order.
            keys[k] = (slice << 16u) + mean;
            normal += vec3<i32>(
                bitcast<i32>(atomicLoad(&table[w + 5u])),
                bitcast<i32>(atomicLoad(&table[w + 6u])),
                bitcast<i32>(atomicLoad(&table[w + 7u])),
            );
        }
        // Insertion sort of at most 8 keys.
        for (var a = 1u; a < n; a++) {
            let x = keys[a];
            var b = a;
            while b > 0u && keys[b - 1u] > x {
                keys[b] = keys[b - 1u];
                b -= 1u;
            }
            keys[b] = x;
        }
        var pick = (n - 1u) / 2u;
        if back == 1u {
            pick = n / 2u;
        }
        let key = keys[pick];
        var c = vec3<u32>(0u, 0u, 0u);
        c[axis] = key >> 16u;
        c[ua] = u32(u);
        c[va] = u32(v);
        let m = vec3<f32>(normal);
        let len = length(m);
        var nq = vec3<i32>(0, 0, 0);
        if len > 0.0 {
            nq = vec3<i32>(floor(m / len * NORMAL_ONE + 0.5));
        }
        let slot = find_or_insert(j, job, pack_key(job, c), true);
        if slot < 0 {
            atomicAdd(&counters[counter_word(j, C_OVERFLOW)], 1u);
            continue;
        }
        let w = slot_word(u32(slot));
        atomicOr(&table[w + 1u], FILL_BIT);
        if !add_count(w + 1u, axis) {
            atomicAdd(&counters[counter_word(j, C_COUNT_OVERFLOW)], 1u);
        }
        atomicAdd(&table[w + 2u + axis], key & 65535u);
        for (var k = 0u; k < 3u; k++) {
            atomicAdd(&table[w + 5u + k], bitcast<u32>(nq[k]));
        }
    }
}
