//! How the server and the command-line readers open stored files (issue 40, N1–N4, N9, N10):
//! FIFOs and devices in the store are skipped unopened and never wedge polling, readiness or
//! shutdown; damage inside an archive is `500 corrupt-blob` (counted), not a retryable `503`;
//! stored files are checked against their limits before they are read, and a broken tileset is
//! read and logged once per change; `plan.json -> /dev/zero` fails at once (exit 3); `pack`
//! writes archives with the mode bakes give files.

#![allow(clippy::unwrap_used, clippy::panic)]

mod common;

use std::collections::BTreeMap;
use std::io::{Seek, Write};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

use common::{bin, fails, http_get, ok, run_within, tree};

const BAKE: [&str; 6] = ["--tile-size", "32", "--levels", "2", "--max-error", "1"];

/// A small finished tileset at `dir/NAME`.
fn baked(dir: &Path, name: &str) -> PathBuf {
    let tif = dir.join("t.tif");
    if !tif.exists() {
        ok(bin().args(["synth", "--width", "97", "--height", "97", "--seed", "4", "--out"]).arg(&tif));
    }
    let out = dir.join(name);
    ok(bin().arg("bake").arg(&tif).arg("--out").arg(&out).args(BAKE).args(["-q", "--gpu", "off"]));
    out
}

fn mkfifo(p: &Path) {
    let st = Command::new("mkfifo").arg(p).status().unwrap();
    assert!(st.success(), "mkfifo {}", p.display());
}

/// A server whose log goes to a file (read with [`Server::log`]); killed when dropped.
struct Server {
    child: Child,
    addr: std::net::SocketAddr,
    log: PathBuf,
}

impl Drop for Server {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

impl Server {
    /// `serve --store STORE --poll-ms 100`, waiting (at most `ready_within`) for `/readyz`.
    fn start(store: &Path, log: PathBuf, ready_within: Duration) -> Self {
        let port = std::net::TcpListener::bind("127.0.0.1:0").unwrap().local_addr().unwrap().port();
        let addr: std::net::SocketAddr = format!("127.0.0.1:{port}").parse().unwrap();
        let child = bin()
            .arg("serve")
            .arg("--store")
            .arg(store)
            .args(["--poll-ms", "100", "--bind", &addr.to_string()])
            .env("TERRASTREAM_LOG", "info")
            .stdout(Stdio::null())
            .stderr(std::fs::File::create(&log).unwrap())
            .spawn()
            .unwrap();
        let s = Self { child, addr, log };
        let t0 = Instant::now();
        while http_get(addr, "/readyz").map(|r| r.0) != Some(200) {
            assert!(
                t0.elapsed() < ready_within,
                "the server did not become ready in {ready_within:?}; its log:\n{}",
                s.log()
            );
            std::thread::sleep(Duration::from_millis(50));
        }
        s
    }

    fn log(&self) -> String {
        std::fs::read_to_string(&self.log).unwrap_or_default()
    }

    fn status(&self, path: &str) -> u16 {
        http_get(self.addr, path).unwrap().0
    }

    /// Waits (at most 20 s) until `path` answers `status`.
    fn wait_for(&self, path: &str, status: u16) {
        let t0 = Instant::now();
        while self.status(path) != status {
            assert!(
                t0.elapsed() < Duration::from_secs(20),
                "{path} never answered {status}; log:\n{}",
                self.log()
            );
            std::thread::sleep(Duration::from_millis(50));
        }
    }

