//! Output formats: every format a tileset is written or served in, other than the native blobs
//! of [`crate::codec`], each in one place. Pure: decoded blobs, manifests and index chunks in,
//! bytes and JSON out; no file or network I/O (the export driver in `bake::export` and the
//! server do that).
//!
//! - [`tiles3d`]: OGC 3D Tiles 1.1 (placement on the globe, glTF binaries, tileset JSON);
//! - [`interchange`]: PLY and OBJ files of one (tile, level), for mesh and point tools;
//! - [`qmesh`]: Cesium quantized-mesh-1.0 globe terrain (geodetic tiles, `layer.json`).
//!
//! Heightmap tiles land here too. May import the stages below it (`codec`,
//! `geom`, `store` records, `tiling`, `raster` limits), never `bake`, `server` or `client`.

pub mod heightmap;
pub mod interchange;
pub mod qmesh;
pub mod tiles3d;
