//! The perspective camera of selection, replay, rendering and evaluation: eye, target, up,
//! viewport and field of view, and the [`View`] (frustum planes and projection constants)
//! derived from it.

use crate::client::ClientError;
use crate::client::stream::flight_path::Pose;
use crate::geom::Bounds;
use glam::DVec3;

/// Smallest eye distance used in `e_scr`, so an eye at a sphere's centre gives a huge, finite error.
pub(crate) const MIN_DISTANCE: f64 = 1e-6;

/// A perspective camera: eye, look-at target, up direction, viewport in pixels and horizontal
/// field of view.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Camera {
    pub eye: DVec3,
    pub target: DVec3,
    pub up: DVec3,
    pub width: u32,
    pub height: u32,
    pub fov_deg: f64,
}

impl Camera {
    #[must_use]
    pub fn new(pose: &Pose, width: u32, height: u32, fov_deg: f64) -> Self {
        Self { eye: pose.eye, target: pose.target, up: pose.up, width, height, fov_deg }
    }

    /// The frustum and projection constants; errors name the bad field.
    pub fn view(&self) -> Result<View, ClientError> {
        let bad = |m: String| Err(ClientError::Camera(m));
        if self.width == 0 || self.height == 0 {
            return bad(format!("viewport {}×{} is empty", self.width, self.height));
        }
        if !(self.fov_deg > 0.0 && self.fov_deg < 180.0) {
            return bad(format!("fov {} is not between 0 and 180 degrees", self.fov_deg));
        }
        if !self.eye.is_finite() || !self.target.is_finite() || !self.up.is_finite() {
            return bad(format!(
                "eye {:?}, target {:?} or up {:?} is not finite",
                self.eye, self.target, self.up
            ));
        }
        let Some(forward) = (self.target - self.eye).try_normalize() else {
            return bad(format!("eye and target are the same point {:?}", self.eye));
        };
        let Some(right) = (forward.cross(self.up)).try_normalize().filter(|_| self.up.length() > 0.0) else {
            return bad(format!("up {:?} is zero or parallel to the view direction", self.up));
        };
        if (forward.cross(self.up.try_normalize().unwrap_or(DVec3::ZERO))).length() < 1e-9 {
            return bad(format!("up {:?} is parallel to the view direction", self.up));
        }
        let up = right.cross(forward);
        let tan_h = (self.fov_deg.to_radians() * 0.5).tan();
        let tan_v = tan_h * f64::from(self.height) / f64::from(self.width);
        let eye = self.eye;
        // Inward normals of the four side planes through the eye, and the plane at the eye
        // facing forward (no far plane: terrain is culled by distance through its error).
        let normals = [
            ((forward * tan_h) - right),
            ((forward * tan_h) + right),
            ((forward * tan_v) - up),
            ((forward * tan_v) + up),
            forward,
        ];
        let planes = normals.map(|n| (n, -n.dot(eye)));
        Ok(View { eye, forward, right, up, k: f64::from(self.width) / (2.0 * tan_h), tan_h, tan_v, planes })
    }
}

/// A validated camera: frustum planes and the screen-space error factor `k`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct View {
    pub eye: DVec3,
    pub forward: DVec3,
    pub right: DVec3,
    pub up: DVec3,
    /// `w / (2·tan(φ/2))`: pixels per world unit at unit distance.
    pub k: f64,
    pub tan_h: f64,
    pub tan_v: f64,
    planes: [(DVec3, f64); 5],
}

impl View {
    /// False only when the box is certainly outside the frustum (conservative p-vertex test).
    #[must_use]
    pub fn intersects(&self, b: &Bounds) -> bool {
        self.planes.iter().all(|(n, d)| {
            let p = DVec3::new(
                if n.x >= 0.0 { b.max[0] } else { b.min[0] },
                if n.y >= 0.0 { b.max[1] } else { b.min[1] },
                if n.z >= 0.0 { b.max[2] } else { b.min[2] },
            );
            (*n).dot(p) + d >= 0.0
        })
    }

    /// Screen-space error in pixels of a world-space error `e_obj` seen from distance `dist`.
    #[must_use]
    pub fn screen_error(&self, e_obj: f64, dist: f64) -> f64 {
        e_obj * self.k / dist.max(MIN_DISTANCE)
    }
}