    /// Sends SIGTERM and asserts the process exits within `within`.
    fn terminate_within(&mut self, within: Duration) {
        let st = Command::new("kill").arg("-TERM").arg(self.child.id().to_string()).status().unwrap();
        assert!(st.success());
        let t0 = Instant::now();
        while self.child.try_wait().unwrap().is_none() {
            assert!(
                t0.elapsed() < within,
                "SIGTERM did not stop the server in {within:?}; log:\n{}",
                self.log()
            );
            std::thread::sleep(Duration::from_millis(50));
        }
    }
}

fn copy_tree(from: &Path, to: &Path) {
    for (rel, b) in tree(from) {
        let p = to.join(rel);
        std::fs::create_dir_all(p.parent().unwrap()).unwrap();
        std::fs::write(p, b).unwrap();
    }
}

/// N1: FIFOs named like an archive or a manifest, there before `serve` starts or made while it
/// runs, are skipped (one log line each), never opened: the server starts, serves the good
/// tileset, keeps polling (a tileset copied in later is found), stays ready, and SIGTERM stops it.
#[test]
fn fifos_in_the_store_are_skipped_and_never_wedge_the_server() {
    let tmp = tempfile::tempdir().unwrap();
    let store = tmp.path().join("store");
    let good = baked(&store, "good");
    mkfifo(&store.join("pipe.tsa"));
    std::fs::create_dir_all(store.join("t")).unwrap();
    mkfifo(&store.join("t/tileset.json"));

    let mut srv = Server::start(&store, tmp.path().join("serve.log"), Duration::from_secs(20));
    assert_eq!(srv.status("/tilesets/good/tileset.json"), 200);
    assert_eq!(srv.status("/tilesets/pipe"), 404);
    assert_eq!(srv.status("/tilesets/t"), 404);

    // Made while it runs: polling goes on past them.
    mkfifo(&store.join("pipe2.tsa"));
    std::fs::create_dir_all(store.join("t2")).unwrap();
    mkfifo(&store.join("t2/tileset.json"));
    std::thread::sleep(Duration::from_millis(500));
    copy_tree(&good, &store.join("late"));
    srv.wait_for("/tilesets/late/tileset.json", 200);
    std::fs::remove_dir_all(&good).unwrap();
    srv.wait_for("/tilesets/good/tileset.json", 404);
    assert_eq!(srv.status("/readyz"), 200);
    // A FIFO blob in a served folder: refused unopened, as damage (not a hang, not a 503).
    std::fs::remove_file(store.join("late/tiles/0/0/0/0.tsb")).unwrap();
    mkfifo(&store.join("late/tiles/0/0/0/0.tsb"));
    let (status, _, body) = http_get(srv.addr, "/tilesets/late/tiles/0/0/0/0").unwrap();
    assert_eq!(status, 500, "{}", String::from_utf8_lossy(&body));
    assert!(String::from_utf8_lossy(&body).contains("corrupt-blob"));
    std::thread::sleep(Duration::from_millis(500));

    let log = srv.log();
    for name in ["pipe", "t", "pipe2", "t2"] {
        let lines = log
            .lines()
            .filter(|l| l.contains("tileset skipped") && l.contains(&format!("tileset={name} ")))
            .count();
        assert_eq!(lines, 1, "{name} logged {lines} times:\n{log}");
    }
    assert!(log.contains("FIFO"), "{log}");
    srv.terminate_within(Duration::from_secs(5));
}

/// N4: a manifest that is a symbolic link to `/dev/zero` (size 0, endless) is refused by its
/// type, never read: the server starts at once and serves the good tileset.
#[test]
fn a_manifest_linked_to_a_device_is_not_read() {
    let tmp = tempfile::tempdir().unwrap();
    let store = tmp.path().join("store");
    baked(&store, "good");
    std::fs::create_dir_all(store.join("z")).unwrap();
    std::os::unix::fs::symlink("/dev/zero", store.join("z/tileset.json")).unwrap();
    std::os::unix::fs::symlink("/dev/zero", store.join("zz.tsa")).unwrap();
    let mut srv = Server::start(&store, tmp.path().join("serve.log"), Duration::from_secs(20));
    assert_eq!(srv.status("/tilesets/good/tileset.json"), 200);
    assert_eq!(srv.status("/tilesets/z"), 404);
    assert_eq!(srv.status("/tilesets/zz"), 404);
    let log = srv.log();
    assert!(log.contains("character device"), "{log}");
    srv.terminate_within(Duration::from_secs(5));
}

/// N4: a plan that is a symbolic link to `/dev/zero` is refused at once as a damaged plan
/// (exit 3, input refused), not read until memory runs out.
#[test]
fn a_plan_linked_to_a_device_fails_at_once_with_exit_3() {
    let tmp = tempfile::tempdir().unwrap();
    let w = tmp.path().join("w");
    std::fs::create_dir_all(w.join("shards")).unwrap();
    std::os::unix::fs::symlink("/dev/zero", w.join("shards/plan.json")).unwrap();
    let mut cmd = bin();
    cmd.arg("bake").arg("--plan").arg(&w).args(["--shard", "0", "-q", "--gpu", "off"]);
    let t0 = Instant::now();
    let out = run_within(&mut cmd, Duration::from_secs(20));
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(3), "{err}");
    assert!(err.contains("plan.json") && err.contains("character device"), "{err}");
    assert!(t0.elapsed() < Duration::from_secs(10));
}

/// An archive of `files` (sorted by path), written sparsely: runs of zeros of a MiB or more
/// are skipped over, not written.
fn write_archive(path: &Path, files: &BTreeMap<String, Vec<u8>>) {
    struct Sparse(std::fs::File, u64);
    impl Write for Sparse {
        fn write(&mut self, buf: &[u8]) -> std::io::Result<usize> {
            if buf.len() >= 1 << 20 && buf.iter().all(|&b| b == 0) {
                self.0.seek(std::io::SeekFrom::Current(buf.len() as i64))?;
            } else {
                self.0.write_all(buf)?;
            }
            self.1 += buf.len() as u64;
            Ok(buf.len())
        }
        fn flush(&mut self) -> std::io::Result<()> {
            self.0.set_len(self.1)
        }
    }
    let mut w =
        terrastream::store::archive::ArchiveWriter::new(Sparse(std::fs::File::create(path).unwrap(), 0))
            .unwrap();
    for (rel, b) in files {
        w.add(rel, b).unwrap();
    }
    w.finish().unwrap();
}

