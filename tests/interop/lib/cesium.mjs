// Checks d (CesiumJS loads the tileset, offline) and e (rendered heights vs the placement rule,
// and on the Earth vs heights computed from the source raster alone).
import fs from 'node:fs';
import path from 'node:path';
import { CheckFailure } from './checks.mjs';
import { openRecordedPage } from './browser.mjs';
import { truncate } from './walk.mjs';
import { makeTolerance, makeEarthTolerance, localFrame, toLocal, sampleGrid } from './heights.mjs';

const pathOf = (u) => {
  try {
    return new URL(u).pathname;
  } catch {
    return u;
  }
};

/**
 * Opens the test page, loads `tilesetUrl` in CesiumJS and waits until it has settled.
 * Returns {page, rec, result}; the page stays open for the heights check (the caller closes it).
 * Throws CheckFailure for every failed condition (the page is still returned through `session`).
 */
export async function cesiumLoadCheck({ browser, pageUrl, tilesetUrl, screenshot, timeoutMs, log, session }) {
  const { page, rec } = await openRecordedPage(browser);
  session.page = page;
  session.rec = rec;
  const resp = await page.goto(pageUrl, { waitUntil: 'load', timeout: 60_000 });
  if (!resp || resp.status() !== 200) throw new CheckFailure(`the test page ${pageUrl} answered ${resp?.status()}`);
  await page.waitForFunction(() => window.interop && window.interop.ready === true && window.Cesium, { timeout: 60_000 });
  const version = await page.evaluate(() => window.Cesium.VERSION);
  const problems = [];
  let result = null;
  try {
    result = await page.evaluate((url, ms) => window.interopLoad(url, ms), tilesetUrl, timeoutMs);
    session.result = result;
  } catch (err) {
    problems.push(`CesiumJS could not load ${tilesetUrl}: ${truncate(err.message, 600)}`);
  }
  if (screenshot) {
    try {
      fs.mkdirSync(path.dirname(screenshot), { recursive: true });
      await page.screenshot({ path: screenshot, type: 'png' });
    } catch (err) {
      log(`screenshot failed: ${err.message}`);
    }
  }
  const server = new URL(tilesetUrl).host;
  const toServer = rec.requests.filter((u) => {
    try {
      return new URL(u).host === server;
    } catch {
      return false;
    }
  });
  log(`CesiumJS ${version}; ${rec.requests.length} requests (${toServer.length} to the tileset server), ${rec.workers.length} workers`);
  if (result) {
    const glb = result.loaded.filter((u) => pathOf(u).endsWith('.glb'));
    const json = result.loaded.filter((u) => pathOf(u).endsWith('.json'));
    log(`loaded ${result.loaded.length} tile contents (${glb.length} GLB, ${json.length} external tileset JSON) in ${(result.ms / 1000).toFixed(1)} s; tilesLoaded=${result.tilesLoaded}`);
    const bs = result.boundingSphere;
    log(`bounding sphere: radius ${bs.radius.toFixed(2)} m, centre lon ${bs.lon?.toFixed(6)}, lat ${bs.lat?.toFixed(6)}, h ${bs.height?.toFixed(2)} m`);
    for (const f of result.failed) problems.push(`tileFailed: ${f.url}: ${truncate(f.message, 400)}`);
    if (result.loaded.length === 0) problems.push('0 tiles loaded');
    else if (glb.length === 0) problems.push('no GLB content loaded (only external tilesets)');
    if (!result.settled && result.failed.length === 0) problems.push(`not settled (tileset.tilesLoaded never stayed true) within ${timeoutMs / 1000} s`);
    for (const e of result.pageErrors) problems.push(`page error: ${truncate(e, 400)}`);
  }
  for (const u of [...rec.offHost].reverse()) problems.unshift(`request to a host other than 127.0.0.1 (aborted): ${u}`);
  for (const s of rec.badStatus) problems.push(`HTTP ${s}`);
  for (const f of rec.failed) problems.push(`request failed: ${f}`);
  for (const e of rec.pageErrors) problems.push(`page error: ${truncate(e, 400)}`);
  for (const c of rec.consoleErrors) log(`console error: ${truncate(c, 300)}`);
  if (problems.length) throw new CheckFailure(`${problems.length} problem(s), first: ${problems[0]}`, problems);
  const glbCount = result.loaded.filter((u) => pathOf(u).endsWith('.glb')).length;
  return `${result.loaded.length} tiles loaded (${glbCount} GLB), 0 failed, ${rec.requests.length} requests all on 127.0.0.1, ${(result.ms / 1000).toFixed(1)} s`;
}

