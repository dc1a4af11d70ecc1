//! Tests of this module: round trips and hostile input (size figures: `examples/codec_figures.rs`).

// Exact float equality is the point of these tests: decoding must be bit-exact.
#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic, clippy::float_cmp)]

use proptest::prelude::*;

use super::testdata::{
    Rng, canonical_positions, canonical_triangles, greedy_tin, quantized_mesh_gzip, synthetic, voxel_points,
};
use super::*;

const KEY: TileKey = TileKey::new(3, 5, 6);
const ERRORS: ErrorFigures = ErrorFigures { max: 1.5, rms: 0.25, gap: 0.0 };

fn tin_blob() -> (Mesh, Bounds, Quantization, Vec<u8>) {
    let hf = synthetic(49, 49, 30.0);
    let m = greedy_tin(&hf, 2.0);
    let b = Bounds::of_points(&m.positions);
    let q = Quantization { xy_step: 30.0, z_step: 0.1 };
    let blob = encode_mesh(KEY, 0, &b, q, &m, ERRORS).unwrap();
    // The header states the bounds grown to the quantized positions (here by a rounding ulp).
    let b = quantized_bounds(&b, &m.positions, q);
    (m, b, q, blob)
}

fn points_blob() -> (PointCloud, Bounds, Quantization, Vec<u8>) {
    let hf = synthetic(49, 49, 30.0);
    let pc = voxel_points(&hf, None, 60.0, false);
    let b = Bounds::new([0.0, 0.0, 0.0], [1500.0, 1500.0, 2000.0]);
    let q = Quantization { xy_step: 60.0 / 64.0, z_step: 60.0 / 64.0 };
    let blob = encode_points(KEY, 2, &b, q, &pc, ErrorFigures { max: 3.0, rms: 1.0, gap: 40.0 }).unwrap();
    (pc, b, q, blob)
}

/// D1: the header bounds hold every decoded position, whatever the bounds given, and grow by
/// less than half a step; positions further out are refused.
#[test]
fn header_bounds_hold_every_decoded_position() {
    let q = Quantization { xy_step: 1.0, z_step: 0.25 };
    // 835.9 is not on the z grid from 800: the vertex there rounds up to 836.0.
    let m = Mesh {
        positions: vec![[0.0, 0.0, 800.0], [4.0, 0.0, 835.9], [0.0, 4.0, 810.0]],
        triangles: vec![[0, 1, 2]],
    };
    let b = Bounds::new([0.0, 0.0, 800.0], [4.0, 4.0, 835.9]);
    let blob = encode_mesh(KEY, 0, &b, q, &m, ERRORS).unwrap();
    let d = decode(&blob).unwrap();
    assert_eq!(d.header.bounds().max[2], 836.0);
    let Geometry::Mesh(back) = d.geometry else { panic!("kind") };
    let hb = d.header.bounds();
    assert!(back.positions.iter().all(|p| (0..3).all(|a| hb.min[a] <= p[a] && p[a] <= hb.max[a])));
    let far = Mesh { positions: vec![[0.0, 0.0, 800.0], [4.0, 0.0, 836.2], [0.0, 4.0, 810.0]], ..m };
    assert!(matches!(
        encode_mesh(KEY, 0, &b, q, &far, ERRORS),
        Err(CodecError::OutOfBounds { index: 1, .. })
    ));
    // Points snapped into fixed bounds stay inside them, the top one a step lower.
    let pts = vec![[1.0, 1.0, 835.9], [2.0, 2.0, 799.9], [9.0, 2.0, 801.0]];
    let snapped = snap_positions(&pts, &b, q).unwrap();
    assert_eq!(snapped, vec![[1.0, 1.0, 835.75], [2.0, 2.0, 800.0], [4.0, 2.0, 801.0]]);
}

