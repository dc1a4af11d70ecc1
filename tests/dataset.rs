//! Datasets read in blocks (issue 14): mosaics equal to the single file, refused mosaics naming
//! the file, out-of-core bakes byte-identical to in-memory ones, a raster larger than the block
//! cache, and the local no-data fill.

// Helpers outside `#[test]` functions unwrap too: a failure there is a test failure.
#![allow(clippy::unwrap_used, clippy::float_cmp, clippy::cast_lossless, clippy::type_complexity)]

mod common;
use common::{bin, blobs_and_index, fails, ok, tree};

use std::path::{Path, PathBuf};

use terrastream::bake::PointLevels;
use terrastream::bake::{self, BakeOptions, NoProgress, TerrainInput};
use terrastream::lod::PointBaker;
use terrastream::raster::dataset::{Dataset, DatasetOptions, MIN_CACHE_BYTES};
use terrastream::raster::geotiff::{Model, write_tiled_f32};
use terrastream::raster::{self, HeightEncoding, LoadOptions, Overrides, WindowReader};
use terrastream::store::Store;

const OPTS: BakeOptions =
    BakeOptions { tile_size: 64, max_error: 1.0, levels: 2, point_levels: PointLevels::Auto };

/// Writes a tiled float32 GeoTIFF of `w × h` samples of `f(col, row)` (global coordinates
/// offset by `(c0, r0)`), origin of its sample (0, 0) at the matching world position.
#[allow(clippy::too_many_arguments)]
fn tiled(
    path: &Path,
    (w, h): (u32, u32),
    (c0, r0): (u32, u32),
    cell: f64,
    model: Model,
    nodata: Option<f64>,
    f: &dyn Fn(u32, u32) -> f32,
) {
    let mut file = std::fs::File::create(path).unwrap();
    let origin = (f64::from(c0) * cell, 1000.0 - f64::from(r0) * cell);
    write_tiled_f32(&mut file, (w, h), 32, model, origin, (cell, -cell), nodata, false, |c, r| {
        f(c + c0, r + r0)
    })
    .unwrap();
}

fn terrain(c: u32, r: u32) -> f32 {
    raster::synth::height_at(300, 200, 7, c, r)
}

fn open(paths: &[PathBuf], cache: u64) -> Result<Dataset, raster::RasterError> {
    let opts = DatasetOptions { cache_bytes: cache, ..DatasetOptions::default() };
    Dataset::open(paths, &opts, &|_, _, _| {})
}

fn bake_dataset(ds: &Dataset, name: &str, out: &Path) {
    bake::bake_input(
        &TerrainInput::of_dataset(ds),
        name,
        &OPTS,
        &PointBaker::Cpu,
        &Store::new(out),
        &NoProgress,
    )
    .unwrap();
}

fn bake_memory(raster: &raster::LoadedRaster, name: &str, out: &Path) {
    bake::bake_terrain(raster, name, &OPTS, &PointBaker::Cpu, &Store::new(out), &NoProgress).unwrap();
}

fn assert_same_tileset(a: &Path, b: &Path) {
    let (ta, tb) = (blobs_and_index(a), blobs_and_index(b));
    assert!(ta.len() > 10, "too few files: {}", ta.len());
    assert_eq!(ta.keys().collect::<Vec<_>>(), tb.keys().collect::<Vec<_>>());
    for (k, v) in &ta {
        assert!(v == &tb[k], "{k} differs");
    }
}

