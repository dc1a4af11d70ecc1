// Quantized-mesh-1.0 globe terrain, checked with no terrastream code: tiles fetched over HTTP,
// decoded by HERE's @here/quantized-mesh-decoder (npm), their structure walked again by the
// spec (lengths, extensions), the header checked against the decoded vertices (WGS 84
// geodesy here, CesiumJS's horizon-culling test), the metadata extension against layer.json,
// and the shared edges of neighbouring tiles compared (the crack test). Also the expected
// heights of CesiumJS's sampleTerrainMostDetailed from the source raster alone (bilinear at
// the point's CRS position, proj4js, EGM96 from lib/geoid.mjs).
import http from 'node:http';
import zlib from 'node:zlib';
import { createRequire } from 'node:module';
import { ecefOf, EPSG_DEFS, toLonLat, interiorGrid } from './earth.mjs';

const require = createRequire(import.meta.url);
const hereDecode = require('@here/quantized-mesh-decoder').default;
const proj4 = require('proj4');

/** The largest quantized u, v or height. */
export const QMAX = 32767;
/** What a client that wants every extension sends (the spec's Accept negotiation). */
export const ACCEPT_ALL = 'application/vnd.quantized-mesh;extensions=octvertexnormals-watermask-metadata';
/** The plain format, no extension. */
export const ACCEPT_NONE = 'application/vnd.quantized-mesh';

const A = 6378137.0;
const F = 1 / 298.257223563;
/** WGS 84 radii: what CesiumJS divides ECEF by for its ellipsoid-scaled space. */
export const RADII = [A, A, A * (1 - F)];
const DEG = Math.PI / 180;

// ---------- HTTP ----------

const agent = new http.Agent({ keepAlive: true, maxSockets: 8 });

/**
 * GET `url` with `headers` through node:http (no automatic decompression: the bytes as sent).
 * Resolves to `{status, headers, body}` (body a Buffer).
 */
export function httpGet(url, headers = {}, timeoutMs = 60_000) {
  return new Promise((resolve, reject) => {
    const req = http.get(url, { headers, agent, timeout: timeoutMs }, (res) => {
      const chunks = [];
      res.on('data', (c) => chunks.push(c));
      res.on('end', () => resolve({ status: res.statusCode, headers: res.headers, body: Buffer.concat(chunks) }));
      res.on('error', reject);
    });
    req.on('timeout', () => req.destroy(new Error(`GET ${url}: no answer within ${timeoutMs / 1000} s`)));
    req.on('error', reject);
  });
}

/** Lets go of the keep-alive sockets (so the process can end). */
export function closeHttp() {
  agent.destroy();
}

// ---------- the geodetic tiling (EPSG:4326, TMS: two root tiles, y from the south) ----------

export const tileKey = (z, x, y) => `${z}/${x}/${y}`;

/** Tiles across and up at zoom z. */
export function tilesAt(z) {
  return { cols: 2 ** (z + 1), rows: 2 ** z };
}

/** A tile's rectangle in degrees. */
export function tileRect(z, x, y) {
  const size = 180 / 2 ** z;
  const west = -180 + x * size, south = -90 + y * size;
  return { west, south, east: west + size, north: south + size };
}

/** Every tile layer.json's `available` names, each once: [{z, x, y}], zoom by zoom. */
export function layerTiles(layer) {
  const out = [];
  const seen = new Set();
  (layer.available ?? []).forEach((ranges, z) => {
    for (const r of ranges) {
      for (let y = r.startY; y <= r.endY; y++) for (let x = r.startX; x <= r.endX; x++) {
        const k = tileKey(z, x, y);
        if (!seen.has(k)) {
          seen.add(k);
          out.push({ z, x, y });
        }
      }
    }
  });
  return out;
}

/** Whether `ranges` (layer.json's {startX, startY, endX, endY}, inclusive) hold tile (x, y). */
export function rangesHold(ranges, x, y) {
  return (ranges ?? []).some((r) => x >= r.startX && x <= r.endX && y >= r.startY && y <= r.endY);
}

/** `ranges` clipped to the rectangle of tiles [x0, x1] × [y0, y1]. */
export function clipRanges(ranges, x0, y0, x1, y1) {
  const out = [];
  for (const r of ranges ?? []) {
    const c = { startX: Math.max(r.startX, x0), startY: Math.max(r.startY, y0), endX: Math.min(r.endX, x1), endY: Math.min(r.endY, y1) };
    if (c.startX <= c.endX && c.startY <= c.endY) out.push(c);
  }
  return out;
}

