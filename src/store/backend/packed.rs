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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::store::archive::ArchiveWriter;

    /// An archive file holding `files`, and where each lies.
    fn packed(dir: &Path, files: &[(&str, &[u8])]) -> std::path::PathBuf {
        let mut w = ArchiveWriter::new(Vec::new()).unwrap();
        for (p, b) in files {
            w.add(p, b).unwrap();
        }
        let (bytes, _) = w.finish().unwrap();
        let p = dir.join("t.tsa");
        std::fs::write(&p, bytes).unwrap();
        p
    }

    /// Damage found in an archive that opened (a file's checksum, a directory page's checksum)
    /// is [`StoreError::Corrupt`], a file over the limit [`StoreError::TooLarge`]: both damage
    /// the server answers `500`, never the retryable I/O error.
    #[test]
    fn damage_in_an_archive_is_corrupt_and_limits_hold() {
        let dir = tempfile::tempdir().unwrap();
        let p = packed(dir.path(), &[("a.json", b"{\"x\": 1}"), ("b.tsb", &[7; 40])]);
        let s = Packed::open(p.to_str().unwrap()).unwrap();
        assert_eq!(s.read("a.json", 100).unwrap().unwrap(), b"{\"x\": 1}");
        let e = s.read("b.tsb", 39).unwrap_err();
        assert!(matches!(e, StoreError::TooLarge { size: Some(40), limit: 39, .. }), "{e}");
        assert!(e.to_string().contains("t.tsa (b.tsb)"), "{e}");

        // A payload byte: the file's checksum.
        let mut bytes = std::fs::read(&p).unwrap();
        let e = s.archive().entry("b.tsb").unwrap().unwrap();
        bytes[(e.offset + 3) as usize] ^= 1;
        // The directory page (read on the first lookup, after the root, which holds its CRC).
        let page_at = (e.offset + e.len) as usize;
        let mut page_damaged = std::fs::read(&p).unwrap();
        page_damaged[page_at + 4] ^= 1;
        std::fs::write(&p, &bytes).unwrap();
        let s = Packed::open(p.to_str().unwrap()).unwrap();
        let e = s.read("b.tsb", 100).unwrap_err();
        assert!(matches!(e, StoreError::Corrupt { .. }) && e.is_damaged(), "{e}");
        assert!(e.to_string().contains("b.tsb") && e.to_string().contains("checksum"), "{e}");
        std::fs::write(&p, &page_damaged).unwrap();
        let s = Packed::open(p.to_str().unwrap()).unwrap();
        let e = s.read("a.json", 100).unwrap_err();
        assert!(matches!(e, StoreError::Corrupt { .. }), "{e}");
        assert!(e.to_string().contains("directory page 0"), "{e}");
        let e = s.exists("a.json").unwrap_err();
        assert!(e.is_damaged(), "{e}");
    }

    /// A FIFO named like an archive is refused by its type, without being opened (an open
    /// would wait for a writer forever), as damage.
    #[test]
    fn a_fifo_is_not_opened_as_an_archive() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("pipe.tsa");
        if !std::process::Command::new("mkfifo").arg(&p).status().is_ok_and(|s| s.success()) {
            eprintln!("mkfifo is not available; skipped");
            return;
        }
        let e = Packed::open(p.to_str().unwrap()).unwrap_err();
        assert!(e.is_damaged() && e.to_string().contains("FIFO"), "{e}");
    }
}
