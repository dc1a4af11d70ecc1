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
        both_modes_agree(&pc, step);
    }

    #[test]
    fn context_payloads_of_random_bytes_never_panic(raw in proptest::collection::vec(any::<u8>(), 0..300), n in 0usize..5000) {
        // A valid stream table around random coded bytes, so the range decoder sees them.
        let w = crate::codec::stream::Writer { bytes: raw };
        let p = crate::codec::stream::pack_stored(context::MODE_CONTEXT, &[&w]).unwrap();
        let frame = QuantGrid::new(&Bounds::new([0.0; 3], [1000.0; 3]), Quantization { xy_step: 1.0, z_step: 1.0 }).unwrap();
        let _ = decode(&frame, n, &p.payload, p.raw_len);
    }

    #[test]
    fn context_coded_bytes_mutated_never_panic(seed in any::<u64>(), flips in 1usize..6, cut in 0usize..4) {
        let mut rng = Rng(seed);
        let hf = synthetic(24, 24, 30.0);
        let pc = voxel_points(&hf, None, 60.0, seed % 2 == 0);
        let (frame, _, _) = setup(&pc, 1.0);
        let p = encode_mode(&frame, &pc, context::MODE_CONTEXT).unwrap();
        let u = crate::codec::stream::unpack(&p.payload, p.raw_len, &context::STREAMS).unwrap();
        let mut bytes = u.readers()[0].rest().to_vec();
        for _ in 0..flips {
            let i = rng.below(bytes.len() as u64) as usize;
            bytes[i] ^= 1 << rng.below(8);
        }
        bytes.truncate(bytes.len().saturating_sub(cut));
        let w = crate::codec::stream::Writer { bytes };
        let bad = crate::codec::stream::pack_stored(context::MODE_CONTEXT, &[&w]).unwrap();
        let _ = decode(&frame, pc.positions.len(), &bad.payload, bad.raw_len);
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
        let p = encode_mode(&frame, &pc, MODE_GRID).unwrap();
        let u = crate::codec::stream::unpack(&p.payload, p.raw_len, &STREAMS).unwrap();
        let bad = u.mutate_and_pack(stream, &flips).unwrap();
        let _ = decode(&frame, pc.positions.len(), &bad.payload, bad.raw_len);
    }

    #[test]
    fn mutated_payloads_never_panic(seed in any::<u64>(), flips in 1usize..8, mode in 0u8..2) {
        let mut rng = Rng(seed);
        let hf = synthetic(20, 20, 30.0);
        let pc = voxel_points(&hf, None, 60.0, seed % 2 == 0);
        let (frame, _, _) = setup(&pc, 1.0);
        let p = encode_mode(&frame, &pc, mode).unwrap();
        let mut raw = p.payload;
        for _ in 0..flips {
            let i = rng.below(raw.len() as u64) as usize;
            raw[i] ^= 1 << rng.below(8);
        }
        let _ = decode(&frame, pc.positions.len(), &raw, p.raw_len);
    }
}

/// Encodes `pc` in both modes and checks that they decode to the same geometry (the context
/// mode is lossless against the grid mode's quantized values).
fn both_modes_agree(pc: &PointCloud, step: f64) -> [usize; 2] {
    let (frame, _, _) = setup(pc, step);
    let n = pc.positions.len();
    let mut out = [0; 2];
    let mut decoded = Vec::new();
    for mode in [MODE_GRID, context::MODE_CONTEXT] {
        let p = encode_mode(&frame, pc, mode).unwrap();
        assert_eq!(p.payload[0], mode);
        assert_eq!(encode_mode(&frame, pc, mode).unwrap().payload, p.payload, "deterministic");
        let back = decode(&frame, n, &p.payload, p.raw_len).unwrap();
        decoded.push(canonical(&back.positions, &back.normals));
        out[usize::from(mode)] = p.payload.len();
    }
    assert_eq!(decoded[0], decoded[1], "decode(context) == decode(grid)");
    out
}