#[test]
fn mosaic_of_tiles_bakes_as_the_single_file() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let whole = d.join("whole.tif");
    tiled(&whole, (300, 200), (0, 0), 10.0, Model::Projected, None, &terrain);
    // 3 × 2 tiles sharing one-sample edges, given in a scrambled order; then a glob and a dir.
    let mut tiles = Vec::new();
    for (i, (c0, c1)) in [(0, 100), (100, 200), (200, 299)].into_iter().enumerate() {
        for (j, (r0, r1)) in [(0, 120), (120, 199)].into_iter().enumerate() {
            let p = d.join(format!("t{j}{i}.tif"));
            tiled(&p, (c1 - c0 + 1, r1 - r0 + 1), (c0, r0), 10.0, Model::Projected, None, &terrain);
            tiles.push(p);
        }
    }
    tiles.reverse();
    let (a, b) = (d.join("a"), d.join("b"));
    let ds = open(&tiles, MIN_CACHE_BYTES).unwrap();
    assert_eq!((ds.summary().width, ds.summary().height), (300, 200));
    assert_eq!(ds.summary().crs, "local");
    bake_dataset(&ds, "mosaic", &a);
    bake_dataset(&open(&[whole], MIN_CACHE_BYTES).unwrap(), "whole.tif", &b);
    assert_same_tileset(&a, &b);

    // The binary takes a pattern and a directory for the same mosaic.
    let (c, e) = (d.join("c"), d.join("e"));
    let tiles_dir = d.join("tiles");
    std::fs::create_dir(&tiles_dir).unwrap();
    for t in &tiles {
        std::fs::copy(t, tiles_dir.join(t.file_name().unwrap())).unwrap();
    }
    let args = ["bake", "--quiet", "--tile-size", "64", "--max-error", "1", "--levels", "2", "--out"];
    ok(bin().args(args).arg(&c).arg(d.join("t*.tif")));
    ok(bin().args(args).arg(&e).arg(&tiles_dir));
    assert_same_tileset(&a, &c);
    assert_same_tileset(&a, &e);
}

#[test]
fn hgt_mosaic_bakes_as_one_geographic_file() {
    // Two 3-arc-second tiles side by side (they share a column) against one GeoTIFF of the
    // same 2° × 1° in degrees.
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let side = 1201u32;
    let f = |c: u32, r: u32| (raster::synth::height_at(2401, 1201, 3, c, r) * 0.5).round();
    let mut tiles = Vec::new();
    for (k, name) in ["N35E138.hgt", "N35E139.hgt"].into_iter().enumerate() {
        let mut bytes = Vec::with_capacity((side * side * 2) as usize);
        for r in 0..side {
            for c in 0..side {
                bytes.extend_from_slice(&(f(c + k as u32 * 1200, r) as i16).to_be_bytes());
            }
        }
        let p = d.join(name);
        std::fs::write(&p, bytes).unwrap();
        tiles.push(p);
    }
    let whole = d.join("whole.tif");
    let mut file = std::fs::File::create(&whole).unwrap();
    let step = 1.0 / 1200.0;
    write_tiled_f32(
        &mut file,
        (2401, 1201),
        256,
        Model::Geographic,
        (138.0, 36.0),
        (step, -step),
        None,
        false,
        f,
    )
    .unwrap();
    drop(file);
    let opts = BakeOptions { tile_size: 256, max_error: 4.0, levels: 1, point_levels: PointLevels::Auto };
    let (a, b) = (d.join("a"), d.join("b"));
    for (inputs, out) in [(tiles.clone(), &a), (vec![whole], &b)] {
        let ds = open(&inputs, 64 << 20).unwrap();
        assert_eq!(
            (ds.summary().width, ds.summary().height, ds.summary().crs.as_str()),
            (2401, 1201, "EPSG:4326")
        );
        bake::bake_input(
            &TerrainInput::of_dataset(&ds),
            "x",
            &opts,
            &PointBaker::Cpu,
            &Store::new(out),
            &NoProgress,
        )
        .unwrap();
    }
    assert_same_tileset(&a, &b);
}

