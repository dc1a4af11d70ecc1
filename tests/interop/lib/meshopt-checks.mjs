// EXT_meshopt_compression GLBs (export --glb-compression meshopt, ?glb=meshopt) decoded with
// meshoptimizer's own decoder (npm `meshoptimizer`, MeshoptDecoder), compared with the plain GLB
// of the same (tile, level): every vertex accessor byte for byte, every index accessor value for
// value with each triangle allowed a cyclic rotation (the triangle codec may rotate a triangle;
// the winding and the triangle order stay), 8-bit indices widened to 16 bits.
import fs from 'node:fs';
import path from 'node:path';
import { MeshoptDecoder } from 'meshoptimizer';

const EXT = 'EXT_meshopt_compression';

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

function accessorValues(json, viewBytes, i) {
  const a = json.accessors[i];
  const v = json.bufferViews[a.bufferView];
  const size = SIZES[a.componentType];
  const n = COMPONENTS[a.type];
  const stride = v.byteStride ?? size * n;
  const bytes = viewBytes[a.bufferView];
  const dv = new DataView(bytes.buffer, bytes.byteOffset, bytes.byteLength);
  const vals = [];
  const raw = [];
  for (let k = 0; k < a.count; k++) {
    for (let c = 0; c < n; c++) {
      const o = (a.byteOffset ?? 0) + k * stride + c * size;
      vals.push(size === 1 ? dv.getUint8(o) : size === 2 ? dv.getUint16(o, true) : dv.getUint32(o, true));
      for (let b = 0; b < size; b++) raw.push(bytes[o + b]);
    }
  }
  return { vals, raw };
}

// Compares one meshopt GLB with its plain GLB; throws naming the first difference. Vertex
// attributes are compared byte for byte per vertex; the encoder may list the vertices and the
// triangles in another order (for locality) and rotate a triangle, so the check is that both list
// the same vertices (multiset of attribute tuples) and the same triangles over them (multiset of
// triangles as vertex tuples, each rotated to a canonical start: the winding must match).
export async function compareGlbs(plainBytes, meshoptBytes, name) {
  const p = await views(plainBytes);
  const m = await views(meshoptBytes);
  for (const list of ['extensionsUsed', 'extensionsRequired']) {
    if (!(m.json[list] ?? []).includes(EXT)) throw new Error(`${name}: ${list} lacks ${EXT}`);
  }
  const side = (g) => {
    const prim = g.json.meshes[0].primitives[0];
    const names = Object.keys(prim.attributes).sort();
    const attrs = names.map((a) => {
      const acc = g.json.accessors[prim.attributes[a]];
      const { raw } = accessorValues(g.json, g.out, prim.attributes[a]);
      const w = raw.length / acc.count;
      return (k) => raw.slice(k * w, (k + 1) * w).join(',');
    });
    const count = g.json.accessors[prim.attributes[names[0]]].count;
    const vertex = (k) => attrs.map((f) => f(k)).join('|');
    const vertices = Array.from({ length: count }, (_, k) => vertex(k)).sort();
    let triangles = [];
    if (prim.indices !== undefined) {
      const idx = accessorValues(g.json, g.out, prim.indices).vals;
      for (let t = 0; t < idx.length; t += 3) {
        if (idx[t] >= count || idx[t + 1] >= count || idx[t + 2] >= count) throw new Error(`${name}: index past the vertices`);
        const v = [vertex(idx[t]), vertex(idx[t + 1]), vertex(idx[t + 2])];
        const r = [v, [v[1], v[2], v[0]], [v[2], v[0], v[1]]].map((x) => x.join(' ')).sort()[0];
        triangles.push(r);
      }
      triangles = triangles.sort();
    }
    return { names: names.join(), vertices, triangles, mode: prim.mode ?? 4 };
  };
  const a = side(p);
  const b = side(m);
  if (a.names !== b.names || a.mode !== b.mode) throw new Error(`${name}: attributes ${a.names} mode ${a.mode}, meshopt ${b.names} mode ${b.mode}`);
  const same = (x, y) => x.length === y.length && x.every((v, k) => v === y[k]);
  if (!same(a.vertices, b.vertices)) throw new Error(`${name}: the vertices differ`);
  if (!same(a.triangles, b.triangles)) throw new Error(`${name}: the triangles differ (${a.triangles.length} vs ${b.triangles.length})`);
  return { plain: plainBytes.length, meshopt: meshoptBytes.length };
}

// Every GLB under plainDir/tiles beside its meshopt form under meshoptDir/tiles.
export async function compareTrees(plainDir, meshoptDir) {
  await MeshoptDecoder.ready;
  const files = [];
  const walk = (d) => {
    for (const e of fs.readdirSync(d, { withFileTypes: true })) {
      const f = path.join(d, e.name);
      if (e.isDirectory()) walk(f);
      else if (e.name.endsWith('.glb')) files.push(path.relative(plainDir, f));
    }
  };
  walk(plainDir);
  let plain = 0;
  let meshopt = 0;
  for (const rel of files.sort()) {
    const r = await compareGlbs(fs.readFileSync(path.join(plainDir, rel)), fs.readFileSync(path.join(meshoptDir, rel)), rel);
    plain += r.plain;
    meshopt += r.meshopt;
  }
  return { glbs: files.length, plain, meshopt };
}
