//! The reference client against a live, in-process `terrastream serve` (127.0.0.1:0) over a
//! tileset baked from fuji.png: the shipped flight replayed end to end (threshold met once the
//! view settles, bytes under a bound), and outages — the server answering `503` with
//! `Retry-After`, then stopped outright — during which the client keeps drawing what it has and
//! after which it recovers; with an adapter, the settled view rendered by the client against a
//! render of the full-resolution TIN from the same camera (no empty pixel where terrain is).
//!
//! GPU parts skip (with the reason printed) when no adapter is found, unless
//! `TERRASTREAM_REQUIRE_GPU=1`: then they fail.

// Helpers outside `#[test]` functions unwrap too: a failure there is a test failure.
#![cfg(all(feature = "client", feature = "server"))]
#![allow(clippy::unwrap_used, clippy::float_cmp)]

mod common;
use common::{gpu_or_skip, require_gpu};

use std::io::{Read, Write};
use std::net::{SocketAddr, TcpListener, TcpStream};
use std::path::{Path, PathBuf};
use std::process::Command;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Duration;

use terrastream::client::select::{Camera, SelectParams};
use terrastream::client::stream::fetch::FetchParams;
use terrastream::client::stream::flight_path::{Flight, Pose};
use terrastream::client::stream::replay::{self as live, ReplayOptions};
use terrastream::client::stream::session::{ReplayPhase, Session, SessionOptions};
use terrastream::server::{Config, Server};
use terrastream::store::Store;

const TILESET: &str = "fuji";

fn flight() -> Flight {
    Flight::load(&Path::new(env!("CARGO_MANIFEST_DIR")).join("data/flight-orbit.json")).unwrap()
}

/// Bakes fuji.png (30 m cells, 128-sample tiles: 85 nodes, 3 levels) into `store/fuji`.
fn bake(store: &Path) {
    let src = tempfile::tempdir().unwrap();
    let fuji = common::fuji_or_generated(src.path(), "client: the fuji.png bake");
    let out = Command::new(env!("CARGO_BIN_EXE_terrastream"))
        .args(["bake", "--quiet", "--encoding", "terrain-rgb", "--cell-size", "30", "--tile-size", "128"])
        .args(["--max-error", "2", "--levels", "3", "--gpu", "off", "--out"])
        .arg(store.join(TILESET))
        .arg(fuji)
        .output()
        .unwrap();
    assert!(out.status.success(), "bake failed: {}", String::from_utf8_lossy(&out.stderr));
}

/// A server running on its own runtime until `stop`.
struct Running {
    rt: tokio::runtime::Runtime,
    stop: Option<tokio::sync::oneshot::Sender<()>>,
    task: Option<tokio::task::JoinHandle<()>>,
    addr: SocketAddr,
}

fn start(store: &Path, bind: &str) -> Running {
    let rt = tokio::runtime::Builder::new_multi_thread().worker_threads(2).enable_all().build().unwrap();
    let mut cfg = Config::for_store(store).unwrap();
    cfg.bind = bind.parse().unwrap();
    let server = rt.block_on(Server::bind(cfg)).unwrap();
    let addr = server.local_addr().unwrap();
    let (tx, rx) = tokio::sync::oneshot::channel::<()>();
    let task = rt.spawn(async move {
        server
            .run(async {
                let _ = rx.await;
            })
            .await
            .unwrap();
    });
    Running { rt, stop: Some(tx), task: Some(task), addr }
}

impl Running {
    fn stop(mut self) {
        let _ = self.stop.take().unwrap().send(());
        let task = self.task.take().unwrap();
        self.rt.block_on(task).unwrap();
    }
}

fn options() -> SessionOptions {
    SessionOptions {
        width: 640,
        height: 360,
        // 2 px: the outage scenario needs the far pose's tiles to differ from the near pose's,
        // which at the default 1 px they already share on this small tileset.
        select: SelectParams { fade_seconds: 0.1, threshold_px: 2.0, ..SelectParams::default() },
        // Short backoff so recovery is quick in a test; the rules are the defaults'.
        fetch: FetchParams {
            backoff_base_s: 0.05,
            backoff_max_s: 0.5,
            timeout_s: 5.0,
            ..FetchParams::default()
        },
        ..SessionOptions::default()
    }
}

