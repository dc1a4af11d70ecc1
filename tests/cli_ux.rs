//! The command line as a new user meets it (issue 35): errors in the user's words, flags that
//! do not apply refused, the same `-q` on every command, the point baker's choice said once,
//! `inspect` saying what its error figures are. Every input is generated here (no shared data).

#![allow(clippy::unwrap_used)]

mod common;

use std::path::{Path, PathBuf};

use common::{bin, fails, ok};

/// A small synthetic GeoTIFF (float heights: its samples are heights already).
fn synth_tif(dir: &Path) -> PathBuf {
    let tif = dir.join("synth.tif");
    ok(bin().arg("synth").arg("--out").arg(&tif).args(["--width", "65", "--cell-size", "10"]));
    tif
}

/// Every command accepts `-q`, before or after its name, and its help says so.
#[test]
fn every_command_takes_the_same_quiet_flag() {
    let commands = [
        "bake",
        "plan",
        "bake-model",
        "inspect",
        "synth",
        "serve",
        "demo",
        "client",
        "eval",
        "export",
        "pack",
    ];
    for c in commands {
        let help = ok(bin().args([c, "-q", "--help"]));
        assert!(help.contains("-q, --quiet"), "{c}: {help}");
        ok(bin().args(["-q", c, "--help"]));
    }
    let dir = tempfile::tempdir().unwrap();
    let out = ok(bin().args(["synth", "-q", "--width", "17", "--out"]).arg(dir.path().join("a.tif")));
    assert!(out.contains("wrote"), "{out}");
    // Quiet: no progress or dataset description on stderr; the summary on stdout stays.
    let tif = synth_tif(dir.path());
    let o = common::run_within(
        bin().arg("-q").arg("bake").arg(&tif).arg("--out").arg(dir.path().join("t")).args(["--gpu", "off"]),
        std::time::Duration::from_mins(2),
    );
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    assert!(String::from_utf8_lossy(&o.stdout).contains("baked "));
    assert!(o.stderr.is_empty(), "{}", String::from_utf8_lossy(&o.stderr));
}

/// `--encoding` says how a PNG's channels encode heights; on a GeoTIFF (samples that are
/// heights already) it is refused, naming the file and the flag, by `bake` and `plan`.
#[test]
fn encoding_on_a_geotiff_is_refused() {
    let dir = tempfile::tempdir().unwrap();
    let tif = synth_tif(dir.path());
    for cmd in ["bake", "plan"] {
        let e = fails(
            bin().arg(cmd).arg(&tif).args(["--encoding", "terrain-rgb", "--out"]).arg(dir.path().join(cmd)),
        );
        assert!(e.contains("synth.tif") && e.contains("--encoding") && e.contains("GeoTIFF"), "{cmd}: {e}");
        assert!(!dir.path().join(cmd).join("tileset.json").exists());
    }
}

/// PNG errors name colour types as users do ("8-bit RGB", "16-bit grayscale") and encodings
/// as the flag spells them, never the decoder's type names (`Rgb8`, `L16`, `Gray16`).
#[test]
fn png_errors_say_colour_types_in_words() {
    let dir = tempfile::tempdir().unwrap();
    let rgb = dir.path().join("rgb.png");
    image::RgbImage::from_pixel(4, 4, image::Rgb([1, 134, 160])).save(&rgb).unwrap();
    let gray = dir.path().join("gray.png");
    image::ImageBuffer::<image::Luma<u16>, _>::from_pixel(4, 4, image::Luma([500])).save(&gray).unwrap();
    let bake = |png: &Path, encoding: Option<&str>| {
        let mut c = bin();
        c.arg("bake").arg(png).args(["--gpu", "off", "--out"]).arg(dir.path().join("out"));
        if let Some(e) = encoding {
            c.args(["--encoding", e]);
        }
        fails(&mut c)
    };
    let cases = [
        (&rgb, None, "8-bit RGB"),
        (&rgb, Some("gray16"), "--encoding gray16 does not apply to this PNG: its samples are 8-bit RGB"),
        (
            &gray,
            Some("terrarium"),
            "--encoding terrarium does not apply to this PNG: its samples are 16-bit grayscale",
        ),
    ];
    for (png, encoding, want) in cases {
        let e = bake(png, encoding);
        assert!(e.contains(want), "{encoding:?}: {e}");
        for internal in ["Rgb8", "L16", "Gray16", "Terrarium"] {
            assert!(!e.contains(internal), "{encoding:?}: names {internal}: {e}");
        }
    }
}

/// Where point levels are baked is said once: the summary's `point levels baked by …`; a
/// fallback notice (`--gpu auto` without a usable adapter) says only why.
#[test]
fn the_point_baker_is_named_once() {
    let dir = tempfile::tempdir().unwrap();
    let tif = synth_tif(dir.path());
    let o = common::run_within(
        bin()
            .arg("bake")
            .arg(&tif)
            .args(["--gpu", "auto", "--threads", "1", "--out"])
            .arg(dir.path().join("t")),
        std::time::Duration::from_mins(2),
    );
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let all = format!("{}{}", String::from_utf8_lossy(&o.stdout), String::from_utf8_lossy(&o.stderr));
    assert_eq!(all.matches("point levels").count(), 1, "{all}");
    assert_eq!(all.to_lowercase().matches("on the cpu").count(), 0, "{all}");
}

/// `inspect` says what its error columns are: the mesh's vertical deviation, the points'
/// distance to the surface and their largest gap (terrain and model tilesets, and one node).
#[test]
fn inspect_says_what_the_errors_are() {
    let dir = tempfile::tempdir().unwrap();
    let tif = synth_tif(dir.path());
    let t = dir.path().join("t");
    ok(bin().arg("bake").arg(&tif).args(["--tile-size", "32", "--gpu", "off", "-q", "--out"]).arg(&t));
    for args in [&[][..], &["--tile", "0/0/0"][..]] {
        let out = ok(bin().arg("inspect").arg(&t).args(args));
        assert!(out.contains("max err") && out.contains("worst gap"), "{out}");
        assert!(out.contains("vertical deviation from the full-resolution raster"), "{out}");
        assert!(out.contains("the largest distance from the surface to its nearest point"), "{out}");
    }
    // A model: a tetrahedron.
    let obj = dir.path().join("tet.obj");
    std::fs::write(&obj, "v 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 1\nf 1 3 2\nf 1 2 4\nf 1 4 3\nf 2 3 4\n").unwrap();
    let m = dir.path().join("m");
    ok(bin()
        .arg("bake-model")
        .arg(&obj)
        .args(["--resolution", "16", "--levels", "2", "--gpu", "off", "--out"])
        .arg(&m));
    let out = ok(bin().arg("inspect").arg(&m));
    assert!(out.contains("errors: model units") && out.contains("quantized positions"), "{out}");
}
