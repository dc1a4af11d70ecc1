//! `terrastream bake-model`: an OBJ, STL or PLY model → a model tileset.

use std::path::PathBuf;

use anyhow::{Context, Result};
use terrastream::bake::model::{self as bake_model, ModelBakeOptions, ModelLevelTable};
use terrastream::lod;
use terrastream::model::FileType;
use terrastream::store::Store;

#[derive(clap::Args)]
pub struct BakeModelArgs {
    /// Model file: Wavefront .obj, .stl (binary or ASCII) or .ply (ASCII or binary).
    pub model: PathBuf,
    /// Output tileset directory (created; must be empty or an earlier bake of the same model).
    #[arg(long)]
    pub out: PathBuf,
    /// Point-cloud levels below the mesh.
    #[arg(long, default_value_t = bake_model::DEFAULT_MODEL_LEVELS)]
    pub levels: u8,
    /// Resolution T of level 1: grid cells across the model's longest side (the paper's
    /// framebuffer size T3); level l of K gets T·(K+1−l)/K.
    #[arg(long, default_value_t = bake_model::DEFAULT_RESOLUTION)]
    pub resolution: u32,
    /// Explicit resolutions, finest first, comma-separated (overrides --levels/--resolution).
    #[arg(long, value_delimiter = ',')]
    pub resolutions: Option<Vec<u32>>,
    /// Read the file as this format instead of going by its extension or content.
    #[arg(long = "format", value_enum)]
    pub file_type: Option<FileType>,
    /// Worker threads (default: all cores).
    #[arg(long)]
    pub threads: Option<usize>,
    /// Where point levels are baked: auto (a hardware GPU adapter, else the CPU with a notice;
    /// a software adapter such as lavapipe is slower than the CPU), on (any GPU adapter,
    /// software ones included, or an error), off (CPU).
    #[arg(long, value_enum, default_value_t = lod::GpuMode::Auto)]
    pub gpu: lod::GpuMode,
    /// GPU memory budget of one batch of point levels, in MiB.
    #[arg(long, default_value_t = lod::DEFAULT_GPU_BUDGET_MIB)]
    pub gpu_budget_mib: u64,
}

pub fn run(a: &BakeModelArgs) -> Result<()> {
    if let Some(n) = a.threads {
        rayon::ThreadPoolBuilder::new().num_threads(n).build_global().context("--threads")?;
    }
    let resolutions = match &a.resolutions {
        Some(r) => r.clone(),
        None => bake_model::ladder(a.resolution, a.levels)?,
    };
    let opts = ModelBakeOptions { resolutions, file_type: a.file_type };
    // Options and the file are checked before a GPU is opened, so a bad input is refused
    // quickly and with nothing but its own error on stderr.
    bake_model::check_options(&opts)?;
    let file = bake_model::read_model_file(&a.model, opts.file_type)?;
    let (baker, notice) = lod::PointBaker::open(a.gpu, a.gpu_budget_mib.saturating_mul(1 << 20))?;
    if let Some(n) = notice {
        eprintln!("{n}");
    }
    let s = bake_model::bake_read_model(&file, &opts, &baker, &Store::new(&a.out))?;
    let st = &s.stats;
    outln!(
        "{} ({}): {} faces → {} triangles read, {} degenerate skipped; {} vertices read, {} unreferenced \
         dropped, {} normals from the file",
        s.file,
        s.encoding,
        st.faces,
        st.triangles_read,
        st.degenerate,
        st.vertices_read,
        st.unreferenced,
        st.normals_from_file
    );
    outln!(
        "baked {} levels into {}{} in {:.3} s (read {:.3} s, bake {:.3} s); bounds {:?} – {:?}",
        s.levels.len(),
        a.out.display(),
        if s.resumed { " (same options: rewritten)" } else { "" },
        s.seconds,
        s.read_seconds,
        s.bake_seconds,
        s.bounds.min,
        s.bounds.max
    );
    outln!("point levels baked by {}", s.point_baker);
    outln!("{}", ModelLevelTable(&s.levels));
    Ok(())
}
