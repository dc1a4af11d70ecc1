//! Where a tileset's files live: one [`Backend`] trait and one file per backend, as pmtiles-rs
//! (`AsyncBackend`, `backends/`) and versatiles (`DataReaderTrait`, `DataLocation`) do it.
//!
//! - [`local::LocalDir`]: a local directory (the default and the fast path): every write goes to
//!   a temporary name and is renamed into place;
//! - [`bucket::Bucket`]: a prefix in object storage (`s3://`, `gs://`, `az://`) through the
//!   `object_store` crate; a PUT is atomic. The same client reads single objects by range (an
//!   archive in a bucket or on any web server, `http(s)://`), which is how [`packed::Packed`]
//!   reads a remote archive; there is no separate HTTP backend;
//! - [`packed::Packed`]: a packed tileset (`.tsa`, local or remote), read-only; the archive
//!   format itself is [`super::archive`].
//!
//! A backend knows files by their path relative to the tileset (`tiles/0/0/0/0.tsb`); what the
//! files are, and in which order a bake writes them, is the tileset layout of [`super`]. Paths
//! in messages are the [`Location`] joined with the relative path, as they always read.

pub mod local;
pub mod packed;

#[cfg(feature = "s3")]
pub mod bucket;
#[cfg(not(feature = "s3"))]
#[path = "no_bucket.rs"]
pub mod bucket;

use std::path::{Path, PathBuf};

use super::StoreError;

/// Where a tileset (or a packed one) is: a local path or a URL.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Location {
    /// A local folder or archive file.
    Path(PathBuf),
    /// A bucket prefix (`s3://BUCKET/PREFIX`, without a trailing slash) or a remote archive
    /// (`s3://BUCKET/KEY.tsa`, `https://HOST/PATH.tsa`).
    Url(String),
}

impl Location {
    /// The location as a path, for messages and for the path-valued accessors of
    /// [`super::Store`] (a URL reads as itself).
    #[must_use]
    pub fn as_path(&self) -> &Path {
        match self {
            Self::Path(p) => p,
            Self::Url(u) => Path::new(u.as_str()),
        }
    }

    /// The URL, when the location is one.
    #[must_use]
    pub fn as_url(&self) -> Option<&str> {
        match self {
            Self::Path(_) => None,
            Self::Url(u) => Some(u),
        }
    }

    /// A file of the tileset by its relative path, as messages name it.
    #[must_use]
    pub fn join(&self, rel: &str) -> PathBuf {
        self.as_path().join(rel)
    }
}

impl std::fmt::Display for Location {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        self.as_path().display().fmt(f)
    }
}

/// Whether `location` names object storage or a web server (a URL with a scheme other than
/// `file://`).
#[must_use]
pub fn is_remote(location: &str) -> bool {
    location.contains("://") && !location.starts_with("file://")
}

/// Which temporary files [`Backend::remove_temps`] looks at: backends whose writes leave none
/// (a PUT is atomic; an archive is read-only) have nothing to remove.
#[derive(Debug, Clone, Copy)]
pub enum Sweep<'a> {
    /// The files at the top of the tileset, and those in the top folders named `folders` and
    /// their folders down to `depth` levels below the top.
    Tree { folders: &'a [&'a str], depth: u32 },
    /// The files directly in each of these folders (relative paths).
    Folders(&'a [String]),
}

/// A boxed future, for the server's reads (a trait object cannot have `async fn`s).
#[cfg(feature = "server")]
pub type BoxFuture<'a, T> = std::pin::Pin<Box<dyn std::future::Future<Output = T> + Send + 'a>>;

/// The operations a tileset needs of the place its files are kept. Paths are relative to the
/// tileset and `/`-separated. Every error is a [`StoreError`] naming the file (its
/// [`Location::join`]) or the URL.
pub trait Backend: std::fmt::Debug + Send + Sync + std::any::Any {
    /// Where the tileset is.
    fn location(&self) -> &Location;

    /// The file's bytes; `Ok(None)` when it does not exist. A file larger than `limit` is
    /// [`StoreError::TooLarge`] (checked before reading where the size is known, and never more
    /// than `limit + 1` bytes read), a local one that is not a regular file
    /// [`StoreError::NotRegular`] (never opened).
    fn read(&self, rel: &str, limit: u64) -> Result<Option<Vec<u8>>, StoreError>;

    /// The file's size, without reading it; `Ok(None)` when it does not exist.
    fn size(&self, rel: &str) -> Result<Option<u64>, StoreError>;

    /// Whether the file exists.
    fn exists(&self, rel: &str) -> Result<bool, StoreError>;

    /// Every file of the tileset with its size, in no particular order. A read-only or remote
    /// backend lists what it holds; a directory refuses a tree nested deeper than a tileset can
    /// be.
    fn list(&self) -> Result<Vec<(String, u64)>, StoreError>;

    /// Writes the file whole and atomically: a reader sees the old file or the complete new one.
    /// A read-only backend refuses.
    fn write(&self, rel: &str, bytes: &[u8]) -> Result<(), StoreError>;

    /// Removes the file; nothing when it does not exist. A read-only backend refuses.
    fn remove(&self, rel: &str) -> Result<(), StoreError>;

    /// Removes a folder and everything in it; nothing when it does not exist.
    fn remove_folder(&self, rel: &str) -> Result<(), StoreError>;

    /// Checks, before anything is read or written, that a tileset can be written here: a
    /// directory path that cannot become a folder (a file, a path under a file, a dangling
    /// symbolic link) is refused by name, an archive as read-only.
    fn check_writable(&self) -> Result<(), StoreError>;

    /// Begins a new tileset with its first file: refuses a location that already holds anything
    /// else ([`StoreError::NotATileset`]), then creates `rel` with `bytes` unless it exists.
    /// Returns false when another writer created `rel` between the check and the write (where
    /// the backend can tell: a conditional create in a bucket); the caller then reads it.
    fn create_first(&self, rel: &str, bytes: &[u8]) -> Result<bool, StoreError>;

    /// Removes the temporary files of interrupted writes in `sweep`: those of processes that no
    /// longer run, or with `every` all of them. Returns how many were removed.
    fn remove_temps(&self, sweep: Sweep<'_>, every: bool) -> Result<u64, StoreError> {
        let _ = (sweep, every);
        Ok(0)
    }

    /// [`Backend::read`] for the server, without blocking its runtime (local files are read
    /// on tokio's blocking pool).
    #[cfg(feature = "server")]
    fn read_async<'a>(
        &'a self,
        rel: &'a str,
        limit: u64,
    ) -> BoxFuture<'a, Result<Option<bytes::Bytes>, StoreError>>;

    /// [`Backend::exists`] for the server, without blocking its runtime.
    #[cfg(feature = "server")]
    fn exists_async<'a>(&'a self, rel: &'a str) -> BoxFuture<'a, Result<bool, StoreError>>;
}
