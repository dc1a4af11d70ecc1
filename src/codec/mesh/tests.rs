//! Tests of this module: round trips, hostile input, and size figures.

// Exact float equality is the point of these tests: decoding must be bit-exact.
#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic, clippy::float_cmp)]

use proptest::prelude::*;

use super::*;
use crate::codec::testdata::{Rng, canonical_positions, canonical_triangles, greedy_tin, synthetic};
use crate::codec::{Quantization, quantize_positions};
use crate::geom::Bounds;

fn frame_for(m: &Mesh, xy_step: f64, z_step: f64) -> (QuantGrid, Bounds, Quantization) {
    let mut b = Bounds::of_points(&m.positions);
    if !b.is_valid() {
        b = Bounds::new([0.0; 3], [1.0; 3]);
    }
    let q = Quantization { xy_step, z_step };
    // The bounds the header would state (grown to the rounded-up positions).
    let b = crate::codec::quantized_bounds(&b, &m.positions, q);
    (QuantGrid::new(&b, q).unwrap(), b, q)
}

/// Encodes and decodes; checks the decoded mesh has the quantized input's triangles and
/// vertices, and returns the mode used and the raw size.
fn round_trip(m: &Mesh, xy_step: f64, z_step: f64) -> (u8, usize) {
    let (frame, b, q) = frame_for(m, xy_step, z_step);
    let packed = encode(&frame, m).unwrap();
    let raw = &packed.payload;
    let back = decode(&frame, m.positions.len(), m.triangles.len(), raw, packed.raw_len).unwrap();
    let snapped = Mesh { positions: quantize_positions(&m.positions, &b, q), triangles: m.triangles.clone() };
    assert_eq!(canonical_triangles(&back), canonical_triangles(&snapped));
    assert_eq!(canonical_positions(&back.positions), canonical_positions(&snapped.positions));
    assert_eq!(&encode(&frame, m).unwrap().payload, raw, "deterministic");
    (raw[0], raw.len())
}

fn grid_delaunay(rng: &mut Rng, w: u32, n: usize) -> Mesh {
    use spade::{DelaunayTriangulation, Point2, Triangulation};
    let mut dt: DelaunayTriangulation<Point2<f64>> = DelaunayTriangulation::new();
    for p in [[0, 0], [w, 0], [0, w], [w, w]] {
        dt.insert(Point2::new(f64::from(p[0]), f64::from(p[1]))).unwrap();
    }
    for _ in 0..n {
        let (x, y) = (rng.below(u64::from(w) + 1), rng.below(u64::from(w) + 1));
        dt.insert(Point2::new(x as f64, y as f64)).unwrap();
    }
    let positions = dt
        .vertices()
        .map(|v| {
            let p = v.position();
            [p.x * 10.0, p.y * 10.0, 100.0 + (p.x * 0.3).sin() * 20.0 + p.y * 0.5]
        })
        .collect();
    let triangles = dt.inner_faces().map(|f| f.vertices().map(|v| v.fix().index() as u32)).collect();
    Mesh { positions, triangles }
}

#[test]
fn empty_mesh() {
    assert_eq!(round_trip(&Mesh::default(), 1.0, 1.0).0, MODE_SWEEP_FORWARD);
}

#[test]
fn lone_vertices() {
    let m = Mesh { positions: vec![[0.0, 0.0, 0.0], [3.0, 1.0, 2.0], [1.0, 2.0, 5.0]], triangles: vec![] };
    round_trip(&m, 1.0, 1.0);
}

#[test]
fn single_triangle_both_windings() {
    let positions = vec![[0.0, 0.0, 1.0], [4.0, 0.0, 2.0], [0.0, 4.0, 3.0]];
    let ccw = Mesh { positions: positions.clone(), triangles: vec![[0, 1, 2]] };
    let cw = Mesh { positions, triangles: vec![[0, 2, 1]] };
    // A lone triangle fits either sweep direction.
    assert_ne!(round_trip(&ccw, 1.0, 0.5).0, MODE_GENERAL);
    assert_ne!(round_trip(&cw, 1.0, 0.5).0, MODE_GENERAL);
}

