#!/usr/bin/env node
// Interoperability checks of terrastream's 3D Tiles output: bake fuji + bunny, serve them, then
// walk, validate (Khronos), parse (loaders.gl), render (CesiumJS, offline), compare heights, and
// open the server's own viewer; bake a real DEM (SRTM, UTM 32N) and fuji below sea level, and
// check that the viewer shows their relief. The last line printed is `N passed, N failed`; exit 1
// on a failure.
//
// Environment: TERRASTREAM_BIN, TERRASTREAM_DATA, CHROMIUM, INTEROP_OUT (see README.md),
// INTEROP_TIMEOUT_S (whole run, default 480), INTEROP_KEEP=1 (keep the temp store).
import fs from 'node:fs';
import os from 'node:os';
import path from 'node:path';
import { fileURLToPath } from 'node:url';
import { Checks, CheckFailure } from './lib/checks.mjs';
import { runCommand, startDaemon, stopDaemon, freePort, waitReady, killAllChildren, fetchWithTimeout } from './lib/proc.mjs';
import { walkTileset, truncate } from './lib/walk.mjs';
import { validateGlbs } from './lib/validate.mjs';
import { loadersGlCheck } from './lib/loadersgl.mjs';
import { startStaticServer } from './lib/static-server.mjs';
import { launchBrowser } from './lib/browser.mjs';
import { cesiumLoadCheck, heightsCheck } from './lib/cesium.mjs';
import { viewerCheck, reliefCheck, seaLevelCheck } from './lib/viewer.mjs';
import { readTerrainRgb, checkPlacement, localFrame, toLocal } from './lib/heights.mjs';
import { readGeoTiff } from './lib/geotiff.mjs';

const HERE = path.dirname(fileURLToPath(import.meta.url));
const fromHere = (p) => path.resolve(HERE, p);
const cfg = {
  bin: process.env.TERRASTREAM_BIN ? path.resolve(process.env.TERRASTREAM_BIN) : fromHere('../../target/release/terrastream'),
  data: process.env.TERRASTREAM_DATA ? path.resolve(process.env.TERRASTREAM_DATA) : fromHere('../../../shared/data'),
  chromium: process.env.CHROMIUM || '/usr/bin/chromium',
  out: process.env.INTEROP_OUT ? path.resolve(process.env.INTEROP_OUT) : fromHere('out'),
  timeoutS: Number(process.env.INTEROP_TIMEOUT_S || 480),
  keep: process.env.INTEROP_KEEP === '1',
};

// The fuji bake: a 512×512 terrain-RGB PNG, 30 m cells, origin 0, anchored at Mt. Fuji, in
// 32-cell tiles: a quadtree 4 deep, so the root's children are external tilesets (one per index
// chunk below the root) and every client must follow them.
const FUJI = { cellSize: 30, tileSize: 32, anchor: { lon: 138.7274, lat: 35.3606 } };
const TILESETS = ['fuji', 'bunny'];
const MIN_SHARE = { fuji: 0.1, bunny: 0.02 };
// Check g, the viewer's relief on a real DEM: SRTM-derived, UTM 32N, PixelIsPoint, the Gabon coast
// at the equator (heights 1–1005 m, a low coastal plain in the west). Its centre as GDAL puts it
// (`gdalinfo`: 10°29'59.78"E, 0°30'0.93"N), for the server's globe position when it gives one.
const RELIEF = {
  name: 'gabon',
  file: 'geo/utm32n_pixelispoint_n00e010.tif',
  centre: { lon: 10 + 29 / 60 + 59.78 / 3600, lat: 30 / 60 + 0.93 / 3600, tolerance: 0.01, from: 'gdalinfo' },
  exaggeration: 5,
};
// And sea level: fuji lowered by 1000 m, so its heights run from about −986 m to 2751 m.
const SEA = { name: 'fuji-sea', zOffset: -1000 };

const checks = new Checks();
const runStarted = Date.now();
const cleanups = [];
let finished = false;

async function cleanup() {
  while (cleanups.length) {
    const fn = cleanups.pop();
    try {
      await fn();
    } catch (err) {
      console.log(`cleanup: ${err.message}`);
    }
  }
  killAllChildren();
}

