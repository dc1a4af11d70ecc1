//! The client's collision region (issue 38) against a live `terrastream serve` over a tileset
//! baked from fuji.png (or its generated stand-in): a flight whose camera stays far above the
//! terrain, looking at the whole tileset (so the view never wants a leaf's full-detail mesh),
//! while the ego drives across many leaf tiles. With `--collision-radius` every leaf within the
//! radius must be resident at level 0 in every frame after warm-up; without it the same flight
//! does not hold them. Which leaves are within the radius is recomputed here from the tileset's
//! index on disk, with this file's own geometry, not the client's.

#![cfg(all(feature = "client", feature = "server"))]
#![allow(clippy::unwrap_used, clippy::float_cmp)]

mod common;

use std::collections::BTreeSet;
use std::path::Path;

use terrastream::client::collision::{CollisionParams, DEFAULT_LOOKAHEAD_S};
use terrastream::client::select::SelectParams;
use terrastream::client::stream::fetch::Resource;
use terrastream::client::stream::flight_path::Flight;
use terrastream::client::stream::replay::{self as live, ReplayOptions};
use terrastream::client::stream::session::{Session, SessionOptions};
use terrastream::store::Store;
use terrastream::tiling::TileKey;

const TILESET: &str = "fuji";
const RADIUS: f64 = 300.0;
/// Flight seconds.
const DURATION: f64 = 6.0;

/// Bakes fuji.png (30 m cells, 64-sample tiles: 8×8 leaves of 1920 m, 2 levels) into `store/fuji`.
fn bake(store: &Path) {
    let src = tempfile::tempdir().unwrap();
    let fuji = common::fuji_or_generated(src.path(), "collision: the fuji.png bake");
    common::ok(
        common::bin()
            .args(["bake", "--quiet", "--encoding", "terrain-rgb", "--cell-size", "30", "--tile-size", "64"])
            .args(["--max-error", "2", "--levels", "2", "--gpu", "off", "--out"])
            .arg(store.join(TILESET))
            .arg(fuji),
    );
}

/// The leaves of the tileset: key and horizontal box (x0, y0, x1, y1), from the index on disk.
fn leaves(store: &Store) -> Vec<(TileKey, [f64; 4])> {
    let m = store.manifest().unwrap();
    let z = m.depth;
    let mut out = Vec::new();
    for x in 0..(1u32 << z) {
        for y in 0..(1u32 << z) {
            let key = TileKey::new(z, x, y);
            if let Some(n) = store.node(key).unwrap() {
                let (a, b) = (n.bounds.min, n.bounds.max);
                out.push((key, [a[0], a[1], b[0], b[1]]));
            }
        }
    }
    out
}

fn distance(b: &[f64; 4], p: [f64; 2]) -> f64 {
    let dx = (b[0] - p[0]).max(p[0] - b[2]).max(0.0);
    let dy = (b[1] - p[1]).max(p[1] - b[3]).max(0.0);
    dx.hypot(dy)
}

/// The ego at flight time `t`, interpolated here from the two ends this test writes.
fn ego_at(a: [f64; 2], b: [f64; 2], t: f64) -> [f64; 2] {
    let s = (t / DURATION).clamp(0.0, 1.0);
    [a[0] + (b[0] - a[0]) * s, a[1] + (b[1] - a[1]) * s]
}

/// Camera far above the south edge, looking at the tileset's centre and drifting east; the ego
/// drives from the south-west to the north-east quarter. World frame, written as JSON like a
/// user's flight file.
fn flight(store: &Store) -> (Flight, [f64; 2], [f64; 2]) {
    let b = store.manifest().unwrap().bounds;
    let (x0, y0, z0) = (b.min[0], b.min[1], b.min[2]);
    let (w, h) = (b.max[0] - x0, b.max[1] - y0);
    let e = w.max(h);
    let (cx, cy) = (x0 + 0.5 * w, y0 + 0.5 * h);
    let ego0 = [x0 + 0.1 * w, y0 + 0.15 * h];
    let ego1 = [x0 + 0.85 * w, y0 + 0.8 * h];
    let json = format!(
        r#"{{"name":"ego across, camera far above","frame":"world","keys":[
          {{"t":0,"eye":[{},{},{}],"target":[{cx},{cy},{z0}],"ego":[{},{},{z0}]}},
          {{"t":{DURATION},"eye":[{},{},{}],"target":[{cx},{cy},{z0}],"ego":[{},{},{z0}]}}]}}"#,
        cx - 0.2 * e,
        cy - 2.0 * e,
        z0 + 2.0 * e,
        ego0[0],
        ego0[1],
        cx + 0.2 * e,
        cy - 2.0 * e,
        z0 + 2.0 * e,
        ego1[0],
        ego1[1],
    );
    (Flight::from_json(&json).unwrap(), ego0, ego1)
}

