//! Sharded bakes (`plan`, `bake --plan … --shard I`, `bake --plan … --finish`): the tileset is
//! byte for byte a one-machine bake's, for 1, 4 and 16 shards run as separate processes in
//! parallel and in a shuffled order, through the local Indexed Job runner, after kills; and each
//! step refuses what it cannot do with a clear error and the exit status the deploy files use.

#![allow(clippy::unwrap_used, clippy::panic)]

mod common;

use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::Duration;

use common::{bin, fails, ok, run_within, shard_step, tree};

fn synth(dir: &Path, seed: u32) -> PathBuf {
    let tif = dir.join(format!("t{seed}.tif"));
    ok(bin()
        .args(["synth", "--width", "513", "--height", "385", "--seed", &seed.to_string(), "--out"])
        .arg(&tif));
    tif
}

const BAKE: [&str; 6] = ["--tile-size", "32", "--levels", "3", "--max-error", "0.5"];

fn one_machine(dir: &Path, tif: &Path) -> PathBuf {
    let out = dir.join("one");
    ok(bin().arg("bake").arg(tif).arg("--out").arg(&out).args(BAKE).args(["-q", "--gpu", "off"]));
    out
}

fn shard(plan: &Path, i: u32) -> Command {
    shard_step(bin(), plan, i)
}

/// A permutation of 0..n from a seed (xorshift), printed so a failure can be replayed.
fn shuffled(n: u32, seed: u64) -> Vec<u32> {
    let mut v: Vec<u32> = (0..n).collect();
    let mut s = seed | 1;
    for i in (1..v.len()).rev() {
        s ^= s << 13;
        s ^= s >> 7;
        s ^= s << 17;
        v.swap(i, (s % (i as u64 + 1)) as usize);
    }
    v
}

fn assert_same_tree(a: &Path, b: &Path) {
    let (ta, tb) = (tree(a), tree(b));
    let names = |t: &std::collections::BTreeMap<String, Vec<u8>>| t.keys().cloned().collect::<Vec<_>>();
    assert_eq!(names(&ta), names(&tb), "{} and {} hold different files", a.display(), b.display());
    for (k, v) in &ta {
        assert!(tb[k] == *v, "{k} differs between {} and {}", a.display(), b.display());
    }
}

/// 1, 4 and 16 shards, all shards at once as separate processes started in a shuffled order,
/// then the final step: the same files with the same bytes as the one-machine bake.
#[test]
fn sharded_bakes_equal_the_one_machine_bake() {
    let dir = tempfile::tempdir().unwrap();
    let tif = synth(dir.path(), 7);
    let one = one_machine(dir.path(), &tif);
    for (n, seed) in [(1u32, 1u64), (4, 2), (16, 3)] {
        let out = dir.path().join(format!("s{n}"));
        let said = ok(bin().arg("plan").arg(&tif).arg("--out").arg(&out).args(BAKE).args([
            "--shards",
            &n.to_string(),
            "-q",
        ]));
        assert!(said.contains(&format!("plan: {n} shards")), "{said}");
        let order = shuffled(n, seed);
        eprintln!("{n} shards, started in the order {order:?}");
        let children: Vec<(u32, Child)> = order
            .iter()
            .map(|&i| (i, shard(&out, i).stdout(Stdio::null()).stderr(Stdio::piped()).spawn().unwrap()))
            .collect();
        for (i, c) in children {
            let o = c.wait_with_output().unwrap();
            assert!(o.status.success(), "shard {i} of {n}: {}", String::from_utf8_lossy(&o.stderr));
        }
        assert!(out.join("shards/plan.json").is_file() && !out.join("tileset.json").exists());
        let said = ok(bin()
            .arg("bake")
            .arg("--plan")
            .arg(out.join("shards/plan.json"))
            .args(["--finish", "-q", "--gpu", "off"]));
        assert!(said.contains(&format!("final step of {n} shards")), "{said}");
        assert_same_tree(&one, &out);
        // Every step is idempotent: run again after the final step, each has nothing to do.
        let again = run_within(&mut shard(&out, 0), Duration::from_mins(1));
        assert!(again.status.success() && String::from_utf8_lossy(&again.stderr).contains("nothing to do"));
        ok(bin().arg("bake").arg("--plan").arg(&out).args(["--finish", "-q"]));
        assert_same_tree(&one, &out);
    }
}

