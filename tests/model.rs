//! Standalone models end to end: OBJ, STL and PLY files in every supported encoding through the
//! `terrastream bake-model` binary and the library, malformed files refused with clear errors
//! (and nothing written), and the Stanford Bunny next to the first paper's Table 3.

#![allow(clippy::unwrap_used, clippy::expect_used, clippy::float_cmp)]

mod common;
use common::{bin, fails, ok, tree};

use std::fmt::Write as _;
use std::path::{Path, PathBuf};

use terrastream::bake::model_tileset::{self as bake_model, MODEL_TILE};
use terrastream::codec::{self, Geometry};
use terrastream::model::{self, ModelEncoding};
use terrastream::store::{Store, TilesetKind};

fn bake(model: &Path, out: &Path, extra: &[&str]) -> String {
    ok(bin().arg("bake-model").arg(model).arg("--out").arg(out).args(extra))
}

fn decode(store: &Store, level: u8) -> codec::Blob {
    codec::decode(&store.read_blob(MODEL_TILE, level).unwrap().unwrap()).unwrap()
}

// A unit cube: 8 corners, 6 outward-facing quads (counter-clockwise seen from outside).
const CUBE_V: [[f32; 3]; 8] = [
    [0.0, 0.0, 0.0],
    [1.0, 0.0, 0.0],
    [1.0, 1.0, 0.0],
    [0.0, 1.0, 0.0],
    [0.0, 0.0, 1.0],
    [1.0, 0.0, 1.0],
    [1.0, 1.0, 1.0],
    [0.0, 1.0, 1.0],
];
const CUBE_Q: [[u32; 4]; 6] =
    [[0, 3, 2, 1], [4, 5, 6, 7], [0, 1, 5, 4], [1, 2, 6, 5], [2, 3, 7, 6], [3, 0, 4, 7]];

/// The cube's quads fan-triangulated as every reader does (v0 v1 v2, v0 v2 v3).
fn cube_triangles() -> Vec<[[f32; 3]; 3]> {
    CUBE_Q
        .iter()
        .flat_map(|q| {
            let p = |i: usize| CUBE_V[q[i] as usize];
            [[p(0), p(1), p(2)], [p(0), p(2), p(3)]]
        })
        .collect()
}

fn stl_binary(header: &[u8], tris: &[[[f32; 3]; 3]]) -> Vec<u8> {
    let mut out = vec![0u8; 80];
    out[..header.len()].copy_from_slice(header);
    out.extend_from_slice(&u32::try_from(tris.len()).unwrap().to_le_bytes());
    for t in tris {
        out.extend_from_slice(&[0u8; 12]);
        for c in t {
            for v in c {
                out.extend_from_slice(&v.to_le_bytes());
            }
        }
        out.extend_from_slice(&[0, 0]);
    }
    out
}

fn stl_ascii(tris: &[[[f32; 3]; 3]]) -> String {
    let mut s = String::from("solid cube\n");
    for t in tris {
        s.push_str("facet normal 0 0 0\n  outer loop\n");
        for c in t {
            writeln!(s, "    vertex {:e} {:e} {:e}", c[0], c[1], c[2]).unwrap();
        }
        s.push_str("  endloop\nendfacet\n");
    }
    s.push_str("endsolid cube\n");
    s
}

fn ply_header(format: &str, vertex_ty: &str) -> String {
    format!(
        "ply\nformat {format} 1.0\ncomment a cube of quads\nelement vertex 8\nproperty {vertex_ty} x\n\
         property {vertex_ty} y\nproperty {vertex_ty} z\nproperty uchar red\nelement face 6\n\
         property list uchar int vertex_indices\nend_header\n"
    )
}

fn ply_ascii() -> String {
    let mut s = ply_header("ascii", "float");
    for v in CUBE_V {
        writeln!(s, "{} {} {} 200", v[0], v[1], v[2]).unwrap();
    }
    for q in CUBE_Q {
        writeln!(s, "4 {} {} {} {}", q[0], q[1], q[2], q[3]).unwrap();
    }
    s
}

