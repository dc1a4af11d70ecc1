// Check k: the globe terrain as 3D Tiles (/tilesets/NAME/terrain/3dtiles/…), what CesiumJS's
// Cesium3DTilesTerrainProvider reads, judged against the same terrain's quantized-mesh tiles
// decoded by @here/quantized-mesh-decoder (an independent reader), the 3D Tiles 1.1 implicit
// tiling and subtree layout as the specification writes it, the Khronos glTF validator, and
// CesiumJS itself.
import { createRequire } from 'node:module';
import fs from 'node:fs';
import { CheckFailure } from './checks.mjs';
import { openRecordedPage } from './browser.mjs';
import { truncate } from './walk.mjs';
import { validateGlbs } from './validate.mjs';
import { ecefOf } from './earth.mjs';
import { httpGet, layerTiles, rangesHold, tileRect, decodeTile, vertexHeight, vertexLonLat } from './terrain.mjs';

const require = createRequire(import.meta.url);
const { PNG } = require('pngjs');

/** Levels per subtree file (the tileset.json must say so). */
export const SUBTREE_LEVELS = 2;

/** Grid tile (z, x, y) → implicit coordinates of its hemisphere's quadtree: root x / 2^z. */
export function implicitOf({ z, x, y }) {
  const side = 2 ** z;
  return { root: Math.floor(x / side), level: z, x: x % side, y };
}

/** The Morton index of (x, y), x in the low bit (3D Tiles implicit tiling). */
export function morton(x, y) {
  let m = 0;
  for (let b = 0; b < 16; b++) m += (((x >> b) & 1) << (2 * b)) + (((y >> b) & 1) << (2 * b + 1));
  return m;
}

/** A GLB's JSON and BIN chunk. */
export function parseGlb(buf) {
  if (buf.toString('latin1', 0, 4) !== 'glTF') throw new Error('not a GLB (magic)');
  const jlen = buf.readUInt32LE(12);
  const json = JSON.parse(buf.toString('utf8', 20, 20 + jlen));
  const bin = buf.subarray(28 + jlen, 28 + jlen + buf.readUInt32LE(20 + jlen));
  return { json, bin };
}

/** An accessor's values (FLOAT, UNSIGNED_BYTE, UNSIGNED_SHORT, UNSIGNED_INT; tightly packed). */
export function accessorValues({ json, bin }, i) {
  const a = json.accessors[i];
  const v = json.bufferViews[a.bufferView];
  const off = (v.byteOffset ?? 0) + (a.byteOffset ?? 0);
  const per = { SCALAR: 1, VEC3: 3 }[a.type];
  const n = a.count * per;
  const read = { 5126: (k) => bin.readFloatLE(off + 4 * k), 5125: (k) => bin.readUInt32LE(off + 4 * k), 5123: (k) => bin.readUInt16LE(off + 2 * k), 5121: (k) => bin.readUInt8(off + k) }[a.componentType];
  if (!read || !per) throw new Error(`accessor ${i}: ${a.componentType} ${a.type} unexpected`);
  return Array.from({ length: n }, (_, k) => read(k));
}

/** A subtree file: its JSON, binary chunk, and a bit reader for its availability objects. */
export function parseSubtree(buf) {
  if (buf.toString('latin1', 0, 4) !== 'subt') throw new Error('not a subtree (magic)');
  if (buf.readUInt32LE(4) !== 1) throw new Error(`subtree version ${buf.readUInt32LE(4)}`);
  const jl = Number(buf.readBigUInt64LE(8)), bl = Number(buf.readBigUInt64LE(16));
  if (24 + jl + bl !== buf.length) throw new Error(`subtree lengths ${jl} + ${bl} + 24 ≠ ${buf.length}`);
  if (jl % 8 || bl % 8) throw new Error('subtree chunks are not padded to 8 bytes');
  const json = JSON.parse(buf.toString('utf8', 24, 24 + jl));
  const bin = buf.subarray(24 + jl);
  const view = (i) => {
    const v = json.bufferViews[i];
    if (v.byteOffset % 8) throw new Error(`bufferView ${i} is not 8-byte aligned`);
    return bin.subarray(v.byteOffset, v.byteOffset + v.byteLength);
  };
  const bit = (avail, i) => (avail.constant !== undefined ? avail.constant === 1 : ((view(avail.bitstream)[i >> 3] >> (i & 7)) & 1) === 1);
  const f64 = (prop) => {
    const b = view(json.propertyTables[0].properties[prop].values);
    return Array.from({ length: b.length / 8 }, (_, k) => b.readDoubleLE(8 * k));
  };
  return { json, bit, f64 };
}

