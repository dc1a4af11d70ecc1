use super::*;
use crate::formats::qmesh::codec::{decode, oct_decode};
use crate::formats::qmesh::grid::TileId;

/// Rough terrain as a function of position only: what any source looks like to the sampler.
#[allow(clippy::unnecessary_wraps)] // the sampler's height function returns an Option
fn relief(lon: f64, lat: f64) -> Option<f64> {
    let (x, y) = (lon * 40.0, lat * 40.0);
    Some(800.0 + 600.0 * (x.sin() * y.cos()) + 90.0 * (3.1 * x + 1.7 * y).sin() + 20.0 * (11.0 * x).cos())
}

fn tile(z: u8, x: u32, y: u32) -> (TileId, BuiltTile, QmTile) {
    let id = TileId::new(z, x, y).unwrap();
    let s = TileSamples::from_fn(id, relief, |_, _| 0.0);
    let b = build_tile(&s, 1.0, None).unwrap();
    let d = decode(&b.bytes).unwrap();
    (id, b, d)
}

/// (lon, lat, height) of every decoded vertex.
fn positions(id: TileId, t: &QmTile) -> Vec<(f64, f64, f64)> {
    let r = id.rect();
    let (lo, hi) = (f64::from(t.header.min_height), f64::from(t.header.max_height));
    (0..t.u.len())
        .map(|k| {
            let f = |q: u16| f64::from(q) / 32767.0;
            (
                r.west + (r.east - r.west) * f(t.u[k]),
                r.south + (r.north - r.south) * f(t.v[k]),
                lo + (hi - lo) * f(t.h[k]),
            )
        })
        .collect()
}

#[test]
fn neighbours_share_edge_vertices_heights_and_normals() {
    for z in [9u8, 12, 14] {
        let (x, y) = ((10.7 + 180.0) as u32 * (1 << z) / 180, (46.6 + 90.0) as u32 * (1 << z) / 180);
        let (a, ta, da) = tile(z, x, y);
        let (b, tb, db) = tile(z, x + 1, y);
        let (c, _, dc) = tile(z, x, y + 1);
        assert!(ta.lattice_exact && tb.lattice_exact);
        let east: Vec<(u16, f64, [u8; 2])> = da
            .east
            .iter()
            .map(|&k| {
                (da.v[k as usize], positions(a, &da)[k as usize].2, da.normals.as_ref().unwrap()[k as usize])
            })
            .collect();
        let west: Vec<(u16, f64, [u8; 2])> = db
            .west
            .iter()
            .map(|&k| {
                (db.v[k as usize], positions(b, &db)[k as usize].2, db.normals.as_ref().unwrap()[k as usize])
            })
            .collect();
        assert_eq!(east.len(), west.len(), "zoom {z}: the same edge vertices");
        for (e, w) in east.iter().zip(&west) {
            assert_eq!(e.0, w.0);
            assert!((e.1 - w.1).abs() < 1e-9, "zoom {z}: heights {} and {}", e.1, w.1);
            assert_eq!(e.2, w.2, "zoom {z}: normals");
        }
        let north: Vec<(u16, f64)> =
            da.north.iter().map(|&k| (da.u[k as usize], positions(a, &da)[k as usize].2)).collect();
        let south: Vec<(u16, f64)> =
            dc.south.iter().map(|&k| (dc.u[k as usize], positions(c, &dc)[k as usize].2)).collect();
        assert_eq!(north.len(), south.len());
        for (n, s) in north.iter().zip(&south) {
            assert_eq!(n.0, s.0);
            assert!((n.1 - s.1).abs() < 1e-9);
        }
    }
}

