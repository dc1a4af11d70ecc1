// KHR_draco_mesh_compression GLBs (export --glb-compression draco, ?glb=draco) decoded with
// Google's own Draco decoder (npm `draco3d`, the WebAssembly build of draco's C++ decoder),
// compared with the plain GLB of the same (tile, level). A mesh GLB (triangles, indexed) must
// hold each primitive as one Draco stream: the decoded point and index counts are the accessors'
// counts, POSITION decodes to the same 16-bit integers (Draco's own integer attribute, no Draco
// quantization) and NORMAL (Draco's 8-bit octahedral normals, decoded to floats) to within
// DRACO_NORMAL_DEG of the plain BYTE normal at the same position (both are rounded from the
// exact direction: Draco's within 1.2°, STEER_DEGREES in src/formats/tiles3d/draco.rs, towards
// Draco's own prediction; the BYTE vector within 1.14°), and the triangles are the plain
// ones as triples of positions (rotation allowed, winding kept; Draco renumbers the vertices);
// see comparePrimitives in lib/meshopt-checks.mjs. A point GLB (the Draco glTF extension is for
// triangles only) must carry EXT_meshopt_compression instead and is compared by compareGlbs.
import fs from 'node:fs';
import path from 'node:path';
import draco3d from 'draco3d';
import { MeshoptDecoder } from 'meshoptimizer';
import { readGlb, primitiveOf, comparePrimitives, compareGlbs, glbFiles } from './meshopt-checks.mjs';

export const EXT = 'KHR_draco_mesh_compression';
export const DRACO_NORMAL_DEG = 1.2 + 1.14;
const UNSIGNED_SHORT = 5123;
const UNSIGNED_INT = 5125;
const FLOAT = 5126;

let modulePromise = null;
/** draco3d's decoder module (WebAssembly), made once. */
export function dracoDecoder() {
  modulePromise ??= draco3d.createDecoderModule({});
  return modulePromise;
}

// The plain GLB's buffer views: slices of its BIN chunk.
function plainViews(json, bin) {
  return json.bufferViews.map((v) => {
    if (v.buffer !== 0 || v.extensions) throw new Error('a plain GLB view outside the BIN chunk or with an extension');
    return bin.subarray(v.byteOffset ?? 0, (v.byteOffset ?? 0) + v.byteLength);
  });
}

// One attribute of a decoded Draco mesh, by its unique id: checks its Draco type, data type and
// components, returns its values for all points (Draco's point order) as a typed array.
function dracoAttribute(M, decoder, mesh, id, want, name) {
  const attr = decoder.GetAttributeByUniqueId(mesh, id);
  if (!attr || attr.ptr === 0) throw new Error(`${name}: no Draco attribute of unique id ${id} (${want.gltf})`);
  const type = attr.attribute_type();
  const dataType = attr.data_type();
  if (type !== M[want.draco] || dataType !== M[want.dataType] || attr.num_components() !== 3) {
    throw new Error(`${name}: Draco attribute ${id} (${want.gltf}) is type ${type}, data type ${dataType}, ${attr.num_components()} components; want ${want.draco} ${want.dataType} ×3`);
  }
  const Typed = want.dataType === 'DT_UINT16' ? Uint16Array : Float32Array;
  return dracoArray(M, Typed, mesh.num_points() * 3, (size, ptr) => decoder.GetAttributeDataArrayForAllPoints(mesh, attr, M[want.dataType], size, ptr),
    `${name}: could not read Draco attribute ${id} (${want.gltf})`);
}

// n values of a typed array that `read(byteSize, pointer)` writes into the decoder's heap.
function dracoArray(M, Typed, n, read, failure) {
  const size = n * Typed.BYTES_PER_ELEMENT;
  const ptr = M._malloc(size);
  try {
    if (!read(size, ptr)) throw new Error(failure);
    return new Typed(M.HEAPU8.buffer, ptr, n).slice();
  } finally {
    M._free(ptr);
  }
}

