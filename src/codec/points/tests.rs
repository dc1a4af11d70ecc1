//! Tests of this module: round trips and hostile input.

// Exact float equality is the point of these tests: decoding must be bit-exact.
#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic, clippy::float_cmp)]

use proptest::prelude::*;

use super::*;
use crate::codec::testdata::{Rng, synthetic, voxel_points};
use crate::codec::{Quantization, quantize_positions};
use crate::geom::Bounds;

fn setup(pc: &PointCloud, step: f64) -> (QuantGrid, Bounds, Quantization) {
    let mut b = Bounds::of_points(&pc.positions);
    if !b.is_valid() {
        b = Bounds::new([0.0; 3], [1.0; 3]);
    }
    let q = Quantization { xy_step: step, z_step: step };
    // The bounds the header would state (grown to the rounded-up positions).
    let b = crate::codec::quantized_bounds(&b, &pc.positions, q);
    (QuantGrid::new(&b, q).unwrap(), b, q)
}

/// Sorted (position bits, normal bits) pairs.
fn canonical(positions: &[[f64; 3]], normals: &[[f32; 3]]) -> Vec<([u64; 3], [u32; 3])> {
    let mut v: Vec<_> =
        positions.iter().zip(normals).map(|(p, n)| (p.map(f64::to_bits), n.map(f32::to_bits))).collect();
    v.sort_unstable();
    v
}

fn round_trip(pc: &PointCloud, step: f64) -> Vec<u8> {
    let (frame, b, q) = setup(pc, step);
    let packed = encode(&frame, pc).unwrap();
    let raw = packed.payload;
    let back = decode(&frame, pc.positions.len(), &raw, packed.raw_len).unwrap();
    let want_p = quantize_positions(&pc.positions, &b, q);
    let want_n = quantize_normals(&pc.normals).unwrap();
    assert_eq!(canonical(&back.positions, &back.normals), canonical(&want_p, &want_n));
    assert_eq!(encode(&frame, pc).unwrap().payload, raw, "deterministic");
    raw
}

#[test]
fn oct_axes_are_exact() {
    for n in [
        [0.0, 0.0, 1.0],
        [0.0, 0.0, -1.0],
        [1.0, 0.0, 0.0],
        [-1.0, 0.0, 0.0],
        [0.0, 1.0, 0.0],
        [0.0, -1.0, 0.0],
    ] {
        assert_eq!(oct_decode(oct_encode(n).unwrap()), n);
    }
    assert_eq!(oct_encode([0.0, 0.0, 5.0]), Some([127, 127]));
}

#[test]
fn oct_decoding_is_canonical() {
    // The fuzz case: (100, 0) lies on the folded seam and stands for the direction of (154, 0).
    assert_eq!(oct_decode([100, 0]).map(f32::to_bits), oct_decode([154, 0]).map(f32::to_bits));
    for u in 0..=255_u8 {
        for v in 0..=255_u8 {
            let n = oct_decode([u, v]);
            let b = oct_encode(n).unwrap();
            assert_eq!(oct_decode_raw(b).map(f32::to_bits), n.map(f32::to_bits), "({u}, {v}) -> {b:?}");
        }
    }
}

#[test]
fn oct_error_is_small() {
    let mut rng = Rng(5);
    let mut worst = 1.0f32;
    for _ in 0..20_000 {
        let n = [rng.unit() * 2.0 - 1.0, rng.unit() * 2.0 - 1.0, rng.unit() * 2.0 - 1.0].map(|v| v as f32);
        let Some(b) = oct_encode(n) else { continue };
        let d = oct_decode(b);
        let l = (n[0] * n[0] + n[1] * n[1] + n[2] * n[2]).sqrt();
        let cos = (d[0] * n[0] + d[1] * n[1] + d[2] * n[2]) / l;
        worst = worst.min(cos);
        let len = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt();
        assert!((len - 1.0).abs() < 1e-6);
    }
    // 8+8 bits: under about 1.5 degrees everywhere.
    assert!(worst > 1.5f32.to_radians().cos(), "worst cosine {worst}");
}

#[test]
fn oct_rejects_bad_vectors() {
    assert_eq!(oct_encode([0.0; 3]), None);
    assert_eq!(oct_encode([f32::NAN, 0.0, 1.0]), None);
    assert_eq!(oct_encode([f32::INFINITY, 0.0, 1.0]), None);
    for b in 0..=255u8 {
        let d = oct_decode([b, 255 - b]);
        assert!(d.iter().all(|v| v.is_finite()));
    }
}

#[test]
fn empty_points() {
    round_trip(&PointCloud::default(), 1.0);
}