function finish(code) {
  if (finished) return;
  finished = true;
  console.log(checks.summary());
  console.log(`run took ${((Date.now() - runStarted) / 1000).toFixed(1)} s`);
  console.log(`${checks.passed} passed, ${checks.failed} failed`);
  process.exitCode = code ?? (checks.failed > 0 ? 1 : 0);
}

// Whatever happens, nothing outlives the run: a hard timeout, signals, and exit all clean up.
const hardTimer = setTimeout(async () => {
  checks.fail('run', `hard timeout: the whole run took longer than ${cfg.timeoutS} s; stopped`);
  const force = setTimeout(() => {
    killAllChildren();
    finish(1);
    process.exit(1);
  }, 15_000);
  force.unref();
  await cleanup();
  finish(1);
  process.exit(1);
}, cfg.timeoutS * 1000);
hardTimer.unref();
for (const sig of ['SIGINT', 'SIGTERM']) {
  process.on(sig, async () => {
    checks.fail('run', `interrupted by ${sig}`);
    await cleanup();
    finish(1);
    process.exit(1);
  });
}
process.on('exit', () => killAllChildren());

/** A check that needs an earlier step: fails with the reason when that step did not happen. */
function needs(cond, reason) {
  if (!cond) throw new CheckFailure(`not run: ${reason}`);
}

