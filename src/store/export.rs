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
    let bytes = store.read_blob(key, level)?.ok_or_else(|| {
        if store.is_unpaid(key, level) {
            crate::store::StoreError::LevelNotStored { path: store.dir().to_owned(), key, level }
        } else {
            crate::store::StoreError::NoSuchTile { path: store.dir().to_owned(), key, level }
        }
    })?;
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
