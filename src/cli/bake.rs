//! `terrastream bake`: a heightfield raster → a tileset directory (resumes an interrupted bake).

use std::path::PathBuf;

use anyhow::{Context, Result};
use terrastream::bake::shard::InputOptions;
use terrastream::bake::{self, BakeOptions, BakeSummary};
use terrastream::crs::{Crs, VerticalDatum};
use terrastream::formats::tiles3d::Anchor;
use terrastream::raster::dataset::{Dataset, DatasetOptions, ScanRecord};
use terrastream::raster::{self, HeightEncoding};
use terrastream::store::Store;
use terrastream::tiling;

use super::parse_pair;

/// `--crs`: a CRS and the vertical datum it names, if any.
fn parse_crs(s: &str) -> Result<(Crs, Option<VerticalDatum>), String> {
    Crs::parse(s).map_err(|e| e.to_string())
}
use super::progress::{Bar, TILES_TEMPLATE, peak_rss_mib};

#[derive(clap::Args)]
pub struct BakeArgs {
    /// Input rasters forming one dataset: files (OpenEXR, 16-bit PNG, terrain-RGB/Terrarium PNG,
    /// GeoTIFF/COG/BigTIFF, SRTM .hgt), directories (their raster files, sorted by name) or
    /// patterns like 'tiles/*.tif'. Several files are placed on one grid by their georeference.
    #[arg(required_unless_present = "plan", conflicts_with = "plan", num_args = 1..)]
    pub inputs: Vec<PathBuf>,
    /// Output tileset directory (created; must be empty or an earlier bake of the same input).
    #[arg(long, required_unless_present = "plan", conflicts_with = "plan")]
    pub out: Option<PathBuf>,
    #[command(flatten)]
    pub input: InputArgs,
    /// Bake one shard of a sharded bake (`terrastream plan`): the tileset the plan was written
    /// to (its --out), or its shards/plan.json. The inputs and options are the plan's.
    /// Every option the plan fixes (how the inputs are read and tiled) is refused beside it:
    /// give those to `plan`.
    #[arg(long, value_name = "TILESET", conflicts_with_all = PLAN_FIXES)]
    pub plan: Option<PathBuf>,
    /// The shard to bake, 0 to N-1. Default: the array index of the engine running this process:
    /// JOB_COMPLETION_INDEX (Kubernetes Indexed Job), AWS_BATCH_JOB_ARRAY_INDEX (AWS Batch array
    /// job), SLURM_ARRAY_TASK_ID (Slurm job array, --array=0-(N-1)).
    #[arg(long, requires = "plan", conflicts_with = "finish")]
    pub shard: Option<u32>,
    /// The final step of a sharded bake: once every shard has finished, bake the tiles above the
    /// shards, write the index and the manifest, remove the plan.
    #[arg(long, requires = "plan")]
    pub finish: bool,
    #[command(flatten)]
    pub baker: super::BakerArgs,
    /// Stop the bake after this many seconds (between tiles; what is baked is kept and a re-run
    /// resumes it). Default: no limit.
    #[arg(long, value_name = "SECONDS", value_parser = parse_time_limit)]
    pub time_limit: Option<f64>,
    /// The origin of a local frame (an input without a coordinate system) on the globe, as
    /// LON,LAT[,HEIGHT] (WGS84 degrees, ellipsoidal metres): the centre of the data, at height
    /// 0, is placed there, east-north-up. Inputs with a CRS are placed exactly by it and ignore
    /// this; without either, 3D Tiles sit at 0°, 0°, 0 m and say so. Recorded in
    /// DIR/placement.json (no re-bake needed to change it). Also `--origin-lonlat`.
    #[arg(long, alias = "origin-lonlat", value_parser = parse_anchor, allow_hyphen_values = true)]
    pub anchor: Option<Anchor>,
    #[command(flatten)]
    pub terrain: TerrainArgs,
}

/// The flags of [`InputArgs`] a plan records and its steps take from it (`bake --plan` refuses
/// them, a usage error): all but `--cache-mib` and `--scratch-dir`, which are per process.
const PLAN_FIXES: [&str; 17] = [
    "tile_size",
    "max_error",
    "levels",
    "point_levels",
    "encoding",
    "channel",
    "cell_size",
    "origin",
    "z_scale",
    "z_offset",
    "crs",
    "vertical_datum",
    "geoid_grid",
    "target_crs",
    "max_side",
    "max_bytes",
    "allow_sparse",
];

