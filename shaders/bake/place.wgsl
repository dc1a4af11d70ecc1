// Pipeline `place`: every entry of a job's cell list (occupied and filled cells) → its point,
// decoded, at its final place in the batch's output: the number of the batch's cells before
// it in (job, k, j, i) order, which is its row's prefix (`scan_rows.wgsl`) plus the bits before
// it in its row. The order is the CPU reference's and does not depend on scheduling, so two
// bakes are identical and the host reads the points back as they are.
//
// Bindings (after common.wgsl's 0..1):
//   2  counters  storage, read  word 0: the job's cell list length
//   3  table     storage, read
//   7  list      storage, read  the cell list (table slots)
//   8  bitmap    storage, read
//   9  scan      storage, read  each row's prefix (complete)
//  10  out       storage, rw    8 words per point: 0 i | j << 16 and 1 k | samples << 16 |
//                               FILL_BIT (local cell, relative to the job's base cell);
//                               2..4 position relative to the job's base corner in fixed
//                               point (cell/2^16), the mean of the cell's offsets rounded to
//                               nearest: integer arithmetic, so the same cell gives the same
//                               point whatever the adapter or dispatch layout; 5..7 the unit
//                               normal (f32 bits; +Z when the normal sum is zero)
//
// Items: every cell-list entry (`job.out_cap` per job); entries past the list's end return.

@group(0) @binding(2) var<storage, read> counters: array<u32>;
@group(0) @binding(3) var<storage, read> table: array<u32>;
@group(0) @binding(7) var<storage, read> list: array<u32>;
@group(0) @binding(8) var<storage, read> bitmap: array<u32>;
@group(0) @binding(9) var<storage, read> scan: array<u32>;
@group(0) @binding(10) var<storage, read_write> out: array<u32>;

@compute @workgroup_size(64)
fn main(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let item = flat_id(gid, nwg);
    if item >= params.out_items {
        return;
    }
    let j = find_job(item, 1u);
    let job = jobs[j];
    if item - job.out_start >= min(counters[counter_word(j, C_OUT)], job.out_cap) {
        return;
    }
    let w = slot_word(list[item]);
    let key = table[w] - 1u;
    let row = key / job.nx;
    let i = key - row * job.nx;
    let bits = job.bit_start + row * job.row_words;
    var rank = scan[job.row_start + row];
    for (var k = 0u; k < i / 32u; k++) {
        rank += countOneBits(bitmap[bits + k]);
    }
    rank += countOneBits(bitmap[bits + i / 32u] & ((1u << (i % 32u)) - 1u));

    let c = vec3<u32>(i, row % job.ny, row / job.ny);
    let word = table[w + 1u];
    let counts = vec3<u32>(word & COUNT_FIELD, (word >> COUNT_BITS) & COUNT_FIELD, (word >> (2u * COUNT_BITS)) & COUNT_FIELD);
    let count = counts.x + counts.y + counts.z;
    let o = point_word(rank);
    out[o] = c.x | (c.y << 16u);
    out[o + 1u] = c.z | (count << 16u) | (word & FILL_BIT);
    let n = max(count, 1u);
    for (var d = 0u; d < 3u; d++) {
        // Per-axis depth sums → the position sum (see the table layout in common.wgsl).
        let sum = table[w + 2u + d] + POS_HALF * (count - counts[d]);
        out[o + 2u + d] = (c[d] << 16u) + (sum + n / 2u) / n;
    }
    let m = vec3<f32>(vec3<i32>(bitcast<i32>(table[w + 5u]), bitcast<i32>(table[w + 6u]), bitcast<i32>(table[w + 7u])));
    let len = sqrt(dot(m, m));
    var normal = vec3<f32>(0.0, 0.0, 1.0);
    if len > 0.0 {
        normal = m / len;
    }
    out[o + 5u] = bitcast<u32>(normal.x);
    out[o + 6u] = bitcast<u32>(normal.y);
    out[o + 7u] = bitcast<u32>(normal.z);
}
