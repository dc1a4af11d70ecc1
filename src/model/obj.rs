//! Wavefront OBJ: `v` positions (extra values such as `w` or vertex colours ignored), `vn`
//! normals, and `f` polygons whose corners are `v`, `v/vt`, `v//vn` or `v/vt/vn`, with 1-based
//! or negative (relative to the vertices read so far) indices. Every other statement (`vt`,
//! `g`, `o`, `s`, `usemtl`, `mtllib`, `l`, `p`, free-form geometry) is ignored: only surfaces
//! are baked.

use super::{Builder, Ctx, MeshError, Model, ModelEncoding, float, int, lines, show, tokens};

/// Decodes an OBJ file's bytes; `name` is used in errors.
pub fn parse(bytes: &[u8], name: &str) -> Result<Model, MeshError> {
    let ctx = Ctx { file: name };
    let mut b = Builder { index_base: 1, ..Builder::default() };
    let mut normals: Vec<[f64; 3]> = Vec::new();
    // (vertex, normal) per corner that names a normal; the largest normal index and its line.
    let mut corner_normals: Vec<[u32; 2]> = Vec::new();
    let mut max_normal: Option<(u32, usize)> = None;
    let mut corners: Vec<u32> = Vec::new();
    for (ln, line) in lines(bytes) {
        let mut tk = tokens(line);
        let Some(kw) = tk.next() else { continue };
        let at = || format!("line {ln}");
        match kw {
            b"v" | b"vn" => {
                let mut p = [0.0; 3];
                for (a, slot) in p.iter_mut().enumerate() {
                    let t = tk.next().ok_or_else(|| {
                        ctx.syntax(at(), format!("`{}` needs 3 coordinates, found {a}", show(kw)))
                    })?;
                    *slot =
                        float(t).ok_or_else(|| ctx.syntax(at(), format!("{} is not a number", show(t))))?;
                }
                let p = ctx.position(at(), p)?;
                if kw == b"v" {
                    b.positions.push(p);
                } else {
                    normals.push(p);
                }
            }
            b"f" => {
                corners.clear();
                for t in tk {
                    let mut parts = t.split(|&c| c == b'/');
                    let v = parts.next().unwrap_or_default();
                    let _texture = parts.next();
                    let n = parts.next().filter(|n| !n.is_empty());
                    let vi = resolve(ctx, ln, v, b.positions.len(), "vertex")?;
                    b.note_index(vi, at);
                    if let Some(n) = n {
                        let ni = resolve(ctx, ln, n, normals.len(), "normal")?;
                        if max_normal.is_none_or(|(m, _)| ni > m) {
                            max_normal = Some((ni, ln));
                        }
                        corner_normals.push([vi, ni]);
                    }
                    corners.push(vi);
                }
                if corners.len() < 3 {
                    return Err(ctx.syntax(at(), format!("a face needs 3 corners, found {}", corners.len())));
                }
                b.polygon(&corners);
            }
            _ => {}
        }
    }
    if let Some((m, ln)) = max_normal
        && m as usize >= normals.len()
    {
        return Err(ctx.syntax(
            format!("line {ln}"),
            format!("normal index {} is out of range ({} normals)", i64::from(m) + 1, normals.len()),
        ));
    }
    b.file_normals = vec![[0.0; 3]; b.positions.len()];
    for [v, n] in corner_normals {
        // Out-of-range vertices are reported by `finish`.
        if let (Some(s), Some(n)) = (b.file_normals.get_mut(v as usize), normals.get(n as usize)) {
            for a in 0..3 {
                s[a] += n[a];
            }
        }
    }
    b.finish(ctx, ModelEncoding::Obj)
}

/// A 1-based or negative (relative) OBJ index → 0-based. Positive indices are range-checked
/// later (a face may name a vertex defined after it); negative ones must land in what was read.
fn resolve(ctx: Ctx<'_>, ln: usize, t: &[u8], count: usize, what: &str) -> Result<u32, MeshError> {
    let at = || format!("line {ln}");
    let i = int(t).ok_or_else(|| ctx.syntax(at(), format!("{what} index {} is not an integer", show(t))))?;
    let resolved = if i > 0 { i - 1 } else { count as i64 + i };
    if i == 0 || resolved < 0 || resolved >= i64::from(u32::MAX) {
        return Err(if what == "vertex" {
            ctx.index(at(), i, count)
        } else {
            ctx.syntax(at(), format!("{what} index {i} is out of range ({count} {what}s so far)"))
        });
    }
    Ok(resolved as u32)
}

