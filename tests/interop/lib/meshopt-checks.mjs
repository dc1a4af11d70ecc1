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

// Compares one meshopt GLB with its plain GLB; throws naming the first difference.
export async function compareGlbs(plainBytes, meshoptBytes, name) {
  const p = await views(plainBytes);
  const m = await views(meshoptBytes);
  for (const list of ['extensionsUsed', 'extensionsRequired']) {
    if (!(m.json[list] ?? []).includes(EXT)) throw new Error(`${name}: ${list} lacks ${EXT}`);
  }
  const prim = (j) => j.meshes[0].primitives[0];
  const pp = prim(p.json);
  const mp = prim(m.json);
  for (const attr of Object.keys(pp.attributes)) {
    const a = accessorValues(p.json, p.out, pp.attributes[attr]);
    const b = accessorValues(m.json, m.out, mp.attributes[attr]);
    if (a.raw.length !== b.raw.length || a.raw.some((x, k) => x !== b.raw[k])) throw new Error(`${name}: ${attr} differs`);
  }
  if (pp.indices !== undefined) {
    const a = accessorValues(p.json, p.out, pp.indices).vals;
    const b = accessorValues(m.json, m.out, mp.indices).vals;
    if (a.length !== b.length) throw new Error(`${name}: ${a.length} indices, decoded ${b.length}`);
    for (let t = 0; t < a.length; t += 3) {
      const [x, y, z] = [a[t], a[t + 1], a[t + 2]];
      const r = [b[t], b[t + 1], b[t + 2]].join();
      if (r !== [x, y, z].join() && r !== [y, z, x].join() && r !== [z, x, y].join()) {
        throw new Error(`${name}: triangle ${t / 3} is ${x},${y},${z}, decoded ${r}`);
      }
    }
  }
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
