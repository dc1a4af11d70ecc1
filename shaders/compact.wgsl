// Pipeline `compact`: turns every occupied or filled cell of the table into one output point
// record (cell, count, position and normal sums), appended to its job's output range.
// Append order depends on scheduling; the host sorts each job's points by cell (k, j, i), so
// the result is deterministic.
//
// Bindings (after common.wgsl's 0..3):
//   7  points  storage, rw  8 words per point, job after job (`job.out_start`, room for
//                           `job.out_cap`): 0 packed local cell key, 1 count word (as in the
//                           table), 2..4 position offset sums (units cell/2^16), 5..7 normal
//                           sums (i32 bits); the host turns them into the point exactly as
//                           `lod::cpu` does (mean position, unit normal or +Z for a zero sum)
//
// Items: every table slot of every job.

@group(0) @binding(7) var<storage, read_write> points: array<u32>;

@compute @workgroup_size(64)
fn main(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let item = flat_id(gid, nwg);
    if item >= params.slots {
        return;
    }
    let w = item * SLOT_WORDS;
    let key1 = atomicLoad(&table[w]);
    if key1 == 0u {
        return;
    }
    let j = find_job(item, 1u);
    let job = jobs[j];
    let word = atomicLoad(&table[w + 1u]);
    let count = max(word & COUNT_MASK, 1u);
    if word >= FILL_FLAG {
        atomicAdd(&counters[j * COUNTER_WORDS + C_FILLED], 1u);
    }
    let idx = atomicAdd(&counters[j * COUNTER_WORDS + C_OUT], 1u);
    if idx >= job.out_cap {
        return;
    }
    let o = (job.out_start + idx) * 8u;
    points[o] = key1 - 1u;
    points[o + 1u] = word;
    // The sums themselves: the host divides them in f64 as the CPU reference does, so a cell
    // with the same fragments gives the same point bit for bit, whatever the adapter's f32
    // division and square root (llvmpipe's differed in the last bit between dispatch layouts).
    for (var k = 2u; k < 8u; k++) {
        points[o + k] = atomicLoad(&table[w + k]);
    }
}
