//! `KHR_draco_mesh_compression` for the 3D Tiles mesh GLBs ([`compress_glb`]): each indexed
//! `TRIANGLES` primitive of a plain GLB of [`super::glb()`] becomes one Draco stream (Google's
//! bitstream 2.2, written by the pure-Rust `draco-core` encoder: EdgeBreaker connectivity,
//! parallelogram-predicted positions, octahedral normals predicted from the decoded triangles
//! (Draco's geometric normal predictor)), which every glTF reader with a Draco
//! decoder reads: CesiumJS natively, three.js with `DRACOLoader`.
//!
//! What the stream keeps:
//! - positions on the GLB's integer grid (`UNSIGNED_SHORT` with `KHR_mesh_quantization`, the
//!   plain GLB's accessor) go in as integers, **exactly**: the decoded values are the plain GLB's;
//! - `FLOAT` positions (tilesets on the Earth, grids wider than 16 bits) are quantized to
//!   [`FLOAT_POSITION_BITS`] bits over the primitive's extent (a 10 km tile: 0.6 mm steps, the
//!   float's own precision there);
//! - normals are quantized to [`NORMAL_BITS`]-bit octahedral coordinates (Draco's normal
//!   transform; the plain GLB's are `BYTE` vectors, about the same precision) and decode as
//!   `FLOAT` vectors;
//! - the triangles are the same triangles, but the stream numbers the vertices in its own order
//!   (the extension allows it; accessors carry the decoded counts).
//!
//! The extension covers triangles only (its "restrictions on geometry type"), so a GLB with a
//! `POINTS` primitive is not this module's: [`super::GlbCompression::Draco`] gives those
//! `EXT_meshopt_compression` instead.

use draco_core::normal_compression_utils::OctahedronToolBox;
use draco_core::{
    DataType, DecoderBuffer, EncoderBuffer, EncoderOptions, GeometryAttributeType, Mesh, MeshDecoder,
    MeshEncoder, PointAttribute,
};
use serde_json::{Value, json};

use super::glb::{ExactNormals, NormalRole};
use super::glb::{GLTF_FLOAT, GLTF_U16, GLTF_U32, write_glb};
use super::meshopt::read_glb;

/// The extension's name, in `extensionsUsed`/`extensionsRequired` and on primitives.
pub const EXT: &str = "KHR_draco_mesh_compression";
/// `KHR_mesh_quantization`, which integer positions keep needing after compression.
const QUANTIZATION: &str = "KHR_mesh_quantization";
/// Octahedral bits per coordinate of a normal: Draco's and gltfpack's default, about the angular
/// step of the plain GLB's `BYTE` normals (≈ 0.5°).
pub const NORMAL_BITS: i32 = 8;
/// Bits per coordinate of `FLOAT` positions over the primitive's largest extent: 2⁻²⁴ of it, the
/// resolution of an `f32` at that magnitude.
pub const FLOAT_POSITION_BITS: i32 = 24;
/// Draco's speed setting (0 densest … 10 fastest): 5, the library's default, EdgeBreaker with
/// the parallelogram predictor; on fuji's meshes within 1 % of the densest setting's bytes.
const SPEED: i32 = 5;
/// Draco's method id of the geometric normal predictor (`MESH_PREDICTION_GEOMETRIC_NORMAL`):
/// each normal predicted as the area-weighted normal of the decoded positions' triangles around
/// it, which is how [`super::glb()`] computes them, so only a small correction is stored. It
/// pays now that positions are on one step for all axes (with a 640× finer z step the
/// prediction came out bent and cost more than the plain delta).
const GEOMETRIC_NORMAL_PREDICTION: i32 = 6;

const GLTF_I8: u64 = 5120;
const GLTF_U8: u64 = 5121;

/// How far (degrees) [`compress_glb_with`] may move a tile's own normal from its exact
/// direction towards Draco's prediction of it. Rounding to the 8-bit octahedral grid alone moves
/// a normal up to 0.9°, the plain GLB's `BYTE` vectors up to 1.14°; rounding those bytes again,
/// as Draco normals were made before, moved them up to 1.8° (mean 0.64° over the 2049² synthetic
/// bake's own vertices); with this bound at most 1.2° (mean 0.67°), and 9 % fewer bytes.
pub const STEER_DEGREES: f64 = 1.2;

/// `v` at unit length; up (+z) for a zero or non-finite vector.
fn unit(v: [f64; 3]) -> [f64; 3] {
    let l = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
    if l > 0.0 && l.is_finite() { v.map(|x| x / l) } else { [0.0, 0.0, 1.0] }
}

