//! Camera flights: the documented JSON of timestamped eye/target/up keys, its validation, the
//! normalised frame (so one flight works on any terrain) and interpolation at time `t`.
//!
//! ```json
//! {
//!   "name": "orbit",
//!   "frame": "normalized",
//!   "keys": [
//!     { "t": 0.0, "eye": [0.5, -0.2, 0.4], "target": [0.5, 0.5, 0.05], "up": [0, 0, 1] },
//!     { "t": 5.0, "eye": [1.2, 0.5, 0.2], "target": [0.5, 0.5, 0.05] }
//!   ]
//! }
//! ```
//!
//! A key may carry an `ego` position (`[x, y, z]`, the vehicle whose collision region the client
//! keeps at full detail): in the flight's frame like `eye`, given on every key or on none, and
//! interpolated linearly between keys like the eye ([`Flight::ego_at`]).
//!
//! `frame` is `"world"` (the tileset's world units, the default) or `"normalized"`: x and y run
//! 0..1 across the tileset's extent in x and y, and z is measured from the tileset's lowest point
//! in multiples of its larger horizontal extent. `up` is a direction (default `[0, 0, 1]`) and is
//! never scaled. Keys need strictly increasing finite times `t` (seconds); between keys the eye
//! and target move linearly and the up vector is interpolated and renormalised; before the first
//! and after the last key the camera holds still.

use std::path::Path;

use glam::DVec3;
use serde::{Deserialize, Serialize};

use crate::client::ClientError;
use crate::geom::Bounds;

/// The up direction when a key gives none.
pub const DEFAULT_UP: [f64; 3] = [0.0, 0.0, 1.0];

/// Most bytes a flight file may have (a million keys are about 150 MB of JSON); read at most
/// one more, so a wrong path such as `/dev/zero` is refused instead of filling memory.
pub const MAX_FLIGHT_BYTES: u64 = 256 << 20;

/// What is wrong with a flight; each names the key and field (`keys[i].t`).
#[derive(Debug, thiserror::Error)]
pub enum FlightError {
    /// The flight file cannot be read.
    #[error("{0}")]
    Read(#[source] std::io::Error),
    #[error("more than {max} bytes; a flight file is at most that")]
    TooLarge { max: u64 },
    #[error("invalid flight JSON: {0}")]
    Json(#[source] serde_json::Error),
    #[error("keys: a flight needs at least one key")]
    NoKeys,
    #[error("keys[{i}].t: {t} is not a finite time")]
    TimeNotFinite { i: usize, t: f64 },
    #[error("keys[{i}].t: {t} is not after keys[{before}].t = {before_t}")]
    TimeNotAfter { i: usize, t: f64, before: usize, before_t: f64 },
    /// `field` is "eye", "target", "up" or "ego".
    #[error("keys[{i}].{field}: {value:?} is not finite")]
    NotFinite { i: usize, field: &'static str, value: [f64; 3] },
    #[error("keys[{i}]: eye and target are the same point {eye:?}")]
    SamePoint { i: usize, eye: [f64; 3] },
    #[error("keys[{i}].up: {up:?} is not a direction")]
    UpNotDirection { i: usize, up: [f64; 3] },
    #[error("keys[{i}].up: {up:?} is parallel to the view direction")]
    UpAlongView { i: usize, up: [f64; 3] },
    /// Some keys carry an ego position and this one does not, or the other way round.
    #[error(
        "keys[{i}].ego: {} while keys[0] {}; give every key an ego position or none",
        if *has { "given" } else { "missing" },
        if *has { "has none" } else { "has one" }
    )]
    EgoTrack { i: usize, has: bool },
    #[error("tileset bounds {min:?} .. {max:?} are not valid")]
    InvalidBounds { min: [f64; 3], max: [f64; 3] },
    #[error("tileset has no horizontal extent; a normalized flight needs one")]
    NoExtent,
    #[error("{0}")]
    Serialize(#[source] serde_json::Error),
    /// A replay of the flight asked for a frame rate that is not a positive number.
    #[error("flight replay: fps {0} must be positive")]
    Fps(f64),
}

/// The frame a flight's positions are given in.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Frame {
    #[default]
    World,
    #[serde(alias = "normalised")]
    Normalized,
}

/// One camera key.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Key {
    pub t: f64,
    pub eye: [f64; 3],
    pub target: [f64; 3],
    #[serde(default = "default_up")]
    pub up: [f64; 3],
    /// The ego (vehicle) position at this key, in the flight's frame; on every key or on none.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub ego: Option<[f64; 3]>,
}

