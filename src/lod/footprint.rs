//! How a point of a level is drawn, which its measured error covers: the point's tangent plane
//! clipped to the cube of half-width `half` cells centred on it, `half` recorded per level in
//! the manifest (`footprint_half`). The render shaders (`shaders/render/splat.wgsl`) draw
//! exactly this; [`super::measure::measure_points`] measures it.

use glam::DVec3;

/// Half-width, in cells, of a model point level's footprint cube. Points lie about a cell
/// apart (each at the mean of the surface it sampled in its cell), so ½ would tile a flat,
/// axis-aligned surface exactly; where neighbours sit off their cells' centres, or a cell the
/// surface only clips got no point, footprints must reach further, and every bit further
/// grows a model's silhouettes. Chosen on the development models (cube clip, 1 px threshold):
/// 0.55 lost up to 0.5 % recall to cracks, 0.65–0.7 lost precision at the far views
/// (rocker-arm 0.968 / 0.963 at 8×); 0.6 held both.
pub const MODEL_FOOTPRINT_HALF: f64 = 0.6;

/// Half-width, in cells, of a terrain point level's footprint cube. A coarse level of rough
/// terrain has noisy normals and cells its surface only clips, and a heightfield seen from
/// above has few silhouettes to grow, so coverage decides: on the render test's terrain frames
/// (levels 1–2 at 8–16 px) 0.6 left 2.5 % of the terrain pixels empty, 0.75 0.6 %, 0.9
/// 0.09–0.19 % (the earlier discs of radius one cell: 0.12–0.26 %).
pub const TERRAIN_FOOTPRINT_HALF: f64 = 0.9;

/// Corners of the footprint of point `p` with normal `n` (any length) and half-width `h`
/// (world units): where its tangent plane crosses the 12 edges of the cube `p ± h`. None for a
/// zero or non-finite normal (drawn as a half-pixel dot at `p`).
pub(crate) fn footprint_corners(p: DVec3, n: DVec3, h: f64, out: &mut Vec<DVec3>) {
    out.clear();
    if !n.is_finite() || n.abs().max_element() < 1e-6 || h.is_nan() || h <= 0.0 {
        return;
    }
    let n = n.normalize();
    for a in 0..3 {
        if n[a].abs() < 1e-12 {
            continue;
        }
        let (b, d) = ((a + 1) % 3, (a + 2) % 3);
        for (sb, sd) in [(-1.0, -1.0), (1.0, -1.0), (-1.0, 1.0), (1.0, 1.0)] {
            let mut e = DVec3::ZERO;
            e[b] = sb * h;
            e[d] = sd * h;
            e[a] = -(n[b] * e[b] + n[d] * e[d]) / n[a];
            if e[a].abs() <= h * (1.0 + 1e-12) {
                out.push(p + e);
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn footprints_are_the_tangent_plane_inside_the_cube() {
        let mut c = Vec::new();
        let p = DVec3::new(0.3, 1.7, 0.9);
        let h = 1.2;
        footprint_corners(p, DVec3::Z, h, &mut c);
        assert_eq!(c.len(), 4);
        for x in &c {
            assert!((x.z - 0.9).abs() < 1e-12);
            assert!(((x.x - p.x).abs() - h).abs() < 1e-12 && ((x.y - p.y).abs() - h).abs() < 1e-12, "{x:?}");
        }
        let n = DVec3::new(1.0, 2.0, 0.5);
        footprint_corners(p, n, h, &mut c);
        assert!((3..=6).contains(&c.len()), "{c:?}");
        for x in &c {
            assert!((*x - p).dot(n).abs() < 1e-9);
            assert!((*x - p).abs().max_element() <= h + 1e-9);
        }
        footprint_corners(p, DVec3::ZERO, h, &mut c);
        assert!(c.is_empty());
        footprint_corners(p, DVec3::Z, 0.0, &mut c);
        assert!(c.is_empty());
    }
}