// A mesh GLB's primitive decoded by draco3d, in comparePrimitives' form, after the checks on the
// glTF side of the extension.
function decodeDracoPrimitive(M, json, bin, prim, name) {
  const x = prim.extensions?.[EXT];
  if (!x) throw new Error(`${name}: a primitive without ${EXT}`);
  if ((prim.mode ?? 4) !== 4 || prim.indices === undefined) throw new Error(`${name}: ${EXT} on mode ${prim.mode ?? 4}${prim.indices === undefined ? ' without indices' : ''}`);
  const names = Object.keys(prim.attributes).sort();
  if (names.join() !== Object.keys(x.attributes).sort().join()) throw new Error(`${name}: the primitive's attributes ${names} but the extension's ${Object.keys(x.attributes)}`);
  for (const i of [...Object.values(prim.attributes), prim.indices]) {
    if (json.accessors[i].bufferView !== undefined) throw new Error(`${name}: accessor ${i} of a Draco primitive has a bufferView`);
  }
  const acc = (a) => json.accessors[prim.attributes[a]];
  if (acc('POSITION').componentType !== UNSIGNED_SHORT || acc('POSITION').type !== 'VEC3' || acc('POSITION').normalized) throw new Error(`${name}: POSITION is not UNSIGNED_SHORT VEC3`);
  if (names.includes('NORMAL') && (acc('NORMAL').componentType !== FLOAT || acc('NORMAL').type !== 'VEC3')) throw new Error(`${name}: NORMAL is not FLOAT VEC3`);
  const ia = json.accessors[prim.indices];
  if (![UNSIGNED_SHORT, UNSIGNED_INT].includes(ia.componentType) || ia.type !== 'SCALAR') throw new Error(`${name}: indices are ${ia.componentType} ${ia.type}`);
  for (const a of names) if (!['POSITION', 'NORMAL'].includes(a)) throw new Error(`${name}: attribute ${a} (this check knows POSITION and NORMAL)`);

  const view = json.bufferViews[x.bufferView];
  if (!view || view.buffer !== 0) throw new Error(`${name}: the Draco bufferView ${x.bufferView} is not in the BIN chunk`);
  const data = bin.subarray(view.byteOffset ?? 0, (view.byteOffset ?? 0) + view.byteLength);
  if (data.length !== view.byteLength) throw new Error(`${name}: the Draco bufferView runs past the BIN chunk`);
  const decoder = new M.Decoder();
  const mesh = new M.Mesh();
  try {
    const bytes = new Int8Array(data.buffer, data.byteOffset, data.byteLength);
    if (decoder.GetEncodedGeometryType(bytes) !== M.TRIANGULAR_MESH) throw new Error(`${name}: the Draco stream is not a triangular mesh`);
    const status = decoder.DecodeArrayToMesh(bytes, bytes.byteLength, mesh);
    if (!status.ok() || mesh.ptr === 0) throw new Error(`${name}: Draco decoding failed: ${status.error_msg()}`);
    const count = mesh.num_points();
    const faces = mesh.num_faces();
    for (const a of names) if (acc(a).count !== count) throw new Error(`${name}: ${a} accessor count ${acc(a).count}, Draco decoded ${count} points`);
    if (ia.count !== faces * 3) throw new Error(`${name}: indices accessor count ${ia.count}, Draco decoded ${faces} triangles`);
    if (ia.componentType === UNSIGNED_SHORT && count > 65536) throw new Error(`${name}: ${count} points behind UNSIGNED_SHORT indices`);

    const pos = dracoAttribute(M, decoder, mesh, x.attributes.POSITION, { gltf: 'POSITION', draco: 'POSITION', dataType: 'DT_UINT16' }, name);
    const min = [Infinity, Infinity, Infinity];
    const max = [-Infinity, -Infinity, -Infinity];
    pos.forEach((v, k) => {
      min[k % 3] = Math.min(min[k % 3], v);
      max[k % 3] = Math.max(max[k % 3], v);
    });
    if (min.join() !== (acc('POSITION').min ?? []).join() || max.join() !== (acc('POSITION').max ?? []).join()) {
      throw new Error(`${name}: POSITION min/max ${acc('POSITION').min}/${acc('POSITION').max}, decoded ${min}/${max}`);
    }
    const normals = names.includes('NORMAL')
      ? dracoAttribute(M, decoder, mesh, x.attributes.NORMAL, { gltf: 'NORMAL', draco: 'NORMAL', dataType: 'DT_FLOAT32' }, name)
      : null;
    const indices = dracoArray(M, Uint32Array, faces * 3, (size, ptr) => decoder.GetTrianglesUInt32Array(mesh, size, ptr), `${name}: could not read the Draco faces`);
    const keys = Array.from({ length: count }, (_, k) => `${pos[3 * k]},${pos[3 * k + 1]},${pos[3 * k + 2]}`);
    return { names: names.join(), mode: 4, count, keys, normals, indices };
  } finally {
    M.destroy(mesh);
    M.destroy(decoder);
  }
}

