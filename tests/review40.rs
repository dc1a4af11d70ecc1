//! The held-back review of issue 40: inputs and configuration the server and the bakes read
//! outside the store — a raster that is a FIFO or a device (refused, never opened: an open
//! waits for a writer forever), a raster too small to tile given to `serve --source` or
//! uploaded to the admin API (the message names the file), `serve --config` bounded whatever
//! the file is (a pipe still works).
#![allow(clippy::unwrap_used, clippy::panic)]

mod common;

use std::io::{Read, Write};
use std::path::Path;
use std::process::Command;
use std::time::{Duration, Instant};

use common::{bin, fails, run_within};

/// A 1×1 terrain-RGB PNG.
fn one_pixel_png(path: &Path) {
    image::RgbImage::from_raw(1, 1, vec![1, 0x86, 0xa0]).unwrap().save(path).unwrap();
}

fn mkfifo(path: &Path) -> bool {
    let ok = Command::new("mkfifo").arg(path).status().is_ok_and(|s| s.success());
    if !ok {
        eprintln!("mkfifo is not available; skipped");
    }
    ok
}

/// `serve --source` with a 1×1 raster: refused at startup naming the file (it said only
/// "bake: raster of 1×1 samples is too small to tile").
#[test]
fn serve_source_too_small_names_the_file() {
    let dir = tempfile::tempdir().unwrap();
    let png = dir.path().join("one.png");
    one_pixel_png(&png);
    let store = dir.path().join("store");
    std::fs::create_dir(&store).unwrap();
    let e = fails(
        bin()
            .args(["serve", "--gpu", "off", "--bind", "127.0.0.1:0", "--store"])
            .arg(&store)
            .arg("--source")
            .arg(format!("t={},encoding=terrain-rgb,cell_size=30", png.display())),
    );
    assert!(e.contains("one.png: is 1×1 samples; a heightfield needs at least 2×2"), "{e}");
}

/// One HTTP/1.1 request with `Connection: close`; the status and the whole raw response.
fn http(addr: std::net::SocketAddr, method: &str, path: &str, body: &[u8]) -> (u16, String) {
    let mut s = std::net::TcpStream::connect(addr).unwrap();
    s.set_read_timeout(Some(Duration::from_secs(30))).unwrap();
    let head = format!(
        "{method} {path} HTTP/1.1\r\nHost: t\r\nConnection: close\r\nAuthorization: Bearer admin-secret-1\r\n\
         Content-Length: {}\r\n\r\n",
        body.len()
    );
    s.write_all(head.as_bytes()).unwrap();
    // The server may answer (and close) before reading the whole body.
    let _ = s.write_all(body);
    let mut out = Vec::new();
    s.read_to_end(&mut out).unwrap();
    let text = String::from_utf8_lossy(&out).into_owned();
    let status = text.get(9..12).and_then(|c| c.parse().ok()).unwrap_or(0);
    (status, text)
}

/// An admin upload of a 1×1 raster: the job fails naming the upload and the size, as `bake`
/// names its input (it said only "bake: raster of 1×1 samples is too small to tile").
#[test]
fn admin_upload_too_small_names_the_upload() {
    let dir = tempfile::tempdir().unwrap();
    let png = dir.path().join("one.png");
    one_pixel_png(&png);
    let store = dir.path().join("store");
    std::fs::create_dir(&store).unwrap();
    let mut cmd = bin();
    cmd.args(["serve", "--gpu", "off", "--admin-token", "admin-secret-1", "--store"]).arg(&store);
    let srv = common::serve(cmd);
    let (status, r) =
        http(srv.addr, "POST", "/tilesets/one?encoding=terrain-rgb", &std::fs::read(&png).unwrap());
    assert_eq!(status, 202, "{r}");
    let t0 = Instant::now();
    let job = loop {
        let (_, j) = http(srv.addr, "GET", "/jobs/j1", &[]);
        if j.contains("\"failed\"") {
            break j;
        }
        assert!(t0.elapsed() < Duration::from_mins(1) && !j.contains("\"done\""), "{j}");
        std::thread::sleep(Duration::from_millis(50));
    };
    assert!(
        job.contains(".upload-j1: is 1×1 samples; a heightfield needs at least 2×2 to be tiled"),
        "{job}"
    );
}

