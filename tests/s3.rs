//! Tilesets in object storage, against a real S3-compatible server on 127.0.0.1 (moto's server,
//! which `.ci/run` starts; `AWS_ENDPOINT_URL` and credentials name it as for the binary, and
//! `TERRASTREAM_TEST_S3_BUCKET` an existing bucket). Without it the tests skip with a printed reason, unless
//! `TERRASTREAM_REQUIRE_S3=1` (CI), which makes them fail.
//!
//! A bake into a bucket writes the same objects with the same bytes as a bake into a directory;
//! it resumes after a kill; a sharded bake (4 and 16 shards, parallel, shuffled) gives the same
//! objects; a bucket that answers errors is retried with backoff, one that keeps failing or
//! stalls ends the bake with an error naming the object and nothing published (no manifest), and
//! the bake resumes once the bucket is back.

#![allow(clippy::unwrap_used, clippy::panic)]

mod common;

use std::collections::BTreeMap;
use std::io::{BufRead, BufReader, Read, Write};
use std::net::{TcpListener, TcpStream};
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::sync::Arc;
use std::sync::atomic::{AtomicU64, Ordering};
use std::time::{Duration, Instant};

use common::{bin, ok, run_within, tree};

/// The endpoint and credentials come from the environment (`AWS_ENDPOINT_URL`,
/// `AWS_ACCESS_KEY_ID`, …), where the library reads them too.
fn s3(what: &str) -> Option<(String, String)> {
    let bucket = std::env::var("TERRASTREAM_TEST_S3_BUCKET").ok();
    let endpoint = std::env::var("AWS_ENDPOINT_URL").ok();
    match (endpoint, bucket) {
        (Some(e), Some(b)) => Some((e, b)),
        _ if std::env::var("TERRASTREAM_REQUIRE_S3").is_ok_and(|v| v == "1") => {
            panic!("TERRASTREAM_REQUIRE_S3=1 but AWS_ENDPOINT_URL or TERRASTREAM_TEST_S3_BUCKET is not set")
        }
        _ => {
            eprintln!(
                "skipping {what}: no S3 server (set AWS_ENDPOINT_URL, its credentials and TERRASTREAM_TEST_S3_BUCKET, as .ci/run does with moto's server)"
            );
            None
        }
    }
}

/// A prefix no other test (or earlier run) uses.
fn prefix(bucket: &str, name: &str) -> String {
    let nanos = std::time::SystemTime::now().duration_since(std::time::UNIX_EPOCH).unwrap().as_nanos();
    format!("s3://{bucket}/{name}-{}-{nanos}", std::process::id())
}

/// `terrastream` with `endpoint` in place of the environment's (the fault proxy's).
fn tbin(endpoint: &str) -> Command {
    let mut c = bin();
    c.env("AWS_ENDPOINT_URL", endpoint).env_remove("AWS_ENDPOINT_URL_S3");
    c
}

/// Every object under `url` with its bytes, by path relative to it (read through the library,
/// configured by the environment).
fn objects(_endpoint: &str, url: &str) -> BTreeMap<String, Vec<u8>> {
    let store = terrastream::store::Store::at(Path::new(url)).unwrap();
    let r = store.bucket().unwrap();
    r.list("").unwrap().into_iter().map(|(k, _)| (k.clone(), r.get(&k).unwrap().unwrap())).collect()
}

fn synth(dir: &Path) -> PathBuf {
    let tif = dir.join("t.tif");
    ok(bin().args(["synth", "--width", "385", "--height", "321", "--seed", "5", "--out"]).arg(&tif));
    tif
}

const BAKE: [&str; 6] = ["--tile-size", "32", "--levels", "3", "--max-error", "0.5"];

fn local_bake(dir: &Path, tif: &Path) -> BTreeMap<String, Vec<u8>> {
    let out = dir.join("local");
    ok(bin().arg("bake").arg(tif).arg("--out").arg(&out).args(BAKE).args(["-q", "--gpu", "off"]));
    tree(&out)
}

fn assert_same(local: &BTreeMap<String, Vec<u8>>, remote: &BTreeMap<String, Vec<u8>>, what: &str) {
    let names = |t: &BTreeMap<String, Vec<u8>>| t.keys().cloned().collect::<Vec<_>>();
    assert_eq!(names(local), names(remote), "{what}: other objects than the directory's files");
    for (k, v) in local {
        assert!(remote[k] == *v, "{what}: {k} differs");
    }
}

