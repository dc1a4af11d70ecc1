//! A tileset in a local directory: files read whole, written to a temporary name in the same
//! folder, synced and renamed into place ([`write_atomic`]), so a reader (or a resumed bake)
//! sees either the old file or the complete new one, never a torn one. The temporary files of a
//! writer killed mid-write (`.NAME.PID.N.tmp`) are removed on resume.

use std::fs;
use std::io::Write;
use std::path::{Path, PathBuf};

use super::{Backend, Location, Sweep};
use crate::store::bounded::read_regular;
use crate::store::{StoreError, read_limit};

/// Folders below a tileset's top a listing follows at most (a tileset is 6 deep).
const MAX_LIST_DEPTH: u32 = 16;

pub(crate) fn io(path: &Path) -> impl FnOnce(std::io::Error) -> StoreError + '_ {
    move |source| StoreError::Io { path: path.to_owned(), source }
}

/// A tileset directory (nothing is created until the first write).
#[derive(Debug, Clone)]
pub struct LocalDir {
    location: Location,
}

impl LocalDir {
    #[must_use]
    pub fn new(dir: &Path) -> Self {
        Self { location: Location::Path(dir.to_owned()) }
    }

    /// The directory.
    #[must_use]
    pub fn dir(&self) -> &Path {
        self.location.as_path()
    }
}

impl Backend for LocalDir {
    fn location(&self) -> &Location {
        &self.location
    }

    fn read(&self, rel: &str, limit: u64) -> Result<Option<Vec<u8>>, StoreError> {
        read_regular(&self.dir().join(rel), limit, read_limit(rel).1)
    }

    fn size(&self, rel: &str) -> Result<Option<u64>, StoreError> {
        let path = self.dir().join(rel);
        match fs::metadata(&path) {
            Ok(m) => Ok(Some(m.len())),
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => Ok(None),
            Err(e) => Err(io(&path)(e)),
        }
    }

    fn exists(&self, rel: &str) -> Result<bool, StoreError> {
        Ok(self.dir().join(rel).is_file())
    }

    fn list(&self) -> Result<Vec<(String, u64)>, StoreError> {
        let mut out = Vec::new();
        let mut stack = vec![(self.dir().to_owned(), String::new(), 0u32)];
        while let Some((dir, rel, depth)) = stack.pop() {
            if depth > MAX_LIST_DEPTH {
                return Err(StoreError::Invalid { path: dir, message: "folders nested too deep".into() });
            }
            for entry in fs::read_dir(&dir).map_err(io(&dir))? {
                let entry = entry.map_err(io(&dir))?;
                let name = entry.file_name().to_string_lossy().into_owned();
                let child = if rel.is_empty() { name.clone() } else { format!("{rel}/{name}") };
                // Symbolic links followed (a `tiles/` linked to another disk is the tileset's),
                // and a file that is not a regular file refused by name: left out, it would be
                // missing from a pack that says it packed the tileset.
                let path = entry.path();
                let md = fs::metadata(&path).map_err(io(&path))?;
                if md.is_dir() {
                    stack.push((path, child, depth + 1));
                } else if let Some(kind) = crate::store::bounded::irregular_kind(md.file_type()) {
                    return Err(StoreError::NotRegular { path, kind });
                } else {
                    out.push((child, md.len()));
                }
            }
        }
        Ok(out)
    }

    fn write(&self, rel: &str, bytes: &[u8]) -> Result<(), StoreError> {
        write_atomic(&self.dir().join(rel), bytes)
    }

    fn remove(&self, rel: &str) -> Result<(), StoreError> {
        let path = self.dir().join(rel);
        match fs::remove_file(&path) {
            Err(e) if e.kind() != std::io::ErrorKind::NotFound => Err(io(&path)(e)),
            _ => Ok(()),
        }
    }

    fn remove_folder(&self, rel: &str) -> Result<(), StoreError> {
        let path = self.dir().join(rel);
        match fs::remove_dir_all(&path) {
            Err(e) if e.kind() != std::io::ErrorKind::NotFound => Err(io(&path)(e)),
            _ => Ok(()),
        }
    }

    fn check_writable(&self) -> Result<(), StoreError> {
        check_out_dir(self.dir())
    }

    fn create_first(&self, rel: &str, bytes: &[u8]) -> Result<bool, StoreError> {
        let dir = self.dir();
        check_out_dir(dir)?;
        if dir.exists() {
            for entry in fs::read_dir(dir).map_err(io(dir))? {
                let entry = entry.map_err(io(dir))?;
                let name = entry.file_name();
                // A bake killed before its first file was first written leaves only that
                // file's temporary file: the directory is still an empty one of ours, not a
                // foreign one.
                if entry.file_type().map_err(io(&entry.path()))?.is_file()
                    && name.to_string_lossy().starts_with(&format!(".{rel}."))
                    && stale_temp(&name.to_string_lossy())
                {
                    fs::remove_file(entry.path()).map_err(io(&entry.path()))?;
                    continue;
                }
                return Err(StoreError::NotATileset { path: dir.to_owned() });
            }
        }
        fs::create_dir_all(dir).map_err(io(dir))?;
        write_atomic(&dir.join(rel), bytes)?;
        Ok(true)
    }

