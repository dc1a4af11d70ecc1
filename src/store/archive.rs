//! Single-file tileset archives (`.tsa`): every file of a finished tileset — manifest, index
//! chunks, blobs, `unpaid` markers, placement — in one file, each addressable by a byte range,
//! so a tileset of millions of blobs is one object in a bucket (one PUT instead of millions) and
//! any host that answers HTTP range requests can serve it.
//!
//! Layout (little-endian; `docs/formats.md` has the full description):
//!
//! ```text
//! "TSARC\x00\x01\n"                       8 bytes, magic
//! file bytes, one after another, in path order
//! directory pages, each written once PAGE_ENTRIES files are in:
//!     per file: path length u16, path (UTF-8), offset u64, length u64, CRC-32 u32
//! root directory: per page: first path length u16, first path, offset u64, length u32,
//!     CRC-32 u32, file count u32
//! footer, 64 bytes: magic "TSARCHV1", version u32, reserved u32, root offset u64, root length
//!     u64, root CRC-32 u32, reserved u32, file count u64, data end u64, reserved u32, CRC-32 of
//!     the footer's first 60 bytes u32
//! ```
//!
//! A reader takes the last 64 bytes (an HTTP suffix range `bytes=-64`), the root (one range),
//! then one page per lookup (cached) and the file's range: three small reads before the first
//! file, one per file after. The footer at the end lets the writer stream in one pass (a
//! multipart upload cannot seek back). Why not PMTiles: its directory addresses tiles by a
//! Hilbert tile id, one byte range per z/x/y; a tileset here is a tree of named files (several
//! levels per node, index chunks, markers), and serving them byte-identical to the directory
//! needs each one by its path.

use std::collections::HashMap;
use std::io::Write;
use std::sync::Mutex;

/// The first bytes of an archive.
pub const MAGIC: &[u8; 8] = b"TSARC\x00\x01\n";
/// The footer's first bytes.
pub const FOOTER_MAGIC: &[u8; 8] = b"TSARCHV1";
pub const VERSION: u32 = 1;
pub const FOOTER_LEN: u64 = 64;
/// Files per directory page.
pub const PAGE_ENTRIES: usize = 4096;
/// Longest path of a file in an archive.
pub const MAX_PATH: usize = 1024;
/// Largest directory page or root an archive may declare (checked before allocating).
pub const MAX_DIR_BYTES: u64 = 64 << 20;
/// Fewest bytes one file takes in a directory page (a one-byte path).
const MIN_ENTRY_BYTES: u64 = 2 + 1 + 8 + 8 + 4;
/// Largest directory page a reader accepts: [`PAGE_ENTRIES`] files of [`MAX_PATH`]-byte paths
/// (about 4.1 MiB), what the writer can produce. Checked before a page is read, so one lookup
/// reads (and the page cache holds) at most that much whatever the archive declares.
pub const MAX_PAGE_BYTES: u64 = PAGE_ENTRIES as u64 * (MIN_ENTRY_BYTES - 1 + MAX_PATH as u64);
/// Directory pages a reader keeps in memory.
const CACHED_PAGES: usize = 512;

