use super::*;
use crate::geom::ErrorFigures;
use crate::lod::measure::point_triangle_dist2;
use proptest::prelude::*;

/// Deterministic xorshift for test inputs.
struct Rng(u64);
impl Rng {
    fn next(&mut self) -> f64 {
        self.0 ^= self.0 << 13;
        self.0 ^= self.0 >> 7;
        self.0 ^= self.0 << 17;
        (self.0 >> 11) as f64 / (1u64 << 53) as f64
    }
}

/// A regular grid mesh over [x0, x0 + nx·step] × [y0, y0 + ny·step] with z = f(x, y),
/// leaving out the quads for which `hole(qx, qy)` is true.
fn grid_mesh(
    nx: u32,
    ny: u32,
    x0: f64,
    y0: f64,
    step: f64,
    f: impl Fn(f64, f64) -> f64,
    hole: impl Fn(u32, u32) -> bool,
) -> Mesh {
    let mut m = Mesh::default();
    for y in 0..=ny {
        for x in 0..=nx {
            let (px, py) = (x0 + f64::from(x) * step, y0 + f64::from(y) * step);
            m.positions.push([px, py, f(px, py)]);
        }
    }
    let id = |x: u32, y: u32| y * (nx + 1) + x;
    for y in 0..ny {
        for x in 0..nx {
            if hole(x, y) {
                continue;
            }
            m.triangles.push([id(x, y), id(x + 1, y), id(x + 1, y + 1)]);
            m.triangles.push([id(x, y), id(x + 1, y + 1), id(x, y + 1)]);
        }
    }
    m
}

/// Icosphere of radius `r` around `c`, outward right-hand triangles.
fn icosphere(c: [f64; 3], r: f64, subdivisions: u32) -> Mesh {
    let t = f64::midpoint(1.0, 5.0f64.sqrt());
    let mut v: Vec<[f64; 3]> = vec![
        [-1.0, t, 0.0],
        [1.0, t, 0.0],
        [-1.0, -t, 0.0],
        [1.0, -t, 0.0],
        [0.0, -1.0, t],
        [0.0, 1.0, t],
        [0.0, -1.0, -t],
        [0.0, 1.0, -t],
        [t, 0.0, -1.0],
        [t, 0.0, 1.0],
        [-t, 0.0, -1.0],
        [-t, 0.0, 1.0],
    ];
    let mut f: Vec<[u32; 3]> = vec![
        [0, 11, 5],
        [0, 5, 1],
        [0, 1, 7],
        [0, 7, 10],
        [0, 10, 11],
        [1, 5, 9],
        [5, 11, 4],
        [11, 10, 2],
        [10, 7, 6],
        [7, 1, 8],
        [3, 9, 4],
        [3, 4, 2],
        [3, 2, 6],
        [3, 6, 8],
        [3, 8, 9],
        [4, 9, 5],
        [2, 4, 11],
        [6, 2, 10],
        [8, 6, 7],
        [9, 8, 1],
    ];
    let norm = |p: [f64; 3]| {
        let l = (p[0] * p[0] + p[1] * p[1] + p[2] * p[2]).sqrt();
        [p[0] / l, p[1] / l, p[2] / l]
    };
    for p in &mut v {
        *p = norm(*p);
    }
    for _ in 0..subdivisions {
        let mut mid = std::collections::HashMap::new();
        let mut next = Vec::new();
        for tri in &f {
            let mut m = [0u32; 3];
            for e in 0..3 {
                let (a, b) = (tri[e], tri[(e + 1) % 3]);
                let key = (a.min(b), a.max(b));
                m[e] = *mid.entry(key).or_insert_with(|| {
                    let (pa, pb) = (v[a as usize], v[b as usize]);
                    v.push(norm([pa[0] + pb[0], pa[1] + pb[1], pa[2] + pb[2]]));
                    (v.len() - 1) as u32
                });
            }
            next.push([tri[0], m[0], m[2]]);
            next.push([tri[1], m[1], m[0]]);
            next.push([tri[2], m[2], m[1]]);
            next.push([m[0], m[1], m[2]]);
        }
        f = next;
    }
    Mesh {
        positions: v.iter().map(|p| [c[0] + r * p[0], c[1] + r * p[1], c[2] + r * p[2]]).collect(),
        triangles: f,
    }
}