/**
 * Whether two lists of tile ranges cover the same tiles (however they are cut into
 * rectangles): compared on the grid of their distinct edges, so any size costs little.
 * Returns null when equal, else one tile that only one of them holds: {x, y, inA}.
 */
export function rangesDiff(a, b) {
  const xs = new Set(), ys = new Set();
  for (const r of [...(a ?? []), ...(b ?? [])]) {
    xs.add(r.startX);
    xs.add(r.endX + 1);
    ys.add(r.startY);
    ys.add(r.endY + 1);
  }
  const sx = [...xs].sort((p, q) => p - q), sy = [...ys].sort((p, q) => p - q);
  for (const y of sy) for (const x of sx) {
    const inA = rangesHold(a, x, y), inB = rangesHold(b, x, y);
    if (inA !== inB) return { x, y, inA };
  }
  return null;
}

// ---------- decoding ----------

/** CesiumJS's oct decoding of a normal's two bytes (AttributeCompression.octDecode): a unit vector. */
export function octDecode(bx, by) {
  let x = (bx / 255) * 2 - 1, y = (by / 255) * 2 - 1;
  const z = 1 - (Math.abs(x) + Math.abs(y));
  if (z < 0) {
    const ox = x;
    x = (1 - Math.abs(y)) * (ox >= 0 ? 1 : -1);
    y = (1 - Math.abs(ox)) * (y >= 0 ? 1 : -1);
  }
  const l = Math.hypot(x, y, z);
  return [x / l, y / l, z / l];
}

/**
 * The tile's byte layout walked by the spec (independently of the decoder): where the indices
 * and edge lists end, and each extension `{id, length}`; throws when a length runs past the end
 * or bytes are left over.
 */
export function qmLayout(buf) {
  const dv = new DataView(buf.buffer, buf.byteOffset, buf.byteLength);
  const need = (at, n, what) => {
    if (at + n > buf.byteLength) throw new Error(`truncated: ${what} needs bytes ${at}..${at + n}, the tile has ${buf.byteLength}`);
  };
  need(0, 92, 'the header and vertex count');
  const n = dv.getUint32(88, true);
  let at = 92 + 6 * n;
  const wide = n > 65536;
  const bytes = wide ? 4 : 2;
  if (wide && at % 4) at += 4 - (at % 4);
  need(at, 4, 'the triangle count');
  const triangles = dv.getUint32(at, true);
  at += 4 + 3 * triangles * bytes;
  const edges = [];
  for (const side of ['west', 'south', 'east', 'north']) {
    need(at, 4, `the ${side} edge count`);
    const k = dv.getUint32(at, true);
    edges.push(k);
    at += 4 + k * bytes;
  }
  need(at, 0, 'the edge lists');
  const extensions = [];
  while (at < buf.byteLength) {
    need(at, 5, 'an extension header');
    const id = dv.getUint8(at), length = dv.getUint32(at + 1, true);
    need(at + 5, length, `extension ${id}`);
    extensions.push({ id, length, at: at + 5 });
    at += 5 + length;
  }
  return { vertices: n, triangles, wide, edges, extensions, end: at };
}

/**
 * Decodes one tile with @here/quantized-mesh-decoder and checks its layout by the spec
 * (qmLayout). Returns `{header, n, u, v, h, triangles, west, south, east, north, normals,
 * waterMask, metadata, layout}`; throws an Error that says what is wrong.
 */