/// A problem with an archive: its text names what is wrong; callers add the archive's name.
#[derive(Debug, thiserror::Error)]
pub enum ArchiveError {
    #[error("{0}")]
    Io(#[from] std::io::Error),
    /// The file is not an archive this build reads (found when it is opened).
    #[error("not a terrastream archive: {0}")]
    Format(String),
    /// Damage found inside an archive that opened: a directory page or a file whose bytes do
    /// not match their checksum, an entry out of range. Reading again will not help.
    #[error("damaged archive: {0}")]
    Corrupt(String),
    /// A file larger than its kind's limit (checked against the directory before reading).
    #[error("{path}: {len} bytes; a {what} is at most {limit} bytes (not read)")]
    TooLarge { path: String, len: u64, limit: u64, what: &'static str },
    #[error("{0}")]
    Write(String),
}

fn damaged(what: impl Into<String>) -> ArchiveError {
    ArchiveError::Corrupt(what.into())
}

/// A directory page is read after the archive opened: what is wrong in it is damage.
fn field<T>(r: Result<T, ArchiveError>) -> Result<T, ArchiveError> {
    r.map_err(|e| match e {
        ArchiveError::Format(m) => damaged(m),
        e => e,
    })
}

/// One file in the directory.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Entry {
    pub path: String,
    pub offset: u64,
    pub len: u64,
    pub crc: u32,
}

#[derive(Debug, Clone)]
struct PageRef {
    first: String,
    offset: u64,
    len: u32,
    crc: u32,
    count: u32,
}

/// Writes an archive to `out` in one pass; files must come in strictly increasing path order.
pub struct ArchiveWriter<W: Write> {
    out: W,
    pos: u64,
    page: Vec<Entry>,
    root: Vec<PageRef>,
    count: u64,
    last: Option<String>,
}

fn put_path(buf: &mut Vec<u8>, path: &str) {
    buf.extend_from_slice(&(path.len() as u16).to_le_bytes());
    buf.extend_from_slice(path.as_bytes());
}

/// A directory page's bytes: per file its path, offset, length and CRC-32.
fn encode_page(entries: &[Entry]) -> Vec<u8> {
    let mut buf = Vec::with_capacity(entries.len() * 64);
    for e in entries {
        put_path(&mut buf, &e.path);
        buf.extend_from_slice(&e.offset.to_le_bytes());
        buf.extend_from_slice(&e.len.to_le_bytes());
        buf.extend_from_slice(&e.crc.to_le_bytes());
    }
    buf
}

/// The root directory's bytes: per page its first path, offset, length, CRC-32 and file count.
fn encode_root(pages: &[PageRef]) -> Vec<u8> {
    let mut root = Vec::new();
    for p in pages {
        put_path(&mut root, &p.first);
        root.extend_from_slice(&p.offset.to_le_bytes());
        root.extend_from_slice(&p.len.to_le_bytes());
        root.extend_from_slice(&p.crc.to_le_bytes());
        root.extend_from_slice(&p.count.to_le_bytes());
    }
    root
}

/// The footer (`FOOTER_LEN` bytes) of an archive whose root `root` starts at `root_offset`.
fn encode_footer(root_offset: u64, root: &[u8], count: u64, data_end: u64) -> Vec<u8> {
    let mut f = Vec::with_capacity(FOOTER_LEN as usize);
    f.extend_from_slice(FOOTER_MAGIC);
    f.extend_from_slice(&VERSION.to_le_bytes());
    f.extend_from_slice(&0u32.to_le_bytes());
    f.extend_from_slice(&root_offset.to_le_bytes());
    f.extend_from_slice(&(root.len() as u64).to_le_bytes());
    f.extend_from_slice(&crc32fast::hash(root).to_le_bytes());
    f.extend_from_slice(&0u32.to_le_bytes());
    f.extend_from_slice(&count.to_le_bytes());
    f.extend_from_slice(&data_end.to_le_bytes());
    f.extend_from_slice(&0u32.to_le_bytes());
    let crc = crc32fast::hash(&f);
    f.extend_from_slice(&crc.to_le_bytes());
    f
}

impl<W: Write> ArchiveWriter<W> {
    pub fn new(mut out: W) -> Result<Self, ArchiveError> {
        out.write_all(MAGIC)?;
        Ok(Self { out, pos: MAGIC.len() as u64, page: Vec::new(), root: Vec::new(), count: 0, last: None })
    }

    /// Appends the file `path` (relative, `/`-separated) with `bytes`.
    pub fn add(&mut self, path: &str, bytes: &[u8]) -> Result<(), ArchiveError> {
        if path.is_empty() || path.len() > MAX_PATH || path.starts_with('/') {
            return Err(ArchiveError::Write(format!(
                "{path:?}: not a relative path of 1 to {MAX_PATH} bytes"
            )));
        }
        if self.last.as_deref().is_some_and(|l| l >= path) {
            return Err(ArchiveError::Write(format!("{path:?}: files must come in increasing path order")));
        }
        self.out.write_all(bytes)?;
        self.page.push(Entry {
            path: path.to_owned(),
            offset: self.pos,
            len: bytes.len() as u64,
            crc: crc32fast::hash(bytes),
        });
        self.pos += bytes.len() as u64;
        self.count += 1;
        self.last = Some(path.to_owned());
        if self.page.len() == PAGE_ENTRIES {
            self.flush_page()?;
        }
        Ok(())
    }

