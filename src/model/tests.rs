//! Cross-format tests: sniffing, and arbitrary or mutated bytes never panic in any parser.

#![allow(clippy::float_cmp)]

use proptest::prelude::*;

use super::*;

const OBJ: &str = "v 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 1\nvn 0 0 1\nf 1 3 2\nf 1 2 4\nf 1//1 4 3\nf 2 3 4\n";
const PLY: &str = "ply\nformat ascii 1.0\nelement vertex 4\nproperty float x\nproperty float y\n\
                   property float z\nelement face 2\nproperty list uchar int vertex_indices\nend_header\n\
                   0 0 0\n1 0 0\n0 1 0\n0 0 1\n4 0 2 1 3\n3 0 1 3\n";
const STL: &str = "solid s\nfacet normal 0 0 0\nouter loop\nvertex 0 0 0\nvertex 0 1 0\nvertex 1 0 0\n\
                   endloop\nendfacet\nendsolid s\n";

/// A little-endian binary PLY with a float vertex and a uint index list.
fn binary_ply() -> Vec<u8> {
    let mut out = b"ply\nformat binary_little_endian 1.0\nelement vertex 3\nproperty float x\n\
                   property float y\nproperty float z\nelement face 1\n\
                   property list uchar uint vertex_indices\nend_header\n"
        .to_vec();
    for v in [[0f32, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]] {
        for c in v {
            out.extend_from_slice(&c.to_le_bytes());
        }
    }
    out.push(3);
    for i in 0u32..3 {
        out.extend_from_slice(&i.to_le_bytes());
    }
    out
}

fn binary_stl() -> Vec<u8> {
    let mut out = b"solid but binary".to_vec();
    out.resize(80, 0);
    out.extend_from_slice(&2u32.to_le_bytes());
    for t in [
        [[0f32, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]],
        [[0.0, 0.0, 0.0], [0.0, 0.0, 1.0], [1.0, 0.0, 0.0]],
    ] {
        out.extend_from_slice(&[0; 12]);
        for c in t {
            for v in c {
                out.extend_from_slice(&v.to_le_bytes());
            }
        }
        out.extend_from_slice(&[0, 0]);
    }
    out
}

#[test]
fn sniffing_without_an_extension() {
    assert_eq!(sniff(OBJ.as_bytes()), Some(FileType::Obj));
    assert_eq!(sniff(PLY.as_bytes()), Some(FileType::Ply));
    assert_eq!(sniff(STL.as_bytes()), Some(FileType::Stl));
    assert_eq!(sniff(&binary_stl()), Some(FileType::Stl));
    assert_eq!(sniff(b"\x00\x01 hello"), None);
    let e = parse(b"\x00\x01 hello", "x.dat", None).unwrap_err().to_string();
    assert!(e.contains("x.dat") && e.contains("\"dat\""), "{e}");
    for (bytes, enc) in [
        (OBJ.as_bytes().to_vec(), ModelEncoding::Obj),
        (PLY.as_bytes().to_vec(), ModelEncoding::PlyAscii),
        (STL.as_bytes().to_vec(), ModelEncoding::StlAscii),
        (binary_stl(), ModelEncoding::StlBinary),
        (binary_ply(), ModelEncoding::PlyBinaryLe),
    ] {
        assert_eq!(parse(&bytes, "model", None).unwrap().encoding, enc);
    }
}

#[test]
fn load_names_the_file() {
    let dir = tempfile::tempdir().unwrap();
    let missing = dir.path().join("nope.obj");
    let e = load(&missing).unwrap_err().to_string();
    assert!(e.contains("nope.obj"), "{e}");
    let p = dir.path().join("tet.OBJ");
    std::fs::write(&p, OBJ).unwrap();
    let m = load(&p).unwrap();
    assert_eq!((m.mesh.positions.len(), m.mesh.triangles.len()), (4, 4));
    let bad = dir.path().join("bad.obj");
    std::fs::write(&bad, "v 0 0 0\nf 1 2 3\n").unwrap();
    let e = load(&bad).unwrap_err().to_string();
    assert!(e.contains("bad.obj") && e.contains("line 2"), "{e}");
}