async function get(url, headers = {}) {
  const r = await httpGet(url, headers);
  if (r.status !== 200) throw new Error(`GET ${url}: ${r.status} ${truncate(r.body.toString('utf8'), 200)}`);
  return r.body;
}

/**
 * Every tile of `name`'s terrain as 3D Tiles: its GLB against its quantized-mesh tile (same
 * vertices as lon/lat/height on the ellipsoid within the f32 rounding of an offset from the node's
 * translation, same triangles, the four edge lists in CESIUM_tile_edges, unit normals), every GLB
 * through the glTF validator, every subtree's availability against layer.json and its metadata
 * against the tiles' headers. With `live`, an on-demand tileset of the same source whose GLBs
 * and subtrees must be the same bytes. Leaves what it fetched in `out` for the CesiumJS check.
 */
export async function tiles3dTerrainCheck({ base, name, live, log }) {
  const root = `${base}/tilesets/${name}/terrain`;
  const layer = JSON.parse(await get(`${root}/layer.json`));
  const tileset = JSON.parse(await get(`${root}/3dtiles/tileset.json`));
  const problems = [];
  const kids = tileset.root?.children ?? [];
  if (kids.length !== 2) problems.push(`tileset.json: root has ${kids.length} children, not the 2 hemispheres`);
  const version = /\?v=(.*)$/.exec(layer.tiles?.[0] ?? '')?.[1] ?? '';
  kids.forEach((k, r) => {
    const region = k.boundingVolume?.region ?? [];
    if (Math.abs(region[0] - (-Math.PI + r * Math.PI)) > 1e-12 || Math.abs(region[2] - r * Math.PI) > 1e-12) problems.push(`child ${r}: region ${JSON.stringify(region)} is not hemisphere ${r}`);
    const it = k.implicitTiling ?? {};
    if (it.subdivisionScheme !== 'QUADTREE' || it.subtreeLevels !== SUBTREE_LEVELS || it.availableLevels !== layer.available.length) problems.push(`child ${r}: implicitTiling ${JSON.stringify(it)}`);
    if (!k.content?.uri?.endsWith(`?v=${version}`)) problems.push(`child ${r}: content ${k.content?.uri} lacks layer.json's ?v=${version}`);
  });
  const semantics = Object.values(tileset.schema?.classes?.tile?.properties ?? {}).map((p) => p.semantic).sort();
  if (semantics.join() !== 'TILE_BOUNDING_SPHERE,TILE_HORIZON_OCCLUSION_POINT,TILE_MAXIMUM_HEIGHT,TILE_MINIMUM_HEIGHT') problems.push(`schema semantics ${semantics}`);

  const tiles = layerTiles(layer);
  const qm = new Map();
  const glbs = [];
  let worst = 0;
  for (const t of tiles) {
    const i = implicitOf(t);
    const key = `${t.z}/${t.x}/${t.y}`;
    const path = `tiles/${i.root}/${i.level}/${i.x}/${i.y}.glb`;
    let q, g, buf;
    try {
      q = decodeTile(await get(`${root}/${t.z}/${t.x}/${t.y}.terrain`, { Accept: 'application/vnd.quantized-mesh;extensions=octvertexnormals' }));
      buf = await get(`${root}/3dtiles/${path}`);
      g = parseGlb(buf);
    } catch (err) {
      problems.push(`${key}: ${err.message}`);
      continue;
    }
    qm.set(key, q);
    glbs.push({ url: `${root}/3dtiles/${path}`, buf, key });
    const prim = g.json.meshes?.[0]?.primitives?.[0];
    const m = g.json.nodes?.[0]?.matrix;
    if (!prim || !m) {
      problems.push(`${key}: no mesh primitive or node matrix`);
      continue;
    }
    const pos = accessorValues(g, prim.attributes.POSITION);
    if (pos.length !== 3 * q.n) {
      problems.push(`${key}: ${pos.length / 3} positions, the quantized-mesh tile has ${q.n} vertices`);
      continue;
    }
    // glTF is y-up: ECEF = (x, −z, y) of (position + translation)
    const rect = tileRect(t.z, t.x, t.y);
    let tileWorst = 0, extent = 0;
    for (let k = 0; k < q.n; k++) {
      const [lon, lat] = vertexLonLat(q, rect, k);
      const e = ecefOf(lon, lat, vertexHeight(q, k));
      const p = [pos[3 * k] + m[12], -(pos[3 * k + 2] + m[14]), pos[3 * k + 1] + m[13]];
      tileWorst = Math.max(tileWorst, ...p.map((c, a) => Math.abs(c - e[a])));
      extent = Math.max(extent, ...[0, 1, 2].map((a) => Math.abs(pos[3 * k + a])));
    }
    // two f32 rounding steps of the largest offset (2⁻²³ each), and a micrometre
    const tol = extent * 2 ** -22 + 1e-6;
    worst = Math.max(worst, tileWorst);
    if (tileWorst > tol) problems.push(`${key}: a vertex lies ${tileWorst.toExponential(3)} m from its quantized-mesh position (tolerance ${tol.toExponential(3)} m)`);
    const same = (a, b) => a.length === b.length && a.every((v, k) => v === b[k]);
    if (!same(accessorValues(g, prim.indices), Array.from(q.triangles))) problems.push(`${key}: triangles differ from the quantized-mesh tile's`);
    const edges = prim.extensions?.CESIUM_tile_edges ?? {};
    // the quantized-mesh edge's vertices, in the order CesiumJS hangs skirts from them
    // (TerrainMesh's westIndicesSouthToNorth, southIndicesEastToWest, eastIndicesNorthToSouth,
    // northIndicesWestToEast): out of order, its skirt walls cut across the tile
    for (const [side, list, coord, sign] of [['left', q.west, q.v, 1], ['bottom', q.south, q.u, -1], ['right', q.east, q.v, -1], ['top', q.north, q.u, 1]]) {
      if (edges[side] === undefined) {
        problems.push(`${key}: CESIUM_tile_edges has no ${side}`);
        continue;
      }
      const got = accessorValues(g, edges[side]);
      const asc = (a) => [...a].sort((p, r) => p - r);
      if (!same(asc(got), asc(Array.from(list)))) problems.push(`${key}: CESIUM_tile_edges.${side} holds other vertices than the quantized-mesh edge list`);
      else if (got.some((v, k) => k > 0 && sign * (coord[v] - coord[got[k - 1]]) <= 0)) problems.push(`${key}: CESIUM_tile_edges.${side} is not in CesiumJS's skirt order`);
    }
    const nrm = accessorValues(g, prim.attributes.NORMAL);
    for (let k = 0; k < q.n; k++) {
      const len = Math.hypot(nrm[3 * k], nrm[3 * k + 1], nrm[3 * k + 2]);
      if (Math.abs(len - 1) > 1e-5) {
        problems.push(`${key}: normal ${k} has length ${len}`);
        break;
      }
    }
  }
  log(`${tiles.length} tiles: GLB vertices vs the quantized-mesh tiles' (decoded by @here/quantized-mesh-decoder), largest distance ${worst.toExponential(3)} m`);

  // subtrees: availability from layer.json, metadata = the tiles' quantized-mesh headers
  let subtrees = 0;
  const subtreeBytes = new Map();
  for (const t of tiles.filter((t) => t.z % SUBTREE_LEVELS === 0)) {
    const i = implicitOf(t);
    const path = `subtrees/${i.root}/${i.level}/${i.x}/${i.y}.subtree`;
    let s;
    try {
      const buf = await get(`${root}/3dtiles/${path}`);
      subtreeBytes.set(path, buf);
      s = parseSubtree(buf);
    } catch (err) {
      problems.push(`${path}: ${err.message}`);
      continue;
    }
    subtrees++;
    const listed = [];
    let bit = 0;
    for (let l = 0; l < SUBTREE_LEVELS; l++) {
      for (let ly = 0; ly < 2 ** l; ly++) for (let lx = 0; lx < 2 ** l; lx++) {
        const z = t.z + l, gx = t.x * 2 ** l + lx, gy = t.y * 2 ** l + ly;
        const want = z < layer.available.length && rangesHold(layer.available[z], gx, gy);
        const k = bit + morton(lx, ly);
        if (s.bit(s.json.tileAvailability, k) !== want) problems.push(`${path}: tile ${z}/${gx}/${gy} is ${want ? '' : 'not '}in layer.json but its bit says otherwise`);
        if (s.bit(s.json.contentAvailability[0], k) !== want) problems.push(`${path}: content bit of ${z}/${gx}/${gy}`);
        if (want) listed.push({ k, key: `${z}/${gx}/${gy}` });
      }
      bit += 4 ** l;
    }
    for (let ly = 0; ly < 4; ly++) for (let lx = 0; lx < 4; lx++) {
      const z = t.z + 2, gx = t.x * 4 + lx, gy = t.y * 4 + ly;
      const want = z < layer.available.length && rangesHold(layer.available[z], gx, gy);
      if (s.bit(s.json.childSubtreeAvailability, morton(lx, ly)) !== want) problems.push(`${path}: child subtree at ${z}/${gx}/${gy}: bit ≠ layer.json`);
    }
    listed.sort((a, b) => a.k - b.k);
    const cols = { minimumHeight: s.f64('minimumHeight'), maximumHeight: s.f64('maximumHeight'), boundingSphere: s.f64('boundingSphere'), horizonOcclusionPoint: s.f64('horizonOcclusionPoint') };
    listed.forEach(({ key }, row) => {
      const h = qm.get(key)?.header;
      if (!h) return;
      const want = {
        minimumHeight: [h.minHeight], maximumHeight: [h.maxHeight],
        boundingSphere: [h.boundingSphereCenterX, h.boundingSphereCenterY, h.boundingSphereCenterZ, h.boundingSphereRadius],
        horizonOcclusionPoint: [h.horizonOcclusionPointX, h.horizonOcclusionPointY, h.horizonOcclusionPointZ],
      };
      for (const [p, w] of Object.entries(want)) {
        const got = cols[p].slice(row * w.length, (row + 1) * w.length);
        if (got.some((v, a) => v !== w[a])) problems.push(`${path}: ${p} of ${key} is ${got}, its quantized-mesh header says ${w}`);
      }
    });
  }
  log(`${subtrees} subtrees: availability = layer.json's, metadata = the tiles' quantized-mesh headers`);

  const validation = await validateGlbs(glbs, log).catch((err) => {
    problems.push(err.message, ...(err.details ?? []).slice(0, 10));
    return null;
  });

  if (live) {
    let same = 0;
    for (const { url, buf, key } of glbs) {
      const other = await get(url.replace(`/tilesets/${name}/`, `/tilesets/${live}/`)).catch((err) => err);
      if (other instanceof Error) problems.push(`${live} ${key}: ${other.message}`);
      else if (!other.equals(buf)) problems.push(`${live}: GLB of ${key} differs from the baked ${name}'s`);
      else same++;
    }
    for (const [path, buf] of subtreeBytes) {
      const other = await get(`${base}/tilesets/${live}/terrain/3dtiles/${path}`).catch((err) => err);
      if (other instanceof Error) problems.push(`${live} ${path}: ${other.message}`);
      else if (!other.equals(buf)) problems.push(`${live}: ${path} differs from the baked ${name}'s`);
      else same++;
    }
    log(`on demand (${live}): ${same} of ${glbs.length + subtreeBytes.size} GLBs and subtrees byte-identical to the baked ones`);
  }
  if (problems.length) throw new CheckFailure(`${problems.length} problem(s), first: ${problems[0]}`, problems.slice(0, 40));
  return `${tiles.length} GLBs = their quantized-mesh tiles (≤ ${worst.toExponential(2)} m), ${subtrees} subtrees = layer.json + headers; ${validation}${live ? '; on demand = baked' : ''}`;
}

