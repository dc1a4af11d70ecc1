// Pipeline `columns`: the occupancy of every column of the three views, from the occupied
// cells before any fill — each column's lowest (front) and highest (back) slice.
//
// Bindings (after common.wgsl's 0..1):
//   2  counters  storage, read  word 0: the job's cell list length after `raster`
//   3  table     storage, read
//   4  columns   storage, rw    `COLUMN_WORDS` atomic words per column, job after job, axis
//                               after axis, row-major in (u, v): 0 FRONT_BASE − front slice,
//                               1 back slice + 1 (both 0 when empty). The front and back cells
//                               are then the cells of the column at those slices: `fill`
//                               finds them in the table by key.
//   7  list      storage, read  the cell list (table slots)
//
// Items: every cell-list entry (`job.out_cap` per job); entries past the list's end return.

@group(0) @binding(2) var<storage, read> counters: array<u32>;
@group(0) @binding(3) var<storage, read> table: array<u32>;
@group(0) @binding(4) var<storage, read_write> columns: array<atomic<u32>>;
@group(0) @binding(7) var<storage, read> list: array<u32>;

@compute @workgroup_size(64)
fn main(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let item = flat_id(gid, nwg);
    if item >= params.out_items {
        return;
    }
    let j = find_job(item, 1u);
    let job = jobs[j];
    let idx = item - job.out_start;
    if job.fill == 0u || idx >= min(counters[counter_word(j, C_OUT)], job.out_cap) {
        return;
    }
    let slot = list[item];
    let c = unpack_key(job, table[slot_word(slot)] - 1u);
    for (var axis = 0u; axis < 3u; axis++) {
        let col = column_index(job, axis, c[(axis + 1u) % 3u], c[(axis + 2u) % 3u]) * COLUMN_WORDS;
        atomicMax(&columns[col], FRONT_BASE - c[axis]);
        atomicMax(&columns[col + 1u], c[axis] + 1u);
    }
}