export function decodeTile(buf) {
  // a copy of its own: the decoder makes typed arrays on the ArrayBuffer at absolute offsets
  const ab = buf.buffer.slice(buf.byteOffset, buf.byteOffset + buf.byteLength);
  let d;
  try {
    d = hereDecode(ab);
  } catch (err) {
    throw new Error(`@here/quantized-mesh-decoder: ${err.message}`);
  }
  const layout = qmLayout(buf);
  const n = d.vertexData.length / 3;
  if (n !== layout.vertices) throw new Error(`the decoder read ${n} vertices, the tile says ${layout.vertices}`);
  const ext = d.extensions ?? {};
  for (const e of layout.extensions) {
    if (e.id === 1 && e.length !== 2 * n) throw new Error(`the octvertexnormals extension holds ${e.length} bytes, 2 per vertex is ${2 * n}`);
    if (e.id === 2 && e.length !== 1 && e.length !== 65536) throw new Error(`the watermask extension holds ${e.length} bytes (1 or 256×256)`);
    if (e.id === 4) {
      const jsonLength = buf.readUInt32LE(e.at);
      if (jsonLength + 4 !== e.length) throw new Error(`the metadata extension holds ${e.length} bytes, its JSON length prefix says ${jsonLength} (+ 4)`);
    }
    if (![1, 2, 4].includes(e.id)) throw new Error(`an unknown extension id ${e.id}`);
  }
  return {
    header: d.header,
    n,
    u: d.vertexData.subarray(0, n),
    v: d.vertexData.subarray(n, 2 * n),
    h: d.vertexData.subarray(2 * n, 3 * n),
    triangles: d.triangleIndices,
    west: d.westIndices,
    south: d.southIndices,
    east: d.eastIndices,
    north: d.northIndices,
    normals: ext.vertexNormals,
    waterMask: ext.waterMask,
    metadata: ext.metadata,
    layout,
  };
}

/** A decoded vertex's height in metres, as a client computes it from the header. */
export function vertexHeight(t, k) {
  const { minHeight, maxHeight } = t.header;
  return minHeight + (t.h[k] / QMAX) * (maxHeight - minHeight);
}

/** A decoded vertex's longitude and latitude in degrees on tile `rect`. */
export function vertexLonLat(t, rect, k) {
  return [rect.west + (t.u[k] / QMAX) * (rect.east - rect.west), rect.south + (t.v[k] / QMAX) * (rect.north - rect.south)];
}

const dot = (a, b) => a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
const sub = (a, b) => [a[0] - b[0], a[1] - b[1], a[2] - b[2]];
const scaled = (p) => [p[0] / RADII[0], p[1] / RADII[1], p[2] / RADII[2]];

/**
 * CesiumJS's horizon culling (EllipsoidalOccluder.isScaledSpacePointVisible): whether a point
 * in ellipsoid-scaled space can be seen from a camera there, the unit sphere in the way.
 */
export function scaledPointVisible(point, camera) {
  const vhMagSq = dot(camera, camera) - 1;
  const vt = sub(point, camera);
  const vtDotVc = -dot(vt, camera);
  const occluded = vhMagSq < 0 ? vtDotVc > 0 : vtDotVc > vhMagSq && (vtDotVc * vtDotVc) / dot(vt, vt) > vhMagSq;
  return !occluded;
}

/** Unit vectors around `d` at angle `theta` (radians), `count` azimuths. */
function around(d, theta, count) {
  const helper = Math.abs(d[2]) < 0.9 ? [0, 0, 1] : [1, 0, 0];
  let e1 = [d[1] * helper[2] - d[2] * helper[1], d[2] * helper[0] - d[0] * helper[2], d[0] * helper[1] - d[1] * helper[0]];
  const l1 = Math.hypot(...e1);
  e1 = e1.map((c) => c / l1);
  const e2 = [d[1] * e1[2] - d[2] * e1[1], d[2] * e1[0] - d[0] * e1[2], d[0] * e1[1] - d[1] * e1[0]];
  const out = [];
  for (let k = 0; k < count; k++) {
    const a = (2 * Math.PI * k) / count;
    out.push([0, 1, 2].map((i) => Math.cos(theta) * d[i] + Math.sin(theta) * (Math.cos(a) * e1[i] + Math.sin(a) * e2[i])));
  }
  return out;
}

/**
 * Camera positions (scaled space) around direction d, from just above the surface to far out:
 * at each distance r, where a point of magnitude `mag` along d has just set below the horizon
 * (the angle acos(1/r) + acos(1/mag) from d, and a little beyond): where a horizon point too
 * low would let a vertex show.
 */
function horizonCameras(d, mag) {
  const cams = [];
  const hp = Math.acos(1 / Math.max(mag, 1));
  for (const r of [1.00002, 1.0002, 1.002, 1.02, 1.2, 2, 4]) {
    const hc = Math.acos(1 / r);
    for (const extra of [1e-7, 1e-4, 3e-3, 0.03]) {
      const theta = hc + hp + extra;
      if (theta >= Math.PI) continue;
      for (const dir of around(d, theta, 12)) cams.push(dir.map((c) => c * r));
    }
  }
  return cams;
}