/// The unit normals to give Draco for the vertices of `pos` (x, y, z each) and the triangle
/// list `idx`: each on the octahedral grid of [`NORMAL_BITS`] bits — for a tile's own vertex
/// ([`NormalRole::Own`]) the point Draco's geometric predictor will compute from the decoded
/// triangles when it lies within [`STEER_DEGREES`] of the direction, else the direction's
/// nearest; for a vertex shared with neighbours the nearest (as theirs); a skirt vertex what
/// the vertex above it gets.
///
/// The predictor is Draco's: per vertex the sum of the cross products of the triangles around
/// it (as wound), scaled to at most 2²⁹ in L1, to the L1 diamond with truncation, to octahedral
/// coordinates. Integer positions (the GLB's 16-bit grid) give it exactly; for `FLOAT`
/// positions, which Draco quantizes first, it can miss by a step, which then costs a
/// correction, as any other normal would.
fn steered_normals(pos: &[f64], idx: &[f64], exact: &ExactNormals) -> Vec<[f64; 3]> {
    const PREDICTION_BOUND: i64 = 1 << 29;
    let n = exact.directions.len();
    let mut tb = OctahedronToolBox::new();
    tb.set_quantization_bits(NORMAL_BITS);
    let p = |i: usize| glam::DVec3::new(pos[3 * i], pos[3 * i + 1], pos[3 * i + 2]);
    let mut sums = vec![glam::DVec3::ZERO; n];
    for t in idx.chunks_exact(3) {
        let [a, b, c] = [t[0] as usize, t[1] as usize, t[2] as usize];
        if a.max(b).max(c) >= n {
            continue;
        }
        let cross = (p(b) - p(a)).cross(p(c) - p(a));
        for v in [a, b, c] {
            sums[v] += cross;
        }
    }
    let integer = pos.iter().all(|v| v.fract() == 0.0 && v.abs() <= f64::from(u16::MAX));
    let predicted = |s: glam::DVec3| -> (i32, i32) {
        // 16-bit integers: every cross product and sum exact in f64. Floats: scaled to 2⁴⁰.
        let s = if integer {
            s
        } else {
            let m = s.abs().max_element();
            if m > 0.0 && m.is_finite() { s * ((1u64 << 40) as f64 / m) } else { glam::DVec3::ZERO }
        };
        let mut v = s.to_array().map(|c| c as i64);
        let l1: i64 = v.iter().map(|c| c.abs()).sum();
        if l1 > PREDICTION_BOUND {
            let q = l1 / PREDICTION_BOUND;
            v = v.map(|c| c / q);
        }
        let mut v = v.map(|c| c as i32);
        tb.canonicalize_integer_vector(&mut v);
        tb.integer_vector_to_quantized_octahedral_coords(&v)
    };
    let cos_bound = STEER_DEGREES.to_radians().cos();
    let cos = |a: [f64; 3], (s, t): (i32, i32)| {
        let b = unit(tb.quantized_octahedral_coords_to_unit_vector(s, t).map(f64::from));
        a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
    };
    // What Draco stores for the unit vector we give it for grid point `c`: `c` itself, except
    // at some points of the octahedron's folded edges, which come back as a neighbour.
    let stored = |(s, t): (i32, i32)| {
        tb.float_vector_to_quantized_octahedral_coords(&tb.quantized_octahedral_coords_to_unit_vector(s, t))
    };
    let nearest = |d: [f64; 3]| stored(tb.float_vector_to_quantized_octahedral_coords(&d.map(|c| c as f32)));
    let max = tb.max_quantized_value();
    let mut coords = vec![(0, 0); n];
    for i in 0..n {
        let d = unit(exact.directions[i]);
        let near = nearest(d);
        coords[i] = match exact.roles.get(i) {
            Some(NormalRole::Own) => {
                // The grid point within the bound nearest the prediction (in the correction's
                // L1 steps; the nearer to `d` among equals): rings around the prediction out
                // to the nearest point's own distance, which is within the bound.
                let (ps, pt) = predicted(sums[i]);
                let reach = (near.0 - ps).abs() + (near.1 - pt).abs();
                let mut best = (f64::NEG_INFINITY, near);
                for k in 0..reach {
                    for ds in -k..=k {
                        let rest = k - ds.abs();
                        for dt in [rest, -rest].into_iter().take(if rest == 0 { 1 } else { 2 }) {
                            let c = (ps + ds, pt + dt);
                            if !(0..=max).contains(&c.0)
                                || !(0..=max).contains(&c.1)
                                || tb.canonicalize_octahedral_coords(c.0, c.1) != c
                            {
                                continue;
                            }
                            let c = stored(c);
                            let v = cos(d, c);
                            if v >= cos_bound && v > best.0 {
                                best = (v, c);
                            }
                        }
                    }
                    if best.0 > f64::NEG_INFINITY {
                        break;
                    }
                }
                best.1
            }
            _ => near,
        };
    }
    // Skirts last, from the vertex above (itself no skirt vertex).
    for (i, role) in exact.roles.iter().enumerate().take(n) {
        if let NormalRole::Below(top) = *role {
            let top = top as usize;
            if top < n && matches!(exact.roles.get(top), Some(NormalRole::Own | NormalRole::Shared)) {
                coords[i] = coords[top];
            }
        }
    }
    coords
        .into_iter()
        .map(|(s, t)| tb.quantized_octahedral_coords_to_unit_vector(s, t).map(f64::from))
        .collect()
}

