//! The quantized-mesh-1.0 binary format: encoder, bounds-checked decoder, and the extension
//! filter that serves one stored tile (made with every extension) to clients that asked for
//! fewer. Little-endian throughout: the 88-byte header, vertex data (u, v, height as zig-zag
//! deltas), indices by high-water mark (16-bit, or 32-bit above 65,536 vertices), the four edge
//! index lists, then extensions as (id, length, bytes).

/// Extension ids of the format.
pub const EXT_NORMALS: u8 = 1;
pub const EXT_WATERMASK: u8 = 2;
pub const EXT_METADATA: u8 = 4;

/// The largest quantized coordinate.
pub const QMAX: u16 = 32767;
/// Vertices above which indices are 32-bit (the format's rule: `vertexCount > 64 × 1024`).
pub const INDEX32_ABOVE: usize = 65_536;
const HEADER_LEN: usize = 88;

/// The header: what a client culls and places the tile by.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct Header {
    /// The tile's centre, ECEF metres (what vertices are relative to on the client).
    pub center: [f64; 3],
    pub min_height: f32,
    pub max_height: f32,
    pub sphere_center: [f64; 3],
    pub sphere_radius: f64,
    /// The horizon-occlusion point, in ellipsoid-scaled ECEF (ECEF divided by the radii).
    pub horizon: [f64; 3],
}

/// A tile's water mask: one value for the whole tile, or 256 × 256 bytes from the north-west
/// corner, rows north to south, west to east (0 land, 255 water).
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum WaterMask {
    Uniform(u8),
    Grid(Vec<u8>),
}

/// Side of a water mask grid.
pub const WATERMASK_SIDE: usize = 256;

/// One tile, decoded.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct QmTile {
    pub header: Header,
    pub u: Vec<u16>,
    pub v: Vec<u16>,
    pub h: Vec<u16>,
    /// Counter-clockwise seen from above; vertices numbered in order of first use.
    pub triangles: Vec<[u32; 3]>,
    pub west: Vec<u32>,
    pub south: Vec<u32>,
    pub east: Vec<u32>,
    pub north: Vec<u32>,
    /// Oct-encoded unit normals (ECEF), one per vertex.
    pub normals: Option<Vec<[u8; 2]>>,
    pub watermask: Option<WaterMask>,
    /// The metadata extension's JSON (child availability).
    pub metadata: Option<String>,
}

/// Why bytes are not a quantized-mesh tile, or a tile cannot be encoded.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum QmError {
    #[error("quantized-mesh: truncated at byte {at} reading {what}")]
    Truncated { at: usize, what: &'static str },
    #[error("quantized-mesh: {0}")]
    Invalid(String),
}

fn invalid(m: impl Into<String>) -> QmError {
    QmError::Invalid(m.into())
}

fn zigzag(v: i32) -> u16 {
    ((v << 1) ^ (v >> 31)) as u16
}

fn unzigzag(v: u16) -> i32 {
    i32::from(v >> 1) ^ -i32::from(v & 1)
}

/// Indices are 32-bit for meshes of more than [`INDEX32_ABOVE`] vertices.
#[must_use]
pub fn wide_indices(vertices: usize) -> bool {
    vertices > INDEX32_ABOVE
}

