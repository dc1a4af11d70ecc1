//! `terrastream inspect`: a tileset's per-level totals and worst errors, or one node.

use std::path::PathBuf;

use anyhow::{Result, bail};
use terrastream::bake::model::{self, ModelLevelTable};
use terrastream::store::{LevelTable, LevelTotals, Store};
use terrastream::tiling::TileKey;

use super::parse_key;

#[derive(clap::Args)]
pub struct InspectArgs {
    /// Tileset directory.
    pub dir: PathBuf,
    /// Print JSON instead of a table.
    #[arg(long)]
    pub json: bool,
    /// One node, as Z/X/Y.
    #[arg(long, value_parser = parse_key)]
    pub tile: Option<TileKey>,
}

pub fn run(a: &InspectArgs) -> Result<()> {
    let (dir, json, tile) = (a.dir.as_path(), a.json, a.tile);
    let store = Store::new(dir);
    let manifest = store.manifest()?;
    if tile.is_none() && store.manifest_kind()? == terrastream::store::TilesetKind::Model {
        let m = model::read_manifest(&store)?;
        if json {
            outln!("{}", serde_json::to_string_pretty(&m)?);
            return Ok(());
        }
        outln!(
            "{}: model {} ({}, {} vertices, {} triangles; {} degenerate skipped), bounds {:?} – {:?}, \
             content version {}",
            dir.display(),
            m.model.file,
            m.model.encoding,
            m.model.vertices,
            m.model.triangles,
            m.model.degenerate_skipped,
            m.tileset.bounds.min.to_array(),
            m.tileset.bounds.max.to_array(),
            m.tileset.content_version
        );
        outln!("{}", ModelLevelTable(&m.model.levels));
        return Ok(());
    }
    if let Some(key) = tile {
        let Some(node) = store.node(key)? else {
            bail!("{}: no tile {key} in this tileset (depth {})", dir.display(), manifest.depth);
        };
        if json {
            outln!("{}", serde_json::to_string_pretty(&node)?);
        } else {
            outln!("tile {key}: bounds {:?} – {:?}", node.bounds.min.to_array(), node.bounds.max.to_array());
            let totals: Vec<LevelTotals> = node
                .levels
                .iter()
                .map(|l| {
                    let mut t = LevelTotals::default();
                    t.add(l);
                    t
                })
                .collect();
            outln!("{}", LevelTable(&totals));
        }
        return Ok(());
    }
    if json {
        outln!("{}", serde_json::to_string_pretty(&manifest)?);
    } else {
        outln!(
            "{}: {} ({}×{} samples, {}), tile size {}, depth {}, content version {}",
            dir.display(),
            manifest.source.file,
            manifest.source.width,
            manifest.source.height,
            manifest.source.format,
            manifest.tile_size,
            manifest.depth,
            manifest.content_version
        );
        outln!("{}", LevelTable(&manifest.totals));
    }
    Ok(())
}