/// Cesium globe terrain (quantized-mesh-1.0) beside the tileset.
#[derive(clap::Args, Clone)]
pub struct TerrainArgs {
    /// Also bake Cesium quantized-mesh-1.0 globe terrain into DIR/terrain: layer.json and
    /// {z}/{x}/{y}.terrain on the global geodetic grid, zoom 0 to where a tile's cells match the
    /// source's, ellipsoidal heights, every extension (normals, water mask, metadata). What
    /// CesiumJS, Cesium for Unreal/Unity and osgEarth read as terrain. Needs a placed input.
    /// Not with --plan: bake the terrain with a plain `bake` (it reads the inputs again).
    #[arg(long, conflicts_with = "plan")]
    pub terrain: bool,
    /// Scales the terrain's error bound at every zoom (1: CesiumJS's own estimate for the
    /// zoom, 77,067 m / 2^z; 0.25 gives tiles four times as exact, and more vertices).
    #[arg(long, default_value_t = 1.0, value_parser = parse_error_scale)]
    pub terrain_error_scale: f64,
    /// The terrain's deepest zoom (default: where a tile's cells match the source's).
    #[arg(long, value_parser = clap::value_parser!(u8).range(0..=24))]
    pub terrain_max_zoom: Option<u8>,
}

impl TerrainArgs {
    pub fn options(&self) -> bake::qmesh::TerrainOptions {
        bake::qmesh::TerrainOptions { error_scale: self.terrain_error_scale, max_zoom: self.terrain_max_zoom }
    }
}

fn parse_error_scale(s: &str) -> Result<f64, String> {
    let v: f64 = s.parse().map_err(|_| format!("{s:?} is not a number"))?;
    if v.is_finite() && v > 0.0 && v <= 1e6 { Ok(v) } else { Err(format!("{s} must be > 0 and at most 1e6")) }
}

/// How the inputs are read and baked: the flags `bake` and `plan` share, recorded in a plan
/// (as [`InputOptions`]) so that its shards read the inputs alike.
#[derive(clap::Args, Clone)]
pub struct InputArgs {
    /// Leaf tile size in raster cells.
    #[arg(long, default_value_t = tiling::DEFAULT_TILE_SIZE)]
    pub tile_size: u32,
    /// TIN error bound for leaf tiles, in metres (parents scale it with their cell size).
    #[arg(long, default_value_t = bake::DEFAULT_MAX_ERROR)]
    pub max_error: f64,
    /// Point-cloud levels below the mesh (cells of 2, 4, 8, … leaf cells).
    #[arg(long, default_value_t = bake::DEFAULT_LEVELS)]
    pub levels: u8,
    /// Which point levels a node stores: `auto`, those a screen-space selector can choose below
    /// the parent's mesh (docs/lod.md); `all`, every level cheaper than a finer one; `none`.
    #[arg(long, value_enum, default_value_t = bake::PointLevels::Auto)]
    pub point_levels: bake::PointLevels,
    /// How a PNG encodes heights.
    #[arg(long, value_enum)]
    pub encoding: Option<HeightEncoding>,
    /// OpenEXR channel to read (default: the first float channel).
    #[arg(long)]
    pub channel: Option<String>,
    /// Cell size in metres of a raster without a coordinate system (refused for one with a CRS:
    /// its grid says); for LAS/LAZ inputs, the grid's cell (required).
    #[arg(long)]
    pub cell_size: Option<f64>,
    /// World position of sample (0, 0) as X,Y of a raster without a coordinate system.
    #[arg(long, value_parser = parse_pair, allow_hyphen_values = true)]
    pub origin: Option<(f64, f64)>,
    /// Multiply raw sample values by this.
    #[arg(long, allow_hyphen_values = true)]
    pub z_scale: Option<f64>,
    /// Add this to heights after scaling.
    #[arg(long, allow_hyphen_values = true)]
    pub z_offset: Option<f64>,
    /// Memory for the block caches, in MiB: the dataset is read in blocks and never held whole.
    /// [default: 512] (with --plan: this process's, else the plan's)
    #[arg(long)]
    pub cache_mib: Option<u64>,
    /// Directory for scratch files (LAS/LAZ inputs are gridded there; default: the system's
    /// temporary directory). The files are unnamed and vanish when the bake ends.
    #[arg(long)]
    pub scratch_dir: Option<PathBuf>,
    /// The inputs' horizontal coordinate system, for inputs that state none or instead of what
    /// they state: EPSG:NNNN, EPSG:NNNN+VVVV (with a vertical CRS: 5773 EGM96, 3855 EGM2008), a
    /// PROJ string, or WKT with an EPSG identifier.
    #[arg(long, value_parser = parse_crs)]
    pub crs: Option<(Crs, Option<VerticalDatum>)>,
    /// What the heights are measured from (default: the input's; `.hgt` is EGM96; otherwise the
    /// ellipsoid). Globe outputs (3D Tiles) are always ellipsoidal.
    #[arg(long, value_enum)]
    pub vertical_datum: Option<VerticalDatum>,
    /// The geoid grid of --vertical-datum as a GTX file (EGM96 15′ is built in; EGM2008 needs
    /// one, e.g. PROJ's egm08_25.gtx).
    #[arg(long)]
    pub geoid_grid: Option<PathBuf>,
    /// Warp the inputs onto a grid in this CRS (EPSG:NNNN, a PROJ string or WKT). Inputs in
    /// different CRSs are warped onto the first input's CRS without it; the cells are the first
    /// input's, resampled bilinearly (no-data aware), the resampling's error added to every tile's.
    #[arg(long, value_parser = parse_crs)]
    pub target_crs: Option<(Crs, Option<VerticalDatum>)>,
    /// Refuse files decoded whole (PNG, OpenEXR) with a side longer than this many samples.
    #[arg(long, default_value_t = raster::DEFAULT_MAX_SIDE)]
    pub max_side: u32,
    /// Refuse files decoded whole (PNG, OpenEXR) whose heights exceed this many bytes.
    #[arg(long, default_value_t = raster::DEFAULT_MAX_BYTES)]
    pub max_bytes: u64,
    /// Accept a dataset (a GDAL VRT's extent, or files far apart) more than 64 times the size
    /// of the samples its files cover (by default refused: the rest is no-data, filled and
    /// baked as flat terrain).
    #[arg(long)]
    pub allow_sparse: bool,
}

