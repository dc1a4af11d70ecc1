//! The defects hostile and unusual input found (issue "Harden what exists"), each reproduced
//! exactly as reported, through the `terrastream` binary: valid rasters that failed to bake
//! (D1), values that spun forever (D2), resume keeping damaged blobs (D4), leftovers of a
//! killed bake (D6), bad values found late (D7) and misleading messages (D8). Server defects
//! are in tests/server.rs, parser fuzz finds in tests/fuzz_regressions.rs.

// Helpers outside `#[test]` functions unwrap and panic as the tests do; 175.1873779296875 is the
// exact f32 from the report (clippy counts its digits, not its bits).
#![allow(
    clippy::unwrap_used,
    clippy::panic,
    clippy::float_cmp,
    clippy::excessive_precision,
    clippy::duration_suboptimal_units,
    clippy::case_sensitive_file_extension_comparisons
)]

mod common;
use common::{bin, fails, fuji_or_generated, ok, run_within, tree};

use std::path::Path;
use std::process::Stdio;
use std::time::{Duration, Instant};

use terrastream::codec::{self, Geometry};
use terrastream::store::Store;

/// Decodes every blob of a tileset and checks that each position lies inside the bounds its
/// header states; returns how many blobs were checked.
fn assert_positions_inside_bounds(dir: &Path) -> usize {
    let mut n = 0;
    for (name, bytes) in tree(dir) {
        if !name.ends_with(".tsb") {
            continue;
        }
        let blob = codec::decode(&bytes).unwrap_or_else(|e| panic!("{name}: {e}"));
        let b = blob.header.bounds();
        let positions = match &blob.geometry {
            Geometry::Mesh(m) => &m.positions,
            Geometry::Points(p) => &p.positions,
        };
        for p in positions {
            for a in 0..3 {
                assert!(
                    b.min[a] <= p[a] && p[a] <= b.max[a],
                    "{name}: {p:?} outside {:?}..{:?}",
                    b.min,
                    b.max
                );
            }
        }
        n += 1;
    }
    n
}

fn write_geotiff(path: &Path, w: u32, h: u32, data: &[f32], cell: f64) {
    let bytes = terrastream::raster::geotiff::encode_f32(w, h, data, (0.0, 0.0), (cell, -cell)).unwrap();
    std::fs::write(path, bytes).unwrap();
}

/// D1, exactly as reported: tile 3/1/3 level 1 had a point 0.475 above the tile's top.
#[test]
fn d1_fuji_small_tiles_bake_with_points_inside_the_bounds() {
    let tmp = tempfile::tempdir().unwrap();
    let fuji =
        fuji_or_generated(tmp.path(), "hardening::d1_fuji_small_tiles_bake_with_points_inside_the_bounds");
    let out = tmp.path().join("x");
    ok(bin()
        .args(["bake", "--quiet", "--encoding", "terrain-rgb", "--cell-size", "30", "--tile-size", "64"])
        .args(["--max-error", "2", "--point-levels", "all", "--gpu", "off", "--out"])
        .arg(&out)
        .arg(&fuji));
    assert!(assert_positions_inside_bounds(&out) > 300);
}

