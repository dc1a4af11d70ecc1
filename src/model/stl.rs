//! STL, binary and ASCII. STL stores every facet's three corners on their own, so corners with
//! bit-identical coordinates are welded into one vertex (in order of first appearance): the
//! bake's rasterization relies on triangles sharing edges by index, and the level 0 mesh is
//! stored indexed. The facet normals are not used (many writers leave them zero); vertex
//! normals are computed from the welded mesh.
//!
//! # Telling binary from ASCII
//!
//! A binary STL's 80-byte header may itself start with `solid` (many exporters write it), so
//! the first five bytes decide nothing. A file is binary when its size is exactly
//! `84 + 50 · n` for the facet count `n` at bytes 80..84; failing that, text that starts with
//! `solid` and has no NUL byte in its first 512 bytes is ASCII; anything else is read as binary
//! and reported truncated when shorter than its facet count says.

use std::collections::HashMap;

use super::{Builder, Ctx, MeshError, Model, ModelEncoding, float, lines, show, tokens};

const HEADER: usize = 80;
const FACET: usize = 50;

/// Whether `bytes` is a binary STL by its exact size.
#[must_use]
pub fn is_binary(bytes: &[u8]) -> bool {
    facet_count(bytes)
        .is_some_and(|n| (HEADER + 4) as u64 + FACET as u64 * u64::from(n) == bytes.len() as u64)
}

/// Whether `bytes` looks like an ASCII STL: `solid` first (after blanks) and no NUL early on.
#[must_use]
pub fn looks_ascii(bytes: &[u8]) -> bool {
    bytes.trim_ascii_start().starts_with(b"solid") && !bytes[..bytes.len().min(512)].contains(&0)
}

fn facet_count(bytes: &[u8]) -> Option<u32> {
    let b = bytes.get(HEADER..HEADER + 4)?;
    Some(u32::from_le_bytes([b[0], b[1], b[2], b[3]]))
}

/// Decodes an STL file's bytes (binary or ASCII, see the module doc); `name` is used in errors.
pub fn parse(bytes: &[u8], name: &str) -> Result<Model, MeshError> {
    let ctx = Ctx { file: name };
    if !is_binary(bytes) && looks_ascii(bytes) { parse_ascii(bytes, ctx) } else { parse_binary(bytes, ctx) }
}

/// Welds corners by their exact coordinates (−0 and +0 as one).
#[derive(Default)]
struct Welder {
    b: Builder,
    index: HashMap<[u64; 3], u32>,
}

impl Welder {
    fn vertex(&mut self, p: [f64; 3]) -> u32 {
        let key = p.map(|v| (v + 0.0).to_bits());
        let next = self.b.positions.len() as u32;
        let b = &mut self.b;
        *self.index.entry(key).or_insert_with(|| {
            b.positions.push(p);
            next
        })
    }
}

fn parse_binary(bytes: &[u8], ctx: Ctx<'_>) -> Result<Model, MeshError> {
    let Some(n) = facet_count(bytes) else {
        return Err(ctx.truncated(
            "header",
            format!(
                "{} bytes; a binary STL has an 84-byte header (and an ASCII one starts with `solid`)",
                bytes.len()
            ),
        ));
    };
    let available = (bytes.len() - HEADER - 4) as u64;
    let needed = FACET as u64 * u64::from(n);
    if needed > available {
        // Short by less than a facet is a cut-off file; short by more, an absurd count: both
        // are refused before allocating for `n` facets.
        return Err(if needed - available < FACET as u64 * 2 && available > 0 {
            ctx.truncated(
                format!("facet {}", available / FACET as u64),
                format!("the header declares {n} facets ({needed} bytes) but {available} bytes follow it"),
            )
        } else {
            ctx.absurd("header", "facets", u64::from(n), u128::from(needed), available)
        });
    }
    if needed < available {
        tracing::warn!(
            "{}: {} bytes after the {n} facets the header declares; ignored",
            ctx.file,
            available - needed
        );
    }
    let mut w = Welder::default();
    w.b.positions.reserve(n as usize / 2);
    w.b.triangles.reserve(n as usize);
    let body = &bytes[HEADER + 4..HEADER + 4 + FACET * n as usize];
    for (f, facet) in body.chunks_exact(FACET).enumerate() {
        let mut tri = [0u32; 3];
        for (c, slot) in tri.iter_mut().enumerate() {
            let at = 12 + 12 * c;
            let p: [f64; 3] = std::array::from_fn(|a| {
                let o = at + 4 * a;
                f64::from(f32::from_le_bytes([facet[o], facet[o + 1], facet[o + 2], facet[o + 3]]))
            });
            let p = ctx.position(format!("facet {f}"), p)?;
            *slot = w.vertex(p);
        }
        w.b.polygon(&tri);
    }
    w.b.finish(ctx, ModelEncoding::StlBinary)
}

