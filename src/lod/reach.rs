//! Which point levels of a node a screen-space-error selector can ever choose (issue 39). Pure.
//!
//! The client (`client::select`) draws a node `B` only while its parent `P` is split, and `P`
//! stays split only while some node `D` of `P`'s subtree outside `B`'s is over the threshold with
//! its finest level, its mesh: `e_D·k / d_D > τ` — `P` itself, or a node under one of `B`'s
//! siblings (`P` merges only once all its children are in the cut). Here `d` is the eye's
//! distance to a node's box centre and `k = w / (2·tan(φ/2))`. `B` draws its level `l` only when
//! `e_l·k / d_B ≤ τ`. Both at once need `e_l / d_B < e_D / d_D`, and `d_B ≤ d_D + δ` with `δ` the
//! distance between the two centres: from `e_l·k/τ ≤ d_B ≤ d_D + δ < e_D·k/τ + δ`,
//!
//! ```text
//!     e_l < e_D + α·δ,     α = τ / k  (the threshold as an angle)
//! ```
//!
//! is necessary for level `l` to be drawn anywhere. The centres of `P`'s subtree lie in `P`'s
//! box and the meshes below `P` are finer than `P`'s, so a node keeps a point level only if
//!
//! ```text
//!     e_l < e_P + α·δ_P,   δ_P = distance from B's centre to the farthest corner of P's box
//! ```
//!
//! ([`reach`], [`farthest_corner`]). A level that fails it is never drawn by such a client,
//! whatever the camera: storing it costs bytes and bake time for nothing. The distance clamp
//! near the eye does not change the bound (clamping both distances keeps `d_B ≤ d_D + δ`).
//! [`REACH_ANGLE`] is the largest `α` a tileset is baked for; a root has no parent, so every
//! level of it can be reached. `tests/levels_reach.rs` replays flights with the selector itself
//! over tilesets with every level stored and checks that no level it draws was dropped.
//!
//! 3D Tiles clients refine by the same comparison with distances to boxes; the 3D Tiles tree
//! lists a child's level only when its error is at most its parent's (the spec's monotone
//! chain), which is within this bound.
//!
//! [`gap_lower_bound`] predicts, before a level is baked, that it cannot be reached: the level's
//! error is at least its gap (the largest distance from the surface to its nearest point), and
//! `N` points whose discs of radius `g` cover the node's footprint (every surface point's
//! projection lies within `g` of a point's projection) need `N·π·g² ≥ A`.

use crate::geom::Mesh;

/// The threshold angle `τ / k` (radians) the stored levels serve: 4 px on a 1024 px wide view of
/// 60° (`4 · 2·tan 30° / 1024`). The reference client's default is 1 px (`--threshold`), so a
/// client at its defaults reaches every stored level from 256 px wide windows up; a client
/// drawing at a coarser angle than this may find a level missing and draws the parent's mesh
/// instead (finer, never a hole). `--point-levels all` stores every level that is cheaper.
pub const REACH_ANGLE: f64 = 4.0 * 1.154_700_538_379_251_5 / 1024.0;

/// The error below which a child's point level can be chosen: `e_P + α·δ` for a parent whose
/// finest level's error is `parent_error`, `delta` from [`farthest_corner`].
#[must_use]
pub fn reach(parent_error: f64, delta: f64) -> f64 {
    parent_error + REACH_ANGLE * delta
}

/// The distance from `centre` to the farthest corner of `parent`.
#[must_use]
pub fn farthest_corner(centre: glam::DVec3, parent: &crate::geom::Bounds) -> f64 {
    let far = |a: f64, lo: f64, hi: f64| (a - lo).abs().max((hi - a).abs());
    glam::DVec3::new(
        far(centre.x, parent.min.x, parent.max.x),
        far(centre.y, parent.min.y, parent.max.y),
        far(centre.z, parent.min.z, parent.max.z),
    )
    .length()
}