fn ply_binary(big_endian: bool) -> Vec<u8> {
    let fmt = if big_endian { "binary_big_endian" } else { "binary_little_endian" };
    let mut out = ply_header(fmt, "double").into_bytes();
    let put = |out: &mut Vec<u8>, mut le: Vec<u8>| {
        if big_endian {
            le.reverse();
        }
        out.extend_from_slice(&le);
    };
    for v in CUBE_V {
        for c in v {
            put(&mut out, f64::from(c).to_le_bytes().to_vec());
        }
        out.push(200);
    }
    for q in CUBE_Q {
        out.push(4);
        for i in q {
            put(&mut out, i32::try_from(i).unwrap().to_le_bytes().to_vec());
        }
    }
    out
}

/// The cube as OBJ: vertices, then faces with negative (relative) indices, no normals.
fn obj_negative() -> String {
    let mut s = String::from("# cube\no cube\n");
    for v in CUBE_V {
        writeln!(s, "v {} {} {}", v[0], v[1], v[2]).unwrap();
    }
    s.push_str("vt 0 0\n");
    for q in CUBE_Q {
        s.push('f');
        for i in q {
            // Index i of 8 vertices read so far is -(8 - i); texture index 1 on every corner.
            write!(s, " {}/1", i64::from(i) - 8).unwrap();
        }
        s.push('\n');
    }
    s
}

fn write(dir: &Path, name: &str, bytes: impl AsRef<[u8]>) -> PathBuf {
    let p = dir.join(name);
    std::fs::write(&p, bytes).unwrap();
    p
}

#[test]
fn every_encoding_reads_the_same_cube() {
    let tmp = tempfile::tempdir().unwrap();
    let d = tmp.path();
    let files = [
        (write(d, "neg.obj", obj_negative()), ModelEncoding::Obj),
        (
            write(d, "cube.stl", stl_binary(b"solid but really binary", &cube_triangles())),
            ModelEncoding::StlBinary,
        ),
        (write(d, "ascii.stl", stl_ascii(&cube_triangles())), ModelEncoding::StlAscii),
        (write(d, "cube.ply", ply_ascii()), ModelEncoding::PlyAscii),
        (write(d, "le.ply", ply_binary(false)), ModelEncoding::PlyBinaryLe),
        (write(d, "be.ply", ply_binary(true)), ModelEncoding::PlyBinaryBe),
    ];
    let reference = model::load(&files[0].0).unwrap();
    // OBJ polygons are fan-triangulated; the normals were missing, so they are computed: at a
    // cube corner the area-weighted sum of the adjacent triangles' normals points outward on
    // every axis (not exactly along the diagonal: a fan gives its root corner two triangles).
    assert_eq!(reference.mesh.positions.len(), 8);
    assert_eq!(reference.mesh.triangles.len(), 12);
    assert_eq!(reference.stats.faces, 6);
    assert_eq!(reference.stats.normals_from_file, 0);
    for (p, n) in reference.mesh.positions.iter().zip(&reference.normals) {
        assert!(((n[0] * n[0] + n[1] * n[1] + n[2] * n[2]).sqrt() - 1.0).abs() < 1e-6, "{n:?}");
        for a in 0..3 {
            let outward = if p[a] > 0.5 { 1.0 } else { -1.0 };
            assert!(n[a] * outward > 0.2, "{p:?} {n:?}");
        }
    }
    for (path, encoding) in &files {
        let m = model::load(path).unwrap();
        assert_eq!(m.encoding, *encoding, "{}", path.display());
        // STL welds its corners in order of first appearance, so its vertex order differs;
        // compare the triangles as coordinate triples.
        let tris = |m: &model::Model| {
            let mut t: Vec<[[u64; 3]; 3]> = m
                .mesh
                .triangles
                .iter()
                .map(|t| t.map(|i| m.mesh.positions[i as usize].map(f64::to_bits)))
                .collect();
            t.sort_unstable();
            t
        };
        assert_eq!(tris(&m), tris(&reference), "{}", path.display());
        assert_eq!(m.stats.degenerate, 0);
    }

    // Baked, every encoding gives the same point levels (the same surface: the counts, bytes
    // and errors of every baked level, stored or not — on an 8-vertex cube no point level pays,
    // so none is stored), and the PLY encodings (same vertex order) identical
    // level 0 meshes.
    let mut points: Option<Vec<terrastream::bake::model_tileset::ModelLevel>> = None;
    for (path, _) in &files {
        let out = d.join(format!("ts-{}", path.file_name().unwrap().to_string_lossy()));
        bake(path, &out, &["--resolutions", "12,6"]);
        let store = Store::new(&out);
        let levels = bake_model::read_manifest(&store).unwrap().model.levels[1..].to_vec();
        assert!(levels.iter().all(|l| !l.stored && l.count > 8), "{levels:?}");
        assert_eq!(common::assert_levels_pay(&out), (1, 1, 2));
        match &points {
            None => points = Some(levels),
            Some(p) => assert!(p == &levels, "{} bakes other points", path.display()),
        }
        let m = decode(&store, 0);
        assert_eq!((m.header.vertex_count, m.header.triangle_count), (8, 12));
    }
    let a = Store::new(&d.join("ts-cube.ply")).read_blob(MODEL_TILE, 0).unwrap();
    for name in ["ts-le.ply", "ts-be.ply"] {
        assert_eq!(Store::new(&d.join(name)).read_blob(MODEL_TILE, 0).unwrap(), a, "{name}");
    }
}

