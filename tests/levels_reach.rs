//! Issue 39: `--point-levels auto` stores only the point levels a screen-space-error selector
//! can choose (`lod::reach`). Each terrain is baked twice, with every cheaper level (`all`) and
//! with `auto`; the client's own selector then flies over the `all` tileset — the shipped flight
//! and random walks with jumps, from a metre above the ground to far away, at several
//! thresholds and window widths within the rule's threshold angle — and every level it draws
//! must be stored by `auto`. Since the selector never finds a dropped level under its threshold
//! while its node is drawn, both tilesets must draw the very same (tile, level) pairs, frame by
//! frame: the same bytes and primitives, no frame over the threshold that `all` does not have.
#![allow(clippy::unwrap_used)]

mod common;

use std::collections::HashSet;
use std::path::Path;

use glam::DVec3;
use terrastream::bake::{self, BakeOptions, PointLevels};
use terrastream::client::camera::Camera;
use terrastream::client::select::{AllResident, SelectParams, Selector};
use terrastream::client::stream::flight_path::{Flight, Pose};
use terrastream::client::tree::TileTree;
use terrastream::eval::flight_cost::{Rule, flight_cost};
use terrastream::lod::PointBaker;
use terrastream::raster::{self, Georef, Heightfield, LoadOptions, LoadedRaster};
use terrastream::store::{SkipReason, Store};

fn bake_both(raster: &LoadedRaster, opts: &BakeOptions, dir: &Path) -> (Store, Store) {
    let out = |p: PointLevels, name: &str| {
        let store = Store::new(&dir.join(name));
        let o = BakeOptions { point_levels: p, ..opts.clone() };
        bake::bake_terrain(raster, "t", &o, &PointBaker::Cpu, &store, &bake::NoProgress).unwrap();
        store
    };
    (out(PointLevels::All, "all"), out(PointLevels::Auto, "auto"))
}

/// A tiny deterministic generator.
struct Rng(u64);
impl Rng {
    fn f(&mut self) -> f64 {
        self.0 = self.0.wrapping_mul(6_364_136_223_846_793_005).wrapping_add(1_442_695_040_888_963_407);
        (self.0 >> 11) as f64 / (1u64 << 53) as f64
    }
}

/// Random camera paths over `b`: walks whose steps are small against the altitude, and jumps.
fn poses(b: &terrastream::geom::Bounds, n: usize, seed: u64) -> Vec<Pose> {
    let mut r = Rng(seed);
    let size = b.size();
    let diag = size.length();
    let mut out = Vec::with_capacity(n);
    let mut eye = b.center() + DVec3::new(0.0, 0.0, diag);
    for i in 0..n {
        if i % 40 == 0 {
            // A jump: anywhere over 1.5× the extent, 1 m to 300 diagonals above the top.
            let alt = (300.0 * diag).powf(r.f());
            eye = DVec3::new(
                b.min.x + size.x * (1.5 * r.f() - 0.25),
                b.min.y + size.y * (1.5 * r.f() - 0.25),
                b.max.z + alt,
            );
        } else {
            let alt = (eye.z - b.min.z).max(1.0);
            eye += DVec3::new(r.f() - 0.5, r.f() - 0.5, 0.6 * (r.f() - 0.5)) * (0.2 * alt);
            eye.z = eye.z.max(b.min.z + 1.0);
        }
        let target = DVec3::new(b.min.x + size.x * r.f(), b.min.y + size.y * r.f(), b.min.z + size.z * r.f());
        let target = if (target - eye).length() < 1e-3 { eye + DVec3::new(1.0, 0.0, -1.0) } else { target };
        let up = if (target - eye).normalize().z.abs() > 0.99 { DVec3::Y } else { DVec3::Z };
        out.push(Pose { eye, target, up });
    }
    out
}

