// Pipeline `compact`: turns every entry of a job's cell list (occupied and filled cells) into
// its output point record (cell, count, position and normal sums), in place. List order
// depends on scheduling; the host sorts each job's points by cell (k, j, i), so the result is
// deterministic.
//
// Bindings (after common.wgsl's 0..1):
//   2  counters  storage, read  word 0: the job's cell list length
//   3  table     storage, read
//   7  points    storage, rw    8 words per point, job after job (`job.out_start`, room for
//                               `job.out_cap`): word 0 holds the cell's table slot on entry;
//                               on exit 0 packed local cell key, 1..7 the slot's words 1..7
//                               (counts, depth sums, normal sums; see common.wgsl); the host
//                               rebuilds the position sums and turns them into the point
//                               exactly as `lod::cpu` does (mean position, unit normal or +Z
//                               for a zero sum), and counts the filled cells (FILL_BIT)
//
// Items: every cell-list entry (`job.out_cap` per job); entries past the list's end return.

@group(0) @binding(2) var<storage, read> counters: array<u32>;
@group(0) @binding(3) var<storage, read> table: array<u32>;
@group(0) @binding(7) var<storage, read_write> points: array<u32>;

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
    let o = point_word(item);
    let w = slot_word(points[o]);
    points[o] = table[w] - 1u;
    // The sums themselves: the host divides them in f64 as the CPU reference does, so a cell
    // with the same fragments gives the same point bit for bit, whatever the adapter's f32
    // division and square root (llvmpipe's differed in the last bit between dispatch layouts).
    for (var k = 1u; k < 8u; k++) {
        points[o + k] = table[w + k];
    }
}