    fn flush_page(&mut self) -> Result<(), ArchiveError> {
        let Some(first) = self.page.first().map(|e| e.path.clone()) else { return Ok(()) };
        let buf = encode_page(&self.page);
        self.out.write_all(&buf)?;
        self.root.push(PageRef {
            first,
            offset: self.pos,
            len: buf.len() as u32,
            crc: crc32fast::hash(&buf),
            count: self.page.len() as u32,
        });
        self.pos += buf.len() as u64;
        self.page.clear();
        Ok(())
    }

    /// Writes the last page, the root and the footer; returns the output and the archive's length.
    pub fn finish(mut self) -> Result<(W, u64), ArchiveError> {
        let data_end = self.pos;
        self.flush_page()?;
        let root = encode_root(&self.root);
        if root.len() as u64 > MAX_DIR_BYTES {
            return Err(ArchiveError::Write(format!(
                "{} files: the directory root would exceed {MAX_DIR_BYTES} bytes",
                self.count
            )));
        }
        let root_offset = self.pos;
        self.out.write_all(&root)?;
        self.pos += root.len() as u64;
        let f = encode_footer(root_offset, &root, self.count, data_end);
        self.out.write_all(&f)?;
        self.pos += FOOTER_LEN;
        self.out.flush()?;
        Ok((self.out, self.pos))
    }
}

/// Where an archive's bytes come from: a local file, an object in a bucket, anything that reads
/// byte ranges.
pub trait RangeSource: Send + Sync {
    /// Bytes `start..start + len`; fewer only past the end.
    fn read_range(&self, start: u64, len: u64) -> std::io::Result<Vec<u8>>;
}

/// A local archive file.
pub struct FileSource(pub std::fs::File);

impl RangeSource for FileSource {
    fn read_range(&self, start: u64, len: u64) -> std::io::Result<Vec<u8>> {
        use std::os::unix::fs::FileExt;
        let mut buf = vec![0u8; usize::try_from(len).map_err(std::io::Error::other)?];
        let mut done = 0;
        while done < buf.len() {
            match self.0.read_at(&mut buf[done..], start + done as u64) {
                Ok(0) => break,
                Ok(n) => done += n,
                Err(e) if e.kind() == std::io::ErrorKind::Interrupted => {}
                Err(e) => return Err(e),
            }
        }
        buf.truncate(done);
        Ok(buf)
    }
}

/// An archive opened for reading: its footer and root in memory, pages read on demand.
pub struct Archive {
    source: Box<dyn RangeSource>,
    len: u64,
    count: u64,
    data_end: u64,
    root: Vec<PageRef>,
    pages: Mutex<HashMap<usize, std::sync::Arc<Vec<Entry>>>>,
}

impl std::fmt::Debug for Archive {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Archive").field("len", &self.len).field("files", &self.count).finish_non_exhaustive()
    }
}

fn bad(what: impl Into<String>) -> ArchiveError {
    ArchiveError::Format(what.into())
}

/// A little-endian cursor over a directory's bytes; every read is bounds-checked.
struct Cursor<'a>(&'a [u8]);

impl Cursor<'_> {
    fn take(&mut self, n: usize, what: &str) -> Result<&[u8], ArchiveError> {
        if self.0.len() < n {
            return Err(bad(format!("{what} is cut short")));
        }
        let (a, b) = self.0.split_at(n);
        self.0 = b;
        Ok(a)
    }
    fn u16(&mut self, what: &str) -> Result<u16, ArchiveError> {
        Ok(u16::from_le_bytes(self.take(2, what)?.try_into().unwrap_or_default()))
    }
    fn u32(&mut self, what: &str) -> Result<u32, ArchiveError> {
        Ok(u32::from_le_bytes(self.take(4, what)?.try_into().unwrap_or_default()))
    }
    fn u64(&mut self, what: &str) -> Result<u64, ArchiveError> {
        Ok(u64::from_le_bytes(self.take(8, what)?.try_into().unwrap_or_default()))
    }
    fn path(&mut self, what: &str) -> Result<String, ArchiveError> {
        let n = usize::from(self.u16(what)?);
        if n == 0 || n > MAX_PATH {
            return Err(bad(format!("{what}: a path of {n} bytes")));
        }
        String::from_utf8(self.take(n, what)?.to_vec())
            .map_err(|_| bad(format!("{what}: a path that is not UTF-8")))
    }
}

