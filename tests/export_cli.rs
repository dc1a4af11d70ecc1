//! `terrastream export` of one (tile, level): the format follows the extension of `--out`, a
//! contradicting `--format` is refused, an existing file is kept unless `--force`; and the
//! top-level help says what export writes.

#![allow(clippy::unwrap_used)]

mod common;

use std::path::{Path, PathBuf};

use common::{bin, fails, ok};
use terrastream::bake::BakeOptions;
use terrastream::bake::PointLevels;

/// A small terrain tileset (65² samples, 16-cell leaves), baked on the CPU.
fn baked(dir: &Path) -> PathBuf {
    let tif = dir.join("t.tif");
    common::write_synth_geotiff(&tif, (65, 65), 4, (500_000.0, 4_000_000.0));
    let out = dir.join("store/t");
    let opts = BakeOptions { tile_size: 16, max_error: 0.5, levels: 2, point_levels: PointLevels::Auto };
    common::bake_file(&tif, &opts, &out);
    out
}

fn export(ts: &Path, out: &Path, extra: &[&str]) -> std::process::Command {
    let mut c = bin();
    c.arg("export").arg(ts).args(["--tile", "0/0/0", "--level", "0"]).args(extra).arg("--out").arg(out);
    c
}

#[test]
fn single_tile_export_follows_the_extension_and_keeps_existing_files() {
    let tmp = tempfile::tempdir().unwrap();
    let ts = baked(tmp.path());

    // No --format: the extension chooses (any case), PLY for any other name.
    let obj = tmp.path().join("x.obj");
    ok(&mut export(&ts, &obj, &[]));
    let text = std::fs::read_to_string(&obj).unwrap();
    assert!(text.starts_with("# terrastream mesh:") && text.contains("\nf "), "{}", &text[..80]);
    let upper = tmp.path().join("y.OBJ");
    ok(&mut export(&ts, &upper, &[]));
    assert!(std::fs::read(&upper).unwrap().starts_with(b"# terrastream mesh:"));
    for name in ["x.ply", "plain"] {
        let p = tmp.path().join(name);
        ok(&mut export(&ts, &p, &[]));
        assert!(std::fs::read(&p).unwrap().starts_with(b"ply\nformat binary_little_endian"), "{name}");
    }
    // An explicit format that agrees is fine; one that contradicts is refused, writing nothing.
    ok(&mut export(&ts, &tmp.path().join("z.obj"), &["--format", "obj"]));
    let w = tmp.path().join("w.obj");
    let e = fails(&mut export(&ts, &w, &["--format", "ply"]));
    assert!(e.contains("--format ply contradicts") && e.contains("w.obj"), "{e}");
    assert!(!w.exists());
    let e = fails(
        bin().arg("export").arg(&ts).args(["--format", "3dtiles", "--out"]).arg(tmp.path().join("v.ply")),
    );
    assert!(e.contains("--format 3dtiles contradicts"), "{e}");

    // An existing file is refused and left as it was, unless --force.
    std::fs::write(&obj, b"keep me").unwrap();
    let e = fails(&mut export(&ts, &obj, &[]));
    assert!(e.contains("x.obj") && e.contains("exists") && e.contains("--force"), "{e}");
    assert_eq!(std::fs::read(&obj).unwrap(), b"keep me");
    ok(&mut export(&ts, &obj, &["--force"]));
    assert_eq!(std::fs::read_to_string(&obj).unwrap(), text);
    // A wrong tile is still reported as such, whatever is at --out.
    let e = fails(bin().arg("export").arg(&ts).args(["--tile", "0/0/0", "--level", "9", "--out"]).arg(&obj));
    assert!(e.contains("level 9"), "{e}");
    // --force does not empty a folder for 3D Tiles.
    let e = fails(
        bin()
            .arg("export")
            .arg(&ts)
            .args(["--format", "3dtiles", "--force", "-q", "--out"])
            .arg(tmp.path().join("t3")),
    );
    assert!(e.contains("--force"), "{e}");
}

#[test]
fn top_level_help_names_every_export_format() {
    let help = ok(bin().arg("--help"));
    let line = help.lines().find(|l| l.trim_start().starts_with("export ")).unwrap();
    let start = help.find(line).unwrap();
    let rest = &help[start..];
    let entry = &rest[..rest.find("\n  pack").unwrap_or(rest.len())];
    assert!(entry.contains("PLY") && entry.contains("OBJ") && entry.contains("3D Tiles"), "{entry}");
}
