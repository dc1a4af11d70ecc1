//! The reference client, in the order a frame runs: [`tree`] (the in-memory tile tree built
//! from a tileset's index), [`camera`] (the perspective camera and its frustum), [`select`]
//! (view-dependent tile and level selection with fades and crack-hiding skirts), [`stream`]
//! (the request scheduler with its decoded-tile cache, HTTP, camera flights and the streaming
//! session with flight replay) and, with the `gpu` feature, [`render`] (headless wgpu
//! rendering of what is drawn, PNG frames). [`eval`] is the first paper's evaluation: pure
//! cameras, coverage metrics, report and charts, and with the `gpu` feature its runner and the
//! N×N instance experiment.
//!
//! Nothing in the pure parts opens a socket, spawns a task or touches a GPU: time is passed in
//! as seconds, the network sits behind [`stream::fetch::Transport`] and residency behind
//! [`select::Residency`], so every rule is unit-testable and the selection can be benchmarked
//! alone (`examples/select_bench.rs`). Rendering, the HTTP transport and flight replay build
//! on these types.

pub mod camera;
pub mod eval;
#[cfg(feature = "gpu")]
pub mod render;
pub mod select;
pub mod stream;
pub mod tree;

use std::path::PathBuf;

/// Errors of the client's pure parts; each names the input and the problem.
#[derive(Debug, thiserror::Error)]
pub enum ClientError {
    #[error("{path}: {message}")]
    Flight { path: PathBuf, message: String },
    #[error("camera: {0}")]
    Camera(String),
    #[error("tile tree: {0}")]
    Tree(String),
    #[error("client: {0}")]
    Network(String),
    #[error("eval: {0}")]
    Eval(String),
    #[error("client: render: {0}")]
    Render(String),
    #[error("{path}: {source}")]
    Io { path: PathBuf, source: std::io::Error },
    #[error(transparent)]
    Store(#[from] crate::store::StoreError),
}

/// Small vector helpers on `[f64; 3]` (the crate has no linear-algebra dependency).
pub(crate) mod v3 {
    pub type V = [f64; 3];

    #[inline]
    pub fn sub(a: V, b: V) -> V {
        [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
    }
    #[inline]
    pub fn add(a: V, b: V) -> V {
        [a[0] + b[0], a[1] + b[1], a[2] + b[2]]
    }
    #[inline]
    pub fn scale(a: V, s: f64) -> V {
        [a[0] * s, a[1] * s, a[2] * s]
    }
    #[inline]
    pub fn dot(a: V, b: V) -> f64 {
        a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
    }
    #[inline]
    pub fn cross(a: V, b: V) -> V {
        [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]]
    }
    #[inline]
    pub fn len(a: V) -> f64 {
        dot(a, a).sqrt()
    }
    /// `a / |a|`, or `None` for a (near-)zero or non-finite vector.
    pub fn normalize(a: V) -> Option<V> {
        let l = len(a);
        (l.is_finite() && l > 1e-300).then(|| scale(a, 1.0 / l))
    }
    #[inline]
    pub fn lerp(a: V, b: V, t: f64) -> V {
        [a[0] + (b[0] - a[0]) * t, a[1] + (b[1] - a[1]) * t, a[2] + (b[2] - a[2]) * t]
    }
    pub fn finite(a: V) -> bool {
        a.iter().all(|v| v.is_finite())
    }
}