/**
 * Checks one decoded tile `t` (z, x, y) against the format and its own header. `layer`:
 * layer.json (for the metadata extension). Returns `{problems, figures}`; figures: the
 * bounding-sphere excess, the horizon point's magnitude, the normals' smallest dot product
 * with the ellipsoid's up, counted cameras.
 */
export function checkTile(t, { z, x, y }, layer, { wantNormals = true, wantMetadataAt = null } = {}) {
  const where = `tile ${tileKey(z, x, y)}`;
  const problems = [];
  const bad = (m) => problems.push(`${where}: ${m}`);
  const rect = tileRect(z, x, y);
  const hd = t.header;
  const figures = { sphereExcess: -Infinity, horizonMag: NaN, minUpDot: Infinity, edgeVertices: 0 };
  if (t.n === 0 || t.triangles.length === 0) bad(`${t.n} vertices, ${t.triangles.length / 3} triangles`);
  if (!(Number.isFinite(hd.minHeight) && Number.isFinite(hd.maxHeight) && hd.minHeight <= hd.maxHeight)) bad(`header heights min ${hd.minHeight} > max ${hd.maxHeight} (or not finite)`);
  for (const [name, arr] of [['u', t.u], ['v', t.v], ['height', t.h]]) {
    const k = arr.findIndex((q) => q > QMAX);
    if (k >= 0) bad(`vertex ${k}: quantized ${name} ${arr[k]} leaves 0..32767 (its deltas wrap)`);
  }
  // triangles: indices in range, counter-clockwise in (u, v) seen from above, none degenerate
  let cw = 0, flat = 0;
  for (let i = 0; i < t.triangles.length; i += 3) {
    const [a, b, c] = [t.triangles[i], t.triangles[i + 1], t.triangles[i + 2]];
    if (a >= t.n || b >= t.n || c >= t.n) {
      bad(`triangle ${i / 3} indexes vertex ${Math.max(a, b, c)} of ${t.n}`);
      break;
    }
    const cross = (t.u[b] - t.u[a]) * (t.v[c] - t.v[a]) - (t.v[b] - t.v[a]) * (t.u[c] - t.u[a]);
    if (cross < 0) cw++;
    else if (cross === 0) flat++;
  }
  if (cw) bad(`${cw} of ${t.triangles.length / 3} triangles are clockwise in (u, v) (the format says counter-clockwise; CesiumJS culls their back faces)`);
  if (flat) bad(`${flat} triangles have no area in (u, v)`);
  // edge lists: exactly the vertices on each edge (skirts hang from them)
  const sides = [['west', t.west, (k) => t.u[k] === 0], ['south', t.south, (k) => t.v[k] === 0], ['east', t.east, (k) => t.u[k] === QMAX], ['north', t.north, (k) => t.v[k] === QMAX]];
  for (const [name, list, on] of sides) {
    const inList = new Set(list);
    const off = [...inList].filter((k) => !on(k));
    let missing = 0;
    for (let k = 0; k < t.n; k++) if (on(k) && !inList.has(k)) missing++;
    if (off.length) bad(`the ${name} edge list names ${off.length} vertices not on the ${name} edge (first: vertex ${off[0]} at u ${t.u[off[0]]}, v ${t.v[off[0]]})`);
    if (missing) bad(`${missing} vertices on the ${name} edge are missing from its edge list (no skirt there)`);
    if (inList.size !== list.length) bad(`the ${name} edge list names a vertex twice`);
    figures.edgeVertices += list.length;
  }
  // positions as a client decodes them; the bounding sphere must hold them (to half a u/v step)
  const ecef = new Array(t.n);
  const up = new Array(t.n);
  for (let k = 0; k < t.n; k++) {
    const [lon, lat] = vertexLonLat(t, rect, k);
    ecef[k] = ecefOf(lon, lat, vertexHeight(t, k));
    up[k] = [Math.cos(lat * DEG) * Math.cos(lon * DEG), Math.cos(lat * DEG) * Math.sin(lon * DEG), Math.sin(lat * DEG)];
  }
  const c = [hd.boundingSphereCenterX, hd.boundingSphereCenterY, hd.boundingSphereCenterZ];
  const halfStep = (0.5 / QMAX) * (180 / 2 ** z) * DEG * A * Math.SQRT2;
  const sphereTol = halfStep + 0.01;
  figures.sphereTol = sphereTol;
  let worst = { d: -Infinity, k: -1 };
  for (let k = 0; k < t.n; k++) {
    const d = Math.hypot(...sub(ecef[k], c)) - hd.boundingSphereRadius;
    if (d > worst.d) worst = { d, k };
  }
  figures.sphereExcess = worst.d;
  if (!(hd.boundingSphereRadius > 0) || worst.d > sphereTol) bad(`the bounding sphere (radius ${hd.boundingSphereRadius.toFixed(3)} m) leaves vertex ${worst.k} outside by ${worst.d.toFixed(3)} m (> ${sphereTol.toFixed(3)} m, half a u/v step + 1 cm)`);
  const centre = [hd.centerX, hd.centerY, hd.centerZ];
  const cOff = Math.hypot(...sub(centre, c)) - hd.boundingSphereRadius;
  if (!(cOff <= sphereTol)) bad(`the header's centre lies ${cOff.toFixed(1)} m outside its own bounding sphere`);
  // the horizon-occlusion point: ellipsoid-scaled (magnitude about 1, not metres), and sound:
  // from every test camera that cannot see it, no vertex can be seen either (vertices below the
  // ellipsoid lifted onto it, as CesiumJS's computation treats them). Not for the two root
  // tiles: a hemisphere has no sound point under CesiumJS's test (any point is below the horizon
  // of a camera a little more than 90° away, while the tile's edge next to it is not).
  const P = [hd.horizonOcclusionPointX, hd.horizonOcclusionPointY, hd.horizonOcclusionPointZ];
  const mag = Math.hypot(...P);
  figures.horizonMag = mag;
  if (!Number.isFinite(mag) || mag < 1 - 1e-9) bad(`the horizon-occlusion point has magnitude ${mag} (< 1: inside the ellipsoid, in scaled units)`);
  else if (z >= 2 && mag >= 2) bad(`the horizon-occlusion point has magnitude ${mag.toPrecision(6)}: not in ellipsoid-scaled units${mag > 1e5 ? ' (metres?)' : ''}; a zoom-${z} tile's is below 2`);
  else if (z > 0) {
    const verts = ecef.map((p) => {
      const s = scaled(p);
      const m = Math.hypot(...s);
      return m < 1 ? s.map((v) => v / m) : s;
    });
    const d = P.map((v) => v / mag);
    let culled = 0, leak = null;
    for (const cam of horizonCameras(d, mag)) {
      if (scaledPointVisible(P, cam)) continue;
      culled++;
      const k = verts.findIndex((v) => scaledPointVisible(v, cam));
      if (k >= 0) {
        leak = { cam, k };
        break;
      }
    }
    figures.horizonCulledCameras = culled;
    if (leak) bad(`the horizon-occlusion point (magnitude ${mag.toFixed(6)}) is below the horizon of camera (${leak.cam.map((v) => v.toFixed(5)).join(', ')}) (scaled) while vertex ${leak.k} is above it: CesiumJS would cull a visible tile`);
  }
  // normals: 2 bytes a vertex, each (decoded as CesiumJS does) a finite unit vector facing out
  if (wantNormals) {
    if (!t.normals) bad('no octvertexnormals extension though it was asked for');
    else {
      for (let k = 0; k < t.n; k++) {
        const nrm = octDecode(t.normals[2 * k], t.normals[2 * k + 1]);
        const len = Math.hypot(...nrm);
        if (!(Math.abs(len - 1) < 1e-9)) {
          bad(`vertex ${k}: normal of length ${len}`);
          break;
        }
        figures.minUpDot = Math.min(figures.minUpDot, dot(nrm, up[k]));
      }
      if (figures.minUpDot <= 0) bad(`a vertex normal points into the ground (smallest dot with the ellipsoid's up ${figures.minUpDot.toFixed(3)})`);
    }
  }
  if (t.waterMask !== undefined && t.waterMask.byteLength !== 1 && t.waterMask.byteLength !== 65536) bad(`a water mask of ${t.waterMask.byteLength} bytes`);
  // metadata: at the zooms layer.json's metadataAvailability names, the availability of the
  // tile's own descendants for that many zooms, as layer.json has it
  if (wantMetadataAt !== null && z % wantMetadataAt === 0) {
    const maxZoom = (layer.available ?? []).length - 1;
    if (!t.metadata) bad(`no metadata extension at zoom ${z} (layer.json: metadataAvailability ${wantMetadataAt})`);
    else if (!Array.isArray(t.metadata.available)) bad(`the metadata has no "available" array: ${JSON.stringify(t.metadata).slice(0, 200)}`);
    else {
      for (let dz = 1; dz <= Math.max(wantMetadataAt, t.metadata.available.length); dz++) {
        const k = 2 ** dz;
        const got = t.metadata.available[dz - 1] ?? [];
        const want = z + dz <= maxZoom && dz <= wantMetadataAt ? clipRanges(layer.available[z + dz], x * k, y * k, x * k + k - 1, y * k + k - 1) : [];
        const diff = rangesDiff(got, want);
        if (diff) {
          bad(`metadata availability at zoom ${z + dz} differs from layer.json's: tile ${tileKey(z + dz, diff.x, diff.y)} is ${diff.inA ? 'in the metadata only' : 'in layer.json only'} (metadata ${JSON.stringify(got)}, layer.json clipped to the descendants ${JSON.stringify(want)})`);
          break;
        }
      }
    }
  }
  return { problems, figures };
}