fn dist_to_mesh(mesh: &Mesh, p: [f64; 3]) -> f64 {
    mesh.triangles
        .iter()
        .map(|t| {
            let tri = t.map(|i| glam::DVec3::from_array(mesh.positions[i as usize]));
            point_triangle_dist2(glam::DVec3::from_array(p), &tri)
        })
        .fold(f64::INFINITY, f64::min)
        .sqrt()
}

/// Synthetic terrain: smooth hills plus a steep ridge, on a jittered grid.
fn terrain(n: u32, step: f64, seed: u64) -> Mesh {
    let mut rng = Rng(seed);
    let mut m = grid_mesh(
        n,
        n,
        0.0,
        0.0,
        step,
        |x, y| {
            20.0 * (x * 0.03).sin() * (y * 0.025).cos()
                + 8.0 * (x * 0.11 + y * 0.07).sin()
                + 30.0 / (1.0 + (-(x - 0.6 * y - 40.0) * 0.5).exp())
        },
        |_, _| false,
    );
    let edge = f64::from(n) * step;
    for p in &mut m.positions {
        if p[0] > 0.0 && p[0] < edge && p[1] > 0.0 && p[1] < edge {
            p[0] += (rng.next() - 0.5) * 0.3 * step;
            p[1] += (rng.next() - 0.5) * 0.3 * step;
        }
    }
    m
}

#[test]
fn flat_square_gives_one_point_per_column_on_the_plane() {
    let m = grid_mesh(1, 1, 0.0, 0.0, 10.0, |_, _| 3.25, |_, _| false);
    let (cells, stats) = bake_cells(&m, [0.0; 3], 1.0, &SliceOptions::default());
    assert_eq!(cells.len(), 100);
    assert_eq!(stats.fragments, [0, 0, 100], "edge-on views have zero area");
    assert_eq!(stats.filled, 0);
    for c in &cells {
        assert_eq!(c.index[2], 3);
        assert_eq!(c.position, [f64::from(c.index[0]) + 0.5, f64::from(c.index[1]) + 0.5, 3.25]);
        assert_eq!(c.normal, [0.0, 0.0, 1.0]);
    }
    let cloud = bake_points(&m, [0.0; 3], 1.0);
    let e = point_errors(&m, &cloud, 1.0);
    assert!(e.max < 1e-12 && e.rms < 1e-12, "{e:?}");
    // Corners of the square are √½ from the nearest pixel centre.
    assert!((e.gap - 0.5f64.sqrt()).abs() < 0.01, "{e:?}");
}

#[test]
fn plane_off_the_fixed_point_lattice_is_within_rounding() {
    let (origin, cell) = ([-3.0, 7.0, 100.0], 0.37);
    let m = grid_mesh(3, 3, -2.9, 7.05, 1.1, |_, _| 101.123_456_7, |_, _| false);
    let cloud = bake_points(&m, origin, cell);
    assert!(!cloud.positions.is_empty());
    for p in &cloud.positions {
        assert!((p[2] - 101.123_456_7).abs() <= cell / POS_ONE, "{p:?}");
    }
}

#[test]
fn pixel_centres_on_shared_edges_and_vertices_are_produced_once() {
    // Vertices and diagonals on pixel centres: every centre is a tie for several triangles.
    let m = grid_mesh(8, 8, 0.5, 0.5, 1.0, |_, _| 0.5, |_, _| false);
    let (cells, stats) = bake_cells(&m, [0.0; 3], 1.0, &SliceOptions { fill_holes: false });
    // Centres 0.5 ..= 8.5 on each axis lie on the closed square; those on its far
    // boundary edges fall on non-tie edges and are left to the (absent) neighbour tile.
    assert_eq!(stats.fragments[2], cells.len() as u64);
    assert_eq!(cells.len(), 64, "one fragment per centre of the half-open square");
    // A mirrored diagonal split must give the same coverage.
    let mut m2 = m.clone();
    for t in &mut m2.triangles {
        t.swap(1, 2);
    }
    let (cells2, stats2) = bake_cells(&m2, [0.0; 3], 1.0, &SliceOptions { fill_holes: false });
    assert_eq!(stats2.fragments[2], 64);
    let idx: Vec<_> = cells.iter().map(|c| c.index).collect();
    let idx2: Vec<_> = cells2.iter().map(|c| c.index).collect();
    assert_eq!(idx, idx2);
}

