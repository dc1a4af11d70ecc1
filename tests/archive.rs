//! Single-file archives (`terrastream pack`): a packed tileset reads and serves byte-identical
//! to its directory; the archive is refused with a clear error when the tileset is unfinished,
//! the name is wrong or the file is damaged; `inspect` and `export` read archives.

#![allow(clippy::unwrap_used, clippy::panic)]

mod common;

use std::path::Path;

use common::{assert_same_responses, bin, fails, ok, serve, tileset_urls, tree};

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
    let mut c = bin();
    c.arg("serve").arg("--store").arg(ts.parent().unwrap());
    let dir_srv = serve(c);
    let mut c = bin();
    c.arg("serve").arg("--store").arg(&packed);
    let tsa_srv = serve(c);
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