/** Opens `url` (terrain3d.html), flies `stops` with terrain-flight.js; the page stays open. */
async function flyPage(browser, url, flightScriptUrl, viewport, stops, msPerStop) {
  const { page, rec } = await openRecordedPage(browser);
  const gaveUp = [];
  page.on('console', (msg) => {
    if (/Could not load (tile|subtree)/.test(msg.text())) gaveUp.push(msg.text());
  });
  if (viewport) await page.setViewport(viewport);
  const resp = await page.goto(url, { waitUntil: 'load', timeout: 60_000 });
  if (!resp || resp.status() !== 200) throw new CheckFailure(`${url} answered ${resp?.status()}`);
  await page.waitForFunction(() => window.terrastream && (window.terrastream.ready || window.terrastream.fatal), { timeout: 90_000 });
  const fatal = await page.evaluate(() => window.terrastream.fatal);
  if (fatal) throw new CheckFailure(`the page failed: ${truncate(fatal, 600)}`, rec.pageErrors.concat(rec.badStatus));
  await page.addScriptTag({ url: flightScriptUrl });
  await page.waitForFunction(() => window.terrainFlightReady === true, { timeout: 30_000 });
  let flight;
  try {
    flight = await page.evaluate((s, ms) => window.terrainFlight(s, ms), stops, msPerStop);
  } catch (err) {
    throw new CheckFailure(`the flight failed in the page: ${truncate(err.message, 600)}`, rec.pageErrors);
  }
  return { page, rec, gaveUp, flight };
}