#[test]
fn greedy_tin_uses_sweep() {
    let hf = synthetic(65, 65, 30.0);
    let m = greedy_tin(&hf, 2.0);
    assert!(m.positions.len() > 100);
    let (mode, size) = round_trip(&m, 30.0, 0.1);
    assert_eq!(mode, MODE_SWEEP_FORWARD);
    assert!(size < 8 * m.positions.len(), "{size} bytes raw for {} vertices", m.positions.len());
    // A clockwise copy sweeps too.
    let cw = Mesh {
        positions: m.positions.clone(),
        triangles: m.triangles.iter().map(|t| [t[0], t[2], t[1]]).collect(),
    };
    assert_ne!(round_trip(&cw, 30.0, 0.1).0, MODE_GENERAL);
}

#[test]
fn random_grid_delaunay_uses_sweep() {
    let mut rng = Rng(7);
    for n in [0, 1, 5, 40, 300] {
        let m = grid_delaunay(&mut rng, 64, n);
        assert_eq!(round_trip(&m, 10.0, 0.01).0, MODE_SWEEP_FORWARD, "n = {n}");
    }
}

#[test]
fn input_order_does_not_matter_for_sweep() {
    let mut rng = Rng(3);
    let m = grid_delaunay(&mut rng, 50, 200);
    let (frame, _, _) = frame_for(&m, 10.0, 0.01);
    // Reverse vertex numbering and triangle order, rotate every triangle.
    let n = m.positions.len() as u32;
    let shuffled = Mesh {
        positions: m.positions.iter().rev().copied().collect(),
        triangles: m.triangles.iter().rev().map(|t| [n - 1 - t[1], n - 1 - t[2], n - 1 - t[0]]).collect(),
    };
    assert_eq!(encode(&frame, &m).unwrap().payload, encode(&frame, &shuffled).unwrap().payload);
}

#[test]
fn non_planar_mesh_uses_general() {
    // A closed tetrahedron: not a planar triangulation of its x, y.
    let m = Mesh {
        positions: vec![[0.0, 0.0, 0.0], [4.0, 0.0, 0.0], [0.0, 4.0, 0.0], [1.0, 1.0, 4.0]],
        triangles: vec![[0, 2, 1], [0, 1, 3], [1, 2, 3], [2, 0, 3]],
    };
    assert_eq!(round_trip(&m, 1.0, 1.0).0, MODE_GENERAL);
}

#[test]
fn degenerate_and_duplicate_triangles_use_general() {
    let m = Mesh {
        positions: vec![[0.0, 0.0, 0.0], [4.0, 0.0, 0.0], [0.0, 4.0, 0.0], [0.0, 4.0, 9.0]],
        triangles: vec![[0, 1, 2], [0, 1, 2], [1, 1, 2], [2, 2, 2], [3, 0, 1]],
    };
    assert_eq!(round_trip(&m, 1.0, 1.0).0, MODE_GENERAL);
}

#[test]
fn general_mesh_keeps_unreferenced_vertices() {
    let mut rng = Rng(11);
    let mut m = Mesh::default();
    for _ in 0..200 {
        m.positions.push([rng.unit() * 100.0, rng.unit() * 100.0, rng.unit() * 100.0]);
    }
    for _ in 0..150 {
        m.triangles.push([0, 1, 2].map(|_| rng.below(120) as u32));
    }
    assert_eq!(round_trip(&m, 0.01, 0.01).0, MODE_GENERAL);
}

#[test]
fn corrupt_payloads_are_errors() {
    let hf = synthetic(33, 33, 30.0);
    let m = greedy_tin(&hf, 1.0);
    let (frame, _, _) = frame_for(&m, 30.0, 0.1);
    let p = encode(&frame, &m).unwrap();
    let (raw, len) = (&p.payload, p.raw_len);
    let (v, t) = (m.positions.len(), m.triangles.len());
    assert!(decode(&frame, v, t, raw, len).is_ok());
    assert!(decode(&frame, v + 1, t, raw, len).is_err());
    assert!(decode(&frame, v, t + 1, raw, len).is_err());
    assert!(decode(&frame, v, t.saturating_sub(1), raw, len).is_err());
    assert!(decode(&frame, v, t, &raw[..raw.len() - 1], len).is_err());
    assert!(decode(&frame, v, t, raw, len + 1).is_err());
    let mut bad = raw.clone();
    bad[0] = 9;
    assert!(decode(&frame, v, t, &bad, len).is_err());
}

