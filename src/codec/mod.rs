//! Blob format: one (tile, level) of geometry — a TIN mesh or a point cloud — as a compact,
//! versioned, checksummed byte string. Pure: bytes in, bytes out, no I/O.
//!
//! # Layout (format version 1)
//!
//! All integers are little-endian. A blob is a fixed 136-byte prefix followed by the payload:
//!
//! | offset | size | field | meaning |
//! |---:|---:|---|---|
//! | 0 | 4 | magic | `b"TSB1"` ([`MAGIC`]) |
//! | 4 | 4 | `header_len: u32` | 128 ([`HEADER_LEN`]); anything else is rejected |
//! | 8 | 2 | `version: u16` | 1 ([`FORMAT_VERSION`]); checked before the rest of the header |
//! | 10 | 4 | `kind: u32` | 0 = mesh, 1 = points |
//! | 14 | 1 | `key.z: u8` | tile key |
//! | 15 | 4 | `key.x: u32` | |
//! | 19 | 4 | `key.y: u32` | |
//! | 23 | 1 | `level: u8` | 0 = TIN mesh, 1.. = point levels |
//! | 24 | 48 | `bounds: [[f64; 3]; 2]` | min x, y, z then max x, y, z (world units) |
//! | 72 | 8 | `xy_step: f64` | quantization step of x and y |
//! | 80 | 8 | `z_step: f64` | quantization step of z |
//! | 88 | 4 | `vertex_count: u32` | mesh vertices, or points |
//! | 92 | 4 | `triangle_count: u32` | mesh triangles; 0 for points |
//! | 96 | 24 | `errors: [f64; 3]` | measured `max`, `rms`, `gap` ([`ErrorFigures`]) |
//! | 120 | 4 | `raw_len: u32` | total size of the payload's streams once decompressed |
//! | 124 | 4 | `payload_len: u32` | payload size as stored |
//! | 128 | 4 | `checksum: u32` | CRC-32 (IEEE, `crc32fast`) of the stored payload |
//! | 132 | 4 | `header_checksum: u32` | CRC-32 of bytes 0..132 |
//! | 136 | `payload_len` | payload | see below |
//!
//! Bytes 8..136 are exactly [`BlobHeader`] encoded by `bincode` 2 with fixed-width
//! little-endian integers (so `kind` is a `u32` variant index). [`decode_header`] needs only the
//! first [`PREFIX_LEN`] bytes and checks the header checksum, so a store can read the measured
//! errors without touching the payload; [`decode`] also checks that the blob is exactly
//! `136 + payload_len` bytes long and that the payload checksum matches.
//!
//! # Quantization
//!
//! Every position is stored as integers `q = round((p − bounds.min) / step)` per axis (`xy_step`
//! for x and y, `z_step` for z) and decoded as exactly `bounds.min + q · step` — the value
//! [`quantize_positions`] returns. The encoder accepts positions up to half a step outside the
//! bounds it is given (`0 ≤ q ≤ round((max − min) / step)`, at most [`MAX_QUANT`] per axis) and
//! rejects the rest; the header then states those bounds with `max` grown, where a position
//! rounded up past it, to exactly that position ([`quantized_bounds`]). So every decoded
//! position lies inside the header bounds and a client may trust them for culling; [`decode`]
//! refuses a blob with a position outside them. (`qmax = round((max − min) / step)` of the
//! header also sizes the sweep code's rows.) Blobs written before the header bounds grew
//! (terrastream 0.1.0 before the hardening release) may hold a position up to half a step past
//! their `max`: they fail to decode, and a resumed `bake` re-bakes them. Writers that want
//! positions inside fixed bounds snap them in first ([`snap_positions`]). A TIN's vertices lie on the raster grid, so
//! with `xy_step` equal to the cell size their x and y are exact.
//!
//! # Payload
//!
//! `mode: u8 | count: u8 | count × (method: u8, raw_len: u32, stored_len: u32) | stored bytes`.
//! The payload is a set of byte streams, each holding one kind of value, stored one after the
//! other; `method` 1 means the stream is one zstd frame (level [`ZSTD_LEVEL`]), 0 that it is
//! stored as is (when zstd would not shrink it). The `raw_len`s add up to the header's.
//!
//! Values are coded as *varints* (unsigned LEB128), *signed* varints (zigzag, then LEB128), or
//! *bucketed* into a pair of streams: a symbol byte and verbatim low bits (LSB first, last byte
//! zero-padded). For an unsigned `u` (signed values are zigzagged first) the symbol is `u` when
//! `u < 4`, else `4 + 4·(b − 3) + t` with `b` the bit length of `u` and `t` the two bits below
//! its leading one; the `b − 3` remaining low bits go to the bit stream. This keeps the skewed
//! part of residuals in bytes zstd codes near their entropy.
//!
//! **Mesh, modes 0 and 1 ("sweep", for planar TINs).** Vertices are sorted by `(qy, qx)` (x, y
//! must be distinct). Streams: `gaps` (varint per vertex: the increase of
//! `qy·(qmax_x + 1) + qx` over the previous vertex, the first its value), `runs` (varint `k`
//! per vertex), `positions` (signed varint `d` per vertex), `z` and `z bits` (bucketed signed
//! residual per vertex). Connectivity is rebuilt by a sweep that keeps a *front*, a list of
//! vertices (possibly repeated). For vertex `v`, `p = anchor + d` where `anchor` is a front index
//! derived from the geometry (`mesh::anchor`: the front edge right below `v`, or the previous
//! vertex's index); then `k = 0` inserts `v` at `p`; `k = 1` hangs `v` from `w = f[p]`, which
//! becomes `w, v, w`; `k ≥ 2` closes the `k − 1` triangles over `f[p..p+k]` (emitted
//! `[f[i], f[i+1], v]` in mode 0, `[f[i+1], f[i], v]` in mode 1) and replaces the interior
//! `f[p+1..p+k−1]` by `v`. z is the residual from a prediction (`mesh::predict_z`): the mean of
//! the planes through each closed triangle's neighbour across its front edge, evaluated at `v`'s
//! x, y; without such neighbours the mean z of the front vertices it joins, else the previous
//! vertex's z. The anchor and the predictor are part of the format.
//!
//! **Mesh, mode 2 ("general", any indexed mesh).** Triangles in a depth-first order over shared
//! edges (chosen by the encoder), vertices numbered by first use. Streams: `codes` (a byte per triangle), `fifo` (bytes), `explicit` (varints), and
//! bucketed signed residuals for `x`, `y`, `z` (two streams each). A 16-entry FIFO of recent
//! directed edges and one of recent vertices are kept: code `c < 48` means the triangle shares
//! the reverse of FIFO edge `c % 16` and its third vertex is new (`c / 16 = 0`), a vertex FIFO
//! entry (`1`, index in `fifo`) or an explicit index (`2`, `next − 1 − index` in `explicit`);
//! codes `48..75` give the three vertices' classes in base 3. New vertices are predicted by the
//! parallelogram rule across the shared edge, or by the previous new vertex; unreferenced
//! vertices follow at the end.
//!
//! **Points, mode 0.** Streams: `params` (varints: per-axis base and stride of the quantized
//! coordinates — their minimum and the GCD of the offsets from it, so points on a lattice cost
//! nothing for the lattice — and a shift `s ≤ 8`), `rows` (per occupied cell row: row delta,
//! cells − 1), `cells` (per cell: x delta), `counts` (per cell: points − 1), `fine x`, `fine y`
//! (a byte per point, only when `s > 0`), `z` and `z bits` (bucketed signed residuals of each
//! cell's first point), `stacked z` (signed varint residuals of the other points), `nu`, `nv`
//! and `stacked nu`, `stacked nv` (octahedral normal bytes as wrapping residuals, first and
//! other points). Lattice x, y are split into a cell (`>> s`) and a fine part; points are sorted
//! by (cell y, cell x, z, fine y, fine x, normal). A cell's first (lowest) point is predicted
//! from the first points of the cells left, above and above-left (z: median edge detector;
//! normal: mean of left and above), the others from the point below them in the cell (z: plus
//! the last rise seen between stacked points). Stacked points get their own streams because
//! their residuals are mostly zero, which zstd codes far better apart.
//!
//! **Points, mode 1 ("context").** One stored stream, `points coded`: varints `base[3]`,
//! `stride[3]` (as in mode 0), the cell shift `s ≤ 8`, `phase[3]` (each `< 2^s`) and
//! `scale[2]` (`≤ 2^24`), then the bytes of an adaptive binary range coder
//! (`rangecoder`: LZMA's coder without its always-zero first byte, 12-bit probabilities whose
//! adaptation shift grows from 2 to 5 over a context's first 15 uses, integer arithmetic only),
//! zero-padded to at least `⌈count / 16⌉` bytes so a decoder can check the header's point count
//! against them before allocating. `s` is the largest shift that leaves at least `count / 2`
//! occupied cells; adding `phase` to the lattice x, y puts each axis's most common offset at a
//! cell's centre `2^(s−1)` (voxel points then fall one to a cell), and `phase[2]` does the same
//! for z, marking the slice centres. `scale` is `stride_z · z_step / (stride_a · xy_step)` in
//! units of 2^−12 for a = x, y. Points are sorted by (cell y, cell x, z, fine y, fine x, normal)
//! and coded in three passes: occupancy (per row: rows skipped, first column against the
//! previous row's, cell count against the previous row's, column gaps, then points − 1 per
//! cell); positions (per cell: the first point's z from the median edge detector of the left,
//! above and above-left cells' first points, in 16 contexts of their activity; then per axis a
//! flag "fine offset = centre" and otherwise the offset's residual from the prediction
//! `centre + (z_c − z) · d / dz`, `z_c` the slice centre and `dz / d` the slope towards the left
//! (above) neighbour; the cell's other points: fine offsets as symbols and z as the rise over
//! the point below); normals (per cell: the first point's octahedral pair against the pair of
//! the gradient normal `(−dz_x · scale_x · d_y, −dz_y · scale_y · d_x, d_x · d_y · 2^12)` from
//! the left/right and above/below cells' first points, in contexts of those neighbours'
//! residuals; the other points against the point below). Signed values are a zero flag, a
//! sign, the Exp-Golomb class in unary and two mantissa bits adaptive, the rest direct. The
//! models, their contexts and the predictions are part of the format
//! (`points::context`).
//!
//! # Order
//!
//! Decoding returns the same geometry, not the same order: mesh vertices come back sorted as
//! described above and triangles may be reordered and cyclically rotated (winding is always
//! kept); points come back sorted. Normals come back as their 8+8-bit octahedral values
//! ([`quantize_normals`]). Encoding is deterministic: equal inputs give byte-identical blobs.
//! A points encoder writes whichever of modes 0 and 1 is smaller (mode 1 on terrain levels);
//! both modes decode to the same quantized values, mode 1's points sorted by its phased cells.
//!
//! # Errors
//!
//! Every function returns [`CodecError`]; decoding any byte string returns `Ok` or `Err`, never
//! panics, and allocates in proportion to the bytes actually present (counts are capped by
//! [`MAX_ELEMENTS`] and checked against stream sizes — a mode 1 points payload holds a byte per
//! 16 points at least; each zstd frame is decompressed incrementally up to its declared size;
//! `raw_len` ≤ [`MAX_RAW_LEN`]). The range decoder reads zeros past its bytes and then fails;
//! every loop it runs is bounded by the point count or a constant.