fn problem_type(body: &[u8]) -> String {
    let v: serde_json::Value = serde_json::from_slice(body).unwrap();
    v["type"].as_str().unwrap_or_default().to_owned()
}

fn corrupt_count(addr: std::net::SocketAddr) -> u64 {
    let (_, _, m) = http_get(addr, "/metrics").unwrap();
    let m = String::from_utf8(m).unwrap();
    let line = m.lines().find(|l| l.starts_with("terrastream_corrupt_blobs_total ")).unwrap();
    line.rsplit(' ').next().unwrap().parse().unwrap()
}

/// N2: a payload byte flipped inside an archive, or a damaged index chunk, is `500
/// corrupt-blob` without `Retry-After`, counted and logged as corruption naming the archive
/// and the entry, as the same damage in a folder store is.
#[test]
fn damage_inside_an_archive_is_corrupt_blob_not_retryable() {
    let tmp = tempfile::tempdir().unwrap();
    let ts = baked(tmp.path(), "ts");
    let store = tmp.path().join("store");
    std::fs::create_dir_all(&store).unwrap();
    let tsa = store.join("ts.tsa");
    ok(bin().arg("pack").arg(&ts).arg("--out").arg(&tsa).arg("-q"));
    let a = terrastream::store::archive::Archive::open_file(&tsa).unwrap();
    let blob = a.entry("tiles/1/0/0/0.tsb").unwrap().unwrap();
    let chunk = a.entry("index/0/0/0.json").unwrap().unwrap();
    drop(a);
    let mut bytes = std::fs::read(&tsa).unwrap();
    bytes[(blob.offset + blob.len - 1) as usize] ^= 0x01;
    bytes[(chunk.offset + chunk.len / 2) as usize] ^= 0x01;
    std::fs::write(&tsa, &bytes).unwrap();

    let srv = Server::start(&store, tmp.path().join("serve.log"), Duration::from_secs(20));
    assert_eq!(corrupt_count(srv.addr), 0);
    for (url, n) in [("/tilesets/ts/tiles/1/0/0/0", 1), ("/tilesets/ts/index/0/0/0.json", 2)] {
        let (status, h, body) = http_get(srv.addr, url).unwrap();
        assert_eq!(status, 500, "{url}: {}", String::from_utf8_lossy(&body));
        assert!(problem_type(&body).ends_with(":corrupt-blob"), "{url}: {}", String::from_utf8_lossy(&body));
        assert!(!h.iter().any(|(k, _)| k == "retry-after"), "{url}: {h:?}");
        assert_eq!(corrupt_count(srv.addr), n, "{url}");
    }
    // Undamaged entries are served.
    assert_eq!(srv.status("/tilesets/ts/tiles/0/0/0/0"), 200);
    let log = srv.log();
    let lines: Vec<&str> = log.lines().filter(|l| l.contains("corrupt")).collect();
    assert!(lines.iter().any(|l| l.contains("ts.tsa") && l.contains("tiles/1/0/0/0.tsb")), "{log}");
    assert!(lines.iter().any(|l| l.contains("ts.tsa") && l.contains("index/0/0/0.json")), "{log}");
    assert!(!log.contains("not a terrastream archive"), "{log}");
}

