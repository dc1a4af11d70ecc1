// Pipeline `scan_add`: completes one level of the prefix sum (`scan.wgsl`): each of the
// `level.count` values from `level.src` gets the scanned total of the blocks before its block
// (the level above, from `level.dst`).
//
// Bindings:
//   9  scan   storage, rw
//  11  level  uniform  `Level`
//
// Items: `level.count`.

struct Level {
    src: u32,
    count: u32,
    dst: u32,
    pad: u32,
}

const SCAN_BLOCK: u32 = 256u;

@group(0) @binding(9) var<storage, read_write> scan: array<u32>;
@group(0) @binding(11) var<uniform> level: Level;

@compute @workgroup_size(256)
fn main(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let item = gid.x + gid.y * nwg.x * 256u;
    if item < level.count {
        scan[level.src + item] += scan[level.dst + item / SCAN_BLOCK];
    }
}
