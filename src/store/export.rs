//! Writers for decoded geometry in common interchange formats (PLY, OBJ), so any (tile, level)
//! can be opened in `MeshLab`, `CloudCompare` or Blender. Writes to any `io::Write`.

use std::io::{self, Write};

use crate::geom::{Mesh, PointCloud};

/// Interchange formats `export` writes.
#[cfg_attr(feature = "cli", derive(clap::ValueEnum))]
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Format {
    /// Binary little-endian PLY: positions as doubles (world coordinates need them), normals as
    /// floats, faces as uchar-counted int lists.
    Ply,
    /// Wavefront OBJ text: `v`, `vn` (points) and `f` (mesh) lines.
    Obj,
}

pub fn write_mesh(mesh: &Mesh, format: Format, out: &mut dyn Write) -> io::Result<()> {
    match format {
        Format::Ply => {
            write!(
                out,
                "ply\nformat binary_little_endian 1.0\ncomment terrastream mesh\nelement vertex {}\n\
                 property double x\nproperty double y\nproperty double z\nelement face {}\n\
                 property list uchar int vertex_indices\nend_header\n",
                mesh.positions.len(),
                mesh.triangles.len()
            )?;
            let mut buf = Vec::with_capacity(mesh.positions.len() * 24 + mesh.triangles.len() * 13);
            for p in &mesh.positions {
                for c in p {
                    buf.extend_from_slice(&c.to_le_bytes());
                }
            }
            for t in &mesh.triangles {
                buf.push(3);
                for &i in t {
                    buf.extend_from_slice(&(i as i32).to_le_bytes());
                }
            }
            out.write_all(&buf)
        }
        Format::Obj => {
            let mut w = io::BufWriter::new(out);
            writeln!(
                w,
                "# terrastream mesh: {} vertices, {} triangles",
                mesh.positions.len(),
                mesh.triangles.len()
            )?;
            for p in &mesh.positions {
                writeln!(w, "v {} {} {}", p[0], p[1], p[2])?;
            }
            for t in &mesh.triangles {
                writeln!(w, "f {} {} {}", t[0] + 1, t[1] + 1, t[2] + 1)?;
            }
            w.flush()
        }
    }
}

