//! The client's in-memory tile tree: one flat array of nodes (key, bounds, bounding sphere,
//! per-level geometric errors, parent and child links) built from a tileset's manifest and index
//! chunks, chunk by chunk as they arrive, or synthetically for tests and benchmarks.
//!
//! Selection walks this array every frame, so nodes are addressed by a `u32` [`NodeId`] and the
//! per-level errors live in one shared `Vec<f64>`; the `TileKey → NodeId` map is only used while
//! inserting.

use std::collections::HashMap;

use crate::client::ClientError;
use crate::geom::{Bounds, ErrorFigures};
use crate::store::{self, IndexChunk, Manifest, NodeEntry, NodeLevel, Store};
use crate::tiling::{Pyramid, TileKey};

/// Index of a node in [`TileTree::nodes`].
pub type NodeId = u32;
/// "No node" in a child slot or as the root's parent.
pub const NO_NODE: NodeId = NodeId::MAX;
/// Most levels a node may carry (residency is a `u32` bit mask per node).
pub const MAX_LEVELS: usize = 32;

/// One node of the tree.
#[derive(Debug, Clone, PartialEq)]
pub struct TreeNode {
    pub key: TileKey,
    /// The node's own geometry bounds (from the index).
    pub bounds: Bounds,
    /// `bounds` grown by every loaded descendant's, so culling a node culls its whole subtree
    /// (a parent's downsampled mesh can miss a child's peak).
    pub cull: Bounds,
    /// Bounding sphere of `bounds`: the centre is the paper's R in `e_scr = e_obj·k/|R − E|`.
    pub center: glam::DVec3,
    pub radius: f64,
    pub parent: NodeId,
    /// Child slots in (y, x) order: slot `2·dy + dx`; `NO_NODE` where absent or not loaded yet.
    pub children: [NodeId; 4],
    /// Bit `2·dy + dx` set for each child the quadtree has (loaded or not).
    pub expected: u8,
    level_start: u32,
    level_count: u8,
    /// Bit `l` set for each level `l` the node stores (a level that did not pay is absent).
    present: u32,
}

impl TreeNode {
    /// One more than the node's highest level id (0 = mesh, 1.. = coarser point levels); the
    /// node may skip ids below it ([`TreeNode::has_level`]).
    #[must_use]
    pub fn level_count(&self) -> usize {
        usize::from(self.level_count)
    }

    /// Bit `l` set for each level `l` the node stores.
    #[must_use]
    pub fn level_mask(&self) -> u32 {
        self.present
    }

    /// True when the node stores level `level`.
    #[must_use]
    pub fn has_level(&self, level: u8) -> bool {
        level < 32 && self.present & (1 << level) != 0
    }

    /// True when every child the quadtree has is loaded (a node without children counts).
    #[must_use]
    pub fn children_loaded(&self) -> bool {
        let present = (0..4).filter(|&s| self.children[s] != NO_NODE).fold(0u8, |m, s| m | (1 << s));
        present == self.expected
    }

    /// True when the quadtree has no children below this node.
    #[must_use]
    pub fn is_leaf(&self) -> bool {
        self.expected == 0
    }

    /// The loaded children.
    pub fn loaded_children(&self) -> impl Iterator<Item = NodeId> + '_ {
        self.children.iter().copied().filter(|&c| c != NO_NODE)
    }
}

/// The tile tree of one tileset.
#[derive(Debug, Clone)]
pub struct TileTree {
    pyramid: Pyramid,
    nodes: Vec<TreeNode>,
    /// Per node and level id: the geometric error (`f64::INFINITY` for a level the node does
    /// not store, so no threshold selects it) and the cost to draw (primitives, bytes).
    errors: Vec<f64>,
    costs: Vec<LevelCost>,
    index: HashMap<TileKey, NodeId>,
}

/// What drawing one level of a node costs: primitives (vertices or points), then bytes.
/// Ordered, so the selector takes the least one among the levels under the threshold.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord)]
pub struct LevelCost {
    pub primitives: u32,
    pub bytes: u64,
}

impl LevelCost {
    /// The cost of a level a node does not store.
    pub const ABSENT: Self = Self { primitives: u32::MAX, bytes: u64::MAX };
}

fn tree_err(msg: impl Into<String>) -> ClientError {
    ClientError::Tree(msg.into())
}

