//! The collision region: the tiles a simulator's ego (vehicle, pawn, landing gear) may touch
//! must be at full detail whatever the camera does. Every leaf node whose bounding box lies
//! within `R` metres of the ego, measured horizontally (x, y) from the ego to the box, is
//! required at level 0 (the leaf's TIN mesh, the surface the heights API calls `mesh`). Pure:
//! the caller passes the tree and the ego; the session fetches, pins and counts.
//!
//! Distance is to the node's subtree box (`cull`, which for a leaf is its own box), so a node
//! whose box is farther than `R` has no descendant within `R` and its subtree is skipped; an
//! ego inside a box is at distance 0 from it, so the leaf under the ego is required however
//! small `R` is, and an ego on a shared edge requires both neighbours. A node within `R`
//! whose children are not loaded yet (their index chunk has not arrived) is *unresolved*: its
//! leaves cannot be named, so it is reported with the chunk to fetch.

use glam::{DVec2, DVec3};

use crate::client::ClientError;
use crate::client::tree::{NodeId, TileTree};
use crate::geom::Bounds;
use crate::store;
use crate::tiling::TileKey;

/// Seconds of ego motion the client fetches ahead of the region (`--collision-lookahead`):
/// leaves within `R` of where the ego will be in this many (wall-clock) seconds are fetched
/// before they are required.
pub const DEFAULT_LOOKAHEAD_S: f64 = 2.0;

/// Settings of the collision region (`--collision-radius`, `--collision-lookahead`).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CollisionParams {
    /// `R`: horizontal distance in world units (metres) from the ego to a node's box.
    pub radius_m: f64,
    /// Wall-clock seconds of ego motion fetched ahead.
    pub lookahead_s: f64,
}

impl CollisionParams {
    /// Checks the radius (finite, > 0) and the look-ahead (finite, ≥ 0).
    pub fn new(radius_m: f64, lookahead_s: f64) -> Result<Self, ClientError> {
        if !(radius_m.is_finite() && radius_m > 0.0) {
            return Err(ClientError::Collision(format!(
                "radius {radius_m} m must be a finite number above 0"
            )));
        }
        if !(lookahead_s.is_finite() && lookahead_s >= 0.0) {
            return Err(ClientError::Collision(format!(
                "look-ahead {lookahead_s} s must be a finite number, 0 or more"
            )));
        }
        Ok(Self { radius_m, lookahead_s })
    }
}

/// Horizontal (x, y) distance from `p` to the box `b`; 0 when `p` is over or under the box.
#[must_use]
pub fn horizontal_distance(b: &Bounds, p: DVec2) -> f64 {
    let (min, max) = (b.min.truncate(), b.max.truncate());
    (min - p).max(p - max).max(DVec2::ZERO).length()
}

/// The nodes within a radius of the ego.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Region {
    /// Leaves within the radius, in tree order (sorted by id).
    pub leaves: Vec<NodeId>,
    /// Inner nodes within the radius whose children are not loaded yet; the tree is empty when
    /// `root_missing`.
    pub unresolved: Vec<NodeId>,
    /// Index chunks (by root key) holding the unresolved nodes' children, sorted, no repeats.
    pub missing_chunks: Vec<TileKey>,
    /// The tree has no root yet: nothing can be named.
    pub root_missing: bool,
}

impl Region {
    /// Nodes that count as required: the leaves, each unresolved node, and the missing root.
    #[must_use]
    pub fn required(&self) -> usize {
        self.leaves.len() + self.unresolved.len() + usize::from(self.root_missing)
    }
}

/// The region of radius `radius` around `ego` (only x and y are used), into `out` (cleared
/// first, so its buffers are reused frame after frame).
pub fn region_into(tree: &TileTree, ego: DVec3, radius: f64, out: &mut Region) {
    out.leaves.clear();
    out.unresolved.clear();
    out.missing_chunks.clear();
    out.root_missing = false;
    let Some(root) = tree.root() else {
        out.root_missing = true;
        out.missing_chunks.push(TileKey::new(0, 0, 0));
        return;
    };
    let p = ego.truncate();
    let mut stack = vec![root];
    while let Some(n) = stack.pop() {
        let node = tree.node(n);
        if horizontal_distance(&node.cull, p) > radius {
            continue;
        }
        if node.is_leaf() {
            out.leaves.push(n);
            continue;
        }
        stack.extend(node.loaded_children());
        if !node.children_loaded() {
            out.unresolved.push(n);
            if let Some(c) = tree.pyramid().children(node.key).first() {
                out.missing_chunks.push(store::chunk_root(*c));
            }
        }
    }
    out.leaves.sort_unstable();
    out.unresolved.sort_unstable();
    out.missing_chunks.sort_unstable();
    out.missing_chunks.dedup();
}

/// The region of radius `radius` around `ego`.
#[must_use]
pub fn region(tree: &TileTree, ego: DVec3, radius: f64) -> Region {
    let mut r = Region::default();
    region_into(tree, ego, radius, &mut r);
    r
}

#[cfg(test)]
#[allow(clippy::float_cmp)] // distances to box corners here are exact
mod tests {
    use super::*;
    use crate::client::tree::Synthetic;

    /// 4×4 leaves of 64 cells × 10 m = 640 m, over 0..2560 m in x and y; depth 2 (21 nodes).
    fn tree() -> TileTree {
        let spec = Synthetic {
            width: 257,
            height: 257,
            tile_size: 64,
            cell_size: 10.0,
            relief: 100.0,
            levels: 2,
            leaf_error: 1.0,
            seed: 3,
        };
        TileTree::synthetic(&spec).unwrap()
    }