#[test]
fn mosaics_that_do_not_fit_are_refused_naming_the_file() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let base = d.join("base.tif");
    tiled(&base, (50, 40), (0, 0), 10.0, Model::Projected, None, &terrain);
    let cases: [(&str, Box<dyn Fn(&Path)>, &str); 4] = [
        (
            "misaligned.tif",
            Box::new(|p: &Path| {
                let mut f = std::fs::File::create(p).unwrap();
                write_tiled_f32(
                    &mut f,
                    (50, 40),
                    32,
                    Model::Projected,
                    (495.5, 1000.0),
                    (10.0, -10.0),
                    None,
                    false,
                    terrain,
                )
                .unwrap();
            }),
            "not aligned",
        ),
        (
            "coarser.tif",
            Box::new(|p: &Path| tiled(p, (50, 40), (49, 0), 20.0, Model::Projected, None, &terrain)),
            "cell size",
        ),
        (
            "degrees.tif",
            Box::new(|p: &Path| {
                let mut f = std::fs::File::create(p).unwrap();
                write_tiled_f32(
                    &mut f,
                    (50, 40),
                    32,
                    Model::Geographic,
                    (10.0, 50.0),
                    (0.001, -0.001),
                    None,
                    false,
                    terrain,
                )
                .unwrap();
            }),
            "coordinate system",
        ),
        (
            "overlap.tif",
            Box::new(|p: &Path| tiled(p, (50, 40), (45, 0), 10.0, Model::Projected, None, &terrain)),
            "overlaps",
        ),
    ];
    for (name, make, what) in cases {
        let p = d.join(name);
        make(&p);
        let e = open(&[base.clone(), p.clone()], MIN_CACHE_BYTES).err().unwrap().to_string();
        assert!(e.contains(name) && e.contains(what), "{name}: {e}");
        // Through the binary too: nothing written.
        let out = d.join(format!("out-{name}"));
        let msg = fails(bin().args(["bake", "--quiet", "--out"]).arg(&out).arg(&base).arg(&p));
        assert!(msg.contains(name) && msg.contains(what), "{msg}");
        assert!(!out.join("tileset.json").exists());
    }
    // The same file twice overlaps itself.
    let e = open(&[base.clone(), base.clone()], MIN_CACHE_BYTES).err().unwrap().to_string();
    assert!(e.contains("overlaps"), "{e}");
    // A PNG has no georeference, so it cannot join a mosaic.
    let opts = DatasetOptions {
        load: LoadOptions { encoding: Some(HeightEncoding::TerrainRgb), ..LoadOptions::default() },
        ..DatasetOptions::default()
    };
    let png = common::fuji_or_generated(d, "dataset: a PNG in a mosaic");
    let e = Dataset::open(&[base, png], &opts, &|_, _, _| {}).err().unwrap().to_string();
    assert!(e.contains("fuji.png") && e.contains("no georeference"), "{e}");
}

#[test]
fn out_of_core_fuji_is_byte_identical_to_in_memory() {
    let dir = tempfile::tempdir().unwrap();
    let fuji =
        common::fuji_or_generated(dir.path(), "dataset::out_of_core_fuji_is_byte_identical_to_in_memory");
    let load = LoadOptions {
        encoding: Some(HeightEncoding::TerrainRgb),
        overrides: Overrides { cell_size: Some(30.0), ..Overrides::default() },
        ..LoadOptions::default()
    };
    let raster = raster::load(&fuji, &load).unwrap();
    let opts = DatasetOptions { load, cache_bytes: MIN_CACHE_BYTES, ..DatasetOptions::default() };
    let ds = Dataset::open(std::slice::from_ref(&fuji), &opts, &|_, _, _| {}).unwrap();
    let (a, b) = (dir.path().join("a"), dir.path().join("b"));
    bake_memory(&raster, "fuji.png", &a);
    bake_dataset(&ds, "fuji.png", &b);
    // Here the whole tileset is the same, manifest and options included.
    assert_eq!(tree(&a), tree(&b));
}

/// A raster with no-data: small holes (within the fill's reach) and a wide one (beyond it).
fn holey(c: u32, r: u32) -> f32 {
    let small = (c % 97 < 3) && (r % 89 < 4);
    let wide = (150..420).contains(&c) && (100..300).contains(&r);
    if small || wide { -9999.0 } else { raster::synth::height_at(600, 400, 11, c, r) }
}