/// `serve --config /dev/zero` is refused at 1 MiB (it read until memory ran out); run under a
/// 2 GB address-space limit so a regression fails instead of exhausting the machine.
#[test]
fn serve_config_is_bounded() {
    let out = run_within(
        Command::new("sh").arg("-c").arg(format!(
            "ulimit -v 2000000; exec {} serve --config /dev/zero --store /nonexistent",
            env!("CARGO_BIN_EXE_terrastream")
        )),
        Duration::from_mins(1),
    );
    let e = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success());
    assert!(e.contains("/dev/zero: more than 1048576 bytes"), "{e}");
}

/// `--config <(…)`: a pipe is read (bounded, not refused), and once: it was read a first time
/// for the log format and a second time, empty, for the settings, so a piped `read_token` was
/// silently dropped and the tileset served to anyone.
#[test]
fn serve_config_from_a_pipe_is_read_once() {
    let dir = tempfile::tempdir().unwrap();
    let store = dir.path().join("store");
    std::fs::create_dir(&store).unwrap();
    let fifo = dir.path().join("config.toml");
    if !mkfifo(&fifo) {
        return;
    }
    let text =
        format!("store = {:?}\ngpu = \"off\"\nread_token = \"read-secret-1\"\n", store.display().to_string());
    let f2 = fifo.clone();
    let writer = std::thread::spawn(move || std::fs::write(f2, text).unwrap());
    let mut cmd = bin();
    cmd.arg("serve").arg("--config").arg(&fifo);
    let srv = common::serve(cmd);
    assert_eq!(common::http_get(srv.addr, "/healthz").unwrap().0, 200);
    assert_eq!(common::http_get(srv.addr, "/tilesets").unwrap().0, 401, "the piped read_token is in force");
    writer.join().unwrap();
}

/// A raster input that is a FIFO — given to `bake`, named by a VRT, or given to
/// `serve --source` — is refused naming it, within seconds (each waited forever for a writer).
#[test]
fn fifo_rasters_are_refused_not_waited_on() {
    let dir = tempfile::tempdir().unwrap();
    let fifo = dir.path().join("pipe.tif");
    if !mkfifo(&fifo) {
        return;
    }
    let vrt = dir.path().join("m.vrt");
    std::fs::write(
        &vrt,
        r#"<VRTDataset rasterXSize="2" rasterYSize="2"><GeoTransform>0,1,0,0,0,-1</GeoTransform>
<VRTRasterBand dataType="Float32" band="1"><SimpleSource><SourceFilename relativeToVRT="1">pipe.tif</SourceFilename>
</SimpleSource></VRTRasterBand></VRTDataset>"#,
    )
    .unwrap();
    let store = dir.path().join("store");
    std::fs::create_dir(&store).unwrap();
    let limit = Duration::from_secs(30);
    let want = "pipe.tif: is a FIFO (named pipe), not a regular file";
    for (what, mut cmd) in [
        ("bake", {
            let mut c = bin();
            c.args(["bake", "-q", "--gpu", "off", "--out"]).arg(dir.path().join("o1")).arg(&fifo);
            c
        }),
        ("bake VRT", {
            let mut c = bin();
            c.args(["bake", "-q", "--gpu", "off", "--out"]).arg(dir.path().join("o2")).arg(&vrt);
            c
        }),
        ("serve --source", {
            let mut c = bin();
            c.args(["serve", "--gpu", "off", "--bind", "127.0.0.1:0", "--store"])
                .arg(&store)
                .arg("--source")
                .arg(format!("p={}", fifo.display()));
            c
        }),
    ] {
        let out = run_within(&mut cmd, limit);
        let e = String::from_utf8_lossy(&out.stderr);
        assert!(!out.status.success(), "{what}");
        assert!(e.contains(want), "{what}: {e}");
    }
}

/// A raster input that is a device (`x.vrt -> /dev/zero`) is refused unread (a VRT was read
/// until memory ran out: its size check saw 0 bytes).
#[test]
fn device_rasters_are_refused_unread() {
    let dir = tempfile::tempdir().unwrap();
    let z = dir.path().join("z.vrt");
    std::os::unix::fs::symlink("/dev/zero", &z).unwrap();
    let out = run_within(
        Command::new("sh").arg("-c").arg(format!(
            "ulimit -v 2000000; exec {} bake -q --gpu off --out {} {}",
            env!("CARGO_BIN_EXE_terrastream"),
            dir.path().join("o").display(),
            z.display()
        )),
        Duration::from_mins(1),
    );
    let e = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success());
    assert!(e.contains("z.vrt: is a character device, not a regular file"), "{e}");
}

