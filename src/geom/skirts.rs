//! Skirts: vertical walls hung below a tile mesh's border edges, so neighbouring tiles drawn
//! at different levels (whose border vertices differ: T-junctions) show no crack; and how deep
//! they must be.

use rustc_hash::FxHashMap;

use super::{Bounds, Mesh};
use glam::DVec3;

/// Skirt depth that hides the crack between a mesh with geometric error `own` and a neighbour
/// with error `neighbour` (world units): both deviate from the same raster by at most their
/// error, so their borders are at most `own + neighbour` apart vertically.
#[must_use]
pub fn skirt_depth(own: f64, neighbour: f64) -> f64 {
    own.max(0.0) + neighbour.max(0.0)
}

/// A mesh with skirts: the input's vertices and triangles first, then one skirt vertex per border
/// vertex (`first_skirt_vertex..`) and two triangles per border edge.
#[derive(Debug, Clone, PartialEq)]
pub struct Skirted {
    pub mesh: Mesh,
    pub first_skirt_vertex: usize,
    pub first_skirt_triangle: usize,
    /// For each skirt vertex (from `first_skirt_vertex`), the border vertex it hangs below.
    pub skirt_tops: Vec<u32>,
}

/// A triangle's edge `(a, b)` in its winding and the triangle's third vertex.
type Corner = (u32, u32, u32);

/// Adds skirts to a tile mesh: every border edge (used by one triangle) gets a vertical wall
/// hanging `depth` below it, facing outward, so a neighbour drawn at another level (whose border
/// vertices differ: a T-junction) shows the wall instead of the background through the crack.
/// Edges on the dataset's outer border (`outer`, within a relative 1e-9) get none: no neighbour
/// can crack there and the wall would be seen from outside. Renderers shade a skirt vertex with
/// the normal of the vertex above it so the wall reads as the surface.
#[must_use]
pub fn add_skirts(mesh: &Mesh, depth: f64, outer: Option<&Bounds>) -> Skirted {
    // Per undirected edge: how many triangles use it, and the last one's (a, b, c).
    let mut edges: FxHashMap<(u32, u32), (u32, Corner)> = FxHashMap::default();
    edges.reserve(mesh.triangles.len() * 3 / 2 + 16);
    for t in &mesh.triangles {
        for k in 0..3 {
            let (a, b, c) = (t[k], t[(k + 1) % 3], t[(k + 2) % 3]);
            let e = edges.entry((a.min(b), a.max(b))).or_insert((0, (a, b, c)));
            e.0 += 1;
            e.1 = (a, b, c);
        }
    }
    let mut border: Vec<(u32, u32, u32)> = edges.values().filter(|(n, _)| *n == 1).map(|(_, u)| *u).collect();
    border.sort_unstable();
    let on_outer = |p: [f64; 3], q: [f64; 3]| {
        outer.is_some_and(|o| {
            let tol = 1e-9 * (o.size()[0].abs() + o.size()[1].abs()).max(1.0);
            (0..2).any(|a| {
                ((p[a] - o.min[a]).abs() <= tol && (q[a] - o.min[a]).abs() <= tol)
                    || ((p[a] - o.max[a]).abs() <= tol && (q[a] - o.max[a]).abs() <= tol)
            })
        })
    };
    let mut out = mesh.clone();
    let first_skirt_vertex = out.positions.len();
    let first_skirt_triangle = out.triangles.len();
    let mut skirt_of: FxHashMap<u32, u32> = FxHashMap::default();
    let mut skirt_tops = Vec::new();
    for (a, b, c) in border {
        let (pa, pb, pc) =
            (mesh.positions[a as usize], mesh.positions[b as usize], mesh.positions[c as usize]);
        if on_outer(pa, pb) {
            continue;
        }
        let mut skirt = |v: u32, p: [f64; 3]| {
            *skirt_of.entry(v).or_insert_with(|| {
                out.positions.push([p[0], p[1], p[2] - depth]);
                skirt_tops.push(v);
                (out.positions.len() - 1) as u32
            })
        };
        let (sa, sb) = (skirt(a, pa), skirt(b, pb));
        // Wall (b, a, a') faces away from the triangle's third vertex.
        let (pa, pb, pc) = (DVec3::from_array(pa), DVec3::from_array(pb), DVec3::from_array(pc));
        let wall = (pa - pb).cross(DVec3::NEG_Z);
        let mid = (pa + pb) * 0.5;
        if wall.dot(pc - mid) <= 0.0 {
            out.triangles.push([b, a, sa]);
            out.triangles.push([b, sa, sb]);
        } else {
            out.triangles.push([a, b, sb]);
            out.triangles.push([a, sb, sa]);
        }
    }
    Skirted { mesh: out, first_skirt_vertex, first_skirt_triangle, skirt_tops }
}