/// A bake into a bucket: the directory bake's files as objects, byte for byte; `inspect` reads
/// it; a bake killed midway leaves no manifest and resumes to the same objects.
#[test]
fn bake_into_a_bucket_equals_a_directory_and_resumes() {
    let Some((endpoint, bucket)) = s3("bake_into_a_bucket") else { return };
    let dir = tempfile::tempdir().unwrap();
    let tif = synth(dir.path());
    let local = local_bake(dir.path(), &tif);

    let url = prefix(&bucket, "bake");
    ok(tbin(&endpoint).arg("bake").arg(&tif).arg("--out").arg(&url).args(BAKE).args(["-q", "--gpu", "off"]));
    assert_same(&local, &objects(&endpoint, &url), "bake into a bucket");
    let said = ok(tbin(&endpoint).arg("inspect").arg(&url));
    assert!(said.contains(&format!("{url}: t.tif")), "{said}");

    // Killed midway: no manifest; run again: resumed, the same objects.
    let url = prefix(&bucket, "killed");
    let mut c = tbin(&endpoint)
        .arg("bake")
        .arg(&tif)
        .arg("--out")
        .arg(&url)
        .args(BAKE)
        .args(["-q", "--gpu", "off", "--threads", "1"])
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .spawn()
        .unwrap();
    let t0 = Instant::now();
    // Wait for some blobs, then kill.
    while objects(&endpoint, &url).keys().filter(|k| k.rsplit('.').next() == Some("tsb")).count() < 20
        && t0.elapsed() < Duration::from_mins(1)
    {
        std::thread::sleep(Duration::from_millis(20));
    }
    c.kill().unwrap();
    c.wait().unwrap();
    let partial = objects(&endpoint, &url);
    assert!(!partial.contains_key("tileset.json"), "a killed bake published its manifest");
    let said =
        ok(tbin(&endpoint).arg("bake").arg(&tif).arg("--out").arg(&url).args(BAKE).args(["--gpu", "off"]));
    assert!(said.contains(" resumed)") && !said.contains("(0 resumed)"), "{said}");
    assert_same(&local, &objects(&endpoint, &url), "resumed bake into a bucket");
}

/// Sharded bakes into a bucket (4 and 16 shards, all at once, started in a shuffled order): the
/// one-machine directory bake's files as objects.
#[test]
fn sharded_bakes_into_a_bucket_equal_a_directory() {
    let Some((endpoint, bucket)) = s3("sharded_bakes_into_a_bucket") else { return };
    let dir = tempfile::tempdir().unwrap();
    let tif = synth(dir.path());
    let local = local_bake(dir.path(), &tif);
    for (n, order) in
        [(4u32, vec![2u32, 0, 3, 1]), (16, vec![5, 12, 0, 9, 15, 3, 7, 1, 14, 10, 2, 8, 13, 4, 11, 6])]
    {
        let url = prefix(&bucket, &format!("shards{n}"));
        ok(tbin(&endpoint).arg("plan").arg(&tif).arg("--out").arg(&url).args(BAKE).args([
            "--shards",
            &n.to_string(),
            "-q",
        ]));
        let children: Vec<_> = order
            .iter()
            .map(|&i| {
                let c = common::shard_step(tbin(&endpoint), &url, i)
                    .stdout(Stdio::null())
                    .stderr(Stdio::piped())
                    .spawn()
                    .unwrap();
                (i, c)
            })
            .collect();
        for (i, c) in children {
            let o = c.wait_with_output().unwrap();
            assert!(o.status.success(), "shard {i}: {}", String::from_utf8_lossy(&o.stderr));
        }
        ok(tbin(&endpoint).args(["bake", "--plan", &url, "--finish", "-q", "--gpu", "off"]));
        assert_same(&local, &objects(&endpoint, &url), &format!("{n} shards into a bucket"));
    }
}

/// How the fault proxy answers.
#[derive(Clone, Copy)]
enum Fault {
    /// Every `k`-th request gets a 503 (a retry succeeds).
    EveryKth(u64),
    /// After `n` requests, every request gets a 500.
    DownAfter(u64),
    /// After `n` requests, requests are read and never answered.
    StallAfter(u64),
}

/// A proxy on 127.0.0.1 in front of the S3 server that injects `fault`: one request per
/// connection (it answers `Connection: close`). Returns its endpoint and its request counter.
fn fault_proxy(upstream: &str, fault: Fault) -> (String, Arc<AtomicU64>) {
    let listener = TcpListener::bind("127.0.0.1:0").unwrap();
    let addr = listener.local_addr().unwrap();
    let upstream = upstream.trim_start_matches("http://").trim_end_matches('/').to_owned();
    let count = Arc::new(AtomicU64::new(0));
    let counter = count.clone();
    std::thread::spawn(move || {
        for conn in listener.incoming() {
            let Ok(conn) = conn else { continue };
            let upstream = upstream.clone();
            let n = counter.fetch_add(1, Ordering::SeqCst) + 1;
            std::thread::spawn(move || {
                let _ = serve_one(conn, &upstream, fault, n);
            });
        }
    });
    (format!("http://{addr}"), count)
}

