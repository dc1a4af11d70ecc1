// Checks h–j of run.mjs, on the quantized-mesh terrain of the GEO tilesets: every tile decoded
// by an independent decoder and checked (lib/terrain.mjs), the crack test, on-demand tiles
// against baked ones, CesiumJS (the docs example page, a scripted flight, heights) and
// 3DTilesRendererJS's QuantizedMeshPlugin. Each function returns the pass message or throws a
// CheckFailure whose details name the tile or URL and the problem.
import fs from 'node:fs';
import path from 'node:path';
import { CheckFailure } from './checks.mjs';
import { openRecordedPage } from './browser.mjs';
import { truncate } from './walk.mjs';
import {
  ACCEPT_ALL, ACCEPT_NONE, httpGet, gunzip, layerTiles, decodeTile, checkTile, crackTest, tileKey, tilesAt, rangesHold,
} from './terrain.mjs';

const CONCURRENCY = 8;

/** Runs `fn` over `items`, `n` at a time, in order of start. */
async function pool(items, n, fn) {
  let next = 0;
  const workers = Array.from({ length: Math.min(n, items.length) }, async () => {
    while (next < items.length) {
      const i = next++;
      await fn(items[i], i);
    }
  });
  await Promise.all(workers);
}

/** GET layer.json of tileset `name`: the parsed document and its URL; throws a CheckFailure. */
export async function fetchLayer(base, name) {
  const url = `${base}/tilesets/${name}/terrain/layer.json`;
  const r = await httpGet(url, { 'accept-encoding': 'identity' });
  if (r.status !== 200) throw new CheckFailure(`GET ${url} -> ${r.status}: ${truncate(r.body.toString(), 300)}`);
  try {
    return { url, layer: JSON.parse(r.body.toString()) };
  } catch (err) {
    throw new CheckFailure(`GET ${url}: not JSON: ${err.message}`);
  }
}

/** What layer.json must say for CesiumJS, Cesium for Unreal/Unity and 3DTilesRendererJS. */
function layerProblems(layer) {
  const p = [];
  if (layer.format !== 'quantized-mesh-1.0') p.push(`format ${JSON.stringify(layer.format)}, "quantized-mesh-1.0" expected`);
  if ((layer.scheme ?? 'tms') !== 'tms') p.push(`scheme ${JSON.stringify(layer.scheme)}, "tms" expected`);
  if ((layer.projection ?? 'EPSG:4326') !== 'EPSG:4326') p.push(`projection ${JSON.stringify(layer.projection)}, the geodetic "EPSG:4326" expected`);
  if (!Array.isArray(layer.tiles) || typeof layer.tiles[0] !== 'string' || !/\{z\}.*\{x\}.*\{y\}/.test(layer.tiles[0])) p.push(`tiles ${JSON.stringify(layer.tiles)} is not a {z}/{x}/{y} template`);
  if (!Array.isArray(layer.available) || layer.available.length === 0) p.push('no "available" array');
  else {
    if (Number.isInteger(layer.maxzoom) && layer.available.length !== layer.maxzoom + 1) p.push(`"available" has ${layer.available.length} zooms, maxzoom ${layer.maxzoom} says ${layer.maxzoom + 1}`);
    if (!rangesHold(layer.available[0], 0, 0) || !rangesHold(layer.available[0], 1, 0)) p.push('zoom 0 does not list both root tiles (0/0/0 and 0/1/0): a client has nothing to start from');
    layer.available.forEach((ranges, z) => {
      const { cols, rows } = tilesAt(z);
      for (const r of ranges) {
        if (!(r.startX <= r.endX && r.startY <= r.endY && r.startX >= 0 && r.startY >= 0 && r.endX < cols && r.endY < rows)) p.push(`zoom ${z}: range ${JSON.stringify(r)} is not within the ${cols}×${rows} tiles`);
      }
    });
  }
  const ext = layer.extensions ?? [];
  for (const e of ['octvertexnormals', 'watermask', 'metadata']) if (!ext.includes(e)) p.push(`extensions ${JSON.stringify(ext)} lacks "${e}"`);
  // CesiumJS throws on every tile carrying metadata when metadataAvailability is missing
  if (ext.includes('metadata') && !(Number.isInteger(layer.metadataAvailability) && layer.metadataAvailability > 0)) p.push(`"metadata" is offered without a metadataAvailability (${JSON.stringify(layer.metadataAvailability)})`);
  const b = layer.bounds;
  if (!Array.isArray(b) || b.length !== 4 || !(b[0] >= -180 && b[2] <= 180 && b[0] < b[2] && b[1] >= -90 && b[3] <= 90 && b[1] < b[3])) p.push(`bounds ${JSON.stringify(b)} is not [west, south, east, north] in degrees`);
  return p;
}

