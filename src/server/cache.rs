//! Verified blobs kept in memory, bounded by bytes, evicted first-in first-out. Keys carry the
//! tileset's load generation, so a tileset that changes on disk (a new generation) never gets
//! an older generation's bytes; stale entries simply age out.

use std::collections::{HashMap, VecDeque};
use std::sync::Mutex;

use axum::http::HeaderValue;
use bytes::Bytes;

use crate::tiling::TileKey;

/// (tileset generation, tile, document): a blob's document is its level; the others are below.
pub type CacheKey = (u64, TileKey, u16);
/// The document of a cache key holding the index chunk rooted at the tile.
pub const INDEX_CHUNK: u16 = u16::MAX;
/// The document holding the 3D Tiles tileset JSON of the index chunk rooted at the tile.
pub const TILES3D_CHUNK: u16 = u16::MAX - 1;
/// The document of a tile level's GLB: this plus the level.
pub const GLB: u16 = 0x100;

/// A verified response body and its strong entity tag.
#[derive(Clone)]
pub struct Entry {
    pub bytes: Bytes,
    pub etag: HeaderValue,
}

pub struct BlobCache {
    limit: u64,
    inner: Mutex<Inner>,
}

#[derive(Default)]
struct Inner {
    map: HashMap<CacheKey, Entry>,
    order: VecDeque<CacheKey>,
    bytes: u64,
}

impl BlobCache {
    #[must_use]
    pub fn new(limit: u64) -> Self {
        Self { limit, inner: Mutex::new(Inner::default()) }
    }

    #[must_use]
    pub fn get(&self, key: &CacheKey) -> Option<Entry> {
        self.inner.lock().ok()?.map.get(key).cloned()
    }

    pub fn insert(&self, key: CacheKey, entry: Entry) {
        let size = entry.bytes.len() as u64;
        if size > self.limit / 4 {
            return;
        }
        let Ok(mut g) = self.inner.lock() else { return };
        if g.map.contains_key(&key) {
            return;
        }
        while g.bytes + size > self.limit {
            let Some(old) = g.order.pop_front() else { break };
            if let Some(e) = g.map.remove(&old) {
                g.bytes -= e.bytes.len() as u64;
            }
        }
        g.bytes += size;
        g.order.push_back(key);
        g.map.insert(key, entry);
    }

    /// Bytes held (for tests and metrics).
    #[must_use]
    pub fn bytes(&self) -> u64 {
        self.inner.lock().map_or(0, |g| g.bytes)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn evicts_oldest_within_the_limit() {
        let c = BlobCache::new(100);
        let e =
            |n: usize| Entry { bytes: Bytes::from(vec![0u8; n]), etag: HeaderValue::from_static("\"x\"") };
        for i in 0..10u32 {
            c.insert((1, TileKey::new(0, i, 0), 0), e(20));
            assert!(c.bytes() <= 100);
        }
        assert!(c.get(&(1, TileKey::new(0, 9, 0), 0)).is_some());
        assert!(c.get(&(1, TileKey::new(0, 0, 0), 0)).is_none());
        c.insert((1, TileKey::new(1, 0, 0), 0), e(90));
        assert!(c.get(&(1, TileKey::new(1, 0, 0), 0)).is_none(), "larger than a quarter of the cache");
    }
}