impl TileTree {
    /// An empty tree over `pyramid`; nodes are added with [`TileTree::insert`].
    #[must_use]
    pub fn new(pyramid: Pyramid) -> Self {
        Self { pyramid, nodes: Vec::new(), errors: Vec::new(), costs: Vec::new(), index: HashMap::new() }
    }

    /// An empty tree for the tileset the manifest describes (its quadtree shape only).
    pub fn for_manifest(m: &Manifest) -> Result<Self, ClientError> {
        let p = Pyramid::new(m.source.width, m.source.height, m.tile_size)
            .map_err(|e| tree_err(format!("manifest: {e}")))?;
        if p.depth != m.depth {
            return Err(tree_err(format!(
                "manifest: depth {} does not match a {}×{} raster with tile size {} (depth {})",
                m.depth, m.source.width, m.source.height, m.tile_size, p.depth
            )));
        }
        Ok(Self::new(p))
    }

    /// The whole tree of a tileset directory: the manifest and every index chunk.
    pub fn load(store: &Store) -> Result<Self, ClientError> {
        let m = store.manifest()?;
        let mut tree = Self::for_manifest(&m)?;
        let mut roots = vec![TileKey::new(0, 0, 0)];
        while let Some(root) = roots.pop() {
            let chunk = store.chunk(root)?;
            tree.insert_chunk(&chunk)?;
            roots.extend(tree.chunks_below(&chunk));
        }
        Ok(tree)
    }

    /// Roots of the index chunks directly below `chunk` (the children of its deepest nodes).
    #[must_use]
    pub fn chunks_below(&self, chunk: &IndexChunk) -> Vec<TileKey> {
        let last = chunk.root.z.saturating_add(store::SUBTREE_LEVELS - 1);
        chunk.nodes.iter().filter(|n| n.key.z == last).flat_map(|n| self.pyramid.children(n.key)).collect()
    }

    /// Adds every node of an index chunk (parents before children); nodes already present are
    /// checked to be identical and skipped, so a chunk may be delivered twice.
    pub fn insert_chunk(&mut self, chunk: &IndexChunk) -> Result<(), ClientError> {
        let mut nodes: Vec<&NodeEntry> = chunk.nodes.iter().collect();
        nodes.sort_by_key(|n| n.key);
        for n in nodes {
            if store::chunk_root(n.key) != chunk.root {
                return Err(tree_err(format!(
                    "index chunk {}: node {} belongs to another chunk",
                    chunk.root, n.key
                )));
            }
            self.insert(n)?;
        }
        Ok(())
    }

    /// Adds one node. Its parent must already be present (the root excepted).
    pub fn insert(&mut self, entry: &NodeEntry) -> Result<NodeId, ClientError> {
        // `f64::max` drops NaN, so check the raw fields before taking the geometric error.
        if let Some(e) = entry.levels.iter().find(|l| !l.errors.max.is_finite() || !l.errors.gap.is_finite())
        {
            return Err(tree_err(format!(
                "node {}: level {} errors (max {}, gap {}) are not finite",
                entry.key, e.level, e.errors.max, e.errors.gap
            )));
        }
        let levels: Vec<(u8, f64, LevelCost)> = entry
            .levels
            .iter()
            .map(|l: &NodeLevel| {
                (l.level, l.errors.geometric(), LevelCost { primitives: l.count, bytes: l.bytes })
            })
            .collect();
        self.insert_levels(entry.key, entry.bounds, &levels)
    }

    /// Adds one node from its key, bounds and per-level geometric errors (world units), every
    /// level present and each coarser level cheaper than the finer ones (synthetic trees).
    pub fn insert_node(
        &mut self,
        key: TileKey,
        bounds: Bounds,
        errors: &[f64],
    ) -> Result<NodeId, ClientError> {
        let levels: Vec<(u8, f64, LevelCost)> = errors
            .iter()
            .enumerate()
            .map(|(l, &e)| {
                let rank = u32::try_from(l).unwrap_or(u32::MAX);
                (
                    u8::try_from(l).unwrap_or(u8::MAX),
                    e,
                    LevelCost { primitives: u32::MAX - rank, bytes: u64::from(u32::MAX - rank) },
                )
            })
            .collect();
        self.insert_levels(key, bounds, &levels)
    }