impl Archive {
    /// Opens the archive of `len` bytes read through `source`: reads and checks its footer and
    /// root directory.
    pub fn open(source: Box<dyn RangeSource>, len: u64) -> Result<Self, ArchiveError> {
        if len < MAGIC.len() as u64 + FOOTER_LEN {
            return Err(bad(format!("{len} bytes is too short")));
        }
        let f = source.read_range(len - FOOTER_LEN, FOOTER_LEN)?;
        if f.len() as u64 != FOOTER_LEN || &f[..8] != FOOTER_MAGIC {
            return Err(bad("no archive footer at the end"));
        }
        let stored = u32::from_le_bytes(f[60..64].try_into().unwrap_or_default());
        if crc32fast::hash(&f[..60]) != stored {
            return Err(bad("the footer's checksum does not match"));
        }
        let mut c = Cursor(&f[8..60]);
        let version = c.u32("footer")?;
        if version != VERSION {
            return Err(bad(format!("version {version}; this build reads version {VERSION}")));
        }
        c.u32("footer")?;
        let root_offset = c.u64("footer")?;
        let root_len = c.u64("footer")?;
        let root_crc = c.u32("footer")?;
        c.u32("footer")?;
        let count = c.u64("footer")?;
        let data_end = c.u64("footer")?;
        let footer_at = len - FOOTER_LEN;
        if root_len > MAX_DIR_BYTES
            || root_offset.checked_add(root_len) != Some(footer_at)
            || data_end > root_offset
            || data_end < MAGIC.len() as u64
        {
            return Err(bad(format!(
                "footer places the root at {root_offset}+{root_len} and the data end at {data_end} in {len} bytes"
            )));
        }
        let head = source.read_range(0, MAGIC.len() as u64)?;
        if head != MAGIC {
            return Err(bad("it does not begin with the archive magic"));
        }
        let root_bytes = source.read_range(root_offset, root_len)?;
        if root_bytes.len() as u64 != root_len || crc32fast::hash(&root_bytes) != root_crc {
            return Err(bad("the root directory's checksum does not match"));
        }
        let mut c = Cursor(&root_bytes);
        let mut root: Vec<PageRef> = Vec::new();
        let mut total = 0u64;
        while !c.0.is_empty() {
            let first = c.path("root directory")?;
            let p = PageRef {
                first,
                offset: c.u64("root directory")?,
                len: c.u32("root directory")?,
                crc: c.u32("root directory")?,
                count: c.u32("root directory")?,
            };
            if root.last().is_some_and(|l| l.first >= p.first)
                || p.offset < MAGIC.len() as u64
                || p.offset.checked_add(u64::from(p.len)).is_none_or(|end| end > root_offset)
                || u64::from(p.len) > MAX_PAGE_BYTES
                || p.count == 0
            {
                return Err(bad(format!("root directory entry {} is out of order or range", root.len())));
            }
            if u64::from(p.count) * MIN_ENTRY_BYTES > u64::from(p.len) {
                return Err(bad(format!(
                    "root directory entry {} counts {} files in a page of {} bytes (at most {} fit)",
                    root.len(),
                    p.count,
                    p.len,
                    u64::from(p.len) / MIN_ENTRY_BYTES
                )));
            }
            if p.count as usize > PAGE_ENTRIES {
                return Err(bad(format!(
                    "root directory entry {} counts {} files; a page holds at most {PAGE_ENTRIES}",
                    root.len(),
                    p.count
                )));
            }
            total += u64::from(p.count);
            root.push(p);
        }
        if total != count {
            return Err(bad(format!("the footer counts {count} files, the directory {total}")));
        }
        Ok(Self { source, len, count, data_end, root, pages: Mutex::new(HashMap::new()) })
    }

