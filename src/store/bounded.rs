//! Reading a stored file of bounded size: the one way every reader of the store (the server,
//! `inspect`, `export`, `pack`, sharded steps reading their plan) reads a local file.
//!
//! A file that is not a regular file (a FIFO, a device, a socket) is refused without being
//! opened: opening a FIFO blocks until a writer comes, and a device such as `/dev/zero` never
//! ends. Its size is checked against the limit before anything is read, and at most
//! `limit + 1` bytes are read whatever the size said (a file that grows, or one whose size
//! says nothing), so no stored file can make a reader allocate more than its limit.
//!
//! Between the `stat` and the `open` a file can be replaced (a FIFO moved into place): the
//! opened file is checked again, and such an `open` may still block. Callers that must not
//! block (the server) run reads off their async workers and never wait on one to stop.

use std::fs;
use std::io::Read;
use std::path::Path;

use super::StoreError;

pub use crate::raster::irregular_kind;

/// Checks that `path` (symbolic links followed) is a regular file of at most `limit` bytes
/// without opening it; returns its size, or `Ok(None)` when it does not exist.
pub fn check_regular(path: &Path, limit: u64, what: &'static str) -> Result<Option<u64>, StoreError> {
    let md = match fs::metadata(path) {
        Ok(md) => md,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(None),
        Err(e) => return Err(StoreError::Io { path: path.to_owned(), source: e }),
    };
    if let Some(kind) = irregular_kind(md.file_type()) {
        return Err(StoreError::NotRegular { path: path.to_owned(), kind });
    }
    if md.len() > limit {
        return Err(StoreError::TooLarge { path: path.to_owned(), size: Some(md.len()), limit, what });
    }
    Ok(Some(md.len()))
}

/// The bytes of the regular file `path` (a `what`: "blob", "JSON document", …) of at most
/// `limit` bytes; `Ok(None)` when it does not exist. Refuses a file that is not a regular file
/// ([`StoreError::NotRegular`], never opened) and one larger than `limit`
/// ([`StoreError::TooLarge`], checked before reading and while reading).
pub fn read_regular(path: &Path, limit: u64, what: &'static str) -> Result<Option<Vec<u8>>, StoreError> {
    let io = |source| StoreError::Io { path: path.to_owned(), source };
    let Some(size) = check_regular(path, limit, what)? else { return Ok(None) };
    let file = match fs::File::open(path) {
        Ok(f) => f,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(None),
        Err(e) => return Err(io(e)),
    };
    // Replaced between the check and the open.
    let md = file.metadata().map_err(io)?;
    if let Some(kind) = irregular_kind(md.file_type()) {
        return Err(StoreError::NotRegular { path: path.to_owned(), kind });
    }
    let mut bytes = Vec::with_capacity(usize::try_from(size.max(md.len()).min(limit)).unwrap_or(0));
    file.take(limit.saturating_add(1)).read_to_end(&mut bytes).map_err(io)?;
    if bytes.len() as u64 > limit {
        return Err(StoreError::TooLarge { path: path.to_owned(), size: None, limit, what });
    }
    Ok(Some(bytes))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn regular_files_within_the_limit_are_read_others_refused() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("a.json");
        fs::write(&p, b"{}").unwrap();
        assert_eq!(read_regular(&p, 2, "document").unwrap().unwrap(), b"{}");
        assert_eq!(read_regular(&dir.path().join("none"), 2, "document").unwrap(), None);
        let e = read_regular(&p, 1, "document").unwrap_err();
        assert!(matches!(e, StoreError::TooLarge { size: Some(2), limit: 1, .. }), "{e}");
        assert!(e.to_string().contains("is 2 bytes; a document is at most 1 bytes"), "{e}");
        let e = read_regular(dir.path(), 100, "document").unwrap_err();
        assert!(e.to_string().contains("is a directory, not a regular file"), "{e}");
    }

    /// `/dev/zero` reports 0 bytes and never ends: refused by its type, unread.
    #[test]
    fn devices_are_refused_without_reading() {
        let link = tempfile::tempdir().unwrap();
        let p = link.path().join("plan.json");
        std::os::unix::fs::symlink("/dev/zero", &p).unwrap();
        let e = read_regular(&p, 1 << 30, "document").unwrap_err();
        assert!(matches!(e, StoreError::NotRegular { kind: "a character device", .. }), "{e}");
    }

    /// A FIFO is refused without being opened (an open would wait for a writer forever).
    #[test]
    fn fifos_are_refused_without_opening() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("tileset.json");
        let ok = std::process::Command::new("mkfifo").arg(&p).status().is_ok_and(|s| s.success());
        if !ok {
            eprintln!("mkfifo is not available; skipped");
            return;
        }
        let e = read_regular(&p, 100, "document").unwrap_err();
        assert!(e.to_string().contains("is a FIFO (named pipe), not a regular file"), "{e}");
    }
}
