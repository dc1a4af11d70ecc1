// Point pipeline: one instance per point, six vertices per instance forming a screen-aligned
// quad (WebGPU points are one pixel). The quad's half-size in pixels is the level's point spacing
// times √2/2 (half a cell's diagonal: a point lies anywhere in its slicing cell, not at its
// centre) projected at the point's view depth (clip w), at least half a pixel.

@vertex
fn vs_main(@builtin(vertex_index) vi: u32, @location(0) p: vec3<f32>, @location(1) n: vec3<f32>) -> VOut {
    var corners = array<vec2<f32>, 6>(
        vec2<f32>(-1.0, -1.0), vec2<f32>(1.0, -1.0), vec2<f32>(1.0, 1.0),
        vec2<f32>(-1.0, -1.0), vec2<f32>(1.0, 1.0), vec2<f32>(-1.0, 1.0),
    );
    let c = g.view_proj * vec4<f32>(p, 1.0);
    let r_px = max(0.70710678 * tile.spacing * g.viewport.z / max(c.w, 1e-6), 0.5);
    let off = corners[vi] * r_px * 2.0 / g.viewport.xy * c.w;
    var out: VOut;
    out.pos = vec4<f32>(c.xy + off, c.z, c.w);
    out.normal = n;
    return out;
}
