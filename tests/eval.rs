//! `terrastream eval` end to end on small bakes: the bunny as a model tileset (coverage and the
//! instance experiment) and a small synthetic terrain; the report, its charts and the final
//! `F-measure:` line are checked. Bad input is refused with the file named.
//!
//! Skips (with the reason printed) when no adapter is found, unless
//! `TERRASTREAM_REQUIRE_GPU=1`: then it fails.
#![cfg(all(feature = "client", feature = "gpu", feature = "cli"))]
#![allow(clippy::unwrap_used, clippy::panic)]

mod common;
use common::{bin, require_gpu};

use std::path::Path;
use std::process::Output;

fn ok(o: &Output, what: &str) {
    assert!(o.status.success(), "{what} failed: {}", String::from_utf8_lossy(&o.stderr));
}

/// Runs eval; `None` when there is no adapter and GPU tests may skip.
fn eval(dir: &Path, out: &Path, extra: &[&str]) -> Option<String> {
    let o = bin()
        .arg("eval")
        .arg(dir)
        .arg("--out")
        .arg(out)
        .args(["--width", "160", "--height", "120", "--azimuths", "2", "--distances", "1,4", "--quiet"])
        .args(extra)
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&o.stderr);
    if !o.status.success() && stderr.contains("no adapter") {
        assert!(!require_gpu(), "TERRASTREAM_REQUIRE_GPU=1 but eval found no adapter: {stderr}");
        eprintln!("skipping eval test: no GPU adapter (set TERRASTREAM_REQUIRE_GPU=1 to fail instead)");
        return None;
    }
    ok(&o, "eval");
    Some(String::from_utf8(o.stdout).unwrap())
}

/// The value of the final `F-measure: <value>` line.
fn final_f(stdout: &str) -> f64 {
    let last = stdout.trim_end().lines().last().unwrap();
    let v = last.strip_prefix("F-measure: ").unwrap_or_else(|| panic!("last line is {last:?}"));
    let f: f64 = v.parse().unwrap();
    assert!((0.0..=1.0).contains(&f), "{f}");
    f
}

fn check_png(path: &Path) -> (u32, u32) {
    let img = image::open(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    (img.width(), img.height())
}

#[test]
fn eval_reports_coverage_and_instances_on_a_model_and_a_terrain() {
    let tmp = tempfile::tempdir().unwrap();
    let model = common::bunny_or_generated(tmp.path(), "eval: the bunny as a model tileset");
    // The bunny, three coarse point levels (fast in debug builds).
    let bunny = tmp.path().join("bunny");
    let o = bin()
        .args(["bake-model", "--gpu", "off", "--resolutions", "60,40,20", "--out"])
        .arg(&bunny)
        .arg(&model)
        .output()
        .unwrap();
    ok(&o, "bake-model");
    let out = tmp.path().join("report-bunny");
    let Some(stdout) = eval(
        &bunny,
        &out,
        &["--elevations", "-45,45", "--grid", "3,5,81", "--max-grid", "5", "--frames", "1"],
    ) else {
        return;
    };
    let f = final_f(&stdout);
    // Not the 0.98 target (tiny viewport, coarse levels): a sanity bound that a broken
    // comparison (empty or misplaced LOD frames) cannot meet.
    assert!(f > 0.9, "bunny F-measure {f}\n{stdout}");
    assert!(stdout.contains("instances     9 (3×3)"), "{stdout}");
    assert!(stdout.contains("instances    25 (5×5)"), "{stdout}");
    assert!(!stdout.contains("(81×81)"), "--max-grid 5 must skip N = 81");
    let md = std::fs::read_to_string(out.join("report.md")).unwrap();
    assert!(md.starts_with("# LOD evaluation"));
    assert!(md.contains("![F-measure by distance](fmeasure.png)"));
    assert!(md.contains("![frame time by instance count](frametime.png)"));
    assert!(md.contains("Not run (over `--max-grid`): N = [81]"));
    assert!(md.contains("| 9 |") && md.contains("| 25 |"));
    let last_md = md.trim_end().lines().last().unwrap();
    assert_eq!(last_md, stdout.trim_end().lines().last().unwrap());
    assert_eq!(check_png(&out.join("fmeasure.png")), (640, 400));
    assert_eq!(check_png(&out.join("frametime.png")), (640, 400));
    assert_eq!(check_png(&out.join("frames/lod-d1.png")), (160, 120));
    let json: serde_json::Value =
        serde_json::from_slice(&std::fs::read(out.join("results.json")).unwrap()).unwrap();
    // 2 distances × 2 elevations × 2 azimuths.
    assert_eq!(json["cameras"].as_array().unwrap().len(), 8);
    assert_eq!(json["instances"].as_array().unwrap().len(), 2);
    assert!((json["f_measure"].as_f64().unwrap() - f).abs() < 1e-4);

    // A small synthetic terrain: 129×129 samples in 64-sample tiles (5 nodes).
    let tif = tmp.path().join("synth.tif");
    ok(
        &bin().args(["synth", "--width", "129", "--cell-size", "10", "--out"]).arg(&tif).output().unwrap(),
        "synth",
    );
    let terrain = tmp.path().join("terrain");
    ok(
        &bin()
            .args(["bake", "--quiet", "--gpu", "off", "--tile-size", "64", "--levels", "2", "--out"])
            .arg(&terrain)
            .arg(&tif)
            .output()
            .unwrap(),
        "bake",
    );
    let out = tmp.path().join("report-terrain");
    let stdout = eval(&terrain, &out, &[]).unwrap();
    let f = final_f(&stdout);
    assert!(f > 0.9, "terrain F-measure {f}\n{stdout}");
    assert!(stdout.contains("needs a model tileset"), "{stdout}");
    let md = std::fs::read_to_string(out.join("report.md")).unwrap();
    assert!(md.contains("terrain tileset"));
    assert!(!out.join("frametime.png").exists());
    assert_eq!(check_png(&out.join("fmeasure.png")), (640, 400));
}

#[test]
fn eval_refuses_a_directory_without_a_tileset() {
    let tmp = tempfile::tempdir().unwrap();
    let o = bin().arg("eval").arg(tmp.path()).arg("--out").arg(tmp.path().join("r")).output().unwrap();
    assert!(!o.status.success());
    let stderr = String::from_utf8_lossy(&o.stderr);
    assert!(stderr.contains("tileset.json"), "{stderr}");
    assert!(!tmp.path().join("r").exists(), "nothing is written for bad input");
}