#[test]
fn polygons_in_obj_and_ply_are_fan_triangulated() {
    // A flat pentagon and a hexagon sharing an edge, with mixed corner syntax.
    let obj = "v 0 0 0\nv 2 0 0\nv 3 1 0\nv 1 2 0\nv -1 1 0\nv 4 -1 0\nv 5 0 0\nv 5 2 0\n\
               vn 0 0 1\nf 1//1 2//1 3//1 4//1 5//1\nf 2 6 7 8 3\n";
    let m = model::parse(obj.as_bytes(), "p.obj", None).unwrap();
    assert_eq!(m.stats.faces, 2);
    assert_eq!(m.mesh.triangles.len(), 3 + 3);
    assert_eq!(m.mesh.triangles[..3], [[0, 1, 2], [0, 2, 3], [0, 3, 4]]);
    assert_eq!(m.stats.normals_from_file, 5);
    let ply = "ply\nformat ascii 1.0\nelement vertex 5\nproperty float x\nproperty float y\nproperty float z\n\
               element face 1\nproperty list uchar uint vertex_index\nend_header\n\
               0 0 0\n2 0 0\n3 1 0\n1 2 0\n-1 1 0\n5 0 1 2 3 4\n";
    let p = model::parse(ply.as_bytes(), "p.ply", None).unwrap();
    assert_eq!(p.mesh.triangles, vec![[0, 1, 2], [0, 2, 3], [0, 3, 4]]);
    assert!(p.normals.iter().all(|n| (n[2] - 1.0).abs() < 1e-6));
}

#[test]
fn degenerate_triangles_are_skipped_and_counted() {
    let tmp = tempfile::tempdir().unwrap();
    // The cube plus a repeated-corner triangle, a collinear one and an unused vertex.
    let mut obj = obj_negative();
    obj.push_str("v 2 2 2\nv 3 3 3\nf 1 1 2\nf 1 7 9\n");
    let path = write(tmp.path(), "dirty.obj", obj);
    let out = tmp.path().join("ts");
    let stdout = bake(&path, &out, &["--resolutions", "8"]);
    assert!(stdout.contains("14 triangles read, 2 degenerate skipped"), "{stdout}");
    assert!(stdout.contains("10 vertices read, 2 unreferenced dropped"), "{stdout}");
    let m = bake_model::read_manifest(&Store::new(&out)).unwrap();
    assert_eq!(m.model.degenerate_skipped, 2);
    assert_eq!(m.model.unreferenced_dropped, 2);
    assert_eq!((m.model.vertices, m.model.triangles), (8, 12));
    // The dropped vertices do not stretch the bounds.
    assert_eq!(m.tileset.bounds.max.to_array(), [1.0, 1.0, 1.0]);
}

