//! PLY (Stanford polygon format): `ascii`, `binary_little_endian` and `binary_big_endian`.
//!
//! Used: the `vertex` element's `x y z` (any scalar type) and optional `nx ny nz`, and the
//! `face` element's `vertex_indices` (or `vertex_index`) list, triangles or polygons. Every
//! other element and property (colours, texture coordinates, confidence, `edge`, `material`,
//! lists of any type) is skipped by its declared type. Before anything is allocated, the header's
//! element counts are checked against the bytes that follow it: each element needs at least
//! its fixed-size properties' bytes (binary) or one byte per property (ASCII), and each list
//! its length times its item size.

use super::{Builder, Ctx, MeshError, Model, ModelEncoding, float, int, lines, show, tokens};

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Scalar {
    I8,
    U8,
    I16,
    U16,
    I32,
    U32,
    F32,
    F64,
}

impl Scalar {
    fn parse(t: &[u8]) -> Option<Self> {
        Some(match t {
            b"char" | b"int8" => Self::I8,
            b"uchar" | b"uint8" => Self::U8,
            b"short" | b"int16" => Self::I16,
            b"ushort" | b"uint16" => Self::U16,
            b"int" | b"int32" => Self::I32,
            b"uint" | b"uint32" => Self::U32,
            b"float" | b"float32" => Self::F32,
            b"double" | b"float64" => Self::F64,
            _ => return None,
        })
    }

    fn size(self) -> usize {
        match self {
            Self::I8 | Self::U8 => 1,
            Self::I16 | Self::U16 => 2,
            Self::I32 | Self::U32 | Self::F32 => 4,
            Self::F64 => 8,
        }
    }

    fn is_int(self) -> bool {
        !matches!(self, Self::F32 | Self::F64)
    }
}

#[derive(Debug, Clone)]
enum PropKind {
    Scalar(Scalar),
    List { count: Scalar, item: Scalar },
}

#[derive(Debug, Clone)]
struct Prop {
    name: Vec<u8>,
    kind: PropKind,
}

#[derive(Debug, Clone)]
struct Element {
    name: Vec<u8>,
    count: u64,
    props: Vec<Prop>,
}

/// Reads values from the body, ASCII or binary.
trait Body {
    /// The next value; `at` names the element for errors.
    fn value(&mut self, ty: Scalar, at: &dyn Fn() -> String) -> Result<f64, MeshError>;
    /// Bytes not yet read (for list-length checks).
    fn remaining(&self) -> usize;
}

struct Binary<'a> {
    bytes: &'a [u8],
    pos: usize,
    big_endian: bool,
    ctx: Ctx<'a>,
}

impl Body for Binary<'_> {
    fn value(&mut self, ty: Scalar, at: &dyn Fn() -> String) -> Result<f64, MeshError> {
        let n = ty.size();
        let Some(b) = self.bytes.get(self.pos..self.pos + n) else {
            return Err(self.ctx.truncated(at(), format!("the file ends at byte {}", self.bytes.len())));
        };
        self.pos += n;
        let mut a = [0u8; 8];
        a[..n].copy_from_slice(b);
        if self.big_endian {
            a[..n].reverse();
        }
        // `a[..n]` now holds the value in little-endian order.
        Ok(match ty {
            Scalar::I8 => f64::from(a[0] as i8),
            Scalar::U8 => f64::from(a[0]),
            Scalar::I16 => f64::from(i16::from_le_bytes([a[0], a[1]])),
            Scalar::U16 => f64::from(u16::from_le_bytes([a[0], a[1]])),
            Scalar::I32 => f64::from(i32::from_le_bytes([a[0], a[1], a[2], a[3]])),
            Scalar::U32 => f64::from(u32::from_le_bytes([a[0], a[1], a[2], a[3]])),
            Scalar::F32 => f64::from(f32::from_le_bytes([a[0], a[1], a[2], a[3]])),
            Scalar::F64 => f64::from_le_bytes(a),
        })
    }
    fn remaining(&self) -> usize {
        self.bytes.len() - self.pos
    }
}