    fn remove_temps(&self, sweep: Sweep<'_>, every: bool) -> Result<u64, StoreError> {
        let mut removed = 0u64;
        let mut remove = |path: &Path, ty: fs::FileType, name: &str| -> Result<(), StoreError> {
            if ty.is_file() && (stale_temp(name) || (every && temp_owner(name).is_some())) {
                fs::remove_file(path).map_err(io(path))?;
                removed += 1;
            }
            Ok(())
        };
        match sweep {
            Sweep::Folders(folders) => {
                for rel in folders {
                    for_each_entry(&self.dir().join(rel), &mut remove)?;
                }
            }
            Sweep::Tree { folders, depth: max } => {
                let mut stack = vec![(self.dir().to_owned(), 0u32)];
                while let Some((dir, depth)) = stack.pop() {
                    for_each_entry(&dir, |path, ty, name| {
                        if ty.is_dir() {
                            let ours = depth > 0 || folders.contains(&name);
                            if ours && depth < max {
                                stack.push((path.to_path_buf(), depth + 1));
                            }
                            return Ok(());
                        }
                        remove(path, ty, name)
                    })?;
                }
            }
        }
        Ok(removed)
    }

    #[cfg(feature = "server")]
    fn read_async<'a>(
        &'a self,
        rel: &'a str,
        limit: u64,
    ) -> super::BoxFuture<'a, Result<Option<bytes::Bytes>, StoreError>> {
        Box::pin(async move {
            let path = self.dir().join(rel);
            let what = read_limit(rel).1;
            let p = path.clone();
            tokio::task::spawn_blocking(move || read_regular(&p, limit, what))
                .await
                .map_err(|e| io(&path)(std::io::Error::other(e)))?
                .map(|b| b.map(bytes::Bytes::from))
        })
    }

    #[cfg(feature = "server")]
    fn exists_async<'a>(&'a self, rel: &'a str) -> super::BoxFuture<'a, Result<bool, StoreError>> {
        Box::pin(
            async move { Ok(tokio::fs::metadata(self.dir().join(rel)).await.is_ok_and(|m| m.is_file())) },
        )
    }
}

/// Writes `bytes` to `path` via a temporary file in the same directory, synced, then renamed.
pub fn write_atomic(path: &Path, bytes: &[u8]) -> Result<(), StoreError> {
    let dir = path.parent().unwrap_or(Path::new("."));
    fs::create_dir_all(dir).map_err(io(dir))?;
    let mut tmp = tempfile_in(dir, path)?;
    let result = (|| {
        tmp.1.write_all(bytes)?;
        tmp.1.sync_data()
    })();
    if let Err(e) = result {
        let _ = fs::remove_file(&tmp.0);
        return Err(io(path)(e));
    }
    drop(tmp.1);
    fs::rename(&tmp.0, path).map_err(|e| {
        let _ = fs::remove_file(&tmp.0);
        io(path)(e)
    })
}

/// A clear error for an output path that cannot become a directory: a dangling symbolic link
/// (which `create_dir_all` reports as "File exists"), a file, or a path under a file.
pub fn check_out_dir(dir: &Path) -> Result<(), StoreError> {
    let invalid = |message: String| StoreError::Invalid { path: dir.to_owned(), message };
    if let Ok(meta) = fs::symlink_metadata(dir)
        && meta.file_type().is_symlink()
        && !dir.exists()
    {
        let target = fs::read_link(dir).map_or_else(|_| "?".into(), |t| t.display().to_string());
        return Err(invalid(format!(
            "is a symbolic link to {target}, which does not exist; create the target directory or remove the link"
        )));
    }
    if dir.exists() && !dir.is_dir() {
        return Err(invalid("exists and is not a directory".into()));
    }
    let mut up = dir.parent();
    while let Some(p) = up {
        if p.as_os_str().is_empty() {
            break;
        }
        if p.exists() {
            if !p.is_dir() {
                return Err(invalid(format!("{} is not a directory", p.display())));
            }
            break;
        }
        up = p.parent();
    }
    Ok(())
}

/// A clear error for an output file that cannot be written at `path` because its folder is
/// missing or is not a folder (said before any work, not as a failed temporary file).
pub fn check_out_file(path: &Path) -> Result<(), StoreError> {
    let Some(dir) = path.parent().filter(|p| !p.as_os_str().is_empty()) else { return Ok(()) };
    if dir.is_dir() {
        return Ok(());
    }
    let invalid = |message: String| StoreError::Invalid { path: path.to_owned(), message };
    // The nearest folder above that exists says what is wrong: a file where a folder should be,
    // or folders that are missing.
    let mut up = Some(dir);
    while let Some(p) = up {
        if p.as_os_str().is_empty() {
            break;
        }
        if fs::symlink_metadata(p).is_ok() {
            if !p.is_dir() {
                return Err(invalid(format!("cannot be written: {} is not a folder", p.display())));
            }
            break;
        }
        up = p.parent();
    }
    Err(invalid(format!("cannot be written: its folder {} does not exist", dir.display())))
}

