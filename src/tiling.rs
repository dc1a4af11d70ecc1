//! Tile keys and the quadtree over a raster: which full-resolution samples each node covers, at
//! which step, and which edge samples it shares with its neighbours. Pure: no I/O.

use serde::{Deserialize, Serialize};

/// A quadtree node: `z = 0` is the root; the deepest `z` holds full-resolution leaf tiles.
#[derive(
    Debug,
    Clone,
    Copy,
    PartialEq,
    Eq,
    Hash,
    PartialOrd,
    Ord,
    Serialize,
    Deserialize,
    bincode::Encode,
    bincode::Decode,
)]
pub struct TileKey {
    pub z: u8,
    pub x: u32,
    pub y: u32,
}

/// The Morton (Z-order) code of `x` and `y`: nearby positions get nearby codes.
#[must_use]
pub fn morton(x: u32, y: u32) -> u64 {
    let spread = |v: u32| {
        let mut v = u64::from(v);
        v = (v | (v << 16)) & 0x0000_ffff_0000_ffff;
        v = (v | (v << 8)) & 0x00ff_00ff_00ff_00ff;
        v = (v | (v << 4)) & 0x0f0f_0f0f_0f0f_0f0f;
        v = (v | (v << 2)) & 0x3333_3333_3333_3333;
        (v | (v << 1)) & 0x5555_5555_5555_5555
    };
    spread(x) | (spread(y) << 1)
}

impl TileKey {
    #[must_use]
    pub const fn new(z: u8, x: u32, y: u32) -> Self {
        Self { z, x, y }
    }
}

impl std::fmt::Display for TileKey {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "{}/{}/{}", self.z, self.x, self.y)
    }
}

/// Default leaf tile size in raster cells (so 257 samples per side with shared borders).
pub const DEFAULT_TILE_SIZE: u32 = 256;

#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum TilingError {
    #[error("raster of {width}×{height} samples is too small to tile: need at least 2×2")]
    TooSmall { width: u32, height: u32 },
    #[error("tile size {0} is out of range: use 1 to 65536 cells")]
    BadTileSize(u32),
    #[error(
        "raster of {width}×{height} samples with tile size {tile_size} needs a quadtree deeper than 24 levels"
    )]
    TooDeep { width: u32, height: u32, tile_size: u32 },
}

/// The quadtree over a `width × height` sample raster with leaf tiles of `tile_size` cells.
///
/// A node at depth `z` samples the raster every `step(z) = 2^(depth − z)` samples, so every node
/// has at most `tile_size + 1` samples per side whatever its depth. Nodes on the raster's right
/// or bottom edge are clipped to the raster: their last sample column/row is the raster's last,
/// even when that breaks the regular step, so no terrain is invented and none is dropped.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub struct Pyramid {
    pub width: u32,
    pub height: u32,
    pub tile_size: u32,
    pub depth: u8,
}

/// The full-resolution sample columns and rows a node reads, in increasing order.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct NodeGrid {
    pub cols: Vec<u32>,
    pub rows: Vec<u32>,
}

/// Inclusive full-resolution sample range a node covers.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Span {
    pub col0: u32,
    pub col1: u32,
    pub row0: u32,
    pub row1: u32,
}

impl Span {
    #[must_use]
    pub fn cols(&self) -> u32 {
        self.col1 - self.col0 + 1
    }
    #[must_use]
    pub fn rows(&self) -> u32 {
        self.row1 - self.row0 + 1
    }
}

impl Pyramid {
    pub fn new(width: u32, height: u32, tile_size: u32) -> Result<Self, TilingError> {
        if width < 2 || height < 2 {
            return Err(TilingError::TooSmall { width, height });
        }
        if tile_size == 0 || tile_size > 65_536 {
            return Err(TilingError::BadTileSize(tile_size));
        }
        let leaves = u64::from((width - 1).div_ceil(tile_size).max((height - 1).div_ceil(tile_size)));
        let depth = 64 - (leaves - 1).leading_zeros();
        if depth > 24 {
            return Err(TilingError::TooDeep { width, height, tile_size });
        }
        Ok(Self { width, height, tile_size, depth: depth as u8 })
    }

    /// Sample step of nodes at depth `z` (1 for leaves).
    #[must_use]
    pub fn step(&self, z: u8) -> u32 {
        1 << (self.depth - z.min(self.depth))
    }

    /// Cells (full resolution) covered by one node side at depth `z`.
    fn node_cells(&self, z: u8) -> u64 {
        u64::from(self.tile_size) << (self.depth - z.min(self.depth))
    }

    /// Number of nodes (columns, rows) at depth `z` that intersect the raster.
    #[must_use]
    pub fn nodes_at(&self, z: u8) -> (u32, u32) {
        let n = self.node_cells(z);
        (u64::from(self.width - 1).div_ceil(n) as u32, u64::from(self.height - 1).div_ceil(n) as u32)
    }