/** Pixels of two same-sized PNGs whose colours differ by more than `t` in a channel. */
function differingPixels(a, b, t) {
  const pa = PNG.sync.read(a), pb = PNG.sync.read(b);
  if (pa.width !== pb.width || pa.height !== pb.height) return { n: Infinity, total: 0 };
  let n = 0;
  for (let i = 0; i < pa.data.length; i += 4) {
    if (Math.abs(pa.data[i] - pb.data[i]) > t || Math.abs(pa.data[i + 1] - pb.data[i + 1]) > t || Math.abs(pa.data[i + 2] - pb.data[i + 2]) > t) n++;
  }
  return { n, total: pa.width * pa.height };
}

/**
 * CesiumJS's Cesium3DTilesTerrainProvider on the terrain: a flight (terrain-flight.js) with 0
 * failed requests, provider errors, tiles it could not load or mesh; sampleTerrainMostDetailed
 * at `points` from both the 3D Tiles and the quantized-mesh provider, equal within `tolM` (the
 * f32 offsets of the GLB) and from the same levels; and the same flight drawn with the
 * quantized-mesh provider must give the same picture (at most `maxDiffShare` of the pixels
 * differing by more than 16 of 255 in a channel: skirts or triangles out of place show as
 * streaks).
 */
export async function cesium3dTerrainCheck({ browser, pageUrl, flightScriptUrl, name, stops, msPerStop, viewport, points, tolM, maxDiffShare, poleZoneDeg = 90, screenshot, log }) {
  const opened = [];
  try {
    const t3 = await flyPage(browser, pageUrl, flightScriptUrl, viewport, stops, msPerStop);
    opened.push(t3.page);
    const { page, rec, gaveUp, flight } = t3;
    const version = await page.evaluate(() => window.Cesium.VERSION);
    let cmp;
    try {
      cmp = await page.evaluate((p, ms) => window.terrain3dCompare(p, ms), points, 90_000);
    } catch (err) {
      throw new CheckFailure(`sampleTerrainMostDetailed failed: ${truncate(err.message, 600)}`, rec.pageErrors);
    }
    const shotA = await page.screenshot({ type: 'png' });
    const qm = await flyPage(browser, `${pageUrl}&draw=quantized-mesh`, flightScriptUrl, viewport, stops, msPerStop);
    opened.push(qm.page);
    const shotB = await qm.page.screenshot({ type: 'png' });
    if (screenshot) {
      try {
        fs.writeFileSync(screenshot, shotA);
        fs.writeFileSync(screenshot.replace(/\.png$/, '-quantized-mesh.png'), shotB);
      } catch (err) {
        log(`screenshot failed: ${err.message}`);
      }
    }
    const mine = (u) => u.includes(`/tilesets/${name}/terrain/3dtiles/`);
    const glbReqs = rec.requests.filter((u) => mine(u) && /\.glb(\?|$)/.test(u));
    const subReqs = rec.requests.filter((u) => mine(u) && /\.subtree(\?|$)/.test(u));
    const levels = {};
    for (const u of glbReqs) {
      const m = /\/tiles\/\d\/(\d+)\//.exec(u);
      if (m) levels[m[1]] = (levels[m[1]] ?? 0) + 1;
    }
    log(`CesiumJS ${version}, Cesium3DTilesTerrainProvider: ${glbReqs.length} GLB requests (by level ${JSON.stringify(levels)}), ${subReqs.length} subtree requests, ${rec.cancelled.filter(mine).length} cancelled by CesiumJS`);
    for (const s of flight.stops) {
      const lv = Object.keys(s.levels).map(Number);
      log(`stop range ${(s.stop.range / 1000).toFixed(0)} km, pitch ${s.stop.pitch}°: ${s.settled ? 'settled' : 'NOT settled'} in ${(s.ms / 1000).toFixed(1)} s; ${s.drawn} tiles drawn, levels ${lv.length ? `${Math.min(...lv)}–${Math.max(...lv)}` : '-'}`);
    }
    const meshFailures = await page.evaluate(() => window.terrastream.meshFailures.slice());
    const problems = [];
    for (const u of rec.offHost) problems.push(`request to a host other than 127.0.0.1: ${u}`);
    for (const s of rec.badStatus.concat(qm.rec.badStatus)) problems.push(`HTTP ${s}`);
    for (const f of rec.failed.concat(qm.rec.failed)) problems.push(`request failed: ${f}`);
    for (const e of cmp.errors) problems.push(`provider errorEvent: ${truncate(e, 300)}`);
    for (const e of gaveUp) problems.push(`CesiumJS: ${truncate(e, 300)}`);
    for (const e of meshFailures) problems.push(`CesiumJS could not make the mesh of tile ${truncate(e, 300)}`);
    for (const t of [...new Set(flight.stops.flatMap((s) => s.failedTiles))]) problems.push(`quadtree tile ${t} FAILED`);
    for (const e of rec.pageErrors.concat(qm.rec.pageErrors)) problems.push(`page error: ${truncate(e, 300)}`);
    if (glbReqs.length === 0) problems.push('no GLB was requested');
    const unsettled = flight.stops.filter((s) => !s.settled).length + qm.flight.stops.filter((s) => !s.settled).length;
    if (unsettled) problems.push(`${unsettled} stops (of both flights) never settled within ${msPerStop / 1000} s`);
    let worst = 0;
    let poleWorst = 0;
    const nearPole = [];
    points.forEach(([lon, lat], k) => {
      const a = cmp.t3.heights[k], b = cmp.qm.heights[k];
      const where = `lon ${lon.toFixed(6)}, lat ${lat.toFixed(6)}`;
      if (a === null || b === null) problems.push(`${where}: no height (3D Tiles ${a}, quantized-mesh ${b})`);
      else if (Math.abs(lat) > poleZoneDeg) {
        // CesiumJS's 3D Tiles terrain takes each vertex's u from its longitude, which a vertex at
        // a pole does not have: the triangles fanning from it get scrambled u, so heights near
        // a pole are interpolated differently there (a CesiumJS limit, reported, not failed)
        nearPole.push(`${where}: 3D Tiles ${a.toFixed(3)} m, quantized-mesh ${b.toFixed(3)} m`);
        poleWorst = Math.max(poleWorst, Math.abs(a - b));
      } else {
        worst = Math.max(worst, Math.abs(a - b));
        if (Math.abs(a - b) > tolM) problems.push(`${where}: 3D Tiles ${a.toFixed(4)} m, quantized-mesh ${b.toFixed(4)} m, |diff| > ${tolM} m`);
      }
      if (cmp.t3.levels[k] !== cmp.qm.levels[k]) problems.push(`${where}: most detailed level ${cmp.t3.levels[k]} (3D Tiles) vs ${cmp.qm.levels[k]} (quantized-mesh)`);
    });
    log(`sampleTerrainMostDetailed at ${points.length} points, both providers, in ${(cmp.ms / 1000).toFixed(1)} s: largest |3D Tiles − quantized-mesh| ${worst.toFixed(5)} m (tolerance ${tolM.toFixed(4)} m) over the ${points.length - nearPole.length} points within ${poleZoneDeg}° of latitude, levels ${Math.min(...cmp.t3.levels)}–${Math.max(...cmp.t3.levels)}`);
    if (nearPole.length) {
      log(`${nearPole.length} points nearer a pole than ${90 - poleZoneDeg}°, not compared (CesiumJS takes a vertex's u from its longitude, which a pole vertex does not have): |diff| up to ${poleWorst.toFixed(1)} m`);
      for (const l of nearPole) log(`  ${l}`);
    }
    const diff = differingPixels(shotA, shotB, 16);
    const share = diff.n / Math.max(diff.total, 1);
    log(`the last stop drawn by both providers: ${diff.n} of ${diff.total} pixels differ by more than 16 (${(100 * share).toFixed(3)} %, at most ${(100 * maxDiffShare).toFixed(3)} %)`);
    if (!(share <= maxDiffShare)) problems.push(`the 3D Tiles terrain and the quantized-mesh terrain draw different pictures: ${(100 * share).toFixed(3)} % of the pixels differ`);
    if (problems.length) throw new CheckFailure(`${problems.length} problem(s), first: ${problems[0]}`, problems.slice(0, 40));
    const poles = nearPole.length ? ` (${nearPole.length} more near a pole: up to ${poleWorst.toFixed(1)} m, CesiumJS's pole limit)` : '';
    return `${glbReqs.length} GLB + ${subReqs.length} subtree requests over ${flight.stops.length} stops, 0 failed; heights = quantized-mesh provider's within ${worst.toFixed(5)} m at ${points.length - nearPole.length} points${poles}; same picture (${(100 * share).toFixed(3)} % pixels differ)`;
  } finally {
    for (const p of opened) await p.close().catch(() => {});
  }
}