/// Every drawn (non-fading) tile's screen-space error, recomputed from the tileset's index on
/// disk (not from the client's tree) for the camera at `pose`.
fn drawn_errors_px(session: &Session, store: &Store, camera: &Camera) -> Vec<f64> {
    let view = camera.view().unwrap();
    session
        .draws()
        .iter()
        .filter(|d| !d.retiring)
        .map(|d| {
            let node = store.node(d.key).unwrap().unwrap();
            let e = node.level(d.level).unwrap().errors.geometric();
            let c = node.bounds.center();
            let dist = ((c[0] - camera.eye[0]).powi(2)
                + (c[1] - camera.eye[1]).powi(2)
                + (c[2] - camera.eye[2]).powi(2))
            .sqrt();
            view.screen_error(e, dist)
        })
        .collect()
}

fn dir_bytes(dir: &Path) -> u64 {
    let mut total = 0;
    for e in std::fs::read_dir(dir).unwrap() {
        let p = e.unwrap().path();
        total += if p.is_dir() { dir_bytes(&p) } else { std::fs::metadata(&p).unwrap().len() };
    }
    total
}

#[test]
fn shipped_flight_settles_under_threshold_within_the_byte_bound() {
    let tmp = tempfile::tempdir().unwrap();
    bake(tmp.path());
    let server = start(tmp.path(), "127.0.0.1:0");
    let url = format!("http://{}", server.addr);
    let opts = options();
    let mut session = Session::connect(&url, TILESET, opts).unwrap();
    let flight = flight();
    // Four flight seconds per wall second keeps the test short; the client still streams live.
    let replay = ReplayOptions { fps: 30.0, settle_s: 20.0, speed: 4.0 };
    let (frames, totals) = live::replay(&mut session, &flight, &replay, |_, _| Ok(())).unwrap();
    assert!(f64::from(totals.flight_frames) >= flight.duration() * 30.0 / 4.0, "{totals:?}");
    assert!(totals.settled, "view never completed: {:?}", frames.last());
    assert_eq!((totals.failed, totals.decode_errors), (0, 0), "{totals:?}");
    assert!(totals.first_complete_s.is_some());
    assert!(totals.latency_p50_ms > 0.0 && totals.latency_p99_ms >= totals.latency_p50_ms);

    // (a) After the view settles every drawn tile meets the threshold — recomputed from the
    // index on disk — and every drawn tile is resident.
    let store = Store::new(&tmp.path().join(TILESET));
    let world = flight.to_world(&session.manifest().bounds).unwrap();
    let camera = Camera::new(&world.pose_at(world.end()), opts.width, opts.height, opts.fov_deg);
    let last = frames.last().unwrap();
    assert!(last.selection.under_threshold && last.selection.holes == 0 && last.complete, "{last:?}");
    let errors = drawn_errors_px(&session, &store, &camera);
    assert!(!errors.is_empty());
    for e in &errors {
        assert!(*e <= opts.select.threshold_px + 1e-9, "drawn tile at {e} px");
    }
    for d in session.draws() {
        assert!(session.cache().contains(d.key, d.level), "{:?} drawn but not resident", d.key);
    }
    // The view is not trivially the root: the flight ends close to the terrain.
    assert!(session.draws().iter().any(|d| d.key.z >= 2), "{:?}", last.selection.drawn_per_level);

    // (c) Bytes. The cache (512 MiB) never evicts on this tileset, so no resource is fetched
    // twice; hence everything received (manifest, chunks, blobs, all complete responses) is at
    // most the tileset itself. And it is at least what the final view draws.
    assert!(session.fetch_counts().values().all(|&n| n == 1), "a resource was fetched twice");
    let bound = dir_bytes(store.dir());
    let drawn: u64 = session
        .draws()
        .iter()
        .map(|d| std::fs::metadata(store.blob_path(d.key, d.level)).unwrap().len())
        .sum();
    println!(
        "received {} bytes in {} requests; tileset {} bytes; final view draws {} bytes; p50 {:.2} ms p99 {:.2} ms",
        totals.bytes, totals.requests, bound, drawn, totals.latency_p50_ms, totals.latency_p99_ms
    );
    assert!(totals.bytes <= bound, "received {} > tileset {bound}", totals.bytes);
    assert!(totals.bytes >= drawn);
    // The per-frame byte counts add up to the total (manifest excluded: it precedes frame 0).
    let per_frame: u64 = frames.iter().map(|f| f.bytes_received).sum();
    assert_eq!(per_frame + std::fs::metadata(store.manifest_path()).unwrap().len(), totals.bytes);
    server.stop();
}

