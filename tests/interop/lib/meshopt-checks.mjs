// EXT_meshopt_compression GLBs (export --glb-compression meshopt, ?glb=meshopt, and the point
// GLBs of --glb-compression draco) decoded with meshoptimizer's own decoder (npm `meshoptimizer`,
// MeshoptDecoder, each view's filter applied), compared with the plain GLB of the same (tile,
// level) by comparePrimitives: the vertices matched by position, POSITION (and any attribute but
// NORMAL) byte for byte, NORMAL by angle (the normals' view goes through the OCTAHEDRAL filter,
// so a decoded normal is within MAX_NORMAL_DEG of the plain one at the same position, not equal
// to it), the triangles as triples of positions with each triangle allowed a cyclic rotation (the
// triangle codec may rotate a triangle; the winding stays), 8-bit indices widened to 16 bits.
// comparePrimitives is also the comparison of lib/draco-checks.mjs.
import fs from 'node:fs';
import path from 'node:path';
import { MeshoptDecoder } from 'meshoptimizer';

const EXT = 'EXT_meshopt_compression';
// A normal after a lossy codec (meshopt's OCTAHEDRAL filter with K = 8, Draco's 8-bit octahedral
// normals) against the plain GLB's BYTE normal at the same position: at most this far apart.
export const MAX_NORMAL_DEG = 2;

export function readGlb(bytes) {
  const dv = new DataView(bytes.buffer, bytes.byteOffset, bytes.byteLength);
  if (dv.getUint32(0, true) !== 0x46546c67) throw new Error('not a GLB');
  const jlen = dv.getUint32(12, true);
  const json = JSON.parse(new TextDecoder().decode(bytes.subarray(20, 20 + jlen)));
  const at = 20 + jlen;
  const bin = at < bytes.length ? bytes.subarray(at + 8, at + 8 + dv.getUint32(at, true)) : new Uint8Array(0);
  return { json, bin };
}

const SIZES = { 5120: 1, 5121: 1, 5122: 2, 5123: 2, 5125: 4, 5126: 4 };
const COMPONENTS = { SCALAR: 1, VEC2: 2, VEC3: 3, VEC4: 4 };

// The bytes of every buffer view: the plain GLB's from its BIN chunk, the meshopt GLB's decoded.
async function views(glb) {
  const { json, bin } = readGlb(glb);
  const out = [];
  for (const v of json.bufferViews) {
    const x = v.extensions?.[EXT];
    if (x) {
      if (json.buffers[v.buffer]?.extensions?.[EXT]?.fallback !== true) throw new Error('a compressed view not on the fallback buffer');
      const target = new Uint8Array(x.count * x.byteStride);
      const src = bin.subarray(x.byteOffset ?? 0, (x.byteOffset ?? 0) + x.byteLength);
      MeshoptDecoder.decodeGltfBuffer(target, x.count, x.byteStride, src, x.mode, x.filter ?? 'NONE');
      out.push(target);
    } else {
      if (v.buffer !== 0) throw new Error('an uncompressed view outside the BIN chunk');
      out.push(bin.subarray(v.byteOffset ?? 0, (v.byteOffset ?? 0) + v.byteLength));
    }
  }
  return { json, out };
}

// An accessor's values: `vals` its components as unsigned integers of their width (bit for bit:
// equal vals are equal bytes), `floats` as the glTF spec reads them (normalized integers mapped to
// [-1, 1] or [0, 1]).
export function accessorValues(json, viewBytes, i) {
  const a = json.accessors[i];
  const v = json.bufferViews[a.bufferView];
  const size = SIZES[a.componentType];
  const n = COMPONENTS[a.type];
  const stride = v.byteStride ?? size * n;
  const bytes = viewBytes[a.bufferView];
  const dv = new DataView(bytes.buffer, bytes.byteOffset, bytes.byteLength);
  const vals = [];
  const floats = [];
  for (let k = 0; k < a.count; k++) {
    for (let c = 0; c < n; c++) {
      const o = (a.byteOffset ?? 0) + k * stride + c * size;
      vals.push(size === 1 ? dv.getUint8(o) : size === 2 ? dv.getUint16(o, true) : dv.getUint32(o, true));
      floats.push(readFloat(dv, o, a.componentType, a.normalized === true));
    }
  }
  return { vals, floats, n };
}

function readFloat(dv, o, type, normalized) {
  switch (type) {
    case 5120: return normalized ? Math.max(dv.getInt8(o) / 127, -1) : dv.getInt8(o);
    case 5121: return normalized ? dv.getUint8(o) / 255 : dv.getUint8(o);
    case 5122: return normalized ? Math.max(dv.getInt16(o, true) / 32767, -1) : dv.getInt16(o, true);
    case 5123: return normalized ? dv.getUint16(o, true) / 65535 : dv.getUint16(o, true);
    case 5125: return dv.getUint32(o, true);
    default: return dv.getFloat32(o, true);
  }
}