struct Ascii<'a> {
    lines: Box<dyn Iterator<Item = (usize, &'a [u8])> + 'a>,
    current: std::vec::IntoIter<&'a [u8]>,
    line: usize,
    first_line: usize,
    remaining: usize,
    ctx: Ctx<'a>,
}

impl Body for Ascii<'_> {
    fn value(&mut self, ty: Scalar, at: &dyn Fn() -> String) -> Result<f64, MeshError> {
        let t = loop {
            if let Some(t) = self.current.next() {
                break t;
            }
            let Some((ln, l)) = self.lines.next() else {
                return Err(self.ctx.truncated(at(), "the file ends before the element's values"));
            };
            self.line = ln + self.first_line - 1;
            self.remaining = self.remaining.saturating_sub(l.len() + 1);
            self.current = tokens(l).collect::<Vec<_>>().into_iter();
        };
        let bad = || {
            self.ctx.syntax(format!("{} (line {})", at(), self.line), format!("{} is not a number", show(t)))
        };
        if ty.is_int() { int(t).map(|v| v as f64).ok_or_else(bad) } else { float(t).ok_or_else(bad) }
    }
    /// The unread lines' bytes plus the current line's unread tokens (each at least a byte).
    fn remaining(&self) -> usize {
        self.remaining + self.current.len()
    }
}

