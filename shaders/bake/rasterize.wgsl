// Pipeline `raster`: rasterizes every triangle of every job in the three axis views and sums
// the fragments into the cell table (the module doc of `lod::cpu` is the specification; this
// is the same rule in f32 on job-local grid coordinates).
//
// Bindings (after common.wgsl's 0..1, and insert.wgsl's 2, 3, 7, 8 read-write):
//   5  verts  storage, read  f32 × 3 per vertex of the job's mesh: grid coordinates relative
//                            to the job's base cell (host-computed in f64 per job, as the
//                            reference specifies), so cell indices start at 0
//   6  tris   storage, read  u32 × 6 per triangle of the job's mesh: vertex indices relative
//                            to the mesh's first vertex, smallest first, then the quantized
//                            normal (i32 bits); only the triangles of the dispatch's window
//  11  tri_window uniform    the window: the batch's triangles `base .. base + count` are bound
//                            at 6 (a batch whose triangles exceed the adapter's largest
//                            storage binding is rasterized in several dispatches, one per
//                            window; the other items return at once)
//
// Items: job.tri_count × 3 per job, item = axis × tri_count + triangle: neighbouring
// invocations (one SIMD batch on llvmpipe) rasterize the same view, whose triangles have
// similar projected sizes (for terrain the top view is large, the side views thin), so fewer
// lanes idle while the others loop over their pixels.

@group(0) @binding(5) var<storage, read> verts: array<f32>;
@group(0) @binding(6) var<storage, read> tris: array<u32>;

struct TriWindow {
    base: u32,
    count: u32,
    pad0: u32,
    pad1: u32,
}
@group(0) @binding(11) var<uniform> tri_window: TriWindow;

struct Edge {
    p: vec2<f32>,
    d: vec2<f32>,
    sign: f32,
    tie: bool,
}

// Canonical edge: endpoints ordered lexicographically, so two triangles sharing an edge
// evaluate bit-identical magnitudes and break ties complementarily.
fn edge_new(a: vec2<f32>, b: vec2<f32>) -> Edge {
    let du = b.x - a.x;
    let dv = b.y - a.y;
    var e: Edge;
    e.tie = dv < 0.0 || (dv == 0.0 && du > 0.0);
    let forward = a.x < b.x || (a.x == b.x && a.y <= b.y);
    if forward {
        e.p = a;
        e.d = b - a;
        e.sign = 1.0;
    } else {
        e.p = b;
        e.d = a - b;
        e.sign = -1.0;
    }
    return e;
}

fn edge_reversed(e: Edge) -> Edge {
    var r = e;
    r.sign = -e.sign;
    r.tie = !e.tie;
    return r;
}

fn edge_eval(e: Edge, x: f32, y: f32) -> f32 {
    return e.sign * (e.d.x * (y - e.p.y) - e.d.y * (x - e.p.x));
}

fn covers(e: Edge, v: f32) -> bool {
    return v > 0.0 || (v == 0.0 && e.tie);
}

fn vert(job: Job, id: u32) -> vec3<f32> {
    let b = (job.vert_start + id) * 3u;
    return vec3<f32>(verts[b], verts[b + 1u], verts[b + 2u]);
}

// Columns of row centre y that can be inside the triangle, widened by a pixel (a speed-up
// only; the edge tests decide coverage). Returns (1, 0) when the row misses it.
fn row_span(p0: vec2<f32>, p1: vec2<f32>, p2: vec2<f32>, y: f32, i0: i32, i1: i32) -> vec2<i32> {
    var lo = 3.0e38;
    var hi = -3.0e38;
    var a = array<vec2<f32>, 3>(p0, p1, p2);
    for (var k = 0u; k < 3u; k++) {
        let pa = a[k];
        let pb = a[(k + 1u) % 3u];
        if (pa.y <= y && y <= pb.y) || (pb.y <= y && y <= pa.y) {
            let dv = pb.y - pa.y;
            if dv == 0.0 {
                lo = min(lo, min(pa.x, pb.x));
                hi = max(hi, max(pa.x, pb.x));
            } else {
                let x = pa.x + (y - pa.y) * (pb.x - pa.x) / dv;
                lo = min(lo, x);
                hi = max(hi, x);
            }
        }
    }
    if lo > hi {
        return vec2<i32>(1, 0);
    }
    return vec2<i32>(max(i32(ceil(lo - 0.5)) - 1, i0), min(i32(floor(hi - 0.5)) + 1, i1));
}

