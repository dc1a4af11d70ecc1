//! `client::render` on a fuji.png bake: the LOD selection (meshes with skirts, point levels as
//! splats) against the full-resolution TIN (every leaf's mesh) from poses of the shipped flight;
//! pixels where the reference has terrain and the LOD frame is empty are counted.
//!
//! Skips (with the reason printed) when no adapter is found, unless
//! `TERRASTREAM_REQUIRE_GPU=1`: then it fails.
#![cfg(all(feature = "client", feature = "gpu"))]
#![allow(clippy::unwrap_used, clippy::panic)]

mod common;
use common::gpu_or_skip;

use std::path::Path;
use std::process::Command;

use terrastream::client::render::{self, Renderer, covered};
use terrastream::client::select::{AllResident, Camera, DrawItem, SelectParams, Selector, skirt_depth};
use terrastream::client::stream::flight_path::Flight;
use terrastream::client::tree::TileTree;
use terrastream::codec;
use terrastream::store::Store;

/// Poses (flight time) and thresholds coarse enough that point levels (footprints) are drawn:
/// levels 1 and 2 of this bake. (The point levels' errors include their footprints' reach, so
/// these thresholds are about twice those that drew the same levels with the earlier discs.)
const POINT_CASES: [(f64, f64); 3] = [(0.0, 16.0), (0.0, 24.0), (8.0, 32.0)];

fn bake(out: &Path) {
    let src = tempfile::tempdir().unwrap();
    let fuji = common::fuji_or_generated(src.path(), "render: the fuji.png bake");
    let o = Command::new(env!("CARGO_BIN_EXE_terrastream"))
        .args(["bake", "--quiet", "--encoding", "terrain-rgb", "--cell-size", "30", "--tile-size", "128"])
        .args(["--max-error", "2", "--levels", "3", "--gpu", "off", "--out"])
        .arg(out)
        .arg(fuji)
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
}

#[test]
fn lod_frames_cover_the_full_resolution_terrain() {
    let Some(ctx) = gpu_or_skip("GPU render test") else { return };
    // Its poses and thresholds (POINT_CASES) are fuji's.
    if common::shared("fuji.png", "render::lod_frames_cover_the_full_resolution_terrain").is_none() {
        return;
    }
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path().join("fuji");
    bake(&dir);
    let store = Store::new(&dir);
    let manifest = store.manifest().unwrap();
    let tree = TileTree::load(&store).unwrap();
    let bounds = manifest.bounds;
    let size = bounds.size();
    let far = 4.0 * (size[0] + size[1] + size[2]);
    let cell = manifest.frame.dx.abs();
    let (w, h) = (480, 270);
    let mut r = Renderer::new(ctx.device, ctx.queue, w, h, bounds.min).unwrap();
    let upload = |r: &mut Renderer, d: &DrawItem, depth: f64| {
        let blob = codec::decode(&store.read_blob(d.key, d.level).unwrap().unwrap()).unwrap();
        let spacing = manifest.levels[usize::from(d.level)]
            .cell_leaf_cells
            .map_or(0.0, |c| f64::from(c) * f64::from(tree.pyramid().step(d.key.z)) * cell);
        r.upload(&blob, depth, Some(&bounds), spacing, render::footprint_half(&manifest, d.level));
    };
    // The reference: every leaf's TIN (full resolution; leaves share their border vertices).
    let leaves: Vec<DrawItem> = tree
        .nodes()
        .iter()
        .enumerate()
        .filter(|(_, n)| n.is_leaf())
        .map(|(i, n)| DrawItem {
            node: i as u32,
            key: n.key,
            level: 0,
            alpha: 1.0,
            retiring: false,
            error_px: 0.0,
            error_world: 0.0,
        })
        .collect();
    for d in &leaves {
        upload(&mut r, d, 0.0);
    }
    let flight = Flight::load(&Path::new(env!("CARGO_MANIFEST_DIR")).join("data/flight-orbit.json"))
        .unwrap()
        .to_world(&bounds)
        .unwrap();
    let out = Path::new(env!("CARGO_TARGET_TMPDIR")).join("client-render");
    std::fs::create_dir_all(&out).unwrap();
    let mut worst = 0.0f64;
    // The default threshold (meshes), then coarse ones where point levels are drawn.
    let cases = [(0.0, 2.0), (8.0, 2.0), (16.0, 2.0), (24.0, 2.0)].into_iter().chain(POINT_CASES);
    for (i, (t, threshold_px)) in cases.enumerate() {
        let camera = Camera::new(&flight.pose_at(t), w, h, 60.0);
        let reference = r.render(&camera, &leaves, far).unwrap();
        let params = SelectParams { fade_seconds: 0.0, threshold_px, ..SelectParams::default() };
        let mut sel = Selector::new(params).unwrap();
        let draws: Vec<DrawItem> = sel.select(&tree, &camera, &AllResident, 0.0).unwrap().draws.clone();
        // A neighbour is one of the drawn tiles: its error is at most the largest drawn.
        let max_e = draws.iter().map(|d| d.error_world).fold(0.0, f64::max);
        let mut lod = r.render(&camera, &[], far).unwrap();
        if !draws.is_empty() {
            // Upload at this frame's skirt depth (tiles shared with the reference are re-made).
            for d in &draws {
                if d.level == 0 && tree.node(d.node).is_leaf() {
                    r.evict(d.key, 0);
                }
                upload(&mut r, d, skirt_depth(d.error_world, max_e));
            }
            lod = r.render(&camera, &draws, far).unwrap();
            for d in &draws {
                if d.level == 0 && tree.node(d.node).is_leaf() {
                    r.evict(d.key, 0);
                    upload(&mut r, d, 0.0);
                }
            }
        }
        Renderer::save_png(&reference, &out.join(format!("ref-{i}.png"))).unwrap();
        Renderer::save_png(&lod, &out.join(format!("lod-{i}.png"))).unwrap();
        let (a, b) = (covered(&reference), covered(&lod));
        let terrain = a.iter().filter(|&&c| c).count();
        let empty: Vec<usize> = (0..a.len()).filter(|&k| a[k] && !b[k]).collect();
        let levels: Vec<u8> = draws.iter().map(|d| d.level).collect();
        if POINT_CASES.contains(&(t, threshold_px)) {
            assert!(levels.iter().any(|&l| l > 0), "no point level drawn at t {t}, {threshold_px} px");
        }
        let share = empty.len() as f64 / terrain.max(1) as f64;
        println!(
            "t {t:>4}, {threshold_px} px: {} tiles drawn (levels {levels:?}); terrain {terrain} px, empty in the LOD frame {} px ({:.3} %), first at {:?}",
            draws.len(),
            empty.len(),
            100.0 * share,
            empty.iter().take(4).map(|&k| (k % w as usize, k / w as usize)).collect::<Vec<_>>()
        );
        assert!(terrain > (w * h / 10) as usize, "reference frame {i} shows little terrain");
        worst = worst.max(share);
    }
    println!("frames written to {}", out.display());
    assert!(worst <= 0.005, "up to {:.3} % of terrain pixels empty in a LOD frame", 100.0 * worst);
}
