//! Baking: the entry points that turn an input into a tileset directory. [`terrain`] bakes a
//! loaded raster (every node of its pyramid, in parallel, resumable); [`model`] bakes one OBJ,
//! STL or PLY model into a single-tile model tileset.

mod terrain;

pub mod model;

pub use terrain::*;