#[test]
fn header_layout() {
    let (m, b, q, blob) = tin_blob();
    assert_eq!(&blob[..4], b"TSB1");
    assert_eq!(u32::from_le_bytes(blob[4..8].try_into().unwrap()) as usize, HEADER_LEN);
    assert_eq!(u16::from_le_bytes(blob[8..10].try_into().unwrap()), FORMAT_VERSION);
    assert_eq!(u32::from_le_bytes(blob[10..14].try_into().unwrap()), 0);
    assert_eq!(blob[14], KEY.z);
    assert_eq!(u32::from_le_bytes(blob[15..19].try_into().unwrap()), KEY.x);
    assert_eq!(u32::from_le_bytes(blob[19..23].try_into().unwrap()), KEY.y);
    assert_eq!(blob[23], 0);
    assert_eq!(f64::from_le_bytes(blob[24..32].try_into().unwrap()), b.min[0]);
    assert_eq!(f64::from_le_bytes(blob[64..72].try_into().unwrap()), b.max[2]);
    assert_eq!(f64::from_le_bytes(blob[72..80].try_into().unwrap()), q.xy_step);
    assert_eq!(f64::from_le_bytes(blob[80..88].try_into().unwrap()), q.z_step);
    assert_eq!(u32::from_le_bytes(blob[88..92].try_into().unwrap()) as usize, m.positions.len());
    assert_eq!(u32::from_le_bytes(blob[92..96].try_into().unwrap()) as usize, m.triangles.len());
    assert_eq!(f64::from_le_bytes(blob[96..104].try_into().unwrap()), ERRORS.max);
    assert_eq!(f64::from_le_bytes(blob[112..120].try_into().unwrap()), ERRORS.gap);
    let payload_len = u32::from_le_bytes(blob[124..128].try_into().unwrap()) as usize;
    assert_eq!(blob.len(), PREFIX_LEN + payload_len);
    assert_eq!(u32::from_le_bytes(blob[128..132].try_into().unwrap()), crc32fast::hash(&blob[PREFIX_LEN..]));
    assert_eq!(u32::from_le_bytes(blob[132..136].try_into().unwrap()), crc32fast::hash(&blob[..132]));
    // The payload opens with its mode and stream table.
    assert_eq!(blob[PREFIX_LEN], 0, "sweep mode");
    assert_eq!(usize::from(blob[PREFIX_LEN + 1]), 5, "sweep streams");
}

#[test]
fn header_from_prefix_only() {
    let (m, b, q, blob) = tin_blob();
    let h = decode_header(&blob[..PREFIX_LEN]).unwrap();
    assert_eq!(h.version, FORMAT_VERSION);
    assert_eq!(h.kind, Kind::Mesh);
    assert_eq!(h.key, KEY);
    assert_eq!(h.level, 0);
    assert_eq!(h.bounds(), b);
    assert_eq!(h.quant, q);
    assert_eq!(h.vertex_count as usize, m.positions.len());
    assert_eq!(h.triangle_count as usize, m.triangles.len());
    assert_eq!(h.errors, ERRORS);
    assert_eq!(h.blob_len(), blob.len());
    assert_eq!(decode(&blob).unwrap().header, h);
    assert!(matches!(decode_header(&blob[..PREFIX_LEN - 1]), Err(CodecError::Truncated { .. })));
}

#[test]
fn mesh_blob_round_trip() {
    let (m, b, q, blob) = tin_blob();
    let Geometry::Mesh(back) = decode(&blob).unwrap().geometry else { panic!("kind") };
    let snapped = Mesh { positions: quantize_positions(&m.positions, &b, q), triangles: m.triangles.clone() };
    assert_eq!(canonical_triangles(&back), canonical_triangles(&snapped));
    assert_eq!(canonical_positions(&back.positions), canonical_positions(&snapped.positions));
    // Grid vertices with xy_step = cell size come back exactly.
    assert!(back.positions.iter().all(|p| p[0] % 30.0 == 0.0 && p[1] % 30.0 == 0.0));
    let again = encode_mesh(KEY, 0, &b, q, &m, ERRORS).unwrap();
    assert_eq!(again, blob);
}

#[test]
fn tin_blob_is_under_half_of_quantized_mesh_gzip() {
    // The design's bar: half the bytes of Cesium quantized-mesh-1.0 + gzip for the same mesh.
    let hf = synthetic(129, 129, 30.0);
    let m = greedy_tin(&hf, 2.0);
    let extent = 128.0 * 30.0;
    let b = Bounds::of_points(&m.positions);
    let q = Quantization { xy_step: 30.0, z_step: 0.1 };
    let blob = encode_mesh(KEY, 0, &b, q, &m, ERRORS).unwrap();
    let qm = quantized_mesh_gzip(&m, extent);
    let ratio = blob.len() as f64 / qm as f64;
    assert!(
        ratio < 0.5,
        "{} vertices: blob {} B, QM+gzip {qm} B, ratio {ratio:.3}",
        m.positions.len(),
        blob.len()
    );
}

