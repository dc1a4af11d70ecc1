//! `EXT_meshopt_compression` for the 3D Tiles GLBs: the meshopt bitstreams (attribute codec
//! version 0 for vertex streams, triangle codec version 1 for index lists) written per the
//! extension's Appendix A, their decoders (for the round trips and to check what the encoder
//! wrote), and [`compress_glb`], which turns a plain GLB of [`super::glb()`] into one whose buffer
//! views point into a compressed buffer (the uncompressed buffer stays a fallback with no data).
//!
//! The triangle codec keeps the triangle order and each triangle's winding but may rotate a
//! triangle's three indices (as meshoptimizer's own encoder does), so a decoded index buffer is
//! the plain one with some triangles rotated; vertex streams decode byte for byte, but for
//! `BYTE` normals, which go through the extension's octahedral filter (Appendix B) and decode to
//! within about 1.5° of the plain GLB's.

use serde_json::{Value, json};

pub use super::glb::write_glb;
use super::glb::{ELEMENT_ARRAY_BUFFER, GLTF_U8, GLTF_U16, GLTF_U32};

/// `BYTE`, the normals' component type.
const GLTF_I8: u64 = 5120;

/// The extension's name, in `extensionsUsed`/`extensionsRequired` and on buffer views.
pub const EXT: &str = "EXT_meshopt_compression";
/// Largest element (`byteStride`) the attribute codec takes.
pub const MAX_STRIDE: usize = 256;
/// Largest element count one stream may declare (a GLB is at most 4 GiB).
pub const MAX_COUNT: usize = 1 << 30;

const VERTEX_HEADER: u8 = 0xa0;
const INDEX_HEADER: u8 = 0xe1;
const BLOCK_BYTES: usize = 8192;
const BLOCK_MAX: usize = 256;
const GROUP: usize = 16;
const TAIL_MIN: usize = 32;
/// The triangle codec's table of (b, c) sources for a triangle that starts at `next`, stored in
/// the stream's tail: nibble 0 is `next`, `k` the vertex FIFO's entry `k − 1`. The last two
/// bytes must be 0 and no nibble may be 0xf.
const CODEAUX: [u8; 16] =
    [0x00, 0x76, 0x87, 0x56, 0x67, 0x78, 0xa9, 0x86, 0x65, 0x89, 0x68, 0x98, 0x01, 0x69, 0, 0];