/// A lower bound on the geometric error of a point level of a terrain node's `mesh` (one that
/// covers its x/y box, [`max_points`]) baked on the cubic grid
/// (`origin`, `cell`), from the most points the bake can make: a covering of the `footprint`
/// area (the node's extent in x and y) by that many discs of radius gap, less the gap's
/// measuring tolerance (`cell / 8`, `lod::measure`). Never above the level's measured
/// `ErrorFigures::geometric`; 0 when nothing can be said.
#[must_use]
pub fn gap_lower_bound(mesh: &Mesh, origin: [f64; 3], cell: f64, footprint: f64) -> f64 {
    let n = max_points(mesh, origin, cell, true);
    if n == 0 || footprint.is_nan() || footprint <= 0.0 || cell.is_nan() || cell <= 0.0 {
        return 0.0;
    }
    ((footprint / (std::f64::consts::PI * n as f64)).sqrt() - cell / 8.0).max(0.0)
}

/// The most points a bake of `mesh` on (`origin`, `cell`) can produce: cells the surface can
/// occupy plus the fills. A bake's cell holds a point only where a fragment of a triangle, a
/// point of the triangle, falls in it, so per x/y column of cells the occupied cells lie within
/// the z cells of the triangles whose boxes reach that column. Fills (`lod::cpu`) come at most
/// two per empty column of an axis whose four edge neighbours are occupied: per axis no more
/// than twice the occupied cells and twice the columns of the box's projection. A terrain
/// node's mesh covers its x/y box, so along z only the box's outer ring of columns can be
/// empty (`covers_box`).
/// Most x/y columns [`max_points`] tracks one by one.
const MAX_COLUMNS: f64 = 1_048_576.0;