pub fn write_points(points: &PointCloud, format: Format, out: &mut dyn Write) -> io::Result<()> {
    match format {
        Format::Ply => {
            write!(
                out,
                "ply\nformat binary_little_endian 1.0\ncomment terrastream points\nelement vertex {}\n\
                 property double x\nproperty double y\nproperty double z\n\
                 property float nx\nproperty float ny\nproperty float nz\nend_header\n",
                points.positions.len()
            )?;
            let mut buf = Vec::with_capacity(points.positions.len() * 36);
            for (p, n) in points.positions.iter().zip(&points.normals) {
                for c in p {
                    buf.extend_from_slice(&c.to_le_bytes());
                }
                for c in n {
                    buf.extend_from_slice(&c.to_le_bytes());
                }
            }
            out.write_all(&buf)
        }
        Format::Obj => {
            let mut w = io::BufWriter::new(out);
            writeln!(
                w,
                "# terrastream points: {} (v and vn lines pair up by order)",
                points.positions.len()
            )?;
            for (p, n) in points.positions.iter().zip(&points.normals) {
                writeln!(w, "v {} {} {}", p[0], p[1], p[2])?;
                writeln!(w, "vn {} {} {}", n[0], n[1], n[2])?;
            }
            w.flush()
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ply_mesh_layout() {
        let mesh =
            Mesh { positions: vec![[0.0; 3], [1.0, 0.0, 0.0], [0.0, 1.0, 2.0]], triangles: vec![[0, 1, 2]] };
        let mut out = Vec::new();
        write_mesh(&mesh, Format::Ply, &mut out).unwrap();
        let header_end = out.windows(11).position(|w| w == b"end_header\n").unwrap() + 11;
        assert_eq!(out.len() - header_end, 3 * 24 + 13);
        assert_eq!(&out[out.len() - 12..out.len() - 8], &0i32.to_le_bytes());
    }

    #[test]
    fn obj_points() {
        let pc = PointCloud { positions: vec![[1.5, 2.0, 3.0]], normals: vec![[0.0, 0.0, 1.0]] };
        let mut out = Vec::new();
        write_points(&pc, Format::Obj, &mut out).unwrap();
        let text = String::from_utf8(out).unwrap();
        assert!(text.contains("v 1.5 2 3\nvn 0 0 1\n"), "{text}");
    }
}

/// Errors of `export_tile`.
#[derive(Debug, thiserror::Error)]
pub enum ExportError {
    #[error(transparent)]
    Store(#[from] crate::store::StoreError),
    #[error("{path}: {source}")]
    Codec { path: std::path::PathBuf, source: crate::codec::CodecError },
    #[error("{path}: {source}")]
    Io { path: std::path::PathBuf, source: io::Error },
}

/// Decodes one (tile, level) of a tileset and writes it to `out` (atomically) in `format`.
/// Returns the number of vertices or points written.
pub fn export_tile(
    store: &crate::store::Store,
    key: crate::tiling::TileKey,
    level: u8,
    format: Format,
    out: &std::path::Path,
) -> Result<usize, ExportError> {
    use crate::codec::{Geometry, decode};
    let path = store.blob_path(key, level);
    let Some(bytes) = store.read_blob(key, level)? else {
        return Err(if store.is_unpaid(key, level)? {
            crate::store::StoreError::LevelNotStored { path: store.dir().to_owned(), key, level }
        } else {
            crate::store::StoreError::NoSuchTile { path: store.dir().to_owned(), key, level }
        }
        .into());
    };
    let blob = decode(&bytes).map_err(|source| ExportError::Codec { path: path.clone(), source })?;
    let mut buf = Vec::new();
    let count = match &blob.geometry {
        Geometry::Mesh(m) => {
            write_mesh(m, format, &mut buf)
                .map_err(|source| ExportError::Io { path: out.to_owned(), source })?;
            m.positions.len()
        }
        Geometry::Points(p) => {
            write_points(p, format, &mut buf)
                .map_err(|source| ExportError::Io { path: out.to_owned(), source })?;
            p.positions.len()
        }
    };
    crate::store::write_atomic(out, &buf)?;
    Ok(count)
}

/// The file beside a tileset's manifest that places it on the globe (`--anchor` of `bake` and
/// `bake-model`): `{"anchor": {"lon": …, "lat": …, "height": …}}`. Not part of the baked content
/// (no blob depends on it), so it can be set or changed without a re-bake.
pub const PLACEMENT_FILE: &str = "placement.json";

#[derive(serde::Serialize, serde::Deserialize)]
struct PlacementRecord {
    anchor: crate::tiles3d::Anchor,
}

/// Records the tileset's anchor ([`PLACEMENT_FILE`]), atomically.
pub fn write_anchor(
    store: &crate::store::Store,
    anchor: crate::tiles3d::Anchor,
) -> Result<(), crate::store::StoreError> {
    let path = store.dir().join(PLACEMENT_FILE);
    let mut bytes = serde_json::to_vec_pretty(&PlacementRecord { anchor })
        .map_err(|source| crate::store::StoreError::Json { path: path.clone(), source })?;
    bytes.push(b'\n');
    store.write_file(PLACEMENT_FILE, &bytes)
}

/// The tileset's recorded anchor; `Ok(None)` when it has none. A record that cannot be read or
/// holds an anchor out of range is an error naming the file.
pub fn read_anchor(
    store: &crate::store::Store,
) -> Result<Option<crate::tiles3d::Anchor>, crate::store::StoreError> {
    let path = store.dir().join(PLACEMENT_FILE);
    let Some(bytes) = store.read_file(PLACEMENT_FILE)? else { return Ok(None) };
    let r: PlacementRecord = serde_json::from_slice(&bytes)
        .map_err(|source| crate::store::StoreError::Json { path: path.clone(), source })?;
    r.anchor.check().map_err(|message| crate::store::StoreError::Invalid {
        path,
        message: format!("anchor: {message}"),
    })?;
    Ok(Some(r.anchor))
}

/// The 3D Tiles view of a tileset directory: its manifest, kind and placement, as the server
/// and `export --format 3dtiles` build it.
pub fn tiles3d_info(
    store: &crate::store::Store,
    name: &str,
    anchor: Option<crate::tiles3d::Anchor>,
    query: String,
) -> Result<crate::tiles3d::TilesetInfo, crate::store::StoreError> {
    // Checks the format and version; the kind and a model's levels come from the raw JSON.
    store.manifest()?;
    let path = store.manifest_path();
    let bytes = store.read_file(crate::store::MANIFEST_FILE)?.ok_or_else(|| {
        crate::store::StoreError::Invalid { path: path.clone(), message: "no manifest".into() }
    })?;
    let anchor = match anchor {
        Some(a) => Some(a),
        None => read_anchor(store)?,
    };
    crate::tiles3d::TilesetInfo::from_manifest_json(name, &bytes, anchor, query)
        .map_err(|message| crate::store::StoreError::Invalid { path, message })
}

/// The GLB of one stored (tile, level), from its verified blob.
#[must_use]
pub fn tile_glb(info: &crate::tiles3d::TilesetInfo, blob: &crate::codec::Blob) -> Vec<u8> {
    let skirt = (info.kind == crate::store::TilesetKind::Terrain
        && blob.header.kind == crate::codec::Kind::Mesh)
        .then(|| (crate::tiles3d::mesh_skirt_depth(blob.header.errors.max), Some(&info.manifest.bounds)));
    crate::tiles3d::glb(blob, &info.place, skirt)
}

/// What `export --format 3dtiles` wrote.
#[derive(Debug, Clone, Copy, Default)]
pub struct Tiles3dExport {
    /// Tileset JSON files (the root and one per index chunk below it).
    pub documents: u64,
    pub glbs: u64,
    pub glb_bytes: u64,
    /// The blobs the GLBs were made from.
    pub blob_bytes: u64,
}

/// Writes a complete tileset as static 3D Tiles 1.1 into `out` (`tileset.json`,
/// `index/{z}/{x}/{y}.json`, `tiles/{z}/{x}/{y}/{level}.glb`), the same documents the server
/// gives at `/tilesets/{name}/3dtiles/` without the `?v=` queries. Everything is written into a
/// staging directory beside `out` and renamed into place when complete, so `out` is never
/// half-written; `out` must not exist or be empty. Every blob is verified first.
/// `progress(done, total)` counts GLBs.
pub fn export_3dtiles(
    store: &crate::store::Store,
    out: &std::path::Path,
    anchor: Option<crate::tiles3d::Anchor>,
    progress: &(dyn Fn(u64, u64) + Sync),
) -> Result<Tiles3dExport, ExportError> {
    use rayon::prelude::*;
    use std::sync::atomic::{AtomicU64, Ordering};

    use crate::store::{StoreError, TilesetKind, chunk_root};

    let io_err = |path: &std::path::Path| {
        let path = path.to_owned();
        move |source| ExportError::Io { path, source }
    };
    if !store.has_manifest()? {
        return Err(StoreError::Invalid {
            path: store.dir().to_owned(),
            message: "no tileset.json: not a complete tileset (finish or resume its bake first)".into(),
        }
        .into());
    }
    if out.exists() {
        let empty = out.is_dir() && std::fs::read_dir(out).map_err(io_err(out))?.next().is_none();
        if !empty {
            return Err(ExportError::Io {
                path: out.to_owned(),
                source: io::Error::new(
                    io::ErrorKind::AlreadyExists,
                    "exists and is not an empty directory; choose another --out",
                ),
            });
        }
    }
    let name = store.name().unwrap_or_else(|| "tileset".to_owned());
    let info = tiles3d_info(store, &name, anchor, String::new())?;
    // The chunks, from the root down (each read once; bounded by the pyramid).
    let mut chunks = Vec::new();
    let mut roots = vec![crate::tiling::TileKey::new(0, 0, 0)];
    while let Some(root) = roots.pop() {
        let chunk = store.chunk(root)?;
        if info.kind == TilesetKind::Terrain
            && let Some(p) = info.pyramid
        {
            let last = root.z.saturating_add(crate::store::SUBTREE_LEVELS - 1);
            for n in &chunk.nodes {
                if n.key.z == last && chunk_root(n.key) == root {
                    roots.extend(p.children(n.key).into_iter().filter(|c| p.contains(*c)));
                }
            }
        }
        chunks.push(chunk);
    }
    let parent = out.parent().filter(|p| !p.as_os_str().is_empty()).unwrap_or(std::path::Path::new("."));
    std::fs::create_dir_all(parent).map_err(io_err(parent))?;
    let stage = parent.join(format!(
        ".{}.partial-{}",
        out.file_name().map_or_else(|| "export".into(), |n| n.to_string_lossy().into_owned()),
        std::process::id()
    ));
    let result = (|| {
        if stage.exists() {
            std::fs::remove_dir_all(&stage).map_err(io_err(&stage))?;
        }
        let mut docs = 0u64;
        for c in &chunks {
            let root = c.root.z == 0;
            let path = if root {
                stage.join("tileset.json")
            } else {
                stage.join(format!("index/{}/{}/{}.json", c.root.z, c.root.x, c.root.y))
            };
            let mut bytes =
                serde_json::to_vec(&crate::tiles3d::chunk_tileset(&info, c, root)).unwrap_or_default();
            bytes.push(b'\n');
            write_file(&path, &bytes).map_err(io_err(&path))?;
            docs += 1;
        }
        let work: Vec<(crate::tiling::TileKey, u8)> = chunks
            .iter()
            .flat_map(|c| &c.nodes)
            .flat_map(|n| n.levels.iter().map(move |l| (n.key, l.level)))
            .collect();
        let total = work.len() as u64;
        let done = AtomicU64::new(0);
        let glb_bytes = AtomicU64::new(0);
        let blob_bytes = AtomicU64::new(0);
        work.par_iter().try_for_each(|&(key, level)| -> Result<(), ExportError> {
            let path = store.blob_path(key, level);
            let bytes = store.read_blob(key, level)?.ok_or_else(|| StoreError::NoSuchTile {
                path: store.dir().to_owned(),
                key,
                level,
            })?;
            let blob = crate::codec::decode(&bytes)
                .map_err(|source| ExportError::Codec { path: path.clone(), source })?;
            if blob.header.key != key || blob.header.level != level {
                return Err(StoreError::Invalid {
                    path,
                    message: format!(
                        "the blob's header names tile {} level {}",
                        blob.header.key, blob.header.level
                    ),
                }
                .into());
            }
            let glb = tile_glb(&info, &blob);
            let dest = stage.join(format!("tiles/{}/{}/{}/{level}.glb", key.z, key.x, key.y));
            write_file(&dest, &glb).map_err(io_err(&dest))?;
            glb_bytes.fetch_add(glb.len() as u64, Ordering::Relaxed);
            blob_bytes.fetch_add(bytes.len() as u64, Ordering::Relaxed);
            progress(done.fetch_add(1, Ordering::Relaxed) + 1, total);
            Ok(())
        })?;
        if out.exists() {
            std::fs::remove_dir(out).map_err(io_err(out))?;
        }
        std::fs::rename(&stage, out).map_err(io_err(out))?;
        Ok(Tiles3dExport {
            documents: docs,
            glbs: total,
            glb_bytes: glb_bytes.into_inner(),
            blob_bytes: blob_bytes.into_inner(),
        })
    })();
    if result.is_err() {
        let _ = std::fs::remove_dir_all(&stage);
    }
    result
}

/// Writes a file of the staging directory (its folders created); the directory as a whole is
/// what is published atomically.
fn write_file(path: &std::path::Path, bytes: &[u8]) -> io::Result<()> {
    if let Some(d) = path.parent() {
        std::fs::create_dir_all(d)?;
    }
    std::fs::write(path, bytes)
}