#[test]
fn tilted_plane_points_lie_on_it_without_holes() {
    let f = |x: f64, y: f64| 0.3 * x + 0.2 * y + 1.1;
    let m = grid_mesh(6, 6, 0.0, 0.0, 2.0, f, |_, _| false);
    let cell = 0.5;
    let (cloud, stats) = bake_points_with_stats(&m, [0.0; 3], cell);
    assert!(stats.fragments.iter().all(|&n| n > 0), "{stats:?}");
    for p in &cloud.positions {
        // Means of points of one plane stay on it, up to the fixed-point rounding.
        let n = (0.3f64 * 0.3 + 0.2 * 0.2 + 1.0).sqrt();
        assert!((p[2] - f(p[0], p[1])).abs() / n < 2.0 * cell / POS_ONE, "{p:?}");
    }
    let e = point_errors(&m, &cloud, cell);
    assert!(e.max < 1e-4 * cell && e.gap < cell, "{e:?}");
}

#[test]
fn steep_slope_is_covered_by_the_side_views() {
    // 3:1 slope: the top view alone would leave 3-cell vertical gaps between its points.
    let f = |x: f64, y: f64| 3.0 * x + 0.5 * y;
    let m = grid_mesh(4, 4, 0.0, 0.0, 2.5, f, |_, _| false);
    let cell = 1.0;
    let (cloud, stats) = bake_points_with_stats(&m, [0.0; 3], cell);
    assert!(stats.fragments[0] > 2 * stats.fragments[2], "{stats:?}");
    let e = point_errors(&m, &cloud, cell);
    assert!(e.gap < cell && e.max < 1e-4, "{e:?}");
}

#[test]
fn closed_sphere_gets_points_on_all_sides_and_none_inside() {
    let (c, r) = ([10.3, -4.2, 7.7], 6.0);
    let m = icosphere(c, r, 3);
    let cell = 0.8;
    let (cells, stats) = bake_cells(&m, [0.0; 3], cell, &SliceOptions::default());
    assert!(stats.skipped_triangles == 0 && cells.len() > 300, "{stats:?}");
    let mut extremes = [f64::INFINITY, f64::NEG_INFINITY].repeat(3);
    for cell_pt in &cells {
        let p = cell_pt.position;
        let d = [p[0] - c[0], p[1] - c[1], p[2] - c[2]];
        let len = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt();
        // The mesh is inscribed in the sphere: its faces sit at most ~1 % inside.
        assert!(len > 0.97 * r && len < 1.001 * r, "{p:?} at {len}");
        let n = cell_pt.normal.map(f64::from);
        assert!(n[0] * d[0] + n[1] * d[1] + n[2] * d[2] > 0.5 * len, "inward normal at {p:?}");
        for a in 0..3 {
            extremes[2 * a] = extremes[2 * a].min(d[a]);
            extremes[2 * a + 1] = extremes[2 * a + 1].max(d[a]);
        }
    }
    for (a, e) in extremes.iter().enumerate() {
        assert!(e.abs() > r - cell, "side {a}: {e}");
    }
    let cloud = bake_points(&m, [0.0; 3], cell);
    let e = point_errors(&m, &cloud, cell);
    assert!(e.max < 0.1 * cell && e.gap < cell, "{e:?}");
}