#[test]
fn points_blob_round_trip() {
    let (pc, b, q, blob) = points_blob();
    let blob2 = decode(&blob).unwrap();
    assert_eq!(blob2.header.kind, Kind::Points);
    assert_eq!(blob2.header.triangle_count, 0);
    let Geometry::Points(back) = blob2.geometry else { panic!("kind") };
    assert_eq!(
        canonical_positions(&back.positions),
        canonical_positions(&quantize_positions(&pc.positions, &b, q))
    );
    let mut want: Vec<[u32; 3]> =
        quantize_normals(&pc.normals).unwrap().iter().map(|n| n.map(f32::to_bits)).collect();
    let mut got: Vec<[u32; 3]> = back.normals.iter().map(|n| n.map(f32::to_bits)).collect();
    want.sort_unstable();
    got.sort_unstable();
    assert_eq!(got, want);
}

/// A draft's length is the finished blob's whatever the errors, and finishing it gives exactly
/// what `encode_points` gives; bad errors are refused at `finish`.
#[test]
fn points_draft_length_is_known_before_the_errors() {
    let (pc, b, q, _) = points_blob();
    let draft = draft_points(KEY, 2, &b, q, &pc).unwrap();
    for e in [
        ErrorFigures::default(),
        ErrorFigures { max: 3.0, rms: 1.0, gap: 40.0 },
        ErrorFigures { max: 1e300, rms: 0.5, gap: 7.25 },
    ] {
        let blob = draft.finish(e).unwrap();
        assert_eq!(blob.len(), draft.len());
        assert_eq!(blob, encode_points(KEY, 2, &b, q, &pc, e).unwrap());
        assert_eq!(decode_header(&blob).unwrap().errors, e);
    }
    assert!(draft.finish(ErrorFigures { max: f64::NAN, rms: 0.0, gap: 0.0 }).is_err());
    assert!(draft.finish(ErrorFigures { max: 1.0, rms: -1.0, gap: 0.0 }).is_err());
}

#[test]
fn empty_geometry_is_allowed() {
    let b = Bounds::new([0.0; 3], [10.0; 3]);
    let q = Quantization { xy_step: 1.0, z_step: 1.0 };
    let blob = encode_mesh(KEY, 0, &b, q, &Mesh::default(), ErrorFigures::default()).unwrap();
    assert_eq!(decode(&blob).unwrap().geometry, Geometry::Mesh(Mesh::default()));
    let blob = encode_points(KEY, 1, &b, q, &PointCloud::default(), ErrorFigures::default()).unwrap();
    assert_eq!(decode(&blob).unwrap().geometry, Geometry::Points(PointCloud::default()));
}

#[test]
fn quantization_is_exact() {
    let b = Bounds::new([-3.7, 12.1, -400.25], [1000.0, 2000.0, 3000.0]);
    let q = Quantization { xy_step: 0.37, z_step: 0.013 };
    let mut rng = Rng(1);
    let positions: Vec<[f64; 3]> =
        (0..500).map(|_| std::array::from_fn(|a| b.min[a] + rng.unit() * (b.max[a] - b.min[a]))).collect();
    let pc = PointCloud { positions: positions.clone(), normals: vec![[0.0, 0.0, 1.0]; 500] };
    let blob = encode_points(KEY, 1, &b, q, &pc, ErrorFigures::default()).unwrap();
    let Geometry::Points(back) = decode(&blob).unwrap().geometry else { panic!("kind") };
    assert_eq!(
        canonical_positions(&back.positions),
        canonical_positions(&quantize_positions(&positions, &b, q))
    );
    for (p, s) in positions.iter().zip(quantize_positions(&positions, &b, q)) {
        assert!((p[0] - s[0]).abs() <= 0.37 / 2.0 + 1e-9 && (p[2] - s[2]).abs() <= 0.013 / 2.0 + 1e-9);
    }
}