/** The URL of tile (z, x, y) by layer.json's template, resolved against layer.json's URL. */
export function tileUrl(layerUrl, layer, { z, x, y }) {
  const rel = layer.tiles[0].replace('{z}', z).replace('{x}', x).replace('{y}', y).replace('{version}', layer.version ?? '');
  return new URL(rel, layerUrl).href;
}

/**
 * Check h, decode: layer.json, then every tile it lists fetched with every extension (identity,
 * and again gzipped: the same bytes once gunzipped), decoded by @here/quantized-mesh-decoder and
 * checked (terrain.mjs checkTile). Also: a tile outside `available` is 404, an Accept with no
 * quantized-mesh type is 406. `out.tiles` (key → decoded) and `out.layer` are kept for the crack test.
 */
export async function decodeCheck({ base, name, out, log }) {
  const started = Date.now();
  const { url: layerUrl, layer } = await fetchLayer(base, name);
  const lp = layerProblems(layer);
  if (lp.length) throw new CheckFailure(`layer.json of ${name}: ${lp[0]}`, lp);
  const ids = layerTiles(layer);
  const maxZoom = layer.available.length - 1;
  log(`layer.json: zoom 0–${maxZoom}, ${ids.length} tiles available, bounds [${layer.bounds.map((v) => v.toFixed(4)).join(', ')}], extensions ${layer.extensions.join(', ')}, metadataAvailability ${layer.metadataAvailability}`);
  const tiles = new Map();
  const problems = [];
  const fig = { bytes: 0, gzBytes: 0, vertices: 0, triangles: 0, sphereExcess: -Infinity, horizonMin: Infinity, horizonMax: 0, minUpDot: Infinity, metadataTiles: 0, waterGrid: 0, waterUniform: 0, cameras: 0 };
  const perZoom = new Map();
  await pool(ids, CONCURRENCY, async (id) => {
    const url = tileUrl(layerUrl, layer, id);
    const key = tileKey(id.z, id.x, id.y);
    let r;
    try {
      r = await httpGet(url, { accept: ACCEPT_ALL, 'accept-encoding': 'identity' });
    } catch (err) {
      problems.push(`tile ${key}: GET ${url}: ${err.message}`);
      return;
    }
    if (r.status !== 200) {
      problems.push(`tile ${key}: GET ${url} -> ${r.status}: ${truncate(r.body.toString(), 200)}`);
      return;
    }
    const ct = String(r.headers['content-type'] ?? '');
    if (!ct.startsWith('application/vnd.quantized-mesh')) problems.push(`tile ${key}: content-type ${JSON.stringify(ct)}`);
    if (r.headers['access-control-allow-origin'] !== '*') problems.push(`tile ${key}: no CORS (access-control-allow-origin ${JSON.stringify(r.headers['access-control-allow-origin'])})`);
    if (!r.headers.etag) problems.push(`tile ${key}: no ETag`);
    let t;
    try {
      t = decodeTile(r.body);
    } catch (err) {
      problems.push(`tile ${key}: does not decode: ${err.message}`);
      return;
    }
    tiles.set(key, t);
    fig.bytes += r.body.length;
    fig.vertices += t.n;
    fig.triangles += t.triangles.length / 3;
    const zs = perZoom.get(id.z) ?? { tiles: 0, vertices: 0 };
    zs.tiles++;
    zs.vertices += t.n;
    perZoom.set(id.z, zs);
    const c = checkTile(t, id, layer, { wantNormals: true, wantMetadataAt: layer.metadataAvailability });
    problems.push(...c.problems);
    fig.sphereExcess = Math.max(fig.sphereExcess, c.figures.sphereExcess);
    if (id.z >= 2) {
      fig.horizonMin = Math.min(fig.horizonMin, c.figures.horizonMag);
      fig.horizonMax = Math.max(fig.horizonMax, c.figures.horizonMag);
    }
    fig.cameras += c.figures.horizonCulledCameras ?? 0;
    fig.minUpDot = Math.min(fig.minUpDot, c.figures.minUpDot);
    if (t.metadata) fig.metadataTiles++;
    if (!t.waterMask) problems.push(`tile ${key}: no watermask extension though it was asked for`);
    else if (t.waterMask.byteLength === 1) fig.waterUniform++;
    else fig.waterGrid++;
    // the same tile gzipped
    try {
      const g = await httpGet(url, { accept: ACCEPT_ALL, 'accept-encoding': 'gzip' });
      if (g.status !== 200) problems.push(`tile ${key}: gzipped GET -> ${g.status}`);
      else if (g.headers['content-encoding'] !== 'gzip') problems.push(`tile ${key}: Accept-Encoding gzip answered content-encoding ${JSON.stringify(g.headers['content-encoding'])}`);
      else if (!gunzip(g.body).equals(r.body)) problems.push(`tile ${key}: the gzipped response does not gunzip to the identity response's bytes`);
      else fig.gzBytes += g.body.length;
    } catch (err) {
      problems.push(`tile ${key}: gzipped: ${err.message}`);
    }
  });
  // negotiation and availability at the edges
  const zm = layer.available[maxZoom][0];
  const outside = [{ z: maxZoom, x: zm.endX + 1, y: zm.endY }, { z: maxZoom, x: zm.startX - 1, y: zm.startY }, { z: maxZoom, x: zm.startX, y: zm.endY + 1 }]
    .find((t) => t.x >= 0 && t.x < tilesAt(t.z).cols && t.y < tilesAt(t.z).rows && !rangesHold(layer.available[t.z], t.x, t.y));
  if (outside) {
    const u = tileUrl(layerUrl, layer, outside);
    const r = await httpGet(u, { accept: ACCEPT_ALL });
    log(`outside "available": GET ${tileKey(outside.z, outside.x, outside.y)} -> ${r.status}`);
    if (r.status !== 404) problems.push(`tile ${tileKey(outside.z, outside.x, outside.y)} is outside layer.json's available, answered ${r.status} (404 expected)`);
  }
  const u0 = tileUrl(layerUrl, layer, ids[0]);
  const r406 = await httpGet(u0, { accept: 'image/png' });
  log(`Accept: image/png -> ${r406.status}`);
  if (r406.status !== 406) problems.push(`GET ${u0} with Accept: image/png answered ${r406.status} (406 expected: no quantized-mesh type is acceptable)`);

  const zoomLine = [...perZoom.entries()].sort((a, b) => a[0] - b[0]).map(([z, s]) => `z${z}: ${s.tiles} (${Math.round(s.vertices / s.tiles)} v)`).join(', ');
  log(`per zoom (tiles, mean vertices): ${zoomLine}`);
  log(`${tiles.size} tiles decoded, ${fig.vertices} vertices, ${fig.triangles} triangles, ${(fig.bytes / 1024).toFixed(0)} KiB (${(fig.gzBytes / 1024).toFixed(0)} KiB gzipped); metadata in ${fig.metadataTiles} tiles; water masks ${fig.waterUniform} uniform, ${fig.waterGrid} 256×256`);
  log(`bounding spheres: largest vertex excess ${fig.sphereExcess.toExponential(2)} m; horizon points (zoom ≥ 2) magnitude ${fig.horizonMin.toFixed(6)}–${fig.horizonMax.toFixed(6)}, sound from ${fig.cameras} culling cameras; normals: smallest dot with up ${fig.minUpDot.toFixed(3)}`);
  out.tiles = tiles;
  out.layer = layer;
  const msg = `${tiles.size}/${ids.length} tiles decoded by @here/quantized-mesh-decoder (and gzipped), zoom 0–${maxZoom}, ${problems.length} problems, ${((Date.now() - started) / 1000).toFixed(1)} s`;
  if (problems.length) throw new CheckFailure(`${problems.length} problem(s), first: ${problems[0]}; ${msg}`, problems.slice(0, 60));
  return msg;
}