#[test]
fn every_sample_is_within_the_bound() {
    for z in [0u8, 3, 8, 12, 15] {
        let (id, b, d) = tile(z, (2u32 << z) * 3 / 5, (1u32 << z) / 2);
        assert!(b.max_error <= b.bound, "zoom {z}: {} > {}", b.max_error, b.bound);
        assert!(b.vertices >= 4 && b.vertices == d.u.len());
        // Independently: the decoded mesh against the height function at every sample.
        let p = positions(id, &d);
        let r = id.rect();
        for tri in &d.triangles {
            let v = tri.map(|k| p[k as usize]);
            // Counter-clockwise seen from above.
            let area = (v[1].0 - v[0].0) * (v[2].1 - v[0].1) - (v[2].0 - v[0].0) * (v[1].1 - v[0].1);
            assert!(area > 0.0, "zoom {z}: clockwise triangle");
        }
        let mut worst = 0.0f64;
        for j in 0..=CELLS {
            for i in 0..=CELLS {
                let (lon, lat) = id.sample(i64::from(i), i64::from(j));
                let want = relief(lon, lat).unwrap();
                let got = interpolate(&p, &d.triangles, lon, lat).expect("covered");
                worst = worst.max((got - want).abs());
            }
        }
        // u/v quantization moves vertices by up to half a step of 1/32767 of the tile.
        let slack = 45_000.0 * (r.east - r.west) / 65_534.0 + 1e-6;
        assert!(worst <= b.bound + slack, "zoom {z}: {worst} > {} (+{slack})", b.bound);
    }
}

fn interpolate(p: &[(f64, f64, f64)], tris: &[[u32; 3]], x: f64, y: f64) -> Option<f64> {
    for t in tris {
        let [a, b, c] = t.map(|k| p[k as usize]);
        let d = (b.1 - c.1) * (a.0 - c.0) + (c.0 - b.0) * (a.1 - c.1);
        let l1 = ((b.1 - c.1) * (x - c.0) + (c.0 - b.0) * (y - c.1)) / d;
        let l2 = ((c.1 - a.1) * (x - c.0) + (a.0 - c.0) * (y - c.1)) / d;
        let l3 = 1.0 - l1 - l2;
        let eps = -1e-9;
        if l1 >= eps && l2 >= eps && l3 >= eps {
            return Some(l1 * a.2 + l2 * b.2 + l3 * c.2);
        }
    }
    None
}

#[test]
fn coarse_tiles_bound_their_chords() {
    // Zoom 0 over flat ground: only the curve asks for vertices, and no triangle's chord sags
    // more than the bound.
    let id = TileId::new(0, 1, 0).unwrap();
    let s = TileSamples::from_fn(id, |_, _| Some(0.0), |_, _| 0.0);
    let b = build_tile(&s, 1.0, None).unwrap();
    let d = decode(&b.bytes).unwrap();
    assert!(
        b.vertices > 9 && b.max_error <= b.bound,
        "{} vertices, {} of {}",
        b.vertices,
        b.max_error,
        b.bound
    );
    let p = positions(id, &d);
    let cell = crate::formats::qmesh::grid::cell_degrees(0);
    for t in &d.triangles {
        for (a, c) in [(t[0], t[1]), (t[1], t[2]), (t[2], t[0])] {
            let (pa, pc) = (p[a as usize], p[c as usize]);
            // The chord's sag on the sphere, from its length in degrees.
            let theta = ((pa.0 - pc.0).powi(2) + (pa.1 - pc.1).powi(2)).sqrt().to_radians();
            assert!(
                6_378_137.0 * theta * theta / 8.0 <= b.bound * 1.0001,
                "an edge of {} samples",
                theta.to_degrees() / cell
            );
        }
    }
    // From zoom 14 the curve asks for nothing: a flat tile is two triangles.
    let id = TileId::new(14, 17_000, 12_000).unwrap();
    let s = TileSamples::from_fn(id, |_, _| Some(120.0), |_, _| 0.0);
    assert_eq!(build_tile(&s, 1.0, None).unwrap().vertices, 4);
}

#[test]
fn normals_point_up_on_flat_ground_and_the_mask_marks_no_data() {
    let id = TileId::new(12, 4000, 2500).unwrap();
    let r = id.rect();
    let mid = f64::midpoint(r.west, r.east);
    let s = TileSamples::from_fn(id, |lon, _| (lon < mid).then_some(100.0), |_, _| 0.0);
    let b = build_tile(&s, 1.0, Some("{\"available\":[]}".into())).unwrap();
    let d = decode(&b.bytes).unwrap();
    assert_eq!(d.metadata.as_deref(), Some("{\"available\":[]}"));
    let Some(WaterMask::Grid(g)) = &d.watermask else { panic!("a mixed tile has a mask grid") };
    // North-west texel: data (land); north-east: no data (water).
    assert_eq!((g[0], g[255]), (0, 255));
    let p = positions(id, &d);
    for (k, n) in d.normals.as_ref().unwrap().iter().enumerate() {
        let (lon, lat, _) = p[k];
        if (lon - mid).abs() < 2.0 * (r.east - r.west) / 64.0 {
            continue; // the step between the two levels
        }
        let (lo, la) = (lon.to_radians(), lat.to_radians());
        let up = [la.cos() * lo.cos(), la.cos() * lo.sin(), la.sin()];
        let v = oct_decode(*n);
        let dot = up[0] * v[0] + up[1] * v[1] + up[2] * v[2];
        assert!(dot > 0.999, "normal {v:?} at {lon}, {lat}");
    }
}

