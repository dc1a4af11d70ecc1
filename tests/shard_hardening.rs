//! Sharded bakes hardened (issue 40, N7 and N8): the final step verifies every shard blob it
//! publishes and sends a damaged shard back; a plan that is edited, empty, a directory or out of
//! the dataset's quadtree is refused with exit 3 and nothing written; usage errors exit 2.

#![allow(clippy::unwrap_used, clippy::panic)]

mod common;

use std::path::{Path, PathBuf};
use std::process::{Command, Output};
use std::time::Duration;

use common::{bin, ok, run_within, shard_step, tree};

/// An edit of a plan's JSON.
type Edit = Box<dyn Fn(&mut serde_json::Value)>;

const BAKE: [&str; 6] = ["--tile-size", "32", "--levels", "2", "--max-error", "0.5"];

fn synth(dir: &Path) -> PathBuf {
    let tif = dir.join("t.tif");
    ok(bin().args(["synth", "--width", "257", "--height", "193", "--seed", "5", "--out"]).arg(&tif));
    tif
}

fn plan(tif: &Path, out: &Path, shards: u32) {
    ok(bin().arg("plan").arg(tif).arg("--out").arg(out).args(BAKE).args([
        "--shards",
        &shards.to_string(),
        "-q",
    ]));
}

fn run(c: &mut Command) -> (Option<i32>, String) {
    let o: Output = run_within(c, Duration::from_mins(2));
    (o.status.code(), String::from_utf8_lossy(&o.stderr).into_owned())
}

fn finish(out: &Path) -> Command {
    let mut c = bin();
    c.arg("bake").arg("--plan").arg(out).args(["--finish", "-q", "--gpu", "off"]);
    c
}

/// Edits `out`'s plan.json with `f`.
fn edit_plan(out: &Path, f: impl FnOnce(&mut serde_json::Value)) {
    let p = out.join("shards/plan.json");
    let mut v: serde_json::Value = serde_json::from_slice(&std::fs::read(&p).unwrap()).unwrap();
    f(&mut v);
    std::fs::write(&p, serde_json::to_vec_pretty(&v).unwrap()).unwrap();
}

/// N7: a shard's blob truncated after it finished: `--finish` fails (retryable, exit 1) naming
/// the shard and the tile, publishes nothing, and marks the shard unfinished; running that shard
/// again re-bakes the blob, and the finished tileset is byte for byte the one-machine bake.
#[test]
fn finish_verifies_what_it_publishes_and_sends_a_damaged_shard_back() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let tif = synth(d);
    let one = d.join("one");
    ok(bin().arg("bake").arg(&tif).arg("--out").arg(&one).args(BAKE).args(["-q", "--gpu", "off"]));
    let out = d.join("w");
    plan(&tif, &out, 4);
    for i in 0..4 {
        ok(&mut shard_step(bin(), &out, i));
    }
    // A shard's result that lacks one of its nodes is sent back too (it would publish a hole).
    let f1 = out.join("shards/shard-1.json");
    let mut frag1: serde_json::Value = serde_json::from_slice(&std::fs::read(&f1).unwrap()).unwrap();
    frag1["nodes"].as_array_mut().unwrap().pop();
    std::fs::write(&f1, serde_json::to_vec(&frag1).unwrap()).unwrap();
    let (code, err) = run(&mut finish(&out));
    assert_eq!(code, Some(1), "{err}");
    assert!(err.contains("shard 1: its result lacks tile"), "{err}");
    assert!(!f1.exists() && !out.join("tileset.json").exists());
    ok(&mut shard_step(bin(), &out, 1));
    // The first blob shard 2 recorded, cut short (the shard's result still records its checksum).
    let frag: serde_json::Value =
        serde_json::from_slice(&std::fs::read(out.join("shards/shard-2.json")).unwrap()).unwrap();
    let node = &frag["nodes"][0];
    let (k, level) = (&node["key"], node["levels"][0]["level"].as_u64().unwrap());
    let blob = out.join(format!("tiles/{}/{}/{}/{level}.tsb", k["z"], k["x"], k["y"]));
    let len = std::fs::metadata(&blob).unwrap().len();
    std::fs::File::options().write(true).open(&blob).unwrap().set_len(len - 7).unwrap();

    let (code, err) = run(&mut finish(&out));
    assert_eq!(code, Some(1), "{err}");
    assert!(
        err.contains("shard 2") && err.contains(&format!("tile {}/{}/{}", k["z"], k["x"], k["y"])),
        "{err}"
    );
    assert!(!out.join("tileset.json").exists(), "a manifest was published over a damaged blob");
    assert!(!out.join("shards/shard-2.json").exists(), "the damaged shard is still marked finished");
    assert!(out.join("shards/shard-1.json").exists());
    // Finishing again before the shard ran: it is unfinished.
    let (code, err) = run(&mut finish(&out));
    assert_eq!(code, Some(1), "{err}");
    assert!(err.contains("have not finished (shards 2)"), "{err}");
    // The shard runs again: it re-bakes the damaged blob (not "nothing to do").
    let said = ok(&mut shard_step(bin(), &out, 2));
    assert!(said.contains("shard 2 of 4"), "{said}");
    assert_eq!(std::fs::metadata(&blob).unwrap().len(), len);
    ok(&mut finish(&out));
    let (a, b) = (tree(&one), tree(&out));
    assert_eq!(a.keys().collect::<Vec<_>>(), b.keys().collect::<Vec<_>>());
    for (name, bytes) in &a {
        assert!(b[name] == *bytes, "{name} differs from the one-machine bake");
    }
}