#[test]
fn out_of_core_with_no_data_matches_in_memory_under_a_small_cache() {
    // 600 × 400 f32 = 960 KB decoded; the cache holds 4 MiB split between raw and filled
    // blocks of 256 KB, so blocks are evicted and read again during the bake.
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("holey.tif");
    tiled(&p, (600, 400), (0, 0), 5.0, Model::Projected, Some(-9999.0), &holey);
    let raster = raster::load(&p, &LoadOptions::default()).unwrap();
    let ds = open(std::slice::from_ref(&p), MIN_CACHE_BYTES).unwrap();
    let s = ds.summary();
    assert_eq!(s.nodata_filled, raster.nodata_filled);
    assert_eq!(s.nodata_fallback, raster.nodata_fallback);
    assert!(s.nodata_fallback > 0 && s.nodata_fallback < s.nodata_filled, "{s:?}");
    // The same heights sample for sample.
    let cols: Vec<u32> = (0..600).collect();
    let rows: Vec<u32> = (0..400).collect();
    let mut v = Vec::new();
    ds.read_window(&cols, &rows, &mut v).unwrap();
    assert!(v == raster.heights.data);
    let (a, b) = (dir.path().join("a"), dir.path().join("b"));
    bake_memory(&raster, "holey.tif", &a);
    bake_dataset(&ds, "holey.tif", &b);
    assert_eq!(tree(&a), tree(&b));
    // The record says the fill rule beyond the reach was used.
    let options: serde_json::Value =
        serde_json::from_slice(&std::fs::read(b.join("bake-options.json")).unwrap()).unwrap();
    assert_eq!(options["fill"]["reach"], 64);
}

/// A dataset opened from its scan record (what the shards of a sharded bake do) reads and
/// bakes exactly as the scanned one, without the scan; a changed file, a record of another
/// dataset or a damaged fallback grid is not taken (the caller scans), and a point cloud is
/// never opened from a record.
#[test]
fn a_scan_record_opens_the_same_dataset_without_scanning_and_only_while_it_stands() {
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("holey.tif");
    tiled(&p, (600, 400), (0, 0), 5.0, Model::Projected, Some(-9999.0), &holey);
    let paths = vec![p.clone()];
    let opts = DatasetOptions { cache_bytes: MIN_CACHE_BYTES, ..DatasetOptions::default() };
    let scanned = Dataset::open(&paths, &opts, &|_, _, _| {}).unwrap();
    let (record, fallback) = scanned.scan_record().unwrap();
    let fallback = fallback.expect("a dataset with no-data has a fallback grid");
    assert_eq!(record.nodata_filled, scanned.summary().nodata_filled);
    // The record survives its JSON form.
    let record: terrastream::raster::dataset::ScanRecord =
        serde_json::from_value(serde_json::to_value(&record).unwrap()).unwrap();

    let passes = std::sync::atomic::AtomicU32::new(0);
    let counting = |_: &str, _: u64, _: u64| {
        passes.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
    };
    let ds = Dataset::open_scanned(&paths, &opts, &record, Some(&fallback), &counting).unwrap().unwrap();
    assert_eq!(passes.load(std::sync::atomic::Ordering::Relaxed), 0, "the record's dataset was scanned");
    assert_eq!(serde_json::to_value(ds.summary()).unwrap(), serde_json::to_value(scanned.summary()).unwrap());
    let cols: Vec<u32> = (0..600).collect();
    let rows: Vec<u32> = (0..400).collect();
    let (mut a, mut b) = (Vec::new(), Vec::new());
    ds.read_window(&cols, &rows, &mut a).unwrap();
    scanned.read_window(&cols, &rows, &mut b).unwrap();
    assert!(a == b, "other heights from the record's dataset");
    let (ta, tb) = (dir.path().join("a"), dir.path().join("b"));
    bake_dataset(&ds, "holey.tif", &ta);
    bake_dataset(&scanned, "holey.tif", &tb);
    assert_eq!(tree(&ta), tree(&tb));

    let not_taken =
        |record: &terrastream::raster::dataset::ScanRecord, fallback: Option<&[u8]>, want: &str| {
            let why = Dataset::open_scanned(&paths, &opts, record, fallback, &|_, _, _| {})
                .unwrap()
                .err()
                .unwrap()
                .to_string();
            assert!(why.contains(want), "{why}");
        };
    let mut damaged = fallback.clone();
    damaged[5] ^= 1;
    not_taken(&record, Some(&damaged), "fallback grid");
    not_taken(&record, None, "fallback grid");
    not_taken(&record, Some(&fallback[4..]), "fallback grid");
    let mut other = record.clone();
    other.width += 1;
    not_taken(&other, Some(&fallback), "600x400");
    // The file rewritten (same length, later time): its stamp differs.
    std::thread::sleep(std::time::Duration::from_millis(20));
    tiled(&p, (600, 400), (0, 0), 5.0, Model::Projected, Some(-9999.0), &|c, r| holey(c, r) + 1.0);
    not_taken(&record, Some(&fallback), "has changed since the scan");
}

