//! Tests of this module: round trips, hostile input, and size figures.

// Exact float equality is the point of these tests: decoding must be bit-exact.
#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic, clippy::float_cmp)]

use proptest::prelude::*;

use super::*;
use crate::codec::testdata::{Rng, canonical_positions, canonical_triangles, greedy_tin, synthetic};
use crate::codec::{Quantization, quantize_positions};
use crate::geom::Bounds;

fn frame_for(m: &Mesh, xy_step: f64, z_step: f64) -> (Frame, Bounds, Quantization) {
    let mut b = Bounds::of_points(&m.positions);
    if !b.is_valid() {
        b = Bounds { min: [0.0; 3], max: [1.0; 3] };
    }
    let q = Quantization { xy_step, z_step };
    (Frame::new(&b, q).unwrap(), b, q)
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
        let frame = Frame::new(&Bounds { min: [0.0; 3], max: [100.0; 3] }, Quantization { xy_step: 1.0, z_step: 1.0 }).unwrap();
        let _ = decode(&frame, v, t, &raw, len);
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

fn entropy(vals: &[i64]) -> f64 {
    let mut m = std::collections::HashMap::new();
    for &v in vals {
        *m.entry(v).or_insert(0usize) += 1;
    }
    let n = vals.len() as f64;
    m.values().map(|&c| -(c as f64 / n) * (c as f64 / n).log2()).sum::<f64>()
}

/// Compares z predictors on real data (order-0 entropy of residuals, bits per vertex).
#[test]
#[ignore = "analysis"]
fn analyse_z_predictors() {
    use crate::codec::testdata::fuji;
    let Some(hf) = fuji() else { return };
    for max_error in [1.0, 5.0] {
        let m = greedy_tin(&hf, max_error);
        let extent = 511.0 * 30.0;
        let b = Bounds::of_points(&m.positions);
        let b = Bounds { min: [0.0, 0.0, b.min[2]], max: [extent, extent, b.max[2]] };
        let frame = Frame::new(&b, Quantization { xy_step: 30.0, z_step: 0.1 }).unwrap();
        let p = encode(&frame, &m).unwrap();
        let back = decode(&frame, m.positions.len(), m.triangles.len(), &p.payload, p.raw_len).unwrap();
        let q: Vec<[i64; 3]> =
            back.positions.iter().enumerate().map(|(i, &p)| frame.quantize(p, i).unwrap()).collect();
        let xy: Vec<[i64; 2]> = q.iter().map(|p| [p[0], p[1]]).collect();
        let z: Vec<i64> = q.iter().map(|p| p[2]).collect();
        let n = q.len();
        let mut tri_start = vec![0usize; n + 1];
        for t in &back.triangles {
            tri_start[t[2] as usize + 1] += 1;
        }
        for v in 0..n {
            tri_start[v + 1] += tri_start[v];
        }
        // Neighbours of every vertex.
        let mut nb: Vec<Vec<u32>> = vec![Vec::new(); n];
        for t in &back.triangles {
            for i in 0..3 {
                let (a, b) = (t[i], t[(i + 1) % 3]);
                if !nb[a as usize].contains(&b) {
                    nb[a as usize].push(b);
                }
                if !nb[b as usize].contains(&a) {
                    nb[b as usize].push(a);
                }
            }
        }
        let mut res: Vec<Vec<i64>> = vec![Vec::new(); 6];
        let mut across = HashMap::new();
        for v in 0..n {
            let fan = &back.triangles[tri_start[v]..tri_start[v + 1]];
            let p0 = predict_z(v, &xy, &z[..v], fan, &across).clamp(0, frame.qmax[2]);
            res[0].push(z[v] - p0);
            // Mean of earlier neighbours.
            let earlier: Vec<u32> = nb[v].iter().copied().filter(|&u| (u as usize) < v).collect();
            let mean = if earlier.is_empty() {
                z.get(v.wrapping_sub(1)).copied().unwrap_or(0)
            } else {
                earlier.iter().map(|&u| z[u as usize]).sum::<i64>() / earlier.len() as i64
            };
            res[1].push(z[v] - mean);
            // Inverse-distance weighted earlier neighbours.
            let idw = if earlier.is_empty() {
                mean
            } else {
                let (mut s, mut w) = (0.0, 0.0);
                for &u in &earlier {
                    let d = ((xy[u as usize][0] - xy[v][0]).pow(2) + (xy[u as usize][1] - xy[v][1]).pow(2))
                        as f64;
                    s += z[u as usize] as f64 / d;
                    w += 1.0 / d;
                }
                (s / w).round() as i64
            };
            res[2].push(z[v] - idw);
            // Median of plane predictions (else mean).
            res[3].push(z[v] - i64::midpoint(p0, idw));
            // Interpolation from all neighbours (upper bound for a two-pass order).
            let all = &nb[v];
            let allmean = if all.is_empty() {
                0
            } else {
                let (mut s, mut w) = (0.0, 0.0);
                for &u in all {
                    let d = ((xy[u as usize][0] - xy[v][0]).pow(2) + (xy[u as usize][1] - xy[v][1]).pow(2))
                        as f64;
                    s += z[u as usize] as f64 / d;
                    w += 1.0 / d;
                }
                (s / w).round() as i64
            };
            res[4].push(z[v] - allmean);
            // Least-squares plane through earlier neighbours, evaluated at v.
            let lsq = if earlier.len() >= 3 {
                let (mut sxx, mut sxy, mut syy, mut sx, mut sy, mut s1, mut sxz, mut syz, mut sz) =
                    (0.0f64, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0);
                for &u in &earlier {
                    let (x, y, zz) = (
                        (xy[u as usize][0] - xy[v][0]) as f64,
                        (xy[u as usize][1] - xy[v][1]) as f64,
                        z[u as usize] as f64,
                    );
                    sxx += x * x;
                    sxy += x * y;
                    syy += y * y;
                    sx += x;
                    sy += y;
                    s1 += 1.0;
                    sxz += x * zz;
                    syz += y * zz;
                    sz += zz;
                }
                // Solve [sxx sxy sx; sxy syy sy; sx sy s1] [a b c] = [sxz syz sz], prediction = c.
                let det =
                    sxx * (syy * s1 - sy * sy) - sxy * (sxy * s1 - sy * sx) + sx * (sxy * sy - syy * sx);
                if det.abs() < 1e-9 {
                    idw
                } else {
                    let c = (sxx * (syy * sz - sy * syz) - sxy * (sxy * sz - sy * sxz)
                        + sx * (sxy * syz - syy * sxz))
                        / det;
                    c.round() as i64
                }
            } else {
                idw
            };
            res[5].push(z[v] - lsq);
            for &[a, b, c] in fan {
                across.insert((a, b), c);
                across.insert((b, c), a);
                across.insert((c, a), b);
            }
        }
        let names = [
            "current planes",
            "mean earlier",
            "idw earlier",
            "avg(planes, idw)",
            "idw all (two-pass bound)",
            "lsq plane earlier",
        ];
        for (name, r) in names.iter().zip(&res) {
            let mut w = BucketWriter::default();
            for &v in r {
                w.signed(v);
            }
            let (a, b) = w.finish();
            let zs = zstd::bulk::compress(&a.bytes, 19).unwrap().len() + b.bytes.len();
            println!(
                "max_err {max_error}: {name}: H0 {:.2} bits, zstd {:.2} bits",
                entropy(r),
                zs as f64 * 8.0 / n as f64
            );
        }
    }
}