#[test]
fn malformed_models_are_refused_with_clear_errors_and_nothing_written() {
    let tmp = tempfile::tempdir().unwrap();
    let d = tmp.path();
    let stl = stl_binary(b"", &cube_triangles());
    let mut absurd_stl = stl.clone();
    absurd_stl[80..84].copy_from_slice(&u32::MAX.to_le_bytes());
    let mut nan_stl = stl.clone();
    // Facet 5, corner 1, y.
    let at = 84 + 5 * 50 + 12 + 12 + 4;
    nan_stl[at..at + 4].copy_from_slice(&f32::NAN.to_le_bytes());
    let ply = ply_binary(false);
    let cases: Vec<(&str, Vec<u8>, Vec<&str>)> = vec![
        ("empty.obj", Vec::new(), vec!["empty.obj", "empty model"]),
        ("points-only.obj", b"v 0 0 0\nv 1 0 0\n".to_vec(), vec!["empty model", "no faces"]),
        ("cut.stl", stl[..stl.len() - 20].to_vec(), vec!["cut.stl", "truncated", "facet 11", "12 facets"]),
        ("header.stl", stl[..50].to_vec(), vec!["truncated", "84-byte header"]),
        (
            "cut-ascii.stl",
            stl_ascii(&cube_triangles()).split_inclusive('\n').take(20).collect::<String>().into_bytes(),
            vec!["truncated", "line 20", "endsolid"],
        ),
        ("cut.ply", ply[..ply.len() - 5].to_vec(), vec!["cut.ply", "truncated", "element face 5"]),
        (
            "absurd.stl",
            absurd_stl,
            vec!["absurd.stl", "declares 4294967295 facets", "refusing it before allocating"],
        ),
        (
            "absurd.ply",
            ply_ascii().replace("element vertex 8", "element vertex 3000000000").into_bytes(),
            vec!["absurd.ply", "3000000000 vertex elements", "before allocating"],
        ),
        (
            "absurd-face.ply",
            ply_ascii().replace("element face 6", "element face 4000000000").into_bytes(),
            vec!["4000000000 face elements", "before allocating"],
        ),
        (
            "range.obj",
            b"v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 4\n".to_vec(),
            vec!["line 4", "vertex index 4", "3 vertices"],
        ),
        ("neg.obj", b"v 0 0 0\nv 1 0 0\nf -3 1 2\n".to_vec(), vec!["line 3", "vertex index -3"]),
        (
            "range.ply",
            ply_ascii().replace("4 3 0 4 7", "4 3 0 4 8").into_bytes(),
            vec!["element face 5", "vertex index 8", "8 vertices"],
        ),
        (
            "nan.obj",
            b"v 0 0 0\nv 1 NaN 0\nv 0 1 0\nf 1 2 3\n".to_vec(),
            vec!["line 2", "NaN", "not a finite"],
        ),
        ("nan.stl", nan_stl, vec!["facet 5", "NaN"]),
        (
            "inf.ply",
            ply_ascii().replace("1 1 0 200", "1 inf 0 200").into_bytes(),
            vec!["element vertex 2", "inf", "not a finite"],
        ),
        (
            "flat.obj",
            b"v 0 0 0\nv 1 1 1\nv 2 2 2\nf 1 2 3\n".to_vec(),
            vec!["all 1 triangles are degenerate"],
        ),
        ("garbage.bin", vec![0, 1, 2, 3, 255], vec!["garbage.bin", "cannot tell the model format"]),
    ];
    for (name, bytes, expect) in cases {
        let path = write(d, name, &bytes);
        let out = d.join(format!("out-{name}"));
        let stderr = fails(bin().arg("bake-model").arg(&path).arg("--out").arg(&out));
        for e in expect {
            assert!(stderr.contains(e), "{name}: expected {e:?} in: {stderr}");
        }
        assert_eq!(stderr.lines().count(), 1, "{name}: one line: {stderr}");
        assert!(!out.exists(), "{name}: nothing may be written");
    }
    let stderr = fails(bin().arg("bake-model").arg(d.join("missing.obj")).arg("--out").arg(d.join("o")));
    assert!(stderr.contains("missing.obj"), "{stderr}");
    let stderr = fails(
        bin()
            .arg("bake-model")
            .arg(write(d, "ok.obj", obj_negative()))
            .args(["--resolutions", "8,16", "--out"])
            .arg(d.join("o")),
    );
    assert!(stderr.contains("must decrease"), "{stderr}");
    let stderr = fails(
        bin()
            .arg("bake-model")
            .arg(d.join("ok.obj"))
            .args(["--levels", "5", "--resolution", "4", "--out"])
            .arg(d.join("o")),
    );
    assert!(stderr.contains("too small for 5 distinct levels"), "{stderr}");
    assert!(!d.join("o").exists());
}

