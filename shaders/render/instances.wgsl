// The rendering experiment of `terrastream eval` (client::instances): N×N instances of one
// model, each drawn at a level (the mesh, or a point level as oriented splats).
// Bindings:
//   group 0, binding 0: Globals (uniform) — view-projection (world relative to the origin),
//                       light direction, viewport (width px, height px, k = pixels per world
//                       unit at unit view depth, unused)
//   group 0, binding 1: offsets (storage, read) — one vec4 per instance (xyz: translation),
//                       indexed by instance_index (draws pass first_instance to pick a range)
//   group 1, binding 0: points (storage, read) — vs_points only: two vec4 per point
//                       (position xyz, normal xyz)
//   group 1, binding 1: Level (uniform) — vs_points only: cell edge in world units and
//                       footprint half-width in cells
// Vertex buffers (vs_mesh only): location 0 = position (vec3<f32>), location 1 = normal.

struct Globals {
    view_proj: mat4x4<f32>,
    light: vec4<f32>,
    viewport: vec4<f32>,
};

struct Point {
    p: vec4<f32>,
    n: vec4<f32>,
};

struct Level {
    spacing: f32,
    half: f32,
    pad1: f32,
    pad2: f32,
};

@group(0) @binding(0) var<uniform> g: Globals;
@group(0) @binding(1) var<storage, read> offsets: array<vec4<f32>>;
@group(1) @binding(0) var<storage, read> points: array<Point>;
@group(1) @binding(1) var<uniform> level: Level;

struct VOut {
    @builtin(position) pos: vec4<f32>,
    @location(0) normal: vec3<f32>,
    // Offset in a point's footprint cube (splat.wgsl); zero for meshes.
    @location(1) uv: vec3<f32>,
};

@vertex
fn vs_mesh(@builtin(instance_index) ii: u32, @location(0) p: vec3<f32>, @location(1) n: vec3<f32>) -> VOut {
    var out: VOut;
    out.pos = g.view_proj * vec4<f32>(p + offsets[ii].xyz, 1.0);
    out.normal = n;
    out.uv = vec3<f32>(0.0);
    return out;
}

// Six vertices per point form its oriented splat (`splat_corner` in splat.wgsl), as the
// client's point pipeline (render_points.wgsl) draws it.
@vertex
fn vs_points(@builtin(vertex_index) vi: u32, @builtin(instance_index) ii: u32) -> VOut {
    var corners = array<vec2<f32>, 6>(
        vec2<f32>(-1.0, -1.0), vec2<f32>(1.0, -1.0), vec2<f32>(1.0, 1.0),
        vec2<f32>(-1.0, -1.0), vec2<f32>(1.0, 1.0), vec2<f32>(-1.0, 1.0),
    );
    let pt = points[vi / 6u];
    var out: VOut;
    let unbounded = vec4<f32>(-3.0e38, -3.0e38, 3.0e38, 3.0e38);
    let s = splat_corner(g.view_proj, g.viewport, pt.p.xyz + offsets[ii].xyz, pt.n.xyz, level.spacing, level.half, unbounded, corners[vi % 6u]);
    out.pos = s.pos;
    out.uv = s.uv;
    out.normal = pt.n.xyz;
    return out;
}

@fragment
fn fs_main(v: VOut) -> @location(0) vec4<f32> {
    if (max(abs(v.uv.x), max(abs(v.uv.y), abs(v.uv.z))) > 1.0) {
        discard;
    }
    let n = normalize(v.normal);
    let shade = 0.25 + 0.75 * abs(dot(n, normalize(g.light.xyz)));
    return vec4<f32>(shade * vec3<f32>(0.85, 0.80, 0.70), 1.0);
}
