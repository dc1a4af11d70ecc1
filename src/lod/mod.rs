//! Point-cloud LOD levels baked from a tile's TIN by the first paper's 6-direction orthographic
//! slicing. `cpu` is the reference implementation; `gpu` (feature `gpu`) runs the same method
//! with wgpu and is checked against it.

mod baker;
pub mod cpu;
mod footprint;
#[cfg(feature = "gpu")]
pub mod gpu;
pub mod measure;
pub mod reach;
pub use footprint::{MODEL_FOOTPRINT_HALF, TERRAIN_FOOTPRINT_HALF};

pub use baker::{BakerError, DEFAULT_GPU_BUDGET_MIB, GpuMode, PointBaker};