#[must_use]
pub fn max_points(mesh: &Mesh, origin: [f64; 3], cell: f64, covers_box: bool) -> u64 {
    if mesh.triangles.is_empty() || cell.is_nan() || cell <= 0.0 {
        return 0;
    }
    let g = |p: [f64; 3], a: usize| ((p[a] - origin[a]) / cell).floor();
    // Per triangle, its box in cells (triangles with a vertex out of range have none).
    let boxes: Vec<([f64; 3], [f64; 3])> = mesh
        .triangles
        .iter()
        .filter_map(|t| {
            let (mut tl, mut th) = ([f64::INFINITY; 3], [f64::NEG_INFINITY; 3]);
            for &v in t {
                let p = *mesh.positions.get(v as usize)?;
                for a in 0..3 {
                    let c = g(p, a);
                    tl[a] = tl[a].min(c);
                    th[a] = th[a].max(c);
                }
            }
            (tl.iter().chain(&th).all(|c| c.is_finite())).then_some((tl, th))
        })
        .collect();
    if boxes.is_empty() {
        return 0;
    }
    let (mut lo, mut hi) = ([f64::INFINITY; 3], [f64::NEG_INFINITY; 3]);
    for (tl, th) in &boxes {
        for a in 0..3 {
            lo[a] = lo[a].min(tl[a]);
            hi[a] = hi[a].max(th[a]);
        }
    }
    let extent: [f64; 3] = std::array::from_fn(|a| hi[a] - lo[a] + 1.0);
    let box_cells: f64 = extent.iter().product();
    let boxes_sum: f64 =
        boxes.iter().map(|(tl, th)| (0..3).map(|a| th[a] - tl[a] + 1.0).product::<f64>()).sum();
    // Columns of z spans when the x/y grid and the triangles' column boxes are small enough to
    // visit (each triangle's box once); else the sum of the triangles' boxes.
    let column_visits: f64 = boxes.iter().map(|(tl, th)| (th[0] - tl[0] + 1.0) * (th[1] - tl[1] + 1.0)).sum();
    let surface = if extent[0] * extent[1] <= MAX_COLUMNS && column_visits <= 16.0 * MAX_COLUMNS {
        let (nx, ny) = (extent[0] as usize, extent[1] as usize);
        let mut span = vec![(i64::MAX, i64::MIN); nx * ny];
        for (tl, th) in &boxes {
            let (k0, k1) = (tl[2] as i64, th[2] as i64);
            for j in (tl[1] - lo[1]) as usize..=(th[1] - lo[1]) as usize {
                for i in (tl[0] - lo[0]) as usize..=(th[0] - lo[0]) as usize {
                    let s = &mut span[j * nx + i];
                    s.0 = s.0.min(k0);
                    s.1 = s.1.max(k1);
                }
            }
        }
        span.iter().filter(|s| s.0 <= s.1).map(|s| (s.1 - s.0 + 1) as f64).sum::<f64>()
    } else {
        boxes_sum
    };
    let surface = surface.min(boxes_sum).min(box_cells);
    let columns: f64 = (0..3)
        .map(|a| {
            let (u, v) = (extent[(a + 1) % 3], extent[(a + 2) % 3]);
            let empty = if a == 2 && covers_box { 2.0 * (u + v) } else { u * v };
            surface.min(empty)
        })
        .sum();
    let n = surface + 2.0 * columns;
    if n >= u64::MAX as f64 { u64::MAX } else { n as u64 }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::lod::cpu;

    fn terrain(n: u32, amp: f64, seed: u64) -> Mesh {
        let mut positions = Vec::new();
        let mut s = seed;
        for j in 0..=n {
            for i in 0..=n {
                s = s.wrapping_mul(6_364_136_223_846_793_005).wrapping_add(1_442_695_040_888_963_407);
                let r = (s >> 11) as f64 / (1u64 << 53) as f64;
                let (x, y) = (f64::from(i), f64::from(j));
                positions.push([x, y, amp * ((x * 0.3).sin() * (y * 0.2).cos() + r)]);
            }
        }
        let w = n + 1;
        let mut triangles = Vec::new();
        for j in 0..n {
            for i in 0..n {
                let a = j * w + i;
                triangles.push([a, a + 1, a + w + 1]);
                triangles.push([a, a + w + 1, a + w]);
            }
        }
        Mesh { positions, triangles }
    }

    /// The bound never exceeds what the bake measures, on smooth, rough and cliff-like surfaces
    /// and every cell from a fraction of the sample spacing to the whole tile.
    #[test]
    fn gap_bound_is_below_the_measured_error() {
        for (amp, seed) in [(0.0, 1), (0.5, 2), (4.0, 3), (20.0, 4)] {
            let mesh = terrain(24, amp, seed);
            let b = crate::geom::Bounds::of_points(&mesh.positions);
            let area = (b.max.x - b.min.x) * (b.max.y - b.min.y);
            for cell in [0.4, 1.0, 2.5, 6.0, 13.0, 30.0] {
                let origin = [b.min.x, b.min.y, (b.min.z / cell).floor() * cell];
                let pc = cpu::bake_points(&mesh, origin, cell);
                let n = max_points(&mesh, origin, cell, true);
                assert!(
                    pc.positions.len() as u64 <= n,
                    "amp {amp} cell {cell}: {} > {n}",
                    pc.positions.len()
                );
                let measured = cpu::measure_points(&mesh, &pc, cell, crate::lod::TERRAIN_FOOTPRINT_HALF);
                let lb = gap_lower_bound(&mesh, origin, cell, area);
                assert!(lb <= measured.geometric(), "amp {amp} cell {cell}: bound {lb} > {measured:?}");
                if amp == 0.0 && 24.0 / cell >= 9.0 {
                    // Useful where it matters: on a flat tile nine cells wide or more, a fifth of the cell.
                    assert!(lb >= 0.2 * cell, "cell {cell}: bound {lb}");
                }
            }
        }
    }

    #[test]
    fn reach_grows_with_distance() {
        assert!((reach(3.0, 0.0) - 3.0).abs() < 1e-12);
        assert!(reach(3.0, 1000.0) > 3.0 + 4.0 && reach(3.0, 1000.0) < 3.0 + 5.0);
        assert_eq!(max_points(&Mesh::default(), [0.0; 3], 1.0, true), 0);
        assert!(gap_lower_bound(&Mesh::default(), [0.0; 3], 1.0, 10.0).abs() < 1e-12);
    }
}