#[test]
fn cube_faces_each_come_from_one_view() {
    let (a, b) = (0.3, 4.3);
    let v = |i: u32| {
        [if i & 1 == 0 { a } else { b }, if i & 2 == 0 { a } else { b }, if i & 4 == 0 { a } else { b }]
    };
    let m = Mesh {
        positions: (0..8).map(v).collect(),
        triangles: vec![
            [0, 2, 1],
            [1, 2, 3],
            [4, 5, 6],
            [5, 7, 6],
            [0, 1, 4],
            [1, 5, 4],
            [2, 6, 3],
            [3, 6, 7],
            [0, 4, 2],
            [2, 4, 6],
            [1, 3, 5],
            [3, 7, 5],
        ],
    };
    let (cells, stats) = bake_cells(&m, [0.0; 3], 1.0, &SliceOptions::default());
    // Each face's 4×4 pixel centres, from its axis's view only.
    assert_eq!(stats.fragments, [32, 32, 32]);
    assert_eq!(stats.filled, 0);
    assert_eq!(cells.iter().map(|c| c.samples).sum::<u64>(), 96);
    let on = |p: f64| (p - a).abs() < 1e-4 || (p - b).abs() < 1e-4;
    for c in &cells {
        let p = c.position;
        // Cells along the cube's edges average fragments of two or three faces.
        let faces: Vec<usize> = (0..3).filter(|&d| on(p[d])).collect();
        let mut expect = [0.0f64; 3];
        for d in 0..3 {
            let lo = f64::from(c.index[d]) < a + 0.5;
            let hi = f64::from(c.index[d]) > b - 1.0;
            if lo || hi {
                expect[d] = if lo { -1.0 } else { 1.0 };
            }
        }
        if c.samples == 1 {
            assert_eq!(faces.len(), 1, "{c:?}");
            let d = faces[0];
            assert_eq!(f64::from(c.normal[d]), expect[d], "{c:?}");
        } else {
            // Inside the cube there are no points; edge cells point diagonally out.
            let dot: f64 = (0..3).map(|d| f64::from(c.normal[d]) * expect[d]).sum();
            assert!(dot > 0.99 * (c.samples as f64).sqrt(), "{c:?}");
        }
    }
}

#[test]
fn output_is_deterministic_and_independent_of_triangle_order() {
    let m = terrain(24, 3.0, 7);
    let cell = 2.0;
    let origin = [0.0, 0.0, -40.0];
    let a = bake_cells(&m, origin, cell, &SliceOptions::default());
    let b = bake_cells(&m, origin, cell, &SliceOptions::default());
    assert_eq!(a, b);
    let mut shuffled = m.clone();
    let mut rng = Rng(99);
    for i in (1..shuffled.triangles.len()).rev() {
        let j = (rng.next() * (i + 1) as f64) as usize;
        shuffled.triangles.swap(i, j);
    }
    for (n, t) in shuffled.triangles.iter_mut().enumerate() {
        t.rotate_left(n % 3);
    }
    let c = bake_cells(&shuffled, origin, cell, &SliceOptions::default());
    assert_eq!(a, c);
    let keys: Vec<_> = a.0.iter().map(|c| (c.index[2], c.index[1], c.index[0])).collect();
    assert!(keys.windows(2).all(|w| w[0] < w[1]), "sorted by (k, j, i), unique");
}

#[test]
fn hole_filler_fills_a_single_pixel_but_not_a_large_hole() {
    // Quads are pixels here: quad (qx, qy) holds pixel centre (qx + ½, qy + ½).
    let f = |_: f64, _: f64| 2.4;
    let one = grid_mesh(9, 9, 0.0, 0.0, 1.0, f, |x, y| x == 4 && y == 5);
    let (cells, stats) = bake_cells(&one, [0.0; 3], 1.0, &SliceOptions::default());
    assert_eq!(stats.filled, 1, "{stats:?}");
    let filled: Vec<_> = cells.iter().filter(|c| c.filled).collect();
    assert_eq!(filled[0].index, [4, 5, 2]);
    // z carries the neighbours' fixed-point rounding.
    assert_eq!(filled[0].position, [4.5, 5.5, 2.0 + (0.4 * POS_ONE + 0.5).floor() / POS_ONE]);
    assert_eq!(filled[0].normal, [0.0, 0.0, 1.0]);
    let without = bake_cells(&one, [0.0; 3], 1.0, &SliceOptions { fill_holes: false });
    assert_eq!(without.0.len() + 1, cells.len());

    // A 6×6 hole stays open, corners included (they lack two edge neighbours).
    let big = grid_mesh(12, 12, 0.0, 0.0, 1.0, f, |x, y| (3..9).contains(&x) && (3..9).contains(&y));
    let (_, stats) = bake_cells(&big, [0.0; 3], 1.0, &SliceOptions::default());
    assert_eq!(stats.filled, 0, "{stats:?}");
    // So does a concave corner of the outline (an L-shaped region).
    let ell = grid_mesh(8, 8, 0.0, 0.0, 1.0, f, |x, y| x >= 4 && y >= 4);
    let (_, stats) = bake_cells(&ell, [0.0; 3], 1.0, &SliceOptions::default());
    assert_eq!(stats.filled, 0, "{stats:?}");
}