/// Decodes a PLY file's bytes; `name` is used in errors.
pub fn parse(bytes: &[u8], name: &str) -> Result<Model, MeshError> {
    let ctx = Ctx { file: name };
    let (encoding, elements, body_start, header_lines) = header(bytes, ctx)?;
    let body = &bytes[body_start..];

    // Lower bounds on each element's size, checked against what follows before allocating.
    let mut needed: u128 = 0;
    for e in &elements {
        let min: u64 = e
            .props
            .iter()
            .map(|p| match (&p.kind, encoding) {
                (_, ModelEncoding::PlyAscii) => 1,
                (PropKind::Scalar(s), _) => s.size() as u64,
                (PropKind::List { count, .. }, _) => count.size() as u64,
            })
            .sum();
        needed += u128::from(e.count) * u128::from(min);
        if needed > body.len() as u128 {
            return Err(ctx.absurd(
                format!("header, element {}", String::from_utf8_lossy(&e.name)),
                format!("{} elements", String::from_utf8_lossy(&e.name)),
                e.count,
                needed,
                body.len() as u64,
            ));
        }
    }

    let mut reader: Box<dyn Body> = match encoding {
        ModelEncoding::PlyAscii => Box::new(Ascii {
            lines: Box::new(lines(body)),
            current: Vec::new().into_iter(),
            line: header_lines,
            first_line: header_lines + 1,
            remaining: body.len(),
            ctx,
        }),
        _ => {
            Box::new(Binary { bytes: body, pos: 0, big_endian: encoding == ModelEncoding::PlyBinaryBe, ctx })
        }
    };

    let mut b = Builder::default();
    let mut seen_vertex = false;
    let mut seen_face = false;
    let mut list: Vec<u32> = Vec::new();
    for e in &elements {
        let ename = String::from_utf8_lossy(&e.name).into_owned();
        let role = match e.name.as_slice() {
            b"vertex" if !seen_vertex => Role::Vertex(vertex_slots(e, ctx)?),
            b"face" if !seen_face => Role::Face(face_slot(e, ctx)?),
            _ => Role::Skip,
        };
        match role {
            Role::Vertex(_) => {
                seen_vertex = true;
                b.positions.reserve_exact(e.count as usize);
            }
            Role::Face(_) => {
                seen_face = true;
                b.triangles.reserve(e.count as usize);
            }
            Role::Skip => {}
        }
        // An element without properties holds no data, whatever its count: nothing to read, and
        // no loop of a count the file never pays for in bytes (`element x 9223372036854775807`
        // spun for hours; found by fuzzing `model_ply`).
        if e.props.is_empty() {
            continue;
        }
        let mut has_normals = false;
        if let Role::Vertex(s) = &role
            && s[3..].iter().all(Option::is_some)
        {
            has_normals = true;
            b.file_normals.reserve_exact(e.count as usize);
        }
        for i in 0..e.count {
            let at = || format!("element {ename} {i}");
            let mut vals = [0.0f64; 6];
            for (pi, p) in e.props.iter().enumerate() {
                match &p.kind {
                    PropKind::Scalar(s) => {
                        let v = reader.value(*s, &at)?;
                        if let Role::Vertex(slots) = &role
                            && let Some(k) = slots.iter().position(|&x| x == Some(pi))
                        {
                            vals[k] = v;
                        }
                    }
                    PropKind::List { count, item } => {
                        let n = reader.value(*count, &at)?;
                        if !(n >= 0.0 && n.fract() == 0.0) {
                            return Err(ctx.syntax(at(), format!("list length {n} is not a count")));
                        }
                        let min_item = if encoding == ModelEncoding::PlyAscii { 1 } else { item.size() };
                        let (need, left) = (n * min_item as f64, reader.remaining() as f64);
                        if need > left {
                            // More than half the list present reads as a cut-off file; a
                            // length far beyond the rest of the file, as a corrupt count.
                            // Either way nothing is read or allocated for it.
                            if left > 0.0 && need < 2.0 * left {
                                return Err(ctx.truncated(
                                    at(),
                                    format!(
                                        "the {} list declares {n} items but the file ends after {left} bytes",
                                        String::from_utf8_lossy(&p.name)
                                    ),
                                ));
                            }
                            return Err(ctx.absurd(
                                at(),
                                format!("{} list items", String::from_utf8_lossy(&p.name)),
                                n as u64,
                                n as u128 * min_item as u128,
                                reader.remaining() as u64,
                            ));
                        }
                        let is_index = matches!(role, Role::Face(slot) if slot == pi);
                        list.clear();
                        for _ in 0..n as u64 {
                            let v = reader.value(*item, &at)?;
                            if is_index {
                                if !(v >= 0.0 && v.fract() == 0.0 && v < f64::from(u32::MAX)) {
                                    return Err(ctx.index(at(), v as i64, b.positions.len()));
                                }
                                list.push(v as u32);
                            }
                        }
                        if is_index {
                            if list.len() < 3 {
                                return Err(
                                    ctx.syntax(at(), format!("a face needs 3 corners, found {}", list.len()))
                                );
                            }
                            for &v in &list {
                                b.note_index(v, at);
                            }
                            b.polygon(&list);
                        }
                    }
                }
            }
            if matches!(role, Role::Vertex(_)) {
                let p = ctx.position(at(), [vals[0], vals[1], vals[2]])?;
                b.positions.push(p);
                if has_normals {
                    b.file_normals.push([vals[3], vals[4], vals[5]]);
                }
            }
        }
    }
    if !seen_vertex {
        return Err(MeshError::Empty { file: name.to_owned(), detail: "no `vertex` element".into() });
    }
    if !b.file_normals.is_empty() && b.file_normals.iter().any(|n| n.iter().any(|v| !v.is_finite())) {
        // Bad normals are not worth refusing a model over: compute them instead.
        b.file_normals.clear();
    }
    b.finish(ctx, encoding)
}

enum Role {
    /// Property positions of x, y, z, nx, ny, nz.
    Vertex([Option<usize>; 6]),
    /// Position of the index list.
    Face(usize),
    Skip,
}