/// D1 on flat terrain: the reported 33×33 lake at 175.1873779296875, then flat rasters at
/// seeded random heights and a plateau with a one-tile lake, every level ladder.
#[test]
fn d1_flat_rasters_and_lakes_bake() {
    let tmp = tempfile::tempdir().unwrap();
    let tif = tmp.path().join("flat.tif");
    write_geotiff(&tif, 33, 33, &[175.187_377_929_687_5; 33 * 33], 1.0);
    let out = tmp.path().join("flat");
    ok(bin().args(["bake", "--quiet", "--tile-size", "32", "--gpu", "off", "--out"]).arg(&out).arg(&tif));
    assert_positions_inside_bounds(&out);

    let mut next = common::xorshift(0x9e37_79b9_7f4a_7c15);
    for case in 0..12 {
        let z = (next() % 2_000_000) as f32 / 1000.0 - 500.0 + (next() % 1000) as f32 / 4096.0;
        let (w, h) = (17 + (next() % 40) as u32, 17 + (next() % 40) as u32);
        let mut data = vec![z; (w * h) as usize];
        if case % 2 == 1 {
            // A plateau with a one-tile lake cut into it.
            for (i, v) in data.iter_mut().enumerate() {
                let (c, r) = (i as u32 % w, i as u32 / w);
                if c > w / 3 {
                    *v = z + 37.25;
                }
                if (2..10).contains(&c) && (2..10).contains(&r) {
                    *v = z - 3.0;
                }
            }
        }
        write_geotiff(&tif, w, h, &data, [1.0, 0.5, 30.0][case % 3]);
        let levels = (1 + case % 4).to_string();
        let out = tmp.path().join(format!("case{case}"));
        ok(bin()
            .args(["bake", "--quiet", "--tile-size", "16", "--gpu", "off", "--max-error", "0.5"])
            .args(["--levels", &levels, "--out"])
            .arg(&out)
            .arg(&tif));
        assert_positions_inside_bounds(&out);
    }
}

/// D2 and D7: absurd options and values are refused before any work, with a message that
/// names the input and the cause, and nothing is written (no directory, no bake-options.json).
#[test]
fn d2_d7_absurd_values_are_refused_up_front() {
    let tmp = tempfile::tempdir().unwrap();
    let fuji = fuji_or_generated(tmp.path(), "hardening::d2_d7_absurd_values_are_refused_up_front");
    let out = tmp.path().join("never");
    let cases: [(&[&str], &str); 4] = [
        (&["--cell-size", "1e300"], "cell size"),
        (&["--cell-size", "1e-300"], "cell size"),
        (&["--origin", "1e300,1e300"], "origin"),
        (&["--origin", "5e8,0", "--cell-size", "1e6"], "samples span"),
    ];
    for (flags, what) in cases {
        let e = fails(
            bin()
                .args(["bake", "--quiet", "--encoding", "terrain-rgb", "--gpu", "off"])
                .args(flags)
                .arg("--out")
                .arg(&out)
                .arg(&fuji),
        );
        assert!(e.contains("fuji.png") && e.contains(what), "{flags:?}: {e}");
        assert!(!out.exists(), "{flags:?} wrote {out:?}");
    }

    // A GeoTIFF whose own pixel scale is 1e300 (spun forever in lod::measure before).
    let tif = tmp.path().join("huge-cells.tif");
    let data: Vec<f32> = (0..64).map(|i| i as f32).collect();
    write_geotiff(&tif, 8, 8, &data, 1e300);
    let e = fails(bin().args(["bake", "--quiet", "--gpu", "off", "--out"]).arg(&out).arg(&tif));
    assert!(e.contains("huge-cells.tif") && e.contains("georeference"), "{e}");
    assert!(!out.exists());

    // Heights of 1e30 and ±3e38 (undeclared no-data values) name the sample.
    for (bad, at) in [(1e30_f32, 10), (3e38, 63), (-3e38, 0)] {
        let mut data = vec![12.5_f32; 64];
        data[at] = bad;
        let tif = tmp.path().join("bad-height.tif");
        write_geotiff(&tif, 8, 8, &data, 1.0);
        let e = fails(bin().args(["bake", "--quiet", "--gpu", "off", "--out"]).arg(&out).arg(&tif));
        let (c, r) = (at % 8, at / 8);
        assert!(
            e.contains("bad-height.tif")
                && e.contains(&format!("column {c}, row {r}"))
                && !e.contains("quantization"),
            "{e}"
        );
        assert!(!out.exists());
    }

    // Relief far beyond the cell size (heights in millimetres on 1 µm cells, say).
    let tif = tmp.path().join("relief.tif");
    let data: Vec<f32> = (0..64).map(|i| if i % 2 == 0 { 0.0 } else { 9e6 }).collect();
    write_geotiff(&tif, 8, 8, &data, 1e-3);
    let e = fails(bin().args(["bake", "--quiet", "--gpu", "off", "--out"]).arg(&out).arg(&tif));
    assert!(e.contains("relief.tif") && e.contains("heights span"), "{e}");
    assert!(!out.exists());
}