fn parse_ascii(bytes: &[u8], ctx: Ctx<'_>) -> Result<Model, MeshError> {
    #[derive(PartialEq)]
    enum State {
        Outside,
        InSolid,
        Facet,
        Loop,
        EndLoop,
    }
    let mut w = Welder::default();
    let mut state = State::Outside;
    let mut corners: Vec<u32> = Vec::new();
    let mut solids = 0usize;
    let mut last = 0usize;
    for (ln, line) in lines(bytes) {
        let at = || format!("line {ln}");
        let mut tk = tokens(line);
        let Some(kw) = tk.next() else { continue };
        // The last line with content: the one a truncation error points at.
        last = ln;
        let expect = |what: &str| ctx.syntax(at(), format!("expected {what}, found {}", show(kw)));
        match (&state, kw) {
            (State::Outside, b"solid") => {
                state = State::InSolid;
                solids += 1;
            }
            (State::InSolid, b"facet") => {
                // `normal nx ny nz` follows; checked for syntax, not used.
                if tk.next() != Some(b"normal".as_slice()) {
                    return Err(ctx.syntax(at(), "expected `facet normal nx ny nz`"));
                }
                for t in tk.by_ref().take(3) {
                    float(t).ok_or_else(|| ctx.syntax(at(), format!("{} is not a number", show(t))))?;
                }
                state = State::Facet;
            }
            (State::InSolid, b"endsolid") => state = State::Outside,
            (State::Facet, b"outer") => {
                if tk.next() != Some(b"loop".as_slice()) {
                    return Err(ctx.syntax(at(), "expected `outer loop`"));
                }
                corners.clear();
                state = State::Loop;
            }
            (State::Loop, b"vertex") => {
                let mut p = [0.0; 3];
                for (a, slot) in p.iter_mut().enumerate() {
                    let t = tk.next().ok_or_else(|| {
                        ctx.syntax(at(), format!("`vertex` needs 3 coordinates, found {a}"))
                    })?;
                    *slot =
                        float(t).ok_or_else(|| ctx.syntax(at(), format!("{} is not a number", show(t))))?;
                }
                let p = ctx.position(at(), p)?;
                corners.push(w.vertex(p));
            }
            (State::Loop, b"endloop") => {
                if corners.len() < 3 {
                    return Err(
                        ctx.syntax(at(), format!("a facet needs 3 vertices, found {}", corners.len()))
                    );
                }
                w.b.polygon(&corners);
                state = State::EndLoop;
            }
            (State::EndLoop, b"endfacet") => state = State::InSolid,
            (State::Outside, _) => return Err(expect("`solid`")),
            (State::InSolid, _) => return Err(expect("`facet` or `endsolid`")),
            (State::Facet, _) => return Err(expect("`outer loop`")),
            (State::Loop, _) => return Err(expect("`vertex` or `endloop`")),
            (State::EndLoop, _) => return Err(expect("`endfacet`")),
        }
    }
    if state != State::Outside || solids == 0 {
        return Err(ctx.truncated(format!("line {last}"), "the file ends before `endsolid`"));
    }
    w.b.finish(ctx, ModelEncoding::StlAscii)
}

#[cfg(test)]
#[allow(clippy::float_cmp)]
mod tests {
    use std::fmt::Write as _;

    use super::*;

    /// A binary STL of `tris`, with `header` at the start of the 80-byte header.
    pub(crate) fn binary(header: &[u8], tris: &[[[f32; 3]; 3]]) -> Vec<u8> {
        let mut out = vec![0u8; HEADER];
        out[..header.len()].copy_from_slice(header);
        out.extend_from_slice(&(tris.len() as u32).to_le_bytes());
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

    const TET: [[[f32; 3]; 3]; 4] = [
        [[0.0, 0.0, 0.0], [0.0, 1.0, 0.0], [1.0, 0.0, 0.0]],
        [[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]],
        [[0.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, 1.0, 0.0]],
        [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]],
    ];

