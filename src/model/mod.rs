//! Standalone 3D models: decodes OBJ, STL (ASCII and binary) and PLY (ASCII and binary, either
//! byte order) into one indexed triangle mesh with per-vertex normals.
//!
//! Parsing works on byte slices ([`parse`], and `obj::parse`, `stl::parse`, `ply::parse`), so it
//! is testable without files; [`load`] reads a file and names it in every error. Every parser
//! ends in the same cleanup ([`Builder::finish`]):
//! - polygons are fan-triangulated (`v0 v1 v2`, `v0 v2 v3`, …);
//! - degenerate triangles (a repeated vertex, or zero area in exact arithmetic) are skipped and
//!   counted in [`ModelStats::degenerate`];
//! - vertices no triangle uses are dropped and counted, so bounds come from the surface;
//! - normals given by the file (OBJ `vn`, PLY `nx ny nz`) are averaged per vertex; missing ones
//!   are computed as the area-weighted sum of the adjacent triangles' normals.
//!
//! # Errors
//!
//! Bad input gives a [`MeshError`] naming the file and the line (text formats) or element
//! (binary formats), never a panic: empty models, vertex indices out of range, non-finite
//! coordinates, truncated files, and declared counts that cannot fit in the bytes that follow
//! (refused before anything is allocated for them).

pub mod obj;
pub mod ply;
pub mod stl;

use std::path::{Path, PathBuf};

use glam::DVec3;
use serde::{Deserialize, Serialize};

use crate::geom::{Mesh, unit_f32};

/// Most vertices or triangles a model may have after cleanup: what one blob can hold
/// ([`crate::codec::MAX_ELEMENTS`]), since the model is stored whole as level 0.
pub const MAX_MODEL_ELEMENTS: usize = crate::codec::MAX_ELEMENTS as usize;

/// Most bytes a model file may have: checked before reading (a regular file's size) and while
/// reading (a pipe, a file that grows). Four times what an OBJ of [`MAX_MODEL_ELEMENTS`] vertices
/// and triangles takes, so every model a blob can hold fits.
pub const MAX_MODEL_FILE_BYTES: u64 = 4 << 30;

/// The model file types, chosen by extension or, failing that, by signature.
#[cfg_attr(feature = "cli", derive(clap::ValueEnum))]
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum FileType {
    Obj,
    Stl,
    Ply,
}

/// The exact encoding a model was read from.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
pub enum ModelEncoding {
    #[serde(rename = "obj")]
    Obj,
    #[serde(rename = "stl-ascii")]
    StlAscii,
    #[serde(rename = "stl-binary")]
    StlBinary,
    #[serde(rename = "ply-ascii")]
    PlyAscii,
    #[serde(rename = "ply-binary-little-endian")]
    PlyBinaryLe,
    #[serde(rename = "ply-binary-big-endian")]
    PlyBinaryBe,
}

impl ModelEncoding {
    /// The name written to manifests and summaries.
    #[must_use]
    pub fn name(self) -> &'static str {
        match self {
            Self::Obj => "obj",
            Self::StlAscii => "stl-ascii",
            Self::StlBinary => "stl-binary",
            Self::PlyAscii => "ply-ascii",
            Self::PlyBinaryLe => "ply-binary-little-endian",
            Self::PlyBinaryBe => "ply-binary-big-endian",
        }
    }
}

/// What reading a model found and cleaned up.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize)]
pub struct ModelStats {
    /// Faces (polygons or facets) in the file.
    pub faces: usize,
    /// Triangles after fan triangulation, degenerate ones included.
    pub triangles_read: usize,
    /// Triangles skipped: a repeated vertex or zero area.
    pub degenerate: usize,
    /// Vertices in the file (STL: after welding identical corners).
    pub vertices_read: usize,
    /// Vertices dropped because no kept triangle uses them.
    pub unreferenced: usize,
    /// Kept vertices whose normal came from the file; the others were computed.
    pub normals_from_file: usize,
}

/// A decoded model: the cleaned mesh, one unit normal per vertex, and what was cleaned.
#[derive(Debug, Clone, PartialEq)]
pub struct Model {
    pub encoding: ModelEncoding,
    pub mesh: Mesh,
    pub normals: Vec<[f32; 3]>,
    pub stats: ModelStats,
}