/// N8: a damaged or edited plan exits 3 ("a retry cannot help") and writes nothing; usage
/// errors exit 2 naming the flag.
#[test]
fn damaged_plans_exit_3_and_usage_errors_exit_2() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let tif = synth(d);
    let base = d.join("base");
    plan(&tif, &base, 4);
    let copy = |name: &str| {
        let to = d.join(name);
        std::fs::create_dir_all(to.join("shards")).unwrap();
        for f in ["bake-options.json", "shards/plan.json"] {
            std::fs::copy(base.join(f), to.join(f)).unwrap();
        }
        to
    };
    let refused = |out: &Path, step: &mut Command, want: &str| {
        let before = tree(out);
        let (code, err) = run(step);
        assert_eq!(code, Some(3), "{}: {err}", out.display());
        assert!(err.contains(want), "{}: {err}", out.display());
        assert!(!err.contains("panicked"), "{err}");
        assert_eq!(
            tree(out).keys().collect::<Vec<_>>(),
            before.keys().collect::<Vec<_>>(),
            "something was written"
        );
    };
    let cases: Vec<(&str, Edit, &str)> = vec![
        (
            "outside",
            Box::new(|p| p["shards"][0]["roots"][0]["x"] = 9.into()),
            "outside the dataset's quadtree",
        ),
        ("deep", Box::new(|p| p["shards"][0]["roots"][0]["z"] = 200.into()), "not at the plan's shard depth"),
        (
            "deep-both",
            Box::new(|p| {
                p["shard_depth"] = 200.into();
                for s in p["shards"].as_array_mut().unwrap() {
                    for r in s["roots"].as_array_mut().unwrap() {
                        r["z"] = 200.into();
                    }
                }
            }),
            "below the dataset's leaves",
        ),
        (
            "twice",
            Box::new(|p| p["shards"][1]["roots"] = p["shards"][0]["roots"].clone()),
            "which an earlier shard has too",
        ),
        (
            "empty",
            Box::new(|p| p["shards"] = serde_json::json!([])),
            "holds 0 shards; a plan has 1 to 100000",
        ),
        ("no-roots", Box::new(|p| p["shards"][3]["roots"] = serde_json::json!([])), "shard 3 has no roots"),
        (
            "read-tile",
            Box::new(|p| p["inputs"]["read"]["tile_size"] = 64.into()),
            "give different bake options",
        ),
        (
            // The checksum edited everywhere the plan records it: the tileset's bake is another.
            "checksum",
            Box::new(|p| {
                p["options"]["source"]["crc32"] = "00000000".into();
                p["inputs"]["scan"]["crc32"] = "00000000".into();
            }),
            "holds an earlier bake with different options",
        ),
        (
            "tile-size",
            Box::new(|p| {
                p["options"]["tile_size"] = 64.into();
                p["bake"]["tile_size"] = 64.into();
                p["inputs"]["read"]["tile_size"] = 64.into();
            }),
            "holds an earlier bake with different options",
        ),
        ("tile-zero", Box::new(|p| p["bake"]["tile_size"] = 0.into()), "--tile-size must be 2 to 65536"),
    ];
    for (name, edit, want) in &cases {
        let out = copy(name);
        edit_plan(&out, edit);
        refused(&out, &mut shard_step(bin(), &out, 0), want);
        refused(&out, &mut finish(&out), want);
    }
    // plan.json a directory.
    let out = copy("dir");
    std::fs::remove_file(out.join("shards/plan.json")).unwrap();
    std::fs::create_dir(out.join("shards/plan.json")).unwrap();
    refused(&out, &mut shard_step(bin(), &out, 0), "plan.json");

    // Usage: --shards 0, and an option the plan fixes given beside --plan.
    let (code, err) =
        run(bin().arg("plan").arg(&tif).arg("--out").arg(d.join("zero")).args(["--shards", "0"]));
    assert_eq!(code, Some(2), "{err}");
    assert!(err.contains("--shards"), "{err}");
    assert!(!d.join("zero").exists());
    // `plan` refuses an input or a shard count the dataset cannot take as the steps do (3).
    let (code, err) =
        run(bin().arg("plan").arg(&tif).arg("--out").arg(d.join("many")).args(["--shards", "5000", "-q"]));
    assert_eq!(code, Some(3), "{err}");
    assert!(err.contains("ask for at most that many shards"), "{err}");
    let (code, err) = run(bin().arg("plan").arg(d.join("missing.tif")).arg("--out").arg(d.join("missing")));
    assert_eq!(code, Some(3), "{err}");
    assert!(err.contains("missing.tif"), "{err}");
    for flag in [["--tile-size", "64"], ["--levels", "1"], ["--max-error", "2"], ["--z-scale", "2"]] {
        let (code, err) = run(shard_step(bin(), &base, 0).args(flag));
        assert_eq!(code, Some(2), "{flag:?}: {err}");
        assert!(err.contains(flag[0]) && err.contains("--plan"), "{flag:?}: {err}");
    }
    // --anchor is the final step's: refused beside a shard, whether the index is a flag or not.
    let (code, err) = run(shard_step(bin(), &base, 0).args(["--anchor", "138.7,35.3"]));
    assert_eq!(code, Some(2), "{err}");
    assert!(err.contains("--anchor") && err.contains("--finish"), "{err}");
    let mut c = bin();
    c.arg("bake")
        .arg("--plan")
        .arg(&base)
        .args(["--anchor", "138.7,35.3", "-q"])
        .env("JOB_COMPLETION_INDEX", "0");
    let (code, err) = run(&mut c);
    assert_eq!(code, Some(2), "{err}");
    // The block cache is the process's: given beside --plan, it is taken.
    let said = ok(shard_step(bin(), &base, 1).args(["--cache-mib", "64"]));
    assert!(said.contains("shard 1 of 4"), "{said}");
    let (code, err) = run(shard_step(bin(), &base, 1).args(["--cache-mib", "1"]));
    assert_eq!(code, Some(3), "{err}");
    assert!(err.contains("block cache of 1048576 bytes"), "{err}");
}