/// Flies `all`'s tree with the selector and checks `auto`: every drawn level stored, the same
/// draws frame by frame. Returns the point-level draws seen (so a caller can tell the check
/// was not vacuous): at the root, and below it.
fn check(name: &str, all: &Store, auto: &Store) -> (usize, usize) {
    let (ta, tb) = (TileTree::load(all).unwrap(), TileTree::load(auto).unwrap());
    let b = all.manifest().unwrap().bounds;
    let stored: HashSet<(terrastream::tiling::TileKey, u8)> = auto
        .all_nodes(&all_pyramid(all))
        .unwrap()
        .iter()
        .flat_map(|n| n.levels.iter().map(move |l| (n.key, l.level)))
        .collect();
    let (mut root_points, mut child_points) = (0, 0);
    // The reference client's default (1 px at 1024), the rule's angle (4 px at 1024), a small
    // window (1 px at 256).
    for (threshold_px, width) in [(1.0, 1024), (4.0, 1024), (1.0, 256)] {
        let params = SelectParams { threshold_px, fade_seconds: 0.0, ..SelectParams::default() };
        let (mut sa, mut sb) = (Selector::new(params).unwrap(), Selector::new(params).unwrap());
        for (i, pose) in poses(&b, 600, 7 + u64::from(width)).iter().enumerate() {
            let cam = Camera::new(pose, width, width * 3 / 4, 60.0);
            let t = i as f64 / 30.0;
            let da = sa.select(&ta, &cam, &AllResident, t).unwrap();
            let db = sb.select(&tb, &cam, &AllResident, t).unwrap();
            let set = |d: &[terrastream::client::select::DrawItem]| {
                let mut v: Vec<_> = d.iter().filter(|d| !d.retiring).map(|d| (d.key, d.level)).collect();
                v.sort_unstable();
                v
            };
            let (va, vb) = (set(&da.draws), set(&db.draws));
            for &(key, level) in &va {
                assert!(
                    stored.contains(&(key, level)),
                    "{name}: {threshold_px} px at {width}: pose {i} draws {key} level {level}, which auto dropped"
                );
                if level > 0 {
                    *(if key.z == 0 { &mut root_points } else { &mut child_points }) += 1;
                }
            }
            assert_eq!(va, vb, "{name}: {threshold_px} px at {width}: pose {i} draws differ");
        }
    }
    // The shipped flight, as `eval --flight` replays it: the same cost frame by frame.
    let flight_path = Path::new(env!("CARGO_MANIFEST_DIR")).join("data/flight-orbit.json");
    let flight = Flight::load(&flight_path).unwrap();
    let cost = |t: &TileTree| {
        flight_cost(&flight_path, t, Rule::Cheapest, &b, &flight, (1024, 768, 60.0), 1.0, 10.0).unwrap()
    };
    let (ca, cb) = (cost(&ta), cost(&tb));
    assert_eq!(ca.frames, cb.frames, "{name}: the flight's frames differ");
    assert_eq!(cb.frames_over_threshold, ca.frames_over_threshold);
    eprintln!(
        "{name}: {root_points} point-level draws at the root and {child_points} below over random paths, all stored by auto; flight: {} frames, {} over the threshold, the same",
        ca.frames.len(),
        ca.frames_over_threshold
    );
    (root_points, child_points)
}

fn all_pyramid(store: &Store) -> terrastream::tiling::Pyramid {
    let m = store.manifest().unwrap();
    terrastream::tiling::Pyramid::new(m.source.width, m.source.height, m.tile_size).unwrap()
}

/// Nodes, levels stored by `all` and by `auto`, and what auto skipped as unreachable.
fn figures(all: &Store, auto: &Store) -> (usize, usize, usize, usize) {
    let p = all_pyramid(all);
    let (na, nb) = (all.all_nodes(&p).unwrap(), auto.all_nodes(&p).unwrap());
    let points = |n: &[terrastream::store::NodeEntry]| n.iter().map(|e| e.levels.len() - 1).sum::<usize>();
    let ladder: Vec<u8> = auto.manifest().unwrap().levels.iter().map(|l| l.level).collect();
    let unreachable = nb
        .iter()
        .flat_map(|e| terrastream::store::skipped_levels(auto, e, &ladder).unwrap())
        .filter(|s| matches!(s.why, SkipReason::Unreachable | SkipReason::PredictedUnreachable))
        .count();
    (na.len(), points(&na), points(&nb), unreachable)
}