/// Encodes `t`. Its vertices must be numbered in order of first use by the triangles (the
/// high-water-mark code needs it; the builder orders them so).
pub fn encode(t: &QmTile) -> Result<Vec<u8>, QmError> {
    let n = t.u.len();
    if t.v.len() != n || t.h.len() != n {
        return Err(invalid("u, v and height arrays differ in length"));
    }
    if t.u.iter().chain(&t.v).chain(&t.h).any(|&q| q > QMAX) {
        return Err(invalid("a quantized value exceeds 32767"));
    }
    let n32 = u32::try_from(n).map_err(|_| invalid("too many vertices"))?;
    let wide = wide_indices(n);
    let mut out = Vec::with_capacity(HEADER_LEN + 4 + 6 * n + 12 * t.triangles.len() + 64);
    let h = &t.header;
    for c in h.center {
        out.extend_from_slice(&c.to_le_bytes());
    }
    out.extend_from_slice(&h.min_height.to_le_bytes());
    out.extend_from_slice(&h.max_height.to_le_bytes());
    for c in h.sphere_center {
        out.extend_from_slice(&c.to_le_bytes());
    }
    out.extend_from_slice(&h.sphere_radius.to_le_bytes());
    for c in h.horizon {
        out.extend_from_slice(&c.to_le_bytes());
    }
    out.extend_from_slice(&n32.to_le_bytes());
    for arr in [&t.u, &t.v, &t.h] {
        let mut prev = 0i32;
        for &q in arr.as_slice() {
            let q = i32::from(q);
            out.extend_from_slice(&zigzag(q - prev).to_le_bytes());
            prev = q;
        }
    }
    if wide {
        while out.len() % 4 != 0 {
            out.push(0);
        }
    }
    let tc = u32::try_from(t.triangles.len()).map_err(|_| invalid("too many triangles"))?;
    out.extend_from_slice(&tc.to_le_bytes());
    let push = |out: &mut Vec<u8>, v: u32| {
        if wide {
            out.extend_from_slice(&v.to_le_bytes());
        } else {
            out.extend_from_slice(&(v as u16).to_le_bytes());
        }
    };
    let mut highest = 0u32;
    for tri in &t.triangles {
        for &i in tri {
            if i >= n32 {
                return Err(invalid(format!("index {i} beyond {n} vertices")));
            }
            if i > highest {
                return Err(invalid(format!("vertex {i} is used before vertex {highest}")));
            }
            push(&mut out, highest - i);
            if i == highest {
                highest += 1;
            }
        }
    }
    for list in [&t.west, &t.south, &t.east, &t.north] {
        out.extend_from_slice(&(list.len() as u32).to_le_bytes());
        for &i in list {
            if i >= n32 {
                return Err(invalid(format!("edge index {i} beyond {n} vertices")));
            }
            push(&mut out, i);
        }
    }
    if let Some(normals) = &t.normals {
        if normals.len() != n {
            return Err(invalid("one normal per vertex"));
        }
        extension(&mut out, EXT_NORMALS, &normals.concat());
    }
    if let Some(w) = &t.watermask {
        match w {
            WaterMask::Uniform(v) => extension(&mut out, EXT_WATERMASK, &[*v]),
            WaterMask::Grid(g) => {
                if g.len() != WATERMASK_SIDE * WATERMASK_SIDE {
                    return Err(invalid("a water mask grid is 256 × 256 bytes"));
                }
                extension(&mut out, EXT_WATERMASK, g);
            }
        }
    }
    if let Some(json) = &t.metadata {
        let mut body = (json.len() as u32).to_le_bytes().to_vec();
        body.extend_from_slice(json.as_bytes());
        extension(&mut out, EXT_METADATA, &body);
    }
    Ok(out)
}

fn extension(out: &mut Vec<u8>, id: u8, body: &[u8]) {
    out.push(id);
    out.extend_from_slice(&(body.len() as u32).to_le_bytes());
    out.extend_from_slice(body);
}

struct Reader<'a> {
    b: &'a [u8],
    at: usize,
}