#[test]
fn invalid_inputs_are_named() {
    let m = Mesh { positions: vec![[0.0; 3], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]], triangles: vec![[0, 1, 2]] };
    let b = Bounds::new([0.0; 3], [10.0; 3]);
    let q = Quantization { xy_step: 1.0, z_step: 1.0 };
    let enc = |b: &Bounds, q: Quantization, m: &Mesh, e: ErrorFigures| encode_mesh(KEY, 0, b, q, m, e);
    assert!(matches!(enc(&Bounds::empty(), q, &m, ERRORS), Err(CodecError::InvalidBounds { .. })));
    let flipped = Bounds::new([1.0; 3], [0.0; 3]);
    assert!(matches!(enc(&flipped, q, &m, ERRORS), Err(CodecError::InvalidBounds { .. })));
    for bad in [0.0, -1.0, f64::NAN, f64::INFINITY] {
        let r = enc(&b, Quantization { xy_step: bad, z_step: 1.0 }, &m, ERRORS);
        assert!(matches!(r, Err(CodecError::InvalidQuantization { .. })));
    }
    let r = enc(&b, Quantization { xy_step: 1e-12, z_step: 1.0 }, &m, ERRORS);
    assert!(matches!(r, Err(CodecError::QuantizationRange { axis: 0, .. })));
    let r = enc(&b, q, &m, ErrorFigures { max: f64::NAN, ..ERRORS });
    assert!(matches!(r, Err(CodecError::InvalidErrors(_))));
    let mut m2 = m.clone();
    m2.triangles.push([0, 1, 3]);
    assert!(matches!(
        enc(&b, q, &m2, ERRORS),
        Err(CodecError::IndexOutOfRange { triangle: 1, index: 3, .. })
    ));
    let mut m3 = m.clone();
    m3.positions[2][2] = f64::INFINITY;
    assert!(matches!(enc(&b, q, &m3, ERRORS), Err(CodecError::NonFinitePosition { index: 2, .. })));
    m3.positions[2][2] = -0.6;
    assert!(matches!(enc(&b, q, &m3, ERRORS), Err(CodecError::OutOfBounds { index: 2, .. })));
    // Within half a step of the bounds is fine: it rounds onto them.
    m3.positions[2][2] = -0.4;
    assert!(enc(&b, q, &m3, ERRORS).is_ok());
}

#[test]
fn header_errors_are_named() {
    let (_, _, _, blob) = tin_blob();
    let mut b = blob.clone();
    b[0] = b'X';
    assert!(matches!(decode(&b), Err(CodecError::BadMagic(_))));
    assert!(matches!(decode(b"PK\x03\x04"), Err(CodecError::BadMagic(_))));
    assert!(matches!(decode(b"TSB"), Err(CodecError::Truncated { .. })));
    let mut b = blob.clone();
    b[8] = 2;
    assert!(matches!(decode(&b), Err(CodecError::UnsupportedVersion { found: 2 })));
    let mut b = blob.clone();
    b[4] = 129;
    assert!(matches!(decode(&b), Err(CodecError::BadHeaderLength(129))));
    let mut b = blob.clone();
    b[100] ^= 1;
    assert!(matches!(decode(&b), Err(CodecError::HeaderChecksum { .. })));
    let mut b = blob.clone();
    let last = b.len() - 1;
    b[last] ^= 0x10;
    assert!(matches!(decode(&b), Err(CodecError::PayloadChecksum { .. })));
    assert!(matches!(decode(&blob[..blob.len() - 1]), Err(CodecError::Truncated { .. })));
    let mut b = blob.clone();
    b.push(0);
    assert!(matches!(decode(&b), Err(CodecError::TrailingBytes { extra: 1 })));
}

/// Rewrites the header checksum so a test can reach the checks behind it.
fn reseal(blob: &mut [u8]) {
    let crc = crc32fast::hash(&blob[..132]);
    blob[132..136].copy_from_slice(&crc.to_le_bytes());
}