    /// Adds one node from its key, bounds and stored levels: (level id, geometric error in
    /// world units, cost), ids increasing from 0 (the mesh).
    pub fn insert_levels(
        &mut self,
        key: TileKey,
        bounds: Bounds,
        levels: &[(u8, f64, LevelCost)],
    ) -> Result<NodeId, ClientError> {
        if !self.pyramid.contains(key) {
            return Err(tree_err(format!("node {key} is outside the tileset's quadtree")));
        }
        if !bounds.is_valid() {
            return Err(tree_err(format!(
                "node {key}: invalid bounds {:?} .. {:?}",
                bounds.min.to_array(),
                bounds.max.to_array()
            )));
        }
        let count = levels.last().map_or(0, |l| usize::from(l.0) + 1);
        if levels.is_empty() || count > MAX_LEVELS {
            return Err(tree_err(format!(
                "node {key}: {count} level ids (need 1 to {MAX_LEVELS}, level 0 the mesh)"
            )));
        }
        if levels[0].0 != 0 || levels.windows(2).any(|w| w[1].0 <= w[0].0) {
            let ids: Vec<u8> = levels.iter().map(|l| l.0).collect();
            return Err(tree_err(format!("node {key}: level ids {ids:?} must start at 0 and increase")));
        }
        if let Some((l, e, _)) = levels.iter().find(|(_, e, _)| !e.is_finite() || *e < 0.0) {
            return Err(tree_err(format!(
                "node {key}: level {l} error {e} is not a finite non-negative number"
            )));
        }
        let mut errors = vec![f64::INFINITY; count];
        let mut costs = vec![LevelCost::ABSENT; count];
        let mut present = 0u32;
        for &(l, e, c) in levels {
            errors[usize::from(l)] = e;
            costs[usize::from(l)] = c;
            present |= 1 << l;
        }
        let errors = &errors[..];
        if let Some(&id) = self.index.get(&key) {
            let n = &self.nodes[id as usize];
            if n.bounds == bounds && self.level_errors(id) == errors && n.present == present {
                return Ok(id);
            }
            return Err(tree_err(format!("node {key} delivered twice with different contents")));
        }
        let parent = if key.z == 0 {
            NO_NODE
        } else {
            let pk = TileKey::new(key.z - 1, key.x / 2, key.y / 2);
            *self
                .index
                .get(&pk)
                .ok_or_else(|| tree_err(format!("node {key} arrived before its parent {pk}")))?
        };
        let id = NodeId::try_from(self.nodes.len()).map_err(|_| tree_err("more than 2^32 nodes"))?;
        let mut expected = 0u8;
        for c in self.pyramid.children(key) {
            expected |= 1 << child_slot(c);
        }
        let center = bounds.center();
        let radius = 0.5 * bounds.size().length();
        let level_start =
            u32::try_from(self.errors.len()).map_err(|_| tree_err("more than 2^32 level entries"))?;
        self.errors.extend_from_slice(errors);
        self.costs.extend_from_slice(&costs);
        self.nodes.push(TreeNode {
            key,
            bounds,
            cull: bounds,
            center,
            radius,
            parent,
            children: [NO_NODE; 4],
            expected,
            level_start,
            level_count: errors.len() as u8,
            present,
        });
        self.index.insert(key, id);
        if parent != NO_NODE {
            self.nodes[parent as usize].children[child_slot(key)] = id;
            // Grow the ancestors' cull boxes until one already contains this node.
            let mut a = parent;
            while a != NO_NODE {
                let n = &mut self.nodes[a as usize];
                let before = n.cull;
                n.cull.extend(bounds.min);
                n.cull.extend(bounds.max);
                if n.cull == before {
                    break;
                }
                a = n.parent;
            }
        }
        Ok(id)
    }

    #[must_use]
    pub fn pyramid(&self) -> &Pyramid {
        &self.pyramid
    }

    #[must_use]
    pub fn len(&self) -> usize {
        self.nodes.len()
    }

    #[must_use]
    pub fn is_empty(&self) -> bool {
        self.nodes.is_empty()
    }

    /// The root, once loaded (it is always the first node inserted).
    #[must_use]
    pub fn root(&self) -> Option<NodeId> {
        self.index.get(&TileKey::new(0, 0, 0)).copied()
    }

    #[must_use]
    pub fn nodes(&self) -> &[TreeNode] {
        &self.nodes
    }

    #[must_use]
    pub fn node(&self, id: NodeId) -> &TreeNode {
        &self.nodes[id as usize]
    }

    #[must_use]
    pub fn find(&self, key: TileKey) -> Option<NodeId> {
        self.index.get(&key).copied()
    }

