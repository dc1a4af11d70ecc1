//! The perspective camera of selection, replay, rendering and evaluation: eye, target, up,
//! viewport and field of view, and the [`View`] (frustum planes and projection constants)
//! derived from it.

use crate::client::ClientError;
use crate::client::stream::flight::Pose;
use crate::client::v3;
use crate::geom::Bounds;

/// Smallest eye distance used in `e_scr`, so an eye at a sphere's centre gives a huge, finite error.
pub(crate) const MIN_DISTANCE: f64 = 1e-6;

/// A perspective camera: eye, look-at target, up direction, viewport in pixels and horizontal
/// field of view.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Camera {
    pub eye: [f64; 3],
    pub target: [f64; 3],
    pub up: [f64; 3],
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
        if !v3::finite(self.eye) || !v3::finite(self.target) || !v3::finite(self.up) {
            return bad(format!(
                "eye {:?}, target {:?} or up {:?} is not finite",
                self.eye, self.target, self.up
            ));
        }
        let Some(forward) = v3::normalize(v3::sub(self.target, self.eye)) else {
            return bad(format!("eye and target are the same point {:?}", self.eye));
        };
        let Some(right) = v3::normalize(v3::cross(forward, self.up)).filter(|_| v3::len(self.up) > 0.0)
        else {
            return bad(format!("up {:?} is zero or parallel to the view direction", self.up));
        };
        if v3::len(v3::cross(forward, v3::normalize(self.up).unwrap_or([0.0; 3]))) < 1e-9 {
            return bad(format!("up {:?} is parallel to the view direction", self.up));
        }
        let up = v3::cross(right, forward);
        let tan_h = (self.fov_deg.to_radians() * 0.5).tan();
        let tan_v = tan_h * f64::from(self.height) / f64::from(self.width);
        let eye = self.eye;
        // Inward normals of the four side planes through the eye, and the plane at the eye
        // facing forward (no far plane: terrain is culled by distance through its error).
        let normals = [
            v3::sub(v3::scale(forward, tan_h), right),
            v3::add(v3::scale(forward, tan_h), right),
            v3::sub(v3::scale(forward, tan_v), up),
            v3::add(v3::scale(forward, tan_v), up),
            forward,
        ];
        let planes = normals.map(|n| (n, -v3::dot(n, eye)));
        Ok(View { eye, forward, right, up, k: f64::from(self.width) / (2.0 * tan_h), tan_h, tan_v, planes })
    }
}

/// A validated camera: frustum planes and the screen-space error factor `k`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct View {
    pub eye: [f64; 3],
    pub forward: [f64; 3],
    pub right: [f64; 3],
    pub up: [f64; 3],
    /// `w / (2·tan(φ/2))`: pixels per world unit at unit distance.
    pub k: f64,
    pub tan_h: f64,
    pub tan_v: f64,
    planes: [([f64; 3], f64); 5],
}

impl View {
    /// False only when the box is certainly outside the frustum (conservative p-vertex test).
    #[must_use]
    pub fn intersects(&self, b: &Bounds) -> bool {
        self.planes.iter().all(|(n, d)| {
            let p = [
                if n[0] >= 0.0 { b.max[0] } else { b.min[0] },
                if n[1] >= 0.0 { b.max[1] } else { b.min[1] },
                if n[2] >= 0.0 { b.max[2] } else { b.min[2] },
            ];
            v3::dot(*n, p) + d >= 0.0
        })
    }

    /// Screen-space error in pixels of a world-space error `e_obj` seen from distance `dist`.
    #[must_use]
    pub fn screen_error(&self, e_obj: f64, dist: f64) -> f64 {
        e_obj * self.k / dist.max(MIN_DISTANCE)
    }
}