/**
 * Check e: raster samples placed by the rule (local_frame + root transform) against
 * scene.sampleHeightMostDetailed, each within its tile's level-0 error + one z step.
 */
export async function heightsCheck({ session, walk, raster, cellSize, grid = 6, timeoutMs, log }) {
  if (!session.page || !session.result) throw new CheckFailure('not run: no tileset loaded in CesiumJS (see the cesium check)');
  if (session.result.failed.length) {
    // sampleHeightMostDetailed waits for every most detailed tile: a failed one never comes
    throw new CheckFailure(`not run: CesiumJS failed to load ${session.result.failed.length} tiles (see the cesium check)`);
  }
  if (!walk.rootJson) throw new CheckFailure('no root tileset.json (see the walk check)');
  let lf;
  try {
    lf = localFrame(walk.rootJson);
  } catch (err) {
    throw new CheckFailure(err.message);
  }
  log(`local_frame: origin [${lf.origin.join(', ')}], north ${lf.north}`);
  // Cesium's root transform must be the JSON's
  const jsonT = walk.rootJson.root?.transform;
  const cesT = session.result.rootTransform;
  if (!Array.isArray(jsonT)) throw new CheckFailure('root.transform is missing from tileset.json');
  const tDiff = Math.max(...jsonT.map((v, i) => Math.abs(v - cesT[i]) / Math.max(1, Math.abs(v))));
  if (tDiff > 1e-9) throw new CheckFailure(`CesiumJS's tileset.root.transform differs from tileset.json's root.transform (relative ${tDiff})`, [`json: ${JSON.stringify(jsonT)}`, `cesium: ${JSON.stringify(cesT)}`]);
  const tol = makeTolerance(walk);
  log(`${tol.count} level-0 mesh tiles with extras.terrastream and a box`);
  if (tol.count === 0) throw new CheckFailure('no content tile carries extras.terrastream {level: 0, kind: "mesh"} with a box: no tolerance can be derived');

  const samples = sampleGrid(raster.width, raster.height, grid).map(({ col, row }) => {
    const x = col * cellSize;
    const y = row * cellSize;
    const h = raster.at(col, row);
    const [e, n, u] = toLocal(lf, x, y, h);
    return { col, row, h, e, n, u, tol: tol.at(e, n, u) };
  });
  let res;
  try {
    res = await session.page.evaluate((pts, ms) => window.interopHeights(pts, ms), samples.map((s) => [s.e, s.n, s.u]), timeoutMs);
  } catch (err) {
    throw new CheckFailure(`sampling heights in CesiumJS failed: ${truncate(err.message, 600)}`);
  }
  const jsonLoaded = res.loaded.filter((u) => pathOf(u).endsWith('.json')).length;
  log(`sampleHeightMostDetailed: ${samples.length} samples in ${(res.ms / 1000).toFixed(1)} s; CesiumJS has loaded ${res.loaded.length} tile contents so far (${jsonLoaded} external tileset JSON), ${res.failed.length} failed`);
  const pad = (s, n) => String(s).padStart(n);
  log(`${pad('col', 4)} ${pad('row', 4)} ${pad('e', 10)} ${pad('n', 10)} ${pad('raster h', 9)} ${pad('expected', 9)} ${pad('sampled', 9)} ${pad('diff', 8)} ${pad('tol', 7)}  tile  (err.max + z step)`);
  const problems = res.failed.map((f) => `tileFailed while sampling: ${f.url}: ${truncate(f.message, 300)}`);
  let worst = { ratio: -1 };
  samples.forEach((s, i) => {
    const r = res.samples[i];
    const t = s.tol;
    const diff = r.sampled === null ? null : r.sampled - r.expected;
    const ratio = diff === null || !t ? Infinity : Math.abs(diff) / t.tol;
    const f = (v, d = 2) => (v === null || v === undefined || Number.isNaN(v) ? '-' : v.toFixed(d));
    log(`${pad(s.col, 4)} ${pad(s.row, 4)} ${pad(f(s.e, 1), 10)} ${pad(f(s.n, 1), 10)} ${pad(f(s.h, 1), 9)} ${pad(f(r.expected), 9)} ${pad(f(r.sampled), 9)} ${pad(f(diff, 3), 8)} ${pad(t ? f(t.tol, 3) : '-', 7)}  ${t ? `${t.key} (${f(t.errMax, 3)} + ${t.step === undefined ? '?' : t.step.toPrecision(3)})` : '-'}`);
    if (!t) problems.push(`sample (${s.col}, ${s.row}) at e ${s.e.toFixed(1)}, n ${s.n.toFixed(1)}: no level-0 mesh tile's box contains it`);
    else if (t.stepInfo?.error) problems.push(`sample (${s.col}, ${s.row}): the z step of tile ${t.key} is unknown: ${t.stepInfo.error}`);
    else if (!Number.isFinite(t.tol)) problems.push(`sample (${s.col}, ${s.row}): tile ${t.key} has no numeric errors.max (${JSON.stringify(t.errMax)})`);
    if (r.sampled === null) problems.push(`sample (${s.col}, ${s.row}) at lon ${r.lonDeg.toFixed(7)}, lat ${r.latDeg.toFixed(7)}: CesiumJS found no geometry there`);
    else if (t && Number.isFinite(t.tol) && Math.abs(diff) > t.tol) {
      problems.push(`sample (${s.col}, ${s.row}) at lon ${r.lonDeg.toFixed(7)}, lat ${r.latDeg.toFixed(7)}: sampled ${r.sampled.toFixed(3)} m, expected ${r.expected.toFixed(3)} m, |diff| ${Math.abs(diff).toFixed(3)} > tol ${t.tol.toFixed(3)} (tile ${t.key})`);
    }
    if (Number.isFinite(ratio) && ratio > worst.ratio) worst = { ratio, diff, tol: t.tol, col: s.col, row: s.row };
  });
  const worstLine = worst.ratio >= 0 ? `worst |diff|/tol ${worst.ratio.toFixed(3)} (|diff| ${Math.abs(worst.diff).toFixed(3)} m, tol ${worst.tol.toFixed(3)} m at col ${worst.col}, row ${worst.row})` : 'no comparable sample';
  log(worstLine);
  if (problems.length) throw new CheckFailure(`${problems.length} of ${samples.length} samples fail; ${worstLine}`, problems);
  return `${samples.length} samples within tolerance; ${worstLine}`;
}