/// Errors of [`compress_glb`] and [`decompress_glb`].
#[derive(Debug, Clone, thiserror::Error, PartialEq, Eq)]
pub enum DracoError {
    #[error("draco: GLB: {0}")]
    Glb(String),
    #[error("draco: encoder: {0}")]
    Encode(String),
    #[error("draco: decoder: {0}")]
    Decode(String),
}

fn bad(m: impl Into<String>) -> DracoError {
    DracoError::Glb(m.into())
}

fn as_usize(v: &Value) -> Option<usize> {
    v.as_u64().and_then(|n| usize::try_from(n).ok())
}

/// Every primitive of the GLB's meshes.
fn primitives(json: &Value) -> Vec<Value> {
    json["meshes"]
        .as_array()
        .map(|m| m.iter().flat_map(|m| m["primitives"].as_array().cloned().unwrap_or_default()).collect())
        .unwrap_or_default()
}

/// Whether every primitive of `glb` is indexed `TRIANGLES` (what the extension covers), and
/// there is at least one: false for a point level's GLB, and for bytes that are not a GLB.
#[must_use]
pub fn all_triangles(glb: &[u8]) -> bool {
    let Ok((json, _)) = read_glb(glb) else { return false };
    let prims = primitives(&json);
    !prims.is_empty()
        && prims.iter().all(|p| p["mode"].as_u64().unwrap_or(4) == 4 && p.get("indices").is_some())
}

/// One accessor's values, widened: `(count, components, componentType, values)`.
fn read_accessor(
    json: &Value,
    bin: &[u8],
    index: usize,
) -> Result<(usize, usize, u64, Vec<f64>), DracoError> {
    let a = json["accessors"].get(index).ok_or_else(|| bad(format!("accessor {index} out of range")))?;
    let count = as_usize(&a["count"]).ok_or_else(|| bad(format!("accessor {index} without count")))?;
    let n = match a["type"].as_str() {
        Some("SCALAR") => 1,
        Some("VEC2") => 2,
        Some("VEC3") => 3,
        Some("VEC4") => 4,
        t => return Err(bad(format!("accessor {index}: type {t:?}"))),
    };
    let ct = a["componentType"].as_u64().unwrap_or(0);
    let size = match ct {
        GLTF_I8 | GLTF_U8 => 1,
        5122 | 5123 => 2,
        5125 | 5126 => 4,
        c => return Err(bad(format!("accessor {index}: componentType {c}"))),
    };
    let vi = as_usize(&a["bufferView"]).ok_or_else(|| bad(format!("accessor {index} without bufferView")))?;
    let v = json["bufferViews"].get(vi).ok_or_else(|| bad(format!("bufferView {vi} out of range")))?;
    let (offset, len) = (as_usize(&v["byteOffset"]).unwrap_or(0), as_usize(&v["byteLength"]).unwrap_or(0));
    let bytes =
        bin.get(offset..offset.saturating_add(len)).ok_or_else(|| bad("bufferView outside the BIN chunk"))?;
    let stride = as_usize(&v["byteStride"]).unwrap_or(n * size);
    if stride < n * size {
        return Err(bad(format!("accessor {index}: byteStride {stride} is shorter than an element")));
    }
    let start = as_usize(&a["byteOffset"]).unwrap_or(0);
    let end = count
        .checked_sub(1)
        .map_or(Some(start), |last| last.checked_mul(stride).and_then(|o| o.checked_add(start + n * size)));
    if end.is_none_or(|e| e > bytes.len()) {
        return Err(bad(format!("accessor {index} runs past its bufferView")));
    }
    let mut values = Vec::with_capacity(count * n);
    for k in 0..count {
        for c in 0..n {
            let o = start + k * stride + c * size;
            let b = &bytes[o..o + size];
            values.push(match ct {
                GLTF_I8 => f64::from(b[0] as i8),
                GLTF_U8 => f64::from(b[0]),
                5122 => f64::from(i16::from_le_bytes([b[0], b[1]])),
                5123 => f64::from(u16::from_le_bytes([b[0], b[1]])),
                5125 => f64::from(u32::from_le_bytes([b[0], b[1], b[2], b[3]])),
                _ => f64::from(f32::from_le_bytes([b[0], b[1], b[2], b[3]])),
            });
        }
    }
    Ok((count, n, ct, values))
}

fn attribute(kind: GeometryAttributeType, data: DataType, bytes: &[u8], points: usize) -> PointAttribute {
    let mut a = PointAttribute::new();
    a.init(kind, 3, data, false, points);
    a.buffer_mut().write(0, bytes);
    a
}