fn default_up() -> [f64; 3] {
    DEFAULT_UP
}

/// A camera pose: where the eye is, what it looks at, which way is up (world units).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Pose {
    pub eye: DVec3,
    pub target: DVec3,
    pub up: DVec3,
}

/// A validated flight.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Flight {
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub name: Option<String>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub description: Option<String>,
    #[serde(default)]
    pub frame: Frame,
    pub keys: Vec<Key>,
}

impl Flight {
    /// Parses and validates a flight; the error says which key and field is wrong.
    pub fn from_json(text: &str) -> Result<Self, FlightError> {
        let f: Self = serde_json::from_str(text).map_err(FlightError::Json)?;
        f.validate()?;
        Ok(f)
    }

    /// Reads a flight file.
    pub fn load(path: &Path) -> Result<Self, ClientError> {
        use std::io::Read;
        let err = |source: FlightError| ClientError::Flight { path: path.to_owned(), source };
        let file = std::fs::File::open(path).map_err(|e| err(FlightError::Read(e)))?;
        if file.metadata().is_ok_and(|m| m.len() > MAX_FLIGHT_BYTES) {
            return Err(err(FlightError::TooLarge { max: MAX_FLIGHT_BYTES }));
        }
        let mut text = String::new();
        // At most one byte past the limit, whatever the file is (a pipe, `/dev/zero`).
        file.take(MAX_FLIGHT_BYTES + 1).read_to_string(&mut text).map_err(|e| err(FlightError::Read(e)))?;
        if text.len() as u64 > MAX_FLIGHT_BYTES {
            return Err(err(FlightError::TooLarge { max: MAX_FLIGHT_BYTES }));
        }
        Self::from_json(&text).map_err(err)
    }

    /// Checks keys: at least one, finite and strictly increasing times, finite positions, eye
    /// distinct from target, up non-zero and not along the view direction, an ego position on
    /// every key or on none.
    pub fn validate(&self) -> Result<(), FlightError> {
        if self.keys.is_empty() {
            return Err(FlightError::NoKeys);
        }
        for (i, k) in self.keys.iter().enumerate() {
            if !k.t.is_finite() {
                return Err(FlightError::TimeNotFinite { i, t: k.t });
            }
            if i > 0 && k.t <= self.keys[i - 1].t {
                return Err(FlightError::TimeNotAfter {
                    i,
                    t: k.t,
                    before: i - 1,
                    before_t: self.keys[i - 1].t,
                });
            }
            if k.ego.is_some() != self.keys[0].ego.is_some() {
                return Err(FlightError::EgoTrack { i, has: k.ego.is_some() });
            }
            let ego = k.ego.map(|e| ("ego", e));
            for (field, value) in [("eye", k.eye), ("target", k.target), ("up", k.up)].into_iter().chain(ego)
            {
                if !DVec3::from_array(value).is_finite() {
                    return Err(FlightError::NotFinite { i, field, value });
                }
            }
            let (eye, target) = (DVec3::from_array(k.eye), DVec3::from_array(k.target));
            let Some(dir) = (target - eye).try_normalize() else {
                return Err(FlightError::SamePoint { i, eye: k.eye });
            };
            let Some(up) = DVec3::from_array(k.up).try_normalize() else {
                return Err(FlightError::UpNotDirection { i, up: k.up });
            };
            if (dir.cross(up)).length() < 1e-6 {
                return Err(FlightError::UpAlongView { i, up: k.up });
            }
        }
        Ok(())
    }

    /// First key time.
    #[must_use]
    pub fn start(&self) -> f64 {
        self.keys.first().map_or(0.0, |k| k.t)
    }