#[derive(Debug, thiserror::Error)]
pub enum MeshError {
    #[error("{path}: {source}")]
    Io { path: PathBuf, source: std::io::Error },
    #[error(
        "{file}: cannot tell the model format from the extension {ext:?} or the content; \
         expected .obj, .stl or .ply"
    )]
    UnknownFormat { file: String, ext: String },
    #[error("{file}: {at}: {message}")]
    Syntax { file: String, at: String, message: String },
    #[error("{file}: truncated: {at}: {message}")]
    Truncated { file: String, at: String, message: String },
    #[error("{file}: {at}: vertex index {index} is out of range ({count} vertices)")]
    IndexOutOfRange { file: String, at: String, index: i64, count: usize },
    #[error("{file}: {at}: coordinate {value} is not a finite number")]
    NonFinite { file: String, at: String, value: f64 },
    #[error(
        "{file}: {at}: declares {count} {what}, which cannot fit in the {available} bytes that \
         follow (at least {needed} needed); refusing it before allocating"
    )]
    AbsurdCount { file: String, at: String, what: String, count: u64, needed: u128, available: u64 },
    #[error("{file}: {what} {count} exceed the limit of {max}")]
    TooLarge { file: String, what: &'static str, count: usize, max: usize },
    #[error("{file}: empty model: {detail}")]
    Empty { file: String, detail: String },
    #[error("{}: is {kind}, not a model file", path.display())]
    NotAFile { path: PathBuf, kind: &'static str },
    #[error("{}: {} bytes; a model file is at most {max} bytes", path.display(), size.map_or_else(|| "more than that".to_owned(), |s| s.to_string()))]
    FileTooLarge { path: PathBuf, size: Option<u64>, max: u64 },
}

/// The bytes of the model file `path`, at most `max` of them. A regular file or a pipe
/// (`<(…)`) is read; a directory, a device or a socket is refused without being opened
/// ([`MeshError::NotAFile`]); a larger file is refused before reading, and a pipe or growing
/// file once past `max` ([`MeshError::FileTooLarge`]).
pub fn read_file(path: &Path, max: u64) -> Result<Vec<u8>, MeshError> {
    use std::io::Read;
    use std::os::unix::fs::FileTypeExt;
    let io = |source| MeshError::Io { path: path.to_owned(), source };
    let check = |md: &std::fs::Metadata| {
        let ty = md.file_type();
        match crate::raster::irregular_kind(ty) {
            Some(kind) if !ty.is_fifo() => Err(MeshError::NotAFile { path: path.to_owned(), kind }),
            _ if md.len() > max => {
                Err(MeshError::FileTooLarge { path: path.to_owned(), size: Some(md.len()), max })
            }
            _ => Ok(md.len()),
        }
    };
    check(&std::fs::metadata(path).map_err(io)?)?;
    let file = std::fs::File::open(path).map_err(io)?;
    let size = check(&file.metadata().map_err(io)?)?;
    let mut bytes = Vec::with_capacity(usize::try_from(size).unwrap_or(0));
    file.take(max.saturating_add(1)).read_to_end(&mut bytes).map_err(io)?;
    if bytes.len() as u64 > max {
        return Err(MeshError::FileTooLarge { path: path.to_owned(), size: None, max });
    }
    Ok(bytes)
}

/// Reads and decodes a model file; the type comes from the extension (`.obj`, `.stl`, `.ply`,
/// any case) or, for other names, from the content (see [`sniff`]).
pub fn load(path: &Path) -> Result<Model, MeshError> {
    let bytes = read_file(path, MAX_MODEL_FILE_BYTES)?;
    let name = path.display().to_string();
    let ext = path.extension().map(|e| e.to_string_lossy().to_ascii_lowercase()).unwrap_or_default();
    let ty = match ext.as_str() {
        "obj" => Some(FileType::Obj),
        "stl" => Some(FileType::Stl),
        "ply" => Some(FileType::Ply),
        _ => None,
    };
    parse(&bytes, &name, ty)
}

/// Decodes a model from bytes. `name` is used in errors; `ty` None means [`sniff`] the content.
pub fn parse(bytes: &[u8], name: &str, ty: Option<FileType>) -> Result<Model, MeshError> {
    let Some(ty) = ty.or_else(|| sniff(bytes)) else {
        return Err(MeshError::UnknownFormat {
            file: name.to_owned(),
            ext: Path::new(name).extension().map(|e| e.to_string_lossy().into_owned()).unwrap_or_default(),
        });
    };
    match ty {
        FileType::Obj => obj::parse(bytes, name),
        FileType::Stl => stl::parse(bytes, name),
        FileType::Ply => ply::parse(bytes, name),
    }
}

/// Guesses a file type from content: `ply` magic, an STL (binary by its exact size, or text
/// starting with `solid`), or OBJ statements (`v `, `f `, `#` at line starts).
#[must_use]
pub fn sniff(bytes: &[u8]) -> Option<FileType> {
    if bytes.starts_with(b"ply\n") || bytes.starts_with(b"ply\r\n") {
        return Some(FileType::Ply);
    }
    if stl::is_binary(bytes) || stl::looks_ascii(bytes) {
        return Some(FileType::Stl);
    }
    let head = &bytes[..bytes.len().min(4096)];
    let obj_like = head.split(|&b| b == b'\n').any(|l| {
        let l = l.trim_ascii_start();
        l.starts_with(b"v ") || l.starts_with(b"f ") || l.starts_with(b"vn ")
    });
    obj_like.then_some(FileType::Obj)
}

/// Error constructors bound to one file name.
#[derive(Clone, Copy)]
pub(crate) struct Ctx<'a> {
    pub(crate) file: &'a str,
}