/** Check h, cracks: terrain.mjs crackTest over the decoded tiles of the decode check. */
export function crackCheck({ tiles, log }) {
  const c = crackTest(tiles);
  for (const p of c.poles) log(`${p.pole} pole, zoom ${p.z}: ${p.vertices} vertices on it, heights spread ${p.spread.toExponential(2)} m`);
  log(`${c.ew} east-west pairs (${c.antimeridian} across the antimeridian), ${c.ns} north-south pairs, ${c.vertices} shared edge vertices; worst height difference ${c.worstDh.toExponential(2)} m; ${c.sameVector} normals with two byte codes of one vector (the octahedral code's folded corners)`);
  const problems = [...c.problems];
  for (const p of c.poles) if (p.spread > 1e-6) problems.push(`the ${p.pole} pole at zoom ${p.z} has ${p.vertices} vertices of different heights: ${p.lo.h.toFixed(3)} m (${p.lo.key}) to ${p.hi.h.toFixed(3)} m (${p.hi.key})`);
  const msg = `${c.ew + c.ns} neighbour pairs (${c.ew} east-west, ${c.antimeridian} across the antimeridian; ${c.ns} north-south), ${c.vertices} shared vertices`;
  if (problems.length) throw new CheckFailure(`${problems.length} crack(s), first: ${problems[0]}; ${msg}`, problems.slice(0, 60));
  return `0 cracks: ${msg}, same positions, heights within 1e-6 m (worst ${c.worstDh.toExponential(1)} m), same normals`;
}

