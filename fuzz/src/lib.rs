//! Invariant checks shared by the fuzz targets in `fuzz_targets/`: each target feeds bytes to
//! one decoder and calls the check here, which panics (a libFuzzer crash) when an `Ok` value
//! breaks what the decoder promises, or an error breaks what errors promise.

#![forbid(unsafe_code)]

use std::path::Path;

use terrastream::codec::{self, Blob, BlobHeader, Geometry};
use terrastream::geom::{Mesh, PointCloud};
use terrastream::model::{self, FileType};
use terrastream::raster::{self, HeightEncoding, Limits, LoadOptions};

/// Small limits so a hostile header can never make a decoder allocate near the 512 MB RSS limit
/// the campaign runs under.
pub const LIMITS: Limits = Limits { max_side: 4096, max_bytes: 16 << 20 };

/// With `TS_FUZZ_SHOW` set, prints what each input decoded to (to see which seeds get past
/// the header: `TS_FUZZ_SHOW=1 fuzz/target/.../raster_geotiff -runs=0 fuzz/seeds/raster_geotiff`).
pub fn show(what: impl FnOnce() -> String) {
    if std::env::var_os("TS_FUZZ_SHOW").is_some() {
        eprintln!("TS_FUZZ_SHOW: {}", what());
    }
}

/// Decodes `data` as a raster file called `name` and checks the result.
pub fn check_raster(name: &str, data: &[u8], encoding: Option<HeightEncoding>, channel: Option<&str>) {
    let opts = LoadOptions {
        encoding,
        channel: channel.map(str::to_owned),
        limits: LIMITS,
        ..LoadOptions::default()
    };
    check_loaded(name, raster::load_bytes(Path::new(name), data, &opts));
}

/// Decodes `data` as an SRTM tile called `name` with `side` samples a side (any side: see
/// [`raster::load_hgt_bytes_any_side`]) and checks the result as [`check_raster`] does.
pub fn check_hgt_any_side(name: &str, data: &[u8], side: u32) {
    let opts = LoadOptions { limits: LIMITS, ..LoadOptions::default() };
    check_loaded(name, raster::load_hgt_bytes_any_side(Path::new(name), data, side, &opts));
}

/// The invariants of a raster decode: a raster within the limits with finite heights and
/// frame, or an error that starts with the file's name.
fn check_loaded(name: &str, result: Result<raster::LoadedRaster, raster::RasterError>) {
    show(|| match &result {
        Ok(r) => format!("Ok {} {}x{} {:?}", r.format, r.heights.width, r.heights.height, r.georef),
        Err(e) => format!("Err {e}"),
    });
    match result {
        Ok(r) => {
            let h = &r.heights;
            assert!(h.width > 0 && h.height > 0, "zero-size raster {}x{}", h.width, h.height);
            assert!(
                h.width <= LIMITS.max_side && h.height <= LIMITS.max_side,
                "{}x{} over max_side",
                h.width,
                h.height
            );
            assert_eq!(h.width as usize * h.height as usize, h.data.len(), "width*height != data.len()");
            assert!(h.data.len() as u64 * 4 <= LIMITS.max_bytes, "{} samples over max_bytes", h.data.len());
            if let Some(i) = h.data.iter().position(|v| !v.is_finite()) {
                panic!("height {i} is {}", h.data[i]);
            }
            assert!(r.nodata_filled < h.data.len() as u64, "filled {} of {}", r.nodata_filled, h.data.len());
            let g = r.georef;
            for (what, v) in
                [("x0", g.x0), ("y0", g.y0), ("dx", g.dx), ("dy", g.dy), ("z0", g.z0), ("dz", g.dz)]
            {
                assert!(v.is_finite(), "georef {what} = {v} ({g:?})");
            }
            assert!(g.dx != 0.0 && g.dy != 0.0 && g.dz != 0.0, "zero georef step {g:?}");
            if let Some(m) = &g.crs {
                for v in [m.e0, m.n0, m.de, m.dn] {
                    assert!(v.is_finite(), "grid in its CRS {m:?}");
                }
            }
            // World coordinates of the far corner must be finite too, or every later stage
            // (tiling, bounds, blobs) works on infinities.
            let far_x = g.x0 + g.dx * f64::from(h.width - 1);
            let far_y = g.y0 + g.dy * f64::from(h.height - 1);
            assert!(far_x.is_finite() && far_y.is_finite(), "far corner ({far_x}, {far_y}) for {g:?}");
        }
        Err(e) => {
            let msg = e.to_string();
            assert!(msg.starts_with(&format!("{name}: ")), "error does not name the file: {msg}");
        }
    }
}