/// A switchable front: forwards to `upstream` while `up`, else answers `503` + `Retry-After: 1`.
fn front(upstream: SocketAddr, up: Arc<AtomicBool>) -> SocketAddr {
    let l = TcpListener::bind("127.0.0.1:0").unwrap();
    let addr = l.local_addr().unwrap();
    std::thread::spawn(move || {
        for conn in l.incoming() {
            let Ok(mut c) = conn else { continue };
            let up = up.load(Ordering::SeqCst);
            std::thread::spawn(move || {
                let mut req = Vec::new();
                let mut buf = [0u8; 4096];
                while !req.windows(4).any(|w| w == b"\r\n\r\n") {
                    match c.read(&mut buf) {
                        Ok(0) | Err(_) => return,
                        Ok(n) => req.extend_from_slice(&buf[..n]),
                    }
                }
                if !up {
                    let body = b"{\"title\":\"down for maintenance\"}";
                    let head = format!(
                        "HTTP/1.1 503 Service Unavailable\r\nRetry-After: 1\r\nContent-Length: {}\r\nConnection: close\r\n\r\n",
                        body.len()
                    );
                    let _ = c.write_all(head.as_bytes());
                    let _ = c.write_all(body);
                    return;
                }
                let Ok(mut s) = TcpStream::connect(upstream) else { return };
                let _ = s.write_all(&req);
                let _ = std::io::copy(&mut s, &mut c);
            });
        }
    });
    addr
}

#[test]
fn outages_keep_the_last_view_drawn_and_recover() {
    // Its flight times (an outage while the view is still incomplete) are fuji's.
    let what = "client::outages_keep_the_last_view_drawn_and_recover";
    if common::shared("fuji.png", what).is_none() {
        return;
    }
    let tmp = tempfile::tempdir().unwrap();
    bake(tmp.path());
    let server = start(tmp.path(), "127.0.0.1:0");
    let upstream = server.addr;
    let up = Arc::new(AtomicBool::new(true));
    let addr = front(upstream, up.clone());
    let mut session = Session::connect(&format!("http://{addr}"), TILESET, options()).unwrap();
    let world = flight().to_world(&session.manifest().bounds).unwrap();
    let (far, near) = (world.pose_at(world.start()), world.pose_at(world.end()));
    let settle = |session: &mut Session, pose: &Pose, limit: f64| {
        let until = session.now() + limit;
        loop {
            let f = session.frame(pose, 0.0, ReplayPhase::Settle).unwrap();
            if (f.complete && f.selection.retiring == 0) || session.now() > until {
                return f;
            }
            std::thread::sleep(Duration::from_millis(20));
        }
    };
    let f = settle(&mut session, &far, 20.0);
    assert!(f.complete && f.selection.holes == 0, "{f:?}");
    let drawn_far = session.draws().len();
    assert!(drawn_far > 0);

    // 503 + Retry-After: the client flies on to the near pose, keeps drawing (coarser) tiles it
    // has with no hole, and its requests are refused and paused, not hammered.
    up.store(false, Ordering::SeqCst);
    let started = session.scheduler().stats().started;
    let until = session.now() + 2.0;
    while session.now() < until {
        let f = session.frame(&near, 0.0, ReplayPhase::Flight).unwrap();
        assert!(!session.draws().is_empty() && f.selection.holes == 0, "{f:?}");
        assert!(!f.complete);
        std::thread::sleep(Duration::from_millis(20));
    }
    let st = session.scheduler().stats().clone();
    assert!(st.retries > 0, "{st:?}");
    // Retry-After: 1 pauses all new requests for a second after a refusal, so in 2 s at most
    // about two rounds of `max_in_flight` requests go out, not one per frame per tile.
    let sent = st.started - started;
    assert!(sent <= 4 * options().fetch.max_in_flight as u64, "{sent} requests while refused");

    // Back up: the near view completes.
    up.store(true, Ordering::SeqCst);
    let f = settle(&mut session, &near, 20.0);
    assert!(f.complete && f.selection.under_threshold && f.selection.holes == 0, "{f:?}");

    // The server stopped outright (connections refused), the camera moves back out: still
    // drawing, no hole; restarted on the same address: complete again.
    server.stop();
    let mid = world.pose_at(0.5 * (world.start() + world.end()));
    let until = session.now() + 1.5;
    while session.now() < until {
        let f = session.frame(&mid, 0.0, ReplayPhase::Flight).unwrap();
        assert!(!session.draws().is_empty() && f.selection.holes == 0, "{f:?}");
        std::thread::sleep(Duration::from_millis(20));
    }
    let server = start(tmp.path(), &upstream.to_string());
    let f = settle(&mut session, &mid, 20.0);
    assert!(f.complete && f.selection.under_threshold && f.selection.holes == 0, "{f:?}");
    assert_eq!(session.scheduler().stats().failed, 0);
    server.stop();
}