    fn ascii(tris: &[[[f32; 3]; 3]]) -> String {
        let mut s = String::from("solid tet\n");
        for t in tris {
            s.push_str("  facet normal 0 0 0\n    outer loop\n");
            for c in t {
                let _ = writeln!(s, "      vertex {} {} {}", c[0], c[1], c[2]);
            }
            s.push_str("    endloop\n  endfacet\n");
        }
        s.push_str("endsolid tet\n");
        s
    }

    #[test]
    fn binary_welds_corners_even_with_a_solid_header() {
        for header in [b"binary".as_slice(), b"solid exported by a CAD tool".as_slice()] {
            let m = parse(&binary(header, &TET), "t.stl").unwrap();
            assert_eq!(m.encoding, ModelEncoding::StlBinary);
            assert_eq!(m.mesh.positions.len(), 4);
            assert_eq!(m.mesh.triangles.len(), 4);
            assert_eq!(m.stats.faces, 4);
        }
    }

    #[test]
    fn ascii_matches_binary() {
        let a = parse(ascii(&TET).as_bytes(), "t.stl").unwrap();
        let b = parse(&binary(b"", &TET), "t.stl").unwrap();
        assert_eq!(a.encoding, ModelEncoding::StlAscii);
        assert_eq!(a.mesh, b.mesh);
        assert_eq!(a.normals, b.normals);
    }

    #[test]
    fn negative_zero_welds_with_zero() {
        let mut t = TET;
        t[3][0] = [1.0, -0.0, 0.0];
        assert_eq!(parse(&binary(b"", &t), "t.stl").unwrap().mesh.positions.len(), 4);
    }

    #[test]
    fn degenerate_facets_are_counted() {
        let mut t = TET.to_vec();
        t.push([[0.0, 0.0, 0.0], [1.0, 1.0, 1.0], [2.0, 2.0, 2.0]]);
        t.push([[0.0, 0.0, 0.0], [0.0, 0.0, 0.0], [2.0, 2.0, 2.0]]);
        let m = parse(&binary(b"", &t), "t.stl").unwrap();
        assert_eq!(m.stats.degenerate, 2);
        assert_eq!(m.stats.unreferenced, 2);
        assert_eq!(m.mesh.triangles.len(), 4);
    }

    #[test]
    fn malformed_binary() {
        let full = binary(b"", &TET);
        let e = parse(&full[..full.len() - 7], "t.stl").unwrap_err().to_string();
        assert!(e.contains("truncated") && e.contains("facet 3") && e.contains("4 facets"), "{e}");
        let e = parse(&full[..40], "t.stl").unwrap_err().to_string();
        assert!(e.contains("84-byte header"), "{e}");
        let mut absurd = full.clone();
        absurd[80..84].copy_from_slice(&u32::MAX.to_le_bytes());
        let e = parse(&absurd, "t.stl").unwrap_err().to_string();
        assert!(e.contains("declares 4294967295 facets") && e.contains("before allocating"), "{e}");
        let e = parse(&binary(b"", &[]), "t.stl").unwrap_err().to_string();
        assert!(e.contains("empty model"), "{e}");
        let mut nan = TET;
        nan[2][1][1] = f32::NAN;
        let e = parse(&binary(b"", &nan), "t.stl").unwrap_err().to_string();
        assert!(e.contains("facet 2") && e.contains("NaN"), "{e}");
    }

    #[test]
    fn malformed_ascii() {
        let good = ascii(&TET);
        let cut = &good[..good.len() / 2];
        let e = parse(cut.as_bytes(), "t.stl").unwrap_err().to_string();
        assert!(e.contains("truncated") && e.contains("endsolid"), "{e}");
        let e = parse(good.replace("endloop", "endlop").as_bytes(), "t.stl").unwrap_err().to_string();
        assert!(e.contains("line 7") && e.contains("endlop"), "{e}");
        let e = parse(good.replacen("vertex 0 1 0", "vertex 0 inf 0", 1).as_bytes(), "t.stl")
            .unwrap_err()
            .to_string();
        assert!(e.contains("not a finite"), "{e}");
        let e = parse(b"solid x\nendsolid x\n", "t.stl").unwrap_err().to_string();
        assert!(e.contains("no faces"), "{e}");
        let two = good.replacen("vertex 1 0 0", "", 1);
        let e = parse(two.as_bytes(), "t.stl").unwrap_err().to_string();
        assert!(e.contains("needs 3 vertices"), "{e}");
    }
}