/// The first paper's Table 3: the bunny's vertex count, then its four point levels.
const PAPER_BUNNY: [u32; 5] = [14_904, 12_654, 7_092, 3_191, 800];

#[test]
fn stanford_bunny_next_to_the_papers_table_3() {
    let Some(bunny) =
        common::shared("stanford-bunny.obj", "model::stanford_bunny_next_to_the_papers_table_3")
    else {
        return;
    };
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("bunny");
    let stdout = bake(&bunny, &out, &[]);
    let store = Store::new(&out);
    assert_eq!(store.manifest_kind().unwrap(), TilesetKind::Model);
    let m = bake_model::read_manifest(&store).unwrap();
    let levels = &m.model.levels;
    println!("{stdout}");
    println!("level  T   paper  ours   max err   gap   (bunny extent {:?})", m.tileset.bounds.size());
    for (l, info) in levels.iter().enumerate() {
        println!(
            "{l}  {:>3}  {:>6}  {:>6}  {:.3e}  {:.3e}",
            info.resolution.unwrap_or(0),
            PAPER_BUNNY[l],
            info.count,
            info.errors.max,
            info.errors.gap
        );
    }
    // Level 0 is the whole scan (the paper's 14,904-vertex bunny is a reduced version): every
    // triangle, every vertex a triangle uses.
    assert_eq!(levels.len(), 5);
    assert_eq!((m.model.vertices_read, m.model.triangles_read), (35_947, 69_451));
    assert_eq!(levels[0].triangles, 69_451);
    assert_eq!(u64::from(levels[0].count), m.model.vertices_read - m.model.unreferenced_dropped);
    // The default ladder's point counts land within 5 % of the paper's.
    for l in 1..5 {
        let ours = f64::from(levels[l].count);
        let paper = f64::from(PAPER_BUNNY[l]);
        assert!((ours / paper - 1.0).abs() < 0.05, "level {l}: {ours} points vs the paper's {paper}");
    }
    // Measured errors: level 0 only by its quantization; the points within a cell of the surface
    // and no hole wider than a few cells.
    assert!(levels[0].errors.max > 0.0 && levels[0].errors.max < levels[0].quant_step);
    for info in &levels[1..] {
        let cell = info.cell.unwrap();
        assert!(info.errors.max > 0.0 && info.errors.max < cell, "{info:?}");
        assert!(info.errors.gap > 0.0 && info.errors.gap < 2.0 * cell, "{info:?}");
    }
    // Only levels that pay are stored (issue 13); blobs hold what the manifest says, and
    // points carry unit normals.
    let (_, stored, left_out) = common::assert_levels_pay(&out);
    assert_eq!(stored + left_out, 5);
    assert_eq!(stored, levels.iter().filter(|l| l.stored).count());
    for info in levels.iter().filter(|l| l.stored) {
        let blob = decode(&store, info.level);
        assert_eq!(blob.header.vertex_count, info.count);
        assert_eq!(blob.header.errors, info.errors);
        if let Geometry::Points(p) = &blob.geometry {
            assert!(
                p.normals
                    .iter()
                    .all(|n| ((n[0] * n[0] + n[1] * n[1] + n[2] * n[2]).sqrt() - 1.0).abs() < 1e-2)
            );
        }
    }

    // Deterministic: a second bake is byte-identical; a rerun in place rewrites the same bytes.
    let again = tmp.path().join("again");
    bake(&bunny, &again, &[]);
    let (a, b) = (tree(&out), tree(&again));
    assert_eq!(a.keys().collect::<Vec<_>>(), b.keys().collect::<Vec<_>>());
    for (k, v) in &a {
        assert!(v == &b[k], "{k} differs between two bakes");
    }
    bake(&bunny, &out, &[]);
    assert!(tree(&out) == a);

    // Other options into the same directory, or a terrain bake into it, are refused.
    let e = fails(bin().arg("bake-model").arg(&bunny).args(["--resolution", "40", "--out"]).arg(&out));
    assert!(e.contains("different options") && e.contains("resolutions"), "{e}");
    let fuji = common::fuji_or_generated(tmp.path(), "model: a terrain bake into a model tileset");
    let e = fails(bin().args(["bake", "--quiet", "--encoding", "terrain-rgb", "--out"]).arg(&out).arg(fuji));
    assert!(e.contains("different options"), "{e}");
    assert!(tree(&out) == a);

    // inspect and export work on the model tileset.
    let text = ok(bin().arg("inspect").arg(&out));
    assert!(text.contains("model stanford-bunny.obj") && text.contains("69451"), "{text}");
    let json: serde_json::Value =
        serde_json::from_str(&ok(bin().arg("inspect").arg(&out).arg("--json"))).unwrap();
    assert_eq!(json["kind"], "model");
    assert_eq!(json["model"]["levels"][1]["count"], levels[1].count);
    let ply = tmp.path().join("l2.ply");
    let text = ok(bin().arg("export").arg(&out).args(["--tile", "0/0/0", "--level", "2", "--out"]).arg(&ply));
    assert!(text.contains(&format!("{} points", levels[2].count)), "{text}");
    // The exported level reads back through the model reader (no faces: a point cloud is not
    // a model), and the exported mesh does.
    let e = model::load(&ply).unwrap_err().to_string();
    assert!(e.contains("no faces"), "{e}");
    let obj = tmp.path().join("l0.obj");
    ok(bin()
        .arg("export")
        .arg(&out)
        .args(["--tile", "0/0/0", "--level", "0", "--format", "obj", "--out"])
        .arg(&obj));
    let back = model::load(&obj).unwrap();
    assert_eq!((back.mesh.positions.len(), back.mesh.triangles.len()), (levels[0].count as usize, 69_451));
    let e = fails(bin().arg("export").arg(&out).args(["--tile", "0/0/0", "--level", "9", "--out"]).arg(&obj));
    assert!(e.contains("no tile 0/0/0 level 9"), "{e}");
}