/// The `KHR_draco_mesh_compression` form of a plain GLB of [`super::glb()`] whose primitives
/// are all indexed `TRIANGLES` with `POSITION` and `NORMAL` (see the module's notes for what is
/// exact and what is quantized). Every compressed accessor loses its buffer view and takes the
/// decoded counts; views nothing else uses are dropped; the streams go into the BIN chunk.
///
/// # Errors
/// A GLB that is not one [`super::glb()`] writes for a mesh (a `POINTS` primitive, an attribute
/// other than those two, an accessor shared between primitives), or the encoder's refusal.
pub fn compress_glb(glb: &[u8]) -> Result<Vec<u8>, DracoError> {
    compress_glb_with(glb, None)
}

/// [`compress_glb`] of a GLB whose one primitive's normals were rounded to bytes from `normals`
/// ([`super::glb_and_normals`]): Draco's octahedral normals are then rounded from those
/// directions rather than again from the bytes, and a tile's own vertex takes Draco's
/// prediction of it (the area-weighted normal of the decoded triangles around it) wherever that
/// lies within [`STEER_DEGREES`] of its direction, so the stream stores no correction for it
/// ([`steered_normals`]). `normals` that do not fit the GLB (another vertex count, several
/// primitives) are not used.
///
/// # Errors
/// As [`compress_glb`].
pub fn compress_glb_with(glb: &[u8], normals: Option<&ExactNormals>) -> Result<Vec<u8>, DracoError> {
    let (mut json, bin) = read_glb(glb).map_err(|e| bad(e.to_string()))?;
    let normals = normals.filter(|_| primitives(&json).len() == 1);
    if json["buffers"].as_array().map_or(0, Vec::len) > 1 {
        return Err(bad("expected at most one buffer"));
    }
    let mut streams: Vec<Vec<u8>> = Vec::new();
    let mut compressed: Vec<usize> = Vec::new();
    let mut accessors = json["accessors"].as_array().cloned().unwrap_or_default();
    let mut meshes = json["meshes"].as_array().cloned().unwrap_or_default();
    for mesh in &mut meshes {
        let Some(prims) = mesh["primitives"].as_array_mut() else { continue };
        for prim in prims {
            if prim["mode"].as_u64().unwrap_or(4) != 4 {
                return Err(bad("a primitive that is not TRIANGLES (the extension covers triangles only)"));
            }
            let ia = as_usize(&prim["indices"]).ok_or_else(|| bad("a primitive without indices"))?;
            let attrs = prim["attributes"].as_object().cloned().unwrap_or_default();
            if attrs.keys().any(|k| k != "POSITION" && k != "NORMAL") {
                return Err(bad(format!(
                    "attributes {:?}: only POSITION and NORMAL are compressed",
                    attrs.keys()
                )));
            }
            let pa = attrs
                .get("POSITION")
                .and_then(as_usize)
                .ok_or_else(|| bad("a primitive without POSITION"))?;
            let na = attrs.get("NORMAL").and_then(as_usize);
            for a in [Some(ia), Some(pa), na].into_iter().flatten() {
                if compressed.contains(&a) {
                    return Err(bad(format!("accessor {a} is used twice")));
                }
                compressed.push(a);
            }
            let (points, pn, pct, pos) = read_accessor(&json, &bin, pa)?;
            if pn != 3 {
                return Err(bad("POSITION is not VEC3"));
            }
            let (ni, _, _, idx) = read_accessor(&json, &bin, ia)?;
            if ni % 3 != 0 || idx.iter().any(|&i| i >= points as f64) {
                return Err(bad("indices are not a triangle list over the vertices"));
            }
            let mut m = Mesh::new();
            m.set_num_points(points);
            let mut opts = EncoderOptions::new();
            opts.set_global_int("encoding_speed", SPEED);
            opts.set_global_int("decoding_speed", SPEED);
            let integer = pct == u64::from(GLTF_U16);
            let pos_att = if integer {
                let b: Vec<u8> = pos.iter().flat_map(|&v| (v as u16).to_le_bytes()).collect();
                attribute(GeometryAttributeType::Position, DataType::Uint16, &b, points)
            } else if pct == u64::from(GLTF_FLOAT) {
                let b: Vec<u8> = pos.iter().flat_map(|&v| (v as f32).to_le_bytes()).collect();
                attribute(GeometryAttributeType::Position, DataType::Float32, &b, points)
            } else {
                return Err(bad(format!("POSITION componentType {pct}")));
            };
            let pid = m.add_attribute(pos_att);
            if !integer {
                opts.set_attribute_int(pid, "quantization_bits", FLOAT_POSITION_BITS);
            }
            let mut ext_attrs = json!({ "POSITION": pid });
            if let Some(na) = na {
                let (count, nn, nct, nrm) = read_accessor(&json, &bin, na)?;
                if count != points || nn != 3 {
                    return Err(bad("NORMAL is not one VEC3 a vertex"));
                }
                let b: Vec<u8> = if let Some(exact) = normals.filter(|n| n.directions.len() == points) {
                    steered_normals(&pos, &idx, exact)
                } else {
                    // Normalized `BYTE` vectors (or floats) as unit floats for the octahedral
                    // transform.
                    let scale = if nct == GLTF_I8 { 1.0 / 127.0 } else { 1.0 };
                    nrm.chunks_exact(3).map(|c| unit([c[0] * scale, c[1] * scale, c[2] * scale])).collect()
                }
                .into_iter()
                .flatten()
                .flat_map(|x| (x as f32).to_le_bytes())
                .collect();
                let nid =
                    m.add_attribute(attribute(GeometryAttributeType::Normal, DataType::Float32, &b, points));
                opts.set_attribute_int(nid, "quantization_bits", NORMAL_BITS);
                opts.set_attribute_int(nid, "prediction_scheme", GEOMETRIC_NORMAL_PREDICTION);
                ext_attrs["NORMAL"] = json!(nid);
            }
            let flat: Vec<u32> = idx.iter().map(|&i| i as u32).collect();
            m.set_num_faces(flat.len() / 3);
            m.set_faces_from_flat_indices(&flat);
            let mut enc = MeshEncoder::new();
            enc.set_mesh(m);
            let mut buf = EncoderBuffer::new();
            let info =
                enc.encode_with_info(&opts, &mut buf).map_err(|e| DracoError::Encode(e.to_string()))?;
            let decoded = info.num_encoded_points;
            let pa_json = &mut accessors[pa];
            pa_json["count"] = json!(decoded);
            // min/max stay the plain GLB's: integers decode exactly, and 24-bit floats within
            // 2⁻²⁴ of the extent (glTF readers use them as bounds).
            if let Some(na) = na {
                let a = &mut accessors[na];
                a["count"] = json!(decoded);
                a["componentType"] = json!(GLTF_FLOAT);
                if let Some(o) = a.as_object_mut() {
                    o.remove("normalized");
                }
            }
            let ix = &mut accessors[ia];
            ix["count"] = json!(info.num_encoded_faces * 3);
            ix["componentType"] = json!(if decoded <= 1 << 16 { GLTF_U16 } else { GLTF_U32 });
            prim["extensions"] = json!({ EXT: { "bufferView": usize::MAX, "attributes": ext_attrs } });
            streams.push(buf.data().to_vec());
        }
    }
    if streams.is_empty() {
        return Err(bad("no triangles to compress"));
    }
    for &a in &compressed {
        if let Some(o) = accessors[a].as_object_mut() {
            o.remove("bufferView");
            o.remove("byteOffset");
        }
    }
    // The views still in use, then one view per stream, in one new BIN chunk.
    let old_views = json["bufferViews"].as_array().cloned().unwrap_or_default();
    let mut remap = vec![None; old_views.len()];
    let (mut views, mut packed) = (Vec::new(), Vec::new());
    for (i, v) in old_views.iter().enumerate() {
        if !accessors.iter().any(|a| as_usize(&a["bufferView"]) == Some(i)) {
            continue;
        }
        let (offset, len) =
            (as_usize(&v["byteOffset"]).unwrap_or(0), as_usize(&v["byteLength"]).unwrap_or(0));
        let bytes = bin
            .get(offset..offset.saturating_add(len))
            .ok_or_else(|| bad("bufferView outside the BIN chunk"))?;
        while !packed.len().is_multiple_of(4) {
            packed.push(0);
        }
        let mut nv = v.clone();
        nv["buffer"] = json!(0);
        nv["byteOffset"] = json!(packed.len());
        packed.extend_from_slice(bytes);
        remap[i] = Some(views.len());
        views.push(nv);
    }
    for a in &mut accessors {
        if let Some(v) = as_usize(&a["bufferView"]) {
            a["bufferView"] = json!(remap.get(v).copied().flatten());
        }
    }
    let mut stream_views = Vec::with_capacity(streams.len());
    for s in &streams {
        while !packed.len().is_multiple_of(4) {
            packed.push(0);
        }
        stream_views.push(views.len());
        views.push(json!({ "buffer": 0, "byteOffset": packed.len(), "byteLength": s.len() }));
        packed.extend_from_slice(s);
    }
    let mut next = stream_views.into_iter();
    for mesh in &mut meshes {
        for prim in mesh["primitives"].as_array_mut().into_iter().flatten() {
            prim["extensions"][EXT]["bufferView"] = json!(next.next());
        }
    }
    while !packed.len().is_multiple_of(4) {
        packed.push(0);
    }
    // `KHR_mesh_quantization` stays only while an attribute is still an integer type.
    let quantized =
        meshes.iter().flat_map(|m| m["primitives"].as_array().cloned().unwrap_or_default()).any(|p| {
            p["attributes"].as_object().is_some_and(|o| {
                o.values()
                    .filter_map(as_usize)
                    .any(|a| accessors.get(a).is_some_and(|x| x["componentType"] != GLTF_FLOAT))
            })
        });
    for list in ["extensionsUsed", "extensionsRequired"] {
        let mut names: Vec<Value> = json[list].as_array().cloned().unwrap_or_default();
        names.retain(|n| quantized || n != QUANTIZATION);
        if !names.iter().any(|n| n == EXT) {
            names.push(json!(EXT));
        }
        json[list] = Value::Array(names);
    }
    json["meshes"] = Value::Array(meshes);
    json["accessors"] = Value::Array(accessors);
    json["bufferViews"] = Value::Array(views);
    json["buffers"] = json!([{ "byteLength": packed.len() }]);
    Ok(write_glb(&json, packed))
}