    /// Opens a local archive file. Anything but a regular file (a FIFO, whose open would wait
    /// for a writer; a device) is refused without being opened.
    pub fn open_file(path: &std::path::Path) -> Result<Self, ArchiveError> {
        let irregular = |ty| {
            crate::store::bounded::irregular_kind(ty)
                .map(|kind| bad(format!("it is {kind}, not a regular file; refused without reading it")))
        };
        if let Some(e) = irregular(std::fs::metadata(path)?.file_type()) {
            return Err(e);
        }
        let file = std::fs::File::open(path)?;
        let md = file.metadata()?;
        if let Some(e) = irregular(md.file_type()) {
            return Err(e);
        }
        Self::open(Box::new(FileSource(file)), md.len())
    }

    /// The archive's length in bytes.
    #[must_use]
    pub fn len(&self) -> u64 {
        self.len
    }

    #[must_use]
    pub fn is_empty(&self) -> bool {
        self.count == 0
    }

    /// Files in the archive.
    #[must_use]
    pub fn file_count(&self) -> u64 {
        self.count
    }

    fn page(&self, i: usize) -> Result<std::sync::Arc<Vec<Entry>>, ArchiveError> {
        if let Some(p) = self.pages.lock().ok().and_then(|m| m.get(&i).cloned()) {
            return Ok(p);
        }
        let r = &self.root[i];
        let bytes = self.source.read_range(r.offset, u64::from(r.len))?;
        if bytes.len() != r.len as usize || crc32fast::hash(&bytes) != r.crc {
            return Err(damaged(format!("directory page {i}'s checksum does not match")));
        }
        let mut c = Cursor(&bytes);
        let mut out = Vec::with_capacity(r.count as usize);
        while !c.0.is_empty() {
            let e = Entry {
                path: field(c.path("directory page"))?,
                offset: field(c.u64("directory page"))?,
                len: field(c.u64("directory page"))?,
                crc: field(c.u32("directory page"))?,
            };
            if out.last().is_some_and(|l: &Entry| l.path >= e.path)
                || e.offset < MAGIC.len() as u64
                || e.offset.checked_add(e.len).is_none_or(|end| end > self.data_end)
            {
                return Err(damaged(format!(
                    "directory page {i}: entry {:?} is out of order or range",
                    e.path
                )));
            }
            out.push(e);
        }
        let next = self.root.get(i + 1).map(|n| &n.first);
        if out.len() != r.count as usize
            || out.first().map(|e| &e.path) != Some(&r.first)
            || out.last().zip(next).is_some_and(|(l, n)| &l.path >= n)
        {
            return Err(damaged(format!(
                "directory page {i} does not match the root (its file count, first path, or order before the next page)"
            )));
        }
        let page = std::sync::Arc::new(out);
        if let Ok(mut m) = self.pages.lock() {
            if m.len() >= CACHED_PAGES {
                m.clear();
            }
            m.insert(i, page.clone());
        }
        Ok(page)
    }

    /// The directory entry of `path`; `None` when the archive has no such file.
    pub fn entry(&self, path: &str) -> Result<Option<Entry>, ArchiveError> {
        let i = self.root.partition_point(|p| p.first.as_str() <= path);
        if i == 0 {
            return Ok(None);
        }
        let page = self.page(i - 1)?;
        Ok(page.binary_search_by(|e| e.path.as_str().cmp(path)).ok().map(|j| page[j].clone()))
    }

    /// The bytes of `path`, checked against its CRC-32; `None` when there is no such file.
    pub fn read(&self, path: &str) -> Result<Option<Vec<u8>>, ArchiveError> {
        self.read_within(path, u64::MAX, "file")
    }

