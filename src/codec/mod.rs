//! Blob format (CONTRACT STUB; the helper replaces the bodies).

use crate::geom::{Bounds, Errors, Mesh, PointCloud};
use crate::tiling::TileKey;

pub const FORMAT_VERSION: u16 = 1;

#[derive(Debug, Clone, Copy, PartialEq, Eq, bincode::Encode, bincode::Decode)]
pub enum Kind {
    Mesh,
    Points,
}

/// Quantization steps in world units.
#[derive(Debug, Clone, Copy, PartialEq, bincode::Encode, bincode::Decode)]
pub struct Quantization {
    pub xy_step: f64,
    pub z_step: f64,
}

#[derive(Debug, Clone, PartialEq, bincode::Encode, bincode::Decode)]
pub struct BlobHeader {
    pub version: u16,
    pub kind: Kind,
    pub key: TileKey,
    pub level: u8,
    pub bounds: [[f64; 3]; 2],
    pub quant: Quantization,
    pub vertex_count: u32,
    pub triangle_count: u32,
    pub errors: Errors,
    pub payload_len: u32,
    pub checksum: u32,
}

#[derive(Debug, Clone, PartialEq)]
pub enum Geometry {
    Mesh(Mesh),
    Points(PointCloud),
}

#[derive(Debug, Clone, PartialEq)]
pub struct Blob {
    pub header: BlobHeader,
    pub geometry: Geometry,
}

#[derive(Debug, thiserror::Error)]
pub enum CodecError {
    #[error("blob: {0}")]
    Invalid(String),
}

/// Snaps positions to the quantization grid relative to `bounds.min` (what decode returns).
#[must_use]
pub fn quantize_positions(positions: &[[f64; 3]], bounds: &Bounds, q: Quantization) -> Vec<[f64; 3]> {
    positions
        .iter()
        .map(|p| {
            let s = [q.xy_step, q.xy_step, q.z_step];
            std::array::from_fn(|a| bounds.min[a] + ((p[a] - bounds.min[a]) / s[a]).round() * s[a])
        })
        .collect()
}

pub fn encode_mesh(
    _key: TileKey,
    _level: u8,
    _bounds: &Bounds,
    _q: Quantization,
    _mesh: &Mesh,
    _errors: Errors,
) -> Result<Vec<u8>, CodecError> {
    Err(CodecError::Invalid("stub".into()))
}

pub fn encode_points(
    _key: TileKey,
    _level: u8,
    _bounds: &Bounds,
    _q: Quantization,
    _points: &PointCloud,
    _errors: Errors,
) -> Result<Vec<u8>, CodecError> {
    Err(CodecError::Invalid("stub".into()))
}

pub fn decode_header(_bytes: &[u8]) -> Result<BlobHeader, CodecError> {
    Err(CodecError::Invalid("stub".into()))
}

pub fn decode(_bytes: &[u8]) -> Result<Blob, CodecError> {
    Err(CodecError::Invalid("stub".into()))
}
