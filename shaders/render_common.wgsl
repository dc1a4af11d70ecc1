// Shared by the client's render pipelines (render_mesh.wgsl, render_points.wgsl).
// Bindings:
//   group 0, binding 0: Globals (uniform) — view-projection (world relative to the tileset
//                       origin), light direction, viewport (width px, height px, k = pixels
//                       per world unit at unit view depth, unused)
//   group 1, binding 0: Tile (uniform) — point spacing in world units (points only)
// Vertex buffers: location 0 = position (vec3<f32>, relative to the origin), location 1 =
// unit normal (vec3<f32>); per vertex for meshes, per instance for points.

struct Globals {
    view_proj: mat4x4<f32>,
    light: vec4<f32>,
    viewport: vec4<f32>,
};

struct Tile {
    spacing: f32,
    pad0: f32,
    pad1: f32,
    pad2: f32,
};

@group(0) @binding(0) var<uniform> g: Globals;
@group(1) @binding(0) var<uniform> tile: Tile;

struct VOut {
    @builtin(position) pos: vec4<f32>,
    @location(0) normal: vec3<f32>,
};

@fragment
fn fs_main(v: VOut) -> @location(0) vec4<f32> {
    // Lambert with an ambient floor; normals flipped to face up (terrain is seen from above).
    var n = normalize(v.normal);
    if (n.z < 0.0) {
        n = -n;
    }
    let shade = 0.25 + 0.75 * max(dot(n, normalize(g.light.xyz)), 0.0);
    return vec4<f32>(shade * vec3<f32>(0.85, 0.80, 0.70), 1.0);
}
