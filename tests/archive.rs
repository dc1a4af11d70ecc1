//! Single-file archives (`terrastream pack`): a packed tileset reads and serves byte-identical
//! to its directory; the archive is refused with a clear error when the tileset is unfinished,
//! the name is wrong or the file is damaged; `inspect` and `export` read archives.

#![allow(clippy::unwrap_used, clippy::panic)]

mod common;

use std::path::Path;

use common::{assert_same_responses, bin, fails, ok, serve_store, tileset_urls, tree};

const BAKE: [&str; 6] = ["--tile-size", "32", "--levels", "3", "--max-error", "0.5"];

fn baked(dir: &Path) -> std::path::PathBuf {
    let tif = dir.join("t.tif");
    ok(bin().args(["synth", "--width", "257", "--height", "225", "--seed", "9", "--out"]).arg(&tif));
    let out = dir.join("dirs/ts");
    ok(bin().arg("bake").arg(&tif).arg("--out").arg(&out).args(BAKE).args(["-q", "--gpu", "off"]));
    out
}

#[test]
fn a_packed_tileset_serves_byte_identical_to_its_directory() {
    let tmp = tempfile::tempdir().unwrap();
    let ts = baked(tmp.path());
    let packed = tmp.path().join("packed");
    std::fs::create_dir_all(&packed).unwrap();
    let out = ok(bin().arg("pack").arg(&ts).arg("--out").arg(packed.join("ts.tsa")).arg("-q"));
    assert!(out.contains("packed"), "{out}");
    // Nothing but the archive is left in its folder (no temporary file).
    let names: Vec<_> = std::fs::read_dir(&packed).unwrap().map(|e| e.unwrap().file_name()).collect();
    assert_eq!(names, vec![std::ffi::OsString::from("ts.tsa")]);

    // The command-line readers see the same tileset.
    let a = ok(bin().arg("inspect").arg(packed.join("ts.tsa")));
    let d = ok(bin().arg("inspect").arg(&ts));
    assert_eq!(a.lines().skip(1).collect::<Vec<_>>(), d.lines().skip(1).collect::<Vec<_>>());
    let (ply_a, ply_d) = (tmp.path().join("a.ply"), tmp.path().join("d.ply"));
    ok(bin()
        .arg("export")
        .arg(packed.join("ts.tsa"))
        .args(["--tile", "1/0/0", "--level", "1", "--out"])
        .arg(&ply_a));
    ok(bin().arg("export").arg(&ts).args(["--tile", "1/0/0", "--level", "1", "--out"]).arg(&ply_d));
    assert_eq!(std::fs::read(ply_a).unwrap(), std::fs::read(ply_d).unwrap());

    let files = tree(&ts);
    let urls = tileset_urls("ts", files.keys());
    assert!(urls.len() > 100, "{}", urls.len());
    let dir_srv = serve_store(ts.parent().unwrap(), &[]);
    let tsa_srv = serve_store(&packed, &[]);
    assert_same_responses(&[("directory", dir_srv.addr), ("archive", tsa_srv.addr)], &urls);
}

