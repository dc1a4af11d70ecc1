//! CPU reference of the 6-direction orthographic slicing (CONTRACT STUB).

use crate::geom::{Bounds, Errors, Mesh, PointCloud};

/// Bakes one point level of `mesh` on a cubic cell grid of edge `cell` anchored at
/// `grid_origin`.
#[must_use]
pub fn bake_points(_mesh: &Mesh, _grid_origin: [f64; 3], _cell: f64) -> PointCloud {
    PointCloud::default()
}

/// Measures a point level against the mesh it was baked from.
#[must_use]
pub fn measure_points(_mesh: &Mesh, _points: &PointCloud, _cell: f64) -> Errors {
    Errors::default()
}

#[allow(dead_code)]
fn _bounds(_: Bounds) {}