fn serve_one(conn: TcpStream, upstream: &str, fault: Fault, n: u64) -> std::io::Result<()> {
    conn.set_read_timeout(Some(Duration::from_secs(30)))?;
    let mut reader = BufReader::new(conn.try_clone()?);
    let mut head = Vec::new();
    let mut length = 0usize;
    loop {
        let mut line = String::new();
        if reader.read_line(&mut line)? == 0 {
            return Ok(());
        }
        if let Some(v) = line.to_ascii_lowercase().strip_prefix("content-length:") {
            length = v.trim().parse().unwrap_or(0);
        }
        if line.to_ascii_lowercase().starts_with("connection:") {
            continue;
        }
        if line == "\r\n" {
            head.extend_from_slice(b"Connection: close\r\n\r\n");
            break;
        }
        head.extend_from_slice(line.as_bytes());
    }
    let mut body = vec![0u8; length];
    reader.read_exact(&mut body)?;
    let mut out = conn;
    let fail = |out: &mut TcpStream, status: &str| {
        let msg = format!("HTTP/1.1 {status}\r\nContent-Length: 0\r\nConnection: close\r\n\r\n");
        out.write_all(msg.as_bytes())
    };
    match fault {
        Fault::EveryKth(k) if n.is_multiple_of(k) => return fail(&mut out, "503 Service Unavailable"),
        Fault::DownAfter(after) if n > after => return fail(&mut out, "500 Internal Server Error"),
        Fault::StallAfter(after) if n > after => {
            std::thread::sleep(Duration::from_mins(10));
            return Ok(());
        }
        _ => {}
    }
    let mut up = TcpStream::connect(upstream)?;
    up.write_all(&head)?;
    up.write_all(&body)?;
    let mut response = Vec::new();
    up.read_to_end(&mut response)?;
    out.write_all(&response)
}

/// A bucket that answers 503 to every fifth request: the bake retries (with backoff) and
/// writes the same objects. One that goes down (500s) or stalls midway: the bake ends with an
/// error naming the object, within its retry and timeout bounds, with no manifest; run again
/// against the healthy bucket it resumes to the same objects.
#[test]
fn a_failing_or_stalling_bucket_is_retried_then_refused_and_nothing_is_published() {
    let Some((endpoint, bucket)) = s3("a_failing_bucket") else { return };
    let dir = tempfile::tempdir().unwrap();
    let tif = synth(dir.path());
    let local = local_bake(dir.path(), &tif);

    let (flaky, count) = fault_proxy(&endpoint, Fault::EveryKth(5));
    let url = prefix(&bucket, "flaky");
    ok(tbin(&flaky).arg("bake").arg(&tif).arg("--out").arg(&url).args(BAKE).args(["-q", "--gpu", "off"]));
    assert!(count.load(Ordering::SeqCst) > 100, "the proxy saw too few requests");
    assert_same(&local, &objects(&endpoint, &url), "bake through 503s");

    for (what, fault) in [("down", Fault::DownAfter(60)), ("stalled", Fault::StallAfter(60))] {
        let (bad, _) = fault_proxy(&endpoint, fault);
        let url = prefix(&bucket, what);
        let t0 = Instant::now();
        let o = run_within(
            tbin(&bad)
                .arg("bake")
                .arg(&tif)
                .arg("--out")
                .arg(&url)
                .args(BAKE)
                .args(["-q", "--gpu", "off"])
                .env("TERRASTREAM_S3_RETRIES", "2")
                .env("TERRASTREAM_S3_TIMEOUT_S", "1"),
            Duration::from_mins(2),
        );
        let err = String::from_utf8_lossy(&o.stderr);
        assert!(!o.status.success(), "{what}: the bake succeeded");
        assert!(err.contains(&format!("{url}/")), "{what}: the error does not name the object: {err}");
        assert!(
            err.contains("retries") || err.contains("timed out") || err.contains("timeout"),
            "{what}: {err}"
        );
        eprintln!("{what}: failed after {:.1} s: {}", t0.elapsed().as_secs_f64(), err.trim());
        let partial = objects(&endpoint, &url);
        assert!(!partial.contains_key("tileset.json"), "{what}: a failed bake published its manifest");
        ok(tbin(&endpoint)
            .arg("bake")
            .arg(&tif)
            .arg("--out")
            .arg(&url)
            .args(BAKE)
            .args(["-q", "--gpu", "off"]));
        assert_same(&local, &objects(&endpoint, &url), &format!("resumed after the bucket was {what}"));
    }
}