#[test]
fn context_mode_is_lossless_and_smaller_on_terrain_points() {
    use crate::codec::testdata::{fuji, greedy_tin, tin_surface};
    let mut fields =
        vec![("synthetic 129", synthetic(129, 129, 30.0)), ("synthetic 64x40", synthetic(64, 40, 10.0))];
    fields.extend(fuji().map(|f| ("fuji", f)));
    for (name, hf) in fields {
        let tin = greedy_tin(&hf, 2.0);
        let (surface, normals) = tin_surface(&hf, &tin);
        for cell in [60.0, 120.0, 240.0] {
            for centres in [true, false] {
                let pc = voxel_points(&surface, Some(&normals), cell, centres);
                let [grid, ctx] = both_modes_agree(&pc, cell / 64.0);
                // Sample means are what a bake writes; voxel centres (z on whole cells) leave
                // the gradient too coarse to predict normals, and the encoder keeps mode 0.
                assert!(centres || ctx < grid, "{name} cell {cell}: context {ctx} B, grid {grid} B");
            }
        }
    }
}

/// Point blobs of fuji's root tile (levels 2 to 4) as terrastream 0.1 wrote them (mode 0, before
/// the context mode): what tilesets, archives and buckets already hold.
const OLD_BLOBS: [&[u8]; 3] = [
    include_bytes!("fixtures/fuji-0-0-0-2.tsb"),
    include_bytes!("fixtures/fuji-0-0-0-3.tsb"),
    include_bytes!("fixtures/fuji-0-0-0-4.tsb"),
];

#[test]
fn old_grid_blobs_still_decode_and_reencode_losslessly() {
    use crate::codec::{Geometry, decode as decode_blob, encode_points};
    for (blob, (count, len)) in OLD_BLOBS.iter().zip([(4141, 13_590), (1029, 4091), (256, 1412)]) {
        assert_eq!(blob.len(), len);
        assert_eq!(blob[crate::codec::PREFIX_LEN], MODE_GRID);
        let old = decode_blob(blob).unwrap();
        let Geometry::Points(pc) = &old.geometry else { panic!("a points blob") };
        assert_eq!(pc.positions.len(), count);
        let h = old.header;
        let new = encode_points(h.key, h.level, &h.bounds(), h.quant, pc, h.errors).unwrap();
        assert_eq!(new[crate::codec::PREFIX_LEN], context::MODE_CONTEXT);
        assert!(new.len() * 10 < len * 9, "{} B against {len} B", new.len());
        let back = decode_blob(&new).unwrap();
        let Geometry::Points(back) = &back.geometry else { panic!("a points blob") };
        assert_eq!(canonical(&back.positions, &back.normals), canonical(&pc.positions, &pc.normals));
    }
}

#[test]
fn context_point_count_is_checked_against_the_bytes() {
    let hf = synthetic(40, 40, 30.0);
    let pc = voxel_points(&hf, None, 60.0, true);
    let (frame, _, _) = setup(&pc, 60.0 / 64.0);
    let p = encode_mode(&frame, &pc, context::MODE_CONTEXT).unwrap();
    let n = pc.positions.len();
    assert!(decode(&frame, n, &p.payload, p.raw_len).is_ok());
    // A header claiming far more points than the bytes can hold fails before allocating them.
    let err = decode(&frame, crate::codec::MAX_ELEMENTS as usize, &p.payload, p.raw_len).unwrap_err();
    assert!(matches!(err, CodecError::Corrupt("point count does not match the streams")), "{err}");
    for wrong in [n - 1, n + 1] {
        assert!(decode(&frame, wrong, &p.payload, p.raw_len).is_err(), "{wrong} points");
    }
}