mod mesh;
mod points;
mod rangecoder;
mod stream;
#[cfg(test)]
mod testdata;

use crate::geom::{Bounds, ErrorFigures, Mesh, PointCloud};
use crate::tiling::TileKey;

pub use points::{oct_decode, oct_encode, quantize_normals};

/// First four bytes of every blob.
pub const MAGIC: [u8; 4] = *b"TSB1";
/// The format version this code writes and reads.
pub const FORMAT_VERSION: u16 = 1;
/// Size of the bincode-encoded [`BlobHeader`].
pub const HEADER_LEN: usize = 128;
/// Bytes [`decode_header`] needs: magic, header length and header.
pub const PREFIX_LEN: usize = 8 + HEADER_LEN;
/// Most vertices, triangles or points one blob may hold (bounds what decoding allocates).
pub const MAX_ELEMENTS: u32 = 1 << 24;
/// Largest decompressed payload accepted (256 MiB).
pub const MAX_RAW_LEN: u32 = 1 << 28;
/// Most bytes a payload's stream table takes beyond its streams: mode, count and 9 bytes per
/// stream. A stream is stored as is when zstd would not shrink it, so a payload is never more
/// than this larger than its decompressed size.
pub const PAYLOAD_TABLE_MAX: u32 = 2 + 9 * stream::MAX_STREAMS as u32;
/// Largest stored payload the format allows ([`MAX_RAW_LEN`] and its stream table): with
/// [`PREFIX_LEN`], the most bytes a reader ever needs to take of one blob.
pub const MAX_PAYLOAD_LEN: u32 = MAX_RAW_LEN + PAYLOAD_TABLE_MAX;
/// Largest quantized coordinate per axis; keeps every delta and product in range.
pub const MAX_QUANT: i64 = (1 << 31) - 1;
/// zstd level of the payload streams. Fixed so output is reproducible. The streams are already
/// decorrelated, so what matters is zstd's entropy stage, not its match search: level 15 was
/// within 1 % of level 19, and level 7 is 3–7 % larger than 15 while a whole bake of a
/// 2049² raster ran 1.5× faster (compression dominated it); zstd decodes at the same speed
/// whatever the level.
pub const ZSTD_LEVEL: i32 = 7;
/// Largest zstd window accepted when decoding (levels up to 19 never use more than 2^23).
pub(crate) const ZSTD_WINDOW_LOG_MAX: u32 = 24;