#[test]
fn local_fill_equals_the_unbounded_fill_within_its_reach() {
    // Holes no wider than the reach: the local fill is the old whole-raster wavefront exactly,
    // so tilesets of such rasters keep their bytes (checked against a hand-rolled wavefront).
    let (w, h) = (300u32, 200u32);
    let hole = |c: u32, r: u32| (40..100).contains(&c) && (30..90).contains(&r);
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("h.tif");
    let f = |c: u32, r: u32| if hole(c, r) { -1.0 } else { terrain(c, r) };
    tiled(&p, (w, h), (0, 0), 10.0, Model::Projected, Some(-1.0), &f);
    let ds = open(&[p], MIN_CACHE_BYTES).unwrap();
    assert_eq!(ds.summary().nodata_fallback, 0);
    let mut got = Vec::new();
    ds.read_window(&(0..w).collect::<Vec<_>>(), &(0..h).collect::<Vec<_>>(), &mut got).unwrap();
    // The unbounded wavefront, written out here.
    let mut want: Vec<f32> =
        (0..h).flat_map(|r| (0..w).map(move |c| if hole(c, r) { f32::NAN } else { terrain(c, r) })).collect();
    loop {
        let prev = want.clone();
        let mut changed = false;
        for r in 0..h as i64 {
            for c in 0..w as i64 {
                if prev[(r * w as i64 + c) as usize].is_finite() {
                    continue;
                }
                let (mut s, mut n) = (0.0f64, 0u32);
                for (dc, dr) in [(-1, -1), (0, -1), (1, -1), (-1, 0), (1, 0), (-1, 1), (0, 1), (1, 1)] {
                    let (cc, rr) = (c + dc, r + dr);
                    if cc >= 0 && rr >= 0 && cc < w as i64 && rr < h as i64 {
                        let v = prev[(rr * w as i64 + cc) as usize];
                        if v.is_finite() {
                            s += f64::from(v);
                            n += 1;
                        }
                    }
                }
                if n > 0 {
                    want[(r * w as i64 + c) as usize] = (s / f64::from(n)) as f32;
                    changed = true;
                }
            }
        }
        if !changed {
            break;
        }
    }
    assert!(got == want);
}

#[test]
fn bigtiff_and_striped_tiff_read_as_the_tiled_one() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let (w, h) = (150u32, 90u32);
    let mut read = Vec::new();
    for (name, big) in [("classic.tif", false), ("big.tif", true)] {
        let p = d.join(name);
        let mut f = std::fs::File::create(&p).unwrap();
        write_tiled_f32(&mut f, (w, h), 48, Model::Projected, (0.0, 0.0), (2.0, -2.0), None, big, terrain)
            .unwrap();
        drop(f);
        read.push(p);
    }
    // Strips of 64 rows, from the strip encoder.
    let data: Vec<f32> = (0..h).flat_map(|r| (0..w).map(move |c| terrain(c, r))).collect();
    let strips = d.join("strips.tif");
    std::fs::write(&strips, raster::geotiff::encode_f32(w, h, &data, (0.0, 0.0), (2.0, -2.0)).unwrap())
        .unwrap();
    read.push(strips);
    let cols: Vec<u32> = (0..w).step_by(7).collect();
    let rows: Vec<u32> = (0..h).collect();
    let mut want = Vec::new();
    raster::Heightfield { width: w, height: h, data }.read_window(&cols, &rows, &mut want).unwrap();
    for p in read {
        let ds = open(std::slice::from_ref(&p), MIN_CACHE_BYTES).unwrap();
        let mut got = Vec::new();
        ds.read_window(&cols, &rows, &mut got).unwrap();
        assert!(got == want, "{}", p.display());
    }
}