/// The local Indexed Job runner (deploy/run-indexed-job.sh) plays the Job of deploy/: 16
/// indexes two at a time in a shuffled order, one index past the plan failing at once (exit 3,
/// the podFailurePolicy's FailIndex) while the others succeed; then the final step.
#[test]
fn the_indexed_job_runner_bakes_every_shard() {
    let dir = tempfile::tempdir().unwrap();
    let tif = synth(dir.path(), 8);
    let one = one_machine(dir.path(), &tif);
    let out = dir.path().join("job");
    ok(bin().arg("plan").arg(&tif).arg("--out").arg(&out).args(BAKE).args(["--shards", "16", "-q"]));
    let runner = Path::new(env!("CARGO_MANIFEST_DIR")).join("deploy/run-indexed-job.sh");
    let o = run_within(
        Command::new(&runner)
            .args([
                "--completions",
                "17",
                "--parallelism",
                "2",
                "--shuffle",
                "--backoff-limit-per-index",
                "2",
                "--",
            ])
            .arg(env!("CARGO_BIN_EXE_terrastream"))
            .args(["bake", "--plan"])
            .arg(&out)
            .args(["-q", "--gpu", "off", "--threads", "1"]),
        Duration::from_mins(5),
    );
    let said = String::from_utf8_lossy(&o.stdout);
    assert!(!o.status.success(), "{said}");
    assert!(said.contains("indexes: 16 succeeded, 1 failed"), "{said}");
    assert!(
        said.contains("index 16: failed at once (exit 3") && said.contains("shard 16 does not exist"),
        "{said}"
    );
    ok(bin().arg("bake").arg("--plan").arg(&out).args(["--finish", "-q", "--gpu", "off"]));
    assert_same_tree(&one, &out);
}

/// Shards killed mid-bake (SIGKILL, and stopped by --time-limit) and run again alone: the
/// result is still the one-machine bake's, with no temporary file left behind.
#[test]
fn killed_shards_run_again_alone() {
    let dir = tempfile::tempdir().unwrap();
    let tif = synth(dir.path(), 9);
    let one = one_machine(dir.path(), &tif);
    let out = dir.path().join("k");
    ok(bin().arg("plan").arg(&tif).arg("--out").arg(&out).args(BAKE).args(["--shards", "4", "-q"]));
    let stopped = fails(shard(&out, 2).args(["--time-limit", "0.001"]));
    assert!(stopped.contains("--time-limit"), "{stopped}");
    for (i, ms) in [(0u32, 50u64), (1, 120), (3, 250)] {
        let mut c = shard(&out, i).stdout(Stdio::null()).stderr(Stdio::null()).spawn().unwrap();
        std::thread::sleep(Duration::from_millis(ms));
        let _ = c.kill();
        let _ = c.wait();
    }
    // The final step refuses while shards are missing, naming them (exit 1: it can run later).
    let early = run_within(
        bin().arg("bake").arg("--plan").arg(&out).args(["--finish", "-q"]),
        Duration::from_mins(1),
    );
    let err = String::from_utf8_lossy(&early.stderr);
    if !(0..4).all(|i| out.join(format!("shards/shard-{i}.json")).exists()) {
        assert_eq!(early.status.code(), Some(1), "{err}");
        assert!(err.contains("shards have not finished"), "{err}");
    }
    for i in [3u32, 1, 0, 2] {
        ok(&mut shard(&out, i));
    }
    ok(bin().arg("bake").arg("--plan").arg(&out).args(["--finish", "-q", "--gpu", "off"]));
    assert_same_tree(&one, &out);
}