fn vertex_slots(e: &Element, ctx: Ctx<'_>) -> Result<[Option<usize>; 6], MeshError> {
    let names: [&[u8]; 6] = [b"x", b"y", b"z", b"nx", b"ny", b"nz"];
    let mut slots = [None; 6];
    for (k, n) in names.iter().enumerate() {
        slots[k] = e.props.iter().position(|p| p.name == *n);
        if let Some(i) = slots[k]
            && matches!(e.props[i].kind, PropKind::List { .. })
        {
            return Err(ctx.syntax("header", format!("vertex property {} is a list", show(n))));
        }
        if k < 3 && slots[k].is_none() {
            return Err(ctx.syntax("header", format!("the vertex element has no {} property", show(n))));
        }
    }
    Ok(slots)
}

fn face_slot(e: &Element, ctx: Ctx<'_>) -> Result<usize, MeshError> {
    let i = e
        .props
        .iter()
        .position(|p| p.name == b"vertex_indices" || p.name == b"vertex_index")
        .ok_or_else(|| ctx.syntax("header", "the face element has no vertex_indices list"))?;
    match e.props[i].kind {
        PropKind::List { count, item } if count.is_int() && item.is_int() => Ok(i),
        _ => Err(ctx.syntax("header", "vertex_indices must be a list of integers")),
    }
}

/// Parses the header: encoding, elements, where the body starts, and the header's line count.
fn header(bytes: &[u8], ctx: Ctx<'_>) -> Result<(ModelEncoding, Vec<Element>, usize, usize), MeshError> {
    let mut encoding = None;
    let mut elements: Vec<Element> = Vec::new();
    let mut offset = 0usize;
    for (ln, raw) in bytes.split_inclusive(|&b| b == b'\n').enumerate() {
        let ln = ln + 1;
        offset += raw.len();
        let at = || format!("header line {ln}");
        if !raw.ends_with(b"\n") {
            break;
        }
        let line = raw.strip_suffix(b"\n").unwrap_or(raw);
        let line = line.strip_suffix(b"\r").unwrap_or(line);
        if ln == 1 {
            if line != b"ply" {
                return Err(ctx.syntax(at(), "not a PLY file (the first line must be `ply`)"));
            }
            continue;
        }
        let t: Vec<&[u8]> = tokens(line).collect();
        match t.as_slice() {
            [] | [b"comment" | b"obj_info", ..] => {}
            [b"format", f, _version] => {
                encoding = Some(match *f {
                    b"ascii" => ModelEncoding::PlyAscii,
                    b"binary_little_endian" => ModelEncoding::PlyBinaryLe,
                    b"binary_big_endian" => ModelEncoding::PlyBinaryBe,
                    _ => return Err(ctx.syntax(at(), format!("unknown format {}", show(f)))),
                });
            }
            [b"element", name, count] => {
                let count = int(count).and_then(|c| u64::try_from(c).ok()).ok_or_else(|| {
                    ctx.syntax(at(), format!("element count {} is not a count", show(count)))
                })?;
                elements.push(Element { name: name.to_vec(), count, props: Vec::new() });
            }
            [b"property", b"list", ct, it, name] => {
                let (Some(count), Some(item)) = (Scalar::parse(ct), Scalar::parse(it)) else {
                    return Err(ctx.syntax(at(), "unknown list property type"));
                };
                if !count.is_int() {
                    return Err(ctx.syntax(at(), "a list's count type must be an integer type"));
                }
                let e = elements.last_mut().ok_or_else(|| ctx.syntax(at(), "property before any element"))?;
                e.props.push(Prop { name: name.to_vec(), kind: PropKind::List { count, item } });
            }
            [b"property", ty, name] => {
                let s = Scalar::parse(ty)
                    .ok_or_else(|| ctx.syntax(at(), format!("unknown property type {}", show(ty))))?;
                let e = elements.last_mut().ok_or_else(|| ctx.syntax(at(), "property before any element"))?;
                e.props.push(Prop { name: name.to_vec(), kind: PropKind::Scalar(s) });
            }
            [b"end_header"] => {
                let encoding = encoding.ok_or_else(|| ctx.syntax(at(), "no `format` line in the header"))?;
                return Ok((encoding, elements, offset, ln));
            }
            _ => return Err(ctx.syntax(at(), format!("cannot read header line {}", show(line)))),
        }
    }
    Err(ctx.truncated("header", "no `end_header` line"))
}