/// Parses `data` as a model of type `ty` and checks the result.
pub fn check_model(data: &[u8], ty: FileType) {
    let name = match ty {
        FileType::Obj => "fuzz.obj",
        FileType::Stl => "fuzz.stl",
        FileType::Ply => "fuzz.ply",
    };
    let result = model::parse(data, name, Some(ty));
    show(|| match &result {
        Ok(m) => format!("Ok {:?} {:?}", m.encoding, m.stats),
        Err(e) => format!("Err {e}"),
    });
    let Ok(m) = result else { return };
    check_mesh(&m.mesh);
    let n = m.mesh.positions.len();
    assert!(n <= model::MAX_MODEL_ELEMENTS && m.mesh.triangles.len() <= model::MAX_MODEL_ELEMENTS);
    assert!(!m.mesh.triangles.is_empty(), "Ok model without triangles");
    assert_eq!(m.normals.len(), n, "one normal per vertex");
    for (i, nv) in m.normals.iter().enumerate() {
        let len = nv.iter().map(|c| f64::from(*c).powi(2)).sum::<f64>().sqrt();
        assert!((len - 1.0).abs() < 1e-3, "normal {i} {nv:?} is not a unit vector");
    }
    let mut used = vec![false; n];
    for t in &m.mesh.triangles {
        assert!(t[0] != t[1] && t[1] != t[2] && t[0] != t[2], "degenerate triangle {t:?} kept");
        for &i in t {
            used[i as usize] = true;
        }
    }
    assert!(used.iter().all(|&u| u), "unreferenced vertex kept");
    let s = m.stats;
    assert_eq!(s.triangles_read - s.degenerate, m.mesh.triangles.len(), "stats {s:?}");
    assert!(s.normals_from_file <= n, "stats {s:?}");
}

/// Every triangle index in range, every position finite.
pub fn check_mesh(m: &Mesh) {
    let n = m.positions.len();
    for (i, p) in m.positions.iter().enumerate() {
        assert!(p.iter().all(|v| v.is_finite()), "position {i} {p:?} not finite");
    }
    for (i, t) in m.triangles.iter().enumerate() {
        assert!(t.iter().all(|&v| (v as usize) < n), "triangle {i} {t:?} indexes past {n} vertices");
    }
}

/// Every position inside the header bounds (the format promises clients may cull by them).
///
/// With `TS_FUZZ_D1_TOLERANT` set, positions may overshoot `max` by up to half a step (defect
/// D1, found by `codec_blob`; fixed: `codec::decode` now refuses such blobs, so the check holds
/// for every accepted blob and the switch is only for fuzzing builds from before the fix).
pub fn check_in_bounds(header: &BlobHeader, positions: &[[f64; 3]]) {
    let [min, mut max] = header.bounds;
    if std::env::var_os("TS_FUZZ_D1_TOLERANT").is_some() {
        let s = [header.quant.xy_step, header.quant.xy_step, header.quant.z_step];
        for a in 0..3 {
            max[a] += s[a] * (0.5 + 1e-9);
        }
    }
    for (i, p) in positions.iter().enumerate() {
        for a in 0..3 {
            assert!(
                min[a] <= p[a] && p[a] <= max[a],
                "position {i} {p:?} outside the header bounds {min:?}..{max:?} on axis {a}"
            );
        }
    }
}