    /// Last key time.
    #[must_use]
    pub fn end(&self) -> f64 {
        self.keys.last().map_or(0.0, |k| k.t)
    }

    #[must_use]
    pub fn duration(&self) -> f64 {
        self.end() - self.start()
    }

    /// The same flight in world units for a tileset with `bounds` (a world flight is returned
    /// as is).
    pub fn to_world(&self, bounds: &Bounds) -> Result<Self, FlightError> {
        if self.frame == Frame::World {
            return Ok(self.clone());
        }
        if !bounds.is_valid() {
            return Err(FlightError::InvalidBounds {
                min: bounds.min.to_array(),
                max: bounds.max.to_array(),
            });
        }
        let size = bounds.size();
        let extent = size[0].max(size[1]);
        if extent <= 0.0 {
            return Err(FlightError::NoExtent);
        }
        let map = |p: [f64; 3]| {
            [bounds.min[0] + p[0] * size[0], bounds.min[1] + p[1] * size[1], bounds.min[2] + p[2] * extent]
        };
        let keys = self
            .keys
            .iter()
            .map(|k| Key { t: k.t, eye: map(k.eye), target: map(k.target), up: k.up, ego: k.ego.map(map) })
            .collect();
        let f = Self {
            name: self.name.clone(),
            description: self.description.clone(),
            frame: Frame::World,
            keys,
        };
        f.validate()?;
        Ok(f)
    }

    /// The pose at time `t` (held before the first key and after the last). Positions are in
    /// the flight's own frame: call [`Flight::to_world`] first for a normalised flight.
    #[must_use]
    pub fn pose_at(&self, t: f64) -> Pose {
        let keys = &self.keys;
        let Some(first) = keys.first() else {
            return Pose { eye: DVec3::Z, target: DVec3::ZERO, up: DVec3::Y };
        };
        // Index of the first key after t.
        let i = keys.partition_point(|k| k.t <= t);
        if i == 0 || !t.is_finite() {
            return pose(first);
        }
        if i >= keys.len() {
            return pose(&keys[keys.len() - 1]);
        }
        let (a, b) = (&keys[i - 1], &keys[i]);
        let s = ((t - a.t) / (b.t - a.t)).clamp(0.0, 1.0);
        let v = DVec3::from_array;
        let eye = v(a.eye).lerp(v(b.eye), s);
        let target = v(a.target).lerp(v(b.target), s);
        let dir = target - eye;
        // Up must stay a direction off the view axis; fall back to the nearer key's.
        let up = v(a.up)
            .lerp(v(b.up), s)
            .try_normalize()
            .filter(|u| u.cross(dir).length() > 1e-9 * dir.length())
            .unwrap_or(v(if s < 0.5 { a.up } else { b.up }));
        Pose { eye, target, up }
    }

    /// True when the keys carry an ego track.
    #[must_use]
    pub fn has_ego(&self) -> bool {
        self.keys.first().is_some_and(|k| k.ego.is_some())
    }

    /// The ego position at time `t`, interpolated like the eye (held before the first key and
    /// after the last); `None` for a flight without an ego track. In the flight's own frame.
    #[must_use]
    pub fn ego_at(&self, t: f64) -> Option<DVec3> {
        let keys = &self.keys;
        let v = |k: &Key| k.ego.map(DVec3::from_array);
        let first = keys.first()?;
        let i = keys.partition_point(|k| k.t <= t);
        if i == 0 || !t.is_finite() {
            return v(first);
        }
        if i >= keys.len() {
            return v(&keys[keys.len() - 1]);
        }
        let (a, b) = (&keys[i - 1], &keys[i]);
        let s = ((t - a.t) / (b.t - a.t)).clamp(0.0, 1.0);
        Some(v(a)?.lerp(v(b)?, s))
    }

    /// Pretty JSON of the flight.
    pub fn to_json(&self) -> Result<String, FlightError> {
        serde_json::to_string_pretty(self).map_err(FlightError::Serialize)
    }
}

