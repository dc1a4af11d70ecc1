//! In-process heights per second (issue 38), the library half of `bench/heights_vs_rasterio.sh`:
//!
//! `heights_bench DEM STORE POINTS.f64 [SECONDS]` loads DEM as `serve --source` does, opens the
//! baked tileset STORE (a directory: blobs read from `tiles/{z}/{x}/{y}/0.tsb` through
//! `Store::read_blob`) and answers the WGS 84 points of POINTS.f64 (little-endian f64 lon, lat
//! pairs) with a [`SourceSampler`] (bilinear, ellipsoid) and a [`MeshSampler`] (the finest TINs,
//! one sampler kept across batches, as a simulator embeds it), in batches of 1, 100, 10,000 and
//! 1,000,000 points, on one thread. Each batch size runs over consecutive points until SECONDS
//! (default 3) have passed or the points run out; one line a batch size:
//! `inproc SURFACE batch=B points=N secs=S pts_per_s=R`.

// A benchmark driver: a failure is a crash with the message.
#![allow(clippy::unwrap_used, clippy::expect_used)]

use std::path::PathBuf;
use std::time::Instant;

use terrastream::heights::{BlobSource, Coords, Datum, Interp, MeshSampler, Query, SourceSampler};
use terrastream::raster::LoadOptions;
use terrastream::store::Store;
use terrastream::tiling::{Pyramid, TileKey};

/// Level-0 blobs of a tileset directory, read from disk at each miss of the sampler's cache.
struct Files(Store);

impl BlobSource for Files {
    fn blob(&self, key: TileKey) -> Result<Option<Vec<u8>>, String> {
        self.0.read_blob(key, 0).map_err(|e| e.to_string())
    }
}

const BATCHES: [usize; 4] = [1, 100, 10_000, 1_000_000];

/// Runs `f` over consecutive batches of `batch` points until `secs` or the points run out.
fn run(name: &str, points: &[[f64; 2]], batch: usize, secs: f64, mut f: impl FnMut(&[[f64; 2]]) -> usize) {
    let t = Instant::now();
    let (mut done, mut answered) = (0usize, 0usize);
    while done < points.len() && (done == 0 || t.elapsed().as_secs_f64() < secs) {
        let end = (done + batch).min(points.len());
        answered += f(&points[done..end]);
        done = end;
    }
    let s = t.elapsed().as_secs_f64();
    println!(
        "inproc {name} batch={batch} points={done} secs={s:.4} pts_per_s={:.0} answered={answered}",
        done as f64 / s
    );
}

fn main() {
    let args: Vec<String> = std::env::args().collect();
    assert!(args.len() >= 4, "usage: heights_bench DEM STORE POINTS.f64 [SECONDS]");
    let (dem, store, pts) = (PathBuf::from(&args[1]), PathBuf::from(&args[2]), PathBuf::from(&args[3]));
    let secs: f64 = args.get(4).map_or(3.0, |s| s.parse().expect("SECONDS"));
    let bytes = std::fs::read(&pts).expect("points file");
    let points: Vec<[f64; 2]> = bytes
        .chunks_exact(16)
        .map(|c| {
            let v = |o: usize| f64::from_le_bytes(c[o..o + 8].try_into().unwrap());
            [v(0), v(8)]
        })
        .collect();

    let t = Instant::now();
    let raster = terrastream::raster::load(&dem, &LoadOptions::default()).expect("DEM");
    println!("load source {:.3} s", t.elapsed().as_secs_f64());
    let source = SourceSampler::new(&raster.heights, &raster.georef).expect("source sampler");
    let q = Query { coords: Coords::Wgs84, interp: Interp::Bilinear, datum: Datum::Ellipsoid };
    for batch in BATCHES {
        run("source-bilinear", &points, batch, secs, |p| {
            source.sample(p, q).expect("source heights").iter().filter(|h| !h.nodata).count()
        });
    }

    let store = Store::new(&store);
    let m = store.manifest().expect("manifest");
    let pyramid = Pyramid::new(m.source.width, m.source.height, m.tile_size).expect("pyramid");
    let mesh = MeshSampler::new(Files(store), pyramid, &m.frame, 256 << 20).expect("mesh sampler");
    let depth = mesh.depth();
    for batch in BATCHES {
        run("mesh", &points, batch, secs, |p| {
            mesh.sample(p, q, depth).expect("mesh heights").iter().filter(|h| !h.nodata).count()
        });
    }
}
