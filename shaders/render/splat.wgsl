// Oriented point splats, shared by the client's point pipeline (render_points.wgsl) and the
// evaluation's instances (eval_instances.wgsl).
//
// A point stands for the patch of surface in its slicing cell. Its splat lies in the point's
// tangent plane (through `p`, normal to `n`): a disc of radius one spacing across the two axes
// the normal is least aligned with (the footprint the slicing sampled along the third axis),
// lifted onto the plane, so that, wherever two adjacent points lie in their cells, their splats
// meet across the shared cell face. Seen along that axis it is the sampled footprint; seen
// edge-on it thins to a line, so splats follow the surface and silhouettes do not grow by a
// splat's radius as screen-aligned squares do. The dominant component of a unit normal is at
// least 1/√3, so the lift is bounded. A terrain's splats are clipped to its horizontal extent
// (its surface does not go on past the raster). Where the splat would be under a pixel, a
// screen-aligned half-pixel quad is drawn instead so the rasterizer never drops distant points.

struct Splat {
    // Clip position of the corner.
    pos: vec4<f32>,
    // Position in the footprint disc (unit radius; fragments outside it are discarded), or
    // zero for the half-pixel fallback (kept whole). The fragment stages discard `|uv| > 1`.
    uv: vec2<f32>,
};

// Corner `corner` (each component ±1) of the splat of point `p` (world, relative to the origin)
// with unit normal `n`, for points `spacing` world units apart. `viewport` = (width px,
// height px, pixels per world unit at unit view depth, unused); `extent` = (min x, min y,
// max x, max y) the corners are clamped to horizontally (unbounded for a model).
fn splat_corner(view_proj: mat4x4<f32>, viewport: vec4<f32>, p: vec3<f32>, n: vec3<f32>, spacing: f32, extent: vec4<f32>, corner: vec2<f32>) -> Splat {
    let c = view_proj * vec4<f32>(p, 1.0);
    let r_px = spacing * viewport.z / max(c.w, 1e-6);
    let a = abs(n);
    if (r_px < 0.5 || max(a.x, max(a.y, a.z)) < 1e-6) {
        let off = corner * 0.5 * 2.0 / viewport.xy * c.w;
        return Splat(vec4<f32>(c.xy + off, c.z, c.w), vec2<f32>(0.0));
    }
    let du = corner.x * spacing;
    let dv = corner.y * spacing;
    var d: vec3<f32>;
    if (a.z >= a.x && a.z >= a.y) {
        d = vec3<f32>(du, dv, -(n.x * du + n.y * dv) / n.z);
    } else if (a.y >= a.x) {
        d = vec3<f32>(du, -(n.x * du + n.z * dv) / n.y, dv);
    } else {
        d = vec3<f32>(-(n.y * du + n.z * dv) / n.x, du, dv);
    }
    let q = p + d;
    return Splat(view_proj * vec4<f32>(clamp(q.xy, extent.xy, extent.zw), q.z, 1.0), corner);
}