/// N3: stored files larger than their kind can be are refused before they are read: a blob
/// entry past the blob format's limit and an index chunk of 5 MiB in an archive (checksums
/// consistent), an index chunk of 5 MiB in a folder; `inspect` and `export` refuse them too.
/// A 5 MiB manifest is skipped once and not read again while unchanged (N10: logged once).
#[test]
fn oversized_stored_files_are_refused_unread() {
    let tmp = tempfile::tempdir().unwrap();
    let ts = baked(tmp.path(), "ts");
    let store = tmp.path().join("store");
    std::fs::create_dir_all(&store).unwrap();
    let mut files = tree(&ts);
    let big_blob = terrastream::store::MAX_BLOB_BYTES as usize + 1;
    files.insert("tiles/1/0/0/0.tsb".into(), vec![0u8; big_blob]);
    let mut chunk = files["index/0/0/0.json"].clone();
    chunk.resize(5 << 20, b' ');
    files.insert("index/0/0/0.json".into(), chunk.clone());
    write_archive(&store.join("big.tsa"), &files);
    drop(files);
    // A folder with the same index chunk, and one whose manifest is 5 MiB.
    copy_tree(&ts, &store.join("dir"));
    std::fs::write(store.join("dir/index/0/0/0.json"), &chunk).unwrap();
    copy_tree(&ts, &store.join("fat"));
    let mut manifest = std::fs::read(store.join("fat/tileset.json")).unwrap();
    manifest.resize(5 << 20, b' ');
    std::fs::write(store.join("fat/tileset.json"), &manifest).unwrap();

    let srv = Server::start(&store, tmp.path().join("serve.log"), Duration::from_secs(20));
    for url in
        ["/tilesets/big/tiles/1/0/0/0", "/tilesets/big/index/0/0/0.json", "/tilesets/dir/index/0/0/0.json"]
    {
        let (status, _, body) = http_get(srv.addr, url).unwrap();
        assert_eq!(status, 500, "{url}: {} bytes", body.len());
        assert!(problem_type(&body).ends_with(":corrupt-blob"), "{url}");
    }
    assert_eq!(srv.status("/tilesets/big/tiles/0/0/0/0"), 200);
    assert_eq!(srv.status("/tilesets/fat"), 404);
    std::thread::sleep(Duration::from_secs(1));
    let log = srv.log();
    assert!(log.contains(&format!("is {big_blob} bytes; a blob is at most")), "{log}");
    let fat = log.lines().filter(|l| l.contains("tileset=fat ")).count();
    assert_eq!(fat, 1, "the 5 MiB manifest was logged {fat} times in 10 polls:\n{log}");
    assert!(log.contains("a JSON document of a tileset is at most 4194304 bytes"), "{log}");
    drop(srv);

    let err = fails(bin().arg("inspect").arg(store.join("fat")));
    assert!(err.contains("tileset.json") && err.contains("at most 4194304 bytes"), "{err}");
    let err = fails(bin().arg("inspect").arg(store.join("big.tsa")));
    assert!(err.contains("index/0/0/0.json") && err.contains("at most 4194304 bytes"), "{err}");
    let err = fails(
        bin()
            .arg("export")
            .arg(store.join("big.tsa"))
            .args(["--tile", "1/0/0", "--level", "0", "--out"])
            .arg(tmp.path().join("x.ply")),
    );
    assert!(err.contains("tiles/1/0/0/0.tsb") && err.contains("a blob is at most"), "{err}");
}

/// N9: `pack` gives the archive the mode a bake gives its files (0666 less the umask), not a
/// temporary file's 0600.
#[test]
fn pack_writes_archives_with_the_umask_mode() {
    use std::os::unix::fs::PermissionsExt;
    let tmp = tempfile::tempdir().unwrap();
    let ts = baked(tmp.path(), "ts");
    for (umask, mode) in [("022", 0o644), ("027", 0o640)] {
        let out = tmp.path().join(format!("ts-{umask}.tsa"));
        let mut c = Command::new("sh");
        c.arg("-c")
            .arg(format!("umask {umask} && exec \"$0\" pack \"$1\" --out \"$2\" -q"))
            .arg(env!("CARGO_BIN_EXE_terrastream"))
            .arg(&ts)
            .arg(&out)
            .stdin(Stdio::null());
        ok(&mut c);
        let got = std::fs::metadata(&out).unwrap().permissions().mode() & 0o777;
        assert_eq!(got, mode, "umask {umask}: {got:o}");
    }
}

/// N10's sibling: a loaded tileset whose directory cannot be read now (here replaced by a file)
/// stays listed and is logged once, not at every poll; once readable again, that is logged.
#[test]
fn an_unreadable_tileset_is_logged_once_per_change() {
    let tmp = tempfile::tempdir().unwrap();
    let store = tmp.path().join("store");
    baked(&store, "u");
    let srv = Server::start(&store, tmp.path().join("serve.log"), Duration::from_secs(20));
    assert_eq!(srv.status("/tilesets/u/tileset.json"), 200);
    std::fs::rename(store.join("u"), tmp.path().join("u-away")).unwrap();
    std::fs::write(store.join("u"), b"not a folder").unwrap();
    std::thread::sleep(Duration::from_millis(1500));
    assert_eq!(srv.status("/tilesets/u/tileset.json"), 200);
    let log = srv.log();
    let n = log.lines().filter(|l| l.contains("tileset cannot be read")).count();
    assert_eq!(n, 1, "logged {n} times in ~15 polls:\n{log}");
    std::fs::remove_file(store.join("u")).unwrap();
    std::fs::rename(tmp.path().join("u-away"), store.join("u")).unwrap();
    let t0 = Instant::now();
    while !srv.log().contains("tileset readable again") {
        assert!(t0.elapsed() < Duration::from_secs(20), "{}", srv.log());
        std::thread::sleep(Duration::from_millis(50));
    }
    assert_eq!(srv.status("/tilesets/u/tileset.json"), 200);
}