/// A small tileset of `fuji.png` in `dir/name`.
fn bake_small(dir: &Path, name: &str) -> std::path::PathBuf {
    let out = dir.join(name);
    common::ok(
        bin()
            .args(["bake", "-q", "--gpu", "off", "--encoding", "terrain-rgb", "--cell-size", "30"])
            .args(["--tile-size", "128", "--out"])
            .arg(&out)
            .arg(common::data("fuji.png")),
    );
    out
}

/// `pack` packs what a server serves from the folder: `tiles/` linked to another disk is
/// followed (it was skipped: an archive of 3 files, exit 0), and a file that is not a regular
/// file is refused naming it (it was left out silently: an archive missing that blob).
#[test]
fn pack_follows_links_and_refuses_irregular_files() {
    let dir = tempfile::tempdir().unwrap();
    let t = bake_small(dir.path(), "t");
    let files = common::tree(&t).len();
    let packed = |out: &str| {
        common::ok(bin().arg("pack").arg(&t).arg("--out").arg(dir.path().join(out)).arg("-q"));
    };
    packed("plain.tsa");
    let plain = std::fs::read(dir.path().join("plain.tsa")).unwrap();
    // tiles/ moved elsewhere and linked: the same archive.
    let elsewhere = dir.path().join("elsewhere");
    std::fs::rename(t.join("tiles"), &elsewhere).unwrap();
    std::os::unix::fs::symlink(&elsewhere, t.join("tiles")).unwrap();
    packed("linked.tsa");
    assert!(std::fs::read(dir.path().join("linked.tsa")).unwrap() == plain, "{files} files: archives differ");
    // A blob replaced by a FIFO: refused, naming it; no archive.
    let blob = elsewhere.join("0/0/0/0.tsb");
    std::fs::remove_file(&blob).unwrap();
    if !mkfifo(&blob) {
        return;
    }
    let e = fails(bin().arg("pack").arg(&t).arg("--out").arg(dir.path().join("fifo.tsa")));
    assert!(e.contains("0/0/0/0.tsb: is a FIFO (named pipe), not a regular file"), "{e}");
    assert!(!dir.path().join("fifo.tsa").exists());
}

/// A damaged index chunk in a folder (truncated: no checksum to catch it) is `500 corrupt-blob`,
/// counted, never sent — as an archive answers for the same chunk (it was sent, `200`, and
/// the 3D Tiles routes answered `500 index`, uncounted).
#[test]
fn a_damaged_index_chunk_in_a_folder_is_corrupt_not_sent() {
    let dir = tempfile::tempdir().unwrap();
    let store = dir.path().join("store");
    std::fs::create_dir(&store).unwrap();
    let t = bake_small(&store, "t");
    let chunk = t.join("index/0/0/0.json");
    let bytes = std::fs::read(&chunk).unwrap();
    std::fs::write(&chunk, &bytes[..bytes.len() / 2]).unwrap();
    let mut cmd = bin();
    cmd.args(["serve", "--gpu", "off", "--store"]).arg(&store);
    let srv = common::serve(cmd);
    for url in ["/tilesets/t/index/0/0/0.json", "/tilesets/t/3dtiles/tileset.json"] {
        let (status, _, body) = common::http_get(srv.addr, url).unwrap();
        let body = String::from_utf8_lossy(&body);
        assert_eq!(status, 500, "{url}: {body}");
        assert!(body.contains("corrupt-blob"), "{url}: {body}");
    }
    let (_, _, metrics) = common::http_get(srv.addr, "/metrics").unwrap();
    assert!(String::from_utf8_lossy(&metrics).contains("terrastream_corrupt_blobs_total 2"));
}

