// Pipeline `column_cells`: records which table slot holds each column's front and back cell
// (exactly one cell per column has each slice, so the writes do not race).
//
// Bindings (after common.wgsl's 0..3):
//   4  columns  storage, rw  as in `columns.wgsl`; this pass writes words 2 and 3
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
        if atomicLoad(&columns[col]) == FRONT_BASE - c[axis] {
            atomicStore(&columns[col + 2u], item + 1u);
        }
        if atomicLoad(&columns[col + 1u]) == c[axis] + 1u {
            atomicStore(&columns[col + 3u], item + 1u);
        }
    }
}