fn pose(k: &Key) -> Pose {
    Pose { eye: DVec3::from_array(k.eye), target: DVec3::from_array(k.target), up: DVec3::from_array(k.up) }
}

#[cfg(test)]
#[allow(clippy::float_cmp)] // interpolation of exactly representable keys is exact
mod tests {
    use super::*;

    /// A flight file past the limit is refused before it is read (a sparse file: before the fix
    /// its 256 MiB of zeros were read whole and then called invalid JSON).
    #[test]
    fn oversized_flight_files_are_refused() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("flight.json");
        std::fs::File::create(&p).unwrap().set_len(MAX_FLIGHT_BYTES + 1).unwrap();
        let e = Flight::load(&p).unwrap_err().to_string();
        assert!(e.contains("flight.json") && e.contains("more than 268435456 bytes"), "{e}");
    }

    #[test]
    fn parses_interpolates_and_holds() {
        let f = Flight::from_json(
            r#"{"frame":"world","keys":[
                {"t":0,"eye":[0,0,10],"target":[10,0,0]},
                {"t":2,"eye":[20,0,10],"target":[10,10,0],"up":[0,0,2]}]}"#,
        )
        .unwrap();
        assert_eq!(f.keys[0].up, DEFAULT_UP);
        let p = f.pose_at(1.0);
        assert_eq!(p.eye, DVec3::from_array([10.0, 0.0, 10.0]));
        assert_eq!(p.target, DVec3::from_array([10.0, 5.0, 0.0]));
        assert!((p.up.length() - 1.0).abs() < 1e-12);
        assert_eq!(f.pose_at(-5.0).eye, DVec3::from_array([0.0, 0.0, 10.0]));
        assert_eq!(f.pose_at(99.0).eye, DVec3::from_array([20.0, 0.0, 10.0]));
        assert_eq!(f.pose_at(2.0).eye, DVec3::from_array([20.0, 0.0, 10.0]));
        assert!((f.duration() - 2.0).abs() < 1e-12);
        // Round trip.
        assert_eq!(Flight::from_json(&f.to_json().unwrap()).unwrap(), f);
    }

    #[test]
    fn errors_name_key_and_field() {
        let e = |s: &str| Flight::from_json(s).unwrap_err().to_string();
        assert!(e(r#"{"keys":[]}"#).contains("at least one key"));
        assert!(
            e(r#"{"keys":[{"t":1,"eye":[0,0,1],"target":[1,0,0]},{"t":1,"eye":[0,0,1],"target":[1,0,0]}]}"#)
                .contains("keys[1].t: 1 is not after keys[0].t = 1")
        );
        assert!(
            e(r#"{"keys":[{"t":0,"eye":[1,1,1],"target":[1,1,1]}]}"#).contains("keys[0]: eye and target")
        );
        assert!(e(r#"{"keys":[{"t":0,"eye":[0,0,5],"target":[0,0,0]}]}"#).contains("keys[0].up"));
        assert!(
            e(r#"{"keys":[{"t":0,"eye":[0,0,5],"target":[0,0,0],"up":[0,0,0]}]}"#)
                .contains("not a direction")
        );
        assert!(e(r#"{"keys":[{"t":0,"eye":[0,0],"target":[0,0,0]}]}"#).contains("invalid flight JSON"));
        assert!(e(r#"{"frame":"polar","keys":[]}"#).contains("invalid flight JSON"));
        assert!(e(r#"{"keys":[{"t":0,"eye":[0,0,1],"target":[1,0,0],"fov":3}]}"#).contains("unknown field"));
        assert!(e("not json").contains("line 1"));
        let err = Flight::load(Path::new("/nonexistent/flight.json")).unwrap_err().to_string();
        assert!(err.starts_with("/nonexistent/flight.json:"), "{err}");
    }

    #[test]
    fn ego_track_loads_interpolates_and_is_validated() {
        let f = Flight::from_json(
            r#"{"keys":[
                {"t":0,"eye":[0,0,10],"target":[10,0,0],"ego":[100,200,5]},
                {"t":4,"eye":[20,0,10],"target":[10,10,0],"ego":[140,180,9]}]}"#,
        )
        .unwrap();
        assert!(f.has_ego());
        assert_eq!(f.ego_at(1.0), Some(DVec3::new(110.0, 195.0, 6.0)));
        assert_eq!(f.ego_at(-1.0), Some(DVec3::new(100.0, 200.0, 5.0)));
        assert_eq!(f.ego_at(9.0), Some(DVec3::new(140.0, 180.0, 9.0)));
        assert_eq!(Flight::from_json(&f.to_json().unwrap()).unwrap(), f);
        // Old flights (no ego) still load and have none.
        let old = Flight::from_json(r#"{"keys":[{"t":0,"eye":[0,0,10],"target":[10,0,0]}]}"#).unwrap();
        assert!(!old.has_ego() && old.ego_at(0.0).is_none());
        assert!(!old.to_json().unwrap().contains("ego"));
        let e = |s: &str| Flight::from_json(s).unwrap_err().to_string();
        let missing = e(r#"{"keys":[{"t":0,"eye":[0,0,1],"target":[1,0,0],"ego":[0,0,0]},
            {"t":1,"eye":[0,0,1],"target":[1,0,0]}]}"#);
        assert!(missing.starts_with("keys[1].ego: missing while keys[0] has one"), "{missing}");
        let given = e(r#"{"keys":[{"t":0,"eye":[0,0,1],"target":[1,0,0]},
            {"t":1,"eye":[0,0,1],"target":[1,0,0],"ego":[0,0,0]}]}"#);
        assert!(given.starts_with("keys[1].ego: given while keys[0] has none"), "{given}");
        // JSON has no NaN: a flight built in code can carry one.
        let mut bad = f.clone();
        bad.keys[1].ego = Some([f64::NAN, 0.0, 0.0]);
        let nan = bad.validate().unwrap_err().to_string();
        assert!(nan.starts_with("keys[1].ego: [NaN, 0.0, 0.0] is not finite"), "{nan}");
        assert!(
            e(r#"{"keys":[{"t":0,"eye":[0,0,1],"target":[1,0,0],"ego":[1,2]}]}"#)
                .contains("invalid flight JSON")
        );
        // A normalised flight's ego is mapped like its eye.
        let n = Flight::from_json(
            r#"{"frame":"normalized","keys":[{"t":0,"eye":[0,0,1],"target":[1,1,0],"ego":[0.5,0.25,0]}]}"#,
        )
        .unwrap();
        let w = n.to_world(&Bounds::new([100.0, 200.0, 10.0], [500.0, 400.0, 60.0])).unwrap();
        assert_eq!(w.keys[0].ego, Some([300.0, 250.0, 10.0]));
    }

    #[test]
    fn normalized_frame_maps_to_bounds() {
        let f = Flight::from_json(
            r#"{"frame":"normalised","keys":[{"t":0,"eye":[0.5,0,0.25],"target":[1,1,0]}]}"#,
        )
        .unwrap();
        let b = Bounds::new([100.0, 200.0, 10.0], [500.0, 400.0, 60.0]);
        let w = f.to_world(&b).unwrap();
        assert_eq!(w.frame, Frame::World);
        assert_eq!(w.keys[0].eye, [300.0, 200.0, 110.0]);
        assert_eq!(w.keys[0].target, [500.0, 400.0, 10.0]);
        assert!(f.to_world(&Bounds::empty()).is_err());
    }

    #[test]
    fn shipped_flight_is_valid_and_normalised() {
        let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("data/flight-orbit.json");
        let f = Flight::load(&path).unwrap();
        assert_eq!(f.frame, Frame::Normalized);
        assert!(f.duration() > 10.0);
        let b = Bounds::new([0.0, 0.0, 0.0], [15360.0, 15360.0, 3700.0]);
        let w = f.to_world(&b).unwrap();
        for i in 0..=100 {
            let p = w.pose_at(w.start() + w.duration() * f64::from(i) / 100.0);
            assert!(p.eye.is_finite() && p.eye[2] > 0.0);
        }
    }
}