fn options(collision: Option<CollisionParams>, cache_bytes: usize) -> SessionOptions {
    SessionOptions {
        cache_bytes,
        width: 640,
        height: 360,
        select: SelectParams { fade_seconds: 0.1, threshold_px: 2.0, ..SelectParams::default() },
        collision,
        ..SessionOptions::default()
    }
}

/// Per frame: the leaves within `RADIUS` of the ego (this file's geometry) and how many of them
/// were not resident at level 0 when the frame was drawn; plus whether the count is safe to
/// compare with the client's (no leaf within a micrometre of the radius).
struct Seen {
    required: Vec<Vec<TileKey>>,
    misses: Vec<usize>,
    clear_of_edge: Vec<bool>,
}

fn fly(
    url: &str,
    flight: &Flight,
    ends: ([f64; 2], [f64; 2]),
    all: &[(TileKey, [f64; 4])],
    collision: Option<CollisionParams>,
    cache_bytes: usize,
) -> (Session, Vec<terrastream::client::stream::session::FrameStats>, live::Totals, Seen) {
    let mut session = Session::connect(url, TILESET, options(collision, cache_bytes)).unwrap();
    let mut seen = Seen { required: Vec::new(), misses: Vec::new(), clear_of_edge: Vec::new() };
    // Two flight seconds per wall second; the client still streams live.
    let replay = ReplayOptions { fps: 30.0, settle_s: 5.0, speed: 2.0 };
    let (frames, totals) = live::replay(&mut session, flight, &replay, |s, f| {
        let ego = ego_at(ends.0, ends.1, f.t);
        let within: Vec<TileKey> =
            all.iter().filter(|(_, b)| distance(b, ego) <= RADIUS).map(|(k, _)| *k).collect();
        seen.misses.push(within.iter().filter(|k| !s.cache().contains(**k, 0)).count());
        seen.clear_of_edge.push(all.iter().all(|(_, b)| (distance(b, ego) - RADIUS).abs() > 1e-6));
        seen.required.push(within);
        Ok(())
    })
    .unwrap();
    (session, frames, totals, seen)
}

#[test]
fn collision_region_holds_while_the_camera_is_far_above() {
    let tmp = tempfile::tempdir().unwrap();
    let root = tmp.path().join("store");
    bake(&root);
    let store = Store::new(&root.join(TILESET));
    let all = leaves(&store);
    assert_eq!(all.len(), 64, "8×8 leaves expected");
    let (flight, ego0, ego1) = flight(&store);
    let server = common::serve_store(&root, &[]);
    let url = format!("http://{}", server.addr);

    // With the region.
    let params = CollisionParams::new(RADIUS, DEFAULT_LOOKAHEAD_S).unwrap();
    let (session, frames, totals, seen) = fly(&url, &flight, (ego0, ego1), &all, Some(params), 64 << 20);
    let union: BTreeSet<TileKey> = seen.required.iter().flatten().copied().collect();
    assert!(union.len() >= 8, "the ego crosses only {} leaves", union.len());
    assert!(seen.required.iter().all(|r| !r.is_empty()), "the ego is always over some leaf");
    // Warm-up (this file's rule: up to the first frame with every required leaf resident)
    // ends, early, and no frame after it misses a leaf.
    let warm = seen.misses.iter().position(|&m| m == 0).expect("the region never completed");
    assert!(warm < frames.len() / 2, "warm only at frame {warm} of {}", frames.len());
    let late: Vec<(usize, usize)> =
        seen.misses.iter().enumerate().skip(warm).filter(|(_, m)| **m > 0).map(|(i, m)| (i, *m)).collect();
    assert!(late.is_empty(), "misses after warm-up (frame, leaves): {late:?}");
    // Every leaf the ego came within the radius of was fetched at level 0.
    for k in &union {
        let r = Resource::Tile { key: *k, level: 0 };
        assert!(session.fetch_counts().contains_key(&r), "leaf {k} never fetched at level 0");
    }
    // The client's own figures agree: per frame, the same count of required leaves at the same
    // ego; no miss after its warm-up; region bytes at least those leaves' blobs.
    let c = totals.collision.as_ref().expect("no collision totals");
    assert_eq!((c.radius_m, c.ego.as_str()), (RADIUS, "flight"));
    assert_eq!(c.misses_after_warmup, Some(0), "{c:?}");
    assert_eq!(c.warm_frame, Some(warm as u32), "{c:?}");
    for (i, f) in frames.iter().enumerate() {
        let fc = f.collision.as_ref().unwrap();
        let ego = ego_at(ego0, ego1, f.t);
        assert!((fc.ego[0] - ego[0]).abs() < 1e-6 && (fc.ego[1] - ego[1]).abs() < 1e-6, "frame {i}");
        if i >= warm && seen.clear_of_edge[i] {
            assert_eq!(fc.required as usize, seen.required[i].len(), "frame {i}");
            assert_eq!(fc.misses, 0, "frame {i}");
        }
    }
    let leaf_bytes: u64 =
        union.iter().map(|k| std::fs::metadata(store.blob_path(*k, 0)).unwrap().len()).sum();
    assert!(
        c.bytes >= leaf_bytes && c.bytes <= totals.bytes,
        "{} vs {leaf_bytes} / {}",
        c.bytes,
        totals.bytes
    );
    assert!(c.leaves_fetched as usize >= union.len());
    println!(
        "with the region: {} frames, warm at frame {warm}, {} leaves crossed, region {} of {} bytes",
        frames.len(),
        union.len(),
        c.bytes,
        totals.bytes
    );

    // Without the region the same flight never holds them: the camera is too far for the view
    // to want any leaf's mesh, so every frame misses.
    let (session, _, totals, seen) = fly(&url, &flight, (ego0, ego1), &all, None, 64 << 20);
    assert!(totals.collision.is_none());
    assert!(seen.misses.iter().all(|&m| m > 0), "{:?}", seen.misses);
    let fetched =
        union.iter().filter(|k| session.fetch_counts().contains_key(&Resource::Tile { key: **k, level: 0 }));
    assert_eq!(fetched.count(), 0);

    // A cache budget of one byte evicts every tile that is not pinned: the region's leaves
    // still stay resident while the ego is near them.
    let (session, _, totals, seen) = fly(&url, &flight, (ego0, ego1), &all, Some(params), 1);
    let warm = seen.misses.iter().position(|&m| m == 0).expect("the region never completed");
    let late: Vec<usize> = seen.misses.iter().skip(warm).copied().filter(|&m| m > 0).collect();
    assert!(late.is_empty(), "misses after warm-up with a 1-byte cache: {late:?}");
    assert_eq!(totals.collision.unwrap().misses_after_warmup, Some(0));
    assert!(session.cache().evictions() > 0, "the budget evicted nothing");
}

