//! Baking: the three entry points that turn an input into tiles.
//!
//! - [`bake_terrain`] bakes a loaded raster into a terrain tileset: every node of its pyramid,
//!   in parallel, resumable, the manifest last (`terrain`);
//! - [`bake_node`] bakes one node of a raster into an existing tileset directory, the same
//!   bytes [`bake_terrain`] writes for it: the server's on-demand tiles (`node`);
//! - [`qmesh`] makes Cesium quantized-mesh globe terrain from a placed dataset, baked into a
//!   store or one tile at a time for the server (the same bytes);
//! - [`terrain3d`] writes that globe terrain's 3D Tiles form (GLBs, subtrees, tileset.json)
//!   from the baked tiles, the bytes the server sends;
//! - [`shard`] splits a terrain bake over many processes or machines (same bytes);
//! - [`model_tileset::bake_model`] bakes one OBJ, STL or PLY model into a single-tile model
//!   tileset (`model_tileset`).

pub mod export;
mod node;
pub mod qmesh;
pub mod shard;
mod terrain;
pub mod terrain3d;

pub mod model_tileset;

pub use node::{LevelPlan, NodeMesh, ParentInfo, bake_node, node_from_blobs, node_mesh};
pub use terrain::*;