#[test]
fn pack_refuses_unfinished_tilesets_bad_names_and_reads_refuse_damaged_archives() {
    let tmp = tempfile::tempdir().unwrap();
    let ts = baked(tmp.path());
    let err = fails(bin().arg("pack").arg(&ts).arg("--out").arg(tmp.path().join("x.zip")));
    assert!(err.contains(".tsa"), "{err}");
    assert!(!tmp.path().join("x.zip").exists());

    let good = tmp.path().join("good.tsa");
    ok(bin().arg("pack").arg(&ts).arg("--out").arg(&good).arg("-q"));
    let bytes = std::fs::read(&good).unwrap();

    // Unfinished: no manifest.
    let unfinished = tmp.path().join("unfinished");
    std::fs::create_dir_all(&unfinished).unwrap();
    for (rel, b) in tree(&ts) {
        if rel != "tileset.json" {
            let p = unfinished.join(&rel);
            std::fs::create_dir_all(p.parent().unwrap()).unwrap();
            std::fs::write(p, b).unwrap();
        }
    }
    let err = fails(bin().arg("pack").arg(&unfinished).arg("--out").arg(tmp.path().join("u.tsa")));
    assert!(err.contains("no manifest") && err.contains("tileset.json"), "{err}");
    assert!(!tmp.path().join("u.tsa").exists());

    // Damaged: cut short, footer flipped, a blob's byte flipped (caught by its CRC on read).
    let cases: Vec<(&str, Vec<u8>)> = vec![
        ("cut", bytes[..bytes.len() - 10].to_vec()),
        ("footer", {
            let mut b = bytes.clone();
            let n = b.len();
            b[n - 30] ^= 0x40;
            b
        }),
        ("empty", Vec::new()),
    ];
    for (what, b) in cases {
        let p = tmp.path().join(format!("{what}.tsa"));
        std::fs::write(&p, b).unwrap();
        let err = fails(bin().arg("inspect").arg(&p));
        assert!(err.contains(&p.display().to_string()) && err.contains("archive"), "{what}: {err}");
    }
    // A flipped byte inside the data: the file holding it is refused when read, naming it.
    let mut b = bytes.clone();
    let mid = b.len() / 2;
    b[mid] ^= 0x01;
    let p = tmp.path().join("data.tsa");
    std::fs::write(&p, b).unwrap();
    let out = bin()
        .arg("export")
        .arg(&p)
        .args(["--format", "3dtiles", "-q", "--out"])
        .arg(tmp.path().join("x3"))
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success() && err.contains("checksum"), "{err}");

    // An archive is read-only.
    let err = fails(
        bin()
            .arg("bake")
            .arg(tmp.path().join("t.tif"))
            .arg("--out")
            .arg(&good)
            .args(BAKE)
            .args(["-q", "--gpu", "off"]),
    );
    assert!(err.contains("read-only"), "{err}");
}

/// A plain static web server for one file, as nginx or a CDN answers: `HEAD` and `GET` of
/// `path` (anything else `404`), a single `Range: bytes=A-B | A- | -N` answered `206` (with
/// `ranges` false the header is ignored and the whole file sent, `200`). One request per
/// connection. Counts the requests and the body bytes sent, and the GETs of the whole file.
struct StaticHost {
    addr: std::net::SocketAddr,
    requests: std::sync::Arc<std::sync::atomic::AtomicU64>,
    sent: std::sync::Arc<std::sync::atomic::AtomicU64>,
    whole: std::sync::Arc<std::sync::atomic::AtomicU64>,
}

fn static_host(file: std::path::PathBuf, path: &'static str, ranges: bool) -> StaticHost {
    use std::io::{BufRead, BufReader, Write};
    use std::sync::Arc;
    use std::sync::atomic::{AtomicU64, Ordering};
    let listener = std::net::TcpListener::bind("127.0.0.1:0").unwrap();
    let addr = listener.local_addr().unwrap();
    let (requests, sent, whole) =
        (Arc::new(AtomicU64::new(0)), Arc::new(AtomicU64::new(0)), Arc::new(AtomicU64::new(0)));
    let (r, s, w) = (requests.clone(), sent.clone(), whole.clone());
    std::thread::spawn(move || {
        let body = std::fs::read(&file).unwrap();
        let n = body.len() as u64;
        for conn in listener.incoming() {
            let Ok(mut conn) = conn else { continue };
            let mut reader = BufReader::new(conn.try_clone().unwrap());
            let mut head = Vec::new();
            for _ in 0..64 {
                let mut line = String::new();
                if reader.read_line(&mut line).unwrap_or(0) == 0 || line == "\r\n" {
                    break;
                }
                head.push(line.trim_end().to_owned());
            }
            r.fetch_add(1, Ordering::Relaxed);
            let first: Vec<&str> = head.first().map(|l| l.split(' ').collect()).unwrap_or_default();
            let (method, target) =
                (first.first().copied().unwrap_or(""), first.get(1).copied().unwrap_or(""));
            if target != path || !matches!(method, "GET" | "HEAD") {
                let _ = conn
                    .write_all(b"HTTP/1.1 404 Not Found\r\ncontent-length: 0\r\nconnection: close\r\n\r\n");
                continue;
            }
            let range = head
                .iter()
                .find_map(|l| l.to_ascii_lowercase().strip_prefix("range: bytes=").map(str::to_owned))
                .filter(|_| ranges)
                .and_then(|spec| {
                    let (a, b) = spec.split_once('-')?;
                    let (start, end) = match (a.parse::<u64>().ok(), b.parse::<u64>().ok()) {
                        (Some(a), Some(b)) => (a, b.min(n - 1)),
                        (Some(a), None) => (a, n - 1),
                        (None, Some(k)) => (n.saturating_sub(k), n - 1),
                        (None, None) => return None,
                    };
                    (start <= end && end < n).then_some((start, end))
                });
            let (status, lo, hi) = match range {
                Some((a, b)) => ("206 Partial Content", a, b + 1),
                None => ("200 OK", 0, n),
            };
            let content_range = if range.is_some() {
                format!("content-range: bytes {lo}-{}/{n}\r\n", hi - 1)
            } else {
                String::new()
            };
            let reply = format!(
                "HTTP/1.1 {status}\r\ncontent-length: {}\r\naccept-ranges: {}\r\nconnection: close\r\n{content_range}\r\n",
                hi - lo,
                if ranges { "bytes" } else { "none" }
            );
            let mut out = reply.into_bytes();
            if method == "GET" {
                if range.is_none() {
                    w.fetch_add(1, Ordering::Relaxed);
                }
                out.extend_from_slice(&body[lo as usize..hi as usize]);
                s.fetch_add(hi - lo, Ordering::Relaxed);
            }
            let _ = conn.write_all(&out);
        }
    });
    StaticHost { addr, requests, sent, whole }
}

