// Point pipeline: one instance per point, six vertices per instance forming the point's oriented
// splat (`splat_corner` in splat.wgsl; WebGPU points are one pixel).

@vertex
fn vs_main(@builtin(vertex_index) vi: u32, @location(0) p: vec3<f32>, @location(1) n: vec3<f32>) -> VOut {
    var corners = array<vec2<f32>, 6>(
        vec2<f32>(-1.0, -1.0), vec2<f32>(1.0, -1.0), vec2<f32>(1.0, 1.0),
        vec2<f32>(-1.0, -1.0), vec2<f32>(1.0, 1.0), vec2<f32>(-1.0, 1.0),
    );
    var out: VOut;
    let s = splat_corner(g.view_proj, g.viewport, p, n, tile.spacing, tile.half, tile.extent, corners[vi]);
    out.pos = s.pos;
    out.uv = s.uv;
    out.normal = n;
    return out;
}