#[test]
fn a_truncated_tiled_tiff_is_an_error_naming_it_and_nothing_is_baked() {
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("cut.tif");
    tiled(&p, (300, 200), (0, 0), 10.0, Model::Projected, None, &terrain);
    let mut bytes = std::fs::read(&p).unwrap();
    // The tile offsets are the first array after the 10 × 7 tiles of 32² f32: point tile 5 past
    // the end of the file, as a truncated download would leave it.
    let offsets = 8 + 70 * 32 * 32 * 4;
    let past = (bytes.len() as u32 + 1000).to_le_bytes();
    bytes[offsets + 5 * 4..offsets + 6 * 4].copy_from_slice(&past);
    std::fs::write(&p, &bytes).unwrap();
    let e = open(std::slice::from_ref(&p), MIN_CACHE_BYTES).err().map(|e| e.to_string());
    let out = dir.path().join("out");
    let msg = fails(bin().args(["bake", "--quiet", "--out"]).arg(&out).arg(&p));
    assert!(msg.contains("cut.tif"), "{msg}");
    assert!(e.is_some_and(|e| e.contains("cut.tif")));
    assert!(!out.join("tileset.json").exists());
}

/// A VRT over `sources` (file, SrcRect, DstRect as x, y, w, h), on the grid of `tiled`'s files
/// (cells of 10, sample (0, 0) centred at (0, 1000)).
fn vrt_text(size: (u32, u32), band_extra: &str, sources: &[(String, [u32; 4], [u32; 4], &str)]) -> String {
    use std::fmt::Write;
    let mut s = format!(
        "<VRTDataset rasterXSize=\"{}\" rasterYSize=\"{}\">\n  <SRS></SRS>\n  \
         <GeoTransform>-5.0, 10.0, 0.0, 1005.0, 0.0, -10.0</GeoTransform>\n  <VRTRasterBand dataType=\"Float32\" band=\"1\">{band_extra}\n",
        size.0, size.1
    );
    for (file, src, dst, kind) in sources {
        let _ = writeln!(
            s,
            "    <{kind}><SourceFilename relativeToVRT=\"1\">{file}</SourceFilename><SourceBand>1</SourceBand>\
             <SrcRect xOff=\"{}\" yOff=\"{}\" xSize=\"{}\" ySize=\"{}\"/><DstRect xOff=\"{}\" yOff=\"{}\" xSize=\"{}\" ySize=\"{}\"/>{}</{kind}>",
            src[0],
            src[1],
            src[2],
            src[3],
            dst[0],
            dst[1],
            dst[2],
            dst[3],
            if *kind == "ComplexSource" { "<NODATA>-1</NODATA>" } else { "" }
        );
    }
    s + "  </VRTRasterBand>\n</VRTDataset>\n"
}

