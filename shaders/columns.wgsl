// Pipeline `columns`: the occupancy of every column of the three views, from the occupied
// cells before any fill — each column's lowest (front) and highest (back) slice.
//
// Bindings (after common.wgsl's 0..3):
//   4  columns  storage, rw  `COLUMN_WORDS` atomic words per column, job after job, axis after
//                            axis, row-major in (u, v): 0 FRONT_BASE − front slice, 1 back slice
//                            + 1 (both 0 when empty), 2 front cell's slot + 1, 3 back's
//                            (written by `column_cells`)
//
// Items: every table slot of every job.

@group(0) @binding(4) var<storage, read_write> columns: array<atomic<u32>>;

@compute @workgroup_size(64)
fn main(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let item = flat_id(gid, nwg);
    if item >= params.slots {
        return;
    }
    let key1 = atomicLoad(&table[item * SLOT_WORDS]);
    if key1 == 0u {
        return;
    }
    let job = jobs[find_job(item, 1u)];
    if job.fill == 0u {
        return;
    }
    let c = unpack_key(job, key1 - 1u);
    for (var axis = 0u; axis < 3u; axis++) {
        let col = column_index(job, axis, c[(axis + 1u) % 3u], c[(axis + 2u) % 3u]) * COLUMN_WORDS;
        atomicMax(&columns[col], FRONT_BASE - c[axis]);
        atomicMax(&columns[col + 1u], c[axis] + 1u);
    }
}