#[test]
fn client_command_writes_stats_json() {
    let tmp = tempfile::tempdir().unwrap();
    bake(tmp.path());
    let server = start(tmp.path(), "127.0.0.1:0");
    let out: PathBuf = tmp.path().join("out");
    // A short flight (2 s) so the command test stays quick.
    let fl = tmp.path().join("flight.json");
    std::fs::write(
        &fl,
        r#"{"frame":"normalized","keys":[
            {"t":0,"eye":[0.5,-0.3,0.6],"target":[0.5,0.5,0.05]},
            {"t":2,"eye":[0.5,-0.1,0.3],"target":[0.5,0.5,0.05]}]}"#,
    )
    .unwrap();
    let o = Command::new(env!("CARGO_BIN_EXE_terrastream"))
        .args(["client", "--url", &format!("http://{}", server.addr), "--tileset", TILESET, "--flight"])
        .arg(&fl)
        .args([
            "--width",
            "320",
            "--height",
            "200",
            "--fov",
            "50",
            "--threshold",
            "3",
            "--frames-every",
            "15",
        ])
        .arg("--out")
        .arg(&out)
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let stats: serde_json::Value =
        serde_json::from_slice(&std::fs::read(out.join("stats.json")).unwrap()).unwrap();
    assert_eq!(stats["width"], 320);
    assert_eq!(stats["threshold_px"], 3.0);
    let frames = stats["frames"].as_array().unwrap();
    assert!(frames.len() >= 60, "{}", frames.len());
    for k in ["visited", "drawn_per_level", "bytes_received", "requests_in_flight", "select_ms", "frame_ms"] {
        assert!(frames[0].get(k).is_some(), "frame field {k} missing");
    }
    for k in
        ["bytes", "requests", "latency_p50_ms", "latency_p99_ms", "first_complete_s", "share_under_threshold"]
    {
        assert!(stats["totals"].get(k).is_some(), "total {k} missing");
    }
    assert!(stats["totals"]["bytes"].as_u64().unwrap() > 0);
    // Rendering (auto): with an adapter every frame is rendered and timed inside the frame
    // time, and every 15th frame plus the settled view is written as PNG.
    let rendering = stats["rendering"].as_str().unwrap();
    if rendering.starts_with("off") {
        assert!(!require_gpu(), "TERRASTREAM_REQUIRE_GPU=1 but the client did not render: {rendering}");
        println!("client did not render: {rendering}");
    } else {
        for f in frames {
            let (r, t) = (f["render_ms"].as_f64().unwrap(), f["frame_ms"].as_f64().unwrap());
            assert!(r > 0.0 && t >= r, "render {r} ms, frame {t} ms");
        }
        let written: Vec<String> = std::fs::read_dir(out.join("frames"))
            .unwrap()
            .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
            .collect();
        assert!(written.contains(&"00000.png".to_owned()) && written.contains(&"00015.png".to_owned()));
        assert!(written.contains(&"final.png".to_owned()), "{written:?}");
        assert!(!written.contains(&"00001.png".to_owned()));
        let img = image::open(out.join("frames/final.png")).unwrap();
        assert_eq!((img.width(), img.height()), (320, 200));
    }
    // Bad input: a flight that is not there is named.
    let o = Command::new(env!("CARGO_BIN_EXE_terrastream"))
        .args(["client", "--url", &format!("http://{}", server.addr), "--tileset", TILESET, "--flight"])
        .arg(tmp.path().join("missing.json"))
        .output()
        .unwrap();
    assert!(!o.status.success());
    assert!(String::from_utf8_lossy(&o.stderr).contains("missing.json"));
    server.stop();
}