// The `at`/`message` arguments are nearly always fresh `format!` strings or literals; taking
// them by value keeps every call site short.
#[allow(clippy::needless_pass_by_value)]
impl Ctx<'_> {
    pub(crate) fn syntax(self, at: impl ToString, message: impl ToString) -> MeshError {
        MeshError::Syntax { file: self.file.to_owned(), at: at.to_string(), message: message.to_string() }
    }
    pub(crate) fn truncated(self, at: impl ToString, message: impl ToString) -> MeshError {
        MeshError::Truncated { file: self.file.to_owned(), at: at.to_string(), message: message.to_string() }
    }
    pub(crate) fn index(self, at: impl ToString, index: i64, count: usize) -> MeshError {
        MeshError::IndexOutOfRange { file: self.file.to_owned(), at: at.to_string(), index, count }
    }
    pub(crate) fn absurd(
        self,
        at: impl ToString,
        what: impl ToString,
        count: u64,
        needed: u128,
        available: u64,
    ) -> MeshError {
        MeshError::AbsurdCount {
            file: self.file.to_owned(),
            at: at.to_string(),
            what: what.to_string(),
            count,
            needed,
            available,
        }
    }
    /// A finite position, or the error naming the first bad coordinate.
    pub(crate) fn position(self, at: impl ToString, p: [f64; 3]) -> Result<[f64; 3], MeshError> {
        match p.iter().find(|v| !v.is_finite()) {
            Some(&value) => {
                Err(MeshError::NonFinite { file: self.file.to_owned(), at: at.to_string(), value })
            }
            None => Ok(p),
        }
    }
}

/// What every parser collects; [`Builder::finish`] turns it into a [`Model`].
#[derive(Debug, Default)]
pub(crate) struct Builder {
    pub(crate) positions: Vec<[f64; 3]>,
    /// Triangles with indices already checked against `positions` (or checked in `finish`
    /// through `max_index`).
    pub(crate) triangles: Vec<[u32; 3]>,
    /// Per-vertex sums of the normals the file gave (zero where none).
    pub(crate) file_normals: Vec<[f64; 3]>,
    pub(crate) faces: usize,
    /// The largest vertex index used and where, for formats whose faces may precede vertices.
    pub(crate) max_index: Option<(u32, String)>,
    /// What the format adds to a 0-based index when it shows one (1 for OBJ).
    pub(crate) index_base: u32,
}

impl Builder {
    /// Fan-triangulates one polygon of checked indices. Fewer than 3 corners is a syntax error
    /// the caller reports; here it only adds nothing.
    pub(crate) fn polygon(&mut self, idx: &[u32]) {
        self.faces += 1;
        if let Some((&first, rest)) = idx.split_first() {
            for w in rest.windows(2) {
                self.triangles.push([first, w[0], w[1]]);
            }
        }
    }

    /// Records a use of vertex `i` at `at` for the range check in `finish`.
    pub(crate) fn note_index(&mut self, i: u32, at: impl FnOnce() -> String) {
        if self.max_index.as_ref().is_none_or(|(m, _)| i > *m) {
            self.max_index = Some((i, at()));
        }
    }