#[test]
fn hole_filler_uses_the_median_neighbour_depth() {
    // Neighbours at different heights: the fill takes the lower median of their keys.
    // Separate horizontal pixel quads around an empty centre, each at its own height.
    let heights = [[0.2, 0.3, 0.9], [0.1, 0.0, 1.4], [2.6, 0.6, 0.7]];
    let mut m = Mesh::default();
    for (qy, row) in heights.iter().enumerate() {
        for (qx, &h) in row.iter().enumerate() {
            if qx == 1 && qy == 1 {
                continue;
            }
            let base = m.positions.len() as u32;
            let (x, y) = (qx as f64, qy as f64);
            m.positions.extend([[x, y, h], [x + 1.0, y, h], [x + 1.0, y + 1.0, h], [x, y + 1.0, h]]);
            m.triangles.push([base, base + 1, base + 2]);
            m.triangles.push([base, base + 2, base + 3]);
        }
    }
    let (cells, stats) = bake_cells(&m, [0.0; 3], 1.0, &SliceOptions::default());
    assert_eq!(stats.filled, 1, "{stats:?}");
    let fill: Vec<_> = cells.iter().filter(|c| c.filled).collect();
    assert_eq!(fill[0].index[..2], [1, 1]);
    // Sorted neighbour heights 0.1 0.2 0.3 0.6 0.7 0.9 1.4 2.6: lower median 0.6, upper 0.7:
    // same slice, so one cell at their mean.
    let expected = 0.5 * ((0.6 * POS_ONE + 0.5).floor() + (0.7 * POS_ONE + 0.5).floor()) / POS_ONE;
    assert!((fill[0].position[2] - expected).abs() < 1e-12, "{:?}", fill[0]);
    assert_eq!(fill[0].samples, 2);
}

#[test]
fn measure_matches_brute_force() {
    let mut rng = Rng(3);
    let mut m = Mesh::default();
    for _ in 0..40 {
        m.positions.push([rng.next() * 6.0, rng.next() * 6.0, rng.next() * 3.0]);
    }
    for _ in 0..25 {
        let pick = |r: &mut Rng| (r.next() * 40.0) as u32;
        m.triangles.push([pick(&mut rng), pick(&mut rng), pick(&mut rng)]);
    }
    let points = PointCloud {
        positions: (0..60)
            .map(|_| [rng.next() * 8.0 - 1.0, rng.next() * 8.0 - 1.0, rng.next() * 5.0 - 1.0])
            .collect(),
        normals: vec![[0.0, 0.0, 1.0]; 60],
    };
    let cell = 0.7;
    let e = point_errors(&m, &points, cell);
    let d: Vec<f64> = points.positions.iter().map(|&p| dist_to_mesh(&m, p)).collect();
    let max = d.iter().copied().fold(0.0, f64::max);
    let rms = (d.iter().map(|v| v * v).sum::<f64>() / d.len() as f64).sqrt();
    assert!((e.max - max).abs() < 1e-9 && (e.rms - rms).abs() < 1e-9, "{e:?} vs {max} {rms}");
    // Brute-force gap on a denser sampling: equal within the sampling spacing.
    let mut gap = 0.0f64;
    for t in &m.triangles {
        let tri = t.map(|i| m.positions[i as usize]);
        for i in 0..=60 {
            for j in 0..=(60 - i) {
                let (u, v) = (f64::from(i) / 60.0, f64::from(j) / 60.0);
                let q =
                    [0, 1, 2].map(|a| tri[0][a] + u * (tri[1][a] - tri[0][a]) + v * (tri[2][a] - tri[0][a]));
                let near = points
                    .positions
                    .iter()
                    .map(|p| ((p[0] - q[0]).powi(2) + (p[1] - q[1]).powi(2) + (p[2] - q[2]).powi(2)).sqrt())
                    .fold(f64::INFINITY, f64::min);
                gap = gap.max(near);
            }
        }
    }
    assert!((e.gap - gap).abs() < cell / 4.0, "{} vs {gap}", e.gap);
}