    fn keys(t: &TileTree, ids: &[NodeId]) -> Vec<(u32, u32)> {
        let mut k: Vec<(u32, u32)> = ids.iter().map(|&n| (t.node(n).key.x, t.node(n).key.y)).collect();
        k.sort_unstable();
        k
    }

    #[test]
    fn horizontal_distance_to_a_box() {
        let b = Bounds::new([0.0, 0.0, -50.0], [10.0, 20.0, 50.0]);
        assert_eq!(horizontal_distance(&b, DVec2::new(5.0, 5.0)), 0.0);
        assert_eq!(horizontal_distance(&b, DVec2::new(10.0, 20.0)), 0.0);
        assert_eq!(horizontal_distance(&b, DVec2::new(13.0, 10.0)), 3.0);
        assert_eq!(horizontal_distance(&b, DVec2::new(-3.0, -4.0)), 5.0);
        assert_eq!(horizontal_distance(&b, DVec2::new(5.0, 27.0)), 7.0);
    }

    #[test]
    fn leaves_within_the_radius() {
        let t = tree();
        assert_eq!(t.pyramid().depth, 2);
        // Inside leaf (1, 1) (640..1280), 100 m from its low-x edge and 200 m from its low-y edge.
        let ego = DVec3::new(740.0, 840.0, 1e6);
        // R smaller than a cell (10 m) and than the distance to any edge: only the leaf under
        // the ego, however high the ego is.
        let r = region(&t, ego, 1.0);
        assert_eq!(keys(&t, &r.leaves), vec![(1, 1)]);
        assert!(r.unresolved.is_empty() && !r.root_missing && r.missing_chunks.is_empty());
        // 100 m reaches the low-x edge exactly (inclusive): leaf (0, 1) joins.
        assert_eq!(keys(&t, &region(&t, ego, 100.0).leaves), vec![(0, 1), (1, 1)]);
        assert_eq!(keys(&t, &region(&t, ego, 99.999).leaves), vec![(1, 1)]);
        // 200 m also reaches the low-y edge, but the corner leaf (0, 0) is √(100² + 200²) away.
        assert_eq!(keys(&t, &region(&t, ego, 200.0).leaves), vec![(0, 1), (1, 0), (1, 1)]);
        assert_eq!(keys(&t, &region(&t, ego, 223.6).leaves), vec![(0, 1), (1, 0), (1, 1)]);
        assert_eq!(keys(&t, &region(&t, ego, 223.61).leaves), vec![(0, 0), (0, 1), (1, 0), (1, 1)]);
        // Only leaves are returned, every one within R and none missed (brute force).
        let r = region(&t, ego, 700.0);
        let brute: Vec<NodeId> = (0..t.len() as NodeId)
            .filter(|&n| {
                t.node(n).is_leaf() && horizontal_distance(&t.node(n).bounds, ego.truncate()) <= 700.0
            })
            .collect();
        assert_eq!(r.leaves, brute);
        assert_eq!(r.leaves.len(), 9, "{:?}", keys(&t, &r.leaves));
        assert_eq!(r.required(), 9);
    }

    #[test]
    fn shared_edges_and_corners_and_outside() {
        let t = tree();
        // On the edge x = 1280 between columns 1 and 2: both, even with a tiny radius.
        assert_eq!(keys(&t, &region(&t, DVec3::new(1280.0, 900.0, 0.0), 0.5).leaves), vec![(1, 1), (2, 1)]);
        // On a corner shared by four leaves: all four.
        assert_eq!(
            keys(&t, &region(&t, DVec3::new(1280.0, 1280.0, 0.0), 0.5).leaves),
            vec![(1, 1), (1, 2), (2, 1), (2, 2)]
        );
        // Outside the tileset, 50 m beyond x = 2560: nothing within 49 m, the edge column at 50.
        assert!(region(&t, DVec3::new(2610.0, 100.0, 0.0), 49.0).leaves.is_empty());
        assert_eq!(keys(&t, &region(&t, DVec3::new(2610.0, 100.0, 0.0), 50.0).leaves), vec![(3, 0)]);
    }

    #[test]
    fn unloaded_subtrees_are_unresolved_with_their_chunk() {
        let empty = TileTree::new(*tree().pyramid());
        let r = region(&empty, DVec3::ZERO, 10.0);
        assert!(r.root_missing && r.leaves.is_empty());
        assert_eq!(r.missing_chunks, vec![TileKey::new(0, 0, 0)]);
        assert_eq!(r.required(), 1);
        // Only the root and its children: the children are unresolved where within R.
        let full = tree();
        let mut part = TileTree::new(*full.pyramid());
        for n in full.nodes().iter().filter(|n| n.key.z <= 1) {
            part.insert_node(n.key, n.bounds, full.level_errors(full.find(n.key).unwrap())).unwrap();
        }
        let r = region(&part, DVec3::new(100.0, 100.0, 0.0), 10.0);
        assert!(r.leaves.is_empty() && !r.root_missing);
        assert_eq!(r.unresolved.len(), 1);
        assert_eq!(part.node(r.unresolved[0]).key, TileKey::new(1, 0, 0));
        assert_eq!(r.missing_chunks, vec![store::chunk_root(TileKey::new(2, 0, 0))]);
    }

    #[test]
    fn parameters_are_checked() {
        assert!(CollisionParams::new(50.0, 2.0).is_ok());
        assert!(CollisionParams::new(50.0, 0.0).is_ok());
        for r in [0.0, -1.0, f64::NAN, f64::INFINITY] {
            let e = CollisionParams::new(r, 2.0).unwrap_err().to_string();
            assert!(e.starts_with(&format!("collision region: radius {r} m")), "{e}");
        }
        let e = CollisionParams::new(1.0, -1.0).unwrap_err().to_string();
        assert!(e.starts_with("collision region: look-ahead -1 s"), "{e}");
    }
}
