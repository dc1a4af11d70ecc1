//! Camera placement: spheres of cameras around a tileset's bounds (see the module doc above),
//! and the instance experiment's grid of copies with its camera and per-copy level choice.

use super::*;

/// Where the evaluation cameras go and what they see.
#[derive(Debug, Clone, PartialEq)]
pub struct CameraPlan {
    pub width: u32,
    pub height: u32,
    pub fov_deg: f64,
    pub distances: Vec<f64>,
    pub azimuths: u32,
    pub elevations: Vec<f64>,
}

/// One evaluation camera and its place on the sphere.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct EvalCamera {
    pub camera: Camera,
    /// Multiple of the fit distance.
    pub distance_factor: f64,
    /// World distance from the eye to the sphere's centre.
    pub distance: f64,
    pub azimuth_deg: f64,
    pub elevation_deg: f64,
    /// Clip planes that hold the whole bounding sphere (near as close as it allows, for depth
    /// precision).
    pub near: f64,
    pub far: f64,
}

/// Centre and radius (half the box diagonal, at least 1e-9) of the bounds' sphere.
#[must_use]
pub fn bounding_sphere(b: &Bounds) -> (DVec3, f64) {
    (b.center(), (0.5 * b.size().length()).max(1e-9))
}

/// The distance at which a sphere of radius `r` just fills the narrower field of view.
#[must_use]
pub fn fit_distance(r: f64, width: u32, height: u32, fov_deg: f64) -> f64 {
    let tan_h = (fov_deg.to_radians() * 0.5).tan();
    let tan_v = tan_h * f64::from(height) / f64::from(width.max(1));
    let half = tan_h.min(tan_v).atan();
    r / half.sin()
}

/// A camera plan [`cameras`] refuses, naming the setting.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum PlanError {
    #[error("bounds {min:?}..{max:?} are empty or not finite")]
    Bounds { min: [f64; 3], max: [f64; 3] },
    #[error("viewport {width}×{height} is empty")]
    Viewport { width: u32, height: u32 },
    #[error("fov {0} is not between 0 and 180 degrees")]
    Fov(f64),
    #[error("distances {0:?} must be positive multiples of the fit distance")]
    Distances(Vec<f64>),
    #[error("azimuths must be 1 or more")]
    Azimuths,
    #[error("elevations {0:?} must lie strictly between -89 and 89 degrees")]
    Elevations(Vec<f64>),
}

/// Cameras for every (distance, elevation, azimuth), all looking at the sphere's centre with the
/// polar axis up. Errors name the bad setting.
pub fn cameras(bounds: &Bounds, subject: Subject, plan: &CameraPlan) -> Result<Vec<EvalCamera>, PlanError> {
    if !bounds.is_valid() {
        return Err(PlanError::Bounds { min: bounds.min.to_array(), max: bounds.max.to_array() });
    }
    if plan.width == 0 || plan.height == 0 {
        return Err(PlanError::Viewport { width: plan.width, height: plan.height });
    }
    if !(plan.fov_deg > 0.0 && plan.fov_deg < 180.0) {
        return Err(PlanError::Fov(plan.fov_deg));
    }
    if plan.distances.is_empty() || plan.distances.iter().any(|d| !(d.is_finite() && *d > 0.0)) {
        return Err(PlanError::Distances(plan.distances.clone()));
    }
    if plan.azimuths == 0 {
        return Err(PlanError::Azimuths);
    }
    if plan.elevations.is_empty() || plan.elevations.iter().any(|e| e.is_nan() || e.abs() >= 89.0) {
        return Err(PlanError::Elevations(plan.elevations.clone()));
    }
    let (c, r) = bounding_sphere(bounds);
    let fit = fit_distance(r, plan.width, plan.height, plan.fov_deg);
    let (pole, u1, u2) = subject.axes();
    let mut out = Vec::new();
    for &f in &plan.distances {
        let d = f * fit;
        for &el in &plan.elevations {
            for i in 0..plan.azimuths {
                let az = 360.0 * f64::from(i) / f64::from(plan.azimuths);
                let (sa, ca) = az.to_radians().sin_cos();
                let (se, ce) = el.to_radians().sin_cos();
                let dir = ((u1 * (ce * ca)) + (u2 * (ce * sa))) + (pole * se);
                let eye = c + (dir * d);
                out.push(EvalCamera {
                    camera: Camera {
                        eye,
                        target: c,
                        up: pole,
                        width: plan.width,
                        height: plan.height,
                        fov_deg: plan.fov_deg,
                    },
                    distance_factor: f,
                    distance: d,
                    azimuth_deg: az,
                    elevation_deg: el,
                    near: (d - 1.05 * r).max(d * 1e-3),
                    far: d + 1.05 * r,
                });
            }
        }
    }
    Ok(out)
}

/// Chooses a level for an object at `dist` whose levels have the geometric errors `errors` and
/// the costs `costs` (by level id, finest first; an absent level's error is infinite): the
/// cheapest with `e · k / dist ≤ threshold` (a tie to the coarser), else level 0 — the
/// selection's rule for one node.
#[must_use]
pub fn level_for(
    errors: &[f64],
    costs: &[crate::client::tree::LevelCost],
    k: f64,
    dist: f64,
    threshold_px: f64,
) -> usize {
    let allowed = threshold_px * dist.max(1e-6) / k;
    (0..errors.len().min(costs.len()))
        .rev()
        .filter(|&l| errors[l] <= allowed)
        .min_by_key(|&l| costs[l])
        .unwrap_or(0)
}

/// Instance offsets of an `n × n` grid centred on the origin in the plane perpendicular to the
/// subject's polar axis, `spacing` apart.
#[must_use]
pub fn grid_offsets(n: u32, spacing: f64, subject: Subject) -> Vec<[f64; 3]> {
    let (_, u1, u2) = subject.axes();
    let half = f64::from(n.saturating_sub(1)) * 0.5;
    let mut out = Vec::with_capacity((n as usize) * (n as usize));
    for j in 0..n {
        for i in 0..n {
            let a = (f64::from(i) - half) * spacing;
            let b = (f64::from(j) - half) * spacing;
            out.push((u1 * a + u2 * b).to_array());
        }
    }
    out
}

/// The camera that sees a whole `n × n` grid of objects with bounding sphere `(c, r)`, from
/// the fit distance of the grid's sphere at [`GRID_ELEVATION_DEG`].
#[must_use]
// The camera needs the grid (n, spacing, subject), the object's sphere and the viewport.
#[allow(clippy::too_many_arguments)]
pub fn grid_camera(
    c: DVec3,
    r: f64,
    n: u32,
    spacing: f64,
    subject: Subject,
    w: u32,
    h: u32,
    fov: f64,
) -> EvalCamera {
    let half_extent = f64::from(n.saturating_sub(1)) * 0.5 * spacing;
    let grid_r = (2.0f64.sqrt() * half_extent + r).max(r);
    let d = fit_distance(grid_r, w, h, fov);
    let (pole, u1, _) = subject.axes();
    let (se, ce) = GRID_ELEVATION_DEG.to_radians().sin_cos();
    let eye = c + ((u1 * (-ce * d)) + (pole * (se * d)));
    EvalCamera {
        camera: Camera { eye, target: c, up: pole, width: w, height: h, fov_deg: fov },
        distance_factor: 1.0,
        distance: d,
        azimuth_deg: 180.0,
        elevation_deg: GRID_ELEVATION_DEG,
        near: (d - 1.05 * grid_r).max(d * 1e-3),
        far: d + 1.05 * grid_r,
    }
}
