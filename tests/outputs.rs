//! Output locations are checked before any work: `pack --out` into a folder that does not exist
//! names that folder (not a temporary file); `bake --out` and `plan --out` naming an existing
//! file say so before the inputs are opened or scanned.

#![allow(clippy::unwrap_used, clippy::panic)]

mod common;

use common::{bin, fails, ok};

#[test]
fn pack_into_a_missing_folder_names_the_folder() {
    let tmp = tempfile::tempdir().unwrap();
    let tif = tmp.path().join("t.tif");
    ok(bin().args(["synth", "--width", "65", "--height", "65", "--seed", "3", "--out"]).arg(&tif));
    let ts = tmp.path().join("ts");
    ok(bin().arg("bake").arg(&tif).arg("--out").arg(&ts).args([
        "--tile-size",
        "32",
        "--levels",
        "1",
        "-q",
        "--gpu",
        "off",
    ]));

    let missing = tmp.path().join("a");
    let e = fails(bin().arg("pack").arg(&ts).arg("--out").arg(missing.join("b.tsa")).arg("-q"));
    assert!(e.contains(&format!("its folder {} does not exist", missing.display())), "{e}");
    assert!(!e.contains("temporary"), "{e}");
    assert!(!missing.exists());

    // A file where the folder should be is named as such.
    let file = tmp.path().join("f");
    std::fs::write(&file, b"x").unwrap();
    let e = fails(bin().arg("pack").arg(&ts).arg("--out").arg(file.join("b.tsa")).arg("-q"));
    assert!(e.contains(&format!("{} is not a folder", file.display())), "{e}");
    assert_eq!(std::fs::read(&file).unwrap(), b"x");
}

/// The input here is not a raster at all: a command that opened it before looking at --out
/// would fail on the input instead.
#[test]
fn bake_and_plan_into_an_existing_file_say_so_before_reading_the_inputs() {
    let tmp = tempfile::tempdir().unwrap();
    let input = tmp.path().join("in.tif");
    std::fs::write(&input, b"not a raster").unwrap();
    let out = tmp.path().join("existing-file");
    std::fs::write(&out, b"mine").unwrap();
    for (cmd, flags) in [("bake", &["-q", "--gpu", "off"][..]), ("plan", &["-q"][..])] {
        let e = fails(bin().arg(cmd).arg(&input).arg("--out").arg(&out).args(flags));
        assert!(e.contains(&format!("{}: exists and is not a directory", out.display())), "{cmd}: {e}");
        assert!(!e.contains("in.tif"), "{cmd} read the input first: {e}");
        assert_eq!(std::fs::read(&out).unwrap(), b"mine");
    }
}