// ---------- the crack test ----------

/** The vertices of one edge: position along it → {k, h (m), normal bytes}; duplicates noted. */
function edgeOf(t, side) {
  const list = t[side];
  const along = side === 'west' || side === 'east' ? t.v : t.u;
  const m = new Map();
  const dup = [];
  for (const k of list) {
    const p = along[k];
    if (m.has(p)) dup.push(p);
    m.set(p, { k, h: vertexHeight(t, k), n: t.normals ? [t.normals[2 * k], t.normals[2 * k + 1]] : null });
  }
  return { m, dup };
}

/**
 * Compares the shared edge of tiles a and b (`sideA` of a against `sideB` of b): the same
 * positions along it, heights within `tolM`, the same normals (the same bytes, or two codes of
 * one vector: `sameVector` counts those). `place(p)` names a position along the edge (0…32767)
 * in messages. Returns `{vertices, worstDh, sameVector, problems}`.
 */
export function compareEdge(a, sideA, b, sideB, { nameA, nameB, tolM = 1e-6, place = (p) => `${p}` }) {
  const ea = edgeOf(a, sideA), eb = edgeOf(b, sideB);
  const problems = [];
  const what = `${nameA} ${sideA} edge vs ${nameB} ${sideB} edge`;
  if (ea.dup.length || eb.dup.length) problems.push(`${what}: two vertices at one position (${ea.dup.length ? nameA : nameB}, position ${(ea.dup[0] ?? eb.dup[0])})`);
  const onlyA = [...ea.m.keys()].filter((p) => !eb.m.has(p));
  const onlyB = [...eb.m.keys()].filter((p) => !ea.m.has(p));
  if (onlyA.length || onlyB.length) {
    problems.push(`${what}: ${onlyA.length + onlyB.length} vertices on one side only (${nameA}: ${onlyA.slice(0, 4).join(', ') || '-'}; ${nameB}: ${onlyB.slice(0, 4).join(', ') || '-'} of 32767 along the edge): a T-junction, a crack`);
  }
  let worstDh = 0, badH = 0, badN = 0, sameVector = 0, firstH = null, firstN = null;
  for (const [p, va] of ea.m) {
    const vb = eb.m.get(p);
    if (!vb) continue;
    const dh = Math.abs(va.h - vb.h);
    worstDh = Math.max(worstDh, dh);
    if (!(dh <= tolM)) {
      badH++;
      firstH ??= `at ${place(p)}: ${va.h.toFixed(6)} m vs ${vb.h.toFixed(6)} m`;
    }
    if (va.n && vb.n && (va.n[0] !== vb.n[0] || va.n[1] !== vb.n[1])) {
      // one direction, two codes: the octahedral code is not unique on the octahedron's
      // folded edges (the −z corners: a pole's normal); the client decodes the same vector
      const na = octDecode(...va.n), nb = octDecode(...vb.n);
      if (Math.max(...na.map((c, i) => Math.abs(c - nb[i]))) < 1e-12) sameVector++;
      else {
        badN++;
        const angle = Math.acos(Math.min(1, dot(na, nb))) / DEG;
        firstN ??= `at ${place(p)}: bytes [${va.n}] vs [${vb.n}], ${angle.toFixed(2)}° apart`;
      }
    }
  }
  if (badH) problems.push(`${what}: ${badH} shared vertices differ in height by more than ${tolM} m (worst ${worstDh.toExponential(3)} m; first ${firstH})`);
  if (badN) problems.push(`${what}: ${badN} shared vertices have different normals (first ${firstN})`);
  return { vertices: Math.min(ea.m.size, eb.m.size), worstDh, sameVector, problems };
}