/// `DELETE /tilesets/NAME` of a tileset served from its archive `NAME.tsa` deletes it (it
/// answered `404 no tileset named …` while the tileset was being served).
#[test]
fn admin_delete_removes_a_packed_tileset() {
    let dir = tempfile::tempdir().unwrap();
    let t = bake_small(dir.path(), "t");
    let store = dir.path().join("store");
    std::fs::create_dir(&store).unwrap();
    common::ok(bin().arg("pack").arg(&t).arg("--out").arg(store.join("p.tsa")).arg("-q"));
    let mut cmd = bin();
    cmd.args(["serve", "--gpu", "off", "--admin-token", "admin-secret-1", "--store"]).arg(&store);
    let srv = common::serve(cmd);
    assert_eq!(common::http_get(srv.addr, "/tilesets/p/tileset.json").unwrap().0, 200);
    let (status, r) = http(srv.addr, "DELETE", "/tilesets/p", &[]);
    assert_eq!(status, 204, "{r}");
    assert_eq!(common::http_get(srv.addr, "/tilesets/p/tileset.json").unwrap().0, 404);
    let t0 = Instant::now();
    while store.join("p.tsa").exists() || std::fs::read_dir(&store).unwrap().next().is_some() {
        assert!(t0.elapsed() < Duration::from_secs(30), "the archive is still in the store");
        std::thread::sleep(Duration::from_millis(50));
    }
    // Not found again by the next scans.
    std::thread::sleep(Duration::from_millis(2500));
    assert_eq!(common::http_get(srv.addr, "/tilesets/p/tileset.json").unwrap().0, 404);
}

/// `--finish` with a shard result that cannot be used — not JSON, a FIFO — sends that shard back
/// (result removed, exit 1 naming it) as for a damaged blob: running the shard again and
/// finishing then succeeds. It exited 3 ("fix the input; a retry cannot help") and kept the file.
#[test]
fn finish_sends_back_an_unusable_shard_result() {
    let dir = tempfile::tempdir().unwrap();
    let w = dir.path().join("w");
    common::ok(
        bin()
            .arg("plan")
            .arg(common::data("fuji.png"))
            .args([
                "--encoding",
                "terrain-rgb",
                "--cell-size",
                "30",
                "--tile-size",
                "128",
                "--shards",
                "2",
                "-q",
            ])
            .arg("--out")
            .arg(&w),
    );
    for i in 0..2 {
        common::ok(&mut common::shard_step(bin(), &w, i));
    }
    let finish = || {
        let mut c = bin();
        c.arg("bake").arg("--plan").arg(&w).args(["--finish", "-q", "--gpu", "off"]);
        c
    };
    let result = |i: u32| w.join(format!("shards/shard-{i}.json"));
    std::fs::write(result(0), b"not json").unwrap();
    std::fs::remove_file(result(1)).unwrap();
    let fifo = mkfifo(&result(1));
    if !fifo {
        std::fs::write(result(1), b"[]").unwrap();
    }
    let out = run_within(&mut finish(), Duration::from_mins(1));
    let e = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(1), "{e}");
    assert!(e.contains("shard 0:") && e.contains("invalid shard result"), "{e}");
    assert!(e.contains("shard 1:") && e.contains("run them again"), "{e}");
    assert!(!result(0).exists() && std::fs::symlink_metadata(result(1)).is_err(), "sent back");
    assert!(!w.join("tileset.json").exists(), "nothing published");
    for i in 0..2 {
        common::ok(&mut common::shard_step(bin(), &w, i));
    }
    common::ok(&mut finish());
    assert!(w.join("tileset.json").exists());
}

/// An upload is written to a new file only: a `.upload-j1` planted in the store after startup
/// (a link to a file elsewhere) is not written through (the linked file was overwritten with
/// the upload); the upload fails `500 store-io` and the next one works.
#[test]
fn admin_upload_does_not_write_through_a_planted_link() {
    let dir = tempfile::tempdir().unwrap();
    let store = dir.path().join("store");
    std::fs::create_dir(&store).unwrap();
    let victim = dir.path().join("victim.txt");
    std::fs::write(&victim, b"keep").unwrap();
    let mut cmd = bin();
    cmd.args(["serve", "--gpu", "off", "--admin-token", "admin-secret-1", "--store"]).arg(&store);
    let srv = common::serve(cmd);
    std::os::unix::fs::symlink(&victim, store.join(".upload-j1")).unwrap();
    // A small body: the server answers before reading it, and a large one could meet a reset.
    one_pixel_png(&dir.path().join("one.png"));
    let png = std::fs::read(dir.path().join("one.png")).unwrap();
    let (status, r) = http(srv.addr, "POST", "/tilesets/one?encoding=terrain-rgb&cell_size=30", &png);
    assert_eq!(status, 500, "{r}");
    assert!(r.contains("store-io"), "{r}");
    assert_eq!(std::fs::read(&victim).unwrap(), b"keep");
    let (status, r) = http(srv.addr, "POST", "/tilesets/one?encoding=terrain-rgb&cell_size=30", &png);
    assert_eq!(status, 202, "{r}");
}
