// Oriented point splats, shared by the client's point pipeline (points.wgsl) and the
// evaluation's instances (instances.wgsl).
//
// A point stands for the patch of surface in its slicing cell, and is drawn as its tangent plane
// (through `p`, normal to `n`) clipped to the cube of half-width `half` cells centred on it (the
// level's `footprint_half` in the manifest, which the bake's error measure used). Points lie about a cell apart, so the footprints cover the surface; the cube, unlike
// a disc lifted onto the plane, keeps a footprint within a cell's reach of its point whatever
// its slope, so silhouettes grow by what the measured error says and no more, and a footprint
// seen edge-on thins to a line. The quad spans the cube across the two axes the normal is least
// aligned with, lifted onto the plane; fragments outside the cube are discarded. A terrain's
// footprints are clipped to its horizontal extent (its surface does not go on past the
// raster). Footprints are never enlarged to a pixel: they cover the surface, so a pixel centre
// on the surface falls inside one of them however small they are (drawing at least a pixel per
// point cost precision 0.01-0.02 on the development models' far views).

struct Splat {
    // Clip position of the corner.
    pos: vec4<f32>,
    // Offset from the point in units of the footprint's half-width (fragments outside the unit
    // cube are discarded), or zero for the half-pixel dot of a point without a normal (kept
    // whole). The fragment stages discard `max(|uv|) > 1`.
    uv: vec3<f32>,
};

// Corner `corner` (each component ±1) of the footprint of point `p` (world, relative to the
// origin) with unit normal `n`, for a level of cell edge `cell` and footprint half-width `half`
// (in cells). `viewport` = (width px,
// height px, pixels per world unit at unit view depth, unused); `extent` = (min x, min y,
// max x, max y) the corners are clamped to horizontally (unbounded for a model).
fn splat_corner(view_proj: mat4x4<f32>, viewport: vec4<f32>, p: vec3<f32>, n: vec3<f32>, cell: f32, half: f32, extent: vec4<f32>, corner: vec2<f32>) -> Splat {
    let a = abs(n);
    if (max(a.x, max(a.y, a.z)) < 1e-6 || cell * half <= 0.0) {
        let c = view_proj * vec4<f32>(p, 1.0);
        let off = corner * 0.5 * 2.0 / viewport.xy * c.w;
        return Splat(vec4<f32>(c.xy + off, c.z, c.w), vec3<f32>(0.0));
    }
    let h = half * cell;
    let du = corner.x * h;
    let dv = corner.y * h;
    var d: vec3<f32>;
    if (a.z >= a.x && a.z >= a.y) {
        d = vec3<f32>(du, dv, -(n.x * du + n.y * dv) / n.z);
    } else if (a.y >= a.x) {
        d = vec3<f32>(du, -(n.x * du + n.z * dv) / n.y, dv);
    } else {
        d = vec3<f32>(-(n.y * du + n.z * dv) / n.x, du, dv);
    }
    let q = p + d;
    let qc = vec3<f32>(clamp(q.xy, extent.xy, extent.zw), q.z);
    return Splat(view_proj * vec4<f32>(qc, 1.0), (qc - p) / h);
}