/// What a blob holds, and so what its level is (`"mesh"` or `"points"` in manifests).
#[derive(
    Debug, Clone, Copy, PartialEq, Eq, bincode::Encode, bincode::Decode, serde::Serialize, serde::Deserialize,
)]
#[serde(rename_all = "lowercase")]
pub enum Kind {
    Mesh,
    Points,
}

impl Kind {
    /// `"mesh"` or `"points"`, as manifests and tables write it.
    #[must_use]
    pub fn as_str(self) -> &'static str {
        match self {
            Self::Mesh => "mesh",
            Self::Points => "points",
        }
    }
}

impl std::fmt::Display for Kind {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.pad(self.as_str())
    }
}

/// Quantization steps in world units.
#[derive(Debug, Clone, Copy, PartialEq, bincode::Encode, bincode::Decode)]
pub struct Quantization {
    pub xy_step: f64,
    pub z_step: f64,
}

/// The fixed header of a blob (see the module docs for its byte layout).
#[derive(Debug, Clone, PartialEq, bincode::Encode, bincode::Decode)]
pub struct BlobHeader {
    pub version: u16,
    pub kind: Kind,
    pub key: TileKey,
    pub level: u8,
    pub bounds: [[f64; 3]; 2],
    pub quant: Quantization,
    /// Mesh vertices, or points.
    pub vertex_count: u32,
    /// Mesh triangles; 0 for points.
    pub triangle_count: u32,
    pub errors: ErrorFigures,
    /// Total size of the payload's streams once decompressed.
    pub raw_len: u32,
    /// Payload size as stored.
    pub payload_len: u32,
    /// CRC-32 of the stored payload.
    pub checksum: u32,
    /// CRC-32 of the blob's bytes before this field (magic, header length, header).
    pub header_checksum: u32,
}