#[test]
fn cli_writes_collision_stats_and_checks_the_flag() {
    let tmp = tempfile::tempdir().unwrap();
    let root = tmp.path().join("store");
    bake(&root);
    let store = Store::new(&root.join(TILESET));
    let (flight, _, _) = flight(&store);
    let flight_path = tmp.path().join("flight.json");
    std::fs::write(&flight_path, flight.to_json().unwrap()).unwrap();
    let server = common::serve_store(&root, &[]);
    let url = format!("http://{}", server.addr);
    let client = |out: &Path| {
        let mut c = common::bin();
        c.args(["client", "--url", &url, "--tileset", TILESET, "--render", "off", "--frames-every", "0"])
            .args(["--width", "640", "--height", "360", "--threshold", "2", "--settle", "5"])
            .arg("--flight")
            .arg(&flight_path)
            .arg("--out")
            .arg(out);
        c
    };
    for bad in ["0", "nan", "inf", "-3"] {
        let err = common::fails(client(&tmp.path().join("bad")).arg(format!("--collision-radius={bad}")));
        assert!(err.contains("collision region: radius"), "{bad}: {err}");
    }
    let err = common::fails(client(&tmp.path().join("bad")).args([
        "--collision-radius",
        "300",
        "--collision-lookahead=-1",
    ]));
    assert!(err.contains("collision region: look-ahead -1 s"), "{err}");
    assert!(!tmp.path().join("bad").join("stats.json").exists());

    let out = tmp.path().join("run");
    let stdout = common::ok(client(&out).args(["--collision-radius", "300"]));
    assert!(stdout.contains("collision region 300 m (ego from the flight)"), "{stdout}");
    let stats: serde_json::Value =
        serde_json::from_slice(&std::fs::read(out.join("stats.json")).unwrap()).unwrap();
    let c = &stats["totals"]["collision"];
    assert_eq!(c["misses_after_warmup"], 0, "{c}");
    assert_eq!(c["ego"], "flight");
    assert!(c["bytes"].as_u64().unwrap() > 0 && c["required_max"].as_u64().unwrap() >= 1, "{c}");
    let frames = stats["frames"].as_array().unwrap();
    assert!(frames.iter().all(|f| f["collision"]["required"].as_u64().unwrap() >= 1));

    // Without the flag: no collision figures at all.
    let out = tmp.path().join("plain");
    common::ok(&mut client(&out));
    let stats: serde_json::Value =
        serde_json::from_slice(&std::fs::read(out.join("stats.json")).unwrap()).unwrap();
    assert!(stats["totals"].get("collision").is_none() && stats["frames"][0].get("collision").is_none());
}
