//! `terrastream export`: one (tile, level) decoded to PLY or OBJ in world coordinates (the
//! format named by `--format` or by the extension of `--out`), or a whole tileset as static 3D
//! Tiles 1.1 (`--format 3dtiles`).

use std::path::PathBuf;
use std::time::{Duration, Instant};

use anyhow::{Result, bail};
use indicatif::{ProgressBar, ProgressStyle};
use terrastream::bake::export;
use terrastream::formats::interchange::Format;
use terrastream::formats::tiles3d::{Anchor, GlbCompression};
use terrastream::store::Store;
use terrastream::tiling::TileKey;

use super::parse_key;

/// What `export` writes.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum ExportFormat {
    /// One (tile, level) as binary little-endian PLY: positions as doubles, normals as floats.
    Ply,
    /// One (tile, level) as Wavefront OBJ text: `v`, `vn` (points) and `f` (mesh) lines.
    Obj,
    /// The whole tileset as OGC 3D Tiles 1.1 for static hosting (tileset.json, external
    /// tilesets per index chunk, one GLB per stored tile and level) into the folder --out.
    #[value(name = "3dtiles")]
    Tiles3d,
    /// A placed tileset's heightmap tiles on the Web-Mercator XYZ grid into the folder --out:
    /// {z}/{x}/{y}.png (Terrarium or Terrain-RGB, --encoding) or .f32 (--encoding float32) and
    /// tiles.json, the tiles the server gives at /tilesets/{name}/heightmap/.
    Heightmap,
}

#[derive(clap::Args)]
pub struct ExportArgs {
    /// Tileset directory.
    pub dir: PathBuf,
    /// The tile to export (PLY, OBJ).
    #[arg(long, value_parser = parse_key, required_unless_present = "format")]
    pub tile: Option<TileKey>,
    /// The level to export (PLY, OBJ).
    #[arg(long, required_unless_present = "format")]
    pub level: Option<u8>,
    /// What to write. Default: the format the extension of --out names (.ply, .obj), else PLY;
    /// a format that contradicts the extension is refused.
    #[arg(long, value_enum)]
    pub format: Option<ExportFormat>,
    /// The output file (PLY, OBJ: must not exist unless --force), or folder (3dtiles: created;
    /// must not exist or be empty).
    #[arg(long)]
    pub out: PathBuf,
    /// PLY, OBJ: overwrite an existing --out file.
    #[arg(long)]
    pub force: bool,
    /// 3dtiles: place the tileset at LON,LAT[,HEIGHT] (overrides the tileset's own anchor).
    #[arg(long, value_parser = super::bake::parse_anchor, allow_hyphen_values = true)]
    pub anchor: Option<Anchor>,
    /// 3dtiles: how the GLBs are compressed: none (plain glTF buffers, any reader), meshopt
    /// (EXT_meshopt_compression: far fewer bytes; the reader must support it: CesiumJS does,
    /// three.js with GLTFLoader.setMeshoptDecoder) or draco (KHR_draco_mesh_compression for
    /// meshes, the fewest bytes; points as meshopt; CesiumJS, three.js with DRACOLoader).
    #[arg(long, default_value = "none", value_parser = parse_glb_compression)]
    pub glb_compression: GlbCompression,
    /// heightmap: the zooms to write, A:B (default: 0 to where the tiles' pixels match the
    /// source's cells).
    #[arg(long, value_parser = parse_zooms)]
    pub zooms: Option<(u8, u8)>,
    /// heightmap: terrarium (default), terrain-rgb, or float32 (.f32 tiles).
    #[arg(long, default_value = "terrarium")]
    pub encoding: String,
    /// No progress bar.
    #[arg(long, short)]
    pub quiet: bool,
}

fn parse_glb_compression(s: &str) -> Result<GlbCompression, String> {
    GlbCompression::parse(s).ok_or_else(|| format!("{s:?}: give none, meshopt or draco"))
}

fn parse_zooms(s: &str) -> Result<(u8, u8), String> {
    let (a, b) = s.split_once(':').ok_or_else(|| format!("{s:?}: give the zooms as A:B, e.g. 0:12"))?;
    let z = |v: &str| v.parse::<u8>().map_err(|_| format!("{v:?} is not a zoom (0 to 22)"));
    Ok((z(a)?, z(b)?))
}

impl ExportFormat {
    fn name(self) -> &'static str {
        match self {
            Self::Ply => "ply",
            Self::Obj => "obj",
            Self::Tiles3d => "3dtiles",
            Self::Heightmap => "heightmap",
        }
    }
}