/**
 * The crack test over `tiles` (Map key → decoded tile): every pair of same-zoom neighbours,
 * east-west (across the antimeridian too: x = last and x = 0) and north-south. Returns counts,
 * the worst height difference and problems naming the tiles. Also the poles: every vertex of a
 * top (bottom) row tile's north (south) edge is the pole, one point: one height.
 */
export function crackTest(tiles) {
  const r = { ew: 0, ns: 0, antimeridian: 0, vertices: 0, sameVector: 0, worstDh: 0, problems: [], poles: [] };
  for (const [key, a] of tiles) {
    const [z, x, y] = key.split('/').map(Number);
    const { cols, rows } = tilesAt(z);
    const xe = (x + 1) % cols;
    const east = tiles.get(tileKey(z, xe, y));
    if (east && xe !== x) {
      const r0 = tileRect(z, x, y);
      const place = (p) => `v ${p} (lon ${r0.east}°, lat ${(r0.south + (p / QMAX) * (r0.north - r0.south)).toFixed(4)}°)`;
      const c = compareEdge(a, 'east', east, 'west', { nameA: key, nameB: tileKey(z, xe, y), place });
      r.ew++;
      if (xe === 0) r.antimeridian++;
      r.vertices += c.vertices;
      r.sameVector += c.sameVector;
      r.worstDh = Math.max(r.worstDh, c.worstDh);
      r.problems.push(...c.problems);
    }
    const north = y + 1 < rows ? tiles.get(tileKey(z, x, y + 1)) : null;
    if (north) {
      const r0 = tileRect(z, x, y);
      const place = (p) => `u ${p} (lon ${(r0.west + (p / QMAX) * (r0.east - r0.west)).toFixed(4)}°, lat ${r0.north}°)`;
      const c = compareEdge(a, 'north', north, 'south', { nameA: key, nameB: tileKey(z, x, y + 1), place });
      r.ns++;
      r.vertices += c.vertices;
      r.sameVector += c.sameVector;
      r.worstDh = Math.max(r.worstDh, c.worstDh);
      r.problems.push(...c.problems);
    }
  }
  for (const pole of ['north', 'south']) {
    const hs = [];
    for (const [key, t] of tiles) {
      const [z, , y] = key.split('/').map(Number);
      if (pole === 'north' ? y !== tilesAt(z).rows - 1 : y !== 0) continue;
      for (const k of t[pole]) hs.push({ key, h: vertexHeight(t, k), z });
    }
    if (!hs.length) continue;
    const byZoom = new Map();
    for (const s of hs) {
      const g = byZoom.get(s.z) ?? { lo: s, hi: s, n: 0 };
      if (s.h < g.lo.h) g.lo = s;
      if (s.h > g.hi.h) g.hi = s;
      g.n++;
      byZoom.set(s.z, g);
    }
    for (const [z, g] of byZoom) r.poles.push({ pole, z, vertices: g.n, spread: g.hi.h - g.lo.h, lo: g.lo, hi: g.hi });
  }
  return r;
}