async function main() {
  console.log(`terrastream interop: bin ${cfg.bin}, data ${cfg.data}, chromium ${cfg.chromium}, out ${cfg.out}`);
  fs.mkdirSync(cfg.out, { recursive: true });
  const tmp = fs.mkdtempSync(path.join(os.tmpdir(), 'terrastream-interop-'));
  const store = path.join(tmp, 'store');
  fs.mkdirSync(store);
  cleanups.push(() => {
    if (cfg.keep) console.log(`kept ${tmp}`);
    else fs.rmSync(tmp, { recursive: true, force: true });
  });

  // 1. bake
  const baked = {};
  const bakes = {
    fuji: ['bake', path.join(cfg.data, 'fuji.png'), '--encoding', 'terrain-rgb', '--cell-size', String(FUJI.cellSize), '--tile-size', String(FUJI.tileSize), '--anchor', `${FUJI.anchor.lon},${FUJI.anchor.lat}`, '--gpu', 'off', '--out', path.join(store, 'fuji')],
    bunny: ['bake-model', path.join(cfg.data, 'stanford-bunny.obj'), '--gpu', 'off', '--out', path.join(store, 'bunny')],
    [RELIEF.name]: ['bake', path.join(cfg.data, RELIEF.file), '--gpu', 'off', '--out', path.join(store, RELIEF.name)],
    [SEA.name]: ['bake', path.join(cfg.data, 'fuji.png'), '--encoding', 'terrain-rgb', '--cell-size', String(FUJI.cellSize), '--z-offset', String(SEA.zOffset), '--gpu', 'off', '--out', path.join(store, SEA.name)],
  };
  for (const name of Object.keys(bakes)) {
    baked[name] = await checks.run(`bake ${name}`, async (log) => {
      if (!fs.existsSync(cfg.bin)) throw new CheckFailure(`no binary at ${cfg.bin} (set TERRASTREAM_BIN)`);
      log(`$ ${path.basename(cfg.bin)} ${bakes[name].join(' ')}`);
      const r = await runCommand(cfg.bin, bakes[name], { timeoutMs: 180_000 });
      if (r.timedOut) throw new CheckFailure(`killed after 180 s`, r.stderr.split('\n').slice(-20));
      if (r.code !== 0) {
        const output = (r.stderr.trim() || r.stdout.trim() || '(no output)').split('\n');
        throw new CheckFailure(`exit ${r.code ?? r.signal}: ${truncate(output.slice(-3).join(' | '), 600)}`, output.slice(-30));
      }
      return `baked in ${(r.ms / 1000).toFixed(1)} s`;
    });
  }

  // 2. serve
  const port = await freePort();
  const base = `http://127.0.0.1:${port}`;
  const served = await checks.run('serve', async (log) => {
    needs(fs.existsSync(cfg.bin), `no binary at ${cfg.bin}`);
    const daemon = startDaemon(cfg.bin, ['serve', '--store', store, '--bind', `127.0.0.1:${port}`, '--gpu', 'off']);
    cleanups.push(async () => {
      await stopDaemon(daemon);
      const output = daemon.output.trim();
      if (checks.failed > 0 && output) console.log(`--- server output (last lines)\n${output.split('\n').slice(-40).join('\n')}`);
    });
    await waitReady(`${base}/readyz`, daemon, 60_000);
    const r = await fetchWithTimeout(`${base}/readyz`);
    log(`GET /readyz -> ${r.status} ${truncate(await r.text(), 200)}`);
    return `ready on ${base}`;
  });

  // 3a-c. walk, validate, parse
  const walks = {};
  for (const name of TILESETS) {
    const url = `${base}/tilesets/${name}/3dtiles/tileset.json`;
    await checks.run(`a. walk ${name}`, async (log) => {
      needs(served, 'the server is not running');
      if (!baked[name]) log(`note: the bake of ${name} failed`);
      const w = await walkTileset(url);
      walks[name] = w;
      const external = w.jsons.length - (w.rootJson ? 1 : 0);
      const bytes = w.glbs.reduce((s, g) => s + g.buf.length, 0);
      const depth = w.tiles.reduce((m, t) => Math.max(m, t.depth), 0);
      for (const n of w.notes) log(`note: ${n}`);
      const msg = `${w.jsons.length} tileset JSONs (${external} external), ${w.tiles.length} tiles, depth ${depth}, ${w.glbs.length} GLBs (${(bytes / 1024).toFixed(0)} KiB), ${w.fetches} fetches`;
      if (w.errors.length) throw new CheckFailure(`${w.errors.length} problem(s), first: ${truncate(w.errors[0], 300)}; ${msg}`, w.errors);
      if (w.glbs.length === 0) throw new CheckFailure(`no GLB content found; ${msg}`);
      return msg;
    });
  }
  for (const name of TILESETS) {
    await checks.run(`b. gltf-validator ${name}`, async (log) => {
      needs(walks[name], 'no walk');
      return validateGlbs(walks[name].glbs, log);
    });
  }
  for (const name of TILESETS) {
    await checks.run(`c. loaders.gl ${name}`, async (log) => {
      needs(walks[name], 'no walk');
      return loadersGlCheck(walks[name], log);
    });
  }
  await checks.run('placement fuji', async (log) => {
    needs(walks.fuji?.rootJson, 'no fuji tileset.json');
    let lf;
    try {
      lf = localFrame(walks.fuji.rootJson);
    } catch (err) {
      throw new CheckFailure(err.message);
    }
    const raster = readTerrainRgb(path.join(cfg.data, 'fuji.png'));
    // the centre of the samples' extent, at height 0
    const centre = toLocal(lf, ((raster.width - 1) * FUJI.cellSize) / 2, ((raster.height - 1) * FUJI.cellSize) / 2, 0);
    log(`local_frame: origin [${lf.origin.join(', ')}], north ${lf.north}`);
    const { lines, problems } = checkPlacement(walks.fuji.rootJson, FUJI.anchor, centre);
    lines.forEach(log);
    if (problems.length) throw new CheckFailure(problems[0], problems);
    return 'root.transform is east-north-up, the centre of the data at height 0 sits on the anchor';
  });

  // 3d-f. browsers
  let browser = null;
  let pageBase = null;
  let browserError = null;
  try {
    const cesiumDir = fromHere('node_modules/cesium/Build/Cesium');
    if (!fs.existsSync(path.join(cesiumDir, 'Cesium.js'))) throw new Error(`${cesiumDir}/Cesium.js is missing (npm ci?)`);
    const st = await startStaticServer({ '/cesium/': cesiumDir, '/': fromHere('page') });
    cleanups.push(() => new Promise((r) => {
      st.server.close(r);
      st.server.closeAllConnections();
    }));
    pageBase = st.url;
    browser = await launchBrowser(cfg.chromium);
    cleanups.push(async () => {
      const proc = browser.process();
      let timer;
      await Promise.race([browser.close(), new Promise((r) => (timer = setTimeout(r, 10_000)))]).catch(() => {});
      clearTimeout(timer);
      if (proc && proc.exitCode === null) proc.kill('SIGKILL');
      for (const s of [proc?.stdin, proc?.stdout, proc?.stderr]) s?.destroy();
    });
    console.log(`chromium ${await browser.version()}; test page on ${pageBase}`);
  } catch (err) {
    browserError = err.message;
    if (!fs.existsSync(cfg.chromium)) browserError += ` (no ${cfg.chromium}: apt-get install -y chromium, or set CHROMIUM)`;
  }

  for (const name of TILESETS) {
    const session = {};
    await checks.run(`d. cesium ${name}`, async (log) => {
      needs(served, 'the server is not running');
      needs(browser, `no browser: ${browserError}`);
      return cesiumLoadCheck({
        browser, pageUrl: `${pageBase}/index.html`, tilesetUrl: `${base}/tilesets/${name}/3dtiles/tileset.json`,
        screenshot: path.join(cfg.out, `cesium-${name}.png`), timeoutMs: 120_000, log, session,
      });
    });
    if (name === 'fuji') {
      await checks.run('e. heights fuji', async (log) => {
        needs(walks.fuji, 'no walk of fuji');
        const raster = readTerrainRgb(path.join(cfg.data, 'fuji.png'));
        return heightsCheck({ session, walk: walks.fuji, raster, cellSize: FUJI.cellSize, grid: 6, timeoutMs: 90_000, log });
      });
    }
    if (session.rec) fs.writeFileSync(path.join(cfg.out, `cesium-${name}-requests.txt`), `${session.rec.requests.join('\n')}\n`);
    if (session.page) await session.page.close().catch(() => {});
  }

  for (const name of TILESETS) {
    await checks.run(`f. viewer ${name}`, async (log) => {
      needs(served, 'the server is not running');
      needs(browser, `no browser: ${browserError}`);
      return viewerCheck({ browser, url: `${base}/viewer?tileset=${name}`, outFile: path.join(cfg.out, `viewer-${name}.png`), minShare: MIN_SHARE[name], log });
    });
  }

  // g. the viewer's relief: colours from the data's own heights, exaggeration, globe position, sea level
  const tilesetOf = async (name) => {
    const get = async (url) => {
      const r = await fetchWithTimeout(url);
      if (r.status !== 200) throw new CheckFailure(`GET ${url} -> ${r.status}: ${truncate(await r.text(), 300)}`);
      return r.json();
    };
    const root = await get(`${base}/tilesets/${name}/3dtiles/tileset.json`);
    let lf;
    try {
      lf = localFrame(root);
    } catch (err) {
      throw new CheckFailure(`${name}: ${err.message}`);
    }
    return { lf, summary: await get(`${base}/tilesets/${name}`) };
  };
  await checks.run(`g. viewer relief ${RELIEF.name}`, async (log) => {
    needs(served, 'the server is not running');
    needs(baked[RELIEF.name], `the bake of ${RELIEF.name} failed`);
    needs(browser, `no browser: ${browserError}`);
    let raster;
    try {
      raster = readGeoTiff(path.join(cfg.data, RELIEF.file));
    } catch (err) {
      throw new CheckFailure(err.message);
    }
    const { lf, summary } = await tilesetOf(RELIEF.name);
    return reliefCheck({ browser, base, name: RELIEF.name, raster, lf, summary, expectedCentre: RELIEF.centre, exaggeration: RELIEF.exaggeration, outDir: cfg.out, log });
  });
  await checks.run(`g. viewer sea level ${SEA.name}`, async (log) => {
    needs(served, 'the server is not running');
    needs(baked[SEA.name], `the bake of ${SEA.name} failed`);
    needs(browser, `no browser: ${browserError}`);
    const png = readTerrainRgb(path.join(cfg.data, 'fuji.png'));
    // fuji has no georeference: sample (col, row) lies at (col·cell, row·cell), as in the placement check
    const raster = { width: png.width, height: png.height, at: png.at, world: (col, row) => [col * FUJI.cellSize, row * FUJI.cellSize] };
    const { lf } = await tilesetOf(SEA.name);
    return seaLevelCheck({ browser, base, name: SEA.name, raster, lf, zOffset: SEA.zOffset, outDir: cfg.out, log });
  });
}

try {
  await main();
} catch (err) {
  checks.fail('run', `unexpected error: ${err?.stack ?? err}`);
}
await cleanup();
finish();
clearTimeout(hardTimer);
