// Shared by the client's render pipelines (render_mesh.wgsl, render_points.wgsl, which also
// takes splat.wgsl).
// Bindings:
//   group 0, binding 0: Globals (uniform) — view-projection (world relative to the tileset
//                       origin), light direction, viewport (width px, height px, k = pixels
//                       per world unit at unit view depth, unused)
//   group 1, binding 0: Tile (uniform) — a point level's cell edge in world units and
//                       footprint half-width in cells, and the dataset's horizontal extent
//                       (points only)
//   group 2, binding 0: Draw (uniform, dynamic offset per draw) — fade alpha and whether the
//                       tile is retiring (fading out)
// Vertex buffers: location 0 = position (vec3<f32>, relative to the origin), location 1 =
// unit normal (vec3<f32>); per vertex for meshes, per instance for points.

struct Globals {
    view_proj: mat4x4<f32>,
    light: vec4<f32>,
    viewport: vec4<f32>,
};

struct Tile {
    // Points: the level's cell edge (world units) and footprint half-width (cells).
    spacing: f32,
    half: f32,
    pad1: f32,
    pad2: f32,
    // The dataset's horizontal extent (min x, min y, max x, max y) splats are clipped to.
    extent: vec4<f32>,
};

@group(0) @binding(0) var<uniform> g: Globals;
struct Draw {
    alpha: f32,
    retiring: f32,
    pad0: f32,
    pad1: f32,
};

@group(1) @binding(0) var<uniform> tile: Tile;
@group(2) @binding(0) var<uniform> draw: Draw;

struct VOut {
    @builtin(position) pos: vec4<f32>,
    @location(0) normal: vec3<f32>,
    // Offset in a point's footprint cube (splat.wgsl); zero for meshes.
    @location(1) uv: vec3<f32>,
};

// Screen-door fade: a 4×4 ordered-dither threshold per pixel. A tile fading in keeps the
// pixels whose threshold is below its alpha, the tile it replaces (alpha 1 − a) those at or
// above it, so during a fade every pixel shows exactly one of the two (no blending, no sort,
// no hole).
fn dither(p: vec2<f32>) -> f32 {
    var bayer = array<f32, 16>(0.0, 8.0, 2.0, 10.0, 12.0, 4.0, 14.0, 6.0, 3.0, 11.0, 1.0, 9.0, 15.0, 7.0, 13.0, 5.0);
    let i = (u32(p.y) % 4u) * 4u + u32(p.x) % 4u;
    return (bayer[i] + 0.5) / 16.0;
}

@fragment
fn fs_main(v: VOut) -> @location(0) vec4<f32> {
    let d = dither(v.pos.xy);
    if (max(abs(v.uv.x), max(abs(v.uv.y), abs(v.uv.z))) > 1.0 || (draw.retiring > 0.5 && d < 1.0 - draw.alpha) || (draw.retiring <= 0.5 && d >= draw.alpha)) {
        discard;
    }
    // Lambert with an ambient floor; normals flipped to face up (terrain is seen from above).
    var n = normalize(v.normal);
    if (n.z < 0.0) {
        n = -n;
    }
    let shade = 0.25 + 0.75 * max(dot(n, normalize(g.light.xyz)), 0.0);
    return vec4<f32>(shade * vec3<f32>(0.85, 0.80, 0.70), 1.0);
}