// ---------- expected heights from the source raster ----------

/** A function (lonDeg, latDeg) → [x, y] in EPSG:`epsg` (proj4js, lib/earth.mjs's definitions). */
export function fromLonLat(epsg) {
  const def = EPSG_DEFS[epsg];
  if (!def) throw new Error(`EPSG:${epsg} is not among the definitions of lib/earth.mjs`);
  if (epsg === 4326) return (lon, lat) => [lon, lat];
  const p = proj4(EPSG_DEFS[4326], def);
  return (lon, lat) => p.forward([lon, lat]);
}

/** The raster's map → fractional (col, row) of sample centres (its georeference is axis-aligned). */
export function pixelOf(raster, x, y) {
  const [x0, y0] = raster.world(0, 0);
  const dx = raster.world(1, 0)[0] - x0, dy = raster.world(0, 1)[1] - y0;
  return [(x - x0) / dx, (y - y0) / dy];
}

/**
 * The raster's heights bilinear at map position (x, y), and the steepest slope (m/m) of the
 * 3×3 cells around it with data (for a margin: `metresPerUnit` converts the map's units). `h` is
 * NaN when one of the four samples around the point is no-data or outside.
 */
export function bilinearAt(raster, x, y, metresPerUnit = [1, 1]) {
  const [c, r] = pixelOf(raster, x, y);
  const c0 = Math.floor(c), r0 = Math.floor(r);
  const fx = c - c0, fy = r - r0;
  const at = (cc, rr) => (cc < 0 || rr < 0 || cc >= raster.width || rr >= raster.height ? NaN : raster.at(cc, rr));
  const h = (at(c0, r0) * (1 - fx) + at(c0 + 1, r0) * fx) * (1 - fy) + (at(c0, r0 + 1) * (1 - fx) + at(c0 + 1, r0 + 1) * fx) * fy;
  const [px, py] = [Math.abs(raster.world(1, 0)[0] - raster.world(0, 0)[0]) * metresPerUnit[0], Math.abs(raster.world(0, 1)[1] - raster.world(0, 0)[1]) * metresPerUnit[1]];
  // the steepest of the 3×3 cells around the point's cell (each cell's forward differences)
  let slope = 0;
  for (let rr = r0 - 1; rr <= r0 + 1; rr++) for (let cc = c0 - 1; cc <= c0 + 1; cc++) {
    const g = Math.hypot((at(cc + 1, rr) - at(cc, rr)) / px, (at(cc, rr + 1) - at(cc, rr)) / py);
    if (Number.isFinite(g)) slope = Math.max(slope, g);   // cells beside no-data left out
  }
  return { h, slope, col: c, row: r };
}