#[test]
fn vrt_mosaic_equals_the_single_file_and_a_subset_reads_its_window() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let whole = d.join("whole.tif");
    tiled(&whole, (300, 200), (0, 0), 10.0, Model::Projected, None, &terrain);
    // Two halves that do not share an edge, one a ComplexSource with a NODATA value.
    tiled(&d.join("w.tif"), (150, 200), (0, 0), 10.0, Model::Projected, None, &terrain);
    // The east half is stored with 7 spare columns on its left: the SrcRect skips them.
    tiled(&d.join("e.tif"), (157, 200), (143, 0), 10.0, Model::Projected, None, &terrain);
    let mosaic = d.join("mosaic.vrt");
    let text = vrt_text(
        (300, 200),
        "<NoDataValue>-9999</NoDataValue>",
        &[
            ("w.tif".into(), [0, 0, 150, 200], [0, 0, 150, 200], "SimpleSource"),
            ("e.tif".into(), [7, 0, 150, 200], [150, 0, 150, 200], "ComplexSource"),
        ],
    );
    std::fs::write(&mosaic, text).unwrap();
    let ds = open(std::slice::from_ref(&mosaic), MIN_CACHE_BYTES).unwrap();
    assert_eq!((ds.summary().width, ds.summary().height, ds.summary().crs.as_str()), (300, 200, "local"));
    let (a, b) = (d.join("a"), d.join("b"));
    bake_dataset(&ds, "mosaic.vrt", &a);
    bake_dataset(&open(std::slice::from_ref(&whole), MIN_CACHE_BYTES).unwrap(), "whole.tif", &b);
    assert_same_tileset(&a, &b);
    // And through the binary.
    let c = d.join("c");
    ok(bin()
        .args(["bake", "--quiet", "--tile-size", "64", "--max-error", "1", "--levels", "2", "--out"])
        .arg(&c)
        .arg(&mosaic));
    assert_same_tileset(&a, &c);

    // A subset: 150 × 100 samples from (60, 40), in a VRT twice that size (the rest no-data).
    let subset = d.join("subset.vrt");
    std::fs::write(
        &subset,
        vrt_text(
            (150, 100),
            "",
            &[("whole.tif".into(), [60, 40, 150, 100], [0, 0, 150, 100], "SimpleSource")],
        ),
    )
    .unwrap();
    let sub = open(std::slice::from_ref(&subset), MIN_CACHE_BYTES).unwrap();
    assert_eq!((sub.summary().width, sub.summary().height), (150, 100));
    assert_eq!(sub.summary().extent, [0.0, 1000.0 - 99.0 * 10.0, 1490.0, 1000.0]);
    let full = open(&[whole], MIN_CACHE_BYTES).unwrap();
    let (mut x, mut y) = (Vec::new(), Vec::new());
    sub.read_window(&(0..150).collect::<Vec<_>>(), &(0..100).collect::<Vec<_>>(), &mut x).unwrap();
    full.read_window(&(60..210).collect::<Vec<_>>(), &(40..140).collect::<Vec<_>>(), &mut y).unwrap();
    assert_eq!(x, y);
}

#[test]
fn vrts_that_resample_or_compute_are_refused_naming_the_element() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    tiled(&d.join("t.tif"), (100, 80), (0, 0), 10.0, Model::Projected, None, &terrain);
    let src = |s: [u32; 4], t: [u32; 4]| vec![("t.tif".to_owned(), s, t, "SimpleSource")];
    let cases: Vec<(&str, String, &str)> = vec![
        ("halved.vrt", vrt_text((50, 40), "", &src([0, 0, 100, 80], [0, 0, 50, 40])), "SimpleSource #1"),
        (
            "scaled.vrt",
            vrt_text(
                (100, 80),
                "",
                &[("t.tif".to_owned(), [0, 0, 100, 80], [0, 0, 100, 80], "ComplexSource")],
            )
            .replace("<NODATA>-1</NODATA>", "<ScaleRatio>0.5</ScaleRatio>"),
            "ScaleRatio",
        ),
        (
            "missing.vrt",
            vrt_text(
                (100, 80),
                "",
                &[("nope.tif".to_owned(), [0, 0, 100, 80], [0, 0, 100, 80], "SimpleSource")],
            ),
            "nope.tif",
        ),
        (
            "averaged.vrt",
            vrt_text((100, 80), "", &src([0, 0, 100, 80], [0, 0, 100, 80]))
                .replace("SimpleSource", "AveragedSource"),
            "AveragedSource",
        ),
    ];
    for (name, text, needle) in cases {
        let p = d.join(name);
        std::fs::write(&p, text).unwrap();
        let out = d.join(format!("out-{name}"));
        let msg = fails(bin().args(["bake", "--quiet", "--out"]).arg(&out).arg(&p));
        assert!(msg.contains(name) && msg.contains(needle), "{name}: {msg}");
        assert!(!out.exists(), "{name}: something was written");
    }
}
