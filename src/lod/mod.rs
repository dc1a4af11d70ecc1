//! Point-cloud LOD levels baked from a tile's TIN by the first paper's 6-direction orthographic
//! slicing. `cpu` is the reference implementation; `gpu` (feature `gpu`) runs the same method
//! with wgpu and is checked against it.

pub mod cpu;
mod fasthash;
#[cfg(feature = "gpu")]
pub mod gpu;
mod measure;