/// (b) The client renders every frame of the shipped flight; once the view has settled, its
/// frame is compared with a render of the full-resolution TIN (every leaf's level-0 mesh, read
/// from the tileset on disk) from the same camera: no pixel where the reference shows terrain
/// may be empty in the client's frame.
#[cfg(feature = "gpu")]
#[test]
fn settled_view_covers_the_full_resolution_terrain() {
    use terrastream::client::render::{Renderer, covered};
    use terrastream::client::select::DrawItem;
    use terrastream::client::stream::view::SessionView;
    use terrastream::client::tree::TileTree;

    let Some(ctx) = gpu_or_skip("GPU streaming test") else { return };
    let tmp = tempfile::tempdir().unwrap();
    bake(tmp.path());
    let server = start(tmp.path(), "127.0.0.1:0");
    let opts = options();
    let mut session = Session::connect(&format!("http://{}", server.addr), TILESET, opts).unwrap();
    let (device, queue) = (ctx.device.clone(), ctx.queue.clone());
    let mut view = SessionView::new(ctx, &session, opts.width, opts.height).unwrap();
    let flight = flight();
    let replay = ReplayOptions { fps: 30.0, settle_s: 20.0, speed: 4.0 };
    let (frames, totals) = live::replay(&mut session, &flight, &replay, |s, f| {
        let start = std::time::Instant::now();
        view.draw(s, false).unwrap();
        f.render_ms = start.elapsed().as_secs_f64() * 1e3;
        Ok(())
    })
    .unwrap();
    assert!(totals.settled, "view never completed: {:?}", frames.last());
    assert!(frames.iter().all(|f| f.render_ms > 0.0));
    let lod = view.draw(&session, true).unwrap().unwrap();
    // Each drawn (tile, level) was uploaded once, or again only when its skirt had to grow.
    assert!(view.uploads() <= 2 * session.fetch_counts().len() as u64, "{} uploads", view.uploads());

    // The reference from the tileset on disk, same camera, same origin and far plane.
    let store = Store::new(&tmp.path().join(TILESET));
    let manifest = store.manifest().unwrap();
    let tree = TileTree::load(&store).unwrap();
    let mut reference = Renderer::new(device, queue, opts.width, opts.height, manifest.bounds.min).unwrap();
    let leaves: Vec<DrawItem> = tree
        .nodes()
        .iter()
        .enumerate()
        .filter(|(_, n)| n.is_leaf())
        .map(|(i, n)| {
            let blob = terrastream::codec::decode(&store.read_blob(n.key, 0).unwrap().unwrap()).unwrap();
            // Leaves share their border vertices: no skirts needed at full resolution.
            reference.upload(&blob, 0.0, Some(&manifest.bounds), 0.0, 0.0);
            DrawItem {
                node: i as u32,
                key: n.key,
                level: 0,
                alpha: 1.0,
                retiring: false,
                error_px: 0.0,
                error_world: 0.0,
            }
        })
        .collect();
    let size = manifest.bounds.size();
    let far = 8.0 * (size[0].abs() + size[1].abs() + size[2].abs());
    let camera = *session.camera().unwrap();
    let full = reference.render(&camera, &leaves, far).unwrap();
    let out = Path::new(env!("CARGO_TARGET_TMPDIR")).join("client-streaming");
    std::fs::create_dir_all(&out).unwrap();
    Renderer::save_png(&full, &out.join("full-resolution.png")).unwrap();
    Renderer::save_png(&lod, &out.join("client.png")).unwrap();
    let (a, b) = (covered(&full), covered(&lod));
    let terrain = a.iter().filter(|&&c| c).count();
    let empty: Vec<usize> = (0..a.len()).filter(|&i| a[i] && !b[i]).collect();
    println!(
        "settled view: {} tiles drawn (per level {:?}); terrain {terrain} px, empty in the client's frame {} px; frames in {}",
        session.draws().len(),
        frames.last().unwrap().selection.drawn_per_level,
        empty.len(),
        out.display()
    );
    assert!(terrain > (opts.width * opts.height / 4) as usize, "the reference shows little terrain");
    assert!(
        empty.is_empty(),
        "{} terrain pixels empty in the client's frame, first at {:?}",
        empty.len(),
        empty.iter().take(5).map(|&i| (i % opts.width as usize, i / opts.width as usize)).collect::<Vec<_>>()
    );
    server.stop();
}
