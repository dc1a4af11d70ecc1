//! A packed tileset (`.tsa`, [`crate::store::archive`]): a local file or one object in a bucket
//! or on a web server, read by ranges, read-only. Its directory root is read when it is opened;
//! a file costs one page lookup (cached) and one range.

use std::path::Path;
use std::sync::Arc;

use super::{Backend, Location, bucket, is_remote};
use crate::store::StoreError;
use crate::store::archive::{Archive, ArchiveError};

/// An archive opened for reading.
#[derive(Debug, Clone)]
pub struct Packed {
    location: Location,
    archive: Arc<Archive>,
}

/// A failure reading `rel` from the archive at `location`, naming the archive and the file:
/// damage found in the archive (a checksum, an entry out of range) is [`StoreError::Corrupt`],
/// a file over its limit [`StoreError::TooLarge`]; only a failed read (local I/O, a remote
/// request) is an I/O or remote error, which may pass.
fn archive_err(location: &Location, rel: &str, e: ArchiveError) -> StoreError {
    let path = || std::path::PathBuf::from(format!("{location} ({rel})"));
    match e {
        e @ (ArchiveError::Corrupt(_) | ArchiveError::Format(_)) => {
            StoreError::Corrupt { path: path(), message: e.to_string() }
        }
        ArchiveError::TooLarge { len, limit, what, .. } => {
            StoreError::TooLarge { path: path(), size: Some(len), limit, what }
        }
        ArchiveError::Io(source) if location.as_url().is_none() => StoreError::Io { path: path(), source },
        e => StoreError::Remote { url: format!("{location} ({rel})"), message: e.to_string() },
    }
}

impl Packed {
    /// Opens the archive at `location` (a local path or a URL): its footer and directory root
    /// are read and checked now.
    pub fn open(location: &str) -> Result<Self, StoreError> {
        let refused = |message: String| StoreError::Remote { url: location.to_owned(), message };
        let (a, at) = if is_remote(location) {
            let r = bucket::Bucket::open(location)?;
            let len = r.size("")?.ok_or_else(|| refused("no such archive".into()))?;
            (Archive::open(Box::new(bucket::BucketSource::new(r)), len), Location::Url(location.to_owned()))
        } else {
            (Archive::open_file(Path::new(location)), Location::Path(location.into()))
        };
        // Not an archive (or a FIFO, a device) is damage, which reading again will not mend; a
        // failed read may pass.
        let archive = a.map_err(|e| match e {
            e @ ArchiveError::Format(_) => {
                StoreError::Corrupt { path: location.into(), message: e.to_string() }
            }
            e => refused(e.to_string()),
        })?;
        Ok(Self { location: at, archive: Arc::new(archive) })
    }

    /// The archive.
    #[must_use]
    pub fn archive(&self) -> &Archive {
        &self.archive
    }

    fn err(&self, rel: &str, e: ArchiveError) -> StoreError {
        archive_err(&self.location, rel, e)
    }

    /// Writes are refused: the tileset is read-only.
    fn read_only(&self) -> StoreError {
        StoreError::Invalid {
            path: self.location.as_path().to_owned(),
            message: "a packed tileset (.tsa) is read-only; bake into a directory or bucket prefix and pack it again".into(),
        }
    }
}

impl Backend for Packed {
    fn location(&self) -> &Location {
        &self.location
    }

    fn read(&self, rel: &str, limit: u64) -> Result<Option<Vec<u8>>, StoreError> {
        self.archive.read_within(rel, limit, crate::store::read_limit(rel).1).map_err(|e| self.err(rel, e))
    }

    fn size(&self, rel: &str) -> Result<Option<u64>, StoreError> {
        Ok(self.archive.entry(rel).map_err(|e| self.err(rel, e))?.map(|e| e.len))
    }

    fn exists(&self, rel: &str) -> Result<bool, StoreError> {
        self.archive.entry(rel).map(|e| e.is_some()).map_err(|e| self.err(rel, e))
    }

    fn list(&self) -> Result<Vec<(String, u64)>, StoreError> {
        Ok(self
            .archive
            .entries()
            .map_err(|e| self.err("", e))?
            .into_iter()
            .map(|e| (e.path, e.len))
            .collect())
    }

    fn write(&self, _: &str, _: &[u8]) -> Result<(), StoreError> {
        Err(self.read_only())
    }

    fn remove(&self, _: &str) -> Result<(), StoreError> {
        Err(self.read_only())
    }

    fn remove_folder(&self, _: &str) -> Result<(), StoreError> {
        Err(self.read_only())
    }

    fn check_writable(&self) -> Result<(), StoreError> {
        Err(self.read_only())
    }

    fn create_first(&self, _: &str, _: &[u8]) -> Result<bool, StoreError> {
        Err(self.read_only())
    }

    /// On tokio's blocking pool: a page read is one small range at most, a file one more.
    #[cfg(feature = "server")]
    fn read_async<'a>(
        &'a self,
        rel: &'a str,
        limit: u64,
    ) -> super::BoxFuture<'a, Result<Option<bytes::Bytes>, StoreError>> {
        let (a, at, rel2) = (self.archive.clone(), self.location.clone(), rel.to_owned());
        Box::pin(async move {
            tokio::task::spawn_blocking(move || {
                a.read_within(&rel2, limit, crate::store::read_limit(&rel2).1)
                    .map_err(|e| archive_err(&at, &rel2, e))
            })
            .await
            .map_err(|e| StoreError::Remote {
                url: self.location.join(rel).display().to_string(),
                message: e.to_string(),
            })?
            .map(|b| b.map(bytes::Bytes::from))
        })
    }

    /// On tokio's blocking pool: the root is in memory; a page read is one small range at most.
    #[cfg(feature = "server")]
    fn exists_async<'a>(&'a self, rel: &'a str) -> super::BoxFuture<'a, Result<bool, StoreError>> {
        let (a, rel2) = (self.archive.clone(), rel.to_owned());
        Box::pin(async move {
            tokio::task::spawn_blocking(move || a.entry(&rel2).map(|e| e.is_some()))
                .await
                .map_err(|e| StoreError::Remote {
                    url: self.location.join(rel).display().to_string(),
                    message: e.to_string(),
                })?
                .map_err(|e| self.err(rel, e))
        })
    }
}