/**
 * Check h, on demand = baked: layer.json of both alike (available, bounds, zooms, extensions),
 * and a sample of tiles at every zoom (first, middle, last available) byte-identical for each
 * Accept of `accepts`. The on-demand tileset's first request builds the tile: its time is kept.
 */
export async function onDemandCheck({ base, baked, live, accepts = [ACCEPT_ALL, ACCEPT_NONE], log }) {
  const a = await fetchLayer(base, baked);
  const b = await fetchLayer(base, live);
  const problems = [];
  for (const k of ['available', 'bounds', 'maxzoom', 'minzoom', 'extensions', 'metadataAvailability', 'format', 'scheme', 'projection']) {
    if (JSON.stringify(a.layer[k]) !== JSON.stringify(b.layer[k])) problems.push(`layer.json "${k}" differs: ${baked} ${truncate(JSON.stringify(a.layer[k]), 200)}, ${live} ${truncate(JSON.stringify(b.layer[k]), 200)}`);
  }
  const ids = layerTiles(a.layer);
  const sample = [];
  for (let z = 0; z < a.layer.available.length; z++) {
    const at = ids.filter((t) => t.z === z);
    for (const i of new Set([0, at.length >> 1, at.length - 1])) if (at[i]) sample.push(at[i]);
  }
  let compared = 0, bytes = 0;
  const buildMs = [];
  for (const id of sample) {
    for (const accept of accepts) {
      const ua = tileUrl(a.url, a.layer, id), ub = tileUrl(b.url, b.layer, id);
      const t0 = Date.now();
      const rb = await httpGet(ub, { accept, 'accept-encoding': 'identity' });
      if (accept === accepts[0]) buildMs.push({ z: id.z, ms: Date.now() - t0 });
      const ra = await httpGet(ua, { accept, 'accept-encoding': 'identity' });
      const key = tileKey(id.z, id.x, id.y);
      if (ra.status !== 200 || rb.status !== 200) {
        problems.push(`tile ${key} (Accept ${accept}): baked ${ra.status}, on demand ${rb.status}: ${truncate((rb.status !== 200 ? rb : ra).body.toString(), 200)}`);
        continue;
      }
      compared++;
      bytes += ra.body.length;
      if (!ra.body.equals(rb.body)) {
        let at = 0;
        while (at < ra.body.length && ra.body[at] === rb.body[at]) at++;
        problems.push(`tile ${key} (Accept ${accept}): baked ${ra.body.length} bytes, on demand ${rb.body.length} bytes, first difference at byte ${at}`);
      }
    }
  }
  const zooms = new Map();
  for (const { z, ms } of buildMs) zooms.set(z, Math.max(zooms.get(z) ?? 0, ms));
  log(`on-demand first requests (build + send), slowest per zoom: ${[...zooms.entries()].map(([z, ms]) => `z${z} ${ms} ms`).join(', ')}`);
  const msg = `${sample.length} tiles (every zoom 0–${a.layer.available.length - 1}) × ${accepts.length} Accept variants: ${compared} compared, ${(bytes / 1024).toFixed(0)} KiB`;
  if (problems.length) throw new CheckFailure(`${problems.length} difference(s), first: ${problems[0]}; ${msg}`, problems);
  return `byte-identical: ${msg}; layer.json alike`;
}