impl<'a> Reader<'a> {
    fn take(&mut self, n: usize, what: &'static str) -> Result<&'a [u8], QmError> {
        let end = self.at.checked_add(n).filter(|&e| e <= self.b.len());
        let end = end.ok_or(QmError::Truncated { at: self.at, what })?;
        let s = &self.b[self.at..end];
        self.at = end;
        Ok(s)
    }
    fn f64(&mut self, what: &'static str) -> Result<f64, QmError> {
        Ok(f64::from_le_bytes(self.take(8, what)?.try_into().unwrap_or_default()))
    }
    fn f32(&mut self, what: &'static str) -> Result<f32, QmError> {
        Ok(f32::from_le_bytes(self.take(4, what)?.try_into().unwrap_or_default()))
    }
    fn u32(&mut self, what: &'static str) -> Result<u32, QmError> {
        Ok(u32::from_le_bytes(self.take(4, what)?.try_into().unwrap_or_default()))
    }
    fn u16s(&mut self, n: usize, what: &'static str) -> Result<Vec<u16>, QmError> {
        let bytes = self.take(n.checked_mul(2).ok_or(QmError::Truncated { at: self.at, what })?, what)?;
        Ok(bytes.chunks_exact(2).map(|c| u16::from_le_bytes([c[0], c[1]])).collect())
    }
    fn indices(&mut self, n: usize, wide: bool, what: &'static str) -> Result<Vec<u32>, QmError> {
        if wide {
            let bytes = self.take(n.checked_mul(4).ok_or(QmError::Truncated { at: self.at, what })?, what)?;
            Ok(bytes.chunks_exact(4).map(|c| u32::from_le_bytes([c[0], c[1], c[2], c[3]])).collect())
        } else {
            Ok(self.u16s(n, what)?.into_iter().map(u32::from).collect())
        }
    }
}

/// Where the extensions start, and the tile up to them.
fn decode_body(b: &[u8]) -> Result<(QmTile, usize), QmError> {
    let mut r = Reader { b, at: 0 };
    let mut h = Header::default();
    for c in &mut h.center {
        *c = r.f64("the header")?;
    }
    h.min_height = r.f32("the header")?;
    h.max_height = r.f32("the header")?;
    for c in &mut h.sphere_center {
        *c = r.f64("the header")?;
    }
    h.sphere_radius = r.f64("the header")?;
    for c in &mut h.horizon {
        *c = r.f64("the header")?;
    }
    let n = r.u32("the vertex count")? as usize;
    // Bytes bound every count before anything is allocated.
    if n.saturating_mul(6) > b.len() {
        return Err(QmError::Truncated { at: r.at, what: "the vertex data" });
    }
    let mut arrays = [Vec::new(), Vec::new(), Vec::new()];
    for a in &mut arrays {
        let raw = r.u16s(n, "the vertex data")?;
        let mut acc = 0i32;
        *a = raw
            .into_iter()
            .map(|d| {
                acc += unzigzag(d);
                u16::try_from(acc).ok().filter(|&q| q <= QMAX)
            })
            .collect::<Option<Vec<u16>>>()
            .ok_or_else(|| invalid("a vertex coordinate leaves 0..=32767"))?;
    }
    let [u, v, hh] = arrays;
    let wide = wide_indices(n);
    if wide {
        while !r.at.is_multiple_of(4) {
            r.take(1, "padding")?;
        }
    }
    let tc = r.u32("the triangle count")? as usize;
    if tc.saturating_mul(3).saturating_mul(if wide { 4 } else { 2 }) > b.len() {
        return Err(QmError::Truncated { at: r.at, what: "the indices" });
    }
    let codes = r.indices(tc * 3, wide, "the indices")?;
    let mut highest = 0u32;
    let mut flat = Vec::with_capacity(codes.len());
    for c in codes {
        let i = highest.checked_sub(c).ok_or_else(|| invalid("an index code exceeds the high-water mark"))?;
        if i as usize >= n {
            return Err(invalid(format!("index {i} beyond {n} vertices")));
        }
        flat.push(i);
        if c == 0 {
            highest += 1;
        }
    }
    let triangles = flat.chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect();
    let mut lists: [Vec<u32>; 4] = Default::default();
    for l in &mut lists {
        let k = r.u32("an edge list")? as usize;
        if k.saturating_mul(2) > b.len() {
            return Err(QmError::Truncated { at: r.at, what: "an edge list" });
        }
        *l = r.indices(k, wide, "an edge list")?;
        if l.iter().any(|&i| i as usize >= n) {
            return Err(invalid("an edge index beyond the vertices"));
        }
    }
    let [west, south, east, north] = lists;
    let t = QmTile { header: h, u, v, h: hh, triangles, west, south, east, north, ..QmTile::default() };
    Ok((t, r.at))
}

/// An extension: its id, the byte range of its whole block, and of its body.
type ExtensionAt = (u8, std::ops::Range<usize>, std::ops::Range<usize>);

/// The extensions after `start`: (id, byte range of the whole block, body range).
fn extensions(b: &[u8], start: usize) -> Result<Vec<ExtensionAt>, QmError> {
    let mut r = Reader { b, at: start };
    let mut out = Vec::new();
    while r.at < b.len() {
        let s = r.at;
        let id = r.take(1, "an extension id")?[0];
        let len = r.u32("an extension length")? as usize;
        let body = r.at;
        r.take(len, "an extension")?;
        out.push((id, s..r.at, body..r.at));
    }
    Ok(out)
}

/// Decodes a tile, every extension included (unknown ones are skipped).
pub fn decode(b: &[u8]) -> Result<QmTile, QmError> {
    let (mut t, end) = decode_body(b)?;
    let n = t.u.len();
    for (id, _, body) in extensions(b, end)? {
        let body = &b[body];
        match id {
            EXT_NORMALS => {
                if body.len() != 2 * n {
                    return Err(invalid("the normals extension holds 2 bytes per vertex"));
                }
                t.normals = Some(body.chunks_exact(2).map(|c| [c[0], c[1]]).collect());
            }
            EXT_WATERMASK => {
                t.watermask = Some(match body.len() {
                    1 => WaterMask::Uniform(body[0]),
                    65_536 => WaterMask::Grid(body.to_vec()),
                    l => return Err(invalid(format!("a water mask of {l} bytes (1 or 65536)"))),
                });
            }
            EXT_METADATA => {
                let len = body
                    .get(..4)
                    .map(|l| u32::from_le_bytes([l[0], l[1], l[2], l[3]]) as usize)
                    .ok_or_else(|| invalid("the metadata extension lacks its JSON length"))?;
                if len + 4 != body.len() {
                    return Err(invalid("the metadata JSON length disagrees with the extension's"));
                }
                let s = std::str::from_utf8(&body[4..]).map_err(|_| invalid("metadata is not UTF-8"))?;
                t.metadata = Some(s.to_owned());
            }
            _ => {}
        }
    }
    Ok(t)
}

/// The extensions a client asked for.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct Extensions {
    pub normals: bool,
    pub watermask: bool,
    pub metadata: bool,
}