/// A mesh as a sorted multiset of triangles given by their corner positions, each as its
/// lexicographically smallest rotation (winding kept), plus the sorted positions: equal for two
/// meshes exactly when they hold the same geometry whatever the vertex and triangle order.
pub fn canonical_mesh(m: &Mesh) -> (Vec<[[u64; 3]; 3]>, Vec<[u64; 3]>) {
    let bits = |p: [f64; 3]| p.map(|v| (v + 0.0).to_bits());
    let mut tris: Vec<[[u64; 3]; 3]> = m
        .triangles
        .iter()
        .map(|t| {
            let c = t.map(|i| bits(m.positions[i as usize]));
            // The smallest of the three rotations: a corner repeated (degenerate triangles
            // are valid) would make "start at the smallest corner" ambiguous.
            (0..3).map(|r| [c[r], c[(r + 1) % 3], c[(r + 2) % 3]]).min().unwrap_or(c)
        })
        .collect();
    tris.sort_unstable();
    let mut pos: Vec<[u64; 3]> = m.positions.iter().map(|p| bits(*p)).collect();
    pos.sort_unstable();
    (tris, pos)
}

/// A point cloud as its sorted (position, normal) bit patterns.
pub fn canonical_points(p: &PointCloud) -> Vec<([u64; 3], [u32; 3])> {
    let mut v: Vec<_> = p
        .positions
        .iter()
        .zip(&p.normals)
        .map(|(x, n)| (x.map(|c| (c + 0.0).to_bits()), n.map(|c| (c + 0.0).to_bits())))
        .collect();
    v.sort_unstable();
    v
}

/// A point cloud as (position bits, normal) sorted by position, then by the normal rounded to
/// 1e-4: distinct octahedral normals differ by about 1/254, while the seam's two decodings of
/// one direction differ by the sign of a zero and an ulp, which must not reorder points that
/// share a position (exact bits would put −0.0 after every positive value).
fn canonical_points_positions(p: &PointCloud) -> Vec<([u64; 3], [f32; 3])> {
    let key = |n: &[f32; 3]| n.map(|c| (f64::from(c) * 1e4).round() as i64);
    let mut v: Vec<_> =
        p.positions.iter().zip(&p.normals).map(|(x, n)| (x.map(|c| (c + 0.0).to_bits()), *n)).collect();
    v.sort_unstable_by(|a, b| a.0.cmp(&b.0).then(key(&a.1).cmp(&key(&b.1))));
    v
}

/// Re-encodes a decoded blob with its own header's key, level, bounds, steps and errors.
pub fn reencode(blob: &Blob) -> Result<Vec<u8>, codec::CodecError> {
    let h = &blob.header;
    match &blob.geometry {
        Geometry::Mesh(m) => codec::encode_mesh(h.key, h.level, &h.bounds(), h.quant, m, h.errors),
        Geometry::Points(p) => codec::encode_points(h.key, h.level, &h.bounds(), h.quant, p, h.errors),
    }
}

/// The header fields that describe content (not the payload's coding).
pub fn header_content(h: &BlobHeader) -> impl PartialEq + std::fmt::Debug {
    (h.version, h.kind, h.key, h.level, h.bounds, h.quant, h.vertex_count, h.triangle_count, h.errors)
}

