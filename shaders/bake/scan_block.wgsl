// Shared by the scan pipelines that scan blocks (`scan_rows`, `scan`): an exclusive prefix sum
// of one workgroup's `SCAN_BLOCK` values in workgroup memory (Hillis–Steele; every invocation
// reaches every barrier, out-of-range ones with the value 0).

const SCAN_BLOCK: u32 = 256u;

var<workgroup> partial: array<u32, 256>;

// The block's exclusive prefix at `lid` and the block's total (from every invocation).
fn block_scan(lid: u32, v: u32) -> vec2<u32> {
    partial[lid] = v;
    workgroupBarrier();
    for (var d = 1u; d < SCAN_BLOCK; d = d * 2u) {
        var add = 0u;
        if lid >= d {
            add = partial[lid - d];
        }
        workgroupBarrier();
        partial[lid] += add;
        workgroupBarrier();
    }
    let inclusive = partial[lid];
    let total = partial[SCAN_BLOCK - 1u];
    return vec2<u32>(inclusive - v, total);
}

// The flat block index of a 2D dispatch (one dimension caps at 65535 groups).
fn block_id(wid: vec3<u32>, nwg: vec3<u32>) -> u32 {
    return wid.x + wid.y * nwg.x;
}
