//! The first paper's evaluation (section 4.6), a research harness on top of the client, kept
//! out of it so a simulator embedding the client does not carry it. [`analysis`] is pure:
//! cameras, coverage metrics, aggregation, the paper's tables, the report and its charts.
//! [`flight_cost`] prices a camera flight with everything resident (`eval --flight`). With the
//! `gpu` feature, the runner (`terrastream eval`: renders full detail against the LOD selection
//! from the tileset directory, re-exported here) and [`instances`] (the N×N instance
//! experiment).
//!
//! May import the client, `bake`, `store` and the pure core; only the CLI imports it.

use std::path::PathBuf;

pub mod analysis;
pub mod flight_cost;
#[cfg(feature = "gpu")]
pub mod frames;
#[cfg(feature = "gpu")]
pub mod instances;
#[cfg(feature = "gpu")]
mod run;

#[cfg(feature = "gpu")]
pub use run::*;

/// Why an evaluation failed; each names the file, setting or stage.
#[derive(Debug, thiserror::Error)]
pub enum EvalError {
    #[error("eval: threshold {0} px must be positive")]
    Threshold(f64),
    #[error("eval: {0}")]
    Plan(#[from] analysis::PlanError),
    #[error("eval: {0}: the tileset's index holds no node")]
    EmptyIndex(PathBuf),
    #[error("eval: {0}: not a terrain tileset (the large-terrain experiment needs one)")]
    NotTerrain(PathBuf),
    #[error("eval: model tileset without a root node")]
    NoRoot,
    #[error("eval: {0}: blob missing")]
    BlobMissing(PathBuf),
    #[error("eval: {path}: {source}")]
    Blob { path: PathBuf, source: crate::codec::CodecError },
    #[error("eval: results.json: {0}")]
    Json(#[from] serde_json::Error),
    #[error(transparent)]
    Tiling(#[from] crate::tiling::TilingError),
    #[error(transparent)]
    Store(#[from] crate::store::StoreError),
    #[error(transparent)]
    Client(#[from] crate::client::ClientError),
    #[cfg(feature = "gpu")]
    #[error(transparent)]
    Gpu(#[from] crate::gpu::GpuError),
}