/// What `stanford_bunny_next_to_the_papers_table_3` checks besides the paper's figures, on a
/// generated model (`common::write_model_obj`), so that a clone without the shared data runs
/// the same paths: the ladder and its measured errors, levels that pay, determinism, refusals,
/// inspect and export.
#[test]
fn generated_model_bakes_inspects_and_exports_like_the_bunny() {
    const VERTICES: u64 = 2 + 99 * 200;
    const TRIANGLES: u64 = 2 * 200 + 98 * 200 * 2;
    let tmp = tempfile::tempdir().unwrap();
    let src = tmp.path().join("generated-model.obj");
    common::write_model_obj(&src);
    let out = tmp.path().join("m");
    bake(&src, &out, &[]);
    let store = Store::new(&out);
    assert_eq!(store.manifest_kind().unwrap(), TilesetKind::Model);
    let m = bake_model::read_manifest(&store).unwrap();
    let levels = &m.model.levels;
    assert_eq!(levels.len(), 5);
    assert_eq!((m.model.vertices_read, m.model.triangles_read), (VERTICES, TRIANGLES));
    assert_eq!(u64::from(levels[0].triangles), TRIANGLES);
    assert_eq!(u64::from(levels[0].count), m.model.vertices_read - m.model.unreferenced_dropped);
    assert!(levels[0].errors.max > 0.0 && levels[0].errors.max < levels[0].quant_step);
    for (l, info) in levels.iter().enumerate().skip(1) {
        assert!(info.count < levels[l - 1].count, "{info:?}");
        let cell = info.cell.unwrap();
        assert!(info.errors.max > 0.0 && info.errors.max < cell, "{info:?}");
        assert!(info.errors.gap > 0.0 && info.errors.gap < 2.0 * cell, "{info:?}");
    }
    let (_, stored, left_out) = common::assert_levels_pay(&out);
    assert_eq!(stored + left_out, 5);
    assert_eq!(stored, levels.iter().filter(|l| l.stored).count());
    for info in levels.iter().filter(|l| l.stored) {
        let blob = decode(&store, info.level);
        assert_eq!(blob.header.vertex_count, info.count);
        assert_eq!(blob.header.errors, info.errors);
    }

    // Deterministic; a rerun in place rewrites the same bytes.
    let again = tmp.path().join("again");
    bake(&src, &again, &[]);
    let a = tree(&out);
    assert!(tree(&again) == a, "two bakes differ");
    bake(&src, &out, &[]);
    assert!(tree(&out) == a);

    // Other options into the same directory, or a terrain bake into it, are refused.
    let e = fails(bin().arg("bake-model").arg(&src).args(["--resolution", "40", "--out"]).arg(&out));
    assert!(e.contains("different options") && e.contains("resolutions"), "{e}");
    let png = tmp.path().join("terrain-rgb.png");
    common::write_terrain_rgb_png(&png, 65, 65, 1);
    let e = fails(bin().args(["bake", "--quiet", "--encoding", "terrain-rgb", "--out"]).arg(&out).arg(&png));
    assert!(e.contains("different options"), "{e}");
    assert!(tree(&out) == a);

    // inspect and export.
    let text = ok(bin().arg("inspect").arg(&out));
    assert!(text.contains("model generated-model.obj") && text.contains(&TRIANGLES.to_string()), "{text}");
    let json: serde_json::Value =
        serde_json::from_str(&ok(bin().arg("inspect").arg(&out).arg("--json"))).unwrap();
    assert_eq!(json["kind"], "model");
    assert_eq!(json["model"]["levels"][1]["count"], levels[1].count);
    let stored_point_level = levels.iter().skip(1).find(|l| l.stored).unwrap().level;
    let ply = tmp.path().join("points.ply");
    let text = ok(bin()
        .arg("export")
        .arg(&out)
        .args(["--tile", "0/0/0", "--level", &stored_point_level.to_string(), "--out"])
        .arg(&ply));
    let count = levels[usize::from(stored_point_level)].count;
    assert!(text.contains(&format!("{count} points")), "{text}");
    let e = model::load(&ply).unwrap_err().to_string();
    assert!(e.contains("no faces"), "{e}");
    let obj = tmp.path().join("l0.obj");
    ok(bin()
        .arg("export")
        .arg(&out)
        .args(["--tile", "0/0/0", "--level", "0", "--format", "obj", "--out"])
        .arg(&obj));
    let back = model::load(&obj).unwrap();
    assert_eq!(
        (back.mesh.positions.len() as u64, back.mesh.triangles.len() as u64),
        (u64::from(levels[0].count), TRIANGLES)
    );
}