/// D4: a resumed bake verifies every blob it keeps (length and payload checksum) and bakes
/// again what fails; the result is the uninterrupted bake, byte for byte. The warning it logs
/// is plain text when stderr is not a terminal (D8).
#[test]
fn d4_resume_rebakes_damaged_blobs() {
    let tmp = tempfile::tempdir().unwrap();
    let fuji = fuji_or_generated(tmp.path(), "hardening::d4_resume_rebakes_damaged_blobs");
    let out = tmp.path().join("t");
    let bake = |out: &Path| {
        let out = run_within(
            bin()
                .args(["bake", "--encoding", "terrain-rgb", "--cell-size", "30", "--tile-size", "128"])
                .args(["--levels", "3", "--point-levels", "all", "--gpu", "off", "--out"])
                .arg(out)
                .arg(&fuji),
            Duration::from_secs(300),
        );
        assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
        String::from_utf8_lossy(&out.stderr).into_owned()
    };
    bake(&out);
    let clean = tree(&out);
    let store = Store::new(&out);
    let key = terrastream::tiling::TileKey::new(2, 1, 1);
    let path = |level: u8| store.blob_path(key, level);
    let original: Vec<Vec<u8>> = (0..3).map(|l| std::fs::read(path(l)).unwrap()).collect();
    // Truncated past the header, a payload byte flipped, bytes appended.
    std::fs::write(path(0), &original[0][..codec::PREFIX_LEN + 10]).unwrap();
    let mut flipped = original[1].clone();
    let at = codec::PREFIX_LEN + (flipped.len() - codec::PREFIX_LEN) / 2;
    flipped[at] ^= 0x20;
    std::fs::write(path(1), &flipped).unwrap();
    let mut longer = original[2].clone();
    longer.extend_from_slice(b"\0\0\0\0");
    std::fs::write(path(2), &longer).unwrap();

    let log = bake(&out);
    assert!(log.contains("re-baking a damaged blob"), "{log}");
    assert!(!log.contains('\u{1b}'), "ANSI escapes in a redirected log: {log:?}");
    assert!(tree(&out) == clean, "resumed tree differs from the clean bake");
}