#[test]
fn normals_are_unit_and_outward_on_a_closed_tetrahedron() {
    let m = parse(OBJ.as_bytes(), "t.obj", None).unwrap();
    // Vertex 3 (0,0,1) has no file normal: computed from its faces, it points away from the
    // centroid.
    let n = m.normals[3];
    let len = (n[0] * n[0] + n[1] * n[1] + n[2] * n[2]).sqrt();
    assert!((len - 1.0).abs() < 1e-6);
    assert!(n[2] > 0.0, "{n:?}");
    assert_eq!(m.normals[0], [0.0, 0.0, 1.0]);
    assert_eq!(m.stats.normals_from_file, 1);
}

fn samples() -> Vec<Vec<u8>> {
    vec![
        OBJ.as_bytes().to_vec(),
        PLY.as_bytes().to_vec(),
        STL.as_bytes().to_vec(),
        binary_stl(),
        binary_ply(),
    ]
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(256))]

    #[test]
    fn random_bytes_never_panic(bytes in proptest::collection::vec(any::<u8>(), 0..600), prefix in 0usize..4) {
        let mut b = match prefix {
            0 => b"ply\n".to_vec(),
            1 => b"solid ".to_vec(),
            2 => b"v 1 2 3\nf ".to_vec(),
            _ => Vec::new(),
        };
        b.extend_from_slice(&bytes);
        for ty in [None, Some(FileType::Obj), Some(FileType::Stl), Some(FileType::Ply)] {
            let _ = parse(&b, "fuzz", ty);
        }
    }

    #[test]
    fn mutated_models_never_panic(
        which in 0usize..5,
        edits in proptest::collection::vec((any::<prop::sample::Index>(), any::<u8>(), 0u8..3), 1..8),
        cut in any::<prop::sample::Index>(),
        truncate in any::<bool>(),
    ) {
        let mut b = samples().swap_remove(which);
        for (at, byte, op) in edits {
            if b.is_empty() {
                break;
            }
            let i = at.index(b.len());
            match op {
                0 => b[i] = byte,
                1 => b.insert(i, byte),
                _ => { b.remove(i); }
            }
        }
        if truncate && !b.is_empty() {
            b.truncate(cut.index(b.len()));
        }
        for ty in [None, Some(FileType::Obj), Some(FileType::Stl), Some(FileType::Ply)] {
            if let Ok(m) = parse(&b, "fuzz", ty) {
                // Whatever parses is a valid mesh.
                prop_assert!(!m.mesh.triangles.is_empty());
                prop_assert_eq!(m.normals.len(), m.mesh.positions.len());
                let n = m.mesh.positions.len() as u32;
                prop_assert!(m.mesh.triangles.iter().flatten().all(|&i| i < n));
                prop_assert!(m.mesh.positions.iter().flatten().all(|v| v.is_finite()));
            }
        }
    }
}

/// A device is refused unread (`/dev/zero` used to be read until memory ran out), a file over
/// the limit before reading (sparse here: nothing to read), and a pipe is read as a file is.
#[test]
fn model_files_are_bounded_and_devices_refused() {
    let dir = tempfile::tempdir().unwrap();
    let zero = dir.path().join("zero.obj");
    std::os::unix::fs::symlink("/dev/zero", &zero).unwrap();
    let e = load(&zero).unwrap_err().to_string();
    assert!(e.contains("zero.obj: is a character device, not a model file"), "{e}");
    let e = load(dir.path()).unwrap_err().to_string();
    assert!(e.contains("is a directory, not a model file"), "{e}");
    let big = dir.path().join("big.obj");
    std::fs::File::create(&big).unwrap().set_len(MAX_MODEL_FILE_BYTES + 1).unwrap();
    let e = load(&big).unwrap_err().to_string();
    assert!(e.contains("big.obj: 4294967297 bytes; a model file is at most 4294967296 bytes"), "{e}");
    let small = dir.path().join("small.obj");
    std::fs::write(&small, OBJ).unwrap();
    let e = read_file(&small, 10).unwrap_err().to_string();
    assert!(e.contains("small.obj") && e.contains("at most 10 bytes"), "{e}");
    let fifo = dir.path().join("pipe.obj");
    if std::process::Command::new("mkfifo").arg(&fifo).status().is_ok_and(|s| s.success()) {
        let f2 = fifo.clone();
        let writer = std::thread::spawn(move || std::fs::write(f2, OBJ).unwrap());
        assert_eq!(load(&fifo).unwrap().mesh.triangles.len(), 4);
        writer.join().unwrap();
    }
}
