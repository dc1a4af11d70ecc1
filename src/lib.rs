//! terrastream: terrain heightfields → tiled, crack-free TIN meshes and point-cloud LOD levels →
//! compact binary blobs in a tileset directory.
//!
//! The pure core (`tiling`, `tin`, `codec`, `lod::cpu`, `geom`) works on values and byte slices
//! only; `raster` reads files; `store` and `bake` own the tileset directory.

pub mod bake;
#[cfg(feature = "client")]
pub mod client;
pub mod codec;
pub mod crs;
mod error;
#[cfg(feature = "client")]
pub mod eval;
pub mod formats;
pub mod geom;
#[cfg(feature = "gpu")]
pub mod gpu;
pub mod heights;
pub mod lod;
pub mod model;
pub mod raster;
#[cfg(feature = "server")]
pub mod server;
pub mod store;
pub mod tiling;
pub mod tin;

pub use error::{Error, Result};