/// A decoded primitive: positions and normals (as decoded, widened to `f32`) and triangles.
#[derive(Debug, Clone, PartialEq)]
pub struct Decoded {
    pub positions: Vec<[f32; 3]>,
    pub normals: Option<Vec<[f32; 3]>>,
    pub triangles: Vec<[u32; 3]>,
}

/// Every Draco primitive of a GLB of [`compress_glb`], decoded with `draco-core`'s decoder (for
/// the round trips; the interop suite decodes the same GLBs with Google's own decoder).
///
/// # Errors
/// A GLB without the extension, or a stream that does not decode to the accessors' counts.
pub fn decompress_glb(glb: &[u8]) -> Result<Vec<Decoded>, DracoError> {
    let (json, bin) = read_glb(glb).map_err(|e| bad(e.to_string()))?;
    let mut out = Vec::new();
    for prim in primitives(&json) {
        let ext = &prim["extensions"][EXT];
        let vi = as_usize(&ext["bufferView"]).ok_or_else(|| bad("a primitive without the extension"))?;
        let v = &json["bufferViews"][vi];
        let (offset, len) =
            (as_usize(&v["byteOffset"]).unwrap_or(0), as_usize(&v["byteLength"]).unwrap_or(0));
        let bytes =
            bin.get(offset..offset.saturating_add(len)).ok_or_else(|| bad("stream outside the BIN chunk"))?;
        let mut mesh = Mesh::new();
        MeshDecoder::new()
            .decode(&mut DecoderBuffer::new(bytes), &mut mesh)
            .map_err(|e| DracoError::Decode(e.to_string()))?;
        let points = mesh.num_points();
        let vec3 = |name: &str| -> Result<Option<Vec<[f32; 3]>>, DracoError> {
            let Some(id) = ext["attributes"][name].as_u64() else { return Ok(None) };
            let a = u32::try_from(id)
                .ok()
                .and_then(|id| mesh.attribute_by_unique_id(id))
                .ok_or_else(|| DracoError::Decode(format!("no attribute {id} ({name})")))?;
            Ok(Some(a.read_f32s(points, 3).chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect()))
        };
        let positions = vec3("POSITION")?.ok_or_else(|| bad("no POSITION in the extension"))?;
        let normals = vec3("NORMAL")?;
        let triangles: Vec<[u32; 3]> =
            (0..mesh.num_faces()).map(|f| mesh.face(draco_core::FaceIndex(f as u32)).map(|p| p.0)).collect();
        let count = |a: &Value| as_usize(&json["accessors"][as_usize(a).unwrap_or(usize::MAX)]["count"]);
        if count(&prim["attributes"]["POSITION"]) != Some(points)
            || count(&prim["indices"]) != Some(triangles.len() * 3)
        {
            return Err(DracoError::Decode("the stream's counts are not the accessors'".into()));
        }
        out.push(Decoded { positions, normals, triangles });
    }
    if out.is_empty() {
        return Err(bad("no primitive with the extension"));
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A plain GLB as [`super::super::glb()`] lays one out: an `n × n` grid of triangles with
    /// `UNSIGNED_SHORT` (stride 8) or `FLOAT` (stride 12) positions, `BYTE` normals (stride 4)
    /// and 16-bit indices; `mode` 0 makes it a point cloud without indices.
    fn plain(n: u16, float: bool, mode: u32) -> Vec<u8> {
        let (mut bin, mut pos, mut nrm) = (Vec::new(), Vec::new(), Vec::new());
        for j in 0..=n {
            for i in 0..=n {
                let p = [i * 37, (i * j) % 251 * 11, j * 41];
                if float {
                    for c in p {
                        pos.extend_from_slice(&(f32::from(c) * 0.731 - 900.0).to_le_bytes());
                    }
                } else {
                    for c in p {
                        pos.extend_from_slice(&c.to_le_bytes());
                    }
                    pos.extend_from_slice(&[0, 0]);
                }
                let v = [(i % 7) as i8 - 3, 120, (j % 5) as i8 - 2];
                nrm.extend_from_slice(&[v[0] as u8, v[1] as u8, v[2] as u8, 0]);
            }
        }
        let mut idx = Vec::new();
        for j in 0..n {
            for i in 0..n {
                let v = j * (n + 1) + i;
                for k in [v, v + 1, v + n + 1, v + 1, v + n + 2, v + n + 1] {
                    idx.extend_from_slice(&k.to_le_bytes());
                }
            }
        }
        let count = usize::from(n + 1).pow(2);
        let stride = if float { 12 } else { 8 };
        let mut views =
            vec![json!({ "buffer": 0, "byteOffset": 0, "byteLength": pos.len(), "byteStride": stride })];
        bin.extend_from_slice(&pos);
        views.push(json!({ "buffer": 0, "byteOffset": bin.len(), "byteLength": nrm.len(), "byteStride": 4 }));
        bin.extend_from_slice(&nrm);
        views.push(json!({ "buffer": 0, "byteOffset": bin.len(), "byteLength": idx.len() }));
        bin.extend_from_slice(&idx);
        let ct = if float { GLTF_FLOAT } else { GLTF_U16 };
        let mut accessors = vec![
            json!({ "bufferView": 0, "componentType": ct, "count": count, "type": "VEC3", "min": [0, 0, 0], "max": [1, 1, 1] }),
            json!({ "bufferView": 1, "componentType": 5120, "normalized": true, "count": count, "type": "VEC3" }),
        ];
        let mut prim = json!({ "attributes": { "POSITION": 0, "NORMAL": 1 }, "mode": mode });
        if mode == 4 {
            accessors.push(json!({ "bufferView": 2, "componentType": GLTF_U16, "count": idx.len() / 2, "type": "SCALAR" }));
            prim["indices"] = json!(2);
        }
        let mut doc = json!({
            "asset": { "version": "2.0" }, "bufferViews": views, "accessors": accessors,
            "meshes": [{ "primitives": [prim] }], "buffers": [{ "byteLength": bin.len() }],
        });
        if !float {
            doc["extensionsUsed"] = json!([QUANTIZATION]);
            doc["extensionsRequired"] = json!([QUANTIZATION]);
        }
        write_glb(&doc, bin)
    }

    /// Positions and triangles of the plain GLB, and the decoded ones, as comparable sets.
    fn triangle_set(pos: &[[f32; 3]], tris: impl Iterator<Item = [u32; 3]>) -> Vec<[[u32; 3]; 3]> {
        let key = |k: u32| pos[k as usize].map(f32::to_bits);
        let mut v: Vec<_> = tris
            .map(|t| {
                let k = t.map(key);
                (0..3).map(|r| [k[r], k[(r + 1) % 3], k[(r + 2) % 3]]).min().unwrap_or(k)
            })
            .collect();
        v.sort_unstable();
        v
    }

    #[test]
    fn integer_meshes_decode_exactly_with_octahedral_normals() {
        let glb = plain(12, false, 4);
        assert!(all_triangles(&glb));
        let out = compress_glb(&glb).unwrap();
        assert!(out.len() * 3 < glb.len(), "{} of {}", out.len(), glb.len());
        let (json, _) = read_glb(&out).unwrap();
        assert_eq!(json["extensionsRequired"], json!([QUANTIZATION, EXT]));
        assert!(json["accessors"].as_array().unwrap().iter().all(|a| a.get("bufferView").is_none()));
        assert_eq!(json["accessors"][1]["componentType"], GLTF_FLOAT);
        assert!(json["accessors"][1].get("normalized").is_none());
        let [d] = &decompress_glb(&out).unwrap()[..] else { panic!("one primitive") };
        // The plain GLB's positions and triangles, renumbered.
        let (pj, pb) = read_glb(&glb).unwrap();
        let (_, _, _, p) = read_accessor(&pj, &pb, 0).unwrap();
        let pos: Vec<[f32; 3]> = p.chunks(3).map(|c| [c[0] as f32, c[1] as f32, c[2] as f32]).collect();
        let (_, _, _, i) = read_accessor(&pj, &pb, 2).unwrap();
        let want = triangle_set(&pos, i.chunks(3).map(|t| [t[0] as u32, t[1] as u32, t[2] as u32]));
        assert_eq!(triangle_set(&d.positions, d.triangles.iter().copied()), want);
        let mut got_pos = d.positions.clone();
        let mut want_pos = pos.clone();
        got_pos.sort_by(|a, b| a.partial_cmp(b).unwrap());
        want_pos.sort_by(|a, b| a.partial_cmp(b).unwrap());
        assert_eq!(got_pos, want_pos);
        // Normals: unit vectors within 1.5° of the plain `BYTE` ones at the same position.
        let (_, _, _, n) = read_accessor(&pj, &pb, 1).unwrap();
        let normals = d.normals.as_ref().unwrap();
        for (k, q) in d.positions.iter().enumerate() {
            let src = pos.iter().position(|p| p.map(f32::to_bits) == q.map(f32::to_bits)).unwrap();
            let w = [n[3 * src], n[3 * src + 1], n[3 * src + 2]];
            let l = (w[0] * w[0] + w[1] * w[1] + w[2] * w[2]).sqrt();
            let g = normals[k].map(f64::from);
            let dot = (g[0] * w[0] + g[1] * w[1] + g[2] * w[2]) / l;
            assert!(dot > 1.5f64.to_radians().cos(), "normal {k}: {g:?} vs {w:?}");
        }
    }

    proptest::proptest! {
        #![proptest_config(proptest::prelude::ProptestConfig::with_cases(48))]
        /// Whatever exact normals come with a GLB (zero, huge or non-finite directions, roles
        /// naming vertices that are not there or other skirts, fewer roles than vertices), the
        /// steered compression neither panics nor fails, and every finite own normal decodes
        /// within the bound of its direction.
        #[test]
        fn any_exact_normals_steer_within_the_bound(
            float in proptest::bool::ANY,
            dirs in proptest::collection::vec(
                (-2.0f64..2.0, -2.0f64..2.0, -2.0f64..2.0, 0u8..12),
                169,
            ),
            roles in proptest::collection::vec((0u8..4, 0u32..200), 150..=169),
        ) {
            let glb = plain(12, float, 4);
            let directions: Vec<[f64; 3]> = dirs
                .iter()
                .map(|&(x, y, z, k)| match k {
                    0 => [0.0; 3],
                    1 => [f64::NAN, y, z],
                    2 => [x * 1e300, y * 1e300, z],
                    _ => [x, y, z],
                })
                .collect();
            let roles: Vec<NormalRole> = roles
                .iter()
                .map(|&(k, t)| match k {
                    0 | 1 => NormalRole::Own,
                    2 => NormalRole::Shared,
                    _ => NormalRole::Below(t),
                })
                .collect();
            let exact = ExactNormals { directions: directions.clone(), roles: roles.clone() };
            let out = compress_glb_with(&glb, Some(&exact)).unwrap();
            let [d] = &decompress_glb(&out).unwrap()[..] else { panic!("one primitive") };
            if !float {
                let (pj, pb) = read_glb(&glb).unwrap();
                let (_, _, _, p) = read_accessor(&pj, &pb, 0).unwrap();
                let cos = (STEER_DEGREES + 1e-3).to_radians().cos();
                for (k, q) in d.positions.iter().enumerate() {
                    let src = (0..169)
                        .find(|&v| (0..3).all(|a| (p[3 * v + a] as f32).to_bits() == q[a].to_bits()))
                        .unwrap();
                    let w = directions[src];
                    let l = (w[0] * w[0] + w[1] * w[1] + w[2] * w[2]).sqrt();
                    if roles.get(src) == Some(&NormalRole::Own) && l > 1e-9 && l.is_finite() {
                        let g = d.normals.as_ref().unwrap()[k].map(f64::from);
                        let dot = (g[0] * w[0] + g[1] * w[1] + g[2] * w[2]) / l;
                        proptest::prop_assert!(dot >= cos, "vertex {src}: {g:?} vs {w:?}");
                    }
                }
            }
        }
    }

    #[test]
    fn float_positions_keep_24_bits_and_drop_mesh_quantization() {
        let glb = plain(9, true, 4);
        let out = compress_glb(&glb).unwrap();
        let (json, _) = read_glb(&out).unwrap();
        assert_eq!(json["extensionsRequired"], json!([EXT]), "no integer attribute is left");
        let (pj, pb) = read_glb(&glb).unwrap();
        let (_, _, _, p) = read_accessor(&pj, &pb, 0).unwrap();
        let extent = p.iter().fold(0.0f64, |m, &v| m.max((v + 900.0).abs()));
        let [d] = &decompress_glb(&out).unwrap()[..] else { panic!("one primitive") };
        for q in &d.positions {
            let near = p
                .chunks(3)
                .map(|c| (0..3).map(|a| (c[a] - f64::from(q[a])).abs()).fold(0.0, f64::max))
                .fold(f64::INFINITY, f64::min);
            assert!(near <= extent * 2f64.powi(-FLOAT_POSITION_BITS + 1), "{q:?} is {near} off");
        }
    }

    #[test]
    fn points_and_bad_glbs_are_refused_not_panicked_on() {
        let points = plain(4, false, 0);
        assert!(!all_triangles(&points));
        assert!(matches!(compress_glb(&points), Err(DracoError::Glb(_))));
        assert!(!all_triangles(b"not a glb"));
        assert!(compress_glb(b"glTF").is_err());
        assert!(decompress_glb(&plain(3, false, 4)).is_err(), "a plain GLB has no stream");
        // Every truncation and a flipped byte in the stream: an error or a decode, never a panic.
        let out = compress_glb(&plain(6, false, 4)).unwrap();
        for cut in (0..out.len()).step_by(7) {
            let _ = decompress_glb(&out[..cut]);
        }
        let (json, bin) = read_glb(&out).unwrap();
        for k in (0..bin.len()).step_by(3) {
            let mut b = bin.clone();
            b[k] ^= 0x5a;
            let _ = decompress_glb(&write_glb(&json, b));
        }
    }
}