/// Calls `f` with the path, type and name of every entry of `dir`; a folder that does not exist
/// has none.
fn for_each_entry(
    dir: &Path,
    mut f: impl FnMut(&Path, fs::FileType, &str) -> Result<(), StoreError>,
) -> Result<(), StoreError> {
    let entries = match fs::read_dir(dir) {
        Ok(e) => e,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(()),
        Err(e) => return Err(io(dir)(e)),
    };
    for entry in entries {
        let entry = entry.map_err(io(dir))?;
        let path = entry.path();
        let ty = entry.file_type().map_err(io(&path))?;
        f(&path, ty, &entry.file_name().to_string_lossy())?;
    }
    Ok(())
}

/// Whether `name` is a [`write_atomic`] temporary file of this process or of one that no longer
/// runs (where `/proc` tells; elsewhere every one counts as stale).
fn stale_temp(name: &str) -> bool {
    temp_owner(name).is_some_and(|pid| {
        pid == std::process::id()
            || !Path::new("/proc/self").exists()
            || !Path::new(&format!("/proc/{pid}")).exists()
    })
}

/// The process id in a [`write_atomic`] temporary file name `.NAME.PID.N.tmp`.
fn temp_owner(name: &str) -> Option<u32> {
    let rest = name.strip_prefix('.')?.strip_suffix(".tmp")?;
    let mut parts = rest.rsplitn(3, '.');
    let attempt = parts.next()?;
    let pid = parts.next()?;
    let target = parts.next()?;
    let digits = |s: &str| !s.is_empty() && s.bytes().all(|b| b.is_ascii_digit());
    (digits(attempt) && !target.is_empty()).then_some(())?;
    digits(pid).then(|| pid.parse().ok())?
}

fn tempfile_in(dir: &Path, path: &Path) -> Result<(PathBuf, fs::File), StoreError> {
    let name = path.file_name().and_then(|n| n.to_str()).unwrap_or("file");
    for attempt in 0..100u32 {
        let tmp = dir.join(format!(".{name}.{}.{attempt}.tmp", std::process::id()));
        match fs::OpenOptions::new().write(true).create_new(true).open(&tmp) {
            Ok(f) => return Ok((tmp, f)),
            Err(e) if e.kind() == std::io::ErrorKind::AlreadyExists => {}
            Err(e) => return Err(io(&tmp)(e)),
        }
    }
    Err(StoreError::Invalid { path: path.to_owned(), message: "could not create a temporary file".into() })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn temp_names_are_recognised() {
        assert_eq!(temp_owner(".1.tsb.4242.0.tmp"), Some(4242));
        assert_eq!(temp_owner(".tileset.json.7.12.tmp"), Some(7));
        for name in ["1.tsb", ".1.tsb.tmp", ".x.4242.tmp", ".x.a.0.tmp", "..1.0.tmp", ".1.tsb.42.0.tmpx"] {
            assert_eq!(temp_owner(name), None, "{name}");
        }
    }

    #[test]
    fn atomic_write_replaces_and_leaves_no_temp() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("a/b/c.bin");
        write_atomic(&p, b"one").unwrap();
        write_atomic(&p, b"two").unwrap();
        assert_eq!(fs::read(&p).unwrap(), b"two");
        let names: Vec<_> =
            fs::read_dir(p.parent().unwrap()).unwrap().map(|e| e.unwrap().file_name()).collect();
        assert_eq!(names.len(), 1);
    }

    /// An output file whose folder is missing, or is a file, is named as such.
    #[test]
    fn out_files_whose_folder_cannot_hold_them_say_why() {
        let dir = tempfile::tempdir().unwrap();
        check_out_file(&dir.path().join("a.tsa")).unwrap();
        check_out_file(Path::new("a.tsa")).unwrap();
        let missing = dir.path().join("a");
        let e = check_out_file(&missing.join("b.tsa")).unwrap_err().to_string();
        assert!(e.contains(&format!("its folder {} does not exist", missing.display())), "{e}");
        let e = check_out_file(&missing.join("c/b.tsa")).unwrap_err().to_string();
        assert!(e.contains(&format!("its folder {} does not exist", missing.join("c").display())), "{e}");
        let file = dir.path().join("f");
        fs::write(&file, b"x").unwrap();
        let e = check_out_file(&file.join("c/b.tsa")).unwrap_err().to_string();
        assert!(e.contains(&format!("{} is not a folder", file.display())), "{e}");
    }
}