/// What a step cannot do: an index past the plan, an index variable that is not a number,
/// inputs changed since the plan (exit 3, no retry can help); a tileset without a plan; another
/// shard count while shards of the first plan have finished.
#[test]
fn steps_refuse_what_they_cannot_do() {
    let dir = tempfile::tempdir().unwrap();
    let tif = synth(dir.path(), 10);
    let out = dir.path().join("r");
    ok(bin().arg("plan").arg(&tif).arg("--out").arg(&out).args(BAKE).args(["--shards", "4", "-q"]));
    let refused = |c: &mut Command, want: &str| {
        let o = run_within(c, Duration::from_mins(1));
        let err = String::from_utf8_lossy(&o.stderr).into_owned();
        assert_eq!(o.status.code(), Some(3), "{err}");
        assert!(err.contains(want), "{err}");
    };
    refused(&mut shard(&out, 4), "shard 4 does not exist: the plan");
    refused(
        bin().arg("bake").arg("--plan").arg(&out).env("JOB_COMPLETION_INDEX", "two"),
        "JOB_COMPLETION_INDEX=\"two\" is not a shard index",
    );
    let none = dir.path().join("none");
    refused(bin().arg("bake").arg("--plan").arg(&none).args(["--shard", "0"]), "no plan");
    // A plan far larger than any plan is refused before it is read (a sparse file: no disk).
    let huge = dir.path().join("huge");
    std::fs::create_dir_all(huge.join("shards")).unwrap();
    let plan = std::fs::File::create(huge.join("shards/plan.json")).unwrap();
    plan.set_len((1 << 30) + 1).unwrap();
    drop(plan);
    refused(
        bin().arg("bake").arg("--plan").arg(&huge).args(["--shard", "0"]),
        "plan.json: is 1073741825 bytes; 0 to 1073741824 bytes were expected",
    );
    // Index from the environment, for each engine.
    for var in ["JOB_COMPLETION_INDEX", "AWS_BATCH_JOB_ARRAY_INDEX", "SLURM_ARRAY_TASK_ID"] {
        let o = run_within(
            bin().arg("bake").arg("--plan").arg(&out).args(["-q", "--gpu", "off"]).env(var, "1"),
            Duration::from_mins(2),
        );
        assert!(o.status.success(), "{var}: {}", String::from_utf8_lossy(&o.stderr));
        assert!(String::from_utf8_lossy(&o.stdout).contains("shard 1 of 4"));
    }
    let other = dir.path().join("r2");
    ok(bin().arg("plan").arg(&tif).arg("--out").arg(&other).args(BAKE).args(["--shards", "4", "-q"]));
    let e =
        fails(bin().arg("plan").arg(&tif).arg("--out").arg(&out).args(BAKE).args(["--shards", "16", "-q"]));
    assert!(e.contains("has finished shards [1]"), "{e}");
    // Touched since the plan (same heights, a new modification time): a shard does not trust
    // the plan's scan record, scans the input whole, finds the same checksum and bakes.
    let f = std::fs::File::options().write(true).open(&tif).unwrap();
    f.set_modified(std::time::SystemTime::now() + Duration::from_secs(5)).unwrap();
    drop(f);
    let o = run_within(&mut shard(&out, 2), Duration::from_mins(2));
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(o.status.success() && err.contains("scanning the inputs whole"), "{err}");
    // The input changed since the plan: every step refuses it.
    std::fs::copy(synth(dir.path(), 11), &tif).unwrap();
    refused(&mut shard(&out, 0), "no longer read as when the plan was made");
    refused(
        bin().arg("bake").arg("--plan").arg(&out).args(["--finish"]),
        "no longer read as when the plan was made",
    );
}

/// A raster with no-data, small holes and one wider than the fill's reach: the plan records its
/// scan (checksum, counts, the fallback grid in `shards/fallback.f32`), every shard opens the
/// input from that record without scanning it, and the tileset is the one-machine bake's.
#[test]
fn a_raster_with_no_data_shards_from_the_plans_scan_record() {
    use terrastream::raster::geotiff::{Model, write_tiled_f32};
    let dir = tempfile::tempdir().unwrap();
    let tif = dir.path().join("holey.tif");
    let mut file = std::fs::File::create(&tif).unwrap();
    write_tiled_f32(
        &mut file,
        (600, 400),
        32,
        Model::Projected,
        (0.0, 1000.0),
        (5.0, -5.0),
        Some(-9999.0),
        false,
        |c, r| {
            let small = (c % 97 < 3) && (r % 89 < 4);
            let wide = (150..420).contains(&c) && (100..300).contains(&r);
            if small || wide { -9999.0 } else { terrastream::raster::synth::height_at(600, 400, 11, c, r) }
        },
    )
    .unwrap();
    drop(file);
    let one = one_machine(dir.path(), &tif);
    let out = dir.path().join("s");
    ok(bin().arg("plan").arg(&tif).arg("--out").arg(&out).args(BAKE).args(["--shards", "4", "-q"]));
    let plan: serde_json::Value =
        serde_json::from_slice(&std::fs::read(out.join("shards/plan.json")).unwrap()).unwrap();
    let scan = &plan["inputs"]["scan"];
    assert!(scan["nodata_filled"].as_u64().unwrap() > 0 && scan["fallback"]["cols"] == 3, "{scan}");
    // A fallback grid of another size than the plan records is refused before it is read.
    let grid = out.join("shards/fallback.f32");
    let bytes = std::fs::read(&grid).unwrap();
    assert_eq!(bytes.len(), 3 * 2 * 4);
    std::fs::write(&grid, [bytes.clone(), vec![0; 1 << 20]].concat()).unwrap();
    let o = run_within(&mut shard(&out, 0), Duration::from_mins(1));
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(3), "{err}");
    assert!(err.contains("fallback.f32: is 1048600 bytes; 24 bytes were expected"), "{err}");
    std::fs::write(&grid, &bytes).unwrap();
    for i in [3, 0, 2, 1] {
        let o = run_within(&mut shard(&out, i), Duration::from_mins(2));
        let err = String::from_utf8_lossy(&o.stderr);
        assert!(o.status.success() && !err.contains("scanning"), "shard {i}: {err}");
    }
    ok(bin().arg("bake").arg("--plan").arg(&out).args(["--finish", "-q", "--gpu", "off"]));
    assert_same_tree(&one, &out);
    assert!(!out.join("shards").exists());
}
