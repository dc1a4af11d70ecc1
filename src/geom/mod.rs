//! Plain geometry values shared by every stage: bounds, triangle meshes, point clouds and the
//! measured errors that travel with them, normals and skirts (`skirts`). No I/O.

use glam::DVec3;
use serde::{Deserialize, Serialize};

mod skirts;

pub use skirts::{Skirted, add_skirts, skirt_depth};

/// Axis-aligned box in world units. Serialized as `{"min": [x, y, z], "max": [x, y, z]}`.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Bounds {
    pub min: DVec3,
    pub max: DVec3,
}

impl Bounds {
    /// The box from corner `min` to corner `max`, as vectors or as arrays (positions are
    /// arrays, see [`Mesh`]).
    #[must_use]
    pub fn new(min: impl Into<DVec3>, max: impl Into<DVec3>) -> Self {
        Self { min: min.into(), max: max.into() }
    }

    /// The empty box (min = +inf, max = -inf); `extend` grows it.
    #[must_use]
    pub fn empty() -> Self {
        Self { min: DVec3::INFINITY, max: DVec3::NEG_INFINITY }
    }

    /// Grows the box to hold `p` (a NaN coordinate leaves it as it was on that axis).
    pub fn extend(&mut self, p: impl Into<DVec3>) {
        let p = p.into();
        for a in 0..3 {
            self.min[a] = self.min[a].min(p[a]);
            self.max[a] = self.max[a].max(p[a]);
        }
    }

    /// The box around `points`; `empty()` for no points.
    #[must_use]
    pub fn of_points(points: &[[f64; 3]]) -> Self {
        let mut b = Self::empty();
        for &p in points {
            b.extend(p);
        }
        b
    }

    #[must_use]
    pub fn is_valid(&self) -> bool {
        (0..3).all(|a| self.min[a].is_finite() && self.max[a].is_finite() && self.min[a] <= self.max[a])
    }

    #[must_use]
    pub fn size(&self) -> DVec3 {
        self.max - self.min
    }

    #[must_use]
    pub fn center(&self) -> DVec3 {
        0.5 * (self.min + self.max)
    }
}

/// An indexed triangle mesh in world coordinates.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Mesh {
    pub positions: Vec<[f64; 3]>,
    pub triangles: Vec<[u32; 3]>,
}

/// A point cloud in world coordinates with one unit normal per point.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct PointCloud {
    pub positions: Vec<[f64; 3]>,
    pub normals: Vec<[f32; 3]>,
}

/// Error figures measured for one (tile, level), in world units (a value, not an error type).
///
/// For a mesh: `max`/`rms` are the vertical deviation from the full-resolution raster and `gap`
/// is 0. For points: `max`/`rms` are the distances from the points to the surface they were
/// baked from and `gap` is the largest distance from any surface point to its nearest point.
#[derive(
    Debug, Clone, Copy, Default, PartialEq, Serialize, Deserialize, bincode::Encode, bincode::Decode,
)]
pub struct ErrorFigures {
    pub max: f64,
    pub rms: f64,
    pub gap: f64,
}

impl ErrorFigures {
    /// The single geometric error a client uses for screen-space error: the worse of the
    /// deviation and the gap.
    #[must_use]
    pub fn geometric(&self) -> f64 {
        self.max.max(self.gap)
    }
}

/// Unit normal of triangle (a, b, c) by the right-hand rule; zero for a degenerate triangle.
#[must_use]
pub fn triangle_normal(a: [f64; 3], b: [f64; 3], c: [f64; 3]) -> [f64; 3] {
    let a = DVec3::from_array(a);
    let n = (DVec3::from_array(b) - a).cross(DVec3::from_array(c) - a);
    let len = n.length();
    // `/ len`, not `normalize()` (a multiply by 1/len): the point levels' normals are these
    // bytes, and the division is what they have always been.
    if len > 0.0 { (n / len).to_array() } else { [0.0; 3] }
}

/// Area-weighted vertex normals, unnormalized: per vertex the sum, in triangle order, of the
/// cross products of its triangles (each twice the triangle's area along its normal). The one
/// implementation behind model normals, rendered meshes and the instance experiment.
#[must_use]
pub fn vertex_normal_sums(positions: &[[f64; 3]], triangles: &[[u32; 3]]) -> Vec<DVec3> {
    let mut acc = vec![DVec3::ZERO; positions.len()];
    for t in triangles {
        let p = |i: u32| DVec3::from_array(positions[i as usize]);
        let c = (p(t[1]) - p(t[0])).cross(p(t[2]) - p(t[0]));
        for &i in t {
            acc[i as usize] += c;
        }
    }
    acc
}

/// `v / |v|` as f32, or `None` for a zero or non-finite vector.
#[must_use]
pub fn unit_f32(v: DVec3) -> Option<[f32; 3]> {
    let len = v.length();
    (len > 0.0 && len.is_finite()).then(|| (v / len).as_vec3().to_array())
}