fn arb_mesh() -> impl Strategy<Value = Mesh> {
    (1usize..40).prop_flat_map(|n| {
        (
            proptest::collection::vec((0u8..16, 0u8..16, 0u16..1000), n),
            proptest::collection::vec([0..n as u32, 0..n as u32, 0..n as u32], 0..60),
        )
            .prop_map(|(p, triangles)| Mesh {
                positions: p
                    .into_iter()
                    .map(|(x, y, z)| [f64::from(x), f64::from(y), f64::from(z) * 0.25])
                    .collect(),
                triangles,
            })
    })
}

proptest! {
    #[test]
    fn any_mesh_round_trips(m in arb_mesh()) {
        round_trip(&m, 1.0, 0.25);
    }

    #[test]
    fn random_payloads_never_panic(raw in proptest::collection::vec(any::<u8>(), 0..200), v in 0usize..50, t in 0usize..50, len in 0usize..300) {
        let frame = QuantGrid::new(&Bounds::new([0.0; 3], [100.0; 3]), Quantization { xy_step: 1.0, z_step: 1.0 }).unwrap();
        let _ = decode(&frame, v, t, &raw, len);
    }

    #[test]
    fn mutated_streams_never_panic(seed in any::<u64>(), stream in 0usize..9, flips in proptest::collection::vec((any::<usize>(), any::<u8>()), 1..6), general in any::<bool>()) {
        let mut rng = Rng(seed);
        let mut m = grid_delaunay(&mut rng, 30, 40);
        if general {
            m.triangles.push([0, 0, 1]);
        }
        let (frame, _, _) = frame_for(&m, 10.0, 0.01);
        let p = encode(&frame, &m).unwrap();
        let names = if general { GENERAL_STREAMS.to_vec() } else { SWEEP_STREAMS.to_vec() };
        let u = crate::codec::stream::unpack(&p.payload, p.raw_len, &names).unwrap();
        let bad = u.mutate_and_pack(stream, &flips).unwrap();
        let _ = decode(&frame, m.positions.len(), m.triangles.len(), &bad.payload, bad.raw_len);
    }

    #[test]
    fn mutated_payloads_never_panic(seed in any::<u64>(), flips in 1usize..8) {
        let mut rng = Rng(seed);
        let m = grid_delaunay(&mut rng, 30, 40);
        let (frame, _, _) = frame_for(&m, 10.0, 0.01);
        let p = encode(&frame, &m).unwrap();
        let mut raw = p.payload;
        for _ in 0..flips {
            let i = rng.below(raw.len() as u64) as usize;
            raw[i] ^= 1 << rng.below(8);
        }
        let _ = decode(&frame, m.positions.len(), m.triangles.len(), &raw, p.raw_len);
    }
}

#[test]
fn gap_buffer_front_matches_a_vec() {
    let mut rng = Rng(9);
    let mut front = Front::default();
    let mut model: Vec<[u32; 2]> = Vec::new();
    for step in 0..5000u32 {
        let len = model.len();
        match rng.below(4) {
            0 => {
                let p = rng.below(len as u64 + 1) as usize;
                front.insert_lone(p, step);
                if p > 0 {
                    model[p - 1][1] = NONE;
                }
                model.insert(p, [step, NONE]);
            }
            1 if len > 0 => {
                let p = rng.below(len as u64) as usize;
                front.insert_spike(p, step);
                let [w, below] = model[p];
                model[p][1] = NONE;
                model.insert(p + 1, [w, below]);
                model.insert(p + 1, [step, NONE]);
            }
            _ if len >= 2 => {
                let k = 2 + rng.below((len as u64 - 1).min(6)) as usize;
                let p = rng.below((len - k + 1) as u64) as usize;
                front.close(p, k, step);
                let (second, before_last) = (model[p + 1][0], model[p + k - 2][0]);
                model[p][1] = second;
                model.splice(p + 1..p + k - 1, [[step, before_last]]);
            }
            _ => {}
        }
        assert_eq!(front.len(), model.len());
        if step % 97 == 0 {
            for (i, e) in model.iter().enumerate() {
                assert_eq!(front.entry(i), *e);
            }
        }
    }
}