    /// [`Archive::read`] of a file of at most `limit` bytes (a `what`, for messages): a larger
    /// entry is [`ArchiveError::TooLarge`], refused before any of it is read.
    pub fn read_within(
        &self,
        path: &str,
        limit: u64,
        what: &'static str,
    ) -> Result<Option<Vec<u8>>, ArchiveError> {
        let Some(e) = self.entry(path)? else { return Ok(None) };
        if e.len > limit {
            return Err(ArchiveError::TooLarge { path: path.to_owned(), len: e.len, limit, what });
        }
        // An empty file (a marker) is read without a request: a range of no bytes is not a
        // valid HTTP range.
        let bytes = if e.len == 0 { Vec::new() } else { self.source.read_range(e.offset, e.len)? };
        if bytes.len() as u64 != e.len || crc32fast::hash(&bytes) != e.crc {
            return Err(damaged(format!("{path}: its bytes do not match the directory's checksum")));
        }
        Ok(Some(bytes))
    }

    /// Every entry, in path order (reads every page).
    pub fn entries(&self) -> Result<Vec<Entry>, ArchiveError> {
        let mut out = Vec::new();
        for i in 0..self.root.len() {
            out.extend(self.page(i)?.iter().cloned());
        }
        Ok(out)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    struct Mem(Vec<u8>, std::sync::atomic::AtomicUsize);
    impl RangeSource for Mem {
        fn read_range(&self, start: u64, len: u64) -> std::io::Result<Vec<u8>> {
            self.1.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
            let s = (start as usize).min(self.0.len());
            let e = start.saturating_add(len).min(self.0.len() as u64) as usize;
            Ok(self.0[s..e].to_vec())
        }
    }

    fn build(files: &[(String, Vec<u8>)]) -> Vec<u8> {
        let mut w = ArchiveWriter::new(Vec::new()).unwrap();
        for (p, b) in files {
            w.add(p, b).unwrap();
        }
        let (out, len) = w.finish().unwrap();
        assert_eq!(out.len() as u64, len);
        out
    }

    #[test]
    fn every_file_reads_back_across_pages_and_absent_ones_are_none() {
        let mut files: Vec<(String, Vec<u8>)> = (0..PAGE_ENTRIES * 2 + 7)
            .map(|i| (format!("tiles/{}/{i:06}.tsb", i % 3), vec![(i % 251) as u8; i % 37]))
            .collect();
        files.sort();
        let bytes = build(&files);
        let len = bytes.len() as u64;
        let a = Archive::open(Box::new(Mem(bytes, 0.into())), len).unwrap();
        assert_eq!(a.file_count(), files.len() as u64);
        for (p, b) in files.iter().step_by(97).chain(files.last()) {
            assert_eq!(a.read(p).unwrap().as_ref(), Some(b), "{p}");
        }
        for p in ["", "a", "tiles/0", "tiles/9/0.tsb", "zzz", "tiles/1/000001.tsb.x"] {
            assert_eq!(a.read(p).unwrap(), None, "{p}");
        }
        assert_eq!(a.entries().unwrap().len(), files.len());
    }

    #[test]
    fn an_empty_archive_opens_and_holds_nothing() {
        let bytes = build(&[]);
        let len = bytes.len() as u64;
        let a = Archive::open(Box::new(Mem(bytes, 0.into())), len).unwrap();
        assert!(a.is_empty());
        assert_eq!(a.read("tileset.json").unwrap(), None);
    }

    #[test]
    fn the_writer_refuses_unordered_or_bad_paths() {
        let mut w = ArchiveWriter::new(Vec::new()).unwrap();
        w.add("b", b"1").unwrap();
        assert!(w.add("a", b"2").is_err());
        assert!(w.add("b", b"2").is_err());
        assert!(w.add("/c", b"2").is_err());
        assert!(w.add("", b"2").is_err());
    }

    /// An archive with every checksum right around hostile directory values: 64 data bytes,
    /// then `pages`, then a root describing them as `tweak` leaves it.
    fn hostile(pages: &[Vec<Entry>], tweak: impl Fn(&mut Vec<PageRef>)) -> Vec<u8> {
        let mut b = MAGIC.to_vec();
        b.extend_from_slice(&[5; 64]);
        let data_end = b.len() as u64;
        let mut refs = Vec::new();
        for p in pages {
            let bytes = encode_page(p);
            refs.push(PageRef {
                first: p[0].path.clone(),
                offset: b.len() as u64,
                len: bytes.len() as u32,
                crc: crc32fast::hash(&bytes),
                count: p.len() as u32,
            });
            b.extend_from_slice(&bytes);
        }
        tweak(&mut refs);
        let count = refs.iter().map(|r| u64::from(r.count)).sum();
        let root = encode_root(&refs);
        let root_offset = b.len() as u64;
        b.extend_from_slice(&root);
        b.extend_from_slice(&encode_footer(root_offset, &root, count, data_end));
        b
    }

    fn entry(path: &str, offset: u64) -> Entry {
        Entry { path: path.into(), offset, len: 4, crc: crc32fast::hash(&[5; 4]) }
    }

    fn open_mem(bytes: Vec<u8>) -> Result<Archive, ArchiveError> {
        let len = bytes.len() as u64;
        Archive::open(Box::new(Mem(bytes, 0.into())), len)
    }

    #[test]
    fn hostile_archives_with_right_checksums_are_refused() {
        let page = || vec![entry("a", 8), entry("b", 12)];
        // The control: the same construction untouched opens and reads.
        let a = open_mem(hostile(&[page()], |_| {})).unwrap();
        assert_eq!(a.read("b").unwrap(), Some(vec![5; 4]));
        // A page placed so that offset + length wraps past 2^64.
        let wrap = open_mem(hostile(&[page()], |r| r[0].offset = u64::MAX - 3)).unwrap_err();
        assert!(wrap.to_string().contains("out of order or range"), "{wrap}");
        // A page claiming 4 billion files in 46 bytes (a reader would reserve ~200 GiB).
        let many = open_mem(hostile(&[page()], |r| r[0].count = u32::MAX)).unwrap_err();
        assert!(many.to_string().contains("root directory entry 0 counts 4294967295 files"), "{many}");
        // A page of more files than a page holds (each lookup in it would read and cache it
        // whole, up to 64 MiB).
        let big: Vec<Entry> = (0..=PAGE_ENTRIES).map(|i| entry(&format!("t/{i:05}"), 8)).collect();
        let e = open_mem(hostile(&[big], |_| {})).unwrap_err();
        assert!(
            e.to_string().contains("root directory entry 0 counts 4097 files; a page holds at most 4096"),
            "{e}"
        );
        let fits: Vec<Entry> = (0..PAGE_ENTRIES).map(|i| entry(&format!("t/{i:05}"), 8)).collect();
        assert!(open_mem(hostile(&[fits], |_| {})).is_ok());
        // A page holding a path that sorts after the next page's first: listed, but a lookup
        // by its path would search the wrong page.
        let a =
            open_mem(hostile(&[vec![entry("a", 8), entry("c", 12)], vec![entry("b", 16)]], |_| {})).unwrap();
        let e = a.read("a").unwrap_err();
        assert!(e.to_string().contains("order before the next page"), "{e}");
        assert!(a.entries().is_err());
    }

    /// Every single-byte change, and every truncation, of a small archive is either refused on
    /// open or on read, or reads back only the original files' bytes — never a panic, never
    /// other bytes.
    #[test]
    fn damaged_archives_are_refused_never_misread() {
        let files: Vec<(String, Vec<u8>)> = vec![
            ("a.json".into(), b"{}".to_vec()),
            ("tiles/0/0/0/0.tsb".into(), vec![7; 40]),
            ("z".into(), vec![]),
        ];
        let good = build(&files);
        let check = |bytes: Vec<u8>| {
            let len = bytes.len() as u64;
            let Ok(a) = Archive::open(Box::new(Mem(bytes, 0.into())), len) else { return };
            for (p, b) in &files {
                if let Ok(Some(got)) = a.read(p) {
                    assert_eq!(&got, b, "{p}");
                }
            }
        };
        for i in 0..good.len() {
            for flip in [1u8, 0x80] {
                let mut b = good.clone();
                b[i] ^= flip;
                check(b);
            }
        }
        for n in 0..good.len() {
            check(good[..n].to_vec());
        }
    }
}