    /// The node's geometric error per level id (world units; `ErrorFigures::geometric`);
    /// `f64::INFINITY` for a level it does not store.
    #[must_use]
    pub fn level_errors(&self, id: NodeId) -> &[f64] {
        let n = &self.nodes[id as usize];
        let s = n.level_start as usize;
        &self.errors[s..s + n.level_count()]
    }

    /// The node's cost per level id ([`LevelCost::ABSENT`] for a level it does not store).
    #[must_use]
    pub fn level_costs(&self, id: NodeId) -> &[LevelCost] {
        let n = &self.nodes[id as usize];
        let s = n.level_start as usize;
        &self.costs[s..s + n.level_count()]
    }

    /// The bounds of the whole dataset (the root's cull box), if the root is loaded.
    #[must_use]
    pub fn bounds(&self) -> Option<Bounds> {
        self.root().map(|r| self.nodes[r as usize].cull)
    }

    /// True when `a` is `b` or one of its ancestors.
    #[must_use]
    pub fn is_ancestor_or_self(&self, a: NodeId, mut b: NodeId) -> bool {
        while b != NO_NODE {
            if a == b {
                return true;
            }
            b = self.nodes[b as usize].parent;
        }
        false
    }

    /// A synthetic tree for tests and benchmarks: the full quadtree of `spec`'s raster, with
    /// bounds from a smooth height function and errors that grow with the node's sample step and
    /// level the way a bake's measured errors do.
    pub fn synthetic(spec: &Synthetic) -> Result<Self, ClientError> {
        let p = Pyramid::new(spec.width, spec.height, spec.tile_size).map_err(|e| tree_err(e.to_string()))?;
        if spec.levels == 0 || spec.levels > MAX_LEVELS {
            return Err(tree_err(format!("synthetic: {} levels (need 1 to {MAX_LEVELS})", spec.levels)));
        }
        let mut tree = Self::new(p);
        let cell = spec.cell_size;
        let h = |x: f64, y: f64| {
            let (u, v) = (x / (cell * f64::from(spec.width)), y / (cell * f64::from(spec.height)));
            spec.relief
                * (0.5 + 0.3 * (u * 7.0 + spec.seed as f64).sin() * (v * 5.0).cos() + 0.2 * (u * 23.0).sin())
        };
        let mut errors = vec![0.0; spec.levels];
        for key in p.nodes() {
            let s = p.span(key);
            let (x0, x1) = (f64::from(s.col0) * cell, f64::from(s.col1) * cell);
            let (y0, y1) = (f64::from(s.row0) * cell, f64::from(s.row1) * cell);
            let mut zmin = f64::INFINITY;
            let mut zmax = f64::NEG_INFINITY;
            for i in 0..=4 {
                for j in 0..=4 {
                    let z = h(x0 + (x1 - x0) * f64::from(i) / 4.0, y0 + (y1 - y0) * f64::from(j) / 4.0);
                    zmin = zmin.min(z);
                    zmax = zmax.max(z);
                }
            }
            // Sampled extremes can miss the true ones: pad by the relief's finest-scale slack.
            let pad = 0.05 * spec.relief;
            let bounds = Bounds::new([x0, y0, zmin - pad], [x1, y1, zmax + pad]);
            let step = f64::from(p.step(key.z));
            for (l, e) in errors.iter_mut().enumerate() {
                *e = if l == 0 { spec.leaf_error * step } else { cell * step * f64::from(1u32 << l) * 0.5 };
            }
            tree.insert_node(key, bounds, &errors)?;
        }
        Ok(tree)
    }
}

/// Shape of a synthetic tree (see [`TileTree::synthetic`]).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Synthetic {
    /// Raster samples per side.
    pub width: u32,
    pub height: u32,
    pub tile_size: u32,
    /// Metres per cell.
    pub cell_size: f64,
    /// Height range of the terrain in metres.
    pub relief: f64,
    /// Levels per node (mesh + point levels).
    pub levels: usize,
    /// Level-0 error of a leaf in metres (parents scale it by their sample step).
    pub leaf_error: f64,
    pub seed: u64,
}

impl Synthetic {
    /// A tree with at least `min_nodes` nodes: square raster, 256-cell tiles, 30 m cells,
    /// 2500 m relief, 5 levels, 1 m leaf error — the shape of a `bake` of a large DEM.
    #[must_use]
    pub fn with_nodes(min_nodes: usize) -> Self {
        let mut leaves: u32 = 1;
        // Full quadtree of side s (a power of two or not) has about 4/3·s² nodes.
        while (u64::from(leaves) * u64::from(leaves) * 4 / 3) < min_nodes as u64 {
            leaves += 1;
        }
        Self {
            width: leaves * 256 + 1,
            height: leaves * 256 + 1,
            tile_size: 256,
            cell_size: 30.0,
            relief: 2500.0,
            levels: 5,
            leaf_error: 1.0,
            seed: 1,
        }
    }
}