// The angle in degrees between two 3-vectors (at offsets i and j of two arrays); NaN when either
// is zero (no direction).
export function angleDeg(a, i, b, j) {
  const dot = a[i] * b[j] + a[i + 1] * b[j + 1] + a[i + 2] * b[j + 2];
  const len = Math.hypot(a[i], a[i + 1], a[i + 2]) * Math.hypot(b[j], b[j + 1], b[j + 2]);
  if (!(len > 0)) return NaN;
  return (Math.acos(Math.min(1, Math.max(-1, dot / len))) * 180) / Math.PI;
}

// One primitive of a GLB in the form comparePrimitives takes: `names` its attributes, `mode`,
// `count` its vertices, `keys` each vertex's exact attributes (POSITION and any other but NORMAL)
// as a string, `normals` NORMAL as floats (3 a vertex, or null), `indices` (or null), and
// `accessors` each attribute's componentType/type/normalized.
export function primitiveOf(json, viewBytes, prim) {
  const names = Object.keys(prim.attributes).sort();
  const exact = names.filter((a) => a !== 'NORMAL').map((a) => accessorValues(json, viewBytes, prim.attributes[a]));
  const count = json.accessors[prim.attributes.POSITION].count;
  for (const a of names) {
    if (json.accessors[prim.attributes[a]].count !== count) throw new Error(`${a} has ${json.accessors[prim.attributes[a]].count} values, POSITION ${count}`);
  }
  const keys = Array.from({ length: count }, (_, k) => exact.map((e) => e.vals.slice(k * e.n, (k + 1) * e.n).join(',')).join('|'));
  const normals = prim.attributes.NORMAL === undefined ? null : accessorValues(json, viewBytes, prim.attributes.NORMAL).floats;
  const indices = prim.indices === undefined ? null : accessorValues(json, viewBytes, prim.indices).vals;
  const accessors = Object.fromEntries(names.map((a) => {
    const acc = json.accessors[prim.attributes[a]];
    return [a, `${acc.componentType}/${acc.type}/${acc.normalized === true}`];
  }));
  return { names: names.join(), mode: prim.mode ?? 4, count, keys, normals, indices, accessors };
}

// Compares a decoded primitive (b, `label` says whose) with the plain GLB's (a); throws naming
// the first difference, returns the largest normal angle. The encoder may list the vertices and
// the triangles in another order and rotate a triangle, so the check is that both list the same
// vertices (multiset of keys: positions, exact), the same triangles over them (multiset of
// triangles as key triples, each rotated to a canonical start: the winding must match), and at
// each position the same number of normals, each decoded one within MAX_NORMAL_DEG of its own
// plain one (a perfect matching where a position repeats; `maxNormalDeg` where another bound
// applies).
export function comparePrimitives(a, b, name, label, maxNormalDeg = MAX_NORMAL_DEG) {
  if (a.names !== b.names || a.mode !== b.mode) throw new Error(`${name}: attributes ${a.names} mode ${a.mode}, ${label} ${b.names} mode ${b.mode}`);
  if (a.count !== b.count) throw new Error(`${name}: ${a.count} vertices, ${label} ${b.count}`);
  const same = (x, y) => x.length === y.length && x.every((v, k) => v === y[k]);
  if (!same([...a.keys].sort(), [...b.keys].sort())) throw new Error(`${name}: the vertices (positions) differ`);
  if ((a.indices === null) !== (b.indices === null)) throw new Error(`${name}: indices ${a.indices !== null}, ${label} ${b.indices !== null}`);
  if (a.indices !== null) {
    const tri = (g) => {
      if (g.indices.length % 3 !== 0) throw new Error(`${name}: ${g.indices.length} indices, not whole triangles`);
      const out = [];
      for (let t = 0; t < g.indices.length; t += 3) {
        const i = [g.indices[t], g.indices[t + 1], g.indices[t + 2]];
        if (i.some((x) => x >= g.count)) throw new Error(`${name}: index past the vertices`);
        const v = i.map((x) => g.keys[x]);
        out.push([v, [v[1], v[2], v[0]], [v[2], v[0], v[1]]].map((x) => x.join(' ')).sort()[0]);
      }
      return out.sort();
    };
    const ta = tri(a);
    const tb = tri(b);
    if (!same(ta, tb)) throw new Error(`${name}: the triangles differ (${ta.length} vs ${tb.length}${ta.length === tb.length ? `; e.g. ${ta.find((t, k) => t !== tb[k])} vs ${tb.find((t, k) => t !== ta[k])}` : ''})`);
  }
  let maxDeg = 0;
  if ((a.normals === null) !== (b.normals === null)) throw new Error(`${name}: NORMAL ${a.normals !== null}, ${label} ${b.normals !== null}`);
  if (a.normals !== null) {
    const byKey = new Map();
    a.keys.forEach((key, k) => (byKey.get(key) ?? byKey.set(key, { a: [], b: [] }).get(key)).a.push(k));
    b.keys.forEach((key, k) => byKey.get(key).b.push(k));
    for (const [key, g] of byKey) {
      const fits = (i, j) => angleDeg(a.normals, 3 * i, b.normals, 3 * j) <= maxNormalDeg;
      // Kuhn's matching of the decoded normals at this position to the plain ones (a position
      // holds one vertex, or a few).
      const taken = new Map();
      const place = (j, seen) => {
        for (const i of g.a) {
          if (!fits(i, j) || seen.has(i)) continue;
          seen.add(i);
          if (!taken.has(i) || place(taken.get(i), seen)) {
            taken.set(i, j);
            return true;
          }
        }
        return false;
      };
      for (const j of g.b) {
        if (!place(j, new Set())) {
          const near = Math.min(...g.a.map((i) => angleDeg(a.normals, 3 * i, b.normals, 3 * j)));
          throw new Error(`${name}: the ${label} normal (${Array.from(b.normals.slice(3 * j, 3 * j + 3), (x) => x.toFixed(4))}) at position ${key} is ${near.toFixed(3)}° from the plain one${g.a.length > 1 ? ` nearest it, but ${g.a.length} vertices share the position and no pairing keeps every one within ${maxNormalDeg}°` : ` (> ${maxNormalDeg}°)`}`);
        }
      }
      for (const [i, j] of taken) maxDeg = Math.max(maxDeg, angleDeg(a.normals, 3 * i, b.normals, 3 * j));
    }
  }
  return { maxDeg };
}