/// An archive on a plain static host (no terrastream server; any host that answers range
/// requests) is read by ranges: `inspect` and the whole 3D Tiles export from its URL equal the
/// directory's, every blob verified, without ever fetching the whole file. A host that ignores
/// ranges, and a URL that names a folder, are refused with a clear error.
#[test]
fn an_archive_on_a_static_host_is_read_by_ranges() {
    use std::sync::atomic::Ordering;
    let tmp = tempfile::tempdir().unwrap();
    let ts = baked(tmp.path());
    let tsa = tmp.path().join("ts.tsa");
    ok(bin().arg("pack").arg(&ts).arg("--out").arg(&tsa).arg("-q"));
    let size = std::fs::metadata(&tsa).unwrap().len();
    let host = static_host(tsa.clone(), "/cdn/terrain/ts.tsa", true);
    let url = format!("http://{}/cdn/terrain/ts.tsa", host.addr);

    let a = ok(bin().arg("inspect").arg(&url));
    let d = ok(bin().arg("inspect").arg(&ts));
    assert_eq!(a.lines().skip(1).collect::<Vec<_>>(), d.lines().skip(1).collect::<Vec<_>>());
    let (from_url, from_dir) = (tmp.path().join("3dt-url"), tmp.path().join("3dt-dir"));
    ok(bin().arg("export").arg(&url).args(["--format", "3dtiles", "-q", "--out"]).arg(&from_url));
    ok(bin().arg("export").arg(&ts).args(["--format", "3dtiles", "-q", "--out"]).arg(&from_dir));
    let (u, d) = (tree(&from_url), tree(&from_dir));
    assert!(u.len() > 100, "{}", u.len());
    assert!(u == d, "the 3D Tiles exported from the archive's URL differ from the directory's");
    assert_eq!(host.whole.load(Ordering::Relaxed), 0, "a GET of the whole archive");
    let (requests, sent) = (host.requests.load(Ordering::Relaxed), host.sent.load(Ordering::Relaxed));
    // Two commands, each reading every file it needs once (export: every blob and index chunk).
    assert!(sent <= 3 * size, "{sent} bytes sent for a {size}-byte archive");
    assert!(requests > 100, "{requests} requests");

    // A host that ignores Range: refused, naming the URL and the reason.
    let plain = static_host(tsa, "/ts.tsa", false);
    let plain_url = format!("http://{}/ts.tsa", plain.addr);
    let err = fails(bin().arg("inspect").arg(&plain_url));
    assert!(err.contains(&plain_url) && err.to_lowercase().contains("range"), "{err}");
    // A folder on a web server cannot be listed; an archive cannot be uploaded to one.
    let err = fails(bin().arg("inspect").arg(format!("http://{}/cdn/terrain", host.addr)));
    assert!(err.contains("archive") && err.contains(".tsa"), "{err}");
    let err = fails(bin().arg("pack").arg(&ts).arg("--out").arg(&url));
    assert!(err.contains("no uploads"), "{err}");
}
