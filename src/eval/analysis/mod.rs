//! The first paper's evaluation (section 4.6), pure parts: camera positions on spheres around a
//! tileset's bounds, per-pixel coverage comparison (TP, FP, FN → recall, precision, F-measure),
//! depth differences, aggregation by distance and level, the instance grid of the rendering
//! experiment, the Markdown report and its PNG charts (drawn with `image`, no fonts).
//!
//! Files: `cameras` (placement, the instance grid), `coverage` (per-pixel metrics, depth,
//! aggregation), `report` (results, Markdown), `charts` (PNG charts), [`paper`] (the first
//! paper's published tables, printed beside ours).
//!
//! No GPU and no file system here: [`crate::eval`] renders and writes, this module only
//! computes on values, so every rule is unit-tested.
//!
//! Camera placement: the tileset's bounding sphere (centre `c`, radius `r` = half the box
//! diagonal) is seen from `d = f · d_fit` for each distance factor `f`, where
//! `d_fit = r / sin(φ_min/2)` is the distance at which the sphere just fills the narrower field
//! of view; directions are the two sphere angles, azimuth (evenly spread over 360°) and
//! elevation (a list). Terrain is seen from above (elevations 20°, 45°, 70° about +Z); models
//! from below, level and above (−45°, 0°, 45° about +Y, the Stanford models' up axis).

use std::fmt::Write as _;

use crate::client::select::Camera;
use crate::geom::Bounds;
use glam::DVec3;

/// Distance factors (multiples of the fit distance) at which cameras are placed.
pub const DEFAULT_DISTANCES: [f64; 5] = [0.5, 1.0, 2.0, 4.0, 8.0];
/// Azimuths per distance and elevation, evenly spread over 360°.
pub const DEFAULT_AZIMUTHS: u32 = 6;
/// Elevations (degrees above the horizontal plane) for terrain tilesets.
pub const TERRAIN_ELEVATIONS: [f64; 3] = [20.0, 45.0, 70.0];
/// Elevations (degrees) for model tilesets.
pub const MODEL_ELEVATIONS: [f64; 3] = [-45.0, 0.0, 45.0];
/// Viewport of the coverage renders.
pub const DEFAULT_EVAL_WIDTH: u32 = 512;
pub const DEFAULT_EVAL_HEIGHT: u32 = 384;
/// Grid sides N of the rendering experiment (N² = 121 … 6,561 instances, the paper's range).
pub const DEFAULT_GRID_SIDES: [u32; 4] = [11, 21, 41, 81];
/// Instance spacing in the grid, in multiples of the model's longest side.
pub const GRID_SPACING: f64 = 1.5;
/// Elevation (degrees) of the camera that sees the whole instance grid.
pub const GRID_ELEVATION_DEG: f64 = 35.0;

/// What a tileset holds; it decides the sphere's polar axis and default elevations.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Subject {
    Terrain,
    Model,
}

impl Subject {
    /// Unit polar axis and two unit axes spanning the plane perpendicular to it (right-handed).
    #[must_use]
    pub fn axes(self) -> (DVec3, DVec3, DVec3) {
        match self {
            Self::Terrain => (DVec3::Z, DVec3::X, DVec3::Y),
            Self::Model => (DVec3::Y, DVec3::Z, DVec3::X),
        }
    }

    #[must_use]
    pub fn default_elevations(self) -> Vec<f64> {
        match self {
            Self::Terrain => TERRAIN_ELEVATIONS.to_vec(),
            Self::Model => MODEL_ELEVATIONS.to_vec(),
        }
    }

    #[must_use]
    pub fn name(self) -> &'static str {
        match self {
            Self::Terrain => "terrain",
            Self::Model => "model",
        }
    }
}

mod cameras;
mod charts;
mod coverage;
pub mod paper;
mod report;

pub use cameras::*;
pub use charts::*;
pub use coverage::*;
pub use report::*;

#[cfg(test)]
#[allow(clippy::float_cmp)]
mod tests;
