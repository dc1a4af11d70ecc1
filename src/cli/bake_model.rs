//! `terrastream bake-model`: an OBJ, STL or PLY model → a model tileset.

use std::path::PathBuf;

use anyhow::Result;
use terrastream::bake::model_tileset::{self as bake_model, ModelBakeOptions};
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
    /// Where the model sits on the globe in 3D Tiles, as LON,LAT[,HEIGHT]: the centre of its
    /// base is placed there, its +y up (default 0°, 0°, 0 m, stated in the tileset JSON).
    #[arg(long, value_parser = super::bake::parse_anchor, allow_hyphen_values = true)]
    pub anchor: Option<terrastream::formats::tiles3d::Anchor>,
    #[command(flatten)]
    pub baker: super::BakerArgs,
}

pub fn run(a: &BakeModelArgs) -> Result<()> {
    a.baker.set_threads()?;
    let resolutions = match &a.resolutions {
        Some(r) => r.clone(),
        None => bake_model::ladder(a.resolution, a.levels)?,
    };
    let opts = ModelBakeOptions { resolutions, file_type: a.file_type };
    // Options and the file are checked before a GPU is opened, so a bad input is refused
    // quickly and with nothing but its own error on stderr.
    bake_model::check_options(&opts)?;
    let file = bake_model::read_model_file(&a.model, opts.file_type)?;
    let baker = a.baker.open()?;
    let store = Store::at(&a.out)?;
    let s = bake_model::bake_model(&file, &opts, &baker, &store)?;
    if let Some(anchor) = a.anchor {
        terrastream::bake::export::write_anchor(&store, anchor)?;
    }
    outln!("{}", bake_model::ModelBakeReport { summary: &s, out: &a.out });
    // The paper's figures live with the evaluation (`client` feature).
    #[cfg(feature = "client")]
    {
        let levels: Vec<(u8, u64)> = s.levels.iter().map(|l| (l.level, u64::from(l.count))).collect();
        if let Some(t) = terrastream::eval::analysis::paper::table_3_comparison(&s.file, &levels) {
            outln!("{t}");
        }
    }
    Ok(())
}