    pub(crate) fn finish(self, ctx: Ctx<'_>, encoding: ModelEncoding) -> Result<Model, MeshError> {
        let Self { positions, triangles, mut file_normals, faces, max_index, index_base } = self;
        let n = positions.len();
        if let Some((m, at)) = max_index
            && m as usize >= n
        {
            return Err(ctx.index(at, i64::from(m) + i64::from(index_base), n));
        }
        if n > MAX_MODEL_ELEMENTS {
            return Err(MeshError::TooLarge {
                file: ctx.file.to_owned(),
                what: "vertices",
                count: n,
                max: MAX_MODEL_ELEMENTS,
            });
        }
        if triangles.is_empty() {
            return Err(MeshError::Empty {
                file: ctx.file.to_owned(),
                detail: format!("{n} vertices and no faces"),
            });
        }
        let triangles_read = triangles.len();
        let kept: Vec<[u32; 3]> = triangles
            .into_iter()
            .filter(|t| {
                let [a, b, c] = *t;
                a != b && b != c && a != c && {
                    let p = |i: u32| DVec3::from_array(positions[i as usize]);
                    (p(b) - p(a)).cross(p(c) - p(a)) != DVec3::ZERO
                }
            })
            .collect();
        let degenerate = triangles_read - kept.len();
        if kept.is_empty() {
            return Err(MeshError::Empty {
                file: ctx.file.to_owned(),
                detail: format!("all {triangles_read} triangles are degenerate"),
            });
        }
        if kept.len() > MAX_MODEL_ELEMENTS {
            return Err(MeshError::TooLarge {
                file: ctx.file.to_owned(),
                what: "triangles",
                count: kept.len(),
                max: MAX_MODEL_ELEMENTS,
            });
        }

        // Keep used vertices in file order so the output does not depend on anything but the
        // file.
        let mut remap = vec![u32::MAX; n];
        for t in &kept {
            for &i in t {
                remap[i as usize] = 0;
            }
        }
        let mut new_positions = Vec::new();
        let mut new_file_normals = Vec::new();
        file_normals.resize(n, [0.0; 3]);
        for (i, r) in remap.iter_mut().enumerate() {
            if *r == 0 {
                *r = new_positions.len() as u32;
                new_positions.push(positions[i]);
                new_file_normals.push(file_normals[i]);
            }
        }
        let unreferenced = n - new_positions.len();
        let triangles: Vec<[u32; 3]> =
            kept.iter().map(|t| [remap[t[0] as usize], remap[t[1] as usize], remap[t[2] as usize]]).collect();

        // Area-weighted vertex normals: the cross product's length is twice the area.
        let computed = crate::geom::vertex_normal_sums(&new_positions, &triangles);
        let mut normals_from_file = 0;
        let normals = new_file_normals
            .iter()
            .zip(&computed)
            .map(|(f, c)| {
                if let Some(n) = unit_f32(DVec3::from_array(*f)) {
                    normals_from_file += 1;
                    n
                } else {
                    // Opposite faces meeting at a vertex can cancel; +Z stands in then.
                    unit_f32(*c).unwrap_or([0.0, 0.0, 1.0])
                }
            })
            .collect();

        Ok(Model {
            encoding,
            mesh: Mesh { positions: new_positions, triangles },
            normals,
            stats: ModelStats {
                faces,
                triangles_read,
                degenerate,
                vertices_read: n,
                unreferenced,
                normals_from_file,
            },
        })
    }
}

/// Splits text into (1-based line number, line without its end) pairs, `\n` or `\r\n`.
pub(crate) fn lines(bytes: &[u8]) -> impl Iterator<Item = (usize, &[u8])> {
    bytes.split(|&b| b == b'\n').enumerate().map(|(i, l)| (i + 1, l.strip_suffix(b"\r").unwrap_or(l)))
}

/// Whitespace-separated tokens of one line.
pub(crate) fn tokens(line: &[u8]) -> impl Iterator<Item = &[u8]> {
    line.split(u8::is_ascii_whitespace).filter(|t| !t.is_empty())
}

/// A token as a float (any Rust float syntax, so `nan` and `inf` parse and are rejected later
/// by the finiteness check with a clearer message).
pub(crate) fn float(t: &[u8]) -> Option<f64> {
    std::str::from_utf8(t).ok()?.parse().ok()
}

/// A token as a signed integer.
pub(crate) fn int(t: &[u8]) -> Option<i64> {
    std::str::from_utf8(t).ok()?.parse().ok()
}

/// Shows a token in an error message, shortened and with non-text bytes escaped.
pub(crate) fn show(t: &[u8]) -> String {
    let s = String::from_utf8_lossy(&t[..t.len().min(40)]).into_owned();
    if t.len() > 40 { format!("{s:?}…") } else { format!("{s:?}") }
}

#[cfg(test)]
mod tests;