/// An opened dataset and what a bake names it.
pub struct Opened {
    pub dataset: Dataset,
    pub name: String,
    pub files: Vec<PathBuf>,
}

impl InputArgs {
    /// The options these flags stand for (what a plan records).
    pub fn options(&self) -> InputOptions {
        InputOptions {
            tile_size: self.tile_size,
            max_error: self.max_error,
            levels: self.levels,
            point_levels: self.point_levels,
            encoding: self.encoding,
            channel: self.channel.clone(),
            cell_size: self.cell_size,
            origin: self.origin,
            z_scale: self.z_scale,
            z_offset: self.z_offset,
            cache_mib: self.cache_mib.unwrap_or(raster::dataset::DEFAULT_CACHE_BYTES >> 20),
            scratch_dir: self.scratch_dir.clone(),
            crs: self.crs.as_ref().map(|c| c.0.clone()),
            vertical_datum: self.vertical_datum.or(self.crs.as_ref().and_then(|c| c.1)),
            geoid_grid: self.geoid_grid.clone(),
            target_crs: self.target_crs.as_ref().map(|c| c.0.clone()),
            max_side: self.max_side,
            max_bytes: self.max_bytes,
            allow_sparse: self.allow_sparse,
        }
    }

    pub fn bake_options(&self) -> BakeOptions {
        self.options().bake_options()
    }

    /// Opens `files` (already expanded) as one dataset with a progress bar for the scan, and
    /// prints its summary unless `quiet`.
    pub fn open(&self, files: Vec<PathBuf>, quiet: bool) -> Result<Opened> {
        open_with(&self.options(), files, None, quiet)
    }
}