#[cfg(test)]
#[allow(clippy::float_cmp)]
mod tests {
    use super::*;

    fn ok(s: &str) -> Model {
        parse(s.as_bytes(), "t.obj").unwrap()
    }

    fn err(s: &str) -> String {
        parse(s.as_bytes(), "t.obj").unwrap_err().to_string()
    }

    #[test]
    fn quad_is_fan_triangulated_and_normals_computed() {
        let m = ok("# quad\nv 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nf 1 2 3 4\n");
        assert_eq!(m.mesh.triangles, vec![[0, 1, 2], [0, 2, 3]]);
        assert_eq!(m.stats.faces, 1);
        assert_eq!(m.stats.normals_from_file, 0);
        assert!(m.normals.iter().all(|n| *n == [0.0, 0.0, 1.0]));
    }

    #[test]
    fn negative_indices_and_slash_forms() {
        let m = ok("v 0 0 0\nv 1 0 0\nv 0 1 0\nvt 0 0\nvn 0 0 -1\nf -3/1/1 -2//1 -1/1\n\
                    v 0 0 1\nf 1/1 2 -1\n");
        assert_eq!(m.mesh.triangles, vec![[0, 1, 2], [0, 1, 3]]);
        // Corners 0 and 1 name the file's normal (pointing down, against the winding); 2 and 3
        // name none, so theirs are computed from the faces.
        assert_eq!(m.stats.normals_from_file, 2);
        assert_eq!(m.normals[0], [0.0, 0.0, -1.0]);
        assert_eq!(m.normals[2], [0.0, 0.0, 1.0]);
    }

    #[test]
    fn crlf_extra_values_and_other_statements() {
        let m = ok(
            "o a\r\ng g\r\nv 0 0 0 1\r\nv 1 0 0 0.5 0.5 0.5\r\nv 0 1 0\r\nusemtl x\r\nl 1 2\r\nf 1 2 3\r\n",
        );
        assert_eq!(m.mesh.triangles.len(), 1);
    }

    #[test]
    fn degenerate_and_unreferenced_are_counted() {
        let m = ok("v 0 0 0\nv 1 0 0\nv 2 0 0\nv 0 1 0\nv 9 9 9\nf 1 2 3\nf 1 1 2\nf 1 2 4\n");
        assert_eq!(m.stats.triangles_read, 3);
        assert_eq!(m.stats.degenerate, 2);
        assert_eq!(m.stats.unreferenced, 2);
        assert_eq!(m.mesh.positions.len(), 3);
        assert_eq!(m.mesh.triangles, vec![[0, 1, 2]]);
    }

    #[test]
    fn malformed_inputs_name_the_line() {
        assert!(err("").contains("empty model"), "{}", err(""));
        assert!(err("v 0 0 0\n").contains("no faces"));
        assert!(err("v 0 0 0\nv 1 1 1\nv 2 2 2\nf 1 2 3\n").contains("degenerate"));
        let e = err("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 4\n");
        assert!(e.contains("line 4") && e.contains("index 4") && e.contains("3 vertices"), "{e}");
        let e = err("v 0 0 0\nv 1 0 0\nf 1 2 -3\n");
        assert!(e.contains("line 3") && e.contains("-3"), "{e}");
        assert!(err("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 0 1 2\n").contains("index 0"));
        let e = err("v 0 0 0\nv 1 nan 0\nv 0 1 0\nf 1 2 3\n");
        assert!(e.contains("line 2") && e.contains("NaN"), "{e}");
        assert!(err("v 0 0 inf\n").contains("not a finite"));
        assert!(err("v 0 0\n").contains("needs 3 coordinates"));
        assert!(err("v 0 x 0\n").contains("\"x\" is not a number"));
        assert!(err("v 0 0 0\nv 1 0 0\nf 1 2\n").contains("3 corners"));
        assert!(err("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1/1/7 2 3\n").contains("normal index 7"));
        assert!(err("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 q\n").contains("not an integer"));
    }

    #[test]
    fn faces_may_precede_vertices() {
        let m = ok("f 1 2 3\nv 0 0 0\nv 1 0 0\nv 0 1 0\n");
        assert_eq!(m.mesh.triangles.len(), 1);
    }
}