/// D6 and the kill -9 promise: a bake killed at several moments and then run again gives the
/// tree of an uninterrupted bake, every file included (temporary files of the killed run are
/// removed). Each kill must interrupt a running bake: the bake is run in short steps between
/// SIGSTOP and SIGCONT, the blobs are counted while it is stopped, and it is killed while still
/// stopped, so it cannot end between the count and the kill; a bake that ended on its own
/// before its kill fails the test rather than passing it untested.
#[test]
fn killed_bakes_resume_to_the_identical_tree() {
    let tmp = tempfile::tempdir().unwrap();
    let tif = tmp.path().join("terrain.tif");
    ok(bin().args(["synth", "--width", "769", "--seed", "7", "--out"]).arg(&tif));
    let args = |out: &Path| {
        let mut c = bin();
        c.args(["bake", "--quiet", "--tile-size", "64", "--levels", "3", "--gpu", "off", "--out"])
            .arg(out)
            .arg(&tif);
        c
    };
    let reference = tmp.path().join("ref");
    let t0 = Instant::now();
    ok(&mut args(&reference));
    let clean = tree(&reference);
    let blobs = clean.keys().filter(|k| k.ends_with(".tsb")).count();
    // Steps cover at most half the time the blobs still missing took in the reference bake.
    let per_blob = t0.elapsed() / u32::try_from(blobs).unwrap();

    // Kill when a share of the blobs exists (or at once), then resume; twice for one of them.
    for (i, share) in [0.0, 0.1, 0.5, 0.9].into_iter().enumerate() {
        let out = tmp.path().join(format!("k{i}"));
        for round in 0..if i == 2 { 2 } else { 1 } {
            let mut child = args(&out).stdout(Stdio::null()).stderr(Stdio::null()).spawn().unwrap();
            let want = (blobs as f64 * share) as usize + round;
            let t0 = Instant::now();
            loop {
                stop(&child);
                if let Some(status) = child.try_wait().unwrap() {
                    panic!(
                        "kill at {share}: the bake ended ({status}) before {want} of {blobs} blobs were \
                         counted: it was never interrupted"
                    );
                }
                let have = if out.exists() { count_files(&out, ".tsb") } else { 0 };
                if have >= want {
                    break;
                }
                assert!(t0.elapsed() < Duration::from_mins(2), "kill at {share}: {have} of {want} blobs");
                signal(&child, "CONT");
                let step = per_blob * u32::try_from(want - have).unwrap() / 2;
                std::thread::sleep(step.clamp(Duration::from_millis(1), Duration::from_millis(50)));
            }
            // Still stopped, so still unfinished: the kill interrupts it.
            child.kill().unwrap(); // SIGKILL
            let status = child.wait().unwrap();
            assert!(!status.success(), "kill at {share}: {status}");
            assert!(
                !out.exists() || tree(&out) != clean,
                "kill at {share}: the killed bake had already written everything"
            );
        }
        // A temporary file a killed writer left mid-write (planted too, since a kill between
        // writes leaves none).
        if out.join("tiles").exists() {
            std::fs::write(out.join(format!("tiles/.0.tsb.{}.0.tmp", u32::MAX - 1)), b"partial").unwrap();
        }
        ok(&mut args(&out));
        let resumed = tree(&out);
        let extra: Vec<&String> = resumed.keys().filter(|k| !clean.contains_key(*k)).collect();
        assert!(extra.is_empty(), "kill at {share}: leftovers {extra:?}");
        assert!(resumed == clean, "kill at {share}: resumed tree differs from the uninterrupted bake");
    }
}

/// Sends `SIG<name>` to `child` (through kill(1): the tests have no libc binding).
fn signal(child: &std::process::Child, name: &str) {
    let st = std::process::Command::new("kill").arg(format!("-{name}")).arg(child.id().to_string()).status();
    assert!(st.unwrap().success(), "kill -{name} {}", child.id());
}

/// Stops `child` (SIGSTOP) and waits until each of its threads is stopped, or it has exited.
fn stop(child: &std::process::Child) {
    signal(child, "STOP");
    let tasks = format!("/proc/{}/task", child.id());
    let t0 = Instant::now();
    loop {
        let states: Vec<String> = std::fs::read_dir(&tasks)
            .map(|d| d.filter_map(Result::ok).map(|e| e.path().join("stat")).collect::<Vec<_>>())
            .unwrap_or_default()
            .into_iter()
            .filter_map(|p| std::fs::read_to_string(p).ok())
            // The state follows the command name's closing parenthesis.
            .filter_map(|s| s.rsplit_once(") ").map(|(_, rest)| rest.chars().take(1).collect()))
            .collect();
        if states.iter().all(|s| s == "T" || s == "Z" || s == "X") {
            return;
        }
        assert!(t0.elapsed() < Duration::from_secs(10), "{tasks}: not stopped: {states:?}");
        std::thread::sleep(Duration::from_micros(200));
    }
}

fn count_files(dir: &Path, suffix: &str) -> usize {
    let Ok(entries) = std::fs::read_dir(dir) else { return 0 };
    entries
        .filter_map(Result::ok)
        .map(|e| {
            let p = e.path();
            if p.is_dir() {
                count_files(&p, suffix)
            } else {
                usize::from(p.to_string_lossy().ends_with(suffix))
            }
        })
        .sum()
}