@compute @workgroup_size(64)
fn main(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let item = flat_id(gid, nwg);
    if item >= params.raster_items {
        return;
    }
    let j = find_job(item, 0u);
    let job = jobs[j];
    let local = item - job.raster_start;
    let axis = local / job.tri_count;
    let t = job.tri_start + local - axis * job.tri_count;
    if t < tri_window.base || t - tri_window.base >= tri_window.count {
        return;
    }
    let tb = (t - tri_window.base) * 6u;
    let g0 = vert(job, tris[tb]);
    let g1 = vert(job, tris[tb + 1u]);
    let g2 = vert(job, tris[tb + 2u]);
    let n = vec3<i32>(bitcast<i32>(tris[tb + 3u]), bitcast<i32>(tris[tb + 4u]), bitcast<i32>(tris[tb + 5u]));
    let ua = (axis + 1u) % 3u;
    let va = (axis + 2u) % 3u;

    // Pixel centres c + ½ inside the projected box.
    let i0 = i32(ceil(min(min(g0[ua], g1[ua]), g2[ua]) - 0.5));
    let i1 = i32(floor(max(max(g0[ua], g1[ua]), g2[ua]) - 0.5));
    let j0 = i32(ceil(min(min(g0[va], g1[va]), g2[va]) - 0.5));
    let j1 = i32(floor(max(max(g0[va], g1[va]), g2[va]) - 0.5));
    if i0 > i1 || j0 > j1 {
        return;
    }
    let p0 = vec2<f32>(g0[ua], g0[va]);
    let p1 = vec2<f32>(g1[ua], g1[va]);
    let p2 = vec2<f32>(g2[ua], g2[va]);
    var d = vec3<f32>(g0[axis], g1[axis], g2[axis]);
    // Edge k is opposite vertex k: its edge function is that vertex's barycentric weight.
    var e0 = edge_new(p1, p2);
    var e1 = edge_new(p2, p0);
    var e2 = edge_new(p0, p1);
    let area = edge_eval(e2, p2.x, p2.y);
    if area == 0.0 {
        return;
    }
    if area < 0.0 {
        let t1 = e1;
        e0 = edge_reversed(e0);
        e1 = edge_reversed(e2);
        e2 = edge_reversed(t1);
        d = vec3<f32>(d.x, d.z, d.y);
    }
    let dmin = min(min(d.x, d.y), d.z);
    let dmax = max(max(d.x, d.y), d.z);
    let narrow = i1 - i0 > 2;
    let dims = job_dims(job);

    var count = 0u;
    var overflow = 0u;
    var count_overflow = 0u;
    for (var pj = j0; pj <= j1; pj++) {
        let y = f32(pj) + 0.5;
        var span = vec2<i32>(i0, i1);
        if narrow {
            span = row_span(p0, p1, p2, y, i0, i1);
        }
        let ay = vec3<f32>(e0.d.x * (y - e0.p.y), e1.d.x * (y - e1.p.y), e2.d.x * (y - e2.p.y));
        for (var pi = span.x; pi <= span.y; pi++) {
            let x = f32(pi) + 0.5;
            let w0 = e0.sign * (ay.x - e0.d.y * (x - e0.p.x));
            let w1 = e1.sign * (ay.y - e1.d.y * (x - e1.p.x));
            let w2 = e2.sign * (ay.z - e2.d.y * (x - e2.p.x));
            if !(covers(e0, w0) && covers(e1, w1) && covers(e2, w2)) {
                continue;
            }
            let sum = w0 + w1 + w2;
            if sum <= 0.0 {
                continue;
            }
            let t = clamp((w0 * d.x + w1 * d.y + w2 * d.z) / sum, dmin, dmax);
            let s = floor(t);
            let q = min(u32((t - s) * POS_ONE + 0.5), 65535u);
            if s < 0.0 || pi < 0 || pj < 0 {
                continue;
            }
            var c = vec3<u32>(0u, 0u, 0u);
            c[axis] = u32(s);
            c[ua] = u32(pi);
            c[va] = u32(pj);
            if any(c >= dims) {
                continue;
            }
            let slot = find_or_insert(j, job, pack_key(job, c), false);
            if slot < 0 {
                overflow += 1u;
                continue;
            }
            let w = slot_word(u32(slot));
            if !add_count(w + 1u, axis) {
                count_overflow += 1u;
            }
            atomicAdd(&table[w + 2u + axis], q);
            for (var k = 0u; k < 3u; k++) {
                atomicAdd(&table[w + 5u + k], bitcast<u32>(n[k]));
            }
            count += 1u;
        }
    }
    if count > 0u {
        atomicAdd(&counters[counter_word(j, C_FRAGS + axis)], count);
    }
    if overflow > 0u {
        atomicAdd(&counters[counter_word(j, C_OVERFLOW)], overflow);
    }
    if count_overflow > 0u {
        atomicAdd(&counters[counter_word(j, C_COUNT_OVERFLOW)], count_overflow);
    }
}