/**
 * Check i, CesiumJS: docs/examples/cesium-terrain.html (its CesiumJS from the local copy) on
 * tileset `name`, then a scripted flight through `stops` (page/terrain-flight.js). Passes with
 * tiles requested and drawn, 0 HTTP errors, 0 provider errors, 0 mesh failures, 0 quadtree
 * tiles failed, no page error, nothing off 127.0.0.1. Leaves the page open in `session`.
 */
export async function cesiumTerrainCheck({ browser, exampleUrl, flightScriptUrl, name, stops, msPerStop, viewport, screenshot, log, session }) {
  const { page, rec } = await openRecordedPage(browser);
  session.page = page;
  session.rec = rec;
  // smaller than the 3D Tiles checks' page: SwiftShader draws about a frame a second at 1024×768
  if (viewport) await page.setViewport(viewport);
  const resp = await page.goto(exampleUrl, { waitUntil: 'load', timeout: 60_000 });
  if (!resp || resp.status() !== 200) throw new CheckFailure(`the example page ${exampleUrl} answered ${resp?.status()}`);
  await page.waitForFunction(() => window.terrastream && (window.terrastream.ready || window.terrastream.fatal), { timeout: 90_000 });
  const fatal = await page.evaluate(() => window.terrastream.fatal);
  if (fatal) throw new CheckFailure(`the example page failed: ${fatal}`, rec.pageErrors.concat(rec.badStatus, rec.offHost));
  await page.addScriptTag({ url: flightScriptUrl });
  await page.waitForFunction(() => window.terrainFlightReady === true, { timeout: 30_000 });
  const version = await page.evaluate(() => window.Cesium.VERSION);
  let flight;
  try {
    flight = await page.evaluate((s, ms) => window.terrainFlight(s, ms), stops, msPerStop);
  } catch (err) {
    throw new CheckFailure(`the flight failed in the page: ${truncate(err.message, 600)}`);
  }
  session.flight = flight;
  if (screenshot) {
    try {
      fs.mkdirSync(path.dirname(screenshot), { recursive: true });
      await page.screenshot({ path: screenshot, type: 'png' });
    } catch (err) {
      log(`screenshot failed: ${err.message}`);
    }
  }
  const mine = (u) => u.includes(`/tilesets/${name}/terrain/`);
  const tileReqs = rec.requests.filter((u) => mine(u) && /\.terrain(\?|$)/.test(u));
  const layerReqs = rec.requests.filter((u) => mine(u) && u.includes('layer.json'));
  const zooms = {};
  for (const u of tileReqs) {
    const m = /\/terrain\/(\d+)\/\d+\/\d+\.terrain/.exec(u);
    if (m) zooms[m[1]] = (zooms[m[1]] ?? 0) + 1;
  }
  log(`CesiumJS ${version}; ${rec.requests.length} requests in all: ${layerReqs.length} layer.json, ${tileReqs.length} terrain tiles (by zoom ${JSON.stringify(zooms)}), ${rec.cancelled.filter(mine).length} cancelled by CesiumJS`);
  for (const s of flight.stops) {
    const lv = Object.keys(s.levels).map(Number);
    log(`stop lon ${s.stop.lon.toFixed(3)}, lat ${s.stop.lat.toFixed(3)}, range ${(s.stop.range / 1000).toFixed(0)} km, pitch ${s.stop.pitch}°: ${s.settled ? 'settled' : 'NOT settled'} in ${(s.ms / 1000).toFixed(1)} s (${s.frames} frames); ${s.drawn} tiles drawn, levels ${lv.length ? `${Math.min(...lv)}–${Math.max(...lv)}` : '-'}`);
  }
  const problems = [];
  for (const u of rec.offHost) problems.push(`request to a host other than 127.0.0.1 (aborted): ${u}`);
  for (const s of rec.badStatus) problems.push(`HTTP ${s}`);
  for (const f of rec.failed) problems.push(`request failed: ${f}`);
  for (const e of flight.providerErrors) problems.push(`terrain provider errorEvent: ${truncate(e, 300)}`);
  for (const e of flight.meshFailures) problems.push(`CesiumJS could not make the mesh of tile ${truncate(e, 300)}`);
  const failedTiles = [...new Set(flight.stops.flatMap((s) => s.failedTiles))];
  for (const t of failedTiles) problems.push(`quadtree tile ${t} (TMS z/x/y) FAILED`);
  for (const e of rec.pageErrors) problems.push(`page error: ${truncate(e, 300)}`);
  for (const c of rec.consoleErrors) log(`console error: ${truncate(c, 300)}`);
  const unsettled = flight.stops.filter((s) => !s.settled).length;
  if (tileReqs.length === 0) problems.push('no terrain tile was requested');
  if (unsettled) problems.push(`${unsettled} of ${flight.stops.length} stops never settled (globe.tilesLoaded) within ${msPerStop / 1000} s`);
  const failures = rec.badStatus.filter(mine).length + rec.failed.filter(mine).length + flight.providerErrors.length + flight.meshFailures.length + failedTiles.length;
  const msg = `${tileReqs.length} terrain tile requests over ${flight.stops.length} stops, ${failures} failed`;
  if (problems.length) throw new CheckFailure(`${problems.length} problem(s), first: ${problems[0]}; ${msg}`, problems.slice(0, 40));
  return `${msg} (0 HTTP errors, 0 provider errors, 0 mesh failures), every stop settled`;
}

