// Mesh pipeline: indexed triangles (a tile's TIN with its skirts), shaded by vertex normals.

@vertex
fn vs_main(@location(0) p: vec3<f32>, @location(1) n: vec3<f32>) -> VOut {
    var out: VOut;
    out.pos = g.view_proj * vec4<f32>(p, 1.0);
    out.normal = n;
    out.uv = vec3<f32>(0.0);
    return out;
}
