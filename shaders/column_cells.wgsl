// Pipeline `column_cells`: records which table slot holds each column's front and back cell
// (exactly one cell per column has each slice, so the writes do not race).
//
// Bindings: as in `columns.wgsl`; this pass writes words 2 and 3 of the columns.
//
// Items: every cell-list entry, as in `columns.wgsl`.

@group(0) @binding(2) var<storage, read> counters: array<u32>;
@group(0) @binding(3) var<storage, read> table: array<u32>;
@group(0) @binding(4) var<storage, read_write> columns: array<atomic<u32>>;
@group(0) @binding(7) var<storage, read> points: array<u32>;

@compute @workgroup_size(64)
fn main(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let item = flat_id(gid, nwg);
    if item >= params.out_items {
        return;
    }
    let j = find_job(item, 1u);
    let job = jobs[j];
    let idx = item - job.out_start;
    if job.fill == 0u || idx >= min(counters[j * COUNTER_WORDS + C_OUT], job.out_cap) {
        return;
    }
    let slot = points[item * 8u];
    let c = unpack_key(job, table[slot * SLOT_WORDS] - 1u);
    for (var axis = 0u; axis < 3u; axis++) {
        let col = column_index(job, axis, c[(axis + 1u) % 3u], c[(axis + 2u) % 3u]) * COLUMN_WORDS;
        if atomicLoad(&columns[col]) == FRONT_BASE - c[axis] {
            atomicStore(&columns[col + 2u], slot + 1u);
        }
        if atomicLoad(&columns[col + 1u]) == c[axis] + 1u {
            atomicStore(&columns[col + 3u], slot + 1u);
        }
    }
}