#[test]
fn degenerate_inputs_give_empty_results() {
    let m = grid_mesh(2, 2, 0.0, 0.0, 1.0, |_, _| 0.0, |_, _| false);
    for cell in [0.0, -1.0, f64::NAN, f64::INFINITY] {
        let (cloud, stats) = bake_points_with_stats(&m, [0.0; 3], cell);
        assert!(cloud.positions.is_empty() && stats.skipped_triangles == m.triangles.len());
    }
    assert!(bake_points(&m, [f64::NAN, 0.0, 0.0], 1.0).positions.is_empty());
    assert!(bake_points(&Mesh::default(), [0.0; 3], 1.0).positions.is_empty());
    let mut bad = m.clone();
    bad.triangles.push([0, 1, 99]);
    bad.positions[8] = [f64::NAN, 0.0, 0.0];
    let (_, stats) = bake_points_with_stats(&bad, [0.0; 3], 1.0);
    // The bad index, and the two triangles at the NaN corner.
    assert_eq!(stats.skipped_triangles, 3);

    let cloud = bake_points(&m, [0.0; 3], 0.5);
    assert_eq!(measure_points(&Mesh::default(), &cloud, 0.5, 0.6), ErrorFigures::default());
    let e = measure_points(&m, &PointCloud::default(), 0.5, 0.6);
    assert!(e.max == 0.0 && (e.gap - 8.0f64.sqrt()).abs() < 1e-12, "{e:?}");
}

#[test]
fn terrain_tile_has_no_holes() {
    let m = terrain(32, 4.0, 11);
    let cell = 2.0;
    let (cloud, stats) = bake_points_with_stats(&m, [0.0, 0.0, -50.0], cell);
    assert!(stats.fragments[0] > 0 && stats.fragments[1] > 0, "{stats:?}");
    let e = point_errors(&m, &cloud, cell);
    // Inside the tile the side views keep the gap under a cell; along the tile's border
    // the surface beyond the last pixel centre (half a cell) is sampled only where it
    // crosses a slice, so the gap there reaches about √½·√(1 + slope²) cells.
    assert!(e.gap < 1.2 * cell && e.max < 0.1 * cell, "{e:?}");
}

#[test]
fn huge_index_boxes_take_the_wide_keys_with_the_same_result() {
    let near = icosphere([3.1, -2.2, 5.3], 4.0, 2);
    let mut far = near.clone();
    // A second triangle 2^26 cells away on every axis: too wide for 64-bit keys.
    let base = far.positions.len() as u32;
    let off = 67_108_864.0;
    far.positions.extend([[off, off, off], [off + 1.0, off, off], [off, off + 1.0, off + 0.5]]);
    far.triangles.push([base, base + 1, base + 2]);
    assert!(PackedCodec::new([-1, -1, -1], [67_108_866; 3]).is_none());
    let (a, sa) = bake_cells(&near, [0.0; 3], 0.5, &SliceOptions::default());
    let (b, sb) = bake_cells(&far, [0.0; 3], 0.5, &SliceOptions::default());
    assert_eq!(sb.skipped_triangles, 0);
    assert!(sb.occupied > sa.occupied);
    assert_eq!(a[..], b[..a.len()]);
    for c in &b[a.len()..] {
        assert!(c.index.iter().all(|&v| v >= 134_217_000), "{c:?}");
    }
}

