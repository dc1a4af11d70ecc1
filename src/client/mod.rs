//! The reference client, in the order a frame runs: [`tree`] (the in-memory tile tree built
//! from a tileset's index), [`camera`] (the perspective camera and its frustum), [`select`]
//! (view-dependent tile and level selection with fades and crack-hiding skirts), [`stream`]
//! (the request scheduler with its decoded-tile cache, HTTP, camera flights and the streaming
//! session with flight replay) and, with the `gpu` feature, [`render`] (headless wgpu
//! rendering of what is drawn, PNG frames); beside the view, [`collision`] names the tiles
//! within a radius of an ego position that are kept at full detail whatever the camera does.
//! The first paper's evaluation builds on the client from outside it, in [`crate::eval`];
//! nothing here imports it.
//!
//! Nothing in the pure parts opens a socket, spawns a task or touches a GPU: time is passed in
//! as seconds, the network sits behind [`stream::fetch::Transport`] and residency behind
//! [`select::Residency`], so every rule is unit-testable and the selection can be benchmarked
//! alone (`examples/select_bench.rs`). Rendering, the HTTP transport and flight replay build
//! on these types.

pub mod camera;
pub mod collision;
#[cfg(feature = "gpu")]
pub mod render;
pub mod select;
pub mod stream;
pub mod tree;

use std::path::PathBuf;

/// Errors of the client's pure parts; each names the input and the problem.
#[derive(Debug, thiserror::Error)]
pub enum ClientError {
    #[error("{path}: {source}")]
    Flight { path: PathBuf, source: stream::flight_path::FlightError },
    /// A flight that cannot be placed on the tileset being replayed.
    #[error("camera: {0}")]
    FlightFrame(#[source] stream::flight_path::FlightError),
    #[error("client: {0}")]
    Url(#[from] stream::http::UrlError),
    #[error("camera: {0}")]
    Camera(String),
    /// Collision region settings out of range.
    #[error("collision region: {0}")]
    Collision(String),
    #[error("tile tree: {0}")]
    Tree(String),
    #[error("client: {0}")]
    Network(String),
    #[cfg(feature = "gpu")]
    #[error("client: render: {0}")]
    Render(#[from] crate::gpu::GpuError),
    #[error("client: render: this build has no `gpu` feature: cannot render")]
    NoGpuFeature,
    #[error("client: render: {}: {source}", path.display())]
    Png { path: PathBuf, source: image::ImageError },
    #[error("{path}: {source}")]
    Io { path: PathBuf, source: std::io::Error },
    #[error(transparent)]
    Store(#[from] crate::store::StoreError),
}
