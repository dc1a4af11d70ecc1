// Pipeline `scan_rows`: the first level of the batch-wide exclusive prefix sum of cells per
// row (one row = one (k, j) of a job's box; rows job after job, so a row's prefix is the
// number of the batch's points before it in the output order: jobs in batch order, cells in
// (k, j, i) order). A row's count is the popcount of its bitmap words.
//
// Bindings (after common.wgsl's 0..1):
//   8  bitmap  storage, read  as in `insert.wgsl`
//   9  scan    storage, rw    words [0, rows): each row's prefix within its block of
//                             SCAN_BLOCK rows; word rows + b: block b's total (`level.dst`)
//  11  level   uniform        `Level` (only `count` = rows and `dst` are used)
//
// Items: every row of every job (`params.rows`), SCAN_BLOCK per workgroup.

struct Level {
    src: u32,
    count: u32,
    dst: u32,
    pad: u32,
}

@group(0) @binding(8) var<storage, read> bitmap: array<u32>;
@group(0) @binding(9) var<storage, read_write> scan: array<u32>;
@group(0) @binding(11) var<uniform> level: Level;

@compute @workgroup_size(256)
fn main(
    @builtin(local_invocation_index) lid: u32,
    @builtin(workgroup_id) wid: vec3<u32>,
    @builtin(num_workgroups) nwg: vec3<u32>,
) {
    let b = block_id(wid, nwg);
    let item = b * SCAN_BLOCK + lid;
    var v = 0u;
    if item < level.count {
        let job = jobs[find_job(item, 3u)];
        let w = job.bit_start + (item - job.row_start) * job.row_words;
        for (var k = 0u; k < job.row_words; k++) {
            v += countOneBits(bitmap[w + k]);
        }
    }
    let r = block_scan(lid, v);
    if item < level.count {
        scan[level.src + item] = r.x;
    }
    if lid == 0u {
        scan[level.dst + b] = r.y;
    }
}
