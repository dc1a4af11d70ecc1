// Minimal GLB reading: the JSON chunk, and a few facts the checks need.

/** Parses a GLB's header and JSON chunk; throws with a clear message on a malformed file. */
export function readGlbJson(buf) {
  const b = Buffer.from(buf.buffer ?? buf, buf.byteOffset ?? 0, buf.byteLength);
  if (b.length < 20) throw new Error(`GLB too short (${b.length} bytes)`);
  const magic = b.toString('latin1', 0, 4);
  if (magic !== 'glTF') throw new Error(`not a GLB: magic ${JSON.stringify(magic)}`);
  const version = b.readUInt32LE(4);
  const length = b.readUInt32LE(8);
  if (version !== 2) throw new Error(`GLB version ${version}, expected 2`);
  if (length !== b.length) throw new Error(`GLB header length ${length} != ${b.length} bytes received`);
  const jsonLen = b.readUInt32LE(12);
  const jsonType = b.toString('latin1', 16, 20);
  if (jsonType !== 'JSON') throw new Error(`first GLB chunk is ${JSON.stringify(jsonType)}, expected JSON`);
  return JSON.parse(b.toString('utf8', 20, 20 + jsonLen));
}

const COMPONENT_MAX = { 5120: 127, 5121: 255, 5122: 32767, 5123: 65535 };

/**
 * The vertical (glTF +Y) quantization step of node 0's POSITION: node 0's scale[1] (or the
 * length of its matrix's second column), divided by the integer range when the accessor is a
 * normalized integer. Returns {step, scaleY, componentType, normalized}.
 */
export function verticalStep(gltf) {
  const node = gltf.nodes?.[0];
  if (!node) throw new Error('GLB has no node 0');
  let scaleY = 1;
  if (Array.isArray(node.scale)) scaleY = node.scale[1];
  else if (Array.isArray(node.matrix)) scaleY = Math.hypot(node.matrix[4], node.matrix[5], node.matrix[6]);
  const mesh = gltf.meshes?.[node.mesh];
  const posIndex = mesh?.primitives?.[0]?.attributes?.POSITION;
  const acc = gltf.accessors?.[posIndex];
  const componentType = acc?.componentType;
  const normalized = Boolean(acc?.normalized);
  // integer grid coordinates (stored as integers, or as floats when they need more than 16 bits)
  // times the node's scale: one step is scale[1]; a normalized integer spans scale[1] in its range
  const step = normalized ? scaleY / (COMPONENT_MAX[componentType] ?? 1) : scaleY;
  return { step, scaleY, componentType, normalized };
}

/** Counts: nodes, meshes, primitives (by mode), vertices (POSITION counts), indices. */
export function gltfCounts(gltf) {
  const counts = { nodes: gltf.nodes?.length ?? 0, meshes: gltf.meshes?.length ?? 0, primitives: 0, vertices: 0, indices: 0, modes: {} };
  for (const mesh of gltf.meshes ?? []) {
    for (const prim of mesh.primitives ?? []) {
      counts.primitives++;
      const mode = prim.mode ?? 4;
      counts.modes[mode] = (counts.modes[mode] ?? 0) + 1;
      const pos = gltf.accessors?.[prim.attributes?.POSITION];
      counts.vertices += pos?.count ?? 0;
      if (prim.indices !== undefined) counts.indices += gltf.accessors?.[prim.indices]?.count ?? 0;
    }
  }
  return counts;
}

/**
 * The f32 step of a GLB's `FLOAT` positions: the spacing of 32-bit floats at the largest
 * |coordinate| of node 0's POSITION (its accessor's `min`/`max`), 2^(⌊log₂ m⌋ − 23); a
 * position rounds to within half of it. Returns {step, largest}; throws when the positions are
 * not FLOAT or the accessor has no bounds.
 */
export function f32Step(gltf) {
  const node = gltf.nodes?.[0];
  if (!node) throw new Error('GLB has no node 0');
  const posIndex = gltf.meshes?.[node.mesh]?.primitives?.[0]?.attributes?.POSITION;
  const acc = gltf.accessors?.[posIndex];
  if (!acc) throw new Error('node 0 has no POSITION accessor');
  if (acc.componentType !== 5126) throw new Error(`POSITION is component type ${acc.componentType}, not FLOAT (5126)`);
  if (!Array.isArray(acc.min) || !Array.isArray(acc.max)) throw new Error('POSITION has no min/max');
  const largest = Math.max(...acc.min.map(Math.abs), ...acc.max.map(Math.abs));
  const step = largest > 0 ? 2 ** (Math.floor(Math.log2(largest)) - 23) : 2 ** -149;
  return { step, largest };
}
