//! The open input files of every dataset of the process, bounded: a dataset of thousands of
//! GeoTIFFs (or a VRT of as many sources) must not hold a descriptor per file, or it fails with
//! "Too many open files" under the usual limit of 1,024 (issue 40, N5).
//!
//! Block sources take a handle (an open TIFF decoder, or a plain file) from the pool when they
//! read a block and give it back after; a source with none idle opens its file again. The pool
//! keeps at most [`cap`] idle handles, closing the least recently used first. Handles in use
//! are one per reading thread, so the process holds at most the cap plus the threads.

use std::collections::{BTreeMap, HashMap};
use std::fs::File;
use std::io::BufReader;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{LazyLock, Mutex, PoisonError};

use tiff::decoder::Decoder;

/// Most idle handles kept open, whatever the descriptor limit.
pub const MAX_IDLE_HANDLES: usize = 256;
/// Fewest idle handles kept open (below that, every block read would open its file).
pub const MIN_IDLE_HANDLES: usize = 4;

/// An open input file, ready to read blocks.
pub(super) enum Handle {
    Tiff(Box<Decoder<BufReader<File>>>),
    File(File),
}

/// The soft limit on open descriptors (`RLIMIT_NOFILE`), where the system says (Linux's
/// `/proc/self/limits`); `None` elsewhere or when it is unlimited.
fn soft_descriptor_limit() -> Option<u64> {
    let text = std::fs::read_to_string("/proc/self/limits").ok()?;
    let line = text.lines().find(|l| l.starts_with("Max open files"))?;
    line.trim_start_matches("Max open files").split_whitespace().next()?.parse().ok()
}

/// Idle handles the pool keeps: a quarter of the soft descriptor limit (the rest is for the
/// store's writes, the threads' handles in use and everything else), within
/// [`MIN_IDLE_HANDLES`]..=[`MAX_IDLE_HANDLES`].
fn cap_for(limit: Option<u64>) -> usize {
    limit
        .map_or(MAX_IDLE_HANDLES, |l| usize::try_from(l / 4).unwrap_or(usize::MAX))
        .clamp(MIN_IDLE_HANDLES, MAX_IDLE_HANDLES)
}

pub(super) static POOL: LazyLock<FilePool> =
    LazyLock::new(|| FilePool::new(cap_for(soft_descriptor_limit())));

static NEXT_OWNER: AtomicU64 = AtomicU64::new(1);

/// A new owner id: one per block source (each of its handles reads the same file).
pub(super) fn new_owner() -> u64 {
    NEXT_OWNER.fetch_add(1, Ordering::Relaxed)
}

/// Idle handles by owner, in least-recently-used order.
pub(super) struct FilePool {
    cap: usize,
    inner: Mutex<Inner>,
}

#[derive(Default)]
struct Inner {
    tick: u64,
    /// Per owner: its idle handles with the tick they were given back at, oldest first.
    idle: HashMap<u64, Vec<(u64, Handle)>>,
    /// Every idle handle's tick → its owner.
    order: BTreeMap<u64, u64>,
}

impl FilePool {
    fn new(cap: usize) -> Self {
        Self { cap, inner: Mutex::new(Inner::default()) }
    }

    fn lock(&self) -> std::sync::MutexGuard<'_, Inner> {
        self.inner.lock().unwrap_or_else(PoisonError::into_inner)
    }

    /// An idle handle of `owner` (the one used last), if any.
    pub(super) fn take(&self, owner: u64) -> Option<Handle> {
        let mut g = self.lock();
        let list = g.idle.get_mut(&owner)?;
        let (tick, handle) = list.pop()?;
        if list.is_empty() {
            g.idle.remove(&owner);
        }
        g.order.remove(&tick);
        Some(handle)
    }

    /// Gives `handle` back; the least recently used idle handles beyond the cap are closed
    /// (after the lock is released).
    pub(super) fn give(&self, owner: u64, handle: Handle) {
        let mut closed = Vec::new();
        {
            let mut g = self.lock();
            g.tick += 1;
            let tick = g.tick;
            g.idle.entry(owner).or_default().push((tick, handle));
            g.order.insert(tick, owner);
            while g.order.len() > self.cap {
                let Some((_, o)) = g.order.pop_first() else { break };
                if let Some(list) = g.idle.get_mut(&o) {
                    // An owner's list is in tick order: its first is the oldest.
                    if !list.is_empty() {
                        closed.push(list.remove(0).1);
                    }
                    if list.is_empty() {
                        g.idle.remove(&o);
                    }
                }
            }
        }
        drop(closed);
    }

    /// Closes every idle handle of `owner` (a source dropped).
    pub(super) fn forget(&self, owner: u64) {
        let list = {
            let mut g = self.lock();
            let list = g.idle.remove(&owner).unwrap_or_default();
            for (tick, _) in &list {
                g.order.remove(tick);
            }
            list
        };
        drop(list);
    }

    /// Idle handles held now.
    #[cfg(test)]
    fn idle(&self) -> usize {
        self.lock().order.len()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn file() -> Handle {
        Handle::File(tempfile::tempfile().unwrap())
    }

    #[test]
    fn the_pool_keeps_at_most_its_cap_and_closes_the_least_recently_used() {
        let pool = FilePool::new(3);
        for owner in 1..=5 {
            pool.give(owner, file());
        }
        assert_eq!(pool.idle(), 3);
        // Owners 1 and 2 were given back first: closed.
        assert!(pool.take(1).is_none() && pool.take(2).is_none());
        assert!(pool.take(3).is_some());
        assert_eq!(pool.idle(), 2);
        pool.give(4, file());
        pool.give(6, file());
        assert_eq!(pool.idle(), 3);
        // 4's older handle went first; its newer one stays.
        assert!(pool.take(4).is_some());
        assert!(pool.take(4).is_none());
        pool.forget(5);
        pool.forget(6);
        assert_eq!(pool.idle(), 0);
    }

    #[test]
    fn the_cap_follows_the_descriptor_limit() {
        assert_eq!(cap_for(Some(64)), 16);
        assert_eq!(cap_for(Some(8)), MIN_IDLE_HANDLES);
        assert_eq!(cap_for(Some(1 << 20)), MAX_IDLE_HANDLES);
        assert_eq!(cap_for(None), MAX_IDLE_HANDLES);
        if std::path::Path::new("/proc/self/limits").exists() {
            assert!(
                soft_descriptor_limit().is_some()
                    || std::fs::read_to_string("/proc/self/limits").unwrap().contains("unlimited")
            );
        }
    }
}