#[test]
fn auto_keeps_every_level_the_selector_draws_on_a_rough_dsm() {
    // A generated DSM: smooth ground, blocks of buildings (steps of 3 to 40 m) and trees
    // (single-sample spikes), where a TIN needs many vertices and point levels can pay.
    let (w, h) = (257u32, 257u32);
    let mut data = terrastream::raster::synth::terrain(w, h, 11);
    let mut r = Rng(5);
    for _ in 0..140 {
        let (x0, y0) = ((r.f() * f64::from(w - 12)) as u32, (r.f() * f64::from(h - 12)) as u32);
        let (bw, bh, top) = (3 + (r.f() * 9.0) as u32, 3 + (r.f() * 9.0) as u32, 3.0 + 37.0 * r.f());
        for y in y0..y0 + bh {
            for x in x0..x0 + bw {
                data[(y * w + x) as usize] += top as f32;
            }
        }
    }
    for _ in 0..2000 {
        let k = (r.f() * f64::from(w * h - 1)) as usize;
        data[k] += (5.0 + 15.0 * r.f()) as f32;
    }
    let raster = LoadedRaster {
        heights: Heightfield { width: w, height: h, data },
        georef: Georef { dx: 2.0, dy: -2.0, y0: f64::from(h) * 2.0, ..Georef::default() },
        nodata_filled: 0,
        nodata_fallback: 0,
        format: "test".into(),
    };
    let tmp = tempfile::tempdir().unwrap();
    let opts = BakeOptions { tile_size: 32, max_error: 0.5, levels: 4, point_levels: PointLevels::Auto };
    let (all, auto) = bake_both(&raster, &opts, tmp.path());
    let (nodes, stored_all, stored_auto, unreachable) = figures(&all, &auto);
    eprintln!(
        "rough DSM: {nodes} nodes, point levels stored: all {stored_all}, auto {stored_auto} ({unreachable} unreachable)"
    );
    assert!(stored_auto > 0 && unreachable > 0, "the rule must keep some levels and drop others here");
    common::assert_levels_pay(all.dir());
    common::assert_levels_pay(auto.dir());
    let (_, below_root) = check("rough DSM", &all, &auto);
    assert!(below_root > 0, "no point level below the root was ever drawn: the check says nothing");
}

#[test]
fn auto_keeps_every_level_the_selector_draws_on_the_shared_terrains() {
    let tmp = tempfile::tempdir().unwrap();
    let mut inputs: Vec<(String, LoadedRaster, u32)> = Vec::new();
    if let Some(fuji) = common::shared("fuji.png", "levels_reach: fuji") {
        let o = LoadOptions {
            encoding: Some(raster::HeightEncoding::TerrainRgb),
            overrides: raster::Overrides { cell_size: Some(30.0), ..raster::Overrides::default() },
            ..LoadOptions::default()
        };
        inputs.push(("fuji".into(), raster::load(&fuji, &o).unwrap(), 64));
    }
    for (f, tile) in [("geo/utm32n_vinschgau.tif", 64), ("geo/nad83_utm18n_dem.tif", 64)] {
        if let Some(p) = common::shared(f, "levels_reach: a shared DEM") {
            inputs.push((f.into(), raster::load(&p, &LoadOptions::default()).unwrap(), tile));
        }
    }
    for (name, r, tile) in &inputs {
        let opts =
            BakeOptions { tile_size: *tile, point_levels: PointLevels::Auto, ..BakeOptions::default() };
        let dir = tmp.path().join(name.replace('/', "_"));
        let (all, auto) = bake_both(r, &opts, &dir);
        let (nodes, stored_all, stored_auto, unreachable) = figures(&all, &auto);
        eprintln!(
            "{name}: {nodes} nodes, point levels stored: all {stored_all}, auto {stored_auto} ({unreachable} unreachable)"
        );
        common::assert_levels_pay(auto.dir());
        check(name, &all, &auto);
    }
}