    #[must_use]
    pub fn contains(&self, key: TileKey) -> bool {
        let (nx, ny) = self.nodes_at(key.z);
        key.z <= self.depth && key.x < nx && key.y < ny
    }

    /// The full-resolution samples a node covers (its borders included).
    #[must_use]
    pub fn span(&self, key: TileKey) -> Span {
        let n = self.node_cells(key.z);
        let col0 = u64::from(key.x) * n;
        let row0 = u64::from(key.y) * n;
        Span {
            col0: col0 as u32,
            row0: row0 as u32,
            col1: (col0 + n).min(u64::from(self.width - 1)) as u32,
            row1: (row0 + n).min(u64::from(self.height - 1)) as u32,
        }
    }

    /// The (possibly downsampled) sample grid a node's TIN is built on.
    #[must_use]
    pub fn grid(&self, key: TileKey) -> NodeGrid {
        let span = self.span(key);
        let step = self.step(key.z);
        NodeGrid { cols: axis(span.col0, span.col1, step), rows: axis(span.row0, span.row1, step) }
    }

    /// The existing children of a node (up to four), in (y, x) order.
    #[must_use]
    pub fn children(&self, key: TileKey) -> Vec<TileKey> {
        if key.z >= self.depth {
            return Vec::new();
        }
        let mut out = Vec::with_capacity(4);
        for dy in 0..2 {
            for dx in 0..2 {
                let c = TileKey::new(key.z + 1, key.x * 2 + dx, key.y * 2 + dy);
                if self.contains(c) {
                    out.push(c);
                }
            }
        }
        out
    }

    /// Every node, root first, then depth by depth in (y, x) order.
    #[must_use]
    pub fn nodes(&self) -> Vec<TileKey> {
        let mut out = Vec::new();
        for z in 0..=self.depth {
            let (nx, ny) = self.nodes_at(z);
            for y in 0..ny {
                for x in 0..nx {
                    out.push(TileKey::new(z, x, y));
                }
            }
        }
        out
    }
}

/// `start, start+step, …` up to `end`, with `end` itself always last.
fn axis(start: u32, end: u32, step: u32) -> Vec<u32> {
    let mut v: Vec<u32> = (start..end).step_by(step as usize).collect();
    v.push(end);
    v
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn depth_and_counts() {
        let p = Pyramid::new(4097, 4097, 256).unwrap();
        assert_eq!(p.depth, 4);
        assert_eq!(p.nodes_at(4), (16, 16));
        assert_eq!(p.nodes_at(0), (1, 1));
        assert_eq!(p.nodes().len(), 1 + 4 + 16 + 64 + 256);
        let p = Pyramid::new(257, 257, 256).unwrap();
        assert_eq!(p.depth, 0);
        assert_eq!(p.grid(TileKey::new(0, 0, 0)).cols.len(), 257);
    }

    #[test]
    fn odd_sizes_are_clipped_not_padded() {
        let p = Pyramid::new(512, 300, 256).unwrap();
        assert_eq!(p.depth, 1);
        assert_eq!(p.nodes_at(1), (2, 2));
        let s = p.span(TileKey::new(1, 1, 1));
        assert_eq!((s.col0, s.col1, s.row0, s.row1), (256, 511, 256, 299));
        let root = p.grid(TileKey::new(0, 0, 0));
        assert_eq!(root.cols.first(), Some(&0));
        assert_eq!(root.cols.last(), Some(&511));
        assert_eq!(root.rows.last(), Some(&299));
        assert!(root.cols.windows(2).all(|w| w[1] > w[0] && w[1] - w[0] <= 2));
    }

    #[test]
    fn neighbours_share_edge_samples() {
        let p = Pyramid::new(1000, 700, 128).unwrap();
        for z in 0..=p.depth {
            let (nx, ny) = p.nodes_at(z);
            for y in 0..ny {
                for x in 0..nx.saturating_sub(1) {
                    let a = p.grid(TileKey::new(z, x, y));
                    let b = p.grid(TileKey::new(z, x + 1, y));
                    assert_eq!(a.cols.last(), b.cols.first());
                    assert_eq!(a.rows, b.rows);
                }
            }
        }
    }

    #[test]
    fn children_cover_parent() {
        let p = Pyramid::new(1000, 700, 128).unwrap();
        for key in p.nodes() {
            let s = p.span(key);
            let kids = p.children(key);
            if key.z < p.depth {
                assert!(!kids.is_empty());
                assert_eq!(kids.iter().map(|k| p.span(*k).col1).max(), Some(s.col1));
                assert_eq!(kids.iter().map(|k| p.span(*k).row1).max(), Some(s.row1));
            }
        }
    }

    #[test]
    fn rejects_bad_input() {
        assert!(Pyramid::new(1, 100, 256).is_err());
        assert!(Pyramid::new(100, 100, 0).is_err());
        assert!(Pyramid::new(u32::MAX, u32::MAX, 1).is_err());
    }
}
