//! `terrastream inspect`: a tileset's per-level totals and worst errors, or one node.

use std::path::PathBuf;

use anyhow::{Result, bail};
use terrastream::bake::model_tileset::{self, ModelLevelTable};
use terrastream::store::{
    LevelTable, LevelTotals, NodeEntry, Store, level_sets, skipped_counts, skipped_levels,
};
use terrastream::tiling::Pyramid;
use terrastream::tiling::TileKey;

use super::parse_key;

/// What the error columns of a terrain tileset's table mean (docs/lod.md, DESIGN's "Geometric
/// error"): the figures of the two kinds of level measure different things.
pub const TERRAIN_LEGEND: &str = "\
errors: world units, the worst tile of each level. mesh (level 0): max err and worst rms are the
  vertical deviation from the full-resolution raster (gap 0). points (levels 1..): max err is the
  largest distance from a drawn point (footprint included) to the surface, worst rms the points'
  RMS distance, worst gap the largest distance from the surface to its nearest point (the widest
  hole). Point levels are coarser by design (cells of 2^l leaf cells), so their errors run far
  above the mesh's; a client draws a level only where the larger of max err and gap is under its
  pixel threshold on screen.";

/// What the error columns of a model tileset's table mean.
pub const MODEL_LEGEND: &str = "\
errors: model units. mesh (level 0): max err and rms are the distances between the file's
  vertices and their quantized positions (gap 0). points (levels 1..): max err is the largest
  distance from a drawn point (footprint included) to the model's surface, rms the points' RMS
  distance, gap the largest distance from the surface to its nearest point (the widest hole);
  coarser by design, so far above the mesh's.";

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
    let store = Store::at(dir)?;
    let manifest = store.manifest()?;
    if tile.is_none() && store.manifest_kind()? == terrastream::store::TilesetKind::Model {
        let m = model_tileset::read_manifest(&store)?;
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
        outln!("{MODEL_LEGEND}");
        let nodes: Vec<_> = store.node(TileKey::new(0, 0, 0))?.into_iter().collect();
        print_level_sets(&store, &nodes, &m.model.levels.iter().map(|l| l.level).collect::<Vec<u8>>())?;
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
            // One row per level of the ladder; a level the node does not store says so.
            let mut totals = vec![LevelTotals::default(); manifest.levels.len().max(1)];
            for l in &node.levels {
                if let Some(t) = totals.get_mut(usize::from(l.level)) {
                    t.add(l);
                }
            }
            outln!("{}", LevelTable(&totals));
            let ladder: Vec<u8> = manifest.levels.iter().map(|l| l.level).collect();
            for sk in skipped_levels(&store, &node, &ladder)? {
                outln!("level {} not stored: {}", sk.level, sk.why.describe());
            }
            outln!("{TERRAIN_LEGEND}");
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
        outln!("{TERRAIN_LEGEND}");
        let pyramid = Pyramid::new(manifest.source.width, manifest.source.height, manifest.tile_size)?;
        let nodes = store.all_nodes(&pyramid)?;
        print_level_sets(&store, &nodes, &manifest.levels.iter().map(|l| l.level).collect::<Vec<u8>>())?;
    }
    Ok(())
}

/// Which levels the nodes store, and why the others of `ladder` are left out (their markers).
fn print_level_sets(store: &Store, nodes: &[NodeEntry], ladder: &[u8]) -> Result<()> {
    outln!("levels per node (a node stores only the levels that pay):");
    for (set, n) in level_sets(nodes) {
        outln!("  {n:>7} nodes: levels {set:?}");
    }
    let skipped = skipped_counts(store, nodes, ladder)?;
    if !skipped.is_empty() {
        outln!("levels left out (nodes, level, why):");
        for ((level, why), n) in skipped {
            outln!("  {n:>7} nodes: level {level}: {}", why.describe());
        }
    }
    Ok(())
}