impl Extensions {
    pub const ALL: Self = Self { normals: true, watermask: true, metadata: true };

    fn wants(self, id: u8) -> bool {
        match id {
            EXT_NORMALS => self.normals,
            EXT_WATERMASK => self.watermask,
            EXT_METADATA => self.metadata,
            _ => false,
        }
    }

    /// The extensions an `Accept` header names, and whether it accepts quantized-mesh at all
    /// (`application/vnd.quantized-mesh`, `application/octet-stream`, `application/*` or `*/*`
    /// not at q=0; no header accepts everything). `extensions=a-b-c` is read on any accepted
    /// range: CesiumJS puts it on the quantized-mesh type
    /// (`application/vnd.quantized-mesh;extensions=octvertexnormals-watermask-metadata,*/*;q=0.01`),
    /// 3DTilesRendererJS after `application/octet-stream;q=0.9`.
    #[must_use]
    pub fn from_accept(accept: Option<&str>) -> (Self, bool) {
        let Some(accept) = accept else { return (Self::default(), true) };
        let mut ext = Self::default();
        let mut ok = false;
        for range in accept.split(',') {
            let mut parts = range.split(';').map(str::trim);
            let ty = parts.next().unwrap_or_default().to_ascii_lowercase();
            let params: Vec<(&str, &str)> =
                parts.filter_map(|p| p.split_once('=')).map(|(k, v)| (k.trim(), v.trim())).collect();
            let q_zero = params
                .iter()
                .any(|(k, v)| k.eq_ignore_ascii_case("q") && v.parse::<f64>().is_ok_and(|q| q == 0.0));
            let accepted = matches!(
                ty.as_str(),
                "application/vnd.quantized-mesh" | "application/octet-stream" | "application/*" | "*/*"
            );
            if q_zero || !accepted {
                continue;
            }
            ok = true;
            for (k, v) in &params {
                if k.eq_ignore_ascii_case("extensions") {
                    for name in v.trim_matches('"').split('-') {
                        match name {
                            "octvertexnormals" | "vertexnormals" => ext.normals = true,
                            "watermask" => ext.watermask = true,
                            "metadata" => ext.metadata = true,
                            _ => {}
                        }
                    }
                }
            }
        }
        (ext, ok)
    }
}