/// Decodes arbitrary bytes as a blob and checks what the format promises of an `Ok` blob.
pub fn check_blob(data: &[u8]) {
    let header = codec::decode_header(data);
    let result = codec::decode(data);
    show(|| match &result {
        Ok(b) => format!("Ok {:?} v{} t{}", b.header.kind, b.header.vertex_count, b.header.triangle_count),
        Err(e) => format!("Err {e}"),
    });
    let Ok(blob) = result else { return };
    let header = header.unwrap_or_else(|e| panic!("decode Ok but decode_header failed: {e}"));
    assert_eq!(header, blob.header, "decode_header and decode disagree");
    let h = &blob.header;
    assert_eq!(h.blob_len(), data.len(), "blob length");
    match &blob.geometry {
        Geometry::Mesh(m) => {
            assert_eq!(h.kind, codec::Kind::Mesh);
            assert_eq!(
                (m.positions.len(), m.triangles.len()),
                (h.vertex_count as usize, h.triangle_count as usize)
            );
            check_mesh(m);
            check_in_bounds(h, &m.positions);
        }
        Geometry::Points(p) => {
            assert_eq!(h.kind, codec::Kind::Points);
            assert_eq!(p.positions.len(), h.vertex_count as usize);
            assert_eq!(p.normals.len(), p.positions.len(), "one normal per point");
            for (i, x) in p.positions.iter().enumerate() {
                assert!(x.iter().all(|v| v.is_finite()), "point {i} {x:?} not finite");
            }
            check_in_bounds(h, &p.positions);
        }
    }
    // Decoding returns canonical order, so the decoded geometry re-encodes (it passed every
    // check the encoder makes) to a blob that decodes to the same geometry. The bytes need not
    // match the input: a hostile blob may store a stream raw that zstd would shrink, or use a
    // different mesh mode; the format only promises deterministic encoding (equal inputs, equal
    // bytes), which the second re-encoding checks.
    let again = reencode(&blob).unwrap_or_else(|e| panic!("decoded geometry does not re-encode: {e}"));
    let back = codec::decode(&again).unwrap_or_else(|e| panic!("re-encoded blob does not decode: {e}"));
    assert_eq!(header_content(&back.header), header_content(h), "header content changed");
    assert_same_geometry(&blob.geometry, &back.geometry);
    let third = reencode(&back).unwrap_or_else(|e| panic!("second re-encoding failed: {e}"));
    if back.geometry == blob.geometry {
        assert!(third == again, "encoding is not deterministic");
    }
}

/// Same geometry up to the order decoding may change (vertices, triangles, rotations).
pub fn assert_same_geometry(a: &Geometry, b: &Geometry) {
    match (a, b) {
        (Geometry::Mesh(a), Geometry::Mesh(b)) => {
            assert!(canonical_mesh(a) == canonical_mesh(b), "mesh geometry changed:\n{a:?}\n{b:?}");
        }
        (Geometry::Points(a), Geometry::Points(b)) => {
            // Positions exactly; normals within 1e-6: on the octahedral map's lower seam
            // (|v| = 1) the pairs (u, v) and (−u, v) are one direction, and a blob may use
            // either, so a decoded normal re-encodes to the other pair, which decodes to the
            // same vector up to the sign of a zero and an ulp (found by this target; reported).
            let (ca, cb) = (canonical_points_positions(a), canonical_points_positions(b));
            assert!(ca.len() == cb.len(), "point count changed");
            for ((pa, na), (pb, nb)) in ca.iter().zip(&cb) {
                assert!(pa == pb, "points changed: {pa:?} vs {pb:?}");
                assert!(
                    (0..3).all(|k| (na[k] - nb[k]).abs() <= 1e-6),
                    "normal changed at {pa:?}: {na:?} vs {nb:?}"
                );
            }
        }
        _ => panic!("geometry kind changed"),
    }
}

/// An archive held in memory, read by ranges as a file or a bucket would be; counts the bytes
/// handed out, so a harness can check that reads stay bounded by the archive's size.
pub struct MemRanges(pub Vec<u8>, pub std::sync::Arc<std::sync::atomic::AtomicU64>);

impl terrastream::store::archive::RangeSource for MemRanges {
    fn read_range(&self, start: u64, len: u64) -> std::io::Result<Vec<u8>> {
        let n = self.0.len() as u64;
        let (s, e) = (start.min(n), start.saturating_add(len).min(n));
        self.1.fetch_add(e - s, std::sync::atomic::Ordering::Relaxed);
        Ok(self.0[s as usize..e as usize].to_vec())
    }
}

