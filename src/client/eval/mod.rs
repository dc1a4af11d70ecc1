//! The first paper's evaluation (section 4.6). [`analysis`] is pure: cameras, coverage
//! metrics, aggregation, the report and its charts. With the `gpu` feature, the runner
//! (`terrastream eval`: renders full detail against the LOD selection from the tileset
//! directory, re-exported here) and [`instances`] (the N×N instance experiment).

pub mod analysis;
#[cfg(feature = "gpu")]
pub mod instances;
#[cfg(feature = "gpu")]
mod run;

#[cfg(feature = "gpu")]
pub use run::*;
