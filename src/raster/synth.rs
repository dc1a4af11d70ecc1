//! Deterministic synthetic terrain: ridged multi-octave value noise with domain warping, so
//! tests, benchmarks and the demo have realistic-looking terrain of any size without shipping
//! large files. Pure: the same (width, height, seed) always gives the same heights.

/// Heights in metres (about 0 to 2500) for a `width × height` raster, row-major.
#[must_use]
pub fn terrain(width: u32, height: u32, seed: u64) -> Vec<f32> {
    let mut out = Vec::with_capacity(width as usize * height as usize);
    for r in 0..height {
        for c in 0..width {
            out.push(height_at(width, height, seed, c, r));
        }
    }
    out
}

/// Sample (`col`, `row`) of [`terrain`]`(width, height, seed)`, alone: what lets a generator
/// write a raster larger than memory tile by tile.
#[must_use]
pub fn height_at(width: u32, height: u32, seed: u64, col: u32, row: u32) -> f32 {
    // Features scale with the raster so any size shows mountains, valleys and fine detail.
    let scale = 1.0 / f64::from(width.max(height).max(2) - 1);
    let (x, y) = (f64::from(col) * scale, f64::from(row) * scale);
    let wx = x + 0.15 * fbm(x * 3.0, y * 3.0, seed ^ 0xA5A5, 3);
    let wy = y + 0.15 * fbm(x * 3.0 + 5.2, y * 3.0 + 1.3, seed ^ 0x5A5A, 3);
    let ridges = ridged(wx * 4.0, wy * 4.0, seed, 7);
    let base = 0.5 + 0.5 * fbm(x * 1.5, y * 1.5, seed ^ 0x1234, 2);
    (2500.0 * base * ridges) as f32
}

fn hash(ix: i64, iy: i64, seed: u64) -> f64 {
    let mut h = seed
        ^ (ix as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15)
        ^ (iy as u64).wrapping_mul(0xC2B2_AE3D_27D4_EB4F);
    h ^= h >> 33;
    h = h.wrapping_mul(0xFF51_AFD7_ED55_8CCD);
    h ^= h >> 33;
    (h >> 11) as f64 / (1u64 << 53) as f64
}

/// Smooth value noise in [0, 1].
fn value_noise(x: f64, y: f64, seed: u64) -> f64 {
    let (fx, fy) = (x.floor(), y.floor());
    let (ix, iy) = (fx as i64, fy as i64);
    let (tx, ty) = (x - fx, y - fy);
    let s = |t: f64| t * t * t * (t * (t * 6.0 - 15.0) + 10.0);
    let (sx, sy) = (s(tx), s(ty));
    let a = hash(ix, iy, seed);
    let b = hash(ix + 1, iy, seed);
    let c = hash(ix, iy + 1, seed);
    let d = hash(ix + 1, iy + 1, seed);
    let top = a + (b - a) * sx;
    let bottom = c + (d - c) * sx;
    top + (bottom - top) * sy
}

/// Fractal sum in about [-1, 1].
fn fbm(x: f64, y: f64, seed: u64, octaves: u32) -> f64 {
    let (mut sum, mut amp, mut freq, mut norm) = (0.0, 1.0, 1.0, 0.0);
    for o in 0..octaves {
        sum += amp * (2.0 * value_noise(x * freq, y * freq, seed.wrapping_add(u64::from(o))) - 1.0);
        norm += amp;
        amp *= 0.5;
        freq *= 2.03;
    }
    sum / norm
}

/// Ridged fractal in [0, 1]: sharp crests where the noise crosses its midpoint.
fn ridged(x: f64, y: f64, seed: u64, octaves: u32) -> f64 {
    let (mut sum, mut amp, mut freq, mut norm, mut weight) = (0.0, 1.0, 1.0, 0.0, 1.0);
    for o in 0..octaves {
        let n =
            1.0 - (2.0 * value_noise(x * freq, y * freq, seed.wrapping_add(101 + u64::from(o))) - 1.0).abs();
        let n = n * n * weight;
        weight = n.clamp(0.0, 1.0);
        sum += amp * n;
        norm += amp;
        amp *= 0.5;
        freq *= 2.1;
    }
    sum / norm
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn deterministic_finite_and_varied() {
        let a = terrain(65, 33, 1);
        assert_eq!(a, terrain(65, 33, 1));
        assert_ne!(a, terrain(65, 33, 2));
        assert!(a.iter().all(|v| v.is_finite() && *v >= 0.0 && *v <= 2500.0));
        let (lo, hi) = a.iter().fold((f32::MAX, f32::MIN), |(l, h), &v| (l.min(v), h.max(v)));
        assert!(hi - lo > 100.0, "range {lo}..{hi}");
    }
}