#[test]
fn lattice_and_continuous_voxel_points() {
    let hf = synthetic(97, 97, 30.0);
    for centres in [true, false] {
        let pc = voxel_points(&hf, None, 60.0, centres);
        let z = round_trip(&pc, 60.0 / 64.0).len();
        // Continuous positions carry their fine offsets (12 bits here); lattice points far less.
        let limit = if centres { 1 } else { 4 };
        assert!(z < limit * pc.positions.len(), "{z} bytes for {} points", pc.positions.len());
    }
}

#[test]
fn input_order_does_not_matter() {
    let hf = synthetic(40, 40, 30.0);
    let pc = voxel_points(&hf, None, 60.0, false);
    let (frame, _, _) = setup(&pc, 1.0);
    let rev = PointCloud {
        positions: pc.positions.iter().rev().copied().collect(),
        normals: pc.normals.iter().rev().copied().collect(),
    };
    assert_eq!(encode(&frame, &pc).unwrap().payload, encode(&frame, &rev).unwrap().payload);
}

#[test]
fn bad_inputs_are_named() {
    let frame = QuantGrid::new(&Bounds::new([0.0; 3], [10.0; 3]), Quantization { xy_step: 1.0, z_step: 1.0 })
        .unwrap();
    let pc = PointCloud { positions: vec![[1.0; 3]], normals: vec![] };
    assert!(matches!(encode(&frame, &pc), Err(CodecError::NormalCountMismatch { points: 1, normals: 0 })));
    let pc = PointCloud { positions: vec![[1.0; 3]; 2], normals: vec![[0.0, 0.0, 1.0], [0.0; 3]] };
    assert!(matches!(encode(&frame, &pc), Err(CodecError::BadNormal { index: 1, .. })));
    let pc = PointCloud { positions: vec![[1.0, f64::NAN, 1.0]], normals: vec![[0.0, 0.0, 1.0]] };
    assert!(matches!(encode(&frame, &pc), Err(CodecError::NonFinitePosition { index: 0, .. })));
    let pc = PointCloud { positions: vec![[1.0, 11.0, 1.0]], normals: vec![[0.0, 0.0, 1.0]] };
    assert!(matches!(encode(&frame, &pc), Err(CodecError::OutOfBounds { index: 0, .. })));
}

fn arb_points() -> impl Strategy<Value = PointCloud> {
    proptest::collection::vec(
        ((0u16..2000, 0u16..2000, 0u16..2000), (-1.0f32..1.0, -1.0f32..1.0, -1.0f32..1.0)),
        0..80,
    )
    .prop_map(|v| {
        let (p, n): (Vec<_>, Vec<_>) = v
            .into_iter()
            .map(|((x, y, z), (a, b, c))| {
                let n = if a == 0.0 && b == 0.0 && c == 0.0 { [0.0, 0.0, 1.0] } else { [a, b, c] };
                ([f64::from(x) * 0.5, f64::from(y) * 0.5, f64::from(z) * 0.125], n)
            })
            .unzip();
        PointCloud { positions: p, normals: n }
    })
}

proptest! {
    #[test]
    fn any_points_round_trip(pc in arb_points(), step in prop_oneof![Just(0.125), Just(0.5), Just(3.0)]) {
        round_trip(&pc, step);
    }

    #[test]
    fn random_payloads_never_panic(raw in proptest::collection::vec(any::<u8>(), 0..200), n in 0usize..50, len in 0usize..300) {
        let frame = QuantGrid::new(&Bounds::new([0.0; 3], [100.0; 3]), Quantization { xy_step: 1.0, z_step: 1.0 }).unwrap();
        let _ = decode(&frame, n, &raw, len);
    }

    #[test]
    fn mutated_streams_never_panic(seed in any::<u64>(), stream in 0usize..13, flips in proptest::collection::vec((any::<usize>(), any::<u8>()), 1..6)) {
        let hf = synthetic(20, 20, 30.0);
        let pc = voxel_points(&hf, None, 60.0, seed % 2 == 0);
        let (frame, _, _) = setup(&pc, 1.0);
        let p = encode(&frame, &pc).unwrap();
        let u = crate::codec::stream::unpack(&p.payload, p.raw_len, &STREAMS).unwrap();
        let bad = u.mutate_and_pack(stream, &flips).unwrap();
        let _ = decode(&frame, pc.positions.len(), &bad.payload, bad.raw_len);
    }

    #[test]
    fn mutated_payloads_never_panic(seed in any::<u64>(), flips in 1usize..8) {
        let mut rng = Rng(seed);
        let hf = synthetic(20, 20, 30.0);
        let pc = voxel_points(&hf, None, 60.0, seed % 2 == 0);
        let (frame, _, _) = setup(&pc, 1.0);
        let p = encode(&frame, &pc).unwrap();
        let mut raw = p.payload;
        for _ in 0..flips {
            let i = rng.below(raw.len() as u64) as usize;
            raw[i] ^= 1 << rng.below(8);
        }
        let _ = decode(&frame, pc.positions.len(), &raw, p.raw_len);
    }
}