/**
 * Check e on a tileset placed on the Earth: at raster samples placed with no terrastream code
 * (`samples`: lib/earth.mjs `placeSample`: lon, lat, raster value, undulation, expected
 * ellipsoidal height h), the height CesiumJS samples on the tileset
 * (scene.sampleHeightMostDetailed) within the deepest level-0 mesh tile's `errors.max` + `margin`
 * + its GLB's f32 step. Prints the table and the worst ratio.
 */
export async function earthHeightsCheck({ session, walk, samples, margin, timeoutMs, log }) {
  if (!session.page || !session.result) throw new CheckFailure('not run: no tileset loaded in CesiumJS (see the cesium check)');
  if (session.result.failed.length) throw new CheckFailure(`not run: CesiumJS failed to load ${session.result.failed.length} tiles (see the cesium check)`);
  const root = walk.rootJson;
  if (!root) throw new CheckFailure('no root tileset.json (see the walk check)');
  const ts = root.asset?.extras?.terrastream;
  if (ts?.placement !== 'exact') throw new CheckFailure(`asset.extras.terrastream.placement is ${JSON.stringify(ts?.placement)}, "exact" expected for a source with a CRS`);
  if (root.root?.transform !== undefined) throw new CheckFailure('the root tile has a transform: an exactly placed tileset has none (its GLB nodes carry their frames)');
  log(`frame: ${ts.frame?.crs?.definition ?? '?'}, vertical datum ${ts.frame?.vertical_datum ?? '?'}${ts.frame?.geoid ? ` (${ts.frame.geoid})` : ''}`);
  const tol = makeEarthTolerance(walk, margin);
  log(`${tol.count} level-0 mesh tiles with a region`);
  if (tol.count === 0) throw new CheckFailure('no content tile carries extras.terrastream {level: 0, kind: "mesh"} with a region: no tolerance can be derived');
  let res;
  try {
    res = await session.page.evaluate((pts, ms) => window.interopHeightsAt(pts, ms), samples.map((s) => [s.lon, s.lat]), timeoutMs);
  } catch (err) {
    throw new CheckFailure(`sampling heights in CesiumJS failed: ${truncate(err.message, 600)}`);
  }
  log(`sampleHeightMostDetailed: ${samples.length} samples in ${(res.ms / 1000).toFixed(1)} s; CesiumJS has loaded ${res.loaded.length} tile contents so far, ${res.failed.length} failed`);
  const pad = (v, n) => String(v).padStart(n);
  const f = (v, d = 2) => (v === null || v === undefined || Number.isNaN(v) ? '-' : v.toFixed(d));
  log(`${pad('col', 4)} ${pad('row', 4)} ${pad('lon', 12)} ${pad('lat', 11)} ${pad('raster', 8)} ${pad('geoid', 7)} ${pad('expected', 9)} ${pad('sampled', 9)} ${pad('diff', 8)} ${pad('tol', 7)}  tile  (err.max + margin + f32 step)`);
  const problems = res.failed.map((x) => `tileFailed while sampling: ${x.url}: ${truncate(x.message, 300)}`);
  let worst = { ratio: -1 };
  samples.forEach((s, i) => {
    const sampled = res.heights[i];
    const t = tol.at(s.lon, s.lat);
    const diff = sampled === null ? null : sampled - s.h;
    const where = `sample (${s.col}, ${s.row}) at lon ${s.lon.toFixed(6)}, lat ${s.lat.toFixed(6)}`;
    log(`${pad(s.col, 4)} ${pad(s.row, 4)} ${pad(f(s.lon, 6), 12)} ${pad(f(s.lat, 6), 11)} ${pad(f(s.value, 1), 8)} ${pad(f(s.undulation), 7)} ${pad(f(s.h), 9)} ${pad(f(sampled), 9)} ${pad(f(diff, 3), 8)} ${pad(t ? f(t.tol, 3) : '-', 7)}  ${t ? `${t.key} (${f(t.errMax, 3)} + ${t.margin} + ${t.step === undefined ? '?' : t.step.toPrecision(2)})` : '-'}`);
    if (!t) problems.push(`${where}: no level-0 mesh tile's region holds it`);
    else if (t.stepInfo?.error) problems.push(`${where}: the f32 step of tile ${t.key} is unknown: ${t.stepInfo.error}`);
    else if (!Number.isFinite(t.tol)) problems.push(`${where}: tile ${t.key} has no numeric errors.max (${JSON.stringify(t.errMax)})`);
    if (sampled === null) problems.push(`${where}: CesiumJS found no geometry there`);
    else if (t && Number.isFinite(t.tol)) {
      const ratio = Math.abs(diff) / t.tol;
      if (ratio > 1) problems.push(`${where}: sampled ${sampled.toFixed(3)} m, expected ${s.h.toFixed(3)} m (raster ${s.value} + geoid ${s.undulation.toFixed(3)}), |diff| ${Math.abs(diff).toFixed(3)} > tol ${t.tol.toFixed(3)} (tile ${t.key})`);
      if (ratio > worst.ratio) worst = { ratio, diff, tol: t.tol, col: s.col, row: s.row };
    }
  });
  const worstLine = worst.ratio >= 0 ? `worst |diff|/tol ${worst.ratio.toFixed(3)} (|diff| ${Math.abs(worst.diff).toFixed(3)} m, tol ${worst.tol.toFixed(3)} m at col ${worst.col}, row ${worst.row})` : 'no comparable sample';
  log(worstLine);
  if (problems.length) throw new CheckFailure(`${problems.length} of ${samples.length} samples fail; ${worstLine}`, problems);
  return `${samples.length} samples within tolerance; ${worstLine}`;
}