/// Opens `data` as a `.tsa` archive and checks what an `Ok` archive promises: its directory is
/// in strictly increasing path order with every file inside the data section, the entry count
/// is the footer's, each file found by its path is that entry, every file read is exactly the
/// bytes at its range (and matches its CRC), an absent path is `None`, and no lookup reads more
/// than a few times the archive's size.
pub fn check_archive(data: &[u8]) {
    use terrastream::store::archive::{Archive, MAGIC};
    let len = data.len() as u64;
    let read = std::sync::Arc::new(std::sync::atomic::AtomicU64::new(0));
    let a = match Archive::open(Box::new(MemRanges(data.to_vec(), read.clone())), len) {
        Ok(a) => a,
        Err(e) => {
            assert!(!e.to_string().is_empty());
            return;
        }
    };
    show(|| format!("archive of {len} bytes, {} files", a.file_count()));
    assert_eq!(a.len(), len);
    let Ok(entries) = a.entries() else { return };
    assert_eq!(entries.len() as u64, a.file_count(), "entries vs the footer's count");
    for w in entries.windows(2) {
        assert!(w[0].path < w[1].path, "directory out of order: {:?} then {:?}", w[0].path, w[1].path);
    }
    for e in entries.iter().take(64) {
        assert!(
            e.offset >= MAGIC.len() as u64 && e.offset.checked_add(e.len).is_some_and(|end| end <= len),
            "{e:?} outside {len} bytes"
        );
        assert_eq!(a.entry(&e.path).ok().flatten().as_ref(), Some(e), "lookup of {:?}", e.path);
        if let Ok(Some(b)) = a.read(&e.path) {
            assert_eq!(&b[..], &data[e.offset as usize..(e.offset + e.len) as usize], "{:?}", e.path);
            assert_eq!(crc32fast::hash(&b), e.crc);
        }
        let absent = format!("{}\u{0}", e.path);
        assert!(matches!(a.read(&absent), Ok(None) | Err(_)), "{absent:?} found");
    }
    // Open + every page + 64 lookups and reads: each touches at most the whole archive.
    let read = read.load(std::sync::atomic::Ordering::Relaxed);
    assert!(read <= 200 * len.max(1), "{read} bytes read from an archive of {len}");
}

/// Rewrites every checksum of an archive that a mutation would break — the footer's, the
/// root's (in the footer) and each page's (in the root) — and the footer's file count (the sum
/// of the root's page counts, as a writer would put it), so a fuzzer gets past them to the
/// directory values. Leaves the bytes alone where the footer or root cannot be located.
pub fn fix_archive_checksums(b: &mut [u8]) {
    use terrastream::store::archive::FOOTER_LEN;
    let n = b.len();
    let fl = FOOTER_LEN as usize;
    if n < fl {
        return;
    }
    let f = n - fl;
    let u64_at = |b: &[u8], i: usize| u64::from_le_bytes(b[i..i + 8].try_into().unwrap_or_default());
    let (root_off, root_len) = (u64_at(b, f + 16), u64_at(b, f + 24));
    if let Some(end) = root_off.checked_add(root_len).filter(|&e| e <= f as u64) {
        let (ro, re) = (root_off as usize, end as usize);
        // Root entries: path length u16, path, offset u64, length u32, CRC u32, count u32.
        let mut i = ro;
        let mut count = 0u64;
        while i + 2 <= re {
            let pl = usize::from(u16::from_le_bytes([b[i], b[i + 1]]));
            let at = i + 2 + pl;
            if at + 20 > re {
                break;
            }
            let off = u64_at(b, at);
            let plen = u64::from(u32::from_le_bytes(b[at + 8..at + 12].try_into().unwrap_or_default()));
            if let Some(pe) = off.checked_add(plen).filter(|&e| e <= n as u64) {
                let crc = crc32fast::hash(&b[off as usize..pe as usize]);
                b[at + 12..at + 16].copy_from_slice(&crc.to_le_bytes());
            }
            count += u64::from(u32::from_le_bytes(b[at + 16..at + 20].try_into().unwrap_or_default()));
            i = at + 20;
        }
        b[f + 40..f + 48].copy_from_slice(&count.to_le_bytes());
        let crc = crc32fast::hash(&b[ro..re]);
        b[f + 32..f + 36].copy_from_slice(&crc.to_le_bytes());
    }
    let crc = crc32fast::hash(&b[f..f + 60]);
    b[f + 60..f + 64].copy_from_slice(&crc.to_le_bytes());
}
