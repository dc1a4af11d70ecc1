// Pipeline `scan`: one upper level of the batch-wide prefix sum (`scan_rows.wgsl`): the block
// totals of the level below, `level.count` of them from `level.src`, scanned in place
// (exclusive, within blocks of SCAN_BLOCK), each block's total to `level.dst`. The host runs
// it level after level until one block remains, then `scan_add` adds the levels back down.
//
// Bindings:
//   9  scan   storage, rw
//  11  level  uniform  `Level`
//
// Items: `level.count`, SCAN_BLOCK per workgroup.

struct Level {
    src: u32,
    count: u32,
    dst: u32,
    pad: u32,
}

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
        v = scan[level.src + item];
    }
    let r = block_scan(lid, v);
    if item < level.count {
        scan[level.src + item] = r.x;
    }
    if lid == 0u {
        scan[level.dst + b] = r.y;
    }
}