/// `serve` from a bucket — a tileset folder and a packed archive — answers every resource with
/// the same status, bytes and headers as from a directory; a tileset uploaded while serving is
/// picked up by polling; a bucket that stalls makes blob reads `503` with `Retry-After` within
/// the request timeout and retries, not a hang.
#[test]
fn serving_from_a_bucket_equals_a_directory_and_picks_up_new_tilesets() {
    let Some((endpoint, bucket)) = s3("serving_from_a_bucket") else { return };
    let dir = tempfile::tempdir().unwrap();
    let tif = synth(dir.path());
    let local_root = dir.path().join("store");
    ok(bin()
        .arg("bake")
        .arg(&tif)
        .arg("--out")
        .arg(local_root.join("ts"))
        .args(BAKE)
        .args(["-q", "--gpu", "off"]));
    let folder_root = prefix(&bucket, "serve-folder");
    let archive_root = prefix(&bucket, "serve-archive");
    ok(tbin(&endpoint)
        .arg("bake")
        .arg(&tif)
        .arg("--out")
        .arg(format!("{folder_root}/ts"))
        .args(BAKE)
        .args(["-q", "--gpu", "off"]));
    ok(tbin(&endpoint)
        .arg("pack")
        .arg(local_root.join("ts"))
        .arg("--out")
        .arg(format!("{archive_root}/ts.tsa"))
        .arg("-q"));

    let serve_at = |store: &str, ep: &str| {
        let mut c = tbin(ep);
        c.args(["serve", "--poll-ms", "200", "--store", store]);
        common::serve(c)
    };
    let local = serve_at(local_root.to_str().unwrap(), &endpoint);
    let folder = serve_at(&folder_root, &endpoint);
    let archive = serve_at(&archive_root, &endpoint);
    let files = common::tree(&local_root.join("ts"));
    let mut urls = common::tileset_urls("ts", files.keys());
    // Heights on the stored TINs (issue 38): the same numbers from a folder, a bucket and an
    // archive. Points across the raster in its world frame (the synthetic raster has no CRS).
    let m: serde_json::Value =
        serde_json::from_slice(&std::fs::read(local_root.join("ts/tileset.json")).unwrap()).unwrap();
    let f = &m["frame"];
    let (x0, y0, dx, dy) = (
        f["x0"].as_f64().unwrap(),
        f["y0"].as_f64().unwrap(),
        f["dx"].as_f64().unwrap(),
        f["dy"].as_f64().unwrap(),
    );
    let pts: Vec<String> = (0..60)
        .map(|k| {
            let (c, r) = (f64::from(k) * 6.37 % 384.0, f64::from(k) * 5.11 % 320.0);
            format!("{},{}", x0 + c * dx, y0 + r * dy)
        })
        .collect();
    urls.push(format!("/tilesets/ts/heights?coords=local&datum=native&points={}", pts.join(";")));
    urls.push(format!("/tilesets/ts/heights?coords=local&datum=native&depth=1&points={}", pts.join(";")));
    common::assert_same_responses(
        &[("directory", local.addr), ("bucket folder", folder.addr), ("bucket archive", archive.addr)],
        &urls,
    );

    // A tileset uploaded while serving appears within a few polls.
    ok(tbin(&endpoint)
        .arg("pack")
        .arg(local_root.join("ts"))
        .arg("--out")
        .arg(format!("{folder_root}/late.tsa"))
        .arg("-q"));
    let t0 = Instant::now();
    while common::http_get(folder.addr, "/tilesets/late/tileset.json").unwrap().0 != 200 {
        assert!(t0.elapsed() < Duration::from_secs(20), "the uploaded archive was not picked up");
        std::thread::sleep(Duration::from_millis(100));
    }

    // The same bucket behind a proxy that stops answering after the server's first scans.
    let (stalling, count) = fault_proxy(&endpoint, Fault::StallAfter(1_000_000));
    let mut c = tbin(&stalling);
    c.args(["serve", "--poll-ms", "60000", "--store", &folder_root])
        .env("TERRASTREAM_S3_RETRIES", "1")
        .env("TERRASTREAM_S3_TIMEOUT_S", "1");
    let srv = common::serve(c);
    count.store(2_000_000, Ordering::SeqCst);
    let blob = urls.iter().find(|u| u.contains("/tiles/") && !u.contains("3dtiles")).unwrap();
    let t0 = Instant::now();
    let (status, headers, body) = common::http_get(srv.addr, blob).unwrap();
    assert_eq!(status, 503, "{}", String::from_utf8_lossy(&body));
    assert!(headers.iter().any(|(k, _)| k == "retry-after"), "{headers:?}");
    assert!(t0.elapsed() < Duration::from_secs(15), "took {:?}", t0.elapsed());
}