/// Errors of the meshopt codecs and of [`compress_glb`].
#[derive(Debug, Clone, thiserror::Error, PartialEq, Eq)]
pub enum MeshoptError {
    #[error("meshopt: byteStride {0} is not a multiple of 4 in 4..=256")]
    Stride(usize),
    #[error("meshopt: {what} {count} exceeds the limit {limit}")]
    TooMany { what: &'static str, count: usize, limit: usize },
    #[error("meshopt: {0} bytes are not a whole number of elements")]
    Ragged(usize),
    #[error("meshopt: triangle index count {0} is not a multiple of 3")]
    NotTriangles(usize),
    #[error("meshopt: vertex stream: {0}")]
    Vertex(&'static str),
    #[error("meshopt: index stream: {0}")]
    Index(&'static str),
    #[error("meshopt: GLB: {0}")]
    Glb(String),
}

fn check_stride(stride: usize) -> Result<(), MeshoptError> {
    if stride == 0 || stride > MAX_STRIDE || !stride.is_multiple_of(4) {
        return Err(MeshoptError::Stride(stride));
    }
    Ok(())
}

fn block_size(stride: usize) -> usize {
    ((BLOCK_BYTES / stride) & !(GROUP - 1)).min(BLOCK_MAX)
}

fn zigzag8(d: u8) -> u8 {
    (d << 1) ^ (((d as i8) >> 7) as u8)
}

fn unzigzag8(v: u8) -> u8 {
    (v >> 1) ^ (0u8.wrapping_sub(v & 1))
}

/// Encodes `data` (whole elements of `stride` bytes) with the attribute codec, version 0.
///
/// # Errors
/// A stride that is not a multiple of 4 up to 256, a length that is not whole elements, more
/// than [`MAX_COUNT`] elements.
pub fn encode_vertex_buffer(data: &[u8], stride: usize) -> Result<Vec<u8>, MeshoptError> {
    check_stride(stride)?;
    if !data.len().is_multiple_of(stride) {
        return Err(MeshoptError::Ragged(data.len()));
    }
    let count = data.len() / stride;
    if count > MAX_COUNT {
        return Err(MeshoptError::TooMany { what: "elements", count, limit: MAX_COUNT });
    }
    let mut out = Vec::with_capacity(data.len() / 2 + TAIL_MIN + 1);
    out.push(VERTEX_HEADER);
    let first: Vec<u8> = data.get(..stride).map_or_else(|| vec![0; stride], <[u8]>::to_vec);
    let mut last = first.clone();
    let bs = block_size(stride);
    let mut deltas = vec![0u8; BLOCK_MAX];
    for block in data.chunks(bs * stride) {
        let n = block.len() / stride;
        let aligned = n.div_ceil(GROUP) * GROUP;
        for k in 0..stride {
            let mut p = last[k];
            for i in 0..aligned {
                deltas[i] = if i < n {
                    let v = block[i * stride + k];
                    let d = zigzag8(v.wrapping_sub(p));
                    p = v;
                    d
                } else {
                    0
                };
            }
            encode_bytes(&deltas[..aligned], &mut out);
        }
        last.copy_from_slice(&block[(n - 1) * stride..n * stride]);
    }
    let tail = stride.max(TAIL_MIN);
    out.resize(out.len() + tail - stride, 0);
    out.extend_from_slice(&first);
    Ok(out)
}

/// One data block: 2 header bits per group of 16 deltas, then each group at the width that
/// takes the fewest bytes (0, 2, 4 bits with sentinel escapes, or 8 bits).
fn encode_bytes(deltas: &[u8], out: &mut Vec<u8>) {
    let groups = deltas.len() / GROUP;
    let header_at = out.len();
    out.resize(header_at + groups.div_ceil(4), 0);
    for (g, group) in deltas.chunks(GROUP).enumerate() {
        let size = |bits: u32| -> usize {
            if bits == 0 {
                return if group.iter().all(|&d| d == 0) { 0 } else { usize::MAX };
            }
            if bits == 8 {
                return GROUP;
            }
            let sentinel = (1u8 << bits) - 1;
            GROUP * bits as usize / 8 + group.iter().filter(|&&d| d >= sentinel).count()
        };
        let (code, bits) =
            [(0u8, 0u32), (1, 2), (2, 4), (3, 8)].into_iter().min_by_key(|&(_, b)| size(b)).unwrap_or((3, 8));
        out[header_at + g / 4] |= code << ((g % 4) * 2);
        match bits {
            0 => {}
            8 => out.extend_from_slice(group),
            _ => {
                let sentinel = (1u8 << bits) - 1;
                let per_byte = 8 / bits as usize;
                for chunk in group.chunks(per_byte) {
                    let mut b = 0u8;
                    for &d in chunk {
                        b = (b << bits) | d.min(sentinel);
                    }
                    out.push(b);
                }
                out.extend(group.iter().filter(|&&d| d >= sentinel));
            }
        }
    }
}

/// Decodes an attribute stream of `count` elements of `stride` bytes (versions 0 only).
///
/// # Errors
/// A bad stride or count, a header that is not version 0, a stream too short or too long.
pub fn decode_vertex_buffer(src: &[u8], count: usize, stride: usize) -> Result<Vec<u8>, MeshoptError> {
    check_stride(stride)?;
    if count > MAX_COUNT || count.saturating_mul(stride) > src.len().saturating_mul(64).max(BLOCK_BYTES) {
        return Err(MeshoptError::TooMany { what: "elements", count, limit: MAX_COUNT.min(src.len() * 64) });
    }
    let tail = stride.max(TAIL_MIN);
    if src.len() < 1 + tail {
        return Err(MeshoptError::Vertex("shorter than its header and tail"));
    }
    if src[0] != VERTEX_HEADER {
        return Err(MeshoptError::Vertex("header is not 0xa0 (attribute codec version 0)"));
    }
    let end = src.len() - tail;
    let mut last = src[src.len() - stride..].to_vec();
    let mut pos = 1;
    let mut out = vec![0u8; count * stride];
    let bs = block_size(stride);
    let mut deltas = vec![0u8; BLOCK_MAX];
    let mut done = 0;
    while done < count {
        let n = bs.min(count - done);
        let aligned = n.div_ceil(GROUP) * GROUP;
        for k in 0..stride {
            pos = decode_bytes(src, pos, end, &mut deltas[..aligned])?;
            let mut p = last[k];
            for i in 0..n {
                p = p.wrapping_add(unzigzag8(deltas[i]));
                out[(done + i) * stride + k] = p;
            }
            last[k] = p;
        }
        done += n;
    }
    if pos != end {
        return Err(MeshoptError::Vertex("bytes left over before the tail"));
    }
    Ok(out)
}

fn decode_bytes(src: &[u8], mut pos: usize, end: usize, deltas: &mut [u8]) -> Result<usize, MeshoptError> {
    let short = MeshoptError::Vertex("truncated data block");
    let groups = deltas.len() / GROUP;
    let header = src.get(pos..pos + groups.div_ceil(4)).ok_or(short.clone())?;
    pos += header.len();
    for (g, group) in deltas.chunks_mut(GROUP).enumerate() {
        match (header[g / 4] >> ((g % 4) * 2)) & 3 {
            0 => group.fill(0),
            3 => {
                group.copy_from_slice(
                    src.get(pos..pos + GROUP).filter(|_| pos + GROUP <= end).ok_or(short.clone())?,
                );
                pos += GROUP;
            }
            code => {
                let bits = if code == 1 { 2 } else { 4 };
                let packed = GROUP * bits / 8;
                let bytes =
                    src.get(pos..pos + packed).filter(|_| pos + packed <= end).ok_or(short.clone())?;
                let mut extra = pos + packed;
                let sentinel = (1u8 << bits) - 1;
                for (i, d) in group.iter_mut().enumerate() {
                    let per = 8 / bits;
                    let shift = 8 - bits * (i % per + 1);
                    let v = (bytes[i / per] >> shift) & sentinel;
                    *d = if v == sentinel {
                        let b = *src.get(extra).filter(|_| extra < end).ok_or(short.clone())?;
                        extra += 1;
                        b
                    } else {
                        v
                    };
                }
                pos = extra;
            }
        }
    }
    Ok(pos)
}

/// The codec's decoder state, which the encoder mirrors exactly.
struct Fifos {
    edges: [[u32; 2]; 16],
    edge_at: usize,
    verts: [u32; 16],
    vert_at: usize,
    next: u32,
    last: u32,
}

impl Fifos {
    fn new() -> Self {
        // u32::MAX is no vertex (counts stay far below it), so empty entries never match.
        Self { edges: [[u32::MAX; 2]; 16], edge_at: 0, verts: [u32::MAX; 16], vert_at: 0, next: 0, last: 0 }
    }
    fn push_edge(&mut self, a: u32, b: u32) {
        self.edges[self.edge_at] = [a, b];
        self.edge_at = (self.edge_at + 1) & 15;
    }
    fn push_vert(&mut self, v: u32) {
        self.verts[self.vert_at] = v;
        self.vert_at = (self.vert_at + 1) & 15;
    }
    fn edge(&self, i: usize) -> [u32; 2] {
        self.edges[(self.edge_at + 15 - i) & 15]
    }
    fn vert(&self, i: usize) -> u32 {
        self.verts[(self.vert_at + 15 - i) & 15]
    }
    fn find_vert(&self, v: u32) -> Option<usize> {
        (0..16).find(|&i| self.vert(i) == v)
    }
}

fn write_index(out: &mut Vec<u8>, f: &mut Fifos, v: u32) {
    let d = v.wrapping_sub(f.last) as i32;
    let mut z = ((d << 1) ^ (d >> 31)) as u32;
    loop {
        let b = (z & 0x7f) as u8;
        z >>= 7;
        if z == 0 {
            out.push(b);
            break;
        }
        out.push(b | 0x80);
    }
    f.last = v;
}

/// Encodes a triangle list with the triangle codec, version 1. Returns the stream and the
/// indices it decodes to (the input with some triangles rotated, winding kept).
///
/// # Errors
/// A count that is not a multiple of 3, more than [`MAX_COUNT`] indices, an index of `u32::MAX`.
pub fn encode_index_buffer(indices: &[u32]) -> Result<(Vec<u8>, Vec<u32>), MeshoptError> {
    if !indices.len().is_multiple_of(3) {
        return Err(MeshoptError::NotTriangles(indices.len()));
    }
    if indices.len() > MAX_COUNT {
        return Err(MeshoptError::TooMany { what: "indices", count: indices.len(), limit: MAX_COUNT });
    }
    if indices.contains(&u32::MAX) {
        return Err(MeshoptError::Index("index 4294967295 cannot be coded"));
    }
    let mut f = Fifos::new();
    let mut codes = Vec::with_capacity(indices.len() / 3);
    let mut data = Vec::new();
    let mut decoded = Vec::with_capacity(indices.len());
    for t in indices.chunks_exact(3) {
        let rots = [[t[0], t[1], t[2]], [t[1], t[2], t[0]], [t[2], t[0], t[1]]];
        let hit = (0..15).find_map(|i| {
            let e = f.edge(i);
            rots.iter().find(|r| r[0] == e[0] && r[1] == e[1]).map(|r| (i, *r))
        });
        if let Some((fe, [a, b, c])) = hit {
            let fe = fe as u8;
            if c == f.next {
                codes.push(fe << 4);
                f.next = f.next.wrapping_add(1);
                f.push_vert(c);
            } else if let Some(fv) = f.find_vert(c).filter(|&i| (1..13).contains(&i)) {
                codes.push((fe << 4) | fv as u8);
            } else if c == f.last.wrapping_sub(1) || c == f.last.wrapping_add(1) {
                codes.push((fe << 4) | if c == f.last.wrapping_sub(1) { 0xd } else { 0xe });
                f.last = c;
                f.push_vert(c);
            } else {
                codes.push((fe << 4) | 0xf);
                write_index(&mut data, &mut f, c);
                f.push_vert(c);
            }
            f.push_edge(c, b);
            f.push_edge(a, c);
            decoded.extend_from_slice(&[a, b, c]);
            continue;
        }
        // No shared edge: start the triangle at `next` where one of its vertices is it.
        let [a, b, c] = *rots.iter().find(|r| r[0] == f.next).unwrap_or(&rots[0]);
        let starts_next = a == f.next;
        // Sources of b and c after a: 0 = next (then incremented), k = FIFO entry k − 1, 15 = explicit.
        let mut next = f.next.wrapping_add(u32::from(starts_next));
        let src = |v: u32, next: &mut u32| -> u8 {
            if v == *next {
                *next = next.wrapping_add(1);
                0
            } else {
                f.find_vert(v).filter(|&i| i < 14).map_or(15, |i| i as u8 + 1)
            }
        };
        let zb = src(b, &mut next);
        let zc = src(c, &mut next);
        let aux = (zb << 4) | zc;
        let table =
            CODEAUX[..14].iter().position(|&x| x == aux).filter(|_| starts_next && zb != 15 && zc != 15);
        let (zb, zc) = if let Some(y) = table {
            codes.push(0xf0 | y as u8);
            (zb, zc)
        } else if starts_next {
            codes.push(0xfe);
            data.push(aux);
            (zb, zc)
        } else {
            codes.push(0xff);
            // 0x00 after 0xff would reset `next`: code c explicitly instead.
            let (zb, zc) = if aux == 0 { (0, 15) } else { (zb, zc) };
            data.push((zb << 4) | zc);
            write_index(&mut data, &mut f, a);
            (zb, zc)
        };
        if starts_next {
            f.next = f.next.wrapping_add(1);
        }
        for (v, z) in [(b, zb), (c, zc)] {
            if z == 0 {
                f.next = f.next.wrapping_add(1);
            } else if z == 15 {
                write_index(&mut data, &mut f, v);
            }
        }
        f.push_edge(b, a);
        f.push_edge(c, b);
        f.push_edge(a, c);
        f.push_vert(a);
        if zb == 0 || zb == 15 {
            f.push_vert(b);
        }
        if zc == 0 || zc == 15 {
            f.push_vert(c);
        }
        decoded.extend_from_slice(&[a, b, c]);
    }
    let mut out = Vec::with_capacity(1 + codes.len() + data.len() + 16);
    out.push(INDEX_HEADER);
    out.extend_from_slice(&codes);
    out.extend_from_slice(&data);
    out.extend_from_slice(&CODEAUX);
    Ok((out, decoded))
}

/// Decodes a triangle stream of `count` indices (triangle codec, version 1).
///
/// # Errors
/// A count that is not a multiple of 3 or that the stream cannot hold, a bad header or table,
/// truncated or left-over data.
pub fn decode_index_buffer(src: &[u8], count: usize) -> Result<Vec<u32>, MeshoptError> {
    if !count.is_multiple_of(3) {
        return Err(MeshoptError::NotTriangles(count));
    }
    let tris = count / 3;
    if src.len() < 1 + 16 || tris > src.len() - 17 {
        return Err(MeshoptError::Index("shorter than its header, one code per triangle and table"));
    }
    if src[0] != INDEX_HEADER {
        return Err(MeshoptError::Index("header is not 0xe1 (triangle codec version 1)"));
    }
    let aux = &src[src.len() - 16..];
    let codes = &src[1..=tris];
    let data_end = src.len() - 16;
    let mut pos = 1 + tris;
    let mut f = Fifos::new();
    let mut out = Vec::with_capacity(count);
    let trunc = MeshoptError::Index("truncated data");
    let read = |pos: &mut usize, f: &mut Fifos| -> Result<u32, MeshoptError> {
        let mut v = 0u32;
        for shift in (0..35).step_by(7) {
            let b =
                *src.get(*pos).filter(|_| *pos < data_end).ok_or(MeshoptError::Index("truncated data"))?;
            *pos += 1;
            v |= u32::from(b & 0x7f).wrapping_shl(shift);
            if b & 0x80 == 0 {
                let d = ((v >> 1) as i32) ^ -((v & 1) as i32);
                f.last = f.last.wrapping_add(d as u32);
                return Ok(f.last);
            }
        }
        Err(MeshoptError::Index("varint longer than 5 bytes"))
    };
    let fifo = |f: &Fifos, i: usize| -> Result<u32, MeshoptError> {
        let v = f.vert(i);
        if v == u32::MAX { Err(MeshoptError::Index("reads an empty vertex FIFO entry")) } else { Ok(v) }
    };
    for &code in codes {
        let (x, y) = ((code >> 4) as usize, code & 15);
        if x < 15 {
            let [a, b] = f.edge(x);
            if a == u32::MAX {
                return Err(MeshoptError::Index("reads an empty edge FIFO entry"));
            }
            let c = match y {
                0 => {
                    let c = f.next;
                    f.next = f.next.wrapping_add(1);
                    f.push_vert(c);
                    c
                }
                13 | 14 => {
                    let c = if y == 13 { f.last.wrapping_sub(1) } else { f.last.wrapping_add(1) };
                    f.last = c;
                    f.push_vert(c);
                    c
                }
                15 => {
                    let c = read(&mut pos, &mut f)?;
                    f.push_vert(c);
                    c
                }
                _ => fifo(&f, y as usize)?,
            };
            f.push_edge(c, b);
            f.push_edge(a, c);
            out.extend_from_slice(&[a, b, c]);
            continue;
        }
        let (a, zw, explicit_a) = if y < 14 {
            (f.next, aux[y as usize], false)
        } else {
            let zw = *src.get(pos).filter(|_| pos < data_end).ok_or(trunc.clone())?;
            pos += 1;
            if zw == 0 {
                f.next = 0;
            }
            if y == 14 { (f.next, zw, false) } else { (read(&mut pos, &mut f)?, zw, true) }
        };
        if !explicit_a {
            f.next = f.next.wrapping_add(1);
        }
        let (z, w) = (zw >> 4, zw & 15);
        let take = |s: u8, f: &mut Fifos, pos: &mut usize| -> Result<u32, MeshoptError> {
            match s {
                0 => {
                    let v = f.next;
                    f.next = f.next.wrapping_add(1);
                    Ok(v)
                }
                15 if y >= 14 => read(pos, f),
                15 => Err(MeshoptError::Index("table entry with nibble 0xf")),
                _ => fifo(f, s as usize - 1),
            }
        };
        let b = take(z, &mut f, &mut pos)?;
        let c = take(w, &mut f, &mut pos)?;
        f.push_edge(b, a);
        f.push_edge(c, b);
        f.push_edge(a, c);
        f.push_vert(a);
        if z == 0 || z == 15 {
            f.push_vert(b);
        }
        if w == 0 || w == 15 {
            f.push_vert(c);
        }
        out.extend_from_slice(&[a, b, c]);
    }
    if pos != data_end {
        return Err(MeshoptError::Index("bytes left over before the table"));
    }
    Ok(out)
}

/// Post-transform cache size [`optimize_order`] aims at: the triangle codec's FIFOs hold 16.
const CACHE: usize = 16;

/// A triangle order with locality (Tipsify, Sander, Nehab and Barczak 2007: fans around
/// vertices still in a `CACHE`-entry FIFO), so consecutive triangles share edges and recent
/// vertices, which the triangle codec codes in about a byte each. Returns the triangles, in
/// their new order, as indices into `tris`. Linear time; vertices at or past `vertices` are
/// refused by the caller.
fn tipsify(tris: &[[u32; 3]], vertices: usize) -> Vec<usize> {
    // Triangles of each vertex (compressed adjacency).
    let mut start = vec![0usize; vertices + 1];
    for t in tris {
        for &v in t {
            start[v as usize + 1] += 1;
        }
    }
    for i in 0..vertices {
        start[i + 1] += start[i];
    }
    let mut fill = start.clone();
    let mut adj = vec![0usize; tris.len() * 3];
    for (i, t) in tris.iter().enumerate() {
        for &v in t {
            adj[fill[v as usize]] = i;
            fill[v as usize] += 1;
        }
    }
    let mut live: Vec<usize> = (0..vertices).map(|v| start[v + 1] - start[v]).collect();
    let mut stamp = vec![0usize; vertices];
    let mut emitted = vec![false; tris.len()];
    let mut dead_end: Vec<u32> = Vec::new();
    let mut order = Vec::with_capacity(tris.len());
    let mut time = CACHE + 1;
    let mut cursor = 0usize;
    let mut fan = (0..vertices).find(|&v| live[v] > 0);
    let mut near: Vec<u32> = Vec::new();
    while let Some(f) = fan {
        near.clear();
        for &t in &adj[start[f]..start[f + 1]] {
            if emitted[t] {
                continue;
            }
            emitted[t] = true;
            order.push(t);
            for &v in &tris[t] {
                let vi = v as usize;
                dead_end.push(v);
                near.push(v);
                live[vi] -= 1;
                if time - stamp[vi] > CACHE {
                    stamp[vi] = time;
                    time += 1;
                }
            }
        }
        // The next fan: a vertex of this one still in the cache with live triangles (the
        // oldest that stays in for its fan), else the latest dead end, else the next in order.
        let mut best: Option<(usize, usize)> = None;
        for &v in &near {
            let vi = v as usize;
            if live[vi] == 0 {
                continue;
            }
            let age = time - stamp[vi];
            let p = if age + 2 * live[vi] <= CACHE { age } else { 0 };
            if best.is_none_or(|(bp, _)| p > bp) {
                best = Some((p, vi));
            }
        }
        fan = best.map(|(_, v)| v).or_else(|| {
            while let Some(d) = dead_end.pop() {
                if live[d as usize] > 0 {
                    return Some(d as usize);
                }
            }
            while cursor < vertices {
                if live[cursor] > 0 {
                    return Some(cursor);
                }
                cursor += 1;
            }
            None
        });
    }
    order
}

/// Orders a triangle list for the triangle codec: triangles by [`tipsify`], then vertices in the
/// order the triangles first use them (unused vertices last, in their order). Returns the new
/// indices and, per new vertex, its old index. The mesh is the same: the same triangles (same
/// winding) over the same vertices, listed in another order.
///
/// # Errors
/// An index count that is not a multiple of 3, an index at or past `vertices`.
pub fn optimize_order(indices: &[u32], vertices: usize) -> Result<(Vec<u32>, Vec<u32>), MeshoptError> {
    if !indices.len().is_multiple_of(3) {
        return Err(MeshoptError::NotTriangles(indices.len()));
    }
    if vertices > MAX_COUNT || indices.len() > MAX_COUNT {
        return Err(MeshoptError::TooMany {
            what: "vertices or indices",
            count: vertices.max(indices.len()),
            limit: MAX_COUNT,
        });
    }
    if indices.iter().any(|&i| i as usize >= vertices) {
        return Err(MeshoptError::Index("an index past the vertex count"));
    }
    let tris: Vec<[u32; 3]> = indices.chunks_exact(3).map(|t| [t[0], t[1], t[2]]).collect();
    let order = tipsify(&tris, vertices);
    let mut new_of = vec![u32::MAX; vertices];
    let mut old_of = Vec::with_capacity(vertices);
    let mut out = Vec::with_capacity(indices.len());
    for &t in &order {
        for &v in &tris[t] {
            let n = &mut new_of[v as usize];
            if *n == u32::MAX {
                *n = old_of.len() as u32;
                old_of.push(v);
            }
            out.push(*n);
        }
    }
    for (v, n) in new_of.iter_mut().enumerate() {
        if *n == u32::MAX {
            *n = old_of.len() as u32;
            old_of.push(v as u32);
        }
    }
    Ok((out, old_of))
}

/// The JSON and BIN chunks of a GLB.
///
/// # Errors
/// A header, chunk type or length that is not a GLB's.
pub fn read_glb(glb: &[u8]) -> Result<(Value, Vec<u8>), MeshoptError> {
    let bad = |m: &str| MeshoptError::Glb(m.to_owned());
    let u32_at = |at: usize| -> Result<usize, MeshoptError> {
        glb.get(at..at + 4)
            .and_then(|b| b.try_into().ok())
            .map(|b: [u8; 4]| u32::from_le_bytes(b) as usize)
            .ok_or_else(|| bad("truncated"))
    };
    if glb.get(..4) != Some(b"glTF") || u32_at(4)? != 2 || u32_at(8)? != glb.len() {
        return Err(bad("not a glTF 2.0 binary of this length"));
    }
    let jlen = u32_at(12)?;
    if u32_at(16)? != 0x4E4F_534A {
        return Err(bad("first chunk is not JSON"));
    }
    let text = glb.get(20..20 + jlen).ok_or_else(|| bad("JSON chunk runs past the end"))?;
    let json: Value =
        serde_json::from_slice(text).map_err(|e| MeshoptError::Glb(format!("JSON chunk: {e}")))?;
    let at = 20 + jlen;
    if at == glb.len() {
        return Ok((json, Vec::new()));
    }
    let blen = u32_at(at)?;
    if u32_at(at + 4)? != 0x004E_4942 {
        return Err(bad("second chunk is not BIN"));
    }
    let bin = glb.get(at + 8..at + 8 + blen).ok_or_else(|| bad("BIN chunk runs past the end"))?;
    Ok((json, bin.to_vec()))
}

fn as_usize(v: &Value) -> Option<usize> {
    v.as_u64().and_then(|n| usize::try_from(n).ok())
}

/// The `EXT_meshopt_compression` form of a plain GLB with one buffer (as [`super::glb()`] writes):
/// a mesh's triangles and vertices first put in an order with locality ([`optimize_order`]: the
/// same mesh, listed in another order), then every strided vertex view in the attribute codec, every index view in the triangle codec (8-bit
/// indices widened to 16 bits, which the codec needs), any other view stored as is. Buffer 0 is
/// the BIN chunk with the compressed data; buffer 1 the fallback, with no data.
///
/// # Errors
/// A GLB that is not one [`super::glb()`] writes (a second buffer, a view outside the BIN chunk,
/// an index view that is not a triangle list) or a stream the codecs refuse.
pub fn compress_glb(glb: &[u8]) -> Result<Vec<u8>, MeshoptError> {
    let (mut json, bin) = read_glb(glb)?;
    let bad = |m: &str| MeshoptError::Glb(m.to_owned());
    if json["buffers"].as_array().map_or(0, Vec::len) != 1 {
        return Err(bad("expected exactly one buffer"));
    }
    let views = json["bufferViews"].as_array().cloned().unwrap_or_default();
    let mut accessors = json["accessors"].as_array().cloned().unwrap_or_default();
    let reorder = reorder_mesh(&json, &views, &accessors, &bin)?;
    let mut packed = Vec::new();
    let mut fallback = 0usize;
    let mut octs = Vec::new();
    let mut new_views = Vec::with_capacity(views.len());
    for (i, view) in views.iter().enumerate() {
        let offset = as_usize(&view["byteOffset"]).unwrap_or(0);
        let len = as_usize(&view["byteLength"]).ok_or_else(|| bad("bufferView without byteLength"))?;
        let bytes = bin
            .get(offset..offset.saturating_add(len))
            .ok_or_else(|| bad("bufferView outside the BIN chunk"))?;
        let permuted;
        let bytes = match &reorder {
            Some(r) if r.vertex_views.contains(&i) => {
                let s = as_usize(&view["byteStride"]).unwrap_or(1);
                permuted = r
                    .old_of
                    .iter()
                    .flat_map(|&o| &bytes[o as usize * s..(o as usize + 1) * s])
                    .copied()
                    .collect::<Vec<u8>>();
                &permuted[..]
            }
            _ => bytes,
        };
        let users: Vec<usize> =
            (0..accessors.len()).filter(|&a| as_usize(&accessors[a]["bufferView"]) == Some(i)).collect();
        let target = view["target"].as_u64();
        let stride = as_usize(&view["byteStride"]);
        let (mode, stride, raw) = if target == Some(u64::from(ELEMENT_ARRAY_BUFFER)) {
            let component = users.first().and_then(|&a| accessors[a]["componentType"].as_u64()).unwrap_or(0);
            let indices: Vec<u32> = match u32::try_from(component).unwrap_or(0) {
                _ if reorder.as_ref().is_some_and(|r| r.index_view == i) => {
                    reorder.as_ref().map(|r| r.indices.clone()).unwrap_or_default()
                }
                GLTF_U8 => bytes.iter().map(|&b| u32::from(b)).collect(),
                GLTF_U16 => {
                    bytes.chunks_exact(2).map(|b| u32::from(u16::from_le_bytes([b[0], b[1]]))).collect()
                }
                GLTF_U32 => {
                    bytes.chunks_exact(4).map(|b| u32::from_le_bytes([b[0], b[1], b[2], b[3]])).collect()
                }
                _ => return Err(bad("index accessor of unknown component type")),
            };
            let wide = component == u64::from(GLTF_U32);
            if !wide {
                for &a in &users {
                    accessors[a]["componentType"] = json!(GLTF_U16);
                }
            }
            let (enc, _) = encode_index_buffer(&indices)?;
            ("TRIANGLES", if wide { 4 } else { 2 }, Some((enc, indices.len())))
        } else if let Some(s) = stride.filter(|s| s.is_multiple_of(4) && *s <= MAX_STRIDE) {
            // `BYTE` unit vectors (the normals) through the octahedral filter: two coordinates
            // carry what three did, and the codec's deltas shrink.
            let normals = s == 4
                && !users.is_empty()
                && users.iter().all(|&a| {
                    accessors[a]["componentType"].as_u64() == Some(GLTF_I8) && accessors[a]["type"] == "VEC3"
                });
            let enc = if normals {
                filter_oct_encode(bytes).and_then(|b| encode_vertex_buffer(&b, s))?
            } else {
                encode_vertex_buffer(bytes, s)?
            };
            if normals {
                octs.push(i);
            }
            ("ATTRIBUTES", s, Some((enc, len / s)))
        } else {
            ("", 0, None)
        };
        while !packed.len().is_multiple_of(4) {
            packed.push(0);
        }
        let mut v = view.clone();
        if let Some((enc, count)) = raw {
            while !fallback.is_multiple_of(4) {
                fallback += 1;
            }
            let full = count * stride;
            v["buffer"] = json!(1);
            v["byteOffset"] = json!(fallback);
            v["byteLength"] = json!(full);
            if mode == "ATTRIBUTES" {
                v["byteStride"] = json!(stride);
            }
            v["extensions"] = json!({ EXT: {
                "buffer": 0, "byteOffset": packed.len(), "byteLength": enc.len(),
                "byteStride": stride, "mode": mode, "count": count,
            }});
            if octs.contains(&i) {
                v["extensions"][EXT]["filter"] = json!("OCTAHEDRAL");
            }
            fallback += full;
            packed.extend_from_slice(&enc);
        } else {
            v["buffer"] = json!(0);
            v["byteOffset"] = json!(packed.len());
            packed.extend_from_slice(bytes);
        }
        new_views.push(v);
    }
    while !packed.len().is_multiple_of(4) {
        packed.push(0);
    }
    json["bufferViews"] = Value::Array(new_views);
    json["accessors"] = Value::Array(accessors);
    json["buffers"] = json!([
        { "byteLength": packed.len() },
        { "byteLength": fallback.max(1), "extensions": { EXT: { "fallback": true } } },
    ]);
    for list in ["extensionsUsed", "extensionsRequired"] {
        let mut names: Vec<Value> = json[list].as_array().cloned().unwrap_or_default();
        if !names.iter().any(|n| n == EXT) {
            names.push(json!(EXT));
        }
        json[list] = Value::Array(names);
    }
    Ok(write_glb(&json, packed))
}

/// A mesh's new order ([`optimize_order`]): its index view and indices, and the vertex views
/// permuted (new vertex `k` is old vertex `old_of[k]`).
struct Reorder {
    index_view: usize,
    indices: Vec<u32>,
    vertex_views: Vec<usize>,
    old_of: Vec<u32>,
}

/// The new order of the GLB's one indexed primitive, when it has one whose attribute views hold
/// exactly its vertices (as [`super::glb()`] writes them: one view per attribute).
fn reorder_mesh(
    json: &Value,
    views: &[Value],
    accessors: &[Value],
    bin: &[u8],
) -> Result<Option<Reorder>, MeshoptError> {
    let bad = |m: &str| MeshoptError::Glb(m.to_owned());
    let prims = json["meshes"]
        .as_array()
        .map(|m| {
            m.iter().flat_map(|m| m["primitives"].as_array().cloned().unwrap_or_default()).collect::<Vec<_>>()
        })
        .unwrap_or_default();
    let [prim] = &prims[..] else { return Ok(None) };
    let Some(ia) = as_usize(&prim["indices"]) else { return Ok(None) };
    if prim["mode"].as_u64().unwrap_or(4) != 4 {
        return Ok(None);
    }
    let acc = |a: usize| accessors.get(a).ok_or_else(|| bad("accessor index out of range"));
    let index_view =
        as_usize(&acc(ia)?["bufferView"]).ok_or_else(|| bad("index accessor without bufferView"))?;
    let attrs: Vec<usize> =
        prim["attributes"].as_object().map(|o| o.values().filter_map(as_usize).collect()).unwrap_or_default();
    let Some(&first) = attrs.first() else { return Ok(None) };
    let vertices = as_usize(&acc(first)?["count"]).unwrap_or(0);
    let mut vertex_views = Vec::new();
    for &a in &attrs {
        let a = acc(a)?;
        let Some(v) = as_usize(&a["bufferView"]) else { return Ok(None) };
        let view = views.get(v).ok_or_else(|| bad("bufferView index out of range"))?;
        let stride = as_usize(&view["byteStride"]).unwrap_or(0);
        let shared = accessors.iter().filter(|x| as_usize(&x["bufferView"]) == Some(v)).count();
        if as_usize(&a["count"]) != Some(vertices)
            || as_usize(&a["byteOffset"]).unwrap_or(0) != 0
            || stride == 0
            || as_usize(&view["byteLength"]) != Some(stride * vertices)
            || shared != 1
            || v == index_view
        {
            return Ok(None);
        }
        vertex_views.push(v);
    }
    let view = &views[index_view];
    let offset = as_usize(&view["byteOffset"]).unwrap_or(0);
    let len = as_usize(&view["byteLength"]).unwrap_or(0);
    let bytes =
        bin.get(offset..offset.saturating_add(len)).ok_or_else(|| bad("bufferView outside the BIN chunk"))?;
    let indices: Vec<u32> = match acc(ia)?["componentType"].as_u64().and_then(|c| u32::try_from(c).ok()) {
        Some(GLTF_U8) => bytes.iter().map(|&b| u32::from(b)).collect(),
        Some(GLTF_U16) => {
            bytes.chunks_exact(2).map(|b| u32::from(u16::from_le_bytes([b[0], b[1]]))).collect()
        }
        Some(GLTF_U32) => {
            bytes.chunks_exact(4).map(|b| u32::from_le_bytes([b[0], b[1], b[2], b[3]])).collect()
        }
        _ => return Err(bad("index accessor of unknown component type")),
    };
    let (indices, old_of) = optimize_order(&indices, vertices)?;
    Ok(Some(Reorder { index_view, indices, vertex_views, old_of }))
}

/// The plain form of a GLB of [`compress_glb`]: every compressed view decoded into one buffer
/// at the fallback's layout. For the round trips and for readers without the extension.
///
/// # Errors
/// A GLB that is not one [`compress_glb`] writes, or a stream that does not decode.
pub fn decompress_glb(glb: &[u8]) -> Result<(Value, Vec<u8>), MeshoptError> {
    let (mut json, bin) = read_glb(glb)?;
    let bad = |m: &str| MeshoptError::Glb(m.to_owned());
    let fallback = as_usize(&json["buffers"][1]["byteLength"]).ok_or_else(|| bad("no fallback buffer"))?;
    if fallback > bin.len().saturating_mul(64).max(BLOCK_BYTES) {
        return Err(bad("fallback buffer larger than its compressed data can hold"));
    }
    let mut out = vec![0u8; fallback];
    let views = json["bufferViews"].as_array().cloned().unwrap_or_default();
    let mut plain = Vec::with_capacity(views.len());
    for view in &views {
        let mut v = view.clone();
        if let Some(x) = view["extensions"].get(EXT) {
            let (o, l) = (as_usize(&x["byteOffset"]).unwrap_or(0), as_usize(&x["byteLength"]).unwrap_or(0));
            let (stride, count) =
                (as_usize(&x["byteStride"]).unwrap_or(0), as_usize(&x["count"]).unwrap_or(0));
            let src = bin
                .get(o..o.saturating_add(l))
                .ok_or_else(|| bad("compressed view outside the BIN chunk"))?;
            let bytes = match x["mode"].as_str() {
                Some("ATTRIBUTES") => {
                    let mut b = decode_vertex_buffer(src, count, stride)?;
                    match x["filter"].as_str() {
                        None | Some("NONE") => {}
                        Some("OCTAHEDRAL") if stride == 4 => filter_oct_decode(&mut b),
                        Some(f) => {
                            return Err(MeshoptError::Glb(format!("filter {f} with byteStride {stride}")));
                        }
                    }
                    b
                }
                Some("TRIANGLES") => {
                    let idx = decode_index_buffer(src, count)?;
                    match stride {
                        2 => idx
                            .iter()
                            .flat_map(|&i| u16::try_from(i).unwrap_or(u16::MAX).to_le_bytes())
                            .collect(),
                        4 => idx.iter().flat_map(|&i| i.to_le_bytes()).collect(),
                        _ => return Err(bad("TRIANGLES byteStride is not 2 or 4")),
                    }
                }
                _ => return Err(bad("unknown mode")),
            };
            let at = as_usize(&view["byteOffset"]).unwrap_or(0);
            out.get_mut(at..at.saturating_add(bytes.len()))
                .ok_or_else(|| bad("view outside the fallback buffer"))?
                .copy_from_slice(&bytes);
            if let Some(o) = v.as_object_mut() {
                o.remove("extensions");
            }
        } else {
            let (o, l) =
                (as_usize(&view["byteOffset"]).unwrap_or(0), as_usize(&view["byteLength"]).unwrap_or(0));
            let src = bin.get(o..o.saturating_add(l)).ok_or_else(|| bad("view outside the BIN chunk"))?;
            let at = out.len();
            out.extend_from_slice(src);
            v["byteOffset"] = json!(at);
        }
        v["buffer"] = json!(0);
        plain.push(v);
    }
    json["bufferViews"] = Value::Array(plain);
    json["buffers"] = json!([{ "byteLength": out.len() }]);
    Ok((json, out))
}

/// Normals (`BYTE` x, y, z and one unused byte each) as the octahedral filter's input
/// (Appendix B, filter 1, K = 8): x, y in 8-bit octahedral coordinates, 127 (1.0), 0. The
/// decoded vector is within about 1° of the given one (the two 8-bit quantizations together).
fn filter_oct_encode(bytes: &[u8]) -> Result<Vec<u8>, MeshoptError> {
    if !bytes.len().is_multiple_of(4) {
        return Err(MeshoptError::Ragged(bytes.len()));
    }
    Ok(bytes
        .chunks_exact(4)
        .flat_map(|n| {
            let v = [f64::from(n[0] as i8), f64::from(n[1] as i8), f64::from(n[2] as i8)];
            let l1 = v[0].abs() + v[1].abs() + v[2].abs();
            let [x, y, z] = if l1 > 0.0 { v.map(|c| c / l1) } else { [0.0, 0.0, 1.0] };
            let (fx, fy) =
                if z >= 0.0 { (x, y) } else { ((1.0 - y.abs()) * x.signum(), (1.0 - x.abs()) * y.signum()) };
            [(fx * 127.0).round() as i8 as u8, (fy * 127.0).round() as i8 as u8, 127, 0]
        })
        .collect())
}

/// The octahedral filter's decoding of 8-bit elements, as Appendix B writes it (in `f32`).
fn filter_oct_decode(bytes: &mut [u8]) {
    for e in bytes.chunks_exact_mut(4) {
        let one = f32::from(e[2] as i8);
        let (mut x, mut y) = (f32::from(e[0] as i8) / one, f32::from(e[1] as i8) / one);
        let z = 1.0 - x.abs() - y.abs();
        let t = z.min(0.0);
        x -= t.copysign(x);
        y -= t.copysign(y);
        let len = (x * x + y * y + z * z).sqrt();
        for (k, c) in [x, y, z].into_iter().enumerate() {
            e[k] = ((c / len) * 127.0).round() as i8 as u8;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn rng(seed: &mut u64) -> u64 {
        *seed ^= *seed << 13;
        *seed ^= *seed >> 7;
        *seed ^= *seed << 17;
        *seed
    }

    #[test]
    fn vertex_round_trip_all_widths() {
        let mut s = 7u64;
        for stride in [4, 8, 12, 16, 256] {
            for count in [0, 1, 15, 16, 17, 255, 256, 257, 1000, 3000] {
                let mut data = vec![0u8; stride * count];
                for (i, b) in data.iter_mut().enumerate() {
                    // Mixed: smooth, noisy and constant lanes.
                    *b = match i % stride % 4 {
                        0 => (i / stride) as u8,
                        1 => rng(&mut s) as u8,
                        2 => 9,
                        _ => ((i / stride) as u8).wrapping_mul(3) ^ (rng(&mut s) as u8 & 3),
                    };
                }
                let enc = encode_vertex_buffer(&data, stride).unwrap();
                assert_eq!(
                    decode_vertex_buffer(&enc, count, stride).unwrap(),
                    data,
                    "stride {stride} count {count}"
                );
            }
        }
    }

    #[test]
    fn vertex_codec_compresses_smooth_data() {
        let data: Vec<u8> = (0..4096u32).flat_map(|i| [(i & 255) as u8, (i >> 8) as u8, 0, 0]).collect();
        let enc = encode_vertex_buffer(&data, 4).unwrap();
        assert!(enc.len() * 3 < data.len(), "{} of {}", enc.len(), data.len());
    }

    #[test]
    fn index_round_trip_up_to_rotation() {
        let mut s = 3u64;
        // A grid mesh (shared edges), random triangles (explicit indices), and a large index.
        let mut grid = Vec::new();
        for y in 0..40u32 {
            for x in 0..40u32 {
                let v = y * 41 + x;
                grid.extend_from_slice(&[v, v + 1, v + 41, v + 1, v + 42, v + 41]);
            }
        }
        let random: Vec<u32> = (0..3000).map(|_| (rng(&mut s) % 500) as u32).collect();
        let big = vec![0, 1, 2, 2, 1, 70_000, 70_000, 1, 3, 5, 5, 5];
        for idx in [grid, random, big, vec![]] {
            let (enc, rotated) = encode_index_buffer(&idx).unwrap();
            let dec = decode_index_buffer(&enc, idx.len()).unwrap();
            assert_eq!(dec, rotated);
            for (t, r) in idx.chunks(3).zip(dec.chunks(3)) {
                let rots = [[t[0], t[1], t[2]], [t[1], t[2], t[0]], [t[2], t[0], t[1]]];
                assert!(rots.iter().any(|x| x == r), "{t:?} -> {r:?}");
            }
        }
    }

    #[test]
    fn index_round_trip_small_vertex_range() {
        // Few vertices: edges recur at every FIFO depth, including 15 (which the codec cannot
        // name: code 0xf? is the table's).
        let mut s = 5u64;
        for range in [4u64, 8, 20, 40] {
            let idx: Vec<u32> = (0..6000)
                .map(|_| (rng(&mut s) % range) as u32)
                .collect::<Vec<_>>()
                .chunks(3)
                .filter(|t| t[0] != t[1] && t[1] != t[2] && t[0] != t[2])
                .flatten()
                .copied()
                .collect();
            let (enc, rotated) = encode_index_buffer(&idx).unwrap();
            assert_eq!(decode_index_buffer(&enc, idx.len()).unwrap(), rotated, "range {range}");
        }
    }

    #[test]
    fn optimized_order_is_the_same_mesh() {
        let mut grid = Vec::new();
        for y in 0..30u32 {
            for x in 0..30u32 {
                let v = y * 31 + x;
                grid.extend_from_slice(&[v, v + 1, v + 31, v + 1, v + 32, v + 31]);
            }
        }
        // Triangles in a random order, as a greedy TIN's insertion leaves them.
        let mut s = 9u64;
        let mut tris: Vec<[u32; 3]> = grid.chunks(3).map(|t| [t[0], t[1], t[2]]).collect();
        for i in (1..tris.len()).rev() {
            tris.swap(i, (rng(&mut s) % (i as u64 + 1)) as usize);
        }
        let grid: Vec<u32> = tris.into_iter().flatten().collect();
        let n = 31 * 31 + 5; // five unused vertices
        let (idx, old_of) = optimize_order(&grid, n).unwrap();
        let mut seen = old_of.clone();
        seen.sort_unstable();
        assert_eq!(seen, (0..n as u32).collect::<Vec<_>>());
        let canon =
            |t: [u32; 3]| *[[t[0], t[1], t[2]], [t[1], t[2], t[0]], [t[2], t[0], t[1]]].iter().min().unwrap();
        let mut a: Vec<_> = grid.chunks(3).map(|t| canon([t[0], t[1], t[2]])).collect();
        let mut b: Vec<_> = idx
            .chunks(3)
            .map(|t| canon([old_of[t[0] as usize], old_of[t[1] as usize], old_of[t[2] as usize]]))
            .collect();
        a.sort_unstable();
        b.sort_unstable();
        assert_eq!(a, b);
        let (plain, _) = encode_index_buffer(&grid).unwrap();
        let (ordered, _) = encode_index_buffer(&idx).unwrap();
        assert!(ordered.len() < plain.len(), "{} vs {}", ordered.len(), plain.len());
        assert!(optimize_order(&[0, 1, 9], 9).is_err());
    }

    #[test]
    fn index_codec_compresses_a_grid() {
        let mut grid = Vec::new();
        for y in 0..50u32 {
            for x in 0..50u32 {
                let v = y * 51 + x;
                grid.extend_from_slice(&[v, v + 1, v + 51, v + 1, v + 52, v + 51]);
            }
        }
        let (enc, _) = encode_index_buffer(&grid).unwrap();
        assert!(enc.len() < grid.len() * 2 / 3, "{} bytes for {} indices", enc.len(), grid.len());
    }

    #[test]
    fn bad_inputs_are_errors() {
        assert_eq!(encode_vertex_buffer(&[0; 6], 6), Err(MeshoptError::Stride(6)));
        assert_eq!(encode_vertex_buffer(&[0; 6], 4), Err(MeshoptError::Ragged(6)));
        assert_eq!(encode_index_buffer(&[0, 1]), Err(MeshoptError::NotTriangles(2)));
        assert!(decode_vertex_buffer(&[0xa0], 1, 4).is_err());
        assert!(decode_vertex_buffer(&[0xa0; 40], usize::MAX / 8, 8).is_err());
        assert!(decode_index_buffer(&[0xe1; 20], 3 << 20).is_err());
        let enc = encode_vertex_buffer(&[1, 2, 3, 4, 9, 9, 9, 9], 4).unwrap();
        for cut in 0..enc.len() {
            assert!(decode_vertex_buffer(&enc[..cut], 2, 4).is_err());
        }
    }

    #[test]
    fn random_bytes_never_panic() {
        let mut s = 11u64;
        for n in 0..2000usize {
            let len = n % 200;
            let mut b: Vec<u8> = (0..len).map(|_| rng(&mut s) as u8).collect();
            if let Some(h) = b.first_mut() {
                *h = if n % 2 == 0 { 0xa0 } else { 0xe1 };
            }
            let _ = decode_vertex_buffer(&b, n % 300, 4 * (1 + n % 5));
            let _ = decode_index_buffer(&b, 3 * (n % 50));
            let _ = decompress_glb(&b);
            let _ = compress_glb(&b);
        }
    }

    #[test]
    fn octahedral_filter_keeps_byte_normals_within_a_degree_and_a_half() {
        let mut bytes = Vec::new();
        for x in (-127i32..=127).step_by(9) {
            for y in (-127i32..=127).step_by(9) {
                for z in [-127, -90, -40, -1, 0, 1, 40, 90, 127] {
                    bytes.extend_from_slice(&[x as i8 as u8, y as i8 as u8, z as i8 as u8, 0]);
                }
            }
        }
        let mut dec = filter_oct_encode(&bytes).unwrap();
        assert!(dec.chunks_exact(4).all(|e| e[2] == 127 && e[3] == 0));
        filter_oct_decode(&mut dec);
        for (a, b) in bytes.chunks_exact(4).zip(dec.chunks_exact(4)) {
            let v = |e: &[u8]| [0, 1, 2].map(|k| f64::from(e[k] as i8));
            let (p, q) = (v(a), v(b));
            let l = |w: [f64; 3]| (w[0] * w[0] + w[1] * w[1] + w[2] * w[2]).sqrt();
            if l(p) == 0.0 {
                continue;
            }
            let cos = (p[0] * q[0] + p[1] * q[1] + p[2] * q[2]) / (l(p) * l(q));
            assert!(cos > 1.5f64.to_radians().cos(), "{p:?} → {q:?}");
            assert!((l(q) / 127.0 - 1.0).abs() < 0.02, "{q:?} is not a unit vector");
        }
        assert!(filter_oct_encode(&[1, 2, 3]).is_err());
    }
}