impl BlobHeader {
    /// The header bounds as a [`Bounds`].
    #[must_use]
    pub fn bounds(&self) -> Bounds {
        Bounds::new(self.bounds[0], self.bounds[1])
    }

    /// Total blob size this header announces.
    #[must_use]
    pub fn blob_len(&self) -> usize {
        PREFIX_LEN + self.payload_len as usize
    }
}

/// The geometry a blob decodes to (order as described in the module docs).
#[derive(Debug, Clone, PartialEq)]
pub enum Geometry {
    Mesh(Mesh),
    Points(PointCloud),
}

/// A decoded blob.
#[derive(Debug, Clone, PartialEq)]
pub struct Blob {
    pub header: BlobHeader,
    pub geometry: Geometry,
}

#[derive(Debug, thiserror::Error)]
pub enum CodecError {
    #[error("blob: {got} bytes, need at least {needed}")]
    Truncated { needed: usize, got: usize },
    #[error("blob: {extra} bytes after the payload")]
    TrailingBytes { extra: usize },
    #[error("blob: bad magic {0:02x?} (expected \"TSB1\")")]
    BadMagic([u8; 4]),
    #[error("blob: format version {found} is not supported (this build reads {FORMAT_VERSION})")]
    UnsupportedVersion { found: u16 },
    #[error("blob: header length {0} (expected {HEADER_LEN})")]
    BadHeaderLength(u32),
    #[error("blob: header checksum {found:08x} does not match {computed:08x}")]
    HeaderChecksum { found: u32, computed: u32 },
    #[error("blob: payload checksum {found:08x} does not match {computed:08x}")]
    PayloadChecksum { found: u32, computed: u32 },
    #[error("blob: cannot decode header")]
    HeaderDecode(#[source] bincode::error::DecodeError),
    #[error("blob: cannot encode header")]
    HeaderEncode(#[source] bincode::error::EncodeError),
    #[error("blob: invalid header: {0}")]
    InvalidHeader(&'static str),
    #[error("blob: invalid bounds min {min:?} max {max:?} (need finite values, min <= max)")]
    InvalidBounds { min: [f64; 3], max: [f64; 3] },
    #[error("blob: invalid quantization steps xy {xy_step} z {z_step} (need finite steps > 0)")]
    InvalidQuantization { xy_step: f64, z_step: f64 },
    #[error("blob: axis {axis} spans {steps} quantization steps (at most {MAX_QUANT})")]
    QuantizationRange { axis: usize, steps: f64 },
    #[error("blob: position {index} is not finite: {position:?}")]
    NonFinitePosition { index: usize, position: [f64; 3] },
    #[error("blob: position {index} {position:?} lies outside the bounds")]
    OutOfBounds { index: usize, position: [f64; 3] },
    #[error("blob: triangle {triangle} refers to vertex {index}, but there are {vertex_count}")]
    IndexOutOfRange { triangle: usize, index: u32, vertex_count: usize },
    #[error("blob: {points} points but {normals} normals")]
    NormalCountMismatch { points: usize, normals: usize },
    #[error("blob: normal {index} {normal:?} is not a finite non-zero vector")]
    BadNormal { index: usize, normal: [f32; 3] },
    #[error("blob: errors {0:?} must be finite and non-negative")]
    InvalidErrors(ErrorFigures),
    #[error("blob: {count} {what} exceed the limit of {max}")]
    TooLarge { what: &'static str, count: usize, max: usize },
    #[error("blob: zstd compression failed")]
    Compress(#[source] std::io::Error),
    #[error("blob: zstd decompression failed")]
    Decompress(#[source] std::io::Error),
    #[error("blob: payload decompresses to {actual} bytes, header says {declared}")]
    RawLength { declared: usize, actual: usize },
    #[error("blob: corrupt payload ({0})")]
    Corrupt(&'static str),
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

/// Snaps positions to the quantization grid like [`quantize_positions`], then into the bounds:
/// each coordinate becomes the nearest grid value `min + q · step` with `min ≤ value ≤ max`, so
/// [`encode_points`] accepts every one. For point clouds, whose points may sit up to a cell
/// outside the surface's box (a slice's centre above the top); moving a point into a box that
/// contains the surface never takes it farther from the surface, except by the last step when
/// `max` is not on the grid. Positions that are not finite are left as they are (the encoder
/// rejects them). Errors: bounds or steps the encoder would reject.
pub fn snap_positions(
    positions: &[[f64; 3]],
    bounds: &Bounds,
    q: Quantization,
) -> Result<Vec<[f64; 3]>, CodecError> {
    let frame = QuantGrid::new(bounds, q)?;
    Ok(positions
        .iter()
        .map(|p| {
            if !p.iter().all(|v| v.is_finite()) {
                return *p;
            }
            let q: [i64; 3] = std::array::from_fn(|a| {
                let v = ((p[a] - frame.min[a]) / frame.step[a]).round();
                v.clamp(0.0, frame.qtop[a] as f64) as i64
            });
            frame.position(q)
        })
        .collect())
}

/// `bounds` with `max` grown to hold `positions` as they decode with steps `q` relative to
/// `bounds.min`: the bounds [`encode_mesh`] and [`encode_points`] write into the header. A
/// mesh's vertices cannot be moved into the bounds without opening cracks against the
/// neighbour that stores the same border vertex, so the bounds grow instead (by less than half
/// a step). Positions that are not finite, or more than half a step outside, are left for the
/// encoder to reject. Returns `bounds` unchanged when they or `q` are unusable.
#[must_use]
pub fn quantized_bounds(bounds: &Bounds, positions: &[[f64; 3]], q: Quantization) -> Bounds {
    let Ok(frame) = QuantGrid::new(bounds, q) else { return *bounds };
    let mut top = [0i64; 3];
    for p in positions {
        if let Ok(qp) = frame.quantize_within(*p, frame.qmax) {
            for a in 0..3 {
                top[a] = top[a].max(qp[a]);
            }
        }
    }
    let highest = frame.position(top);
    let mut out = *bounds;
    for (a, h) in highest.into_iter().enumerate() {
        out.max[a] = out.max[a].max(h);
    }
    out
}

/// The integer grid positions live on: origin, steps and the largest index per axis.
#[derive(Debug, Clone, Copy)]
pub(crate) struct QuantGrid {
    min: [f64; 3],
    step: [f64; 3],
    /// `round((max − min) / step)`: what decoders accept, and part of the sweep code.
    pub(crate) qmax: [i64; 3],
    /// The largest `q` whose position `min + q · step` is ≤ `max`: what encoders accept.
    qtop: [i64; 3],
}

impl QuantGrid {
    fn new(bounds: &Bounds, q: Quantization) -> Result<Self, CodecError> {
        if !bounds.is_valid() {
            return Err(CodecError::InvalidBounds { min: bounds.min.to_array(), max: bounds.max.to_array() });
        }
        let ok = |s: f64| s.is_finite() && s > 0.0;
        if !ok(q.xy_step) || !ok(q.z_step) {
            return Err(CodecError::InvalidQuantization { xy_step: q.xy_step, z_step: q.z_step });
        }
        let step = [q.xy_step, q.xy_step, q.z_step];
        let mut qmax = [0i64; 3];
        for a in 0..3 {
            let steps = ((bounds.max[a] - bounds.min[a]) / step[a]).round();
            if steps.is_nan() || steps > MAX_QUANT as f64 {
                return Err(CodecError::QuantizationRange { axis: a, steps });
            }
            qmax[a] = steps as i64;
        }
        // The float expression `position` uses decides, so the limit is exact whatever the
        // rounding of the division; two corrections at most either way.
        let qtop = std::array::from_fn(|a| {
            let at = |q: i64| bounds.min[a] + (q as f64) * step[a];
            let mut q = qmax[a];
            for _ in 0..4 {
                if q > 0 && at(q) > bounds.max[a] {
                    q -= 1;
                } else if q < MAX_QUANT && at(q + 1) <= bounds.max[a] {
                    q += 1;
                } else {
                    break;
                }
            }
            q
        });
        Ok(Self { min: bounds.min.to_array(), step, qmax, qtop })
    }

    /// The integer coordinates of `p`, which must decode inside the bounds; `index` names the
    /// position in errors.
    pub(crate) fn quantize(&self, p: [f64; 3], index: usize) -> Result<[i64; 3], CodecError> {
        self.quantize_within(p, self.qtop).map_err(|e| match e {
            CodecError::NonFinitePosition { position, .. } => {
                CodecError::NonFinitePosition { index, position }
            }
            _ => CodecError::OutOfBounds { index, position: p },
        })
    }

    /// The integer coordinates of `p` if they lie in `0..=limit` per axis.
    fn quantize_within(&self, p: [f64; 3], limit: [i64; 3]) -> Result<[i64; 3], CodecError> {
        if !p.iter().all(|v| v.is_finite()) {
            return Err(CodecError::NonFinitePosition { index: 0, position: p });
        }
        let mut q = [0i64; 3];
        for a in 0..3 {
            let v = ((p[a] - self.min[a]) / self.step[a]).round();
            // Compared as floats first so a huge value cannot saturate into range.
            if v.is_nan() || v < 0.0 || v > limit[a] as f64 {
                return Err(CodecError::OutOfBounds { index: 0, position: p });
            }
            q[a] = v as i64;
        }
        Ok(q)
    }

    /// Whether `q` is a valid quantized position (decoders check every one they build).
    pub(crate) fn contains(&self, q: [i64; 3]) -> bool {
        (0..3).all(|a| (0..=self.qmax[a]).contains(&q[a]))
    }

    /// `min + q · step`, bit-identical to [`quantize_positions`] for the same `q`.
    pub(crate) fn position(&self, q: [i64; 3]) -> [f64; 3] {
        std::array::from_fn(|a| self.min[a] + (q[a] as f64) * self.step[a])
    }
}

fn bincode_config() -> impl bincode::config::Config {
    // The limit caps what a hostile header can make the decoder allocate; the header has no
    // variable-length fields, so it never needs more than its own size.
    bincode::config::standard().with_little_endian().with_fixed_int_encoding().with_limit::<256>()
}

fn check_errors(e: ErrorFigures) -> Result<(), CodecError> {
    let ok = |v: f64| v.is_finite() && v >= 0.0;
    if ok(e.max) && ok(e.rms) && ok(e.gap) { Ok(()) } else { Err(CodecError::InvalidErrors(e)) }
}

fn check_count(what: &'static str, count: usize) -> Result<u32, CodecError> {
    u32::try_from(count).ok().filter(|&c| c <= MAX_ELEMENTS).ok_or(CodecError::TooLarge {
        what,
        count,
        max: MAX_ELEMENTS as usize,
    })
}

/// Writes magic, header and payload.
#[allow(clippy::too_many_arguments)]
fn assemble(
    kind: Kind,
    key: TileKey,
    level: u8,
    bounds: &Bounds,
    quant: Quantization,
    vertex_count: u32,
    triangle_count: u32,
    errors: ErrorFigures,
    packed: &stream::Packed,
) -> Result<Vec<u8>, CodecError> {
    let too_large =
        |count: usize| CodecError::TooLarge { what: "payload bytes", count, max: MAX_RAW_LEN as usize };
    let payload = packed.payload.as_slice();
    let raw_len =
        u32::try_from(packed.raw_len).ok().filter(|&n| n <= MAX_RAW_LEN).ok_or(too_large(packed.raw_len))?;
    let payload_len = u32::try_from(payload.len()).map_err(|_| too_large(payload.len()))?;
    let header = BlobHeader {
        version: FORMAT_VERSION,
        kind,
        key,
        level,
        bounds: [bounds.min.to_array(), bounds.max.to_array()],
        quant,
        vertex_count,
        triangle_count,
        errors,
        raw_len,
        payload_len,
        checksum: crc32fast::hash(payload),
        header_checksum: 0,
    };
    let mut out = Vec::with_capacity(PREFIX_LEN + payload.len());
    out.extend_from_slice(&MAGIC);
    out.extend_from_slice(&(HEADER_LEN as u32).to_le_bytes());
    bincode::encode_into_std_write(&header, &mut out, bincode_config()).map_err(CodecError::HeaderEncode)?;
    if out.len() != PREFIX_LEN {
        return Err(CodecError::InvalidHeader("encoded header has the wrong size"));
    }
    let crc = crc32fast::hash(&out[..PREFIX_LEN - 4]);
    out[PREFIX_LEN - 4..].copy_from_slice(&crc.to_le_bytes());
    out.extend_from_slice(payload);
    Ok(out)
}

/// Encodes a mesh; the header states `bounds` grown to hold the quantized positions
/// ([`quantized_bounds`]). Errors: invalid bounds, steps or errors, non-finite positions or
/// positions more than half a step outside `bounds`, out-of-range triangle indices, more than [`MAX_ELEMENTS`] vertices or triangles.
pub fn encode_mesh(
    key: TileKey,
    level: u8,
    bounds: &Bounds,
    q: Quantization,
    mesh: &Mesh,
    errors: ErrorFigures,
) -> Result<Vec<u8>, CodecError> {
    QuantGrid::new(bounds, q)?;
    let bounds = &quantized_bounds(bounds, &mesh.positions, q);
    let frame = QuantGrid::new(bounds, q)?;
    check_errors(errors)?;
    let v = check_count("vertices", mesh.positions.len())?;
    let t = check_count("triangles", mesh.triangles.len())?;
    let packed = mesh::encode(&frame, mesh)?;
    assemble(Kind::Mesh, key, level, bounds, q, v, t, errors, &packed)
}

/// Encodes a point cloud with its normals. Errors: as [`encode_mesh`], plus a normal count that
/// differs from the point count and normals that are not finite non-zero vectors.
pub fn encode_points(
    key: TileKey,
    level: u8,
    bounds: &Bounds,
    q: Quantization,
    points: &PointCloud,
    errors: ErrorFigures,
) -> Result<Vec<u8>, CodecError> {
    QuantGrid::new(bounds, q)?;
    check_errors(errors)?;
    draft_points(key, level, bounds, q, points)?.finish(errors)
}

/// A point blob encoded but for its measured errors: the header's errors are fixed-size fields,
/// so its length is known before they are (a baker decides whether a level pays from its length
/// and measures only the levels it keeps). [`PointsDraft::finish`] gives exactly the bytes
/// [`encode_points`] gives for the same input.
#[derive(Debug, Clone)]
pub struct PointsDraft {
    key: TileKey,
    level: u8,
    bounds: Bounds,
    q: Quantization,
    count: u32,
    packed: stream::Packed,
}

/// [`encode_points`] without the errors: the payload, packed. Errors: as [`encode_points`]
/// except those about the errors.
pub fn draft_points(
    key: TileKey,
    level: u8,
    bounds: &Bounds,
    q: Quantization,
    points: &PointCloud,
) -> Result<PointsDraft, CodecError> {
    QuantGrid::new(bounds, q)?;
    let bounds = quantized_bounds(bounds, &points.positions, q);
    let frame = QuantGrid::new(&bounds, q)?;
    let count = check_count("points", points.positions.len())?;
    let packed = points::encode(&frame, points)?;
    Ok(PointsDraft { key, level, bounds, q, count, packed })
}

impl PointsDraft {
    /// Length of the finished blob, in bytes.
    #[must_use]
    pub fn len(&self) -> usize {
        PREFIX_LEN + self.packed.payload.len()
    }

    /// Never true: a blob has at least its header.
    #[must_use]
    pub fn is_empty(&self) -> bool {
        false
    }

    /// The blob with `errors` in its header. Errors: errors that are not finite and
    /// non-negative, a payload over the size limit.
    pub fn finish(&self, errors: ErrorFigures) -> Result<Vec<u8>, CodecError> {
        check_errors(errors)?;
        assemble(
            Kind::Points,
            self.key,
            self.level,
            &self.bounds,
            self.q,
            self.count,
            0,
            errors,
            &self.packed,
        )
    }
}

/// Reads and validates the header from the first [`PREFIX_LEN`] bytes (more may follow and are
/// ignored). Checks magic, version, header length, header checksum and the header's values; the
/// payload is not looked at.
pub fn decode_header(bytes: &[u8]) -> Result<BlobHeader, CodecError> {
    let Some(prefix) = bytes.get(..PREFIX_LEN) else {
        // Report the magic first when there is enough of it: a wrong file type is the likelier
        // mistake than a short read.
        if let Some(m) = bytes.first_chunk::<4>()
            && *m != MAGIC
        {
            return Err(CodecError::BadMagic(*m));
        }
        return Err(CodecError::Truncated { needed: PREFIX_LEN, got: bytes.len() });
    };
    let magic: [u8; 4] = [prefix[0], prefix[1], prefix[2], prefix[3]];
    if magic != MAGIC {
        return Err(CodecError::BadMagic(magic));
    }
    let header_len = u32::from_le_bytes([prefix[4], prefix[5], prefix[6], prefix[7]]);
    // The version is checked before the rest so a newer layout is reported as such, not as
    // corruption.
    let version = u16::from_le_bytes([prefix[8], prefix[9]]);
    if version != FORMAT_VERSION {
        return Err(CodecError::UnsupportedVersion { found: version });
    }
    if header_len as usize != HEADER_LEN {
        return Err(CodecError::BadHeaderLength(header_len));
    }
    let found = u32::from_le_bytes([prefix[132], prefix[133], prefix[134], prefix[135]]);
    let computed = crc32fast::hash(&prefix[..PREFIX_LEN - 4]);
    if found != computed {
        return Err(CodecError::HeaderChecksum { found, computed });
    }
    let (header, used): (BlobHeader, usize) =
        bincode::decode_from_slice(&prefix[8..], bincode_config()).map_err(CodecError::HeaderDecode)?;
    if used != HEADER_LEN {
        return Err(CodecError::InvalidHeader("header length"));
    }
    QuantGrid::new(&header.bounds(), header.quant)?;
    check_errors(header.errors)?;
    if header.vertex_count > MAX_ELEMENTS || header.triangle_count > MAX_ELEMENTS {
        return Err(CodecError::InvalidHeader("element count above the limit"));
    }
    if header.raw_len > MAX_RAW_LEN {
        return Err(CodecError::InvalidHeader("decompressed size above the limit"));
    }
    if u64::from(header.payload_len) > u64::from(header.raw_len) + u64::from(PAYLOAD_TABLE_MAX) {
        return Err(CodecError::InvalidHeader("stored payload larger than its decompressed size allows"));
    }
    if header.kind == Kind::Points && header.triangle_count != 0 {
        return Err(CodecError::InvalidHeader("point blob with triangles"));
    }
    Ok(header)
}

/// Checks a whole blob without decoding its geometry: everything [`decode_header`] checks, the
/// exact length the header announces and the payload checksum. What a resumed bake checks of
/// every blob it keeps.
pub fn verify(bytes: &[u8]) -> Result<BlobHeader, CodecError> {
    let header = decode_header(bytes)?;
    let total = header.blob_len();
    if bytes.len() < total {
        return Err(CodecError::Truncated { needed: total, got: bytes.len() });
    }
    if bytes.len() > total {
        return Err(CodecError::TrailingBytes { extra: bytes.len() - total });
    }
    let computed = crc32fast::hash(&bytes[PREFIX_LEN..]);
    if computed != header.checksum {
        return Err(CodecError::PayloadChecksum { found: header.checksum, computed });
    }
    Ok(header)
}

/// Decodes a whole blob. Errors: everything [`verify`] reports and corrupt payloads.
pub fn decode(bytes: &[u8]) -> Result<Blob, CodecError> {
    let header = verify(bytes)?;
    let payload = &bytes[PREFIX_LEN..];
    let frame = QuantGrid::new(&header.bounds(), header.quant)?;
    let (v, t, raw_len) =
        (header.vertex_count as usize, header.triangle_count as usize, header.raw_len as usize);
    let geometry = match header.kind {
        Kind::Mesh => Geometry::Mesh(mesh::decode(&frame, v, t, payload, raw_len)?),
        Kind::Points => Geometry::Points(points::decode(&frame, v, payload, raw_len)?),
    };
    // The promise clients cull by: every position inside the header bounds, exactly.
    let positions = match &geometry {
        Geometry::Mesh(m) => &m.positions,
        Geometry::Points(p) => &p.positions,
    };
    let b = header.bounds();
    if let Some((index, p)) =
        positions.iter().enumerate().find(|(_, p)| (0..3).any(|a| p[a] < b.min[a] || p[a] > b.max[a]))
    {
        return Err(CodecError::OutOfBounds { index, position: *p });
    }
    Ok(Blob { header, geometry })
}

#[cfg(test)]
mod tests;