#[cfg(test)]
#[allow(clippy::float_cmp)]
mod tests {
    use super::*;

    const TET_V: [[f32; 3]; 4] = [[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]];

    fn ascii_tet(extra_face: &str) -> String {
        format!(
            "ply\nformat ascii 1.0\ncomment test\nelement vertex 4\nproperty float x\nproperty float y\n\
             property float z\nproperty uchar red\nelement edge 1\nproperty int a\nproperty int b\n\
             element face {}\nproperty uchar flags\nproperty list uchar int vertex_indices\n\
             property list uchar float texcoord\nend_header\n\
             0 0 0 255\n1 0 0 0\n0 1 0 1\n0 0 1 2\n0 1\n0 3 0 2 1 0\n0 3 0 1 3 2 0.5 0.5\n\
             0 4 0 3 2 1 0\n{extra_face}",
            if extra_face.is_empty() { 3 } else { 4 }
        )
    }

    /// The same tetrahedron (a quad and two triangles) in binary, either byte order, with
    /// double coordinates, an int16 extra property and a uint index list.
    fn binary_tet(big: bool) -> Vec<u8> {
        let fmt = if big { "binary_big_endian" } else { "binary_little_endian" };
        let mut out = format!(
            "ply\r\nformat {fmt} 1.0\r\nelement vertex 4\r\nproperty double x\r\nproperty double y\r\n\
             property double z\r\nproperty short s\r\nelement face 3\r\nproperty list uchar uint vertex_indices\r\n\
             end_header\r\n"
        )
        .into_bytes();
        let put = |out: &mut Vec<u8>, le: &[u8]| {
            let mut b = le.to_vec();
            if big {
                b.reverse();
            }
            out.extend_from_slice(&b);
        };
        for v in TET_V {
            for c in v {
                put(&mut out, &f64::from(c).to_le_bytes());
            }
            put(&mut out, &(-7i16).to_le_bytes());
        }
        for f in [&[0u32, 2, 1][..], &[0, 1, 3], &[0, 3, 2, 1]] {
            out.push(f.len() as u8);
            for &i in f {
                put(&mut out, &i.to_le_bytes());
            }
        }
        out
    }

    fn replace(b: &[u8], from: &[u8], to: &[u8]) -> Vec<u8> {
        let i = b.windows(from.len()).position(|w| w == from).unwrap();
        [&b[..i], to, &b[i + from.len()..]].concat()
    }

    #[test]
    fn elements_without_properties_cost_nothing_whatever_their_count() {
        for format in ["ascii", "binary_little_endian"] {
            let mut text = format!(
                "ply\nformat {format} 1.0\nelement empty 9223372036854775807\nelement vertex 3\n\
                 property float x\nproperty float y\nproperty float z\nelement face 1\n\
                 property list uchar int vertex_indices\nend_header\n"
            )
            .into_bytes();
            if format == "ascii" {
                text.extend_from_slice(b"0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n");
            } else {
                for v in [[0f32, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]] {
                    for c in v {
                        text.extend_from_slice(&c.to_le_bytes());
                    }
                }
                text.push(3);
                for i in [0i32, 1, 2] {
                    text.extend_from_slice(&i.to_le_bytes());
                }
            }
            let t0 = std::time::Instant::now();
            let m = parse(&text, "empty.ply").unwrap();
            assert_eq!((m.mesh.positions.len(), m.mesh.triangles.len()), (3, 1), "{format}");
            assert!(t0.elapsed() < std::time::Duration::from_secs(5), "{format}: {:?}", t0.elapsed());
        }
    }

