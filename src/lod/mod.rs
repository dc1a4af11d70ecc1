//! Point-cloud LOD levels baked from a tile's TIN by the first paper's 6-direction orthographic
//! slicing. `cpu` is the reference implementation.

pub mod cpu;
mod fasthash;
mod measure;