/// [`InputArgs::open`] with `opts`, taking the scan's results from `scanned` (a plan's record
/// and fallback grid) when it still stands for the files; else scanning them, with a notice.
pub fn open_with(
    opts: &InputOptions,
    files: Vec<PathBuf>,
    scanned: Option<(&ScanRecord, Option<&[u8]>)>,
    quiet: bool,
) -> Result<Opened> {
    bake::check_options(&opts.bake_options())?;
    let ds_opts = opts.dataset_options();
    let scan_bar = Bar::stderr("{msg:>16} {bar:40} {human_pos}/{human_len}  ETA {eta}", quiet, None);
    let progress = |what: &str, done, total| {
        let bar = scan_bar.bar();
        bar.set_message(what.to_owned());
        bar.set_length(total);
        bar.set_position(done);
        if total > 0 {
            scan_bar.show();
        }
    };
    let dataset = match scanned.map(|(r, f)| Dataset::open_scanned(&files, &ds_opts, r, f, &progress)) {
        Some(Ok(Ok(ds))) => Ok(ds),
        Some(Err(e)) => Err(e),
        Some(Ok(Err(why))) => {
            eprintln!("{why}: scanning the inputs whole to check them against the plan");
            Dataset::open(&files, &ds_opts, &progress)
        }
        None => Dataset::open(&files, &ds_opts, &progress),
    };
    scan_bar.finish();
    let dataset = dataset?;
    let file_name = |p: &std::path::Path| {
        p.file_name().map_or_else(|| p.display().to_string(), |n| n.to_string_lossy().into())
    };
    let name = match files.as_slice() {
        [one] => file_name(one),
        [first, rest @ ..] => format!("{} + {} more files", file_name(first), rest.len()),
        [] => String::new(),
    };
    if !quiet {
        eprintln!("{}", describe(&dataset, &ds_opts));
    }
    Ok(Opened { dataset, name, files })
}

/// The tiles progress bar of a bake (with `--time-limit`): drawn from the bake's start.
pub fn tiles_bar(quiet: bool, time_limit: Option<f64>) -> Bar {
    Bar::stderr(TILES_TEMPLATE, quiet, time_limit)
}

pub fn parse_anchor(s: &str) -> Result<Anchor, terrastream::formats::tiles3d::AnchorError> {
    Anchor::parse(s)
}

fn parse_time_limit(s: &str) -> Result<f64, String> {
    let v: f64 = s.parse().map_err(|_| format!("{s:?} is not a number of seconds"))?;
    if v.is_finite() && v > 0.0 && v <= 1e9 {
        Ok(v)
    } else {
        Err(format!("{s} must be > 0 and at most 1e9 seconds"))
    }
}

/// `bake INPUTS --out DIR` (a step of a sharded bake, `--plan`, is [`super::plan::run_step`]).
pub fn run(a: &BakeArgs, quiet: bool) -> Result<()> {
    a.baker.set_threads()?;
    let Some(out) = &a.out else { anyhow::bail!("bake: --out is required") };
    let store = Store::at(out)?;
    store.check_out()?;
    let files = raster::dataset::expand_inputs(&a.inputs)?;
    let opened = a.input.open(files, quiet)?;
    if a.terrain.terrain && !opened.dataset.georef().is_placed() {
        anyhow::bail!(
            "--terrain: globe terrain needs an input placed on the Earth; {} has no coordinate reference system (give --crs)",
            opened.name
        );
    }
    // The globe terrain's source is made before the bake (its frame, geoid grid and heights
    // checked), so a bake that cannot make its terrain stops before writing anything.
    let terrain = if a.terrain.terrain {
        let src =
            bake::qmesh::TerrainSource::new(&opened.dataset, opened.dataset.georef(), a.terrain.options());
        Some(src.with_context(|| format!("--terrain: {}", opened.name))?)
    } else {
        None
    };
    let baker = a.baker.open()?;
    let progress = tiles_bar(quiet, a.time_limit);
    let input = bake::TerrainInput::of_dataset(&opened.dataset);
    let opts = a.input.bake_options();
    let summary = bake::bake_input(&input, &opened.name, &opts, &baker, &store, &progress);
    progress.finish();
    let summary = summary?;
    if let Some(anchor) = a.anchor {
        terrastream::bake::export::write_anchor(&store, anchor)?;
    }
    print_summary(&summary, out);
    if let Some(src) = &terrain {
        bake_globe_terrain(&opened, src, &store, quiet)?;
    }
    Ok(())
}