/// The tile `b` with only the extensions in `keep` (in their stored order).
pub fn filter_extensions(b: &[u8], keep: Extensions) -> Result<Vec<u8>, QmError> {
    let (_, end) = decode_body(b)?;
    let exts = extensions(b, end)?;
    let mut out = b[..end].to_vec();
    for (id, block, _) in exts {
        if keep.wants(id) {
            out.extend_from_slice(&b[block]);
        }
    }
    Ok(out)
}

/// A tile gzipped as served and counted (level 6).
#[must_use]
pub fn gzip(b: &[u8]) -> Vec<u8> {
    use std::io::Write;
    let mut e = flate2::write::GzEncoder::new(Vec::with_capacity(b.len() / 2), flate2::Compression::new(6));
    let _ = e.write_all(b);
    e.finish().unwrap_or_default()
}

/// Oct-encodes a unit vector into two bytes (CesiumJS's `AttributeCompression.octEncode`).
#[must_use]
pub fn oct_encode(n: [f64; 3]) -> [u8; 2] {
    // Rounding residue (a pole's east component, 1e-17) must not pick a sign: it would flip
    // the encoding between the two corners that both mean straight down.
    let n = n.map(|c| if c.abs() < 1e-12 { 0.0 } else { c });
    let l1 = n[0].abs() + n[1].abs() + n[2].abs();
    if l1 == 0.0 || !l1.is_finite() {
        return [128, 128];
    }
    let (mut x, mut y) = (n[0] / l1, n[1] / l1);
    if n[2] < 0.0 {
        let (ox, oy) = (x, y);
        x = (1.0 - oy.abs()) * if ox >= 0.0 { 1.0 } else { -1.0 };
        y = (1.0 - ox.abs()) * if oy >= 0.0 { 1.0 } else { -1.0 };
    }
    let snorm = |v: f64| -> u8 { ((v.clamp(-1.0, 1.0) * 0.5 + 0.5) * 255.0).round() as u8 };
    [snorm(x), snorm(y)]
}

/// Decodes [`oct_encode`]'s two bytes to a unit vector.
#[must_use]
pub fn oct_decode(b: [u8; 2]) -> [f64; 3] {
    let f = |v: u8| f64::from(v) / 255.0 * 2.0 - 1.0;
    let (mut x, mut y) = (f(b[0]), f(b[1]));
    let z = 1.0 - (x.abs() + y.abs());
    if z < 0.0 {
        let (ox, oy) = (x, y);
        x = (1.0 - oy.abs()) * if ox >= 0.0 { 1.0 } else { -1.0 };
        y = (1.0 - ox.abs()) * if oy >= 0.0 { 1.0 } else { -1.0 };
    }
    let l = (x * x + y * y + z * z).sqrt();
    [x / l, y / l, z / l]
}

#[cfg(test)]
mod tests {
    use super::*;

    fn strip(n: u32) -> QmTile {
        // A strip of 2n vertices: triangles reference vertices in order of first use.
        let mut t = QmTile::default();
        for k in 0..n {
            for side in 0..2u32 {
                t.u.push((k * 32767 / (n - 1)) as u16);
                t.v.push((side * 32767) as u16);
                t.h.push(((k * 7919 + side * 13) % 32768) as u16);
            }
        }
        for k in 0..n - 1 {
            let (a, b, c, d) = (2 * k, 2 * k + 1, 2 * k + 2, 2 * k + 3);
            t.triangles.push([a, b, c]);
            t.triangles.push([b, c, d]);
        }
        t.west = vec![0, 1];
        t.east = vec![2 * n - 2, 2 * n - 1];
        t.south = (0..n).map(|k| 2 * k).collect();
        t.north = (0..n).map(|k| 2 * k + 1).collect();
        t.header.min_height = -12.5;
        t.header.max_height = 400.25;
        t.header.horizon = [0.1, 0.2, 1.01];
        t
    }