/**
 * Check i, heights: Cesium.sampleTerrainMostDetailed at `samples` (terrain.mjs's expected
 * heights from the source raster), each within `errMax` (stats.json's max_error of the deepest
 * zoom) + its own margin. Prints the table, max and median |difference|.
 */
export async function terrainHeightsCheck({ session, samples, errMax, maxZoom, timeoutMs, log }) {
  if (!session.page || !session.flight) throw new CheckFailure('not run: the CesiumJS terrain check did not get that far');
  let res;
  try {
    res = await session.page.evaluate((pts, ms) => window.terrainSample(pts, ms), samples.map((s) => [s.lon, s.lat]), timeoutMs);
  } catch (err) {
    throw new CheckFailure(`sampleTerrainMostDetailed failed: ${truncate(err.message, 600)}`);
  }
  const pad = (v, n) => String(v).padStart(n);
  const f = (v, d = 2) => (v === null || v === undefined || Number.isNaN(v) ? '-' : v.toFixed(d));
  log(`sampleTerrainMostDetailed: ${samples.length} points in ${(res.ms / 1000).toFixed(1)} s; tolerance = stats.json max_error at zoom ${maxZoom} (${errMax.toFixed(3)} m) + margin (0.1 m + the raster's steepest slope there × half a u/v step)`);
  log(`${pad('lon', 12)} ${pad('lat', 11)} ${pad('raster', 9)} ${pad('geoid', 7)} ${pad('expected', 9)} ${pad('sampled', 9)} ${pad('diff', 8)} ${pad('margin', 7)} ${pad('level', 5)}`);
  const problems = [];
  const diffs = [];
  samples.forEach((s, i) => {
    const got = res.heights[i];
    const diff = got === null ? null : got - s.h;
    const tol = errMax + s.margin;
    log(`${pad(f(s.lon, 6), 12)} ${pad(f(s.lat, 6), 11)} ${pad(f(s.value), 9)} ${pad(f(s.undulation), 7)} ${pad(f(s.h), 9)} ${pad(f(got), 9)} ${pad(f(diff, 3), 8)} ${pad(f(s.margin, 3), 7)} ${pad(res.levels[i], 5)}`);
    const where = `lon ${s.lon.toFixed(6)}, lat ${s.lat.toFixed(6)}`;
    if (got === null) problems.push(`${where}: CesiumJS sampled no height`);
    else {
      diffs.push(Math.abs(diff));
      if (Math.abs(diff) > tol) problems.push(`${where}: sampled ${got.toFixed(3)} m, expected ${s.h.toFixed(3)} m (raster ${s.value.toFixed(3)} + geoid ${s.undulation.toFixed(3)}), |diff| ${Math.abs(diff).toFixed(3)} > ${tol.toFixed(3)} m`);
    }
    if (res.levels[i] !== maxZoom) problems.push(`${where}: CesiumJS's availability gives level ${res.levels[i]} as the most detailed, layer.json's maxzoom is ${maxZoom}`);
  });
  for (const e of res.providerErrors) problems.push(`terrain provider errorEvent: ${truncate(e, 300)}`);
  diffs.sort((a, b) => a - b);
  const max = diffs.length ? diffs[diffs.length - 1] : NaN;
  const median = diffs.length ? diffs[diffs.length >> 1] : NaN;
  const msg = `|diff| max ${max.toFixed(3)} m, median ${median.toFixed(3)} m over ${diffs.length} points; tolerance ${errMax.toFixed(2)} m + margin`;
  if (problems.length) throw new CheckFailure(`${problems.length} of ${samples.length} points fail; ${msg}`, problems);
  return msg;
}

