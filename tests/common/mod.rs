//! Helpers shared by the integration tests: the binary runner (with a time limit, so a hang is
//! a failure rather than a stuck run), the GPU-or-skip rule, the shared test data and tileset
//! tree comparison.

// Each test binary uses what it needs of this module; a failed unwrap is the test failing.
#![allow(dead_code, clippy::unwrap_used, clippy::panic)]

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::process::{Command, Output, Stdio};
use std::time::{Duration, Instant};

/// The `terrastream` binary of this build, with stdin closed.
pub fn bin() -> Command {
    let mut c = Command::new(env!("CARGO_BIN_EXE_terrastream"));
    c.stdin(Stdio::null());
    c
}

/// Runs `cmd`, killing it after `limit` (a hang is a failure, not a stuck test run).
pub fn run_within(cmd: &mut Command, limit: Duration) -> Output {
    let mut child = cmd.stdout(Stdio::piped()).stderr(Stdio::piped()).spawn().unwrap();
    let t0 = Instant::now();
    while child.try_wait().unwrap().is_none() {
        if t0.elapsed() > limit {
            child.kill().unwrap();
            let out = child.wait_with_output().unwrap();
            panic!("{cmd:?} still running after {limit:?}\n{}", String::from_utf8_lossy(&out.stderr));
        }
        std::thread::sleep(Duration::from_millis(20));
    }
    child.wait_with_output().unwrap()
}

/// Runs `cmd` (at most 5 minutes), asserts it succeeded and returns its stdout.
pub fn ok(cmd: &mut Command) -> String {
    let out = run_within(cmd, Duration::from_mins(5));
    assert!(out.status.success(), "{cmd:?} failed\n{}", String::from_utf8_lossy(&out.stderr));
    String::from_utf8_lossy(&out.stdout).into_owned()
}

/// Runs `cmd` (at most a minute), asserts it failed and returns its stderr.
pub fn fails(cmd: &mut Command) -> String {
    let out = run_within(cmd, Duration::from_mins(1));
    assert!(!out.status.success(), "{cmd:?} should fail");
    String::from_utf8_lossy(&out.stderr).into_owned()
}

/// GPU tests skip with a printed reason when no adapter is found, unless
/// `TERRASTREAM_REQUIRE_GPU=1` (CI sets it, with Mesa's lavapipe installed): then they fail.
pub fn require_gpu() -> bool {
    std::env::var("TERRASTREAM_REQUIRE_GPU").is_ok_and(|v| v == "1")
}

/// An adapter for a GPU test, or `None` after printing why `what` is skipped; panics instead
/// under `TERRASTREAM_REQUIRE_GPU=1` (see [`require_gpu`]).
#[cfg(feature = "gpu")]
pub fn gpu_or_skip(what: &str) -> Option<terrastream::gpu::GpuContext> {
    match terrastream::gpu::open() {
        Ok(ctx) => Some(ctx),
        Err(e) if require_gpu() => panic!("TERRASTREAM_REQUIRE_GPU=1 but no adapter: {e}"),
        Err(e) => {
            eprintln!("skipping {what}: {e} (set TERRASTREAM_REQUIRE_GPU=1 to fail instead)");
            None
        }
    }
}

/// A file of the shared test data (`$TERRASTREAM_DATA`, default `../shared/data`).
pub fn data(name: &str) -> PathBuf {
    terrastream::raster::test_data_dir().join(name)
}

/// Every file under `dir` (hidden ones included) with its bytes, by relative path.
pub fn tree(dir: &Path) -> BTreeMap<String, Vec<u8>> {
    fn walk(root: &Path, dir: &Path, out: &mut BTreeMap<String, Vec<u8>>) {
        for e in std::fs::read_dir(dir).unwrap() {
            let p = e.unwrap().path();
            if p.is_dir() {
                walk(root, &p, out);
            } else {
                out.insert(p.strip_prefix(root).unwrap().display().to_string(), std::fs::read(&p).unwrap());
            }
        }
    }
    let mut out = BTreeMap::new();
    walk(dir, dir, &mut out);
    out
}

/// The blobs and index of a tileset: [`tree`] without the files that name the sources (the
/// manifest), for comparing bakes of the same heights from different inputs.
pub fn blobs_and_index(dir: &Path) -> BTreeMap<String, Vec<u8>> {
    tree(dir).into_iter().filter(|(k, _)| k.starts_with("tiles/") || k.starts_with("index/")).collect()
}

/// Asserts that every node of the tileset in `dir` stores only levels that pay: level 0 always,
/// each further level with fewer primitives *and* fewer bytes than every finer level the node
/// stores; the index's figures match the blobs; and every level of the ladder a node does not
/// store has its `unpaid` marker and no blob. Returns (nodes, levels stored, levels left out).
pub fn assert_levels_pay(dir: &Path) -> (usize, usize, usize) {
    use terrastream::store::{Store, TilesetKind};
    let store = Store::new(dir);
    let m = store.manifest().unwrap();
    let nodes = if store.manifest_kind().unwrap() == TilesetKind::Model {
        vec![store.node(terrastream::tiling::TileKey::new(0, 0, 0)).unwrap().unwrap()]
    } else {
        let pyramid =
            terrastream::tiling::Pyramid::new(m.source.width, m.source.height, m.tile_size).unwrap();
        let all = store.all_nodes(&pyramid).unwrap();
        assert_eq!(all.len(), pyramid.nodes().len(), "{}: index misses nodes", dir.display());
        all
    };
    let (mut stored, mut left_out) = (0, 0);
    for n in &nodes {
        assert_eq!(n.levels.first().map(|l| l.level), Some(0), "{}: no mesh", n.key);
        for (i, l) in n.levels.iter().enumerate() {
            let bytes = store
                .read_blob(n.key, l.level)
                .unwrap()
                .unwrap_or_else(|| panic!("{} level {}: listed in the index, no blob", n.key, l.level));
            let h = terrastream::codec::decode(&bytes).unwrap().header;
            assert_eq!(
                (h.level, h.vertex_count, bytes.len() as u64),
                (l.level, l.count, l.bytes),
                "{}",
                n.key
            );
            for finer in &n.levels[..i] {
                assert!(
                    l.count < finer.count && l.bytes < finer.bytes,
                    "{} level {} ({} primitives, {} B) does not pay against level {} ({} primitives, {} B)",
                    n.key,
                    l.level,
                    l.count,
                    l.bytes,
                    finer.level,
                    finer.count,
                    finer.bytes
                );
            }
            stored += 1;
        }
        for spec in &m.levels {
            if n.level(spec.level).is_none() {
                assert!(
                    store.is_unpaid(n.key, spec.level).unwrap(),
                    "{} level {}: neither blob nor marker",
                    n.key,
                    spec.level
                );
                assert!(store.read_blob(n.key, spec.level).unwrap().is_none());
                left_out += 1;
            }
        }
    }
    (nodes.len(), stored, left_out)
}