// Compares one meshopt GLB with its plain GLB, primitive by primitive (see comparePrimitives);
// every attribute's accessor keeps its component type, type and normalization; throws naming
// the first difference.
export async function compareGlbs(plainBytes, meshoptBytes, name) {
  const p = await views(plainBytes);
  const m = await views(meshoptBytes);
  for (const list of ['extensionsUsed', 'extensionsRequired']) {
    if (!(m.json[list] ?? []).includes(EXT)) throw new Error(`${name}: ${list} lacks ${EXT}`);
  }
  const shape = (g) => g.json.meshes.map((mesh) => mesh.primitives.length).join();
  if (shape(p) !== shape(m)) throw new Error(`${name}: primitives per mesh ${shape(p)}, meshopt ${shape(m)}`);
  let maxDeg = 0;
  p.json.meshes.forEach((mesh, mi) => mesh.primitives.forEach((prim, pi) => {
    const a = primitiveOf(p.json, p.out, prim);
    const b = primitiveOf(m.json, m.out, m.json.meshes[mi].primitives[pi]);
    for (const attr of Object.keys(a.accessors)) {
      if (a.accessors[attr] !== b.accessors[attr]) throw new Error(`${name}: ${attr} is ${a.accessors[attr]}, meshopt ${b.accessors[attr]}`);
    }
    maxDeg = Math.max(maxDeg, comparePrimitives(a, b, name, 'meshopt').maxDeg);
  }));
  return { plain: plainBytes.length, meshopt: meshoptBytes.length, maxDeg };
}

// Every GLB under plainDir/tiles beside its meshopt form under meshoptDir/tiles.
export async function compareTrees(plainDir, meshoptDir) {
  await MeshoptDecoder.ready;
  let plain = 0;
  let meshopt = 0;
  let maxDeg = 0;
  const files = glbFiles(plainDir);
  for (const rel of files) {
    const r = await compareGlbs(fs.readFileSync(path.join(plainDir, rel)), fs.readFileSync(path.join(meshoptDir, rel)), rel);
    plain += r.plain;
    meshopt += r.meshopt;
    maxDeg = Math.max(maxDeg, r.maxDeg);
  }
  return { glbs: files.length, plain, meshopt, maxDeg };
}

// The GLBs under dir, relative to it, sorted.
export function glbFiles(dir) {
  const files = [];
  const walk = (d) => {
    for (const e of fs.readdirSync(d, { withFileTypes: true })) {
      const f = path.join(d, e.name);
      if (e.isDirectory()) walk(f);
      else if (e.name.endsWith('.glb')) files.push(path.relative(dir, f));
    }
  };
  walk(dir);
  return files.sort();
}