/// The child slot (`2·dy + dx`) of `key` under its parent.
#[must_use]
pub fn child_slot(key: TileKey) -> usize {
    ((key.y & 1) * 2 + (key.x & 1)) as usize
}

/// A node entry for tests and tools that build trees by hand: level errors given as geometric
/// errors (`max`, no gap).
#[must_use]
pub fn entry(key: TileKey, bounds: Bounds, errors: &[f64]) -> NodeEntry {
    NodeEntry {
        key,
        bounds,
        levels: errors
            .iter()
            .enumerate()
            .map(|(l, &e)| NodeLevel {
                level: l as u8,
                errors: ErrorFigures { max: e, rms: e, gap: 0.0 },
                count: 0,
                triangles: 0,
                bytes: 0,
                checksum: 0,
            })
            .collect(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn small() -> TileTree {
        TileTree::synthetic(&Synthetic {
            width: 1000,
            height: 700,
            tile_size: 128,
            cell_size: 10.0,
            relief: 500.0,
            levels: 3,
            leaf_error: 0.5,
            seed: 3,
        })
        .unwrap()
    }

    #[test]
    fn synthetic_matches_pyramid_and_links() {
        let t = small();
        assert_eq!(t.len(), t.pyramid().nodes().len());
        let root = t.root().unwrap();
        assert_eq!(root, 0);
        for (i, n) in t.nodes().iter().enumerate() {
            assert!(n.children_loaded());
            assert_eq!(n.loaded_children().count(), t.pyramid().children(n.key).len());
            for c in n.loaded_children() {
                assert_eq!(t.node(c).parent, i as NodeId);
                // Cull boxes nest.
                let (a, b) = (&n.cull, &t.node(c).cull);
                assert!((0..3).all(|k| a.min[k] <= b.min[k] && a.max[k] >= b.max[k]));
            }
            assert_eq!(t.level_errors(i as NodeId).len(), 3);
        }
        let big = Synthetic::with_nodes(100_000);
        let p = Pyramid::new(big.width, big.height, big.tile_size).unwrap();
        assert!(p.nodes().len() >= 100_000);
    }

    #[test]
    fn insertion_rules() {
        let p = Pyramid::new(513, 513, 256).unwrap();
        let mut t = TileTree::new(p);
        let b = Bounds::new([0.0, 0.0, 0.0], [512.0, 512.0, 10.0]);
        let child = entry(TileKey::new(1, 1, 0), b, &[1.0]);
        assert!(t.insert(&child).unwrap_err().to_string().contains("before its parent 0/0/0"));
        t.insert(&entry(TileKey::new(0, 0, 0), b, &[2.0, 4.0])).unwrap();
        assert!(!t.node(0).children_loaded());
        // Same entry twice is fine, different contents are not.
        t.insert(&entry(TileKey::new(0, 0, 0), b, &[2.0, 4.0])).unwrap();
        assert!(t.insert(&entry(TileKey::new(0, 0, 0), b, &[3.0])).is_err());
        let high = Bounds::new([256.0, 0.0, 0.0], [512.0, 256.0, 50.0]);
        let id = t.insert(&entry(TileKey::new(1, 1, 0), high, &[1.0])).unwrap();
        assert_eq!(t.node(0).children[1], id);
        assert!((t.node(0).cull.max[2] - 50.0).abs() < 1e-12);
        assert!(
            t.insert(&entry(TileKey::new(1, 2, 0), b, &[1.0])).unwrap_err().to_string().contains("outside")
        );
        assert!(
            t.insert(&entry(TileKey::new(1, 0, 0), b, &[f64::NAN]))
                .unwrap_err()
                .to_string()
                .contains("level 0")
        );
        assert!(t.insert(&entry(TileKey::new(1, 0, 0), b, &[])).is_err());
        let bad = Bounds::new([1.0, 0.0, 0.0], [0.0, 1.0, 1.0]);
        assert!(
            t.insert(&entry(TileKey::new(1, 0, 0), bad, &[1.0])).unwrap_err().to_string().contains("bounds")
        );
    }
}