/** CesiumJS's Accept for tiles with every extension (CesiumTerrainProvider), for a diagnosis. */
const CESIUM_ACCEPT = 'application/vnd.quantized-mesh;extensions=octvertexnormals-watermask-metadata,application/octet-stream;q=0.9,*/*;q=0.01';

/**
 * Check j: 3DTilesRendererJS (three.js) with QuantizedMeshPlugin on the terrain of `name`
 * (page/qm-three.html), looking down on `view` from `view.range` metres. Passes when tiles load,
 * the renderer refines to zoom `minZoom` or deeper, 0 load errors, no page error, nothing off
 * 127.0.0.1. When it does not refine that far, the page runs again with CesiumJS's Accept header
 * (a diagnosis, logged: whether the server's Accept negotiation is what stops it).
 */
export async function threeTerrainCheck({ browser, pageUrl, terrainUrl, view, minZoom, timeoutMs, screenshot, log }) {
  const first = await threeRun({ browser, pageUrl, terrainUrl, view, timeoutMs, screenshot, log });
  if (first.problems.length === 0 && first.deepest >= minZoom) return first.msg;
  const problems = [...first.problems];
  if (first.deepest < minZoom) {
    problems.unshift(`3DTilesRendererJS refined no deeper than zoom ${first.deepest} from ${(view.range / 1000).toFixed(0)} km up (zoom ${minZoom} or deeper expected); its tile requests said Accept: ${first.pluginAccept}`);
    const again = await threeRun({ browser, pageUrl, terrainUrl, view, timeoutMs, accept: CESIUM_ACCEPT, log: () => {} });
    problems.push(`diagnosis: the same page with CesiumJS's Accept header (${CESIUM_ACCEPT}) refines to zoom ${again.deepest} (${again.msg})`);
  }
  throw new CheckFailure(`${problems.length} problem(s), first: ${problems[0]}; ${first.msg}`, problems.slice(0, 40));
}

