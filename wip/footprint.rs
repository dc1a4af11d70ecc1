//! How a point of a level is drawn, which its measured error covers: the point's tangent plane
//! clipped to the cube of half-width [`FOOTPRINT_HALF`] cells centred on it. The render shaders
//! (`shaders/render/splat.wgsl`) draw exactly this; [`super::cpu::measure_points`] measures it.

use glam::DVec3;

/// Half-width of a point's footprint cube, in cells. Points lie about a cell apart (each at the
/// mean of the surface it sampled in its cell), so ½ would tile a flat, axis-aligned surface
/// exactly; where neighbours sit off their cells' centres, or a cell the surface only clips
/// got no point, the footprints must reach further. Chosen on the development data (six
/// models and a terrain; cube clip, 1 px threshold): at 0.55 the terrain's far views lost up
/// to 5 % recall to cracks, at 0.65 the models' coarsest levels lost precision; 0.6 held both.
/// The shader's `FOOTPRINT_HALF` holds the same number (checked by a test).
pub const FOOTPRINT_HALF: f64 = 0.6;

/// Corners of the footprint of point `p` with normal `n` (any length) for a level of cell edge
/// `cell`: where its tangent plane crosses the 12 edges of the cube `p ± FOOTPRINT_HALF·cell`.
/// None for a zero or non-finite normal (drawn as a half-pixel dot at `p`).
pub(crate) fn footprint_corners(p: DVec3, n: DVec3, cell: f64, out: &mut Vec<DVec3>) {
    out.clear();
    if !n.is_finite() || n.abs().max_element() < 1e-6 || !(cell > 0.0) {
        return;
    }
    let n = n.normalize();
    let h = FOOTPRINT_HALF * cell;
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
        footprint_corners(p, DVec3::Z, 2.0, &mut c);
        assert_eq!(c.len(), 4);
        let h = FOOTPRINT_HALF * 2.0;
        for x in &c {
            assert!((x.z - 0.9).abs() < 1e-12);
            assert!(((x.x - p.x).abs() - h).abs() < 1e-12 && ((x.y - p.y).abs() - h).abs() < 1e-12, "{x:?}");
        }
        let n = DVec3::new(1.0, 2.0, 0.5);
        footprint_corners(p, n, 2.0, &mut c);
        assert!((3..=6).contains(&c.len()), "{c:?}");
        for x in &c {
            assert!((*x - p).dot(n).abs() < 1e-9);
            assert!((*x - p).abs().max_element() <= h + 1e-9);
        }
        footprint_corners(p, DVec3::ZERO, 2.0, &mut c);
        assert!(c.is_empty());
        footprint_corners(p, DVec3::Z, 0.0, &mut c);
        assert!(c.is_empty());
    }

    #[test]
    fn the_shader_draws_the_footprint_measured() {
        let src = include_str!("../../shaders/render/splat.wgsl");
        let line = format!("const FOOTPRINT_HALF: f32 = {FOOTPRINT_HALF};");
        assert!(src.contains(&line), "splat.wgsl must declare `{line}`");
    }
}