    #[test]
    fn ascii_skips_extra_properties_and_elements() {
        let m = parse(ascii_tet("").as_bytes(), "t.ply").unwrap();
        assert_eq!(m.encoding, ModelEncoding::PlyAscii);
        assert_eq!(m.mesh.positions.len(), 4);
        assert_eq!(m.mesh.triangles, vec![[0, 2, 1], [0, 1, 3], [0, 3, 2], [0, 2, 1]]);
        assert_eq!(m.stats.faces, 3);
    }

    #[test]
    fn binary_both_byte_orders_match_ascii() {
        let a = parse(ascii_tet("").as_bytes(), "t.ply").unwrap();
        for big in [false, true] {
            let m = parse(&binary_tet(big), "t.ply").unwrap();
            assert_eq!(m.encoding, if big { ModelEncoding::PlyBinaryBe } else { ModelEncoding::PlyBinaryLe });
            assert_eq!(m.mesh, a.mesh, "big endian {big}");
        }
    }

    #[test]
    fn file_normals_are_used() {
        let s = "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\n\
                 property float nx\nproperty float ny\nproperty float nz\nelement face 1\n\
                 property list uchar int vertex_index\nend_header\n\
                 0 0 0 0 0 -1\n1 0 0 0 0 -1\n0 1 0 0 0 -1\n3 0 1 2\n";
        let m = parse(s.as_bytes(), "t.ply").unwrap();
        assert_eq!(m.stats.normals_from_file, 3);
        assert_eq!(m.normals[0], [0.0, 0.0, -1.0]);
    }

    #[test]
    fn malformed_inputs() {
        let err = |b: &[u8]| parse(b, "t.ply").unwrap_err().to_string();
        let good = binary_tet(false);
        let e = err(&good[..good.len() - 3]);
        assert!(e.contains("truncated") && e.contains("element face 2"), "{e}");
        let s = ascii_tet("").replace("element vertex 4", "element vertex 4000000000");
        let e = err(s.as_bytes());
        assert!(e.contains("4000000000") && e.contains("before allocating"), "{e}");
        let e = err(&replace(&good, b"element face 3", b"element face 99999999"));
        assert!(e.contains("before allocating"), "{e}");
        let e = err(ascii_tet("0 3 0 1 9 0\n").as_bytes());
        assert!(e.contains("element face 3") && e.contains("index 9") && e.contains("4 vertices"), "{e}");
        let e = err(ascii_tet("0 3 0 1 -1 0\n").as_bytes());
        assert!(e.contains("index -1"), "{e}");
        let e = err(ascii_tet("").replace("0 1 0 1\n", "0 nan 0 1\n").as_bytes());
        assert!(e.contains("element vertex 2") && e.contains("NaN"), "{e}");
        let e = err(ascii_tet("").replace("0 1 0 1\n", "0 y 0 1\n").as_bytes());
        assert!(e.contains("line 19") && e.contains("\"y\""), "{e}");
        let e = err(b"ply\nformat ascii 1.0\nelement vertex 0\nproperty float x\n");
        assert!(e.contains("end_header"), "{e}");
        let e = err(
            b"ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\nproperty float y\nend_header\n0 0\n",
        );
        assert!(e.contains("no \"z\" property"), "{e}");
        let e = err(b"ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\nproperty float y\nproperty float z\nend_header\n0 0 0\n");
        assert!(e.contains("no faces"), "{e}");
        let e = err(b"ply\nformat weird 1.0\nend_header\n");
        assert!(e.contains("unknown format"), "{e}");
        let e = err(b"plx\n");
        assert!(e.contains("not a PLY"), "{e}");
        // A list whose declared length cannot fit: refused before reading its items.
        let mut huge = binary_tet(false);
        let at = huge.len() - (1 + 4 * 4);
        assert_eq!(huge[at], 4);
        huge[at] = 255;
        let e = err(&huge);
        assert!(
            e.contains("element face 2")
                && e.contains("255 vertex_indices")
                && e.contains("before allocating"),
            "{e}"
        );
    }
}