/// D8: each cause is printed once; a model with ±1e308 coordinates is not "zero extent"; a
/// dangling symbolic link as --out says so.
#[test]
fn d8_messages_name_the_cause_once() {
    let tmp = tempfile::tempdir().unwrap();
    let fuji = fuji_or_generated(tmp.path(), "hardening::d8_messages_name_the_cause_once");
    let file = tmp.path().join("a-file");
    std::fs::write(&file, b"x").unwrap();
    let e = fails(
        bin()
            .args(["bake", "--quiet", "--encoding", "terrain-rgb", "--gpu", "off", "--out"])
            .arg(file.join("sub"))
            .arg(&fuji),
    );
    assert!(e.contains("not a directory"), "{e}");
    for line in e.lines() {
        let parts: Vec<&str> = line.split(": ").collect();
        for w in parts.windows(2) {
            assert_ne!(w[0], w[1], "repeated cause in {line:?}");
        }
    }

    let obj = tmp.path().join("far.obj");
    std::fs::write(&obj, "v -1e308 0 0\nv 1e308 0 0\nv 0 1e308 0\nf 1 2 3\n").unwrap();
    let e = fails(bin().args(["bake-model", "--gpu", "off", "--out"]).arg(tmp.path().join("m")).arg(&obj));
    assert!(e.contains("far.obj") && !e.contains("zero extent") && e.contains("beyond"), "{e}");

    let link = tmp.path().join("link");
    std::os::unix::fs::symlink(tmp.path().join("missing"), &link).unwrap();
    let e = fails(
        bin()
            .args(["bake", "--quiet", "--encoding", "terrain-rgb", "--gpu", "off", "--out"])
            .arg(&link)
            .arg(&fuji),
    );
    assert!(e.contains("symbolic link") && !e.contains("File exists"), "{e}");
}

/// Found while testing these: a closed stdout (`… | head -1`) made every command panic in
/// `println!`; now it ends quietly. Deterministic: the pipe's read end is closed before the
/// command starts.
#[test]
fn closed_stdout_is_not_a_panic() {
    let tmp = tempfile::tempdir().unwrap();
    let fuji = fuji_or_generated(tmp.path(), "hardening::closed_stdout_is_not_a_panic");
    let out = tmp.path().join("t");
    ok(bin()
        .args(["bake", "--quiet", "--encoding", "terrain-rgb", "--cell-size", "30", "--tile-size", "256"])
        .args(["--levels", "1", "--gpu", "off", "--out"])
        .arg(&out)
        .arg(&fuji));
    let (reader, writer) = std::io::pipe().unwrap();
    drop(reader);
    let o = bin().arg("inspect").arg(&out).stdout(writer).stderr(Stdio::piped()).output().unwrap();
    let stderr = String::from_utf8_lossy(&o.stderr);
    assert!(!stderr.contains("panicked"), "{stderr}");
    assert!(o.status.success(), "{stderr}");
}

/// D2: a bake that runs past `--time-limit` is stopped between tiles and says so; what it
/// baked is kept and a re-run finishes it.
#[test]
fn time_limit_stops_a_bake_and_it_resumes() {
    let tmp = tempfile::tempdir().unwrap();
    let fuji = fuji_or_generated(tmp.path(), "hardening::time_limit_stops_a_bake_and_it_resumes");
    let out = tmp.path().join("t");
    let base = |limit: Option<&str>| {
        let mut c = bin();
        c.args(["bake", "--quiet", "--encoding", "terrain-rgb", "--cell-size", "30", "--tile-size", "32"])
            .args(["--gpu", "off"]);
        if let Some(l) = limit {
            c.args(["--time-limit", l]);
        }
        c.arg("--out").arg(&out).arg(&fuji);
        c
    };
    let e = fails(&mut base(Some("0.000001")));
    assert!(e.contains("--time-limit") && e.contains("resume"), "{e}");
    assert!(!e.contains("panicked"), "{e}");
    ok(&mut base(None));
    assert!(Store::new(&out).manifest().is_ok());
    assert!(fails(&mut base(Some("0"))).contains("time-limit"));
}