/** Degrees of one sample step of the terrain's geodetic tiles at zoom z (65 × 65 samples a tile). */
export const sampleStep = (z) => 180 / (64 * 2 ** z);

/** (lon, lat) moved to the nearest sample position of zoom z's tiles. */
export function snapToSamples(lon, lat, z) {
  const s = sampleStep(z);
  return [-180 + Math.round((lon + 180) / s) * s, -90 + Math.round((lat + 90) / s) * s];
}

/**
 * Half a quantized u/v step of a zoom-z tile at latitude `lat`, in metres (east, north): how far
 * a client's decoded vertex may lie from the sample it stands for.
 */
export function halfUvStep(z, lat) {
  const deg = (0.5 / QMAX) * (180 / 2 ** z);
  return [deg * DEG * A * Math.cos(lat * DEG), deg * DEG * A];
}

/**
 * Where CesiumJS's terrain heights are checked, and what they must be, from the source raster
 * alone: a k×k grid of raster samples (not the outer 2, off no-data: earth.mjs interiorGrid),
 * each to longitude and latitude (proj4js), moved to the nearest sample position of the deepest
 * zoom's tiles (where a tile's measured error holds: its mesh against its samples), then back
 * to the raster's CRS: the expected ellipsoidal height = the raster bilinear there + the EGM96
 * undulation (`geoid`, when the heights are EGM96). `margin`: 0.1 m + the raster's steepest
 * slope around the point × half a quantized u/v step (how far a client's vertex may sit from
 * its sample). Returns [{lon, lat, value, undulation, h, slope, margin}].
 */
export function terrainSamples({ raster, geoid, maxZoom, k = 6 }) {
  const lonLatOf = toLonLat(raster.epsg);
  const toMap = fromLonLat(raster.epsg);
  const geographic = raster.epsg === 4326;
  const out = [];
  for (const g of interiorGrid(raster, k)) {
    const [x0, y0] = raster.world(g.col, g.row);
    const [lon0, lat0] = lonLatOf(x0, y0);
    const [lon, lat] = snapToSamples(lon0, lat0, maxZoom);
    let [x, y] = toMap(lon, lat);
    // a raster in longitudes past ±180 (ETOPO1's −180.5…180.5): the turn that lands inside it
    if (geographic) {
      const [c] = pixelOf(raster, x, y);
      if (c < 0) x += 360;
      else if (c > raster.width - 1) x -= 360;
    }
    const perUnit = geographic ? [DEG * A * Math.cos(lat * DEG), DEG * A] : [1, 1];
    const b = bilinearAt(raster, x, y, perUnit);
    if (!Number.isFinite(b.h)) continue;
    const undulation = geoid ? geoid.undulation(lon, lat) : 0;
    const [he, hn] = halfUvStep(maxZoom, lat);
    out.push({ lon, lat, value: b.h, undulation, h: b.h + undulation, slope: b.slope, margin: 0.1 + b.slope * Math.hypot(he, hn) });
  }
  return out;
}

/** gunzip, as a promise-free helper for the checks. */
export const gunzip = (b) => zlib.gunzipSync(b);
