//! PLY and OBJ files of decoded geometry, so any (tile, level) can be opened in `MeshLab`,
//! `CloudCompare` or Blender. Pure: geometry in, the file's bytes out.

use std::fmt::Write as _;

use crate::geom::{Mesh, PointCloud};

/// Interchange formats `export` writes.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Format {
    /// Binary little-endian PLY: positions as doubles (world coordinates need them), normals as
    /// floats, faces as uchar-counted int lists.
    Ply,
    /// Wavefront OBJ text: `v`, `vn` (points) and `f` (mesh) lines.
    Obj,
}

impl Format {
    /// The format a file name's extension names (`.ply`, `.obj`, any case); `None` for any other.
    #[must_use]
    pub fn from_extension(path: &std::path::Path) -> Option<Self> {
        let ext = path.extension()?.to_str()?.to_ascii_lowercase();
        match ext.as_str() {
            "ply" => Some(Self::Ply),
            "obj" => Some(Self::Obj),
            _ => None,
        }
    }
}

/// The file of a mesh in `format`.
#[must_use]
pub fn mesh_bytes(mesh: &Mesh, format: Format) -> Vec<u8> {
    match format {
        Format::Ply => {
            let header = format!(
                "ply\nformat binary_little_endian 1.0\ncomment terrastream mesh\nelement vertex {}\n\
                 property double x\nproperty double y\nproperty double z\nelement face {}\n\
                 property list uchar int vertex_indices\nend_header\n",
                mesh.positions.len(),
                mesh.triangles.len()
            );
            let mut buf =
                Vec::with_capacity(header.len() + mesh.positions.len() * 24 + mesh.triangles.len() * 13);
            buf.extend_from_slice(header.as_bytes());
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
            buf
        }
        Format::Obj => {
            let mut w = String::new();
            // Writing to a String cannot fail.
            let _ = writeln!(
                w,
                "# terrastream mesh: {} vertices, {} triangles",
                mesh.positions.len(),
                mesh.triangles.len()
            );
            for p in &mesh.positions {
                let _ = writeln!(w, "v {} {} {}", p[0], p[1], p[2]);
            }
            for t in &mesh.triangles {
                let _ = writeln!(w, "f {} {} {}", t[0] + 1, t[1] + 1, t[2] + 1);
            }
            w.into_bytes()
        }
    }
}

/// The file of a point cloud (positions and normals) in `format`.
#[must_use]
pub fn points_bytes(points: &PointCloud, format: Format) -> Vec<u8> {
    match format {
        Format::Ply => {
            let header = format!(
                "ply\nformat binary_little_endian 1.0\ncomment terrastream points\nelement vertex {}\n\
                 property double x\nproperty double y\nproperty double z\n\
                 property float nx\nproperty float ny\nproperty float nz\nend_header\n",
                points.positions.len()
            );
            let mut buf = Vec::with_capacity(header.len() + points.positions.len() * 36);
            buf.extend_from_slice(header.as_bytes());
            for (p, n) in points.positions.iter().zip(&points.normals) {
                for c in p {
                    buf.extend_from_slice(&c.to_le_bytes());
                }
                for c in n {
                    buf.extend_from_slice(&c.to_le_bytes());
                }
            }
            buf
        }
        Format::Obj => {
            let mut w = String::new();
            // Writing to a String cannot fail.
            let _ = writeln!(
                w,
                "# terrastream points: {} (v and vn lines pair up by order)",
                points.positions.len()
            );
            for (p, n) in points.positions.iter().zip(&points.normals) {
                let _ = writeln!(w, "v {} {} {}", p[0], p[1], p[2]);
                let _ = writeln!(w, "vn {} {} {}", n[0], n[1], n[2]);
            }
            w.into_bytes()
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
        let out = mesh_bytes(&mesh, Format::Ply);
        let header_end = out.windows(11).position(|w| w == b"end_header\n").unwrap() + 11;
        assert_eq!(out.len() - header_end, 3 * 24 + 13);
        assert_eq!(&out[out.len() - 12..out.len() - 8], &0i32.to_le_bytes());
    }

    #[test]
    fn obj_points() {
        let pc = PointCloud { positions: vec![[1.5, 2.0, 3.0]], normals: vec![[0.0, 0.0, 1.0]] };
        let text = String::from_utf8(points_bytes(&pc, Format::Obj)).unwrap();
        assert!(text.contains("v 1.5 2 3\nvn 0 0 1\n"), "{text}");
    }

    #[test]
    fn obj_mesh_is_one_based() {
        let mesh =
            Mesh { positions: vec![[0.0; 3], [1.0, 0.0, 0.0], [0.0, 1.0, 0.5]], triangles: vec![[0, 1, 2]] };
        let text = String::from_utf8(mesh_bytes(&mesh, Format::Obj)).unwrap();
        assert!(text.starts_with("# terrastream mesh: 3 vertices, 1 triangles\n"), "{text}");
        assert!(text.ends_with("v 0 1 0.5\nf 1 2 3\n"), "{text}");
    }

    #[test]
    fn formats_follow_extensions() {
        use std::path::Path;
        assert_eq!(Format::from_extension(Path::new("a/b.ply")), Some(Format::Ply));
        assert_eq!(Format::from_extension(Path::new("B.OBJ")), Some(Format::Obj));
        assert_eq!(Format::from_extension(Path::new("x.glb")), None);
        assert_eq!(Format::from_extension(Path::new("plain")), None);
    }
}
