//! Structured round trip: a small random mesh or point cloud on a random quantization grid is
//! encoded, decoded and compared with what the format says decoding returns (positions snapped
//! by `quantize_positions`, normals by `quantize_normals`, order free).
#![no_main]
use arbitrary::Arbitrary;
use libfuzzer_sys::fuzz_target;
use terrastream::codec::{self, Geometry, Quantization};
use terrastream::geom::{Bounds, ErrorFigures, Mesh, PointCloud};
use terrastream::tiling::TileKey;
use terrastream_fuzz::{canonical_mesh, canonical_points, check_in_bounds};

#[derive(Debug, Arbitrary)]
struct Input {
    points: bool,
    key: (u8, u32, u32),
    level: u8,
    /// bounds.min = origin · 2^origin_exp.
    origin: [i32; 3],
    origin_exp: i8,
    /// Steps: (1 + m/256) · 2^e.
    xy_step: (u8, i8),
    z_step: (u8, i8),
    /// Steps per axis, and how far (in 1/256 of a step, below half a step; negative means 0)
    /// max lies beyond the last step. Never a max below the last grid point: that is the
    /// `codec_blob` target's bounds check (defect D1), kept out of this round trip.
    extent: [(u16, i8); 3],
    /// Grid coordinates (taken modulo the extent) and an offset in 1/256 of a step (±0.5).
    verts: Vec<([u16; 3], [i8; 3])>,
    tris: Vec<[u16; 3]>,
    normals: Vec<[i8; 3]>,
    errors: [u16; 3],
}

fn step((m, e): (u8, i8)) -> f64 {
    (1.0 + f64::from(m) / 256.0) * 2f64.powi(i32::from(e % 24))
}

// Caps keep one execution well under a millisecond (at 2,000 vertices the grown corpus ran at
// 433 exec/s); larger clouds exercise no other code path: the codec's per-vertex loops are the
// same, and the tests in `src/codec` cover full tiles.
fuzz_target!(|inp: Input| {
    if inp.verts.len() > 256 || inp.tris.len() > 512 {
        return;
    }
    let q = Quantization { xy_step: step(inp.xy_step), z_step: step(inp.z_step) };
    let s = [q.xy_step, q.xy_step, q.z_step];
    let scale = 2f64.powi(i32::from(inp.origin_exp % 16));
    let min: [f64; 3] = std::array::from_fn(|a| f64::from(inp.origin[a]) * scale);
    let max: [f64; 3] = std::array::from_fn(|a| {
        let (n, frac) = inp.extent[a];
        let beyond = (f64::from(frac) / 256.0).max(0.0);
        min[a] + (f64::from(n) + beyond) * s[a]
    });
    let bounds = Bounds::new(min, max);
    let qmax: [i64; 3] = std::array::from_fn(|a| ((max[a] - min[a]) / s[a]).round() as i64);
    let positions: Vec<[f64; 3]> = inp
        .verts
        .iter()
        .map(|(g, off)| {
            std::array::from_fn(|a| {
                let k = i64::from(g[a]) % (qmax[a] + 1);
                // Offsets stay strictly inside ±half a step and never leave [min, max].
                let o = f64::from(off[a]) / 257.0;
                let o = if k == 0 {
                    o.max(0.0)
                } else if k == qmax[a] {
                    o.min(0.0)
                } else {
                    o
                };
                (min[a] + (k as f64 + o) * s[a]).clamp(min[a], max[a])
            })
        })
        .collect();
    let key = TileKey { z: inp.key.0, x: inp.key.1, y: inp.key.2 };
    let errors = ErrorFigures {
        max: f64::from(inp.errors[0]) / 16.0,
        rms: f64::from(inp.errors[1]) / 16.0,
        gap: f64::from(inp.errors[2]) / 16.0,
    };
    let snapped = codec::quantize_positions(&positions, &bounds, q);
    // The header states the bounds grown to the quantized positions (D1's fix).
    let stated = codec::quantized_bounds(&bounds, &positions, q);
    let (bytes, expect) = if inp.points {
        let normals: Vec<[f32; 3]> = (0..positions.len())
            .map(|i| {
                let n = inp.normals.get(i).copied().unwrap_or([0, 0, 1]);
                if n == [0, 0, 0] { [0.0, 0.0, 1.0] } else { n.map(f32::from) }
            })
            .collect();
        let pc = PointCloud { positions, normals };
        let bytes = codec::encode_points(key, inp.level, &bounds, q, &pc, errors)
            .unwrap_or_else(|e| panic!("valid points rejected: {e}"));
        let normals = codec::quantize_normals(&pc.normals).unwrap_or_else(|e| panic!("normals: {e}"));
        (bytes, Geometry::Points(PointCloud { positions: snapped, normals }))
    } else {
        let n = positions.len();
        let triangles: Vec<[u32; 3]> = if n == 0 {
            Vec::new()
        } else {
            inp.tris.iter().map(|t| t.map(|i| u32::from(i) % n as u32)).collect()
        };
        let mesh = Mesh { positions, triangles };
        let bytes = codec::encode_mesh(key, inp.level, &bounds, q, &mesh, errors)
            .unwrap_or_else(|e| panic!("valid mesh rejected: {e}"));
        (bytes, Geometry::Mesh(Mesh { positions: snapped, triangles: mesh.triangles }))
    };
    let blob = codec::decode(&bytes).unwrap_or_else(|e| panic!("encoded blob does not decode: {e}"));
    assert_eq!(codec::decode_header(&bytes).ok().as_ref(), Some(&blob.header));
    let h = &blob.header;
    assert_eq!((h.key, h.level, h.bounds(), h.quant, h.errors), (key, inp.level, stated, q, errors));
    match (&blob.geometry, &expect) {
        (Geometry::Mesh(got), Geometry::Mesh(want)) => {
            assert!(canonical_mesh(got) == canonical_mesh(want), "mesh changed:\n{got:?}\n{want:?}");
            check_in_bounds(h, &got.positions);
        }
        (Geometry::Points(got), Geometry::Points(want)) => {
            assert!(canonical_points(got) == canonical_points(want), "points changed:\n{got:?}\n{want:?}");
            check_in_bounds(h, &got.positions);
        }
        _ => panic!("kind changed"),
    }
    // Deterministic: the same input encodes to the same bytes.
    let again =
        terrastream_fuzz::reencode(&blob).unwrap_or_else(|e| panic!("decoded blob does not re-encode: {e}"));
    let back = codec::decode(&again).unwrap_or_else(|e| panic!("re-encoded blob does not decode: {e}"));
    terrastream_fuzz::assert_same_geometry(&blob.geometry, &back.geometry);
});