async function threeRun({ browser, pageUrl, terrainUrl, view, timeoutMs, screenshot, accept, log }) {
  const { page, rec } = await openRecordedPage(browser);
  try {
    const resp = await page.goto(pageUrl, { waitUntil: 'load', timeout: 60_000 });
    if (!resp || resp.status() !== 200) throw new CheckFailure(`${pageUrl} answered ${resp?.status()}`);
    await page.waitForFunction(() => window.qmThreeReady === true, { timeout: 60_000 }).catch(() => {
      throw new CheckFailure(`the page's modules did not load (three, 3d-tiles-renderer)`, rec.pageErrors.concat(rec.badStatus, rec.consoleErrors));
    });
    let r;
    try {
      r = await page.evaluate((u, v, ms, a) => window.qmThreeLoad(u, v, ms, a), terrainUrl, view, timeoutMs, accept ?? null);
    } catch (err) {
      throw new CheckFailure(`3DTilesRendererJS failed in the page: ${truncate(err.message, 600)}`);
    }
    if (screenshot) await page.screenshot({ path: screenshot, type: 'png' }).catch((err) => log(`screenshot failed: ${err.message}`));
    const terrainReqs = rec.requests.filter((u) => /\.terrain(\?|$)/.test(u));
    log(`${terrainReqs.length} terrain requests; loaded ${r.loaded.length} tile meshes (by zoom, "split": a parent's quadrant where no child tile exists: ${JSON.stringify(r.levels)}), ${r.vertices} vertices; ${r.settled ? 'settled' : 'NOT settled'} in ${(r.ms / 1000).toFixed(1)} s; stats ${JSON.stringify(r.stats)}`);
    const problems = [];
    for (const u of rec.offHost) problems.push(`request to a host other than 127.0.0.1 (aborted): ${u}`);
    for (const s of rec.badStatus) problems.push(`HTTP ${s}`);
    for (const f of rec.failed) problems.push(`request failed: ${f}`);
    for (const f of r.failed) problems.push(`load-error: ${truncate(f, 300)}`);
    for (const e of [...r.errors, ...rec.pageErrors]) problems.push(`page error: ${truncate(e, 300)}`);
    for (const c of rec.consoleErrors) log(`console error: ${truncate(c, 300)}`);
    const tilesLoaded = r.loaded.filter((u) => /\.terrain/.test(u)).length;
    if (tilesLoaded === 0) problems.push('no terrain tile loaded');
    if (!r.settled) problems.push(`not settled within ${timeoutMs / 1000} s`);
    const zs = Object.keys(r.levels).filter((k) => k !== 'split').map(Number);
    const deepest = zs.length ? Math.max(...zs) : -1;
    const msg = `${tilesLoaded} terrain tiles loaded (zoom ${zs.length ? `${Math.min(...zs)}–${deepest}` : '-'}), ${r.failed.length} errors`;
    return { problems, msg, deepest, pluginAccept: r.pluginAccept };
  } finally {
    await page.close().catch(() => {});
  }
}