#[test]
fn forged_headers_are_rejected() {
    let (_, _, _, blob) = tin_blob();
    // Claimed sizes far beyond the payload: rejected without allocating for them.
    for (at, v) in
        [(88, u32::MAX), (88, MAX_ELEMENTS), (92, MAX_ELEMENTS), (120, u32::MAX), (120, MAX_RAW_LEN)]
    {
        let mut b = blob.clone();
        b[at..at + 4].copy_from_slice(&v.to_le_bytes());
        reseal(&mut b);
        assert!(decode(&b).is_err(), "field at {at} = {v}");
    }
    // A stored payload larger than its decompressed size and stream table allow: what a reader
    // checks a blob's size against before reading it (`MAX_PAYLOAD_LEN`).
    let raw_len = u32::from_le_bytes(blob[120..124].try_into().unwrap());
    for (v, ok) in
        [(raw_len + PAYLOAD_TABLE_MAX, true), (raw_len + PAYLOAD_TABLE_MAX + 1, false), (u32::MAX, false)]
    {
        let mut b = blob.clone();
        b[124..128].copy_from_slice(&v.to_le_bytes());
        reseal(&mut b);
        let r = decode_header(&b);
        assert_eq!(r.is_ok(), ok, "payload_len {v}: {r:?}");
    }
    assert!(decode_header(&blob).unwrap().payload_len <= raw_len + PAYLOAD_TABLE_MAX);
    // A bad kind index.
    let mut b = blob.clone();
    b[10] = 7;
    reseal(&mut b);
    assert!(matches!(decode(&b), Err(CodecError::HeaderDecode(_))));
    // A NaN step.
    let mut b = blob.clone();
    b[72..80].copy_from_slice(&f64::NAN.to_le_bytes());
    reseal(&mut b);
    assert!(matches!(decode(&b), Err(CodecError::InvalidQuantization { .. })));
    // Points with triangles.
    let (_, _, _, pblob) = points_blob();
    let mut b = pblob.clone();
    b[92] = 1;
    reseal(&mut b);
    assert!(matches!(decode(&b), Err(CodecError::InvalidHeader(_))));
    // Mesh header over a points payload: the payload does not parse as a mesh.
    let mut b = pblob.clone();
    b[10] = 0;
    reseal(&mut b);
    assert!(decode(&b).is_err());
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(64))]

    #[test]
    fn random_bytes_never_panic(mut bytes in proptest::collection::vec(any::<u8>(), 0..400), magic in any::<bool>()) {
        if magic && bytes.len() >= 10 {
            bytes[..4].copy_from_slice(&MAGIC);
            bytes[4..8].copy_from_slice(&(HEADER_LEN as u32).to_le_bytes());
            bytes[8..10].copy_from_slice(&FORMAT_VERSION.to_le_bytes());
            if bytes.len() >= PREFIX_LEN {
                reseal(&mut bytes);
            }
        }
        let _ = decode(&bytes);
        let _ = decode_header(&bytes);
    }

    #[test]
    fn mutated_blobs_never_panic(seed in any::<u64>(), which in 0usize..2, op in 0usize..4) {
        let mut rng = Rng(seed);
        let mut b = if which == 0 { tin_blob().3 } else { points_blob().3 };
        let orig = b.clone();
        match op {
            0 => {
                // Bit flips anywhere: every one is caught by a checksum.
                let flips = 1 + rng.below(4) as usize;
                for _ in 0..flips {
                    let i = rng.below(b.len() as u64) as usize;
                    b[i] ^= 1 << rng.below(8);
                }
                prop_assert!(b == orig || decode(&b).is_err());
            }
            1 => {
                let n = rng.below(b.len() as u64) as usize;
                b.truncate(n);
                prop_assert!(decode(&b).is_err());
            }
            2 => {
                let extra = 1 + rng.below(64) as usize;
                for _ in 0..extra {
                    b.push(rng.next() as u8);
                }
                prop_assert!(decode(&b).is_err());
            }
            _ => {
                // Payload damage behind valid checksums reaches the payload decoders.
                let i = PREFIX_LEN + rng.below((b.len() - PREFIX_LEN) as u64) as usize;
                b[i] ^= 1 << rng.below(8);
                let crc = crc32fast::hash(&b[PREFIX_LEN..]);
                b[128..132].copy_from_slice(&crc.to_le_bytes());
                reseal(&mut b);
                let _ = decode(&b);
            }
        }
    }
}