// Compares one GLB of a draco export with the plain GLB; throws naming the first difference.
// Returns its kind ('mesh' or 'points'), sizes and the largest normal angle.
export async function compareDracoGlb(plainBytes, dracoBytes, name) {
  const M = await dracoDecoder();
  const p = readGlb(plainBytes);
  const d = readGlb(dracoBytes);
  const prims = p.json.meshes.flatMap((m) => m.primitives);
  const meshes = prims.filter((q) => (q.mode ?? 4) === 4 && q.indices !== undefined).length;
  if (meshes === 0) {
    // points: EXT_meshopt_compression, the Draco extension nowhere
    if (prims.some((q) => (q.mode ?? 4) !== 0)) throw new Error(`${name}: a plain GLB neither indexed triangles nor points`);
    if ((d.json.extensionsUsed ?? []).includes(EXT)) throw new Error(`${name}: a point GLB lists ${EXT}`);
    await MeshoptDecoder.ready;
    const r = await compareGlbs(plainBytes, dracoBytes, name);
    return { kind: 'points', plain: plainBytes.length, draco: dracoBytes.length, maxDeg: r.maxDeg };
  }
  if (meshes !== prims.length) throw new Error(`${name}: a plain GLB mixing indexed triangles with other primitives`);
  for (const list of ['extensionsUsed', 'extensionsRequired']) {
    if (!(d.json[list] ?? []).includes(EXT)) throw new Error(`${name}: ${list} lacks ${EXT}`);
  }
  const shape = (j) => j.meshes.map((m) => m.primitives.length).join();
  if (shape(p.json) !== shape(d.json)) throw new Error(`${name}: primitives per mesh ${shape(p.json)}, draco ${shape(d.json)}`);
  const views = plainViews(p.json, p.bin);
  let maxDeg = 0;
  p.json.meshes.forEach((mesh, mi) => mesh.primitives.forEach((prim, pi) => {
    const a = primitiveOf(p.json, views, prim);
    if (a.accessors.POSITION !== `${UNSIGNED_SHORT}/VEC3/false`) throw new Error(`${name}: the plain POSITION is ${a.accessors.POSITION}`);
    const b = decodeDracoPrimitive(M, d.json, d.bin, d.json.meshes[mi].primitives[pi], name);
    maxDeg = Math.max(maxDeg, comparePrimitives(a, b, name, 'draco', DRACO_NORMAL_DEG).maxDeg);
  }));
  return { kind: 'mesh', plain: plainBytes.length, draco: dracoBytes.length, maxDeg };
}

// Every GLB under plainDir/tiles beside its draco-export form under dracoDir/tiles.
export async function compareDracoTrees(plainDir, dracoDir) {
  const files = glbFiles(plainDir);
  const r = { glbs: files.length, meshes: 0, points: 0, plain: 0, draco: 0, maxDeg: { mesh: 0, points: 0 } };
  for (const rel of files) {
    const one = await compareDracoGlb(fs.readFileSync(path.join(plainDir, rel)), fs.readFileSync(path.join(dracoDir, rel)), rel);
    r[one.kind === 'mesh' ? 'meshes' : 'points'] += 1;
    r.plain += one.plain;
    r.draco += one.draco;
    r.maxDeg[one.kind] = Math.max(r.maxDeg[one.kind], one.maxDeg);
  }
  const extra = glbFiles(dracoDir).filter((f) => !files.includes(f));
  if (extra.length) throw new Error(`the draco export has GLBs the plain one lacks: ${extra.slice(0, 3)}`);
  return r;
}