#[test]
fn flat_ground_is_padded_to_the_minimum_size() {
    // Perfectly flat, upright points cost almost nothing: the encoder pads to one byte per
    // POINTS_PER_BYTE points, and the decoder accepts exactly that padding.
    let mut pc = PointCloud::default();
    for y in 0..200 {
        for x in 0..200 {
            pc.positions.push([f64::from(x), f64::from(y), 5.0]);
            pc.normals.push([0.0, 0.0, 1.0]);
        }
    }
    let (frame, _, _) = setup(&pc, 1.0);
    let p = encode_mode(&frame, &pc, context::MODE_CONTEXT).unwrap();
    let n = pc.positions.len();
    assert!(p.payload.len() >= n / context::POINTS_PER_BYTE);
    let back = decode(&frame, n, &p.payload, p.raw_len).unwrap();
    assert_eq!(back.positions.len(), n);
    both_modes_agree(&pc, 1.0);
}

#[test]
fn stacked_and_sparse_clouds_round_trip_in_context_mode() {
    // Cliffs (many points per column), isolated points far apart, one row, one column.
    let mut rng = Rng(11);
    let mut pc = PointCloud::default();
    for _ in 0..500 {
        let (x, y) = (rng.below(20) as f64, rng.below(20) as f64);
        pc.positions.push([x * 3.0, y * 3.0, rng.below(400) as f64 * 0.25]);
        pc.normals.push([rng.unit() as f32 - 0.5, rng.unit() as f32 - 0.5, -0.3]);
    }
    pc.positions.push([5000.0, 9000.0, 1.0]);
    pc.normals.push([0.0, -1.0, 0.0]);
    both_modes_agree(&pc, 0.25);
    let row = PointCloud {
        positions: (0..300).map(|i| [f64::from(i) * 2.0, 7.0, f64::from(i % 17)]).collect(),
        normals: vec![[0.3, 0.1, 0.9]; 300],
    };
    both_modes_agree(&row, 0.5);
    let column = PointCloud {
        positions: (0..300).map(|i| [7.0, f64::from(i) * 2.0, f64::from(i % 17)]).collect(),
        normals: vec![[0.3, 0.1, -0.9]; 300],
    };
    both_modes_agree(&column, 0.5);
}

#[test]
fn lattice_params_round_trip_and_are_range_checked() {
    let frame = QuantGrid::new(&Bounds::new([0.0; 3], [10.0; 3]), Quantization { xy_step: 1.0, z_step: 1.0 })
        .unwrap();
    let lp = LatticeParams { base: [1, 2, 3], stride: [1, 2, 5], shift: MAX_SHIFT };
    let mut w = Writer::default();
    lp.write(&mut w);
    let mut r = Reader::new(&w.bytes, "points params");
    let back = LatticeParams::read(&mut r, &frame).unwrap();
    r.finish().unwrap();
    assert_eq!((back.base, back.stride, back.shift), (lp.base, lp.stride, lp.shift));
    assert_eq!(back.position(&frame, [0, 0, 0]).unwrap(), frame.position([1, 2, 3]));
    assert_eq!(back.position(&frame, [1, 2, 1]).unwrap(), frame.position([2, 6, 8]));
    // Off the frame, and overflowing: errors, not wrapped positions.
    assert!(back.position(&frame, [0, 0, 2]).is_err());
    assert!(back.position(&frame, [i64::MAX, 0, 0]).is_err());

    let bad = |base: [i64; 3], stride: [i64; 3], shift: u32| {
        let mut w = Writer::default();
        LatticeParams { base, stride, shift }.write(&mut w);
        LatticeParams::read(&mut Reader::new(&w.bytes, "points params"), &frame).unwrap_err().to_string()
    };
    assert!(bad([1, 2, 3], [1, 0, 1], 0).contains("points params"), "a zero stride");
    let beyond = frame.qmax[0] + 1;
    assert!(bad([beyond, 0, 0], [1; 3], 0).contains("points params"), "a base past the frame");
    assert!(bad([0; 3], [MAX_QUANT + 2, 1, 1], 0).contains("points params"), "a stride past the lattice");
    assert!(bad([0; 3], [1; 3], MAX_SHIFT + 1).contains("points params"), "a shift past MAX_SHIFT");
    // Truncated: every prefix is an error.
    for cut in 0..w.bytes.len() {
        assert!(
            LatticeParams::read(&mut Reader::new(&w.bytes[..cut], "points params"), &frame).is_err(),
            "{cut}"
        );
    }
}