/// The format to write: `--format`, else the one the extension of `--out` names, else PLY. A
/// `--format` that contradicts the extension (`--format ply --out x.obj`, or 3D Tiles, a folder,
/// into `x.ply`) is refused rather than written under a misleading name.
fn format_of(a: &ExportArgs) -> Result<ExportFormat> {
    let by_ext = Format::from_extension(&a.out).map(|f| match f {
        Format::Ply => ExportFormat::Ply,
        Format::Obj => ExportFormat::Obj,
    });
    match (a.format, by_ext) {
        (Some(f), Some(e)) if f != e => bail!(
            "export: --format {} contradicts --out {} (a .{} file name); drop --format, or name the output after its format",
            f.name(),
            a.out.display(),
            e.name()
        ),
        (Some(f), _) => Ok(f),
        (None, Some(e)) => Ok(e),
        (None, None) => Ok(ExportFormat::Ply),
    }
}

pub fn run(a: &ExportArgs) -> Result<()> {
    let chosen = format_of(a)?;
    let store = Store::at(&a.dir)?;
    if chosen != ExportFormat::Tiles3d && a.glb_compression != GlbCompression::None {
        bail!("export: --glb-compression applies to 3D Tiles only (--format 3dtiles)");
    }
    let format = match chosen {
        ExportFormat::Ply => Format::Ply,
        ExportFormat::Obj => Format::Obj,
        ExportFormat::Tiles3d => return run_3dtiles(a, &store),
        ExportFormat::Heightmap => return run_heightmap(a, &store),
    };
    let (Some(tile), Some(level)) = (a.tile, a.level) else {
        bail!("export --format {}: --tile Z/X/Y and --level N name the tile to export", chosen.name());
    };
    if a.anchor.is_some() {
        bail!("export: --anchor places 3D Tiles only (--format 3dtiles); PLY and OBJ keep world coordinates");
    }
    let n = export::export_tile(&store, tile, level, format, &a.out, a.force)?;
    outln!("wrote {} ({n} {})", a.out.display(), if level == 0 { "vertices" } else { "points" });
    Ok(())
}

fn run_heightmap(a: &ExportArgs, store: &Store) -> Result<()> {
    if a.tile.is_some() || a.level.is_some() || a.anchor.is_some() || a.force {
        bail!(
            "export --format heightmap writes every tile of its zooms into a new folder: drop --tile, --level, --anchor and --force"
        );
    }
    let encoding = match a.encoding.as_str() {
        "float32" => None,
        e => Some(terrastream::formats::heightmap::Encoding::parse(e).ok_or_else(|| {
            anyhow::anyhow!("export --encoding {e:?}: use terrarium, terrain-rgb or float32")
        })?),
    };
    let bar = if a.quiet { ProgressBar::hidden() } else { ProgressBar::new(0) };
    bar.set_style(
        ProgressStyle::with_template("{bar:40} {pos}/{len} heightmap tiles  {per_sec}  ETA {eta}")
            .unwrap_or_else(|_| ProgressStyle::default_bar()),
    );
    bar.enable_steady_tick(Duration::from_millis(200));
    let t0 = Instant::now();
    let r = export::export_heightmap(store, &a.out, a.zooms, encoding, &|done, total| {
        bar.set_length(total);
        bar.set_position(done);
    });
    bar.finish_and_clear();
    let r = r?;
    outln!(
        "wrote {} in {:.2} s: {} heightmap tiles, zooms {}–{}, {} bytes; tiles.json is a MapLibre raster-dem source",
        a.out.display(),
        t0.elapsed().as_secs_f64(),
        r.tiles,
        r.zooms.0,
        r.zooms.1,
        r.bytes
    );
    Ok(())
}

fn run_3dtiles(a: &ExportArgs, store: &Store) -> Result<()> {
    if a.tile.is_some() || a.level.is_some() {
        bail!("export --format 3dtiles writes the whole tileset: drop --tile and --level");
    }
    if a.force {
        bail!(
            "export --format 3dtiles: --force overwrites PLY and OBJ files only; 3D Tiles go into a new or empty folder"
        );
    }
    let bar = if a.quiet { ProgressBar::hidden() } else { ProgressBar::new(0) };
    bar.set_style(
        ProgressStyle::with_template("{bar:40} {pos}/{len} GLBs  {per_sec}  ETA {eta}")
            .unwrap_or_else(|_| ProgressStyle::default_bar()),
    );
    bar.enable_steady_tick(Duration::from_millis(200));
    let t0 = Instant::now();
    let r = export::export_3dtiles_with(store, &a.out, a.anchor, a.glb_compression, &|done, total| {
        bar.set_length(total);
        bar.set_position(done);
    });
    bar.finish_and_clear();
    let r = r?;
    outln!(
        "wrote {} in {:.2} s: {} tileset JSON files, {} GLBs, {} bytes ({:.2}× the {} bytes of their blobs); open {}/tileset.json in any 3D Tiles client",
        a.out.display(),
        t0.elapsed().as_secs_f64(),
        r.documents,
        r.glbs,
        r.glb_bytes,
        r.glb_bytes as f64 / r.blob_bytes.max(1) as f64,
        r.blob_bytes,
        a.out.display()
    );
    Ok(())
}