/// The `--terrain` stage: every quantized-mesh tile of the dataset into `store`'s `terrain/`.
fn bake_globe_terrain(
    opened: &Opened,
    src: &bake::qmesh::TerrainSource<'_>,
    store: &Store,
    quiet: bool,
) -> Result<()> {
    let version = store
        .read_file(terrastream::store::MANIFEST_FILE)?
        .and_then(|b| serde_json::from_slice::<serde_json::Value>(&b).ok())
        .and_then(|m| m["content_version"].as_str().map(str::to_owned))
        .unwrap_or_default();
    let bar = Bar::stderr("terrain {bar:40} {pos}/{len} tiles  {per_sec}  ETA {eta}  {elapsed}", quiet, None);
    bar.bar().set_length(src.coverage.tile_count());
    bar.show();
    let stats = bake::qmesh::bake_terrain_tiles(src, store, &opened.name, &version, &|done, _| {
        bar.bar().set_position(done);
    });
    bar.finish();
    let stats = stats?;
    outln!(
        "terrain: {} quantized-mesh tiles, zoom 0–{}, in {:.1} s ({:.0} tiles/s; building {:.2} ms a tile, p99 {:.2}), {:.1} MB with every extension ({:.1} MB gzipped), {}",
        stats.tiles,
        stats.max_zoom,
        stats.seconds,
        stats.tiles as f64 / stats.seconds.max(1e-9),
        stats.build_seconds * 1e3 / stats.tiles.max(1) as f64,
        stats.ms_p99,
        stats.bytes_raw_all as f64 / 1e6,
        stats.bytes_gzip_all as f64 / 1e6,
        store.describe("terrain/layer.json"),
    );
    if stats.lattice_misses > 0 {
        eprintln!(
            "warning: terrain: {} tiles have more relief than their edge lattice holds; their edges may differ \
             from their neighbours' by a height step (see terrain/stats.json)",
            stats.lattice_misses
        );
    }
    // The same terrain as static 3D Tiles (the bytes `serve` sends under terrain/3dtiles/).
    let w = bake::terrain3d::write_terrain_3dtiles(store)?;
    outln!(
        "terrain as 3D Tiles: {} GLBs, {} subtrees, {:.1} MB, {}",
        w.glbs,
        w.subtrees,
        w.bytes as f64 / 1e6,
        store.describe(&format!("{}/tileset.json", bake::terrain3d::TILES3D_DIR)),
    );
    Ok(())
}

pub fn print_summary(s: &BakeSummary, out: &std::path::Path) {
    outln!("{}", bake::BakeReport { summary: s, out, peak_rss_mib: peak_rss_mib() });
}

/// The dataset summary printed before the bake: files, grid, extent, CRS, no-data, heights.
fn describe(ds: &Dataset, _opts: &DatasetOptions) -> String {
    use std::fmt::Write;
    let s = ds.summary();
    let g = ds.georef();
    let files = match s.files.as_slice() {
        [one] => one.display().to_string(),
        many => format!("{} files ({} … {})", many.len(), many[0].display(), many[many.len() - 1].display()),
    };
    let unit = if g.crs.as_ref().is_some_and(|c| c.crs.is_geographic()) { "°" } else { "" };
    let mut out = format!(
        "{files}: {}×{} {} samples, {} CRS, extent x {:.6}{unit}..{:.6}{unit}, y {:.6}{unit}..{:.6}{unit}, cell {:.3} × {:.3} m, {} no-data filled",
        s.width,
        s.height,
        s.format,
        s.crs,
        s.extent[0],
        s.extent[2],
        s.extent[1],
        s.extent[3],
        g.dx.abs(),
        g.dy.abs(),
        s.nodata_filled,
    );
    if s.nodata_fallback > 0 {
        let _ = write!(
            out,
            " ({} beyond the fill's reach of {} cells, set from the block-mean fallback)",
            s.nodata_fallback,
            raster::dataset::FILL_REACH
        );
    }
    if let Some(p) = &s.points {
        let rule = match (p.classified_files, s.files.len()) {
            (0, _) => "no file is classified: each cell takes its lowest point".to_owned(),
            (c, n) if c == n => {
                "every file is classified: each cell takes the mean of its ground (class 2) points".into()
            }
            (c, n) => format!(
                "{c} of {n} files are classified (their cells take the mean of the ground points), the others give each cell its lowest point"
            ),
        };
        let _ = write!(
            out,
            "\npoints: {} read, {} used; {rule}; {} of {} cells got points, the rest are filled like no-data",
            p.points,
            p.used,
            p.cells_with_points,
            u64::from(s.width) * u64::from(s.height)
        );
    }
    match s.vertical {
        Some(v) => {
            let _ = write!(
                out,
                "\nheights: {} ({})",
                v.name(),
                match v {
                    VerticalDatum::Ellipsoid =>
                        "the input states no vertical datum, so its heights are taken as ellipsoidal; give --vertical-datum if they are not",
                    VerticalDatum::Egm96 | VerticalDatum::Egm2008 =>
                        "orthometric: globe outputs add the geoid's undulation",
                }
            );
        }
        None => {
            let _ = write!(
                out,
                "\nno coordinate system: a local frame; globe outputs need --anchor (or --crs on a georeferenced grid)"
            );
        }
    }
    out
}