#[test]
fn codecs_round_trip() {
    let packed = PackedCodec::new([-7, 3, -100], [20, 9, 400]).unwrap();
    for idx in [[-7, 3, -100], [20, 9, 400], [0, 5, 0], [-1, 4, 399]] {
        for axis in 0..3 {
            let k = packed.encode(idx, axis);
            assert_eq!((packed.decode(k), PackedCodec::axis(k)), (idx, axis));
            let w = WideCodec.encode(idx, axis);
            assert_eq!((WideCodec.decode(w), WideCodec::axis(w)), (idx, axis));
        }
    }
    let order = |i: [i32; 3]| (i[2], i[1], i[0]);
    let pairs = [([-7, 9, 0], [20, 3, 1]), ([0, 3, -100], [-7, 4, -100]), ([5, 5, 5], [6, 5, 5])];
    for (x, y) in pairs {
        assert_eq!(packed.encode(x, 2) < packed.encode(y, 0), order(x) < order(y));
        assert_eq!(WideCodec.encode(x, 2) < WideCodec.encode(y, 0), order(x) < order(y));
    }
    assert!(WideCodec.encode([i32::MIN, 0, -1], 0) < WideCodec.encode([i32::MAX, 0, -1], 0));
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(48))]
    #[test]
    fn points_lie_in_their_cells_near_the_mesh(
        seed in 1u64..u64::MAX,
        cell in 0.2f64..3.0,
        ox in -5.0f64..5.0, oy in -5.0f64..5.0, oz in -5.0f64..5.0,
    ) {
        let mut rng = Rng(seed);
        let mut m = Mesh::default();
        for _ in 0..12 {
            m.positions.push([rng.next() * 8.0, rng.next() * 8.0, rng.next() * 8.0]);
        }
        for _ in 0..8 {
            let pick = |r: &mut Rng| (r.next() * 12.0) as u32;
            m.triangles.push([pick(&mut rng), pick(&mut rng), pick(&mut rng)]);
        }
        let origin = [ox, oy, oz];
        let (cells, _) = bake_cells(&m, origin, cell, &SliceOptions::default());
        let eps = 1e-9 * (1.0 + cell);
        for c in &cells {
            for d in 0..3 {
                let lo = origin[d] + f64::from(c.index[d]) * cell;
                prop_assert!(c.position[d] >= lo - eps && c.position[d] <= lo + cell + eps, "{:?}", c);
            }
            let dist = dist_to_mesh(&m, c.position);
            // A fill copies a neighbour's depth one pixel away: allow two more cells.
            let bound = if c.filled { cell * (3.0f64.sqrt() + 2.2) } else { cell * 3.0f64.sqrt() };
            prop_assert!(dist <= bound, "{:?} at {}", c, dist);
            let n = c.normal;
            let len = f32::sqrt(n[0] * n[0] + n[1] * n[1] + n[2] * n[2]);
            prop_assert!((len - 1.0).abs() < 1e-5);
        }
    }
}

/// The errors with every point measured as a point (no normals, so no footprints): what the
/// slicing itself put where, before the footprints the renderer draws around each point.
fn point_errors(m: &Mesh, cloud: &PointCloud, cell: f64) -> ErrorFigures {
    let bare =
        PointCloud { positions: cloud.positions.clone(), normals: vec![[0.0; 3]; cloud.positions.len()] };
    measure_points(m, &bare, cell, 0.6)
}

#[test]
fn max_error_covers_a_footprint_tilted_off_the_surface() {
    // A flat 8 × 8 square; one point at its centre with its normal tilted 45° about x: the
    // footprint's corners lie half a footprint's width above and below the plane.
    let m = Mesh {
        positions: vec![[0.0, 0.0, 0.0], [8.0, 0.0, 0.0], [8.0, 8.0, 0.0], [0.0, 8.0, 0.0]],
        triangles: vec![[0, 1, 2], [0, 2, 3]],
    };
    let s = std::f32::consts::FRAC_1_SQRT_2;
    let cell = 1.0;
    let tilted = PointCloud { positions: vec![[4.0, 4.0, 0.0]], normals: vec![[0.0, s, s]] };
    let e = measure_points(&m, &tilted, cell, 0.6);
    assert!((e.max - 0.6 * cell).abs() < 1e-6, "{e:?}");
    assert!(e.rms < 1e-12, "{e:?}");
    let flat = PointCloud { positions: vec![[4.0, 4.0, 0.0]], normals: vec![[0.0, 0.0, 1.0]] };
    assert!(measure_points(&m, &flat, cell, 0.6).max < 1e-12);
}