    #[test]
    fn round_trip_with_every_extension() {
        let mut t = strip(50);
        t.normals = Some((0..100).map(|k| [k as u8, 255 - k as u8]).collect());
        t.watermask = Some(WaterMask::Grid((0..65_536).map(|k| (k % 251) as u8).collect()));
        t.metadata = Some(r#"{"available":[[{"startX":0,"startY":0,"endX":1,"endY":1}]]}"#.into());
        let b = encode(&t).unwrap();
        assert_eq!(decode(&b).unwrap(), t);
        // Filtering keeps the body and the asked-for extensions only.
        let only = filter_extensions(&b, Extensions { metadata: true, ..Extensions::default() }).unwrap();
        let d = decode(&only).unwrap();
        assert_eq!((d.normals, d.watermask, d.metadata.clone()), (None, None, t.metadata.clone()));
        assert_eq!(d.triangles, t.triangles);
        let none = filter_extensions(&b, Extensions::default()).unwrap();
        assert!(none.len() < only.len());
    }

    #[test]
    fn index_width_switches_above_65536_vertices() {
        // 65,536 vertices: 16-bit indices (index 65535 fits); 65,538: 32-bit.
        for (n, wide) in [(32_768u32, false), (32_769, true)] {
            let t = strip(n);
            assert_eq!(wide_indices(t.u.len()), wide);
            let b = encode(&t).unwrap();
            let d = decode(&b).unwrap();
            assert_eq!(d, t, "{} vertices", t.u.len());
            if wide {
                let idx_start = 88 + 4 + 6 * t.u.len();
                assert_eq!(idx_start.next_multiple_of(4) % 4, 0);
            }
        }
    }

    #[test]
    fn refuses_bad_tiles() {
        let mut t = strip(3);
        t.triangles[0] = [0, 2, 1];
        assert!(encode(&t).is_err(), "a vertex used before its turn");
        let b = encode(&strip(3)).unwrap();
        for cut in [0, 10, 88, 95, b.len() - 1] {
            assert!(decode(&b[..cut]).is_err(), "cut at {cut}");
        }
        let mut huge = b.clone();
        huge[88..92].copy_from_slice(&u32::MAX.to_le_bytes());
        assert!(matches!(decode(&huge), Err(QmError::Truncated { .. })));
    }

    #[test]
    fn accept_negotiation() {
        let (e, ok) = Extensions::from_accept(Some(
            "application/vnd.quantized-mesh;extensions=octvertexnormals-watermask-metadata,*/*;q=0.01",
        ));
        assert!(ok && e == Extensions::ALL);
        let (e, ok) =
            Extensions::from_accept(Some("application/vnd.quantized-mesh,application/octet-stream;q=0.9"));
        assert!(ok && e == Extensions::default());
        let (_, ok) = Extensions::from_accept(Some("image/png"));
        assert!(!ok);
        // 3DTilesRendererJS's QuantizedMeshPlugin: the parameter after the octet-stream range.
        let (e, ok) = Extensions::from_accept(Some(
            "application/vnd.quantized-mesh,application/octet-stream;q=0.9;extensions=octvertexnormals-watermask-metadata",
        ));
        assert!(ok && e == Extensions::ALL);
        // Not on a refused range.
        let (e, ok) = Extensions::from_accept(Some("image/png;extensions=metadata"));
        assert!(!ok && e == Extensions::default());
        let (_, ok) = Extensions::from_accept(Some("application/vnd.quantized-mesh;q=0"));
        assert!(!ok);
    }

    #[test]
    fn oct_round_trip() {
        for n in [[0.0f64, 0.0, 1.0], [0.0, 0.0, -1.0], [0.6, -0.8, 0.0], [0.3, 0.4, -0.866]] {
            let l = (n[0] * n[0] + n[1] * n[1] + n[2] * n[2]).sqrt();
            let n = [n[0] / l, n[1] / l, n[2] / l];
            let d = oct_decode(oct_encode(n));
            let dot = n[0] * d[0] + n[1] * d[1] + n[2] * d[2];
            assert!(dot > 0.9995, "{n:?} -> {d:?}");
        }
    }
}