#[test]
fn horizon_point_hides_the_tile_only_behind_the_horizon() {
    let (_, _, d) = tile(10, 1100, 700);
    let hp = d.header.horizon;
    let m = (hp[0] * hp[0] + hp[1] * hp[1] + hp[2] * hp[2]).sqrt();
    // In ellipsoid-scaled units: just above the unit sphere for a small tile (not metres).
    assert!(m > 1.0 && m < 1.01, "{m}");
}

#[test]
fn bad_samples_are_refused() {
    let id = TileId::new(3, 1, 1).unwrap();
    let mut s = TileSamples::from_fn(id, relief, |_, _| 0.0);
    s.heights[100] = f64::NAN;
    assert!(matches!(build_tile(&s, 1.0, None), Err(BuildError::NonFinite { .. })));
    let s = TileSamples::from_fn(id, |_, _| Some(1.0e6), |_, _| 0.0);
    assert!(matches!(build_tile(&s, 1.0, None), Err(BuildError::Range { .. })));
}

/// A 2.5 km high plateau whose edge (a cliff down to sea level) crosses the shared edge of two
/// zoom-17 tiles: more relief than 32,767 steps of the zoom's lattice (1/32 m) hold. Told the
/// dataset's relief, both tiles coarsen the lattice alike: the edge decodes to the same heights
/// on both sides and every sample stays within the bound; not told it, the tiles miss the
/// lattice (their edges are a height step apart).
#[test]
fn relief_beyond_the_lattice_keeps_edges_exact_when_the_dataset_relief_is_known() {
    let z = 17u8;
    let (x, y) = ((7.7 + 180.0) / 180.0 * f64::from(1u32 << z), (46.4 + 90.0) / 180.0 * f64::from(1u32 << z));
    let (x, y) = (x as u32, y as u32);
    let a = TileId::new(z, x, y).unwrap();
    let (edge_lon, mid_lat) = (a.rect().east, f64::midpoint(a.rect().south, a.rect().north));
    let cliff = move |lon: f64, lat: f64| {
        let above = lat - mid_lat > 0.3 * (lon - edge_lon);
        Some(if above { 2_450.0 + 3_000.0 * (lon - edge_lon) } else { 48.0 })
    };
    let build = |id: TileId, relief: Option<f64>| {
        let mut s = TileSamples::from_fn(id, cliff, |_, _| 48.0);
        s.relief = relief;
        let b = build_tile(&s, 1.0, None).unwrap();
        let d = decode(&b.bytes).unwrap();
        (b, d)
    };
    let b = TileId::new(z, x + 1, y).unwrap();
    let ((ta, _), (tb, _)) = (build(a, None), build(b, None));
    assert!(!ta.lattice_exact && !tb.lattice_exact, "the tiles outgrow the zoom's own lattice");
    let ((ta, da), (tb, db)) = (build(a, Some(2_700.0)), build(b, Some(2_700.0)));
    assert!(ta.lattice_exact && tb.lattice_exact);
    assert!(
        ta.max_error <= ta.bound && tb.max_error <= tb.bound,
        "{} {} of {}",
        ta.max_error,
        tb.max_error,
        ta.bound
    );
    let edge = |id: TileId, d: &QmTile, ks: &[u32]| -> Vec<(u16, f64)> {
        let p = positions(id, d);
        ks.iter().map(|&k| (d.v[k as usize], p[k as usize].2)).collect()
    };
    let (east, west) = (edge(a, &da, &da.east), edge(b, &db, &db.west));
    assert!(east.len() > 2);
    assert_eq!(east, west, "the same edge vertices at the same heights");
    let (lo, hi) = east.iter().fold((f64::MAX, f64::MIN), |(l, h), e| (l.min(e.1), h.max(e.1)));
    assert!(hi - lo > 2_000.0, "the cliff crosses the shared edge");
}
