//! `terrastream export`: one (tile, level) decoded to PLY or OBJ in world coordinates.

use std::path::PathBuf;

use anyhow::Result;
use terrastream::store::{Store, export};
use terrastream::tiling::TileKey;

use super::parse_key;

#[derive(clap::Args)]
pub struct ExportArgs {
    /// Tileset directory.
    pub dir: PathBuf,
    #[arg(long, value_parser = parse_key)]
    pub tile: TileKey,
    #[arg(long)]
    pub level: u8,
    #[arg(long, value_enum, default_value_t = export::Format::Ply)]
    pub format: export::Format,
    #[arg(long)]
    pub out: PathBuf,
}

pub fn run(a: &ExportArgs) -> Result<()> {
    let n = export::export_tile(&Store::new(&a.dir), a.tile, a.level, a.format, &a.out)?;
    outln!("wrote {} ({n} {})", a.out.display(), if a.level == 0 { "vertices" } else { "points" });
    Ok(())
}
