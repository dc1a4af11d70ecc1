//! The point-level baker of a bake: [`cpu`] (the reference) or [`gpu`], chosen once from
//! `--gpu` and shared by the terrain, node and model bakes and the server's on-demand bakes.

use rayon::prelude::*;

use super::cpu;
#[cfg(feature = "gpu")]
use super::gpu;
use crate::geom::{Mesh, PointCloud};

/// Default GPU memory budget of one batch of point levels, in MiB.
#[cfg(feature = "gpu")]
pub const DEFAULT_GPU_BUDGET_MIB: u64 = gpu::DEFAULT_BATCH_BUDGET_MIB;
/// Default GPU memory budget of one batch of point levels, in MiB (unused without `gpu`).
#[cfg(not(feature = "gpu"))]
pub const DEFAULT_GPU_BUDGET_MIB: u64 = 256;
/// Where point levels are baked (`--gpu`).
#[cfg_attr(feature = "cli", derive(clap::ValueEnum))]
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, serde::Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum GpuMode {
    /// A hardware adapter if there is one, else the CPU with a notice: a software adapter
    /// (Mesa lavapipe) bakes several times slower than the CPU reference, so only `on` uses it.
    #[default]
    Auto,
    /// An adapter or a clear error.
    On,
    /// The CPU reference.
    Off,
}

/// The point-level baker of a bake.
pub enum PointBaker {
    /// `lod::cpu`, node by node in parallel.
    Cpu,
    /// `lod::gpu`, many nodes and all their levels per submission.
    #[cfg(feature = "gpu")]
    Gpu(Box<gpu::GpuBaker>),
}

impl PointBaker {
    /// Resolves `mode`; `gpu_budget_bytes` caps one GPU batch. Returns the baker and, when
    /// `auto` falls back to the CPU, a one-line notice saying why (the choice itself is the
    /// bake summary's, [`PointBaker::describe`]: said once).
    pub fn open(mode: GpuMode, gpu_budget_bytes: u64) -> Result<(Self, Option<String>), BakerError> {
        if mode == GpuMode::Off {
            return Ok((Self::Cpu, None));
        }
        #[cfg(feature = "gpu")]
        {
            let on_cpu = |why: String| Ok((Self::Cpu, Some(why)));
            let ctx = match crate::gpu::open() {
                Ok(ctx) => ctx,
                Err(e) if mode == GpuMode::Auto => return on_cpu(e.to_string()),
                Err(e) => return Err(e.into()),
            };
            if mode == GpuMode::Auto && ctx.software {
                return on_cpu(format!(
                    "gpu: only the software adapter {} was found (several times slower than the CPU for \
                     baking; --gpu on uses it)",
                    ctx.adapter
                ));
            }
            match gpu::GpuBaker::new(ctx.device, ctx.queue, ctx.adapter, gpu_budget_bytes) {
                Ok(g) => Ok((Self::Gpu(Box::new(g)), None)),
                Err(e) if mode == GpuMode::Auto => on_cpu(e.to_string()),
                Err(e) => Err(e.into()),
            }
        }
        #[cfg(not(feature = "gpu"))]
        {
            let _ = gpu_budget_bytes;
            match mode {
                GpuMode::On => Err(BakerError::NoGpuSupport),
                _ => Ok((Self::Cpu, Some("gpu: this build has no `gpu` feature".into()))),
            }
        }
    }

    /// Point clouds of one mesh on several cubic grids (origin, cell edge), unquantized, with
    /// what the GPU path cost (`None` on the CPU): one terrain node's levels. The CPU bakes the
    /// grids one after the other (the caller runs nodes in parallel).
    pub fn bake_levels(
        &self,
        mesh: &Mesh,
        grids: &[([f64; 3], f64)],
    ) -> Result<(Vec<PointCloud>, Option<[u64; 4]>), BakerError> {
        match self {
            Self::Cpu => {
                Ok((grids.iter().map(|&(origin, cell)| cpu::bake_points(mesh, origin, cell)).collect(), None))
            }
            #[cfg(feature = "gpu")]
            Self::Gpu(gpu) => {
                let jobs: Vec<gpu::LevelJob<'_>> =
                    grids.iter().map(|&(origin, cell)| gpu::LevelJob { mesh, origin, cell }).collect();
                let (results, rep) = gpu.bake_clouds(&jobs, &cpu::SliceOptions::default())?;
                let clouds = results.into_iter().map(|(cloud, _)| cloud).collect();
                Ok((clouds, Some([rep.batches, rep.peak_batch_bytes, rep.budget_bytes, rep.cpu_jobs])))
            }
        }
    }

    /// Point clouds of one mesh on several cubic grids (origin, cell edge), with what each bake
    /// did: the model bake's levels. The GPU takes them all in one submission (split only by
    /// the batch budget); the CPU bakes them in parallel.
    pub fn bake_grids(
        &self,
        mesh: &Mesh,
        grids: &[([f64; 3], f64)],
    ) -> Result<Vec<(PointCloud, cpu::BakeStats)>, BakerError> {
        match self {
            Self::Cpu => Ok(grids
                .par_iter()
                .map(|&(origin, cell)| cpu::bake_points_with_stats(mesh, origin, cell))
                .collect()),
            #[cfg(feature = "gpu")]
            Self::Gpu(gpu) => {
                let jobs: Vec<gpu::LevelJob<'_>> =
                    grids.iter().map(|&(origin, cell)| gpu::LevelJob { mesh, origin, cell }).collect();
                let (results, _) = gpu.bake_clouds(&jobs, &cpu::SliceOptions::default())?;
                Ok(results)
            }
        }
    }

    /// "cpu" or "gpu: <adapter>", as in the summary and the manifest.
    #[must_use]
    pub fn describe(&self) -> String {
        match self {
            Self::Cpu => "cpu".into(),
            #[cfg(feature = "gpu")]
            Self::Gpu(g) => format!("gpu: {}", g.adapter()),
        }
    }
}

/// Why a [`PointBaker`] could not be opened or failed.
#[derive(Debug, thiserror::Error)]
pub enum BakerError {
    /// `--gpu on` in a build without the `gpu` feature.
    #[error("--gpu on: this build has no GPU support (feature `gpu` off)")]
    NoGpuSupport,
    #[cfg(feature = "gpu")]
    #[error(transparent)]
    Gpu(#[from] crate::gpu::GpuError),
}
